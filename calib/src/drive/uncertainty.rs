//! How sure the fit is: the sandwich covariance (fixes' and inputs' noise,
//! autocorrelation counted), which parameters the drive tells, and the
//! delete-a-block jackknife that bounds each σ from below by the model's
//! own error along the drive.

use super::{
    Fit, GAIN, LATENCY, N_GLOBAL, N_GROUP, N_LOCAL, OFFSET, Problem, Row, SCALE, STEER, YAW,
};
use crate::error::{Error, Result};
use nalgebra::DMatrix;

/// Blocks of the delete-a-block jackknife (see `Problem::jackknife_sigma`):
/// at most this many, each of at least [`JACKKNIFE_MIN_FIXES`] fixes.
const JACKKNIFE_BLOCKS: usize = 6;
/// Fewest fixes in a jackknife block: a block must be longer than the turn
/// or the slip whose model error it is to reveal (ten fixes: ten seconds of
/// a 1 Hz receiver, about one turn of a road car).
const JACKKNIFE_MIN_FIXES: usize = 10;

impl Problem<'_> {
    /// Covariance of the globals (see the module documentation).
    pub(super) fn covariance(&self, fit: &Fit) -> Result<DMatrix<f64>> {
        let rows = self.rows(fit, f64::INFINITY, true);
        let (h, _) = self.normal(fit, &rows);
        let h = self.with_ridge(h);
        let n = h.nrows();
        let tau = self.autocorrelation_times(&rows);
        // Per fix, the sum of its rows' scores.
        let mut scores: Vec<Vec<(usize, f64)>> = vec![Vec::new(); self.fixes.len()];
        for row in &rows {
            let w = tau[row.group].sqrt() * row.r;
            scores[row.fix].extend(row.jac.iter().map(|&(c, j)| (c, j * w)));
        }
        let mut s = DMatrix::zeros(n, n);
        for score in &scores {
            let mut dense: Vec<(usize, f64)> = Vec::new();
            for &(c, v) in score {
                match dense.iter_mut().find(|(d, _)| *d == c) {
                    Some(e) => e.1 += v,
                    None => dense.push((c, v)),
                }
            }
            for &(a, va) in &dense {
                for &(b, vb) in &dense {
                    s[(a, b)] += va * vb;
                }
            }
        }
        self.add_input_noise(fit, &rows, &mut s);
        let n_rows = rows.len() as f64;
        let n_free = (N_GLOBAL - fit.fixed.iter().filter(|&&f| f).count()) as f64
            + (3 * self.segments.len()) as f64;
        s *= n_rows / (n_rows - n_free).max(1.0);
        for i in 0..N_GLOBAL {
            s[(i, i)] += if fit.fixed[i] {
                1.0
            } else {
                1.0 / self.prior_sigma[i].powi(2)
            };
        }
        let chol = h.cholesky().ok_or(Error::Numerical {
            context: "drive calibration: covariance",
        })?;
        let mut e = DMatrix::zeros(n, N_GLOBAL);
        for i in 0..N_GLOBAL {
            e[(i, i)] = 1.0;
        }
        let x = chol.solve(&e);
        Ok(x.transpose() * s * x)
    }

    /// Adds to the score covariance `s` what the yaw-rate and steering
    /// signals' white noise does to the fit. The residual rows cannot show
    /// it: noise on every sample integrates into a heading random walk whose
    /// slow part the fit takes for a bias or a start heading. A heading
    /// error `δ` entering at sample `k` moves every later fix `j` of the
    /// segment by `δ·J(p_j − p_k)` (J: a quarter turn) and its heading by
    /// `δ`, so it changes the whitened score by `δ·u_k`; with the input's
    /// noise σ per sample and `c_k = ∂Δθ_k/∂input`, `s` gains
    /// `Σ_k σ² c_k² u_k u_kᵀ`. (A signal held over several samples, sent
    /// at a lower rate, is counted as if each sample were new: a small
    /// underestimate.)
    fn add_input_noise(&self, fit: &Fit, rows: &[Row], s: &mut DMatrix<f64>) {
        let g: Vec<f64> = fit.p.rows(0, N_GLOBAL).iter().copied().collect();
        for (si, seg) in self.segments.iter().enumerate() {
            let base = N_GLOBAL + N_LOCAL * si;
            let local = |c: usize| if c < N_GLOBAL { c } else { c - base + N_GLOBAL };
            let global = |c: usize| if c < N_GLOBAL { c } else { c - N_GLOBAL + base };
            for src in [YAW, STEER] {
                let sigma_in = self.prep.noise[src];
                if !self.active[src] || sigma_in <= 0.0 {
                    continue;
                }
                // Whitened derivatives of each fix's rows, per unit of
                // position (x, y) and heading.
                let n = seg.fixes.len();
                let mut per_fix = vec![[[0.0; N_GLOBAL + N_LOCAL]; 3]; n];
                for row in rows
                    .iter()
                    .filter(|r| r.segment == si && r.group / 2 == src)
                {
                    let Ok(j) = seg.fixes.binary_search(&row.fix) else {
                        continue;
                    };
                    let unit = 1.0 / (fit.sigma[row.group] * row.scale);
                    for &(c, v) in &row.jac {
                        per_fix[j][row.component][local(c)] += v * unit;
                    }
                }
                // World poses of the reckoning at every sample.
                let at = self.at(seg, g[LATENCY]);
                let end = at[n - 1].0 + 1;
                let path = self.path(seg, src, &g, end);
                let (i0, f0) = at[0];
                let (a, b) = (path[i0 - seg.start], path[i0 + 1 - seg.start]);
                let origin: [f64; 3] = [0, 1, 2].map(|c| a[c] + f0 * (b[c] - a[c]));
                let turn = fit.p[base + 2 + src] - origin[2];
                let (sn, cs) = turn.sin_cos();
                let world = |p: &[f64; 3]| {
                    let (dx, dy) = (p[0] - origin[0], p[1] - origin[1]);
                    (
                        fit.p[base] + cs * dx - sn * dy,
                        fit.p[base + 1] + sn * dx + cs * dy,
                    )
                };
                let fix_pos: Vec<(f64, f64)> = at
                    .iter()
                    .map(|&(i, f)| {
                        let (a, b) = (path[i - seg.start], path[i + 1 - seg.start]);
                        world(&[0, 1, 2].map(|c| a[c] + f * (b[c] - a[c])))
                    })
                    .collect();
                // Suffix sums over the fixes after sample k: u_k = A + y_k·Bx − x_k·By.
                let mut acc = [[0.0; N_GLOBAL + N_LOCAL]; 3];
                let mut local_s = [[0.0; N_GLOBAL + N_LOCAL]; N_GLOBAL + N_LOCAL];
                let mut j = n;
                for k in (i0 + 1..=end).rev() {
                    while j > 1 && at[j - 1].0 >= k {
                        j -= 1;
                        let (xj, yj) = fix_pos[j];
                        for c in 0..N_GLOBAL + N_LOCAL {
                            let [jx, jy, jh] = [0, 1, 2].map(|m| per_fix[j][m][c]);
                            acc[0][c] += -jx * yj + jy * xj + jh;
                            acc[1][c] += jx;
                            acc[2][c] += jy;
                        }
                    }
                    if j >= n {
                        continue;
                    }
                    let ck = if src == YAW {
                        (self.prep.t[k] - self.prep.t[k - 1]) / g[SCALE]
                    } else {
                        let phi = self
                            .prep
                            .steer
                            .as_ref()
                            .map_or(0.0, |p| 0.5 * (p[k - 1] + p[k]));
                        let (d, _) = self.increment(src, &g, k);
                        let sec = 1.0 / g[GAIN].mul_add(phi, g[OFFSET]).cos();
                        d * g[GAIN] * sec * sec / self.model.wheelbase_m
                    };
                    let w = (sigma_in * ck).powi(2);
                    if w == 0.0 {
                        continue;
                    }
                    let (xk, yk) = world(&path[k - seg.start]);
                    let u: Vec<f64> = (0..N_GLOBAL + N_LOCAL)
                        .map(|c| acc[0][c] + yk * acc[1][c] - xk * acc[2][c])
                        .collect();
                    for (a, ua) in u.iter().enumerate() {
                        for (b, ub) in u.iter().enumerate() {
                            local_s[a][b] += w * ua * ub;
                        }
                    }
                }
                for a in 0..N_GLOBAL + N_LOCAL {
                    for b in 0..N_GLOBAL + N_LOCAL {
                        s[(global(a), global(b))] += local_s[a][b];
                    }
                }
            }
        }
    }

    /// Each group's integrated autocorrelation time over its residual
    /// series (per segment and component, in fix order), at least 1.
    fn autocorrelation_times(&self, rows: &[Row]) -> [f64; N_GROUP] {
        let mut tau = [1.0; N_GROUP];
        for (group, t) in tau.iter_mut().enumerate() {
            let mut series: Vec<Vec<f64>> = Vec::new();
            for si in 0..self.segments.len() {
                for component in 0..3 {
                    let v: Vec<f64> = rows
                        .iter()
                        .filter(|r| r.group == group && r.segment == si && r.component == component)
                        .map(|r| r.r)
                        .collect();
                    if v.len() >= 4 {
                        series.push(v);
                    }
                }
            }
            let den: f64 = series.iter().flatten().map(|r| r * r).sum();
            let longest = series.iter().map(Vec::len).max().unwrap_or(0);
            if den <= 0.0 {
                continue;
            }
            let mut sum = 0.0;
            for lag in 1..longest / 2 {
                let num: f64 = series
                    .iter()
                    .filter(|v| v.len() > lag)
                    .map(|v| v.windows(lag + 1).map(|w| w[0] * w[lag]).sum::<f64>())
                    .sum();
                let rho = num / den;
                if rho <= 0.0 {
                    break;
                }
                sum += rho;
            }
            *t = 1.0 + 2.0 * sum;
        }
        tau
    }

    /// Which globals the drive tells (sandwich σ below
    /// [`DriveOptions::observable_ratio`] of the prior's); the others are
    /// held at their value in use and the rest refitted. Returns that and
    /// the sandwich σ of the final fit.
    pub(super) fn hold_what_is_not_told(
        &self,
        fit: &mut Fit,
    ) -> Result<([bool; N_GLOBAL], [f64; N_GLOBAL])> {
        let cov = self.covariance(fit)?;
        let mut sigma: [f64; N_GLOBAL] = std::array::from_fn(|i| cov[(i, i)].max(0.0).sqrt());
        let observable: [bool; N_GLOBAL] = std::array::from_fn(|i| {
            !fit.fixed[i] && sigma[i] < self.options.observable_ratio * self.prior_sigma[i]
        });
        let hold: Vec<usize> = (0..N_GLOBAL)
            .filter(|&i| !fit.fixed[i] && !observable[i])
            .collect();
        if !hold.is_empty() {
            for &i in &hold {
                fit.fixed[i] = true;
                fit.p[i] = self.in_use[i];
            }
            self.fit(fit)?;
            let cov = self.covariance(fit)?;
            for i in (0..N_GLOBAL).filter(|i| observable[*i]) {
                sigma[i] = cov[(i, i)].max(0.0).sqrt();
            }
        }
        Ok((observable, sigma))
    }

    /// Each global's delete-a-block jackknife σ (0 for a held one, and for
    /// all on a drive of fewer than three blocks' fixes). The used fixes
    /// are cut, in time order, into `k` blocks; the fit is repeated `k`
    /// times, each time without one block (its fixes' weights 0, the
    /// others' robust weights and the groups' σ as the full fit left them,
    /// from the full fit's values), and `σ² = (k−1)/k Σ (θ₋ᵦ − θ̄)²`.
    ///
    /// The sandwich counts the noise of the fixes and of the inputs; what
    /// it cannot count is the model's own error where it changes along the
    /// drive: an effective tread that depends on the turn, a tyre's slip
    /// that depends on the load, a gyro reading in a roll. Each makes the
    /// parameters the fit finds depend on which stretch of road it saw,
    /// and the jackknife measures exactly that. The reported σ is the
    /// larger of the two (issue #31: on the multi-body drives the sandwich
    /// σ alone put the truth 3–17σ away).
    pub(super) fn jackknife_sigma(&self, fit: &Fit) -> Result<[f64; N_GLOBAL]> {
        let mut used: Vec<usize> = self
            .segments
            .iter()
            .flat_map(|s| s.fixes.iter().copied())
            .collect();
        used.sort_unstable();
        let k = JACKKNIFE_BLOCKS.min(used.len() / JACKKNIFE_MIN_FIXES);
        let mut sigma = [0.0; N_GLOBAL];
        if k < 3 {
            return Ok(sigma);
        }
        let mut estimates: Vec<[f64; N_GLOBAL]> = Vec::with_capacity(k);
        for b in 0..k {
            let mut trial = fit.clone();
            for &f in &used[b * used.len() / k..(b + 1) * used.len() / k] {
                trial.weights[f] = [0.0; N_GROUP];
            }
            self.levenberg_marquardt(&mut trial, f64::INFINITY)?;
            estimates.push(std::array::from_fn(|i| trial.p[i]));
        }
        let kf = k as f64;
        for (i, s) in sigma.iter_mut().enumerate() {
            if fit.fixed[i] {
                continue;
            }
            let mean = estimates.iter().map(|e| e[i]).sum::<f64>() / kf;
            let ss: f64 = estimates.iter().map(|e| (e[i] - mean).powi(2)).sum();
            *s = ((kf - 1.0) / kf * ss).sqrt();
        }
        Ok(sigma)
    }
}
