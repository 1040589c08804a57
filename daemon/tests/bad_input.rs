//! Bad input never crashes nor corrupts: every case is counted under its
//! reason, and the pose stays what the good frames alone give.

use crate::util::{frames_of, rc_car, simulated_log};
use canodom::cmd::replay::replay;
use canodom_can::frame::{CanFrame, FrameId};
use canodom_can::time::Timestamp;
use canodom_pipeline::config::Config;
use canodom_pipeline::pipeline::Pipeline;
use canodom_pipeline::stats::Reject;
use canodom_sim::vehicle::PathKind;
use proptest::prelude::*;
use std::fmt::Write as _;

const REAR: FrameId = FrameId::Standard(0x100);

/// The first `n` frames of a simulated rc_car drive.
fn clean(n: usize) -> (Config, Vec<(Timestamp, CanFrame)>) {
    let config = rc_car();
    let (log, _) = simulated_log(&config, PathKind::Circle, 3);
    let mut frames = frames_of(&log);
    frames.truncate(n);
    (config, frames)
}

fn run(config: &Config, frames: &[(Timestamp, CanFrame)]) -> Pipeline {
    let mut p = Pipeline::new(config).unwrap();
    for (t, f) in frames {
        p.push(*t, f);
    }
    p
}

/// Inserts `bad(frame)` after every 100th rear frame; returns the count.
fn inject(
    frames: &[(Timestamp, CanFrame)],
    bad: impl Fn(&CanFrame) -> CanFrame,
) -> (Vec<(Timestamp, CanFrame)>, u64) {
    let mut out = Vec::new();
    let mut n = 0;
    for (i, (t, f)) in frames.iter().enumerate() {
        out.push((*t, *f));
        if f.id() == REAR && i % 300 == 2 {
            out.push((*t, bad(f)));
            n += 1;
        }
    }
    (out, n)
}

/// The corrupted stream is counted under `reason` and leaves the filter state
/// exactly as the clean stream does.
fn assert_counted_and_harmless(reason: Reject, bad: impl Fn(&CanFrame) -> CanFrame) {
    let (config, frames) = clean(6000);
    let good = run(&config, &frames);
    let (dirty, n) = inject(&frames, bad);
    assert!(n >= 5);
    let p = run(&config, &dirty);
    println!("{reason:?}: {}", p.stats());
    assert_eq!(p.stats().get(reason), n, "{}", p.stats());
    assert_eq!(p.stats().used, good.stats().used);
    assert_eq!(p.state(), good.state(), "bad frames changed the pose");
}

fn with_data(f: &CanFrame, data: &[u8]) -> CanFrame {
    CanFrame::new_data(f.id(), data).unwrap()
}

#[test]
fn truncated_frames() {
    assert_counted_and_harmless(Reject::Truncated, |f| with_data(f, &f.data()[..5]));
}

#[test]
fn wrong_dlc_frames() {
    assert_counted_and_harmless(Reject::WrongDlc, |f| {
        let mut d = [0u8; 12];
        d[..8].copy_from_slice(f.data());
        CanFrame::new_fd(f.id(), 0, &d).unwrap()
    });
}

#[test]
fn bad_checksum_frames() {
    assert_counted_and_harmless(Reject::BadChecksum, |f| {
        let mut d = [0u8; 8];
        d.copy_from_slice(f.data());
        d[0] ^= 0x40;
        with_data(f, &d)
    });
}

#[test]
fn unknown_ids() {
    assert_counted_and_harmless(Reject::UnknownId, |f| {
        CanFrame::new_data(FrameId::Standard(0x7FE), f.data()).unwrap()
    });
}

#[test]
fn remote_frames() {
    assert_counted_and_harmless(Reject::NotData, |f| {
        CanFrame::new_remote(f.id(), 8, None).unwrap()
    });
}

#[test]
fn bad_counter_frames() {
    // A frame repeated with its old counter (and a valid CRC): a replay attack
    // or a stuck sender. It is refused, and the next good frame resynchronises
    // (counted too); tick counters are cumulative, so no distance is lost.
    let (config, frames) = clean(6000);
    let good = run(&config, &frames);
    let mut dirty = Vec::new();
    let mut injected = 0;
    let mut prev_rear: Option<CanFrame> = None;
    for (i, (t, f)) in frames.iter().enumerate() {
        if let Some(prev) = prev_rear.filter(|_| f.id() == REAR && i % 300 == 2) {
            dirty.push((*t, prev));
            injected += 1;
            continue; // the stale copy replaces this sample
        }
        if f.id() == REAR {
            prev_rear = Some(*f);
        }
        dirty.push((*t, *f));
    }
    let p = run(&config, &dirty);
    println!("bad counter: {}", p.stats());
    assert!(
        p.stats().get(Reject::BadCounter) >= injected,
        "{}",
        p.stats()
    );
    let (a, b) = (good.state().pose(), p.state().pose());
    let d = (a.x_m - b.x_m).hypot(a.y_m - b.y_m);
    assert!(d < 0.002, "pose moved {d} m");
}

