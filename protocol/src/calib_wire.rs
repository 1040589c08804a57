//! The calibration protocol on the wire: `CALIB_CMD`, `CALIB_STATUS`,
//! `CALIB_PARAMS` and `CALIB_ACK` of `dbc/canodom.dbc` as typed values, their
//! codes and names (the DBC's `VAL_` tables), and pure encode/decode through
//! the same DBC codec CAN tools use.
//!
//! Both ends use this module: the daemon decodes commands and encodes status,
//! parameter and (in tests) acknowledgement frames; the operator client does
//! the opposite. Every frame carries the 4-bit rolling `COUNTER` (bits 52..55)
//! and the CRC-8 SAE J1850 `CHECKSUM` in byte 7 ([`Checksum::rc_car`]).
//!
//! Reason codes are one table for run rejections and command refusals, so a
//! client needs one lookup: `1..=13` are [`Refusal`] codes of the session state
//! machine unchanged, `14..=18` the run [`Rejection`]s (`13 + code`), `19..`
//! refusals of the protocol and the daemon.

use crate::own_dbc::{BaseId, OwnDbc, OwnFrame};
#[cfg(doc)]
use canodom_calib::{run::Rejection, session::Refusal};
use canodom_can::frame::{CanFrame, FrameError, FrameId};
use canodom_dbc::{Checksum, Database, SignalHandle};
use std::sync::Arc;

mod assembler;
mod codes;
mod messages;
pub use assembler::ParamsAssembler;
pub use codes::{
    AckStatus, CmdCode, InstructionCode, Reason, StartPoint, State, WireDirection, Writeback,
};
pub use messages::{
    Ack, Command, CommandFrame, Counts, DEFAULT_RUNS_PER_DIRECTION, GnssSourceKind, GnssStatus,
    ParamSet, ParamsData, ParamsPage, Progress, StatusPage,
};

