//! The words a user reads when something is wrong: each cause once, and a
//! suggestion for a misspelt name.

use crate::util::{manifest, rc_car_toml, tmp_dir};
use std::process::Command;

fn stderr_of(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_canodom"))
        .args(args)
        .current_dir(manifest())
        .output()
        .unwrap();
    assert!(!out.status.success(), "{args:?} succeeded");
    String::from_utf8(out.stderr).unwrap()
}

#[test]
fn an_os_error_is_printed_once() {
    for args in [
        &["replay", "--config", "/nonexistent/car.toml", "x.log"][..],
        &["decode", "--dbc", "/nonexistent/car.dbc", "x.log"],
        &[
            "replay",
            "--config",
            rc_car_toml().to_str().unwrap(),
            "/nonexistent/drive.log",
        ],
    ] {
        let err = stderr_of(args);
        assert_eq!(
            err.matches("No such file or directory").count(),
            1,
            "{args:?}:\n{err}"
        );
        assert!(err.contains("/nonexistent/"), "{err}");
    }
}

#[test]
fn a_misspelt_signal_gets_a_suggestion() {
    let dir = tmp_dir("misspelt_signal");
    let toml = std::fs::read_to_string(rc_car_toml())
        .unwrap()
        .replace(
            "../../data/dbc/rc_car.dbc",
            &manifest().join("../data/dbc/rc_car.dbc").to_string_lossy(),
        )
        .replace("WHEEL_ENC_REAR.RL_TICKS", "WHEEL_ENC_REAR.RL_TIKS");
    let config = dir.join("car.toml");
    std::fs::write(&config, toml).unwrap();
    let err = stderr_of(&["replay", "--config", config.to_str().unwrap(), "x.log"]);
    assert!(
        err.contains("RL_TIKS") && err.contains("did you mean RL_TICKS?"),
        "{err}"
    );
}

#[test]
fn global_options_may_follow_the_subcommand() {
    let cfg = rc_car_toml();
    let cfg = cfg.to_str().unwrap();
    // After the action as before it: the error is about the bus (none on
    // the test host), not about the arguments.
    for args in [
        &["calib", "status", "--config", cfg, "--timeout-s", "0.2"][..],
        &["calib", "--config", cfg, "status"],
    ] {
        let err = stderr_of(args);
        assert!(!err.contains("unexpected argument"), "{args:?}: {err}");
        assert!(err.contains("vcan0"), "{args:?}: {err}");
    }
    let err = stderr_of(&["calib", "status"]);
    assert!(err.contains("--config FILE"), "{err}");
}
