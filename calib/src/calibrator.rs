//! The whole calibration state of a running vehicle: the guided rear
//! session ([`crate::session`]), the steering arcs ([`crate::arcs`]), a drive
//! against position fixes ([`crate::drive_record`]), the history of
//! committed sets ([`crate::history`]), the standstill judge and the set
//! waiting for a standstill to be applied.
//!
//! [`Calibrator`] is a plain state machine: operator commands, filter steps,
//! fixes, input faults and clock ticks come in; [`Output`]s say what must be
//! done. The two slow effects are asked for, not done: [`Output::Persist`]
//! (store the file durably, then [`Calibrator::on_persisted`]) and
//! [`Output::Compute`] (run the [`Job`], then [`Calibrator::on_computed`]), so
//! the caller can do them away from its frame path. Until that answer comes
//! every command is refused as busy; a commit whose file cannot be stored
//! changes nothing (`PersistFailed`): a command is carried out whole or not
//! at all.
//!
//! Each command is answered once ([`Output::Answer`]), at once or when the
//! persistence or the computation it started has finished; the answer comes
//! before whatever the command caused.

use canodom_fusion::{Pose, SteeringMap, VehicleParams, Wheel};

use crate::arcs::{ArcCollector, ArcFitError, ArcGeometry};
use crate::drive::{DriveCalibration, DriveModel, DriveSample, Fix};
use crate::drive_record::{DriveJob, DriveRecorder, DriveStep};
use crate::error::Result;
use crate::history::{ParamBounds, ParamFile, ParamValues};
use crate::methods::CalibrationResult;
use crate::run::{InputFault, RearParams, Rejection, RevSample, Run};
use crate::session::{
    Action, CalibrationJob, Event, Instruction, Phase, Refusal, Session, SessionConfig,
};
use crate::standstill::Standstill;
use crate::steering::{SteeringFit, SteeringProvenance};
use crate::track::{Direction, Track};

/// Settings of the live calibration, fixed at start.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibratorConfig {
    /// Below this rear-axle speed the vehicle stands still, m/s.
    pub standstill_speed_mps: f64,
    /// How long it must stay below it, s.
    pub standstill_time_s: f64,
    /// Bounds a committed set must lie in.
    pub bounds: ParamBounds,
    /// Largest tread standard deviation a rear commit accepts, m.
    pub max_tread_std_m: f64,
    /// Largest diameter-ratio standard deviation a rear commit accepts.
    pub max_ratio_std: f64,
    /// Largest steering-gain standard deviation a steering commit accepts,
    /// relative to the nominal gain.
    pub max_steer_gain_std_rel: f64,
    /// Largest steering-offset standard deviation a steering commit accepts, rad.
    pub max_steer_offset_std_rad: f64,
    /// Previous sets kept in the file for rollback.
    pub max_history: usize,
    /// Whether position fixes are on the bus (a drive can be calibrated).
    pub fixes_available: bool,
    /// The quality a drive's fit must show before its values are committed
    /// (its tread limit relative to the tread in use).
    pub drive_gate: crate::drive_gate::DriveGate,
    /// How much of the drive the online calibration keeps for its refits
    /// (`[calibration.drift] window_s`), s; `None`: none kept.
    pub online_window_s: Option<f64>,
}

/// An operator command.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Command {
    /// Start a guided session on a track of radius `radius_m`.
    StartSession {
        /// ρ of the track.
        radius_m: f64,
        /// Runs per direction.
        runs_per_direction: u8,
    },
    /// Start recording the next run now.
    StartRun,
    /// End the run being recorded now.
    EndRun,
    /// The measured end pose of the last accepted run.
    EndPose(Pose),
    /// Drop the session, steering arcs or drive in progress.
    Abort,
    /// Compute the calibration of what is in progress.
    Compute,
    /// Store and apply the computed result.
    Commit,
    /// Restore the set in use before the last commit.
    Rollback,
    /// Start collecting steering arcs (§10).
    StartSteering,
    /// Start recording a drive against the bus's position fixes.
    StartDrive,
}

/// Why a command was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refused {
    /// The guided session refused it.
    Session(Refusal),
    /// The result lies outside the configured bounds.
    OutOfBounds,
    /// The result's uncertainty exceeds the configured limit.
    UncertaintyTooHigh,
    /// The computation failed (the recorded data is kept).
    ComputeFailed,
    /// The parameter file could not be stored (nothing changed).
    PersistFailed,
    /// Position fixes are not configured: no drive calibration.
    NotSupported,
    /// The previous set's write-back still waits for its acknowledgement.
    WritebackBusy,
    /// Too few samples or fixes were recorded to compute.
    TooFewSamples,
}

/// A computation to run away from the frame path: pure and owned.
#[derive(Debug, Clone, PartialEq)]
pub enum Job {
    /// The rear calibration of the session's accepted runs.
    Rear(CalibrationJob),
    /// The fit of a recorded drive to its fixes.
    Drive(DriveJob),
}

/// What a [`Job`] gave.
#[derive(Debug, Clone)]
pub enum JobOutcome {
    /// Of [`Job::Rear`].
    Rear(Result<CalibrationResult>),
    /// Of [`Job::Drive`]: the calibration and the values it gives.
    Drive(Result<Box<(DriveCalibration, ParamValues)>>),
}

