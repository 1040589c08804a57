//! `canodom calibrate`: the calibration of issue 6 offline, from candump logs
//! of whole runs (standstill, one lap of the test track, standstill).
//!
//! The logs go through the daemon's own [`Pipeline`] so that checksums,
//! counters, tick wrap-around and wheel faults are judged exactly as live.
//! The pipeline reports the rear-wheel-only odometry pose per step; its
//! increments are inverted back into wheel distances (exact: the pose update
//! is `d·(cos, sin)(θ + Δθ/2)` with `Δθ = (d_r − d_l)/b`), which are the
//! revolutions the calib crate wants once divided by π·D of the same
//! nominal parameters.

use anyhow::{Context as _, bail};
use canodom_calib::methods::{ExactOptions, PaperOptions, exact, heading, paper};
use canodom_calib::run::{InputFault, Tolerances};
use canodom_calib::{CalibrationResult, Direction, RearParams, RevSample, Run, RunRecorder, Track};
use canodom_fusion::{Pose, VehicleParams};
use canodom_pipeline::config::Config;
use canodom_pipeline::pipeline::{Outcome, Pipeline};
use canodom_pipeline::stats::Reject;
use serde::Deserialize;
use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Arguments of `calibrate`.
#[derive(Debug, clap::Args)]
#[command(after_help = "Example:\n  \
canodom simulate --config rc_car.toml --log cw1.log --path track-cw --true-params truth.toml --seed 1\n  \
canodom simulate --config rc_car.toml --log ccw1.log --path track-ccw --true-params truth.toml --seed 2\n  \
canodom calibrate --config rc_car.toml --track-radius 0.78 --cw cw1.log --ccw ccw1.log --out calibrated.toml --report report\n\n\
Each log is one whole run: standing still, one lap of the track (straight 2R, semicircle R, \
straight 2R, semicircle R), standing still; the run is found inside it (moving off to stopping). \
Runs are validated (length within 10 %, total turn of 2 pi in the announced direction, no input \
faults, steering following the track); rejected runs are named on stderr with their reasons and \
left out. The result is a TOML document on stdout (and in --out, written atomically).\n\n\
--report DIR writes DIR/calibration.svg (every run's path before and after, the end \
positions and their centres of gravity around each start point, the reference track) and \
DIR/calibration.json (every number of the result and of each run).\n\n\
--end-poses FILE gives measured real end poses, in the run frame (x along the first straight, \
y to the left), for some or all logs; a log not listed is assumed to end exactly at its start:\n  \
[[run]]\n  log = \"cw1.log\"      # as given on the command line, or its file name\n  \
dx_m = 0.012\n  dy_m = -0.004\n  dtheta_deg = 0.8\n\n\
Without a track: calibration from an ordinary drive with position fixes (GNSS, a surveyed route):\n  \
canodom calibrate --config car.toml --fixes fixes.csv --out params.toml drive.log\n\
The fixes (the rear-axle centre, times on the log's clock; 1 Hz is plenty) are read from a CSV \
t_unix_s,x_m,y_m[,heading_rad] in a local metric frame, a CSV t_unix_s,lat_deg,lon_deg[,alt_m] \
(WGS-84, turned into metres around the first fix) or an NMEA 0183 log (GGA/RMC, UTC times), told \
apart by content. The rear diameter ratio, the speed scale, the steering offset and gain, the \
yaw-rate sensor's bias and scale, the effective rear tread (from turns both ways) and the fixes' \
latency (within ±--fixes-latency-bound-s, or given with --fixes-latency-s) are fitted over the whole \
drive with a robust loss: a receiver's jumps are down-weighted and listed, each estimate has its \
standard deviation; what the drive cannot tell is held and said so. Each value is committed only if \
its standard deviation is within [calibration]'s max_*_std and the fit is plausible (its residual \
at the fixes within what their noise explains plus max_fix_residual_m, the noise as the fixes state \
it — a horiz_std_m column, NMEA GST or HDOP — else estimated, at most max_fix_sigma_m; at most \
max_down_weighted_share of the fixes down-weighted), else the previous value is kept and the reason \
printed. The result goes to the parameter file --out (created if missing, history kept, bounds \
checked), which `replay --params` and `run` (param_file) use.")]
pub struct CalibrateArgs {
    /// The configuration file: DBC, signals and the parameters in use while recording.
    #[arg(long)]
    pub config: PathBuf,
    /// Radius R of the track's semicircles, in metres.
    #[arg(long, required_unless_present = "fixes", conflicts_with = "fixes")]
    pub track_radius: Option<f64>,
    /// Logs of clockwise runs (any format `replay` reads).
    #[arg(long, num_args = 1.., required_unless_present = "fixes", conflicts_with = "fixes")]
    pub cw: Vec<PathBuf>,
    /// Logs of counter-clockwise runs.
    #[arg(long, num_args = 1.., required_unless_present = "fixes", conflicts_with = "fixes")]
    pub ccw: Vec<PathBuf>,
    /// Position fixes of an ordinary drive (CSV, see below): calibrate from
    /// LOG instead of track runs; the result is committed to --out.
    #[arg(long, requires_all = ["out", "log"])]
    pub fixes: Option<PathBuf>,
    /// With --fixes: the log of the drive (candump, ASC, BLF, compressed).
    #[arg(requires = "fixes")]
    pub log: Option<PathBuf>,
    /// With --fixes: the fixes' latency is known: a fix stamped t on the log's
    /// clock describes the vehicle at t − SECONDS (default: estimated within
    /// ±--fixes-latency-bound-s and reported with its σ).
    #[arg(
        long,
        requires = "fixes",
        value_name = "SECONDS",
        allow_negative_numbers = true
    )]
    pub fixes_latency_s: Option<f64>,
    /// With --fixes: the largest latency the fit may estimate, seconds.
    #[arg(
        long,
        requires = "fixes",
        conflicts_with = "fixes_latency_s",
        value_name = "SECONDS",
        default_value_t = 1.0
    )]
    pub fixes_latency_bound_s: f64,
    /// Measured real end poses per log (TOML, see below).
    #[arg(long)]
    pub end_poses: Option<PathBuf>,
    /// The calibration method.
    #[arg(long, value_enum, default_value = "exact")]
    pub method: MethodArg,
    /// Track runs: also write the TOML result to this file (atomically).
    /// With --fixes: the parameter file the result is committed to.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write a report into this directory (created if missing): calibration.svg,
    /// every run's path before and after with the centres of gravity of the ends,
    /// and calibration.json with every number.
    #[arg(long, value_name = "DIR")]
    pub report: Option<PathBuf>,
    /// Refuse a DBC file with a message that cannot be decoded (a signal past
    /// its end, ...) instead of leaving the message out with a warning.
    #[arg(long)]
    pub strict: bool,
    /// Only the frames of this interface (a log may hold several buses).
    #[arg(long)]
    pub interface: Option<String>,
}

