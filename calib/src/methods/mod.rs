//! The calibration methods and their common result.
//!
//! Every method is a pure function of the accepted runs and the rear
//! parameters used while recording them ([`RearParams`]); the runs hold
//! wheel revolutions, so any candidate parameters can be replayed.
//!
//! **What is estimated.** A closed track cannot see a uniform scale of both
//! wheels (`docs/calibration-math.md` §4): every method keeps the mean rear
//! diameter D̄ it was given and returns the *effective* tread
//! b_eff = b_true · D̄_used / D̄_true together with the true ratio
//! E = D_R/D_L. Headings are then right and distances keep the error of D̄.
//! [`CalibrationResult::with_known_length`] fixes the scale from a run of
//! known length; then the tread is the true one.
//!
//! - [`paper()`]: the paper's centre-of-gravity closed form, sign-consistent (§6–§8),
//!   one shot or iterated.
//! - [`heading()`]: the heading law (§6), linear, one shot.
//! - [`exact()`]: Levenberg–Marquardt on the replayed runs with heading residuals (§7).

mod exact;
mod heading;
mod paper;

pub use exact::{ExactOptions, ExactStart, exact};
pub use heading::heading;
pub use paper::{PaperOptions, PaperVariant, paper};

use std::f64::consts::PI;

use crate::error::{Error, Result, finite, positive};
use crate::run::{RearParams, Run, replay_rear};
use crate::track::{Direction, Track};

/// Which method produced a result. Stable numeric [`Method::code`]s.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Method {
    /// Centre-of-gravity closed form on the x coordinates.
    PaperX,
    /// Centre-of-gravity closed form on the y coordinates (the paper's own, most biased).
    PaperY,
    /// Centre-of-gravity closed form, least squares over x and y.
    PaperLeastSquares,
    /// The heading law.
    Heading,
    /// Levenberg–Marquardt refinement with heading residuals.
    Exact,
}

impl Method {
    /// Stable numeric code for status frames.
    pub fn code(self) -> u8 {
        match self {
            Method::PaperX => 1,
            Method::PaperY => 2,
            Method::PaperLeastSquares => 3,
            Method::Heading => 4,
            Method::Exact => 5,
        }
    }
}

/// The outcome of a calibration.
///
/// It estimates the **effective** rear tread (§4): the mean rear diameter is
/// not observable from a closed track, so it is kept as used and the tread
/// absorbs its error, unless [`CalibrationResult::with_known_length`] fixed
/// the scale (then [`CalibrationResult::scale_fixed`] is true).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalibrationResult {
    /// The method that produced it.
    pub method: Method,
    /// The rear parameters used while recording.
    pub used: RearParams,
    /// The calibrated rear tread and diameters (mean diameter as used,
    /// unless the scale was fixed).
    pub rear: RearParams,
    /// α: odometry over-turn per semicircle with the used parameters (§2).
    pub alpha_rad: f64,
    /// β: leftward heading drift per straight of 2ρ with the used parameters (§2).
    pub beta_rad: f64,
    /// E_max (the larger centre-of-gravity error) of the calibration runs
    /// with the used parameters.
    pub e_max_before_m: f64,
    /// E_max of the calibration runs with the calibrated parameters.
    pub e_max_after_m: f64,
    /// Standard deviation of the tread (None when the runs cannot tell).
    pub tread_std_m: Option<f64>,
    /// Standard deviation of the ratio E (None when the runs cannot tell).
    pub ratio_std: Option<f64>,
    /// Iterations (1 for one-shot methods).
    pub iterations: u32,
    /// Whether an iterative method met its convergence test (always true one shot).
    pub converged: bool,
    /// Whether a known-length run fixed the mean diameter.
    pub scale_fixed: bool,
}

impl CalibrationResult {
    /// The calibrated rear tread.
    pub fn tread_m(&self) -> f64 {
        self.rear.tread_m
    }

    /// The calibrated diameter ratio E = D_R / D_L.
    pub fn ratio(&self) -> f64 {
        self.rear.ratio()
    }

