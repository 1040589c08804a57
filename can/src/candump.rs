//! The `candump -L` log format of can-utils: a streaming parser and the
//! formatter that writes exactly the same text back.
//!
//! ```text
//! (1700000000.123456) vcan0 123#DEADBEEF          classical data, 11-bit id
//! (1700000000.123456) vcan0 00000123#01           classical data, 29-bit id
//! (1700000000.123456) vcan0 123#1122334455667788_E   8 bytes sent with raw DLC 14
//! (1700000000.123456) vcan0 123#R  / 123#R4       remote frame (optional DLC digit)
//! (1700000000.123456) vcan0 123##5DEADBEEF        CAN FD, flags nibble 5, ≤ 64 bytes
//! (1700000000.123456) vcan0 20000004#000C000000000000   error frame (CAN_ERR_FLAG)
//! (1700000000.123456) vcan0 123#01 R              `candump -x` direction field
//! ```
//!
//! The number of id digits decides the format (3: standard, 8: extended or,
//! with `CAN_ERR_FLAG` set, an error frame), not the value. Hex digits may be
//! upper or lower case and a `.` may separate payload bytes, as canplayer
//! accepts; the formatter writes candump's canonical spelling (upper case,
//! no dots, 10-digit zero-padded seconds), so canonical lines round-trip to
//! identical text. Blank lines are skipped; anything else that is not a valid
//! record is a [`Malformed`] line with its 1-based line number and a
//! [`Reason`]; the caller decides whether to skip and count it or to stop.
//!
//! Timestamps are kept as integer microseconds ([`Timestamp`]): candump
//! writes exactly six fractional digits, so nothing is lost and replay is
//! reproducible bit for bit. [`Timestamp::as_secs_f64`] is one correctly
//! rounded division, the same on every machine.
//!
//! Speed: the hot path allocates nothing and reads no byte twice but to
//! find the newline. [`LogReader`] reads large blocks into one buffer, the
//! common line shape takes a straight-line fast path (`parse_common`; the
//! general parser handles the rest and every error), hex is decoded through
//! a 256-entry table, and the formatter appends bytes to a caller's `Vec`.
//!
//! Why not socketcan's `dump` module (issue #21), which the tests keep as an
//! independent oracle (`socketcan_dump_agrees`): on the same 1,000,000-line
//! rc_car log it reads 1.48 M lines/s (674 ms) where [`LogReader`] reads
//! 6.79 M/s (147 ms), 4.6× slower (`cargo bench -p canodom-can --bench
//! candump -- parse`, 2 shared cores under load ≈ 13; the ratio is what
//! counts): it reads each line into a `String` and allocates the interface
//! name and every payload. Nor does it read everything canodom's logs hold:
//! it rejects the `_` raw-DLC suffix, `.` between payload bytes and blank
//! lines, reports no line number or [`Reason`] for a malformed line, and
//! writes seconds unpadded, so canonical lines would not round-trip to
//! identical text.

use crate::frame::{CLASSIC_MAX_LEN, CanFrame, FrameId};
use crate::time::Timestamp;
use std::fmt;
use std::io;

mod format;
mod parse;
mod reader;
pub use format::{format_frame, format_record};
pub use parse::parse_line;
pub(crate) use reader::Interfaces;
pub use reader::{DEFAULT_BUFFER_BYTES, LogReader, MAX_INTERFACES_LISTED};

/// Longest line the reader accepts; a valid record is at most ~330 bytes,
/// so this only stops a corrupt file from growing the buffer without bound.
pub const MAX_LINE_BYTES: usize = 1024;

/// Longest interface name accepted (Linux allows 15, other tools more).
pub const MAX_IFACE_BYTES: usize = 64;

/// The optional `candump -x` direction field.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Received on the interface (`R`).
    Rx,
    /// Transmitted from the interface (`T`).
    Tx,
}

/// One log line: when, where, what.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Record<'a> {
    /// Receive time.
    pub timestamp: Timestamp,
    /// Interface name, borrowed from the reader's line buffer.
    pub iface: &'a str,
    /// The frame.
    pub frame: CanFrame,
    /// `candump -x` direction, when the log has it.
    pub direction: Option<Direction>,
}

/// A classical data frame read from a log line, with its time: what nearly
/// every line of a real log holds, in a third of a [`Record`]'s size (a
/// [`CanFrame`] carries a 64-byte FD payload buffer). For readers that hand
/// frames on in bulk, such as replay's batches between threads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ClassicData {
    /// Receive time.
    pub timestamp: Timestamp,
    /// The identifier.
    pub id: FrameId,
    /// Payload length, at most [`CLASSIC_MAX_LEN`].
    len: u8,
    /// The payload, zero past `len`.
    data: [u8; CLASSIC_MAX_LEN],
}

impl ClassicData {
    /// The payload bytes.
    #[inline]
    pub fn payload(&self) -> &[u8] {
        &self.data[..usize::from(self.len)]
    }

    /// The same frame as a [`CanFrame`].
    pub fn frame(&self) -> CanFrame {
        match CanFrame::new_data(self.id, self.payload()) {
            Ok(frame) => frame,
            // `len` is at most CLASSIC_MAX_LEN by construction.
            Err(_) => unreachable!("a classical payload of at most 8 bytes"),
        }
    }
}