/// `--method`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum MethodArg {
    /// The paper's centre-of-gravity closed form (least squares over x and y), iterated.
    Paper,
    /// The heading law (one shot).
    Heading,
    /// Levenberg–Marquardt refinement from the heading law (docs/calibration-math.md §7).
    Exact,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct EndPosesFile {
    #[serde(default)]
    run: Vec<EndPose>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct EndPose {
    log: String,
    dx_m: f64,
    dy_m: f64,
    dtheta_deg: f64,
}

/// Reads an `--end-poses` file: log name → measured end pose in the run frame.
fn load_end_poses(path: &Path) -> anyhow::Result<HashMap<String, Pose>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("{}: cannot read the end poses", path.display()))?;
    let file: EndPosesFile = toml::from_str(&text)
        .with_context(|| format!("{}: not a valid end-poses file", path.display()))?;
    let mut out = HashMap::new();
    for (i, p) in file.run.into_iter().enumerate() {
        if !(p.dx_m.is_finite() && p.dy_m.is_finite() && p.dtheta_deg.is_finite()) {
            bail!(
                "{}: [[run]] #{} ({}): a value is not finite",
                path.display(),
                i + 1,
                p.log
            );
        }
        let pose = Pose {
            x_m: p.dx_m,
            y_m: p.dy_m,
            heading_rad: p.dtheta_deg.to_radians(),
        };
        if out.insert(p.log.clone(), pose).is_some() {
            bail!("{}: log {} is listed twice", path.display(), p.log);
        }
    }
    Ok(out)
}

