//! `canodom calibrate --fixes`: calibration from an ordinary drive with
//! sparse position fixes (a GNSS receiver, a surveyed route), no test track.
//!
//! The log goes through the daemon's own [`Pipeline`] with the parameters in
//! use (the parameter file's current set, else the configuration's nominal
//! ones), so every frame is judged as live; each filter step becomes a
//! [`DriveSample`] (rear wheel distances, steering angle, yaw rate) on the
//! log's clock. [`canodom_calib::drive`] fits the rear diameter ratio, the
//! speed scale, the steering offset and gain and the yaw-rate sensor's bias
//! and scale to the fixes by least squares over the whole drive; what the
//! drive could not observe is held. The result is committed to the parameter
//! file as a new set (history kept, bounds checked), which `replay --params`
//! and `run` (through `param_file`) then use.
//!
//! [`Pipeline`]: canodom_pipeline::pipeline::Pipeline
//! [`DriveSample`]: canodom_calib::drive::DriveSample

use anyhow::bail;
use canodom_calib::drive::{DriveCalibration, DriveOptions, Estimate};
use canodom_calib::drive_gate::{misfit_refusal, misfits};
use canodom_params::persist::{ParamFile, ParamSet, ParamValues, PersistError};
use canodom_pipeline::config::Config;
use std::fmt::Write as _;
use std::path::Path;

/// The parameter file at `path` as it is (an empty one if it does not exist yet).
///
/// # Errors
/// A damaged or out-of-bounds file: a calibration is not committed over it.
pub fn load_or_new(path: &Path, config: &Config) -> anyhow::Result<ParamFile> {
    match canodom_params::persist::load(path, &config.calibration.bounds) {
        Ok(f) => Ok(f),
        Err(PersistError::Missing { .. }) => Ok(ParamFile::default()),
        Err(e) => Err(anyhow::Error::new(e).context("the parameter file cannot be extended")),
    }
}

pub use canodom_offline::drive::{DriveLog, values_in_use};

/// Runs `log` through the pipeline with `set` in use and collects a
/// [`canodom_calib::drive::DriveSample`] per filter step ([`canodom_offline::drive::samples_from_frames`]).
///
/// # Errors
/// Unreadable log, a set the filter refuses, or no step at all.
pub fn samples_from_log(
    config: &Config,
    set: Option<&ParamSet>,
    log: &Path,
    interface: Option<&str>,
) -> anyhow::Result<DriveLog> {
    let frames = super::log_frames(log, "calibrate", interface)?;
    let drive = canodom_offline::drive::samples_from_frames(
        config,
        set,
        frames,
        &log.display().to_string(),
    )?;
    if let Some(warning) = &drive.mixed_buses {
        tracing::warn!("calibrate: {warning}");
    }
    for w in &drive.warnings {
        tracing::warn!("calibrate: {}: warning: {w}", log.display());
    }
    Ok(drive)
}

