//! The presets' inputs as a real car sends them (issue #45): a yaw rate held
//! at its DBC range's end, a configured message the car never sends, and a
//! Honda's gear in whichever gearbox message is on the bus. Frames are
//! built with the configuration's own signal handles from the shipped
//! presets (`daemon/examples`), fed to the pipeline, and the statistics,
//! warnings and poses judged.

// Test helpers outside #[test] functions unwrap too: a failure is a test failure.
#![allow(clippy::unwrap_used)]

use canodom_can::time::Timestamp;
use canodom_pipeline::config::Config;
use canodom_pipeline::pipeline::{Outcome, Pipeline, Step};
use canodom_pipeline::plausibility::Suspicion;
use canodom_pipeline::signal_forms::SignalForm;
use canodom_pipeline::stats::Reject;
use std::path::PathBuf;

fn preset(name: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../daemon/examples")).join(name)
}

/// The preset `name`, its text changed by `edit`.
fn config(name: &str, edit: impl Fn(String) -> String) -> Config {
    let path = preset(name);
    let text = edit(std::fs::read_to_string(&path).unwrap());
    Config::from_toml(&text, &path).unwrap()
}

/// The preset without its `[checks.*]` sections: these tests build frames
/// by signal, not with the carmaker's checksums.
#[allow(clippy::needless_pass_by_value)] // the shape `config` takes its edit in
fn without_checks(text: String) -> String {
    let mut out = String::new();
    let mut skipping = false;
    for line in text.lines() {
        if line.starts_with('[') {
            skipping = line.starts_with("[checks");
        }
        if !skipping {
            out.push_str(line);
            out.push('\n');
        }
    }
    out
}

/// A car sending the configuration's messages by name.
struct Bus<'a> {
    config: &'a Config,
    pipeline: Pipeline,
    t_us: u64,
}

impl<'a> Bus<'a> {
    fn new(config: &'a Config) -> Self {
        Self {
            config,
            pipeline: Pipeline::new(config).unwrap(),
            t_us: 1_000_000,
        }
    }

    /// Sends `message` with each (form, value) written into it.
    fn send(&mut self, message: &str, values: &[(SignalForm, f64)]) -> Outcome {
        let m = self
            .config
            .db
            .messages()
            .iter()
            .find(|m| m.name() == message)
            .unwrap();
        let mut data = vec![0u8; m.length()];
        for (form, value) in values {
            assert!(form.encode(*value, &mut data), "{message}");
        }
        self.pipeline
            .push_data(Timestamp::from_micros(self.t_us), m.id(), &data)
    }

    /// Sends a gear message (`MESSAGE.SIGNAL`) saying R or D by its DBC
    /// value table, whatever the configuration reads.
    fn gear(&mut self, path: &str, reverse: bool) {
        let db = &self.config.db;
        let h = db.signal(path).unwrap();
        let m = &db.messages()[h.message_index()];
        let name = if reverse { "R" } else { "D" };
        let raw = m.signals()[h.signal_index()]
            .value_descriptions()
            .iter()
            .find(|(_, n)| n == name)
            .unwrap()
            .0;
        let mut data = vec![0u8; m.length()];
        assert!(h.encode_raw(u64::try_from(raw).unwrap(), &mut data));
        self.pipeline
            .push_data(Timestamp::from_micros(self.t_us), m.id(), &data);
    }
}

/// One second of the Hyundai preset's messages at 50 Hz: a left circle at
/// `speed_mps` and `yaw_dps`, the steering signal at `steer`, the gyro
/// reading `gyro_dps` as its signal holds it (the encoder saturates at the
/// range's end, as the sensor does). The steps it made.
fn hyundai_steps(
    bus: &mut Bus<'_>,
    (speed_mps, yaw_dps): (f64, f64),
    steer: f64,
    gyro_dps: f64,
) -> Vec<Step> {
    let s = bus.config.signals;
    let kph = 3.6 * speed_mps;
    let tread = bus.config.params.rear_tread_m();
    let half = yaw_dps.to_radians() * tread / 2.0 * 3.6;
    let yaw = s.yaw_rate.unwrap().signal.form;
    let mut steps = Vec::new();
    for _ in 0..50 {
        bus.t_us += 20_000;
        bus.send("SAS11", &[(s.steering.form, steer)]);
        bus.send("ESP12", &[(yaw, gyro_dps)]);
        if let Outcome::Step(step, _) = bus.send(
            "WHL_SPD11",
            &[
                (s.wheels.rear_left.form, kph - half),
                (s.wheels.rear_right.form, kph + half),
                (s.wheels.front_left.form, kph - half),
                (s.wheels.front_right.form, kph + half),
            ],
        ) {
            steps.push(step);
        }
    }
    steps
}

