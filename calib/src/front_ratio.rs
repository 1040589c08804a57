//! The front wheels' right/left ratio from ordinary driving, for the drift
//! watch (issue #46 item 3): a front tyre losing pressure.
//!
//! The drive fit reads the rear wheels, so a front tyre's change leaves it
//! untouched (the multi-body Escort of seed 126, its front-left tyre 0.5 %
//! smaller from 600 s: no flag over 12.6 km). The front pair tells its own
//! ratio without fixes: on a straight both front wheels roll as far as the
//! rear axle's centre, and in a gentle bend each rolls a known amount more
//! or less. So over the stretches of a window where the rear wheels (with
//! the rear ratio the refit learnt) say the car goes nearly straight, the
//! front wheels' distances are compared with what that motion makes them
//! roll; their right/left quotient is the front tyres' ratio against the
//! diameters in use.
//!
//! Pure: samples in, an estimate with its σ out.

use crate::drive::DriveSample;

/// The car's geometry the front wheels' motion is predicted with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrontGeometry {
    /// The rear tread the rear wheels' turn is read with, m.
    pub rear_tread_m: f64,
    /// The front tread, m.
    pub front_tread_m: f64,
    /// Rear axle to front axle, m.
    pub wheelbase_m: f64,
}

/// The front tyres' right/left ratio a window tells.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrontRatio {
    /// The front-right wheel's effective diameter over the front-left's,
    /// relative to the diameters in use (1: they agree).
    pub value: f64,
    /// Its σ: the spread of [`BLOCKS`] consecutive parts of the stretches
    /// used.
    pub sigma: f64,
    /// The rear axle's distance over the stretches used, m.
    pub distance_m: f64,
}

/// The bounds below are in wheelbases, so that a 1:10 robot car is read as
/// a road car is: a road car's figures are given for a 2.7 m wheelbase.
///
/// The largest curvature of a stretch the ratio is read on, times the
/// wheelbase (a radius of 500 m on a road car). A bend's front wheels roll
/// `κ·t_f` apart (0.3 % on a 1.5 m tread at this bound): predicted from the
/// rear wheels, but a rear ratio the refit knows only to its σ makes that
/// prediction off by as much; on near-straights the error is a small share
/// of a small term.
pub const STRAIGHT_MAX_CURVATURE_PER_WHEELBASE: f64 = 0.0054;

/// The least speed of a stretch, wheelbases a second (3 m/s on a road car):
/// below it a wheel-speed sensor's floor (about 2 km/h) and its 0.01 km/h
/// steps are a large share of a reading.
pub const MIN_SPEED_WHEELBASES_PER_S: f64 = 1.1;

/// The longest gap between two samples a stretch may span, s (the drive
/// record's bins are 0.05 s; a longer gap is lost frames).
pub const MAX_SAMPLE_GAP_S: f64 = 0.25;

/// A front wheel rolling more than this share off its prediction in a
/// sample is slipping (a driven wheel spinning, a wheel locking): left out.
pub const MAX_WHEEL_OFF: f64 = 0.05;

/// A sample whose right/left quotient lies more than this share off the
/// window's median is left out (one wheel slipping more than the other).
pub const MAX_QUOTIENT_OFF: f64 = 0.01;

/// The least distance on near-straights a window must hold, wheelbases
/// (200 m on a road car): on the multi-body drives a 3-minute window held
/// 470–720 m.
pub const MIN_DISTANCE_WHEELBASES: f64 = 75.0;

/// How many consecutive parts the used stretches are split into for σ.
pub const BLOCKS: usize = 8;

/// One sample's front distances and their prediction.
// Units in names, as everywhere in this project.
#[allow(clippy::struct_field_names)]
#[derive(Debug, Clone, Copy)]
struct Used {
    front_left_m: f64,
    front_right_m: f64,
    predicted_left_m: f64,
    predicted_right_m: f64,
    centre_m: f64,
}

impl Used {
    fn quotient(&self) -> f64 {
        (self.front_right_m / self.predicted_right_m) / (self.front_left_m / self.predicted_left_m)
    }
}

