//! What `replay`'s CSV text costs per row, against the float formatter
//! under it: the rows of a simulated rc_car drive (pose values as the
//! filter makes them, 16–17 significant digits) written by
//! [`push_csv_row`], by `zmij` alone (the shortest round-trip digits of the
//! six values, nothing assembled) and by the standard library's `{}`.
//! The gap between the first two is what this crate adds around `zmij`;
//! `zmij` itself is the floor while the CSV keeps shortest round-trip text.
//!
//! `cargo bench -p canodom --bench csv_rows`

use canodom::cmd::replay::replay;
use canodom_pipeline::config::Config;
use canodom_report::float_text::push_csv_row;
use canodom_sim::drive::{simulator, write_log};
use canodom_sim::vehicle::PathKind;
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;
use std::io::Write as _;
use std::path::PathBuf;

/// Replay's rows of one simulated lap, read back from its CSV: the time in
/// microseconds and the six pose values.
fn drive_rows() -> Vec<(i64, [f64; 6])> {
    let path = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/examples/rc_car.toml"));
    let config = Config::load(&path).expect("example config");
    let mut sim = simulator(&config, PathKind::TrackCcw, None, 1, false).expect("simulator");
    let mut log = Vec::new();
    write_log(&config, &mut sim, &mut log, None).expect("log");
    let mut csv = Vec::new();
    replay(&config, &log[..], &mut csv, &mut std::io::sink()).expect("replay");
    let text = String::from_utf8(csv).expect("CSV is ASCII");
    text.lines()
        .skip(1)
        .map(|line| {
            // The time and the six pose values lead the row; the columns
            // after them (the correction's text, the pose sample) are not these.
            let mut fields = line
                .split(',')
                .take(7)
                .map(|f| f.parse::<f64>().expect("number"));
            let t_s = fields.next().expect("time");
            let values: Vec<f64> = fields.collect();
            let micros = (t_s * 1e6).round() as i64;
            (micros, values.try_into().expect("six values"))
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let rows = drive_rows();
    let mut group = c.benchmark_group("csv_rows");
    group.throughput(Throughput::Elements(rows.len() as u64));
    let mut out = Vec::with_capacity(rows.len() * 128);
    group.bench_function("push_csv_row", |b| {
        b.iter(|| {
            out.clear();
            for (micros, values) in &rows {
                push_csv_row(&mut out, *micros, values);
            }
            black_box(out.len())
        });
    });
    group.bench_function("zmij_six_values_only", |b| {
        b.iter(|| {
            let mut bytes = 0;
            for (_, values) in &rows {
                for &v in values {
                    bytes += zmij::Buffer::new().format_finite(black_box(v)).len();
                }
            }
            black_box(bytes)
        });
    });
    group.bench_function("std_display_row", |b| {
        b.iter(|| {
            out.clear();
            for (micros, values) in &rows {
                let _ = write!(out, "{}", *micros as f64 / 1e6);
                for v in values {
                    let _ = write!(out, ",{v}");
                }
                out.push(b'\n');
            }
            black_box(out.len())
        });
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
