//! `canodom run`: loads the configuration and runs [`crate::server::run`] on
//! SocketCAN until SIGINT or SIGTERM.

use crate::server::{Observers, SocketCan};
use canodom_export::live::{LiveOptions, LiveOutputs};
use canodom_export::recorder::RecorderOptions;
use canodom_pipeline::config::Config;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;
use tracing::{info, warn};

/// Arguments of `run`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  canodom run --config /etc/canodom/rc_car.toml\n  \
canodom run --config car.toml --interface vcan0 --log-format json\n  canodom run --config car.toml --record drive.mcap --record-max-s 600 --foxglove\n\n\
Reads the configured wheel and steering messages (kernel filters, kernel timestamps), checks \
DLC, rolling counters, checksums and timeouts, runs the EKF, and publishes ODOM_POSITION, \
ODOM_MOTION and ODOM_QUALITY (protocol/dbc/canodom.dbc at output.base_id; `canodom dbc own` writes it for yours) at output.pose_rate_hz. \
An ODOM_CMD frame with ODOM_REQUEST=1 publishes at once; ODOM_REQUEST=2 (RESET_POSE, with the \
arming code when one is configured) moves the pose to the origin if the vehicle stands still. \
The interface going down, away or \
bus-off is retried with backoff. SIGINT/SIGTERM stop it cleanly; under systemd it sends \
READY, WATCHDOG and STOPPING (see daemon/dist/canodom.service).\n\n\
Before opening the bus it checks that the parameter file ([calibration] param_file) can be \
created or replaced, and exits naming the path otherwise. Relative paths in the configuration \
are taken from its folder; without param_file the file is canodom-params.toml in \
$STATE_DIRECTORY when systemd sets it (StateDirectory=), else beside the configuration. \
Under systemd the state (what the filter learnt: wheel scales, steering offset, gyro bias) is \
kept in $STATE_DIRECTORY/canodom-state.json unless --state-file or --no-state-file says otherwise, \
so a restart resumes what the car taught it.\n\n\
With [gnss] (README: GNSS on the vehicle) it reads gpsd, a receiver's NMEA on a serial port \
(source = \"nmea\", device = \"/dev/ttyACM0\") or a ROS 2 NavSatFix topic and hands each \
accepted fix to the calibration on the bus clock; the CAN pipeline never waits on it, a gpsd \
that is down or restarts and a receiver unplugged are retried with backoff, and the source's \
state is CALIB_STATUS page 6."
)]
pub struct RunArgs {
    /// The configuration file.
    #[arg(long)]
    pub config: PathBuf,
    /// Keep the state here (JSON, written atomically and durably): last
    /// pose, covariance, statistics, the parameter set in use and what the
    /// filter learnt (steering offset, yaw-rate bias, rear ratio and
    /// effective tread errors, ...). Written every --state-every-s seconds,
    /// after a calibrated set is applied, and on stopping. At start the
    /// learnt values are taken back when they were learnt on the parameter
    /// set in use; otherwise (another set, an edited configuration, a
    /// damaged or older file, a value out of bounds) they are dropped with a
    /// warning and the filter starts from its priors.
    ///
    /// Default: `$STATE_DIRECTORY/canodom-state.json` when systemd sets
    /// `$STATE_DIRECTORY` (the shipped unit does), else none.
    #[arg(long, conflicts_with = "no_state_file")]
    pub state_file: Option<PathBuf>,
    /// Keep no state file, even under systemd: every start learns anew.
    #[arg(long)]
    pub no_state_file: bool,
    /// With --state-file: seconds between two writes while running, the most
    /// a power cut can lose.
    #[arg(long, value_name = "SECONDS", default_value_t = crate::state_file::DEFAULT_EVERY_S,
        value_parser = state_period)]
    pub state_every_s: f64,
    /// Refuse a DBC file with a message that cannot be decoded (a signal past
    /// its end, ...) instead of leaving the message out with a warning.
    #[arg(long)]
    pub strict: bool,
    /// The CAN interface, instead of the configuration's `interface`.
    #[arg(long)]
    pub interface: Option<String>,
    /// Log events on stderr as human-readable lines or one JSON object each
    /// (for journald and log collectors). The offline commands print their
    /// results on stdout in their own formats (CSV, JSON lines, TOML).
    #[arg(long, value_enum, default_value = "text")]
    pub log_format: LogFormat,
    /// Record every published pose, its step and raw frames to this MCAP file
    /// (Foxglove and ROS 2 messages, as `replay --out x.mcap`), flushed every second.
    #[arg(long, value_name = "FILE.mcap")]
    pub record: Option<PathBuf>,
    /// With --record: a new file (`<stem>-0001.mcap`, …) every this many MB …
    #[arg(long, requires = "record", value_name = "MB")]
    pub record_max_mb: Option<u64>,
    /// … or every this many seconds.
    #[arg(long, requires = "record", value_name = "SECONDS")]
    pub record_max_s: Option<f64>,
    /// Serve the same channels live over the Foxglove WebSocket protocol (default 127.0.0.1:8765).
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8765")]
    pub foxglove: Option<std::net::SocketAddr>,
}

