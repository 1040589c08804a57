//! `canodom replay`: the daemon's pipeline over a candump log, timed by the
//! log's timestamps, as fast as the machine goes; one CSV row per filter step.
//! The work is `canodom_offline::replay`'s (the Python package runs the same);
//! this is its command line.

use anyhow::Context as _;
use canodom_pipeline::config::Config;
use canodom_pipeline::stats::Reject;
use std::fmt::Write as _;
use std::io::Write;
use std::path::PathBuf;

pub use canodom_offline::replay::{
    CSV_HEADER, McapOut, ReplayOptions, ReplayRow, ReplaySummary, WRITE_BYTES, replay, replay_log,
    replay_rows, replay_with,
};

/// Arguments of `replay`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  canodom simulate --config rc_car.toml --log drive.log --truth truth.csv\n  \
canodom replay --config rc_car.toml drive.log --out pose.csv\n  canodom replay --config rc_car.toml drive.log --out drive.mcap   # Foxglove, ROS 2\n  \
canodom replay --config car.toml --params params.toml drive.log --out pose.csv\n  \
canodom replay --config car.toml drive.log --fixes fixes.nmea --learnt-out learnt.csv --out pose.csv\n\n\
The CSV has one row per filter step (one per rear-wheel frame): seconds since the first input \
frame, the fused pose, then rear-wheel-only odometry; both start at (0, 0, 0) at the first \
wheel sample, headings are unwrapped (total turn, radians). The last column says what the \
filter's correction window did at that step: empty inside a window; `accepted` (front and rear \
agree: the rear increment is kept), `kept_rear` or `used_front` (the gate rejected the window \
and blamed a front or a rear wheel), `no_front` (front wheels or steering stale). Statistics \
go to stderr, with the gate's rejections by action and by the wheel blamed."
)]
pub struct ReplayArgs {
    /// The configuration file (the same one `run` uses).
    #[arg(long)]
    pub config: PathBuf,
    /// The CAN log: candump (`-L` or plain), Vector ASC or BLF, each also
    /// `.gz` or `.zst` compressed, told apart by content; `-` reads standard
    /// input.
    pub log: PathBuf,
    /// Where to write the CSV (standard output when absent), or the MCAP
    /// file (`.mcap`): Foxglove and ROS 2 messages of every step.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// `csv` or `mcap` (default: told by --out's extension).
    #[arg(long, value_parser = ["csv", "mcap"])]
    pub format: Option<String>,
    /// MCAP chunk compression: `lz4` (a quarter of the size) or `none`
    /// (faster to make where the file's bytes cost nothing to write).
    #[arg(long, default_value = "lz4")]
    pub compression: canodom_export::mcap_file::Compression,
    /// A calibrated parameter file (written by `calibrate --out`, or the
    /// daemon's `param_file`): its current set is used from the first frame,
    /// as `run` uses it. Checksums and the configuration's bounds are checked.
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// Refuse a DBC file with a message that cannot be decoded (a signal past
    /// its end, ...) instead of leaving the message out with a warning.
    #[arg(long)]
    pub strict: bool,
    /// Only the frames of this interface (a log may hold several buses).
    #[arg(long)]
    pub interface: Option<String>,
    /// A reference trajectory to compare with: CSV `t_unix_s,x_m,y_m[,heading_rad]`
    /// on the log's clock (the format of `calibrate --fixes`), e.g. GNSS in a local
    /// metric frame or motion capture.
    #[arg(long, value_name = "CSV")]
    pub truth: Option<PathBuf>,
    /// With --truth: dead-reckon from the reference's pose this many seconds after
    /// the log's first frame (default: the first step inside the reference).
    #[arg(long, requires = "truth", value_name = "SECONDS")]
    pub truth_start_s: Option<f64>,
    /// With --truth: where the comparison's picture and numbers go
    /// (default: beside --out, `<out stem>-truth/`, else `replay-truth/`).
    #[arg(long, requires = "truth", value_name = "DIR")]
    pub truth_report: Option<PathBuf>,
    /// Position fixes of the drive (NMEA 0183, a `t_unix_s,lat_deg,lon_deg`
    /// CSV or a local-metres CSV, as `calibrate --fixes` reads them): the
    /// car is calibrated against them as it drives (refitted every
    /// --fixes-every-s of fixes over all driven so far, judged by
    /// `[calibration]`'s gate), and each set learnt is taken into use from
    /// the time it was learnt: the pose shows what the car would have done.
    /// The drift watch refits every `[calibration.drift] every_s` over the
    /// last `window_s` and judges each refit against the set the replay
    /// started with (what the daemon, committing nothing by itself, holds):
    /// a line when a parameter's flag rises or clears, and the distance
    /// driven until the first flag at the end.
    #[arg(long, value_name = "FILE", conflicts_with = "ros2")]
    pub fixes: Option<PathBuf>,
    /// With --fixes: seconds of fixes between two refits.
    #[arg(long, requires = "fixes", default_value_t = canodom_offline::online::DEFAULT_EVERY_S)]
    pub fixes_every_s: f64,
    /// With --fixes: each refit fits only this many seconds of the drive up
    /// to it (default: all of it).
    #[arg(long, requires = "fixes", value_name = "SECONDS")]
    pub fixes_window_s: Option<f64>,
    /// With --fixes: write what was learnt at each refit (every parameter
    /// with its σ, whether it passed the gate, whether the set was taken
    /// into use, whether the drift watch flags it) to this CSV.
    #[arg(long, requires = "fixes", value_name = "CSV")]
    pub learnt_out: Option<PathBuf>,
    /// `--ros2`: the drive published on ROS 2 at its pace (#43).
    #[command(flatten)]
    pub ros2: canodom_ros2::replay::Ros2ReplayArgs,
}

