//! The channels a recording has and the encoding of one step into a message
//! on each: Foxglove `PoseInFrame` and `FrameTransform` (their ROS 2 form,
//! `foxglove_msgs`), ROS 2 `Odometry` and `TFMessage`, and canodom's own
//! quality, gate, calibration and raw-frame messages, all in CDR with
//! `ros2msg` schemas ([`crate::cdr`], which says why every channel is CDR:
//! the Foxglove messages were protobuf first). (The own messages
//! were JSON first: a third of the file's bytes and a tenth of its time went
//! to their text; in CDR they are a third of the size, and Foxglove and the
//! ROS 2 readers decode them from the schema in the file all the same.)
//!
//! A step's nine messages are written straight into the sink's buffer
//! ([`MessageSink`]), without allocating.

use crate::cdr::{self, Cdr, Odometry, RosTime, Transform};
use crate::sample::{DriftState, FrameRef, FrameSource, OwnedFrame, StepSample};
use canodom_fusion::VehicleParams;
use canodom_fusion::Wheel;

/// The fixed frame the pose is in (REP-105).
pub const ODOM_FRAME: &str = "odom";
/// The vehicle's frame (REP-105).
pub const BASE_FRAME: &str = "base_link";

/// Variance given to what the planar filter does not estimate (z, roll,
/// pitch; lateral, vertical and roll/pitch rates): "unknown", the value ROS's
/// `diff_drive_controller` uses for the same components.
pub const UNKNOWN_VARIANCE: f64 = 1e6;

/// Added to the estimated variances so every covariance is positive
/// definite (readers such as `robot_localization` invert them); at a
/// standstill the filter's own can be exactly zero, and its covariance is
/// singular at times (rank 2 at the real RAV4 drive's second step).
///
/// 1e-8 (0.1 mm, 0.1 mrad standard deviation) because a reader computes
/// eigenvalues of the whole 6×6 matrix in double precision, whose rounding
/// is about ε·1e6 ≈ 2e-10 with the [`UNKNOWN_VARIANCE`]s in it: with a floor
/// of 1e-12, numpy read that RAV4 step's pose covariance as having the
/// eigenvalue −1.9e-11. Larger covariances get [`RELATIVE_VARIANCE_FLOOR`].
pub const VARIANCE_FLOOR: f64 = 1e-8;

/// The floor relative to the largest estimated variance (about 450 ε), for
/// covariances so large that their own rounding exceeds [`VARIANCE_FLOOR`].
pub const RELATIVE_VARIANCE_FLOOR: f64 = 1e-13;

/// What [`pose_covariance`] and [`twist_covariance`] add to the estimated
/// variances, whose largest is `largest_variance`.
fn variance_floor(largest_variance: f64) -> f64 {
    VARIANCE_FLOOR.max(RELATIVE_VARIANCE_FLOOR * largest_variance)
}

/// One channel of a recording.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Topic {
    /// The fused pose, Foxglove's `PoseInFrame` (`foxglove_msgs`) in `odom`.
    Pose,
    /// Rear-wheel-only odometry, Foxglove's `PoseInFrame` in `odom`.
    RearOdometry,
    /// `odom` → `base_link`, Foxglove's `FrameTransform`.
    Transform,
    /// The pose sample's quality flags, standard deviations and the
    /// pipeline's counts (CDR, `canodom_msgs/msg/…`).
    Quality,
    /// The correction window's gate decision (CDR, `canodom_msgs/msg/…`).
    Gate,
    /// The parameter set in use (CDR, `canodom_msgs/msg/…`).
    Calibration,
    /// The raw CAN frames since the previous step, the step's own last (CDR, `canodom_msgs/msg/…`).
    Can,
    /// The fused pose and twist with covariances, `nav_msgs/msg/Odometry` (CDR).
    RosOdometry,
    /// `odom` → `base_link`, `tf2_msgs/msg/TFMessage` (CDR).
    RosTf,
}

impl Topic {
    /// Every channel, in channel-id order.
    pub const ALL: [Topic; 9] = [
        Topic::Pose,
        Topic::RearOdometry,
        Topic::Transform,
        Topic::Quality,
        Topic::Gate,
        Topic::Calibration,
        Topic::Can,
        Topic::RosOdometry,
        Topic::RosTf,
    ];

