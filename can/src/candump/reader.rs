//! The streaming reader of a `candump -L` log: one block buffer, each line
//! found and parsed in place, and the interface filter; what a line holds
//! is `parse`'s to say.

use super::parse::{parse_common, parse_line};
use super::{ClassicData, MAX_LINE_BYTES, Malformed, ReadError, Reason, Record};
#[cfg(doc)]
use crate::frame::CanFrame;
use std::io::{self, Read};

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
    pub(super) iface: String,
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

pub(super) fn trim_end(mut line: &[u8]) -> &[u8] {
    while let [rest @ .., last] = line {
        if last.is_ascii_whitespace() {
            line = rest;
        } else {
            break;
        }
    }
    line
}
