//! `f64` written exactly as `format!("{}", v)` writes it, faster: a replay
//! profile spent a third of its instructions in the standard library's float
//! formatting. `zmij` (the Schubfach-based formatter serde_json uses) finds
//! the same shortest round-trip digits (closest to the exact value when
//! several are shortest) that the standard library finds, in about half the
//! instructions `ryu` needed (replay of 200,000 frames: 822 M instructions
//! with `{}`, 711 M with `ryu`, see the commit log for `zmij`); only the
//! layout differs (`zmij` writes `1.0` and `1e16`, `{}` writes `1` and
//! `10000000000000000`), so this module takes `zmij`'s text where its layout
//! is `{}`'s and leaves the rest to `{}`. One more possible difference: when
//! the value lies exactly half-way between two shortest candidates, the
//! tie-breaking rules of the two may differ; such a tie needs a value with
//! few binary fraction digits (see `tie_possible`), so those rare values
//! go to `{}` itself. Output files therefore stay byte-identical to what
//! earlier versions wrote.

/// Appends `value` to `out` exactly as `write!(out, "{}", value)` would.
pub fn push_f64(out: &mut Vec<u8>, value: f64) {
    let mut buffer = zmij::Buffer::new();
    push_text_or_display(out, fast_text(&mut buffer, value), value);
}

/// Appends one CSV line: `micros` as [`push_micros_as_seconds`] writes it,
/// then `,` and each of `values` as [`push_f64`] writes it, then `\n`.
///
/// The same bytes as those calls, assembled on the stack and appended with
/// one copy: copied field by field into the `Vec`, each of the seven short
/// texts of a replay row was a call to `memcpy` plus a capacity check. All
/// values are formatted before any is copied: a text copied right after
/// zmij wrote it is read back before its stores left the CPU's store
/// buffer, and stalls (perf put a quarter of float formatting's time there).
pub fn push_csv_row<const N: usize>(out: &mut Vec<u8>, micros: i64, values: &[f64; N]) {
    const { assert!(N <= 8, "a row's fields must fit ROW_BYTES") };
    let mut buffers: [zmij::Buffer; N] = std::array::from_fn(|_| zmij::Buffer::new());
    let mut formatted = buffers.iter_mut().zip(values);
    let texts: [Option<&[u8]>; N] = std::array::from_fn(|_| {
        formatted
            .next()
            .and_then(|(buffer, &value)| fast_text(buffer, value))
    });
    let mut row = [0u8; ROW_BYTES];
    let Some(mut at) = put_micros_as_seconds(&mut row, micros) else {
        return push_csv_row_slowly(out, micros, values);
    };
    for text in texts {
        let Some(text) = text else {
            return push_csv_row_slowly(out, micros, values);
        };
        row[at] = b',';
        at = put(&mut row, at + 1, text);
    }
    row[at] = b'\n';
    out.extend_from_slice(&row[..=at]);
}

/// [`push_csv_row`] field by field, for rows with a value off the fast path.
#[cold]
fn push_csv_row_slowly<const N: usize>(out: &mut Vec<u8>, micros: i64, values: &[f64; N]) {
    push_micros_as_seconds(out, micros);
    for &value in values {
        out.push(b',');
        push_f64(out, value);
    }
    out.push(b'\n');
}

/// Room for the longest row of [`push_csv_row`]: a time of 17 bytes (sign,
/// nine digits of seconds below 10⁹ s, `.` and six digits; its fraction is
/// written as eight bytes, one past its end, which the next field covers),
/// eight fields of 25 (`,`, sign, `0.0000` and 17 digits) and the newline.
/// An index past it would panic, not corrupt: the longest row is tested.
const ROW_BYTES: usize = 17 + 8 * 25 + 1;

/// Copies `text` to `row` at `at`, from 8 to 32 bytes (the texts here have
/// 3 to 24) in two fixed-size moves, overlapping, instead of a `memcpy` call
/// sized at run time; returns the end.
#[inline]
fn put(row: &mut [u8; ROW_BYTES], at: usize, text: &[u8]) -> usize {
    let n = text.len();
    if (16..=32).contains(&n) {
        row[at..at + 16].copy_from_slice(&text[..16]);
        row[at + n - 16..at + n].copy_from_slice(&text[n - 16..]);
    } else if (8..16).contains(&n) {
        row[at..at + 8].copy_from_slice(&text[..8]);
        row[at + n - 8..at + n].copy_from_slice(&text[n - 8..]);
    } else {
        row[at..at + n].copy_from_slice(text);
    }
    at + n
}

