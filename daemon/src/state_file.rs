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
//! a torn one.

use crate::server::Summary;
use canodom_pipeline::config::Config;
use canodom_pipeline::stats::{Reject, Stats};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

/// Version of the layout written by this code.
pub const FORMAT_VERSION: u32 = 1;

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

/// Everything the state file holds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SavedState {
    /// [`FORMAT_VERSION`].
    pub format_version: u32,
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
}

/// What the filter learnt online, as saved (see [`canodom_fusion::ekf::Learnt`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SavedLearnt {
    /// The steering sensor's offset, road-wheel radians.
    pub steer_offset_rad: f64,
    /// Its standard deviation (0: not learnt yet).
    pub steer_offset_sigma_rad: f64,
    /// The front wheels' distance factor.
    pub front_scale: f64,
    /// Its standard deviation (0: not learnt yet).
    pub front_scale_sigma: f64,
    /// The yaw-rate sensor's bias, rad/s (with a yaw-rate sensor only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub yaw_bias_radps: Option<f64>,
    /// Its standard deviation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub yaw_bias_sigma_radps: Option<f64>,
    /// The rear diameter ratio's relative error.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rear_ratio_err: Option<f64>,
    /// Its standard deviation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rear_ratio_sigma: Option<f64>,
    /// The effective rear tread's relative error (learnt against the
    /// yaw-rate sensor in turns).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tread_err: Option<f64>,
    /// Its standard deviation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tread_sigma: Option<f64>,
}

/// The largest learnt values a restart takes back: beyond them a saved
/// value is damaged or learnt from nonsense (openpilot has shipped both
/// bugs), and the filter starts from its priors instead.
pub mod learnt_bounds {
    /// Steering offset, road-wheel radians (5°).
    pub const STEER_OFFSET_RAD: f64 = 5.0 * std::f64::consts::PI / 180.0;
    /// Front distance factor's distance from 1 (5 %).
    pub const FRONT_SCALE: f64 = 0.05;
    /// Yaw-rate bias, rad/s (5°/s).
    pub const YAW_BIAS_RADPS: f64 = canodom_params::persist::YAW_BIAS_MAX_RADPS;
    /// Rear ratio error (1 %).
    pub const REAR_RATIO_ERR: f64 = 0.01;
    /// Effective rear tread error (20 %).
    pub const TREAD_ERR: f64 = 0.2;
}

/// A saved learnt value a restart refuses.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error("saved {name} = {value} is outside ±{bound} (or not finite)")]
pub struct LearntOutOfBounds {
    /// The value's name as in the file.
    pub name: &'static str,
    /// The saved value.
    pub value: f64,
    /// The bound it broke.
    pub bound: f64,
}

impl SavedLearnt {
    /// What `state` learnt.
    pub fn from_state(state: &canodom_fusion::ekf::State) -> Self {
        let l = state.learnt();
        Self {
            steer_offset_rad: l.steer_offset_rad,
            steer_offset_sigma_rad: l.steer_offset_sigma_rad,
            front_scale: l.front_scale,
            front_scale_sigma: l.front_scale_sigma,
            yaw_bias_radps: l.yaw_bias.map(|y| y.yaw_bias_radps),
            yaw_bias_sigma_radps: l.yaw_bias.map(|y| y.yaw_bias_sigma_radps),
            rear_ratio_err: l.yaw_bias.map(|y| y.rear_ratio_err),
            rear_ratio_sigma: l.yaw_bias.map(|y| y.rear_ratio_sigma),
            tread_err: l.yaw_bias.map(|y| y.tread_err),
            tread_sigma: l.yaw_bias.map(|y| y.tread_sigma),
        }
    }

