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

use crate::frame::{
    CAN_ERR_FLAG, CLASSIC_MAX_LEN, CanFrame, ERROR_FRAME_LEN, FD_MAX_LEN, FrameId, FrameKind,
    MAX_EXTENDED_ID, MAX_STANDARD_ID, is_fd_len,
};
use crate::time::Timestamp;
use std::fmt;
use std::io::{self, Read};

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

/// Bytes [`LogReader::new`] reads at a time: large reads keep the per-line
/// cost of I/O bookkeeping to a few instructions.
pub const DEFAULT_BUFFER_BYTES: usize = 1 << 18;

/// Streaming candump log reader over any `Read`.
///
/// The reader owns one block buffer: it reads large blocks, finds each line
/// with `memchr` and parses it in place (the record borrows the buffer until
/// the next call); only the unfinished tail of a block is moved to the front
/// before the next read. Memory is the buffer, whatever the log's length.
/// The interface name is kept in one reused `String`, so the common case,
/// a log of one interface, neither allocates nor re-validates it per line.
#[derive(Debug)]
pub struct LogReader<R> {
    inner: R,
    buf: Vec<u8>,
    /// First byte not yet handed out as a line.
    start: usize,
    /// End of the bytes read so far.
    end: usize,
    eof: bool,
    line_no: u64,
    /// The interface name of the last record parsed on the fast path.
    iface: String,
    /// The interfaces seen and the `--interface` filter.
    interfaces: Interfaces,
}

/// How many distinct interface names [`LogReader::interfaces`] keeps.
pub const MAX_INTERFACES_LISTED: usize = 32;

/// The interfaces a log reader has met (in order of appearance, at most
/// [`MAX_INTERFACES_LISTED`]) and the filter it applies, with the records
/// filtered out counted: the same for every log format.
#[derive(Debug, Default)]
pub(crate) struct Interfaces {
    only: Option<String>,
    seen: Vec<String>,
    other_lines: u64,
}

impl Interfaces {
    /// Notes `name`; `true` when the filter lets its records through (a
    /// record filtered out is counted).
    pub(crate) fn pass(&mut self, name: &str) -> bool {
        self.pass_bytes(name.as_bytes())
    }

    /// As [`Self::pass`] for a name as read (a name that is not UTF-8 is
    /// not listed).
    pub(crate) fn pass_bytes(&mut self, name: &[u8]) -> bool {
        if self.seen.len() < MAX_INTERFACES_LISTED
            && !self.seen.iter().any(|n| n.as_bytes() == name)
            && let Ok(text) = std::str::from_utf8(name)
        {
            // Owned only for a name not seen before (rare): reading does
            // not allocate per line.
            self.seen.push(text.to_owned());
        }
        let passes = self
            .only
            .as_deref()
            .is_none_or(|only| only.as_bytes() == name);
        if !passes {
            self.other_lines += 1;
        }
        passes
    }

    /// The names met.
    pub(crate) fn seen(&self) -> &[String] {
        &self.seen
    }

    /// Records filtered out.
    pub(crate) fn other_lines(&self) -> u64 {
        self.other_lines
    }

    /// Lets only `name`'s records through.
    pub(crate) fn only(&mut self, name: &str) {
        self.only = Some(name.to_owned());
    }
}

impl<R: Read> LogReader<R> {
    /// Wraps a reader (buffered or not: the reader does its own buffering).
    pub fn new(inner: R) -> Self {
        Self::with_capacity(DEFAULT_BUFFER_BYTES, inner)
    }

    /// As [`LogReader::new`] with a buffer of `bytes` (at least
    /// [`MAX_LINE_BYTES`] + 2, so a line of the longest accepted length
    /// and its newline always fit).
    pub fn with_capacity(bytes: usize, inner: R) -> Self {
        Self {
            inner,
            buf: vec![0; bytes.max(MAX_LINE_BYTES + 2)],
            start: 0,
            end: 0,
            eof: false,
            line_no: 0,
            iface: String::new(),
            interfaces: Interfaces::default(),
        }
    }

    /// Returns only the records of interface `name`; lines of other
    /// interfaces are skipped and counted ([`Self::other_interface_lines`]).
    #[must_use]
    pub fn only_interface(mut self, name: &str) -> Self {
        self.interfaces.only(name);
        self
    }

    /// The distinct interface names of the lines read so far, filtered out or
    /// not, in order of appearance: more than one means the log mixes buses.
    pub fn interfaces(&self) -> &[String] {
        self.interfaces.seen()
    }

    /// Lines skipped because they belong to another interface than the one
    /// asked for with [`Self::only_interface`].
    pub fn other_interface_lines(&self) -> u64 {
        self.interfaces.other_lines()
    }

    /// Number of the line most recently read (1-based; 0 before the first).
    pub fn line_no(&self) -> u64 {
        self.line_no
    }

    /// The next record, `Ok(None)` at end of input.
    ///
    /// # Errors
    /// [`ReadError::Malformed`] for a bad line, after which the reader is
    /// positioned on the next line; [`ReadError::Io`] when reading fails.
    pub fn next_record(&mut self) -> Result<Option<Record<'_>>, ReadError> {
        if let Some(classic) = self.next_common() {
            return Ok(Some(Record {
                timestamp: classic.timestamp,
                iface: &self.iface,
                frame: classic.frame(),
                direction: None,
            }));
        }
        self.next_record_general()
    }

    /// The next line if it is a classical data frame of the common shape
    /// (nearly every line of a real log), consumed, without building a
    /// [`CanFrame`] or its interface name; `None` leaves the line (any other
    /// kind, a malformed one, one not yet read whole, the end) to
    /// [`Self::next_record_general`]. A bulk reader alternates the two:
    /// together they read what [`Self::next_record`] reads, and the common
    /// record is built where the caller stores it, not returned through memory.
    // `always` (perf): as a call, the caller copied the record from the
    // stack right after this wrote it there field by field, and each copy
    // stalled on store forwarding (a third of replay's feeding loop).
    #[allow(clippy::inline_always)]
    #[inline(always)]
    pub fn next_classic(&mut self) -> Option<ClassicData> {
        self.next_common()
    }

    /// The next line if it has the common shape ([`parse_common`]), consumed.
    #[allow(clippy::inline_always)]
    #[inline(always)]
    fn next_common(&mut self) -> Option<ClassicData> {
        loop {
            // `self.iface` is only ever an accepted name, so a line of the
            // known interface needs no filtering: the common case stays as fast.
            let line = parse_common(&self.buf[self.start..self.end], self.iface.as_bytes())?;
            if !line.known_iface {
                let range = self.start + line.iface.start..self.start + line.iface.end;
                // `parse_common` checked it is printable ASCII; else the general
                // parser judges the line.
                let name = std::str::from_utf8(&self.buf[range.clone()])
                    .ok()?
                    .to_owned();
                if !self.interfaces.pass(&name) {
                    self.start += line.consumed;
                    self.line_no += 1;
                    continue;
                }
                self.iface = name;
            }
            self.start += line.consumed;
            self.line_no += 1;
            return Some(line.classic);
        }
    }

    /// [`Self::next_record`] without its fast path, for any line: finds its
    /// end, skips blank lines and enforces [`MAX_LINE_BYTES`], then parses
    /// with [`parse_line`]. For a bulk reader after [`Self::next_classic`]
    /// returned `None` (trying the fast path again would only fail again).
    ///
    /// # Errors
    /// As [`Self::next_record`].
    pub fn next_record_general(&mut self) -> Result<Option<Record<'_>>, ReadError> {
        let (line_start, len) = loop {
            let window_end = self.end.min(self.start + MAX_LINE_BYTES + 1);
            let window = &self.buf[self.start..window_end];
            let line_len = if let Some(pos) = memchr::memchr(b'\n', window) {
                pos
            } else if window.len() == MAX_LINE_BYTES + 1 {
                self.line_no += 1;
                self.start = window_end;
                self.skip_rest_of_line()?;
                return Err(Malformed {
                    line_no: self.line_no,
                    reason: Reason::LineTooLong,
                }
                .into());
            } else if self.eof {
                if window.is_empty() {
                    return Ok(None);
                }
                // The last line, without a newline.
                window.len()
            } else {
                self.refill()?;
                continue;
            };
            let line_start = self.start;
            self.start = (line_start + line_len + 1).min(self.end);
            self.line_no += 1;
            let len = trim_end(&self.buf[line_start..line_start + line_len]).len();
            if len == 0 {
                continue;
            }
            // The interface is the line's second word (after the time): the
            // filter and the list judge it before parsing, so a line of
            // another bus is skipped whatever its content.
            let line = &self.buf[line_start..line_start + len];
            let mut words = line
                .split(u8::is_ascii_whitespace)
                .filter(|w| !w.is_empty());
            // Only a line shaped as a record names an interface (garbage's
            // second word is not one).
            let (Some(b'('), Some(iface)) = (words.next().and_then(|w| w.first()), words.next())
            else {
                break (line_start, len);
            };
            if !self.interfaces.pass_bytes(iface) {
                continue;
            }
            break (line_start, len);
        };
        match parse_line(&self.buf[line_start..line_start + len]) {
            Ok(record) => Ok(Some(record)),
            Err(reason) => Err(Malformed {
                line_no: self.line_no,
                reason,
            }
            .into()),
        }
    }

    /// Moves the unread tail to the front and reads once; marks end of input.
    fn refill(&mut self) -> io::Result<()> {
        if self.start > 0 {
            self.buf.copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.start = 0;
        }
        loop {
            match self.inner.read(&mut self.buf[self.end..]) {
                Ok(0) => {
                    self.eof = true;
                    return Ok(());
                }
                Ok(n) => {
                    self.end += n;
                    return Ok(());
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
    }

    fn skip_rest_of_line(&mut self) -> io::Result<()> {
        loop {
            if let Some(pos) = memchr::memchr(b'\n', &self.buf[self.start..self.end]) {
                self.start += pos + 1;
                return Ok(());
            }
            self.start = self.end;
            if self.eof {
                return Ok(());
            }
            self.refill()?;
        }
    }
}

/// `a == b` for the few bytes of an interface name: slice equality calls
/// `memcmp`, whose call costs more than comparing five bytes in a loop.
#[inline]
fn same_bytes(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x == y)
}

fn trim_end(mut line: &[u8]) -> &[u8] {
    while let [rest @ .., last] = line {
        if last.is_ascii_whitespace() {
            line = rest;
        } else {
            break;
        }
    }
    line
}

const INVALID: u8 = 0xFF;

/// Hex digit value by byte, `INVALID` for non-hex bytes.
static HEX: [u8; 256] = {
    let mut table = [INVALID; 256];
    let mut i = 0;
    while i < 10 {
        table[b'0' as usize + i] = i as u8;
        i += 1;
    }
    let mut i = 0;
    while i < 6 {
        table[b'a' as usize + i] = 10 + i as u8;
        table[b'A' as usize + i] = 10 + i as u8;
        i += 1;
    }
    table
};

#[inline]
fn hex(b: u8) -> u8 {
    HEX[usize::from(b)]
}

/// A byte cursor over one line.
struct Cursor<'a> {
    s: &'a [u8],
    pos: usize,
}

