//! ASAM MDF 4 bus logging files (`.mf4`, #34): what fleet loggers write
//! (CANedge, Vector, python-can's `MF4Writer` through asammdf), read as
//! CAN frames in time order.
//!
//! An MF4 file is a tree of blocks linked by absolute file offsets: the
//! identification (`MDF     `/`UnFinMF `), a header `##HD` (the start time
//! in ns), data groups `##DG`, each with channel groups `##CG` whose
//! channels `##CN` say where each value sits in a fixed-size record, and the
//! records themselves in `##DT` blocks, deflated in `##DZ` blocks (perhaps
//! transposed), chained by `##DL` lists (under a `##HL` in 4.1). A CAN bus
//! logging group (ASAM MDF bus logging) has a master time channel and a
//! structure channel `CAN_DataFrame` (or `CAN_RemoteFrame`,
//! `CAN_ErrorFrame`) whose components are `ID`, `IDE`, `DLC`,
//! `DataLength`, `DataBytes`, `BusChannel`, `Dir`, `EDL`, `BRS`, `ESI`.
//! A sorted data group holds one channel group; an unsorted one (CANedge)
//! holds several, each record led by its record id. Each data group's
//! records are in time order; the groups are merged by time (as python-can's
//! `MF4Reader` does), a tie going to the earlier group.
//!
//! Why by hand and not a crate (weighed for #34): `mdf4-rs` (0.6) reads the
//! whole file into memory (`MdfFile::parse_from_file` reads to the end) and
//! decodes a channel at a time into vectors of values, where a fleet log of
//! gigabytes must stream frame by frame; it also brings `serde_json`,
//! `dbc-rs` and `embedded-can` by default and changed maintainers twice in
//! its 12 releases of a few months. `falcon_mdf` (0.7) is careful on bad
//! input but also channel-wise (a `Signal` per channel, memory-mapped, with
//! rayon by default), so a frame would be reassembled from a dozen full
//! columns. What canodom needs is the few blocks above, read lazily: one
//! data block in memory at a time (a `##DZ` block is at most a few MB),
//! a few hundred lines. Decompression is `flate2`'s.
//!
//! Time: the header's start (ns since the epoch; read as UTC even when its
//! flag says local time, which has no offset to recover — python-can writes
//! the machine's local time there) plus the master channel's seconds
//! (float, or an integer through a linear conversion), rounded to the µs.
//! Channels are named by their `BusChannel` number (`1`, `2`, ...; `0`
//! where the file has none). A broken structure (no block where a link
//! points, a truncated block or record, a failed inflate, a bus logging
//! group without an `ID` or data bytes) ends reading with
//! [`ReadError::Corrupt`] naming the block and its byte offset. Records
//! stored as variable-length signal data (VLSD) are refused by name, not
//! misread.

use crate::candump::{Direction, Interfaces, ReadError, Record};
use crate::frame::{CLASSIC_MAX_LEN, CanFrame, FD_MAX_LEN, FrameId, MAX_EXTENDED_ID};
use crate::time::Timestamp;
use std::io::{self, Read, Seek, SeekFrom};

/// The first 8 bytes of a finalized MDF file.
pub const MAGIC: &[u8; 8] = b"MDF     ";
/// The first 8 bytes of an MDF file its writer did not finalize.
pub const MAGIC_UNFINISHED: &[u8; 8] = b"UnFinMF ";

/// Largest block read into memory (a `##DZ` block, a text): stops a corrupt
/// length from allocating gigabytes.
const MAX_BLOCK: u64 = 256 << 20;
/// Bytes of a `##DT` block read at a time.
const DT_CHUNK: u64 = 1 << 20;
/// Most channels followed in one channel group (a loop of links stops here).
const MAX_CHANNELS: usize = 4096;
/// Most blocks followed along one chain (data groups, list blocks).
const MAX_CHAIN: usize = 1 << 20;

/// Whether `head` starts like an MDF file (version 4 or not: the reader
/// names a version it does not read).
pub fn is_mdf(head: &[u8]) -> bool {
    head.starts_with(MAGIC) || head.starts_with(MAGIC_UNFINISHED)
}

