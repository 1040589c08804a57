//! Where a signal's bits sit in the payload, precomputed once so that extracting or
//! inserting a value is a handful of shifts over at most nine bytes.
//!
//! DBC conventions: an Intel (little-endian, `@1`) signal's `start_bit` is its least
//! significant bit, numbered `byte * 8 + bit` with bit 0 the byte's LSB. A Motorola
//! (big-endian, `@0`) signal's `start_bit` is its *most* significant bit in the same
//! numbering, and the signal continues towards lower bits of that byte, then into the MSB
//! of the next byte (the "sawtooth"). Both are mapped here to a contiguous run of bytes
//! read as one little- or big-endian integer, then shifted and masked.

/// Byte order of a signal, in DBC vocabulary.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ByteOrder {
    /// Intel, `@1` in DBC: `start_bit` is the least significant bit.
    LittleEndian,
    /// Motorola, `@0` in DBC: `start_bit` is the most significant bit (sawtooth numbering).
    BigEndian,
}

/// A compiled bit position: byte run plus shift and mask.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct BitLayout {
    /// First byte of the run the signal touches.
    byte_lo: u8,
    /// Number of bytes in the run (1..=9).
    n_bytes: u8,
    /// Right shift that brings the signal's LSB to bit 0 of the run integer.
    shift: u8,
    /// Signal size in bits (1..=64).
    size: u8,
    /// Byte order of the run integer.
    big_endian: bool,
    /// Fast path: the run lies inside the 8-byte window starting at `window`, which lies
    /// inside the message, so one unaligned 64-bit load plus shift and mask extracts it.
    fast: bool,
    window: u8,
    /// Right shift of the signal's LSB within the 64-bit window.
    window_shift: u8,
}

/// Why a layout cannot be built; the caller adds message and signal names.
#[derive(Debug, PartialEq, Eq)]
pub(crate) enum LayoutError {
    BadSize(u64),
    PastEnd { last_byte: u64, length: u64 },
}

impl std::fmt::Display for LayoutError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::BadSize(s) => write!(f, "size {s} bits is not within 1..=64"),
            // "needs N bytes", not a byte index: an index leaves the reader guessing whether
            // it counts from 0 or 1.
            Self::PastEnd { last_byte, length } => write!(
                f,
                "needs {} bytes but the message is only {length} bytes long",
                last_byte + 1
            ),
        }
    }
}

impl BitLayout {
    /// Compile a DBC `start_bit|size@byte_order` against a message `length` in bytes.
    pub(crate) fn new(
        start_bit: u64,
        size: u64,
        order: ByteOrder,
        length: u64,
    ) -> Result<Self, LayoutError> {
        if size == 0 || size > 64 {
            return Err(LayoutError::BadSize(size));
        }
        // Work in a linear numbering where the run is [first, first + size).
        let (first, big_endian) = match order {
            ByteOrder::LittleEndian => (start_bit, false),
            // Motorola: map the MSB to "big-endian linear" index (bit 7 of byte 0 is 0).
            ByteOrder::BigEndian => ((start_bit / 8) * 8 + (7 - start_bit % 8), true),
        };
        let last = first.saturating_add(size - 1);
        let byte_lo = first / 8;
        let byte_hi = last / 8;
        if byte_hi >= length {
            return Err(LayoutError::PastEnd {
                last_byte: byte_hi,
                length,
            });
        }
        let n_bytes = byte_hi - byte_lo + 1;
        let shift = if big_endian {
            n_bytes * 8 - (first % 8) - size
        } else {
            first % 8
        };
        // A window of 8 bytes holding the run: it starts at the run's first byte, or as
        // late as the message allows.
        let hi = byte_hi + 1;
        let (fast, window, window_shift) = if n_bytes <= 8 && length >= 8 {
            let w = byte_lo.min(length - 8);
            let ws = if big_endian {
                8 * (w + 8 - hi) + shift
            } else {
                8 * (byte_lo - w) + shift
            };
            (true, w, ws)
        } else {
            (false, 0, 0)
        };
        // length <= 64 is checked by the caller, so every field fits a u8.
        Ok(Self {
            byte_lo: byte_lo as u8,
            n_bytes: n_bytes as u8,
            shift: shift as u8,
            size: size as u8,
            big_endian,
            fast,
            window: window as u8,
            window_shift: window_shift as u8,
        })
    }

    /// Size of the signal in bits.
    pub(crate) fn size(self) -> u32 {
        u32::from(self.size)
    }

    fn mask(self) -> u128 {
        (1u128 << self.size) - 1
    }

    /// The signal's raw bits, zero-extended; `None` if `data` is too short to hold them.
    #[inline]
    pub(crate) fn extract(self, data: &[u8]) -> Option<u64> {
        if self.fast {
            let w = usize::from(self.window);
            let bytes: [u8; 8] = data.get(w..w + 8)?.try_into().ok()?;
            let x = if self.big_endian {
                u64::from_be_bytes(bytes)
            } else {
                u64::from_le_bytes(bytes)
            };
            return Some((x >> self.window_shift) & (u64::MAX >> (64 - u32::from(self.size))));
        }
        self.extract_slow(data)
    }

    /// Any run, through a 128-bit accumulator (runs of 9 bytes, messages under 8 bytes).
    fn extract_slow(self, data: &[u8]) -> Option<u64> {
        let lo = usize::from(self.byte_lo);
        let run = data.get(lo..lo + usize::from(self.n_bytes))?;
        let acc = if self.big_endian {
            run.iter().fold(0u128, |acc, &b| (acc << 8) | u128::from(b))
        } else {
            run.iter()
                .rev()
                .fold(0u128, |acc, &b| (acc << 8) | u128::from(b))
        };
        Some(((acc >> self.shift) & self.mask()) as u64)
    }

