//! The live calibration session over CAN: `CALIB_CMD` in, `CALIB_STATUS`,
//! `CALIB_PARAMS` out, `CALIB_ACK` back (issue 6).
//!
//! [`LiveCalibration`] is pure: no async, no clock. Time comes in as bus
//! timestamps, frames come in already routed by id, and what the daemon must
//! do comes out as [`Output`]s. The one side effect it cannot defer, storing
//! the parameter file, goes through a [`Persister`] the caller supplies, so a
//! commit whose file cannot be written is refused before anything changes
//! (`PERSIST_FAILED`): a command is either carried out whole or not at all.
//!
//! Checks of a command, in order: CRC-8 (`BAD_CHECKSUM`), a counter equal to
//! the previous command's (`BAD_COUNTER`: a duplicate frame), the arming code
//! (`BAD_ARMING_CODE`), the command code (`UNKNOWN_COMMAND`), then the session
//! state (calib's refusals) and the daemon's own conditions (bounds,
//! uncertainty, write-back in progress). Every command, carried out or
//! refused, is answered on status page 1 (`LAST_CMD`, `CMD_REASON`, `CMD_SEQ`)
//! at once.

use canodom_calib::CalibrationResult;
use canodom_calib::RearParams;
use canodom_calib::drive::{DriveCalibration, DriveModel, DriveSample, Fix, calibrate_drive};
use canodom_calib::run::{InputFault, RevSample, Run};
use canodom_calib::session::{Action, Event, Instruction, Phase, Session, SessionConfig};
use canodom_calib::steering::{
    ArcEstimate, ArcOptions, SteeringFit, SteeringProvenance, estimate_arc, fit_steering,
};
use canodom_calib::track::{Direction, Track};
use canodom_can::frame::CanFrame;
use canodom_can::time::Timestamp;
use canodom_fusion::{Pose, VehicleParams, Wheel};
use canodom_params::persist::{ParamFile, ParamValues};
use canodom_pipeline::config::CalibrationConfig;
use canodom_protocol::calib_wire::{
    Ack, AckStatus, CalibWire, Command, Counts, DEFAULT_RUNS_PER_DIRECTION, InstructionCode,
    ParamSet as WireSet, Progress, Reason, StartPoint, State, StatusPage, WireDirection, Writeback,
};
use canodom_report::committed::Report;
use canodom_report::report::CalibrationReport;
use canodom_report::steering_report::SteeringReport;

/// Status period while a session is active, s (10 Hz).
const ACTIVE_STATUS_S: f64 = 0.1;
/// Status period otherwise, s.
const IDLE_STATUS_S: f64 = 1.0;
/// A steering arc ends when the signal moves the nominal road-wheel angle
/// by more than this from the arc's first sample, rad (0.25°): a servo
/// holding a command jitters far less, a new command moves it by degrees.
const ARC_SIGNAL_TOL_RAD: f64 = 0.25 * std::f64::consts::PI / 180.0;
/// Arcs whose signals differ by less than this (nominal angle, rad) count
/// as one command when judging whether the fit has enough distinct ones.
const DISTINCT_SIGNAL_RAD: f64 = 1.0 * std::f64::consts::PI / 180.0;
/// Distinct commands a steering fit needs: two fix a line, a third checks it.
const MIN_STEERING_COMMANDS: usize = 3;

/// The steering calibration (§10) in progress: constant-command arcs driven
/// with the calibrated rear set in use.
#[derive(Debug, Clone, Default)]
struct SteeringCollect {
    /// Arcs closed and long enough to estimate.
    arcs: Vec<ArcEstimate>,
    /// Samples of the arc being driven.
    current: Vec<RevSample>,
    /// Distance of the arc being driven, m.
    current_m: f64,
    /// The fit of `compute`, awaiting commit.
    fit: Option<SteeringFit>,
}

/// Stores the parameter file durably; `Err` carries the cause for the log.
pub type Persister = Box<dyn FnMut(&ParamFile) -> Result<(), String> + Send>;

/// What the daemon must do.
#[derive(Debug, Clone)]
pub enum Output {
    /// Send this frame on the bus.
    Send(CanFrame),
    /// Put this set (version ≥ 1) into the running odometry now (the vehicle
    /// stands still).
    Apply(u16, ParamValues),
    /// Write this report of a committed session or steering map (version, report).
    Report(u16, Box<Report>),
}

/// The parameter write-back in progress.
#[derive(Debug, Clone, Copy)]
struct WriteBack {
    set: WireSet,
    state: Writeback,
    /// Sends so far (the first and the retries).
    attempts: u8,
    deadline_s: f64,
}

/// The live calibration (see the module doc).
pub struct LiveCalibration {
    wire: CalibWire,
    config: CalibrationConfig,
    nominal: VehicleParams,
    session: Option<Session>,
    session_config: SessionConfig,
    file: ParamFile,
    persister: Persister,
    /// Set committed or rolled back to but not yet applied (moving).
    pending_apply: Option<(u16, ParamValues)>,
    last_counter: Option<u8>,
    last_cmd: u8,
    cmd_reason: Reason,
    cmd_seq: u8,
    /// Accepted and rejected runs, [CW, CCW].
    accepted: [u8; 2],
    rejected: [u8; 2],
    reject_reason: Reason,
    run_direction: Option<Direction>,
    run_distance_m: f64,
    result: Option<CalibrationResult>,
    /// The track and runs the result came from (for the report).
    computed_from: Option<(Track, Vec<Run>)>,
    writeback: Option<WriteBack>,
    still_since_s: Option<f64>,
    last_step_s: Option<f64>,
    next_status_s: Option<f64>,
    status_counter: u8,
    params_counter: u8,
    steering: Option<SteeringCollect>,
    /// A drive recorded against the bus's position fixes (START_DRIVE).
    drive: Option<DriveCollect>,
}

/// Steps of a recorded drive are merged into bins of this length: the fit
/// needs the shape of the drive, not every 10 ms, and runs inline (#21
/// moves computations off the runtime thread), so a ten-minute drive is
/// 12,000 samples, a fraction of a second to fit.
const DRIVE_BIN_S: f64 = 0.05;

/// The most samples a drive keeps (20 minutes of bins): the rest is not recorded.
const DRIVE_MAX_SAMPLES: usize = 24_000;

/// Mean Earth radius, metres, for latitude/longitude fixes turned into a
/// local frame (equirectangular around the first fix: centimetres over the
/// kilometres of a calibration drive).
const EARTH_RADIUS_M: f64 = 6_371_000.0;

/// A drive being recorded for calibration against the bus's fixes.
#[derive(Debug, Default)]
struct DriveCollect {
    samples: Vec<DriveSample>,
    /// The open bin: its distances, the last steering angle, and ∫ω dt, ∫dt.
    bin: Option<(DriveSample, f64, f64)>,
    fixes: Vec<Fix>,
    /// Latitude and longitude of the first fix (geodetic fixes only), degrees.
    origin: Option<(f64, f64)>,
    /// The computed set, with the fit it came from.
    result: Option<(DriveCalibration, ParamValues)>,
}

impl DriveCollect {
    /// Adds one filter step to the open bin, closing it after [`DRIVE_BIN_S`].
    fn push(
        &mut self,
        t_s: f64,
        left_m: f64,
        right_m: f64,
        steer: Option<f64>,
        yaw: Option<f64>,
        dt_s: f64,
    ) {
        if self.samples.len() >= DRIVE_MAX_SAMPLES {
            return;
        }
        let (bin, yaw_dt, dt) = self.bin.get_or_insert((
            DriveSample {
                t_s,
                rear_left_m: 0.0,
                rear_right_m: 0.0,
                steer_angle_rad: None,
                yaw_rate_radps: None,
            },
            0.0,
            0.0,
        ));
        bin.t_s = t_s;
        bin.rear_left_m += left_m;
        bin.rear_right_m += right_m;
        bin.steer_angle_rad = steer.or(bin.steer_angle_rad);
        if let Some(w) = yaw {
            *yaw_dt += w * dt_s;
            *dt += dt_s;
        }
        let start = self.samples.last().map_or(f64::NEG_INFINITY, |s| s.t_s);
        if t_s - start >= DRIVE_BIN_S {
            self.flush();
        }
    }

    /// Closes the open bin.
    fn flush(&mut self) {
        if let Some((mut bin, yaw_dt, dt)) = self.bin.take() {
            bin.yaw_rate_radps = (dt > 0.0).then(|| yaw_dt / dt);
            self.samples.push(bin);
        }
    }
}

impl std::fmt::Debug for LiveCalibration {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveCalibration")
            .field("phase", &self.phase())
            .field("file", &self.file)
            .finish_non_exhaustive()
    }
}

fn seconds(t: Timestamp) -> f64 {
    t.as_micros() as f64 * 1e-6
}

fn dir_index(d: Direction) -> usize {
    match d {
        Direction::Cw => 0,
        Direction::Ccw => 1,
    }
}

