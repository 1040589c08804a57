//! The deterministic ground-truth vehicle simulator: the judge of every test
//! in the project.
//!
//! A car with *true* parameters (which may differ from the nominal ones the
//! odometry uses) drives a [`Plan`] from rest to rest. The driver turns the
//! plan's curvature into a steering command through their *belief* of the
//! steering map (default: the true map; a wrong belief reproduces the
//! order-of-operations trap of `docs/calibration-math.md` §10). The actuator
//! follows the command with a first-order servo lag and path-following noise
//! (Ornstein–Uhlenbeck steering and speed noise, §9). The car moves as a
//! bicycle at the rear axle, integrated with exact arcs; each wheel rolls
//! `ds·g_i` (§3), times `1 + ratio` while it slips.
//!
//! At every output period the simulator emits a [`Sample`]: the four wheels'
//! wrapping tick counters and speeds (both always, quantised as configured),
//! the measured steering signal (noise, bias, slow drift, quantisation), and
//! the ground truth (pose, steering angle, wheel distances, slip flags).
//!
//! Everything random comes from one `ChaCha8Rng` seeded by the caller, so a
//! run is a pure function of (config, plan, seed). With
//! [`PathFollowing::NONE`], [`SteeringSensor::EXACT`] and [`SlipConfig::NONE`]
//! the run is exact: the car drives the plan's geometry to rounding error.

pub mod family;
pub mod plan;

pub use plan::{Direction, Plan, Segment};

use crate::error::{Error, Result, require_non_negative, require_positive};
use crate::odometry::{Pose, wheel_distance_factors};
use crate::params::{SteeringMap, VehicleParams};
use crate::wheel::SpeedUnit;
use crate::{Wheel, WheelSet};
use plan::Steer;
use rand::{Rng, RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// An Ornstein–Uhlenbeck process: stationary standard deviation `sigma`,
/// correlation time `tau_s`. A `sigma` of 0 switches it off.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OuNoise {
    /// Stationary standard deviation (in the quantity's unit).
    pub sigma: f64,
    /// Correlation time.
    pub tau_s: f64,
}

impl OuNoise {
    /// No noise.
    pub const OFF: Self = Self {
        sigma: 0.0,
        tau_s: 1.0,
    };
}

/// How closely the car follows the plan (`docs/calibration-math.md` §9).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathFollowing {
    /// Noise added to the road-wheel angle command, radians.
    pub steer_noise_rad: OuNoise,
    /// Relative speed noise (0.01 = 1 %).
    pub speed_noise: OuNoise,
    /// First-order lag of the steering servo (0 = instantaneous).
    pub servo_lag_s: f64,
    /// Fastest the road-wheel angle can change (a driver turning the wheel,
    /// or a rate-limited actuator); `f64::INFINITY` lets it jump.
    pub steer_rate_limit_rad_per_s: f64,
}

impl PathFollowing {
    /// Perfect following: the car drives the plan exactly.
    pub const NONE: Self = Self {
        steer_noise_rad: OuNoise::OFF,
        speed_noise: OuNoise::OFF,
        servo_lag_s: 0.0,
        steer_rate_limit_rad_per_s: f64::INFINITY,
    };

    /// §9's driver: OU noise of 0.15° steering and 1 % speed (2 s), 0.15 s servo lag.
    pub const PAPER: Self = Self {
        steer_noise_rad: OuNoise {
            sigma: 0.15 * std::f64::consts::PI / 180.0,
            tau_s: 2.0,
        },
        speed_noise: OuNoise {
            sigma: 0.01,
            tau_s: 2.0,
        },
        servo_lag_s: 0.15,
        steer_rate_limit_rad_per_s: f64::INFINITY,
    };
}

/// How the tyres turn the steering angle into motion. Kinematic (the
/// default) means no lateral slip: the car drives the Ackermann geometry.
/// A real car's tyres need slip angles to carry lateral force, so at
/// lateral acceleration `a_y` it turns less than the kinematic path
/// (understeer) and its rear axle slides sideways (a sideslip angle at the
/// rear axle); the linear single-track model's steady state gives both as
/// gradients in `a_y`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TyreModel {
    /// Understeer gradient `K_us`: the path curvature is
    /// `tan φ / (L + K_us v²)`, radians of road-wheel angle per m/s² of
    /// lateral acceleration (0.0025 ≈ 1.4°/g, a typical passenger car).
    pub understeer_rad_per_mps2: f64,
    /// Rear-axle sideslip per m/s² of lateral acceleration, radians: the
    /// rear axle's velocity points `−k·a_y` off the heading (outwards).
    pub rear_sideslip_rad_per_mps2: f64,
    /// First-order lag of the body's curvature behind the steady state of
    /// the steering angle, s: a real car's yaw builds up through its tyres'
    /// lateral forces (0.1–0.4 s), so the steering leads the yaw in every
    /// turn-in and exit. 0 = none.
    pub yaw_lag_s: f64,
}

impl TyreModel {
    /// No lateral slip: the kinematic Ackermann car.
    pub const KINEMATIC: Self = Self {
        understeer_rad_per_mps2: 0.0,
        rear_sideslip_rad_per_mps2: 0.0,
        yaw_lag_s: 0.0,
    };