impl Job {
    /// Runs the job (some 20 ms for a rear session, up to a second for a
    /// long drive).
    pub fn run(&self) -> JobOutcome {
        match self {
            Job::Rear(job) => JobOutcome::Rear(job.run()),
            Job::Drive(job) => JobOutcome::Drive(job.run().map(Box::new)),
        }
    }
}

/// What a commit stored, for its report.
#[derive(Debug, Clone, PartialEq)]
pub enum Committed {
    /// A rear result, with the track and runs it came from.
    Rear {
        /// The result.
        result: CalibrationResult,
        /// The track.
        track: Track,
        /// The accepted runs.
        runs: Vec<Run>,
    },
    /// A steering map.
    Steering {
        /// The fit.
        fit: SteeringFit,
        /// The map in use before.
        before: SteeringMap,
        /// The gain's standard deviation relative to the nominal gain.
        gain_std_rel: f64,
        /// The offset's standard deviation, rad.
        offset_std_rad: f64,
    },
}

/// What the caller must do.
#[derive(Debug, Clone, PartialEq)]
pub enum Output {
    /// The answer to the last command (`Ok`: carried out).
    Answer(std::result::Result<(), Refused>),
    /// Store this file durably, then call [`Calibrator::on_persisted`].
    Persist(ParamFile),
    /// Run this job, then call [`Calibrator::on_computed`].
    Compute(Job),
    /// Put this set into the running odometry now (the vehicle stands still).
    Apply {
        /// The set's version.
        version: u16,
        /// Its values.
        values: ParamValues,
    },
    /// A new set is in use (committed or rolled back to): write it back.
    Adopted {
        /// The set's version.
        version: u16,
    },
    /// Write the report of this committed set.
    Report {
        /// The set's version.
        version: u16,
        /// What was committed.
        committed: Box<Committed>,
    },
    /// What the driver should do changed: tell at once.
    InstructionChanged,
}

/// The step a stored file completes.
#[derive(Debug, Clone)]
enum AfterStore {
    Rear {
        result: CalibrationResult,
        values: ParamValues,
    },
    Drive {
        values: ParamValues,
    },
    Steering {
        fit: SteeringFit,
        values: ParamValues,
        before: SteeringMap,
        stds: (f64, f64),
    },
    Rollback {
        values: ParamValues,
    },
    /// The drift watch's candidate: by COMMIT, or automatically (`auto`:
    /// nobody asked, nobody is answered).
    Candidate {
        values: ParamValues,
        auto: bool,
    },
}

/// The slow effect being carried out by the caller.
#[derive(Debug, Clone)]
enum Pending {
    Store {
        file: ParamFile,
        version: u16,
        then: Box<AfterStore>,
    },
    ComputeRear {
        track: Track,
        runs: Vec<Run>,
    },
    ComputeDrive,
}

fn dir_index(d: Direction) -> usize {
    match d {
        Direction::Cw => 0,
        Direction::Ccw => 1,
    }
}

/// The live calibration state (see the module doc).
#[derive(Debug, Clone)]
pub struct Calibrator {
    config: CalibratorConfig,
    nominal: VehicleParams,
    /// Taken out only while it handles an event.
    session: Option<Session>,
    file: ParamFile,
    standstill: Standstill,
    pending: Option<Pending>,
    /// Set committed or rolled back to but not yet applied (moving).
    pending_apply: Option<(u16, ParamValues)>,
    /// Accepted and rejected runs, [CW, CCW].
    accepted: [u8; 2],
    rejected: [u8; 2],
    reject_reason: Option<Rejection>,
    run_direction: Option<Direction>,
    run_distance_m: f64,
    result: Option<CalibrationResult>,
    /// The track and runs the result came from (for the report).
    computed_from: Option<(Track, Vec<Run>)>,
    steering: Option<ArcCollector>,
    drive: Option<DriveRecorder>,
    drive_result: Option<(DriveCalibration, ParamValues)>,
    /// The online calibration's ring of the drive (no guided session).
    online: Option<DriveRecorder>,
    /// +1 whenever the ring is emptied: a refit of an older ring is stale.
    online_generation: u64,
    /// Distance driven since start (the rear wheels' mean), m.
    odometer_m: f64,
    /// The set the drift watch learnt, offered for COMMIT.
    drift_candidate: Option<ParamValues>,
}

/// What the online calibration refits: the last stretch of the drive kept
/// in the ring ([`Calibrator::online_window`]).
#[derive(Debug, Clone, PartialEq)]
pub struct OnlineWindow {
    /// The binned steps.
    pub samples: Vec<DriveSample>,
    /// The fixes within their time, in metres.
    pub fixes: Vec<Fix>,
    /// The values the steps were read with (in use now).
    pub base: ParamValues,
    /// The ring's generation ([`Calibrator::online_generation`]).
    pub generation: u64,
    /// Distance driven since start, m.
    pub odometer_m: f64,
}

