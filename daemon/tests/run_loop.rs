//! The async daemon on the in-process bus: same poses as replay bit for bit,
//! published pose frames, reconnection after the interface goes away.

use crate::util::rc_car;
use canodom::server::{InProcessDaemon, Observers, run};
use canodom_can::bus::{BusEvent, FrameSink, FrameSource, InProcessBus, LinkState, Received};
use canodom_can::frame::{CanFrame, ErrorFrame};
use canodom_can::time::Timestamp;
use canodom_dbc::{Checksum, Database, FrameId};
use canodom_pipeline::config::Config;
use canodom_pipeline::pipeline::Pipeline;
use canodom_protocol::own_dbc::{OwnFrame, dbc_for_base};
use canodom_sim::drive::{LOG_EPOCH_US, drive, simulator};
use canodom_sim::vehicle::PathKind;
use std::sync::Arc;
use std::time::Duration;
use tokio_util::sync::CancellationToken;

#[derive(Clone)]
enum Disturb {
    Gone {
        at: Duration,
        outage: Duration,
    },
    BusOff {
        at: Duration,
    },
    /// ODOM_CMD payloads (CRC applied here), each at its time since the
    /// start; the drive's end waits for the last one.
    OdomCmd {
        base: canodom_protocol::own_dbc::BaseId,
        commands: Vec<(Duration, [u8; 8])>,
    },
}

/// An ODOM_CMD payload: request, arming code, counter (CRC applied later).
fn odom_cmd(request: u8, arming_code: u8, counter: u8) -> [u8; 8] {
    let mut d = [0u8; 8];
    d[0] = (request & 0x0F) | (arming_code << 4);
    d[1] = arming_code >> 4;
    d[6] = (counter & 0x0F) << 4;
    d
}

struct Outcome {
    summary: canodom::server::Summary,
    /// Every input frame as the daemon's side of the bus stamped it.
    recorded: Vec<Received>,
    /// Pose frames seen on the bus.
    pose_frames: Vec<Received>,
}

/// Drives a simulated vehicle against the daemon; `during` may disturb the bus.
async fn drive_against_daemon(
    config: Arc<Config>,
    path: PathKind,
    disturb: Option<Disturb>,
) -> Outcome {
    let daemon = InProcessDaemon::spawn(Arc::clone(&config), 8192, Observers::default());
    let bus = daemon.bus.clone();
    // A listener recording everything, as candump would.
    let (mut listener, _) = bus.open().unwrap();
    let base = config.output.base_id;
    let own: Vec<_> = OwnFrame::ALL.iter().map(|f| f.id(base)).collect();
    let rec_stop = CancellationToken::new();
    let rec_token = rec_stop.clone();
    let recorder = tokio::spawn(async move {
        let (mut inputs, mut poses) = (Vec::new(), Vec::new());
        loop {
            tokio::select! {
                () = rec_token.cancelled() => break,
                ev = listener.recv() => match ev {
                    Ok(BusEvent::Frame(r)) => {
                        if own.contains(&r.frame.id()) {
                            poses.push(r);
                        } else {
                            inputs.push(r);
                        }
                    }
                    Ok(_) => {}
                    // The link went down: wait for it to come back.
                    Err(_) => tokio::time::sleep(Duration::from_millis(5)).await,
                },
            }
        }
        (inputs, poses)
    });
    tokio::time::sleep(Duration::from_millis(10)).await;
    let mut commands_sent = None;
    if let Some(disturb) = disturb {
        let b = bus.clone();
        let task = tokio::spawn(async move {
            match disturb {
                Disturb::Gone { at, outage } => {
                    tokio::time::sleep(at).await;
                    b.set_link(LinkState::Gone);
                    tokio::time::sleep(outage).await;
                    b.set_link(LinkState::Up);
                }
                Disturb::BusOff { at } => {
                    tokio::time::sleep(at).await;
                    b.inject_error(ErrorFrame {
                        class: canodom_can::frame::err_class::BUS_OFF,
                        detail: [0; 8],
                    });
                }
                Disturb::OdomCmd { base, commands } => {
                    let (_rx, tx) = b.open().unwrap();
                    let start = tokio::time::Instant::now();
                    for (at, mut d) in commands {
                        tokio::time::sleep_until(start + at).await;
                        Checksum::rc_car().apply(&mut d).unwrap();
                        let f = CanFrame::new_data(OwnFrame::OdomCmd.id(base), &d).unwrap();
                        tx.send(&f).await.unwrap();
                    }
                }
            }
        });
        commands_sent = Some(task);
    }
    let (_vrx, vtx) = bus.open().unwrap();
    let sim = simulator(&config, path, None, 5, false).unwrap();
    drive(&config, sim, &vtx, 100.0, CancellationToken::new(), |_| {})
        .await
        .unwrap();
    if let Some(task) = commands_sent {
        task.await.unwrap();
    }
    tokio::time::sleep(Duration::from_millis(200)).await;
    let summary = daemon.stop().await.unwrap();
    rec_stop.cancel();
    let (recorded, pose_frames) = recorder.await.unwrap();
    Outcome {
        summary,
        recorded,
        pose_frames,
    }
}

