//! The pure, synchronous core shared by `run`, `replay` and `demo`: frames
//! in, filter steps and pose samples out. No clock, no I/O: time comes from
//! the frames' timestamps, so the same frames give the same poses bit for bit
//! whichever command feeds them.
//!
//! # How separate frames are combined
//! The rear wheels drive the filter: **every accepted rear-wheel frame is one
//! EKF step**. Front-wheel distances are accumulated between steps (a front
//! frame adds to the sum, the step consumes it), and the step uses the latest
//! steering angle. Within one frame, steering is read first, then the front
//! wheels, then the rear, so a vehicle that packs all wheels in one message
//! (the Toyota file) steps with that same frame's front distances. Front
//! distance is conserved across steps, so a front frame arriving just after
//! its rear frame only shifts one sample between adjacent windows.
//!
//! # Integrity and staleness
//! Each input message has a health record: its checks (DLC, rolling counter,
//! checksum, finite values) and its period (`GenMsgCycleTime`, or learnt from
//! good frames when the DBC gives none). A message is *stale* when no good
//! frame came for `timeout_factor` periods, or after `invalid_after_faults`
//! bad frames in a row, and is trusted again only after
//! `trusted_after_frames` good frames in a row (hysteresis both ways).
//! Staleness that influences the filter is judged at each rear frame's own
//! timestamp, never at the reader's clock; the pose flags judged at publish
//! time are output only. While the front wheels or steering are stale the
//! step runs with `front_valid = false` (prediction from the rear alone);
//! while the rear is stale the pose says `POSE_VALID = 0`.

use crate::config::{Config, InputsConfig, WheelKind};
use crate::param_set;
use crate::plausibility::{Plausibility, Warning};
use crate::signal_forms::{DirectionSignal, Saturation, SignalForm};
use crate::stats::{Reasons, Reject, Stats};
use canodom_can::frame::{CanFrame, FrameKind};
use canodom_can::time::Timestamp;
use canodom_dbc::{CounterCheck, CounterStatus, FrameId, SignalHandle};
use canodom_fusion::ekf::{Ekf, Learnt, LearntPair, OdometryInput, State, WindowOutcome};
pub use canodom_protocol::pose_frames::{PoseFlags, PoseOutput};

/// A wheel message's silence, in periods, past which a frame was lost.
const LOST_FRAME_PERIODS: f64 = 1.9;

/// Traffic after which a configured message that never came is warned of,
/// µs: longer than any input's period (a gear message at 1 Hz), short
/// enough to say it before a user drives off (issue #45: a Honda preset's
/// steering message that a car does not send went unreported).
const MISSING_AFTER_US: u64 = 5_000_000;

/// How sure the filter starts of a calibrated yaw-rate bias, rad/s (0.1°/s).
const CALIBRATED_YAW_BIAS_SIGMA_RADPS: f64 = 0.1 * std::f64::consts::PI / 180.0;
use canodom_fusion::odometry::{PoseIntegrator, rear_increment};
use canodom_fusion::wheel::{
    InputConfig, InputFault, SpeedDecoder, SpeedIntegration, TickDecoder, WheelStep,
};
use canodom_fusion::{Pose, SteeringMap, VehicleParams, Wheel, WheelSet};

pub use crate::step::Step;

/// What [`Pipeline::push`] did with one frame: the caller learns from the
/// answer what it would otherwise have to work out by comparing the
/// statistics before and after. Every reason here was also counted in
/// [`Pipeline::stats`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Outcome {
    /// The frame was used and stepped the filter (a rear-wheel frame); the
    /// reasons are what it came with (a gap, a wheel fault, a gate rejection).
    Step(Step, Reasons),
    /// The frame was used without a step: front wheels, steering, yaw rate,
    /// or a rear frame whose step the filter refused (`FilterError` among the
    /// reasons, the previous state kept).
    Used(Reasons),
    /// The frame was not used, for this reason: not a configured input
    /// (`UnknownId`), not a data frame, or a failed check.
    Rejected(Reject),
}

impl Outcome {
    /// The filter step the frame caused, if any.
    pub fn step(&self) -> Option<&Step> {
        match self {
            Self::Step(step, _) => Some(step),
            Self::Used(_) | Self::Rejected(_) => None,
        }
    }

    /// Every reason the frame was counted under: the rejection, or what a
    /// used frame came with.
    pub fn reasons(&self) -> Reasons {
        match *self {
            Self::Step(_, reasons) | Self::Used(reasons) => reasons,
            Self::Rejected(reason) => {
                let mut one = Reasons::default();
                one.insert(reason);
                one
            }
        }
    }
}

/// Health of one input message (see the module doc).
#[derive(Clone, Debug)]
struct Health {
    /// From the DBC; `None` means the period is learnt.
    fixed_period_s: Option<f64>,
    period_s: f64,
    /// `period_s · timeout_factor` in µs, kept with `period_s`: it is
    /// judged several times per frame and changes only with a learnt period.
    timeout_us: u64,
    last_good_us: Option<u64>,
    good_run: u32,
    bad_run: u32,
    trusted: bool,
}

impl Health {
    fn new(cycle_ms: Option<u64>, inputs: &InputsConfig) -> Self {
        let fixed = cycle_ms.filter(|&ms| ms > 0).map(|ms| ms as f64 / 1000.0);
        let period_s = fixed.unwrap_or(inputs.default_period_s);
        Self {
            fixed_period_s: fixed,
            period_s,
            timeout_us: Self::timeout_of(period_s, inputs),
            last_good_us: None,
            good_run: 0,
            bad_run: 0,
            trusted: false,
        }
    }

