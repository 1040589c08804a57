//! The fusion experiments of `docs/calibration-math.md` §11 and §12 reproduced on
//! the simulator with fixed seeds; every figure is printed
//! (`cargo test -p canodom-fusion --test experiments -- --nocapture`).
//!
//! The same default configuration ([`EkfConfig::new`]) must pass both: the
//! slip experiment (fused mean squared end error ≥ 90 % below rear-only) and
//! the full-size car (end error ≤ 0.15 % of the distance).

// Helpers of a test harness: a failure to set up is a test failure.
#![allow(clippy::unwrap_used)]

mod common;

use canodom_fusion::ekf::{CorrectionForm, Ekf, EkfConfig, FrontHeading};
use canodom_fusion::sim::{
    Direction, OuNoise, Plan, SimConfig, SlipConfig, SlipWheels, SteeringSensor, simulate,
};
use canodom_fusion::{Pose, SteeringMap, VehicleParams, WheelSet};
use common::{Wheels, replay};

const DEG: f64 = std::f64::consts::PI / 180.0;

/// The §9/§11 1:10 car; the truth equals the nominal parameters here, the
/// errors come from slip and the steering sensor.
fn rc_car() -> VehicleParams {
    VehicleParams::nominal(0.25, 0.30, 0.09, 1000).unwrap()
}

/// The §12 full-size car: the steering signal is the steering-wheel angle in
/// degrees with a ratio of 15.
fn road_car() -> VehicleParams {
    VehicleParams::new(
        2.70,
        1.55,
        1.55,
        WheelSet::splat(0.65),
        100,
        SteeringMap {
            gain: DEG / 15.0,
            offset_rad: 0.0,
        },
    )
    .unwrap()
}

fn err_sq(est: Pose, truth: Pose) -> f64 {
    (est.x_m - truth.x_m).powi(2) + (est.y_m - truth.y_m).powi(2)
}

/// The §11 set-up: two CCW laps of the 0.78 m track, 0.3° white + 0.3° per-run
/// bias on the steering measurement, slips per `slip`.
fn slip_experiment(
    slip: SlipWheels,
    seeds: &[u64],
    runs_per_seed: u64,
    filters: &[(&str, Ekf)],
) -> Vec<f64> {
    let p = rc_car();
    let mut cfg = SimConfig::rc_car(p);
    cfg.slip = SlipConfig::paper(slip);
    cfg.steering_sensor = SteeringSensor {
        white_sigma_rad: 0.3 * DEG,
        bias_sigma_rad: 0.3 * DEG,
        ..SteeringSensor::EXACT
    };
    let plan = Plan::track(0.78, Direction::Ccw, 2).unwrap();
    let ekfs: Vec<Ekf> = filters.iter().map(|(_, f)| *f).collect();
    let mut sums = vec![0.0; filters.len()];
    let mut n = 0.0;
    let mut rejections = 0;
    for seed in seeds {
        for r in 0..runs_per_seed {
            let run = simulate(&cfg, &plan, seed * 1000 + r).unwrap();
            let states = replay(&run, &p, Wheels::ticks(&p, 16), &ekfs);
            for (sum, st) in sums.iter_mut().zip(&states) {
                *sum += err_sq(st.pose(), run.true_end);
            }
            rejections += states.last().map_or(0, |s| {
                s.stats.rejected_used_front + s.stats.rejected_kept_rear
            });
            n += 1.0;
        }
    }
    let means: Vec<f64> = sums.iter().map(|s| s / n).collect();
    println!("slips on {slip:?}, {n} runs (last filter's gate rejections: {rejections}):");
    for ((name, _), m) in filters.iter().zip(&means) {
        // A percentage of a near-zero rear-only error means nothing.
        let pct = if means[0] > 1e-3 {
            format!(", {:+.0} %", 100.0 * (m / means[0] - 1.0))
        } else {
            String::new()
        };
        println!(
            "  {name:<34} mean |e|^2 = {m:.4} m^2  ({:+.4} m^2{pct} vs rear-only)",
            m - means[0]
        );
    }
    means
}

