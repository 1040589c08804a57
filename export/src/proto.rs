//! Foxglove's `PoseInFrame` and `FrameTransform` in protobuf, byte for byte
//! as the `foxglove` crate's own encoder (prost) writes them: fields in
//! number order, fields at their default value (0.0, an empty string) left
//! out, a message field written whenever it is present.
//!
//! Written here rather than through `foxglove::Encode`, for time: prost
//! walks each nested message twice (once for its length, once to write it)
//! through the general field code, and the three messages of a step cost
//! a fifth of the MCAP replay's filter thread that way (bench/README.md,
//! "MCAP output"). These messages nest three deep with a handful of doubles,
//! so their lengths are known from which doubles are zero. The tests
//! compare every byte with the crate's encoder.

/// A length-delimited field's wire type.
const LEN: u8 = 2;
/// A `double` field's wire type (64-bit).
const I64: u8 = 1;
/// A varint field's wire type.
const VARINT: u8 = 0;

/// A field's key: its number and wire type (every number here is below 16: one byte).
fn key(field: u8, wire: u8) -> u8 {
    field << 3 | wire
}

fn varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn varint_len(v: u64) -> usize {
    // 1 byte per 7 bits, at least one.
    (64 - (v | 1).leading_zeros() as usize).div_ceil(7)
}

/// The length of a message of `values` as fields 1, 2, …: 9 bytes per non-zero value.
fn doubles_len(values: &[f64]) -> usize {
    9 * values.iter().filter(|v| **v != 0.0).count()
}

