//! The live calibration over CAN: `CALIB_CMD` in, `CALIB_STATUS`,
//! `CALIB_PARAMS` out, `CALIB_ACK` back (issue 6).
//!
//! [`LiveCalibration`] is the wire side of `canodom_calib::calibrator`: it
//! checks and decodes commands, hands them to the [`Calibrator`] that owns
//! the whole calibration state, and turns its outputs into frames, applies,
//! reports, and the two slow effects it asks for, [`Output::Persist`] and
//! [`Output::Compute`], which the caller carries out away from the frame
//! path and reports back ([`LiveCalibration::on_persisted`],
//! [`LiveCalibration::on_computed`]). It keeps only what the wire needs:
//! the command counter, the answer sequence, the status schedule and the
//! write-back of `CALIB_PARAMS` with its retries. No async, no clock: time
//! comes in as bus timestamps.
//!
//! Checks of a command, in order: CRC-8 (`BAD_CHECKSUM`), a counter equal to
//! the previous command's (`BAD_COUNTER`: a duplicate frame), the arming code
//! (`BAD_ARMING_CODE`), the command code (`UNKNOWN_COMMAND`), then the
//! calibrator's refusals (session state, bounds, uncertainty, write-back in
//! progress, busy while a store or a computation is out). Every command,
//! carried out or refused, is answered on status page 1 (`LAST_CMD`,
//! `CMD_REASON`, `CMD_SEQ`): at once, or for COMMIT, ROLLBACK and COMPUTE
//! when the store or the computation is done.

use canodom_calib::calibrator::{
    Calibrator, CalibratorConfig, Command as CalibCommand, Committed, Job, JobOutcome,
    Output as CalibOutput,
};
use canodom_calib::session::{Instruction, Phase};

pub mod drift_watch;

use canodom_can::frame::CanFrame;
use canodom_can::time::Timestamp;
use canodom_fusion::{Pose, VehicleParams};
use canodom_params::persist::{ParamFile, ParamValues};
use canodom_pipeline::config::CalibrationConfig;
use canodom_protocol::calib_wire::{
    Ack, AckStatus, CalibWire, Command, Counts, DEFAULT_RUNS_PER_DIRECTION, GnssStatus,
    InstructionCode, ParamSet as WireSet, Progress, Reason, StartPoint, State, StatusPage,
    WireDirection, Writeback,
};
use canodom_report::committed::Report;
use canodom_report::report::CalibrationReport;
use canodom_report::steering_report::SteeringReport;
use drift_watch::{DriftReport, Judged, OnlineWatch, RefitJob};

/// Status period while a session is active, s (10 Hz).
const ACTIVE_STATUS_S: f64 = 0.1;
/// Status period otherwise, s.
const IDLE_STATUS_S: f64 = 1.0;

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
    /// Store this parameter file durably, off the frame path, then call
    /// [`LiveCalibration::on_persisted`].
    Persist(ParamFile),
    /// Run this calibration job off the frame path, then call
    /// [`LiveCalibration::on_computed`].
    Compute(Job),
    /// Run this refit of the online calibration off the frame path
    /// ([`canodom_offline::online::refit`]), then call
    /// [`LiveCalibration::on_refit`]; at most one is asked for at a time.
    Refit(Box<RefitJob>),
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
#[derive(Debug)]
pub struct LiveCalibration {
    wire: CalibWire,
    config: CalibrationConfig,
    calibrator: Calibrator,
    last_counter: Option<u8>,
    last_cmd: u8,
    cmd_reason: Reason,
    cmd_seq: u8,
    writeback: Option<WriteBack>,
    next_status_s: Option<f64>,
    status_counter: u8,
    params_counter: u8,
    online: OnlineWatch,
    /// The live GNSS source's state for `CALIB_STATUS` page 6 (`None`
    /// without `[gnss]`: the page is not sent).
    gnss: Option<GnssStatus>,
}

fn seconds(t: Timestamp) -> f64 {
    t.as_micros() as f64 * 1e-6
}

