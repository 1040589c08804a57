//! A drive recorded for calibration against the bus's position fixes
//! (START_DRIVE): the filter's steps merged into short bins, the fixes in a
//! local frame, and the job that fits them ([`crate::drive`]).

use crate::drive::{DriveCalibration, DriveModel, DriveSample, Fix, calibrate_drive};
use crate::drive_gate::{DriveGate, apply_gate};
use crate::error::Result;
use crate::history::ParamValues;

/// Steps are merged into bins of this length: the fit needs the shape of the
/// drive, not every 10 ms, so a ten-minute drive is 12,000 samples, a
/// fraction of a second to fit.
const DRIVE_BIN_S: f64 = 0.05;

/// The most samples a drive keeps (20 minutes of bins): the rest is not recorded.
const DRIVE_MAX_SAMPLES: usize = 24_000;

/// Mean Earth radius, metres, for latitude/longitude fixes turned into a
/// local frame (equirectangular around the first fix: centimetres over the
/// kilometres of a calibration drive).
const EARTH_RADIUS_M: f64 = 6_371_000.0;

/// One filter step as the drive records it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriveStep {
    /// Bus time, s.
    pub t_s: f64,
    /// Rear-left distance of the step with the diameters in use, m.
    pub rear_left_m: f64,
    /// Rear-right distance, m.
    pub rear_right_m: f64,
    /// Front (left, right) distances with the diameters in use, m; `None`
    /// where the front wheels were not fresh.
    pub front_m: Option<(f64, f64)>,
    /// The road-wheel angle of the map in use, rad.
    pub steer_angle_rad: Option<f64>,
    /// The yaw rate the filter used, rad/s.
    pub yaw_rate_radps: Option<f64>,
    /// Length of the step, s.
    pub dt_s: f64,
}

/// Why a recorded drive cannot be fitted yet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TooFewSamples;

/// The fit of a recorded drive: pure and owned, to run away from the frame path.
#[derive(Debug, Clone, PartialEq)]
pub struct DriveJob {
    /// The binned steps.
    pub samples: Vec<DriveSample>,
    /// The fixes within the steps' time span.
    pub fixes: Vec<Fix>,
    /// The geometry in use.
    pub model: DriveModel,
    /// The values in use while recording.
    pub base: ParamValues,
    /// The quality a fit must show for its values to be committed.
    pub gate: DriveGate,
}

impl DriveJob {
    /// Fits the drive; the calibration and the values it gives.
    ///
    /// # Errors
    /// As [`calibrate_drive`].
    pub fn run(&self) -> Result<(DriveCalibration, ParamValues)> {
        let mut cal = calibrate_drive(&self.samples, &self.fixes, &self.model)?;
        apply_gate(&mut cal, &self.gate);
        let values = crate::drive::calibrated_values(&self.base, &cal);
        Ok((cal, values))
    }
}

/// A drive being recorded (see the module doc).
#[derive(Debug, Clone, Default)]
pub struct DriveRecorder {
    samples: Vec<DriveSample>,
    /// The open bin: its distances, the last steering angle, and ∫ω dt, ∫dt.
    bin: Option<(DriveSample, f64, f64)>,
    fixes: Vec<Fix>,
    /// Latitude and longitude of the first fix (geodetic fixes only), degrees.
    origin: Option<(f64, f64)>,
    /// A job is out or a result awaits commit: the recording is closed.
    closed: bool,
    /// The first sample of the filter's open correction window.
    window_start: usize,
    /// A ring rather than a recording (the online calibration's,
    /// [`DriveRecorder::ring`]): only this much of the drive is kept, s.
    keep_s: Option<f64>,
    /// Each fix's latitude and longitude when it was geodetic, to turn the
    /// kept fixes into metres around a nearer origin as the ring moves on.
    geodetic: Vec<Option<(f64, f64)>>,
}

/// A ring trims its oldest samples once they are this share of its length
/// beyond it: a trim moves the whole ring, so it is done seldom (amortised
/// O(1) a step) rather than at every bin.
const RING_SLACK: f64 = 0.1;

impl DriveRecorder {
    /// A ring over the last `keep_s` of the drive: it never closes and never
    /// fills, its oldest bins and fixes giving way to new ones (kept between
    /// `keep_s` and `(1 + RING_SLACK)·keep_s`, or [`DRIVE_MAX_SAMPLES`] bins
    /// if fewer). The online calibration's drift watch
    /// ([`crate::drift`]) refits [`DriveRecorder::window`] of it.
    pub fn ring(keep_s: f64) -> Self {
        Self {
            keep_s: Some(keep_s),
            ..Self::default()
        }
    }

