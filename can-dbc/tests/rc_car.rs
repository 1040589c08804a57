//! The project's own rc_car.dbc end to end: metadata, Motorola and Intel layouts,
//! counters and the CRC-8 SAE J1850 its comments specify.

use canodom_dbc::{
    ByteOrder, Checksum, ChecksumAlgorithm, CounterCheck, CounterStatus, Database, FrameId,
};

use crate::util::shared_dbc;

fn db() -> Database {
    Database::from_file(shared_dbc("rc_car.dbc")).unwrap()
}

#[test]
fn metadata_is_exposed() {
    let db = db();
    assert_eq!(db.messages().len(), 4);
    let m = db.message_by_id(FrameId::standard(288).unwrap()).unwrap();
    assert_eq!(m.name(), "VEHICLE_STATE");
    assert_eq!(m.length(), 4);
    assert_eq!(m.cycle_time_ms(), Some(100));
    assert_eq!(m.comment(), Some("Drive state, sent every 100 ms."));
    assert_eq!(m.transmitter(), Some("ECU"));
    let mode = m.signal("DRIVE_MODE").unwrap();
    assert_eq!(mode.value_name(2), Some("AUTO"));
    assert_eq!(mode.value_descriptions().len(), 4);
    let speed = m.signal("SPEED_CMD").unwrap();
    assert_eq!((speed.unit(), speed.min(), speed.max()), ("m/s", -5.0, 5.0));
    assert_eq!(speed.factor(), 0.001);
    let steer = db.message_by_name("STEERING").unwrap();
    assert_eq!(steer.cycle_time_ms(), Some(10));
    let crc = steer.signal("CHECKSUM").unwrap();
    assert!(crc.comment().unwrap().contains("over data bytes 0 to 6"));
    assert_eq!(crc.byte_order(), ByteOrder::BigEndian);
    assert!(
        db.message_by_id(FrameId::standard(0x7FF).unwrap())
            .is_none()
    );
    assert!(db.message_by_id(FrameId::extended(256).unwrap()).is_none());
}

#[test]
fn motorola_and_intel_frames_decode_and_encode() {
    let db = db();
    let front = db.message_by_name("WHEEL_ENC_FRONT").unwrap();
    // FL_TICKS 7|16@0+: big-endian bytes 0..2; COUNTER 51|4@0+: low nibble of byte 6.
    let frame = [0x12, 0x34, 0xAB, 0xCD, 0, 0, 0x05, 0x00];
    let got: Vec<(String, f64)> = front
        .decode(&frame)
        .unwrap()
        .map(|(s, v)| (s.name().to_owned(), v))
        .collect();
    assert_eq!(
        got,
        [
            ("FL_TICKS".to_owned(), 4660.0),
            ("FR_TICKS".to_owned(), 43981.0),
            ("COUNTER".to_owned(), 5.0),
            ("CHECKSUM".to_owned(), 0.0)
        ]
    );
    let built = front
        .encode(&[
            ("FL_TICKS", 4660.0),
            ("FR_TICKS", 43981.0),
            ("COUNTER", 5.0),
            ("CHECKSUM", 0.0),
        ])
        .unwrap();
    assert_eq!(built, frame);

    let steer = db.signal("STEERING.STEER_ANGLE").unwrap();
    let mut f = [0u8; 8];
    assert!(steer.encode(-12.34, &mut f));
    assert_eq!(&f[..2], &(-1234i16).to_be_bytes());
    assert_eq!(steer.decode(&f), Some(-1234.0 * 0.01));
}

#[test]
fn encoded_frames_pass_counter_and_crc_checks() {
    let db = db();
    let m = db.message_by_name("WHEEL_ENC_REAR").unwrap();
    let counter = db.signal("WHEEL_ENC_REAR.COUNTER").unwrap();
    let crc = Checksum::rc_car();
    let tx_counter = CounterCheck::new(counter.size()).unwrap();
    let mut rx = CounterCheck::new(counter.size()).unwrap();
    let mut c = 14;
    for k in 0..40u32 {
        let mut frame = m
            .encode(&[
                ("RL_TICKS", f64::from(k * 7)),
                ("RR_TICKS", f64::from(k * 9)),
                ("COUNTER", c as f64),
                ("CHECKSUM", 0.0),
            ])
            .unwrap();
        crc.apply(&mut frame).unwrap();
        assert!(crc.verify(&frame).unwrap());
        // The configurable CRC-8 with J1850's parameters agrees with the catalogue one.
        let generic = Checksum::new(
            ChecksumAlgorithm::Crc8 {
                poly: 0x1D,
                init: 0xFF,
                xor_out: 0xFF,
            },
            0..=6,
            7,
        )
        .unwrap();
        assert_eq!(generic.compute(&frame).unwrap(), frame[7]);
        let status = rx.observe(counter.raw(&frame).unwrap());
        assert_eq!(
            status,
            if k == 0 {
                CounterStatus::First
            } else {
                CounterStatus::InSequence
            }
        );
        // Every single-bit corruption of the covered bytes is caught.
        let mut bad = frame.clone();
        bad[(k % 7) as usize] ^= 1 << (k % 8);
        assert!(!crc.verify(&bad).unwrap());
        c = tx_counter.next_value(c);
    }
    assert_eq!(rx.gaps(), 0);
    // Drop two frames: one gap, with what was expected.
    let last = (c + 15) % 16;
    assert_eq!(
        rx.observe((last + 3) % 16),
        CounterStatus::Gap {
            expected: c,
            got: (last + 3) % 16
        }
    );
    assert_eq!(rx.gaps(), 1);
}

