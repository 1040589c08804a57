//! Calibration while the car drives (#46 item 2, first form): the drive's
//! calibration against position fixes ([`crate::drive::fit_samples`]) refitted
//! as fixes come, each refit over everything driven so far, and the set it
//! learnt taken into use from the moment it was learnt. `replay --fixes`
//! runs it over a recorded drive, so a user sees offline what the car would
//! have learnt and where its pose would have ended.
//!
//! A sliding refit rather than a recursive filter: the drive fit already
//! handles what fixes do (jumps, outages, their latency, what a drive
//! cannot tell) and is judged by the same gate as `calibrate --fixes`; a
//! refit of a 10-minute drive costs well under a second, once every
//! `every_s` of fixes. The pose never jumps: a new set changes how the
//! wheels and the gyro are read from then on, not where the car is.
//!
//! Each refit fits the last `window_s` of the drive (`[calibration.drift]
//! window_s`), not all of it: the daemon keeps only that much of a drive
//! that may last hours, and a parameter that changes (a tyre losing
//! pressure) shows in a refit once a good share of its window was driven
//! since. [`drift_watch`] judges the refits against the set in use.

use crate::drive::{DriveLog, fit_samples};
use canodom_calib::drift::{Change, DriftConfig, Watch, Watcher, window_is_full};
use canodom_calib::drive::{DriveCalibration, DriveOptions, DriveSample, Fix};
use canodom_calib::drive_gate::misfits;
use canodom_calib::front_ratio::{FrontGeometry, FrontRatio, front_ratio};
use canodom_params::persist::ParamValues;
use canodom_pipeline::config::Config;
use std::fmt::Write as _;

/// The least fix time between two refits, s: the default of `replay
/// --fixes-every-s`. Two minutes of 1 Hz fixes pin the speed scale to
/// about 0.1 % (σ 1.5 m over a kilometre); refitting more often adds cost,
/// not information.
pub const DEFAULT_EVERY_S: f64 = 120.0;