impl LiveCalibration {
    /// A live calibration for a vehicle with `nominal` parameters, whose
    /// parameter file currently holds `file` (its current set is in use).
    pub fn new(
        wire: CalibWire,
        config: CalibrationConfig,
        nominal: VehicleParams,
        file: ParamFile,
    ) -> Self {
        let calibrator = Calibrator::new(
            CalibratorConfig {
                standstill_speed_mps: config.standstill_speed_mps,
                standstill_time_s: config.standstill_time_s,
                bounds: config.bounds,
                max_tread_std_m: config.max_tread_std_m,
                max_ratio_std: config.max_ratio_std,
                max_steer_gain_std_rel: config.max_steer_gain_std_rel,
                max_steer_offset_std_rad: config.max_steer_offset_std_rad,
                max_history: config.max_history,
                fixes_available: config.fixes.is_some(),
                drive_gate: canodom_offline::drive::drive_gate(&config, nominal.rear_tread_m()),
                online_window_s: Some(config.drift.window_s),
            },
            nominal,
            file,
        );
        let online = OnlineWatch::new(config.drift);
        Self {
            wire,
            config,
            calibrator,
            last_counter: None,
            last_cmd: 0,
            cmd_reason: Reason::None,
            cmd_seq: 0,
            writeback: None,
            next_status_s: None,
            status_counter: 0,
            params_counter: 0,
            online,
            gnss: None,
        }
    }

    /// The live GNSS source's state, sent as `CALIB_STATUS` page 6 from the
    /// next status on (#46: connected, fixes per second, error estimate).
    pub fn set_gnss_status(&mut self, status: GnssStatus) {
        self.gnss = Some(status);
    }

    /// The front tyres' ratio a previous run's drift watch judged against
    /// (its state file): a front tyre changed while the daemon was down is
    /// then flagged as one changed while it ran. Whether it was taken (an
    /// implausible ratio from a damaged file is not).
    pub fn restore_front_baseline(
        &mut self,
        baseline: canodom_calib::front_ratio::FrontRatio,
    ) -> bool {
        self.online.restore_front_baseline(baseline)
    }

    /// What the drift watch knows now, the candidate as it awaits COMMIT.
    pub fn drift(&self) -> DriftReport {
        DriftReport {
            candidate: self.calibrator.drift_candidate().copied(),
            ..self.online.report().clone()
        }
    }

    /// The refit of `job` came back (`epoch`: `None` when it could not
    /// run): judged against the set in use, the candidate offered or
    /// withdrawn, and the status sent when a flag changed. The changes are
    /// the caller's to log (`None`: the ring was emptied since, not judged).
    pub fn on_refit(
        &mut self,
        t: Timestamp,
        job: &RefitJob,
        epoch: Option<&canodom_offline::online::Epoch>,
    ) -> (Vec<Output>, Option<Judged>) {
        let (generation, in_use) = (
            self.calibrator.online_generation(),
            self.calibrator.current_values(),
        );
        let Some((judged, candidate)) = self.online.judged(job, epoch, generation, &in_use) else {
            return (Vec::new(), None);
        };
        let before = self.calibrator.drift_candidate().copied();
        self.calibrator.set_drift_candidate(candidate);
        let out = if judged.changes.is_empty() && before.is_some() == candidate.is_some() {
            Vec::new()
        } else {
            self.status(seconds(t))
        };
        (out, Some(judged))
    }

    /// The parameter file as the daemon last stored it.
    pub fn file(&self) -> &ParamFile {
        self.calibrator.file()
    }

    /// The session's phase.
    pub fn phase(&self) -> Phase {
        self.calibrator.phase()
    }

    /// The write-back state.
    pub fn writeback(&self) -> Writeback {
        self.writeback.map_or(Writeback::Idle, |w| w.state)
    }

    /// Whether the vehicle has stood still (below the configured standstill
    /// speed for the configured time) at `t`, as the calibration judges it.
    pub fn is_standstill(&self, t: Timestamp) -> bool {
        self.calibrator.is_standstill(seconds(t))
    }

