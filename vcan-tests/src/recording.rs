//! Reading `canodom run --record` files back the two ways a user would: a
//! file whose daemon was killed with a streaming reader (it has no summary),
//! a finished one through its summary (the indexed reader Foxglove and
//! `ros2 bag` use). Each read also checks what issue #25 promises of every
//! file: nothing unreadable before its end, and per channel log times that
//! never go back.
//!
//! The streaming read is checked against a walk of the file's own records:
//! the walk decodes every whole chunk itself, and the `mcap` crate's
//! [`mcap::MessageStream`] must return exactly those messages, in that
//! order, before any error. A reader that stopped early (a damaged chunk, a
//! torn record in the middle) would return fewer, so "fails only at the very
//! end" is a comparison, not a hope.

use mcap::records::{Record, op};
use std::collections::{BTreeMap, HashMap};

/// One channel's messages in a file.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ChannelRead {
    /// Messages read.
    pub messages: u64,
    /// Log time of its first message, ns.
    pub first_ns: u64,
    /// Log time of its last message, ns.
    pub last_ns: u64,
}

/// What a read of one file found.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct FileRead {
    /// Messages by topic.
    pub channels: BTreeMap<String, ChannelRead>,
    /// Chunks read whole.
    pub chunks: u64,
    /// The file's size, bytes.
    pub bytes: usize,
    /// Bytes up to the end of the last whole record (all of them in a finished file).
    pub whole_bytes: usize,
    /// The file ends with a footer and the closing magic.
    pub finished: bool,
    /// The streaming reader's error after the last message: a file cut by a
    /// kill has no end magic, so some error there is expected.
    pub tail_error: Option<String>,
}

impl FileRead {
    /// Messages on every channel.
    pub fn messages(&self) -> u64 {
        self.channels.values().map(|c| c.messages).sum()
    }

    /// The first and last log time over every channel, ns; `None` without messages.
    pub fn span_ns(&self) -> Option<(u64, u64)> {
        let first = self.channels.values().map(|c| c.first_ns).min()?;
        let last = self.channels.values().map(|c| c.last_ns).max()?;
        Some((first, last))
    }

    /// The steps in the file: each step writes one message on each of the
    /// `channels` channels, so every channel must hold the same number, and
    /// at least one.
    ///
    /// # Errors
    /// Another number of channels, unequal counts, or no message.
    pub fn steps(&self, channels: usize) -> Result<u64, String> {
        if self.channels.len() != channels {
            return Err(format!(
                "{} channels with messages, expected {channels}: {:?}",
                self.channels.len(),
                self.channels.keys().collect::<Vec<_>>()
            ));
        }
        let counts: Vec<u64> = self.channels.values().map(|c| c.messages).collect();
        let steps = counts.first().copied().unwrap_or(0);
        if counts.iter().any(|&n| n != steps) {
            return Err(format!(
                "unequal message counts by channel: {:?}",
                self.channels
                    .iter()
                    .map(|(t, c)| (t.as_str(), c.messages))
                    .collect::<Vec<_>>()
            ));
        }
        if steps == 0 {
            return Err("no message".into());
        }
        Ok(steps)
    }
}

/// Adds a message at `log_ns` to `channels[topic]`, refusing a log time
/// before the channel's previous one.
fn count(
    channels: &mut BTreeMap<String, ChannelRead>,
    topic: &str,
    log_ns: u64,
) -> Result<(), String> {
    let c = channels.entry(topic.to_owned()).or_default();
    if c.messages > 0 && log_ns < c.last_ns {
        return Err(format!(
            "{topic}: message {} at {log_ns} ns, before the previous one at {} ns",
            c.messages + 1,
            c.last_ns
        ));
    }
    if c.messages == 0 {
        c.first_ns = log_ns;
    }
    c.last_ns = log_ns;
    c.messages += 1;
    Ok(())
}

