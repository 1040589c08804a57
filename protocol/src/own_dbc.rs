//! canodom's own frames: the DBC shipped in `protocol/dbc/canodom.dbc`, the
//! id offsets from the configurable base id, and the same DBC rewritten for
//! another base so CAN tools decode a relocated daemon from one file.
//!
//! Id map (offsets from `base_id`, default 0x600, clear of `rc_car.dbc`):
//!
//! | offset | frame | sender | cycle |
//! |---|---|---|---|
//! | +0x00 | `ODOM_POSITION` | canodom | pose rate (20 ms) |
//! | +0x01 | `ODOM_MOTION` | canodom | pose rate |
//! | +0x02 | `ODOM_QUALITY` | canodom | pose rate |
//! | +0x03 | `ODOM_CMD` | operator | event |
//! | +0x04 | `ODOM_CMD_AUTH` | operator | after `ODOM_CMD`, with a key |
//! | +0x10 | `CALIB_CMD` | operator | event |
//! | +0x11 | `CALIB_STATUS` | canodom | 100 ms / 1 s |
//! | +0x12 | `CALIB_PARAMS` | canodom | event |
//! | +0x13 | `CALIB_ACK` | parameter store ECU | event |
//! | +0x14 | `CALIB_CMD_AUTH` | operator | after `CALIB_CMD`, with a key |
//! | +0x15 | `CALIB_PARAMS_AUTH` | canodom | after each `CALIB_PARAMS`, with a key |
//! | +0x16 | `CALIB_ACK_AUTH` | parameter store ECU | after `CALIB_ACK`, with a key |
//! | +0x17 | `SECOC_SYNC` | canodom | 1 s and after each accepted secured frame, with a key |
//! | +0x18 | `SECOC_SYNC_AUTH` | canodom | twice after each `SECOC_SYNC` (operators' key, parameter store's key) |
//!
//! Every frame is 8 bytes with `COUNTER` at bits 52..55 and a CRC-8 SAE
//! J1850 `CHECKSUM` over bytes 0..=6 in byte 7, as in `rc_car.dbc`, except
//! the `*_AUTH` authenticators of [`crate::secoc`] (freshness value and MAC)
//! and `SECOC_SYNC` (the receiver's epoch and floor).

use canodom_can::frame::{FrameId, MAX_EXTENDED_ID, MAX_STANDARD_ID};
use canodom_dbc::Database;
use std::fmt::Write as _;
use std::sync::Arc;

/// The DBC text for the default base id.
pub const OWN_DBC: &str = include_str!("../dbc/canodom.dbc");

/// Base id the shipped DBC is written for.
pub const DEFAULT_BASE_ID: u32 = 0x600;

/// Largest offset in the map; `base_id + MAX_OFFSET` must be a valid id.
pub const MAX_OFFSET: u32 = 0x18;

/// One of canodom's own frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum OwnFrame {
    /// Pose x, y.
    OdomPosition,
    /// Heading, speed, yaw rate.
    OdomMotion,
    /// Standard deviations, validity flags, parameter version.
    OdomQuality,
    /// Publish-now / reset-pose requests.
    OdomCmd,
    /// Calibration commands.
    CalibCmd,
    /// Calibration status pages.
    CalibStatus,
    /// Calibrated parameter pages.
    CalibParams,
    /// Parameter store acknowledgement.
    CalibAck,
    /// Authenticator of `ODOM_CMD` (SecOC, [`crate::secoc`]).
    OdomCmdAuth,
    /// Authenticator of `CALIB_CMD`.
    CalibCmdAuth,
    /// Authenticator of `CALIB_PARAMS`.
    CalibParamsAuth,
    /// Authenticator of `CALIB_ACK`.
    CalibAckAuth,
    /// The daemon's SecOC announcement: its epoch and floor
    /// ([`crate::secoc::Sync`]).
    SecocSync,
    /// Authenticators of `SECOC_SYNC`, one per key it is signed with.
    SecocSyncAuth,
}

