//! §10 on the simulator: the steering map from constant-command arcs with
//! calibrated rear odometry, and the order-of-operations trap.

use crate::common::{DEG, RHO_M, effective, laps, nominal, record, truth};
use canodom_calib::methods::{ExactOptions, PaperOptions, exact, heading, paper};
use canodom_calib::steering::{ArcEstimate, ArcOptions, SteeringFit, estimate_arc, fit_steering};
use canodom_calib::{Direction, RearParams, Track};
use canodom_fusion::SteeringMap;
use canodom_fusion::sim::{self, Plan, SimConfig};

/// Constant commands −20..20 (steps of 5), 2.2 m each, §9's path-following
/// noise; the steering signal recorded is the *command* (as an RC car
/// reports it), so the servo noise and lag stay in the data.
fn arcs(cfg: &SimConfig, rear: &RearParams, seed0: u64) -> Vec<ArcEstimate> {
    let params = nominal();
    (-20..=20)
        .step_by(5)
        .enumerate()
        .map(|(k, u)| {
            let plan = Plan::constant_command(f64::from(u), 2.2).unwrap();
            let run = sim::simulate(cfg, &plan, seed0 + k as u64).unwrap();
            let mut rec = record(
                &run,
                Direction::Ccw,
                &params,
                false,
                cfg.wheel_output.counter_bits,
            );
            for (s, raw) in rec.samples.iter_mut().zip(&run.samples[1..]) {
                s.steer_signal = raw.steer_command;
            }
            estimate_arc(
                &rec.samples,
                rear,
                params.wheelbase_m(),
                &ArcOptions::default(),
            )
            .unwrap()
        })
        .collect()
}

fn show(label: &str, fit: &SteeringFit) {
    println!(
        "{label:<44} k = {:.4}  c = {:+.3}°  rms {:.3}°  (varying arcs dropped: {})",
        fit.gain / DEG,
        fit.offset_rad / DEG,
        fit.rms_rad / DEG,
        fit.dropped_varying
    );
}

#[test]
fn steering_map_is_recovered_from_arcs_with_calibrated_rear_odometry() {
    let t = truth(false, false);
    let cfg = SimConfig::rc_car(t);
    let track = Track::new(RHO_M).unwrap();
    let used = RearParams::of(&nominal());
    // Rear calibration first (5+5 runs, measured ends), then the arcs.
    let cal = laps(&cfg, &nominal(), 5, 500, true);
    let rear = exact(&cal, &used, track, ExactOptions::default())
        .unwrap()
        .rear;
    let fit = fit_steering(&arcs(&cfg, &rear, 600), false).unwrap();
    let fit_nominal = fit_steering(&arcs(&cfg, &used, 600), false).unwrap();
    println!(
        "\n§10 steering calibration (truth φ = 0.93 u + 0.80°, §9 path noise, 9 arcs of 2.2 m)"
    );
    show("calibrated rear odometry (exact method):", &fit);
    show("nominal rear odometry (§10: 0.888, 0.53°):", &fit_nominal);
    assert!(
        (fit.gain / DEG / 0.93 - 1.0).abs() < 0.005,
        "k {}",
        fit.gain / DEG
    );
    assert!(
        (fit.offset_rad / DEG - 0.80).abs() < 0.05,
        "c {}",
        fit.offset_rad / DEG
    );
    assert!(fit.rms_rad / DEG < 0.2);
    // The nominal rear wheels bias the map as §10 predicts (tread error
    // scales k, ratio error shifts c).
    assert!(fit_nominal.gain / DEG < 0.9 && fit_nominal.offset_rad / DEG < 0.65);
}

#[test]
fn order_of_operations_trap_needs_measured_end_poses() {
    let t = truth(false, false);
    let track = Track::new(RHO_M).unwrap();
    let used = RearParams::of(&nominal());
    let (b_eff, e_true) = effective(&t, &used);
    // Round 0: the steering map fitted with the uncalibrated rear odometry.
    let cfg = SimConfig::rc_car(t);
    let trap_fit = fit_steering(&arcs(&cfg, &used, 700), false).unwrap();
    let mut trapped = cfg.clone();
    trapped.driver_steering = Some(SteeringMap {
        gain: trap_fit.gain,
        offset_rad: trap_fit.offset_rad,
    });
    let measured = laps(&trapped, &nominal(), 5, 800, true);
    let worst_end =
        measured
            .iter()
            .map(|r| r.measured_end.unwrap())
            .fold((0.0_f64, 0.0_f64), |(p, h), e| {
                (
                    p.max(e.x_m.hypot(e.y_m)),
                    h.max(canodom_fusion::wrap_angle(e.heading_rad).abs()),
                )
            });
    let mut assumed = measured.clone();
    for r in &mut assumed {
        r.measured_end = None;
    }
    let p = paper(&assumed, &used, track, PaperOptions::default()).unwrap();
    let h = heading(&assumed, &used, track).unwrap();
    let x = exact(&measured, &used, track, ExactOptions::default()).unwrap();
    let refit = fit_steering(&arcs(&cfg, &x.rear, 900), false).unwrap();
    println!(
        "\n§10 order-of-operations trap: driver map k = {:.4}, c = {:.3}° (fitted with nominal rear); real ends up to {:.1} cm and {:.1}° off the start",
        trap_fit.gain / DEG,
        trap_fit.offset_rad / DEG,
        100.0 * worst_end.0,
        worst_end.1 / DEG
    );
    println!(
        "ends assumed at the start: paper {:.2} cm / {:.4}, heading law {:.2} cm / {:.4} (nominal 30.00 cm / 1.0000)",
        100.0 * p.tread_m(),
        p.ratio(),
        100.0 * h.tread_m(),
        h.ratio()
    );
    println!(
        "ends measured: exact {:.2} cm / {:.4} (truth {:.2} cm / {:.4})",
        100.0 * x.tread_m(),
        x.ratio(),
        100.0 * b_eff,
        e_true
    );
    show("steering refit with the calibrated rear:", &refit);
    // Assuming end = start confirms the old parameters...
    assert!(
        (h.tread_m() - 0.30).abs() < 0.003 && (h.ratio() - 1.0).abs() < 0.002,
        "{h:?}"
    );
    // ...while the measured ends give the truth, and the refit the true map.
    assert!((x.tread_m() / b_eff - 1.0).abs() < 0.003 && (x.ratio() / e_true - 1.0).abs() < 6e-4);
    assert!((refit.gain / DEG / 0.93 - 1.0).abs() < 0.005);
    assert!((refit.offset_rad / DEG - 0.80).abs() < 0.05);
}
