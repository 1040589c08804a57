//! Tests of the drive calibration (`super`).

#![allow(clippy::unwrap_used)]
use super::*;
use crate::drive_gate::{DriveGate, apply_gate};
use crate::history::ParamValues;

#[test]
fn fixes_parse_by_header_name_and_errors_name_the_line() {
    let f = parse_fixes("x_m,t_unix_s,y_m\n1.0,100.5,2.0\n3,101.5,4\n", "f.csv").unwrap();
    assert_eq!(f.len(), 2);
    assert_eq!(
        (f[1].t_s, f[1].x_m, f[1].y_m, f[1].heading_rad),
        (101.5, 3.0, 4.0, None)
    );
    let f = parse_fixes("t_unix_s,x_m,y_m,heading_rad\n1,0,0,0.5\n", "f.csv").unwrap();
    assert_eq!(f[0].heading_rad, Some(0.5));
    let e = parse_fixes("t,x,y\n1,2,3\n", "f.csv")
        .unwrap_err()
        .to_string();
    assert!(e.contains("f.csv:1") && e.contains("t_unix_s"), "{e}");
    let e = parse_fixes("t_unix_s,x_m,y_m\n1,2,3\n2,abc,3\n", "f.csv")
        .unwrap_err()
        .to_string();
    assert!(e.contains("f.csv:3") && e.contains("x_m"), "{e}");
    let e = parse_fixes("t_unix_s,x_m,y_m\n2,0,0\n1,0,0\n", "f.csv")
        .unwrap_err()
        .to_string();
    assert!(e.contains("increase"), "{e}");
    assert!(parse_fixes("", "f.csv").is_err());
}

use proptest::prelude::*;

const DEG: f64 = PI / 180.0;
pub(super) const MODEL: DriveModel = DriveModel {
    rear_tread_m: 1.55,
    wheelbase_m: 2.7,
};

/// The true vehicle against the values in use, in the estimator's terms.
#[derive(Debug, Clone, Copy)]
pub(super) struct Truth {
    pub(super) g: [f64; N_GLOBAL],
}

pub(super) const TRUTH: Truth = Truth {
    g: [1.012, 1.0015, 0.5 * DEG, 0.95, 0.4 * DEG, 1.02, 0.2, 1.015],
};

/// A noise-free drive built directly: 2 s at rest, then speed `v` along
/// a smooth curvature `kappa(s)`, exact arcs at 50 Hz. The samples carry
/// what odometry with the values in use would read; a fix every second
/// from the true pose (every fifth with a heading), stamped the truth's
/// latency later; the rear wheels on the truth's effective tread.
pub(super) fn drive(
    truth: Truth,
    duration_s: f64,
    kappa: impl Fn(f64) -> f64,
) -> (Vec<DriveSample>, Vec<Fix>) {
    let [s, r, offset, gain, bias, scale, latency, tread] = truth.g;
    let (k_r, k_l) = (s * 2.0 * r / (1.0 + r), s * 2.0 / (1.0 + r));
    let (b, l) = (MODEL.rear_tread_m * tread, MODEL.wheelbase_m);
    let dt = 0.02;
    let steps = (duration_s / dt).round() as usize;
    let phi_meas = |dist: f64| ((kappa(dist) * l).atan() - offset) / gain;
    let mut samples = vec![DriveSample {
        t_s: 0.0,
        rear_left_m: 0.0,
        rear_right_m: 0.0,
        front_m: None,
        steer_angle_rad: Some(phi_meas(0.0)),
        yaw_rate_radps: Some(bias),
        rear_slip: false,
    }];
    // Fixes stamped within the samples only (a negative latency stamps
    // them early).
    let mut fixes: Vec<Fix> = [Fix {
        t_s: latency,
        x_m: 3.0,
        y_m: -2.0,
        heading_rad: Some(0.3),
        sigma_m: None,
    }]
    .into_iter()
    .filter(|f| f.t_s >= 0.0)
    .collect();
    let (mut x, mut y, mut th, mut dist) = (3.0, -2.0, 0.3, 0.0);
    for k in 1..=steps {
        let t = k as f64 * dt;
        let v = if t < 2.0 { 0.0 } else { (t - 2.0).min(5.0) };
        let ds = v * dt;
        let kap = kappa(dist + 0.5 * ds);
        let dth = kap * ds;
        let half = 0.5 * dth;
        let sinc = if half.abs() < 1e-9 {
            1.0
        } else {
            half.sin() / half
        };
        x += ds * sinc * (th + half).cos();
        y += ds * sinc * (th + half).sin();
        th += dth;
        dist += ds;
        samples.push(DriveSample {
            t_s: t,
            rear_left_m: ds * (1.0 - kap * b / 2.0) / k_l,
            rear_right_m: ds * (1.0 + kap * b / 2.0) / k_r,
            front_m: None,
            steer_angle_rad: Some(phi_meas(dist)),
            yaw_rate_radps: Some(scale * dth / dt + bias),
            rear_slip: false,
        });
        if k % 50 == 0 && (0.0..=duration_s).contains(&(t + latency)) {
            fixes.push(Fix {
                t_s: t + latency,
                x_m: x,
                y_m: y,
                heading_rad: (k % 250 == 0).then_some(th),
                sigma_m: None,
            });
        }
    }
    (samples, fixes)
}

