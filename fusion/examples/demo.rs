//! The canodom demo: a simulated car drives, and the fused odometry is
//! compared with rear-only odometry against the simulator's ground truth.
//!
//! ```text
//! cargo run --release -p canodom-fusion --example demo [seed]
//! ```
//!
//! Three drives, each from rest to rest:
//! 1. a 1:10 car (§9 of `docs/calibration-math.md`) drives two CCW laps of the
//!    0.78 m calibration track while its wheels slip now and then (all four
//!    wheels, 0.05 events/s each, ratio N(0, 0.35), 0.5–2 s) and its steering
//!    sensor has 0.3° of white noise and a bias;
//! 2. the same car drives a figure eight of 1 m loops, slipping the same way;
//! 3. a full-size car drives 660 m at 8 m/s reporting wheel speeds in km/h
//!    (0.01 steps) and a steering-wheel angle in 1.5° steps with a bias.
//!
//! The wheels arrive as a real vehicle sends them (16-bit wrapping tick
//! counters, or quantised speeds) and go through the crate's decoders. For
//! each drive the demo prints the end-position error of rear-only odometry,
//! of the paper's literal filter and of the default fused filter, the gate's
//! decisions and which wheels it blamed, against the slips that really
//! happened.

use canodom_fusion::ekf::{Ekf, EkfConfig, OdometryInput, State};
use canodom_fusion::sim::{
    Direction, OuNoise, Plan, Run, SimConfig, SlipConfig, SlipWheels, SteeringSensor, simulate,
};
use canodom_fusion::wheel::{
    FaultCounts, InputConfig, SpeedDecoder, SpeedIntegration, SpeedUnit, TickDecoder,
};
use canodom_fusion::{Pose, SteeringMap, VehicleParams, Wheel, WheelSet};

const DEG: f64 = std::f64::consts::PI / 180.0;

/// One wheel's decoder, of the kind the vehicle needs.
enum Decoder {
    Ticks(TickDecoder),
    Speed(SpeedDecoder),
}

impl Decoder {
    fn faults(&self) -> FaultCounts {
        match self {
            Decoder::Ticks(d) => d.faults(),
            Decoder::Speed(d) => d.faults(),
        }
    }
}

struct Outcome {
    distance_m: f64,
    errors_m: Vec<f64>,
    fused: State,
    slips_true: WheelSet<u32>,
    input_faults: u64,
    true_bias_rad: f64,
}

fn replay(
    run: &Run,
    params: &VehicleParams,
    mut decoders: Vec<Decoder>,
    filters: &[Ekf],
) -> Result<Outcome, canodom_fusion::Error> {
    let mut states = vec![State::origin(); filters.len()];
    let mut slips_true = WheelSet::splat(0u32);
    let mut was_slipping = WheelSet::splat(false);
    for (k, s) in run.samples.iter().enumerate() {
        let mut wheel_m = WheelSet::splat(0.0);
        for (dec, w) in decoders.iter_mut().zip(Wheel::ALL) {
            let step = match dec {
                Decoder::Ticks(d) => d.push(s.t_s, s.ticks[w]),
                Decoder::Speed(d) => d.push(s.t_s, s.wheel_speed[w]),
            };
            wheel_m[w] = step.distance_m;
            if s.slipping[w] && !was_slipping[w] {
                slips_true[w] += 1;
            }
        }
        was_slipping = s.slipping;
        if k == 0 {
            continue;
        }
        let input = OdometryInput {
            wheel_m,
            front_valid: true,
            steer_angle_rad: params.steering().angle_rad(s.steer_signal),
            // The demo's car has tick encoders: a zero step is quantisation.
            zero_is_floor: false,
            yaw_rate_radps: None,
            dt_s: 0.0,
        };
        for (st, f) in states.iter_mut().zip(filters) {
            *st = f.step(st, &input)?;
        }
    }
    let err = |p: Pose| (p.x_m - run.true_end.x_m).hypot(p.y_m - run.true_end.y_m);
    Ok(Outcome {
        distance_m: run.samples.last().map_or(0.0, |s| s.true_distance_m),
        errors_m: states.iter().map(|s| err(s.pose())).collect(),
        fused: states[states.len() - 1],
        slips_true,
        input_faults: decoders.iter().map(|d| d.faults().total()).sum(),
        true_bias_rad: run.steer_bias_rad,
    })
}

