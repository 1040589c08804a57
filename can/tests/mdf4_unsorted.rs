//! An unsorted MF4 file, as CANedge loggers write them: several channel
//! groups in one data group, each record led by its record id. python-can and
//! asammdf write sorted files only, so this one is built here block by block
//! after ASAM MDF 4.1 (identification, `##HD`, `##DG` with a record id size,
//! `##CG`s with record ids, `##CN` structures, a linear `##CC` on an integer
//! time channel, the data under a `##HL` over two chained `##DL` lists of
//! `##DT` blocks split inside records), with a non-CAN group and a VLSD
//! group among the CAN groups: both must be skipped by their length.

// Test helpers outside #[test] functions unwrap too: a failure is a test failure.
#![allow(clippy::unwrap_used)]

mod common;

use canodom_can::any_log::AnyLogReader;
use canodom_can::log_format::LogFormat;
use std::io::Write;

/// Where a channel's value sits: (channel type, sync type, data type, bit
/// offset, byte offset, bits).
type Layout = (u8, u8, u8, u8, u32, u32);

/// The file being built: blocks appended at 8-byte aligned offsets.
struct Mf4 {
    bytes: Vec<u8>,
}

impl Mf4 {
    /// The identification block and room for the `##HD` at 64.
    fn new() -> Self {
        let mut bytes = Vec::new();
        bytes.extend_from_slice(b"MDF     4.10    canodom ");
        bytes.extend_from_slice(&[0; 4]);
        bytes.extend_from_slice(&410u16.to_le_bytes());
        bytes.resize(64, 0);
        Self { bytes }
    }

    /// Appends a block; its offset.
    fn block(&mut self, id: [u8; 4], links: &[u64], data: &[u8]) -> u64 {
        let at = self.bytes.len() as u64;
        let len = 24 + 8 * links.len() + data.len();
        self.bytes.extend_from_slice(&id);
        self.bytes.extend_from_slice(&[0; 4]);
        self.bytes.extend_from_slice(&(len as u64).to_le_bytes());
        self.bytes
            .extend_from_slice(&(links.len() as u64).to_le_bytes());
        for l in links {
            self.bytes.extend_from_slice(&l.to_le_bytes());
        }
        self.bytes.extend_from_slice(data);
        while !self.bytes.len().is_multiple_of(8) {
            self.bytes.push(0);
        }
        at
    }

    fn text(&mut self, text: &str) -> u64 {
        let mut data = text.as_bytes().to_vec();
        data.push(0);
        self.block(*b"##TX", &[], &data)
    }

    /// A `##CN`: (type, sync, data type, bit offset, byte offset, bits).
    fn channel(
        &mut self,
        next: u64,
        composition: u64,
        name: &str,
        conversion: u64,
        (cn_type, sync, data_type, bit_offset, byte_offset, bits): Layout,
    ) -> u64 {
        let name = self.text(name);
        let mut data = vec![cn_type, sync, data_type, bit_offset];
        data.extend_from_slice(&byte_offset.to_le_bytes());
        data.extend_from_slice(&bits.to_le_bytes());
        data.resize(72, 0);
        self.block(
            *b"##CN",
            &[next, composition, name, 0, conversion, 0, 0, 0],
            &data,
        )
    }

    /// A chain of channels (the first one's offset), given in order.
    fn chain(&mut self, channels: &[(&str, u64, Layout)]) -> u64 {
        let mut next = 0;
        for &(name, conversion, layout) in channels.iter().rev() {
            next = self.channel(next, 0, name, conversion, layout);
        }
        next
    }

    /// A `##CG` of `record_id`, `data_bytes` long, `flags` (bit 0: VLSD).
    fn group(&mut self, next: u64, first: u64, record_id: u64, data_bytes: u32, flags: u16) -> u64 {
        let mut data = Vec::new();
        data.extend_from_slice(&record_id.to_le_bytes());
        data.extend_from_slice(&0u64.to_le_bytes());
        data.extend_from_slice(&flags.to_le_bytes());
        data.extend_from_slice(&[0; 6]);
        data.extend_from_slice(&data_bytes.to_le_bytes());
        data.extend_from_slice(&0u32.to_le_bytes());
        self.block(*b"##CG", &[next, first, 0, 0, 0, 0], &data)
    }
}

const START_NS: u64 = 1_700_000_000_123_456_000;
/// The time channel counts 10 µs ticks (a linear conversion to seconds).
const TICK_S: f64 = 1e-5;

/// One record of the data group, and the frame (µs, channel, candump text)
/// it must read as, if any.
struct Written {
    bytes: Vec<u8>,
    frame: Option<(u64, String, String)>,
}

