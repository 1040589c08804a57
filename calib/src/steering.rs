//! Steering calibration without a camera (`docs/calibration-math.md` §10).
//!
//! Drive constant commands u_j (about 2 m each), drop the first seconds, and
//! measure each arc's curvature with *calibrated* rear odometry:
//! κ_j = Σ(d_R − d_L) / (b · Σ(d_R + d_L)/2), which does not depend on D̄
//! and needs no closed circle. Then φ_j = atan(L κ_j) and φ = k·u + c is
//! fitted by least squares. A curvature that varies along a run means slip
//! or a nonlinear map, and is flagged.
//!
//! **Order of operations.** A steering map fitted with *uncalibrated* rear
//! odometry makes the car drive exactly the path on which that odometry
//! closes the loop, so a track calibration that assumes end = start returns
//! the old parameters. [`needs_measured_end_poses`] says when the guided
//! session must ask for measured end poses; refit the steering after the
//! rear calibration.

use std::f64::consts::PI;

use canodom_fusion::SteeringMap;
use nalgebra::{Matrix2, Vector2};

use crate::error::{Error, Result, positive};
use crate::run::{RearParams, RevSample};

/// Where the steering map in use came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SteeringProvenance {
    /// Measured independently of the rear odometry (camera, protractor, data sheet).
    Independent,
    /// Fitted (§10) with rear odometry that was calibrated at the time.
    CalibratedOdometry,
    /// Fitted (§10) with rear odometry that was not yet calibrated: the trap.
    UncalibratedOdometry,
}

/// Whether the runs of calibration round `round` (0 = first) need measured
/// real end poses: yes in the first round when the steering map was fitted
/// from uncalibrated odometry (§10), because then the car drives the path on
/// which the *old* odometry closes and end = start would confirm the old
/// parameters.
pub fn needs_measured_end_poses(steering: SteeringProvenance, round: u32) -> bool {
    steering == SteeringProvenance::UncalibratedOdometry && round == 0
}

/// Options of [`estimate_arc`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArcOptions {
    /// Time dropped at the start of each arc (servo and path settling), in s.
    pub settle_s: f64,
    /// Pieces of equal distance the curvature is compared over.
    pub pieces: usize,
    /// Allowed spread of the pieces' curvatures, relative to |κ|.
    pub varying_rel: f64,
    /// Allowed spread of the pieces' curvatures, absolute, in 1/m.
    pub varying_abs_per_m: f64,
}

impl Default for ArcOptions {
    fn default() -> Self {
        Self {
            settle_s: 2.0,
            pieces: 4,
            varying_rel: 0.05,
            varying_abs_per_m: 0.03,
        }
    }
}

/// What one constant-command arc showed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArcEstimate {
    /// The mean steering signal over the used part.
    pub command: f64,
    /// κ over the used part, left positive, in 1/m.
    pub curvature_per_m: f64,
    /// φ = atan(L κ).
    pub steer_angle_rad: f64,
    /// Distance used, in metres.
    pub distance_m: f64,
    /// Largest minus smallest curvature of the pieces, in 1/m.
    pub curvature_spread_per_m: f64,
    /// The curvature varied along the run more than allowed (slip or a
    /// nonlinear map): do not trust this arc.
    pub varying: bool,
}

