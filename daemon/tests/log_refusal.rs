//! Logs canodom does not read are refused by name, logs it reads nothing
//! from are refused, and logs of several buses are warned about and can be
//! filtered: through the real binary, for decode, replay and calibrate.

use crate::util::{manifest, rc_car_toml, tmp_dir};
use std::path::Path;
use std::process::{Command, Output};

fn canodom(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_canodom"))
        .args(args)
        .current_dir(manifest())
        .output()
        .unwrap()
}

/// A simulated 1:10 car's candump -L log in `dir`.
fn simulated_log(dir: &Path) -> String {
    let log = dir.join("drive.log");
    let out = canodom(&[
        "simulate",
        "--config",
        rc_car_toml().to_str().unwrap(),
        "--log",
        log.to_str().unwrap(),
        "--path",
        "circle",
    ]);
    assert!(out.status.success(), "{out:?}");
    log.to_str().unwrap().to_owned()
}

/// The three commands that read logs, each on `log`.
fn every_reader(log: &str, dir: &Path) -> Vec<(&'static str, Output)> {
    let cfg = rc_car_toml();
    let cfg = cfg.to_str().unwrap();
    let dbc = manifest().join("../data/dbc/rc_car.dbc");
    let fixes = dir.join("fixes.csv");
    std::fs::write(
        &fixes,
        "t_unix_s,x_m,y_m\n1700000000.0,0,0\n1700000001.0,1,0\n",
    )
    .unwrap();
    let out = dir.join("params.toml");
    vec![
        (
            "decode",
            canodom(&["decode", "--dbc", dbc.to_str().unwrap(), log]),
        ),
        ("replay", canodom(&["replay", "--config", cfg, log])),
        (
            "calibrate (track)",
            canodom(&[
                "calibrate",
                "--config",
                cfg,
                "--track-radius",
                "0.78",
                "--cw",
                log,
                "--ccw",
                log,
            ]),
        ),
        (
            "calibrate (fixes)",
            canodom(&[
                "calibrate",
                "--config",
                cfg,
                "--fixes",
                fixes.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                log,
            ]),
        ),
    ]
}

#[test]
fn logs_of_formats_not_read_are_refused_by_name() {
    let dir = tmp_dir("log_formats");
    let formats: [(&str, &[u8], &str); 2] = [
        (
            "drive.csv",
            b"timestamp,arbitration_id,extended,remote,error,dlc,data\n\
1700000000.0,0x110,0,0,0,8,05B10000000000E4\n",
            "a python-can CSV log",
        ),
        (
            "drive.trc",
            b";$FILEVERSION=2.1\n;$STARTTIME=45000.25\n;   Start time: 25.11.2026 06:00:00.000.0\n\
      1         0.000 DT     0110 Rx 8  05 B1 00 00 00 00 00 E4\n",
            "a PEAK TRC log",
        ),
    ];
    for (name, bytes, format) in formats {
        let path = dir.join(name);
        std::fs::write(&path, bytes).unwrap();
        for (command, out) in every_reader(path.to_str().unwrap(), &dir) {
            let err = String::from_utf8_lossy(&out.stderr);
            assert!(!out.status.success(), "{command} {name} succeeded:\n{err}");
            assert!(
                err.contains(format) && err.contains(name),
                "{command} {name}: the format is not named:\n{err}"
            );
            assert!(
                err.contains("candump -L"),
                "{command} {name}: no way forward:\n{err}"
            );
        }
    }
}

#[test]
fn plain_candump_output_is_decoded_but_refused_where_time_is_needed() {
    let dir = tmp_dir("log_plain");
    let path = dir.join("plain.txt");
    std::fs::write(
        &path,
        b"  vcan0  110   [8]  05 B1 00 00 00 00 00 E4\n  vcan0  101   [8]  20 58 8A 17 00 00 00 7A\n",
    )
    .unwrap();
    for (command, out) in every_reader(path.to_str().unwrap(), &dir) {
        let err = String::from_utf8_lossy(&out.stderr);
        if command == "decode" {
            assert!(out.status.success(), "{err}");
            let text = String::from_utf8_lossy(&out.stdout);
            assert!(text.contains("\"t\": null"), "{text}");
            continue;
        }
        assert!(!out.status.success(), "{command} succeeded:\n{err}");
        assert!(
            err.contains("plain candump output")
                && err.contains("no time")
                && err.contains("plain.txt"),
            "{command}: {err}"
        );
    }
}

/// The fixtures python-can's writers made from a simulated log (#25).
fn python_can_fixture(name: &str) -> String {
    manifest()
        .join("../can/tests/fixtures/logs")
        .join(name)
        .to_str()
        .unwrap()
        .to_owned()
}

#[test]
fn replay_poses_of_every_format_equal_the_candump_l_originals() {
    let cfg = rc_car_toml();
    let cfg = cfg.to_str().unwrap();
    let replay = |name: &str| {
        let out = Command::new(env!("CARGO_BIN_EXE_canodom"))
            .args(["replay", "--config", cfg, &python_can_fixture(name)])
            .current_dir(manifest())
            // ASC dates are local time; the CSV's times are relative anyway.
            .env("TZ", "UTC")
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        out.stdout
    };
    let original = replay("drive.log");
    assert!(original.split(|&b| b == b'\n').count() > 10);
    for name in [
        "drive.asc",
        "drive.asc.gz",
        "drive.blf",
        "drive.blf.zst",
        "drive.blf.gz",
        "drive.pycan.log",
        "drive.log.zst",
        "drive.ta.txt",
    ] {
        assert!(
            replay(name) == original,
            "{name}: poses differ from drive.log's"
        );
    }
}