impl LiveCalibration {
    /// A live calibration for a vehicle with `nominal` parameters, whose
    /// parameter file currently holds `file` (its current set is in use).
    pub fn new(
        wire: CalibWire,
        config: CalibrationConfig,
        nominal: VehicleParams,
        file: ParamFile,
        persister: Persister,
    ) -> Self {
        let session_config = SessionConfig {
            standstill_speed_mps: config.standstill_speed_mps,
            standstill_time_s: config.standstill_time_s,
            ..SessionConfig::default()
        };
        let mut me = Self {
            wire,
            config,
            nominal,
            session: None,
            session_config,
            file,
            persister,
            pending_apply: None,
            last_counter: None,
            last_cmd: 0,
            cmd_reason: Reason::None,
            cmd_seq: 0,
            accepted: [0; 2],
            rejected: [0; 2],
            reject_reason: Reason::None,
            run_direction: None,
            run_distance_m: 0.0,
            result: None,
            computed_from: None,
            writeback: None,
            still_since_s: None,
            last_step_s: None,
            next_status_s: None,
            status_counter: 0,
            params_counter: 0,
            steering: None,
            drive: None,
        };
        me.session = Some(me.fresh_session());
        me
    }

    /// The parameter file as the daemon last stored it.
    pub fn file(&self) -> &ParamFile {
        &self.file
    }

    /// The session's phase.
    pub fn phase(&self) -> Phase {
        self.session.as_ref().map_or(Phase::Idle, Session::phase)
    }

    /// The write-back state.
    pub fn writeback(&self) -> Writeback {
        self.writeback.map_or(Writeback::Idle, |w| w.state)
    }

