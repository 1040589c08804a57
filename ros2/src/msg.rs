//! The ROS 2 messages canodom puts on DDS, in CDR (XCDR1, little-endian, as
//! ROS 2's middlewares write them), with their DDS type names.
//!
//! `nav_msgs/Odometry` and `tf2_msgs/TFMessage` are encoded by
//! [`canodom_export::cdr`] from the values [`canodom_export::encode`] gives
//! the MCAP recordings (the issue asks for "the same values as in MCAP": a
//! test here checks the bytes are the recording's, frame names aside).
//! `diagnostic_msgs/DiagnosticArray` and `sensor_msgs/NavSatFix` are
//! encoded here; `NavSatFix` is also decoded (a fix source from ROS 2).

use crate::{Error, Result};
use canodom_export::cdr::{self, Odometry, RosTime, Transform};
use canodom_export::encode::{pose_covariance, twist_covariance};
use canodom_export::sample::StepSample;

/// DDS type name of `nav_msgs/msg/Odometry` (ROS 2's `rosidl` mapping).
pub const ODOMETRY_TYPE: &str = "nav_msgs::msg::dds_::Odometry_";
/// DDS type name of `tf2_msgs/msg/TFMessage`.
pub const TF_TYPE: &str = "tf2_msgs::msg::dds_::TFMessage_";
/// DDS type name of `diagnostic_msgs/msg/DiagnosticArray`.
pub const DIAGNOSTICS_TYPE: &str = "diagnostic_msgs::msg::dds_::DiagnosticArray_";
/// DDS type name of `sensor_msgs/msg/NavSatFix`.
pub const NAV_SAT_FIX_TYPE: &str = "sensor_msgs::msg::dds_::NavSatFix_";

/// The frames a pose is published in (REP-105).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Frames {
    /// The fixed frame of the pose (`odom`).
    pub odom: String,
    /// The vehicle's frame (`base_link`).
    pub base: String,
}

impl Default for Frames {
    fn default() -> Self {
        Self {
            odom: canodom_export::encode::ODOM_FRAME.to_owned(),
            base: canodom_export::encode::BASE_FRAME.to_owned(),
        }
    }
}

/// The stamp of a step: its time on the log's (bus) clock.
pub fn stamp_of(sample: &StepSample) -> RosTime {
    RosTime::from_nanos((sample.t_unix_us.max(0) as u64) * 1000)
}

/// The yaw quaternion (x, y, z, w) of a heading.
fn yaw(heading_rad: f64) -> [f64; 4] {
    let (s, c) = (0.5 * heading_rad).sin_cos();
    [0.0, 0.0, s, c]
}

/// Appends the CDR `nav_msgs/msg/Odometry` of `sample` to `buf`, with the
/// covariances the MCAP recordings carry (`k_rear_m`: the filter's rear
/// wheel noise; `rear_tread_m`: the tread in use).
pub fn encode_odometry(
    sample: &StepSample,
    frames: &Frames,
    (k_rear_m, rear_tread_m): (f64, f64),
    buf: &mut Vec<u8>,
) {
    let pose = pose_covariance(&sample.covariance);
    let twist = twist_covariance(k_rear_m, sample.rear_m, rear_tread_m, sample.dt_s);
    let msg = Odometry {
        stamp: stamp_of(sample),
        frame_id: &frames.odom,
        child_frame_id: &frames.base,
        position: [sample.fused.x_m, sample.fused.y_m, 0.0],
        orientation: yaw(sample.fused.heading_rad),
        pose_covariance: &pose,
        linear: [sample.output.speed_mps, 0.0, 0.0],
        angular: [0.0, 0.0, sample.output.yaw_rate_radps],
        twist_covariance: &twist,
    };
    cdr::encode_odometry(&msg, buf);
}

/// Appends the CDR `tf2_msgs/msg/TFMessage` of `sample` (one transform,
/// `odom` → `base_link`) to `buf`.
pub fn encode_tf(sample: &StepSample, frames: &Frames, buf: &mut Vec<u8>) {
    let t = Transform {
        stamp: stamp_of(sample),
        frame_id: &frames.odom,
        child_frame_id: &frames.base,
        translation: [sample.fused.x_m, sample.fused.y_m, 0.0],
        rotation: yaw(sample.fused.heading_rad),
    };
    cdr::encode_tf(&[t], buf);
}

