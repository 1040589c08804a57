//! Loading: DBC text → the crates.io `can-dbc` AST (kept private) → a compiled
//! [`Database`] with O(1) lookup by frame ID and by `MESSAGE.SIGNAL` name.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::path::Path;

use can_dbc as ast;

use crate::error::{Error, Result};
use crate::frame_id::FrameId;
use crate::layout::{BitLayout, ByteOrder};
use crate::message::{Decoded, MAX_MULTIPLEXORS, Message};
use crate::signal::{Codec, MuxCondition, Signal, SignalHandle, ValueType};

/// Largest payload a message may declare (CAN FD).
pub const MAX_MESSAGE_LENGTH: usize = 64;

/// Vector's pseudo-message that holds signals not assigned to any frame; it is never on the
/// bus, so it is left out of the database.
const INDEPENDENT_SIGNALS_MESSAGE: &str = "VECTOR__INDEPENDENT_SIG_MSG";

/// Hasher for the extended-ID table: the keys are already well-spread 29-bit integers, so a
/// multiply-shift is enough and far cheaper than SipHash on the per-frame path.
#[derive(Default, Clone, Copy)]
struct IdHasher(u64);

impl Hasher for IdHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
    }
    fn write_u32(&mut self, i: u32) {
        self.0 = u64::from(i).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    }
}

/// How a load treats a message that cannot be compiled (a signal past the message's end,
/// a bad size, an ID used twice, …).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LoadMode {
    /// Leave the message out, record a [`LoadWarning`] and load the rest, as cantools
    /// does: real files from car makers often carry one broken message nobody uses.
    #[default]
    Tolerant,
    /// Refuse the whole file with the first such message's error.
    Strict,
}

/// A message left out of a [`LoadMode::Tolerant`] load, and why; its `Display` is the
/// warning line a program should print (this crate does no logging).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LoadWarning {
    source_name: String,
    message: String,
    signal: Option<String>,
    reason: String,
}

impl LoadWarning {
    /// The warning for a message that failed to compile with `error`.
    fn from_error(error: Error, message: &str, source_name: &str) -> Self {
        let (signal, reason) = match error {
            Error::InvalidSignal { signal, reason, .. } => (Some(signal), reason),
            Error::InvalidMessage { reason, .. } => (None, reason),
            // Compiling a message only fails with the two above; keep any other whole.
            other => (None, other.to_string()),
        };
        Self {
            source_name: source_name.to_owned(),
            message: message.to_owned(),
            signal,
            reason,
        }
    }
    /// File name (or caller-chosen name) of the DBC text.
    pub fn source_name(&self) -> &str {
        &self.source_name
    }
    /// Name of the message left out (its long name, if the DBC gives one).
    pub fn message(&self) -> &str {
        &self.message
    }
    /// The signal at fault, if a signal is (else the message itself is).
    pub fn signal(&self) -> Option<&str> {
        self.signal.as_deref()
    }
    /// What is wrong.
    pub fn reason(&self) -> &str {
        &self.reason
    }
}

impl std::fmt::Display for LoadWarning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: message {} left out (it cannot be decoded): ",
            self.source_name, self.message
        )?;
        if let Some(signal) = &self.signal {
            write!(f, "signal {signal}: ")?;
        }
        f.write_str(&self.reason)
    }
}

/// A compiled DBC database.
#[derive(Clone, Debug)]
pub struct Database {
    source_name: String,
    messages: Vec<Message>,
    /// Messages left out by a tolerant load, in DBC order.
    warnings: Vec<LoadWarning>,
    /// Short and long names of the left-out messages → index in `warnings`, so a lookup
    /// can say why instead of "no such message".
    left_out: HashMap<String, usize>,
    /// Standard IDs index a flat table (`u32::MAX` = none): one load per lookup.
    standard: Box<[u32]>,
    extended: HashMap<u32, u32, BuildHasherDefault<IdHasher>>,
    by_name: HashMap<String, usize>,
}

impl Database {
    /// Read and compile a DBC file (UTF-8 or Windows-1252), tolerantly: a message that
    /// cannot be compiled is left out and reported in [`Self::warnings`].
    ///
    /// # Errors
    /// [`Error::Io`] naming the path, or [`Error::Parse`].
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self> {
        Self::from_file_with(path, LoadMode::Tolerant)
    }

