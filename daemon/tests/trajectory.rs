//! Replay of simulated logs reproduces the simulator's true trajectory.

use crate::util::{csv_rows, rc_car, replayed_end_errors, simulated_log};
use canodom::cmd::replay::{CSV_HEADER, replay};
use canodom_pipeline::config::Config;
use canodom_sim::vehicle::PathKind;

/// Interpolates the truth at `t_s` (rows are t, x, y, heading at 100 Hz).
fn truth_at(truth: &[Vec<f64>], t_s: f64) -> &[f64] {
    let i = truth.partition_point(|r| r[0] < t_s - 1e-9);
    &truth[i.min(truth.len() - 1)]
}

fn check(config: &Config, path: PathKind, seed: u64, max_end_m: f64, max_heading_rad: f64) {
    let (log, truth_csv) = simulated_log(config, path, seed);
    let mut csv = Vec::new();
    let summary = replay(config, &log[..], &mut csv, &mut std::io::sink()).unwrap();
    let csv = String::from_utf8(csv).unwrap();
    assert_eq!(csv.lines().next(), Some(CSV_HEADER));
    let rows = csv_rows(&csv);
    let truth = csv_rows(&truth_csv);
    assert_eq!(rows[0][1..4], [0.0, 0.0, 0.0], "starts at the origin");
    assert!(rows.len() > 1000);
    let mut worst = 0.0f64;
    for r in &rows {
        let t = truth_at(&truth, r[0]);
        assert!(
            (t[0] - r[0]).abs() < 1e-6,
            "one row per sample: t {} vs {}",
            r[0],
            t[0]
        );
        worst = worst.max((r[1] - t[1]).hypot(r[2] - t[2]));
    }
    let last = rows.last().unwrap();
    let t = truth.last().unwrap();
    let end = (last[1] - t[1]).hypot(last[2] - t[2]);
    let dh = (last[3] - t[3]).abs();
    println!(
        "{path:?} seed {seed}: end error {end:.4} m, worst {worst:.4} m, heading {dh:.5} rad; {}",
        summary.stats
    );
    assert!(end < max_end_m, "end error {end} m");
    assert!(worst < 2.0 * max_end_m, "worst error {worst} m");
    assert!(dh < max_heading_rad, "heading error {dh} rad");
    assert_eq!(summary.stats.nonzero().count(), 0, "{}", summary.stats);
}

#[test]
fn rc_car_track_replay_follows_the_truth() {
    // The nominal vehicle is the true one, so the error left is the
    // encoders' quantisation and the path noise the filter cannot see:
    // millimetres over the 7 m track.
    check(&rc_car(), PathKind::TrackCcw, 1, 0.01, 0.01);
}

#[test]
fn rc_car_random_drive_replay_follows_the_truth() {
    check(&rc_car(), PathKind::Random, 2, 0.02, 0.01);
}

#[test]
fn toyota_road_drive_replay_follows_the_truth() {
    // km/h speeds in 0.01 steps and a 1.5°/0.1° steering wheel angle over
    // the 660 m road drive: the fusion crate's §12 bar is 0.05 % of the distance.
    let config = Config::load(&crate::util::toyota_toml()).unwrap();
    check(&config, PathKind::Random, 1, 0.0005 * 660.0, 0.01);
}

/// The fusion tests' full-size family through the whole daemon path (Toyota
/// DBC, frames, decoders, pipeline): on each drive the fused end error is at
/// most rear-only's plus 0.05 % of the distance, and at most 0.15 % of it.
#[test]
fn toyota_full_size_family_fused_never_worse_than_rear_only() {
    let config = Config::load(&crate::util::toyota_toml()).unwrap();
    for seed in 0..4 {
        let (distance_m, fused, rear, summary) =
            replayed_end_errors(&config, PathKind::FullSize, seed);
        println!(
            "full-size seed {seed}: {distance_m:.0} m, rear-only {rear:.2} m, fused {fused:.2} m; {}",
            summary.stats
        );
        assert!(
            fused <= rear + 0.0005 * distance_m,
            "seed {seed}: {fused} vs {rear}"
        );
        assert!(
            fused <= 0.0015 * distance_m,
            "seed {seed}: {fused} m of {distance_m} m"
        );
    }
}
