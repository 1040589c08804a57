//! What a drive calibration finds: each parameter's estimate with its σ
//! and whether the drive told it, the fit's diagnostics, and the parameter
//! values that result when the observable corrections are applied.

use crate::history::ParamValues;

/// One estimated parameter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// The estimate; the value in use (1 or 0) when not observable.
    pub value: f64,
    /// Its posterior standard deviation.
    pub sigma: f64,
    /// Whether the drive told this parameter (posterior σ well below the
    /// prior σ). When false the daemon keeps the value in use.
    pub observable: bool,
}

/// A parameter the gate kept at its previous value, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct GateRefusal {
    /// The parameter (as the report names it).
    pub parameter: &'static str,
    /// Why, with the numbers.
    pub reason: String,
}

/// A fix the robust loss down-weighted: it disagrees with every source's
/// reckoning far beyond the others' scatter (a receiver's jump).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DownWeighted {
    /// The fix's time (its stamp, on the log's clock).
    pub t_s: f64,
    /// Its position residual against the source that agrees best, metres.
    pub residual_m: f64,
    /// Its weight in that source (1 = in full).
    pub weight: f64,
}

/// The result of [`calibrate_drive`](super::calibrate_drive).
#[derive(Debug, Clone, PartialEq)]
pub struct DriveCalibration {
    /// Multiplies the mean of the two rear distances (both rear diameters) — 1 = unchanged.
    pub speed_scale: Estimate,
    /// Right/left rear distance ratio correction: k_R/k_L (k_R = s·2r/(1+r),
    /// k_L = s·2/(1+r)) — 1 = unchanged.
    pub rear_ratio: Estimate,
    /// φ_true = steer_gain · φ_measured + steer_offset_rad (None when no
    /// sample had steering).
    pub steer_offset_rad: Option<Estimate>,
    /// See `steer_offset_rad`.
    pub steer_gain: Option<Estimate>,
    /// The sensor model: ω_measured = yaw_scale · ω_true + yaw_bias_radps
    /// (None without yaw-rate samples).
    pub yaw_bias_radps: Option<Estimate>,
    /// See `yaw_bias_radps`.
    pub yaw_scale: Option<Estimate>,
    /// The yaw-rate bias's σ from the fixes' and the inputs' noise alone
    /// (the sandwich), rad/s: the live filter's prior on the bias it learns
    /// next. `yaw_bias_radps`'s σ is at least the jackknife's as well, what
    /// the bias's effective value varies along the drive; the filter
    /// follows that variation with its own random walk, and starting it
    /// that unsure sent the RAV4's calibrated rest after 45 s 0.80 % off
    /// instead of 0.65 % (calibration-math §14). None without yaw rate.
    pub yaw_bias_noise_sigma_radps: Option<f64>,
    /// The effective rear tread's correction (multiplies the tread in use):
    /// held at 1, not observable, on a drive without turns both ways.
    pub rear_tread: Estimate,
    /// The turning of the drive's used part (rear wheels), left and right, radians.
    pub turns_rad: [f64; 2],
    /// The fixes' latency on the log's clock: a fix stamped `t` describes
    /// the vehicle at `t − latency`. Observable and with its σ when
    /// estimated; the given value with σ 0 when given.
    pub fixes_latency_s: Estimate,
    /// Whether the latency was given rather than estimated.
    pub latency_given: bool,
    /// The fixes the robust loss down-weighted, in time order.
    pub down_weighted: Vec<DownWeighted>,
    /// The weighted RMS position residual of each source (what the fixes it
    /// kept say), metres; None for a source without data.
    pub weighted_rms_m: [Option<f64>; 3],
    /// Each source's weighted RMS position residual, metres, judged by the
    /// misfit check: the joint fit's (`weighted_rms_m`), or, for a source
    /// that leaves more than [`MISFIT_RMS_M`](super::MISFIT_RMS_M)
    /// there, its reckoning's alone with its own parameters refitted (the
    /// other sources off): what no values of that source remove.
    pub own_fit_rms_m: [Option<f64>; 3],
    /// The fixes' 1σ horizontal error per axis, metres: the RMS of what
    /// their source stated ([`Fix::sigma_m`](super::Fix::sigma_m)) over the
    /// fixes the fit kept, or, when no fix states one, estimated from the
    /// residuals of the source that fits best (the median, so that jumps
    /// and a stretch the reckoning gets wrong do not pass for noise). The
    /// quality gate allows the residual this explains.
    pub fixes_sigma_m: f64,
    /// Whether `fixes_sigma_m` is what the fixes' source stated (else estimated).
    pub fixes_sigma_stated: bool,
    /// What the quality gate (`drive_gate`) refused, and why (empty
    /// before it ran or when everything passed).
    pub refused: Vec<GateRefusal>,
    /// Fixes used (those in segments of at least three fixes).
    pub fixes_used: usize,
    /// Distance driven over the used segments, with the fitted scale.
    pub distance_m: f64,
    /// The RMS position residual at the fixes after the fit of each heading
    /// source (rear wheels, yaw rate, steering), metres; None for a source
    /// without data.
    pub residual_rms_m: [Option<f64>; 3],
}

/// The parameter values after the calibration `cal` of a drive recorded
/// with `base`: every observable correction applied, the rest as in `base`.
pub fn calibrated_values(base: &ParamValues, cal: &DriveCalibration) -> ParamValues {
    let mut v = *base;
    let used = |e: &Estimate, held: f64| if e.observable { e.value } else { held };
    let s = used(&cal.speed_scale, 1.0);
    let r = used(&cal.rear_ratio, 1.0);
    v.rear_left_diameter_m *= s * 2.0 / (1.0 + r);
    v.rear_right_diameter_m *= s * 2.0 * r / (1.0 + r);
    v.rear_tread_m *= used(&cal.rear_tread, 1.0);
    // φ = g·(gain·u + offset) + o.
    let g = cal.steer_gain.map_or(1.0, |e| used(&e, 1.0));
    let o = cal.steer_offset_rad.map_or(0.0, |e| used(&e, 0.0));
    v.steering_gain *= g;
    v.steering_offset_rad = g * v.steering_offset_rad + o;
    // The samples carried ω_raw / c0 (c0 the scale in use): ω_raw = c0·c·ω + c0·b.
    let c0 = base.yaw_rate_scale.unwrap_or(1.0);
    let b0 = base.yaw_rate_bias_radps.unwrap_or(0.0);
    if let (Some(bias), Some(scale)) = (cal.yaw_bias_radps, cal.yaw_scale) {
        let c = used(&scale, 1.0);
        if scale.observable || bias.observable {
            v.yaw_rate_scale = Some(c0 * c);
        }
        if bias.observable {
            v.yaw_rate_bias_radps = Some(c0 * bias.value);
            // The filter's prior: the noise's σ (see
            // `DriveCalibration::yaw_bias_noise_sigma_radps`).
            let sigma = cal.yaw_bias_noise_sigma_radps.unwrap_or(bias.sigma);
            v.yaw_rate_bias_sigma_radps = Some(c0 * sigma);
        } else if scale.observable {
            v.yaw_rate_bias_radps = Some(b0);
        }
    }
    v
}
