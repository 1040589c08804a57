//! Which kind of CAN log a file is, judged from its first bytes, so that
//! [`crate::any_log::AnyLogReader`] picks its reader and a log canodom does
//! not read is refused by name with the way forward instead of being skipped
//! line by line as malformed `candump -L` records.

use crate::candump::parse_line;
use crate::log_lines::InterfaceList;

/// How many of the first non-blank lines are looked at.
const LINES_LOOKED_AT: usize = 20;

/// A CAN log format, as far as its first bytes tell.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LogFormat {
    /// `candump -L` (`(1700000000.123456) can0 123#1122`): what canodom reads.
    CandumpL,
    /// `candump can0` without `-L` (`  can0  123   [8]  11 22 ...`).
    CandumpPlain,
    /// `candump -ta`/`-td`/`-tz`/`-tA` (a time in brackets, then the plain layout).
    CandumpTimed,
    /// Vector ASC text (`date ...`, `base hex  timestamps absolute`).
    VectorAsc,
    /// Vector BLF binary (`LOGG` magic).
    VectorBlf,
    /// ASAM MDF 4 bus logging (`MDF     ` or `UnFinMF ` magic).
    Mf4,
    /// python-can's CSV (`timestamp,arbitration_id,extended,...`).
    PythonCanCsv,
    /// PEAK PCAN-View TRC (`;$FILEVERSION=...`).
    PeakTrc,
    /// gzip-compressed (of any format).
    Gzip,
    /// zstd-compressed (of any format).
    Zstd,
    /// Nothing in it.
    Empty,
    /// None of the above: read as `candump -L`, whose reader names each bad line.
    Unknown,
}

impl LogFormat {
    /// The format's name as its users call it.
    pub fn name(self) -> &'static str {
        match self {
            Self::CandumpL => "a candump -L log",
            Self::CandumpPlain => "plain candump output (candump without -L)",
            Self::CandumpTimed => "candump output with -t timestamps (candump -ta/-td/-tz/-tA)",
            Self::VectorAsc => "a Vector ASC log",
            Self::VectorBlf => "a Vector BLF log",
            Self::Mf4 => "an ASAM MDF 4 (MF4) log",
            Self::PythonCanCsv => "a python-can CSV log",
            Self::PeakTrc => "a PEAK TRC log",
            Self::Gzip => "a gzip-compressed file",
            Self::Zstd => "a zstd-compressed file",
            Self::Empty => "an empty file",
            Self::Unknown => "not a known CAN log format",
        }
    }

    /// Whether canodom reads it ([`crate::any_log::AnyLogReader`]; an
    /// unknown text is read as `candump -L`, whose reader names every line
    /// it cannot use; compressed files by their content's format).
    pub fn is_read(self) -> bool {
        self.way_forward().is_none()
    }

    /// What to do with a log of this format, for one that is not read.
    pub fn way_forward(self) -> Option<&'static str> {
        Some(match self {
            Self::CandumpL
            | Self::Unknown
            | Self::CandumpPlain
            | Self::CandumpTimed
            | Self::VectorAsc
            | Self::VectorBlf
            | Self::Mf4
            | Self::Gzip
            | Self::Zstd => return None,
            Self::PythonCanCsv | Self::PeakTrc => {
                "convert it with python-can: `pip install python-can` then \
                 `python3 -m can.logconvert INPUT drive.log` (a .log output is candump -L)"
            }
            Self::Empty => "record a log with `candump -L can0 > drive.log`",
        })
    }

    /// What to do with a log whose records have no time (plain candump
    /// output), for the commands that need time (replay, calibrate).
    pub fn untimed_way_forward() -> &'static str {
        "its frames have no time, which replay and calibrate need: record with \
         `candump -L can0 > drive.log` (or `candump -ta can0`); decode reads it as it is"
    }
}

/// The format of a log whose first bytes are `head` (a few kB are plenty;
/// a cut last line is ignored).
pub fn sniff(head: &[u8]) -> LogFormat {
    if head.starts_with(b"LOGG") {
        return LogFormat::VectorBlf;
    }
    if crate::mdf4::is_mdf(head) {
        return LogFormat::Mf4;
    }
    if head.starts_with(&[0x1f, 0x8b]) {
        return LogFormat::Gzip;
    }
    if head.starts_with(&[0x28, 0xb5, 0x2f, 0xfd]) {
        return LogFormat::Zstd;
    }
    let head = head.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(head);
    // A cut last line could look like anything: judge whole lines only,
    // unless the head is the whole file (no newline at its end is normal).
    let whole = match head.iter().rposition(|&b| b == b'\n') {
        Some(end) if head.len() > 4096 => &head[..end],
        _ => head,
    };
    let lines: Vec<&[u8]> = whole
        .split(|&b| b == b'\n')
        .map(trim)
        .filter(|l| !l.is_empty())
        .take(LINES_LOOKED_AT)
        .collect();
    if lines.is_empty() {
        return LogFormat::Empty;
    }
    // One readable record among the first lines: a candump -L log, perhaps
    // with a damaged line before it.
    if lines.iter().any(|l| parse_line(l).is_ok()) {
        return LogFormat::CandumpL;
    }
    lines
        .iter()
        .find_map(|l| foreign_line(l))
        .unwrap_or(LogFormat::Unknown)
}

