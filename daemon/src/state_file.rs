//! The state `canodom run --state-file PATH` leaves behind when it stops
//! (SIGTERM, SIGINT): where the vehicle was, how sure the filter was, what
//! the pipeline did with every frame, and the parameters it ran with.
//!
//! What is saved is the daemon's end state after the pipeline task has
//! drained every frame already queued (see [`crate::server`]): the pose of
//! the last filter step, the position and heading standard deviations of
//! its covariance, the complete statistics (every reject reason, zeros
//! included, so a reader never mistakes "absent" for "not counted"), the
//! pose samples published, frames lost, connections and outages, and the
//! vehicle parameters in use.
//!
//! The file is JSON, written atomically and durably: a temporary file in
//! the same directory is written and `fsync`ed, renamed over the target,
//! and the directory `fsync`ed, so a crash or power loss at any instant
//! leaves either the previous complete file or the new complete one, never
//! a torn one. The daemon writes it every `--state-every-s` seconds while
//! it runs, at once after a parameter set was applied, and when it stops
//! ([`write_latest`], on tokio's blocking pool: the odometry task only hands
//! over a copy of its state and never waits for the disk), so a power cut
//! loses at most the last period of learning.
//!
//! The learnt values are corrections relative to the parameter set they
//! were learnt on, so the file records that set's identity
//! ([`ParamIdentity`]: its version and a checksum of the values in use); a
//! start on another set (a commit while the daemon was down, an edited
//! configuration) drops them with a warning naming both ([`restore`]).

use crate::summary::Summary;
use canodom_pipeline::config::Config;
use canodom_pipeline::param_set::ParamIdentity;
use canodom_pipeline::stats::{Reject, Stats};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use tokio::sync::watch;
use tracing::{info, warn};

/// Version of the layout written by this code (2: the parameter set's
/// identity; a file of version 1 cannot tell what its values were learnt on
/// and is refused).
pub const FORMAT_VERSION: u32 = 2;

/// How often the daemon writes the state file by default, seconds.
pub const DEFAULT_EVERY_S: f64 = 10.0;

/// Where and how often the daemon keeps its state (`run --state-file`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StateFileOptions {
    /// The file.
    pub path: PathBuf,
    /// The longest time between two writes while running: what a power cut
    /// may lose.
    pub every: Duration,
}

/// Why the state file cannot be written or read.
#[derive(Debug, thiserror::Error)]
pub enum StateFileError {
    /// A file system operation failed.
    #[error("{path}: {source}")]
    Io {
        /// The path that failed.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// The text is not a state file of this version.
    #[error("{path}: {reason}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
}

/// The pose of the last filter step.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SavedPose {
    /// Seconds since the first input frame of the run.
    pub t_s: f64,
    /// Position of the rear-axle centre, metres.
    pub x_m: f64,
    /// Position, metres.
    pub y_m: f64,
    /// Heading in (−π, π], as the pose frames carry it.
    pub heading_rad: f64,
    /// Heading as the total turn since the start.
    pub heading_unwrapped_rad: f64,
}

/// The filter's uncertainty at the end, as the pose frames summarise it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SavedCovariance {
    /// Square root of the largest eigenvalue of the x/y covariance, metres.
    pub pos_std_m: f64,
    /// Standard deviation of the heading, radians.
    pub heading_std_rad: f64,
    /// The full 3×3 covariance of (x, y, heading), row by row.
    pub p: [[f64; 3]; 3],
}

/// The pipeline's statistics.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SavedStats {
    /// Frames offered to the pipeline.
    pub frames: u64,
    /// Frames used.
    pub used: u64,
    /// Filter steps.
    pub steps: u64,
    /// Steps without a valid front window.
    pub steps_without_front: u64,
    /// Every reject reason by its log name ([`Reject::as_str`]), zeros included.
    pub rejects: BTreeMap<String, u64>,
}

impl From<&Stats> for SavedStats {
    fn from(s: &Stats) -> Self {
        Self {
            frames: s.frames,
            used: s.used,
            steps: s.steps,
            steps_without_front: s.steps_without_front,
            rejects: Reject::ALL
                .iter()
                .map(|&r| (r.as_str().to_owned(), s.get(r)))
                .collect(),
        }
    }
}

/// The vehicle parameters the filter ran with.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SavedParams {
    /// Wheelbase, metres.
    pub wheelbase_m: f64,
    /// Rear tread, metres.
    pub rear_tread_m: f64,
    /// Front tread, metres.
    pub front_tread_m: f64,
    /// Rear-left wheel diameter, metres.
    pub rear_left_diameter_m: f64,
    /// Rear-right wheel diameter, metres.
    pub rear_right_diameter_m: f64,
    /// Front-left wheel diameter, metres.
    pub front_left_diameter_m: f64,
    /// Front-right wheel diameter, metres.
    pub front_right_diameter_m: f64,
    /// Road-wheel radians per unit of the steering signal.
    pub steering_gain: f64,
    /// Road-wheel angle at a zero steering signal, radians.
    pub steering_offset_rad: f64,
}

