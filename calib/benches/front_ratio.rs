//! The cost of reading the front tyres' ratio from a refit's window
//! (`canodom_calib::front_ratio`, issue #46's drift watch): once per refit,
//! over the window's samples. A road car's 180 s window at the drive
//! record's 0.05 s bins is 3,600 samples: straights, gentle bends and tight
//! turns at 12 m/s, the front-right tyre 0.3 % off.
//!
//! `cargo bench -p canodom-calib --bench front_ratio`

use canodom_calib::drive::DriveSample;
use canodom_calib::front_ratio::{FrontGeometry, front_ratio};
use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;

const GEOMETRY: FrontGeometry = FrontGeometry {
    rear_tread_m: 1.5,
    front_tread_m: 1.55,
    wheelbase_m: 2.7,
};

/// A kinematic car's 180 s window, as the unit tests drive it.
fn window() -> Vec<DriveSample> {
    let g = GEOMETRY;
    let (dt, speed) = (0.05, 12.0);
    (0..3600)
        .map(|i| {
            let t = f64::from(i) * dt;
            let k = match (t / 10.0) as u32 % 4 {
                0 => 0.0,
                1 => 0.0015 * (t * 0.7).sin(),
                2 => 0.02,
                _ => -0.0012,
            };
            let d = speed * dt;
            let turn = k * d;
            let front =
                |side: f64| (d + side * 0.5 * g.front_tread_m * turn).hypot(g.wheelbase_m * turn);
            DriveSample {
                t_s: t,
                rear_left_m: d - 0.5 * g.rear_tread_m * turn,
                rear_right_m: d + 0.5 * g.rear_tread_m * turn,
                front_m: Some((front(-1.0), 1.003 * front(1.0))),
                steer_angle_rad: None,
                yaw_rate_radps: None,
                rear_slip: false,
            }
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let samples = window();
    assert!(front_ratio(&samples, &GEOMETRY, 1.0).is_some());
    c.bench_function("front_ratio/road_180s", |b| {
        b.iter(|| black_box(front_ratio(black_box(&samples), &GEOMETRY, 1.0)));
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
