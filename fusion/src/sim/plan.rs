//! Paths for the simulator: segments (straights, arcs, steering ramps,
//! constant steering commands) and ready-made plans (the calibration track,
//! circles, a figure eight, random drives, a full-size road drive).
//!
//! A plan is what the driver *intends*: curvature as a function of the
//! distance along the path. The simulated car turns it into steering
//! commands through the driver's belief of the steering map, so with a
//! wrong belief, or path-following noise, the real path differs.

use crate::error::{Error, Result};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::PI;

/// The direction of a run on the calibration track (`docs/calibration-math.md` §2).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Counter-clockwise: turns left, the loop lies at +y of the run frame.
    Ccw,
    /// Clockwise: turns right, the loop lies at −y.
    Cw,
}

impl Direction {
    /// +1 for CCW, −1 for CW (the `d` of §2).
    pub fn sign(self) -> f64 {
        match self {
            Direction::Ccw => 1.0,
            Direction::Cw => -1.0,
        }
    }
}

/// One piece of a plan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Segment {
    /// Straight ahead.
    Straight {
        /// Length of the rear-axle centre's path.
        length_m: f64,
    },
    /// A constant-curvature arc.
    Arc {
        /// Radius of the rear-axle centre's path (> 0).
        radius_m: f64,
        /// Heading change, positive to the left (CCW).
        angle_rad: f64,
    },
    /// Curvature changing linearly with distance (a clothoid), as a driver
    /// turning the wheel steadily.
    Ramp {
        /// Curvature at the start, left positive.
        from_curvature_per_m: f64,
        /// Curvature at the end.
        to_curvature_per_m: f64,
        /// Length of the ramp.
        length_m: f64,
    },
    /// A constant steering *command* in the vehicle's signal units, whatever
    /// path it gives (`docs/calibration-math.md` §10 steering calibration).
    Command {
        /// The steering signal `u` sent to the actuator.
        signal: f64,
        /// Distance to drive with it.
        length_m: f64,
    },
    /// A stop (no length): the car brakes to rest exactly here, stands for
    /// `duration_s`, then drives on, backwards if `reverse` flips the
    /// direction of travel (stop-and-go, manoeuvring). Reversed segments are
    /// driven with the steering their curvature asks for, so their heading
    /// change has the opposite sign of [`Segment::turn_rad`].
    Stop {
        /// Time at rest.
        duration_s: f64,
        /// Flip the direction of travel after the stop.
        reverse: bool,
    },
    /// A speed change (no length): from here on the car cruises at
    /// `speed_mps` (it brakes ahead of the mark to reach a lower speed there).
    Speed {
        /// The new cruising speed of the rear-axle centre.
        speed_mps: f64,
    },
}

/// What the car is asked to steer on a piece of path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Steer {
    /// An intended curvature, turned into a command through the driver's belief.
    Curvature(f64),
    /// A raw steering signal.
    Signal(f64),
}

impl Segment {
    /// The segment's length along the rear-axle centre's path.
    pub fn length_m(&self) -> f64 {
        match *self {
            Segment::Straight { length_m }
            | Segment::Ramp { length_m, .. }
            | Segment::Command { length_m, .. } => length_m,
            Segment::Arc {
                radius_m,
                angle_rad,
            } => radius_m * angle_rad.abs(),
            Segment::Stop { .. } | Segment::Speed { .. } => 0.0,
        }
    }

    /// The intended steering at `s_m` metres into the segment.
    pub(crate) fn steer_at(&self, s_m: f64) -> Steer {
        match *self {
            Segment::Straight { .. } | Segment::Stop { .. } | Segment::Speed { .. } => {
                Steer::Curvature(0.0)
            }
            Segment::Arc {
                radius_m,
                angle_rad,
            } => Steer::Curvature(angle_rad.signum() / radius_m),
            Segment::Ramp {
                from_curvature_per_m,
                to_curvature_per_m,
                length_m,
            } => {
                let f = (s_m / length_m).clamp(0.0, 1.0);
                Steer::Curvature(
                    from_curvature_per_m + f * (to_curvature_per_m - from_curvature_per_m),
                )
            }
            Segment::Command { signal, .. } => Steer::Signal(signal),
        }
    }

    /// The total heading change of a curvature segment (`None` for a command,
    /// whose turn depends on the vehicle's true steering map).
    pub fn turn_rad(&self) -> Option<f64> {
        match *self {
            Segment::Straight { .. } | Segment::Stop { .. } | Segment::Speed { .. } => Some(0.0),
            Segment::Arc { angle_rad, .. } => Some(angle_rad),
            Segment::Ramp {
                from_curvature_per_m,
                to_curvature_per_m,
                length_m,
            } => Some(0.5 * (from_curvature_per_m + to_curvature_per_m) * length_m),
            Segment::Command { .. } => None,
        }
    }

