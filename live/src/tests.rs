use super::*;
use canodom_calib::session::Instruction;
use canodom_calib::track::Track;
use canodom_fusion::Wheel;
use canodom_fusion::{SteeringMap, VehicleParams};
use canodom_pipeline::config::Config;
use canodom_pipeline::pipeline::Pipeline;
use std::sync::{Arc, Mutex};

type Stored = Arc<Mutex<Vec<ParamFile>>>;

fn config() -> Config {
    let p = std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../daemon/examples/rc_car.toml"
    ));
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
        yaw_rate_bias_sigma_radps: None,
    }
}

/// A live calibration whose stores and jobs are carried out at once,
/// as the calibration task does them off the frame path: what a test
/// sees is what the bus sees once they are done.
struct Live {
    inner: LiveCalibration,
    stored: Stored,
    fail: bool,
}

impl std::ops::Deref for Live {
    type Target = LiveCalibration;
    fn deref(&self) -> &LiveCalibration {
        &self.inner
    }
}

impl Live {
    fn settle(&mut self, t: Timestamp, mut out: Vec<Output>) -> Vec<Output> {
        let mut done = Vec::new();
        while !out.is_empty() {
            let mut next = Vec::new();
            for o in out {
                match o {
                    Output::Persist(file) => {
                        let stored = if self.fail {
                            Err("disk full".to_owned())
                        } else {
                            self.stored.lock().unwrap().push(file);
                            Ok(())
                        };
                        next.extend(self.inner.on_persisted(t, &stored));
                    }
                    Output::Compute(job) => next.extend(self.inner.on_computed(t, job.run())),
                    other => done.push(other),
                }
            }
            out = next;
        }
        done
    }
    fn on_command(&mut self, t: Timestamp, frame: &CanFrame) -> Vec<Output> {
        let out = self.inner.on_command(t, frame);
        self.settle(t, out)
    }
    fn on_step(
        &mut self,
        t: Timestamp,
        rear_rev: (f64, f64),
        steer_signal: Option<f64>,
        yaw_rate_radps: Option<f64>,
    ) -> Vec<Output> {
        let out = self
            .inner
            .on_step(t, rear_rev, steer_signal, yaw_rate_radps);
        self.settle(t, out)
    }
    fn tick(&mut self, t: Timestamp) -> Vec<Output> {
        let out = self.inner.tick(t);
        self.settle(t, out)
    }
    fn on_ack(&mut self, t: Timestamp, frame: &CanFrame) -> Vec<Output> {
        self.inner.on_ack(t, frame)
    }
    fn on_fault(&mut self, t: Timestamp, code: u8) {
        self.inner.on_fault(t, code);
    }
    fn on_fix(&mut self, t: Timestamp, first: f64, second: f64, geodetic: bool) {
        self.inner.on_fix(t, first, second, geodetic, None);
    }
    fn instruction(&self) -> Instruction {
        self.inner.calibrator.instruction()
    }
    fn current_values(&self) -> ParamValues {
        self.inner.calibrator.current_values()
    }
    fn vehicle(&self, v: &ParamValues) -> VehicleParams {
        let nominal = *self.inner.calibrator.nominal();
        nominal
            .with_rear(
                v.rear_tread_m,
                v.rear_left_diameter_m,
                v.rear_right_diameter_m,
            )
            .and_then(|p| p.with_steering(v.steering_map()))
            .unwrap_or(nominal)
    }
}

/// A live calibration over `file`; `fail` makes every store fail.
fn core(c: &Config, file: ParamFile, fail: bool) -> (Live, CalibWire, Stored) {
    let stored: Stored = Arc::default();
    let nominal = *Pipeline::new(c).unwrap().params();
    let live = LiveCalibration::new(
        CalibWire::new(c.output.base_id).unwrap(),
        c.calibration.clone(),
        nominal,
        file,
    );
    (
        Live {
            inner: live,
            stored: Arc::clone(&stored),
            fail,
        },
        CalibWire::new(c.output.base_id).unwrap(),
        stored,
    )
}

fn at(ms: u64) -> Timestamp {
    Timestamp::from_micros(1_000_000_000 + ms * 1000)
}

fn cmd(w: &CalibWire, data: [u8; 8]) -> CanFrame {
    CalibWire::frame(w.cmd_id(), &data).unwrap()
}