/// A broken structure: the block `id` at byte offset `at`.
fn corrupt(id: &str, at: u64, why: &str) -> ReadError {
    ReadError::Corrupt(format!("MF4 block {id} at byte offset {at}: {why}"))
}

fn le(b: &[u8], at: usize, n: usize) -> Option<u64> {
    let s = b.get(at..at + n)?;
    Some(s.iter().rev().fold(0u64, |v, &x| (v << 8) | u64::from(x)))
}

/// A block read from the file: its id (`##XX`), links and data.
struct Block {
    id: [u8; 4],
    at: u64,
    links: Vec<u64>,
    data: Vec<u8>,
}

impl Block {
    fn name(&self) -> String {
        String::from_utf8_lossy(&self.id).into_owned()
    }

    fn link(&self, i: usize) -> u64 {
        self.links.get(i).copied().unwrap_or(0)
    }

    fn corrupt(&self, why: &str) -> ReadError {
        corrupt(&self.name(), self.at, why)
    }

    fn field(&self, at: usize, n: usize) -> Result<u64, ReadError> {
        le(&self.data, at, n).ok_or_else(|| self.corrupt("too short for its fields"))
    }
}

/// Where a value sits in a record and how it is stored.
#[derive(Clone, Copy, Debug)]
struct Field {
    byte_offset: usize,
    bit_offset: u32,
    bit_count: u32,
    data_type: u8,
}

impl Field {
    /// An unsigned integer value (little- or big-endian).
    fn uint(&self, record: &[u8]) -> Option<u64> {
        let bytes = (u64::from(self.bit_offset) + u64::from(self.bit_count)).div_ceil(8);
        if bytes == 0 || bytes > 8 {
            return None;
        }
        let raw = record.get(self.byte_offset..self.byte_offset + bytes as usize)?;
        let v = match self.data_type {
            0 | 2 => raw.iter().rev().fold(0u64, |v, &x| (v << 8) | u64::from(x)),
            1 | 3 => raw.iter().fold(0u64, |v, &x| (v << 8) | u64::from(x)),
            _ => return None,
        };
        let v = v >> self.bit_offset;
        Some(if self.bit_count >= 64 {
            v
        } else {
            v & ((1u64 << self.bit_count) - 1)
        })
    }

    /// A numeric value as f64 (float, unsigned or signed integer).
    fn number(&self, record: &[u8]) -> Option<f64> {
        match (self.data_type, self.bit_count) {
            (4 | 5, 32 | 64) => {
                let n = (self.bit_count / 8) as usize;
                let raw = record.get(self.byte_offset..self.byte_offset + n)?;
                let mut b = [0u8; 8];
                b[..n].copy_from_slice(raw);
                if self.data_type == 5 {
                    b[..n].reverse();
                }
                Some(if n == 8 {
                    f64::from_le_bytes(b)
                } else {
                    f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                })
            }
            (0 | 1, _) => self.uint(record).map(|v| v as f64),
            (2 | 3, 1..=64) => {
                let v = self.uint(record)?;
                let shift = 64 - self.bit_count;
                Some((((v << shift) as i64) >> shift) as f64)
            }
            _ => None,
        }
    }

    /// The bytes of a byte-array value.
    fn bytes<'r>(&self, record: &'r [u8]) -> Option<&'r [u8]> {
        let n = (self.bit_count / 8) as usize;
        record.get(self.byte_offset..self.byte_offset + n)
    }
}

/// A channel as its `##CN` block describes it.
struct Channel {
    name: String,
    cn_type: u8,
    sync: u8,
    field: Field,
    /// Its `##CC` conversion (0: none).
    conversion: u64,
    at: u64,
    /// Its signal data link (variable-length values).
    data_link: u64,
}

/// The kind of frame a bus logging channel group holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Data,
    Remote,
    Error,
}

/// The fields of a CAN bus logging channel group's records.
#[derive(Clone, Debug, Default)]
struct CanFields {
    id: Option<Field>,
    ide: Option<Field>,
    dlc: Option<Field>,
    data_length: Option<Field>,
    data_bytes: Option<Field>,
    bus_channel: Option<Field>,
    dir: Option<Field>,
    edl: Option<Field>,
    brs: Option<Field>,
    esi: Option<Field>,
}