    fn validate(&self) -> Result<()> {
        let bad = |name: &'static str, v: f64| Error::InvalidConfig {
            name,
            reason: format!("must be finite and > 0, got {v}"),
        };
        match *self {
            Segment::Straight { length_m }
            | Segment::Command { length_m, .. }
            | Segment::Ramp { length_m, .. }
                if !(length_m.is_finite() && length_m > 0.0) =>
            {
                Err(bad("segment length_m", length_m))
            }
            Segment::Arc { radius_m, .. } if !(radius_m.is_finite() && radius_m > 0.0) => {
                Err(bad("arc radius_m", radius_m))
            }
            Segment::Arc { angle_rad, .. } if !(angle_rad.is_finite() && angle_rad != 0.0) => {
                Err(bad("arc angle_rad (non-zero)", angle_rad))
            }
            Segment::Ramp {
                from_curvature_per_m: a,
                to_curvature_per_m: b,
                ..
            } if !(a.is_finite() && b.is_finite()) => Err(bad(
                "ramp curvature_per_m",
                if a.is_finite() { b } else { a },
            )),
            Segment::Command { signal, .. } if !signal.is_finite() => {
                Err(bad("command signal", signal))
            }
            Segment::Stop { duration_s, .. } if !(duration_s.is_finite() && duration_s >= 0.0) => {
                Err(Error::InvalidConfig {
                    name: "stop duration_s",
                    reason: format!("must be finite and >= 0, got {duration_s}"),
                })
            }
            Segment::Speed { speed_mps } if !(speed_mps.is_finite() && speed_mps > 0.0) => {
                Err(bad("speed speed_mps", speed_mps))
            }
            _ => Ok(()),
        }
    }
}

/// A path to drive: segments in order, from rest to rest.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Plan {
    /// The segments, driven in order.
    pub segments: Vec<Segment>,
}

