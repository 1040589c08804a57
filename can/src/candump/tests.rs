//! Tests of the `candump -L` reader, parser and formatter (`super`), with
//! socketcan's `dump` module as an independent oracle of the format.

use super::parse::{INVALID, eight_digits, eight_hex_digits, hex, parse_common};
use super::reader::trim_end;
use super::*;
use crate::frame::{
    CAN_ERR_FLAG, ErrorSeverity, FrameKind, MAX_EXTENDED_ID, MAX_STANDARD_ID, err_class, is_fd_len,
};
use proptest::prelude::*;
use std::io::Read;

fn parse(s: &str) -> Result<Record<'_>, Reason> {
    parse_line(s.as_bytes())
}

/// Every record `reader` returns, through the fast and general paths
/// as replay alternates them, as `(iface, id)`.
fn read_all(mut reader: LogReader<&[u8]>) -> (Vec<(String, u32)>, LogReader<&[u8]>) {
    let mut out = Vec::new();
    loop {
        if let Some(c) = reader.next_classic() {
            out.push((reader.iface.clone(), c.id.raw()));
            continue;
        }
        match reader.next_record_general() {
            Ok(Some(r)) => out.push((r.iface.to_owned(), r.frame.id().raw())),
            Ok(None) => return (out, reader),
            Err(ReadError::Malformed(_)) => {}
            Err(e @ (ReadError::Io(_) | ReadError::Corrupt(_))) => panic!("{e}"),
        }
    }
}

const TWO_BUSES: &str = "(1.000001) can0 100#11\n(1.000002) can1 200#22\n\
    (1.000003) can0 101##1AA\n(1.000004) can1 201##1BB\ngarbage words here\n\
    (1.000005) can0 102#33\n(1.000006) can1 202#R\n";

#[test]
fn the_interfaces_of_a_log_are_listed_in_order() {
    let (records, reader) = read_all(LogReader::new(TWO_BUSES.as_bytes()));
    assert_eq!(records.len(), 6);
    assert_eq!(reader.interfaces(), ["can0", "can1"]);
    assert_eq!(reader.other_interface_lines(), 0);
}

#[test]
fn an_interface_filter_keeps_one_bus_on_both_paths() {
    let (records, reader) = read_all(LogReader::new(TWO_BUSES.as_bytes()).only_interface("can1"));
    assert_eq!(
        records,
        [
            ("can1".to_owned(), 0x200),
            ("can1".to_owned(), 0x201),
            ("can1".to_owned(), 0x202)
        ]
    );
    assert_eq!(reader.other_interface_lines(), 3);
    assert_eq!(reader.interfaces(), ["can0", "can1"]);
    let (none, reader) = read_all(LogReader::new(TWO_BUSES.as_bytes()).only_interface("can9"));
    assert!(none.is_empty());
    assert_eq!(reader.other_interface_lines(), 6);
}

fn roundtrip(s: &str) {
    let rec = parse(s).unwrap_or_else(|r| panic!("{s}: {r}"));
    let mut out = Vec::new();
    format_record(&mut out, &rec);
    assert_eq!(String::from_utf8(out).unwrap(), format!("{s}\n"));
}

#[test]
fn classical_data_frame() {
    let r = parse("(1700000000.123456) vcan0 123#DEADBEEF").unwrap();
    assert_eq!(r.timestamp.secs(), 1_700_000_000);
    assert_eq!(r.timestamp.subsec_micros(), 123_456);
    assert_eq!(r.iface, "vcan0");
    assert_eq!(r.frame.id(), FrameId::Standard(0x123));
    assert_eq!(r.frame.data(), &[0xDE, 0xAD, 0xBE, 0xEF]);
    assert_eq!(r.frame.kind(), FrameKind::Data { len8_dlc: None });
    assert_eq!(r.direction, None);
}

