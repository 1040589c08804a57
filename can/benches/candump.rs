//! Throughput of the candump log reader and formatter on a generated log of
//! rc_car-like traffic (three 8-byte frames and one 4-byte frame per 10 ms).
//!
//! `cargo bench -p canodom-can --bench candump`
//!
//! `socketcan_dump_parse_1M_lines` reads the same log with socketcan's own
//! `dump::Reader` (issue #21: our parser is kept only while it earns its
//! place; the figures are in `candump.rs`'s module doc).

use canodom_can::candump::{LogReader, Record, format_record};
use canodom_can::frame::{CanFrame, FrameId};
use canodom_can::time::Timestamp;
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;
use std::time::Duration;

const LINES: usize = 1_000_000;

fn generated_log(lines: usize) -> Vec<u8> {
    let mut out = Vec::with_capacity(lines * 48);
    let mut state = 0x1234_5678_u32;
    for i in 0..lines {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        let bytes = state.to_le_bytes();
        let payload = [
            bytes[0], bytes[1], bytes[2], bytes[3], bytes[3], bytes[2], bytes[1], bytes[0],
        ];
        let (id, len) = match i % 4 {
            0 => (0x100, 8),
            1 => (0x101, 8),
            2 => (0x110, 8),
            _ => (0x120, 4),
        };
        let frame =
            CanFrame::new_data(FrameId::Standard(id), &payload[..len]).expect("valid frame");
        let record = Record {
            timestamp: Timestamp::from_micros(1_700_000_000_000_000 + (i as u64 / 4) * 10_000),
            iface: "vcan0",
            frame,
            direction: None,
        };
        format_record(&mut out, &record);
    }
    out
}

fn parse(log: &[u8]) -> (usize, u64) {
    let mut reader = LogReader::new(log);
    let (mut frames, mut checksum) = (0usize, 0u64);
    while let Some(record) = reader.next_record().expect("generated log is valid") {
        frames += 1;
        checksum = checksum.wrapping_add(u64::from(record.frame.data()[0]));
    }
    (frames, checksum)
}

/// As [`parse`] with `socketcan::dump::Reader`, which reads a line into a
/// `String` and allocates the interface name and the payload per record.
fn parse_with_socketcan(log: &[u8]) -> (usize, u64) {
    use socketcan::{CanAnyFrame, EmbeddedFrame as _};
    let mut reader = socketcan::dump::Reader::from_reader(log);
    let (mut frames, mut checksum) = (0usize, 0u64);
    while let Some(record) = reader.next_record().expect("generated log is valid") {
        frames += 1;
        let first = match &record.frame {
            CanAnyFrame::Normal(f) => f.data()[0],
            _ => 0,
        };
        checksum = checksum.wrapping_add(u64::from(first));
    }
    (frames, checksum)
}

fn bench(c: &mut Criterion) {
    let log = generated_log(LINES);
    let mut group = c.benchmark_group("candump");
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(5));
    group.throughput(Throughput::Elements(LINES as u64));
    group.bench_function("parse_1M_lines", |b| {
        b.iter(|| {
            let (frames, sum) = parse(black_box(&log));
            assert_eq!(frames, LINES);
            sum
        });
    });
    group.bench_function("socketcan_dump_parse_1M_lines", |b| {
        b.iter(|| {
            let (frames, sum) = parse_with_socketcan(black_box(&log));
            assert_eq!(frames, LINES);
            sum
        });
    });
    let records: Vec<(u64, CanFrame)> = {
        let mut reader = LogReader::new(&log[..]);
        let mut v = Vec::with_capacity(LINES);
        while let Some(r) = reader.next_record().expect("valid") {
            v.push((r.timestamp.as_micros(), r.frame));
        }
        v
    };
    let mut out = Vec::with_capacity(log.len());
    group.bench_function("format_1M_lines", |b| {
        b.iter(|| {
            out.clear();
            for &(t, frame) in &records {
                let record = Record {
                    timestamp: Timestamp::from_micros(t),
                    iface: "vcan0",
                    frame,
                    direction: None,
                };
                format_record(&mut out, &record);
            }
            assert_eq!(out.len(), log.len());
            out.len()
        });
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