/// Looks a log up by the path as given, then by its file name.
fn end_pose_of(poses: &HashMap<String, Pose>, log: &Path) -> Option<Pose> {
    poses.get(&log.display().to_string()).copied().or_else(|| {
        log.file_name()
            .and_then(|n| poses.get(&n.to_string_lossy().into_owned()))
            .copied()
    })
}

/// Faults of the inputs (not frames of other messages, not the filter's gate).
fn input_faults(pipeline: &Pipeline) -> u64 {
    Reject::ALL
        .iter()
        .filter(|r| {
            // A saturated or distrusted yaw rate is no fault of the wheels
            // this fits.
            !matches!(
                r,
                Reject::UnknownId
                    | Reject::NotData
                    | Reject::GateReject
                    | Reject::YawSaturated
                    | Reject::YawImplausible
            )
        })
        .map(|&r| pipeline.stats().get(r))
        .sum()
}

/// A wheel turned more than this in one step (revolutions): the vehicle is
/// moving. Far below one tick, far above the rounding of the inversion.
const MOVING_REV: f64 = 1e-9;

/// Extracts the run of one log: the samples from the last standstill before
/// moving off to the first standstill after the last motion.
///
/// # Errors
/// Unreadable log, or no motion in it.
pub fn run_from_log(
    config: &Config,
    log: &Path,
    direction: Direction,
    measured_end: Option<Pose>,
    max_gap_s: f64,
    interface: Option<&str>,
) -> anyhow::Result<Run> {
    let mut frames = super::log_frames(log, "calibrate", interface)?;
    let mut pipeline = Pipeline::new(config)?;
    let params = config.params;
    let tread_m = params.rear_tread_m();
    let steer_id = config.db.messages()[config.signals.steering.message_index].id();
    let mut steer_signal = 0.0;
    let mut prev: Option<Pose> = None;
    // (sample, input faults so far)
    let mut samples: Vec<(RevSample, u64)> = Vec::new();
    while let Some((timestamp, frame)) = frames.next_frame()? {
        let outcome = pipeline.push(timestamp, &frame);
        if frame.id() == steer_id {
            let data = frame.data();
            let u = config
                .signals
                .steering
                .form
                .decode(data)
                .unwrap_or(f64::NAN);
            if u.is_finite() {
                steer_signal = u;
            }
        }
        let Outcome::Step(step, _) = outcome else {
            continue;
        };
        let pose = step.odometry;
        let (rear_m, t_s) = match prev {
            None => ([0.0, 0.0], step.t_s),
            Some(p) => {
                let dtheta = pose.heading_rad - p.heading_rad;
                let (s, c) = (p.heading_rad + 0.5 * dtheta).sin_cos();
                let d = (pose.x_m - p.x_m) * c + (pose.y_m - p.y_m) * s;
                (
                    [d - 0.5 * tread_m * dtheta, d + 0.5 * tread_m * dtheta],
                    step.t_s,
                )
            }
        };
        prev = Some(pose);
        samples.push((
            RevSample::from_distances(&params, t_s, rear_m, None, steer_signal),
            input_faults(&pipeline),
        ));
    }
    if let Some(warning) = frames.finish(pipeline.stats().frames)? {
        tracing::warn!("calibrate: {warning}");
    }
    // What `replay` ends with: a saturated yaw rate, a configured message
    // that never came, an implausible signal (issue #45).
    for w in pipeline.plausibility_at_end().0 {
        tracing::warn!("calibrate: {}: warning: {w}", log.display());
    }
    let malformed = frames.malformed();
    let moving = |s: &RevSample| s.rear_left_rev.abs().max(s.rear_right_rev.abs()) > MOVING_REV;
    let Some(first) = samples.iter().position(|(s, _)| moving(s)) else {
        bail!(
            "{}: the vehicle never moves ({} filter steps, {malformed} malformed lines)",
            log.display(),
            samples.len()
        );
    };
    let last = samples
        .iter()
        .rposition(|(s, _)| moving(s))
        .unwrap_or(first);
    let begin = first.saturating_sub(1);
    let mut recorder = RunRecorder::new(direction, max_gap_s);
    let faults_before = samples[begin].1;
    for &(s, faults) in &samples[begin..=last] {
        recorder.push(s);
        if faults > faults_before {
            recorder.push_fault(s.t_s, InputFault::Decoder { code: 1 });
            break;
        }
    }
    Ok(recorder.finish(measured_end))
}