/// `--params`: the current set of a parameter file, if one is given.
///
/// # Errors
/// A damaged file, or one without a current set.
fn load_params(
    args: &ReplayArgs,
    config: &Config,
) -> anyhow::Result<Option<canodom_params::persist::ParamSet>> {
    Ok(match &args.params {
        None => None,
        Some(path) => {
            let file = canodom_params::persist::load(path, &config.calibration.bounds)
                .with_context(|| "--params".to_string())?;
            let set = file.current.with_context(|| {
                format!(
                    "--params {}: the file has no current set (rolled back to nominal)",
                    path.display()
                )
            })?;
            eprintln!(
                "replay: parameters version {} ({}) from {}",
                set.version,
                set.method,
                path.display()
            );
            Some(set)
        }
    })
}

/// `--truth`: the reference trajectory, if one is given.
///
/// # Errors
/// An unreadable or malformed file, naming it.
fn read_truth(args: &ReplayArgs) -> anyhow::Result<Option<Vec<canodom_calib::drive::Fix>>> {
    Ok(match &args.truth {
        None => None,
        Some(path) => {
            let text = std::fs::read_to_string(path).map_err(|e| {
                anyhow::anyhow!("{}: cannot read the reference: {e}", path.display())
            })?;
            Some(canodom_calib::drive::parse_fixes(
                &text,
                &path.display().to_string(),
            )?)
        }
    })
}

/// `--fixes`: the sets learnt as the fixes come, with their times, and the
/// drift watch's summary (nothing without `--fixes`).
///
/// # Errors
/// As [`super::replay_fixes::learn`].
fn learn_from_fixes(
    args: &ReplayArgs,
    config: &Config,
    params: Option<&canodom_params::persist::ParamSet>,
) -> anyhow::Result<super::replay_fixes::Learnt> {
    Ok(match &args.fixes {
        Some(path) => super::replay_fixes::learn(
            &super::replay_fixes::FixesArgs {
                path,
                log: &args.log,
                interface: args.interface.as_deref(),
                every_s: args.fixes_every_s,
                window_s: args.fixes_window_s,
                learnt_out: args.learnt_out.as_deref(),
            },
            config,
            params,
        )?,
        None => super::replay_fixes::Learnt::default(),
    })
}

