//! The one error type of the fusion crate.

use crate::Wheel;

/// Everything that can go wrong in the fusion crate.
///
/// Variants carry the offending value and the name of the quantity, so a
/// message read in a log says what was wrong without the source at hand.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Error {
    /// A vehicle parameter is not a finite, strictly positive number.
    #[error("vehicle parameter `{name}` must be finite and > 0, got {value}")]
    InvalidParameter {
        /// The parameter's name, with its unit (e.g. `rear_tread_m`).
        name: &'static str,
        /// The rejected value.
        value: f64,
    },
    /// An input to a pure step function is NaN or infinite.
    #[error("input `{name}` is not finite: {value}")]
    NonFiniteInput {
        /// The input's name, with its unit.
        name: &'static str,
        /// The rejected value.
        value: f64,
    },
    /// A steering angle at or beyond ±90°, where the bicycle model breaks down.
    #[error("steering angle {steer_angle_rad} rad is outside (-pi/2, pi/2)")]
    SteeringOutOfRange {
        /// The rejected road-wheel angle.
        steer_angle_rad: f64,
    },
    /// A tick counter width that cannot be represented (must be 1..=64 bits).
    #[error("tick counter width must be 1..=64 bits, got {bits}")]
    InvalidCounterWidth {
        /// The rejected width.
        bits: u32,
    },
    /// A wheel sample was refused; see [`InputFault`].
    #[error("wheel {wheel:?}: {fault}")]
    WheelInput {
        /// The wheel whose sample was refused.
        wheel: Wheel,
        /// Why it was refused.
        fault: InputFault,
    },
    /// A matrix that must be invertible or positive definite is not.
    #[error("numerical failure in {context}")]
    Numerical {
        /// What was being computed.
        context: &'static str,
    },
    /// A configuration value outside its valid range.
    #[error("invalid configuration `{name}`: {reason}")]
    InvalidConfig {
        /// The configuration item's name.
        name: &'static str,
        /// What was expected.
        reason: String,
    },
}

/// The fusion crate's result type.
pub type Result<T> = std::result::Result<T, Error>;

/// Checks a configuration value that must be finite and strictly positive.
pub(crate) fn require_positive(name: &'static str, value: f64) -> Result<()> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(Error::InvalidConfig {
            name,
            reason: format!("must be finite and > 0, got {value}"),
        })
    }
}

/// Checks a configuration value that must be finite and zero or more.
pub(crate) fn require_non_negative(name: &'static str, value: f64) -> Result<()> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(Error::InvalidConfig {
            name,
            reason: format!("must be finite and >= 0, got {value}"),
        })
    }
}

/// Why a wheel sample was not integrated as it came.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum InputFault {
    /// The sample's timestamp is earlier than the previous one. Nothing is
    /// integrated and the previous sample stays the reference.
    #[error("timestamp went backwards from {prev_t_s} s to {t_s} s")]
    TimestampBackwards {
        /// The previous sample's time.
        prev_t_s: f64,
        /// This sample's time.
        t_s: f64,
    },
    /// The sample has the same timestamp as the previous one (a repeated
    /// frame). Nothing is integrated; for a cumulative counter nothing is lost,
    /// the next sample's delta carries any movement.
    #[error("duplicated sample at {t_s} s")]
    DuplicateSample {
        /// The repeated timestamp.
        t_s: f64,
    },
    /// The gap since the previous sample exceeds the configured factor times
    /// the nominal period. The increment was still integrated (it was
    /// physically plausible), but the caller should know samples were lost.
    #[error("missed about {missed} sample(s): gap of {gap_s} s")]
    MissedSamples {
        /// The time since the previous sample.
        gap_s: f64,
        /// Estimated number of lost samples.
        missed: u64,
    },
    /// The increment needs a wheel speed above the configured maximum. It was
    /// not integrated; the decoder re-anchors on this sample so that a
    /// counter reset costs one fault, not a fault per sample.
    #[error("implausible jump of {distance_m} m in {dt_s} s (max {max_distance_m} m)")]
    ImplausibleJump {
        /// The distance the sample implies.
        distance_m: f64,
        /// The time since the previous sample.
        dt_s: f64,
        /// The largest distance the maximum wheel speed allows.
        max_distance_m: f64,
    },
    /// The timestamp or speed is NaN or infinite. Nothing is integrated.
    #[error("non-finite sample value {value}")]
    NonFinite {
        /// The rejected value.
        value: f64,
    },
}
