//! Which TPV reports become fixes (pure), and why the others are refused.

use crate::protocol::Tpv;
use crate::status::{RateWindow, SourceStatus};

/// gpsd documents `epx`/`epy` as 95 % confidence per axis: for a normal error
/// that is 1.96 σ, so σ per axis = ep / 1.96.
pub const PER_AXIS_95_TO_SIGMA: f64 = 1.96;

/// `eph` is a horizontal (2-D) 95 % radius. For a circular normal error of σ
/// per axis the radius holding 95 % is σ·√χ²₂(0.95) = σ·√5.991 = 2.448 σ, so
/// σ per axis = eph / 2.448 (dividing by √2 alone would keep the 95 % scale).
pub const HORIZONTAL_95_TO_SIGMA: f64 = 2.447_746_830_680_816;

/// An accepted fix: the antenna's position with its 1σ and both of its times.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fix {
    /// Latitude, degrees.
    pub lat_deg: f64,
    /// Longitude, degrees.
    pub lon_deg: f64,
    /// Altitude, metres, when the fix is 3-D.
    pub alt_m: Option<f64>,
    /// 1σ horizontal error per axis, metres, from the receiver's own estimate
    /// (`max(epx, epy)` / 1.96, else `eph` / 2.448); `None` when gpsd sent none.
    pub sigma_m: Option<f64>,
    /// The receiver's GNSS time of the fix, seconds since the Unix epoch (UTC).
    pub gnss_time_unix_s: Option<f64>,
    /// When the line arrived, seconds on the receiving clock (the caller's);
    /// with `gnss_time_unix_s` it lets the latency be estimated downstream.
    pub receipt_time_s: f64,
    /// gpsd's fix mode (2 or 3).
    pub mode: u8,
}

/// Why a TPV report did not become a fix.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Refusal {
    /// Mode 0 or 1: the receiver has no position.
    NoFix,
    /// Mode ≥ 2 but no latitude or longitude.
    NoPosition,
    /// The error estimate exceeds the configured limit.
    ErrorTooLarge,
}

impl Refusal {
    /// Every reason, in the order the status lists them.
    pub const ALL: [Self; 3] = [Self::NoFix, Self::NoPosition, Self::ErrorTooLarge];

    /// A stable index into per-reason counters.
    pub fn index(self) -> usize {
        match self {
            Self::NoFix => 0,
            Self::NoPosition => 1,
            Self::ErrorTooLarge => 2,
        }
    }

    /// The reason as the log and the status name it.
    pub fn name(self) -> &'static str {
        match self {
            Self::NoFix => "no_fix",
            Self::NoPosition => "no_position",
            Self::ErrorTooLarge => "error_too_large",
        }
    }
}

/// The acceptance rule, and its counters.
#[derive(Debug, Clone, PartialEq)]
pub struct Acceptance {
    /// Largest accepted error estimate, metres, compared with gpsd's own
    /// 95 % value (`max(epx, epy)`, else `eph`) as a receiver shows it.
    pub max_error_m: f64,
    /// Refusals so far, indexed by [`Refusal::index`].
    pub refused: [u64; 3],
    /// Fixes accepted so far.
    pub accepted: u64,
}

impl Acceptance {
    /// A rule refusing error estimates above `max_error_m` (95 %, metres).
    pub fn new(max_error_m: f64) -> Self {
        Self {
            max_error_m,
            refused: [0; 3],
            accepted: 0,
        }
    }

    /// The receiver's 95 % error estimate of `tpv`: `max(epx, epy)`, else `eph`.
    pub fn error_estimate_m(tpv: &Tpv) -> Option<f64> {
        match (tpv.epx_m, tpv.epy_m) {
            (Some(x), Some(y)) => Some(x.max(y)),
            (Some(v), None) | (None, Some(v)) => Some(v),
            (None, None) => tpv.eph_m,
        }
    }

    /// 1σ per axis of `tpv` (see [`PER_AXIS_95_TO_SIGMA`], [`HORIZONTAL_95_TO_SIGMA`]).
    pub fn sigma_m(tpv: &Tpv) -> Option<f64> {
        match (tpv.epx_m, tpv.epy_m) {
            (None, None) => tpv.eph_m.map(|e| e / HORIZONTAL_95_TO_SIGMA),
            _ => Self::error_estimate_m(tpv).map(|e| e / PER_AXIS_95_TO_SIGMA),
        }
    }

