//! Configuration errors name the file, the key and what was expected.

use canodom_pipeline::config::Config;

fn error_for(edit: impl Fn(String) -> String) -> String {
    let path = crate::util::rc_car_toml();
    let text = edit(std::fs::read_to_string(&path).unwrap());
    let err = Config::from_toml(&text, &path).unwrap_err().to_string();
    assert!(err.contains("rc_car.toml"), "names the file: {err}");
    err
}

#[test]
fn both_shipped_examples_load() {
    let rc = crate::util::rc_car();
    assert_eq!(rc.checks.len(), 3);
    let toyota = Config::load(&crate::util::toyota_toml()).unwrap();
    assert!(toyota.signals.steering.form.fine.is_some());
    assert_eq!(toyota.output.base_id.id().raw(), 0x6A0);
    // Steering-wheel degrees through a ratio of 15.
    let gain = toyota.params.steering().gain;
    assert!((gain - 1f64.to_radians() / 15.0).abs() < 1e-15);
}

#[test]
fn unknown_key_names_key_and_expected_keys() {
    let e = error_for(|t| t.replace("pose_rate_hz", "pose_rate"));
    assert!(e.contains("pose_rate") && e.contains("pose_rate_hz"), "{e}");
}

#[test]
fn unknown_section_is_refused() {
    let e = error_for(|t| format!("{t}\n[calibrate]\nx = 1\n"));
    assert!(e.contains("calibrate"), "{e}");
}

#[test]
fn wrong_type_names_the_key() {
    let e = error_for(|t| t.replace("wheelbase_m = 0.26", "wheelbase_m = \"long\""));
    assert!(e.contains("wheelbase_m"), "{e}");
}

#[test]
fn signal_missing_from_the_dbc() {
    let e = error_for(|t| t.replace("STEERING.STEER_ANGLE", "STEERING.ANGLE"));
    assert!(
        e.contains("signals.steering") && e.contains("STEERING.ANGLE"),
        "{e}"
    );
}

#[test]
fn check_on_a_missing_message_or_signal() {
    let e = error_for(|t| t.replace("[checks.STEERING]", "[checks.STEERIN]"));
    assert!(e.contains("checks.STEERIN"), "{e}");
    let e = error_for(|t| t.replacen("counter = \"COUNTER\"", "counter = \"CTR\"", 1));
    assert!(e.contains("checks.WHEEL_ENC_REAR.counter"), "{e}");
}

#[test]
fn speed_kind_on_tick_signals_needs_a_speed_unit() {
    let e = error_for(|t| t.replace("wheel_kind = \"ticks\"", "wheel_kind = \"speed\""));
    assert!(e.contains("signals.rear_left") && e.contains("km/h"), "{e}");
}

#[test]
fn out_of_range_values() {
    let e = error_for(|t| t.replace("pose_rate_hz = 50.0", "pose_rate_hz = 0.0"));
    assert!(
        e.contains("output.pose_rate_hz") && e.contains("> 0"),
        "{e}"
    );
    let e = error_for(|t| t.replace("timeout_factor = 3.0", "timeout_factor = 0.5"));
    assert!(e.contains("inputs.timeout_factor"), "{e}");
    let e = error_for(|t| t.replace("interface = \"vcan0\"", "interface = \"a/b\""));
    assert!(e.contains("can.interface"), "{e}");
}

#[test]
fn yaw_rate_signal_takes_its_unit_from_the_dbc_and_its_sign_from_the_config() {
    let path = crate::util::toyota_toml();
    // The example reads the gyro; each case below writes its own line.
    let text = std::fs::read_to_string(&path)
        .unwrap()
        .replace("yaw_rate = \"KINEMATICS.YAW_RATE\"\n", "");
    let with = |extra: &str| {
        let t = text.replace(
            "steering_kind = \"steering_wheel\"",
            &format!("steering_kind = \"steering_wheel\"\n{extra}"),
        );
        Config::from_toml(&t, &path)
    };
    // KINEMATICS.YAW_RATE is in deg/s: one unit is π/180 rad/s.
    let c = with("yaw_rate = \"KINEMATICS.YAW_RATE\"").unwrap();
    let y = c.signals.yaw_rate.unwrap();
    assert!((y.radps_per_unit - 1f64.to_radians()).abs() < 1e-15);
    let c = with("yaw_rate = \"KINEMATICS.YAW_RATE\"\nyaw_rate_sign = -1").unwrap();
    assert!((c.signals.yaw_rate.unwrap().radps_per_unit + 1f64.to_radians()).abs() < 1e-15);
    let e = with("yaw_rate = \"KINEMATICS.YAW_RATE\"\nyaw_rate_sign = 2")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("signals.yaw_rate_sign") && e.contains("-1"),
        "{e}"
    );
    // ACCEL_Y is in m/s^2, not a rate.
    let e = with("yaw_rate = \"KINEMATICS.ACCEL_Y\"")
        .unwrap_err()
        .to_string();
    assert!(e.contains("signals.yaw_rate") && e.contains("deg/s"), "{e}");
    let e = with("yaw_rate_sign = 1").unwrap_err().to_string();
    assert!(e.contains("signals.yaw_rate_sign"), "{e}");
    assert!(
        Config::from_toml(&text, &path)
            .unwrap()
            .signals
            .yaw_rate
            .is_none()
    );
    assert!(Config::load(&path).unwrap().signals.yaw_rate.is_some());
}

