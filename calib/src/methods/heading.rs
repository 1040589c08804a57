//! The heading law of `docs/calibration-math.md` §6: per run, the odometry total
//! turn θ_o = g·Θ + c·P (Θ the true total turn, P the odometry length),
//! fitted by linear least squares in one shot.
//!
//! With P the *odometry* length the law is exact, not first order: θ_o and P
//! are both linear in the two wheels' revolutions, so (g, c) is a
//! reparametrisation of (π D_R/b, π D_L/b), and the §7 updates
//! E_new = E_used (1 − c b/2)/(1 + c b/2), b_new = 2π D̄ / (π D_R/b + π D_L/b)
//! hold exactly (for E_used = 1, b_new = g·b_used).

use std::f64::consts::PI;

use nalgebra::{Matrix2, Vector2};

use super::{CalibrationResult, Method, check_inputs, replayed_result};
use crate::error::{Error, Result, finite};
use crate::run::{RearParams, Run, need_both_directions, replay_rear};
use crate::track::Track;

/// The heading law, one shot.
///
/// # Errors
/// No run in one of the directions, a singular fit, or a fit that implies
/// non-positive parameters.
pub fn heading(runs: &[Run], used: &RearParams, track: Track) -> Result<CalibrationResult> {
    check_inputs(runs, used, track)?;
    need_both_directions(runs, "at least one run each way")?;
    let mut ata = Matrix2::<f64>::zeros();
    let mut atb = Vector2::<f64>::zeros();
    let mut rows = Vec::with_capacity(runs.len());
    for run in runs {
        let odo = replay_rear(&run.samples, used);
        let a = Vector2::new(run.true_total_turn_rad(), odo.length_m);
        ata += a * a.transpose();
        atb += a * odo.end.heading_rad;
        rows.push((a, odo.end.heading_rad));
    }
    let inv = ata.try_inverse().ok_or(Error::Numerical {
        context: "heading law normal equations",
    })?;
    let x = inv * atb;
    let (g, c) = (
        finite("heading law g", x[0])?,
        finite("heading law c", x[1])?,
    );
    let b = used.tread_m;
    let p = PI * used.right_diameter_m * (1.0 / b - 0.5 * c) / g;
    let q = PI * used.left_diameter_m * (1.0 / b + 0.5 * c) / g;
    if !(p > 0.0 && q > 0.0) {
        return Err(Error::Numerical {
            context: "heading law implies a non-positive diameter",
        });
    }
    let rear = RearParams::from_ratio(
        2.0 * PI * used.mean_diameter_m() / (p + q),
        used.mean_diameter_m(),
        p / q,
    )?;
    // Covariance of (g, c) from the residuals, propagated to first order.
    let dof = runs.len().saturating_sub(2);
    let (tread_std_m, ratio_std) = if dof > 0 {
        let rss: f64 = rows.iter().map(|(a, t)| (t - a.dot(&x)).powi(2)).sum();
        let cov = inv * (rss / dof as f64);
        let sg = cov[(0, 0)].max(0.0).sqrt();
        let sc = cov[(1, 1)].max(0.0).sqrt();
        (
            Some(rear.tread_m * sg / g.abs()),
            Some(rear.ratio() * b * sc),
        )
    } else {
        (None, None)
    };
    Ok(replayed_result(
        Method::Heading,
        runs,
        used,
        rear,
        track,
        (tread_std_m, ratio_std),
        1,
        true,
    ))
}
