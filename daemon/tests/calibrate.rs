//! `canodom calibrate` on logs from `canodom simulate` (issue 6, "Must show"
//! third bullet): the four Table-2 cases of calibration-math.md §9 on the
//! 1:10 car of `examples/rc_car.toml` (nominal b = 0.30 m, D = 0.09 m).

use crate::util::{rc_car_toml, tmp_dir};
use std::path::Path;
use std::process::Command;

fn canodom(args: &[&str]) -> (String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_canodom"))
        .args(args)
        .output()
        .unwrap();
    let (so, se) = (
        String::from_utf8(out.stdout).unwrap(),
        String::from_utf8(out.stderr).unwrap(),
    );
    assert!(out.status.success(), "{args:?} failed:\n{se}");
    (so, se)
}

fn simulate(dir: &Path, truth: &Path, path: &str, seed: u64) -> String {
    let log = dir.join(format!("{path}-{seed}.log"));
    canodom(&[
        "simulate",
        "--config",
        rc_car_toml().to_str().unwrap(),
        "--log",
        log.to_str().unwrap(),
        "--path",
        path,
        "--true-params",
        truth.to_str().unwrap(),
        "--seed",
        &seed.to_string(),
    ]);
    log.to_str().unwrap().to_owned()
}

/// One §9 case: true tread and rear diameters; returns the `[calibration]` table.
fn calibrate_case(name: &str, tread_m: f64, left_m: f64, right_m: f64) -> toml::Table {
    let dir = tmp_dir(&format!("calibrate-{name}"));
    let truth = dir.join("truth.toml");
    std::fs::write(
        &truth,
        format!(
            "rear_tread_m = {tread_m:?}\nrear_left_diameter_m = {left_m:?}\nrear_right_diameter_m = {right_m:?}\n"
        ),
    )
    .unwrap();
    let cw: Vec<String> = (1..=5)
        .map(|s| simulate(&dir, &truth, "track-cw", s))
        .collect();
    let ccw: Vec<String> = (11..=15)
        .map(|s| simulate(&dir, &truth, "track-ccw", s))
        .collect();
    let out = dir.join("calibrated.toml");
    let cfg = rc_car_toml();
    let mut args = vec![
        "calibrate",
        "--config",
        cfg.to_str().unwrap(),
        "--track-radius",
        "0.78",
        "--out",
        out.to_str().unwrap(),
        "--cw",
    ];
    args.extend(cw.iter().map(String::as_str));
    args.push("--ccw");
    args.extend(ccw.iter().map(String::as_str));
    let (stdout, stderr) = canodom(&args);
    assert!(!stderr.contains("rejected"), "{stderr}");
    assert_eq!(std::fs::read_to_string(&out).unwrap(), stdout);
    assert!(stdout.contains("EFFECTIVE tread"), "{stdout}");
    let doc: toml::Table = stdout.parse().unwrap();
    doc["calibration"].as_table().unwrap().clone()
}

#[test]
fn calibrate_recovers_the_table2_cases_from_simulated_logs() {
    let nominal_d_m = 0.09;
    let tread_m = 0.285;
    // §9: E = 1.005 around the nominal mean diameter; the tape adds 3.5 %.
    let left_m = 2.0 * nominal_d_m / 2.005;
    let right_m = left_m * 1.005;
    let cases = [
        ("1-base", "52.9 -> 9.6", left_m, right_m),
        ("2-right", "196.8 -> 12.7", left_m, right_m * 1.035),
        ("3-left", "159.8 -> 16.7", left_m * 1.035, right_m),
        ("4-both", "91.5 -> 8.9", left_m * 1.035, right_m * 1.035),
    ];
    for (name, paper, l, r) in cases {
        let c = calibrate_case(name, tread_m, l, r);
        let f = |k: &str| c[k].as_float().unwrap();
        // §4: only the effective tread b·D̄_used/D̄_true is observable.
        let tread_eff_m = tread_m * nominal_d_m / (0.5 * (l + r));
        let ratio = r / l;
        let tread_err = (f("rear_tread_m") - tread_eff_m) / tread_eff_m;
        let ratio_err = (f("diameter_ratio") - ratio) / ratio;
        let (before, after) = (f("end_error_before_m"), f("end_error_after_m"));
        println!(
            "case {name}: E_max {:.1} -> {:.1} cm (paper {paper} cm); tread {:.4} m vs effective \
             {tread_eff_m:.4} ({:+.3} %), ratio {:.5} vs {ratio:.5} ({:+.4} %)",
            before * 100.0,
            after * 100.0,
            f("rear_tread_m"),
            tread_err * 100.0,
            f("diameter_ratio"),
            ratio_err * 100.0,
        );
        assert!(tread_err.abs() < 0.005, "{name}: tread off by {tread_err}");
        assert!(ratio_err.abs() < 0.001, "{name}: ratio off by {ratio_err}");
        assert!(after < 0.2 * before, "{name}: {before} -> {after}");
        assert_eq!(c["method"].as_str(), Some("exact"));
    }
}
