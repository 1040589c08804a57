//! The calibration track of `docs/calibration-math.md` §2: straight 2ρ, semicircle
//! ρ, straight 2ρ, semicircle; driven counter-clockwise or clockwise.
//!
//! Poses are given in the *run frame* (origin at the run's start, x along the
//! first straight, y to the left) unless a name says `world`. The world frame
//! is the CCW run frame; the CW run frame is it rotated by 180° about the
//! middle of the first straight's ends, so that both loops lie on the same
//! side of the shared straight.

use std::f64::consts::PI;

use canodom_fusion::Pose;

use crate::error::{Result, positive};

/// The direction a run drives the track.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Counter-clockwise: every turn is a left turn, the loop lies at +y.
    Ccw,
    /// Clockwise: every turn is a right turn, the loop lies at −y.
    Cw,
}

impl Direction {
    /// Both directions, CCW first.
    pub const BOTH: [Direction; 2] = [Direction::Ccw, Direction::Cw];

    /// d = +1 for CCW, −1 for CW (the sign of every turn).
    pub fn sign(self) -> f64 {
        match self {
            Direction::Ccw => 1.0,
            Direction::Cw => -1.0,
        }
    }

    /// Stable numeric code (0 = CCW, 1 = CW) for status frames.
    pub fn code(self) -> u8 {
        match self {
            Direction::Ccw => 0,
            Direction::Cw => 1,
        }
    }
}

/// What a piece of the track is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    /// Arc length of the segment in metres.
    pub length_m: f64,
    /// Signed curvature (left positive): 0 on a straight, ±1/ρ on a semicircle.
    pub curvature_per_m: f64,
}

impl Segment {
    /// True for the semicircles.
    pub fn is_arc(&self) -> bool {
        self.curvature_per_m != 0.0
    }
}

/// The track, fixed by the radius ρ of its semicircles.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Track {
    radius_m: f64,
}

impl Track {
    /// A track with semicircles of radius `radius_m` (0.78 m in the paper).
    ///
    /// # Errors
    /// [`crate::Error::InvalidArgument`] unless the radius is finite and > 0.
    pub fn new(radius_m: f64) -> Result<Self> {
        Ok(Self {
            radius_m: positive("radius_m", radius_m)?,
        })
    }

    /// ρ, the radius of the semicircles.
    pub fn radius_m(&self) -> f64 {
        self.radius_m
    }

    /// The length of one lap, P = (4 + 2π)ρ.
    pub fn length_m(&self) -> f64 {
        (4.0 + 2.0 * PI) * self.radius_m
    }

    /// The true total turn of one lap: +2π CCW, −2π CW.
    pub fn total_turn_rad(&self, direction: Direction) -> f64 {
        direction.sign() * 2.0 * PI
    }

    /// The four segments in driving order.
    pub fn segments(&self, direction: Direction) -> [Segment; 4] {
        let straight = Segment {
            length_m: 2.0 * self.radius_m,
            curvature_per_m: 0.0,
        };
        let arc = Segment {
            length_m: PI * self.radius_m,
            curvature_per_m: direction.sign() / self.radius_m,
        };
        [straight, arc, straight, arc]
    }

    /// The segment index (0..4) and the segment at arc length `s_m` from the
    /// start (clamped to the lap).
    pub fn segment_at(&self, direction: Direction, s_m: f64) -> (usize, Segment) {
        let segments = self.segments(direction);
        let mut start = 0.0;
        for (i, seg) in segments.iter().enumerate() {
            if s_m < start + seg.length_m {
                return (i, *seg);
            }
            start += seg.length_m;
        }
        (3, segments[3])
    }

    /// The pose on the track after arc length `s_m` (clamped to `0..=P`), in
    /// the run frame, heading unwrapped.
    pub fn pose_at(&self, direction: Direction, s_m: f64) -> Pose {
        let mut remaining = s_m.clamp(0.0, self.length_m());
        let mut pose = Pose::default();
        for seg in self.segments(direction) {
            let step = remaining.min(seg.length_m);
            pose = along(pose, seg.curvature_per_m, step);
            remaining -= step;
            if remaining <= 0.0 {
                break;
            }
        }
        pose
    }

    /// The start pose of a run in the world frame: S_CCW = (0, 0, 0) and
    /// S_CW = (2ρ, 0, π), the two ends of the shared straight.
    pub fn start_pose_world(&self, direction: Direction) -> Pose {
        match direction {
            Direction::Ccw => Pose::default(),
            Direction::Cw => Pose {
                x_m: 2.0 * self.radius_m,
                y_m: 0.0,
                heading_rad: PI,
            },
        }
    }