    /// A mid-size passenger car: 1.4°/g understeer, 0.25° of rear sideslip
    /// per m/s² (1.1° at 4.3 m/s², a 15 m circle at 8 m/s).
    pub const PASSENGER_CAR: Self = Self {
        understeer_rad_per_mps2: 0.0025,
        rear_sideslip_rad_per_mps2: 0.0044,
        yaw_lag_s: 0.0,
    };

    fn is_kinematic(&self) -> bool {
        self.understeer_rad_per_mps2 == 0.0
            && self.rear_sideslip_rad_per_mps2 == 0.0
            && self.yaw_lag_s == 0.0
    }
}

/// The vehicle's yaw-rate sensor (an ESC's gyro): `scale · ω + bias + white`,
/// quantised. Production sensors have biases of tenths of a degree per
/// second that drift with temperature, and a scale error of a per cent.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct YawRateSensor {
    /// Constant bias, rad/s.
    pub bias_radps: f64,
    /// Scale factor (1 = exact).
    pub scale: f64,
    /// White noise per sample, rad/s.
    pub white_sigma_radps: f64,
    /// Quantisation step, rad/s (0 = none).
    pub quantum_radps: f64,
}

impl YawRateSensor {
    /// A perfect sensor.
    pub const EXACT: Self = Self {
        bias_radps: 0.0,
        scale: 1.0,
        white_sigma_radps: 0.0,
        quantum_radps: 0.0,
    };
}

/// The error of the steering measurement the vehicle reports. All angles are
/// road-wheel radians; the result is converted to the signal through the true
/// steering map and then quantised in signal units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SteeringSensor {
    /// White noise per sample.
    pub white_sigma_rad: f64,
    /// A fixed bias.
    pub bias_rad: f64,
    /// A bias drawn once per run, N(0, this).
    pub bias_sigma_rad: f64,
    /// A slowly varying offset.
    pub drift_rad: OuNoise,
    /// Quantisation step of the signal, in signal units (0 = none), e.g. 1.5
    /// for a steering-wheel angle in degrees as the Toyota file sends it.
    pub quantum: f64,
}

impl SteeringSensor {
    /// A perfect sensor.
    pub const EXACT: Self = Self {
        white_sigma_rad: 0.0,
        bias_rad: 0.0,
        bias_sigma_rad: 0.0,
        drift_rad: OuNoise::OFF,
        quantum: 0.0,
    };
}

/// Which wheels may slip.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SlipWheels {
    /// The two rear wheels.
    Rear,
    /// The two front wheels.
    Front,
    /// All four.
    All,
}

impl SlipWheels {
    fn includes(self, wheel: Wheel) -> bool {
        match self {
            SlipWheels::Rear => wheel.is_rear(),
            SlipWheels::Front => !wheel.is_rear(),
            SlipWheels::All => true,
        }
    }
}

/// Wheel-slip events: per wheel a Poisson process; during an event the
/// wheel's *reported* distance is multiplied by `1 + ratio`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlipConfig {
    /// Events per second per eligible wheel (0 = no slip).
    pub rate_per_s: f64,
    /// The ratio is drawn N(0, this) per event.
    pub ratio_sigma: f64,
    /// Shortest event.
    pub min_duration_s: f64,
    /// Longest event (durations are uniform in between).
    pub max_duration_s: f64,
    /// Which wheels slip.
    pub wheels: SlipWheels,
}

impl SlipConfig {
    /// No slip.
    pub const NONE: Self = Self {
        rate_per_s: 0.0,
        ratio_sigma: 0.0,
        min_duration_s: 0.5,
        max_duration_s: 2.0,
        wheels: SlipWheels::All,
    };

    /// §11's slips: 0.02 events/s per wheel, ratio N(0, 0.35), 0.5–2 s, on `wheels`.
    pub fn paper(wheels: SlipWheels) -> Self {
        Self {
            rate_per_s: 0.02,
            ratio_sigma: 0.35,
            wheels,
            ..Self::NONE
        }
    }
}

/// How the wheels are reported.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WheelOutput {
    /// Width of the wrapping tick counters (1..=64).
    pub counter_bits: u32,
    /// Unit of the reported wheel speeds.
    pub speed_unit: SpeedUnit,
    /// Quantisation step of the speeds in `speed_unit` (0 = none), e.g. 0.01 km/h.
    pub speed_quantum: f64,
    /// Start the counters at random values (so tests cross the wrap point);
    /// otherwise at 0.
    pub random_counter_start: bool,
    /// Speeds below this (m/s) are reported as 0, as many production
    /// wheel-speed sensors do below about 2 km/h (0 = none). Ticks are exact.
    pub zero_below_mps: f64,
}

impl WheelOutput {
    /// 16-bit counters (as `rc_car.dbc`), speeds in m/s unquantised.
    pub const RC_CAR: Self = Self {
        counter_bits: 16,
        speed_unit: SpeedUnit::MetresPerSecond,
        speed_quantum: 0.0,
        random_counter_start: true,
        zero_below_mps: 0.0,
    };
    /// Speeds in km/h quantised to 0.01 (the Toyota file's `WHEEL_SPEEDS`).
    pub const ROAD_CAR: Self = Self {
        counter_bits: 32,
        speed_unit: SpeedUnit::KilometresPerHour,
        speed_quantum: 0.01,
        random_counter_start: true,
        zero_below_mps: 0.0,
    };
}