/// [`hyundai_steps`] with the steering straight and the gyro right: each
/// step's yaw rate as the filter got it.
fn hyundai_second(bus: &mut Bus<'_>, speed_mps: f64, yaw_dps: f64) -> Vec<Option<f64>> {
    hyundai_steps(bus, (speed_mps, yaw_dps), 0.0, yaw_dps)
        .iter()
        .map(|s| s.yaw_rate_radps)
        .collect()
}

#[test]
fn a_yaw_rate_at_its_dbc_range_is_not_used_and_warned_of_by_name() {
    let c = config("hyundai.toml", |t| t);
    // ESP12.YAW_RATE: 0.01 steps from -40.95 to 40.96 deg/s.
    let sat = c.signals.yaw_rate.unwrap().saturation;
    assert!(
        (sat.range.0 + 40.95).abs() < 1e-9 && (sat.range.1 - 40.96).abs() < 1e-9,
        "{:?}",
        sat.range
    );
    assert!(sat.is_saturated(40.96) && sat.is_saturated(-40.95) && sat.is_saturated(40.94));
    assert!(!sat.is_saturated(40.5) && !sat.is_saturated(0.0) && !sat.is_saturated(-40.5));
    let mut bus = Bus::new(&c);
    bus.gear("LVR12.CF_Lvr_Gear", false);
    // Inside the range: every step has the gyro.
    let inside = hyundai_second(&mut bus, 5.0, 30.0);
    assert!(inside.iter().skip(6).all(Option::is_some), "{inside:?}");
    assert_eq!(bus.pipeline.stats().get(Reject::YawSaturated), 0);
    assert!(bus.pipeline.plausibility_warnings().is_empty());
    // Past it (a 6 m circle at 5.1 m/s, 49 deg/s): the reading held at
    // 40.96 deg/s is given to no step, counted, and warned of once.
    let past = hyundai_second(&mut bus, 5.1, 49.0);
    assert!(past.iter().skip(1).all(Option::is_none), "{past:?}");
    assert_eq!(bus.pipeline.stats().get(Reject::YawSaturated), 50);
    let warnings = bus.pipeline.plausibility_warnings();
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    let w = &warnings[0];
    assert_eq!(
        (w.signal, w.suspicion),
        ("signals.yaw_rate", Suspicion::Range)
    );
    assert!(
        w.message.contains("ESP12.YAW_RATE") && w.message.contains("40.96"),
        "{w}"
    );
    // Back inside: used again, no second warning.
    let again = hyundai_second(&mut bus, 5.0, 20.0);
    assert!(again.iter().skip(1).all(Option::is_some), "{again:?}");
    assert_eq!(bus.pipeline.plausibility_warnings().len(), 1);
    assert!(
        bus.pipeline
            .stats()
            .to_string()
            .contains("yaw_saturated=50")
    );
}

/// A second of [`hyundai_steps`] with the steering at the angle the
/// circle takes. The last step's (fused, rear-only) headings.
fn hyundai_circle_second(
    bus: &mut Bus<'_>,
    speed_mps: f64,
    yaw_dps: f64,
    gyro_dps: f64,
) -> Option<(f64, f64)> {
    let p = bus.config.params;
    let road_wheel_rad = (yaw_dps.to_radians() * p.wheelbase_m() / speed_mps).atan();
    let map = p.steering();
    let steer = (road_wheel_rad - map.offset_rad) / map.gain;
    hyundai_steps(bus, (speed_mps, yaw_dps), steer, gyro_dps)
        .last()
        .map(|s| (s.fused.heading_rad, s.odometry.heading_rad))
}

