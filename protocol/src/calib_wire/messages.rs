//! The typed values the four calibration frames carry (a command with its
//! arguments, the status pages, a parameter set and its pages, the
//! acknowledgement), apart from how the codec packs them into bytes.

use super::codes::{
    AckStatus, CmdCode, InstructionCode, Reason, StartPoint, State, WireDirection, Writeback,
};

/// A calibration command with its arguments.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// Start a session on the stadium track of semicircle radius `track_radius_mm`.
    StartSession {
        /// ρ, millimetres.
        track_radius_mm: u16,
        /// Runs per direction, 1..=15; 0 on the wire means the default of 5.
        runs_per_direction: u8,
    },
    /// Start the steering calibration.
    StartSteering,
    /// End the current run now.
    EndRun,
    /// The measured real end pose of the last run, relative to its start pose.
    EndPose {
        /// x, millimetres (−8192..=8191).
        dx_mm: i16,
        /// y, millimetres (−8192..=8191).
        dy_mm: i16,
        /// Heading, tenths of a degree (−2048..=2047), CCW positive.
        dtheta_decideg: i16,
    },
    /// Drop the session.
    Abort,
    /// Compute.
    Compute,
    /// Commit the computed set.
    Commit,
    /// Roll back to the previous set.
    Rollback,
    /// Send the set in use.
    RequestParams,
    /// Start recording the next run now.
    StartRun,
    /// Start recording a drive (wheels, steering, yaw rate and the bus's
    /// position fixes) for calibration without a track; COMPUTE fits it,
    /// COMMIT commits it, ABORT drops it.
    StartDrive,
}

/// Runs per direction when START_SESSION says 0.
pub const DEFAULT_RUNS_PER_DIRECTION: u8 = 5;

impl Command {
    /// The command's code.
    pub fn code(self) -> CmdCode {
        match self {
            Self::StartSession { .. } => CmdCode::StartSession,
            Self::StartSteering => CmdCode::StartSteering,
            Self::EndRun => CmdCode::EndRun,
            Self::EndPose { .. } => CmdCode::EndPose,
            Self::Abort => CmdCode::Abort,
            Self::Compute => CmdCode::Compute,
            Self::Commit => CmdCode::Commit,
            Self::Rollback => CmdCode::Rollback,
            Self::RequestParams => CmdCode::RequestParams,
            Self::StartRun => CmdCode::StartRun,
            Self::StartDrive => CmdCode::StartDrive,
        }
    }
}

/// A decoded `CALIB_CMD` frame, checks not yet judged: the receiver decides
/// what a bad checksum, counter or arming code means.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CommandFrame {
    /// The raw CMD field.
    pub cmd_raw: u8,
    /// The command, `None` when CMD is undefined (or NONE).
    pub command: Option<Command>,
    /// The ARMING_CODE field.
    pub arming_code: u8,
    /// The rolling counter.
    pub counter: u8,
    /// Whether byte 7 is the CRC-8 of bytes 0..=6.
    pub checksum_ok: bool,
}

/// `CALIB_STATUS` page 0: progress.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Progress {
    /// Session state.
    pub state: State,
    /// What to do next.
    pub instruction: InstructionCode,
    /// Run k (1-based) to drive or being driven; 0 when none applies.
    pub run_index: u8,
    /// Runs per direction n.
    pub runs_total: u8,
    /// Direction of that run.
    pub direction: WireDirection,
    /// Where it starts.
    pub start_point: StartPoint,
    /// Distance driven in the current run, metres (0.01 m resolution).
    pub run_distance_m: f64,
    /// Write-back state.
    pub writeback: Writeback,
    /// Whether the vehicle stands still.
    pub standstill: bool,
    /// CALIB_PARAMS sends of the current write-back (0..=7, saturating).
    pub writeback_attempts: u8,
    /// The drift watch flags a parameter (`DRIFT`).
    pub drift: bool,
    /// A learnt set awaits COMMIT outside any session (`DRIFT_CANDIDATE`).
    pub drift_candidate: bool,
}

/// `CALIB_STATUS` page 1: counts and the answer to the last command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Counts {
    /// Clockwise runs accepted.
    pub cw_accepted: u8,
    /// Clockwise runs rejected.
    pub cw_rejected: u8,
    /// Counter-clockwise runs accepted.
    pub ccw_accepted: u8,
    /// Counter-clockwise runs rejected.
    pub ccw_rejected: u8,
    /// Why the last run was rejected; NONE if accepted.
    pub reject_reason: Reason,
    /// CMD field of the last command received (raw: it may be undefined).
    pub last_cmd: u8,
    /// NONE when it was carried out, else why it was refused.
    pub cmd_reason: Reason,
    /// Version of the set applied to live odometry; 0 for nominal.
    pub active_version: u16,
    /// Commands answered so far, modulo 8.
    pub cmd_seq: u8,
}

