//! The extended Kalman filter fusing rear and front odometry
//! (`docs/calibration-math.md` §11–§12).
//!
//! **State** `X = [x, y, θ]` of the rear-axle centre, θ wrapped to (−π, π]
//! (the unwrapped heading is kept beside it), covariance `P` (3×3).
//! **Input** per sample: the four wheels' distances and the measured
//! road-wheel angle φ ([`OdometryInput`]).
//!
//! **Prediction** (paper eqs. 28–30) from rear odometry `u = [Δd, Δθ]`,
//! with `m = θ + Δθ/2`:
//! `A = [[1, 0, −Δd sin m], [0, 1, Δd cos m], [0, 0, 1]]`,
//! `B = [[cos m, −(Δd/2) sin m], [sin m, (Δd/2) cos m], [0, 1]]`,
//! `P⁻ = A P Aᵀ + B Q_u Bᵀ`, `Q_u = J diag(k_r|d_R|, k_r|d_L|) Jᵀ`,
//! `J = [[½, ½], [1/b, −1/b]]`.
//!
//! The filter works in **windows** of `correct_every` samples: the rear and
//! the front odometry are each integrated from zero in the frame of the
//! window's start (the *anchor*), with their own covariances. At the end of
//! a window one of the [`CorrectionForm`]s fuses them and the result is
//! composed onto the anchor (`P = J_a P_a J_aᵀ + R P_w Rᵀ`, which equals the
//! sample-by-sample propagation). Every covariance update is the Joseph form,
//! symmetrised.
//!
//! - [`CorrectionForm::Anchored`] (default): `ν = front − rear` increment
//!   over the window, `S = P_w,rear + P_w,front`, `K = P_w,rear S⁻¹`; by
//!   default the update is applied only through the gate
//!   ([`EkfConfig::blend_accepted`]).
//! - [`CorrectionForm::Literal`]: the paper's own filter: `z` is the front
//!   odometry integrated on its own from the start, `H = I`, `S = P⁻ + R`.
//! - [`CorrectionForm::RearOnly`]: no correction (rear odometry with a covariance).
//!
//! **Steering error model**: white noise (`steer_sigma_rad`, per sample, in
//! `Q_f = J_f diag(k_f|Δd_f|, σ_φ²) J_fᵀ`) plus a bias held over each window
//! (`steer_bias_sigma_rad`), whose effect is propagated as the sensitivity
//! `v = ∂w_front/∂b` and added as `σ_b² v vᵀ` to the front window covariance.
//!
//! **Steering offset**: optionally (on by default) a scalar Kalman filter
//! learns the sensor's offset from each accepted window's heading innovation
//! `ν_θ ≈ (b − b̂)·v_θ` and subtracts it from the measured angle.
//!
//! **Gate**: the squared Mahalanobis distance `d² = νᵀS⁻¹ν` against a
//! threshold (χ²₃(0.99) = 11.34). On rejection the [`GateAction::Consensus`]
//! compares each wheel's implied centre distance `s_i = Σ d_i/g_i(φ)` over the
//! window: the wheel farthest from the median of the four slipped; if it is a
//! rear wheel the front increment is used, if a front wheel the rear one is kept.
//!
//! # Robustness: cars and drives the filter was not tuned on
//!
//! The judge is `tests/robustness.rs`: 200 random drives of full-size cars
//! (`sim::family::full_size_car`: random size, tyre slip angles, steering
//! bias and ratio error, km/h and steering-wheel quantisation, jumping or
//! rate-limited steering, 10–20 m circles at 6–10 m/s), 200 drives of the
//! 1:10 car with slips, and 200 town drives. What was measured, and what
//! the default therefore does:
//!
//! - **Tyres break the kinematic front.** A real car needs slip angles to
//!   turn: the rear axle slides outwards (1–2° at 4–6 m/s²) and the front
//!   wheels read 0.3–0.6 % short of the kinematic conversion in a circle.
//!   The blended filter read that as a heading error: 3 % of the distance
//!   with the gate off, 19 % with it. With kinematic tyres the same filter
//!   was within 0.04 %. Rear sideslip alone explained most of it (0.3 %
//!   without it).
//! - **A front distance scale term** (`front_scale_sigma`, 1 %, `σ_s² w_f
//!   w_fᵀ`) takes the front's distance error out of the heading: it cut the
//!   blended worst case from 19 % to 0.5 %, and the gate's false alarms on
//!   no-slip drives to zero (2.8 per km before).
//! - **Blending agreeing windows** still cost up to 0.5 % on these cars and
//!   gained nothing on them (rear-only is within 0.06 % on average); on the
//!   1:10 car with slips the filter with and without blending ends at 1.5 %
//!   of rear-only's mean squared error alike, because the slips it must
//!   repair are the ones the gate catches. So the default keeps the rear
//!   increment in accepted windows and uses the front only on rejection.
//!   Full-size, no slip: worst fused − rear-only +0.000 %, worst fused
//!   0.149 % of the distance, 0 rejections in 136 km. §11's slip experiment:
//!   −97 %. Front slips only: equal to rear-only.
//! - **A blame by a hair is not a slip.** Harsher cars (twice the tyre
//!   effects, a steering ratio 8 % off) still made the gate fire now and
//!   then (0.4 per km), and a rear wheel blamed by the consensus then handed
//!   the window to the front: up to 1.5 % of the distance. A real slip moves
//!   the blamed wheel's implied distance by tens of per cent; these by one
//!   or two. So the front replaces the window only when the blamed rear
//!   wheel is 5 % off the others' median (`min_slip_ratio`): the harsher
//!   cars are then never worse than rear-only, and §11 stays at −97 %.
//! - **A steering gain term** (ratio error, understeer as `φ·∂w/∂φ`) and a
//!   larger steering bias were tried and changed nothing; a per-wheel
//!   substitution of a blamed rear wheel instead of the whole front window
//!   was 1 point worse on §11 and no better in town. Neither is kept.
//! - **Town driving: the sensors' floor.** Wheel-speed sensors report 0
//!   below about 2 km/h, the inner wheels first; stopping and crawling made
//!   the wheels disagree with nothing slipping (40 rejections per km) and
//!   plain rear-only drift by 1.4 % of the distance on average. A wheel that
//!   reads exactly 0 while another moves the same way is filled from the
//!   others through the geometry ([`OdometryInput::zero_is_floor`], set for
//!   speed sensors only: an encoder's zero step is quantisation). Then 4
//!   rejections per km, fused 1.21 % on average; worst fused − rear-only
//!   (with the same fill) +0.076 %. What crawling below the floor loses on
//!   all four wheels stays lost: no wheel can say it.
//!
//! Steps are pure: [`Ekf::step`] takes the previous [`State`] and returns a
//! new one, or an error for a non-finite input, leaving the caller's state
//! untouched; no step allocates.
#![allow(non_snake_case)]

use crate::error::{Error, Result};
use crate::odometry::Increment;
#[cfg(test)]
use crate::odometry::{Pose, wheel_distance_factors};
use crate::rotation::advance_heading;
use crate::{Wheel, WheelSet, wrap_angle};
use nalgebra::{Matrix2, Matrix3, Vector3};

mod aided;
mod algebra;
mod config;
mod retro;
mod scales;
mod slide;
mod state;
mod wheels;
use aided::{Aided, Learnable};
#[cfg(test)]
use algebra::propagate;
use algebra::{
    compose, compose_covariance, joseph, propagate_sensitivity, propagate_with, symmetric,
    symmetric_inverse, turned_cos_sin,
};
pub use config::{CorrectionForm, EkfConfig, FrontHeading, GateAction};
use retro::{RETRO_ORDER, add_rear_moments, reapply_rear_pair};
pub use scales::{Fault, HYPOTHESES, Held, WheelScales};
use scales::{Geometry, ScaleLearner};
use slide::Slide;
use wheels::{
    Axle, AxleWatch, MAX_FLOOR_FILL_MPS, blamed_wheel, every_wheel_reads_zero, launch_variance,
    outlier_excess,
};

