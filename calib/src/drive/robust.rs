//! The robust loss: Cauchy's weights by iteratively reweighted least
//! squares, so that a receiver's jump is down-weighted instead of pulling
//! the whole fit, and the fixes it down-weighted named in the result.

use super::options::Loss;
use super::result::DownWeighted;
use super::{Fit, HEADING_SIGMA_FLOOR_RAD, N_GROUP, POS_SIGMA_FLOOR_M, Problem, Row};

/// Cauchy's constant (95 % asymptotic efficiency on Gaussian residuals).
const CAUCHY_C: f64 = 2.385;
/// A fix whose weight falls below this in every source is named as down-weighted.
pub(super) const DOWN_WEIGHTED: f64 = 0.5;

impl Problem<'_> {
    /// The robust loss's weights from the residuals at `fit` (iteratively
    /// reweighted least squares): per group, the scale from the median of the
    /// fixes' squared residuals (`σ² = median(e²)/median(χ²_m)`, `m` the
    /// components: robust to any share of jumps below one half), then
    /// Cauchy's weight of each fix. With [`Loss::LeastSquares`] all stay 1.
    pub(super) fn update_weights(&self, fit: &mut Fit, horizon_s: f64) {
        if self.options.loss == Loss::LeastSquares {
            return;
        }
        let rows = self.rows(fit, horizon_s, false);
        for group in 0..N_GROUP {
            // Each fix's residual in units of its stated σ (relative to the
            // reference): a fix its receiver calls noisier is not a jump for
            // the scatter it was told to have.
            let mut e2: Vec<(usize, f64)> = Vec::new();
            for r in rows.iter().filter(|r| r.group == group) {
                let e = (r.raw / r.scale).powi(2);
                match e2.last_mut() {
                    Some((f, acc)) if *f == r.fix => *acc += e,
                    _ => e2.push((r.fix, e)),
                }
            }
            if e2.len() < 5 {
                continue;
            }
            let (m, median_chi2, floor) = if group % 2 == 1 {
                (1.0, 0.454_936, HEADING_SIGMA_FLOOR_RAD)
            } else {
                (2.0, 2.0 * std::f64::consts::LN_2, POS_SIGMA_FLOOR_M)
            };
            let mut sorted: Vec<f64> = e2.iter().map(|e| e.1).collect();
            sorted.sort_by(f64::total_cmp);
            let scale2 = (sorted[sorted.len() / 2] / median_chi2).max(floor * floor);
            for (f, e) in e2 {
                fit.weights[f][group] = 1.0 / (1.0 + e / (m * CAUCHY_C * CAUCHY_C * scale2));
            }
        }
    }

    /// The fixes every active source down-weighted, with the residual of the
    /// source that agrees best.
    pub(super) fn down_weighted(&self, fit: &Fit, rows: &[Row]) -> Vec<DownWeighted> {
        let mut e2 = vec![[0.0_f64; 3]; self.fixes.len()];
        let mut used = vec![false; self.fixes.len()];
        for r in rows.iter().filter(|r| r.group % 2 == 0) {
            e2[r.fix][r.group / 2] += r.raw * r.raw;
            used[r.fix] = true;
        }
        (0..self.fixes.len())
            .filter(|&f| used[f])
            .filter_map(|f| {
                let best = (0..3)
                    .filter(|&src| self.active[src])
                    .max_by(|&a, &b| fit.weights[f][a * 2].total_cmp(&fit.weights[f][b * 2]))?;
                let weight = fit.weights[f][best * 2];
                (weight < DOWN_WEIGHTED).then(|| DownWeighted {
                    t_s: self.fixes[f].t_s,
                    residual_m: e2[f][best].sqrt(),
                    weight,
                })
            })
            .collect()
    }
}
