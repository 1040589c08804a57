//! Property tests: decode(encode(x)) within one LSB, encode never writes outside the
//! signal's bits, for random layouts, byte orders, sizes and scalings.

use canodom_dbc::Database;
use proptest::prelude::*;

fn one_signal_db(
    start: u64,
    size: u64,
    big_endian: bool,
    signed: bool,
    factor: f64,
    offset: f64,
) -> Database {
    let text = format!(
        "VERSION \"\"\n\nBS_:\n\nBU_: ECU\n\nBO_ 100 M: 64 ECU\n SG_ S : {start}|{size}@{}{} ({factor:e},{offset:e}) [0|0] \"\" ECU\n",
        i32::from(!big_endian),
        if signed { '-' } else { '+' },
    );
    Database::parse(&text, "prop.dbc").unwrap()
}

fn layout() -> impl Strategy<Value = (u64, u64, bool)> {
    (1u64..=64, any::<bool>()).prop_flat_map(|(size, be)| {
        let starts = if be {
            // Motorola: MSB position; the run must end inside 64 bytes.
            (0u64..512)
                .prop_filter("fits", move |&s| (s / 8) * 8 + (7 - s % 8) + size <= 512)
                .boxed()
        } else {
            (0u64..=512 - size).boxed()
        };
        (starts, Just(size), Just(be))
    })
}

proptest! {
    // No persistence file: this is an integration test binary, and CI prints the seed.
    #![proptest_config(ProptestConfig { failure_persistence: None, ..ProptestConfig::with_cases(256) })]

    #[test]
    fn decode_encode_within_one_lsb_and_only_own_bits(
        (start, size, be) in layout(),
        signed in any::<bool>(),
        factor in prop_oneof![Just(1.0), 0.001f64..10.0, -10.0f64..-0.001],
        offset in -1000.0f64..1000.0,
        frac in 0.0f64..1.0,
        background in any::<u8>(),
    ) {
        let db = one_signal_db(start, size, be, signed, factor, offset);
        let h = db.signal("M.S").unwrap();
        let m = db.message_by_name("M").unwrap();
        let (lo, hi) = m.signals()[0].encodable_range();
        // Keep inside the range and away from f64's 53-bit precision limit.
        let span = (hi - lo).min(factor.abs() * 2f64.powi(50));
        let x = lo + frac * span;
        let mut frame = [background; 64];
        prop_assert!(h.encode(x, &mut frame));
        let y = h.decode(&frame).unwrap();
        prop_assert!((y - x).abs() <= factor.abs() * 0.5 * (1.0 + 1e-9) + 1e-9 * x.abs(), "x={x} y={y}");
        let mut mask = [0u8; 64];
        m.signals()[0].or_bit_mask(&mut mask);
        for k in 0..64 {
            prop_assert_eq!(frame[k] & !mask[k], background & !mask[k], "byte {} outside the signal changed", k);
        }
        prop_assert_eq!(mask.iter().map(|b| b.count_ones()).sum::<u32>() as u64, size);
    }

    #[test]
    fn saturating_encode_is_encode_inside_the_range_and_the_nearest_end_outside(
        size in 2u64..=32,
        signed in any::<bool>(),
        factor in prop_oneof![Just(1.0), 0.001f64..10.0, -10.0f64..-0.001],
        offset in -1000.0f64..1000.0,
        value in prop_oneof![-1e12f64..1e12, Just(f64::NAN), Just(f64::INFINITY), Just(f64::NEG_INFINITY)],
    ) {
        let db = one_signal_db(0, size, false, signed, factor, offset);
        let h = db.signal("M.S").unwrap();
        let m = db.message_by_name("M").unwrap();
        let (lo, hi) = m.signals()[0].encodable_range();
        let mut saturated = [0u8; 64];
        prop_assert!(h.encode_saturating(value, &mut saturated));
        let mut plain = [0u8; 64];
        if h.encode(value, &mut plain) {
            prop_assert_eq!(saturated, plain, "a value that fits is written as it is");
        } else {
            let y = h.decode(&saturated).unwrap();
            // NaN is written as 0, itself saturated.
            let target = if value.is_nan() { 0.0 } else { value };
            let nearest_end = if target <= lo { lo } else { hi };
            let lsb_slack = factor.abs() * 0.5 * (1.0 + 1e-9);
            if target < lo - lsb_slack || target > hi + lsb_slack {
                prop_assert_eq!(y, nearest_end, "value {} range [{}, {}]", value, lo, hi);
            } else {
                // Only rounding pushed it out: the written value is within one LSB.
                prop_assert!((y - target).abs() <= factor.abs() * (1.0 + 1e-9), "value {} wrote {}", value, y);
            }
        }
    }
}
