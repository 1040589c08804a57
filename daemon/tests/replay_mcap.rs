//! `replay --out x.mcap` (issue #25), read back with the `mcap` crate: one
//! message per step on every channel, and every frame of the log in the
//! raw-frame channel exactly once and in order, also across batches
//! without a step (whose frames wait for the next batch's first step), with
//! either thread encoding a batch.

use crate::util::{frames_of, rc_car, simulated_log};
use canodom::cmd::replay::{McapOut, ReplayOptions, replay_log};
use canodom_export::mcap_file::{Compression, McapOptions};
use canodom_sim::vehicle::PathKind;
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// A log of frames `(time µs, id, data)` as the raw-frame channel carries them.
type Frames = Vec<(u64, u32, Vec<u8>)>;

/// The frames of one `canodom_msgs/msg/CanFrames` message (XCDR1, little-endian).
fn can_frames(cdr: &[u8]) -> Frames {
    let payload = &cdr[4..];
    let mut at = 0usize;
    let u32_at = |at: &mut usize| {
        *at = at.next_multiple_of(4);
        let v = u32::from_le_bytes(payload[*at..*at + 4].try_into().unwrap());
        *at += 4;
        v
    };
    let count = u32_at(&mut at);
    (0..count)
        .map(|_| {
            let sec = u64::from(u32_at(&mut at));
            let nsec = u64::from(u32_at(&mut at));
            let id = u32_at(&mut at);
            at += 1; // extended
            let len = u32_at(&mut at) as usize;
            let data = payload[at..at + len].to_vec();
            at += len;
            ((sec * 1_000_000_000 + nsec) / 1000, id, data)
        })
        .collect()
}

/// `log` with `n` frames of an id the vehicle does not use inserted at its
/// middle line, at that line's time.
fn with_unused_frames(log: &[u8], n: usize) -> Vec<u8> {
    let text = std::str::from_utf8(log).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let middle = lines.len() / 2;
    let stamp = lines[middle].split(' ').next().unwrap();
    let mut out = String::new();
    for line in &lines[..middle] {
        writeln!(out, "{line}").unwrap();
    }
    for k in 0..n {
        writeln!(out, "{stamp} can0 7EE#{:04X}", k % 0x1_0000).unwrap();
    }
    for line in &lines[middle..] {
        writeln!(out, "{line}").unwrap();
    }
    out.into_bytes()
}

#[test]
fn every_frame_reaches_the_raw_channel_once_and_in_order() {
    let config = rc_car();
    let (log, _) = simulated_log(&config, PathKind::Circle, 11);
    // Over two batches (4,096 records each) without a step.
    let log = with_unused_frames(&log, 10_000);
    let expected: Frames = frames_of(&log)
        .into_iter()
        .map(|(t, f)| (t.as_micros(), f.id().raw(), f.data().to_vec()))
        .collect();

    for compression in [Compression::Lz4, Compression::None] {
        let path = std::env::temp_dir().join(format!(
            "canodom-replay-mcap-{compression:?}-{}.mcap",
            std::process::id()
        ));
        let file = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
        let options = McapOptions {
            compression,
            ..McapOptions::default()
        };
        let mcap = McapOut::new(file, options, config.ekf.k_rear_m).unwrap();
        let (mut csv, mut diag) = (Vec::new(), Vec::new());
        let summary = replay_log(
            &config,
            None,
            ReplayOptions::default(),
            &log[..],
            &mut csv,
            &mut diag,
            Some(mcap),
        )
        .unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let _ = std::fs::remove_file(&path);

        let mut by_topic: BTreeMap<String, Vec<(u32, u64)>> = BTreeMap::new();
        let mut raw: Frames = Vec::new();
        for message in mcap::MessageStream::new(&bytes).unwrap() {
            let message = message.unwrap();
            let topic = message.channel.topic.clone();
            if topic == "/canodom/can" {
                raw.extend(can_frames(&message.data));
            }
            by_topic
                .entry(topic)
                .or_default()
                .push((message.sequence, message.log_time));
        }
        let steps = summary.stats.steps;
        assert!(steps > 1000, "{steps} steps");
        assert_eq!(by_topic.len(), 9, "{compression:?}: {:?}", by_topic.keys());
        for (topic, messages) in &by_topic {
            assert_eq!(messages.len() as u64, steps, "{compression:?} {topic}");
            // The sequence is the step's count: one apart, times in order.
            for pair in messages.windows(2) {
                assert_eq!(pair[1].0, pair[0].0 + 1, "{compression:?} {topic}");
                assert!(pair[1].1 >= pair[0].1, "{compression:?} {topic}");
            }
        }
        // The frames after the last step belong to no step.
        let last_step_frames = raw.len();
        assert!(last_step_frames <= expected.len());
        assert!(expected.len() - last_step_frames < 16, "{compression:?}");
        assert_eq!(raw, expected[..last_step_frames], "{compression:?}");
    }
}