    fn timeout_of(period_s: f64, inputs: &InputsConfig) -> u64 {
        (period_s * inputs.timeout_factor * 1e6) as u64
    }

    fn timeout_us(&self) -> u64 {
        self.timeout_us
    }

    fn fresh(&self, now_us: u64) -> bool {
        self.trusted
            && self
                .last_good_us
                .is_some_and(|t| now_us.saturating_sub(t) <= self.timeout_us())
    }

    fn good(&mut self, t_us: u64, inputs: &InputsConfig) {
        if let Some(prev) = self.last_good_us {
            let gap = t_us.saturating_sub(prev);
            if gap > self.timeout_us() {
                // A timeout: trust is earned again from this frame on.
                self.trusted = false;
                self.good_run = 0;
            } else if self.fixed_period_s.is_none() && gap > 0 {
                self.period_s += 0.05 * (gap as f64 * 1e-6 - self.period_s);
                self.timeout_us = Self::timeout_of(self.period_s, inputs);
            }
        }
        self.last_good_us = Some(t_us);
        self.bad_run = 0;
        self.good_run = self.good_run.saturating_add(1);
        if self.good_run >= inputs.trusted_after_frames {
            self.trusted = true;
        }
    }

    fn bad(&mut self, inputs: &InputsConfig) {
        self.good_run = 0;
        self.bad_run = self.bad_run.saturating_add(1);
        if self.bad_run >= inputs.invalid_after_faults {
            self.trusted = false;
        }
    }
}

/// Per-message state: checks and which roles it carries.
// Each role flag is independent (one message may carry several roles).
#[allow(clippy::struct_excessive_bools)]
#[derive(Clone, Debug)]
struct Input {
    id: FrameId,
    length: usize,
    rear: bool,
    front: bool,
    steering: bool,
    yaw: bool,
    /// Carries the reversing signal (`[signals] direction`).
    direction: bool,
    /// Its index in the database (which direction signal it carries).
    message_index: usize,
    /// Its DBC name, for warnings.
    name: String,
    /// A frame of it came (checked or not): a message that never does is
    /// warned of after [`MISSING_AFTER_US`] of traffic.
    arrived: bool,
    counter: Option<(SignalHandle, CounterCheck)>,
    checksum: Option<canodom_dbc::FrameChecksum>,
    health: Health,
}

#[derive(Clone, Debug)]
enum Decoders {
    Ticks(Box<WheelSet<TickDecoder>>),
    Speed(Box<WheelSet<SpeedDecoder>>),
}

/// The pipeline: decode, check, decode wheels, step the EKF.
#[derive(Clone, Debug)]
pub struct Pipeline {
    inputs_cfg: InputsConfig,
    wheels: WheelSet<SignalForm>,
    /// Multiplies a wheel speed into the decoders' unit.
    wheel_speed_factor: f64,
    /// The reversing signal, and whether it last said the car reverses.
    direction: Option<DirectionSignal>,
    /// The other gearbox's gear signal (`direction` naming two), read
    /// until a frame of the first came.
    direction_alt: Option<DirectionSignal>,
    primary_gear_came: bool,
    reversing: bool,
    steering: SignalForm,
    /// The yaw-rate signal, its rad/s (left positive) per unit, and where
    /// its readings are saturated.
    yaw_signal: Option<(SignalForm, f64, Saturation)>,
    /// `MESSAGE.SIGNAL` of the yaw rate, for its warnings.
    yaw_name: String,
    /// The latest yaw rate, rad/s, its scale corrected.
    yaw_radps: Option<f64>,
    /// The yaw-rate sensor's scale in use (1, or calibrated): measured =
    /// scale · true + bias; the filter learns the bias.
    yaw_scale: f64,
    steer_map: SteeringMap,
    params: VehicleParams,
    inputs: Vec<Input>,
    /// Index into `inputs` + 1 by standard (11-bit) id, 0 for none: every
    /// frame is looked up, and a search of `inputs` cost ~45 instructions.
    standard_inputs: Box<[u8; STANDARD_IDS]>,
    decoders: Decoders,
    ekf: Ekf,
    /// The filter state and a scratch buffer the next step is written into;
    /// `states[current]` is the state. A step flips `current` on success, so
    /// the ~0.7 kB state is copied once per step, not four times.
    states: [State; 2],
    current: usize,
    odometry: PoseIntegrator,
    t0_us: Option<u64>,
    last_t_us: u64,
    front_acc_m: (f64, f64),
    steer_rad: Option<f64>,
    steer_signal: Option<f64>,
    last_step: Option<Step>,
    speed_mps: f64,
    yaw_rate_radps: f64,
    latched: PoseFlags,
    stats: Stats,
    /// The run-time plausibility checks (#32): fed every step, judged on the
    /// statistics at every pose sample; any warning sets INPUT_IMPLAUSIBLE.
    plausibility: Plausibility,
    /// The parameters the wheel decoders were built with (the configured
    /// nominal ones): decoded distances are in these units.
    decoder_params: VehicleParams,
    /// Rear (left, right) distance factors: diameter in use over decoder diameter.
    rear_scale: (f64, f64),
    /// Version of the calibrated set in use; `None` for the nominal parameters.
    param_version: Option<u16>,
    /// The set's yaw-rate calibration (bias rad/s, scale), part of its identity.
    set_yaw_rate: (Option<f64>, Option<f64>),
    /// The first frame's time (any id): the traffic a missing message is
    /// judged after.
    traffic_t0_us: Option<u64>,
    /// Missing messages were judged (once per pipeline).
    missing_judged: bool,
}