/// A `diagnostic_msgs/msg/DiagnosticStatus` level.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Level {
    /// `OK` (0).
    Ok = 0,
    /// `WARN` (1).
    Warn = 1,
    /// `ERROR` (2).
    Error = 2,
    /// `STALE` (3).
    Stale = 3,
}

/// One `diagnostic_msgs/msg/DiagnosticStatus`.
#[derive(Clone, Debug, PartialEq)]
pub struct Status {
    /// The level.
    pub level: Level,
    /// The status's name (`canodom: link`).
    pub name: String,
    /// A one-line summary.
    pub message: String,
    /// The hardware (the CAN interface, the node).
    pub hardware_id: String,
    /// Key-value pairs.
    pub values: Vec<(String, String)>,
}

/// A little-endian XCDR1 writer: alignment counted from after the 4-byte
/// encapsulation header, strings with their NUL counted.
struct Writer<'a> {
    buf: &'a mut Vec<u8>,
    origin: usize,
}

impl<'a> Writer<'a> {
    fn new(buf: &'a mut Vec<u8>) -> Self {
        buf.extend_from_slice(&[0x00, 0x01, 0x00, 0x00]);
        let origin = buf.len();
        Self { buf, origin }
    }

    fn align(&mut self, n: usize) {
        let pad = (n - (self.buf.len() - self.origin) % n) % n;
        self.buf.resize(self.buf.len() + pad, 0);
    }

    fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    fn u16(&mut self, v: u16) {
        self.align(2);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    fn time(&mut self, t: RosTime) {
        self.u32(t.sec as u32);
        self.u32(t.nanosec);
    }

    fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }
}

/// Appends a CDR `diagnostic_msgs/msg/DiagnosticArray` of `status` at
/// `stamp` to `buf`.
pub fn encode_diagnostics(stamp: RosTime, frame_id: &str, status: &[Status], buf: &mut Vec<u8>) {
    let mut w = Writer::new(buf);
    w.time(stamp);
    w.string(frame_id);
    w.u32(status.len() as u32);
    for s in status {
        w.u8(s.level as u8);
        w.string(&s.name);
        w.string(&s.message);
        w.string(&s.hardware_id);
        w.u32(s.values.len() as u32);
        for (k, v) in &s.values {
            w.string(k);
            w.string(v);
        }
    }
}

/// DDS type name of `rmw_dds_common/msg/ParticipantEntitiesInfo`, the
/// message of ROS 2's graph topic [`GRAPH_TOPIC`].
pub const PARTICIPANT_ENTITIES_INFO_TYPE: &str =
    "rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_";

/// The DDS topic on which every ROS 2 participant says which nodes it holds
/// and which readers and writers each node owns: what `ros2 node list` and
/// `ros2 topic info -v` read (rmw's names are not prefixed `rt/`).
pub const GRAPH_TOPIC: &str = "ros_discovery_info";

/// A node's entry on the graph topic: its name and namespace and the GUIDs
/// (16 bytes, the DDS GUID as rmw takes it) of its readers and writers.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct NodeEntities {
    /// The node's namespace, absolute (`/` for none).
    pub namespace: String,
    /// The node's name.
    pub name: String,
    /// Its readers' GUIDs.
    pub readers: Vec<[u8; 16]>,
    /// Its writers' GUIDs.
    pub writers: Vec<[u8; 16]>,
}