    /// Fixes the scale (§4): multiplies both rear diameters, and the tread
    /// with them so that headings do not change, by the factor that makes
    /// the odometry length of `run` equal `known_length_m`.
    ///
    /// # Errors
    /// A non-positive known length or a run without distance.
    pub fn with_known_length(&self, run: &Run, known_length_m: f64) -> Result<Self> {
        positive("known_length_m", known_length_m)?;
        let odo_m = run.rear_odometry(&self.rear).length_m;
        let scale = positive("odometry length of the known-length run", odo_m)
            .map(|odo| known_length_m / odo)?;
        let mut out = *self;
        out.rear = RearParams::new(
            self.rear.tread_m * scale,
            self.rear.left_diameter_m * scale,
            self.rear.right_diameter_m * scale,
        )?;
        out.scale_fixed = true;
        Ok(out)
    }
}

/// Centres of gravity of the end errors per direction, with their spreads.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Centroids {
    /// ē of the CCW runs (x, y) in metres.
    pub ccw_m: [f64; 2],
    /// ē of the CW runs.
    pub cw_m: [f64; 2],
    /// Variance of the CCW mean (x, y), NaN with fewer than two runs.
    pub ccw_var_m2: [f64; 2],
    /// Variance of the CW mean.
    pub cw_var_m2: [f64; 2],
    /// Runs each way.
    pub counts: (usize, usize),
}

impl Centroids {
    /// E_max: the larger distance of the two centres of gravity from zero
    /// (a direction without runs counts 0).
    pub fn e_max_m(&self) -> f64 {
        let n = |v: [f64; 2], c: usize| if c == 0 { 0.0 } else { v[0].hypot(v[1]) };
        n(self.ccw_m, self.counts.0).max(n(self.cw_m, self.counts.1))
    }
}

/// The centres of gravity of the end errors e = odometry end − real end
/// of `runs` replayed with `rear`.
pub fn centroids(runs: &[Run], rear: &RearParams) -> Centroids {
    let mut acc = [[0.0_f64; 2]; 2];
    let mut acc2 = [[0.0_f64; 2]; 2];
    let mut counts = [0usize; 2];
    for run in runs {
        let e = run.end_error_m(rear);
        let i = usize::from(run.direction == Direction::Cw);
        counts[i] += 1;
        for k in 0..2 {
            acc[i][k] += e[k];
            acc2[i][k] += e[k] * e[k];
        }
    }
    let mean = |i: usize| {
        if counts[i] == 0 {
            [0.0, 0.0]
        } else {
            let n = counts[i] as f64;
            [acc[i][0] / n, acc[i][1] / n]
        }
    };
    let var_of_mean = |i: usize| {
        if counts[i] < 2 {
            return [f64::NAN, f64::NAN];
        }
        let n = counts[i] as f64;
        let m = mean(i);
        let v = |k: usize| ((acc2[i][k] - n * m[k] * m[k]) / (n - 1.0)).max(0.0) / n;
        [v(0), v(1)]
    };
    Centroids {
        ccw_m: mean(0),
        cw_m: mean(1),
        ccw_var_m2: var_of_mean(0),
        cw_var_m2: var_of_mean(1),
        counts: (counts[0], counts[1]),
    }
}

/// E_max of `runs` replayed with `rear` (validation: fresh runs, real ends
/// as measured).
pub fn e_max_m(runs: &[Run], rear: &RearParams) -> f64 {
    centroids(runs, rear).e_max_m()
}

/// The §7 update from α and β measured with `used`:
/// b_new = b_used (1 + α/π), E_new = E_used (4ρ − b_used β)/(4ρ + b_used β),
/// mean diameter kept.
///
/// # Errors
/// [`Error::Numerical`] when the update leaves the positive reals.
pub fn update_from_alpha_beta(
    used: &RearParams,
    alpha_rad: f64,
    beta_rad: f64,
    radius_m: f64,
) -> Result<RearParams> {
    let b = used.tread_m;
    let tread = finite("tread update", b * (1.0 + alpha_rad / PI))?;
    let ratio = finite(
        "ratio update",
        used.ratio() * (4.0 * radius_m - b * beta_rad) / (4.0 * radius_m + b * beta_rad),
    )?;
    if tread <= 0.0 || ratio <= 0.0 {
        return Err(Error::Numerical {
            context: "update left the positive reals",
        });
    }
    RearParams::from_ratio(tread, used.mean_diameter_m(), ratio)
}