#[tokio::test(start_paused = true)]
async fn run_equals_replay_bit_for_bit() {
    let config = Arc::new(rc_car());
    let out = drive_against_daemon(Arc::clone(&config), PathKind::TrackCw, None).await;
    let mut pipeline = Pipeline::new(&config).unwrap();
    for r in &out.recorded {
        pipeline.push(r.timestamp, &r.frame);
    }
    let s = out.summary;
    println!("run: {}, {} poses published", s.stats, s.poses_published);
    assert!(s.stats.steps > 5000);
    assert_eq!(s.stats, *pipeline.stats());
    assert_eq!(
        s.state,
        *pipeline.state(),
        "same frames, same filter state, bit for bit"
    );
    assert_eq!(s.last_step, pipeline.last_step());
    assert_eq!(s.frames_lost, 0);
    assert_eq!(s.connections, 1);
}

#[tokio::test(start_paused = true)]
async fn pose_frames_are_published_at_the_rate_and_decode() {
    let config = Arc::new(rc_car());
    let out = drive_against_daemon(Arc::clone(&config), PathKind::Circle, None).await;
    let db = Database::parse(&dbc_for_base(config.output.base_id), "canodom.dbc").unwrap();
    let positions: Vec<_> = out
        .pose_frames
        .iter()
        .filter(|r| r.frame.id() == OwnFrame::OdomPosition.id(config.output.base_id))
        .collect();
    let duration_s = (positions.last().unwrap().timestamp.as_micros()
        - positions[0].timestamp.as_micros()) as f64
        * 1e-6;
    let rate = (positions.len() - 1) as f64 / duration_s;
    println!(
        "{} pose samples over {duration_s:.1} s: {rate:.2} Hz",
        positions.len()
    );
    assert!((rate - 50.0).abs() < 0.5, "rate {rate}");
    for r in &out.pose_frames {
        assert!(Checksum::rc_car().verify(r.frame.data()).unwrap());
    }
    // The last pose sample carries the daemon's final pose.
    let last = positions.last().unwrap();
    let x = db.signal("ODOM_POSITION.POS_X").unwrap();
    let fused = out.summary.last_step.unwrap().fused;
    assert!((x.decode(last.frame.data()).unwrap() - fused.x_m).abs() < 0.002);
    let q = out.pose_frames.last().unwrap();
    let m = db
        .message_by_id(FrameId::standard(q.frame.id().raw() as u16).unwrap())
        .unwrap();
    assert_eq!(m.name(), "ODOM_QUALITY");
    let valid = db.signal("ODOM_QUALITY.POSE_VALID").unwrap();
    let stale = db.signal("ODOM_QUALITY.REAR_STALE").unwrap();
    // After the drive ended (200 ms of silence) the rear wheels are stale.
    assert_eq!(valid.decode(q.frame.data()), Some(0.0));
    assert_eq!(stale.decode(q.frame.data()), Some(1.0));
    // During the drive the pose was valid.
    let mid = out
        .pose_frames
        .iter()
        .filter(|r| r.frame.id() == OwnFrame::OdomQuality.id(config.output.base_id))
        .nth(positions.len() / 2)
        .unwrap();
    assert_eq!(valid.decode(mid.frame.data()), Some(1.0));
}

