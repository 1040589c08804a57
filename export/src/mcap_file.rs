//! An MCAP file of filter steps (<https://mcap.dev/spec>): the header, every
//! schema and channel once at the start, then chunks of messages each
//! followed by its message indexes, and at the end the summary (schemas,
//! channels, statistics, chunk indexes), its offsets and the footer.
//!
//! Written here rather than with the `mcap` crate's `Writer`, for time:
//! on the 1 M-frame bench log (333 k steps, 3 M messages) that writer took
//! 1.4 s of CPU with LZ4 (7 times the CSV replay's), this one 0.7 s (both
//! under the same load; bench/README.md has the figures). A third of it was the LZ4 frame's content checksum (XXH32,
//! not switchable there), a sixth the LZ4 frame API called once per field
//! written (each message's header is written field by field), the rest its
//! per-message bookkeeping (map lookups, counting writers). Here a message is
//! appended to the chunk's buffer with one copy and an index entry, and a
//! chunk is compressed with one call, without the content checksum; CRCs
//! are left out (0: "not computed", as the spec allows). The `mcap` crate
//! reads these files in this module's tests, the Python `mcap` library in
//! `tests/check_mcap.py`.
//!
//! Each chunk, with its message indexes, is written with one `write_all`
//! when it is full or on [`StepWriter::flush`]: a file whose writer was
//! killed holds every chunk finished before, readable by a streaming reader
//! (it lacks only the summary, which indexed readers want).

use crate::encode::{MessageSink, StepEncoder, Topic};
use crate::sample::{FrameSource, StepSample};
use crate::{Error, Result};
use canodom_fusion::VehicleParams;
use std::io::Write;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc;

/// MCAP's magic, at both ends of a file.
const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

/// Record opcodes (MCAP spec, "Records").
mod op {
    pub const HEADER: u8 = 0x01;
    pub const FOOTER: u8 = 0x02;
    pub const SCHEMA: u8 = 0x03;
    pub const CHANNEL: u8 = 0x04;
    pub const MESSAGE: u8 = 0x05;
    pub const CHUNK: u8 = 0x06;
    pub const MESSAGE_INDEX: u8 = 0x07;
    pub const CHUNK_INDEX: u8 = 0x08;
    pub const STATISTICS: u8 = 0x0B;
    pub const SUMMARY_OFFSET: u8 = 0x0E;
    pub const DATA_END: u8 = 0x0F;
}

/// How chunks are compressed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Compression {
    /// LZ4 frames: a quarter of the size, at the cost of the compression.
    #[default]
    Lz4,
    /// Uncompressed chunks: the fastest, the largest.
    None,
}

impl std::str::FromStr for Compression {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "lz4" => Ok(Self::Lz4),
            "none" => Ok(Self::None),
            other => Err(format!("unknown compression `{other}` (lz4, none)")),
        }
    }
}

/// How an MCAP file is written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct McapOptions {
    /// Chunk compression.
    pub compression: Compression,
    /// Uncompressed bytes per chunk (at most 4 MiB: one LZ4 block): what a
    /// kill can lose at most between flushes.
    pub chunk_bytes: usize,
}

impl Default for McapOptions {
    fn default() -> Self {
        Self {
            compression: Compression::Lz4,
            chunk_bytes: 1 << 20,
        }
    }
}

/// Little-endian record building on a `Vec`.
trait Put {
    fn u8(&mut self, v: u8);
    fn u16(&mut self, v: u16);
    fn u32(&mut self, v: u32);
    fn u64(&mut self, v: u64);
    fn string(&mut self, s: &[u8]);
    /// Starts a record: opcode and a length to patch; returns where the content starts.
    fn open(&mut self, opcode: u8) -> usize;
    /// Patches the length of the record whose content starts at `start`.
    fn close(&mut self, start: usize);
}

