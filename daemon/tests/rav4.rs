//! The real RAV4 minute (`data/comma2k19-rav4`): calibrated from ordinary
//! driving with fixes over its first 30 s, the last 30 s dead-reckoned from
//! the truth's pose at 30 s stay within 1 % of their distance (issue #23).

use canodom::cmd::calibrate_drive;
use canodom::cmd::replay::replay_with;
use canodom_pipeline::config::Config;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

fn data() -> PathBuf {
    crate::util::manifest().join("../data/comma2k19-rav4")
}

/// The truth: (t_unix_s, x_m, y_m) at 20 Hz.
fn truth() -> Vec<(f64, f64, f64)> {
    let text = std::fs::read_to_string(data().join("truth.csv")).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|f| f.parse().unwrap()).collect();
            (v[0], v[1], v[2])
        })
        .collect()
}

fn truth_at(truth: &[(f64, f64, f64)], t: f64) -> (f64, f64) {
    let i = truth.partition_point(|r| r.0 < t).clamp(1, truth.len() - 1);
    let (a, b) = (truth[i - 1], truth[i]);
    let f = ((t - a.0) / (b.0 - a.0)).clamp(0.0, 1.0);
    (a.1 + f * (b.1 - a.1), a.2 + f * (b.2 - a.2))
}

/// The truth's heading at `t`: its course over a second (a highway: no sideslip to speak of).
fn course_at(truth: &[(f64, f64, f64)], t: f64) -> f64 {
    let (p, q) = (truth_at(truth, t - 0.5), truth_at(truth, t + 0.5));
    (q.1 - p.1).atan2(q.0 - p.0)
}

fn first_timestamp(log: &str) -> f64 {
    log[1..log.find(')').unwrap()].parse().unwrap()
}

/// The second half's end error, as a fraction of its distance, of the
/// replay rows (t_s, x, y, heading) dead-reckoned from the truth at `split_s`.
fn second_half_error(rows: &[Vec<f64>], t0: f64, truth: &[(f64, f64, f64)], split_s: f64) -> f64 {
    let (error_m, distance_m) = second_half_error_m(rows, t0, truth, split_s);
    error_m / distance_m
}

/// [`second_half_error`] as (end error, distance) in metres.
fn second_half_error_m(
    rows: &[Vec<f64>],
    t0: f64,
    truth: &[(f64, f64, f64)],
    split_s: f64,
) -> (f64, f64) {
    let a = rows
        .iter()
        .min_by(|r, s| (r[0] - split_s).abs().total_cmp(&(s[0] - split_s).abs()))
        .unwrap();
    let b = rows.last().unwrap();
    let (c, s) = ((-a[3]).cos(), (-a[3]).sin());
    let (dx, dy) = (b[1] - a[1], b[2] - a[2]);
    let (bx, by) = (c * dx - s * dy, s * dx + c * dy);
    let start = truth_at(truth, t0 + a[0]);
    let th = course_at(truth, t0 + a[0]);
    let predicted = (
        start.0 + th.cos() * bx - th.sin() * by,
        start.1 + th.sin() * bx + th.cos() * by,
    );
    let end = truth_at(truth, t0 + b[0]);
    let distance: f64 = truth
        .windows(2)
        .filter(|w| w[0].0 >= t0 + a[0] && w[1].0 <= t0 + b[0])
        .map(|w| (w[1].1 - w[0].1).hypot(w[1].2 - w[0].2))
        .sum();
    ((predicted.0 - end.0).hypot(predicted.1 - end.1), distance)
}

fn replay_rows(config: &Config, params: Option<&Path>, log: &str) -> Vec<Vec<f64>> {
    let set = params.map(|p| {
        canodom_params::persist::load(p, &config.calibration.bounds)
            .unwrap()
            .current
            .unwrap()
    });
    let mut csv = Vec::new();
    replay_with(
        config,
        set.as_ref(),
        log.as_bytes(),
        &mut csv,
        &mut std::io::sink(),
    )
    .unwrap();
    crate::util::csv_rows(&String::from_utf8(csv).unwrap())
}

