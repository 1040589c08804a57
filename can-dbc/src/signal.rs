//! A compiled signal: bit layout, value type and scaling, plus its DBC metadata, and the
//! small `Copy` [`SignalHandle`] the daemon keeps for the few signals it reads or writes.
//!
//! Scaling follows cantools' `BaseConversion.factory` exactly, so decoded values are
//! bit-identical to cantools': `scale == 1 && offset == 0` returns the raw value as is,
//! integer `scale`/`offset` on an integer signal are applied in exact integer arithmetic
//! (here `i128`, rounded once to `f64`), anything else is `raw * factor + offset` in `f64`
//! (two roundings, never a fused multiply-add).

use crate::error::{Error, Result};
use crate::layout::BitLayout;

pub use crate::layout::ByteOrder;

/// How the raw bits are interpreted (`+`/`-` in `SG_`, or `SIG_VALTYPE_`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ValueType {
    /// Unsigned integer (`+`).
    Unsigned,
    /// Two's-complement signed integer (`-`).
    Signed,
    /// IEEE 754 single (`SIG_VALTYPE_ … : 1`), 32 bits.
    Float32,
    /// IEEE 754 double (`SIG_VALTYPE_ … : 2`), 64 bits.
    Float64,
}

/// A decoded physical value, typed as cantools types it: a Python `int` for an integer
/// signal whose factor and offset are whole numbers, else a `float`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Value {
    /// Integer raw value, whole factor and offset: exact at any size (64-bit raw values
    /// times a factor can exceed `i64`, hence `i128`).
    Integer(i128),
    /// Any other value, bit-identical to cantools' `float`.
    Float(f64),
}

impl Value {
    /// The value as an `f64` (what [`crate::Message::decode`] gives; rounded past 2^53).
    pub fn as_f64(self) -> f64 {
        match self {
            Self::Integer(i) => i as f64,
            Self::Float(f) => f,
        }
    }
}

impl std::fmt::Display for Value {
    /// Integers in full, floats as `{}` writes an `f64`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Integer(i) => write!(f, "{i}"),
            Self::Float(x) => write!(f, "{x}"),
        }
    }
}

/// The three cantools conversions, chosen once at compile time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Scaling {
    /// `factor == 1`, `offset == 0`: the raw value itself.
    Identity,
    /// Integer factor and offset whose products stay below 2^53, so `f64` is exact.
    Linear { factor: f64, offset: f64 },
    /// Integer factor and offset where `f64` might round: exact in `i128`.
    Integer { factor: i64, offset: i64 },
}

/// The decode path, flattened so `raw_to_scaled` is a single match: integer signals with
/// identity scaling use `raw * 1.0 + 0.0`, which is exact for every integer `f64` holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum DecodeKind {
    Unsigned,
    Signed,
    UnsignedExact,
    SignedExact,
    Float32,
    Float64,
}

/// Everything needed to go between bits and physical values; `Copy` so handles can hold it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Codec {
    pub(crate) layout: BitLayout,
    pub(crate) value_type: ValueType,
    kind: DecodeKind,
    /// Factor and offset of the `f64` path (1 and 0 for identity).
    mul: f64,
    add: f64,
    pub(crate) scaling: Scaling,
    pub(crate) factor: f64,
    pub(crate) offset: f64,
    /// Whether every value is a [`Value::Integer`]: an integer signal whose factor and
    /// offset are whole numbers. Judged once here, not per value (the `fract` checks were
    /// 2 % of decoding a log to Arrow, python/bench/decode_vs_cantools.py).
    integer_valued: bool,
}

const TWO_POW_53: f64 = 9_007_199_254_740_992.0;

