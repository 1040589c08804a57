//! Per-frame cost of SecOC authentication (issues #22, #33; goal under
//! 1 µs): the truncated CMAC-AES-128 of one secured frame over its id,
//! data and 64-bit freshness value (what a sender and a verifier each
//! compute once), a verification of a valid authenticator (freshness
//! rebuilt from the clock), and the receiver's whole path for a secured
//! frame and its authenticator frame (pairing, window, MAC, freshness; the
//! store write of an accepted value is left out, as it is a file write,
//! not CPU), alone and behind plain frames slipped in (up to four MACs).
//!
//! `cargo bench -p canodom-protocol --bench secoc`

use canodom_can::frame::FrameId;
use canodom_protocol::secoc::{
    Authenticator, DEFAULT_WINDOW_MS, Key, Link, Lockout, Receiver, SecuredId, Verdict,
};
use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;

/// 2025-11-24 16:00 UTC, ms: the clock of the bench.
const T0_MS: u64 = 1_764_000_000_000;

fn key() -> Key {
    Key::from_bytes([
        0x2b, 0x7e, 0x15, 0x16, 0x28, 0xae, 0xd2, 0xa6, 0xab, 0xf7, 0x15, 0x88, 0x09, 0xcf, 0x4f,
        0x3c,
    ])
}

fn receiver(link: Link) -> Receiver {
    Receiver::new(
        &[SecuredId {
            link,
            key: key(),
            last_accepted: None,
            lockable: true,
        }],
        &Lockout::new(10, 10_000_000, 60_000_000),
        DEFAULT_WINDOW_MS,
    )
}

fn bench(c: &mut Criterion) {
    let id = FrameId::Standard(0x610);
    let auth_id = FrameId::Standard(0x614);
    let a = Authenticator::new(&key());
    let payload = [1, 0xC0, 0x30, 0x50, 0, 0, 0x10, 0xF4];
    let mut group = c.benchmark_group("secoc");
    group.bench_function("mac", |b| {
        let mut fv = T0_MS;
        b.iter(|| {
            fv = fv.wrapping_add(1);
            black_box(a.mac(black_box(id), black_box(&payload), fv))
        });
    });
    let signed = a.sign(id, &payload, T0_MS);
    group.bench_function("verify", |b| {
        b.iter(|| {
            black_box(a.verify(
                black_box(id),
                black_box(&payload),
                black_box(&signed),
                black_box(T0_MS + 3),
            ))
        });
    });
    // The receiver: one secured frame + its authenticator per iteration,
    // each with a fresh value 1 ms apart (signed ahead, outside the timing).
    let n = 1u64 << 16;
    let auths: Vec<[u8; 8]> = (0..n).map(|k| a.sign(id, &payload, T0_MS + k)).collect();
    let link = Link {
        secured: id,
        authenticator: auth_id,
    };
    let plain = [1, 0xC0, 0x30, 0x50, 0, 0, 0x20, 0x99];
    for (name, interleaved) in [
        ("receive_pair_accepted", false),
        ("receive_pair_behind_three_plain_frames", true),
    ] {
        group.bench_function(name, |b| {
            let mut rx = receiver(link);
            let mut k = 0usize;
            b.iter(|| {
                if k == auths.len() {
                    rx = receiver(link);
                    k = 0;
                }
                let t_us = (T0_MS + k as u64) * 1000;
                if interleaved {
                    // A plain frame ahead of each command: they wait their
                    // 100 ms, so three are pending at every authenticator
                    // and are tried first (the worst case: four MACs).
                    let _ = rx.on_frame(t_us, id, &plain, |_, _| Ok::<(), ()>(()));
                }
                let held = rx.on_frame(t_us + 5, id, &payload, |_, _| Ok::<(), ()>(()));
                let v = rx.on_frame(t_us + 10, auth_id, &auths[k], |_, _| Ok::<(), ()>(()));
                k += 1;
                debug_assert_eq!(held, Verdict::Held);
                debug_assert!(matches!(v, Verdict::Accepted { .. }));
                black_box(v)
            });
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
