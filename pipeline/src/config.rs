//! The configuration file: raw TOML structs (serde, unknown keys refused)
//! validated once into a typed [`Config`] (ripgrep's `LowArgs` → `HiArgs`).
//!
//! After [`Config::load`] nothing re-reads a file: the DBC is parsed, every
//! configured signal and check is resolved to a codec handle, units are
//! converted, and the tasks receive only checked values. Every error names the
//! file, the key and what was expected.
//!
//! Sections: `[can]`, `[vehicle]`, `[signals]`, `[checks.MESSAGE]` (as issue 5
//! writes them), and with defaults `[inputs]` (timeouts, hysteresis),
//! `[ekf]` (noise and gate; defaults are `canodom_fusion`'s `EkfConfig::new`)
//! and `[output]` (own frames' base id, pose rate), and `[calibration]` (the
//! live session over CAN: command id, arming code, parameter file, bounds,
//! uncertainty limits, write-back timing; see [`CalibrationConfig`]), and
//! `[security]` (the SecOC key and lockout; see [`crate::security`]).

use crate::signal_forms::{
    DirectionSignal, FormError, Quantity, RawDirection, RawSignal, SignalForm, Unit,
};
use canodom_dbc::{
    Checksum, ChecksumAlgorithm, Database, FrameChecksum, Maker, MakerChecksum, SignalHandle,
};
use canodom_fusion::ekf::EkfConfig;
use canodom_fusion::wheel::{InputConfig, SpeedUnit};
use canodom_fusion::{SteeringMap, VehicleParams, WheelSet};
use canodom_protocol::own_dbc::BaseId;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::ffi::{OsStr, OsString};
use std::path::{Path, PathBuf};

/// A configuration that cannot be used: which file, which key, what was expected.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file cannot be read.
    #[error("{file}: cannot read: {source}")]
    Io {
        /// The configuration file.
        file: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// TOML syntax, a wrong type or an unknown key (toml names the key and the expected keys).
    #[error("{file}: {message}")]
    Toml {
        /// The configuration file.
        file: PathBuf,
        /// toml's message with line, column, key and expectation.
        message: String,
    },
    /// A value that parses but cannot be used.
    #[error("{file}: key `{key}`: expected {expected}, got {got}")]
    Invalid {
        /// The configuration file.
        file: PathBuf,
        /// Dotted key, e.g. `signals.rear_left`.
        key: String,
        /// What would have been accepted.
        expected: String,
        /// What the file says.
        got: String,
    },
    /// The parameter file cannot be created or replaced where the
    /// configuration puts it (see [`Config::check_param_file`]).
    // The OS error is part of the message and deliberately not a `source`:
    // the binary prints the whole cause chain, which would repeat it.
    #[error(
        "{file}: key `calibration.param_file`: cannot create or write {}: {reason}",
        path.display()
    )]
    ParamFile {
        /// The configuration file.
        file: PathBuf,
        /// The resolved parameter file.
        path: PathBuf,
        /// The OS error of the failed probe.
        reason: std::io::Error,
    },
    /// `[security] key_file` is unreadable, open to group or others, or not a key.
    #[error("{file}: key `security.key_file`: {}: {reason}", path.display())]
    KeyFile {
        /// The configuration file.
        file: PathBuf,
        /// The key file.
        path: PathBuf,
        /// Why it is refused (never any of its content).
        reason: String,
    },
}

/// The variable systemd sets to the unit's state directory (`StateDirectory=`;
/// a colon-separated list when the unit names several, ours the first).
pub const STATE_DIRECTORY_ENV: &str = "STATE_DIRECTORY";

/// Name of the parameter file when `[calibration] param_file` is not set.
pub const DEFAULT_PARAM_FILE: &str = "canodom-params.toml";

/// Where the parameter file goes when `[calibration] param_file` is not set:
/// in the state directory when systemd gives one (the unit's `/etc/canodom`
/// is read-only, so a file beside the configuration could never be
/// committed), else beside the configuration file.
pub fn default_param_file(config_file: &Path, state_directory: Option<&OsStr>) -> PathBuf {
    let state = state_directory
        .and_then(|dirs| std::env::split_paths(dirs).next())
        .filter(|dir| !dir.as_os_str().is_empty());
    match state {
        Some(dir) => dir.join(DEFAULT_PARAM_FILE),
        None => beside(config_file, Path::new(DEFAULT_PARAM_FILE)),
    }
}

/// `path` as written in `config_file`: a relative one is taken from the
/// configuration's folder, so a configuration reads the same files whatever
/// the working directory (under systemd it is the state directory).
fn beside(config_file: &Path, path: &Path) -> PathBuf {
    config_file.parent().unwrap_or(Path::new(".")).join(path)
}

// ---------------------------------------------------------------- raw (serde)

/// The file as written; every table refuses unknown keys.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConfig {
    can: RawCan,
    vehicle: RawVehicle,
    signals: RawSignals,
    #[serde(default)]
    checks: BTreeMap<String, RawCheck>,
    #[serde(default)]
    inputs: RawInputs,
    #[serde(default)]
    ekf: RawEkf,
    #[serde(default)]
    output: RawOutput,
    #[serde(default)]
    calibration: RawCalibration,
    /// `None` without a `[security]` section (secure defaults differ: #33).
    #[serde(default)]
    security: Option<crate::security::RawSecurity>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCan {
    interface: String,
    dbc: PathBuf,
}