/// Why a frame could not be encoded or decoded.
#[derive(Debug, thiserror::Error)]
pub enum WireError {
    /// The shipped DBC lacks a signal (a unit test proves it does not).
    #[error("canodom.dbc: {0}")]
    Dbc(#[from] canodom_dbc::Error),
    /// The frame is shorter than 8 bytes.
    #[error("{message}: frame of {len} bytes, 8 needed")]
    ShortFrame {
        /// Message name.
        message: &'static str,
        /// Bytes received.
        len: usize,
    },
    /// Byte 7 is not the CRC-8 of bytes 0..=6.
    #[error("{message}: checksum mismatch")]
    BadChecksum {
        /// Message name.
        message: &'static str,
    },
    /// A coded field holds a value its table does not define.
    #[error("{message}.{signal}: undefined code {raw}")]
    UnknownCode {
        /// Message name.
        message: &'static str,
        /// Signal name.
        signal: &'static str,
        /// The raw value.
        raw: u64,
    },
    /// A value does not fit its signal (parameters far outside any vehicle).
    #[error("{message}.{signal}: {value} does not fit the signal")]
    OutOfRange {
        /// Message name.
        message: &'static str,
        /// Signal name.
        signal: &'static str,
        /// The value.
        value: f64,
    },
    /// The frame type refused the payload.
    #[error("frame: {0}")]
    Frame(#[from] FrameError),
}

/// Result of this module.
pub type Result<T> = std::result::Result<T, WireError>;

/// `GNSS_ERROR_95`'s raw value for "the source stated no error estimate".
const GNSS_ERROR_NOT_STATED: u64 = 4095;

/// The largest error estimate `GNSS_ERROR_95` carries, metres (raw 4094).
const GNSS_ERROR_95_MAX_M: f64 = 409.4;

/// Handles of `CALIB_STATUS` signals.
#[derive(Debug)]
struct StatusHandles {
    page: SignalHandle,
    p0: [SignalHandle; 12],
    p1: [SignalHandle; 9],
    results: [[SignalHandle; 3]; 4],
    gnss: [SignalHandle; 7],
}

impl StatusHandles {
    /// The `CALIB_STATUS` signals, looked up by name with `st`.
    fn new(
        st: &impl Fn(&str) -> std::result::Result<SignalHandle, canodom_dbc::Error>,
    ) -> Result<Self> {
        Ok(StatusHandles {
            page: st("PAGE")?,
            p0: [
                st("STATE")?,
                st("INSTRUCTION")?,
                st("RUN_INDEX")?,
                st("RUNS_TOTAL")?,
                st("DIRECTION")?,
                st("START_POINT")?,
                st("RUN_DISTANCE")?,
                st("WRITEBACK")?,
                st("STANDSTILL")?,
                st("WB_ATTEMPTS")?,
                st("DRIFT")?,
                st("DRIFT_CANDIDATE")?,
            ],
            p1: [
                st("CW_ACCEPTED")?,
                st("CW_REJECTED")?,
                st("CCW_ACCEPTED")?,
                st("CCW_REJECTED")?,
                st("REJECT_REASON")?,
                st("LAST_CMD")?,
                st("CMD_REASON")?,
                st("ACTIVE_VERSION")?,
                st("CMD_SEQ")?,
            ],
            results: [
                [
                    st("RES_REAR_TREAD")?,
                    st("RES_REAR_TREAD_STD")?,
                    st("RES_DIAMETER_RATIO")?,
                ],
                [
                    st("RES_DIAMETER_RATIO_STD")?,
                    st("END_ERR_BEFORE")?,
                    st("END_ERR_AFTER")?,
                ],
                [
                    st("RES_STEER_GAIN")?,
                    st("RES_STEER_GAIN_STD")?,
                    st("RES_STEER_OFFSET")?,
                ],
                [
                    st("RES_STEER_OFFSET_STD")?,
                    st("RES_VERSION")?,
                    // Page 5 has two signals; the third slot repeats the
                    // first so the array stays rectangular.
                    st("RES_STEER_OFFSET_STD")?,
                ],
            ],
            gnss: [
                st("GNSS_SOURCE")?,
                st("GNSS_CONNECTED")?,
                st("GNSS_FIXES_PER_S")?,
                st("GNSS_ERROR_95")?,
                st("GNSS_FORWARDED")?,
                st("GNSS_REFUSED")?,
                st("GNSS_RECONNECTS")?,
            ],
        })
    }
}

/// The codec of the four calibration frames at one base id.
#[derive(Debug)]
pub struct CalibWire {
    db: Arc<Database>,
    ids: [FrameId; 4],
    crc: Checksum,
    cmd: [SignalHandle; 7],
    status: StatusHandles,
    params: [SignalHandle; 9],
    ack: [SignalHandle; 3],
    counters: [SignalHandle; 4],
    /// `CALIB_STATUS.AUTH_LOCKOUT` (page 0), stamped by the SecOC gate.
    auth_lockout: SignalHandle,
}

const CMD: &str = "CALIB_CMD";
const STATUS: &str = "CALIB_STATUS";
const PARAMS: &str = "CALIB_PARAMS";
const ACK: &str = "CALIB_ACK";

/// Order of `CALIB_PARAMS` signals in [`CalibWire::params`] (after PAGE and
/// PARAM_VERSION), which is also the order of SET_CRC's raw values.
const PARAM_SIGNALS: [&str; 7] = [
    "REAR_TREAD",
    "RL_DIAMETER",
    "RR_DIAMETER",
    "DIAMETER_RATIO",
    "STEER_GAIN",
    "STEER_OFFSET",
    "SET_CRC",
];

impl CalibWire {
    /// The codec for frames at `base`.
    ///
    /// # Errors
    /// Only if the shipped DBC is broken (a unit test proves it is not).
    pub fn new(base: BaseId) -> Result<Self> {
        Self::with_dbc(&OwnDbc::new(base)?)
    }

    /// The codec on an already parsed own DBC (the daemon parses it once
    /// for every codec).
    ///
    /// # Errors
    /// Only if the shipped DBC lacks a signal (a unit test proves it does not).
    pub fn with_dbc(own: &OwnDbc) -> Result<Self> {
        let base = own.base();
        let db = own.shared_database();
        let s = |m: &str, n: &str| db.signal(&format!("{m}.{n}"));
        let st = |n: &str| s(STATUS, n);
        let p = |n: &str| s(PARAMS, n);
        Ok(Self {
            ids: [
                OwnFrame::CalibCmd.id(base),
                OwnFrame::CalibStatus.id(base),
                OwnFrame::CalibParams.id(base),
                OwnFrame::CalibAck.id(base),
            ],
            crc: Checksum::rc_car(),
            cmd: [
                s(CMD, "CMD")?,
                s(CMD, "ARMING_CODE")?,
                s(CMD, "TRACK_RADIUS")?,
                s(CMD, "RUNS_PER_DIR")?,
                s(CMD, "END_DX")?,
                s(CMD, "END_DY")?,
                s(CMD, "END_DTHETA")?,
            ],
            status: StatusHandles::new(&st)?,
            params: [
                p("PAGE")?,
                p("PARAM_VERSION")?,
                p(PARAM_SIGNALS[0])?,
                p(PARAM_SIGNALS[1])?,
                p(PARAM_SIGNALS[2])?,
                p(PARAM_SIGNALS[3])?,
                p(PARAM_SIGNALS[4])?,
                p(PARAM_SIGNALS[5])?,
                p(PARAM_SIGNALS[6])?,
            ],
            ack: [
                s(ACK, "ACK_VERSION")?,
                s(ACK, "ACK_STATUS")?,
                s(ACK, "ACK_SET_CRC")?,
            ],
            auth_lockout: st("AUTH_LOCKOUT")?,
            counters: [
                s(CMD, "COUNTER")?,
                s(STATUS, "COUNTER")?,
                s(PARAMS, "COUNTER")?,
                s(ACK, "COUNTER")?,
            ],
            db,
        })
    }

    /// The DBC database the frames are coded with.
    pub fn database(&self) -> &Database {
        &self.db
    }

    /// Id of `CALIB_CMD` at this base.
    pub fn cmd_id(&self) -> FrameId {
        self.ids[0]
    }

    /// Id of `CALIB_STATUS`.
    pub fn status_id(&self) -> FrameId {
        self.ids[1]
    }

    /// Id of `CALIB_PARAMS`.
    pub fn params_id(&self) -> FrameId {
        self.ids[2]
    }

    /// Id of `CALIB_ACK`.
    pub fn ack_id(&self) -> FrameId {
        self.ids[3]
    }

    /// Whether byte 7 of an 8-byte payload is its CRC-8.
    pub fn checksum_ok(&self, data: &[u8]) -> bool {
        data.len() >= 8 && self.crc.is_valid(data)
    }

    fn seal(&self, which: usize, counter: u8, mut buf: [u8; 8]) -> [u8; 8] {
        self.counters[which].encode_raw(u64::from(counter & 0x0F), &mut buf);
        // 8 bytes always cover the checksum's range.
        let _ = self.crc.apply(&mut buf);
        buf
    }

    fn counter_of(&self, which: usize, data: &[u8]) -> u8 {
        self.counters[which].raw(data).unwrap_or(0) as u8
    }

    fn open(&self, message: &'static str, data: &[u8]) -> Result<()> {
        if data.len() < 8 {
            return Err(WireError::ShortFrame {
                message,
                len: data.len(),
            });
        }
        if !self.checksum_ok(data) {
            return Err(WireError::BadChecksum { message });
        }
        Ok(())
    }

    /// Encodes a command. Arguments beyond their signal's range are clamped
    /// to it (the daemon refuses the resulting values if they are absurd).
    pub fn encode_command(&self, cmd: Command, arming_code: u8, counter: u8) -> [u8; 8] {
        self.encode_command_raw(cmd.code().code(), cmd, arming_code, counter)
    }

    /// As [`Self::encode_command`] with CMD set to `cmd_raw` (tests and tools
    /// that need an undefined code); the arguments of `cmd` are written.
    pub fn encode_command_raw(
        &self,
        cmd_raw: u8,
        cmd: Command,
        arming_code: u8,
        counter: u8,
    ) -> [u8; 8] {
        let mut buf = [0u8; 8];
        let [code, arming, radius, runs, dx, dy, dth] = &self.cmd;
        code.encode_raw(u64::from(cmd_raw), &mut buf);
        arming.encode_raw(u64::from(arming_code), &mut buf);
        match cmd {
            Command::StartSession {
                track_radius_mm,
                runs_per_direction,
            } => {
                radius.encode_raw(u64::from(track_radius_mm), &mut buf);
                runs.encode_raw(u64::from(runs_per_direction.min(15)), &mut buf);
            }
            Command::EndPose {
                dx_mm,
                dy_mm,
                dtheta_decideg,
            } => {
                dx.encode_raw(dx_mm.clamp(-8192, 8191) as u64, &mut buf);
                dy.encode_raw(dy_mm.clamp(-8192, 8191) as u64, &mut buf);
                dth.encode_raw(dtheta_decideg.clamp(-2048, 2047) as u64, &mut buf);
            }
            _ => {}
        }
        self.seal(0, counter, buf)
    }

    /// Decodes a command frame without judging its checks.
    ///
    /// # Errors
    /// [`WireError::ShortFrame`] for fewer than 8 bytes.
    pub fn decode_command(&self, data: &[u8]) -> Result<CommandFrame> {
        if data.len() < 8 {
            return Err(WireError::ShortFrame {
                message: CMD,
                len: data.len(),
            });
        }
        let [code, arming, radius, runs, dx, dy, dth] = &self.cmd;
        let raw = |h: &SignalHandle| h.raw(data).unwrap_or(0);
        let signed = |h: &SignalHandle| h.decode(data).unwrap_or(0.0).round() as i16;
        let cmd_raw = raw(code) as u8;
        let command = match CmdCode::from_code(cmd_raw) {
            None | Some(CmdCode::None) => None,
            Some(CmdCode::StartSession) => Some(Command::StartSession {
                track_radius_mm: raw(radius) as u16,
                runs_per_direction: raw(runs) as u8,
            }),
            Some(CmdCode::StartSteering) => Some(Command::StartSteering),
            Some(CmdCode::EndRun) => Some(Command::EndRun),
            Some(CmdCode::EndPose) => Some(Command::EndPose {
                dx_mm: signed(dx),
                dy_mm: signed(dy),
                // The signal's factor is 0.1°; the field is in tenths.
                dtheta_decideg: (dth.decode(data).unwrap_or(0.0) * 10.0).round() as i16,
            }),
            Some(CmdCode::Abort) => Some(Command::Abort),
            Some(CmdCode::Compute) => Some(Command::Compute),
            Some(CmdCode::Commit) => Some(Command::Commit),
            Some(CmdCode::Rollback) => Some(Command::Rollback),
            Some(CmdCode::RequestParams) => Some(Command::RequestParams),
            Some(CmdCode::StartRun) => Some(Command::StartRun),
            Some(CmdCode::StartDrive) => Some(Command::StartDrive),
        };
        Ok(CommandFrame {
            cmd_raw,
            command,
            arming_code: raw(arming) as u8,
            counter: self.counter_of(0, data),
            checksum_ok: self.checksum_ok(data),
        })
    }

    /// Encodes a status page; values beyond a signal's range are clamped to it.
    pub fn encode_status(&self, page: &StatusPage, counter: u8) -> [u8; 8] {
        let mut buf = [0u8; 8];
        let h = &self.status;
        h.page.encode_raw(u64::from(page.page()), &mut buf);
        match page {
            StatusPage::Progress(p) => {
                let raws = [
                    p.state.code(),
                    p.instruction.code(),
                    p.run_index.min(15),
                    p.runs_total.min(15),
                    p.direction.code(),
                    p.start_point.code(),
                ];
                for (hd, r) in h.p0.iter().zip(raws) {
                    hd.encode_raw(u64::from(r), &mut buf);
                }
                h.p0[6].encode_saturating(p.run_distance_m, &mut buf);
                h.p0[7].encode_raw(u64::from(p.writeback.code()), &mut buf);
                h.p0[8].encode_raw(u64::from(p.standstill), &mut buf);
                h.p0[9].encode_raw(u64::from(p.writeback_attempts.min(7)), &mut buf);
                h.p0[10].encode_raw(u64::from(p.drift), &mut buf);
                h.p0[11].encode_raw(u64::from(p.drift_candidate), &mut buf);
            }
            StatusPage::Counts(c) => {
                let raws = [
                    u64::from(c.cw_accepted.min(15)),
                    u64::from(c.cw_rejected.min(15)),
                    u64::from(c.ccw_accepted.min(15)),
                    u64::from(c.ccw_rejected.min(15)),
                    u64::from(c.reject_reason.code()),
                    u64::from(c.last_cmd & 0x0F),
                    u64::from(c.cmd_reason.code()),
                    u64::from(c.active_version),
                    u64::from(c.cmd_seq & 0x07),
                ];
                for (hd, r) in h.p1.iter().zip(raws) {
                    hd.encode_raw(r, &mut buf);
                }
            }
            StatusPage::ResultGeometry {
                rear_tread_m,
                rear_tread_std_m,
                diameter_ratio,
            } => put_all(
                &h.results[0],
                [*rear_tread_m, *rear_tread_std_m, *diameter_ratio],
                &mut buf,
            ),
            StatusPage::ResultQuality {
                diameter_ratio_std,
                end_err_before_m,
                end_err_after_m,
            } => put_all(
                &h.results[1],
                [*diameter_ratio_std, *end_err_before_m, *end_err_after_m],
                &mut buf,
            ),
            StatusPage::ResultSteering {
                steer_gain,
                steer_gain_std,
                steer_offset_rad,
            } => put_all(
                &h.results[2],
                [*steer_gain, *steer_gain_std, *steer_offset_rad],
                &mut buf,
            ),
            StatusPage::ResultExtra {
                steer_offset_std_rad,
                version,
            } => {
                h.results[3][0].encode_saturating(*steer_offset_std_rad, &mut buf);
                h.results[3][1].encode_raw(u64::from(*version), &mut buf);
            }
            StatusPage::Gnss(g) => {
                let p = &h.gnss;
                p[0].encode_raw(u64::from(g.source.code()), &mut buf);
                p[1].encode_raw(u64::from(g.connected), &mut buf);
                p[2].encode_saturating(g.fixes_per_s, &mut buf);
                match g.error_95_m {
                    // Beyond the range reads as its top, never as NOT_STATED.
                    Some(e) => p[3].encode_saturating(e.min(GNSS_ERROR_95_MAX_M), &mut buf),
                    None => p[3].encode_raw(GNSS_ERROR_NOT_STATED, &mut buf),
                };
                p[4].encode_raw(u64::from(g.forwarded), &mut buf);
                p[5].encode_raw(u64::from(g.refused), &mut buf);
                p[6].encode_raw(u64::from(g.reconnects.min(3)), &mut buf);
            }
        }
        self.seal(1, counter, buf)
    }

    /// Decodes a status frame (checksum verified) and its counter.
    ///
    /// # Errors
    /// [`WireError::ShortFrame`], [`WireError::BadChecksum`],
    /// [`WireError::UnknownCode`] for an undefined page or coded field.
    pub fn decode_status(&self, data: &[u8]) -> Result<(StatusPage, u8)> {
        self.open(STATUS, data)?;
        let h = &self.status;
        let raw = |hd: &SignalHandle| hd.raw(data).unwrap_or(0);
        let val = |hd: &SignalHandle| hd.decode(data).unwrap_or(0.0);
        let page = match raw(&h.page) {
            0 => {
                let p = &h.p0;
                StatusPage::Progress(Progress {
                    state: coded(State::from_code, "STATE", raw(&p[0]))?,
                    instruction: coded(InstructionCode::from_code, "INSTRUCTION", raw(&p[1]))?,
                    run_index: raw(&p[2]) as u8,
                    runs_total: raw(&p[3]) as u8,
                    direction: coded(WireDirection::from_code, "DIRECTION", raw(&p[4]))?,
                    start_point: coded(StartPoint::from_code, "START_POINT", raw(&p[5]))?,
                    run_distance_m: val(&p[6]),
                    writeback: coded(Writeback::from_code, "WRITEBACK", raw(&p[7]))?,
                    standstill: raw(&p[8]) == 1,
                    writeback_attempts: raw(&p[9]) as u8,
                    drift: raw(&p[10]) == 1,
                    drift_candidate: raw(&p[11]) == 1,
                })
            }
            1 => {
                let p = &h.p1;
                StatusPage::Counts(Counts {
                    cw_accepted: raw(&p[0]) as u8,
                    cw_rejected: raw(&p[1]) as u8,
                    ccw_accepted: raw(&p[2]) as u8,
                    ccw_rejected: raw(&p[3]) as u8,
                    reject_reason: coded(Reason::from_code, "REJECT_REASON", raw(&p[4]))?,
                    last_cmd: raw(&p[5]) as u8,
                    cmd_reason: coded(Reason::from_code, "CMD_REASON", raw(&p[6]))?,
                    active_version: raw(&p[7]) as u16,
                    cmd_seq: raw(&p[8]) as u8,
                })
            }
            2 => {
                let [a, b, c] = h.results[0].each_ref().map(val);
                StatusPage::ResultGeometry {
                    rear_tread_m: a,
                    rear_tread_std_m: b,
                    diameter_ratio: c,
                }
            }
            3 => {
                let [a, b, c] = h.results[1].each_ref().map(val);
                StatusPage::ResultQuality {
                    diameter_ratio_std: a,
                    end_err_before_m: b,
                    end_err_after_m: c,
                }
            }
            4 => {
                let [a, b, c] = h.results[2].each_ref().map(val);
                StatusPage::ResultSteering {
                    steer_gain: a,
                    steer_gain_std: b,
                    steer_offset_rad: c,
                }
            }
            5 => StatusPage::ResultExtra {
                steer_offset_std_rad: val(&h.results[3][0]),
                version: raw(&h.results[3][1]) as u16,
            },
            6 => {
                let p = &h.gnss;
                StatusPage::Gnss(GnssStatus {
                    source: GnssSourceKind::from_code(raw(&p[0]) as u8),
                    connected: raw(&p[1]) == 1,
                    fixes_per_s: val(&p[2]),
                    error_95_m: (raw(&p[3]) != GNSS_ERROR_NOT_STATED).then(|| val(&p[3])),
                    forwarded: raw(&p[4]) as u16,
                    refused: raw(&p[5]) as u8,
                    reconnects: raw(&p[6]) as u8,
                })
            }
            other => {
                return Err(WireError::UnknownCode {
                    message: STATUS,
                    signal: "PAGE",
                    raw: other,
                });
            }
        };
        Ok((page, self.counter_of(1, data)))
    }

    /// Raw values of a set in SET_CRC order (PARAM_VERSION first).
    fn param_raws(&self, set: &ParamSet) -> Result<[u64; 7]> {
        let values = [
            set.rear_tread_m,
            set.rear_left_diameter_m,
            set.rear_right_diameter_m,
            set.diameter_ratio,
            set.steer_gain,
            set.steer_offset_rad,
        ];
        let mut raws = [u64::from(set.version); 7];
        for (i, v) in values.into_iter().enumerate() {
            raws[i + 1] = self.params[i + 2]
                .scaled_to_raw(v)
                .ok_or(WireError::OutOfRange {
                    message: PARAMS,
                    signal: PARAM_SIGNALS[i],
                    value: v,
                })?;
        }
        Ok(raws)
    }

    /// SET_CRC of a set: CRC-16/CCITT-FALSE over the raw values, 2 bytes
    /// little-endian each, in the DBC comment's order.
    ///
    /// # Errors
    /// [`WireError::OutOfRange`] if a value does not fit its signal.
    pub fn set_crc(&self, set: &ParamSet) -> Result<u16> {
        let raws = self.param_raws(set)?;
        let crc = crc::Crc::<u16>::new(&crc::CRC_16_IBM_3740);
        let mut digest = crc.digest();
        for r in raws {
            digest.update(&(r as u16).to_le_bytes());
        }
        Ok(digest.finalize())
    }

    /// The four `CALIB_PARAMS` pages of a set, with counters `counter`,
    /// `counter + 1`, … (modulo 16).
    ///
    /// # Errors
    /// [`WireError::OutOfRange`] if a value does not fit its signal.
    pub fn encode_params(&self, set: &ParamSet, counter: u8) -> Result<[[u8; 8]; 4]> {
        let raws = self.param_raws(set)?;
        let set_crc = self.set_crc(set)?;
        let mut pages = [[0u8; 8]; 4];
        let layout: [&[(usize, u64)]; 4] = [
            &[(2, raws[1]), (8, u64::from(set_crc))],
            &[(3, raws[2]), (4, raws[3])],
            &[(5, raws[4]), (6, raws[5])],
            &[(7, raws[6])],
        ];
        for (page, (buf, fields)) in pages.iter_mut().zip(layout).enumerate() {
            self.params[0].encode_raw(page as u64, buf);
            self.params[1].encode_raw(u64::from(set.version), buf);
            for &(i, r) in fields {
                self.params[i].encode_raw(r, buf);
            }
            *buf = self.seal(2, counter.wrapping_add(page as u8), *buf);
        }
        Ok(pages)
    }

    /// Decodes one `CALIB_PARAMS` page (checksum verified) and its counter.
    ///
    /// # Errors
    /// [`WireError::ShortFrame`], [`WireError::BadChecksum`].
    pub fn decode_params(&self, data: &[u8]) -> Result<(ParamsPage, u8)> {
        self.open(PARAMS, data)?;
        let val = |i: usize| self.params[i].decode(data).unwrap_or(0.0);
        let raw = |i: usize| self.params[i].raw(data).unwrap_or(0);
        let data_ = match raw(0) {
            0 => ParamsData::TreadCrc {
                rear_tread_m: val(2),
                set_crc: raw(8) as u16,
            },
            1 => ParamsData::Diameters {
                rear_left_diameter_m: val(3),
                rear_right_diameter_m: val(4),
            },
            2 => ParamsData::RatioGain {
                diameter_ratio: val(5),
                steer_gain: val(6),
            },
            _ => ParamsData::Offset {
                steer_offset_rad: val(7),
            },
        };
        Ok((
            ParamsPage {
                version: raw(1) as u16,
                data: data_,
            },
            self.counter_of(2, data),
        ))
    }

    /// Encodes an acknowledgement.
    pub fn encode_ack(&self, ack: Ack, counter: u8) -> [u8; 8] {
        let mut buf = [0u8; 8];
        self.ack[0].encode_raw(u64::from(ack.version), &mut buf);
        self.ack[1].encode_raw(u64::from(ack.status.code()), &mut buf);
        self.ack[2].encode_raw(u64::from(ack.set_crc), &mut buf);
        self.seal(3, counter, buf)
    }

    /// Decodes an acknowledgement (checksum verified) and its counter.
    ///
    /// # Errors
    /// [`WireError::ShortFrame`], [`WireError::BadChecksum`],
    /// [`WireError::UnknownCode`] for an undefined ACK_STATUS.
    pub fn decode_ack(&self, data: &[u8]) -> Result<(Ack, u8)> {
        self.open(ACK, data)?;
        let raw = self.ack[1].raw(data).unwrap_or(0);
        let status = u8::try_from(raw)
            .ok()
            .and_then(AckStatus::from_code)
            .ok_or(WireError::UnknownCode {
                message: ACK,
                signal: "ACK_STATUS",
                raw,
            })?;
        Ok((
            Ack {
                version: self.ack[0].raw(data).unwrap_or(0) as u16,
                status,
                set_crc: self.ack[2].raw(data).unwrap_or(0) as u16,
            },
            self.counter_of(3, data),
        ))
    }

    /// `AUTH_LOCKOUT` of a page-0 `CALIB_STATUS` payload (reserved, always
    /// 0 since issue #33: an unauthenticated lockout hint helped only an
    /// attacker); `None` for another page or a bad CRC.
    pub fn auth_lockout(&self, data: &[u8]) -> Option<bool> {
        if !self.checksum_ok(data) || self.status.page.raw(data) != Some(0) {
            return None;
        }
        self.auth_lockout.raw(data).map(|r| r == 1)
    }

    /// A frame at `id` with `data` (helper for senders).
    ///
    /// # Errors
    /// Never for 8-byte payloads.
    pub fn frame(id: FrameId, data: &[u8; 8]) -> Result<CanFrame> {
        Ok(CanFrame::new_data(id, data)?)
    }
}

/// A coded `CALIB_STATUS` field, or why not.
fn coded<T>(f: fn(u8) -> Option<T>, signal: &'static str, raw: u64) -> Result<T> {
    u8::try_from(raw)
        .ok()
        .and_then(f)
        .ok_or(WireError::UnknownCode {
            message: STATUS,
            signal,
            raw,
        })
}

fn put_all(handles: &[SignalHandle; 3], values: [f64; 3], buf: &mut [u8]) {
    for (h, v) in handles.iter().zip(values) {
        h.encode_saturating(v, buf);
    }
}

#[cfg(test)]
mod tests;