fn report(title: &str, o: &Outcome, names: &[&str]) {
    println!("\n== {title}: {:.1} m driven", o.distance_m);
    for (name, e) in names.iter().zip(&o.errors_m) {
        println!(
            "   {name:<32} end error {:>8.3} m  ({:.3} % of distance)",
            e,
            100.0 * e / o.distance_m
        );
    }
    let g = o.fused.stats;
    println!(
        "   gate: {} corrections, {} accepted, {} rejected → front used (rear slip), {} rejected → rear kept (front slip)",
        g.corrections, g.accepted, g.rejected_used_front, g.rejected_kept_rear
    );
    let c = o.fused.slip_counts;
    let t = o.slips_true;
    println!(
        "   windows blamed per wheel (RL RR FL FR): {} {} {} {}   true slip events: {} {} {} {}",
        c.rear_left,
        c.rear_right,
        c.front_left,
        c.front_right,
        t.rear_left,
        t.rear_right,
        t.front_left,
        t.front_right
    );
    println!(
        "   wheel input faults reported by the decoders: {}   learnt steering offset {:.3}° (true sensor bias {:.3}°)",
        o.input_faults,
        o.fused.steer_offset_rad() / DEG,
        o.true_bias_rad / DEG
    );
}

/// The three filters compared: rear-only, the paper's, the default.
fn filters(p: VehicleParams) -> Result<Vec<Ekf>, canodom_fusion::Error> {
    Ok(vec![
        Ekf::new(EkfConfig::rear_only(p))?,
        Ekf::new(EkfConfig::paper_literal(p))?,
        Ekf::new(EkfConfig::new(p))?,
    ])
}

/// Drive 3: the full-size car of §12.
fn full_size_car(seed: u64, names: &[&str]) -> Result<(), canodom_fusion::Error> {
    // The full-size car: steering signal = steering-wheel angle (deg), ratio 15.
    let car = VehicleParams::new(
        2.70,
        1.55,
        1.55,
        WheelSet::splat(0.65),
        100,
        SteeringMap {
            gain: DEG / 15.0,
            offset_rad: 0.0,
        },
    )?;
    let sensor = SteeringSensor {
        white_sigma_rad: 0.05 * DEG,
        bias_rad: 0.2 * DEG,
        bias_sigma_rad: 0.1 * DEG,
        drift_rad: OuNoise {
            sigma: 0.1 * DEG,
            tau_s: 30.0,
        },
        quantum: 1.5,
    };
    let run = simulate(
        &SimConfig::road_car(car, sensor),
        &Plan::road_drive(seed)?,
        seed,
    )?;
    let speeds: Result<Vec<Decoder>, _> = (0..4)
        .map(|_| {
            SpeedDecoder::new(
                SpeedUnit::KilometresPerHour,
                SpeedIntegration::Trapezoid,
                InputConfig {
                    nominal_period_s: 0.01,
                    ..InputConfig::ROAD_CAR
                },
            )
            .map(Decoder::Speed)
        })
        .collect();
    report(
        "full-size car, 660 m at 8 m/s, km/h wheel speeds, biased steering-wheel angle, no slip",
        &replay(&run, &car, speeds?, &filters(car)?)?,
        names,
    );
    Ok(())
}

fn main() -> Result<(), canodom_fusion::Error> {
    let seed: u64 = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(2026);
    println!(
        "canodom demo (seed {seed}): fused front/rear odometry against the simulator's ground truth"
    );
    let names = [
        "rear-only odometry",
        "paper's literal EKF (R=10, 10 Hz)",
        "canodom default fused EKF",
    ];

    // The 1:10 car; the odometry uses the same (calibrated) parameters.
    let rc = VehicleParams::nominal(0.25, 0.30, 0.09, 1000)?;
    let mut cfg = SimConfig::rc_car(rc);
    cfg.slip = SlipConfig {
        rate_per_s: 0.05,
        ..SlipConfig::paper(SlipWheels::All)
    };
    cfg.steering_sensor = SteeringSensor {
        white_sigma_rad: 0.3 * DEG,
        bias_sigma_rad: 0.3 * DEG,
        ..SteeringSensor::EXACT
    };
    let ticks = |p: &VehicleParams| -> Result<Vec<Decoder>, canodom_fusion::Error> {
        Wheel::ALL
            .iter()
            .map(|w| {
                TickDecoder::new(16, p.tick_distance_m(*w, 1.0), InputConfig::RC_CAR)
                    .map(Decoder::Ticks)
            })
            .collect()
    };
    for (title, plan) in [
        (
            "1:10 car, calibration track, 2 CCW laps, slips",
            Plan::track(0.78, Direction::Ccw, 2)?,
        ),
        (
            "1:10 car, figure eight (1 m loops), slips",
            Plan::figure_eight(1.0)?,
        ),
    ] {
        let run = simulate(&cfg, &plan, seed)?;
        report(
            title,
            &replay(&run, &rc, ticks(&rc)?, &filters(rc)?)?,
            &names,
        );
    }

    full_size_car(seed, &names)?;
    println!(
        "\nThe default filter: anchored front/rear increments every 0.5 s, the steering error modelled as a bias \
         held over each window and its offset learnt online, and a χ² gate whose wheel consensus decides \
         which axle slipped."
    );
    Ok(())
}