impl Put for Vec<u8> {
    fn u8(&mut self, v: u8) {
        self.push(v);
    }
    fn u16(&mut self, v: u16) {
        self.extend_from_slice(&v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.extend_from_slice(&v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.extend_from_slice(&v.to_le_bytes());
    }
    fn string(&mut self, s: &[u8]) {
        self.u32(s.len() as u32);
        self.extend_from_slice(s);
    }
    fn open(&mut self, opcode: u8) -> usize {
        self.push(opcode);
        self.u64(0);
        self.len()
    }
    fn close(&mut self, start: usize) {
        let len = (self.len() - start) as u64;
        self[start - 8..start].copy_from_slice(&len.to_le_bytes());
    }
}

/// What the summary keeps of a written chunk.
#[derive(Clone, Debug)]
struct ChunkIndex {
    start_ns: u64,
    end_ns: u64,
    offset: u64,
    length: u64,
    /// (channel id, offset of its message index record).
    message_indexes: Vec<(u16, u64)>,
    message_index_length: u64,
    compressed: u64,
    uncompressed: u64,
    /// `lz4` or empty (stored as it is).
    compression: &'static [u8],
}

/// A chunk of whole steps, uncompressed, with its message indexes: what
/// [`StepWriter::write_step`] fills, or what a caller fills on a thread of
/// its own ([`Chunk::push_step`]) and hands to [`StepWriter::write_chunk`].
#[derive(Debug, Default)]
pub struct Chunk {
    records: Vec<u8>,
    /// By channel: (log time, offset in `records`).
    index: [Vec<(u64, u64)>; Topic::ALL.len()],
    /// Messages by channel.
    counts: [u64; Topic::ALL.len()],
    /// First and last log time, once there is a message.
    time: Option<(u64, u64)>,
}

impl Chunk {
    /// Appends one step's messages, one per [`Topic`]: `sample`, the
    /// parameters in use, and the raw frames `frames.1..frames.2` of
    /// `frames.0` after those `encoder` carries ([`StepEncoder::carry`]).
    /// The message sequence number is the step's count
    /// ([`crate::sample::Counts::steps`]), so a chunk can be filled on any
    /// thread, and a gap in the numbers is a gap in the steps.
    pub fn push_step(
        &mut self,
        encoder: &mut StepEncoder,
        sample: &StepSample,
        params: &VehicleParams,
        frames: (&impl FrameSource, usize, usize),
    ) {
        let mut sink = ChunkSink {
            chunk: self,
            sequence: sample.counts.steps as u32,
            t_ns: None,
        };
        encoder.encode(sample, params, frames, &mut sink);
        // Every message of a step has the step's time.
        if let Some(t) = sink.t_ns {
            self.time = Some(widen(self.time, (t, t)));
        }
    }

    /// Uncompressed bytes so far.
    pub fn len(&self) -> usize {
        self.records.len()
    }

    /// Whether the chunk has no message.
    pub fn is_empty(&self) -> bool {
        self.records.is_empty()
    }

    /// Empties the chunk, keeping its allocations.
    fn clear(&mut self) {
        self.records.clear();
        for entries in &mut self.index {
            entries.clear();
        }
        self.counts = [0; Topic::ALL.len()];
        self.time = None;
    }
}

/// What the writing thread is asked to do.
enum Job {
    /// Compress and write a chunk.
    Chunk(Box<Chunk>),
    /// Say when every chunk sent before is written and flushed.
    Flush(mpsc::SyncSender<()>),
}

/// The output and what the summary needs of it: owned by the writing thread.
struct Output<W> {
    out: W,
    /// Bytes written to `out` so far (offsets in the summary count from the file's start).
    position: u64,
    /// `position`, for the caller (size rotation).
    written: Arc<AtomicU64>,
    compression: Compression,
    chunks: Vec<ChunkIndex>,
    /// A compressed chunk.
    scratch: Vec<u8>,
    /// Blocks of a chunk compressed on other threads (one per core beyond
    /// the writing thread's, at most three), reused.
    parts: Vec<Vec<u8>>,
    /// A chunk record with its message indexes, written at once.
    record: Vec<u8>,
}

/// The writing thread's handle: chunks go one way, emptied buffers come back.
struct Worker<W> {
    jobs: mpsc::SyncSender<Job>,
    spare: mpsc::Receiver<Box<Chunk>>,
    thread: std::thread::JoinHandle<(Output<W>, Result<()>)>,
}

/// Writes steps to an MCAP file, one message per [`Topic`] and step.
///
/// Chunks are compressed and written on a thread of the writer's own, fed
/// through a channel of two chunks, while the caller encodes the next: on
/// two cores the compression then costs little of the caller's time.
pub struct StepWriter<W: Write + Send + 'static> {
    worker: Worker<W>,
    options: McapOptions,
    /// The chunk [`Self::write_step`] fills.
    chunk: Box<Chunk>,
    /// Messages by channel, and the file's first and last log time.
    counts: [u64; Topic::ALL.len()],
    time: Option<(u64, u64)>,
    /// The schema and channel records (written at the start and in the summary).
    definitions: Vec<u8>,
    encoder: StepEncoder,
    /// The rear noise the encoders' twist covariance takes.
    k_rear_m: f64,
    /// Bytes the writing thread has written.
    written: Arc<AtomicU64>,
}

impl<W: Write + Send + 'static> std::fmt::Debug for StepWriter<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StepWriter")
            .field("counts", &self.counts)
            .finish_non_exhaustive()
    }
}

