//! Each wheel's scale, learnt from the other sensors (`docs/calibration-math.md` §15).
//!
//! **What the sensors tell.** Four wheel speeds and the steering angle tell
//! the car's curvature three times (the rear pair's difference, the front
//! pair's, the steering) and its speed four times. A wheel whose scale is off
//! (tyre size, wear, pressure, a sensor's own factor) makes its pair's
//! curvature disagree with the other two for as long as the car drives, and
//! its axle's mean speed disagree with the other axle's. Per window the car's
//! own distance and curvature are unknown, so of the five readings three
//! constraints remain: the log distances of the RR, FL and FR wheels less the
//! RL wheel's, against the distance factors `g_i(κ)` of §3 at the steering's
//! curvature `κ = tan(atan(t̄) − δ)/L` (`t̄` the window's mean `tan φ`, `δ`
//! the steering sensor's offset).
//!
//! **What they cannot tell, and what decides it.** To first order a
//! curvature bias common to all three sources is the car really curving:
//! one rear tyre 0.3 % large reads exactly as the front-left tyre 0.3 %
//! small with a steering offset of `0.003·L/b`. A Gaussian prior over four
//! scales and an offset spreads such a fault over every wheel and leaves a
//! third of it in the heading (one tyre 0.3 % off, σ 0.5 % per wheel and
//! 0.3° on the offset: the rear pair's curvature still 2.6·10⁻⁴ /m off,
//! 10 m on an 865 m drive). What does tell them apart is second order: in a
//! turn the front wheels roll `√((1 ∓ κb_f/2)² + (κL)²)` times the centre,
//! and the `(κL)²` term pins the true |κ|, so the two explanations part by
//! `κL²·ε/b` (0.09 % of the front's distance in a 15 m circle for a 0.3 %
//! tyre, the opposite way in the other direction). As a continuous estimate
//! that is too weak (σ 8·10⁻⁵ /m after the whole drive); as a choice
//! between a few discrete explanations it is decisive within a circle.
//!
//! **So the learner compares explanations** ([`Fault`]): no wheel off, one
//! of the four wheels off, or the rear axle's scale off against the front's
//! (tyres of another size). Each is a two-state Kalman filter of its scale
//! error `ε` and the steering offset `δ`, fed by every clean window; its
//! evidence is the accumulated log likelihood of its innovations, whose
//! `ln det S` term is Occam's razor: a fault explanation pays for its free
//! `ε` until the data need it, so matched tyres stay "no wheel off" and the
//! pose is then the one it was without the learner, bit for bit. The learnt
//! scales are the explanations' mixture, and their σ holds the spread
//! between explanations still in play: where the sources cannot tell which
//! wheel is off, the σ says so rather than the estimate picking one.
//!
//! **With a yaw-rate sensor** the rear pair's scale difference is first
//! order: the aided estimator learns it against the gyro (its rear ratio).
//! Once the aided estimator carries the pose, an explanation whose rear
//! pair that ratio contradicts is left out ([`ScaleLearner::set_gyro_rear_ratio`]),
//! and a rear wheel it confirms needs no turns both ways. On 21 multi-body
//! drives with a rear tyre 0.3 % large the wheels alone named it on 6 and
//! held it on 9 (turns one way), took it for the front-left tyre on 3 and
//! stayed undecided on 3; with the gyro's ratio a rear wheel is named on
//! all 21 (the rear-left on 19, the rear-right reading as much too far on
//! two), and on 21 drives with a front tyre 0.3 % large none is applied to
//! a rear wheel (the front-right named on 19; one stays undecided). The
//! pose is the aided estimator's then, as before: the 42 replays' poses and
//! the 34 matched multi-body ones are the same byte for byte, and the 160
//! opendbc drives' end points to the millimetre.
//!
//! A window is used only when every wheel rolled the same way, the front was
//! valid, no wheel sat at its sensor's floor, neither axle was suspected of
//! slipping, and the car went faster than [`MIN_SPEED_MPS`]; one that no
//! explanation fits within [`GATE_CHI2`] (a slip the checks missed) is
//! dropped.

// The small filters below index their matrices as the maths writes them.
#![allow(clippy::needless_range_loop)]

use super::LearntWheelFault;
use crate::WheelSet;

/// The explanations the learner compares, in the order of its arrays.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Fault {
    /// Every wheel reads true (to a common scale, which nothing on board tells).
    None,
    /// The rear-left wheel reads `1 + ε` times the others.
    RearLeft,
    /// The rear-right wheel.
    RearRight,
    /// The front-left wheel.
    FrontLeft,
    /// The front-right wheel.
    FrontRight,
    /// Both front wheels read `1 + ε` times the rear pair (tyres of another
    /// size on one axle). Which axle is right nothing on board tells (the
    /// common scale); the rear pair stays the distance's reference, so the
    /// correction goes to the front pair and leaves the pose alone: applied
    /// to the rear it turned the heading by `ε` of every turn, 0.3 % of the
    /// distance on full-size drives whose slip angles made a spurious 0.1 %.
    FrontAxle,
}

impl Fault {
    /// Every explanation, in the learner's order.
    pub const ALL: [Self; HYPOTHESES] = [
        Self::None,
        Self::RearLeft,
        Self::RearRight,
        Self::FrontLeft,
        Self::FrontRight,
        Self::FrontAxle,
    ];

    /// `∂ ln(wheel i's reading)/∂ε` for each wheel in RL, RR, FL, FR order.
    fn wheel_sensitivity(self) -> [f64; 4] {
        match self {
            Self::None => [0.0; 4],
            Self::RearLeft => [1.0, 0.0, 0.0, 0.0],
            Self::RearRight => [0.0, 1.0, 0.0, 0.0],
            Self::FrontLeft => [0.0, 0.0, 1.0, 0.0],
            Self::FrontRight => [0.0, 0.0, 0.0, 1.0],
            Self::FrontAxle => [0.0, 0.0, 1.0, 1.0],
        }
    }

    /// For one wheel off, the index (RL, RR, FL, FR) of the wheel on the
    /// same side of the other axle: the one whose opposite error, with a
    /// steering offset, reads the same to first order in the curvature.
    fn same_side_partner(self) -> Option<usize> {
        match self {
            Self::RearLeft => Some(2),
            Self::RearRight => Some(3),
            Self::FrontLeft => Some(0),
            Self::FrontRight => Some(1),
            Self::None | Self::FrontAxle => None,
        }
    }

    /// The explanation of this [`Fault::as_str`] name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|f| f.as_str() == name)
    }

    /// Short snake-case name for logs, CSV columns and the state file.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::RearLeft => "rear_left",
            Self::RearRight => "rear_right",
            Self::FrontLeft => "front_left",
            Self::FrontRight => "front_right",
            Self::FrontAxle => "front_axle",
        }
    }
}