    fn current_values(&self) -> ParamValues {
        self.file.current.as_ref().map_or_else(
            || {
                let steer = self.nominal.steering();
                ParamValues {
                    rear_tread_m: self.nominal.rear_tread_m(),
                    rear_left_diameter_m: self.nominal.wheel_diameter_m(Wheel::RearLeft),
                    rear_right_diameter_m: self.nominal.wheel_diameter_m(Wheel::RearRight),
                    steering_gain: steer.gain,
                    steering_offset_rad: steer.offset_rad,
                    yaw_rate_bias_radps: None,
                    yaw_rate_scale: None,
                }
            },
            |s| s.values,
        )
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

    /// A session over the parameters in the file: the runs are recorded with
    /// the parameters the odometry uses.
    fn fresh_session(&self) -> Session {
        Session::new(
            self.vehicle(&self.current_values()),
            SteeringProvenance::Independent,
            self.session_config,
        )
    }

    /// Whether the vehicle has stood still (below the configured standstill
    /// speed for the configured time) at `t`, as the calibration judges it.
    pub fn is_standstill(&self, t: Timestamp) -> bool {
        self.standstill(seconds(t))
    }

    fn standstill(&self, t_s: f64) -> bool {
        match (self.last_step_s, self.still_since_s) {
            // No wheel data: nothing moves the vehicle we could see.
            (None, _) => true,
            (Some(_), None) => false,
            (Some(_), Some(since)) => t_s - since >= self.config.standstill_time_s,
        }
    }

    fn event(&mut self, event: Event) -> Vec<Action> {
        let session = self.session.take().unwrap_or_else(|| self.fresh_session());
        let before = session.instruction();
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
                    self.reject_reason = Reason::of_rejection(reason);
                }
                _ => {}
            }
        }
        actions
    }

    fn instruction(&self) -> Instruction {
        self.session
            .as_ref()
            .map_or(Instruction::Idle, Session::instruction)
    }

    /// A filter step: `rear_rev` wheel revolutions (left, right) since the
    /// previous step with the diameters in use, the steering signal, and the
    /// yaw rate the filter used (for a drive recorded against fixes).
    pub fn on_step(
        &mut self,
        t: Timestamp,
        rear_rev: (f64, f64),
        steer_signal: Option<f64>,
        yaw_rate_radps: Option<f64>,
    ) -> Vec<Output> {
        let t_s = seconds(t);
        let p = self.vehicle(&self.current_values());
        if let Some(drive) = self.drive.as_mut().filter(|d| d.result.is_none()) {
            let dt_s = self.last_step_s.map_or(0.0, |last| (t_s - last).max(0.0));
            let (dl, dr) = (
                std::f64::consts::PI * p.wheel_diameter_m(Wheel::RearLeft) * rear_rev.0,
                std::f64::consts::PI * p.wheel_diameter_m(Wheel::RearRight) * rear_rev.1,
            );
            let steer = steer_signal.map(|u| p.steering().angle_rad(u));
            drive.push(t_s, dl, dr, steer, yaw_rate_radps, dt_s);
        }
        let distance_m = 0.5
            * std::f64::consts::PI
            * (p.wheel_diameter_m(Wheel::RearLeft) * rear_rev.0
                + p.wheel_diameter_m(Wheel::RearRight) * rear_rev.1);
        // The first step has no interval: any distance is motion.
        let dt_s = self.last_step_s.map_or(0.0, |last| (t_s - last).max(0.0));
        let moving =
            !distance_m.is_finite() || distance_m.abs() > self.config.standstill_speed_mps * dt_s;
        if moving {
            self.still_since_s = None;
        } else if self.still_since_s.is_none() {
            self.still_since_s = Some(t_s);
        }
        self.last_step_s = Some(t_s);
        if self.steering.is_some() {
            self.steering_sample(t_s, rear_rev, steer_signal, distance_m, moving);
        }
        let phase = self.phase();
        if matches!(phase, Phase::Positioning | Phase::Recording) {
            if phase == Phase::Recording && distance_m.is_finite() {
                self.run_distance_m += distance_m.abs();
            }
            let before = self.instruction();
            self.event(Event::Sample(RevSample {
                t_s,
                rear_left_rev: rear_rev.0,
                rear_right_rev: rear_rev.1,
                front_rev: None,
                steer_signal: steer_signal.unwrap_or(0.0),
            }));
            if self.instruction() != before {
                // The driver's next move changed: tell at once.
                let mut out = self.status(t_s);
                out.extend(self.apply_if_still(t_s));
                return out;
            }
        }
        self.apply_if_still(t_s)
    }

    /// A position fix from the bus: a local x and y in metres, or (`geodetic`)
    /// latitude and longitude in degrees. Recorded while a drive is.
    pub fn on_fix(&mut self, t: Timestamp, first: f64, second: f64, geodetic: bool) {
        let Some(drive) = self.drive.as_mut().filter(|d| d.result.is_none()) else {
            return;
        };
        if !(first.is_finite() && second.is_finite()) {
            return;
        }
        let (x_m, y_m) = if geodetic {
            let (lat0, lon0) = *drive.origin.get_or_insert((first, second));
            (
                EARTH_RADIUS_M * lat0.to_radians().cos() * (second - lon0).to_radians(),
                EARTH_RADIUS_M * (first - lat0).to_radians(),
            )
        } else {
            (first, second)
        };
        let t_s = seconds(t);
        if drive.fixes.last().is_none_or(|f| t_s > f.t_s) {
            drive.fixes.push(Fix {
                t_s,
                x_m,
                y_m,
                heading_rad: None,
            });
        }
    }

    /// The input path refused or faulted a wheel frame (`code`: the
    /// decoder's fault code): a run recording now is rejected at its end.
    pub fn on_fault(&mut self, t: Timestamp, code: u8) {
        if let Some(st) = self.steering.as_mut() {
            // The arc lost samples: its curvature would be wrong.
            st.current.clear();
            st.current_m = 0.0;
        }
        if self.phase() == Phase::Recording {
            self.event(Event::InputFault {
                t_s: seconds(t),
                fault: InputFault::Decoder { code },
            });
        }
    }

    fn apply_if_still(&mut self, t_s: f64) -> Vec<Output> {
        match self.pending_apply {
            Some((v, values)) if self.standstill(t_s) => {
                self.pending_apply = None;
                vec![Output::Apply(v, values)]
            }
            _ => Vec::new(),
        }
    }

    /// Periodic work: status frames, write-back timeouts, deferred applies.
    pub fn tick(&mut self, t: Timestamp) -> Vec<Output> {
        let t_s = seconds(t);
        let mut out = self.apply_if_still(t_s);
        if let Some(wb) = self.writeback
            && wb.state == Writeback::Pending
            && t_s >= wb.deadline_s
        {
            if u32::from(wb.attempts) <= self.config.writeback_retries {
                out.extend(self.send_params(t_s, wb.set, wb.attempts.saturating_add(1)));
            } else {
                self.writeback = Some(WriteBack {
                    state: Writeback::Failed,
                    ..wb
                });
                out.extend(self.status(t_s));
            }
        }
        // 1 ms of slack: a tick exactly one period later must not miss by rounding.
        if self.next_status_s.is_none_or(|n| t_s >= n - 1e-3) {
            out.extend(self.status(t_s));
        }
        out
    }

    /// A `CALIB_ACK` frame.
    pub fn on_ack(&mut self, t: Timestamp, frame: &CanFrame) -> Vec<Output> {
        let t_s = seconds(t);
        if !self.wire.checksum_ok(frame.data()) {
            return Vec::new();
        }
        let Ok((Ack { version, status }, _)) = self.wire.decode_ack(frame.data()) else {
            return Vec::new();
        };
        match self.writeback {
            Some(wb) if wb.state == Writeback::Pending && wb.set.version == version => {
                let state = match status {
                    AckStatus::Stored => Writeback::Acked,
                    AckStatus::Refused => Writeback::Failed,
                };
                self.writeback = Some(WriteBack { state, ..wb });
                self.status(t_s)
            }
            _ => Vec::new(),
        }
    }

    /// A `CALIB_CMD` frame (the caller routes the configured command id here).
    ///
    /// The answer (status page 1 with the new `CMD_SEQ`) goes out before
    /// whatever the command caused, such as the `CALIB_PARAMS` pages of
    /// REQUEST_PARAMS: a client waits for its answer first and then for the
    /// result, so a result sent ahead of the answer would pass it by.
    pub fn on_command(&mut self, t: Timestamp, frame: &CanFrame) -> Vec<Output> {
        let t_s = seconds(t);
        let mut effects = Vec::new();
        let reason = self.judge(t_s, frame, &mut effects);
        self.cmd_reason = reason;
        self.cmd_seq = (self.cmd_seq + 1) % 8;
        let mut out = self.status(t_s);
        out.extend(effects);
        out
    }

    /// Carries out the command or refuses it; the reason (`None` = done).
    fn judge(&mut self, t_s: f64, frame: &CanFrame, out: &mut Vec<Output>) -> Reason {
        let data = frame.data();
        let Ok(cmd) = self.wire.decode_command(data) else {
            self.last_cmd = 0;
            return Reason::BadChecksum;
        };
        self.last_cmd = cmd.cmd_raw;
        if !cmd.checksum_ok {
            return Reason::BadChecksum;
        }
        let repeated = self.last_counter == Some(cmd.counter);
        self.last_counter = Some(cmd.counter);
        if repeated {
            return Reason::BadCounter;
        }
        if self
            .config
            .arming_code
            .is_some_and(|code| code != cmd.arming_code)
        {
            return Reason::BadArmingCode;
        }
        let Some(command) = cmd.command else {
            return Reason::UnknownCommand;
        };
        if let Some(reason) = self.drive_command(command, t_s, out) {
            return reason;
        }
        match command {
            Command::StartSession { .. } if self.steering.is_some() => Reason::SessionActive,
            Command::StartSession {
                track_radius_mm,
                runs_per_direction,
            } => {
                let runs = if runs_per_direction == 0 {
                    DEFAULT_RUNS_PER_DIRECTION
                } else {
                    runs_per_direction
                };
                if self.phase() == Phase::Idle {
                    // Record with the parameters in use now.
                    self.session = Some(self.fresh_session());
                }
                let r = self.session_event(Event::StartSession {
                    radius_m: f64::from(track_radius_mm) * 1e-3,
                    runs_per_direction: runs,
                });
                if r == Reason::None {
                    self.accepted = [0; 2];
                    self.rejected = [0; 2];
                    self.reject_reason = Reason::None;
                    self.result = None;
                    self.run_distance_m = 0.0;
                }
                r
            }
            Command::StartSteering => self.start_steering(),
            Command::StartDrive => self.start_drive(),
            Command::Abort if self.steering.is_some() => {
                self.steering = None;
                Reason::None
            }
            Command::Compute if self.steering.is_some() => self.compute_steering(),
            Command::Commit if self.steering.is_some() => self.commit_steering(t_s, out),
            Command::EndRun => self.session_event(Event::EndRun),
            Command::StartRun => self.session_event(Event::StartRun),
            Command::EndPose {
                dx_mm,
                dy_mm,
                dtheta_decideg,
            } => self.session_event(Event::MeasuredEndPose(Pose {
                x_m: f64::from(dx_mm) * 1e-3,
                y_m: f64::from(dy_mm) * 1e-3,
                heading_rad: (f64::from(dtheta_decideg) * 0.1).to_radians(),
            })),
            Command::Abort => {
                let r = self.session_event(Event::Abort);
                if r == Reason::None {
                    self.result = None;
                }
                r
            }
            Command::Compute => self.compute(),
            Command::Commit => self.commit(t_s, out),
            Command::Rollback => self.rollback(t_s, out),
            Command::RequestParams => {
                let set = self.wire_set();
                match self.wire.encode_params(&set, self.params_counter) {
                    Ok(pages) => {
                        self.params_counter = self.params_counter.wrapping_add(1);
                        out.extend(Self::frames(self.wire.params_id(), &pages));
                        Reason::None
                    }
                    Err(_) => Reason::OutOfBounds,
                }
            }
        }
    }

    /// Feeds a command event to the session; its refusal as a wire reason.
    fn session_event(&mut self, event: Event) -> Reason {
        let actions = self.event(event);
        actions
            .iter()
            .find_map(|a| match a {
                Action::Refused { reason, .. } => Some(Reason::of_refusal(*reason)),
                _ => None,
            })
            .unwrap_or(Reason::None)
    }

    fn compute(&mut self) -> Reason {
        let actions = self.event(Event::Compute);
        if let Some(Action::Refused { reason, .. }) = actions.first() {
            return Reason::of_refusal(*reason);
        }
        // The exact method takes some 20 ms: inline keeps the core pure.
        let Some(job) = self.session.as_ref().and_then(Session::calibration_job) else {
            return Reason::ComputeFailed;
        };
        let outcome = job.run();
        self.computed_from = Some((job.track, job.runs));
        let actions = self.event(Event::Computed(outcome));
        match actions.iter().find_map(|a| match a {
            Action::ResultReady(r) => Some(*r),
            _ => None,
        }) {
            Some(r) => {
                self.result = Some(r);
                Reason::None
            }
            None => Reason::ComputeFailed,
        }
    }

    fn values_of(&self, r: &CalibrationResult) -> ParamValues {
        ParamValues {
            rear_tread_m: r.rear.tread_m,
            rear_left_diameter_m: r.rear.left_diameter_m,
            rear_right_diameter_m: r.rear.right_diameter_m,
            ..self.current_values()
        }
    }

    fn commit(&mut self, t_s: f64, out: &mut Vec<Output>) -> Reason {
        let (Phase::Computed, Some(result)) = (self.phase(), self.result) else {
            return Reason::NothingToCommit;
        };
        if self.writeback() == Writeback::Pending {
            return Reason::WritebackBusy;
        }
        let values = self.values_of(&result);
        if self.config.bounds.check(&values).is_err() {
            return Reason::OutOfBounds;
        }
        let uncertain = |std: Option<f64>, max: f64| std.is_none_or(|s| s.is_nan() || s > max);
        if uncertain(result.tread_std_m, self.config.max_tread_std_m)
            || uncertain(result.ratio_std, self.config.max_ratio_std)
        {
            return Reason::UncertaintyTooHigh;
        }
        let method = format!("{:?}", result.method).to_lowercase();
        let version = match self.store_committed(values, &method, t_s) {
            Ok(v) => v,
            Err(reason) => return reason,
        };
        let actions = self.event(Event::Commit);
        if let Some(Action::Refused { reason, .. }) = actions.first() {
            // Not reachable after the checks above; the file is stored, so
            // keep it consistent with what is in use.
            tracing::warn!(?reason, "session refused a checked commit");
        }
        self.result = None;
        if let Some((track, runs)) = self.computed_from.take() {
            out.push(Output::Report(
                version,
                Box::new(Report::Rear(CalibrationReport::build(
                    &result,
                    track,
                    &runs,
                    &[],
                ))),
            ));
        }
        self.adopt(t_s, version, values, out);
        Reason::None
    }

    /// Commits `values` to the parameter file and stores it durably; the
    /// new version, or `PERSIST_FAILED` (and no change) when it cannot be
    /// stored.
    fn store_committed(
        &mut self,
        values: ParamValues,
        method: &str,
        t_s: f64,
    ) -> Result<u16, Reason> {
        let mut file = self.file.clone();
        // Bus timestamps are Unix time on a live bus.
        let created = t_s.max(0.0) as u64;
        let version = file
            .commit(values, method, created, self.config.max_history)
            .version;
        if let Err(cause) = (self.persister)(&file) {
            tracing::warn!(%cause, method, "calibrated parameters not stored; commit refused");
            return Err(Reason::PersistFailed);
        }
        self.file = file;
        Ok(version)
    }

    /// Applies (now or at the next standstill) and writes back a set.
    fn adopt(&mut self, t_s: f64, version: u16, values: ParamValues, out: &mut Vec<Output>) {
        self.pending_apply = Some((version, values));
        out.extend(self.apply_if_still(t_s));
        self.session = Some(self.fresh_session());
        let set = self.wire_set();
        out.extend(self.send_params(t_s, set, 1));
    }

    fn rollback(&mut self, t_s: f64, out: &mut Vec<Output>) -> Reason {
        if self.phase() != Phase::Idle || self.steering.is_some() {
            return Reason::SessionActive;
        }
        if self.writeback() == Writeback::Pending {
            return Reason::WritebackBusy;
        }
        let mut file = self.file.clone();
        let Some(set) = file.rollback().cloned() else {
            return Reason::NothingToRollback;
        };
        if let Err(cause) = (self.persister)(&file) {
            tracing::warn!(%cause, "rolled-back parameters not stored; rollback refused");
            return Reason::PersistFailed;
        }
        self.file = file;
        self.adopt(t_s, set.version, set.values, out);
        Reason::None
    }

    /// The commands a recorded drive answers itself (`None` for the others).
    fn drive_command(
        &mut self,
        command: Command,
        t_s: f64,
        out: &mut Vec<Output>,
    ) -> Option<Reason> {
        self.drive.as_ref()?;
        Some(match command {
            Command::StartSession { .. } | Command::StartSteering => Reason::SessionActive,
            Command::Abort => {
                self.drive = None;
                Reason::None
            }
            Command::Compute => self.compute_drive(),
            Command::Commit => self.commit_drive(t_s, out),
            _ => return None,
        })
    }

    /// Starts recording a drive against the bus's position fixes: only with
    /// no session, and with `[calibration.fixes]` configured.
    fn start_drive(&mut self) -> Reason {
        if self.phase() != Phase::Idle || self.steering.is_some() || self.drive.is_some() {
            return Reason::SessionActive;
        }
        if self.config.fixes.is_none() {
            return Reason::NotSupported;
        }
        self.drive = Some(DriveCollect::default());
        self.result = None;
        Reason::None
    }

    /// Fits the recorded drive to its fixes (`canodom_calib::drive`).
    fn compute_drive(&mut self) -> Reason {
        let base = self.current_values();
        let p = self.vehicle(&base);
        let Some(drive) = self.drive.as_mut() else {
            return Reason::NoSession;
        };
        drive.flush();
        if drive.fixes.len() < 3 || drive.samples.len() < 3 {
            return Reason::TooFewSamples;
        }
        let model = DriveModel {
            rear_tread_m: p.rear_tread_m(),
            wheelbase_m: p.wheelbase_m(),
        };
        // Fixes outside the recorded steps say nothing about them.
        let (first, last) = (
            drive.samples[0].t_s,
            drive.samples[drive.samples.len() - 1].t_s,
        );
        let fixes: Vec<Fix> = drive
            .fixes
            .iter()
            .copied()
            .filter(|f| f.t_s >= first && f.t_s <= last)
            .collect();
        match calibrate_drive(&drive.samples, &fixes, &model) {
            Ok(cal) => {
                let values = crate::cmd::calibrate_drive::calibrated_values(&base, &cal);
                drive.result = Some((cal, values));
                Reason::None
            }
            Err(e) => {
                tracing::warn!(cause = %e, samples = drive.samples.len(), fixes = fixes.len(), "drive calibration failed");
                Reason::ComputeFailed
            }
        }
    }

    /// Commits a computed drive the way a rear result is committed: bounds,
    /// stored, applied at standstill, written back.
    fn commit_drive(&mut self, t_s: f64, out: &mut Vec<Output>) -> Reason {
        let Some((_, values)) = self.drive.as_ref().and_then(|d| d.result) else {
            return Reason::NothingToCommit;
        };
        if self.writeback() == Writeback::Pending {
            return Reason::WritebackBusy;
        }
        if self.config.bounds.check(&values).is_err() {
            return Reason::OutOfBounds;
        }
        let version = match self.store_committed(values, "drive", t_s) {
            Ok(v) => v,
            Err(reason) => return reason,
        };
        self.drive = None;
        self.adopt(t_s, version, values, out);
        Reason::None
    }

    /// Starts the steering calibration (§10): only with the rear session idle
    /// and a calibrated rear set in use, since a map fitted with uncalibrated
    /// rear odometry makes the car drive the path on which that odometry
    /// closes (the trap of §10); without one, `NOTHING_TO_COMMIT` (no
    /// calibrated set to build on).
    fn start_steering(&mut self) -> Reason {
        if self.phase() != Phase::Idle || self.steering.is_some() {
            return Reason::SessionActive;
        }
        if self.file.current.as_ref().is_none_or(|s| s.version == 0) {
            return Reason::NothingToCommit;
        }
        self.steering = Some(SteeringCollect::default());
        self.result = None;
        Reason::None
    }

    /// One step while collecting steering arcs: extends the current arc or
    /// closes it when the signal changed or the vehicle stopped.
    fn steering_sample(
        &mut self,
        t_s: f64,
        rear_rev: (f64, f64),
        steer_signal: Option<f64>,
        distance_m: f64,
        moving: bool,
    ) {
        let nominal_gain = self.nominal.steering().gain;
        let Some(st) = self.steering.as_ref() else {
            return;
        };
        if st.fit.is_some() {
            return;
        }
        let same_command = match (st.current.first(), steer_signal) {
            (Some(first), Some(u)) => {
                (nominal_gain * (u - first.steer_signal)).abs() <= ARC_SIGNAL_TOL_RAD
            }
            (None, _) => true,
            (Some(_), None) => false,
        };
        let usable = moving && distance_m.is_finite() && steer_signal.is_some();
        if !(usable && same_command) {
            self.close_arc();
        }
        if let (true, Some(u), Some(st)) = (usable, steer_signal, self.steering.as_mut()) {
            st.current.push(RevSample {
                t_s,
                rear_left_rev: rear_rev.0,
                rear_right_rev: rear_rev.1,
                front_rev: None,
                steer_signal: u,
            });
            st.current_m += distance_m.abs();
        }
    }

    /// Ends the current arc; estimates it with the rear set in use when it
    /// is long enough after the settling time (else it is dropped).
    fn close_arc(&mut self) {
        let v = self.current_values();
        let wheelbase_m = self.nominal.wheelbase_m();
        let Some(st) = self.steering.as_mut() else {
            return;
        };
        let samples = std::mem::take(&mut st.current);
        st.current_m = 0.0;
        if samples.is_empty() {
            return;
        }
        let rear = RearParams {
            tread_m: v.rear_tread_m,
            left_diameter_m: v.rear_left_diameter_m,
            right_diameter_m: v.rear_right_diameter_m,
        };
        match estimate_arc(&samples, &rear, wheelbase_m, &ArcOptions::default()) {
            Ok(arc) if arc.curvature_per_m.is_finite() => st.arcs.push(arc),
            Ok(_) => {}
            Err(e) => tracing::debug!(%e, "steering arc dropped"),
        }
    }

    /// Fits the steering map over the arcs: `RUNS_INCOMPLETE` with fewer
    /// than three distinct commands.
    fn compute_steering(&mut self) -> Reason {
        if self.steering.as_ref().is_some_and(|s| s.fit.is_some()) {
            return Reason::SessionActive;
        }
        self.close_arc();
        let nominal_gain = self.nominal.steering().gain;
        let Some(st) = self.steering.as_mut() else {
            return Reason::NoSession;
        };
        let mut commands: Vec<f64> = Vec::new();
        for a in &st.arcs {
            if !commands
                .iter()
                .any(|&u| (nominal_gain * (u - a.command)).abs() < DISTINCT_SIGNAL_RAD)
            {
                commands.push(a.command);
            }
        }
        if commands.len() < MIN_STEERING_COMMANDS {
            return Reason::RunsIncomplete;
        }
        match fit_steering(&st.arcs, false) {
            Ok(fit) if fit.gain.is_finite() && fit.offset_rad.is_finite() => {
                st.fit = Some(fit);
                Reason::None
            }
            _ => Reason::ComputeFailed,
        }
    }

    /// The fitted map with the rear values in use.
    fn steering_values(&self, fit: &SteeringFit) -> ParamValues {
        let map = fit.map();
        ParamValues {
            steering_gain: map.gain,
            steering_offset_rad: map.offset_rad,
            ..self.current_values()
        }
    }

    /// Commits a steering fit the way a rear result is committed: bounds,
    /// uncertainty limits, stored, applied at standstill, written back.
    fn commit_steering(&mut self, t_s: f64, out: &mut Vec<Output>) -> Reason {
        let Some(fit) = self.steering.as_ref().and_then(|s| s.fit.clone()) else {
            return Reason::NothingToCommit;
        };
        if self.writeback() == Writeback::Pending {
            return Reason::WritebackBusy;
        }
        let values = self.steering_values(&fit);
        if self.config.bounds.check(&values).is_err() {
            return Reason::OutOfBounds;
        }
        // The figures the operator saw on the result pages.
        let (gain_std_rel, offset_std_rad) = self.steering_uncertainty(&fit);
        let uncertain = |std: f64, max: f64| std.is_nan() || std > max;
        if uncertain(gain_std_rel.abs(), self.config.max_steer_gain_std_rel)
            || uncertain(offset_std_rad, self.config.max_steer_offset_std_rad)
        {
            return Reason::UncertaintyTooHigh;
        }
        let before = self.current_values().steering_map();
        let version = match self.store_committed(values, "steering", t_s) {
            Ok(v) => v,
            Err(reason) => return reason,
        };
        self.steering = None;
        out.push(Output::Report(
            version,
            Box::new(Report::Steering(SteeringReport::build(
                &fit,
                before,
                gain_std_rel.abs(),
                offset_std_rad,
            ))),
        ));
        self.adopt(t_s, version, values, out);
        Reason::None
    }

    /// The fit's uncertainty as the result pages show it and a commit judges
    /// it: the gain's standard deviation relative to the nominal gain (as the
    /// gain itself goes on the wire), the offset's in radians.
    fn steering_uncertainty(&self, fit: &SteeringFit) -> (f64, f64) {
        let (gain_std, offset_std_rad) = Self::fit_std(fit);
        (gain_std / self.nominal.steering().gain, offset_std_rad)
    }

    /// Standard deviations of the fit's gain and offset (least squares,
    /// residual variance over n − 2); NaN with no degree of freedom left.
    fn fit_std(fit: &SteeringFit) -> (f64, f64) {
        let n = fit.arcs.len() as f64;
        let mean_u = fit.arcs.iter().map(|a| a.command).sum::<f64>() / n;
        let sxx: f64 = fit.arcs.iter().map(|a| (a.command - mean_u).powi(2)).sum();
        let dof = n - 2.0;
        if dof <= 0.0 || sxx <= 0.0 {
            return (f64::NAN, f64::NAN);
        }
        let var = fit.residuals_rad.iter().map(|r| r * r).sum::<f64>() / dof;
        (
            (var / sxx).sqrt(),
            (var * (1.0 / n + mean_u * mean_u / sxx)).sqrt(),
        )
    }

    /// The steering map on the wire, relative to the nominal map: the
    /// "measured angle" of `CALIB_PARAMS` is the nominal map's angle (the
    /// raw signal's unit is the vehicle's, so an absolute gain may be 0.017
    /// for degrees and would not fit STEER_GAIN's range around 1).
    fn wire_steering(&self, v: &ParamValues) -> (f64, f64) {
        let n = self.nominal.steering();
        let gain = v.steering_gain / n.gain;
        (gain, v.steering_offset_rad - gain * n.offset_rad)
    }

    fn wire_set(&self) -> WireSet {
        let v = self.current_values();
        let (steer_gain, steer_offset_rad) = self.wire_steering(&v);
        WireSet {
            version: self.file.current.as_ref().map_or(0, |s| s.version),
            rear_tread_m: v.rear_tread_m,
            rear_left_diameter_m: v.rear_left_diameter_m,
            rear_right_diameter_m: v.rear_right_diameter_m,
            diameter_ratio: v.diameter_ratio(),
            steer_gain,
            steer_offset_rad,
        }
    }

    fn send_params(&mut self, t_s: f64, set: WireSet, attempts: u8) -> Vec<Output> {
        let Ok(pages) = self.wire.encode_params(&set, self.params_counter) else {
            self.writeback = Some(WriteBack {
                set,
                state: Writeback::Failed,
                attempts,
                deadline_s: t_s,
            });
            return Vec::new();
        };
        self.params_counter = self.params_counter.wrapping_add(1);
        self.writeback = Some(WriteBack {
            set,
            state: Writeback::Pending,
            attempts,
            deadline_s: t_s + self.config.ack_timeout.as_secs_f64(),
        });
        Self::frames(self.wire.params_id(), &pages)
    }

    fn frames(id: canodom_can::frame::FrameId, pages: &[[u8; 8]]) -> Vec<Output> {
        pages
            .iter()
            .filter_map(|p| CalibWire::frame(id, p).ok())
            .map(Output::Send)
            .collect()
    }

    /// The result pages of a rear result or a steering fit awaiting commit.
    fn result_pages(&self) -> Vec<StatusPage> {
        let mut pages = Vec::new();
        if let Some(r) = self.result {
            let (steer_gain, steer_offset_rad) = self.wire_steering(&self.values_of(&r));
            pages.extend([
                StatusPage::ResultGeometry {
                    rear_tread_m: r.rear.tread_m,
                    rear_tread_std_m: r.tread_std_m.unwrap_or(f64::NAN),
                    diameter_ratio: r.rear.ratio(),
                },
                StatusPage::ResultQuality {
                    diameter_ratio_std: r.ratio_std.unwrap_or(f64::NAN),
                    end_err_before_m: r.e_max_before_m,
                    end_err_after_m: r.e_max_after_m,
                },
                StatusPage::ResultSteering {
                    steer_gain,
                    steer_gain_std: 0.0,
                    steer_offset_rad,
                },
                StatusPage::ResultExtra {
                    steer_offset_std_rad: 0.0,
                    version: self.file.last_version.checked_add(1).unwrap_or(1),
                },
            ]);
        }
        if let Some(fit) = self.steering.as_ref().and_then(|s| s.fit.as_ref()) {
            let (steer_gain, steer_offset_rad) = self.wire_steering(&self.steering_values(fit));
            let (gain_std_rel, offset_std_rad) = self.steering_uncertainty(fit);
            pages.extend([
                StatusPage::ResultSteering {
                    steer_gain,
                    steer_gain_std: gain_std_rel,
                    steer_offset_rad,
                },
                StatusPage::ResultExtra {
                    steer_offset_std_rad: offset_std_rad,
                    version: self.file.last_version.checked_add(1).unwrap_or(1),
                },
            ]);
        }
        pages
    }

    /// The status pages now; schedules the next.
    fn status(&mut self, t_s: f64) -> Vec<Output> {
        let phase = self.phase();
        let active = phase != Phase::Idle || self.steering.is_some();
        self.next_status_s = Some(
            t_s + if active {
                ACTIVE_STATUS_S
            } else {
                IDLE_STATUS_S
            },
        );
        let instruction = self.instruction();
        let (run, runs, direction) = match instruction {
            Instruction::GoToStart {
                run,
                runs,
                direction,
            }
            | Instruction::Go {
                run,
                runs,
                direction,
            }
            | Instruction::Drive {
                run,
                runs,
                direction,
            } => (run, runs, Some(direction)),
            Instruction::Stop { run, runs } => (run, runs, self.run_direction),
            _ => (0, 0, None),
        };
        let wb = self.writeback;
        // The steering calibration has no state of its own on the wire: it
        // shows as RECORDING while arcs are collected (RUN_INDEX = arcs
        // estimated so far, RUN_DISTANCE = the current arc's length) and as
        // COMPUTED once a fit awaits commit (RESULT_STEERING pages).
        let (state, run, run_distance_m) = match &self.steering {
            Some(st) if st.fit.is_some() => (State::Computed, 0, 0.0),
            Some(st) => (
                State::Recording,
                u8::try_from(st.arcs.len()).unwrap_or(u8::MAX),
                st.current_m,
            ),
            None => (
                State::of(phase),
                run,
                if phase == Phase::Recording {
                    self.run_distance_m
                } else {
                    0.0
                },
            ),
        };
        let mut pages = vec![
            StatusPage::Progress(Progress {
                state,
                instruction: InstructionCode::of(&instruction),
                run_index: run,
                runs_total: runs,
                direction: WireDirection::of(direction),
                start_point: StartPoint::of(direction),
                run_distance_m,
                writeback: wb.map_or(Writeback::Idle, |w| w.state),
                standstill: self.standstill(t_s),
                writeback_attempts: wb.map_or(0, |w| w.attempts),
            }),
            StatusPage::Counts(Counts {
                cw_accepted: self.accepted[0],
                cw_rejected: self.rejected[0],
                ccw_accepted: self.accepted[1],
                ccw_rejected: self.rejected[1],
                reject_reason: self.reject_reason,
                last_cmd: self.last_cmd,
                cmd_reason: self.cmd_reason,
                active_version: self.file.current.as_ref().map_or(0, |s| s.version),
                cmd_seq: self.cmd_seq,
            }),
        ];
        pages.extend(self.result_pages());
        let id = self.wire.status_id();
        let mut out = Vec::with_capacity(pages.len());
        for p in &pages {
            let data = self.wire.encode_status(p, self.status_counter);
            self.status_counter = self.status_counter.wrapping_add(1);
            if let Ok(f) = CalibWire::frame(id, &data) {
                out.push(Output::Send(f));
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use canodom_fusion::{SteeringMap, VehicleParams};
    use canodom_pipeline::config::Config;
    use canodom_pipeline::pipeline::Pipeline;
    use std::sync::{Arc, Mutex};

    type Stored = Arc<Mutex<Vec<ParamFile>>>;

    fn config() -> Config {
        let p = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/examples/rc_car.toml"));
        Config::load(p).unwrap()
    }

    fn values(tread_m: f64) -> ParamValues {
        ParamValues {
            rear_tread_m: tread_m,
            rear_left_diameter_m: 0.09,
            rear_right_diameter_m: 0.0915,
            steering_gain: 1f64.to_radians(),
            steering_offset_rad: 0.0,
            yaw_rate_bias_radps: None,
            yaw_rate_scale: None,
        }
    }

    /// A core over `file`; `fail` makes every store fail.
    fn core(c: &Config, file: ParamFile, fail: bool) -> (LiveCalibration, CalibWire, Stored) {
        let stored: Stored = Arc::default();
        let s = Arc::clone(&stored);
        let persister: Persister = Box::new(move |f: &ParamFile| {
            if fail {
                return Err("disk full".into());
            }
            s.lock().unwrap().push(f.clone());
            Ok(())
        });
        let nominal = *Pipeline::new(c).unwrap().params();
        let live = LiveCalibration::new(
            CalibWire::new(c.output.base_id).unwrap(),
            c.calibration.clone(),
            nominal,
            file,
            persister,
        );
        (live, CalibWire::new(c.output.base_id).unwrap(), stored)
    }

    fn at(ms: u64) -> Timestamp {
        Timestamp::from_micros(1_000_000_000 + ms * 1000)
    }

    fn cmd(w: &CalibWire, data: [u8; 8]) -> CanFrame {
        CalibWire::frame(w.cmd_id(), &data).unwrap()
    }

    /// The CALIB_STATUS pages among `out`, decoded, in order.
    fn status_pages<'a>(
        w: &'a CalibWire,
        out: &'a [Output],
    ) -> impl Iterator<Item = StatusPage> + 'a {
        out.iter().filter_map(|o| match o {
            Output::Send(f) if f.id() == w.status_id() => {
                w.decode_status(f.data()).ok().map(|(page, _)| page)
            }
            _ => None,
        })
    }

    /// Status page 1 among the outputs.
    fn counts(w: &CalibWire, out: &[Output]) -> Counts {
        status_pages(w, out)
            .find_map(|page| match page {
                StatusPage::Counts(c) => Some(c),
                _ => None,
            })
            .expect("status page 1")
    }

    fn progress(w: &CalibWire, out: &[Output]) -> Option<Progress> {
        status_pages(w, out).find_map(|page| match page {
            StatusPage::Progress(p) => Some(p),
            _ => None,
        })
    }

    fn params_sent(w: &CalibWire, out: &[Output]) -> Vec<u16> {
        out.iter()
            .filter_map(|o| match o {
                Output::Send(f) if f.id() == w.params_id() => {
                    w.decode_params(f.data()).ok().map(|(p, _)| p.version)
                }
                _ => None,
            })
            .collect()
    }

    fn two_sets() -> ParamFile {
        let mut file = ParamFile::default();
        file.commit(values(0.30), "exact", 1, 10);
        file.commit(values(0.31), "exact", 2, 10);
        file
    }

    #[test]
    fn every_refusal_is_answered_on_page_1_and_changes_nothing() {
        let mut c = config();
        c.calibration.arming_code = Some(0x5a);
        let (mut live, w, stored) = core(&c, ParamFile::default(), false);
        let start = Command::StartSession {
            track_radius_mm: 1000,
            runs_per_direction: 5,
        };
        let cases: Vec<([u8; 8], Reason)> = vec![
            (
                {
                    let mut d = w.encode_command(start, 0x5a, 1);
                    d[7] ^= 0xff;
                    d
                },
                Reason::BadChecksum,
            ),
            (w.encode_command(start, 0x11, 2), Reason::BadArmingCode),
            (
                w.encode_command_raw(0x0f, Command::Abort, 0x5a, 3),
                Reason::UnknownCommand,
            ),
            (
                w.encode_command(Command::Commit, 0x5a, 4),
                Reason::NothingToCommit,
            ),
            (
                w.encode_command(Command::Commit, 0x5a, 4),
                Reason::BadCounter,
            ),
            (
                w.encode_command(Command::Rollback, 0x5a, 5),
                Reason::NothingToRollback,
            ),
            (
                w.encode_command(Command::StartSteering, 0x5a, 6),
                Reason::NothingToCommit,
            ),
            (
                w.encode_command(Command::Compute, 0x5a, 7),
                Reason::NoSession,
            ),
            (
                w.encode_command(Command::EndRun, 0x5a, 8),
                Reason::NoSession,
            ),
        ];
        for (i, (data, reason)) in cases.iter().enumerate() {
            let out = live.on_command(at(i as u64), &cmd(&w, *data));
            let page = counts(&w, &out);
            assert_eq!(page.cmd_reason, *reason, "case {i}");
            assert_eq!(page.cmd_seq, u8::try_from((i + 1) % 8).unwrap());
            assert_eq!(live.phase(), Phase::Idle);
            assert!(params_sent(&w, &out).is_empty());
        }
        assert!(stored.lock().unwrap().is_empty());
        // The right code starts the session.
        let out = live.on_command(at(20), &cmd(&w, w.encode_command(start, 0x5a, 9)));
        assert_eq!(counts(&w, &out).cmd_reason, Reason::None);
        assert_eq!(live.phase(), Phase::Positioning);
        let p = progress(&w, &out).unwrap();
        assert_eq!(p.state, State::Positioning);
        assert_eq!((p.run_index, p.runs_total), (1, 10));
        // Out of order: a second start, a commit while positioning.
        let out = live.on_command(at(21), &cmd(&w, w.encode_command(start, 0x5a, 10)));
        assert_eq!(counts(&w, &out).cmd_reason, Reason::SessionActive);
        let out = live.on_command(
            at(22),
            &cmd(&w, w.encode_command(Command::Rollback, 0x5a, 11)),
        );
        assert_eq!(counts(&w, &out).cmd_reason, Reason::SessionActive);
        let out = live.on_command(at(23), &cmd(&w, w.encode_command(Command::Abort, 0x5a, 12)));
        assert_eq!(counts(&w, &out).cmd_reason, Reason::None);
        assert_eq!(live.phase(), Phase::Idle);
    }

    #[test]
    fn write_back_retries_exactly_then_fails_keeping_the_set_applied() {
        let c = config();
        let retries = c.calibration.writeback_retries;
        let timeout_ms = u64::try_from(c.calibration.ack_timeout.as_millis()).unwrap();
        let (mut live, w, stored) = core(&c, two_sets(), false);
        let out = live.on_command(at(0), &cmd(&w, w.encode_command(Command::Rollback, 0, 1)));
        assert_eq!(counts(&w, &out).cmd_reason, Reason::None);
        assert_eq!(counts(&w, &out).active_version, 1);
        assert_eq!(params_sent(&w, &out), vec![1; 4]);
        // No wheel data yet: standing still, applied at once.
        assert!(
            out.iter()
                .any(|o| matches!(o, Output::Apply(1, v) if *v == values(0.30)))
        );
        assert_eq!(
            stored
                .lock()
                .unwrap()
                .last()
                .unwrap()
                .current
                .as_ref()
                .unwrap()
                .version,
            1
        );
        let mut sends = 1;
        let mut failed_at = None;
        for ms in (10..=timeout_ms * u64::from(retries + 3)).step_by(10) {
            let out = live.tick(at(ms));
            if !params_sent(&w, &out).is_empty() {
                sends += 1;
                // Each resend comes one timeout after the previous.
                assert_eq!(ms % timeout_ms, 0, "resend at {ms} ms");
            }
            if failed_at.is_none() && live.writeback() == Writeback::Failed {
                failed_at = Some(ms);
                assert_eq!(progress(&w, &out).unwrap().writeback, Writeback::Failed);
            }
            assert!(!out.iter().any(|o| matches!(o, Output::Apply(..))));
        }
        assert_eq!(sends, 1 + retries);
        assert_eq!(failed_at, Some(timeout_ms * u64::from(retries + 1)));
        assert_eq!(live.file().current.as_ref().unwrap().version, 1);
    }

    #[test]
    fn ack_of_the_version_ends_the_write_back_and_moving_defers_the_apply() {
        let c = config();
        let (mut live, w, _) = core(&c, two_sets(), false);
        // Moving: the set waits for the standstill.
        let _ = live.on_step(at(0), (0.1, 0.1), Some(0.0), None);
        let out = live.on_command(at(5), &cmd(&w, w.encode_command(Command::Rollback, 0, 1)));
        assert!(!out.iter().any(|o| matches!(o, Output::Apply(..))));
        let ack = |version, status| {
            CalibWire::frame(w.ack_id(), &w.encode_ack(Ack { version, status }, 0)).unwrap()
        };
        assert!(live.on_ack(at(10), &ack(2, AckStatus::Stored)).is_empty());
        assert_eq!(live.writeback(), Writeback::Pending);
        let out = live.on_ack(at(20), &ack(1, AckStatus::Stored));
        assert_eq!(progress(&w, &out).unwrap().writeback, Writeback::Acked);
        let _ = live.on_step(at(100), (0.0, 0.0), Some(0.0), None);
        let still_ms = u64::try_from((c.calibration.standstill_time_s * 1000.0) as i64).unwrap();
        let early = live.on_step(at(100 + still_ms - 10), (0.0, 0.0), Some(0.0), None);
        assert!(!early.iter().any(|o| matches!(o, Output::Apply(..))));
        let late = live.on_step(at(100 + still_ms), (0.0, 0.0), Some(0.0), None);
        assert!(late.iter().any(|o| matches!(o, Output::Apply(1, _))));
        assert_eq!(
            live.tick(at(200 + still_ms))
                .iter()
                .filter(|o| matches!(o, Output::Apply(..)))
                .count(),
            0
        );
    }

    #[test]
    fn a_wheel_fault_during_a_run_rejects_it() {
        let c = config();
        let (mut live, w, _) = core(&c, ParamFile::default(), false);
        let start = Command::StartSession {
            track_radius_mm: 780,
            runs_per_direction: 1,
        };
        let _ = live.on_command(at(0), &cmd(&w, w.encode_command(start, 0, 1)));
        let mut ms = 0;
        for _ in 0..150 {
            ms += 10;
            let _ = live.on_step(at(ms), (0.0, 0.0), Some(0.0), None);
        }
        // Straight ahead for 2 m: recording.
        for _ in 0..200 {
            ms += 10;
            let _ = live.on_step(at(ms), (0.035, 0.035), Some(0.0), None);
        }
        assert_eq!(live.phase(), Phase::Recording);
        live.on_fault(at(ms), 2);
        let out = live.on_command(
            at(ms + 5),
            &cmd(&w, w.encode_command(Command::EndRun, 0, 2)),
        );
        let page = counts(&w, &out);
        assert_eq!(page.cmd_reason, Reason::None);
        assert_eq!(page.reject_reason, Reason::InputFault);
        assert_eq!(page.ccw_rejected + page.cw_rejected, 1);
        assert_eq!(live.phase(), Phase::Positioning);
    }

    /// Drives a whole noise-free session of `truth` to Computed; the time.
    fn computed_session(live: &mut LiveCalibration, w: &CalibWire, truth: &VehicleParams) -> u64 {
        use canodom_calib::synth::lap;
        let start = Command::StartSession {
            track_radius_mm: 780,
            runs_per_direction: 2,
        };
        let _ = live.on_command(at(0), &cmd(w, w.encode_command(start, 0, 1)));
        let track = Track::new(0.78).unwrap();
        let mut ms = 0;
        let rest = |live: &mut LiveCalibration, ms: &mut u64| {
            for _ in 0..150 {
                *ms += 10;
                let _ = live.on_step(at(*ms), (0.0, 0.0), Some(0.0), None);
            }
        };
        rest(live, &mut ms);
        for _ in 0..4 {
            let Instruction::Go { direction, .. } = live.instruction() else {
                panic!("{:?}", live.instruction());
            };
            for s in lap(truth, track, direction, 0.3, 100.0).unwrap() {
                ms += 10;
                let _ = live.on_step(
                    at(ms),
                    (s.rear_left_rev, s.rear_right_rev),
                    Some(s.steer_signal),
                    None,
                );
            }
            rest(live, &mut ms);
        }
        let out = live.on_command(at(ms), &cmd(w, w.encode_command(Command::Compute, 0, 2)));
        assert_eq!(counts(w, &out).cmd_reason, Reason::None);
        assert_eq!(live.phase(), Phase::Computed);
        ms
    }

    #[test]
    fn a_drive_against_the_bus_fixes_calibrates_without_a_track() {
        let mut c = config();
        let (live0, w0, _) = core(&c, ParamFile::default(), false);
        let mut live0 = live0;
        let out = live0.on_command(
            at(0),
            &cmd(&w0, w0.encode_command(Command::StartDrive, 0, 1)),
        );
        assert_eq!(
            counts(&w0, &out).cmd_reason,
            Reason::NotSupported,
            "no [calibration.fixes]"
        );
        c.calibration.fixes = Some(canodom_pipeline::config::FixSignals {
            message_index: c.signals.wheels.rear_left.message_index,
            first: c.signals.wheels.rear_left.handle,
            second: c.signals.wheels.rear_right.handle,
            geodetic: false,
        });
        let (mut live, w, stored) = core(&c, ParamFile::default(), false);
        let out = live.on_command(at(0), &cmd(&w, w.encode_command(Command::StartDrive, 0, 1)));
        assert_eq!(counts(&w, &out).cmd_reason, Reason::None);
        let start = Command::StartSession {
            track_radius_mm: 780,
            runs_per_direction: 1,
        };
        let out = live.on_command(at(1), &cmd(&w, w.encode_command(start, 0, 2)));
        assert_eq!(counts(&w, &out).cmd_reason, Reason::SessionActive);
        // 60 s at 0.2 m/s, weaving (radius down to 2 m); the right rear tyre
        // reads 0.1 % short. Fixes at 1 Hz of the true rear-axle centre.
        let p = live.vehicle(&live.current_values());
        let (b, dl, dr) = (
            p.rear_tread_m(),
            std::f64::consts::PI * p.wheel_diameter_m(Wheel::RearLeft),
            std::f64::consts::PI * p.wheel_diameter_m(Wheel::RearRight),
        );
        let (mut x, mut y, mut th) = (0.0f64, 0.0f64, 0.0f64);
        for k in 1..=6000u64 {
            let t = k as f64 * 0.01;
            let kappa = 0.5 * (std::f64::consts::TAU * t / 20.0).sin();
            let ds = 0.002;
            let (d_l, d_r) = (ds * (1.0 - 0.5 * kappa * b), ds * (1.0 + 0.5 * kappa * b));
            let mid = th + 0.5 * ds * kappa;
            x += ds * mid.cos();
            y += ds * mid.sin();
            th += ds * kappa;
            let _ = live.on_step(
                at(10 * k),
                (d_l / dl, d_r * (1.0 - 1e-3) / dr),
                Some(0.0),
                None,
            );
            if k % 100 == 0 {
                live.on_fix(at(10 * k), x, y, false);
            }
        }
        let out = live.on_command(
            at(60_010),
            &cmd(&w, w.encode_command(Command::Compute, 0, 3)),
        );
        assert_eq!(counts(&w, &out).cmd_reason, Reason::None);
        let out = live.on_command(
            at(60_020),
            &cmd(&w, w.encode_command(Command::Commit, 0, 4)),
        );
        assert_eq!(counts(&w, &out).cmd_reason, Reason::None);
        let file = stored.lock().unwrap().last().cloned().unwrap();
        let set = file.current.unwrap();
        assert_eq!(set.method, "drive");
        let ratio = set.values.rear_right_diameter_m
            / set.values.rear_left_diameter_m
            / (p.wheel_diameter_m(Wheel::RearRight) / p.wheel_diameter_m(Wheel::RearLeft));
        assert!((ratio - 1.0 / (1.0 - 1e-3)).abs() < 2e-4, "{ratio}");
        // The drive is over: a track session may start again.
        let out = live.on_command(at(60_030), &cmd(&w, w.encode_command(start, 0, 5)));
        assert_eq!(counts(&w, &out).cmd_reason, Reason::None);
    }

    #[test]
    fn commit_checks_bounds_and_uncertainty_then_persists_applies_and_reports() {
        let mut c = config();
        let nominal = *Pipeline::new(&c).unwrap().params();
        let truth = nominal
            .with_rear(
                nominal.rear_tread_m() * 1.033,
                nominal.wheel_diameter_m(Wheel::RearLeft),
                nominal.wheel_diameter_m(Wheel::RearRight) * 1.015,
            )
            .unwrap();
        let commit = |live: &mut LiveCalibration, w: &CalibWire, ms: u64| {
            live.on_command(at(ms), &cmd(w, w.encode_command(Command::Commit, 0, 3)))
        };
        // Bounds tighter than the result: refused, still computed.
        let wide = c.calibration.bounds;
        c.calibration.bounds.rear_tread_m.1 = nominal.rear_tread_m() * 1.01;
        let (mut live, w, stored) = core(&c, ParamFile::default(), false);
        let ms = computed_session(&mut live, &w, &truth);
        let out = commit(&mut live, &w, ms);
        assert_eq!(counts(&w, &out).cmd_reason, Reason::OutOfBounds);
        assert_eq!(live.phase(), Phase::Computed);
        assert!(stored.lock().unwrap().is_empty());
        // An uncertainty limit no estimate meets: refused.
        c.calibration.bounds = wide;
        c.calibration.max_tread_std_m = -1.0;
        let (mut live, w, stored) = core(&c, ParamFile::default(), false);
        let ms = computed_session(&mut live, &w, &truth);
        let out = commit(&mut live, &w, ms);
        assert_eq!(counts(&w, &out).cmd_reason, Reason::UncertaintyTooHigh);
        assert!(stored.lock().unwrap().is_empty());
        // Within both: stored, applied at standstill, reported, written back.
        c.calibration.max_tread_std_m = 1.0;
        c.calibration.max_ratio_std = 1.0;
        let (mut live, w, stored) = core(&c, ParamFile::default(), false);
        let ms = computed_session(&mut live, &w, &truth);
        let out = commit(&mut live, &w, ms);
        assert_eq!(counts(&w, &out).cmd_reason, Reason::None);
        assert_eq!(live.phase(), Phase::Idle);
        assert_eq!(stored.lock().unwrap().len(), 1);
        let applied = out.iter().find_map(|o| match o {
            Output::Apply(v, values) => Some((*v, *values)),
            _ => None,
        });
        let (version, values) = applied.expect("applied at standstill");
        assert_eq!(version, 1);
        assert!(
            (values.diameter_ratio() / 1.015 - 1.0).abs() < 1e-3,
            "{values:?}"
        );
        assert!(out.iter().any(|o| matches!(o, Output::Report(1, _))));
        assert_eq!(params_sent(&w, &out), vec![1; 4]);
    }

    #[test]
    fn a_rollback_that_cannot_be_stored_is_refused_whole() {
        let c = config();
        let (mut live, w, _) = core(&c, two_sets(), true);
        let out = live.on_command(at(0), &cmd(&w, w.encode_command(Command::Rollback, 0, 1)));
        assert_eq!(counts(&w, &out).cmd_reason, Reason::PersistFailed);
        assert_eq!(live.file().current.as_ref().unwrap().version, 2);
        assert!(params_sent(&w, &out).is_empty());
        assert!(!out.iter().any(|o| matches!(o, Output::Apply(..))));
    }

    #[test]
    fn request_params_sends_the_set_in_use_and_status_keeps_its_rate() {
        let c = config();
        let (mut live, w, _) = core(&c, two_sets(), false);
        let out = live.on_command(
            at(0),
            &cmd(&w, w.encode_command(Command::RequestParams, 0, 1)),
        );
        assert_eq!(params_sent(&w, &out), vec![2; 4]);
        // The answer comes first, then the pages it announces.
        let first_params = out
            .iter()
            .position(|o| matches!(o, Output::Send(f) if f.id() == w.params_id()));
        let answer = out.iter().position(|o| {
            matches!(o, Output::Send(f) if f.id() == w.status_id()
                && matches!(w.decode_status(f.data()), Ok((StatusPage::Counts(_), _))))
        });
        assert!(answer.unwrap() < first_params.unwrap(), "{out:?}");
        assert_eq!(live.writeback(), Writeback::Idle);
        let statuses = |live: &mut LiveCalibration, from: u64, to: u64| {
            (from..to)
                .step_by(50)
                .filter(|&ms| progress(&w, &live.tick(at(ms))).is_some())
                .count()
        };
        assert_eq!(statuses(&mut live, 50, 3050), 3);
        let start = Command::StartSession {
            track_radius_mm: 1000,
            runs_per_direction: 0,
        };
        let out = live.on_command(at(3050), &cmd(&w, w.encode_command(start, 0, 2)));
        assert_eq!(progress(&w, &out).unwrap().runs_total, 10);
        assert_eq!(statuses(&mut live, 3100, 4100), 10);
    }

    /// A file whose current set (version 1) holds the nominal rear values.
    fn calibrated(nominal: &VehicleParams) -> ParamFile {
        let steer = nominal.steering();
        let mut file = ParamFile::default();
        file.commit(
            ParamValues {
                rear_tread_m: nominal.rear_tread_m(),
                rear_left_diameter_m: nominal.wheel_diameter_m(Wheel::RearLeft),
                rear_right_diameter_m: nominal.wheel_diameter_m(Wheel::RearRight),
                steering_gain: steer.gain,
                steering_offset_rad: steer.offset_rad,
                yaw_rate_bias_radps: None,
                yaw_rate_scale: None,
            },
            "exact",
            1,
            10,
        );
        file
    }

    /// Drives one constant-command arc of `truth` then stands still 1.5 s.
    fn drive_arc(live: &mut LiveCalibration, truth: &VehicleParams, u: f64, ms: &mut u64) {
        use canodom_calib::synth::arc;
        for s in arc(truth, u, 3.0, 0.5, 100.0).unwrap() {
            *ms += 10;
            let _ = live.on_step(
                at(*ms),
                (s.rear_left_rev, s.rear_right_rev),
                Some(s.steer_signal),
                None,
            );
        }
        for _ in 0..150 {
            *ms += 10;
            let _ = live.on_step(at(*ms), (0.0, 0.0), Some(u), None);
        }
    }

    #[test]
    fn steering_needs_a_calibrated_set_and_three_commands() {
        let c = config();
        let nominal = *Pipeline::new(&c).unwrap().params();
        let (mut live, w, _) = core(&c, ParamFile::default(), false);
        let out = live.on_command(
            at(0),
            &cmd(&w, w.encode_command(Command::StartSteering, 0, 1)),
        );
        assert_eq!(counts(&w, &out).cmd_reason, Reason::NothingToCommit);
        let (mut live, w, stored) = core(&c, calibrated(&nominal), false);
        let out = live.on_command(
            at(0),
            &cmd(&w, w.encode_command(Command::StartSteering, 0, 1)),
        );
        assert_eq!(counts(&w, &out).cmd_reason, Reason::None);
        assert_eq!(progress(&w, &out).unwrap().state, State::Recording);
        let mut ms = 0;
        drive_arc(&mut live, &nominal, -10.0, &mut ms);
        drive_arc(&mut live, &nominal, 10.0, &mut ms);
        let p = progress(&w, &live.tick(at(ms))).unwrap();
        assert_eq!(p.run_index, 2);
        let out = live.on_command(at(ms), &cmd(&w, w.encode_command(Command::Compute, 0, 2)));
        assert_eq!(counts(&w, &out).cmd_reason, Reason::RunsIncomplete);
        // A rear session cannot start over it; abort drops it.
        let start = Command::StartSession {
            track_radius_mm: 1000,
            runs_per_direction: 1,
        };
        let out = live.on_command(at(ms), &cmd(&w, w.encode_command(start, 0, 3)));
        assert_eq!(counts(&w, &out).cmd_reason, Reason::SessionActive);
        let out = live.on_command(at(ms), &cmd(&w, w.encode_command(Command::Abort, 0, 4)));
        assert_eq!(counts(&w, &out).cmd_reason, Reason::None);
        let out = live.on_command(at(ms), &cmd(&w, w.encode_command(Command::Commit, 0, 5)));
        assert_eq!(counts(&w, &out).cmd_reason, Reason::NothingToCommit);
        assert!(stored.lock().unwrap().is_empty());
    }

    #[test]
    fn steering_arcs_fit_commit_and_write_back_the_true_map() {
        let c = config();
        let nominal = *Pipeline::new(&c).unwrap().params();
        let n = nominal.steering();
        let truth_gain = n.gain * 0.93;
        let truth_offset_rad = 0.8f64.to_radians();
        let truth = nominal
            .with_steering(SteeringMap {
                gain: truth_gain,
                offset_rad: truth_offset_rad,
            })
            .unwrap();
        let (mut live, w, stored) = core(&c, calibrated(&nominal), false);
        let _ = live.on_command(
            at(0),
            &cmd(&w, w.encode_command(Command::StartSteering, 0, 1)),
        );
        let mut ms = 0;
        for u in [-20.0, -8.0, 5.0, 18.0] {
            drive_arc(&mut live, &truth, u, &mut ms);
        }
        let out = live.on_command(at(ms), &cmd(&w, w.encode_command(Command::Compute, 0, 2)));
        assert_eq!(counts(&w, &out).cmd_reason, Reason::None);
        assert_eq!(progress(&w, &out).unwrap().state, State::Computed);
        let (wire_gain, wire_offset_rad) = status_pages(&w, &out)
            .find_map(|page| match page {
                StatusPage::ResultSteering {
                    steer_gain,
                    steer_offset_rad,
                    ..
                } => Some((steer_gain, steer_offset_rad)),
                _ => None,
            })
            .expect("steering result page");
        eprintln!(
            "wire steering gain {wire_gain:.4}, offset {:.3}°",
            wire_offset_rad.to_degrees()
        );
        assert!((wire_gain / 0.93 - 1.0).abs() < 0.01, "{wire_gain}");
        let out = live.on_command(at(ms), &cmd(&w, w.encode_command(Command::Commit, 0, 3)));
        assert_eq!(counts(&w, &out).cmd_reason, Reason::None);
        assert_eq!(counts(&w, &out).active_version, 2);
        let (version, values) = out
            .iter()
            .find_map(|o| match o {
                Output::Apply(v, values) => Some((*v, *values)),
                _ => None,
            })
            .expect("applied at standstill");
        assert_eq!(version, 2);
        eprintln!(
            "committed steering gain {:.5} (truth {truth_gain:.5}), offset {:.4}° (truth 0.8°)",
            values.steering_gain,
            values.steering_offset_rad.to_degrees()
        );
        assert!((values.steering_gain / truth_gain - 1.0).abs() < 0.01);
        assert!(
            (values.steering_offset_rad - truth_offset_rad)
                .abs()
                .to_degrees()
                < 0.05
        );
        assert!((values.rear_tread_m - nominal.rear_tread_m()).abs() < 1e-12);
        assert_eq!(params_sent(&w, &out), vec![2; 4]);
        assert_eq!(stored.lock().unwrap().len(), 1);
        assert_eq!(live.file().current.as_ref().unwrap().version, 2);
        // Its report, for version 2: the arcs, the fitted map, the one before.
        let report = out
            .iter()
            .find_map(|o| match o {
                Output::Report(2, r) => match r.as_ref() {
                    Report::Steering(s) => Some(s),
                    Report::Rear(_) => None,
                },
                _ => None,
            })
            .expect("steering report");
        assert_eq!(report.arcs.len(), 4);
        assert_eq!(report.calibrated.gain, values.steering_gain);
        assert_eq!(report.before.gain, n.gain);
        assert!(report.rms_rad < 1e-3, "{report:?}");
    }

    #[test]
    fn a_steering_fit_whose_arcs_disagree_is_refused_as_too_uncertain() {
        let c = config();
        let nominal = *Pipeline::new(&c).unwrap().params();
        let n = nominal.steering();
        let (mut live, w, stored) = core(&c, calibrated(&nominal), false);
        let _ = live.on_command(
            at(0),
            &cmd(&w, w.encode_command(Command::StartSteering, 0, 1)),
        );
        // Each arc driven by a map 2° off the last the other way (a sloppy
        // steering linkage): within the ±10° bounds, but no line fits them.
        let mut ms = 0;
        for (u, offset_deg) in [(-20.0, 2.0), (-8.0, -2.0), (5.0, 2.0), (18.0, -2.0)] {
            let truth = nominal
                .with_steering(SteeringMap {
                    gain: n.gain,
                    offset_rad: n.offset_rad + f64::to_radians(offset_deg),
                })
                .unwrap();
            drive_arc(&mut live, &truth, u, &mut ms);
        }
        let out = live.on_command(at(ms), &cmd(&w, w.encode_command(Command::Compute, 0, 2)));
        assert_eq!(counts(&w, &out).cmd_reason, Reason::None);
        let offset_std_rad = status_pages(&w, &out)
            .find_map(|page| match page {
                StatusPage::ResultExtra {
                    steer_offset_std_rad,
                    ..
                } => Some(steer_offset_std_rad),
                _ => None,
            })
            .expect("steering result page");
        assert!(
            offset_std_rad > c.calibration.max_steer_offset_std_rad,
            "offset std {:.3}°",
            offset_std_rad.to_degrees()
        );
        let out = live.on_command(at(ms), &cmd(&w, w.encode_command(Command::Commit, 0, 3)));
        assert_eq!(counts(&w, &out).cmd_reason, Reason::UncertaintyTooHigh);
        assert!(stored.lock().unwrap().is_empty(), "nothing stored");
        assert!(!out.iter().any(|o| matches!(o, Output::Apply(..))));
        assert_eq!(live.file().current.as_ref().unwrap().version, 1);
    }
}
