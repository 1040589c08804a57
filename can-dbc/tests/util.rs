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
        .filter(|n| n.ends_with(".dbc") && !cantools_cannot_load(n))
        .collect();
    v.sort();
    v
}

/// Whether cantools refuses to load the shared DBC file `name`, so there is
/// nothing to compare with (the list and the reasons:
/// data/dbc/cantools-cannot-load.txt, shared with the daemon's tests).
pub fn cantools_cannot_load(name: &str) -> bool {
    include_str!("../../data/dbc/cantools-cannot-load.txt")
        .lines()
        .filter(|l| !l.starts_with('#'))
        .filter_map(|l| l.split_whitespace().next())
        .any(|file| file == name)
}

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