/// A channel group of a data group: how long its records are and, for a
/// CAN bus logging group, where its frame's fields are.
#[derive(Clone, Debug)]
struct Group {
    record_id: u64,
    /// Bytes after the record id (data and invalidation bytes).
    record_bytes: usize,
    /// Variable-length records (a VLSD group): a u32 length, then the bytes.
    vlsd: bool,
    /// The frames it holds, with its time and fields; `None`: not CAN.
    can: Option<(Kind, Field, (f64, f64), CanFields)>,
}

/// One data group's records, read block by block.
#[derive(Debug)]
struct Stream {
    rec_id_size: usize,
    groups: Vec<Group>,
    /// Its data blocks (`##DT`/`##DZ`), in order.
    blocks: Vec<u64>,
    next_block: usize,
    /// The `##DT` block being read: file offset of the next chunk, bytes left.
    dt_at: u64,
    dt_left: u64,
    /// The block whose bytes are in `buf`, for error messages.
    block_name: &'static str,
    block_at: u64,
    buf: Vec<u8>,
    pos: usize,
    /// The next frame, read ahead for the merge by time.
    pending: Option<Pending>,
}

#[derive(Clone, Copy, Debug)]
struct Pending {
    t_us: u64,
    channel: u64,
    frame: CanFrame,
    direction: Direction,
}

/// Reader of an ASAM MDF 4 CAN bus logging file, from a seekable input.
#[derive(Debug)]
pub struct Mf4Reader<R> {
    inner: R,
    pub(crate) interfaces: Interfaces,
    started: bool,
    /// The file's length (0: not yet known).
    file_len: u64,
    start_ns: i128,
    streams: Vec<Stream>,
    /// Records met so far (their number names a bad one).
    records: u64,
    /// The channel `iface` names.
    channel: Option<u64>,
    iface: String,
}

impl<R: Read + Seek> Mf4Reader<R> {
    /// A reader over `input`, an MDF file from its first byte.
    pub fn new(input: R) -> Self {
        Self {
            inner: input,
            interfaces: Interfaces::default(),
            started: false,
            file_len: 0,
            start_ns: 0,
            streams: Vec::new(),
            records: 0,
            channel: None,
            iface: String::new(),
        }
    }

    fn read_at(&mut self, at: u64, buf: &mut [u8], id: &str) -> Result<(), ReadError> {
        if self.file_len == 0 {
            self.file_len = self.inner.seek(SeekFrom::End(0))?;
        }
        if at.saturating_add(buf.len() as u64) > self.file_len {
            return Err(corrupt(
                id,
                at,
                "lies past the end of the file (truncated, or a damaged link)",
            ));
        }
        self.inner.seek(SeekFrom::Start(at))?;
        self.inner.read_exact(buf).map_err(|e| {
            if e.kind() == io::ErrorKind::UnexpectedEof {
                corrupt(id, at, "the file ends inside this block (truncated?)")
            } else {
                ReadError::Io(e)
            }
        })
    }

    /// The block at `at`, which must be one of `expected` (ids as `b"##DG"`).
    fn block(&mut self, at: u64, expected: &[&[u8; 4]], what: &str) -> Result<Block, ReadError> {
        let mut head = [0u8; 24];
        self.read_at(at, &mut head, what)?;
        let mut id = [0u8; 4];
        id.copy_from_slice(&head[..4]);
        if !expected.iter().any(|e| **e == id) {
            return Err(corrupt(
                what,
                at,
                &format!(
                    "a link points here but finds {:?}, not a block of this kind",
                    String::from_utf8_lossy(&id)
                ),
            ));
        }
        let name = String::from_utf8_lossy(&id).into_owned();
        let len = le(&head, 8, 8).unwrap_or(0);
        let link_count = le(&head, 16, 8).unwrap_or(0);
        if !(24..=MAX_BLOCK).contains(&len) || link_count > (len - 24) / 8 {
            return Err(corrupt(&name, at, "implausible block length or link count"));
        }
        let mut body = vec![0u8; (len - 24) as usize];
        self.read_at(at + 24, &mut body, &name)?;
        let links_end = (link_count * 8) as usize;
        let links = body[..links_end]
            .chunks_exact(8)
            .map(|c| le(c, 0, 8).unwrap_or(0))
            .collect();
        Ok(Block {
            id,
            at,
            links,
            data: body[links_end..].to_vec(),
        })
    }