/// Appends a step's messages to the current chunk as message records.
struct ChunkSink<'a> {
    chunk: &'a mut Chunk,
    sequence: u32,
    /// The messages' log time.
    t_ns: Option<u64>,
}

impl MessageSink for ChunkSink<'_> {
    fn message(&mut self, topic: Topic, t_ns: u64, payload: impl FnOnce(&mut Vec<u8>)) {
        let chunk = &mut *self.chunk;
        let records = &mut chunk.records;
        let at = records.len();
        let k = topic as usize;
        chunk.index[k].push((t_ns, at as u64));
        chunk.counts[k] += 1;
        self.t_ns = Some(t_ns);
        // The record's 31 header bytes with one copy, its length patched
        // once the payload is written behind it.
        let mut header = [0u8; 31];
        header[0] = op::MESSAGE;
        header[9..11].copy_from_slice(&channel_id(topic).to_le_bytes());
        header[11..15].copy_from_slice(&self.sequence.to_le_bytes());
        header[15..23].copy_from_slice(&t_ns.to_le_bytes());
        header[23..31].copy_from_slice(&t_ns.to_le_bytes());
        records.extend_from_slice(&header);
        payload(records);
        let length = (records.len() - at - 9) as u64;
        records[at + 1..at + 9].copy_from_slice(&length.to_le_bytes());
    }
}

/// The span of times `a` widened to take in `b`.
fn widen(a: Option<(u64, u64)>, b: (u64, u64)) -> (u64, u64) {
    a.map_or(b, |(first, last)| (first.min(b.0), last.max(b.1)))
}

/// The channel id of a topic: its place in [`Topic::ALL`], from 1.
fn channel_id(topic: Topic) -> u16 {
    topic as u16 + 1
}

