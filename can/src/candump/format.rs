//! Writing `candump -L` text in candump's canonical spelling, so that the
//! lines the parser reads back are the same text.

use super::{Direction, Record};
use crate::frame::{CAN_ERR_FLAG, CanFrame, FrameId, FrameKind};
use std::fmt;

const UPPER_HEX: &[u8; 16] = b"0123456789ABCDEF";

#[inline]
fn push_hex_fixed(out: &mut Vec<u8>, value: u32, digits: u32) {
    for shift in (0..digits).rev() {
        out.push(UPPER_HEX[((value >> (shift * 4)) & 0xF) as usize]);
    }
}

#[inline]
fn push_decimal_padded(out: &mut Vec<u8>, mut value: u64, width: usize) {
    let mut buf = [b'0'; 20];
    let mut i = buf.len();
    while value > 0 {
        i -= 1;
        buf[i] = b'0' + (value % 10) as u8;
        value /= 10;
    }
    let start = i.min(buf.len() - width);
    out.extend_from_slice(&buf[start..]);
}

/// Appends the candump spelling of `frame` (`123#DEADBEEF`, `123##1AB`, …).
pub fn format_frame(out: &mut Vec<u8>, frame: &CanFrame) {
    let raw_dlc = |out: &mut Vec<u8>, len8: Option<u8>| {
        if let Some(dlc) = len8 {
            out.push(b'_');
            out.push(UPPER_HEX[usize::from(dlc & 0xF)]);
        }
    };
    match frame.kind() {
        FrameKind::Error => push_hex_fixed(out, frame.id().raw() | CAN_ERR_FLAG, 8),
        _ => match frame.id() {
            FrameId::Standard(id) => push_hex_fixed(out, u32::from(id), 3),
            FrameId::Extended(id) => push_hex_fixed(out, id, 8),
        },
    }
    out.push(b'#');
    match frame.kind() {
        FrameKind::Remote { len8_dlc } => {
            out.push(b'R');
            if !frame.is_empty() {
                out.push(UPPER_HEX[frame.len()]);
            }
            raw_dlc(out, len8_dlc);
            return;
        }
        FrameKind::Fd { flags } => {
            out.push(b'#');
            out.push(UPPER_HEX[usize::from(flags & 0xF)]);
        }
        FrameKind::Data { .. } | FrameKind::Error => {}
    }
    for &b in frame.data() {
        out.push(UPPER_HEX[usize::from(b >> 4)]);
        out.push(UPPER_HEX[usize::from(b & 0xF)]);
    }
    if let FrameKind::Data { len8_dlc } = frame.kind() {
        raw_dlc(out, len8_dlc);
    }
}

/// Appends one full log line, newline included, as `candump -L` writes it.
pub fn format_record(out: &mut Vec<u8>, record: &Record<'_>) {
    out.push(b'(');
    push_decimal_padded(out, record.timestamp.secs(), 10);
    out.push(b'.');
    push_decimal_padded(out, u64::from(record.timestamp.subsec_micros()), 6);
    out.extend_from_slice(b") ");
    out.extend_from_slice(record.iface.as_bytes());
    out.push(b' ');
    format_frame(out, &record.frame);
    match record.direction {
        None => {}
        Some(Direction::Rx) => out.extend_from_slice(b" R"),
        Some(Direction::Tx) => out.extend_from_slice(b" T"),
    }
    out.push(b'\n');
}

impl fmt::Display for Record<'_> {
    /// The log line without its newline.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut buf = Vec::with_capacity(64);
        format_record(&mut buf, self);
        buf.pop();
        f.write_str(&String::from_utf8_lossy(&buf))
    }
}