/// Everything that defines a simulated vehicle and its driver.
#[derive(Debug, Clone, PartialEq)]
pub struct SimConfig {
    /// The physical vehicle, including its true steering map φ = gain·u + offset.
    pub true_params: VehicleParams,
    /// The driver's belief of the steering map, used to turn intended
    /// curvature into a command (`None`: the true map).
    pub driver_steering: Option<SteeringMap>,
    /// Cruising speed of the rear-axle centre.
    pub speed_mps: f64,
    /// Acceleration and braking at the start and end of the plan.
    pub accel_mps2: f64,
    /// Output rate (also the integration rate).
    pub rate_hz: f64,
    /// Time at rest before moving off and after stopping.
    pub standstill_s: f64,
    /// Path-following noise and servo lag.
    pub path_following: PathFollowing,
    /// The steering measurement's errors.
    pub steering_sensor: SteeringSensor,
    /// Wheel slip.
    pub slip: SlipConfig,
    /// How wheels are reported.
    pub wheel_output: WheelOutput,
    /// Tyre slip angles (kinematic by default).
    pub tyres: TyreModel,
    /// The yaw-rate sensor's errors (exact by default).
    pub yaw_rate_sensor: YawRateSensor,
}

impl SimConfig {
    /// The 1:10 car of §9 at 0.1 m/s and 100 Hz, with §9's path-following
    /// noise, an exact steering sensor and no slip.
    pub fn rc_car(true_params: VehicleParams) -> Self {
        Self {
            true_params,
            driver_steering: None,
            speed_mps: 0.1,
            accel_mps2: 0.5,
            rate_hz: 100.0,
            standstill_s: 1.0,
            path_following: PathFollowing::PAPER,
            steering_sensor: SteeringSensor::EXACT,
            slip: SlipConfig::NONE,
            wheel_output: WheelOutput::RC_CAR,
            tyres: TyreModel::KINEMATIC,
            yaw_rate_sensor: YawRateSensor::EXACT,
        }
    }

    /// Like [`SimConfig::rc_car`] with every noise, lag and slip off: exact.
    pub fn noise_free(true_params: VehicleParams) -> Self {
        Self {
            path_following: PathFollowing::NONE,
            ..Self::rc_car(true_params)
        }
    }

    /// The full-size car of §12 at 8 m/s and 100 Hz: speeds in km/h
    /// quantised to 0.01, the steering signal a steering-wheel angle in
    /// degrees (`true_params`' map should carry the ratio, e.g. gain
    /// `(π/180)/15`) in 1.5° steps, with `steering_sensor` errors as given.
    pub fn road_car(true_params: VehicleParams, steering_sensor: SteeringSensor) -> Self {
        Self {
            true_params,
            driver_steering: None,
            speed_mps: 8.0,
            accel_mps2: 2.0,
            rate_hz: 100.0,
            standstill_s: 1.0,
            path_following: PathFollowing {
                servo_lag_s: 0.1,
                ..PathFollowing::PAPER
            },
            steering_sensor,
            slip: SlipConfig::NONE,
            wheel_output: WheelOutput::ROAD_CAR,
            tyres: TyreModel::KINEMATIC,
            yaw_rate_sensor: YawRateSensor::EXACT,
        }
    }

    fn validate(&self) -> Result<()> {
        let positive = require_positive;
        let non_negative = require_non_negative;
        positive("speed_mps", self.speed_mps)?;
        positive("accel_mps2", self.accel_mps2)?;
        positive("rate_hz", self.rate_hz)?;
        non_negative("standstill_s", self.standstill_s)?;
        let pf = &self.path_following;
        non_negative("servo_lag_s", pf.servo_lag_s)?;
        non_negative("yaw_lag_s", self.tyres.yaw_lag_s)?;
        if pf.steer_rate_limit_rad_per_s.is_nan() || pf.steer_rate_limit_rad_per_s <= 0.0 {
            return Err(Error::InvalidConfig {
                name: "steer_rate_limit_rad_per_s",
                reason: format!(
                    "must be > 0 (or infinite), got {}",
                    pf.steer_rate_limit_rad_per_s
                ),
            });
        }
        non_negative("zero_below_mps", self.wheel_output.zero_below_mps)?;
        let y = &self.yaw_rate_sensor;
        non_negative("yaw white_sigma_radps", y.white_sigma_radps)?;
        non_negative("yaw quantum_radps", y.quantum_radps)?;
        for (name, v) in [("yaw bias_radps", y.bias_radps), ("yaw scale", y.scale)] {
            if !v.is_finite() {
                return Err(Error::InvalidConfig {
                    name,
                    reason: format!("must be finite, got {v}"),
                });
            }
        }
        for (name, v) in [
            (
                "understeer_rad_per_mps2",
                self.tyres.understeer_rad_per_mps2,
            ),
            (
                "rear_sideslip_rad_per_mps2",
                self.tyres.rear_sideslip_rad_per_mps2,
            ),
            ("yaw_lag_s", self.tyres.yaw_lag_s),
        ] {
            if !v.is_finite() {
                return Err(Error::InvalidConfig {
                    name,
                    reason: format!("must be finite, got {v}"),
                });
            }
        }
        for (name, ou) in [
            ("steer_noise_rad", pf.steer_noise_rad),
            ("speed_noise", pf.speed_noise),
            ("drift_rad", self.steering_sensor.drift_rad),
        ] {
            non_negative(name, ou.sigma)?;
            positive(name, ou.tau_s)?;
        }
        let s = &self.steering_sensor;
        non_negative("white_sigma_rad", s.white_sigma_rad)?;
        non_negative("bias_sigma_rad", s.bias_sigma_rad)?;
        non_negative("steering quantum", s.quantum)?;
        if !s.bias_rad.is_finite() {
            return Err(Error::InvalidConfig {
                name: "bias_rad",
                reason: format!("must be finite, got {}", s.bias_rad),
            });
        }
        non_negative("slip rate_per_s", self.slip.rate_per_s)?;
        non_negative("slip ratio_sigma", self.slip.ratio_sigma)?;
        non_negative("slip min_duration_s", self.slip.min_duration_s)?;
        if !(self.slip.max_duration_s.is_finite()
            && self.slip.max_duration_s >= self.slip.min_duration_s)
        {
            return Err(Error::InvalidConfig {
                name: "slip max_duration_s",
                reason: "must be finite and >= min_duration_s".into(),
            });
        }
        if !(1..=64).contains(&self.wheel_output.counter_bits) {
            return Err(Error::InvalidCounterWidth {
                bits: self.wheel_output.counter_bits,
            });
        }
        non_negative("speed_quantum", self.wheel_output.speed_quantum)?;
        if let Some(m) = self.driver_steering {
            m.signal_for(0.0)?;
        }
        Ok(())
    }
}