/// Index of a message within `inputs`, by role.
fn find(inputs: &[Input], id: FrameId) -> Option<usize> {
    inputs.iter().position(|i| i.id == id)
}

/// Standard (11-bit) frame ids.
const STANDARD_IDS: usize = 1 << 11;

/// The table of [`Pipeline::standard_inputs`].
fn standard_table(inputs: &[Input]) -> Box<[u8; STANDARD_IDS]> {
    let mut table = Box::new([0u8; STANDARD_IDS]);
    for (i, input) in inputs.iter().enumerate() {
        // At most four inputs (one per role), so `i + 1` fits a u8.
        if let FrameId::Standard(id) = input.id
            && let Ok(slot) = u8::try_from(i + 1)
        {
            table[usize::from(id)] = slot;
        }
    }
    table
}

/// The four wheel decoders of the configured kind, each told its message's period.
fn wheel_decoders(config: &Config) -> Result<Decoders, canodom_fusion::Error> {
    let s = &config.signals;
    let db = &config.db;
    let period = |idx: usize| {
        db.messages()[idx]
            .cycle_time_ms()
            .filter(|&ms| ms > 0)
            .map_or(config.inputs.default_period_s, |ms| ms as f64 / 1000.0)
    };
    let input_cfg = |idx: usize| InputConfig {
        nominal_period_s: period(idx),
        gap_factor: 1.5,
        max_wheel_speed_mps: config.inputs.max_wheel_speed_mps,
    };
    let rear_cfg = input_cfg(s.wheels.rear_left.message_index);
    let front_cfg = input_cfg(s.wheels.front_left.message_index);
    let params = config.params;
    let cfg_of = |w: Wheel| if w.is_rear() { rear_cfg } else { front_cfg };
    let decoders = match s.wheel_kind {
        WheelKind::Ticks => {
            let mk =
                |w: Wheel| TickDecoder::new(s.tick_bits, params.tick_distance_m(w, 1.0), cfg_of(w));
            Decoders::Ticks(Box::new(WheelSet {
                rear_left: mk(Wheel::RearLeft)?,
                rear_right: mk(Wheel::RearRight)?,
                front_left: mk(Wheel::FrontLeft)?,
                front_right: mk(Wheel::FrontRight)?,
            }))
        }
        WheelKind::Speed(unit) => {
            let mk = |w: Wheel| SpeedDecoder::new(unit, SpeedIntegration::Trapezoid, cfg_of(w));
            Decoders::Speed(Box::new(WheelSet {
                rear_left: mk(Wheel::RearLeft)?,
                rear_right: mk(Wheel::RearRight)?,
                front_left: mk(Wheel::FrontLeft)?,
                front_right: mk(Wheel::FrontRight)?,
            }))
        }
    };
    Ok(decoders)
}

/// The input messages of `config`, one per message, with the roles each
/// carries, its checks and its health.
fn inputs_of(config: &Config) -> Vec<Input> {
    let s = &config.signals;
    let db = &config.db;
    let mut inputs: Vec<Input> = Vec::new();
    let mut role = |idx: usize, rear: bool, front: bool, steering: bool, yaw: bool, dir: bool| {
        let m = &db.messages()[idx];
        let pos = if let Some(p) = find(&inputs, m.id()) {
            p
        } else {
            let check = config.checks.iter().find(|c| c.message_index == idx);
            inputs.push(Input {
                id: m.id(),
                length: m.length(),
                rear: false,
                front: false,
                steering: false,
                yaw: false,
                direction: false,
                message_index: idx,
                name: m.name().to_owned(),
                arrived: false,
                counter: check
                    .and_then(|c| c.counter)
                    .and_then(|h| CounterCheck::new(h.size()).ok().map(|cc| (h, cc))),
                checksum: check.and_then(|c| c.checksum.clone()),
                health: Health::new(m.cycle_time_ms(), &config.inputs),
            });
            inputs.len() - 1
        };
        let i = &mut inputs[pos];
        i.rear |= rear;
        i.front |= front;
        i.steering |= steering;
        i.yaw |= yaw;
        i.direction |= dir;
    };
    role(
        s.wheels.rear_left.message_index,
        true,
        false,
        false,
        false,
        false,
    );
    role(
        s.wheels.front_left.message_index,
        false,
        true,
        false,
        false,
        false,
    );
    role(s.steering.message_index, false, false, true, false, false);
    if let Some(y) = &s.yaw_rate {
        role(y.signal.message_index, false, false, false, true, false);
    }
    for d in s.direction.iter().chain(&s.direction_alt) {
        role(d.message_index, false, false, false, false, true);
    }
    inputs
}