#[test]
fn extended_ids_are_distinct_from_standard() {
    let db = Database::from_file(shared_dbc("cantools_multiplex.dbc")).unwrap();
    let m = db.messages()[0].id();
    assert_eq!(m, FrameId::Extended(2_148_676_694 - 0x8000_0000));
    assert!(db.message_by_id(FrameId::Extended(m.raw())).is_some());
}

#[test]
fn every_shared_file_loads() {
    for f in crate::util::all_shared_dbcs() {
        let db = Database::from_file(shared_dbc(&f)).unwrap_or_else(|e| panic!("{e}"));
        assert!(!db.messages().is_empty(), "{f}");
    }
}

#[test]
fn toyota_wheel_speeds_handles() {
    let db = Database::from_file(shared_dbc("opendbc_toyota_2017.dbc")).unwrap();
    let m = db.message_by_id(FrameId::standard(0xAA).unwrap()).unwrap();
    assert_eq!(m.name(), "WHEEL_SPEEDS");
    let names = [
        "WHEEL_SPEED_FR",
        "WHEEL_SPEED_FL",
        "WHEEL_SPEED_RR",
        "WHEEL_SPEED_RL",
    ];
    let handles: Vec<_> = names
        .iter()
        .map(|n| db.signal(&format!("WHEEL_SPEEDS.{n}")).unwrap())
        .collect();
    let mut frame = [0u8; 8];
    for (k, h) in handles.iter().enumerate() {
        assert!(h.encode(10.0 * k as f64, &mut frame));
    }
    for (k, h) in handles.iter().enumerate() {
        let v = h.decode(&frame).unwrap();
        assert!(
            (v - 10.0 * k as f64).abs() <= 0.005 + 1e-9,
            "{} = {v}",
            names[k]
        );
    }
}

#[test]
fn multiplexed_signals_follow_the_multiplexor() {
    let db = Database::from_file(shared_dbc("cantools_multiplex.dbc")).unwrap();
    let m = db.message_by_name("Message1").unwrap();
    let names = |frame: &[u8]| -> Vec<String> {
        m.decode(frame)
            .unwrap()
            .map(|(s, _)| s.name().to_owned())
            .collect()
    };
    // Multiplexor is 2|6@1+: value 8 selects m8 signals, SG_MUL_VAL_ adds 16 and 24 to them.
    let frame = |mux: u8| [mux << 2, 0, 0, 0, 0, 0, 0, 0];
    assert_eq!(
        names(&frame(8)),
        ["BIT_L", "BIT_G", "BIT_C", "BIT_J", "Multiplexor"]
    );
    assert_eq!(
        names(&frame(16)),
        ["BIT_L", "BIT_G", "BIT_C", "BIT_J", "Multiplexor"]
    );
    assert_eq!(names(&frame(24)).len(), 12);
    assert_eq!(names(&frame(9)), ["Multiplexor"]);
    let bit_l = db.signal("Message1.BIT_L").unwrap();
    let bit_k = db.signal("Message1.BIT_K").unwrap();
    let mut f = frame(16);
    f[3] = 1; // BIT_L at bit 24
    assert_eq!(bit_l.decode(&f), Some(1.0));
    assert_eq!(bit_k.decode(&f), None);
    assert_eq!(bit_l.decode(&frame(9)), None);
    let k = m.signal("BIT_K").unwrap();
    assert!(!m.is_present(k, &f) && m.is_present(k, &frame(24)));
    // Encoding picks the multiplexed signals of the multiplexor value given.
    let built = m
        .encode(&[
            ("Multiplexor", 8.0),
            ("BIT_L", 1.0),
            ("BIT_G", 0.0),
            ("BIT_C", 1.0),
            ("BIT_J", 0.0),
        ])
        .unwrap();
    assert_eq!(built, [8 << 2, 0, 1 << 3, 1, 0, 0, 0, 0]);
}