    /// [`Self::from_file`] with a choice of [`LoadMode`].
    ///
    /// # Errors
    /// [`Error::Io`] naming the path, or any error of [`Self::parse_with`].
    pub fn from_file_with(path: impl AsRef<Path>, mode: LoadMode) -> Result<Self> {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(|source| Error::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::from_bytes_with(&bytes, &path.display().to_string(), mode)
    }

    /// Compile DBC bytes tolerantly, UTF-8 or else Windows-1252 (which Vector tools write).
    ///
    /// # Errors
    /// [`Error::Parse`].
    pub fn from_bytes(bytes: &[u8], source_name: &str) -> Result<Self> {
        Self::from_bytes_with(bytes, source_name, LoadMode::Tolerant)
    }

    /// [`Self::from_bytes`] with a choice of [`LoadMode`].
    ///
    /// # Errors
    /// Any error of [`Self::parse_with`].
    pub fn from_bytes_with(bytes: &[u8], source_name: &str, mode: LoadMode) -> Result<Self> {
        if let Ok(text) = std::str::from_utf8(bytes) {
            Self::parse_with(text, source_name, mode)
        } else {
            // Windows-1252 (WHATWG) maps every byte, so the lossy fallback is only defensive.
            let text =
                can_dbc::decode_cp1252(bytes).unwrap_or_else(|| String::from_utf8_lossy(bytes));
            Self::parse_with(&text, source_name, mode)
        }
    }

    /// Compile DBC text tolerantly ([`LoadMode::Tolerant`]); `source_name` (usually the
    /// file name) prefixes every error and warning.
    ///
    /// # Errors
    /// [`Error::Parse`] with line and column.
    pub fn parse(text: &str, source_name: &str) -> Result<Self> {
        Self::parse_with(text, source_name, LoadMode::Tolerant)
    }

    /// Compile DBC text with a choice of [`LoadMode`].
    ///
    /// # Errors
    /// [`Error::Parse`] with line and column; under [`LoadMode::Strict`] also
    /// [`Error::InvalidMessage`] or [`Error::InvalidSignal`] naming the first message and
    /// signal that cannot be compiled.
    pub fn parse_with(text: &str, source_name: &str, mode: LoadMode) -> Result<Self> {
        // The parser can panic on some malformed inputs (it `expect`s what its grammar
        // should guarantee); a daemon must get an error, not an abort.
        let parsed = std::panic::catch_unwind(|| ast::Dbc::try_from(text)).unwrap_or(Err(
            ast::DbcError::NotImplemented("input that makes the DBC parser panic"),
        ));
        let dbc = parsed.map_err(|e| parse_error(&e, source_name))?;
        compile(&dbc, text, source_name, mode)
    }

    /// The messages a tolerant load left out, one warning each, in DBC order (empty after
    /// a strict load, which refuses instead).
    pub fn warnings(&self) -> &[LoadWarning] {
        &self.warnings
    }

    /// Why the message of this (short or long) name was left out, if it was.
    pub fn left_out(&self, message: &str) -> Option<&LoadWarning> {
        self.left_out.get(message).map(|&i| &self.warnings[i])
    }

    /// Name given at load (file path or caller's choice).
    pub fn source_name(&self) -> &str {
        &self.source_name
    }

    /// All messages, in DBC order.
    pub fn messages(&self) -> &[Message] {
        &self.messages
    }

    /// The message with this frame ID, in O(1); `None` for an ID the DBC does not define.
    #[inline]
    pub fn message_by_id(&self, id: FrameId) -> Option<&Message> {
        self.messages.get(self.message_index(id)?)
    }

    /// The place in [`Self::messages`] of the message with this frame ID, in O(1); `None`
    /// for an ID the DBC does not define. For a caller keeping its own state per message
    /// in a `Vec` beside the database (no hashing per frame).
    #[inline]
    pub fn message_index(&self, id: FrameId) -> Option<usize> {
        let i = match id {
            FrameId::Standard(s) => *self.standard.get(usize::from(s))?,
            FrameId::Extended(e) => *self.extended.get(&e)?,
        };
        let i = i as usize;
        (i < self.messages.len()).then_some(i)
    }

    /// The message with this name: its long name (`SystemMessageLongSymbol`) or its
    /// short `BO_` name.
    pub fn message_by_name(&self, name: &str) -> Option<&Message> {
        self.by_name.get(name).map(|&i| &self.messages[i])
    }

    /// Look up the frame's message and decode it; `None` for an unknown ID (a normal event
    /// on a shared bus, not an error).
    pub fn decode<'m, 'd>(
        &'m self,
        id: FrameId,
        data: &'d [u8],
    ) -> Option<Result<Decoded<'m, 'd>>> {
        self.message_by_id(id).map(|m| m.decode(data))
    }

    /// Look up the frame's message and call `f(signal, physical value)` for each present
    /// signal ([`Message::decode_each`]); `None` for an unknown ID.
    #[inline]
    pub fn decode_each(
        &self,
        id: FrameId,
        data: &[u8],
        f: impl FnMut(&Signal, f64),
    ) -> Option<Result<()>> {
        self.message_by_id(id).map(|m| m.decode_each(data, f))
    }

    /// A fast handle on one signal, named `MESSAGE.SIGNAL` (long or short names, each).
    ///
    /// # Errors
    /// [`Error::LeftOut`] if the message was left out at load, with the reason;
    /// [`Error::UnknownSignal`] naming what was looked for and which part is missing, or
    /// if the signal's multiplexing is too complex for a handle (nested, or more than
    /// [`crate::signal::HANDLE_MAX_MUX_RANGES`] value ranges) — decode the message instead.
    pub fn signal(&self, path: &str) -> Result<SignalHandle> {
        let unknown = |reason: String| Error::UnknownSignal {
            looked_for: path.to_owned(),
            reason,
        };
        let (msg_name, sig_name) = path
            .split_once('.')
            .ok_or_else(|| unknown("expected MESSAGE.SIGNAL".to_owned()))?;
        let Some(&mi) = self.by_name.get(msg_name) else {
            return Err(match self.left_out(msg_name) {
                Some(w) => Error::LeftOut {
                    looked_for: path.to_owned(),
                    warning: w.clone(),
                },
                None => unknown(format!(
                    "no message {msg_name} in {}{}",
                    self.source_name,
                    did_you_mean(msg_name, self.messages.iter().map(Message::name))
                )),
            });
        };
        let m = &self.messages[mi];
        let s = m.signal(sig_name).ok_or_else(|| {
            unknown(format!(
                "message {msg_name} has no signal {sig_name}{}",
                did_you_mean(sig_name, m.signals().iter().map(Signal::name))
            ))
        })?;
        let multiplexor = s.mux.as_ref().map(|c| &m.signals[c.multiplexor]);
        SignalHandle::new(s, multiplexor, m.length as u8, m.id, mi).ok_or_else(|| {
            unknown("its multiplexing is nested or has too many ranges for a handle; decode the whole message".to_owned())
        })
    }
}

/// `"; did you mean X?"` for the name among `names` closest to a misspelt
/// `wanted` (case ignored), or nothing when none is close: a suggestion
/// must be a likely typo, not any name of the file.
fn did_you_mean<'a>(wanted: &str, names: impl Iterator<Item = &'a str>) -> String {
    let wanted_lower = wanted.to_ascii_lowercase();
    names
        .map(|n| {
            (
                strsim::jaro_winkler(&wanted_lower, &n.to_ascii_lowercase()),
                n,
            )
        })
        .filter(|(score, _)| *score >= 0.85)
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, n)| format!("; did you mean {n}?"))
        .unwrap_or_default()
}