impl Pipeline {
    /// Builds the pipeline for a validated configuration.
    ///
    /// # Errors
    /// The fusion crate refused a decoder or filter configuration (e.g. a tick
    /// counter too narrow for `inputs.max_wheel_speed_mps`).
    pub fn new(config: &Config) -> Result<Self, canodom_fusion::Error> {
        let s = &config.signals;
        let db = &config.db;
        let inputs = inputs_of(config);
        let decoders = wheel_decoders(config)?;
        let params = config.params;
        Ok(Self {
            inputs_cfg: config.inputs,
            wheels: s.wheels.map(|_, w| w.form),
            wheel_speed_factor: s.wheel_speed_factor,
            direction: s.direction,
            direction_alt: s.direction_alt,
            primary_gear_came: false,
            reversing: false,
            steering: s.steering.form,
            yaw_signal: s
                .yaw_rate
                .map(|y| (y.signal.form, y.radps_per_unit, y.saturation)),
            yaw_name: s.yaw_rate.map_or_else(String::new, |y| {
                crate::signal_forms::signal_path(db, y.signal.form.main)
            }),
            yaw_radps: None,
            yaw_scale: 1.0,
            steer_map: params.steering(),
            params,
            standard_inputs: standard_table(&inputs),
            inputs,
            decoders,
            ekf: Ekf::new(config.ekf)?,
            states: [State::origin(); 2],
            current: 0,
            odometry: PoseIntegrator::default(),
            t0_us: None,
            last_t_us: 0,
            front_acc_m: (0.0, 0.0),
            steer_rad: None,
            steer_signal: None,
            last_step: None,
            speed_mps: 0.0,
            yaw_rate_radps: 0.0,
            latched: PoseFlags::default(),
            stats: Stats::default(),
            plausibility: Plausibility::new(
                params.wheelbase_m(),
                params.rear_tread_m(),
                params.steering(),
            ),
            decoder_params: params,
            rear_scale: (1.0, 1.0),
            param_version: None,
            set_yaw_rate: (None, None),
            traffic_t0_us: None,
            missing_judged: false,
        })
    }

    /// Puts a calibrated parameter set (`version` ≥ 1) into the running
    /// odometry: rear wheel distances, rear tread and steering map from the
    /// next step on; the pose so far is kept. `None` returns to the nominal
    /// parameters. The caller chooses the instant (canodom applies sets only
    /// at standstill).
    ///
    /// What the filter learnt on a parameter the set changes goes back to its
    /// prior ([`param_set::reset_learnt`]): a new diameter ratio resets the
    /// rear ratio error (and the front scale), a new tread the effective
    /// tread error, a new steering map the steering offset, a new yaw-rate
    /// calibration the yaw-rate bias (to the calibrated one when the set
    /// carries it). Values learnt on unchanged parameters are kept.
    ///
    /// # Errors
    /// The filter refused the parameters; nothing changed then.
    pub fn apply_params(
        &mut self,
        set: Option<(u16, &canodom_params::persist::ParamValues)>,
    ) -> Result<(), canodom_fusion::Error> {
        let params = match set {
            None => self.decoder_params,
            Some((_, v)) => self
                .decoder_params
                .with_rear(
                    v.rear_tread_m,
                    v.rear_left_diameter_m,
                    v.rear_right_diameter_m,
                )?
                .with_steering(v.steering_map())?,
        };
        let ekf = Ekf::new(canodom_fusion::ekf::EkfConfig {
            params,
            ..*self.ekf.config()
        })?;
        let d = |p: &VehicleParams, w: Wheel| p.wheel_diameter_m(w);
        self.rear_scale = (
            d(&params, Wheel::RearLeft) / d(&self.decoder_params, Wheel::RearLeft),
            d(&params, Wheel::RearRight) / d(&self.decoder_params, Wheel::RearRight),
        );
        let before = self.params_in_use();
        self.ekf = ekf;
        self.params = params;
        self.steer_map = params.steering();
        self.param_version = set.map(|(v, _)| v);
        let (_, values) = set.unzip();
        self.set_yaw_rate = (
            values.and_then(|v| v.yaw_rate_bias_radps),
            values.and_then(|v| v.yaw_rate_scale),
        );
        self.yaw_scale = self.set_yaw_rate.1.unwrap_or(1.0);
        let changes = param_set::ParamChanges::between(&before, &self.params_in_use());
        if changes.any() {
            let state = &mut self.states[self.current];
            let reset = param_set::reset_learnt(&state.learnt(), changes, self.ekf.config());
            *state = state.with_learnt(&reset);
        }
        if let Some(bias) = self.set_yaw_rate.0.filter(|_| changes.yaw_rate) {
            // The calibrated bias as the filter's prior, as sure as its
            // calibration said (a set without its σ: a tenth of a degree per
            // second); the rear diameters were calibrated with it, so their
            // error starts at 0. The set's bias is the sensor's, in its raw
            // units (measured = scale · true + bias); the filter subtracts
            // its bias from the rate already divided by the scale, so it
            // starts from bias / scale (issue #31: it was used raw).
            let sigma = values
                .and_then(|v| v.yaw_rate_bias_sigma_radps)
                .unwrap_or(CALIBRATED_YAW_BIAS_SIGMA_RADPS);
            let state = &mut self.states[self.current];
            let learnt = Learnt {
                yaw_bias: Some(LearntPair {
                    yaw_bias_radps: bias / self.yaw_scale,
                    yaw_bias_sigma_radps: sigma / self.yaw_scale.abs(),
                    rear_ratio_err: 0.0,
                    rear_ratio_sigma: self.ekf.config().rear_ratio_sigma,
                    tread_err: 0.0,
                    tread_sigma: self.ekf.config().tread_sigma,
                }),
                ..state.learnt()
            };
            *state = state.with_learnt(&learnt);
        }
        Ok(())
    }

    /// Puts what an earlier run learnt (checked by the caller) into the filter.
    pub fn restore_learnt(&mut self, learnt: &Learnt) {
        let state = &mut self.states[self.current];
        *state = state.with_learnt(learnt);
    }

    /// Moves the odometry frame to where the vehicle stands: the fused and
    /// the rear-only pose restart at the origin; what the filter has learnt
    /// and the statistics are kept. Meant for standstill (the caller checks).
    pub fn reset_pose(&mut self) {
        self.states[self.current] = self.states[self.current].rebased_at_origin();
        self.odometry = PoseIntegrator::default();
        if let Some(step) = &mut self.last_step {
            step.fused = Pose::default();
            step.odometry = Pose::default();
        }
    }

