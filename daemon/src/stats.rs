//! Counters of what the pipeline did with every frame: used, or rejected and
//! why. One array indexed by [`Reject`], so adding a reason cannot forget a
//! place that prints them.

use std::fmt;

/// Why a frame (or a part of it) was not used.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Reject {
    /// The id is not one of the configured input messages.
    UnknownId,
    /// A remote or error frame where data was expected.
    NotData,
    /// Fewer data bytes than the DBC's message length (a truncated frame).
    Truncated,
    /// More data bytes than the DBC's message length.
    WrongDlc,
    /// The rolling counter did not advance by one.
    BadCounter,
    /// The checksum does not match.
    BadChecksum,
    /// A configured signal decoded to NaN or infinity.
    NonFinite,
    /// The steering angle is outside (−90°, 90°).
    SteerRange,
    /// A wheel decoder refused the sample (time backwards, duplicate, implausible jump).
    WheelFault,
    /// A wheel decoder saw missed samples (the sample was still integrated).
    WheelGap,
    /// The EKF gate rejected a correction window.
    GateReject,
    /// The EKF refused a step (the previous state was kept).
    FilterError,
}

impl Reject {
    /// Every reason, in the order statistics print them.
    pub const ALL: [Self; 12] = [
        Self::UnknownId,
        Self::NotData,
        Self::Truncated,
        Self::WrongDlc,
        Self::BadCounter,
        Self::BadChecksum,
        Self::NonFinite,
        Self::SteerRange,
        Self::WheelFault,
        Self::WheelGap,
        Self::GateReject,
        Self::FilterError,
    ];

    /// Short snake-case name for logs.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::UnknownId => "unknown_id",
            Self::NotData => "not_data",
            Self::Truncated => "truncated",
            Self::WrongDlc => "wrong_dlc",
            Self::BadCounter => "bad_counter",
            Self::BadChecksum => "bad_checksum",
            Self::NonFinite => "non_finite",
            Self::SteerRange => "steer_range",
            Self::WheelFault => "wheel_fault",
            Self::WheelGap => "wheel_gap",
            Self::GateReject => "gate_reject",
            Self::FilterError => "filter_error",
        }
    }
}

/// Frame and step counts of a pipeline.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Stats {
    /// Frames offered.
    pub frames: u64,
    /// Frames that passed every check and were used.
    pub used: u64,
    /// Filter steps.
    pub steps: u64,
    /// Steps without a valid front window (front or steering stale).
    pub steps_without_front: u64,
    rejects: [u64; Reject::ALL.len()],
}

impl Stats {
    /// Counts one `reason`.
    pub fn add(&mut self, reason: Reject) {
        self.add_n(reason, 1);
    }

    /// Counts `n` of `reason`.
    pub fn add_n(&mut self, reason: Reject, n: u64) {
        self.rejects[reason as usize] += n;
    }

    /// The count of `reason`.
    pub fn get(&self, reason: Reject) -> u64 {
        self.rejects[reason as usize]
    }

    /// The non-zero reasons.
    pub fn nonzero(&self) -> impl Iterator<Item = (Reject, u64)> + '_ {
        Reject::ALL
            .iter()
            .map(|&r| (r, self.get(r)))
            .filter(|&(_, n)| n > 0)
    }
}

impl fmt::Display for Stats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "frames={} used={} steps={} steps_without_front={}",
            self.frames, self.used, self.steps, self.steps_without_front
        )?;
        for (r, n) in self.nonzero() {
            write!(f, " {}={n}", r.as_str())?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn display_lists_nonzero_reasons() {
        let mut s = Stats::default();
        s.add(Reject::BadChecksum);
        s.add_n(Reject::UnknownId, 3);
        let line = s.to_string();
        assert!(line.contains("bad_checksum=1") && line.contains("unknown_id=3"));
        assert!(!line.contains("bad_counter"));
        assert_eq!(s.nonzero().count(), 2);
    }
}