#[test]
fn id_width_decides_format() {
    let ext = parse("(0000000001.000000) can0 00000123#01").unwrap();
    assert_eq!(ext.frame.id(), FrameId::Extended(0x123));
    let max = parse("(0000000001.000000) can0 1FFFFFFF#").unwrap();
    assert_eq!(max.frame.id(), FrameId::Extended(0x1FFF_FFFF));
    assert!(max.frame.is_empty());
    assert_eq!(parse("(1.000000) can0 800#01"), Err(Reason::IdOutOfRange));
    assert_eq!(
        parse("(1.000000) can0 40000000#01"),
        Err(Reason::IdOutOfRange)
    );
    assert_eq!(parse("(1.000000) can0 12#01"), Err(Reason::BadId));
    assert_eq!(parse("(1.000000) can0 1234#01"), Err(Reason::BadId));
    assert_eq!(parse("(1.000000) can0 123456789#01"), Err(Reason::BadId));
    assert_eq!(parse("(1.000000) can0 12G#01"), Err(Reason::BadId));
}

#[test]
fn fd_frames() {
    let r = parse("(1.000000) can0 123##5DEADBEEF").unwrap();
    assert_eq!(r.frame.kind(), FrameKind::Fd { flags: 5 });
    assert_eq!(r.frame.data(), &[0xDE, 0xAD, 0xBE, 0xEF]);
    let long = format!("(1.000000) can0 1ABCDEF0##1{}", "A5".repeat(64));
    assert_eq!(parse(&long).unwrap().frame.len(), 64);
    let too_long = format!("(1.000000) can0 123##1{}", "A5".repeat(65));
    assert_eq!(parse(&too_long), Err(Reason::TooLong));
    let odd_len = format!("(1.000000) can0 123##1{}", "A5".repeat(9));
    assert_eq!(parse(&odd_len), Err(Reason::BadFdLength));
    assert_eq!(parse("(1.000000) can0 123##"), Err(Reason::BadFdFlags));
    assert_eq!(parse("(1.000000) can0 123##X00"), Err(Reason::BadFdFlags));
    // An empty FD frame with flags only is valid.
    assert_eq!(parse("(1.000000) can0 123##4").unwrap().frame.len(), 0);
}

#[test]
fn remote_frames() {
    let r = parse("(1.000000) can0 123#R").unwrap();
    assert_eq!(r.frame.kind(), FrameKind::Remote { len8_dlc: None });
    assert_eq!(r.frame.len(), 0);
    let r4 = parse("(1.000000) can0 123#R4").unwrap();
    assert_eq!(r4.frame.len(), 4);
    assert!(r4.frame.data().is_empty());
    assert_eq!(parse("(1.000000) can0 123#r2").unwrap().frame.len(), 2);
    assert_eq!(
        parse("(1.000000) can0 123#R9"),
        Err(Reason::BadRemoteLength)
    );
    let r8e = parse("(1.000000) can0 123#R8_E").unwrap();
    assert_eq!(r8e.frame.kind(), FrameKind::Remote { len8_dlc: Some(14) });
    assert_eq!(parse("(1.000000) can0 123#R4_E"), Err(Reason::BadLen8Dlc));
    assert_eq!(
        parse("(1.000000) can0 123#R4X"),
        Err(Reason::TrailingGarbage)
    );
}

#[test]
fn raw_dlc_suffix() {
    let r = parse("(1.000000) can0 123#1122334455667788_F").unwrap();
    assert_eq!(r.frame.kind(), FrameKind::Data { len8_dlc: Some(15) });
    assert_eq!(
        parse("(1.000000) can0 123#11223344556677_9"),
        Err(Reason::BadLen8Dlc)
    );
    assert_eq!(
        parse("(1.000000) can0 123#1122334455667788_8"),
        Err(Reason::BadLen8Dlc)
    );
    assert_eq!(
        parse("(1.000000) can0 123#1122334455667788_"),
        Err(Reason::BadLen8Dlc)
    );
}

