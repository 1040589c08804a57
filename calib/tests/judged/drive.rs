//! Issue #23 on the simulator: speed scale, rear ratio, steering map and
//! yaw-rate sensor fitted from an ordinary road drive (`Plan::road_drive`,
//! 660 m at 8 m/s, about 85 s) with 1 Hz position fixes of 5 cm noise.
//!
//! The samples are built as the daemon builds them: rear distances from the
//! wrapping tick counters decoded with the *nominal* diameters, the steering
//! signal through the *nominal* map, the yaw rate as the sensor sends it.
//! Each estimate must lie within 3 of its reported σ of the truth, on every
//! seed. Run with `--nocapture` for the table.

use canodom_calib::drive::{
    DriveCalibration, DriveModel, DriveSample, Estimate, Fix, calibrate_drive,
};
use canodom_fusion::sim::{
    self, PathFollowing, Plan, Segment, SimConfig, SteeringSensor, YawRateSensor,
};
use canodom_fusion::{SteeringMap, VehicleParams, Wheel, WheelSet};

const DEG: f64 = std::f64::consts::PI / 180.0;
const WHEELBASE_M: f64 = 2.7;
const TREAD_M: f64 = 1.55;
const DIAMETER_M: f64 = 0.65;
/// The steering signal is a steering-wheel angle in degrees, ratio 15.
const STEER_RATIO: f64 = 15.0;
const FIX_SIGMA_M: f64 = 0.05;

/// The biases of one scenario, as the estimator names them.
#[derive(Debug, Clone, Copy)]
struct Truth {
    speed_scale: f64,
    rear_ratio: f64,
    steer_offset_rad: f64,
    steer_gain: f64,
    yaw_bias_radps: f64,
    yaw_scale: f64,
}

const BASE: Truth = Truth {
    speed_scale: 1.0,
    rear_ratio: 1.0,
    steer_offset_rad: 0.5 * DEG,
    steer_gain: 0.95,
    yaw_bias_radps: 0.4 * DEG,
    yaw_scale: 1.02,
};

/// A deterministic N(0, 1) stream (splitmix64 and Box–Muller), so the
/// fixes' noise needs no extra dependency.
struct Normal(u64);

