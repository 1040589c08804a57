//! Frame validity as production cars use it: rolling counters and checksums.
//!
//! The DLC check is part of decoding ([`crate::Message::decode`] rejects a short frame
//! with [`crate::Error::ShortFrame`]); this module adds the counter and checksum checks
//! and the helpers to produce valid frames (next counter value, checksum insertion).

use std::ops::RangeInclusive;

use crate::error::{Error, Result};

/// Outcome of one rolling-counter observation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CounterStatus {
    /// First frame seen: accepted, nothing to compare against.
    First,
    /// The counter advanced by exactly one (modulo 2^bits).
    InSequence,
    /// The counter did not advance by one: frames were lost, repeated or reordered.
    Gap {
        /// The value that was expected.
        expected: u64,
        /// The value that arrived.
        got: u64,
    },
}

/// Tracks a rolling counter signal of `bits` bits: each frame should carry the previous
/// value plus one, modulo 2^bits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CounterCheck {
    mask: u64,
    last: Option<u64>,
    gaps: u64,
}

impl CounterCheck {
    /// A checker for a counter of `bits` bits (1..=64).
    ///
    /// # Errors
    /// [`Error::InvalidCheck`] if `bits` is 0 or above 64.
    pub fn new(bits: u32) -> Result<Self> {
        if bits == 0 || bits > 64 {
            return Err(Error::InvalidCheck(format!(
                "a rolling counter of {bits} bits (needs 1..=64)"
            )));
        }
        Ok(Self {
            mask: u64::MAX >> (64 - bits),
            last: None,
            gaps: 0,
        })
    }

    /// Record the counter value of a new frame and say whether it follows the previous one.
    /// The new value becomes the reference even after a gap, so one lost frame counts once.
    pub fn observe(&mut self, counter: u64) -> CounterStatus {
        let counter = counter & self.mask;
        let status = match self.last {
            None => CounterStatus::First,
            Some(prev) => {
                let expected = prev.wrapping_add(1) & self.mask;
                if counter == expected {
                    CounterStatus::InSequence
                } else {
                    self.gaps += 1;
                    CounterStatus::Gap {
                        expected,
                        got: counter,
                    }
                }
            }
        };
        self.last = Some(counter);
        status
    }

    /// Number of gaps seen so far.
    pub fn gaps(&self) -> u64 {
        self.gaps
    }

    /// Forget the last value (e.g. after a bus-off), keeping the gap count.
    pub fn reset(&mut self) {
        self.last = None;
    }

    /// The value to send after `counter` (for encoding frames).
    pub fn next_value(&self, counter: u64) -> u64 {
        counter.wrapping_add(1) & self.mask
    }
}

/// The checksum algorithms met on production cars.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ChecksumAlgorithm {
    /// CRC-8 SAE J1850: poly 0x1D, init 0xFF, xor-out 0xFF, not reflected.
    Crc8SaeJ1850,
    /// Any non-reflected CRC-8 (MSB first): `poly`, `init`, `xor_out`. AUTOSAR's
    /// 0x2F/0xFF/0xFF fits; per-message "magic" bytes are the caller's (append them to
    /// the covered bytes by computing over a copy).
    Crc8 {
        /// Generator polynomial without the x^8 term.
        poly: u8,
        /// Register value before the first byte.
        init: u8,
        /// Value XORed into the register at the end.
        xor_out: u8,
    },
    /// Sum of the covered bytes plus `init`, modulo 256.
    Sum {
        /// Starting value of the sum.
        init: u8,
    },
    /// XOR of the covered bytes and `init`.
    Xor {
        /// Starting value of the XOR.
        init: u8,
    },
}

/// A checksum over a byte range of the payload, stored in one byte of the payload.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Checksum {
    algorithm: ChecksumAlgorithm,
    covered: RangeInclusive<usize>,
    position: usize,
    /// 256-entry table for the configurable CRC, built once: the `crc` crate needs a
    /// `&'static` algorithm, which a poly known only at run time (from config) cannot be
    /// without leaking memory.
    table: Option<Box<[u8; 256]>>,
    /// For a CRC-8 over at most [`CLASSIC_BYTES`] bytes (every classic CAN frame):
    /// see [`ByPosition`].
    by_position: Option<Box<ByPosition>>,
}