impl Calibrator {
    /// The calibration of a vehicle with `nominal` parameters whose
    /// parameter file holds `file` (its current set is in use).
    pub fn new(config: CalibratorConfig, nominal: VehicleParams, file: ParamFile) -> Self {
        let mut me = Self {
            config,
            nominal,
            session: None,
            file,
            standstill: Standstill::new(config.standstill_speed_mps, config.standstill_time_s),
            pending: None,
            pending_apply: None,
            accepted: [0; 2],
            rejected: [0; 2],
            reject_reason: None,
            run_direction: None,
            run_distance_m: 0.0,
            result: None,
            computed_from: None,
            steering: None,
            drive: None,
            drive_result: None,
            online: config.online_window_s.map(DriveRecorder::ring),
            online_generation: 0,
            odometer_m: 0.0,
            drift_candidate: None,
        };
        me.session = Some(me.fresh_session());
        me
    }

    /// The parameter file as last stored.
    pub fn file(&self) -> &ParamFile {
        &self.file
    }

    /// Whether a guided calibration (track session, steering, drive) runs:
    /// the online calibration then keeps nothing.
    pub fn is_guided(&self) -> bool {
        self.is_active() || self.drive.is_some()
    }

    /// The last `window_s` of the drive the ring holds, with what the
    /// refit needs; `None` without a ring or while a guided calibration runs.
    pub fn online_window(&self, window_s: f64) -> Option<OnlineWindow> {
        if self.is_guided() {
            return None;
        }
        let (samples, fixes) = self.online.as_ref()?.window(window_s);
        Some(OnlineWindow {
            samples,
            fixes,
            base: self.current_values(),
            generation: self.online_generation,
            odometer_m: self.odometer_m,
        })
    }

    /// The ring's generation: +1 whenever it is emptied (a new set in use,
    /// a guided calibration).
    pub fn online_generation(&self) -> u64 {
        self.online_generation
    }

    /// Distance driven since start, m.
    pub fn odometer_m(&self) -> f64 {
        self.odometer_m
    }

    /// The drift watch's candidate awaiting COMMIT.
    pub fn drift_candidate(&self) -> Option<&ParamValues> {
        self.drift_candidate.as_ref()
    }

    /// Offers `values` (the learnt set) for COMMIT outside any session, or
    /// withdraws the offer (`None`).
    pub fn set_drift_candidate(&mut self, values: Option<ParamValues>) {
        self.drift_candidate = values;
    }

    /// Commits `values` (the candidate bounded per step,
    /// [`crate::drift::bounded_step`]) by itself: only at a standstill with
    /// a candidate, no guided calibration, nothing out and no write-back
    /// pending, and within the bounds; stored, applied and written back as
    /// a COMMIT is, but nobody is answered. Nothing when it may not.
    pub fn auto_commit(
        &mut self,
        t_s: f64,
        values: ParamValues,
        writeback_pending: bool,
    ) -> Vec<Output> {
        let mut out = Vec::new();
        if self.drift_candidate.is_none()
            || self.is_guided()
            || self.pending.is_some()
            || writeback_pending
            || !self.is_standstill(t_s)
            || values == self.current_values()
            || self.config.bounds.check(&values).is_err()
        {
            return out;
        }
        let then = AfterStore::Candidate { values, auto: true };
        let _ = self.store(values, "drift-auto", t_s, then, &mut out);
        out
    }

    /// Empties the online ring (its steps were read with a set no longer in
    /// use, or a guided calibration took over).
    fn restart_online(&mut self) {
        if let Some(r) = self.online.as_mut() {
            r.clear();
            self.online_generation += 1;
        }
    }

    /// The nominal parameters.
    pub fn nominal(&self) -> &VehicleParams {
        &self.nominal
    }

    /// The guided session's phase.
    pub fn phase(&self) -> Phase {
        self.session.as_ref().map_or(Phase::Idle, Session::phase)
    }

    /// What the driver should do now.
    pub fn instruction(&self) -> Instruction {
        self.session
            .as_ref()
            .map_or(Instruction::Idle, Session::instruction)
    }

    /// Whether a session or a steering calibration is in progress.
    pub fn is_active(&self) -> bool {
        self.phase() != Phase::Idle || self.steering.is_some()
    }

    /// The direction of the run being driven (or last driven).
    pub fn run_direction(&self) -> Option<Direction> {
        self.run_direction
    }

    /// The distance of the run being recorded, m.
    pub fn run_distance_m(&self) -> f64 {
        self.run_distance_m
    }

    /// Accepted runs, [CW, CCW].
    pub fn accepted(&self) -> [u8; 2] {
        self.accepted
    }

    /// Rejected runs, [CW, CCW].
    pub fn rejected(&self) -> [u8; 2] {
        self.rejected
    }

    /// Why the last run was rejected.
    pub fn reject_reason(&self) -> Option<&Rejection> {
        self.reject_reason.as_ref()
    }

    /// The rear result awaiting commit.
    pub fn result(&self) -> Option<&CalibrationResult> {
        self.result.as_ref()
    }

    /// The steering calibration in progress.
    pub fn steering(&self) -> Option<&ArcCollector> {
        self.steering.as_ref()
    }

    /// Whether the vehicle has stood still long enough at `t_s`.
    pub fn is_standstill(&self, t_s: f64) -> bool {
        self.standstill.is_still(t_s)
    }

