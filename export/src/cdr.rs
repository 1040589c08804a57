//! ROS 2 messages in CDR: `nav_msgs/msg/Odometry`, `tf2_msgs/msg/TFMessage`
//! and Foxglove's `foxglove_msgs/msg/PoseInFrame` and `FrameTransform` (the
//! Foxglove schemas in their ROS 2 form, which Foxglove displays as it does
//! their protobuf form), with the `ros2msg` schema texts MCAP readers
//! (`ros2 bag`, `rosbags`, `mcap-ros2-support`, Foxglove) decode them with.
//!
//! Every channel is CDR so that a file is a valid MCAP `ros2` profile file:
//! `ros2 bag play` (Humble, Jazzy) refuses a file whose channels mix
//! serialisation formats even when told to play only `/odom` and `/tf`, and
//! `rosbags`' reader fails on a protobuf schema (binary, not `ros2msg` text).
//!
//! Hand-encoded, on purpose: both messages have a fixed layout of a few
//! strings and doubles, and the one crate that writes CDR (`cdr`, through
//! serde) allocates a `Vec` per message and cannot serialise the
//! `float64[36]` covariances (serde stops at arrays of 32). Written here into
//! a reused buffer, an `Odometry` costs about as much as copying its 700
//! bytes. The layout is XCDR1 little-endian as ROS 2's middlewares write it:
//! the 4-byte encapsulation header `00 01 00 00`, then each primitive aligned
//! to its own size counted from the end of that header, strings as a `u32`
//! length with the terminating NUL included.

/// Schema name of the odometry messages.
pub const ODOMETRY_SCHEMA_NAME: &str = "nav_msgs/msg/Odometry";

/// Schema name of the transform messages.
pub const TF_SCHEMA_NAME: &str = "tf2_msgs/msg/TFMessage";

/// Schema name of the Foxglove pose messages.
pub const POSE_IN_FRAME_SCHEMA_NAME: &str = "foxglove_msgs/msg/PoseInFrame";

/// Schema name of the Foxglove transform messages.
pub const FRAME_TRANSFORM_SCHEMA_NAME: &str = "foxglove_msgs/msg/FrameTransform";

/// The separator between a `ros2msg` schema's definitions.
const SEP: &str =
    "================================================================================\n";

const HEADER: &str = "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n";
const TIME: &str = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n";
const VECTOR3: &str = "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n";
const QUATERNION: &str =
    "MSG: geometry_msgs/Quaternion\nfloat64 x\nfloat64 y\nfloat64 z\nfloat64 w\n";
const POSE: &str =
    "MSG: geometry_msgs/Pose\ngeometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n";
const POINT: &str = "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n";

/// The `ros2msg` schema of canodom's quality message.
pub fn quality_schema() -> String {
    "# ODOM_QUALITY of the pose sample at a filter step, and the pipeline's counts so far.\n\
     bool pose_valid\nbool rear_stale\nbool front_stale\nbool steer_stale\n\
     bool counter_fault\nbool checksum_fault\nbool gate_reject\nbool nominal_params\n\
     bool input_implausible\n\
     uint16 quality # the flags as ODOM_QUALITY's bits, POSE_VALID in bit 0, INPUT_IMPLAUSIBLE in bit 8\n\
     float64 speed_mps\nfloat64 yaw_rate_radps\nfloat64 pos_std_m\nfloat64 heading_std_rad\n\
     uint64 frames\nuint64 used\nuint64 steps\nuint64 steps_without_front\n\
     uint64 gate_kept_rear\nuint64 gate_used_front\n"
        .to_owned()
}

/// The `ros2msg` schema of canodom's gate message.
pub fn gate_schema() -> String {
    "# What the filter's correction window did at a step: open (inside a window), rear_only,\n\
     # no_front (front or steering stale), accepted (front and rear agree), kept_rear or\n\
     # used_front (the gate rejected the window and blamed a front or a rear wheel).\n\
     string correction\nbool rejected\n"
        .to_owned()
}

