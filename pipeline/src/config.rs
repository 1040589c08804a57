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
//! `[security]` (the SecOC key and freshness; see [`crate::security`]), and
//! `[gnss]` (a live GNSS source, gpsd or a ROS 2 topic; see [`GnssConfig`]).

mod calibration;
mod ekf;
mod gnss;
mod raw;
mod validate;
mod validator;

use crate::signal_forms::{DirectionSignal, Saturation, SignalForm};
use canodom_dbc::{Database, FrameChecksum, SignalHandle};
use canodom_fusion::ekf::EkfConfig;
use canodom_fusion::wheel::SpeedUnit;
use canodom_fusion::{VehicleParams, WheelSet};
use canodom_protocol::own_dbc::BaseId;
pub use gnss::{
    DEFAULT_GPSD_ADDRESS, DEFAULT_MAX_ERROR_M, DEFAULT_NMEA_MAX_ERROR_M, GnssConfig, GnssSource,
    NMEA_BAUD_RATES,
};
use raw::RawConfig;
use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use validator::Validator;

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

/// The unit's own state directory from [`STATE_DIRECTORY_ENV`]'s value: the
/// first of the list, `None` when unset or empty.
pub fn unit_state_directory(state_directory: Option<&OsStr>) -> Option<PathBuf> {
    state_directory
        .and_then(|dirs| std::env::split_paths(dirs).next())
        .filter(|dir| !dir.as_os_str().is_empty())
}

/// Name of the parameter file when `[calibration] param_file` is not set.
pub const DEFAULT_PARAM_FILE: &str = "canodom-params.toml";

/// Where the parameter file goes when `[calibration] param_file` is not set:
/// in the state directory when systemd gives one (the unit's `/etc/canodom`
/// is read-only, so a file beside the configuration could never be
/// committed), else beside the configuration file.
pub fn default_param_file(config_file: &Path, state_directory: Option<&OsStr>) -> PathBuf {
    match unit_state_directory(state_directory) {
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

/// The wheel diameter a configuration with speed signals and no
/// `vehicle.wheel_diameter_m` uses, metres: a typical road car's. With
/// speeds it only scales revolutions and is what a calibrated diameter is
/// relative to; distances do not depend on it.
pub const SPEED_SENSOR_REFERENCE_DIAMETER_M: f64 = 0.65;

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
    /// The second gear message `direction` names, for the other gearbox of
    /// the car line: whichever of the two is on the bus says it.
    pub direction_alt: Option<DirectionSignal>,
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
    /// Where its readings are at an end of the DBC signal's range (in the
    /// signal's unit): not given to the filter.
    pub saturation: Saturation,
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
    /// The residual at the fixes (weighted RMS) a drive's fit may leave
    /// beyond what the fixes' own noise explains, for anything to be
    /// committed, m (default 2): the limit is `√(2σ² + this²)`, σ the fixes'
    /// per axis (stated by them, else estimated from the residuals; at most
    /// `max_fix_sigma_m`). Before issue #46 it was the limit itself.
    pub max_fix_residual_m: f64,
    /// The largest σ per axis of the fixes, m, that the residual gate allows
    /// for (default 3: a consumer receiver without corrections is 1–3 m);
    /// a larger stated or estimated σ is taken as this.
    pub max_fix_sigma_m: f64,
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
    /// The online calibration's refits and the drift watch (`[calibration.drift]`).
    pub drift: DriftWatchConfig,
    /// Whether the daemon commits the drift watch's learnt set by itself
    /// at a standstill, each parameter moved at most
    /// [`canodom_calib::drift::AUTO_STEP_TOLERANCES`] of its drift
    /// tolerance per commit (`[calibration] auto_commit`, default false:
    /// the operator commits it with COMMIT).
    pub auto_commit: bool,
}

/// `[calibration.drift]` (#46 item 3): the drift watch's refits of the
/// drive against the fixes, and its tolerances.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DriftWatchConfig {
    /// The tolerances (radians and rad/s inside; configured in degrees) and
    /// the σ multiple (see [`canodom_calib::drift::DriftConfig::default`]).
    pub judge: canodom_calib::drift::DriftConfig,
    /// The least fix time between two of the watch's refits, s (default 60).
    pub every_s: f64,
    /// Each of the watch's refits fits the last this many seconds of the
    /// drive (default 180). The drive fit holds on to the value from before
    /// a change until the change fills most of its window (measured on a
    /// tyre that changes mid-drive: a 600 s window flagged it 600 s later, a
    /// 300 s one 300 s later), so a change is flagged about `window_s +
    /// every_s` after it: 240 s, 2.7 km at 40 km/h, inside issue #46's 3 km.
    /// A window much shorter leaves the rear ratio's σ above a fifth of the
    /// 0.5 % to be seen (0.07 % over 180 s measured). A refit is judged
    /// only once its fixes span nine tenths of the window
    /// ([`canodom_calib::drift::window_is_full`]): the first `window_s` of
    /// a drive's fixes, or of fixes back after a longer outage, flag nothing.
    pub window_s: f64,
}

impl Default for DriftWatchConfig {
    fn default() -> Self {
        Self {
            judge: canodom_calib::drift::DriftConfig::default(),
            every_s: 60.0,
            window_s: 180.0,
        }
    }
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
    /// The `[ros2]` section as written (#43), read by `canodom-ros2`.
    pub ros2: Option<toml::Table>,
    /// A live GNSS source (`[gnss]`, #46); `None` without the section.
    pub gnss: Option<GnssConfig>,
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

#[cfg(test)]
pub(crate) mod tests;