pub(super) fn winding(dist: f64) -> f64 {
    0.04 * (2.0 * PI * dist / 150.0).sin() + 0.01
}

fn assert_recovers(cal: &DriveCalibration, truth: Truth, tol: f64) {
    let got = [
        Some(cal.speed_scale),
        Some(cal.rear_ratio),
        cal.steer_offset_rad,
        cal.steer_gain,
        cal.yaw_bias_radps,
        cal.yaw_scale,
        Some(cal.fixes_latency_s),
        Some(cal.rear_tread),
    ];
    // A given latency is not estimated (checked by the caller).
    let estimated = |i: &usize| *i != LATENCY || !cal.latency_given;
    for (i, e) in got.iter().enumerate().filter(|(i, _)| estimated(i)) {
        let e = e.unwrap();
        assert!(e.observable, "parameter {i} not observable: {e:?}");
        assert!(
            (e.value - truth.g[i]).abs() < tol,
            "parameter {i}: {} vs {} ({cal:?})",
            e.value,
            truth.g[i]
        );
    }
}

#[test]
fn noise_free_drive_is_recovered_exactly() {
    let (samples, fixes) = drive(TRUTH, 130.0, winding);
    let cal = calibrate_drive(&samples, &fixes, &MODEL).unwrap();
    // Not to rounding: the drive is built with exact arcs and the steering
    // at the samples, the reckonings use mid-point headings and the mean
    // steering of an interval (2.5e-6 in the gain here).
    assert_recovers(&cal, TRUTH, 1e-5);
    assert_eq!(cal.fixes_used, fixes.len());
    for rms in cal.residual_rms_m {
        assert!(rms.unwrap() < 1e-4, "{cal:?}");
    }
    // From rest to the last fix's instant (129 s): 122 s at 5 m/s after
    // a 5 s ramp.
    let driven = 5.0 * 122.0 + 12.5;
    assert!((cal.distance_m - driven).abs() < 0.1, "{}", cal.distance_m);
}

#[test]
fn without_steering_or_yaw_rate_those_are_none() {
    let (mut samples, fixes) = drive(TRUTH, 70.0, winding);
    for s in &mut samples {
        s.steer_angle_rad = None;
        s.yaw_rate_radps = None;
    }
    let cal = calibrate_drive(&samples, &fixes, &MODEL).unwrap();
    assert!(cal.steer_gain.is_none() && cal.steer_offset_rad.is_none());
    assert!(cal.yaw_bias_radps.is_none() && cal.yaw_scale.is_none());
    assert_eq!(cal.residual_rms_m[1], None);
    assert!((cal.speed_scale.value - TRUTH.g[SPEED]).abs() < 1e-6);
    assert!((cal.rear_ratio.value - TRUTH.g[RATIO]).abs() < 1e-7);
}

#[test]
fn steering_sent_at_a_lower_rate_is_held() {
    let (mut samples, fixes) = drive(TRUTH, 70.0, winding);
    // Steering in every fifth sample only, as a slower CAN frame.
    for (k, s) in samples.iter_mut().enumerate() {
        if k % 5 != 0 {
            s.steer_angle_rad = None;
        }
    }
    let cal = calibrate_drive(&samples, &fixes, &MODEL).unwrap();
    let gain = cal.steer_gain.unwrap();
    assert!(gain.observable);
    assert!((gain.value - 0.95).abs() < 3e-3, "{gain:?}");
}