/// Turn the parser's error into ours, pulling the `--> line:col` pest prints.
fn parse_error(e: &ast::DbcError, source_name: &str) -> Error {
    let detail = e.to_string();
    let (line, column) = detail
        .lines()
        .find_map(|l| l.trim_start().strip_prefix("--> "))
        .and_then(|pos| pos.split_once(':'))
        .map_or((None, None), |(l, c)| {
            (l.trim().parse().ok(), c.trim().parse().ok())
        });
    Error::Parse {
        source_name: source_name.to_owned(),
        line,
        column,
        detail,
    }
}

/// The numbers written after `BO_` in the text, in order. The crates.io parser truncates
/// IDs above 0xFFFF that lack the extended flag to 16 bits; reading the numbers here lets
/// such an ID be reported instead of silently decoding another frame.
fn written_message_ids(text: &str) -> Vec<(Option<u64>, &str)> {
    text.lines()
        .filter_map(|l| l.trim_start().strip_prefix("BO_"))
        .filter(|rest| rest.starts_with([' ', '\t']))
        .map(|rest| {
            let mut tokens = rest.split_whitespace();
            let id = tokens.next().and_then(|t| t.parse().ok());
            let name = tokens.next().unwrap_or("").trim_end_matches(':');
            (id, name)
        })
        .collect()
}

