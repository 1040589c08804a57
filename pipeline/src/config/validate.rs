//! The whole file validated in one pass into a [`Config`]: the DBC read,
//! every signal and check resolved to a codec handle and units converted,
//! the sections taken in the order they depend on each other.

use super::raw::RawConfig;
use super::validator::Validator;
use super::{
    Config, ConfigError, InputSignal, InputsConfig, MessageCheck, OutputConfig,
    SPEED_SENSOR_REFERENCE_DIAMETER_M, Signals, SteeringKind, WheelKind, YawRateSignal, beside,
};
use crate::signal_forms::{Quantity, RawSignal, Unit};
use canodom_dbc::{
    Checksum, ChecksumAlgorithm, Database, FrameChecksum, Maker, MakerChecksum, SignalHandle,
};
use canodom_fusion::ekf::EkfConfig;
use canodom_fusion::wheel::{InputConfig, SpeedUnit};
use canodom_fusion::{SteeringMap, VehicleParams, WheelSet};
use canodom_protocol::own_dbc::BaseId;

impl Validator<'_> {
    #[allow(clippy::too_many_lines)]
    pub(super) fn validate(
        &self,
        raw: RawConfig,
        db: Option<Database>,
    ) -> Result<Config, ConfigError> {
        let iface = raw.can.interface;
        if iface.is_empty()
            || iface.len() > 15
            || iface.chars().any(|c| c.is_whitespace() || c == '/')
        {
            return Err(self.err(
                "can.interface",
                "a network interface name (1 to 15 characters, no '/' or spaces)",
                format!("{iface:?}"),
            ));
        }
        let dbc_path = beside(self.file, &raw.can.dbc);
        let db = match db {
            Some(db) => db,
            None => Database::from_file(&dbc_path).map_err(|e| {
                self.err(
                    "can.dbc",
                    "a readable DBC file (relative to the configuration file)",
                    format!("{} ({e})", dbc_path.display()),
                )
            })?,
        };

        // Signals.
        let s = &raw.signals;
        let speed = match s.wheel_kind.as_deref() {
            Some("ticks") => false,
            Some("speed") => true,
            other => {
                return Err(self.err(
                    "signals.wheel_kind",
                    "\"ticks\" (cumulative encoder counters) or \"speed\" (km/h, m/s or mph signals)",
                    other.map_or_else(|| "nothing".to_owned(), |o| format!("{o:?}")),
                ));
            }
        };
        let wheel_quantity = speed.then_some(Quantity::Speed);
        let wheel = |key: &str, raw: &RawSignal| self.quantity(&db, key, raw, wheel_quantity);
        let (rear_left, rl_unit) = wheel("signals.rear_left", &s.rear_left)?;
        let (rear_right, rr_unit) = wheel("signals.rear_right", &s.rear_right)?;
        let (front_left, fl_unit) = wheel("signals.front_left", &s.front_left)?;
        let (front_right, fr_unit) = wheel("signals.front_right", &s.front_right)?;
        let wheels = WheelSet {
            rear_left,
            rear_right,
            front_left,
            front_right,
        };
        // One step per rear frame needs both rear wheels in one frame.
        if wheels.rear_left.message_index != wheels.rear_right.message_index {
            return Err(self.err(
                "signals.rear_right",
                "a signal in the same message as signals.rear_left",
                s.rear_right.name(),
            ));
        }
        if wheels.front_left.message_index != wheels.front_right.message_index {
            return Err(self.err(
                "signals.front_right",
                "a signal in the same message as signals.front_left",
                s.front_right.name(),
            ));
        }
        let (wheel_kind, wheel_speed_factor) = if speed {
            // `quantity` gave every wheel a speed unit.
            let unit = rl_unit.unwrap_or(Unit::KilometresPerHour);
            for (key, u) in [
                ("signals.rear_right", rr_unit),
                ("signals.front_left", fl_unit),
                ("signals.front_right", fr_unit),
            ] {
                if u != Some(unit) {
                    return Err(self.err(
                        key,
                        &format!("the same unit as signals.rear_left ({unit:?})"),
                        format!("{u:?}"),
                    ));
                }
            }
            match unit {
                Unit::MetresPerSecond => (WheelKind::Speed(SpeedUnit::MetresPerSecond), 1.0),
                Unit::MilesPerHour => (
                    WheelKind::Speed(SpeedUnit::MetresPerSecond),
                    Unit::MilesPerHour.si_per_unit(),
                ),
                _ => (WheelKind::Speed(SpeedUnit::KilometresPerHour), 1.0),
            }
        } else {
            for (key, w, raw) in [
                ("signals.rear_left", &wheels.rear_left, &s.rear_left),
                ("signals.rear_right", &wheels.rear_right, &s.rear_right),
                ("signals.front_left", &wheels.front_left, &s.front_left),
                ("signals.front_right", &wheels.front_right, &s.front_right),
            ] {
                if !w.form.is_plain() {
                    return Err(self.err(
                        key,
                        "one tick-counter signal (sign and sum forms are for speeds)",
                        raw.name(),
                    ));
                }
                let unit = unit_of(&db, w);
                if Unit::parse(&unit).is_some_and(|u| u.quantity() == Quantity::Speed) {
                    return Err(self.err(
                        "signals.wheel_kind",
                        &format!(
                            "\"speed\": {} is a speed in {unit:?}, not a tick counter",
                            raw.name()
                        ),
                        "\"ticks\"",
                    ));
                }
            }
            if s.direction.is_some() {
                return Err(self.err(
                    "signals.direction",
                    "no direction with tick counters (they count backwards when reversing)",
                    "a direction signal",
                ));
            }
            (WheelKind::Ticks, 1.0)
        };
        let (mut steering, steer_unit) =
            self.quantity(&db, "signals.steering", &s.steering, Some(Quantity::Angle))?;
        if let Some(p) = &s.steering_fine {
            let fine = self.signal(&db, "signals.steering_fine", p)?;
            if fine.message_index != steering.message_index {
                return Err(self.err(
                    "signals.steering_fine",
                    "a signal in the same message as signals.steering",
                    p,
                ));
            }
            if steering.form.fine.is_some() {
                return Err(self.err(
                    "signals.steering_fine",
                    "no steering_fine beside a signals.steering sum",
                    p,
                ));
            }
            steering.form.fine = Some(fine.handle);
        }
        let (direction, direction_alt) = match &s.direction {
            None => (None, None),
            Some(d) => {
                let (first, second) =
                    crate::signal_forms::resolve_direction(&db, d).map_err(|e| self.form(e))?;
                (Some(first), second)
            }
        };
        let tick_bits = wheels.rear_left.handle.size();
        let steering_kind = match s.steering_kind.as_deref() {
            Some("road_wheel") => SteeringKind::RoadWheel,
            Some("steering_wheel") => SteeringKind::SteeringWheel,
            other => {
                return Err(self.err(
                    "signals.steering_kind",
                    "\"road_wheel\" (the wheels' angle) or \"steering_wheel\" (divided by vehicle.steering_ratio)",
                    other.map_or_else(|| "nothing".to_owned(), |o| format!("{o:?}")),
                ));
            }
        };
        let yaw_rate = match &s.yaw_rate {
            None => {
                if s.yaw_rate_sign.is_some() {
                    return Err(self.err(
                        "signals.yaw_rate_sign",
                        "signals.yaw_rate beside it",
                        "a sign without a yaw-rate signal",
                    ));
                }
                None
            }
            Some(raw_yaw) => {
                let (signal, unit) = self.quantity(
                    &db,
                    "signals.yaw_rate",
                    raw_yaw,
                    Some(Quantity::AngularRate),
                )?;
                let per_unit = unit.map_or(1.0, Unit::si_per_unit);
                let sign = match s.yaw_rate_sign {
                    None | Some(1) => 1.0,
                    Some(-1) => -1.0,
                    Some(other) => {
                        return Err(self.err(
                            "signals.yaw_rate_sign",
                            "1 (left turn positive) or -1 (right turn positive)",
                            other,
                        ));
                    }
                };
                Some(YawRateSignal {
                    saturation: crate::signal_forms::Saturation::of(&db, &signal.form),
                    signal,
                    radps_per_unit: per_unit * sign,
                })
            }
        };
        let rad_per_unit = steer_unit.map_or(1.0, Unit::si_per_unit);
        if steering_kind == SteeringKind::RoadWheel {
            // A road wheel turns well under 90°; a DBC range far beyond it
            // is a steering-wheel angle (VW's LWI_01 reaches 800°).
            let sig =
                &db.messages()[steering.message_index].signals()[steering.handle.signal_index()];
            let reach_deg = sig.min().abs().max(sig.max().abs()) * rad_per_unit.to_degrees();
            if reach_deg > 120.0 {
                return Err(self.err(
                    "signals.steering_kind",
                    &format!(
                        "\"steering_wheel\" with vehicle.steering_ratio: {} ranges to {reach_deg:.0}°, \
                         beyond any road wheel",
                        s.steering.name()
                    ),
                    "\"road_wheel\"",
                ));
            }
        }

        // Vehicle.
        let v = &raw.vehicle;
        let wheelbase_m = self.positive("vehicle.wheelbase_m", v.wheelbase_m)?;
        let rear_tread_m = self.positive("vehicle.rear_tread_m", v.rear_tread_m)?;
        let front_tread_m = self.positive("vehicle.front_tread_m", v.front_tread_m)?;
        let nominal = match (wheel_kind, v.wheel_diameter_m) {
            (_, Some(d)) => self.positive("vehicle.wheel_diameter_m", d)?,
            (WheelKind::Ticks, None) => {
                return Err(self.err(
                    "vehicle.wheel_diameter_m",
                    "the wheels' diameter in metres (tick encoders count revolutions)",
                    "nothing",
                ));
            }
            // Speed signals are distances already: the diameter is only the
            // reference the calibration's speed scale multiplies (a
            // calibrated 0.6532 m is a 0.49 % scale on this 0.65 m).
            (WheelKind::Speed(_), None) => SPEED_SENSOR_REFERENCE_DIAMETER_M,
        };
        let diameter = |key: &str, o: Option<f64>| match o {
            Some(d) => self.positive(key, d),
            None => Ok(nominal),
        };
        let diameters = WheelSet {
            rear_left: diameter("vehicle.rear_left_diameter_m", v.rear_left_diameter_m)?,
            rear_right: diameter("vehicle.rear_right_diameter_m", v.rear_right_diameter_m)?,
            front_left: diameter("vehicle.front_left_diameter_m", v.front_left_diameter_m)?,
            front_right: diameter("vehicle.front_right_diameter_m", v.front_right_diameter_m)?,
        };
        let ticks = match (wheel_kind, v.encoder_ticks_per_rev) {
            (WheelKind::Ticks, None) => {
                return Err(self.err(
                    "vehicle.encoder_ticks_per_rev",
                    "a tick count per wheel revolution (signals.wheel_kind = \"ticks\")",
                    "nothing",
                ));
            }
            (WheelKind::Ticks, Some(0)) => {
                return Err(self.err("vehicle.encoder_ticks_per_rev", "an integer >= 1", 0));
            }
            (_, t) => t.unwrap_or(1),
        };
        let gain = match (steering_kind, v.steering_ratio) {
            (SteeringKind::RoadWheel, None) => rad_per_unit,
            (SteeringKind::RoadWheel, Some(r)) => {
                return Err(self.err(
                    "vehicle.steering_ratio",
                    "no steering_ratio with signals.steering_kind = \"road_wheel\"",
                    r,
                ));
            }
            (SteeringKind::SteeringWheel, None) => {
                return Err(self.err(
                    "vehicle.steering_ratio",
                    "a steering ratio (signals.steering_kind = \"steering_wheel\")",
                    "nothing",
                ));
            }
            (SteeringKind::SteeringWheel, Some(r)) => {
                rad_per_unit / self.positive("vehicle.steering_ratio", r)?
            }
        };
        let params = VehicleParams::new(
            wheelbase_m,
            rear_tread_m,
            front_tread_m,
            diameters,
            ticks,
            SteeringMap {
                gain,
                offset_rad: 0.0,
            },
        )
        .map_err(|e| self.err("vehicle", "a valid parameter set", e))?;

        // Checks.
        let mut checks = Vec::new();
        for (name, c) in &raw.checks {
            let key = format!("checks.{name}");
            let m = db.message_by_name(name).ok_or_else(|| {
                self.err(
                    &key,
                    &format!("a message name of {}", db.source_name()),
                    name,
                )
            })?;
            let message_index = db
                .messages()
                .iter()
                .position(|x| x.name() == name)
                .unwrap_or_default();
            let counter = match &c.counter {
                None => None,
                Some(sig) => Some(
                    self.signal(&db, &format!("{key}.counter"), &format!("{name}.{sig}"))?
                        .handle,
                ),
            };
            let checksum = match (&c.checksum, &c.algorithm) {
                (None, None) => None,
                (None, Some(_)) => {
                    return Err(self.err(
                        &format!("{key}.checksum"),
                        "the checksum signal's name when an algorithm is given",
                        "nothing",
                    ));
                }
                (Some(sig), alg) => {
                    let h = self
                        .signal(&db, &format!("{key}.checksum"), &format!("{name}.{sig}"))?
                        .handle;
                    let name = alg.as_deref().unwrap_or("crc8_sae_j1850");
                    if let Some(maker) = Maker::from_name(name) {
                        let c = MakerChecksum::new(maker, m.id().to_dbc(), h, m.length()).map_err(
                            |e| self.err(&format!("{key}.checksum"), "a usable checksum", e),
                        )?;
                        checks.push(MessageCheck {
                            message_index,
                            counter,
                            checksum: Some(FrameChecksum::Maker(c)),
                        });
                        continue;
                    }
                    let algorithm = match name {
                        "crc8_sae_j1850" => ChecksumAlgorithm::Crc8SaeJ1850,
                        "sum" => ChecksumAlgorithm::Sum { init: 0 },
                        "xor" => ChecksumAlgorithm::Xor { init: 0 },
                        other => {
                            let makers: Vec<&str> = Maker::ALL.iter().map(|(_, n)| *n).collect();
                            return Err(self.err(
                                &format!("{key}.algorithm"),
                                &format!(
                                    "\"crc8_sae_j1850\", \"sum\", \"xor\", or a carmaker's: {}",
                                    makers.join(", ")
                                ),
                                other,
                            ));
                        }
                    };
                    let len = m.length();
                    let position = checksum_byte(m, h).ok_or_else(|| {
                        self.err(
                            &format!("{key}.checksum"),
                            "an 8-bit, byte-aligned signal in the first or last byte",
                            sig,
                        )
                    })?;
                    let covered = if position + 1 == len {
                        0..=len.saturating_sub(2)
                    } else {
                        1..=len - 1
                    };
                    Some(FrameChecksum::Bytes(
                        Checksum::new(algorithm, covered, position).map_err(|e| {
                            self.err(&format!("{key}.checksum"), "a usable checksum", e)
                        })?,
                    ))
                }
            };
            checks.push(MessageCheck {
                message_index,
                counter,
                checksum,
            });
        }

        // Inputs.
        let i = &raw.inputs;
        let timeout_factor = self.positive("inputs.timeout_factor", i.timeout_factor)?;
        if timeout_factor < 1.0 {
            return Err(self.err("inputs.timeout_factor", "a factor >= 1", timeout_factor));
        }
        let default_period_s =
            self.positive("inputs.default_period_ms", i.default_period_ms)? / 1000.0;
        let max_wheel_speed_mps = match i.max_wheel_speed_mps {
            Some(v) => self.positive("inputs.max_wheel_speed_mps", v)?,
            None => match wheel_kind {
                WheelKind::Ticks => InputConfig::RC_CAR.max_wheel_speed_mps,
                WheelKind::Speed(_) => InputConfig::ROAD_CAR.max_wheel_speed_mps,
            },
        };
        if i.trusted_after_frames == 0 || i.invalid_after_faults == 0 {
            return Err(self.err(
                "inputs.trusted_after_frames / inputs.invalid_after_faults",
                "integers >= 1",
                format!("{} / {}", i.trusted_after_frames, i.invalid_after_faults),
            ));
        }
        let inputs = InputsConfig {
            timeout_factor,
            default_period_s,
            invalid_after_faults: i.invalid_after_faults,
            trusted_after_frames: i.trusted_after_frames,
            max_wheel_speed_mps,
        };

        // EKF.
        let e = &raw.ekf;
        let mut ekf = EkfConfig::new(params);
        // The yaw-rate signal's step: a standing car's readings repeat one
        // value, whose rounding no average removes.
        if let Some(y) = &yaw_rate {
            let m = &db.messages()[y.signal.message_index];
            let factor = m.signals()[y.signal.handle.signal_index()].factor();
            ekf.yaw_quantum_radps = (factor * y.radps_per_unit).abs();
        }
        if let Some(k) = e.k_rear_m {
            ekf.k_rear_m = self.positive("ekf.k_rear_m", k)?;
        }
        if let Some(k) = e.k_front_m {
            ekf.k_front_m = self.positive("ekf.k_front_m", k)?;
        }
        if let Some(d) = e.steer_sigma_deg {
            ekf.steer_sigma_rad = self.positive("ekf.steer_sigma_deg", d)?.to_radians();
        }
        if let Some(d) = e.steer_bias_sigma_deg {
            ekf.steer_bias_sigma_rad = self
                .non_negative("ekf.steer_bias_sigma_deg", d)?
                .to_radians();
        }
        if let Some(n) = e.correct_every {
            if n == 0 {
                return Err(self.err("ekf.correct_every", "an integer >= 1", n));
            }
            ekf.correct_every = n;
        }
        if let Some(g) = e.gate_threshold {
            ekf.gate_threshold = Some(self.positive("ekf.gate_threshold", g)?);
        }
        if e.gate_enabled == Some(false) {
            ekf.gate_threshold = None;
        }
        if e.learn_steer_offset == Some(false) {
            ekf.steer_offset_drift_rad = None;
        }
        self.ekf_choices(e, &mut ekf)?;
        canodom_fusion::ekf::Ekf::new(ekf)
            .map_err(|err| self.err("ekf", "a valid filter configuration", err))?;

        // Output.
        let o = &raw.output;
        let base_id = BaseId::new(o.base_id, o.extended).map_err(|err| {
            self.err(
                "output.base_id",
                "a base id whose frames (base + 0x16) fit the id format",
                err,
            )
        })?;
        let output = OutputConfig {
            base_id,
            pose_rate_hz: self.positive("output.pose_rate_hz", o.pose_rate_hz)?,
            publish_on_update: o.publish_on_update,
            stats_interval_s: self.positive("output.stats_interval_s", o.stats_interval_s)?,
        };
        for w in [wheels.rear_left, wheels.front_left, steering] {
            let id = db.messages()[w.message_index].id();
            let own = (0..=canodom_protocol::own_dbc::MAX_OFFSET).any(|off| {
                base_id.id().raw() + off == id.raw()
                    && base_id.id().is_extended() == id.is_extended()
            });
            if own {
                return Err(self.err(
                    "output.base_id",
                    "own frame ids (base .. base + 0x16) clear of the input messages",
                    format!("{:#x}", o.base_id),
                ));
            }
        }

        let mut calibration = self.calibration(&raw.calibration, base_id, &params)?;
        calibration.fixes = match &raw.calibration.fixes {
            None => None,
            Some(f) => {
                let fixes = self.fix_signals(&db, f)?;
                let inputs = [
                    wheels.rear_left.message_index,
                    wheels.front_left.message_index,
                    steering.message_index,
                ];
                if inputs.contains(&fixes.message_index)
                    || yaw_rate.is_some_and(|y| y.signal.message_index == fixes.message_index)
                {
                    return Err(self.err(
                        "calibration.fixes",
                        "signals of a message that is not an odometry input",
                        db.messages()[fixes.message_index].name(),
                    ));
                }
                Some(fixes)
            }
        };

        Ok(Config {
            file: self.file.to_owned(),
            interface: iface,
            dbc_path,
            db,
            params,
            signals: Signals {
                wheels,
                steering,
                wheel_kind,
                steering_kind,
                tick_bits,
                yaw_rate,
                wheel_speed_factor,
                direction,
                direction_alt,
            },
            checks,
            inputs,
            ekf,
            output,
            security: crate::security::validate(
                self.file,
                raw.security.as_ref(),
                &calibration.param_file,
            )
            .map_err(|e| match e {
                crate::security::SecurityError::Invalid(key, expected, got) => {
                    self.err(&key, &expected, got)
                }
                crate::security::SecurityError::KeyFile(path, reason) => ConfigError::KeyFile {
                    file: self.file.to_owned(),
                    path,
                    reason,
                },
            })?,
            calibration,
            gnss: self.gnss(raw.gnss.as_ref())?,
            ros2: raw.ros2,
        })
    }
}

/// The unit the DBC gives an input's main signal.
fn unit_of(db: &Database, sig: &InputSignal) -> String {
    db.messages()[sig.message_index].signals()[sig.handle.signal_index()]
        .unit()
        .to_owned()
}

/// The byte a checksum signal occupies, if it is a whole byte.
fn checksum_byte(m: &canodom_dbc::Message, h: SignalHandle) -> Option<usize> {
    if h.size() != 8 {
        return None;
    }
    let mut probe = vec![0u8; m.length()];
    if !h.encode_raw(0xFF, &mut probe) {
        return None;
    }
    let set: Vec<usize> = (0..probe.len()).filter(|&b| probe[b] != 0).collect();
    match set.as_slice() {
        [b] if probe[*b] == 0xFF && (*b == 0 || *b + 1 == probe.len()) => Some(*b),
        _ => None,
    }
}