/// The wheel diameter a configuration with speed signals and no
/// `vehicle.wheel_diameter_m` uses, metres: a typical road car's. With
/// speeds it only scales revolutions and is what a calibrated diameter is
/// relative to; distances do not depend on it.
pub const SPEED_SENSOR_REFERENCE_DIAMETER_M: f64 = 0.65;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawVehicle {
    wheelbase_m: f64,
    rear_tread_m: f64,
    front_tread_m: f64,
    wheel_diameter_m: Option<f64>,
    rear_left_diameter_m: Option<f64>,
    rear_right_diameter_m: Option<f64>,
    front_left_diameter_m: Option<f64>,
    front_right_diameter_m: Option<f64>,
    encoder_ticks_per_rev: Option<u32>,
    steering_ratio: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSignals {
    rear_left: RawSignal,
    rear_right: RawSignal,
    front_left: RawSignal,
    front_right: RawSignal,
    steering: RawSignal,
    /// A second, finer steering signal added to `steering` (Toyota's `STEER_FRACTION`).
    steering_fine: Option<String>,
    /// Optional in serde so that a missing one is named with its values.
    wheel_kind: Option<String>,
    steering_kind: Option<String>,
    /// The car's yaw-rate sensor (`KINEMATICS.YAW_RATE` on a Toyota), optional.
    yaw_rate: Option<RawSignal>,
    /// The signal that says the car reverses (wheel speeds as magnitudes).
    direction: Option<RawDirection>,
    /// +1 when the signal reads a left turn positive (ISO 8855), −1 when right.
    yaw_rate_sign: Option<i64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCheck {
    counter: Option<String>,
    checksum: Option<String>,
    algorithm: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawInputs {
    timeout_factor: f64,
    default_period_ms: f64,
    invalid_after_faults: u32,
    trusted_after_frames: u32,
    max_wheel_speed_mps: Option<f64>,
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
struct RawEkf {
    // Wheels and steering.
    k_rear_m: Option<f64>,
    k_front_m: Option<f64>,
    steer_sigma_deg: Option<f64>,
    steer_bias_sigma_deg: Option<f64>,
    front_scale_sigma: Option<f64>,
    // Windows, gate and blending.
    correct_every: Option<u32>,
    gate_threshold: Option<f64>,
    gate_enabled: Option<bool>,
    gate_action: Option<String>,
    min_slip_ratio: Option<f64>,
    blend_accepted: Option<bool>,
    // Online learning of the steering offset and the front scale.
    learn_steer_offset: Option<bool>,
    steer_offset_drift_deg: Option<f64>,
    front_scale_drift: Option<f64>,
    // The yaw-rate-aided estimator.
    yaw_sigma_deg_s: Option<f64>,
    yaw_bias_walk_deg_s_per_sqrt_s: Option<f64>,
    yaw_bias_sigma_deg_s: Option<f64>,
    yaw_scale_sigma: Option<f64>,
    rear_ratio_sigma: Option<f64>,
    ratio_walk: Option<f64>,
    tread_sigma: Option<f64>,
    tread_turn_sigma: Option<f64>,
    wheel_turn_sigma_deg: Option<f64>,
    distance_scale_sigma: Option<f64>,
    still_min_s: Option<f64>,
    aided_window_s: Option<f64>,
    yaw_gate_sigma: Option<f64>,
    slip_accel_sigma: Option<f64>,
    straight_yaw_sigma_deg_s: Option<f64>,
    straight_max_deg_s: Option<f64>,
    straight_max_steer_deg: Option<f64>,
    straight_min_s: Option<f64>,
    straight_min_speed_mps: Option<f64>,
    // A slide on locked wheels (wheel-speed sensors).
    max_accel_mps2: Option<f64>,
    slide_decel_mps2: Option<f64>,
    slide_decel_sigma_mps2: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct RawOutput {
    base_id: u32,
    extended: bool,
    pose_rate_hz: f64,
    publish_on_update: bool,
    stats_interval_s: f64,
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
struct RawCalibration {
    param_file: Option<PathBuf>,
    command_id: Option<u32>,
    arming_code: Option<u8>,
    bounds_rel: f64,
    max_steer_offset_deg: f64,
    max_tread_std_m: f64,
    max_ratio_std: f64,
    max_steer_gain_std_rel: f64,
    max_steer_offset_std_deg: f64,
    max_speed_scale_std: f64,
    max_yaw_bias_std_dps: f64,
    max_yaw_scale_std: f64,
    max_fix_residual_m: f64,
    max_down_weighted_share: f64,
    ack_timeout_ms: u64,
    writeback_retries: u32,
    max_history: usize,
    standstill_speed_mps: f64,
    standstill_time_s: f64,
    /// Position fixes on the bus (GNSS on CAN) for calibration from a drive.
    fixes: Option<RawFixes>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFixes {
    /// `MESSAGE.SIGNAL` of a local metric x, metres.
    x: Option<String>,
    /// `MESSAGE.SIGNAL` of a local metric y, metres.
    y: Option<String>,
    /// `MESSAGE.SIGNAL` of the latitude, degrees.
    latitude: Option<String>,
    /// `MESSAGE.SIGNAL` of the longitude, degrees.
    longitude: Option<String>,
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
            max_fix_residual_m: 2.0,
            max_down_weighted_share: 0.25,
            ack_timeout_ms: 500,
            writeback_retries: 3,
            max_history: canodom_params::persist::DEFAULT_MAX_HISTORY,
            standstill_speed_mps: 0.01,
            standstill_time_s: 1.0,
            fixes: None,
        }
    }
}

// ---------------------------------------------------------------- typed

/// How wheels are reported.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WheelKind {
    /// Cumulative wrapping tick counters of the signal's width.
    Ticks,
    /// Signed speeds in the unit the DBC gives.
    Speed(SpeedUnit),
}

/// What the steering signal measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SteeringKind {
    /// The road-wheel angle itself.
    RoadWheel,
    /// The steering-wheel angle, divided by `steering_ratio`.
    SteeringWheel,
}

/// A resolved input signal.
#[derive(Clone, Copy, Debug)]
pub struct InputSignal {
    /// The codec handle (of the magnitude or the coarse part in a form).
    pub handle: SignalHandle,
    /// Index of its message in the database.
    pub message_index: usize,
    /// How the quantity is read: one signal, magnitude and sign, or a sum.
    pub form: SignalForm,
}

/// The four wheel signals and the steering.
#[derive(Clone, Copy, Debug)]
pub struct Signals {
    /// Wheel signals.
    pub wheels: WheelSet<InputSignal>,
    /// Steering signal (in its unit; converted by `steering_map`); a
    /// `steering_fine` is the fine part of its sum form.
    pub steering: InputSignal,
    /// Ticks or speeds.
    pub wheel_kind: WheelKind,
    /// Road-wheel or steering-wheel angle.
    pub steering_kind: SteeringKind,
    /// Counter width of tick signals (the signal's size in bits).
    pub tick_bits: u32,
    /// The yaw-rate sensor, if configured.
    pub yaw_rate: Option<YawRateSignal>,
    /// Multiplies a wheel speed's value into the `wheel_kind` unit (1, or
    /// the m/s per mph of a speed in mph).
    pub wheel_speed_factor: f64,
    /// The signal that says the car reverses: wheel speeds are then read as
    /// magnitudes, negative while it says so.
    pub direction: Option<DirectionSignal>,
}

/// The bus's position fixes: two signals of one message.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FixSignals {
    /// Index of the message in the database.
    pub message_index: usize,
    /// x (metres) or latitude (degrees).
    pub first: SignalHandle,
    /// y (metres) or longitude (degrees).
    pub second: SignalHandle,
    /// Latitude and longitude (turned into a local metric frame at the first
    /// fix, x east and y north), rather than a local x and y.
    pub geodetic: bool,
}

/// A resolved yaw-rate signal.
#[derive(Clone, Copy, Debug)]
pub struct YawRateSignal {
    /// The signal.
    pub signal: InputSignal,
    /// Radians per second, left positive, per unit of the signal (the DBC
    /// unit's conversion times `yaw_rate_sign`).
    pub radps_per_unit: f64,
}

/// Integrity checks of one input message.
#[derive(Clone, Debug)]
pub struct MessageCheck {
    /// Index of the message in the database.
    pub message_index: usize,
    /// Rolling counter signal.
    pub counter: Option<SignalHandle>,
    /// Checksum (algorithm, covered bytes, position; or a carmaker's).
    pub checksum: Option<FrameChecksum>,
}

/// Timeouts and hysteresis of the inputs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InputsConfig {
    /// A message is stale after `timeout_factor` × its period without a good frame.
    pub timeout_factor: f64,
    /// Period of a message without `GenMsgCycleTime`, until one is learnt.
    pub default_period_s: f64,
    /// Consecutive bad frames (counter, checksum, DLC, non-finite) before an input is invalid.
    pub invalid_after_faults: u32,
    /// Consecutive good frames before a stale or new input is trusted.
    pub trusted_after_frames: u32,
    /// Fastest plausible wheel; larger increments are wheel faults.
    pub max_wheel_speed_mps: f64,
}

/// What canodom sends.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OutputConfig {
    /// Base id of canodom's own frames.
    pub base_id: BaseId,
    /// Pose frames per second.
    pub pose_rate_hz: f64,
    /// Also publish after every filter step.
    pub publish_on_update: bool,
    /// Period of the one-line statistics log.
    pub stats_interval_s: f64,
}

