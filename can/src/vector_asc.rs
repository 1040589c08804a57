//! Vector ASC logs (#25), read as python-can's `ASCReader` reads them, so
//! that its results are the oracle of the tests.
//!
//! ```text
//! date Wed Nov 25 06:00:00.000 am 2026
//! base hex  timestamps absolute
//! internal events logged
//! Begin Triggerblock Wed Nov 25 06:00:00.000 am 2026
//!    0.000000 Start of measurement
//!    0.010000 1  110             Rx   d 8 05 B1 00 00 00 00 00 E4
//!    0.020000 1  18FF0001x       Tx   d 2 01 02
//!    0.030000 1  123             Rx   r 4
//!    0.040000 1  ErrorFrame
//!    0.050000 CANFD   1 Rx      123                                   1 0 9 12 00 11 ...
//! End TriggerBlock
//! ```
//!
//! Why by hand: no maintained Rust crate reads ASC (the few on crates.io
//! are young one-author crates without users, one already yanked), and the
//! format is plain text a page of code reads.
//!
//! Time: an event's time is seconds since the trigger block began (or
//! since the previous event, under `timestamps relative`); the block's
//! start (`Begin Triggerblock`, else the `date` line) is a local date and
//! time with milliseconds, read in this machine's time zone as python-can
//! and Vector's tools read it. Times are kept to the microsecond, rounded.
//! Channels are named by their number as the file writes it (`1`, `2`, ...).
//! Lines that are not CAN events (comments, statistics, J1939, markers) are
//! skipped as python-can skips them; a CAN event line that cannot be read is
//! [`Reason::BadAscEvent`] with its line number. Vector's error frames carry
//! no error class: they are read as error frames of class 0.

use crate::candump::Interfaces;
use crate::candump::{Direction, Malformed, ReadError, Reason, Record};
use crate::candump_plain::parse_decimal_micros;
use crate::frame::{CLASSIC_MAX_LEN, CanFrame, FD_MAX_LEN, FrameId};
use crate::log_lines::Lines;
use crate::time::Timestamp;
use std::io::BufRead;

/// Reader of a Vector ASC log.
#[derive(Debug)]
pub struct AscReader<R> {
    lines: Lines<R>,
    pub(crate) interfaces: Interfaces,
    /// Ids and data in decimal (`base dec`).
    decimal: bool,
    /// `timestamps relative`: each time counts from the previous event.
    relative: bool,
    /// Microseconds since the epoch at which the trigger block began.
    start_us: i64,
    /// The previous event's time, for `timestamps relative`.
    last_us: i64,
    iface: String,
}

impl<R: BufRead> AscReader<R> {
    /// A reader over `input`.
    pub fn new(input: R) -> Self {
        Self {
            lines: Lines::new(input),
            interfaces: Interfaces::default(),
            decimal: false,
            relative: false,
            start_us: 0,
            last_us: 0,
            iface: String::new(),
        }
    }

