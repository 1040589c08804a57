//! The exact method (LM with heading residuals) on 10 runs of one lap
//! (8.02 m at 0.1 m/s, 100 Hz: 8021 samples each), from the heading law's
//! start and from the nominal parameters. Goal: under 50 ms.

use std::hint::black_box;

use canodom_calib::methods::{ExactOptions, ExactStart, exact, heading};
use canodom_calib::{Direction, RearParams, Run, Track, synth};
use canodom_fusion::{VehicleParams, WheelSet, params::rear_diameters_for_ratio};
use criterion::{Criterion, criterion_group, criterion_main};

fn runs() -> (Vec<Run>, RearParams, Track) {
    let track = Track::new(0.78).expect("valid radius");
    let (l, r) = rear_diameters_for_ratio(0.09, 1.005);
    let mut d = WheelSet::splat(0.09);
    d.rear_left = l;
    d.rear_right = r * 1.035;
    let truth = VehicleParams::nominal(0.25, 0.285, 0.09, 1000)
        .and_then(|p| p.with_diameters(d))
        .expect("valid truth");
    let runs = (0..10)
        .map(|k| {
            let dir = if k < 5 { Direction::Ccw } else { Direction::Cw };
            Run {
                direction: dir,
                samples: synth::lap(&truth, track, dir, 0.1, 100.0).expect("lap"),
                faults: vec![],
                measured_end: None,
            }
        })
        .collect();
    let used = RearParams::new(0.30, 0.09, 0.09).expect("valid nominal");
    (runs, used, track)
}

fn bench(c: &mut Criterion) {
    let (runs, used, track) = runs();
    let mut group = c.benchmark_group("calibration_10_runs_8m_100hz");
    group.sample_size(20);
    group.bench_function("exact_from_heading_law", |b| {
        b.iter(|| exact(black_box(&runs), &used, track, ExactOptions::default()));
    });
    group.bench_function("exact_from_nominal", |b| {
        let options = ExactOptions {
            start: ExactStart::Used,
            ..ExactOptions::default()
        };
        b.iter(|| exact(black_box(&runs), &used, track, options));
    });
    group.bench_function("heading_law", |b| {
        b.iter(|| heading(black_box(&runs), &used, track));
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
