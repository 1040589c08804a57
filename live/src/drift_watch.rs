//! The online calibration's schedule and the drift watch in the running
//! daemon (issue #46 items 2 and 3): while fixes come and no guided
//! calibration runs, every `every_s` of fix time the last `window_s` of the
//! drive the calibrator keeps ([`canodom_calib::calibrator::OnlineWindow`])
//! is refitted — by [`canodom_offline::online::refit`], as `replay --fixes`
//! refits — and each refit is judged by [`canodom_calib::drift::Watch`]
//! against the set in use. A flagged refit's learnt set is the candidate
//! COMMIT commits.
//!
//! Pure: it asks for a refit ([`OnlineWatch::due`]) and is told its outcome
//! ([`OnlineWatch::judged`]); the daemon runs the refit on its blocking
//! pool, at most one at a time.

use canodom_calib::calibrator::OnlineWindow;
use canodom_calib::drift::{Change, Param, Reading, Watch, Watcher, fixes_span_s, window_is_full};
use canodom_offline::online::Epoch;
use canodom_params::persist::ParamValues;
use canodom_pipeline::config::DriftWatchConfig;

/// The least number of fixes a refit needs (the drive fit's own minimum).
const MIN_FIXES: usize = 3;

/// A refit to run off the frame path, then hand to
/// [`crate::LiveCalibration::on_refit`].
#[derive(Debug, Clone, PartialEq)]
pub struct RefitJob {
    /// What to refit.
    pub window: OnlineWindow,
    /// The fix time it is made at, s (the last fix's).
    pub t_s: f64,
}

/// What the drift watch knows now, for the state file and the diagnostics.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DriftReport {
    /// Refits judged so far.
    pub refits: u64,
    /// The flagged parameters.
    pub flagged: Vec<Param>,
    /// The last judged refit's readings (each learnt value with σ and the
    /// value in use), empty before the first.
    pub readings: Vec<Reading>,
    /// The fix time of the last judged refit, s (bus clock: Unix time).
    pub t_s: Option<f64>,
    /// Distance driven at the last judged refit, m.
    pub distance_m: f64,
    /// The learnt set offered for COMMIT, if one is.
    pub candidate: Option<ParamValues>,
    /// The front tyres' ratio the watch judges against (its first reading,
    /// or the one a previous run read), kept by the state file even when
    /// no refit ran since.
    pub front_baseline: Option<canodom_calib::front_ratio::FrontRatio>,
}

/// What a judged refit changed: the flags that rose or cleared and the
/// distance driven, for the log.
#[derive(Debug, Clone, PartialEq)]
pub struct Judged {
    /// The flags that rose or cleared.
    pub changes: Vec<Change>,
    /// Distance driven since start at the refit, m.
    pub distance_m: f64,
}

/// The schedule of refits and the watch (see the module doc).
#[derive(Debug, Clone)]
pub struct OnlineWatch {
    config: DriftWatchConfig,
    watch: Watcher,
    /// The fix time the next refit is due at (set by the first fix).
    next_s: Option<f64>,
    in_flight: bool,
    report: DriftReport,
}

impl OnlineWatch {
    /// A watch with `[calibration.drift]`'s settings, nothing flagged.
    pub fn new(config: DriftWatchConfig) -> Self {
        Self {
            config,
            watch: Watcher::default(),
            next_s: None,
            in_flight: false,
            report: DriftReport::default(),
        }
    }

    /// The flags.
    pub fn watch(&self) -> Watch {
        self.watch.watch()
    }

    /// The settings.
    pub fn config(&self) -> &DriftWatchConfig {
        &self.config
    }

    /// What the watch knows now.
    pub fn report(&self) -> &DriftReport {
        &self.report
    }

    /// A fix came at `t_s`: the refit to run when one is due (`every_s`
    /// of fix time since the last, none in flight) and `window` — the
    /// calibrator's ring (`None` during a guided calibration) — holds
    /// enough fixes, spanning most of `window_s`
    /// ([`canodom_calib::drift::window_is_full`]: a refit of the first
    /// minute of fixes is not judged, so it is not run; the schedule
    /// moves on as if it had been).
    pub fn due(
        &mut self,
        t_s: f64,
        window: impl FnOnce(f64) -> Option<OnlineWindow>,
    ) -> Option<RefitJob> {
        let next = *self.next_s.get_or_insert(t_s + self.config.every_s);
        if self.in_flight || t_s < next {
            return None;
        }
        let window = window(self.config.window_s)?;
        if window.fixes.len() < MIN_FIXES || window.samples.len() < MIN_FIXES {
            return None;
        }
        self.next_s = Some(t_s + self.config.every_s);
        if !window_is_full(fixes_span_s(&window.fixes), self.config.window_s) {
            return None;
        }
        self.in_flight = true;
        Some(RefitJob { window, t_s })
    }