/// The identity of the parameter set the learnt values were learnt on.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SavedParamSet {
    /// The calibrated set's version; `null`: the configuration's nominal parameters.
    pub version: Option<u16>,
    /// CRC-32 of the values in use, 8 hex digits (as the parameter file writes its checksums).
    pub values_crc32: String,
}

impl From<ParamIdentity> for SavedParamSet {
    fn from(id: ParamIdentity) -> Self {
        Self {
            version: id.version,
            values_crc32: format!("{:08x}", id.values_crc32),
        }
    }
}

impl SavedParamSet {
    /// The identity, or why the text is not one.
    ///
    /// # Errors
    /// `values_crc32` is not 8 hex digits.
    pub fn identity(&self) -> Result<ParamIdentity, String> {
        match u32::from_str_radix(&self.values_crc32, 16) {
            Ok(values_crc32) if self.values_crc32.len() == 8 => Ok(ParamIdentity {
                version: self.version,
                values_crc32,
            }),
            _ => Err(format!(
                "param_set.values_crc32 {:?} is not 8 hex digits",
                self.values_crc32
            )),
        }
    }
}

/// Everything the state file holds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SavedState {
    /// [`FORMAT_VERSION`].
    pub format_version: u32,
    /// The parameter set in use when the file was written: the one the
    /// learnt values were learnt on.
    pub param_set: SavedParamSet,
    /// Wall-clock time of the save, µs since the Unix epoch.
    pub saved_at_unix_us: u64,
    /// The CAN interface.
    pub interface: String,
    /// The configuration file.
    pub config: PathBuf,
    /// The last filter step's pose; `None` when no step was made.
    pub pose: Option<SavedPose>,
    /// The final covariance.
    pub covariance: SavedCovariance,
    /// The pipeline's statistics.
    pub stats: SavedStats,
    /// Pose samples published.
    pub poses_published: u64,
    /// Frames the transport reported lost (kernel socket drops included).
    pub frames_lost: u64,
    /// Connections opened (1 + reconnects).
    pub connections: u64,
    /// Outages seen.
    pub outages: u64,
    /// The parameters in use.
    pub params: SavedParams,
    /// What the filter learnt about the vehicle online; `run --state-file`
    /// restores it at the next start (absent in files of older versions).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub learnt: Option<SavedLearnt>,
    /// The drift watch (#46 item 3): absent before its first refit, and in
    /// files of older versions.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drift: Option<SavedDrift>,
}

/// The drift watch as the state file shows it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SavedDrift {
    /// Refits judged since the daemon started.
    pub refits: u64,
    /// The flagged parameters (`canodom_calib::drift::Param::name`).
    pub flagged: Vec<String>,
    /// When the last refit was made: its last fix's bus time, s (Unix time
    /// on a live bus).
    pub at_unix_s: Option<f64>,
    /// Distance driven since the daemon started, at the last refit, m.
    pub distance_m: f64,
    /// What the last refit learnt, each with its σ and the value in use.
    pub learnt: Vec<SavedDriftReading>,
    /// The learnt set offered for COMMIT, if one is.
    pub candidate: Option<canodom_params::persist::ParamValues>,
    /// The front tyres' ratio the watch judges `front_ratio` against (its
    /// first reading, or one a previous run read): no parameter set
    /// carries the front tyres, so the next start takes it from here.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub front_ratio_first_read: Option<SavedFrontRatio>,
}

/// The front tyres' right/left ratio the drift watch judges against.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SavedFrontRatio {
    /// The ratio (front-right's effective diameter over front-left's,
    /// relative to the diameters in use).
    pub ratio: f64,
    /// Its σ.
    pub sigma: f64,
}

/// One parameter of the last refit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SavedDriftReading {
    /// Which.
    pub parameter: String,
    /// The learnt value (relative parameters relative to the set the drive
    /// was read with).
    pub learnt: f64,
    /// Its σ.
    pub sigma: f64,
    /// The set in use's value on the same scale (for `front_ratio`, which
    /// no set carries, the watch's first reading of it).
    pub in_use: f64,
    /// Whether it is flagged.
    pub flagged: bool,
}