fn data_record(ticks: u64, channel: u8, id: u32, extended: bool, data: &[u8]) -> Written {
    let mut b = vec![1u8];
    b.extend_from_slice(&ticks.to_le_bytes());
    b.push(channel);
    b.extend_from_slice(&id.to_le_bytes());
    b.push(u8::from(extended) | ((data.len() as u8) << 1));
    b.push(data.len() as u8);
    let mut payload = [0xEEu8; 8];
    payload[..data.len()].copy_from_slice(data);
    b.extend_from_slice(&payload);
    let hex: String = data
        .iter()
        .fold(String::new(), |hex, x| hex + &format!("{x:02X}"));
    let text = if extended {
        format!("{id:08X}#{hex}")
    } else {
        format!("{id:03X}#{hex}")
    };
    Written {
        bytes: b,
        frame: Some((START_NS / 1000 + ticks * 10, channel.to_string(), text)),
    }
}

fn remote_record(ticks: u64, channel: u8, id: u32, dlc: u8) -> Written {
    let mut b = vec![2u8];
    b.extend_from_slice(&ticks.to_le_bytes());
    b.push(channel);
    // Bit 31: the extended flag as some writers store it, without IDE.
    b.extend_from_slice(&(id | 0x8000_0000).to_le_bytes());
    b.push(dlc);
    Written {
        bytes: b,
        frame: Some((
            START_NS / 1000 + ticks * 10,
            channel.to_string(),
            if dlc == 0 {
                format!("{id:08X}#R")
            } else {
                format!("{id:08X}#R{dlc}")
            },
        )),
    }
}

fn gps_record(ticks: u64, speed: f64) -> Written {
    let mut b = vec![3u8];
    b.extend_from_slice(&(ticks as f64 * TICK_S).to_le_bytes());
    b.extend_from_slice(&speed.to_le_bytes());
    Written {
        bytes: b,
        frame: None,
    }
}

fn vlsd_record(text: &[u8]) -> Written {
    let mut b = vec![4u8];
    b.extend_from_slice(&(text.len() as u32).to_le_bytes());
    b.extend_from_slice(text);
    Written {
        bytes: b,
        frame: None,
    }
}

/// The records of the drive: CAN frames of both kinds on two channels,
/// with GPS and VLSD records between them.
fn records() -> Vec<Written> {
    let mut out = Vec::new();
    for k in 0..60u64 {
        let t = 100 + k * 37;
        let byte = k as u8;
        out.push(data_record(
            t,
            1,
            0x1A0,
            false,
            &[byte, 2, 3, 4, 5, 6, 7, 8],
        ));
        out.push(data_record(
            t + 1,
            2,
            0x18FE_F100 + k as u32,
            true,
            &[byte; 3],
        ));
        if k % 5 == 0 {
            out.push(gps_record(t + 2, 12.5 + k as f64));
            out.push(vlsd_record(
                &b"a variable-length value"[..(k as usize % 20)],
            ));
        }
        if k % 7 == 0 {
            out.push(remote_record(t + 3, 1, 0x0123_4567, (k % 9) as u8));
        }
        if k % 11 == 0 {
            out.push(data_record(t + 4, 1, 0x7FF, false, &[]));
        }
    }
    out
}

