//! `canodom replay`: the daemon's pipeline over a candump log, timed by the
//! log's timestamps, as fast as the machine goes; one CSV row per filter step.

use crate::candump::{LogReader, MalformedCounts, ReadError};
use crate::config::Config;
use crate::float_text::push_f64;
use crate::pipeline::{Pipeline, Step};
use crate::stats::Stats;
use anyhow::Context as _;
use std::fmt::Write as _;
use std::io::Write;
use std::path::PathBuf;

/// The CSV header `replay` writes.
pub const CSV_HEADER: &str = "t_s,x_m,y_m,heading_rad,odo_x_m,odo_y_m,odo_heading_rad";

/// Arguments of `replay`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example:\n  canodom simulate --config rc_car.toml --log drive.log --truth truth.csv\n  \
canodom replay --config rc_car.toml drive.log --out pose.csv\n\n\
The CSV has one row per filter step (one per rear-wheel frame): seconds since the first input \
frame, the fused pose, then rear-wheel-only odometry; both start at (0, 0, 0) at the first \
wheel sample, headings are unwrapped (total turn, radians). Statistics go to stderr."
)]
pub struct ReplayArgs {
    /// The configuration file (the same one `run` uses).
    #[arg(long)]
    pub config: PathBuf,
    /// The candump -L log; `-` reads standard input.
    pub log: PathBuf,
    /// Where to write the CSV (standard output when absent).
    #[arg(long)]
    pub out: Option<PathBuf>,
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
}

/// Runs `replay`.
///
/// # Errors
/// Configuration, unreadable log, write failure.
pub fn execute(args: &ReplayArgs) -> anyhow::Result<()> {
    let config = Config::load(&args.config)?;
    let mut input = super::open_input(&args.log, "replay")
        .with_context(|| format!("{}", args.log.display()))?;
    let started = std::time::Instant::now();
    let summary = if let Some(path) = &args.out {
        let file = std::fs::File::create(path)
            .with_context(|| format!("cannot create {}", path.display()))?;
        let mut w = std::io::BufWriter::with_capacity(1 << 16, file);
        let s = replay(&config, &mut input, &mut w, &mut std::io::stderr())?;
        w.flush()?;
        s
    } else {
        let mut w = std::io::BufWriter::with_capacity(1 << 16, std::io::stdout().lock());
        let s = replay(&config, &mut input, &mut w, &mut std::io::stderr())?;
        w.flush()?;
        s
    };
    input.finish();
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
    Ok(())
}

/// Replays `input` through a fresh pipeline, CSV rows to `out`, malformed
/// lines reported on `diag` (the first 20, then counted only).
///
/// # Errors
/// Pipeline construction, I/O.
pub fn replay(
    config: &Config,
    input: impl std::io::BufRead,
    out: &mut impl Write,
    diag: &mut impl Write,
) -> anyhow::Result<ReplaySummary> {
    let mut pipeline = Pipeline::new(config)?;
    let mut reader = LogReader::new(input);
    let mut malformed = 0u64;
    let mut by_reason = MalformedCounts::default();
    writeln!(out, "{CSV_HEADER}")?;
    let mut row = Vec::with_capacity(160);
    loop {
        let record = match reader.next_record() {
            Ok(Some(r)) => r,
            Ok(None) => break,
            Err(ReadError::Malformed(m)) => {
                malformed += 1;
                by_reason.add(m.reason);
                if malformed <= 20 {
                    writeln!(diag, "replay: {m}; skipped")?;
                }
                continue;
            }
            Err(e @ ReadError::Io(_)) => return Err(e.into()),
        };
        if let Some(s) = pipeline.push(record.timestamp, &record.frame) {
            row.clear();
            for (i, v) in [
                s.t_s,
                s.fused.x_m,
                s.fused.y_m,
                s.fused.heading_rad,
                s.odometry.x_m,
                s.odometry.y_m,
                s.odometry.heading_rad,
            ]
            .into_iter()
            .enumerate()
            {
                if i > 0 {
                    row.push(b',');
                }
                push_f64(&mut row, v);
            }
            row.push(b'\n');
            out.write_all(&row)?;
        }
    }
    Ok(ReplaySummary {
        stats: *pipeline.stats(),
        malformed,
        malformed_by_reason: by_reason,
        last_step: pipeline.last_step(),
        state: *pipeline.state(),
    })
}