/// Curvature of one constant-command arc with calibrated `rear` parameters.
///
/// # Errors
/// A non-positive wheelbase, or too little distance after the settling time.
pub fn estimate_arc(
    samples: &[RevSample],
    rear: &RearParams,
    wheelbase_m: f64,
    options: &ArcOptions,
) -> Result<ArcEstimate> {
    positive("wheelbase_m", wheelbase_m)?;
    let t0 = samples.first().map_or(0.0, |s| s.t_s);
    let used: Vec<(f64, f64, f64)> = samples
        .iter()
        .filter(|s| s.t_s - t0 >= options.settle_s)
        .map(|s| {
            (
                PI * rear.left_diameter_m * s.rear_left_rev,
                PI * rear.right_diameter_m * s.rear_right_rev,
                s.steer_signal,
            )
        })
        .collect();
    let curvature = |part: &[(f64, f64, f64)]| {
        let diff: f64 = part.iter().map(|(l, r, _)| r - l).sum();
        let dist: f64 = part.iter().map(|(l, r, _)| 0.5 * (l + r)).sum();
        (diff / (rear.tread_m * dist), dist)
    };
    let (kappa, distance_m) = curvature(&used);
    if !(distance_m.abs() > 1e-3 && kappa.is_finite()) {
        return Err(Error::InvalidArgument {
            name: "arc distance_m",
            value: distance_m,
            reason: "no distance left after the settling time",
        });
    }
    let pieces = options.pieces.max(1);
    let piece_m = distance_m / pieces as f64;
    let mut sums = vec![(0.0_f64, 0.0_f64); pieces];
    let mut done_m = 0.0;
    for (l, r, _) in &used {
        let p = ((done_m / piece_m).floor().max(0.0) as usize).min(pieces - 1);
        sums[p].0 += r - l;
        sums[p].1 += 0.5 * (l + r);
        done_m += 0.5 * (l + r);
    }
    let spread = sums
        .iter()
        .filter(|(_, d)| d.abs() > 0.0)
        .map(|(diff, d)| diff / (rear.tread_m * d))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), k| {
            (lo.min(k), hi.max(k))
        });
    let curvature_spread_per_m = (spread.1 - spread.0).max(0.0);
    let command = used.iter().map(|(_, _, u)| u).sum::<f64>() / used.len() as f64;
    Ok(ArcEstimate {
        command,
        curvature_per_m: kappa,
        steer_angle_rad: (wheelbase_m * kappa).atan(),
        distance_m,
        curvature_spread_per_m,
        varying: curvature_spread_per_m
            > options.varying_rel * kappa.abs() + options.varying_abs_per_m,
    })
}

/// The fitted steering map with its evidence.
#[derive(Debug, Clone, PartialEq)]
pub struct SteeringFit {
    /// k: radians of road-wheel angle per unit of steering signal.
    pub gain: f64,
    /// c: road-wheel angle at zero signal, in radians.
    pub offset_rad: f64,
    /// φ_j − (k u_j + c) for every arc used, in radians.
    pub residuals_rad: Vec<f64>,
    /// Root mean square of the residuals.
    pub rms_rad: f64,
    /// The arcs the fit used.
    pub arcs: Vec<ArcEstimate>,
    /// Arcs left out because their curvature varied.
    pub dropped_varying: usize,
}

impl SteeringFit {
    /// The steering map to put into the vehicle parameters.
    pub fn map(&self) -> SteeringMap {
        SteeringMap {
            gain: self.gain,
            offset_rad: self.offset_rad,
        }
    }

    /// Standard deviations of the gain and the offset (least squares,
    /// residual variance over n − 2); NaN with no degree of freedom left.
    pub fn std_devs(&self) -> (f64, f64) {
        let n = self.arcs.len() as f64;
        let mean_u = self.arcs.iter().map(|a| a.command).sum::<f64>() / n;
        let sxx: f64 = self.arcs.iter().map(|a| (a.command - mean_u).powi(2)).sum();
        let dof = n - 2.0;
        if dof <= 0.0 || sxx <= 0.0 {
            return (f64::NAN, f64::NAN);
        }
        let var = self.residuals_rad.iter().map(|r| r * r).sum::<f64>() / dof;
        (
            (var / sxx).sqrt(),
            (var * (1.0 / n + mean_u * mean_u / sxx)).sqrt(),
        )
    }
}