/// A result whose α, β and end errors all follow from replaying the runs with
/// the used and the new parameters (the heading law and the exact method; the
/// paper's closed form reports its own measured α, β instead).
#[allow(clippy::too_many_arguments)]
pub(crate) fn replayed_result(
    method: Method,
    runs: &[Run],
    used: &RearParams,
    rear: RearParams,
    track: Track,
    (tread_std_m, ratio_std): (Option<f64>, Option<f64>),
    iterations: u32,
    converged: bool,
) -> CalibrationResult {
    let (alpha_rad, beta_rad) = alpha_beta_between(used, &rear, track.radius_m());
    CalibrationResult {
        method,
        used: *used,
        rear,
        alpha_rad,
        beta_rad,
        e_max_before_m: centroids(runs, used).e_max_m(),
        e_max_after_m: centroids(runs, &rear).e_max_m(),
        tread_std_m,
        ratio_std,
        iterations,
        converged,
        scale_fixed: false,
    }
}

/// α and β that the change from `used` to `new` corrects (the inverse of
/// [`update_from_alpha_beta`]): how the used parameters mis-turned.
pub(crate) fn alpha_beta_between(used: &RearParams, new: &RearParams, radius_m: f64) -> (f64, f64) {
    let alpha = PI * (new.tread_m / used.tread_m - 1.0);
    let (eu, en) = (used.ratio(), new.ratio());
    let beta = 4.0 * radius_m * (eu - en) / (used.tread_m * (eu + en));
    (alpha, beta)
}

/// Rejects runs with no samples and checks the inputs all methods share.
pub(crate) fn check_inputs(runs: &[Run], used: &RearParams, track: Track) -> Result<()> {
    RearParams::new(used.tread_m, used.left_diameter_m, used.right_diameter_m)?;
    positive("radius_m", track.radius_m())?;
    if let Some(i) = runs.iter().position(|r| r.samples.is_empty()) {
        return Err(Error::InvalidArgument {
            name: "run without samples",
            value: i as f64,
            reason: "every run needs samples",
        });
    }
    Ok(())
}