    /// A `##TX` text (or the XML of a `##MD`), empty for a null link.
    fn text(&mut self, at: u64) -> Result<String, ReadError> {
        if at == 0 {
            return Ok(String::new());
        }
        let block = self.block(at, &[b"##TX", b"##MD"], "##TX")?;
        let end = block
            .data
            .iter()
            .position(|&b| b == 0)
            .unwrap_or(block.data.len());
        Ok(String::from_utf8_lossy(&block.data[..end]).into_owned())
    }

    /// Reads the identification, header and every data group's layout.
    fn start(&mut self) -> Result<(), ReadError> {
        let mut id = [0u8; 64];
        self.read_at(0, &mut id, "identification")?;
        if !is_mdf(&id) {
            return Err(corrupt("identification", 0, "not an MDF file"));
        }
        let version = le(&id, 28, 2).unwrap_or(0);
        if !(400..500).contains(&version) {
            return Err(corrupt(
                "identification",
                0,
                &format!(
                    "MDF version {version}: canodom reads MDF 4 (convert with asammdf: \
                     `MDF(path).convert(\"4.10\").save(...)`)"
                ),
            ));
        }
        let hd = self.block(64, &[b"##HD"], "##HD")?;
        self.start_ns = i128::from(hd.field(0, 8)?);
        let mut dg_at = hd.link(0);
        let mut chain = 0;
        while dg_at != 0 {
            chain += 1;
            if chain > MAX_CHAIN {
                return Err(corrupt("##DG", dg_at, "the data group chain loops"));
            }
            let dg = self.block(dg_at, &[b"##DG"], "##DG")?;
            let rec_id_size = dg.field(0, 1)? as usize;
            if !matches!(rec_id_size, 0 | 1 | 2 | 4 | 8) {
                return Err(dg.corrupt(&format!("record id size {rec_id_size}")));
            }
            let mut groups = Vec::new();
            let mut cg_at = dg.link(1);
            while cg_at != 0 {
                if groups.len() > MAX_CHANNELS {
                    return Err(dg.corrupt("the channel group chain loops"));
                }
                let (group, next) = self.group(cg_at)?;
                groups.push(group);
                cg_at = next;
            }
            if rec_id_size == 0 && groups.len() > 1 {
                return Err(dg.corrupt("several channel groups without record ids"));
            }
            if groups.iter().any(|g| g.can.is_some()) && dg.link(2) != 0 {
                let blocks = self.data_blocks(dg.link(2))?;
                self.streams.push(Stream {
                    rec_id_size,
                    groups,
                    blocks,
                    next_block: 0,
                    dt_at: 0,
                    dt_left: 0,
                    block_name: "##DG",
                    block_at: dg.at,
                    buf: Vec::new(),
                    pos: 0,
                    pending: None,
                });
            }
            dg_at = dg.link(0);
        }
        self.started = true;
        Ok(())
    }

