//! `canodom demo`: the whole system on a machine without CAN hardware. A
//! simulated vehicle sends its wheel and steering frames (encoded with the
//! configured DBC) onto an in-process bus; the daemon's own run loop
//! ([`crate::server::run`], the same code as `canodom run`) reads them at the
//! other end and publishes its pose frames back. Time is tokio's paused
//! clock, so a minute of driving takes a moment, and the run is reproducible.

use crate::server::{InProcessDaemon, Observers, Summary};
use canodom_fusion::Pose;
use canodom_pipeline::config::Config;
use canodom_sim::vehicle::PathKind;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::watch;

/// The built-in configuration: the 1:10 car of `rc_car.dbc`.
pub const DEFAULT_CONFIG: &str = include_str!("../../examples/rc_car.toml");

/// `rc_car.dbc`, built in with the configuration so the installed binary's
/// demo needs no file.
pub const DEFAULT_DBC: &str = include_str!("../../../data/dbc/rc_car.dbc");

/// Arguments of `demo`.
#[derive(Debug, clap::Args)]
#[command(after_help = "Example:\n  cargo run --release -p canodom -- demo\n  \
canodom demo --config daemon/examples/toyota.toml --path random --seed 3\n\n\
Prints a table every --every seconds of simulated time: the true pose, the fused pose, \
rear-wheel-only odometry, the fused pose's distance from the truth, and frames rejected so \
far; then the end errors. Without --config it uses the built-in rc_car configuration \
(daemon/examples/rc_car.toml with rc_car.dbc, both compiled in).")]
pub struct DemoArgs {
    /// A configuration file (default: daemon/examples/rc_car.toml, built in).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// The drive.
    #[arg(long, value_enum, default_value = "random")]
    pub path: PathKind,
    /// Seed of the simulated drive.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Wheels that never slip (by default they slip now and then, as in
    /// docs/calibration-math.md §11, which is where fusing the front wheels beats
    /// rear-only odometry).
    #[arg(long)]
    pub no_slip: bool,
    /// Seconds of simulated time between table rows.
    #[arg(long, default_value_t = 20.0)]
    pub every: f64,
}

/// What the demo measured.
#[derive(Clone, Debug)]
pub struct DemoReport {
    /// The printed table and end summary.
    pub text: String,
    /// The true end pose.
    pub true_end: Pose,
    /// The fused end pose (heading unwrapped).
    pub fused_end: Pose,
    /// Rear-only end pose.
    pub odometry_end: Pose,
    /// The daemon's summary.
    pub summary: Summary,
}

/// Loads the demo configuration: the file given, or the built-in one (with
/// its DBC built in too).
///
/// # Errors
/// The configuration is invalid.
pub fn load_config(path: Option<&std::path::Path>) -> anyhow::Result<Config> {
    Ok(match path {
        Some(p) => Config::load(p)?,
        None => Config::from_toml_with_dbc(
            DEFAULT_CONFIG,
            &PathBuf::from("<built-in rc_car.toml>"),
            DEFAULT_DBC,
        )?,
    })
}

/// Runs the demo on a paused-clock runtime.
///
/// # Errors
/// Configuration, simulator or daemon failure.
pub fn demo(
    config: Config,
    path: PathKind,
    seed: u64,
    slip: bool,
    every_s: f64,
) -> anyhow::Result<DemoReport> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()?;
    rt.block_on(demo_async(Arc::new(config), path, seed, slip, every_s))
}

fn row(out: &mut String, t: f64, truth: Pose, fused: Pose, odo: Pose, rejects: u64) {
    let err = |p: Pose| (p.x_m - truth.x_m).hypot(p.y_m - truth.y_m);
    let _ = writeln!(
        out,
        "{t:7.1} | {:8.3} {:8.3} {:7.2} | {:8.3} {:8.3} {:7.2} | {:8.3} {:8.3} {:7.2} | {:8.4} {:8.4} | {rejects:7}",
        truth.x_m,
        truth.y_m,
        truth.heading_rad.to_degrees(),
        fused.x_m,
        fused.y_m,
        fused.heading_rad.to_degrees(),
        odo.x_m,
        odo.y_m,
        odo.heading_rad.to_degrees(),
        err(fused),
        err(odo),
    );
}