/// How `run` writes its log events.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LogFormat {
    /// Human-readable lines.
    Text,
    /// One JSON object per event.
    Json,
}

/// Runs the daemon.
///
/// # Errors
/// Configuration, or the transport failing for good.
pub fn execute(args: &RunArgs) -> anyhow::Result<()> {
    let mut config = Config::load(&args.config)?;
    if let Some(iface) = &args.interface {
        config.interface.clone_from(iface);
    }
    let config = Arc::new(config);
    super::dbc_warnings(&config.db, args.strict)?;
    // Before the bus is opened: a parameter file that can never be written
    // would otherwise only show at the first commit, after a whole
    // calibration drive.
    config.check_param_file()?;
    require_keys(&config.security)?;
    if let Some(why) = clock_unsynchronised(std::path::Path::new(TIMESYNC_MARK).exists()) {
        warn!("{why}");
    }
    let connector = SocketCan {
        iface: config.interface.clone(),
    };
    let state_path = state_file_path(
        args.state_file.as_deref(),
        args.no_state_file,
        std::env::var_os(canodom_pipeline::config::STATE_DIRECTORY_ENV).as_deref(),
    );
    if let Some(path) = &state_path {
        info!(path = %path.display(), "state file: learnt values kept here across restarts");
    }
    let state_file = state_path
        .clone()
        .map(|path| crate::state_file::StateFileOptions {
            path,
            every: Duration::from_secs_f64(args.state_every_s),
        });
    // `[ros2]` (#43): a DDS failure is a warning, and the pipeline never waits on it.
    let ros2 = canodom_ros2::node::Node::from_config(&config).unwrap_or_else(|e| {
        warn!(error = %e, "ROS 2 not started: the daemon goes on without it");
        None
    });
    if let Some(node) = &ros2 {
        info!(node = %node.describe, "ROS 2: publishing odometry, /tf and /diagnostics");
    }
    let live = (args.record.is_some() || args.foxglove.is_some() || ros2.is_some())
        .then(|| {
            let record = args.record.clone().map(|path| RecorderOptions {
                max_bytes: args.record_max_mb.map(|mb| mb << 20),
                max_seconds: args.record_max_s,
                ..RecorderOptions::new(path)
            });
            let k_rear_m = config.ekf.k_rear_m;
            LiveOutputs::start(LiveOptions {
                record,
                foxglove: args.foxglove,
                k_rear_m,
                queue: 256,
                forward: ros2.map(canodom_ros2::node::Node::into_forward),
            })
        })
        .transpose()?;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let (tap, outputs) = live.unzip();
    let summary = rt.block_on(crate::server::run(
        Arc::clone(&config),
        connector,
        shutdown_signal(),
        Observers {
            state_file,
            tap,
            ..Observers::default()
        },
    ));
    // The recording is finished (indexed) whether the daemon stopped or failed.
    if let Some(outputs) = outputs {
        let r = outputs.join()?;
        info!(poses = r.poses, dropped = r.dropped, files = ?r.files, "recording and live view stopped");
    }
    let summary = summary?;
    if let (Some(path), Some(written)) = (&state_path, &summary.state_file) {
        match written {
            Ok(()) => info!(path = %path.display(), "state saved"),
            Err(cause) => anyhow::bail!("end state not saved: {cause}"),
        }
    }
    info!(stats = %summary.stats, poses = summary.poses_published, "canodom stopped");
    Ok(())
}

/// The file systemd-timesyncd keeps while the clock is synchronised
/// (systemd 239 and newer; `adjtimex` would tell any daemon's state, but
/// needs `unsafe`, which this workspace forbids).
pub const TIMESYNC_MARK: &str = "/run/systemd/timesync/synchronized";

