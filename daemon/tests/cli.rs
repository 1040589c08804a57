//! Every command through the real binary.

use crate::util::{csv_corrections, csv_rows, manifest, rc_car_toml, tmp_dir};
use std::io::Write as _;
use std::process::{Command, Output};

fn canodom(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_canodom"))
        .args(args)
        .current_dir(manifest())
        .output()
        .unwrap()
}

fn ok(args: &[&str]) -> (String, String) {
    let out = canodom(args);
    let (so, se) = (
        String::from_utf8(out.stdout).unwrap(),
        String::from_utf8(out.stderr).unwrap(),
    );
    assert!(out.status.success(), "{args:?} failed:\n{se}");
    (so, se)
}

#[test]
fn every_command_has_help_with_an_example() {
    for cmd in [
        "run",
        "decode",
        "dbc",
        "replay",
        "simulate",
        "demo",
        "calibrate",
    ] {
        let (help, _) = ok(&[cmd, "--help"]);
        assert!(help.contains("Example"), "{cmd} --help:\n{help}");
        assert!(
            help.contains(&format!("canodom {cmd}")) || cmd == "demo",
            "{help}"
        );
    }
}

#[test]
fn simulate_decode_replay_round_trip() {
    let dir = tmp_dir("cli");
    let log = dir.join("drive.log");
    let truth = dir.join("truth.csv");
    let pose = dir.join("pose.csv");
    let cfg = rc_car_toml();
    let cfg = cfg.to_str().unwrap();
    let (_, se) = ok(&[
        "simulate",
        "--config",
        cfg,
        "--log",
        log.to_str().unwrap(),
        "--path",
        "figure-eight",
        "--seed",
        "4",
        "--truth",
        truth.to_str().unwrap(),
    ]);
    assert!(se.contains("true end pose"), "{se}");

    // decode: one JSON object per frame, the issue's shape.
    let (json, se) = ok(&[
        "decode",
        "--dbc",
        "../data/dbc/rc_car.dbc",
        log.to_str().unwrap(),
    ]);
    let lines: Vec<&str> = json.lines().collect();
    let log_lines = std::fs::read_to_string(&log).unwrap().lines().count();
    assert_eq!(lines.len(), log_lines, "{se}");
    let first: serde_json::Value = serde_json::from_str(lines[0]).unwrap();
    assert_eq!(first["t"], serde_json::json!(1_700_000_000.0));
    assert_eq!(first["iface"], "vcan0");
    assert_eq!(first["extended"], false);
    assert!(first["id"].is_u64() && first["name"].is_string());
    let rear = lines
        .iter()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .find(|v| v["name"] == "WHEEL_ENC_REAR")
        .unwrap();
    assert_eq!(rear["id"], 256);
    assert!(rear["signals"]["RL_TICKS"].is_number() && rear["signals"]["COUNTER"] == 0);
    assert!(lines[0].starts_with("{\"t\": 1700000000.000000, \"iface\": \"vcan0\", \"id\": "));

    // replay: the CSV of the issue, ending near the truth.
    let (_, se) = ok(&[
        "replay",
        "--config",
        cfg,
        log.to_str().unwrap(),
        "--out",
        pose.to_str().unwrap(),
    ]);
    assert!(se.contains("steps="), "{se}");
    let csv = std::fs::read_to_string(&pose).unwrap();
    assert_eq!(
        csv.lines().next().unwrap(),
        "t_s,x_m,y_m,heading_rad,odo_x_m,odo_y_m,odo_heading_rad,correction,\
         t_unix_s,speed_mps,pos_std_m,heading_std_rad,pose_valid,quality"
    );
    // The absolute time is the log's (the simulator's epoch), the sample's
    // columns are those of the pose frames `run` would publish.
    let last: Vec<f64> = csv_rows(&csv).pop().unwrap();
    assert!(
        (last[7] - (1_700_000_000.0 + last[0])).abs() < 0.05,
        "{last:?}"
    );
    assert!(
        last[8] >= 0.0 && last[9] > 0.0 && last[10] > 0.0,
        "{last:?}"
    );
    assert_eq!(last[11], 1.0, "pose valid at the end: {last:?}");
    assert_eq!(last[12] as u8 & 1, 1, "{last:?}");
    // One correction a window (50 steps) and nothing in between.
    let corrections = csv_corrections(&csv);
    let closed = corrections.iter().filter(|c| !c.is_empty()).count();
    assert!(closed > 0 && closed * 45 < corrections.len(), "{closed}");
    assert!(
        corrections
            .iter()
            .all(|c| ["", "accepted", "kept_rear", "used_front", "no_front"].contains(&c.as_str())),
        "{corrections:?}"
    );
    // Times are the log's microseconds as written: `0.07`, never the
    // `0.06999999999999999` of a product by 1e-6.
    let long_time = csv.lines().skip(1).find(|l| {
        let t_s = l.split(',').next().unwrap_or("");
        t_s.split('.')
            .nth(1)
            .is_some_and(|fraction| fraction.len() > 6)
    });
    assert_eq!(long_time, None);
    let rows = csv_rows(&csv);
    let t = csv_rows(&std::fs::read_to_string(&truth).unwrap());
    let (a, b) = (rows.last().unwrap(), t.last().unwrap());
    assert!((a[1] - b[1]).hypot(a[2] - b[2]) < 0.02, "{a:?} vs {b:?}");
}

