//! Issue #20, point by point, on small texts: tolerant loading with warnings and strict
//! refusal, long names, exact integers above 2^53.

use canodom_dbc::{Database, Error, LoadMode, Value};

const TWO_MESSAGES: &str = r#"VERSION ""

BS_:

BU_: ECU

BO_ 256 GOOD: 8 ECU
 SG_ SPEED : 0|16@1+ (0.01,0) [0|655.35] "km/h" ECU

BO_ 257 BROKEN: 2 ECU
 SG_ OK_PART : 0|8@1+ (1,0) [0|255] "" ECU
 SG_ TOO_FAR : 12|8@1+ (1,0) [0|255] "" ECU
"#;

#[test]
fn one_broken_message_is_left_out_with_a_warning() {
    let db = Database::parse(TWO_MESSAGES, "car.dbc").unwrap();
    assert_eq!(db.messages().len(), 1);
    assert!(db.message_by_name("GOOD").is_some());
    assert!(db.message_by_name("BROKEN").is_none());
    let [w] = db.warnings() else {
        panic!("{:?}", db.warnings())
    };
    assert_eq!(
        w.to_string(),
        "car.dbc: message BROKEN left out (it cannot be decoded): signal TOO_FAR: \
         needs 3 bytes but the message is only 2 bytes long"
    );
    assert_eq!(
        (w.source_name(), w.message(), w.signal()),
        ("car.dbc", "BROKEN", Some("TOO_FAR"))
    );
    assert!(db.signal("GOOD.SPEED").is_ok());
}

#[test]
fn using_a_left_out_message_is_an_error_naming_signal_and_reason() {
    let db = Database::parse(TWO_MESSAGES, "car.dbc").unwrap();
    // Even a signal of it that compiles on its own: the whole message is out.
    let e = db.signal("BROKEN.OK_PART").unwrap_err();
    assert!(matches!(e, Error::LeftOut { .. }), "{e:?}");
    assert_eq!(
        e.to_string(),
        "\"BROKEN.OK_PART\" cannot be used: car.dbc: message BROKEN left out (it cannot be \
         decoded): signal TOO_FAR: needs 3 bytes but the message is only 2 bytes long"
    );
    assert_eq!(
        db.left_out("BROKEN").map(canodom_dbc::LoadWarning::reason),
        Some("needs 3 bytes but the message is only 2 bytes long")
    );
}

#[test]
fn strict_mode_refuses_the_file() {
    let e = Database::parse_with(TWO_MESSAGES, "car.dbc", LoadMode::Strict).unwrap_err();
    assert_eq!(
        e.to_string(),
        "car.dbc: message BROKEN, signal TOO_FAR: needs 3 bytes but the message is only 2 bytes long"
    );
    let clean = Database::parse_with(
        &TWO_MESSAGES.replace("12|8@1+", "8|8@1+"),
        "car.dbc",
        LoadMode::Strict,
    )
    .unwrap();
    assert!(clean.warnings().is_empty() && clean.messages().len() == 2);
}

#[test]
fn a_duplicate_id_leaves_out_the_second_message() {
    let text = TWO_MESSAGES.replace("BO_ 257 BROKEN: 2", "BO_ 256 BROKEN: 2");
    let db = Database::parse(&text, "car.dbc").unwrap();
    assert_eq!(db.messages().len(), 1);
    assert!(db.warnings()[0].reason().contains("also used by GOOD"));
}

/// cantools' tests/files/dbc/mod_name_len_src.dbc: names cut to 32 characters in `BO_`
/// and `SG_`, the whole names in `SystemMessageLongSymbol` / `SystemSignalLongSymbol`.
#[test]
fn long_names_name_messages_and_signals() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/corpus/cantools/mod_name_len_src.dbc"
    );
    let db = Database::from_file(path).unwrap();
    let m = &db.messages()[0];
    assert_eq!(m.name(), "Msg_will_be_shortened_3456789_12YYYY");
    assert_eq!(m.short_name(), "Msg_will_be_shortened_3456789_12");
    let s = &m.signals()[0];
    assert_eq!(s.name(), "Sig_will_be_shortened_3456789_12XXXX");
    assert_eq!(s.short_name(), "Sig_will_be_shortened_3456789_12");
    // Decoding names signals by their long names.
    let data = [0u8; 8];
    let names: Vec<&str> = m.decode(&data).unwrap().map(|(s, _)| s.name()).collect();
    assert_eq!(names, ["Sig_will_be_shortened_3456789_12XXXX"]);
    // MESSAGE.SIGNAL lookups take long and short names, in any combination.
    let long = db
        .signal("Msg_will_be_shortened_3456789_12YYYY.Sig_will_be_shortened_3456789_12XXXX")
        .unwrap();
    for path in [
        "Msg_will_be_shortened_3456789_12.Sig_will_be_shortened_3456789_12",
        "Msg_will_be_shortened_3456789_12YYYY.Sig_will_be_shortened_3456789_12",
        "Msg_will_be_shortened_3456789_12.Sig_will_be_shortened_3456789_12XXXX",
    ] {
        assert_eq!(db.signal(path).unwrap(), long, "{path}");
    }
    assert!(
        db.message_by_name("Msg_will_be_shortened_3456789_12")
            .is_some()
    );
}