    /// The samples and fixes of the last `window_s` (the open bin left
    /// out), the fixes within the samples' time span, geodetic fixes in
    /// metres around the first of them.
    pub fn window(&self, window_s: f64) -> (Vec<DriveSample>, Vec<Fix>) {
        let Some(last) = self.samples.last().map(|s| s.t_s) else {
            return (Vec::new(), Vec::new());
        };
        let from = self.samples.partition_point(|s| s.t_s < last - window_s);
        let samples = self.samples[from..].to_vec();
        let first = samples.first().map_or(last, |s| s.t_s);
        let kept = |f: &Fix| f.t_s >= first && f.t_s <= last;
        let mut origin = None;
        let fixes = self
            .fixes
            .iter()
            .zip(&self.geodetic)
            .filter(|(f, _)| kept(f))
            .map(|(f, geo)| match geo {
                Some((lat, lon)) => {
                    let (lat0, lon0) = *origin.get_or_insert((*lat, *lon));
                    let (x_m, y_m) = local_m(lat0, lon0, *lat, *lon);
                    Fix { x_m, y_m, ..*f }
                }
                None => *f,
            })
            .collect();
        (samples, fixes)
    }

    /// Forgets everything recorded (a ring whose samples were converted
    /// with a set no longer in use).
    pub fn clear(&mut self) {
        *self = Self {
            keep_s: self.keep_s,
            ..Self::default()
        };
    }

    /// Whether nothing is recorded (no bin, no fix).
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty() && self.bin.is_none() && self.fixes.is_empty()
    }

    /// Whether the recording is closed (a fit is running or awaits commit).
    pub fn is_closed(&self) -> bool {
        self.closed
    }

    /// Adds one filter step to the open bin, closing the bin after
    /// `DRIVE_BIN_S`.
    pub fn step(&mut self, step: &DriveStep) {
        if self.closed || (self.keep_s.is_none() && self.samples.len() >= DRIVE_MAX_SAMPLES) {
            return;
        }
        let (bin, yaw_dt, dt) = self.bin.get_or_insert((
            DriveSample {
                t_s: step.t_s,
                rear_left_m: 0.0,
                rear_right_m: 0.0,
                front_m: Some((0.0, 0.0)),
                steer_angle_rad: None,
                yaw_rate_radps: None,
                rear_slip: false,
            },
            0.0,
            0.0,
        ));
        bin.t_s = step.t_s;
        bin.rear_left_m += step.rear_left_m;
        bin.rear_right_m += step.rear_right_m;
        // A bin is read on the front only if every step in it was.
        bin.front_m = bin
            .front_m
            .zip(step.front_m)
            .map(|(b, s)| (b.0 + s.0, b.1 + s.1));
        bin.steer_angle_rad = step.steer_angle_rad.or(bin.steer_angle_rad);
        if let Some(w) = step.yaw_rate_radps {
            *yaw_dt += w * step.dt_s;
            *dt += step.dt_s;
        }
        let start = self.samples.last().map_or(f64::NEG_INFINITY, |s| s.t_s);
        if step.t_s - start >= DRIVE_BIN_S {
            self.flush();
        }
    }

    /// The filter closed a correction window at the last step; with
    /// `rear_slipped` its gate found a rear wheel slipping in it, and every
    /// sample of the window is marked so the fit reckons across none of them.
    pub fn window_closed(&mut self, rear_slipped: bool) {
        if rear_slipped {
            let from = self.window_start.min(self.samples.len());
            for s in &mut self.samples[from..] {
                s.rear_slip = true;
            }
            if let Some((bin, _, _)) = self.bin.as_mut() {
                bin.rear_slip = true;
            }
        }
        // The open bin may hold steps of the next window too: it counts in both.
        self.window_start = self.samples.len();
    }

    /// A position fix: a local x and y in metres, or (`geodetic`) latitude
    /// and longitude in degrees (turned into metres around the first fix).
    /// Fixes that are not finite or not later than the last are dropped.
    /// `sigma_m`: the 1σ error per axis the source states (gpsd's
    /// `epx`/`epy`, a `NavSatFix` covariance), used by the fit's weights
    /// and gates; a σ that is not finite and positive counts as unstated.
    pub fn fix(&mut self, t_s: f64, first: f64, second: f64, geodetic: bool, sigma_m: Option<f64>) {
        if self.closed || !(first.is_finite() && second.is_finite()) {
            return;
        }
        let (x_m, y_m) = if geodetic {
            let (lat0, lon0) = *self.origin.get_or_insert((first, second));
            local_m(lat0, lon0, first, second)
        } else {
            (first, second)
        };
        if self.fixes.last().is_none_or(|f| t_s > f.t_s) {
            self.geodetic.push(geodetic.then_some((first, second)));
            self.fixes.push(Fix {
                t_s,
                x_m,
                y_m,
                heading_rad: None,
                sigma_m: sigma_m.filter(|s| s.is_finite() && *s > 0.0),
            });
        }
    }

    /// Closes the open bin; a ring then drops what it no longer keeps.
    fn flush(&mut self) {
        if let Some((mut bin, yaw_dt, dt)) = self.bin.take() {
            bin.yaw_rate_radps = (dt > 0.0).then(|| yaw_dt / dt);
            self.samples.push(bin);
        }
        if let Some(keep_s) = self.keep_s {
            self.trim(keep_s);
        }
    }

    /// Drops the samples and fixes older than `keep_s` before the last
    /// sample, once they are [`RING_SLACK`] of the ring (or it is full).
    fn trim(&mut self, keep_s: f64) {
        let (Some(first), Some(last)) = (
            self.samples.first().map(|s| s.t_s),
            self.samples.last().map(|s| s.t_s),
        ) else {
            return;
        };
        if last - first <= (1.0 + RING_SLACK) * keep_s && self.samples.len() < DRIVE_MAX_SAMPLES {
            return;
        }
        let cut = self
            .samples
            .partition_point(|s| s.t_s < last - keep_s)
            .max(self.samples.len().saturating_sub(DRIVE_MAX_SAMPLES - 1));
        self.samples.drain(..cut);
        self.window_start = self.window_start.saturating_sub(cut);
        let t0 = self.samples.first().map_or(last, |s| s.t_s);
        let old = self.fixes.partition_point(|f| f.t_s < t0);
        self.fixes.drain(..old);
        self.geodetic.drain(..old);
    }

    /// Closes the recording and hands out the fit to run: the fixes outside
    /// the recorded steps say nothing about them and are left out.
    ///
    /// # Errors
    /// [`TooFewSamples`] with fewer than three fixes or three bins; the
    /// recording goes on.
    pub fn job(
        &mut self,
        model: DriveModel,
        base: ParamValues,
        gate: DriveGate,
    ) -> std::result::Result<DriveJob, TooFewSamples> {
        self.flush();
        if self.fixes.len() < 3 || self.samples.len() < 3 {
            return Err(TooFewSamples);
        }
        let (first, last) = (
            self.samples[0].t_s,
            self.samples[self.samples.len() - 1].t_s,
        );
        let fixes = self
            .fixes
            .iter()
            .copied()
            .filter(|f| f.t_s >= first && f.t_s <= last)
            .collect();
        self.closed = true;
        Ok(DriveJob {
            samples: self.samples.clone(),
            fixes,
            model,
            base,
            gate,
        })
    }

    /// The fit failed: record on, to fit again later.
    pub fn reopen(&mut self) {
        self.closed = false;
    }
}