    /// The standstill judge.
    pub fn standstill(&self) -> Standstill {
        self.standstill
    }

    /// Whether a store of the file is out.
    pub fn is_storing(&self) -> bool {
        matches!(self.pending, Some(Pending::Store { .. }))
    }

    /// Whether a persistence or computation is out.
    pub fn is_busy(&self) -> bool {
        self.pending.is_some()
    }

    /// The values in use: the file's current set, or the nominal ones.
    pub fn current_values(&self) -> ParamValues {
        self.file
            .current
            .as_ref()
            .map_or_else(|| ParamValues::nominal(&self.nominal), |s| s.values)
    }

    /// The values a rear result gives, the rest as in use.
    pub fn values_of(&self, r: &CalibrationResult) -> ParamValues {
        ParamValues {
            rear_tread_m: r.rear.tread_m,
            rear_left_diameter_m: r.rear.left_diameter_m,
            rear_right_diameter_m: r.rear.right_diameter_m,
            ..self.current_values()
        }
    }

    /// The values a steering fit gives, the rest as in use.
    pub fn steering_values(&self, fit: &SteeringFit) -> ParamValues {
        let map = fit.map();
        ParamValues {
            steering_gain: map.gain,
            steering_offset_rad: map.offset_rad,
            ..self.current_values()
        }
    }

    /// The fit's uncertainty as a commit judges it: the gain's standard
    /// deviation relative to the nominal gain, the offset's in radians.
    pub fn steering_uncertainty(&self, fit: &SteeringFit) -> (f64, f64) {
        let (gain_std, offset_std_rad) = fit.std_devs();
        (gain_std / self.nominal.steering().gain, offset_std_rad)
    }

    fn vehicle(&self, v: &ParamValues) -> VehicleParams {
        self.nominal
            .with_rear(
                v.rear_tread_m,
                v.rear_left_diameter_m,
                v.rear_right_diameter_m,
            )
            .and_then(|p| p.with_steering(v.steering_map()))
            .unwrap_or(self.nominal)
    }

    /// A session over the values in use: runs are recorded with the
    /// parameters the odometry uses.
    fn fresh_session(&self) -> Session {
        Session::new(
            self.vehicle(&self.current_values()),
            SteeringProvenance::Independent,
            SessionConfig {
                standstill_speed_mps: self.config.standstill_speed_mps,
                standstill_time_s: self.config.standstill_time_s,
                ..SessionConfig::default()
            },
        )
    }

    fn arc_geometry(&self) -> ArcGeometry {
        let v = self.current_values();
        ArcGeometry {
            nominal_gain: self.nominal.steering().gain,
            rear: RearParams {
                tread_m: v.rear_tread_m,
                left_diameter_m: v.rear_left_diameter_m,
                right_diameter_m: v.rear_right_diameter_m,
            },
            wheelbase_m: self.nominal.wheelbase_m(),
        }
    }

    /// Feeds the session and keeps the run counts.
    fn event(&mut self, event: Event) -> Vec<Action> {
        let before = self.instruction();
        let session = self.session.take().unwrap_or_else(|| self.fresh_session());
        let (session, actions) = session.on_event(event);
        self.session = Some(session);
        for a in &actions {
            match a {
                Action::RunStarted { .. } => {
                    self.run_distance_m = 0.0;
                    self.run_direction = match self.instruction() {
                        Instruction::Drive { direction, .. }
                        | Instruction::Go { direction, .. }
                        | Instruction::GoToStart { direction, .. } => Some(direction),
                        _ => match before {
                            Instruction::Go { direction, .. }
                            | Instruction::GoToStart { direction, .. } => Some(direction),
                            _ => None,
                        },
                    };
                }
                Action::RunAccepted { .. } => {
                    if let Some(d) = self.run_direction {
                        self.accepted[dir_index(d)] = self.accepted[dir_index(d)].saturating_add(1);
                    }
                }
                Action::RunRejected { reason, .. } => {
                    if let Some(d) = self.run_direction {
                        self.rejected[dir_index(d)] = self.rejected[dir_index(d)].saturating_add(1);
                    }
                    self.reject_reason = Some(*reason);
                }
                _ => {}
            }
        }
        actions
    }

    /// Feeds a command event to the session; its refusal.
    fn session_event(&mut self, event: Event) -> std::result::Result<(), Refused> {
        let actions = self.event(event);
        actions
            .iter()
            .find_map(|a| match a {
                Action::Refused { reason, .. } => Some(Err(Refused::Session(*reason))),
                _ => None,
            })
            .unwrap_or(Ok(()))
    }

    /// The filter closed a correction window at the last step, its gate
    /// finding a rear wheel slipping in it or not: a drive being recorded
    /// marks the window's samples (see [`DriveRecorder::window_closed`]).
    pub fn on_window(&mut self, rear_slipped: bool) {
        if let Some(drive) = self.drive.as_mut() {
            drive.window_closed(rear_slipped);
        }
        if let Some(r) = self.online.as_mut() {
            r.window_closed(rear_slipped);
        }
    }