impl std::fmt::Display for WheelScales {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (s, sd) = (&self.scale, &self.sigma);
        write!(
            f,
            "RL {:.4} ± {:.4}, RR {:.4} ± {:.4}, FL {:.4} ± {:.4}, FR {:.4} ± {:.4} \
             (likeliest: {} off, p {:.3}{}; {} windows)",
            s.rear_left,
            sd.rear_left,
            s.rear_right,
            sd.rear_right,
            s.front_left,
            sd.front_left,
            s.front_right,
            sd.front_right,
            match self.likeliest.0 {
                Fault::None => "no wheel",
                other => other.as_str(),
            },
            self.likeliest.1,
            if self.told_by_gyro {
                " with the yaw-rate sensor's rear ratio"
            } else {
                ""
            },
            self.windows
        )?;
        if let Some(h) = self.held {
            write!(
                f,
                "; {} by {:+.3} %: {}",
                self.likeliest.0.as_str(),
                100.0 * self.likeliest_error,
                h.as_str()
            )?;
        }
        Ok(())
    }
}

/// Why the learner applies no, or not the likeliest, correction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Held {
    /// No explanation holds [`DECIDED`] of the probability yet.
    Undecided,
    /// One wheel's explanation leads, but the car has not turned tightly
    /// both ways: a rear tyre and the front one on its side are not told
    /// apart until it has.
    TurnsOneWay,
    /// The error is below [`MIN_APPLIED_SCALE`] (0.2 %) or within 3σ of 0.
    Insignificant,
}

impl Held {
    /// A few words for summaries.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Undecided => "undecided",
            Self::TurnsOneWay => "not applied until the car has turned tightly both ways",
            Self::Insignificant => "too small to apply",
        }
    }
}

/// Number of explanations compared.
pub const HYPOTHESES: usize = 6;

/// The probability at which the leading explanation's scales are applied.
const DECIDED: f64 = 0.95;
/// How much turning each way, `Σ κ² d` over the used windows (1/m), a
/// single-wheel explanation needs before it is applied: a quarter circle of
/// 20 m radius. A rear tyre and the front one on its side differ only in a
/// term odd in the curvature; with turns one way only, the tyres' slip-angle
/// effects (even in it) take its place: §12's full-size drive 2 (both tight
/// circles the same way), front-right tyre 0.3 % large, was taken for the
/// rear-right one at p 1.000 and ended 32 % off.
const TURN_BALANCE_PER_M: f64 = 0.075;

/// The yaw-rate sensor's rear ratio counts once the aided estimator has
/// learnt it this well (relative: the rear wheels' log scale difference) …
pub(crate) const GYRO_RATIO_MAX_SIGMA: f64 = 5e-4;
/// … and an explanation whose rear pair disagrees with it by more than
/// this (or four of its σ) is not the car's: a rear tyre 0.3 % large
/// reads 0.27–0.33 % against the gyro on the multi-body cars, matched rear
/// tyres (each ±0.025 %) within 0.035 %.
const GYRO_RATIO_TOLERANCE: f64 = 1e-3;

/// The least scale error applied: tyres that match leave spurious ones below
/// it where the kinematic model meets real tyres (slip angles, the km/h
/// quantum): 0.01 % at p 0.993 on §12's full-size drive 2 of
/// `tests/experiments.rs` (1.4 % of 660 m as a heading bias), 0.10–0.11 %
/// on three of the 200 full-size drives of `tests/robustness.rs` (up to
/// 3.9 %). A smaller true error is left as it was before the learner: a
/// tyre 0.2 % off ends as rear-only odometry does.
const MIN_APPLIED_SCALE: f64 = 2e-3;
/// … and it must stand this many of its σ from 0.
const MIN_APPLIED_SIGMAS: f64 = 3.0;

/// Prior log odds of a fault explanation against "no wheel off": a tyre is
/// more often matched than not, and the evidence of one clean window of a
/// 0.3 % fault (tens of nats) outweighs this at once.
const FAULT_LOG_PRIOR: f64 = -2.0;

/// An explanation whose evidence falls this many nats behind the best one is
/// held there: a fault that begins later (a tyre losing pressure) can then
/// take over within a few kilometres instead of never.
const MAX_LOG_LAG: f64 = 25.0;

/// The least speed of a window, m/s: below it the wheel-speed signals'
/// quantum is a large share of each reading. A road car's figure: a 1:10
/// robot car at 1 m/s (the demo's) gives the learner no window, and its
/// tick encoders' quantum (0.5 % of a 0.5 m window) would need a noise
/// model of its own before it could.
pub(crate) const MIN_SPEED_MPS: f64 = 3.0;

/// A window closes at this distance of the rear axle's centre, m …
const WINDOW_M: f64 = 5.0;
/// … or after this long, s (whichever first).
const WINDOW_S: f64 = 1.0;

/// χ²₃(0.999): a window that the best explanation misses by more is not used.
pub(crate) const GATE_CHI2: f64 = 16.27;

/// Each wheel's relative noise over a window beyond the distance noise:
/// the signals' quantum and timing, floor of the comparison.
const FLOOR_REL_SIGMA: f64 = 3e-4;

/// Prior σ of the front wheels' read-short in a curve from the tyres' slip
/// angles, per m/s² of lateral acceleration (0.3–0.6 % at 4–6 m/s² on the
/// full-size cars of `tests/robustness.rs`). It is even in the curvature and
/// common to both front wheels, so a state of every explanation rather than
/// noise: as noise it drowned the odd second-order term that tells a rear
/// tyre from the front one on its side.
const FRONT_SLIP_PRIOR_PER_MPS2: f64 = 2e-3;
/// What the linear read-short leaves, per m/s² of lateral acceleration.
const FRONT_SLIP_RESIDUAL_PER_MPS2: f64 = 2e-4;

/// Prior σ of a wheel's scale error: a tyre's rolling diameter is off its
/// neighbour's by well under 2 %, a wheel-speed sensor's factor less.
const SCALE_PRIOR_SIGMA: f64 = 0.01;
/// Prior σ of the steering sensor's offset, road-wheel radians (5°: the
/// filter's own `steer_bias_sigma_rad`): the learner trusts the steering's
/// zero not at all, only its shape.
const OFFSET_PRIOR_SIGMA_RAD: f64 = 0.087;

/// Random walk of a scale error per window: lets a pressure loss be followed.
const SCALE_WALK_PER_WINDOW: f64 = 2e-5;
/// Random walk of the steering offset per window, rad.
const OFFSET_WALK_RAD_PER_WINDOW: f64 = 1e-5;

