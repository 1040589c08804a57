//! A whole guided calibration over the in-process bus (issue 6): a simulated
//! vehicle whose true rear parameters differ from the nominal ones drives
//! the runs `CALIB_STATUS` asks for; one run is cut short and rejected; the
//! committed `CALIB_PARAMS` carry the effective tread and the true diameter
//! ratio; an ECU emulator acknowledges the write-back, and without it the
//! daemon retries and reports FAILED; rollback; refused commands.
//!
//! The runtime's clock is paused: the bus stamps frames with tokio's virtual
//! time, so minutes of driving take seconds.

use crate::util::{rc_car, tmp_dir};
use canodom::server::{InProcessDaemon, Observers};
use canodom_can::bus::{BusEvent, FrameSink, FrameSource, InProcessTx};
use canodom_can::frame::FrameId;
use canodom_dbc::Database;
use canodom_fusion::sim::{Direction, Plan, simulate};
use canodom_fusion::{VehicleParams, Wheel};
use canodom_params::persist::{ParamFile, ParamValues, store};
use canodom_pipeline::pipeline::Pipeline;
use canodom_protocol::calib_wire::{
    CalibWire, Command, Counts, ParamSet, ParamsAssembler, Progress, Reason, State, StatusPage,
    WireDirection, Writeback,
};
use canodom_protocol::own_dbc::{OwnFrame, dbc_for_base};
use canodom_sim::vehicle::{SampleEncoder, sim_config};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

const ARMING: u8 = 0x42;
const RHO_M: f64 = 0.78;
const RUNS: u8 = 5;

#[derive(Default)]
struct Seen {
    progress: Vec<Progress>,
    counts: Vec<Counts>,
    sets: Vec<ParamSet>,
    /// ODOM_QUALITY.PARAM_VERSION of the latest pose.
    pose_param_version: Option<u16>,
}

struct Driver {
    wire: CalibWire,
    tx: InProcessTx,
    counter: u8,
    seen: Arc<Mutex<Seen>>,
}

impl Driver {
    async fn raw(&self, id: FrameId, data: [u8; 8]) {
        self.tx
            .send(&CalibWire::frame(id, &data).unwrap())
            .await
            .unwrap();
    }

    /// Sends a command and returns the page-1 answer to it.
    async fn command(&mut self, cmd: Command) -> Counts {
        self.counter = (self.counter + 1) % 16;
        let before = self.seen.lock().unwrap().counts.len();
        let data = self.wire.encode_command(cmd, ARMING, self.counter);
        self.raw(self.wire.cmd_id(), data).await;
        self.answer(before).await.expect("an answer")
    }

    /// The first page 1 after `before` whose CMD_SEQ moved, within 0.3 s.
    async fn answer(&self, before: usize) -> Option<Counts> {
        let seq = self.seen.lock().unwrap().counts.last().map(|c| c.cmd_seq);
        for _ in 0..30 {
            tokio::time::sleep(Duration::from_millis(10)).await;
            let s = self.seen.lock().unwrap();
            if let Some(c) = s.counts[before..].iter().find(|c| Some(c.cmd_seq) != seq) {
                return Some(*c);
            }
        }
        None
    }

    fn progress(&self) -> Progress {
        *self.seen.lock().unwrap().progress.last().unwrap()
    }

    fn counts(&self) -> Counts {
        *self.seen.lock().unwrap().counts.last().unwrap()
    }

    /// Waits (bounded) until the latest progress satisfies `ok`.
    async fn until(&self, what: &str, ok: impl Fn(&Progress) -> bool) -> Progress {
        for _ in 0..600 {
            tokio::time::sleep(Duration::from_millis(50)).await;
            if let Some(p) = self.seen.lock().unwrap().progress.last()
                && ok(p)
            {
                return *p;
            }
        }
        panic!("waited 30 s for {what}; last {:?}", self.progress());
    }
}

/// Sends one run's samples 10 ms apart (virtual time), with counters carried
/// over from the previous run, rest before and after.
struct Vehicle {
    encoder: SampleEncoder,
    carry: [u64; 4],
    tick_mask: u64,
}