impl Codec {
    pub(crate) fn new(layout: BitLayout, value_type: ValueType, factor: f64, offset: f64) -> Self {
        let is_int = |x: f64| x.is_finite() && x.fract() == 0.0 && x.abs() < 9.2e18;
        let integer_valued = matches!(value_type, ValueType::Unsigned | ValueType::Signed)
            && is_int(factor)
            && is_int(offset);
        let scaling = if factor == 1.0 && offset == 0.0 {
            Scaling::Identity
        } else if integer_valued {
            // Largest |raw| the signal can hold, as f64 (exact: a power of two).
            let raw_max = 2f64.powi(layout.size() as i32);
            if raw_max * factor.abs() + offset.abs() < TWO_POW_53 {
                Scaling::Linear { factor, offset }
            } else {
                Scaling::Integer {
                    factor: factor as i64,
                    offset: offset as i64,
                }
            }
        } else {
            Scaling::Linear { factor, offset }
        };
        let kind = match (value_type, scaling) {
            (ValueType::Unsigned, Scaling::Integer { .. }) => DecodeKind::UnsignedExact,
            (ValueType::Signed, Scaling::Integer { .. }) => DecodeKind::SignedExact,
            (ValueType::Unsigned, _) => DecodeKind::Unsigned,
            (ValueType::Signed, _) => DecodeKind::Signed,
            (ValueType::Float32, _) => DecodeKind::Float32,
            (ValueType::Float64, _) => DecodeKind::Float64,
        };
        let (mul, add) = match scaling {
            Scaling::Linear { factor, offset } => (factor, offset),
            _ => (1.0, 0.0),
        };
        Self {
            layout,
            value_type,
            kind,
            mul,
            add,
            scaling,
            factor,
            offset,
            integer_valued,
        }
    }

    /// Raw bits of the signal in `data`, zero-extended (`None` if `data` is too short).
    #[inline]
    pub(crate) fn raw_bits(&self, data: &[u8]) -> Option<u64> {
        self.layout.extract(data)
    }

    /// The raw value as a signed integer if the signal is signed, else as unsigned.
    #[inline]
    fn signed(&self, bits: u64) -> i64 {
        let unused = 64 - self.layout.size();
        ((bits << unused) as i64) >> unused
    }

    /// The physical value of raw `bits` (cantools `raw_to_scaled`).
    #[inline]
    pub(crate) fn raw_to_scaled(&self, bits: u64) -> f64 {
        match self.kind {
            DecodeKind::Unsigned => bits as f64 * self.mul + self.add,
            DecodeKind::Signed => self.signed(bits) as f64 * self.mul + self.add,
            DecodeKind::UnsignedExact | DecodeKind::SignedExact => {
                let Scaling::Integer { factor, offset } = self.scaling else {
                    return f64::NAN; // unreachable: kind follows scaling
                };
                let raw = if self.kind == DecodeKind::SignedExact {
                    i128::from(self.signed(bits))
                } else {
                    i128::from(bits)
                };
                (raw * i128::from(factor) + i128::from(offset)) as f64
            }
            // Floats keep identity exact: x * 1.0 + 0.0 would turn -0.0 into +0.0.
            DecodeKind::Float32 => self.scale_float(f64::from(f32::from_bits(bits as u32))),
            DecodeKind::Float64 => self.scale_float(f64::from_bits(bits)),
        }
    }

    /// The physical value of raw `bits`, exact when cantools' is a Python `int`: an
    /// integer signal whose factor and offset are whole numbers. Past 2^53 an `f64` cannot
    /// hold every such value (`3791054832379806569` would become `…6700`).
    #[inline]
    pub(crate) fn raw_to_value(&self, bits: u64) -> Value {
        if self.integer_valued {
            let raw = if self.value_type == ValueType::Signed {
                i128::from(self.signed(bits))
            } else {
                i128::from(bits)
            };
            // |raw| < 2^64 and |factor|, |offset| < 2^63: no overflow is possible, but the
            // checked form costs nothing and needs no argument.
            if let Some(v) = raw
                .checked_mul(i128::from(self.factor as i64))
                .and_then(|v| v.checked_add(i128::from(self.offset as i64)))
            {
                return Value::Integer(v);
            }
        }
        Value::Float(self.raw_to_scaled(bits))
    }