/// 3-vector of the state `[x, y, θ]`.
pub type Vec3 = Vector3<f64>;
/// 3×3 covariance.
pub type Mat3 = Matrix3<f64>;

/// χ²₃(0.99), the default gate.
pub const CHI2_3_99: f64 = 11.34;

/// How many of its standard deviations the rear diameter ratio's error,
/// learnt against the gyro, must lie from 0 before the aided estimator
/// carries the pose instead of the wheels. Where the wheels are exact (the
/// opendbc drives) the learnt ratio stays within 2.4σ of 0; where they are
/// not it lies 4.7σ (the multi-body Vanagon of seed 22) to 26σ (the real
/// RAV4, a 0.044 % ratio the wheels' own learning cannot tell on a
/// highway) off. Until then the wheels carry it: a kinematic car's exact
/// wheels ended 0.002–0.04 % off where the gyro-carried heading ended
/// 0.05–1.35 %.
pub const AIDED_LEAD_SIGMAS: f64 = 3.5;

/// How far the car must have driven with the gyro before the aided
/// estimator may take the pose over, m: the wheels' own learning decides
/// which wheel is off 150–250 m into a drive (and the aided estimator's
/// rear ratio then follows what it applies); a ratio it has not explained
/// by then is the gyro's to carry. The effective tread's counts from the
/// aided estimator's start: a decision of the wheels' learning scales one
/// wheel's distance, not the turn (counted from the decision, a car 2 %
/// wider with a rear tyre 0.5 % large kept the wheels' pose on 2 of 10
/// simulated drives, 1.2 % off).
pub const AIDED_LEAD_MIN_DISTANCE_M: f64 = 300.0;

/// As [`AIDED_LEAD_SIGMAS`] for the effective tread's error: where the
/// wheels are exact it stays within 0.2σ of 0 (its σ is 0.5 % after an
/// opendbc drive), where the tread is 2 % wider than configured it lies
/// 3.7σ off after 800 m. Tyres that slip in curves show it less clearly:
/// the multi-body Escort (seed 105, 1.2 km) ended with +1.45 ± 0.62 %
/// (2.3σ), and at 3σ kept its rear wheels' pose, 2.27 % off where the
/// gyro-carried one ends 0.66 %. At 2σ the 100 opendbc drives of five gyro
/// platforms (seeds 10–13, tyres and treads off), the other 35 multi-body
/// drives and the real RAV4 end exactly as at 3σ.
pub const AIDED_LEAD_TREAD_SIGMAS: f64 = 2.0;

/// A gyro whose bias is known this well (rad/s: 0.005°/s, 0.3° a minute)
/// carries the heading whatever the wheels show: the real RAV4 calibrated
/// from its first 30 s (bias σ 0.0008°/s) ended its second half 0.09 % off
/// with the gyro and 0.91 % with its calibrated wheels, whose learnt ratio
/// no longer looks off. An uncalibrated gyro's stays at 0.02–0.06°/s over
/// opendbc's drives.
pub const AIDED_LEAD_BIAS_SIGMA_RADPS: f64 = 0.005 * std::f64::consts::PI / 180.0;

/// The least effective-tread error, relative, for which the aided
/// estimator takes the pose over (beside [`AIDED_LEAD_SIGMAS`]): a tread
/// 0.5 % off turns the wheels' heading 1.8° a full circle.
pub const AIDED_LEAD_MIN_TREAD: f64 = 0.005;

/// Whether the aided estimator carries the pose, and what it needs to
/// decide it.
#[derive(Debug, Clone, Copy, PartialEq)]
struct AidedLead {
    /// The aided estimator carries the pose (the rules beside
    /// [`AIDED_LEAD_SIGMAS`]).
    leads: bool,
    /// The wheel scales the aided estimator's wheels are read with: those
    /// the wheels' own learning applies until it leads (its rear ratio then
    /// follows each change), those applied when it took the lead from then
    /// on.
    factor: [f64; 4],
    /// The rear axle's distance since the aided estimator started (or since
    /// the wheels' learning last decided), m: the rear ratio's evidence.
    distance_m: f64,
    /// The rear axle's distance since the aided estimator started, m: the
    /// effective tread's evidence, which a decision of the wheels' learning
    /// does not reset (it scales one wheel's distance, not the turn).
    total_m: f64,
}

impl AidedLead {
    const NONE: Self = Self {
        leads: false,
        factor: [1.0; 4],
        distance_m: 0.0,
        total_m: 0.0,
    };
}

/// A change of the rear wheels' applied scales this large (relative) is a
/// decision of the wheels' learning, not its ordinary refinement window by
/// window (±10⁻⁶).
const RATIO_DECISION: f64 = 1e-4;

/// The least rear ratio error, relative, for which the aided estimator
/// takes the pose over (beside [`AIDED_LEAD_SIGMAS`]): 5·10⁻⁵ turns a car of
/// 1.5 m tread by under 2° a kilometre.
pub const AIDED_LEAD_MIN_RATIO: f64 = 5e-5;

/// How far the aided estimator must have driven since it started (or since
/// a decision of the wheels' learning started its rear ratio afresh) before
/// the learner takes that ratio, m: the ratio parts from the gyro's bias
/// only as the speed varies, which a few hundred metres of driving do.
const GYRO_RATIO_MIN_DISTANCE_M: f64 = 200.0;

/// What the yaw-rate sensor says of the rear pair, for the wheels'
/// learner: `ln s_RL − ln s_RR` of the raw readings and its σ, once the
/// aided estimator carries the pose and has learnt its rear ratio (on the
/// wheels as it reads them, with `st.lead.factor`, which no decision of
/// the learner changes from then on) over [`GYRO_RATIO_MIN_DISTANCE_M`] to
/// [`scales::GYRO_RATIO_MAX_SIGMA`]; `None` before, and without a gyro.
///
/// Only once it carries the pose: a decision the gyro told while the
/// wheels still carried it started the aided estimator's rear ratio afresh
/// (a decision does), and on the multi-body cars the corrected wheels then
/// kept the pose, whose tyres slip in curves (a rear tyre 0.3 % large, seed
/// 27: 0.27 % → 9.1 % of the distance).
fn gyro_rear_ratio(st: &State) -> Option<(f64, f64)> {
    if !st.aided_on || !st.lead.leads || st.lead.distance_m < GYRO_RATIO_MIN_DISTANCE_M {
        return None;
    }
    let [_, (ratio, sd), _] = st.aided.learnt();
    // The aided estimator's wheels read d·f: its ratio error is
    // (ln s_RL + ln f_RL) − (ln s_RR + ln f_RR).
    let [f_rl, f_rr, _, _] = st.lead.factor;
    (sd < scales::GYRO_RATIO_MAX_SIGMA).then(|| (ratio - f_rl.ln() + f_rr.ln(), sd))
}

/// One sample's input: each wheel's distance since the previous sample and
/// the measured road-wheel angle (the steering signal mapped through the
/// steering map in use).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct OdometryInput {
    /// Distance of each wheel since the previous sample (signed).
    pub wheel_m: WheelSet<f64>,
    /// False when the front wheels' sample is missing (stale): the window then
    /// is not corrected and the filter predicts from the rear alone.
    pub front_valid: bool,
    /// The measured road-wheel angle φ.
    pub steer_angle_rad: f64,
    /// The wheels are wheel-speed sensors, which report 0 below a floor of
    /// about 2 km/h: a wheel reading exactly 0 while another moves the same
    /// way is then below its floor, not still (the inner wheels drop out
    /// first when stopping and crawling). The filter fills such a wheel from
    /// the others through the steering geometry. False for tick encoders,
    /// whose zero steps are quantisation that the next tick makes up.
    pub zero_is_floor: bool,
    /// The yaw-rate sensor, rad/s, left positive, its scale corrected but
    /// not its bias (the filter learns that); `None` without one or while it
    /// is stale.
    pub yaw_rate_radps: Option<f64>,
    /// Time since the previous sample, s (integrates the yaw rate; 0 when
    /// unknown, which leaves the yaw rate out of the step).
    pub dt_s: f64,
}