impl OwnFrame {
    /// Every frame, in id order.
    pub const ALL: [Self; 14] = [
        Self::OdomPosition,
        Self::OdomMotion,
        Self::OdomQuality,
        Self::OdomCmd,
        Self::OdomCmdAuth,
        Self::CalibCmd,
        Self::CalibStatus,
        Self::CalibParams,
        Self::CalibAck,
        Self::CalibCmdAuth,
        Self::CalibParamsAuth,
        Self::CalibAckAuth,
        Self::SecocSync,
        Self::SecocSyncAuth,
    ];

    /// Offset from the base id.
    pub fn offset(self) -> u32 {
        match self {
            Self::OdomPosition => 0x00,
            Self::OdomMotion => 0x01,
            Self::OdomQuality => 0x02,
            Self::OdomCmd => 0x03,
            Self::CalibCmd => 0x10,
            Self::CalibStatus => 0x11,
            Self::CalibParams => 0x12,
            Self::CalibAck => 0x13,
            Self::OdomCmdAuth => 0x04,
            Self::CalibCmdAuth => 0x14,
            Self::CalibParamsAuth => 0x15,
            Self::CalibAckAuth => 0x16,
            Self::SecocSync => 0x17,
            Self::SecocSyncAuth => 0x18,
        }
    }

    /// Message name in the DBC.
    pub fn name(self) -> &'static str {
        match self {
            Self::OdomPosition => "ODOM_POSITION",
            Self::OdomMotion => "ODOM_MOTION",
            Self::OdomQuality => "ODOM_QUALITY",
            Self::OdomCmd => "ODOM_CMD",
            Self::CalibCmd => "CALIB_CMD",
            Self::CalibStatus => "CALIB_STATUS",
            Self::CalibParams => "CALIB_PARAMS",
            Self::CalibAck => "CALIB_ACK",
            Self::OdomCmdAuth => "ODOM_CMD_AUTH",
            Self::CalibCmdAuth => "CALIB_CMD_AUTH",
            Self::CalibParamsAuth => "CALIB_PARAMS_AUTH",
            Self::CalibAckAuth => "CALIB_ACK_AUTH",
            Self::SecocSync => "SECOC_SYNC",
            Self::SecocSyncAuth => "SECOC_SYNC_AUTH",
        }
    }

    /// The frame's id for a base.
    pub fn id(self, base: BaseId) -> FrameId {
        match base.0 {
            FrameId::Standard(b) => FrameId::Standard(b + self.offset() as u16),
            FrameId::Extended(b) => FrameId::Extended(b + self.offset()),
        }
    }
}

/// A validated base id: every own frame's id fits its format.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct BaseId(FrameId);

/// A base id whose last frame would not fit the id format.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("base id {base:#x} + {MAX_OFFSET:#x} exceeds the largest {kind} id {max:#x}")]
pub struct BaseIdError {
    /// The requested base.
    pub base: u32,
    /// `standard` or `extended`.
    pub kind: &'static str,
    /// The largest id of that format.
    pub max: u32,
}

impl BaseId {
    /// The default base, 0x600 standard.
    pub const DEFAULT: Self = Self(FrameId::Standard(DEFAULT_BASE_ID as u16));

    /// Validates `base` (standard or extended per `extended`).
    ///
    /// # Errors
    /// [`BaseIdError`] when `base + MAX_OFFSET` does not fit.
    pub fn new(base: u32, extended: bool) -> Result<Self, BaseIdError> {
        let (kind, max) = if extended {
            ("extended", MAX_EXTENDED_ID)
        } else {
            ("standard", MAX_STANDARD_ID)
        };
        if base.checked_add(MAX_OFFSET).is_none_or(|last| last > max) {
            return Err(BaseIdError { base, kind, max });
        }
        Ok(Self(if extended {
            FrameId::Extended(base)
        } else {
            FrameId::Standard(base as u16)
        }))
    }

    /// The base as an id.
    pub fn id(self) -> FrameId {
        self.0
    }
}

