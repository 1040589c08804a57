//! The guided calibration session: a plain state machine,
//! `on_event(self, event) -> (Self, Vec<Action>)`, that the daemon drives
//! with operator commands and odometry samples and whose [`Action`]s it
//! carries out (send status, compute, apply and persist parameters).
//!
//! Flow: `StartSession` → for each run (all CCW runs, then all CW runs):
//! position the car at the run's start point and stand still → the run starts
//! when the car moves off (or on `StartRun`) → it ends at a standstill after
//! at least 90 % of the track length (or on `EndRun`) → it is validated and
//! accepted or rejected (then repeated) → the measured end pose is asked for
//! when required (§10's order-of-operations rule) → `Compute` → the daemon
//! runs [`Session::calibration_job`] and returns `Computed` → `Commit` applies
//! and persists, `Rollback` restores the previous parameters.
//!
//! Every event is either applied entirely or refused with a [`Refusal`]
//! leaving the session unchanged; nothing panics. Actions, instructions,
//! refusals and events have stable numeric codes for CAN status frames.

use canodom_fusion::{Pose, VehicleParams};

use crate::error::Result;
use crate::methods::{CalibrationResult, ExactOptions, exact};
use crate::run::{InputFault, RearParams, Rejection, RevSample, Run, RunRecorder, Tolerances};
use crate::steering::{SteeringProvenance, needs_measured_end_poses};
use crate::track::{Direction, Track};

/// Settings of a session, fixed when it is created.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SessionConfig {
    /// Run validation tolerances.
    pub tolerances: Tolerances,
    /// Below this rear-axle speed the car stands still, in m/s.
    pub standstill_speed_mps: f64,
    /// How long the car must stand still to arm a run and to end one, in s.
    pub standstill_time_s: f64,
    /// The fraction of the track length after which a standstill ends a run.
    pub end_fraction: f64,
    /// The largest number of runs per direction a session accepts.
    pub max_runs_per_direction: u8,
}

impl Default for SessionConfig {
    fn default() -> Self {
        Self {
            tolerances: Tolerances::default(),
            standstill_speed_mps: 0.01,
            standstill_time_s: 1.0,
            end_fraction: 0.9,
            max_runs_per_direction: 20,
        }
    }
}

/// Something that happened: an operator command, a sample, a result.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// Start a session on a track of radius `radius_m` with
    /// `runs_per_direction` runs each way.
    StartSession {
        /// ρ of the track.
        radius_m: f64,
        /// Runs per direction (1..=max).
        runs_per_direction: u8,
    },
    /// Start recording the next run now (instead of waiting for the car to move off).
    StartRun,
    /// End the run being recorded now (instead of waiting for the standstill).
    EndRun,
    /// The measured real end pose of the last accepted run, in its run frame.
    MeasuredEndPose(Pose),
    /// Drop the session and everything recorded.
    Abort,
    /// Compute the calibration from the accepted runs.
    Compute,
    /// The outcome of the calibration job the daemon ran for [`Action::Compute`].
    Computed(Result<CalibrationResult>),
    /// Apply and persist the computed result.
    Commit,
    /// Restore the parameters in use before the last commit.
    Rollback,
    /// The steering map was refitted with calibrated rear odometry (§10).
    SteeringRefitted,
    /// An odometry sample (wheel revolutions since the previous one).
    Sample(RevSample),
    /// The wheel decoder reported an input fault at `t_s`.
    InputFault {
        /// When.
        t_s: f64,
        /// What.
        fault: InputFault,
    },
}

impl Event {
    /// Stable numeric code.
    pub fn code(&self) -> u8 {
        match self {
            Event::StartSession { .. } => 1,
            Event::StartRun => 2,
            Event::EndRun => 3,
            Event::MeasuredEndPose(_) => 4,
            Event::Abort => 5,
            Event::Compute => 6,
            Event::Computed(_) => 7,
            Event::Commit => 8,
            Event::Rollback => 9,
            Event::SteeringRefitted => 10,
            Event::Sample(_) => 11,
            Event::InputFault { .. } => 12,
        }
    }
}

/// Why an event was refused. The discriminant is the stable code.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Refusal {
    /// No session is active.
    NoSession = 1,
    /// A session is active; abort it first.
    SessionActive = 2,
    /// An argument is out of range (radius, run count, pose).
    InvalidArgument = 3,
    /// A run is being recorded already.
    AlreadyRecording = 4,
    /// No run is being recorded.
    NotRecording = 5,
    /// There is no accepted run to attach an end pose to.
    NoRunForEndPose = 6,
    /// The measured end pose of the last run is required first.
    EndPoseRequired = 7,
    /// Not all runs are accepted yet.
    RunsIncomplete = 8,
    /// No calibration is being computed.
    NotComputing = 9,
    /// There is no computed result to commit.
    NothingToCommit = 10,
    /// There is no commit to roll back.
    NothingToRollback = 11,
    /// A calibration is being computed or awaits commit.
    Busy = 12,
    /// All runs are recorded; compute or abort.
    AllRunsDone = 13,
}

impl Refusal {
    /// Every refusal, in code order (codes 1..=13).
    pub const ALL: [Self; 13] = [
        Self::NoSession,
        Self::SessionActive,
        Self::InvalidArgument,
        Self::AlreadyRecording,
        Self::NotRecording,
        Self::NoRunForEndPose,
        Self::EndPoseRequired,
        Self::RunsIncomplete,
        Self::NotComputing,
        Self::NothingToCommit,
        Self::NothingToRollback,
        Self::Busy,
        Self::AllRunsDone,
    ];

    /// Stable numeric code.
    pub fn code(self) -> u8 {
        self as u8
    }
}

