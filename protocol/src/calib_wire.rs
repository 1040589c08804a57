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
use canodom_calib::calibrator::Refused;
use canodom_calib::run::Rejection;
use canodom_calib::session::{Instruction, Phase, Refusal};
use canodom_calib::track::Direction;
use canodom_can::frame::{CanFrame, FrameError, FrameId};
use canodom_dbc::{Checksum, Database, SignalHandle};
use std::sync::Arc;

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

/// Declares a coded enum: variant ↔ wire code ↔ DBC `VAL_` name.
macro_rules! wire_codes {
    ($(#[$meta:meta])* $name:ident { $($(#[$vmeta:meta])* $var:ident = $code:literal => $text:literal,)+ }) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        pub enum $name {
            $($(#[$vmeta])* $var,)+
        }

        impl $name {
            /// Every value, in code order.
            pub const ALL: &'static [Self] = &[$(Self::$var,)+];

            /// The wire code.
            pub fn code(self) -> u8 {
                match self { $(Self::$var => $code,)+ }
            }

            /// The value of a wire code, `None` for an undefined one.
            pub fn from_code(code: u8) -> Option<Self> {
                match code { $($code => Some(Self::$var),)+ _ => None }
            }

            /// The name in the DBC's value table.
            pub fn name(self) -> &'static str {
                match self { $(Self::$var => $text,)+ }
            }
        }

        impl std::fmt::Display for $name {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(self.name())
            }
        }
    };
}

wire_codes! {
    /// `CALIB_CMD.CMD` (also `CALIB_STATUS.LAST_CMD`).
    CmdCode {
        /// No command (refused as unknown).
        None = 0 => "NONE",
        /// Start a session.
        StartSession = 1 => "START_SESSION",
        /// Start the steering calibration (§10).
        StartSteering = 2 => "START_STEERING",
        /// End the current run by hand.
        EndRun = 3 => "END_RUN",
        /// The measured real end pose of the last run.
        EndPose = 4 => "END_POSE",
        /// Drop the session.
        Abort = 5 => "ABORT",
        /// Compute the calibration.
        Compute = 6 => "COMPUTE",
        /// Commit the computed set.
        Commit = 7 => "COMMIT",
        /// Roll back to the previous set.
        Rollback = 8 => "ROLLBACK",
        /// Send the set in use as `CALIB_PARAMS`.
        RequestParams = 9 => "REQUEST_PARAMS",
        /// Start recording the next run now.
        StartRun = 10 => "START_RUN",
        /// Start recording a drive for calibration against the bus's position fixes.
        StartDrive = 11 => "START_DRIVE",
    }
}

wire_codes! {
    /// `CALIB_STATUS.STATE`: the session's [`Phase`].
    State {
        /// No session.
        Idle = 0 => "IDLE",
        /// Waiting for the car at the next run's start point.
        Positioning = 1 => "POSITIONING",
        /// Recording a run.
        Recording = 2 => "RECORDING",
        /// Waiting for the measured end pose of the last run.
        AwaitingEndPose = 3 => "AWAITING_END_POSE",
        /// All runs accepted.
        Ready = 4 => "READY",
        /// Computing.
        Computing = 5 => "COMPUTING",
        /// A result awaits commit.
        Computed = 6 => "COMPUTED",
    }
}

impl State {
    /// The wire state of a session phase.
    pub fn of(phase: Phase) -> Self {
        match phase {
            Phase::Idle => Self::Idle,
            Phase::Positioning => Self::Positioning,
            Phase::Recording => Self::Recording,
            Phase::AwaitingEndPose => Self::AwaitingEndPose,
            Phase::Ready => Self::Ready,
            Phase::Computing => Self::Computing,
            Phase::Computed => Self::Computed,
        }
    }

    /// Whether a session is active (status at 10 Hz).
    pub fn is_active(self) -> bool {
        self != Self::Idle
    }
}