impl Cursor<'_> {
    #[inline]
    fn peek(&self) -> Option<u8> {
        self.s.get(self.pos).copied()
    }

    #[inline]
    fn eat(&mut self, b: u8) -> bool {
        if self.peek() == Some(b) {
            self.pos += 1;
            true
        } else {
            false
        }
    }

    /// Decimal digits as u64; returns (value, digit count), `None` beyond
    /// 19 digits (which is where u64 could overflow).
    #[inline]
    fn decimal(&mut self) -> Option<(u64, usize)> {
        let start = self.pos;
        let mut value: u64 = 0;
        while let Some(&b) = self.s.get(self.pos) {
            let digit = b.wrapping_sub(b'0');
            if digit > 9 {
                break;
            }
            value = value.wrapping_mul(10).wrapping_add(u64::from(digit));
            self.pos += 1;
        }
        let n = self.pos - start;
        (n <= 19).then_some((value, n))
    }
}

/// What the fast path found: the record's parts and the line's length.
struct Common {
    classic: ClassicData,
    /// Where the interface name lies in the text.
    iface: std::ops::Range<usize>,
    /// Whether the name is `known_iface` (otherwise it differs).
    known_iface: bool,
    /// Bytes up to and with the line's `\n`.
    consumed: usize,
}

/// Eight ASCII decimal digits (most significant first) as a number, `None`
/// if any byte is not a digit: a few multiplications on one `u64` instead of
/// a loop of eight (the timestamps are most of a line's digits).
#[inline]
fn eight_digits(chunk: [u8; 8]) -> Option<u64> {
    const HIGH: u64 = 0xF0F0_F0F0_F0F0_F0F0;
    const ZEROS: u64 = 0x3030_3030_3030_3030;
    let v = u64::from_le_bytes(chunk);
    // Each byte 0x30..=0x39: high nibble 3, and still 3 after adding 6
    // (no byte can carry into the next: each is at most 0x3F + 6).
    if v & HIGH != ZEROS || v.wrapping_add(0x0606_0606_0606_0606) & HIGH != ZEROS {
        return None;
    }
    // Pairs, then quads, then the eight digits.
    let v = (v & 0x0F0F_0F0F_0F0F_0F0F).wrapping_mul(10 << 8 | 1) >> 8;
    let v = (v & 0x00FF_00FF_00FF_00FF).wrapping_mul(100 << 16 | 1) >> 16;
    Some((v & 0x0000_FFFF_0000_FFFF).wrapping_mul(10_000 << 32 | 1) >> 32)
}

/// Eight ASCII hex digits (either case, most significant first) as a
/// number, `None` if any byte is not a hex digit: a payload is 16 digits,
/// and a loop of table look-ups over them was a tenth of a replay's reading.
// `always`: as a call (two per line) it cost a third more than inlined.
#[inline(always)]
fn eight_hex_digits(chunk: [u8; 8]) -> Option<u32> {
    const ONES: u64 = 0x0101_0101_0101_0101;
    const HIGH_BITS: u64 = 0x8080_8080_8080_8080;
    let v = u64::from_le_bytes(chunk);
    if v & HIGH_BITS != 0 {
        return None;
    }
    // Per byte (all below 0x80, so no sum carries into the next byte): the
    // high bit of `x + 0x80 - lo` is set when x >= lo, that of
    // `x + 0x7F - hi` when x > hi.
    let in_range = |x: u64, lo: u64, hi: u64| {
        x.wrapping_add((0x80 - lo) * ONES) & !x.wrapping_add((0x7F - hi) * ONES) & HIGH_BITS
    };
    let digit = in_range(v, 0x30, 0x39);
    // `| 0x20` lower-cases letters (and maps nothing else into a..f).
    let letter = in_range(v | (0x20 * ONES), 0x61, 0x66);
    if digit | letter != HIGH_BITS {
        return None;
    }
    // Low nibble, plus 9 for a letter ('A' and 'a' end in 1).
    let nibbles = (v & (0x0F * ONES)) + (letter >> 7) * 9;
    // Byte pairs (first digit in the lower byte) into bytes, then together.
    let bytes = ((nibbles << 4) | (nibbles >> 8)) & 0x00FF_00FF_00FF_00FF;
    let bytes = (bytes | (bytes >> 8)) & 0x0000_FFFF_0000_FFFF;
    let bytes = (bytes | (bytes >> 16)) & 0xFFFF_FFFF;
    // The first digit pair is now the lowest byte: the most significant.
    Some((bytes as u32).swap_bytes())
}

