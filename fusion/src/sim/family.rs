//! Families of random drives: the vehicles, sensors and roads the fusion
//! filter is judged on, each drive a pure function of its seed.
//!
//! A [`Drive`] holds what a test needs: the simulator's configuration (the
//! *true* vehicle, its tyres, its sensors' errors), the plan, and the
//! *nominal* parameters a user would configure (the steering ratio off by a
//! few per cent, as a datasheet is). The families widen the world that §11
//! and §12 of `docs/calibration-math.md` sampled:
//!
//! - [`full_size_car`]: a passenger car of random size at 6–10 m/s: a 30 m
//!   straight, a full circle of 10–20 m radius to the left, 30 m, a full
//!   circle to the right, then eight segments of constant curvature
//!   (|κ| ≤ 0.06 1/m, 20–80 m each). Tyre slip angles (understeer and rear
//!   sideslip growing with lateral acceleration), steering that jumps or
//!   turns at a finite rate, wheel speeds quantised as production cars send
//!   them (0.0075–0.03125 km/h), steering-wheel angles in 0.1° or 1.5°
//!   steps, a steering bias and a steering-ratio error. About 600–800 m.
//! - [`urban_car`]: the same cars in town: stops, short reversing
//!   manoeuvres and crawling below 2 km/h, where the wheel-speed sensors
//!   report 0, between pieces of 10–40 m. About 300 m.
//! - [`rc_car`]: the 1:10 car of §9 with tick encoders on random drives of
//!   20–30 m, §11's steering sensor, and the given wheel slips.

use super::plan::{Plan, Segment};
use super::{
    OuNoise, PathFollowing, SimConfig, SlipConfig, SteeringSensor, TyreModel, WheelOutput,
};
use crate::WheelSet;
use crate::error::Result;
use crate::params::{SteeringMap, VehicleParams};
use crate::wheel::SpeedUnit;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::PI;

const DEG: f64 = PI / 180.0;

/// The most lateral acceleration a family's driver asks of a full-size car:
/// curves are driven no faster than this allows.
const MAX_LATERAL_MPS2: f64 = 6.5;

/// One random drive of a family.
#[derive(Debug, Clone, PartialEq)]
pub struct Drive {
    /// The simulator's configuration: the true vehicle and its sensors.
    pub sim: SimConfig,
    /// The path the driver follows.
    pub plan: Plan,
    /// The parameters a user would configure (what the odometry uses).
    pub nominal: VehicleParams,
    /// The seed of the drive (also the simulator's).
    pub seed: u64,
}

/// A full-size passenger car's drive (see the module's documentation).
///
/// # Errors
/// Never for the built-in ranges; kept fallible like the plans.
pub fn full_size_car(seed: u64) -> Result<Drive> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x00F5_11C0);
    let (truth, nominal) = passenger_car(&mut rng)?;
    let speed_mps: f64 = rng.random_range(6.0..10.0);
    let curve_speed = |kappa: f64| speed_mps.min((MAX_LATERAL_MPS2 / kappa.abs()).sqrt());
    let mut segments = vec![Segment::Straight { length_m: 30.0 }];
    for sign in [1.0, -1.0] {
        let radius_m: f64 = rng.random_range(10.0..20.0);
        segments.extend([
            Segment::Speed {
                speed_mps: curve_speed(1.0 / radius_m),
            },
            Segment::Arc {
                radius_m,
                angle_rad: sign * 2.0 * PI,
            },
            Segment::Speed { speed_mps },
            Segment::Straight { length_m: 30.0 },
        ]);
    }
    for _ in 0..8 {
        let kappa: f64 = rng.random_range(-0.06..0.06);
        let length_m = rng.random_range(20.0..80.0);
        segments.push(Segment::Speed {
            speed_mps: curve_speed(kappa),
        });
        segments.push(constant_curvature(kappa, length_m));
    }
    let sim = SimConfig {
        speed_mps,
        ..road_sim(&mut rng, truth)
    };
    Ok(Drive {
        sim,
        plan: Plan::new(segments)?,
        nominal,
        seed,
    })
}

