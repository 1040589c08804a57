//! The filter's settings ([`EkfConfig`]) and their validation: every
//! choice a user may change under `[ekf]`, with its unit and default.

use super::CHI2_3_99;
use crate::error::{Error, Result, require_non_negative, require_positive};
use crate::params::VehicleParams;

/// How the front odometry corrects the rear prediction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CorrectionForm {
    /// No correction: rear odometry with a propagated covariance.
    RearOnly,
    /// The paper's literal filter: `z` = front odometry pose integrated on its
    /// own from the start, `H = I`, measurement covariance `R = diag(r)`
    /// (m², m², rad²). Its error is a random walk, not white, so `R` acts as a
    /// blending knob.
    Literal {
        /// The diagonal of `R`.
        r_diag: [f64; 3],
    },
    /// Front increment over the window against the rear one (default).
    Anchored,
}

/// Where the front odometry's heading change comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrontHeading {
    /// `Δθ = Δd_r tan φ / L` from the steering angle (eqs. 21–26).
    Steering,
    /// `Δθ` from the front wheels' difference; φ enters only through cos φ
    /// (§12), which removes a steering bias but doubles the slip exposure.
    WheelDifference,
}

/// What to do when the gate rejects a correction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GateAction {
    /// Decide by the four wheels' implied centre distances (§11).
    Consensus,
    /// Always take the front increment (right for rear slips only).
    UseFront,
    /// Always keep the rear prediction.
    KeepRear,
}