    /// The parameters in use (nominal or calibrated).
    pub fn params(&self) -> &VehicleParams {
        &self.params
    }

    /// The parameters in use with the set's yaw-rate calibration.
    pub fn params_in_use(&self) -> param_set::ParamsInUse {
        param_set::ParamsInUse {
            params: self.params,
            yaw_rate_bias_radps: self.set_yaw_rate.0,
            yaw_rate_scale: self.set_yaw_rate.1,
        }
    }

    /// Which parameter set the filter runs on, the one its learnt values
    /// are learnt on (a state file records it).
    pub fn param_identity(&self) -> param_set::ParamIdentity {
        param_set::ParamIdentity::of(self.param_version, &self.params_in_use())
    }

    /// Version of the calibrated set in use, `None` for nominal.
    pub fn param_version(&self) -> Option<u16> {
        self.param_version
    }

    /// The statistics so far.
    pub fn stats(&self) -> &Stats {
        &self.stats
    }

    /// The filter state (bit-for-bit comparisons between commands).
    pub fn state(&self) -> &State {
        &self.states[self.current]
    }

    /// Every plausibility warning so far (#32), oldest first: `run` logs
    /// each once, and ODOM_QUALITY.INPUT_IMPLAUSIBLE is 1 from the first.
    pub fn plausibility_warnings(&self) -> &[Warning] {
        self.plausibility.warnings()
    }

    /// Judges the statistics once more, frames after the last pose sample
    /// included, and returns every plausibility warning with the diagnosis
    /// paragraph (`None` when nothing fired): what `replay` reports when its
    /// log ends. Every step was judged as it came, as `run` judges it.
    pub fn plausibility_at_end(&mut self) -> (Vec<Warning>, Option<String>) {
        self.plausibility
            .judge_stats(&self.stats, self.last_step.map_or(0.0, |s| s.t_s));
        (
            self.plausibility.warnings().to_vec(),
            self.plausibility.diagnosis(),
        )
    }

    /// The last filter step, if any.
    pub fn last_step(&self) -> Option<Step> {
        self.last_step
    }

    /// The timestamp of the first input frame, from which [`Step::t_s`] counts.
    pub fn first_frame_time(&self) -> Option<Timestamp> {
        self.t0_us.map(Timestamp::from_micros)
    }

    /// Offers one frame received at `t`; says what became of it (the filter
    /// step it caused, or why it was not used). Never panics, whatever the
    /// frame holds.
    pub fn push(&mut self, t: Timestamp, frame: &CanFrame) -> Outcome {
        if matches!(frame.kind(), FrameKind::Data { .. } | FrameKind::Fd { .. }) {
            return self.push_data(t, frame.id(), frame.data());
        }
        self.stats.frames += 1;
        self.reject(if self.input_index(frame.id()).is_some() {
            Reject::NotData
        } else {
            Reject::UnknownId
        })
    }

    /// Counts a frame not used for `reason`.
    fn reject(&mut self, reason: Reject) -> Outcome {
        self.stats.add(reason);
        Outcome::Rejected(reason)
    }

    /// Counts `reason` for a frame that is still used, and notes it in the
    /// frame's `reasons`.
    fn remark(stats: &mut Stats, reasons: &mut Reasons, reason: Reject) {
        stats.add(reason);
        reasons.insert(reason);
    }

    /// The index into `inputs` of the message with this id.
    #[inline]
    fn input_index(&self, id: FrameId) -> Option<usize> {
        match id {
            FrameId::Standard(s) => self
                .standard_inputs
                .get(usize::from(s))
                .and_then(|&slot| usize::from(slot).checked_sub(1)),
            FrameId::Extended(_) => find(&self.inputs, id),
        }
    }