fn numeric(v: &ast::NumericValue) -> f64 {
    match *v {
        ast::NumericValue::Uint(u) => u as f64,
        ast::NumericValue::Int(i) => i as f64,
        ast::NumericValue::Double(d) => d,
    }
}

fn attribute_u64(v: &ast::AttributeValue) -> Option<u64> {
    match *v {
        ast::AttributeValue::Uint(u) => Some(u),
        ast::AttributeValue::Int(i) => u64::try_from(i).ok(),
        ast::AttributeValue::Double(d) if d >= 0.0 && d.fract() == 0.0 => Some(d as u64),
        _ => None,
    }
}

type SigKey<'a> = (ast::MessageId, &'a str);

/// Per-file lookups built once, so compiling is linear in the file size.
struct Side<'a> {
    message_comments: HashMap<ast::MessageId, &'a str>,
    signal_comments: HashMap<SigKey<'a>, &'a str>,
    values: HashMap<SigKey<'a>, &'a [ast::ValDescription]>,
    value_types: HashMap<SigKey<'a>, ast::SignalExtendedValueType>,
    ext_mux: HashMap<SigKey<'a>, &'a ast::ExtendedMultiplex>,
    cycle_times: HashMap<ast::MessageId, u64>,
    cycle_default: Option<u64>,
    /// Vector's `SystemMessageLongSymbol` / `SystemSignalLongSymbol`: names longer than the
    /// 32 characters a `BO_`/`SG_` name may have; cantools names things by them.
    message_long_names: HashMap<ast::MessageId, String>,
    signal_long_names: HashMap<SigKey<'a>, String>,
}

/// The text of a long-name attribute, as cantools takes it (`str(value)`); an empty
/// string is ignored, since a message or signal without a name cannot be looked up.
fn long_name(v: &ast::AttributeValue) -> Option<String> {
    let text = match v {
        ast::AttributeValue::String(s) => s.clone(),
        ast::AttributeValue::Uint(u) => u.to_string(),
        ast::AttributeValue::Int(i) => i.to_string(),
        ast::AttributeValue::Double(d) => d.to_string(),
    };
    (!text.is_empty()).then_some(text)
}

impl<'a> Side<'a> {
    fn new(dbc: &'a ast::Dbc) -> Self {
        let mut s = Side {
            message_comments: HashMap::new(),
            signal_comments: HashMap::new(),
            values: HashMap::new(),
            value_types: HashMap::new(),
            ext_mux: HashMap::new(),
            cycle_times: HashMap::new(),
            message_long_names: HashMap::new(),
            signal_long_names: HashMap::new(),
            cycle_default: dbc
                .attribute_default("GenMsgCycleTime")
                .and_then(attribute_u64),
        };
        for c in &dbc.comments {
            match c {
                ast::Comment::Message { id, comment } => {
                    s.message_comments.entry(*id).or_insert(comment);
                }
                ast::Comment::Signal {
                    message_id,
                    name,
                    comment,
                } => {
                    s.signal_comments
                        .entry((*message_id, name))
                        .or_insert(comment);
                }
                _ => {}
            }
        }
        for v in &dbc.value_descriptions {
            if let ast::ValueDescription::Signal {
                message_id,
                name,
                value_descriptions,
            } = v
            {
                s.values.insert((*message_id, name), value_descriptions);
            }
        }
        for t in &dbc.signal_extended_value_type_list {
            s.value_types
                .insert((t.message_id, &t.signal_name), t.signal_extended_value_type);
        }
        for x in &dbc.extended_multiplex {
            s.ext_mux.insert((x.message_id, &x.signal_name), x);
        }
        for a in &dbc.attribute_values_message {
            if let Some(ms) = attribute_u64(&a.value).filter(|_| a.name == "GenMsgCycleTime") {
                s.cycle_times.insert(a.message_id, ms);
            }
            if let Some(name) = long_name(&a.value).filter(|_| a.name == "SystemMessageLongSymbol")
            {
                s.message_long_names.insert(a.message_id, name);
            }
        }
        for a in &dbc.attribute_values_signal {
            if let Some(name) = long_name(&a.value).filter(|_| a.name == "SystemSignalLongSymbol") {
                s.signal_long_names
                    .insert((a.message_id, a.signal_name.as_str()), name);
            }
        }
        s
    }
}