/// The filter's configuration. Build with [`EkfConfig::new`] (the default
/// chosen from evidence, see the crate's `tests/experiments.rs`) and adjust.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EkfConfig {
    /// The vehicle parameters in use (nominal or calibrated), not the truth.
    pub params: VehicleParams,
    /// The correction form.
    pub form: CorrectionForm,
    /// Rear wheel distance noise: variance `k_r·|d|` per wheel, metres.
    pub k_rear_m: f64,
    /// Front wheel distance noise: variance `k_f·|Δd_f|`, metres.
    pub k_front_m: f64,
    /// Standard deviation of the steering angle's white (per-sample) error.
    pub steer_sigma_rad: f64,
    /// Standard deviation of a steering error that holds over a whole window
    /// (a bias or slow drift, as real sensors have, §12). Its effect on the
    /// front window is propagated exactly as a sensitivity vector, so the
    /// window's heading is trusted as little as a bias deserves. 0 = off.
    pub steer_bias_sigma_rad: f64,
    /// Relative standard deviation of the front axle's distance scale, held
    /// over a window. Front tyres differ from the rear ones in size, and on
    /// a real car the front wheels read the body's motion through slip
    /// angles the kinematic model does not have (0.3–0.6 % short in a
    /// tight circle at 4–6 m/s² with a sideslipping rear axle). Scaling
    /// every front distance scales the whole front window pose, so its
    /// sensitivity is the window itself: `σ_s² w_f w_fᵀ` joins the front
    /// covariance. Without it a distance mismatch in a curve leaks into the
    /// heading through the window's geometry. 0 = off.
    pub front_scale_sigma: f64,
    /// The yaw-rate sensor's white noise per sample, rad/s (quantisation
    /// included): the weight of its heading against the rear wheels'.
    pub yaw_sigma_radps: f64,
    /// Random walk of the yaw-rate sensor's bias, rad/s per √s: how fast
    /// the learnt bias may follow a drift (temperature).
    pub yaw_bias_walk_radps: f64,
    /// Prior standard deviation of the yaw-rate bias when nothing was learnt
    /// or calibrated, rad/s.
    pub yaw_bias_sigma_radps: f64,
    /// Prior standard deviation of the rear diameter ratio's relative error
    /// (the rear wheels' heading is off by `e·d/b` per step), learnt with
    /// the yaw-rate bias when the speed varies or the car stands.
    pub rear_ratio_sigma: f64,
    /// Prior standard deviation of the yaw-rate sensor's scale error
    /// (relative). Considered, not learnt: against the wheels it cannot be
    /// told from the effective tread; it widens the heading's σ by the
    /// share of every turn it could be.
    pub yaw_scale_sigma: f64,
    /// Prior standard deviation of the effective rear tread's relative
    /// error: load transfer and drive torque make the wheels' turn a few per
    /// cent more or less than the body's. Learnt against the gyro in turns.
    pub tread_sigma: f64,
    /// Share of a window's turn the wheels may miss beyond the learnt
    /// effective tread (the tread changes with the lateral load within a
    /// curve): the comparison's model error. The prior of that share: the
    /// drive's turning windows bring it down to what they show (not below
    /// 0.2 %), so wheels that turn as the body does are weighed as such.
    pub tread_turn_sigma: f64,
    /// Standard deviation of the wheels' turn over one window from the
    /// wheel-speed quantum, rad. 5e-5: two wheels rounded to 0.01 km/h at
    /// 100 Hz over a 0.5 s window whose speed dithers the rounding
    /// (`q·dt·√(n/6)/b`). It was 5e-4 (the rounding held for the whole
    /// window), which left the gyro's noise and bias to carry the heading
    /// between straights: on opendbc drives with exact wheels and a gyro
    /// of 0.1°/s noise the fused pose ended 0.13–0.68 % off where the
    /// wheels alone ended 0.002–0.07 %; now 0.015–0.07 % (the multi-body
    /// drives with the gyro and the real RAV4 within 0.01 % of before).
    pub wheel_turn_sigma_rad: f64,
    /// Share of a window's distance by which the rear wheels' turn may be
    /// off beyond the learnt diameter ratio (unequal drive slip, a bump),
    /// per unit of `d/b_t`.
    pub ratio_walk: f64,
    /// Prior standard deviation of the wheels' distance scale (relative):
    /// nothing on board tells it (position fixes do), so it only keeps the
    /// position's σ honest. 1 %: a tyre's rolling diameter is off its data
    /// sheet's by that much (the real RAV4's wheels read 0.92 % short; at
    /// 0.5 % only 25 % of its uncalibrated minute lay inside 3σ, NEES mean
    /// 11; at 1 %, 100 % and 2.8).
    pub distance_scale_sigma: f64,
    /// Seconds every wheel must read 0 before the car counts as standing
    /// and its yaw rate as the gyro's bias: shorter, a crawl below the
    /// wheel-speed sensors' floor (about 2 km/h) could teach a turn as bias.
    pub still_min_s: f64,
    /// Length of the window over which the wheels' turn is compared with
    /// the gyro's, s.
    pub aided_window_s: f64,
    /// Relative difference between the rear wheels' longitudinal slips per
    /// m/s² of acceleration, per unit of `d/b_t`: drive and brake torque
    /// make the less loaded inner wheel slip more in a curve, which the
    /// wheels' turn then misses (2 % of the turn of an accelerating rear-
    /// driven car in a bend on the multi-body model).
    pub slip_accel_sigma: f64,
    /// How far a straight road's yaw rate strays from 0 over one window
    /// (lane keeping), rad/s: the weight of "the car drives straight" as a
    /// measurement of the gyro's bias. 0 = never assumed.
    pub straight_yaw_sigma_radps: f64,
    /// The largest rate of the wheels' turn, rad/s, and steering angle,
    /// rad, at which the car counts as driving straight. The prior says 0
    /// within `straight_yaw_sigma_radps`, so a gentle bend let through here
    /// is a wrong measurement of the bias. Lower is not safer: the wheels'
    /// rate over a window is noisy, so fewer straights are found — at
    /// 0.2°/s the real RAV4's rest after a calibration on its first 30 s
    /// ended 0.69 % off instead of 0.08 %, at 0.15°/s 4.4 %, and at
    /// 0.10°/s one multi-body drive 1.6 % instead of 0.2 %. The wheels'
    /// rate is taken less their learnt diameter ratio, and the threshold
    /// widened by twice that ratio's σ (`2 σ_e v / b_t`): before the drive
    /// has told the ratio, a straight whose rear tyres roll unequally reads
    /// as a turn (−0.35°/s on the multi-body BMW, seed 105, which then
    /// learnt its bias only after 36 s and ended 0.85 % off; 0.65 % now).
    pub straight_max_radps: f64,
    /// See [`EkfConfig::straight_max_radps`].
    pub straight_max_steer_rad: f64,
    /// The least speed, m/s, at which a straight counts. A road's gentle
    /// curve turns a slow car below any usable rate threshold (the
    /// multi-body Escort, seed 3, braking to a stop in a 1.75 km-radius
    /// curve: −0.06°/s at 2 m/s, read as the gyro's bias, 0.95 % off at the
    /// end; 0.27 % with 5 m/s), while the prior buys little there: the
    /// ratio error it separates from the bias turns the wheels by `e v /
    /// b_t`, small at low speed. Default: two wheelbases a second (5 m/s
    /// for a road car, 0.5 m/s for a 1:10 one); 0 = straights at any speed.
    pub straight_min_speed_mps: f64,
    /// Seconds of straight driving before it counts.
    pub straight_min_s: f64,
    /// The yaw-rate signal's step (its DBC factor), rad/s; 0 when unknown.
    /// A standing car's or a straight's readings repeat one rounded value
    /// whose error no average removes unless noise dithers it: the aided
    /// estimator carries that offset as a state whose prior is bounded by
    /// `q/π` (less as noise dithers the steps).
    pub yaw_quantum_radps: f64,
    /// The fastest a car's speed changes on its tyres, m/s² (default 12,
    /// 1.2 g: a road car's hardest braking on dry asphalt is 1.0–1.1 g). A
    /// wheel-speed sensor whose wheel falls faster is not rolling with the
    /// car: three or four such wheels are a slide on locked wheels, and the
    /// gyro filter's axle reference follows the wheels no faster than this.
    pub max_accel_mps2: f64,
    /// The deceleration of a car sliding on locked wheels, m/s² (default
    /// 7.5: locked tyres on dry asphalt slide at 0.7–0.8 g; the multi-body
    /// Escort slid at 8.0). The slide is bridged with it until the wheels
    /// roll again, and then corrected to the speed they roll at; it alone
    /// decides a slide that ends at a standstill.
    pub slide_decel_mps2: f64,
    /// The σ of [`EkfConfig::slide_decel_mps2`], m/s² (default 2.5, which
    /// covers a wet road's 0.4 g): the along-track variance `(σ t²/2)²` a
    /// slide of `t` seconds adds.
    pub slide_decel_sigma_mps2: f64,
    /// A window whose wheels disagree with the gyro by more than this many
    /// standard deviations is not used (a slip the wheel test missed, a bump).
    pub yaw_gate_sigma: f64,
    /// The least relative excess of the blamed rear wheel's implied centre
    /// distance over the other three's median for the front to replace the
    /// window: below it the rejection keeps the rear. A real slip moves a
    /// wheel by tens of per cent; a model mismatch (understeer, a steering
    /// ratio off) splits the wheels by one or two, and the front, which
    /// carries that mismatch in full, would do more harm than the rear.
    pub min_slip_ratio: f64,
    /// Blend the front into windows the gate accepts (the Kalman update);
    /// when false an accepted window keeps the rear increment, and the front
    /// acts only through the gate, against slips.
    pub blend_accepted: bool,
    /// A correction every this many samples (50 = 0.5 s at 100 Hz).
    pub correct_every: u32,
    /// The χ² gate threshold on `d²`; `None` disables the gate.
    pub gate_threshold: Option<f64>,
    /// What a rejection does.
    pub gate_action: GateAction,
    /// Where the front heading comes from.
    pub front_heading: FrontHeading,
    /// A window whose rear axle the gate rejected takes its heading change
    /// from the front pair's distances instead of the steering (a locked
    /// rear axle lets the car yaw while the driver counter-steers).
    pub rejected_front_from_pair: bool,
    /// Learn the steering sensor's offset online (`None`: off): a scalar
    /// Kalman filter on the offset, fed by each accepted window's heading
    /// innovation, whose random walk has this standard deviation per window.
    /// The rear wheels make the offset observable whenever the car turns or
    /// drives straight (§12: production systems learn it online).
    pub steer_offset_drift_rad: Option<f64>,
    /// Learn the front axle's distance scale relative to the rear online
    /// (`None`: off): a scalar Kalman filter on `ln(scale)`, fed by each
    /// accepted window's front/rear distance ratio, whose random walk has
    /// this standard deviation per window. Front tyres are not calibrated by
    /// the track method, and a front/rear scale mismatch otherwise leaks into
    /// the heading through the rear wheels' correlated noise. Off by default:
    /// it turns a 0.3 % front tyre mismatch from 0.9–2.5 % of a 660 m drive
    /// into 0.1–0.5 %, but with matched tyres it learns quantisation noise and
    /// costs margin on §12 (0.12 % against 0.04 %; `tests/experiments.rs`).
    pub front_scale_drift: Option<f64>,
    /// Learn each wheel's scale from the other sensors and correct the
    /// readings by it where the wheels carry the heading (no yaw-rate
    /// sensor): see [`super::scales`]. One rear tyre 0.3 % large otherwise
    /// turns a car without a gyro by `0.003/b` per metre.
    pub learn_wheel_scales: bool,
}

