//! A drive on CommonRoad's multi-body model (`data/multibody/vanagon/seed-8`)
//! calibrated from its first 60 s against GNSS-like fixes written by pynmea2
//! (`sim/multibody/fixes.py`: 1 Hz, σ 0.3 m, 0.2 s latency, two 15 m
//! jumps): the jumps are named and down-weighted, the latency found, the
//! bias within its σ of the model's; and the rest
//! of the drive dead-reckoned from the truth at 60 s within issue #31's
//! 0.5 % of its distance: 0.35 % with these fixes.

use canodom::cmd::calibrate_drive;
use canodom::cmd::replay::replay_with;
use canodom_calib::drive::DriveOptions;
use canodom_pipeline::config::Config;
use std::path::PathBuf;

fn drive_dir() -> PathBuf {
    crate::util::manifest().join("../data/multibody/vanagon/seed-8")
}

/// (t, x, y, heading) of the truth at 50 Hz.
fn truth() -> Vec<[f64; 4]> {
    let text = std::fs::read_to_string(drive_dir().join("truth.csv")).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|f| f.parse().unwrap()).collect();
            [v[0], v[1], v[2], v[3]]
        })
        .collect()
}

fn at(truth: &[[f64; 4]], t: f64) -> [f64; 3] {
    let i = truth
        .partition_point(|r| r[0] < t)
        .clamp(1, truth.len() - 1);
    let (a, b) = (truth[i - 1], truth[i]);
    let f = ((t - a[0]) / (b[0] - a[0])).clamp(0.0, 1.0);
    [1, 2, 3].map(|c| a[c] + f * (b[c] - a[c]))
}

/// The held-out share of the rest after the calibration of the first minute.
/// `name`: the test's own folder (the two tests run in parallel).
fn calibrate_first_minute_and_replay(name: &str) -> f64 {
    let dir = crate::util::tmp_dir(name);
    let config = Config::load(&drive_dir().parent().unwrap().join("config_yaw.toml")).unwrap();
    let log = crate::util::zstd_text(&drive_dir().join("drive.log.zst"));
    let t0: f64 = log[1..log.find(')').unwrap()].parse().unwrap();
    let first: String = log
        .lines()
        .filter(|l| l[1..l.find(')').unwrap()].parse::<f64>().unwrap() - t0 < 60.0)
        .flat_map(|l| [l, "\n"])
        .collect();
    let first_log = dir.join("first.log");
    std::fs::write(&first_log, &first).unwrap();
    let nmea = drive_dir().join("fixes/fixes.nmea");

    // The fit itself: the jumps named, the latency found.
    let fixes = canodom_offline::drive::read_fixes(&nmea).unwrap();
    let base = canodom_offline::drive::values_in_use(&config, None);
    let drive = calibrate_drive::samples_from_log(&config, None, &first_log, None).unwrap();
    let fit = canodom_offline::drive::fit_drive(
        &config,
        base,
        &drive,
        &fixes,
        "the first minute",
        &DriveOptions::default(),
    )
    .unwrap();
    let cal = &fit.calibration;
    println!("{}", calibrate_drive::report_text(cal, &base, &fit.values));
    let named: Vec<f64> = cal.down_weighted.iter().map(|d| d.t_s).collect();
    // fixes.json: a jump at 1700080023.2 and one over 1700080031.2–33.2. The
    // first falls in the stop at 20–29 s, where the gate finds the rear
    // wheels below their speed floor (used_front): no segment reckons across
    // that, so its fixes are left out, not down-weighted.
    assert_eq!(named, [1_700_080_031.2, 1_700_080_032.2, 1_700_080_033.2]);
    for d in &cal.down_weighted {
        assert!(
            (d.residual_m - 15.0).abs() < 1.5 && d.weight < 0.05,
            "{d:?}"
        );
    }
    assert!((50..60).contains(&cal.fixes_used), "{}", cal.fixes_used);
    let latency = cal.fixes_latency_s;
    assert!(latency.observable, "{latency:?}");
    // 0.2 s late, plus the pipeline's own lag of wheel distances behind the
    // frames (0.05 s with clean fixes on these drives).
    assert!((0.1..0.35).contains(&latency.value), "{latency:?}");
    let bias = cal.yaw_bias_radps.unwrap();
    // meta.json: 0.01856°/s.
    assert!(
        (bias.value.to_degrees() - 0.018_56).abs() < 3.0 * bias.sigma.to_degrees(),
        "{bias:?}"
    );

    // Committed, then the whole log replayed with it.
    let params = dir.join("params.toml");
    calibrate_drive::execute(
        &config,
        &nmea,
        &first_log,
        &params,
        None,
        None,
        &DriveOptions::default(),
    )
    .unwrap();
    let set = canodom_params::persist::load(&params, &config.calibration.bounds)
        .unwrap()
        .current
        .unwrap();
    let mut csv = Vec::new();
    replay_with(
        &config,
        Some(&set),
        log.as_bytes(),
        &mut csv,
        &mut std::io::sink(),
    )
    .unwrap();
    let rows = crate::util::csv_rows(&String::from_utf8(csv).unwrap());
    let truth = truth();
    // Rows: t_s, x, y, heading; the rest from the row nearest 60 s.
    let a = rows
        .iter()
        .min_by(|r, s| (r[0] - 60.0).abs().total_cmp(&(s[0] - 60.0).abs()))
        .unwrap();
    let b = rows.last().unwrap();
    let (c, s) = ((-a[3]).cos(), (-a[3]).sin());
    let (dx, dy) = (b[1] - a[1], b[2] - a[2]);
    let (bx, by) = (c * dx - s * dy, s * dx + c * dy);
    let start = at(&truth, t0 + a[0]);
    let (tc, ts) = (start[2].cos(), start[2].sin());
    let end = at(&truth, t0 + b[0]);
    let error_m =
        (start[0] + tc * bx - ts * by - end[0]).hypot(start[1] + ts * bx + tc * by - end[1]);
    let distance_m: f64 = truth
        .windows(2)
        .filter(|w| w[0][0] >= t0 + a[0] && w[1][0] <= t0 + b[0])
        .map(|w| (w[1][1] - w[0][1]).hypot(w[1][2] - w[0][2]))
        .sum();
    let share = error_m / distance_m;
    println!(
        "held out after 60 s: {error_m:.2} m in {distance_m:.0} m ({:.2} %)",
        100.0 * share
    );
    share
}

#[test]
fn gnss_like_fixes_in_nmea_calibrate_the_first_minute() {
    let share = calibrate_first_minute_and_replay("gnss-drive-checks");
    assert!(share.is_finite());
}

/// Issue #31's bar, on this drive with these fixes: 0.35 % since the gyro
/// scale is committed only when surer than the filter's prior (0.65 % before).
/// It is not met on every drive: `sim/multibody/evaluate_fixes.py` shows the
/// six drives' rests at 0.18–1.28 % (Escort seed 3 is the filter's own floor).
#[test]
fn gnss_like_fixes_in_nmea_the_rest_stays_within_half_a_percent() {
    let share = calibrate_first_minute_and_replay("gnss-drive-bar");
    assert!(share <= 0.005, "{share}");
}