/// The file's records from its start, each whole chunk decompressed here:
/// what it holds, and (channel, log time) of every message in file order.
/// Stops at the footer or at the first record the file does not hold whole.
fn walk(bytes: &[u8]) -> Result<(FileRead, Vec<(u16, u64)>), String> {
    if !bytes.starts_with(mcap::MAGIC) {
        return Err(format!(
            "no MCAP magic at the start of the file ({} bytes: {:02x?})",
            bytes.len(),
            &bytes[..bytes.len().min(8)]
        ));
    }
    let mut read = FileRead {
        bytes: bytes.len(),
        whole_bytes: mcap::MAGIC.len(),
        ..FileRead::default()
    };
    let mut topics: HashMap<u16, String> = HashMap::new();
    // (channel, log time) of every message in a whole chunk, in file order.
    let mut walked: Vec<(u16, u64)> = Vec::new();
    let mut at = mcap::MAGIC.len();
    // Records are opcode (1 byte), length (8, little-endian), content. The
    // walk stops at the first one the file does not hold whole: a kill cut
    // it, and nothing can follow it.
    while let Some(head) = bytes.get(at..at + 9) {
        let opcode = head[0];
        let mut len = [0u8; 8];
        len.copy_from_slice(&head[1..]);
        let Some(end) = usize::try_from(u64::from_le_bytes(len))
            .ok()
            .and_then(|n| (at + 9).checked_add(n))
            .filter(|&end| end <= bytes.len())
        else {
            break;
        };
        let record = mcap::parse_record(opcode, &bytes[at + 9..end])
            .map_err(|e| format!("record at byte {at} (opcode {opcode:#04x}): {e}"))?;
        match record {
            Record::Channel(c) => {
                topics.insert(c.id, c.topic);
            }
            Record::Chunk { header, data } => {
                let records = mcap::read::ChunkReader::new(header, &data)
                    .map_err(|e| format!("chunk at byte {at}: {e}"))?;
                for r in records {
                    match r.map_err(|e| format!("chunk at byte {at}: {e}"))? {
                        Record::Message { header, .. } => {
                            let topic = topics.get(&header.channel_id).ok_or_else(|| {
                                format!(
                                    "chunk at byte {at}: a message on unknown channel {}",
                                    header.channel_id
                                )
                            })?;
                            count(&mut read.channels, topic, header.log_time)?;
                            walked.push((header.channel_id, header.log_time));
                        }
                        // Other writers (the `mcap` crate's) put them in chunks.
                        Record::Channel(c) => {
                            topics.insert(c.id, c.topic);
                        }
                        _ => {}
                    }
                }
                read.chunks += 1;
            }
            Record::Message { header, .. } => {
                return Err(format!(
                    "a message outside a chunk at byte {at} (channel {}): canodom writes none",
                    header.channel_id
                ));
            }
            Record::Footer(_) => {
                if bytes[end..] != *mcap::MAGIC {
                    return Err(format!(
                        "footer at byte {at} not followed by the closing magic alone ({} bytes after it)",
                        bytes.len() - end
                    ));
                }
                read.finished = true;
                read.whole_bytes = bytes.len();
                break;
            }
            _ => {}
        }
        at = end;
        read.whole_bytes = end;
    }

    Ok((read, walked))
}

/// Reads a file from its start as a streaming reader does, which is all a
/// file whose writer was killed allows (see the module doc for how this
/// proves the reader fails only at the end).
///
/// # Errors
/// No MCAP magic at the start, a whole record that does not parse or
/// decompress, a message on an unknown channel, a log time going back on a
/// channel, a finished file the reader fails on, or the streaming reader
/// returning other messages than the file's whole chunks hold.
pub fn read_streaming(bytes: &[u8]) -> Result<FileRead, String> {
    let (mut read, walked) = walk(bytes)?;
    let mut stream = mcap::MessageStream::new(bytes).map_err(|e| e.to_string())?;
    let mut streamed: Vec<(u16, u64)> = Vec::with_capacity(walked.len());
    for m in stream.by_ref() {
        match m {
            Ok(m) => streamed.push((m.channel.id, m.log_time)),
            Err(e) => {
                read.tail_error = Some(e.to_string());
                break;
            }
        }
    }
    if read.tail_error.is_some() && stream.next().is_some() {
        return Err("the streaming reader went on after its error".into());
    }
    if let (true, Some(e)) = (read.finished, &read.tail_error) {
        return Err(format!(
            "a finished file, yet the streaming reader failed: {e}"
        ));
    }
    if streamed != walked {
        let same = streamed
            .iter()
            .zip(&walked)
            .take_while(|(a, b)| a == b)
            .count();
        return Err(format!(
            "the streaming reader returned {} messages ({:?}), the whole chunks hold {}; \
             they agree on the first {same}",
            streamed.len(),
            read.tail_error,
            walked.len()
        ));
    }
    Ok(read)
}