/// The human report of a drive calibration: every parameter with its σ,
/// what was held and why, the residuals.
pub fn report_text(cal: &DriveCalibration, base: &ParamValues, new: &ParamValues) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "calibrate: {} fixes over {:.0} m",
        cal.fixes_used, cal.distance_m
    );
    let line = |s: &mut String, name: &str, e: Option<&Estimate>, unit: &str, k: f64| {
        let _ = match e {
            None => writeln!(s, "  {name:<32} no data in the log"),
            Some(e) if e.observable => writeln!(
                s,
                "  {name:<32} {:+.6}{unit} ± {:.6}{unit}",
                e.value * k,
                e.sigma * k
            ),
            // Refused by the quality gate: the fit is shown, so a user sees
            // how far from the limit it was (the reason is listed below).
            Some(e) if cal.refused.iter().any(|r| name.starts_with(r.parameter)) => writeln!(
                s,
                "  {name:<32} held: refused by the quality gate (fitted {:+.6}{unit} ± {:.6}{unit}; below)",
                e.value * k,
                e.sigma * k
            ),
            Some(e) => writeln!(
                s,
                "  {name:<32} held: the drive does not tell it (σ {:.6}{unit}, too close to the prior)",
                e.sigma * k
            ),
        };
    };
    let deg = 180.0 / std::f64::consts::PI;
    for (name, estimate, unit, k) in [
        ("speed scale", Some(&cal.speed_scale), "", 1.0),
        ("rear ratio (R/L)", Some(&cal.rear_ratio), "", 1.0),
        // The offset is of the road wheels' angle (after the ratio), the
        // gain a factor on the gain in use: the parameter file stores the
        // absolute gain (steering_gain, road-wheel rad per signal unit).
        (
            "steering offset (road-wheel)",
            cal.steer_offset_rad.as_ref(),
            "°",
            deg,
        ),
        (
            "steering gain (× the one in use)",
            cal.steer_gain.as_ref(),
            "",
            1.0,
        ),
        ("yaw-rate bias", cal.yaw_bias_radps.as_ref(), "°/s", deg),
        ("yaw-rate scale", cal.yaw_scale.as_ref(), "", 1.0),
    ] {
        line(&mut s, name, estimate, unit, k);
    }
    tread_and_latency(&mut s, cal, base, new);
    residual_lines(&mut s, cal);
    if cal.down_weighted.is_empty() {
        let _ = writeln!(s, "  down-weighted fixes: none");
    } else {
        let _ = writeln!(
            s,
            "  down-weighted fixes ({}; they disagree with every reckoning):",
            cal.down_weighted.len()
        );
        for d in &cal.down_weighted {
            let _ = writeln!(
                s,
                "    t {:.3} s: residual {:.2} m, weight {:.3}",
                d.t_s, d.residual_m, d.weight
            );
        }
    }
    let _ = writeln!(
        s,
        "  rear diameters {:.6} / {:.6} m -> {:.6} / {:.6} m",
        base.rear_left_diameter_m,
        base.rear_right_diameter_m,
        new.rear_left_diameter_m,
        new.rear_right_diameter_m
    );
    let _ = writeln!(
        s,
        "  stored: steering_gain {:.6} -> {:.6} road-wheel rad per signal unit, steering_offset_rad {:.6} -> {:.6}",
        base.steering_gain, new.steering_gain, base.steering_offset_rad, new.steering_offset_rad
    );
    s
}

/// The report's lines of the residuals at the fixes and the fixes' noise.
fn residual_lines(s: &mut String, cal: &DriveCalibration) {
    let names = ["rear wheels", "yaw rate", "steering"];
    let residuals: Vec<String> = names
        .iter()
        .zip(cal.residual_rms_m)
        .zip(cal.weighted_rms_m.iter().zip(cal.own_fit_rms_m))
        .filter_map(|((n, r), (w, own))| {
            let w = (*w)?;
            // A source the misfit check judged on its own refit says so.
            let alone = own
                .filter(|o| *o != w)
                .map(|o| format!(", {o:.3} m fitted alone"))
                .unwrap_or_default();
            Some(format!("{n} {:.3} m ({w:.3} m weighted{alone})", r?))
        })
        .collect();
    let _ = writeln!(*s, "  residual RMS at the fixes: {}", residuals.join(", "));
    let _ = writeln!(
        *s,
        "  the fixes' noise: σ {:.3} m per axis ({})",
        cal.fixes_sigma_m,
        if cal.fixes_sigma_stated {
            "as the fixes state it"
        } else {
            "estimated from the residuals; none stated"
        }
    );
}

