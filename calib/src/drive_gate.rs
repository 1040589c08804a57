//! The quality gate before a drive's calibration is committed (issue #31):
//! each estimate only with its σ below its limit, and only from a plausible fit.

use crate::drive::{DriveCalibration, Estimate, GateRefusal};
use std::f64::consts::PI;

/// The quality a drive's fit must show before its values are committed
/// (issue #31): each parameter's σ below its limit, and the fit as a whole
/// plausible. The limits state what a user needs of a committed value, not
/// what a fit reaches.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriveGate {
    /// Largest σ of the speed scale (relative).
    pub speed_scale: f64,
    /// Largest σ of the rear ratio correction (relative).
    pub rear_ratio: f64,
    /// Largest σ of the steering offset, rad.
    pub steer_offset_rad: f64,
    /// Largest σ of the steering gain correction (relative).
    pub steer_gain: f64,
    /// Largest σ of the yaw-rate bias, rad/s.
    pub yaw_bias_radps: f64,
    /// Largest σ of the yaw-rate scale (relative).
    pub yaw_scale: f64,
    /// Largest σ of the rear tread correction (relative).
    pub rear_tread: f64,
    /// The reckoning's own error at the fixes that a right configuration
    /// may leave beyond the fixes' noise, metres (weighted RMS of the best
    /// source, added in quadrature to what the noise explains, see
    /// [`DriveGate::residual_limit_m`]): past the sum the reckoning and the
    /// fixes disagree (a wrong configuration, a wrong log) and nothing is
    /// committed.
    pub max_residual_m: f64,
    /// The largest 1σ per axis of the fixes, metres, that the residual gate
    /// and the misfit check allow for: a σ the fixes state or the fit
    /// estimates above it is taken as this, so noisy fixes, or residuals
    /// that only look like noise, cannot excuse any residual.
    pub max_fix_sigma_m: f64,
    /// Largest share of fixes the robust loss may down-weight: past it the
    /// "outliers" are the rule and nothing is committed.
    pub max_down_weighted_share: f64,
}

impl Default for DriveGate {
    /// 0.2 %, 0.2 %, 0.5°, 2 %, 0.05°/s, 0.25 %, 0.5 %; 2 m over the
    /// noise of fixes of σ up to 3 m; a quarter of the fixes:
    /// `[calibration]`'s defaults (pipeline::config), which a live or
    /// offline commit uses.
    fn default() -> Self {
        Self {
            speed_scale: 0.002,
            rear_ratio: 0.002,
            steer_offset_rad: 0.5 * PI / 180.0,
            steer_gain: 0.02,
            yaw_bias_radps: 0.05 * PI / 180.0,
            yaw_scale: 0.0025,
            rear_tread: 0.005,
            max_residual_m: 2.0,
            max_fix_sigma_m: 3.0,
            max_down_weighted_share: 0.25,
        }
    }
}

impl DriveGate {
    /// The fixes' σ per axis the gate allows for, metres: `cal`'s, at most
    /// [`DriveGate::max_fix_sigma_m`].
    pub fn noise_sigma_m(&self, cal: &DriveCalibration) -> f64 {
        // A NaN σ allows nothing.
        let s = cal.fixes_sigma_m;
        if s.is_finite() {
            s.clamp(0.0, self.max_fix_sigma_m)
        } else {
            0.0
        }
    }

    /// The largest weighted RMS residual at the fixes, metres, that the
    /// fixes' noise and `allowance_m` of the reckoning's own error explain:
    /// `√(2σ² + allowance²)`, σ the fixes' per axis
    /// ([`DriveGate::noise_sigma_m`]). The residual is horizontal (both
    /// axes), so noise of σ per axis leaves `2σ²` of it squared; the
    /// reckoning's error is independent of the receiver's noise, so the two
    /// add in quadrature. Fixes of σ 1.5 m leave ~2.1 m after a right fit:
    /// the limit is then 2.9 m with the default 2 m, 4.7 m at σ 3 m.
    pub fn residual_limit_m(&self, cal: &DriveCalibration, allowance_m: f64) -> f64 {
        let sigma = self.noise_sigma_m(cal);
        2.0_f64
            .mul_add(sigma * sigma, allowance_m * allowance_m)
            .sqrt()
    }