    /// The values to restore, each checked against [`learnt_bounds`] (and
    /// every standard deviation finite and not negative).
    ///
    /// # Errors
    /// [`LearntOutOfBounds`] naming the first value refused.
    pub fn checked(&self) -> Result<canodom_fusion::ekf::Learnt, LearntOutOfBounds> {
        use learnt_bounds as b;
        let within = |name: &'static str, value: f64, center: f64, bound: f64| {
            if (value - center).abs() <= bound {
                Ok(value)
            } else {
                Err(LearntOutOfBounds { name, value, bound })
            }
        };
        let sigma = |name: &'static str, value: f64| {
            if value.is_finite() && value >= 0.0 {
                Ok(value)
            } else {
                Err(LearntOutOfBounds {
                    name,
                    value,
                    bound: f64::INFINITY,
                })
            }
        };
        let yaw = match (
            self.yaw_bias_radps,
            self.yaw_bias_sigma_radps,
            self.rear_ratio_err,
            self.rear_ratio_sigma,
        ) {
            (Some(bias), Some(bias_sigma), Some(err), Some(err_sigma)) => {
                Some(canodom_fusion::ekf::LearntPair {
                    yaw_bias_radps: within("yaw_bias_radps", bias, 0.0, b::YAW_BIAS_RADPS)?,
                    yaw_bias_sigma_radps: sigma("yaw_bias_sigma_radps", bias_sigma)?,
                    rear_ratio_err: within("rear_ratio_err", err, 0.0, b::REAR_RATIO_ERR)?,
                    rear_ratio_sigma: sigma("rear_ratio_sigma", err_sigma)?,
                    // Files written before the tread was learnt: not learnt.
                    tread_err: within(
                        "tread_err",
                        self.tread_err.unwrap_or(0.0),
                        0.0,
                        b::TREAD_ERR,
                    )?,
                    tread_sigma: sigma("tread_sigma", self.tread_sigma.unwrap_or(0.0))?,
                })
            }
            _ => None,
        };
        Ok(canodom_fusion::ekf::Learnt {
            steer_offset_rad: within(
                "steer_offset_rad",
                self.steer_offset_rad,
                0.0,
                b::STEER_OFFSET_RAD,
            )?,
            steer_offset_sigma_rad: sigma("steer_offset_sigma_rad", self.steer_offset_sigma_rad)?,
            front_scale: within("front_scale", self.front_scale, 1.0, b::FRONT_SCALE)?,
            front_scale_sigma: sigma("front_scale_sigma", self.front_scale_sigma)?,
            yaw_bias: yaw,
        })
    }
}

/// What a start takes from a previous run's state file.
#[derive(Debug)]
pub enum Restored {
    /// No file: a first start.
    Nothing,
    /// The learnt values, checked.
    Learnt(canodom_fusion::ekf::Learnt),
    /// The file is damaged, of another version, or a value is out of
    /// bounds: the filter starts from its priors (the caller warns).
    Refused(String),
}