/// States of each explanation's filter: the scale error `ε`, the steering
/// offset `δ`, the front tyres' read-short `c` per m/s² of lateral
/// acceleration and the steering's gain error `γ` (`κ = (1 + γ) tan(ψ − δ)/L`:
/// a steering ratio off, understeer, or treads that differ from the
/// configuration's). Without `γ` an understeering car (the full-size cars of
/// `tests/experiments.rs` §12) misfit every explanation in each turn, and the
/// least bad one was a wheel that was not off (4.8 % of a 660 m drive).
const S: usize = 4;
/// Index of `c` in an explanation's state.
const SLIP: usize = 2;
/// Index of `γ`.
const GAIN: usize = 3;
/// Prior σ of the steering's gain error: a ratio 10 % off.
const GAIN_PRIOR: f64 = 0.1;

/// One explanation's filter: state `[ε, δ, c, γ]`, covariance, evidence.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Hypothesis {
    x: [f64; S],
    p: [[f64; S]; S],
    log_evidence: f64,
}

/// The geometry the learner needs, from the vehicle in use.
// Units in names, as everywhere in this project.
#[allow(clippy::struct_field_names)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Geometry {
    /// Rear and front treads and the wheelbase, m.
    pub(crate) rear_tread_m: f64,
    pub(crate) front_tread_m: f64,
    pub(crate) wheelbase_m: f64,
}

/// The learnt scales of the four wheels: each wheel reads `scale` times the
/// distance it rolled (relative to the others), with a standard deviation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WheelScales {
    /// Each wheel's scale (1: reads true).
    pub scale: WheelSet<f64>,
    /// Its standard deviation (the mixture's, explanations included).
    pub sigma: WheelSet<f64>,
    /// The explanation the evidence favours most, and its probability.
    pub likeliest: (Fault, f64),
    /// That explanation's scale error (its wheel reads `1 + ε` times true).
    pub likeliest_error: f64,
    /// Why the scales applied are not the likeliest explanation's, if not.
    pub held: Option<Held>,
    /// Whether the yaw-rate sensor's rear ratio left explanations out
    /// (those whose rear pair it contradicts).
    pub told_by_gyro: bool,
    /// Windows used so far.
    pub windows: u32,
}

/// The learner: the explanations' filters, the open window's sums, and the
/// correction in use. `Copy`, no allocation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ScaleLearner {
    hyps: [Hypothesis; HYPOTHESES],
    /// The open window: each wheel's distance (RL, RR, FL, FR), the rear
    /// centre's, `Σ d_r tan φ`, `Σ |d_r| tan² φ`, its time.
    win_wheel_m: [f64; 4],
    win_centre_m: f64,
    win_turn_m: f64,
    win_turn_sq_m: f64,
    win_t_s: f64,
    /// Something in the window disqualified it.
    win_spoilt: bool,
    /// The previous window's mean speed, m/s (for the acceleration's share).
    last_speed_mps: f64,
    /// The mixture's log scale per wheel, applied to the readings
    /// (`reading · exp(−ln_scale)`); all 0 while "no wheel off" leads.
    ln_scale: [f64; 4],
    ln_scale_var: [f64; 4],
    windows: u32,
    /// `Σ κ² d` of the used windows turning left and right (1/m).
    turned_left: f64,
    turned_right: f64,
    /// The last sample's steering angle and its tangent (the angle holds
    /// its value for most samples).
    last_phi_rad: f64,
    last_tan_phi: f64,
    /// What the yaw-rate sensor says of the rear pair: `ln s_RL − ln s_RR`
    /// of the raw readings and its σ (see [`ScaleLearner::set_gyro_rear_ratio`]).
    gyro_rear_ratio: Option<(f64, f64)>,
}

impl ScaleLearner {
    /// A learner with nothing seen: every explanation at its prior.
    pub(crate) fn new() -> Self {
        Self::with_priors(SCALE_PRIOR_SIGMA, OFFSET_PRIOR_SIGMA_RAD)
    }

    /// A learner with the scale errors' prior σ `scale_sigma` and the
    /// offset's `offset_sigma_rad`.
    fn with_priors(scale_sigma: f64, offset_sigma_rad: f64) -> Self {
        let mut hyps = [Hypothesis {
            x: [0.0; S],
            p: [[0.0; S]; S],
            log_evidence: FAULT_LOG_PRIOR,
        }; HYPOTHESES];
        for (h, fault) in hyps.iter_mut().zip(Fault::ALL) {
            h.p[1][1] = offset_sigma_rad * offset_sigma_rad;
            h.p[SLIP][SLIP] = FRONT_SLIP_PRIOR_PER_MPS2 * FRONT_SLIP_PRIOR_PER_MPS2;
            h.p[GAIN][GAIN] = GAIN_PRIOR * GAIN_PRIOR;
            if fault == Fault::None {
                h.log_evidence = 0.0;
            } else {
                h.p[0][0] = scale_sigma * scale_sigma;
            }
        }
        Self {
            hyps,
            win_wheel_m: [0.0; 4],
            win_centre_m: 0.0,
            win_turn_m: 0.0,
            win_turn_sq_m: 0.0,
            win_t_s: 0.0,
            win_spoilt: false,
            last_speed_mps: 0.0,
            ln_scale: [0.0; 4],
            ln_scale_var: [0.0; 4],
            windows: 0,
            turned_left: 0.0,
            turned_right: 0.0,
            last_phi_rad: 0.0,
            last_tan_phi: 0.0,
            gyro_rear_ratio: None,
        }
    }

    /// This learner with its open window dropped (an operator's reset at
    /// standstill): what it learnt is kept.
    pub(crate) fn rebased(&self) -> Self {
        let mut s = *self;
        s.reset_window();
        s
    }

    /// Drops the open window's sums.
    fn reset_window(&mut self) {
        self.win_wheel_m = [0.0; 4];
        self.win_centre_m = 0.0;
        self.win_turn_m = 0.0;
        self.win_turn_sq_m = 0.0;
        self.win_t_s = 0.0;
        self.win_spoilt = false;
    }

    /// What a state file keeps: `None` before the first window.
    pub(crate) fn kept(&self) -> Option<LearntWheelFault> {
        if self.windows == 0 {
            return None;
        }
        let (k, _) = self.lead();
        let fault = Fault::ALL[k];
        let h = &self.hyps[k];
        let none = fault == Fault::None;
        Some(LearntWheelFault {
            fault,
            scale: if none { 1.0 } else { h.x[0].exp() },
            sigma: if none { 0.0 } else { h.p[0][0].max(0.0).sqrt() },
            lead_log_odds: self.lead_log_odds(),
            windows: self.windows,
        })
    }

