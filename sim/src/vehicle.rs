//! A simulated vehicle on the bus: the fusion crate's simulator, its samples
//! encoded with the configured DBC into the configured input messages, with
//! valid rolling counters and checksums. Used by `simulate`, `demo` and the
//! tests, so every frame the daemon reads in a test is one a real ECU with
//! that DBC could have sent.

use canodom_can::frame::{CanFrame, FrameId};
use canodom_dbc::SignalHandle;
use canodom_fusion::sim::{Direction, Plan, SimConfig, SteeringSensor, WheelOutput, family};
use canodom_fusion::{SteeringMap, VehicleParams, Wheel};
use canodom_pipeline::config::{Config, SteeringKind, WheelKind};
use canodom_pipeline::signal_forms::{DirectionSignal, SignalForm};
use serde::Deserialize;
use std::path::Path;

/// The drives `simulate --path` offers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum PathKind {
    /// The calibration track, clockwise.
    TrackCw,
    /// The calibration track, counter-clockwise.
    TrackCcw,
    /// One circle to the left.
    Circle,
    /// A left circle then a right circle.
    FigureEight,
    /// A random smooth drive (seeded).
    Random,
    /// A drive of the fusion tests' full-size family (seeded, road cars
    /// only): a 30 m straight, full circles of 10–20 m radius left and
    /// right, eight constant-curvature segments; tyre slip angles, a
    /// steering bias, steering that jumps or turns at a finite rate.
    FullSize,
    /// A town drive of the same family (seeded, road cars only): stops,
    /// reversing, crawling below the wheel-speed sensors' 2 km/h floor.
    Town,
}

/// Corner radius of the calibration track the simulated 1:10 car drives, m.
const TRACK_RADIUS_M: f64 = 0.78;

/// How much larger the paths are for a road car (speed inputs) than for a
/// 1:10 car (tick inputs).
const ROAD_SCALE: f64 = 20.0;

/// The semicircle radius ρ of the simulated calibration track (`--path track-*`):
/// 0.78 m for a 1:10 car, 20 times that at road scale.
pub fn track_radius_m(road_scale: bool) -> f64 {
    if road_scale {
        TRACK_RADIUS_M * ROAD_SCALE
    } else {
        TRACK_RADIUS_M
    }
}

impl PathKind {
    /// The plan, sized for the vehicle: metres for a 1:10 car (ticks), tens of
    /// metres for a road car (speeds).
    ///
    /// # Errors
    /// The fusion crate refused the plan.
    pub fn plan(self, road_scale: bool, seed: u64) -> canodom_fusion::Result<Plan> {
        self.plan_laps(road_scale, seed, 1)
    }

    /// [`Self::plan`] driven `laps` times: laps of the track, turns of the
    /// circle, `laps` × 20 m of the random drive (a long log for benchmarks).
    /// The figure eight and the road-scale random drive are always one lap.
    ///
    /// # Errors
    /// The fusion crate refused the plan (zero laps among others).
    pub fn plan_laps(self, road_scale: bool, seed: u64, laps: u32) -> canodom_fusion::Result<Plan> {
        let k = if road_scale { ROAD_SCALE } else { 1.0 };
        match self {
            Self::TrackCw => Plan::track(track_radius_m(road_scale), Direction::Cw, laps),
            Self::TrackCcw => Plan::track(track_radius_m(road_scale), Direction::Ccw, laps),
            Self::Circle => Plan::circle(1.0 * k, Direction::Ccw, f64::from(laps)),
            Self::FigureEight => Plan::figure_eight(1.0 * k),
            Self::Random if road_scale => Plan::road_drive(seed),
            Self::Random => Plan::random_drive(seed, 20.0 * f64::from(laps), 0.5),
            Self::FullSize | Self::Town => Ok(self.family_drive(seed)?.plan),
        }
    }

    /// The family drive of [`PathKind::FullSize`] and [`PathKind::Town`]
    /// (its plan, and the tyres, driver and sensor errors it was drawn
    /// with); an error for the other kinds.
    ///
    /// # Errors
    /// Not a family kind, or the fusion crate refused the drive.
    pub fn family_drive(self, seed: u64) -> canodom_fusion::Result<family::Drive> {
        match self {
            Self::FullSize => family::full_size_car(seed),
            Self::Town => family::urban_car(seed),
            _ => Err(canodom_fusion::Error::InvalidConfig {
                name: "path",
                reason: "only full-size and town drives come from a family".into(),
            }),
        }
    }

