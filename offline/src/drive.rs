//! A drive's calibration against position fixes (`canodom calibrate
//! --fixes`): the log goes through the daemon's own [`Pipeline`] with the
//! parameters in use, each filter step becomes a [`DriveSample`] on the
//! log's clock, and [`canodom_calib::drive`] fits the parameters the drive
//! tells to the fixes; what it could not tell is held.

use crate::log::LogFrames;
use crate::{Error, Result};
use canodom_calib::drive::{
    DriveCalibration, DriveModel, DriveOptions, DriveSample, Fix, GateRefusal,
    calibrate_drive_with, calibrated_values,
};
use canodom_calib::drive_gate::{DriveGate, apply_gate};
use canodom_fusion::ekf::WindowOutcome;
use canodom_params::persist::{ParamSet, ParamValues};
use canodom_pipeline::config::Config;
use canodom_pipeline::pipeline::{Outcome, Pipeline};

/// The values a set describes when `set` is absent: the configuration's nominal parameters.
pub fn values_in_use(config: &Config, set: Option<&ParamSet>) -> ParamValues {
    set.map_or_else(|| ParamValues::nominal(&config.params), |s| s.values)
}

/// What one log gave: the samples and how the pipeline judged its frames.
pub struct DriveLog {
    /// One sample a filter step, on the log's clock.
    pub samples: Vec<DriveSample>,
    /// The pipeline's statistics line.
    pub stats: String,
    /// Malformed lines skipped.
    pub malformed: u64,
    /// The warning when the log mixes several interfaces and none was chosen.
    pub mixed_buses: Option<String>,
    /// The pipeline's warnings at the log's end (a saturated yaw rate, a
    /// configured message that never came, an implausible signal), as
    /// `replay` prints them.
    pub warnings: Vec<String>,
}

/// Runs `frames` through the pipeline with `set` in use and collects a
/// [`DriveSample`] per filter step.
///
/// # Errors
/// Unreadable log, a set the filter refuses, or no step at all.
pub fn samples_from_frames(
    config: &Config,
    set: Option<&ParamSet>,
    mut frames: LogFrames<'_>,
    log_name: &str,
) -> Result<DriveLog> {
    let filter = |context: &str| {
        let context = context.to_owned();
        move |source| Error::Filter { context, source }
    };
    let mut pipeline = Pipeline::new(config).map_err(filter("the configured vehicle"))?;
    if let Some(s) = set {
        pipeline
            .apply_params(Some((s.version, &s.values)))
            .map_err(filter(&format!("parameter set version {}", s.version)))?;
    }
    let map = pipeline.params().steering();
    let [d_left, d_right, d_front_left, d_front_right] = {
        use canodom_fusion::Wheel;
        let p = pipeline.params();
        [
            Wheel::RearLeft,
            Wheel::RearRight,
            Wheel::FrontLeft,
            Wheel::FrontRight,
        ]
        .map(|w| std::f64::consts::PI * p.wheel_diameter_m(w))
    };
    let mut samples: Vec<DriveSample> = Vec::new();
    // The first sample of the filter's open correction window: when its gate
    // rejects the window, the whole window's samples are marked (see
    // `gate_rejected`).
    let mut window_start = 0;
    while let Some((timestamp, frame)) = frames.next_frame()? {
        let Outcome::Step(step, _) = pipeline.push(timestamp, &frame) else {
            continue;
        };
        let t0 = pipeline
            .first_frame_time()
            .map_or(0.0, |t| t.as_micros() as f64 / 1e6);
        samples.push(DriveSample {
            t_s: t0 + step.t_s,
            rear_left_m: step.rear_rev.0 * d_left,
            rear_right_m: step.rear_rev.1 * d_right,
            front_m: step
                .front_rev
                .map(|(l, r)| (l * d_front_left, r * d_front_right)),
            steer_angle_rad: step.steer_signal.map(|u| map.angle_rad(u)),
            yaw_rate_radps: step.yaw_rate_radps,
            rear_slip: false,
        });
        if step.correction != WindowOutcome::Open {
            if gate_rejected(step.correction) {
                for s in &mut samples[window_start..] {
                    s.rear_slip = true;
                }
            }
            window_start = samples.len();
        }
    }
    let mixed_buses = frames.finish(pipeline.stats().frames)?;
    if samples.len() < 2 {
        return Err(Error::Log(format!(
            "{log_name}: {} filter steps ({}); is this the configured car's log?",
            samples.len(),
            pipeline.stats()
        )));
    }
    let warnings = pipeline
        .plausibility_at_end()
        .0
        .iter()
        .map(ToString::to_string)
        .collect();
    Ok(DriveLog {
        warnings,
        samples,
        stats: pipeline.stats().to_string(),
        malformed: frames.malformed(),
        mixed_buses,
    })
}