#[test]
fn decode_reports_malformed_lines_and_strict_fails() {
    let dir = tmp_dir("decode");
    let log = dir.join("bad.log");
    std::fs::write(
        &log,
        "(1700000000.000100) vcan0 100#0102030405060708\n\
         garbage here\n\
         (1700000000.000200) can1 7FF#00\n\
         (1700000000.000300) vcan0 12345678#01\n",
    )
    .unwrap();
    let l = log.to_str().unwrap();
    let dbc = "../data/dbc/rc_car.dbc";
    let (json, se) = ok(&["decode", "--dbc", dbc, l]);
    assert_eq!(json.lines().count(), 1);
    assert!(se.contains("line 2"), "{se}");
    let (json, _) = ok(&["decode", "--dbc", dbc, l, "--all"]);
    let all: Vec<serde_json::Value> = json
        .lines()
        .map(|x| serde_json::from_str(x).unwrap())
        .collect();
    assert_eq!(all.len(), 3);
    assert_eq!(all[1]["name"], serde_json::Value::Null);
    assert_eq!(all[2]["extended"], true);
    assert_eq!(all[2]["id"], 0x1234_5678);
    let out = canodom(&["decode", "--dbc", dbc, l, "--strict"]);
    assert!(!out.status.success());
    assert!(String::from_utf8(out.stderr).unwrap().contains("line 2"));
}

#[test]
fn replay_names_the_log_and_line_of_a_malformed_line_and_every_format_in_a_refusal() {
    let dir = tmp_dir("replay-malformed");
    let cfg = rc_car_toml();
    let c = cfg.to_str().unwrap();
    let log = dir.join("drive.log");
    std::fs::write(
        &log,
        "(1700000000.000100) vcan0 100#0102030405060708\n\
         garbage here\n\
         (1700000000.000200) vcan0 100#0102030405060708\n",
    )
    .unwrap();
    let l = log.to_str().unwrap();
    let (_, se) = ok(&["replay", "--config", c, l, "--out", "/dev/null"]);
    assert!(
        se.contains(&format!("replay: {l}: line 2: malformed")),
        "{se}"
    );
    // Nothing readable at all: refused, and the refusal lists what is read.
    let junk = dir.join("junk.log");
    std::fs::write(&junk, "not a log\nnor this\n").unwrap();
    let out = canodom(&["replay", "--config", c, junk.to_str().unwrap()]);
    assert!(!out.status.success());
    let se = String::from_utf8(out.stderr).unwrap();
    for format in ["candump -L", "plain candump", "ASC", "BLF", "zstd"] {
        assert!(se.contains(format), "{format} missing: {se}");
    }
}

