//! The follower against the real daemon on the in-process bus (paused
//! clock): a whole session at 1 m/s, ten times the 1:10 car's default
//! speed, still meets the calibration bars.

use canodom::server::{InProcessDaemon, Observers};
use canodom_can::bus::InProcessBus;
use canodom_can::bus::{BusEvent, FrameSink, FrameSource};
use canodom_fusion::Wheel;
use canodom_pipeline::config::Config;
use canodom_protocol::calib_wire::{Ack, AckStatus, ParamSet, ParamsAssembler, Writeback};
use canodom_protocol::calib_wire::{CalibWire, Command, Counts, Progress, State, StatusPage};
use canodom_sim::follow::*;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

const ARMING: u8 = 0x42;

#[derive(Default)]
struct Heard {
    progress: Option<Progress>,
    counts: Option<Counts>,
    sets: Vec<ParamSet>,
}

/// Listens to the daemon and acknowledges every complete parameter set.
fn ecu_and_listener(bus: &InProcessBus, wire: CalibWire) -> Arc<Mutex<Heard>> {
    let heard = Arc::new(Mutex::new(Heard::default()));
    let (mut rx, tx) = bus.open().unwrap();
    let h = Arc::clone(&heard);
    tokio::spawn(async move {
        let mut assembler = ParamsAssembler::default();
        let mut counter = 0u8;
        while let Ok(ev) = rx.recv().await {
            let BusEvent::Frame(r) = ev else { continue };
            if r.frame.id() == wire.status_id() {
                match wire.decode_status(r.frame.data()) {
                    Ok((StatusPage::Progress(p), _)) => h.lock().unwrap().progress = Some(p),
                    Ok((StatusPage::Counts(c), _)) => h.lock().unwrap().counts = Some(c),
                    _ => {}
                }
            } else if r.frame.id() == wire.params_id()
                && let Ok((page, _)) = wire.decode_params(r.frame.data())
                && let Some(Ok(set)) = assembler.push(&wire, page)
            {
                assembler = ParamsAssembler::default();
                h.lock().unwrap().sets.push(set);
                let ack = Ack {
                    version: set.version,
                    status: AckStatus::Stored,
                    set_crc: wire.set_crc(&set).unwrap(),
                };
                let data = wire.encode_ack(ack, counter);
                counter = counter.wrapping_add(1);
                let _ = tx
                    .send(&CalibWire::frame(wire.ack_id(), &data).unwrap())
                    .await;
            }
        }
    });
    heard
}