/// Nested multiplexing (`m1M` plus SG_MUL_VAL_), checked against what cantools 45.1
/// decodes for the same two frames.
#[test]
fn nested_multiplexing_matches_cantools() {
    let text = r#"VERSION ""

BS_:

BU_: ECU

BO_ 300 NEST: 8 ECU
 SG_ TOP M : 0|4@1+ (1,0) [0|0] "" ECU
 SG_ SUB m1M : 4|4@1+ (1,0) [0|0] "" ECU
 SG_ LEAF m2 : 8|8@1+ (1,0) [0|0] "" ECU
 SG_ OTHER m2 : 16|8@1+ (1,0) [0|0] "" ECU

SG_MUL_VAL_ 300 SUB TOP 1-1;
SG_MUL_VAL_ 300 LEAF SUB 2-2;
SG_MUL_VAL_ 300 OTHER TOP 2-2;
"#;
    let db = Database::parse(text, "nest.dbc").unwrap();
    let m = db.message_by_name("NEST").unwrap();
    let decode = |frame: [u8; 8]| -> Vec<(String, f64)> {
        m.decode(&frame)
            .unwrap()
            .map(|(s, v)| (s.name().to_owned(), v))
            .collect()
    };
    // cantools: {'TOP': 1, 'SUB': 2, 'LEAF': 5} and {'TOP': 2, 'OTHER': 6}
    assert_eq!(
        decode([0x21, 5, 6, 0, 0, 0, 0, 0]),
        [
            ("TOP".to_owned(), 1.0),
            ("SUB".to_owned(), 2.0),
            ("LEAF".to_owned(), 5.0)
        ]
    );
    assert_eq!(
        decode([0x22, 5, 6, 0, 0, 0, 0, 0]),
        [("TOP".to_owned(), 2.0), ("OTHER".to_owned(), 6.0)]
    );
    // A handle cannot check two levels of multiplexors: refused, with the reason.
    let e = db.signal("NEST.LEAF").unwrap_err().to_string();
    assert!(e.contains("NEST.LEAF") && e.contains("nested"), "{e}");
    let sub = db.signal("NEST.SUB").unwrap();
    assert_eq!(sub.decode(&[0x21, 0, 0, 0, 0, 0, 0, 0]), Some(2.0));
    assert_eq!(sub.decode(&[0x22, 0, 0, 0, 0, 0, 0, 0]), None);
}

#[test]
fn ieee_float_and_double_signals_in_a_can_fd_frame() {
    let text = r#"VERSION ""

BS_:

BU_: ECU

BO_ 2147483906 FD_FLOATS: 64 ECU
 SG_ F32 : 0|32@1- (1,0) [0|0] "" ECU
 SG_ F64 : 39|64@0- (2,1) [0|0] "m" ECU
 SG_ TAIL : 504|8@1+ (1,0) [0|0] "" ECU

SIG_VALTYPE_ 2147483906 F32 : 1;
SIG_VALTYPE_ 2147483906 F64 : 2;
"#;
    let db = Database::parse(text, "floats.dbc").unwrap();
    let m = db.message_by_id(FrameId::extended(0x102).unwrap()).unwrap();
    assert_eq!(m.length(), 64);
    let frame = m
        .encode(&[("F32", -1.5), ("F64", 7.0), ("TAIL", 255.0)])
        .unwrap();
    assert_eq!(&frame[..4], &(-1.5f32).to_le_bytes());
    // Motorola double, MSB at bit 39 (byte 4): bytes 4..12 big-endian; raw = (7 - 1) / 2.
    assert_eq!(&frame[4..12], &3.0f64.to_be_bytes());
    assert_eq!(frame[63], 255);
    let got: Vec<f64> = m.decode(&frame).unwrap().map(|(_, v)| v).collect();
    assert_eq!(got, [-1.5, 7.0, 255.0]);
    let f32_handle = db.signal("FD_FLOATS.F32").unwrap();
    assert_eq!(f32_handle.decode(&frame), Some(-1.5));
    // 1e39 does not fit an f32: an error, not infinity.
    let e = m
        .encode(&[("F32", 1e39), ("F64", 0.0), ("TAIL", 0.0)])
        .unwrap_err();
    assert!(e.to_string().contains("signal F32"), "{e}");
}