#[test]
fn duplicate_samples_are_wheel_faults() {
    // A valid frame whose timestamp repeats the previous one: the decoder
    // refuses it (no time passed) and counts it.
    let (config, frames) = clean(3000);
    let mut dirty = Vec::new();
    let mut counter_shift = 0u8;
    let mut n = 0;
    for (i, (t, f)) in frames.iter().enumerate() {
        let mut d = [0u8; 8];
        d.copy_from_slice(f.data());
        if f.id() == REAR {
            // Re-number counters so the extra frame passes the counter check.
            d[6] = (d[6] & 0xF0) | ((d[6] + counter_shift) & 0x0F);
            canodom_dbc::Checksum::rc_car().apply(&mut d).unwrap();
        }
        dirty.push((*t, with_data(f, &d)));
        if f.id() == REAR && i % 300 == 2 {
            counter_shift = counter_shift.wrapping_add(1);
            d[6] = (d[6] & 0xF0) | ((d[6] + 1) & 0x0F);
            canodom_dbc::Checksum::rc_car().apply(&mut d).unwrap();
            dirty.push((*t, with_data(f, &d)));
            n += 1;
        }
    }
    let p = run(&config, &dirty);
    println!("duplicates: {}", p.stats());
    assert_eq!(p.stats().get(Reject::WheelFault), 2 * n, "{}", p.stats());
    assert_eq!(p.stats().get(Reject::BadCounter), 0, "{}", p.stats());
}

#[test]
fn nan_float_signals() {
    let path = crate::util::manifest().join("tests/fixtures/float_car.toml");
    let config = Config::load(&path).unwrap();
    let wheels = FrameId::Standard(0x200);
    let steer = FrameId::Standard(0x201);
    let mut p = Pipeline::new(&config).unwrap();
    let speed = 500i16.to_le_bytes(); // 0.5 m/s
    let wheel_data = [speed, speed, speed, speed].concat();
    let mut nan_count = 0;
    for k in 0..200u64 {
        let t = Timestamp::from_micros(1_000_000 + k * 10_000);
        let angle: f32 = match k % 50 {
            10 => f32::NAN,
            20 => f32::INFINITY,
            _ => 2.0,
        };
        if !angle.is_finite() {
            nan_count += 1;
        }
        p.push(t, &CanFrame::new_data(steer, &angle.to_le_bytes()).unwrap());
        p.push(t, &CanFrame::new_data(wheels, &wheel_data).unwrap());
    }
    println!("float: {}", p.stats());
    assert_eq!(p.stats().get(Reject::NonFinite), nan_count);
    let pose = p.state().pose();
    assert!(pose.x_m.is_finite() && pose.y_m.is_finite() && pose.heading_rad.is_finite());
    assert!(pose.x_m > 0.9, "{pose:?}");
    // The finite 2° angles reached the filter: against wheels that drive
    // straight it learns them as the sensor's offset (the default fuses the
    // front through the gate only, so they do not turn the pose).
    let offset = p.state().steer_offset_rad();
    assert!(offset > 0.5f64.to_radians(), "{offset}");
}

#[test]
fn log_with_garbage_lines() {
    let config = rc_car();
    let (log, _) = simulated_log(&config, PathKind::Circle, 3);
    let text = String::from_utf8(log.clone()).unwrap();
    let mut dirty = String::new();
    let mut garbage = 0;
    for (i, line) in text.lines().enumerate() {
        dirty.push_str(line);
        dirty.push('\n');
        if i % 1000 == 7 {
            dirty.push_str(
                [
                    "not a frame",
                    "(1700000000.000001) vcan0 100#ZZ",
                    "(1700000000.000001) vcan0 12345678901#00",
                    "(1700000000.000001) vcan0",
                ][garbage % 4],
            );
            dirty.push('\n');
            garbage += 1;
        }
    }
    // Half a line at the end, as a killed candump leaves.
    dirty.push_str("(1700000100.000000) vcan0 100#0102");
    let mut clean_csv = Vec::new();
    let a = replay(&config, &log[..], &mut clean_csv, &mut std::io::sink()).unwrap();
    let mut dirty_csv = Vec::new();
    let mut diag = Vec::new();
    let b = replay(&config, dirty.as_bytes(), &mut dirty_csv, &mut diag).unwrap();
    let diag = String::from_utf8(diag).unwrap();
    println!(
        "garbage: malformed {}, {}\n{}",
        b.malformed,
        b.stats,
        diag.lines().next().unwrap()
    );
    assert_eq!(b.malformed as usize, garbage);
    assert_eq!(b.malformed_by_reason.total() as usize, garbage);
    assert!(
        b.malformed_by_reason.nonzero().count() >= 2,
        "several reasons"
    );
    assert!(diag.contains("line 9:"), "{diag}");
    assert_eq!(a.state, b.state);
    // The cut last line is a short frame at worst, counted, never used.
    assert!(b.stats.get(Reject::Truncated) <= 1);
    assert_eq!(clean_csv, dirty_csv);
}

