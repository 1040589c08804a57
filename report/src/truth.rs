//! A replay against a reference trajectory (`replay --truth`): the replayed
//! poses placed on the reference at a start time, then their distance from
//! it at every step; the end error, the largest error and the end error per
//! distance driven, for the fused pose and for rear-only odometry; and a
//! picture of the three tracks with the errors over time.
//!
//! Odometry starts at the origin facing +x, the reference is in its own
//! frame (a local east-north plane, a motion-capture frame, a simulator's
//! world), so the replay is dead-reckoned from the reference's pose at the
//! start: its position there and its heading, from the reference's
//! `heading_rad` column when it has one, else from its course around the
//! start (which needs the vehicle to be moving then).

use crate::files::TRAJECTORY_AXES;
use crate::files::{
    PlotResult, PlottedReport, ReportError, draw_legend, draw_line, square_view, xy_chart,
};
use canodom_calib::drive::Fix;
use canodom_fusion::Pose;
use plotters::coord::Shift;
use plotters::prelude::*;
use serde::Serialize;

/// Paths are thinned to at most this many points in the picture.
const MAX_PATH_POINTS: usize = 2_000;
/// The course is taken over points at least this far apart, metres.
const MIN_COURSE_BASE_M: f64 = 0.5;

/// One replay step at its absolute time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackPoint {
    /// Time on the log's clock (Unix seconds, as candump -L writes).
    pub t_unix_s: f64,
    /// The fused pose.
    pub fused: Pose,
    /// Rear-wheel-only odometry.
    pub rear: Pose,
}

/// How far one reckoning strays from the reference.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Errors {
    /// Distance from the reference at the last step, metres.
    pub end_error_m: f64,
    /// The largest distance at any step, metres.
    pub max_error_m: f64,
    /// The end error over the distance the reference drove, as a fraction.
    pub end_error_per_distance: f64,
}

/// The comparison of a replay with a reference.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TruthComparison {
    /// The start (Unix seconds): the step nearest the asked start time.
    pub start_unix_s: f64,
    /// From the start to the last step compared, seconds.
    pub duration_s: f64,
    /// The reference's path length over that time, metres.
    pub distance_m: f64,
    /// The reference's heading at the start, radians, and where it came from.
    pub start_heading_rad: f64,
    /// `"heading_rad column"` or `"course"`.
    pub start_heading_from: &'static str,
    /// The fused pose's errors.
    pub fused: Errors,
    /// Rear-only odometry's errors.
    pub rear: Errors,
    /// `[t since start, fused error, rear error]` at each step (thinned).
    pub errors_over_time: Vec<[f64; 3]>,
    /// The reference over the compared time, x-y (thinned).
    pub truth_path: Vec<[f64; 2]>,
    /// The fused track placed on the reference, x-y (thinned).
    pub fused_path: Vec<[f64; 2]>,
    /// The rear-only track placed on the reference, x-y (thinned).
    pub rear_path: Vec<[f64; 2]>,
}

/// The reference position at `t`, linear between its rows; `None` outside it.
fn truth_at(truth: &[Fix], t: f64) -> Option<(f64, f64)> {
    let (first, last) = (truth.first()?, truth.last()?);
    if t < first.t_s || t > last.t_s {
        return None;
    }
    let i = truth
        .partition_point(|r| r.t_s < t)
        .clamp(1, truth.len() - 1);
    let (a, b) = (&truth[i - 1], &truth[i]);
    let f = if b.t_s > a.t_s {
        ((t - a.t_s) / (b.t_s - a.t_s)).clamp(0.0, 1.0)
    } else {
        0.0
    };
    Some((a.x_m + f * (b.x_m - a.x_m), a.y_m + f * (b.y_m - a.y_m)))
}