wire_codes! {
    /// `CALIB_STATUS.INSTRUCTION`: the kind of [`Instruction`] (same codes).
    InstructionCode {
        /// No session.
        None = 0 => "NONE",
        /// Refit the steering map with calibrated rear odometry (§10).
        RefitSteering = 1 => "REFIT_STEERING",
        /// Drive to START_POINT, stop and wait.
        GoToStart = 2 => "GO_TO_START",
        /// Standing at the start: drive run RUN_INDEX in DIRECTION.
        Go = 3 => "GO",
        /// Recording: keep following the track.
        Drive = 4 => "DRIVE",
        /// The lap is nearly done: stop at the start point.
        Stop = 5 => "STOP",
        /// Measure the real end pose and send END_POSE.
        MeasureEndPose = 6 => "MEASURE_END_POSE",
        /// All runs recorded: send COMPUTE.
        ReadyToCompute = 7 => "READY_TO_COMPUTE",
        /// Wait.
        Wait = 8 => "WAIT",
        /// Review the result: COMMIT or ABORT.
        ReviewResult = 9 => "REVIEW_RESULT",
    }
}

impl InstructionCode {
    /// The code of a session instruction (equal to [`Instruction::code`]).
    pub fn of(instruction: &Instruction) -> Self {
        match instruction {
            Instruction::Idle => Self::None,
            Instruction::RefitSteering => Self::RefitSteering,
            Instruction::GoToStart { .. } => Self::GoToStart,
            Instruction::Go { .. } => Self::Go,
            Instruction::Drive { .. } => Self::Drive,
            Instruction::Stop { .. } => Self::Stop,
            Instruction::MeasureEndPose { .. } => Self::MeasureEndPose,
            Instruction::ReadyToCompute => Self::ReadyToCompute,
            Instruction::Wait => Self::Wait,
            Instruction::ReviewResult => Self::ReviewResult,
        }
    }
}

wire_codes! {
    /// `CALIB_STATUS.DIRECTION`.
    WireDirection {
        /// No run applies.
        None = 0 => "NONE",
        /// Clockwise.
        Cw = 1 => "CW",
        /// Counter-clockwise.
        Ccw = 2 => "CCW",
    }
}

impl WireDirection {
    /// The wire value of a direction.
    pub fn of(direction: Option<Direction>) -> Self {
        match direction {
            None => Self::None,
            Some(Direction::Cw) => Self::Cw,
            Some(Direction::Ccw) => Self::Ccw,
        }
    }

    /// The direction, `None` for NONE.
    pub fn direction(self) -> Option<Direction> {
        match self {
            Self::None => None,
            Self::Cw => Some(Direction::Cw),
            Self::Ccw => Some(Direction::Ccw),
        }
    }
}

wire_codes! {
    /// `CALIB_STATUS.START_POINT`: where the next run starts (each direction
    /// has its own start point on the track, `docs/calibration-math.md`).
    StartPoint {
        /// No run applies.
        None = 0 => "NONE",
        /// The counter-clockwise start point.
        SCcw = 1 => "S_CCW",
        /// The clockwise start point.
        SCw = 2 => "S_CW",
    }
}

impl StartPoint {
    /// The start point of a run direction.
    pub fn of(direction: Option<Direction>) -> Self {
        match direction {
            None => Self::None,
            Some(Direction::Ccw) => Self::SCcw,
            Some(Direction::Cw) => Self::SCw,
        }
    }
}

wire_codes! {
    /// `CALIB_STATUS.WRITEBACK`.
    Writeback {
        /// Nothing sent yet.
        Idle = 0 => "IDLE",
        /// Sent, waiting for `CALIB_ACK`.
        Pending = 1 => "PENDING",
        /// The parameter store acknowledged the version.
        Acked = 2 => "ACKED",
        /// No (or a refusing) acknowledgement after the retries; the set stays applied.
        Failed = 3 => "FAILED",
    }
}