    /// A filter step at `t_s`: `rear_rev` wheel revolutions (left, right)
    /// since the previous step, the steering signal, and the yaw rate the
    /// filter used; the front wheels not read ([`Self::on_step_with_front`]).
    pub fn on_step(
        &mut self,
        t_s: f64,
        rear_rev: (f64, f64),
        steer_signal: Option<f64>,
        yaw_rate_radps: Option<f64>,
    ) -> Vec<Output> {
        self.on_step_with_front(t_s, rear_rev, None, steer_signal, yaw_rate_radps)
    }

    /// [`Self::on_step`] with the front wheels' revolutions (left, right)
    /// of the step, `None` when they were not fresh: the drift watch reads
    /// the front tyres' ratio from them ([`crate::front_ratio`]).
    pub fn on_step_with_front(
        &mut self,
        t_s: f64,
        rear_rev: (f64, f64),
        front_rev: Option<(f64, f64)>,
        steer_signal: Option<f64>,
        yaw_rate_radps: Option<f64>,
    ) -> Vec<Output> {
        let p = self.vehicle(&self.current_values());
        let circumference = |w: Wheel| std::f64::consts::PI * p.wheel_diameter_m(w);
        let (left_m, right_m) = (
            circumference(Wheel::RearLeft) * rear_rev.0,
            circumference(Wheel::RearRight) * rear_rev.1,
        );
        let step = DriveStep {
            t_s,
            rear_left_m: left_m,
            rear_right_m: right_m,
            front_m: front_rev.map(|(l, r)| {
                (
                    circumference(Wheel::FrontLeft) * l,
                    circumference(Wheel::FrontRight) * r,
                )
            }),
            steer_angle_rad: steer_signal.map(|u| p.steering().angle_rad(u)),
            yaw_rate_radps,
            dt_s: self.standstill.interval_s(t_s),
        };
        if let Some(drive) = self.drive.as_mut() {
            drive.step(&step);
        }
        if self.is_guided() {
            if self.online.as_ref().is_some_and(|r| !r.is_empty()) {
                self.restart_online();
            }
        } else if let Some(r) = self.online.as_mut() {
            r.step(&step);
        }
        let distance_m = 0.5 * (left_m + right_m);
        if distance_m.is_finite() {
            self.odometer_m += distance_m.abs();
        }
        let moving = self.standstill.step(t_s, distance_m);
        let sample = RevSample {
            t_s,
            rear_left_rev: rear_rev.0,
            rear_right_rev: rear_rev.1,
            front_rev: None,
            steer_signal: steer_signal.unwrap_or(0.0),
        };
        let geometry = self.arc_geometry();
        if let Some(st) = self.steering.as_mut() {
            st.step(
                sample,
                steer_signal.is_some(),
                distance_m,
                moving,
                &geometry,
            );
        }
        let mut out = Vec::new();
        let phase = self.phase();
        if matches!(phase, Phase::Positioning | Phase::Recording) {
            if phase == Phase::Recording && distance_m.is_finite() {
                self.run_distance_m += distance_m.abs();
            }
            let before = self.instruction();
            self.event(Event::Sample(sample));
            if self.instruction() != before {
                out.push(Output::InstructionChanged);
            }
        }
        out.extend(self.apply_if_still(t_s));
        out
    }

    /// A position fix from the bus: a local x and y in metres, or
    /// (`geodetic`) latitude and longitude in degrees; kept while a drive
    /// is recorded; `sigma_m` the 1σ per axis its source states, if it does.
    pub fn on_fix(
        &mut self,
        t_s: f64,
        first: f64,
        second: f64,
        geodetic: bool,
        sigma_m: Option<f64>,
    ) {
        if let Some(drive) = self.drive.as_mut() {
            drive.fix(t_s, first, second, geodetic, sigma_m);
        }
        if !self.is_guided()
            && let Some(r) = self.online.as_mut()
        {
            r.fix(t_s, first, second, geodetic, sigma_m);
        }
    }

    /// The input path refused or faulted a wheel frame (`code`: the
    /// decoder's fault code): a run recording now is rejected at its end,
    /// and the steering arc being driven is dropped.
    pub fn on_fault(&mut self, t_s: f64, code: u8) {
        if let Some(st) = self.steering.as_mut() {
            st.fault();
        }
        if self.phase() == Phase::Recording {
            self.event(Event::InputFault {
                t_s,
                fault: InputFault::Decoder { code },
            });
        }
    }

    /// The clock: a set waiting for a standstill is applied when there is one.
    pub fn tick(&mut self, t_s: f64) -> Vec<Output> {
        self.apply_if_still(t_s)
    }

    fn apply_if_still(&mut self, t_s: f64) -> Vec<Output> {
        match self.pending_apply {
            Some((version, values)) if self.is_standstill(t_s) => {
                self.pending_apply = None;
                vec![Output::Apply { version, values }]
            }
            _ => Vec::new(),
        }
    }