    /// The channel's topic name.
    pub fn name(self) -> &'static str {
        match self {
            Topic::Pose => "/canodom/pose",
            Topic::RearOdometry => "/canodom/rear_odometry",
            Topic::Transform => "/canodom/transform",
            Topic::Quality => "/canodom/quality",
            Topic::Gate => "/canodom/gate",
            Topic::Calibration => "/canodom/calibration",
            Topic::Can => "/canodom/can",
            Topic::RosOdometry => "/odom",
            Topic::RosTf => "/tf",
        }
    }

    /// The messages' encoding (an MCAP well-known message encoding): CDR
    /// for every channel, as MCAP's `ros2` profile wants.
    pub fn message_encoding(self) -> &'static str {
        "cdr"
    }

    /// The schema: name, encoding and data.
    pub fn schema(self) -> Schema {
        let ros = |name: &str, data: String| Schema {
            name: name.to_owned(),
            encoding: "ros2msg".to_owned(),
            data: data.into_bytes(),
        };
        match self {
            Topic::Pose | Topic::RearOdometry => {
                ros(cdr::POSE_IN_FRAME_SCHEMA_NAME, cdr::pose_in_frame_schema())
            }
            Topic::Transform => ros(
                cdr::FRAME_TRANSFORM_SCHEMA_NAME,
                cdr::frame_transform_schema(),
            ),
            Topic::Quality => ros("canodom_msgs/msg/Quality", cdr::quality_schema()),
            Topic::Gate => ros("canodom_msgs/msg/Gate", cdr::gate_schema()),
            Topic::Calibration => ros("canodom_msgs/msg/Calibration", cdr::calibration_schema()),
            Topic::Can => ros("canodom_msgs/msg/CanFrames", cdr::can_schema()),
            Topic::RosOdometry => ros(cdr::ODOMETRY_SCHEMA_NAME, cdr::odometry_schema()),
            Topic::RosTf => ros(cdr::TF_SCHEMA_NAME, cdr::tf_schema()),
        }
    }
}

/// A channel's schema.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Schema {
    /// The schema's name (`foxglove_msgs/msg/PoseInFrame`, `nav_msgs/msg/Odometry`).
    pub name: String,
    /// `ros2msg`.
    pub encoding: String,
    /// The schema itself.
    pub data: Vec<u8>,
}

/// Where a step's messages go. Each message is written straight into the
/// sink's own buffer (an MCAP chunk, a scratch buffer), not built in a
/// buffer of the encoder's and copied: that copy was a tenth of the MCAP
/// replay's filter thread.
pub trait MessageSink {
    /// Takes one message on `topic` at `t_ns` (ns since the Unix epoch),
    /// whose bytes `payload` appends to the buffer it is given. A sink
    /// cannot fail here: one that writes to a file or a socket does so
    /// later, and reports there.
    fn message(&mut self, topic: Topic, t_ns: u64, payload: impl FnOnce(&mut Vec<u8>));
}

/// A [`MessageSink`] handing each message's bytes to a closure, for sinks
/// that take a finished slice (the Foxglove live view).
pub struct SliceSink<F> {
    buf: Vec<u8>,
    take: F,
}

impl<F: FnMut(Topic, u64, &[u8])> SliceSink<F> {
    /// A sink calling `take(topic, t_ns, bytes)` for each message.
    pub fn new(take: F) -> Self {
        Self {
            buf: Vec::with_capacity(4096),
            take,
        }
    }
}

impl<F: FnMut(Topic, u64, &[u8])> MessageSink for SliceSink<F> {
    fn message(&mut self, topic: Topic, t_ns: u64, payload: impl FnOnce(&mut Vec<u8>)) {
        self.buf.clear();
        payload(&mut self.buf);
        (self.take)(topic, t_ns, &self.buf);
    }
}