wire_codes! {
    /// `CALIB_STATUS.REJECT_REASON` and `CMD_REASON`: one table.
    Reason {
        /// Accepted / carried out.
        None = 0 => "NONE",
        /// [`Refusal::NoSession`].
        NoSession = 1 => "NO_SESSION",
        /// [`Refusal::SessionActive`].
        SessionActive = 2 => "SESSION_ACTIVE",
        /// [`Refusal::InvalidArgument`].
        InvalidArgument = 3 => "INVALID_ARGUMENT",
        /// [`Refusal::AlreadyRecording`].
        AlreadyRecording = 4 => "ALREADY_RECORDING",
        /// [`Refusal::NotRecording`].
        NotRecording = 5 => "NOT_RECORDING",
        /// [`Refusal::NoRunForEndPose`].
        NoRunForEndPose = 6 => "NO_RUN_FOR_END_POSE",
        /// [`Refusal::EndPoseRequired`].
        EndPoseRequired = 7 => "END_POSE_REQUIRED",
        /// [`Refusal::RunsIncomplete`].
        RunsIncomplete = 8 => "RUNS_INCOMPLETE",
        /// [`Refusal::NotComputing`].
        NotComputing = 9 => "NOT_COMPUTING",
        /// [`Refusal::NothingToCommit`].
        NothingToCommit = 10 => "NOTHING_TO_COMMIT",
        /// [`Refusal::NothingToRollback`].
        NothingToRollback = 11 => "NOTHING_TO_ROLLBACK",
        /// [`Refusal::Busy`].
        Busy = 12 => "BUSY",
        /// [`Refusal::AllRunsDone`].
        AllRunsDone = 13 => "ALL_RUNS_DONE",
        /// [`Rejection::TooFewSamples`].
        TooFewSamples = 14 => "TOO_FEW_SAMPLES",
        /// [`Rejection::LengthOff`]: distance off the track length by more than the tolerance.
        LengthOff = 15 => "LENGTH_OFF",
        /// [`Rejection::TurnOff`]: total turn not ±2π in the announced direction.
        TurnOff = 16 => "TURN_OFF",
        /// [`Rejection::InputFault`].
        InputFault = 17 => "INPUT_FAULT",
        /// [`Rejection::SteeringInconsistent`].
        SteeringInconsistent = 18 => "STEERING_INCONSISTENT",
        /// The arming code differs from the configured one.
        BadArmingCode = 19 => "BAD_ARMING_CODE",
        /// Byte 7 is not the CRC-8 of bytes 0..=6.
        BadChecksum = 20 => "BAD_CHECKSUM",
        /// The counter repeated the previous command's (a duplicate frame).
        BadCounter = 21 => "BAD_COUNTER",
        /// CMD holds no defined command.
        UnknownCommand = 22 => "UNKNOWN_COMMAND",
        /// Parameters change only at standstill.
        NotAtStandstill = 23 => "NOT_AT_STANDSTILL",
        /// The result lies outside the configured bounds around the nominal values.
        OutOfBounds = 24 => "OUT_OF_BOUNDS",
        /// The result's uncertainty exceeds the configured limit.
        UncertaintyTooHigh = 25 => "UNCERTAINTY_TOO_HIGH",
        /// The calibration job failed (runs kept: compute again or abort).
        ComputeFailed = 26 => "COMPUTE_FAILED",
        /// The parameter file could not be written (nothing changed).
        PersistFailed = 27 => "PERSIST_FAILED",
        /// The command is defined but this daemon does not carry it out.
        NotSupported = 28 => "NOT_SUPPORTED",
        /// The write-back is still waiting for its acknowledgement.
        WritebackBusy = 29 => "WRITEBACK_BUSY",
    }
}

impl Reason {
    /// The wire reason of a session refusal (same code).
    pub fn of_refusal(refusal: Refusal) -> Self {
        match refusal {
            Refusal::NoSession => Self::NoSession,
            Refusal::SessionActive => Self::SessionActive,
            Refusal::InvalidArgument => Self::InvalidArgument,
            Refusal::AlreadyRecording => Self::AlreadyRecording,
            Refusal::NotRecording => Self::NotRecording,
            Refusal::NoRunForEndPose => Self::NoRunForEndPose,
            Refusal::EndPoseRequired => Self::EndPoseRequired,
            Refusal::RunsIncomplete => Self::RunsIncomplete,
            Refusal::NotComputing => Self::NotComputing,
            Refusal::NothingToCommit => Self::NothingToCommit,
            Refusal::NothingToRollback => Self::NothingToRollback,
            Refusal::Busy => Self::Busy,
            Refusal::AllRunsDone => Self::AllRunsDone,
        }
    }