/// The filters compared; the last is the default configuration.
fn variants(p: VehicleParams) -> Vec<(&'static str, Ekf)> {
    let default = EkfConfig::new(p);
    // The anchored form with the steering model matched to §11's sensor
    // (0.3° white, 0.3° bias per run), no gate: §11's "anchored fusion".
    let anchored_matched = EkfConfig {
        steer_sigma_rad: 0.3 * DEG,
        steer_bias_sigma_rad: 0.5 * DEG,
        gate_threshold: None,
        // Without a gate, slips would teach the offset learner nonsense.
        steer_offset_drift_rad: None,
        front_scale_sigma: 0.0,
        blend_accepted: true,
        ..default
    };
    let default_no_gate = EkfConfig {
        gate_threshold: None,
        ..default
    };
    // §12's recipe: the steering as white noise of 20° in the window model.
    let white_20 = EkfConfig {
        steer_sigma_rad: 20.0 * DEG,
        steer_bias_sigma_rad: 0.0,
        ..default
    };
    let wheel_diff = EkfConfig {
        front_heading: FrontHeading::WheelDifference,
        blend_accepted: true,
        ..default
    };
    let ekf = |c| Ekf::new(c).unwrap();
    vec![
        ("rear only", ekf(EkfConfig::rear_only(p))),
        (
            "paper literal R=10,10,10 @10Hz",
            ekf(EkfConfig::paper_literal(p)),
        ),
        ("anchored, sensor-matched, no gate", ekf(anchored_matched)),
        ("default without its gate", ekf(default_no_gate)),
        ("anchored white 20deg + gate", ekf(white_20)),
        ("anchored wheel-diff heading + gate", ekf(wheel_diff)),
        (
            "default without offset learning",
            ekf(EkfConfig {
                steer_offset_drift_rad: None,
                ..default
            }),
        ),
        (
            "default + front scale learning",
            ekf(EkfConfig {
                front_scale_drift: Some(1e-5),
                ..default
            }),
        ),
        ("DEFAULT anchored + consensus gate", ekf(default)),
    ]
}

#[test]
fn section_11_slip_experiment_and_front_only_slips() {
    let p = rc_car();
    let filters = variants(p);
    let m = slip_experiment(SlipWheels::All, &[11, 12, 13], 60, &filters);
    let n = m.len();
    let (rear, literal, anchored, default) = (m[0], m[1], m[2], m[n - 1]);
    println!(
        "§11 table: rear-only {rear:.4} m², literal {literal:.4} ({:+.0} %), anchored {anchored:.4} ({:+.0} %), \
         anchored+consensus {default:.4} ({:+.0} %)",
        100.0 * (literal / rear - 1.0),
        100.0 * (anchored / rear - 1.0),
        100.0 * (default / rear - 1.0)
    );
    assert!(literal <= 0.70 * rear, "literal {literal} vs rear {rear}");
    assert!(
        anchored <= 0.40 * rear,
        "anchored {anchored} vs rear {rear}"
    );
    assert!(default <= 0.10 * rear, "gated {default} vs rear {rear}");

    let front_only = [
        filters[0], filters[1], filters[2], filters[5], filters[6], filters[7], filters[8],
    ];
    let m = slip_experiment(SlipWheels::Front, &[21, 22, 23], 20, &front_only);
    let (rear, default) = (m[0], m[m.len() - 1]);
    println!(
        "front-only slips: rear-only {rear:.4} m², literal {:.4} m², default {default:.4} m² (default − rear-only {:+.4} m²)",
        m[1],
        default - rear
    );
    assert!(default <= rear + 0.005, "{m:?}");
}