impl Normal {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    fn next(&mut self) -> f64 {
        let (u1, u2) = (self.uniform(), self.uniform());
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

/// The true vehicle for `truth` and the nominal one the odometry uses.
fn vehicles(truth: &Truth) -> (VehicleParams, VehicleParams) {
    let true_gain = DEG / STEER_RATIO;
    let mean = DIAMETER_M * truth.speed_scale;
    let e = truth.rear_ratio;
    let diameters = WheelSet {
        rear_left: 2.0 * mean / (1.0 + e),
        rear_right: 2.0 * mean * e / (1.0 + e),
        front_left: DIAMETER_M,
        front_right: DIAMETER_M,
    };
    let map = SteeringMap {
        gain: true_gain,
        offset_rad: 0.0,
    };
    let real = VehicleParams::new(WHEELBASE_M, TREAD_M, TREAD_M, diameters, 100, map).unwrap();
    // φ_meas = (φ_true + bias)/gain_truth... through a nominal map whose gain
    // is 1/steer_gain of the true one: φ_true = steer_gain·φ_meas − bias.
    let nominal = VehicleParams::new(
        WHEELBASE_M,
        TREAD_M,
        TREAD_M,
        WheelSet::splat(DIAMETER_M),
        100,
        SteeringMap {
            gain: true_gain / truth.steer_gain,
            offset_rad: 0.0,
        },
    )
    .unwrap();
    (real, nominal)
}

fn config(truth: &Truth) -> (SimConfig, VehicleParams) {
    let (real, nominal) = vehicles(truth);
    let sensor = SteeringSensor {
        white_sigma_rad: 0.05 * DEG,
        bias_rad: -truth.steer_offset_rad,
        // 0.1° of steering wheel: 0.0067° at the road wheels.
        quantum: 0.1,
        ..SteeringSensor::EXACT
    };
    let mut cfg = SimConfig::road_car(real, sensor);
    cfg.yaw_rate_sensor = YawRateSensor {
        bias_radps: truth.yaw_bias_radps,
        scale: truth.yaw_scale,
        white_sigma_radps: 0.1 * DEG,
        quantum_radps: 0.05 * DEG,
    };
    (cfg, nominal)
}

/// The daemon's samples and 1 Hz noisy fixes of a simulated drive.
fn record(
    cfg: &SimConfig,
    nominal: &VehicleParams,
    plan: &Plan,
    seed: u64,
) -> (Vec<DriveSample>, Vec<Fix>) {
    let run = sim::simulate(cfg, plan, seed).unwrap();
    let mask = (1u64 << cfg.wheel_output.counter_bits) - 1;
    let half = 1u64 << (cfg.wheel_output.counter_bits - 1);
    let ticks = |now: u64, before: u64| {
        let d = now.wrapping_sub(before) & mask;
        if d >= half {
            -((mask - d + 1) as f64)
        } else {
            d as f64
        }
    };
    let map = nominal.steering();
    let mut samples = Vec::with_capacity(run.samples.len());
    let mut noise = Normal(seed ^ 0xF1C5);
    let mut fixes = Vec::new();
    for (k, s) in run.samples.iter().enumerate() {
        let prev = &run.samples[k.saturating_sub(1)];
        let d = |w: Wheel| nominal.tick_distance_m(w, ticks(s.ticks[w], prev.ticks[w]));
        samples.push(DriveSample {
            t_s: s.t_s,
            rear_left_m: d(Wheel::RearLeft),
            rear_right_m: d(Wheel::RearRight),
            front_m: Some((d(Wheel::FrontLeft), d(Wheel::FrontRight))),
            steer_angle_rad: Some(map.angle_rad(s.steer_signal)),
            yaw_rate_radps: Some(s.yaw_rate_radps),
            rear_slip: false,
        });
        if k % 100 == 0 {
            fixes.push(Fix {
                t_s: s.t_s,
                x_m: s.true_pose.x_m + FIX_SIGMA_M * noise.next(),
                y_m: s.true_pose.y_m + FIX_SIGMA_M * noise.next(),
                heading_rad: None,
                sigma_m: None,
            });
        }
    }
    (samples, fixes)
}

fn model() -> DriveModel {
    DriveModel {
        rear_tread_m: TREAD_M,
        wheelbase_m: WHEELBASE_M,
    }
}

fn estimates(cal: &DriveCalibration) -> [(&'static str, Estimate, f64); 6] {
    [
        ("speed scale", cal.speed_scale, 1.0),
        ("rear ratio", cal.rear_ratio, 1.0),
        ("steer offset °", cal.steer_offset_rad.unwrap(), 1.0 / DEG),
        ("steer gain", cal.steer_gain.unwrap(), 1.0),
        ("yaw bias °/s", cal.yaw_bias_radps.unwrap(), 1.0 / DEG),
        ("yaw scale", cal.yaw_scale.unwrap(), 1.0),
    ]
}

fn truths(t: &Truth) -> [f64; 6] {
    [
        t.speed_scale,
        t.rear_ratio,
        t.steer_offset_rad,
        t.steer_gain,
        t.yaw_bias_radps,
        t.yaw_scale,
    ]
}

/// Prints one scenario's table and returns |error|/σ and σ per parameter.
fn show(label: &str, cal: &DriveCalibration, truth: &Truth) -> [(f64, f64); 6] {
    println!(
        "{label}: {} fixes over {:.0} m, residual RMS rear {:.3} m, yaw {:.3} m, steering {:.3} m",
        cal.fixes_used,
        cal.distance_m,
        cal.residual_rms_m[0].unwrap(),
        cal.residual_rms_m[1].unwrap(),
        cal.residual_rms_m[2].unwrap()
    );
    let mut out = [(0.0, 0.0); 6];
    for (i, ((name, e, unit), t)) in estimates(cal).iter().zip(truths(truth)).enumerate() {
        let z = (e.value - t) / e.sigma;
        println!(
            "  {name:<15} truth {:>10.6}  estimate {:>10.6}  σ {:>9.6}  error/σ {:+5.2}  observable {}",
            t * unit,
            e.value * unit,
            e.sigma * unit,
            z,
            e.observable
        );
        out[i] = (z, e.sigma);
    }
    out
}

#[test]
fn road_drive_recovers_every_bias_within_three_sigma() {
    // Rear ratio 1.0005-1.002 and speed scale 0.98-1.02 through the two rear
    // diameters, over eight seeds of the road drive. (Over 30 seeds the RMS
    // of error/σ came out 0.97-1.19 per parameter, the worst 2.83 σ.)
    let cases = [
        (1.0005, 0.98),
        (1.001, 1.0),
        (1.002, 1.02),
        (1.0005, 1.02),
        (1.001, 0.98),
        (1.002, 1.0),
    ];
    let mut worst = [(0.0_f64, 0.0_f64); 6];
    println!(
        "\nissue #23: road drives, 1 Hz fixes of {:.0} cm",
        100.0 * FIX_SIGMA_M
    );
    let n_seeds = 8;
    let mut mean_sq = [0.0_f64; 6];
    for (seed, (rear_ratio, speed_scale)) in cases.into_iter().cycle().take(n_seeds).enumerate() {
        let truth = Truth {
            speed_scale,
            rear_ratio,
            ..BASE
        };
        let (cfg, nominal) = config(&truth);
        let plan = Plan::road_drive(seed as u64).unwrap();
        let (samples, fixes) = record(&cfg, &nominal, &plan, 40 + seed as u64);
        let cal = calibrate_drive(&samples, &fixes, &model()).unwrap();
        let zs = show(&format!("seed {seed}"), &cal, &truth);
        for (m, (z, _)) in mean_sq.iter_mut().zip(zs) {
            *m += z * z / n_seeds as f64;
        }
        for (w, (z, s)) in worst.iter_mut().zip(zs) {
            *w = (w.0.max(z.abs()), w.1.max(s));
        }
        for (name, e, _) in estimates(&cal) {
            assert!(e.observable, "seed {seed}: {name} not observable: {e:?}");
        }
    }
    println!("worst |error|/σ, RMS error/σ and largest σ over the seeds:");
    let names = estimates_names();
    let rms = mean_sq.map(f64::sqrt);
    for ((name, (z, s)), q) in names.iter().zip(worst).zip(rms) {
        println!("  {name:<15} {z:5.2}  {q:5.2}  σ {s:.3e}");
    }
    // Within 3σ of the truth, and σ not too small on the whole...
    for ((name, (z, _)), q) in names.iter().zip(worst).zip(rms) {
        assert!(z < 3.0, "{name}: error {z:.2} σ");
        // The steering's σ is the least exact (RMS 1.5 on these seeds,
        // 1.05-1.14 over 30): 2 still catches a σ half its true size.
        assert!(q < 2.0, "{name}: RMS error {q:.2} σ");
    }
    // ...and σ small enough to be worth applying: a tenth of the smallest
    // ratio bias, 0.1 % in speed, 0.05° of offset, 1 % of gain, 0.02°/s of
    // yaw bias, 0.5 % of yaw scale.
    let limits = [1e-3, 5e-5, 0.05 * DEG, 0.01, 0.02 * DEG, 0.005];
    for ((name, (_, s)), limit) in names.iter().zip(worst).zip(limits) {
        assert!(s < limit, "{name}: σ {s:e} over {limit:e}");
    }
}

fn estimates_names() -> [&'static str; 6] {
    [
        "speed scale",
        "rear ratio",
        "steer offset",
        "steer gain",
        "yaw bias",
        "yaw scale",
    ]
}

#[test]
fn straight_road_cannot_tell_steering_gain_or_yaw_scale() {
    let truth = Truth {
        rear_ratio: 1.001,
        speed_scale: 1.01,
        ..BASE
    };
    let (mut cfg, nominal) = config(&truth);
    // A straight road held straight: no steering noise, so the car neither
    // turns nor wanders (with §9's driver noise it wanders by degrees, and
    // that alone shows a gain error).
    cfg.path_following = PathFollowing::NONE;
    let plan = Plan::new(vec![Segment::Straight { length_m: 600.0 }]).unwrap();
    let (samples, fixes) = record(&cfg, &nominal, &plan, 7);
    let cal = calibrate_drive(&samples, &fixes, &model()).unwrap();
    println!("\nissue #23: a straight road (offset's truth with the gain held at 1)");
    // φ_true = 0 here, so with the gain held at 1 the offset that closes the
    // reckoning is −φ_meas = offset/gain.
    let held = Truth {
        steer_offset_rad: truth.steer_offset_rad / truth.steer_gain,
        ..truth
    };
    show("straight", &cal, &held);
    let offset = cal.steer_offset_rad.unwrap();
    assert!((offset.value - held.steer_offset_rad).abs() < 3.0 * offset.sigma);
    let gain = cal.steer_gain.unwrap();
    let scale = cal.yaw_scale.unwrap();
    assert!(!gain.observable && gain.value == 1.0, "{gain:?}");
    assert!(!scale.observable && scale.value == 1.0, "{scale:?}");
    // What a straight road does tell: speed scale and yaw bias.
    assert!((cal.speed_scale.value - truth.speed_scale).abs() < 3.0 * cal.speed_scale.sigma);
    let bias = cal.yaw_bias_radps.unwrap();
    assert!(bias.observable);
    assert!((bias.value - truth.yaw_bias_radps).abs() < 3.0 * bias.sigma);
}
