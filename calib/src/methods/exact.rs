//! The exact refinement of `docs/calibration-math.md` §7: Levenberg–Marquardt
//! over q = (ln b, ln E) with the mean diameter held, minimising
//! F(q) = Σ |p_odo,end(q) − p_real,end|² + w² Σ (θ_odo,j(q) − Θ_j)², w = ρ.
//!
//! The heading residuals matter: position-only surfaces have false closures
//! (a semicircle turning about 2π in the odometry), which is also why a
//! result with |θ_odo,j − Θ_j| > π/2 on any run is rejected.

use std::f64::consts::FRAC_PI_2;

use nalgebra::{Matrix2, Vector2};

use super::{CalibrationResult, Method, check_inputs, heading, replayed_result, turns};
use crate::error::{Error, Result};
use crate::run::{RearParams, Run, need_both_directions, replay_rear};
use crate::track::Track;

/// Where the refinement starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ExactStart {
    /// From the heading law's one-shot solution (recommended, §7); from the
    /// used parameters if the heading law fails.
    HeadingLaw,
    /// From the parameters used while recording.
    Used,
}

/// Options of [`exact`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExactOptions {
    /// The starting point.
    pub start: ExactStart,
    /// Include the heading residuals (§7); without them the surface has
    /// false closures (kept for comparison only).
    pub heading_residuals: bool,
    /// Upper bound on LM iterations.
    pub max_iterations: u32,
}

impl Default for ExactOptions {
    fn default() -> Self {
        Self {
            start: ExactStart::HeadingLaw,
            heading_residuals: true,
            max_iterations: 50,
        }
    }
}

/// Central-difference step in log space (§7).
const H: f64 = 1e-6;
/// Largest step in log space (§7).
const MAX_STEP: f64 = 0.3;

struct Problem<'a> {
    runs: &'a [Run],
    mean_diameter_m: f64,
    weight: f64,
    targets: Vec<[f64; 3]>,
}