/// Appends a CDR `rmw_dds_common/msg/ParticipantEntitiesInfo` to `buf`:
/// the participant's GUID and its nodes.
///
/// A GID is `char[gid_bytes] data`: 16 bytes since Iron (Jazzy, Kilted,
/// Rolling: the DDS GUID), 24 in Humble (the GUID then zeros); rmw copies
/// the GUID in either way, so only the padding differs.
pub fn encode_participant_entities(
    participant: [u8; 16],
    nodes: &[NodeEntities],
    gid_bytes: GidBytes,
    buf: &mut Vec<u8>,
) {
    let mut w = Writer::new(buf);
    let gid = |w: &mut Writer<'_>, g: &[u8; 16]| {
        w.buf.extend_from_slice(g);
        w.buf
            .resize(w.buf.len() + (gid_bytes as usize - g.len()), 0);
    };
    let gids = |w: &mut Writer<'_>, list: &[[u8; 16]]| {
        w.u32(list.len() as u32);
        for g in list {
            gid(w, g);
        }
    };
    gid(&mut w, &participant);
    w.u32(nodes.len() as u32);
    for n in nodes {
        w.string(&n.namespace);
        w.string(&n.name);
        gids(&mut w, &n.readers);
        gids(&mut w, &n.writers);
    }
}

/// The size of a GID on ROS 2's graph topic, which differs by distribution.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GidBytes {
    /// `char[16]`: Iron and later (Jazzy, Kilted, Rolling).
    Sixteen = 16,
    /// `uint8[24]`: Humble and earlier.
    TwentyFour = 24,
}

/// A `sensor_msgs/msg/NavSatFix`.
#[derive(Clone, Debug, PartialEq)]
pub struct NavSatFix {
    /// The header's stamp.
    pub stamp: RosTime,
    /// The header's frame.
    pub frame_id: String,
    /// `NavSatStatus.status`: −1 no fix, 0 fix, 1 SBAS, 2 GBAS (RTK).
    pub status: i8,
    /// `NavSatStatus.service`: the GNSS systems used (bit mask).
    pub service: u16,
    /// Latitude, degrees (positive north).
    pub latitude: f64,
    /// Longitude, degrees (positive east).
    pub longitude: f64,
    /// Altitude above the WGS 84 ellipsoid, metres (NaN when unknown).
    pub altitude: f64,
    /// Position covariance (east, north, up), m², row-major.
    pub position_covariance: [f64; 9],
    /// 0 unknown, 1 approximated, 2 diagonal known, 3 known.
    pub position_covariance_type: u8,
}

/// Appends `fix` as a CDR `sensor_msgs/msg/NavSatFix` to `buf`.
pub fn encode_nav_sat_fix(fix: &NavSatFix, buf: &mut Vec<u8>) {
    let mut w = Writer::new(buf);
    w.time(fix.stamp);
    w.string(&fix.frame_id);
    w.u8(fix.status as u8);
    w.u16(fix.service);
    for v in [fix.latitude, fix.longitude, fix.altitude] {
        w.f64(v);
    }
    for v in fix.position_covariance {
        w.f64(v);
    }
    w.u8(fix.position_covariance_type);
}

