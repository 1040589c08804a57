//! Decode benchmarks: the 4 wheel-speed signals of Toyota's WHEEL_SPEEDS, and lookup +
//! decode of frames among 500 message definitions. `benches/cantools_timing.py` times
//! cantools on the same frames (same splitmix64 payloads, same generated DBC text);
//! `benches/compare_cantools.sh` runs both and prints the ratio.

// A benchmark's fixtures are known good; a failure to load them should stop it loudly.
#![allow(clippy::unwrap_used)]

use std::fmt::Write as _;
use std::hint::black_box;

use canodom_dbc::{Database, FrameId};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};

/// Frames per iteration: enough distinct payloads that branch predictors cannot learn one.
const FRAMES: usize = 1024;

struct SplitMix64(u64);
impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
}

/// The 500-message DBC text (same generator as cantools_timing.py): every fifth message
/// has an extended ID; four 16-bit signals each, alternating Intel and Motorola.
fn dbc_500() -> String {
    let mut t = String::from("VERSION \"\"\n\nNS_ :\n\nBS_:\n\nBU_: ECU\n\n");
    for k in 0..500u32 {
        let id = if k % 5 == 4 {
            0x8000_0000 | (0x18F0_0000 + k)
        } else {
            0x100 + k
        };
        writeln!(t, "BO_ {id} MSG_{k}: 8 ECU").unwrap();
        for s in 0..4u32 {
            let (start, order) = if s % 2 == 0 {
                (16 * s, 1)
            } else {
                (16 * s + 7, 0)
            };
            writeln!(
                t,
                " SG_ SIG_{k}_{s} : {start}|16@{order}+ (0.01,-{k}) [0|655] \"km/h\" ECU"
            )
            .unwrap();
        }
        t += "\n";
    }
    t
}

fn toyota_wheel_speeds(c: &mut Criterion) {
    let db = Database::from_file(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../data/dbc/opendbc_toyota_2017.dbc"
    ))
    .unwrap();
    let handles: Vec<_> = ["FR", "FL", "RR", "RL"]
        .iter()
        .map(|w| db.signal(&format!("WHEEL_SPEEDS.WHEEL_SPEED_{w}")).unwrap())
        .collect();
    let handles: [_; 4] = handles.try_into().unwrap();
    let msg = db.message_by_id(FrameId::standard(0xAA).unwrap()).unwrap();
    let mut rng = SplitMix64(0xAA);
    let frames: Vec<[u8; 8]> = (0..FRAMES).map(|_| rng.next_u64().to_le_bytes()).collect();

    let mut g = c.benchmark_group("wheel_speeds_4_signals");
    g.throughput(Throughput::Elements(FRAMES as u64));
    g.bench_function("handles", |b| {
        b.iter(|| {
            let mut sum = 0.0;
            for f in &frames {
                for h in &handles {
                    sum += h.decode(black_box(f)).unwrap_or(0.0);
                }
            }
            sum
        });
    });
    g.bench_function("message_decode", |b| {
        b.iter(|| {
            let mut sum = 0.0;
            for f in &frames {
                for (_, v) in msg.decode(black_box(f)).unwrap() {
                    sum += v;
                }
            }
            sum
        });
    });
    g.bench_function("message_decode_each", |b| {
        b.iter(|| {
            let mut sum = 0.0;
            for f in &frames {
                msg.decode_each(black_box(f), |_, v| sum += v).unwrap();
            }
            sum
        });
    });
    g.finish();
}

fn lookup_among_500(c: &mut Criterion) {
    let db = Database::parse(&dbc_500(), "bench_500.dbc").unwrap();
    assert_eq!(db.messages().len(), 500);
    let mut rng = SplitMix64(500);
    let frames: Vec<(FrameId, [u8; 8])> = (0..FRAMES)
        .map(|_| {
            let k = (rng.next_u64() % 500) as usize;
            (db.messages()[k].id(), rng.next_u64().to_le_bytes())
        })
        .collect();
    let mut g = c.benchmark_group("lookup_decode_500_messages");
    g.throughput(Throughput::Elements(FRAMES as u64));
    g.bench_function("database_decode", |b| {
        b.iter(|| {
            let mut sum = 0.0;
            for (id, f) in &frames {
                if let Some(Ok(d)) = db.decode(black_box(*id), black_box(f)) {
                    for (_, v) in d {
                        sum += v;
                    }
                }
            }
            sum
        });
    });
    g.bench_function("lookup_only", |b| {
        b.iter(|| {
            let mut n = 0;
            for (id, _) in &frames {
                n += db
                    .message_by_id(black_box(*id))
                    .map_or(0, canodom_dbc::Message::length);
            }
            n
        });
    });
    g.bench_function("database_decode_each", |b| {
        b.iter(|| {
            let mut sum = 0.0;
            for (id, f) in &frames {
                let _ = db.decode_each(black_box(*id), black_box(f), |_, v| sum += v);
            }
            sum
        });
    });
    g.finish();
}

criterion_group!(benches, toyota_wheel_speeds, lookup_among_500);
criterion_main!(benches);
