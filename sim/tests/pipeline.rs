//! The pipeline fed with frames a DBC-encoded simulated vehicle sends: the
//! integration of the pipeline crate with the sample encoder.

// A failure to build the fixture is a test failure.
#![allow(clippy::unwrap_used)]

use canodom_can::frame::CanFrame;
use canodom_can::time::Timestamp;
use canodom_fusion::ekf::WindowOutcome;
use canodom_fusion::sim::Simulator;
use canodom_pipeline::config::Config;
use canodom_pipeline::pipeline::*;
use canodom_pipeline::stats::Reject;
use canodom_sim::vehicle::{PathKind, SampleEncoder, sim_config};
use std::path::PathBuf;

fn config() -> Config {
    let p = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../daemon/examples/rc_car.toml"
    ));
    Config::load(&p).unwrap()
}

/// `(timestamp, frame)` of a simulated circle drive, steering/front/rear per sample.
fn frames(config: &Config, seconds: f64) -> Vec<(Timestamp, CanFrame)> {
    let plan = PathKind::Circle.plan(false, 1).unwrap();
    let sim = Simulator::new(&sim_config(config, config.params), &plan, 1).unwrap();
    let mut enc = SampleEncoder::new(config);
    let mut out = Vec::new();
    let mut buf = Vec::new();
    for s in sim.take_while(|s| s.t_s <= seconds) {
        buf.clear();
        enc.encode(&s, &mut buf);
        let t = Timestamp::from_micros(1_000_000 + (s.t_s * 1e6).round() as u64);
        out.extend(buf.iter().map(|f| (t, *f)));
    }
    out
}

const REAR: u32 = 0x100;
const FRONT: u32 = 0x101;

#[test]
fn an_applied_set_drives_the_next_steps_and_is_reported() {
    let c = config();
    let fr = frames(&c, 10.0);
    let mut nominal = Pipeline::new(&c).unwrap();
    let mut calibrated = Pipeline::new(&c).unwrap();
    let steer = c.params.steering();
    let set = canodom_params::persist::ParamValues {
        rear_tread_m: 0.33,
        rear_left_diameter_m: 0.09,
        rear_right_diameter_m: 0.09 * 1.01,
        steering_gain: steer.gain,
        steering_offset_rad: steer.offset_rad,
        yaw_rate_bias_radps: None,
        yaw_rate_scale: None,
        yaw_rate_bias_sigma_radps: None,
    };
    calibrated.apply_params(Some((4, &set))).unwrap();
    for (t, f) in &fr {
        nominal.push(*t, f);
        calibrated.push(*t, f);
    }
    let (a, b) = (
        nominal.last_step().unwrap().odometry,
        calibrated.last_step().unwrap().odometry,
    );
    // Rear odometry turns by (D_R·n_R − D_L·n_L)/b: with the calibrated
    // set the right wheel goes 1 % further and the tread is 10 % wider.
    assert!((a.heading_rad - b.heading_rad).abs() > 0.03, "{a:?} {b:?}");
    let out = calibrated.pose_output(fr.last().unwrap().0);
    assert_eq!((out.param_version, out.flags.nominal_params), (4, false));
    assert!((calibrated.params().rear_diameter_ratio() - 1.01).abs() < 1e-12);
    calibrated.apply_params(None).unwrap();
    assert_eq!(calibrated.param_version(), None);
    assert!(
        calibrated
            .pose_output(fr.last().unwrap().0)
            .flags
            .nominal_params
    );
}

#[test]
fn gate_decisions_are_reported_per_step_per_action_and_per_wheel() {
    let c = config();
    let plan = PathKind::Circle.plan(false, 1).unwrap();
    let mut sim_cfg = sim_config(&c, c.params);
    sim_cfg.slip = canodom_fusion::sim::SlipConfig {
        rate_per_s: 0.3,
        ..canodom_fusion::sim::SlipConfig::paper(canodom_fusion::sim::SlipWheels::Rear)
    };
    let sim = Simulator::new(&sim_cfg, &plan, 3).unwrap();
    let mut enc = SampleEncoder::new(&c);
    let mut p = Pipeline::new(&c).unwrap();
    let mut buf = Vec::new();
    let mut outcomes = std::collections::HashMap::<WindowOutcome, u64>::new();
    for s in sim {
        buf.clear();
        enc.encode(&s, &mut buf);
        let t = Timestamp::from_micros(1_000_000 + (s.t_s * 1e6).round() as u64);
        for f in &buf {
            if let Some(step) = p.push(t, f).step() {
                *outcomes.entry(step.correction).or_default() += 1;
            }
        }
    }
    let s = *p.stats();
    let count = |o| outcomes.get(&o).copied().unwrap_or(0);
    assert!(count(WindowOutcome::Accepted) > 0, "{outcomes:?}");
    assert!(s.gate.used_front > 0, "{s}");
    assert_eq!(count(WindowOutcome::RejectedUsedFront), s.gate.used_front);
    // The aided estimator's disagreements keep the rear increment too.
    assert_eq!(
        count(WindowOutcome::RejectedKeptRear) + count(WindowOutcome::Disagreed),
        s.gate.kept_rear
    );
    let blamed = s.gate.blamed;
    let total = blamed.rear_left + blamed.rear_right + blamed.front_left + blamed.front_right;
    assert_eq!(total, s.get(Reject::GateReject), "{s}");
    // Only rear wheels slipped: the consensus blames them.
    assert!(
        blamed.rear_left + blamed.rear_right > 2 * (blamed.front_left + blamed.front_right),
        "{s}"
    );
    assert_eq!(
        count(WindowOutcome::Open)
            + s.gate.used_front
            + s.gate.kept_rear
            + count(WindowOutcome::Accepted)
            + count(WindowOutcome::NoFront),
        s.steps
    );
}