#[tokio::test(start_paused = true)]
async fn interface_gone_then_back_is_survived() {
    let config = Arc::new(rc_car());
    let out = drive_against_daemon(
        Arc::clone(&config),
        PathKind::TrackCcw,
        Some(Disturb::Gone {
            at: Duration::from_secs(10),
            outage: Duration::from_secs(2),
        }),
    )
    .await;
    let s = out.summary;
    println!(
        "after an outage: {}, connections {}",
        s.stats, s.connections
    );
    assert!(s.connections >= 2, "reopened after the interface came back");
    // It resumed: steps continue well after the outage (the drive is ~80 s).
    assert!(s.last_step.unwrap().t_s > 60.0);
    // The filter ran on across the gap: wheel decoders saw it as missed samples.
    assert!(s.stats.get(canodom_pipeline::stats::Reject::WheelGap) >= 1);
}

#[tokio::test(start_paused = true)]
async fn bunched_arrival_gives_the_same_pose_as_even_timing() {
    // The same frames, once as sent (100 Hz) and once as a busy host or
    // canplayer in a slow guest delivers them: in bursts of four, 20 µs apart.
    let config = Arc::new(rc_car());
    let out = drive_against_daemon(Arc::clone(&config), PathKind::FigureEight, None).await;
    let mut even = Pipeline::new(&config).unwrap();
    let mut bunched = Pipeline::new(&config).unwrap();
    let mut burst_start_us = 0;
    for (i, r) in out.recorded.iter().enumerate() {
        even.push(r.timestamp, &r.frame);
        if i % 4 == 0 {
            burst_start_us = r.timestamp.as_micros();
        }
        let t = Timestamp::from_micros(burst_start_us + (i % 4) as u64 * 20);
        bunched.push(t, &r.frame);
    }
    let (e, b) = (even.last_step().unwrap(), bunched.last_step().unwrap());
    println!(
        "even: {} | bunched: {} | end pose even ({:.6}, {:.6}, {:.6}) bunched ({:.6}, {:.6}, {:.6})",
        even.stats(),
        bunched.stats(),
        e.fused.x_m,
        e.fused.y_m,
        e.fused.heading_rad,
        b.fused.x_m,
        b.fused.y_m,
        b.fused.heading_rad
    );
    assert!(even.stats().steps > 5000);
    assert_eq!(bunched.stats().steps, even.stats().steps);
    assert_eq!(
        bunched
            .stats()
            .get(canodom_pipeline::stats::Reject::WheelFault),
        0
    );
    assert_eq!(
        even.stats()
            .get(canodom_pipeline::stats::Reject::WheelFault),
        0
    );
    for (a, b) in [
        (e.fused.x_m, b.fused.x_m),
        (e.fused.y_m, b.fused.y_m),
        (e.fused.heading_rad, b.fused.heading_rad),
        (e.odometry.x_m, b.odometry.x_m),
        (e.odometry.y_m, b.odometry.y_m),
    ] {
        assert!((a - b).abs() < 1e-9, "{a} vs {b}");
    }
}

/// The in-process bus, except that its receivers never see the link go down
/// (as a raw CAN socket whose pending `ENETDOWN` a pose send consumed):
/// only the sending half can tell the daemon.
struct DeafReceiver(InProcessBus);

