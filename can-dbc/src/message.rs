//! A compiled message: its signals, decoding a payload into physical values (honouring
//! multiplexing) without allocating, and encoding physical values into a payload.

use std::collections::HashMap;

use crate::error::{Error, Result};
use crate::frame_id::FrameId;
use crate::signal::{Codec, MuxCondition, Signal, Value};

/// Most multiplexor signals (`M` or `m<n>M`) one message may have; the per-frame
/// multiplexor state is a fixed array of this size so decoding never allocates.
pub const MAX_MULTIPLEXORS: usize = 8;

/// One message (`BO_`) of the database, compiled.
#[derive(Clone, Debug)]
pub struct Message {
    pub(crate) name: String,
    pub(crate) short_name: String,
    pub(crate) id: FrameId,
    pub(crate) length: usize,
    pub(crate) cycle_time_ms: Option<u64>,
    pub(crate) comment: Option<String>,
    pub(crate) transmitter: Option<String>,
    pub(crate) signals: Vec<Signal>,
    /// The signals' codecs, contiguous, so decoding walks a dense array instead of the
    /// metadata-laden `Signal`s; `true` marks a multiplexed signal.
    pub(crate) hot: Box<[(Codec, bool)]>,
    /// Multiplexor signal indices in dependency order: a nested multiplexor comes after the
    /// one that selects it, so one pass computes every multiplexor's state.
    pub(crate) multiplexors: Vec<usize>,
    pub(crate) by_name: HashMap<String, usize>,
}

/// Raw values and validity of a frame's multiplexors, computed once per decoded frame.
#[derive(Clone, Copy, Debug, Default)]
struct MuxState {
    raw: [u64; MAX_MULTIPLEXORS],
    /// Bit `slot` set if that multiplexor is itself present in this frame.
    present: u8,
}

impl MuxState {
    #[inline]
    fn selects(&self, cond: &MuxCondition) -> bool {
        let slot = usize::from(cond.slot);
        self.present & (1 << slot) != 0 && cond.selects(self.raw[slot])
    }
}

impl Message {
    /// Message name as cantools gives it: the `SystemMessageLongSymbol` attribute if the
    /// DBC has one (names longer than 32 characters), else the `BO_` name.
    pub fn name(&self) -> &str {
        &self.name
    }
    /// The `BO_` name, at most 32 characters in files written by Vector tools.
    pub fn short_name(&self) -> &str {
        &self.short_name
    }
    /// Frame ID (standard or extended).
    pub fn id(&self) -> FrameId {
        self.id
    }
    /// Payload length in bytes from the DBC (up to 64 for CAN FD).
    pub fn length(&self) -> usize {
        self.length
    }
    /// `GenMsgCycleTime` attribute (or its default) in milliseconds; `None` if absent or 0.
    pub fn cycle_time_ms(&self) -> Option<u64> {
        self.cycle_time_ms
    }
    /// `CM_ BO_` comment.
    pub fn comment(&self) -> Option<&str> {
        self.comment.as_deref()
    }
    /// Transmitting node, if named.
    pub fn transmitter(&self) -> Option<&str> {
        self.transmitter.as_deref()
    }
    /// Signals in DBC order.
    pub fn signals(&self) -> &[Signal] {
        &self.signals
    }
    /// A signal by long or short name.
    pub fn signal(&self, name: &str) -> Option<&Signal> {
        self.by_name.get(name).map(|&i| &self.signals[i])
    }

    fn check_length(&self, got: usize) -> Result<()> {
        if got < self.length {
            return Err(Error::ShortFrame {
                message: self.name.clone(),
                expected: self.length,
                got,
            });
        }
        Ok(())
    }

    #[inline]
    fn mux_state(&self, data: &[u8]) -> MuxState {
        let mut st = MuxState::default();
        if self.multiplexors.is_empty() {
            return st;
        }
        for (slot, &i) in self.multiplexors.iter().enumerate() {
            let s = &self.signals[i];
            let raw = s
                .codec
                .raw_bits(data)
                .filter(|_| s.mux.as_ref().is_none_or(|c| st.selects(c)));
            if let Some(raw) = raw {
                st.raw[slot] = raw;
                st.present |= 1 << slot;
            }
        }
        st
    }

    /// Whether `signal` is present in a frame with payload `data` (always true for signals
    /// that are not multiplexed).
    pub fn is_present(&self, signal: &Signal, data: &[u8]) -> bool {
        signal
            .mux
            .as_ref()
            .is_none_or(|c| self.mux_state(data).selects(c))
    }

    /// Decode a payload into `(signal, physical value)` pairs, in DBC order, skipping
    /// multiplexed signals the frame's multiplexor value does not select. Nothing is
    /// allocated; bytes beyond the message's length are ignored (as cantools does).
    ///
    /// # Errors
    /// [`Error::ShortFrame`] if `data` is shorter than the message's length.
    #[inline]
    pub fn decode<'m, 'd>(&'m self, data: &'d [u8]) -> Result<Decoded<'m, 'd>> {
        self.check_length(data.len())?;
        Ok(Decoded {
            items: self.signals.iter().zip(self.hot.iter()),
            data,
            mux: self.mux_state(data),
        })
    }

    /// Decode a payload, calling `f(signal, physical value)` for each present signal in DBC
    /// order: the same values as [`Self::decode`], through a tight loop the compiler can
    /// inline into the caller (the fastest way to decode whole frames).
    ///
    /// # Errors
    /// [`Error::ShortFrame`] if `data` is shorter than the message's length.
    #[inline]
    pub fn decode_each(&self, data: &[u8], mut f: impl FnMut(&Signal, f64)) -> Result<()> {
        if self.multiplexors.is_empty() {
            self.check_length(data.len())?;
            for (s, (codec, _)) in self.signals.iter().zip(self.hot.iter()) {
                if let Some(bits) = codec.raw_bits(data) {
                    f(s, codec.raw_to_scaled(bits));
                }
            }
        } else {
            for (s, v) in self.decode(data)? {
                f(s, v);
            }
        }
        Ok(())
    }