    /// The next CAN event; `Ok(None)` at the end.
    ///
    /// # Errors
    /// A CAN event line that cannot be read ([`Reason::BadAscEvent`], with
    /// its line number), a line too long; I/O.
    pub fn next_record(&mut self) -> Result<Option<Record<'_>>, ReadError> {
        loop {
            let Some((line_no, line)) = self.lines.next_line()? else {
                return Ok(None);
            };
            let bad = |reason| ReadError::Malformed(Malformed { line_no, reason });
            let Ok(text) = std::str::from_utf8(line) else {
                // Comments may be in any code page; an event is ASCII.
                continue;
            };
            let text = text.trim();
            let lower = text.to_ascii_lowercase();
            if let Some(rest) = lower.strip_prefix("begin triggerblock") {
                if let Some(us) = parse_date(rest) {
                    self.start_us = us;
                    self.last_us = 0;
                }
                continue;
            }
            if let Some(rest) = lower.strip_prefix("date ") {
                if let Some(us) = parse_date(rest) {
                    self.start_us = us;
                }
                continue;
            }
            if let Some(rest) = lower.strip_prefix("base ") {
                let mut words = rest.split_ascii_whitespace();
                self.decimal = words.next() == Some("dec");
                self.relative = words.nth(1) == Some("relative");
                continue;
            }
            let Some(event) = classify(text) else {
                continue;
            };
            let Some((rel_us, channel, frame, direction)) = parse_event(event, self.decimal) else {
                return Err(bad(Reason::BadAscEvent));
            };
            let rel_us = rel_us as i64;
            let t_us = if self.relative {
                self.last_us += rel_us;
                self.last_us
            } else {
                rel_us
            };
            let Ok(timestamp) = u64::try_from(self.start_us + t_us) else {
                return Err(bad(Reason::BadAscEvent));
            };
            if !self.interfaces.pass(channel) {
                continue;
            }
            if self.iface != channel {
                channel.clone_into(&mut self.iface);
            }
            return Ok(Some(Record {
                timestamp: Timestamp::from_micros(timestamp),
                iface: &self.iface,
                frame,
                direction,
            }));
        }
    }
}

/// A CAN event line, as python-can's `ASC_MESSAGE_REGEX` tells one: a time,
/// then a channel number and `ErrorFrame` or an id and `Rx`/`Tx`, or
/// `CANFD`. Everything else is skipped.
fn classify(text: &str) -> Option<&str> {
    let mut words = text.split_ascii_whitespace();
    let time = words.next()?;
    let (secs, frac) = time.split_once('.')?;
    if secs.is_empty()
        || frac.is_empty()
        || !secs.bytes().chain(frac.bytes()).all(|b| b.is_ascii_digit())
    {
        return None;
    }
    let second = words.next()?;
    if second == "CANFD" {
        return Some(text);
    }
    if !second.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let third = words.next()?;
    if third.eq_ignore_ascii_case("errorframe") {
        return Some(text);
    }
    let fourth = words.next()?;
    (fourth.eq_ignore_ascii_case("rx") || fourth.eq_ignore_ascii_case("tx")).then_some(text)
}

/// One event's time (µs since the block began), channel, frame and direction.
fn parse_event(text: &str, decimal: bool) -> Option<(u64, &str, CanFrame, Option<Direction>)> {
    let mut words = text.split_ascii_whitespace();
    let rel_us = parse_decimal_micros(words.next()?)?;
    let second = words.next()?;
    let number = |w: &str| {
        if decimal {
            w.parse::<u32>().ok()
        } else {
            u32::from_str_radix(w, 16).ok()
        }
    };
    let byte = |w: &str| number(w).and_then(|v| u8::try_from(v).ok());
    if second == "CANFD" {
        let channel = words.next()?;
        let direction = direction(words.next()?)?;
        let id_word = words.next()?;
        if id_word.eq_ignore_ascii_case("errorframe") {
            return Some((rel_us, channel, error_frame()?, Some(direction)));
        }
        let id = frame_id(id_word, decimal)?;
        // An optional symbolic name stands before the BRS digit.
        let mut brs = words.next()?;
        if !brs.bytes().all(|b| b.is_ascii_digit()) {
            brs = words.next()?;
        }
        let esi = words.next()?;
        let _dlc = u8::from_str_radix(words.next()?, 16).ok()?;
        let len: usize = words.next()?.parse().ok()?;
        if len > FD_MAX_LEN {
            return None;
        }
        let mut data = [0u8; FD_MAX_LEN];
        for b in &mut data[..len] {
            *b = byte(words.next()?)?;
        }
        let flags = u8::from(brs == "1") | (u8::from(esi == "1") << 1);
        let frame = if len == 0 {
            // python-can: a data length of 0 is a remote frame.
            CanFrame::new_remote(id, 0, None).ok()?
        } else {
            CanFrame::new_fd(id, flags, &data[..len]).ok()?
        };
        return Some((rel_us, second_channel(channel)?, frame, Some(direction)));
    }
    let channel = second;
    let id_word = words.next()?;
    if id_word.eq_ignore_ascii_case("errorframe") {
        return Some((rel_us, channel, error_frame()?, None));
    }
    let id = frame_id(id_word, decimal)?;
    let direction = direction(words.next()?)?;
    let kind = words.next()?;
    let frame = match kind {
        "r" | "R" => {
            let dlc = match words.next() {
                Some(w) => usize::from(u8::from_str_radix(w, 16).ok()?),
                None => 0,
            };
            CanFrame::new_remote(id, dlc.min(CLASSIC_MAX_LEN), None).ok()?
        }
        "d" | "D" => {
            let dlc = u8::from_str_radix(words.next()?, 16).ok()?;
            let len = usize::from(dlc).min(CLASSIC_MAX_LEN);
            let mut data = [0u8; CLASSIC_MAX_LEN];
            for b in &mut data[..len] {
                *b = byte(words.next()?)?;
            }
            let len8_dlc = (dlc > 8).then_some(dlc);
            CanFrame::new_data_with_dlc(id, &data[..len], len8_dlc).ok()?
        }
        _ => return None,
    };
    Some((rel_us, channel, frame, Some(direction)))
}

