//! Per-frame cost of a receiver's CRC-8 check: canodom-dbc's [`Checksum`]
//! (a hand-made table for any polynomial, read as one look-up per byte
//! position) against the `crc` crate's `Crc<u8, _>` with the same custom
//! polynomial in its three implementations (`NoTable`, `Table<1>`,
//! `Table<16>`). Issue #21 asks each hand-written piece to earn its place;
//! the figures are written beside `crc8_table` in `can-dbc/src/integrity.rs`.
//!
//! `cargo bench -p canodom-can --bench checksum`
//!
//! The frames are classic 8-byte payloads with the CRC over bytes 0..=6 in
//! byte 7 (the rc_car layout), AUTOSAR's CRC-8/H2F (poly 0x2F, init and
//! xor-out 0xFF), which the crate has no `&'static` constant for here: the
//! algorithm is leaked once, as a caller configuring a poly at run time would.

use canodom_dbc::{Checksum, ChecksumAlgorithm};
use crc::{Algorithm, Crc, NoTable, Table};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;
use std::time::Duration;

const FRAMES: usize = 4096;
const POLY: u8 = 0x2F;

fn algorithm() -> &'static Algorithm<u8> {
    Box::leak(Box::new(Algorithm {
        width: 8,
        poly: POLY,
        init: 0xFF,
        refin: false,
        refout: false,
        xorout: 0xFF,
        check: 0xDF,
        residue: 0x42,
    }))
}

fn configured() -> Checksum {
    Checksum::new(
        ChecksumAlgorithm::Crc8 {
            poly: POLY,
            init: 0xFF,
            xor_out: 0xFF,
        },
        0..=6,
        7,
    )
    .expect("valid layout")
}

/// `FRAMES` pseudo-random payloads with a valid CRC in byte 7.
fn frames() -> Vec<[u8; 8]> {
    let checksum = configured();
    let mut state = 0x2545_F491_4F6C_DD1D_u64;
    (0..FRAMES)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let mut frame = state.to_le_bytes();
            checksum.apply(&mut frame).expect("8 bytes");
            frame
        })
        .collect()
}

fn count_valid(frames: &[[u8; 8]], valid: impl Fn(&[u8; 8]) -> bool) -> usize {
    frames.iter().filter(|f| valid(f)).count()
}

fn bench(c: &mut Criterion) {
    let frames = frames();
    let ours = configured();
    let alg = algorithm();
    let no_table = Crc::<u8, NoTable>::new(alg);
    let table1 = Crc::<u8, Table<1>>::new(alg);
    let table16 = Crc::<u8, Table<16>>::new(alg);
    // Same answers before timing anything.
    for f in &frames {
        assert_eq!(table1.checksum(&f[..7]), f[7]);
        assert_eq!(table16.checksum(&f[..7]), f[7]);
        assert_eq!(no_table.checksum(&f[..7]), f[7]);
    }

    let mut g = c.benchmark_group("crc8_verify_7_bytes");
    g.sample_size(20);
    g.measurement_time(Duration::from_secs(3));
    g.throughput(Throughput::Elements(FRAMES as u64));
    g.bench_function("canodom_checksum_is_valid", |b| {
        b.iter(|| count_valid(black_box(&frames), |f| ours.is_valid(f)));
    });
    g.bench_function("crc_table1", |b| {
        b.iter(|| count_valid(black_box(&frames), |f| table1.checksum(&f[..7]) == f[7]));
    });
    g.bench_function("crc_table16", |b| {
        b.iter(|| count_valid(black_box(&frames), |f| table16.checksum(&f[..7]) == f[7]));
    });
    g.bench_function("crc_no_table", |b| {
        b.iter(|| count_valid(black_box(&frames), |f| no_table.checksum(&f[..7]) == f[7]));
    });
    g.finish();

    // Set-up, once per configured checksum: ours builds a 256-entry table
    // and eight position tables; the crate builds its table(s) at run time
    // for a non-const algorithm.
    let mut g = c.benchmark_group("crc8_build");
    g.sample_size(20);
    g.measurement_time(Duration::from_secs(2));
    g.bench_function("canodom_checksum_new", |b| {
        b.iter(|| black_box(configured()));
    });
    g.bench_function("crc_table1_new", |b| {
        b.iter(|| black_box(Crc::<u8, Table<1>>::new(black_box(alg))));
    });
    g.bench_function("crc_table16_new", |b| {
        b.iter(|| black_box(Crc::<u8, Table<16>>::new(black_box(alg))));
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
