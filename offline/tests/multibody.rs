//! Issue #30's judge: drives on CommonRoad's multi-body vehicle model (Pacejka
//! tyres, load transfer, wheels that lock and spin; `data/multibody/`, made by
//! `sim/multibody/generate.py`), read through a Toyota's sensors and replayed
//! through the daemon's pipeline exactly as `canodom replay` does.
//!
//! Bars (the issue's): with the yaw-rate sensor, every drive ends within 1.0 %
//! of its distance, and the published heading σ covers the error (at least
//! 90 % of the family's steps inside 3σ); without it, a drive on which no wheel slipped
//! ends no worse than rear-only + 0.05 % of the distance. On drives whose
//! wheels lock or spin, rear-only takes each slip as a heading jump and the
//! fused pose does not; which of them ends nearer the truth is then a matter of
//! how those jumps happen to cancel the rear wheels' drift, so the test prints
//! both and `sim/multibody/evaluate.py` tabulates them.

#![allow(clippy::unwrap_used)]

use canodom_fusion::ekf::Fault;
use canodom_offline::replay::{ReplayOptions, ReplayRow, ReplaySummary, replay_rows};
use canodom_pipeline::config::Config;
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/multibody")
}

/// Truth: `t_unix_s, x_m, y_m, heading_rad` (heading unwrapped here).
fn truth(dir: &Path) -> Vec<[f64; 4]> {
    let text = std::fs::read_to_string(dir.join("truth.csv")).unwrap();
    let mut rows: Vec<[f64; 4]> = text
        .lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            [v[0], v[1], v[2], v[3]]
        })
        .collect();
    for k in 1..rows.len() {
        let d = rows[k][3] - rows[k - 1][3];
        let wrap = (d / std::f64::consts::TAU).round() * std::f64::consts::TAU;
        for row in &mut rows[k..] {
            row[3] -= wrap;
        }
    }
    rows
}

fn at(truth: &[[f64; 4]], t: f64) -> [f64; 3] {
    let k = truth
        .partition_point(|r| r[0] < t)
        .clamp(1, truth.len() - 1);
    let (a, b) = (truth[k - 1], truth[k]);
    let f = ((t - a[0]) / (b[0] - a[0])).clamp(0.0, 1.0);
    [0, 1, 2].map(|i| a[i + 1] + f * (b[i + 1] - a[i + 1]))
}

struct Judged {
    distance_m: f64,
    fused_pct: f64,
    rear_pct: f64,
    heading_in_3_sigma: f64,
    slipped: bool,
}

/// Replays `dir`'s drive with its vehicle's `config` against the truth. Every
/// configuration here is right, so the plausibility checks must warn
/// nothing, however hard the wheels lock or spin: they once read the harsh
/// Vanagon's spin and locks as steering and yaw rate "0.66 times the rear
/// wheels" and diagnosed the pose as likely wrong.
fn judge(dir: &Path, config_name: &str) -> Judged {
    judge_with_summary(dir, config_name).0
}

/// [`judge`], with the replay's summary (what the filter learnt).
fn judge_with_summary(dir: &Path, config_name: &str) -> (Judged, ReplaySummary) {
    let config = Config::load(&dir.parent().unwrap().join(config_name)).unwrap();
    let log = std::fs::File::open(dir.join("drive.log.zst")).unwrap();
    let (rows, summary) = replay_rows(
        &config,
        None,
        ReplayOptions::default(),
        log,
        &mut std::io::sink(),
    )
    .unwrap();
    assert!(
        summary.warnings.is_empty(),
        "{} with {config_name}: {:?}",
        dir.display(),
        summary.warnings
    );
    let truth = truth(dir);
    let t_of = |r: &ReplayRow| r.t_unix_us as f64 / 1e6;
    let t0 = t_of(&rows[0]);
    let start = at(&truth, t0);
    let (c, s) = (start[2].cos(), start[2].sin());
    let place = |x: f64, y: f64| [start[0] + c * x - s * y, start[1] + s * x + c * y];
    let last = rows.last().unwrap();
    let end = at(&truth, t_of(last));
    let mut distance_m = 0.0;
    let mut prev = start;
    let mut inside = 0usize;
    for r in &rows {
        let p = at(&truth, t_of(r));
        distance_m += (p[0] - prev[0]).hypot(p[1] - prev[1]);
        prev = p;
        let err = start[2] + r.values[2] - p[2];
        if err.abs() <= 3.0 * r.sample[2] + 1e-9 {
            inside += 1;
        }
    }
    let err = |x: f64, y: f64| {
        let q = place(x, y);
        100.0 * (q[0] - end[0]).hypot(q[1] - end[1]) / distance_m
    };
    let meta = std::fs::read_to_string(dir.join("meta.json")).unwrap();
    let judged = Judged {
        distance_m,
        fused_pct: err(last.values[0], last.values[1]),
        rear_pct: err(last.values[3], last.values[4]),
        heading_in_3_sigma: inside as f64 / rows.len() as f64,
        slipped: meta.contains("\"brake_lock\"") || meta.contains("\"spin\""),
    };
    (judged, summary)
}

fn drives() -> Vec<PathBuf> {
    let mut found = Vec::new();
    for vehicle in ["escort", "bmw320i", "vanagon"] {
        for entry in std::fs::read_dir(root().join(vehicle)).unwrap() {
            let p = entry.unwrap().path();
            if p.join("drive.log.zst").exists() {
                found.push(p);
            }
        }
    }
    found.sort();
    // Two drives per vehicle, and the Escort of seed 105, whose tyres slip
    // enough in its curves to hide its effective tread from the gyro (2.3σ).
    assert_eq!(found.len(), 7, "the family's drives: {found:?}");
    found
}