impl Vehicle {
    async fn drive(
        &mut self,
        tx: &InProcessTx,
        samples: &[canodom_fusion::sim::Sample],
        rest_s: f64,
    ) {
        let mut frames = Vec::new();
        let rest = (rest_s * 100.0) as usize;
        let first = samples[0];
        let last = samples[samples.len() - 1];
        let seq = std::iter::repeat_n(&first, rest)
            .chain(samples)
            .chain(std::iter::repeat_n(&last, rest));
        for s in seq {
            let mut s = *s;
            for (i, w) in Wheel::ALL.iter().enumerate() {
                s.ticks[*w] = (s.ticks[*w] + self.carry[i]) & self.tick_mask;
            }
            frames.clear();
            self.encoder.encode(&s, &mut frames);
            for f in &frames {
                tx.send(f).await.unwrap();
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        for (i, w) in Wheel::ALL.iter().enumerate() {
            self.carry[i] = (last.ticks[*w] + self.carry[i]) & self.tick_mask;
        }
    }
}

#[tokio::test(start_paused = true)]
#[allow(clippy::too_many_lines)]
async fn a_driven_session_commits_the_true_parameters_and_writes_them_back() {
    let dir = tmp_dir("calib-session");
    let mut config = rc_car();
    config.calibration.param_file = dir.join("params.toml");
    config.calibration.arming_code = Some(ARMING);
    let nominal: VehicleParams = *Pipeline::new(&config).unwrap().params();
    let (b_nom, dl_nom, dr_nom) = (
        nominal.rear_tread_m(),
        nominal.wheel_diameter_m(Wheel::RearLeft),
        nominal.wheel_diameter_m(Wheel::RearRight),
    );
    // A stored set (the nominal values) gives rollback a target.
    let mut file = ParamFile::default();
    let steer = nominal.steering();
    file.commit(
        ParamValues {
            rear_tread_m: b_nom,
            rear_left_diameter_m: dl_nom,
            rear_right_diameter_m: dr_nom,
            steering_gain: steer.gain,
            steering_offset_rad: steer.offset_rad,
            yaw_rate_bias_radps: None,
            yaw_rate_scale: None,
            yaw_rate_bias_sigma_radps: None,
        },
        "nominal",
        1,
        10,
    );
    store(&config.calibration.param_file, &file).unwrap();
    let config = Arc::new(config);

    // True vehicle: tread 1/30 wider, right rear diameter +1.5 %.
    let (b_true, dl_true, dr_true) = (b_nom * 31.0 / 30.0, dl_nom, dr_nom * 1.015);
    let truth = nominal.with_rear(b_true, dl_true, dr_true).unwrap();
    let k_mean = 0.5 * (dl_nom / dl_true + dr_nom / dr_true);
    let b_eff = k_mean * b_true;
    let ratio_true = dr_true / dl_true;

    // The session is recorded (`run --record`): its calibration channel
    // carries the session's phase.
    let recording = tmp_dir("session-record").join("session.mcap");
    let (tap, outputs) = crate::util::recording_to(&recording, &config);
    let observers = Observers {
        tap: Some(tap),
        ..Observers::default()
    };
    let daemon = InProcessDaemon::spawn(Arc::clone(&config), 65536, observers);
    let bus = daemon.bus.clone();
    let wire = CalibWire::new(config.output.base_id).unwrap();
    let (status_id, params_id) = (wire.status_id(), wire.params_id());
    let quality_id = OwnFrame::OdomQuality.id(config.output.base_id);
    let own_db = Database::parse(&dbc_for_base(config.output.base_id), "canodom.dbc").unwrap();
    let param_version = own_db.signal("ODOM_QUALITY.PARAM_VERSION").unwrap();

    // Listener and ECU emulator: collects status and parameter sets, and
    // acknowledges every complete set while `ecu_on`.
    let seen = Arc::new(Mutex::new(Seen::default()));
    let ecu_on = Arc::new(AtomicBool::new(true));
    let (mut rx, ecu_tx) = bus.open().unwrap();
    let listener = {
        let (seen, ecu_on) = (Arc::clone(&seen), Arc::clone(&ecu_on));
        let wire = CalibWire::new(config.output.base_id).unwrap();
        tokio::spawn(async move {
            let mut assembler = ParamsAssembler::default();
            let mut ack_counter = 0u8;
            while let Ok(ev) = rx.recv().await {
                let BusEvent::Frame(r) = ev else { continue };
                let id = r.frame.id();
                if id == quality_id {
                    seen.lock().unwrap().pose_param_version = param_version
                        .raw(r.frame.data())
                        .and_then(|v| u16::try_from(v).ok());
                } else if id == status_id {
                    match wire.decode_status(r.frame.data()) {
                        Ok((StatusPage::Progress(p), _)) => seen.lock().unwrap().progress.push(p),
                        Ok((StatusPage::Counts(c), _)) => seen.lock().unwrap().counts.push(c),
                        _ => {}
                    }
                } else if id == params_id
                    && let Ok(page) = wire.decode_params(r.frame.data())
                    && let Some(Ok(set)) = assembler.push(&wire, page.0)
                {
                    assembler = ParamsAssembler::default();
                    seen.lock().unwrap().sets.push(set);
                    if ecu_on.load(Ordering::Relaxed) {
                        let f = crate::util::stored_ack(&wire, &set, ack_counter);
                        ack_counter = ack_counter.wrapping_add(1);
                        let _ = ecu_tx.send(&f).await;
                    }
                }
            }
        })
    };
    let (_, tx) = bus.open().unwrap();
    let mut driver = Driver {
        wire,
        tx: tx.clone(),
        counter: 0,
        seen: Arc::clone(&seen),
    };
    // The daemon needs a frame to start its bus clock: the vehicle at rest.
    let mut sim = sim_config(&config, truth);
    sim.speed_mps = 0.3;
    sim.wheel_output.random_counter_start = false;
    let tick_mask = (1u64 << config.signals.tick_bits) - 1;
    let mut vehicle = Vehicle {
        encoder: SampleEncoder::new(&config),
        carry: [0; 4],
        tick_mask,
    };
    let rest = simulate(&sim, &Plan::track(RHO_M, Direction::Ccw, 1).unwrap(), 0).unwrap();
    vehicle.drive(&tx, &rest.samples[..1], 0.5).await;
    driver
        .until("an idle status", |p| p.state == State::Idle)
        .await;

    // Refusals, in Idle.
    let seq = driver.counts().cmd_seq;
    let wrong_id = FrameId::Standard(0x123);
    driver
        .raw(
            wrong_id,
            driver.wire.encode_command(Command::Commit, ARMING, 9),
        )
        .await;
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert_eq!(
        driver.counts().cmd_seq,
        seq,
        "a command on a wrong id is ignored"
    );
    let mut bad_crc = driver.wire.encode_command(Command::Abort, ARMING, 10);
    bad_crc[7] ^= 0x5a;
    let before = seen.lock().unwrap().counts.len();
    driver.raw(driver.wire.cmd_id(), bad_crc).await;
    assert_eq!(
        driver.answer(before).await.unwrap().cmd_reason,
        Reason::BadChecksum
    );
    let before = seen.lock().unwrap().counts.len();
    let wrong_code = driver.wire.encode_command(Command::Compute, ARMING ^ 1, 11);
    driver.raw(driver.wire.cmd_id(), wrong_code).await;
    assert_eq!(
        driver.answer(before).await.unwrap().cmd_reason,
        Reason::BadArmingCode
    );
    assert_eq!(
        driver.command(Command::Commit).await.cmd_reason,
        Reason::NothingToCommit
    );
    assert_eq!(driver.progress().state, State::Idle);

    // The session, driven as instructed.
    let start = Command::StartSession {
        track_radius_mm: (RHO_M * 1000.0) as u16,
        runs_per_direction: RUNS,
    };
    assert_eq!(driver.command(start).await.cmd_reason, Reason::None);
    let mut cut_short_done = false;
    for attempt in 0..(2 * u64::from(RUNS) + 3) {
        let p = driver
            .until("the next instruction", |p| {
                matches!(p.state, State::Positioning | State::Ready)
            })
            .await;
        if p.state == State::Ready {
            break;
        }
        let direction = match p.direction {
            WireDirection::Cw => Direction::Cw,
            WireDirection::Ccw => Direction::Ccw,
            other @ WireDirection::None => panic!("no direction to drive: {other:?}"),
        };
        let run = simulate(
            &sim,
            &Plan::track(RHO_M, direction, 1).unwrap(),
            100 + attempt,
        )
        .unwrap();
        if !cut_short_done && p.run_index == 3 {
            // Run 3 stops at 40 % of the lap and the driver ends it by hand.
            let cut = run.samples.len() * 2 / 5;
            vehicle.drive(&tx, &run.samples[..cut], 1.5).await;
            assert_eq!(driver.progress().state, State::Recording);
            assert_eq!(
                driver.command(Command::EndRun).await.cmd_reason,
                Reason::None
            );
            let c = driver.counts();
            println!("cut-short run rejected: {:?}", c.reject_reason);
            assert_eq!(c.reject_reason, Reason::LengthOff);
            assert_eq!(c.cw_rejected + c.ccw_rejected, 1);
            let again = driver.progress();
            assert_eq!((again.state, again.run_index), (State::Positioning, 3));
            cut_short_done = true;
            continue;
        }
        vehicle.drive(&tx, &run.samples, 1.5).await;
    }
    assert!(cut_short_done);
    let c = driver.counts();
    assert_eq!((c.cw_accepted, c.ccw_accepted), (RUNS, RUNS), "{c:?}");
    assert_eq!(driver.progress().state, State::Ready);

    assert_eq!(
        driver.command(Command::Compute).await.cmd_reason,
        Reason::None
    );
    assert_eq!(driver.progress().state, State::Computed);
    let sets_before = seen.lock().unwrap().sets.len();
    let answer = driver.command(Command::Commit).await;
    assert_eq!(answer.cmd_reason, Reason::None);
    assert_eq!(answer.active_version, 2);
    let acked = driver
        .until("ACKED", |p| p.writeback == Writeback::Acked)
        .await;
    assert_eq!(acked.writeback_attempts, 1);
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert_eq!(seen.lock().unwrap().pose_param_version, Some(2));
    let set = seen.lock().unwrap().sets[sets_before];
    assert_eq!(set.version, 2);
    let tread_err = set.rear_tread_m / b_eff - 1.0;
    let ratio_err = set.diameter_ratio / ratio_true - 1.0;
    println!(
        "committed tread {:.5} m (effective {b_eff:.5}, error {:+.3} %), ratio {:.5} (true {ratio_true:.5}, error {:+.4} %)",
        set.rear_tread_m,
        100.0 * tread_err,
        set.diameter_ratio,
        100.0 * ratio_err
    );
    assert!(tread_err.abs() < 0.005, "tread error {tread_err}");
    assert!(ratio_err.abs() < 0.001, "ratio error {ratio_err}");
    // The committed session's report, beside the parameter file.
    let report = dir.join("params-reports").join("2");
    for _ in 0..200 {
        if report.join("calibration.json").exists() {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(report.join("calibration.svg").exists());
    assert!(report.join("calibration.json").exists());

    // With a calibrated set in use the steering fit (§10) starts over the
    // bus and shows as RECORDING; ABORT drops it and nothing is committed.
    let answer = driver.command(Command::StartSteering).await;
    assert_eq!(answer.cmd_reason, Reason::None);
    assert_eq!(driver.progress().state, State::Recording);
    let answer = driver.command(Command::Abort).await;
    assert_eq!(
        (answer.cmd_reason, answer.active_version),
        (Reason::None, 2)
    );
    assert_eq!(driver.progress().state, State::Idle);

    // Rollback with the ECU silent: the previous set is re-applied and
    // re-sent, retried, then the write-back fails with the set kept.
    ecu_on.store(false, Ordering::Relaxed);
    let sets_before = seen.lock().unwrap().sets.len();
    let answer = driver.command(Command::Rollback).await;
    assert_eq!(answer.cmd_reason, Reason::None);
    // The previous set's values, re-issued as a new version (#33).
    assert_eq!(answer.active_version, 3);
    let failed = driver
        .until("FAILED", |p| p.writeback == Writeback::Failed)
        .await;
    let retries = config.calibration.writeback_retries;
    assert_eq!(u32::from(failed.writeback_attempts), 1 + retries);
    let resent: Vec<u16> = seen.lock().unwrap().sets[sets_before..]
        .iter()
        .map(|s| s.version)
        .collect();
    assert_eq!(resent, vec![3; 1 + retries as usize]);
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert_eq!(
        seen.lock().unwrap().sets.len(),
        sets_before + 1 + retries as usize
    );
    assert_eq!(driver.counts().active_version, 3);
    // The odometry runs on the rolled-back set: its poses say so.
    assert_eq!(seen.lock().unwrap().pose_param_version, Some(3));

    let summary = daemon.stop().await.unwrap();
    assert!(summary.stats.steps > 0);
    listener.abort();

    outputs.join().unwrap();
    let bytes = std::fs::read(&recording).unwrap();
    let mut phases: Vec<String> = Vec::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        if m.channel.topic == "/canodom/calibration" {
            // The last field, a CDR string: length, text, NUL.
            let text = &m.data[..m.data.len() - 1];
            let start = text
                .iter()
                .rposition(|b| !(b.is_ascii_lowercase() || *b == b'_'))
                .unwrap()
                + 1;
            let phase = String::from_utf8(text[start..].to_vec()).unwrap();
            if phases.last() != Some(&phase) {
                phases.push(phase);
            }
        }
    }
    // The phases in the order the session went through them.
    let at = |p: &str| {
        phases
            .iter()
            .position(|q| q == p)
            .unwrap_or_else(|| panic!("{p} not in {phases:?}"))
    };
    assert_eq!(phases[0], "idle", "{phases:?}");
    assert!(at("positioning") < at("recording"), "{phases:?}");
    assert!(at("recording") < at("computed"), "{phases:?}");
}