/// Most covered bytes [`ByPosition`] serves: a classic CAN payload.
const CLASSIC_BYTES: usize = 8;

/// A CRC-8 over a fixed number of bytes as independent table look-ups, one
/// per byte position, XORed together: a CRC is linear, so each byte's share
/// of the result is a function of that byte and its distance from the end
/// alone. The byte-wise loop chains every look-up on the one before (a
/// receiver's 7-byte CRC was a third of its per-frame time, perf); these
/// run side by side.
///
/// Positions past the covered length have all-zero tables, so eight bytes
/// from the first covered one can be read as one word whatever follows the
/// covered bytes (the stored checksum, other signals).
#[derive(Clone, Debug, PartialEq, Eq)]
struct ByPosition {
    /// `tables[i][b]`: the share of byte value `b` at position `i`.
    tables: [[u8; 256]; CLASSIC_BYTES],
    /// The share of the initial register and the final XOR.
    constant: u8,
}

impl ByPosition {
    /// For `len` bytes (1..=8) of the CRC-8 with byte-wise table `table`.
    fn new(table: &[u8; 256], init: u8, xor_out: u8, len: usize) -> Self {
        // `later[k][b]`: the register after byte `b` then `k` zero bytes, from 0.
        let mut later = [[0u8; 256]; CLASSIC_BYTES];
        later[0] = *table;
        for k in 1..CLASSIC_BYTES {
            for b in 0..256 {
                later[k][b] = table[usize::from(later[k - 1][b])];
            }
        }
        let mut tables = [[0u8; 256]; CLASSIC_BYTES];
        for (i, position) in tables.iter_mut().take(len).enumerate() {
            *position = later[len - 1 - i];
        }
        Self {
            tables,
            constant: later[len - 1][usize::from(init)] ^ xor_out,
        }
    }

    /// The CRC of the covered bytes, which `bytes` starts with.
    #[inline]
    fn checksum(&self, bytes: &[u8]) -> u8 {
        if let Some(word) = bytes.first_chunk::<CLASSIC_BYTES>() {
            // The common case: a fixed eight look-ups the compiler unrolls.
            let mut r = self.constant;
            for (table, &b) in self.tables.iter().zip(word) {
                r ^= table[usize::from(b)];
            }
            return r;
        }
        bytes
            .iter()
            .zip(&self.tables)
            .fold(self.constant, |r, (&b, table)| r ^ table[usize::from(b)])
    }
}

/// A static, not a const: the table inside is then one object in memory that
/// [`Checksum`] reads from, not a 256-byte temporary per use.
static J1850: crc::Crc<u8> = crc::Crc::<u8>::new(&crc::CRC_8_SAE_J1850);

/// A non-reflected byte-wise table CRC-8 over `bytes` (the catalogue J1850
/// and the configurable ones share it).
#[inline]
fn crc8(table: &[u8; 256], init: u8, xor_out: u8, bytes: &[u8]) -> u8 {
    bytes.iter().fold(init, |r, &b| table[usize::from(r ^ b)]) ^ xor_out
}

impl Checksum {
    /// A checksum of `algorithm` over payload bytes `covered`, stored in byte `position`.
    ///
    /// # Errors
    /// [`Error::InvalidCheck`] if the range is empty, or contains the checksum byte.
    pub fn new(
        algorithm: ChecksumAlgorithm,
        covered: RangeInclusive<usize>,
        position: usize,
    ) -> Result<Self> {
        if covered.is_empty() {
            return Err(Error::InvalidCheck(format!(
                "checksum over the empty byte range {covered:?}"
            )));
        }
        if covered.contains(&position) {
            return Err(Error::InvalidCheck(format!(
                "checksum byte {position} lies inside the bytes it covers {covered:?}"
            )));
        }
        let table = match algorithm {
            ChecksumAlgorithm::Crc8 { poly, .. } => Some(Box::new(crc8_table(poly))),
            _ => None,
        };
        let len = covered.clone().count();
        let by_position = match (&algorithm, len <= CLASSIC_BYTES) {
            (ChecksumAlgorithm::Crc8SaeJ1850, true) => {
                let a = J1850.algorithm;
                Some(ByPosition::new(&J1850.table()[0], a.init, a.xorout, len))
            }
            (ChecksumAlgorithm::Crc8 { init, xor_out, .. }, true) => table
                .as_deref()
                .map(|t| ByPosition::new(t, *init, *xor_out, len)),
            _ => None,
        };
        Ok(Self {
            algorithm,
            covered,
            position,
            table,
            by_position: by_position.map(Box::new),
        })
    }