#[test]
fn with_the_yaw_rate_sensor_every_drive_ends_within_one_percent_and_sigma_covers_the_heading() {
    let (mut inside, mut drives_n) = (0.0, 0.0);
    for dir in drives() {
        let j = judge(&dir, "config_yaw.toml");
        println!(
            "{}: {:.0} m, fused with the gyro {:.2} % (rear-only {:.2} %), heading inside 3σ {:.0} %",
            dir.display(),
            j.distance_m,
            j.fused_pct,
            j.rear_pct,
            100.0 * j.heading_in_3_sigma
        );
        assert!(
            j.fused_pct <= 1.0,
            "{}: {:.2} %",
            dir.display(),
            j.fused_pct
        );
        inside += j.heading_in_3_sigma;
        drives_n += 1.0;
    }
    // Consistency is the family's: one drive (Escort seed 3) was once inside
    // 3σ on only 71 % of its steps, the six together on 95 % (each of the
    // seven is on 100 % now).
    assert!(
        inside / drives_n >= 0.9,
        "heading inside 3σ on {:.0} % of steps",
        100.0 * inside / drives_n
    );
}

#[test]
fn without_it_a_slip_free_drive_is_never_worse_than_rear_only() {
    let mut judged = 0;
    for dir in drives() {
        let j = judge(&dir, "config.toml");
        println!(
            "{}: {:.0} m, fused {:.2} %, rear-only {:.2} %{}",
            dir.display(),
            j.distance_m,
            j.fused_pct,
            j.rear_pct,
            if j.slipped { " (wheels slip)" } else { "" }
        );
        if !j.slipped {
            judged += 1;
            assert!(
                j.fused_pct <= j.rear_pct + 0.05,
                "{}: fused {:.2} % against rear-only {:.2} %",
                dir.display(),
                j.fused_pct,
                j.rear_pct
            );
        }
    }
    assert!(judged >= 1, "no slip-free drive to judge");
}

#[test]
fn a_spin_of_both_driven_wheels_is_not_taken_for_the_car() {
    // `generate.py --harsh`, Vanagon seed 202: at 113 s both rear (driven)
    // wheels spin to two to four times the car's speed for 0.9 s, and the
    // rear wheels lock twice. Rear-only ends 12.3 % off. Without the axle
    // watch the windowed filter took the rolling front for a locked one,
    // kept the spinning rear and turned 79° in 0.6 s (11.1 %).
    let dir = root().join("harsh/vanagon/seed-202");
    let without = judge(&dir, "config.toml");
    let with = judge(&dir, "config_yaw.toml");
    println!(
        "{}: {:.0} m, rear-only {:.2} %, fused {:.2} %, with the gyro {:.2} %",
        dir.display(),
        without.distance_m,
        without.rear_pct,
        without.fused_pct,
        with.fused_pct
    );
    assert!(
        without.fused_pct <= 0.5 * without.rear_pct,
        "without the gyro: fused {:.2} %, rear-only {:.2} %",
        without.fused_pct,
        without.rear_pct
    );
    assert!(
        with.fused_pct <= 1.0,
        "with the gyro: {:.2} %",
        with.fused_pct
    );
}

#[test]
fn a_rear_tyre_that_is_off_is_told_and_its_error_taken_back() {
    // `generate.py --tyre-large RL 0.003`: the rear-left wheel reads 0.3 %
    // short, the rest of the drive as its seed draws it. BMW 320i seed 21,
    // without the gyro: the wheels' learner tells the tyre from the front one
    // on its side only 758 m into the 1.1 km (the tyres slip in curves), when
    // the rear wheels' heading is 1.6 rad off; the pose's history is then
    // moved back (10.0 % where rear-only ends 51.8 %; while the history was
    // cut at 1 rad the pose ended 53.7 %).
    let dir = root().join("tyre/bmw320i/seed-21");
    let (without, summary) = judge_with_summary(&dir, "config.toml");
    let scales = summary.state.wheel_scales();
    println!(
        "{}: {:.0} m, fused {:.2} %, rear-only {:.2} %; {scales}",
        dir.display(),
        without.distance_m,
        without.fused_pct,
        without.rear_pct
    );
    assert_eq!(scales.likeliest.0, Fault::RearLeft, "{scales}");
    assert!(
        (scales.scale.rear_left - 1.0 / 1.003).abs() < 1e-3,
        "{scales}"
    );
    assert!(
        without.fused_pct <= 0.3 * without.rear_pct,
        "fused {:.2} %, rear-only {:.2} %",
        without.fused_pct,
        without.rear_pct
    );
    // Escort seed 25: the wheels alone take the same tyre for the front-left
    // one (p 1.000); once the gyro carries the pose, its rear ratio (−0.27 %)
    // leaves that explanation out.
    let dir = root().join("tyre/escort/seed-25");
    let (alone, summary) = judge_with_summary(&dir, "config.toml");
    assert_eq!(
        summary.state.wheel_scales().likeliest.0,
        Fault::FrontLeft,
        "what the wheels alone tell (if this changes, the gyro check below proves nothing)"
    );
    let (with, summary) = judge_with_summary(&dir, "config_yaw.toml");
    let scales = summary.state.wheel_scales();
    println!(
        "{}: {:.0} m, with the gyro {:.2} % (without {:.2} %, rear-only {:.2} %); {scales}",
        dir.display(),
        with.distance_m,
        with.fused_pct,
        alone.fused_pct,
        with.rear_pct
    );
    assert_eq!(scales.likeliest.0, Fault::RearLeft, "{scales}");
    assert!(scales.told_by_gyro, "{scales}");
    assert!(with.fused_pct <= 1.0, "{:.2} %", with.fused_pct);
}