    /// Each wheel's decided log scale (RL, RR, FL, FR): all 0 while no
    /// wheel is taken to be off.
    pub(crate) fn ln_scale(&self) -> [f64; 4] {
        self.ln_scale
    }

    /// What the learner holds now.
    pub(crate) fn learnt(&self) -> WheelScales {
        let (k, prob) = self.lead();
        let best = Fault::ALL[k];
        let eps = self.hyps[k].x[0];
        let applied = best.wheel_sensitivity().map(|s| s * eps);
        let held =
            (best != Fault::None && self.ln_scale != applied).then(|| self.why_held(k, prob));
        // The σ is about the scales as applied: a correction held back is
        // that much doubt on its wheel, and a rear tyre held until the car
        // has turned both ways is still the front one on its side as well
        // (the mixture alone, sure of the rear one after turns one way,
        // gave both ±0.0001 on the multi-body cars while neither was applied).
        let mut var = self.ln_scale_var;
        if held.is_some() {
            for (v, (&a, &d)) in var.iter_mut().zip(applied.iter().zip(&self.ln_scale)) {
                *v += (a - d) * (a - d);
            }
        }
        if held == Some(Held::TurnsOneWay)
            && let Some(partner) = best.same_side_partner()
        {
            var[partner] += eps * eps;
        }
        let set = |v: [f64; 4]| WheelSet {
            rear_left: v[0],
            rear_right: v[1],
            front_left: v[2],
            front_right: v[3],
        };
        WheelScales {
            scale: set(self.ln_scale.map(f64::exp)),
            sigma: set(var.map(|v| v.max(0.0).sqrt())),
            likeliest: (best, prob),
            likeliest_error: eps.exp() - 1.0,
            held,
            told_by_gyro: self.gyro_allows().contains(&false),
            windows: self.windows,
        }
    }

    /// Why the likeliest explanation's scales are not the ones applied.
    fn why_held(&self, k: usize, p: f64) -> Held {
        let h = &self.hyps[k];
        if p < DECIDED {
            Held::Undecided
        } else if !Self::significant(h) {
            Held::Insignificant
        } else {
            Held::TurnsOneWay
        }
    }

    /// A scale error large and sure enough to apply.
    fn significant(h: &Hypothesis) -> bool {
        h.x[0].abs() >= MIN_APPLIED_SCALE
            && h.x[0].abs() >= MIN_APPLIED_SIGMAS * h.p[0][0].max(0.0).sqrt()
    }

    /// Restores what a state file kept: the leading explanation with its
    /// scale error and σ gets the lead it had against the rest. Values out
    /// of range (a damaged file) leave the learner as it is.
    pub(crate) fn restore(&mut self, kept: &LearntWheelFault) {
        let none = kept.fault == Fault::None;
        let scale_ok = kept.scale.is_finite()
            && (kept.scale.ln()).abs() < 5.0 * SCALE_PRIOR_SIGMA
            && kept.sigma.is_finite()
            && (none || kept.sigma > 0.0);
        if !scale_ok || !kept.lead_log_odds.is_finite() {
            return;
        }
        let k = Fault::ALL
            .iter()
            .position(|f| *f == kept.fault)
            .unwrap_or(0);
        let lag = kept.lead_log_odds.clamp(0.0, MAX_LOG_LAG);
        for (i, h) in self.hyps.iter_mut().enumerate() {
            h.log_evidence = if i == k { 0.0 } else { -lag };
        }
        if !none {
            let h = &mut self.hyps[k];
            h.x[0] = kept.scale.ln();
            for i in 0..S {
                h.p[0][i] = 0.0;
                h.p[i][0] = 0.0;
            }
            h.p[0][0] = kept.sigma * kept.sigma;
        }
        self.windows = kept.windows;
        // It was decided on turns both ways.
        self.turned_left = TURN_BALANCE_PER_M;
        self.turned_right = TURN_BALANCE_PER_M;
        self.mix();
    }

    /// The index of the evidence's favourite and its probability.
    fn lead(&self) -> (usize, f64) {
        let w = self.weights();
        let mut k = 0;
        for i in 1..HYPOTHESES {
            if w[i] > w[k] {
                k = i;
            }
        }
        (k, w[k])
    }

    /// The log odds of the favourite against the runner-up (for the state file).
    pub(crate) fn lead_log_odds(&self) -> f64 {
        let (mut first, mut second) = (f64::NEG_INFINITY, f64::NEG_INFINITY);
        for h in &self.hyps {
            if h.log_evidence > first {
                second = first;
                first = h.log_evidence;
            } else if h.log_evidence > second {
                second = h.log_evidence;
            }
        }
        first - second
    }

    fn weights(&self) -> [f64; HYPOTHESES] {
        let allowed = self.gyro_allows();
        let max = self
            .hyps
            .iter()
            .zip(allowed)
            .filter(|(_, ok)| *ok)
            .fold(f64::NEG_INFINITY, |m, (h, _)| m.max(h.log_evidence));
        let mut w = [0.0; HYPOTHESES];
        for ((v, h), ok) in w.iter_mut().zip(&self.hyps).zip(allowed) {
            if ok {
                *v = (h.log_evidence - max).exp();
            }
        }
        let sum: f64 = w.iter().sum();
        for v in &mut w {
            *v /= sum;
        }
        w
    }

    /// Tells the learner what the yaw-rate sensor says of the rear pair:
    /// `ln s_RL − ln s_RR` of the raw readings (`s` a wheel's scale, as in
    /// [`WheelScales`]) and its σ, or `None` while it says nothing yet.
    /// The odd term that tells a rear tyre from the front one on its side
    /// is second order in the curvature; on tyres that slip in curves (the
    /// multi-body cars) it tells them apart slowly or the wrong way, while
    /// the gyro against the rear pair tells it at once.
    pub(crate) fn set_gyro_rear_ratio(&mut self, told: Option<(f64, f64)>) {
        self.gyro_rear_ratio = told.filter(|(v, sd)| v.is_finite() && sd.is_finite());
    }

    /// Which explanations the yaw-rate sensor allows: each predicts the rear
    /// pair's log difference; one off the gyro's by more than
    /// [`GYRO_RATIO_TOLERANCE`] (or 4σ) is left out, unless that would
    /// leave none (then the gyro is the odd one, and says nothing here).
    fn gyro_allows(&self) -> [bool; HYPOTHESES] {
        let Some((told, sd)) = self.gyro_rear_ratio else {
            return [true; HYPOTHESES];
        };
        let tolerance = GYRO_RATIO_TOLERANCE.max(4.0 * sd);
        let mut allowed = [true; HYPOTHESES];
        for ((ok, h), fault) in allowed.iter_mut().zip(&self.hyps).zip(Fault::ALL) {
            let sens = fault.wheel_sensitivity();
            let predicted = (sens[0] - sens[1]) * h.x[0];
            *ok = (predicted - told).abs() <= tolerance;
        }
        if allowed.iter().any(|ok| *ok) {
            allowed
        } else {
            [true; HYPOTHESES]
        }
    }

