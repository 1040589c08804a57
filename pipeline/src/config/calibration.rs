//! The `[calibration]` table: the live session's command id, bounds and
//! commit limits, and the bus's position fixes. Apart from `validate`
//! because it needs the nominal vehicle and the output's base id first.

use super::raw::{RawCalibration, RawDrift, RawFixes};
use super::validator::Validator;
use super::{
    CalibrationConfig, ConfigError, DriftWatchConfig, FixSignals, beside, default_param_file,
};
use canodom_dbc::Database;
use canodom_fusion::VehicleParams;
use canodom_protocol::own_dbc::BaseId;

impl Validator<'_> {
    pub(super) fn calibration(
        &self,
        c: &RawCalibration,
        base_id: BaseId,
        params: &VehicleParams,
    ) -> Result<CalibrationConfig, ConfigError> {
        use canodom_can::frame::FrameId;
        let command_id = match c.command_id {
            None => canodom_protocol::own_dbc::OwnFrame::CalibCmd.id(base_id),
            Some(raw) => {
                let id = if base_id.id().is_extended() {
                    FrameId::extended(raw).ok()
                } else {
                    u16::try_from(raw)
                        .ok()
                        .and_then(|r| FrameId::standard(r).ok())
                };
                id.ok_or_else(|| {
                    self.err(
                        "calibration.command_id",
                        "an id of the base id's format (11 or 29 bits)",
                        format!("{raw:#x}"),
                    )
                })?
            }
        };
        let rel = c.bounds_rel;
        if !(rel.is_finite() && rel > 0.0 && rel < 1.0) {
            return Err(self.err("calibration.bounds_rel", "a fraction in (0, 1)", rel));
        }
        let offset_deg =
            self.positive("calibration.max_steer_offset_deg", c.max_steer_offset_deg)?;
        if c.ack_timeout_ms == 0 {
            return Err(self.err("calibration.ack_timeout_ms", "an integer >= 1", 0));
        }
        if c.writeback_retries > 6 {
            // WB_ATTEMPTS is 3 bits: 1 + retries must fit 7.
            return Err(self.err(
                "calibration.writeback_retries",
                "an integer 0..=6",
                c.writeback_retries,
            ));
        }
        let param_file = match &c.param_file {
            Some(p) if p.as_os_str().is_empty() => {
                return Err(self.err("calibration.param_file", "a file path", "\"\""));
            }
            Some(p) => beside(self.file, p),
            None => default_param_file(self.file, self.state_directory.as_deref()),
        };
        let mut bounds = canodom_params::persist::ParamBounds::around(
            params.rear_tread_m(),
            params.rear_mean_diameter_m(),
            rel,
            offset_deg.to_radians(),
        );
        // The gain's bounds are around the configured map's gain, whatever its sign.
        let g = params.steering().gain;
        let (a, b) = (g * (1.0 - rel), g * (1.0 + rel));
        bounds.steering_gain = (a.min(b), a.max(b));
        bounds.steering_offset_rad = (
            params.steering().offset_rad - offset_deg.to_radians(),
            params.steering().offset_rad + offset_deg.to_radians(),
        );
        Ok(CalibrationConfig {
            param_file,
            command_id,
            arming_code: c.arming_code,
            bounds,
            max_tread_std_m: self.positive("calibration.max_tread_std_m", c.max_tread_std_m)?,
            max_ratio_std: self.positive("calibration.max_ratio_std", c.max_ratio_std)?,
            max_steer_gain_std_rel: self.positive(
                "calibration.max_steer_gain_std_rel",
                c.max_steer_gain_std_rel,
            )?,
            max_steer_offset_std_rad: self
                .positive(
                    "calibration.max_steer_offset_std_deg",
                    c.max_steer_offset_std_deg,
                )?
                .to_radians(),
            max_speed_scale_std: self
                .positive("calibration.max_speed_scale_std", c.max_speed_scale_std)?,
            max_yaw_bias_std_radps: self
                .positive("calibration.max_yaw_bias_std_dps", c.max_yaw_bias_std_dps)?
                .to_radians(),
            max_yaw_scale_std: self
                .positive("calibration.max_yaw_scale_std", c.max_yaw_scale_std)?,
            max_fix_residual_m: self
                .positive("calibration.max_fix_residual_m", c.max_fix_residual_m)?,
            max_fix_sigma_m: self.positive("calibration.max_fix_sigma_m", c.max_fix_sigma_m)?,
            max_down_weighted_share: self.positive(
                "calibration.max_down_weighted_share",
                c.max_down_weighted_share,
            )?,
            ack_timeout: std::time::Duration::from_millis(c.ack_timeout_ms),
            writeback_retries: c.writeback_retries,
            max_history: c.max_history.max(1),
            standstill_speed_mps: self
                .positive("calibration.standstill_speed_mps", c.standstill_speed_mps)?,
            standstill_time_s: self
                .positive("calibration.standstill_time_s", c.standstill_time_s)?,
            fixes: None,
            drift: self.drift(&c.drift)?,
            auto_commit: c.auto_commit,
        })
    }

    /// `[calibration.drift]`: every number positive, the refit window at
    /// least two refit intervals (a window shorter than the interval would
    /// leave fixes no refit sees).
    fn drift(&self, d: &RawDrift) -> Result<DriftWatchConfig, ConfigError> {
        use canodom_calib::drift::Param;
        let default = DriftWatchConfig::default();
        let mut judge = default.judge;
        let pick = |key: &str, v: Option<f64>, default: f64| match v {
            None => Ok(default),
            Some(v) => self.positive(key, v),
        };
        judge.k_sigma = pick("calibration.drift.k_sigma", d.k_sigma, judge.k_sigma)?;
        for (param, key, v, degrees) in [
            (
                Param::SpeedScale,
                "speed_scale_tol_rel",
                d.speed_scale_tol_rel,
                false,
            ),
            (
                Param::RearRatio,
                "rear_ratio_tol_rel",
                d.rear_ratio_tol_rel,
                false,
            ),
            (
                Param::RearTread,
                "rear_tread_tol_rel",
                d.rear_tread_tol_rel,
                false,
            ),
            (
                Param::SteerGain,
                "steer_gain_tol_rel",
                d.steer_gain_tol_rel,
                false,
            ),
            (
                Param::SteerOffset,
                "steer_offset_tol_deg",
                d.steer_offset_tol_deg,
                true,
            ),
            (Param::YawBias, "yaw_bias_tol_dps", d.yaw_bias_tol_dps, true),
            (
                Param::YawScale,
                "yaw_scale_tol_rel",
                d.yaw_scale_tol_rel,
                false,
            ),
            (
                Param::FrontRatio,
                "front_ratio_tol_rel",
                d.front_ratio_tol_rel,
                false,
            ),
        ] {
            let i = Param::ALL
                .iter()
                .position(|p| *p == param)
                .unwrap_or_default();
            if let Some(v) = v {
                let v = self.positive(&format!("calibration.drift.{key}"), v)?;
                judge.tolerance[i] = if degrees { v.to_radians() } else { v };
            }
        }
        let every_s = pick("calibration.drift.every_s", d.every_s, default.every_s)?;
        let window_s = pick("calibration.drift.window_s", d.window_s, default.window_s)?;
        if window_s < 2.0 * every_s {
            return Err(self.err(
                "calibration.drift.window_s",
                &format!("at least twice calibration.drift.every_s ({every_s} s)"),
                window_s,
            ));
        }
        Ok(DriftWatchConfig {
            judge,
            every_s,
            window_s,
        })
    }

    /// The `[calibration.fixes]` signals: `x` and `y`, or `latitude` and
    /// `longitude`, of one message.
    pub(super) fn fix_signals(
        &self,
        db: &Database,
        f: &RawFixes,
    ) -> Result<FixSignals, ConfigError> {
        let ((k1, p1), (k2, p2), geodetic) = match (&f.x, &f.y, &f.latitude, &f.longitude) {
            (Some(x), Some(y), None, None) => (
                ("calibration.fixes.x", x),
                ("calibration.fixes.y", y),
                false,
            ),
            (None, None, Some(lat), Some(lon)) => (
                ("calibration.fixes.latitude", lat),
                ("calibration.fixes.longitude", lon),
                true,
            ),
            _ => {
                return Err(self.err(
                    "calibration.fixes",
                    "either x and y (metres) or latitude and longitude (degrees)",
                    "another combination",
                ));
            }
        };
        let first = self.signal(db, k1, p1)?;
        let second = self.signal(db, k2, p2)?;
        if first.message_index != second.message_index {
            return Err(self.err(k2, &format!("a signal in the same message as {k1}"), p2));
        }
        Ok(FixSignals {
            message_index: first.message_index,
            first: first.handle,
            second: second.handle,
            geodetic,
        })
    }
}
