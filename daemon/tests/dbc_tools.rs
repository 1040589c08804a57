//! The everyday DBC and command tools through the real binary: `dbc dump`
//! on every DBC file of the repository and against cantools, `dbc own` at a
//! base id of one's own, and `calib --print-frame` lines that are the frames
//! the daemon takes.

use crate::util::{manifest, rc_car_toml, tmp_dir};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn canodom(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_canodom"))
        .args(args)
        .current_dir(manifest())
        .output()
        .unwrap()
}

fn stdout_ok(args: &[&str]) -> String {
    let out = canodom(args);
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// Every `.dbc` below `dir`.
fn dbc_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            dbc_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "dbc") {
            out.push(path);
        }
    }
}

#[test]
fn dbc_dump_reads_every_dbc_file_of_the_repository() {
    let root = manifest().join("..");
    let mut files = Vec::new();
    for dir in ["data/dbc", "protocol/dbc", "can-dbc/tests/corpus"] {
        dbc_files(&root.join(dir), &mut files);
    }
    assert!(files.len() > 100, "{}", files.len());
    for file in &files {
        let file = file.to_str().unwrap();
        let text = stdout_ok(&["dbc", "dump", file]);
        assert!(text.contains(" messages, "), "{file}:\n{text}");
        let json: serde_json::Value =
            serde_json::from_str(&stdout_ok(&["dbc", "dump", "--json", file])).unwrap();
        assert!(json["messages"].is_array(), "{file}");
    }
}

#[test]
fn dbc_dump_agrees_with_cantools_on_the_toyota_file() {
    let dbc = manifest().join("../data/dbc/opendbc_toyota_2017.dbc");
    let ours: serde_json::Value = serde_json::from_str(&stdout_ok(&[
        "dbc",
        "dump",
        "--json",
        dbc.to_str().unwrap(),
    ]))
    .unwrap();
    let theirs: Vec<serde_json::Value> = serde_json::from_str(
        &std::fs::read_to_string(
            manifest().join("tests/fixtures/opendbc_toyota_2017.cantools.json"),
        )
        .unwrap(),
    )
    .unwrap();
    let ours = ours["messages"].as_array().unwrap();
    let (mut messages, mut signals) = (0, 0);
    for m in &theirs {
        let mine = ours
            .iter()
            .find(|o| o["name"] == m["name"])
            .unwrap_or_else(|| panic!("{} missing", m["name"]));
        for key in ["id", "extended", "length"] {
            assert_eq!(mine[key], m[key], "{} {key}", m["name"]);
        }
        for s in m["signals"].as_array().unwrap() {
            let my = mine["signals"]
                .as_array()
                .unwrap()
                .iter()
                .find(|o| o["name"] == s["name"])
                .unwrap_or_else(|| panic!("{}.{} missing", m["name"], s["name"]));
            for key in ["start", "length", "byte_order", "unit"] {
                assert_eq!(my[key], s[key], "{}.{} {key}", m["name"], s["name"]);
            }
            for key in ["scale", "offset"] {
                assert_eq!(
                    my[key].as_f64().unwrap(),
                    s[key].as_f64().unwrap(),
                    "{}.{} {key}",
                    m["name"],
                    s["name"]
                );
            }
            signals += 1;
        }
        messages += 1;
    }
    assert_eq!((messages, signals), (50, 310));
}