/// The report's lines of the rear tread and the fixes' latency.
fn tread_and_latency(
    s: &mut String,
    cal: &DriveCalibration,
    base: &ParamValues,
    new: &ParamValues,
) {
    let [left, right] = cal.turns_rad.map(f64::to_degrees);
    let _ = if cal.rear_tread.observable {
        writeln!(
            *s,
            "  {:<18} {:+.6} ± {:.6} (turns {left:.0}° left, {right:.0}° right): {:.4} -> {:.4} m",
            "rear tread (rel.)",
            cal.rear_tread.value,
            cal.rear_tread.sigma,
            base.rear_tread_m,
            new.rear_tread_m
        )
    } else if cal
        .refused
        .iter()
        .any(|r| r.parameter == "rear tread (rel.)")
    {
        writeln!(
            *s,
            "  {:<18} held at {} m: fitted from {left:.0}° left and {right:.0}° right, \
             refused by the quality gate (below)",
            "rear tread (rel.)", base.rear_tread_m
        )
    } else {
        writeln!(
            *s,
            "  {:<18} held at {} m: the drive turned {left:.0}° left and {right:.0}° right, \
             too little both ways to tell it from the ratio",
            "rear tread (rel.)", base.rear_tread_m
        )
    };
    let lat = cal.fixes_latency_s;
    let _ = if cal.latency_given {
        writeln!(*s, "  {:<18} {:+.3} s given", "fixes latency", lat.value)
    } else if lat.observable {
        writeln!(
            *s,
            "  {:<18} {:+.6}s ± {:.6}s (a fix stamped t holds the pose at t − latency)",
            "fixes latency", lat.value, lat.sigma
        )
    } else {
        writeln!(
            *s,
            "  {:<18} held at 0 s: the drive does not tell it (σ {:.3} s); give --fixes-latency-s",
            "fixes latency", lat.sigma
        )
    };
}

