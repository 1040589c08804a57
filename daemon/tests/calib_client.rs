//! `canodom calib` through the real binary: on a host without SocketCAN it
//! says so, naming the interface; argument errors are clear.

use crate::util::{manifest, rc_car_toml};
use std::process::{Command, Output};

fn canodom(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_canodom"))
        .args(args)
        .current_dir(manifest())
        .output()
        .unwrap()
}

fn calib(args: &[&str]) -> (Option<i32>, String, String) {
    let cfg = rc_car_toml();
    let mut full = vec!["calib", "--config", cfg.to_str().unwrap()];
    full.extend_from_slice(args);
    let out = canodom(&full);
    (
        out.status.code(),
        String::from_utf8(out.stdout).unwrap(),
        String::from_utf8(out.stderr).unwrap(),
    )
}

#[test]
fn help_shows_a_session_from_start_to_commit() {
    let out = canodom(&["calib", "--help"]);
    assert!(out.status.success());
    let help = String::from_utf8(out.stdout).unwrap();
    assert!(help.contains("Example"), "{help}");
    for step in [
        "calib",
        "start --track-radius",
        "watch",
        "compute",
        "commit",
    ] {
        assert!(help.contains(step), "{step} missing in:\n{help}");
    }
    let start = help.find("start --track-radius").unwrap();
    assert!(
        start < help.rfind("calib --config car.toml commit").unwrap(),
        "{help}"
    );
}

#[test]
fn without_the_interface_it_is_named_unavailable() {
    if vcan0_opens() {
        // The VM: the daemon may be absent, which the client reports with exit 2.
        let (code, _, err) = calib(&["--timeout-s", "0.3", "status"]);
        assert_eq!(code, Some(2), "{err}");
        assert!(
            err.contains("no CALIB_STATUS from canodom on vcan0"),
            "{err}"
        );
        return;
    }
    for args in [&["status"][..], &["commit"], &["watch", "--count", "1"]] {
        let (code, _, err) = calib(args);
        assert!(code.is_some_and(|c| c != 0), "{args:?}: {code:?} {err}");
        assert!(
            err.contains("SocketCAN interface vcan0 is unavailable"),
            "{err}"
        );
    }
}

/// Whether vcan0 can be opened here (no CAN support, or no such interface,
/// on a plain host).
fn vcan0_opens() -> bool {
    use canodom_can::bus::{IdFilter, open_socketcan};
    open_socketcan("vcan0", &[IdFilter::accept_all()]).is_ok()
}

#[test]
fn argument_errors_are_clear() {
    let (code, _, err) = calib(&["start"]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("--track-radius"), "{err}");
    let (code, _, err) = calib(&["start", "--track-radius", "-1.5"]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("must be positive"), "{err}");
    let (code, _, err) = calib(&["end-pose", "--dx-mm", "5"]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("--dy-mm"), "{err}");
    let (code, _, err) = calib(&["fly"]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("fly"), "{err}");
}

#[test]
fn a_missing_config_is_named() {
    let out = canodom(&["calib", "--config", "no/such.toml", "status"]);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains("no/such.toml"), "{err}");
}

/// `canodom calib`'s arguments as clap parses them (moved here from the
/// client's own tests to keep daemon/src under its line limit).
fn parse(args: &[&str]) -> Result<canodom::cmd::calib::CalibArgs, clap::Error> {
    use clap::Parser as _;
    #[derive(Debug, clap::Parser)]
    struct Cli {
        #[command(flatten)]
        args: canodom::cmd::calib::CalibArgs,
    }
    Cli::try_parse_from(std::iter::once("calib").chain(args.iter().copied())).map(|c| c.args)
}

#[test]
fn argument_errors_say_what_is_wrong() {
    let err = |argv: &[&str]| {
        let mut full = vec!["--config", "x.toml"];
        full.extend_from_slice(argv);
        parse(&full).unwrap_err().to_string()
    };
    assert!(err(&["start"]).contains("--track-radius"));
    assert!(err(&["start", "--track-radius", "-1"]).contains("must be positive"));
    assert!(err(&["start", "--track-radius", "0"]).contains("must be positive"));
    assert!(err(&["start", "--track-radius", "70"]).contains("65.535"));
    assert!(err(&["start", "--track-radius", "1", "--runs", "16"]).contains("16"));
    assert!(
        err(&[
            "end-pose",
            "--dx-mm",
            "9000",
            "--dy-mm",
            "0",
            "--dtheta-deg",
            "0"
        ])
        .contains("9000")
    );
    assert!(
        err(&[
            "end-pose",
            "--dx-mm",
            "0",
            "--dy-mm",
            "0",
            "--dtheta-deg",
            "300"
        ])
        .contains("204.7")
    );
    assert!(err(&["--timeout-s", "0", "status"]).contains("timeout"));
}
