//! Per-frame cost of SecOC authentication (issue #22; goal under 1 µs):
//! the truncated CMAC-AES-128 of one secured frame (what a sender and a
//! verifier each compute once), a verification of a valid authenticator,
//! and the receiver's whole path for a secured frame and its authenticator
//! frame (pairing, MAC, freshness; the store write of an accepted value is
//! left out, as it is a file write, not CPU).
//!
//! `cargo bench -p canodom-protocol --bench secoc`

use canodom_can::frame::FrameId;
use canodom_protocol::secoc::{Authenticator, Key, Link, Lockout, Receiver, Verdict};
use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;

fn key() -> Key {
    Key::from_bytes([
        0x2b, 0x7e, 0x15, 0x16, 0x28, 0xae, 0xd2, 0xa6, 0xab, 0xf7, 0x15, 0x88, 0x09, 0xcf, 0x4f,
        0x3c,
    ])
}

fn bench(c: &mut Criterion) {
    let id = FrameId::Standard(0x610);
    let auth_id = FrameId::Standard(0x614);
    let a = Authenticator::new(&key());
    let payload = [1, 0xC0, 0x30, 0x50, 0, 0, 0x10, 0xF4];
    let mut group = c.benchmark_group("secoc");
    group.bench_function("mac", |b| {
        let mut fv = 0u32;
        b.iter(|| {
            fv = fv.wrapping_add(1);
            black_box(a.mac(black_box(id), black_box(&payload), fv))
        });
    });
    let signed = a.sign(id, &payload, 7);
    group.bench_function("verify", |b| {
        b.iter(|| black_box(a.verify(black_box(id), black_box(&payload), black_box(&signed))));
    });
    // The receiver: one secured frame + its authenticator per iteration,
    // each with a fresh value (signed ahead, outside the timing).
    let n = 1 << 16;
    let auths: Vec<[u8; 8]> = (1..=n).map(|fv| a.sign(id, &payload, fv)).collect();
    group.bench_function("receive_pair_accepted", |b| {
        let link = Link {
            secured: id,
            authenticator: auth_id,
        };
        let mut rx = Receiver::new(
            &key(),
            &[(link, None)],
            Lockout::new(10, 1_000_000, 60_000_000),
        );
        let mut k = 0usize;
        let mut t = 0u64;
        b.iter(|| {
            if k == auths.len() {
                rx = Receiver::new(
                    &key(),
                    &[(link, None)],
                    Lockout::new(10, 1_000_000, 60_000_000),
                );
                k = 0;
            }
            t += 1000;
            let held = rx.on_frame(t, id, &payload, |_, _| Ok::<(), ()>(()));
            let v = rx.on_frame(t + 10, auth_id, &auths[k], |_, _| Ok::<(), ()>(()));
            k += 1;
            debug_assert_eq!(held, Verdict::Held);
            black_box(v)
        });
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
