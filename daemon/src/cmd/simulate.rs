//! `canodom simulate`: the fusion crate's simulator as a vehicle, its
//! samples encoded with the configured DBC (valid counters and checksums),
//! written to a candump log or sent onto an interface in real time.

use canodom_pipeline::config::Config;
use canodom_sim::drive::{drive, simulator_at, true_vehicle, write_log};
use canodom_sim::vehicle::PathKind;
use std::io::Write;
use std::path::PathBuf;

/// Arguments of `simulate`.
#[derive(Debug, clap::Args)]
#[command(
    group(clap::ArgGroup::new("target").required(true).args(["iface", "log"])),
    after_help = "Examples:\n  canodom simulate --config rc_car.toml --log drive.log --path track-ccw --truth truth.csv\n  \
canodom simulate --config rc_car.toml --iface vcan0 --path figure-eight\n  \
canodom simulate --config rc_car.toml --iface vcan0 --follow-calibration --true-params truth.toml --speed-mps 1\n\n\
With --follow-calibration the vehicle drives a guided calibration session of `canodom run` on the \
interface: it stands still until CALIB_STATUS says GO, then drives one lap of the track (radius from the \
operator's `canodom calib start --track-radius`, or --track-radius) in the direction asked for, stops, \
and waits for the next instruction; it stops by itself once the session is committed or aborted. \
Start it before `canodom calib ... start` so it hears the track radius.\n\n\
The vehicle is the configuration's nominal one unless --true-params gives a TOML file with any of: \
wheelbase_m, rear_tread_m, front_tread_m, rear_left_diameter_m, rear_right_diameter_m, \
front_left_diameter_m, front_right_diameter_m, steering_gain_factor, steering_offset_deg.\n\
Paths are sized for a 1:10 car with tick inputs (track radius 0.78 m) and 20x larger for a road car \
with speed inputs. `full-size` and `town` (road cars only) are the drives the fusion tests judge the \
filter on, drawn from --seed: tyre slip angles, a steering bias, stops, reversing, crawling. The truth CSV has t_s,x_m,y_m,heading_rad of the rear-axle centre per sample."
)]
pub struct SimulateArgs {
    /// The configuration file: DBC, signals, checks, nominal vehicle.
    #[arg(long)]
    pub config: PathBuf,
    /// Send onto this CAN interface in real time.
    #[arg(long)]
    pub iface: Option<String>,
    /// Write a candump -L log instead.
    #[arg(long)]
    pub log: Option<PathBuf>,
    /// The drive.
    #[arg(long, value_enum, default_value = "track-ccw")]
    pub path: PathKind,
    /// The true vehicle (TOML), when it differs from the nominal one.
    #[arg(long)]
    pub true_params: Option<PathBuf>,
    /// Seed of every random choice (noise, random path).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Write the true trajectory as CSV.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Let the wheels slip now and then (docs/calibration-math.md §11: 0.02 events/s per
    /// wheel, ratio N(0, 0.35), 0.5–2 s).
    #[arg(long)]
    pub slip: bool,
    /// Drive the path this many times (track laps, circle turns, 20 m of random drive each):
    /// long logs for benchmarks, about 24 700 frames per track lap.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub laps: u32,
    /// Cruise speed, m/s (default: the simulator's, 0.1 m/s for a 1:10 car with tick inputs).
    /// The path stays the default speed's: the driver's noise and the servo lag scale to the same
    /// size per metre and the car reaches its speed in the same time, so a faster drive is the
    /// same drive played faster.
    #[arg(long, value_parser = parse_positive)]
    pub speed_mps: Option<f64>,
    /// Drive the runs the daemon's guided calibration asks for on --iface (see below).
    #[arg(long, requires = "iface", conflicts_with_all = ["log", "truth", "laps", "slip"])]
    pub follow_calibration: bool,
    /// With --follow-calibration: the track's semicircle radius ρ, m, instead of the one heard in START_SESSION.
    #[arg(long, requires = "follow_calibration", value_parser = parse_positive)]
    pub track_radius: Option<f64>,
    /// With --follow-calibration: stop after this many seconds whatever happens.
    #[arg(long, default_value_t = 900.0, value_parser = parse_positive)]
    pub time_limit_s: f64,
}

/// A positive, finite number (speeds, radii, time limits).
fn parse_positive(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("expected a positive number, got `{s}`")),
    }
}

