use super::*;
use crate::synth::lap;

fn nominal() -> VehicleParams {
    VehicleParams::nominal(0.25, 0.30, 0.09, 1000).unwrap()
}

fn config() -> CalibratorConfig {
    CalibratorConfig {
        standstill_speed_mps: 0.01,
        standstill_time_s: 1.0,
        bounds: ParamBounds::around(0.30, 0.09, 0.3, 10f64.to_radians()),
        max_tread_std_m: 0.005,
        max_ratio_std: 0.002,
        max_steer_gain_std_rel: 0.02,
        max_steer_offset_std_rad: 0.5f64.to_radians(),
        max_history: 10,
        fixes_available: false,
        drive_gate: crate::drive_gate::DriveGate::default(),
        online_window_s: None,
    }
}

fn values(tread_m: f64) -> ParamValues {
    ParamValues::plain(tread_m, 0.09)
}

fn answers(out: &[Output]) -> Vec<std::result::Result<(), Refused>> {
    out.iter()
        .filter_map(|o| match o {
            Output::Answer(a) => Some(*a),
            _ => None,
        })
        .collect()
}

#[test]
fn a_rollback_waits_for_its_store_refuses_meanwhile_and_a_failed_store_changes_nothing() {
    let mut file = ParamFile::default();
    file.commit(values(0.30), "exact", 1, 10);
    file.commit(values(0.31), "exact", 2, 10);
    let mut cal = Calibrator::new(config(), nominal(), file.clone());
    let out = cal.on_command(1.0, Command::Rollback, false);
    let [Output::Persist(stored)] = out.as_slice() else {
        panic!("a rollback asks for a store and waits: {out:?}");
    };
    // Set 1's values under a new version (#33: versions are never re-used).
    assert_eq!(stored.current.as_ref().map(|s| s.version), Some(3));
    assert_eq!(
        stored.current.as_ref().map(|s| s.values),
        Some(values(0.30))
    );
    assert!(cal.is_busy() && cal.is_storing());
    for command in [Command::Rollback, Command::StartSteering, Command::Abort] {
        assert_eq!(
            answers(&cal.on_command(1.1, command, false)),
            vec![Err(Refused::Session(Refusal::Busy))]
        );
    }
    let out = cal.on_persisted(1.2, false);
    assert_eq!(answers(&out), vec![Err(Refused::PersistFailed)]);
    assert_eq!(
        out.len(),
        1,
        "a failed store applies and writes back nothing"
    );
    assert_eq!(cal.file(), &file, "the file in use is unchanged");
    assert!(!cal.is_busy());
    // Again, stored this time: answered first, then applied (no step yet:
    // standing still) and handed out for write-back.
    let _ = cal.on_command(2.0, Command::Rollback, false);
    let out = cal.on_persisted(2.1, true);
    assert_eq!(
        out,
        vec![
            Output::Answer(Ok(())),
            Output::Apply {
                version: 3,
                values: values(0.30)
            },
            Output::Adopted { version: 3 },
        ]
    );
    assert_eq!(cal.file().current.as_ref().map(|s| s.version), Some(3));
    assert_eq!(
        answers(&cal.on_command(3.0, Command::Rollback, true)),
        vec![Err(Refused::WritebackBusy)]
    );
    // An answer nobody waits for is ignored.
    assert!(cal.on_persisted(3.1, true).is_empty());
}