#[test]
fn a_gyro_of_the_wrong_sign_is_named_and_the_wheels_carry_on_without_it() {
    let c = config("hyundai.toml", |t| t);
    let mut bus = Bus::new(&c);
    bus.gear("LVR12.CF_Lvr_Gear", false);
    // A 23 m circle at 8 m/s: the wheels and the steering turn left, the
    // gyro (its sign configured the other way) right.
    let mut headings = None;
    for _ in 0..12 {
        headings = hyundai_circle_second(&mut bus, 8.0, 20.0, -20.0);
    }
    let warnings = bus.pipeline.plausibility_warnings();
    let w = warnings
        .iter()
        .find(|w| w.signal == "signals.yaw_rate")
        .unwrap_or_else(|| panic!("no gyro warning: {warnings:?}"));
    assert_eq!(w.suspicion, Suspicion::Sign, "{w}");
    assert!(w.message.contains("not used from here on"), "{w}");
    assert!(
        warnings.iter().all(|w| w.signal == "signals.yaw_rate"),
        "the steering and the wheels were right: {warnings:?}"
    );
    assert!(bus.pipeline.stats().get(Reject::YawImplausible) > 0);
    // From the warning on, the fused heading is the wheels': 240° of turn
    // in 12 s, where the gyro said −240°.
    let (fused, rear) = headings.unwrap();
    assert!(rear.to_degrees() > 200.0, "{}", rear.to_degrees());
    assert!(
        (fused - rear).abs().to_degrees() < 1.0,
        "fused {:.1}°, rear wheels {:.1}°",
        fused.to_degrees(),
        rear.to_degrees()
    );
}

/// Each gyro its DBC carries, read from the preset's DBC (the line added
/// where the preset leaves it off, as `[signals] yaw_rate` would say it).
#[test]
fn every_gyro_dbcs_range_is_its_signals() {
    for (name, line, range) in [
        (
            "toyota.toml",
            "yaw_rate = \"KINEMATICS.YAW_RATE\"",
            (-125.0, 124.612),
        ),
        (
            "vw_mqb.toml",
            "yaw_rate = { signal = \"ESP_02.ESP_Gierrate\", sign = \"ESP_02.ESP_VZ_Gierrate\" }",
            (-163.82, 163.82),
        ),
        (
            "hyundai_canfd.toml",
            "yaw_rate = \"ESC_02_10ms.ESC_YawRtVal\"",
            (-163.84, 163.835),
        ),
        (
            "gm.toml",
            "yaw_rate = \"EBCMVehicleDynamic.YawRate2\"",
            (-128.0, 127.9375),
        ),
    ] {
        let c = config(name, |t| {
            let kept: String = t
                .lines()
                .filter(|l| !l.starts_with("yaw_rate") && !l.starts_with("# yaw_rate"))
                .fold(String::new(), |acc, l| acc + l + "\n");
            kept.replace("[signals]\n", &format!("[signals]\n{line}\n"))
        });
        let r = c.signals.yaw_rate.unwrap().saturation.range;
        assert!(
            (r.0 - range.0).abs() < 1e-9 && (r.1 - range.1).abs() < 1e-9,
            "{name}: {r:?}"
        );
    }
}

/// One second of the Honda preset's wheels at `speed_mps` straight ahead
/// (magnitudes, as the Civic sends them), with its steering message or not.
fn honda_second(bus: &mut Bus<'_>, speed_mps: f64, steering: bool, gear: Option<(&str, bool)>) {
    let s = bus.config.signals;
    let kph = 3.6 * speed_mps.abs();
    for i in 0..50 {
        bus.t_us += 20_000;
        if steering {
            bus.send("STEERING_SENSORS", &[(s.steering.form, 0.0)]);
        }
        if let Some((message, reverse)) = gear
            && i % 5 == 0
        {
            bus.gear(message, reverse);
        }
        bus.send(
            "WHEEL_SPEEDS",
            &[
                (s.wheels.rear_left.form, kph),
                (s.wheels.rear_right.form, kph),
                (s.wheels.front_left.form, kph),
                (s.wheels.front_right.form, kph),
            ],
        );
    }
}