impl<W: Write + Send + 'static> StepWriter<W> {
    /// A writer onto `out` with the header, schemas and channels written;
    /// `k_rear_m` is the filter's rear noise (the twist covariance's).
    ///
    /// # Errors
    /// Writing.
    pub fn new(out: W, options: McapOptions, k_rear_m: f64) -> Result<Self> {
        let mut definitions = Vec::new();
        for topic in Topic::ALL {
            let schema = topic.schema();
            let at = definitions.open(op::SCHEMA);
            definitions.u16(channel_id(topic));
            definitions.string(schema.name.as_bytes());
            definitions.string(schema.encoding.as_bytes());
            definitions.string(&schema.data);
            definitions.close(at);
            let at = definitions.open(op::CHANNEL);
            definitions.u16(channel_id(topic));
            definitions.u16(channel_id(topic));
            definitions.string(topic.name().as_bytes());
            definitions.string(topic.message_encoding().as_bytes());
            definitions.u32(0);
            definitions.close(at);
        }
        let mut head = MAGIC.to_vec();
        let at = head.open(op::HEADER);
        head.string(b"ros2");
        head.string(concat!("canodom ", env!("CARGO_PKG_VERSION")).as_bytes());
        head.close(at);
        head.extend_from_slice(&definitions);
        let written = Arc::new(AtomicU64::new(0));
        let mut output = Output {
            out,
            position: 0,
            written: Arc::clone(&written),
            compression: options.compression,
            chunks: Vec::new(),
            scratch: Vec::new(),
            parts: vec![Vec::new(); compression_helpers()],
            record: Vec::new(),
        };
        output.emit(&head)?;
        // Out at once: a file killed before its first chunk is still an
        // MCAP file (header, schemas, channels, no message), not 0 bytes.
        output.out.flush().map_err(Error::write)?;
        let (jobs, inbox) = mpsc::sync_channel(2);
        let (give_back, spare) = mpsc::sync_channel(4);
        let thread = std::thread::Builder::new()
            .name("mcap-writer".into())
            .spawn(move || output.serve(&inbox, &give_back))
            .map_err(Error::write)?;
        Ok(Self {
            worker: Worker {
                jobs,
                spare,
                thread,
            },
            options,
            chunk: Box::default(),
            counts: [0; Topic::ALL.len()],
            time: None,
            definitions,
            encoder: StepEncoder::new(k_rear_m),
            k_rear_m,
            written,
        })
    }

    /// Writes one step: its sample, the parameters in use, and the raw
    /// frames `frames.1..frames.2` of `frames.0` (after those carried over
    /// by [`Self::carry`]).
    ///
    /// # Errors
    /// Writing.
    pub fn write_step(
        &mut self,
        sample: &StepSample,
        params: &VehicleParams,
        frames: (&impl FrameSource, usize, usize),
    ) -> Result<()> {
        self.chunk
            .push_step(&mut self.encoder, sample, params, frames);
        if self.chunk.records.len() >= self.options.chunk_bytes {
            self.finish_chunk()?;
        }
        Ok(())
    }

    /// Keeps frames `from..` of `frames` for the next step's raw-frame message.
    pub fn carry(&mut self, frames: &impl FrameSource, from: usize) {
        self.encoder.carry(frames, from);
    }

    /// Steps written (those in the chunk [`Self::write_step`] fills included).
    pub fn steps(&self) -> u64 {
        self.counts[0] + self.chunk.counts[0]
    }

    /// A new encoder for [`Chunk::push_step`], with this file's twist noise.
    pub fn encoder(&self) -> StepEncoder {
        StepEncoder::new(self.k_rear_m)
    }

    /// Writes `chunk` after everything written so far (the chunk
    /// [`Self::write_step`] was filling goes first), and returns an empty
    /// chunk to fill next, one the writing thread has finished with when it
    /// has one.
    ///
    /// # Errors
    /// Writing.
    pub fn write_chunk(&mut self, chunk: Chunk) -> Result<Chunk> {
        self.finish_chunk()?;
        let mut next = Box::new(chunk);
        std::mem::swap(&mut next, &mut self.chunk);
        self.finish_chunk()?;
        let mut spare = std::mem::replace(&mut self.chunk, next);
        spare.clear();
        Ok(*spare)
    }

    /// Bytes in the file so far (chunks still being compressed not yet).
    pub fn bytes_written(&self) -> u64 {
        self.written.load(Ordering::Relaxed)
    }

    /// Hands the current chunk to the writing thread.
    fn finish_chunk(&mut self) -> Result<()> {
        let Some(time) = self.chunk.time else {
            return Ok(());
        };
        self.time = Some(widen(self.time, time));
        for (total, n) in self.counts.iter_mut().zip(self.chunk.counts) {
            *total += n;
        }
        let mut next = self.worker.spare.try_recv().unwrap_or_default();
        std::mem::swap(&mut next, &mut self.chunk);
        self.send(Job::Chunk(next))
    }

    /// Sends `job` to the writing thread; if it has stopped, its error.
    fn send(&mut self, job: Job) -> Result<()> {
        if self.worker.jobs.send(job).is_ok() {
            return Ok(());
        }
        Err(Error::write(std::io::Error::other(
            "the MCAP writing thread stopped (its error comes with finish)",
        )))
    }

    /// Writes the current chunk out and flushes the output: a kill from now
    /// on loses nothing written so far.
    ///
    /// # Errors
    /// Writing.
    pub fn flush(&mut self) -> Result<()> {
        self.finish_chunk()?;
        let (done, written) = mpsc::sync_channel(1);
        self.send(Job::Flush(done))?;
        written
            .recv()
            .map_err(|_| Error::write(std::io::Error::other("the MCAP writing thread stopped")))
    }

    /// Finishes the file (last chunk, summary, footer) and returns the output.
    ///
    /// # Errors
    /// Writing.
    pub fn finish(mut self) -> Result<W> {
        let sent = self.finish_chunk();
        let Self {
            worker,
            counts,
            time,
            definitions,
            ..
        } = self;
        drop(worker.jobs);
        let (mut output, written) = worker
            .thread
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
        written?;
        sent?;
        let mut tail = Vec::new();
        let at = tail.open(op::DATA_END);
        tail.u32(0);
        tail.close(at);
        let summary_start = output.position + tail.len() as u64;
        // The summary: schemas, channels, statistics, chunk indexes, each a
        // group whose place the summary offsets give.
        let mut summary = Vec::new();
        let mut groups = Vec::new();
        let (mut schemas, mut channels) = (Vec::new(), Vec::new());
        let mut rest = &definitions[..];
        while rest.len() >= 9 {
            let len = u64::from_le_bytes(rest[1..9].try_into().unwrap_or_default()) as usize;
            let (record, after) = rest.split_at((9 + len).min(rest.len()));
            if record[0] == op::SCHEMA {
                schemas.extend_from_slice(record);
            } else {
                channels.extend_from_slice(record);
            }
            rest = after;
        }
        for (opcode, records) in [(op::SCHEMA, schemas), (op::CHANNEL, channels)] {
            groups.push((opcode, summary.len(), records.len()));
            summary.extend_from_slice(&records);
        }
        let start = summary.len();
        let (first, last) = time.unwrap_or((0, 0));
        let at = summary.open(op::STATISTICS);
        summary.u64(counts.iter().sum());
        summary.u16(Topic::ALL.len() as u16);
        summary.u32(Topic::ALL.len() as u32);
        summary.u32(0);
        summary.u32(0);
        summary.u32(output.chunks.len() as u32);
        summary.u64(first);
        summary.u64(last);
        summary.u32((counts.len() * 10) as u32);
        for (topic, n) in Topic::ALL.iter().zip(counts) {
            summary.u16(channel_id(*topic));
            summary.u64(n);
        }
        summary.close(at);
        groups.push((op::STATISTICS, start, summary.len() - start));
        let start = summary.len();
        for c in &output.chunks {
            let at = summary.open(op::CHUNK_INDEX);
            summary.u64(c.start_ns);
            summary.u64(c.end_ns);
            summary.u64(c.offset);
            summary.u64(c.length);
            summary.u32((c.message_indexes.len() * 10) as u32);
            for (id, offset) in &c.message_indexes {
                summary.u16(*id);
                summary.u64(*offset);
            }
            summary.u64(c.message_index_length);
            summary.string(c.compression);
            summary.u64(c.compressed);
            summary.u64(c.uncompressed);
            summary.close(at);
        }
        if !output.chunks.is_empty() {
            groups.push((op::CHUNK_INDEX, start, summary.len() - start));
        }
        let offsets_start = summary_start + summary.len() as u64;
        for (opcode, start, length) in groups {
            let at = summary.open(op::SUMMARY_OFFSET);
            summary.u8(opcode);
            summary.u64(summary_start + start as u64);
            summary.u64(length as u64);
            summary.close(at);
        }
        tail.extend_from_slice(&summary);
        let at = tail.open(op::FOOTER);
        tail.u64(summary_start);
        tail.u64(offsets_start);
        tail.u32(0);
        tail.close(at);
        tail.extend_from_slice(MAGIC);
        output.emit(&tail)?;
        output.out.flush().map_err(Error::write)?;
        Ok(output.out)
    }
}