#[test]
fn other_frame_kinds_in_a_log_replay_as_the_pipeline_sees_them() {
    // Replay hands the common line to its filter thread in a compact form
    // and every other kind of record as a whole frame: interleaved, both
    // must reach the pipeline in log order, as one loop over the log does.
    let config = rc_car();
    let (log, _) = simulated_log(&config, PathKind::Circle, 5);
    let text = String::from_utf8(log).unwrap();
    let mut mixed = String::new();
    for (i, line) in text.lines().enumerate() {
        let t = line.split(' ').next().unwrap();
        let other = match i % 7 {
            // Remote frame on the rear wheels' id, FD frame on it (data,
            // used as such), error frame, a frame with a direction, an
            // extended id no message has.
            1 => format!("{t} vcan0 100#R"),
            2 if i % 3 == 0 => format!("{t} vcan0 100##0{}", &line[line.len() - 16..]),
            3 => format!("{t} vcan0 20000080#0000000000000000"),
            4 => format!("{line} R"),
            5 => format!("{t} vcan0 1ABCDEF0#01"),
            _ => String::new(),
        };
        mixed.push_str(line);
        mixed.push('\n');
        if !other.is_empty() {
            mixed.push_str(&other);
            mixed.push('\n');
        }
    }
    let mut csv = Vec::new();
    let summary = replay(&config, mixed.as_bytes(), &mut csv, &mut std::io::sink()).unwrap();

    let mut reference = Pipeline::new(&config).unwrap();
    let mut expected = format!("{}\n", canodom::cmd::replay::CSV_HEADER);
    let mut reader = canodom_can::candump::LogReader::new(mixed.as_bytes());
    while let Some(record) = reader.next_record().unwrap() {
        if let Some(s) = reference
            .push(record.timestamp, &record.frame)
            .step()
            .copied()
        {
            let (f, o) = (s.fused, s.odometry);
            let p = reference.pose_output(record.timestamp);
            let t0 = reference.first_frame_time().unwrap().as_micros();
            let mut t_unix = Vec::new();
            canodom_report::float_text::push_micros_as_seconds(&mut t_unix, t0 as i64 + s.t_us);
            writeln!(
                expected,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                s.t_s,
                f.x_m,
                f.y_m,
                f.heading_rad,
                o.x_m,
                o.y_m,
                o.heading_rad,
                s.correction.as_str(),
                String::from_utf8(t_unix).unwrap(),
                p.speed_mps,
                p.pos_std_m,
                p.heading_std_rad,
                u8::from(p.flags.pose_valid),
                p.flags.bits()
            )
            .unwrap();
        }
    }
    println!("mixed kinds: {}", summary.stats);
    assert!(summary.stats.get(Reject::NotData) > 0 && summary.stats.get(Reject::UnknownId) > 0);
    assert_eq!(summary.stats, *reference.stats());
    assert_eq!(summary.state, *reference.state());
    assert_eq!(String::from_utf8(csv).unwrap(), expected);
}

fn arb_frame() -> impl Strategy<Value = (u64, CanFrame)> {
    let id = prop_oneof![
        Just(0x100u16),
        Just(0x101),
        Just(0x110),
        Just(0x120),
        0u16..0x800
    ];
    (
        0u64..10_000_000,
        id,
        prop::collection::vec(any::<u8>(), 0..=8),
        any::<bool>(),
    )
        .prop_map(|(t, id, data, remote)| {
            let f = if remote {
                CanFrame::new_remote(FrameId::Standard(id), data.len(), None).unwrap()
            } else {
                CanFrame::new_data(FrameId::Standard(id), &data).unwrap()
            };
            (t, f)
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    #[test]
    fn arbitrary_frames_never_panic(frames in prop::collection::vec(arb_frame(), 0..300)) {
        for path in [crate::util::rc_car_toml(), crate::util::toyota_toml()] {
            let config = Config::load(&path).unwrap();
            let mut p = Pipeline::new(&config).unwrap();
            for (t, f) in &frames {
                p.push(Timestamp::from_micros(1_700_000_000_000_000 + t), f);
            }
            let pose = p.pose_output(Timestamp::from_micros(1_700_000_010_000_000));
            prop_assert!(pose.x_m.is_finite() && pose.y_m.is_finite() && pose.heading_rad.is_finite());
            prop_assert!(pose.pos_std_m.is_finite());
            prop_assert_eq!(p.stats().frames, frames.len() as u64);
        }
    }
}