    /// The channel group at `at` and the next one's offset.
    fn group(&mut self, at: u64) -> Result<(Group, u64), ReadError> {
        let cg = self.block(at, &[b"##CG"], "##CG")?;
        let record_id = cg.field(0, 8)?;
        let flags = cg.field(16, 2)?;
        let data_bytes = cg.field(24, 4)?;
        let inval_bytes = cg.field(28, 4)?;
        let vlsd = flags & 1 != 0;
        let mut group = Group {
            record_id,
            record_bytes: (data_bytes + inval_bytes) as usize,
            vlsd,
            can: None,
        };
        if vlsd {
            return Ok((group, cg.link(0)));
        }
        let channels = self.channels(&cg)?;
        let mut time = None;
        let mut fields = CanFields::default();
        let mut kind = None;
        for Channel {
            name,
            cn_type,
            sync,
            field,
            conversion: cc,
            at: cn_at,
            data_link,
        } in channels
        {
            if cn_type == 2 && sync == 1 {
                time = Some((field, self.conversion(cc)?));
                continue;
            }
            let (prefix, leaf) = name.rsplit_once('.').unwrap_or(("", name.as_str()));
            let of = |k| prefix.ends_with(k) || name == k;
            let this = if of("CAN_DataFrame") {
                Kind::Data
            } else if of("CAN_RemoteFrame") {
                Kind::Remote
            } else if of("CAN_ErrorFrame") {
                Kind::Error
            } else {
                continue;
            };
            kind.get_or_insert(this);
            if cn_type == 1 || (leaf == "DataBytes" && data_link != 0) {
                return Err(corrupt(
                    "##CN",
                    cn_at,
                    &format!(
                        "{name} is stored as variable-length signal data, which canodom \
                         does not read yet (convert with asammdf to fixed-length records)"
                    ),
                ));
            }
            let slot = match leaf {
                "ID" => &mut fields.id,
                "IDE" => &mut fields.ide,
                "DLC" => &mut fields.dlc,
                "DataLength" => &mut fields.data_length,
                "DataBytes" => &mut fields.data_bytes,
                "BusChannel" => &mut fields.bus_channel,
                "Dir" => &mut fields.dir,
                "EDL" => &mut fields.edl,
                "BRS" => &mut fields.brs,
                "ESI" => &mut fields.esi,
                _ => continue,
            };
            *slot = Some(field);
        }
        if let Some(kind) = kind {
            let Some((time, conversion)) = time else {
                return Err(cg.corrupt("a CAN bus logging group without a master time channel"));
            };
            let missing = if fields.id.is_none() && kind != Kind::Error {
                Some("ID")
            } else if kind == Kind::Data && fields.data_bytes.is_none() {
                Some("DataBytes")
            } else {
                None
            };
            if let Some(missing) = missing {
                return Err(cg.corrupt(&format!(
                    "a CAN bus logging group without its {missing} channel"
                )));
            }
            for f in [fields.id, fields.data_bytes, Some(time)]
                .into_iter()
                .flatten()
            {
                if f.byte_offset + (f.bit_count as usize).div_ceil(8) > group.record_bytes {
                    return Err(cg.corrupt("a channel lies outside the record"));
                }
            }
            group.can = Some((kind, time, conversion, fields));
        }
        Ok((group, cg.link(0)))
    }

    /// Every channel of the channel group `cg`, structure components included.
    fn channels(&mut self, cg: &Block) -> Result<Vec<Channel>, ReadError> {
        let mut channels = Vec::new();
        let mut todo = vec![cg.link(1)];
        while let Some(mut cn_at) = todo.pop() {
            while cn_at != 0 {
                if channels.len() > MAX_CHANNELS {
                    return Err(cg.corrupt("the channel chain loops"));
                }
                let cn = self.block(cn_at, &[b"##CN"], "##CN")?;
                let name = self.text(cn.link(2))?;
                let field = Field {
                    byte_offset: cn.field(4, 4)? as usize,
                    bit_offset: cn.field(3, 1)? as u32,
                    bit_count: cn.field(8, 4)? as u32,
                    data_type: cn.field(2, 1)? as u8,
                };
                let kind = cn.field(0, 1)? as u8;
                let sync = cn.field(1, 1)? as u8;
                // A composition link to a structure's components (not a CA array).
                if cn.link(1) != 0 {
                    let mut head = [0u8; 4];
                    self.read_at(cn.link(1), &mut head, "##CN")?;
                    if &head == b"##CN" {
                        todo.push(cn.link(1));
                    }
                }
                channels.push(Channel {
                    name,
                    cn_type: kind,
                    sync,
                    field,
                    conversion: cn.link(4),
                    at: cn.at,
                    data_link: cn.link(5),
                });
                cn_at = cn.link(0);
            }
        }
        Ok(channels)
    }