/// The `ros2msg` schema of canodom's calibration message.
pub fn calibration_schema() -> String {
    [
        "# The vehicle parameters in use; param_version 0: the configuration's nominal ones.\n\
         uint16 param_version\nbool nominal\nfloat64 wheelbase_m\nfloat64 rear_tread_m\n\
         float64 front_tread_m\n\
         float64[4] wheel_diameter_m # rear left, rear right, front left, front right\n\
         # The drift watch (#46): refits judged (0: none yet, or a replay); drift while any\n\
         # parameter is flagged (CALIB_STATUS DRIFT); drift_candidate while a learnt set is\n\
         # offered for COMMIT (DRIFT_CANDIDATE); the distance driven at the last refit; the\n\
         # flagged parameters; and what the last refit learnt of each parameter it read.\n\
         uint64 drift_refits\nbool drift\nbool drift_candidate\nfloat64 drift_distance_m\n\
         string[] drift_flagged\ncanodom_msgs/DriftReading[] drift_readings\n\
         # The guided calibration's phase: idle, positioning, recording, awaiting_end_pose,\n\
         # ready, computing or computed (a replay has no session: idle).\n\
         string session\n",
        "MSG: canodom_msgs/DriftReading\n\
         # The learnt value with its sigma and the value in use, in the parameter's unit\n\
         # (relative ones relative to the set the drive was recorded with).\n\
         string parameter\nfloat64 learnt\nfloat64 sigma\nfloat64 in_use\nbool flagged\n",
    ]
    .join(SEP)
}

/// The `ros2msg` schema of canodom's raw-frame message.
pub fn can_schema() -> String {
    [
        "# The CAN frames received since the previous filter step, the step's own last.\n\
         canodom_msgs/CanFrame[] frames\n",
        "MSG: canodom_msgs/CanFrame\nbuiltin_interfaces/Time stamp\nuint32 id\nbool extended\nuint8[] data\n",
        TIME,
    ]
    .join(SEP)
}

/// The `ros2msg` schema of `nav_msgs/msg/Odometry` with every type it uses.
pub fn odometry_schema() -> String {
    [
        "std_msgs/Header header\nstring child_frame_id\n\
         geometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n",
        HEADER,
        TIME,
        "MSG: geometry_msgs/PoseWithCovariance\ngeometry_msgs/Pose pose\nfloat64[36] covariance\n",
        POSE,
        POINT,
        QUATERNION,
        "MSG: geometry_msgs/TwistWithCovariance\ngeometry_msgs/Twist twist\nfloat64[36] covariance\n",
        "MSG: geometry_msgs/Twist\ngeometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n",
        VECTOR3,
    ]
    .join(SEP)
}

/// The `ros2msg` schema of `tf2_msgs/msg/TFMessage` with every type it uses.
pub fn tf_schema() -> String {
    [
        "geometry_msgs/TransformStamped[] transforms\n",
        "MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\n\
         geometry_msgs/Transform transform\n",
        HEADER,
        TIME,
        "MSG: geometry_msgs/Transform\ngeometry_msgs/Vector3 translation\n\
         geometry_msgs/Quaternion rotation\n",
        VECTOR3,
        QUATERNION,
    ]
    .join(SEP)
}

/// The `ros2msg` schema of `foxglove_msgs/msg/PoseInFrame` (Foxglove's
/// schema as its ROS 2 package `foxglove_msgs` defines it) with every type it
/// uses.
pub fn pose_in_frame_schema() -> String {
    [
        "# A timestamped pose for an object or reference frame in 3D space (Foxglove).\n\
         builtin_interfaces/Time timestamp\nstring frame_id\ngeometry_msgs/Pose pose\n",
        TIME,
        POSE,
        POINT,
        QUATERNION,
    ]
    .join(SEP)
}

/// The `ros2msg` schema of `foxglove_msgs/msg/FrameTransform` with every
/// type it uses.
pub fn frame_transform_schema() -> String {
    [
        "# A transform between two reference frames in 3D space (Foxglove).\n\
         builtin_interfaces/Time timestamp\nstring parent_frame_id\nstring child_frame_id\n\
         geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n",
        TIME,
        VECTOR3,
        QUATERNION,
    ]
    .join(SEP)
}

/// A ROS 2 time: seconds and nanoseconds since the Unix epoch.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RosTime {
    /// Whole seconds.
    pub sec: i32,
    /// Nanoseconds within the second.
    pub nanosec: u32,
}

