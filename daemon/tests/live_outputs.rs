//! `run --record` and `run --foxglove` on the in-process bus (#25): the
//! recording holds every pose the daemon published, a WebSocket client
//! receives them live, and a client that stops reading does not slow the
//! pipeline.

use crate::util::rc_car;
use canodom::server::{InProcessDaemon, Observers};
use canodom_export::live::{LiveOptions, LiveOutputs, LiveReport};
use canodom_export::recorder::RecorderOptions;
use canodom_pipeline::config::Config;
use canodom_sim::drive::{drive, simulator};
use canodom_sim::vehicle::PathKind;
use std::net::TcpStream;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio_util::sync::CancellationToken;
use tungstenite::Message;

type Client = tungstenite::WebSocket<tungstenite::stream::MaybeTlsStream<TcpStream>>;

/// Connects to the view and subscribes to every channel; returns the
/// client and the channel ids by topic.
fn subscribe(port: u16) -> (Client, Vec<(u64, String)>) {
    let mut request = tungstenite::client::IntoClientRequest::into_client_request(format!(
        "ws://127.0.0.1:{port}"
    ))
    .unwrap();
    request
        .headers_mut()
        .insert("Sec-WebSocket-Protocol", "foxglove.sdk.v1".parse().unwrap());
    let (mut ws, _) = tungstenite::connect(request).unwrap();
    if let tungstenite::stream::MaybeTlsStream::Plain(tcp) = ws.get_mut() {
        tcp.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    }
    let mut channels = Vec::new();
    while channels.len() < 9 {
        if let Message::Text(text) = ws.read().unwrap() {
            let v: serde_json::Value = serde_json::from_str(&text).unwrap();
            if v["op"] == "advertise" {
                for c in v["channels"].as_array().unwrap() {
                    channels.push((
                        c["id"].as_u64().unwrap(),
                        c["topic"].as_str().unwrap().to_owned(),
                    ));
                }
            }
        }
    }
    let subscriptions: Vec<_> = channels
        .iter()
        .map(|(id, _)| serde_json::json!({"id": id, "channelId": id}))
        .collect();
    let subscribe = serde_json::json!({"op": "subscribe", "subscriptions": subscriptions});
    ws.send(Message::Text(subscribe.to_string().into()))
        .unwrap();
    (ws, channels)
}

/// Drives the simulator's circle against an in-process daemon with `tap`
/// until `stop`; returns the wall time the drive took (in paused time, as
/// fast as the machine goes), the poses published and the frames lost.
async fn drive_with(
    config: &Arc<Config>,
    tap: canodom_export::live::Tap,
    stop: CancellationToken,
) -> (Duration, u64, u64) {
    let observers = Observers {
        tap: Some(tap),
        ..Observers::default()
    };
    let daemon = InProcessDaemon::spawn(Arc::clone(config), 8192, observers);
    tokio::time::sleep(Duration::from_millis(10)).await;
    let (_vrx, vtx) = daemon.bus.open().unwrap();
    let sim = simulator(config, PathKind::Circle, None, 5, false).unwrap();
    let started = Instant::now();
    drive(config, sim, &vtx, 100.0, stop, |_| {}).await.unwrap();
    let took = started.elapsed();
    tokio::time::sleep(Duration::from_millis(200)).await;
    let summary = daemon.stop().await.unwrap();
    (took, summary.poses_published, summary.frames_lost)
}

fn config() -> Arc<Config> {
    let mut config = rc_car();
    // A pose at every step: the most messages the outputs can get.
    config.output.publish_on_update = true;
    Arc::new(config)
}

