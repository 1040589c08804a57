//! Every error path, each checked to name its fault (file and line, message, signal).
//! A message that cannot be compiled is an error under `LoadMode::Strict`, and under the
//! default tolerant load a warning with the same reason (the rest of the file loads).

use canodom_dbc::{Database, Error, FrameId, LoadMode};

fn dbc(messages: &str) -> String {
    format!("VERSION \"\"\n\nBS_:\n\nBU_: ECU\n\n{messages}\n")
}

/// The strict load's error text, after checking that the tolerant load of the same text
/// succeeds with one warning giving the same reason.
fn load_err(messages: &str) -> String {
    let text = dbc(messages);
    let err = Database::parse_with(&text, "test.dbc", LoadMode::Strict).unwrap_err();
    let tolerant = Database::parse(&text, "test.dbc").unwrap();
    let [warning] = tolerant.warnings() else {
        panic!("one warning expected, got {:?}", tolerant.warnings());
    };
    let reason = match &err {
        Error::InvalidMessage { reason, .. } | Error::InvalidSignal { reason, .. } => reason,
        other => panic!("not a compile error: {other}"),
    };
    assert_eq!(warning.reason(), reason);
    assert!(
        warning.to_string().starts_with("test.dbc: message "),
        "{warning}"
    );
    err.to_string()
}

#[test]
fn syntax_error_names_file_line_and_column() {
    let text = dbc(
        "BO_ 256 MSG: 8 ECU\n SG_ A : 0|8@1+ (1,0) [0|255] \"\" ECU\n SG_ B 8|8@1+ (1,0) [0|255] \"\" ECU",
    );
    let err = Database::parse(&text, "broken.dbc").unwrap_err();
    let Error::Parse { line, column, .. } = &err else {
        panic!("expected a parse error, got {err}");
    };
    let msg = err.to_string();
    assert!(msg.starts_with("broken.dbc:"), "{msg}");
    assert!(line.is_some() && column.is_some(), "{msg}");
    // The fault is on the line of signal B: the error quotes it.
    assert!(msg.contains("SG_ B 8|8"), "{msg}");
}

#[test]
fn missing_file_names_the_path() {
    let err = Database::from_file("/nonexistent/car.dbc")
        .unwrap_err()
        .to_string();
    assert!(err.contains("/nonexistent/car.dbc"), "{err}");
}

#[test]
fn zero_size_signal_names_message_and_signal() {
    let e = load_err("BO_ 256 MSG: 8 ECU\n SG_ EMPTY : 0|0@1+ (1,0) [0|0] \"\" ECU");
    assert!(
        e.contains("message MSG, signal EMPTY") && e.contains("size 0"),
        "{e}"
    );
}

#[test]
fn oversized_signal_names_message_and_signal() {
    let e = load_err("BO_ 256 MSG: 16 ECU\n SG_ HUGE : 0|65@1+ (1,0) [0|0] \"\" ECU");
    assert!(
        e.contains("message MSG, signal HUGE") && e.contains("size 65"),
        "{e}"
    );
}

#[test]
fn signal_past_frame_end_names_message_and_signal() {
    let e = load_err("BO_ 256 MSG: 2 ECU\n SG_ FAR : 12|8@1+ (1,0) [0|0] \"\" ECU");
    assert!(
        e.contains("message MSG, signal FAR") && e.contains("only 2 bytes"),
        "{e}"
    );
    // Motorola: MSB at bit 7 of byte 1, 16 bits, needs byte 2.
    let e = load_err("BO_ 256 MSG: 2 ECU\n SG_ MOTO : 15|16@0+ (1,0) [0|0] \"\" ECU");
    assert!(
        e.contains("signal MOTO") && e.contains("needs 3 bytes"),
        "{e}"
    );
}

#[test]
fn float_of_wrong_size_names_signal() {
    let e = load_err(
        "BO_ 256 MSG: 8 ECU\n SG_ F : 0|16@1- (1,0) [0|0] \"\" ECU\n\nSIG_VALTYPE_ 256 F : 1;",
    );
    assert!(e.contains("signal F") && e.contains("needs 32"), "{e}");
}

#[test]
fn zero_factor_names_signal() {
    let e = load_err("BO_ 256 MSG: 8 ECU\n SG_ Z : 0|8@1+ (0,0) [0|0] \"\" ECU");
    assert!(
        e.contains("signal Z") && e.contains("cannot be inverted"),
        "{e}"
    );
}