async fn demo_async(
    config: Arc<Config>,
    path: PathKind,
    seed: u64,
    slip: bool,
    every_s: f64,
) -> anyhow::Result<DemoReport> {
    let sim = canodom_sim::drive::simulator(&config, path, None, seed, slip)?;
    let (steps_tx, steps_rx) = watch::channel(None);
    let (stats_tx, stats_rx) = watch::channel(canodom_pipeline::stats::Stats::default());
    let daemon = InProcessDaemon::spawn(
        Arc::clone(&config),
        4096,
        Observers {
            steps: Some(steps_tx),
            stats: Some(stats_tx),
            ..Observers::default()
        },
    );
    // Let the daemon open its endpoint before the vehicle starts.
    tokio::time::sleep(Duration::from_millis(10)).await;
    let (_vrx, vtx) = daemon.bus.open()?;
    let mut text = String::new();
    let _ = writeln!(
        text,
        "{:>7} | {:^26} | {:^26} | {:^26} | {:^17} | {:>7}",
        "t [s]",
        "true x y [m] θ [°]",
        "fused x y [m] θ [°]",
        "rear-only x y [m] θ [°]",
        "error fused/rear",
        "rejects"
    );
    let mut next_row = 0.0;
    let mut truth = Pose::default();
    let mut t_last = 0.0;
    let vehicle_stop = tokio_util::sync::CancellationToken::new();
    canodom_sim::drive::drive(&config, sim, &vtx, 100.0, vehicle_stop, |s| {
        truth = s.true_pose;
        t_last = s.t_s;
        if s.t_s + 1e-9 >= next_row {
            let step = *steps_rx.borrow();
            if let Some(step) = step {
                let rejects: u64 = stats_rx.borrow().nonzero().map(|(_, n)| n).sum();
                row(&mut text, s.t_s, truth, step.fused, step.odometry, rejects);
            }
            next_row += every_s;
        }
    })
    .await?;
    // Let the last frames through, then stop the daemon as SIGTERM would.
    tokio::time::sleep(Duration::from_millis(100)).await;
    let summary = daemon.stop().await?;
    let last = summary
        .last_step
        .ok_or_else(|| anyhow::anyhow!("the daemon made no filter step"))?;
    let rejects: u64 = summary.stats.nonzero().map(|(_, n)| n).sum();
    row(&mut text, t_last, truth, last.fused, last.odometry, rejects);
    let err = |p: Pose| (p.x_m - truth.x_m).hypot(p.y_m - truth.y_m);
    let _ = writeln!(
        text,
        "\nend after {t_last:.1} s: fused position error {:.4} m, heading error {:.3}°; \
         rear-only {:.4} m, {:.3}°",
        err(last.fused),
        (last.fused.heading_rad - truth.heading_rad).to_degrees(),
        err(last.odometry),
        (last.odometry.heading_rad - truth.heading_rad).to_degrees(),
    );
    let _ = writeln!(
        text,
        "daemon: {}; {} pose samples published on {} (ids {:#x}..)",
        summary.stats,
        summary.poses_published,
        config.interface,
        config.output.base_id.id().raw()
    );
    Ok(DemoReport {
        text,
        true_end: truth,
        fused_end: last.fused,
        odometry_end: last.odometry,
        summary,
    })
}

/// Runs `demo` and prints its report.
///
/// # Errors
/// As [`demo`].
pub fn execute(args: &DemoArgs) -> anyhow::Result<()> {
    let config = load_config(args.config.as_deref())?;
    let report = demo(config, args.path, args.seed, !args.no_slip, args.every)?;
    print!("{}", report.text);
    Ok(())
}
