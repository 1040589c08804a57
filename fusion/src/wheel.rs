//! Wheel inputs as real vehicles send them, turned into checked distance increments.

/// Why a wheel sample was not integrated as it came.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum InputFault {
    /// The sample's timestamp is earlier than the previous one.
    #[error("timestamp went backwards from {prev_t_s} s to {t_s} s")]
    TimestampBackwards {
        /// The previous sample's time.
        prev_t_s: f64,
        /// This sample's time.
        t_s: f64,
    },
}