/// The fast path for the shape nearly every line of a real log has: a
/// timestamp of at most 12 second digits, an interface name, a 3- or 8-digit
/// data frame id and up to 8 payload bytes as plain hex, then the newline
/// (`\n` or `\r\n`). `text` starts at a line and runs on past it: the
/// line's end is found while parsing, so the common line is read once and
/// never searched for its newline. Returns `None` for anything else (other
/// frame kinds, `-x` directions, dots, trailing blanks, a line not whole in
/// `text`, every malformed line), which the general [`parse_line`] then
/// parses or rejects, so errors and every other case come from one parser.
/// Whenever this returns a record, [`parse_line`] returns the same (tested).
///
/// `known_iface` is a name accepted before: an equal name is not checked again.
// `always` (measured): as a call, its result (with a 64-byte frame buffer)
// went through the stack twice; copying it was a fifth of this function's time.
#[allow(clippy::inline_always)]
#[inline(always)]
fn parse_common(text: &[u8], known_iface: &[u8]) -> Option<Common> {
    if text.first() != Some(&b'(') {
        return None;
    }
    let (secs, p) = if let Some([d0, d1, rest @ .., b'.']) = text.get(1..12) {
        // The usual 10 digits (years 2001 to 2286): eight of them at once.
        let (d0, d1) = (d0.wrapping_sub(b'0'), d1.wrapping_sub(b'0'));
        if d0 > 9 || d1 > 9 {
            return None;
        }
        let rest: [u8; 8] = rest.try_into().ok()?;
        let high = u64::from(d0) * 10 + u64::from(d1);
        (high * 100_000_000 + eight_digits(rest)?, 11)
    } else {
        let mut secs: u64 = 0;
        let mut p = 1;
        while let Some(&b) = text.get(p) {
            let digit = b.wrapping_sub(b'0');
            if digit > 9 || p > 12 {
                break;
            }
            secs = secs * 10 + u64::from(digit);
            p += 1;
        }
        (secs, p)
    };
    // 1..=12 digits (a 13th fails the `.` test below): no overflow below,
    // so no check as in `Timestamp::from_parts` is needed.
    if p == 1 {
        return None;
    }
    let [b'.', m0, m1, m2, m3, m4, m5, b')', b' '] = *text.get(p..p + 9)? else {
        return None;
    };
    let micros = eight_digits([b'0', b'0', m0, m1, m2, m3, m4, m5])?;
    let timestamp = Timestamp::from_micros(secs * 1_000_000 + micros);
    let iface_start = p + 9;
    let known_end = iface_start + known_iface.len();
    let known = !known_iface.is_empty()
        && text.get(known_end) == Some(&b' ')
        && same_bytes(&text[iface_start..known_end], known_iface);
    let q = if known {
        // The name of the line before (nearly always): no byte-wise search.
        known_end
    } else {
        let mut q = iface_start;
        while *text.get(q)? != b' ' {
            q += 1;
            if q - iface_start > MAX_IFACE_BYTES {
                return None;
            }
        }
        let name = &text[iface_start..q];
        if name.is_empty() || !name.iter().all(u8::is_ascii_graphic) {
            return None;
        }
        q
    };
    let id_start = q + 1;
    let digits = if text.get(id_start + 3) == Some(&b'#') {
        3
    } else if text.get(id_start + 8) == Some(&b'#') {
        8
    } else {
        return None;
    };
    let mut raw: u32 = 0;
    for &b in &text[id_start..id_start + digits] {
        let v = hex(b);
        if v == INVALID {
            return None;
        }
        raw = (raw << 4) | u32::from(v);
    }
    let id = match digits {
        3 if raw <= MAX_STANDARD_ID => FrameId::Standard(raw as u16),
        // Above MAX_EXTENDED_ID lie CAN_ERR_FLAG (error frames) and errors.
        8 if raw <= MAX_EXTENDED_ID => FrameId::Extended(raw),
        _ => return None,
    };
    let (data, len, end) = payload(text, id_start + digits + 1)?;
    let consumed = match text[end] {
        b'\n' => end + 1,
        b'\r' if text.get(end + 1) == Some(&b'\n') => end + 2,
        _ => return None,
    };
    Some(Common {
        classic: ClassicData {
            timestamp,
            id,
            // `payload` stops at CLASSIC_MAX_LEN bytes.
            len: len as u8,
            data,
        },
        iface: iface_start..q,
        known_iface: known,
        consumed,
    })
}

/// The payload of a [`parse_common`] line from `payload_start`: the bytes,
/// their count and where the hex digits end.
// `always` (measured): as a call it was a quarter of a line's parsing, and
// `#[inline]` alone left it a call.
#[allow(clippy::inline_always)]
#[inline(always)]
fn payload(text: &[u8], payload_start: usize) -> Option<([u8; CLASSIC_MAX_LEN], usize, usize)> {
    let mut data = [0u8; CLASSIC_MAX_LEN];
    let mut len = 0;
    let mut at = payload_start;
    // The usual 8-byte payload: 16 digits, then the line's end, at once. Any
    // other payload (or a non-hex byte) goes through the loop below.
    if let Some([chunk @ .., b'\n' | b'\r']) = text.get(payload_start..payload_start + 17)
        && let (Some(high), Some(low)) = (
            eight_hex_digits(chunk[..8].try_into().ok()?),
            eight_hex_digits(chunk[8..].try_into().ok()?),
        )
    {
        // One 8-byte store: two 4-byte ones, read back as one 8-byte load
        // when the frame is built, stalled store forwarding (perf).
        data = ((u64::from(high) << 32) | u64::from(low)).to_be_bytes();
        len = CLASSIC_MAX_LEN;
        at += 2 * CLASSIC_MAX_LEN;
    }
    let end = loop {
        let hi = hex(*text.get(at)?);
        if hi == INVALID {
            break at;
        }
        let lo = hex(*text.get(at + 1)?);
        if lo == INVALID || len == CLASSIC_MAX_LEN {
            return None;
        }
        data[len] = (hi << 4) | lo;
        len += 1;
        at += 2;
    };
    Some((data, len, end))
}

/// Parses one line (without its newline) into a record.
///
/// # Errors
/// The [`Reason`] the line is not a valid candump record.
#[inline]
pub fn parse_line(line: &[u8]) -> Result<Record<'_>, Reason> {
    let mut c = Cursor { s: line, pos: 0 };
    let timestamp = parse_timestamp(&mut c).ok_or(Reason::BadTimestamp)?;
    if !c.eat(b' ') {
        return Err(Reason::BadTimestamp);
    }
    let iface = parse_iface(&mut c)?;
    if !c.eat(b' ') {
        return Err(Reason::BadInterface);
    }
    let frame = parse_frame(&mut c)?;
    let direction = match &line[c.pos..] {
        [] => None,
        b" R" => Some(Direction::Rx),
        b" T" => Some(Direction::Tx),
        _ => return Err(Reason::TrailingGarbage),
    };
    Ok(Record {
        timestamp,
        iface,
        frame,
        direction,
    })
}

#[inline]
fn parse_timestamp(c: &mut Cursor<'_>) -> Option<Timestamp> {
    if !c.eat(b'(') {
        return None;
    }
    let (secs, n) = c.decimal()?;
    if n == 0 || !c.eat(b'.') {
        return None;
    }
    let (micros, n) = c.decimal()?;
    if n != 6 || !c.eat(b')') {
        return None;
    }
    Timestamp::from_parts(secs, micros as u32)
}

#[inline]
fn parse_iface<'a>(c: &mut Cursor<'a>) -> Result<&'a str, Reason> {
    let start = c.pos;
    while let Some(b) = c.peek() {
        if b == b' ' {
            break;
        }
        if !b.is_ascii_graphic() {
            return Err(Reason::BadInterface);
        }
        c.pos += 1;
    }
    let name = &c.s[start..c.pos];
    if name.is_empty() || name.len() > MAX_IFACE_BYTES {
        return Err(Reason::BadInterface);
    }
    // Every byte was checked to be printable ASCII, so this cannot fail.
    std::str::from_utf8(name).map_err(|_| Reason::BadInterface)
}

/// What an identifier field denotes.
enum Target {
    Id(FrameId),
    /// Error class bits (the id had `CAN_ERR_FLAG`).
    Error(u32),
}