    #[inline]
    fn scale_float(&self, x: f64) -> f64 {
        match self.scaling {
            Scaling::Identity => x,
            _ => x * self.mul + self.add,
        }
    }

    /// The physical value in raw units, before rounding.
    fn unscaled(&self, value: f64) -> f64 {
        match self.scaling {
            Scaling::Identity => value,
            _ => (value - self.offset) / self.factor,
        }
    }

    /// Raw bits for a physical value (cantools `scaled_to_raw`, rounding half to even as
    /// Python's `round` does); `None` if the raw value does not fit the signal.
    pub(crate) fn scaled_to_raw(&self, value: f64) -> Option<u64> {
        let unscaled = self.unscaled(value);
        let size = self.layout.size();
        match self.value_type {
            ValueType::Float32 => {
                let f = unscaled as f32;
                // A finite value that overflows f32 would silently become infinity.
                if unscaled.is_finite() && !f.is_finite() {
                    return None;
                }
                Some(u64::from(f.to_bits()))
            }
            ValueType::Float64 => Some(unscaled.to_bits()),
            ValueType::Unsigned => {
                let r = unscaled.round_ties_even();
                // 2^size is exact in f64, so `<` is an exact bound even for 64 bits.
                (r >= 0.0 && r < 2f64.powi(size as i32)).then_some(r as u64)
            }
            ValueType::Signed => {
                let r = unscaled.round_ties_even();
                let half = 2f64.powi(size as i32 - 1);
                (r >= -half && r < half).then_some((r as i64) as u64 & raw_mask(size))
            }
        }
    }

    /// Raw bits for a physical value, saturated: a value beyond the signal's
    /// range gives the nearest end of it (judged in raw space, so a negative
    /// factor saturates the right way), NaN gives the raw value of physical 0
    /// (saturated in turn).
    pub(crate) fn scaled_to_raw_saturating(&self, value: f64) -> u64 {
        let value = if value.is_nan() { 0.0 } else { value };
        if let Some(raw) = self.scaled_to_raw(value) {
            return raw;
        }
        let below = self.unscaled(value) < 0.0;
        let mask = raw_mask(self.layout.size());
        match self.value_type {
            ValueType::Float32 => u64::from(if below { f32::MIN } else { f32::MAX }.to_bits()),
            // Every f64 fits: `scaled_to_raw` has already answered.
            ValueType::Float64 => self.unscaled(value).to_bits(),
            ValueType::Unsigned => {
                if below {
                    0
                } else {
                    mask
                }
            }
            // Two's complement: the minimum is the sign bit alone, the maximum every other bit.
            ValueType::Signed => {
                if below {
                    (mask >> 1) + 1
                } else {
                    mask >> 1
                }
            }
        }
    }

    /// Smallest and largest physical values the raw range can encode.
    pub(crate) fn scaled_range(&self) -> (f64, f64) {
        let size = self.layout.size();
        let (lo, hi) = match self.value_type {
            ValueType::Unsigned => (0.0, 2f64.powi(size as i32) - 1.0),
            ValueType::Signed => {
                let half = 2f64.powi(size as i32 - 1);
                (-half, half - 1.0)
            }
            ValueType::Float32 => (f64::from(f32::MIN), f64::from(f32::MAX)),
            ValueType::Float64 => (f64::MIN, f64::MAX),
        };
        let (a, b) = (
            lo * self.factor + self.offset,
            hi * self.factor + self.offset,
        );
        if a <= b { (a, b) } else { (b, a) }
    }
}

/// The low `size` bits set (`size` is 1 to 64).
fn raw_mask(size: u32) -> u64 {
    u64::MAX >> (64 - size)
}

/// Which multiplexor values select a multiplexed signal.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct MuxCondition {
    /// Index (in the message) of the multiplexor signal.
    pub(crate) multiplexor: usize,
    /// The multiplexor's slot in the per-frame multiplexor state (see `Message::decode`).
    pub(crate) slot: u8,
    /// Sorted, merged inclusive ranges of raw multiplexor values.
    pub(crate) ranges: Box<[(u64, u64)]>,
}