struct DeafRx(canodom_can::bus::InProcessRx);

impl FrameSource for DeafRx {
    async fn recv(&mut self) -> Result<BusEvent, canodom_can::bus::BusError> {
        match self.0.recv().await {
            Err(canodom_can::bus::BusError::InterfaceDown { .. }) => std::future::pending().await,
            other => other,
        }
    }
    fn set_filters(
        &mut self,
        filters: &[canodom_can::bus::IdFilter],
    ) -> Result<(), canodom_can::bus::BusError> {
        self.0.set_filters(filters)
    }
}

impl canodom::server::Connector for DeafReceiver {
    type Rx = DeafRx;
    type Tx = canodom_can::bus::InProcessTx;
    fn connect(
        &self,
        filters: &[canodom_can::bus::IdFilter],
    ) -> Result<(Self::Rx, Self::Tx), canodom_can::bus::BusError> {
        let (rx, tx) = canodom::server::Connector::connect(&self.0, filters)?;
        Ok((DeafRx(rx), tx))
    }
    fn name(&self) -> String {
        "deaf".to_owned()
    }
}

#[tokio::test(start_paused = true)]
async fn link_down_seen_only_by_a_send_is_an_outage_and_resumes() {
    let config = Arc::new(rc_car());
    let bus = InProcessBus::with_epoch("vcan0", 8192, Timestamp::from_micros(LOG_EPOCH_US));
    let stop = CancellationToken::new();
    let daemon = tokio::spawn(run(
        Arc::clone(&config),
        DeafReceiver(bus.clone()),
        stop.clone().cancelled_owned(),
        Observers::default(),
    ));
    tokio::time::sleep(Duration::from_millis(10)).await;
    let b = bus.clone();
    let up_at = Arc::new(std::sync::Mutex::new(None));
    let up = Arc::clone(&up_at);
    tokio::spawn(async move {
        tokio::time::sleep(Duration::from_secs(5)).await;
        b.set_link(LinkState::Down);
        tokio::time::sleep(Duration::from_secs(2)).await;
        b.set_link(LinkState::Up);
        *up.lock().unwrap() = Some(tokio::time::Instant::now());
    });
    let (_vrx, vtx) = bus.open().unwrap();
    let sim = simulator(&config, PathKind::Circle, None, 5, false).unwrap();
    // The simulator's own sends fail while the link is down; it carries on.
    let _ = drive(&config, sim, &vtx, 100.0, CancellationToken::new(), |_| {}).await;
    tokio::time::sleep(Duration::from_millis(200)).await;
    stop.cancel();
    let s = daemon.await.unwrap().unwrap();
    println!(
        "deaf receiver: {}, connections {}, outages {}",
        s.stats, s.connections, s.outages
    );
    assert!(up_at.lock().unwrap().is_some());
    assert!(s.outages >= 1, "the outage was noticed and counted");
    assert!(s.connections >= 2, "reopened after the link came back");
    // It resumed: steps continue after the outage (the drive is ~60 s).
    assert!(s.last_step.unwrap().t_s > 20.0, "{:?}", s.last_step);
}

#[tokio::test(start_paused = true)]
async fn bus_off_reopens_the_interface() {
    let config = Arc::new(rc_car());
    let out = drive_against_daemon(
        Arc::clone(&config),
        PathKind::Circle,
        Some(Disturb::BusOff {
            at: Duration::from_secs(5),
        }),
    )
    .await;
    let s = out.summary;
    assert_eq!(s.connections, 2, "one reopen after the bus-off");
    assert!(s.stats.steps > 3000, "{}", s.stats);
}