    /// Accumulates one sample's raw wheel distances (floor fill not
    /// applied), its measured road-wheel angle and time step.
    /// `clean` is false when the sample must not be learnt from (a stale
    /// front, a wheel at its floor, an axle suspected of slipping).
    #[inline]
    pub(crate) fn accumulate(
        &mut self,
        geo: &Geometry,
        w: &WheelSet<f64>,
        phi_rad: f64,
        dt_s: f64,
        clean: bool,
    ) {
        if phi_rad.to_bits() != self.last_phi_rad.to_bits() {
            self.last_phi_rad = phi_rad;
            self.last_tan_phi = phi_rad.tan();
        }
        let tan_phi = self.last_tan_phi;
        let d = [w.rear_left, w.rear_right, w.front_left, w.front_right];
        let forward = d.iter().all(|v| *v > 0.0);
        let backward = d.iter().all(|v| *v < 0.0);
        self.win_spoilt |= !(clean && (forward || backward));
        let centre = 0.5 * (d[0] + d[1]);
        for (s, v) in self.win_wheel_m.iter_mut().zip(d) {
            *s += v;
        }
        self.win_centre_m += centre;
        self.win_turn_m += centre * tan_phi;
        self.win_turn_sq_m += centre.abs() * tan_phi * tan_phi;
        self.win_t_s += dt_s.max(0.0);
        if self.win_centre_m.abs() >= WINDOW_M || self.win_t_s >= WINDOW_S {
            self.close_window(geo);
        }
    }

    fn close_window(&mut self, geo: &Geometry) {
        let signed_m = self.win_centre_m;
        let dist = signed_m.abs();
        let t = self.win_t_s;
        let speed = if t > 0.0 { dist / t } else { 0.0 };
        let accel = if t > 0.0 {
            (speed - self.last_speed_mps) / t
        } else {
            0.0
        };
        let usable = !self.win_spoilt && speed >= MIN_SPEED_MPS && dist > 0.0;
        let (wheels, turn, turn_sq) = (self.win_wheel_m, self.win_turn_m, self.win_turn_sq_m);
        self.last_speed_mps = speed;
        self.reset_window();
        if !usable {
            return;
        }
        // The distance-weighted mean of tan φ and its spread over the window.
        let tan_mean = turn / signed_m;
        let tan_var = (turn_sq / dist - tan_mean * tan_mean).max(0.0);
        self.update(geo, wheels, tan_mean, tan_var, speed, accel);
    }

    /// One window's three constraints against every explanation.
    fn update(
        &mut self,
        geo: &Geometry,
        wheels: [f64; 4],
        tan_mean: f64,
        tan_var: f64,
        speed_mps: f64,
        accel_mps2: f64,
    ) {
        let y = wheels.map(|d| d.abs().ln());
        // Each wheel's relative variance over the window: its distance noise
        // share, the floor, the front's slip-angle share, the acceleration's.
        let lat = speed_mps * speed_mps * tan_mean.abs() / geo.wheelbase_m;
        // The front factors' spread term is itself approximate: half of it
        // joins the front wheels' noise.
        let spread = 0.25 * tan_var;
        let mut var = [0.0; 4];
        for (i, v) in var.iter_mut().enumerate() {
            let front = if i >= 2 {
                FRONT_SLIP_RESIDUAL_PER_MPS2 * lat + spread
            } else {
                0.0
            };
            let acc = 1e-3 * accel_mps2.abs();
            *v = FLOOR_REL_SIGMA * FLOOR_REL_SIGMA + front * front + acc * acc;
        }
        let psi = tan_mean.atan();
        let mut evals = [(0.0, [0.0; 3], [[0.0; 3]; 3], [[0.0; S]; 3]); HYPOTHESES];
        let mut best_d2 = f64::INFINITY;
        for (k, (h, fault)) in self.hyps.iter().zip(Fault::ALL).enumerate() {
            let (delta, gain) = (h.x[1], 1.0 + h.x[GAIN]);
            let t = (psi - delta).tan();
            let kappa = gain * t / geo.wheelbase_m;
            let dkappa_ddelta = -gain * (1.0 + t * t) / geo.wheelbase_m;
            let dkappa_dgain = t / geo.wheelbase_m;
            // A window's curvature varies: the front factors, second order
            // in it, average to more than their value at the mean.
            let kappa_var = tan_var / (geo.wheelbase_m * geo.wheelbase_m);
            let (lg, dlg) = log_factors(geo, kappa, kappa_var);
            let sens = fault.wheel_sensitivity();
            let (eps, slip) = (h.x[0], h.x[SLIP]);
            // The front wheels read `−c·|a_y|` short (log).
            let short = [0.0, 0.0, -lat, -lat];
            let mut nu = [0.0; 3];
            let mut hm = [[0.0; S]; 3];
            for j in 0..3 {
                let i = j + 1;
                let predicted = eps * (sens[i] - sens[0]) + slip * short[i] + lg[i] - lg[0];
                nu[j] = (y[i] - y[0]) - predicted;
                hm[j] = [
                    sens[i] - sens[0],
                    (dlg[i] - dlg[0]) * dkappa_ddelta,
                    short[i],
                    (dlg[i] - dlg[0]) * dkappa_dgain,
                ];
            }
            // R = A diag(var) Aᵀ for the differences against RL.
            let mut r = [[var[0]; 3]; 3];
            for j in 0..3 {
                r[j][j] += var[j + 1];
            }
            // S = H P Hᵀ + R.
            let mut s = r;
            for j in 0..3 {
                for l in 0..3 {
                    for a in 0..S {
                        for b in 0..S {
                            s[j][l] += hm[j][a] * h.p[a][b] * hm[l][b];
                        }
                    }
                }
            }
            let Some((s_inv, det)) = inverse3(&s) else {
                return;
            };
            let mut d2 = 0.0;
            for j in 0..3 {
                for l in 0..3 {
                    d2 += nu[j] * s_inv[j][l] * nu[l];
                }
            }
            best_d2 = best_d2.min(d2);
            evals[k] = (d2 + det.ln(), nu, s_inv, hm);
        }
        if best_d2.is_nan() || best_d2 > GATE_CHI2 {
            return;
        }
        self.windows += 1;
        let kappa = tan_mean / geo.wheelbase_m;
        let turned = kappa * kappa * wheels.iter().map(|d| d.abs()).sum::<f64>() * 0.25;
        if kappa > 0.0 {
            self.turned_left += turned;
        } else {
            self.turned_right += turned;
        }
        for (h, (cost, nu, s_inv, hm)) in self.hyps.iter_mut().zip(evals) {
            h.log_evidence -= 0.5 * cost;
            kalman_update(h, &nu, &s_inv, &hm);
            h.p[0][0] += SCALE_WALK_PER_WINDOW * SCALE_WALK_PER_WINDOW;
            h.p[1][1] += OFFSET_WALK_RAD_PER_WINDOW * OFFSET_WALK_RAD_PER_WINDOW;
        }
        // "No wheel off" has no scale to learn.
        let none = &mut self.hyps[0];
        none.x[0] = 0.0;
        for i in 0..S {
            none.p[0][i] = 0.0;
            none.p[i][0] = 0.0;
        }
        let max = self
            .hyps
            .iter()
            .fold(f64::NEG_INFINITY, |m, h| m.max(h.log_evidence));
        for h in &mut self.hyps {
            h.log_evidence = (h.log_evidence - max).max(-MAX_LOG_LAG);
        }
        self.mix();
    }

