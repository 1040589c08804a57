//! The steering calibration as it is driven (§10): the filter's steps are
//! split into constant-command arcs, each arc is estimated with the
//! calibrated rear set in use, and the map φ = k·u + c is fitted over them.

use crate::run::{RearParams, RevSample};
use crate::steering::{ArcEstimate, ArcOptions, SteeringFit, estimate_arc, fit_steering};

/// An arc ends when the signal moves the nominal road-wheel angle by more
/// than this from the arc's first sample, rad (0.25°): a servo holding a
/// command jitters far less, a new command moves it by degrees.
const ARC_SIGNAL_TOL_RAD: f64 = 0.25 * std::f64::consts::PI / 180.0;
/// Arcs whose signals differ by less than this (nominal angle, rad) count as
/// one command when judging whether the fit has enough distinct ones.
const DISTINCT_SIGNAL_RAD: f64 = 1.0 * std::f64::consts::PI / 180.0;
/// Distinct commands a fit needs: two fix a line, a third checks it.
pub const MIN_STEERING_COMMANDS: usize = 3;

/// What the arcs are estimated with: the nominal gain (to compare signals
/// as road-wheel angles), the rear set in use and the wheelbase.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArcGeometry {
    /// The nominal map's gain, rad per unit of signal.
    pub nominal_gain: f64,
    /// The calibrated rear set in use.
    pub rear: RearParams,
    /// The wheelbase, m.
    pub wheelbase_m: f64,
}

/// Why the arcs cannot be fitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ArcFitError {
    /// Fewer than [`MIN_STEERING_COMMANDS`] distinct commands were driven.
    TooFewCommands,
    /// The fit failed or gave a map that is not finite.
    FitFailed,
}

/// The arcs collected so far and the fit awaiting commit.
#[derive(Debug, Clone, Default)]
pub struct ArcCollector {
    arcs: Vec<ArcEstimate>,
    current: Vec<RevSample>,
    current_m: f64,
    fit: Option<SteeringFit>,
}

impl ArcCollector {
    /// Arcs closed and long enough to estimate.
    pub fn arcs(&self) -> &[ArcEstimate] {
        &self.arcs
    }

    /// Distance of the arc being driven, m.
    pub fn current_m(&self) -> f64 {
        self.current_m
    }

    /// The fit awaiting commit.
    pub fn fit(&self) -> Option<&SteeringFit> {
        self.fit.as_ref()
    }

    /// One step: extends the current arc, or closes it when the signal
    /// changed, the vehicle stopped or the step is unusable. Ignored once a
    /// fit awaits commit.
    pub fn step(
        &mut self,
        sample: RevSample,
        steer_signal_present: bool,
        distance_m: f64,
        moving: bool,
        geometry: &ArcGeometry,
    ) {
        if self.fit.is_some() {
            return;
        }
        let same_command = match self.current.first() {
            Some(first) if steer_signal_present => {
                (geometry.nominal_gain * (sample.steer_signal - first.steer_signal)).abs()
                    <= ARC_SIGNAL_TOL_RAD
            }
            None => true,
            Some(_) => false,
        };
        let usable = moving && distance_m.is_finite() && steer_signal_present;
        if !(usable && same_command) {
            self.close_arc(geometry);
        }
        if usable {
            self.current.push(sample);
            self.current_m += distance_m.abs();
        }
    }

    /// The input lost samples: the arc being driven would have a wrong
    /// curvature, so it is dropped.
    pub fn fault(&mut self) {
        self.current.clear();
        self.current_m = 0.0;
    }

    /// Ends the current arc; keeps its estimate when it is long enough after
    /// the settling time (else it is dropped).
    fn close_arc(&mut self, geometry: &ArcGeometry) {
        let samples = std::mem::take(&mut self.current);
        self.current_m = 0.0;
        if samples.is_empty() {
            return;
        }
        if let Ok(arc) = estimate_arc(
            &samples,
            &geometry.rear,
            geometry.wheelbase_m,
            &ArcOptions::default(),
        ) && arc.curvature_per_m.is_finite()
        {
            self.arcs.push(arc);
        }
    }