/// Runs `replay`.
///
/// # Errors
/// Configuration, unreadable log, write failure.
pub fn execute(args: &ReplayArgs) -> anyhow::Result<()> {
    let config = Config::load(&args.config)?;
    super::dbc_warnings(&config.db, args.strict)?;
    let params = load_params(args, &config)?;
    if args.ros2.ros2 {
        let log = (args.log.as_path(), args.interface.as_deref());
        canodom_ros2::replay::execute(&args.ros2, &config, params.as_ref(), log)?;
        return Ok(());
    }
    let truth = read_truth(args)?;
    let learnt = learn_from_fixes(args, &config, params.as_ref())?;
    let switches = learnt.switches;
    let mut input = super::open_input(&args.log, "replay")?;
    let started = std::time::Instant::now();
    let (sink, mcap) = open_output(args, &config)?;
    // A replay that fails leaves no header-only or partial file behind.
    let mut partial = PartialOutput::of(args.out.as_deref());
    let mut w = std::io::BufWriter::with_capacity(WRITE_BYTES, sink);
    let summary = replay_log(
        &config,
        params.as_ref(),
        ReplayOptions {
            interface: args.interface.as_deref(),
            keep_track: truth.is_some(),
            log_name: Some(&args.log.display().to_string()),
            switches: &switches,
        },
        &mut input,
        &mut w,
        &mut std::io::stderr(),
        mcap,
    )
    .with_context(|| args.log.display().to_string())?;
    w.flush()?;
    input.finish();
    super::check_log_read(
        "replay",
        &args.log,
        &summary.seen,
        args.interface.as_deref(),
    )?;
    if summary.stats.get(Reject::UnknownId) == summary.stats.frames {
        anyhow::bail!(
            "{}: none of its {} frames has an id the configuration reads ({}): \
             is this the configured vehicle's log, and {} its DBC? \
             (`canodom decode --dbc {} {}` shows what the DBC knows of it)",
            args.log.display(),
            summary.stats.frames,
            config
                .input_ids()
                .iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join(", "),
            config.db.source_name(),
            config.db.source_name(),
            args.log.display()
        );
    }
    partial.keep();
    let secs = started.elapsed().as_secs_f64();
    let mut malformed = format!("malformed lines {}", summary.malformed);
    for (reason, n) in summary.malformed_by_reason.nonzero() {
        let _ = write!(malformed, " {reason}={n}");
    }
    eprintln!(
        "replay: {} ({:.0} frames/s), {malformed}",
        summary.stats,
        summary.stats.frames as f64 / secs.max(1e-9),
    );
    if let Some(s) = summary.last_step {
        eprintln!(
            "replay: end at t={:.3} s: fused ({:.4}, {:.4}, {:.4} rad), rear-only ({:.4}, {:.4}, {:.4} rad)",
            s.t_s,
            s.fused.x_m,
            s.fused.y_m,
            s.fused.heading_rad,
            s.odometry.x_m,
            s.odometry.y_m,
            s.odometry.heading_rad
        );
    }
    eprintln!("replay: wheel scales: {}", summary.state.wheel_scales());
    print_yaw_learnt(&summary.state);
    if let Some(drift) = &learnt.drift_summary {
        eprintln!("replay: {drift}");
    }
    for w in &summary.warnings {
        eprintln!("replay: warning: {w}");
    }
    if let Some(d) = &summary.diagnosis {
        eprintln!("replay: {d}");
    }
    if let Some(truth) = truth {
        compare_with_truth(args, &truth, &summary.track, summary.first_frame)?;
    }
    Ok(())
}

/// What the gyro taught the filter, when it has one: a user without a
/// reference trajectory sees whether the gyro carries the heading and what
/// it found the wheels to be.
fn print_yaw_learnt(state: &canodom_fusion::ekf::State) {
    let Some(y) = state.learnt().yaw_bias else {
        return;
    };
    eprintln!(
        "replay: yaw-rate sensor: bias {:+.4} ± {:.4} °/s; rear wheels against it: ratio {:+.3} ± {:.3} %, \
         effective tread {:+.2} ± {:.2} %; the gyro carries the heading: {}",
        y.yaw_bias_radps.to_degrees(),
        y.yaw_bias_sigma_radps.to_degrees(),
        100.0 * y.rear_ratio_err,
        100.0 * y.rear_ratio_sigma,
        100.0 * y.tread_err,
        100.0 * y.tread_sigma,
        if state.aided_leads() {
            "yes"
        } else {
            "no (the wheels do)"
        }
    );
}

/// The `--out` file of a replay still running: removed when dropped before
/// [`PartialOutput::keep`] (the replay failed), so no header-only or
/// truncated file is taken for a result. A device or other non-regular
/// `--out` (`/dev/null`) is never touched.
struct PartialOutput(Option<PathBuf>);