    /// Whether the yaw-rate sensor tells the rear wheel `fault` from the
    /// front one on its side: it sees the rear pair off as that wheel
    /// would make it, and not matched as the front one would leave it. A
    /// front wheel it only tells from the rear one: which front wheel,
    /// the left or the right, is the wheels' evidence alone, and on the
    /// multi-body cars that took a front-right tyre for the front-left
    /// one after turns one way (Escort seed 24).
    fn gyro_tells(&self, fault: Fault) -> bool {
        // Indices into `Fault::ALL`: the rear wheel and the front one on its side.
        const _: () = assert!(
            matches!(Fault::ALL[1], Fault::RearLeft)
                && matches!(Fault::ALL[2], Fault::RearRight)
                && matches!(Fault::ALL[3], Fault::FrontLeft)
                && matches!(Fault::ALL[4], Fault::FrontRight)
        );
        let (own, partner) = match fault {
            Fault::RearLeft => (1, 3),
            Fault::RearRight => (2, 4),
            _ => return false,
        };
        let allowed = self.gyro_allows();
        self.gyro_rear_ratio.is_some() && allowed[own] && !allowed[partner]
    }

    /// The mixture's per-wheel variance, and the scales applied: those of
    /// the leading explanation once it holds [`DECIDED`] of the
    /// probability, else the ones applied before. A half-applied correction
    /// while a rear tyre and the front one on its side are still in play
    /// turns the heading either way; held back, the pose's retro-correction
    /// ([`super::State`]'s rear pair sensitivities) repairs the wait.
    fn mix(&mut self) {
        let w = self.weights();
        let mut mean = [0.0; 4];
        for (h, (fault, wk)) in self.hyps.iter().zip(Fault::ALL.iter().zip(w)) {
            let sens = fault.wheel_sensitivity();
            for i in 0..4 {
                mean[i] += wk * sens[i] * h.x[0];
            }
        }
        let mut var = [0.0; 4];
        for (h, (fault, wk)) in self.hyps.iter().zip(Fault::ALL.iter().zip(w)) {
            let sens = fault.wheel_sensitivity();
            for i in 0..4 {
                let e = sens[i] * h.x[0] - mean[i];
                var[i] += wk * (sens[i] * sens[i] * h.p[0][0] + e * e);
            }
        }
        self.ln_scale_var = var;
        let (k, p) = self.lead();
        let best = Fault::ALL[k];
        let one_wheel = !matches!(best, Fault::None | Fault::FrontAxle);
        if p < DECIDED
            || (one_wheel
                && !self.gyro_tells(best)
                && self.turned_left.min(self.turned_right) < TURN_BALANCE_PER_M)
        {
            return;
        }
        let h = &self.hyps[k];
        let eps = if Self::significant(h) { h.x[0] } else { 0.0 };
        // Below a part in 10⁷ the correction would only move the pose by
        // rounding: "no wheel off" leaves it bit for bit unchanged.
        self.ln_scale = best
            .wheel_sensitivity()
            .map(|s| if (s * eps).abs() < 1e-7 { 0.0 } else { s * eps });
    }
}

/// `ln g_i(κ)` and `∂ ln g_i/∂κ` for RL, RR, FL, FR (§3), the front pair's
/// averaged over a window whose curvature has variance `kappa_var` (the rear
/// factors are linear in κ and average exactly).
fn log_factors(geo: &Geometry, kappa: f64, kappa_var: f64) -> ([f64; 4], [f64; 4]) {
    let (hb, hf, l) = (
        0.5 * geo.rear_tread_m,
        0.5 * geo.front_tread_m,
        geo.wheelbase_m,
    );
    let kl = kappa * l;
    let rear = |sign: f64| {
        let g = 1.0 + sign * kappa * hb;
        (g.abs().max(1e-9).ln(), sign * hb / g)
    };
    let front = |sign: f64| {
        let a = 1.0 + sign * kappa * hf;
        let g2 = a * a + kl * kl + kappa_var * l * l;
        (0.5 * g2.ln(), (a * sign * hf + kl * l) / g2)
    };
    let (rl, rr, fl, fr) = (rear(-1.0), rear(1.0), front(-1.0), front(1.0));
    ([rl.0, rr.0, fl.0, fr.0], [rl.1, rr.1, fl.1, fr.1])
}

/// The inverse and determinant of a symmetric positive 3×3 matrix.
fn inverse3(s: &[[f64; 3]; 3]) -> Option<([[f64; 3]; 3], f64)> {
    let (a, b, c) = (s[0][0], s[1][1], s[2][2]);
    let (d, e, f) = (s[0][1], s[0][2], s[1][2]);
    let (c00, c01, c02) = (b * c - f * f, e * f - d * c, d * f - e * b);
    let (c11, c12, c22) = (a * c - e * e, d * e - a * f, a * b - d * d);
    let det = a * c00 + d * c01 + e * c02;
    if !(det > 0.0 && det.is_finite()) {
        return None;
    }
    let i = 1.0 / det;
    Some((
        [
            [c00 * i, c01 * i, c02 * i],
            [c01 * i, c11 * i, c12 * i],
            [c02 * i, c12 * i, c22 * i],
        ],
        det,
    ))
}