/// Whether a closed correction window's rear wheel distances must stay out
/// of a drive's reckoning: whenever the filter's gate found the axles
/// disagreeing, whichever it then blamed. A gate that blames the front
/// axle may be wrong: both rear wheels locking together under braking look
/// to it like two front wheels turning too far (the multi-body drives of
/// seed 108 lock both rears for 1.1 s at 30 s; the gate kept the rear, the
/// fit reckoned across the 8 m they did not read and its residual of
/// 2.7 m refused the whole calibration). A wrongly marked window costs the
/// fit only a new segment's start — while marks are sparse.
///
/// Not [`WindowOutcome::Disagreed`]: the yaw-rate-aided estimator's gate
/// between the wheels' turn and the gyro's, with no wheel seen slipping
/// (its slip test catches a lock or a spin). A rear tyre whose size
/// changed makes every turning window disagree; marked, they cut the drive
/// into pieces of fewer than three fixes, and the drift watch, whose job
/// that change is, could not refit at all (the multi-body Escort of seed
/// 124, its rear-left tyre 0.5 % smaller from 600 s on: the refits of 780
/// and 840 s found no segment, the flag came at 960 s, 3.6 km after the
/// change).
pub fn gate_rejected(outcome: WindowOutcome) -> bool {
    matches!(
        outcome,
        WindowOutcome::RejectedUsedFront | WindowOutcome::RejectedKeptRear
    )
}

/// The quality gate of a drive's commit from the configuration's limits
/// (`[calibration]`), the tread's relative to `rear_tread_m`.
pub fn drive_gate(c: &canodom_pipeline::config::CalibrationConfig, rear_tread_m: f64) -> DriveGate {
    DriveGate {
        speed_scale: c.max_speed_scale_std,
        rear_ratio: c.max_ratio_std,
        steer_offset_rad: c.max_steer_offset_std_rad,
        steer_gain: c.max_steer_gain_std_rel,
        yaw_bias_radps: c.max_yaw_bias_std_radps,
        yaw_scale: c.max_yaw_scale_std,
        rear_tread: c.max_tread_std_m / rear_tread_m,
        max_residual_m: c.max_fix_residual_m,
        max_fix_sigma_m: c.max_fix_sigma_m,
        max_down_weighted_share: c.max_down_weighted_share,
    }
}

/// A drive calibrated against its fixes.
pub struct DriveFit {
    /// The fit: each parameter with its σ and whether the drive told it.
    pub calibration: DriveCalibration,
    /// The values in use during the drive (the configured set without a parameter file).
    pub base: ParamValues,
    /// The calibrated values: the fit applied to `base`, what it could not
    /// tell or the quality gate refused held.
    pub values: ParamValues,
    /// What the quality gate refused, and why (the previous value is kept).
    pub refused: Vec<GateRefusal>,
    /// The fixes within the log's time, which the fit used.
    pub fixes: Vec<Fix>,
    /// The fixes outside the log's time, left out.
    pub fixes_outside: usize,
    /// The first and last filter step's time on the log's clock, s.
    pub span_s: (f64, f64),
    /// Why the calibrated set is outside the configured bounds (`[calibration]
    /// bounds_rel`, ...), if it is: then it is not to be committed.
    pub out_of_bounds: Option<String>,
}