#[test]
fn a_straight_drive_cannot_tell_steering_gain_or_yaw_scale() {
    let (samples, fixes) = drive(TRUTH, 70.0, |_| 0.0);
    let cal = calibrate_drive(&samples, &fixes, &MODEL).unwrap();
    for e in [cal.steer_gain.unwrap(), cal.yaw_scale.unwrap()] {
        assert!(!e.observable, "{cal:?}");
        assert_eq!(e.value, 1.0);
        assert!(e.sigma > 0.3 * 0.1, "{e:?}");
    }
    // What a straight line does tell: the speed scale, the ratio (the
    // path stays straight), the steering offset and the yaw bias.
    let bias = cal.yaw_bias_radps.unwrap();
    assert!(bias.observable && (bias.value - TRUTH.g[BIAS]).abs() < 1e-6);
    let offset = cal.steer_offset_rad.unwrap();
    // With the gain held at 1 the offset absorbs gain·φ_meas + offset
    // − φ_meas at φ_true = 0: offset − (1 − gain)·(−offset/gain).
    let apparent = TRUTH.g[OFFSET] / TRUTH.g[GAIN];
    assert!(
        offset.observable && (offset.value - apparent).abs() < 1e-6,
        "{offset:?} vs {apparent}"
    );
    assert!((cal.rear_ratio.value - TRUTH.g[RATIO]).abs() < 1e-7);
}

#[test]
fn bad_input_is_named() {
    let (samples, fixes) = drive(TRUTH, 20.0, winding);
    let err = |s: &[DriveSample], f: &[Fix]| calibrate_drive(s, f, &MODEL).unwrap_err();
    assert_eq!(
        err(&samples, &[]),
        Error::NotEnoughFixes {
            what: "in all",
            got: 0,
            needed: 3
        }
    );
    assert!(matches!(
        err(&samples, &fixes[..2]),
        Error::NotEnoughFixes { got: 2, .. }
    ));
    assert_eq!(
        err(&samples[..1], &fixes),
        Error::NotEnoughSamples { got: 1 }
    );
    let mut late = fixes.clone();
    late.push(Fix {
        t_s: 25.0,
        ..fixes[0]
    });
    let e = err(&samples, &late);
    assert!(
        matches!(e, Error::FixOutsideSamples { index, t_s, .. } if index == fixes.len() && t_s == 25.0),
        "{e}"
    );
    assert!(e.to_string().contains("outside the samples' span"), "{e}");
    let mut nan = samples.clone();
    nan[7].rear_right_m = f64::NAN;
    let e = err(&nan, &fixes);
    assert!(matches!(
        e,
        Error::NotFinite {
            what: "sample",
            index: 7,
            field: "rear_right_m",
            ..
        }
    ));
    assert_eq!(
        e.to_string(),
        "sample 7: `rear_right_m` is not finite (NaN)"
    );
    let mut inf = samples.clone();
    inf[3].yaw_rate_radps = Some(f64::INFINITY);
    assert!(matches!(
        err(&inf, &fixes),
        Error::NotFinite {
            field: "yaw_rate_radps",
            index: 3,
            ..
        }
    ));
    let mut bad_fix = fixes.clone();
    bad_fix[2].heading_rad = Some(f64::NAN);
    assert!(matches!(
        err(&samples, &bad_fix),
        Error::NotFinite {
            what: "fix",
            index: 2,
            field: "heading_rad",
            ..
        }
    ));
    let mut back = samples.clone();
    back[10].t_s = back[9].t_s;
    assert!(matches!(
        err(&back, &fixes),
        Error::NotIncreasing {
            what: "sample",
            index: 10,
            ..
        }
    ));
    let mut swapped = fixes.clone();
    swapped.swap(1, 2);
    assert!(matches!(
        err(&samples, &swapped),
        Error::NotIncreasing {
            what: "fix",
            index: 2,
            ..
        }
    ));
    let bad_model = DriveModel {
        wheelbase_m: 0.0,
        ..MODEL
    };
    assert!(matches!(
        calibrate_drive(&samples, &fixes, &bad_model),
        Err(Error::InvalidArgument {
            name: "wheelbase_m",
            ..
        })
    ));
}

