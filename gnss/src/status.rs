//! The source's status (pure): what the log and the daemon's status show.

use std::collections::VecDeque;

/// Fixes per second are counted over this window, seconds: long enough to
/// smooth a 1 Hz receiver, short enough to show an outage within seconds.
pub const RATE_WINDOW_S: f64 = 5.0;

/// The state of a live GNSS source.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SourceStatus {
    /// Connected to gpsd (a socket is open and `?WATCH` was sent).
    pub connected: bool,
    /// Accepted fixes per second over the last [`RATE_WINDOW_S`].
    pub fixes_per_s: f64,
    /// The last TPV's 95 % error estimate, metres (`max(epx, epy)`, else `eph`).
    pub last_error_m: Option<f64>,
    /// Refusals so far by reason, indexed by [`crate::Refusal::index`].
    pub refused: [u64; 3],
    /// Fixes accepted so far.
    pub accepted: u64,
    /// Connections lost or refused after the first attempt.
    pub reconnects: u64,
    /// Fixes dropped because the consumer's channel was full.
    pub dropped: u64,
    /// The last connection or protocol error, as text.
    pub last_error: Option<String>,
}

/// Receipt times of recent fixes, for [`SourceStatus::fixes_per_s`].
#[derive(Debug, Clone, Default)]
pub struct RateWindow {
    times_s: VecDeque<f64>,
}

impl RateWindow {
    /// Records a fix received at `t_s`.
    pub fn push(&mut self, t_s: f64) {
        self.times_s.push_back(t_s);
    }

    /// Fixes per second over the [`RATE_WINDOW_S`] before `now_s`.
    pub fn rate(&mut self, now_s: f64) -> f64 {
        while self
            .times_s
            .front()
            .is_some_and(|t| *t <= now_s - RATE_WINDOW_S)
        {
            self.times_s.pop_front();
        }
        self.times_s.len() as f64 / RATE_WINDOW_S
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn one_hertz_reads_one_and_an_outage_reads_zero() {
        let mut w = RateWindow::default();
        for i in 0..20 {
            w.push(f64::from(i));
        }
        assert!((w.rate(19.5) - 1.0).abs() < 1e-12);
        assert_eq!(w.rate(30.0), 0.0);
    }

    proptest! {
        #[test]
        fn rate_counts_only_the_window(times in proptest::collection::vec(0.0f64..100.0, 0..200), now in 0.0f64..120.0) {
            let mut sorted = times.clone();
            sorted.sort_by(f64::total_cmp);
            let mut w = RateWindow::default();
            for t in &sorted { w.push(*t); }
            let expect = sorted.iter().filter(|t| **t > now - RATE_WINDOW_S).count() as f64 / RATE_WINDOW_S;
            prop_assert!((w.rate(now) - expect).abs() < 1e-12);
        }
    }
}