/// Reads a finished file through its summary: every chunk its index names,
/// the statistics checked against what the chunks hold, and the streaming
/// read (without error) giving the same counts.
///
/// # Errors
/// No summary (an unfinished file), a chunk the index names that cannot be
/// read, statistics that disagree with the chunks, or as [`read_streaming`].
pub fn read_indexed(bytes: &[u8]) -> Result<FileRead, String> {
    let summary = mcap::Summary::read(bytes)
        .map_err(|e| format!("summary: {e}"))?
        .ok_or("no summary: the file was not finished")?;
    let stats = summary
        .stats
        .as_ref()
        .ok_or("the summary has no statistics")?;
    let mut channels = BTreeMap::new();
    let mut by_id: BTreeMap<u16, u64> = BTreeMap::new();
    for index in &summary.chunk_indexes {
        let messages = summary
            .stream_chunk(bytes, index)
            .map_err(|e| format!("chunk at byte {}: {e}", index.chunk_start_offset))?;
        for m in messages {
            let m = m.map_err(|e| format!("chunk at byte {}: {e}", index.chunk_start_offset))?;
            count(&mut channels, &m.channel.topic, m.log_time)?;
            *by_id.entry(m.channel.id).or_default() += 1;
        }
    }
    let total: u64 = by_id.values().sum();
    if stats.chunk_count as usize != summary.chunk_indexes.len()
        || stats.message_count != total
        || stats
            .channel_message_counts
            .iter()
            .any(|(id, &n)| by_id.get(id).copied().unwrap_or(0) != n)
    {
        return Err(format!(
            "statistics ({} chunks, {} messages, {:?}) against the indexed chunks ({}, {total}, {by_id:?})",
            stats.chunk_count,
            stats.message_count,
            stats.channel_message_counts,
            summary.chunk_indexes.len()
        ));
    }
    let streamed = read_streaming(bytes)?;
    if !streamed.finished || streamed.channels != channels {
        return Err(format!(
            "the streaming read ({:?}) and the indexed read ({channels:?}) differ",
            streamed.channels
        ));
    }
    if let Some((first, last)) = streamed.span_ns()
        && (first != stats.message_start_time || last != stats.message_end_time)
    {
        return Err(format!(
            "messages span {first}..{last} ns, the statistics say {}..{}",
            stats.message_start_time, stats.message_end_time
        ));
    }
    Ok(streamed)
}

/// The record a kill cut at the end of `bytes`, whose whole records end at
/// `whole_bytes`: its opcode and the content length it declares (`None`
/// for the length when even its 9-byte head was cut); `None` when the file
/// ends on a record's end.
pub fn cut_record(bytes: &[u8], whole_bytes: usize) -> Option<(u8, Option<u64>)> {
    let opcode = *bytes.get(whole_bytes)?;
    let len = bytes
        .get(whole_bytes + 1..whole_bytes + 9)
        .and_then(|b| b.try_into().ok())
        .map(u64::from_le_bytes);
    Some((opcode, len))
}

/// `op::CHUNK` and `op::MESSAGE_INDEX`: the records a kill between two
/// flushes can cut (each chunk goes out with its indexes in one write).
pub const RECORDS_A_KILL_CUTS: [u8; 2] = [op::CHUNK, op::MESSAGE_INDEX];

// Host tests only: run-vm.sh runs every test the `vcan` build holds as a
// guest scenario, and these need no bus.
#[cfg(all(test, not(feature = "vcan")))]
mod tests {
    use super::*;
    use std::io::Cursor;

    const START_NS: u64 = 1_700_000_000_000_000_000;