    /// The time channel's conversion to seconds, `(offset, factor)`.
    fn conversion(&mut self, at: u64) -> Result<(f64, f64), ReadError> {
        if at == 0 {
            return Ok((0.0, 1.0));
        }
        let cc = self.block(at, &[b"##CC"], "##CC")?;
        let number = |i: usize| cc.field(24 + 8 * i, 8).map(f64::from_bits);
        match cc.field(0, 1)? {
            0 => Ok((0.0, 1.0)),
            1 => Ok((number(0)?, number(1)?)),
            t => Err(cc.corrupt(&format!(
                "time channel conversion of type {t}; canodom reads none or linear"
            ))),
        }
    }

    /// The data blocks under the data link `at`, in order.
    fn data_blocks(&mut self, at: u64) -> Result<Vec<u64>, ReadError> {
        let head = self.block_id(at)?;
        match &head {
            b"##DT" | b"##DZ" => return Ok(vec![at]),
            b"##HL" => {
                let hl = self.block(at, &[b"##HL"], "##HL")?;
                return self.list_blocks(hl.link(0));
            }
            b"##DL" => return self.list_blocks(at),
            _ => {}
        }
        Err(corrupt(
            &String::from_utf8_lossy(&head),
            at,
            "a data group's data link finds no data block (##DT, ##DZ, ##DL, ##HL)",
        ))
    }

    fn block_id(&mut self, at: u64) -> Result<[u8; 4], ReadError> {
        let mut id = [0u8; 4];
        self.read_at(at, &mut id, "data block")?;
        Ok(id)
    }

    fn list_blocks(&mut self, mut at: u64) -> Result<Vec<u64>, ReadError> {
        let mut blocks = Vec::new();
        let mut chain = 0;
        while at != 0 {
            chain += 1;
            if chain > MAX_CHAIN {
                return Err(corrupt("##DL", at, "the list chain loops"));
            }
            let dl = self.block(at, &[b"##DL"], "##DL")?;
            for &b in dl.links.iter().skip(1) {
                if b != 0 {
                    blocks.push(b);
                }
            }
            at = dl.link(0);
        }
        Ok(blocks)
    }

    /// Makes at least `n` unread bytes of `stream` available; `false` at
    /// the clean end of its data.
    fn fill(&mut self, s: usize, n: usize) -> Result<bool, ReadError> {
        loop {
            let stream = &mut self.streams[s];
            if stream.buf.len() - stream.pos >= n {
                return Ok(true);
            }
            if stream.pos > 0 {
                stream.buf.drain(..stream.pos);
                stream.pos = 0;
            }
            if stream.dt_left > 0 {
                let take = stream.dt_left.min(DT_CHUNK);
                let (at, block_at) = (stream.dt_at, stream.block_at);
                let mut chunk = vec![0u8; take as usize];
                self.read_at(at, &mut chunk, "##DT").map_err(|e| match e {
                    ReadError::Corrupt(_) => corrupt(
                        "##DT",
                        block_at,
                        "the file ends inside this block (truncated?)",
                    ),
                    other => other,
                })?;
                let stream = &mut self.streams[s];
                stream.buf.extend_from_slice(&chunk);
                stream.dt_at += take;
                stream.dt_left -= take;
                continue;
            }
            let Some(&at) = stream.blocks.get(stream.next_block) else {
                if stream.buf.is_empty() {
                    return Ok(false);
                }
                return Err(corrupt(
                    stream.block_name,
                    stream.block_at,
                    "the data ends inside a record",
                ));
            };
            stream.next_block += 1;
            let id = self.block_id(at)?;
            match &id {
                b"##DT" => {
                    let mut head = [0u8; 24];
                    self.read_at(at, &mut head, "##DT")?;
                    let len = le(&head, 8, 8).unwrap_or(0);
                    if len < 24 {
                        return Err(corrupt("##DT", at, "implausible block length"));
                    }
                    let stream = &mut self.streams[s];
                    stream.block_name = "##DT";
                    stream.block_at = at;
                    stream.dt_at = at + 24;
                    stream.dt_left = len - 24;
                }
                b"##DZ" => {
                    let dz = self.block(at, &[b"##DZ"], "##DZ")?;
                    let content = inflate(&dz)?;
                    let stream = &mut self.streams[s];
                    stream.block_name = "##DZ";
                    stream.block_at = at;
                    stream.buf.extend_from_slice(&content);
                }
                other => {
                    return Err(corrupt(
                        &String::from_utf8_lossy(other),
                        at,
                        "a data list links here but this is no ##DT or ##DZ block",
                    ));
                }
            }
        }
    }

