//! `canodom simulate --follow-calibration`: a simulated vehicle that drives
//! what the daemon's guided calibration asks for, so the whole session can be
//! tried with no car at hand.
//!
//! The vehicle listens to `CALIB_STATUS` (decoded with [`CalibWire`]) and to
//! the operator's `CALIB_CMD` `START_SESSION` (for the track radius). When
//! the status says GO it drives one lap of the track in the instructed
//! direction with the fusion crate's simulator, from rest to rest; otherwise
//! it stands still and keeps sending rest frames, as a parked car's ECUs do.
//! Wheel counters carry over from run to run, so they never jump. It stops
//! when the session has ended (committed or aborted), after its time limit,
//! or on SIGINT/SIGTERM.
//!
//! [`follow`] is generic over the bus so a test drives it against the real
//! daemon on the in-process bus.

use crate::vehicle::{SampleEncoder, sim_config};
use canodom_can::bus::{BusEvent, FrameSink, FrameSource};
use canodom_can::frame::{CanFrame, FrameId};
use canodom_fusion::sim::{Direction, Plan, Sample, Segment, SimConfig, Simulator};
use canodom_fusion::{Pose, VehicleParams, Wheel};
use canodom_pipeline::config::Config;
use canodom_protocol::calib_wire::{
    CalibWire, CmdCode, Command, Counts, InstructionCode, Progress, State,
};
use canodom_protocol::calib_wire::{Reason, StatusPage, WireDirection};
use std::io::Write;
use std::time::Duration;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

/// Rest kept by the simulator before and after each lap, s. The follower's
/// own rest frames stand in for the rest of the wait; the daemon asks for
/// the next run only after its own standstill time anyway.
const RUN_REST_S: f64 = 0.3;

/// Rest frames sent after the session has ended, so a committed set is
/// applied at a standstill the daemon can see before the vehicle goes quiet.
const LINGER: Duration = Duration::from_secs(2);

/// A GO seen this soon after a lap ended may predate the daemon's view of
/// that lap's end; it is not taken as the next instruction.
const GO_SETTLE: Duration = Duration::from_millis(300);

/// What the follower is told, beyond the configuration.
#[derive(Debug, Clone, Copy)]
pub struct FollowOptions {
    /// The true vehicle.
    pub true_params: VehicleParams,
    /// Cruise speed, m/s; `None` keeps the simulator's default for the vehicle.
    pub speed_mps: Option<f64>,
    /// Track semicircle radius ρ, m; `None` takes it from the operator's
    /// `START_SESSION` seen on the bus (or, failing that, the default track).
    pub track_radius_m: Option<f64>,
    /// Give up after this long.
    pub time_limit: Duration,
    /// Seed of the first lap (each lap adds one).
    pub seed: u64,
}

/// How the follower ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FollowOutcome {
    /// The session ended with a commit; the version now in use.
    Committed(u16),
    /// The session ended otherwise (abort, or a command that dropped it).
    Ended,
    /// The time limit passed first.
    TimeLimit,
    /// Stopped by a signal (or the caller).
    Stopped,
}

/// One lap driven.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LapRecord {
    /// Run index the status asked for (1-based).
    pub run_index: u8,
    /// Direction driven.
    pub direction: Direction,
    /// Track semicircle radius ρ, m.
    pub track_radius_m: f64,
    /// True distance driven, m.
    pub distance_m: f64,
    /// Bus time the lap took (rests included), s.
    pub duration_s: f64,
    /// True end pose relative to the start pose: what an operator measures.
    pub true_end: Pose,
}

/// What the follower did.
#[derive(Debug, Clone, PartialEq)]
pub struct FollowSummary {
    /// Every lap, in order.
    pub laps: Vec<LapRecord>,
    /// Frames sent.
    pub frames_sent: u64,
    /// Frames the bus refused (a full queue, a link down).
    pub send_failures: u64,
    /// Why it stopped.
    pub outcome: FollowOutcome,
}

/// The lap being driven.
struct Lap {
    sim: Simulator,
    record: LapRecord,
    started: Instant,
    /// Added to the simulator's counters (modulo their width) so the first
    /// sample continues the previous lap's last one.
    offset: Option<[u64; 4]>,
    last_true_distance_m: f64,
}

/// The status as last seen.
#[derive(Default)]
struct Seen {
    progress: Option<(Progress, Instant)>,
    counts: Option<Counts>,
    /// Radius of the last well-formed `START_SESSION` on the bus, m.
    start_radius_m: Option<f64>,
    /// A session was seen active.
    session_active_once: bool,
    /// The version a carried-out COMMIT put in use.
    committed: Option<u16>,
}

