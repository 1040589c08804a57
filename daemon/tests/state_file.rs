//! `run --state-file` on the in-process bus (issue #30 item 5): the file is
//! written while the daemon runs, so a daemon that dies leaves one at most
//! `--state-every-s` old; learnt values are taken back only onto the
//! parameter set they were learnt on, and dropped with a warning naming
//! both sets otherwise; a set applied while running (a rollback over
//! `CALIB_CMD`, the same path as a commit) resets what was learnt on the
//! parameters it changes, and the file follows the new set.
//!
//! The runtime's clock is paused: the bus stamps frames with tokio's
//! virtual time, so the periods are exact and seconds of driving are quick.

use crate::util::{Logs, rc_car, tmp_dir};
use canodom::server::{InProcessDaemon, Observers, Summary};
use canodom::state_file::{FORMAT_VERSION, SavedState, StateFileOptions, load};
use canodom_can::bus::{FrameSink, InProcessTx};
use canodom_fusion::ekf::{EkfConfig, Learnt, LearntPair};
use canodom_params::persist::{ParamFile, ParamValues, store};
use canodom_pipeline::config::Config;
use canodom_pipeline::pipeline::Pipeline;
use canodom_protocol::calib_wire::{CalibWire, Command};
use canodom_sim::drive::simulator;
use canodom_sim::vehicle::{PathKind, SampleEncoder};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

/// The rc car with its parameter file in `dir`.
fn config_in(dir: &Path) -> Config {
    let mut c = rc_car();
    c.calibration.param_file = dir.join("params.toml");
    let _ = std::fs::remove_file(&c.calibration.param_file);
    c
}

fn options(path: &Path, every_s: f64) -> Observers {
    Observers {
        state_file: Some(StateFileOptions {
            path: path.to_owned(),
            every: Duration::from_secs_f64(every_s),
        }),
        ..Observers::default()
    }
}

/// Values no filter learns from nothing: a restore is told from priors.
fn learnt() -> Learnt {
    Learnt {
        steer_offset_rad: 0.4f64.to_radians(),
        steer_offset_sigma_rad: 0.05f64.to_radians(),
        front_scale: 1.004,
        front_scale_sigma: 3e-4,
        yaw_bias: Some(LearntPair {
            yaw_bias_radps: -0.3f64.to_radians(),
            yaw_bias_sigma_radps: 0.01f64.to_radians(),
            rear_ratio_err: 6e-4,
            rear_ratio_sigma: 1e-4,
            tread_err: 0.03,
            tread_sigma: 2e-3,
        }),
        wheel_fault: None,
    }
}

/// The same learnt values, each within an ulp: serde_json reads floats to
/// within one (no `float_roundtrip`).
fn same_learnt(a: &Learnt, b: &Learnt) -> bool {
    let close = |x: f64, y: f64| (x - y).abs() <= 1e-15 * x.abs().max(y.abs());
    let pair = |p: &LearntPair| {
        [
            p.yaw_bias_radps,
            p.yaw_bias_sigma_radps,
            p.rear_ratio_err,
            p.rear_ratio_sigma,
            p.tread_err,
            p.tread_sigma,
        ]
    };
    let top = |l: &Learnt| {
        [
            l.steer_offset_rad,
            l.steer_offset_sigma_rad,
            l.front_scale,
            l.front_scale_sigma,
        ]
    };
    let pairs_close = match (&a.yaw_bias, &b.yaw_bias) {
        (None, None) => true,
        (Some(p), Some(q)) => pair(p).iter().zip(pair(q)).all(|(x, y)| close(*x, y)),
        _ => false,
    };
    pairs_close && top(a).iter().zip(top(b)).all(|(x, y)| close(*x, y))
}