/// The DBC's message id (with bit 31 for extended) of a frame at `base`.
fn dbc_id(frame: OwnFrame, base: BaseId) -> u32 {
    match frame.id(base) {
        FrameId::Standard(id) => u32::from(id),
        FrameId::Extended(id) => id | 0x8000_0000,
    }
}

/// The shipped DBC with every message id moved to `base`, so a CAN tool can
/// decode a daemon configured with a non-default base from one file.
pub fn dbc_for_base(base: BaseId) -> String {
    let map: Vec<(String, String)> = OwnFrame::ALL
        .iter()
        .map(|&f| {
            (
                dbc_id(f, BaseId::DEFAULT).to_string(),
                dbc_id(f, base).to_string(),
            )
        })
        .collect();
    let rename = |token: &str| -> String {
        map.iter()
            .find(|(old, _)| old == token)
            .map_or_else(|| token.to_owned(), |(_, new)| new.clone())
    };
    let mut out = String::with_capacity(OWN_DBC.len() + 64);
    for line in OWN_DBC.lines() {
        // Message ids appear as the token after `BO_ ` (definitions,
        // `CM_ BO_`, `BA_ ... BO_`), after `CM_ SG_ `, and after `VAL_ `.
        let mut tokens: Vec<&str> = line.split(' ').collect();
        let id_at = match tokens.as_slice() {
            ["BO_" | "VAL_", ..] => Some(1),
            ["CM_", "BO_" | "SG_", ..] => Some(2),
            ["BA_", ..] => tokens.iter().position(|t| *t == "BO_").map(|i| i + 1),
            _ => None,
        };
        let renamed;
        if let Some(i) = id_at.filter(|&i| i < tokens.len()) {
            renamed = rename(tokens[i]);
            tokens[i] = &renamed;
        }
        let _ = writeln!(out, "{}", tokens.join(" "));
    }
    if base == BaseId::DEFAULT {
        return out;
    }
    let raw_base = base.id().raw();
    out.replace(
        "this file is written for the default base_id 0x600",
        &format!("this file is written for base_id {raw_base:#X}"),
    )
}

/// canodom's own DBC for one base id, rewritten ([`dbc_for_base`]) and
/// parsed once: the pose encoder, the calibration wire codec and the daemon's
/// `ODOM_CMD` checks all take their signals from this one copy, where each
/// used to rewrite and parse the text again at start.
#[derive(Clone, Debug)]
pub struct OwnDbc {
    base: BaseId,
    /// Shared, not copied: each codec keeps it to hand out for decoding.
    db: Arc<Database>,
}

impl OwnDbc {
    /// The shipped DBC moved to `base`, parsed.
    ///
    /// # Errors
    /// Only if the shipped DBC is broken (a unit test proves it is not).
    pub fn new(base: BaseId) -> Result<Self, canodom_dbc::Error> {
        let db = Database::parse(&dbc_for_base(base), "canodom.dbc")?;
        Ok(Self {
            base,
            db: Arc::new(db),
        })
    }

    /// The base id the DBC was written for.
    pub fn base(&self) -> BaseId {
        self.base
    }

    /// The parsed DBC.
    pub fn database(&self) -> &Database {
        &self.db
    }