/// What happened at a step's correction window, if the step closed one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum WindowOutcome {
    /// The step did not close a window (most steps).
    #[default]
    Open,
    /// The window closed without a correction: rear-only form.
    RearOnly,
    /// The window closed without a correction: a front sample was missing.
    NoFront,
    /// The gate let the correction through.
    Accepted,
    /// The gate rejected it and the rear increment was kept (a front wheel slipped).
    RejectedKeptRear,
    /// The gate rejected it and the front increment was used (a rear wheel slipped).
    RejectedUsedFront,
    /// The yaw-rate-aided estimator's gate rejected the window: the rear
    /// wheels' turn and the gyro's disagreed beyond `yaw_gate_sigma` with
    /// no wheel seen slipping. The gyro carried the heading and the rear
    /// distance was kept, as in [`WindowOutcome::RejectedKeptRear`], and
    /// nothing was learnt; but the rear wheels' distances are not suspect
    /// (a tyre whose size changed does this in every turning window).
    Disagreed,
}

impl WindowOutcome {
    /// Short snake-case name for logs and CSV columns (`""` for [`WindowOutcome::Open`]).
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Open => "",
            Self::RearOnly => "rear_only",
            Self::NoFront => "no_front",
            Self::Accepted => "accepted",
            Self::RejectedKeptRear => "kept_rear",
            Self::RejectedUsedFront => "used_front",
            Self::Disagreed => "disagreed",
        }
    }

    /// Whether a gate rejected the window's correction, whatever it did
    /// then (the `GateReject` count, the gate flag of the recordings).
    pub fn is_rejected(self) -> bool {
        matches!(
            self,
            Self::RejectedKeptRear | Self::RejectedUsedFront | Self::Disagreed
        )
    }
}

/// How the corrections went.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct GateStats {
    /// Windows closed with a correction attempt.
    pub corrections: u64,
    /// Corrections the gate let through (or all, without a gate).
    pub accepted: u64,
    /// Rejections resolved by taking the front increment (a rear wheel slipped).
    pub rejected_used_front: u64,
    /// Rejections resolved by keeping the rear prediction (a front wheel slipped).
    pub rejected_kept_rear: u64,
    /// Windows not corrected because a front sample was missing.
    pub skipped_no_front: u64,
    /// Samples where the yaw-rate sensor and the rear wheels disagreed and
    /// the steering sided with the yaw rate (a rear wheel slipped): the
    /// heading came from the yaw rate alone.
    pub yaw_over_rear: u64,
    /// Samples where they disagreed and the yaw rate was refused (no
    /// steering to side with it, or the steering sided with the wheels).
    pub yaw_refused: u64,
}

/// The filter's state after a step. `Copy`, fixed-size: no allocation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct State {
    anchor: Vec3,
    anchor_heading_unwrapped_rad: f64,
    anchor_cos_sin: (f64, f64),
    p_anchor: Mat3,
    rear_w: Vec3,
    p_rear_w: Mat3,
    front_w: Vec3,
    p_front_w: Mat3,
    /// ∂(front window pose)/∂(steering bias).
    front_bias_sens: Vec3,
    /// (cos, sin) of the rear and front window headings, rotated along with
    /// them so that a step needs no trigonometric call (see [`advance_heading`]).
    rear_cs: (f64, f64),
    front_cs: (f64, f64),
    /// Literal form: the front odometry integrated alone (global, unwrapped θ).
    front_alone: Vec3,
    /// The window's distance of each wheel (in [`WHEEL_ORDER`]), the front
    /// pair scaled, and `Σ Δd_r tan φ` for the steering's curvature.
    wheel_sum_m: [f64; 4],
    steer_turn_sum_m: f64,
    window_len: u32,
    window_front_ok: bool,
    /// Counts of gate decisions.
    pub stats: GateStats,
    /// Per wheel: how many windows the consensus blamed on it.
    pub slip_counts: WheelSet<u64>,
    /// Per wheel: blamed in the most recent closed window.
    pub slip_flags: WheelSet<bool>,
    /// `d²` of the most recent correction (NaN-free; 0 before the first).
    pub last_mahalanobis_sq: f64,
    /// What this step's window did ([`WindowOutcome::Open`] unless the
    /// step closed one); the wheel blamed on a rejection is in `slip_flags`.
    pub last_window: WindowOutcome,
    steer_offset_rad: f64,
    /// Variance of the offset estimate; 0 until the first update (the prior
    /// is the configuration's `steer_bias_sigma_rad`).
    steer_offset_var: f64,
    /// The yaw-rate-aided estimator, which runs from the first yaw-rate
    /// sample on (`aided_on`) and carries the pose once it has shown the
    /// wheels off (`lead`).
    aided: Aided,
    aided_on: bool,
    /// Whether the aided estimator leads, and what decides it.
    lead: AidedLead,
    /// What an earlier run or a calibration taught about the yaw-rate
    /// sensor, for the aided estimator to start from.
    pending_yaw: Option<LearntPair>,
    /// Factor applied to the front wheels' distances (learnt, 1 if off).
    front_scale: f64,
    /// Variance of `ln(front_scale)`; 0 until the first update.
    front_scale_var: f64,
    /// The window's rear and front (scaled) centre distances.
    window_rear_m: f64,
    window_front_m: f64,
    /// What the last step derived from its steering angle, reused while the
    /// angle (less the learnt offset) stays the same to the bit.
    steer_terms: SteerTerms,
    /// Every wheel read 0 in the last step (a launch is the first step
    /// after such a one that does not).
    wheels_were_zero: bool,
    /// The car's speed as the wheels tell it, and a slide on locked wheels
    /// being bridged ([`slide`]).
    slide: Slide,
    /// Which axle changed speed faster than the car can ([`AxleWatch`]).
    axle_watch: AxleWatch,
    /// Each wheel's scale, learnt from the other sensors ([`scales`]).
    scales: ScaleLearner,
    /// The pose's history as the rear pair correction acts on it: a heading
    /// bias β per metre rotates every displacement by `−β·S`, `S` the rear
    /// distance driven before it, so the windows' global displacements are
    /// kept as moments `M_n = Σ S_midⁿ Δx` (n = 0…[`RETRO_ORDER`]) with `S`
    /// itself. When the learner changes its mind, the pose moves to where
    /// the new scales applied from the start would have put it
    /// ([`reapply_rear_pair`]): a fault the sensors only tell apart after
    /// the car turned both ways (a rear tyre 0.3 % large against the front
    /// one on its side 0.3 % small) would otherwise leave the heading it
    /// turned before that, 0.3–0.6 rad in the first 200 m.
    rear_moments: [[f64; 2]; RETRO_ORDER + 1],
    rear_distance_m: f64,
    /// A wheel's scale acts on its own distance, the centre's plus `(b/2)Δθ`:
    /// the pair's mean scale turns the heading by `−Δμ·Θ` too, `Θ` the
    /// wheels' turn so far (0.016 rad in a full circle for a 0.5 % tyre),
    /// carried to first order as `N_n = Σ S_midⁿ Θ_mid Δx` with `Θ` itself.
    rear_turn_moments: [[f64; 2]; RETRO_ORDER + 1],
    rear_turn_rad: f64,
    /// The wheels' log scales the readings are corrected by, and the
    /// factors `exp(−ln s)`: taken from the learner at a window's close
    /// only, with the pose moved to match, so that no window mixes two.
    applied_ln_scale: [f64; 4],
    applied_factor: [f64; 4],
}