/// What the calibration message says: parameter version, whether nominal,
/// the parameters, the session's phase, the drift watch's state.
type CalibrationKey = (u16, bool, VehicleParams, &'static str, Option<DriftState>);

/// Encodes steps into one message per [`Topic`].
#[derive(Debug)]
pub struct StepEncoder {
    /// Rear wheel distance noise (`[ekf] k_rear_m`): variance `k·|d|` per wheel.
    k_rear_m: f64,
    /// The calibration message of the parameters and phase last seen, kept while they stay.
    calibration: Option<(CalibrationKey, Vec<u8>)>,
    /// The frames of the current batch's tail, for the next step.
    pending: Vec<OwnedFrame>,
}

impl StepEncoder {
    /// An encoder whose twist covariance uses the filter's rear noise `k_rear_m`.
    pub fn new(k_rear_m: f64) -> Self {
        Self {
            k_rear_m,
            calibration: None,
            pending: Vec::new(),
        }
    }

    /// Keeps frames `from..` of `frames` for the next step (the tail of a
    /// batch after its last step).
    pub fn carry(&mut self, frames: &impl FrameSource, from: usize) {
        for i in from..frames.frame_count() {
            if let Some(f) = frames.frame(i) {
                self.pending.push(OwnedFrame::of(f));
            }
        }
    }

    /// Forgets the frames kept by [`Self::carry`] (a caller that hands each
    /// batch its carried frames itself starts every batch from none).
    pub fn forget_carried(&mut self) {
        self.pending.clear();
    }

    /// Encodes `sample` into one message per topic, in [`Topic::ALL`]'s
    /// order, each stamped with the step's time. The raw-frame message
    /// holds the frames carried over, then `frames[from..to]`. `params` is
    /// the parameter set in use.
    pub fn encode(
        &mut self,
        sample: &StepSample,
        params: &VehicleParams,
        frames: (&impl FrameSource, usize, usize),
        sink: &mut impl MessageSink,
    ) {
        let t_ns = (sample.t_unix_us.max(0) as u64) * 1000;
        let rt = RosTime::from_nanos(t_ns);
        let yaw = |heading_rad: f64| {
            let (s, c) = (0.5 * heading_rad).sin_cos();
            [0.0, 0.0, s, c]
        };
        let q = yaw(sample.fused.heading_rad);
        let pos = [sample.fused.x_m, sample.fused.y_m, 0.0];

        let transform = Transform {
            stamp: rt,
            frame_id: ODOM_FRAME,
            child_frame_id: BASE_FRAME,
            translation: pos,
            rotation: q,
        };
        sink.message(Topic::Pose, t_ns, |out| {
            cdr::encode_pose_in_frame(rt, ODOM_FRAME, &pos, &q, out);
        });
        sink.message(Topic::RearOdometry, t_ns, |out| {
            let rear = &sample.rear_only;
            let p = [rear.x_m, rear.y_m, 0.0];
            cdr::encode_pose_in_frame(rt, ODOM_FRAME, &p, &yaw(rear.heading_rad), out);
        });
        sink.message(Topic::Transform, t_ns, |out| {
            cdr::encode_frame_transform(&transform, out);
        });
        sink.message(Topic::Quality, t_ns, |out| quality_cdr(sample, out));
        sink.message(Topic::Gate, t_ns, |out| gate_cdr(sample, out));

        let key = (
            sample.output.param_version,
            sample.output.flags.nominal_params,
            *params,
            sample.calibration_phase,
            sample.drift,
        );
        let text = match &mut self.calibration {
            Some((k, text)) if *k == key => text,
            slot => {
                let mut text = Vec::new();
                calibration_cdr(&key, params, &mut text);
                &mut slot.insert((key, text)).1
            }
        };
        sink.message(Topic::Calibration, t_ns, |out| out.extend_from_slice(text));

        let (source, from, to) = frames;
        let pending = &mut self.pending;
        sink.message(Topic::Can, t_ns, |out| {
            can_cdr(
                pending
                    .iter()
                    .map(OwnedFrame::as_ref)
                    .chain((from..to).filter_map(|i| source.frame(i))),
                pending.len() + to.saturating_sub(from),
                out,
            );
        });
        pending.clear();

        sink.message(Topic::RosOdometry, t_ns, |out| {
            let twist = twist_covariance(
                self.k_rear_m,
                sample.rear_m,
                params.rear_tread_m(),
                sample.dt_s,
            );
            let pose = pose_covariance(&sample.covariance);
            cdr::encode_odometry(&odometry(sample, rt, q, &pose, &twist), out);
        });
        sink.message(Topic::RosTf, t_ns, |out| {
            cdr::encode_tf(&[transform], out);
        });
    }
}

/// The fused pose of `sample` as an `Odometry` (REP-103: the pose in `odom`,
/// the twist in `base_link`).
fn odometry<'a>(
    sample: &StepSample,
    stamp: RosTime,
    q: [f64; 4],
    pose_covariance: &'a [f64; 36],
    twist_covariance: &'a [f64; 36],
) -> Odometry<'a> {
    Odometry {
        stamp,
        frame_id: ODOM_FRAME,
        child_frame_id: BASE_FRAME,
        position: [sample.fused.x_m, sample.fused.y_m, 0.0],
        orientation: q,
        pose_covariance,
        linear: [sample.output.speed_mps, 0.0, 0.0],
        angular: [0.0, 0.0, sample.output.yaw_rate_radps],
        twist_covariance,
    }
}