#[test]
fn a_damaged_compressed_or_blf_log_is_named_with_where() {
    let dir = tmp_dir("log_damaged");
    for (name, bytes, needle) in [
        (
            "drive.blf",
            &b"LOGG\x90\x00\x00\x00\x01\x02\x03\x04\x00\x00\x00\x00"[..],
            "byte offset",
        ),
        (
            "drive.log.gz",
            &b"\x1f\x8b\x08\x00\x00\x00\x00\x00\x00\x03"[..],
            "drive.log.gz",
        ),
    ] {
        let path = dir.join(name);
        std::fs::write(&path, bytes).unwrap();
        for (command, out) in every_reader(path.to_str().unwrap(), &dir) {
            let err = String::from_utf8_lossy(&out.stderr);
            assert!(!out.status.success(), "{command} {name} succeeded:\n{err}");
            assert!(
                err.contains(name) && err.contains(needle),
                "{command} {name}:\n{err}"
            );
        }
    }
}

#[test]
fn a_log_of_garbage_lines_or_nothing_is_refused() {
    let dir = tmp_dir("log_garbage");
    let garbage = dir.join("garbage.log");
    std::fs::write(&garbage, "hello world\nthis is not\na CAN log at all\n").unwrap();
    let empty = dir.join("empty.log");
    std::fs::write(&empty, "").unwrap();
    for (path, says) in [
        (
            &garbage,
            "no frame could be read: all 3 lines are malformed",
        ),
        (&empty, "an empty file"),
    ] {
        for (command, out) in every_reader(path.to_str().unwrap(), &dir) {
            let err = String::from_utf8_lossy(&out.stderr);
            assert!(
                !out.status.success(),
                "{command} {path:?} succeeded:\n{err}"
            );
            assert!(err.contains(says), "{command} {path:?}:\n{err}");
        }
    }
}

#[test]
fn the_wrong_dbc_or_config_gets_a_hint() {
    let dir = tmp_dir("log_wrong_dbc");
    let log = simulated_log(&dir);
    let toyota = manifest().join("../data/dbc/opendbc_toyota_2017.dbc");
    let out = canodom(&["decode", "--dbc", toyota.to_str().unwrap(), &log]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(err.contains("is this the vehicle's DBC?"), "{err}");
    let toyota_cfg = manifest().join("examples/toyota.toml");
    let out = canodom(&["replay", "--config", toyota_cfg.to_str().unwrap(), &log]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("is this the configured vehicle's log"),
        "{err}"
    );
}

#[test]
fn a_log_of_two_buses_is_warned_about_and_filtered() {
    let dir = tmp_dir("log_two_buses");
    let log = simulated_log(&dir);
    let text = std::fs::read_to_string(&log).unwrap();
    // The car's frames on vcan0, another bus's traffic on can1 between them.
    let mixed: String = text
        .lines()
        .flat_map(|l| {
            let other = l.replace(" vcan0 ", " can1 ");
            [format!("{l}\n"), format!("{other}\n")]
        })
        .collect();
    let mixed_log = dir.join("mixed.log");
    std::fs::write(&mixed_log, mixed).unwrap();
    let cfg = rc_car_toml();
    let cfg = cfg.to_str().unwrap();

    let replay = |log: &str, extra: &[&str], csv: &Path| {
        let mut args = vec![
            "replay",
            "--config",
            cfg,
            log,
            "--out",
            csv.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        canodom(&args)
    };
    let (alone, filtered) = (dir.join("alone.csv"), dir.join("filtered.csv"));
    assert!(replay(&log, &[], &alone).status.success());

    // Without a filter: read as one bus, with a warning naming both and the way out.
    let out = replay(mixed_log.to_str().unwrap(), &[], &dir.join("both.csv"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("holds frames of 2 interfaces (vcan0, can1)")
            && err.contains("--interface vcan0"),
        "{err}"
    );

    // With --interface: exactly the car's bus, as if the other were not there.
    let out = replay(
        mixed_log.to_str().unwrap(),
        &["--interface", "vcan0"],
        &filtered,
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(!err.contains("interfaces"), "{err}");
    assert_eq!(
        std::fs::read(&alone).unwrap(),
        std::fs::read(&filtered).unwrap()
    );

    // decode keeps only that bus too; an interface the log lacks is refused.
    let dbc = manifest().join("../data/dbc/rc_car.dbc");
    let dbc = dbc.to_str().unwrap();
    let out = canodom(&[
        "decode",
        "--dbc",
        dbc,
        mixed_log.to_str().unwrap(),
        "--interface",
        "can1",
        "--all",
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success());
    assert_eq!(stdout.lines().count(), text.lines().count());
    assert!(stdout.lines().all(|l| l.contains("\"iface\": \"can1\"")));
    let out = canodom(&[
        "decode",
        "--dbc",
        dbc,
        mixed_log.to_str().unwrap(),
        "--interface",
        "can9",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("no frame of interface can9; the log holds vcan0, can1"),
        "{err}"
    );
}