#[inline]
fn parse_frame(c: &mut Cursor<'_>) -> Result<CanFrame, Reason> {
    let start = c.pos;
    let mut raw: u32 = 0;
    while let Some(b) = c.peek() {
        let v = hex(b);
        if v == INVALID || c.pos - start == 8 {
            break;
        }
        raw = (raw << 4) | u32::from(v);
        c.pos += 1;
    }
    let digits = c.pos - start;
    if !c.eat(b'#') {
        return Err(Reason::BadId);
    }
    let target = match digits {
        3 if raw <= MAX_STANDARD_ID => Target::Id(FrameId::Standard(raw as u16)),
        8 if raw & CAN_ERR_FLAG != 0 => {
            let class = raw & !CAN_ERR_FLAG;
            if class > MAX_EXTENDED_ID {
                return Err(Reason::IdOutOfRange);
            }
            Target::Error(class)
        }
        8 if raw <= MAX_EXTENDED_ID => Target::Id(FrameId::Extended(raw)),
        3 | 8 => return Err(Reason::IdOutOfRange),
        _ => return Err(Reason::BadId),
    };
    let mut data = [0u8; FD_MAX_LEN];
    if c.eat(b'#') {
        let Target::Id(id) = target else {
            return Err(Reason::BadErrorFrame);
        };
        let flags = c.peek().map_or(INVALID, hex);
        if flags == INVALID {
            return Err(Reason::BadFdFlags);
        }
        c.pos += 1;
        let len = parse_payload(c, &mut data, FD_MAX_LEN)?;
        if !is_fd_len(len) {
            return Err(Reason::BadFdLength);
        }
        return CanFrame::new_fd(id, flags, &data[..len]).map_err(|_| Reason::BadFdLength);
    }
    if c.peek() == Some(b'R') || c.peek() == Some(b'r') {
        let Target::Id(id) = target else {
            return Err(Reason::BadErrorFrame);
        };
        c.pos += 1;
        let mut len = 0;
        if let Some(b) = c.peek().filter(|&b| hex(b) != INVALID) {
            len = usize::from(hex(b));
            if len > CLASSIC_MAX_LEN {
                return Err(Reason::BadRemoteLength);
            }
            c.pos += 1;
        }
        let len8_dlc = parse_len8_dlc(c, len)?;
        return CanFrame::new_remote(id, len, len8_dlc).map_err(|_| Reason::BadLen8Dlc);
    }
    match target {
        Target::Id(id) => {
            let len = parse_payload(c, &mut data, CLASSIC_MAX_LEN)?;
            let len8_dlc = parse_len8_dlc(c, len)?;
            CanFrame::new_data_with_dlc(id, &data[..len], len8_dlc).map_err(|_| Reason::BadLen8Dlc)
        }
        Target::Error(class) => {
            let len = parse_payload(c, &mut data, ERROR_FRAME_LEN)?;
            if len != ERROR_FRAME_LEN || c.peek() == Some(b'_') {
                return Err(Reason::BadErrorFrame);
            }
            let mut detail = [0; ERROR_FRAME_LEN];
            detail.copy_from_slice(&data[..ERROR_FRAME_LEN]);
            CanFrame::new_error(class, detail).map_err(|_| Reason::IdOutOfRange)
        }
    }
}

/// Hex byte pairs (optionally `.`-separated) up to the next space, `_` or end.
#[inline]
fn parse_payload(
    c: &mut Cursor<'_>,
    data: &mut [u8; FD_MAX_LEN],
    max: usize,
) -> Result<usize, Reason> {
    let mut len = 0;
    loop {
        match c.peek() {
            None | Some(b' ' | b'_') => return Ok(len),
            Some(b'.') => {
                c.pos += 1;
                continue;
            }
            Some(_) => {}
        }
        let (Some(&hi), Some(&lo)) = (c.s.get(c.pos), c.s.get(c.pos + 1)) else {
            return Err(Reason::BadHex);
        };
        let (hi, lo) = (hex(hi), hex(lo));
        if hi == INVALID || lo == INVALID {
            return Err(Reason::BadHex);
        }
        if len == max {
            return Err(Reason::TooLong);
        }
        data[len] = (hi << 4) | lo;
        len += 1;
        c.pos += 2;
    }
}

#[inline]
fn parse_len8_dlc(c: &mut Cursor<'_>, len: usize) -> Result<Option<u8>, Reason> {
    if !c.eat(b'_') {
        return Ok(None);
    }
    let dlc = c.peek().map_or(INVALID, hex);
    if len != CLASSIC_MAX_LEN || !(9..=15).contains(&dlc) {
        return Err(Reason::BadLen8Dlc);
    }
    c.pos += 1;
    Ok(Some(dlc))
}

const UPPER_HEX: &[u8; 16] = b"0123456789ABCDEF";

#[inline]
fn push_hex_fixed(out: &mut Vec<u8>, value: u32, digits: u32) {
    for shift in (0..digits).rev() {
        out.push(UPPER_HEX[((value >> (shift * 4)) & 0xF) as usize]);
    }
}

#[inline]
fn push_decimal_padded(out: &mut Vec<u8>, mut value: u64, width: usize) {
    let mut buf = [b'0'; 20];
    let mut i = buf.len();
    while value > 0 {
        i -= 1;
        buf[i] = b'0' + (value % 10) as u8;
        value /= 10;
    }
    let start = i.min(buf.len() - width);
    out.extend_from_slice(&buf[start..]);
}

/// Appends the candump spelling of `frame` (`123#DEADBEEF`, `123##1AB`, …).
pub fn format_frame(out: &mut Vec<u8>, frame: &CanFrame) {
    let raw_dlc = |out: &mut Vec<u8>, len8: Option<u8>| {
        if let Some(dlc) = len8 {
            out.push(b'_');
            out.push(UPPER_HEX[usize::from(dlc & 0xF)]);
        }
    };
    match frame.kind() {
        FrameKind::Error => push_hex_fixed(out, frame.id().raw() | CAN_ERR_FLAG, 8),
        _ => match frame.id() {
            FrameId::Standard(id) => push_hex_fixed(out, u32::from(id), 3),
            FrameId::Extended(id) => push_hex_fixed(out, id, 8),
        },
    }
    out.push(b'#');
    match frame.kind() {
        FrameKind::Remote { len8_dlc } => {
            out.push(b'R');
            if !frame.is_empty() {
                out.push(UPPER_HEX[frame.len()]);
            }
            raw_dlc(out, len8_dlc);
            return;
        }
        FrameKind::Fd { flags } => {
            out.push(b'#');
            out.push(UPPER_HEX[usize::from(flags & 0xF)]);
        }
        FrameKind::Data { .. } | FrameKind::Error => {}
    }
    for &b in frame.data() {
        out.push(UPPER_HEX[usize::from(b >> 4)]);
        out.push(UPPER_HEX[usize::from(b & 0xF)]);
    }
    if let FrameKind::Data { len8_dlc } = frame.kind() {
        raw_dlc(out, len8_dlc);
    }
}

/// Appends one full log line, newline included, as `candump -L` writes it.
pub fn format_record(out: &mut Vec<u8>, record: &Record<'_>) {
    out.push(b'(');
    push_decimal_padded(out, record.timestamp.secs(), 10);
    out.push(b'.');
    push_decimal_padded(out, u64::from(record.timestamp.subsec_micros()), 6);
    out.extend_from_slice(b") ");
    out.extend_from_slice(record.iface.as_bytes());
    out.push(b' ');
    format_frame(out, &record.frame);
    match record.direction {
        None => {}
        Some(Direction::Rx) => out.extend_from_slice(b" R"),
        Some(Direction::Tx) => out.extend_from_slice(b" T"),
    }
    out.push(b'\n');
}