/// The whole file: `records`' bytes split into `##DT` blocks at `cuts`.
fn unsorted_mf4(records: &[Written], cuts: &[usize]) -> Vec<u8> {
    let mut f = Mf4::new();
    // The `##HD` at 64, its data-group link patched at the end.
    let hd = f.block(*b"##HD", &[0; 6], &{
        let mut d = START_NS.to_le_bytes().to_vec();
        d.resize(32, 0);
        d
    });
    assert_eq!(hd, 64);
    let cc = {
        let mut d = vec![1u8, 0, 0, 0, 0, 0, 2, 0];
        d.extend_from_slice(&0f64.to_le_bytes());
        d.extend_from_slice(&0f64.to_le_bytes());
        d.extend_from_slice(&0f64.to_le_bytes());
        d.extend_from_slice(&TICK_S.to_le_bytes());
        f.block(*b"##CC", &[0, 0, 0, 0], &d)
    };
    // (type, sync, data type, bit offset, byte offset, bits); data types:
    // 0 unsigned LE, 4 float LE, 10 byte array.
    let data_parts = f.chain(&[
        ("CAN_DataFrame.BusChannel", 0, (0, 0, 0, 0, 8, 8)),
        ("CAN_DataFrame.ID", 0, (0, 0, 0, 0, 9, 32)),
        ("CAN_DataFrame.IDE", 0, (0, 0, 0, 0, 13, 1)),
        ("CAN_DataFrame.DLC", 0, (0, 0, 0, 1, 13, 4)),
        ("CAN_DataFrame.DataLength", 0, (0, 0, 0, 0, 14, 8)),
        ("CAN_DataFrame.DataBytes", 0, (0, 0, 10, 0, 15, 64)),
    ]);
    let data_struct = f.channel(0, data_parts, "CAN_DataFrame", 0, (0, 0, 10, 0, 8, 15 * 8));
    let data_time = f.channel(data_struct, 0, "t", cc, (2, 1, 0, 0, 0, 64));
    let remote_parts = f.chain(&[
        ("CAN_RemoteFrame.BusChannel", 0, (0, 0, 0, 0, 8, 8)),
        ("CAN_RemoteFrame.ID", 0, (0, 0, 0, 0, 9, 32)),
        ("CAN_RemoteFrame.DLC", 0, (0, 0, 0, 0, 13, 4)),
    ]);
    let remote_struct = f.channel(
        0,
        remote_parts,
        "CAN_RemoteFrame",
        0,
        (0, 0, 10, 0, 8, 6 * 8),
    );
    let remote_time = f.channel(remote_struct, 0, "t", cc, (2, 1, 0, 0, 0, 64));
    let gps = f.chain(&[
        ("t", 0, (2, 1, 4, 0, 0, 64)),
        ("GPS.Speed", 0, (0, 0, 4, 0, 8, 64)),
    ]);
    let vlsd = f.group(0, 0, 4, 0, 1);
    let gps = f.group(vlsd, gps, 3, 16, 0);
    let remote = f.group(gps, remote_time, 2, 14, 0);
    let data = f.group(remote, data_time, 1, 23, 0);
    // The records, cut into ##DT blocks, listed by two ##DL under a ##HL.
    let all: Vec<u8> = records.iter().flat_map(|r| r.bytes.clone()).collect();
    let mut bounds = vec![0];
    bounds.extend(cuts.iter().copied().filter(|&c| c > 0 && c < all.len()));
    bounds.push(all.len());
    let dts: Vec<u64> = bounds
        .windows(2)
        .map(|w| f.block(*b"##DT", &[], &all[w[0]..w[1]]))
        .collect();
    let half = dts.len() / 2;
    // A list's data: flags, count, and each block's offset in the records.
    let list = |f: &mut Mf4, next: u64, blocks: &[u64], offsets: &[usize]| {
        let mut links = vec![next];
        links.extend_from_slice(blocks);
        let mut d = vec![0u8; 4];
        d.extend_from_slice(&(blocks.len() as u32).to_le_bytes());
        for &o in offsets {
            d.extend_from_slice(&(o as u64).to_le_bytes());
        }
        f.block(*b"##DL", &links, &d)
    };
    let starts = &bounds[..bounds.len() - 1];
    let second = list(&mut f, 0, &dts[half..], &starts[half..]);
    let first = list(&mut f, second, &dts[..half], &starts[..half]);
    let hl = f.block(*b"##HL", &[first], &[0; 8]);
    let dg = f.block(*b"##DG", &[0, data, hl, 0], &[1, 0, 0, 0, 0, 0, 0, 0]);
    f.bytes[64 + 24..64 + 32].copy_from_slice(&dg.to_le_bytes());
    f.bytes
}

fn written(bytes: &[u8]) -> tempfile::NamedTempFile {
    let mut file = tempfile::NamedTempFile::new().unwrap();
    file.write_all(bytes).unwrap();
    file.flush().unwrap();
    file
}

#[test]
fn an_unsorted_mf4_reads_every_can_record_in_its_order_skipping_the_others() {
    let records = records();
    let expected: Vec<_> = records.iter().filter_map(|r| r.frame.clone()).collect();
    let total: usize = records.iter().map(|r| r.bytes.len()).sum();
    // One block; blocks cut inside records (a record id, a time, a payload).
    for cuts in [
        vec![],
        vec![1, 2, 3, 700, 701, 1500],
        vec![total / 3, total / 2 + 5],
    ] {
        let bytes = unsorted_mf4(&records, &cuts);
        let file = written(&bytes);
        let (reader, format, _) =
            AnyLogReader::open_file(std::fs::File::open(file.path()).unwrap()).unwrap();
        assert_eq!(format, LogFormat::Mf4);
        let got = common::records(reader).unwrap();
        assert_eq!(got.len(), expected.len(), "cuts {cuts:?}");
        assert_eq!(got, expected, "cuts {cuts:?}");
        // The same through a stream (a temporary copy).
        let (reader, _, _) = AnyLogReader::open(std::io::Cursor::new(bytes)).unwrap();
        assert_eq!(common::records(reader).unwrap(), expected);
    }
    assert!(expected.iter().any(|(_, _, t)| t.contains("#R")));
    assert!(expected.iter().any(|(_, c, _)| c == "2"));
}

#[test]
fn an_unknown_record_id_or_a_record_cut_short_is_an_error_naming_the_block() {
    let mut records = records();
    records.insert(
        10,
        Written {
            bytes: vec![9, 0, 0, 0],
            frame: None,
        },
    );
    let bytes = unsorted_mf4(&records, &[]);
    let (reader, _, _) = AnyLogReader::open(std::io::Cursor::new(bytes)).unwrap();
    let e = common::records(reader).unwrap_err().to_string();
    assert!(
        e.contains("##DT at byte offset") && e.contains("a record of id 9"),
        "{e}"
    );

    let mut records = self::records();
    let last = records.len() - 1;
    let cut = records[last].bytes.len() - 3;
    records[last].bytes.truncate(cut);
    let bytes = unsorted_mf4(&records, &[]);
    let (reader, _, _) = AnyLogReader::open(std::io::Cursor::new(bytes)).unwrap();
    let e = common::records(reader).unwrap_err().to_string();
    assert!(e.contains("the data ends inside a record"), "{e}");
}