#[test]
fn stale_front_runs_on_prediction_and_says_so() {
    let c = config();
    let mut p = Pipeline::new(&c).unwrap();
    let mut last = Timestamp::from_micros(0);
    for (t, f) in frames(&c, 20.0) {
        // The front ECU falls silent after 10 s.
        if f.id().raw() == FRONT && t.as_micros() > 11_000_000 {
            continue;
        }
        p.push(t, &f);
        last = t;
    }
    let s = *p.stats();
    // Steps after the timeout (3 × 10 ms) ran without the front.
    assert!(s.steps_without_front > 900, "{s}");
    let out = p.pose_output(last);
    assert!(out.flags.front_stale && !out.flags.rear_stale && out.flags.pose_valid);
    assert!(out.x_m.is_finite());
}

#[test]
fn stale_rear_invalidates_the_pose() {
    let c = config();
    let mut p = Pipeline::new(&c).unwrap();
    let fr = frames(&c, 5.0);
    let last = fr.last().unwrap().0;
    for (t, f) in &fr {
        p.push(*t, f);
    }
    assert!(p.pose_output(last).flags.pose_valid);
    // 30 ms later (3 periods) it is still fresh; 31 ms later it is stale.
    let later = |us| Timestamp::from_micros(last.as_micros() + us);
    assert!(p.pose_output(later(30_000)).flags.pose_valid);
    let o = p.pose_output(later(31_000));
    assert!(!o.flags.pose_valid && o.flags.rear_stale && o.flags.front_stale);
}

#[test]
fn trust_returns_only_after_enough_good_frames() {
    let c = config();
    let mut p = Pipeline::new(&c).unwrap();
    let fr = frames(&c, 6.0);
    let mut rear_after_gap = 0;
    for (t, f) in &fr {
        let us = t.as_micros();
        // A 100 ms rear outage at 4 s.
        if f.id().raw() == REAR && (5_000_000..5_100_000).contains(&us) {
            continue;
        }
        p.push(*t, f);
        if f.id().raw() == REAR && us >= 5_100_000 {
            rear_after_gap += 1;
            let valid = p.pose_output(*t).flags.pose_valid;
            // trusted_after_frames = 5 good frames in a row.
            assert_eq!(
                valid,
                rear_after_gap >= 5,
                "frame {rear_after_gap} after the gap"
            );
        }
    }
    assert!(rear_after_gap > 50);
}

#[test]
fn consecutive_bad_frames_invalidate_the_input() {
    let c = config();
    let mut p = Pipeline::new(&c).unwrap();
    let mut bad_run = 0;
    for (t, f) in frames(&c, 6.0) {
        let us = t.as_micros();
        if f.id().raw() == REAR && (5_000_000..5_040_000).contains(&us) {
            // Four rear frames in a row with a broken checksum.
            let mut d = [0u8; 8];
            d.copy_from_slice(f.data());
            d[7] ^= 0xFF;
            p.push(t, &CanFrame::new_data(f.id(), &d).unwrap());
            bad_run += 1;
            let o = p.pose_output(t);
            // invalid_after_faults = 3; the flag latches the fault either way.
            assert_eq!(o.flags.pose_valid, bad_run < 3, "bad frame {bad_run}");
            assert!(o.flags.checksum_fault);
            continue;
        }
        p.push(t, &f);
    }
    assert_eq!(p.stats().get(Reject::BadChecksum), 4);
    // Latches clear once reported.
    let o = p.pose_output(Timestamp::from_micros(7_000_000));
    assert!(!o.flags.checksum_fault);
}

/// A set's yaw-rate bias is the sensor's, in its raw units (measured =
/// scale · true + bias); the filter subtracts its bias from the rate already
/// divided by the scale, so it must start from bias / scale, as sure as the
/// set's σ says (issue #31: it started from the raw bias, with a fixed σ).
#[test]
fn a_sets_yaw_rate_bias_is_the_filters_prior_in_its_units_with_its_sigma() {
    let c = config();
    let steer = c.params.steering();
    let mut pipeline = Pipeline::new(&c).unwrap();
    let set = canodom_params::persist::ParamValues {
        rear_tread_m: c.params.rear_tread_m(),
        rear_left_diameter_m: 0.09,
        rear_right_diameter_m: 0.09,
        steering_gain: steer.gain,
        steering_offset_rad: steer.offset_rad,
        yaw_rate_bias_radps: Some(0.01),
        yaw_rate_scale: Some(1.25),
        yaw_rate_bias_sigma_radps: Some(0.002),
    };
    pipeline.apply_params(Some((2, &set))).unwrap();
    let pair = pipeline.state().learnt().yaw_bias.unwrap();
    assert!((pair.yaw_bias_radps - 0.008).abs() < 1e-15, "{pair:?}");
    assert!(
        (pair.yaw_bias_sigma_radps - 0.0016).abs() < 1e-15,
        "{pair:?}"
    );
}
