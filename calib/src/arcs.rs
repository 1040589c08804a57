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