    /// Judges one TPV received at `receipt_time_s`, counting the outcome.
    ///
    /// # Errors
    /// The [`Refusal`] when it is not used. A fix with no error estimate at all
    /// is accepted (many NMEA-only receivers give none) with `sigma_m = None`.
    pub fn judge(&mut self, tpv: &Tpv, receipt_time_s: f64) -> Result<Fix, Refusal> {
        let verdict = Self::verdict(self.max_error_m, tpv, receipt_time_s);
        match verdict {
            Ok(_) => self.accepted += 1,
            Err(r) => self.refused[r.index()] += 1,
        }
        verdict
    }

    fn verdict(max_error_m: f64, tpv: &Tpv, receipt_time_s: f64) -> Result<Fix, Refusal> {
        if tpv.mode < 2 {
            return Err(Refusal::NoFix);
        }
        let (Some(lat_deg), Some(lon_deg)) = (tpv.lat_deg, tpv.lon_deg) else {
            return Err(Refusal::NoPosition);
        };
        if Self::error_estimate_m(tpv).is_some_and(|e| e > max_error_m) {
            return Err(Refusal::ErrorTooLarge);
        }
        Ok(Fix {
            lat_deg,
            lon_deg,
            alt_m: if tpv.mode >= 3 { tpv.alt_m } else { None },
            sigma_m: Self::sigma_m(tpv),
            gnss_time_unix_s: tpv.time_unix_s,
            receipt_time_s,
            mode: tpv.mode,
        })
    }
}

/// Tells when what becomes of the reports changes (accepted, or refused for
/// another reason), so the log says so once per change rather than per fix.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct OutcomeChanges {
    /// Whether a report was judged yet.
    seen: bool,
    /// The last report's refusal (`None`: accepted).
    last: Option<Refusal>,
}

impl OutcomeChanges {
    /// Records the outcome of one report (`None`: accepted); true when it
    /// differs from the previous one's, and for the first report.
    pub fn changed(&mut self, refusal: Option<Refusal>) -> bool {
        let changed = !self.seen || self.last != refusal;
        self.seen = true;
        self.last = refusal;
        changed
    }
}

/// One source's judgement of its reports, as gpsd's client, the serial
/// reader and the daemon's ROS 2 source all make it: the rule, the last
/// outcome (a change is logged once, not per report) and the accepted
/// fixes' receipt times (fixes per second).
#[derive(Debug, Clone)]
pub struct Judge {
    /// The rule and its counts.
    pub acceptance: Acceptance,
    outcomes: OutcomeChanges,
    /// Receipt times of the accepted fixes.
    pub rate: RateWindow,
}

impl Judge {
    /// A judge refusing error estimates above `max_error_m` (95 %, metres).
    pub fn new(max_error_m: f64) -> Self {
        Self {
            acceptance: Acceptance::new(max_error_m),
            outcomes: OutcomeChanges::default(),
            rate: RateWindow::default(),
        }
    }

