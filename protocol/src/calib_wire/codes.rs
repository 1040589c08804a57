//! The coded fields of the calibration frames: each an enum whose variants
//! are its DBC `VAL_` table (code and name), with the mappings from the
//! session's own types, so both ends read one table.

use canodom_calib::calibrator::Refused;
use canodom_calib::run::Rejection;
use canodom_calib::session::{Instruction, Phase, Refusal};
use canodom_calib::track::Direction;

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
