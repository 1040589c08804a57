//! What the readers of every log format share: the interfaces met and the
//! `--interface` filter, and the bounded lines of a text log. Below the
//! readers ([`crate::candump_plain`], [`crate::vector_asc`],
//! [`crate::vector_blf`]) and [`crate::any_log`], which chooses among them.

use crate::candump::LogReader;
use std::io::{self, BufRead, Read};

/// The interfaces a reader has met and the filter it applies: the same
/// bookkeeping as [`LogReader`]'s, for the other formats.
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
        if self.seen.len() < crate::candump::MAX_INTERFACES_LISTED
            && !self.seen.iter().any(|n| n == name)
        {
            self.seen.push(name.to_owned());
        }
        let passes = self.only.as_deref().is_none_or(|only| only == name);
        if !passes {
            self.other_lines += 1;
        }
        passes
    }

    pub(crate) fn seen(&self) -> &[String] {
        &self.seen
    }

    pub(crate) fn other_lines(&self) -> u64 {
        self.other_lines
    }

    pub(crate) fn only(&mut self, name: &str) {
        self.only = Some(name.to_owned());
    }
}

/// Lines of a text log, each at most [`crate::candump::MAX_LINE_BYTES`]
/// (a longer one is cut there and its rest skipped, so a corrupt file
/// cannot grow the buffer), counted from 1.
#[derive(Debug)]
pub(crate) struct Lines<R> {
    inner: R,
    buf: Vec<u8>,
    line_no: u64,
}

impl<R: BufRead> Lines<R> {
    pub(crate) fn new(inner: R) -> Self {
        Self {
            inner,
            buf: Vec::with_capacity(256),
            line_no: 0,
        }
    }

    /// The next line's number, the line without its line end, and whether
    /// it was too long; `None` at the end.
    pub(crate) fn next_line(&mut self) -> io::Result<Option<(u64, &[u8], bool)>> {
        self.buf.clear();
        let limit = crate::candump::MAX_LINE_BYTES as u64 + 1;
        let n = (&mut self.inner)
            .take(limit)
            .read_until(b'\n', &mut self.buf)?;
        if n == 0 {
            return Ok(None);
        }
        self.line_no += 1;
        let mut too_long = false;
        if self.buf.last() != Some(&b'\n') && n as u64 == limit {
            too_long = true;
            // Skip the rest of the line, a block at a time.
            loop {
                let chunk = self.inner.fill_buf()?;
                if chunk.is_empty() {
                    break;
                }
                if let Some(pos) = memchr::memchr(b'\n', chunk) {
                    self.inner.consume(pos + 1);
                    break;
                }
                let len = chunk.len();
                self.inner.consume(len);
            }
        }
        while matches!(self.buf.last(), Some(b'\n' | b'\r')) {
            self.buf.pop();
        }
        Ok(Some((self.line_no, &self.buf, too_long)))
    }
}

/// What a reader over a log knows of its interfaces (for [`crate::log_format::LogSeen`]).
pub trait InterfaceList {
    /// The distinct interface (channel) names met, in order of appearance.
    fn interfaces(&self) -> &[String];
    /// Records skipped as another interface's.
    fn other_interface_lines(&self) -> u64;
}

impl<R: Read> InterfaceList for LogReader<R> {
    fn interfaces(&self) -> &[String] {
        LogReader::interfaces(self)
    }
    fn other_interface_lines(&self) -> u64 {
        LogReader::other_interface_lines(self)
    }
}