/// Runs `simulate`.
///
/// # Errors
/// Configuration, simulator, I/O or the interface.
pub fn execute(args: &SimulateArgs) -> anyhow::Result<()> {
    let config = Config::load(&args.config)?;
    if args.follow_calibration {
        return execute_follow(args, &config);
    }
    let mut sim = simulator_at(
        &config,
        args.path,
        args.true_params.as_deref(),
        args.seed,
        args.slip,
        args.laps,
        args.speed_mps,
    )?;
    if let Some(log) = &args.log {
        let file = std::fs::File::create(log)?;
        let mut out = std::io::BufWriter::with_capacity(1 << 16, file);
        let mut truth_file = match &args.truth {
            Some(p) => Some(std::io::BufWriter::new(std::fs::File::create(p)?)),
            None => None,
        };
        let n = write_log(
            &config,
            &mut sim,
            &mut out,
            truth_file.as_mut().map(|w| w as &mut dyn Write),
        )?;
        out.flush()?;
        if let Some(t) = truth_file.as_mut() {
            t.flush()?;
        }
        let end = sim.true_pose();
        eprintln!(
            "simulate: {n} frames to {}; true end pose ({:.4} m, {:.4} m, {:.4} rad)",
            log.display(),
            end.x_m,
            end.y_m,
            end.heading_rad
        );
        return Ok(());
    }
    let iface = args.iface.clone().unwrap_or_default();
    let truth_path = args.truth.clone();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async move {
        let (_rx, tx) = canodom_can::bus::open_socketcan(&iface, &[])?;
        let stop = tokio_util::sync::CancellationToken::new();
        let ctrl_c = stop.clone();
        tokio::spawn(async move {
            let _ = tokio::signal::ctrl_c().await;
            ctrl_c.cancel();
        });
        let mut truth = match &truth_path {
            Some(p) => {
                let mut w = std::io::BufWriter::new(std::fs::File::create(p)?);
                writeln!(w, "t_s,x_m,y_m,heading_rad")?;
                Some(w)
            }
            None => None,
        };
        let (sent, failed) = drive(&config, sim, &tx, 100.0, stop, |s| {
            if let Some(w) = truth.as_mut() {
                let p = s.true_pose;
                let _ = writeln!(w, "{},{},{},{}", s.t_s, p.x_m, p.y_m, p.heading_rad);
            }
        })
        .await?;
        if let Some(w) = truth.as_mut() {
            w.flush()?;
        }
        eprintln!("simulate: {sent} frames sent on {iface}, {failed} failed");
        anyhow::Ok(())
    })
}

/// `simulate --follow-calibration`: the vehicle of [`canodom_sim::follow`]
/// on the interface until the session ends, the time limit or a signal.
fn execute_follow(args: &SimulateArgs, config: &Config) -> anyhow::Result<()> {
    use canodom_sim::follow::{FollowOptions, FollowOutcome, follow};
    let options = FollowOptions {
        true_params: true_vehicle(config, args.true_params.as_deref())?,
        speed_mps: args.speed_mps,
        track_radius_m: args.track_radius,
        time_limit: std::time::Duration::from_secs_f64(args.time_limit_s),
        seed: args.seed,
    };
    let iface = args.iface.clone().unwrap_or_default();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async move {
        let wire = canodom_protocol::calib_wire::CalibWire::new(config.output.base_id)?;
        let filters = [
            canodom_can::bus::IdFilter::exact(wire.status_id()),
            canodom_can::bus::IdFilter::exact(config.calibration.command_id),
        ];
        let (rx, tx) = canodom_can::bus::open_socketcan(&iface, &filters)?;
        let stop = tokio_util::sync::CancellationToken::new();
        let on_signal = stop.clone();
        let mut term =
            tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
        tokio::spawn(async move {
            tokio::select! {
                _ = tokio::signal::ctrl_c() => {}
                _ = term.recv() => {}
            }
            on_signal.cancel();
        });
        let mut stdout = std::io::stdout();
        println!("simulate: following the guided calibration on {iface}");
        let summary = follow(config, &options, rx, &tx, stop, &mut stdout).await?;
        let outcome = match summary.outcome {
            FollowOutcome::Committed(v) => format!("session committed (parameter set {v})"),
            FollowOutcome::Ended => "session ended without a commit".to_owned(),
            FollowOutcome::TimeLimit => "time limit reached".to_owned(),
            FollowOutcome::Stopped => "stopped by a signal".to_owned(),
        };
        println!(
            "simulate: follow-calibration on {iface}: {} runs driven, {} frames sent, {} failed; {outcome}",
            summary.laps.len(),
            summary.frames_sent,
            summary.send_failures
        );
        anyhow::Ok(())
    })
}