async fn until(heard: &Mutex<Heard>, what: &str, limit_s: u64, ok: impl Fn(&Heard) -> bool) {
    for _ in 0..limit_s * 10 {
        if ok(&heard.lock().unwrap()) {
            return;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!(
        "no {what} within {limit_s} s; last {:?} {:?}",
        heard.lock().unwrap().progress,
        heard.lock().unwrap().counts
    );
}

#[tokio::test(start_paused = true)]
#[allow(clippy::too_many_lines)]
async fn a_session_followed_at_1_mps_commits_the_true_rear_parameters() {
    let dir = std::env::temp_dir().join(format!("canodom-follow-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/examples/rc_car.toml");
    let mut config = Config::load(std::path::Path::new(path)).unwrap();
    config.calibration.param_file = dir.join("params.toml");
    config.calibration.arming_code = Some(ARMING);
    let nominal = config.params;
    let (b_nom, dl_nom, dr_nom) = (
        nominal.rear_tread_m(),
        nominal.wheel_diameter_m(Wheel::RearLeft),
        nominal.wheel_diameter_m(Wheel::RearRight),
    );
    // True vehicle: tread 1/30 wider, right rear diameter +1.5 %.
    let (b_true, dl_true, dr_true) = (b_nom * 31.0 / 30.0, dl_nom, dr_nom * 1.015);
    let truth = nominal.with_rear(b_true, dl_true, dr_true).unwrap();
    // §4: the tread odometry with nominal diameters needs.
    let b_eff = 0.5 * (dl_nom / dl_true + dr_nom / dr_true) * b_true;
    let ratio_true = dr_true / dl_true;

    let config = Arc::new(config);
    let daemon = InProcessDaemon::spawn(Arc::clone(&config), 65536, Observers::default());
    let bus = daemon.bus.clone();
    // The vehicle stops by itself after the commit; this is its Ctrl-C.
    let stop = CancellationToken::new();
    let wire = CalibWire::new(config.output.base_id).unwrap();
    let heard = ecu_and_listener(&bus, CalibWire::new(config.output.base_id).unwrap());
    let (vehicle_rx, vehicle_tx) = bus.open().unwrap();
    let options = FollowOptions {
        true_params: truth,
        speed_mps: Some(1.0),
        track_radius_m: None,
        time_limit: Duration::from_secs(400),
        seed: 7,
    };
    let follower = {
        let config = Arc::clone(&config);
        let stop = stop.clone();
        tokio::spawn(async move {
            let mut out = Vec::new();
            let summary = follow(&config, &options, vehicle_rx, &vehicle_tx, stop, &mut out)
                .await
                .unwrap();
            (summary, String::from_utf8(out).unwrap())
        })
    };
    let (_, operator) = bus.open().unwrap();
    let mut counter = 0u8;
    let mut command = async |cmd: Command| {
        counter = (counter + 1) % 16;
        let data = wire.encode_command(cmd, ARMING, counter);
        let f = CalibWire::frame(config.calibration.command_id, &data).unwrap();
        operator.send(&f).await.unwrap();
    };
    until(&heard, "idle status", 5, |h| h.progress.is_some()).await;
    let started = Instant::now();
    command(Command::StartSession {
        track_radius_mm: 780,
        runs_per_direction: 5,
    })
    .await;
    until(&heard, "READY", 300, |h| {
        h.progress.is_some_and(|p| p.state == State::Ready)
    })
    .await;
    let session_s = started.elapsed().as_secs_f64();
    command(Command::Compute).await;
    until(&heard, "COMPUTED", 10, |h| {
        h.progress.is_some_and(|p| p.state == State::Computed)
    })
    .await;
    command(Command::Commit).await;
    until(&heard, "ACKED", 10, |h| {
        h.progress.is_some_and(|p| p.writeback == Writeback::Acked)
    })
    .await;
    let (summary, log) = follower.await.unwrap();
    println!("{log}");
    daemon.stop().await.unwrap();

    assert_eq!(summary.outcome, FollowOutcome::Committed(1), "{log}");
    assert_eq!(summary.send_failures, 0);
    let c = heard.lock().unwrap().counts.unwrap();
    assert_eq!((c.ccw_accepted, c.cw_accepted), (5, 5), "{c:?}");
    // Every lap the status asked for was driven once: none rejected.
    assert_eq!(summary.laps.len(), 10, "{log}");
    assert!(
        summary
            .laps
            .iter()
            .all(|l| (l.distance_m - 8.0).abs() < 0.1)
    );
    let set = heard.lock().unwrap().sets[0];
    assert_eq!(set.version, 1);
    let tread_err = set.rear_tread_m / b_eff - 1.0;
    let ratio_err = set.diameter_ratio / ratio_true - 1.0;
    println!(
        "{} m/s: session {session_s:.0} s (bus time), tread {:.5} m (effective {b_eff:.5}, error {:+.3} %), \
         ratio {:.5} (true {ratio_true:.5}, error {:+.4} %)",
        options.speed_mps.unwrap_or_default(),
        set.rear_tread_m,
        100.0 * tread_err,
        set.diameter_ratio,
        100.0 * ratio_err
    );
    assert!(tread_err.abs() < 0.005, "tread error {tread_err}");
    assert!(ratio_err.abs() < 0.001, "ratio error {ratio_err}");
    let _ = std::fs::remove_dir_all(&dir);
}
