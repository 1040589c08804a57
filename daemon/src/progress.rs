//! A progress line for long offline work (decode and replay of big logs):
//! drawn on stderr only when stderr is a terminal, nothing when piped or
//! redirected, so scripts and logs see no extra output.

use std::io::{BufRead, IsTerminal, Read, Write};
use std::time::{Duration, Instant};

/// Wraps a reader and redraws `label: n% (MB read)` at most 4 times a second.
pub struct Progress<R> {
    inner: R,
    label: &'static str,
    total: Option<u64>,
    done: u64,
    last_draw: Instant,
    enabled: bool,
}

impl<R> Progress<R> {
    /// `total` is the input's size when known (a file), for the percentage.
    pub fn new(inner: R, label: &'static str, total: Option<u64>) -> Self {
        Self {
            inner,
            label,
            total,
            done: 0,
            last_draw: Instant::now(),
            enabled: std::io::stderr().is_terminal(),
        }
    }

    fn advance(&mut self, n: usize) {
        self.done += n as u64;
        if self.enabled && self.last_draw.elapsed() >= Duration::from_millis(250) {
            self.last_draw = Instant::now();
            let mb = self.done as f64 / 1e6;
            let mut err = std::io::stderr().lock();
            let _ = match self.total.filter(|&t| t > 0) {
                Some(t) => write!(
                    err,
                    "\r{}: {:5.1}% ({mb:.1} MB)",
                    self.label,
                    100.0 * self.done as f64 / t as f64
                ),
                None => write!(err, "\r{}: {mb:.1} MB", self.label),
            };
        }
    }

    /// Clears the line (call when done).
    pub fn finish(&self) {
        if self.enabled {
            let _ = write!(std::io::stderr().lock(), "\r\x1b[2K");
        }
    }
}

impl<R: Read> Read for Progress<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.advance(n);
        Ok(n)
    }
}

impl<R: BufRead> BufRead for Progress<R> {
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        self.inner.fill_buf()
    }

    fn consume(&mut self, amt: usize) {
        self.inner.consume(amt);
        self.advance(amt);
    }
}