/// [`push_micros_as_seconds`]'s text written to `row` from its start:
/// whole seconds, then up to six digits after a point, trailing zeros
/// dropped (`12.5`, `3`, `0.000001`); returns its end, or `None` from 10⁹ s
/// on (then that function's `{}`).
#[inline]
fn put_micros_as_seconds(row: &mut [u8; ROW_BYTES], micros: i64) -> Option<usize> {
    let magnitude = micros.unsigned_abs();
    if magnitude >= 1_000_000_000_000_000 {
        return None;
    }
    row[0] = b'-';
    let at = usize::from(micros < 0);
    let mut whole = itoa::Buffer::new();
    let at = put(row, at, whole.format(magnitude / 1_000_000).as_bytes());
    let mut fraction = (magnitude % 1_000_000) as u32;
    if fraction == 0 {
        return Some(at);
    }
    // `.` and six digits, written whole; the end drops trailing zeros.
    let mut digits = [b'0'; 8];
    digits[0] = b'.';
    for d in digits[1..7].iter_mut().rev() {
        *d = b'0' + (fraction % 10) as u8;
        fraction /= 10;
    }
    row[at..at + 8].copy_from_slice(&digits);
    let end = digits[..7]
        .iter()
        .rposition(|&d| d != b'0')
        .map_or(0, |i| i + 1);
    Some(at + end)
}

/// `text` if the fast path produced one, else `value` through `{}`.
#[inline]
fn push_text_or_display(out: &mut Vec<u8>, text: Option<&[u8]>, value: f64) {
    use std::io::Write as _;
    match text {
        Some(text) => out.extend_from_slice(text),
        None => {
            let _ = write!(out, "{value}");
        }
    }
}

/// zmij's text for `value` when it is `{}`'s (see the module comment), else
/// `None`: NaN, infinities, exponents and possible ties, rare in odometry
/// output, are left to `{}`.
#[inline]
fn fast_text(buffer: &mut zmij::Buffer, value: f64) -> Option<&[u8]> {
    // zmij writes 1e-5 <= |x| < 1e16 without an exponent, in `{}`'s layout
    // but for the `.0` of whole numbers.
    let magnitude = value.abs();
    // zmij's layout is fixed exactly when its shortest digits lie in
    // [1e-5, 1e16) (or the value is 0): those digits read back as `value`,
    // and rounding is monotonic, so they lie there exactly when `value`
    // does. One comparison instead of looking for an `e` in the text.
    if !((1e-5..1e16).contains(&magnitude) || magnitude == 0.0) {
        return None;
    }
    let text = buffer.format_finite(value).as_bytes();
    // Whether the text ends in `.0` is told by the value's bits: reading the
    // text's last bytes right after zmij's stores stalled (store
    // forwarding), a tenth of the formatting's time.
    if is_whole(value) {
        let whole = text.strip_suffix(b".0")?;
        return (!tie_possible(value, 0)).then_some(whole);
    }
    (!tie_possible(value, MAX_FIXED_FRACTION_DIGITS) || !tie_possible(value, fraction_digits(text)))
        .then_some(text)
}

/// Appends the time `micros / 10⁶` s exactly as [`push_f64`] appends the
/// `f64` nearest to it (`micros as f64 / 1e6`, how replay's times are
/// made), straight from the integer: a few dozen instructions, no float to
/// take apart.
///
/// Why the text of `n / 10⁶` is `{}`'s for that `f64`: it reads back as it
/// (that is what "nearest" means), and no other decimal with as few digits
/// does, because below 10⁹ s the `f64` spacing is under 10⁻⁶ and any such
/// decimal lies on the 10⁻⁶ grid too, at least 10⁻⁶ away. Beyond 10⁹ s,
/// `{}` itself.
pub fn push_micros_as_seconds(out: &mut Vec<u8>, micros: i64) {
    let mut row = [0u8; ROW_BYTES];
    match put_micros_as_seconds(&mut row, micros) {
        Some(end) => out.extend_from_slice(&row[..end]),
        None => push_f64(out, micros as f64 / 1e6),
    }
}

/// Most digits after the point zmij's fixed layout can have: 4 zeros
/// after `0.` (from 1e-5 on) and 17 significant digits, with a margin of one.
/// A value with more binary fraction digits than this allows cannot be a
/// tie, whatever its decimal text: the common case needs no digit count.
const MAX_FIXED_FRACTION_DIGITS: i64 = 22;

/// Digits after the decimal point of a fixed-layout `text`.
fn fraction_digits(text: &[u8]) -> i64 {
    text.iter()
        .position(|&b| b == b'.')
        .map_or(0, |point| (text.len() - point - 1) as i64)
}