/// Fits `drive` to the fixes of `all_fixes` within its time with `options`
/// (the latency estimated or given, the loss, ...).
///
/// # Errors
/// [`Error::Calibration`] when the fit fails (too few fixes in the log, ...).
pub fn fit_drive(
    config: &Config,
    base: ParamValues,
    drive: &DriveLog,
    all_fixes: &[Fix],
    what: &str,
    options: &DriveOptions,
) -> Result<DriveFit> {
    fit_samples(config, base, &drive.samples, all_fixes, what, options)
}

/// [`fit_drive`] on a drive's samples (all of them, or those up to a time:
/// [`crate::online`]).
///
/// # Errors
/// [`Error::Calibration`] when the fit fails (too few fixes in the samples' time, ...).
pub fn fit_samples(
    config: &Config,
    base: ParamValues,
    samples: &[DriveSample],
    all_fixes: &[Fix],
    what: &str,
    options: &DriveOptions,
) -> Result<DriveFit> {
    let first = samples.first().map_or(0.0, |s| s.t_s);
    let last = samples.last().map_or(0.0, |s| s.t_s);
    let fixes: Vec<Fix> = all_fixes
        .iter()
        .copied()
        .filter(|f| f.t_s >= first && f.t_s <= last)
        .collect();
    let model = DriveModel {
        rear_tread_m: base.rear_tread_m,
        wheelbase_m: config.params.wheelbase_m(),
    };
    let mut calibration = calibrate_drive_with(samples, &fixes, &model, options)
        .map_err(|e| Error::Calibration(format!("calibration of {what} failed: {e}")))?;
    let refused = apply_gate(
        &mut calibration,
        &drive_gate(&config.calibration, base.rear_tread_m),
    );
    let values = calibrated_values(&base, &calibration);
    let out_of_bounds = config
        .calibration
        .bounds
        .check(&values)
        .err()
        .map(|e| e.to_string());
    Ok(DriveFit {
        calibration,
        base,
        values,
        refused,
        fixes_outside: all_fixes.len() - fixes.len(),
        fixes,
        span_s: (first, last),
        out_of_bounds,
    })
}

/// Reads position fixes from `path`: a CSV in local metres
/// (`t_unix_s,x_m,y_m[,heading_rad]`), a CSV of `t_unix_s,lat_deg,lon_deg[,alt_m]`
/// or an NMEA 0183 log (GGA/RMC), told apart by content ([`crate::fixes`]).
///
/// # Errors
/// The file cannot be read or is not text, or it is in none of the formats,
/// or a line is not a fix ([`Error::Calibration`] naming the format seen and the line).
pub fn read_fixes(path: &std::path::Path) -> Result<Vec<Fix>> {
    let bytes = std::fs::read(path).map_err(|source| Error::File {
        path: crate::shown(path),
        what: "read the fixes",
        source,
    })?;
    let name = path.display().to_string();
    let text = String::from_utf8(bytes).map_err(|_| {
        Error::Calibration(format!(
            "{name}: not text (a receiver's binary log, UBX or SBF?): give the fixes as NMEA 0183 \
             GGA/RMC, a CSV t_unix_s,lat_deg,lon_deg or a CSV t_unix_s,x_m,y_m"
        ))
    })?;
    Ok(crate::fixes::parse_fixes_any(&text, &name)?.0)
}

#[cfg(test)]
mod tests {
    use super::gate_rejected;
    use canodom_fusion::ekf::WindowOutcome;

    #[test]
    fn only_a_window_whose_wheels_may_have_slipped_is_kept_out_of_the_fit() {
        // Either consensus action may follow a slip the gate blamed on the
        // wrong axle; the gyro-aided gate's disagreement follows a tyre
        // whose size changed as well, in every turning window.
        assert!(gate_rejected(WindowOutcome::RejectedUsedFront));
        assert!(gate_rejected(WindowOutcome::RejectedKeptRear));
        for kept in [
            WindowOutcome::Disagreed,
            WindowOutcome::Accepted,
            WindowOutcome::Open,
            WindowOutcome::RearOnly,
            WindowOutcome::NoFront,
        ] {
            assert!(!gate_rejected(kept), "{kept:?}");
        }
    }
}
