//! `canodom replay`'s work: the daemon's pipeline over a CAN log, timed by
//! the log's timestamps, as fast as the machine goes; one CSV row (or one
//! [`ReplayRow`] of values) per filter step.

use crate::{Error, Result};
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
use canodom_pipeline::stats::Stats;
use canodom_report::float_text::{push_csv_row, push_f64, push_micros_as_seconds};
use std::io::{Read, Write};
use std::sync::mpsc;

/// The CSV header `replay` writes.
pub const CSV_HEADER: &str = "t_s,x_m,y_m,heading_rad,odo_x_m,odo_y_m,odo_heading_rad,correction,\
t_unix_s,speed_mps,pos_std_m,heading_std_rad,pose_valid,quality";

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
    pub seen: canodom_can::log_format::LogSeen,
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
    /// Parameter sets taken into use as the replay reaches their times (in
    /// time order): what `replay --fixes` learnt, from when it learnt it.
    pub switches: &'a [(Timestamp, canodom_params::persist::ParamSet)],
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

/// Records per batch handed from the reading thread to the filter thread:
/// enough that the hand-over costs nothing per record and a thread seldom
/// sleeps on the other (1,024 made ~370 context switches a million frames,
/// this ~40), few enough that the batches in flight stay in the CPU caches
/// (≈ 130 kB of records, 170 kB of CSV each).
const BATCH_RECORDS: usize = 4096;

/// CSV bytes written at once: what `execute`'s `BufWriter` holds, so that it
/// passes each write straight on (a copy into it was 3 % of the reading
/// thread's instructions).
pub const WRITE_BYTES: usize = 1 << 16;

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
    rows: Vec<ReplayRow>,
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

impl Batch {
    /// An empty batch with room for [`BATCH_RECORDS`] records.
    fn new() -> Self {
        Self {
            records: Vec::with_capacity(BATCH_RECORDS),
            others: Vec::new(),
            rows: Vec::with_capacity(BATCH_RECORDS),
            text: Vec::new(),
            samples: Vec::new(),
            params: None,
            carried: FrameBuffer::default(),
            chunk: Chunk::default(),
            encoded: false,
        }
    }
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

/// One filter step as replay's CSV row holds it, as values: the step's time
/// in microseconds since the first frame (the CSV writes it from the
/// integer: exact, and no float to take apart), the six pose values and the
/// pose sample `run` would publish there.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReplayRow {
    /// The step's time since the log's first frame, µs (`t_s`).
    pub t_us: i64,
    /// `x_m, y_m, heading_rad` fused, then `odo_x_m, odo_y_m, odo_heading_rad` rear-only.
    pub values: [f64; 6],
    /// What the correction window did at the step (`correction`).
    pub correction: WindowOutcome,
    /// The step's time on the log's clock, µs (`t_unix_s`).
    pub t_unix_us: i64,
    /// Speed, position and heading standard deviations of the pose sample
    /// (`speed_mps, pos_std_m, heading_std_rad`).
    pub sample: [f64; 3],
    /// The pose sample's flags ([`PoseFlags::bits`]): `quality`, its bit 0
    /// `pose_valid`.
    ///
    /// [`PoseFlags::bits`]: canodom_pipeline::pipeline::PoseFlags::bits
    pub quality: u16,
}

/// Appends `rows` to `text` as CSV lines.
fn push_rows(text: &mut Vec<u8>, rows: &[ReplayRow]) {
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
        text.push(if row.quality & 1 == 1 { b'1' } else { b'0' });
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
) -> Result<ReplaySummary> {
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
) -> Result<ReplaySummary> {
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
pub fn replay_log(
    config: &Config,
    params: Option<&canodom_params::persist::ParamSet>,
    options: ReplayOptions<'_>,
    input: impl Read,
    out: &mut impl Write,
    diag: &mut impl Write,
    mut mcap: Option<McapOut>,
) -> Result<ReplaySummary> {
    let mut pipeline = new_pipeline(config, params)?;
    // Read unbuffered by LogReader's own large blocks (a BufReader passes
    // reads larger than its buffer straight through); other formats use it.
    let mut reader =
        crate::log::log_reader(std::io::BufReader::new(input), options.interface, true)?;
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
        let mut switcher = Switcher::new(options.switches);
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
                    filter_batch(&mut pipeline, &mut batch, samples, &mut switcher);
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
                (pipeline, switcher.failed)
            })?;
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
        let (mut pipeline, switch_failed) = filter
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
        let (malformed, by_reason) = fed?;
        if let Some(why) = switch_failed {
            return Err(Error::Calibration(why));
        }
        if let Some(m) = mcap {
            m.finish()?.flush()?;
        }
        Ok(summary_of(
            &mut pipeline,
            &reader,
            (malformed, by_reason),
            kept,
        ))
    })
}