    /// [`Self::push`] for a data frame (classical or FD) with payload `data`,
    /// for callers that hold frames without a [`CanFrame`] (replay's batches).
    pub fn push_data(
        &mut self,
        t: Timestamp,
        id: canodom_can::frame::FrameId,
        data: &[u8],
    ) -> Outcome {
        self.stats.frames += 1;
        let t_us = t.as_micros();
        self.judge_missing(t_us);
        let Some(idx) = self.input_index(id) else {
            return self.reject(Reject::UnknownId);
        };
        let input = &mut self.inputs[idx];
        input.arrived = true;
        if let Some(reason) = Self::check(input, data, t_us) {
            input.health.bad(&self.inputs_cfg);
            match reason {
                Reject::BadCounter => self.latched.counter_fault = true,
                Reject::BadChecksum => self.latched.checksum_fault = true,
                _ => {}
            }
            return self.reject(reason);
        }
        // Every configured signal of this message must be finite before any is used.
        let (rear, front, steering, yaw) = (input.rear, input.front, input.steering, input.yaw);
        if input.direction {
            // Read before this frame's wheels: a message may carry both.
            let index = input.message_index;
            self.read_gear(index, data);
        }
        let val = |f: &SignalForm| f.decode(data).unwrap_or(f64::NAN);
        // (rad/s, at its range's end): no measurement of the rate at the
        // end, where the sensor holds it however fast the car turns.
        let yaw_reading = match (&self.yaw_signal, yaw) {
            (Some((f, per_unit, saturation)), true) => {
                let reading = val(f);
                Some((reading * per_unit, saturation.is_saturated(reading)))
            }
            _ => None,
        };
        let mut steer_signal = None;
        if steering {
            steer_signal = Some(val(&self.steering));
        }
        // With a reversing signal the speeds are magnitudes it signs.
        let (factor, direction) = (self.wheel_speed_factor, self.direction.is_some());
        let sign = if self.reversing { -1.0 } else { 1.0 };
        // Each wheel signal is read once: its raw bits feed a tick decoder,
        // its physical value the finiteness check and a speed decoder.
        let wheel_raw = |on: bool, f: &SignalForm| {
            wheel_reading(on, f, data, factor, direction.then_some(sign))
        };
        let raws = WheelSet {
            rear_left: wheel_raw(rear, &self.wheels.rear_left),
            rear_right: wheel_raw(rear, &self.wheels.rear_right),
            front_left: wheel_raw(front, &self.wheels.front_left),
            front_right: wheel_raw(front, &self.wheels.front_right),
        };
        let speeds = raws.map(|_, (_, v)| v);
        if steer_signal.is_some_and(|u| !u.is_finite())
            || yaw_reading.is_some_and(|(w, _)| !w.is_finite())
            || !(speeds.rear_left.is_finite()
                && speeds.rear_right.is_finite()
                && speeds.front_left.is_finite()
                && speeds.front_right.is_finite())
        {
            self.inputs[idx].health.bad(&self.inputs_cfg);
            return self.reject(Reject::NonFinite);
        }
        let steer_rad = steer_signal.map(|u| self.steer_map.angle_rad(u));
        if steer_rad.is_some_and(|phi| phi.abs() >= std::f64::consts::FRAC_PI_2) {
            self.inputs[idx].health.bad(&self.inputs_cfg);
            return self.reject(Reject::SteerRange);
        }
        let mut reasons = Reasons::default();
        let health = &mut self.inputs[idx].health;
        // A wheel frame after a silence long enough that one must have been
        // lost: two periods, less a margin for the jitter of timestamps (a
        // logger's batches: the RAV4 recording's 11.2 ms period shows
        // intervals of 17 ms at the 90th percentile, with nothing lost).
        if (rear || front)
            && health.last_good_us.is_some_and(|last| {
                t_us.saturating_sub(last) as f64 > LOST_FRAME_PERIODS * health.period_s * 1e6
            })
        {
            Self::remark(&mut self.stats, &mut reasons, Reject::WheelGap);
        }
        health.good(t_us, &self.inputs_cfg);
        self.stats.used += 1;
        let t0 = *self.t0_us.get_or_insert(t_us);
        // Signed: a log's timestamps may go backwards; the decoders judge that.
        // Divided, not multiplied by 1e-6: the quotient is the double nearest
        // the exact time (`0.07`, where the product was 0.06999999999999999
        // in 3 of 10 steps), and `Step::t_us` is then its exact source.
        let t_rel_us = t_us as i64 - t0 as i64;
        let t_s = t_rel_us as f64 / 1e6;
        self.last_t_us = self.last_t_us.max(t_us);
        if let Some(phi) = steer_rad {
            self.steer_rad = Some(phi);
            self.steer_signal = steer_signal;
        }
        if let Some(reading) = yaw_reading {
            self.take_yaw(reading, t_s, &mut reasons);
        }
        if front {
            let fl = self.wheel(Wheel::FrontLeft, t_s, raws.front_left, &mut reasons);
            let fr = self.wheel(Wheel::FrontRight, t_s, raws.front_right, &mut reasons);
            self.front_acc_m.0 += fl;
            self.front_acc_m.1 += fr;
        }
        if rear {
            let rl =
                self.wheel(Wheel::RearLeft, t_s, raws.rear_left, &mut reasons) * self.rear_scale.0;
            let rr = self.wheel(Wheel::RearRight, t_s, raws.rear_right, &mut reasons)
                * self.rear_scale.1;
            return self.step(t_s, t_rel_us, t_us, rl, rr, reasons);
        }
        Outcome::Used(reasons)
    }

    /// A gear or direction frame of message `index`: says whether the car
    /// reverses. The first gear message listed says it once it came
    /// (openpilot reads a Honda's GEARBOX_CVT when 0x191 is on the bus),
    /// the second until then.
    fn read_gear(&mut self, index: usize, data: &[u8]) {
        let primary = self.direction.filter(|d| d.message_index == index);
        self.primary_gear_came |= primary.is_some();
        let gear = primary.or_else(|| {
            self.direction_alt
                .filter(|d| d.message_index == index && !self.primary_gear_came)
        });
        if let Some(d) = gear
            && let Some(raw) = d.handle.raw(data)
        {
            self.reversing = d.is_reverse(raw);
        }
    }

    /// A yaw-rate reading (rad/s, and whether it is at its range's end).
    fn take_yaw(&mut self, (w_radps, saturated): (f64, bool), t_s: f64, reasons: &mut Reasons) {
        if self.plausibility.yaw_rate_at_fault() {
            // A gyro found at fault would turn the heading the wrong way (or
            // 57 times too far) for the rest of the drive: the filter goes
            // on with the wheels and the steering, from the rear wheels'
            // pose (the aided one followed the gyro until it was found).
            let state = &mut self.states[self.current];
            if state.yaw_aided() {
                *state = state.without_yaw_rate(self.odometry.pose());
            }
            self.yaw_radps = None;
            Self::remark(&mut self.stats, reasons, Reject::YawImplausible);
        } else if saturated {
            self.yaw_saturated(w_radps, t_s, reasons);
        } else {
            self.yaw_radps = Some(w_radps / self.yaw_scale);
        }
    }