/// What the driver should do now.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Instruction {
    /// No session.
    Idle,
    /// Refit the steering map with the calibrated rear odometry (§10).
    RefitSteering,
    /// Drive to the start point of `direction` (S_CCW or S_CW), stop and wait.
    GoToStart {
        /// Run number, from 1.
        run: u8,
        /// Runs in the session.
        runs: u8,
        /// Direction of the run (and so its start point).
        direction: Direction,
    },
    /// Standing at the start: drive the lap when ready.
    Go {
        /// Run number, from 1.
        run: u8,
        /// Runs in the session.
        runs: u8,
        /// Direction of the run.
        direction: Direction,
    },
    /// Recording: keep following the track.
    Drive {
        /// Run number, from 1.
        run: u8,
        /// Runs in the session.
        runs: u8,
        /// Direction of the run.
        direction: Direction,
    },
    /// The lap is nearly done: stop at the start point.
    Stop {
        /// Run number, from 1.
        run: u8,
        /// Runs in the session.
        runs: u8,
    },
    /// Measure the real end pose of the run (tape and protractor) and enter it.
    MeasureEndPose {
        /// Run number, from 1.
        run: u8,
    },
    /// All runs recorded: compute.
    ReadyToCompute,
    /// Wait: computing.
    Wait,
    /// Review the result: commit or abort.
    ReviewResult,
}

impl Instruction {
    /// Stable numeric code.
    pub fn code(&self) -> u8 {
        match self {
            Instruction::Idle => 0,
            Instruction::RefitSteering => 1,
            Instruction::GoToStart { .. } => 2,
            Instruction::Go { .. } => 3,
            Instruction::Drive { .. } => 4,
            Instruction::Stop { .. } => 5,
            Instruction::MeasureEndPose { .. } => 6,
            Instruction::ReadyToCompute => 7,
            Instruction::Wait => 8,
            Instruction::ReviewResult => 9,
        }
    }
}

/// What the daemon must do.
#[derive(Debug, Clone, PartialEq)]
pub enum Action {
    /// Show the driver a new instruction.
    Instruct(Instruction),
    /// The event with code `event` was refused.
    Refused {
        /// [`Event::code`] of the refused event.
        event: u8,
        /// Why.
        reason: Refusal,
    },
    /// Run `run` (from 1) started recording.
    RunStarted {
        /// Run number.
        run: u8,
    },
    /// Run `run` was accepted.
    RunAccepted {
        /// Run number.
        run: u8,
    },
    /// Run `run` was rejected (it will be driven again); the first reason.
    RunRejected {
        /// Run number.
        run: u8,
        /// The first reason ([`Rejection::code`] for frames).
        reason: Rejection,
    },
    /// Run [`Session::calibration_job`] and send back [`Event::Computed`].
    Compute,
    /// A result is ready for review.
    ResultReady(CalibrationResult),
    /// The calibration failed; the runs are kept, compute again or abort.
    ComputeFailed,
    /// Put these rear parameters into the running odometry.
    ApplyParams(RearParams),
    /// Store these rear parameters so they survive a restart.
    PersistParams(RearParams),
    /// The session was dropped.
    SessionAborted,
}

impl Action {
    /// Stable numeric code.
    pub fn code(&self) -> u8 {
        match self {
            Action::Instruct(_) => 1,
            Action::Refused { .. } => 2,
            Action::RunStarted { .. } => 3,
            Action::RunAccepted { .. } => 4,
            Action::RunRejected { .. } => 5,
            Action::Compute => 6,
            Action::ResultReady(_) => 7,
            Action::ComputeFailed => 8,
            Action::ApplyParams(_) => 9,
            Action::PersistParams(_) => 10,
            Action::SessionAborted => 11,
        }
    }
}

/// Where the session stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Phase {
    /// No session.
    Idle,
    /// Waiting for the car at the next run's start point.
    Positioning,
    /// Recording a run.
    Recording,
    /// Waiting for the measured end pose of the last run.
    AwaitingEndPose,
    /// All runs accepted.
    Ready,
    /// The daemon is computing.
    Computing,
    /// A result awaits commit.
    Computed,
}

impl Phase {
    /// The phase's name in recordings and logs (`idle`, `awaiting_end_pose`, …).
    pub fn as_str(self) -> &'static str {
        match self {
            Phase::Idle => "idle",
            Phase::Positioning => "positioning",
            Phase::Recording => "recording",
            Phase::AwaitingEndPose => "awaiting_end_pose",
            Phase::Ready => "ready",
            Phase::Computing => "computing",
            Phase::Computed => "computed",
        }
    }
}

/// The calibration the daemon runs for [`Action::Compute`]: pure, owned.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationJob {
    /// The accepted runs.
    pub runs: Vec<Run>,
    /// The rear parameters used while recording.
    pub used: RearParams,
    /// The track.
    pub track: Track,
    /// A run of known length (in metres) to fix the scale (§4); the session
    /// leaves it `None`, the daemon may set it when the operator drove one.
    pub known_length: Option<(Run, f64)>,
}