    /// The standstill judge, as the calibration keeps it.
    pub fn standstill(&self) -> canodom_calib::standstill::Standstill {
        self.calibrator.standstill()
    }

    /// Whether a store of the parameter file is out (else a job, if anything).
    pub fn is_storing(&self) -> bool {
        self.calibrator.is_storing()
    }

    /// A filter step: `rear_rev` wheel revolutions (left, right) since the
    /// previous step with the diameters in use, the steering signal, and the
    /// yaw rate the filter used (for a drive recorded against fixes); the
    /// front wheels not read ([`Self::on_step_with_front`]).
    pub fn on_step(
        &mut self,
        t: Timestamp,
        rear_rev: (f64, f64),
        steer_signal: Option<f64>,
        yaw_rate_radps: Option<f64>,
    ) -> Vec<Output> {
        self.on_step_with_front(t, rear_rev, None, steer_signal, yaw_rate_radps)
    }

    /// [`Self::on_step`] with the front wheels' revolutions (left, right),
    /// `None` when they were not fresh: the drift watch reads the front
    /// tyres' ratio from them.
    pub fn on_step_with_front(
        &mut self,
        t: Timestamp,
        rear_rev: (f64, f64),
        front_rev: Option<(f64, f64)>,
        steer_signal: Option<f64>,
        yaw_rate_radps: Option<f64>,
    ) -> Vec<Output> {
        let t_s = seconds(t);
        let out = self.calibrator.on_step_with_front(
            t_s,
            rear_rev,
            front_rev,
            steer_signal,
            yaw_rate_radps,
        );
        self.carry(t_s, out)
    }

    /// The filter's correction window closed at the last step with `outcome`
    /// (nothing when it is [`WindowOutcome::Open`]): a window the gate
    /// rejected is kept out of a drive's reckoning, as offline
    /// ([`canodom_offline::drive::gate_rejected`]).
    ///
    /// [`WindowOutcome::Open`]: canodom_fusion::ekf::WindowOutcome::Open
    pub fn on_window(&mut self, outcome: canodom_fusion::ekf::WindowOutcome) {
        use canodom_fusion::ekf::WindowOutcome;
        if outcome != WindowOutcome::Open {
            self.calibrator
                .on_window(canodom_offline::drive::gate_rejected(outcome));
        }
    }

    /// A position fix from the bus: a local x and y in metres, or (`geodetic`)
    /// latitude and longitude in degrees, with the 1σ per axis its source
    /// states (gpsd, ROS 2; none from the bus). Recorded while a drive is.
    ///
    /// Outside a guided calibration the fix also feeds the online
    /// calibration: the refit it makes due, if any ([`Output::Refit`]).
    pub fn on_fix(
        &mut self,
        t: Timestamp,
        first: f64,
        second: f64,
        geodetic: bool,
        sigma_m: Option<f64>,
    ) -> Vec<Output> {
        let t_s = seconds(t);
        self.calibrator
            .on_fix(t_s, first, second, geodetic, sigma_m);
        let cal = &self.calibrator;
        self.online
            .due(t_s, |window_s| cal.online_window(window_s))
            .map(|job| Output::Refit(Box::new(job)))
            .into_iter()
            .collect()
    }

    /// The input path refused or faulted a wheel frame (`code`: the
    /// decoder's fault code): a run recording now is rejected at its end.
    pub fn on_fault(&mut self, t: Timestamp, code: u8) {
        self.calibrator.on_fault(seconds(t), code);
    }