/// The live calibration session (`[calibration]`).
#[derive(Clone, Debug, PartialEq)]
pub struct CalibrationConfig {
    /// The calibrated-parameter file, relative paths taken from the
    /// configuration's folder (default: [`default_param_file`]).
    pub param_file: PathBuf,
    /// The only id `CALIB_CMD` is accepted on (default base id + 0x10).
    pub command_id: canodom_can::frame::FrameId,
    /// When set, every `CALIB_CMD` and an `ODOM_CMD` RESET_POSE must carry
    /// this `ARMING_CODE`.
    pub arming_code: Option<u8>,
    /// Bounds around the nominal parameters a committed or loaded set must
    /// lie in (default ±30 %, steering offset ±10°).
    pub bounds: canodom_params::persist::ParamBounds,
    /// Largest tread standard deviation a commit accepts, m (default 5 mm).
    pub max_tread_std_m: f64,
    /// Largest diameter-ratio standard deviation a commit accepts (default 0.002).
    pub max_ratio_std: f64,
    /// Largest steering-gain standard deviation a steering commit accepts,
    /// relative to the nominal gain as `CALIB_STATUS` shows it (default 0.02).
    pub max_steer_gain_std_rel: f64,
    /// Largest steering-offset standard deviation a steering commit
    /// accepts, rad (configured in degrees; default 0.5°).
    pub max_steer_offset_std_rad: f64,
    /// Largest speed-scale standard deviation a drive's commit accepts (default 0.002).
    pub max_speed_scale_std: f64,
    /// Largest yaw-rate bias standard deviation a drive's commit accepts,
    /// rad/s (configured in °/s; default 0.05°/s).
    pub max_yaw_bias_std_radps: f64,
    /// Largest yaw-rate scale standard deviation a drive's commit accepts (default 0.01).
    pub max_yaw_scale_std: f64,
    /// Largest residual at the fixes (weighted RMS) a drive's fit may have
    /// for anything to be committed, m (default 2).
    pub max_fix_residual_m: f64,
    /// Largest share of a drive's fixes the fit may down-weight for anything
    /// to be committed (default 0.25).
    pub max_down_weighted_share: f64,
    /// How long to wait for `CALIB_ACK` after sending `CALIB_PARAMS` (default 500 ms).
    pub ack_timeout: std::time::Duration,
    /// Resends after the first without an ACK before the write-back fails (default 3).
    pub writeback_retries: u32,
    /// Previous sets kept in the file for rollback (default 10).
    pub max_history: usize,
    /// Below this rear-axle speed the vehicle stands still, m/s (default 0.01).
    pub standstill_speed_mps: f64,
    /// Position fixes on the bus for `START_DRIVE` (calibration from a drive).
    pub fixes: Option<FixSignals>,
    /// How long it must stay below it, s (default 1).
    pub standstill_time_s: f64,
}

/// The validated configuration.
#[derive(Debug)]
pub struct Config {
    /// The file it came from (for messages).
    pub file: PathBuf,
    /// CAN interface name.
    pub interface: String,
    /// Resolved DBC path.
    pub dbc_path: PathBuf,
    /// The vehicle's database.
    pub db: Database,
    /// Nominal vehicle parameters, steering map included.
    pub params: VehicleParams,
    /// Input signals.
    pub signals: Signals,
    /// Per-message checks.
    pub checks: Vec<MessageCheck>,
    /// Timeouts, hysteresis.
    pub inputs: InputsConfig,
    /// The filter's configuration.
    pub ekf: EkfConfig,
    /// Output.
    pub output: OutputConfig,
    /// The live calibration session.
    pub calibration: CalibrationConfig,
    /// Authentication of commands and write-back (`[security]`).
    pub security: crate::security::SecurityConfig,
}

impl Config {
    /// Reads and validates `path`.
    ///
    /// # Errors
    /// [`ConfigError`] naming the file, key and expectation.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
            file: path.to_owned(),
            source,
        })?;
        Self::from_toml(&text, path)
    }

    /// Validates `text` as if read from `path` (relative paths resolve from its folder).
    ///
    /// # Errors
    /// [`ConfigError`] naming the file, key and expectation.
    pub fn from_toml(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let raw: RawConfig = toml::from_str(text).map_err(|e| ConfigError::Toml {
            file: path.to_owned(),
            message: e.to_string().trim_end().to_owned(),
        })?;
        Validator::new(path).validate(raw, None)
    }

    /// As [`Config::from_toml`], with the DBC given as text instead of read
    /// from `can.dbc` (the built-in demo configuration, which must run
    /// wherever the binary is installed).
    ///
    /// # Errors
    /// [`ConfigError`] naming the file, key and expectation.
    pub fn from_toml_with_dbc(
        text: &str,
        path: &Path,
        dbc_text: &str,
    ) -> Result<Self, ConfigError> {
        let raw: RawConfig = toml::from_str(text).map_err(|e| ConfigError::Toml {
            file: path.to_owned(),
            message: e.to_string().trim_end().to_owned(),
        })?;
        let v = Validator::new(path);
        let name = raw.can.dbc.display().to_string();
        let db = Database::parse(dbc_text, &name)
            .map_err(|e| v.err("can.dbc", "a DBC that parses", e))?;
        v.validate(raw, Some(db))
    }

    /// Ids of every input message, for kernel filters.
    pub fn input_ids(&self) -> Vec<canodom_dbc::FrameId> {
        let mut idx: Vec<usize> = [
            self.signals.wheels.rear_left.message_index,
            self.signals.wheels.rear_right.message_index,
            self.signals.wheels.front_left.message_index,
            self.signals.wheels.front_right.message_index,
            self.signals.steering.message_index,
        ]
        .to_vec();
        idx.sort_unstable();
        idx.dedup();
        idx.iter().map(|&i| self.db.messages()[i].id()).collect()
    }

    /// Checks that the parameter file can be created or replaced, as a commit
    /// will (a temporary file beside it renamed over it), so a daemon that
    /// could never keep a calibration refuses to start instead of failing at
    /// the commit, after the operator has driven every run.
    ///
    /// Nothing is destroyed: an existing file is only opened for appending,
    /// and the probe is the temporary file a commit writes anyway, removed
    /// again. The folder is not created: a missing one is a mistake to report.
    ///
    /// # Errors
    /// [`ConfigError::ParamFile`] naming the key, the path and the OS reason.
    pub fn check_param_file(&self) -> Result<(), ConfigError> {
        let path = &self.calibration.param_file;
        probe_writable(path).map_err(|reason| ConfigError::ParamFile {
            file: self.file.clone(),
            path: path.clone(),
            reason,
        })
    }
}

/// The operations a commit of `path` needs, without changing its content.
fn probe_writable(path: &Path) -> std::io::Result<()> {
    use std::fs::OpenOptions;
    // An existing file the daemon cannot open for writing (or a folder) is
    // refused: it was not meant to be replaced by this daemon.
    match OpenOptions::new().append(true).open(path) {
        Ok(_) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(e),
    }
    let tmp = canodom_params::persist::temp_path(path);
    // Not truncated, and removed again: a leftover of a crashed commit goes
    // with it, which the next commit would have overwritten anyway.
    OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(false)
        .open(&tmp)?;
    std::fs::remove_file(&tmp)
}

struct Validator<'a> {
    file: &'a Path,
    /// `$STATE_DIRECTORY` as the process found it, for [`default_param_file`].
    state_directory: Option<OsString>,
}

impl<'a> Validator<'a> {
    fn new(file: &'a Path) -> Self {
        Self {
            file,
            state_directory: std::env::var_os(STATE_DIRECTORY_ENV),
        }
    }
}