    /// Judges `tpv`, received at `receipt_s`, into `status` (its error
    /// estimate and the counts); the verdict, and whether it differs from
    /// the previous report's (the caller logs it then).
    pub fn judge(
        &mut self,
        tpv: &Tpv,
        receipt_s: f64,
        status: &mut SourceStatus,
    ) -> (Result<Fix, Refusal>, bool) {
        status.last_error_m = Acceptance::error_estimate_m(tpv);
        let verdict = self.acceptance.judge(tpv, receipt_s);
        let changed = self.outcomes.changed(verdict.err());
        if verdict.is_ok() {
            self.rate.push(receipt_s);
        }
        status.accepted = self.acceptance.accepted;
        status.refused = self.acceptance.refused;
        (verdict, changed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn tpv(mode: u8, epx: Option<f64>, epy: Option<f64>, eph: Option<f64>) -> Tpv {
        Tpv {
            mode,
            lat_deg: Some(48.0),
            lon_deg: Some(11.0),
            alt_m: Some(500.0),
            epx_m: epx,
            epy_m: epy,
            eph_m: eph,
            time_unix_s: Some(100.0),
            ..Tpv::default()
        }
    }

    #[test]
    fn the_judge_fills_the_status_counts_accepted_fixes_and_tells_each_change_once() {
        let mut j = Judge::new(30.0);
        let mut status = SourceStatus::default();
        let reports = [
            (tpv(3, None, None, Some(10.0)), true, true),
            (tpv(3, None, None, Some(12.0)), true, false),
            (tpv(3, None, None, Some(50.0)), false, true),
            (tpv(3, None, None, Some(60.0)), false, false),
            (tpv(1, None, None, None), false, true),
            (tpv(3, Some(4.0), Some(5.0), None), true, true),
        ];
        for (k, (report, accepted, changed)) in reports.iter().enumerate() {
            let (verdict, told) = j.judge(report, k as f64, &mut status);
            assert_eq!((verdict.is_ok(), told), (*accepted, *changed), "report {k}");
            assert_eq!(status.last_error_m, Acceptance::error_estimate_m(report));
        }
        assert_eq!(status.accepted, 3);
        assert_eq!(status.refused, [1, 0, 2]);
        // Only accepted fixes count towards fixes per second (at 0, 1 and
        // 5 s); at 5.5 s the window holds those after 0.5 s.
        assert!((j.rate.rate(5.5) - 2.0 / crate::status::RATE_WINDOW_S).abs() < 1e-12);
    }

    #[test]
    fn refusals_are_counted_by_reason() {
        let mut a = Acceptance::new(10.0);
        assert_eq!(a.judge(&tpv(1, None, None, None), 0.0), Err(Refusal::NoFix));
        assert_eq!(a.judge(&tpv(0, None, None, None), 0.0), Err(Refusal::NoFix));
        let mut no_pos = tpv(3, None, None, None);
        no_pos.lon_deg = None;
        assert_eq!(a.judge(&no_pos, 0.0), Err(Refusal::NoPosition));
        assert_eq!(
            a.judge(&tpv(3, Some(3.0), Some(12.0), None), 0.0),
            Err(Refusal::ErrorTooLarge)
        );
        assert_eq!(
            a.judge(&tpv(2, None, None, Some(11.0)), 0.0),
            Err(Refusal::ErrorTooLarge)
        );
        let fix = a
            .judge(&tpv(2, Some(3.92), Some(1.0), Some(50.0)), 7.0)
            .expect("accepted");
        assert_eq!(a.refused, [2, 1, 2]);
        assert_eq!(a.accepted, 1);
        // epx/epy win over eph, and 2-D fixes carry no altitude.
        assert!((fix.sigma_m.expect("sigma") - 2.0).abs() < 1e-12);
        assert_eq!(fix.alt_m, None);
        assert_eq!(
            (fix.gnss_time_unix_s, fix.receipt_time_s),
            (Some(100.0), 7.0)
        );
    }

    #[test]
    fn outcome_changes_are_told_once() {
        let mut c = OutcomeChanges::default();
        let seq = [
            None,
            None,
            Some(Refusal::ErrorTooLarge),
            Some(Refusal::ErrorTooLarge),
            Some(Refusal::NoFix),
            None,
        ];
        let told: Vec<bool> = seq.iter().map(|r| c.changed(*r)).collect();
        assert_eq!(told, [true, false, true, false, true, true]);
    }

    #[test]
    fn eph_alone_gives_a_per_axis_sigma() {
        let mut a = Acceptance::new(100.0);
        let fix = a
            .judge(&tpv(3, None, None, Some(HORIZONTAL_95_TO_SIGMA * 1.5)), 0.0)
            .expect("accepted");
        assert!((fix.sigma_m.expect("sigma") - 1.5).abs() < 1e-12);
        assert_eq!(fix.alt_m, Some(500.0));
        let fix = a.judge(&tpv(3, None, None, None), 0.0).expect("accepted");
        assert_eq!(fix.sigma_m, None);
    }

    #[test]
    fn the_95_percent_radius_of_a_circular_normal() {
        // P(r ≤ k σ) = 1 − exp(−k²/2) for a circular normal.
        let k = HORIZONTAL_95_TO_SIGMA;
        assert!((1.0 - (-k * k / 2.0).exp() - 0.95).abs() < 1e-9);
    }

    proptest! {
        #[test]
        fn accepted_or_counted_never_both(mode in 0u8..4, epx in proptest::option::of(0.0f64..50.0),
                                          epy in proptest::option::of(0.0f64..50.0), eph in proptest::option::of(0.0f64..50.0),
                                          limit in 0.1f64..40.0) {
            let mut a = Acceptance::new(limit);
            let t = tpv(mode, epx, epy, eph);
            match a.judge(&t, 1.0) {
                Ok(fix) => {
                    prop_assert!(mode >= 2);
                    prop_assert!(Acceptance::error_estimate_m(&t).is_none_or(|e| e <= limit));
                    prop_assert!(fix.sigma_m.is_none_or(|s| s <= limit / 1.9));
                    prop_assert_eq!(a.accepted, 1);
                }
                Err(r) => {
                    prop_assert_eq!(a.accepted, 0);
                    prop_assert_eq!(a.refused.iter().sum::<u64>(), 1);
                    prop_assert_eq!(a.refused[r.index()], 1);
                }
            }
        }
    }
}