#[test]
fn segments_respect_their_limits_and_drop_what_is_too_short() {
    let t: Vec<f64> = (0..=2000).map(|k| f64::from(k) * 0.1).collect();
    let fix = |t_s: f64| Fix {
        t_s,
        x_m: 0.0,
        y_m: 0.0,
        heading_rad: None,
        sigma_m: None,
    };
    // 1 Hz for 130 s: 60 + 60 + 11 fixes.
    let fixes: Vec<Fix> = (0..=130).map(|k| fix(f64::from(k))).collect();
    let segs = split(&t, &vec![0; t.len()], &fixes, &DriveOptions::default(), 0.0);
    let sizes: Vec<usize> = segs.iter().map(|s| s.fixes.len()).collect();
    assert_eq!(sizes, [60, 60, 11]);
    // A remainder of two joins its neighbour; two lone fixes after a
    // long gap are dropped.
    let mut fixes: Vec<Fix> = (0..=61).map(|k| fix(f64::from(k))).collect();
    fixes.extend([fix(150.0), fix(151.0)]);
    let segs = split(&t, &vec![0; t.len()], &fixes, &DriveOptions::default(), 0.0);
    let sizes: Vec<usize> = segs.iter().map(|s| s.fixes.len()).collect();
    assert_eq!(sizes, [62]);
    let at = |seg: &Segment, j: usize| {
        let tf = fixes[seg.fixes[j]].t_s;
        let k = t.partition_point(|&ts| ts < tf).clamp(1, t.len() - 1);
        (k - 1, (tf - t[k - 1]) / (t[k] - t[k - 1]))
    };
    let (i, frac) = at(&segs[0], 61);
    assert_eq!(i, 609);
    assert!((frac - 1.0).abs() < 1e-9 || frac.abs() < 1e-9);
    // Interpolation between samples.
    let segs = split(
        &t,
        &vec![0; t.len()],
        &[fix(0.0), fix(0.25), fix(0.5)],
        &DriveOptions::default(),
        0.0,
    );
    let fixes = [fix(0.0), fix(0.25), fix(0.5)];
    let at = |seg: &Segment, j: usize| {
        let tf = fixes[seg.fixes[j]].t_s;
        let k = t.partition_point(|&ts| ts < tf).clamp(1, t.len() - 1);
        (k - 1, (tf - t[k - 1]) / (t[k] - t[k - 1]))
    };
    assert_eq!(at(&segs[0], 1).0, 2);
    assert!((at(&segs[0], 1).1 - 0.5).abs() < 1e-9);
    assert_eq!(segs[0].start, 0);
    // A wheel slipping at 20.5 s (sample 205) ends a segment there.
    let slips: Vec<usize> = (0..t.len()).map(|k| usize::from(k >= 205)).collect();
    let fixes: Vec<Fix> = (0..=40).map(|k| fix(f64::from(k))).collect();
    let segs = split(&t, &slips, &fixes, &DriveOptions::default(), 0.0);
    let sizes: Vec<usize> = segs.iter().map(|s| s.fixes.len()).collect();
    assert_eq!(sizes, [21, 20]);
}

/// Two 15 m jumps of a receiver (one fix, then two in a row) on an
/// otherwise exact drive.
fn with_jumps(fixes: &mut [Fix]) -> [f64; 3] {
    let at = [20, 55, 56];
    for (k, (dx, dy)) in at.iter().zip([(12.0, 9.0), (-9.0, 12.0), (-9.0, 12.0)]) {
        fixes[*k].x_m += dx;
        fixes[*k].y_m += dy;
    }
    at.map(|k| fixes[k].t_s)
}