impl From<&canodom_live::drift_watch::DriftReport> for SavedDrift {
    fn from(d: &canodom_live::drift_watch::DriftReport) -> Self {
        Self {
            refits: d.refits,
            flagged: d.flagged.iter().map(|p| p.name().to_owned()).collect(),
            at_unix_s: d.t_s,
            distance_m: d.distance_m,
            learnt: d
                .readings
                .iter()
                .map(|r| SavedDriftReading {
                    parameter: r.param.name().to_owned(),
                    learnt: r.learnt,
                    sigma: r.sigma,
                    in_use: r.in_use,
                    flagged: d.flagged.contains(&r.param),
                })
                .collect(),
            candidate: d.candidate,
            front_ratio_first_read: d.front_baseline.map(|f| SavedFrontRatio {
                ratio: f.value,
                sigma: f.sigma,
            }),
        }
    }
}

/// The front tyres' ratio the drift watch of the run that wrote `state`
/// judged against: what the next start's watch judges against, since no
/// parameter set carries the front tyres.
/// The watch judges whether it is plausible
/// (`canodom_calib::drift::Watcher::restore_front_baseline`).
pub fn saved_front_baseline(state: &SavedState) -> Option<canodom_calib::front_ratio::FrontRatio> {
    let f = state.drift.as_ref()?.front_ratio_first_read?;
    Some(canodom_calib::front_ratio::FrontRatio {
        value: f.ratio,
        sigma: f.sigma,
        distance_m: 0.0,
    })
}

pub use canodom_params::learnt::{
    LearntOutOfBounds, SavedFault, SavedLearnt, SavedWheelFault, learnt_bounds,
};

/// What a start takes from a previous run's state file.
#[derive(Debug, PartialEq)]
pub enum Restored {
    /// No file: a first start.
    Nothing,
    /// The learnt values, checked.
    Learnt(canodom_fusion::ekf::Learnt),
    /// The file is damaged, of another version, or a value is out of
    /// bounds: the filter starts from its priors (the caller warns).
    Refused(String),
    /// The values were learnt on another parameter set than the one in use:
    /// dropped, the filter starts from its priors (the caller warns).
    OtherParamSet {
        /// The set the file's values were learnt on.
        saved: ParamIdentity,
        /// The set in use now.
        in_use: ParamIdentity,
    },
}