    /// Reads the next CAN frame of stream `s` into its `pending`.
    fn advance(&mut self, s: usize) -> Result<(), ReadError> {
        self.streams[s].pending = None;
        loop {
            let rec_id_size = self.streams[s].rec_id_size;
            if !self.fill(s, rec_id_size.max(1))? {
                return Ok(());
            }
            let stream = &self.streams[s];
            let (at, name) = (stream.block_at, stream.block_name);
            let record_id = if rec_id_size == 0 {
                stream.groups.first().map_or(0, |g| g.record_id)
            } else {
                le(&stream.buf, stream.pos, rec_id_size).unwrap_or(0)
            };
            let Some(g) = stream.groups.iter().position(|g| g.record_id == record_id) else {
                return Err(corrupt(
                    name,
                    at,
                    &format!("a record of id {record_id}, which no channel group has"),
                ));
            };
            let length = if stream.groups[g].vlsd {
                if !self.fill(s, rec_id_size + 4)? {
                    return Err(corrupt(name, at, "the data ends inside a record"));
                }
                let stream = &self.streams[s];
                let n = le(&stream.buf, stream.pos + rec_id_size, 4).unwrap_or(0);
                if n > MAX_BLOCK {
                    return Err(corrupt(name, at, "implausible variable-length record"));
                }
                4 + n as usize
            } else {
                self.streams[s].groups[g].record_bytes
            };
            if !self.fill(s, rec_id_size + length)? {
                return Err(corrupt(name, at, "the data ends inside a record"));
            }
            let stream = &mut self.streams[s];
            let start = stream.pos + rec_id_size;
            stream.pos = start + length;
            let Some((kind, time, conversion, fields)) = &stream.groups[g].can else {
                continue;
            };
            self.records += 1;
            let record = &stream.buf[start..start + length];
            let Some(t_s) = time.number(record).map(|v| conversion.0 + conversion.1 * v) else {
                return Err(corrupt(name, at, "the time channel cannot be read"));
            };
            let t_ns = self.start_ns.saturating_add((t_s * 1e9).round() as i128);
            let t_us = t_ns.saturating_add(500).div_euclid(1000);
            let Some((frame, channel, direction)) = can_frame(*kind, fields, record) else {
                return Err(corrupt(
                    name,
                    at,
                    &format!(
                        "record {} holds no valid CAN frame (id or length out of range)",
                        self.records
                    ),
                ));
            };
            let Ok(t_us) = u64::try_from(t_us) else {
                return Err(corrupt(
                    name,
                    at,
                    &format!("record {} lies before 1970", self.records),
                ));
            };
            self.streams[s].pending = Some(Pending {
                t_us,
                channel,
                frame,
                direction,
            });
            return Ok(());
        }
    }

    /// The next CAN record, in time order; `Ok(None)` at the end.
    ///
    /// # Errors
    /// [`ReadError::Corrupt`] naming the block and its byte offset for a
    /// broken or truncated file; I/O.
    pub fn next_record(&mut self) -> Result<Option<Record<'_>>, ReadError> {
        if !self.started {
            self.start()?;
            for s in 0..self.streams.len() {
                self.advance(s)?;
            }
        }
        loop {
            let next = self
                .streams
                .iter()
                .enumerate()
                .filter_map(|(i, s)| s.pending.map(|p| (p.t_us, i)))
                .min();
            let Some((_, s)) = next else {
                return Ok(None);
            };
            let Some(p) = self.streams[s].pending else {
                return Ok(None);
            };
            self.advance(s)?;
            if self.channel != Some(p.channel) {
                self.channel = Some(p.channel);
                self.iface = p.channel.to_string();
            }
            if !self.interfaces.pass(&self.iface) {
                continue;
            }
            return Ok(Some(Record {
                timestamp: Timestamp::from_micros(p.t_us),
                iface: &self.iface,
                frame: p.frame,
                direction: Some(p.direction),
            }));
        }
    }
}