    /// A shared handle on the parsed DBC, for a codec that keeps it.
    pub fn shared_database(&self) -> Arc<Database> {
        Arc::clone(&self.db)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use can_dbc::{
        ByteOrder, Comment, Dbc, MessageId, MultiplexIndicator, NumericValue, ValueType,
    };
    use std::collections::{HashMap, HashSet};

    fn num(v: NumericValue) -> f64 {
        match v {
            NumericValue::Uint(u) => u as f64,
            NumericValue::Int(i) => i as f64,
            NumericValue::Double(d) => d,
        }
    }

    fn parse(text: &str) -> Dbc {
        Dbc::try_from(text).unwrap_or_else(|e| panic!("can-dbc rejects the DBC: {e:?}"))
    }

    fn msg_id(id: FrameId) -> MessageId {
        match id {
            FrameId::Standard(s) => MessageId::Standard(s),
            FrameId::Extended(e) => MessageId::Extended(e),
        }
    }

    #[test]
    fn shipped_dbc_parses_with_crates_io_can_dbc_and_matches_the_id_map() {
        let dbc = parse(OWN_DBC);
        assert_eq!(dbc.messages.len(), OwnFrame::ALL.len());
        for f in OwnFrame::ALL {
            let m = dbc
                .messages
                .iter()
                .find(|m| m.name == f.name())
                .unwrap_or_else(|| panic!("{} missing", f.name()));
            assert_eq!(m.id, msg_id(f.id(BaseId::DEFAULT)), "{}", f.name());
            assert_eq!(m.size, 8);
        }
        // Clear of the vehicle DBC the defaults are designed to live beside.
        let rc = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../data/dbc/rc_car.dbc"
        ))
        .unwrap();
        let rc_ids: HashSet<MessageId> = parse(&rc).messages.iter().map(|m| m.id).collect();
        assert!(dbc.messages.iter().all(|m| !rc_ids.contains(&m.id)));
    }

    #[test]
    fn every_frame_has_counter_checksum_comments_and_cycle_time() {
        let dbc = parse(OWN_DBC);
        let commented_msgs: HashSet<MessageId> = dbc
            .comments
            .iter()
            .filter_map(|c| match c {
                Comment::Message { id, .. } => Some(*id),
                _ => None,
            })
            .collect();
        let commented_sigs: HashSet<(MessageId, String)> = dbc
            .comments
            .iter()
            .filter_map(|c| match c {
                Comment::Signal {
                    message_id, name, ..
                } => Some((*message_id, name.clone())),
                _ => None,
            })
            .collect();
        let cycle_times = dbc
            .attribute_values_message
            .iter()
            .filter(|a| a.name == "GenMsgCycleTime")
            .map(|a| a.message_id)
            .collect::<HashSet<_>>();
        for m in &dbc.messages {
            assert!(commented_msgs.contains(&m.id), "{} has no comment", m.name);
            assert!(
                cycle_times.contains(&m.id),
                "{} has no GenMsgCycleTime",
                m.name
            );
            let sig = |name: &str| {
                m.signals
                    .iter()
                    .find(|s| s.name == name)
                    .unwrap_or_else(|| panic!("{} lacks {name}", m.name))
            };
            if m.name.ends_with("_AUTH") {
                // A SecOC authenticator: freshness and MAC, no counter or CRC.
                assert_eq!(m.signals.len(), 2, "{}", m.name);
                assert_eq!((sig("FRESHNESS").start_bit, sig("FRESHNESS").size), (0, 16));
                assert_eq!((sig("MAC").start_bit, sig("MAC").size), (16, 48));
                continue;
            }
            if m.name == "SECOC_SYNC" {
                // The receiver's epoch and floor, signed by SECOC_SYNC_AUTH.
                assert_eq!((sig("EPOCH").start_bit, sig("EPOCH").size), (0, 32));
                assert_eq!((sig("FLOOR").start_bit, sig("FLOOR").size), (32, 32));
                continue;
            }
            let counter = sig("COUNTER");
            assert_eq!((counter.start_bit, counter.size), (52, 4), "{}", m.name);
            let crc = sig("CHECKSUM");
            assert_eq!((crc.start_bit, crc.size), (56, 8), "{}", m.name);
            for s in &m.signals {
                assert!(
                    commented_sigs.contains(&(m.id, s.name.clone())),
                    "{}.{} has no comment",
                    m.name,
                    s.name
                );
                assert_eq!(
                    s.byte_order,
                    ByteOrder::LittleEndian,
                    "{}.{}",
                    m.name,
                    s.name
                );
                assert!(s.start_bit + s.size <= 64, "{}.{}", m.name, s.name);
                if s.name != "CHECKSUM" {
                    // CRC covers bytes 0..=6: every other signal lives there.
                    assert!(s.start_bit + s.size <= 56, "{}.{}", m.name, s.name);
                }
            }
        }
    }

    /// Signals that can be present together must not share a bit.
    #[test]
    fn no_two_coexisting_signals_overlap() {
        let dbc = parse(OWN_DBC);
        for m in &dbc.messages {
            let mux_values: HashSet<u64> = m
                .signals
                .iter()
                .filter_map(|s| match s.multiplexer_indicator {
                    MultiplexIndicator::MultiplexedSignal(v) => Some(v),
                    _ => None,
                })
                .collect();
            let cases: Vec<Option<u64>> = if mux_values.is_empty() {
                vec![None]
            } else {
                mux_values.into_iter().map(Some).collect()
            };
            for case in cases {
                let mut owner: HashMap<u64, &str> = HashMap::new();
                for s in &m.signals {
                    let present = match s.multiplexer_indicator {
                        MultiplexIndicator::MultiplexedSignal(v) => Some(v) == case,
                        _ => true,
                    };
                    if !present {
                        continue;
                    }
                    for bit in s.start_bit..s.start_bit + s.size {
                        if let Some(other) = owner.insert(bit, &s.name) {
                            panic!("{}: {} and {} share bit {bit}", m.name, other, s.name);
                        }
                    }
                }
            }
        }
    }

    /// The scaled ranges must be reachable from the raw bits (min/max are
    /// what cantools checks encodes against).
    #[test]
    fn declared_ranges_fit_the_raw_range() {
        let dbc = parse(OWN_DBC);
        for m in &dbc.messages {
            for s in &m.signals {
                let (raw_min, raw_max) = match s.value_type {
                    ValueType::Signed => (
                        -(2f64.powi(s.size as i32 - 1)),
                        2f64.powi(s.size as i32 - 1) - 1.0,
                    ),
                    ValueType::Unsigned => (0.0, 2f64.powi(s.size as i32) - 1.0),
                };
                let lo = raw_min * s.factor + s.offset;
                let hi = raw_max * s.factor + s.offset;
                let (min, max) = (num(s.min), num(s.max));
                let eps = s.factor.abs() * 1e-6;
                assert!(
                    min >= lo - eps && max <= hi + eps,
                    "{}.{}: [{min}, {max}] outside raw range [{lo}, {hi}]",
                    m.name,
                    s.name
                );
            }
        }
    }

    /// Extracts a little-endian signal as can-dbc describes it.
    fn decode(sig: &can_dbc::Signal, data: u64) -> f64 {
        let raw = (data >> sig.start_bit) & (u64::MAX >> (64 - sig.size));
        let raw = match sig.value_type {
            ValueType::Signed if raw >> (sig.size - 1) & 1 == 1 => raw as i64 - (1i64 << sig.size),
            _ => raw as i64,
        };
        raw as f64 * sig.factor + sig.offset
    }

    /// cantools' reading of the DBC (committed vectors, regenerated by
    /// `dbc/check_cantools.py --write-vectors`) and can-dbc's agree on every
    /// signal of every frame and multiplexer value, and byte 7 is the CRC-8
    /// SAE J1850 the comments promise.
    #[test]
    fn cantools_vectors_decode_identically_with_the_can_dbc_layout() {
        let text = include_str!("../dbc/canodom_vectors.json");
        let vectors: serde_json::Value = serde_json::from_str(text).unwrap();
        let dbc = parse(OWN_DBC);
        let crc8 = crc::Crc::<u8>::new(&crc::CRC_8_SAE_J1850);
        let frames = vectors["frames"].as_array().unwrap();
        assert_eq!(frames.len(), 23, "one vector per message and mux value");
        for v in frames {
            let id = v["id"].as_u64().unwrap();
            let msg = dbc
                .messages
                .iter()
                .find(|m| u64::from(m.id.raw()) == id)
                .unwrap();
            let hex = v["data"].as_str().unwrap();
            let bytes: Vec<u8> = (0..8)
                .map(|i| u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).unwrap())
                .collect();
            if !msg.name.starts_with("SECOC_") && !msg.name.ends_with("_AUTH") {
                assert_eq!(bytes[7], crc8.checksum(&bytes[..7]), "{}", msg.name);
            }
            let data = u64::from_le_bytes(bytes.try_into().unwrap());
            let mux = msg
                .signals
                .iter()
                .find(|s| s.multiplexer_indicator == MultiplexIndicator::Multiplexor)
                .map(|s| decode(s, data) as u64);
            let expected = v["signals"].as_object().unwrap();
            let mut seen = 0;
            for sig in &msg.signals {
                let present = match sig.multiplexer_indicator {
                    MultiplexIndicator::MultiplexedSignal(m) => Some(m) == mux,
                    _ => true,
                };
                if !present {
                    assert!(
                        !expected.contains_key(&sig.name),
                        "{}.{}",
                        msg.name,
                        sig.name
                    );
                    continue;
                }
                seen += 1;
                let want = expected[&sig.name].as_f64().unwrap();
                let got = decode(sig, data);
                assert!(
                    (got - want).abs() <= 1e-9 * want.abs().max(1.0),
                    "{}.{}: can-dbc layout gives {got}, cantools {want}",
                    msg.name,
                    sig.name
                );
            }
            assert_eq!(seen, expected.len(), "{}", msg.name);
        }
    }

    #[test]
    fn base_ids_are_validated() {
        assert_eq!(BaseId::new(0x600, false), Ok(BaseId::DEFAULT));
        assert!(BaseId::new(0x7E7, false).is_ok());
        let err = BaseId::new(0x7E8, false).unwrap_err();
        assert_eq!(err.max, MAX_STANDARD_ID);
        assert!(BaseId::new(0x1FFF_FFE7, true).is_ok());
        assert!(BaseId::new(0x1FFF_FFE8, true).is_err());
        assert!(BaseId::new(u32::MAX, true).is_err());
        let ext = BaseId::new(0x18FF_0000, true).unwrap();
        assert_eq!(OwnFrame::CalibAck.id(ext), FrameId::Extended(0x18FF_0013));
        assert_eq!(
            OwnFrame::CalibCmd.id(BaseId::DEFAULT),
            FrameId::Standard(0x610)
        );
    }

    #[test]
    fn rebased_dbc_moves_every_reference() {
        let unchanged = dbc_for_base(BaseId::DEFAULT);
        assert!(
            parse(&unchanged) == parse(OWN_DBC),
            "default base must not change the DBC"
        );
        for base in [
            BaseId::new(0x300, false).unwrap(),
            BaseId::new(0x18FF_0000, true).unwrap(),
        ] {
            let text = dbc_for_base(base);
            let dbc = parse(&text);
            let original = parse(OWN_DBC);
            for f in OwnFrame::ALL {
                let id = msg_id(f.id(base));
                let m = dbc.messages.iter().find(|m| m.name == f.name()).unwrap();
                assert_eq!(m.id, id, "{}", f.name());
            }
            // Same number of comments, attributes and value tables, all on
            // moved ids: nothing was left pointing at the default base.
            let moved: HashSet<MessageId> = dbc.messages.iter().map(|m| m.id).collect();
            assert_eq!(dbc.comments.len(), original.comments.len());
            for c in &dbc.comments {
                match c {
                    Comment::Message { id, .. } | Comment::Signal { message_id: id, .. } => {
                        assert!(moved.contains(id), "{c:?}");
                    }
                    _ => {}
                }
            }
            assert_eq!(
                dbc.attribute_values_message.len(),
                original.attribute_values_message.len()
            );
            assert!(
                dbc.attribute_values_message
                    .iter()
                    .all(|a| moved.contains(&a.message_id))
            );
            assert_eq!(
                dbc.value_descriptions.len(),
                original.value_descriptions.len()
            );
            assert!(text.contains(&format!("base_id {:#X}", base.id().raw())));
        }
    }
}