/// The learnt values of the state file at `path`, if it exists, was learnt
/// on the parameter set `in_use`, and its values pass [`SavedLearnt::checked`].
pub fn restore(path: &Path, in_use: &ParamIdentity) -> Restored {
    match load(path) {
        Err(StateFileError::Io { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => {
            Restored::Nothing
        }
        Err(e) => Restored::Refused(e.to_string()),
        Ok(saved) => match saved.param_set.identity() {
            Err(e) => Restored::Refused(format!("{}: {e}", path.display())),
            Ok(id) if id != *in_use => Restored::OtherParamSet {
                saved: id,
                in_use: *in_use,
            },
            Ok(_) => match saved.learnt.map(|l| l.checked()) {
                None => Restored::Nothing,
                Some(Ok(learnt)) => Restored::Learnt(learnt),
                Some(Err(e)) => Restored::Refused(format!("{}: {e}", path.display())),
            },
        },
    }
}

/// [`restore`] with its outcome logged: the learnt values to put into the
/// filter, if any.
pub fn restore_logged(path: &Path, in_use: &ParamIdentity) -> Option<canodom_fusion::ekf::Learnt> {
    match restore(path, in_use) {
        Restored::Nothing => None,
        Restored::Learnt(learnt) => {
            info!(file = %path.display(), param_set = %in_use, "learnt values restored from the state file");
            Some(learnt)
        }
        Restored::Refused(why) => {
            warn!(file = %path.display(), cause = %why, "learnt values not restored; the filter starts from its priors");
            None
        }
        Restored::OtherParamSet { saved, in_use } => {
            warn!(file = %path.display(), learnt_on = %saved, in_use = %in_use,
                "learnt values dropped: they were learnt on another parameter set; the filter starts from its priors");
            None
        }
    }
}

/// Writes the newest summary `latest` holds whenever it changes (what the
/// odometry task hands over: periodically, after a set was applied, and at
/// its end), each write on tokio's blocking pool; a summary that arrives
/// while a write is under way waits, and only the newest is written. Ends
/// when the sender is gone and its last summary is written; returns how
/// that last write went (`None`: nothing was handed over).
pub async fn write_latest(
    config: Arc<Config>,
    path: PathBuf,
    mut latest: watch::Receiver<Option<Summary>>,
) -> Option<Result<(), String>> {
    let mut last = None;
    let mut failing = false;
    // `changed` reports a value sent just before the sender went away
    // before it reports the end.
    while latest.changed().await.is_ok() {
        let Some(summary) = latest.borrow_and_update().clone() else {
            continue;
        };
        let (config, file) = (Arc::clone(&config), path.clone());
        let written = tokio::task::spawn_blocking(move || {
            save(&file, &SavedState::new(&config, &summary)).map_err(|e| e.to_string())
        })
        .await
        .unwrap_or_else(|e| Err(format!("{}: state writer failed: {e}", path.display())));
        // A failing disk is logged once, and again when it recovers, not at every period.
        match &written {
            Err(cause) if !failing => {
                warn!(cause = %cause, "state file not written (retried every period)");
                failing = true;
            }
            Ok(()) if failing => {
                info!(file = %path.display(), "state file written again");
                failing = false;
            }
            _ => {}
        }
        last = Some(written);
    }
    last
}

impl SavedState {
    /// The state of a daemon run that ended with `summary` (or stood at
    /// it when a periodic write took it).
    pub fn new(config: &Config, summary: &Summary) -> Self {
        let pose = summary.state.pose();
        let unwrapped = summary.state.pose_unwrapped();
        let p = summary.state.covariance();
        let (a, b, c) = (p[(0, 0)], p[(0, 1)], p[(1, 1)]);
        // The same summary as ODOM_QUALITY.POS_STD: the worst direction.
        let lambda_max = 0.5 * (a + c) + (0.25 * (a - c) * (a - c) + b * b).sqrt();
        // The parameters in use (a calibrated set's), not the configuration's nominal ones.
        let params = &summary.params.params;
        let d = params.wheel_diameters_m();
        let steering = params.steering();
        Self {
            format_version: FORMAT_VERSION,
            param_set: summary.param_identity.into(),
            saved_at_unix_us: SystemTime::now()
                .duration_since(UNIX_EPOCH)
                .map_or(0, |d| d.as_micros() as u64),
            interface: config.interface.clone(),
            config: config.file.clone(),
            pose: summary.last_step.map(|step| SavedPose {
                t_s: step.t_s,
                x_m: pose.x_m,
                y_m: pose.y_m,
                heading_rad: pose.heading_rad,
                heading_unwrapped_rad: unwrapped.heading_rad,
            }),
            covariance: SavedCovariance {
                pos_std_m: lambda_max.max(0.0).sqrt(),
                heading_std_rad: p[(2, 2)].max(0.0).sqrt(),
                p: [0, 1, 2].map(|i| [0, 1, 2].map(|j| p[(i, j)])),
            },
            stats: SavedStats::from(&summary.stats),
            poses_published: summary.poses_published,
            frames_lost: summary.frames_lost,
            connections: summary.connections,
            outages: summary.outages,
            params: SavedParams {
                wheelbase_m: params.wheelbase_m(),
                rear_tread_m: params.rear_tread_m(),
                front_tread_m: params.front_tread_m(),
                rear_left_diameter_m: d.rear_left,
                rear_right_diameter_m: d.rear_right,
                front_left_diameter_m: d.front_left,
                front_right_diameter_m: d.front_right,
                steering_gain: steering.gain,
                steering_offset_rad: steering.offset_rad,
            },
            learnt: Some(SavedLearnt::from_state(&summary.state)),
            drift: summary.drift.as_ref().map(SavedDrift::from),
        }
    }
}

/// Writes `state` to `path` atomically and durably (see the module doc).
///
/// # Errors
/// [`StateFileError::Io`] naming the path that failed; the previous file is
/// then untouched.
pub fn save(path: &Path, state: &SavedState) -> Result<(), StateFileError> {
    let mut text = serde_json::to_string_pretty(state).map_err(|e| StateFileError::Format {
        path: path.to_owned(),
        reason: e.to_string(),
    })?;
    text.push('\n');
    canodom_params::atomic_file::write(path, text.as_bytes()).map_err(|e| StateFileError::Io {
        path: e.path,
        source: e.source,
    })
}

/// Reads a state file written by [`save`].
///
/// # Errors
/// Unreadable file, not JSON of this layout, or another format version.
pub fn load(path: &Path) -> Result<SavedState, StateFileError> {
    /// The version alone, read first: a file of another version is named as
    /// such, not as a missing or unknown field of this one.
    #[derive(Deserialize)]
    struct Versioned {
        format_version: u32,
    }
    let format = |reason: String| StateFileError::Format {
        path: path.to_owned(),
        reason,
    };
    let text = fs::read_to_string(path).map_err(|source| StateFileError::Io {
        path: path.to_owned(),
        source,
    })?;
    let version = serde_json::from_str::<Versioned>(&text)
        .map_err(|e| format(e.to_string()))?
        .format_version;
    if version != FORMAT_VERSION {
        let by = if version < FORMAT_VERSION {
            "an older canodom"
        } else {
            "a newer canodom"
        };
        return Err(format(format!(
            "format_version {version} is not supported (expected {FORMAT_VERSION}; written by {by})"
        )));
    }
    serde_json::from_str(&text).map_err(|e| format(e.to_string()))
}