fn second_channel(channel: &str) -> Option<&str> {
    channel
        .bytes()
        .all(|b| b.is_ascii_digit())
        .then_some(channel)
}

fn error_frame() -> Option<CanFrame> {
    CanFrame::new_error(0, [0; 8]).ok()
}

fn direction(word: &str) -> Option<Direction> {
    if word.eq_ignore_ascii_case("rx") {
        Some(Direction::Rx)
    } else if word.eq_ignore_ascii_case("tx") {
        Some(Direction::Tx)
    } else {
        None
    }
}

/// `123` (11-bit) or `18FF0001x` (29-bit: the `x`).
fn frame_id(word: &str, decimal: bool) -> Option<FrameId> {
    let (digits, extended) = match word.strip_suffix(['x', 'X']) {
        Some(d) => (d, true),
        None => (word, false),
    };
    let raw = if decimal {
        digits.parse::<u32>().ok()?
    } else {
        u32::from_str_radix(digits, 16).ok()?
    };
    if extended {
        FrameId::extended(raw).ok()
    } else {
        FrameId::standard(u16::try_from(raw).ok()?).ok()
    }
}

/// A header date after its keyword, lower-cased: `wed nov 25 06:00:00.000
/// am 2026` or `wed nov 25 18:00:00.000 2026` (German month names too, as
/// python-can), local time, as microseconds since the epoch.
fn parse_date(text: &str) -> Option<i64> {
    use chrono::{NaiveDate, TimeZone as _};
    let mut words = text.split_ascii_whitespace();
    let _weekday = words.next()?;
    let month = match words.next()? {
        "jan" => 1,
        "feb" => 2,
        "mar" | "mär" => 3,
        "apr" => 4,
        "may" | "mai" => 5,
        "jun" => 6,
        "jul" => 7,
        "aug" => 8,
        "sep" => 9,
        "oct" | "okt" => 10,
        "nov" => 11,
        "dec" | "dez" => 12,
        _ => return None,
    };
    let day: u32 = words.next()?.parse().ok()?;
    let clock = words.next()?;
    let mut next = words.next()?;
    let meridiem = match next {
        "am" | "pm" => {
            let m = next;
            next = words.next()?;
            Some(m)
        }
        _ => None,
    };
    let year: i32 = next.parse().ok()?;
    let (hms, millis) = clock.split_once('.').unwrap_or((clock, "0"));
    let mut hms = hms.split(':').map(str::parse::<u32>);
    let (mut hour, minute, second) = (hms.next()?.ok()?, hms.next()?.ok()?, hms.next()?.ok()?);
    let millis: u32 = millis.parse().ok()?;
    match meridiem {
        Some("pm") if hour < 12 => hour += 12,
        Some("am") if hour == 12 => hour = 0,
        _ => {}
    }
    let naive = NaiveDate::from_ymd_opt(year, month, day)?
        .and_hms_milli_opt(hour, minute, second, millis)?;
    let local = chrono::Local.from_local_datetime(&naive).earliest()?;
    Some(local.timestamp_micros())
}

