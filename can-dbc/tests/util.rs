//! Helpers shared by the integration tests: fixture paths and the payload generator the
//! cantools vectors were made with.

use std::path::PathBuf;

/// Path of a DBC file of the repository's `data/dbc`.
pub fn shared_dbc(name: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../data/dbc")).join(name)
}

/// Every `.dbc` file of the shared directory, sorted.
pub fn all_shared_dbcs() -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(shared_dbc(""))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".dbc") && !CANTOOLS_CANNOT_LOAD.contains(&n.as_str()))
        .collect();
    v.sort();
    v
}

/// Shared DBC files cantools refuses to load, so nothing to compare with:
/// opendbc's generated Honda file has a `CM_ SG_` comment without a signal
/// name (cantools 40: "Invalid syntax at line 211"); Chrysler CUSW 29-bit
/// ids without the extended flag; GM VAL_ entries for signals no message
/// has; Hyundai/Kia a `CM_ 145 "..."` without an object kind; Mazda a
/// message name starting with a digit; PSA a signal name starting with one.
pub const CANTOOLS_CANNOT_LOAD: [&str; 6] = [
    "opendbc_honda_civic_touring_2016_can.dbc",
    "opendbc_chrysler_cusw.dbc",
    "opendbc_gm_global_a_powertrain.dbc",
    "opendbc_hyundai_kia_generic.dbc",
    "opendbc_mazda_2017.dbc",
    "opendbc_psa_aee2010_r3.dbc",
];

/// FNV-1a 64 of a string: the per-message seed (same as gen_vectors.py).
pub fn fnv1a64(text: &str) -> u64 {
    text.bytes().fold(0xCBF2_9CE4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01B3)
    })
}

/// splitmix64, identical to gen_vectors.py's.
pub struct SplitMix64(pub u64);

impl SplitMix64 {
    /// Next 64-bit output.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// A payload of `length` bytes: whole 64-bit words, little-endian, truncated.
    pub fn payload(&mut self, length: usize, out: &mut Vec<u8>) {
        out.clear();
        while out.len() < length {
            out.extend_from_slice(&self.next_u64().to_le_bytes());
        }
        out.truncate(length);
    }
}
