//! One reader for every CAN log format canodom reads (#25): `candump -L`,
//! plain and `-t` timed candump output, Vector ASC and BLF, ASAM MDF 4
//! (#34), each also gzip- or zstd-compressed, chosen from the content (never
//! the file name, which a pipe does not have).
//!
//! MF4 links its blocks by file offset and writers put the data before the
//! channels that describe it, so it is read from a seekable file: a file
//! opened by [`AnyLogReader::open_file`] directly, an MF4 met in a stream
//! (standard input, a `.mf4.gz`) through an unlinked temporary copy.
//!
//! Decompression is layered under the format: the compressed stream is
//! decompressed as it is read (`flate2`, `zstd`), and the decompressed
//! stream's own first bytes are sniffed again, so `drive.asc.gz` is read as
//! ASC. Nothing is decompressed to memory or disk first.
//!
//! `candump -L` keeps its reader's fast path ([`AnyLogReader::next_classic`]
//! hands it through); the other formats come through
//! [`AnyLogReader::next_record_general`], slower, as logs of tools that
//! record far fewer frames per second than canodom replays.

use crate::candump::{ClassicData, LogReader, ReadError, Record};
use crate::candump_plain::PlainReader;
use crate::log_format::{LogFormat, sniff};
use crate::log_lines::InterfaceList;
use crate::mdf4::Mf4Reader;
use crate::vector_asc::AscReader;
use crate::vector_blf::BlfReader;
use std::io::{self, BufRead, BufReader, Read, Seek};

/// Bytes looked at to judge a (decompressed) stream's format.
const SNIFF_BYTES: usize = 8192;

/// A buffered byte source (a file, standard input, a decompressor).
pub trait LogSource: BufRead {}

impl<T: BufRead> LogSource for T {}

impl std::fmt::Debug for dyn LogSource + '_ {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("LogSource")
    }
}

/// A boxed [`LogSource`] of any lifetime: the formats' readers are built
/// over one type whatever the compression.
pub type Source<'a> = Box<dyn LogSource + 'a>;

/// Why a log cannot be read at all.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// Reading its first bytes failed.
    #[error("cannot read: {0}")]
    Io(#[from] io::Error),
    /// Its format is one canodom does not read (its decompressed content's,
    /// when `compressed` names the compression).
    #[error("this is {}{}, which canodom does not read", .format.name(), .compressed.map(|c| format!(" inside {}", c.name())).unwrap_or_default())]
    NotRead {
        /// The format of the content.
        format: LogFormat,
        /// The compression around it, if any.
        compressed: Option<LogFormat>,
    },
}

impl OpenError {
    /// What to do instead, for a format not read.
    pub fn way_forward(&self) -> Option<&'static str> {
        match self {
            Self::Io(_) => None,
            Self::NotRead { format, .. } => format.way_forward(),
        }
    }
}