#[test]
fn a_configured_message_that_never_comes_is_warned_of_by_name() {
    let c = config("honda.toml", without_checks);
    let mut bus = Bus::new(&c);
    // No STEERING_SENSORS (a Nidec Honda that sends another steering
    // message); GEARBOX_AUTO, not GEARBOX_CVT: one gear message is enough.
    for _ in 0..4 {
        honda_second(
            &mut bus,
            5.0,
            false,
            Some(("GEARBOX_AUTO.GEAR_SHIFTER", false)),
        );
    }
    assert!(
        bus.pipeline.plausibility_warnings().is_empty(),
        "warned before 5 s of traffic"
    );
    for _ in 0..2 {
        honda_second(
            &mut bus,
            5.0,
            false,
            Some(("GEARBOX_AUTO.GEAR_SHIFTER", false)),
        );
    }
    let warnings = bus.pipeline.plausibility_warnings();
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    let w = &warnings[0];
    assert_eq!(
        (w.signal, w.suspicion),
        ("signals.steering", Suspicion::Message)
    );
    assert!(
        w.message.contains("STEERING_SENSORS") && w.message.contains("0x14A"),
        "{w}"
    );
    // The replay's summary lists it too (its end judgement keeps it).
    assert_eq!(bus.pipeline.plausibility_at_end().0.len(), 1);

    // Neither gear message: that is warned of, naming the key.
    let mut bus = Bus::new(&c);
    for _ in 0..6 {
        honda_second(&mut bus, 5.0, true, None);
    }
    let warnings = bus.pipeline.plausibility_warnings();
    assert_eq!(warnings.len(), 2, "{warnings:?}");
    assert!(warnings.iter().all(|w| w.signal == "signals.direction"));
}

/// The Civic's CVT gear.
const CVT: &str = "GEARBOX_CVT.GEAR_SHIFTER";

/// `seconds` of the Honda preset's messages at `speed_mps`, GEARBOX_CVT
/// saying R (`reverse`) or D, and GEARBOX_AUTO saying D too when `auto_d`.
fn cvt_drive(bus: &mut Bus<'_>, seconds: u32, speed_mps: f64, reverse: bool, auto_d: bool) {
    for _ in 0..seconds {
        if auto_d {
            bus.gear("GEARBOX_AUTO.GEAR_SHIFTER", false);
        }
        honda_second(bus, speed_mps, true, Some((CVT, reverse)));
    }
}

/// The Civic's CVT (issue #45): 30 m out in D, 30 m back in R, the gear in
/// GEARBOX_CVT. The preset signed the speeds by GEARBOX_AUTO only, which a
/// CVT Civic does not send, and ended 60 m off.
#[test]
fn a_cvt_civic_reversing_counts_backwards() {
    let c = config("honda.toml", without_checks);
    let mut bus = Bus::new(&c);
    cvt_drive(&mut bus, 10, 3.0, false, false);
    cvt_drive(&mut bus, 2, 0.0, true, false);
    cvt_drive(&mut bus, 10, 3.0, true, false);
    // Near the start, not 60 m off: the speed's steps to and from 3 m/s,
    // which no car makes, leave about 0.6 m of the trapezoid's rounding.
    let end = bus.pipeline.last_step().unwrap().fused;
    assert!(end.x_m.hypot(end.y_m) < 1.0, "ended at {end:?}");
    assert!(bus.pipeline.plausibility_warnings().is_empty());

    // A car sending both: GEARBOX_CVT says it (openpilot reads 0x191 when
    // it is on the bus), a GEARBOX_AUTO saying D does not undo it.
    let mut bus = Bus::new(&c);
    cvt_drive(&mut bus, 10, 3.0, false, false);
    cvt_drive(&mut bus, 10, 3.0, true, true);
    let end = bus.pipeline.last_step().unwrap().fused;
    assert!(end.x_m.hypot(end.y_m) < 1.0, "ended at {end:?}");
}
