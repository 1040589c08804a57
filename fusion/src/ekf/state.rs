//! The filter's state: its constructors, what it shows (the pose, its
//! covariance, who carries it) and what it has learnt, to keep across
//! restarts and hand back ([`State::learnt`], [`State::with_learnt`]).
//! Split from `ekf.rs`, which keeps the types and the step.

use super::algebra::{compose, compose_covariance, symmetrise};
use super::retro::RETRO_ORDER;
use super::slide::Slide;
use super::wheels::AxleWatch;
use super::{
    Aided, AidedLead, GateStats, Learnt, LearntPair, Mat3, ScaleLearner, State, SteerTerms, Vec3,
    WheelScales, WindowOutcome, finite,
};
use crate::error::{Error, Result};
use crate::odometry::Pose;
use crate::{WheelSet, wrap_angle};

impl State {
    /// A state at `pose` with covariance `p` (e.g. zero at a run's start).
    ///
    /// # Errors
    /// [`Error::NonFiniteInput`] for a non-finite pose or covariance entry.
    pub fn new(pose: Pose, p: Mat3) -> Result<Self> {
        for (name, v) in [
            ("x_m", pose.x_m),
            ("y_m", pose.y_m),
            ("heading_rad", pose.heading_rad),
        ] {
            finite(name, v)?;
        }
        if p.iter().any(|v| !v.is_finite()) {
            return Err(Error::NonFiniteInput {
                name: "initial covariance",
                value: f64::NAN,
            });
        }
        let anchor = Vec3::new(pose.x_m, pose.y_m, wrap_angle(pose.heading_rad));
        Ok(Self {
            anchor,
            anchor_heading_unwrapped_rad: pose.heading_rad,
            anchor_cos_sin: (anchor.z.cos(), anchor.z.sin()),
            p_anchor: symmetrise(&p),
            rear_w: Vec3::zeros(),
            p_rear_w: Mat3::zeros(),
            front_w: Vec3::zeros(),
            p_front_w: Mat3::zeros(),
            front_bias_sens: Vec3::zeros(),
            rear_cs: (1.0, 0.0),
            front_cs: (1.0, 0.0),
            front_alone: Vec3::new(pose.x_m, pose.y_m, pose.heading_rad),
            wheel_sum_m: [0.0; 4],
            steer_turn_sum_m: 0.0,
            window_len: 0,
            window_front_ok: true,
            stats: GateStats::default(),
            slip_counts: WheelSet::splat(0),
            slip_flags: WheelSet::splat(false),
            last_mahalanobis_sq: 0.0,
            last_window: WindowOutcome::Open,
            steer_offset_rad: 0.0,
            steer_offset_var: 0.0,
            front_scale: 1.0,
            front_scale_var: 0.0,
            aided: Aided::zeroed(),
            aided_on: false,
            lead: AidedLead::NONE,
            pending_yaw: None,
            window_rear_m: 0.0,
            window_front_m: 0.0,
            steer_terms: SteerTerms::NONE,
            wheels_were_zero: false,
            slide: Slide::default(),
            axle_watch: AxleWatch::default(),
            scales: ScaleLearner::new(),
            rear_moments: [[0.0; 2]; RETRO_ORDER + 1],
            rear_distance_m: 0.0,
            rear_turn_moments: [[0.0; 2]; RETRO_ORDER + 1],
            rear_turn_rad: 0.0,
            applied_ln_scale: [0.0; 4],
            applied_factor: [1.0; 4],
        })
    }

    /// A state at the origin with zero covariance (a run frame's start).
    pub fn origin() -> Self {
        Self::new(Pose::default(), Mat3::zeros())
            .unwrap_or_else(|_| unreachable!("the origin is finite"))
    }

    /// This filter with its frame moved to where the vehicle stands: pose at
    /// the origin with zero covariance (an operator's reset, at standstill).
    /// What it has learnt about the vehicle (steering offset, front scale and
    /// their variances) and its counts are kept; the open correction window
    /// is dropped, which loses nothing at standstill.
    #[must_use]
    pub fn rebased_at_origin(&self) -> Self {
        Self {
            aided: self.aided.rebased_at_origin(),
            aided_on: self.aided_on,
            lead: self.lead,
            pending_yaw: self.pending_yaw,
            ..self.wheels_learning_onto(Self::origin())
        }
    }

