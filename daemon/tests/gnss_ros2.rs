//! `[gnss] source = "ros2"` (#43 item 2, #46): NavSatFix messages published
//! by a DDS participant of the test's own (loopback, domain 155, unicast
//! discovery to 127.0.0.1 only) reach the daemon's calibration, judged by
//! the same rule as gpsd's reports: a fix whose covariance states a 95 %
//! error beyond `max_error_m` is refused and counted, one without a
//! position is left out by the subscription; the CAN side loses nothing.

use canodom::server::{InProcessDaemon, Observers};
use canodom_can::bus::InProcessBus;
use canodom_export::cdr::RosTime;
use canodom_pipeline::config::Config;
use canodom_ros2::config::DiscoveryRange;
use canodom_ros2::msg::{self, NavSatFix};
use canodom_ros2::node::{RawCdr, RawCdrAdapter, participant};
use canodom_sim::vehicle::PathKind;
use rustdds::policy::{Durability, History, Reliability};
use rustdds::{QosPolicyBuilder, TopicKind};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;
use tokio_util::sync::CancellationToken;

const DOMAIN: u16 = 155;

/// Fix `k`: σ 1.5 m, except every 5th, σ 60 m (a 95 % radius of 147 m).
fn fix(k: u32) -> NavSatFix {
    let var = if k % 5 == 4 { 3600.0 } else { 2.25 };
    NavSatFix {
        stamp: RosTime {
            sec: 1_700_000_000 + k as i32,
            nanosec: 0,
        },
        frame_id: "gnss".to_owned(),
        status: 0,
        service: 1,
        latitude: 48.1 + f64::from(k) * 1e-6,
        longitude: 11.5,
        altitude: 520.0,
        position_covariance: [var, 0.0, 0.0, 0.0, var, 0.0, 0.0, 0.0, 9.0],
        position_covariance_type: 2,
    }
}

/// A GNSS driver's publisher at 10 Hz (sensor-data QoS, a participant of
/// its own) until `publishing` is cleared; how many it wrote.
fn publish_fixes(publishing: &AtomicBool) -> u32 {
    let participant = participant(DOMAIN, DiscoveryRange::Localhost).unwrap();
    let qos = QosPolicyBuilder::new()
        .reliability(Reliability::BestEffort)
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 5 })
        .build();
    let topic = participant
        .create_topic(
            "rt/fix".to_owned(),
            msg::NAV_SAT_FIX_TYPE.to_owned(),
            &qos,
            TopicKind::NoKey,
        )
        .unwrap();
    let writer = participant
        .create_publisher(&qos)
        .unwrap()
        .create_datawriter_no_key::<RawCdr, RawCdrAdapter>(&topic, Some(qos))
        .unwrap();
    let mut k = 0;
    while publishing.load(Ordering::Relaxed) {
        let mut buf = Vec::new();
        msg::encode_nav_sat_fix(&fix(k), &mut buf);
        writer.write(RawCdr(buf), None).unwrap();
        k += 1;
        std::thread::sleep(Duration::from_millis(100));
    }
    k
}

#[tokio::test]
async fn navsatfix_fixes_reach_the_calibration_and_bad_ones_are_refused() {
    let path = crate::util::rc_car_toml();
    let text = std::fs::read_to_string(&path).unwrap();
    let text = format!(
        "{text}\n[ros2]\ndomain_id = {DOMAIN}\ndiscovery = \"localhost\"\n\
         [gnss]\nsource = \"ros2\"\ntopic = \"/fix\"\n"
    );
    let config = Arc::new(Config::from_toml(&text, &path).unwrap());
    let bus = InProcessBus::new(&config.interface, 8192);
    let daemon = InProcessDaemon::spawn_on(Arc::clone(&config), bus, Observers::default());
    tokio::time::sleep(Duration::from_millis(10)).await;
    let (_rx, tx) = daemon.bus.open().unwrap();

    let publishing = Arc::new(AtomicBool::new(true));
    let publisher = {
        let publishing = Arc::clone(&publishing);
        std::thread::spawn(move || publish_fixes(&publishing))
    };
    let stop = CancellationToken::new();
    let timer = {
        let stop = stop.clone();
        let publishing = Arc::clone(&publishing);
        tokio::spawn(async move {
            // Publishing stops a second before the drive, so no fix is in flight at the end.
            tokio::time::sleep(Duration::from_secs(7)).await;
            publishing.store(false, Ordering::Relaxed);
            tokio::time::sleep(Duration::from_secs(1)).await;
            stop.cancel();
        })
    };
    let sim = canodom_sim::drive::simulator(&config, PathKind::Random, None, 2, false).unwrap();
    let (sent, failed) = canodom_sim::drive::drive(&config, sim, &tx, 100.0, stop, |_| {})
        .await
        .unwrap();
    timer.await.unwrap();
    let published = tokio::task::spawn_blocking(move || publisher.join().unwrap())
        .await
        .unwrap();
    let summary = daemon.stop().await.unwrap();
    let gnss = summary.gnss.expect("the ROS 2 source started");
    let s = &gnss.status;
    eprintln!(
        "published {published}; gnss {}: accepted {}, refused {:?}, forwarded {}, dropped {}, \
         before the first frame {}; CAN frames sent {sent}, counted {}",
        gnss.source,
        s.accepted,
        s.refused,
        gnss.forwarded,
        gnss.dropped,
        gnss.before_bus,
        summary.stats.frames
    );
    assert_eq!(failed, 0);
    assert_eq!(
        summary.stats.frames, sent,
        "every CAN frame sent was counted"
    );
    assert_eq!(summary.frames_lost, 0);
    // Discovery takes the first second or two (best effort): most of the rest arrive.
    assert!(
        gnss.forwarded >= 20,
        "{} of {published} fixes",
        gnss.forwarded
    );
    assert!(s.refused[2] >= 5, "every 5th fix states 147 m: refused");
    assert_eq!((s.refused[0], s.refused[1]), (0, 0));
    assert!(
        s.accepted + s.refused[2] <= u64::from(published),
        "more judged than published"
    );
    assert_eq!(gnss.received, s.accepted);
    assert_eq!(
        gnss.forwarded, s.accepted,
        "every accepted fix reached the calibration"
    );
    assert_eq!((gnss.dropped, gnss.before_bus), (0, 0));
    // The last fix's 95 % radius: 2.448 σ, of σ 1.5 m or 60 m.
    let k95 = canodom_gnss::accept::HORIZONTAL_95_TO_SIGMA;
    let last = s.last_error_m.expect("an error estimate");
    assert!(
        [1.5 * k95, 60.0 * k95]
            .iter()
            .any(|e| (e - last).abs() < 1e-9),
        "{last}"
    );
}