/// The Kalman update of one explanation with its innovation `nu`, `S⁻¹` and
/// Jacobian `hm` (3×S): `K = P Hᵀ S⁻¹`, `P − K H P` symmetrised.
fn kalman_update(h: &mut Hypothesis, nu: &[f64; 3], s_inv: &[[f64; 3]; 3], hm: &[[f64; S]; 3]) {
    // P Hᵀ (S×3).
    let mut pht = [[0.0; 3]; S];
    for a in 0..S {
        for j in 0..3 {
            pht[a][j] = (0..S).map(|b| h.p[a][b] * hm[j][b]).sum();
        }
    }
    let mut k = [[0.0; 3]; S];
    for a in 0..S {
        for j in 0..3 {
            k[a][j] = (0..3).map(|l| pht[a][l] * s_inv[l][j]).sum();
        }
    }
    for a in 0..S {
        h.x[a] += (0..3).map(|j| k[a][j] * nu[j]).sum::<f64>();
    }
    // K H P = K (P Hᵀ)ᵀ.
    let mut p = h.p;
    for a in 0..S {
        for b in 0..S {
            p[a][b] -= (0..3).map(|j| k[a][j] * pht[b][j]).sum::<f64>();
        }
    }
    for a in 0..S {
        for b in a..S {
            let v = 0.5 * (p[a][b] + p[b][a]);
            p[a][b] = v;
            p[b][a] = v;
        }
        p[a][a] = p[a][a].max(0.0);
    }
    h.p = p;
}

#[cfg(test)]
mod tests {
    use super::*;

    const GEO: Geometry = Geometry {
        rear_tread_m: 1.6,
        front_tread_m: 1.6,
        wheelbase_m: 2.7,
    };

    /// Feeds a kinematic drive: `legs` of (metres, curvature 1/m) at 8 m/s,
    /// 100 Hz, wheels scaled by `scale` (RL, RR, FL, FR), the steering
    /// reading `offset_rad` more than the road-wheel angle.
    fn drive(legs: &[(f64, f64)], scale: [f64; 4], offset_rad: f64) -> ScaleLearner {
        let mut s = ScaleLearner::new();
        let (v, dt) = (8.0, 0.01);
        for &(metres, kappa) in legs {
            let steps = (metres / (v * dt)).round() as usize;
            for _ in 0..steps {
                let (lg, _) = log_factors(&GEO, kappa, 0.0);
                let d = v * dt;
                let w = WheelSet {
                    rear_left: d * lg[0].exp() * scale[0],
                    rear_right: d * lg[1].exp() * scale[1],
                    front_left: d * lg[2].exp() * scale[2],
                    front_right: d * lg[3].exp() * scale[3],
                };
                let phi = (kappa * GEO.wheelbase_m).atan() + offset_rad;
                s.accumulate(&GEO, &w, phi, dt, true);
            }
        }
        s
    }

    /// A straight, a 15 m circle left, a 20 m circle right, some curves.
    fn route() -> Vec<(f64, f64)> {
        vec![
            (60.0, 0.0),
            (94.2, 1.0 / 15.0),
            (24.0, 0.0),
            (125.7, -1.0 / 20.0),
            (50.0, 0.03),
            (50.0, -0.06),
            (60.0, 0.0),
        ]
    }

    #[test]
    fn matched_wheels_with_a_steering_offset_stay_untouched() {
        let s = drive(&route(), [1.0; 4], 0.3f64.to_radians());
        let learnt = s.learnt();
        assert_eq!(learnt.likeliest.0, Fault::None, "{learnt:?}");
        assert!(learnt.likeliest.1 > 0.99, "{learnt:?}");
        assert_eq!(s.ln_scale(), [0.0; 4], "{learnt:?}");
    }

    #[test]
    fn one_wheel_off_is_named_and_its_scale_learnt() {
        for (k, fault) in Fault::ALL.iter().enumerate().skip(1).take(4) {
            for eps in [0.003, -0.005] {
                let mut scale = [1.0; 4];
                scale[k - 1] += eps;
                let s = drive(&route(), scale, 0.2f64.to_radians());
                let l = s.learnt();
                assert_eq!(l.likeliest.0, *fault, "{eps}: {l:?}");
                assert!(l.likeliest.1 > 0.99, "{eps}: {l:?}");
                let got = s.ln_scale[k - 1];
                let truth = (1.0 + eps).ln();
                assert!(
                    (got - truth).abs() < 1e-4,
                    "{fault:?} {eps}: {got} vs {truth}"
                );
                // The rear pair's curvature after the correction: what
                // carries the heading.
                let corrected = |i: usize| scale[i] * (-s.ln_scale()[i]).exp();
                let bias = (corrected(1) - corrected(0)) / GEO.rear_tread_m;
                assert!(
                    bias.abs() < 2e-5,
                    "{fault:?} {eps}: rear curvature bias {bias}"
                );
            }
        }
    }

    #[test]
    fn before_any_turn_the_sigma_says_which_wheels_are_in_doubt() {
        // A straight cannot tell a large rear-left tyre from a small
        // front-left one: both stay in play, and the σ of each says so.
        let s = drive(&[(200.0, 0.0)], [1.003, 1.0, 1.0, 1.0], 0.0);
        let l = s.learnt();
        assert!(l.likeliest.1 < 0.9, "{l:?}");
        assert!(
            l.sigma.rear_left > 5e-4 && l.sigma.front_left > 5e-4,
            "{l:?}"
        );
        // The turns then decide.
        let mut legs = vec![(200.0, 0.0)];
        legs.extend(route());
        let s = drive(&legs, [1.003, 1.0, 1.0, 1.0], 0.0);
        assert_eq!(s.learnt().likeliest.0, Fault::RearLeft);
        assert!(s.learnt().sigma.rear_left < 1e-4, "{:?}", s.learnt());
    }

    #[test]
    fn turns_one_way_only_decide_no_single_wheel() {
        let legs = [
            (60.0, 0.0),
            (94.2, 1.0 / 15.0),
            (60.0, 0.0),
            (94.2, 1.0 / 15.0),
        ];
        let s = drive(&legs, [1.0, 1.003, 1.0, 1.0], 0.0);
        assert_eq!(s.ln_scale(), [0.0; 4], "{:?}", s.learnt());
        // Nothing applied, the σ says where the doubt is.
        let l = s.learnt();
        assert!(l.sigma.rear_right > 0.5 * 1.003f64.ln(), "{l:?}");
        // The other way too: now it is applied.
        let mut both = legs.to_vec();
        both.push((94.2, -1.0 / 15.0));
        let s = drive(&both, [1.0, 1.003, 1.0, 1.0], 0.0);
        assert!(
            (s.ln_scale()[1] - 1.003f64.ln()).abs() < 1e-4,
            "{:?}",
            s.learnt()
        );
    }

