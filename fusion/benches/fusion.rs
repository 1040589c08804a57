//! Criterion benchmarks: one EKF predict + correct step, and 1,000,000 steps
//! of the simulator.
//!
//! `cargo bench -p canodom-fusion -- --warm-up-time 1 --measurement-time 3`

use canodom_fusion::ekf::{Ekf, EkfConfig, OdometryInput, State};
use canodom_fusion::odometry::wheel_distance_factors;
use canodom_fusion::sim::{Plan, SimConfig, Simulator, SlipConfig, SlipWheels};
use canodom_fusion::{VehicleParams, WheelSet};
use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;

fn params() -> VehicleParams {
    VehicleParams::nominal(0.25, 0.30, 0.09, 1000).unwrap_or_else(|e| panic!("{e}"))
}

fn input(p: &VehicleParams, slip: f64) -> OdometryInput {
    input_at(p, slip, 0.2)
}

fn input_at(p: &VehicleParams, slip: f64, phi: f64) -> OdometryInput {
    let [g_rl, g_rr, g_fl, g_fr] = wheel_distance_factors(p, phi);
    let ds = 0.001;
    OdometryInput {
        wheel_m: WheelSet {
            rear_left: ds * g_rl * (1.0 + slip),
            rear_right: ds * g_rr,
            front_left: ds * g_fl,
            front_right: ds * g_fr,
        },
        front_valid: true,
        steer_angle_rad: phi,
        zero_is_floor: true,
        yaw_rate_radps: None,
        dt_s: 0.01,
    }
}

fn ekf_step(c: &mut Criterion) {
    let p = params();
    let ekf = Ekf::new(EkfConfig {
        correct_every: 1,
        ..EkfConfig::new(p)
    })
    .unwrap_or_else(|e| panic!("{e}"));
    let mut g = c.benchmark_group("ekf");
    // A yardstick measured in the same run: on a shared or emulated machine
    // the ratio to it says more than the absolute time.
    g.bench_function("reference: one sin_cos + one tan", |b| {
        let x = 0.123_f64;
        b.iter(|| {
            let (s, c) = black_box(x).sin_cos();
            s + c + black_box(x).tan()
        });
    });
    // A correction on every step: the cost of one predict + correct. The
    // state runs on (as in the daemon) rather than being rebuilt per
    // iteration, so no batch of 0.5 kB states is measured with it.
    g.bench_function("predict+correct (anchored, gate)", |b| {
        let inp = input(&p, 0.0);
        let mut st = State::origin();
        b.iter(|| {
            st = ekf
                .step(black_box(&st), black_box(&inp))
                .unwrap_or_else(|e| panic!("{e}"));
        });
    });
    // The default cadence: 49 predictions and one correction per 50 samples.
    let default = Ekf::new(EkfConfig::new(p)).unwrap_or_else(|e| panic!("{e}"));
    // The steering angle held (the filter reuses what it derived from it).
    g.bench_function("step, default cadence (per sample)", |b| {
        let inp = input(&p, 0.0);
        let mut st = State::origin();
        b.iter(|| {
            st = default
                .step(black_box(&st), black_box(&inp))
                .unwrap_or_else(|e| panic!("{e}"));
        });
    });
    // The same without the wheel-scale learner (issue #45): what it costs.
    let unlearnt = Ekf::new(EkfConfig {
        learn_wheel_scales: false,
        ..EkfConfig::new(p)
    })
    .unwrap_or_else(|e| panic!("{e}"));
    g.bench_function("step, default cadence, wheel scales not learnt", |b| {
        let inp = input(&p, 0.0);
        let mut st = State::origin();
        b.iter(|| {
            st = unlearnt
                .step(black_box(&st), black_box(&inp))
                .unwrap_or_else(|e| panic!("{e}"));
        });
    });
    // At 10 m/s in a curve: the learner closes a window every 5 m and
    // compares its six explanations (at the bench's 0.1 m/s it never does).
    g.bench_function(
        "step, default cadence, 10 m/s (wheel-scale windows every 5 m)",
        |b| {
            let mut inp = input_at(&p, 0.0, (2.5f64 / 50.0).atan());
            inp.wheel_m = WheelSet {
                rear_left: inp.wheel_m.rear_left * 100.0,
                rear_right: inp.wheel_m.rear_right * 100.0,
                front_left: inp.wheel_m.front_left * 100.0,
                front_right: inp.wheel_m.front_right * 100.0,
            };
            let mut st = State::origin();
            b.iter(|| {
                st = default
                    .step(black_box(&st), black_box(&inp))
                    .unwrap_or_else(|e| panic!("{e}"));
            });
        },
    );
    // A new steering angle every sample: the tangent and square roots anew.
    g.bench_function(
        "step, default cadence, steering changing every sample",
        |b| {
            let inputs: Vec<_> = (0..64)
                .map(|k| input_at(&p, 0.0, 0.2 + 1e-4 * f64::from(k)))
                .collect();
            let mut st = State::origin();
            let mut k = 0;
            b.iter(|| {
                k = (k + 1) % inputs.len();
                st = default
                    .step(black_box(&st), black_box(&inputs[k]))
                    .unwrap_or_else(|e| panic!("{e}"));
            });
        },
    );
    // With a yaw-rate sensor: the aided estimator (issue #30), its window
    // measurement every 0.5 s of samples 10 ms apart.
    g.bench_function("step with the yaw-rate sensor (aided, per sample)", |b| {
        let mut inp = input(&p, 0.0);
        inp.yaw_rate_radps = Some(0.02);
        let mut st = State::origin();
        b.iter(|| {
            st = default
                .step(black_box(&st), black_box(&inp))
                .unwrap_or_else(|e| panic!("{e}"));
        });
    });
    g.finish();
}

fn sim_steps(c: &mut Criterion) {
    let mut cfg = SimConfig::rc_car(params());
    cfg.slip = SlipConfig::paper(SlipWheels::All);
    // Long enough for a million samples at 100 Hz (10,000 s at 0.1 m/s).
    let plan = Plan::random_drive(1, 1100.0, 1.0).unwrap_or_else(|e| panic!("{e}"));
    let mut g = c.benchmark_group("sim");
    g.sample_size(10);
    g.bench_function("1,000,000 steps", |b| {
        b.iter(|| {
            let sim = Simulator::new(&cfg, &plan, 7).unwrap_or_else(|e| panic!("{e}"));
            let mut acc = 0u64;
            for s in sim.take(1_000_000) {
                acc = acc.wrapping_add(s.ticks.rear_left);
            }
            black_box(acc)
        });
    });
    g.finish();
}

criterion_group!(benches, ekf_step, sim_steps);
criterion_main!(benches);
