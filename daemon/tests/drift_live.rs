//! The drift watch in the running daemon (#46 item 3) on the in-process
//! bus: the simulated RC car drives a random course with position fixes on
//! the bus (`[calibration.fixes]`) and no guided session. With its right
//! rear tyre 1 % larger than the set in use (a tyre changed since the
//! calibration), the daemon's refits flag the rear wheels' ratio: DRIFT and
//! DRIFT_CANDIDATE rise on CALIB_STATUS, the warning names the parameter,
//! and the state file's `drift` section lists it with the learnt candidate;
//! COMMIT then stores that candidate as the next version. The drive is
//! recorded (`run --record`): the recording's calibration channel carries
//! the watch, the flag only from the refit that raised it. With the tyres
//! as the set says, nothing is flagged. With `[calibration] auto_commit =
//! true` and no operator, the candidate is committed by itself at the
//! standstill, bounded per step, and written back to the ECU.
//!
//! The runtime's clock is paused (the bus stamps frames with tokio's
//! virtual time); the watch refits every 10 s of fixes over the last 20 s.

use crate::util::{Logs, tmp_dir};
use canodom::server::{InProcessDaemon, Observers};
use canodom::state_file::{StateFileOptions, load};
use canodom_can::bus::{BusEvent, FrameSink, FrameSource};
use canodom_export::cdr::CdrReader;
use canodom_fusion::sim::{Plan, simulate};
use canodom_pipeline::config::Config;
use canodom_pipeline::pipeline::Pipeline;
use canodom_protocol::calib_wire::{CalibWire, Command, ParamSet, ParamsAssembler, StatusPage};
use canodom_sim::vehicle::sim_config;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// rc_car.dbc with a GNSS message: the rear-axle centre in a local frame, mm.
/// What one drive showed.
struct Outcome {
    /// (DRIFT, DRIFT_CANDIDATE) of every progress page seen.
    progress: Vec<(bool, bool)>,
    logs: String,
    state: canodom::state_file::SavedState,
    /// The parameter file after the drive (and a COMMIT, if sent).
    file: Option<canodom_params::persist::ParamFile>,
    /// Every complete `CALIB_PARAMS` set written back on the bus.
    written_back: Vec<ParamSet>,
    /// The true right/left rear diameter ratio.
    true_ratio: f64,
    /// The configuration the daemon ran with.
    config: Arc<Config>,
    /// The drift watch of every calibration message recorded.
    recorded: Vec<RecordedDrift>,
}

/// The drift fields of a recorded `canodom_msgs/msg/Calibration`.
#[derive(Debug, Clone, PartialEq)]
struct RecordedDrift {
    refits: u64,
    drift: bool,
    candidate: bool,
    flagged: Vec<String>,
    /// (parameter, learnt, σ, in use, flagged).
    readings: Vec<(String, f64, f64, f64, bool)>,
}

/// The drift fields of a calibration message, as its schema lists them.
fn recorded_drift(data: &[u8]) -> RecordedDrift {
    let mut r = CdrReader::new(data);
    let whole = (|| {
        // version, the fixed flag, wheelbase, treads, four diameters.
        r.u16()?;
        r.u8()?;
        for _ in 0..7 {
            r.f64()?;
        }
        let refits = r.u64()?;
        let drift = r.u8()? == 1;
        let candidate = r.u8()? == 1;
        r.f64()?;
        let flagged = r.strings()?;
        let readings = (0..r.u32()?)
            .map(|_| Some((r.string()?, r.f64()?, r.f64()?, r.f64()?, r.u8()? == 1)))
            .collect::<Option<_>>()?;
        Some(RecordedDrift {
            refits,
            drift,
            candidate,
            flagged,
            readings,
        })
    })();
    whole.expect("a calibration message with the drift fields")
}

/// The RC car's configuration in `dir` (fixes on the bus, the watch's
/// short periods) and a random drive of it with its right rear tyre
/// `right_scale` times the set's; the true right/left ratio.
fn car_and_drive(
    dir: &std::path::Path,
    right_scale: f64,
) -> (Config, canodom_fusion::sim::Run, f64) {
    let config = crate::util::rc_car_with_fixes(
        dir,
        "[calibration.drift]\nevery_s = 10.0\nwindow_s = 20.0\n",
    );
    let nominal = *Pipeline::new(&config).unwrap().params();
    let mut d = nominal.wheel_diameters_m();
    d.rear_right *= right_scale;
    let truth = nominal.with_diameters(d).unwrap();
    let run = simulate(
        &sim_config(&config, truth),
        &Plan::random_drive(7, 60.0, 0.8).unwrap(),
        7,
    )
    .unwrap();
    (config, run, d.rear_right / d.rear_left)
}