/// The quantities a step derives from `φ − offset` alone: a tangent, three
/// square roots and two divisions, all on the step's critical path. The
/// angle repeats in most steps (a steering signal holds its value on
/// straights and steady curves: three steps in four of the benchmark drive),
/// so the last set is kept and reused when the angle is bit-identical: the
/// same numbers, not an approximation (2.4 % off the whole replay's time).
#[derive(Debug, Clone, Copy, PartialEq)]
struct SteerTerms {
    /// Bits of the angle these are for; [`SteerTerms::NONE`] before any.
    angle_bits: u64,
    tan_phi: f64,
    /// The `g_i` of [`distance_factors`].
    g: [f64; 4],
    /// `1 / (g_RL g_RR g_FL g_FR)`, or 0 where a pivot turn makes a `g_i` zero.
    inv_g_product: f64,
    /// cos and sin of the angle, from `tan φ`.
    cos_phi: f64,
    sin_phi: f64,
}

impl SteerTerms {
    /// No angle yet: the bits of a NaN, which no checked angle has.
    const NONE: Self = Self {
        angle_bits: u64::MAX,
        tan_phi: 0.0,
        g: [1.0; 4],
        inv_g_product: 1.0,
        cos_phi: 1.0,
        sin_phi: 0.0,
    };

    /// The terms for `angle_rad` (`φ − offset`), as the step computed them inline.
    fn at(k: &Derived, angle_rad: f64) -> Self {
        let tan_phi = angle_rad.tan();
        let g = distance_factors(k, tan_phi);
        let [g_rl, g_rr, g_fl, g_fr] = g;
        // Four reciprocals from one division.
        // A pivot turn tighter than half the tread makes a g_i zero: that
        // sample then says nothing about slip, rather than poisoning the window.
        let inv = 1.0 / ((g_rl * g_rr) * (g_fl * g_fr));
        let cos_phi = 1.0 / tan_phi.mul_add(tan_phi, 1.0).sqrt();
        Self {
            angle_bits: angle_rad.to_bits(),
            tan_phi,
            g,
            inv_g_product: if inv.is_finite() { inv } else { 0.0 },
            cos_phi,
            sin_phi: tan_phi * cos_phi,
        }
    }
}

/// What a filter learns about its vehicle online, kept across restarts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Learnt {
    /// The steering sensor's offset, road-wheel radians.
    pub steer_offset_rad: f64,
    /// Its standard deviation (0: not learnt).
    pub steer_offset_sigma_rad: f64,
    /// The front wheels' distance factor.
    pub front_scale: f64,
    /// Its standard deviation (0: not learnt).
    pub front_scale_sigma: f64,
    /// The yaw-rate bias and rear ratio error, once a yaw-rate sensor was seen.
    pub yaw_bias: Option<LearntPair>,
    /// The wheel taken to read off its scale, once the learner has used a
    /// window ([`State::wheel_scales`]).
    pub wheel_fault: Option<LearntWheelFault>,
}

/// What the wheel-scale learner keeps across a restart: its leading
/// explanation, the scale error it learnt, and how far it leads.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LearntWheelFault {
    /// The explanation the evidence favoured.
    pub fault: Fault,
    /// Its wheel's scale (1 for [`Fault::None`]).
    pub scale: f64,
    /// The scale's standard deviation (0 for [`Fault::None`]).
    pub sigma: f64,
    /// Its log odds against the runner-up, nats.
    pub lead_log_odds: f64,
    /// Windows the learner had used.
    pub windows: u32,
}

/// The yaw-rate sensor's bias and the rear wheels' errors, learnt together
/// against it. A σ of 0 means "not learnt": the configuration's prior.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LearntPair {
    /// Bias of the yaw-rate sensor, rad/s.
    pub yaw_bias_radps: f64,
    /// Its standard deviation.
    pub yaw_bias_sigma_radps: f64,
    /// Relative error of the rear diameter ratio.
    pub rear_ratio_err: f64,
    /// Its standard deviation.
    pub rear_ratio_sigma: f64,
    /// Relative error of the effective rear tread (the wheels turn `1 + τ`
    /// times the body).
    pub tread_err: f64,
    /// Its standard deviation.
    pub tread_sigma: f64,
}

/// The filter: a validated configuration and pure step functions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ekf {
    cfg: EkfConfig,
    /// Constants of the configuration a step would otherwise recompute.
    k: Derived,
}

/// Reciprocals and products of the configuration, computed once: a division
/// costs as much as the rest of a product chain, and a step had twenty.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Derived {
    /// 1/b.
    inv_rear_tread: f64,
    /// 1/L.
    inv_wheelbase: f64,
    /// b/(2L) and b_f/(2L): `g_i` needs `κ b/2` with `κ = tan φ / L`.
    half_rear_tread_per_wheelbase: f64,
    half_front_tread_per_wheelbase: f64,
    /// 1/(2 b_f).
    inv_two_front_tread: f64,
    /// σ_φ² and σ_b².
    steer_var: f64,
    steer_bias_var: f64,
    front_scale_var: f64,
    /// The treads and wheelbase, for the wheel-scale learner.
    geometry: Geometry,
}

impl Derived {
    fn new(cfg: &EkfConfig) -> Self {
        let p = &cfg.params;
        let inv_wheelbase = 1.0 / p.wheelbase_m();
        Self {
            inv_rear_tread: 1.0 / p.rear_tread_m(),
            inv_wheelbase,
            half_rear_tread_per_wheelbase: 0.5 * p.rear_tread_m() * inv_wheelbase,
            half_front_tread_per_wheelbase: 0.5 * p.front_tread_m() * inv_wheelbase,
            inv_two_front_tread: 0.5 / p.front_tread_m(),
            steer_var: cfg.steer_sigma_rad * cfg.steer_sigma_rad,
            steer_bias_var: cfg.steer_bias_sigma_rad * cfg.steer_bias_sigma_rad,
            front_scale_var: cfg.front_scale_sigma * cfg.front_scale_sigma,
            geometry: Geometry {
                rear_tread_m: p.rear_tread_m(),
                front_tread_m: p.front_tread_m(),
                wheelbase_m: p.wheelbase_m(),
            },
        }
    }
}

/// An input's values are finite and its steering angle short of ±90°.
fn check_input(input: &OdometryInput) -> Result<()> {
    let w = &input.wheel_m;
    let phi = input.steer_angle_rad;
    // One test on the sum in the common case; the slow path names the culprit.
    let front_sum = if input.front_valid {
        w.front_left + w.front_right
    } else {
        0.0
    };
    if !(w.rear_left + w.rear_right + phi + front_sum).is_finite() {
        finite("rear_left_m", w.rear_left)?;
        finite("rear_right_m", w.rear_right)?;
        finite("steer_angle_rad", phi)?;
        if input.front_valid {
            finite("front_left_m", w.front_left)?;
            finite("front_right_m", w.front_right)?;
        }
    }
    if phi.abs() >= std::f64::consts::FRAC_PI_2 - 1e-6 {
        return Err(Error::SteeringOutOfRange {
            steer_angle_rad: phi,
        });
    }
    Ok(())
}

fn finite(name: &'static str, value: f64) -> Result<f64> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(Error::NonFiniteInput { name, value })
    }
}

/// The wheel distance factors `g_i` of §3 (as [`crate::odometry::wheel_distance_factors`])
/// from `tan φ`, without a second tangent.
fn distance_factors(k: &Derived, tan_phi: f64) -> [f64; 4] {
    let lk2 = tan_phi * tan_phi;
    let half_b = k.half_rear_tread_per_wheelbase * tan_phi;
    let half_bf = k.half_front_tread_per_wheelbase * tan_phi;
    [
        1.0 - half_b,
        1.0 + half_b,
        (lk2 + (1.0 - half_bf) * (1.0 - half_bf)).sqrt(),
        (lk2 + (1.0 + half_bf) * (1.0 + half_bf)).sqrt(),
    ]
}

/// A road car for the filter's unit tests: 2.5 m wheelbase, 1.5 m treads
/// (least straight speed 5 m/s), the default settings.
#[cfg(test)]
fn road_car() -> EkfConfig {
    let params = crate::params::VehicleParams::new(
        2.5,
        1.5,
        1.5,
        WheelSet::splat(0.65),
        100,
        crate::params::SteeringMap::IDENTITY,
    )
    .unwrap_or_else(|e| unreachable!("a valid road car: {e}"));
    EkfConfig::new(params)
}