#[test]
fn dbc_own_at_another_base_decodes_the_daemons_frames() {
    use canodom_can::candump::{Record, format_record};
    use canodom_can::time::Timestamp;
    use canodom_protocol::own_dbc::BaseId;
    use canodom_protocol::pose_frames::{PoseEncoder, PoseFlags, PoseOutput};
    let dir = tmp_dir("dbc_own");
    let own = dir.join("own.dbc");
    stdout_ok(&[
        "dbc",
        "own",
        "--base-id",
        "0x6A0",
        "--out",
        own.to_str().unwrap(),
    ]);
    // The frames the daemon publishes at that base.
    let mut encoder = PoseEncoder::new(BaseId::new(0x6A0, false).unwrap()).unwrap();
    let frames = encoder
        .encode(&PoseOutput {
            timestamp: Timestamp::from_micros(1_700_000_000_000_000),
            x_m: 12.5,
            y_m: -3.25,
            heading_rad: 0.5,
            speed_mps: 1.0,
            yaw_rate_radps: 0.1,
            pos_std_m: 0.05,
            heading_std_rad: 0.01,
            flags: PoseFlags {
                pose_valid: true,
                ..PoseFlags::default()
            },
            param_version: 3,
        })
        .unwrap();
    let mut log = Vec::new();
    for frame in frames {
        format_record(
            &mut log,
            &Record {
                timestamp: Timestamp::from_micros(1_700_000_000_000_000),
                iface: "can0",
                frame,
                direction: None,
            },
        );
    }
    let log_path = dir.join("pose.log");
    std::fs::write(&log_path, log).unwrap();
    let decoded = stdout_ok(&[
        "decode",
        "--dbc",
        own.to_str().unwrap(),
        log_path.to_str().unwrap(),
    ]);
    assert_eq!(decoded.lines().count(), 3, "{decoded}");
    assert!(decoded.contains("\"name\": \"ODOM_POSITION\""), "{decoded}");
    assert!(decoded.contains("\"id\": 1696"), "{decoded}");
    let position: serde_json::Value =
        serde_json::from_str(decoded.lines().next().unwrap()).unwrap();
    let x = position["signals"]["POS_X"].as_f64().unwrap();
    assert!((x - 12.5).abs() < 0.01, "{position}");
    // With the default base (the repository's file), the same frames are unknown.
    let out = canodom(&[
        "decode",
        "--dbc",
        "../protocol/dbc/canodom.dbc",
        log_path.to_str().unwrap(),
    ]);
    assert!(!out.status.success());
}

#[test]
fn print_frame_gives_the_command_frames_the_daemon_takes() {
    use canodom_pipeline::config::Config;
    use canodom_protocol::calib_wire::{CalibWire, CmdCode};
    let cfg = rc_car_toml();
    let config = Config::load(&cfg).unwrap();
    let wire = CalibWire::new(config.output.base_id).unwrap();
    let cfg = cfg.to_str().unwrap();
    for (action, code) in [
        (
            &["start", "--track-radius", "0.78"][..],
            CmdCode::StartSession,
        ),
        (&["start-steering"], CmdCode::StartSteering),
        (&["start-drive"], CmdCode::StartDrive),
        (&["compute"], CmdCode::Compute),
        (&["commit"], CmdCode::Commit),
        (&["rollback"], CmdCode::Rollback),
        (&["abort"], CmdCode::Abort),
    ] {
        for counter in ["0", "9"] {
            let mut args = vec!["calib"];
            args.extend_from_slice(action);
            args.extend_from_slice(&["--config", cfg, "--print-frame", "--counter", counter]);
            let line = stdout_ok(&args);
            // `cansend vcan0 610#0102...`
            let words: Vec<&str> = line.split_whitespace().collect();
            assert_eq!(words[..2], ["cansend", "vcan0"], "{line}");
            let (id, hex) = words[2].split_once('#').unwrap();
            assert_eq!(
                u32::from_str_radix(id, 16).unwrap(),
                config.calibration.command_id.raw()
            );
            let data: Vec<u8> = (0..hex.len())
                .step_by(2)
                .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
                .collect();
            // Decoded as the daemon decodes it: CRC and arming code valid.
            let cmd = wire
                .decode_command(&data)
                .unwrap_or_else(|e| panic!("{line}: {e}"));
            assert!(cmd.checksum_ok, "{line}");
            assert_eq!(cmd.cmd_raw, code.code(), "{line}");
            assert_eq!(cmd.arming_code, config.calibration.arming_code.unwrap_or(0));
            assert_eq!(cmd.counter.to_string(), counter, "{line}");
        }
    }
    let out = canodom(&["calib", "status", "--config", cfg, "--print-frame"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("sends no command"));
}
