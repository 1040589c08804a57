//! The daemon's SocketCAN transport on a real `vcan0`: kernel receive filters,
//! kernel receive timestamps, interoperation with can-utils in both
//! directions, and the typed errors of an interface that goes down or
//! disappears (the daemon's retry logic depends on them).
#![cfg(feature = "vcan")]

use canodom_can::bus::{BusError, BusEvent, FrameSink, FrameSource, IdFilter, open_socketcan};
use canodom_can::candump::parse_line;
use canodom_can::frame::{CanFrame, FrameId};
use canodom_vcan_tests::{DEFAULT_WAIT, ip, metric, run};
use std::process::{Command, Stdio};
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use tokio::time::timeout;

fn now_micros() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .expect("clock after 1970")
        .as_micros() as u64
}

async fn next_frame(rx: &mut impl FrameSource) -> CanFrame {
    loop {
        let event = timeout(DEFAULT_WAIT, rx.recv())
            .await
            .expect("a frame within the wait limit")
            .expect("receive succeeds");
        match event {
            BusEvent::Frame(received) => return received.frame,
            BusEvent::Lost { count } => panic!("{count} frames lost on an idle vcan"),
            BusEvent::Error { .. } => {}
        }
    }
}

#[tokio::test]
async fn kernel_filters_pass_exactly_the_configured_ids_with_kernel_timestamps() {
    let wanted = [
        FrameId::standard(0x100).unwrap(),
        FrameId::extended(0x1234_5678).unwrap(),
    ];
    let filters: Vec<IdFilter> = wanted.iter().map(|id| IdFilter::exact(*id)).collect();
    let (mut rx, _) = open_socketcan("vcan0", &filters).expect("open vcan0 for receiving");
    let (_, tx) = open_socketcan("vcan0", &[]).expect("open vcan0 for sending");

    // 1,500 frames, a third of them on an id nobody asked for; the same
    // numeric id in the other format must be filtered out as well. Sending
    // and receiving run concurrently, as in the daemon: a receiver that
    // waited for all 1,500 would overflow its socket buffer and lose frames.
    let unwanted = FrameId::extended(0x100).unwrap();
    let frames: Vec<(CanFrame, bool)> = (0..1500u32)
        .map(|i| {
            let id = [wanted[0], wanted[1], unwanted][(i % 3) as usize];
            (
                CanFrame::new_data(id, &i.to_le_bytes()).unwrap(),
                i % 3 != 2,
            )
        })
        .collect();
    let expected: Vec<CanFrame> = frames.iter().filter(|(_, w)| *w).map(|(f, _)| *f).collect();
    let before_us = now_micros();
    let send_all = async {
        for (n, (frame, _)) in frames.iter().enumerate() {
            tx.send(frame).await.expect("send on vcan0");
            if n % 20 == 19 {
                tokio::task::yield_now().await;
            }
        }
    };
    let receive_all = async {
        let mut last_us = 0;
        for (n, want) in expected.iter().enumerate() {
            let event = timeout(DEFAULT_WAIT, rx.recv())
                .await
                .unwrap_or_else(|_| panic!("frame {n} of {} not received in time", expected.len()))
                .expect("receive succeeds");
            let BusEvent::Frame(received) = event else {
                panic!("unexpected event {event:?} at frame {n}");
            };
            assert_eq!(&received.frame, want, "frame {n} differs");
            let t = received.timestamp.as_micros();
            assert!(
                t >= last_us,
                "kernel timestamps went backwards at frame {n}"
            );
            assert!(
                t + 1_000 >= before_us && t <= now_micros() + 1_000,
                "timestamp {t} not within the send window"
            );
            last_us = t;
        }
    };
    tokio::join!(send_all, receive_all);
    // Nothing else may arrive: the unwanted third stayed in the kernel.
    let extra = timeout(Duration::from_millis(300), rx.recv()).await;
    assert!(extra.is_err(), "an unfiltered frame got through: {extra:?}");
    metric("filtered_frames_received", expected.len());
}

#[tokio::test]
async fn frames_round_trip_with_can_utils_in_both_directions() {
    // can-utils → canodom: cansend's frames arrive intact.
    let (mut rx, tx) = open_socketcan("vcan0", &[IdFilter::accept_all()]).expect("open vcan0");
    run("cansend", &["vcan0", "123#DEADBEEF"]).expect("cansend standard");
    run("cansend", &["vcan0", "1ABCDEF0#0102030405060708"]).expect("cansend extended");
    run("cansend", &["vcan0", "7FF#"]).expect("cansend empty");
    let expected = [
        CanFrame::new_data(FrameId::standard(0x123).unwrap(), &[0xDE, 0xAD, 0xBE, 0xEF]).unwrap(),
        CanFrame::new_data(
            FrameId::extended(0x1ABC_DEF0).unwrap(),
            &[1, 2, 3, 4, 5, 6, 7, 8],
        )
        .unwrap(),
        CanFrame::new_data(FrameId::standard(0x7FF).unwrap(), &[]).unwrap(),
    ];
    for want in &expected {
        assert_eq!(&next_frame(&mut rx).await, want);
    }

    // canodom → can-utils: candump -L logs exactly what we sent, in the
    // format our own log parser reads back.
    let candump = Command::new("candump")
        .args(["-L", "-n", "3", "-T", "5000", "vcan0"])
        .stdout(Stdio::piped())
        .spawn()
        .expect("start candump");
    tokio::time::sleep(Duration::from_millis(300)).await;
    for frame in &expected {
        tx.send(frame).await.expect("send");
    }
    let output = candump.wait_with_output().expect("candump finishes");
    let text = String::from_utf8(output.stdout).expect("candump prints text");
    let logged: Vec<CanFrame> = text
        .lines()
        .map(|line| {
            parse_line(line.as_bytes())
                .expect("candump line parses")
                .frame
        })
        .collect();
    assert_eq!(logged, expected, "candump saw:\n{text}");
}