/// The format a single line of another tool's log gives away, if any.
fn foreign_line(line: &[u8]) -> Option<LogFormat> {
    let text = std::str::from_utf8(line).ok()?;
    let lower = text.to_ascii_lowercase();
    if lower.starts_with(";$fileversion") || lower.starts_with(";   start time") {
        return Some(LogFormat::PeakTrc);
    }
    if lower.starts_with("date ")
        || lower.starts_with("base hex")
        || lower.starts_with("base dec")
        || lower.starts_with("begin triggerblock")
        || lower.starts_with("internal events logged")
    {
        return Some(LogFormat::VectorAsc);
    }
    if lower.starts_with("timestamp,arbitration_id") {
        return Some(LogFormat::PythonCanCsv);
    }
    let mut words = text.split_whitespace();
    let first = words.next()?;
    let timed = first.starts_with('(') && first.ends_with(')') && first.len() > 2;
    let (iface, id, len) = if timed {
        (words.next()?, words.next()?, words.next()?)
    } else {
        (first, words.next()?, words.next()?)
    };
    let plain_shape = is_iface(iface)
        && !id.is_empty()
        && id.len() <= 8
        && id.bytes().all(|b| b.is_ascii_hexdigit())
        && len.starts_with('[')
        && len.ends_with(']');
    match (plain_shape, timed) {
        (true, true) => Some(LogFormat::CandumpTimed),
        (true, false) => Some(LogFormat::CandumpPlain),
        _ => None,
    }
}

/// A plausible network interface name (`can0`, `vcan1`, `slcan0`, `any`).
fn is_iface(word: &str) -> bool {
    !word.is_empty()
        && word.len() <= 16
        && word.starts_with(|c: char| c.is_ascii_alphabetic())
        && word
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'-' | b'.' | b':'))
}

fn trim(line: &[u8]) -> &[u8] {
    let start = line
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .unwrap_or(line.len());
    let end = line
        .iter()
        .rposition(|b| !b.is_ascii_whitespace())
        .map_or(start, |e| e + 1);
    &line[start..end.max(start)]
}

/// What reading a log met: enough to refuse a log nothing was read from
/// and to warn of one that mixes buses.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct LogSeen {
    /// Frames read (of the chosen interface).
    pub frames: u64,
    /// Malformed lines skipped.
    pub malformed: u64,
    /// The distinct interfaces of the log, in order of appearance.
    pub interfaces: Vec<String>,
    /// Lines skipped as another interface's.
    pub other_interface_lines: u64,
}

impl LogSeen {
    /// What `reader` met, with the frames and malformed lines its user counted.
    pub fn of(reader: &impl InterfaceList, frames: u64, malformed: u64) -> Self {
        Self {
            frames,
            malformed,
            interfaces: reader.interfaces().to_vec(),
            other_interface_lines: reader.other_interface_lines(),
        }
    }

    /// Why the log gave nothing to work on, when it did not (`interface`: the
    /// one asked for), in words with the way forward.
    pub fn refusal(&self, interface: Option<&str>) -> Option<String> {
        if self.frames > 0 {
            return None;
        }
        Some(match interface {
            Some(name) if self.other_interface_lines > 0 => format!(
                "no frame of interface {name}; the log holds {}",
                self.interfaces.join(", ")
            ),
            _ if self.malformed > 0 => format!(
                "no frame could be read: all {} lines are malformed; canodom reads \
                 candump -L records such as `(1700000000.000100) can0 123#11223344` \
                 (record with `candump -L can0 > drive.log`), plain candump output \
                 (`  can0  123   [4]  11 22 33 44`), Vector ASC and BLF, ASAM MDF 4, \
                 each also gzip or zstd compressed",
                self.malformed
            ),
            _ => "holds no frame (record with `candump -L can0 > drive.log`)".to_owned(),
        })
    }