impl Ekf {
    /// A filter with a validated configuration.
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] for a non-positive noise, zero window, or bad `R`.
    pub fn new(config: EkfConfig) -> Result<Self> {
        config.validate()?;
        Ok(Self {
            k: Derived::new(&config),
            cfg: config,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &EkfConfig {
        &self.cfg
    }

    /// Rear input covariance `Q_u = J diag(k_r|d_R|, k_r|d_L|) Jᵀ`.
    fn q_rear(&self, d_l: f64, d_r: f64) -> Matrix2<f64> {
        let ib = self.k.inv_rear_tread;
        let vr = self.cfg.k_rear_m * d_r.abs();
        let vl = self.cfg.k_rear_m * d_l.abs();
        let q12 = 0.5 * (vr - vl) * ib;
        Matrix2::new(0.25 * (vr + vl), q12, q12, (vr + vl) * ib * ib)
    }

    /// The front increment at the rear axle, its input covariance and its
    /// sensitivity to a steering bias. `tan φ`, the front `g_i` and the
    /// angle's cosine and sine come precomputed: the step needs some of them
    /// for the consensus too.
    fn front(
        &self,
        d_fl: f64,
        d_fr: f64,
        terms: &SteerTerms,
    ) -> (Increment, Matrix2<f64>, (f64, f64)) {
        let k_f = self.cfg.k_front_m;
        let inv_L = self.k.inv_wheelbase;
        let d_f = 0.5 * (d_fl + d_fr);
        let (tan_phi, c, s) = (terms.tan_phi, terms.cos_phi, terms.sin_phi);
        let [_, _, g_fl, g_fr] = terms.g;
        // The exact conversion (front_increment_exact): Δd_r = (d_FR + d_FL)/(g_FR + g_FL).
        let distance_m = (d_fl + d_fr) / (g_fl + g_fr);
        match self.cfg.front_heading {
            FrontHeading::Steering => {
                let inc = Increment {
                    distance_m,
                    dtheta_rad: distance_m * tan_phi * inv_L,
                };
                // Q_f = J_f diag(k_f|Δd_f|, σ_φ²) J_fᵀ written out (symmetric,
                // D diagonal): the matrix products formed zeros and both halves.
                let (j11, j12, j21, j22) = (c, -d_f * s, s * inv_L, d_f * c * inv_L);
                let (dv, sv) = (k_f * d_f.abs(), self.k.steer_var);
                let q12 = j11 * dv * j21 + j12 * sv * j22;
                let q = Matrix2::new(
                    j11 * dv * j11 + j12 * sv * j12,
                    q12,
                    q12,
                    j21 * dv * j21 + j22 * sv * j22,
                );
                (inc, q, (j12, j22))
            }
            FrontHeading::WheelDifference => {
                // As front_increment_differential.
                let inc = Increment {
                    distance_m,
                    dtheta_rad: (d_fr - d_fl) * (g_fl + g_fr) * self.k.inv_two_front_tread,
                };
                let g = (g_fl + g_fr) * self.k.inv_two_front_tread;
                let var_theta = k_f * (d_fl.abs() + d_fr.abs()) * g * g;
                let q = Matrix2::new(k_f * d_f.abs() * c * c, 0.0, 0.0, var_theta);
                (inc, q, (-d_f * s, inc.dtheta_rad * tan_phi))
            }
        }
    }

    /// One sample: prediction from the rear wheels, the front window
    /// integrated beside it, and a correction when the window is full.
    ///
    /// # Errors
    /// [`Error::NonFiniteInput`] for a NaN or infinite input,
    /// [`Error::SteeringOutOfRange`] for |φ| ≥ 90°, [`Error::Numerical`] if the
    /// result is not finite. On error `prev` stays the valid state.
    pub fn step(&self, prev: &State, input: &OdometryInput) -> Result<State> {
        let mut next = *prev;
        self.advance(&mut next, input)?;
        Ok(next)
    }

    /// [`Ekf::step`] writing the next state into `next` (which may hold
    /// anything: it is overwritten): the same result, bit for bit, with one
    /// copy of the state instead of the two or more that returning it by
    /// value costs. A caller that keeps two states and flips between them
    /// on success never copies a state back.
    ///
    /// # Errors
    /// As [`Ekf::step`]; `prev` is untouched and `next` holds garbage then.
    pub fn step_into(&self, prev: &State, next: &mut State, input: &OdometryInput) -> Result<()> {
        *next = *prev;
        self.advance(next, input)
    }

    /// Gives the wheels' learner the sample's raw wheels, and what the gyro
    /// says of the rear pair.
    #[inline]
    fn teach_scales(&self, st: &mut State, input: &OdometryInput, phi: f64) {
        // Only what the wheels read themselves, while both axles move as
        // a car can.
        let clean = input.front_valid && st.axle_watch.calm();
        st.scales.set_gyro_rear_ratio(gyro_rear_ratio(st));
        st.scales
            .accumulate(&self.k.geometry, &input.wheel_m, phi, input.dt_s, clean);
    }

    /// The body of [`Ekf::step`], on a copy of the previous state.
    #[inline]
    fn advance(&self, st: &mut State, input: &OdometryInput) -> Result<()> {
        st.last_window = WindowOutcome::Open;
        check_input(input)?;
        let phi = input.steer_angle_rad;
        let yaw_aided = st.aided_on || input.yaw_rate_radps.is_some_and(f64::is_finite);
        let scaled = self.scaled_wheels(st, input);
        // The wheels as read, with the scales learnt for them: what the
        // floor fill and a slide's bridge below change is the geometry's.
        let read = scaled.as_ref().unwrap_or(&input.wheel_m);
        let filled;
        let w = if input.zero_is_floor {
            filled = self.fill_floor(st, read, phi, input.front_valid, input.dt_s);
            &filled
        } else {
            read
        };
        st.axle_watch.watch(input, w, self.cfg.max_accel_mps2);
        if self.cfg.learn_wheel_scales {
            self.teach_scales(st, input, phi);
        }
        // Every wheel locked while the car slides on: the distance the
        // wheels cannot read is bridged (wheel-speed sensors, four wheels).
        let bridged = (input.zero_is_floor && input.front_valid)
            .then(|| {
                let (calm, spinning) = (st.axle_watch.calm(), st.axle_watch.spinning());
                st.slide
                    .step(&self.cfg, w, input.dt_s, MAX_FLOOR_FILL_MPS, calm, spinning)
            })
            .flatten();
        let (w, slide_var_m2) = bridged
            .as_ref()
            .map_or((w, 0.0), |b| (&b.wheel_m, b.var_m2));
        let launch_var_m2 = launch_variance(st, input, w) + slide_var_m2;
        // Until the aided estimator shows the wheels off, they carry the pose.
        if yaw_aided && self.aided_advance(st, input, read, w, phi, launch_var_m2)? {
            return Ok(());
        }
        // As odometry::rear_increment, with 1/b precomputed (inputs checked above).
        let rear = Increment {
            distance_m: 0.5 * (w.rear_right + w.rear_left),
            dtheta_rad: (w.rear_right - w.rear_left) * self.k.inv_rear_tread,
        };
        let q = self.q_rear(w.rear_left, w.rear_right);
        let (sin_m, cos_m);
        ((sin_m, cos_m), st.rear_cs) = advance_heading(st.rear_cs, rear.dtheta_rad);
        (st.rear_w, st.p_rear_w) = propagate_with(&st.rear_w, &st.p_rear_w, rear, &q, sin_m, cos_m);
        if launch_var_m2 > 0.0 {
            let (c, s) = st.rear_cs;
            st.p_rear_w[(0, 0)] += launch_var_m2 * c * c;
            st.p_rear_w[(0, 1)] += launch_var_m2 * c * s;
            st.p_rear_w[(1, 0)] += launch_var_m2 * c * s;
            st.p_rear_w[(1, 1)] += launch_var_m2 * s * s;
        }
        let angle_rad = phi - st.steer_offset_rad;
        if st.steer_terms.angle_bits != angle_rad.to_bits() {
            st.steer_terms = SteerTerms::at(&self.k, angle_rad);
        }
        let terms = st.steer_terms;
        st.wheel_sum_m[0] += w.rear_left;
        st.wheel_sum_m[1] += w.rear_right;
        st.steer_turn_sum_m += rear.distance_m * terms.tan_phi;
        st.window_rear_m += rear.distance_m;
        if input.front_valid {
            let (d_fl, d_fr) = (
                w.front_left * st.front_scale,
                w.front_right * st.front_scale,
            );
            let (front, qf, j) = self.front(d_fl, d_fr, &terms);
            st.window_front_m += front.distance_m;
            let ((sin_m, cos_m), cs) = advance_heading(st.front_cs, front.dtheta_rad);
            st.front_cs = cs;
            st.front_bias_sens = propagate_sensitivity(&st.front_bias_sens, front, j, sin_m, cos_m);
            (st.front_w, st.p_front_w) =
                propagate_with(&st.front_w, &st.p_front_w, front, &qf, sin_m, cos_m);
            if matches!(self.cfg.form, CorrectionForm::Literal { .. }) {
                let z = &st.front_alone;
                let (sz, cz) = (z.z + 0.5 * front.dtheta_rad).sin_cos();
                st.front_alone = Vec3::new(
                    z.x + front.distance_m * cz,
                    z.y + front.distance_m * sz,
                    z.z + front.dtheta_rad,
                );
            }
            st.wheel_sum_m[2] += d_fl;
            st.wheel_sum_m[3] += d_fr;
        } else {
            st.window_front_ok = false;
        }
        st.window_len += 1;
        if st.window_len >= self.cfg.correct_every {
            self.close_window(st)?;
        }
        // A NaN or infinity anywhere makes the sum non-finite: one check, not nine.
        if !(st.anchor.sum()
            + st.rear_w.sum()
            + st.p_rear_w.sum()
            + st.front_w.sum()
            + st.p_front_w.sum())
        .is_finite()
        {
            return Err(Error::Numerical {
                context: "EKF step",
            });
        }
        Ok(())
    }

    /// The readings corrected by the applied wheel scales (those applied
    /// when the aided estimator took the lead, once it has: it learnt the
    /// rear ratio against the gyro on them); `None` where nothing is to
    /// correct.
    #[inline]
    fn scaled_wheels(&self, st: &State, input: &OdometryInput) -> Option<WheelSet<f64>> {
        let c = if st.lead.leads {
            st.lead.factor
        } else {
            st.applied_factor
        };
        if !self.cfg.learn_wheel_scales || c == [1.0; 4] {
            return None;
        }
        let r = &input.wheel_m;
        Some(WheelSet {
            rear_left: r.rear_left * c[0],
            rear_right: r.rear_right * c[1],
            front_left: r.front_left * c[2],
            front_right: r.front_right * c[3],
        })
    }

    /// A step of the yaw-rate-aided estimator ([`aided`]), which starts at
    /// the wheels-only filter's pose at the first yaw-rate sample and runs
    /// beside it; true when it carries the pose (the wheels-only step is
    /// then not taken).
    fn aided_advance(
        &self,
        st: &mut State,
        input: &OdometryInput,
        read: &WheelSet<f64>,
        w: &WheelSet<f64>,
        phi: f64,
        launch_var_m2: f64,
    ) -> Result<bool> {
        if !st.aided_on {
            let pose = st.pose_unwrapped();
            let c = st.covariance();
            let mut a = Aided::new(&self.cfg);
            if let Some(y) = st.pending_yaw.take() {
                a.restore(&y);
            }
            let mut p_pose = [[0.0; 3]; 3];
            for (i, row) in p_pose.iter_mut().enumerate() {
                for (j, v) in row.iter_mut().enumerate() {
                    *v = c[(i, j)];
                }
            }
            a.set_pose([pose.x_m, pose.y_m, pose.heading_rad], p_pose);
            st.aided = a;
            st.aided_on = true;
        }
        if !st.lead.leads && st.applied_factor != st.lead.factor {
            // The wheels' learning rescaled a rear wheel: the aided
            // estimator's rear ratio refers to the wheels as read now. A
            // new decision (a wheel found off) starts it afresh: what it
            // learnt on the wheels as they were read is not worth keeping
            // (a Toyota gyro's had the RL tyre's +0.30 % as +0.21 ± 0.014 %,
            // and shifted by the learner's −0.30 % it showed a ratio off
            // that the corrected wheels no longer have).
            let [rl, rr, _, _] = st.applied_factor;
            let [rl0, rr0, _, _] = st.lead.factor;
            let delta = -((rr - rr0) - (rl - rl0));
            if delta.abs() >= RATIO_DECISION {
                st.aided
                    .set_learnt(Learnable::Ratio, 0.0, self.cfg.rear_ratio_sigma);
                st.lead.distance_m = 0.0;
            } else {
                st.aided.shift_ratio(delta);
            }
            st.lead.factor = st.applied_factor;
        }
        let rear_m = 0.5 * (w.rear_left + w.rear_right).abs();
        st.lead.distance_m += rear_m;
        st.lead.total_m += rear_m;
        // A rear wheel that slipped or locked (the aided estimator's test,
        // with the gyro's turn) is a drive whose wheels cannot carry the
        // heading through it: the gyro takes over at once.
        if !st.lead.leads
            && (st.stats.yaw_over_rear > 0
                || st.aided.gyro_known()
                || st.lead.distance_m >= AIDED_LEAD_MIN_DISTANCE_M && st.aided.shows_ratio_off()
                || st.lead.total_m >= AIDED_LEAD_MIN_DISTANCE_M && st.aided.shows_tread_off())
        {
            // The aided estimator has run beside the wheels from the first
            // yaw-rate sample: the pose moves once, to where it has brought
            // the car (as the wheels' learning moves it when it decides),
            // and follows it from then on.
            st.lead.leads = true;
            st.lead.factor = st.applied_factor;
        }
        let angle_rad = phi - st.steer_offset_rad;
        if st.steer_terms.angle_bits != angle_rad.to_bits() {
            st.steer_terms = SteerTerms::at(&self.k, angle_rad);
        }
        let terms = st.steer_terms;
        aided::step(
            &self.cfg,
            &self.k,
            st,
            input,
            read,
            w,
            terms.g[2] + terms.g[3],
            terms.tan_phi,
            launch_var_m2,
        );
        if !st.aided.is_finite() {
            return Err(Error::Numerical {
                context: "yaw-rate-aided step",
            });
        }
        Ok(st.lead.leads)
    }

    /// `w` with each wheel that reads exactly 0 beside a wheel that moves
    /// replaced by the median implied centre distance of the moving wheels
    /// times its own distance factor `g_i` (the sensor-floor fill of
    /// [`OdometryInput::zero_is_floor`]); `w` itself when no wheel is at the
    /// floor or the moving wheels do not agree on a direction.
    #[cold]
    fn floor_filled(
        &self,
        st: &mut State,
        w: &WheelSet<f64>,
        phi: f64,
        wheels: usize,
    ) -> WheelSet<f64> {
        let angle_rad = phi - st.steer_offset_rad;
        if st.steer_terms.angle_bits != angle_rad.to_bits() {
            st.steer_terms = SteerTerms::at(&self.k, angle_rad);
        }
        let g = st.steer_terms.g;
        let d = [w.rear_left, w.rear_right, w.front_left, w.front_right];
        let mut centre = [0.0; 4];
        let mut n = 0;
        for k in 0..wheels {
            if d[k] != 0.0 && g[k] != 0.0 {
                centre[n] = d[k] / g[k];
                n += 1;
            }
        }
        let moving = &mut centre[..n];
        if n == 0
            || n == wheels
            || !(moving.iter().all(|c| *c > 0.0) || moving.iter().all(|c| *c < 0.0))
        {
            return *w;
        }
        moving.sort_by(f64::total_cmp);
        let c = if n % 2 == 1 {
            moving[n / 2]
        } else {
            0.5 * (moving[n / 2 - 1] + moving[n / 2])
        };
        let fill = |k: usize| {
            if d[k] == 0.0 && k < wheels {
                c * g[k]
            } else {
                d[k]
            }
        };
        WheelSet {
            rear_left: fill(0),
            rear_right: fill(1),
            front_left: fill(2),
            front_right: fill(3),
        }
    }

    /// [`Ekf::floor_filled`] in the common case's fast path: no wheel reads
    /// exactly 0 while another moves, so nothing to fill.
    #[inline]
    fn fill_floor(
        &self,
        st: &mut State,
        w: &WheelSet<f64>,
        phi: f64,
        front_valid: bool,
        dt_s: f64,
    ) -> WheelSet<f64> {
        // A stale front's distances say nothing: only the rear pair then.
        let wheels = if front_valid { 4 } else { 2 };
        // A wheel at 0 beside wheels faster than the sensors' floor is a
        // locked wheel, not one below its floor: filled from the others it
        // turned a braking car by 14° in three samples (multi-body model,
        // BMW 320i, rear wheels locking at 1 m/s).
        let fastest = [w.rear_left, w.rear_right, w.front_left, w.front_right][..wheels]
            .iter()
            .fold(0.0f64, |m, d| m.max(d.abs()));
        // Without a time step (unknown) the zero is taken as the floor, as before.
        if dt_s > 0.0 && fastest > MAX_FLOOR_FILL_MPS * dt_s {
            return *w;
        }
        let zeros = usize::from(w.rear_left == 0.0)
            + usize::from(w.rear_right == 0.0)
            + if front_valid {
                usize::from(w.front_left == 0.0) + usize::from(w.front_right == 0.0)
            } else {
                0
            };
        if zeros == 0 || zeros == wheels {
            *w
        } else {
            self.floor_filled(st, w, phi, wheels)
        }
    }

    /// Fuses the window (per the form), composes it onto the anchor, resets it.
    fn close_window(&self, st: &mut State) -> Result<()> {
        st.slip_flags = WheelSet::splat(false);
        let turn_rad = match self.cfg.form {
            // The literal correction composes the anchor itself.
            CorrectionForm::Literal { r_diag } if st.window_front_ok => {
                st.stats.corrections += 1;
                self.correct_literal(st, r_diag)?
            }
            form => {
                let (w, p_w) = if matches!(form, CorrectionForm::RearOnly) {
                    st.last_window = WindowOutcome::RearOnly;
                    (st.rear_w, st.p_rear_w)
                } else if !st.window_front_ok {
                    st.stats.skipped_no_front += 1;
                    st.last_window = WindowOutcome::NoFront;
                    (st.rear_w, st.p_rear_w)
                } else {
                    st.stats.corrections += 1;
                    self.correct_anchored(st)?
                };
                let new_anchor = compose(&st.anchor, st.anchor_cos_sin, &w);
                st.p_anchor = compose_covariance(&st.p_anchor, st.anchor_cos_sin, &w, &p_w);
                st.anchor_heading_unwrapped_rad += w.z;
                if self.cfg.learn_wheel_scales {
                    let rear_kept = st.last_window != WindowOutcome::RejectedUsedFront;
                    let moved = [new_anchor.x - st.anchor.x, new_anchor.y - st.anchor.y];
                    add_rear_moments(st, moved, rear_kept.then_some((st.window_rear_m, w.z)));
                }
                st.anchor = new_anchor;
                w.z
            }
        };
        st.anchor_cos_sin = turned_cos_sin(st.anchor_cos_sin, turn_rad, st.anchor.z);
        if self.cfg.learn_wheel_scales {
            reapply_rear_pair(st, self.k.inv_rear_tread);
        }
        st.rear_w = Vec3::zeros();
        st.p_rear_w = Mat3::zeros();
        st.front_w = Vec3::zeros();
        st.p_front_w = Mat3::zeros();
        st.front_bias_sens = Vec3::zeros();
        st.rear_cs = (1.0, 0.0);
        st.front_cs = (1.0, 0.0);
        st.wheel_sum_m = [0.0; 4];
        st.axle_watch.new_window();
        st.steer_turn_sum_m = 0.0;
        st.window_rear_m = 0.0;
        st.window_front_m = 0.0;
        st.window_len = 0;
        st.window_front_ok = true;
        // A NaN or infinity anywhere makes the sum non-finite: one check, not twelve.
        if !(st.anchor.sum() + st.p_anchor.sum()).is_finite() {
            return Err(Error::Numerical {
                context: "EKF correction",
            });
        }
        Ok(())
    }

    /// The anchored correction; returns the fused window increment and covariance.
    #[allow(clippy::too_many_lines)]
    fn correct_anchored(&self, st: &mut State) -> Result<(Vec3, Mat3)> {
        let mut nu = st.front_w - st.rear_w;
        nu.z = wrap_angle(nu.z);
        // A tiny floor keeps S invertible when the car stood still all window.
        let v = st.front_bias_sens;
        // P_front + σ_b² v vᵀ and S, entry by entry on the upper triangle
        // (nalgebra's operators form all nine entries of each term).
        let u = v * self.k.steer_bias_var;
        let (pf, pr) = (&st.p_front_w, &st.p_rear_w);
        let pf_xy = pf[(0, 1)] + u.x * v.y;
        let pf_xz = pf[(0, 2)] + u.x * v.z;
        let pf_yz = pf[(1, 2)] + u.y * v.z;
        let (pf_xx, pf_yy, pf_zz) = (
            pf[(0, 0)] + u.x * v.x,
            pf[(1, 1)] + u.y * v.y,
            pf[(2, 2)] + u.z * v.z,
        );
        // The front scale's rank-one term, σ_s² w_f w_fᵀ.
        let vs = st.front_w;
        let us = vs * self.k.front_scale_var;
        let (pf_xy, pf_xz, pf_yz) = (
            pf_xy + us.x * vs.y,
            pf_xz + us.x * vs.z,
            pf_yz + us.y * vs.z,
        );
        let (pf_xx, pf_yy, pf_zz) = (
            pf_xx + us.x * vs.x,
            pf_yy + us.y * vs.y,
            pf_zz + us.z * vs.z,
        );
        let p_front = symmetric(pf_xx, pf_xy, pf_xz, pf_yy, pf_yz, pf_zz);
        let S = symmetric(
            pr[(0, 0)] + pf_xx + 1e-15,
            pr[(0, 1)] + pf_xy,
            pr[(0, 2)] + pf_xz,
            pr[(1, 1)] + pf_yy + 1e-15,
            pr[(1, 2)] + pf_yz,
            pr[(2, 2)] + pf_zz + 1e-15,
        );
        let S_inv = symmetric_inverse(&S).ok_or(Error::Numerical {
            context: "innovation covariance",
        })?;
        let d2 = nu.dot(&(S_inv * nu));
        st.last_mahalanobis_sq = if d2.is_finite() { d2 } else { 0.0 };
        let beyond_gate = self
            .cfg
            .gate_threshold
            .is_some_and(|threshold| d2 > threshold);
        // The consensus's verdict: the wheel farthest from the others, and
        // whether it is a slip (min_slip_ratio off) rather than a model
        // mismatch the front carries too (tyres, a steering ratio off, the
        // yaw lagging the steering).
        let blamed = (beyond_gate && self.cfg.gate_action == GateAction::Consensus).then(|| {
            let centre = self.window_centres(st);
            let wheel = blamed_wheel(centre, st.axle_watch.window_suspect());
            (
                wheel,
                outlier_excess(centre, wheel) >= self.cfg.min_slip_ratio,
            )
        });
        let rejected = match blamed {
            Some((_, slipped)) => slipped,
            None => beyond_gate,
        };
        if rejected {
            let use_front = match self.cfg.gate_action {
                GateAction::UseFront => true,
                GateAction::KeepRear => false,
                GateAction::Consensus => {
                    let wheel = blamed.map_or(Wheel::FrontLeft, |(w, _)| w);
                    st.slip_flags[wheel] = true;
                    st.slip_counts[wheel] += 1;
                    wheel.is_rear()
                }
            };
            return Ok(if use_front {
                st.stats.rejected_used_front += 1;
                st.last_window = WindowOutcome::RejectedUsedFront;
                (self.front_pair_turn(st), p_front)
            } else {
                st.stats.rejected_kept_rear += 1;
                st.last_window = WindowOutcome::RejectedKeptRear;
                (st.rear_w, st.p_rear_w)
            });
        }
        st.stats.accepted += 1;
        st.last_window = WindowOutcome::Accepted;
        if let Some(drift) = self.cfg.steer_offset_drift_rad
            && !beyond_gate
        {
            // ν_θ ≈ (b − b̂)·v_θ + noise, the noise being the windows' own
            // heading variances (without the bias term).
            let v_theta = v.z;
            let prior = if st.steer_offset_var > 0.0 {
                st.steer_offset_var
            } else {
                self.k.steer_bias_var
            } + drift * drift;
            let r = st.p_rear_w[(2, 2)] + st.p_front_w[(2, 2)] + 1e-15;
            let k = prior * v_theta / (v_theta * v_theta * prior + r);
            st.steer_offset_rad += k * nu.z;
            st.steer_offset_var = ((1.0 - k * v_theta) * prior).max(1e-18);
        }
        if let Some(drift) = self.cfg.front_scale_drift
            && st.window_rear_m.abs() > 1e-3
        {
            // z = front/rear − 1 ≈ ln(true front excess · scale), variance
            // from the wheels' noise over the window.
            let z = st.window_front_m / st.window_rear_m - 1.0;
            let r = (0.5 * self.cfg.k_rear_m + self.cfg.k_front_m) / st.window_rear_m.abs();
            let prior = if st.front_scale_var > 0.0 {
                st.front_scale_var
            } else {
                1e-4
            } + drift * drift;
            let k = prior / (prior + r);
            st.front_scale *= (-k * z).exp();
            st.front_scale_var = ((1.0 - k) * prior).max(1e-18);
        }
        if !self.cfg.blend_accepted {
            return Ok((st.rear_w, st.p_rear_w));
        }
        let K = st.p_rear_w * S_inv;
        let w = st.rear_w + K * nu;
        Ok((w, joseph(&K, &st.p_rear_w, &p_front)))
    }

    /// The front increment with its heading change from the front pair's
    /// distances, not the steering: a rear axle that slipped this window —
    /// locked under hard braking, most often — lets the car yaw on its own
    /// while the driver counter-steers, so the steering geometry turns the
    /// wrong way (on the multi-body BMW the steering said +0.44° where the car
    /// turned −0.76° in a quarter second; the front pair said −0.90°). The
    /// chord keeps its length and points half the turn.
    fn front_pair_turn(&self, st: &State) -> Vec3 {
        if !self.cfg.rejected_front_from_pair || st.axle_watch.slipped_in_window(Axle::Front) {
            return st.front_w;
        }
        let [rl, rr, fl, fr] = st.wheel_sum_m;
        // The pair's difference over the sum of its distance factors (exact
        // on an arc, as FrontHeading::WheelDifference), at the window's mean
        // steering: near 1 each at the small angles of a slip at speed.
        let d_rear = 0.5 * (rl + rr);
        let tan_phi = if d_rear.abs() > 1e-9 {
            st.steer_turn_sum_m / d_rear
        } else {
            0.0
        };
        let [_, _, g_fl, g_fr] = distance_factors(&self.k, tan_phi);
        let turn = (fr - fl) * (g_fl + g_fr) * self.k.inv_two_front_tread;
        let chord = st.front_w.x.hypot(st.front_w.y).copysign(st.front_w.x);
        let (s, c) = (0.5 * turn).sin_cos();
        Vec3::new(chord * c, chord * s, turn)
    }

    /// Each wheel's implied centre distance over the window (in
    /// [`WHEEL_ORDER`]), through the distance factors at the window's
    /// curvature: the median of the rear pair's, the front pair's and the
    /// steering's. A slipping wheel throws its own pair's curvature off, and
    /// a steering that leads the yaw (tyre dynamics), is offset or has its
    /// ratio wrong throws the steering's off, but never two of the three:
    /// with the steering's alone a rear wheel looked 8 % off in every
    /// turn-in of a 15 m circle at 8 m/s with 0.4 s of yaw lag.
    fn window_centres(&self, st: &State) -> [f64; 4] {
        let [rl, rr, fl, fr] = st.wheel_sum_m;
        let p = &self.cfg.params;
        let curvature = |difference: f64, tread_m: f64, distance: f64| {
            if distance.abs() > 1e-9 {
                difference / (tread_m * distance)
            } else {
                0.0
            }
        };
        let d_rear = 0.5 * (rl + rr);
        let kappa_rear = curvature(rr - rl, p.rear_tread_m(), d_rear);
        let kappa_front = curvature(fr - fl, p.front_tread_m(), 0.5 * (fl + fr));
        let kappa_steer = if d_rear.abs() > 1e-9 {
            st.steer_turn_sum_m * self.k.inv_wheelbase / d_rear
        } else {
            0.0
        };
        let mut k3 = [kappa_rear, kappa_front, kappa_steer];
        k3.sort_by(f64::total_cmp);
        let g = distance_factors(&self.k, k3[1] * p.wheelbase_m());
        let implied = |d: f64, g: f64| if g.abs() > 1e-9 { d / g } else { d };
        [
            implied(rl, g[0]),
            implied(rr, g[1]),
            implied(fl, g[2]),
            implied(fr, g[3]),
        ]
    }

    /// The paper's literal correction with `z` the front odometry alone; moves
    /// the anchor and returns its heading change.
    fn correct_literal(&self, st: &mut State, r_diag: [f64; 3]) -> Result<f64> {
        let x_prior = compose(&st.anchor, st.anchor_cos_sin, &st.rear_w);
        let p_prior = compose_covariance(&st.p_anchor, st.anchor_cos_sin, &st.rear_w, &st.p_rear_w);
        let prior_unwrapped = st.anchor_heading_unwrapped_rad + st.rear_w.z;
        let mut nu = st.front_alone - x_prior;
        nu.z = wrap_angle(st.front_alone.z - prior_unwrapped);
        let R = Mat3::from_diagonal(&Vec3::new(r_diag[0], r_diag[1], r_diag[2]));
        let S = p_prior + R;
        let S_inv = symmetric_inverse(&S).ok_or(Error::Numerical {
            context: "innovation covariance",
        })?;
        let d2 = (nu.transpose() * S_inv * nu)[(0, 0)];
        st.last_mahalanobis_sq = if d2.is_finite() { d2 } else { 0.0 };
        let (x, p, turn) = if self.cfg.gate_threshold.is_some_and(|t| d2 > t) {
            // Rejected: the literal z is a whole trajectory, not a window, so
            // the only sound action is to keep the prediction.
            st.stats.rejected_kept_rear += 1;
            st.last_window = WindowOutcome::RejectedKeptRear;
            (x_prior, p_prior, st.rear_w.z)
        } else {
            st.stats.accepted += 1;
            st.last_window = WindowOutcome::Accepted;
            let K = p_prior * S_inv;
            let dx = K * nu;
            let x = Vec3::new(
                x_prior.x + dx.x,
                x_prior.y + dx.y,
                wrap_angle(x_prior.z + dx.z),
            );
            (x, joseph(&K, &p_prior, &R), st.rear_w.z + dx.z)
        };
        st.anchor = x;
        st.p_anchor = p;
        st.anchor_heading_unwrapped_rad += turn;
        Ok(turn)
    }
}

#[cfg(test)]
mod tests;