/// Field `field` holding a message of `values` as `double` fields 1, 2, … (a
/// `Vector3` or a `Quaternion`).
fn doubles(out: &mut Vec<u8>, field: u8, values: &[f64]) {
    out.push(key(field, LEN));
    varint(out, doubles_len(values) as u64);
    for (number, v) in (1u8..).zip(values) {
        if *v != 0.0 {
            out.push(key(number, I64));
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
}

/// Field `field` holding a string, left out when empty.
fn string(out: &mut Vec<u8>, field: u8, s: &str) {
    if s.is_empty() {
        return;
    }
    out.push(key(field, LEN));
    varint(out, s.len() as u64);
    out.extend_from_slice(s.as_bytes());
}

/// Field 1 holding a `google.protobuf.Timestamp` (`seconds` an `int64`,
/// `nanos` an `int32`), as Foxglove's `Timestamp` is written.
fn timestamp(out: &mut Vec<u8>, sec: u32, nsec: u32) {
    let (sec, nsec) = (u64::from(sec), u64::from(nsec));
    let field_len = |v: u64| if v == 0 { 0 } else { 1 + varint_len(v) };
    out.push(key(1, LEN));
    varint(out, (field_len(sec) + field_len(nsec)) as u64);
    for (number, v) in [(1, sec), (2, nsec)] {
        if v != 0 {
            out.push(key(number, VARINT));
            varint(out, v);
        }
    }
}

/// Appends a `foxglove.PoseInFrame` at (`sec`, `nsec`) in `frame_id`:
/// position `p` (x, y, z), orientation `q` (x, y, z, w).
pub(crate) fn pose_in_frame(
    out: &mut Vec<u8>,
    (sec, nsec): (u32, u32),
    frame_id: &str,
    p: &[f64; 3],
    q: &[f64; 4],
) {
    timestamp(out, sec, nsec);
    string(out, 2, frame_id);
    // Pose { position: 1, orientation: 2 }, both always present.
    let (lp, lq) = (doubles_len(p), doubles_len(q));
    out.push(key(3, LEN));
    varint(
        out,
        (2 + varint_len(lp as u64) + lp + varint_len(lq as u64) + lq) as u64,
    );
    doubles(out, 1, p);
    doubles(out, 2, q);
}

/// Appends a `foxglove.FrameTransform` at (`sec`, `nsec`) from `parent` to
/// `child`: translation `t` (x, y, z), rotation `q` (x, y, z, w).
pub(crate) fn frame_transform(
    out: &mut Vec<u8>,
    (sec, nsec): (u32, u32),
    parent: &str,
    child: &str,
    t: &[f64; 3],
    q: &[f64; 4],
) {
    timestamp(out, sec, nsec);
    string(out, 2, parent);
    string(out, 3, child);
    doubles(out, 4, t);
    doubles(out, 5, q);
}

#[cfg(test)]
mod tests {
    use super::*;
    use foxglove::Encode as _;
    use foxglove::messages::{FrameTransform, Pose, PoseInFrame, Quaternion, Timestamp, Vector3};

    /// Values that exercise every branch: zeros (left out), negative zero
    /// (a default too), tiny and huge doubles, NaN (not a default).
    const VALUES: [f64; 7] = [0.0, -0.0, 1.5, -2.25e-300, 7.0e300, f64::NAN, 0.1];
    const TIMES: [(u32, u32); 6] = [
        (0, 0),
        (0, 1),
        (1, 0),
        (127, 128),
        (1_700_000_000, 999_999_999),
        (u32::MAX, 16_383),
    ];

    fn vector(v: [f64; 3]) -> Vector3 {
        Vector3 {
            x: v[0],
            y: v[1],
            z: v[2],
        }
    }

    fn quaternion(q: [f64; 4]) -> Quaternion {
        Quaternion {
            x: q[0],
            y: q[1],
            z: q[2],
            w: q[3],
        }
    }

    /// Every combination of a few values over (x, y, z, w), and each time.
    fn cases() -> impl Iterator<Item = ((u32, u32), [f64; 3], [f64; 4])> {
        let n = VALUES.len();
        (0..n.pow(4)).map(move |k| {
            let pick = |i: u32| VALUES[(k / n.pow(i)) % n];
            let q = [pick(0), pick(1), pick(2), pick(3)];
            let p = [pick(3), pick(1), pick(0)];
            (TIMES[k % TIMES.len()], p, q)
        })
    }

    #[test]
    fn pose_in_frame_is_what_the_foxglove_crate_writes() {
        for (frame_id, ((sec, nsec), p, q)) in ["odom", "", "a_longer_frame_name"]
            .into_iter()
            .cycle()
            .zip(cases())
        {
            let msg = PoseInFrame {
                timestamp: Some(Timestamp::new(sec, nsec)),
                frame_id: frame_id.to_owned(),
                pose: Some(Pose {
                    position: Some(vector(p)),
                    orientation: Some(quaternion(q)),
                }),
            };
            let mut want = Vec::new();
            msg.encode(&mut want).expect("a Vec grows");
            let mut got = Vec::new();
            pose_in_frame(&mut got, (sec, nsec), frame_id, &p, &q);
            assert_eq!(got, want, "{msg:?}");
        }
    }

    #[test]
    fn frame_transform_is_what_the_foxglove_crate_writes() {
        for ((sec, nsec), t, q) in cases() {
            let msg = FrameTransform {
                timestamp: Some(Timestamp::new(sec, nsec)),
                parent_frame_id: "odom".to_owned(),
                child_frame_id: "base_link".to_owned(),
                translation: Some(vector(t)),
                rotation: Some(quaternion(q)),
            };
            let mut want = Vec::new();
            msg.encode(&mut want).expect("a Vec grows");
            let mut got = Vec::new();
            frame_transform(&mut got, (sec, nsec), "odom", "base_link", &t, &q);
            assert_eq!(got, want, "{msg:?}");
        }
    }

    #[test]
    fn varint_lengths_match_the_written_varints() {
        for v in [
            0,
            1,
            127,
            128,
            16_383,
            16_384,
            u64::from(u32::MAX),
            u64::MAX,
        ] {
            let mut out = Vec::new();
            varint(&mut out, v);
            assert_eq!(out.len(), varint_len(v), "{v}");
        }
    }
}