impl fmt::Display for Record<'_> {
    /// The log line without its newline.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut buf = Vec::with_capacity(64);
        format_record(&mut buf, self);
        buf.pop();
        f.write_str(&String::from_utf8_lossy(&buf))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{ErrorSeverity, err_class};
    use proptest::prelude::*;

    fn parse(s: &str) -> Result<Record<'_>, Reason> {
        parse_line(s.as_bytes())
    }

    /// Every record `reader` returns, through the fast and general paths
    /// as replay alternates them, as `(iface, id)`.
    fn read_all(mut reader: LogReader<&[u8]>) -> (Vec<(String, u32)>, LogReader<&[u8]>) {
        let mut out = Vec::new();
        loop {
            if let Some(c) = reader.next_classic() {
                out.push((reader.iface.clone(), c.id.raw()));
                continue;
            }
            match reader.next_record_general() {
                Ok(Some(r)) => out.push((r.iface.to_owned(), r.frame.id().raw())),
                Ok(None) => return (out, reader),
                Err(ReadError::Malformed(_)) => {}
                Err(e @ (ReadError::Io(_) | ReadError::Corrupt(_))) => panic!("{e}"),
            }
        }
    }

    const TWO_BUSES: &str = "(1.000001) can0 100#11\n(1.000002) can1 200#22\n\
        (1.000003) can0 101##1AA\n(1.000004) can1 201##1BB\ngarbage words here\n\
        (1.000005) can0 102#33\n(1.000006) can1 202#R\n";

    #[test]
    fn the_interfaces_of_a_log_are_listed_in_order() {
        let (records, reader) = read_all(LogReader::new(TWO_BUSES.as_bytes()));
        assert_eq!(records.len(), 6);
        assert_eq!(reader.interfaces(), ["can0", "can1"]);
        assert_eq!(reader.other_interface_lines(), 0);
    }

    #[test]
    fn an_interface_filter_keeps_one_bus_on_both_paths() {
        let (records, reader) =
            read_all(LogReader::new(TWO_BUSES.as_bytes()).only_interface("can1"));
        assert_eq!(
            records,
            [
                ("can1".to_owned(), 0x200),
                ("can1".to_owned(), 0x201),
                ("can1".to_owned(), 0x202)
            ]
        );
        assert_eq!(reader.other_interface_lines(), 3);
        assert_eq!(reader.interfaces(), ["can0", "can1"]);
        let (none, reader) = read_all(LogReader::new(TWO_BUSES.as_bytes()).only_interface("can9"));
        assert!(none.is_empty());
        assert_eq!(reader.other_interface_lines(), 6);
    }

    fn roundtrip(s: &str) {
        let rec = parse(s).unwrap_or_else(|r| panic!("{s}: {r}"));
        let mut out = Vec::new();
        format_record(&mut out, &rec);
        assert_eq!(String::from_utf8(out).unwrap(), format!("{s}\n"));
    }

    #[test]
    fn classical_data_frame() {
        let r = parse("(1700000000.123456) vcan0 123#DEADBEEF").unwrap();
        assert_eq!(r.timestamp.secs(), 1_700_000_000);
        assert_eq!(r.timestamp.subsec_micros(), 123_456);
        assert_eq!(r.iface, "vcan0");
        assert_eq!(r.frame.id(), FrameId::Standard(0x123));
        assert_eq!(r.frame.data(), &[0xDE, 0xAD, 0xBE, 0xEF]);
        assert_eq!(r.frame.kind(), FrameKind::Data { len8_dlc: None });
        assert_eq!(r.direction, None);
    }

    #[test]
    fn id_width_decides_format() {
        let ext = parse("(0000000001.000000) can0 00000123#01").unwrap();
        assert_eq!(ext.frame.id(), FrameId::Extended(0x123));
        let max = parse("(0000000001.000000) can0 1FFFFFFF#").unwrap();
        assert_eq!(max.frame.id(), FrameId::Extended(0x1FFF_FFFF));
        assert!(max.frame.is_empty());
        assert_eq!(parse("(1.000000) can0 800#01"), Err(Reason::IdOutOfRange));
        assert_eq!(
            parse("(1.000000) can0 40000000#01"),
            Err(Reason::IdOutOfRange)
        );
        assert_eq!(parse("(1.000000) can0 12#01"), Err(Reason::BadId));
        assert_eq!(parse("(1.000000) can0 1234#01"), Err(Reason::BadId));
        assert_eq!(parse("(1.000000) can0 123456789#01"), Err(Reason::BadId));
        assert_eq!(parse("(1.000000) can0 12G#01"), Err(Reason::BadId));
    }

    #[test]
    fn fd_frames() {
        let r = parse("(1.000000) can0 123##5DEADBEEF").unwrap();
        assert_eq!(r.frame.kind(), FrameKind::Fd { flags: 5 });
        assert_eq!(r.frame.data(), &[0xDE, 0xAD, 0xBE, 0xEF]);
        let long = format!("(1.000000) can0 1ABCDEF0##1{}", "A5".repeat(64));
        assert_eq!(parse(&long).unwrap().frame.len(), 64);
        let too_long = format!("(1.000000) can0 123##1{}", "A5".repeat(65));
        assert_eq!(parse(&too_long), Err(Reason::TooLong));
        let odd_len = format!("(1.000000) can0 123##1{}", "A5".repeat(9));
        assert_eq!(parse(&odd_len), Err(Reason::BadFdLength));
        assert_eq!(parse("(1.000000) can0 123##"), Err(Reason::BadFdFlags));
        assert_eq!(parse("(1.000000) can0 123##X00"), Err(Reason::BadFdFlags));
        // An empty FD frame with flags only is valid.
        assert_eq!(parse("(1.000000) can0 123##4").unwrap().frame.len(), 0);
    }

    #[test]
    fn remote_frames() {
        let r = parse("(1.000000) can0 123#R").unwrap();
        assert_eq!(r.frame.kind(), FrameKind::Remote { len8_dlc: None });
        assert_eq!(r.frame.len(), 0);
        let r4 = parse("(1.000000) can0 123#R4").unwrap();
        assert_eq!(r4.frame.len(), 4);
        assert!(r4.frame.data().is_empty());
        assert_eq!(parse("(1.000000) can0 123#r2").unwrap().frame.len(), 2);
        assert_eq!(
            parse("(1.000000) can0 123#R9"),
            Err(Reason::BadRemoteLength)
        );
        let r8e = parse("(1.000000) can0 123#R8_E").unwrap();
        assert_eq!(r8e.frame.kind(), FrameKind::Remote { len8_dlc: Some(14) });
        assert_eq!(parse("(1.000000) can0 123#R4_E"), Err(Reason::BadLen8Dlc));
        assert_eq!(
            parse("(1.000000) can0 123#R4X"),
            Err(Reason::TrailingGarbage)
        );
    }

    #[test]
    fn raw_dlc_suffix() {
        let r = parse("(1.000000) can0 123#1122334455667788_F").unwrap();
        assert_eq!(r.frame.kind(), FrameKind::Data { len8_dlc: Some(15) });
        assert_eq!(
            parse("(1.000000) can0 123#11223344556677_9"),
            Err(Reason::BadLen8Dlc)
        );
        assert_eq!(
            parse("(1.000000) can0 123#1122334455667788_8"),
            Err(Reason::BadLen8Dlc)
        );
        assert_eq!(
            parse("(1.000000) can0 123#1122334455667788_"),
            Err(Reason::BadLen8Dlc)
        );
    }

    #[test]
    fn error_frames_are_recognised_and_classified() {
        let r = parse("(1.000000) can0 20000044#0020000000008000").unwrap();
        let err = r.frame.as_error().unwrap();
        assert_eq!(err.class, err_class::BUS_OFF | err_class::CONTROLLER);
        assert_eq!(err.severity(), ErrorSeverity::BusOff);
        let passive = parse("(1.000000) can0 20000204#0010000000000080").unwrap();
        let e = passive.frame.as_error().unwrap();
        assert_eq!(e.severity(), ErrorSeverity::ErrorPassive);
        assert_eq!(e.error_counters(), Some((0, 0x80)));
        assert_eq!(
            parse("(1.000000) can0 20000004#00"),
            Err(Reason::BadErrorFrame)
        );
        assert_eq!(
            parse("(1.000000) can0 20000004#R"),
            Err(Reason::BadErrorFrame)
        );
        assert_eq!(
            parse("(1.000000) can0 20000004##100"),
            Err(Reason::BadErrorFrame)
        );
        assert_eq!(
            parse("(1.000000) can0 20000004#0000000000000000_9"),
            Err(Reason::BadErrorFrame)
        );
        assert_eq!(
            parse("(1.000000) can0 60000004#0000000000000000"),
            Err(Reason::IdOutOfRange)
        );
    }

    #[test]
    fn timestamps() {
        assert_eq!(parse("1.000000 can0 123#"), Err(Reason::BadTimestamp));
        assert_eq!(parse("(1.00000) can0 123#"), Err(Reason::BadTimestamp));
        assert_eq!(parse("(1.0000000) can0 123#"), Err(Reason::BadTimestamp));
        assert_eq!(parse("(.000000) can0 123#"), Err(Reason::BadTimestamp));
        assert_eq!(parse("(1.000000 can0 123#"), Err(Reason::BadTimestamp));
        assert_eq!(parse("(1.000000)can0 123#"), Err(Reason::BadTimestamp));
        assert_eq!(
            parse("(99999999999999999999.000000) can0 123#"),
            Err(Reason::BadTimestamp)
        );
        assert_eq!(
            parse("(18446744073709.551616) c 123#"),
            Err(Reason::BadTimestamp)
        );
        let t = parse("(18446744073708.551615) c 123#").unwrap().timestamp;
        assert_eq!(t.as_micros(), 18_446_744_073_708_551_615);
        let t = parse("(1700000000.000001) c 123#").unwrap().timestamp;
        assert_eq!(t.as_micros(), 1_700_000_000_000_001);
        assert_eq!(t.as_secs_f64(), 1_700_000_000.000_001);
        assert_eq!(t.to_string(), "1700000000.000001");
    }

    #[test]
    fn interface_and_trailer() {
        assert_eq!(parse("(1.000000)  123#"), Err(Reason::BadInterface));
        assert_eq!(parse("(1.000000) can0"), Err(Reason::BadInterface));
        assert_eq!(parse("(1.000000) can\t0 123#"), Err(Reason::BadInterface));
        let long = format!("(1.000000) {} 123#", "x".repeat(65));
        assert_eq!(parse(&long), Err(Reason::BadInterface));
        assert_eq!(
            parse("(1.000000) can0 123#01 R").unwrap().direction,
            Some(Direction::Rx)
        );
        assert_eq!(
            parse("(1.000000) can0 123#01 T").unwrap().direction,
            Some(Direction::Tx)
        );
        assert_eq!(
            parse("(1.000000) can0 123#01 X"),
            Err(Reason::TrailingGarbage)
        );
        assert_eq!(
            parse("(1.000000) can0 123#01 R extra"),
            Err(Reason::TrailingGarbage)
        );
        assert_eq!(
            parse("(1.000000) can0 123#01  R"),
            Err(Reason::TrailingGarbage)
        );
    }

    #[test]
    fn payload_errors() {
        assert_eq!(parse("(1.000000) can0 123#0"), Err(Reason::BadHex));
        assert_eq!(parse("(1.000000) can0 123#0G"), Err(Reason::BadHex));
        assert_eq!(
            parse("(1.000000) can0 123#001122334455667788"),
            Err(Reason::TooLong)
        );
        // canplayer's optional dots and lower case are accepted.
        let r = parse("(1.000000) can0 123#de.ad.be.ef").unwrap();
        assert_eq!(r.frame.data(), &[0xDE, 0xAD, 0xBE, 0xEF]);
    }

    #[test]
    fn canonical_lines_round_trip_to_identical_text() {
        for line in [
            "(1700000000.123456) vcan0 123#DEADBEEF",
            "(1700000000.000000) vcan0 123#",
            "(0000000001.000001) can1 00000123#0102030405060708",
            "(1700000000.123456) vcan0 123#1122334455667788_E",
            "(1700000000.123456) vcan0 123#R",
            "(1700000000.123456) vcan0 1FFFFFFF#R8_9",
            "(1700000000.123456) vcan0 123#R4",
            "(1700000000.123456) vcan0 123##5DEADBEEF",
            "(1700000000.123456) vcan0 123##0",
            "(1700000000.123456) vcan0 20000004#000C000000000000",
            "(1700000000.123456) vcan0 7FF#00 T",
            "(12345678901.999999) a-very.long_name 7FF#00 R",
        ] {
            roundtrip(line);
        }
    }

    #[test]
    fn reader_reports_line_numbers_and_recovers() {
        let long = "x".repeat(MAX_LINE_BYTES + 100);
        let log = format!(
            "(1.000000) can0 123#01\n\ngarbage\r\n(2.000000) can0 124#02\r\n{long}\n(3.000000) can0 125#03"
        );
        let mut r = LogReader::new(log.as_bytes());
        let first = r.next_record().unwrap().unwrap();
        assert_eq!(first.frame.id(), FrameId::Standard(0x123));
        match r.next_record() {
            Err(ReadError::Malformed(m)) => {
                assert_eq!(
                    m,
                    Malformed {
                        line_no: 3,
                        reason: Reason::BadTimestamp
                    }
                );
                assert_eq!(
                    m.to_string(),
                    "line 3: malformed candump record (bad_timestamp)"
                );
            }
            other => panic!("{other:?}"),
        }
        let second = r.next_record().unwrap().unwrap();
        assert_eq!(second.timestamp.secs(), 2);
        assert_eq!(second.frame.data(), &[2]);
        match r.next_record() {
            Err(ReadError::Malformed(m)) => {
                assert_eq!(
                    m,
                    Malformed {
                        line_no: 5,
                        reason: Reason::LineTooLong
                    }
                );
            }
            other => panic!("{other:?}"),
        }
        let third = r.next_record().unwrap().unwrap();
        assert_eq!(third.frame.id(), FrameId::Standard(0x125));
        assert_eq!(r.line_no(), 6);
        assert!(r.next_record().unwrap().is_none());
        assert!(r.next_record().unwrap().is_none());
    }

    #[test]
    fn malformed_lines_are_counted_by_reason() {
        let log = "(1.000000) can0 123#01\nnot a record\n(1.000000) can0 800#00\n\
                   (2.000000) can0 124#0G\n(3.000000) can0 125#\njunk\n";
        let mut r = LogReader::new(log.as_bytes());
        let (mut counts, mut frames) = (MalformedCounts::default(), 0);
        loop {
            match r.next_record() {
                Ok(Some(_)) => frames += 1,
                Ok(None) => break,
                Err(ReadError::Malformed(m)) => counts.add(m.reason),
                Err(e @ (ReadError::Io(_) | ReadError::Corrupt(_))) => panic!("{e}"),
            }
        }
        assert_eq!(frames, 2);
        assert_eq!(counts.total(), 4);
        assert_eq!(counts.get(Reason::BadTimestamp), 2);
        assert_eq!(
            counts.nonzero().collect::<Vec<_>>(),
            [
                (Reason::BadTimestamp, 2),
                (Reason::IdOutOfRange, 1),
                (Reason::BadHex, 1)
            ]
        );
        // Every reason has its own slot and a distinct statistics name.
        let names: std::collections::HashSet<_> = Reason::ALL.iter().map(|r| r.as_str()).collect();
        assert_eq!(names.len(), Reason::ALL.len());
        let mut all = MalformedCounts::default();
        for r in Reason::ALL {
            all.add(r);
        }
        assert!(Reason::ALL.iter().all(|&r| all.get(r) == 1));
    }

    #[test]
    fn reader_surfaces_io_errors() {
        struct Failing;
        impl Read for Failing {
            fn read(&mut self, _: &mut [u8]) -> io::Result<usize> {
                Err(io::Error::other("disk on fire"))
            }
        }
        let mut r = LogReader::new(io::BufReader::new(Failing));
        assert!(matches!(r.next_record(), Err(ReadError::Io(_))));
    }

    fn r_line(rec: &Record<'_>) -> String {
        rec.to_string()
    }

    /// Hands out at most `chunk` bytes per read, as a pipe or socket may.
    struct Trickle<'a> {
        data: &'a [u8],
        chunk: usize,
    }

    impl Read for Trickle<'_> {
        fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
            let n = buf.len().min(self.chunk).min(self.data.len());
            buf[..n].copy_from_slice(&self.data[..n]);
            self.data = &self.data[n..];
            Ok(n)
        }
    }

    #[test]
    fn eight_digits_reads_digits_and_refuses_the_rest() {
        assert_eq!(eight_digits(*b"01234567"), Some(1_234_567));
        assert_eq!(eight_digits(*b"99999999"), Some(99_999_999));
        assert_eq!(eight_digits(*b"00000000"), Some(0));
        // Each byte next to the digit range, in each position.
        for i in 0..8 {
            for bad in [b'/', b':', b'0' + 0x80, b' ', 0, 0xFF, b'?'] {
                let mut chunk = *b"12345678";
                chunk[i] = bad;
                assert_eq!(eight_digits(chunk), None, "{chunk:?}");
            }
        }
    }

    #[test]
    fn eight_hex_digits_refuses_every_other_byte_in_every_position() {
        for i in 0..8 {
            for b in 0..=u8::MAX {
                let mut chunk = *b"09afAF5c";
                chunk[i] = b;
                let expected = chunk.iter().try_fold(0u32, |n, &b| {
                    (hex(b) != INVALID).then(|| n << 4 | u32::from(hex(b)))
                });
                assert_eq!(eight_hex_digits(chunk), expected, "{chunk:?}");
            }
        }
        assert_eq!(eight_hex_digits(*b"DEADbeef"), Some(0xDEAD_BEEF));
    }

    #[test]
    fn common_lines_take_the_fast_path_and_others_do_not() {
        let fast = |s: &str| {
            parse_common(format!("{s}\n").as_bytes(), b"")
                .map(|c| (c.classic.timestamp, c.classic.frame()))
        };
        let r = parse("(1700000000.123456) vcan0 123#DEADBEEF").unwrap();
        assert_eq!(
            fast("(1700000000.123456) vcan0 123#DEADBEEF"),
            Some((r.timestamp, r.frame))
        );
        assert!(fast("(1.000000) can0 1FFFFFFF#").is_some());
        for other in [
            "(1.000000) can0 123#DE.AD",
            "(1.000000) can0 123#R",
            "(1.000000) can0 123##1DEADBEEF",
            "(1.000000) can0 123#01 R",
            "(1.000000) can0 123#1122334455667788_E",
            "(1.000000) can0 20000004#000C000000000000",
            "(1700000000123.000000) can0 123#",
            "(1.000000) can0 800#01",
            "(1.000000) can0 123#0",
            "(1.000000) can0 123#0G",
            "(1.000000) can0 123#00 ",
        ] {
            assert_eq!(fast(other), None, "{other}");
        }
        // A line not whole in the text is left to the general reader.
        assert!(parse_common(b"(1.000000) can0 123#00", b"").is_none());
        assert!(parse_common(b"(1.000000) can0 123#00\r", b"").is_none());
    }

    fn arb_id() -> impl Strategy<Value = FrameId> {
        prop_oneof![
            (0..=MAX_STANDARD_ID).prop_map(|v| FrameId::Standard(v as u16)),
            (0..=MAX_EXTENDED_ID).prop_map(FrameId::Extended),
        ]
    }

    prop_compose! {
        fn arb_frame()(
            id in arb_id(),
            sel in 0..4u8,
            bytes in proptest::collection::vec(any::<u8>(), 0..=64),
            flags in 0..16u8,
            rtr_len in 0..=8usize,
            len8 in proptest::option::of(9..=15u8),
            class in 0..=MAX_EXTENDED_ID,
        ) -> CanFrame {
            match sel {
                0 => {
                    let b = &bytes[..bytes.len().min(8)];
                    let len8 = if b.len() == 8 { len8 } else { None };
                    CanFrame::new_data_with_dlc(id, b, len8).unwrap()
                }
                1 => {
                    let len8 = if rtr_len == 8 { len8 } else { None };
                    CanFrame::new_remote(id, rtr_len, len8).unwrap()
                }
                2 => {
                    let mut n = bytes.len();
                    while !is_fd_len(n) { n -= 1; }
                    CanFrame::new_fd(id, flags, &bytes[..n]).unwrap()
                }
                _ => {
                    let mut d = [0; 8];
                    for (dst, src) in d.iter_mut().zip(&bytes) { *dst = *src; }
                    CanFrame::new_error(class, d).unwrap()
                }
            }
        }
    }

    proptest! {
        #[test]
        fn format_then_parse_is_identity(
            micros in 0u64..=99_999_999_999_999_999,
            iface in "[a-zA-Z0-9_.:-]{1,16}",
            frame in arb_frame(),
            dir in proptest::option::of(prop_oneof![Just(Direction::Rx), Just(Direction::Tx)]),
        ) {
            let rec = Record { timestamp: Timestamp::from_micros(micros), iface: &iface, frame, direction: dir };
            let mut out = Vec::new();
            format_record(&mut out, &rec);
            let text = std::str::from_utf8(&out).unwrap();
            prop_assert!(text.ends_with('\n'));
            let parsed = parse_line(&out[..out.len() - 1]).map_err(|r| TestCaseError::fail(format!("{text}: {r}")))?;
            prop_assert_eq!(parsed, rec);
            prop_assert_eq!(format!("{parsed}\n"), text);
        }

        /// socketcan's `dump` reader (an independent implementation of the
        /// format) reads our output as we do, and writes the same text.
        /// Excluded: the `_` raw DLC, which it does not support, and FD
        /// frames without the FDF flag, which it always sets.
        #[test]
        fn socketcan_dump_agrees(
            // 10-digit seconds: candump zero-pads to 10, socketcan does not pad.
            micros in 1_000_000_000_000_000u64..=9_999_999_999_999_999,
            frame in arb_frame(),
            dir in proptest::option::of(prop_oneof![Just(Direction::Rx), Just(Direction::Tx)]),
        ) {
            use socketcan::{CanAnyFrame, EmbeddedFrame, Frame as _};
            let frame = match frame.kind() {
                FrameKind::Data { len8_dlc: Some(_) } => CanFrame::new_data(frame.id(), frame.data()).unwrap(),
                FrameKind::Remote { len8_dlc: Some(_) } => CanFrame::new_remote(frame.id(), frame.len(), None).unwrap(),
                FrameKind::Fd { flags } => CanFrame::new_fd(frame.id(), flags | 0x4, frame.data()).unwrap(),
                _ => frame,
            };
            let rec = Record { timestamp: Timestamp::from_micros(micros), iface: "can0", frame, direction: dir };
            let mut out = Vec::new();
            format_record(&mut out, &rec);
            let mut theirs = socketcan::dump::Reader::from_reader(&out[..]);
            let other = theirs.next_record().unwrap().unwrap();
            prop_assert_eq!(other.t_us, micros);
            prop_assert_eq!(&other.device, "can0");
            prop_assert_eq!(other.direction.is_some(), dir.is_some());
            let expected_id = frame.id().raw() | match frame.kind() {
                FrameKind::Error => CAN_ERR_FLAG,
                _ if frame.id().is_extended() => 0x8000_0000,
                _ => 0,
            };
            match (&other.frame, frame.kind()) {
                (CanAnyFrame::Normal(f), FrameKind::Data { .. }) => {
                    prop_assert_eq!(f.data(), frame.data());
                    prop_assert_eq!(f.id_word(), expected_id);
                }
                (CanAnyFrame::Remote(f), FrameKind::Remote { .. }) => {
                    prop_assert_eq!(f.dlc(), frame.len());
                    prop_assert_eq!(f.id_word() & !0x4000_0000, expected_id);
                }
                (CanAnyFrame::Fd(f), FrameKind::Fd { flags }) => {
                    prop_assert_eq!(f.data(), frame.data());
                    // Its `flags()` truncates to the named bits; the text keeps all four.
                    prop_assert_eq!(f.flags().bits(), flags & 0x7);
                    prop_assert_eq!(f.id_word(), expected_id);
                }
                (CanAnyFrame::Error(f), FrameKind::Error) => {
                    prop_assert_eq!(f.data(), frame.data());
                    prop_assert_eq!(f.id_word(), expected_id);
                }
                (theirs, ours) => prop_assert!(false, "kind mismatch: {:?} vs {:?}", theirs, ours),
            }
            prop_assert_eq!(format!("{other}\n"), String::from_utf8(out).unwrap());
        }

        /// Whatever the buffer size and however the input trickles in, the
        /// reader gives the records, errors and line numbers of an obvious
        /// reference: split at newlines, cut to size, trim, `parse_line`.
        #[test]
        fn reader_matches_the_obvious_reference(
            lines in proptest::collection::vec(prop_oneof![
                4 => (arb_frame(), 0u64..=99_999_999_999_999, "[a-z]{1,3}[0-9]?").prop_map(|(frame, t, iface)| {
                    let mut out = Vec::new();
                    format_record(&mut out, &Record { timestamp: Timestamp::from_micros(t), iface: &iface, frame, direction: None });
                    out.pop();
                    String::from_utf8(out).unwrap()
                }),
                1 => "[ -~]{0,80}",
                1 => Just(String::new()),
                1 => Just(" \t".to_string()),
                1 => (MAX_LINE_BYTES - 2..MAX_LINE_BYTES + 3).prop_map(|n| "x".repeat(n)),
            ], 0..40),
            crlf in any::<bool>(),
            final_newline in any::<bool>(),
            capacity in prop_oneof![Just(0usize), Just(MAX_LINE_BYTES + 7), Just(4096)],
            chunk in prop_oneof![Just(1usize), 2..300usize, Just(usize::MAX)],
        ) {
            let sep = if crlf { "\r\n" } else { "\n" };
            let mut log = lines.join(sep);
            if final_newline {
                log.push_str(sep);
            }
            let mut reference = Vec::new();
            let mut text = log.as_bytes();
            let mut line_no = 0;
            while !text.is_empty() {
                let (line, rest) = match text.iter().position(|&b| b == b'\n') {
                    Some(i) => (&text[..i], &text[i + 1..]),
                    None => (text, &text[text.len()..]),
                };
                text = rest;
                line_no += 1;
                if line.len() > MAX_LINE_BYTES {
                    reference.push(Err(Malformed { line_no, reason: Reason::LineTooLong }));
                    continue;
                }
                let line = trim_end(line);
                if !line.is_empty() {
                    reference.push(parse_line(line).map(|r| (r.to_string(), r.frame)).map_err(|reason| Malformed { line_no, reason }));
                }
            }
            let mut r = LogReader::with_capacity(capacity, Trickle { data: log.as_bytes(), chunk });
            let mut got = Vec::new();
            loop {
                match r.next_record() {
                    Ok(Some(rec)) => got.push(Ok((r_line(&rec), rec.frame))),
                    Ok(None) => break,
                    Err(ReadError::Malformed(m)) => got.push(Err(m)),
                    Err(e @ (ReadError::Io(_) | ReadError::Corrupt(_))) => panic!("{e}"),
                }
            }
            prop_assert_eq!(got, reference);
            prop_assert_eq!(r.line_no(), line_no);
        }

        /// The fast path accepts only what the general parser accepts, as
        /// the same record, on valid lines of every kind and on mutations.
        #[test]
        fn fast_path_agrees_with_the_general_parser(
            micros in prop_oneof![
                0u64..=99_999_999_999_999_999,
                // 10 and 13 second digits: the usual and one beyond the fast path's 12.
                0u64..=9_999_999_999_999_999,
                1_000_000_000_000_000_000u64..=1_999_999_999_999_999_999,
            ],
            iface in "[a-zA-Z0-9_.:-]{1,16}",
            frame in arb_frame(),
            dir in proptest::option::of(prop_oneof![Just(Direction::Rx), Just(Direction::Tx)]),
            mutation in proptest::option::of((any::<prop::sample::Index>(), prop_oneof![any::<u8>(), Just(b' '), Just(b'#'), Just(b'0'), Just(b'F')])),
            known in prop_oneof![Just(String::new()), Just("can0".to_string()), "[a-z]{1,4}"],
            crlf in any::<bool>(),
        ) {
            let rec = Record { timestamp: Timestamp::from_micros(micros), iface: &iface, frame, direction: dir };
            let mut out = Vec::new();
            format_record(&mut out, &rec);
            out.pop();
            if let Some((pos, byte)) = mutation {
                let i = pos.index(out.len());
                out[i] = byte;
            }
            // A newline inside would end the line there, for both parsers.
            prop_assume!(!out.contains(&b'\n') && !out.contains(&b'\r'));
            let general = parse_line(&out);
            let mut text = out.clone();
            text.extend_from_slice(if crlf { b"\r\n(1" } else { b"\n(1" });
            if let Some(c) = parse_common(&text, known.as_bytes()) {
                let Ok(general) = general else {
                    return Err(TestCaseError::fail(format!("fast path accepted {:?}", String::from_utf8_lossy(&out))));
                };
                prop_assert_eq!(general.timestamp, c.classic.timestamp);
                prop_assert_eq!(c.known_iface, general.iface == known);
                prop_assert_eq!(general.iface.as_bytes(), &out[c.iface]);
                prop_assert_eq!(general.frame, c.classic.frame());
                prop_assert_eq!(general.direction, None);
                prop_assert_eq!(c.consumed, text.len() - 2);
            } else if mutation.is_none() && dir.is_none() && micros < 1_000_000_000_000_000_000
                && matches!(frame.kind(), FrameKind::Data { len8_dlc: None })
            {
                // The common shape itself must take the fast path.
                prop_assert!(false, "fast path refused {:?}", String::from_utf8_lossy(&out));
            }
        }

        #[test]
        fn eight_digits_matches_a_digit_loop(chunk in prop_oneof![
            any::<[u8; 8]>(),
            "[0-9]{8}".prop_map(|s| <[u8; 8]>::try_from(s.as_bytes()).unwrap()),
            ("[0-9]{7}", any::<u8>(), 0..8usize).prop_map(|(s, b, i)| {
                let mut v = s.into_bytes();
                v.insert(i, b);
                <[u8; 8]>::try_from(&v[..]).unwrap()
            }),
        ]) {
            let expected = chunk.iter().try_fold(0u64, |n, &b| b.is_ascii_digit().then(|| n * 10 + u64::from(b - b'0')));
            prop_assert_eq!(eight_digits(chunk), expected);
        }

        #[test]
        fn eight_hex_digits_matches_a_digit_loop(chunk in prop_oneof![
            any::<[u8; 8]>(),
            "[0-9a-fA-F]{8}".prop_map(|s| <[u8; 8]>::try_from(s.as_bytes()).unwrap()),
            ("[0-9a-fA-F]{7}", any::<u8>(), 0..8usize).prop_map(|(s, b, i)| {
                let mut v = s.into_bytes();
                v.insert(i, b);
                <[u8; 8]>::try_from(&v[..]).unwrap()
            }),
        ]) {
            let expected = chunk.iter().try_fold(0u32, |n, &b| (hex(b) != INVALID).then(|| n << 4 | u32::from(hex(b))));
            prop_assert_eq!(eight_hex_digits(chunk), expected);
        }

        #[test]
        fn parser_never_panics_on_mutated_lines(
            frame in arb_frame(),
            pos in any::<prop::sample::Index>(),
            byte in any::<u8>(),
        ) {
            let rec = Record { timestamp: Timestamp::from_micros(1), iface: "can0", frame, direction: None };
            let mut out = Vec::new();
            format_record(&mut out, &rec);
            out.pop();
            let i = pos.index(out.len());
            out[i] = byte;
            // Either a valid record that formats back to a parseable line, or a reason.
            if let Ok(r) = parse_line(&out) {
                let mut again = Vec::new();
                format_record(&mut again, &r);
                again.pop();
                prop_assert_eq!(parse_line(&again), Ok(r));
            }
        }
    }
}
