//! Counters of what the pipeline did with every frame: used, or rejected and
//! why. One array indexed by [`Reject`], so adding a reason cannot forget a
//! place that prints them.

use canodom_fusion::{Wheel, WheelSet};
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
    /// A wheel frame came after a silence of more than 1.9 of the message's
    /// periods (learnt, or `GenMsgCycleTime`): a frame was probably lost. The
    /// frame was still used: a speed integrates over the real interval, and
    /// a counter's increment spans it.
    WheelGap,
    /// The EKF gate rejected a correction window.
    GateReject,
    /// The EKF refused a step (the previous state was kept).
    FilterError,
    /// The yaw-rate reading was at (or within a step or two of) an end of
    /// its DBC signal's range: the sensor may be saturated, so the reading
    /// is not given to the filter (the rest of the frame is used).
    YawSaturated,
    /// The yaw-rate sensor was found at fault (its sign or unit disagrees
    /// with the rear wheels and, with a steering angle, with the steering
    /// too): its readings are no longer given to the filter.
    YawImplausible,
}

impl Reject {
    /// Every reason, in the order statistics print them.
    pub const ALL: [Self; 14] = [
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
        Self::YawSaturated,
        Self::YawImplausible,
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
            Self::YawSaturated => "yaw_saturated",
            Self::YawImplausible => "yaw_implausible",
        }
    }
}

/// A set of [`Reject`] reasons, one bit each: what a frame that was still
/// used came with (a wheel gap, a wheel decoder's fault, a gate rejection, a
/// refused filter step). A set, not one reason, because one frame can earn
/// several (a gap and a wheel fault), and the calibration's fault report
/// picks among them by its own order.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Reasons(u16);

// One bit per reason must fit the set.
const _: () = assert!(Reject::ALL.len() <= u16::BITS as usize);

impl Reasons {
    /// Adds `reason`.
    pub fn insert(&mut self, reason: Reject) {
        self.0 |= 1 << reason as u16;
    }

    /// Whether `reason` is in the set.
    pub fn contains(self, reason: Reject) -> bool {
        self.0 & (1 << reason as u16) != 0
    }

    /// Whether the set is empty (the frame was used without a remark).
    pub fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// The reasons in the set, in [`Reject::ALL`]'s order.
    pub fn iter(self) -> impl Iterator<Item = Reject> {
        Reject::ALL.into_iter().filter(move |&r| self.contains(r))
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
    /// The gate's rejections by what they did and which wheel they blamed.
    pub gate: GateCounts,
    rejects: [u64; Reject::ALL.len()],
}

/// The EKF gate's rejections: by the action taken and by the wheel the
/// consensus blamed (`GateReject` counts them all).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GateCounts {
    /// Rejections that kept the rear increment (a front wheel blamed, or
    /// the gyro-aided estimator's wheels and gyro disagreeing:
    /// `WindowOutcome::Disagreed`).
    pub kept_rear: u64,
    /// Rejections that took the front increment (a rear wheel blamed).
    pub used_front: u64,
    /// Rejections by the wheel blamed.
    pub blamed: WheelSet<u64>,
    /// Samples whose heading came from the yaw-rate sensor alone: it and the
    /// rear wheels disagreed and the steering sided with it.
    pub yaw_over_rear: u64,
    /// Samples whose yaw rate was refused: it disagreed with the wheels.
    pub yaw_refused: u64,
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
        let g = &self.gate;
        if g.kept_rear + g.used_front > 0 {
            write!(
                f,
                " gate_kept_rear={} gate_used_front={} gate_blamed=",
                g.kept_rear, g.used_front
            )?;
            for (k, w) in Wheel::ALL.iter().enumerate() {
                let sep = if k == 0 { "" } else { "," };
                write!(f, "{sep}{}:{}", wheel_short(*w), g.blamed[*w])?;
            }
        }
        if g.yaw_over_rear + g.yaw_refused > 0 {
            write!(
                f,
                " yaw_over_rear={} yaw_refused={}",
                g.yaw_over_rear, g.yaw_refused
            )?;
        }
        Ok(())
    }
}

/// `rl`, `rr`, `fl`, `fr`.
fn wheel_short(w: Wheel) -> &'static str {
    match w {
        Wheel::RearLeft => "rl",
        Wheel::RearRight => "rr",
        Wheel::FrontLeft => "fl",
        Wheel::FrontRight => "fr",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gate_counts_print_by_action_and_wheel_only_when_any() {
        let mut s = Stats::default();
        assert!(!s.to_string().contains("gate_"));
        s.add_n(Reject::GateReject, 3);
        s.gate.kept_rear = 1;
        s.gate.used_front = 2;
        s.gate.blamed.rear_right = 2;
        s.gate.blamed.front_left = 1;
        let line = s.to_string();
        assert!(
            line.ends_with(
                "gate_reject=3 gate_kept_rear=1 gate_used_front=2 gate_blamed=rl:0,rr:2,fl:1,fr:0"
            ),
            "{line}"
        );
    }

    #[test]
    fn reasons_hold_each_reason_once_in_print_order() {
        let mut r = Reasons::default();
        assert!(r.is_empty());
        r.insert(Reject::GateReject);
        r.insert(Reject::WheelFault);
        r.insert(Reject::GateReject);
        assert!(r.contains(Reject::WheelFault) && !r.contains(Reject::WheelGap));
        assert_eq!(
            r.iter().collect::<Vec<_>>(),
            [Reject::WheelFault, Reject::GateReject]
        );
        assert!(Reject::ALL.iter().all(|&x| {
            let mut one = Reasons::default();
            one.insert(x);
            one.iter().eq([x])
        }));
    }

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