    /// A run-frame pose expressed in the world frame.
    pub fn run_to_world(&self, direction: Direction, pose: Pose) -> Pose {
        match direction {
            Direction::Ccw => pose,
            Direction::Cw => Pose {
                x_m: 2.0 * self.radius_m - pose.x_m,
                y_m: -pose.y_m,
                heading_rad: pose.heading_rad + PI,
            },
        }
    }

    /// `points` poses evenly spaced along the lap (both ends included), in the
    /// world frame: the reference path for plots.
    pub fn reference_path_world(&self, direction: Direction, points: usize) -> Vec<Pose> {
        let n = points.max(2);
        (0..n)
            .map(|i| {
                let s = self.length_m() * i as f64 / (n - 1) as f64;
                self.run_to_world(direction, self.pose_at(direction, s))
            })
            .collect()
    }
}

/// Moves `distance_m` along a constant-curvature path from `pose`.
fn along(pose: Pose, curvature_per_m: f64, distance_m: f64) -> Pose {
    let h0 = pose.heading_rad;
    if curvature_per_m == 0.0 {
        let (s, c) = h0.sin_cos();
        return Pose {
            x_m: pose.x_m + distance_m * c,
            y_m: pose.y_m + distance_m * s,
            heading_rad: h0,
        };
    }
    let h1 = h0 + curvature_per_m * distance_m;
    Pose {
        x_m: pose.x_m + (h1.sin() - h0.sin()) / curvature_per_m,
        y_m: pose.y_m - (h1.cos() - h0.cos()) / curvature_per_m,
        heading_rad: h1,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() < 1e-12
    }

    #[test]
    fn lap_length_and_turn() {
        let t = Track::new(0.78).unwrap();
        assert!(
            (t.length_m() - 8.020_884_540).abs() < 1e-8,
            "{}",
            t.length_m()
        );
        assert_eq!(t.total_turn_rad(Direction::Cw), -2.0 * PI);
        let sum: f64 = t.segments(Direction::Ccw).iter().map(|s| s.length_m).sum();
        assert!(close(sum, t.length_m()));
        assert!(Track::new(0.0).is_err() && Track::new(f64::NAN).is_err());
    }

    #[test]
    fn corners_of_the_box_in_both_directions() {
        let t = Track::new(0.5).unwrap();
        for dir in Direction::BOTH {
            let d = dir.sign();
            let p = t.pose_at(dir, 1.0);
            assert!(close(p.x_m, 1.0) && close(p.y_m, 0.0) && close(p.heading_rad, 0.0));
            let p = t.pose_at(dir, 1.0 + PI * 0.5);
            assert!(close(p.x_m, 1.0) && close(p.y_m, d * 1.0), "{p:?}");
            assert!(close(p.heading_rad, d * PI));
            let p = t.pose_at(dir, t.length_m());
            assert!(p.x_m.abs() < 1e-12 && p.y_m.abs() < 1e-12);
            assert!(close(p.heading_rad, d * 2.0 * PI));
            // Apex of the first semicircle: 3ρ along x, on the loop's side.
            let p = t.pose_at(dir, 1.0 + PI * 0.25);
            assert!(close(p.x_m, 1.5) && close(p.y_m, d * 0.5), "{p:?}");
        }
        assert_eq!(t.segment_at(Direction::Cw, 1.5).0, 1);
        assert!(t.segment_at(Direction::Cw, 1.5).1.curvature_per_m < 0.0);
        assert_eq!(t.segment_at(Direction::Ccw, 2.7).0, 2);
        assert_eq!(t.segment_at(Direction::Ccw, 99.0).0, 3);
    }

    #[test]
    fn both_loops_lie_on_the_same_side_of_the_shared_straight() {
        let t = Track::new(0.78).unwrap();
        for dir in Direction::BOTH {
            let path = t.reference_path_world(dir, 401);
            assert!(path.iter().all(|p| p.y_m > -1e-9), "{dir:?}");
            let start = t.start_pose_world(dir);
            assert!(close(path[0].x_m, start.x_m) && close(path[0].heading_rad, start.heading_rad));
            // The lap closes on its start.
            let end = path[path.len() - 1];
            assert!((end.x_m - start.x_m).abs() < 1e-12 && end.y_m.abs() < 1e-12);
        }
        // Each run first drives the straight towards the other start point.
        for dir in Direction::BOTH {
            let other = t.start_pose_world(match dir {
                Direction::Ccw => Direction::Cw,
                Direction::Cw => Direction::Ccw,
            });
            let p = t.run_to_world(dir, t.pose_at(dir, 2.0 * t.radius_m()));
            assert!(
                (p.x_m - other.x_m).abs() < 1e-12 && p.y_m.abs() < 1e-12,
                "{dir:?}"
            );
        }
    }
}