/// A full-size car in town: stop-and-go, reversing, crawling (see the
/// module's documentation).
///
/// # Errors
/// Never for the built-in ranges; kept fallible like the plans.
pub fn urban_car(seed: u64) -> Result<Drive> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0B0A_4000);
    let (truth, nominal) = passenger_car(&mut rng)?;
    let speed_mps: f64 = rng.random_range(4.0..8.0);
    let mut sim = SimConfig {
        speed_mps,
        ..road_sim(&mut rng, truth)
    };
    // Below about 2 km/h many production sensors report nothing.
    sim.wheel_output.zero_below_mps = 0.55;
    let mut segments = Vec::new();
    let mut total_m = 0.0;
    while total_m < 300.0 {
        let kappa = if rng.random_bool(0.5) {
            rng.random_range(-0.1..0.1)
        } else {
            0.0
        };
        let length_m = rng.random_range(10.0..40.0);
        segments.push(Segment::Speed {
            speed_mps: speed_mps.min((MAX_LATERAL_MPS2 / f64::abs(kappa)).sqrt()),
        });
        segments.push(constant_curvature(kappa, length_m));
        total_m += length_m;
        match rng.random_range(0..4) {
            0 => segments.push(Segment::Stop {
                duration_s: rng.random_range(1.0..4.0),
                reverse: false,
            }),
            1 => {
                let back_m = rng.random_range(5.0..12.0);
                segments.extend([
                    Segment::Stop {
                        duration_s: rng.random_range(0.5..2.0),
                        reverse: true,
                    },
                    Segment::Speed { speed_mps: 1.5 },
                    constant_curvature(rng.random_range(-0.15..0.15), back_m),
                    Segment::Stop {
                        duration_s: rng.random_range(0.5..2.0),
                        reverse: true,
                    },
                ]);
                total_m += back_m;
            }
            2 => {
                let crawl_m = rng.random_range(1.0..3.0);
                segments.extend([
                    Segment::Speed { speed_mps: 0.4 },
                    Segment::Straight { length_m: crawl_m },
                ]);
                total_m += crawl_m;
            }
            _ => {}
        }
    }
    Ok(Drive {
        sim,
        plan: Plan::new(segments)?,
        nominal,
        seed,
    })
}

/// The 1:10 car of §9 on a random drive of 20–30 m at 0.1–0.3 m/s, with
/// §11's steering sensor (0.3° white, a 0.3° bias per run) and `slip`.
///
/// # Errors
/// Never for the built-in ranges; kept fallible like the plans.
pub fn rc_car(seed: u64, slip: SlipConfig) -> Result<Drive> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0001_0C0A);
    let truth = VehicleParams::nominal(0.25, 0.30, 0.09, 1000)?;
    let length_m = rng.random_range(20.0..30.0);
    let plan = Plan::random_drive(seed, length_m, 0.8)?;
    let mut sim = SimConfig::rc_car(truth);
    sim.speed_mps = rng.random_range(0.1..0.3);
    sim.slip = slip;
    sim.steering_sensor = SteeringSensor {
        white_sigma_rad: 0.3 * DEG,
        bias_sigma_rad: 0.3 * DEG,
        ..SteeringSensor::EXACT
    };
    Ok(Drive {
        sim,
        plan,
        nominal: truth,
        seed,
    })
}

/// A straight for `kappa == 0`, else an arc of that curvature and length.
fn constant_curvature(kappa: f64, length_m: f64) -> Segment {
    if kappa.abs() < 1e-4 {
        Segment::Straight { length_m }
    } else {
        Segment::Arc {
            radius_m: 1.0 / kappa.abs(),
            angle_rad: length_m * kappa,
        }
    }
}