    /// The refit of `job` came back as `epoch` (`None`: it failed to
    /// run); `generation` is the calibrator's ring generation now and
    /// `in_use` the set in use now. A refit of a ring since emptied (a set
    /// committed meanwhile) is dropped unjudged. Returns what changed, and
    /// the candidate to offer (the learnt set while anything a set carries
    /// is flagged and the refit's set passed its gate; else none).
    pub fn judged(
        &mut self,
        job: &RefitJob,
        epoch: Option<&Epoch>,
        generation: u64,
        in_use: &ParamValues,
    ) -> Option<(Judged, Option<ParamValues>)> {
        self.in_flight = false;
        if job.window.generation != generation {
            return None;
        }
        let read = self.watch.refit_readings(
            &job.window.base,
            epoch.and_then(|e| e.judged.as_ref()),
            epoch.and_then(|e| e.front_ratio.as_ref()),
            in_use,
        );
        let changes = self.watch.judge(&read, &self.config.judge);
        let next = self.watch.watch();
        // A set is offered only for what a set carries: committing one
        // does nothing for a front tyre (watched, in no set).
        let set_drifted = next
            .flagged_params()
            .into_iter()
            .any(|p| p != Param::FrontRatio);
        let candidate = if set_drifted {
            epoch.and_then(Epoch::accepted).copied()
        } else {
            None
        };
        self.report = DriftReport {
            refits: self.report.refits + 1,
            flagged: next.flagged_params(),
            readings: read,
            t_s: Some(job.t_s),
            distance_m: job.window.odometer_m,
            candidate,
            front_baseline: self.watch.front_baseline(),
        };
        Some((
            Judged {
                changes,
                distance_m: job.window.odometer_m,
            },
            candidate,
        ))
    }

    /// The front tyres' ratio a previous run judged against (its state
    /// file): see [`Watcher::restore_front_baseline`]; whether it was taken.
    pub fn restore_front_baseline(
        &mut self,
        baseline: canodom_calib::front_ratio::FrontRatio,
    ) -> bool {
        let taken = self.watch.restore_front_baseline(baseline);
        self.report.front_baseline = self.watch.front_baseline();
        taken
    }