#[test]
fn standard_id_above_11_bits_is_rejected_not_truncated() {
    let e = load_err("BO_ 2048 WIDE: 8 ECU");
    assert!(e.contains("message WIDE") && e.contains("0x800"), "{e}");
    // 70000 would be truncated to 70000 & 0xFFFF = 4464 by the parser alone.
    let e = load_err("BO_ 70000 TRUNC: 8 ECU");
    assert!(e.contains("message TRUNC") && e.contains("70000"), "{e}");
    // Still caught among other BO_-prefixed keywords and tab-separated definitions.
    let e = load_err(
        "BO_ 256 OK: 8 ECU

BO_	70001	TABS: 8 ECU

BO_TX_BU_ 256 : ECU;",
    );
    assert!(e.contains("message TABS") && e.contains("70001"), "{e}");
}

#[test]
fn too_long_message_is_rejected() {
    let e = load_err("BO_ 256 FD: 65 ECU");
    assert!(e.contains("message FD") && e.contains("65 bytes"), "{e}");
}

#[test]
fn duplicate_ids_and_names_are_rejected() {
    let e = load_err("BO_ 256 A: 8 ECU\n\nBO_ 256 B: 8 ECU");
    assert!(
        e.contains("message B") && e.contains("also used by A"),
        "{e}"
    );
    let e = load_err(
        "BO_ 256 A: 8 ECU\n SG_ S : 0|8@1+ (1,0) [0|0] \"\" ECU\n SG_ S : 8|8@1+ (1,0) [0|0] \"\" ECU",
    );
    assert!(
        e.contains("message A, signal S") && e.contains("twice"),
        "{e}"
    );
}

#[test]
fn multiplexed_signal_without_multiplexor_is_rejected() {
    let e = load_err("BO_ 256 MUX: 8 ECU\n SG_ ORPHAN m3 : 8|8@1+ (1,0) [0|0] \"\" ECU");
    assert!(
        e.contains("message MUX, signal ORPHAN") && e.contains("no multiplexor"),
        "{e}"
    );
}

#[test]
fn unknown_signal_names_what_was_looked_for() {
    let db = Database::parse(
        &dbc("BO_ 256 MSG: 8 ECU\n SG_ A : 0|8@1+ (1,0) [0|0] \"\" ECU"),
        "t.dbc",
    )
    .unwrap();
    for (path, part) in [
        ("MSG.B", "has no signal B"),
        ("NOPE.A", "no message NOPE"),
        ("MSGA", "expected MESSAGE.SIGNAL"),
    ] {
        let e = db.signal(path).unwrap_err().to_string();
        assert!(e.contains(path) && e.contains(part), "{e}");
    }
    let m = db.message_by_name("MSG").unwrap();
    let e = m.encode(&[("B", 1.0)]).unwrap_err().to_string();
    assert!(e.contains("MSG.B"), "{e}");
    let e = m
        .encode_into([(5, 1.0)], &mut [0; 8])
        .unwrap_err()
        .to_string();
    assert!(e.contains("MSG[5]"), "{e}");
}

#[test]
fn a_misspelt_name_gets_a_suggestion_and_a_foreign_one_none() {
    let db = Database::parse(
        &dbc(
            "BO_ 256 WHEEL_SPEEDS: 8 ECU\n SG_ WHEEL_SPEED_RL : 0|16@1+ (0.01,0) [0|0] \"\" ECU\n \
              SG_ WHEEL_SPEED_RR : 16|16@1+ (0.01,0) [0|0] \"\" ECU",
        ),
        "t.dbc",
    )
    .unwrap();
    let e = db
        .signal("WHEEL_SPEEDS.WHEEL_SPEED_LR")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("did you mean WHEEL_SPEED_RL?") || e.contains("did you mean WHEEL_SPEED_RR?"),
        "{e}"
    );
    let e = db
        .signal("wheel_speed.WHEEL_SPEED_RL")
        .unwrap_err()
        .to_string();
    assert!(e.contains("did you mean WHEEL_SPEEDS?"), "{e}");
    let e = db.signal("STEERING.ANGLE").unwrap_err().to_string();
    assert!(!e.contains("did you mean"), "{e}");
}

#[test]
fn short_frame_is_rejected_with_lengths() {
    let db = Database::from_file(crate::util::shared_dbc("rc_car.dbc")).unwrap();
    let m = db.message_by_id(FrameId::standard(256).unwrap()).unwrap();
    let e = m.decode(&[0; 7]).unwrap_err().to_string();
    assert!(
        e.contains("WHEEL_ENC_REAR") && e.contains("7 data bytes") && e.contains("needs 8"),
        "{e}"
    );
    let h = db.signal("WHEEL_ENC_REAR.RL_TICKS").unwrap();
    // RL_TICKS sits in bytes 0..2, but the frame is malformed: no value.
    assert_eq!(h.decode(&[1, 2, 3]), None);
    let e = h.decode_checked(&db, &[1, 2, 3]).unwrap_err().to_string();
    assert!(
        e.contains("WHEEL_ENC_REAR") && e.contains("3 data bytes"),
        "{e}"
    );
    let e = m
        .encode_into([(0, 1.0)], &mut [0; 4])
        .unwrap_err()
        .to_string();
    assert!(e.contains("4 data bytes"), "{e}");
    assert!(!h.encode(1.0, &mut [0; 4]));
}