/// Runs the drive calibration: samples from `log`, fixes from `fixes`,
/// committed to the parameter file `out`.
///
/// # Errors
/// Unreadable inputs, too few fixes within the log, a failed fit, a set
/// outside the configured bounds, an unwritable parameter file.
pub fn execute(
    config: &Config,
    fixes_path: &Path,
    log: &Path,
    out: &Path,
    report_dir: Option<&Path>,
    interface: Option<&str>,
    options: &DriveOptions,
) -> anyhow::Result<()> {
    let all_fixes = canodom_offline::drive::read_fixes(fixes_path)?;
    let mut file = load_or_new(out, config)?;
    let base_set = file.current.clone();
    let base = values_in_use(config, base_set.as_ref());
    let drive = samples_from_log(config, base_set.as_ref(), log, interface)?;
    let what = format!("{} against {}", log.display(), fixes_path.display());
    let fit = canodom_offline::drive::fit_drive(config, base, &drive, &all_fixes, &what, options)?;
    let (first, last) = fit.span_s;
    if fit.fixes_outside > 0 {
        eprintln!(
            "calibrate: {} of {} fixes lie outside the log's {first:.3}–{last:.3} s and are left out",
            fit.fixes_outside,
            all_fixes.len()
        );
    }
    eprintln!(
        "calibrate: {}: {} filter steps; {}{}",
        log.display(),
        drive.samples.len(),
        drive.stats,
        if drive.malformed > 0 {
            format!(", {} malformed lines", drive.malformed)
        } else {
            String::new()
        }
    );
    let (cal, values, fixes) = (fit.calibration, fit.values, fit.fixes);
    print!("{}", report_text(&cal, &base, &values));
    for r in &fit.refused {
        println!(
            "  not committed, the previous value kept: {}: {}",
            r.parameter, r.reason
        );
    }
    let gate = canodom_offline::drive::drive_gate(&config.calibration, base.rear_tread_m);
    let found = misfits(&cal, &gate);
    if !found.is_empty() {
        bail!("{}", misfit_refusal(&found));
    }
    if let Some(why) = fit.out_of_bounds {
        bail!("the calibrated set is outside the configured bounds; not committed: {why}");
    }
    if values == base {
        bail!(
            "nothing passed the quality gate ([calibration] max_*_std, max_fix_residual_m, \
             max_fix_sigma_m, max_down_weighted_share); the parameter file is left as it was"
        );
    }
    let created = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let version = file
        .commit(values, "drive", created, config.calibration.max_history)
        .version;
    canodom_params::persist::store(out, &file)?;
    println!("  committed as version {version} to {}", out.display());
    if let Some(dir) = report_dir {
        let paths = canodom_report::drive_report::write_drive_report(
            dir,
            &drive.samples,
            &fixes,
            &base,
            &values,
            &cal,
        )?;
        eprintln!(
            "calibrate: report written to {} and {}",
            paths.0.display(),
            paths.1.display()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use canodom_calib::drive::calibrated_values;

    fn estimate(value: f64, observable: bool) -> Estimate {
        Estimate {
            value,
            sigma: 1e-4,
            observable,
        }
    }

    #[test]
    fn observable_corrections_are_applied_and_the_rest_held() {
        let base = ParamValues {
            rear_tread_m: 1.57,
            rear_left_diameter_m: 0.72,
            rear_right_diameter_m: 0.72,
            steering_gain: 0.001,
            steering_offset_rad: 0.0,
            yaw_rate_bias_radps: None,
            yaw_rate_scale: None,
            yaw_rate_bias_sigma_radps: None,
        };
        let cal = DriveCalibration {
            speed_scale: estimate(1.01, true),
            rear_ratio: estimate(0.9996, true),
            steer_offset_rad: Some(estimate(0.002, true)),
            steer_gain: Some(estimate(0.9, false)),
            yaw_bias_radps: Some(estimate(-0.007, true)),
            yaw_scale: Some(estimate(1.05, false)),
            yaw_bias_noise_sigma_radps: None,
            fixes_used: 30,
            distance_m: 500.0,
            residual_rms_m: [Some(0.1), Some(0.1), None],
            rear_tread: estimate(1.0, false),
            turns_rad: [0.5, 0.0],
            fixes_latency_s: estimate(0.2, true),
            latency_given: false,
            down_weighted: Vec::new(),
            weighted_rms_m: [Some(0.1), Some(0.1), None],
            own_fit_rms_m: [Some(0.1), Some(0.1), None],
            fixes_sigma_m: 0.08,
            fixes_sigma_stated: false,
            refused: Vec::new(),
        };
        let v = calibrated_values(&base, &cal);
        let (l, r) = (v.rear_left_diameter_m, v.rear_right_diameter_m);
        assert!((r / l - 0.9996).abs() < 1e-12);
        assert!((f64::midpoint(l, r) / 0.72 - 1.01).abs() < 1e-12);
        assert_eq!(v.steering_gain, 0.001, "gain held");
        assert!((v.steering_offset_rad - 0.002).abs() < 1e-15);
        assert_eq!(v.yaw_rate_bias_radps, Some(-0.007));
        assert_eq!(
            v.yaw_rate_scale,
            Some(1.0),
            "scale held at the value in use"
        );
        assert_eq!(v.rear_tread_m, 1.57);
        let text = report_text(&cal, &base, &v);
        assert!(
            text.contains("steering gain") && text.contains("held"),
            "{text}"
        );
        assert!(
            text.contains("rear tread") && text.contains("too little both ways"),
            "{text}"
        );
        assert!(
            text.contains("steering offset (road-wheel)")
                && text.contains("× the one in use")
                && text.contains("stored: steering_gain 0.001000 -> 0.001000 road-wheel rad"),
            "{text}"
        );
        assert!(
            text.contains("the fixes' noise: σ 0.080 m per axis (estimated from the residuals"),
            "{text}"
        );
        let gate = canodom_calib::drive_gate::DriveGate::default();
        assert!(
            misfits(&cal, &gate).is_empty(),
            "0.1 m at the fixes is a fit"
        );
    }
}