#[test]
fn jumps_are_down_weighted_named_and_move_nothing() {
    let (samples, mut fixes) = drive(TRUTH, 130.0, winding);
    // A receiver's: positions only.
    for f in &mut fixes {
        f.heading_rad = None;
    }
    let jumped = with_jumps(&mut fixes);
    let cal = calibrate_drive(&samples, &fixes, &MODEL).unwrap();
    let named: Vec<f64> = cal.down_weighted.iter().map(|d| d.t_s).collect();
    assert_eq!(named, jumped, "{:?}", cal.down_weighted);
    for d in &cal.down_weighted {
        assert!(
            (d.residual_m - 15.0).abs() < 0.1 && d.weight < 0.01,
            "{d:?}"
        );
    }
    // Exact but for the jumps: Cauchy's weights leave them a pull of
    // order (σ/15 m)², far below the test's tolerance.
    assert_recovers(&cal, TRUTH, 1e-4);
    // Plain least squares on the same fixes is pulled far off, and
    // says its σ grew: what the robust loss prevents.
    let options = DriveOptions {
        loss: Loss::LeastSquares,
        ..DriveOptions::default()
    };
    let ls = calibrate_drive_with(&samples, &fixes, &MODEL, &options).unwrap();
    assert!(ls.down_weighted.is_empty());
    let (bias, robust) = (ls.yaw_bias_radps.unwrap(), cal.yaw_bias_radps.unwrap());
    println!("least squares {bias:?}, Cauchy {robust:?}");
    assert!(
        (bias.value - TRUTH.g[BIAS]).abs() > 1e-3 * DEG,
        "{bias:?} vs {robust:?}"
    );
    assert!(bias.sigma > 100.0 * robust.sigma, "{bias:?} vs {robust:?}");
    assert!(ls.weighted_rms_m[YAW].unwrap() > 1.0, "{ls:?}");
}

#[test]
fn a_given_latency_is_used_and_a_wrong_one_shows() {
    let (samples, fixes) = drive(TRUTH, 130.0, winding);
    let given = |latency_s: f64| {
        let options = DriveOptions {
            latency: FixesLatency::Given(latency_s),
            ..DriveOptions::default()
        };
        calibrate_drive_with(&samples, &fixes, &MODEL, &options).unwrap()
    };
    let right = given(TRUTH.g[LATENCY]);
    assert!(right.latency_given && right.fixes_latency_s.value == TRUTH.g[LATENCY]);
    assert_recovers(&right, TRUTH, 1e-5);
    assert_eq!(right.fixes_latency_s.sigma, 0.0);
    // Told there is none, the fit is off by what 0.2 s at 5 m/s does.
    let wrong = given(0.0);
    assert!(wrong.residual_rms_m[YAW].unwrap() > 0.05, "{wrong:?}");
}

#[test]
fn the_gate_keeps_what_is_too_uncertain_and_everything_of_an_implausible_fit() {
    let (samples, fixes) = drive(TRUTH, 130.0, winding);
    let cal = calibrate_drive(&samples, &fixes, &MODEL).unwrap();
    let base = ParamValues::plain(1.55, 0.7);
    let mut passed = cal.clone();
    assert!(apply_gate(&mut passed, &DriveGate::default()).is_empty());
    assert_eq!(
        calibrated_values(&base, &passed),
        calibrated_values(&base, &cal)
    );
    // A bias limit below what the fit reached: the bias alone is kept.
    let strict = DriveGate {
        yaw_bias_radps: 0.5 * cal.yaw_bias_radps.unwrap().sigma,
        ..DriveGate::default()
    };
    let mut gated = cal.clone();
    let refused = apply_gate(&mut gated, &strict);
    assert_eq!(refused.len(), 1, "{refused:?}");
    assert_eq!(refused[0].parameter, "yaw-rate bias");
    assert!(refused[0].reason.contains("above the limit"), "{refused:?}");
    assert_eq!(gated.refused, refused);
    let v = calibrated_values(&base, &gated);
    // Kept as it was (none: 0 beside the new scale), without a σ.
    assert_eq!(v.yaw_rate_bias_radps, Some(0.0));
    assert_eq!(v.yaw_rate_bias_sigma_radps, None);
    assert_eq!(
        v.yaw_rate_scale,
        calibrated_values(&base, &cal).yaw_rate_scale
    );
    // Residuals beyond a receiver's: nothing passes.
    let mut off = cal.clone();
    off.weighted_rms_m = [Some(5.0), Some(4.0), None];
    let refused = apply_gate(&mut off, &DriveGate::default());
    assert_eq!(refused.len(), 7, "{refused:?}");
    assert!(refused[0].reason.contains("4.00 m"), "{refused:?}");
    assert_eq!(calibrated_values(&base, &off), base);
    // Too many fixes down-weighted: nothing passes either.
    let mut jumpy = cal.clone();
    let d = DownWeighted {
        t_s: 0.0,
        residual_m: 9.0,
        weight: 0.01,
    };
    jumpy.down_weighted = vec![d; jumpy.fixes_used / 2];
    assert_eq!(apply_gate(&mut jumpy, &DriveGate::default()).len(), 7);
}

