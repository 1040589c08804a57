//! The subcommands, one file each (mini-redis `cmd/`): their clap arguments
//! and the code they run. `main.rs` only parses, sets up logging and calls
//! [`Command::execute`].

pub mod calib;
pub mod calibrate;
pub mod calibrate_drive;
pub mod config_init;
pub mod dbc;
pub mod decode;
pub mod demo;
pub mod keys;
pub mod replay;
pub mod replay_fixes;
pub mod run;
pub mod simulate;

pub use canodom_can::any_log::AnyLogReader;
pub use canodom_can::log_format::LogSeen;
use std::path::Path;

/// Every subcommand.
#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// The daemon: fused odometry from SocketCAN, published on CAN.
    Run(run::RunArgs),
    /// Decode a CAN log (candump, Vector ASC/BLF, compressed) with a DBC into JSON lines.
    Decode(decode::DecodeArgs),
    /// What a DBC file holds (to fill in `[signals]`), and canodom's own DBC at your base id.
    Dbc(dbc::DbcArgs),
    /// Run the daemon's pipeline over a CAN log, as fast as it can; pose CSV (and --truth errors).
    Replay(replay::ReplayArgs),
    /// The simulated vehicle, onto an interface or into a candump log.
    Simulate(simulate::SimulateArgs),
    /// The whole system without CAN hardware: a simulated vehicle and the daemon on an in-process bus.
    Demo(demo::DemoArgs),
    /// Calibrate the rear tread and wheel diameters offline from candump logs of track runs.
    Calibrate(calibrate::CalibrateArgs),
    /// The operator's client of the live calibration: send CALIB_CMD, show CALIB_STATUS as a guide.
    Calib(calib::CalibArgs),
    /// A ready configuration for a car platform opendbc knows (`config init --car`, `--list`).
    Config(config_init::ConfigArgs),
    /// SecOC key files: derive each party's keys from a master key.
    Keys(keys::KeysArgs),
    /// GNSS fixes from a ROS 2 `sensor_msgs/NavSatFix` topic into a CSV for `calibrate --fixes`.
    Ros2Fixes(canodom_ros2::fixes::FixesArgs),
}

impl Command {
    /// Runs the command.
    ///
    /// # Errors
    /// Whatever the command reports (already in words for the user).
    pub fn execute(self) -> anyhow::Result<()> {
        match self {
            Self::Run(a) => run::execute(&a),
            Self::Decode(a) => decode::execute(&a),
            Self::Dbc(a) => dbc::execute(&a),
            Self::Replay(a) => replay::execute(&a),
            Self::Simulate(a) => simulate::execute(&a),
            Self::Demo(a) => demo::execute(&a),
            Self::Calibrate(a) => calibrate::execute(&a),
            Self::Calib(a) => calib::execute(&a),
            Self::Config(a) => config_init::execute(&a),
            Self::Keys(a) => keys::execute(&a),
            Self::Ros2Fixes(a) => canodom_ros2::fixes::execute(&a)
                .map(drop)
                .map_err(Into::into),
        }
    }
}

/// Opens a log path, `-` meaning standard input, buffered, with a progress
/// line drawn on stderr when it is a terminal. Its format is judged from
/// its content by [`log_reader`].
///
/// # Errors
/// The file cannot be opened.
pub fn open_input(
    path: &Path,
    label: &'static str,
) -> anyhow::Result<crate::progress::Progress<Box<dyn std::io::BufRead>>> {
    let (reader, total): (Box<dyn std::io::BufRead>, _) = if path == Path::new("-") {
        (
            Box::new(std::io::BufReader::with_capacity(
                1 << 16,
                std::io::stdin().lock(),
            )),
            None,
        )
    } else {
        let file = std::fs::File::open(path)
            .map_err(|e| anyhow::anyhow!("{}: cannot open: {e}", path.display()))?;
        let len = file.metadata().ok().map(|m| m.len());
        (
            Box::new(std::io::BufReader::with_capacity(1 << 16, file)),
            len,
        )
    };
    Ok(crate::progress::Progress::new(reader, label, total))
}

/// A reader of whatever log `input` holds, judged from its content
/// ([`canodom_offline::log::log_reader`]). The error does not name the
/// file: the caller adds it.
///
/// # Errors
/// A format not read, no time when `needs_time`, unreadable first bytes.
pub fn log_reader<'a>(
    input: impl std::io::BufRead + 'a,
    interface: Option<&str>,
    needs_time: bool,
) -> anyhow::Result<AnyLogReader<'a>> {
    Ok(canodom_offline::log::log_reader(
        input, interface, needs_time,
    )?)
}

/// Refuses a log from which no frame was read (exit non-zero, saying why),
/// and warns when a log mixes the frames of several interfaces without
/// `--interface` choosing one.
///
/// # Errors
/// No frame read.
pub fn check_log_read(
    label: &str,
    path: &Path,
    seen: &LogSeen,
    interface: Option<&str>,
) -> anyhow::Result<()> {
    if let Some(warning) = canodom_offline::log::check_log_read(path, seen, interface)? {
        tracing::warn!("{label}: {warning}");
    }
    Ok(())
}

/// Logs the messages a tolerant DBC load left out (one `warn` each, naming file,
/// message, signal and reason: canodom-dbc does no logging itself), or, under
/// `--strict`, refuses the DBC with all of them.
///
/// # Errors
/// `strict` and at least one message left out.
pub fn dbc_warnings(db: &canodom_dbc::Database, strict: bool) -> anyhow::Result<()> {
    let warnings = db.warnings();
    if strict && !warnings.is_empty() {
        let list = warnings.iter().fold(String::new(), |mut list, w| {
            use std::fmt::Write as _;
            let _ = write!(list, "\n  {w}");
            list
        });
        anyhow::bail!(
            "--strict: {} message(s) of {} cannot be decoded:{list}",
            warnings.len(),
            db.source_name()
        );
    }
    for w in warnings {
        tracing::warn!("{w}");
    }
    Ok(())
}

/// `secs.micros` without padding: a valid JSON number and CSV field.
pub fn write_timestamp(out: &mut Vec<u8>, t: canodom_can::time::Timestamp) {
    use std::io::Write as _;
    let _ = write!(out, "{}.{:06}", t.secs(), t.subsec_micros());
}

pub use canodom_offline::log::LogFrames;

/// The frames of the log at `path` ([`LogFrames`]), read through
/// [`open_input`] (its progress line on a terminal).
///
/// # Errors
/// As [`open_input`] and [`log_reader`].
pub fn log_frames<'a>(
    path: &'a Path,
    label: &'static str,
    interface: Option<&'a str>,
) -> anyhow::Result<LogFrames<'a>> {
    let reader = log_reader(open_input(path, label)?, interface, true)
        .map_err(|e| anyhow::anyhow!("{}: {e:#}", path.display()))?;
    Ok(LogFrames::new(reader, path, label, interface))
}
