//! `canodom calibrate` on logs from `canodom simulate` (issue 6, "Must show"
//! third bullet): the four Table-2 cases of docs/calibration-math.md §9 on the
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

/// One §9 case: true tread and rear diameters; returns the `[calibration]`
/// table, after checking the `--report` files against it.
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
        "--report",
    ];
    let report_dir = dir.join("report");
    args.push(report_dir.to_str().unwrap());
    args.push("--cw");
    args.extend(cw.iter().map(String::as_str));
    args.push("--ccw");
    args.extend(ccw.iter().map(String::as_str));
    let (stdout, stderr) = canodom(&args);
    assert!(!stderr.contains("rejected"), "{stderr}");
    assert_eq!(std::fs::read_to_string(&out).unwrap(), stdout);
    assert!(stdout.contains("EFFECTIVE tread"), "{stdout}");
    let doc: toml::Table = stdout.parse().unwrap();
    let calibration = doc["calibration"].as_table().unwrap().clone();
    check_report(&report_dir, &calibration, &cw, &ccw);
    calibration
}

/// The `--report` files: the JSON carries exactly the numbers of the TOML,
/// the SVG draws every run before and after, and the centres of gravity
/// moved towards the start.
fn check_report(dir: &Path, toml: &toml::Table, cw: &[String], ccw: &[String]) {
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("calibration.json")).unwrap())
            .unwrap();
    let t = |k: &str| toml[k].as_float().unwrap();
    let j = |v: &serde_json::Value| v.as_f64().unwrap();
    // The files carry the shortest round-trip text of each float; serde_json
    // without `float_roundtrip` may read it one unit in the last place off.
    let same = |a: f64, b: f64| (a - b).abs() <= f64::EPSILON * b.abs();
    for key in ["end_error_before_m", "end_error_after_m"] {
        assert!(same(j(&json[key]), t(key)), "{key}");
    }
    let cal = &json["calibrated"];
    for key in [
        "rear_tread_m",
        "rear_left_diameter_m",
        "rear_right_diameter_m",
        "diameter_ratio",
        "rear_tread_std_m",
    ] {
        assert!(same(j(&cal[key]), t(key)), "{key}");
    }
    assert_eq!(json["method"].as_str(), toml["method"].as_str());
    let runs = json["runs"].as_array().unwrap();
    let labels: Vec<&str> = runs.iter().map(|r| r["label"].as_str().unwrap()).collect();
    let logs: Vec<&str> = cw.iter().chain(ccw).map(String::as_str).collect();
    assert_eq!(labels, logs);
    for which in ["ccw_distance_m", "cw_distance_m"] {
        let before = j(&json["centres_before"][which]);
        let after = j(&json["centres_after"][which]);
        assert!(after < 0.5 * before, "{which}: {before} -> {after}");
    }
    let svg = std::fs::read_to_string(dir.join("calibration.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
    assert_eq!(svg.matches("<svg").count(), 1);
    let polylines = |colour: &str| {
        svg.lines()
            .filter(|l| l.contains("<polyline") && l.contains(&format!("stroke=\"{colour}\"")))
            .count()
    };
    let [before, after] = [
        canodom_report::files::BEFORE_COLOUR,
        canodom_report::files::AFTER_COLOUR,
    ]
    .map(|c| polylines(&format!("#{:02X}{:02X}{:02X}", c.0, c.1, c.2)));
    assert_eq!((before, after), (runs.len(), runs.len()));
    for text in [
        "before: parameters used",
        "after: calibrated",
        "reference track",
        "CoG before: ",
        "CoG after: ",
        "x [m]",
    ] {
        assert!(svg.contains(text), "the SVG lacks {text:?}");
    }
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