/// What the listener on the bus collects: (DRIFT, DRIFT_CANDIDATE) of every
/// progress page, and every complete parameter set written back.
type Heard = (Arc<Mutex<Vec<(bool, bool)>>>, Arc<Mutex<Vec<ParamSet>>>);

/// Listens on `rx` for status pages and written-back sets, and answers each
/// set on `ecu_tx` as the ECU that stored it would.
fn listen_and_acknowledge(
    mut rx: canodom_can::bus::InProcessRx,
    ecu_tx: canodom_can::bus::InProcessTx,
    base_id: canodom_protocol::own_dbc::BaseId,
) -> Heard {
    let progress = Arc::new(Mutex::new(Vec::new()));
    let written_back = Arc::new(Mutex::new(Vec::new()));
    let (seen, sets) = (Arc::clone(&progress), Arc::clone(&written_back));
    let wire = CalibWire::new(base_id).unwrap();
    let (status_id, params_id) = (wire.status_id(), wire.params_id());
    tokio::spawn(async move {
        let mut assembler = ParamsAssembler::default();
        let mut ack_counter = 0u8;
        while let Ok(ev) = rx.recv().await {
            let BusEvent::Frame(r) = ev else { continue };
            let id = r.frame.id();
            if id == status_id
                && let Ok((StatusPage::Progress(p), _)) = wire.decode_status(r.frame.data())
            {
                seen.lock().unwrap().push((p.drift, p.drift_candidate));
            } else if id == params_id
                && let Ok(page) = wire.decode_params(r.frame.data())
                && let Some(Ok(set)) = assembler.push(&wire, page.0)
            {
                assembler = ParamsAssembler::default();
                sets.lock().unwrap().push(set);
                let ack = crate::util::stored_ack(&wire, &set, ack_counter);
                ack_counter = ack_counter.wrapping_add(1);
                let _ = ecu_tx.send(&ack).await;
            }
        }
    });
    (progress, written_back)
}

/// Who commits the drift watch's candidate.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Committer {
    /// The operator sends COMMIT at the standstill after the drive.
    Operator,
    /// Nobody: `[calibration] auto_commit = true`.
    Auto,
}

