//! Tests of the configuration (`super`): the examples load, every key
//! reaches its field in its unit, and every refusal names the file, the
//! key and what was expected.

use super::*;
use canodom_dbc::Checksum;

pub(crate) const RC_CAR: &str = r#"
[can]
interface = "vcan0"
dbc = "rc_car.dbc"

[vehicle]
wheelbase_m = 0.26
rear_tread_m = 0.30
front_tread_m = 0.30
wheel_diameter_m = 0.09
encoder_ticks_per_rev = 1024

[signals]
rear_left = "WHEEL_ENC_REAR.RL_TICKS"
rear_right = "WHEEL_ENC_REAR.RR_TICKS"
front_left = "WHEEL_ENC_FRONT.FL_TICKS"
front_right = "WHEEL_ENC_FRONT.FR_TICKS"
steering = "STEERING.STEER_ANGLE"
wheel_kind = "ticks"
steering_kind = "road_wheel"

[checks.WHEEL_ENC_REAR]
counter = "COUNTER"
checksum = "CHECKSUM"
algorithm = "crc8_sae_j1850"
"#;

fn path() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../data/dbc/x.toml"))
}

#[test]
fn issue_example_loads() {
    let c = Config::from_toml(RC_CAR, &path()).unwrap();
    assert_eq!(c.interface, "vcan0");
    assert_eq!(c.signals.wheel_kind, WheelKind::Ticks);
    assert_eq!(c.signals.tick_bits, 16);
    assert_eq!(c.checks.len(), 1);
    let crc = c.checks[0].checksum.as_ref().unwrap();
    assert_eq!(crc, &FrameChecksum::Bytes(Checksum::rc_car()));
    assert!((c.params.steering().gain - 1f64.to_radians()).abs() < 1e-15);
    assert_eq!(c.output.pose_rate_hz, 50.0);
    assert_eq!(c.ekf, EkfConfig::new(c.params));
    assert_eq!(c.input_ids().len(), 3);
}

#[test]
fn ekf_and_output_keys_reach_the_typed_config() {
    let text = format!(
        "{RC_CAR}\n[ekf]\nk_rear_m = 2e-5\nsteer_sigma_deg = 1.0\ncorrect_every = 20\n\
         gate_enabled = false\nlearn_steer_offset = false\n\
         [output]\nbase_id = 0x18FF0000\nextended = true\npose_rate_hz = 10.0\n\
         [inputs]\ntimeout_factor = 5.0\ntrusted_after_frames = 2\n"
    );
    let c = Config::from_toml(&text, &path()).unwrap();
    assert_eq!(c.ekf.k_rear_m, 2e-5);
    assert!((c.ekf.steer_sigma_rad - 1f64.to_radians()).abs() < 1e-15);
    assert_eq!(c.ekf.correct_every, 20);
    assert_eq!(c.ekf.gate_threshold, None);
    assert_eq!(c.ekf.steer_offset_drift_rad, None);
    assert_eq!(
        c.output.base_id.id(),
        canodom_can::frame::FrameId::Extended(0x18FF_0000)
    );
    assert_eq!(c.output.pose_rate_hz, 10.0);
    assert_eq!(c.inputs.timeout_factor, 5.0);
    assert_eq!(c.inputs.trusted_after_frames, 2);
    assert_eq!(c.inputs.max_wheel_speed_mps, 5.0);
}

/// The RAV4 configuration with a yaw-rate sensor, and `extra` appended.
fn rav4_yaw(extra: &str) -> Result<Config, ConfigError> {
    let file = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../data/comma2k19-rav4/config_yaw.toml"
    ));
    let text = std::fs::read_to_string(&file).unwrap();
    assert!(
        !text.contains("[ekf]"),
        "config_yaw.toml grew an [ekf] table"
    );
    Config::from_toml(&format!("{text}\n{extra}"), &file)
}