impl MuxCondition {
    #[inline]
    pub(crate) fn selects(&self, mux_raw: u64) -> bool {
        self.ranges
            .iter()
            .any(|&(lo, hi)| lo <= mux_raw && mux_raw <= hi)
    }
}

/// One signal of a compiled message, with its DBC metadata.
#[derive(Clone, Debug, PartialEq)]
pub struct Signal {
    pub(crate) name: String,
    pub(crate) short_name: String,
    pub(crate) index: usize,
    pub(crate) codec: Codec,
    pub(crate) start_bit: u64,
    pub(crate) byte_order: ByteOrder,
    pub(crate) min: f64,
    pub(crate) max: f64,
    pub(crate) unit: String,
    pub(crate) comment: Option<String>,
    pub(crate) value_descriptions: Vec<(i64, String)>,
    pub(crate) is_multiplexor: bool,
    pub(crate) mux: Option<MuxCondition>,
    pub(crate) receivers: Vec<String>,
}

impl Signal {
    /// Signal name as cantools gives it: the `SystemSignalLongSymbol` attribute if the DBC
    /// has one (names longer than 32 characters), else the `SG_` name.
    pub fn name(&self) -> &str {
        &self.name
    }
    /// The `SG_` name, at most 32 characters in files written by Vector tools.
    pub fn short_name(&self) -> &str {
        &self.short_name
    }
    /// Position of the signal in its message's [`crate::Message::signals`] (DBC order).
    pub fn index(&self) -> usize {
        self.index
    }
    /// DBC `start_bit` (LSB for Intel, MSB for Motorola).
    pub fn start_bit(&self) -> u64 {
        self.start_bit
    }
    /// Size in bits.
    pub fn size(&self) -> u32 {
        self.codec.layout.size()
    }
    /// DBC byte order.
    pub fn byte_order(&self) -> ByteOrder {
        self.byte_order
    }
    /// Integer signedness or IEEE float type.
    pub fn value_type(&self) -> ValueType {
        self.codec.value_type
    }
    /// DBC factor (physical = raw * factor + offset).
    pub fn factor(&self) -> f64 {
        self.codec.factor
    }
    /// DBC offset.
    pub fn offset(&self) -> f64 {
        self.codec.offset
    }
    /// DBC minimum physical value (informative: encoding only enforces the raw range).
    pub fn min(&self) -> f64 {
        self.min
    }
    /// DBC maximum physical value (informative, as `min`).
    pub fn max(&self) -> f64 {
        self.max
    }
    /// Physical unit, empty if none.
    pub fn unit(&self) -> &str {
        &self.unit
    }
    /// `CM_ SG_` comment.
    pub fn comment(&self) -> Option<&str> {
        self.comment.as_deref()
    }
    /// `VAL_` entries: raw value and its name.
    pub fn value_descriptions(&self) -> &[(i64, String)] {
        &self.value_descriptions
    }
    /// The `VAL_` name of a raw value, if any.
    pub fn value_name(&self, raw: i64) -> Option<&str> {
        self.value_descriptions
            .iter()
            .find(|(v, _)| *v == raw)
            .map(|(_, n)| n.as_str())
    }
    /// Whether this signal is a multiplexor (`M`).
    pub fn is_multiplexor(&self) -> bool {
        self.is_multiplexor
    }
    /// Whether this signal is only present for some multiplexor values (`m<n>`).
    pub fn is_multiplexed(&self) -> bool {
        self.mux.is_some()
    }
    /// Receiving nodes.
    pub fn receivers(&self) -> &[String] {
        &self.receivers
    }
    /// The least and greatest value [`Self::value`] can give, when every value it gives is
    /// a [`Value::Integer`] (an integer signal with whole factor and offset); `None` when
    /// the values are [`Value::Float`]s. Lets a caller choose a column type for the signal
    /// once, from the DBC, before any frame: `i64` holds every value of most signals, a
    /// 64-bit raw value times a factor may need more.
    pub fn integer_range(&self) -> Option<(i128, i128)> {
        let codec = &self.codec;
        if !codec.integer_valued {
            return None;
        }
        let size = codec.layout.size().clamp(1, 64);
        let (raw_min, raw_max) = if codec.value_type == ValueType::Signed {
            (-(1i128 << (size - 1)), (1i128 << (size - 1)) - 1)
        } else {
            (0, (1i128 << size) - 1)
        };
        // Whole factor and offset below 9.2e18 (integer_valued): exact as i64, and
        // |raw| < 2^64 times them stays far inside i128.
        let (factor, offset) = (
            i128::from(codec.factor as i64),
            i128::from(codec.offset as i64),
        );
        let (a, b) = (raw_min * factor + offset, raw_max * factor + offset);
        Some((a.min(b), a.max(b)))
    }
    /// Physical range the signal's raw bits can encode.
    pub fn encodable_range(&self) -> (f64, f64) {
        self.codec.scaled_range()
    }
    /// Physical value of raw bits (cantools `raw_to_scaled`); `raw` holds the signal's bits
    /// zero-extended (two's complement for signed, IEEE bits for floats).
    pub fn raw_to_scaled(&self, raw: u64) -> f64 {
        self.codec.raw_to_scaled(raw)
    }
    /// Physical value of raw bits, exact for integer signals with whole factor and offset
    /// (see [`Value`]).
    pub fn value(&self, raw: u64) -> Value {
        self.codec.raw_to_value(raw)
    }
    /// Raw bits for a physical value, rounded to the nearest raw (cantools `scaled_to_raw`).
    ///
    /// # Errors
    /// [`Error::OutOfRange`] if the raw value does not fit the signal (or is NaN).
    pub fn scaled_to_raw(&self, value: f64, message: &str) -> Result<u64> {
        self.codec.scaled_to_raw(value).ok_or_else(|| {
            let (min, max) = self.codec.scaled_range();
            Error::OutOfRange {
                message: message.to_owned(),
                signal: self.name.clone(),
                value,
                min,
                max,
            }
        })
    }
    /// Write raw bits (the low `size` bits of `raw`) into `data`, leaving other bits alone;
    /// `false` if `data` is too short. For signals wider than 53 bits, whose raw values an
    /// `f64` physical value cannot always carry.
    pub fn encode_raw(&self, raw: u64, data: &mut [u8]) -> bool {
        self.codec.layout.insert(data, raw)
    }
    /// Set in `mask` (at least as long as the message) every payload bit this signal occupies.
    pub fn or_bit_mask(&self, mask: &mut [u8]) {
        self.codec.layout.or_mask(mask);
    }
}