    /// A finished file of `steps` steps, one message on each of three
    /// channels at `time(k)`, in LZ4 chunks of about 1 kB.
    fn file_timed(steps: u64, time: impl Fn(u64) -> u64) -> Vec<u8> {
        let mut out = Cursor::new(Vec::new());
        let options = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Lz4))
            .chunk_size(Some(1024));
        let mut w = options.create(&mut out).expect("an MCAP writer");
        let schema = w.add_schema("s", "jsonschema", b"{}").expect("a schema");
        let ids: Vec<u16> = ["/a", "/b", "/c"]
            .iter()
            .map(|t| {
                w.add_channel(schema, t, "json", &BTreeMap::new())
                    .expect("a channel")
            })
            .collect();
        for k in 0..steps {
            for &id in &ids {
                let header = mcap::records::MessageHeader {
                    channel_id: id,
                    sequence: k as u32,
                    log_time: time(k),
                    publish_time: time(k),
                };
                let data = format!("{{\"k\":{k},\"pad\":\"{:040}\"}}", k * 7919);
                w.write_to_known_channel(&header, data.as_bytes())
                    .expect("a message");
            }
        }
        w.finish().expect("a finished file");
        drop(w);
        out.into_inner()
    }

    fn file(steps: u64) -> Vec<u8> {
        file_timed(steps, |k| START_NS + k * 10_000_000)
    }

    /// Where the whole chunk records of `bytes` start.
    fn chunk_offsets(bytes: &[u8]) -> Vec<usize> {
        let summary = mcap::Summary::read(bytes)
            .expect("a readable summary")
            .expect("a finished file");
        summary
            .chunk_indexes
            .iter()
            .map(|c| c.chunk_start_offset as usize)
            .collect()
    }

    #[test]
    fn a_finished_file_reads_whole_both_ways() {
        let bytes = file(300);
        let read = read_indexed(&bytes).unwrap();
        assert!(read.finished && read.tail_error.is_none());
        assert_eq!(read.whole_bytes, bytes.len());
        assert_eq!(read.steps(3).unwrap(), 300);
        assert!(read.chunks > 10, "{} chunks", read.chunks);
        assert_eq!(
            read.span_ns(),
            Some((START_NS, START_NS + 299 * 10_000_000))
        );
        assert!(read.steps(9).is_err(), "three channels are not nine");
    }

    #[test]
    fn a_file_cut_inside_a_chunk_reads_up_to_that_chunk_and_fails_only_there() {
        let bytes = file(300);
        let chunks = chunk_offsets(&bytes);
        let cut_at = chunks[chunks.len() / 2] + 20;
        let cut = &bytes[..cut_at];
        let read = read_streaming(cut).unwrap();
        assert!(!read.finished);
        assert!(read.tail_error.is_some());
        assert_eq!(read.whole_bytes, chunks[chunks.len() / 2]);
        let (opcode, len) = cut_record(cut, read.whole_bytes).unwrap();
        assert_eq!(opcode, op::CHUNK);
        assert!(len.unwrap() as usize > cut.len() - read.whole_bytes - 9);
        assert_eq!(read.chunks as usize, chunks.len() / 2);
        assert!(read.messages() > 0 && read.messages() < 900);
        assert!(read_indexed(cut).is_err(), "no summary in a cut file");
    }

    #[test]
    fn a_damaged_chunk_before_the_end_is_an_error() {
        let mut bytes = file(300);
        let chunks = chunk_offsets(&bytes);
        // Inside the second chunk's compressed records.
        for b in &mut bytes[chunks[1] + 80..chunks[1] + 120] {
            *b = 0xFF;
        }
        let cut = &bytes[..chunks[chunks.len() - 1] + 20];
        assert!(read_streaming(cut).is_err());
    }

    #[test]
    fn a_torn_record_before_the_end_is_an_error() {
        let bytes = file(300);
        let chunks = chunk_offsets(&bytes);
        // What a writer that lost part of a chunk, then went on, would leave.
        let mut torn = bytes[..chunks[2] + 30].to_vec();
        torn.extend_from_slice(&bytes[chunks[3]..chunks[chunks.len() - 1]]);
        assert!(read_streaming(&torn).is_err());
    }

    #[test]
    fn an_empty_file_and_time_going_back_are_errors() {
        assert!(read_streaming(&[]).unwrap_err().contains("no MCAP magic"));
        let back = file_timed(100, |k| START_NS + (k % 60) * 10_000_000);
        assert!(
            read_streaming(&back)
                .unwrap_err()
                .contains("before the previous one")
        );
    }
}