/// A model error that changes along the drive: the rear wheels read 0.3 %
/// more from half-way on (as a tyre's slip under another load would). No
/// speed scale fits both halves; the fit lands between them, and its σ
/// must say it is that unsure though the fixes are exact: each half's own
/// scale within 3σ, where a consistent drive's σ is a hundred times
/// smaller. (The sandwich alone passes this too: its σ puts the first
/// half's scale 2.8σ away, the jackknife's 2.1σ. Its effect on the multi-body
/// drives, where the sandwich put the truth up to 13σ away, is measured
/// by `sim/multibody/evaluate_fixes.py`, calibration-math §14.)
#[test]
fn a_parameter_that_changes_along_the_drive_has_a_sigma_that_says_so() {
    let (consistent, fixes) = drive(TRUTH, 130.0, winding);
    let change = 1.003;
    let mut samples = consistent.clone();
    for s in samples.iter_mut().filter(|s| s.t_s > 65.0) {
        s.rear_left_m *= change;
        s.rear_right_m *= change;
    }
    let cal = calibrate_drive(&samples, &fixes, &MODEL).unwrap();
    // The filter's prior on the bias is the noise's σ, the reported σ at
    // least that.
    let (bias, noise) = (
        cal.yaw_bias_radps.unwrap(),
        cal.yaw_bias_noise_sigma_radps.unwrap(),
    );
    assert!(noise > 0.0 && noise <= bias.sigma, "{noise} vs {bias:?}");
    let v = calibrated_values(&ParamValues::plain(1.55, 0.7), &cal);
    assert_eq!(v.yaw_rate_bias_sigma_radps, Some(noise));
    let e = cal.speed_scale;
    assert!(e.observable, "{e:?}");
    let (first, second) = (TRUTH.g[SPEED], TRUTH.g[SPEED] / change);
    assert!(
        e.value < first && e.value > second,
        "between the halves' scales: {e:?}"
    );
    for truth in [first, second] {
        assert!((e.value - truth).abs() < 3.0 * e.sigma, "{truth} vs {e:?}");
    }
    let exact = calibrate_drive(&consistent, &fixes, &MODEL)
        .unwrap()
        .speed_scale;
    assert!(exact.sigma < 0.01 * e.sigma, "{exact:?} vs {e:?}");
    // Still a measurement: far below the prior's 5 %.
    assert!(e.sigma < 0.005, "{e:?}");
}

#[test]
fn a_drive_turning_one_way_holds_the_tread_and_says_why() {
    let (samples, fixes) = drive(TRUTH, 90.0, |_| 0.01);
    let cal = calibrate_drive(&samples, &fixes, &MODEL).unwrap();
    assert!(
        !cal.rear_tread.observable && cal.rear_tread.value == 1.0,
        "{cal:?}"
    );
    assert!(
        cal.turns_rad[0] > 2.0 && cal.turns_rad[1] < 0.01,
        "{:?}",
        cal.turns_rad
    );
    let v = calibrated_values(&ParamValues::plain(1.55, 0.7), &cal);
    assert_eq!(v.rear_tread_m, 1.55);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 6, ..ProptestConfig::default() })]
    /// Any truth within the priors' reach is recovered from a noise-free
    /// drive, whatever the fixes' frame.
    #[test]
    fn any_truth_is_recovered(
        s in 0.97..1.03_f64,
        r in 0.997..1.003_f64,
        offset_deg in -1.5..1.5_f64,
        gain in 0.85..1.15_f64,
        bias_deg in -0.8..0.8_f64,
        scale in 0.93..1.07_f64,
        latency_s in -0.5..0.5_f64,
        tread in 0.97..1.03_f64,
        turn in -PI..PI,
    ) {
        let truth = Truth {
            g: [s, r, offset_deg * DEG, gain, bias_deg * DEG, scale, latency_s, tread],
        };
        let (samples, mut fixes) = drive(truth, 90.0, winding);
        let (sn, cs) = turn.sin_cos();
        for f in &mut fixes {
            (f.x_m, f.y_m) = (cs * f.x_m - sn * f.y_m + 100.0, sn * f.x_m + cs * f.y_m);
            f.heading_rad = f.heading_rad.map(|h| wrap(h + turn));
        }
        let cal = calibrate_drive(&samples, &fixes, &MODEL).unwrap();
        assert_recovers(&cal, truth, 1e-5);
    }
}