/// One timestamped output of the simulator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Time since the start of the run.
    pub t_s: f64,
    /// The four cumulative tick counters, wrapped to `counter_bits`.
    pub ticks: WheelSet<u64>,
    /// The four wheel speeds in the configured unit, quantised, signed: the
    /// wheel's rotation rate times the circumference of the mean of the four
    /// true diameters (an ECU uses one tyre size), so unequal tyres show.
    pub wheel_speed: WheelSet<f64>,
    /// The measured steering signal (noise, bias, drift, quantisation).
    pub steer_signal: f64,
    /// The steering command sent to the actuator, in signal units.
    pub steer_command: f64,
    /// Ground truth: the rear-axle centre's pose, heading unwrapped.
    pub true_pose: Pose,
    /// Ground truth: the road-wheel angle of the equivalent centre wheel.
    pub true_steer_angle_rad: f64,
    /// Ground truth: the rear-axle centre's cumulative path length (signed).
    pub true_distance_m: f64,
    /// Ground truth: each wheel's cumulative rolled distance, without slip.
    pub true_wheel_distance_m: WheelSet<f64>,
    /// Each wheel's cumulative reported distance (slip included, before
    /// quantisation into ticks).
    pub wheel_distance_m: WheelSet<f64>,
    /// Which wheels are slipping at this sample.
    pub slipping: WheelSet<bool>,
    /// The measured yaw rate (bias, scale, noise, quantisation), rad/s.
    pub yaw_rate_radps: f64,
    /// Ground truth: the yaw rate over the last period, rad/s.
    pub true_yaw_rate_radps: f64,
}

/// A finished run: all samples and the truth at its end.
#[derive(Debug, Clone, PartialEq)]
pub struct Run {
    /// The samples, the first at t = 0 at rest.
    pub samples: Vec<Sample>,
    /// The true end pose (heading unwrapped).
    pub true_end: Pose,
    /// The steering sensor bias drawn for this run (fixed + random part), radians.
    pub steer_bias_rad: f64,
    /// Slip events started during the run.
    pub slip_events: u32,
}

#[derive(Debug, Clone, Copy)]
struct Ou {
    value: f64,
    decay: f64,
    kick: f64,
}

impl Ou {
    fn new(cfg: OuNoise, dt_s: f64, rng: &mut impl Rng) -> Self {
        let decay = (-dt_s / cfg.tau_s).exp();
        let value = if cfg.sigma > 0.0 {
            cfg.sigma * rng.sample::<f64, _>(StandardNormal)
        } else {
            0.0
        };
        Self {
            value,
            decay,
            kick: cfg.sigma * (1.0 - decay * decay).sqrt(),
        }
    }