/// The simulated vehicle's mechanics between status frames.
struct Vehicle {
    sim: SimConfig,
    encoder: SampleEncoder,
    /// The sample the vehicle rests at (its counters are the current ones).
    rest: Sample,
    tick_mask: u64,
    frames: Vec<CanFrame>,
}

impl Vehicle {
    /// Sends one sample; returns (sent, failed).
    async fn send<S: FrameSink>(&mut self, sink: &S, sample: &Sample) -> (u64, u64) {
        self.frames.clear();
        self.encoder.encode(sample, &mut self.frames);
        let (mut sent, mut failed) = (0, 0);
        for f in &self.frames {
            if sink.send(f).await.is_ok() {
                sent += 1;
            } else {
                failed += 1;
            }
        }
        (sent, failed)
    }

    /// The next sample of `lap` with counters carried over, or `None` at its end.
    fn next_of(&self, lap: &mut Lap) -> crate::error::Result<Option<Sample>> {
        let Some(mut s) = lap.sim.try_next()? else {
            return Ok(None);
        };
        let offset = *lap.offset.get_or_insert_with(|| {
            let mut o = [0u64; 4];
            for (i, w) in Wheel::ALL.iter().enumerate() {
                o[i] = self.rest.ticks[*w].wrapping_sub(s.ticks[*w]) & self.tick_mask;
            }
            o
        });
        for (i, w) in Wheel::ALL.iter().enumerate() {
            s.ticks[*w] = s.ticks[*w].wrapping_add(offset[i]) & self.tick_mask;
        }
        lap.last_true_distance_m = s.true_distance_m;
        Ok(Some(s))
    }
}

/// The default track of the vehicle's scale (the `simulate --path track-*` one).
fn default_radius_m(config: &Config) -> f64 {
    crate::vehicle::track_radius_m(matches!(
        config.signals.wheel_kind,
        canodom_pipeline::config::WheelKind::Speed(_)
    ))
}

/// One lap of the track (`Plan::track`) driven by a driver who knows the
/// steering servo's first-order lag `servo_lag_s`: each change of curvature
/// is commanded early by the distance the car covers in one lag time at the
/// speed it has there (cruise `speed_mps`, ramps of `accel_mps2` at both
/// ends), so the wheels' angle changes where the track's curvature does.
/// The last change comes as the car stops and needs no lead. Without this a
/// lap at 0.1 m/s ends about 1° short of the last turn (11° with the lag of
/// a real servo at 1 m/s), and the calibration learns the driver's lateness
/// instead of the wheels.
fn anticipated_track(
    radius_m: f64,
    direction: Direction,
    sim: &SimConfig,
) -> crate::error::Result<Plan> {
    let pi = std::f64::consts::PI;
    let arc_m = pi * radius_m;
    let straight_m = 2.0 * radius_m;
    let total_m = 2.0 * (arc_m + straight_m);
    let speed_at = |s_m: f64| {
        let ramp = |d_m: f64| (2.0 * sim.accel_mps2 * d_m.max(0.0)).sqrt();
        sim.speed_mps.min(ramp(s_m)).min(ramp(total_m - s_m))
    };
    let lead =
        |s_m: f64| (speed_at(s_m) * sim.path_following.servo_lag_s).clamp(0.0, 0.25 * radius_m);
    // Commanded change points: the track's, each moved early by its lead.
    let changes = [
        straight_m - lead(straight_m),
        straight_m + arc_m - lead(straight_m + arc_m),
        2.0 * straight_m + arc_m - lead(2.0 * straight_m + arc_m),
        total_m,
    ];
    let mut from_m = 0.0;
    let mut segments = Vec::with_capacity(4);
    for (k, to_m) in changes.into_iter().enumerate() {
        let length_m = to_m - from_m;
        segments.push(if k % 2 == 0 {
            Segment::Straight { length_m }
        } else {
            Segment::Arc {
                radius_m,
                angle_rad: direction.sign() * length_m / radius_m,
            }
        });
        from_m = to_m;
    }
    Ok(Plan::new(segments)?)
}

fn direction_name(d: Direction) -> &'static str {
    match d {
        Direction::Cw => "CW",
        Direction::Ccw => "CCW",
    }
}