    /// Write the low `size` bits of `raw` into `data`, leaving every other bit untouched.
    /// Returns `false` (and writes nothing) if `data` is too short.
    #[inline]
    pub(crate) fn insert(self, data: &mut [u8], raw: u64) -> bool {
        let lo = usize::from(self.byte_lo);
        let n = usize::from(self.n_bytes);
        let Some(run) = data.get_mut(lo..lo + n) else {
            return false;
        };
        let field_mask = self.mask() << self.shift;
        let field = ((u128::from(raw)) << self.shift) & field_mask;
        for (i, byte) in run.iter_mut().enumerate() {
            // Byte i of the run holds bits 8*k..8*k+8 of the run integer.
            let k = if self.big_endian { n - 1 - i } else { i };
            let m = (field_mask >> (8 * k)) as u8;
            let v = (field >> (8 * k)) as u8;
            *byte = (*byte & !m) | (v & m);
        }
        true
    }

    /// Set, in `mask`, every bit this signal occupies.
    pub(crate) fn or_mask(self, mask: &mut [u8]) {
        let mut ones = [0u8; 64];
        if self.insert(&mut ones, u64::MAX) {
            for (m, o) in mask.iter_mut().zip(ones.iter()) {
                *m |= *o;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn intel_byte_aligned_is_little_endian() {
        let l = BitLayout::new(0, 16, ByteOrder::LittleEndian, 8).unwrap();
        assert_eq!(l.extract(&[0x34, 0x12, 0, 0, 0, 0, 0, 0]), Some(0x1234));
    }

    #[test]
    fn motorola_msb_start_bit_is_big_endian() {
        // rc_car WHEEL_ENC_FRONT FL_TICKS: 7|16@0+ covers bytes 0 and 1, byte 0 most significant.
        let l = BitLayout::new(7, 16, ByteOrder::BigEndian, 8).unwrap();
        assert_eq!(l.extract(&[0x12, 0x34, 0, 0, 0, 0, 0, 0]), Some(0x1234));
        // COUNTER 51|4@0+: bits 51..48, the high nibble's low part of byte 6.
        let c = BitLayout::new(51, 4, ByteOrder::BigEndian, 8).unwrap();
        assert_eq!(c.extract(&[0, 0, 0, 0, 0, 0, 0x0A, 0]), Some(0xA));
    }

    #[test]
    fn motorola_sawtooth_crosses_bytes() {
        // Start at bit 3 of byte 0, 12 bits: byte0 bits 3..0 then all of byte 1.
        let l = BitLayout::new(3, 12, ByteOrder::BigEndian, 2).unwrap();
        assert_eq!(l.extract(&[0xFA, 0xBC]), Some(0xABC));
        let mut d = [0xF0, 0x00];
        assert!(l.insert(&mut d, 0x123));
        assert_eq!(d, [0xF1, 0x23]);
    }

    #[test]
    fn sixty_four_bits_unaligned_span_nine_bytes() {
        let l = BitLayout::new(4, 64, ByteOrder::LittleEndian, 9).unwrap();
        let mut d = [0u8; 9];
        assert!(l.insert(&mut d, 0x0123_4567_89AB_CDEF));
        assert_eq!(l.extract(&d), Some(0x0123_4567_89AB_CDEF));
        assert_eq!(d[0] & 0x0F, 0);
        assert_eq!(d[8] & 0xF0, 0);
    }

    #[test]
    fn bad_layouts_are_rejected() {
        assert_eq!(
            BitLayout::new(0, 0, ByteOrder::LittleEndian, 8),
            Err(LayoutError::BadSize(0))
        );
        assert_eq!(
            BitLayout::new(0, 65, ByteOrder::LittleEndian, 9),
            Err(LayoutError::BadSize(65))
        );
        assert!(matches!(
            BitLayout::new(60, 8, ByteOrder::LittleEndian, 8),
            Err(LayoutError::PastEnd { .. })
        ));
        // Motorola start bit 7 of byte 7 with 9 bits needs a 9th byte.
        assert!(matches!(
            BitLayout::new(63, 9, ByteOrder::BigEndian, 8),
            Err(LayoutError::PastEnd { .. })
        ));
    }

    #[test]
    fn fast_window_agrees_with_the_byte_loop() {
        let mut x = 0x1234_5678_9ABC_DEF0_u64;
        let mut data = [0u8; 64];
        for b in &mut data {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            *b = x as u8;
        }
        let mut checked = 0;
        for length in [8u64, 12, 64] {
            for size in 1..=64 {
                for start in 0..length * 8 {
                    for order in [ByteOrder::LittleEndian, ByteOrder::BigEndian] {
                        if let Ok(l) = BitLayout::new(start, size, order, length) {
                            let d = &data[..length as usize];
                            assert_eq!(l.extract(d), l.extract_slow(d), "{start}|{size} {order:?}");
                            checked += u32::from(l.fast);
                        }
                    }
                }
            }
        }
        assert!(checked > 10_000);
    }

    #[test]
    fn short_data_is_none_not_a_panic() {
        let l = BitLayout::new(56, 8, ByteOrder::LittleEndian, 8).unwrap();
        assert_eq!(l.extract(&[0; 7]), None);
        assert!(!l.insert(&mut [0; 7], 1));
    }
}