/// Why a line is not a valid record. Each has a stable snake_case name
/// ([`Reason::as_str`]) for statistics.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Reason {
    /// Does not start with `(seconds.micros)`.
    BadTimestamp,
    /// Interface name missing, too long or not printable ASCII.
    BadInterface,
    /// Id not 3 or 8 hex digits, or no `#` after it.
    BadId,
    /// Id value does not fit its format (`800#`, or flag bits other than
    /// `CAN_ERR_FLAG` in 8 digits).
    IdOutOfRange,
    /// A payload character is not a hex digit, or a byte lacks its second digit.
    BadHex,
    /// More payload bytes than the frame kind allows.
    TooLong,
    /// CAN FD flags nibble missing or not hex.
    BadFdFlags,
    /// CAN FD payload length that no DLC encodes.
    BadFdLength,
    /// Remote frame DLC digit above 8.
    BadRemoteLength,
    /// `_` raw DLC not 9..=F or not after exactly 8 bytes.
    BadLen8Dlc,
    /// Error frame that is remote, FD, or not 8 bytes long.
    BadErrorFrame,
    /// A fourth field other than `R` or `T`, or text after it.
    TrailingGarbage,
    /// Longer than [`MAX_LINE_BYTES`].
    LineTooLong,
    /// A Vector ASC CAN event line that cannot be read (`crate::vector_asc`).
    BadAscEvent,
    /// A plain `candump` line (without `-L`) that cannot be read (`crate::candump_plain`).
    BadPlainRecord,
    /// A Vector BLF CAN object that cannot be read (`crate::vector_blf`);
    /// its "line" is the object's number.
    BadBlfObject,
}

impl Reason {
    /// Every reason, for statistics tables that list zero counts too.
    pub const ALL: [Self; 16] = [
        Self::BadTimestamp,
        Self::BadInterface,
        Self::BadId,
        Self::IdOutOfRange,
        Self::BadHex,
        Self::TooLong,
        Self::BadFdFlags,
        Self::BadFdLength,
        Self::BadRemoteLength,
        Self::BadLen8Dlc,
        Self::BadErrorFrame,
        Self::TrailingGarbage,
        Self::LineTooLong,
        Self::BadAscEvent,
        Self::BadPlainRecord,
        Self::BadBlfObject,
    ];

    /// Stable snake_case name, used as a statistics key.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::BadTimestamp => "bad_timestamp",
            Self::BadInterface => "bad_interface",
            Self::BadId => "bad_id",
            Self::IdOutOfRange => "id_out_of_range",
            Self::BadHex => "bad_hex",
            Self::TooLong => "too_long",
            Self::BadFdFlags => "bad_fd_flags",
            Self::BadFdLength => "bad_fd_length",
            Self::BadRemoteLength => "bad_remote_length",
            Self::BadLen8Dlc => "bad_len8_dlc",
            Self::BadErrorFrame => "bad_error_frame",
            Self::TrailingGarbage => "trailing_garbage",
            Self::LineTooLong => "line_too_long",
            Self::BadAscEvent => "bad_asc_event",
            Self::BadPlainRecord => "bad_plain_record",
            Self::BadBlfObject => "bad_blf_object",
        }
    }
}

impl Reason {
    /// What a malformed record is called in its format, for messages.
    pub fn record_kind(self) -> &'static str {
        match self {
            Self::BadAscEvent => "ASC event",
            Self::BadPlainRecord => "plain candump record",
            Self::BadBlfObject => "BLF object",
            _ => "candump record",
        }
    }

    /// What the number of a malformed record counts: lines of a text log,
    /// objects of a BLF file.
    pub fn unit(self) -> &'static str {
        if self == Self::BadBlfObject {
            "object"
        } else {
            "line"
        }
    }
}

impl fmt::Display for Reason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Malformed lines counted by reason, for the skip-and-count policy of
/// `decode` and `replay` (`--strict` stops at the first instead).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MalformedCounts([u64; Reason::ALL.len()]);

impl MalformedCounts {
    fn slot(reason: Reason) -> usize {
        Reason::ALL.iter().position(|&r| r == reason).unwrap_or(0)
    }

    /// Counts one malformed line.
    pub fn add(&mut self, reason: Reason) {
        self.0[Self::slot(reason)] += 1;
    }

    /// Lines counted under `reason`.
    pub fn get(&self, reason: Reason) -> u64 {
        self.0[Self::slot(reason)]
    }

    /// All malformed lines.
    pub fn total(&self) -> u64 {
        self.0.iter().sum()
    }

    /// Non-zero counts by reason, in [`Reason::ALL`] order.
    pub fn nonzero(&self) -> impl Iterator<Item = (Reason, u64)> + '_ {
        Reason::ALL
            .iter()
            .zip(self.0)
            .filter(|(_, n)| *n > 0)
            .map(|(&r, n)| (r, n))
    }
}

/// A malformed line: where and why.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{} {line_no}: malformed {} ({reason})", reason.unit(), reason.record_kind())]
pub struct Malformed {
    /// 1-based line number.
    pub line_no: u64,
    /// What is wrong with it.
    pub reason: Reason,
}

/// Failure to read the next record.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The underlying reader failed; reading cannot go on.
    #[error("reading candump log: {0}")]
    Io(#[from] io::Error),
    /// This line is bad; the next call reads the following line.
    #[error(transparent)]
    Malformed(#[from] Malformed),
    /// A binary log's structure is broken where it says (BLF: the byte
    /// offset); reading cannot go on.
    #[error("{0}")]
    Corrupt(String),
}

#[cfg(test)]
mod tests;
