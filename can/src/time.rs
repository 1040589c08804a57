//! Log and bus time: integer microseconds since the Unix epoch, as
//! candump writes it, exact and reproducible bit for bit. Every transport,
//! log reader and the pipeline count time in it.

use std::fmt;

/// A log timestamp: integer microseconds since the Unix epoch.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Timestamp(u64);

impl Timestamp {
    /// From whole seconds and microseconds (`micros` < 1 000 000), or
    /// `None` when out of range.
    pub fn from_parts(secs: u64, micros: u32) -> Option<Self> {
        if micros >= 1_000_000 {
            return None;
        }
        secs.checked_mul(1_000_000)
            .and_then(|us| us.checked_add(u64::from(micros)))
            .map(Self)
    }

    /// From microseconds since the epoch.
    pub fn from_micros(micros: u64) -> Self {
        Self(micros)
    }

    /// Microseconds since the epoch.
    pub fn as_micros(self) -> u64 {
        self.0
    }

    /// Whole seconds.
    pub fn secs(self) -> u64 {
        self.0 / 1_000_000
    }

    /// Microseconds within the second.
    pub fn subsec_micros(self) -> u32 {
        (self.0 % 1_000_000) as u32
    }

    /// Seconds as `f64`: exact below 2^53 µs (year 2255), then one correctly
    /// rounded division, so resolution is ≈ 0.24 µs around 2023's epoch
    /// seconds and the result is identical on every IEEE-754 machine.
    pub fn as_secs_f64(self) -> f64 {
        self.0 as f64 / 1e6
    }
}

impl fmt::Display for Timestamp {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:010}.{:06}", self.secs(), self.subsec_micros())
    }
}