    /// Closes the current arc and fits the map over all arcs; the fit then
    /// awaits commit. A line fit over a few dozen arcs takes microseconds, so
    /// it runs where it is asked for.
    ///
    /// # Errors
    /// [`ArcFitError`]; the arcs are kept to drive more and fit again.
    pub fn compute(&mut self, geometry: &ArcGeometry) -> Result<&SteeringFit, ArcFitError> {
        self.close_arc(geometry);
        let mut commands: Vec<f64> = Vec::new();
        for a in &self.arcs {
            if !commands
                .iter()
                .any(|&u| (geometry.nominal_gain * (u - a.command)).abs() < DISTINCT_SIGNAL_RAD)
            {
                commands.push(a.command);
            }
        }
        if commands.len() < MIN_STEERING_COMMANDS {
            return Err(ArcFitError::TooFewCommands);
        }
        match fit_steering(&self.arcs, false) {
            Ok(fit) if fit.gain.is_finite() && fit.offset_rad.is_finite() => {
                Ok(self.fit.insert(fit))
            }
            _ => Err(ArcFitError::FitFailed),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TREAD_M: f64 = 0.25;
    const DIAMETER_M: f64 = 0.09;
    const WHEELBASE_M: f64 = 0.3;
    /// The true map: φ = 0.9·u + 0.02 rad, u in radians of nominal angle.
    fn true_angle_rad(u: f64) -> f64 {
        0.9 * u + 0.02
    }

    fn geometry() -> ArcGeometry {
        ArcGeometry {
            nominal_gain: 1.0,
            rear: RearParams {
                tread_m: TREAD_M,
                left_diameter_m: DIAMETER_M,
                right_diameter_m: DIAMETER_M,
            },
            wheelbase_m: WHEELBASE_M,
        }
    }

    /// `seconds` of driving at 0.5 m/s with command `u`, 100 Hz, from `t_s`.
    fn drive(arcs: &mut ArcCollector, t_s: &mut f64, u: f64, seconds: f64) {
        let kappa = true_angle_rad(u).tan() / WHEELBASE_M;
        let ds = 0.005;
        let circumference = std::f64::consts::PI * DIAMETER_M;
        for _ in 0..(seconds * 100.0) as usize {
            *t_s += 0.01;
            let sample = RevSample {
                t_s: *t_s,
                rear_left_rev: ds * (1.0 - 0.5 * kappa * TREAD_M) / circumference,
                rear_right_rev: ds * (1.0 + 0.5 * kappa * TREAD_M) / circumference,
                front_rev: None,
                steer_signal: u,
            };
            arcs.step(sample, true, ds, true, &geometry());
        }
    }

    #[test]
    fn arcs_split_at_each_new_command_and_fit_the_true_map() {
        let mut arcs = ArcCollector::default();
        let mut t_s = 0.0;
        drive(&mut arcs, &mut t_s, -0.2, 8.0);
        drive(&mut arcs, &mut t_s, 0.1, 8.0);
        assert_eq!(
            arcs.arcs().len(),
            1,
            "a new command closes the arc before it"
        );
        assert_eq!(
            arcs.clone().compute(&geometry()).map(|_| ()),
            Err(ArcFitError::TooFewCommands),
            "two commands fix a line but cannot check it"
        );
        drive(&mut arcs, &mut t_s, 0.3, 8.0);
        let fit = arcs.compute(&geometry()).expect("three commands fit");
        assert_eq!(fit.arcs.len(), 3);
        assert!((fit.gain - 0.9).abs() < 0.01, "{}", fit.gain);
        assert!((fit.offset_rad - 0.02).abs() < 0.005, "{}", fit.offset_rad);
        let (gain_std, offset_std) = fit.std_devs();
        assert!(
            gain_std < 1e-3 && offset_std < 1e-3,
            "{gain_std} {offset_std}"
        );
        // A fit awaits commit: more driving changes nothing.
        drive(&mut arcs, &mut t_s, 0.5, 8.0);
        assert_eq!(arcs.arcs().len(), 3);
        assert_eq!(arcs.current_m(), 0.0);
    }

    #[test]
    fn a_fault_drops_the_arc_being_driven_and_short_arcs_are_dropped() {
        let mut arcs = ArcCollector::default();
        let mut t_s = 0.0;
        drive(&mut arcs, &mut t_s, 0.1, 8.0);
        assert!(arcs.current_m() > 3.9);
        arcs.fault();
        assert_eq!(arcs.current_m(), 0.0);
        // Shorter than the settling time: nothing to estimate.
        drive(&mut arcs, &mut t_s, 0.2, 1.0);
        drive(&mut arcs, &mut t_s, 0.3, 1.0);
        assert!(arcs.arcs().is_empty());
    }
}