#[cfg(test)]
mod tests {
    use super::*;

    const LOG: &str = "date Wed Nov 25 06:00:00.000 am 2026\n\
base hex  timestamps absolute\n\
internal events logged\n\
// version 9.0.0\n\
Begin Triggerblock Wed Nov 25 06:00:00.000 am 2026\n\
   0.000000 Start of measurement\n\
   0.010000 1  110             Rx   d 8 05 B1 00 00 00 00 00 E4\n\
   0.020000 2  18FF0001x       Tx   d 2 01 02  Length = 0 BitCount = 0\n\
   0.030000 1  123             Rx   r 4\n\
   0.040000 1  ErrorFrame\n\
   0.050000 CANFD   1 Rx      123                                   1 0 9 12 00 11 22 33 44 55 66 77 88 99 AA BB       0    0     3000        0        0        0        0        0\n\
   0.060000 1  Statistic: D 0 R 0 XD 0 XR 0 E 0 O 0 B 0.00%\n\
   0.070000 1  12G             Rx   d 1 01\n\
End TriggerBlock\n";

    #[test]
    fn events_read_as_python_can_reads_them() {
        let mut r = AscReader::new(LOG.as_bytes());
        let mut got = Vec::new();
        let mut bad = Vec::new();
        loop {
            match r.next_record() {
                Ok(Some(rec)) => got.push((
                    rec.timestamp.as_micros() as i64,
                    rec.iface.to_owned(),
                    crate::candump::Record {
                        timestamp: Timestamp::from_micros(0),
                        ..rec
                    }
                    .to_string(),
                )),
                Ok(None) => break,
                Err(ReadError::Malformed(m)) => bad.push(m.line_no),
                Err(e) => panic!("{e}"),
            }
        }
        let start = parse_date("wed nov 25 06:00:00.000 am 2026").unwrap();
        let texts: Vec<_> = got.iter().map(|g| g.2.as_str()).collect();
        assert_eq!(
            texts,
            [
                "(0000000000.000000) 1 110#05B10000000000E4 R",
                "(0000000000.000000) 2 18FF0001#0102 T",
                "(0000000000.000000) 1 123#R4 R",
                "(0000000000.000000) 1 20000000#0000000000000000",
                "(0000000000.000000) 1 123##100112233445566778899AABB R",
            ]
        );
        let times: Vec<_> = got.iter().map(|g| g.0 - start).collect();
        assert_eq!(times, [10_000, 20_000, 30_000, 40_000, 50_000]);
        assert_eq!(bad, [13], "the unreadable event is named by its line");
        assert_eq!(r.interfaces.seen(), ["1", "2"]);
    }

    #[test]
    fn dates_in_both_clocks_and_relative_times() {
        assert_eq!(
            parse_date("wed nov 25 06:00:00.250 pm 2026"),
            parse_date("wed nov 25 18:00:00.250 2026")
        );
        assert_eq!(
            parse_date("wed nov 25 12:00:00.000 am 2026").map(|t| t + 86_400_000_000 / 2),
            parse_date("wed nov 25 12:00:00.000 pm 2026")
        );
        let log = "base hex  timestamps relative\n\
                   0.5 1 1 Rx d 0\n\
                   0.25 1 2 Rx d 0\n";
        let mut r = AscReader::new(log.as_bytes());
        let a = r.next_record().unwrap().unwrap().timestamp.as_micros();
        let b = r.next_record().unwrap().unwrap().timestamp.as_micros();
        assert_eq!((a, b), (500_000, 750_000));
    }
}