    /// The candidate was committed (or withdrawn): the report no longer
    /// offers it.
    pub fn candidate_taken(&mut self) {
        self.report.candidate = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use canodom_calib::drive::{DriveCalibration, DriveSample, Estimate, Fix};

    /// A ring of `fixes` fixes spread over 179 s, as 1 Hz fixes fill the
    /// default 180 s window.
    fn window(generation: u64, fixes: usize) -> OnlineWindow {
        window_spanning(generation, fixes, 179.0)
    }

    fn window_spanning(generation: u64, fixes: usize, span_s: f64) -> OnlineWindow {
        let sample = DriveSample {
            t_s: 0.0,
            rear_left_m: 0.1,
            rear_right_m: 0.1,
            front_m: None,
            steer_angle_rad: None,
            yaw_rate_radps: None,
            rear_slip: false,
        };
        let fix = Fix {
            t_s: 0.0,
            x_m: 0.0,
            y_m: 0.0,
            heading_rad: None,
            sigma_m: None,
        };
        let step_s = span_s / (fixes.max(2) - 1) as f64;
        OnlineWindow {
            samples: vec![sample; 10],
            fixes: (0..fixes)
                .map(|i| Fix {
                    t_s: i as f64 * step_s,
                    ..fix
                })
                .collect(),
            base: ParamValues::plain(1.5, 0.65),
            generation,
            odometer_m: 1234.0,
        }
    }

    fn estimate(value: f64, sigma: f64) -> Estimate {
        Estimate {
            value,
            sigma,
            observable: true,
        }
    }

    fn epoch(rear_ratio: f64, values: ParamValues) -> Epoch {
        let cal = DriveCalibration {
            speed_scale: estimate(1.0, 1e-4),
            rear_ratio: estimate(rear_ratio, 1e-4),
            steer_offset_rad: None,
            steer_gain: None,
            yaw_bias_radps: None,
            yaw_scale: None,
            yaw_bias_noise_sigma_radps: None,
            rear_tread: estimate(1.0, 1e-3),
            turns_rad: [0.0; 2],
            fixes_latency_s: estimate(0.0, 0.0),
            latency_given: true,
            down_weighted: Vec::new(),
            weighted_rms_m: [None; 3],
            own_fit_rms_m: [None; 3],
            fixes_sigma_m: 1.0,
            fixes_sigma_stated: true,
            refused: Vec::new(),
            fixes_used: 10,
            distance_m: 1000.0,
            residual_rms_m: [None; 3],
        };
        Epoch {
            t_s: 0.0,
            fixes: 10,
            fixes_span_s: 179.0,
            values: Some(values),
            estimates: Vec::new(),
            refused: None,
            judged: Some(cal),
            distance_m: 0.0,
            front_ratio: None,
        }
    }

    #[test]
    fn refits_come_every_every_s_of_fixes_one_at_a_time() {
        let mut w = OnlineWatch::new(DriftWatchConfig::default());
        assert!(
            w.due(100.0, |_| Some(window(0, 10))).is_none(),
            "the first fix starts the clock"
        );
        assert!(w.due(159.0, |_| Some(window(0, 10))).is_none());
        assert!(
            w.due(160.0, |_| Some(window(0, 2))).is_none(),
            "too few fixes"
        );
        let job = w.due(161.0, |s| {
            assert_eq!(s, 180.0);
            Some(window(0, 10))
        });
        let job = job.expect("due");
        assert!(
            w.due(300.0, |_| Some(window(0, 10))).is_none(),
            "one in flight"
        );
        let in_use = job.window.base;
        assert!(w.judged(&job, None, 0, &in_use).is_some());
        assert!(w.due(220.0, |_| Some(window(0, 10))).is_none());
        assert!(w.due(221.0, |_| Some(window(0, 10))).is_some());
    }

    #[test]
    fn a_ring_whose_fixes_span_less_than_most_of_the_window_is_not_refitted() {
        let mut w = OnlineWatch::new(DriftWatchConfig::default());
        let _ = w.due(0.0, |_| None);
        // A minute of fixes at the start of a drive (or after an outage).
        assert!(
            w.due(60.0, |_| Some(window_spanning(0, 61, 60.0)))
                .is_none()
        );
        // Not asked again at the next fix: the schedule moved on.
        assert!(w.due(61.0, |_| panic!("not due")).is_none());
        assert!(
            w.due(120.0, |_| Some(window_spanning(0, 121, 120.0)))
                .is_none()
        );
        // Three minutes: refitted and judged.
        assert!(
            w.due(180.0, |_| Some(window_spanning(0, 180, 179.0)))
                .is_some()
        );
    }

    #[test]
    fn a_drift_flags_offers_the_learnt_set_and_clears_when_the_car_agrees() {
        let mut w = OnlineWatch::new(DriftWatchConfig::default());
        let _ = w.due(0.0, |_| None);
        let base = ParamValues::plain(1.5, 0.65);
        let learnt = ParamValues {
            rear_right_diameter_m: 0.65 * 1.005,
            ..base
        };
        let job = w.due(60.0, |_| Some(window(0, 10))).unwrap();
        let (j, cand) = w
            .judged(&job, Some(&epoch(1.005, learnt)), 0, &base)
            .unwrap();
        assert_eq!(j.changes.len(), 1);
        assert!(j.changes[0].raised && j.changes[0].reading.param == Param::RearRatio);
        assert_eq!(j.distance_m, 1234.0);
        assert_eq!(cand, Some(learnt));
        assert_eq!(w.report().flagged, vec![Param::RearRatio]);
        assert_eq!(w.report().candidate, Some(learnt));
        // A refit of a ring emptied since (a commit) is not judged.
        let job = w.due(120.0, |_| Some(window(0, 10))).unwrap();
        assert!(w.judged(&job, Some(&epoch(1.0, base)), 1, &base).is_none());
        assert!(w.watch().flagged(Param::RearRatio));
        // The car agrees again: cleared, nothing offered.
        let job = w.due(180.0, |_| Some(window(1, 10))).unwrap();
        let (j, cand) = w.judged(&job, Some(&epoch(1.0, base)), 1, &base).unwrap();
        assert!(j.changes.len() == 1 && !j.changes[0].raised);
        assert_eq!(cand, None);
        assert!(!w.watch().any() && w.report().refits == 2);
    }

    #[test]
    fn the_front_tyres_first_reading_is_what_later_ones_are_judged_against() {
        use canodom_calib::front_ratio::FrontRatio;
        let mut w = OnlineWatch::new(DriftWatchConfig::default());
        let _ = w.due(0.0, |_| None);
        let base = ParamValues::plain(1.5, 0.65);
        let with_front = |value: f64| Epoch {
            front_ratio: Some(FrontRatio {
                value,
                sigma: 0.00003,
                distance_m: 600.0,
            }),
            ..epoch(1.0, base)
        };
        let job = w.due(60.0, |_| Some(window(0, 10))).unwrap();
        let (j, _) = w.judged(&job, Some(&with_front(1.002)), 0, &base).unwrap();
        assert!(j.changes.is_empty());
        let front = |w: &OnlineWatch| {
            w.report()
                .readings
                .iter()
                .find(|r| r.param == Param::FrontRatio)
                .copied()
                .unwrap()
        };
        assert_eq!((front(&w).learnt, front(&w).in_use), (1.002, 1.002));
        // The front-left tyre 0.5 % soft: flagged, and the diagnostics
        // show it against the first reading.
        let job = w.due(120.0, |_| Some(window(0, 10))).unwrap();
        let (j, candidate) = w.judged(&job, Some(&with_front(1.007)), 0, &base).unwrap();
        assert!(j.changes.len() == 1 && j.changes[0].raised, "{j:?}");
        assert_eq!(w.report().flagged, vec![Param::FrontRatio]);
        // No set is offered: none carries the front tyres.
        assert_eq!(candidate, None);
        assert_eq!((front(&w).learnt, front(&w).in_use), (1.007, 1.002));
        // A refit that cannot read the front says nothing about it.
        let job = w.due(180.0, |_| Some(window(0, 10))).unwrap();
        let (j, _) = w.judged(&job, Some(&epoch(1.0, base)), 0, &base).unwrap();
        assert!(j.changes.is_empty() && w.watch().flagged(Param::FrontRatio));
    }
}
