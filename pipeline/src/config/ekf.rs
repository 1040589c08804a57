//! The `[ekf]` table's optional keys mapped onto [`EkfConfig`]: one row per
//! key with its unit and bound, a long table apart from the rest because it
//! grows whenever the filter gains a setting.

use super::ConfigError;
use super::raw::RawEkf;
use super::validator::Validator;
use canodom_fusion::ekf::EkfConfig;

impl Validator<'_> {
    /// The `[ekf]` keys beyond the wheel noises and the gate threshold:
    /// gate, blending, learning and the yaw-rate-aided estimator. Angles are
    /// written in degrees (deg/s for rates), relative values as fractions.
    // One table row per key: splitting it would only scatter the table.
    #[allow(clippy::too_many_lines)]
    pub(super) fn ekf_choices(&self, e: &RawEkf, ekf: &mut EkfConfig) -> Result<(), ConfigError> {
        let deg = |d: f64| d.to_radians();
        // (key, value, field, must be > 0 rather than >= 0, to radians)
        let numbers: [(&str, Option<f64>, &mut f64, bool, bool); 23] = [
            (
                "front_scale_sigma",
                e.front_scale_sigma,
                &mut ekf.front_scale_sigma,
                false,
                false,
            ),
            (
                "min_slip_ratio",
                e.min_slip_ratio,
                &mut ekf.min_slip_ratio,
                false,
                false,
            ),
            (
                "yaw_sigma_deg_s",
                e.yaw_sigma_deg_s,
                &mut ekf.yaw_sigma_radps,
                true,
                true,
            ),
            (
                "yaw_bias_walk_deg_s_per_sqrt_s",
                e.yaw_bias_walk_deg_s_per_sqrt_s,
                &mut ekf.yaw_bias_walk_radps,
                false,
                true,
            ),
            (
                "yaw_bias_sigma_deg_s",
                e.yaw_bias_sigma_deg_s,
                &mut ekf.yaw_bias_sigma_radps,
                true,
                true,
            ),
            (
                "yaw_scale_sigma",
                e.yaw_scale_sigma,
                &mut ekf.yaw_scale_sigma,
                false,
                false,
            ),
            (
                "rear_ratio_sigma",
                e.rear_ratio_sigma,
                &mut ekf.rear_ratio_sigma,
                true,
                false,
            ),
            (
                "ratio_walk",
                e.ratio_walk,
                &mut ekf.ratio_walk,
                false,
                false,
            ),
            (
                "tread_sigma",
                e.tread_sigma,
                &mut ekf.tread_sigma,
                true,
                false,
            ),
            (
                "tread_turn_sigma",
                e.tread_turn_sigma,
                &mut ekf.tread_turn_sigma,
                false,
                false,
            ),
            (
                "wheel_turn_sigma_deg",
                e.wheel_turn_sigma_deg,
                &mut ekf.wheel_turn_sigma_rad,
                true,
                true,
            ),
            (
                "distance_scale_sigma",
                e.distance_scale_sigma,
                &mut ekf.distance_scale_sigma,
                false,
                false,
            ),
            (
                "still_min_s",
                e.still_min_s,
                &mut ekf.still_min_s,
                false,
                false,
            ),
            (
                "aided_window_s",
                e.aided_window_s,
                &mut ekf.aided_window_s,
                true,
                false,
            ),
            (
                "slip_accel_sigma",
                e.slip_accel_sigma,
                &mut ekf.slip_accel_sigma,
                false,
                false,
            ),
            (
                "straight_yaw_sigma_deg_s",
                e.straight_yaw_sigma_deg_s,
                &mut ekf.straight_yaw_sigma_radps,
                false,
                true,
            ),
            (
                "straight_max_deg_s",
                e.straight_max_deg_s,
                &mut ekf.straight_max_radps,
                true,
                true,
            ),
            (
                "straight_max_steer_deg",
                e.straight_max_steer_deg,
                &mut ekf.straight_max_steer_rad,
                true,
                true,
            ),
            (
                "straight_min_s",
                e.straight_min_s,
                &mut ekf.straight_min_s,
                false,
                false,
            ),
            (
                "straight_min_speed_mps",
                e.straight_min_speed_mps,
                &mut ekf.straight_min_speed_mps,
                false,
                false,
            ),
            (
                "max_accel_mps2",
                e.max_accel_mps2,
                &mut ekf.max_accel_mps2,
                true,
                false,
            ),
            (
                "slide_decel_mps2",
                e.slide_decel_mps2,
                &mut ekf.slide_decel_mps2,
                true,
                false,
            ),
            (
                "slide_decel_sigma_mps2",
                e.slide_decel_sigma_mps2,
                &mut ekf.slide_decel_sigma_mps2,
                false,
                false,
            ),
        ];
        for (name, value, field, strictly_positive, in_degrees) in numbers {
            let Some(v) = value else { continue };
            let key = format!("ekf.{name}");
            let v = if strictly_positive {
                self.positive(&key, v)?
            } else {
                self.non_negative(&key, v)?
            };
            *field = if in_degrees { deg(v) } else { v };
        }
        if let Some(s) = e.yaw_gate_sigma {
            ekf.yaw_gate_sigma = self.positive("ekf.yaw_gate_sigma", s)?;
        }
        if let Some(b) = e.blend_accepted {
            ekf.blend_accepted = b;
        }
        if let Some(b) = e.learn_wheel_scales {
            ekf.learn_wheel_scales = b;
        }
        if let Some(a) = &e.gate_action {
            use canodom_fusion::ekf::GateAction;
            ekf.gate_action = match a.as_str() {
                "consensus" => GateAction::Consensus,
                "use_front" => GateAction::UseFront,
                "keep_rear" => GateAction::KeepRear,
                _ => {
                    return Err(self.err(
                        "ekf.gate_action",
                        "\"consensus\", \"use_front\" or \"keep_rear\"",
                        format!("{a:?}"),
                    ));
                }
            };
        }
        if let Some(d) = e.steer_offset_drift_deg {
            if e.learn_steer_offset == Some(false) {
                return Err(self.err(
                    "ekf.steer_offset_drift_deg",
                    "no value with learn_steer_offset = false (the offset is not learnt)",
                    d,
                ));
            }
            ekf.steer_offset_drift_rad = Some(
                self.non_negative("ekf.steer_offset_drift_deg", d)?
                    .to_radians(),
            );
        }
        if let Some(d) = e.front_scale_drift {
            ekf.front_scale_drift = Some(self.non_negative("ekf.front_scale_drift", d)?);
        }
        Ok(())
    }
}