impl Problem<'_> {
    fn params(&self, q: Vector2<f64>) -> Option<RearParams> {
        RearParams::from_ratio(q[0].exp(), self.mean_diameter_m, q[1].exp()).ok()
    }

    fn residuals(&self, q: Vector2<f64>, out: &mut Vec<f64>) -> Option<f64> {
        let rear = self.params(q)?;
        out.clear();
        for (run, t) in self.runs.iter().zip(&self.targets) {
            let odo = replay_rear(&run.samples, &rear);
            out.push(odo.end.x_m - t[0]);
            out.push(odo.end.y_m - t[1]);
            if self.weight > 0.0 {
                out.push(self.weight * (odo.end.heading_rad - t[2]));
            }
        }
        let f: f64 = out.iter().map(|r| r * r).sum();
        f.is_finite().then_some(f)
    }

    /// JᵀJ and the Jacobian columns by central differences.
    fn jacobian(&self, q: Vector2<f64>) -> Option<(Vec<f64>, Vec<f64>)> {
        let mut plus = Vec::new();
        let mut minus = Vec::new();
        let mut cols = [Vec::new(), Vec::new()];
        for (k, col) in cols.iter_mut().enumerate() {
            let mut dq = Vector2::zeros();
            dq[k] = H;
            self.residuals(q + dq, &mut plus)?;
            self.residuals(q - dq, &mut minus)?;
            *col = plus
                .iter()
                .zip(&minus)
                .map(|(p, m)| (p - m) / (2.0 * H))
                .collect();
        }
        let [a, b] = cols;
        Some((a, b))
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

struct Fit {
    q: Vector2<f64>,
    r: Vec<f64>,
    f: f64,
    iterations: u32,
    converged: bool,
}

/// Levenberg–Marquardt with Marquardt's diagonal scaling and steps capped
/// at [`MAX_STEP`] in log space.
fn levenberg_marquardt(problem: &Problem, q0: Vector2<f64>, max_iterations: u32) -> Result<Fit> {
    let numerical = |context| Error::Numerical { context };
    let mut q = q0;
    let mut r = Vec::new();
    let mut f = problem
        .residuals(q, &mut r)
        .ok_or(numerical("LM start residuals"))?;
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let mut converged = false;
    let mut trial = Vec::new();
    while iterations < max_iterations {
        iterations += 1;
        let (ja, jb) = problem.jacobian(q).ok_or(numerical("LM Jacobian"))?;
        let jtj = Matrix2::new(dot(&ja, &ja), dot(&ja, &jb), dot(&ja, &jb), dot(&jb, &jb));
        let jtr = Vector2::new(dot(&ja, &r), dot(&jb, &r));
        let mut accepted = false;
        let mut step_norm = 0.0;
        for _ in 0..12 {
            let damped = jtj + Matrix2::from_diagonal(&jtj.diagonal()) * lambda;
            let Some(inv) = damped.try_inverse() else {
                lambda *= 10.0;
                continue;
            };
            let mut step = -(inv * jtr);
            let big = step.amax();
            if !big.is_finite() {
                lambda *= 10.0;
                continue;
            }
            if big > MAX_STEP {
                step *= MAX_STEP / big;
            }
            step_norm = step.amax();
            match problem.residuals(q + step, &mut trial) {
                Some(f_new) if f_new <= f => {
                    let gain = f - f_new;
                    q += step;
                    std::mem::swap(&mut r, &mut trial);
                    f = f_new;
                    lambda = (lambda / 10.0).max(1e-12);
                    accepted = true;
                    if step_norm < 1e-10 || gain <= 1e-14 * f.max(1e-300) {
                        converged = true;
                    }
                    break;
                }
                _ => lambda *= 10.0,
            }
        }
        // No decrease even with heavy damping: at the minimum to rounding.
        if !accepted || converged || step_norm < 1e-10 {
            converged = true;
            break;
        }
    }
    Ok(Fit {
        q,
        r,
        f,
        iterations,
        converged,
    })
}

/// The exact method: Levenberg–Marquardt on the replayed runs.
///
/// The result's standard deviations come from s²(JᵀJ)⁻¹ with s² = F/(m−2);
/// its `iterations` and `converged` report the LM run.
///
/// # Errors
/// No run in one of the directions, a numerical failure, or
/// [`Error::FalseClosure`] when the solution turns a run more than π/2 away
/// from its true turn.
pub fn exact(
    runs: &[Run],
    used: &RearParams,
    track: Track,
    options: ExactOptions,
) -> Result<CalibrationResult> {
    check_inputs(runs, used, track)?;
    need_both_directions(runs, "at least one run each way")?;
    let start = match options.start {
        ExactStart::HeadingLaw => heading(runs, used, track).map_or(*used, |r| r.rear),
        ExactStart::Used => *used,
    };
    let problem = Problem {
        runs,
        mean_diameter_m: used.mean_diameter_m(),
        weight: if options.heading_residuals {
            track.radius_m()
        } else {
            0.0
        },
        targets: runs
            .iter()
            .map(|r| {
                let [x, y] = r.real_end_m();
                [x, y, r.true_total_turn_rad()]
            })
            .collect(),
    };
    let numerical = |context| Error::Numerical { context };
    let q0 = Vector2::new(start.tread_m.ln(), start.ratio().ln());
    let Fit {
        q,
        r,
        f,
        iterations,
        converged,
    } = levenberg_marquardt(&problem, q0, options.max_iterations)?;
    let rear = problem.params(q).ok_or(numerical("LM result"))?;
    for (i, (turn, run)) in turns(runs, &rear).iter().zip(runs).enumerate() {
        let err = turn - run.true_total_turn_rad();
        if err.abs() > FRAC_PI_2 {
            return Err(Error::FalseClosure {
                run: i,
                turn_error_rad: err,
            });
        }
    }
    let m = r.len();
    let (tread_std_m, ratio_std) = match problem.jacobian(q) {
        Some((ja, jb)) if m > 2 => {
            let jtj = Matrix2::new(dot(&ja, &ja), dot(&ja, &jb), dot(&ja, &jb), dot(&jb, &jb));
            match jtj.try_inverse() {
                Some(inv) => {
                    let cov = inv * (f / (m - 2) as f64);
                    (
                        Some(rear.tread_m * cov[(0, 0)].max(0.0).sqrt()),
                        Some(rear.ratio() * cov[(1, 1)].max(0.0).sqrt()),
                    )
                }
                None => (None, None),
            }
        }
        _ => (None, None),
    };
    Ok(replayed_result(
        Method::Exact,
        runs,
        used,
        rear,
        track,
        (tread_std_m, ratio_std),
        iterations,
        converged,
    ))
}