impl Plan {
    /// A plan from segments, validated (finite, positive lengths and radii).
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] naming the first bad segment value, or an empty plan.
    pub fn new(segments: Vec<Segment>) -> Result<Self> {
        if segments.is_empty() {
            return Err(Error::InvalidConfig {
                name: "plan",
                reason: "has no segments".into(),
            });
        }
        for s in &segments {
            s.validate()?;
        }
        if !segments.iter().any(|s| s.length_m() > 0.0) {
            return Err(Error::InvalidConfig {
                name: "plan",
                reason: "has no segment with a length".into(),
            });
        }
        Ok(Self { segments })
    }

    /// The calibration track (§2): straight 2ρ, semicircle ρ, straight 2ρ,
    /// semicircle, repeated `laps` times; length `(4+2π)ρ` per lap. The run
    /// frame has its origin at the start and x along the first straight.
    ///
    /// # Errors
    /// For a non-positive ρ or zero laps.
    pub fn track(rho_m: f64, direction: Direction, laps: u32) -> Result<Self> {
        if laps == 0 {
            return Err(Error::InvalidConfig {
                name: "laps",
                reason: "must be at least 1".into(),
            });
        }
        let half = Segment::Arc {
            radius_m: rho_m,
            angle_rad: direction.sign() * PI,
        };
        let straight = Segment::Straight {
            length_m: 2.0 * rho_m,
        };
        let lap = [straight, half, straight, half];
        Self::new(
            lap.iter()
                .copied()
                .cycle()
                .take(4 * laps as usize)
                .collect(),
        )
    }

    /// A constant-curvature circle of `turns` full turns.
    ///
    /// # Errors
    /// For a non-positive radius or number of turns.
    pub fn circle(radius_m: f64, direction: Direction, turns: f64) -> Result<Self> {
        Self::new(vec![Segment::Arc {
            radius_m,
            angle_rad: direction.sign() * 2.0 * PI * turns,
        }])
    }

    /// A constant steering command `signal` for `length_m` (§10: about 2 m each).
    ///
    /// # Errors
    /// For a non-finite signal or a non-positive length.
    pub fn constant_command(signal: f64, length_m: f64) -> Result<Self> {
        Self::new(vec![Segment::Command { signal, length_m }])
    }

    /// A figure eight: a full left circle then a full right circle, both of
    /// radius `radius_m`, meeting where the run starts and ends.
    ///
    /// # Errors
    /// For a non-positive radius.
    pub fn figure_eight(radius_m: f64) -> Result<Self> {
        Self::new(vec![
            Segment::Arc {
                radius_m,
                angle_rad: 2.0 * PI,
            },
            Segment::Arc {
                radius_m,
                angle_rad: -2.0 * PI,
            },
        ])
    }

    /// A random drive of about `length_m`: straights, then curves entered and
    /// left through steering ramps, radii never below `min_radius_m`.
    /// Deterministic for a seed.
    ///
    /// # Errors
    /// For a non-positive length or radius.
    pub fn random_drive(seed: u64, length_m: f64, min_radius_m: f64) -> Result<Self> {
        if !(length_m.is_finite()
            && length_m > 0.0
            && min_radius_m.is_finite()
            && min_radius_m > 0.0)
        {
            return Err(Error::InvalidConfig {
                name: "random_drive",
                reason: format!("length {length_m} m and radius {min_radius_m} m must be > 0"),
            });
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut segments = Vec::new();
        let mut total_m = 0.0;
        // Pieces scale with the turning radius so a 1:10 car and a road car
        // get drives of the same character.
        let unit_m = min_radius_m;
        while total_m < length_m {
            let straight_m = unit_m * rng.random_range(0.5..3.0);
            segments.push(Segment::Straight {
                length_m: straight_m,
            });
            let radius_m = min_radius_m * rng.random_range(1.0..4.0);
            let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let kappa = sign / radius_m;
            let ramp_m = unit_m * rng.random_range(0.2..0.6);
            let arc_rad = rng.random_range(0.3..2.5);
            segments.push(Segment::Ramp {
                from_curvature_per_m: 0.0,
                to_curvature_per_m: kappa,
                length_m: ramp_m,
            });
            segments.push(Segment::Arc {
                radius_m,
                angle_rad: sign * arc_rad,
            });
            segments.push(Segment::Ramp {
                from_curvature_per_m: kappa,
                to_curvature_per_m: 0.0,
                length_m: ramp_m,
            });
            total_m += straight_m + 2.0 * ramp_m + radius_m * arc_rad;
        }
        Self::new(segments)
    }

    /// The full-size car's drive of `docs/calibration-math.md` §12: two loops of
    /// 15 m radius and eight gentle curves (radius 50–120 m, entered through
    /// steering ramps), joined by straights, 660 m in all. The curves' sizes
    /// and sides vary with the seed.
    ///
    /// # Errors
    /// Never for the built-in figures; kept fallible like the other plans.
    pub fn road_drive(seed: u64) -> Result<Self> {
        const TOTAL_M: f64 = 660.0;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut curves = Vec::new();
        let mut curved_m = 0.0;
        for k in 0..10 {
            let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let (radius_m, angle_rad, ramp_m) = if k == 2 || k == 6 {
                (15.0, 2.0 * PI, 6.0)
            } else {
                (
                    rng.random_range(50.0..120.0),
                    rng.random_range(0.15..0.35),
                    8.0,
                )
            };
            let kappa = sign / radius_m;
            let piece = [
                Segment::Ramp {
                    from_curvature_per_m: 0.0,
                    to_curvature_per_m: kappa,
                    length_m: ramp_m,
                },
                Segment::Arc {
                    radius_m,
                    angle_rad: sign * angle_rad,
                },
                Segment::Ramp {
                    from_curvature_per_m: kappa,
                    to_curvature_per_m: 0.0,
                    length_m: ramp_m,
                },
            ];
            curved_m += piece.iter().map(Segment::length_m).sum::<f64>();
            curves.push(piece);
        }
        let straight_m = (TOTAL_M - curved_m) / 11.0;
        if straight_m <= 0.0 {
            return Err(Error::InvalidConfig {
                name: "road_drive",
                reason: "curves longer than the drive".into(),
            });
        }
        let mut segments = vec![Segment::Straight {
            length_m: straight_m,
        }];
        for piece in curves {
            segments.extend(piece);
            segments.push(Segment::Straight {
                length_m: straight_m,
            });
        }
        Self::new(segments)
    }

    /// This plan followed by another.
    #[must_use]
    pub fn then(mut self, other: &Plan) -> Plan {
        self.segments.extend_from_slice(&other.segments);
        self
    }

    /// The plan's length along the rear-axle centre's path.
    pub fn length_m(&self) -> f64 {
        self.segments.iter().map(Segment::length_m).sum()
    }

    /// The plan's total intended heading change (`None` if it holds commands).
    pub fn turn_rad(&self) -> Option<f64> {
        self.segments.iter().map(Segment::turn_rad).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn track_length_and_turn() {
        let p = Plan::track(0.78, Direction::Cw, 2).unwrap();
        assert!((p.length_m() - 2.0 * (4.0 + 2.0 * PI) * 0.78).abs() < 1e-12);
        assert!((p.turn_rad().unwrap() + 4.0 * PI).abs() < 1e-12);
        assert!(Plan::track(0.0, Direction::Cw, 1).is_err());
        assert!(Plan::track(0.78, Direction::Cw, 0).is_err());
    }

    #[test]
    fn road_drive_is_660_m_with_two_loops() {
        for seed in 0..5 {
            let p = Plan::road_drive(seed).unwrap();
            assert!((p.length_m() - 660.0).abs() < 1e-9);
            let loops = p
                .segments
                .iter()
                .filter(|s| matches!(s, Segment::Arc { radius_m, .. } if *radius_m == 15.0))
                .count();
            assert_eq!(loops, 2);
        }
    }

    #[test]
    fn random_drive_is_deterministic_and_long_enough() {
        let a = Plan::random_drive(7, 50.0, 1.0).unwrap();
        assert_eq!(a, Plan::random_drive(7, 50.0, 1.0).unwrap());
        assert_ne!(a, Plan::random_drive(8, 50.0, 1.0).unwrap());
        assert!(a.length_m() >= 50.0);
        assert!(Plan::new(vec![Segment::Straight { length_m: f64::NAN }]).is_err());
    }
}
