//! `candump` output without `-L` (#25): the layout candump prints on a
//! terminal, with or without a `-t` time in front.
//!
//! ```text
//!   can0  123   [8]  11 22 33 44 55 66 77 88          plain
//!   can0  1F334455   [2]  01 02                      29-bit id (8 digits)
//!   can0  123   [4]  remote request                  remote frame
//!   can0  123  [12]  00 11 ...                       CAN FD (two-digit length)
//!   can0  20000080   [8]  00 ...   ERRORFRAME        error frame (CAN_ERR_FLAG)
//!   can0  RX - -  123   [8]  11 22 ...               -x (direction, flags)
//!  (1700000000.000100)  can0  123   [2]  01 02        -ta (absolute time)
//!  (000.010000)  can0  123   [2]  01 02               -tz / -td (since start / delta)
//! ```
//!
//! Time: a `-ta` time is the Unix time, as in `candump -L`; `-tz` gives
//! seconds since the capture started and is read as such (time 0 = the
//! epoch; replay and calibrate use only differences of times); `-td` gives
//! the delta to the previous frame, which is not a time: such a log is read
//! as written and its frames are out of order. Without `-t` there is no
//! time at all: every record has time 0 and [`PlainReader::has_time`] is
//! false, so that commands needing time can refuse the log. `-tA` (a date)
//! is not read. Lines that start with a tab (`candump -e`'s error frame
//! explanations) are skipped.

use crate::candump::Interfaces;
use crate::candump::{Direction, Malformed, ReadError, Reason, Record};
use crate::frame::{CAN_ERR_FLAG, CLASSIC_MAX_LEN, CanFrame, FrameId, MAX_EXTENDED_ID};
use crate::log_lines::Lines;
use crate::time::Timestamp;
use std::io::BufRead;

/// Reader of plain or `-t` timed candump output.
#[derive(Debug)]
pub struct PlainReader<R> {
    lines: Lines<R>,
    pub(crate) interfaces: Interfaces,
    /// Whether the lines carry a `-t` time (judged from the first record).
    timed: Option<bool>,
    iface: String,
}

impl<R: BufRead> PlainReader<R> {
    /// A reader over `input`.
    pub fn new(input: R) -> Self {
        Self {
            lines: Lines::new(input),
            interfaces: Interfaces::default(),
            timed: None,
            iface: String::new(),
        }
    }

    /// Whether the records carry a time (`-t`); judged from the first
    /// record, and `true` before any (an unknown is not refused).
    pub fn has_time(&self) -> bool {
        self.timed != Some(false)
    }

    /// Sets whether the lines carry a time, as the log's first lines showed
    /// (so [`Self::has_time`] answers before any record is read).
    pub(crate) fn judge_time(&mut self, timed: bool) {
        self.timed = Some(timed);
    }

    /// The next record; `Ok(None)` at the end.
    ///
    /// # Errors
    /// A line that cannot be read ([`Reason::BadPlainRecord`], or
    /// [`Reason::LineTooLong`]); I/O.
    pub fn next_record(&mut self) -> Result<Option<Record<'_>>, ReadError> {
        loop {
            let Some((line_no, line)) = self.lines.next_line()? else {
                return Ok(None);
            };
            let bad = |reason| ReadError::Malformed(Malformed { line_no, reason });
            if line.first() == Some(&b'\t') || line.iter().all(u8::is_ascii_whitespace) {
                continue;
            }
            let Some(parsed) = parse(line) else {
                return Err(bad(Reason::BadPlainRecord));
            };
            let timed = parsed.timestamp.is_some();
            if *self.timed.get_or_insert(timed) != timed {
                // A line with a time among lines without (or the reverse):
                // not one candump run's output.
                return Err(bad(Reason::BadPlainRecord));
            }
            if !self.interfaces.pass(parsed.iface) {
                continue;
            }
            if self.iface != parsed.iface {
                parsed.iface.clone_into(&mut self.iface);
            }
            return Ok(Some(Record {
                timestamp: parsed.timestamp.unwrap_or_default(),
                iface: &self.iface,
                frame: parsed.frame,
                direction: parsed.direction,
            }));
        }
    }
}

/// One line's content.
struct Parsed<'a> {
    timestamp: Option<Timestamp>,
    iface: &'a str,
    frame: CanFrame,
    direction: Option<Direction>,
}

/// `(secs.micros)` as candump's `-t` writes it (at most 6 fraction digits).
pub(crate) fn parse_paren_time(word: &str) -> Option<Timestamp> {
    let inner = word.strip_prefix('(')?.strip_suffix(')')?;
    parse_decimal_micros(inner).map(Timestamp::from_micros)
}

/// `secs[.fraction]` as microseconds, the fraction rounded to the nearest
/// microsecond (Vector writes up to nanoseconds).
pub(crate) fn parse_decimal_micros(text: &str) -> Option<u64> {
    let (secs, frac) = text.split_once('.').unwrap_or((text, ""));
    if secs.is_empty()
        || !secs.bytes().all(|b| b.is_ascii_digit())
        || !frac.bytes().all(|b| b.is_ascii_digit())
        || secs.len() > 12
        || frac.len() > 9
    {
        return None;
    }
    let secs: u64 = secs.parse().ok()?;
    let mut nanos = 0u64;
    for b in frac.bytes().chain(std::iter::repeat(b'0')).take(9) {
        nanos = nanos * 10 + u64::from(b - b'0');
    }
    Some(secs * 1_000_000 + (nanos + 500) / 1000)
}