#[test]
fn an_empty_ekf_table_is_the_filters_default_with_the_dbcs_yaw_quantum() {
    let c = rav4_yaw("[ekf]\n").unwrap();
    // KINEMATICS.YAW_RATE counts in 0.244 deg/s steps.
    let quantum = 0.244f64.to_radians();
    assert!((c.ekf.yaw_quantum_radps - quantum).abs() < 1e-15);
    let want = EkfConfig {
        yaw_quantum_radps: c.ekf.yaw_quantum_radps,
        ..EkfConfig::new(c.params)
    };
    assert_eq!(c.ekf, want);
    assert_eq!(rav4_yaw("").unwrap().ekf, want);
}

#[test]
fn the_slide_keys_reach_their_fields_and_a_zero_deceleration_is_refused() {
    let c = rav4_yaw(
        "[ekf]\nmax_accel_mps2 = 10.0\nslide_decel_mps2 = 5.0\nslide_decel_sigma_mps2 = 1.5\n",
    )
    .unwrap();
    assert_eq!(c.ekf.max_accel_mps2, 10.0);
    assert_eq!(c.ekf.slide_decel_mps2, 5.0);
    assert_eq!(c.ekf.slide_decel_sigma_mps2, 1.5);
    let d = EkfConfig::new(c.params);
    assert_ne!(d.max_accel_mps2, 10.0);
    assert_ne!(d.slide_decel_mps2, 5.0);
    assert_ne!(d.slide_decel_sigma_mps2, 1.5);
    for bad in [
        "slide_decel_mps2 = 0.0",
        "max_accel_mps2 = -1.0",
        "slide_decel_sigma_mps2 = -0.5",
    ] {
        let e = rav4_yaw(&format!("[ekf]\n{bad}\n"))
            .unwrap_err()
            .to_string();
        let key = bad.split(' ').next().unwrap();
        assert!(e.contains(&format!("ekf.{key}")), "{bad}: {e}");
    }
}

#[test]
fn every_ekf_key_reaches_its_field_in_its_unit() {
    use canodom_fusion::ekf::GateAction;
    let c = rav4_yaw(
        "[ekf]\nfront_scale_sigma = 0.02\nmin_slip_ratio = 0.1\nblend_accepted = true\nlearn_wheel_scales = false\n\
         gate_action = \"keep_rear\"\nyaw_gate_sigma = 4.0\nyaw_sigma_deg_s = 0.2\n\
         yaw_bias_walk_deg_s_per_sqrt_s = 0.001\nyaw_bias_sigma_deg_s = 0.3\n\
         yaw_scale_sigma = 0.01\nrear_ratio_sigma = 0.002\nratio_walk = 1e-4\n\
         tread_sigma = 0.04\ntread_turn_sigma = 0.03\nwheel_turn_sigma_deg = 0.02\n\
         distance_scale_sigma = 0.004\nstill_min_s = 3.0\naided_window_s = 1.0\n\
         steer_offset_drift_deg = 0.01\nfront_scale_drift = 1e-4\n",
    )
    .unwrap();
    let e = c.ekf;
    let deg = f64::to_radians;
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-15 * b.abs();
    assert_eq!(e.front_scale_sigma, 0.02);
    assert_eq!(e.min_slip_ratio, 0.1);
    assert!(e.blend_accepted);
    assert!(!e.learn_wheel_scales);
    assert_eq!(e.gate_action, GateAction::KeepRear);
    assert_eq!(e.yaw_gate_sigma, 4.0);
    assert!(close(e.yaw_sigma_radps, deg(0.2)));
    assert!(close(e.yaw_bias_walk_radps, deg(0.001)));
    assert!(close(e.yaw_bias_sigma_radps, deg(0.3)));
    assert_eq!(e.yaw_scale_sigma, 0.01);
    assert_eq!(e.rear_ratio_sigma, 0.002);
    assert_eq!(e.ratio_walk, 1e-4);
    assert_eq!(e.tread_sigma, 0.04);
    assert_eq!(e.tread_turn_sigma, 0.03);
    assert!(close(e.wheel_turn_sigma_rad, deg(0.02)));
    assert_eq!(e.distance_scale_sigma, 0.004);
    assert_eq!(e.still_min_s, 3.0);
    assert_eq!(e.aided_window_s, 1.0);
    assert!(close(e.steer_offset_drift_rad.unwrap(), deg(0.01)));
    assert_eq!(e.front_scale_drift, Some(1e-4));
    // Every key set differs from its default: none was silently dropped.
    let d = EkfConfig::new(c.params);
    for (name, set, default) in [
        (
            "front_scale_sigma",
            e.front_scale_sigma,
            d.front_scale_sigma,
        ),
        ("min_slip_ratio", e.min_slip_ratio, d.min_slip_ratio),
        ("yaw_gate_sigma", e.yaw_gate_sigma, d.yaw_gate_sigma),
        ("yaw_sigma", e.yaw_sigma_radps, d.yaw_sigma_radps),
        (
            "yaw_bias_walk",
            e.yaw_bias_walk_radps,
            d.yaw_bias_walk_radps,
        ),
        (
            "yaw_bias_sigma",
            e.yaw_bias_sigma_radps,
            d.yaw_bias_sigma_radps,
        ),
        ("yaw_scale_sigma", e.yaw_scale_sigma, d.yaw_scale_sigma),
        ("rear_ratio_sigma", e.rear_ratio_sigma, d.rear_ratio_sigma),
        ("ratio_walk", e.ratio_walk, d.ratio_walk),
        ("tread_sigma", e.tread_sigma, d.tread_sigma),
        ("tread_turn_sigma", e.tread_turn_sigma, d.tread_turn_sigma),
        (
            "wheel_turn_sigma",
            e.wheel_turn_sigma_rad,
            d.wheel_turn_sigma_rad,
        ),
        (
            "distance_scale_sigma",
            e.distance_scale_sigma,
            d.distance_scale_sigma,
        ),
        ("still_min_s", e.still_min_s, d.still_min_s),
        ("aided_window_s", e.aided_window_s, d.aided_window_s),
    ] {
        assert_ne!(set, default, "{name}");
    }
}