    /// Periodic work: status frames, write-back timeouts, deferred applies.
    pub fn tick(&mut self, t: Timestamp) -> Vec<Output> {
        let t_s = seconds(t);
        let applies = self.calibrator.tick(t_s);
        let mut out = self.carry(t_s, applies);
        if self.config.auto_commit
            && let Some(candidate) = self.calibrator.drift_candidate()
        {
            let values = canodom_calib::drift::bounded_step(
                &self.calibrator.current_values(),
                candidate,
                &self.config.drift.judge,
            );
            let pending = self.writeback() == Writeback::Pending;
            let before = self.calibrator.current_values();
            let stored = self.calibrator.auto_commit(t_s, values, pending);
            if !stored.is_empty() {
                // Nobody answers an automatic commit: the log is where an
                // operator finds what changed, and why.
                tracing::warn!(
                    rear_ratio_from = before.diameter_ratio(),
                    rear_ratio_to = values.diameter_ratio(),
                    tread_m_from = before.rear_tread_m,
                    tread_m_to = values.rear_tread_m,
                    "drift: committing the learnt set at this standstill by itself \
                     ([calibration] auto_commit = true), each parameter moved at most \
                     {} of its tolerances",
                    canodom_calib::drift::AUTO_STEP_TOLERANCES
                );
            }
            out.extend(self.carry(t_s, stored));
        }
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
        let Ok((
            Ack {
                version,
                status,
                set_crc,
            },
            _,
        )) = self.wire.decode_ack(frame.data())
        else {
            return Vec::new();
        };
        // The acknowledgement must echo the set's CRC as well as its
        // version: one for another set under a re-used version is not ours.
        match self.writeback {
            Some(wb)
                if wb.state == Writeback::Pending
                    && wb.set.version == version
                    && self.wire.set_crc(&wb.set).ok() == Some(set_crc) =>
            {
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
        match self.judge(frame) {
            Err(reason) => self.answer(t_s, reason),
            Ok(None) => match self.request_params() {
                Some(frames) => {
                    let mut out = self.answer(t_s, Reason::None);
                    out.extend(frames);
                    out
                }
                None => self.answer(t_s, Reason::OutOfBounds),
            },
            Ok(Some(command)) => {
                let writeback_pending = self.writeback() == Writeback::Pending;
                let out = self.calibrator.on_command(t_s, command, writeback_pending);
                self.carry(t_s, out)
            }
        }
    }

    /// The store of the last [`Output::Persist`] finished (`Err`: its cause,
    /// for the log): the command that asked for it is answered.
    pub fn on_persisted(&mut self, t: Timestamp, stored: &Result<(), String>) -> Vec<Output> {
        if let Err(cause) = stored {
            tracing::warn!(%cause, "calibrated parameters not stored; command refused, nothing changed");
        }
        let t_s = seconds(t);
        let out = self.calibrator.on_persisted(t_s, stored.is_ok());
        self.carry(t_s, out)
    }

    /// The job of the last [`Output::Compute`] finished: the command that
    /// asked for it is answered.
    pub fn on_computed(&mut self, t: Timestamp, outcome: JobOutcome) -> Vec<Output> {
        if let JobOutcome::Drive(Err(e)) | JobOutcome::Rear(Err(e)) = &outcome {
            tracing::warn!(cause = %e, "calibration failed");
        }
        if let JobOutcome::Drive(Ok(result)) = &outcome {
            for r in &result.0.refused {
                tracing::warn!(
                    parameter = r.parameter,
                    reason = %r.reason,
                    "drive calibration: not committed, the previous value kept"
                );
            }
        }
        let t_s = seconds(t);
        let out = self.calibrator.on_computed(outcome);
        self.carry(t_s, out)
    }

    /// The wire checks of a command and its meaning: `Ok(None)` for
    /// REQUEST_PARAMS, which the wire side answers itself.
    fn judge(&mut self, frame: &CanFrame) -> Result<Option<CalibCommand>, Reason> {
        let Ok(cmd) = self.wire.decode_command(frame.data()) else {
            self.last_cmd = 0;
            return Err(Reason::BadChecksum);
        };
        self.last_cmd = cmd.cmd_raw;
        if !cmd.checksum_ok {
            return Err(Reason::BadChecksum);
        }
        let repeated = self.last_counter == Some(cmd.counter);
        self.last_counter = Some(cmd.counter);
        if repeated {
            return Err(Reason::BadCounter);
        }
        if self
            .config
            .arming_code
            .is_some_and(|code| code != cmd.arming_code)
        {
            return Err(Reason::BadArmingCode);
        }
        let Some(command) = cmd.command else {
            return Err(Reason::UnknownCommand);
        };
        Ok(Some(match command {
            Command::StartSession {
                track_radius_mm,
                runs_per_direction,
            } => CalibCommand::StartSession {
                radius_m: f64::from(track_radius_mm) * 1e-3,
                runs_per_direction: if runs_per_direction == 0 {
                    DEFAULT_RUNS_PER_DIRECTION
                } else {
                    runs_per_direction
                },
            },
            Command::StartRun => CalibCommand::StartRun,
            Command::EndRun => CalibCommand::EndRun,
            Command::EndPose {
                dx_mm,
                dy_mm,
                dtheta_decideg,
            } => CalibCommand::EndPose(Pose {
                x_m: f64::from(dx_mm) * 1e-3,
                y_m: f64::from(dy_mm) * 1e-3,
                heading_rad: (f64::from(dtheta_decideg) * 0.1).to_radians(),
            }),
            Command::Abort => CalibCommand::Abort,
            Command::Compute => CalibCommand::Compute,
            Command::Commit => CalibCommand::Commit,
            Command::Rollback => CalibCommand::Rollback,
            Command::StartSteering => CalibCommand::StartSteering,
            Command::StartDrive => CalibCommand::StartDrive,
            Command::RequestParams => return Ok(None),
        }))
    }

    /// Answers the last command: status page 1 with the reason and the next
    /// `CMD_SEQ`.
    fn answer(&mut self, t_s: f64, reason: Reason) -> Vec<Output> {
        self.cmd_reason = reason;
        self.cmd_seq = (self.cmd_seq + 1) % 8;
        self.status(t_s)
    }

    /// REQUEST_PARAMS: the set in use, once, not as a write-back; `None`
    /// when it does not fit the wire's ranges.
    fn request_params(&mut self) -> Option<Vec<Output>> {
        let set = self.wire_set();
        let pages = self.wire.encode_params(&set, self.params_counter).ok()?;
        self.params_counter = self.params_counter.wrapping_add(1);
        Some(Self::frames(self.wire.params_id(), &pages))
    }

    /// Turns the calibrator's outputs into the daemon's, in order. The
    /// answer's status pages take the answer's place but show the state
    /// after everything the command caused (the write-back it started too).
    fn carry(&mut self, t_s: f64, outputs: Vec<CalibOutput>) -> Vec<Output> {
        let mut out = Vec::new();
        let mut answer = None;
        for o in outputs {
            match o {
                CalibOutput::Answer(result) => {
                    answer = Some((
                        out.len(),
                        result.err().map_or(Reason::None, Reason::of_refused),
                    ));
                }
                CalibOutput::InstructionChanged => out.extend(self.status(t_s)),
                CalibOutput::Persist(file) => out.push(Output::Persist(file)),
                CalibOutput::Compute(job) => out.push(Output::Compute(job)),
                CalibOutput::Apply { version, values } => out.push(Output::Apply(version, values)),
                CalibOutput::Adopted { .. } => {
                    let set = self.wire_set();
                    out.extend(self.send_params(t_s, set, 1));
                }
                CalibOutput::Report { version, committed } => {
                    let report = match *committed {
                        Committed::Rear {
                            result,
                            track,
                            runs,
                        } => Report::Rear(CalibrationReport::build(&result, track, &runs, &[])),
                        Committed::Steering {
                            fit,
                            before,
                            gain_std_rel,
                            offset_std_rad,
                        } => Report::Steering(SteeringReport::build(
                            &fit,
                            before,
                            gain_std_rel,
                            offset_std_rad,
                        )),
                    };
                    out.push(Output::Report(version, Box::new(report)));
                }
            }
        }
        if let Some((at, reason)) = answer {
            let pages = self.answer(t_s, reason);
            out.splice(at..at, pages);
        }
        out
    }

    /// The steering map on the wire, relative to the nominal map: the
    /// "measured angle" of `CALIB_PARAMS` is the nominal map's angle (the
    /// raw signal's unit is the vehicle's, so an absolute gain may be 0.017
    /// for degrees and would not fit STEER_GAIN's range around 1).
    fn wire_steering(&self, v: &ParamValues) -> (f64, f64) {
        let n = self.calibrator.nominal().steering();
        let gain = v.steering_gain / n.gain;
        (gain, v.steering_offset_rad - gain * n.offset_rad)
    }

    fn wire_set(&self) -> WireSet {
        let v = self.calibrator.current_values();
        let (steer_gain, steer_offset_rad) = self.wire_steering(&v);
        WireSet {
            version: self.file().current.as_ref().map_or(0, |s| s.version),
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
        let next_version = self.file().last_version.checked_add(1).unwrap_or(1);
        if let Some(r) = self.calibrator.result() {
            let (steer_gain, steer_offset_rad) = self.wire_steering(&self.calibrator.values_of(r));
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
                    version: next_version,
                },
            ]);
        }
        if let Some(fit) = self.calibrator.steering().and_then(|s| s.fit()) {
            let (steer_gain, steer_offset_rad) =
                self.wire_steering(&self.calibrator.steering_values(fit));
            let (gain_std_rel, offset_std_rad) = self.calibrator.steering_uncertainty(fit);
            pages.extend([
                StatusPage::ResultSteering {
                    steer_gain,
                    steer_gain_std: gain_std_rel,
                    steer_offset_rad,
                },
                StatusPage::ResultExtra {
                    steer_offset_std_rad: offset_std_rad,
                    version: next_version,
                },
            ]);
        }
        pages
    }