/// One refit of the online calibration.
#[derive(Clone, Debug)]
pub struct Epoch {
    /// When it was made: the time of the last fix it used (the log's clock, s).
    pub t_s: f64,
    /// Fixes it used.
    pub fixes: usize,
    /// Their span: the last one's time minus the first's, s (0 for fewer
    /// than two). The drift watch judges only a refit that spans most of
    /// its window ([`canodom_calib::drift::window_is_full`]).
    pub fixes_span_s: f64,
    /// The set it learnt: the values in use with every estimate that
    /// passed the gate applied (`None` when the fit failed).
    pub values: Option<ParamValues>,
    /// Each estimate as (name, value, σ, told by the drive and passed the
    /// gate), for the
    /// learnt-parameters CSV.
    pub estimates: Vec<(&'static str, f64, f64, bool)>,
    /// Why the learnt set is not taken into use, when it is not: the fit
    /// failed, misfits the fixes, leaves the configured bounds, or nothing
    /// passed the gate.
    pub refused: Option<String>,
    /// The fit, for the drift watch: `None` when it failed or misfits the
    /// fixes (what it learnt then says nothing about the car).
    pub judged: Option<DriveCalibration>,
    /// Distance driven from the drive's start to `t_s` (the rear wheels'
    /// mean with the set in use), m.
    pub distance_m: f64,
    /// The front tyres' right/left ratio over the window's near-straights
    /// ([`canodom_calib::front_ratio`]), the rear wheels read with the rear
    /// ratio the fit learnt; `None` when the fit is not judged or the
    /// window holds too little of them.
    pub front_ratio: Option<FrontRatio>,
}

impl Epoch {
    /// The set to take into use from `t_s` on, when there is one.
    pub fn accepted(&self) -> Option<&ParamValues> {
        if self.refused.is_some() {
            None
        } else {
            self.values.as_ref()
        }
    }
}

/// Refits the drive every `every_s` of fixes (and once at the last fix),
/// each over the samples and fixes of the `window_s` up to that time,
/// starting from `base` (the values in use when the drive was recorded).
pub fn learn(
    config: &Config,
    base: ParamValues,
    drive: &DriveLog,
    fixes: &[Fix],
    options: &DriveOptions,
    every_s: f64,
    window_s: f64,
) -> Vec<Epoch> {
    let (Some(first), Some(last)) = (drive.samples.first(), drive.samples.last()) else {
        return Vec::new();
    };
    let inside: Vec<Fix> = fixes
        .iter()
        .copied()
        .filter(|f| f.t_s >= first.t_s && f.t_s <= last.t_s)
        .collect();
    let (Some(f0), Some(f_end)) = (inside.first(), inside.last()) else {
        return Vec::new();
    };
    let mut times = Vec::new();
    let mut t = f0.t_s + every_s;
    while t < f_end.t_s {
        times.push(t);
        t += every_s;
    }
    times.push(f_end.t_s);
    // Distance from the start to each sample's end, for the epochs' `distance_m`.
    let mut distance_m = 0.0;
    let travelled: Vec<f64> = drive
        .samples
        .iter()
        .map(|s| {
            distance_m += 0.5 * (s.rear_left_m + s.rear_right_m).abs();
            distance_m
        })
        .collect();
    times
        .into_iter()
        .map(|t_s| {
            let from = drive.samples.partition_point(|s| s.t_s < t_s - window_s);
            let upto = drive.samples.partition_point(|s| s.t_s <= t_s);
            let used: Vec<Fix> = inside
                .iter()
                .copied()
                .filter(|f| f.t_s <= t_s && f.t_s >= t_s - window_s)
                .collect();
            let mut e = refit(
                config,
                base,
                &drive.samples[from..upto],
                &used,
                options,
                t_s,
            );
            e.distance_m = upto.checked_sub(1).map_or(0.0, |i| travelled[i]);
            e
        })
        .collect()
}

/// The drift watch over `epochs` (fitted on samples recorded with `base`,
/// each over at most `window_s` of the drive), each judged against
/// `in_use`: the watch after each refit and what it changed, in the
/// epochs' order. A refit whose fixes do not yet span most of the window
/// leaves the watch as it was ([`window_is_full`]).
pub fn drift_watch(
    epochs: &[Epoch],
    base: &ParamValues,
    in_use: &ParamValues,
    judge: &DriftConfig,
    window_s: f64,
) -> Vec<(Watch, Vec<Change>)> {
    let mut watcher = Watcher::default();
    epochs
        .iter()
        .map(|e| {
            if !window_is_full(e.fixes_span_s, window_s) {
                return (watcher.watch(), Vec::new());
            }
            let read =
                watcher.refit_readings(base, e.judged.as_ref(), e.front_ratio.as_ref(), in_use);
            let changes = watcher.judge(&read, judge);
            (watcher.watch(), changes)
        })
        .collect()
}

/// One refit at `t_s` over `samples` (recorded with `base` in use) and the
/// fixes among `fixes` within their time: what [`learn`] does at each of
/// its times, and what the daemon's drift watch runs live over the ring it
/// keeps (`distance_m` is left 0 for the caller).
pub fn refit(
    config: &Config,
    base: ParamValues,
    samples: &[DriveSample],
    fixes: &[Fix],
    options: &DriveOptions,
    t_s: f64,
) -> Epoch {
    let what = format!("the drive up to t={t_s:.1} s");
    let fixes_span_s = canodom_calib::drift::fixes_span_s(fixes);
    let fit = match fit_samples(config, base, samples, fixes, &what, options) {
        Ok(fit) => fit,
        Err(e) => {
            return Epoch {
                t_s,
                fixes: fixes.len(),
                fixes_span_s,
                values: None,
                estimates: Vec::new(),
                refused: Some(e.to_string()),
                judged: None,
                distance_m: 0.0,
                front_ratio: None,
            };
        }
    };
    let cal = &fit.calibration;
    // The gate marks what it refused as not told: `observable` is "passed".
    let mut estimates = vec![
        (
            "speed_scale",
            cal.speed_scale.value,
            cal.speed_scale.sigma,
            cal.speed_scale.observable,
        ),
        (
            "rear_ratio",
            cal.rear_ratio.value,
            cal.rear_ratio.sigma,
            cal.rear_ratio.observable,
        ),
        (
            "rear_tread",
            cal.rear_tread.value,
            cal.rear_tread.sigma,
            cal.rear_tread.observable,
        ),
        (
            "fixes_latency_s",
            cal.fixes_latency_s.value,
            cal.fixes_latency_s.sigma,
            cal.fixes_latency_s.observable,
        ),
    ];
    for (name, e) in [
        ("steer_offset_rad", cal.steer_offset_rad),
        ("steer_gain", cal.steer_gain),
        ("yaw_bias_radps", cal.yaw_bias_radps),
        ("yaw_scale", cal.yaw_scale),
    ] {
        if let Some(e) = e {
            estimates.push((name, e.value, e.sigma, e.observable));
        }
    }
    let found = misfits(
        cal,
        &crate::drive::drive_gate(&config.calibration, base.rear_tread_m),
    );
    // Read only off a fit that is judged: its rear ratio reads the stretches.
    let front = if found.is_empty() {
        let geometry = FrontGeometry {
            rear_tread_m: base.rear_tread_m * cal.rear_tread.value,
            front_tread_m: config.params.front_tread_m(),
            wheelbase_m: config.params.wheelbase_m(),
        };
        front_ratio(samples, &geometry, cal.rear_ratio.value)
    } else {
        None
    };
    if let Some(f) = &front {
        estimates.push(("front_ratio", f.value, f.sigma, true));
    }
    let refused = if !found.is_empty() {
        Some(canodom_calib::drive_gate::misfit_refusal(&found))
    } else if let Some(why) = &fit.out_of_bounds {
        Some(format!("outside the configured bounds: {why}"))
    } else if fit.values == base {
        Some("nothing passed the quality gate".to_owned())
    } else {
        None
    };
    Epoch {
        t_s,
        fixes: fixes.len(),
        fixes_span_s,
        values: Some(fit.values),
        estimates,
        refused,
        judged: found.is_empty().then(|| fit.calibration.clone()),
        distance_m: 0.0,
        front_ratio: front,
    }
}

/// The learnt-parameters CSV: a row per refit and estimate; `drifted` is
/// the drift watch's flag of that parameter after the refit (0 for one it
/// does not judge, the fixes' latency).
pub const LEARNT_CSV_HEADER: &str =
    "t_unix_s,fixes,parameter,value,sigma,passed,taken_into_use,drifted";

/// The learnt-parameters CSV's rows for `epochs`, with the watch after each
/// (`watches[i]` after `epochs[i]`; a missing one counts as no flag).
pub fn learnt_csv(epochs: &[Epoch], watches: &[Watch]) -> String {
    let mut out = format!("{LEARNT_CSV_HEADER}\n");
    for (i, e) in epochs.iter().enumerate() {
        let used = u8::from(e.accepted().is_some());
        for (name, value, sigma, passed) in &e.estimates {
            let drifted = canodom_calib::drift::Param::from_name(name)
                .zip(watches.get(i))
                .is_some_and(|(p, w)| w.flagged(p));
            // Writing to a String cannot fail.
            let _ = writeln!(
                out,
                "{:.3},{},{name},{value:.9},{sigma:.9},{},{used},{}",
                e.t_s,
                e.fixes,
                u8::from(*passed),
                u8::from(drifted)
            );
        }
    }
    out
}
