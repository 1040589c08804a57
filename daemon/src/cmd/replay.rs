//! `canodom replay`: the daemon's pipeline over a candump log, timed by the
//! log's timestamps, as fast as the machine goes; one CSV row per filter step.

use anyhow::Context as _;
use canodom_can::candump::{ClassicData, MalformedCounts, ReadError};
use canodom_can::frame::CanFrame;
use canodom_can::time::Timestamp;
use canodom_export::encode::StepEncoder;
use canodom_export::mcap_file::{Chunk, StepWriter};
use canodom_export::sample::{FrameBuffer, FrameRef, FrameSource, StepSample};
use canodom_fusion::VehicleParams;
use canodom_fusion::ekf::WindowOutcome;
use canodom_pipeline::config::Config;
use canodom_pipeline::pipeline::{Pipeline, Step};
use canodom_pipeline::plausibility::Plausibility;
use canodom_pipeline::stats::{Reject, Stats};
use canodom_report::float_text::{push_csv_row, push_f64, push_micros_as_seconds};
use std::fmt::Write as _;
use std::io::{Read, Write};
use std::path::PathBuf;
use std::sync::mpsc;

/// The CSV header `replay` writes.
pub const CSV_HEADER: &str = "t_s,x_m,y_m,heading_rad,odo_x_m,odo_y_m,odo_heading_rad,correction,\
t_unix_s,speed_mps,pos_std_m,heading_std_rad,pose_valid,quality";

/// Arguments of `replay`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  canodom simulate --config rc_car.toml --log drive.log --truth truth.csv\n  \
canodom replay --config rc_car.toml drive.log --out pose.csv\n  canodom replay --config rc_car.toml drive.log --out drive.mcap   # Foxglove, ROS 2\n  \
canodom replay --config car.toml --params params.toml drive.log --out pose.csv\n\n\
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
}

/// What a replay did.
#[derive(Clone, Debug)]
pub struct ReplaySummary {
    /// Pipeline statistics.
    pub stats: Stats,
    /// Malformed log lines skipped.
    pub malformed: u64,
    /// The same by reason.
    pub malformed_by_reason: MalformedCounts,
    /// The last step.
    pub last_step: Option<Step>,
    /// The filter's final state.
    pub state: canodom_fusion::ekf::State,
    /// The log's interfaces and the lines of others skipped.
    pub seen: super::LogSeen,
    /// Every step at its absolute time, when [`ReplayOptions::keep_track`] asked.
    pub track: Vec<canodom_report::truth::TrackPoint>,
    /// Time of the first input frame, which steps' `t_s` count from.
    pub first_frame: Option<canodom_can::time::Timestamp>,
    /// What the plausibility checks suspect (#32).
    pub warnings: Vec<canodom_pipeline::plausibility::Warning>,
    /// Their one-paragraph diagnosis, when any fired.
    pub diagnosis: Option<String>,
}

/// How [`replay_log`] reads and what it keeps.
#[derive(Clone, Copy, Debug, Default)]
pub struct ReplayOptions<'a> {
    /// Only the frames of this interface.
    pub interface: Option<&'a str>,
    /// Keep every step with its absolute time (for `--truth`).
    pub keep_track: bool,
    /// The log's name, in the warnings about its malformed lines.
    pub log_name: Option<&'a str>,
}

impl ReplayOptions<'_> {
    /// What the warnings about the log's lines start with.
    fn warning_prefix(&self) -> String {
        match self.log_name {
            Some(name) => format!("replay: {name}"),
            None => "replay".to_owned(),
        }
    }
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