/// [`full_size_car`] widened to what issue #30's full-size family names: the
/// yaw lagging the steering's steady state by 0.1–0.4 s (tyre dynamics),
/// a steering offset up to 0.4° at the road wheels and a configured steering
/// ratio up to 5 % off. Drawn from its own stream, so the drive's plan,
/// size and other errors are [`full_size_car`]'s for the same seed.
///
/// # Errors
/// Never for the built-in ranges; kept fallible like the plans.
pub fn wide_full_size_car(seed: u64) -> Result<Drive> {
    let mut drive = full_size_car(seed)?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0057_1DE0);
    drive.sim.tyres.yaw_lag_s = rng.random_range(0.1..0.4);
    drive.sim.steering_sensor.bias_rad = rng.random_range(-0.4..0.4) * DEG;
    let truth = drive.sim.true_params.steering();
    drive.nominal = drive.nominal.with_steering(SteeringMap {
        gain: truth.gain * (1.0 + rng.random_range(-0.05..0.05)),
        offset_rad: 0.0,
    })?;
    Ok(drive)
}

/// A random passenger car (true parameters) and what its user configures:
/// the same geometry, the datasheet's steering ratio a few per cent off.
fn passenger_car(rng: &mut ChaCha8Rng) -> Result<(VehicleParams, VehicleParams)> {
    let wheelbase_m = rng.random_range(2.5..3.1);
    let tread_m = rng.random_range(1.45..1.70);
    let front_tread_m = tread_m + rng.random_range(-0.05..0.05);
    let wheel_m = rng.random_range(0.60..0.75);
    let ratio = rng.random_range(13.0..18.0);
    let truth = VehicleParams::new(
        wheelbase_m,
        tread_m,
        front_tread_m,
        WheelSet::splat(wheel_m),
        100,
        SteeringMap {
            gain: DEG / ratio,
            offset_rad: 0.0,
        },
    )?;
    let believed_ratio = ratio * (1.0 + rng.random_range(-0.03..0.03));
    let nominal = truth.with_steering(SteeringMap {
        gain: DEG / believed_ratio,
        offset_rad: 0.0,
    })?;
    Ok((truth, nominal))
}

/// The full-size car's tyres, driver and sensors, drawn at random.
fn road_sim(rng: &mut ChaCha8Rng, truth: VehicleParams) -> SimConfig {
    let quantum = if rng.random_bool(0.5) { 1.5 } else { 0.1 };
    let bias_rad = (0.25 * DEG * normal(rng)).clamp(-0.6 * DEG, 0.6 * DEG);
    let sensor = SteeringSensor {
        white_sigma_rad: 0.05 * DEG,
        bias_rad,
        bias_sigma_rad: 0.0,
        drift_rad: OuNoise {
            sigma: 0.05 * DEG,
            tau_s: 30.0,
        },
        quantum,
    };
    let mut sim = SimConfig::road_car(truth, sensor);
    sim.tyres = TyreModel {
        understeer_rad_per_mps2: rng.random_range(0.001..0.004),
        rear_sideslip_rad_per_mps2: rng.random_range(0.002..0.006),
        yaw_lag_s: 0.0,
    };
    sim.path_following = PathFollowing {
        servo_lag_s: rng.random_range(0.05..0.15),
        // Half the drives jump to each new curvature; the others turn the
        // road wheels at 0.2–0.6 rad/s (a steering wheel at 170–500°/s).
        steer_rate_limit_rad_per_s: if rng.random_bool(0.5) {
            f64::INFINITY
        } else {
            rng.random_range(0.2..0.6)
        },
        ..sim.path_following
    };
    let speed_quantum = [0.01, 0.03125, 0.0075][rng.random_range(0..3)];
    sim.wheel_output = WheelOutput {
        speed_unit: SpeedUnit::KilometresPerHour,
        speed_quantum,
        ..WheelOutput::ROAD_CAR
    };
    sim
}

