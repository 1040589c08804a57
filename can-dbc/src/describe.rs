//! A loaded database described for people and scripts (`canodom dbc dump`):
//! every message with its id, length, sender and cycle time, every signal
//! with its bits, scaling, range, unit and value table, as the compiled codec
//! sees them (long names, messages left out at load listed as such).

use crate::database::Database;
use crate::layout::ByteOrder;
use crate::signal::{Signal, ValueType};
use serde::Serialize;
use std::fmt;

/// The whole database.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DatabaseDescription {
    /// The file, as it was named at load.
    pub source: String,
    /// Every message that was compiled, in file order.
    pub messages: Vec<MessageDescription>,
    /// Messages left out at load, each with why.
    pub left_out: Vec<String>,
}

/// One message.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MessageDescription {
    /// Name (the long name where the DBC has one).
    pub name: String,
    /// The numeric id, without the DBC's extended flag.
    pub id: u32,
    /// Whether the id is a 29-bit one.
    pub extended: bool,
    /// Payload length, bytes.
    pub length: usize,
    /// The sending node, when the DBC names one.
    pub sender: Option<String>,
    /// `GenMsgCycleTime`, milliseconds, when the DBC gives one.
    pub cycle_time_ms: Option<u64>,
    /// Its signals, in file order.
    pub signals: Vec<SignalDescription>,
}

/// One signal.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SignalDescription {
    /// Name (the long name where the DBC has one).
    pub name: String,
    /// The start bit as the DBC writes it (for big-endian signals the most
    /// significant bit in the DBC's sawtooth numbering, as cantools keeps it).
    pub start: u64,
    /// Length, bits.
    pub length: u32,
    /// `"little_endian"` (Intel, `@1`) or `"big_endian"` (Motorola, `@0`).
    pub byte_order: &'static str,
    /// `"unsigned"`, `"signed"`, `"float32"` or `"float64"`.
    pub value_type: &'static str,
    /// Physical = raw × scale + offset.
    pub scale: f64,
    /// See `scale`.
    pub offset: f64,
    /// The DBC's minimum (physical).
    pub minimum: f64,
    /// The DBC's maximum (physical).
    pub maximum: f64,
    /// Unit, empty when none.
    pub unit: String,
    /// `"multiplexor"`, `"multiplexed"` or `""`.
    pub multiplexing: &'static str,
    /// Named raw values (`VAL_`).
    pub values: Vec<(i64, String)>,
}

impl SignalDescription {
    fn of(s: &Signal) -> Self {
        Self {
            name: s.name().to_owned(),
            start: s.start_bit(),
            length: s.size(),
            byte_order: match s.byte_order() {
                ByteOrder::LittleEndian => "little_endian",
                ByteOrder::BigEndian => "big_endian",
            },
            value_type: match s.value_type() {
                ValueType::Unsigned => "unsigned",
                ValueType::Signed => "signed",
                ValueType::Float32 => "float32",
                ValueType::Float64 => "float64",
            },
            scale: s.factor(),
            offset: s.offset(),
            minimum: s.min(),
            maximum: s.max(),
            unit: s.unit().to_owned(),
            multiplexing: if s.is_multiplexor() {
                "multiplexor"
            } else if s.is_multiplexed() {
                "multiplexed"
            } else {
                ""
            },
            values: s.value_descriptions().to_vec(),
        }
    }
}

impl Database {
    /// Everything this database holds, for printing or serialising.
    pub fn describe(&self) -> DatabaseDescription {
        DatabaseDescription {
            source: self.source_name().to_owned(),
            messages: self
                .messages()
                .iter()
                .map(|m| MessageDescription {
                    name: m.name().to_owned(),
                    id: m.id().raw(),
                    extended: m.id().is_extended(),
                    length: m.length(),
                    sender: m.transmitter().map(str::to_owned),
                    cycle_time_ms: m.cycle_time_ms(),
                    signals: m.signals().iter().map(SignalDescription::of).collect(),
                })
                .collect(),
            left_out: self.warnings().iter().map(ToString::to_string).collect(),
        }
    }
}

