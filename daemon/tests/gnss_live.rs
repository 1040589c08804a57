//! `[gnss] source = "gpsd"` live (#46): the daemon's own run loop on the
//! in-process bus (there is no SocketCAN here; `canodom run` needs one)
//! with a simulated vehicle sending in real time, and a real gpsd under
//! gpsfake that `daemon/tests/gpsd_daemon.sh` starts, kills and restarts
//! in the middle of the drive. The test checks what the daemon alone can
//! know (every CAN frame sent was counted, none lost; every fix the source
//! accepted reached the calibration; the connections it was told to
//! expect); the script checks the fixes against the NMEA file and an
//! independent gpsd client, and the log lines of the loss and reconnect.

use canodom::server::{InProcessDaemon, Observers};
use canodom_can::bus::InProcessBus;
use canodom_pipeline::config::Config;
use canodom_sim::vehicle::PathKind;
use std::sync::Arc;
use std::time::Duration;
use tokio_util::sync::CancellationToken;

fn env(name: &str) -> Option<String> {
    std::env::var(name).ok().filter(|v| !v.is_empty())
}

#[tokio::test]
#[ignore = "needs a gpsd under gpsfake: run by daemon/tests/gpsd_daemon.sh"]
async fn gpsd_fixes_reach_the_calibration_and_no_can_frame_is_lost() {
    let address = env("CANODOM_TEST_GPSD").expect("CANODOM_TEST_GPSD=HOST:PORT of a gpsd");
    let seconds: f64 = env("CANODOM_TEST_SECONDS").map_or(20.0, |s| s.parse().unwrap());
    let connections: u64 = env("CANODOM_TEST_CONNECTIONS").map_or(1, |s| s.parse().unwrap());
    // The daemon's log on stderr, with each forwarded fix (debug): the script reads it.
    let _ = tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::new(
            "info,canodom::gnss_task=debug",
        ))
        .with_writer(std::io::stderr)
        .try_init();
    let path = crate::util::rc_car_toml();
    let text = std::fs::read_to_string(&path).unwrap();
    let text = format!("{text}\n[gnss]\nsource = \"gpsd\"\naddress = \"{address}\"\n");
    let config = Arc::new(Config::from_toml(&text, &path).unwrap());
    // A bus on the wall clock, as SocketCAN stamps with the realtime clock.
    let bus = InProcessBus::new(&config.interface, 8192);
    let daemon = InProcessDaemon::spawn_on(Arc::clone(&config), bus, Observers::default());
    tokio::time::sleep(Duration::from_millis(10)).await;
    let (_rx, tx) = daemon.bus.open().unwrap();
    let sim = canodom_sim::drive::simulator_at(&config, PathKind::Random, None, 4, false, 20, None)
        .unwrap();
    let stop = CancellationToken::new();
    let timer = {
        let stop = stop.clone();
        tokio::spawn(async move {
            tokio::time::sleep(Duration::from_secs_f64(seconds)).await;
            stop.cancel();
        })
    };
    let started = tokio::time::Instant::now();
    let (sent, failed) = canodom_sim::drive::drive(&config, sim, &tx, 100.0, stop, |_| {})
        .await
        .unwrap();
    let drove_s = started.elapsed().as_secs_f64();
    timer.abort();
    let summary = daemon.stop().await.unwrap();
    let gnss = summary.gnss.clone().expect("the gpsd source started");
    let s = &gnss.status;
    eprintln!(
        "daemon summary: drove {drove_s:.1} s, CAN frames sent {sent} (failed {failed}), counted {}, \
         lost {}; gnss {}: connections {}, accepted {}, refused {:?} (no_fix, no_position, \
         error_too_large), received {}, forwarded {}, dropped {}, before the first frame {}, \
         reconnect attempts {}, last error estimate {:?} m",
        summary.stats.frames,
        summary.frames_lost,
        gnss.source,
        gnss.connections,
        s.accepted,
        s.refused,
        gnss.received,
        gnss.forwarded,
        gnss.dropped,
        gnss.before_bus,
        s.reconnects,
        s.last_error_m,
    );
    assert!(drove_s > seconds - 1.0, "the simulated drive ended early");
    assert_eq!(failed, 0);
    assert_eq!(
        summary.stats.frames, sent,
        "every CAN frame sent was counted"
    );
    assert_eq!(summary.frames_lost, 0);
    assert_eq!(gnss.connections, connections, "connections to gpsd");
    assert!(gnss.forwarded > 0, "no fix reached the calibration");
    // The client's final status counts every fix it accepted; none was lost
    // in its queue, in the daemon, or for want of a bus time.
    assert_eq!(s.dropped, 0, "fixes dropped in the client's queue");
    assert_eq!(
        gnss.received, s.accepted,
        "every accepted fix was delivered"
    );
    assert_eq!(
        gnss.forwarded, s.accepted,
        "every accepted fix reached the calibration"
    );
    assert_eq!((gnss.dropped, gnss.before_bus), (0, 0));
}