/// A standard normal draw (Box–Muller: one draw, no extra dependency).
fn normal(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random_range(f64::EPSILON..1.0);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::simulate;

    #[test]
    fn drives_are_deterministic_and_differ_by_seed() {
        for family in [full_size_car, urban_car] {
            let a = family(3).unwrap();
            assert_eq!(a, family(3).unwrap());
            assert_ne!(a, family(4).unwrap());
        }
        let slip = SlipConfig::NONE;
        assert_eq!(rc_car(5, slip).unwrap(), rc_car(5, slip).unwrap());
    }

    #[test]
    fn full_size_drive_has_the_issue_shape_and_tyre_slip() {
        let d = full_size_car(1).unwrap();
        let loops = d
            .plan
            .segments
            .iter()
            .filter(|s| matches!(s, Segment::Arc { angle_rad, .. } if (angle_rad.abs() - 2.0 * PI).abs() < 1e-12))
            .count();
        assert_eq!(loops, 2);
        let length = d.plan.length_m();
        assert!((220.0..900.0).contains(&length), "{length}");
        let run = simulate(&d.sim, &d.plan, d.seed).unwrap();
        let end = run.samples.last().unwrap();
        assert!((end.true_distance_m - length).abs() < 1e-6);
    }

    #[test]
    fn understeer_needs_more_steering_and_the_rear_axle_slides_out() {
        let truth = VehicleParams::nominal(2.7, 1.55, 0.65, 100).unwrap();
        let mut cfg = SimConfig::road_car(truth, SteeringSensor::EXACT);
        cfg.path_following = PathFollowing::NONE;
        cfg.tyres = TyreModel {
            understeer_rad_per_mps2: 0.004,
            rear_sideslip_rad_per_mps2: 0.006,
            yaw_lag_s: 0.0,
        };
        let (radius_m, v) = (15.0, 8.0);
        let plan = Plan::new(vec![
            Segment::Straight { length_m: 40.0 },
            Segment::Arc {
                radius_m,
                angle_rad: PI,
            },
        ])
        .unwrap();
        cfg.speed_mps = v;
        let run = simulate(&cfg, &plan, 1).unwrap();
        let mid = run
            .samples
            .iter()
            .find(|s| s.true_distance_m > 40.0 + 0.5 * PI * radius_m)
            .unwrap();
        // The driver steers tan φ = (L + K v²)/R: 9.5 % more than kinematic.
        let want = (2.7 + 0.004 * v * v) / radius_m;
        assert!((mid.true_steer_angle_rad.tan() / want - 1.0).abs() < 1e-6);
        // The car still drives the circle: heading turned by s/R.
        let turned = mid.true_pose.heading_rad;
        assert!((turned - (mid.true_distance_m - 40.0) / radius_m).abs() < 1e-3);
        // The rear axle's velocity points outwards by k·a_y (2.2° here), so the
        // path sits that much inside... the rear wheels still read ω·b apart.
        let beta = 0.006 * v * v / radius_m;
        let rl = mid.true_wheel_distance_m.rear_left;
        let rr = mid.true_wheel_distance_m.rear_right;
        let expect_diff = (mid.true_distance_m - 40.0) * 1.55 / radius_m;
        assert!(
            ((rr - rl) - expect_diff).abs() < 1e-3,
            "{} {}",
            rr - rl,
            expect_diff
        );
        // Each rear wheel reads cos β of the path (less than the kinematic car).
        let mean = 0.5 * (rl + rr) - 40.0;
        let along = mid.true_distance_m - 40.0;
        assert!(
            (mean / along - beta.cos()).abs() < 1e-4,
            "{} {}",
            mean / along,
            beta.cos()
        );
    }

    #[test]
    fn urban_drive_stops_reverses_and_crawls_below_the_sensor() {
        let mut reversed = false;
        let mut zero_while_moving = false;
        for seed in 0..5 {
            let d = urban_car(seed).unwrap();
            let run = simulate(&d.sim, &d.plan, d.seed).unwrap();
            let mut prev = run.samples[0];
            for s in &run.samples[1..] {
                let moved =
                    s.true_wheel_distance_m.rear_left - prev.true_wheel_distance_m.rear_left;
                reversed |= moved < -1e-6;
                zero_while_moving |= moved.abs() > 1e-4 && s.wheel_speed.rear_left == 0.0;
                prev = *s;
            }
        }
        assert!(reversed, "no drive reversed");
        assert!(
            zero_while_moving,
            "no drive crawled below the sensor's floor"
        );
    }
}