#[test]
fn decode_reads_stdin() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_canodom"))
        .args(["decode", "--dbc", "../data/dbc/rc_car.dbc", "-"])
        .current_dir(manifest())
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(b"(1.000001) vcan0 110#0064000000000000\n")
        .unwrap();
    let out = child.wait_with_output().unwrap();
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["name"], "STEERING");
    assert_eq!(v["t"], serde_json::json!(1.000_001));
    // 0x0064 big-endian at 0.01 deg.
    assert_eq!(v["signals"]["STEER_ANGLE"].as_f64(), Some(1.0));
}

#[test]
fn simulate_needs_a_target() {
    let cfg = rc_car_toml();
    let out = canodom(&["simulate", "--config", cfg.to_str().unwrap()]);
    assert!(!out.status.success());
}

#[test]
fn run_refuses_a_bad_config_naming_the_key() {
    let dir = tmp_dir("run");
    let cfg = dir.join("bad.toml");
    let text = std::fs::read_to_string(rc_car_toml())
        .unwrap()
        .replace(
            "../../data/dbc/rc_car.dbc",
            &manifest()
                .join("../data/dbc/rc_car.dbc")
                .display()
                .to_string(),
        )
        .replace("pose_rate_hz = 50.0", "pose_rate_hz = -1.0");
    std::fs::write(&cfg, text).unwrap();
    let out = canodom(&["run", "--config", cfg.to_str().unwrap()]);
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(
        err.contains("bad.toml") && err.contains("output.pose_rate_hz"),
        "{err}"
    );
}

#[test]
fn demo_prints_the_table_and_end_errors() {
    // Run from elsewhere: the built-in configuration and DBC need no file.
    let out = Command::new(env!("CARGO_BIN_EXE_canodom"))
        .args(["demo", "--path", "track-ccw", "--every", "30"])
        .current_dir(std::env::temp_dir())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let so = String::from_utf8(out.stdout).unwrap();
    println!("{so}");
    assert!(so.contains("fused") && so.contains("rear-only"));
    assert!(so.contains("end after"));
    assert!(so.lines().count() >= 5);
}

#[test]
fn run_stops_cleanly_on_sigterm_even_while_retrying() {
    // No CAN interface exists on the test host: the daemon retries with
    // backoff, and SIGTERM must still stop it at once (the backoff watches
    // the shutdown token). The example refuses to run without keys: its
    // bench lines turned on, as a bench does.
    let text = std::fs::read_to_string(rc_car_toml()).unwrap();
    let cfg = crate::util::tmp_dir("sigterm").join("bench.toml");
    let bench = text
        .replace(
            "# [security]\n# allow_without_key",
            "[security]\nallow_without_key",
        )
        .replace(
            "dbc = \"../../data/dbc/rc_car.dbc\"",
            &format!("dbc = {:?}", manifest().join("../data/dbc/rc_car.dbc")),
        );
    std::fs::write(&cfg, bench).unwrap();
    let child = Command::new(env!("CARGO_BIN_EXE_canodom"))
        .args([
            "run",
            "--config",
            cfg.to_str().unwrap(),
            "--log-format",
            "json",
            "--interface",
            "canodomif9",
        ])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(700));
    let killed = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let started = std::time::Instant::now();
    let out = child.wait_with_output().unwrap();
    assert!(started.elapsed() < std::time::Duration::from_secs(5));
    assert!(out.status.success(), "{:?}", out.status);
    let log = String::from_utf8(out.stderr).unwrap();
    // --log-format json: every line is a JSON object.
    for line in log.lines() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        assert!(v["level"].is_string());
    }
    assert!(
        log.contains("shutdown requested") && log.contains("pipeline stopped"),
        "{log}"
    );
    // --interface replaces the configuration's.
    assert!(log.contains("canodomif9"), "{log}");
    // How to make the interface, said once, not at every retry.
    assert_eq!(
        log.matches("ip link add dev canodomif9").count(),
        1,
        "{log}"
    );
}