    /// The fixes' noise as a refusal states it.
    fn noise_text(&self, cal: &DriveCalibration) -> String {
        let how = if cal.fixes_sigma_stated {
            "stated by the fixes"
        } else {
            "estimated from the residuals"
        };
        let sigma = self.noise_sigma_m(cal);
        if sigma < cal.fixes_sigma_m || !cal.fixes_sigma_m.is_finite() {
            format!(
                "σ {:.2} m per axis {how}, taken as max_fix_sigma_m {sigma:.2} m",
                cal.fixes_sigma_m
            )
        } else {
            format!("σ {sigma:.2} m per axis {how}")
        }
    }
}

/// Why the fit as a whole is not plausible (None: it is): its residual
/// beyond what the fixes' noise and the allowance explain, or too many
/// fixes down-weighted.
fn whole_refusal(cal: &DriveCalibration, gate: &DriveGate) -> Option<String> {
    let best_rms = cal
        .weighted_rms_m
        .iter()
        .flatten()
        .copied()
        .fold(f64::INFINITY, f64::min);
    let share = cal.down_weighted.len() as f64 / cal.fixes_used.max(1) as f64;
    let limit = gate.residual_limit_m(cal, gate.max_residual_m);
    // A NaN residual fails too.
    if best_rms.partial_cmp(&limit) != Some(std::cmp::Ordering::Less) && best_rms != limit {
        Some(format!(
            "the fit's residual at the fixes is {best_rms:.2} m (weighted RMS of the best source), \
             above the {limit:.2} m that the fixes' noise ({}) and max_fix_residual_m's {:.2} m \
             explain: the reckoning and the fixes disagree (configuration, log or fixes wrong?)",
            gate.noise_text(cal),
            gate.max_residual_m
        ))
    } else if share > gate.max_down_weighted_share {
        Some(format!(
            "{} of {} fixes were down-weighted ({:.0} %), more than {:.0} %: the fixes are not \
             a receiver's with a few jumps",
            cal.down_weighted.len(),
            cal.fixes_used,
            100.0 * share,
            100.0 * gate.max_down_weighted_share
        ))
    } else {
        None
    }
}