    /// The wire reason of a refused live-calibration command.
    pub fn of_refused(refused: Refused) -> Self {
        match refused {
            Refused::Session(refusal) => Self::of_refusal(refusal),
            Refused::OutOfBounds => Self::OutOfBounds,
            Refused::UncertaintyTooHigh => Self::UncertaintyTooHigh,
            Refused::ComputeFailed => Self::ComputeFailed,
            Refused::PersistFailed => Self::PersistFailed,
            Refused::NotSupported => Self::NotSupported,
            Refused::WritebackBusy => Self::WritebackBusy,
            Refused::TooFewSamples => Self::TooFewSamples,
        }
    }

    /// The wire reason of a run rejection (`13 +` [`Rejection::code`]).
    pub fn of_rejection(rejection: &Rejection) -> Self {
        match rejection {
            Rejection::TooFewSamples { .. } => Self::TooFewSamples,
            Rejection::LengthOff { .. } => Self::LengthOff,
            Rejection::TurnOff { .. } => Self::TurnOff,
            Rejection::InputFault { .. } => Self::InputFault,
            Rejection::SteeringInconsistent { .. } => Self::SteeringInconsistent,
        }
    }
}

wire_codes! {
    /// `CALIB_ACK.ACK_STATUS`.
    AckStatus {
        /// The set was stored.
        Stored = 0 => "STORED",
        /// The store refused the set.
        Refused = 1 => "REFUSED",
    }
}

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