/// The default least speed of a straight, in wheelbases per second
/// ([`EkfConfig::straight_min_speed_mps`]): 5 m/s on a road car's 2.5 m.
const STRAIGHT_MIN_WHEELBASES_PER_S: f64 = 2.0;

impl EkfConfig {
    /// The default configuration: anchored increments every 50 samples,
    /// k_r = k_f = 1e-5 m, steering error 0.5° white plus a 5° bias held over
    /// each window, a 1 % front distance scale held over each window, the
    /// steering offset learnt online (random walk 0.005° per window),
    /// consensus gate at χ²₃(0.99) = 11.34, front heading from the steering
    /// angle, and windows the gate accepts keep the rear increment
    /// (`blend_accepted = false`): the front acts against slips only.
    ///
    /// Why not blend agreeing windows (see "Robustness" in the module docs):
    /// on 200 random drives of full-size cars with tyre slip angles, the
    /// blended filter ended 0.4–19 % of the distance off where rear-only
    /// odometry was within 0.15 %; the kinematic front model is wrong by a
    /// few tenths of a per cent in every curve of a real car, and no blend
    /// weight made that up. Kept from the blend: the gate's verdict and the
    /// front increment for a window whose rear wheel slipped.
    ///
    /// Chosen from evidence (`tests/experiments.rs`, `tests/robustness.rs`):
    /// §11's slip experiment −97 % mean squared end error against rear-only,
    /// §12's full-size car ≤ 0.04 % of 660 m, 200 random full-size drives
    /// never worse than rear-only and 0 false alarms, the 1:10 car with slips
    /// at 0.01 × rear-only. The steering terms matter in the windows the
    /// front is used for: modelled as a window bias, the front heading's
    /// weight falls with the square of the window's length, and the learnt
    /// offset removes what a bias would still leak there. The front heading
    /// does not come from the front wheels' difference: a front tyre 0.3 %
    /// larger than the other turns that into 20 % errors.
    pub fn new(params: VehicleParams) -> Self {
        Self {
            params,
            form: CorrectionForm::Anchored,
            k_rear_m: 1e-5,
            k_front_m: 1e-5,
            steer_sigma_rad: 0.5f64.to_radians(),
            steer_bias_sigma_rad: 5f64.to_radians(),
            front_scale_sigma: 0.01,
            yaw_sigma_radps: 0.003,
            yaw_bias_walk_radps: 2e-5,
            yaw_bias_sigma_radps: 0.5f64.to_radians(),
            rear_ratio_sigma: 5e-3,
            yaw_scale_sigma: 0.005,
            tread_sigma: 0.05,
            tread_turn_sigma: 0.1,
            wheel_turn_sigma_rad: 5e-5,
            ratio_walk: 2e-4,
            distance_scale_sigma: 0.01,
            still_min_s: 2.0,
            aided_window_s: 0.5,
            yaw_gate_sigma: 5.0,
            yaw_quantum_radps: 0.0,
            max_accel_mps2: 12.0,
            slide_decel_mps2: 7.5,
            slide_decel_sigma_mps2: 2.5,
            slip_accel_sigma: 1e-3,
            straight_yaw_sigma_radps: 0.025f64.to_radians(),
            straight_max_radps: 0.3f64.to_radians(),
            straight_max_steer_rad: 1f64.to_radians(),
            straight_min_speed_mps: STRAIGHT_MIN_WHEELBASES_PER_S * params.wheelbase_m(),
            straight_min_s: 2.0,
            min_slip_ratio: 0.05,
            blend_accepted: false,
            correct_every: 50,
            gate_threshold: Some(CHI2_3_99),
            gate_action: GateAction::Consensus,
            front_heading: FrontHeading::Steering,
            rejected_front_from_pair: true,
            steer_offset_drift_rad: Some(0.005f64.to_radians()),
            front_scale_drift: None,
            learn_wheel_scales: true,
        }
    }

