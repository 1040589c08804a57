//! canodom's log readers agree with python-can's (#25): the fixtures in
//! `fixtures/logs` were written by python-can's writers from a `canodom
//! simulate` log (`make_fixtures.py`), and each `*.pycan.txt` is what
//! python-can's reader (ASCReader, BLFReader, CanutilsLogReader) read from
//! it. Every format, compressed or not, must give the same frames in the
//! same order with the same times. `check_python_can.sh` regenerates the
//! fixtures and re-runs this.

// Test helpers outside #[test] functions unwrap too: a failure is a test failure.
#![allow(clippy::unwrap_used)]

mod common;

use canodom_can::any_log::AnyLogReader;
use canodom_can::candump::{LogReader, ReadError, format_frame};
use canodom_can::log_format::LogFormat;
use std::path::PathBuf;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/logs")
        .join(name)
}

/// (µs, candump frame text) of every record canodom reads from `name`.
fn ours(name: &str) -> (Vec<(u64, String)>, bool) {
    let file = std::fs::File::open(fixture(name)).unwrap();
    let (mut reader, _, _) = AnyLogReader::open(std::io::BufReader::new(file)).unwrap();
    let mut out = Vec::new();
    loop {
        match reader.next_record() {
            Ok(Some(r)) => {
                let mut text = Vec::new();
                format_frame(&mut text, &r.frame);
                out.push((r.timestamp.as_micros(), String::from_utf8(text).unwrap()));
            }
            Ok(None) => break,
            Err(ReadError::Malformed(m)) => panic!("{name}: {m}"),
            Err(e) => panic!("{name}: {e}"),
        }
    }
    let timed = reader.has_time();
    (out, timed)
}

/// The same from python-can's reading (or any candump -L file).
fn reading(name: &str) -> Vec<(u64, String)> {
    let text = std::fs::read(fixture(name)).unwrap();
    let mut reader = LogReader::new(&text[..]);
    let mut out = Vec::new();
    while let Some(r) = reader.next_record().unwrap() {
        let mut text = Vec::new();
        format_frame(&mut text, &r.frame);
        out.push((r.timestamp.as_micros(), String::from_utf8(text).unwrap()));
    }
    out
}

fn assert_same(name: &str, ours: &[(u64, String)], theirs: &[(u64, String)], shift_us: i64) {
    assert_eq!(ours.len(), theirs.len(), "{name}: frame count");
    assert!(!ours.is_empty());
    for (i, (a, b)) in ours.iter().zip(theirs).enumerate() {
        assert_eq!(
            (a.0 as i64 + shift_us, &a.1),
            (b.0 as i64, &b.1),
            "{name}: frame {i} differs"
        );
    }
}

/// How far this machine's local time is ahead of UTC at the fixtures' time:
/// ASC dates are local, and the readings were made under TZ=UTC.
fn local_offset_us() -> i64 {
    use chrono::{Offset as _, TimeZone as _};
    let t = chrono::Local.timestamp_opt(1_700_000_000, 0).unwrap();
    i64::from(t.offset().fix().local_minus_utc()) * 1_000_000
}

#[test]
fn every_format_reads_as_python_can_reads_it() {
    let original = reading("drive.log");
    assert_same(
        "python-can's reading of drive.log",
        &reading("drive.log.pycan.txt"),
        &original,
        0,
    );
    for (file, oracle, shift) in [
        ("drive.pycan.log", "drive.pycan.log.pycan.txt", 0),
        ("drive.asc", "drive.asc.pycan.txt", local_offset_us()),
        ("drive.asc.gz", "drive.asc.pycan.txt", local_offset_us()),
        ("drive.blf", "drive.blf.pycan.txt", 0),
        ("drive.blf.zst", "drive.blf.pycan.txt", 0),
        ("drive.blf.gz", "drive.blf.pycan.txt", 0),
        ("drive.log.zst", "drive.log.pycan.txt", 0),
    ] {
        let (got, timed) = ours(file);
        assert!(timed, "{file}");
        assert_same(file, &got, &reading(oracle), shift);
        // And python-can read what canodom simulated: the same frames, times.
        assert_same(file, &got, &original, shift);
    }
}