/// The 6×6 pose covariance over (x, y, z, roll, pitch, yaw) of the filter's
/// (x, y, θ) covariance `p` (row-major): its nine entries in place, the
/// unestimated axes [`UNKNOWN_VARIANCE`].
pub fn pose_covariance(p: &[f64; 9]) -> [f64; 36] {
    let mut c = [0.0; 36];
    let axis = [0usize, 1, 5];
    let floor = variance_floor(p[0].max(p[4]).max(p[8]));
    for (i, &a) in axis.iter().enumerate() {
        for (j, &b) in axis.iter().enumerate() {
            // Symmetrised: the filter's P is symmetric up to rounding.
            c[a * 6 + b] = 0.5 * (p[i * 3 + j] + p[j * 3 + i]);
        }
        c[a * 6 + a] += floor;
    }
    for k in [2, 3, 4] {
        c[k * 6 + k] = UNKNOWN_VARIANCE;
    }
    c
}

/// The 6×6 twist covariance over (vx, vy, vz, wx, wy, wz) of a step of rear
/// wheel distances `rear_m` (left, right) over `dt_s`, from the filter's
/// input noise (§11): each wheel's distance has variance `k·|d|`, speed is
/// their mean and yaw rate their difference over the tread, both over `dt`.
/// With no interval yet (the first step) only the floor remains.
pub fn twist_covariance(k_rear_m: f64, rear_m: [f64; 2], tread_m: f64, dt_s: f64) -> [f64; 36] {
    let (vl, vr) = (k_rear_m * rear_m[0].abs(), k_rear_m * rear_m[1].abs());
    let inv_dt2 = if dt_s > 0.0 { 1.0 / (dt_s * dt_s) } else { 0.0 };
    let var_v = 0.25 * (vl + vr) * inv_dt2;
    let var_w = (vl + vr) / (tread_m * tread_m) * inv_dt2;
    let cov = 0.5 * (vr - vl) / tread_m * inv_dt2;
    let floor = variance_floor(var_v.max(var_w));
    let mut c = [0.0; 36];
    c[0] = var_v + floor;
    c[35] = var_w + floor;
    c[5] = cov;
    c[30] = cov;
    for k in [1, 2, 3, 4] {
        c[k * 6 + k] = UNKNOWN_VARIANCE;
    }
    c
}

fn quality_cdr(s: &StepSample, out: &mut Vec<u8>) {
    let f = s.output.flags;
    let mut w = Cdr::new(out);
    for on in f.in_order() {
        w.u8(u8::from(on));
    }
    w.u16(f.bits());
    w.f64s(&[
        s.output.speed_mps,
        s.output.yaw_rate_radps,
        s.output.pos_std_m,
        s.output.heading_std_rad,
    ]);
    let c = s.counts;
    w.u64s(&[
        c.frames,
        c.used,
        c.steps,
        c.steps_without_front,
        c.gate_kept_rear,
        c.gate_used_front,
    ]);
}

fn gate_cdr(s: &StepSample, out: &mut Vec<u8>) {
    use canodom_fusion::ekf::WindowOutcome;
    let mut w = Cdr::new(out);
    w.string(match s.correction {
        WindowOutcome::Open => "open",
        other => other.as_str(),
    });
    w.u8(u8::from(s.correction.is_rejected()));
}

fn calibration_cdr(key: &CalibrationKey, p: &VehicleParams, out: &mut Vec<u8>) {
    let &(version, nominal, _, phase, drift) = key;
    let mut w = Cdr::new(out);
    w.u16(version);
    w.u8(u8::from(nominal));
    w.f64s(&[p.wheelbase_m(), p.rear_tread_m(), p.front_tread_m()]);
    w.f64s(&Wheel::ALL.map(|wh| p.wheel_diameter_m(wh)));
    // No watch reads as one that has judged nothing: the fields are there
    // in every message, so a reader's schema never changes mid-file.
    let d = drift.unwrap_or_default();
    w.u64s(&[d.refits]);
    w.u8(u8::from(d.any_flagged()));
    w.u8(u8::from(d.candidate));
    w.f64s(&[d.distance_m]);
    let flagged: Vec<&str> = d.flagged().map(|q| q.name).collect();
    w.strings(flagged.iter().copied());
    // A sequence of messages, not one `float64[]` per column: an empty
    // `float64[]` is aligned by some readers and not by others.
    let read: Vec<_> = d
        .params()
        .filter_map(|q| q.reading.map(|r| (q, r)))
        .collect();
    w.u32(read.len() as u32);
    for (q, r) in read {
        w.string(q.name);
        w.f64s(&[r.learnt, r.sigma, r.in_use]);
        w.u8(u8::from(q.flagged));
    }
    // The session's phase stays the last field: readers find it from the end.
    w.string(phase);
}

