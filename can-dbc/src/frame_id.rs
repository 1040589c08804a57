//! CAN frame identifiers, keeping the standard/extended distinction that DBC files encode
//! with the 0x8000_0000 flag.

use crate::error::{Error, Result};

/// Flag DBC files set on a message ID to mark it as a 29-bit extended ID.
pub const DBC_EXTENDED_FLAG: u32 = 0x8000_0000;

/// A CAN identifier: 11-bit standard or 29-bit extended. The two are distinct IDs on the
/// bus, so `Standard(0x100)` and `Extended(0x100)` are different messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum FrameId {
    /// 11-bit identifier (0..=0x7FF).
    Standard(u16),
    /// 29-bit identifier (0..=0x1FFF_FFFF).
    Extended(u32),
}

impl FrameId {
    /// A standard ID, checked to fit 11 bits.
    ///
    /// # Errors
    /// [`Error::InvalidCheck`] is not used here; an out-of-range ID gives
    /// [`Error::InvalidMessage`] naming the ID.
    pub fn standard(id: u16) -> Result<Self> {
        if id > 0x7FF {
            return Err(invalid_id(
                u64::from(id),
                "a standard ID has 11 bits (max 0x7FF)",
            ));
        }
        Ok(Self::Standard(id))
    }

    /// An extended ID, checked to fit 29 bits.
    ///
    /// # Errors
    /// [`Error::InvalidMessage`] naming the ID if it needs more than 29 bits.
    pub fn extended(id: u32) -> Result<Self> {
        if id > 0x1FFF_FFFF {
            return Err(invalid_id(
                u64::from(id),
                "an extended ID has 29 bits (max 0x1FFFFFFF)",
            ));
        }
        Ok(Self::Extended(id))
    }

    /// The ID as a DBC file writes it (extended IDs carry [`DBC_EXTENDED_FLAG`]).
    ///
    /// # Errors
    /// [`Error::InvalidMessage`] if the number is neither an 11-bit ID nor a flagged 29-bit ID.
    pub fn from_dbc(dbc_id: u32) -> Result<Self> {
        if dbc_id & DBC_EXTENDED_FLAG != 0 {
            Self::extended(dbc_id & !DBC_EXTENDED_FLAG)
        } else if dbc_id > 0x7FF {
            Err(invalid_id(
                u64::from(dbc_id),
                "above 0x7FF without the extended flag 0x80000000",
            ))
        } else {
            Ok(Self::Standard(dbc_id as u16))
        }
    }

    /// The ID as a DBC file writes it.
    pub fn to_dbc(self) -> u32 {
        match self {
            Self::Standard(id) => u32::from(id),
            Self::Extended(id) => id | DBC_EXTENDED_FLAG,
        }
    }

    /// The bare identifier bits, without any flag.
    pub fn raw(self) -> u32 {
        match self {
            Self::Standard(id) => u32::from(id),
            Self::Extended(id) => id,
        }
    }

    /// Whether this is a 29-bit extended ID.
    pub fn is_extended(self) -> bool {
        matches!(self, Self::Extended(_))
    }
}

impl std::fmt::Display for FrameId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Standard(id) => write!(f, "0x{id:03X}"),
            Self::Extended(id) => write!(f, "0x{id:08X}x"),
        }
    }
}

fn invalid_id(id: u64, reason: &str) -> Error {
    Error::InvalidMessage {
        source_name: String::from("frame id"),
        message: format!("0x{id:X}"),
        reason: reason.to_owned(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dbc_flag_selects_extended() {
        assert_eq!(
            FrameId::from_dbc(0x8000_0123).unwrap(),
            FrameId::Extended(0x123)
        );
        assert_eq!(FrameId::from_dbc(0x123).unwrap(), FrameId::Standard(0x123));
        assert_eq!(FrameId::Extended(0x123).to_dbc(), 0x8000_0123);
        assert_ne!(FrameId::Extended(0x123), FrameId::Standard(0x123));
    }

    #[test]
    fn out_of_range_ids_name_the_id() {
        let e = FrameId::from_dbc(0x800).unwrap_err().to_string();
        assert!(e.contains("0x800") && e.contains("extended flag"), "{e}");
        let e = FrameId::extended(0x2000_0000).unwrap_err().to_string();
        assert!(e.contains("0x20000000") && e.contains("29 bits"), "{e}");
        let e = FrameId::standard(0x800).unwrap_err().to_string();
        assert!(e.contains("11 bits"), "{e}");
    }
}