/// Whether `value` could lie exactly half-way between two decimals with
/// `fraction_digits` digits after the point (negative: trailing zeros before
/// it). That needs `value · 10^(fraction_digits + 1)` to be an integer, which
/// with `value = m · 2^e` (m odd) needs `e + fraction_digits + 1 >= 0`.
fn tie_possible(value: f64, fraction_digits: i64) -> bool {
    odd_exponent(value) + fraction_digits + 1 >= 0
}

/// The `e` of `value = m · 2^e` with `m` odd (of 0: a number below every
/// other value's, so 0 is neither whole by [`is_whole`] nor a tie).
fn odd_exponent(value: f64) -> i64 {
    let bits = value.to_bits();
    let biased = ((bits >> 52) & 0x7ff) as i64;
    let fraction = bits & ((1u64 << 52) - 1);
    let (mantissa, exponent) = if biased == 0 {
        (fraction, -1074)
    } else {
        (fraction | (1u64 << 52), biased - 1075)
    };
    exponent + i64::from(mantissa.trailing_zeros())
}

/// Whether a finite `value` is a whole number: exactly when its shortest
/// text ends in `.0` (any shorter text reading back as a whole number is a
/// whole number's), found from its bits, not by reading back the text.
fn is_whole(value: f64) -> bool {
    value == 0.0 || odd_exponent(value) >= 0
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
        // Either side of where zmij's layout changes (a wrong bound would
        // let zmij's `e` through).
        for edge in [1e-5, 1e16] {
            let mut below = edge;
            let mut above = edge;
            for _ in 0..1000 {
                below = f64::next_down(below);
                above = f64::next_up(above);
                for v in [below, above, -below, -above] {
                    assert_eq!(ours(v), format!("{v}"), "{v:e}");
                }
            }
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
        // Replay's values have full binary fractions: no tie possible, zmij's digits are used.
        let mut fast = 0;
        for i in 1..10_000u32 {
            let v = f64::from(i) * 0.012_345_678_9 - 50.0;
            let mut buffer = zmij::Buffer::new();
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

    #[test]
    fn micros_as_seconds_match_display_over_days() {
        // The first 3 s µs by µs, then sparser up to 11.6 days, both signs.
        let sparse = (3_000_000..1_000_000_000_000).step_by(999_983);
        for micros in (0..3_000_000).chain(sparse) {
            for m in [micros, -micros] {
                let mut out = Vec::new();
                push_micros_as_seconds(&mut out, m);
                let expected = format!("{}", m as f64 / 1e6);
                assert_eq!(String::from_utf8(out).unwrap(), expected, "{m}");
            }
        }
    }

    #[test]
    fn micros_as_seconds_at_the_edges() {
        for micros in [
            0,
            1,
            -1,
            10_000,
            -500_000,
            999_999_999_999_999,
            -999_999_999_999_999,
            1_000_000_000_000_000,
            i64::MAX,
            i64::MIN,
        ] {
            let mut out = Vec::new();
            push_micros_as_seconds(&mut out, micros);
            let expected = format!("{}", micros as f64 / 1e6);
            assert_eq!(String::from_utf8(out).unwrap(), expected, "{micros}");
        }
    }

    /// The row as the field-by-field functions write it.
    fn row_by_fields<const N: usize>(micros: i64, values: &[f64; N]) -> Vec<u8> {
        let mut out = b"earlier text".to_vec();
        push_micros_as_seconds(&mut out, micros);
        for &v in values {
            out.push(b',');
            push_f64(&mut out, v);
        }
        out.push(b'\n');
        out
    }

    fn row(micros: i64, values: &[f64]) -> Vec<u8> {
        let mut out = b"earlier text".to_vec();
        match values.len() {
            0 => push_csv_row(&mut out, micros, &[0.0f64; 0]),
            1 => push_csv_row(&mut out, micros, &[values[0]]),
            _ => push_csv_row(&mut out, micros, &<[f64; 8]>::try_from(values).unwrap()),
        }
        out
    }

    #[test]
    fn the_longest_row_fits() {
        // 24 bytes: sign, `0.0000` and 17 significant digits.
        let longest = -0.000_012_345_678_901_234_567;
        let mut text = zmij::Buffer::new();
        assert_eq!(fast_text(&mut text, longest).map(<[u8]>::len), Some(24));
        let mut out = Vec::new();
        push_csv_row(&mut out, -999_999_999_999_999, &[longest; 8]);
        assert_eq!(out.len(), ROW_BYTES);
        assert_eq!(
            out,
            row_by_fields(-999_999_999_999_999, &[longest; 8])[12..]
        );
    }

    #[test]
    fn csv_rows_at_the_edges_equal_their_fields() {
        // Texts of every length `put` is given (3..=24 bytes, checked), the
        // longest time, the slow paths (exponents, NaN, ties, beyond 10⁹ s),
        // and rows of 0, 1 and 8 values.
        let mut lengths: Vec<f64> = Vec::new();
        for digits in 1..=17 {
            let significand = &"12345678901234567"[..digits];
            for point in 0..=digits {
                let whole = format!("{}.{}", &significand[..point], &significand[point..]);
                lengths.push(format!("0{whole}0").parse().unwrap());
            }
            for zeros in 0..=4 {
                let text = format!("0.{}{significand}", "0".repeat(zeros));
                lengths.push(text.parse().unwrap());
            }
        }
        lengths.extend(lengths.clone().iter().map(|v| -v));
        let covered: std::collections::BTreeSet<usize> = lengths
            .iter()
            .filter_map(|&v| fast_text(&mut zmij::Buffer::new(), v).map(<[u8]>::len))
            .collect();
        // (Whole numbers, the only texts under 3 bytes, go to `{}`.)
        assert_eq!(covered, (3..=24).collect(), "fast-path text lengths");
        lengths.extend([
            0.0,
            -0.0,
            1.0,
            -7.0,
            0.5,
            12.25,
            -0.125,
            1234.5678,
            0.1,
            -0.3,
            1e-5,
            -1.234_567_890_123_456_7e-5,
            123_456_789.123_456_7,
            -9_999_999_999_999_998.0,
            std::f64::consts::PI,
            -std::f64::consts::E,
            1e16,
            1e300,
            f64::NAN,
            f64::NEG_INFINITY,
            5e-324,
            1_658_206_780_088_562.2,
            0.012_345_678_901_234_5,
            -0.000_012_345_678_901_234_56,
        ]);
        for micros in [
            0,
            1,
            -1,
            999_999,
            -120_500_000,
            999_999_999_999_999,
            -999_999_999_999_999,
            1_000_000_000_000_000,
            i64::MIN,
            i64::MAX,
        ] {
            assert_eq!(
                row(micros, &[]),
                row_by_fields(micros, &[0.0f64; 0]),
                "{micros}"
            );
            for &v in &lengths {
                assert_eq!(
                    row(micros, &[v]),
                    row_by_fields(micros, &[v]),
                    "{micros} {v:e}"
                );
            }
            for window in lengths.windows(8) {
                let values = <[f64; 8]>::try_from(window).unwrap();
                assert_eq!(
                    row(micros, window),
                    row_by_fields(micros, &values),
                    "{micros} {values:?}"
                );
            }
        }
    }

    proptest! {
        #[test]
        fn csv_rows_equal_their_fields(
            micros in prop_oneof![any::<i64>(), -10_000_000_000i64..10_000_000_000],
            values in prop::array::uniform8(prop_oneof![
                any::<u64>().prop_map(f64::from_bits),
                -1e3f64..1e3,
                -1e-3f64..1e-3,
                (-1_000_000i64..1_000_000).prop_map(|n| n as f64 * 0.5),
            ])
        ) {
            prop_assert_eq!(row(micros, &values), row_by_fields(micros, &values));
        }

        #[test]
        fn any_f64_matches_display(bits in any::<u64>()) {
            let v = f64::from_bits(bits);
            prop_assert_eq!(ours(v), format!("{}", v));
        }

        #[test]
        fn csv_rows_match_display(
            micros in -10_000_000_000i64..10_000_000_000,
            values in prop::array::uniform6(prop_oneof![
                any::<u64>().prop_map(f64::from_bits),
                -1e3f64..1e3,
                (-1_000_000i64..1_000_000).prop_map(|n| n as f64 * 0.5),
            ])
        ) {
            let mut out = Vec::new();
            push_csv_row(&mut out, micros, &values);
            let mut expected = format!("{}", micros as f64 / 1e6);
            for v in values {
                expected.push(',');
                expected.push_str(&v.to_string());
            }
            expected.push('\n');
            prop_assert_eq!(String::from_utf8(out).unwrap(), expected);
        }

        #[test]
        fn micros_as_seconds_match_display_of_the_quotient(
            micros in prop_oneof![
                -1_000_000_000_000_000_000i64..1_000_000_000_000_000_000,
                -2_000_000_000_000_000i64..2_000_000_000_000_000,
                -10_000_000i64..10_000_000,
            ]
        ) {
            let mut out = Vec::new();
            push_micros_as_seconds(&mut out, micros);
            prop_assert_eq!(String::from_utf8(out).unwrap(), format!("{}", micros as f64 / 1e6));
        }
    }
}
