//! Encoding a pose sample into canodom's own frames (`ODOM_POSITION`,
//! `ODOM_MOTION`, `ODOM_QUALITY` of `dbc/canodom.dbc`) at the configured base
//! id, with the shared rolling counter and CRC-8 SAE J1850, through the same
//! DBC codec users decode them with.

use crate::own_dbc::{BaseId, OwnDbc, OwnFrame};
use canodom_can::frame::{CanFrame, FrameError};
use canodom_can::time::Timestamp;
use canodom_dbc::{Checksum, Database, SignalHandle};
use std::sync::Arc;

/// Encodes pose samples; owns the rolling counter.
#[derive(Debug)]
pub struct PoseEncoder {
    ids: [canodom_can::frame::FrameId; 3],
    db: Arc<Database>,
    x: SignalHandle,
    y: SignalHandle,
    heading: SignalHandle,
    speed: SignalHandle,
    yaw_rate: SignalHandle,
    pos_std: SignalHandle,
    heading_std: SignalHandle,
    flags: [SignalHandle; 9],
    version: SignalHandle,
    counters: [SignalHandle; 3],
    crc: Checksum,
    counter: u8,
}

/// Why a pose could not be encoded (only a broken shipped DBC can cause it).
#[derive(Debug, thiserror::Error)]
pub enum PoseEncodeError {
    /// The shipped DBC lacks a signal or does not parse.
    #[error("canodom.dbc: {0}")]
    Dbc(#[from] canodom_dbc::Error),
    /// The frame type refused the payload.
    #[error("pose frame: {0}")]
    Frame(#[from] FrameError),
}

impl PoseEncoder {
    /// An encoder for frames at `base`.
    ///
    /// # Errors
    /// Only if the shipped DBC is broken (a unit test proves it is not).
    pub fn new(base: BaseId) -> Result<Self, PoseEncodeError> {
        Self::with_dbc(&OwnDbc::new(base)?)
    }

    /// An encoder on an already parsed own DBC (the daemon parses it once
    /// for every codec).
    ///
    /// # Errors
    /// Only if the shipped DBC is broken (a unit test proves it is not).
    pub fn with_dbc(own: &OwnDbc) -> Result<Self, PoseEncodeError> {
        let base = own.base();
        let db = own.shared_database();
        let s = |p: &str| db.signal(p);
        Ok(Self {
            ids: [
                OwnFrame::OdomPosition.id(base),
                OwnFrame::OdomMotion.id(base),
                OwnFrame::OdomQuality.id(base),
            ],
            x: s("ODOM_POSITION.POS_X")?,
            y: s("ODOM_POSITION.POS_Y")?,
            heading: s("ODOM_MOTION.HEADING")?,
            speed: s("ODOM_MOTION.SPEED")?,
            yaw_rate: s("ODOM_MOTION.YAW_RATE")?,
            pos_std: s("ODOM_QUALITY.POS_STD")?,
            heading_std: s("ODOM_QUALITY.HEADING_STD")?,
            flags: [
                s("ODOM_QUALITY.POSE_VALID")?,
                s("ODOM_QUALITY.REAR_STALE")?,
                s("ODOM_QUALITY.FRONT_STALE")?,
                s("ODOM_QUALITY.STEER_STALE")?,
                s("ODOM_QUALITY.COUNTER_FAULT")?,
                s("ODOM_QUALITY.CHECKSUM_FAULT")?,
                s("ODOM_QUALITY.GATE_REJECT")?,
                s("ODOM_QUALITY.NOMINAL_PARAMS")?,
                s("ODOM_QUALITY.INPUT_IMPLAUSIBLE")?,
            ],
            version: s("ODOM_QUALITY.PARAM_VERSION")?,
            counters: [
                s("ODOM_POSITION.COUNTER")?,
                s("ODOM_MOTION.COUNTER")?,
                s("ODOM_QUALITY.COUNTER")?,
            ],
            crc: Checksum::rc_car(),
            counter: 0,
            db,
        })
    }

    /// The database the frames are encoded with (for decoding them back).
    pub fn database(&self) -> &Database {
        &self.db
    }

    /// The three frames of one pose sample, sharing one counter value.
    ///
    /// # Errors
    /// Never for the shipped DBC; see [`PoseEncodeError`].
    pub fn encode(&mut self, pose: &PoseOutput) -> Result<[CanFrame; 3], PoseEncodeError> {
        let mut bufs = [[0u8; 8]; 3];
        // Position wraps beyond ±33.5 km (the DBC says so): raw two's complement.
        put_wrapped(&self.x, pose.x_m / 0.001, &mut bufs[0]);
        put_wrapped(&self.y, pose.y_m / 0.001, &mut bufs[0]);
        self.heading
            .encode_saturating(pose.heading_rad, &mut bufs[1]);
        self.speed.encode_saturating(pose.speed_mps, &mut bufs[1]);
        self.yaw_rate
            .encode_saturating(pose.yaw_rate_radps, &mut bufs[1]);
        self.pos_std.encode_saturating(pose.pos_std_m, &mut bufs[2]);
        self.heading_std
            .encode_saturating(pose.heading_std_rad, &mut bufs[2]);
        for (h, on) in self.flags.iter().zip(pose.flags.in_order()) {
            h.encode_raw(u64::from(on), &mut bufs[2]);
        }
        self.version
            // 15 bits: the version modulo 32768 (the DBC says so), never
            // spilling into INPUT_IMPLAUSIBLE.
            .encode_raw(u64::from(pose.param_version) & 0x7FFF, &mut bufs[2]);
        for (h, buf) in self.counters.iter().zip(bufs.iter_mut()) {
            h.encode_raw(u64::from(self.counter), buf);
            self.crc.apply(buf)?;
        }
        self.counter = (self.counter + 1) & 0x0F;
        Ok([
            CanFrame::new_data(self.ids[0], &bufs[0])?,
            CanFrame::new_data(self.ids[1], &bufs[1])?,
            CanFrame::new_data(self.ids[2], &bufs[2])?,
        ])
    }
}

fn put_wrapped(h: &SignalHandle, raw_scaled: f64, buf: &mut [u8]) {
    let raw = if raw_scaled.is_finite() {
        raw_scaled.round() as i64
    } else {
        0
    };
    h.encode_raw(raw as u64, buf);
}

/// Validity flags of a pose sample.
// Each is one bit of ODOM_QUALITY: independent flags, not a state machine.
#[allow(clippy::struct_excessive_bools)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PoseFlags {
    /// Rear wheels fresh and trusted: the pose may be used.
    pub pose_valid: bool,
    /// A rear wheel input is stale or not yet trusted.
    pub rear_stale: bool,
    /// The front wheel input is stale: no front corrections.
    pub front_stale: bool,
    /// The steering input is stale.
    pub steer_stale: bool,
    /// A counter fault since the previous pose sample.
    pub counter_fault: bool,
    /// A checksum fault since the previous pose sample.
    pub checksum_fault: bool,
    /// A gate rejection since the previous pose sample.
    pub gate_reject: bool,
    /// The nominal parameters from the configuration are in use.
    pub nominal_params: bool,
    /// The run-time plausibility checks found the inputs implausible (a
    /// sign, unit, checksum algorithm or wheel kind likely wrong); stays set.
    pub input_implausible: bool,
}

impl PoseFlags {
    /// The flags as ODOM_QUALITY orders them, POSE_VALID in bit 0 up to
    /// NOMINAL_PARAMS in bit 7 and INPUT_IMPLAUSIBLE in bit 8: one number
    /// for CSV columns and logs.
    pub fn bits(self) -> u16 {
        self.in_order()
            .iter()
            .enumerate()
            .fold(0, |bits, (k, &on)| bits | (u16::from(on) << k))
    }