#[test]
fn a_session_computes_as_a_job_and_commits_after_its_store() {
    let truth = VehicleParams::nominal(0.25, 0.285, 0.09, 1000).unwrap();
    let mut cal = Calibrator::new(config(), nominal(), ParamFile::default());
    let start = Command::StartSession {
        radius_m: 0.78,
        runs_per_direction: 2,
    };
    assert_eq!(answers(&cal.on_command(0.0, start, false)), vec![Ok(())]);
    let track = Track::new(0.78).unwrap();
    let mut t_s = 0.0;
    let rest = |cal: &mut Calibrator, t_s: &mut f64| {
        for _ in 0..150 {
            *t_s += 0.01;
            let _ = cal.on_step(*t_s, (0.0, 0.0), Some(0.0), None);
        }
    };
    rest(&mut cal, &mut t_s);
    for _ in 0..4 {
        let Instruction::Go { direction, .. } = cal.instruction() else {
            panic!("{:?}", cal.instruction());
        };
        for s in lap(&truth, track, direction, 0.3, 100.0).unwrap() {
            t_s += 0.01;
            let _ = cal.on_step(
                t_s,
                (s.rear_left_rev, s.rear_right_rev),
                Some(s.steer_signal),
                None,
            );
        }
        rest(&mut cal, &mut t_s);
    }
    assert_eq!(cal.accepted(), [2, 2]);
    let out = cal.on_command(t_s, Command::Compute, false);
    let [Output::Compute(job)] = out.as_slice() else {
        panic!("compute hands out a job: {out:?}");
    };
    assert!(matches!(job, Job::Rear(_)));
    let outcome = job.run();
    assert_eq!(
        answers(&cal.on_command(t_s, Command::Commit, false)),
        vec![Err(Refused::Session(Refusal::Busy))]
    );
    // The outcome of another kind of job is not this one's.
    assert!(
        cal.on_computed(JobOutcome::Drive(Err(crate::Error::Numerical {
            context: "test"
        })))
        .is_empty()
    );
    assert!(cal.is_busy());
    assert_eq!(answers(&cal.on_computed(outcome)), vec![Ok(())]);
    let tread_m = cal.result().map(|r| r.rear.tread_m).unwrap();
    assert!((tread_m - 0.285).abs() < 1e-4, "{tread_m}");
    let out = cal.on_command(t_s, Command::Commit, false);
    let [Output::Persist(file)] = out.as_slice() else {
        panic!("commit asks for a store: {out:?}");
    };
    assert_eq!(
        file.current.as_ref().map(|s| s.method.as_str()),
        Some("exact")
    );
    let out = cal.on_persisted(t_s + 0.01, true);
    assert_eq!(out[0], Output::Answer(Ok(())));
    assert!(matches!(
        &out[1],
        Output::Report { version: 1, committed } if matches!(**committed, Committed::Rear { .. })
    ));
    assert!(out.contains(&Output::Adopted { version: 1 }));
    assert_eq!(cal.phase(), Phase::Idle);
    assert!(cal.result().is_none());
    let in_use = cal.current_values();
    assert!((in_use.rear_tread_m - 0.285).abs() < 1e-4);
}

#[test]
fn a_drift_candidate_is_committed_by_commit_or_by_itself_at_a_standstill_only() {
    let mut cal = Calibrator::new(config(), nominal(), ParamFile::default());
    assert_eq!(
        answers(&cal.on_command(0.0, Command::Commit, false)),
        vec![Err(Refused::Session(Refusal::NothingToCommit))]
    );
    let learnt = ParamValues {
        rear_right_diameter_m: 0.0905,
        ..values(0.30)
    };
    cal.set_drift_candidate(Some(ParamValues {
        rear_right_diameter_m: 0.5,
        ..learnt
    }));
    assert_eq!(
        answers(&cal.on_command(0.0, Command::Commit, false)),
        vec![Err(Refused::OutOfBounds)]
    );
    cal.set_drift_candidate(Some(learnt));
    assert_eq!(
        answers(&cal.on_command(0.0, Command::Commit, true)),
        vec![Err(Refused::WritebackBusy)]
    );
    let out = cal.on_command(0.0, Command::Commit, false);
    assert!(answers(&out).is_empty(), "answered once stored");
    assert!(out.iter().any(|o| matches!(o, Output::Persist(f)
        if f.current.as_ref().is_some_and(|s| s.method == "drift" && s.values == learnt))));
    let out = cal.on_persisted(0.0, true);
    assert_eq!(answers(&out), vec![Ok(())]);
    assert!(
        out.iter()
            .any(|o| matches!(o, Output::Adopted { version: 1 }))
    );
    assert!(cal.drift_candidate().is_none());

    // By itself: not while moving, then at a standstill, answering nobody.
    let next = ParamValues {
        rear_right_diameter_m: 0.0906,
        ..learnt
    };
    cal.set_drift_candidate(Some(next));
    for k in 0..=100 {
        let _ = cal.on_step(1.0 + f64::from(k) * 0.01, (0.01, 0.01), None, None);
    }
    assert!(cal.auto_commit(2.0, next, false).is_empty(), "moving");
    for k in 1..=150 {
        let _ = cal.on_step(2.0 + f64::from(k) * 0.01, (0.0, 0.0), None, None);
    }
    assert!(
        cal.auto_commit(3.5, next, true).is_empty(),
        "write-back pending"
    );
    let out = cal.auto_commit(3.5, next, false);
    assert!(out.iter().any(|o| matches!(o, Output::Persist(f)
        if f.current.as_ref().is_some_and(|s| s.method == "drift-auto" && s.version == 2))));
    let out = cal.on_persisted(3.5, true);
    assert!(answers(&out).is_empty(), "nobody asked");
    assert!(
        out.iter()
            .any(|o| matches!(o, Output::Apply { version: 2, .. }))
    );
    assert_eq!(cal.current_values(), next);
    assert!(
        cal.auto_commit(3.6, next, false).is_empty(),
        "no candidate left"
    );
}