/// Applies `gate` to `cal`: every estimate that fails it is marked not
/// observable, so [`calibrated_values`] keeps the previous value; the
/// refusals say which and why (empty: everything the drive told passes).
///
/// [`calibrated_values`]: crate::drive::calibrated_values
pub fn apply_gate(cal: &mut DriveCalibration, gate: &DriveGate) -> Vec<GateRefusal> {
    let mut refusals = Vec::new();
    let whole = whole_refusal(cal, gate);
    let deg = 180.0 / PI;
    let entries: [(&'static str, Option<&mut Estimate>, f64, &str, f64); 7] = [
        (
            "speed scale",
            Some(&mut cal.speed_scale),
            gate.speed_scale,
            "",
            1.0,
        ),
        (
            "rear ratio (R/L)",
            Some(&mut cal.rear_ratio),
            gate.rear_ratio,
            "",
            1.0,
        ),
        (
            "steering offset",
            cal.steer_offset_rad.as_mut(),
            gate.steer_offset_rad,
            "°",
            deg,
        ),
        (
            "steering gain",
            cal.steer_gain.as_mut(),
            gate.steer_gain,
            "",
            1.0,
        ),
        (
            "yaw-rate bias",
            cal.yaw_bias_radps.as_mut(),
            gate.yaw_bias_radps,
            "°/s",
            deg,
        ),
        (
            "yaw-rate scale",
            cal.yaw_scale.as_mut(),
            gate.yaw_scale,
            "",
            1.0,
        ),
        (
            "rear tread (rel.)",
            Some(&mut cal.rear_tread),
            gate.rear_tread,
            "",
            1.0,
        ),
    ];
    for (parameter, estimate, limit, unit, k) in entries {
        let Some(e) = estimate.filter(|e| e.observable) else {
            continue;
        };
        let reason = match &whole {
            Some(why) => why.clone(),
            // A NaN σ fails too.
            None if e.sigma.partial_cmp(&limit) != Some(std::cmp::Ordering::Less)
                && e.sigma != limit =>
            {
                format!(
                    "σ {:.6}{unit} above the limit {:.6}{unit}",
                    e.sigma * k,
                    limit * k
                )
            }
            None => continue,
        };
        e.observable = false;
        refusals.push(GateRefusal { parameter, reason });
    }
    cal.refused.extend(refusals.iter().cloned());
    refusals
}

pub use crate::drive::MISFIT_RMS_M;

/// The heading sources whose fit leaves more at the fixes than their noise
/// and [`MISFIT_RMS_M`] explain (`gate` caps the noise): (source, the
/// `[signals]` keys to check, residual RMS m).
pub fn misfits(cal: &DriveCalibration, gate: &DriveGate) -> Vec<(&'static str, &'static str, f64)> {
    const SOURCES: [(&str, &str); 3] = [
        (
            "rear wheels",
            "signals.rear_left / rear_right, wheel_kind, direction",
        ),
        ("yaw rate", "signals.yaw_rate (its sign and unit)"),
        (
            "steering",
            "signals.steering (its sign and unit), steering_kind, vehicle.steering_ratio",
        ),
    ];
    let limit = gate.residual_limit_m(cal, MISFIT_RMS_M);
    SOURCES
        .iter()
        // The robust RMS (a receiver's jumps, down-weighted by the fit, are
        // not a misfit of the configuration) of the source's own best fit.
        .zip(cal.own_fit_rms_m)
        .filter_map(|(&(source, keys), rms)| {
            rms.filter(|&r| r > limit || !r.is_finite())
                .map(|r| (source, keys, r))
        })
        .collect()
}

/// The refusal of a misfit, and how it differs from a parameter the drive
/// does not observe.
pub fn misfit_refusal(found: &[(&str, &str, f64)]) -> String {
    let each: Vec<String> = found
        .iter()
        .map(|(source, keys, rms)| {
            format!("the {source} leave {rms:.1} m RMS at the fixes (check {keys})")
        })
        .collect();
    format!(
        "not committed: a misfit: {}. More than {MISFIT_RMS_M} m beyond what the fixes' own \
         error explains, after the fit: no parameter values fit this drive, so the configuration is likely wrong \
         (`canodom replay` names what it suspects). This is not a parameter the drive does not \
         tell: such a parameter is held at its value (\"held\" above) and the rest is committed",
        each.join("; ")
    )
}

#[cfg(test)]
mod misfit_tests {
    use super::*;

    fn estimate(value: f64, observable: bool) -> Estimate {
        Estimate {
            value,
            sigma: 1e-4,
            observable,
        }
    }

    #[test]
    fn a_misfit_is_refused_and_told_apart_from_a_held_parameter() {
        // The case: "yaw-rate bias held" beside a 74 m residual.
        let cal = DriveCalibration {
            speed_scale: estimate(1.0, true),
            rear_ratio: estimate(1.0, true),
            steer_offset_rad: Some(estimate(0.0, true)),
            steer_gain: Some(estimate(1.0, true)),
            yaw_bias_radps: Some(estimate(0.0, false)),
            yaw_scale: Some(estimate(1.0, true)),
            yaw_bias_noise_sigma_radps: None,
            fixes_used: 30,
            distance_m: 700.0,
            residual_rms_m: [Some(1.2), Some(74.0), Some(MISFIT_RMS_M)],
            rear_tread: estimate(1.0, false),
            turns_rad: [0.5, 0.0],
            fixes_latency_s: estimate(0.2, true),
            latency_given: false,
            down_weighted: Vec::new(),
            weighted_rms_m: [Some(1.2), Some(74.0), Some(MISFIT_RMS_M)],
            own_fit_rms_m: [Some(1.2), Some(74.0), Some(MISFIT_RMS_M)],
            fixes_sigma_m: 0.8,
            fixes_sigma_stated: false,
            refused: Vec::new(),
        };
        let gate = DriveGate::default();
        let found = misfits(&cal, &gate);
        assert_eq!(found.len(), 1, "{found:?}");
        assert_eq!(found[0].0, "yaw rate");
        let text = misfit_refusal(&found);
        assert!(
            text.starts_with("not committed: a misfit: the yaw rate leave 74.0 m RMS")
                && text.contains("signals.yaw_rate")
                && text.contains("is held at its value"),
            "{text}"
        );
        let nan = DriveCalibration {
            own_fit_rms_m: [Some(f64::NAN), None, None],
            ..cal
        };
        assert_eq!(misfits(&nan, &gate)[0].0, "rear wheels");
    }
}