/// Drives the RC car with its right rear tyre `right_scale` times the
/// set's, fixes at 5 Hz, then stands still (and the operator sends COMMIT,
/// if it is the committer); the state file is written every `state_every`
/// (and when the watch's flags change). An ECU on the bus acknowledges
/// every set written back.
async fn drive(
    name: &str,
    right_scale: f64,
    state_every: Duration,
    committer: Committer,
) -> Outcome {
    let dir = tmp_dir(name);
    let (mut config, run, true_ratio) = car_and_drive(&dir, right_scale);
    config.calibration.auto_commit = committer == Committer::Auto;
    let config = Arc::new(config);
    let state_path = dir.join("state.json");
    let recording = dir.join("drive.mcap");
    let (tap, outputs) = crate::util::recording_to(&recording, &config);
    let observers = Observers {
        state_file: Some(StateFileOptions {
            path: state_path.clone(),
            every: state_every,
        }),
        tap: Some(tap),
        ..Observers::default()
    };
    let (logs, _guard) = Logs::capture();
    let daemon = InProcessDaemon::spawn(Arc::clone(&config), 1 << 16, observers);
    let (rx, tx) = daemon.bus.open().unwrap();
    let wire = CalibWire::new(config.output.base_id).unwrap();
    let (progress, written_back) =
        listen_and_acknowledge(rx, daemon.bus.open().unwrap().1, config.output.base_id);
    tokio::time::sleep(Duration::from_millis(20)).await;
    let mut encoder = crate::util::send_drive_with_fixes(&tx, &config, &run, 20).await;
    // The last refit on the blocking pool (real time), and a standstill.
    let last = run.samples.last().unwrap();
    let mut still = Vec::new();
    for _ in 0..300 {
        still.clear();
        let mut s = *last;
        s.t_s += 0.01;
        encoder.encode(&s, &mut still);
        for f in &still {
            tx.send(f).await.unwrap();
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
        std::thread::sleep(Duration::from_millis(2));
    }
    // The state before the COMMIT (which takes the candidate).
    let state = load(&state_path).unwrap();
    if committer == Committer::Operator {
        let data = wire.encode_command(
            Command::Commit,
            config.calibration.arming_code.unwrap_or(0),
            1,
        );
        tx.send(&CalibWire::frame(wire.cmd_id(), &data).unwrap())
            .await
            .unwrap();
    }
    for _ in 0..20 {
        tokio::time::sleep(Duration::from_millis(50)).await;
        std::thread::sleep(Duration::from_millis(20));
    }
    daemon.stop().await.unwrap();
    outputs.join().unwrap();
    let bytes = std::fs::read(&recording).unwrap();
    let recorded = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(Result::unwrap)
        .filter(|m| m.channel.topic == "/canodom/calibration")
        .map(|m| recorded_drift(&m.data))
        .collect();
    let file =
        canodom_params::persist::load(&dir.join("params.toml"), &config.calibration.bounds).ok();
    let progress = progress.lock().unwrap().clone();
    let written_back = written_back.lock().unwrap().clone();
    Outcome {
        progress,
        logs: logs.take(),
        state,
        file,
        written_back,
        true_ratio,
        config,
        recorded,
    }
}

#[tokio::test(start_paused = true)]
async fn a_changed_tyre_is_flagged_on_the_bus_in_the_log_and_the_state_file_and_committed() {
    // The state file's period is longer than the drive: what it holds was
    // written when the flag rose (or the candidate changed).
    let o = Box::pin(drive(
        "drift-live-tyre",
        1.01,
        Duration::from_secs(3600),
        Committer::Operator,
    ))
    .await;
    let flags: Vec<&str> = o
        .logs
        .lines()
        .filter(|l| l.contains("drift: rear_ratio flagged: learnt "))
        .collect();
    println!("{flags:?}");
    assert!(
        flags.len() == 1 && flags[0].contains("WARN") && flags[0].contains("in use 1.000000"),
        "{}",
        o.logs
    );
    assert!(
        o.progress.iter().any(|&(d, c)| d && c),
        "DRIFT and DRIFT_CANDIDATE on CALIB_STATUS: {:?}",
        o.progress
    );
    assert!(!o.progress[0].0, "not flagged before the first refit");
    let drift = o.state.drift.expect("a drift section in the state file");
    assert!(
        drift.flagged.contains(&"rear_ratio".to_owned()),
        "{drift:?}"
    );
    let ratio = drift
        .learnt
        .iter()
        .find(|r| r.parameter == "rear_ratio")
        .unwrap();
    assert!(
        ratio.flagged && (ratio.learnt - o.true_ratio).abs() < 3.0 * ratio.sigma + 1e-3,
        "{ratio:?} against {}",
        o.true_ratio
    );
    let candidate = drift.candidate.expect("the learnt set offered");
    let learnt = candidate.rear_right_diameter_m / candidate.rear_left_diameter_m;
    assert!((learnt - o.true_ratio).abs() < 2e-3, "{learnt}");
    // COMMIT stored the candidate as the first version, by the drift watch.
    let set = o
        .file
        .and_then(|f| f.current)
        .expect("COMMIT stored the candidate");
    assert_eq!((set.version, set.method.as_str()), (1, "drift"));
    assert_eq!(set.values, candidate);
    assert!(
        o.written_back.iter().any(|w| w.version == 1),
        "the committed set written back: {:?}",
        o.written_back
    );

    // The recording: no drift before the refit that raised the flag, then
    // the flagged ratio with what that refit learnt and the candidate.
    let first = o
        .recorded
        .iter()
        .position(|d| d.drift)
        .expect("a recorded flag");
    assert!(
        o.recorded[..first]
            .iter()
            .all(|d| !d.candidate && d.flagged.is_empty()),
        "{:?}",
        &o.recorded[..first]
    );
    assert_eq!(o.recorded[0].refits, 0, "{:?}", o.recorded[0]);
    // (The larger tyre moves the mean diameter too: speed_scale may be
    // flagged beside the ratio.)
    let flag = &o.recorded[first];
    assert!(
        flag.candidate && flag.flagged.contains(&"rear_ratio".to_owned()),
        "{flag:?}"
    );
    let (_, learnt, sigma, in_use, flagged) = flag
        .readings
        .iter()
        .find(|r| r.0 == "rear_ratio")
        .expect("the ratio's reading")
        .clone();
    assert!(
        flagged && in_use == 1.0 && (learnt - o.true_ratio).abs() < 3.0 * sigma + 1e-3,
        "{flag:?} against {}",
        o.true_ratio
    );
}

#[tokio::test(start_paused = true)]
async fn a_car_that_agrees_with_its_set_is_not_flagged() {
    let o = Box::pin(drive(
        "drift-live-steady",
        1.0,
        Duration::from_secs(1),
        Committer::Operator,
    ))
    .await;
    assert!(!o.logs.contains("flagged"), "{}", o.logs);
    assert!(!o.progress.is_empty() && o.progress.iter().all(|&(d, c)| !d && !c));
    let drift = o.state.drift.expect("refits made: a drift section");
    assert!(drift.refits >= 3 && drift.flagged.is_empty(), "{drift:?}");
    assert!(drift.learnt.iter().any(|r| r.parameter == "rear_ratio"));
    // The recording carries the refits, and never a flag.
    assert!(
        o.recorded.iter().all(|d| !d.drift && d.flagged.is_empty()),
        "{:?}",
        o.recorded.iter().find(|d| d.drift)
    );
    let last = o.recorded.last().expect("calibration messages recorded");
    assert!(
        last.refits >= 3 && last.readings.iter().any(|r| r.0 == "rear_ratio" && !r.4),
        "{last:?}"
    );
    assert_eq!(drift.candidate, None);
    assert!(
        o.file.and_then(|f| f.current).is_none() && o.written_back.is_empty(),
        "COMMIT with nothing to commit stores nothing"
    );
}

#[tokio::test(start_paused = true)]
async fn with_auto_commit_a_changed_tyre_is_committed_at_the_standstill_a_bounded_step_at_a_time() {
    let o = Box::pin(drive(
        "drift-live-auto",
        1.01,
        Duration::from_secs(3600),
        Committer::Auto,
    ))
    .await;
    let file = o.file.expect("the parameter file");
    let current = file.current.clone().expect("an automatic commit");
    println!(
        "auto commits: {:?}; written back: {:?}",
        file.history
            .iter()
            .chain([&current])
            .map(|s| (
                s.version,
                s.method.as_str(),
                s.values.rear_right_diameter_m / s.values.rear_left_diameter_m
            ))
            .collect::<Vec<_>>(),
        o.written_back
            .iter()
            .map(|w| (w.version, w.diameter_ratio))
            .collect::<Vec<_>>()
    );
    // Every set stored was the drift watch's own, each at most two
    // tolerances (0.2 % speed scale each) from the one before, starting
    // from the nominal set in use.
    let config = &o.config;
    let nominal = *Pipeline::new(config).unwrap().params();
    let mut before = (
        nominal.wheel_diameters_m().rear_left,
        nominal.wheel_diameters_m().rear_right,
    );
    let step = canodom_calib::drift::AUTO_STEP_TOLERANCES
        * config
            .calibration
            .drift
            .judge
            .tolerance(canodom_calib::drift::Param::SpeedScale);
    for set in file.history.iter().chain([&current]) {
        assert_eq!(set.method, "drift-auto", "{set:?}");
        let v = &set.values;
        let moved = [
            v.rear_left_diameter_m / before.0 - 1.0,
            v.rear_right_diameter_m / before.1 - 1.0,
        ];
        assert!(
            moved.iter().all(|m| m.abs() <= step + 1e-12),
            "one automatic commit moved a rear diameter by {moved:?}, more than {step}"
        );
        before = (v.rear_left_diameter_m, v.rear_right_diameter_m);
    }
    // The ratio moved toward the tyres' (1 % apart), and the step bound held
    // it from getting there in one commit.
    let ratio = current.values.rear_right_diameter_m / current.values.rear_left_diameter_m;
    assert!(
        ratio > 1.0 + 0.5 * step && ratio <= o.true_ratio + 2e-3,
        "ratio after the automatic commits {ratio}, the tyres' {}",
        o.true_ratio
    );
    // Each commit was written back to the ECU, as an operator's COMMIT is.
    assert!(
        o.written_back
            .iter()
            .any(|w| w.version == current.version && (w.diameter_ratio - ratio).abs() < 1e-4),
        "{:?} against version {}",
        o.written_back,
        current.version
    );
    // The flag was raised on the bus before the commit took the candidate,
    // and the log says that the daemon committed by itself, and what.
    assert!(o.progress.iter().any(|&(d, c)| d && c), "{:?}", o.progress);
    let said: Vec<&str> = o
        .logs
        .lines()
        .filter(|l| l.contains("committing the learnt set at this standstill by itself"))
        .collect();
    assert!(
        said.len() == file.history.len() + 1
            && said
                .iter()
                .all(|l| l.contains("WARN") && l.contains("rear_ratio_to")),
        "{}",
        o.logs
    );
    assert!(
        o.logs.contains("calibrated parameters applied"),
        "{}",
        o.logs
    );
}