/// Largest number of multiplexor value ranges a [`SignalHandle`] can check inline.
pub const HANDLE_MAX_MUX_RANGES: usize = 4;

/// The multiplexor check carried by a handle of a multiplexed signal.
#[derive(Clone, Copy, Debug, PartialEq)]
struct HandleMux {
    layout: BitLayout,
    ranges: [(u64, u64); HANDLE_MAX_MUX_RANGES],
    n_ranges: u8,
}

/// A small `Copy` handle on one signal: decodes or encodes just that signal with
/// precomputed shifts and masks, without allocating. Obtain it with
/// [`crate::Database::signal`]`("MESSAGE.SIGNAL")`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SignalHandle {
    codec: Codec,
    /// The message's DBC length: shorter frames are rejected even if this signal's bytes
    /// happen to be present, because a short frame is a malformed frame.
    message_length: u8,
    /// The message's frame ID, so the caller can match frames to handles.
    frame_id: crate::FrameId,
    message_index: u32,
    signal_index: u32,
    mux: Option<HandleMux>,
}

impl SignalHandle {
    pub(crate) fn new(
        signal: &Signal,
        multiplexor: Option<&Signal>,
        message_length: u8,
        frame_id: crate::FrameId,
        message_index: usize,
    ) -> Option<Self> {
        let mux = match (&signal.mux, multiplexor) {
            (None, _) => None,
            (Some(cond), Some(m))
                if m.mux.is_none() && cond.ranges.len() <= HANDLE_MAX_MUX_RANGES =>
            {
                let mut ranges = [(1, 0); HANDLE_MAX_MUX_RANGES];
                ranges[..cond.ranges.len()].copy_from_slice(&cond.ranges);
                Some(HandleMux {
                    layout: m.codec.layout,
                    ranges,
                    n_ranges: cond.ranges.len() as u8,
                })
            }
            _ => return None,
        };
        Some(Self {
            codec: signal.codec,
            message_length,
            frame_id,
            message_index: message_index as u32,
            signal_index: signal.index as u32,
            mux,
        })
    }