/// Runs `replay`.
///
/// # Errors
/// Configuration, unreadable log, write failure.
pub fn execute(args: &ReplayArgs) -> anyhow::Result<()> {
    let config = Config::load(&args.config)?;
    super::dbc_warnings(&config.db, args.strict)?;
    let params = load_params(args, &config)?;
    let truth = match &args.truth {
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
    };
    let mut input = super::open_input(&args.log, "replay")?;
    let started = std::time::Instant::now();
    let (sink, mcap) = open_output(args, &config)?;
    let mut w = std::io::BufWriter::with_capacity(WRITE_BYTES, sink);
    let summary = replay_log(
        &config,
        params.as_ref(),
        ReplayOptions {
            interface: args.interface.as_deref(),
            keep_track: truth.is_some(),
            log_name: Some(&args.log.display().to_string()),
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

/// Records per batch handed from the reading thread to the filter thread:
/// enough that the hand-over costs nothing per record and a thread seldom
/// sleeps on the other (1,024 made ~370 context switches a million frames,
/// this ~40), few enough that the batches in flight stay in the CPU caches
/// (≈ 130 kB of records, 170 kB of CSV each).
const BATCH_RECORDS: usize = 4096;

/// CSV bytes written at once: what `execute`'s `BufWriter` holds, so that it
/// passes each write straight on (a copy into it was 3 % of the reading
/// thread's instructions).
const WRITE_BYTES: usize = 1 << 16;

/// Batches in existence at once (reused, never reallocated): the memory of a
/// replay is bounded by these whatever the log's length.
const BATCHES: usize = 4;

/// The unit of work between the two threads of [`replay`]: records in, the
/// CSV values of the filter steps they caused out, and their text when the
/// filter thread had time to write it.
struct Batch {
    records: Vec<Entry>,
    /// The frames of [`Entry::Other`], in order.
    others: Vec<(Timestamp, CanFrame)>,
    rows: Vec<Row>,
    /// `rows` as CSV lines, or empty: then the reading thread writes them.
    text: Vec<u8>,
    /// For an MCAP file: each step's sample and the index of the record after its frame.
    samples: Vec<(usize, StepSample)>,
    /// The parameters the filter used for the batch (the MCAP calibration
    /// channel's), once it has been through the filter.
    params: Option<VehicleParams>,
    /// For an MCAP file: the frames of earlier batches after their last
    /// step, which belong to this batch's first step.
    carried: FrameBuffer,
    /// For an MCAP file: the batch's steps as a chunk, once encoded.
    chunk: Chunk,
    /// Whether `chunk` holds the batch's steps.
    encoded: bool,
}

/// Moves the frames `carry` holds into `batch` (they belong to its first
/// step) and keeps in `carry` those of `batch` after its last step.
fn carry_tail(batch: &mut Batch, carry: &mut FrameBuffer) {
    std::mem::swap(&mut batch.carried, carry);
    carry.clear();
    let tail_from = if let Some((to, _)) = batch.samples.last() {
        *to
    } else {
        // No step: everything waits for the next batch's first.
        for i in 0..batch.carried.frame_count() {
            if let Some(f) = batch.carried.frame(i) {
                carry.push(f);
            }
        }
        0
    };
    for i in tail_from..batch.frame_count() {
        if let Some(f) = batch.frame(i) {
            carry.push(f);
        }
    }
}

/// Encodes the steps of `batch` into its chunk.
fn encode_batch(encoder: &mut StepEncoder, batch: &mut Batch) {
    let Some(params) = batch.params else {
        return;
    };
    let mut chunk = std::mem::take(&mut batch.chunk);
    encoder.forget_carried();
    encoder.carry(&batch.carried, 0);
    let mut from = 0;
    for (to, sample) in &batch.samples {
        chunk.push_step(encoder, sample, &params, (&*batch, from, *to));
        from = *to;
    }
    batch.chunk = chunk;
    batch.encoded = true;
}

/// An MCAP output of a replay.
pub type McapOut = StepWriter<std::io::BufWriter<std::fs::File>>;

impl FrameSource for Batch {
    fn frame_count(&self) -> usize {
        self.records.len()
    }

    fn frame(&self, index: usize) -> Option<FrameRef<'_>> {
        let (timestamp, id, data) = match self.records.get(index)? {
            Entry::Classic(c) => (c.timestamp, c.id, c.payload()),
            Entry::Other(i) => self.others.get(*i).map(|(t, f)| (*t, f.id(), f.data()))?,
        };
        Some(FrameRef {
            timestamp,
            id,
            data,
        })
    }
}

/// One record of a [`Batch`]: a classical data frame in place (a third of
/// a [`CanFrame`]'s size, so a third of the bytes crossing between the
/// threads), any other frame in [`Batch::others`].
enum Entry {
    Classic(ClassicData),
    /// Index into [`Batch::others`].
    Other(usize),
}

/// One CSV row: the step's time in microseconds since the first frame
/// (written from the integer: exact, and no float to take apart) and the
/// six pose values.
struct Row {
    t_us: i64,
    values: [f64; 6],
    correction: WindowOutcome,
    /// The step's time on the log's clock, µs.
    t_unix_us: i64,
    /// Speed, position and heading standard deviations of the pose sample.
    sample: [f64; 3],
    /// The pose sample's flags ([`canodom_protocol::pose_frames::PoseFlags::bits`]).
    quality: u8,
}

/// Appends `rows` to `text` as CSV lines.
fn push_rows(text: &mut Vec<u8>, rows: &[Row]) {
    for row in rows {
        push_csv_row(text, row.t_us, &row.values);
        // The text column after the numbers: the row's newline becomes
        // `,tag\n` (two pushes; the number row keeps its single copy).
        text.pop();
        text.push(b',');
        text.extend_from_slice(row.correction.as_str().as_bytes());
        text.push(b',');
        push_micros_as_seconds(text, row.t_unix_us);
        for v in row.sample {
            text.push(b',');
            push_f64(text, v);
        }
        text.push(b',');
        text.push(b'0' + (row.quality & 1));
        text.push(b',');
        text.extend_from_slice(itoa::Buffer::new().format(row.quality).as_bytes());
        text.push(b'\n');
    }
}

/// Replays `input` through a fresh pipeline, CSV rows to `out`, malformed
/// lines reported on `diag` (the first 20, then counted only).
///
/// Two threads share the work, as the log's frames must go through the one
/// filter in order: the calling thread reads and parses the log and writes
/// the CSV, a second thread runs the pipeline. Batches of records go one way
/// and batches of rows come back in the same order, so the output is byte
/// for byte what one thread would write. Turning the rows into text (float
/// formatting, a fifth of the work) goes to whichever thread has time: the
/// filter thread does it for a batch when no next batch is waiting for it,
/// so neither thread idles while the other is the bottleneck (a fixed split
/// left the reading thread a sixth busier than the filter thread). An MCAP
/// output's messages are shared the same way, a batch's steps making a
/// chunk of their own ([`replay_log`]).
///
/// # Errors
/// Pipeline construction, I/O.
pub fn replay(
    config: &Config,
    input: impl Read,
    out: &mut impl Write,
    diag: &mut impl Write,
) -> anyhow::Result<ReplaySummary> {
    replay_with(config, None, input, out, diag)
}

/// [`replay`] with a calibrated parameter set in use from the first frame.
///
/// # Errors
/// Pipeline construction, a set the filter refuses, I/O.
pub fn replay_with(
    config: &Config,
    params: Option<&canodom_params::persist::ParamSet>,
    input: impl Read,
    out: &mut impl Write,
    diag: &mut impl Write,
) -> anyhow::Result<ReplaySummary> {
    replay_log(
        config,
        params,
        ReplayOptions::default(),
        input,
        out,
        diag,
        None,
    )
}

/// [`replay_with`] as `options` say: one interface's frames only, the track kept.
///
/// # Errors
/// Pipeline construction, a set the filter refuses, I/O.
// The reading, filter and writer threads are set up and joined in one place.
#[allow(clippy::too_many_lines)]
pub fn replay_log(
    config: &Config,
    params: Option<&canodom_params::persist::ParamSet>,
    options: ReplayOptions<'_>,
    input: impl Read,
    out: &mut impl Write,
    diag: &mut impl Write,
    mut mcap: Option<McapOut>,
) -> anyhow::Result<ReplaySummary> {
    let mut pipeline = Pipeline::new(config)?;
    let mut plausibility = Plausibility::new(config.params.wheelbase_m(), config.params.steering());
    if let Some(set) = params {
        pipeline
            .apply_params(Some((set.version, &set.values)))
            .with_context(|| format!("parameter set version {}", set.version))?;
    }
    // Read unbuffered by LogReader's own large blocks (a BufReader passes
    // reads larger than its buffer straight through); other formats use it.
    let mut reader = super::log_reader(std::io::BufReader::new(input), options.interface, true)?;
    let mut kept = options.keep_track.then(Vec::new);
    let samples = mcap.is_some();
    if !samples {
        writeln!(out, "{CSV_HEADER}")?;
    }
    let (to_filter, filter_in) = mpsc::channel::<Batch>();
    let (to_writer, from_filter) = mpsc::channel::<Batch>();
    std::thread::scope(|scope| {
        // The MCAP messages are encoded by whichever thread has time, as the
        // CSV text is: a batch's steps are a chunk of their own, so either
        // can encode any batch.
        let mut encoder = mcap.as_ref().map(McapOut::encoder);
        // Named, so profiles and `top -H` tell the threads apart.
        let filter = std::thread::Builder::new()
            .name("filter".into())
            .spawn_scoped(scope, move || {
                let mut carry = FrameBuffer::default();
                let mut waiting = filter_in.recv().ok();
                while let Some(mut batch) = waiting.take() {
                    batch.rows.clear();
                    batch.text.clear();
                    batch.samples.clear();
                    batch.encoded = false;
                    filter_batch(&mut pipeline, &mut plausibility, &mut batch, samples);
                    batch.params = Some(*pipeline.params());
                    if samples {
                        carry_tail(&mut batch, &mut carry);
                    }
                    waiting = filter_in.try_recv().ok();
                    if waiting.is_none() {
                        // Ahead of the reading thread (or past its end):
                        // encode or write the text here.
                        if let Some(encoder) = encoder.as_mut() {
                            encode_batch(encoder, &mut batch);
                        } else {
                            push_rows(&mut batch.text, &batch.rows);
                        }
                    }
                    if to_writer.send(batch).is_err() {
                        break;
                    }
                    if waiting.is_none() {
                        waiting = filter_in.recv().ok();
                    }
                }
                (pipeline, plausibility)
            })
            .context("starting the filter thread")?;
        let fed = feed(
            &mut reader,
            &to_filter,
            &from_filter,
            (out, mcap.as_mut()),
            (diag, &options.warning_prefix()),
            kept.as_mut(),
        );
        // Ends the filter thread's loop, whether feeding ended or failed.
        drop(to_filter);
        let (pipeline, mut plausibility) = filter
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
        plausibility.judge_stats(
            pipeline.stats(),
            pipeline.last_step().map_or(0.0, |s| s.t_s),
        );
        let (malformed, by_reason) = fed?;
        if let Some(m) = mcap {
            m.finish()?.flush()?;
        }
        let seen = super::LogSeen::of(&reader, pipeline.stats().frames, malformed);
        let t0_us = pipeline
            .first_frame_time()
            .map_or(0, |t| t.as_micros() as i64);
        let track = kept
            .unwrap_or_default()
            .into_iter()
            .map(|(t_us, v)| canodom_report::truth::TrackPoint {
                t_unix_s: (t0_us + t_us) as f64 / 1e6,
                fused: canodom_fusion::Pose {
                    x_m: v[0],
                    y_m: v[1],
                    heading_rad: v[2],
                },
                rear: canodom_fusion::Pose {
                    x_m: v[3],
                    y_m: v[4],
                    heading_rad: v[5],
                },
            })
            .collect();
        Ok(ReplaySummary {
            seen,
            track,
            first_frame: pipeline.first_frame_time(),
            stats: *pipeline.stats(),
            malformed,
            malformed_by_reason: by_reason,
            last_step: pipeline.last_step(),
            state: *pipeline.state(),
            warnings: plausibility.warnings().to_vec(),
            diagnosis: plausibility.diagnosis(),
        })
    })
}

/// Runs one batch's records through the pipeline, a row per filter step
/// with the pose sample `run` would publish at that frame.
fn filter_batch(
    pipeline: &mut Pipeline,
    plausibility: &mut Plausibility,
    batch: &mut Batch,
    samples: bool,
) {
    for (k, entry) in batch.records.iter().enumerate() {
        let (at, step) = match entry {
            Entry::Classic(c) => (
                c.timestamp,
                pipeline
                    .push_data(c.timestamp, c.id, c.payload())
                    .step()
                    .copied(),
            ),
            Entry::Other(i) => match batch.others.get(*i) {
                Some((t, frame)) => (*t, pipeline.push(*t, frame).step().copied()),
                None => continue,
            },
        };
        if let Some(s) = step {
            plausibility.push(&s);
            let p = pipeline.pose_output(at);
            if samples {
                batch.samples.push((k + 1, StepSample::of(pipeline, &s, p)));
            }
            let t0_us = pipeline
                .first_frame_time()
                .map_or(0, |t| t.as_micros() as i64);
            batch.rows.push(Row {
                t_us: s.t_us,
                values: [
                    s.fused.x_m,
                    s.fused.y_m,
                    s.fused.heading_rad,
                    s.odometry.x_m,
                    s.odometry.y_m,
                    s.odometry.heading_rad,
                ],
                correction: s.correction,
                t_unix_us: t0_us + s.t_us,
                sample: [p.speed_mps, p.pos_std_m, p.heading_std_rad],
                quality: p.flags.bits(),
            });
        }
    }
}

/// The reading and writing side of [`replay`]: parses batches for the
/// filter thread and writes the rows of those it has finished, in order.
/// Returns the malformed line counts.
fn feed(
    reader: &mut super::AnyLogReader<'_>,
    to_filter: &mpsc::Sender<Batch>,
    from_filter: &mpsc::Receiver<Batch>,
    (out, mut mcap): (&mut impl Write, Option<&mut McapOut>),
    (diag, warn_prefix): (&mut impl Write, &str),
    mut kept: Option<&mut Vec<(i64, [f64; 6])>>,
) -> anyhow::Result<(u64, MalformedCounts)> {
    let mut malformed = 0u64;
    let mut by_reason = MalformedCounts::default();
    let mut spare: Vec<Batch> = (0..BATCHES)
        .map(|_| Batch {
            records: Vec::with_capacity(BATCH_RECORDS),
            others: Vec::new(),
            rows: Vec::with_capacity(BATCH_RECORDS),
            text: Vec::new(),
            samples: Vec::new(),
            params: None,
            carried: FrameBuffer::default(),
            chunk: Chunk::default(),
            encoded: false,
        })
        .collect();
    let mut in_flight = 0usize;
    let mut text = Vec::with_capacity(2 * WRITE_BYTES);
    // Rows are gathered until at least `WRITE_BYTES` (a `BufWriter` of that
    // capacity then hands them on without copying them into its buffer).
    let mut encoder = mcap.as_deref().map(McapOut::encoder);
    let mut write_rows = |batch: &mut Batch, out: &mut dyn Write| -> anyhow::Result<()> {
        if let Some(kept) = kept.as_deref_mut() {
            kept.extend(batch.rows.iter().map(|r| (r.t_us, r.values)));
        }
        if let (Some(m), Some(encoder)) = (mcap.as_deref_mut(), encoder.as_mut()) {
            if !batch.encoded {
                encode_batch(encoder, batch);
            }
            batch.chunk = m.write_chunk(std::mem::take(&mut batch.chunk))?;
            return Ok(());
        }
        if batch.text.is_empty() {
            push_rows(&mut text, &batch.rows);
        } else {
            // Written as it is (a batch's text is over `WRITE_BYTES` but for
            // the odd short batch), not copied behind `text` first.
            if !text.is_empty() {
                out.write_all(&text)?;
                text.clear();
            }
            return Ok(out.write_all(&batch.text)?);
        }
        if text.len() >= WRITE_BYTES {
            out.write_all(&text)?;
            text.clear();
        }
        Ok(())
    };
    let filter_gone = || anyhow::anyhow!("replay: the filter thread stopped");
    let mut at_end = false;
    while !at_end {
        let mut batch = if let Some(b) = spare.pop() {
            b
        } else {
            // All batches are with the filter: write the oldest, reuse it.
            let mut b = from_filter.recv().map_err(|_| filter_gone())?;
            in_flight -= 1;
            write_rows(&mut b, out)?;
            b
        };
        batch.records.clear();
        batch.others.clear();
        while batch.records.len() < BATCH_RECORDS {
            // The common line first, then any other (or the end, or an error).
            if let Some(c) = reader.next_classic() {
                batch.records.push(Entry::Classic(c));
                continue;
            }
            match reader.next_record_general() {
                Ok(Some(r)) => {
                    batch.records.push(Entry::Other(batch.others.len()));
                    batch.others.push((r.timestamp, r.frame));
                }
                Ok(None) => {
                    at_end = true;
                    break;
                }
                Err(ReadError::Malformed(m)) => {
                    malformed += 1;
                    by_reason.add(m.reason);
                    if malformed <= 20 {
                        writeln!(diag, "{warn_prefix}: {m}; skipped")?;
                    }
                }
                Err(e @ (ReadError::Io(_) | ReadError::Corrupt(_))) => return Err(e.into()),
            }
        }
        to_filter.send(batch).map_err(|_| filter_gone())?;
        in_flight += 1;
        // Write what the filter finished meanwhile, without waiting.
        while let Ok(mut b) = from_filter.try_recv() {
            in_flight -= 1;
            write_rows(&mut b, out)?;
            spare.push(b);
        }
    }
    while in_flight > 0 {
        let mut b = from_filter.recv().map_err(|_| filter_gone())?;
        in_flight -= 1;
        write_rows(&mut b, out)?;
    }
    out.write_all(&text)?;
    Ok((malformed, by_reason))
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
