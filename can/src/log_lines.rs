//! What the readers of every log format share besides the interface
//! filter (`candump::Interfaces`, crate-private): the bounded lines of a
//! text log, and what a reader tells of the interfaces it met. Below the
//! readers ([`crate::candump_plain`], [`crate::vector_asc`],
//! [`crate::vector_blf`]) and [`crate::any_log`], which chooses among them.

use crate::candump::{LogReader, Malformed, ReadError, Reason};
use std::io::{BufRead, Read};

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

    /// The next line's number and the line without its line end; `None` at
    /// the end.
    ///
    /// # Errors
    /// A line too long ([`Reason::LineTooLong`], its rest skipped, so the
    /// next call reads on); I/O.
    pub(crate) fn next_line(&mut self) -> Result<Option<(u64, &[u8])>, ReadError> {
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
        if too_long {
            return Err(ReadError::Malformed(Malformed {
                line_no: self.line_no,
                reason: Reason::LineTooLong,
            }));
        }
        while matches!(self.buf.last(), Some(b'\n' | b'\r')) {
            self.buf.pop();
        }
        Ok(Some((self.line_no, &self.buf)))
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