#[test]
fn simulate_true_params_differ_from_the_nominal_vehicle() {
    // A true rear-right wheel 0.5 % larger than the configuration says: the
    // replay (nominal parameters) then drifts off the truth, as an
    // uncalibrated car does; unknown keys in the file are refused.
    let dir = tmp_dir("true-params");
    let cfg = rc_car_toml();
    let cfg = cfg.to_str().unwrap();
    let params = dir.join("true.toml");
    std::fs::write(&params, "rear_right_diameter_m = 0.09045\n").unwrap();
    let end_error = |extra: &[&str]| {
        let log = dir.join("d.log");
        let truth = dir.join("t.csv");
        let pose = dir.join("p.csv");
        let mut args = vec![
            "simulate",
            "--config",
            cfg,
            "--log",
            log.to_str().unwrap(),
            "--path",
            "track-ccw",
            "--truth",
            truth.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        ok(&args);
        ok(&[
            "replay",
            "--config",
            cfg,
            log.to_str().unwrap(),
            "--out",
            pose.to_str().unwrap(),
        ]);
        let a = csv_rows(&std::fs::read_to_string(&pose).unwrap());
        let b = csv_rows(&std::fs::read_to_string(&truth).unwrap());
        let (a, b) = (a.last().unwrap(), b.last().unwrap());
        (a[4] - b[1]).hypot(a[5] - b[2]) // rear-only odometry vs truth
    };
    let exact = end_error(&[]);
    let wrong = end_error(&["--true-params", params.to_str().unwrap()]);
    println!("rear-only end error: nominal = truth {exact:.4} m, 0.5 % tyre {wrong:.4} m");
    assert!(exact < 0.02 && wrong > 0.1, "{exact} {wrong}");
    std::fs::write(&params, "rear_right_diameter = 0.09\n").unwrap();
    let out = canodom(&[
        "simulate",
        "--config",
        cfg,
        "--log",
        "/dev/null",
        "--true-params",
        params.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
    assert!(
        String::from_utf8(out.stderr)
            .unwrap()
            .contains("rear_right_diameter")
    );
}

/// Issue #20: a DBC with one message that cannot be compiled still decodes the rest (a
/// warning names file, message, signal and reason); `--strict` refuses it; a 64-bit
/// integer prints exactly; CAN FD is read; `decode --help` says so.
#[test]
fn decode_tolerates_a_broken_message_prints_exact_integers_and_strict_refuses() {
    let dir = tmp_dir("issue20");
    let dbc = dir.join("car.dbc");
    std::fs::write(
        &dbc,
        "VERSION \"\"\n\nBS_:\n\nBU_: ECU\n\n\
         BO_ 2 BIG: 8 ECU\n SG_ s64 : 0|64@1- (1,0) [0|0] \"\" ECU\n\n\
         BO_ 3 BROKEN: 2 ECU\n SG_ FAR : 12|8@1+ (1,0) [0|0] \"\" ECU\n",
    )
    .unwrap();
    let log = dir.join("x.log");
    let mut f = std::fs::File::create(&log).unwrap();
    let big = 3_791_054_832_379_806_569i64.to_le_bytes();
    let hex = format!("{:016X}", u64::from_be_bytes(big));
    writeln!(f, "(1700000000.000001) vcan0 002#{hex}").unwrap();
    writeln!(f, "(1700000000.000002) vcan0 002##0{hex}").unwrap();
    drop(f);
    let (dbc, log) = (dbc.to_str().unwrap(), log.to_str().unwrap());
    let (out, err) = ok(&["decode", "--dbc", dbc, log]);
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(lines.len(), 2, "{out}");
    for line in lines {
        assert!(
            line.ends_with(r#""signals": {"s64": 3791054832379806569}}"#),
            "{line}"
        );
    }
    assert!(
        err.contains(&format!(
            "{dbc}: message BROKEN left out (it cannot be decoded): signal FAR: \
             needs 3 bytes but the message is only 2 bytes long"
        )),
        "{err}"
    );
    let refused = canodom(&["decode", "--dbc", dbc, "--strict", log]);
    let err = String::from_utf8(refused.stderr).unwrap();
    assert!(
        !refused.status.success() && refused.stdout.is_empty(),
        "{err}"
    );
    assert!(
        err.contains("--strict: 1 message(s)") && err.contains("message BROKEN left out"),
        "{err}"
    );
    let (help, _) = ok(&["decode", "--help"]);
    assert!(
        help.contains("CAN FD") && help.contains("##") && help.contains("more than 8 data"),
        "{help}"
    );
}

/// Issue #20: the commands that load a configuration take `--strict` too, and a
/// configured signal in a left-out message is refused with the reason.
#[test]
fn replay_strict_refuses_and_a_used_left_out_message_is_named() {
    let dir = tmp_dir("issue20_replay");
    let rc_dbc = std::fs::read_to_string(manifest().join("../data/dbc/rc_car.dbc")).unwrap();
    std::fs::write(
        dir.join("car.dbc"),
        format!("{rc_dbc}\nBO_ 2000 BROKEN: 2 ECU\n SG_ FAR : 12|8@1+ (1,0) [0|0] \"\" ECU\n"),
    )
    .unwrap();
    let toml = std::fs::read_to_string(rc_car_toml())
        .unwrap()
        .replace("../../data/dbc/rc_car.dbc", "car.dbc");
    std::fs::write(dir.join("car.toml"), &toml).unwrap();
    let config = dir.join("car.toml");
    let (config, log) = (
        config.to_str().unwrap(),
        dir.join("drive.log").to_str().unwrap().to_owned(),
    );
    // A log with frames: replay refuses one it reads nothing from.
    ok(&[
        "simulate", "--config", config, "--log", &log, "--path", "circle",
    ]);
    let (_, err) = ok(&["replay", "--config", config, &log]);
    assert!(err.contains("message BROKEN left out"), "{err}");
    let refused = canodom(&["replay", "--config", config, "--strict", &log]);
    let err = String::from_utf8(refused.stderr).unwrap();
    assert!(
        !refused.status.success() && err.contains("--strict"),
        "{err}"
    );
    // Configured to read a signal of the left-out message: refused, with the reason.
    std::fs::write(
        dir.join("car.toml"),
        toml.replace(
            "rear_left = \"WHEEL_ENC_REAR.RL_TICKS\"",
            "rear_left = \"BROKEN.FAR\"",
        ),
    )
    .unwrap();
    let refused = canodom(&["replay", "--config", config, &log]);
    let err = String::from_utf8(refused.stderr).unwrap();
    assert!(
        !refused.status.success()
            && err.contains("\"BROKEN.FAR\" cannot be used")
            && err.contains("needs 3 bytes but the message is only 2 bytes long"),
        "{err}"
    );
}

/// A replay that fails leaves no header-only file behind (#32), and never
/// touches a device given as --out.
#[test]
fn a_failed_replay_leaves_no_output_file() {
    let dir = tmp_dir("failed-replay-out");
    let cfg = rc_car_toml();
    let c = cfg.to_str().unwrap();
    // Frames, but none of an id the configuration reads: the replay fails
    // after the CSV header was written.
    let log = dir.join("other-car.log");
    std::fs::write(
        &log,
        "(1700000000.000100) can0 7FF#0102030405060708\n\
         (1700000000.010100) can0 7FF#0102030405060708\n",
    )
    .unwrap();
    let out_path = dir.join("pose.csv");
    let out = canodom(&[
        "replay",
        "--config",
        c,
        log.to_str().unwrap(),
        "--out",
        out_path.to_str().unwrap(),
    ]);
    let se = String::from_utf8(out.stderr).unwrap();
    assert!(!out.status.success(), "{se}");
    assert!(se.contains("none of its 2 frames"), "{se}");
    assert!(
        !out_path.exists(),
        "a failed replay left {}",
        out_path.display()
    );
    assert!(se.contains("removed: the replay failed"), "{se}");
    // /dev/null is not a regular file: left alone.
    let out = canodom(&[
        "replay",
        "--config",
        c,
        log.to_str().unwrap(),
        "--out",
        "/dev/null",
    ]);
    assert!(!out.status.success());
    assert!(std::path::Path::new("/dev/null").exists());
}