    /// Frame ID of the message the signal belongs to.
    pub fn frame_id(&self) -> crate::FrameId {
        self.frame_id
    }
    /// Index of the message in [`crate::Database::messages`].
    pub fn message_index(&self) -> usize {
        self.message_index as usize
    }
    /// Index of the signal in its message's signals.
    pub fn signal_index(&self) -> usize {
        self.signal_index as usize
    }

    #[inline]
    fn check_len(&self, data: &[u8]) -> std::result::Result<(), (usize, usize)> {
        if data.len() < usize::from(self.message_length) {
            Err((usize::from(self.message_length), data.len()))
        } else {
            Ok(())
        }
    }

    /// Raw bits of the signal, or `None` if the frame is too short or a multiplexor value
    /// that does not select this signal. Allocation-free; see [`Self::decode`] for errors.
    // The multiplexed case lives apart so that this stays small enough to be
    // inlined into a receiver's per-frame loop (as a call it cost ~36
    // instructions per signal, a tenth of canodom's filter thread).
    #[inline]
    pub fn raw(&self, data: &[u8]) -> Option<u64> {
        self.check_len(data).ok()?;
        if self.mux.is_some() {
            return self.raw_multiplexed(data);
        }
        self.codec.raw_bits(data)
    }

    /// [`Self::raw`] of a multiplexed signal, length already checked.
    #[inline(never)]
    fn raw_multiplexed(&self, data: &[u8]) -> Option<u64> {
        if let Some(m) = &self.mux {
            let mux_raw = m.layout.extract(data)?;
            if !m.ranges[..usize::from(m.n_ranges)]
                .iter()
                .any(|&(lo, hi)| lo <= mux_raw && mux_raw <= hi)
            {
                return None;
            }
        }
        self.codec.raw_bits(data)
    }

    /// Physical value of the signal, or `None` if the frame is shorter than the message
    /// (a DLC fault) or carries another multiplexor value. Allocation-free, so the hot path
    /// can call it per frame; use [`Self::decode_checked`] to get the reason as an error.
    #[inline]
    pub fn decode(&self, data: &[u8]) -> Option<f64> {
        self.raw(data).map(|bits| self.codec.raw_to_scaled(bits))
    }

    /// As [`Self::decode`], but a short frame is an [`Error::ShortFrame`] naming the message
    /// (resolved through `db`); a non-selected multiplexed signal is `Ok(None)`.
    ///
    /// # Errors
    /// [`Error::ShortFrame`] if `data` is shorter than the message's length.
    pub fn decode_checked(&self, db: &crate::Database, data: &[u8]) -> Result<Option<f64>> {
        if let Err((expected, got)) = self.check_len(data) {
            return Err(Error::ShortFrame {
                message: db.messages()[self.message_index()].name().to_owned(),
                expected,
                got,
            });
        }
        Ok(self.decode(data))
    }

    /// Physical value of raw bits.
    #[inline]
    pub fn raw_to_scaled(&self, raw: u64) -> f64 {
        self.codec.raw_to_scaled(raw)
    }

    /// Raw bits for a physical value (round to nearest); `None` if it does not fit.
    #[inline]
    pub fn scaled_to_raw(&self, value: f64) -> Option<u64> {
        self.codec.scaled_to_raw(value)
    }

