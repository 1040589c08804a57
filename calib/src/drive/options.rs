//! The settings of a drive calibration: the priors around the values in
//! use, the fixes' latency (estimated or given), the loss, and how the
//! drive is cut into segments; with their defaults, which are the method.

use std::f64::consts::PI;

/// Prior standard deviations around the values in use.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PriorSigmas {
    /// Relative effective rear tread (fitted only from a drive with turns both ways).
    pub rear_tread: f64,
    /// Speed scale (relative).
    pub speed_scale: f64,
    /// Rear ratio correction (relative).
    pub rear_ratio: f64,
    /// Steering offset, radians.
    pub steer_offset_rad: f64,
    /// Steering gain correction (relative).
    pub steer_gain: f64,
    /// Yaw-rate bias, rad/s.
    pub yaw_bias_radps: f64,
    /// Yaw-rate scale (relative).
    pub yaw_scale: f64,
}

impl Default for PriorSigmas {
    /// 5 %, 1 %, 2°, 20 %, 1°/s, 10 %, tread 5 %.
    fn default() -> Self {
        Self {
            rear_tread: 0.05,
            speed_scale: 0.05,
            rear_ratio: 0.01,
            steer_offset_rad: 2.0 * PI / 180.0,
            steer_gain: 0.2,
            yaw_bias_radps: PI / 180.0,
            yaw_scale: 0.1,
        }
    }
}

/// The time between the log's clock and the fixes'.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FixesLatency {
    /// Estimated with the other parameters, within ±`bound_s` (a receiver's
    /// solution and its transport take a few tenths of a second; a clock
    /// more than a second off is a setup error to fix, not to fit).
    Estimate {
        /// The largest offset the fit may find, seconds.
        bound_s: f64,
    },
    /// Known: a fix stamped `t` on the log's clock describes the vehicle at
    /// `t − latency_s`.
    Given(f64),
}

/// The loss the fit minimises over the fixes' residuals.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Loss {
    /// Plain least squares: every fix counts in full (a jump of a receiver
    /// pulls the whole fit).
    LeastSquares,
    /// Cauchy's loss by iteratively reweighted least squares: a fix's weight
    /// is `1/(1 + e²/(m c² σ²))` (`e` its residual, `m` its components, `c`
    /// 2.385, 95 % efficient on Gaussian residuals) with `σ` from the
    /// median residual (the data's own scale, not a setting); a fix ten σ
    /// off counts 6 %, and unlike Huber's its pull falls to zero with the
    /// distance, so a 15 m jump moves nothing.
    Cauchy,
}

/// Settings of [`calibrate_drive_with`](super::calibrate_drive_with);
/// [`calibrate_drive`](super::calibrate_drive) uses the defaults.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriveOptions {
    /// The time offset between the log and the fixes: estimated or given.
    pub latency: FixesLatency,
    /// The loss over the fixes' residuals.
    pub loss: Loss,
    /// The effective rear tread is fitted only when the drive turns at least
    /// this much each way (summed over its turns), radians; otherwise it is
    /// held (a drive turning one way only cannot tell it from the ratio).
    pub min_turn_each_way_rad: f64,
    /// Longest segment, from its first fix to its last.
    pub max_segment_s: f64,
    /// Most fixes in one segment.
    pub max_segment_fixes: usize,
    /// Priors around the values in use.
    pub priors: PriorSigmas,
    /// A parameter is observable when posterior σ < this × prior σ.
    pub observable_ratio: f64,
}

impl Default for DriveOptions {
    /// Segments of at most 60 s and 60 fixes, the default priors, observable
    /// below 0.3, the latency estimated within ±1 s, Cauchy's loss, the tread
    /// fitted from 60° of turns each way.
    fn default() -> Self {
        Self {
            latency: FixesLatency::Estimate { bound_s: 1.0 },
            loss: Loss::Cauchy,
            min_turn_each_way_rad: 60.0 * PI / 180.0,
            max_segment_s: 60.0,
            max_segment_fixes: 60,
            priors: PriorSigmas::default(),
            observable_ratio: 0.3,
        }
    }
}