    fn step(&mut self, rng: &mut impl Rng) -> f64 {
        if self.kick > 0.0 {
            self.value = self.value * self.decay + self.kick * rng.sample::<f64, _>(StandardNormal);
        }
        self.value
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    Start,
    Before(u64),
    Moving,
    After(u64),
    /// At rest at a [`Segment::Stop`]: steps stood so far, steps to stand.
    Paused(u64, u64),
    Done,
}

/// The simulator as an iterator of [`Sample`]s, for streaming (a simulated
/// vehicle on a bus) or for runs too long to collect.
#[derive(Debug, Clone)]
pub struct Simulator {
    cfg: SimConfig,
    plan: Plan,
    rng: ChaCha8Rng,
    dt_s: f64,
    step: u64,
    phase: Phase,
    standstill_steps: u64,
    // Plan progress: which segment, how far into it, and overall.
    segment: usize,
    segment_s_m: f64,
    plan_s_m: f64,
    plan_length_m: f64,
    speed_cmd_mps: f64,
    pose: Pose,
    distance_m: f64,
    steer_angle_rad: f64,
    steer_command: f64,
    steer_noise: Ou,
    speed_noise: Ou,
    sensor_drift: Ou,
    servo_alpha_per_s: f64,
    bias_rad: f64,
    true_wheel_m: WheelSet<f64>,
    wheel_m: WheelSet<f64>,
    ticks_f: WheelSet<f64>,
    tick_offset: WheelSet<u64>,
    wheel_speed_mps: WheelSet<f64>,
    slip_left_s: WheelSet<f64>,
    slip_ratio: WheelSet<f64>,
    slip_events: u32,
    /// The body's curvature lagging its steady state ([`TyreModel::yaw_lag_s`]).
    lagged_kappa: f64,
    /// The true yaw rate over the last period.
    yaw_rate_radps: f64,
    /// +1 forwards, −1 reversing.
    direction: f64,
    /// The plan's stops in order: position along the plan, duration, reverse.
    stops: Vec<(f64, f64, bool)>,
    /// How many of `stops` the car has made.
    stops_done: usize,
    /// The plan's speed marks in order: position along the plan, speed.
    speed_marks: Vec<(f64, f64)>,
}

impl Simulator {
    /// A simulator for `plan` driven with `config`, deterministic for `seed`.
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] (or [`Error::InvalidCounterWidth`]) for a bad
    /// configuration value, or an empty plan.
    pub fn new(config: &SimConfig, plan: &Plan, seed: u64) -> Result<Self> {
        config.validate()?;
        let plan = Plan::new(plan.segments.clone())?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let dt_s = 1.0 / config.rate_hz;
        let pf = config.path_following;
        let steer_noise = Ou::new(pf.steer_noise_rad, dt_s, &mut rng);
        let speed_noise = Ou::new(pf.speed_noise, dt_s, &mut rng);
        let sensor_drift = Ou::new(config.steering_sensor.drift_rad, dt_s, &mut rng);
        let bias_rad = config.steering_sensor.bias_rad
            + config.steering_sensor.bias_sigma_rad * rng.sample::<f64, _>(StandardNormal);
        let bits = config.wheel_output.counter_bits;
        let tick_offset = WheelSet::splat(0u64).map(|_, _| {
            if config.wheel_output.random_counter_start {
                rng.random::<u64>() & counter_mask(bits)
            } else {
                0
            }
        });
        let servo_alpha_per_s = if pf.servo_lag_s > 0.0 {
            1.0 / pf.servo_lag_s
        } else {
            f64::INFINITY
        };
        let mut sim = Self {
            plan_length_m: plan.length_m(),
            cfg: config.clone(),
            plan,
            rng,
            dt_s,
            step: 0,
            phase: Phase::Start,
            standstill_steps: (config.standstill_s * config.rate_hz).round() as u64,
            segment: 0,
            segment_s_m: 0.0,
            plan_s_m: 0.0,
            speed_cmd_mps: 0.0,
            pose: Pose::default(),
            distance_m: 0.0,
            steer_angle_rad: 0.0,
            steer_command: 0.0,
            steer_noise,
            speed_noise,
            sensor_drift,
            servo_alpha_per_s,
            bias_rad,
            true_wheel_m: WheelSet::splat(0.0),
            wheel_m: WheelSet::splat(0.0),
            ticks_f: WheelSet::splat(0.0),
            tick_offset,
            wheel_speed_mps: WheelSet::splat(0.0),
            slip_left_s: WheelSet::splat(0.0),
            slip_ratio: WheelSet::splat(0.0),
            slip_events: 0,
            lagged_kappa: 0.0,
            yaw_rate_radps: 0.0,
            direction: 1.0,
            stops: Vec::new(),
            stops_done: 0,
            speed_marks: Vec::new(),
        };
        let mut at_m = 0.0;
        for seg in &sim.plan.segments {
            match *seg {
                Segment::Stop {
                    duration_s,
                    reverse,
                } => sim.stops.push((at_m, duration_s, reverse)),
                Segment::Speed { speed_mps } => sim.speed_marks.push((at_m, speed_mps)),
                _ => at_m += seg.length_m(),
            }
        }
        // At rest the wheels point where the first segment asks, as a driver would.
        let first = sim.command_for(0.0)?;
        sim.steer_command = first;
        sim.steer_angle_rad = sim.cfg.true_params.steering().angle_rad(first);
        Ok(sim)
    }

    /// The true pose now.
    pub fn true_pose(&self) -> Pose {
        self.pose
    }

    /// The steering sensor bias drawn for this run.
    pub fn steer_bias_rad(&self) -> f64 {
        self.bias_rad
    }

    /// Slip events started so far.
    pub fn slip_events(&self) -> u32 {
        self.slip_events
    }

    /// Steering command (signal units) for the plan at `s_m` from its start.
    fn command_for(&self, segment_s_m: f64) -> Result<f64> {
        let seg = self.plan.segments[self.segment.min(self.plan.segments.len() - 1)];
        match seg.steer_at(segment_s_m) {
            Steer::Signal(u) => Ok(u),
            Steer::Curvature(kappa) => {
                // The driver follows the road: with understeer they steer as
                // much more as the car needs at this speed.
                let v = self.speed_cmd_mps;
                let effective_wheelbase_m = self.cfg.true_params.wheelbase_m()
                    + self.cfg.tyres.understeer_rad_per_mps2 * v * v;
                let phi = (effective_wheelbase_m * kappa).atan();
                self.cfg
                    .driver_steering
                    .unwrap_or(self.cfg.true_params.steering())
                    .signal_for(phi)
            }
        }
    }