impl fmt::Display for DatabaseDescription {
    /// A plain-text listing: one block a message, one aligned line a signal.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let signals: usize = self.messages.iter().map(|m| m.signals.len()).sum();
        writeln!(
            f,
            "{}: {} messages, {} signals",
            self.source,
            self.messages.len(),
            signals
        )?;
        for m in &self.messages {
            let id = if m.extended {
                format!("0x{:08X} (extended)", m.id)
            } else {
                format!("0x{:03X}", m.id)
            };
            write!(f, "\n{} {id}, {} bytes", m.name, m.length)?;
            if let Some(sender) = &m.sender {
                write!(f, ", from {sender}")?;
            }
            if let Some(ms) = m.cycle_time_ms {
                write!(f, ", every {ms} ms")?;
            }
            writeln!(f)?;
            let width = m.signals.iter().map(|s| s.name.len()).max().unwrap_or(0);
            for s in &m.signals {
                let order = if s.byte_order == "big_endian" {
                    "BE"
                } else {
                    "LE"
                };
                let mux = match s.multiplexing {
                    "multiplexor" => " [mux]",
                    "multiplexed" => " [muxed]",
                    _ => "",
                };
                write!(
                    f,
                    "  {:<width$}  bit {:>3} len {:>2} {order} {:<8} ×{} {:+} [{} .. {}] {}{mux}",
                    s.name,
                    s.start,
                    s.length,
                    s.value_type,
                    s.scale,
                    s.offset,
                    s.minimum,
                    s.maximum,
                    if s.unit.is_empty() { "-" } else { &s.unit },
                )?;
                if !s.values.is_empty() {
                    let named: Vec<String> =
                        s.values.iter().map(|(v, n)| format!("{v}={n}")).collect();
                    write!(f, "  values: {}", named.join(", "))?;
                }
                writeln!(f)?;
            }
        }
        for w in &self.left_out {
            writeln!(f, "\nleft out: {w}")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const DBC: &str = r#"VERSION ""
BU_: ECU ODOM
BO_ 256 WHEELS: 8 ECU
 SG_ SPEED_RL : 0|16@1+ (0.01,0) [0|250] "km/h" ODOM
 SG_ GEAR : 23|3@0- (1,-1) [-1|5] "" ODOM
BO_ 2147484160 EXT_MSG: 4 ECU
 SG_ X : 0|8@1+ (1,0) [0|255] "" ODOM
BA_DEF_ BO_ "GenMsgCycleTime" INT 0 10000;
BA_ "GenMsgCycleTime" BO_ 256 10;
VAL_ 256 GEAR 0 "P" 1 "R" ;
"#;

    #[test]
    fn every_field_is_described() {
        let db = Database::parse(DBC, "t.dbc").unwrap();
        let d = db.describe();
        assert_eq!(d.messages.len(), 2);
        let w = &d.messages[0];
        assert_eq!(
            (
                w.id,
                w.extended,
                w.length,
                w.sender.as_deref(),
                w.cycle_time_ms
            ),
            (256, false, 8, Some("ECU"), Some(10))
        );
        let gear = &w.signals[1];
        assert_eq!(
            (gear.start, gear.length, gear.byte_order, gear.value_type),
            (23, 3, "big_endian", "signed")
        );
        assert_eq!((gear.scale, gear.offset), (1.0, -1.0));
        assert_eq!(gear.values, [(0, "P".to_owned()), (1, "R".to_owned())]);
        assert_eq!((d.messages[1].id, d.messages[1].extended), (0x200, true));
        let text = d.to_string();
        assert!(
            text.contains("WHEELS 0x100, 8 bytes, from ECU, every 10 ms"),
            "{text}"
        );
        assert!(text.contains("EXT_MSG 0x00000200 (extended)"), "{text}");
        assert!(text.contains("values: 0=P, 1=R"), "{text}");
        assert!(text.contains("km/h"), "{text}");
    }
}