impl PartialOutput {
    fn of(out: Option<&std::path::Path>) -> Self {
        Self(
            out.filter(|p| std::fs::metadata(p).is_ok_and(|m| m.is_file()))
                .map(std::path::Path::to_path_buf),
        )
    }

    fn keep(&mut self) {
        self.0 = None;
    }
}

impl Drop for PartialOutput {
    fn drop(&mut self) {
        if let Some(path) = self.0.take()
            && std::fs::remove_file(&path).is_ok()
        {
            eprintln!("replay: {} removed: the replay failed", path.display());
        }
    }
}

/// The CSV output (standard output without `--out`), or the MCAP file.
fn open_output(
    args: &ReplayArgs,
    config: &Config,
) -> anyhow::Result<(Box<dyn Write>, Option<McapOut>)> {
    let is_mcap = args.format.as_deref().map_or_else(
        || args.out.as_ref().and_then(|p| p.extension()) == Some("mcap".as_ref()),
        |f| f == "mcap",
    );
    let create = |path: &PathBuf| {
        std::fs::File::create(path).with_context(|| format!("cannot create {}", path.display()))
    };
    Ok(match (&args.out, is_mcap) {
        (None, true) => anyhow::bail!("--format mcap needs --out FILE"),
        (None, false) => (Box::new(std::io::stdout().lock()), None),
        (Some(path), false) => (Box::new(create(path)?), None),
        (Some(path), true) => {
            let file = std::io::BufWriter::with_capacity(1 << 20, create(path)?);
            let options = canodom_export::mcap_file::McapOptions {
                compression: args.compression,
                ..Default::default()
            };
            let writer = McapOut::new(file, options, config.ekf.k_rear_m)?;
            (Box::new(std::io::sink()), Some(writer))
        }
    })
}

/// Where `--truth`'s report goes without `--truth-report`: beside `--out`
/// as `<out stem>-truth/` when `--out` is (or will be) a regular file, else
/// `replay-truth/` (`--out /dev/null` made `/dev/null-truth/`, issue #32).
fn default_truth_report(out: Option<&std::path::Path>) -> PathBuf {
    match out {
        Some(out) if std::fs::metadata(out).map_or(true, |m| m.is_file()) => {
            let stem = out
                .file_stem()
                .map_or_else(|| "replay".to_owned(), |s| s.to_string_lossy().into_owned());
            out.with_file_name(format!("{stem}-truth"))
        }
        _ => PathBuf::from("replay-truth"),
    }
}

/// `--truth`: the replay placed on the reference, the errors printed, the
/// picture and numbers written.
fn compare_with_truth(
    args: &ReplayArgs,
    truth: &[canodom_calib::drive::Fix],
    track: &[canodom_report::truth::TrackPoint],
    first_frame: Option<canodom_can::time::Timestamp>,
) -> anyhow::Result<()> {
    // Seconds after the log's first frame, on the log's clock.
    let start = args
        .truth_start_s
        .zip(first_frame)
        .map(|(s, t0)| t0.as_secs_f64() + s);
    let truth_path = args
        .truth
        .as_deref()
        .unwrap_or(std::path::Path::new("truth"));
    let comparison = canodom_report::truth::TruthComparison::build(truth, track, start)
        .map_err(|e| anyhow::anyhow!("--truth {}: {e}", truth_path.display()))?;
    eprintln!("replay: {}", comparison.summary());
    let dir = match &args.truth_report {
        Some(dir) => dir.clone(),
        None => default_truth_report(args.out.as_deref()),
    };
    let (svg, json) = canodom_report::files::write_report(&dir, &comparison)?;
    eprintln!(
        "replay: comparison in {} and {}",
        svg.display(),
        json.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::default_truth_report;
    use std::path::{Path, PathBuf};

    #[test]
    fn truth_report_goes_beside_a_file_output_only() {
        assert_eq!(
            default_truth_report(Some(Path::new("/tmp/x/pose.csv"))),
            Path::new("/tmp/x/pose-truth")
        );
        // A device is not a place for a folder beside it.
        assert_eq!(
            default_truth_report(Some(Path::new("/dev/null"))),
            PathBuf::from("replay-truth")
        );
        assert_eq!(default_truth_report(None), PathBuf::from("replay-truth"));
    }
}