/// A little-endian XCDR1 reader over a payload without its encapsulation
/// header (alignment counted from the payload's start).
struct Reader<'a> {
    data: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, align: usize) -> Result<&'a [u8]> {
        let start = self.at.next_multiple_of(align);
        let end = start
            .checked_add(n)
            .ok_or(Error::Decode("length overflow"))?;
        let bytes = self
            .data
            .get(start..end)
            .ok_or(Error::Decode("message ends early"))?;
        self.at = end;
        Ok(bytes)
    }

    fn u8(&mut self) -> Result<u8> {
        Ok(self.take(1, 1)?[0])
    }

    fn u16(&mut self) -> Result<u16> {
        let b = self.take(2, 2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }

    fn u32(&mut self) -> Result<u32> {
        let b = self.take(4, 4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn f64(&mut self) -> Result<f64> {
        let b = self.take(8, 8)?;
        let mut a = [0; 8];
        a.copy_from_slice(b);
        Ok(f64::from_le_bytes(a))
    }

    fn string(&mut self) -> Result<String> {
        let n = self.u32()? as usize;
        let b = self.take(n, 1)?;
        let text = b.strip_suffix(&[0]).unwrap_or(b);
        String::from_utf8(text.to_vec()).map_err(|_| Error::Decode("a string is not UTF-8"))
    }
}

/// Decodes a `sensor_msgs/msg/NavSatFix` from its CDR bytes, with or
/// without the 4-byte encapsulation header (little-endian only).
///
/// # Errors
/// A big-endian or truncated message, a string not UTF-8.
pub fn decode_nav_sat_fix(bytes: &[u8]) -> Result<NavSatFix> {
    let payload = match bytes {
        [0x00, 0x01, _, _, rest @ ..] => rest,
        [0x00, 0x00, _, _, ..] => return Err(Error::Decode("big-endian CDR is not read")),
        _ => bytes,
    };
    let mut r = Reader {
        data: payload,
        at: 0,
    };
    let sec = r.u32()? as i32;
    let nanosec = r.u32()?;
    let frame_id = r.string()?;
    let status = r.u8()? as i8;
    let service = r.u16()?;
    let latitude = r.f64()?;
    let longitude = r.f64()?;
    let altitude = r.f64()?;
    let mut position_covariance = [0.0; 9];
    for v in &mut position_covariance {
        *v = r.f64()?;
    }
    let position_covariance_type = r.u8()?;
    Ok(NavSatFix {
        stamp: RosTime { sec, nanosec },
        frame_id,
        status,
        service,
        latitude,
        longitude,
        altitude,
        position_covariance,
        position_covariance_type,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use canodom_export::encode::{MessageSink, StepEncoder, Topic};
    use canodom_export::sample::FrameBuffer;

    /// rmw_dds_common's layout: GID, then per node namespace, name, reader
    /// GIDs, writer GIDs; a Humble GID is the same 16 bytes and 8 zeros.
    #[test]
    fn graph_message_is_rmw_dds_commons_layout() {
        let node = NodeEntities {
            namespace: "/".into(),
            name: "cn".into(),
            readers: vec![],
            writers: vec![[2; 16]],
        };
        let mut jazzy = Vec::new();
        encode_participant_entities(
            [1; 16],
            std::slice::from_ref(&node),
            GidBytes::Sixteen,
            &mut jazzy,
        );
        let mut want = vec![0, 1, 0, 0];
        want.extend([1; 16]);
        want.extend(1u32.to_le_bytes()); // one node
        want.extend(2u32.to_le_bytes()); // "/" and its NUL
        want.extend(b"/\0\0\0"); // padded to 4 for the next length
        want.extend(3u32.to_le_bytes());
        want.extend(b"cn\0\0");
        want.extend(0u32.to_le_bytes()); // no readers
        want.extend(1u32.to_le_bytes());
        want.extend([2; 16]);
        assert_eq!(jazzy, want);

        let mut humble = Vec::new();
        encode_participant_entities([1; 16], &[node], GidBytes::TwentyFour, &mut humble);
        assert_eq!(humble.len(), jazzy.len() + 16);
        assert_eq!(&humble[4..20], &[1; 16]);
        assert_eq!(&humble[20..28], &[0; 8]);
        assert_eq!(&humble[humble.len() - 24..humble.len() - 8], &[2; 16]);
    }

    /// A sample as a replay's step gives it (values chosen, not computed).
    fn sample() -> StepSample {
        use canodom_can::time::Timestamp;
        use canodom_pipeline::pipeline::PoseOutput;
        StepSample {
            t_unix_us: 1_533_245_256_584_930,
            fused: canodom_fusion::Pose {
                x_m: 12.5,
                y_m: -3.25,
                heading_rad: 0.4,
            },
            rear_only: canodom_fusion::Pose {
                x_m: 12.0,
                y_m: -3.0,
                heading_rad: 0.39,
            },
            output: PoseOutput {
                timestamp: Timestamp::from_micros(1_533_245_256_584_930),
                x_m: 12.5,
                y_m: -3.25,
                heading_rad: 0.4,
                speed_mps: 27.0,
                yaw_rate_radps: 0.01,
                pos_std_m: 0.2,
                heading_std_rad: 0.01,
                flags: canodom_pipeline::pipeline::PoseFlags::default(),
                param_version: 0,
            },
            covariance: [0.04, 0.001, 0.0, 0.001, 0.03, 0.0, 0.0, 0.0, 1e-4],
            rear_m: [0.27, 0.271],
            dt_s: 0.01,
            correction: canodom_fusion::ekf::WindowOutcome::Open,
            counts: canodom_export::sample::Counts::default(),
            calibration_phase: "idle",
            gnss: None,
            drift: None,
        }
    }

    struct Keep(Vec<(Topic, Vec<u8>)>);
    impl MessageSink for Keep {
        fn message(&mut self, topic: Topic, _t_ns: u64, payload: impl FnOnce(&mut Vec<u8>)) {
            let mut b = Vec::new();
            payload(&mut b);
            self.0.push((topic, b));
        }
    }

    #[test]
    fn odometry_and_tf_are_the_recordings_bytes() {
        let config = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../data/comma2k19-rav4/config.toml");
        let config = canodom_pipeline::config::Config::load(&config).expect("the RAV4 config");
        let params = *canodom_pipeline::pipeline::Pipeline::new(&config)
            .expect("a pipeline")
            .params();
        let k_rear_m = 2e-5;
        let mut sink = Keep(Vec::new());
        StepEncoder::new(k_rear_m).encode(
            &sample(),
            &params,
            (&FrameBuffer::default(), 0, 0),
            &mut sink,
        );
        let of = |t| {
            sink.0
                .iter()
                .find(|(topic, _)| *topic == t)
                .map(|(_, b)| b.clone())
                .expect("the recording has the topic")
        };
        let mut odom = Vec::new();
        encode_odometry(
            &sample(),
            &Frames::default(),
            (k_rear_m, params.rear_tread_m()),
            &mut odom,
        );
        assert_eq!(odom, of(Topic::RosOdometry));
        let mut tf = Vec::new();
        encode_tf(&sample(), &Frames::default(), &mut tf);
        assert_eq!(tf, of(Topic::RosTf));
    }

    #[test]
    fn nav_sat_fix_round_trips() {
        let fix = NavSatFix {
            stamp: RosTime {
                sec: 1_533_245_256,
                nanosec: 584_930_000,
            },
            frame_id: "gnss".to_owned(),
            status: 2,
            service: 1,
            latitude: 37.4,
            longitude: -122.1,
            altitude: 12.0,
            position_covariance: [0.01, 0.0, 0.0, 0.0, 0.01, 0.0, 0.0, 0.0, 0.04],
            position_covariance_type: 2,
        };
        let mut buf = Vec::new();
        encode_nav_sat_fix(&fix, &mut buf);
        // Header 8 + "gnss\0" 4+5 = 17, status 1 → 18, service (aligned) 18..20,
        // the doubles from payload 24.
        assert_eq!(buf.len(), 4 + 24 + 12 * 8 + 1);
        assert_eq!(decode_nav_sat_fix(&buf).expect("decodes"), fix);
        assert_eq!(decode_nav_sat_fix(&buf[4..]).expect("decodes"), fix);
        assert!(decode_nav_sat_fix(&buf[..40]).is_err());
        assert!(decode_nav_sat_fix(&[0, 0, 0, 0, 1]).is_err());
    }

    #[test]
    fn diagnostics_lay_out_as_xcdr1() {
        let mut buf = Vec::new();
        let status = [Status {
            level: Level::Warn,
            name: "n".to_owned(),
            message: "m".to_owned(),
            hardware_id: "h".to_owned(),
            values: vec![("k".to_owned(), "v".to_owned())],
        }];
        encode_diagnostics(RosTime { sec: 1, nanosec: 2 }, "", &status, &mut buf);
        let p = &buf[4..];
        // stamp 8, "" as 4+1 → 13, pad → 16: one status.
        assert_eq!(&p[13..16], &[0, 0, 0]);
        assert_eq!(&p[16..20], &1u32.to_le_bytes());
        assert_eq!(p[20], 1);
        // name at 24 (aligned): length 2, "n\0".
        assert_eq!(&p[24..28], &2u32.to_le_bytes());
        assert_eq!(&p[28..30], b"n\0");
    }
}