    /// As [`Self::decode_each`], with each value as a [`Value`]: integers exact at any
    /// size, for output that must print what the frame holds.
    ///
    /// # Errors
    /// [`Error::ShortFrame`] if `data` is shorter than the message's length.
    pub fn decode_each_value(&self, data: &[u8], mut f: impl FnMut(&Signal, Value)) -> Result<()> {
        let it = self.decode(data)?;
        for (s, (codec, muxed)) in self.signals.iter().zip(self.hot.iter()) {
            if *muxed && s.mux.as_ref().is_some_and(|c| !it.mux.selects(c)) {
                continue;
            }
            if let Some(bits) = codec.raw_bits(data) {
                f(s, codec.raw_to_value(bits));
            }
        }
        Ok(())
    }

    /// Encode physical values given by signal name into a new payload of the message's
    /// length. Like cantools, every signal present for the chosen multiplexor value needs a
    /// value, and no value may be given for an absent one. Unused bits are 0.
    ///
    /// # Errors
    /// [`Error::UnknownSignal`], [`Error::OutOfRange`], [`Error::MissingSignal`],
    /// [`Error::InactiveSignal`], each naming message and signal.
    pub fn encode(&self, values: &[(&str, f64)]) -> Result<Vec<u8>> {
        let mut data = vec![0u8; self.length];
        let mut given = vec![false; self.signals.len()];
        for &(name, value) in values {
            let i = *self.by_name.get(name).ok_or_else(|| Error::UnknownSignal {
                looked_for: format!("{}.{name}", self.name),
                reason: format!("message {} has no signal {name}", self.name),
            })?;
            self.encode_one(i, value, &mut data)?;
            given[i] = true;
        }
        let st = self.mux_state(&data);
        for (s, &g) in self.signals.iter().zip(&given) {
            let present = s.mux.as_ref().is_none_or(|c| st.selects(c));
            if present && !g {
                return Err(Error::MissingSignal {
                    message: self.name.clone(),
                    signal: s.name.clone(),
                });
            }
            if !present && g {
                return Err(Error::InactiveSignal {
                    message: self.name.clone(),
                    signal: s.name.clone(),
                });
            }
        }
        Ok(data)
    }

    fn encode_one(&self, index: usize, value: f64, data: &mut [u8]) -> Result<()> {
        let s = &self.signals[index];
        let raw = s.scaled_to_raw(value, &self.name)?;
        // Length was checked by every caller, so the insert cannot fall short.
        s.codec.layout.insert(data, raw);
        Ok(())
    }

    /// Encode `(signal index, physical value)` pairs into `data` in place, leaving all other
    /// bits as they are; no allocation and no completeness check (the caller chooses which
    /// signals to write, e.g. the ones [`Self::decode`] produced).
    ///
    /// # Errors
    /// [`Error::ShortFrame`], [`Error::OutOfRange`], or [`Error::UnknownSignal`] for an index
    /// past the message's signals.
    pub fn encode_into(
        &self,
        values: impl IntoIterator<Item = (usize, f64)>,
        data: &mut [u8],
    ) -> Result<()> {
        self.check_length(data.len())?;
        for (i, value) in values {
            if i >= self.signals.len() {
                return Err(Error::UnknownSignal {
                    looked_for: format!("{}[{i}]", self.name),
                    reason: format!("message {} has {} signals", self.name, self.signals.len()),
                });
            }
            self.encode_one(i, value, data)?;
        }
        Ok(())
    }

    /// Mask of the payload bits occupied by the signals present in `data` (multiplexing
    /// honoured); the bits `encode_into(decode(data))` reproduces.
    ///
    /// # Errors
    /// [`Error::ShortFrame`] if `data` is shorter than the message's length.
    pub fn signal_bits(&self, data: &[u8]) -> Result<Vec<u8>> {
        self.check_length(data.len())?;
        let st = self.mux_state(data);
        let mut mask = vec![0u8; self.length];
        for s in &self.signals {
            if s.mux.as_ref().is_none_or(|c| st.selects(c)) {
                s.or_bit_mask(&mut mask);
            }
        }
        Ok(mask)
    }
}

/// Iterator over the decoded signals of one frame; see [`Message::decode`].
#[derive(Clone, Debug)]
pub struct Decoded<'m, 'd> {
    items: std::iter::Zip<std::slice::Iter<'m, Signal>, std::slice::Iter<'m, (Codec, bool)>>,
    data: &'d [u8],
    mux: MuxState,
}

impl<'m> Iterator for Decoded<'m, '_> {
    type Item = (&'m Signal, f64);

    #[inline]
    fn next(&mut self) -> Option<Self::Item> {
        for (s, (codec, muxed)) in self.items.by_ref() {
            if *muxed && s.mux.as_ref().is_some_and(|c| !self.mux.selects(c)) {
                continue;
            }
            if let Some(bits) = codec.raw_bits(self.data) {
                return Some((s, codec.raw_to_scaled(bits)));
            }
        }
        None
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        (0, Some(self.items.len()))
    }
}

impl Decoded<'_, '_> {
    /// Raw bits of the current frame's signal `signal` if it is present (for signals wider
    /// than 53 bits, whose physical `f64` cannot carry every raw value).
    pub fn raw(&self, signal: &Signal) -> Option<u64> {
        if signal.mux.as_ref().is_some_and(|c| !self.mux.selects(c)) {
            return None;
        }
        signal.codec.raw_bits(self.data)
    }
}