impl RosTime {
    /// The time of `t_ns` nanoseconds since the epoch (seconds saturate at `i32`).
    pub fn from_nanos(t_ns: u64) -> Self {
        Self {
            sec: i32::try_from(t_ns / 1_000_000_000).unwrap_or(i32::MAX),
            nanosec: (t_ns % 1_000_000_000) as u32,
        }
    }
}

/// What an `Odometry` message carries (REP-103: metres, radians, x forward,
/// y left, z up; pose in `frame_id`, twist in `child_frame_id`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Odometry<'a> {
    /// The header's stamp.
    pub stamp: RosTime,
    /// The pose's frame (`odom`).
    pub frame_id: &'a str,
    /// The twist's frame, the vehicle (`base_link`).
    pub child_frame_id: &'a str,
    /// Position x, y, z.
    pub position: [f64; 3],
    /// Orientation quaternion x, y, z, w.
    pub orientation: [f64; 4],
    /// Pose covariance, row-major over (x, y, z, roll, pitch, yaw).
    pub pose_covariance: &'a [f64; 36],
    /// Linear velocity x, y, z in the child frame.
    pub linear: [f64; 3],
    /// Angular velocity x, y, z in the child frame.
    pub angular: [f64; 3],
    /// Twist covariance, row-major over (vx, vy, vz, wx, wy, wz).
    pub twist_covariance: &'a [f64; 36],
}

/// A CDR writer appending to a buffer.
pub(crate) struct Cdr<'a> {
    buf: &'a mut Vec<u8>,
    /// Where the payload starts (after the encapsulation header): alignment counts from here.
    origin: usize,
}

impl<'a> Cdr<'a> {
    #[inline]
    pub(crate) fn new(buf: &'a mut Vec<u8>) -> Self {
        buf.extend_from_slice(&[0x00, 0x01, 0x00, 0x00]);
        let origin = buf.len();
        Self { buf, origin }
    }

    #[inline]
    fn align(&mut self, n: usize) {
        let pad = (n - (self.buf.len() - self.origin) % n) % n;
        self.buf.resize(self.buf.len() + pad, 0);
    }

    #[inline]
    pub(crate) fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    #[inline]
    pub(crate) fn u16(&mut self, v: u16) {
        self.align(2);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    #[inline]
    pub(crate) fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    #[inline]
    pub(crate) fn u64s(&mut self, values: &[u64]) {
        self.align(8);
        if cfg!(target_endian = "little") {
            self.buf.extend_from_slice(bytemuck::cast_slice(values));
        } else {
            for v in values {
                self.buf.extend_from_slice(&v.to_le_bytes());
            }
        }
    }

    /// A `uint8[]`: length, then the bytes.
    #[inline]
    pub(crate) fn bytes(&mut self, b: &[u8]) {
        self.u32(b.len() as u32);
        self.buf.extend_from_slice(b);
    }

    #[inline]
    pub(crate) fn time(&mut self, t: RosTime) {
        self.align(4);
        self.buf.extend_from_slice(&t.sec.to_le_bytes());
        self.buf.extend_from_slice(&t.nanosec.to_le_bytes());
    }

    #[inline]
    pub(crate) fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }

