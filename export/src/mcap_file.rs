//! An MCAP file of filter steps: the `mcap` crate's writer used directly,
//! every channel registered once at the start, chunked, LZ4 or no
//! compression. (Logging each message through the Foxglove SDK's channel
//! API cost 19 times the CSV replay's time: a lookup, a lock and a copy per
//! message; written here, a step's nine messages cost about what its CSV row
//! does.)

use crate::encode::{StepEncoder, Topic};
use crate::sample::{FrameSource, StepSample};
use crate::{Error, Result};
use canodom_fusion::VehicleParams;
use mcap::records::MessageHeader;
use std::collections::BTreeMap;
use std::io::{Seek, Write};

/// How chunks are compressed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Compression {
    /// LZ4 frames: a quarter of the size at a small cost.
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
    /// Uncompressed bytes per chunk: what a kill can lose at most when
    /// chunks are finished as they fill.
    pub chunk_bytes: u64,
    /// Build each chunk in memory and write it whole: a file cut short then
    /// ends on a record boundary, readable up to its last chunk (and an
    /// unseekable output, a pipe, works).
    pub whole_chunks: bool,
}

impl Default for McapOptions {
    fn default() -> Self {
        Self {
            compression: Compression::Lz4,
            chunk_bytes: 1 << 20,
            whole_chunks: true,
        }
    }
}

/// Writes steps to an MCAP file, one message per [`Topic`] and step.
pub struct StepWriter<W: Write + Seek> {
    writer: mcap::Writer<W>,
    /// Channel ids by [`Topic::ALL`]'s order.
    ids: [u16; Topic::ALL.len()],
    encoder: StepEncoder,
    sequence: u32,
    steps: u64,
}

impl<W: Write + Seek> std::fmt::Debug for StepWriter<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StepWriter")
            .field("ids", &self.ids)
            .field("steps", &self.steps)
            .finish_non_exhaustive()
    }
}

impl<W: Write + Seek> StepWriter<W> {
    /// A writer onto `out` with every channel registered; `k_rear_m` is the
    /// filter's rear noise (the twist covariance's).
    ///
    /// # Errors
    /// Writing the header, schemas and channels.
    pub fn new(out: W, options: McapOptions, k_rear_m: f64) -> Result<Self> {
        let mut writer = mcap::WriteOptions::new()
            .compression(match options.compression {
                Compression::Lz4 => Some(mcap::Compression::Lz4),
                Compression::None => None,
            })
            .chunk_size(Some(options.chunk_bytes))
            .disable_seeking(options.whole_chunks)
            // CRCs are optional in MCAP (0: not computed); over every byte
            // twice (chunk and data section) they were a tenth of the time.
            .calculate_chunk_crcs(false)
            .calculate_data_section_crc(false)
            .profile("ros2")
            .library(concat!("canodom ", env!("CARGO_PKG_VERSION")))
            .create(out)
            .map_err(Error::mcap)?;
        let mut ids = [0; Topic::ALL.len()];
        for (id, topic) in ids.iter_mut().zip(Topic::ALL) {
            let schema = topic.schema();
            let schema_id = writer
                .add_schema(&schema.name, &schema.encoding, &schema.data)
                .map_err(Error::mcap)?;
            *id = writer
                .add_channel(
                    schema_id,
                    topic.name(),
                    topic.message_encoding(),
                    &BTreeMap::new(),
                )
                .map_err(Error::mcap)?;
        }
        Ok(Self {
            writer,
            ids,
            encoder: StepEncoder::new(k_rear_m),
            sequence: 0,
            steps: 0,
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
        let (writer, ids, sequence) = (&mut self.writer, &self.ids, &mut self.sequence);
        self.encoder
            .encode(sample, params, frames, |topic, t_ns, data| {
                let header = MessageHeader {
                    channel_id: ids[topic as usize],
                    sequence: *sequence,
                    log_time: t_ns,
                    publish_time: t_ns,
                };
                writer.write_to_known_channel(&header, data)
            })
            .map_err(Error::mcap)?;
        self.sequence = self.sequence.wrapping_add(1);
        self.steps += 1;
        Ok(())
    }

    /// Keeps frames `from..` of `frames` for the next step's raw-frame message.
    pub fn carry(&mut self, frames: &impl FrameSource, from: usize) {
        self.encoder.carry(frames, from);
    }

    /// Steps written.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Finishes the current chunk and flushes it to the output: a kill from
    /// now on loses nothing written so far.
    ///
    /// # Errors
    /// Writing.
    pub fn flush(&mut self) -> Result<()> {
        self.writer.flush().map_err(Error::mcap)
    }

    /// Finishes the file (last chunk, indexes, summary, footer) and returns the output.
    ///
    /// # Errors
    /// Writing.
    pub fn finish(mut self) -> Result<W> {
        self.writer.finish().map_err(Error::mcap)?;
        Ok(self.writer.into_inner())
    }
}
