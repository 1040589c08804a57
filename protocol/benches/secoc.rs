//! Per-frame cost of SecOC authentication (issues #22, #33, #44; goal under
//! 1 µs): the truncated CMAC-AES-128 of one secured frame over its id,
//! data and 64-bit freshness value (what a sender and a verifier each
//! compute once), a verification of a valid authenticator (counter
//! rebuilt from its low bits), and the receiver's whole path for a secured
//! frame and its authenticator frame (pairing, window, MAC, marks), alone
//! and behind plain frames slipped in (up to four MACs). Profile 3 writes
//! nothing per frame: the epoch is stored once per start.
//!
//! `cargo bench -p canodom-protocol --bench secoc`

use canodom_can::frame::FrameId;
use canodom_protocol::secoc::{
    Authenticator, DEFAULT_WINDOW_TICKS, Key, Link, Receiver, SecuredId, Verdict, freshness,
};
use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;

/// The receiver's epoch in the bench.
const EPOCH: u32 = 0x5EC0_C003;

fn key() -> Key {
    Key::from_bytes([
        0x2b, 0x7e, 0x15, 0x16, 0x28, 0xae, 0xd2, 0xa6, 0xab, 0xf7, 0x15, 0x88, 0x09, 0xcf, 0x4f,
        0x3c,
    ])
}

fn receiver(link: Link) -> Receiver {
    Receiver::new(
        &[SecuredId { link, key: key() }],
        EPOCH,
        DEFAULT_WINDOW_TICKS,
    )
}

fn bench(c: &mut Criterion) {
    let id = FrameId::Standard(0x610);
    let auth_id = FrameId::Standard(0x614);
    let a = Authenticator::new(&key());
    let payload = [1, 0xC0, 0x30, 0x50, 0, 0, 0x10, 0xF4];
    let mut group = c.benchmark_group("secoc");
    group.bench_function("mac", |b| {
        let mut fv = freshness(EPOCH, 1);
        b.iter(|| {
            fv = fv.wrapping_add(1);
            black_box(a.mac(black_box(id), black_box(&payload), fv))
        });
    });
    let fv = freshness(EPOCH, 1000);
    let signed = a.sign(id, &payload, fv);
    group.bench_function("verify", |b| {
        b.iter(|| {
            black_box(a.verify_near(
                black_box(id),
                black_box(&payload),
                black_box(&signed),
                black_box(fv - 3),
            ))
        });
    });
    // The receiver: one secured frame + its authenticator per iteration,
    // each with the next counter (signed ahead, outside the timing).
    let n = 1u32 << 16;
    let auths: Vec<[u8; 8]> = (1..=n)
        .map(|c| a.sign(id, &payload, freshness(EPOCH, c)))
        .collect();
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
                let t_us = k as u64 * 1000;
                if interleaved {
                    // A plain frame ahead of each command: they wait their
                    // 100 ms, so three are pending at every authenticator
                    // and are tried first (the worst case: four MACs).
                    let _ = rx.on_frame(t_us, id, &plain);
                }
                let held = rx.on_frame(t_us + 5, id, &payload);
                let v = rx.on_frame(t_us + 10, auth_id, &auths[k]);
                k += 1;
                // Checked in every build: a refusal would time a cheaper path.
                assert_eq!(held, Verdict::Held);
                assert!(matches!(v, Verdict::Accepted { .. }), "{v:?}");
                black_box(v)
            });
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