#[test]
fn error_frames_are_recognised_and_classified() {
    let r = parse("(1.000000) can0 20000044#0020000000008000").unwrap();
    let err = r.frame.as_error().unwrap();
    assert_eq!(err.class, err_class::BUS_OFF | err_class::CONTROLLER);
    assert_eq!(err.severity(), ErrorSeverity::BusOff);
    let passive = parse("(1.000000) can0 20000204#0010000000000080").unwrap();
    let e = passive.frame.as_error().unwrap();
    assert_eq!(e.severity(), ErrorSeverity::ErrorPassive);
    assert_eq!(e.error_counters(), Some((0, 0x80)));
    assert_eq!(
        parse("(1.000000) can0 20000004#00"),
        Err(Reason::BadErrorFrame)
    );
    assert_eq!(
        parse("(1.000000) can0 20000004#R"),
        Err(Reason::BadErrorFrame)
    );
    assert_eq!(
        parse("(1.000000) can0 20000004##100"),
        Err(Reason::BadErrorFrame)
    );
    assert_eq!(
        parse("(1.000000) can0 20000004#0000000000000000_9"),
        Err(Reason::BadErrorFrame)
    );
    assert_eq!(
        parse("(1.000000) can0 60000004#0000000000000000"),
        Err(Reason::IdOutOfRange)
    );
}

#[test]
fn timestamps() {
    assert_eq!(parse("1.000000 can0 123#"), Err(Reason::BadTimestamp));
    assert_eq!(parse("(1.00000) can0 123#"), Err(Reason::BadTimestamp));
    assert_eq!(parse("(1.0000000) can0 123#"), Err(Reason::BadTimestamp));
    assert_eq!(parse("(.000000) can0 123#"), Err(Reason::BadTimestamp));
    assert_eq!(parse("(1.000000 can0 123#"), Err(Reason::BadTimestamp));
    assert_eq!(parse("(1.000000)can0 123#"), Err(Reason::BadTimestamp));
    assert_eq!(
        parse("(99999999999999999999.000000) can0 123#"),
        Err(Reason::BadTimestamp)
    );
    assert_eq!(
        parse("(18446744073709.551616) c 123#"),
        Err(Reason::BadTimestamp)
    );
    let t = parse("(18446744073708.551615) c 123#").unwrap().timestamp;
    assert_eq!(t.as_micros(), 18_446_744_073_708_551_615);
    let t = parse("(1700000000.000001) c 123#").unwrap().timestamp;
    assert_eq!(t.as_micros(), 1_700_000_000_000_001);
    assert_eq!(t.as_secs_f64(), 1_700_000_000.000_001);
    assert_eq!(t.to_string(), "1700000000.000001");
}

#[test]
fn interface_and_trailer() {
    assert_eq!(parse("(1.000000)  123#"), Err(Reason::BadInterface));
    assert_eq!(parse("(1.000000) can0"), Err(Reason::BadInterface));
    assert_eq!(parse("(1.000000) can\t0 123#"), Err(Reason::BadInterface));
    let long = format!("(1.000000) {} 123#", "x".repeat(65));
    assert_eq!(parse(&long), Err(Reason::BadInterface));
    assert_eq!(
        parse("(1.000000) can0 123#01 R").unwrap().direction,
        Some(Direction::Rx)
    );
    assert_eq!(
        parse("(1.000000) can0 123#01 T").unwrap().direction,
        Some(Direction::Tx)
    );
    assert_eq!(
        parse("(1.000000) can0 123#01 X"),
        Err(Reason::TrailingGarbage)
    );
    assert_eq!(
        parse("(1.000000) can0 123#01 R extra"),
        Err(Reason::TrailingGarbage)
    );
    assert_eq!(
        parse("(1.000000) can0 123#01  R"),
        Err(Reason::TrailingGarbage)
    );
}

#[test]
fn payload_errors() {
    assert_eq!(parse("(1.000000) can0 123#0"), Err(Reason::BadHex));
    assert_eq!(parse("(1.000000) can0 123#0G"), Err(Reason::BadHex));
    assert_eq!(
        parse("(1.000000) can0 123#001122334455667788"),
        Err(Reason::TooLong)
    );
    // canplayer's optional dots and lower case are accepted.
    let r = parse("(1.000000) can0 123#de.ad.be.ef").unwrap();
    assert_eq!(r.frame.data(), &[0xDE, 0xAD, 0xBE, 0xEF]);
}