fn temp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("canodom-live-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[tokio::test]
async fn the_recording_and_a_viewer_get_every_published_pose() {
    let config = config();
    let dir = temp("record");
    let (tap, outputs) = LiveOutputs::start(LiveOptions {
        record: Some(RecorderOptions::new(dir.join("run.mcap"))),
        foxglove: Some("127.0.0.1:0".parse().unwrap()),
        k_rear_m: config.ekf.k_rear_m,
        queue: 1 << 16,
        forward: None,
    })
    .unwrap();
    let port = outputs.port().unwrap();
    let (mut ws, channels) = subscribe(port);
    let pose_channel = channels
        .iter()
        .find(|(_, t)| t == "/canodom/pose")
        .unwrap()
        .0;
    // The client reads on a thread of its own, in real time.
    let reader = std::thread::spawn(move || {
        let mut poses = 0u64;
        if let tungstenite::stream::MaybeTlsStream::Plain(tcp) = ws.get_mut() {
            tcp.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
        }
        while let Ok(m) = ws.read() {
            if let Message::Binary(b) = m
                && b[0] == 1
                && u64::from(u32::from_le_bytes(b[1..5].try_into().unwrap())) == pose_channel
            {
                poses += 1;
            }
        }
        poses
    });
    // Let the subscription settle, then drive 3 s in real time.
    tokio::time::sleep(Duration::from_millis(300)).await;
    let stop = CancellationToken::new();
    let timer = stop.clone();
    tokio::spawn(async move {
        tokio::time::sleep(Duration::from_secs(3)).await;
        timer.cancel();
    });
    let (_, published, _) = drive_with(&config, tap, stop).await;
    let report: LiveReport = outputs.join().unwrap();
    let live_poses = reader.join().unwrap();
    println!(
        "published {published}, recorded {}, dropped {}, live {live_poses}",
        report.poses, report.dropped
    );
    assert!(published > 300, "{published} poses");
    assert_eq!(report.dropped, 0);
    // Every published pose reached the outputs (one more may come from the
    // last tick after the stop was asked for).
    assert!(
        report.poses.abs_diff(published) <= 1,
        "{} vs {published}",
        report.poses
    );
    // In real time the client keeps up; the server's stop at the end may
    // cut the last few still queued for it.
    assert!(
        live_poses * 10 >= report.poses * 9,
        "{live_poses} of {}",
        report.poses
    );
    assert_eq!(report.files, vec![dir.join("run.mcap")]);
    let bytes = std::fs::read(&report.files[0]).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let stats = summary.stats.unwrap();
    assert_eq!(stats.channel_message_counts.len(), 9);
    assert!(
        stats
            .channel_message_counts
            .values()
            .all(|&n| n == report.poses)
    );
}

#[tokio::test(start_paused = true)]
async fn a_stalled_viewer_does_not_slow_the_pipeline() {
    let config = config();
    let options = LiveOptions {
        record: None,
        foxglove: Some("127.0.0.1:0".parse().unwrap()),
        k_rear_m: config.ekf.k_rear_m,
        queue: 256,
        forward: None,
    };
    // Alternating runs without and with a client that subscribes to every
    // channel and then never reads; the best of each (the host is shared).
    let (mut free, mut stalled) = (Duration::MAX, Duration::MAX);
    let mut stalled_report = LiveReport::default();
    for _ in 0..5 {
        let (tap, outputs) = LiveOutputs::start(options.clone()).unwrap();
        let (took, free_poses, lost) = drive_with(&config, tap, CancellationToken::new()).await;
        free = free.min(took);
        outputs.join().unwrap();
        assert_eq!(lost, 0);

        let (tap, outputs) = LiveOutputs::start(options.clone()).unwrap();
        let (ws, _) = subscribe(outputs.port().unwrap());
        let (took, published, lost) = drive_with(&config, tap, CancellationToken::new()).await;
        stalled = stalled.min(took);
        stalled_report = outputs.join().unwrap();
        // The pipeline lost no frame and published every pose it publishes
        // without the client: nothing waited for the viewer.
        assert_eq!((lost, published), (0, free_poses));
        assert!(stalled_report.poses + stalled_report.dropped + 1 >= published);
        drop(ws);
    }
    println!(
        "drive with the view: {free:?} without a client, {stalled:?} with a stalled one \
         ({} poses to the view, {} dropped before it)",
        stalled_report.poses, stalled_report.dropped
    );
    let ratio = stalled.as_secs_f64() / free.as_secs_f64();
    // Best of five each; the bound is the noise of a shared 2-core host
    // running the other tests beside this one.
    assert!(
        ratio < 1.5,
        "the stalled client slowed the pipeline {ratio:.2}x"
    );
}

#[tokio::test]
async fn ros2_subscribers_get_every_published_pose_as_odometry() {
    // `[ros2] enabled` (#43): the node hangs off the live outputs. A RustDDS
    // reader of the test's own on loopback (domain 153) counts the samples.
    use canodom_ros2::node::{Node, RawCdr, RawCdrAdapter};
    use rustdds::policy::{Durability, History, Reliability};
    let config = config();
    let ros2 = canodom_ros2::config::Ros2Config {
        enabled: true,
        domain_id: Some(153),
        discovery: Some(canodom_ros2::config::DiscoveryRange::Localhost),
        queue: 1 << 16,
        ..Default::default()
    }
    .resolve_with(|_| None)
    .unwrap();
    let node = Arc::new(Node::start(&ros2, config.ekf.k_rear_m).unwrap());
    let participant =
        canodom_ros2::node::participant(153, canodom_ros2::config::DiscoveryRange::Localhost)
            .unwrap();
    let qos = rustdds::QosPolicyBuilder::new()
        .reliability(Reliability::Reliable {
            max_blocking_time: rustdds::Duration::from_millis(100),
        })
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 1 << 16 })
        .build();
    let topic = participant
        .create_topic(
            "rt/odom".into(),
            canodom_ros2::msg::ODOMETRY_TYPE.into(),
            &qos,
            rustdds::TopicKind::NoKey,
        )
        .unwrap();
    let mut reader = participant
        .create_subscriber(&qos)
        .unwrap()
        .create_datareader_no_key::<RawCdr, RawCdrAdapter>(&topic, Some(qos))
        .unwrap();
    assert!(node.wait_for_subscribers(1, Duration::from_secs(30)));
    let forward_node = Arc::clone(&node);
    let (tap, outputs) = LiveOutputs::start(LiveOptions {
        record: None,
        foxglove: None,
        k_rear_m: config.ekf.k_rear_m,
        queue: 1 << 16,
        forward: Some(Arc::new(move |s, p| {
            forward_node.publish_pose(s, p);
        })),
    })
    .unwrap();
    let (_, published, lost) = drive_with(&config, tap, CancellationToken::new()).await;
    let report = outputs.join().unwrap();
    assert_eq!(lost, 0);
    assert_eq!(report.poses, published);
    // Read while the node is up: RustDDS forgets a gone writer's samples.
    let mut received = 0u64;
    let until = Instant::now() + Duration::from_secs(20);
    while received < published && Instant::now() < until {
        match reader.take_next_sample() {
            Ok(Some(_)) => received += 1,
            Ok(None) => std::thread::sleep(Duration::from_millis(10)),
            Err(e) => panic!("reading: {e:?}"),
        }
    }
    let node = Arc::into_inner(node).expect("the outputs dropped their hook");
    let stats = node.finish();
    assert_eq!((stats.odometry, stats.dropped), (published, 0));
    assert!(published > 100, "{published} poses");
    assert_eq!(received, published);
}