    /// The paper's filter: literal form, `R = diag(10, 10, 10)`, a correction
    /// every 10 samples (10 Hz at 100 Hz), no gate.
    pub fn paper_literal(params: VehicleParams) -> Self {
        Self {
            form: CorrectionForm::Literal {
                r_diag: [10.0, 10.0, 10.0],
            },
            correct_every: 10,
            gate_threshold: None,
            ..Self::new(params)
        }
    }

    /// Rear odometry only.
    pub fn rear_only(params: VehicleParams) -> Self {
        Self {
            form: CorrectionForm::RearOnly,
            gate_threshold: None,
            ..Self::new(params)
        }
    }

    pub(super) fn validate(&self) -> Result<()> {
        for (name, drift) in [
            ("steer_offset_drift_rad", self.steer_offset_drift_rad),
            ("front_scale_drift", self.front_scale_drift),
        ] {
            if let Some(d) = drift {
                require_non_negative(name, d)?;
            }
        }
        require_positive("k_rear_m", self.k_rear_m)?;
        require_positive("k_front_m", self.k_front_m)?;
        require_positive("steer_sigma_rad", self.steer_sigma_rad)?;
        require_non_negative("steer_bias_sigma_rad", self.steer_bias_sigma_rad)?;
        require_non_negative("front_scale_sigma", self.front_scale_sigma)?;
        require_positive("yaw_sigma_radps", self.yaw_sigma_radps)?;
        require_non_negative("yaw_bias_walk_radps", self.yaw_bias_walk_radps)?;
        require_positive("yaw_bias_sigma_radps", self.yaw_bias_sigma_radps)?;
        require_positive("rear_ratio_sigma", self.rear_ratio_sigma)?;
        require_non_negative("yaw_scale_sigma", self.yaw_scale_sigma)?;
        require_positive("tread_sigma", self.tread_sigma)?;
        require_non_negative("tread_turn_sigma", self.tread_turn_sigma)?;
        require_positive("wheel_turn_sigma_rad", self.wheel_turn_sigma_rad)?;
        require_non_negative("ratio_walk", self.ratio_walk)?;
        require_non_negative("distance_scale_sigma", self.distance_scale_sigma)?;
        require_non_negative("still_min_s", self.still_min_s)?;
        require_positive("aided_window_s", self.aided_window_s)?;
        require_positive("yaw_gate_sigma", self.yaw_gate_sigma)?;
        require_non_negative("yaw_quantum_radps", self.yaw_quantum_radps)?;
        require_non_negative("slip_accel_sigma", self.slip_accel_sigma)?;
        require_non_negative("straight_yaw_sigma_radps", self.straight_yaw_sigma_radps)?;
        require_positive("straight_max_radps", self.straight_max_radps)?;
        require_positive("straight_max_steer_rad", self.straight_max_steer_rad)?;
        require_non_negative("straight_min_s", self.straight_min_s)?;
        require_non_negative("straight_min_speed_mps", self.straight_min_speed_mps)?;
        require_non_negative("min_slip_ratio", self.min_slip_ratio)?;
        require_positive("max_accel_mps2", self.max_accel_mps2)?;
        require_positive("slide_decel_mps2", self.slide_decel_mps2)?;
        require_non_negative("slide_decel_sigma_mps2", self.slide_decel_sigma_mps2)?;
        if self.correct_every == 0 {
            return Err(Error::InvalidConfig {
                name: "correct_every",
                reason: "must be at least 1".into(),
            });
        }
        if let Some(t) = self.gate_threshold {
            require_positive("gate_threshold", t)?;
        }
        if let CorrectionForm::Literal { r_diag } = self.form {
            for r in r_diag {
                require_positive("literal r_diag", r)?;
            }
        }
        Ok(())
    }
}