    /// The flags in ODOM_QUALITY's order, POSE_VALID first: how every
    /// encoding (frames, CSV, recordings) lists them.
    pub fn in_order(self) -> [bool; 9] {
        [
            self.pose_valid,
            self.rear_stale,
            self.front_stale,
            self.steer_stale,
            self.counter_fault,
            self.checksum_fault,
            self.gate_reject,
            self.nominal_params,
            self.input_implausible,
        ]
    }
}

/// What a pose frame carries.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseOutput {
    /// Time of the newest frame the pose includes.
    pub timestamp: Timestamp,
    /// Position x, metres.
    pub x_m: f64,
    /// Position y, metres.
    pub y_m: f64,
    /// Heading wrapped to (−π, π], radians.
    pub heading_rad: f64,
    /// Speed of the rear-axle centre, m/s.
    pub speed_mps: f64,
    /// Yaw rate, rad/s.
    pub yaw_rate_radps: f64,
    /// Square root of the largest eigenvalue of the x-y covariance, metres.
    pub pos_std_m: f64,
    /// Heading standard deviation, radians.
    pub heading_std_rad: f64,
    /// Validity flags.
    pub flags: PoseFlags,
    /// Version of the parameter set in use; 0 for nominal.
    pub param_version: u16,
}

#[cfg(test)]
mod tests {
    use super::PoseFlags;
    use super::*;
    use crate::own_dbc::dbc_for_base;
    use canodom_can::time::Timestamp;
    use canodom_dbc::FrameId;