/// Sends `seconds` of a standing car (the drive's first sample, repeated)
/// 10 ms apart.
async fn stand(
    tx: &InProcessTx,
    enc: &mut SampleEncoder,
    first: &canodom_fusion::sim::Sample,
    seconds: f64,
) {
    let mut frames = Vec::new();
    for _ in 0..(seconds * 100.0) as usize {
        frames.clear();
        enc.encode(first, &mut frames);
        for f in &frames {
            tx.send(f).await.unwrap();
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

/// Runs a daemon with `observers` and no frames, and stops it.
async fn start_and_stop(config: &Arc<Config>, observers: Observers) -> Summary {
    let daemon = InProcessDaemon::spawn(Arc::clone(config), 1024, observers);
    tokio::time::sleep(Duration::from_millis(50)).await;
    daemon.stop().await.unwrap()
}

/// A daemon driving a figure eight dies (its runtime dropped: no shutdown,
/// no final write) at a moment unrelated to its 2 s period. The file it
/// leaves holds the state of at most 2 s before, and a complete file was
/// there at every instant of the drive.
#[test]
fn a_daemon_that_dies_leaves_a_state_at_most_one_period_old() {
    const EVERY_S: f64 = 2.0;
    let dir = tmp_dir("state-dies");
    let path = dir.join("state.json");
    let _ = std::fs::remove_file(&path);
    let config = Arc::new(config_in(&dir));
    let nominal = Pipeline::new(&config).unwrap().param_identity();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()
        .unwrap();
    let mut ages = Vec::new();
    let (first_s, last_sent_s) = rt.block_on(async {
        let daemon = InProcessDaemon::spawn(Arc::clone(&config), 1 << 16, options(&path, EVERY_S));
        let (_rx, tx) = daemon.bus.open().unwrap();
        tokio::time::sleep(Duration::from_millis(50)).await;
        let mut sim = simulator(&config, PathKind::FigureEight, None, 3, false).unwrap();
        let mut enc = SampleEncoder::new(&config);
        let mut frames = Vec::new();
        let mut last_sent_s = 0.0;
        let mut first_s = None;
        while let Some(sample) = sim.try_next().unwrap() {
            // The saved pose counts from the first frame.
            let first_s = *first_s.get_or_insert(sample.t_s);
            if sample.t_s > 9.37 {
                break;
            }
            frames.clear();
            enc.encode(&sample, &mut frames);
            for f in &frames {
                tx.send(f).await.unwrap();
            }
            last_sent_s = sample.t_s;
            tokio::time::sleep(Duration::from_millis(10)).await;
            // What a power cut now would leave.
            if sample.t_s - first_s > EVERY_S + 0.1 {
                let saved = load(&path).unwrap();
                ages.push(sample.t_s - first_s - saved.pose.unwrap().t_s);
            }
        }
        // Dropping the handle does not stop the daemon: it runs until its
        // runtime is dropped below, as a process killed or cut from power.
        drop(daemon);
        (first_s.unwrap(), last_sent_s)
    });
    drop(rt);
    let saved = load(&path).unwrap();
    let age_s = last_sent_s - first_s - saved.pose.unwrap().t_s;
    let worst = ages.iter().copied().fold(0.0, f64::max);
    println!(
        "state file at the kill {age_s:.3} s old, worst while driving {worst:.3} s (period {EVERY_S} s)"
    );
    // The period, and the frames of one sample interval (10 ms) the write
    // may be taken before (the step of a frame sent at the tick).
    assert!(age_s <= EVERY_S + 0.011, "{age_s}");
    assert!(worst <= EVERY_S + 0.011, "{worst}");
    // Periodic, not at every step: the age runs up to the period.
    assert!(worst > 0.8 * EVERY_S, "{worst}");
    assert_eq!(saved.format_version, FORMAT_VERSION);
    assert_eq!(saved.param_set.identity().unwrap(), nominal);
    assert!(saved.stats.steps > 0 && saved.pose.unwrap().x_m.hypot(saved.pose.unwrap().y_m) > 0.1);
    assert!(!dir.join(".state.json.tmp").exists(), "temporary file left");
}

/// A stopped daemon writes its end state; the next start on the same set
/// takes the learnt values back. A commit made while the daemon was down,
/// an edited configuration, and a file of the previous format each drop
/// them with a warning naming the file (and both sets).
#[tokio::test(start_paused = true)]
async fn learnt_values_come_back_only_onto_the_set_they_were_learnt_on() {
    let (logs, _guard) = Logs::capture();
    let dir = tmp_dir("state-identity");
    let path = dir.join("state.json");
    let _ = std::fs::remove_file(&path);
    let config = Arc::new(config_in(&dir));
    let first = start_and_stop(
        &config,
        Observers {
            restore_learnt: Some(learnt()),
            ..options(&path, 10.0)
        },
    )
    .await;
    assert_eq!(first.state_file, Some(Ok(())));
    let saved = load(&path).unwrap();
    assert!(same_learnt(
        &saved.learnt.unwrap().checked().unwrap(),
        &learnt()
    ));
    let nominal = saved.param_set.identity().unwrap();
    assert_eq!(nominal.version, None);

    // Same set: restored.
    logs.take();
    let again = start_and_stop(&config, options(&path, 10.0)).await;
    assert!(same_learnt(&again.state.learnt(), &learnt()));
    assert!(logs.take().contains("learnt values restored"));

    // A set committed while the daemon was down.
    let mut file = ParamFile::default();
    let steering_gain = config.params.steering().gain;
    file.commit(
        ParamValues {
            steering_gain,
            ..ParamValues::plain(0.305, 0.0905)
        },
        "exact",
        100,
        10,
    );
    store(&config.calibration.param_file, &file).unwrap();
    let calibrated = start_and_stop(&config, options(&path, 10.0)).await;
    let log = logs.take();
    let line = log
        .lines()
        .find(|l| l.contains("learnt values dropped"))
        .unwrap_or_else(|| panic!("no warning in:\n{log}"));
    assert!(line.contains("WARN"), "{line}");
    assert!(line.contains(&path.display().to_string()), "{line}");
    assert!(line.contains(&nominal.to_string()), "{line}");
    assert!(line.contains("calibrated set version 1"), "{line}");
    let fresh = canodom_fusion::ekf::State::origin().learnt();
    assert_eq!(calibrated.state.learnt(), fresh);
    assert_eq!(calibrated.param_identity.version, Some(1));
    // The file now holds the new set's identity and the priors.
    assert_eq!(
        load(&path).unwrap().param_set.identity().unwrap(),
        calibrated.param_identity
    );

    // An edited configuration (another nominal wheel size), same (absent) set.
    std::fs::remove_file(&config.calibration.param_file).unwrap();
    let again = start_and_stop(
        &config,
        Observers {
            restore_learnt: Some(learnt()),
            ..options(&path, 10.0)
        },
    )
    .await;
    assert_eq!(again.param_identity, nominal);
    let mut edited = config_in(&dir);
    edited.params = edited
        .params
        .with_diameters(canodom_fusion::WheelSet::splat(0.091))
        .unwrap();
    edited.ekf = EkfConfig {
        params: edited.params,
        ..edited.ekf
    };
    logs.take();
    let other = start_and_stop(&Arc::new(edited), options(&path, 10.0)).await;
    let log = logs.take();
    assert!(
        log.contains("learnt values dropped") && log.contains(&nominal.to_string()),
        "{log}"
    );
    assert_eq!(other.state.learnt(), fresh);
    assert_ne!(other.param_identity, nominal);

    // A file of format 1 (no identity): refused as such, the daemon runs.
    let mut text = std::fs::read_to_string(&path).unwrap();
    let this = format!("\"format_version\": {FORMAT_VERSION}");
    assert!(text.contains(&this), "{text}");
    text = text.replace(&this, "\"format_version\": 1");
    std::fs::write(&path, text).unwrap();
    logs.take();
    let old = start_and_stop(&config, options(&path, 10.0)).await;
    let log = logs.take();
    assert!(
        log.contains("learnt values not restored")
            && log.contains("format_version 1")
            && log.contains("older canodom")
            && log.contains("state.json"),
        "{log}"
    );
    assert_eq!(old.state.learnt(), fresh);
    // ... and replaced by a file of this format.
    assert_eq!(load(&path).unwrap().format_version, FORMAT_VERSION);
}

/// Two committed sets that differ in the rear diameters and tread, the
/// same steering map. A daemon on set 2 with learnt values is told to roll
/// back to set 1 at standstill: the rear ratio error, the front scale and
/// the effective tread error go back to their priors, the steering offset
/// and the yaw-rate bias stay, and the state file (written at once) carries
/// set 1's identity. A restart on set 1 takes those values back.
#[tokio::test(start_paused = true)]
async fn an_applied_set_resets_what_was_learnt_on_the_parameters_it_sets() {
    let dir = tmp_dir("state-commit");
    let path = dir.join("state.json");
    let _ = std::fs::remove_file(&path);
    let config = Arc::new(config_in(&dir));
    let steering_gain = config.params.steering().gain;
    let set = |tread_m: f64, right_m: f64| ParamValues {
        steering_gain,
        rear_right_diameter_m: right_m,
        ..ParamValues::plain(tread_m, 0.09)
    };
    let mut file = ParamFile::default();
    file.commit(set(0.30, 0.09), "exact", 100, 10);
    file.commit(set(0.305, 0.0903), "exact", 200, 10);
    store(&config.calibration.param_file, &file).unwrap();
    // Learnt on set 2, as a previous run would have left it.
    let on_two = start_and_stop(
        &config,
        Observers {
            restore_learnt: Some(learnt()),
            ..options(&path, 0.5)
        },
    )
    .await;
    assert_eq!(on_two.param_identity.version, Some(2));
    let mut pipeline_on_one = Pipeline::new(&config).unwrap();
    pipeline_on_one
        .apply_params(Some((1, &set(0.30, 0.09))))
        .unwrap();
    let set_one = pipeline_on_one.param_identity();

    let daemon = InProcessDaemon::spawn(Arc::clone(&config), 1 << 16, options(&path, 0.5));
    let (_rx, tx) = daemon.bus.open().unwrap();
    tokio::time::sleep(Duration::from_millis(50)).await;
    let mut sim = simulator(&config, PathKind::FigureEight, None, 1, false).unwrap();
    let first = sim.try_next().unwrap().unwrap();
    let mut enc = SampleEncoder::new(&config);
    stand(&tx, &mut enc, &first, 2.0).await;
    let before: SavedState = load(&path).unwrap();
    assert_eq!(before.param_set.identity().unwrap(), on_two.param_identity);
    assert!(
        same_learnt(&before.learnt.unwrap().checked().unwrap(), &learnt()) || {
            // The offset's σ grows by its walk at every window, standing or not.
            let b = before.learnt.unwrap().checked().unwrap();
            same_learnt(
                &Learnt {
                    steer_offset_sigma_rad: learnt().steer_offset_sigma_rad,
                    ..b
                },
                &learnt(),
            )
        }
    );
    let wire = CalibWire::new(config.output.base_id).unwrap();
    let data = wire.encode_command(
        Command::Rollback,
        config.calibration.arming_code.unwrap_or(0),
        1,
    );
    tx.send(&CalibWire::frame(wire.cmd_id(), &data).unwrap())
        .await
        .unwrap();
    // Within a period: the write after an applied set does not wait for it.
    stand(&tx, &mut enc, &first, 0.2).await;
    let after = load(&path).unwrap();
    // A rollback re-issues set one's values under a new version (#33).
    assert_eq!(
        after.param_set.identity().unwrap().values_crc32,
        set_one.values_crc32
    );
    assert!((after.params.rear_tread_m - 0.30).abs() < 1e-12);
    let l = after.learnt.unwrap().checked().unwrap();
    let priors = &config.ekf;
    let was = learnt();
    let (y, was_y) = (l.yaw_bias.unwrap(), was.yaw_bias.unwrap());
    // Reset: learnt on the rear diameters and the tread.
    assert_eq!((l.front_scale, l.front_scale_sigma), (1.0, 0.0));
    assert_eq!(
        (y.rear_ratio_err, y.rear_ratio_sigma),
        (0.0, priors.rear_ratio_sigma)
    );
    assert_eq!((y.tread_err, y.tread_sigma), (0.0, priors.tread_sigma));
    // Kept: the steering map and the yaw-rate calibration did not change
    // (standing still moves neither value; the offset's σ grows by its walk).
    let kept = Learnt {
        steer_offset_sigma_rad: was.steer_offset_sigma_rad,
        front_scale: was.front_scale,
        front_scale_sigma: was.front_scale_sigma,
        yaw_bias: Some(LearntPair {
            rear_ratio_err: was_y.rear_ratio_err,
            rear_ratio_sigma: was_y.rear_ratio_sigma,
            tread_err: was_y.tread_err,
            tread_sigma: was_y.tread_sigma,
            ..y
        }),
        ..l
    };
    assert!(same_learnt(&kept, &was), "{l:?}");
    assert!(l.steer_offset_sigma_rad >= 0.999 * was.steer_offset_sigma_rad);
    let summary = daemon.stop().await.unwrap();
    assert_eq!(summary.param_identity.values_crc32, set_one.values_crc32);
    assert_eq!(summary.state.learnt().front_scale, 1.0);

    // The parameter file's set in use is 1 now: a restart takes the values back.
    let restarted = start_and_stop(&config, options(&path, 0.5)).await;
    assert_eq!(restarted.param_identity.values_crc32, set_one.values_crc32);
    assert!(same_learnt(
        &restarted.state.learnt(),
        &summary.state.learnt()
    ));
}

/// The writer's end: a state file that cannot be written is reported by
/// the summary (and `run` exits with it), not lost silently.
#[tokio::test(start_paused = true)]
async fn a_state_file_that_cannot_be_written_is_reported() {
    let dir = tmp_dir("state-unwritable");
    let config = Arc::new(config_in(&dir));
    let path: PathBuf = dir.join("no-such-dir").join("state.json");
    let summary = start_and_stop(&config, options(&path, 10.0)).await;
    let Some(Err(cause)) = summary.state_file else {
        panic!("{:?}", summary.state_file)
    };
    assert!(cause.contains("no-such-dir"), "{cause}");
}

/// The file's format and checks, as pure functions (the unit tests of the
/// state file; in this binary because daemon/src is kept to the service).
mod format {
    use canodom::server::{InProcessDaemon, Observers, Summary};
    use canodom::state_file::*;
    use canodom_can::frame::{CanFrame, FrameId};
    use canodom_pipeline::config::Config;
    use canodom_pipeline::param_set::ParamIdentity;
    use canodom_pipeline::stats::{Reject, Stats};
    use canodom_sim::drive::simulator;
    use canodom_sim::vehicle::{PathKind, SampleEncoder};
    use std::fs;
    use std::path::{Path, PathBuf};
    use std::sync::Arc;
    use std::time::Duration;

    fn config() -> Config {
        crate::util::rc_car()
    }

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("canodom-state-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// The daemon on the in-process bus, fed `seconds` of a simulated drive
    /// plus a few rejects, stopped by its shutdown future once everything
    /// was sent (the frames still queued must be drained, not lost).
    async fn daemon_run(config: &Arc<Config>, seconds: f64) -> (Summary, u64) {
        let daemon = InProcessDaemon::spawn(Arc::clone(config), 1 << 16, Observers::default());
        let (_, tx) = daemon.bus.open().unwrap();
        // Let the link task open its endpoint before the first frame.
        tokio::time::sleep(Duration::from_millis(50)).await;
        let mut sim = simulator(config, PathKind::FigureEight, None, 1, false).unwrap();
        let mut enc = SampleEncoder::new(config);
        let mut frames = Vec::new();
        let mut sent = 0u64;
        while let Some(sample) = sim.try_next().unwrap() {
            if sample.t_s > seconds {
                break;
            }
            frames.clear();
            enc.encode(&sample, &mut frames);
            for f in &frames {
                canodom_can::bus::FrameSink::send(&tx, f).await.unwrap();
                sent += 1;
            }
            // Every 100th sample a rear-wheel frame with a broken checksum.
            if sent.is_multiple_of(300) {
                let rear = frames
                    .iter()
                    .find(|f| f.id() == FrameId::Standard(0x100))
                    .unwrap();
                let mut data = [0u8; 8];
                data.copy_from_slice(rear.data());
                data[7] ^= 0x5A;
                let bad = CanFrame::new_data(FrameId::Standard(0x100), &data).unwrap();
                canodom_can::bus::FrameSink::send(&tx, &bad).await.unwrap();
                sent += 1;
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        // Stop at once: frames still queued for the pipeline must count.
        (daemon.stop().await.unwrap(), sent)
    }

    #[tokio::test(start_paused = true)]
    async fn the_saved_state_is_the_daemons_end_state_and_survives_a_round_trip() {
        let config = Arc::new(config());
        let (summary, sent) = daemon_run(&config, 6.0).await;
        assert_eq!(summary.stats.frames, sent, "every frame sent was counted");
        assert!(summary.stats.get(Reject::BadChecksum) > 0);
        let dir = scratch("roundtrip");
        let path = dir.join("state.json");
        let state = SavedState::new(&config, &summary);
        save(&path, &state).unwrap();
        let back = load(&path).unwrap();
        // serde_json reads floats to within an ulp (no `float_roundtrip`):
        // everything else is exact.
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-15 * a.abs().max(b.abs());
        assert_eq!(back.stats, state.stats);
        assert_eq!(back.params, state.params);
        assert_eq!(
            (back.poses_published, back.frames_lost, back.connections),
            (state.poses_published, state.frames_lost, state.connections)
        );
        let (bp, sp) = (back.pose.unwrap(), state.pose.unwrap());
        assert!(
            close(bp.x_m, sp.x_m) && close(bp.y_m, sp.y_m) && close(bp.heading_rad, sp.heading_rad)
        );
        // The file holds the run's numbers, not defaults.
        let pose = back.pose.expect("steps were made");
        let end = summary.state.pose();
        assert!(close(pose.x_m, end.x_m) && close(pose.y_m, end.y_m));
        assert!(pose.x_m.hypot(pose.y_m) > 0.1, "the car moved: {pose:?}");
        assert_eq!(back.stats.frames, sent);
        assert_eq!(back.stats.steps, summary.stats.steps);
        assert_eq!(
            back.stats.rejects["bad_checksum"],
            summary.stats.get(Reject::BadChecksum)
        );
        assert_eq!(back.stats.rejects.len(), Reject::ALL.len());
        assert!(back.covariance.pos_std_m > 0.0 && back.covariance.pos_std_m.is_finite());
        assert_eq!(back.params.wheelbase_m, 0.26);
        assert!(!dir.join(".state.json.tmp").exists(), "temporary file left");
        fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn a_failed_save_leaves_the_previous_file_and_bad_files_are_typed() {
        let dir = scratch("errors");
        let path = dir.join("state.json");
        let mut state = SavedState {
            format_version: FORMAT_VERSION,
            param_set: SavedParamSet {
                version: None,
                values_crc32: "0000abcd".into(),
            },
            saved_at_unix_us: 1,
            interface: "vcan0".into(),
            config: PathBuf::from("car.toml"),
            pose: None,
            covariance: SavedCovariance {
                pos_std_m: 0.0,
                heading_std_rad: 0.0,
                p: [[0.0; 3]; 3],
            },
            stats: SavedStats::from(&Stats::default()),
            poses_published: 0,
            frames_lost: 0,
            connections: 1,
            outages: 0,
            params: SavedParams {
                wheelbase_m: 0.26,
                rear_tread_m: 0.3,
                front_tread_m: 0.3,
                rear_left_diameter_m: 0.09,
                rear_right_diameter_m: 0.09,
                front_left_diameter_m: 0.09,
                front_right_diameter_m: 0.09,
                steering_gain: 1.0,
                steering_offset_rad: 0.0,
            },
            learnt: None,
            drift: None,
        };
        save(&path, &state).unwrap();
        // The temporary name is taken by a directory: the write fails and
        // the previous file is untouched.
        fs::create_dir(dir.join(".state.json.tmp")).unwrap();
        state.poses_published = 99;
        assert!(matches!(
            save(&path, &state),
            Err(StateFileError::Io { .. })
        ));
        assert_eq!(load(&path).unwrap().poses_published, 0);
        fs::write(&path, format!("{{\"format_version\": {FORMAT_VERSION}}}")).unwrap();
        assert!(matches!(load(&path), Err(StateFileError::Format { .. })));
        let mut text = serde_json::to_string(&state).unwrap();
        let this = format!("\"format_version\":{FORMAT_VERSION}");
        assert!(text.contains(&this));
        text = text.replace(&this, "\"format_version\":7");
        fs::write(&path, text).unwrap();
        let e = load(&path).unwrap_err();
        assert!(
            e.to_string().contains("format_version 7") && e.to_string().contains("newer"),
            "{e}"
        );
        fs::remove_dir_all(dir).unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn a_drift_section_round_trips_and_a_file_without_one_still_loads() {
        use canodom_calib::drift::{Param, Reading};
        use canodom_live::drift_watch::DriftReport;
        let dir = scratch("drift");
        let path = dir.join("state.json");
        let config = Arc::new(config());
        let report = DriftReport {
            refits: 4,
            flagged: vec![Param::RearRatio],
            readings: vec![
                Reading {
                    param: Param::RearRatio,
                    learnt: 1.005,
                    sigma: 0.0004,
                    in_use: 1.0,
                },
                Reading {
                    param: Param::FrontRatio,
                    learnt: 1.0004,
                    sigma: 0.00005,
                    in_use: 1.0003,
                },
            ],
            t_s: Some(1_700_000_240.0),
            distance_m: 2_500.0,
            candidate: Some(canodom_params::persist::ParamValues::plain(0.3, 0.09)),
            front_baseline: Some(canodom_calib::front_ratio::FrontRatio {
                value: 1.0003,
                sigma: 0.00005,
                distance_m: 400.0,
            }),
        };
        let drift = SavedDrift::from(&report);
        assert_eq!(drift.flagged, ["rear_ratio"]);
        assert!(drift.learnt[0].flagged && drift.learnt[0].parameter == "rear_ratio");
        let (summary, _) = daemon_run(&config, 0.5).await;
        let mut state = SavedState::new(&config, &summary);
        assert_eq!(state.drift, None, "no refit: no section");
        state.drift = Some(drift.clone());
        save(&path, &state).unwrap();
        let text = fs::read_to_string(&path).unwrap();
        assert!(
            text.contains("\"flagged\": [\n      \"rear_ratio\"\n    ]"),
            "{text}"
        );
        assert_eq!(load(&path).unwrap().drift, Some(drift));
        // The front tyres' ratio the watch judged against is what the next
        // start judges against.
        let front = canodom::state_file::saved_front_baseline(&load(&path).unwrap()).unwrap();
        assert_eq!((front.value, front.sigma), (1.0003, 0.00005));
        // A file written before the drift watch (no section) still loads.
        state.drift = None;
        let mut old: serde_json::Value = serde_json::to_value(&state).unwrap();
        assert!(old.get("drift").is_none());
        old.as_object_mut().unwrap().remove("drift");
        fs::write(&path, old.to_string()).unwrap();
        assert_eq!(load(&path).unwrap().drift, None);
        assert_eq!(
            canodom::state_file::saved_front_baseline(&load(&path).unwrap()),
            None
        );
        fs::remove_dir_all(dir).unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn the_front_tyres_first_reading_comes_back_at_the_next_start_and_stays() {
        let (logs, _guard) = crate::util::Logs::capture();
        let dir = scratch("front-baseline");
        let path = dir.join("state.json");
        let config = Arc::new(config());
        let options = || Observers {
            state_file: Some(StateFileOptions {
                path: path.clone(),
                every: Duration::from_secs(10),
            }),
            ..Observers::default()
        };
        let daemon = InProcessDaemon::spawn(Arc::clone(&config), 1024, options());
        tokio::time::sleep(Duration::from_millis(50)).await;
        daemon.stop().await.unwrap();
        let mut state = load(&path).unwrap();
        assert_eq!(state.drift, None, "no refit, no first reading: no section");
        assert!(!logs.take().contains("front tyres are judged against"));
        // The run before read the front pair at 1.0031.
        state.drift = Some(SavedDrift {
            refits: 12,
            flagged: Vec::new(),
            at_unix_s: Some(1_700_000_720.0),
            distance_m: 9_000.0,
            learnt: Vec::new(),
            candidate: None,
            front_ratio_first_read: Some(canodom::state_file::SavedFrontRatio {
                ratio: 1.0031,
                sigma: 0.00004,
            }),
        });
        save(&path, &state).unwrap();
        let daemon = InProcessDaemon::spawn(Arc::clone(&config), 1024, options());
        tokio::time::sleep(Duration::from_millis(50)).await;
        daemon.stop().await.unwrap();
        let log = logs.take();
        assert!(
            log.contains(
                "drift watch: the front tyres are judged against the ratio the last run read"
            ) && log.contains("front_ratio=1.0031"),
            "{log}"
        );
        // This run refitted nothing (no fixes), and still keeps it for the
        // next.
        let kept = load(&path).unwrap().drift.unwrap();
        assert_eq!(kept.refits, 0);
        let front = canodom::state_file::saved_front_baseline(&load(&path).unwrap()).unwrap();
        assert_eq!((front.value, front.sigma), (1.0031, 0.00004));
        fs::remove_dir_all(dir).unwrap();
    }

    fn learnt(offset_deg: f64, yaw_bias_dps: Option<f64>) -> SavedLearnt {
        SavedLearnt {
            steer_offset_rad: offset_deg.to_radians(),
            steer_offset_sigma_rad: 0.001,
            front_scale: 1.002,
            front_scale_sigma: 1e-4,
            yaw_bias_radps: yaw_bias_dps.map(f64::to_radians),
            yaw_bias_sigma_radps: yaw_bias_dps.map(|_| 1e-4),
            rear_ratio_err: yaw_bias_dps.map(|_| -4e-4),
            rear_ratio_sigma: yaw_bias_dps.map(|_| 1e-4),
            tread_err: yaw_bias_dps.map(|_| 0.01),
            tread_sigma: yaw_bias_dps.map(|_| 1e-3),
            wheel_fault: None,
        }
    }

    #[test]
    fn learnt_values_are_restored_within_bounds_and_refused_beyond() {
        let ok = learnt(0.3, Some(-0.4)).checked().unwrap();
        assert!((ok.steer_offset_rad - 0.3f64.to_radians()).abs() < 1e-15);
        let y = ok.yaw_bias.unwrap();
        assert!((y.yaw_bias_radps + 0.4f64.to_radians()).abs() < 1e-15);
        assert_eq!(y.rear_ratio_err, -4e-4);
        assert!(learnt(0.3, None).checked().unwrap().yaw_bias.is_none());
        // A steering offset of 7°, a 6°/s gyro bias, a 6 % front scale, a NaN:
        // damaged or learnt from nonsense; each is named.
        for (bad, name) in [
            (learnt(7.0, None), "steer_offset_rad"),
            (learnt(0.3, Some(6.0)), "yaw_bias_radps"),
            (
                SavedLearnt {
                    front_scale: 1.06,
                    ..learnt(0.0, None)
                },
                "front_scale",
            ),
            (
                SavedLearnt {
                    steer_offset_sigma_rad: f64::NAN,
                    ..learnt(0.0, None)
                },
                "steer_offset_sigma_rad",
            ),
            (
                SavedLearnt {
                    rear_ratio_err: Some(0.02),
                    ..learnt(0.0, Some(0.1))
                },
                "rear_ratio_err",
            ),
        ] {
            let e = bad.checked().unwrap_err();
            assert_eq!(e.name, name, "{e}");
        }
    }

    #[test]
    fn restore_takes_back_what_a_run_saved_and_refuses_a_damaged_file() {
        let dir = scratch("restore");
        let path = dir.join("state.json");
        let in_use = ParamIdentity {
            version: Some(4),
            values_crc32: 0x1234_abcd,
        };
        let restore = |path: &Path| canodom::state_file::restore(path, &in_use);
        assert!(matches!(restore(&path), Restored::Nothing));
        fs::write(&path, "{ not json").unwrap();
        assert!(matches!(restore(&path), Restored::Refused(_)));
        let mut state = serde_json::from_str::<SavedState>(&format!(
            r#"{{"format_version":{FORMAT_VERSION},"param_set":{{"version":4,"values_crc32":"1234abcd"}},
            "saved_at_unix_us":1,"interface":"vcan0","config":"c.toml","pose":null,
            "covariance":{{"pos_std_m":0.0,"heading_std_rad":0.0,"p":[[0,0,0],[0,0,0],[0,0,0]]}},
            "stats":{{"frames":0,"used":0,"steps":0,"steps_without_front":0,"rejects":{{}}}},
            "poses_published":0,"frames_lost":0,"connections":1,"outages":0,
            "params":{{"wheelbase_m":0.26,"rear_tread_m":0.3,"front_tread_m":0.3,"rear_left_diameter_m":0.09,
            "rear_right_diameter_m":0.09,"front_left_diameter_m":0.09,"front_right_diameter_m":0.09,
            "steering_gain":1.0,"steering_offset_rad":0.0}}}}"#
        ))
        .unwrap();
        // A file of the version before learnt values: nothing to restore.
        save(&path, &state).unwrap();
        assert!(matches!(restore(&path), Restored::Nothing));
        state.learnt = Some(learnt(0.5, Some(-0.42)));
        save(&path, &state).unwrap();
        let Restored::Learnt(l) = restore(&path) else {
            panic!("not restored")
        };
        assert_eq!(Some(l), state.learnt.unwrap().checked().ok());
        state.learnt = Some(learnt(9.0, None));
        save(&path, &state).unwrap();
        let Restored::Refused(why) = restore(&path) else {
            panic!("restored an out-of-bounds offset")
        };
        assert!(
            why.contains("steer_offset_rad") && why.contains("state.json"),
            "{why}"
        );
        // What the filter learnt goes back into it as it was.
        let st = canodom_fusion::ekf::State::origin().with_learnt(&l);
        assert_eq!(SavedLearnt::from_state(&st), learnt(0.5, Some(-0.42)));
        // Learnt on another set (another version, or the same version with
        // other values): dropped, both named.
        state.learnt = Some(learnt(0.5, Some(-0.42)));
        for (version, crc) in [
            (Some(3), "1234abcd"),
            (None, "1234abcd"),
            (Some(4), "1234abce"),
        ] {
            state.param_set = SavedParamSet {
                version,
                values_crc32: crc.into(),
            };
            save(&path, &state).unwrap();
            let Restored::OtherParamSet { saved, in_use: now } = restore(&path) else {
                panic!("restored values learnt on {version:?}/{crc}")
            };
            assert_eq!(now, in_use);
            assert_eq!(saved, state.param_set.identity().unwrap());
        }
        // A damaged identity is refused, not taken for a match.
        state.param_set.values_crc32 = "12g4abcd".into();
        save(&path, &state).unwrap();
        let Restored::Refused(why) = restore(&path) else {
            panic!("a damaged identity passed")
        };
        assert!(why.contains("values_crc32"), "{why}");
        // A file of format 1 (no identity): refused as written by an older canodom.
        let text = serde_json::to_string(&state).unwrap().replace(
            &format!("\"format_version\":{FORMAT_VERSION}"),
            "\"format_version\":1",
        );
        fs::write(&path, text).unwrap();
        let Restored::Refused(why) = restore(&path) else {
            panic!("a format 1 file was restored")
        };
        assert!(
            why.contains("format_version 1") && why.contains("older") && why.contains("state.json"),
            "{why}"
        );
        fs::remove_dir_all(dir).unwrap();
    }

    #[tokio::test]
    async fn the_daemon_starts_from_the_restored_learnt_values_and_saves_them() {
        let config = Arc::new(config());
        let restored = learnt(0.5, None).checked().unwrap();
        let daemon = InProcessDaemon::spawn(
            Arc::clone(&config),
            1024,
            Observers {
                restore_learnt: Some(restored),
                ..Observers::default()
            },
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
        let summary = daemon.stop().await.unwrap();
        assert_eq!(summary.state.learnt(), restored);
        let saved = SavedState::new(&config, &summary);
        assert_eq!(saved.learnt, Some(learnt(0.5, None)));
    }
}