#[test]
fn canonical_lines_round_trip_to_identical_text() {
    for line in [
        "(1700000000.123456) vcan0 123#DEADBEEF",
        "(1700000000.000000) vcan0 123#",
        "(0000000001.000001) can1 00000123#0102030405060708",
        "(1700000000.123456) vcan0 123#1122334455667788_E",
        "(1700000000.123456) vcan0 123#R",
        "(1700000000.123456) vcan0 1FFFFFFF#R8_9",
        "(1700000000.123456) vcan0 123#R4",
        "(1700000000.123456) vcan0 123##5DEADBEEF",
        "(1700000000.123456) vcan0 123##0",
        "(1700000000.123456) vcan0 20000004#000C000000000000",
        "(1700000000.123456) vcan0 7FF#00 T",
        "(12345678901.999999) a-very.long_name 7FF#00 R",
    ] {
        roundtrip(line);
    }
}

#[test]
fn reader_reports_line_numbers_and_recovers() {
    let long = "x".repeat(MAX_LINE_BYTES + 100);
    let log = format!(
        "(1.000000) can0 123#01\n\ngarbage\r\n(2.000000) can0 124#02\r\n{long}\n(3.000000) can0 125#03"
    );
    let mut r = LogReader::new(log.as_bytes());
    let first = r.next_record().unwrap().unwrap();
    assert_eq!(first.frame.id(), FrameId::Standard(0x123));
    match r.next_record() {
        Err(ReadError::Malformed(m)) => {
            assert_eq!(
                m,
                Malformed {
                    line_no: 3,
                    reason: Reason::BadTimestamp
                }
            );
            assert_eq!(
                m.to_string(),
                "line 3: malformed candump record (bad_timestamp)"
            );
        }
        other => panic!("{other:?}"),
    }
    let second = r.next_record().unwrap().unwrap();
    assert_eq!(second.timestamp.secs(), 2);
    assert_eq!(second.frame.data(), &[2]);
    match r.next_record() {
        Err(ReadError::Malformed(m)) => {
            assert_eq!(
                m,
                Malformed {
                    line_no: 5,
                    reason: Reason::LineTooLong
                }
            );
        }
        other => panic!("{other:?}"),
    }
    let third = r.next_record().unwrap().unwrap();
    assert_eq!(third.frame.id(), FrameId::Standard(0x125));
    assert_eq!(r.line_no(), 6);
    assert!(r.next_record().unwrap().is_none());
    assert!(r.next_record().unwrap().is_none());
}

#[test]
fn malformed_lines_are_counted_by_reason() {
    let log = "(1.000000) can0 123#01\nnot a record\n(1.000000) can0 800#00\n\
               (2.000000) can0 124#0G\n(3.000000) can0 125#\njunk\n";
    let mut r = LogReader::new(log.as_bytes());
    let (mut counts, mut frames) = (MalformedCounts::default(), 0);
    loop {
        match r.next_record() {
            Ok(Some(_)) => frames += 1,
            Ok(None) => break,
            Err(ReadError::Malformed(m)) => counts.add(m.reason),
            Err(e @ (ReadError::Io(_) | ReadError::Corrupt(_))) => panic!("{e}"),
        }
    }
    assert_eq!(frames, 2);
    assert_eq!(counts.total(), 4);
    assert_eq!(counts.get(Reason::BadTimestamp), 2);
    assert_eq!(
        counts.nonzero().collect::<Vec<_>>(),
        [
            (Reason::BadTimestamp, 2),
            (Reason::IdOutOfRange, 1),
            (Reason::BadHex, 1)
        ]
    );
    // Every reason has its own slot and a distinct statistics name.
    let names: std::collections::HashSet<_> = Reason::ALL.iter().map(|r| r.as_str()).collect();
    assert_eq!(names.len(), Reason::ALL.len());
    let mut all = MalformedCounts::default();
    for r in Reason::ALL {
        all.add(r);
    }
    assert!(Reason::ALL.iter().all(|&r| all.get(r) == 1));
}

#[test]
fn reader_surfaces_io_errors() {
    struct Failing;
    impl Read for Failing {
        fn read(&mut self, _: &mut [u8]) -> io::Result<usize> {
            Err(io::Error::other("disk on fire"))
        }
    }
    let mut r = LogReader::new(io::BufReader::new(Failing));
    assert!(matches!(r.next_record(), Err(ReadError::Io(_))));
}