#[test]
fn a_drive_needs_fixes_configured_and_enough_of_them() {
    let mut cal = Calibrator::new(config(), nominal(), ParamFile::default());
    assert_eq!(
        answers(&cal.on_command(0.0, Command::StartDrive, false)),
        vec![Err(Refused::NotSupported)]
    );
    let mut cal = Calibrator::new(
        CalibratorConfig {
            fixes_available: true,
            ..config()
        },
        nominal(),
        ParamFile::default(),
    );
    assert_eq!(
        answers(&cal.on_command(0.0, Command::StartDrive, false)),
        vec![Ok(())]
    );
    for k in 1..=100 {
        let _ = cal.on_step(f64::from(k) * 0.01, (0.01, 0.01), Some(0.0), None);
    }
    assert_eq!(
        answers(&cal.on_command(1.0, Command::Compute, false)),
        vec![Err(Refused::TooFewSamples)]
    );
    assert_eq!(
        answers(&cal.on_command(1.0, Command::Commit, false)),
        vec![Err(Refused::Session(Refusal::NothingToCommit))]
    );
    assert_eq!(
        answers(&cal.on_command(1.0, Command::Abort, false)),
        vec![Ok(())]
    );
}

#[test]
fn the_online_ring_keeps_the_front_wheels_in_metres_with_the_diameters_in_use() {
    let mut cal = Calibrator::new(
        CalibratorConfig {
            online_window_s: Some(60.0),
            ..config()
        },
        nominal(),
        ParamFile::default(),
    );
    let circumference = std::f64::consts::PI * 0.09;
    for k in 0..200 {
        let t_s = f64::from(k) * 0.01;
        // The front wheels stale for the middle steps.
        let front = (!(80..120).contains(&k)).then_some((0.1, 0.102));
        let _ = cal.on_step_with_front(t_s, (0.1, 0.1), front, Some(0.0), None);
    }
    cal.on_fix(2.0, 0.0, 0.0, false, None);
    let window = cal.online_window(60.0).unwrap();
    let (read, stale): (Vec<&DriveSample>, Vec<&DriveSample>) =
        window.samples.iter().partition(|s| s.front_m.is_some());
    assert!(read.len() > 20 && !stale.is_empty(), "{:?}", window.samples);
    for s in read {
        let (l, r) = s.front_m.unwrap();
        // A bin's front distances sum its steps', as its rear ones do.
        let steps = s.rear_left_m / (0.1 * circumference);
        assert!((l - steps * 0.1 * circumference).abs() < 1e-12, "{s:?}");
        assert!((r - steps * 0.102 * circumference).abs() < 1e-12, "{s:?}");
    }
    // Without the front wheels (`on_step`) nothing is read of them.
    let mut blind = Calibrator::new(
        CalibratorConfig {
            online_window_s: Some(60.0),
            ..config()
        },
        nominal(),
        ParamFile::default(),
    );
    for k in 0..200 {
        let _ = blind.on_step(f64::from(k) * 0.01, (0.1, 0.1), Some(0.0), None);
    }
    blind.on_fix(2.0, 0.0, 0.0, false, None);
    let window = blind.online_window(60.0).unwrap();
    assert!(window.samples.iter().all(|s| s.front_m.is_none()));
}