#[test]
fn calibration_fixes_name_two_signals_of_one_message() {
    let path = crate::util::toyota_toml();
    // KINEMATICS stands in for a GNSS message here: without the example's
    // gyro, which reads it (a fixes message must not be an odometry input).
    let text = std::fs::read_to_string(&path)
        .unwrap()
        .replace("yaw_rate = \"KINEMATICS.YAW_RATE\"\n", "");
    let with =
        |table: &str| Config::from_toml(&format!("{text}\n[calibration.fixes]\n{table}\n"), &path);
    // Any two signals of one message stand in for a GNSS message here.
    let c = with("x = \"KINEMATICS.ACCEL_X\"\ny = \"KINEMATICS.ACCEL_Y\"").unwrap();
    let f = c.calibration.fixes.unwrap();
    assert!(!f.geodetic);
    let c = with("latitude = \"KINEMATICS.ACCEL_X\"\nlongitude = \"KINEMATICS.ACCEL_Y\"").unwrap();
    assert!(c.calibration.fixes.unwrap().geodetic);
    let e = with("x = \"KINEMATICS.ACCEL_X\"\nlongitude = \"KINEMATICS.ACCEL_Y\"")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("calibration.fixes") && e.contains("latitude"),
        "{e}"
    );
    let e = with("x = \"KINEMATICS.ACCEL_X\"\ny = \"WHEEL_SPEEDS.WHEEL_SPEED_FL\"")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("calibration.fixes.y") && e.contains("same message"),
        "{e}"
    );
    let e = with("x = \"GNSS.X\"\ny = \"GNSS.Y\"")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("calibration.fixes.x") && e.contains("GNSS.X"),
        "{e}"
    );
    let e = with("x = \"WHEEL_SPEEDS.WHEEL_SPEED_FL\"\ny = \"WHEEL_SPEEDS.WHEEL_SPEED_FR\"")
        .unwrap_err()
        .to_string();
    assert!(e.contains("not an odometry input"), "{e}");
    assert!(Config::load(&path).unwrap().calibration.fixes.is_none());
}