#[test]
fn calibrated_on_the_first_half_the_second_half_stays_within_one_percent() {
    let dir = crate::util::tmp_dir("rav4");
    let log = std::fs::read_to_string(data().join("drive.log")).unwrap();
    let t0 = first_timestamp(&log);
    let truth = truth();
    // What a user would have: the first 30 s of the log, and fixes at 1 Hz
    // from a GNSS receiver over the same 30 s (every 20th truth row).
    let first: String = log
        .lines()
        .filter(|l| first_timestamp(l) - t0 < 30.0)
        .flat_map(|l| [l, "\n"])
        .collect();
    let first_log = dir.join("first.log");
    std::fs::write(&first_log, &first).unwrap();
    let mut fixes = String::from("t_unix_s,x_m,y_m\n");
    for r in truth
        .iter()
        .step_by(20)
        .filter(|r| r.0 - truth[0].0 <= 30.0)
    {
        writeln!(fixes, "{},{},{}", r.0, r.1, r.2).unwrap();
    }
    let fixes_path = dir.join("fixes.csv");
    std::fs::write(&fixes_path, fixes).unwrap();
    let config = Config::load(&data().join("config_yaw.toml")).unwrap();
    let params = dir.join("params.toml");
    calibrate_drive::execute(
        &config,
        &fixes_path,
        &first_log,
        &params,
        Some(&dir.join("report")),
        None,
        &canodom_calib::drive::DriveOptions::default(),
    )
    .unwrap();
    let set = canodom_params::persist::load(&params, &config.calibration.bounds)
        .unwrap()
        .current
        .unwrap();
    // The rear right tyre reads 0.042 % slow; the gyro reads −0.41°/s at rest.
    let v = set.values;
    let ratio = v.rear_right_diameter_m / v.rear_left_diameter_m;
    println!("calibrated: {v:?} (ratio {ratio:.6})");
    assert!((1.0003..1.0006).contains(&ratio), "{ratio}");
    let bias_dps = v.yaw_rate_bias_radps.unwrap().to_degrees();
    assert!((-0.45..-0.35).contains(&bias_dps), "{bias_dps}");
    assert!(dir.join("report/calibration.svg").exists());

    let uncalibrated = replay_rows(&config, None, &log);
    let before = second_half_error(&uncalibrated, t0, &truth, 30.0);
    let rear_of = |rows: &[Vec<f64>]| -> Vec<Vec<f64>> {
        rows.iter().map(|r| vec![r[0], r[4], r[5], r[6]]).collect()
    };
    let rear_before = second_half_error(&rear_of(&uncalibrated), t0, &truth, 30.0);
    let rows = replay_rows(&config, Some(&params), &log);
    let fused = second_half_error(&rows, t0, &truth, 30.0);
    let rear = second_half_error(&rear_of(&rows), t0, &truth, 30.0);
    println!(
        "second half dead-reckoned from the truth at 30 s: uncalibrated fused {:.2} %, rear-only {:.2} %; \
         calibrated fused {:.2} %, rear-only {:.2} %",
        100.0 * before,
        100.0 * rear_before,
        100.0 * fused,
        100.0 * rear
    );
    // The drive needs its calibration: the rear wheels alone are 5 % off
    // before. (The fused pose learns the gyro's bias on this highway's
    // straights by itself since #30's straight-road rule: 0.8 % before.)
    assert!(rear_before > 0.04, "{rear_before}");
    assert!(before <= 0.010, "{before}");
    assert!(fused <= 0.010, "{fused}");
    assert!(rear <= 0.010, "{rear}");

    replay_truth_agrees(&dir, &params, &log, &rows, &truth);
}

/// `replay --truth` tells the same as this test: the end error of the same
/// second half, for the fused pose and rear-only (`rows`: the calibrated replay).
fn replay_truth_agrees(
    dir: &Path,
    params: &Path,
    log: &str,
    rows: &[Vec<f64>],
    truth: &[(f64, f64, f64)],
) {
    // `replay --truth` tells the same: the end error of the same second half.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_canodom"))
        .args(["replay", "--config"])
        .arg(data().join("config_yaw.toml"))
        .arg(data().join("drive.log"))
        .arg("--params")
        .arg(params)
        .arg("--out")
        .arg(dir.join("pose.csv"))
        .args(["--truth-start-s", "30", "--truth"])
        .arg(data().join("truth.csv"))
        .output()
        .unwrap();
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(out.status.success(), "{err}");
    println!("{err}");
    // What the gyro taught the filter is told: the calibrated car's gyro
    // carries the heading, and its bias stays within the drift watch's
    // tolerance (0.05 °/s) of the calibration's −0.394 °/s.
    let yaw = err
        .lines()
        .find_map(|l| l.strip_prefix("replay: yaw-rate sensor: bias "))
        .expect("the yaw-rate sensor's line");
    assert!(yaw.ends_with("the gyro carries the heading: yes"), "{yaw}");
    let bias_dps: f64 = yaw.split(' ').next().unwrap().parse().unwrap();
    assert!((bias_dps + 0.394).abs() < 0.05, "{yaw}");
    let metres = |who: &str| -> f64 {
        let line = err
            .lines()
            .find(|l| l.trim_start().starts_with(who))
            .unwrap();
        let at = line.find("end error ").unwrap() + "end error ".len();
        line[at..].split(' ').next().unwrap().parse().unwrap()
    };
    // The rows' times count from the first frame the pipeline used (the
    // assertions above count from the log's first line, a few ms earlier).
    let first_input = {
        let config = Config::load(&data().join("config_yaw.toml")).unwrap();
        replay_with(
            &config,
            None,
            log.as_bytes(),
            &mut std::io::sink(),
            &mut std::io::sink(),
        )
        .unwrap()
        .first_frame
        .unwrap()
        .as_secs_f64()
    };
    // Like replay --truth, only the steps the truth covers (the log runs a
    // few ms past the truth's last row).
    let t_end = truth.last().unwrap().0;
    let ours = |rows: &[Vec<f64>]| {
        let covered: Vec<Vec<f64>> = rows
            .iter()
            .filter(|r| first_input + r[0] <= t_end)
            .cloned()
            .collect();
        second_half_error_m(&covered, first_input, truth, 30.0).0
    };
    let rear_rows: Vec<Vec<f64>> = rows.iter().map(|r| vec![r[0], r[4], r[5], r[6]]).collect();
    for (who, expected) in [("fused", ours(rows)), ("rear-only", ours(&rear_rows))] {
        let cli = metres(who);
        assert!(
            (cli - expected).abs() < 0.1,
            "{who}: replay --truth {cli} m, test {expected} m"
        );
    }
    assert!(dir.join("pose-truth/calibration.svg").exists());
}
