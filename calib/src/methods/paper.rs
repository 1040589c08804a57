//! The paper's centre-of-gravity closed form, sign-consistent as
//! `docs/calibration-math.md` §6–§7 states it, with the parameter updates
//! corrected per §8 (α an over-turn, β a leftward drift, the E update with
//! the tread that was used).

use std::f64::consts::PI;

use super::{
    CalibrationResult, Centroids, Method, centroids, check_inputs, update_from_alpha_beta,
};
use crate::error::Result;
use crate::run::{RearParams, Run, need_both_directions};
use crate::track::Track;

/// Which coordinates of the centres of gravity the closed form uses (§6).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PaperVariant {
    /// α_x, β_x: the least biased single set (§6 "prefer x").
    X,
    /// α_y, β_y: the paper's (13)–(15).
    Y,
    /// The mean of both: least squares over the four coordinates.
    LeastSquares,
}

/// Options of [`paper`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PaperOptions {
    /// Which coordinates to use.
    pub variant: PaperVariant,
    /// 1 for the paper's one shot; more for the fixed-point iteration of §7
    /// (replay with the new parameters and update again).
    pub max_iterations: u32,
}

impl Default for PaperOptions {
    /// Least squares over x and y, one shot: the form whose errors §9 quotes
    /// as "the paper's one-shot equations" (E 0.25 % off in case 2).
    fn default() -> Self {
        Self {
            variant: PaperVariant::LeastSquares,
            max_iterations: 1,
        }
    }
}

/// α and β from the centres of gravity (§6, linear inverse formulas).
pub fn alpha_beta(c: &Centroids, radius_m: f64, variant: PaperVariant) -> (f64, f64) {
    let rho = radius_m;
    let k = 2.0 * (2.0 + PI) * rho;
    let ax = (c.ccw_m[0] + c.cw_m[0]) / (4.0 * rho);
    let bx = (c.ccw_m[0] - c.cw_m[0]) / k;
    let ay = (c.cw_m[1] - c.ccw_m[1]) / (4.0 * rho);
    let by = -(c.ccw_m[1] + c.cw_m[1]) / k;
    match variant {
        PaperVariant::X => (ax, bx),
        PaperVariant::Y => (ay, by),
        PaperVariant::LeastSquares => (0.5 * (ax + ay), 0.5 * (bx + by)),
    }
}

/// Standard deviations of α and β from the spread of the runs' end errors.
fn alpha_beta_std(c: &Centroids, radius_m: f64, variant: PaperVariant) -> (f64, f64) {
    let k = 2.0 * (2.0 + PI) * radius_m;
    let vx = c.ccw_var_m2[0] + c.cw_var_m2[0];
    let vy = c.ccw_var_m2[1] + c.cw_var_m2[1];
    let v = match variant {
        PaperVariant::X => vx,
        PaperVariant::Y => vy,
        PaperVariant::LeastSquares => 0.25 * (vx + vy),
    };
    (v.sqrt() / (4.0 * radius_m), v.sqrt() / k)
}

/// The paper's method: α and β from the centres of gravity of the end
/// errors, then the §7 updates; iterated up to `max_iterations` times until
/// |Δb| < 1 µm and |ΔE| < 1e-7.
///
/// # Errors
/// No run in one of the directions, or an update that leaves the positive reals.
pub fn paper(
    runs: &[Run],
    used: &RearParams,
    track: Track,
    options: PaperOptions,
) -> Result<CalibrationResult> {
    check_inputs(runs, used, track)?;
    need_both_directions(runs, "at least one run each way")?;
    let rho = track.radius_m();
    let first = centroids(runs, used);
    let (alpha, beta) = alpha_beta(&first, rho, options.variant);
    let (sa, sb) = alpha_beta_std(&first, rho, options.variant);
    let mut rear = update_from_alpha_beta(used, alpha, beta, rho)?;
    let mut iterations = 1;
    let mut converged = options.max_iterations <= 1;
    while iterations < options.max_iterations {
        let c = centroids(runs, &rear);
        let (a, b) = alpha_beta(&c, rho, options.variant);
        let next = update_from_alpha_beta(&rear, a, b, rho)?;
        iterations += 1;
        let small = (next.tread_m - rear.tread_m).abs() < 1e-6
            && (next.ratio() - rear.ratio()).abs() < 1e-7;
        rear = next;
        if small {
            converged = true;
            break;
        }
    }
    let some = |v: f64| v.is_finite().then_some(v);
    Ok(CalibrationResult {
        method: match options.variant {
            PaperVariant::X => Method::PaperX,
            PaperVariant::Y => Method::PaperY,
            PaperVariant::LeastSquares => Method::PaperLeastSquares,
        },
        used: *used,
        rear,
        alpha_rad: alpha,
        beta_rad: beta,
        e_max_before_m: first.e_max_m(),
        e_max_after_m: centroids(runs, &rear).e_max_m(),
        tread_std_m: some(used.tread_m * sa / PI),
        ratio_std: some(rear.ratio() * used.tread_m * sb / (2.0 * rho)),
        iterations,
        converged,
        scale_fixed: false,
    })
}