/// The examples document every `[ekf]` key commented out with its default:
/// uncommented, the block must give the filter's defaults (the degree values
/// are written to six digits), and it must name every key the table takes.
#[test]
fn the_examples_ekf_blocks_state_the_defaults() {
    use canodom_fusion::ekf::EkfConfig;
    for path in [crate::util::rc_car_toml(), crate::util::toyota_toml()] {
        let text = std::fs::read_to_string(&path).unwrap();
        let start = text
            .find("\n# [ekf]\n")
            .unwrap_or_else(|| panic!("{}: no commented [ekf] block", path.display()));
        let block: Vec<&str> = text[start + 1..]
            .lines()
            .take_while(|l| l.starts_with('#'))
            .filter_map(|l| l.strip_prefix("# "))
            .filter(|l| !l.starts_with(' ') && (l.starts_with("[ekf]") || l.contains(" = ")))
            .collect();
        let keys: Vec<&str> = block
            .iter()
            .filter_map(|l| l.split_once(" = ").map(|(k, _)| k))
            .collect();
        let uncommented = format!("{}\n{}\n", text, block.join("\n"));
        let config = Config::from_toml(&uncommented, &path).unwrap();
        let defaults = Config::load(&path).unwrap().ekf;
        let e = &config.ekf;
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-5 * b.abs();
        assert!(close(e.yaw_sigma_radps, defaults.yaw_sigma_radps));
        assert!(close(e.yaw_bias_walk_radps, defaults.yaw_bias_walk_radps));
        assert!(close(e.wheel_turn_sigma_rad, defaults.wheel_turn_sigma_rad));
        assert!(close(
            e.steer_offset_drift_rad.unwrap(),
            defaults.steer_offset_drift_rad.unwrap()
        ));
        // front_scale_drift is shown with a value to set; unset it is off.
        assert_eq!(defaults.front_scale_drift, None);
        let same = EkfConfig {
            yaw_sigma_radps: defaults.yaw_sigma_radps,
            yaw_bias_walk_radps: defaults.yaw_bias_walk_radps,
            wheel_turn_sigma_rad: defaults.wheel_turn_sigma_rad,
            steer_offset_drift_rad: defaults.steer_offset_drift_rad,
            front_scale_drift: None,
            steer_sigma_rad: defaults.steer_sigma_rad,
            steer_bias_sigma_rad: defaults.steer_bias_sigma_rad,
            yaw_bias_sigma_radps: defaults.yaw_bias_sigma_radps,
            ..*e
        };
        assert_eq!(same, defaults, "{}", path.display());
        assert!(close(e.steer_sigma_rad, defaults.steer_sigma_rad));
        assert!(close(e.yaw_bias_sigma_radps, defaults.yaw_bias_sigma_radps));
        // Every key of the table is documented.
        for key in [
            "k_rear_m",
            "k_front_m",
            "steer_sigma_deg",
            "steer_bias_sigma_deg",
            "front_scale_sigma",
            "correct_every",
            "gate_enabled",
            "gate_threshold",
            "gate_action",
            "min_slip_ratio",
            "blend_accepted",
            "learn_steer_offset",
            "steer_offset_drift_deg",
            "front_scale_drift",
            "yaw_sigma_deg_s",
            "yaw_bias_walk_deg_s_per_sqrt_s",
            "yaw_bias_sigma_deg_s",
            "yaw_scale_sigma",
            "rear_ratio_sigma",
            "ratio_walk",
            "tread_sigma",
            "tread_turn_sigma",
            "wheel_turn_sigma_deg",
            "distance_scale_sigma",
            "still_min_s",
            "aided_window_s",
            "yaw_gate_sigma",
            "slip_accel_sigma",
            "straight_yaw_sigma_deg_s",
            "straight_max_deg_s",
            "straight_max_steer_deg",
            "straight_min_s",
            "straight_min_speed_mps",
            "max_accel_mps2",
            "slide_decel_mps2",
            "slide_decel_sigma_mps2",
            "learn_wheel_scales",
        ] {
            assert!(
                keys.contains(&key),
                "{}: {key} undocumented",
                path.display()
            );
        }
        assert_eq!(keys.len(), 37, "{}: {keys:?}", path.display());
    }
}

/// The issue's wrong configurations refused at start (#32): tick counters
/// on km/h signals, a sign signal of another message, an unknown unit.
#[test]
fn issue_32_wrong_forms_are_named_at_start() {
    let path = crate::util::toyota_toml();
    let text = std::fs::read_to_string(&path).unwrap();
    let e = Config::from_toml(
        &text.replace("wheel_kind = \"speed\"", "wheel_kind = \"ticks\"\n"),
        &path,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("signals.wheel_kind") && e.contains("\"speed\"") && e.contains("km/h"),
        "{e}"
    );
    let e = Config::from_toml(
        &text.replace(
            "rear_left = \"WHEEL_SPEEDS.WHEEL_SPEED_RL\"",
            "rear_left = { signal = \"WHEEL_SPEEDS.WHEEL_SPEED_RL\", sign = \"KINEMATICS.YAW_RATE\" }",
        ),
        &path,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("signals.rear_left.sign") && e.contains("WHEEL_SPEEDS"),
        "{e}"
    );
    let e = Config::from_toml(
        &text.replace(
            "rear_left = \"WHEEL_SPEEDS.WHEEL_SPEED_RL\"",
            "rear_left = { signal = \"WHEEL_SPEEDS.WHEEL_SPEED_RL\", unit = \"furlongs\" }",
        ),
        &path,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("signals.rear_left.unit") && e.contains("furlongs"),
        "{e}"
    );
    // A steering-wheel angle (±500°) configured as the road wheels' angle.
    let e = Config::from_toml(
        &text
            .replace(
                "steering_kind = \"steering_wheel\"",
                "steering_kind = \"road_wheel\"",
            )
            .replace("steering_ratio = 15.0\n", ""),
        &path,
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("signals.steering_kind") && e.contains("500°"),
        "{e}"
    );
}
