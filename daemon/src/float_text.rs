//! `f64` written exactly as `format!("{}", v)` writes it, faster: a replay
//! profile spent a third of its instructions in the standard library's float
//! formatting (with this module, replay of 200,000 frames went from 822 to
//! 711 million instructions). `ryu` finds the same shortest round-trip
//! digits (closest to the exact value when several are shortest) that the
//! standard library finds; only the layout differs (`ryu` writes `1.0` and
//! `1e16`, `{}` writes `1` and `10000000000000000`), so this module takes
//! `ryu`'s text where its layout is `{}`'s and leaves the rest to `{}`. One more difference:
//! when the value lies exactly half-way between two shortest candidates,
//! `ryu` rounds to even and `{}` rounds up; such a tie needs a value with few
//! binary fraction digits (see [`tie_possible`]), so those rare values go to
//! `{}` itself. Output files therefore stay byte-identical to what earlier
//! versions wrote.

/// Appends `value` to `out` exactly as `write!(out, "{}", value)` would.
pub fn push_f64(out: &mut Vec<u8>, value: f64) {
    use std::io::Write as _;
    // ryu writes 1e-5 <= |x| < 1e16 without an exponent, in `{}`'s layout
    // but for the `.0` of whole numbers; everything else (NaN, infinities,
    // exponents, possible ties) is rare in odometry output and goes to `{}`.
    if value.is_finite() {
        let mut buffer = ryu::Buffer::new();
        let text = buffer.format_finite(value).as_bytes();
        if !text.contains(&b'e')
            && let Some(point) = text.iter().position(|&b| b == b'.')
        {
            let fraction = &text[point + 1..];
            let text = if fraction == b"0" {
                &text[..point]
            } else {
                text
            };
            let fraction_digits = if fraction == b"0" { 0 } else { fraction.len() };
            if !tie_possible(value, fraction_digits as i64) {
                out.extend_from_slice(text);
                return;
            }
        }
    }
    let _ = write!(out, "{value}");
}

/// Whether `value` could lie exactly half-way between two decimals with
/// `fraction_digits` digits after the point (negative: trailing zeros before
/// it). That needs `value · 10^(fraction_digits + 1)` to be an integer, which
/// with `value = m · 2^e` (m odd) needs `e + fraction_digits + 1 >= 0`.
fn tie_possible(value: f64, fraction_digits: i64) -> bool {
    let bits = value.to_bits();
    let biased = ((bits >> 52) & 0x7ff) as i64;
    let fraction = bits & ((1u64 << 52) - 1);
    let (mantissa, exponent) = if biased == 0 {
        (fraction, -1074)
    } else {
        (fraction | (1u64 << 52), biased - 1075)
    };
    let odd_exponent = exponent + i64::from(mantissa.trailing_zeros());
    odd_exponent + fraction_digits + 1 >= 0
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn ours(v: f64) -> String {
        let mut out = Vec::new();
        push_f64(&mut out, v);
        String::from_utf8(out).unwrap()
    }

    #[test]
    fn special_and_boundary_values_match_display() {
        let values = [
            0.0,
            -0.0,
            1.0,
            -1.0,
            0.1,
            0.5,
            10.0,
            100.0,
            1e15,
            1e16,
            1e17,
            1.5e300,
            f64::MAX,
            f64::MIN,
            f64::MIN_POSITIVE,
            5e-324,
            1e-5,
            1e-7,
            123.456,
            1_658_206_780_088_562.2,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            std::f64::consts::PI,
        ];
        for v in values {
            assert_eq!(ours(v), format!("{v}"), "{v:e}");
        }
    }

    #[test]
    fn a_million_values_of_replay_magnitudes_match_display() {
        // Poses, headings and times as replay prints them, plus random bits.
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        for i in 0..1_000_000u64 {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            let v = match i % 3 {
                0 => f64::from_bits(state),
                1 => (state >> 11) as f64 / (1u64 << 53) as f64 * 200.0 - 100.0,
                _ => (state >> 20) as f64 * 1e-6,
            };
            assert_eq!(ours(v), format!("{v}"), "bits {:#x}", v.to_bits());
        }
    }

    #[test]
    fn poses_take_the_fast_path_and_ties_do_not() {
        // Replay's values have full binary fractions: no tie possible, ryu's digits are used.
        let mut fast = 0;
        for i in 1..10_000u32 {
            let v = f64::from(i) * 0.012_345_678_9 - 50.0;
            let mut buffer = ryu::Buffer::new();
            let text = buffer.format_finite(v);
            let fraction_digits = text.split('.').nth(1).map_or(0, |f| f.len() as i64);
            if !tie_possible(v, fraction_digits) {
                fast += 1;
            }
        }
        assert!(fast > 9_900, "{fast} of 9,999 on the fast path");
        // 1658206780088562.25 is half-way between ...62.2 and ...62.3.
        assert!(tie_possible(1_658_206_780_088_562.2, 1));
    }

    proptest! {
        #[test]
        fn any_f64_matches_display(bits in any::<u64>()) {
            let v = f64::from_bits(bits);
            prop_assert_eq!(ours(v), format!("{}", v));
        }
    }
}