/// Runs the method.
///
/// # Errors
/// What the calib crate reports.
pub fn compute(
    method: MethodArg,
    runs: &[Run],
    used: &RearParams,
    track: Track,
) -> canodom_calib::Result<CalibrationResult> {
    match method {
        MethodArg::Paper => paper(runs, used, track, PaperOptions::default()),
        MethodArg::Heading => heading(runs, used, track),
        MethodArg::Exact => exact(runs, used, track, ExactOptions::default()),
    }
}

/// The TOML document printed and written by `calibrate`.
pub fn result_toml(
    r: &CalibrationResult,
    params: &VehicleParams,
    accepted: (usize, usize),
) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# canodom calibrate: {} CW and {} CCW runs.",
        accepted.0, accepted.1
    );
    let _ = writeln!(
        s,
        "# rear_tread_m is the EFFECTIVE tread (docs/calibration-math.md §4): the one that makes\n\
         # odometry close, not the distance between tyre centres; use it for odometry only."
    );
    let _ = writeln!(
        s,
        "# Held at nominal (track runs do not tell them): the front tread and wheel diameters,\n\
         # the steering map; calibrate those with `canodom calib start-steering` or a drive with fixes."
    );
    let _ = writeln!(s, "[calibration]");
    let num = |s: &mut String, k: &str, v: f64| {
        let _ = writeln!(s, "{k} = {v:?}");
    };
    num(&mut s, "rear_tread_m", r.rear.tread_m);
    num(&mut s, "rear_left_diameter_m", r.rear.left_diameter_m);
    num(&mut s, "rear_right_diameter_m", r.rear.right_diameter_m);
    num(&mut s, "diameter_ratio", r.ratio());
    num(&mut s, "alpha_rad", r.alpha_rad);
    num(&mut s, "beta_rad", r.beta_rad);
    let method = match r.method {
        canodom_calib::Method::PaperX => "paper-x",
        canodom_calib::Method::PaperY => "paper-y",
        canodom_calib::Method::PaperLeastSquares => "paper",
        canodom_calib::Method::Heading => "heading",
        canodom_calib::Method::Exact => "exact",
    };
    let _ = writeln!(s, "method = \"{method}\"");
    num(&mut s, "end_error_before_m", r.e_max_before_m);
    num(&mut s, "end_error_after_m", r.e_max_after_m);
    if let Some(v) = r.tread_std_m {
        num(&mut s, "rear_tread_std_m", v);
    }
    if let Some(v) = r.ratio_std {
        num(&mut s, "diameter_ratio_std", v);
    }
    let _ = writeln!(s, "iterations = {}", r.iterations);
    let _ = writeln!(s, "converged = {}", r.converged);
    let _ = writeln!(s, "\n# The parameters used while recording.\n[nominal]");
    num(&mut s, "rear_tread_m", params.rear_tread_m());
    num(&mut s, "rear_left_diameter_m", r.used.left_diameter_m);
    num(&mut s, "rear_right_diameter_m", r.used.right_diameter_m);
    s
}

/// Writes `text` to `path` through a temporary file beside it and a rename,
/// so a reader never sees half a file.
fn write_atomic(path: &Path, text: &str) -> anyhow::Result<()> {
    use std::io::Write as _;
    let name = path
        .file_name()
        .with_context(|| format!("{}: not a file path", path.display()))?;
    let tmp = path.with_file_name(format!(
        ".{}.tmp{}",
        name.to_string_lossy(),
        std::process::id()
    ));
    let write = || -> std::io::Result<()> {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(text.as_bytes())?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    };
    write().map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        anyhow::Error::new(e).context(format!("cannot write {}", path.display()))
    })
}