/// A `##DZ` block's original data: inflated (zlib), and un-transposed when
/// it was transposed (`dz_zip_parameter` columns, the rows that fill them;
/// a remainder that fills no row is stored as it was).
fn inflate(dz: &Block) -> Result<Vec<u8>, ReadError> {
    let zip_type = dz.field(2, 1)?;
    let columns = dz.field(4, 4)? as usize;
    let original = dz.field(8, 8)?;
    let stored = dz.field(16, 8)? as usize;
    if original > MAX_BLOCK {
        return Err(dz.corrupt("implausible original length"));
    }
    let Some(zipped) = dz.data.get(24..24usize.saturating_add(stored)) else {
        return Err(dz.corrupt("its compressed data is longer than the block"));
    };
    let mut out = Vec::with_capacity(original as usize);
    flate2::read::ZlibDecoder::new(zipped)
        .take(original)
        .read_to_end(&mut out)
        .map_err(|e| dz.corrupt(&format!("does not inflate: {e}")))?;
    if out.len() as u64 != original {
        return Err(dz.corrupt(&format!(
            "inflates to {} bytes, not the {original} it says",
            out.len()
        )));
    }
    match zip_type {
        0 => Ok(out),
        1 if columns > 0 => {
            let rows = out.len() / columns;
            let mut plain = vec![0u8; out.len()];
            for c in 0..columns {
                for r in 0..rows {
                    plain[r * columns + c] = out[c * rows + r];
                }
            }
            plain[rows * columns..].copy_from_slice(&out[rows * columns..]);
            Ok(plain)
        }
        t => Err(dz.corrupt(&format!("unknown compression {t}"))),
    }
}

/// The frame, channel and direction of a bus logging record.
fn can_frame(kind: Kind, f: &CanFields, record: &[u8]) -> Option<(CanFrame, u64, Direction)> {
    let get = |field: Option<Field>| field.and_then(|f| f.uint(record));
    let channel = get(f.bus_channel).unwrap_or(0);
    let direction = if get(f.dir).unwrap_or(0) != 0 {
        Direction::Tx
    } else {
        Direction::Rx
    };
    if kind == Kind::Error {
        return Some((CanFrame::new_error(0, [0; 8]).ok()?, channel, direction));
    }
    let raw = u32::try_from(get(f.id)?).ok()?;
    // Bit 31 is the extended flag of some writers; IDE is the standard's.
    let extended = get(f.ide).unwrap_or(0) != 0 || raw & 0x8000_0000 != 0;
    let id = if extended {
        FrameId::extended(raw & MAX_EXTENDED_ID).ok()?
    } else {
        FrameId::standard(u16::try_from(raw).ok()?).ok()?
    };
    let dlc = u8::try_from(get(f.dlc).unwrap_or(0)).ok()?;
    let len = match get(f.data_length) {
        Some(n) => usize::try_from(n).ok()?,
        None => crate::frame::fd_dlc_len(dlc),
    };
    if kind == Kind::Remote {
        let len8 = (dlc > 8).then_some(dlc);
        return Some((
            CanFrame::new_remote(id, usize::from(dlc.min(8)), len8).ok()?,
            channel,
            direction,
        ));
    }
    let bytes = f.data_bytes?.bytes(record)?;
    let data = bytes.get(..len)?;
    let frame = if get(f.edl).unwrap_or(0) != 0 {
        if len > FD_MAX_LEN {
            return None;
        }
        let flags =
            u8::from(get(f.brs).unwrap_or(0) != 0) | (u8::from(get(f.esi).unwrap_or(0) != 0) << 1);
        CanFrame::new_fd(id, flags, data).ok()?
    } else {
        let len8 = (dlc > 8 && len == CLASSIC_MAX_LEN).then_some(dlc);
        CanFrame::new_data_with_dlc(id, data, len8).ok()?
    };
    Some((frame, channel, direction))
}