    /// CRC-8 SAE J1850 over bytes `0..=6`, stored in byte 7: the layout of `rc_car.dbc`.
    pub fn rc_car() -> Self {
        // A valid layout by construction: the range is not empty and excludes byte 7.
        match Self::new(ChecksumAlgorithm::Crc8SaeJ1850, 0..=6, 7) {
            Ok(checksum) => checksum,
            Err(_) => unreachable!("0..=6 stored in byte 7 is a valid checksum layout"),
        }
    }

    /// Smallest payload length the checksum needs.
    pub fn needed_length(&self) -> usize {
        (*self.covered.end()).max(self.position) + 1
    }

    /// The checksum of `data`'s covered bytes.
    ///
    /// # Errors
    /// [`Error::InvalidCheck`] if `data` is too short for the covered bytes or the checksum
    /// byte (never reads past the end).
    #[inline]
    pub fn compute(&self, data: &[u8]) -> Result<u8> {
        self.computed_and_stored(data)
            .map(|(computed, _)| computed)
            .ok_or_else(|| self.too_short(data.len()))
    }

    /// Whether the stored checksum byte matches.
    ///
    /// # Errors
    /// As [`Self::compute`].
    #[inline]
    pub fn verify(&self, data: &[u8]) -> Result<bool> {
        self.computed_and_stored(data)
            .map(|(computed, stored)| computed == stored)
            .ok_or_else(|| self.too_short(data.len()))
    }

    /// Whether `data` holds the checksum byte and it matches: [`Self::verify`]
    /// for receivers, which reject a short frame the same as a bad one,
    /// without building the error (a `Result` with a message went through
    /// memory on every frame).
    // Inlined into a receiver's per-frame loop: the checks around the CRC
    // cost as much as the CRC of 7 bytes itself when called.
    #[inline]
    pub fn is_valid(&self, data: &[u8]) -> bool {
        self.computed_and_stored(data)
            .is_some_and(|(computed, stored)| computed == stored)
    }

    /// The checksum of `data`'s covered bytes and the byte stored for it;
    /// `None` when `data` is too short for either.
    // `always`: as a call of its own the receivers' check cost 0.7 % more
    // replay instructions (callgrind) than with the body in `is_valid`.
    #[allow(clippy::inline_always)]
    #[inline(always)]
    fn computed_and_stored(&self, data: &[u8]) -> Option<(u8, u8)> {
        let bytes = data.get(*self.covered.start()..=*self.covered.end())?;
        let &stored = data.get(self.position)?;
        Some((self.checksum_of(data, bytes), stored))
    }

    /// The checksum of `bytes`, the covered part of `data`.
    #[inline]
    fn checksum_of(&self, data: &[u8], bytes: &[u8]) -> u8 {
        if let Some(by_position) = &self.by_position {
            // From the first covered byte on: whatever lies past the covered
            // ones has no share (see `ByPosition`).
            return by_position.checksum(&data[*self.covered.start()..]);
        }
        match &self.algorithm {
            ChecksumAlgorithm::Crc8SaeJ1850 => {
                let a = J1850.algorithm;
                crc8(&J1850.table()[0], a.init, a.xorout, bytes)
            }
            ChecksumAlgorithm::Crc8 { init, xor_out, .. } => {
                let table = self.table.as_deref().map_or(&[0u8; 256], |t| t);
                crc8(table, *init, *xor_out, bytes)
            }
            ChecksumAlgorithm::Sum { init } => bytes.iter().fold(*init, |a, &b| a.wrapping_add(b)),
            ChecksumAlgorithm::Xor { init } => bytes.iter().fold(*init, |a, &b| a ^ b),
        }
    }

    #[cold]
    fn too_short(&self, len: usize) -> Error {
        Error::InvalidCheck(format!(
            "frame of {len} bytes is too short for a checksum over {:?} stored in byte {}",
            self.covered, self.position
        ))
    }

