//! A CAN log opened by path, its format judged from its content (never the
//! file name), and the frames of one log walked through in order.

use crate::{Error, Result, shown};
use canodom_can::any_log::{AnyLogReader, OpenError};
use canodom_can::candump::ReadError;
use canodom_can::frame::CanFrame;
use canodom_can::log_format::{LogFormat, LogSeen};
use canodom_can::time::Timestamp;
use std::io::BufReader;
use std::path::Path;

/// Bytes read from a log file at once.
const READ_BYTES: usize = 1 << 16;

/// Opens the file at `path`, buffered.
///
/// # Errors
/// [`Error::File`] naming the path.
pub fn open_file(path: &Path) -> Result<BufReader<std::fs::File>> {
    let file = std::fs::File::open(path).map_err(|source| Error::File {
        path: shown(path),
        what: "open",
        source,
    })?;
    Ok(BufReader::with_capacity(READ_BYTES, file))
}

/// A reader of whatever log `input` holds (candump -L, plain or timed
/// candump, Vector ASC or BLF, MF4, each perhaps gzip- or zstd-compressed: judged
/// from the content), keeping only interface `interface` when given. A log
/// of a format not read (python-can CSV, PEAK TRC, an empty one) is refused
/// by name with the way forward, and so is one without time (plain candump
/// output) when the caller `needs_time`. The error does not name the file:
/// the caller adds it.
///
/// # Errors
/// As above ([`Error::Log`]), or its first bytes cannot be read or decompressed.
pub fn log_reader<'a>(
    input: impl std::io::BufRead + 'a,
    interface: Option<&str>,
    needs_time: bool,
) -> Result<AnyLogReader<'a>> {
    checked_reader(AnyLogReader::open(input), interface, needs_time)
}

/// [`log_reader`]'s checks on an opened log.
fn checked_reader<'a>(
    opened: std::result::Result<(AnyLogReader<'a>, LogFormat, Option<LogFormat>), OpenError>,
    interface: Option<&str>,
    needs_time: bool,
) -> Result<AnyLogReader<'a>> {
    let (reader, format, _) = match opened {
        Ok(opened) => opened,
        Err(e @ OpenError::Io(_)) => return Err(Error::Log(e.to_string())),
        Err(e) => {
            let way = e.way_forward().unwrap_or("");
            return Err(Error::Log(format!("{e}; {way}")));
        }
    };
    if needs_time && !reader.has_time() {
        return Err(Error::Log(format!(
            "this is {}: {}",
            format.name(),
            LogFormat::untimed_way_forward()
        )));
    }
    Ok(match interface {
        Some(name) => reader.only_interface(name),
        None => reader,
    })
}

/// [`log_reader`] of the file at `path`, the errors naming it.
///
/// # Errors
/// The file cannot be opened, or [`log_reader`]'s.
pub fn open_log(
    path: &Path,
    interface: Option<&str>,
    needs_time: bool,
) -> Result<AnyLogReader<'static>> {
    // A file, not a stream: an MF4 log is read in place (no temporary copy).
    let file = open_file(path)?.into_inner();
    checked_reader(AnyLogReader::open_file(file), interface, needs_time).map_err(|e| match e {
        Error::Log(why) => Error::Log(format!("{}: {why}", path.display())),
        other => other,
    })
}

/// Why a log gave nothing to work on ([`Error::Log`] naming it), or the
/// warning when it mixes several interfaces and none was chosen.
///
/// # Errors
/// No frame read.
pub fn check_log_read(
    path: &Path,
    seen: &LogSeen,
    interface: Option<&str>,
) -> Result<Option<String>> {
    if let Some(why) = seen.refusal(interface) {
        return Err(Error::Log(format!("{}: {why}", path.display())));
    }
    Ok(seen
        .mixed_buses(interface)
        .map(|warning| format!("{}: {warning}", path.display())))
}

/// The frames of one log for work that goes through them in order
/// (calibration): malformed lines skipped and counted (the first five named
/// on stderr), one interface kept when asked, and the log refused at the
/// end when nothing usable was in it.
pub struct LogFrames<'a> {
    reader: AnyLogReader<'static>,
    path: &'a Path,
    label: &'static str,
    interface: Option<&'a str>,
    malformed: u64,
}

impl<'a> LogFrames<'a> {
    /// The frames `reader` reads of the log at `path` (named in messages
    /// with `label`, the command's name).
    pub fn new(
        reader: AnyLogReader<'static>,
        path: &'a Path,
        label: &'static str,
        interface: Option<&'a str>,
    ) -> Self {
        Self {
            reader,
            path,
            label,
            interface,
            malformed: 0,
        }
    }

    /// Opens the log at `path`.
    ///
    /// # Errors
    /// As [`open_log`].
    pub fn open(path: &'a Path, label: &'static str, interface: Option<&'a str>) -> Result<Self> {
        Ok(Self::new(
            open_log(path, interface, true)?,
            path,
            label,
            interface,
        ))
    }

    /// The next frame with its time; `None` at the end of the log.
    ///
    /// # Errors
    /// The log cannot be read.
    pub fn next_frame(&mut self) -> Result<Option<(Timestamp, CanFrame)>> {
        loop {
            match self.reader.next_record() {
                Ok(r) => return Ok(r.map(|r| (r.timestamp, r.frame))),
                Err(ReadError::Malformed(m)) => {
                    self.malformed += 1;
                    if self.malformed <= 5 {
                        eprintln!("{}: {}: {m}; skipped", self.label, self.path.display());
                    }
                }
                Err(e @ (ReadError::Io(_) | ReadError::Corrupt(_))) => {
                    return Err(Error::Read {
                        path: shown(self.path),
                        source: e,
                    });
                }
            }
        }
    }

    /// Malformed lines skipped so far.
    pub fn malformed(&self) -> u64 {
        self.malformed
    }

    /// [`check_log_read`] once the log is read, `frames` of it used: the
    /// warning about mixed interfaces, if any.
    ///
    /// # Errors
    /// No frame read.
    pub fn finish(&self, frames: u64) -> Result<Option<String>> {
        check_log_read(
            self.path,
            &LogSeen::of(&self.reader, frames, self.malformed),
            self.interface,
        )
    }
}
