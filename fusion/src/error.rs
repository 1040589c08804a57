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
    /// A wheel sample was refused; see [`crate::wheel::InputFault`].
    #[error("wheel {wheel:?}: {fault}")]
    WheelInput {
        /// The wheel whose sample was refused.
        wheel: Wheel,
        /// Why it was refused.
        fault: crate::wheel::InputFault,
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