    fn sample(&mut self) -> Sample {
        let s = &self.cfg.steering_sensor;
        let white = if s.white_sigma_rad > 0.0 {
            s.white_sigma_rad * self.rng.sample::<f64, _>(StandardNormal)
        } else {
            0.0
        };
        let drift = self.sensor_drift.step(&mut self.rng);
        let measured_rad = self.steer_angle_rad + self.bias_rad + drift + white;
        let map = self.cfg.true_params.steering();
        // The gain was validated non-zero, so the inverse exists.
        let mut signal = (measured_rad - map.offset_rad) / map.gain;
        if s.quantum > 0.0 {
            signal = (signal / s.quantum).round() * s.quantum;
        }
        let out = self.cfg.wheel_output;
        let mask = counter_mask(out.counter_bits);
        let offset = self.tick_offset;
        let ticks = self
            .ticks_f
            .map(|w, t| (t.floor() as i64 as u64).wrapping_add(offset[w]) & mask);
        let wheel_speed = self.wheel_speed_mps.map(|_, v| {
            let v = if v.abs() < out.zero_below_mps { 0.0 } else { v };
            let v = out.speed_unit.from_mps(v);
            if out.speed_quantum > 0.0 {
                (v / out.speed_quantum).round() * out.speed_quantum
            } else {
                v
            }
        });
        let slip_left = self.slip_left_s;
        let y = self.cfg.yaw_rate_sensor;
        // Drawn only for a noisy sensor, so other runs keep their random sequence.
        let yaw_white = if y.white_sigma_radps > 0.0 {
            y.white_sigma_radps * self.rng.sample::<f64, _>(StandardNormal)
        } else {
            0.0
        };
        let mut yaw_rate_radps = y.scale * self.yaw_rate_radps + y.bias_radps + yaw_white;
        if y.quantum_radps > 0.0 {
            yaw_rate_radps = (yaw_rate_radps / y.quantum_radps).round() * y.quantum_radps;
        }
        Sample {
            t_s: self.step as f64 * self.dt_s,
            ticks,
            wheel_speed,
            steer_signal: signal,
            steer_command: self.steer_command,
            true_pose: self.pose,
            true_steer_angle_rad: self.steer_angle_rad,
            true_distance_m: self.distance_m,
            true_wheel_distance_m: self.true_wheel_m,
            wheel_distance_m: self.wheel_m,
            slipping: slip_left.map(|_, t| t > 0.0),
            yaw_rate_radps,
            true_yaw_rate_radps: self.yaw_rate_radps,
        }
    }

    /// Advances the slip processes by one period.
    fn step_slip(&mut self) {
        let cfg = self.cfg.slip;
        if cfg.rate_per_s <= 0.0 {
            return;
        }
        let p_start = 1.0 - (-cfg.rate_per_s * self.dt_s).exp();
        for w in Wheel::ALL {
            if self.slip_left_s[w] > 0.0 {
                self.slip_left_s[w] -= self.dt_s;
                if self.slip_left_s[w] <= 0.0 {
                    self.slip_left_s[w] = 0.0;
                    self.slip_ratio[w] = 0.0;
                }
            } else if cfg.wheels.includes(w) && self.rng.random::<f64>() < p_start {
                self.slip_ratio[w] = cfg.ratio_sigma * self.rng.sample::<f64, _>(StandardNormal);
                self.slip_left_s[w] = self
                    .rng
                    .random_range(cfg.min_duration_s..=cfg.max_duration_s);
                self.slip_events += 1;
            }
        }
    }

    /// Moves the car by `ds_m` of rear-axle path with a constant road-wheel angle.
    /// The path curvature of the rear-axle centre, its sideslip angle and
    /// each wheel's rolled distance per metre of that path, at road-wheel
    /// angle `phi_rad` and speed `v_mps`. Kinematic tyres give `tan φ / L`,
    /// 0 and the `g_i` of §3 exactly; with slip angles the wheels' speeds
    /// are the body's velocity at each contact point projected on the
    /// wheel's rolling direction (Ackermann wheel angles).
    fn motion(&self, phi_rad: f64, v_mps: f64) -> (f64, f64, WheelSet<f64>) {
        let p = &self.cfg.true_params;
        let l = p.wheelbase_m();
        if self.cfg.tyres.is_kinematic() {
            let [g_rl, g_rr, g_fl, g_fr] = wheel_distance_factors(p, phi_rad);
            let g = WheelSet {
                rear_left: g_rl,
                rear_right: g_rr,
                front_left: g_fl,
                front_right: g_fr,
            };
            return (phi_rad.tan() / l, 0.0, g);
        }
        let t = self.cfg.tyres;
        let tan_phi = phi_rad.tan();
        let kappa = if t.yaw_lag_s > 0.0 {
            self.lagged_kappa
        } else {
            tan_phi / (l + t.understeer_rad_per_mps2 * v_mps * v_mps)
        };
        let beta = -t.rear_sideslip_rad_per_mps2 * v_mps * v_mps * kappa;
        let (vy, vx) = beta.sin_cos();
        let (half_b, half_bf) = (0.5 * p.rear_tread_m(), 0.5 * p.front_tread_m());
        // Ackermann wheel angles of the kinematic geometry for this φ.
        let kappa_k = tan_phi / l;
        let front = |side: f64| {
            let delta = (l * kappa_k).atan2(1.0 - side * kappa_k * half_bf);
            let (sd, cd) = delta.sin_cos();
            (vx - side * kappa * half_bf) * cd + (vy + kappa * l) * sd
        };
        let g = WheelSet {
            rear_left: vx - kappa * half_b,
            rear_right: vx + kappa * half_b,
            front_left: front(1.0),
            front_right: front(-1.0),
        };
        (kappa, beta, g)
    }

