//! The cost of the live drift watch (#46 item 3) on the calibration task:
//! (a) one filter step handed to the live calibration, which now also
//! pushes it into the online ring of the drive (the per-CAN-step cost the
//! watch adds is that push, `ring_push`, beside the whole `on_step`), and
//! (b) one refit of a 180 s window with fixes at 1 Hz, as the daemon runs
//! it on its blocking pool every `every_s` of fixes (with the front tyres'
//! ratio read from the window's near-straights).
//!
//! The drive: the simulated rc_car on a random course through the daemon's
//! own pipeline and live calibration, a fix of the true position each
//! second.
//!
//! `CARGO_TARGET_DIR=target cargo bench -p canodom --bench drift_watch`

use canodom_calib::drive::DriveOptions;
use canodom_calib::drive_record::{DriveRecorder, DriveStep};
use canodom_can::time::Timestamp;
use canodom_fusion::sim::{Plan, simulate};
use canodom_live::drift_watch::RefitJob;
use canodom_live::{LiveCalibration, Output};
use canodom_params::persist::ParamFile;
use canodom_pipeline::config::Config;
use canodom_pipeline::pipeline::{Outcome, Pipeline};
use canodom_pipeline::step::Step;
use canodom_protocol::calib_wire::CalibWire;
use canodom_sim::vehicle::{SampleEncoder, sim_config};
use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use std::path::PathBuf;

fn bench(c: &mut Criterion) {
    let path = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/examples/rc_car.toml"));
    let config = Config::load(&path).expect("example config");
    let mut pipeline = Pipeline::new(&config).expect("pipeline");
    let nominal = *pipeline.params();
    let run = simulate(
        &sim_config(&config, nominal),
        &Plan::random_drive(3, 400.0, 0.8).expect("plan"),
        3,
    )
    .expect("drive");
    let wire = CalibWire::new(config.output.base_id).expect("wire");
    let mut live = LiveCalibration::new(
        wire,
        config.calibration.clone(),
        nominal,
        ParamFile::default(),
    );
    let mut encoder = SampleEncoder::new(&config);
    let (mut frames, mut steps, mut jobs) = (Vec::new(), Vec::new(), Vec::new());
    for (k, s) in run.samples.iter().enumerate() {
        let t = Timestamp::from_micros((1.7e9 + s.t_s).mul_add(1e6, 0.0) as u64);
        frames.clear();
        encoder.encode(s, &mut frames);
        for f in &frames {
            if let Outcome::Step(step, _) = pipeline.push(t, f) {
                steps.push((t, step));
                let _ = hand_over(&mut live, t, &step);
                live.on_window(step.correction);
            }
        }
        if k % 100 == 0 {
            for o in live.on_fix(t, s.true_pose.x_m, s.true_pose.y_m, false, None) {
                if let Output::Refit(job) = o {
                    // Judged at once: the next is asked for `every_s` later.
                    let _ = live.on_refit(t, &job, None);
                    jobs.push(job);
                }
            }
        }
    }
    let job = jobs
        .iter()
        .max_by_key(|j| j.window.fixes.len())
        .expect("a refit was due");
    let span = job.window.samples.last().map_or(0.0, |l| l.t_s) - job.window.samples[0].t_s;
    eprintln!(
        "refit window: {:.0} s, {} samples, {} fixes ({} refits over {:.0} s of drive)",
        span,
        job.window.samples.len(),
        job.window.fixes.len(),
        jobs.len(),
        run.samples.last().map_or(0.0, |s| s.t_s)
    );

    let mut group = c.benchmark_group("drift_watch");
    group.bench_function("ring_push", |b| {
        let mut ring = DriveRecorder::ring(config.calibration.drift.window_s);
        let mut t_s = 0.0;
        b.iter(|| {
            t_s += 0.01;
            ring.step(black_box(&DriveStep {
                t_s,
                rear_left_m: 0.01,
                rear_right_m: 0.0101,
                front_m: Some((0.0102, 0.0103)),
                steer_angle_rad: Some(0.05),
                yaw_rate_radps: None,
                dt_s: 0.01,
            }));
        });
    });
    group.bench_function("on_step", |b| {
        let mut k = 0;
        let t_end = steps.last().map_or(0, |(t, _)| t.as_micros());
        b.iter(|| {
            // The drive's steps again, on a clock that keeps going.
            let (t, step) = &steps[k % steps.len()];
            let lap = (k / steps.len()) as u64;
            let t = Timestamp::from_micros(t.as_micros() + lap * t_end);
            k += 1;
            black_box(hand_over(&mut live, t, step))
        });
    });
    say_whether_the_refit_reads_the_front_tyres(&config, job);
    group.sample_size(10);
    group.bench_function("refit_180s_1hz", |b| {
        b.iter(|| {
            let w = &job.window;
            black_box(canodom_offline::online::refit(
                &config,
                w.base,
                &w.samples,
                &w.fixes,
                &DriveOptions::default(),
                job.t_s,
            ))
        });
    });
    group.finish();
}

/// A pipeline step handed to the live calibration, as the daemon's
/// calibration task hands it.
fn hand_over(live: &mut LiveCalibration, t: Timestamp, step: &Step) -> Vec<Output> {
    live.on_step_with_front(
        t,
        step.rear_rev,
        step.front_rev,
        step.steer_signal,
        step.yaw_rate_radps,
    )
}

/// Whether the benchmarked refit reads the front tyres' ratio (a window
/// too slow or too short for it does not), on stderr.
fn say_whether_the_refit_reads_the_front_tyres(config: &Config, job: &RefitJob) {
    let once = canodom_offline::online::refit(
        config,
        job.window.base,
        &job.window.samples,
        &job.window.fixes,
        &DriveOptions::default(),
        job.t_s,
    );
    eprintln!("the refit reads the front tyres: {:?}", once.front_ratio);
}

criterion_group!(benches, bench);
criterion_main!(benches);