    /// A `string[]`: length, then the strings.
    pub(crate) fn strings<'s>(&mut self, values: impl ExactSizeIterator<Item = &'s str>) {
        self.u32(values.len() as u32);
        for v in values {
            self.string(v);
        }
    }

    /// Doubles. On a little-endian host their bytes are already CDR's: one
    /// copy of the slice (pushed value by value, an `Odometry`'s 85 doubles
    /// were most of its encoding time).
    #[inline]
    pub(crate) fn f64s(&mut self, values: &[f64]) {
        self.align(8);
        if cfg!(target_endian = "little") {
            self.buf.extend_from_slice(bytemuck::cast_slice(values));
        } else {
            for v in values {
                self.buf.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
}

/// Appends `msg` as a CDR `nav_msgs/msg/Odometry` to `buf`.
pub fn encode_odometry(msg: &Odometry<'_>, buf: &mut Vec<u8>) {
    let mut w = Cdr::new(buf);
    w.time(msg.stamp);
    w.string(msg.frame_id);
    w.string(msg.child_frame_id);
    w.f64s(&msg.position);
    w.f64s(&msg.orientation);
    w.f64s(msg.pose_covariance);
    w.f64s(&msg.linear);
    w.f64s(&msg.angular);
    w.f64s(msg.twist_covariance);
}

/// One `geometry_msgs/TransformStamped`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transform<'a> {
    /// The header's stamp.
    pub stamp: RosTime,
    /// The parent frame.
    pub frame_id: &'a str,
    /// The child frame.
    pub child_frame_id: &'a str,
    /// Translation x, y, z of the child's origin in the parent.
    pub translation: [f64; 3],
    /// Rotation quaternion x, y, z, w.
    pub rotation: [f64; 4],
}

/// Appends a CDR `tf2_msgs/msg/TFMessage` of `transforms` to `buf`.
pub fn encode_tf(transforms: &[Transform<'_>], buf: &mut Vec<u8>) {
    let mut w = Cdr::new(buf);
    w.u32(transforms.len() as u32);
    for t in transforms {
        transform_fields(&mut w, t);
    }
}

/// A transform's fields, laid out alike in a `geometry_msgs/TransformStamped`
/// (header stamp and frame, child frame, translation, rotation) and a
/// `foxglove_msgs/msg/FrameTransform`.
fn transform_fields(w: &mut Cdr<'_>, t: &Transform<'_>) {
    w.time(t.stamp);
    w.string(t.frame_id);
    w.string(t.child_frame_id);
    w.f64s(&t.translation);
    w.f64s(&t.rotation);
}

/// Appends a CDR `foxglove_msgs/msg/PoseInFrame` to `buf`: `position`
/// x, y, z and `orientation` x, y, z, w in `frame_id` at `stamp`.
pub fn encode_pose_in_frame(
    stamp: RosTime,
    frame_id: &str,
    position: &[f64; 3],
    orientation: &[f64; 4],
    buf: &mut Vec<u8>,
) {
    let mut w = Cdr::new(buf);
    w.time(stamp);
    w.string(frame_id);
    w.f64s(position);
    w.f64s(orientation);
}

/// Appends a CDR `foxglove_msgs/msg/FrameTransform` to `buf`: the child
/// frame's origin at `t.translation` and its orientation `t.rotation` in
/// the parent `t.frame_id`.
pub fn encode_frame_transform(t: &Transform<'_>, buf: &mut Vec<u8>) {
    transform_fields(&mut Cdr::new(buf), t);
}

/// A reader of a little-endian XCDR1 payload, field by field in its
/// schema's order: what a test or a tool needs to check a message this
/// crate wrote without a ROS 2 stack. Each call returns `None` past the
/// end (or for a string that is not UTF-8 and NUL-terminated) and then
/// stays there.
#[derive(Debug, Clone)]
pub struct CdrReader<'a> {
    payload: &'a [u8],
    at: usize,
}

impl<'a> CdrReader<'a> {
    /// A reader of `message`: the 4-byte encapsulation header, then the
    /// payload (alignment counts from the payload's start).
    pub fn new(message: &'a [u8]) -> Self {
        Self {
            payload: message.get(4..).unwrap_or_default(),
            at: 0,
        }
    }

    /// `n` bytes at the next multiple of `align`.
    pub fn take(&mut self, n: usize, align: usize) -> Option<&'a [u8]> {
        let start = self.at.next_multiple_of(align.max(1));
        let bytes = self.payload.get(start..start.checked_add(n)?)?;
        self.at = start + n;
        Some(bytes)
    }

    /// A `uint8` (or `bool`).
    pub fn u8(&mut self) -> Option<u8> {
        self.take(1, 1).map(|b| b[0])
    }

    /// A `uint16`.
    pub fn u16(&mut self) -> Option<u16> {
        Some(u16::from_le_bytes(self.take(2, 2)?.try_into().ok()?))
    }

    /// A `uint32` (and a sequence's length).
    pub fn u32(&mut self) -> Option<u32> {
        Some(u32::from_le_bytes(self.take(4, 4)?.try_into().ok()?))
    }

    /// A `uint64`.
    pub fn u64(&mut self) -> Option<u64> {
        Some(u64::from_le_bytes(self.take(8, 8)?.try_into().ok()?))
    }

    /// A `float64`.
    pub fn f64(&mut self) -> Option<f64> {
        Some(f64::from_le_bytes(self.take(8, 8)?.try_into().ok()?))
    }

    /// A `string`: its length with the NUL, the bytes, the NUL.
    pub fn string(&mut self) -> Option<String> {
        let n = usize::try_from(self.u32()?).ok()?;
        let (text, nul) = self.take(n, 1)?.split_last().map(|(l, t)| (t, *l))?;
        (nul == 0).then_some(())?;
        String::from_utf8(text.to_vec()).ok()
    }

    /// A `string[]`.
    pub fn strings(&mut self) -> Option<Vec<String>> {
        (0..self.u32()?).map(|_| self.string()).collect()
    }

    /// Whether every byte of the payload has been read.
    pub fn at_end(&self) -> bool {
        self.at == self.payload.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const POSE_COVARIANCE: [f64; 36] = {
        let mut c = [0.0; 36];
        c[0] = 1.5;
        c
    };
    const TWIST_COVARIANCE: [f64; 36] = {
        let mut c = [0.0; 36];
        c[35] = 2.5;
        c
    };

    fn odometry() -> Odometry<'static> {
        Odometry {
            stamp: RosTime { sec: 7, nanosec: 9 },
            frame_id: "odom",
            child_frame_id: "base_link",
            position: [1.0, 2.0, 0.0],
            orientation: [0.0, 0.0, 0.5, 0.75],
            pose_covariance: &POSE_COVARIANCE,
            linear: [3.0, 0.0, 0.0],
            angular: [0.0, 0.0, 4.0],
            twist_covariance: &TWIST_COVARIANCE,
        }
    }

    fn f64_at(buf: &[u8], at: usize) -> f64 {
        f64::from_le_bytes(buf[at..at + 8].try_into().unwrap())
    }

    #[test]
    fn odometry_fields_sit_where_xcdr1_puts_them() {
        let mut buf = Vec::new();
        encode_odometry(&odometry(), &mut buf);
        // Header 4, stamp 8, "odom\0" as 4+5 → 21, pad to 24 (20 after the
        // encapsulation header), "base_link\0" 4+10 → 34 (payload 30), pad to
        // payload 32 for the first double: byte 36.
        assert_eq!(&buf[..4], &[0, 1, 0, 0]);
        assert_eq!(&buf[4..8], &7i32.to_le_bytes());
        assert_eq!(&buf[8..12], &9u32.to_le_bytes());
        assert_eq!(&buf[12..16], &5u32.to_le_bytes());
        assert_eq!(&buf[16..21], b"odom\0");
        assert_eq!(&buf[24..28], &10u32.to_le_bytes());
        assert_eq!(&buf[28..38], b"base_link\0");
        let p = 4 + 40;
        assert_eq!(f64_at(&buf, p), 1.0);
        assert_eq!(f64_at(&buf, p + 8), 2.0);
        assert_eq!(f64_at(&buf, p + 5 * 8), 0.5);
        assert_eq!(f64_at(&buf, p + 7 * 8), 1.5);
        let twist = p + 7 * 8 + 36 * 8;
        assert_eq!(f64_at(&buf, twist), 3.0);
        assert_eq!(f64_at(&buf, twist + 5 * 8), 4.0);
        assert_eq!(f64_at(&buf, twist + 6 * 8 + 35 * 8), 2.5);
        assert_eq!(buf.len(), twist + 6 * 8 + 36 * 8);
    }

    #[test]
    fn tf_message_is_a_sequence_of_transforms() {
        let mut buf = Vec::new();
        let t = Transform {
            stamp: RosTime::from_nanos(3_000_000_005),
            frame_id: "odom",
            child_frame_id: "base_link",
            translation: [1.0, 2.0, 0.0],
            rotation: [0.0, 0.0, 0.0, 1.0],
        };
        encode_tf(&[t], &mut buf);
        assert_eq!(&buf[4..8], &1u32.to_le_bytes());
        assert_eq!(&buf[8..12], &3i32.to_le_bytes());
        assert_eq!(&buf[12..16], &5u32.to_le_bytes());
        // "odom\0" ends at payload 21, "base_link\0" at payload 38; doubles at 40.
        assert_eq!(f64_at(&buf, 4 + 40), 1.0);
        assert_eq!(f64_at(&buf, 4 + 40 + 6 * 8), 1.0);
        assert_eq!(buf.len(), 4 + 40 + 7 * 8);
    }

    #[test]
    fn foxglove_pose_and_transform_sit_where_xcdr1_puts_them() {
        let mut buf = Vec::new();
        let stamp = RosTime::from_nanos(3_000_000_005);
        encode_pose_in_frame(
            stamp,
            "odom",
            &[1.0, 2.0, 0.0],
            &[0.0, 0.0, 0.5, 0.75],
            &mut buf,
        );
        assert_eq!(&buf[4..8], &3i32.to_le_bytes());
        assert_eq!(&buf[8..12], &5u32.to_le_bytes());
        assert_eq!(&buf[12..16], &5u32.to_le_bytes());
        assert_eq!(&buf[16..21], b"odom\0");
        // "odom\0" ends at payload 17; the doubles start at payload 24.
        assert_eq!(f64_at(&buf, 4 + 24), 1.0);
        assert_eq!(f64_at(&buf, 4 + 24 + 6 * 8), 0.75);
        assert_eq!(buf.len(), 4 + 24 + 7 * 8);

        let mut buf = Vec::new();
        let t = Transform {
            stamp,
            frame_id: "odom",
            child_frame_id: "base_link",
            translation: [1.0, 2.0, 0.0],
            rotation: [0.0, 0.0, 0.0, 1.0],
        };
        encode_frame_transform(&t, &mut buf);
        // As one TFMessage transform without the sequence length: "base_link\0"
        // ends at payload 34, doubles at 40.
        assert_eq!(&buf[24..28], &10u32.to_le_bytes());
        assert_eq!(&buf[28..38], b"base_link\0");
        assert_eq!(f64_at(&buf, 4 + 40), 1.0);
        assert_eq!(f64_at(&buf, 4 + 40 + 6 * 8), 1.0);
        assert_eq!(buf.len(), 4 + 40 + 7 * 8);
    }

    #[test]
    fn schemas_define_every_type_they_use() {
        for schema in [
            calibration_schema(),
            odometry_schema(),
            tf_schema(),
            pose_in_frame_schema(),
            frame_transform_schema(),
        ] {
            let defined: Vec<&str> = schema
                .lines()
                .filter_map(|l| l.strip_prefix("MSG: "))
                .collect();
            for line in schema.lines() {
                let Some(ty) = line.split_whitespace().next() else {
                    continue;
                };
                let ty = ty.trim_end_matches("[]").split('[').next().unwrap_or(ty);
                if ty.contains('/') && !line.starts_with("MSG: ") {
                    assert!(defined.contains(&ty), "{ty} is used but not defined");
                }
            }
        }
    }

    #[test]
    fn the_reader_reads_what_the_writer_wrote_and_stops_at_the_end() {
        let mut buf = Vec::new();
        let mut w = Cdr::new(&mut buf);
        w.u8(7);
        w.u16(0x1234);
        w.u32(5);
        w.f64s(&[1.5]);
        w.string("drift");
        w.strings(["a", "bc"].into_iter());
        let mut r = CdrReader::new(&buf);
        assert_eq!(r.u8(), Some(7));
        assert_eq!(r.u16(), Some(0x1234));
        assert_eq!(r.u32(), Some(5));
        assert_eq!(r.f64(), Some(1.5));
        assert_eq!(r.string().as_deref(), Some("drift"));
        assert_eq!(r.strings(), Some(vec!["a".to_owned(), "bc".to_owned()]));
        assert!(r.at_end());
        assert_eq!(r.u8(), None);
        // A cut message, a string without its NUL: None, no panic.
        assert_eq!(CdrReader::new(&buf[..buf.len() - 1]).strings(), None);
        let mut bad = Vec::new();
        let mut w = Cdr::new(&mut bad);
        w.u32(2);
        w.u8(b'x');
        w.u8(b'y');
        assert_eq!(CdrReader::new(&bad).string(), None);
        assert_eq!(CdrReader::new(&[0, 1]).u8(), None);
    }
}