    fn roll(&mut self, ds_m: f64, phi_rad: f64, v_mps: f64) {
        let (kappa, beta, g) = self.motion(phi_rad, v_mps);
        let t = self.cfg.tyres;
        if t.yaw_lag_s > 0.0 && v_mps > 0.0 {
            let l = self.cfg.true_params.wheelbase_m();
            let steady = phi_rad.tan() / (l + t.understeer_rad_per_mps2 * v_mps * v_mps);
            let dt = ds_m.abs() / v_mps;
            self.lagged_kappa += (steady - self.lagged_kappa) * (1.0 - (-dt / t.yaw_lag_s).exp());
        }
        let dtheta = kappa * ds_m;
        let half = 0.5 * dtheta;
        let sinc = if half.abs() < 1e-4 {
            1.0 - half * half / 6.0
        } else {
            half.sin() / half
        };
        let mid = self.pose.heading_rad + half + beta;
        let (s, c) = mid.sin_cos();
        self.pose.x_m += ds_m * sinc * c;
        self.pose.y_m += ds_m * sinc * s;
        self.pose.heading_rad += dtheta;
        self.distance_m += ds_m.abs();
        let p = &self.cfg.true_params;
        for w in Wheel::ALL {
            let true_m = ds_m * g[w];
            let reported_m = true_m * (1.0 + self.slip_ratio[w]);
            self.true_wheel_m[w] += true_m;
            self.wheel_m[w] += reported_m;
            self.ticks_f[w] += reported_m / p.tick_distance_m(w, 1.0);
        }
    }

    /// One period of driving.
    fn drive(&mut self) -> Result<()> {
        let dt = self.dt_s;
        let a = self.cfg.accel_mps2;
        // The car stops at the next stop mark, or at the plan's end.
        let stop = self.stops.get(self.stops_done).copied();
        let stop_at_m = stop.map_or(self.plan_length_m, |(at_m, _, _)| at_m);
        let remaining_m = stop_at_m - self.plan_s_m;
        let v0 = self.speed_cmd_mps;
        let target_mps = self.target_speed_mps();
        let mut v1 = if v0 > target_mps {
            (v0 - a * dt).max(target_mps)
        } else {
            (v0 + a * dt).min(target_mps)
        }
        .min((2.0 * a * remaining_m).sqrt());
        // The plan is indexed by the distance actually driven: a driver steers
        // by where they are on the track and stops at the end mark, so speed
        // noise changes the timing, not the geometry. (Indexed by time, 1 %
        // speed noise alone would spread the track's end by 2.5 cm and the
        // total to 4.7 cm, against §9's 2.5–3.5 cm; this way it is 3.3 cm.)
        let speed_factor = 1.0 + self.speed_noise.step(&mut self.rng);
        let mut step_m = 0.5 * (v0 + v1) * dt * speed_factor;
        // The last step covers what is left and stops the car: the run ends
        // exactly at the plan's length whatever rounding accumulated.
        let last_step = step_m >= remaining_m || remaining_m < 1e-12;
        if last_step {
            step_m = remaining_m.max(0.0);
            v1 = 0.0;
        }
        let v_mean_mps = 0.5 * (v0 + v1) * speed_factor;
        self.speed_cmd_mps = v1;
        let steer_noise = self.steer_noise.step(&mut self.rng);
        self.step_slip();
        let map = self.cfg.true_params.steering();
        // Split the step at segment boundaries so noise-free runs are exact.
        let mut left_m = step_m;
        while left_m > 0.0 {
            let seg_len = self.plan.segments[self.segment].length_m();
            let piece_m = left_m.min(seg_len - self.segment_s_m).max(0.0);
            let piece_dt = if step_m > 0.0 {
                dt * piece_m / step_m
            } else {
                dt
            };
            let u = self.command_for(self.segment_s_m + 0.5 * piece_m)?;
            self.steer_command = u;
            let phi_cmd = map.angle_rad(u) + steer_noise;
            let phi_old = self.steer_angle_rad;
            let phi_new = if self.servo_alpha_per_s.is_finite() {
                phi_cmd + (phi_old - phi_cmd) * (-self.servo_alpha_per_s * piece_dt).exp()
            } else {
                phi_cmd
            };
            let rate = self.cfg.path_following.steer_rate_limit_rad_per_s;
            let phi_new = if rate.is_finite() {
                let most = rate * piece_dt;
                phi_old + (phi_new - phi_old).clamp(-most, most)
            } else {
                phi_new
            };
            let phi_mean = if self.servo_alpha_per_s.is_finite() || rate.is_finite() {
                0.5 * (phi_old + phi_new)
            } else {
                phi_cmd
            };
            if phi_mean.abs() >= 1.5 {
                return Err(Error::SteeringOutOfRange {
                    steer_angle_rad: phi_mean,
                });
            }
            self.steer_angle_rad = phi_new;
            self.roll(self.direction * piece_m, phi_mean, v_mean_mps);
            self.segment_s_m += piece_m;
            self.plan_s_m += piece_m;
            left_m -= piece_m;
            if self.segment_s_m >= seg_len - 1e-12 && self.segment + 1 < self.plan.segments.len() {
                self.segment += 1;
                self.segment_s_m = 0.0;
            } else if piece_m <= 0.0 {
                break;
            }
        }
        // Instantaneous wheel speeds at the end of the step.
        let v_true = v1 * speed_factor;
        let (_, _, g) = self.motion(self.steer_angle_rad, v_true);
        let v_true = self.direction * v_true;
        let ratio = self.slip_ratio;
        // An ECU turns rotation into speed with one tyre size for all wheels:
        // take the four wheels' mean, so a tyre larger than the others reads fast.
        let d = self.cfg.true_params.wheel_diameters_m();
        let mean_d = 0.25 * (d.rear_left + d.rear_right + d.front_left + d.front_right);
        self.wheel_speed_mps = g.map(|w, gi| v_true * gi * (1.0 + ratio[w]) * mean_d / d[w]);
        if last_step {
            self.phase = match stop {
                Some((_, duration_s, reverse)) => {
                    self.stops_done += 1;
                    if reverse {
                        self.direction = -self.direction;
                    }
                    Phase::Paused(0, (duration_s * self.cfg.rate_hz).round() as u64)
                }
                None => Phase::After(0),
            };
        }
        Ok(())
    }