    /// An operator command at `t_s`; `writeback_pending` says whether the
    /// previous set still waits for its acknowledgement (a new set is not
    /// stored meanwhile).
    pub fn on_command(
        &mut self,
        t_s: f64,
        command: Command,
        writeback_pending: bool,
    ) -> Vec<Output> {
        if self.pending.is_some() {
            return vec![Output::Answer(Err(Refused::Session(Refusal::Busy)))];
        }
        let mut out = Vec::new();
        match self.judge(t_s, command, writeback_pending, &mut out) {
            Some(answer) => {
                out.insert(0, Output::Answer(answer));
                out
            }
            // Persisting or computing: answered when that is done.
            None => out,
        }
    }

    /// Carries out the command or refuses it; `None` when the answer waits
    /// for an effect the caller carries out.
    fn judge(
        &mut self,
        t_s: f64,
        command: Command,
        writeback_pending: bool,
        out: &mut Vec<Output>,
    ) -> Option<std::result::Result<(), Refused>> {
        if self.drive.is_some() {
            match command {
                Command::StartSession { .. } | Command::StartSteering => {
                    return Some(Err(Refused::Session(Refusal::SessionActive)));
                }
                Command::Abort => {
                    self.drive = None;
                    self.drive_result = None;
                    return Some(Ok(()));
                }
                Command::Compute => return self.compute_drive(out),
                Command::Commit => return self.commit_drive(t_s, writeback_pending, out),
                _ => {}
            }
        }
        let steering = self.steering.is_some();
        Some(match command {
            Command::StartSession { .. } if steering => {
                Err(Refused::Session(Refusal::SessionActive))
            }
            Command::StartSession {
                radius_m,
                runs_per_direction,
            } => {
                if self.phase() == Phase::Idle {
                    // Record with the parameters in use now.
                    self.session = Some(self.fresh_session());
                }
                let r = self.session_event(Event::StartSession {
                    radius_m,
                    runs_per_direction,
                });
                if r.is_ok() {
                    self.accepted = [0; 2];
                    self.rejected = [0; 2];
                    self.reject_reason = None;
                    self.result = None;
                    self.run_distance_m = 0.0;
                }
                r
            }
            Command::StartSteering => self.start_steering(),
            Command::StartDrive => self.start_drive(),
            Command::Abort if steering => {
                self.steering = None;
                Ok(())
            }
            Command::Compute if steering => self.compute_steering(),
            Command::Commit if steering => {
                return self.commit_steering(t_s, writeback_pending, out);
            }
            Command::EndRun => self.session_event(Event::EndRun),
            Command::StartRun => self.session_event(Event::StartRun),
            Command::EndPose(pose) => self.session_event(Event::MeasuredEndPose(pose)),
            Command::Abort => {
                let r = self.session_event(Event::Abort);
                if r.is_ok() {
                    self.result = None;
                }
                r
            }
            Command::Compute => return self.compute(out),
            Command::Commit => return self.commit(t_s, writeback_pending, out),
            Command::Rollback => return self.rollback(writeback_pending, out),
        })
    }

    fn compute(&mut self, out: &mut Vec<Output>) -> Option<std::result::Result<(), Refused>> {
        let actions = self.event(Event::Compute);
        if let Some(Action::Refused { reason, .. }) = actions.first() {
            return Some(Err(Refused::Session(*reason)));
        }
        let Some(job) = self.session.as_ref().and_then(Session::calibration_job) else {
            return Some(Err(Refused::ComputeFailed));
        };
        self.pending = Some(Pending::ComputeRear {
            track: job.track,
            runs: job.runs.clone(),
        });
        out.push(Output::Compute(Job::Rear(job)));
        None
    }

    /// The outcome of the [`Job`] of the last [`Output::Compute`].
    pub fn on_computed(&mut self, outcome: JobOutcome) -> Vec<Output> {
        let answer = match (self.pending.take(), outcome) {
            (Some(Pending::ComputeRear { track, runs }), JobOutcome::Rear(outcome)) => {
                self.computed_from = Some((track, runs));
                let actions = self.event(Event::Computed(outcome));
                match actions.iter().find_map(|a| match a {
                    Action::ResultReady(r) => Some(*r),
                    _ => None,
                }) {
                    Some(r) => {
                        self.result = Some(r);
                        Ok(())
                    }
                    None => Err(Refused::ComputeFailed),
                }
            }
            (Some(Pending::ComputeDrive), JobOutcome::Drive(outcome)) => {
                match (outcome, self.drive.as_mut()) {
                    (Ok(result), Some(_)) => {
                        self.drive_result = Some(*result);
                        Ok(())
                    }
                    (_, drive) => {
                        if let Some(d) = drive {
                            d.reopen();
                        }
                        Err(Refused::ComputeFailed)
                    }
                }
            }
            (pending, _) => {
                // Not the outcome of what is out: keep waiting for that.
                self.pending = pending;
                return Vec::new();
            }
        };
        vec![Output::Answer(answer)]
    }

    /// Commits `values` to a copy of the file (the next version) and asks
    /// for it to be stored; the answer waits for the store.
    fn store(
        &mut self,
        values: ParamValues,
        method: &str,
        t_s: f64,
        then: AfterStore,
        out: &mut Vec<Output>,
    ) -> Option<std::result::Result<(), Refused>> {
        let mut file = self.file.clone();
        // Bus timestamps are Unix time on a live bus.
        let created = t_s.max(0.0) as u64;
        let version = file
            .commit(values, method, created, self.config.max_history)
            .version;
        self.ask_to_store(file, version, then, out)
    }