#[test]
fn bad_ekf_values_are_named_with_what_was_expected() {
    for (line, key, expected) in [
        ("yaw_sigma_deg_s = 0.0", "ekf.yaw_sigma_deg_s", "> 0"),
        ("tread_sigma = -0.1", "ekf.tread_sigma", "> 0"),
        ("aided_window_s = nan", "ekf.aided_window_s", "> 0"),
        ("min_slip_ratio = -0.05", "ekf.min_slip_ratio", ">= 0"),
        ("still_min_s = inf", "ekf.still_min_s", ">= 0"),
        (
            "yaw_bias_walk_deg_s_per_sqrt_s = -1e-3",
            "ekf.yaw_bias_walk_deg_s_per_sqrt_s",
            ">= 0",
        ),
        ("yaw_gate_sigma = 0", "ekf.yaw_gate_sigma", "> 0"),
        ("gate_action = \"front\"", "ekf.gate_action", "keep_rear"),
        ("front_scale_drift = -1.0", "ekf.front_scale_drift", ">= 0"),
        (
            "learn_steer_offset = false\nsteer_offset_drift_deg = 0.01",
            "ekf.steer_offset_drift_deg",
            "learn_steer_offset = false",
        ),
    ] {
        let e = rav4_yaw(&format!("[ekf]\n{line}\n"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("config_yaw.toml") && e.contains(key) && e.contains(expected),
            "{line}: {e}"
        );
    }
    // A key with its unit missing is an unknown key, named.
    let e = rav4_yaw("[ekf]\nyaw_sigma = 0.2\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("yaw_sigma"), "{e}");
}

fn invalid(text: &str) -> String {
    let e = Config::from_toml(text, &path()).unwrap_err();
    let s = e.to_string();
    assert!(s.contains("x.toml"), "{s}");
    s
}

#[test]
fn unknown_key_is_named() {
    let s = invalid(&RC_CAR.replace("wheelbase_m", "wheelbase_mm"));
    assert!(s.contains("wheelbase_mm"), "{s}");
    let s = invalid(&format!("{RC_CAR}\n[output]\npose_rate = 5\n"));
    assert!(s.contains("pose_rate"), "{s}");
}

#[test]
fn missing_signal_is_named() {
    let s = invalid(&RC_CAR.replace("RR_TICKS", "RR_TICK"));
    assert!(
        s.contains("signals.rear_right") && s.contains("RR_TICK"),
        "{s}"
    );
}

#[test]
fn bad_values_are_named() {
    let s = invalid(&RC_CAR.replace("0.26", "-1.0"));
    assert!(
        s.contains("vehicle.wheelbase_m") && s.contains("> 0"),
        "{s}"
    );
    let s = invalid(&RC_CAR.replace("\"ticks\"", "\"pulses\""));
    assert!(s.contains("signals.wheel_kind"), "{s}");
    // A missing kind is named with the values it takes (it was a TOML
    // parse error without them).
    let s = invalid(&RC_CAR.replace("wheel_kind = \"ticks\"\n", ""));
    assert!(
        s.contains("signals.wheel_kind") && s.contains("\"speed\"") && s.contains("nothing"),
        "{s}"
    );
    // Tick encoders need the diameter (speed signals do not: the daemon's
    // config_errors test loads the Toyota example without it).
    assert!(RC_CAR.contains("wheel_diameter_m = 0.09\n"));
    let s = invalid(&RC_CAR.replace("wheel_diameter_m = 0.09\n", ""));
    assert!(
        s.contains("vehicle.wheel_diameter_m") && s.contains("tick encoders count revolutions"),
        "{s}"
    );
    let s = invalid(&RC_CAR.replace("steering_kind = \"road_wheel\"\n", ""));
    assert!(
        s.contains("signals.steering_kind") && s.contains("\"steering_wheel\""),
        "{s}"
    );
    let s = invalid(&RC_CAR.replace("crc8_sae_j1850", "crc32"));
    assert!(s.contains("checks.WHEEL_ENC_REAR.algorithm"), "{s}");
    let s = invalid(&RC_CAR.replace("rc_car.dbc", "nope.dbc"));
    assert!(s.contains("can.dbc"), "{s}");
    let s = invalid(&RC_CAR.replace("road_wheel", "steering_wheel"));
    assert!(s.contains("vehicle.steering_ratio"), "{s}");
    let s = invalid(&format!("{RC_CAR}\n[output]\nbase_id = 0x100\n"));
    assert!(s.contains("output.base_id"), "{s}");
    let s = invalid(&format!("{RC_CAR}\n[calibration]\nparam_file = \"\"\n"));
    assert!(s.contains("calibration.param_file"), "{s}");
}

#[test]
fn param_file_defaults_to_the_state_directory_under_systemd() {
    let config = Path::new("/etc/canodom/canodom.toml");
    let state = |s: &str| default_param_file(config, Some(OsStr::new(s)));
    assert_eq!(
        state("/var/lib/canodom"),
        Path::new("/var/lib/canodom/canodom-params.toml")
    );
    // Several StateDirectory= entries: the first is canodom's.
    assert_eq!(
        state("/var/lib/canodom:/var/lib/other"),
        Path::new("/var/lib/canodom/canodom-params.toml")
    );
    // Without systemd (or an empty variable): beside the configuration.
    let beside_config = Path::new("/etc/canodom/canodom-params.toml");
    assert_eq!(state(""), beside_config);
    assert_eq!(default_param_file(config, None), beside_config);
    assert_eq!(
        default_param_file(Path::new("car.toml"), None),
        Path::new("canodom-params.toml")
    );
}

#[test]
fn relative_paths_are_taken_from_the_configuration_folder() {
    let dir = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../data/dbc"));
    let c = Config::from_toml(
        &format!("{RC_CAR}\n[calibration]\nparam_file = \"../state/p.toml\"\n"),
        &path(),
    )
    .unwrap();
    assert_eq!(c.dbc_path, dir.join("rc_car.dbc"));
    assert_eq!(c.calibration.param_file, dir.join("../state/p.toml"));
    let c = Config::from_toml(
        &format!("{RC_CAR}\n[calibration]\nparam_file = \"/var/lib/x/p.toml\"\n"),
        &path(),
    )
    .unwrap();
    assert_eq!(c.calibration.param_file, Path::new("/var/lib/x/p.toml"));
}

fn scratch(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("canodom-config-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn with_param_file(param_file: &Path) -> Config {
    let mut c = Config::from_toml(RC_CAR, &path()).unwrap();
    c.calibration.param_file = param_file.to_owned();
    c
}

#[test]
fn param_file_check_leaves_an_existing_file_and_no_probe() {
    let dir = scratch("probe-ok");
    let file = dir.join("p.toml");
    with_param_file(&file).check_param_file().unwrap();
    assert!(!file.exists(), "the check creates no parameter file");
    std::fs::write(&file, "kept").unwrap();
    with_param_file(&file).check_param_file().unwrap();
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "kept");
    let left: Vec<_> = std::fs::read_dir(&dir).unwrap().collect();
    assert_eq!(left.len(), 1, "only the parameter file: {left:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn param_file_check_names_key_path_and_one_os_reason() {
    let dir = scratch("probe-bad");
    // A file where a folder should be: refused even for root.
    std::fs::write(dir.join("not-a-folder"), "").unwrap();
    for file in [
        dir.join("not-a-folder/p.toml"),
        dir.join("missing/p.toml"),
        dir,
    ] {
        let e = with_param_file(&file).check_param_file().unwrap_err();
        assert!(matches!(e, ConfigError::ParamFile { .. }), "{e:?}");
        let s = e.to_string();
        assert!(s.contains("x.toml"), "{s}");
        assert!(s.contains("calibration.param_file"), "{s}");
        assert!(s.contains(&file.display().to_string()), "{s}");
        assert_eq!(s.matches("(os error").count(), 1, "{s}");
        assert!(std::error::Error::source(&e).is_none(), "printed once: {s}");
    }
}

#[test]
fn the_ros2_section_is_kept_as_written_for_the_ros2_crate() {
    // #43: pipeline does not read `[ros2]` (canodom-ros2 does), but must not
    // refuse it as an unknown section.
    let c = Config::from_toml(RC_CAR, &path()).unwrap();
    assert_eq!(c.ros2, None);
    let text = format!("{RC_CAR}\n[ros2]\nenabled = true\ndomain_id = 7\n");
    let c = Config::from_toml(&text, &path()).unwrap();
    let section = c.ros2.unwrap();
    assert_eq!(section["enabled"].as_bool(), Some(true));
    assert_eq!(section["domain_id"].as_integer(), Some(7));
}

#[test]
fn the_gnss_section_is_off_unless_written_and_fills_its_defaults() {
    let c = Config::from_toml(RC_CAR, &path()).unwrap();
    assert_eq!(c.gnss, None);
    let c = Config::from_toml(&format!("{RC_CAR}\n[gnss]\nsource = \"gpsd\"\n"), &path()).unwrap();
    assert_eq!(
        c.gnss,
        Some(GnssConfig {
            source: GnssSource::Gpsd {
                address: DEFAULT_GPSD_ADDRESS.to_owned()
            },
            max_error_m: DEFAULT_MAX_ERROR_M,
        })
    );
    let text = format!(
        "{RC_CAR}\n[gnss]\nsource = \"gpsd\"\naddress = \"[::1]:2948\"\nmax_error_m = 30.5\n"
    );
    let c = Config::from_toml(&text, &path()).unwrap();
    assert_eq!(
        c.gnss,
        Some(GnssConfig {
            source: GnssSource::Gpsd {
                address: "[::1]:2948".to_owned()
            },
            max_error_m: 30.5,
        })
    );
    let text = format!("{RC_CAR}\n[gnss]\nsource = \"ros2\"\ntopic = \"/gnss/fix\"\n");
    let c = Config::from_toml(&text, &path()).unwrap();
    assert_eq!(
        c.gnss,
        Some(GnssConfig {
            source: GnssSource::Ros2 {
                topic: "/gnss/fix".to_owned()
            },
            max_error_m: DEFAULT_MAX_ERROR_M,
        })
    );
    let text = format!("{RC_CAR}\n[gnss]\nsource = \"nmea\"\ndevice = \"/dev/ttyACM0\"\n");
    let c = Config::from_toml(&text, &path()).unwrap();
    assert_eq!(
        c.gnss,
        Some(GnssConfig {
            source: GnssSource::Nmea {
                device: "/dev/ttyACM0".into(),
                baud: None,
            },
            max_error_m: DEFAULT_NMEA_MAX_ERROR_M,
        })
    );
    let text = format!(
        "{RC_CAR}\n[gnss]\nsource = \"nmea\"\ndevice = \"/dev/serial/by-id/usb-u-blox\"\nbaud = 38400\n"
    );
    let c = Config::from_toml(&text, &path()).unwrap();
    assert_eq!(
        c.gnss.map(|g| g.source),
        Some(GnssSource::Nmea {
            device: "/dev/serial/by-id/usb-u-blox".into(),
            baud: Some(38_400),
        })
    );
}

#[test]
fn every_bad_gnss_key_is_named() {
    for (section, key, expected) in [
        (
            "source = \"serial\"",
            "gnss.source",
            "\"nmea\" (a serial receiver)",
        ),
        ("source = \"nmea\"", "gnss.device", "/dev/ttyACM0"),
        (
            "source = \"nmea\"\ndevice = \"ttyACM0\"",
            "gnss.device",
            "absolute path",
        ),
        (
            "source = \"nmea\"\ndevice = \"/dev/ttyACM0\"\nbaud = 9601",
            "gnss.baud",
            "9600",
        ),
        (
            "source = \"nmea\"\ndevice = \"/dev/ttyACM0\"\naddress = \"a:1\"",
            "gnss.address",
            "source = \"gpsd\"",
        ),
        (
            "source = \"gpsd\"\nbaud = 9600",
            "gnss.baud",
            "source = \"nmea\"",
        ),
        (
            "source = \"ros2\"\ntopic = \"/fix\"\ndevice = \"/dev/ttyUSB0\"",
            "gnss.device",
            "source = \"nmea\"",
        ),
        (
            "source = \"nmea\"\ndevice = \"/dev/ttyACM0\"\nmax_error_m = 0.0",
            "gnss.max_error_m",
            "> 0",
        ),
        (
            "source = \"gpsd\"\naddress = \"localhost\"",
            "gnss.address",
            "HOST:PORT",
        ),
        (
            "source = \"gpsd\"\naddress = \":2947\"",
            "gnss.address",
            "HOST:PORT",
        ),
        (
            "source = \"gpsd\"\naddress = \"gps:0\"",
            "gnss.address",
            "HOST:PORT",
        ),
        (
            "source = \"gpsd\"\ntopic = \"/fix\"",
            "gnss.topic",
            "source = \"ros2\"",
        ),
        (
            "source = \"gpsd\"\nmax_error_m = 0.0",
            "gnss.max_error_m",
            "> 0",
        ),
        (
            "source = \"gpsd\"\nmax_error_m = nan",
            "gnss.max_error_m",
            "> 0",
        ),
        ("source = \"ros2\"", "gnss.topic", "NavSatFix"),
        (
            "source = \"ros2\"\ntopic = \"/9fix\"",
            "gnss.topic",
            "NavSatFix",
        ),
        (
            "source = \"ros2\"\ntopic = \"/fix\"\naddress = \"a:1\"",
            "gnss.address",
            "source = \"gpsd\"",
        ),
        (
            "source = \"ros2\"\ntopic = \"/fix\"\nmax_error_m = -3.0",
            "gnss.max_error_m",
            "> 0",
        ),
    ] {
        let e = invalid(&format!("{RC_CAR}\n[gnss]\n{section}\n"));
        assert!(e.contains(&format!("key `{key}`")), "{section}: {e}");
        assert!(e.contains(expected), "{section}: {e}");
        assert!(e.contains("x.toml"), "{section}: {e}");
    }
    // Unknown keys and a missing source are toml's to name.
    let e = invalid(&format!(
        "{RC_CAR}\n[gnss]\nsource = \"gpsd\"\nport = 2947\n"
    ));
    assert!(e.contains("port"), "{e}");
    let e = invalid(&format!("{RC_CAR}\n[gnss]\naddress = \"a:1\"\n"));
    assert!(e.contains("source"), "{e}");
}

#[test]
fn the_drift_watch_keys_reach_their_fields_in_their_units() {
    use canodom_calib::drift::Param;
    let text = format!(
        "{RC_CAR}\n[calibration.drift]\nk_sigma = 5.0\nyaw_bias_tol_dps = 0.1\nrear_ratio_tol_rel = 0.003\nsteer_offset_tol_deg = 0.5\nfront_ratio_tol_rel = 0.004\nevery_s = 30.0\nwindow_s = 300.0\n"
    );
    let c = Config::from_toml(&text, &path()).unwrap();
    let d = c.calibration.drift;
    assert_eq!(d.judge.k_sigma, 5.0);
    assert!((d.judge.tolerance(Param::YawBias) - 0.1f64.to_radians()).abs() < 1e-15);
    assert!((d.judge.tolerance(Param::SteerOffset) - 0.5f64.to_radians()).abs() < 1e-15);
    assert_eq!(d.judge.tolerance(Param::RearRatio), 0.003);
    assert_eq!(d.judge.tolerance(Param::FrontRatio), 0.004);
    // The others keep their defaults.
    let default = DriftWatchConfig::default();
    assert_eq!(
        d.judge.tolerance(Param::SpeedScale),
        default.judge.tolerance(Param::SpeedScale)
    );
    assert_eq!((d.every_s, d.window_s), (30.0, 300.0));
    assert_eq!(
        Config::from_toml(RC_CAR, &path())
            .unwrap()
            .calibration
            .drift,
        default
    );
}

#[test]
fn auto_commit_is_off_unless_set_and_must_be_a_bool() {
    let c = Config::from_toml(RC_CAR, &path()).unwrap();
    assert!(!c.calibration.auto_commit);
    let text = format!("{RC_CAR}\n[calibration]\nauto_commit = true\n");
    let c = Config::from_toml(&text, &path()).unwrap();
    assert!(c.calibration.auto_commit);
    let text = format!("{RC_CAR}\n[calibration]\nauto_commit = 1\n");
    let e = Config::from_toml(&text, &path()).unwrap_err().to_string();
    assert!(e.contains("auto_commit"), "{e}");
}

#[test]
fn every_bad_drift_key_is_named() {
    for (line, key, expected) in [
        ("k_sigma = 0.0", "calibration.drift.k_sigma", "> 0"),
        (
            "speed_scale_tol_rel = -0.002",
            "calibration.drift.speed_scale_tol_rel",
            "> 0",
        ),
        (
            "rear_ratio_tol_rel = nan",
            "calibration.drift.rear_ratio_tol_rel",
            "> 0",
        ),
        (
            "rear_tread_tol_rel = 0.0",
            "calibration.drift.rear_tread_tol_rel",
            "> 0",
        ),
        (
            "steer_gain_tol_rel = inf",
            "calibration.drift.steer_gain_tol_rel",
            "> 0",
        ),
        (
            "steer_offset_tol_deg = -1.0",
            "calibration.drift.steer_offset_tol_deg",
            "> 0",
        ),
        (
            "yaw_bias_tol_dps = 0.0",
            "calibration.drift.yaw_bias_tol_dps",
            "> 0",
        ),
        (
            "yaw_scale_tol_rel = -0.1",
            "calibration.drift.yaw_scale_tol_rel",
            "> 0",
        ),
        (
            "front_ratio_tol_rel = 0.0",
            "calibration.drift.front_ratio_tol_rel",
            "> 0",
        ),
        ("every_s = 0.0", "calibration.drift.every_s", "> 0"),
        ("window_s = -5.0", "calibration.drift.window_s", "> 0"),
        (
            "window_s = 100.0",
            "calibration.drift.window_s",
            "twice calibration.drift.every_s",
        ),
    ] {
        let e = invalid(&format!("{RC_CAR}\n[calibration.drift]\n{line}\n"));
        assert!(e.contains(&format!("key `{key}`")), "{line}: {e}");
        assert!(e.contains(expected), "{line}: {e}");
    }
    let e = invalid(&format!("{RC_CAR}\n[calibration.drift]\nk = 3.0\n"));
    assert!(e.contains("k_sigma"), "{e}");
}