/// Drives what `CALIB_STATUS` instructs until the session ends, the time
/// limit passes or `stop` fires. Progress goes to `out` as plain lines.
///
/// `rx` must deliver the daemon's `CALIB_STATUS` and the operator's
/// `CALIB_CMD` (other frames are ignored); `tx` carries the vehicle's frames.
///
/// # Errors
/// The simulator refused the vehicle or a lap, or the bus failed for good.
#[allow(clippy::too_many_lines)] // one select loop: splitting it hides the timing
pub async fn follow<R: FrameSource, S: FrameSink>(
    config: &Config,
    options: &FollowOptions,
    mut rx: R,
    tx: &S,
    stop: CancellationToken,
    out: &mut (dyn Write + Send),
) -> crate::error::Result<FollowSummary> {
    let wire = CalibWire::new(config.output.base_id)?;
    let cmd_id: FrameId = config.calibration.command_id;
    let mut sim = sim_config(config, options.true_params);
    if let Some(v) = options.speed_mps {
        if !(v.is_finite() && v > 0.0) {
            return Err(crate::error::Error::Invalid(format!(
                "the speed must be positive, got {v} m/s"
            )));
        }
        crate::drive::set_speed(&mut sim, v);
    }
    sim.standstill_s = RUN_REST_S;
    let rate_hz = sim.rate_hz;
    // The first sample of any lap is the vehicle at rest at the origin.
    let rest = Simulator::new(
        &sim,
        &Plan::track(default_radius_m(config), Direction::Ccw, 1)?,
        options.seed,
    )?
    .try_next()?
    .ok_or_else(|| crate::error::Error::Invalid("the simulator produced no sample".to_owned()))?;
    let mut vehicle = Vehicle {
        tick_mask: if sim.wheel_output.counter_bits >= 64 {
            u64::MAX
        } else {
            (1u64 << sim.wheel_output.counter_bits) - 1
        },
        sim,
        encoder: SampleEncoder::new(config),
        rest,
        frames: Vec::new(),
    };
    let mut summary = FollowSummary {
        laps: Vec::new(),
        frames_sent: 0,
        send_failures: 0,
        outcome: FollowOutcome::Stopped,
    };
    let mut seen = Seen::default();
    let mut lap: Option<Lap> = None;
    let mut lap_ended: Option<Instant> = None;
    let mut ended: Option<Instant> = None;
    let mut waiting_end_pose_told = false;
    let started = Instant::now();
    let deadline = started + options.time_limit;
    let mut tick = tokio::time::interval(Duration::from_secs_f64(1.0 / rate_hz));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
    writeln!(
        out,
        "follow: standing still until CALIB_STATUS says GO (time limit {:.0} s)",
        options.time_limit.as_secs_f64()
    )?;
    loop {
        tokio::select! {
            biased;
            () = stop.cancelled() => {
                summary.outcome = FollowOutcome::Stopped;
                break;
            }
            ev = rx.recv() => {
                let BusEvent::Frame(r) = ev? else { continue };
                let data = r.frame.data();
                if r.frame.id() == wire.status_id() {
                    match wire.decode_status(data) {
                        Ok((StatusPage::Progress(p), _)) => {
                            seen.session_active_once |= p.state.is_active();
                            seen.progress = Some((p, Instant::now()));
                        }
                        Ok((StatusPage::Counts(c), _)) => {
                            report_counts(out, seen.counts.as_ref(), &c)?;
                            // The answer to COMMIT may come after the IDLE
                            // progress page it caused: remember it apart.
                            if seen.session_active_once
                                && c.last_cmd == CmdCode::Commit.code()
                                && c.cmd_reason == Reason::None
                            {
                                seen.committed = Some(c.active_version);
                            }
                            seen.counts = Some(c);
                        }
                        _ => {}
                    }
                } else if r.frame.id() == cmd_id
                    && let Ok(cmd) = wire.decode_command(data)
                    && cmd.checksum_ok
                    && let Some(Command::StartSession { track_radius_mm, .. }) = cmd.command
                {
                    seen.start_radius_m = Some(f64::from(track_radius_mm) / 1000.0);
                }
                continue;
            }
            _ = tick.tick() => {}
        }
        let now = Instant::now();
        // Drive the lap, or stand still.
        let sample = match lap.as_mut() {
            Some(l) => vehicle.next_of(l)?,
            None => None,
        };
        if let Some(s) = sample {
            let (a, b) = vehicle.send(tx, &s).await;
            summary.frames_sent += a;
            summary.send_failures += b;
            vehicle.rest = s;
        } else {
            if let Some(mut l) = lap.take() {
                l.record.duration_s = (now - l.started).as_secs_f64();
                l.record.distance_m = l.last_true_distance_m;
                l.record.true_end = l.sim.true_pose();
                let e = l.record.true_end;
                writeln!(
                    out,
                    "follow: run {} {} done: {:.2} m in {:.1} s; true end from its start: \
                     dx {:+.0} mm, dy {:+.0} mm, dθ {:+.1}°",
                    l.record.run_index,
                    direction_name(l.record.direction),
                    l.record.distance_m,
                    l.record.duration_s,
                    e.x_m * 1000.0,
                    e.y_m * 1000.0,
                    (e.heading_rad - l.record.direction.sign() * std::f64::consts::TAU)
                        .to_degrees()
                )?;
                summary.laps.push(l.record);
                lap_ended = Some(now);
            }
            let rest = vehicle.rest;
            let (a, b) = vehicle.send(tx, &rest).await;
            summary.frames_sent += a;
            summary.send_failures += b;
        }
        if let Some(at) = ended {
            if now - at >= LINGER {
                summary.outcome = if let Some(v) = seen.committed {
                    writeln!(out, "follow: session committed, parameter set {v} in use")?;
                    FollowOutcome::Committed(v)
                } else {
                    writeln!(out, "follow: session ended without a commit")?;
                    FollowOutcome::Ended
                };
                break;
            }
            continue;
        }
        if now >= deadline {
            summary.outcome = FollowOutcome::TimeLimit;
            writeln!(out, "follow: time limit reached")?;
            break;
        }
        let Some((p, p_at)) = seen.progress else {
            continue;
        };
        if seen.session_active_once && p.state == State::Idle && lap.is_none() {
            writeln!(
                out,
                "follow: the session is over; standing still {:.0} s, then stopping",
                LINGER.as_secs_f64()
            )?;
            ended = Some(now);
            continue;
        }
        if lap.is_some() {
            continue;
        }
        if p.state == State::AwaitingEndPose && !waiting_end_pose_told {
            waiting_end_pose_told = true;
            writeln!(
                out,
                "follow: the daemon asks for the measured end pose (END_POSE); the true one is printed above"
            )?;
        }
        let settled = lap_ended.is_none_or(|t| p_at >= t + GO_SETTLE);
        if p.state == State::Positioning && p.instruction == InstructionCode::Go && settled {
            let direction = match p.direction {
                WireDirection::Ccw => Direction::Ccw,
                WireDirection::Cw => Direction::Cw,
                WireDirection::None => continue,
            };
            waiting_end_pose_told = false;
            let radius_m = options
                .track_radius_m
                .or(seen.start_radius_m)
                .unwrap_or_else(|| default_radius_m(config));
            let seed = options.seed + summary.laps.len() as u64 + 1;
            let plan = anticipated_track(radius_m, direction, &vehicle.sim)?;
            writeln!(
                out,
                "follow: run {} of {} {}: driving {:.2} m at {:.2} m/s (track radius {radius_m} m, seed {seed})",
                p.run_index,
                p.runs_total,
                direction_name(direction),
                plan.length_m(),
                vehicle.sim.speed_mps
            )?;
            lap = Some(Lap {
                sim: Simulator::new(&vehicle.sim, &plan, seed)?,
                record: LapRecord {
                    run_index: p.run_index,
                    direction,
                    track_radius_m: radius_m,
                    distance_m: 0.0,
                    duration_s: 0.0,
                    true_end: Pose::default(),
                },
                started: now,
                offset: None,
                last_true_distance_m: 0.0,
            });
            // A status still naming this GO must not start a second lap.
            seen.progress = None;
        }
    }
    Ok(summary)
}

/// Prints run verdicts as the counts change.
fn report_counts(
    out: &mut dyn Write,
    before: Option<&Counts>,
    now: &Counts,
) -> std::io::Result<()> {
    let Some(b) = before else { return Ok(()) };
    let accepted = (now.ccw_accepted + now.cw_accepted) > (b.ccw_accepted + b.cw_accepted);
    let rejected = (now.ccw_rejected + now.cw_rejected) > (b.ccw_rejected + b.cw_rejected);
    if accepted {
        writeln!(
            out,
            "follow: run accepted (CCW {} accepted, CW {} accepted)",
            now.ccw_accepted, now.cw_accepted
        )?;
    }
    if rejected {
        writeln!(out, "follow: run rejected: {}", now.reject_reason)?;
    }
    Ok(())
}