/// Handles of `CALIB_STATUS` signals.
#[derive(Debug)]
struct StatusHandles {
    page: SignalHandle,
    p0: [SignalHandle; 10],
    p1: [SignalHandle; 9],
    results: [[SignalHandle; 3]; 4],
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
            status: StatusHandles {
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
            },
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

/// Collects the four pages of one `CALIB_PARAMS` set, as a parameter store
/// does, and yields the set once all arrived with a matching SET_CRC.
#[derive(Debug, Default, Clone)]
pub struct ParamsAssembler {
    version: Option<u16>,
    pages: [Option<ParamsData>; 4],
}

impl ParamsAssembler {
    /// Adds a page; pages of another version restart the set. Returns the set
    /// when complete: `Ok` if SET_CRC matches, `Err(set)` if not.
    pub fn push(
        &mut self,
        wire: &CalibWire,
        page: ParamsPage,
    ) -> Option<std::result::Result<ParamSet, ParamSet>> {
        if self.version != Some(page.version) {
            *self = Self {
                version: Some(page.version),
                ..Self::default()
            };
        }
        let slot = match page.data {
            ParamsData::TreadCrc { .. } => 0,
            ParamsData::Diameters { .. } => 1,
            ParamsData::RatioGain { .. } => 2,
            ParamsData::Offset { .. } => 3,
        };
        self.pages[slot] = Some(page.data);
        let [
            Some(ParamsData::TreadCrc {
                rear_tread_m,
                set_crc,
            }),
            Some(ParamsData::Diameters {
                rear_left_diameter_m,
                rear_right_diameter_m,
            }),
            Some(ParamsData::RatioGain {
                diameter_ratio,
                steer_gain,
            }),
            Some(ParamsData::Offset { steer_offset_rad }),
        ] = self.pages
        else {
            return None;
        };
        let set = ParamSet {
            version: page.version,
            rear_tread_m,
            rear_left_diameter_m,
            rear_right_diameter_m,
            diameter_ratio,
            steer_gain,
            steer_offset_rad,
        };
        *self = Self::default();
        Some(match wire.set_crc(&set) {
            Ok(crc) if crc == set_crc => Ok(set),
            _ => Err(set),
        })
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
mod tests {
    use super::*;
    use std::collections::HashSet;

    #[test]
    fn auth_lockout_is_always_0_on_page_0_and_absent_elsewhere() {
        let w = wire();
        let p0 = StatusPage::Progress(Progress {
            state: State::Idle,
            instruction: InstructionCode::None,
            run_index: 0,
            runs_total: 0,
            direction: WireDirection::None,
            start_point: StartPoint::None,
            run_distance_m: 0.0,
            writeback: Writeback::Idle,
            standstill: true,
            writeback_attempts: 0,
        });
        assert_eq!(w.auth_lockout(&w.encode_status(&p0, 3)), Some(false));
        let p5 = w.encode_status(
            &StatusPage::ResultExtra {
                steer_offset_std_rad: 0.0,
                version: 1,
            },
            0,
        );
        assert_eq!(w.auth_lockout(&p5), None);
    }

    fn wire() -> CalibWire {
        CalibWire::new(BaseId::DEFAULT).unwrap()
    }

    /// The DBC's `VAL_` table of `message.signal` as (code, name) pairs.
    fn table(w: &CalibWire, message: &str, signal: &str) -> Vec<(i64, String)> {
        w.database()
            .message_by_name(message)
            .unwrap()
            .signal(signal)
            .unwrap()
            .value_descriptions()
            .to_vec()
    }

    fn same_table(w: &CalibWire, message: &str, signal: &str, ours: Vec<(u8, &str)>) {
        let mut dbc = table(w, message, signal);
        dbc.sort_by_key(|(c, _)| *c);
        let ours: Vec<(i64, String)> = ours
            .into_iter()
            .map(|(c, n)| (i64::from(c), n.to_owned()))
            .collect();
        assert_eq!(dbc, ours, "{message}.{signal}");
    }

    macro_rules! pairs {
        ($t:ty) => {
            <$t>::ALL
                .iter()
                .map(|v| (v.code(), v.name()))
                .collect::<Vec<_>>()
        };
    }

    #[test]
    fn every_code_table_equals_the_dbc_value_table_and_round_trips() {
        let w = wire();
        same_table(&w, CMD, "CMD", pairs!(CmdCode));
        same_table(&w, STATUS, "LAST_CMD", pairs!(CmdCode));
        same_table(&w, STATUS, "STATE", pairs!(State));
        same_table(&w, STATUS, "INSTRUCTION", pairs!(InstructionCode));
        same_table(&w, STATUS, "DIRECTION", pairs!(WireDirection));
        same_table(&w, STATUS, "START_POINT", pairs!(StartPoint));
        same_table(&w, STATUS, "WRITEBACK", pairs!(Writeback));
        same_table(&w, STATUS, "REJECT_REASON", pairs!(Reason));
        same_table(&w, STATUS, "CMD_REASON", pairs!(Reason));
        same_table(&w, ACK, "ACK_STATUS", pairs!(AckStatus));
        for c in 0..=255u8 {
            if let Some(r) = Reason::from_code(c) {
                assert_eq!(r.code(), c);
            }
            if let Some(v) = CmdCode::from_code(c) {
                assert_eq!(v.code(), c);
            }
        }
    }

    #[test]
    fn every_refusal_and_rejection_has_its_own_reason() {
        use canodom_calib::run::InputFault;
        let refusals = (1..=13u8).map(|c| {
            let r = [
                Refusal::NoSession,
                Refusal::SessionActive,
                Refusal::InvalidArgument,
                Refusal::AlreadyRecording,
                Refusal::NotRecording,
                Refusal::NoRunForEndPose,
                Refusal::EndPoseRequired,
                Refusal::RunsIncomplete,
                Refusal::NotComputing,
                Refusal::NothingToCommit,
                Refusal::NothingToRollback,
                Refusal::Busy,
                Refusal::AllRunsDone,
            ][usize::from(c - 1)];
            assert_eq!(r.code(), c);
            let reason = Reason::of_refusal(r);
            assert_eq!(reason.code(), r.code());
            reason
        });
        let rejections = [
            Rejection::TooFewSamples { samples: 1 },
            Rejection::LengthOff {
                length_m: 1.0,
                expected_m: 2.0,
            },
            Rejection::TurnOff {
                total_turn_rad: 1.0,
                expected_rad: std::f64::consts::TAU,
            },
            Rejection::InputFault {
                count: 1,
                first_t_s: 0.0,
                first: InputFault::NonFinite,
            },
            Rejection::SteeringInconsistent {
                segment: 0,
                mean_angle_rad: 0.0,
                expected_rad: 0.1,
            },
        ]
        .map(|r| {
            let reason = Reason::of_rejection(&r);
            assert_eq!(reason.code(), 13 + r.code());
            reason
        });
        let all: Vec<Reason> = refusals.chain(rejections).collect();
        let distinct: HashSet<Reason> = all.iter().copied().collect();
        assert_eq!(distinct.len(), 18);
        assert!(!distinct.contains(&Reason::None));
    }

    #[test]
    fn states_and_instructions_follow_the_session_codes() {
        let phases = [
            Phase::Idle,
            Phase::Positioning,
            Phase::Recording,
            Phase::AwaitingEndPose,
            Phase::Ready,
            Phase::Computing,
            Phase::Computed,
        ];
        for (i, p) in phases.into_iter().enumerate() {
            assert_eq!(usize::from(State::of(p).code()), i);
        }
        let d = Direction::Cw;
        for ins in [
            Instruction::Idle,
            Instruction::RefitSteering,
            Instruction::GoToStart {
                run: 1,
                runs: 5,
                direction: d,
            },
            Instruction::Go {
                run: 1,
                runs: 5,
                direction: d,
            },
            Instruction::Drive {
                run: 1,
                runs: 5,
                direction: d,
            },
            Instruction::Stop { run: 1, runs: 5 },
            Instruction::MeasureEndPose { run: 1 },
            Instruction::ReadyToCompute,
            Instruction::Wait,
            Instruction::ReviewResult,
        ] {
            assert_eq!(InstructionCode::of(&ins).code(), ins.code());
        }
        for d in [None, Some(Direction::Cw), Some(Direction::Ccw)] {
            assert_eq!(WireDirection::of(d).direction(), d);
        }
    }

    #[test]
    fn every_command_round_trips_with_counter_and_crc() {
        let w = wire();
        let cmds = [
            Command::StartSession {
                track_radius_mm: 780,
                runs_per_direction: 5,
            },
            Command::StartSession {
                track_radius_mm: 65_535,
                runs_per_direction: 0,
            },
            Command::StartSteering,
            Command::EndRun,
            Command::EndPose {
                dx_mm: -8192,
                dy_mm: 8191,
                dtheta_decideg: -2048,
            },
            Command::EndPose {
                dx_mm: 12,
                dy_mm: -340,
                dtheta_decideg: 57,
            },
            Command::Abort,
            Command::Compute,
            Command::Commit,
            Command::Rollback,
            Command::RequestParams,
            Command::StartRun,
        ];
        for (k, cmd) in cmds.into_iter().enumerate() {
            let counter = (k % 16) as u8;
            let data = w.encode_command(cmd, 0xA5, counter);
            let f = w.decode_command(&data).unwrap();
            assert!(f.checksum_ok);
            assert_eq!(f.command, Some(cmd));
            assert_eq!(f.cmd_raw, cmd.code().code());
            assert_eq!((f.arming_code, f.counter), (0xA5, counter));
            // cantools' view: the multiplexed arguments decode to the same values.
            let m = w.database().message_by_name(CMD).unwrap();
            let names: Vec<&str> = m.decode(&data).unwrap().map(|(s, _)| s.name()).collect();
            match cmd {
                Command::StartSession { .. } => assert!(names.contains(&"TRACK_RADIUS")),
                Command::EndPose { .. } => assert!(names.contains(&"END_DTHETA")),
                _ => assert!(!names.contains(&"TRACK_RADIUS")),
            }
            let mut bad = data;
            bad[7] ^= 1;
            assert!(!w.decode_command(&bad).unwrap().checksum_ok);
        }
        let undefined = w.encode_command_raw(14, Command::Abort, 0, 3);
        let f = w.decode_command(&undefined).unwrap();
        assert_eq!((f.cmd_raw, f.command), (14, None));
        assert!(w.decode_command(&[0; 7]).is_err());
    }

    #[test]
    fn every_status_page_round_trips() {
        let w = wire();
        let pages = [
            StatusPage::Progress(Progress {
                state: State::Recording,
                instruction: InstructionCode::Drive,
                run_index: 3,
                runs_total: 5,
                direction: WireDirection::Cw,
                start_point: StartPoint::SCw,
                run_distance_m: 7.25,
                writeback: Writeback::Failed,
                standstill: true,
                writeback_attempts: 4,
            }),
            StatusPage::Counts(Counts {
                cw_accepted: 5,
                cw_rejected: 1,
                ccw_accepted: 4,
                ccw_rejected: 2,
                reject_reason: Reason::LengthOff,
                last_cmd: CmdCode::Commit.code(),
                cmd_reason: Reason::OutOfBounds,
                active_version: 65_535,
                cmd_seq: 6,
            }),
            StatusPage::ResultGeometry {
                rear_tread_m: 0.3101,
                rear_tread_std_m: 0.000_123,
                diameter_ratio: 1.015,
            },
            StatusPage::ResultQuality {
                diameter_ratio_std: 0.000_01,
                end_err_before_m: 0.529,
                end_err_after_m: 0.096,
            },
            StatusPage::ResultSteering {
                steer_gain: 0.98,
                steer_gain_std: 0.001,
                steer_offset_rad: -0.012,
            },
            StatusPage::ResultExtra {
                steer_offset_std_rad: 0.0005,
                version: 42,
            },
        ];
        for (k, page) in pages.iter().enumerate() {
            let data = w.encode_status(page, k as u8 + 9);
            let (back, counter) = w.decode_status(&data).unwrap();
            assert_eq!(counter, (k as u8 + 9) & 0x0F);
            assert_eq!(back.page(), page.page());
            close(&back, page);
            let mut bad = data;
            bad[2] ^= 0x10;
            assert!(matches!(
                w.decode_status(&bad),
                Err(WireError::BadChecksum { .. })
            ));
        }
        // Out-of-range values clamp rather than wrap.
        let huge = StatusPage::ResultQuality {
            diameter_ratio_std: 1.0,
            end_err_before_m: 1e6,
            end_err_after_m: f64::NAN,
        };
        let (back, _) = w.decode_status(&w.encode_status(&huge, 0)).unwrap();
        let StatusPage::ResultQuality {
            diameter_ratio_std,
            end_err_before_m,
            end_err_after_m,
        } = back
        else {
            panic!("page 3 expected")
        };
        assert!((diameter_ratio_std - 0.065_535).abs() < 1e-9);
        assert!((end_err_before_m - 65.535).abs() < 1e-9);
        assert_eq!(end_err_after_m, 0.0);
    }

    fn close(a: &StatusPage, b: &StatusPage) {
        let num = |p: &StatusPage| -> Vec<f64> {
            match *p {
                StatusPage::Progress(p) => vec![p.run_distance_m],
                StatusPage::Counts(_) => vec![],
                StatusPage::ResultGeometry {
                    rear_tread_m,
                    rear_tread_std_m,
                    diameter_ratio,
                } => vec![rear_tread_m, rear_tread_std_m, diameter_ratio],
                StatusPage::ResultQuality {
                    diameter_ratio_std,
                    end_err_before_m,
                    end_err_after_m,
                } => vec![diameter_ratio_std, end_err_before_m, end_err_after_m],
                StatusPage::ResultSteering {
                    steer_gain,
                    steer_gain_std,
                    steer_offset_rad,
                } => vec![steer_gain, steer_gain_std, steer_offset_rad],
                StatusPage::ResultExtra {
                    steer_offset_std_rad,
                    ..
                } => vec![steer_offset_std_rad],
            }
        };
        for (x, y) in num(a).into_iter().zip(num(b)) {
            assert!((x - y).abs() < 1e-4 * y.abs().max(0.01), "{a:?} vs {b:?}");
        }
        match (a, b) {
            (StatusPage::Progress(x), StatusPage::Progress(y)) => {
                assert_eq!(
                    Progress {
                        run_distance_m: 0.0,
                        ..*x
                    },
                    Progress {
                        run_distance_m: 0.0,
                        ..*y
                    }
                );
            }
            (StatusPage::Counts(x), StatusPage::Counts(y)) => assert_eq!(x, y),
            (
                StatusPage::ResultExtra { version: x, .. },
                StatusPage::ResultExtra { version: y, .. },
            ) => assert_eq!(x, y),
            _ => {}
        }
    }

    fn set() -> ParamSet {
        ParamSet {
            version: 7,
            rear_tread_m: 0.3102,
            rear_left_diameter_m: 0.08944,
            rear_right_diameter_m: 0.09078,
            diameter_ratio: 1.01498,
            steer_gain: 0.98765,
            steer_offset_rad: -0.01234,
        }
    }

    #[test]
    fn params_round_trip_through_the_assembler_and_a_corrupt_set_crc_is_caught() {
        let w = wire();
        let pages = w.encode_params(&set(), 14).unwrap();
        let mut asm = ParamsAssembler::default();
        let mut out = None;
        for (i, p) in pages.iter().enumerate() {
            let (page, counter) = w.decode_params(p).unwrap();
            assert_eq!(counter, (14 + i as u8) & 0x0F);
            assert_eq!(page.version, 7);
            out = asm.push(&w, page);
            assert_eq!(out.is_some(), i == 3);
        }
        let got = out.unwrap().unwrap();
        let want = set();
        for (g, e) in [
            (got.rear_tread_m, want.rear_tread_m),
            (got.rear_left_diameter_m, want.rear_left_diameter_m),
            (got.rear_right_diameter_m, want.rear_right_diameter_m),
            (got.diameter_ratio, want.diameter_ratio),
            (got.steer_gain, want.steer_gain),
            (got.steer_offset_rad, want.steer_offset_rad),
        ] {
            assert!((g - e).abs() < 2e-5, "{g} vs {e}");
        }
        // A page whose value changed but whose SET_CRC did not: caught.
        let mut p0 = pages[0];
        w.params[2].encode_raw(3202, &mut p0);
        let p0 = w.seal(2, 0, p0);
        let mut asm = ParamsAssembler::default();
        let mut last = None;
        for p in [p0, pages[1], pages[2], pages[3]] {
            last = asm.push(&w, w.decode_params(&p).unwrap().0);
        }
        assert!(last.unwrap().is_err(), "changed tread, old SET_CRC");
        // Corrupt SET_CRC itself.
        let mut asm = ParamsAssembler::default();
        let crc_h = w.params[8];
        let mut p0 = pages[0];
        crc_h.encode_raw(u64::from(w.set_crc(&want).unwrap() ^ 1), &mut p0);
        let p0 = w.seal(2, 0, p0);
        let mut last = None;
        for p in [p0, pages[1], pages[2], pages[3]] {
            last = asm.push(&w, w.decode_params(&p).unwrap().0);
        }
        assert!(last.unwrap().is_err());
        // Unrepresentable values are an error, not a wrap.
        let mut absurd = want;
        absurd.rear_tread_m = 9.0;
        assert!(matches!(
            w.encode_params(&absurd, 0),
            Err(WireError::OutOfRange { .. })
        ));
    }

    #[test]
    fn set_crc_matches_the_documented_algorithm() {
        // CRC-16/CCITT-FALSE check value of "123456789" (the catalogue's).
        let crc = crc::Crc::<u16>::new(&crc::CRC_16_IBM_3740);
        assert_eq!(crc.checksum(b"123456789"), 0x29B1);
        let w = wire();
        let s = set();
        let raws = w.param_raws(&s).unwrap();
        let bytes: Vec<u8> = raws
            .iter()
            .flat_map(|r| (*r as u16).to_le_bytes())
            .collect();
        assert_eq!(w.set_crc(&s).unwrap(), crc.checksum(&bytes));
        assert_eq!(raws[1], 3102);
    }

    #[test]
    fn ack_round_trips() {
        let w = wire();
        for (v, st, crc) in [
            (0u16, AckStatus::Stored, 0u16),
            (65_535, AckStatus::Refused, 0xBEEF),
            (7, AckStatus::Stored, 0xFFFF),
        ] {
            let data = w.encode_ack(
                Ack {
                    version: v,
                    status: st,
                    set_crc: crc,
                },
                5,
            );
            let (ack, c) = w.decode_ack(&data).unwrap();
            assert_eq!((ack.version, ack.status, ack.set_crc, c), (v, st, crc, 5));
        }
        let mut data = w.encode_ack(
            Ack {
                version: 1,
                status: AckStatus::Stored,
                set_crc: 0,
            },
            0,
        );
        data[0] ^= 1;
        assert!(w.decode_ack(&data).is_err());
        let ext = CalibWire::new(BaseId::new(0x18FF_0000, true).unwrap()).unwrap();
        assert_eq!(ext.ack_id(), FrameId::Extended(0x18FF_0013));
        assert_eq!(wire().cmd_id(), FrameId::Standard(0x610));
    }
}