    /// A yaw-rate reading of `w_radps` at its range's end: the filter runs
    /// without the gyro until it leaves the end; counted and warned of.
    fn yaw_saturated(&mut self, w_radps: f64, t_s: f64, reasons: &mut Reasons) {
        self.yaw_radps = None;
        Self::remark(&mut self.stats, reasons, Reject::YawSaturated);
        if let Some((_, per_unit, saturation)) = &self.yaw_signal {
            let dps_per_unit = per_unit.abs().to_degrees();
            self.plausibility.saturated(
                &self.yaw_name,
                w_radps.to_degrees(),
                (
                    saturation.range.0 * dps_per_unit,
                    saturation.range.1 * dps_per_unit,
                ),
                t_s,
            );
        }
    }

    /// Once the traffic has lasted [`MISSING_AFTER_US`]: every configured
    /// message that never came is a warning naming it (a car line that does
    /// not send it, or a message of another bus). Of two gear messages
    /// (`direction` naming two) one coming is enough.
    #[inline]
    fn judge_missing(&mut self, t_us: u64) {
        if self.missing_judged {
            return;
        }
        let t0 = *self.traffic_t0_us.get_or_insert(t_us);
        if t_us.saturating_sub(t0) < MISSING_AFTER_US {
            return;
        }
        self.missing_judged = true;
        let gear_came = self.inputs.iter().any(|i| i.direction && i.arrived);
        let t_s = self
            .t0_us
            .map_or(0.0, |first| t_us.saturating_sub(first) as f64 / 1e6);
        let waited_s = t_us.saturating_sub(t0) as f64 / 1e6;
        for input in self.inputs.iter().filter(|i| !i.arrived) {
            let key = if input.rear {
                "signals.rear_left"
            } else if input.front {
                "signals.front_left"
            } else if input.steering {
                "signals.steering"
            } else if input.yaw {
                "signals.yaw_rate"
            } else if gear_came {
                continue;
            } else {
                "signals.direction"
            };
            self.plausibility.missing(
                key,
                &format!("{} ({})", input.name, input.id),
                waited_s,
                t_s,
            );
        }
    }

    /// DLC, checksum and counter checks; `Some(reason)` rejects the frame.
    fn check(input: &mut Input, data: &[u8], t_us: u64) -> Option<Reject> {
        if data.len() < input.length {
            return Some(Reject::Truncated);
        }
        if data.len() > input.length {
            return Some(Reject::WrongDlc);
        }
        if let Some(c) = &input.checksum
            && !c.is_valid(data)
        {
            return Some(Reject::BadChecksum);
        }
        if let Some((h, cc)) = &mut input.counter {
            // After a timeout the counter has moved on by the frames lost: that
            // gap is the timeout's (already flagged), not this frame's fault.
            if input
                .health
                .last_good_us
                .is_some_and(|last| t_us.saturating_sub(last) > input.health.timeout_us())
            {
                cc.reset();
            }
            let raw = h.raw(data)?;
            if let CounterStatus::Gap { .. } = cc.observe(raw) {
                return Some(Reject::BadCounter);
            }
        }
        None
    }

    /// Feeds one wheel decoder the signal's (raw bits, physical value); the
    /// distance it integrated (0 on a fault, noted in `reasons`).
    // Inlined into its four call sites, each with a constant wheel, the choice
    // of decoder is made at compile time instead of by a jump table whose
    // target changes on every call.
    #[allow(clippy::inline_always)]
    #[inline(always)]
    fn wheel(
        &mut self,
        w: Wheel,
        t_s: f64,
        (raw, value): (u64, f64),
        reasons: &mut Reasons,
    ) -> f64 {
        let step: WheelStep = match &mut self.decoders {
            Decoders::Ticks(d) => wheel_mut(d, w).push(t_s, raw),
            Decoders::Speed(d) => wheel_mut(d, w).push(t_s, value),
        };
        match step.fault {
            // Judged once per frame against the message's learnt period
            // (`push_data`): the decoders know only the nominal one.
            None | Some(InputFault::MissedSamples { .. }) => {}
            Some(_) => Self::remark(&mut self.stats, reasons, Reject::WheelFault),
        }
        step.distance_m
    }

