//! One filter step, what the pipeline hands every consumer (replay's rows,
//! the calibration, the plausibility checks): its own module so those
//! consumers inside the crate need not import the pipeline.

use canodom_fusion::Pose;
use canodom_fusion::ekf::WindowOutcome;

/// One filter step: the row `replay` writes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Step {
    /// Seconds since the first input frame.
    pub t_s: f64,
    /// The same time in whole microseconds, as the timestamps count it
    /// (`t_s` is this divided by 10⁶): exact, for writing it as text.
    pub t_us: i64,
    /// The fused pose (heading unwrapped: total turn).
    pub fused: Pose,
    /// Rear-wheel-only odometry (heading unwrapped).
    pub odometry: Pose,
    /// Rear (left, right) wheel revolutions of this step, with the diameters
    /// in use: what the calibration session records.
    pub rear_rev: (f64, f64),
    /// Front (left, right) wheel revolutions of this step with the
    /// diameters in use; `None` when the front wheels were not fresh (or are
    /// not configured): the drift watch reads the front tyres from them.
    pub front_rev: Option<(f64, f64)>,
    /// The latest steering signal `u` as the vehicle reports it (before the
    /// steering map), if any arrived yet.
    pub steer_signal: Option<f64>,
    /// What the filter's correction window did at this step
    /// ([`WindowOutcome::Open`] when the step did not close one).
    pub correction: WindowOutcome,
    /// The yaw rate the step used (rad/s, left positive, scale corrected,
    /// bias not removed); `None` without a fresh yaw-rate sensor.
    pub yaw_rate_radps: Option<f64>,
}