fn r_line(rec: &Record<'_>) -> String {
    rec.to_string()
}

/// Hands out at most `chunk` bytes per read, as a pipe or socket may.
struct Trickle<'a> {
    data: &'a [u8],
    chunk: usize,
}

impl Read for Trickle<'_> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let n = buf.len().min(self.chunk).min(self.data.len());
        buf[..n].copy_from_slice(&self.data[..n]);
        self.data = &self.data[n..];
        Ok(n)
    }
}

#[test]
fn eight_digits_reads_digits_and_refuses_the_rest() {
    assert_eq!(eight_digits(*b"01234567"), Some(1_234_567));
    assert_eq!(eight_digits(*b"99999999"), Some(99_999_999));
    assert_eq!(eight_digits(*b"00000000"), Some(0));
    // Each byte next to the digit range, in each position.
    for i in 0..8 {
        for bad in [b'/', b':', b'0' + 0x80, b' ', 0, 0xFF, b'?'] {
            let mut chunk = *b"12345678";
            chunk[i] = bad;
            assert_eq!(eight_digits(chunk), None, "{chunk:?}");
        }
    }
}

#[test]
fn eight_hex_digits_refuses_every_other_byte_in_every_position() {
    for i in 0..8 {
        for b in 0..=u8::MAX {
            let mut chunk = *b"09afAF5c";
            chunk[i] = b;
            let expected = chunk.iter().try_fold(0u32, |n, &b| {
                (hex(b) != INVALID).then(|| n << 4 | u32::from(hex(b)))
            });
            assert_eq!(eight_hex_digits(chunk), expected, "{chunk:?}");
        }
    }
    assert_eq!(eight_hex_digits(*b"DEADbeef"), Some(0xDEAD_BEEF));
}

#[test]
fn common_lines_take_the_fast_path_and_others_do_not() {
    let fast = |s: &str| {
        parse_common(format!("{s}\n").as_bytes(), b"")
            .map(|c| (c.classic.timestamp, c.classic.frame()))
    };
    let r = parse("(1700000000.123456) vcan0 123#DEADBEEF").unwrap();
    assert_eq!(
        fast("(1700000000.123456) vcan0 123#DEADBEEF"),
        Some((r.timestamp, r.frame))
    );
    assert!(fast("(1.000000) can0 1FFFFFFF#").is_some());
    for other in [
        "(1.000000) can0 123#DE.AD",
        "(1.000000) can0 123#R",
        "(1.000000) can0 123##1DEADBEEF",
        "(1.000000) can0 123#01 R",
        "(1.000000) can0 123#1122334455667788_E",
        "(1.000000) can0 20000004#000C000000000000",
        "(1700000000123.000000) can0 123#",
        "(1.000000) can0 800#01",
        "(1.000000) can0 123#0",
        "(1.000000) can0 123#0G",
        "(1.000000) can0 123#00 ",
    ] {
        assert_eq!(fast(other), None, "{other}");
    }
    // A line not whole in the text is left to the general reader.
    assert!(parse_common(b"(1.000000) can0 123#00", b"").is_none());
    assert!(parse_common(b"(1.000000) can0 123#00\r", b"").is_none());
}

fn arb_id() -> impl Strategy<Value = FrameId> {
    prop_oneof![
        (0..=MAX_STANDARD_ID).prop_map(|v| FrameId::Standard(v as u16)),
        (0..=MAX_EXTENDED_ID).prop_map(FrameId::Extended),
    ]
}

