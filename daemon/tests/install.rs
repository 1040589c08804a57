//! A vehicle install that keeps its calibration (#24): the parameter file is
//! checked before the bus is opened, defaults to systemd's state directory,
//! and relative paths are taken from the configuration's folder.

use crate::util::{manifest, rc_car_toml, tmp_dir};
use canodom_pipeline::config::Config;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// An interface that does not exist: were the bus opened before the check,
/// `run` would wait for it (retrying) instead of exiting.
const NO_INTERFACE: &str = "canodomnone0";

/// A folder holding the rc_car DBC and a configuration beside it that names
/// it relatively, on [`NO_INTERFACE`], with `calibration` appended.
fn install(name: &str, calibration: &str) -> (PathBuf, PathBuf) {
    let dir = tmp_dir(name);
    std::fs::copy(
        manifest().join("../data/dbc/rc_car.dbc"),
        dir.join("vehicle.dbc"),
    )
    .unwrap();
    let text = std::fs::read_to_string(rc_car_toml()).unwrap();
    let text = text
        .replace(
            "dbc = \"../../data/dbc/rc_car.dbc\"",
            "dbc = \"vehicle.dbc\"",
        )
        .replace(
            "interface = \"vcan0\"",
            &format!("interface = \"{NO_INTERFACE}\""),
        )
        .replace(
            "[calibration]\n",
            &format!("[calibration]\n{calibration}\n"),
        );
    assert!(text.contains("vehicle.dbc") && text.contains(NO_INTERFACE));
    let config = dir.join("canodom.toml");
    std::fs::write(&config, text).unwrap();
    // A file where the parameter file's folder should be: unwritable even for
    // root, which the tests may run as.
    std::fs::write(dir.join("not-a-folder"), "").unwrap();
    (dir, config)
}

/// `canodom run` from the crate folder (not the config's), killed after
/// 10 s; returns its output and how long it took.
fn run(config: &Path, state_directory: Option<&Path>) -> (Output, Duration) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_canodom"));
    cmd.args(["run", "--config", config.to_str().unwrap()])
        .current_dir(manifest())
        .env_remove("STATE_DIRECTORY")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    if let Some(dir) = state_directory {
        cmd.env("STATE_DIRECTORY", dir);
    }
    let start = Instant::now();
    let mut child = cmd.spawn().unwrap();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > Duration::from_secs(10) {
            child.kill().unwrap();
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let elapsed = start.elapsed();
    (child.wait_with_output().unwrap(), elapsed)
}

/// `run` failed at once, naming the key and `path` with one OS error.
fn refused(out: &Output, elapsed: Duration, path: &Path) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "run went on:\n{stderr}");
    assert!(
        elapsed < Duration::from_secs(1),
        "took {elapsed:?}:\n{stderr}"
    );
    assert!(stderr.contains("param_file"), "{stderr}");
    assert!(stderr.contains(&path.display().to_string()), "{stderr}");
    assert_eq!(stderr.matches("(os error").count(), 1, "{stderr}");
    // The check comes before the bus: nothing about the interface.
    assert!(!stderr.contains(NO_INTERFACE), "{stderr}");
    stderr
}

#[test]
fn run_refuses_an_unwritable_param_file_before_opening_the_bus() {
    let (dir, config) = install("install-unwritable", "param_file = \"not-a-folder/p.toml\"");
    let (out, elapsed) = run(&config, None);
    // Relative to the config's folder, not to run's working directory.
    let stderr = refused(&out, elapsed, &dir.join("not-a-folder/p.toml"));
    assert!(stderr.contains("Not a directory"), "{stderr}");
    eprintln!("{elapsed:?}: {stderr}");
}

#[test]
fn run_puts_the_param_file_in_the_state_directory_by_default() {
    let (dir, config) = install("install-state", "");
    // systemd's state directory, here unwritable so `run` says where it looked.
    let state = dir.join("not-a-folder");
    let (out, elapsed) = run(&config, Some(&state));
    refused(&out, elapsed, &state.join("canodom-params.toml"));
}