/// cantools' signed.dbc: a 64-bit signal with scale 1 and offset 0.
#[test]
fn integers_above_2_pow_53_are_exact() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/corpus/cantools/signed.dbc"
    );
    let db = Database::from_file(path).unwrap();
    let (m, s) = db
        .messages()
        .iter()
        .find_map(|m| m.signals().iter().find(|s| s.size() == 64).map(|s| (m, s)))
        .unwrap();
    let raw = 3_791_054_832_379_806_569u64;
    assert_eq!(
        s.value(raw),
        Value::Integer(3_791_054_832_379_806_569),
        "{}",
        s.name()
    );
    assert_eq!(s.value(raw).to_string(), "3791054832379806569");
    // The f64 path rounds, as it must.
    assert_eq!(s.raw_to_scaled(raw).to_string(), "3791054832379806700");
    // Decoding a whole frame keeps it exact.
    let mut frame = vec![0u8; m.length()];
    assert!(s.encode_raw(raw, &mut frame));
    let mut seen = None;
    m.decode_each_value(&frame, |sig, v| {
        if sig.index() == s.index() {
            seen = Some(v);
        }
    })
    .unwrap();
    assert_eq!(seen, Some(Value::Integer(3_791_054_832_379_806_569)));
    // Scaled and float signals stay floats, as in cantools.
    let text = r#"VERSION ""
BO_ 1 M: 8 ECU
 SG_ A : 0|8@1+ (0.5,0) [0|0] "" ECU
 SG_ B : 8|8@1- (2,-3) [0|0] "" ECU
"#;
    let db = Database::parse(text, "t.dbc").unwrap();
    let mut values = Vec::new();
    db.messages()[0]
        .decode_each_value(&[3, 0xFF, 0, 0, 0, 0, 0, 0], |_, v| values.push(v))
        .unwrap();
    assert_eq!(values, [Value::Float(1.5), Value::Integer(-5)]);
}

/// `integer_range` is what a column type is chosen from before any frame: every value
/// [`canodom_dbc::Signal::value`] gives must lie in it, at its ends too.
#[test]
fn integer_range_holds_every_value_the_signal_can_give() {
    let text = r#"VERSION ""
BO_ 1 M: 8 ECU
 SG_ HALF : 0|8@1+ (0.5,0) [0|0] "" ECU
 SG_ NEG : 8|8@1- (-3,10) [0|0] "" ECU
 SG_ U16 : 16|16@1+ (1,0) [0|0] "" ECU
 SG_ FLT : 32|32@1- (1,0) [0|0] "" ECU
BO_ 2 WIDE: 8 ECU
 SG_ U64 : 0|64@1+ (1,0) [0|0] "" ECU
BO_ 3 WIDER: 8 ECU
 SG_ S64X : 0|64@1- (4,-7) [0|0] "" ECU
SIG_VALTYPE_ 1 FLT : 1;
"#;
    let db = Database::parse(text, "t.dbc").unwrap();
    let signal = |m: &str, s: &str| {
        db.message_by_name(m)
            .and_then(|m| m.signal(s))
            .unwrap()
            .clone()
    };
    assert_eq!(signal("M", "HALF").integer_range(), None);
    assert_eq!(signal("M", "FLT").integer_range(), None);
    assert_eq!(signal("M", "NEG").integer_range(), Some((-371, 394)));
    assert_eq!(signal("M", "U16").integer_range(), Some((0, 65_535)));
    assert_eq!(
        signal("WIDE", "U64").integer_range(),
        Some((0, i128::from(u64::MAX)))
    );
    let s64 = signal("WIDER", "S64X");
    let (lo, hi) = s64.integer_range().unwrap();
    assert_eq!(
        (lo, hi),
        (i128::from(i64::MIN) * 4 - 7, i128::from(i64::MAX) * 4 - 7)
    );
    // The ends are reached, and nothing lies beyond them.
    for s in [
        signal("M", "NEG"),
        signal("M", "U16"),
        signal("WIDE", "U64"),
        s64,
    ] {
        let (lo, hi) = s.integer_range().unwrap();
        let mut seen = Vec::new();
        for raw in [
            0u64,
            1,
            u64::MAX,
            u64::MAX >> 1,
            1 << 63,
            0x7F,
            0x80,
            0xFF,
            0xFFFF,
        ] {
            let raw = raw & (u64::MAX >> (64 - s.size()));
            let Value::Integer(v) = s.value(raw) else {
                panic!("{}: not an integer", s.name())
            };
            assert!(lo <= v && v <= hi, "{}: {v} outside {lo}..={hi}", s.name());
            seen.push(v);
        }
        assert!(
            seen.contains(&lo) && seen.contains(&hi),
            "{}: {seen:?}",
            s.name()
        );
    }
}

#[test]
fn message_index_is_the_place_in_messages_of_the_id_and_none_for_others() {
    let text = r#"VERSION ""
BO_ 5 A: 8 ECU
 SG_ X : 0|8@1+ (1,0) [0|0] "" ECU
BO_ 2147483905 B: 8 ECU
 SG_ Y : 0|8@1+ (1,0) [0|0] "" ECU
"#;
    let db = Database::parse(text, "t.dbc").unwrap();
    for (i, m) in db.messages().iter().enumerate() {
        assert_eq!(db.message_index(m.id()), Some(i), "{}", m.name());
    }
    assert_eq!(db.message_index(canodom_dbc::FrameId::Standard(6)), None);
    assert_eq!(db.message_index(canodom_dbc::FrameId::Extended(5)), None);
    assert_eq!(
        db.message_index(canodom_dbc::FrameId::Extended(0x101)),
        Some(1)
    );
}