    /// A warning when the log mixes several interfaces and none was chosen.
    pub fn mixed_buses(&self, interface: Option<&str>) -> Option<String> {
        (interface.is_none() && self.interfaces.len() > 1).then(|| {
            format!(
                "holds frames of {} interfaces ({}), read as one bus; choose one with --interface {}",
                self.interfaces.len(),
                self.interfaces.join(", "),
                self.interfaces[0]
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn candump_l_is_read_even_after_a_damaged_first_line() {
        assert_eq!(
            sniff(b"(1700000000.000100) can0 123#1122\n"),
            LogFormat::CandumpL
        );
        assert_eq!(
            sniff(b"garbage\n(1700000000.000100) can0 123##1AABB\n"),
            LogFormat::CandumpL
        );
        assert!(LogFormat::CandumpL.is_read());
    }

    #[test]
    fn other_tools_logs_are_named() {
        let cases: [(&[u8], LogFormat); 11] = [
            (b"MDF     4.10    amdf8.8.", LogFormat::Mf4),
            (b"UnFinMF 4.11    ", LogFormat::Mf4),
            (
                b"  vcan0  123   [8]  11 22 33 44 55 66 77 88\n",
                LogFormat::CandumpPlain,
            ),
            (
                b" (1700000000.000100)  can0  18FF0000   [3]  01 02 03\n",
                LogFormat::CandumpTimed,
            ),
            (
                b" (000.010000)  can0  123   [2]  01 02\n",
                LogFormat::CandumpTimed,
            ),
            (
                b"date Wed Nov 25 06:00:00.000 am 2026\nbase hex  timestamps absolute\n",
                LogFormat::VectorAsc,
            ),
            (b"LOGG\x90\x00\x00\x00", LogFormat::VectorBlf),
            (
                b"timestamp,arbitration_id,extended,remote,error,dlc,data\n",
                LogFormat::PythonCanCsv,
            ),
            (
                b";$FILEVERSION=2.1\n;$STARTTIME=45000.1\n",
                LogFormat::PeakTrc,
            ),
            (b"\x1f\x8b\x08\x00", LogFormat::Gzip),
            (b"\x28\xb5\x2f\xfd\x00", LogFormat::Zstd),
        ];
        for (head, format) in cases {
            assert_eq!(sniff(head), format, "{}", String::from_utf8_lossy(head));
            // Read since #25 but for python-can CSV and PEAK TRC.
            let refused = matches!(format, LogFormat::PythonCanCsv | LogFormat::PeakTrc);
            assert_eq!(!format.is_read(), refused, "{format:?}");
            assert_eq!(format.way_forward().is_some(), refused, "{format:?}");
        }
    }

    #[test]
    fn what_a_log_held_decides_refusal_and_warning() {
        let seen = |frames, malformed, interfaces: &[&str], other| LogSeen {
            frames,
            malformed,
            interfaces: interfaces.iter().map(|s| (*s).to_owned()).collect(),
            other_interface_lines: other,
        };
        assert_eq!(seen(5, 2, &["can0"], 0).refusal(None), None);
        let r = seen(0, 3, &[], 0).refusal(None).unwrap();
        assert!(r.contains("all 3 lines are malformed"), "{r}");
        let r = seen(0, 0, &[], 0).refusal(None).unwrap();
        assert!(r.contains("holds no frame"), "{r}");
        let r = seen(0, 0, &["can0", "can1"], 7)
            .refusal(Some("can2"))
            .unwrap();
        assert!(
            r.contains("no frame of interface can2; the log holds can0, can1"),
            "{r}"
        );
        let w = seen(9, 0, &["can0", "can1"], 0).mixed_buses(None).unwrap();
        assert!(
            w.contains("2 interfaces (can0, can1)") && w.contains("--interface can0"),
            "{w}"
        );
        assert_eq!(
            seen(9, 0, &["can0", "can1"], 4).mixed_buses(Some("can1")),
            None
        );
        assert_eq!(seen(9, 0, &["can0"], 0).mixed_buses(None), None);
    }

    #[test]
    fn empty_and_unknown_inputs() {
        assert_eq!(sniff(b""), LogFormat::Empty);
        assert_eq!(sniff(b"\n \n\t\n"), LogFormat::Empty);
        assert_eq!(sniff(b"hello world\nnot a log\n"), LogFormat::Unknown);
        assert!(LogFormat::Unknown.is_read());
    }

    #[test]
    fn a_cut_last_line_of_a_long_head_is_ignored() {
        let mut head = Vec::new();
        for i in 0..200 {
            head.extend_from_slice(format!("(1700000000.{i:06}) can0 123#11\n").as_bytes());
        }
        head.extend_from_slice(b"  can0  12");
        assert_eq!(sniff(&head), LogFormat::CandumpL);
    }
}