impl<W: Write> Output<W> {
    fn emit(&mut self, bytes: &[u8]) -> Result<()> {
        self.out.write_all(bytes).map_err(Error::write)?;
        self.position += bytes.len() as u64;
        self.written.store(self.position, Ordering::Relaxed);
        Ok(())
    }

    /// The writing thread: chunks until the channel closes or a write fails.
    fn serve(
        mut self,
        jobs: &mpsc::Receiver<Job>,
        give_back: &mpsc::SyncSender<Box<Chunk>>,
    ) -> (Self, Result<()>) {
        for job in jobs {
            let done = match job {
                Job::Chunk(mut chunk) => {
                    let written = self.write_chunk(&mut chunk);
                    let _ = give_back.try_send(chunk);
                    written
                }
                Job::Flush(done) => {
                    let flushed = self.out.flush().map_err(Error::write);
                    let _ = done.send(());
                    flushed
                }
            };
            if let Err(e) = done {
                return (self, Err(e));
            }
        }
        (self, Ok(()))
    }

    /// Writes `chunk` and its message indexes with one write and flushes;
    /// leaves `chunk` empty for reuse.
    fn write_chunk(&mut self, chunk: &mut Chunk) -> Result<()> {
        let (start_ns, end_ns) = chunk.time.unwrap_or_default();
        let mut scratch = std::mem::take(&mut self.scratch);
        let mut head = std::mem::take(&mut self.record);
        let (compression, records): (&'static [u8], &[u8]) = match self.compression {
            Compression::None => (b"", &chunk.records),
            Compression::Lz4 => {
                scratch.clear();
                lz4_frame(&chunk.records, &mut scratch, &mut self.parts).map_err(Error::write)?;
                (b"lz4", &scratch)
            }
        };
        // The chunk record's fields, then its records as they are (not
        // copied behind the fields: that was a tenth of an uncompressed
        // file's time), then the message indexes.
        head.clear();
        head.push(op::CHUNK);
        head.u64((8 + 8 + 8 + 4 + 4 + compression.len() + 8 + records.len()) as u64);
        head.u64(start_ns);
        head.u64(end_ns);
        head.u64(chunk.records.len() as u64);
        head.u32(0);
        head.string(compression);
        head.u64(records.len() as u64);
        let length = (head.len() + records.len()) as u64;
        let fields = head.len();
        let mut message_indexes = Vec::new();
        for (topic, entries) in Topic::ALL.iter().zip(&mut chunk.index) {
            if entries.is_empty() {
                continue;
            }
            let at = self.position + length + (head.len() - fields) as u64;
            message_indexes.push((channel_id(*topic), at));
            let start = head.open(op::MESSAGE_INDEX);
            head.u16(channel_id(*topic));
            head.u32((entries.len() * 16) as u32);
            for (t, offset) in entries.drain(..) {
                head.u64(t);
                head.u64(offset);
            }
            head.close(start);
        }
        self.chunks.push(ChunkIndex {
            start_ns,
            end_ns,
            offset: self.position,
            length,
            message_indexes,
            message_index_length: (head.len() - fields) as u64,
            compressed: records.len() as u64,
            uncompressed: chunk.records.len() as u64,
            compression,
        });
        let written = self
            .emit(&head[..fields])
            .and_then(|()| self.emit(records))
            .and_then(|()| self.emit(&head[fields..]));
        chunk.clear();
        self.scratch = scratch;
        self.record = head;
        written?;
        self.out.flush().map_err(Error::write)
    }
}