/// The CALIB_STATUS pages among `out`, decoded, in order.
fn status_pages<'a>(w: &'a CalibWire, out: &'a [Output]) -> impl Iterator<Item = StatusPage> + 'a {
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

/// SET_CRC of the `CALIB_PARAMS` set among the outputs.
fn sent_set_crc(w: &CalibWire, out: &[Output]) -> u16 {
    out.iter()
        .find_map(|o| match o {
            Output::Send(f) if f.id() == w.params_id() => {
                match w.decode_params(f.data()).ok()?.0.data {
                    canodom_protocol::calib_wire::ParamsData::TreadCrc { set_crc, .. } => {
                        Some(set_crc)
                    }
                    _ => None,
                }
            }
            _ => None,
        })
        .expect("CALIB_PARAMS page 0")
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
    // A rollback writes set 1's values back under a new version (3), so
    // no acknowledgement of the old version 1 can end its write-back.
    assert_eq!(counts(&w, &out).active_version, 3);
    assert_eq!(params_sent(&w, &out), vec![3; 4]);
    // No wheel data yet: standing still, applied at once.
    assert!(
        out.iter()
            .any(|o| matches!(o, Output::Apply(3, v) if *v == values(0.30)))
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
        3
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
    assert_eq!(live.file().current.as_ref().unwrap().version, 3);
}

#[test]
fn ack_of_the_version_ends_the_write_back_and_moving_defers_the_apply() {
    let c = config();
    let (mut live, w, _) = core(&c, two_sets(), false);
    // Moving: the set waits for the standstill.
    let _ = live.on_step(at(0), (0.1, 0.1), Some(0.0), None);
    let out = live.on_command(at(5), &cmd(&w, w.encode_command(Command::Rollback, 0, 1)));
    assert!(!out.iter().any(|o| matches!(o, Output::Apply(..))));
    let set_crc = sent_set_crc(&w, &out);
    let ack = |version, set_crc| {
        let status = AckStatus::Stored;
        CalibWire::frame(
            w.ack_id(),
            &w.encode_ack(
                Ack {
                    version,
                    status,
                    set_crc,
                },
                0,
            ),
        )
        .unwrap()
    };
    let version = live.file().current.as_ref().unwrap().version;
    // Another version, or this version with another set's CRC: not ours.
    assert!(live.on_ack(at(10), &ack(version + 1, set_crc)).is_empty());
    assert!(live.on_ack(at(15), &ack(version, set_crc ^ 1)).is_empty());
    assert_eq!(live.writeback(), Writeback::Pending);
    let out = live.on_ack(at(20), &ack(version, set_crc));
    assert_eq!(progress(&w, &out).unwrap().writeback, Writeback::Acked);
    let _ = live.on_step(at(100), (0.0, 0.0), Some(0.0), None);
    let still_ms = u64::try_from((c.calibration.standstill_time_s * 1000.0) as i64).unwrap();
    let early = live.on_step(at(100 + still_ms - 10), (0.0, 0.0), Some(0.0), None);
    assert!(!early.iter().any(|o| matches!(o, Output::Apply(..))));
    let late = live.on_step(at(100 + still_ms), (0.0, 0.0), Some(0.0), None);
    assert!(
        late.iter()
            .any(|o| matches!(o, Output::Apply(v, _) if *v == version))
    );
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
fn computed_session(live: &mut Live, w: &CalibWire, truth: &VehicleParams) -> u64 {
    use canodom_calib::synth::lap;
    let start = Command::StartSession {
        track_radius_mm: 780,
        runs_per_direction: 2,
    };
    let _ = live.on_command(at(0), &cmd(w, w.encode_command(start, 0, 1)));
    let track = Track::new(0.78).unwrap();
    let mut ms = 0;
    let rest = |live: &mut Live, ms: &mut u64| {
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
    let commit = |live: &mut Live, w: &CalibWire, ms: u64| {
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
    let statuses = |live: &mut Live, from: u64, to: u64| {
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
    let mut file = ParamFile::default();
    file.commit(ParamValues::nominal(nominal), "exact", 1, 10);
    file
}

/// Drives one constant-command arc of `truth` then stands still 1.5 s.
fn drive_arc(live: &mut Live, truth: &VehicleParams, u: f64, ms: &mut u64) {
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

#[test]
fn the_gnss_page_goes_out_only_with_a_source_and_tells_its_state() {
    use canodom_protocol::calib_wire::{GnssSourceKind, GnssStatus};
    let c = config();
    let (mut live, w, _) = core(&c, two_sets(), false);
    let gnss_of = |out: &[Output]| {
        status_pages(&w, out).find_map(|p| match p {
            StatusPage::Gnss(g) => Some(g),
            _ => None,
        })
    };
    // Without `[gnss]` no status carries page 6.
    let mut sent = 0;
    for ms in (0..2100).step_by(50) {
        let out = live.tick(at(ms));
        sent += usize::from(progress(&w, &out).is_some());
        assert_eq!(gnss_of(&out), None);
    }
    assert!(sent >= 2);
    let state = GnssStatus {
        source: GnssSourceKind::Nmea,
        connected: true,
        fixes_per_s: 1.0,
        error_95_m: Some(7.3),
        forwarded: 612,
        refused: 4,
        reconnects: 1,
    };
    live.inner.set_gnss_status(state);
    let with_page: Vec<GnssStatus> = (2100..4200)
        .step_by(50)
        .filter_map(|ms| gnss_of(&live.tick(at(ms))))
        .collect();
    // Every status from then on carries it (once a second when idle).
    assert_eq!(with_page.len(), 2, "{with_page:?}");
    let got = with_page[0];
    assert_eq!(
        (
            got.source,
            got.connected,
            got.forwarded,
            got.refused,
            got.reconnects
        ),
        (GnssSourceKind::Nmea, true, 612, 4, 1)
    );
    assert!((got.fixes_per_s - 1.0).abs() < 1e-9);
    assert!(got.error_95_m.is_some_and(|e| (e - 7.3).abs() < 1e-9));
}