    /// `fresh` with what this filter learnt of the wheels and the steering
    /// (steering offset, front scale, wheel scales, their variances) and its
    /// counts; its open windows dropped.
    fn wheels_learning_onto(&self, fresh: Self) -> Self {
        Self {
            stats: self.stats,
            slip_counts: self.slip_counts,
            slip_flags: self.slip_flags,
            last_mahalanobis_sq: self.last_mahalanobis_sq,
            steer_offset_rad: self.steer_offset_rad,
            steer_offset_var: self.steer_offset_var,
            front_scale: self.front_scale,
            front_scale_var: self.front_scale_var,
            scales: self.scales.rebased(),
            applied_ln_scale: self.applied_ln_scale,
            applied_factor: self.applied_factor,
            ..fresh
        }
    }

    /// This filter without the yaw-rate sensor, for a gyro found at fault
    /// (its sign or unit wrong), restarted at `pose` (the rear wheels'
    /// odometry at that instant): the wheels-only filter carries on from
    /// there as if no gyro had been configured. Neither the aided pose nor
    /// what the aided filter learnt against that gyro (bias, rear ratio,
    /// effective tread) is kept: a sign-flipped Toyota gyro has turned the
    /// heading the wrong way for the seconds it took to find it, and kept
    /// in the aided filter without its readings its fitted terms ended 66 %
    /// of an opendbc drive off. The covariance is the aided one's (the
    /// wheels' own drift is not less); the wheels' own learning is kept;
    /// the open correction window is dropped. Where the aided filter did
    /// not carry the pose, the wheels-only filter already does: it goes on
    /// as it is (its pose and window kept, `pose` unused) and only the aided
    /// filter is dropped.
    #[must_use]
    pub fn without_yaw_rate(&self, pose: Pose) -> Self {
        if !self.lead.leads {
            return Self {
                aided: Aided::zeroed(),
                aided_on: false,
                lead: AidedLead::NONE,
                pending_yaw: None,
                ..*self
            };
        }
        let Ok(handed_over) = Self::new(pose, self.covariance()) else {
            // A non-finite pose or covariance: keep the filter as it is (the
            // next step's numerical check reports a broken state).
            return *self;
        };
        self.wheels_learning_onto(handed_over)
    }

    /// The pose estimate, heading wrapped to (−π, π].
    pub fn pose(&self) -> Pose {
        if self.lead.leads {
            let [x_m, y_m, heading_rad] = self.aided.pose();
            return Pose {
                x_m,
                y_m,
                heading_rad: wrap_angle(heading_rad),
            };
        }
        let pose = compose(&self.anchor, self.anchor_cos_sin, &self.rear_w);
        Pose {
            x_m: pose.x,
            y_m: pose.y,
            heading_rad: pose.z,
        }
    }

    /// The pose estimate with the heading unwrapped (total turn since the start).
    pub fn pose_unwrapped(&self) -> Pose {
        if self.lead.leads {
            let [x_m, y_m, heading_rad] = self.aided.pose();
            return Pose {
                x_m,
                y_m,
                heading_rad,
            };
        }
        Pose {
            heading_rad: self.anchor_heading_unwrapped_rad + self.rear_w.z,
            ..self.pose()
        }
    }

    /// The covariance of [`State::pose`].
    pub fn covariance(&self) -> Mat3 {
        if self.lead.leads {
            let c = self.aided.pose_covariance();
            return Mat3::new(
                c[0][0], c[0][1], c[0][2], c[1][0], c[1][1], c[1][2], c[2][0], c[2][1], c[2][2],
            );
        }
        compose_covariance(
            &self.p_anchor,
            self.anchor_cos_sin,
            &self.rear_w,
            &self.p_rear_w,
        )
    }

    /// The learnt steering offset (road-wheel radians), subtracted from the
    /// measured angle; 0 unless [`EkfConfig::steer_offset_drift_rad`] is set.
    pub fn steer_offset_rad(&self) -> f64 {
        self.steer_offset_rad
    }