#[tokio::test]
async fn interface_down_and_deleted_are_typed_errors_and_reopening_recovers() {
    let (mut rx, _) = open_socketcan("vcan0", &[IdFilter::accept_all()]).expect("open vcan0");
    ip(&["link", "set", "vcan0", "down"]).unwrap();
    let err = timeout(DEFAULT_WAIT, rx.recv())
        .await
        .expect("the socket reports the outage promptly")
        .expect_err("a downed interface is an error");
    assert!(
        matches!(err, BusError::InterfaceDown { .. }),
        "want InterfaceDown, got {err:?}"
    );
    assert!(err.is_transient());

    ip(&["link", "set", "vcan0", "up"]).unwrap();
    let (mut rx, tx) = open_socketcan("vcan0", &[IdFilter::accept_all()]).expect("reopen");
    let frame = CanFrame::new_data(FrameId::standard(0x42).unwrap(), &[7]).unwrap();
    let (_, sender) = open_socketcan("vcan0", &[]).expect("open sender");
    sender.send(&frame).await.unwrap();
    assert_eq!(next_frame(&mut rx).await, frame);
    drop(tx);

    ip(&["link", "del", "vcan0"]).unwrap();
    let err = timeout(DEFAULT_WAIT, rx.recv())
        .await
        .expect("the socket reports the removal promptly")
        .expect_err("a deleted interface is an error");
    assert!(
        matches!(
            err,
            BusError::NoSuchInterface { .. } | BusError::InterfaceDown { .. }
        ),
        "want NoSuchInterface or InterfaceDown, got {err:?}"
    );
    let reopened = open_socketcan("vcan0", &[]);
    assert!(
        matches!(reopened, Err(BusError::NoSuchInterface { .. })),
        "opening a missing interface: {reopened:?}"
    );
    ip(&["link", "add", "dev", "vcan0", "type", "vcan"]).unwrap();
    ip(&["link", "set", "vcan0", "up"]).unwrap();
    let (mut rx, _) = open_socketcan("vcan0", &[IdFilter::accept_all()]).expect("reopen");
    sender_after_recreate(&frame).await;
    assert_eq!(next_frame(&mut rx).await, frame);
}

async fn sender_after_recreate(frame: &CanFrame) {
    let (_, sender) = open_socketcan("vcan0", &[]).expect("open sender on the new vcan0");
    sender.send(frame).await.expect("send on the new vcan0");
}

#[tokio::test]
async fn frames_the_kernel_drops_on_a_full_socket_are_reported_with_their_count() {
    // A receiver that reads nothing while 20,000 frames are sent overflows
    // its socket's receive queue: the kernel drops the excess and counts it
    // (sk_drops). Every frame must then be either received or reported lost.
    let (mut rx, _) = open_socketcan("vcan0", &[IdFilter::accept_all()]).expect("open vcan0");
    let (_, tx) = open_socketcan("vcan0", &[]).expect("open vcan0 for sending");
    let sent = 20_000u32;
    for i in 0..sent {
        let f = CanFrame::new_data(FrameId::standard(0x321).unwrap(), &i.to_le_bytes()).unwrap();
        tx.send(&f).await.expect("send");
    }
    let drops = rx.kernel_drops().expect("SO_MEMINFO on this kernel");
    assert!(
        drops > 0,
        "20,000 unread frames did not overflow the socket"
    );
    let (mut received, mut lost) = (0u64, 0u64);
    while received + lost < u64::from(sent) {
        match timeout(DEFAULT_WAIT, rx.recv()).await {
            Ok(Ok(BusEvent::Frame(_))) => received += 1,
            Ok(Ok(BusEvent::Lost { count })) => lost += count,
            Ok(Ok(BusEvent::Error { .. })) => {}
            Ok(Err(e)) => panic!("receive failed: {e}"),
            Err(elapsed) => {
                panic!("stalled at {received} received + {lost} lost of {sent}: {elapsed}")
            }
        }
    }
    metric("socket_overflow_received", received);
    metric("socket_overflow_lost_reported", lost);
    assert_eq!(lost, drops, "Lost events add up to the kernel's count");
    assert_eq!(received + lost, u64::from(sent));
}