#[test]
fn candump_without_l_reads_the_same_frames() {
    let original = reading("drive.log");
    let (timed, has_time) = ours("drive.ta.txt");
    assert!(has_time);
    assert_same("drive.ta.txt", &timed, &original, 0);
    let (plain, has_time) = ours("drive.plain.txt");
    assert!(!has_time, "plain candump output has no time");
    let frames: Vec<_> = original.iter().map(|(_, f)| (0, f.clone())).collect();
    assert_same("drive.plain.txt", &plain, &frames, 0);
}

/// Every record canodom reads from `name` as (µs, channel, frame text),
/// opened as a file (MF4 read in place) or as a stream (a temporary copy).
fn ours_with_channels(name: &str, as_file: bool) -> Vec<(u64, String, String)> {
    let file = std::fs::File::open(fixture(name)).unwrap();
    let (reader, format, _) = if as_file {
        AnyLogReader::open_file(file).unwrap()
    } else {
        AnyLogReader::open(std::io::BufReader::new(file)).unwrap()
    };
    assert_eq!(format, LogFormat::Mf4, "{name}");
    common::records(reader).unwrap()
}

#[test]
fn mf4_reads_as_python_can_reads_it_and_as_its_candump_original() {
    let original = reading("drive.log");
    for name in ["drive.mf4", "drive.deflate.mf4", "drive.plain.mf4"] {
        for as_file in [true, false] {
            let got: Vec<_> = ours_with_channels(name, as_file)
                .into_iter()
                .map(|(t, _, f)| (t, f))
                .collect();
            assert_same(name, &got, &reading(&format!("{name}.pycan.txt")), 0);
            assert_same(name, &got, &original, 0);
        }
    }
    // Every frame kind, two channels, three data groups merged by time.
    let got = ours_with_channels("mixed.mf4", true);
    let want = reading("mixed.log");
    let frames: Vec<_> = got.iter().map(|(t, _, f)| (*t, f.clone())).collect();
    assert_same("mixed.mf4", &frames, &want, 0);
    assert_same("mixed.mf4", &frames, &reading("mixed.mf4.pycan.txt"), 0);
    let channels: Vec<_> = got.iter().map(|(_, c, _)| c.as_str()).collect();
    let expected: Vec<_> = (0..want.len())
        .map(|i| if i % 2 == 0 { "1" } else { "2" })
        .collect();
    assert_eq!(channels, expected);
}

#[test]
fn a_truncated_or_damaged_mf4_is_a_clear_error_never_a_panic() {
    let whole = std::fs::read(fixture("drive.mf4")).unwrap();
    let plain = std::fs::read(fixture("drive.plain.mf4")).unwrap();
    let read_all = |bytes: &[u8]| -> Result<usize, String> {
        let (mut reader, _, _) = AnyLogReader::open(bytes).map_err(|e| e.to_string())?;
        let mut n = 0;
        loop {
            match reader.next_record() {
                Ok(Some(_)) => n += 1,
                Ok(None) => return Ok(n),
                Err(e) => return Err(e.to_string()),
            }
        }
    };
    // Cut anywhere: an error naming an MF4 block and its offset, or (cut in
    // metadata nothing reads) fewer frames — never a panic, never more.
    let n_all = read_all(&whole).unwrap();
    for cut in (8..whole.len()).step_by(97) {
        match read_all(&whole[..cut]) {
            Err(e) => assert!(
                e.contains("MF4 block") && e.contains("byte offset"),
                "cut {cut}: {e}"
            ),
            Ok(n) => assert!(n <= n_all, "cut {cut}"),
        }
    }
    // The uncompressed data block cut in the middle of a record.
    let e = read_all(&plain[..plain.len() / 3]).unwrap_err();
    assert!(e.contains("MF4 block"), "{e}");
    // Every byte of the metadata flipped in turn: errors or frames, no panic.
    for at in (64..whole.len()).step_by(13) {
        let mut bad = whole.clone();
        bad[at] ^= 0xA5;
        if let Err(e) = read_all(&bad) {
            assert!(
                e.contains("MF4 block") || e.contains("MF4"),
                "byte {at}: {e}"
            );
        }
    }
    // A damaged deflate stream names its ##DZ block.
    let dz = whole.windows(4).position(|w| w == b"##DZ").unwrap();
    let mut bad = whole.clone();
    for b in &mut bad[dz + 60..dz + 80] {
        *b ^= 0xFF;
    }
    let e = read_all(&bad).unwrap_err();
    assert!(
        e.contains(&format!("MF4 block ##DZ at byte offset {dz}")),
        "{e}"
    );
}