fn parse(line: &[u8]) -> Option<Parsed<'_>> {
    let text = std::str::from_utf8(line).ok()?;
    let mut words = text.split_ascii_whitespace().peekable();
    let timestamp = match words.peek() {
        Some(w) if w.starts_with('(') => {
            let t = parse_paren_time(w)?;
            words.next();
            Some(t)
        }
        _ => None,
    };
    let iface = words.next()?;
    if iface.len() > crate::candump::MAX_IFACE_BYTES || !iface.bytes().all(|b| b.is_ascii_graphic())
    {
        return None;
    }
    let mut direction = None;
    let mut id_word = words.next()?;
    if matches!(id_word, "RX" | "TX") {
        // `-x`: direction, then two flag columns (BRS, ESI or `-`).
        direction = Some(if id_word == "RX" {
            Direction::Rx
        } else {
            Direction::Tx
        });
        words.next()?;
        words.next()?;
        id_word = words.next()?;
    }
    let len_word = words.next()?;
    let len_digits = len_word.strip_prefix('[')?.strip_suffix(']')?;
    if len_digits.is_empty() || len_digits.len() > 2 {
        return None;
    }
    let len: usize = len_digits.parse().ok()?;
    // candump prints a CAN FD length with two digits (`[08]`, `[64]`).
    let fd = len_digits.len() == 2;
    if id_word.is_empty() || !id_word.bytes().all(|b| b.is_ascii_hexdigit()) {
        return None;
    }
    let raw = u32::from_str_radix(id_word, 16).ok()?;
    let extended = match id_word.len() {
        3 => false,
        8 => true,
        _ => return None,
    };
    let mut rest = words.peekable();
    if rest.peek() == Some(&"remote") {
        if fd {
            return None;
        }
        let id = frame_id(raw, extended)?;
        let frame = CanFrame::new_remote(id, len, None).ok()?;
        return Some(Parsed {
            timestamp,
            iface,
            frame,
            direction,
        });
    }
    let mut data = [0u8; crate::frame::FD_MAX_LEN];
    if len > data.len() {
        return None;
    }
    for byte in &mut data[..len] {
        let word = rest.next()?;
        if word.len() != 2 {
            return None;
        }
        *byte = u8::from_str_radix(word, 16).ok()?;
    }
    // What follows the bytes (`-a`'s ASCII column, `ERRORFRAME`) is not read.
    let data = &data[..len];
    let frame = if extended && raw & CAN_ERR_FLAG != 0 {
        let class = raw & !CAN_ERR_FLAG;
        if class > MAX_EXTENDED_ID || fd {
            return None;
        }
        CanFrame::new_error(class, data.try_into().ok()?).ok()?
    } else {
        let id = frame_id(raw, extended)?;
        if fd {
            CanFrame::new_fd(id, 0, data).ok()?
        } else if len <= CLASSIC_MAX_LEN {
            CanFrame::new_data(id, data).ok()?
        } else {
            return None;
        }
    };
    Some(Parsed {
        timestamp,
        iface,
        frame,
        direction,
    })
}

fn frame_id(raw: u32, extended: bool) -> Option<FrameId> {
    if extended {
        FrameId::extended(raw).ok()
    } else {
        FrameId::standard(u16::try_from(raw).ok()?).ok()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read_all(text: &str) -> (Vec<String>, Vec<u64>) {
        let mut r = PlainReader::new(text.as_bytes());
        let (mut ok, mut bad) = (Vec::new(), Vec::new());
        loop {
            match r.next_record() {
                Ok(Some(rec)) => ok.push(rec.to_string()),
                Ok(None) => break,
                Err(ReadError::Malformed(m)) => bad.push(m.line_no),
                Err(e) => panic!("{e}"),
            }
        }
        (ok, bad)
    }

    #[test]
    fn every_kind_of_line_reads_as_its_candump_l_record() {
        let (ok, bad) = read_all(
            " (1700000000.000100)  can0  123   [8]  11 22 33 44 55 66 77 88\n\
             (1700000000.000200)  can0  1F334455   [2]  01 02  '..'\n\
             (1700000000.000300)  can0  123   [4]  remote request\n\
             (1700000000.000400)  can0  123  [12]  00 11 22 33 44 55 66 77 88 99 AA BB\n\
             (1700000000.000500)  can0  20000080   [8]  00 00 00 00 00 00 00 00   ERRORFRAME\n\
            \tbus-error\n\
             (1700000000.000600)  vcan1  RX - -  7FF   [1]  FF\n",
        );
        assert!(bad.is_empty(), "{bad:?}");
        assert_eq!(
            ok,
            [
                "(1700000000.000100) can0 123#1122334455667788",
                "(1700000000.000200) can0 1F334455#0102",
                "(1700000000.000300) can0 123#R4",
                "(1700000000.000400) can0 123##000112233445566778899AABB",
                "(1700000000.000500) can0 20000080#0000000000000000",
                "(1700000000.000600) vcan1 7FF#FF R",
            ]
        );
    }

    #[test]
    fn bad_lines_are_named_by_number_and_untimed_logs_say_so() {
        let (ok, bad) =
            read_all("  can0  123   [2]  01\n  can0  123   [1]  01\n  can0  12   [1]  01\n");
        assert_eq!(ok.len(), 1);
        assert_eq!(bad, [1, 3]);
        let mut r = PlainReader::new(&b"  can0  123   [1]  01\n"[..]);
        assert!(r.next_record().unwrap().is_some());
        assert!(!r.has_time());
    }

    #[test]
    fn fractions_round_to_the_microsecond() {
        assert_eq!(parse_decimal_micros("1.0000005"), Some(1_000_001));
        assert_eq!(parse_decimal_micros("1.5"), Some(1_500_000));
        assert_eq!(parse_decimal_micros("12"), Some(12_000_000));
        assert_eq!(parse_decimal_micros("1.x"), None);
        assert_eq!(parse_decimal_micros(".5"), None);
    }
}