#[test]
fn relative_paths_are_taken_from_the_config_folder() {
    let (dir, config) = install("install-relative", "param_file = \"state/p.toml\"");
    let c = Config::load(&config).unwrap();
    assert_eq!(c.dbc_path, dir.join("vehicle.dbc"));
    assert_eq!(c.calibration.param_file, dir.join("state/p.toml"));
    // The folder is not created for it: a missing one is refused at start.
    assert!(c.check_param_file().is_err());
    std::fs::create_dir(dir.join("state")).unwrap();
    c.check_param_file().unwrap();
    assert!(!dir.join("state/p.toml").exists());
}

#[test]
fn the_unit_keeps_the_calibration_in_its_state_directory() {
    let unit = std::fs::read_to_string(manifest().join("dist/canodom.service")).unwrap();
    assert!(unit.contains("\nStateDirectory=canodom\n"), "{unit}");
    assert!(unit.contains("\nProtectSystem=strict\n"), "{unit}");
    assert!(!unit.contains("example.invalid"), "{unit}");
    // The comment names the real key (`params` is refused as unknown).
    assert!(unit.contains("param_file = \"/var/lib/canodom/"), "{unit}");
    assert!(!unit.contains("params ="), "{unit}");
}

#[test]
fn the_unit_keeps_keys_out_of_core_dumps_and_starts_after_time_sync() {
    // Issue #44: a core dump would carry the keys; the logs and the
    // parameter file's history carry wall-clock times.
    let unit = std::fs::read_to_string(manifest().join("dist/canodom.service")).unwrap();
    for line in [
        "LimitCORE=0",
        "After=time-sync.target",
        "Wants=time-sync.target",
    ] {
        assert!(
            unit.lines().any(|l| l.trim() == line),
            "{line} missing: {unit}"
        );
    }
}

/// Whether a configuration text says it is a keyless bench (an active
/// `allow_without_key = true`, not a comment).
fn is_keyless_bench(text: &str) -> bool {
    text.lines().any(|l| {
        let code = l.split('#').next().unwrap_or("").trim();
        code.replace(' ', "") == "allow_without_key=true"
    })
}

#[test]
fn no_shipped_example_or_preset_is_a_keyless_bench() {
    // Issue #44: a copied example, or a `config init` preset, must not run
    // a vehicle with nothing authenticated.
    let mut checked = 0;
    for entry in std::fs::read_dir(manifest().join("examples")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let text = std::fs::read_to_string(&path).unwrap();
            assert!(!is_keyless_bench(&text), "{}", path.display());
            checked += 1;
        }
    }
    for p in canodom_cars::PLATFORMS {
        assert!(
            !is_keyless_bench(&p.config_text("can0")),
            "config init --car {}",
            p.name
        );
        checked += 1;
    }
    assert!(checked > 10, "{checked}");
    assert!(is_keyless_bench(
        "[security]\nallow_without_key = true   # a bench\n"
    ));
}

/// The README's service recipe for the configuration: the example with its
/// DBC beside it and any bench line deleted (`sed -e '/^allow_without_key = true/d'`,
/// which since issue #44 finds none).
fn service_config(name: &str) -> (PathBuf, PathBuf) {
    let (dir, config) = install(name, "");
    let text = std::fs::read_to_string(&config).unwrap();
    let kept: String = text
        .lines()
        .filter(|l| !l.starts_with("allow_without_key = true"))
        .fold(String::new(), |mut out, l| {
            out.push_str(l);
            out.push('\n');
            out
        });
    assert_eq!(
        kept, text,
        "the example has no active bench line (issue #44)"
    );
    std::fs::write(&config, kept).unwrap();
    (dir, config)
}

/// `canodom run` as the unit starts it: `CREDENTIALS_DIRECTORY` and
/// `STATE_DIRECTORY` set, killed after `secs`.
fn run_as_service(config: &Path, credentials: Option<&Path>, state: &Path, secs: u64) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_canodom"));
    cmd.args(["run", "--config", config.to_str().unwrap()])
        .env("STATE_DIRECTORY", state)
        .env_remove("CREDENTIALS_DIRECTORY")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    if let Some(c) = credentials {
        cmd.env("CREDENTIALS_DIRECTORY", c);
    }
    let start = Instant::now();
    let mut child = cmd.spawn().unwrap();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > Duration::from_secs(secs) {
            child.kill().unwrap();
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    child.wait_with_output().unwrap()
}