/// The front tyres' ratio over `samples` (consecutive, recorded with the
/// diameters in use), the rear wheels read with `rear_ratio` (the rear
/// ratio correction a refit learnt, `k_R/k_L`; 1 when it told none).
/// `None` when the samples hold too little near-straight driving
/// ([`MIN_DISTANCE_WHEELBASES`]) or carry no front wheels.
pub fn front_ratio(
    samples: &[DriveSample],
    geometry: &FrontGeometry,
    rear_ratio: f64,
) -> Option<FrontRatio> {
    let g = geometry;
    if !(rear_ratio.is_finite()
        && rear_ratio > 0.0
        && g.rear_tread_m > 0.0
        && g.front_tread_m > 0.0
        && g.wheelbase_m > 0.0)
    {
        return None;
    }
    let (k_left, k_right) = (
        2.0 / (1.0 + rear_ratio),
        2.0 * rear_ratio / (1.0 + rear_ratio),
    );
    let mut used: Vec<Used> = samples
        .windows(2)
        .filter_map(|pair| {
            let (prev, s) = (&pair[0], &pair[1]);
            let dt = s.t_s - prev.t_s;
            let (fl, fr) = s.front_m?;
            if s.rear_slip || !(dt > 0.0 && dt <= MAX_SAMPLE_GAP_S) {
                return None;
            }
            let (left, right) = (k_left * s.rear_left_m, k_right * s.rear_right_m);
            let centre = 0.5 * (left + right);
            let turn = (right - left) / g.rear_tread_m;
            let forward = left > 0.0 && right > 0.0 && fl > 0.0 && fr > 0.0;
            if !(forward
                && centre >= MIN_SPEED_WHEELBASES_PER_S * g.wheelbase_m * dt
                && turn.abs() * g.wheelbase_m <= STRAIGHT_MAX_CURVATURE_PER_WHEELBASE * centre)
            {
                return None;
            }
            let half = 0.5 * g.front_tread_m * turn;
            let lateral = g.wheelbase_m * turn;
            let u = Used {
                front_left_m: fl,
                front_right_m: fr,
                predicted_left_m: (centre - half).hypot(lateral),
                predicted_right_m: (centre + half).hypot(lateral),
                centre_m: centre,
            };
            let off = |m: f64, p: f64| (m / p - 1.0).abs() > MAX_WHEEL_OFF;
            (!off(u.front_left_m, u.predicted_left_m) && !off(u.front_right_m, u.predicted_right_m))
                .then_some(u)
        })
        .collect();
    let mut quotients: Vec<f64> = used.iter().map(Used::quotient).collect();
    quotients.sort_by(f64::total_cmp);
    let median = *quotients.get(quotients.len() / 2)?;
    used.retain(|u| (u.quotient() / median - 1.0).abs() <= MAX_QUOTIENT_OFF);
    let distance_m: f64 = used.iter().map(|u| u.centre_m).sum();
    if distance_m < MIN_DISTANCE_WHEELBASES * g.wheelbase_m || used.len() < 2 * BLOCKS {
        return None;
    }
    let ratio = |part: &[Used]| {
        let sum = |f: fn(&Used) -> f64| part.iter().map(f).sum::<f64>();
        (sum(|u| u.front_right_m) / sum(|u| u.predicted_right_m))
            / (sum(|u| u.front_left_m) / sum(|u| u.predicted_left_m))
    };
    let value = ratio(&used);
    let size = used.len().div_ceil(BLOCKS);
    let parts: Vec<f64> = used.chunks(size).map(ratio).collect();
    let n = parts.len() as f64;
    let mean = parts.iter().sum::<f64>() / n;
    let var = parts.iter().map(|p| (p - mean).powi(2)).sum::<f64>() / (n - 1.0);
    let sigma = (var / n).sqrt();
    (value.is_finite() && sigma.is_finite()).then_some(FrontRatio {
        value,
        sigma,
        distance_m,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const GEOMETRY: FrontGeometry = FrontGeometry {
        rear_tread_m: 1.5,
        front_tread_m: 1.55,
        wheelbase_m: 2.7,
    };

    /// A kinematic car at `speed` along `curvature(t)`, sampled every
    /// 0.05 s for `seconds`, each wheel read with its scale (`scales`: RL,
    /// RR, FL, FR; > 1 reads long, as a smaller tyre does).
    fn drive(
        seconds: f64,
        speed: f64,
        curvature: impl Fn(f64) -> f64,
        scales: impl Fn(f64) -> [f64; 4],
    ) -> Vec<DriveSample> {
        let g = GEOMETRY;
        let dt = 0.05;
        (0..(seconds / dt) as usize)
            .map(|i| {
                let t = i as f64 * dt;
                let (d, k) = (speed * dt, curvature(t));
                let turn = k * d;
                let [rl, rr, fl, fr] = scales(t);
                let front = |side: f64| {
                    (d + side * 0.5 * g.front_tread_m * turn).hypot(g.wheelbase_m * turn)
                };
                DriveSample {
                    t_s: t,
                    rear_left_m: rl * (d - 0.5 * g.rear_tread_m * turn),
                    rear_right_m: rr * (d + 0.5 * g.rear_tread_m * turn),
                    front_m: Some((fl * front(-1.0), fr * front(1.0))),
                    steer_angle_rad: None,
                    yaw_rate_radps: None,
                    rear_slip: false,
                }
            })
            .collect()
    }

    /// Straights, gentle bends both ways and tight turns, as a road gives.
    fn road(t: f64) -> f64 {
        match (t / 10.0) as u32 % 4 {
            0 => 0.0,
            1 => 0.0015 * (t * 0.7).sin(),
            2 => 0.02,
            _ => -0.0012,
        }
    }

    #[test]
    fn a_front_tyre_off_is_read_on_a_road_of_straights_bends_and_turns() {
        for fr in [1.0, 1.003, 0.995] {
            let s = drive(180.0, 12.0, road, |_| [1.0, 1.0, 1.0, fr]);
            let r = front_ratio(&s, &GEOMETRY, 1.0).unwrap();
            assert!((r.value - fr).abs() < 2e-5, "{fr}: {r:?}");
            assert!(r.distance_m > 1000.0 && r.distance_m < 1800.0, "{r:?}");
        }
    }

    #[test]
    fn a_robot_car_a_tenth_the_size_is_read_as_a_road_car_is() {
        // The road drive scaled to a tenth: 0.27 m wheelbase, 1.2 m/s.
        let small = FrontGeometry {
            rear_tread_m: 0.15,
            front_tread_m: 0.155,
            wheelbase_m: 0.27,
        };
        let mut s = drive(180.0, 12.0, road, |_| [1.0, 1.0, 1.0, 1.004]);
        for x in &mut s {
            x.rear_left_m *= 0.1;
            x.rear_right_m *= 0.1;
            x.front_m = x.front_m.map(|(l, r)| (0.1 * l, 0.1 * r));
        }
        let r = front_ratio(&s, &small, 1.0).unwrap();
        assert!((r.value - 1.004).abs() < 2e-5, "{r:?}");
        assert!(r.distance_m > 100.0 && r.distance_m < 180.0, "{r:?}");
        // Read as a road car, it is too slow and too short.
        assert_eq!(front_ratio(&s, &GEOMETRY, 1.0), None);
    }

    #[test]
    fn a_rear_ratio_off_is_taken_from_the_refit_not_from_the_front_tyres() {
        // The right rear reads 0.5 % long (the refit's correction, which
        // multiplies the diameters in use, is 1/1.005): unread, the rear
        // wheels take a straight for a bend of 1/300 m and the front pair's
        // prediction for one that pulls them 0.5 % apart.
        let s = drive(180.0, 12.0, road, |_| [1.0, 1.005, 1.0, 1.0]);
        let with = front_ratio(&s, &GEOMETRY, 1.0 / 1.005).unwrap();
        assert!((with.value - 1.0).abs() < 2e-5, "{with:?}");
        let without = front_ratio(&s, &GEOMETRY, 1.0);
        assert!(
            without.is_none_or(|r| (r.value - 1.0).abs() > 1e-3),
            "{without:?}"
        );
    }

    #[test]
    fn a_change_in_the_window_reads_between_and_spreads_its_parts() {
        let s = drive(180.0, 12.0, road, |t| {
            [1.0, 1.0, if t < 90.0 { 1.0 } else { 1.005 }, 1.0]
        });
        let r = front_ratio(&s, &GEOMETRY, 1.0).unwrap();
        assert!(r.value < 0.999 && r.value > 0.996, "{r:?}");
        assert!(r.sigma > 5e-4, "{r:?}");
    }

    #[test]
    fn slips_slow_driving_and_missing_front_wheels_are_left_out() {
        // A front-left wheel spinning 20 % for a second in every ten.
        let spin = drive(180.0, 12.0, road, |t| {
            [1.0, 1.0, if t % 10.0 < 1.0 { 1.2 } else { 1.0 }, 1.002]
        });
        let r = front_ratio(&spin, &GEOMETRY, 1.0).unwrap();
        assert!((r.value - 1.002).abs() < 2e-5, "{r:?}");
        // Rear slips the pipeline marked are not read.
        let mut marked = drive(180.0, 12.0, road, |_| [1.0, 1.0, 1.0, 1.002]);
        for s in marked.iter_mut().step_by(3) {
            s.rear_left_m *= 0.5;
            s.rear_slip = true;
        }
        let r = front_ratio(&marked, &GEOMETRY, 1.0).unwrap();
        assert!((r.value - 1.002).abs() < 2e-5, "{r:?}");
        // Too slow, too short, or no front wheels: nothing told.
        assert_eq!(
            front_ratio(&drive(180.0, 2.5, road, |_| [1.0; 4]), &GEOMETRY, 1.0),
            None
        );
        assert_eq!(
            front_ratio(&drive(15.0, 12.0, |_| 0.0, |_| [1.0; 4]), &GEOMETRY, 1.0),
            None
        );
        let mut blind = drive(180.0, 12.0, road, |_| [1.0; 4]);
        for s in &mut blind {
            s.front_m = None;
        }
        assert_eq!(front_ratio(&blind, &GEOMETRY, 1.0), None);
        assert_eq!(front_ratio(&[], &GEOMETRY, 1.0), None);
    }

    #[test]
    fn nonsense_geometry_or_ratio_tells_nothing() {
        let s = drive(180.0, 12.0, road, |_| [1.0; 4]);
        for (g, r) in [
            (GEOMETRY, f64::NAN),
            (GEOMETRY, 0.0),
            (
                FrontGeometry {
                    front_tread_m: 0.0,
                    ..GEOMETRY
                },
                1.0,
            ),
        ] {
            assert_eq!(front_ratio(&s, &g, r), None);
        }
    }

    #[test]
    fn reversing_is_not_read() {
        let mut back = drive(180.0, 12.0, road, |_| [1.0; 4]);
        for s in &mut back {
            s.rear_left_m = -s.rear_left_m;
            s.rear_right_m = -s.rear_right_m;
            s.front_m = s.front_m.map(|(l, r)| (-l, -r));
        }
        assert_eq!(front_ratio(&back, &GEOMETRY, 1.0), None);
    }
}