    /// Asks for `file` to be stored; `then` finishes the command once it
    /// is (set `version` in use), and the answer waits until then.
    fn ask_to_store(
        &mut self,
        file: ParamFile,
        version: u16,
        then: AfterStore,
        out: &mut Vec<Output>,
    ) -> Option<std::result::Result<(), Refused>> {
        out.push(Output::Persist(file.clone()));
        self.pending = Some(Pending::Store {
            file,
            version,
            then: Box::new(then),
        });
        None
    }

    fn commit(
        &mut self,
        t_s: f64,
        writeback_pending: bool,
        out: &mut Vec<Output>,
    ) -> Option<std::result::Result<(), Refused>> {
        if self.phase() == Phase::Idle
            && let Some(values) = self.drift_candidate
        {
            return self.commit_candidate(t_s, values, writeback_pending, out);
        }
        let (Phase::Computed, Some(result)) = (self.phase(), self.result) else {
            return Some(Err(Refused::Session(Refusal::NothingToCommit)));
        };
        if writeback_pending {
            return Some(Err(Refused::WritebackBusy));
        }
        let values = self.values_of(&result);
        if self.config.bounds.check(&values).is_err() {
            return Some(Err(Refused::OutOfBounds));
        }
        let uncertain = |std: Option<f64>, max: f64| std.is_none_or(|s| s.is_nan() || s > max);
        if uncertain(result.tread_std_m, self.config.max_tread_std_m)
            || uncertain(result.ratio_std, self.config.max_ratio_std)
        {
            return Some(Err(Refused::UncertaintyTooHigh));
        }
        let method = format!("{:?}", result.method).to_lowercase();
        self.store(
            values,
            &method,
            t_s,
            AfterStore::Rear { result, values },
            out,
        )
    }

    /// COMMIT of the drift watch's candidate outside any session: checked
    /// against the bounds as any commit, stored as the next version,
    /// applied at a standstill and written back.
    fn commit_candidate(
        &mut self,
        t_s: f64,
        values: ParamValues,
        writeback_pending: bool,
        out: &mut Vec<Output>,
    ) -> Option<std::result::Result<(), Refused>> {
        if writeback_pending {
            return Some(Err(Refused::WritebackBusy));
        }
        if self.config.bounds.check(&values).is_err() {
            return Some(Err(Refused::OutOfBounds));
        }
        let then = AfterStore::Candidate {
            values,
            auto: false,
        };
        self.store(values, "drift", t_s, then, out)
    }

    fn rollback(
        &mut self,
        writeback_pending: bool,
        out: &mut Vec<Output>,
    ) -> Option<std::result::Result<(), Refused>> {
        if self.phase() != Phase::Idle || self.steering.is_some() {
            return Some(Err(Refused::Session(Refusal::SessionActive)));
        }
        if writeback_pending {
            return Some(Err(Refused::WritebackBusy));
        }
        let mut file = self.file.clone();
        let Some(set) = file.rollback().cloned() else {
            return Some(Err(Refused::Session(Refusal::NothingToRollback)));
        };
        let then = AfterStore::Rollback { values: set.values };
        self.ask_to_store(file, set.version, then, out)
    }

    /// Whether the file of the last [`Output::Persist`] was stored at `t_s`
    /// (`Err`: it was not, and the command that asked is refused with
    /// nothing changed).
    pub fn on_persisted(&mut self, t_s: f64, stored: bool) -> Vec<Output> {
        let Some(Pending::Store {
            file,
            version,
            then,
        }) = self.pending.take()
        else {
            return Vec::new();
        };
        let auto = matches!(*then, AfterStore::Candidate { auto: true, .. });
        if !stored {
            return if auto {
                Vec::new()
            } else {
                vec![Output::Answer(Err(Refused::PersistFailed))]
            };
        }
        self.file = file;
        let mut out = if auto {
            Vec::new()
        } else {
            vec![Output::Answer(Ok(()))]
        };
        let values = match *then {
            AfterStore::Rear { result, values } => {
                let actions = self.event(Event::Commit);
                debug_assert!(
                    !matches!(actions.first(), Some(Action::Refused { .. })),
                    "the session refused a checked commit"
                );
                self.result = None;
                if let Some((track, runs)) = self.computed_from.take() {
                    out.push(Output::Report {
                        version,
                        committed: Box::new(Committed::Rear {
                            result,
                            track,
                            runs,
                        }),
                    });
                }
                values
            }
            AfterStore::Drive { values } => {
                self.drive = None;
                self.drive_result = None;
                values
            }
            AfterStore::Steering {
                fit,
                values,
                before,
                stds,
            } => {
                self.steering = None;
                out.push(Output::Report {
                    version,
                    committed: Box::new(Committed::Steering {
                        fit,
                        before,
                        gain_std_rel: stds.0.abs(),
                        offset_std_rad: stds.1,
                    }),
                });
                values
            }
            AfterStore::Rollback { values } => values,
            AfterStore::Candidate { values, .. } => {
                self.drift_candidate = None;
                values
            }
        };
        self.adopt(t_s, version, values, &mut out);
        out
    }

