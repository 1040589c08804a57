//! One `candump -L` line into a record: the general parser, which judges
//! every line and names what is wrong, and the fast path for the shape
//! nearly every line has, which must agree with it.

use super::{ClassicData, Direction, MAX_IFACE_BYTES, Reason, Record};
use crate::frame::{
    CAN_ERR_FLAG, CLASSIC_MAX_LEN, CanFrame, ERROR_FRAME_LEN, FD_MAX_LEN, FrameId, MAX_EXTENDED_ID,
    MAX_STANDARD_ID, is_fd_len,
};
use crate::time::Timestamp;

/// `a == b` for the few bytes of an interface name: slice equality calls
/// `memcmp`, whose call costs more than comparing five bytes in a loop.
#[inline]
fn same_bytes(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x == y)
}

pub(super) const INVALID: u8 = 0xFF;

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
pub(super) fn hex(b: u8) -> u8 {
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
pub(super) struct Common {
    pub(super) classic: ClassicData,
    /// Where the interface name lies in the text.
    pub(super) iface: std::ops::Range<usize>,
    /// Whether the name is `known_iface` (otherwise it differs).
    pub(super) known_iface: bool,
    /// Bytes up to and with the line's `\n`.
    pub(super) consumed: usize,
}

/// Eight ASCII decimal digits (most significant first) as a number, `None`
/// if any byte is not a digit: a few multiplications on one `u64` instead of
/// a loop of eight (the timestamps are most of a line's digits).
#[inline]
pub(super) fn eight_digits(chunk: [u8; 8]) -> Option<u64> {
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
pub(super) fn eight_hex_digits(chunk: [u8; 8]) -> Option<u32> {
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
pub(super) fn parse_common(text: &[u8], known_iface: &[u8]) -> Option<Common> {
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
