//! Differential test against cantools: for every message of every shared DBC file, the
//! payloads gen_vectors.py decoded with cantools are regenerated (splitmix64, same seed),
//! decoded here, and must give bit-identical values (checked through a CRC-32 of the
//! value stream over all payloads, and value by value within 1e-9 relative on the stored
//! first payloads, which also pins the payload generator). Every payload must also
//! survive encode(decode(payload)) on the bits of its present signals.
//!
//! Regenerate the vectors: see can-dbc/README.md.

use canodom_dbc::{Database, FrameId, ValueType};
use serde_json::Value;
use std::fmt::Write as _;

use crate::util::{SplitMix64, fnv1a64, shared_dbc};

const NAN_BITS: u64 = 0x7FF8_0000_0000_0000;
const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

fn bits(v: f64) -> u64 {
    if v.is_nan() { NAN_BITS } else { v.to_bits() }
}

fn close(a: f64, b: f64) -> bool {
    a.to_bits() == b.to_bits()
        || (a.is_nan() && b.is_nan())
        || (a - b).abs() <= 1e-9 * a.abs().max(b.abs())
}

fn check_file(file: &str) {
    let vectors_path = format!(
        "{}/tests/cantools/vectors/{}",
        env!("CARGO_MANIFEST_DIR"),
        file.replace(".dbc", ".json")
    );
    let vectors: Value =
        serde_json::from_str(&std::fs::read_to_string(&vectors_path).unwrap()).unwrap();
    let db = Database::from_file(shared_dbc(file)).unwrap();
    let payloads = vectors["payloads"].as_u64().unwrap();
    let messages = vectors["messages"].as_array().unwrap();
    assert_eq!(
        messages.len(),
        db.messages().len(),
        "{file}: cantools and canodom-dbc see different numbers of messages"
    );
    let mut data = Vec::new();
    let mut decoded = Vec::new();
    let mut total_values = 0u64;
    for mv in messages {
        let name = mv["name"].as_str().unwrap();
        let dbc_id = mv["dbc_id"].as_u64().unwrap();
        let id = FrameId::from_dbc(u32::try_from(dbc_id).unwrap()).unwrap();
        let msg = db
            .message_by_id(id)
            .unwrap_or_else(|| panic!("{file}: no message {id} ({name})"));
        assert_eq!(
            msg.length() as u64,
            mv["length"].as_u64().unwrap(),
            "{file} {name}"
        );
        assert_eq!(
            msg.signals().len() as u64,
            mv["signals"].as_u64().unwrap(),
            "{file} {name}"
        );
        let first = mv["first"].as_array().unwrap();
        let mut rng = SplitMix64(fnv1a64(&format!("{file}:{dbc_id}")));
        let mut digest = CRC32.digest();
        let mut count = 0u64;
        for p in 0..payloads {
            rng.payload(msg.length(), &mut data);
            decoded.clear();
            let it = msg.decode(&data).unwrap();
            let mut wide = Vec::new();
            for (s, v) in it.clone() {
                digest.update(&(s.index() as u32).to_le_bytes());
                digest.update(&bits(v).to_le_bytes());
                decoded.push((s.index(), v));
                if s.size() > 53
                    && matches!(s.value_type(), ValueType::Signed | ValueType::Unsigned)
                {
                    wide.push((s.index(), it.raw(s).unwrap()));
                }
            }
            digest.update(&u32::MAX.to_le_bytes());
            count += decoded.len() as u64;

            if let Some(expected) = first.get(p as usize) {
                let hex = data.iter().fold(String::new(), |mut h, b| {
                    let _ = write!(h, "{b:02x}");
                    h
                });
                assert_eq!(
                    expected[0].as_str().unwrap(),
                    hex,
                    "{file} {name}: payload generator differs"
                );
                let want: Vec<(usize, f64)> = expected[1]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|pair| {
                        let i = pair[0].as_u64().unwrap() as usize;
                        let b = u64::from_str_radix(pair[1].as_str().unwrap(), 16).unwrap();
                        (i, f64::from_bits(b))
                    })
                    .collect();
                assert_eq!(
                    want.iter().map(|w| w.0).collect::<Vec<_>>(),
                    decoded.iter().map(|d| d.0).collect::<Vec<_>>(),
                    "{file} {name} payload {hex}: different signals present"
                );
                for (&(i, w), &(_, g)) in want.iter().zip(&decoded) {
                    assert!(
                        close(w, g),
                        "{file} {name} payload {hex}: signal {} cantools {w:e} canodom {g:e}",
                        msg.signals()[i].name()
                    );
                }
            }

            // encode(decode(payload)) gives back the bits of the present signals.
            let mut rebuilt = vec![0u8; msg.length()];
            msg.encode_into(
                decoded
                    .iter()
                    .copied()
                    .filter(|&(i, _)| !wide.iter().any(|w| w.0 == i)),
                &mut rebuilt,
            )
            .unwrap_or_else(|e| panic!("{file} {name}: re-encoding failed: {e}"));
            for &(i, raw) in &wide {
                assert!(msg.signals()[i].encode_raw(raw, &mut rebuilt));
            }
            let mask = msg.signal_bits(&data).unwrap();
            for k in 0..msg.length() {
                assert_eq!(
                    rebuilt[k] & mask[k],
                    data[k] & mask[k],
                    "{file} {name}: encode(decode) differs in byte {k} of {data:02x?}"
                );
            }
        }
        assert_eq!(
            count,
            mv["values"].as_u64().unwrap(),
            "{file} {name}: value count"
        );
        assert_eq!(
            u64::from(digest.finalize()),
            mv["crc32"].as_u64().unwrap(),
            "{file} {name}: decoded values differ from cantools' in some payload \
             (the first {} payloads agree within 1e-9)",
            first.len()
        );
        total_values += count;
    }
    println!(
        "{file}: {} messages x {payloads} payloads, {total_values} values bit-identical to cantools {}",
        messages.len(),
        vectors["cantools"].as_str().unwrap_or("?")
    );
}

macro_rules! diff_tests {
    ($($test:ident => $file:literal,)*) => {
        $(#[test] fn $test() { check_file($file); })*

        /// Every shared DBC file has a test above and a vector file.
        #[test]
        fn every_shared_dbc_is_covered() {
            let covered = [$($file),*];
            for f in crate::util::all_shared_dbcs() {
                assert!(covered.contains(&f.as_str()), "{f} has no differential test");
            }
        }
    };
}

diff_tests! {
    rc_car => "rc_car.dbc",
    cantools_motohawk => "cantools_motohawk.dbc",
    cantools_multiplex => "cantools_multiplex.dbc",
    cantools_padding_bit_order => "cantools_padding_bit_order.dbc",
    cantools_signed => "cantools_signed.dbc",
    cantools_vehicle => "cantools_vehicle.dbc",
    opendbc_hyundai_2015_ccan => "opendbc_hyundai_2015_ccan.dbc",
    opendbc_tesla_model3_party => "opendbc_tesla_model3_party.dbc",
    opendbc_toyota_2017 => "opendbc_toyota_2017.dbc",
    opendbc_vw_mqb => "opendbc_vw_mqb.dbc",
    opendbc_hyundai_canfd => "opendbc_hyundai_canfd.dbc",
    opendbc_nissan_x_trail_2017 => "opendbc_nissan_x_trail_2017.dbc",
    opendbc_subaru_global_2017 => "opendbc_subaru_global_2017.dbc",
}