/// `--fixes-latency-s` / `--fixes-latency-bound-s` as the drive fit's options.
fn drive_options(args: &CalibrateArgs) -> anyhow::Result<canodom_calib::drive::DriveOptions> {
    let latency = match args.fixes_latency_s {
        Some(s) if s.is_finite() => canodom_calib::drive::FixesLatency::Given(s),
        Some(s) => bail!("--fixes-latency-s {s}: not a finite number of seconds"),
        None if args.fixes_latency_bound_s.is_finite() && args.fixes_latency_bound_s > 0.0 => {
            canodom_calib::drive::FixesLatency::Estimate {
                bound_s: args.fixes_latency_bound_s,
            }
        }
        None => bail!(
            "--fixes-latency-bound-s {}: must be a positive number of seconds",
            args.fixes_latency_bound_s
        ),
    };
    Ok(canodom_calib::drive::DriveOptions {
        latency,
        ..canodom_calib::drive::DriveOptions::default()
    })
}

/// Runs `calibrate`.
///
/// # Errors
/// Configuration, unreadable logs or end poses, too few accepted runs,
/// a failed calibration, an unwritable output.
pub fn execute(args: &CalibrateArgs) -> anyhow::Result<()> {
    let config = Config::load(&args.config)?;
    super::dbc_warnings(&config.db, args.strict)?;
    if let (Some(fixes), Some(log), Some(out)) = (&args.fixes, &args.log, &args.out) {
        let options = drive_options(args)?;
        return super::calibrate_drive::execute(
            &config,
            fixes,
            log,
            out,
            args.report.as_deref(),
            args.interface.as_deref(),
            &options,
        );
    }
    let radius = args
        .track_radius
        .context("--track-radius is needed for track runs")?;
    let track = Track::new(radius).with_context(|| format!("--track-radius {radius}"))?;
    let poses = match &args.end_poses {
        Some(p) => load_end_poses(p)?,
        None => HashMap::new(),
    };
    for name in poses.keys() {
        let known = args.cw.iter().chain(&args.ccw).any(|l| {
            l.display().to_string() == *name
                || l.file_name()
                    .is_some_and(|n| n.to_string_lossy() == name.as_str())
        });
        if !known {
            let file = args.end_poses.as_deref().unwrap_or(Path::new("")).display();
            bail!("{file}: log {name} is not one of the --cw/--ccw logs");
        }
    }
    let tolerances = Tolerances::default();
    let mut runs = Vec::new();
    // The report names each accepted run after its log.
    let mut labels = Vec::new();
    let mut accepted = (0, 0);
    let logs = args
        .cw
        .iter()
        .map(|l| (l, Direction::Cw))
        .chain(args.ccw.iter().map(|l| (l, Direction::Ccw)));
    for (log, dir) in logs {
        let run = run_from_log(
            &config,
            log,
            dir,
            end_pose_of(&poses, log),
            tolerances.max_gap_s,
            args.interface.as_deref(),
        )?;
        let reasons = run.validate(track, &config.params, &tolerances);
        if reasons.is_empty() {
            match dir {
                Direction::Cw => accepted.0 += 1,
                Direction::Ccw => accepted.1 += 1,
            }
            runs.push(run);
            labels.push(log.display().to_string());
        } else {
            for r in &reasons {
                eprintln!("calibrate: {}: run rejected: {r}", log.display());
            }
        }
    }
    if accepted.0 == 0 || accepted.1 == 0 {
        bail!(
            "calibrate needs at least one accepted run each way; accepted {} CW and {} CCW",
            accepted.0,
            accepted.1
        );
    }
    let used = RearParams::of(&config.params);
    let result = compute(args.method, &runs, &used, track).context("calibration failed")?;
    let text = result_toml(&result, &config.params, accepted);
    print!("{text}");
    if let Some(out) = &args.out {
        write_atomic(out, &text)?;
    }
    if let Some(dir) = &args.report {
        let report =
            canodom_report::report::CalibrationReport::build(&result, track, &runs, &labels);
        let (svg, json) = canodom_report::files::write_report(dir, &report)?;
        eprintln!(
            "calibrate: report written to {} and {}",
            svg.display(),
            json.display()
        );
    }
    Ok(())
}