/// The warning for a clock not known to be synchronised, `None` when it is
/// (`synchronised`: [`TIMESYNC_MARK`] exists). SecOC (profile 3) reads no
/// wall clock; what does is the record: log times, recordings, and the
/// parameter file's history.
pub fn clock_unsynchronised(synchronised: bool) -> Option<String> {
    (!synchronised).then(|| {
        format!(
            "the system clock is not known to be synchronised ({TIMESYNC_MARK} is absent: no \
             systemd-timesyncd sync yet, or another time daemon): log times, recordings and the \
             parameter file's history carry this clock; authentication does not depend on it"
        )
    })
}

/// The state file's name in systemd's state directory.
pub const STATE_FILE_NAME: &str = "canodom-state.json";

/// Where `run` keeps its state: `--state-file`, else none with
/// `--no-state-file`, else `STATE_FILE_NAME` in the service's state directory
/// (`$STATE_DIRECTORY`, set by systemd's `StateDirectory=`), else none.
pub fn state_file_path(
    explicit: Option<&std::path::Path>,
    none: bool,
    state_directory: Option<&std::ffi::OsStr>,
) -> Option<PathBuf> {
    if let Some(p) = explicit {
        return Some(p.to_path_buf());
    }
    if none {
        return None;
    }
    canodom_pipeline::config::unit_state_directory(state_directory)
        .map(|dir| dir.join(STATE_FILE_NAME))
}

/// `--state-every-s`: a finite number of seconds > 0 (and at most a day: a
/// longer period is a typo, not a choice).
fn state_period(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(s) if s.is_finite() && s > 0.0 && s <= 86_400.0 => Ok(s),
        _ => Err(format!(
            "{text:?} is not a number of seconds > 0 and <= 86400"
        )),
    }
}

/// Completes on SIGINT or SIGTERM.
pub async fn shutdown_signal() {
    let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).ok();
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {}
        () = async {
            match term.as_mut() {
                Some(t) => { t.recv().await; }
                None => std::future::pending::<()>().await,
            }
        } => {}
    }
}

/// Secure by default (#33): `run` authenticates commands and
/// acknowledgements unless the configuration says this is a bench.
///
/// # Errors
/// No key and no `allow_without_key = true`.
fn require_keys(security: &canodom_pipeline::security::SecurityConfig) -> anyhow::Result<()> {
    match (&security.keys, security.allow_without_key) {
        (Some(keys), _) => {
            info!(vehicle = %keys.vehicle, party = keys.party.name(),
                key_file = %security.key_file.as_deref().unwrap_or(std::path::Path::new("")).display(),
                "SecOC keys loaded: commands and CALIB_ACK are authenticated");
            Ok(())
        }
        (None, true) => {
            warn!(
                "allow_without_key = true: commands and CALIB_ACK are NOT authenticated; a bench only (README: Security)"
            );
            Ok(())
        }
        (None, false) => anyhow::bail!(
            "no SecOC keys: canodom run authenticates commands by default. Give [security] key_file \
             (the `canodom` file of `canodom keys derive`), or run under systemd with \
             LoadCredential={}:..., or for a bench without keys add\n  [security]\n  allow_without_key = true\n\
             (README: Security)",
            canodom_pipeline::security::KEY_CREDENTIAL
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::ffi::OsStr;
    use std::path::Path;

    #[test]
    fn an_unsynchronised_clock_is_warned_of_and_names_what_it_affects() {
        assert_eq!(clock_unsynchronised(true), None);
        let w = clock_unsynchronised(false).unwrap_or_default();
        assert!(w.contains(TIMESYNC_MARK) && w.contains("history"), "{w}");
    }

    #[test]
    fn a_service_keeps_its_state_in_its_state_directory_by_default() {
        let dir = Some(OsStr::new("/var/lib/canodom"));
        assert_eq!(
            state_file_path(None, false, dir),
            Some(PathBuf::from("/var/lib/canodom/canodom-state.json"))
        );
        // systemd lists several directories with ':'; the first is the unit's own.
        assert_eq!(
            state_file_path(None, false, Some(OsStr::new("/var/lib/a:/var/lib/b"))),
            Some(PathBuf::from("/var/lib/a/canodom-state.json"))
        );
        // Asked for explicitly, or turned off.
        let mine = Path::new("/tmp/mine.json");
        assert_eq!(
            state_file_path(Some(mine), false, dir),
            Some(mine.to_path_buf())
        );
        assert_eq!(state_file_path(None, true, dir), None);
        // Outside systemd nothing is written unasked.
        assert_eq!(state_file_path(None, false, None), None);
        assert_eq!(state_file_path(None, false, Some(OsStr::new(""))), None);
    }
}