fn compile(dbc: &ast::Dbc, text: &str, source_name: &str, mode: LoadMode) -> Result<Database> {
    let side = Side::new(dbc);
    let written = written_message_ids(text);
    // Only trust the text scan if it saw exactly the parser's messages.
    let written = (written.len() == dbc.messages.len()).then_some(written);

    let mut messages: Vec<Message> = Vec::with_capacity(dbc.messages.len());
    let mut standard = vec![u32::MAX; 0x800].into_boxed_slice();
    let mut extended = HashMap::default();
    let mut by_name = HashMap::new();
    let mut warnings = Vec::new();
    let mut left_out = HashMap::new();

    for (k, m) in dbc.messages.iter().enumerate() {
        if m.name == INDEPENDENT_SIGNALS_MESSAGE {
            continue;
        }
        let name = side
            .message_long_names
            .get(&m.id)
            .map_or(m.name.as_str(), String::as_str);
        let invalid = |reason: String| Error::InvalidMessage {
            source_name: source_name.to_owned(),
            message: name.to_owned(),
            reason,
        };
        // The scanned number is used only if the scan lines up on this very message.
        let dbc_id = written
            .as_ref()
            .and_then(|w| w[k].0.filter(|_| w[k].1 == m.name))
            .unwrap_or(u64::from(m.id.raw()));
        let checked = u32::try_from(dbc_id)
            .ok()
            .and_then(|i| FrameId::from_dbc(i).ok())
            .ok_or_else(|| {
                invalid(format!(
                    "ID {dbc_id} (0x{dbc_id:X}) is neither an 11-bit standard ID nor a 29-bit ID flagged with 0x80000000"
                ))
            })
            .and_then(|id| {
                let length = usize::try_from(m.size)
                    .ok()
                    .filter(|&l| l <= MAX_MESSAGE_LENGTH)
                    .ok_or_else(|| {
                        invalid(format!(
                            "length {} bytes exceeds the CAN FD maximum of {MAX_MESSAGE_LENGTH}",
                            m.size
                        ))
                    })?;
                let taken = match id {
                    FrameId::Standard(s) => standard[usize::from(s)],
                    FrameId::Extended(e) => extended.get(&e).copied().unwrap_or(u32::MAX),
                };
                if let Some(other) = messages.get(taken as usize) {
                    return Err(invalid(format!(
                        "frame ID {id} is also used by {}",
                        other.name
                    )));
                }
                if by_name.contains_key(name) || by_name.contains_key(&m.name) {
                    return Err(invalid("two messages have this name".to_owned()));
                }
                compile_message(m, name, id, length, &side, source_name)
            });
        let message = match checked {
            Ok(message) => message,
            Err(e) if mode == LoadMode::Strict => return Err(e),
            Err(e) => {
                // A name already loaded keeps pointing at the loaded message.
                left_out.entry(name.to_owned()).or_insert(warnings.len());
                left_out.entry(m.name.clone()).or_insert(warnings.len());
                warnings.push(LoadWarning::from_error(e, name, source_name));
                continue;
            }
        };
        let index = messages.len() as u32;
        match message.id {
            FrameId::Standard(s) => standard[usize::from(s)] = index,
            FrameId::Extended(e) => {
                extended.insert(e, index);
            }
        }
        by_name.insert(name.to_owned(), index as usize);
        by_name.insert(m.name.clone(), index as usize);
        messages.push(message);
    }
    Ok(Database {
        source_name: source_name.to_owned(),
        messages,
        warnings,
        left_out,
        standard,
        extended,
        by_name,
    })
}

/// A multiplexed signal's multiplexor index and the raw values that select it.
type Parent = (usize, Vec<(u64, u64)>);