impl CalibrationJob {
    /// Runs the exact method (§7), then fixes the scale when a known-length
    /// run is given.
    ///
    /// # Errors
    /// As [`exact`] and [`CalibrationResult::with_known_length`].
    pub fn run(&self) -> Result<CalibrationResult> {
        let result = exact(&self.runs, &self.used, self.track, ExactOptions::default())?;
        match &self.known_length {
            Some((run, length_m)) => result.with_known_length(run, *length_m),
            None => Ok(result),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Plan {
    track: Track,
    runs_per_direction: u8,
    end_poses_required: bool,
}

impl Plan {
    fn total(&self) -> usize {
        2 * usize::from(self.runs_per_direction)
    }
    fn direction(&self, index: usize) -> Direction {
        if index < usize::from(self.runs_per_direction) {
            Direction::Ccw
        } else {
            Direction::Cw
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Motion {
    last_t_s: Option<f64>,
    still_since_s: Option<f64>,
}

impl Motion {
    fn still_for_s(&self) -> f64 {
        match (self.still_since_s, self.last_t_s) {
            (Some(a), Some(b)) => b - a,
            _ => 0.0,
        }
    }
}

/// The guided calibration session. See the module doc for the flow.
#[derive(Debug, Clone, PartialEq)]
pub struct Session {
    config: SessionConfig,
    params: VehicleParams,
    steering: SteeringProvenance,
    round: u32,
    plan: Option<Plan>,
    accepted: Vec<Run>,
    recorder: Option<RunRecorder>,
    recorded_m: f64,
    phase: Phase,
    result: Option<CalibrationResult>,
    previous: Option<VehicleParams>,
    motion: Motion,
}

fn run_number(index: usize) -> u8 {
    u8::try_from(index + 1).unwrap_or(u8::MAX)
}

impl Session {
    /// A session machine for a vehicle whose parameters in use are `params`,
    /// with a steering map of the given provenance.
    pub fn new(params: VehicleParams, steering: SteeringProvenance, config: SessionConfig) -> Self {
        Self {
            config,
            params,
            steering,
            round: 0,
            plan: None,
            accepted: Vec::new(),
            recorder: None,
            recorded_m: 0.0,
            phase: Phase::Idle,
            result: None,
            previous: None,
            motion: Motion::default(),
        }
    }

    /// The phase.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// The parameters in use (changed by commit and rollback).
    pub fn params(&self) -> &VehicleParams {
        &self.params
    }

    /// The accepted runs of the current session.
    pub fn accepted_runs(&self) -> &[Run] {
        &self.accepted
    }

    /// The computed result awaiting commit.
    pub fn result(&self) -> Option<&CalibrationResult> {
        self.result.as_ref()
    }

    /// Calibration rounds committed (and not rolled back) so far.
    pub fn round(&self) -> u32 {
        self.round
    }

    /// Where the steering map in use came from.
    pub fn steering_provenance(&self) -> SteeringProvenance {
        self.steering
    }

    /// Whether this session's runs need measured end poses (§10).
    pub fn end_poses_required(&self) -> bool {
        self.plan.is_some_and(|p| p.end_poses_required)
    }

    /// The job to run for [`Action::Compute`] (while computing).
    pub fn calibration_job(&self) -> Option<CalibrationJob> {
        let plan = self.plan?;
        (self.phase == Phase::Computing).then(|| CalibrationJob {
            runs: self.accepted.clone(),
            used: RearParams::of(&self.params),
            track: plan.track,
            known_length: None,
        })
    }

    /// What the driver should do now.
    pub fn instruction(&self) -> Instruction {
        let Some(plan) = self.plan else {
            return if self.round > 0 && self.steering == SteeringProvenance::UncalibratedOdometry {
                Instruction::RefitSteering
            } else {
                Instruction::Idle
            };
        };
        let index = self.accepted.len();
        let run = run_number(index);
        let runs = u8::try_from(plan.total()).unwrap_or(u8::MAX);
        let direction = plan.direction(index);
        match self.phase {
            Phase::Idle => Instruction::Idle,
            Phase::Positioning => {
                if self.motion.still_for_s() >= self.config.standstill_time_s {
                    Instruction::Go {
                        run,
                        runs,
                        direction,
                    }
                } else {
                    Instruction::GoToStart {
                        run,
                        runs,
                        direction,
                    }
                }
            }
            Phase::Recording => {
                if self.recorded_m >= self.config.end_fraction * plan.track.length_m() {
                    Instruction::Stop { run, runs }
                } else {
                    Instruction::Drive {
                        run,
                        runs,
                        direction,
                    }
                }
            }
            Phase::AwaitingEndPose => Instruction::MeasureEndPose {
                run: run_number(index.saturating_sub(1)),
            },
            Phase::Ready => Instruction::ReadyToCompute,
            Phase::Computing => Instruction::Wait,
            Phase::Computed => Instruction::ReviewResult,
        }
    }

    /// Handles one event. Refused events leave the session unchanged and
    /// yield a single [`Action::Refused`]; otherwise the actions say what
    /// the daemon must do, ending with the new instruction if it changed.
    ///
    /// Every handler checks all its conditions before it changes anything,
    /// so a refusal never leaves a half-applied event behind (and no copy of
    /// the recorded runs is needed per sample).
    #[must_use]
    pub fn on_event(mut self, event: Event) -> (Self, Vec<Action>) {
        let before = self.instruction();
        let code = event.code();
        let mut actions = Vec::new();
        match self.apply(event, &mut actions) {
            Ok(()) => {
                let after = self.instruction();
                if after != before {
                    actions.push(Action::Instruct(after));
                }
                (self, actions)
            }
            Err(reason) => (
                self,
                vec![Action::Refused {
                    event: code,
                    reason,
                }],
            ),
        }
    }

    fn apply(
        &mut self,
        event: Event,
        actions: &mut Vec<Action>,
    ) -> std::result::Result<(), Refusal> {
        match event {
            Event::StartSession {
                radius_m,
                runs_per_direction,
            } => self.start_session(radius_m, runs_per_direction),
            Event::StartRun => match self.phase {
                Phase::Positioning => {
                    self.begin_run(actions);
                    Ok(())
                }
                _ => Err(self.busy_reason(Refusal::AlreadyRecording)),
            },
            Event::EndRun => match self.phase {
                Phase::Recording => {
                    self.end_run(actions);
                    Ok(())
                }
                Phase::Idle => Err(Refusal::NoSession),
                _ => Err(Refusal::NotRecording),
            },
            Event::MeasuredEndPose(pose) => self.end_pose(pose),
            Event::Abort => {
                if self.phase == Phase::Idle {
                    return Err(Refusal::NoSession);
                }
                self.clear_session();
                actions.push(Action::SessionAborted);
                Ok(())
            }
            Event::Compute => match self.phase {
                Phase::Ready => {
                    self.phase = Phase::Computing;
                    actions.push(Action::Compute);
                    Ok(())
                }
                Phase::Idle => Err(Refusal::NoSession),
                Phase::Computing | Phase::Computed => Err(Refusal::Busy),
                Phase::AwaitingEndPose => Err(Refusal::EndPoseRequired),
                Phase::Positioning | Phase::Recording => Err(Refusal::RunsIncomplete),
            },
            Event::Computed(outcome) => {
                if self.phase != Phase::Computing {
                    return Err(Refusal::NotComputing);
                }
                match outcome {
                    Ok(r) if r.rear.apply_to(&self.params).is_ok() => {
                        self.phase = Phase::Computed;
                        self.result = Some(r);
                        actions.push(Action::ResultReady(r));
                    }
                    _ => {
                        self.phase = Phase::Ready;
                        actions.push(Action::ComputeFailed);
                    }
                }
                Ok(())
            }
            Event::Commit => self.commit(actions),
            Event::Rollback => match (self.phase, self.previous) {
                (Phase::Idle, Some(previous)) => {
                    let rear = RearParams::of(&previous);
                    self.params = previous;
                    self.previous = None;
                    // The old parameters are back, and with them the
                    // round they belonged to (§10: the trap applies again).
                    self.round = self.round.saturating_sub(1);
                    actions.push(Action::ApplyParams(rear));
                    actions.push(Action::PersistParams(rear));
                    Ok(())
                }
                (Phase::Idle, None) => Err(Refusal::NothingToRollback),
                _ => Err(Refusal::SessionActive),
            },
            Event::SteeringRefitted => {
                if self.phase != Phase::Idle {
                    return Err(Refusal::SessionActive);
                }
                self.steering = SteeringProvenance::CalibratedOdometry;
                Ok(())
            }
            Event::Sample(sample) => {
                self.sample(sample, actions);
                Ok(())
            }
            Event::InputFault { t_s, fault } => {
                if let Some(rec) = self.recorder.as_mut() {
                    rec.push_fault(t_s, fault);
                }
                Ok(())
            }
        }
    }

    /// The reason to refuse starting a run in the current phase.
    fn busy_reason(&self, recording: Refusal) -> Refusal {
        match self.phase {
            Phase::Idle => Refusal::NoSession,
            Phase::Recording => recording,
            Phase::AwaitingEndPose => Refusal::EndPoseRequired,
            Phase::Ready => Refusal::AllRunsDone,
            Phase::Positioning | Phase::Computing | Phase::Computed => Refusal::Busy,
        }
    }

    fn start_session(&mut self, radius_m: f64, runs: u8) -> std::result::Result<(), Refusal> {
        if self.phase != Phase::Idle {
            return Err(Refusal::SessionActive);
        }
        let track = Track::new(radius_m).map_err(|_| Refusal::InvalidArgument)?;
        if runs == 0 || runs > self.config.max_runs_per_direction {
            return Err(Refusal::InvalidArgument);
        }
        self.plan = Some(Plan {
            track,
            runs_per_direction: runs,
            end_poses_required: needs_measured_end_poses(self.steering, self.round),
        });
        self.phase = Phase::Positioning;
        Ok(())
    }

    fn clear_session(&mut self) {
        self.plan = None;
        self.accepted.clear();
        self.recorder = None;
        self.recorded_m = 0.0;
        self.result = None;
        self.phase = Phase::Idle;
    }

    fn begin_run(&mut self, actions: &mut Vec<Action>) {
        let Some(plan) = self.plan else { return };
        let index = self.accepted.len();
        self.recorder = Some(RunRecorder::new(
            plan.direction(index),
            self.config.tolerances.max_gap_s,
        ));
        self.recorded_m = 0.0;
        self.phase = Phase::Recording;
        actions.push(Action::RunStarted {
            run: run_number(index),
        });
    }

    fn end_run(&mut self, actions: &mut Vec<Action>) {
        let (Some(plan), Some(rec)) = (self.plan, self.recorder.take()) else {
            return;
        };
        let index = self.accepted.len();
        let run = rec.finish(None);
        let reasons = run.validate(plan.track, &self.params, &self.config.tolerances);
        self.recorded_m = 0.0;
        if let Some(first) = reasons.first() {
            actions.push(Action::RunRejected {
                run: run_number(index),
                reason: *first,
            });
            self.phase = Phase::Positioning;
            return;
        }
        self.accepted.push(run);
        actions.push(Action::RunAccepted {
            run: run_number(index),
        });
        self.phase = if plan.end_poses_required {
            Phase::AwaitingEndPose
        } else {
            self.after_run_phase(plan)
        };
    }

    fn after_run_phase(&self, plan: Plan) -> Phase {
        if self.accepted.len() >= plan.total() {
            Phase::Ready
        } else {
            Phase::Positioning
        }
    }

    fn end_pose(&mut self, pose: Pose) -> std::result::Result<(), Refusal> {
        let Some(plan) = self.plan else {
            return Err(Refusal::NoSession);
        };
        let finite = pose.x_m.is_finite() && pose.y_m.is_finite() && pose.heading_rad.is_finite();
        let bound = plan.track.length_m();
        if !finite || pose.x_m.abs() > bound || pose.y_m.abs() > bound {
            return Err(Refusal::InvalidArgument);
        }
        match self.phase {
            Phase::AwaitingEndPose | Phase::Positioning | Phase::Ready => {}
            Phase::Recording => return Err(Refusal::AlreadyRecording),
            _ => return Err(Refusal::Busy),
        }
        let Some(last) = self.accepted.last_mut() else {
            return Err(Refusal::NoRunForEndPose);
        };
        last.measured_end = Some(pose);
        if self.phase == Phase::AwaitingEndPose {
            self.phase = self.after_run_phase(plan);
        }
        Ok(())
    }

    fn commit(&mut self, actions: &mut Vec<Action>) -> std::result::Result<(), Refusal> {
        let (Phase::Computed, Some(result)) = (self.phase, self.result) else {
            return Err(Refusal::NothingToCommit);
        };
        let new = result
            .rear
            .apply_to(&self.params)
            .map_err(|_| Refusal::InvalidArgument)?;
        self.previous = Some(self.params);
        self.params = new;
        self.round += 1;
        self.clear_session();
        actions.push(Action::ApplyParams(result.rear));
        actions.push(Action::PersistParams(result.rear));
        Ok(())
    }

    fn sample(&mut self, sample: RevSample, actions: &mut Vec<Action>) {
        let armed = self.motion.still_for_s() >= self.config.standstill_time_s;
        let rear = RearParams::of(&self.params);
        let distance_m = 0.5
            * std::f64::consts::PI
            * (rear.left_diameter_m * sample.rear_left_rev
                + rear.right_diameter_m * sample.rear_right_rev);
        let usable = sample.t_s.is_finite()
            && distance_m.is_finite()
            && self.motion.last_t_s.is_none_or(|t| sample.t_s > t);
        let mut moving = false;
        if usable {
            let dt = self
                .motion
                .last_t_s
                .map_or(f64::INFINITY, |t| sample.t_s - t);
            moving = distance_m.abs() > self.config.standstill_speed_mps * dt;
            if moving {
                self.motion.still_since_s = None;
            } else if self.motion.still_since_s.is_none() {
                self.motion.still_since_s = Some(self.motion.last_t_s.unwrap_or(sample.t_s));
            }
            self.motion.last_t_s = Some(sample.t_s);
        }
        if self.phase == Phase::Positioning && armed && moving {
            self.begin_run(actions);
        }
        if self.phase != Phase::Recording {
            return;
        }
        if let Some(rec) = self.recorder.as_mut() {
            rec.push(sample);
        }
        if usable {
            self.recorded_m += distance_m.abs();
        }
        let Some(plan) = self.plan else { return };
        if self.recorded_m >= self.config.end_fraction * plan.track.length_m()
            && self.motion.still_for_s() >= self.config.standstill_time_s
        {
            self.end_run(actions);
        }
    }

    /// The first broken invariant, if any. These hold after every event:
    /// - no plan ⇔ Idle, and Idle holds no runs, recorder or result;
    /// - at most `2n` accepted runs, the k-th in the planned direction;
    /// - a recorder exists ⇔ Recording, for the next run in its direction;
    /// - AwaitingEndPose ⇒ end poses required and the last run lacks one;
    /// - Ready/Computing/Computed ⇒ all `2n` runs, each with an end pose when
    ///   required;
    /// - a result exists ⇔ Computed, with finite positive parameters;
    /// - the distance counter is finite and not negative.
    pub fn invariant_violation(&self) -> Option<&'static str> {
        let Some(plan) = self.plan else {
            let clean = self.phase == Phase::Idle
                && self.accepted.is_empty()
                && self.recorder.is_none()
                && self.result.is_none();
            return (!clean).then_some("idle session holds state");
        };
        if self.phase == Phase::Idle {
            return Some("plan without session");
        }
        let n = self.accepted.len();
        if n > plan.total() {
            return Some("more runs than planned");
        }
        if self
            .accepted
            .iter()
            .enumerate()
            .any(|(k, r)| r.direction != plan.direction(k))
        {
            return Some("run in the wrong direction");
        }
        match (&self.recorder, self.phase) {
            (Some(rec), Phase::Recording) => {
                if n >= plan.total() {
                    return Some("recording beyond the plan");
                }
                if rec.direction() != plan.direction(n) {
                    return Some("recording in the wrong direction");
                }
            }
            (None, Phase::Recording) => return Some("recording without recorder"),
            (Some(_), _) => return Some("recorder outside recording"),
            _ => {}
        }
        if self.phase == Phase::AwaitingEndPose
            && !(plan.end_poses_required
                && self
                    .accepted
                    .last()
                    .is_some_and(|r| r.measured_end.is_none()))
        {
            return Some("awaiting an end pose that is not needed");
        }
        let complete = n == plan.total()
            && (!plan.end_poses_required || self.accepted.iter().all(|r| r.measured_end.is_some()));
        if matches!(
            self.phase,
            Phase::Ready | Phase::Computing | Phase::Computed
        ) && !complete
        {
            return Some("computing without all runs");
        }
        if matches!(self.phase, Phase::Positioning) && n >= plan.total() {
            return Some("positioning after the last run");
        }
        match (self.phase, self.result) {
            (Phase::Computed, Some(r))
                if RearParams::new(
                    r.rear.tread_m,
                    r.rear.left_diameter_m,
                    r.rear.right_diameter_m,
                )
                .is_err() =>
            {
                return Some("result with invalid parameters");
            }
            (Phase::Computed, None) => return Some("computed without result"),
            (Phase::Computed, Some(_)) => {}
            (_, Some(_)) => return Some("result outside computed"),
            _ => {}
        }
        if !(self.recorded_m.is_finite() && self.recorded_m >= 0.0) {
            return Some("distance counter broken");
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::methods::tests::{truth, used};
    use crate::synth;
    use proptest::prelude::*;
    use std::sync::OnceLock;

    const RATE_HZ: f64 = 5.0;

    fn laps() -> &'static [Vec<RevSample>; 2] {
        static LAPS: OnceLock<[Vec<RevSample>; 2]> = OnceLock::new();
        LAPS.get_or_init(|| {
            let track = Track::new(0.78).unwrap();
            Direction::BOTH
                .map(|d| synth::lap(&truth(false, false), track, d, 0.1, RATE_HZ).unwrap())
        })
    }

    fn nominal() -> VehicleParams {
        used().apply_to(&truth(false, false)).unwrap()
    }

    /// Drives a session like the daemon would, checking the invariants and
    /// the no-half-applied rule after every event.
    struct Harness {
        s: Option<Session>,
        t_s: f64,
        actions: Vec<Action>,
    }

    impl Harness {
        fn new(steering: SteeringProvenance) -> Self {
            Self {
                s: Some(Session::new(nominal(), steering, SessionConfig::default())),
                t_s: 0.0,
                actions: Vec::new(),
            }
        }
        fn s(&self) -> &Session {
            self.s.as_ref().unwrap()
        }
        fn send(&mut self, e: Event) -> Vec<Action> {
            let before = self.s.take().unwrap();
            let copy = before.clone();
            let (after, actions) = before.on_event(e);
            if let Some(v) = after.invariant_violation() {
                panic!("invariant broken: {v}: {after:?}");
            }
            if matches!(actions.first(), Some(Action::Refused { .. })) {
                assert_eq!(actions.len(), 1);
                assert_eq!(after, copy, "a refused event changed the session");
            }
            self.s = Some(after);
            self.actions.extend(actions.iter().cloned());
            actions
        }
        fn refused(&mut self, e: Event) -> Option<Refusal> {
            match self.send(e).as_slice() {
                [Action::Refused { reason, .. }] => Some(*reason),
                _ => None,
            }
        }
        fn still(&mut self, secs: f64) {
            for _ in 0..(secs * RATE_HZ).round() as usize {
                self.t_s += 1.0 / RATE_HZ;
                self.send(Event::Sample(RevSample {
                    t_s: self.t_s,
                    rear_left_rev: 0.0,
                    rear_right_rev: 0.0,
                    front_rev: None,
                    steer_signal: 0.0,
                }));
            }
        }
        fn drive(&mut self, samples: &[RevSample]) {
            for s in samples {
                self.t_s += 1.0 / RATE_HZ;
                self.send(Event::Sample(RevSample {
                    t_s: self.t_s,
                    ..*s
                }));
            }
        }
        fn lap(&mut self, dir: Direction) {
            self.still(1.6);
            self.drive(&laps()[usize::from(dir.code())]);
            self.still(1.6);
        }
        fn compute(&mut self) -> Vec<Action> {
            let a = self.send(Event::Compute);
            assert!(a.contains(&Action::Compute), "{a:?}");
            let job = self.s().calibration_job().unwrap();
            self.send(Event::Computed(job.run()))
        }
    }

    fn instruction_of(actions: &[Action]) -> Option<Instruction> {
        actions.iter().rev().find_map(|a| match a {
            Action::Instruct(i) => Some(*i),
            _ => None,
        })
    }

    #[test]
    fn a_full_session_runs_commits_and_rolls_back() {
        let mut h = Harness::new(SteeringProvenance::Independent);
        assert_eq!(h.s().instruction(), Instruction::Idle);
        h.send(Event::StartSession {
            radius_m: 0.78,
            runs_per_direction: 2,
        });
        assert_eq!(
            h.s().instruction(),
            Instruction::GoToStart {
                run: 1,
                runs: 4,
                direction: Direction::Ccw
            }
        );
        h.still(1.6);
        assert!(matches!(
            h.s().instruction(),
            Instruction::Go { run: 1, .. }
        ));
        for k in 0..4u8 {
            let dir = if k < 2 { Direction::Ccw } else { Direction::Cw };
            assert!(
                matches!(
                    h.s().instruction(),
                    Instruction::GoToStart { direction, run, .. } | Instruction::Go { direction, run, .. }
                        if direction == dir && run == k + 1
                ),
                "{:?}",
                h.s().instruction()
            );
            h.actions.clear();
            h.lap(dir);
            assert!(
                h.actions.contains(&Action::RunStarted { run: k + 1 }),
                "{:?}",
                h.actions
            );
            assert!(
                h.actions.contains(&Action::RunAccepted { run: k + 1 }),
                "{:?}",
                h.actions
            );
            assert!(h.actions.iter().any(
                |a| matches!(a, Action::Instruct(Instruction::Stop { run, .. }) if *run == k + 1)
            ));
        }
        assert_eq!(h.s().phase(), Phase::Ready);
        assert_eq!(h.s().instruction(), Instruction::ReadyToCompute);
        let mut job = {
            let mut probe = h.s().clone();
            probe = probe.on_event(Event::Compute).0;
            probe.calibration_job().unwrap()
        };
        // A known-length run (here: a lap of the true 8.02 m) fixes the scale.
        job.known_length = Some((job.runs[0].clone(), Track::new(0.78).unwrap().length_m()));
        let scaled = job.run().unwrap();
        assert!(scaled.scale_fixed && (scaled.tread_m() - 0.285).abs() < 1e-5);
        let a = h.compute();
        let Some(Action::ResultReady(r)) = a.first() else {
            panic!("{a:?}")
        };
        assert!(
            (r.tread_m() - 0.285).abs() < 1e-5 && (r.ratio() - 1.005).abs() < 1e-6,
            "{r:?}"
        );
        assert_eq!(instruction_of(&a), Some(Instruction::ReviewResult));
        let a = h.send(Event::Commit);
        assert!(matches!(a[0], Action::ApplyParams(p) if (p.tread_m - 0.285).abs() < 1e-5));
        assert!(matches!(a[1], Action::PersistParams(_)));
        assert!((h.s().params().rear_tread_m() - 0.285).abs() < 1e-5);
        let a = h.send(Event::Rollback);
        assert!(matches!(a[0], Action::ApplyParams(p) if p.tread_m == 0.30));
        assert_eq!(h.s().params(), &nominal());
        assert_eq!(h.refused(Event::Rollback), Some(Refusal::NothingToRollback));
    }

    #[test]
    fn the_steering_trap_asks_for_end_poses_in_the_first_round_only() {
        let mut h = Harness::new(SteeringProvenance::UncalibratedOdometry);
        h.send(Event::StartSession {
            radius_m: 0.78,
            runs_per_direction: 1,
        });
        assert!(h.s().end_poses_required());
        h.lap(Direction::Ccw);
        assert_eq!(h.s().phase(), Phase::AwaitingEndPose);
        assert_eq!(h.s().instruction(), Instruction::MeasureEndPose { run: 1 });
        assert_eq!(h.refused(Event::StartRun), Some(Refusal::EndPoseRequired));
        assert_eq!(h.refused(Event::Compute), Some(Refusal::EndPoseRequired));
        let bad = Pose {
            x_m: f64::NAN,
            ..Pose::default()
        };
        assert_eq!(
            h.refused(Event::MeasuredEndPose(bad)),
            Some(Refusal::InvalidArgument)
        );
        h.send(Event::MeasuredEndPose(Pose::default()));
        assert_eq!(h.s().phase(), Phase::Positioning);
        h.lap(Direction::Cw);
        h.send(Event::MeasuredEndPose(Pose::default()));
        assert_eq!(h.s().phase(), Phase::Ready);
        h.compute();
        let a = h.send(Event::Commit);
        assert_eq!(instruction_of(&a), Some(Instruction::RefitSteering));
        // Second round: the poses are optional.
        h.send(Event::StartSession {
            radius_m: 0.78,
            runs_per_direction: 1,
        });
        assert!(!h.s().end_poses_required());
        assert_eq!(
            h.refused(Event::SteeringRefitted),
            Some(Refusal::SessionActive)
        );
        h.send(Event::Abort);
        // Rolling back restores the uncalibrated odometry, and the trap.
        h.send(Event::Rollback);
        assert_eq!(h.s().round(), 0);
        h.send(Event::StartSession {
            radius_m: 0.78,
            runs_per_direction: 1,
        });
        assert!(h.s().end_poses_required());
        h.send(Event::Abort);
        h.send(Event::SteeringRefitted);
        assert_eq!(h.s().instruction(), Instruction::Idle);
        assert_eq!(
            h.s().steering_provenance(),
            SteeringProvenance::CalibratedOdometry
        );
    }

    #[test]
    fn a_short_run_is_rejected_and_repeated() {
        let mut h = Harness::new(SteeringProvenance::Independent);
        h.send(Event::StartSession {
            radius_m: 0.78,
            runs_per_direction: 1,
        });
        let a = h.send(Event::StartRun);
        assert_eq!(a[0], Action::RunStarted { run: 1 });
        let half = &laps()[0][..laps()[0].len() / 2];
        h.drive(half);
        // A standstill before 90 % does not end the run.
        h.still(3.0);
        assert_eq!(h.s().phase(), Phase::Recording);
        let a = h.send(Event::EndRun);
        assert!(
            matches!(
                a[0],
                Action::RunRejected {
                    run: 1,
                    reason: Rejection::LengthOff { .. }
                }
            ),
            "{a:?}"
        );
        assert_eq!(h.s().phase(), Phase::Positioning);
        assert!(h.s().accepted_runs().is_empty());
        // An input fault inside the run rejects it too.
        h.still(1.6);
        h.drive(&laps()[0][..10]);
        h.send(Event::InputFault {
            t_s: h.t_s,
            fault: InputFault::Decoder { code: 3 },
        });
        h.drive(&laps()[0][10..]);
        h.actions.clear();
        h.still(1.6);
        assert!(
            h.actions.iter().any(|a| matches!(
                a,
                Action::RunRejected {
                    reason: Rejection::InputFault { .. },
                    ..
                }
            )),
            "{:?}",
            h.actions
        );
        h.lap(Direction::Ccw);
        assert_eq!(h.s().accepted_runs().len(), 1);
    }

    #[test]
    fn every_illegal_command_is_refused_with_its_reason_in_every_phase() {
        use Refusal as R;
        let pose = Event::MeasuredEndPose(Pose::default());
        let computed = || Event::Computed(Err(crate::Error::Numerical { context: "test" }));
        let start = || Event::StartSession {
            radius_m: 0.78,
            runs_per_direction: 1,
        };
        // Idle.
        let mut h = Harness::new(SteeringProvenance::Independent);
        for (e, r) in [
            (Event::StartRun, R::NoSession),
            (Event::EndRun, R::NoSession),
            (pose.clone(), R::NoSession),
            (Event::Abort, R::NoSession),
            (Event::Compute, R::NoSession),
            (computed(), R::NotComputing),
            (Event::Commit, R::NothingToCommit),
            (Event::Rollback, R::NothingToRollback),
            (
                Event::StartSession {
                    radius_m: -1.0,
                    runs_per_direction: 1,
                },
                R::InvalidArgument,
            ),
            (
                Event::StartSession {
                    radius_m: 0.78,
                    runs_per_direction: 0,
                },
                R::InvalidArgument,
            ),
            (
                Event::StartSession {
                    radius_m: 0.78,
                    runs_per_direction: 21,
                },
                R::InvalidArgument,
            ),
        ] {
            assert_eq!(h.refused(e.clone()), Some(r), "idle {e:?}");
        }
        // Positioning.
        h.send(start());
        for (e, r) in [
            (start(), R::SessionActive),
            (Event::EndRun, R::NotRecording),
            (pose.clone(), R::NoRunForEndPose),
            (Event::Compute, R::RunsIncomplete),
            (computed(), R::NotComputing),
            (Event::Commit, R::NothingToCommit),
            (Event::Rollback, R::SessionActive),
            (Event::SteeringRefitted, R::SessionActive),
        ] {
            assert_eq!(h.refused(e.clone()), Some(r), "positioning {e:?}");
        }
        // Recording.
        h.send(Event::StartRun);
        for (e, r) in [
            (Event::StartRun, R::AlreadyRecording),
            (pose.clone(), R::AlreadyRecording),
            (Event::Compute, R::RunsIncomplete),
            (Event::Commit, R::NothingToCommit),
        ] {
            assert_eq!(h.refused(e.clone()), Some(r), "recording {e:?}");
        }
        h.send(Event::Abort);
        // Ready, Computing, Computed.
        h.send(start());
        h.lap(Direction::Ccw);
        h.lap(Direction::Cw);
        assert_eq!(h.s().phase(), Phase::Ready);
        for (e, r) in [
            (Event::StartRun, R::AllRunsDone),
            (Event::EndRun, R::NotRecording),
            (Event::Commit, R::NothingToCommit),
            (computed(), R::NotComputing),
        ] {
            assert_eq!(h.refused(e.clone()), Some(r), "ready {e:?}");
        }
        // End poses are optional here and may be entered late.
        assert!(h.refused(pose.clone()).is_none());
        h.send(Event::Compute);
        for (e, r) in [
            (Event::Compute, R::Busy),
            (Event::StartRun, R::Busy),
            (pose.clone(), R::Busy),
            (Event::Commit, R::NothingToCommit),
        ] {
            assert_eq!(h.refused(e.clone()), Some(r), "computing {e:?}");
        }
        // A failed computation keeps the runs.
        let a = h.send(computed());
        assert_eq!(a[0], Action::ComputeFailed);
        assert_eq!(h.s().phase(), Phase::Ready);
        h.compute();
        for (e, r) in [
            (computed(), R::NotComputing),
            (Event::Compute, R::Busy),
            (start(), R::SessionActive),
        ] {
            assert_eq!(h.refused(e.clone()), Some(r), "computed {e:?}");
        }
        assert_eq!(h.send(Event::Abort)[0], Action::SessionAborted);
        assert_eq!(h.s().phase(), Phase::Idle);
        assert_eq!(h.s().params(), &nominal(), "abort applies nothing");
    }

    #[test]
    fn codes_are_stable_and_distinct() {
        let codes: Vec<u8> = Refusal::ALL.iter().map(|r| r.code()).collect();
        assert_eq!(codes, (1..=13).collect::<Vec<u8>>());
        assert_eq!(Action::Compute.code(), 6);
        assert_eq!(Action::SessionAborted.code(), 11);
        assert_eq!(Instruction::ReviewResult.code(), 9);
        assert_eq!(Event::Sample(laps()[0][0]).code(), 11);
    }

    /// One step of a random operator/vehicle sequence.
    #[derive(Debug, Clone)]
    enum Op {
        Command(u8, u8),
        Still(u8),
        Lap(bool, u8),
        BadSample(u8),
        FeedResult(bool),
    }

    fn op() -> impl Strategy<Value = Op> {
        prop_oneof![
            4 => (0u8..12, 0u8..4).prop_map(|(c, a)| Op::Command(c, a)),
            2 => (1u8..25).prop_map(Op::Still),
            3 => (any::<bool>(), 10u8..=100).prop_map(|(d, f)| Op::Lap(d, f)),
            1 => (0u8..3).prop_map(Op::BadSample),
            1 => any::<bool>().prop_map(Op::FeedResult),
        ]
    }

    fn command(c: u8, a: u8) -> Event {
        match c {
            0 => Event::StartSession {
                radius_m: [0.78, 0.0, f64::NAN, 0.78][usize::from(a)],
                runs_per_direction: [1, 2, 0, 30][usize::from(a)],
            },
            2 => Event::EndRun,
            3 => Event::MeasuredEndPose(Pose {
                x_m: [0.01, f64::INFINITY, -0.02, 99.0][usize::from(a)],
                y_m: 0.01,
                heading_rad: 0.01,
            }),
            4 => Event::Abort,
            5 => Event::Compute,
            6 => Event::Commit,
            7 => Event::Rollback,
            8 => Event::SteeringRefitted,
            9 => Event::InputFault {
                t_s: 0.0,
                fault: InputFault::TimestampNotIncreasing,
            },
            10 => Event::Computed(Err(crate::Error::Numerical { context: "random" })),
            _ => Event::StartRun,
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]
        #[test]
        fn random_event_sequences_never_reach_an_invalid_state(
            ops in proptest::collection::vec(op(), 1..40),
            trap in any::<bool>(),
        ) {
            let mut h = Harness::new(if trap {
                SteeringProvenance::UncalibratedOdometry
            } else {
                SteeringProvenance::Independent
            });
            for op in ops {
                match op {
                    Op::Command(c, a) => {
                        h.send(command(c, a));
                    }
                    Op::Still(tenths) => h.still(f64::from(tenths) / 10.0),
                    Op::Lap(planned, pct) => {
                        // Full laps in the planned direction (so that
                        // sessions get to Ready and beyond) or partial laps
                        // in either direction.
                        let next_dir = match h.s().instruction() {
                            Instruction::Go { direction, .. }
                            | Instruction::GoToStart { direction, .. } => direction,
                            _ => Direction::Cw,
                        };
                        let dir = if planned { next_dir } else { Direction::Ccw };
                        let lap = &laps()[usize::from(dir.code())];
                        if pct >= 90 {
                            h.lap(dir);
                        } else {
                            h.drive(&lap[..lap.len() * usize::from(pct) / 100]);
                        }
                    }
                    Op::BadSample(kind) => {
                        let t = [h.t_s - 1.0, f64::NAN, h.t_s + 0.1][usize::from(kind)];
                        let mut s = laps()[0][5];
                        s.t_s = t;
                        if kind == 2 {
                            s.rear_left_rev = f64::INFINITY;
                        }
                        h.send(Event::Sample(s));
                    }
                    Op::FeedResult(ok) => {
                        let outcome = match h.s().calibration_job() {
                            Some(job) if ok => job.run(),
                            _ => Err(crate::Error::Numerical { context: "random" }),
                        };
                        h.send(Event::Computed(outcome));
                    }
                }
                let s = h.s();
                prop_assert!(s.invariant_violation().is_none());
                // The instruction always names a run inside the plan.
                if let Instruction::Go { run, runs, .. }
                | Instruction::GoToStart { run, runs, .. }
                | Instruction::Drive { run, runs, .. }
                | Instruction::Stop { run, runs } = s.instruction()
                {
                    prop_assert!(run >= 1 && run <= runs);
                }
            }
        }
    }
}