    fn pose(x: f64) -> PoseOutput {
        PoseOutput {
            timestamp: Timestamp::from_micros(0),
            x_m: x,
            y_m: -2.5,
            heading_rad: 1.0,
            speed_mps: 0.1,
            yaw_rate_radps: -0.2,
            pos_std_m: 100.0,
            heading_std_rad: 0.01,
            flags: PoseFlags {
                pose_valid: true,
                gate_reject: true,
                nominal_params: true,
                ..PoseFlags::default()
            },
            param_version: 7,
        }
    }

    #[test]
    fn frames_decode_back_with_valid_counter_and_crc() {
        let base = BaseId::new(0x700, false).unwrap();
        let mut enc = PoseEncoder::new(base).unwrap();
        let db = Database::parse(&dbc_for_base(base), "x").unwrap();
        for k in 0..17u64 {
            let frames = enc.encode(&pose(12.345)).unwrap();
            for f in &frames {
                assert!(Checksum::rc_car().verify(f.data()).unwrap());
                let m = db
                    .message_by_id(FrameId::standard(f.id().raw() as u16).unwrap())
                    .unwrap();
                let counter = m
                    .decode(f.data())
                    .unwrap()
                    .find(|(s, _)| s.name() == "COUNTER");
                assert_eq!(counter.unwrap().1, (k % 16) as f64);
            }
            assert_eq!(frames[0].id().raw(), 0x700);
            let x = db.signal("ODOM_POSITION.POS_X").unwrap();
            assert!((x.decode(frames[0].data()).unwrap() - 12.345).abs() < 1e-9);
            let std = db.signal("ODOM_QUALITY.POS_STD").unwrap();
            assert!((std.decode(frames[2].data()).unwrap() - 65.535).abs() < 1e-9);
            let v = db.signal("ODOM_QUALITY.PARAM_VERSION").unwrap();
            assert_eq!(v.decode(frames[2].data()), Some(7.0));
            let g = db.signal("ODOM_QUALITY.GATE_REJECT").unwrap();
            assert_eq!(g.decode(frames[2].data()), Some(1.0));
        }
    }

    #[test]
    fn input_implausible_is_its_own_bit_beside_the_version() {
        let mut enc = PoseEncoder::new(BaseId::DEFAULT).unwrap();
        let flag = enc
            .database()
            .signal("ODOM_QUALITY.INPUT_IMPLAUSIBLE")
            .unwrap();
        let version = enc.database().signal("ODOM_QUALITY.PARAM_VERSION").unwrap();
        let mut p = pose(1.0);
        p.param_version = 32_768 + 5;
        let f = enc.encode(&p).unwrap();
        assert_eq!(flag.decode(f[2].data()), Some(0.0));
        assert_eq!(version.decode(f[2].data()), Some(5.0));
        p.flags.input_implausible = true;
        p.param_version = 0x7FFF;
        let f = enc.encode(&p).unwrap();
        assert_eq!(flag.decode(f[2].data()), Some(1.0));
        assert_eq!(version.decode(f[2].data()), Some(32_767.0));
        assert_eq!(p.flags.bits() >> 8, 1);
    }

    #[test]
    fn position_wraps_beyond_its_range() {
        let mut enc = PoseEncoder::new(BaseId::DEFAULT).unwrap();
        let f = enc.encode(&pose(33_554.432 + 1.0)).unwrap();
        let x = enc.database().signal("ODOM_POSITION.POS_X").unwrap();
        assert!((x.decode(f[0].data()).unwrap() - (-33_554.432 + 1.0)).abs() < 1e-6);
    }
}