/// Takes [`ReplayOptions::switches`] into use as the frames reach their times.
struct Switcher<'a> {
    switches: &'a [(Timestamp, canodom_params::persist::ParamSet)],
    next: usize,
    /// Why a set could not be taken into use (the replay then fails).
    failed: Option<String>,
}

impl<'a> Switcher<'a> {
    fn new(switches: &'a [(Timestamp, canodom_params::persist::ParamSet)]) -> Self {
        Self {
            switches,
            next: 0,
            failed: None,
        }
    }

    /// Takes every set due by `at` into use before the frame at `at`.
    fn before(&mut self, pipeline: &mut Pipeline, at: Timestamp) {
        while let Some((due, set)) = self.switches.get(self.next) {
            if *due > at {
                break;
            }
            self.next += 1;
            if let Err(e) = pipeline.apply_params(Some((set.version, &set.values))) {
                self.failed.get_or_insert(format!(
                    "the set learnt at {:.3} s (version {}) was refused by the filter: {e}",
                    due.as_micros() as f64 / 1e6,
                    set.version
                ));
            }
        }
    }
}

/// Runs one batch's records through the pipeline, a row per filter step
/// with the pose sample `run` would publish at that frame.
fn filter_batch(
    pipeline: &mut Pipeline,
    batch: &mut Batch,
    samples: bool,
    switcher: &mut Switcher<'_>,
) {
    for (k, entry) in batch.records.iter().enumerate() {
        let (at, step) = match entry {
            Entry::Classic(c) => {
                switcher.before(pipeline, c.timestamp);
                (
                    c.timestamp,
                    pipeline
                        .push_data(c.timestamp, c.id, c.payload())
                        .step()
                        .copied(),
                )
            }
            Entry::Other(i) => match batch.others.get(*i) {
                Some((t, frame)) => {
                    switcher.before(pipeline, *t);
                    (*t, pipeline.push(*t, frame).step().copied())
                }
                None => continue,
            },
        };
        if let Some(s) = step {
            let p = pipeline.pose_output(at);
            if samples {
                batch.samples.push((k + 1, StepSample::of(pipeline, &s, p)));
            }
            let t0_us = pipeline
                .first_frame_time()
                .map_or(0, |t| t.as_micros() as i64);
            batch.rows.push(ReplayRow {
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
    reader: &mut canodom_can::any_log::AnyLogReader<'_>,
    to_filter: &mpsc::Sender<Batch>,
    from_filter: &mpsc::Receiver<Batch>,
    (out, mut mcap): (&mut impl Write, Option<&mut McapOut>),
    (diag, warn_prefix): (&mut impl Write, &str),
    mut kept: Option<&mut Vec<(i64, [f64; 6])>>,
) -> Result<(u64, MalformedCounts)> {
    let mut malformed = 0u64;
    let mut by_reason = MalformedCounts::default();
    let mut spare: Vec<Batch> = (0..BATCHES).map(|_| Batch::new()).collect();
    let mut in_flight = 0usize;
    let mut text = Vec::with_capacity(2 * WRITE_BYTES);
    // Rows are gathered until at least `WRITE_BYTES` (a `BufWriter` of that
    // capacity then hands them on without copying them into its buffer).
    let mut encoder = mcap.as_deref().map(McapOut::encoder);
    let mut write_rows = |batch: &mut Batch, out: &mut dyn Write| -> Result<()> {
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
    let filter_gone = || Error::FilterThread;
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
        at_end = fill_batch(
            reader,
            &mut batch,
            &mut malformed,
            &mut by_reason,
            (&mut *diag, warn_prefix),
        )?;
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

/// Fills `batch` with the log's next records, counting (and reporting the
/// first 20 of) its malformed lines. Returns whether the log has ended.
fn fill_batch(
    reader: &mut canodom_can::any_log::AnyLogReader<'_>,
    batch: &mut Batch,
    malformed: &mut u64,
    by_reason: &mut MalformedCounts,
    (diag, warn_prefix): (&mut impl Write, &str),
) -> Result<bool> {
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
            Ok(None) => return Ok(true),
            Err(ReadError::Malformed(m)) => {
                *malformed += 1;
                by_reason.add(m.reason);
                if *malformed <= 20 {
                    writeln!(diag, "{warn_prefix}: {m}; skipped")?;
                }
            }
            Err(e @ (ReadError::Io(_) | ReadError::Corrupt(_))) => {
                return Err(Error::Read {
                    path: warn_prefix.trim_start_matches("replay: ").to_owned(),
                    source: e,
                });
            }
        }
    }
    Ok(false)
}

/// A fresh pipeline for `config`, with `params` in use from the first frame.
fn new_pipeline(
    config: &Config,
    params: Option<&canodom_params::persist::ParamSet>,
) -> Result<Pipeline> {
    let mut pipeline = Pipeline::new(config).map_err(|source| Error::Filter {
        context: "the configured vehicle".to_owned(),
        source,
    })?;
    if let Some(set) = params {
        pipeline
            .apply_params(Some((set.version, &set.values)))
            .map_err(|source| Error::Filter {
                context: format!("parameter set version {}", set.version),
                source,
            })?;
    }
    Ok(pipeline)
}

/// What a finished replay did.
fn summary_of(
    pipeline: &mut Pipeline,
    reader: &canodom_can::any_log::AnyLogReader<'_>,
    (malformed, by_reason): (u64, MalformedCounts),
    kept: Option<Vec<(i64, [f64; 6])>>,
) -> ReplaySummary {
    let (warnings, diagnosis) = pipeline.plausibility_at_end();
    let seen = canodom_can::log_format::LogSeen::of(reader, pipeline.stats().frames, malformed);
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
    ReplaySummary {
        seen,
        track,
        first_frame: pipeline.first_frame_time(),
        stats: *pipeline.stats(),
        malformed,
        malformed_by_reason: by_reason,
        last_step: pipeline.last_step(),
        state: *pipeline.state(),
        warnings,
        diagnosis,
    }
}

/// [`replay_log`]'s steps as values instead of text, on the calling thread
/// alone (a fleet job runs one log per core; replay's second thread would
/// only compete with the next log's). The same pipeline and the same
/// reading of the log as the CSV: each row holds the values its CSV line
/// prints. Memory: the rows, and one batch of records.
///
/// # Errors
/// As [`replay_log`].
pub fn replay_rows(
    config: &Config,
    params: Option<&canodom_params::persist::ParamSet>,
    options: ReplayOptions<'_>,
    input: impl Read,
    diag: &mut impl Write,
) -> Result<(Vec<ReplayRow>, ReplaySummary)> {
    let mut pipeline = new_pipeline(config, params)?;
    let mut reader =
        crate::log::log_reader(std::io::BufReader::new(input), options.interface, true)?;
    let mut batch = Batch::new();
    let mut rows = Vec::new();
    let (mut malformed, mut by_reason) = (0, MalformedCounts::default());
    let prefix = options.warning_prefix();
    let mut switcher = Switcher::new(options.switches);
    loop {
        let at_end = fill_batch(
            &mut reader,
            &mut batch,
            &mut malformed,
            &mut by_reason,
            (&mut *diag, &prefix),
        )?;
        batch.rows.clear();
        filter_batch(&mut pipeline, &mut batch, false, &mut switcher);
        rows.extend_from_slice(&batch.rows);
        if at_end {
            break;
        }
    }
    if let Some(why) = switcher.failed {
        return Err(Error::Calibration(why));
    }
    let summary = summary_of(&mut pipeline, &reader, (malformed, by_reason), None);
    Ok((rows, summary))
}