    /// Whether the drive comes from a fusion-test family (road cars only).
    pub fn is_family(self) -> bool {
        matches!(self, Self::FullSize | Self::Town)
    }
}

/// The true vehicle as `--true-params FILE` gives it (TOML); keys left out
/// take the configuration's nominal values.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrueParamsFile {
    wheelbase_m: Option<f64>,
    rear_tread_m: Option<f64>,
    front_tread_m: Option<f64>,
    rear_left_diameter_m: Option<f64>,
    rear_right_diameter_m: Option<f64>,
    front_left_diameter_m: Option<f64>,
    front_right_diameter_m: Option<f64>,
    /// Multiplies the configured steering map's gain.
    steering_gain_factor: Option<f64>,
    /// Road-wheel angle at a zero steering signal, degrees.
    steering_offset_deg: Option<f64>,
}

/// A `--true-params` file that cannot be used.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {message}")]
pub struct TrueParamsError {
    file: String,
    message: String,
}

impl TrueParamsFile {
    /// Reads and parses `path`.
    ///
    /// # Errors
    /// Unreadable file, bad TOML or unknown key.
    pub fn load(path: &Path) -> Result<Self, TrueParamsError> {
        let err = |message: String| TrueParamsError {
            file: path.display().to_string(),
            message,
        };
        let text = std::fs::read_to_string(path).map_err(|e| err(e.to_string()))?;
        toml::from_str(&text).map_err(|e| err(e.to_string()))
    }

    /// The true parameters: these values over the configuration's nominal ones.
    ///
    /// # Errors
    /// A value the fusion crate refuses (names the parameter).
    pub fn apply(&self, nominal: &VehicleParams) -> canodom_fusion::Result<VehicleParams> {
        let d = nominal.wheel_diameters_m();
        let map = nominal.steering();
        VehicleParams::new(
            self.wheelbase_m.unwrap_or(nominal.wheelbase_m()),
            self.rear_tread_m.unwrap_or(nominal.rear_tread_m()),
            self.front_tread_m.unwrap_or(nominal.front_tread_m()),
            canodom_fusion::WheelSet {
                rear_left: self.rear_left_diameter_m.unwrap_or(d.rear_left),
                rear_right: self.rear_right_diameter_m.unwrap_or(d.rear_right),
                front_left: self.front_left_diameter_m.unwrap_or(d.front_left),
                front_right: self.front_right_diameter_m.unwrap_or(d.front_right),
            },
            nominal.encoder_ticks_per_rev(),
            SteeringMap {
                gain: map.gain * self.steering_gain_factor.unwrap_or(1.0),
                offset_rad: self
                    .steering_offset_deg
                    .map_or(map.offset_rad, f64::to_radians),
            },
        )
    }
}

/// The simulator configuration matching the configured inputs: counter width,
/// speed unit and quantum, steering quantum taken from the DBC.
pub fn sim_config(config: &Config, true_params: VehicleParams) -> SimConfig {
    let s = &config.signals;
    let steer_quantum = s.steering.form.quantum();
    match s.wheel_kind {
        WheelKind::Ticks => {
            let mut c = SimConfig::rc_car(true_params);
            c.wheel_output.counter_bits = s.tick_bits;
            c.steering_sensor.quantum = steer_quantum;
            c
        }
        WheelKind::Speed(unit) => {
            let sensor = SteeringSensor {
                quantum: steer_quantum,
                ..SteeringSensor::EXACT
            };
            let mut c = SimConfig::road_car(true_params, sensor);
            c.wheel_output = WheelOutput {
                speed_unit: unit,
                speed_quantum: s.wheels.rear_left.form.quantum() * s.wheel_speed_factor,
                ..c.wheel_output
            };
            if let Some(y) = &s.yaw_rate {
                c.yaw_rate_sensor.quantum_radps = y.signal.form.quantum() * y.radps_per_unit.abs();
            }
            if s.steering_kind == SteeringKind::RoadWheel {
                c.speed_mps = c.speed_mps.min(3.0);
            }
            c
        }
    }
}