/// Least-squares fit of φ = k·u + c over the arcs whose curvature did not
/// vary (all arcs when `keep_varying`).
///
/// # Errors
/// Fewer than two distinct commands left, or a singular fit.
pub fn fit_steering(arcs: &[ArcEstimate], keep_varying: bool) -> Result<SteeringFit> {
    let used: Vec<ArcEstimate> = arcs
        .iter()
        .filter(|a| keep_varying || !a.varying)
        .copied()
        .collect();
    let mut ata = Matrix2::<f64>::zeros();
    let mut atb = Vector2::<f64>::zeros();
    for a in &used {
        let row = Vector2::new(a.command, 1.0);
        ata += row * row.transpose();
        atb += row * a.steer_angle_rad;
    }
    let inv = ata.try_inverse().ok_or(Error::Numerical {
        context: "steering fit needs two distinct commands",
    })?;
    let x = inv * atb;
    let (gain, offset_rad) = (x[0], x[1]);
    if !(gain.is_finite() && offset_rad.is_finite() && gain != 0.0) {
        return Err(Error::Numerical {
            context: "steering fit",
        });
    }
    let residuals_rad: Vec<f64> = used
        .iter()
        .map(|a| a.steer_angle_rad - gain.mul_add(a.command, offset_rad))
        .collect();
    let rms_rad = (residuals_rad.iter().map(|r| r * r).sum::<f64>() / used.len() as f64).sqrt();
    Ok(SteeringFit {
        gain,
        offset_rad,
        residuals_rad,
        rms_rad,
        dropped_varying: arcs.len() - used.len(),
        arcs: used,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::methods::tests::truth;
    use crate::synth;

    const DEG: f64 = PI / 180.0;

    fn truth_with_map() -> canodom_fusion::VehicleParams {
        truth(false, false)
            .with_steering(SteeringMap {
                gain: 0.93 * DEG,
                offset_rad: 0.80 * DEG,
            })
            .unwrap()
    }

    #[test]
    fn noise_free_arcs_give_back_the_map_and_a_ratio_error_shifts_the_offset() {
        let t = truth_with_map();
        let true_rear = RearParams::of(&t);
        let mut arcs = Vec::new();
        let mut arcs_nominal = Vec::new();
        let nominal = RearParams::new(0.30, 0.09, 0.09).unwrap();
        for u in (-20..=20).step_by(5) {
            let s = synth::arc(&t, f64::from(u), 2.2, 0.1, 100.0).unwrap();
            let a = estimate_arc(&s, &true_rear, 0.25, &ArcOptions::default()).unwrap();
            assert!(!a.varying, "{a:?}");
            assert!((a.distance_m - 2.0).abs() < 0.01);
            arcs.push(a);
            arcs_nominal.push(estimate_arc(&s, &nominal, 0.25, &ArcOptions::default()).unwrap());
        }
        let fit = fit_steering(&arcs, false).unwrap();
        println!(
            "noise-free: k = {:.5}, c = {:.4}°, rms {:.2e}°",
            fit.gain / DEG,
            fit.offset_rad / DEG,
            fit.rms_rad / DEG
        );
        assert!((fit.gain / DEG - 0.93).abs() < 1e-9 && (fit.offset_rad / DEG - 0.80).abs() < 1e-9);
        assert!(fit.rms_rad < 1e-9);
        // §10 sensitivity: with nominal rear wheels k shrinks and c drops.
        let bad = fit_steering(&arcs_nominal, false).unwrap();
        println!(
            "nominal rear: k = {:.4}, c = {:.3}°",
            bad.gain / DEG,
            bad.offset_rad / DEG
        );
        assert!(bad.gain < fit.gain && bad.offset_rad < fit.offset_rad);
    }

    #[test]
    fn varying_curvature_is_flagged_and_left_out() {
        let t = truth_with_map();
        let rear = RearParams::of(&t);
        let mut s = synth::arc(&t, 10.0, 2.2, 0.1, 100.0).unwrap();
        // The second half of the run turns tighter (slip or a nonlinear map).
        let half = s.len() / 2;
        let tighter = synth::arc(&t, 14.0, 2.2, 0.1, 100.0).unwrap();
        for (a, b) in s[half..].iter_mut().zip(&tighter) {
            a.rear_left_rev = b.rear_left_rev;
            a.rear_right_rev = b.rear_right_rev;
        }
        let a = estimate_arc(&s, &rear, 0.25, &ArcOptions::default()).unwrap();
        assert!(a.varying && a.curvature_spread_per_m > 0.05, "{a:?}");
        let good = estimate_arc(
            &synth::arc(&t, -5.0, 2.2, 0.1, 100.0).unwrap(),
            &rear,
            0.25,
            &ArcOptions::default(),
        )
        .unwrap();
        let good2 = estimate_arc(
            &synth::arc(&t, 5.0, 2.2, 0.1, 100.0).unwrap(),
            &rear,
            0.25,
            &ArcOptions::default(),
        )
        .unwrap();
        let fit = fit_steering(&[a, good, good2], false).unwrap();
        assert_eq!((fit.dropped_varying, fit.arcs.len()), (1, 2));
        assert!(fit_steering(&[a, good], false).is_err(), "one command left");
        assert!(estimate_arc(&s[..100], &rear, 0.25, &ArcOptions::default()).is_err());
    }

    #[test]
    fn end_poses_are_needed_only_in_the_trap() {
        assert!(needs_measured_end_poses(
            SteeringProvenance::UncalibratedOdometry,
            0
        ));
        assert!(!needs_measured_end_poses(
            SteeringProvenance::UncalibratedOdometry,
            1
        ));
        assert!(!needs_measured_end_poses(
            SteeringProvenance::CalibratedOdometry,
            0
        ));
        assert!(!needs_measured_end_poses(
            SteeringProvenance::Independent,
            0
        ));
    }
}