prop_compose! {
    fn arb_frame()(
        id in arb_id(),
        sel in 0..4u8,
        bytes in proptest::collection::vec(any::<u8>(), 0..=64),
        flags in 0..16u8,
        rtr_len in 0..=8usize,
        len8 in proptest::option::of(9..=15u8),
        class in 0..=MAX_EXTENDED_ID,
    ) -> CanFrame {
        match sel {
            0 => {
                let b = &bytes[..bytes.len().min(8)];
                let len8 = if b.len() == 8 { len8 } else { None };
                CanFrame::new_data_with_dlc(id, b, len8).unwrap()
            }
            1 => {
                let len8 = if rtr_len == 8 { len8 } else { None };
                CanFrame::new_remote(id, rtr_len, len8).unwrap()
            }
            2 => {
                let mut n = bytes.len();
                while !is_fd_len(n) { n -= 1; }
                CanFrame::new_fd(id, flags, &bytes[..n]).unwrap()
            }
            _ => {
                let mut d = [0; 8];
                for (dst, src) in d.iter_mut().zip(&bytes) { *dst = *src; }
                CanFrame::new_error(class, d).unwrap()
            }
        }
    }
}

proptest! {
    #[test]
    fn format_then_parse_is_identity(
        micros in 0u64..=99_999_999_999_999_999,
        iface in "[a-zA-Z0-9_.:-]{1,16}",
        frame in arb_frame(),
        dir in proptest::option::of(prop_oneof![Just(Direction::Rx), Just(Direction::Tx)]),
    ) {
        let rec = Record { timestamp: Timestamp::from_micros(micros), iface: &iface, frame, direction: dir };
        let mut out = Vec::new();
        format_record(&mut out, &rec);
        let text = std::str::from_utf8(&out).unwrap();
        prop_assert!(text.ends_with('\n'));
        let parsed = parse_line(&out[..out.len() - 1]).map_err(|r| TestCaseError::fail(format!("{text}: {r}")))?;
        prop_assert_eq!(parsed, rec);
        prop_assert_eq!(format!("{parsed}\n"), text);
    }

    /// socketcan's `dump` reader (an independent implementation of the
    /// format) reads our output as we do, and writes the same text.
    /// Excluded: the `_` raw DLC, which it does not support, and FD
    /// frames without the FDF flag, which it always sets.
    #[test]
    fn socketcan_dump_agrees(
        // 10-digit seconds: candump zero-pads to 10, socketcan does not pad.
        micros in 1_000_000_000_000_000u64..=9_999_999_999_999_999,
        frame in arb_frame(),
        dir in proptest::option::of(prop_oneof![Just(Direction::Rx), Just(Direction::Tx)]),
    ) {
        use socketcan::{CanAnyFrame, EmbeddedFrame, Frame as _};
        let frame = match frame.kind() {
            FrameKind::Data { len8_dlc: Some(_) } => CanFrame::new_data(frame.id(), frame.data()).unwrap(),
            FrameKind::Remote { len8_dlc: Some(_) } => CanFrame::new_remote(frame.id(), frame.len(), None).unwrap(),
            FrameKind::Fd { flags } => CanFrame::new_fd(frame.id(), flags | 0x4, frame.data()).unwrap(),
            _ => frame,
        };
        let rec = Record { timestamp: Timestamp::from_micros(micros), iface: "can0", frame, direction: dir };
        let mut out = Vec::new();
        format_record(&mut out, &rec);
        let mut theirs = socketcan::dump::Reader::from_reader(&out[..]);
        let other = theirs.next_record().unwrap().unwrap();
        prop_assert_eq!(other.t_us, micros);
        prop_assert_eq!(&other.device, "can0");
        prop_assert_eq!(other.direction.is_some(), dir.is_some());
        let expected_id = frame.id().raw() | match frame.kind() {
            FrameKind::Error => CAN_ERR_FLAG,
            _ if frame.id().is_extended() => 0x8000_0000,
            _ => 0,
        };
        match (&other.frame, frame.kind()) {
            (CanAnyFrame::Normal(f), FrameKind::Data { .. }) => {
                prop_assert_eq!(f.data(), frame.data());
                prop_assert_eq!(f.id_word(), expected_id);
            }
            (CanAnyFrame::Remote(f), FrameKind::Remote { .. }) => {
                prop_assert_eq!(f.dlc(), frame.len());
                prop_assert_eq!(f.id_word() & !0x4000_0000, expected_id);
            }
            (CanAnyFrame::Fd(f), FrameKind::Fd { flags }) => {
                prop_assert_eq!(f.data(), frame.data());
                // Its `flags()` truncates to the named bits; the text keeps all four.
                prop_assert_eq!(f.flags().bits(), flags & 0x7);
                prop_assert_eq!(f.id_word(), expected_id);
            }
            (CanAnyFrame::Error(f), FrameKind::Error) => {
                prop_assert_eq!(f.data(), frame.data());
                prop_assert_eq!(f.id_word(), expected_id);
            }
            (theirs, ours) => prop_assert!(false, "kind mismatch: {:?} vs {:?}", theirs, ours),
        }
        prop_assert_eq!(format!("{other}\n"), String::from_utf8(out).unwrap());
    }

    /// Whatever the buffer size and however the input trickles in, the
    /// reader gives the records, errors and line numbers of an obvious
    /// reference: split at newlines, cut to size, trim, `parse_line`.
    #[test]
    fn reader_matches_the_obvious_reference(
        lines in proptest::collection::vec(prop_oneof![
            4 => (arb_frame(), 0u64..=99_999_999_999_999, "[a-z]{1,3}[0-9]?").prop_map(|(frame, t, iface)| {
                let mut out = Vec::new();
                format_record(&mut out, &Record { timestamp: Timestamp::from_micros(t), iface: &iface, frame, direction: None });
                out.pop();
                String::from_utf8(out).unwrap()
            }),
            1 => "[ -~]{0,80}",
            1 => Just(String::new()),
            1 => Just(" \t".to_string()),
            1 => (MAX_LINE_BYTES - 2..MAX_LINE_BYTES + 3).prop_map(|n| "x".repeat(n)),
        ], 0..40),
        crlf in any::<bool>(),
        final_newline in any::<bool>(),
        capacity in prop_oneof![Just(0usize), Just(MAX_LINE_BYTES + 7), Just(4096)],
        chunk in prop_oneof![Just(1usize), 2..300usize, Just(usize::MAX)],
    ) {
        let sep = if crlf { "\r\n" } else { "\n" };
        let mut log = lines.join(sep);
        if final_newline {
            log.push_str(sep);
        }
        let mut reference = Vec::new();
        let mut text = log.as_bytes();
        let mut line_no = 0;
        while !text.is_empty() {
            let (line, rest) = match text.iter().position(|&b| b == b'\n') {
                Some(i) => (&text[..i], &text[i + 1..]),
                None => (text, &text[text.len()..]),
            };
            text = rest;
            line_no += 1;
            if line.len() > MAX_LINE_BYTES {
                reference.push(Err(Malformed { line_no, reason: Reason::LineTooLong }));
                continue;
            }
            let line = trim_end(line);
            if !line.is_empty() {
                reference.push(parse_line(line).map(|r| (r.to_string(), r.frame)).map_err(|reason| Malformed { line_no, reason }));
            }
        }
        let mut r = LogReader::with_capacity(capacity, Trickle { data: log.as_bytes(), chunk });
        let mut got = Vec::new();
        loop {
            match r.next_record() {
                Ok(Some(rec)) => got.push(Ok((r_line(&rec), rec.frame))),
                Ok(None) => break,
                Err(ReadError::Malformed(m)) => got.push(Err(m)),
                Err(e @ (ReadError::Io(_) | ReadError::Corrupt(_))) => panic!("{e}"),
            }
        }
        prop_assert_eq!(got, reference);
        prop_assert_eq!(r.line_no(), line_no);
    }

    /// The fast path accepts only what the general parser accepts, as
    /// the same record, on valid lines of every kind and on mutations.
    #[test]
    fn fast_path_agrees_with_the_general_parser(
        micros in prop_oneof![
            0u64..=99_999_999_999_999_999,
            // 10 and 13 second digits: the usual and one beyond the fast path's 12.
            0u64..=9_999_999_999_999_999,
            1_000_000_000_000_000_000u64..=1_999_999_999_999_999_999,
        ],
        iface in "[a-zA-Z0-9_.:-]{1,16}",
        frame in arb_frame(),
        dir in proptest::option::of(prop_oneof![Just(Direction::Rx), Just(Direction::Tx)]),
        mutation in proptest::option::of((any::<prop::sample::Index>(), prop_oneof![any::<u8>(), Just(b' '), Just(b'#'), Just(b'0'), Just(b'F')])),
        known in prop_oneof![Just(String::new()), Just("can0".to_string()), "[a-z]{1,4}"],
        crlf in any::<bool>(),
    ) {
        let rec = Record { timestamp: Timestamp::from_micros(micros), iface: &iface, frame, direction: dir };
        let mut out = Vec::new();
        format_record(&mut out, &rec);
        out.pop();
        if let Some((pos, byte)) = mutation {
            let i = pos.index(out.len());
            out[i] = byte;
        }
        // A newline inside would end the line there, for both parsers.
        prop_assume!(!out.contains(&b'\n') && !out.contains(&b'\r'));
        let general = parse_line(&out);
        let mut text = out.clone();
        text.extend_from_slice(if crlf { b"\r\n(1" } else { b"\n(1" });
        if let Some(c) = parse_common(&text, known.as_bytes()) {
            let Ok(general) = general else {
                return Err(TestCaseError::fail(format!("fast path accepted {:?}", String::from_utf8_lossy(&out))));
            };
            prop_assert_eq!(general.timestamp, c.classic.timestamp);
            prop_assert_eq!(c.known_iface, general.iface == known);
            prop_assert_eq!(general.iface.as_bytes(), &out[c.iface]);
            prop_assert_eq!(general.frame, c.classic.frame());
            prop_assert_eq!(general.direction, None);
            prop_assert_eq!(c.consumed, text.len() - 2);
        } else if mutation.is_none() && dir.is_none() && micros < 1_000_000_000_000_000_000
            && matches!(frame.kind(), FrameKind::Data { len8_dlc: None })
        {
            // The common shape itself must take the fast path.
            prop_assert!(false, "fast path refused {:?}", String::from_utf8_lossy(&out));
        }
    }

    #[test]
    fn eight_digits_matches_a_digit_loop(chunk in prop_oneof![
        any::<[u8; 8]>(),
        "[0-9]{8}".prop_map(|s| <[u8; 8]>::try_from(s.as_bytes()).unwrap()),
        ("[0-9]{7}", any::<u8>(), 0..8usize).prop_map(|(s, b, i)| {
            let mut v = s.into_bytes();
            v.insert(i, b);
            <[u8; 8]>::try_from(&v[..]).unwrap()
        }),
    ]) {
        let expected = chunk.iter().try_fold(0u64, |n, &b| b.is_ascii_digit().then(|| n * 10 + u64::from(b - b'0')));
        prop_assert_eq!(eight_digits(chunk), expected);
    }

    #[test]
    fn eight_hex_digits_matches_a_digit_loop(chunk in prop_oneof![
        any::<[u8; 8]>(),
        "[0-9a-fA-F]{8}".prop_map(|s| <[u8; 8]>::try_from(s.as_bytes()).unwrap()),
        ("[0-9a-fA-F]{7}", any::<u8>(), 0..8usize).prop_map(|(s, b, i)| {
            let mut v = s.into_bytes();
            v.insert(i, b);
            <[u8; 8]>::try_from(&v[..]).unwrap()
        }),
    ]) {
        let expected = chunk.iter().try_fold(0u32, |n, &b| (hex(b) != INVALID).then(|| n << 4 | u32::from(hex(b))));
        prop_assert_eq!(eight_hex_digits(chunk), expected);
    }

    #[test]
    fn parser_never_panics_on_mutated_lines(
        frame in arb_frame(),
        pos in any::<prop::sample::Index>(),
        byte in any::<u8>(),
    ) {
        let rec = Record { timestamp: Timestamp::from_micros(1), iface: "can0", frame, direction: None };
        let mut out = Vec::new();
        format_record(&mut out, &rec);
        out.pop();
        let i = pos.index(out.len());
        out[i] = byte;
        // Either a valid record that formats back to a parseable line, or a reason.
        if let Ok(r) = parse_line(&out) {
            let mut again = Vec::new();
            format_record(&mut again, &r);
            again.pop();
            prop_assert_eq!(parse_line(&again), Ok(r));
        }
    }
}