    /// What the filter has learnt about the vehicle, to keep across a
    /// restart ([`State::with_learnt`]).
    pub fn learnt(&self) -> Learnt {
        Learnt {
            steer_offset_rad: self.steer_offset_rad,
            steer_offset_sigma_rad: self.steer_offset_var.sqrt(),
            front_scale: self.front_scale,
            front_scale_sigma: self.front_scale_var.sqrt(),
            wheel_fault: self.scales.kept(),
            yaw_bias: if self.aided_on {
                let [(bias, bias_sd), (ratio, ratio_sd), (tread, tread_sd)] = self.aided.learnt();
                Some(LearntPair {
                    yaw_bias_radps: bias,
                    yaw_bias_sigma_radps: bias_sd,
                    rear_ratio_err: ratio,
                    rear_ratio_sigma: ratio_sd,
                    tread_err: tread,
                    tread_sigma: tread_sd,
                })
            } else {
                self.pending_yaw
            },
        }
    }

    /// This state with `learnt` restored (from a state file, or from a
    /// calibration). A σ of 0 means "not learnt": the configuration's prior
    /// is used. The caller bounds the values first.
    #[must_use]
    pub fn with_learnt(&self, learnt: &Learnt) -> Self {
        let mut st = *self;
        st.steer_offset_rad = learnt.steer_offset_rad;
        st.steer_offset_var = learnt.steer_offset_sigma_rad * learnt.steer_offset_sigma_rad;
        st.front_scale = learnt.front_scale;
        st.front_scale_var = learnt.front_scale_sigma * learnt.front_scale_sigma;
        // The learner keeps more than it saves (every explanation's filter):
        // only a value other than its own replaces it, and "none" is its prior.
        if learnt.wheel_fault != st.scales.kept() {
            st.scales = ScaleLearner::new();
            if let Some(f) = learnt.wheel_fault {
                st.scales.restore(&f);
            }
        }
        st.steer_terms = SteerTerms::NONE;
        if let Some(y) = learnt.yaw_bias {
            if st.aided_on {
                st.aided.restore(&y);
            } else {
                st.pending_yaw = Some(y);
            }
        }
        st
    }

    /// The learnt yaw-rate bias, rad/s (0 before any yaw-rate sample).
    pub fn yaw_bias_radps(&self) -> f64 {
        self.learnt().yaw_bias.map_or(0.0, |y| y.yaw_bias_radps)
    }

    /// The learnt relative error of the rear diameter ratio (0 before any
    /// yaw-rate sample): the rear wheels' heading is corrected by `e·d/b`.
    pub fn rear_ratio_err(&self) -> f64 {
        self.learnt().yaw_bias.map_or(0.0, |y| y.rear_ratio_err)
    }

    /// The learnt relative error of the effective rear tread (0 before any
    /// yaw-rate sample): the rear wheels turn `1 + τ` times the body.
    pub fn tread_err(&self) -> f64 {
        self.learnt().yaw_bias.map_or(0.0, |y| y.tread_err)
    }

    /// True once the yaw-rate-aided estimator runs (from the first
    /// yaw-rate sample).
    pub fn yaw_aided(&self) -> bool {
        self.aided_on
    }

    /// True once the yaw-rate-aided estimator carries the pose: it has shown
    /// the rear wheels' ratio or tread off beyond what the wheels' own
    /// learning corrects ([`AIDED_LEAD_SIGMAS`]), a rear wheel slipped, or
    /// the gyro's bias is known ([`AIDED_LEAD_BIAS_SIGMA_RADPS`]).
    pub fn aided_leads(&self) -> bool {
        self.lead.leads
    }

    /// The learnt factor applied to the front wheels' distances; 1 unless
    /// [`EkfConfig::front_scale_drift`] is set.
    pub fn front_scale(&self) -> f64 {
        self.front_scale
    }

    /// Each wheel's learnt scale with its σ and the explanation the
    /// evidence favours ([`Fault`]); every scale 1 until a wheel is off.
    pub fn wheel_scales(&self) -> WheelScales {
        self.scales.learnt()
    }

    /// The front odometry integrated on its own (the literal form's `z`).
    pub fn front_alone(&self) -> Pose {
        Pose {
            x_m: self.front_alone.x,
            y_m: self.front_alone.y,
            heading_rad: self.front_alone.z,
        }
    }
}