fn can_cdr<'a>(frames: impl Iterator<Item = FrameRef<'a>>, count: usize, out: &mut Vec<u8>) {
    let mut w = Cdr::new(out);
    w.u32(count as u32);
    for f in frames {
        w.time(RosTime::from_nanos(f.timestamp.as_micros() * 1000));
        w.u32(f.id.raw());
        w.u8(u8::from(f.id.is_extended()));
        w.bytes(f.data);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn covariances_are_symmetric_with_a_positive_diagonal() {
        let p = [1e-4, 2e-5, 1e-6, 2.1e-5, 3e-4, 2e-6, 1e-6, 2e-6, 1e-5];
        let c = pose_covariance(&p);
        let t = twist_covariance(1e-5, [0.01, 0.012], 0.2, 0.01);
        for m in [c, t] {
            for i in 0..6 {
                assert!(m[i * 6 + i] > 0.0);
                for j in 0..6 {
                    assert_eq!(m[i * 6 + j], m[j * 6 + i]);
                }
            }
        }
        assert_eq!(c[1], 0.5 * (2e-5 + 2.1e-5));
        assert_eq!(c[35], 1e-5 + VARIANCE_FLOOR);
        // vr > vl: turning left adds to the yaw rate's and speed's covariance.
        assert!(t[5] > 0.0);
        assert!((t[0] - (0.25 * 1e-5 * 0.022 / 1e-4 + VARIANCE_FLOOR)).abs() < 1e-15);
    }

    /// The smallest eigenvalue of a 6×6 covariance as a reader computes it:
    /// in double precision, over the whole matrix (the unknown axes' 1e6
    /// included), as numpy's `eigvalsh` in `tests/check_mcap.py` does.
    fn smallest_eigenvalue(c: &[f64; 36]) -> f64 {
        nalgebra::Matrix6::from_row_slice(c)
            .symmetric_eigenvalues()
            .min()
    }

    #[test]
    fn a_singular_filter_covariance_still_reads_as_positive_definite() {
        // The filter's P at the second step of the real RAV4 drive
        // (data/comma2k19-rav4): rank 2. With a floor of 1e-12, numpy read
        // the Odometry's pose covariance's smallest eigenvalue as -1.9e-11.
        let p = [
            3.537_263_72e-7,
            8.907_956_15e-11,
            1.257_879_50e-9,
            8.907_956_15e-11,
            7.192_450_65e-10,
            2.030_481_34e-8,
            1.257_879_50e-9,
            2.030_481_34e-8,
            5.740_224_83e-7,
        ];
        let c = pose_covariance(&p);
        assert!(
            smallest_eigenvalue(&c) > 0.5 * VARIANCE_FLOOR,
            "{}",
            smallest_eigenvalue(&c)
        );
        assert!(nalgebra::Matrix6::from_row_slice(&c).cholesky().is_some());
    }

    proptest::proptest! {
        /// Any positive semi-definite filter covariance, singular or not, from
        /// a tenth of a millimetre to 300 km, gives Odometry covariances that a reader
        /// finds positive definite.
        #[test]
        fn every_covariance_reads_as_positive_definite(
            a in proptest::array::uniform9(-1.0f64..1.0),
            scale_exp in -5i32..12,
            rank in 0usize..=3,
            rear_m in proptest::array::uniform2(0.0f64..0.5),
        ) {
            // P = A Aᵀ with A's last columns zeroed: PSD of the chosen rank.
            let mut m = nalgebra::Matrix3::from_row_slice(&a) * 10f64.powi(scale_exp).sqrt();
            for j in rank..3 {
                m.set_column(j, &nalgebra::Vector3::zeros());
            }
            let p = m * m.transpose();
            let p: [f64; 9] = std::array::from_fn(|k| p[(k / 3, k % 3)]);
            let pose = pose_covariance(&p);
            proptest::prop_assert!(smallest_eigenvalue(&pose) > 0.0, "pose {:?}", pose);
            let twist = twist_covariance(1e-3, rear_m, 1.5, 0.01);
            proptest::prop_assert!(smallest_eigenvalue(&twist) > 0.0, "twist {:?}", twist);
        }
    }

    /// The drift fields and the session of a calibration message.
    #[derive(Debug, PartialEq)]
    struct Message {
        refits: u64,
        drift: bool,
        candidate: bool,
        distance_m: f64,
        flagged: Vec<String>,
        /// (parameter, learnt, σ, in use, flagged).
        readings: Vec<(String, f64, f64, f64, bool)>,
        session: String,
    }

    fn calibration_message(drift: Option<&DriftState>) -> Message {
        let p = VehicleParams::nominal(0.25, 0.30, 0.09, 1000).unwrap();
        let mut out = Vec::new();
        calibration_cdr(&(3, false, p, "idle", drift.copied()), &p, &mut out);
        let mut r = cdr::CdrReader::new(&out);
        assert_eq!(r.u16(), Some(3));
        r.u8();
        for _ in 0..7 {
            r.f64();
        }
        let d = (|| {
            Some(Message {
                refits: r.u64()?,
                drift: r.u8()? == 1,
                candidate: r.u8()? == 1,
                distance_m: r.f64()?,
                flagged: r.strings()?,
                readings: (0..r.u32()?)
                    .map(|_| Some((r.string()?, r.f64()?, r.f64()?, r.f64()?, r.u8()? == 1)))
                    .collect::<Option<_>>()?,
                session: r.string()?,
            })
        })()
        .expect("a whole calibration message");
        assert!(r.at_end(), "nothing after the session");
        d
    }

    #[test]
    fn the_calibration_message_carries_the_drift_watch_before_the_session() {
        use crate::sample::{DriftParam, DriftReading};
        let read = |name, flagged, learnt| DriftParam {
            name,
            flagged,
            reading: Some(DriftReading {
                learnt,
                sigma: 0.001,
                in_use: 1.0,
            }),
        };
        // A flag the last refit did not read (it stays until one clears
        // it) is flagged without a reading.
        let state = DriftState::new(
            4,
            1234.5,
            true,
            [
                read("speed_scale", false, 1.0005),
                read("rear_ratio", true, 1.01),
                DriftParam {
                    name: "yaw_bias",
                    flagged: true,
                    reading: None,
                },
            ],
        );
        assert_eq!(
            calibration_message(Some(&state)),
            Message {
                refits: 4,
                drift: true,
                candidate: true,
                distance_m: 1234.5,
                flagged: vec!["rear_ratio".into(), "yaw_bias".into()],
                readings: vec![
                    ("speed_scale".into(), 1.0005, 0.001, 1.0, false),
                    ("rear_ratio".into(), 1.01, 0.001, 1.0, true),
                ],
                session: "idle".into(),
            }
        );
        // No watch (a replay, or before the first refit): the same fields, empty.
        assert_eq!(
            calibration_message(None),
            Message {
                refits: 0,
                drift: false,
                candidate: false,
                distance_m: 0.0,
                flagged: vec![],
                readings: vec![],
                session: "idle".into(),
            }
        );
    }

    #[test]
    fn a_drift_state_keeps_at_most_its_fixed_number_of_parameters() {
        use crate::sample::{DRIFT_PARAMS, DriftParam};
        let p = DriftParam {
            name: "p",
            flagged: true,
            reading: None,
        };
        let d = DriftState::new(1, 0.0, false, std::iter::repeat_n(p, DRIFT_PARAMS + 2));
        assert_eq!(d.params().count(), DRIFT_PARAMS);
        assert!(d.any_flagged());
        assert!(!DriftState::default().any_flagged());
    }

    #[test]
    fn can_frames_are_a_sequence_with_time_id_and_payload() {
        let mut out = Vec::new();
        let frames = [FrameRef {
            timestamp: canodom_can::time::Timestamp::from_micros(1_700_000_000_000_001),
            id: canodom_can::frame::FrameId::standard(0x123).unwrap(),
            data: &[0x0a, 0xff],
        }];
        can_cdr(frames.into_iter(), 1, &mut out);
        let mut want = vec![0, 1, 0, 0, 1, 0, 0, 0];
        want.extend_from_slice(&1_700_000_000i32.to_le_bytes());
        want.extend_from_slice(&1000u32.to_le_bytes());
        want.extend_from_slice(&0x123u32.to_le_bytes());
        want.extend_from_slice(&[0, 0, 0, 0, 2, 0, 0, 0, 0x0a, 0xff]);
        assert_eq!(out, want);
    }
}