#[test]
fn section_12_full_size_car_default_within_0_15_percent() {
    let p = road_car();
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
    let cfg = SimConfig::road_car(p, sensor);
    let filters = variants(p);
    let ekfs: Vec<Ekf> = filters.iter().map(|(_, f)| *f).collect();
    let mut worst_default = 0.0f64;
    for seed in 0..3 {
        let run = simulate(&cfg, &Plan::road_drive(seed).unwrap(), seed).unwrap();
        let distance_m = run.samples.last().unwrap().true_distance_m;
        let states = replay(&run, &p, Wheels::speeds(), &ekfs);
        println!(
            "§12 drive {seed}: {distance_m:.0} m, steering bias {:.2}° (road wheel)",
            run.steer_bias_rad / DEG
        );
        for ((name, _), st) in filters.iter().zip(&states) {
            let e = err_sq(st.pose(), run.true_end).sqrt();
            println!(
                "  {name:<34} end error {e:6.2} m = {:.3} % (gate rejections {} {})",
                100.0 * e / distance_m,
                st.stats.rejected_used_front,
                st.stats.rejected_kept_rear
            );
        }
        let e = err_sq(states[states.len() - 1].pose(), run.true_end).sqrt() / distance_m;
        worst_default = worst_default.max(e);
    }
    println!(
        "§12 default worst: {:.3} % of distance",
        100.0 * worst_default
    );
    assert!(worst_default <= 0.0015, "{worst_default}");
    assert!(matches!(EkfConfig::new(p).form, CorrectionForm::Anchored));
    beyond_the_bar(p, sensor);
}

/// Evidence for the default's front heading and offset learning, beyond
/// §12's bar: a front tyre 0.3 % larger than the others (the front wheels'
/// difference then reads a turn that is not there; every fused variant
/// suffers from the front/rear distance mismatch, the default far less), and
/// a 1° road-wheel steering bias (15° at the steering wheel).
fn beyond_the_bar(p: VehicleParams, sensor: SteeringSensor) {
    let mut tyres = p.wheel_diameters_m();
    tyres.front_right *= 1.003;
    let tyre_cfg = SimConfig::road_car(p.with_diameters(tyres).unwrap(), sensor);
    let biased = SimConfig::road_car(
        p,
        SteeringSensor {
            bias_rad: 1.0 * DEG,
            ..sensor
        },
    );
    let filters = [
        Ekf::new(EkfConfig::rear_only(p)).unwrap(),
        Ekf::new(EkfConfig {
            front_heading: FrontHeading::WheelDifference,
            blend_accepted: true,
            ..EkfConfig::new(p)
        })
        .unwrap(),
        Ekf::new(EkfConfig::new(p)).unwrap(),
        Ekf::new(EkfConfig {
            steer_offset_drift_rad: None,
            ..EkfConfig::new(p)
        })
        .unwrap(),
        Ekf::new(EkfConfig {
            front_scale_drift: Some(1e-5),
            ..EkfConfig::new(p)
        })
        .unwrap(),
        Ekf::new(EkfConfig {
            front_scale_drift: Some(1e-4),
            ..EkfConfig::new(p)
        })
        .unwrap(),
    ];
    for (case, cfg) in [
        ("front-right tyre +0.3 %", &tyre_cfg),
        ("1° steering bias", &biased),
    ] {
        for seed in 0..3 {
            let run = simulate(cfg, &Plan::road_drive(seed).unwrap(), 10 + seed).unwrap();
            let st = replay(&run, &p, Wheels::speeds(), &filters);
            let e: Vec<f64> = st
                .iter()
                .map(|s| err_sq(s.pose(), run.true_end).sqrt())
                .collect();
            println!(
                "§12 {case}, drive {seed}: rear-only {:.2} m, wheel-diff heading {:.2} m, default {:.2} m \
                 ({:.3} %, gate rejections {})",
                e[0],
                e[1],
                e[2],
                100.0 * e[2] / 660.0,
                st[2].stats.rejected_used_front + st[2].stats.rejected_kept_rear
            );
            println!(
                "   without offset learning {:.2} m; learnt offset {:.3}° (true bias {:.3}°)",
                e[3],
                st[2].steer_offset_rad() / DEG,
                run.steer_bias_rad / DEG
            );
            println!(
                "   with front scale learning: {:.2} m (1e-5/window, learnt scale {:.5}), {:.2} m (1e-4/window)",
                e[4],
                st[4].front_scale(),
                e[5]
            );
            if case.starts_with("front") {
                // The reason the default takes its heading from the steering.
                assert!(e[2] * 5.0 < e[1], "{e:?}");
            } else {
                // The reason the default learns the steering offset.
                assert!(e[2] <= 0.0015 * 660.0, "{e:?}");
            }
        }
    }
}
