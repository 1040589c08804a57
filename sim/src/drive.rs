//! A drive on the bus or in a log: the simulator built for a configuration
//! (path, true vehicle, slips, laps, speed), its samples encoded with the
//! configured DBC and written as a candump log or sent through a transport.

use crate::vehicle::{PathKind, SampleEncoder, TrueParamsFile, sim_config};
use canodom_can::bus::FrameSink;
use canodom_can::candump::{Record, format_record};
use canodom_can::frame::CanFrame;
use canodom_can::time::Timestamp;
use canodom_fusion::VehicleParams;
use canodom_fusion::sim::{Sample, Simulator, SlipConfig, SlipWheels, SteeringSensor};
use canodom_pipeline::config::{Config, WheelKind};
use std::io::Write;

/// Log time of the first sample (2023-11-14T22:13:20Z): a fixed epoch keeps logs reproducible.
pub const LOG_EPOCH_US: u64 = 1_700_000_000_000_000;

/// Builds the simulator for `config` and the arguments.
///
/// # Errors
/// Bad true-parameter file, or the fusion crate refused the drive.
pub fn simulator(
    config: &Config,
    path: PathKind,
    true_params: Option<&std::path::Path>,
    seed: u64,
    slip: bool,
) -> crate::error::Result<Simulator> {
    simulator_at(config, path, true_params, seed, slip, 1, None)
}

/// The true vehicle: the configuration's nominal one changed by `true_params`.
///
/// # Errors
/// The file cannot be read or gives an impossible vehicle.
pub fn true_vehicle(
    config: &Config,
    true_params: Option<&std::path::Path>,
) -> crate::error::Result<VehicleParams> {
    Ok(match true_params {
        Some(p) => TrueParamsFile::load(p)?.apply(&config.params)?,
        None => config.params,
    })
}

/// [`simulator`] driving the path `laps` times ([`PathKind::plan_laps`]) at
/// `speed_mps` (`None`: the simulator's default).
///
/// # Errors
/// Bad true-parameter file, or the fusion crate refused the drive.
pub fn simulator_at(
    config: &Config,
    path: PathKind,
    true_params: Option<&std::path::Path>,
    seed: u64,
    slip: bool,
    laps: u32,
    speed_mps: Option<f64>,
) -> crate::error::Result<Simulator> {
    let mut cfg = sim_config(config, true_vehicle(config, true_params)?);
    if path.is_family() {
        if !matches!(config.signals.wheel_kind, WheelKind::Speed(_)) {
            return Err(crate::error::Error::Invalid(format!(
                "--path {} is a road car's drive: it needs wheel-speed inputs (wheel_kind = \"speed\")",
                if path == PathKind::Town {
                    "town"
                } else {
                    "full-size"
                }
            )));
        }
        // The family's world on the configured vehicle: its tyres, driver,
        // speeds and steering errors; the DBC's quantisation stays.
        let drive = path.family_drive(seed)?;
        cfg.tyres = drive.sim.tyres;
        cfg.path_following = drive.sim.path_following;
        cfg.speed_mps = drive.sim.speed_mps;
        cfg.steering_sensor = SteeringSensor {
            quantum: cfg.steering_sensor.quantum,
            ..drive.sim.steering_sensor
        };
        cfg.wheel_output.zero_below_mps = drive.sim.wheel_output.zero_below_mps;
    }
    if let Some(v) = speed_mps {
        set_speed(&mut cfg, v);
    }
    if slip {
        cfg.slip = SlipConfig::paper(SlipWheels::All);
    }
    let plan = path.plan_laps(
        matches!(config.signals.wheel_kind, WheelKind::Speed(_)),
        seed,
        laps,
    )?;
    Ok(Simulator::new(&cfg, &plan, seed)?)
}

/// Drives at `speed_mps` the path the simulator's default speed would
/// drive: the driver's noise and the servo's lag keep their size per metre
/// of path (their time constants scale with default speed / `speed_mps`), so
/// a faster drive is the same drive played faster and a calibration on it
/// is judged on the same geometry. The car reaches its speed in the same
/// time (acceleration scales with the speed), so the ramps stay short
/// beside the path.
pub fn set_speed(cfg: &mut canodom_fusion::sim::SimConfig, speed_mps: f64) {
    let k = cfg.speed_mps / speed_mps;
    cfg.accel_mps2 /= k;
    let pf = &mut cfg.path_following;
    pf.steer_noise_rad.tau_s *= k;
    pf.speed_noise.tau_s *= k;
    pf.servo_lag_s *= k;
    cfg.steering_sensor.drift_rad.tau_s *= k;
    cfg.speed_mps = speed_mps;
}

/// The bus time of a sample.
pub fn sample_time(s: &Sample) -> Timestamp {
    Timestamp::from_micros(LOG_EPOCH_US + (s.t_s * 1e6).round() as u64)
}

/// Writes the whole drive as a candump log to `out`, the truth to `truth`.
///
/// # Errors
/// Simulator failure or I/O.
pub fn write_log(
    config: &Config,
    sim: &mut Simulator,
    out: &mut impl Write,
    mut truth: Option<&mut dyn Write>,
) -> crate::error::Result<u64> {
    let mut enc = SampleEncoder::new(config);
    let mut frames = Vec::new();
    let mut line = Vec::with_capacity(128);
    let mut n = 0;
    if let Some(t) = truth.as_deref_mut() {
        writeln!(t, "t_s,x_m,y_m,heading_rad")?;
    }
    while let Some(s) = sim.try_next()? {
        frames.clear();
        enc.encode(&s, &mut frames);
        let timestamp = sample_time(&s);
        for frame in &frames {
            line.clear();
            format_record(
                &mut line,
                &Record {
                    timestamp,
                    iface: &config.interface,
                    frame: *frame,
                    direction: None,
                },
            );
            out.write_all(&line)?;
            n += 1;
        }
        if let Some(t) = truth.as_deref_mut() {
            let p = s.true_pose;
            writeln!(t, "{},{},{},{}", s.t_s, p.x_m, p.y_m, p.heading_rad)?;
        }
    }
    Ok(n)
}

/// Sends the drive onto `sink` in real time (the sample rate), stopping early
/// when `stop` fires. Each sample's frames go out back to back.
///
/// # Errors
/// Simulator failure; send errors are counted, not fatal (a bus may drop frames).
pub async fn drive<S: FrameSink>(
    config: &Config,
    sim: Simulator,
    sink: &S,
    rate_hz: f64,
    stop: tokio_util::sync::CancellationToken,
    mut on_sample: impl FnMut(&Sample),
) -> crate::error::Result<(u64, u64)> {
    let mut enc = SampleEncoder::new(config);
    let mut frames: Vec<CanFrame> = Vec::new();
    let mut tick = tokio::time::interval(std::time::Duration::from_secs_f64(1.0 / rate_hz));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
    let (mut sent, mut failed) = (0u64, 0u64);
    let mut sim = sim;
    loop {
        tokio::select! {
            () = stop.cancelled() => break,
            _ = tick.tick() => {}
        }
        let Some(s) = sim.try_next()? else { break };
        frames.clear();
        enc.encode(&s, &mut frames);
        for f in &frames {
            if sink.send(f).await.is_ok() {
                sent += 1;
            } else {
                failed += 1;
            }
        }
        on_sample(&s);
    }
    Ok((sent, failed))
}
