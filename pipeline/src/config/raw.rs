//! The configuration file as TOML gives it: one serde struct per table,
//! unknown keys refused and defaults filled in, so that a misspelt key is
//! an error rather than a setting silently left at its default.

use crate::signal_forms::{RawDirection, RawSignal};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// The file as written; every table refuses unknown keys.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawConfig {
    pub(super) can: RawCan,
    pub(super) vehicle: RawVehicle,
    pub(super) signals: RawSignals,
    #[serde(default)]
    pub(super) checks: BTreeMap<String, RawCheck>,
    #[serde(default)]
    pub(super) inputs: RawInputs,
    #[serde(default)]
    pub(super) ekf: RawEkf,
    #[serde(default)]
    pub(super) output: RawOutput,
    #[serde(default)]
    pub(super) calibration: RawCalibration,
    /// `None` without a `[security]` section (secure defaults differ: #33).
    #[serde(default)]
    pub(super) security: Option<crate::security::RawSecurity>,
    /// `[ros2]` (#43), kept as written: `canodom-ros2` reads it, so that the
    /// DDS stack stays out of this crate.
    #[serde(default)]
    pub(super) ros2: Option<toml::Table>,
    /// `[gnss]` (#46): a live GNSS source; off without it.
    #[serde(default)]
    pub(super) gnss: Option<super::gnss::RawGnss>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawCan {
    pub(super) interface: String,
    pub(super) dbc: PathBuf,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawVehicle {
    pub(super) wheelbase_m: f64,
    pub(super) rear_tread_m: f64,
    pub(super) front_tread_m: f64,
    pub(super) wheel_diameter_m: Option<f64>,
    pub(super) rear_left_diameter_m: Option<f64>,
    pub(super) rear_right_diameter_m: Option<f64>,
    pub(super) front_left_diameter_m: Option<f64>,
    pub(super) front_right_diameter_m: Option<f64>,
    pub(super) encoder_ticks_per_rev: Option<u32>,
    pub(super) steering_ratio: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawSignals {
    pub(super) rear_left: RawSignal,
    pub(super) rear_right: RawSignal,
    pub(super) front_left: RawSignal,
    pub(super) front_right: RawSignal,
    pub(super) steering: RawSignal,
    /// A second, finer steering signal added to `steering` (Toyota's `STEER_FRACTION`).
    pub(super) steering_fine: Option<String>,
    /// Optional in serde so that a missing one is named with its values.
    pub(super) wheel_kind: Option<String>,
    pub(super) steering_kind: Option<String>,
    /// The car's yaw-rate sensor (`KINEMATICS.YAW_RATE` on a Toyota), optional.
    pub(super) yaw_rate: Option<RawSignal>,
    /// The signal that says the car reverses (wheel speeds as magnitudes).
    pub(super) direction: Option<RawDirection>,
    /// +1 when the signal reads a left turn positive (ISO 8855), −1 when right.
    pub(super) yaw_rate_sign: Option<i64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawCheck {
    pub(super) counter: Option<String>,
    pub(super) checksum: Option<String>,
    pub(super) algorithm: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(super) struct RawInputs {
    pub(super) timeout_factor: f64,
    pub(super) default_period_ms: f64,
    pub(super) invalid_after_faults: u32,
    pub(super) trusted_after_frames: u32,
    pub(super) max_wheel_speed_mps: Option<f64>,
}

impl Default for RawInputs {
    fn default() -> Self {
        Self {
            timeout_factor: 3.0,
            default_period_ms: 10.0,
            invalid_after_faults: 3,
            trusted_after_frames: 5,
            max_wheel_speed_mps: None,
        }
    }
}

/// `[ekf]`: every key optional, absent ones keep `EkfConfig::new`'s value
/// (the meaning of each is on the `EkfConfig` field of the same name; the
/// examples list them with units and defaults).
#[derive(Debug, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct RawEkf {
    // Wheels and steering.
    pub(super) k_rear_m: Option<f64>,
    pub(super) k_front_m: Option<f64>,
    pub(super) steer_sigma_deg: Option<f64>,
    pub(super) steer_bias_sigma_deg: Option<f64>,
    pub(super) front_scale_sigma: Option<f64>,
    // Windows, gate and blending.
    pub(super) correct_every: Option<u32>,
    pub(super) gate_threshold: Option<f64>,
    pub(super) gate_enabled: Option<bool>,
    pub(super) gate_action: Option<String>,
    pub(super) min_slip_ratio: Option<f64>,
    pub(super) blend_accepted: Option<bool>,
    // Online learning of the steering offset and the front scale.
    pub(super) learn_steer_offset: Option<bool>,
    pub(super) steer_offset_drift_deg: Option<f64>,
    pub(super) front_scale_drift: Option<f64>,
    pub(super) learn_wheel_scales: Option<bool>,
    // The yaw-rate-aided estimator.
    pub(super) yaw_sigma_deg_s: Option<f64>,
    pub(super) yaw_bias_walk_deg_s_per_sqrt_s: Option<f64>,
    pub(super) yaw_bias_sigma_deg_s: Option<f64>,
    pub(super) yaw_scale_sigma: Option<f64>,
    pub(super) rear_ratio_sigma: Option<f64>,
    pub(super) ratio_walk: Option<f64>,
    pub(super) tread_sigma: Option<f64>,
    pub(super) tread_turn_sigma: Option<f64>,
    pub(super) wheel_turn_sigma_deg: Option<f64>,
    pub(super) distance_scale_sigma: Option<f64>,
    pub(super) still_min_s: Option<f64>,
    pub(super) aided_window_s: Option<f64>,
    pub(super) yaw_gate_sigma: Option<f64>,
    pub(super) slip_accel_sigma: Option<f64>,
    pub(super) straight_yaw_sigma_deg_s: Option<f64>,
    pub(super) straight_max_deg_s: Option<f64>,
    pub(super) straight_max_steer_deg: Option<f64>,
    pub(super) straight_min_s: Option<f64>,
    pub(super) straight_min_speed_mps: Option<f64>,
    // A slide on locked wheels (wheel-speed sensors).
    pub(super) max_accel_mps2: Option<f64>,
    pub(super) slide_decel_mps2: Option<f64>,
    pub(super) slide_decel_sigma_mps2: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(super) struct RawOutput {
    pub(super) base_id: u32,
    pub(super) extended: bool,
    pub(super) pose_rate_hz: f64,
    pub(super) publish_on_update: bool,
    pub(super) stats_interval_s: f64,
}

impl Default for RawOutput {
    fn default() -> Self {
        Self {
            base_id: canodom_protocol::own_dbc::DEFAULT_BASE_ID,
            extended: false,
            pose_rate_hz: 50.0,
            publish_on_update: false,
            stats_interval_s: 10.0,
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(super) struct RawCalibration {
    pub(super) param_file: Option<PathBuf>,
    pub(super) command_id: Option<u32>,
    pub(super) arming_code: Option<u8>,
    pub(super) bounds_rel: f64,
    pub(super) max_steer_offset_deg: f64,
    pub(super) max_tread_std_m: f64,
    pub(super) max_ratio_std: f64,
    pub(super) max_steer_gain_std_rel: f64,
    pub(super) max_steer_offset_std_deg: f64,
    pub(super) max_speed_scale_std: f64,
    pub(super) max_yaw_bias_std_dps: f64,
    pub(super) max_yaw_scale_std: f64,
    pub(super) max_fix_residual_m: f64,
    pub(super) max_fix_sigma_m: f64,
    pub(super) max_down_weighted_share: f64,
    pub(super) ack_timeout_ms: u64,
    pub(super) writeback_retries: u32,
    pub(super) max_history: usize,
    pub(super) standstill_speed_mps: f64,
    pub(super) standstill_time_s: f64,
    /// Position fixes on the bus (GNSS on CAN) for calibration from a drive.
    pub(super) fixes: Option<RawFixes>,
    /// `[calibration.drift]`: the online calibration's refits and the drift watch.
    pub(super) drift: RawDrift,
    /// Commit the drift watch's learnt set at a standstill by itself.
    pub(super) auto_commit: bool,
}

/// `[calibration.drift]` (#46 item 3); the defaults are
/// `canodom_calib::drift::DriftConfig::default`'s and `DriftWatchConfig`'s.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(super) struct RawDrift {
    pub(super) k_sigma: Option<f64>,
    pub(super) speed_scale_tol_rel: Option<f64>,
    pub(super) rear_ratio_tol_rel: Option<f64>,
    pub(super) rear_tread_tol_rel: Option<f64>,
    pub(super) steer_gain_tol_rel: Option<f64>,
    pub(super) steer_offset_tol_deg: Option<f64>,
    pub(super) yaw_bias_tol_dps: Option<f64>,
    pub(super) yaw_scale_tol_rel: Option<f64>,
    pub(super) front_ratio_tol_rel: Option<f64>,
    pub(super) every_s: Option<f64>,
    pub(super) window_s: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawFixes {
    /// `MESSAGE.SIGNAL` of a local metric x, metres.
    pub(super) x: Option<String>,
    /// `MESSAGE.SIGNAL` of a local metric y, metres.
    pub(super) y: Option<String>,
    /// `MESSAGE.SIGNAL` of the latitude, degrees.
    pub(super) latitude: Option<String>,
    /// `MESSAGE.SIGNAL` of the longitude, degrees.
    pub(super) longitude: Option<String>,
}

impl Default for RawCalibration {
    fn default() -> Self {
        Self {
            param_file: None,
            command_id: None,
            arming_code: None,
            bounds_rel: 0.30,
            max_steer_offset_deg: 10.0,
            max_tread_std_m: 0.005,
            max_ratio_std: 0.002,
            // §10's reference fit: rms 0.07°, gain within 0.2 %; these are
            // several times that, so only a fit whose arcs disagree fails.
            max_steer_gain_std_rel: 0.02,
            max_steer_offset_std_deg: 0.5,
            // A drive's commit (issue #31): a speed scale to 0.2 % (2 m a
            // km), a yaw-rate bias to 0.05°/s (a degree in 20 s of driving
            // blind), its scale as below; the fit at least this plausible.
            max_speed_scale_std: 0.002,
            max_yaw_bias_std_dps: 0.05,
            // Half the filter's own prior on the scale (EkfConfig::yaw_scale_sigma,
            // 0.005): a scale surer than the nominal one, or none (at 0.01 a
            // 0.9 %-sure scale made the multi-body BMW's rest 1.26 % off, not 0.78 %).
            max_yaw_scale_std: 0.0025,
            // Allowed beyond the fixes' noise (issue #46): the reckoning's own
            // error over a 60 s segment that no parameter removes (a tyre's
            // slip in a curve, its radius under load), 0.2 % of the ~900 m
            // such a segment drives at town-to-country speeds — below the
            // 0.5 % the odometry is to keep, far below the tens of metres a
            // wrong sign or unit leaves.
            max_fix_residual_m: 2.0,
            // The noisiest fixes a calibration is meant for: a consumer
            // receiver without corrections, σ 1–3 m per axis (issue #46).
            max_fix_sigma_m: 3.0,
            max_down_weighted_share: 0.25,
            ack_timeout_ms: 500,
            writeback_retries: 3,
            max_history: canodom_params::persist::DEFAULT_MAX_HISTORY,
            standstill_speed_mps: 0.01,
            standstill_time_s: 1.0,
            fixes: None,
            drift: RawDrift::default(),
            auto_commit: false,
        }
    }
}