/// Threads that compress beside the writing thread: one per further core,
/// at most three (the replay's own two threads need cores too, and four
/// compressing threads already outpace them).
fn compression_helpers() -> usize {
    std::thread::available_parallelism().map_or(0, |n| n.get().saturating_sub(1).min(3))
}

/// The LZ4 frame header of [`lz4_frame`]: magic, FLG `0x60` (version 1,
/// independent blocks, no checksums, no content size), BD `0x70` (blocks up
/// to 4 MiB), and the header's checksum (byte 2 of XXH32 of FLG and BD).
const LZ4_FRAME_HEADER: [u8; 7] = [0x04, 0x22, 0x4d, 0x18, 0x60, 0x70, 0x73];

/// LZ4's acceleration (1, its default, searches matches the hardest).
/// Measured on the bench log (replay CPU time, file size): 1 → 0.70 s,
/// 160 MB; 8 → 0.65 s, 181 MB; 32 → 0.60 s, 273 MB: the time goes to more
/// than the compressor, so the smallest file is kept.
const LZ4_ACCELERATION: i32 = 1;

/// The largest LZ4 block the frame header announces (BD `0x70`: 4 MiB).
const LZ4_MAX_BLOCK: usize = 4 << 20;

/// The smallest block worth a thread of its own: below it the thread costs
/// more than it saves.
const LZ4_MIN_PARALLEL_BLOCK: usize = 256 << 10;

/// `data` as one LZ4 frame (what MCAP's `lz4` means) appended to `out`:
/// LZ4's block compressor called once per block, without the frame API's
/// content checksum (a sixth of the time) and per-call overhead.
///
/// The frame's blocks are independent, so they compress at once, one per
/// buffer of `parts` (the first into `out` on the calling thread, the rest
/// on scoped threads): compression was the MCAP replay's longest thread, a
/// single one while the machine's other cores had time.
fn lz4_frame(data: &[u8], out: &mut Vec<u8>, parts: &mut [Vec<u8>]) -> std::io::Result<()> {
    out.extend_from_slice(&LZ4_FRAME_HEADER);
    let threads = 1 + parts.len();
    let block = data
        .len()
        .div_ceil(threads)
        .clamp(LZ4_MIN_PARALLEL_BLOCK, LZ4_MAX_BLOCK);
    let mut blocks = data.chunks(block);
    while blocks.len() > 0 {
        let first = blocks.next().unwrap_or_default();
        let rest: Vec<&[u8]> = blocks.by_ref().take(parts.len()).collect();
        let done = std::thread::scope(|scope| {
            let helpers: Vec<_> = rest
                .iter()
                .zip(parts.iter_mut())
                .map(|(b, part)| {
                    part.clear();
                    scope.spawn(move || lz4_block(b, part))
                })
                .collect();
            let mine = lz4_block(first, out);
            helpers
                .into_iter()
                .map(|h| {
                    h.join()
                        .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
                })
                .fold(mine, std::result::Result::and)
        });
        done?;
        for part in &parts[..rest.len()] {
            out.extend_from_slice(part);
        }
    }
    out.extend_from_slice(&0u32.to_le_bytes());
    Ok(())
}