    /// The cruising speed asked for here: the last speed mark passed (the
    /// configuration's speed before any), or less where a lower mark ahead
    /// needs braking now to be met.
    fn target_speed_mps(&self) -> f64 {
        let a = self.cfg.accel_mps2;
        let mut target = self.cfg.speed_mps;
        for &(at_m, speed_mps) in &self.speed_marks {
            if at_m <= self.plan_s_m {
                target = speed_mps;
            } else {
                let reachable = speed_mps.mul_add(speed_mps, 2.0 * a * (at_m - self.plan_s_m));
                target = target.min(reachable.sqrt());
            }
        }
        target
    }

    /// The next sample, or an error if the plan asks for an impossible
    /// steering angle (|φ| ≥ 1.5 rad). `Ok(None)` when the run is over.
    ///
    /// # Errors
    /// [`Error::SteeringOutOfRange`], or [`Error::InvalidParameter`] from the driver's map.
    pub fn try_next(&mut self) -> Result<Option<Sample>> {
        match self.phase {
            Phase::Done => return Ok(None),
            Phase::Start => {
                self.phase = if self.standstill_steps > 0 {
                    Phase::Before(0)
                } else {
                    Phase::Moving
                };
                return Ok(Some(self.sample()));
            }
            Phase::Before(k) => {
                self.step_slip();
                self.phase = if k + 1 >= self.standstill_steps {
                    Phase::Moving
                } else {
                    Phase::Before(k + 1)
                };
            }
            Phase::Moving => {
                let heading_before = self.pose.heading_rad;
                self.drive()?;
                self.yaw_rate_radps = (self.pose.heading_rad - heading_before) / self.dt_s;
            }
            Phase::Paused(k, steps) => {
                self.yaw_rate_radps = 0.0;
                self.step_slip();
                self.wheel_speed_mps = WheelSet::splat(0.0);
                self.phase = if k + 1 >= steps {
                    Phase::Moving
                } else {
                    Phase::Paused(k + 1, steps)
                };
            }
            Phase::After(k) => {
                self.yaw_rate_radps = 0.0;
                self.step_slip();
                self.wheel_speed_mps = WheelSet::splat(0.0);
                if k >= self.standstill_steps {
                    self.phase = Phase::Done;
                    return Ok(None);
                }
                self.phase = Phase::After(k + 1);
            }
        }
        self.step += 1;
        Ok(Some(self.sample()))
    }
}

impl Iterator for Simulator {
    type Item = Sample;

    /// The next sample; an impossible steering angle ends the run (use
    /// [`Simulator::try_next`] to see the error).
    fn next(&mut self) -> Option<Sample> {
        self.try_next().ok().flatten()
    }
}

fn counter_mask(bits: u32) -> u64 {
    if bits >= 64 {
        u64::MAX
    } else {
        (1u64 << bits) - 1
    }
}

/// Runs `plan` to the end and collects every sample.
///
/// # Errors
/// As [`Simulator::new`] and [`Simulator::try_next`].
pub fn simulate(config: &SimConfig, plan: &Plan, seed: u64) -> Result<Run> {
    let mut sim = Simulator::new(config, plan, seed)?;
    let mut samples = Vec::with_capacity(
        ((plan.length_m() / config.speed_mps + 2.0 * config.standstill_s + 5.0) * config.rate_hz)
            as usize,
    );
    while let Some(s) = sim.try_next()? {
        samples.push(s);
    }
    Ok(Run {
        samples,
        true_end: sim.true_pose(),
        steer_bias_rad: sim.steer_bias_rad(),
        slip_events: sim.slip_events(),
    })
}

#[cfg(test)]
mod tests;