#[test]
fn the_unit_hands_the_key_file_over_as_a_credential_and_the_recipe_starts_with_it() {
    use canodom_protocol::secoc_keys::{MasterKey, Party};
    use std::os::unix::fs::PermissionsExt as _;
    let unit = std::fs::read_to_string(manifest().join("dist/canodom.service")).unwrap();
    assert!(
        unit.contains("\nLoadCredential=canodom.keys:/etc/canodom/canodom.keys\n"),
        "{unit}"
    );
    assert!(unit.contains("\nDynamicUser=yes\n"), "{unit}");
    let (dir, config) = service_config("install-credential");
    let state = dir.join("state");
    std::fs::create_dir_all(&state).unwrap();
    // Without the credential the recipe's config is refused at once.
    let out = run_as_service(&config, None, &state, 10);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(
        stderr.contains("LoadCredential") && stderr.contains("key_file"),
        "{stderr}"
    );
    // systemd's layout: a private folder, the file 0400 plus an ACL entry
    // for the service's user, which stat shows as mode 0440.
    let creds = dir.join("credentials");
    std::fs::create_dir_all(&creds).unwrap();
    let key = creds.join("canodom.keys");
    let _ = std::fs::remove_file(&key);
    let master = MasterKey::parse("00112233445566778899aabbccddeeff").unwrap();
    std::fs::write(
        &key,
        master
            .key_file("bench-1", Party::Canodom)
            .unwrap()
            .as_bytes(),
    )
    .unwrap();
    std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o440)).unwrap();
    std::fs::set_permissions(&creds, std::fs::Permissions::from_mode(0o500)).unwrap();
    let out = run_as_service(&config, Some(&creds), &state, 3);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("SecOC keys loaded"), "{stderr}");
    assert!(stderr.contains("bench-1"), "names the vehicle: {stderr}");
    // Past the key, it waits for its interface (none here) until killed.
    assert!(stderr.contains(NO_INTERFACE), "{stderr}");
    // The same file named as key_file, outside the credentials folder, is
    // refused for its group bit.
    std::fs::set_permissions(&creds, std::fs::Permissions::from_mode(0o700)).unwrap();
    let text = std::fs::read_to_string(&config).unwrap()
        + &format!("\n[security]\nkey_file = {:?}\n", key.display().to_string());
    std::fs::write(&config, text).unwrap();
    let out = run_as_service(&config, None, &state, 10);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && stderr.contains("mode 0440"),
        "{stderr}"
    );
}

#[test]
fn the_unit_lets_gpsd_and_ros2_through_on_the_loopback_only() {
    // #46: gpsd on localhost:2947 and ROS 2's UDP need AF_INET; the unit
    // once allowed AF_CAN, AF_UNIX and AF_NETLINK only, and the service
    // could not reach the gpsd the README sets up.
    let unit = std::fs::read_to_string(manifest().join("dist/canodom.service")).unwrap();
    let families = unit
        .lines()
        .find_map(|l| l.strip_prefix("RestrictAddressFamilies="))
        .expect("RestrictAddressFamilies=");
    for family in ["AF_CAN", "AF_UNIX", "AF_NETLINK", "AF_INET", "AF_INET6"] {
        assert!(
            families.split_whitespace().any(|f| f == family),
            "{family} missing: {families}"
        );
    }
    for line in ["IPAddressDeny=any", "IPAddressAllow=localhost"] {
        assert!(unit.lines().any(|l| l.trim() == line), "{line} missing");
    }
    // The README's drop-ins name what the unit leaves closed.
    let readme = std::fs::read_to_string(manifest().join("../README.md")).unwrap();
    for needle in [
        "IPAddressAllow=",
        "DeviceAllow=",
        "SupplementaryGroups=dialout",
    ] {
        assert!(readme.contains(needle), "README lacks {needle}");
    }
}