/// Which live GNSS source `[gnss]` names (`GNSS_SOURCE`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GnssSourceKind {
    /// No source (a page that says nothing is running).
    None,
    /// gpsd's JSON on TCP.
    Gpsd,
    /// A receiver's NMEA read from a serial port.
    Nmea,
    /// A ROS 2 `NavSatFix` topic.
    Ros2,
}

impl GnssSourceKind {
    /// The wire code.
    pub fn code(self) -> u8 {
        match self {
            Self::None => 0,
            Self::Gpsd => 1,
            Self::Nmea => 2,
            Self::Ros2 => 3,
        }
    }

    /// The kind of a wire code (2 bits: every code is defined).
    pub fn from_code(code: u8) -> Self {
        match code & 3 {
            1 => Self::Gpsd,
            2 => Self::Nmea,
            3 => Self::Ros2,
            _ => Self::None,
        }
    }
}

/// `CALIB_STATUS` page 6: the live GNSS source (#46), sent while `[gnss]`
/// is configured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GnssStatus {
    /// Which source.
    pub source: GnssSourceKind,
    /// Connected (socket or device open, topic's fixes arriving).
    pub connected: bool,
    /// Accepted fixes per second (0.1 resolution, up to 25.5).
    pub fixes_per_s: f64,
    /// The last fix's 95 % horizontal error estimate, metres (0.1 m
    /// resolution, up to 409.5); `None` when the source stated none.
    pub error_95_m: Option<f64>,
    /// Fixes handed to the calibration, modulo 65536.
    pub forwarded: u16,
    /// Reports refused, saturating at 255.
    pub refused: u8,
    /// Reconnection attempts, saturating at 3.
    pub reconnects: u8,
}

/// A `CALIB_STATUS` frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StatusPage {
    /// Page 0.
    Progress(Progress),
    /// Page 1.
    Counts(Counts),
    /// Page 2.
    ResultGeometry {
        /// Effective rear tread, m.
        rear_tread_m: f64,
        /// Its standard deviation, m.
        rear_tread_std_m: f64,
        /// Diameter ratio right over left.
        diameter_ratio: f64,
    },
    /// Page 3.
    ResultQuality {
        /// Standard deviation of the ratio.
        diameter_ratio_std: f64,
        /// End error with the nominal parameters, m.
        end_err_before_m: f64,
        /// End error with the computed ones, m.
        end_err_after_m: f64,
    },
    /// Page 4.
    ResultSteering {
        /// Steering gain.
        steer_gain: f64,
        /// Its standard deviation.
        steer_gain_std: f64,
        /// Steering offset, rad.
        steer_offset_rad: f64,
    },
    /// Page 5.
    ResultExtra {
        /// Standard deviation of the offset, rad.
        steer_offset_std_rad: f64,
        /// Version the computed set will have when committed.
        version: u16,
    },
    /// Page 6.
    Gnss(GnssStatus),
}

impl StatusPage {
    /// The page number (the PAGE multiplexor).
    pub fn page(&self) -> u8 {
        match self {
            Self::Progress(_) => 0,
            Self::Counts(_) => 1,
            Self::ResultGeometry { .. } => 2,
            Self::ResultQuality { .. } => 3,
            Self::ResultSteering { .. } => 4,
            Self::ResultExtra { .. } => 5,
            Self::Gnss(_) => 6,
        }
    }
}

/// A calibrated parameter set as `CALIB_PARAMS` carries it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParamSet {
    /// Version (increases with every commit).
    pub version: u16,
    /// Effective rear tread, m.
    pub rear_tread_m: f64,
    /// Rear-left diameter, m.
    pub rear_left_diameter_m: f64,
    /// Rear-right diameter, m.
    pub rear_right_diameter_m: f64,
    /// Right over left.
    pub diameter_ratio: f64,
    /// Steering gain.
    pub steer_gain: f64,
    /// Steering offset, rad.
    pub steer_offset_rad: f64,
}

/// The payload of one `CALIB_PARAMS` page.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ParamsData {
    /// Page 0.
    TreadCrc {
        /// Rear tread, m.
        rear_tread_m: f64,
        /// CRC-16 over the set's raw values.
        set_crc: u16,
    },
    /// Page 1.
    Diameters {
        /// Rear-left, m.
        rear_left_diameter_m: f64,
        /// Rear-right, m.
        rear_right_diameter_m: f64,
    },
    /// Page 2.
    RatioGain {
        /// Right over left.
        diameter_ratio: f64,
        /// Steering gain.
        steer_gain: f64,
    },
    /// Page 3.
    Offset {
        /// Steering offset, rad.
        steer_offset_rad: f64,
    },
}

/// A decoded `CALIB_PARAMS` frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParamsPage {
    /// The set's version.
    pub version: u16,
    /// The page's payload.
    pub data: ParamsData,
}

/// A `CALIB_ACK`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Ack {
    /// The echoed PARAM_VERSION.
    pub version: u16,
    /// Stored or refused.
    pub status: AckStatus,
    /// The echoed SET_CRC of the set acknowledged (#33): an acknowledgement
    /// of another set under the same version does not match.
    pub set_crc: u16,
}
