//! Production cars' signal forms end to end (#32): a simulated drive encoded
//! with the car's own DBC and conventions, replayed from its configuration.

use crate::util::{csv_rows, simulated_log};
use canodom::cmd::replay::replay;
use canodom_pipeline::config::Config;
use canodom_pipeline::stats::Reject;
use canodom_sim::vehicle::PathKind;
use std::path::PathBuf;

fn example(name: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/examples")).join(name)
}

/// (distance, fused end error, rear-only end error) of `path` with `seed`.
pub fn drive(config: &Config, path: PathKind, seed: u64) -> (f64, f64, f64) {
    let (log, truth_csv) = simulated_log(config, path, seed);
    let mut csv = Vec::new();
    let summary = replay(config, &log[..], &mut csv, &mut std::io::sink()).unwrap();
    let rows = csv_rows(&String::from_utf8(csv).unwrap());
    let truth = csv_rows(&truth_csv);
    let distance_m: f64 = truth
        .windows(2)
        .map(|w| (w[1][1] - w[0][1]).hypot(w[1][2] - w[0][2]))
        .sum();
    let (last, t) = (rows.last().unwrap(), truth.last().unwrap());
    let fused = (last[1] - t[1]).hypot(last[2] - t[2]);
    let rear = (last[4] - t[1]).hypot(last[5] - t[2]);
    println!(
        "{path:?} seed {seed}: {distance_m:.0} m, rear-only {rear:.3} m, fused {fused:.3} m; {}",
        summary.stats
    );
    let s = summary.stats;
    for reject in [
        Reject::BadChecksum,
        Reject::BadCounter,
        Reject::NonFinite,
        Reject::SteerRange,
    ] {
        assert_eq!(s.get(reject), 0, "{path:?} seed {seed}: {s}");
    }
    (distance_m, fused, rear)
}

/// The VW Golf 7: steering and yaw rate as magnitude + sign bit, VW
/// unit spellings, VW's CRC, speeds signed by the gear. The fused pose ends
/// within 0.05 % of the distance of rear-only or better (it was 12.97 % off).
#[test]
fn vw_mqb_drives_fuse_no_worse_than_rear_only() {
    let config = Config::load(&example("vw_mqb.toml")).unwrap();
    for (path, seed) in [
        (PathKind::FullSize, 0),
        (PathKind::FullSize, 1),
        (PathKind::FullSize, 2),
        (PathKind::Town, 3),
    ] {
        let (distance_m, fused, rear) = drive(&config, path, seed);
        assert!(
            fused <= rear + 0.0005 * distance_m,
            "{path:?} seed {seed}: fused {fused} m vs rear-only {rear} m of {distance_m} m"
        );
        assert!(
            fused <= 0.01 * distance_m,
            "{path:?} seed {seed}: fused {fused} m of {distance_m} m"
        );
    }
}