impl Validator<'_> {
    fn err(&self, key: &str, expected: &str, got: impl std::fmt::Display) -> ConfigError {
        ConfigError::Invalid {
            file: self.file.to_owned(),
            key: key.to_owned(),
            expected: expected.to_owned(),
            got: got.to_string(),
        }
    }

    fn positive(&self, key: &str, v: f64) -> Result<f64, ConfigError> {
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err(self.err(key, "a finite number > 0", v))
        }
    }

    fn non_negative(&self, key: &str, v: f64) -> Result<f64, ConfigError> {
        if v.is_finite() && v >= 0.0 {
            Ok(v)
        } else {
            Err(self.err(key, "a finite number >= 0", v))
        }
    }

    /// The `[ekf]` keys beyond the wheel noises and the gate threshold:
    /// gate, blending, learning and the yaw-rate-aided estimator. Angles are
    /// written in degrees (deg/s for rates), relative values as fractions.
    // One table row per key: splitting it would only scatter the table.
    #[allow(clippy::too_many_lines)]
    fn ekf_choices(&self, e: &RawEkf, ekf: &mut EkfConfig) -> Result<(), ConfigError> {
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

    fn signal(&self, db: &Database, key: &str, path: &str) -> Result<InputSignal, ConfigError> {
        let handle = db.signal(path).map_err(|e| {
            self.err(
                key,
                &format!("\"MESSAGE.SIGNAL\" present in {}", db.source_name()),
                format!("{path:?} ({e})"),
            )
        })?;
        Ok(InputSignal {
            handle,
            message_index: handle.message_index(),
            form: SignalForm::plain(handle),
        })
    }

    /// A quantity of `[signals]` in any form ([`crate::signal_forms`]),
    /// its unit of `quantity` when given.
    fn quantity(
        &self,
        db: &Database,
        key: &str,
        raw: &RawSignal,
        quantity: Option<Quantity>,
    ) -> Result<(InputSignal, Option<Unit>), ConfigError> {
        let r = crate::signal_forms::resolve(db, key, raw, quantity).map_err(|e| self.form(e))?;
        Ok((
            InputSignal {
                handle: r.form.main,
                message_index: r.message_index,
                form: r.form,
            },
            r.unit,
        ))
    }

    fn form(&self, e: FormError) -> ConfigError {
        self.err(&e.key, &e.expected, e.got)
    }

    #[allow(clippy::too_many_lines)]
    fn validate(&self, raw: RawConfig, db: Option<Database>) -> Result<Config, ConfigError> {
        let iface = raw.can.interface;
        if iface.is_empty()
            || iface.len() > 15
            || iface.chars().any(|c| c.is_whitespace() || c == '/')
        {
            return Err(self.err(
                "can.interface",
                "a network interface name (1 to 15 characters, no '/' or spaces)",
                format!("{iface:?}"),
            ));
        }
        let dbc_path = beside(self.file, &raw.can.dbc);
        let db = match db {
            Some(db) => db,
            None => Database::from_file(&dbc_path).map_err(|e| {
                self.err(
                    "can.dbc",
                    "a readable DBC file (relative to the configuration file)",
                    format!("{} ({e})", dbc_path.display()),
                )
            })?,
        };

        // Signals.
        let s = &raw.signals;
        let speed = match s.wheel_kind.as_deref() {
            Some("ticks") => false,
            Some("speed") => true,
            other => {
                return Err(self.err(
                    "signals.wheel_kind",
                    "\"ticks\" (cumulative encoder counters) or \"speed\" (km/h, m/s or mph signals)",
                    other.map_or_else(|| "nothing".to_owned(), |o| format!("{o:?}")),
                ));
            }
        };
        let wheel_quantity = speed.then_some(Quantity::Speed);
        let wheel = |key: &str, raw: &RawSignal| self.quantity(&db, key, raw, wheel_quantity);
        let (rear_left, rl_unit) = wheel("signals.rear_left", &s.rear_left)?;
        let (rear_right, rr_unit) = wheel("signals.rear_right", &s.rear_right)?;
        let (front_left, fl_unit) = wheel("signals.front_left", &s.front_left)?;
        let (front_right, fr_unit) = wheel("signals.front_right", &s.front_right)?;
        let wheels = WheelSet {
            rear_left,
            rear_right,
            front_left,
            front_right,
        };
        // One step per rear frame needs both rear wheels in one frame.
        if wheels.rear_left.message_index != wheels.rear_right.message_index {
            return Err(self.err(
                "signals.rear_right",
                "a signal in the same message as signals.rear_left",
                s.rear_right.name(),
            ));
        }
        if wheels.front_left.message_index != wheels.front_right.message_index {
            return Err(self.err(
                "signals.front_right",
                "a signal in the same message as signals.front_left",
                s.front_right.name(),
            ));
        }
        let (wheel_kind, wheel_speed_factor) = if speed {
            // `quantity` gave every wheel a speed unit.
            let unit = rl_unit.unwrap_or(Unit::KilometresPerHour);
            for (key, u) in [
                ("signals.rear_right", rr_unit),
                ("signals.front_left", fl_unit),
                ("signals.front_right", fr_unit),
            ] {
                if u != Some(unit) {
                    return Err(self.err(
                        key,
                        &format!("the same unit as signals.rear_left ({unit:?})"),
                        format!("{u:?}"),
                    ));
                }
            }
            match unit {
                Unit::MetresPerSecond => (WheelKind::Speed(SpeedUnit::MetresPerSecond), 1.0),
                Unit::MilesPerHour => (
                    WheelKind::Speed(SpeedUnit::MetresPerSecond),
                    Unit::MilesPerHour.si_per_unit(),
                ),
                _ => (WheelKind::Speed(SpeedUnit::KilometresPerHour), 1.0),
            }
        } else {
            for (key, w, raw) in [
                ("signals.rear_left", &wheels.rear_left, &s.rear_left),
                ("signals.rear_right", &wheels.rear_right, &s.rear_right),
                ("signals.front_left", &wheels.front_left, &s.front_left),
                ("signals.front_right", &wheels.front_right, &s.front_right),
            ] {
                if !w.form.is_plain() {
                    return Err(self.err(
                        key,
                        "one tick-counter signal (sign and sum forms are for speeds)",
                        raw.name(),
                    ));
                }
                let unit = unit_of(&db, w);
                if Unit::parse(&unit).is_some_and(|u| u.quantity() == Quantity::Speed) {
                    return Err(self.err(
                        "signals.wheel_kind",
                        &format!(
                            "\"speed\": {} is a speed in {unit:?}, not a tick counter",
                            raw.name()
                        ),
                        "\"ticks\"",
                    ));
                }
            }
            if s.direction.is_some() {
                return Err(self.err(
                    "signals.direction",
                    "no direction with tick counters (they count backwards when reversing)",
                    "a direction signal",
                ));
            }
            (WheelKind::Ticks, 1.0)
        };
        let (mut steering, steer_unit) =
            self.quantity(&db, "signals.steering", &s.steering, Some(Quantity::Angle))?;
        if let Some(p) = &s.steering_fine {
            let fine = self.signal(&db, "signals.steering_fine", p)?;
            if fine.message_index != steering.message_index {
                return Err(self.err(
                    "signals.steering_fine",
                    "a signal in the same message as signals.steering",
                    p,
                ));
            }
            if steering.form.fine.is_some() {
                return Err(self.err(
                    "signals.steering_fine",
                    "no steering_fine beside a signals.steering sum",
                    p,
                ));
            }
            steering.form.fine = Some(fine.handle);
        }
        let direction = match &s.direction {
            None => None,
            Some(d) => {
                Some(crate::signal_forms::resolve_direction(&db, d).map_err(|e| self.form(e))?)
            }
        };
        let tick_bits = wheels.rear_left.handle.size();
        let steering_kind = match s.steering_kind.as_deref() {
            Some("road_wheel") => SteeringKind::RoadWheel,
            Some("steering_wheel") => SteeringKind::SteeringWheel,
            other => {
                return Err(self.err(
                    "signals.steering_kind",
                    "\"road_wheel\" (the wheels' angle) or \"steering_wheel\" (divided by vehicle.steering_ratio)",
                    other.map_or_else(|| "nothing".to_owned(), |o| format!("{o:?}")),
                ));
            }
        };
        let yaw_rate = match &s.yaw_rate {
            None => {
                if s.yaw_rate_sign.is_some() {
                    return Err(self.err(
                        "signals.yaw_rate_sign",
                        "signals.yaw_rate beside it",
                        "a sign without a yaw-rate signal",
                    ));
                }
                None
            }
            Some(raw_yaw) => {
                let (signal, unit) = self.quantity(
                    &db,
                    "signals.yaw_rate",
                    raw_yaw,
                    Some(Quantity::AngularRate),
                )?;
                let per_unit = unit.map_or(1.0, Unit::si_per_unit);
                let sign = match s.yaw_rate_sign {
                    None | Some(1) => 1.0,
                    Some(-1) => -1.0,
                    Some(other) => {
                        return Err(self.err(
                            "signals.yaw_rate_sign",
                            "1 (left turn positive) or -1 (right turn positive)",
                            other,
                        ));
                    }
                };
                Some(YawRateSignal {
                    signal,
                    radps_per_unit: per_unit * sign,
                })
            }
        };
        let rad_per_unit = steer_unit.map_or(1.0, Unit::si_per_unit);
        if steering_kind == SteeringKind::RoadWheel {
            // A road wheel turns well under 90°; a DBC range far beyond it
            // is a steering-wheel angle (VW's LWI_01 reaches 800°).
            let sig =
                &db.messages()[steering.message_index].signals()[steering.handle.signal_index()];
            let reach_deg = sig.min().abs().max(sig.max().abs()) * rad_per_unit.to_degrees();
            if reach_deg > 120.0 {
                return Err(self.err(
                    "signals.steering_kind",
                    &format!(
                        "\"steering_wheel\" with vehicle.steering_ratio: {} ranges to {reach_deg:.0}°, \
                         beyond any road wheel",
                        s.steering.name()
                    ),
                    "\"road_wheel\"",
                ));
            }
        }

        // Vehicle.
        let v = &raw.vehicle;
        let wheelbase_m = self.positive("vehicle.wheelbase_m", v.wheelbase_m)?;
        let rear_tread_m = self.positive("vehicle.rear_tread_m", v.rear_tread_m)?;
        let front_tread_m = self.positive("vehicle.front_tread_m", v.front_tread_m)?;
        let nominal = match (wheel_kind, v.wheel_diameter_m) {
            (_, Some(d)) => self.positive("vehicle.wheel_diameter_m", d)?,
            (WheelKind::Ticks, None) => {
                return Err(self.err(
                    "vehicle.wheel_diameter_m",
                    "the wheels' diameter in metres (tick encoders count revolutions)",
                    "nothing",
                ));
            }
            // Speed signals are distances already: the diameter is only the
            // reference the calibration's speed scale multiplies (a
            // calibrated 0.6532 m is a 0.49 % scale on this 0.65 m).
            (WheelKind::Speed(_), None) => SPEED_SENSOR_REFERENCE_DIAMETER_M,
        };
        let diameter = |key: &str, o: Option<f64>| match o {
            Some(d) => self.positive(key, d),
            None => Ok(nominal),
        };
        let diameters = WheelSet {
            rear_left: diameter("vehicle.rear_left_diameter_m", v.rear_left_diameter_m)?,
            rear_right: diameter("vehicle.rear_right_diameter_m", v.rear_right_diameter_m)?,
            front_left: diameter("vehicle.front_left_diameter_m", v.front_left_diameter_m)?,
            front_right: diameter("vehicle.front_right_diameter_m", v.front_right_diameter_m)?,
        };
        let ticks = match (wheel_kind, v.encoder_ticks_per_rev) {
            (WheelKind::Ticks, None) => {
                return Err(self.err(
                    "vehicle.encoder_ticks_per_rev",
                    "a tick count per wheel revolution (signals.wheel_kind = \"ticks\")",
                    "nothing",
                ));
            }
            (WheelKind::Ticks, Some(0)) => {
                return Err(self.err("vehicle.encoder_ticks_per_rev", "an integer >= 1", 0));
            }
            (_, t) => t.unwrap_or(1),
        };
        let gain = match (steering_kind, v.steering_ratio) {
            (SteeringKind::RoadWheel, None) => rad_per_unit,
            (SteeringKind::RoadWheel, Some(r)) => {
                return Err(self.err(
                    "vehicle.steering_ratio",
                    "no steering_ratio with signals.steering_kind = \"road_wheel\"",
                    r,
                ));
            }
            (SteeringKind::SteeringWheel, None) => {
                return Err(self.err(
                    "vehicle.steering_ratio",
                    "a steering ratio (signals.steering_kind = \"steering_wheel\")",
                    "nothing",
                ));
            }
            (SteeringKind::SteeringWheel, Some(r)) => {
                rad_per_unit / self.positive("vehicle.steering_ratio", r)?
            }
        };
        let params = VehicleParams::new(
            wheelbase_m,
            rear_tread_m,
            front_tread_m,
            diameters,
            ticks,
            SteeringMap {
                gain,
                offset_rad: 0.0,
            },
        )
        .map_err(|e| self.err("vehicle", "a valid parameter set", e))?;

        // Checks.
        let mut checks = Vec::new();
        for (name, c) in &raw.checks {
            let key = format!("checks.{name}");
            let m = db.message_by_name(name).ok_or_else(|| {
                self.err(
                    &key,
                    &format!("a message name of {}", db.source_name()),
                    name,
                )
            })?;
            let message_index = db
                .messages()
                .iter()
                .position(|x| x.name() == name)
                .unwrap_or_default();
            let counter = match &c.counter {
                None => None,
                Some(sig) => Some(
                    self.signal(&db, &format!("{key}.counter"), &format!("{name}.{sig}"))?
                        .handle,
                ),
            };
            let checksum = match (&c.checksum, &c.algorithm) {
                (None, None) => None,
                (None, Some(_)) => {
                    return Err(self.err(
                        &format!("{key}.checksum"),
                        "the checksum signal's name when an algorithm is given",
                        "nothing",
                    ));
                }
                (Some(sig), alg) => {
                    let h = self
                        .signal(&db, &format!("{key}.checksum"), &format!("{name}.{sig}"))?
                        .handle;
                    let name = alg.as_deref().unwrap_or("crc8_sae_j1850");
                    if let Some(maker) = Maker::from_name(name) {
                        let c = MakerChecksum::new(maker, m.id().to_dbc(), h, m.length()).map_err(
                            |e| self.err(&format!("{key}.checksum"), "a usable checksum", e),
                        )?;
                        checks.push(MessageCheck {
                            message_index,
                            counter,
                            checksum: Some(FrameChecksum::Maker(c)),
                        });
                        continue;
                    }
                    let algorithm = match name {
                        "crc8_sae_j1850" => ChecksumAlgorithm::Crc8SaeJ1850,
                        "sum" => ChecksumAlgorithm::Sum { init: 0 },
                        "xor" => ChecksumAlgorithm::Xor { init: 0 },
                        other => {
                            let makers: Vec<&str> = Maker::ALL.iter().map(|(_, n)| *n).collect();
                            return Err(self.err(
                                &format!("{key}.algorithm"),
                                &format!(
                                    "\"crc8_sae_j1850\", \"sum\", \"xor\", or a carmaker's: {}",
                                    makers.join(", ")
                                ),
                                other,
                            ));
                        }
                    };
                    let len = m.length();
                    let position = checksum_byte(m, h).ok_or_else(|| {
                        self.err(
                            &format!("{key}.checksum"),
                            "an 8-bit, byte-aligned signal in the first or last byte",
                            sig,
                        )
                    })?;
                    let covered = if position + 1 == len {
                        0..=len.saturating_sub(2)
                    } else {
                        1..=len - 1
                    };
                    Some(FrameChecksum::Bytes(
                        Checksum::new(algorithm, covered, position).map_err(|e| {
                            self.err(&format!("{key}.checksum"), "a usable checksum", e)
                        })?,
                    ))
                }
            };
            checks.push(MessageCheck {
                message_index,
                counter,
                checksum,
            });
        }

        // Inputs.
        let i = &raw.inputs;
        let timeout_factor = self.positive("inputs.timeout_factor", i.timeout_factor)?;
        if timeout_factor < 1.0 {
            return Err(self.err("inputs.timeout_factor", "a factor >= 1", timeout_factor));
        }
        let default_period_s =
            self.positive("inputs.default_period_ms", i.default_period_ms)? / 1000.0;
        let max_wheel_speed_mps = match i.max_wheel_speed_mps {
            Some(v) => self.positive("inputs.max_wheel_speed_mps", v)?,
            None => match wheel_kind {
                WheelKind::Ticks => InputConfig::RC_CAR.max_wheel_speed_mps,
                WheelKind::Speed(_) => InputConfig::ROAD_CAR.max_wheel_speed_mps,
            },
        };
        if i.trusted_after_frames == 0 || i.invalid_after_faults == 0 {
            return Err(self.err(
                "inputs.trusted_after_frames / inputs.invalid_after_faults",
                "integers >= 1",
                format!("{} / {}", i.trusted_after_frames, i.invalid_after_faults),
            ));
        }
        let inputs = InputsConfig {
            timeout_factor,
            default_period_s,
            invalid_after_faults: i.invalid_after_faults,
            trusted_after_frames: i.trusted_after_frames,
            max_wheel_speed_mps,
        };

        // EKF.
        let e = &raw.ekf;
        let mut ekf = EkfConfig::new(params);
        // The yaw-rate signal's step: a standing car's readings repeat one
        // value, whose rounding no average removes.
        if let Some(y) = &yaw_rate {
            let m = &db.messages()[y.signal.message_index];
            let factor = m.signals()[y.signal.handle.signal_index()].factor();
            ekf.yaw_quantum_radps = (factor * y.radps_per_unit).abs();
        }
        if let Some(k) = e.k_rear_m {
            ekf.k_rear_m = self.positive("ekf.k_rear_m", k)?;
        }
        if let Some(k) = e.k_front_m {
            ekf.k_front_m = self.positive("ekf.k_front_m", k)?;
        }
        if let Some(d) = e.steer_sigma_deg {
            ekf.steer_sigma_rad = self.positive("ekf.steer_sigma_deg", d)?.to_radians();
        }
        if let Some(d) = e.steer_bias_sigma_deg {
            ekf.steer_bias_sigma_rad = self
                .non_negative("ekf.steer_bias_sigma_deg", d)?
                .to_radians();
        }
        if let Some(n) = e.correct_every {
            if n == 0 {
                return Err(self.err("ekf.correct_every", "an integer >= 1", n));
            }
            ekf.correct_every = n;
        }
        if let Some(g) = e.gate_threshold {
            ekf.gate_threshold = Some(self.positive("ekf.gate_threshold", g)?);
        }
        if e.gate_enabled == Some(false) {
            ekf.gate_threshold = None;
        }
        if e.learn_steer_offset == Some(false) {
            ekf.steer_offset_drift_rad = None;
        }
        self.ekf_choices(e, &mut ekf)?;
        canodom_fusion::ekf::Ekf::new(ekf)
            .map_err(|err| self.err("ekf", "a valid filter configuration", err))?;

        // Output.
        let o = &raw.output;
        let base_id = BaseId::new(o.base_id, o.extended).map_err(|err| {
            self.err(
                "output.base_id",
                "a base id whose frames (base + 0x16) fit the id format",
                err,
            )
        })?;
        let output = OutputConfig {
            base_id,
            pose_rate_hz: self.positive("output.pose_rate_hz", o.pose_rate_hz)?,
            publish_on_update: o.publish_on_update,
            stats_interval_s: self.positive("output.stats_interval_s", o.stats_interval_s)?,
        };
        for w in [wheels.rear_left, wheels.front_left, steering] {
            let id = db.messages()[w.message_index].id();
            let own = (0..=canodom_protocol::own_dbc::MAX_OFFSET).any(|off| {
                base_id.id().raw() + off == id.raw()
                    && base_id.id().is_extended() == id.is_extended()
            });
            if own {
                return Err(self.err(
                    "output.base_id",
                    "own frame ids (base .. base + 0x16) clear of the input messages",
                    format!("{:#x}", o.base_id),
                ));
            }
        }

        let mut calibration = self.calibration(&raw.calibration, base_id, &params)?;
        calibration.fixes = match &raw.calibration.fixes {
            None => None,
            Some(f) => {
                let fixes = self.fix_signals(&db, f)?;
                let inputs = [
                    wheels.rear_left.message_index,
                    wheels.front_left.message_index,
                    steering.message_index,
                ];
                if inputs.contains(&fixes.message_index)
                    || yaw_rate.is_some_and(|y| y.signal.message_index == fixes.message_index)
                {
                    return Err(self.err(
                        "calibration.fixes",
                        "signals of a message that is not an odometry input",
                        db.messages()[fixes.message_index].name(),
                    ));
                }
                Some(fixes)
            }
        };

        Ok(Config {
            file: self.file.to_owned(),
            interface: iface,
            dbc_path,
            db,
            params,
            signals: Signals {
                wheels,
                steering,
                wheel_kind,
                steering_kind,
                tick_bits,
                yaw_rate,
                wheel_speed_factor,
                direction,
            },
            checks,
            inputs,
            ekf,
            output,
            security: crate::security::validate(
                self.file,
                raw.security.as_ref(),
                &calibration.param_file,
            )
            .map_err(|e| match e {
                crate::security::SecurityError::Invalid(key, expected, got) => {
                    self.err(&key, &expected, got)
                }
                crate::security::SecurityError::KeyFile(path, reason) => ConfigError::KeyFile {
                    file: self.file.to_owned(),
                    path,
                    reason,
                },
            })?,
            calibration,
        })
    }

    fn calibration(
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
        })
    }

    /// The `[calibration.fixes]` signals: `x` and `y`, or `latitude` and
    /// `longitude`, of one message.
    fn fix_signals(&self, db: &Database, f: &RawFixes) -> Result<FixSignals, ConfigError> {
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

/// The unit the DBC gives an input's main signal.
fn unit_of(db: &Database, sig: &InputSignal) -> String {
    db.messages()[sig.message_index].signals()[sig.handle.signal_index()]
        .unit()
        .to_owned()
}

/// The byte a checksum signal occupies, if it is a whole byte.
fn checksum_byte(m: &canodom_dbc::Message, h: SignalHandle) -> Option<usize> {
    if h.size() != 8 {
        return None;
    }
    let mut probe = vec![0u8; m.length()];
    if !h.encode_raw(0xFF, &mut probe) {
        return None;
    }
    let set: Vec<usize> = (0..probe.len()).filter(|&b| probe[b] != 0).collect();
    match set.as_slice() {
        [b] if probe[*b] == 0xFF && (*b == 0 || *b + 1 == probe.len()) => Some(*b),
        _ => None,
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub(crate) const RC_CAR: &str = r#"
[can]
interface = "vcan0"
dbc = "rc_car.dbc"

[vehicle]
wheelbase_m = 0.26
rear_tread_m = 0.30
front_tread_m = 0.30
wheel_diameter_m = 0.09
encoder_ticks_per_rev = 1024

[signals]
rear_left = "WHEEL_ENC_REAR.RL_TICKS"
rear_right = "WHEEL_ENC_REAR.RR_TICKS"
front_left = "WHEEL_ENC_FRONT.FL_TICKS"
front_right = "WHEEL_ENC_FRONT.FR_TICKS"
steering = "STEERING.STEER_ANGLE"
wheel_kind = "ticks"
steering_kind = "road_wheel"

[checks.WHEEL_ENC_REAR]
counter = "COUNTER"
checksum = "CHECKSUM"
algorithm = "crc8_sae_j1850"
"#;

    fn path() -> PathBuf {
        PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../data/dbc/x.toml"))
    }

    #[test]
    fn issue_example_loads() {
        let c = Config::from_toml(RC_CAR, &path()).unwrap();
        assert_eq!(c.interface, "vcan0");
        assert_eq!(c.signals.wheel_kind, WheelKind::Ticks);
        assert_eq!(c.signals.tick_bits, 16);
        assert_eq!(c.checks.len(), 1);
        let crc = c.checks[0].checksum.as_ref().unwrap();
        assert_eq!(crc, &FrameChecksum::Bytes(Checksum::rc_car()));
        assert!((c.params.steering().gain - 1f64.to_radians()).abs() < 1e-15);
        assert_eq!(c.output.pose_rate_hz, 50.0);
        assert_eq!(c.ekf, EkfConfig::new(c.params));
        assert_eq!(c.input_ids().len(), 3);
    }

    #[test]
    fn ekf_and_output_keys_reach_the_typed_config() {
        let text = format!(
            "{RC_CAR}\n[ekf]\nk_rear_m = 2e-5\nsteer_sigma_deg = 1.0\ncorrect_every = 20\n\
             gate_enabled = false\nlearn_steer_offset = false\n\
             [output]\nbase_id = 0x18FF0000\nextended = true\npose_rate_hz = 10.0\n\
             [inputs]\ntimeout_factor = 5.0\ntrusted_after_frames = 2\n"
        );
        let c = Config::from_toml(&text, &path()).unwrap();
        assert_eq!(c.ekf.k_rear_m, 2e-5);
        assert!((c.ekf.steer_sigma_rad - 1f64.to_radians()).abs() < 1e-15);
        assert_eq!(c.ekf.correct_every, 20);
        assert_eq!(c.ekf.gate_threshold, None);
        assert_eq!(c.ekf.steer_offset_drift_rad, None);
        assert_eq!(
            c.output.base_id.id(),
            canodom_can::frame::FrameId::Extended(0x18FF_0000)
        );
        assert_eq!(c.output.pose_rate_hz, 10.0);
        assert_eq!(c.inputs.timeout_factor, 5.0);
        assert_eq!(c.inputs.trusted_after_frames, 2);
        assert_eq!(c.inputs.max_wheel_speed_mps, 5.0);
    }

    /// The RAV4 configuration with a yaw-rate sensor, and `extra` appended.
    fn rav4_yaw(extra: &str) -> Result<Config, ConfigError> {
        let file = PathBuf::from(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../data/comma2k19-rav4/config_yaw.toml"
        ));
        let text = std::fs::read_to_string(&file).unwrap();
        assert!(
            !text.contains("[ekf]"),
            "config_yaw.toml grew an [ekf] table"
        );
        Config::from_toml(&format!("{text}\n{extra}"), &file)
    }

    #[test]
    fn an_empty_ekf_table_is_the_filters_default_with_the_dbcs_yaw_quantum() {
        let c = rav4_yaw("[ekf]\n").unwrap();
        // KINEMATICS.YAW_RATE counts in 0.244 deg/s steps.
        let quantum = 0.244f64.to_radians();
        assert!((c.ekf.yaw_quantum_radps - quantum).abs() < 1e-15);
        let want = EkfConfig {
            yaw_quantum_radps: c.ekf.yaw_quantum_radps,
            ..EkfConfig::new(c.params)
        };
        assert_eq!(c.ekf, want);
        assert_eq!(rav4_yaw("").unwrap().ekf, want);
    }

    #[test]
    fn the_slide_keys_reach_their_fields_and_a_zero_deceleration_is_refused() {
        let c = rav4_yaw(
            "[ekf]\nmax_accel_mps2 = 10.0\nslide_decel_mps2 = 5.0\nslide_decel_sigma_mps2 = 1.5\n",
        )
        .unwrap();
        assert_eq!(c.ekf.max_accel_mps2, 10.0);
        assert_eq!(c.ekf.slide_decel_mps2, 5.0);
        assert_eq!(c.ekf.slide_decel_sigma_mps2, 1.5);
        let d = EkfConfig::new(c.params);
        assert_ne!(d.max_accel_mps2, 10.0);
        assert_ne!(d.slide_decel_mps2, 5.0);
        assert_ne!(d.slide_decel_sigma_mps2, 1.5);
        for bad in [
            "slide_decel_mps2 = 0.0",
            "max_accel_mps2 = -1.0",
            "slide_decel_sigma_mps2 = -0.5",
        ] {
            let e = rav4_yaw(&format!("[ekf]\n{bad}\n"))
                .unwrap_err()
                .to_string();
            let key = bad.split(' ').next().unwrap();
            assert!(e.contains(&format!("ekf.{key}")), "{bad}: {e}");
        }
    }

    #[test]
    fn every_ekf_key_reaches_its_field_in_its_unit() {
        use canodom_fusion::ekf::GateAction;
        let c = rav4_yaw(
            "[ekf]\nfront_scale_sigma = 0.02\nmin_slip_ratio = 0.1\nblend_accepted = true\n\
             gate_action = \"keep_rear\"\nyaw_gate_sigma = 4.0\nyaw_sigma_deg_s = 0.2\n\
             yaw_bias_walk_deg_s_per_sqrt_s = 0.001\nyaw_bias_sigma_deg_s = 0.3\n\
             yaw_scale_sigma = 0.01\nrear_ratio_sigma = 0.002\nratio_walk = 1e-4\n\
             tread_sigma = 0.04\ntread_turn_sigma = 0.03\nwheel_turn_sigma_deg = 0.02\n\
             distance_scale_sigma = 0.004\nstill_min_s = 3.0\naided_window_s = 1.0\n\
             steer_offset_drift_deg = 0.01\nfront_scale_drift = 1e-4\n",
        )
        .unwrap();
        let e = c.ekf;
        let deg = f64::to_radians;
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-15 * b.abs();
        assert_eq!(e.front_scale_sigma, 0.02);
        assert_eq!(e.min_slip_ratio, 0.1);
        assert!(e.blend_accepted);
        assert_eq!(e.gate_action, GateAction::KeepRear);
        assert_eq!(e.yaw_gate_sigma, 4.0);
        assert!(close(e.yaw_sigma_radps, deg(0.2)));
        assert!(close(e.yaw_bias_walk_radps, deg(0.001)));
        assert!(close(e.yaw_bias_sigma_radps, deg(0.3)));
        assert_eq!(e.yaw_scale_sigma, 0.01);
        assert_eq!(e.rear_ratio_sigma, 0.002);
        assert_eq!(e.ratio_walk, 1e-4);
        assert_eq!(e.tread_sigma, 0.04);
        assert_eq!(e.tread_turn_sigma, 0.03);
        assert!(close(e.wheel_turn_sigma_rad, deg(0.02)));
        assert_eq!(e.distance_scale_sigma, 0.004);
        assert_eq!(e.still_min_s, 3.0);
        assert_eq!(e.aided_window_s, 1.0);
        assert!(close(e.steer_offset_drift_rad.unwrap(), deg(0.01)));
        assert_eq!(e.front_scale_drift, Some(1e-4));
        // Every key set differs from its default: none was silently dropped.
        let d = EkfConfig::new(c.params);
        for (name, set, default) in [
            (
                "front_scale_sigma",
                e.front_scale_sigma,
                d.front_scale_sigma,
            ),
            ("min_slip_ratio", e.min_slip_ratio, d.min_slip_ratio),
            ("yaw_gate_sigma", e.yaw_gate_sigma, d.yaw_gate_sigma),
            ("yaw_sigma", e.yaw_sigma_radps, d.yaw_sigma_radps),
            (
                "yaw_bias_walk",
                e.yaw_bias_walk_radps,
                d.yaw_bias_walk_radps,
            ),
            (
                "yaw_bias_sigma",
                e.yaw_bias_sigma_radps,
                d.yaw_bias_sigma_radps,
            ),
            ("yaw_scale_sigma", e.yaw_scale_sigma, d.yaw_scale_sigma),
            ("rear_ratio_sigma", e.rear_ratio_sigma, d.rear_ratio_sigma),
            ("ratio_walk", e.ratio_walk, d.ratio_walk),
            ("tread_sigma", e.tread_sigma, d.tread_sigma),
            ("tread_turn_sigma", e.tread_turn_sigma, d.tread_turn_sigma),
            (
                "wheel_turn_sigma",
                e.wheel_turn_sigma_rad,
                d.wheel_turn_sigma_rad,
            ),
            (
                "distance_scale_sigma",
                e.distance_scale_sigma,
                d.distance_scale_sigma,
            ),
            ("still_min_s", e.still_min_s, d.still_min_s),
            ("aided_window_s", e.aided_window_s, d.aided_window_s),
        ] {
            assert_ne!(set, default, "{name}");
        }
    }

    #[test]
    fn bad_ekf_values_are_named_with_what_was_expected() {
        for (line, key, expected) in [
            ("yaw_sigma_deg_s = 0.0", "ekf.yaw_sigma_deg_s", "> 0"),
            ("tread_sigma = -0.1", "ekf.tread_sigma", "> 0"),
            ("aided_window_s = nan", "ekf.aided_window_s", "> 0"),
            ("min_slip_ratio = -0.05", "ekf.min_slip_ratio", ">= 0"),
            ("still_min_s = inf", "ekf.still_min_s", ">= 0"),
            (
                "yaw_bias_walk_deg_s_per_sqrt_s = -1e-3",
                "ekf.yaw_bias_walk_deg_s_per_sqrt_s",
                ">= 0",
            ),
            ("yaw_gate_sigma = 0", "ekf.yaw_gate_sigma", "> 0"),
            ("gate_action = \"front\"", "ekf.gate_action", "keep_rear"),
            ("front_scale_drift = -1.0", "ekf.front_scale_drift", ">= 0"),
            (
                "learn_steer_offset = false\nsteer_offset_drift_deg = 0.01",
                "ekf.steer_offset_drift_deg",
                "learn_steer_offset = false",
            ),
        ] {
            let e = rav4_yaw(&format!("[ekf]\n{line}\n"))
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("config_yaw.toml") && e.contains(key) && e.contains(expected),
                "{line}: {e}"
            );
        }
        // A key with its unit missing is an unknown key, named.
        let e = rav4_yaw("[ekf]\nyaw_sigma = 0.2\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("yaw_sigma"), "{e}");
    }

    fn invalid(text: &str) -> String {
        let e = Config::from_toml(text, &path()).unwrap_err();
        let s = e.to_string();
        assert!(s.contains("x.toml"), "{s}");
        s
    }

    #[test]
    fn unknown_key_is_named() {
        let s = invalid(&RC_CAR.replace("wheelbase_m", "wheelbase_mm"));
        assert!(s.contains("wheelbase_mm"), "{s}");
        let s = invalid(&format!("{RC_CAR}\n[output]\npose_rate = 5\n"));
        assert!(s.contains("pose_rate"), "{s}");
    }

    #[test]
    fn missing_signal_is_named() {
        let s = invalid(&RC_CAR.replace("RR_TICKS", "RR_TICK"));
        assert!(
            s.contains("signals.rear_right") && s.contains("RR_TICK"),
            "{s}"
        );
    }

    #[test]
    fn bad_values_are_named() {
        let s = invalid(&RC_CAR.replace("0.26", "-1.0"));
        assert!(
            s.contains("vehicle.wheelbase_m") && s.contains("> 0"),
            "{s}"
        );
        let s = invalid(&RC_CAR.replace("\"ticks\"", "\"pulses\""));
        assert!(s.contains("signals.wheel_kind"), "{s}");
        // A missing kind is named with the values it takes (it was a TOML
        // parse error without them).
        let s = invalid(&RC_CAR.replace("wheel_kind = \"ticks\"\n", ""));
        assert!(
            s.contains("signals.wheel_kind") && s.contains("\"speed\"") && s.contains("nothing"),
            "{s}"
        );
        // Tick encoders need the diameter (speed signals do not: the daemon's
        // config_errors test loads the Toyota example without it).
        assert!(RC_CAR.contains("wheel_diameter_m = 0.09\n"));
        let s = invalid(&RC_CAR.replace("wheel_diameter_m = 0.09\n", ""));
        assert!(
            s.contains("vehicle.wheel_diameter_m") && s.contains("tick encoders count revolutions"),
            "{s}"
        );
        let s = invalid(&RC_CAR.replace("steering_kind = \"road_wheel\"\n", ""));
        assert!(
            s.contains("signals.steering_kind") && s.contains("\"steering_wheel\""),
            "{s}"
        );
        let s = invalid(&RC_CAR.replace("crc8_sae_j1850", "crc32"));
        assert!(s.contains("checks.WHEEL_ENC_REAR.algorithm"), "{s}");
        let s = invalid(&RC_CAR.replace("rc_car.dbc", "nope.dbc"));
        assert!(s.contains("can.dbc"), "{s}");
        let s = invalid(&RC_CAR.replace("road_wheel", "steering_wheel"));
        assert!(s.contains("vehicle.steering_ratio"), "{s}");
        let s = invalid(&format!("{RC_CAR}\n[output]\nbase_id = 0x100\n"));
        assert!(s.contains("output.base_id"), "{s}");
        let s = invalid(&format!("{RC_CAR}\n[calibration]\nparam_file = \"\"\n"));
        assert!(s.contains("calibration.param_file"), "{s}");
    }

    #[test]
    fn param_file_defaults_to_the_state_directory_under_systemd() {
        let config = Path::new("/etc/canodom/canodom.toml");
        let state = |s: &str| default_param_file(config, Some(OsStr::new(s)));
        assert_eq!(
            state("/var/lib/canodom"),
            Path::new("/var/lib/canodom/canodom-params.toml")
        );
        // Several StateDirectory= entries: the first is canodom's.
        assert_eq!(
            state("/var/lib/canodom:/var/lib/other"),
            Path::new("/var/lib/canodom/canodom-params.toml")
        );
        // Without systemd (or an empty variable): beside the configuration.
        let beside_config = Path::new("/etc/canodom/canodom-params.toml");
        assert_eq!(state(""), beside_config);
        assert_eq!(default_param_file(config, None), beside_config);
        assert_eq!(
            default_param_file(Path::new("car.toml"), None),
            Path::new("canodom-params.toml")
        );
    }

    #[test]
    fn relative_paths_are_taken_from_the_configuration_folder() {
        let dir = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../data/dbc"));
        let c = Config::from_toml(
            &format!("{RC_CAR}\n[calibration]\nparam_file = \"../state/p.toml\"\n"),
            &path(),
        )
        .unwrap();
        assert_eq!(c.dbc_path, dir.join("rc_car.dbc"));
        assert_eq!(c.calibration.param_file, dir.join("../state/p.toml"));
        let c = Config::from_toml(
            &format!("{RC_CAR}\n[calibration]\nparam_file = \"/var/lib/x/p.toml\"\n"),
            &path(),
        )
        .unwrap();
        assert_eq!(c.calibration.param_file, Path::new("/var/lib/x/p.toml"));
    }

    fn scratch(tag: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("canodom-config-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn with_param_file(param_file: &Path) -> Config {
        let mut c = Config::from_toml(RC_CAR, &path()).unwrap();
        c.calibration.param_file = param_file.to_owned();
        c
    }

    #[test]
    fn param_file_check_leaves_an_existing_file_and_no_probe() {
        let dir = scratch("probe-ok");
        let file = dir.join("p.toml");
        with_param_file(&file).check_param_file().unwrap();
        assert!(!file.exists(), "the check creates no parameter file");
        std::fs::write(&file, "kept").unwrap();
        with_param_file(&file).check_param_file().unwrap();
        assert_eq!(std::fs::read_to_string(&file).unwrap(), "kept");
        let left: Vec<_> = std::fs::read_dir(&dir).unwrap().collect();
        assert_eq!(left.len(), 1, "only the parameter file: {left:?}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn param_file_check_names_key_path_and_one_os_reason() {
        let dir = scratch("probe-bad");
        // A file where a folder should be: refused even for root.
        std::fs::write(dir.join("not-a-folder"), "").unwrap();
        for file in [
            dir.join("not-a-folder/p.toml"),
            dir.join("missing/p.toml"),
            dir,
        ] {
            let e = with_param_file(&file).check_param_file().unwrap_err();
            assert!(matches!(e, ConfigError::ParamFile { .. }), "{e:?}");
            let s = e.to_string();
            assert!(s.contains("x.toml"), "{s}");
            assert!(s.contains("calibration.param_file"), "{s}");
            assert!(s.contains(&file.display().to_string()), "{s}");
            assert_eq!(s.matches("(os error").count(), 1, "{s}");
            assert!(std::error::Error::source(&e).is_none(), "printed once: {s}");
        }
    }
}