    /// Applies (now or at the next standstill) and writes back a set.
    fn adopt(&mut self, t_s: f64, version: u16, values: ParamValues, out: &mut Vec<Output>) {
        self.pending_apply = Some((version, values));
        out.extend(self.apply_if_still(t_s));
        // The ring's steps were read with the set before.
        self.restart_online();
        self.session = Some(self.fresh_session());
        out.push(Output::Adopted { version });
    }

    /// Starts recording a drive against the bus's fixes: only with no
    /// session, and with fixes configured.
    fn start_drive(&mut self) -> std::result::Result<(), Refused> {
        if self.phase() != Phase::Idle || self.steering.is_some() || self.drive.is_some() {
            return Err(Refused::Session(Refusal::SessionActive));
        }
        if !self.config.fixes_available {
            return Err(Refused::NotSupported);
        }
        self.drive = Some(DriveRecorder::default());
        self.drive_result = None;
        self.result = None;
        Ok(())
    }

    fn compute_drive(&mut self, out: &mut Vec<Output>) -> Option<std::result::Result<(), Refused>> {
        let base = self.current_values();
        let p = self.vehicle(&base);
        let model = DriveModel {
            rear_tread_m: p.rear_tread_m(),
            wheelbase_m: p.wheelbase_m(),
        };
        let drive = self.drive.as_mut()?;
        match drive.job(model, base, self.config.drive_gate) {
            Ok(job) => {
                self.pending = Some(Pending::ComputeDrive);
                out.push(Output::Compute(Job::Drive(job)));
                None
            }
            Err(_) => Some(Err(Refused::TooFewSamples)),
        }
    }

    fn commit_drive(
        &mut self,
        t_s: f64,
        writeback_pending: bool,
        out: &mut Vec<Output>,
    ) -> Option<std::result::Result<(), Refused>> {
        let Some((_, values)) = self.drive_result else {
            return Some(Err(Refused::Session(Refusal::NothingToCommit)));
        };
        if writeback_pending {
            return Some(Err(Refused::WritebackBusy));
        }
        if self.config.bounds.check(&values).is_err() {
            return Some(Err(Refused::OutOfBounds));
        }
        self.store(values, "drive", t_s, AfterStore::Drive { values }, out)
    }

    /// Starts the steering calibration (§10): only with the rear session
    /// idle and a calibrated rear set in use, since a map fitted with
    /// uncalibrated rear odometry makes the car drive the path on which that
    /// odometry closes (the trap of §10); without one, nothing to build on.
    fn start_steering(&mut self) -> std::result::Result<(), Refused> {
        if self.phase() != Phase::Idle || self.steering.is_some() {
            return Err(Refused::Session(Refusal::SessionActive));
        }
        if self.file.current.as_ref().is_none_or(|s| s.version == 0) {
            return Err(Refused::Session(Refusal::NothingToCommit));
        }
        self.steering = Some(ArcCollector::default());
        self.result = None;
        Ok(())
    }

    /// Fits the steering map over the arcs: `RunsIncomplete` with fewer than
    /// three distinct commands.
    fn compute_steering(&mut self) -> std::result::Result<(), Refused> {
        let geometry = self.arc_geometry();
        let Some(st) = self.steering.as_mut() else {
            return Err(Refused::Session(Refusal::NoSession));
        };
        if st.fit().is_some() {
            return Err(Refused::Session(Refusal::SessionActive));
        }
        match st.compute(&geometry) {
            Ok(_) => Ok(()),
            Err(ArcFitError::TooFewCommands) => Err(Refused::Session(Refusal::RunsIncomplete)),
            Err(ArcFitError::FitFailed) => Err(Refused::ComputeFailed),
        }
    }

    /// Commits a steering fit the way a rear result is committed: bounds,
    /// uncertainty limits, stored, applied at standstill, written back.
    fn commit_steering(
        &mut self,
        t_s: f64,
        writeback_pending: bool,
        out: &mut Vec<Output>,
    ) -> Option<std::result::Result<(), Refused>> {
        let Some(fit) = self.steering.as_ref().and_then(|s| s.fit().cloned()) else {
            return Some(Err(Refused::Session(Refusal::NothingToCommit)));
        };
        if writeback_pending {
            return Some(Err(Refused::WritebackBusy));
        }
        let values = self.steering_values(&fit);
        if self.config.bounds.check(&values).is_err() {
            return Some(Err(Refused::OutOfBounds));
        }
        // The figures the operator saw on the result pages.
        let stds = self.steering_uncertainty(&fit);
        let uncertain = |std: f64, max: f64| std.is_nan() || std > max;
        if uncertain(stds.0.abs(), self.config.max_steer_gain_std_rel)
            || uncertain(stds.1, self.config.max_steer_offset_std_rad)
        {
            return Some(Err(Refused::UncertaintyTooHigh));
        }
        let before = self.current_values().steering_map();
        self.store(
            values,
            "steering",
            t_s,
            AfterStore::Steering {
                fit,
                values,
                before,
                stds,
            },
            out,
        )
    }
}

#[cfg(test)]
mod tests;