struct OutMessage {
    id: FrameId,
    length: usize,
    wheels: Vec<(Wheel, SignalForm)>,
    steering: bool,
    yaw: bool,
    direction: bool,
    counter: Option<SignalHandle>,
    counter_value: u64,
    checksum: Option<canodom_dbc::FrameChecksum>,
}

/// Encodes simulator samples into the configured input frames.
pub struct SampleEncoder {
    messages: Vec<OutMessage>,
    steering: SignalForm,
    /// The yaw-rate signal and its rad/s per unit.
    yaw: Option<(SignalForm, f64)>,
    direction: Option<DirectionSignal>,
    /// Divides a speed into the wheel signals' unit.
    wheel_speed_factor: f64,
    ticks: bool,
}

impl SampleEncoder {
    /// An encoder for `config`'s input messages, in the order reversing
    /// signal, yaw rate, steering, front, rear (a reader then steps with
    /// this sample's direction, yaw rate, front and steering).
    pub fn new(config: &Config) -> Self {
        let s = &config.signals;
        let db = &config.db;
        let mut order = Vec::new();
        order.extend(s.direction.map(|d| d.message_index));
        order.extend(s.yaw_rate.map(|y| y.signal.message_index));
        order.extend([
            s.steering.message_index,
            s.wheels.front_left.message_index,
            s.wheels.rear_left.message_index,
        ]);
        let mut seen = Vec::new();
        order.retain(|i| {
            let new = !seen.contains(i);
            seen.push(*i);
            new
        });
        let messages = order
            .into_iter()
            .map(|idx| {
                let m = &db.messages()[idx];
                let check = config.checks.iter().find(|c| c.message_index == idx);
                let wheels = Wheel::ALL
                    .iter()
                    .filter(|&&w| s.wheels[w].message_index == idx)
                    .map(|&w| (w, s.wheels[w].form))
                    .collect();
                let id = m.id();
                OutMessage {
                    id: if id.is_extended() {
                        FrameId::Extended(id.raw())
                    } else {
                        FrameId::Standard(id.raw() as u16)
                    },
                    length: m.length(),
                    wheels,
                    steering: s.steering.message_index == idx,
                    yaw: s.yaw_rate.is_some_and(|y| y.signal.message_index == idx),
                    direction: s.direction.is_some_and(|d| d.message_index == idx),
                    counter: check.and_then(|c| c.counter),
                    counter_value: 0,
                    checksum: check.and_then(|c| c.checksum.clone()),
                }
            })
            .collect();
        Self {
            messages,
            steering: s.steering.form,
            yaw: s.yaw_rate.map(|y| (y.signal.form, y.radps_per_unit)),
            direction: s.direction,
            wheel_speed_factor: s.wheel_speed_factor,
            ticks: s.wheel_kind == WheelKind::Ticks,
        }
    }

    /// The frames of one sample, appended to `out`.
    pub fn encode(&mut self, sample: &canodom_fusion::sim::Sample, out: &mut Vec<CanFrame>) {
        for m in &mut self.messages {
            let mut buf = [0u8; 64];
            let data = &mut buf[..m.length];
            let speeds = &sample.wheel_speed;
            let reversing = speeds.rear_left + speeds.rear_right < 0.0;
            if m.direction
                && let Some(d) = &self.direction
            {
                let raw = if reversing {
                    d.reverse_raw()
                } else {
                    d.forward_raw
                };
                d.handle.encode_raw(raw, data);
            }
            for &(w, f) in &m.wheels {
                if self.ticks {
                    f.main.encode_raw(sample.ticks[w], data);
                } else {
                    let v = speeds[w] / self.wheel_speed_factor;
                    // Beyond the signal's range the form sends its largest magnitude.
                    f.encode(if self.direction.is_some() { v.abs() } else { v }, data);
                }
            }
            if m.yaw
                && let Some((f, per_unit)) = &self.yaw
            {
                f.encode(sample.yaw_rate_radps / per_unit, data);
            }
            if m.steering {
                self.steering.encode(sample.steer_signal, data);
            }
            if let Some(c) = m.counter {
                c.encode_raw(m.counter_value, data);
                m.counter_value = m.counter_value.wrapping_add(1);
            }
            if let Some(crc) = &m.checksum {
                // The configured layout fits the message (checked at load).
                let _ = crc.apply(data);
            }
            if let Ok(f) = CanFrame::new_data(m.id, data) {
                out.push(f);
            }
        }
    }
}