    #[test]
    fn a_rear_tyre_held_for_turns_one_way_leaves_its_doubt_on_both_axles() {
        // The multi-body cars' tyres make the evidence sure of the rear
        // wheel after turns one way; the rule still holds it, and the σ
        // must then say that the front wheel on its side is as much in play.
        let error = 1.003f64.ln();
        let mut s = ScaleLearner::new();
        for (k, h) in s.hyps.iter_mut().enumerate() {
            h.log_evidence = if k == 2 { 0.0 } else { -MAX_LOG_LAG };
        }
        s.hyps[2].x[0] = error;
        s.hyps[2].p[0][0] = 1e-8;
        s.windows = 150;
        s.turned_right = 4.0 * TURN_BALANCE_PER_M;
        s.mix();
        let l = s.learnt();
        assert_eq!(l.likeliest.0, Fault::RearRight, "{l:?}");
        assert_eq!(l.held, Some(Held::TurnsOneWay), "{l:?}");
        assert_eq!(s.ln_scale(), [0.0; 4]);
        assert!(
            l.sigma.rear_right > 0.9 * error && l.sigma.front_right > 0.9 * error,
            "{l:?}"
        );
        assert!(
            l.sigma.rear_left < 0.01 * error && l.sigma.front_left < 0.01 * error,
            "{l:?}"
        );
        // Turned the other way too, it is applied, and the σ is its own.
        s.turned_left = TURN_BALANCE_PER_M;
        s.mix();
        let l = s.learnt();
        assert_eq!(l.held, None, "{l:?}");
        assert!(
            l.sigma.rear_right < 1e-3 && l.sigma.front_right < 1e-3,
            "{l:?}"
        );
    }

    /// A learner whose evidence leads with `lead` (p ≈ 1) over `second`,
    /// each explanation holding `error` as its scale error, after turns to
    /// the right only.
    fn leaning(lead: Fault, second: Fault, error: f64) -> ScaleLearner {
        let mut s = ScaleLearner::new();
        for (h, fault) in s.hyps.iter_mut().zip(Fault::ALL) {
            h.log_evidence = if fault == lead {
                0.0
            } else if fault == second {
                -10.0
            } else {
                -MAX_LOG_LAG
            };
            if fault != Fault::None {
                h.x[0] = error;
                h.p[0][0] = 1e-8;
            }
        }
        s.windows = 150;
        s.turned_right = 4.0 * TURN_BALANCE_PER_M;
        s.mix();
        s
    }

    #[test]
    fn the_gyro_tells_a_rear_tyre_from_the_front_one_on_its_side() {
        // The wheels' evidence took a large rear-left tyre (reads 0.3 %
        // short) for the front-left one, as on three multi-body cars; the
        // gyro against the rear pair says the rear pair is off by the tyre.
        let error = 0.997f64.ln();
        let mut s = leaning(Fault::FrontLeft, Fault::RearLeft, error);
        assert_eq!(s.learnt().likeliest.0, Fault::FrontLeft);
        s.set_gyro_rear_ratio(Some((error, 2e-5)));
        s.mix();
        let l = s.learnt();
        assert_eq!(l.likeliest.0, Fault::RearLeft, "{l:?}");
        assert!(l.told_by_gyro, "{l:?}");
        // Applied although the car turned one way only: the gyro told the
        // two apart.
        assert!((s.ln_scale()[0] - error).abs() < 1e-12, "{l:?}");
        assert_eq!(l.held, None, "{l:?}");
    }

    #[test]
    fn the_gyro_keeps_a_front_tyre_from_being_taken_for_the_rear_one() {
        // A front-right tyre read as the rear-right one (its turns one way
        // held it, as on two multi-body cars); the gyro finds the rear
        // pair matched, so the rear explanation is out.
        let error = 1.003f64.ln();
        let mut s = leaning(Fault::RearRight, Fault::FrontRight, error);
        assert_eq!(s.learnt().held, Some(Held::TurnsOneWay));
        s.set_gyro_rear_ratio(Some((-2e-4, 2e-5)));
        s.mix();
        let l = s.learnt();
        assert_eq!(l.likeliest.0, Fault::FrontRight, "{l:?}");
        // Still held for turns one way: the gyro does not see the front pair.
        assert_eq!(l.held, Some(Held::TurnsOneWay), "{l:?}");
        assert_eq!(s.ln_scale(), [0.0; 4]);
    }

    #[test]
    fn a_gyro_that_contradicts_every_explanation_says_nothing() {
        let error = 1.003f64.ln();
        let mut s = leaning(Fault::RearRight, Fault::FrontRight, error);
        let before = s.learnt();
        s.set_gyro_rear_ratio(Some((0.05, 1e-5)));
        s.mix();
        let l = s.learnt();
        assert_eq!(l.likeliest, before.likeliest, "{l:?}");
        assert!(!l.told_by_gyro, "{l:?}");
        s.set_gyro_rear_ratio(Some((f64::NAN, 1e-5)));
        assert_eq!(s.learnt().likeliest, before.likeliest);
    }

    #[test]
    fn tyres_of_another_size_on_one_axle_leave_the_heading_alone() {
        let s = drive(&route(), [1.01, 1.01, 1.0, 1.0], 0.1f64.to_radians());
        let l = s.learnt();
        assert_eq!(l.likeliest.0, Fault::FrontAxle, "{l:?}");
        // The front pair is scaled to the rear one; the rear stays as it reads.
        let l = s.ln_scale();
        assert_eq!([l[0], l[1]], [0.0, 0.0]);
        assert!(
            (l[2] - l[3]).abs() < 1e-12 && (l[2] + 1.01f64.ln()).abs() < 1e-4,
            "{l:?}"
        );
    }

    #[test]
    fn a_window_with_a_wheel_rolling_backwards_is_not_learnt() {
        let mut s = ScaleLearner::new();
        let w = WheelSet {
            rear_left: 0.08,
            rear_right: -0.08,
            front_left: 0.08,
            front_right: 0.08,
        };
        for _ in 0..500 {
            s.accumulate(&GEO, &w, 0.0, 0.01, true);
        }
        assert_eq!(s.learnt().windows, 0);
    }

    #[test]
    fn a_restored_fault_is_applied_at_once() {
        let mut s = ScaleLearner::new();
        let kept = LearntWheelFault {
            fault: Fault::RearRight,
            scale: 1.004,
            sigma: 1e-5,
            lead_log_odds: 20.0,
            windows: 300,
        };
        s.restore(&kept);
        let l = s.ln_scale();
        assert!((l[1] - 1.004f64.ln()).abs() < 1e-12, "{l:?}");
        assert_eq!(s.learnt().likeliest.0, Fault::RearRight);
        assert_eq!(s.kept(), Some(kept));
        // A damaged value is not taken.
        let mut fresh = ScaleLearner::new();
        fresh.restore(&LearntWheelFault {
            scale: f64::NAN,
            ..kept
        });
        assert_eq!(fresh, ScaleLearner::new());
    }
}