/// A reader of any log format canodom reads. Build it with [`AnyLogReader::open`].
#[derive(Debug)]
pub enum AnyLogReader<'a> {
    /// `candump -L` (and text of no known format, whose reader names every bad line).
    CandumpL(LogReader<Source<'a>>),
    /// Plain or `-t` timed candump output.
    Plain(PlainReader<Source<'a>>),
    /// Vector ASC.
    Asc(AscReader<Source<'a>>),
    /// Vector BLF.
    Blf(BlfReader<Source<'a>>),
    /// ASAM MDF 4, from a file (or a temporary copy of a stream).
    Mf4(Mf4Reader<BufReader<std::fs::File>>),
}

/// The first bytes of a decompressed `input`, as many as [`SNIFF_BYTES`]
/// or its end, consumed (a decompressor hands out small pieces, so one
/// `fill_buf` may show only a few bytes; the caller chains them back).
fn head(input: &mut Source<'_>) -> io::Result<Vec<u8>> {
    // A BufReader of SNIFF_BYTES over the stream can show that many bytes
    // only by filling its buffer from several reads: gather them here, then
    // chain them back in front.
    let mut head = Vec::with_capacity(SNIFF_BYTES);
    (&mut *input)
        .take(SNIFF_BYTES as u64)
        .read_to_end(&mut head)?;
    Ok(head)
}

impl<'a> AnyLogReader<'a> {
    /// Judges `input`'s format from its content (through gzip or zstd
    /// compression, one level), and returns a reader of it, with the format
    /// and the compression found.
    ///
    /// # Errors
    /// The first bytes cannot be read or decompressed, or the format is not
    /// one canodom reads ([`OpenError::NotRead`]: python-can CSV, PEAK TRC,
    /// an empty log, compression inside compression).
    pub fn open(
        input: impl BufRead + 'a,
    ) -> Result<(Self, LogFormat, Option<LogFormat>), OpenError> {
        Self::open_stream(Box::new(input))
    }

    /// [`Self::open`] of a file: an MF4 file is read in place (any other
    /// format as from a stream).
    ///
    /// # Errors
    /// As [`Self::open`].
    pub fn open_file(
        file: std::fs::File,
    ) -> Result<(Self, LogFormat, Option<LogFormat>), OpenError> {
        let mut reader = BufReader::with_capacity(1 << 16, file);
        if crate::mdf4::is_mdf(reader.fill_buf()?) {
            reader.rewind()?;
            let reader = Self::Mf4(Mf4Reader::new(reader));
            return Ok((reader, LogFormat::Mf4, None));
        }
        Self::open_stream(Box::new(reader))
    }

    fn open_stream(
        mut input: Source<'a>,
    ) -> Result<(Self, LogFormat, Option<LogFormat>), OpenError> {
        // The outer stream's buffer, not a gathered head: on a live pipe
        // (`candump -L can0 | canodom decode -`) the first frames must not
        // wait for kilobytes more.
        let outer = sniff(input.fill_buf()?);
        let compressed = match outer {
            LogFormat::Gzip => {
                // Multi-member: `cat a.gz b.gz` and pigz output are one stream.
                input = Box::new(BufReader::with_capacity(
                    1 << 16,
                    flate2::bufread::MultiGzDecoder::new(input),
                ));
                Some(outer)
            }
            LogFormat::Zstd => {
                input = Box::new(BufReader::with_capacity(
                    1 << 16,
                    zstd::stream::read::Decoder::with_buffer(input)?,
                ));
                Some(outer)
            }
            _ => None,
        };
        let format = if compressed.is_some() {
            let inner = head(&mut input)?;
            let format = sniff(&inner);
            input = Box::new(io::Cursor::new(inner).chain(input));
            format
        } else {
            outer
        };
        let reader = match format {
            LogFormat::CandumpL | LogFormat::Unknown => Self::CandumpL(LogReader::new(input)),
            LogFormat::CandumpPlain | LogFormat::CandumpTimed => {
                let mut reader = PlainReader::new(input);
                reader.judge_time(format == LogFormat::CandumpTimed);
                Self::Plain(reader)
            }
            LogFormat::VectorAsc => Self::Asc(AscReader::new(input)),
            LogFormat::VectorBlf => Self::Blf(BlfReader::new(input)),
            LogFormat::Mf4 => {
                // Its blocks link by offset: a temporary copy to seek in
                // (unlinked at once, gone with the reader).
                let mut copy = tempfile::tempfile()?;
                io::copy(&mut input, &mut copy)?;
                copy.rewind()?;
                Self::Mf4(Mf4Reader::new(BufReader::with_capacity(1 << 16, copy)))
            }
            LogFormat::PythonCanCsv
            | LogFormat::PeakTrc
            | LogFormat::Empty
            | LogFormat::Gzip
            | LogFormat::Zstd => return Err(OpenError::NotRead { format, compressed }),
        };
        Ok((reader, format, compressed))
    }

    /// Returns only the records of interface (channel) `name`; those of
    /// others are skipped and counted. ASC and BLF channels are named by
    /// their number as the file writes it (`1`, `2`, ...).
    #[must_use]
    pub fn only_interface(self, name: &str) -> Self {
        match self {
            Self::CandumpL(r) => Self::CandumpL(r.only_interface(name)),
            Self::Plain(mut r) => {
                r.interfaces.only(name);
                Self::Plain(r)
            }
            Self::Asc(mut r) => {
                r.interfaces.only(name);
                Self::Asc(r)
            }
            Self::Blf(mut r) => {
                r.interfaces.only(name);
                Self::Blf(r)
            }
            Self::Mf4(mut r) => {
                r.interfaces.only(name);
                Self::Mf4(r)
            }
        }
    }

    /// Whether the log's records carry a time: plain candump output (no
    /// `-t`) does not, and its records all read as time 0.
    pub fn has_time(&self) -> bool {
        match self {
            Self::Plain(r) => r.has_time(),
            _ => true,
        }
    }

    /// The next record, `Ok(None)` at the end.
    ///
    /// # Errors
    /// [`ReadError::Malformed`] for a bad line (or BLF object), after which
    /// reading goes on; [`ReadError::Io`] and [`ReadError::Corrupt`] end it.
    pub fn next_record(&mut self) -> Result<Option<Record<'_>>, ReadError> {
        match self {
            Self::CandumpL(r) => r.next_record(),
            _ => self.next_record_general(),
        }
    }

    /// `candump -L`'s fast path ([`LogReader::next_classic`]); `None` for
    /// every other format, whose records all come through
    /// [`Self::next_record_general`].
    // `always`: as LogReader::next_classic, replay's feeding loop.
    #[allow(clippy::inline_always)]
    #[inline(always)]
    pub fn next_classic(&mut self) -> Option<ClassicData> {
        match self {
            Self::CandumpL(r) => r.next_classic(),
            _ => None,
        }
    }

    /// Any record (for `candump -L`, after [`Self::next_classic`] gave `None`).
    ///
    /// # Errors
    /// As [`Self::next_record`].
    pub fn next_record_general(&mut self) -> Result<Option<Record<'_>>, ReadError> {
        match self {
            Self::CandumpL(r) => r.next_record_general(),
            Self::Plain(r) => r.next_record(),
            Self::Asc(r) => r.next_record(),
            Self::Blf(r) => r.next_record(),
            Self::Mf4(r) => r.next_record(),
        }
    }
}

impl InterfaceList for AnyLogReader<'_> {
    fn interfaces(&self) -> &[String] {
        match self {
            Self::CandumpL(r) => r.interfaces(),
            Self::Plain(r) => r.interfaces.seen(),
            Self::Asc(r) => r.interfaces.seen(),
            Self::Blf(r) => r.interfaces.seen(),
            Self::Mf4(r) => r.interfaces.seen(),
        }
    }

    fn other_interface_lines(&self) -> u64 {
        match self {
            Self::CandumpL(r) => r.other_interface_lines(),
            Self::Plain(r) => r.interfaces.other_lines(),
            Self::Asc(r) => r.interfaces.other_lines(),
            Self::Blf(r) => r.interfaces.other_lines(),
            Self::Mf4(r) => r.interfaces.other_lines(),
        }
    }
}