/// The total turn of every run replayed with `rear`.
pub(crate) fn turns(runs: &[Run], rear: &RearParams) -> Vec<f64> {
    runs.iter()
        .map(|r| replay_rear(&r.samples, rear).end.heading_rad)
        .collect()
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::synth;
    use canodom_fusion::{VehicleParams, WheelSet};

    /// §9's truth with optional tape on the rear wheels (3.5 % on a diameter).
    pub(crate) fn truth(tape_left: bool, tape_right: bool) -> VehicleParams {
        synth::section9_truth(tape_left, tape_right).unwrap()
    }

    pub(crate) fn used() -> RearParams {
        RearParams::new(0.30, 0.09, 0.09).unwrap()
    }

    pub(crate) fn clean_runs(truth: &VehicleParams, per_dir: usize, rate_hz: f64) -> Vec<Run> {
        let track = Track::new(0.78).unwrap();
        let mut runs = Vec::new();
        for dir in Direction::BOTH {
            for _ in 0..per_dir {
                runs.push(Run {
                    direction: dir,
                    samples: synth::lap(truth, track, dir, 0.1, rate_hz).unwrap(),
                    faults: vec![],
                    measured_end: None,
                });
            }
        }
        runs
    }

    /// (b_eff, E) of the truth as seen with the used mean diameter (§4).
    pub(crate) fn effective(truth: &VehicleParams, used: &RearParams) -> (f64, f64) {
        let t = RearParams::of(truth);
        (
            t.tread_m * used.mean_diameter_m() / t.mean_diameter_m(),
            t.ratio(),
        )
    }

    fn rel(a: f64, b: f64) -> f64 {
        (a / b - 1.0).abs()
    }

    #[test]
    fn every_method_recovers_the_effective_tread_and_ratio_noise_free() {
        let track = Track::new(0.78).unwrap();
        for (tl, tr) in [(false, false), (false, true), (true, false), (true, true)] {
            let truth = truth(tl, tr);
            let runs = clean_runs(&truth, 1, 20.0);
            let u = used();
            let (b_eff, e_true) = effective(&truth, &u);
            let iterated = |variant| PaperOptions {
                variant,
                max_iterations: 30,
            };
            let results = [
                paper(&runs, &u, track, iterated(PaperVariant::X)).unwrap(),
                paper(&runs, &u, track, iterated(PaperVariant::Y)).unwrap(),
                paper(&runs, &u, track, iterated(PaperVariant::LeastSquares)).unwrap(),
                heading(&runs, &u, track).unwrap(),
                exact(&runs, &u, track, ExactOptions::default()).unwrap(),
            ];
            for r in results {
                println!(
                    "tape L{tl} R{tr} {:?}: b {:.6} (eff {:.6}) E {:.7} (true {:.7}) iters {} Emax {:.4}→{:.2e} m",
                    r.method,
                    r.tread_m(),
                    b_eff,
                    r.ratio(),
                    e_true,
                    r.iterations,
                    r.e_max_before_m,
                    r.e_max_after_m
                );
                assert!(rel(r.tread_m(), b_eff) < 1e-5, "{r:?}");
                assert!(rel(r.ratio(), e_true) < 1e-5, "{r:?}");
                assert!(r.converged);
                assert!(rel(r.rear.mean_diameter_m(), u.mean_diameter_m()) < 1e-12);
            }
        }
    }

    #[test]
    fn alpha_beta_signs_follow_the_conventions() {
        // b_used > b_true: under-turn, α < 0; E_used < E_true: β < 0.
        let track = Track::new(0.78).unwrap();
        let truth = truth(false, false);
        let runs = clean_runs(&truth, 1, 20.0);
        let r = paper(&runs, &used(), track, PaperOptions::default()).unwrap();
        assert!(r.alpha_rad < 0.0 && r.beta_rad < 0.0, "{r:?}");
        assert!(r.e_max_after_m < 0.5 * r.e_max_before_m, "{r:?}");
        let h = heading(&runs, &used(), track).unwrap();
        assert!(
            (h.alpha_rad - r.alpha_rad).abs() < 0.02 && (h.beta_rad - r.beta_rad).abs() < 0.02,
            "{h:?}"
        );
    }

    #[test]
    fn known_length_run_fixes_the_scale() {
        let track = Track::new(0.78).unwrap();
        let truth = truth(true, true);
        let runs = clean_runs(&truth, 1, 20.0);
        let r = exact(&runs, &used(), track, ExactOptions::default()).unwrap();
        let t = RearParams::of(&truth);
        assert!(
            rel(r.tread_m(), t.tread_m) > 0.02,
            "the tape must show in the tread"
        );
        let fixed = r.with_known_length(&runs[0], track.length_m()).unwrap();
        assert!(fixed.scale_fixed);
        assert!(rel(fixed.tread_m(), t.tread_m) < 1e-6, "{fixed:?}");
        assert!(rel(fixed.rear.left_diameter_m, t.left_diameter_m) < 1e-6);
        assert!(rel(fixed.rear.right_diameter_m, t.right_diameter_m) < 1e-6);
        assert!(r.with_known_length(&runs[0], -1.0).is_err());
    }

    #[test]
    fn methods_refuse_runs_in_one_direction_only() {
        let track = Track::new(0.78).unwrap();
        let mut runs = clean_runs(&truth(false, false), 1, 10.0);
        runs.pop();
        assert!(matches!(
            heading(&runs, &used(), track),
            Err(Error::NotEnoughRuns { .. })
        ));
        assert!(paper(&runs, &used(), track, PaperOptions::default()).is_err());
        assert!(exact(&runs, &used(), track, ExactOptions::default()).is_err());
        assert!(exact(&[], &used(), track, ExactOptions::default()).is_err());
    }

    #[test]
    fn position_only_refinement_finds_the_false_closure() {
        // §7: truth (30 cm, 1.15); position-only LM from nominal settles on a
        // false closure, which the heading check rejects; with heading
        // residuals it finds the truth.
        let track = Track::new(0.78).unwrap();
        let (l, r) = canodom_fusion::params::rear_diameters_for_ratio(0.09, 1.15);
        let mut d = WheelSet::splat(0.09);
        d.rear_left = l;
        d.rear_right = r;
        let truth = VehicleParams::nominal(0.25, 0.30, 0.09, 1000)
            .unwrap()
            .with_diameters(d)
            .unwrap();
        let runs = clean_runs(&truth, 1, 10.0);
        let position_only = ExactOptions {
            start: ExactStart::Used,
            heading_residuals: false,
            max_iterations: 100,
        };
        let res = exact(&runs, &used(), track, position_only);
        println!("position-only from nominal: {res:?}");
        assert!(matches!(res, Err(Error::FalseClosure { .. })), "{res:?}");
        let good = exact(&runs, &used(), track, ExactOptions::default()).unwrap();
        assert!(rel(good.ratio(), 1.15) < 1e-5 && rel(good.tread_m(), 0.30) < 1e-5);
        let s = good.tread_std_m.unwrap();
        assert!(s.is_finite() && s < 1e-5);
    }
}