/// Latitude and longitude in degrees as metres east and north of
/// (`lat0`, `lon0`) (equirectangular: centimetres over a few kilometres).
fn local_m(lat0: f64, lon0: f64, lat: f64, lon: f64) -> (f64, f64) {
    (
        EARTH_RADIUS_M * lat0.to_radians().cos() * (lon - lon0).to_radians(),
        EARTH_RADIUS_M * (lat - lat0).to_radians(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step(t_s: f64) -> DriveStep {
        DriveStep {
            t_s,
            rear_left_m: 0.01,
            rear_right_m: 0.012,
            front_m: Some((0.011, 0.013)),
            steer_angle_rad: Some(0.1),
            yaw_rate_radps: Some(0.2),
            dt_s: 0.01,
        }
    }

    #[test]
    fn a_window_with_a_slipping_rear_wheel_marks_its_samples_only() {
        let mut d = DriveRecorder::default();
        // Windows of 0.5 s closing at 0.5, 1.0 (rear slipped) and 1.5 s.
        for k in 0..=150 {
            let t = f64::from(k) * 0.01;
            d.step(&step(t));
            if k > 0 && k % 50 == 0 {
                d.window_closed(k == 100);
            }
        }
        for k in 0..5 {
            d.fix(f64::from(k) * 0.3, f64::from(k), 0.0, false, None);
        }
        let model = DriveModel {
            rear_tread_m: 0.25,
            wheelbase_m: 0.3,
        };
        let job = d
            .job(model, ParamValues::plain(0.25, 0.09), DriveGate::default())
            .unwrap();
        // Marked: every bin (≥ 50 ms, stamped at its last step) holding a step
        // of the window 0.5–1.0 s, those straddling its ends included.
        for s in &job.samples {
            if s.t_s > 0.5 + 1e-9 && s.t_s <= 1.0 + 1e-9 {
                assert!(s.rear_slip, "{s:?}");
            }
            if s.t_s <= 0.5 + 1e-9 || s.t_s > 1.1 + 1e-9 {
                assert!(!s.rear_slip, "{s:?}");
            }
        }
        assert!(job.samples.iter().any(|s| s.rear_slip));
    }

    #[test]
    fn a_fixs_stated_sigma_is_kept_and_a_meaningless_one_is_unstated() {
        let mut d = DriveRecorder::default();
        d.fix(1.0, 0.0, 0.0, false, Some(1.5));
        d.fix(2.0, 1.0, 0.0, false, None);
        d.fix(3.0, 2.0, 0.0, false, Some(f64::NAN));
        d.fix(4.0, 3.0, 0.0, false, Some(-1.0));
        d.fix(5.0, 4.0, 0.0, false, Some(0.0));
        let sigmas: Vec<Option<f64>> = d.fixes.iter().map(|f| f.sigma_m).collect();
        assert_eq!(sigmas, [Some(1.5), None, None, None, None]);
    }

    #[test]
    fn steps_are_binned_and_fixes_outside_the_drive_left_out() {
        let mut d = DriveRecorder::default();
        d.fix(-1.0, 0.0, 0.0, false, None);
        for k in 0..=100 {
            d.step(&step(f64::from(k) * 0.01));
        }
        for k in 0..5 {
            d.fix(f64::from(k) * 0.2, f64::from(k), 0.0, false, None);
        }
        d.fix(0.5, 9.0, 9.0, false, None); // not later than the last: dropped
        d.fix(0.9, f64::NAN, 0.0, false, None); // not finite: dropped
        let base = ParamValues::plain(0.25, 0.09);
        let model = DriveModel {
            rear_tread_m: 0.25,
            wheelbase_m: 0.3,
        };
        let job = d.job(model, base, DriveGate::default()).unwrap();
        assert!(d.is_closed());
        // 1 s of 10 ms steps in bins of at least 50 ms.
        assert!(
            (18..=21).contains(&job.samples.len()),
            "{}",
            job.samples.len()
        );
        let total: f64 = job.samples.iter().map(|s| s.rear_left_m).sum();
        assert!(
            (total - 1.01).abs() < 1e-9,
            "every step's distance is kept: {total}"
        );
        assert!(
            job.samples
                .iter()
                .all(|s| s.yaw_rate_radps.is_some_and(|w| (w - 0.2).abs() < 1e-12))
        );
        assert_eq!(job.fixes.len(), 5, "the fix before the drive is left out");
        d.step(&step(2.0));
        assert_eq!(d.samples.len(), job.samples.len(), "closed: no more steps");
        d.reopen();
        d.step(&step(2.0));
        assert_eq!(d.samples.len(), job.samples.len() + 1);
    }

    #[test]
    fn geodetic_fixes_become_metres_around_the_first() {
        let mut d = DriveRecorder::default();
        d.fix(0.0, 48.0, 11.0, true, None);
        d.fix(1.0, 48.001, 11.0, true, None);
        let north = d.fixes[1].y_m;
        assert!((north - 111.19).abs() < 0.1, "{north}");
        assert!(d.fixes[1].x_m.abs() < 1e-9);
    }

    #[test]
    fn a_ring_keeps_its_window_and_never_closes() {
        let mut d = DriveRecorder::ring(10.0);
        for k in 0..=3000 {
            let t = f64::from(k) * 0.01;
            d.step(&step(t));
            if k % 100 == 0 {
                d.fix(t, 48.0 + t * 1e-5, 11.0, true, None);
            }
        }
        // 30 s driven: between 10 s and 11 s kept.
        let span = d.samples.last().unwrap().t_s - d.samples[0].t_s;
        assert!((10.0..=11.0 + 1e-9).contains(&span), "{span}");
        assert!(d.fixes.len() <= 12 && d.fixes.len() == d.geodetic.len());
        let (samples, fixes) = d.window(5.0);
        let span = samples.last().unwrap().t_s - samples[0].t_s;
        assert!((4.9..=5.0).contains(&span), "{span}");
        assert_eq!(fixes.len(), 5, "{fixes:?}");
        // Around the window's first fix: 1e-5° of latitude a second.
        assert!(fixes[0].y_m.abs() < 1e-9 && fixes[0].x_m.abs() < 1e-9);
        assert!((fixes[4].y_m - 4.0 * 1.112).abs() < 0.01, "{:?}", fixes[4]);
        d.clear();
        assert!(d.window(5.0).0.is_empty());
        d.step(&step(40.0));
        d.step(&step(40.1));
        assert_eq!(d.window(5.0).0.len(), 2, "still a ring after a clear");
    }

    #[test]
    fn too_few_fixes_keep_recording() {
        let mut d = DriveRecorder::default();
        for k in 0..100 {
            d.step(&step(f64::from(k) * 0.01));
        }
        let model = DriveModel {
            rear_tread_m: 0.25,
            wheelbase_m: 0.3,
        };
        let base = ParamValues::plain(0.25, 0.09);
        assert_eq!(d.job(model, base, DriveGate::default()), Err(TooFewSamples));
        assert!(!d.is_closed());
    }
}