/// The learnt values of the state file at `path`, if it exists and they pass.
pub fn restore(path: &Path) -> Restored {
    match load(path) {
        Err(StateFileError::Io { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => {
            Restored::Nothing
        }
        Err(e) => Restored::Refused(e.to_string()),
        Ok(saved) => match saved.learnt.map(|l| l.checked()) {
            None => Restored::Nothing,
            Some(Ok(learnt)) => Restored::Learnt(learnt),
            Some(Err(e)) => Restored::Refused(format!("{}: {e}", path.display())),
        },
    }
}

impl SavedState {
    /// The state of a daemon run that ended with `summary`.
    pub fn new(config: &Config, summary: &Summary) -> Self {
        let pose = summary.state.pose();
        let unwrapped = summary.state.pose_unwrapped();
        let p = summary.state.covariance();
        let (a, b, c) = (p[(0, 0)], p[(0, 1)], p[(1, 1)]);
        // The same summary as ODOM_QUALITY.POS_STD: the worst direction.
        let lambda_max = 0.5 * (a + c) + (0.25 * (a - c) * (a - c) + b * b).sqrt();
        let d = config.params.wheel_diameters_m();
        let steering = config.params.steering();
        Self {
            format_version: FORMAT_VERSION,
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
                wheelbase_m: config.params.wheelbase_m(),
                rear_tread_m: config.params.rear_tread_m(),
                front_tread_m: config.params.front_tread_m(),
                rear_left_diameter_m: d.rear_left,
                rear_right_diameter_m: d.rear_right,
                front_left_diameter_m: d.front_left,
                front_right_diameter_m: d.front_right,
                steering_gain: steering.gain,
                steering_offset_rad: steering.offset_rad,
            },
            learnt: Some(SavedLearnt::from_state(&summary.state)),
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
    let text = fs::read_to_string(path).map_err(|source| StateFileError::Io {
        path: path.to_owned(),
        source,
    })?;
    let state: SavedState = serde_json::from_str(&text).map_err(|e| StateFileError::Format {
        path: path.to_owned(),
        reason: e.to_string(),
    })?;
    if state.format_version != FORMAT_VERSION {
        return Err(StateFileError::Format {
            path: path.to_owned(),
            reason: format!(
                "format_version {} is not supported (expected {FORMAT_VERSION})",
                state.format_version
            ),
        });
    }
    Ok(state)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::server::{InProcessDaemon, Observers};
    use canodom_can::frame::{CanFrame, FrameId};
    use canodom_sim::drive::simulator;
    use canodom_sim::vehicle::{PathKind, SampleEncoder};
    use std::sync::Arc;
    use std::time::Duration;

    fn config() -> Config {
        Config::load(Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/examples/rc_car.toml"
        )))
        .unwrap()
    }

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("canodom-state-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// The daemon on the in-process bus, fed `seconds` of a simulated drive
    /// plus a few rejects, stopped by its shutdown future once everything
    /// was sent (the frames still queued must be drained, not lost).
    async fn daemon_run(config: &Arc<Config>, seconds: f64) -> (Summary, u64) {
        let daemon = InProcessDaemon::spawn(Arc::clone(config), 1 << 16, Observers::default());
        let (_, tx) = daemon.bus.open().unwrap();
        // Let the link task open its endpoint before the first frame.
        tokio::time::sleep(Duration::from_millis(50)).await;
        let mut sim = simulator(config, PathKind::FigureEight, None, 1, false).unwrap();
        let mut enc = SampleEncoder::new(config);
        let mut frames = Vec::new();
        let mut sent = 0u64;
        while let Some(sample) = sim.try_next().unwrap() {
            if sample.t_s > seconds {
                break;
            }
            frames.clear();
            enc.encode(&sample, &mut frames);
            for f in &frames {
                canodom_can::bus::FrameSink::send(&tx, f).await.unwrap();
                sent += 1;
            }
            // Every 100th sample a rear-wheel frame with a broken checksum.
            if sent.is_multiple_of(300) {
                let rear = frames
                    .iter()
                    .find(|f| f.id() == FrameId::Standard(0x100))
                    .unwrap();
                let mut data = [0u8; 8];
                data.copy_from_slice(rear.data());
                data[7] ^= 0x5A;
                let bad = CanFrame::new_data(FrameId::Standard(0x100), &data).unwrap();
                canodom_can::bus::FrameSink::send(&tx, &bad).await.unwrap();
                sent += 1;
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        // Stop at once: frames still queued for the pipeline must count.
        (daemon.stop().await.unwrap(), sent)
    }

    #[tokio::test(start_paused = true)]
    async fn the_saved_state_is_the_daemons_end_state_and_survives_a_round_trip() {
        let config = Arc::new(config());
        let (summary, sent) = daemon_run(&config, 6.0).await;
        assert_eq!(summary.stats.frames, sent, "every frame sent was counted");
        assert!(summary.stats.get(Reject::BadChecksum) > 0);
        let dir = scratch("roundtrip");
        let path = dir.join("state.json");
        let state = SavedState::new(&config, &summary);
        save(&path, &state).unwrap();
        let back = load(&path).unwrap();
        // serde_json reads floats to within an ulp (no `float_roundtrip`):
        // everything else is exact.
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-15 * a.abs().max(b.abs());
        assert_eq!(back.stats, state.stats);
        assert_eq!(back.params, state.params);
        assert_eq!(
            (back.poses_published, back.frames_lost, back.connections),
            (state.poses_published, state.frames_lost, state.connections)
        );
        let (bp, sp) = (back.pose.unwrap(), state.pose.unwrap());
        assert!(
            close(bp.x_m, sp.x_m) && close(bp.y_m, sp.y_m) && close(bp.heading_rad, sp.heading_rad)
        );
        // The file holds the run's numbers, not defaults.
        let pose = back.pose.expect("steps were made");
        let end = summary.state.pose();
        assert!(close(pose.x_m, end.x_m) && close(pose.y_m, end.y_m));
        assert!(pose.x_m.hypot(pose.y_m) > 0.1, "the car moved: {pose:?}");
        assert_eq!(back.stats.frames, sent);
        assert_eq!(back.stats.steps, summary.stats.steps);
        assert_eq!(
            back.stats.rejects["bad_checksum"],
            summary.stats.get(Reject::BadChecksum)
        );
        assert_eq!(back.stats.rejects.len(), Reject::ALL.len());
        assert!(back.covariance.pos_std_m > 0.0 && back.covariance.pos_std_m.is_finite());
        assert_eq!(back.params.wheelbase_m, 0.26);
        assert!(!dir.join(".state.json.tmp").exists(), "temporary file left");
        fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn a_failed_save_leaves_the_previous_file_and_bad_files_are_typed() {
        let dir = scratch("errors");
        let path = dir.join("state.json");
        let mut state = SavedState {
            format_version: FORMAT_VERSION,
            saved_at_unix_us: 1,
            interface: "vcan0".into(),
            config: PathBuf::from("car.toml"),
            pose: None,
            covariance: SavedCovariance {
                pos_std_m: 0.0,
                heading_std_rad: 0.0,
                p: [[0.0; 3]; 3],
            },
            stats: SavedStats::from(&Stats::default()),
            poses_published: 0,
            frames_lost: 0,
            connections: 1,
            outages: 0,
            params: SavedParams {
                wheelbase_m: 0.26,
                rear_tread_m: 0.3,
                front_tread_m: 0.3,
                rear_left_diameter_m: 0.09,
                rear_right_diameter_m: 0.09,
                front_left_diameter_m: 0.09,
                front_right_diameter_m: 0.09,
                steering_gain: 1.0,
                steering_offset_rad: 0.0,
            },
            learnt: None,
        };
        save(&path, &state).unwrap();
        // The temporary name is taken by a directory: the write fails and
        // the previous file is untouched.
        fs::create_dir(dir.join(".state.json.tmp")).unwrap();
        state.poses_published = 99;
        assert!(matches!(
            save(&path, &state),
            Err(StateFileError::Io { .. })
        ));
        assert_eq!(load(&path).unwrap().poses_published, 0);
        fs::write(&path, "{\"format_version\": 1}").unwrap();
        assert!(matches!(load(&path), Err(StateFileError::Format { .. })));
        let mut text = serde_json::to_string(&state).unwrap();
        text = text.replace("\"format_version\":1", "\"format_version\":7");
        fs::write(&path, text).unwrap();
        let e = load(&path).unwrap_err();
        assert!(e.to_string().contains("format_version 7"), "{e}");
        fs::remove_dir_all(dir).unwrap();
    }

    fn learnt(offset_deg: f64, yaw_bias_dps: Option<f64>) -> SavedLearnt {
        SavedLearnt {
            steer_offset_rad: offset_deg.to_radians(),
            steer_offset_sigma_rad: 0.001,
            front_scale: 1.002,
            front_scale_sigma: 1e-4,
            yaw_bias_radps: yaw_bias_dps.map(f64::to_radians),
            yaw_bias_sigma_radps: yaw_bias_dps.map(|_| 1e-4),
            rear_ratio_err: yaw_bias_dps.map(|_| -4e-4),
            rear_ratio_sigma: yaw_bias_dps.map(|_| 1e-4),
            tread_err: yaw_bias_dps.map(|_| 0.01),
            tread_sigma: yaw_bias_dps.map(|_| 1e-3),
        }
    }

    #[test]
    fn learnt_values_are_restored_within_bounds_and_refused_beyond() {
        let ok = learnt(0.3, Some(-0.4)).checked().unwrap();
        assert!((ok.steer_offset_rad - 0.3f64.to_radians()).abs() < 1e-15);
        let y = ok.yaw_bias.unwrap();
        assert!((y.yaw_bias_radps + 0.4f64.to_radians()).abs() < 1e-15);
        assert_eq!(y.rear_ratio_err, -4e-4);
        assert!(learnt(0.3, None).checked().unwrap().yaw_bias.is_none());
        // A steering offset of 7°, a 6°/s gyro bias, a 6 % front scale, a NaN:
        // damaged or learnt from nonsense; each is named.
        for (bad, name) in [
            (learnt(7.0, None), "steer_offset_rad"),
            (learnt(0.3, Some(6.0)), "yaw_bias_radps"),
            (
                SavedLearnt {
                    front_scale: 1.06,
                    ..learnt(0.0, None)
                },
                "front_scale",
            ),
            (
                SavedLearnt {
                    steer_offset_sigma_rad: f64::NAN,
                    ..learnt(0.0, None)
                },
                "steer_offset_sigma_rad",
            ),
            (
                SavedLearnt {
                    rear_ratio_err: Some(0.02),
                    ..learnt(0.0, Some(0.1))
                },
                "rear_ratio_err",
            ),
        ] {
            let e = bad.checked().unwrap_err();
            assert_eq!(e.name, name, "{e}");
        }
    }

    #[test]
    fn restore_takes_back_what_a_run_saved_and_refuses_a_damaged_file() {
        let dir = scratch("restore");
        let path = dir.join("state.json");
        assert!(matches!(restore(&path), Restored::Nothing));
        fs::write(&path, "{ not json").unwrap();
        assert!(matches!(restore(&path), Restored::Refused(_)));
        let mut state = serde_json::from_str::<SavedState>(&format!(
            r#"{{"format_version":{FORMAT_VERSION},"saved_at_unix_us":1,"interface":"vcan0","config":"c.toml","pose":null,
            "covariance":{{"pos_std_m":0.0,"heading_std_rad":0.0,"p":[[0,0,0],[0,0,0],[0,0,0]]}},
            "stats":{{"frames":0,"used":0,"steps":0,"steps_without_front":0,"rejects":{{}}}},
            "poses_published":0,"frames_lost":0,"connections":1,"outages":0,
            "params":{{"wheelbase_m":0.26,"rear_tread_m":0.3,"front_tread_m":0.3,"rear_left_diameter_m":0.09,
            "rear_right_diameter_m":0.09,"front_left_diameter_m":0.09,"front_right_diameter_m":0.09,
            "steering_gain":1.0,"steering_offset_rad":0.0}}}}"#
        ))
        .unwrap();
        // A file of the version before learnt values: nothing to restore.
        save(&path, &state).unwrap();
        assert!(matches!(restore(&path), Restored::Nothing));
        state.learnt = Some(learnt(0.5, Some(-0.42)));
        save(&path, &state).unwrap();
        let Restored::Learnt(l) = restore(&path) else {
            panic!("not restored")
        };
        assert_eq!(Some(l), state.learnt.unwrap().checked().ok());
        state.learnt = Some(learnt(9.0, None));
        save(&path, &state).unwrap();
        let Restored::Refused(why) = restore(&path) else {
            panic!("restored an out-of-bounds offset")
        };
        assert!(
            why.contains("steer_offset_rad") && why.contains("state.json"),
            "{why}"
        );
        // What the filter learnt goes back into it as it was.
        let st = canodom_fusion::ekf::State::origin().with_learnt(&l);
        assert_eq!(SavedLearnt::from_state(&st), learnt(0.5, Some(-0.42)));
        fs::remove_dir_all(dir).unwrap();
    }

    #[tokio::test]
    async fn the_daemon_starts_from_the_restored_learnt_values_and_saves_them() {
        let config = Arc::new(config());
        let restored = learnt(0.5, None).checked().unwrap();
        let daemon = InProcessDaemon::spawn(
            Arc::clone(&config),
            1024,
            Observers {
                restore_learnt: Some(restored),
                ..Observers::default()
            },
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
        let summary = daemon.stop().await.unwrap();
        assert_eq!(summary.state.learnt(), restored);
        let saved = SavedState::new(&config, &summary);
        assert_eq!(saved.learnt, Some(learnt(0.5, None)));
    }
}