#[tokio::test(start_paused = true)]
async fn reset_pose_moves_the_origin_at_standstill_and_is_refused_while_moving() {
    let config = Arc::new(crate::util::rc_car_with(
        "# arming_code = 0xA5",
        "arming_code = 0xA5",
    ));
    assert_eq!(config.calibration.arming_code, Some(0xA5));
    let base = config.output.base_id;
    let (moving_s, unarmed_s, still_s) = (5, 150, 151);
    let out = drive_against_daemon(
        Arc::clone(&config),
        PathKind::Circle,
        Some(Disturb::OdomCmd {
            base,
            commands: vec![
                (Duration::from_secs(moving_s), odom_cmd(2, 0xA5, 0)),
                (Duration::from_secs(unarmed_s), odom_cmd(2, 0x00, 1)),
                (Duration::from_secs(still_s), odom_cmd(2, 0xA5, 2)),
            ],
        }),
    )
    .await;
    let db = Database::parse(&dbc_for_base(base), "canodom.dbc").unwrap();
    let (x, y) = (
        db.signal("ODOM_POSITION.POS_X").unwrap(),
        db.signal("ODOM_POSITION.POS_Y").unwrap(),
    );
    let positions: Vec<(f64, f64, f64)> = out
        .pose_frames
        .iter()
        .filter(|r| r.frame.id() == OwnFrame::OdomPosition.id(base))
        .map(|r| {
            let t_s = (r.timestamp.as_micros() - LOG_EPOCH_US) as f64 * 1e-6;
            let d = r.frame.data();
            (t_s, x.decode(d).unwrap(), y.decode(d).unwrap())
        })
        .collect();
    let from_origin = |(_, x, y): &(f64, f64, f64)| x.hypot(*y);
    let between = |a: f64, b: f64| positions.iter().filter(move |p| p.0 > a && p.0 < b);
    // Moving at 5 s: refused, the pose goes on away from the origin.
    let after_moving: Vec<_> = between(moving_s as f64, moving_s as f64 + 1.0).collect();
    assert!(!after_moving.is_empty());
    assert!(
        after_moving.iter().all(|p| from_origin(p) > 0.3),
        "{after_moving:?}"
    );
    // Standing, but the wrong arming code: refused too.
    let before_reset: Vec<_> = between(unarmed_s as f64, still_s as f64).collect();
    assert!(!before_reset.is_empty());
    let end_of_drive = from_origin(before_reset[before_reset.len() - 1]);
    assert!(
        end_of_drive > 0.01,
        "the circle's end is {end_of_drive} m off"
    );
    // Standing and armed: the pose is the origin from then on.
    let after: Vec<_> = between(still_s as f64, f64::INFINITY).collect();
    assert!(after.len() > 5, "{after:?}");
    assert!(after.iter().all(|p| from_origin(p) < 1e-9), "{after:?}");
    assert_eq!(out.summary.state.pose(), canodom_fusion::Pose::default());
    println!(
        "RESET_POSE: refused while moving and unarmed; at standstill the pose moved {end_of_drive:.4} m to the origin"
    );
}

#[tokio::test(start_paused = true)]
async fn odom_cmd_publishes_on_demand() {
    let config = Arc::new(crate::util::rc_car_with(
        "pose_rate_hz = 50.0",
        "pose_rate_hz = 0.01",
    ));
    let base = config.output.base_id;
    let out = drive_against_daemon(
        Arc::clone(&config),
        PathKind::Circle,
        Some(Disturb::OdomCmd {
            base,
            commands: vec![(Duration::from_secs(5), odom_cmd(1, 0, 0))],
        }),
    )
    .await;
    let positions: Vec<_> = out
        .pose_frames
        .iter()
        .filter(|r| r.frame.id() == OwnFrame::OdomPosition.id(base))
        .collect();
    // The interval's first tick (before any frame, so nothing to send) and
    // one every 100 s: all a 0.01 Hz rate sends in this drive is the requested one.
    assert_eq!(positions.len(), 1, "{}", positions.len());
    let t = positions[0].timestamp.as_micros() - LOG_EPOCH_US;
    assert!((5_000_000..5_100_000).contains(&t), "published at {t} µs");
}