/// The reference heading at `t`: its heading column, or its course over the
/// shortest window around `t` (from ±0.5 s, doubled up to ±8 s) whose ends
/// are [`MIN_COURSE_BASE_M`] apart.
fn heading_at(truth: &[Fix], t: f64) -> Option<(f64, &'static str)> {
    let i = truth
        .partition_point(|r| r.t_s < t)
        .clamp(1, truth.len() - 1);
    let (a, b) = (&truth[i - 1], &truth[i]);
    if let (Some(ha), Some(hb)) = (a.heading_rad, b.heading_rad) {
        let f = if b.t_s > a.t_s {
            ((t - a.t_s) / (b.t_s - a.t_s)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let d = (hb - ha + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
            - std::f64::consts::PI;
        return Some((ha + f * d, "heading_rad column"));
    }
    let (t0, t1) = (truth.first()?.t_s, truth.last()?.t_s);
    let mut half = 0.5;
    while half <= 8.0 {
        let (p, q) = (
            truth_at(truth, (t - half).max(t0))?,
            truth_at(truth, (t + half).min(t1))?,
        );
        if (q.0 - p.0).hypot(q.1 - p.1) >= MIN_COURSE_BASE_M {
            return Some(((q.1 - p.1).atan2(q.0 - p.0), "course"));
        }
        half *= 2.0;
    }
    None
}

/// The reference's path length between `a` and `b` (interpolated ends).
fn distance_between(truth: &[Fix], a: f64, b: f64) -> f64 {
    let mut points: Vec<(f64, f64)> = truth_at(truth, a).into_iter().collect();
    points.extend(
        truth
            .iter()
            .filter(|r| r.t_s > a && r.t_s < b)
            .map(|r| (r.x_m, r.y_m)),
    );
    points.extend(truth_at(truth, b));
    points
        .windows(2)
        .map(|w| (w[1].0 - w[0].0).hypot(w[1].1 - w[0].1))
        .sum()
}

/// Every `n`-th point so that at most [`MAX_PATH_POINTS`] remain, the last kept.
fn thin<T: Copy>(points: &[T]) -> Vec<T> {
    let step = points.len().div_ceil(MAX_PATH_POINTS).max(1);
    let mut out: Vec<T> = points.iter().step_by(step).copied().collect();
    if let Some(&last) = points.last()
        && !(points.len() - 1).is_multiple_of(step)
    {
        out.push(last);
    }
    out
}

impl TruthComparison {
    /// Places `track` on `truth` at the step nearest `start_unix_s` (the
    /// first step inside the reference when `None`) and measures it.
    ///
    /// # Errors
    /// [`ReportError::Truth`] when the reference and the replay do not
    /// overlap in time, or the start heading cannot be told.
    pub fn build(
        truth: &[Fix],
        track: &[TrackPoint],
        start_unix_s: Option<f64>,
    ) -> Result<Self, ReportError> {
        let bad = |why: String| ReportError::Truth(why);
        let (Some(first), Some(last)) = (truth.first(), truth.last()) else {
            return Err(bad("the reference has no row".to_owned()));
        };
        let inside: Vec<&TrackPoint> = track
            .iter()
            .filter(|p| p.t_unix_s >= first.t_s && p.t_unix_s <= last.t_s)
            .collect();
        if inside.len() < 2 {
            return Err(bad(format!(
                "the reference covers {:.3}–{:.3} s (Unix time) and the replay's steps {}: \
                 they do not overlap (are both on the log's clock?)",
                first.t_s,
                last.t_s,
                match (track.first(), track.last()) {
                    (Some(a), Some(b)) => format!("{:.3}–{:.3} s", a.t_unix_s, b.t_unix_s),
                    _ => "are none".to_owned(),
                }
            )));
        }
        let wanted = start_unix_s.unwrap_or(inside[0].t_unix_s);
        let start_index = inside
            .iter()
            .enumerate()
            .min_by(|(_, p), (_, q)| {
                (p.t_unix_s - wanted)
                    .abs()
                    .total_cmp(&(q.t_unix_s - wanted).abs())
            })
            .map_or(0, |(i, _)| i);
        let steps = &inside[start_index..];
        let start = steps[0];
        let start_xy = truth_at(truth, start.t_unix_s)
            .ok_or_else(|| bad("the start is outside the reference".to_owned()))?;
        let (heading, heading_from) = heading_at(truth, start.t_unix_s).ok_or_else(|| {
            bad(format!(
                "the reference does not move around {:.3} s, so its heading there is unknown: \
                 start later, or give a heading_rad column",
                start.t_unix_s
            ))
        })?;
        let place = |pose: Pose, at: Pose| -> [f64; 2] {
            let turn = heading - at.heading_rad;
            let (s, c) = turn.sin_cos();
            let (dx, dy) = (pose.x_m - at.x_m, pose.y_m - at.y_m);
            [start_xy.0 + c * dx - s * dy, start_xy.1 + s * dx + c * dy]
        };
        let mut fused_path = Vec::with_capacity(steps.len());
        let mut rear_path = Vec::with_capacity(steps.len());
        let mut truth_path = Vec::with_capacity(steps.len());
        let mut errors = Vec::with_capacity(steps.len());
        for p in steps {
            let Some(reference) = truth_at(truth, p.t_unix_s) else {
                continue;
            };
            let (f, r) = (place(p.fused, start.fused), place(p.rear, start.rear));
            errors.push([
                p.t_unix_s - start.t_unix_s,
                (f[0] - reference.0).hypot(f[1] - reference.1),
                (r[0] - reference.0).hypot(r[1] - reference.1),
            ]);
            fused_path.push(f);
            rear_path.push(r);
            truth_path.push([reference.0, reference.1]);
        }
        let end = steps[steps.len() - 1];
        let distance_m = distance_between(truth, start.t_unix_s, end.t_unix_s);
        let of = |k: usize| {
            let end_error_m = errors.last().map_or(0.0, |e| e[k]);
            Errors {
                end_error_m,
                max_error_m: errors.iter().map(|e| e[k]).fold(0.0, f64::max),
                end_error_per_distance: end_error_m / distance_m.max(f64::MIN_POSITIVE),
            }
        };
        Ok(Self {
            start_unix_s: start.t_unix_s,
            duration_s: end.t_unix_s - start.t_unix_s,
            distance_m,
            start_heading_rad: heading,
            start_heading_from: heading_from,
            fused: of(1),
            rear: of(2),
            errors_over_time: thin(&errors),
            truth_path: thin(&truth_path),
            fused_path: thin(&fused_path),
            rear_path: thin(&rear_path),
        })
    }

    /// The comparison in words, one line each for the fused pose and rear-only.
    pub fn summary(&self) -> String {
        let line = |name: &str, e: &Errors| {
            format!(
                "{name}: end error {:.3} m ({:.2} % of {:.1} m), largest {:.3} m",
                e.end_error_m,
                100.0 * e.end_error_per_distance,
                self.distance_m,
                e.max_error_m
            )
        };
        format!(
            "against the reference from {:.3} s for {:.1} s (start heading {:.1}° from its {}):\n  {}\n  {}",
            self.start_unix_s,
            self.duration_s,
            self.start_heading_rad.to_degrees(),
            self.start_heading_from,
            line("fused    ", &self.fused),
            line("rear-only", &self.rear)
        )
    }
}

impl PlottedReport for TruthComparison {
    const SVG_SIZE_PX: (u32, u32) = (900, 900);

    fn draw(&self, root: &DrawingArea<SVGBackend<'_>, Shift>) -> PlotResult {
        root.fill(&WHITE)?;
        let (xs, ys) = square_view(
            self.truth_path
                .iter()
                .chain(&self.fused_path)
                .chain(&self.rear_path),
        );
        let title = format!(
            "canodom replay against the reference: {:.0} m in {:.0} s",
            self.distance_m, self.duration_s
        );
        let root = root.titled(&title, ("sans-serif", 22))?;
        let (top, bottom) = root.split_vertically(430);
        let mut chart = xy_chart(
            &top,
            "the replay, dead-reckoned from the reference at the start",
            &TRAJECTORY_AXES,
            (xs, ys),
        )?;
        let fused_label = format!("fused: end {:.2} m", self.fused.end_error_m);
        let rear_label = format!("rear-only: end {:.2} m", self.rear.end_error_m);
        for (path, colour, label) in [
            (&self.truth_path, BLACK, "reference"),
            (&self.rear_path, RED, rear_label.as_str()),
            (&self.fused_path, BLUE, fused_label.as_str()),
        ] {
            draw_line(&mut chart, path.iter().map(|p| (p[0], p[1])), colour, label)?;
        }
        if let Some(p) = self.truth_path.first() {
            chart.draw_series(std::iter::once(Circle::new(
                (p[0], p[1]),
                5,
                BLACK.filled(),
            )))?;
        }
        draw_legend(&mut chart)?;

        let t_max = self.errors_over_time.last().map_or(1.0, |e| e[0]).max(1e-3);
        let e_max = self
            .errors_over_time
            .iter()
            .flat_map(|e| [e[1], e[2]])
            .filter(|e| e.is_finite())
            .fold(0.01f64, f64::max);
        let mut chart = ChartBuilder::on(&bottom)
            .caption("distance from the reference", ("sans-serif", 16))
            .margin(15)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..t_max, 0.0..e_max * 1.05)?;
        chart
            .configure_mesh()
            .x_desc("time since the start (s)")
            .y_desc("error (m)")
            .draw()?;
        for (k, colour, label) in [(2, RED, "rear-only"), (1, BLUE, "fused")] {
            draw_line(
                &mut chart,
                self.errors_over_time.iter().map(|e| (e[0], e[k])),
                colour,
                label,
            )?;
        }
        draw_legend(&mut chart)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::files::ReportFiles;

    /// A reference driving a quarter circle of radius 20 m at 10 m/s from
    /// (100, 50) heading north, at 20 Hz.
    fn reference(with_heading: bool) -> Vec<Fix> {
        (0..=63)
            .map(|i| {
                let t = f64::from(i) * 0.05;
                let a = t * 10.0 / 20.0;
                Fix {
                    t_s: 1000.0 + t,
                    x_m: 100.0 - 20.0 + 20.0 * a.cos(),
                    y_m: 50.0 + 20.0 * a.sin(),
                    heading_rad: with_heading.then_some(std::f64::consts::FRAC_PI_2 + a),
                    sigma_m: None,
                }
            })
            .collect()
    }

    /// The same drive as odometry sees it (origin, facing +x), `scale` times
    /// too long for the rear.
    fn track(scale: f64) -> Vec<TrackPoint> {
        (0..=30)
            .map(|i| {
                let t = f64::from(i) * 0.1;
                let pose = |s: f64| {
                    let a = t * 10.0 * s / 20.0;
                    Pose {
                        x_m: 20.0 * a.sin(),
                        y_m: 20.0 * (1.0 - a.cos()),
                        heading_rad: a,
                    }
                };
                TrackPoint {
                    t_unix_s: 1000.0 + t,
                    fused: pose(1.0),
                    rear: pose(scale),
                }
            })
            .collect()
    }

    #[test]
    fn a_perfect_replay_has_no_error_and_a_scaled_one_its_own() {
        // Without a heading column the course is a chord around the start:
        // centred (1 s in) it is parallel to the arc's tangent.
        for (with_heading, start, metres) in [(true, None, 30.0), (false, Some(1001.0), 20.0)] {
            let c = TruthComparison::build(&reference(with_heading), &track(1.01), start).unwrap();
            assert!(c.fused.end_error_m < 0.05, "{c:?}");
            assert!((c.distance_m - metres).abs() < 0.01, "{}", c.distance_m);
            // 1 % long: about 1 % of the distance ahead along the arc.
            assert!(
                (c.rear.end_error_m - 0.01 * metres).abs() < 0.03,
                "{}",
                c.rear.end_error_m
            );
            assert!(c.rear.max_error_m >= c.rear.end_error_m);
            assert!((c.rear.end_error_per_distance - 0.01).abs() < 0.001);
        }
    }

    #[test]
    fn a_later_start_measures_from_there() {
        let c = TruthComparison::build(&reference(true), &track(1.01), Some(1001.5)).unwrap();
        assert!((c.start_unix_s - 1001.5).abs() < 1e-9);
        assert!((c.distance_m - 15.0).abs() < 0.01, "{}", c.distance_m);
        assert!((c.rear.end_error_m - 0.15).abs() < 0.02, "{c:?}");
    }

    #[test]
    fn no_overlap_or_no_motion_is_refused_in_words() {
        let mut late = track(1.0);
        for p in &mut late {
            p.t_unix_s += 100.0;
        }
        let e = TruthComparison::build(&reference(true), &late, None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("do not overlap"), "{e}");
        let still: Vec<Fix> = (0..40)
            .map(|i| Fix {
                t_s: 1000.0 + f64::from(i) * 0.1,
                x_m: 1.0,
                y_m: 2.0,
                heading_rad: None,
                sigma_m: None,
            })
            .collect();
        let e = TruthComparison::build(&still, &track(1.0), None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("heading there is unknown"), "{e}");
    }

    #[test]
    fn the_picture_and_numbers_are_written() {
        let c = TruthComparison::build(&reference(false), &track(1.02), Some(1001.0)).unwrap();
        let svg = c.svg().unwrap();
        assert!(svg.contains("<svg") && svg.contains("rear-only"));
        let json: serde_json::Value = serde_json::from_str(&c.json().unwrap()).unwrap();
        assert!((json["rear"]["end_error_m"].as_f64().unwrap() - 0.4).abs() < 0.05);
        assert!(c.summary().contains("course"));
    }
}