    /// Compute and store the checksum (for encoding frames).
    ///
    /// # Errors
    /// As [`Self::compute`].
    pub fn apply(&self, data: &mut [u8]) -> Result<()> {
        data[self.position] = self.compute(data)?;
        Ok(())
    }
}

/// Byte-wise table of a non-reflected CRC-8.
///
/// Kept beside the `crc` crate (issue #21), which serves the catalogue J1850
/// above: `crc::Crc::new` takes a `&'static Algorithm`, which a poly read
/// from config at run time can only be by leaking it, and the crate's
/// per-frame check is slower than the position tables built from this one.
/// Verifying a 7-byte CRC-8 (poly 0x2F) in an 8-byte frame: ours
/// ([`Checksum::is_valid`]) 6.0 ns, `Crc<u8, Table<1>>` 10.7 ns,
/// `Table<16>` 21.3 ns, `NoTable` 125 ns; set-up once per checksum 2.2 µs
/// against 0.17 µs (`Table<1>`) and 4.9 µs (`Table<16>`) (`cargo bench -p
/// canodom-can --bench checksum`, 2 shared cores under load ≈ 13). The test
/// `crc8_table_is_the_crc_crates_table` holds it to the crate's table for
/// every poly.
pub(crate) fn crc8_table(poly: u8) -> [u8; 256] {
    let mut table = [0u8; 256];
    for (i, entry) in table.iter_mut().enumerate() {
        let mut r = i as u8;
        for _ in 0..8 {
            r = if r & 0x80 != 0 {
                (r << 1) ^ poly
            } else {
                r << 1
            };
        }
        *entry = r;
    }
    table
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn j1850_check_value() {
        // The catalogue check value of CRC-8/SAE-J1850 over "123456789" is 0x4B.
        let c = Checksum::new(ChecksumAlgorithm::Crc8SaeJ1850, 0..=8, 9).unwrap();
        let mut d = *b"123456789\0";
        c.apply(&mut d).unwrap();
        assert_eq!(d[9], 0x4B);
        assert!(c.verify(&d).unwrap() && c.is_valid(&d));
        d[3] ^= 0x10;
        assert!(!c.verify(&d).unwrap() && !c.is_valid(&d));
        assert!(!c.is_valid(&d[..9]), "too short for the checksum byte");
    }

    #[test]
    fn configurable_crc_matches_catalogue() {
        let j = Checksum::new(
            ChecksumAlgorithm::Crc8 {
                poly: 0x1D,
                init: 0xFF,
                xor_out: 0xFF,
            },
            0..=8,
            9,
        )
        .unwrap();
        // Over 9 bytes there are no position tables: the byte-wise loop serves.
        assert!(j.by_position.is_none());
        assert_eq!(j.compute(b"123456789\0").unwrap(), 0x4B);
        // AUTOSAR CRC-8/H2F (poly 0x2F): check value 0xDF.
        let a = Checksum::new(
            ChecksumAlgorithm::Crc8 {
                poly: 0x2F,
                init: 0xFF,
                xor_out: 0xFF,
            },
            0..=8,
            9,
        )
        .unwrap();
        assert_eq!(a.compute(b"123456789\0").unwrap(), 0xDF);
        // Same bytes, different layout: checksum first, data after.
        let first = Checksum::new(ChecksumAlgorithm::Crc8SaeJ1850, 1..=9, 0).unwrap();
        assert_eq!(first.compute(b"\x00123456789").unwrap(), 0x4B);
    }

    #[test]
    fn j1850_table_fold_matches_the_crc_crate() {
        // `crc8` with the crate's table must be the crate's own checksum
        // (J1850 is not reflected, so the plain byte-wise fold applies).
        assert!(!J1850.algorithm.refin && !J1850.algorithm.refout);
        let c = Checksum::new(ChecksumAlgorithm::Crc8SaeJ1850, 0..=6, 7).unwrap();
        assert!(
            c.by_position.is_some(),
            "7 bytes: the position tables serve"
        );
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        for _ in 0..10_000 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let data = state.to_le_bytes();
            assert_eq!(c.compute(&data).unwrap(), J1850.checksum(&data[..7]));
        }
    }

    #[test]
    fn crc8_table_is_the_crc_crates_table() {
        // The crate as an oracle for every poly; leaking 256 small
        // algorithms is fine in a test (see `crc8_table` for why the
        // library does not).
        for poly in 0..=u8::MAX {
            let algorithm: &'static crc::Algorithm<u8> = Box::leak(Box::new(crc::Algorithm {
                poly,
                ..crc::CRC_8_SAE_J1850
            }));
            let theirs = crc::Crc::<u8, crc::Table<1>>::new(algorithm);
            assert_eq!(crc8_table(poly), theirs.table()[0], "poly {poly:#04x}");
        }
    }

    proptest::proptest! {
        /// The by-position look-ups are the byte-wise CRC, for every CRC-8,
        /// covered length and payload.
        #[test]
        fn by_position_equals_the_byte_wise_crc(
            poly: u8,
            init: u8,
            xor_out: u8,
            data in proptest::collection::vec(proptest::prelude::any::<u8>(), 1..=CLASSIC_BYTES),
            after in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..=CLASSIC_BYTES),
        ) {
            let table = crc8_table(poly);
            let by_position = ByPosition::new(&table, init, xor_out, data.len());
            // Bytes after the covered ones (the stored CRC, other signals)
            // must not change it, whether the word or the loop reads them.
            let with_after = [data.as_slice(), after.as_slice()].concat();
            let expected = crc8(&table, init, xor_out, &data);
            proptest::prop_assert_eq!(by_position.checksum(&data), expected);
            proptest::prop_assert_eq!(by_position.checksum(&with_after), expected);
        }
    }

    #[test]
    fn sum_and_xor() {
        let s = Checksum::new(ChecksumAlgorithm::Sum { init: 0 }, 0..=2, 3).unwrap();
        assert_eq!(s.compute(&[0xF0, 0x20, 0x01, 0]).unwrap(), 0x11);
        let x = Checksum::new(ChecksumAlgorithm::Xor { init: 0xFF }, 0..=2, 3).unwrap();
        assert_eq!(
            x.compute(&[0xF0, 0x20, 0x01, 0]).unwrap(),
            0xFF ^ 0xF0 ^ 0x20 ^ 0x01
        );
    }

    #[test]
    fn short_frames_and_bad_layouts_are_errors() {
        let c = Checksum::rc_car();
        let e = c.compute(&[0; 7]).unwrap_err().to_string();
        assert!(e.contains("7 bytes is too short"), "{e}");
        let e = Checksum::new(ChecksumAlgorithm::Xor { init: 0 }, 0..=7, 7)
            .unwrap_err()
            .to_string();
        assert!(e.contains("byte 7 lies inside"), "{e}");
        #[allow(clippy::reversed_empty_ranges)]
        let e = Checksum::new(ChecksumAlgorithm::Xor { init: 0 }, 5..=2, 7)
            .unwrap_err()
            .to_string();
        assert!(e.contains("empty byte range"), "{e}");
    }

    #[test]
    fn counter_wraps_and_counts_gaps() {
        let mut c = CounterCheck::new(4).unwrap();
        assert_eq!(c.observe(14), CounterStatus::First);
        assert_eq!(c.observe(15), CounterStatus::InSequence);
        assert_eq!(c.observe(0), CounterStatus::InSequence);
        assert_eq!(
            c.observe(2),
            CounterStatus::Gap {
                expected: 1,
                got: 2
            }
        );
        assert_eq!(c.observe(3), CounterStatus::InSequence);
        assert_eq!(
            c.observe(3),
            CounterStatus::Gap {
                expected: 4,
                got: 3
            }
        );
        assert_eq!(c.gaps(), 2);
        assert_eq!(c.next_value(15), 0);
        c.reset();
        assert_eq!(c.observe(9), CounterStatus::First);
        let e = CounterCheck::new(0).unwrap_err().to_string();
        assert!(e.contains("0 bits"), "{e}");
        assert!(CounterCheck::new(65).is_err());
        let mut wide = CounterCheck::new(64).unwrap();
        wide.observe(u64::MAX);
        assert_eq!(wide.observe(0), CounterStatus::InSequence);
    }
}