#[allow(clippy::too_many_lines)] // one linear pass over the signals reads best unsplit
fn compile_message(
    m: &ast::Message,
    name: &str,
    id: FrameId,
    length: usize,
    side: &Side<'_>,
    source_name: &str,
) -> Result<Message> {
    // Long names where the DBC gives them (cantools' names), else the `SG_` names.
    let names: Vec<&str> = m
        .signals
        .iter()
        .map(|s| {
            side.signal_long_names
                .get(&(m.id, s.name.as_str()))
                .map_or(s.name.as_str(), String::as_str)
        })
        .collect();
    let invalid = |signal: &str, reason: String| Error::InvalidSignal {
        source_name: source_name.to_owned(),
        message: name.to_owned(),
        signal: signal.to_owned(),
        reason,
    };
    // Short names first: multiplexing (`SG_MUL_VAL_`) refers to signals by them.
    let mut by_name = HashMap::with_capacity(m.signals.len());
    for (i, s) in m.signals.iter().enumerate() {
        if by_name.insert(s.name.clone(), i).is_some() {
            return Err(invalid(names[i], "defined twice in the message".to_owned()));
        }
    }
    // Plain `M` multiplexors: the implicit parent of `m<n>` signals.
    let plain_muxes: Vec<usize> = m
        .signals
        .iter()
        .enumerate()
        .filter(|(_, s)| s.multiplexer_indicator == ast::MultiplexIndicator::Multiplexor)
        .map(|(i, _)| i)
        .collect();

    let mut signals = Vec::with_capacity(m.signals.len());
    let mut parents: Vec<Option<Parent>> = Vec::with_capacity(m.signals.len());
    for (i, s) in m.signals.iter().enumerate() {
        let key = (m.id, s.name.as_str());
        let order = match s.byte_order {
            ast::ByteOrder::LittleEndian => ByteOrder::LittleEndian,
            ast::ByteOrder::BigEndian => ByteOrder::BigEndian,
        };
        let layout = BitLayout::new(s.start_bit, s.size, order, length as u64)
            .map_err(|e| invalid(names[i], e.to_string()))?;
        let value_type = match side.value_types.get(&key) {
            Some(ast::SignalExtendedValueType::IEEEfloat32Bit) => ValueType::Float32,
            Some(ast::SignalExtendedValueType::IEEEdouble64bit) => ValueType::Float64,
            _ => match s.value_type {
                ast::ValueType::Signed => ValueType::Signed,
                ast::ValueType::Unsigned => ValueType::Unsigned,
            },
        };
        let needed = match value_type {
            ValueType::Float32 => Some(32),
            ValueType::Float64 => Some(64),
            _ => None,
        };
        if let Some(bits) = needed.filter(|&b| b != s.size) {
            return Err(invalid(
                names[i],
                format!(
                    "an IEEE float signal of {} bits (SIG_VALTYPE_ needs {bits})",
                    s.size
                ),
            ));
        }
        if !(s.factor.is_finite() && s.offset.is_finite()) || s.factor == 0.0 {
            return Err(invalid(
                names[i],
                format!(
                    "factor {} / offset {} cannot be inverted",
                    s.factor, s.offset
                ),
            ));
        }

        // Multiplexing: `m<n>` (and `m<n>M`) select on the message's single `M` unless
        // SG_MUL_VAL_ names the multiplexor; SG_MUL_VAL_ ranges add to `<n>` as in cantools.
        let own_id = match s.multiplexer_indicator {
            ast::MultiplexIndicator::MultiplexedSignal(v)
            | ast::MultiplexIndicator::MultiplexorAndMultiplexedSignal(v) => Some(v),
            _ => None,
        };
        let ext = side.ext_mux.get(&key);
        let parent = if let Some(x) = ext {
            let p = *by_name
                .get(x.multiplexor_signal_name.as_str())
                .ok_or_else(|| {
                    invalid(
                        names[i],
                        format!(
                            "SG_MUL_VAL_ names unknown multiplexor {}",
                            x.multiplexor_signal_name
                        ),
                    )
                })?;
            let mut ranges: Vec<(u64, u64)> = x
                .mappings
                .iter()
                .map(|r| (r.min_value, r.max_value))
                .collect();
            ranges.extend(own_id.map(|v| (v, v)));
            Some((p, ranges))
        } else if let Some(v) = own_id {
            match plain_muxes.as_slice() {
                [p] => Some((*p, vec![(v, v)])),
                [] => {
                    return Err(invalid(
                        names[i],
                        format!("multiplexed (m{v}) but the message has no multiplexor (M)"),
                    ));
                }
                _ => {
                    return Err(invalid(
                        names[i],
                        format!(
                            "multiplexed (m{v}) but the message has several multiplexors and no SG_MUL_VAL_ picks one"
                        ),
                    ));
                }
            }
        } else {
            None
        };
        if parent.as_ref().is_some_and(|(p, _)| *p == i) {
            return Err(invalid(names[i], "multiplexed by itself".to_owned()));
        }
        parents.push(parent);

        signals.push(Signal {
            name: names[i].to_owned(),
            short_name: s.name.clone(),
            index: i,
            codec: Codec::new(layout, value_type, s.factor, s.offset),
            start_bit: s.start_bit,
            byte_order: order,
            min: numeric(&s.min),
            max: numeric(&s.max),
            unit: s.unit.clone(),
            comment: side.signal_comments.get(&key).map(|c| (*c).to_owned()),
            value_descriptions: side
                .values
                .get(&key)
                .map(|v| v.iter().map(|d| (d.id, d.description.clone())).collect())
                .unwrap_or_default(),
            is_multiplexor: false,
            mux: None,
            receivers: s.receivers.clone(),
        });
    }

    // Multiplexors in dependency order (parents first); a cycle never resolves.
    let is_mux: Vec<bool> = (0..signals.len())
        .map(|i| {
            parents
                .iter()
                .any(|p| p.as_ref().is_some_and(|(q, _)| *q == i))
        })
        .collect();
    let mut order: Vec<usize> = Vec::new();
    let mut pending: Vec<usize> = (0..signals.len()).filter(|&i| is_mux[i]).collect();
    while !pending.is_empty() {
        let before = pending.len();
        pending.retain(|&i| {
            let ready = parents[i].as_ref().is_none_or(|(p, _)| order.contains(p));
            if ready {
                order.push(i);
            }
            !ready
        });
        if pending.len() == before {
            let s = &signals[pending[0]].name;
            return Err(invalid(
                s,
                "multiplexors select each other in a cycle".to_owned(),
            ));
        }
    }
    if order.len() > MAX_MULTIPLEXORS {
        let s = &signals[order[MAX_MULTIPLEXORS]].name;
        return Err(invalid(
            s,
            format!("more than {MAX_MULTIPLEXORS} multiplexors in one message"),
        ));
    }
    for (i, parent) in parents.into_iter().enumerate() {
        signals[i].is_multiplexor =
            is_mux[i] || m.signals[i].multiplexer_indicator == ast::MultiplexIndicator::Multiplexor;
        if let Some((p, mut ranges)) = parent {
            ranges.sort_unstable();
            let mut merged: Vec<(u64, u64)> = Vec::with_capacity(ranges.len());
            for (lo, hi) in ranges {
                match merged.last_mut() {
                    Some(last) if lo <= last.1.saturating_add(1) => last.1 = last.1.max(hi),
                    _ => merged.push((lo, hi)),
                }
            }
            let slot = order.iter().position(|&q| q == p).unwrap_or(0) as u8;
            signals[i].mux = Some(MuxCondition {
                multiplexor: p,
                slot,
                ranges: merged.into_boxed_slice(),
            });
        }
    }

    // Long names are looked up too; a long name that is some other signal's short name
    // keeps meaning that signal.
    for s in &signals {
        by_name.entry(s.name.clone()).or_insert(s.index);
    }
    let hot = signals.iter().map(|s| (s.codec, s.mux.is_some())).collect();
    Ok(Message {
        hot,
        name: name.to_owned(),
        short_name: m.name.clone(),
        id,
        length,
        cycle_time_ms: side
            .cycle_times
            .get(&m.id)
            .copied()
            .or(side.cycle_default)
            .filter(|&ms| ms > 0),
        comment: side.message_comments.get(&m.id).map(|c| (*c).to_owned()),
        transmitter: m.transmitter.clone(),
        signals,
        multiplexors: order,
        by_name,
    })
}