    /// Write the physical `value` into `data`, leaving every other bit untouched; does not
    /// touch the multiplexor. Returns `false` (writing nothing) if the value does not fit
    /// the signal's raw range or `data` is shorter than the message.
    #[inline]
    pub fn encode(&self, value: f64, data: &mut [u8]) -> bool {
        match self.codec.scaled_to_raw(value) {
            Some(raw) => self.encode_raw(raw, data),
            None => false,
        }
    }

    /// Write the physical `value` into `data`, or, when it does not fit, the
    /// nearest end of the signal's range (NaN as 0): for outputs that must
    /// always carry a value, such as a position far from the origin.
    /// `false` (writing nothing) only if `data` is shorter than the message.
    #[inline]
    pub fn encode_saturating(&self, value: f64, data: &mut [u8]) -> bool {
        self.encode_raw(self.codec.scaled_to_raw_saturating(value), data)
    }

    /// Write raw bits (low `size` bits of `raw`) into `data`; `false` if `data` is too short.
    #[inline]
    pub fn encode_raw(&self, raw: u64, data: &mut [u8]) -> bool {
        self.check_len(data).is_ok() && self.codec.layout.insert(data, raw)
    }

    /// Size of the signal in bits.
    pub fn size(&self) -> u32 {
        self.codec.layout.size()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn codec(start: u64, size: u64, order: ByteOrder, vt: ValueType, f: f64, o: f64) -> Codec {
        Codec::new(BitLayout::new(start, size, order, 8).unwrap(), vt, f, o)
    }

    #[test]
    fn signed_values_sign_extend() {
        let c = codec(0, 4, ByteOrder::LittleEndian, ValueType::Signed, 1.0, 0.0);
        assert_eq!(c.raw_to_scaled(0xF), -1.0);
        assert_eq!(c.raw_to_scaled(0x8), -8.0);
        assert_eq!(c.raw_to_scaled(0x7), 7.0);
        assert_eq!(c.scaled_to_raw(-8.0), Some(0x8));
        assert_eq!(c.scaled_to_raw(-9.0), None);
        assert_eq!(c.scaled_to_raw(8.0), None);
    }

    #[test]
    fn integer_scaling_is_exact_for_64_bits() {
        let c = codec(
            0,
            64,
            ByteOrder::LittleEndian,
            ValueType::Unsigned,
            3.0,
            1.0,
        );
        assert!(matches!(c.scaling, Scaling::Integer { .. }));
        let exact = (i128::from(u64::MAX) * 3 + 1) as f64;
        assert_eq!(c.raw_to_scaled(u64::MAX), exact);
    }

    #[test]
    fn out_of_range_and_nan_do_not_wrap() {
        let c = codec(0, 8, ByteOrder::LittleEndian, ValueType::Unsigned, 0.5, 0.0);
        assert_eq!(c.scaled_to_raw(127.5), Some(255));
        assert_eq!(c.scaled_to_raw(128.0), None);
        assert_eq!(c.scaled_to_raw(-0.5), None);
        assert_eq!(c.scaled_to_raw(f64::NAN), None);
        // Rounds to the nearest raw value, ties to even like cantools.
        assert_eq!(c.scaled_to_raw(1.2), Some(2));
        assert_eq!(c.scaled_to_raw(1.25), Some(2));
    }

    #[test]
    fn floats_use_ieee_bits() {
        let c = codec(0, 32, ByteOrder::LittleEndian, ValueType::Float32, 1.0, 0.0);
        assert_eq!(c.raw_to_scaled(u64::from(1.5f32.to_bits())), 1.5);
        assert_eq!(c.scaled_to_raw(1.5), Some(u64::from(1.5f32.to_bits())));
        assert_eq!(c.scaled_to_raw(1e300), None);
        let d = codec(0, 64, ByteOrder::LittleEndian, ValueType::Float64, 2.0, 1.0);
        assert_eq!(d.raw_to_scaled(2.5f64.to_bits()), 6.0);
        assert_eq!(d.scaled_to_raw(6.0), Some(2.5f64.to_bits()));
    }
}
