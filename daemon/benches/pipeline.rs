//! Throughput of the offline commands' cores on a simulated rc_car drive
//! (24 741 frames of the track): `replay` (log → pipeline → CSV) and
//! `decode` (log → JSON lines), both into memory.
//!
//! `CARGO_TARGET_DIR=/work/tgt/daemon2 cargo bench -p canodom --bench pipeline`

use canodom::cmd::decode::{DecodeArgs, decode};
use canodom::cmd::replay::replay;
use canodom_pipeline::config::Config;
use canodom_sim::drive::{simulator, write_log};
use canodom_sim::vehicle::PathKind;
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;
use std::path::PathBuf;

fn bench(c: &mut Criterion) {
    let path = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/examples/rc_car.toml"));
    let config = Config::load(&path).expect("example config");
    let mut sim = simulator(&config, PathKind::TrackCcw, None, 1, false).expect("simulator");
    let mut log = Vec::new();
    let frames = write_log(&config, &mut sim, &mut log, None).expect("log");
    let mut group = c.benchmark_group("offline");
    group.throughput(Throughput::Elements(frames));
    group.sample_size(20);
    group.bench_function("replay", |b| {
        let mut out = Vec::with_capacity(1 << 20);
        b.iter(|| {
            out.clear();
            let s = replay(&config, &log[..], &mut out, &mut std::io::sink()).expect("replay");
            black_box(s.stats.steps)
        });
    });
    let args = DecodeArgs {
        dbc: config.dbc_path.clone(),
        log: PathBuf::from("-"),
        all: false,
        strict: false,
        interface: None,
    };
    group.bench_function("decode", |b| {
        let mut out = Vec::with_capacity(1 << 22);
        b.iter(|| {
            out.clear();
            let n = decode(&config.db, &log[..], &mut out, &args, &mut std::io::sink())
                .expect("decode");
            black_box(n.printed)
        });
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
