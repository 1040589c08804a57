//! Fuzz decoding of arbitrary frames against every shared DBC file. Input layout:
//! byte 0 picks the database, bytes 1..3 the message (or, with the top bit set, a raw frame
//! ID that is probably unknown), the rest is the payload (any length, up to 64 bytes).
//! Checks: no panic; a short frame is an error; encode(decode(frame)) restores the bits of
//! the present signals (values wider than 53 bits excepted); handles and `decode_each`
//! agree with the message iterator; checksums over arbitrary ranges never read past the end.
#![no_main]

use std::sync::OnceLock;

use canodom_dbc::{Checksum, ChecksumAlgorithm, Database, FrameId, ValueType};
use libfuzzer_sys::fuzz_target;

macro_rules! shared {
    ($($f:literal),*) => {
        [$( ($f, include_bytes!(concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/dbc/", $f)).as_slice()) ),*]
    };
}

fn databases() -> &'static [Database] {
    static DBS: OnceLock<Vec<Database>> = OnceLock::new();
    DBS.get_or_init(|| {
        shared!(
            "rc_car.dbc",
            "cantools_motohawk.dbc",
            "cantools_multiplex.dbc",
            "cantools_padding_bit_order.dbc",
            "cantools_signed.dbc",
            "cantools_vehicle.dbc",
            "opendbc_hyundai_2015_ccan.dbc",
            "opendbc_tesla_model3_party.dbc",
            "opendbc_toyota_2017.dbc",
            "opendbc_vw_mqb.dbc"
        )
        .iter()
        .map(|(name, bytes)| Database::from_bytes(bytes, name).unwrap())
        .collect()
    })
}

fuzz_target!(|input: &[u8]| {
    if input.len() < 3 {
        return;
    }
    let dbs = databases();
    let db = &dbs[usize::from(input[0]) % dbs.len()];
    let sel = u16::from_le_bytes([input[1], input[2]]);
    let payload = &input[3..input.len().min(3 + 64)];
    let id = if sel & 0x8000 != 0 {
        FrameId::Standard(sel & 0x7FF)
    } else {
        db.messages()[usize::from(sel) % db.messages().len()].id()
    };
    let Some(msg) = db.message_by_id(id) else {
        return;
    };
    let decoded = match db.decode(id, payload).unwrap() {
        Ok(d) => d,
        Err(_) => {
            assert!(payload.len() < msg.length());
            return;
        }
    };
    let mut values = Vec::new();
    let mut wide = Vec::new();
    for (s, v) in decoded.clone() {
        let handle = db.signal(&format!("{}.{}", msg.name(), s.name()));
        if let Ok(h) = handle {
            let hv = h.decode(payload).expect("handle decodes a present signal");
            assert!(hv.to_bits() == v.to_bits() || (hv.is_nan() && v.is_nan()));
        }
        if s.size() > 53 && matches!(s.value_type(), ValueType::Signed | ValueType::Unsigned) {
            wide.push((s.index(), decoded.raw(s).unwrap()));
        } else {
            values.push((s.index(), v));
        }
    }
    // The callback decoder yields exactly what the iterator does.
    let mut k = 0;
    let all: Vec<(usize, f64)> = decoded.clone().map(|(s, v)| (s.index(), v)).collect();
    msg.decode_each(payload, |s, v| {
        assert_eq!(all[k].0, s.index());
        assert!(all[k].1.to_bits() == v.to_bits() || (v.is_nan() && all[k].1.is_nan()));
        k += 1;
    })
    .unwrap();
    assert_eq!(k, all.len());
    let mut rebuilt = vec![0u8; msg.length()];
    msg.encode_into(values, &mut rebuilt)
        .expect("decoded values re-encode");
    for (i, raw) in wide {
        assert!(msg.signals()[i].encode_raw(raw, &mut rebuilt));
    }
    let mask = msg.signal_bits(payload).unwrap();
    for k in 0..msg.length() {
        // Float signals: a NaN may come back with another payload; skip their bytes.
        let has_float = msg
            .signals()
            .iter()
            .any(|s| matches!(s.value_type(), ValueType::Float32 | ValueType::Float64));
        if !has_float {
            assert_eq!(rebuilt[k] & mask[k], payload[k] & mask[k], "byte {k}");
        }
    }
    // Checksums over byte ranges chosen by the input: errors, never out-of-bounds reads.
    let lo = usize::from(input[1] % 70);
    let hi = usize::from(input[2] % 70);
    for alg in [
        ChecksumAlgorithm::Crc8SaeJ1850,
        ChecksumAlgorithm::Crc8 {
            poly: input[1],
            init: input[2],
            xor_out: 0,
        },
        ChecksumAlgorithm::Sum { init: 0 },
        ChecksumAlgorithm::Xor { init: 0 },
    ] {
        if let Ok(c) = Checksum::new(alg, lo..=hi, hi + 1) {
            let _ = c.compute(payload);
        }
    }
});