    /// The status pages now; schedules the next.
    fn status(&mut self, t_s: f64) -> Vec<Output> {
        let cal = &self.calibrator;
        let phase = cal.phase();
        self.next_status_s = Some(
            t_s + if cal.is_active() {
                ACTIVE_STATUS_S
            } else {
                IDLE_STATUS_S
            },
        );
        let instruction = cal.instruction();
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
            Instruction::Stop { run, runs } => (run, runs, cal.run_direction()),
            _ => (0, 0, None),
        };
        let wb = self.writeback;
        // The steering calibration has no state of its own on the wire: it
        // shows as RECORDING while arcs are collected (RUN_INDEX = arcs
        // estimated so far, RUN_DISTANCE = the current arc's length) and as
        // COMPUTED once a fit awaits commit (RESULT_STEERING pages).
        let (state, run, run_distance_m) = match cal.steering() {
            Some(st) if st.fit().is_some() => (State::Computed, 0, 0.0),
            Some(st) => (
                State::Recording,
                u8::try_from(st.arcs().len()).unwrap_or(u8::MAX),
                st.current_m(),
            ),
            None => (
                State::of(phase),
                run,
                if phase == Phase::Recording {
                    cal.run_distance_m()
                } else {
                    0.0
                },
            ),
        };
        let (accepted, rejected) = (cal.accepted(), cal.rejected());
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
                standstill: cal.is_standstill(t_s),
                writeback_attempts: wb.map_or(0, |w| w.attempts),
                drift: self.online.watch().any(),
                drift_candidate: cal.drift_candidate().is_some(),
            }),
            StatusPage::Counts(Counts {
                cw_accepted: accepted[0],
                cw_rejected: rejected[0],
                ccw_accepted: accepted[1],
                ccw_rejected: rejected[1],
                reject_reason: cal
                    .reject_reason()
                    .map_or(Reason::None, Reason::of_rejection),
                last_cmd: self.last_cmd,
                cmd_reason: self.cmd_reason,
                active_version: self.file().current.as_ref().map_or(0, |s| s.version),
                cmd_seq: self.cmd_seq,
            }),
        ];
        pages.extend(self.gnss.map(StatusPage::Gnss));
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
mod tests;