    fn step(
        &mut self,
        t_s: f64,
        t_rel_us: i64,
        t_us: u64,
        rl: f64,
        rr: f64,
        mut reasons: Reasons,
    ) -> Outcome {
        let front_fresh = self.role_fresh(t_us, |i| i.front);
        let steer_fresh = self.role_fresh(t_us, |i| i.steering);
        let input = OdometryInput {
            wheel_m: WheelSet {
                rear_left: rl,
                rear_right: rr,
                front_left: self.front_acc_m.0,
                front_right: self.front_acc_m.1,
            },
            front_valid: front_fresh && steer_fresh && self.steer_rad.is_some(),
            steer_angle_rad: self.steer_rad.unwrap_or(0.0),
            zero_is_floor: matches!(self.decoders, Decoders::Speed(_)),
            yaw_rate_radps: self.yaw_radps.filter(|_| self.role_fresh(t_us, |i| i.yaw)),
            dt_s: self.last_step.map_or(0.0, |prev| (t_s - prev.t_s).max(0.0)),
        };
        self.front_acc_m = (0.0, 0.0);
        let [a, b] = &mut self.states;
        let (prev, next) = if self.current == 0 {
            (&*a, b)
        } else {
            (&*b, a)
        };
        if self.ekf.step_into(prev, next, &input).is_err() {
            Self::remark(&mut self.stats, &mut reasons, Reject::FilterError);
            return Outcome::Used(reasons);
        }
        self.current ^= 1;
        let state = &self.states[self.current];
        self.stats.gate.yaw_over_rear = state.stats.yaw_over_rear;
        self.stats.gate.yaw_refused = state.stats.yaw_refused;
        let correction = state.last_window;
        if correction.is_rejected() {
            self.latched.gate_reject = true;
            Self::remark(&mut self.stats, &mut reasons, Reject::GateReject);
            if correction == WindowOutcome::RejectedUsedFront {
                self.stats.gate.used_front += 1;
            } else {
                self.stats.gate.kept_rear += 1;
            }
            for w in Wheel::ALL {
                if state.slip_flags[w] {
                    self.stats.gate.blamed[w] += 1;
                }
            }
        }
        if !input.front_valid {
            self.stats.steps_without_front += 1;
        }
        if let Ok(inc) = rear_increment(&self.params, rl, rr) {
            self.odometry.advance(inc);
        }
        self.stats.steps += 1;
        let fused = self.states[self.current].pose_unwrapped();
        if let Some(prev) = self.last_step {
            let dt = t_s - prev.t_s;
            if dt > 0.0 {
                self.speed_mps = 0.5 * (rl + rr) / dt;
                self.yaw_rate_radps = (fused.heading_rad - prev.fused.heading_rad) / dt;
            }
        }
        let rev = |m: f64, w: Wheel| m / (std::f64::consts::PI * self.params.wheel_diameter_m(w));
        let step = Step {
            t_s,
            t_us: t_rel_us,
            fused,
            odometry: self.odometry.pose(),
            rear_rev: (rev(rl, Wheel::RearLeft), rev(rr, Wheel::RearRight)),
            front_rev: front_fresh.then(|| {
                (
                    rev(input.wheel_m.front_left, Wheel::FrontLeft),
                    rev(input.wheel_m.front_right, Wheel::FrontRight),
                )
            }),
            steer_signal: self.steer_signal,
            correction,
            yaw_rate_radps: input.yaw_rate_radps,
        };
        self.last_step = Some(step);
        self.plausibility.push(&step);
        Outcome::Step(step, reasons)
    }

    fn role_fresh(&self, now_us: u64, role: impl Fn(&Input) -> bool) -> bool {
        self.inputs
            .iter()
            .filter(|i| role(i))
            .all(|i| i.health.fresh(now_us))
    }

    /// The pose sample at `now` (the reader's clock: only the flags depend on
    /// it). Clears the "since the previous sample" fault latches.
    pub fn pose_output(&mut self, now: Timestamp) -> PoseOutput {
        let now_us = now.as_micros();
        let rear_fresh = self.role_fresh(now_us, |i| i.rear);
        self.plausibility
            .judge_stats(&self.stats, self.last_step.map_or(0.0, |s| s.t_s));
        let flags = PoseFlags {
            pose_valid: rear_fresh,
            rear_stale: !rear_fresh,
            front_stale: !self.role_fresh(now_us, |i| i.front),
            steer_stale: !self.role_fresh(now_us, |i| i.steering),
            counter_fault: self.latched.counter_fault,
            checksum_fault: self.latched.checksum_fault,
            gate_reject: self.latched.gate_reject,
            nominal_params: self.param_version.is_none(),
            input_implausible: !self.plausibility.warnings().is_empty(),
        };
        self.latched = PoseFlags::default();
        let state = &self.states[self.current];
        let pose = state.pose();
        let p = state.covariance();
        let (a, b, c) = (p[(0, 0)], p[(0, 1)], p[(1, 1)]);
        let lambda_max = 0.5 * (a + c) + (0.25 * (a - c) * (a - c) + b * b).sqrt();
        PoseOutput {
            timestamp: Timestamp::from_micros(self.last_t_us),
            x_m: pose.x_m,
            y_m: pose.y_m,
            heading_rad: pose.heading_rad,
            speed_mps: self.speed_mps,
            yaw_rate_radps: self.yaw_rate_radps,
            pos_std_m: lambda_max.max(0.0).sqrt(),
            heading_std_rad: p[(2, 2)].max(0.0).sqrt(),
            flags,
            param_version: self.param_version.unwrap_or(0),
        }
    }
}

/// A wheel signal's (raw bits, value in the decoders' unit): the raw bits
/// feed a tick decoder, the value the finiteness check and a speed decoder;
/// `signed_by` (the reversing signal's sign) makes the value a magnitude
/// of that sign. `(0, 0.0)` for a message that does not carry the wheel.
#[inline]
fn wheel_reading(
    on: bool,
    f: &SignalForm,
    data: &[u8],
    factor: f64,
    signed_by: Option<f64>,
) -> (u64, f64) {
    let signed = |v: f64| signed_by.map_or(v, |sign| sign * v.abs());
    if !on {
        (0, 0.0)
    } else if f.is_plain() {
        let h = &f.main;
        h.raw(data)
            .map_or((0, f64::NAN), |r| (r, signed(h.raw_to_scaled(r) * factor)))
    } else {
        (0, signed(f.decode(data).unwrap_or(f64::NAN) * factor))
    }
}

fn wheel_mut<T>(set: &mut WheelSet<T>, w: Wheel) -> &mut T {
    match w {
        Wheel::RearLeft => &mut set.rear_left,
        Wheel::RearRight => &mut set.rear_right,
        Wheel::FrontLeft => &mut set.front_left,
        Wheel::FrontRight => &mut set.front_right,
    }
}