#[test]
fn out_of_range_encode_names_signal_and_range() {
    let db = Database::from_file(crate::util::shared_dbc("rc_car.dbc")).unwrap();
    let m = db.message_by_name("STEERING").unwrap();
    // STEER_ANGLE: 16-bit signed, factor 0.01 -> [-327.68, 327.67].
    let e = m
        .encode(&[
            ("STEER_ANGLE", 400.0),
            ("STEER_CMD", 0.0),
            ("COUNTER", 0.0),
            ("CHECKSUM", 0.0),
        ])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("message STEERING, signal STEER_ANGLE")
            && e.contains("400")
            && e.contains("327.67"),
        "{e}"
    );
    let e = m
        .encode(&[
            ("STEER_ANGLE", f64::NAN),
            ("STEER_CMD", 0.0),
            ("COUNTER", 0.0),
            ("CHECKSUM", 0.0),
        ])
        .unwrap_err()
        .to_string();
    assert!(e.contains("STEER_ANGLE") && e.contains("NaN"), "{e}");
    let h = db.signal("STEERING.COUNTER").unwrap();
    let mut frame = [0xAAu8; 8];
    assert!(
        !h.encode(16.0, &mut frame),
        "16 does not fit 4 bits and must not wrap to 0"
    );
    assert_eq!(frame, [0xAA; 8]);
}

#[test]
fn missing_and_inactive_signals_are_named() {
    let db = Database::from_file(crate::util::shared_dbc("rc_car.dbc")).unwrap();
    let m = db.message_by_name("VEHICLE_STATE").unwrap();
    let e = m.encode(&[("DRIVE_MODE", 1.0)]).unwrap_err().to_string();
    assert!(
        e.contains("VEHICLE_STATE") && e.contains("signal SPEED_CMD"),
        "{e}"
    );

    let db = Database::from_file(crate::util::shared_dbc("cantools_multiplex.dbc")).unwrap();
    let m = db.message_by_name("Message1").unwrap();
    let e = m
        .encode(&[("Multiplexor", 8.0), ("BIT_K", 1.0)])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("Message1") && e.contains("BIT_K") && e.contains("not selected"),
        "{e}"
    );
}

#[test]
fn unresolvable_multiplexing_names_the_signal() {
    let e = load_err(
        "BO_ 256 MUX: 8 ECU\n SG_ A M : 0|4@1+ (1,0) [0|0] \"\" ECU\n SG_ B M : 4|4@1+ (1,0) [0|0] \"\" ECU\n SG_ C m1 : 8|8@1+ (1,0) [0|0] \"\" ECU",
    );
    assert!(
        e.contains("message MUX, signal C") && e.contains("several multiplexors"),
        "{e}"
    );
    let e = load_err(
        "BO_ 256 MUX: 8 ECU\n SG_ A M : 0|4@1+ (1,0) [0|0] \"\" ECU\n SG_ C m1 : 8|8@1+ (1,0) [0|0] \"\" ECU\n\nSG_MUL_VAL_ 256 C NOPE 1-1;",
    );
    assert!(
        e.contains("signal C") && e.contains("unknown multiplexor NOPE"),
        "{e}"
    );
    let e = load_err(
        "BO_ 256 MUX: 8 ECU\n SG_ A m1M : 0|4@1+ (1,0) [0|0] \"\" ECU\n SG_ B m1M : 4|4@1+ (1,0) [0|0] \"\" ECU\n\nSG_MUL_VAL_ 256 A B 1-1;\nSG_MUL_VAL_ 256 B A 1-1;",
    );
    assert!(e.contains("message MUX") && e.contains("cycle"), "{e}");
}

#[test]
fn too_many_multiplexors_is_rejected() {
    use std::fmt::Write as _;
    let mut text = String::from("BO_ 256 MANY: 8 ECU\n SG_ M0 M : 0|1@1+ (1,0) [0|0] \"\" ECU\n");
    let mut mul = String::new();
    for k in 1..10 {
        writeln!(text, " SG_ M{k} m1M : {k}|1@1+ (1,0) [0|0] \"\" ECU").unwrap();
        writeln!(mul, "SG_MUL_VAL_ 256 M{k} M{} 1-1;", k - 1).unwrap();
    }
    let e = load_err(&format!("{text}\n{mul}"));
    assert!(
        e.contains("message MANY, signal M8") && e.contains("more than 8"),
        "{e}"
    );
}