/// One LZ4 frame block of `block` (at most [`LZ4_MAX_BLOCK`]) appended to
/// `out`: its size, then the compressed bytes, or the bytes as they are
/// when they do not shrink.
fn lz4_block(block: &[u8], out: &mut Vec<u8>) -> std::io::Result<()> {
    let at = out.len();
    let bound = lz4::block::compress_bound(block.len())?;
    out.resize(at + 4 + bound, 0);
    let n = lz4::block::compress_to_buffer(
        block,
        Some(lz4::block::CompressionMode::FAST(LZ4_ACCELERATION)),
        false,
        &mut out[at + 4..],
    )?;
    if n < block.len() {
        out.truncate(at + 4 + n);
        out[at..at + 4].copy_from_slice(&(n as u32).to_le_bytes());
    } else {
        // Stored: the block's size with the high bit set, then the bytes.
        out.truncate(at);
        out.extend_from_slice(&(block.len() as u32 | 0x8000_0000).to_le_bytes());
        out.extend_from_slice(block);
    }
    Ok(())
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::sample::{Counts, FrameBuffer, FrameRef};
    use canodom_can::time::Timestamp;
    use canodom_fusion::Pose;
    use canodom_fusion::ekf::WindowOutcome;
    use canodom_pipeline::pipeline::{PoseFlags, PoseOutput};

    /// A step `k` × 10 ms into a drive.
    pub(crate) fn sample(k: i64) -> StepSample {
        let pose = Pose {
            x_m: k as f64,
            y_m: 0.5,
            heading_rad: 0.1,
        };
        StepSample {
            t_unix_us: 1_700_000_000_000_000 + k * 10_000,
            fused: pose,
            rear_only: pose,
            output: PoseOutput {
                timestamp: Timestamp::from_micros(0),
                x_m: pose.x_m,
                y_m: pose.y_m,
                heading_rad: pose.heading_rad,
                speed_mps: 1.0,
                yaw_rate_radps: 0.0,
                pos_std_m: 0.01,
                heading_std_rad: 0.001,
                flags: PoseFlags::default(),
                param_version: 0,
            },
            covariance: [1e-4, 0.0, 0.0, 0.0, 1e-4, 0.0, 0.0, 0.0, 1e-6],
            rear_m: [0.01, 0.01],
            dt_s: 0.01,
            correction: WindowOutcome::Open,
            counts: Counts {
                steps: k as u64 + 1,
                ..Counts::default()
            },
            // A session that starts recording half-way.
            calibration_phase: if k < 250 { "idle" } else { "recording" },
            gnss: None,
            drift: None,
        }
    }

    /// Steps written with `options`, each with two raw frames.
    fn file(options: McapOptions, steps: i64) -> Vec<u8> {
        let params = canodom_fusion::VehicleParams::nominal(0.25, 0.30, 0.09, 1000).unwrap();
        let mut w = StepWriter::new(Vec::new(), options, 1e-5).unwrap();
        let mut frames = FrameBuffer::default();
        for k in 0..steps {
            frames.clear();
            for _ in 0..2 {
                frames.push(FrameRef {
                    timestamp: Timestamp::from_micros(k as u64),
                    id: canodom_can::frame::FrameId::standard(0x100).unwrap(),
                    data: &[1, 2, 3],
                });
            }
            w.write_step(&sample(k), &params, (&frames, 0, 2)).unwrap();
        }
        w.finish().unwrap()
    }

    #[test]
    fn the_mcap_crate_reads_every_message_and_the_summary() {
        for compression in [Compression::Lz4, Compression::None] {
            let options = McapOptions {
                compression,
                chunk_bytes: 16 << 10,
            };
            let bytes = file(options, 500);
            let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
            let stats = summary.stats.clone().unwrap();
            assert_eq!(stats.message_count, 500 * 9);
            assert!(stats.chunk_count > 10, "{} chunks", stats.chunk_count);
            assert_eq!(summary.chunk_indexes.len(), stats.chunk_count as usize);
            assert!(stats.channel_message_counts.values().all(|&n| n == 500));
            let mut per_topic = std::collections::BTreeMap::<String, u64>::new();
            let mut phases = Vec::new();
            for m in mcap::MessageStream::new(&bytes).unwrap() {
                let m = m.unwrap();
                let n = per_topic.entry(m.channel.topic.clone()).or_default();
                *n += 1;
                // The sequence is the step's count.
                assert_eq!(u64::from(m.sequence), *n, "{}", m.channel.topic);
                if m.channel.topic == Topic::Calibration.name() {
                    // The phase is the message's last field: a CDR string.
                    let text = m.data.rsplit(|&b| b == 0).nth(1).unwrap();
                    let phase = text.rsplit(|b| !b.is_ascii_lowercase()).next().unwrap();
                    phases.push(String::from_utf8(phase.to_vec()).unwrap());
                }
            }
            assert_eq!(per_topic.len(), 9);
            assert!(per_topic.values().all(|&n| n == 500));
            assert_eq!(phases[249], "idle");
            assert_eq!(phases[250], "recording");
            // The indexed read: every message of a chunk through its index.
            let first = &summary.chunk_indexes[0];
            let indexes = summary.read_message_indexes(&bytes, first).unwrap();
            let indexed: usize = indexes.values().map(Vec::len).sum();
            assert_eq!(
                indexed,
                mcap::MessageStream::new(&bytes)
                    .unwrap()
                    .take(indexed)
                    .count()
            );
        }
    }

    #[test]
    fn chunks_filled_elsewhere_go_in_order_between_the_writers_own_steps() {
        let params = canodom_fusion::VehicleParams::nominal(0.25, 0.30, 0.09, 1000).unwrap();
        let mut w = StepWriter::new(Vec::new(), McapOptions::default(), 1e-5).unwrap();
        let frames = FrameBuffer::default();
        for k in 0..3 {
            w.write_step(&sample(k), &params, (&frames, 0, 0)).unwrap();
        }
        // Filled as another thread would, with an encoder of its own.
        let mut encoder = w.encoder();
        let mut chunk = Chunk::default();
        for k in 3..6 {
            chunk.push_step(&mut encoder, &sample(k), &params, (&frames, 0, 0));
        }
        assert!(!chunk.is_empty());
        let spare = w.write_chunk(chunk).unwrap();
        assert!(spare.is_empty());
        for k in 6..9 {
            w.write_step(&sample(k), &params, (&frames, 0, 0)).unwrap();
        }
        assert_eq!(w.steps(), 9);
        let bytes = w.finish().unwrap();
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        assert_eq!(summary.chunk_indexes.len(), 3);
        let stats = summary.stats.unwrap();
        assert_eq!(stats.message_count, 9 * 9);
        let poses: Vec<(u32, u64)> = mcap::MessageStream::new(&bytes)
            .unwrap()
            .map(|m| m.unwrap())
            .filter(|m| m.channel.topic == Topic::Pose.name())
            .map(|m| (m.sequence, m.log_time))
            .collect();
        assert_eq!(
            poses.iter().map(|p| p.0).collect::<Vec<_>>(),
            (1..=9).collect::<Vec<_>>()
        );
        assert!(poses.windows(2).all(|p| p[0].1 < p[1].1));
    }

    #[test]
    fn a_file_killed_before_its_first_chunk_holds_its_header_and_channels() {
        let path = std::env::temp_dir().join(format!("canodom-head-{}.mcap", std::process::id()));
        let out = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
        let w = StepWriter::new(out, McapOptions::default(), 1e-5).unwrap();
        // What a kill now leaves: the bytes on disk, whole records only.
        let bytes = std::fs::read(&path).unwrap();
        assert!(bytes.starts_with(MAGIC));
        let (mut at, mut channels) = (MAGIC.len(), 0);
        while at < bytes.len() {
            let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
            channels += usize::from(bytes[at] == op::CHANNEL);
            at += 9 + len;
        }
        assert_eq!(at, bytes.len());
        assert_eq!(channels, Topic::ALL.len());
        w.finish().unwrap();
        let _ = std::fs::remove_file(&path);
    }

    #[test]
    fn an_lz4_frame_of_blocks_compressed_at_once_decodes_to_its_data() {
        // Repetitive enough to compress, varied enough to need real matches;
        // over 4 MiB, so even one thread writes two blocks.
        let data: Vec<u8> = (0..5_000_000u32)
            .map(|k| (k % 251) as u8 ^ (k / 7919) as u8)
            .collect();
        for helpers in [0, 1, 3] {
            let (mut out, mut parts) = (Vec::new(), vec![Vec::new(); helpers]);
            lz4_frame(&data, &mut out, &mut parts).unwrap();
            assert!(out.len() < data.len() / 2, "{helpers}: {} bytes", out.len());
            let mut back = Vec::new();
            let mut decoder = lz4::Decoder::new(&out[..]).unwrap();
            std::io::Read::read_to_end(&mut decoder, &mut back).unwrap();
            assert!(back == data, "{helpers} helpers: not the data back");
        }
    }

    #[test]
    fn a_file_cut_after_a_flush_is_readable_up_to_it() {
        let params = canodom_fusion::VehicleParams::nominal(0.25, 0.30, 0.09, 1000).unwrap();
        let mut w = StepWriter::new(Vec::new(), McapOptions::default(), 1e-5).unwrap();
        let frames = FrameBuffer::default();
        for k in 0..10 {
            w.write_step(&sample(k), &params, (&frames, 0, 0)).unwrap();
        }
        w.flush().unwrap();
        let whole = w.finish().unwrap();
        // What a kill right after the flush leaves: the start, up to the chunk's indexes.
        let Some(data_end) = whole
            .windows(9)
            .rposition(|r| r[0] == op::DATA_END && r[1] == 4)
        else {
            panic!("no DataEnd record");
        };
        let cut = &whole[..data_end];
        let mut n = 0;
        for m in mcap::MessageStream::new(cut).unwrap() {
            if m.is_err() {
                break;
            }
            n += 1;
        }
        assert_eq!(n, 10 * 9);
    }
}
