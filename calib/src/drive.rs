//! Calibration from ordinary driving with sparse position fixes (issue #23).
//!
//! The vehicle drives wherever it drives; a position source (GNSS, a
//! surveyed marker, a motion-capture system) gives the rear-axle centre's
//! position now and then, optionally with a heading. From that and the
//! odometry samples the estimator fits, by least squares over the whole
//! drive, the rear wheels' speed scale and diameter ratio, the steering
//! map's offset and gain correction, and the yaw-rate sensor's bias and
//! scale.
//!
//! # Model
//!
//! Three dead reckonings run over the samples, all with distance from the
//! rear wheels, `d = (k_R d_R + k_L d_L)/2` with `k_R = s·2r/(1+r)` and
//! `k_L = s·2/(1+r)` (speed scale `s`, ratio correction `r`), and with the
//! heading from
//! - (R) the rear wheels: `Δθ = (k_R d_R − k_L d_L)/b`;
//! - (Y) the yaw rate: `Δθ = (ω_meas − bias)/scale · Δt`;
//! - (S) the steering: `Δθ = d·tan(gain·φ̄ + offset)/L`, `φ̄` the mean of the
//!   interval's two ends.
//!
//! Each is integrated with the mid-point heading (`docs/calibration-math.md` §3).
//! A sample's distances and yaw rate describe the interval since the
//! previous sample; its steering angle is the angle at its time.
//!
//! The drive is split into segments of at most
//! [`DriveOptions::max_segment_s`] and [`DriveOptions::max_segment_fixes`],
//! so that a heading error cannot grow into a large nonlinearity. Each
//! segment starts at its first fix with an unknown start position (shared by
//! the sources) and an unknown start heading per source (nuisance
//! parameters); the vehicle parameters are shared by all segments. A fix's
//! position residual is the reckoned pose, interpolated linearly to the
//! fix's time, minus the fix; a fix with a heading adds a heading residual.
//! Weak priors around the values in use (see [`PriorSigmas`]) regularise
//! what the drive cannot tell.
//!
//! # Fit
//!
//! Levenberg–Marquardt on the stacked residuals, each source's position and
//! heading residuals weighted by their own σ, which is re-estimated from the
//! residuals (variance components). The fit is started on the first 10 s of
//! every segment and the window doubled until it holds the whole segment
//! (continuation), so it starts near a solution even when a yaw-rate bias
//! turns the reckoning by tens of degrees over a full segment.
//!
//! # Uncertainty
//!
//! The residuals are neither independent in time (a heading error integrates
//! into a smooth position error) nor across sources (the three reckonings
//! are compared with the same fixes and share the wheel distances). The
//! reported σ therefore comes from a sandwich: `H⁻¹ (S + P) H⁻¹`, where `H`
//! is the Gauss–Newton matrix, `P` the priors' information and `S` the sum
//! over fixes of the outer products of each fix's score (all sources' rows at
//! that fix added, so cross-source correlation is counted), each row's score
//! scaled by its group's integrated autocorrelation time `τ` (the variance
//! factor of the mean of an autocorrelated series: `τ = 1 + 2 Σ ρ_l`, summed
//! while the pooled autocorrelation ρ_l of the residual series stays
//! positive; the number of effectively independent fixes is `n/τ`), and by
//! `N/(N − p)` for the parameters fitted.
//!
//! The sandwich counts noise; it does not count the model's own error where
//! that changes along the drive (an effective tread that depends on the
//! turn, a tyre's slip on its load, a gyro reading in a roll), which makes
//! the fitted values depend on the stretch of road the fit saw. So each
//! reported σ is at least the delete-a-block jackknife's: the used fixes cut
//! in up to six blocks of at least ten, the fit repeated without each
//! (`Problem::jackknife_sigma`). The filter's prior on the bias keeps the
//! sandwich's σ ([`DriveCalibration::yaw_bias_noise_sigma_radps`]).
//!
//! A parameter is observable when its posterior σ is below
//! [`DriveOptions::observable_ratio`] of its prior σ; one that is not is
//! reported at its value in use, and the others are refitted with it held
//! there, so the reported set is consistent.

mod inputs;
mod options;
mod prepare;
mod result;
mod robust;
mod uncertainty;

pub use inputs::{
    DriveModel, DriveSample, Fix, FixRow, FixRowsError, SIGMA_COLUMN, fix_rows, parse_fixes,
};
pub use options::{DriveOptions, FixesLatency, Loss, PriorSigmas};
pub use result::{DownWeighted, DriveCalibration, Estimate, GateRefusal, calibrated_values};

use crate::error::{Error, Result, positive};
use nalgebra::{DMatrix, DVector};
use prepare::{Prepared, Segment, check, held, split, turns, white_noise};
use std::f64::consts::PI;

/// Fits the vehicle parameters of a drive to its fixes with the default
/// [`DriveOptions`] (see the module documentation).
///
/// # Errors
/// [`Error::InvalidArgument`] for a bad model, [`Error::NotEnoughSamples`],
/// [`Error::NotEnoughFixes`] (fewer than 3 fixes, or fewer than 3 left in
/// usable segments), [`Error::NotFinite`], [`Error::NotIncreasing`],
/// [`Error::FixOutsideSamples`], and [`Error::Numerical`] when the fit
/// breaks down.
pub fn calibrate_drive(
    samples: &[DriveSample],
    fixes: &[Fix],
    model: &DriveModel,
) -> Result<DriveCalibration> {
    calibrate_drive_with(samples, fixes, model, &DriveOptions::default())
}

/// [`calibrate_drive`] with explicit options.
///
/// # Errors
/// As [`calibrate_drive`], and [`Error::InvalidArgument`] for bad options.
pub fn calibrate_drive_with(
    samples: &[DriveSample],
    fixes: &[Fix],
    model: &DriveModel,
    options: &DriveOptions,
) -> Result<DriveCalibration> {
    let problem = Problem::new(samples, fixes, model, options)?;
    problem.solve()
}

// ---------------------------------------------------------------------------
// Parameter layout

/// Global parameters: speed scale, rear ratio, steer offset, steer gain,
/// yaw bias, yaw scale, the fixes' latency, the rear tread's correction.
/// Residual RMS at the fixes beyond the fixes' own noise, metres, above
/// which a heading source's fit is a misfit (the limit is
/// the drive gate's `residual_limit_m` with this allowance: 5.4 m for
/// fixes of
/// σ 1.5 m, 6.6 m at σ 3 m): the residuals are the fitted parameters', so
/// beyond it no parameter values explain the drive and the configuration
/// (a sign, a unit, a wheel or steering kind) is what is wrong. Committing
/// such a fit would store parameters that only look calibrated.
pub const MISFIT_RMS_M: f64 = 5.0;

const N_GLOBAL: usize = 8;
const SPEED: usize = 0;
const RATIO: usize = 1;
const OFFSET: usize = 2;
const GAIN: usize = 3;
const BIAS: usize = 4;
const SCALE: usize = 5;
const LATENCY: usize = 6;
const TREAD: usize = 7;
/// Values in use (the priors' means; the latency's is the given one, else 0).
const IN_USE: [f64; N_GLOBAL] = [1.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0];
/// Per segment: start x, start y, start heading of each source.
const N_LOCAL: usize = 5;

const REAR: usize = 0;
const YAW: usize = 1;
const STEER: usize = 2;
/// The globals each source's reckoning depends on.
const DEPS: [&[usize]; 3] = [
    &[SPEED, RATIO, LATENCY, TREAD],
    &[SPEED, RATIO, BIAS, SCALE, LATENCY],
    &[SPEED, RATIO, OFFSET, GAIN, LATENCY],
];
/// Central-difference steps of the globals (see `Problem::rows`). The
/// latency's: 0.1 ms, within one sample interval mostly (the reckoning is
/// interpolated linearly between samples, a kink at each).
const FD_STEP: [f64; N_GLOBAL] = [1e-6, 1e-6, 1e-7, 1e-6, 1e-7, 1e-6, 1e-4, 1e-6];

/// Residual groups: `source * 2 + kind`, kind 0 position, 1 heading.
const N_GROUP: usize = 6;
const POS_SIGMA_FLOOR_M: f64 = 1e-3;
const HEADING_SIGMA_FLOOR_RAD: f64 = 1e-4;
const HEADING_SIGMA_DEFAULT_RAD: f64 = 0.02;
/// A ridge on the nuisance headings, so a segment that never moved (or a
/// source without data) keeps a regular normal matrix: 1/(10 rad)².
const HEADING_RIDGE: f64 = 1e-2;
/// The same for the segments' start positions, 1/(1 km)²: only a
/// jackknife refit that leaves a whole segment out needs it (its start
/// position then has no fix), and next to a fix's information (1/σ², σ
/// metres at most) it moves nothing.
const POSITION_RIDGE: f64 = 1e-6;

/// The median σ the fixes state, metres (None when none states one): the
/// reference of the fit's per-fix scales, and the σ of a fix that states
/// none among fixes that do.
fn stated_sigma_m(fixes: &[Fix]) -> Option<f64> {
    let mut stated: Vec<f64> = fixes.iter().filter_map(|f| f.sigma_m).collect();
    stated.sort_by(f64::total_cmp);
    stated.get(stated.len() / 2).copied()
}

/// The median of χ² with two degrees of freedom, 2 ln 2: the median of a
/// fix's squared horizontal residual is this times σ² per axis.
const MEDIAN_CHI2_2: f64 = 2.0 * std::f64::consts::LN_2;

fn wrap(a: f64) -> f64 {
    let w = a.rem_euclid(2.0 * PI);
    if w > PI { w - 2.0 * PI } else { w }
}

struct Row {
    fix: usize,
    group: usize,
    /// Residual and derivatives, whitened by the group's σ.
    r: f64,
    jac: Vec<(usize, f64)>,
    /// The residual in its own unit (for the RMS and the σ estimates).
    raw: f64,
    segment: usize,
    /// 0 x, 1 y, 2 heading.
    component: usize,
    /// The fix's stated σ relative to the reference (`Problem::fix_scale`;
    /// 1 for a heading row): the row is whitened by the group's σ times it.
    scale: f64,
}

#[derive(Clone)]
struct Problem<'a> {
    prep: Prepared,
    fixes: &'a [Fix],
    model: DriveModel,
    options: DriveOptions,
    segments: Vec<Segment>,
    active: [bool; 3],
    prior_sigma: [f64; N_GLOBAL],
    /// The priors' means (the values in use; the given latency).
    in_use: [f64; N_GLOBAL],
    /// The latency's bound, seconds.
    latency_bound_s: f64,
    /// The rear wheels' turning over the used samples, left and right.
    turns_rad: [f64; 2],
    /// Each fix's stated σ relative to the median stated σ (1 for a fix
    /// that states none, and for all when none does): a group's σ is fitted
    /// for a fix of the reference σ and scaled by this for each fix.
    fix_scale: Vec<f64>,
}

#[derive(Clone)]
struct Fit {
    p: DVector<f64>,
    sigma: [f64; N_GROUP],
    /// Globals held at their value in use.
    fixed: [bool; N_GLOBAL],
    /// Each fix's weight in each residual group (the robust loss's).
    weights: Vec<[f64; N_GROUP]>,
}

impl<'a> Problem<'a> {
    fn new(
        samples: &[DriveSample],
        fixes: &'a [Fix],
        model: &DriveModel,
        options: &DriveOptions,
    ) -> Result<Self> {
        positive("rear_tread_m", model.rear_tread_m)?;
        positive("wheelbase_m", model.wheelbase_m)?;
        positive("max_segment_s", options.max_segment_s)?;
        positive("observable_ratio", options.observable_ratio)?;
        let pr = options.priors;
        let prior_sigma = [
            positive("priors.speed_scale", pr.speed_scale)?,
            positive("priors.rear_ratio", pr.rear_ratio)?,
            positive("priors.steer_offset_rad", pr.steer_offset_rad)?,
            positive("priors.steer_gain", pr.steer_gain)?,
            positive("priors.yaw_bias_radps", pr.yaw_bias_radps)?,
            positive("priors.yaw_scale", pr.yaw_scale)?,
            0.0,
            positive("priors.rear_tread", pr.rear_tread)?,
        ];
        let mut prior_sigma = prior_sigma;
        let mut in_use = IN_USE;
        let latency_bound_s = match options.latency {
            FixesLatency::Estimate { bound_s } => {
                // The bound as a weak prior too: it keeps the normal matrix
                // regular on a drive that cannot tell the latency.
                prior_sigma[LATENCY] = positive("latency.bound_s", bound_s)?;
                bound_s
            }
            FixesLatency::Given(latency_s) => {
                crate::error::finite("fixes_latency_s", latency_s)?;
                in_use[LATENCY] = latency_s;
                prior_sigma[LATENCY] = 1.0;
                latency_s.abs()
            }
        };
        if options.max_segment_fixes < 3 {
            return Err(Error::InvalidArgument {
                name: "max_segment_fixes",
                value: options.max_segment_fixes as f64,
                reason: "must be at least 3",
            });
        }
        check(samples, fixes)?;
        let prep = Prepared {
            t: samples.iter().map(|s| s.t_s).collect(),
            dl: samples.iter().map(|s| s.rear_left_m).collect(),
            dr: samples.iter().map(|s| s.rear_right_m).collect(),
            steer: held(samples.iter().map(|s| s.steer_angle_rad)),
            yaw: held(samples.iter().map(|s| s.yaw_rate_radps)),
            noise: [
                0.0,
                white_noise(samples.iter().map(|s| s.yaw_rate_radps)),
                white_noise(samples.iter().map(|s| s.steer_angle_rad)),
            ],
            slips: samples
                .iter()
                .scan(0, |n, s| {
                    *n += usize::from(s.rear_slip);
                    Some(*n)
                })
                .collect(),
        };
        let mut active = [false; 3];
        active[REAR] = true;
        active[YAW] = prep.yaw.is_some();
        active[STEER] = prep.steer.is_some();
        let segments = split(&prep.t, &prep.slips, fixes, options, latency_bound_s);
        let used: usize = segments.iter().map(|s| s.fixes.len()).sum();
        if used < 3 {
            return Err(Error::NotEnoughFixes {
                what: "in segments of at least 3 fixes",
                got: used,
                needed: 3,
            });
        }
        let turns_rad = turns(&prep, &segments, model.rear_tread_m);
        let fix_scale = match stated_sigma_m(fixes) {
            Some(reference) => fixes
                .iter()
                .map(|f| f.sigma_m.map_or(1.0, |s| s / reference))
                .collect(),
            None => vec![1.0; fixes.len()],
        };
        Ok(Self {
            fix_scale,
            prep,
            fixes,
            model: *model,
            options: *options,
            segments,
            active,
            prior_sigma,
            in_use,
            latency_bound_s,
            turns_rad,
        })
    }

    /// Where each of the segment's fixes lies among the samples at
    /// `latency_s`: the instant `t_fix − latency_s`, kept within the
    /// segment's samples.
    fn at(&self, seg: &Segment, latency_s: f64) -> Vec<(usize, f64)> {
        let t = &self.prep.t;
        seg.fixes
            .iter()
            .map(|&f| {
                let tf = (self.fixes[f].t_s - latency_s).clamp(t[seg.start], t[seg.end]);
                let k = t
                    .partition_point(|&ts| ts < tf)
                    .clamp(seg.start + 1, seg.end);
                let i = k - 1;
                (i, ((tf - t[i]) / (t[k] - t[i])).clamp(0.0, 1.0))
            })
            .collect()
    }

    fn n_params(&self) -> usize {
        N_GLOBAL + N_LOCAL * self.segments.len()
    }

    /// The heading increment of sample `k`'s interval and its distance.
    fn increment(&self, src: usize, g: &[f64], k: usize) -> (f64, f64) {
        let prep = &self.prep;
        let (s, r) = (g[SPEED], g[RATIO]);
        let (dr, dl) = (
            s * 2.0 * r / (1.0 + r) * prep.dr[k],
            s * 2.0 / (1.0 + r) * prep.dl[k],
        );
        let d = 0.5 * (dr + dl);
        let dth = match (src, &prep.yaw, &prep.steer) {
            (YAW, Some(w), _) => (w[k] - g[BIAS]) / g[SCALE] * (prep.t[k] - prep.t[k - 1]),
            (STEER, _, Some(phi)) => {
                let mean = 0.5 * (phi[k - 1] + phi[k]);
                d * g[GAIN].mul_add(mean, g[OFFSET]).tan() / self.model.wheelbase_m
            }
            _ => (dr - dl) / (self.model.rear_tread_m * g[TREAD]),
        };
        (d, dth)
    }

    /// The reckoning of `src` from sample `seg.start` (at the origin) to
    /// sample `end`, mid-point heading.
    fn path(&self, seg: &Segment, src: usize, g: &[f64], end: usize) -> Vec<[f64; 3]> {
        let mut poses = Vec::with_capacity(end + 1 - seg.start);
        let (mut x, mut y, mut th) = (0.0, 0.0, 0.0);
        poses.push([x, y, th]);
        for k in seg.start + 1..=end {
            let (d, dth) = self.increment(src, g, k);
            let mid = th + 0.5 * dth;
            x += d * mid.cos();
            y += d * mid.sin();
            th += dth;
            poses.push([x, y, th]);
        }
        poses
    }

    /// Poses of source `src` at the first `n` fixes of `seg`, relative to
    /// the pose at its first fix (that pose at the origin, heading 0).
    fn reckon(&self, seg: &Segment, src: usize, g: &[f64], n: usize) -> Vec<[f64; 3]> {
        let at = self.at(seg, g[LATENCY]);
        let poses = self.path(seg, src, g, at[n - 1].0 + 1);
        let pose_at = |&(i, frac): &(usize, f64)| {
            let (a, b) = (poses[i - seg.start], poses[i + 1 - seg.start]);
            [0, 1, 2].map(|c| a[c] + frac * (b[c] - a[c]))
        };
        let origin = pose_at(&at[0]);
        let (sn, cs) = (-origin[2]).sin_cos();
        at[..n]
            .iter()
            .map(|at| {
                let p = pose_at(at);
                let (dx, dy) = (p[0] - origin[0], p[1] - origin[1]);
                [cs * dx - sn * dy, sn * dx + cs * dy, p[2] - origin[2]]
            })
            .collect()
    }

    /// How many of the segment's fixes lie within `horizon_s` of its first.
    fn in_horizon(&self, seg: &Segment, horizon_s: f64) -> usize {
        let t0 = self.fixes[seg.fixes[0]].t_s;
        seg.fixes
            .iter()
            .take_while(|&&f| self.fixes[f].t_s - t0 <= horizon_s)
            .count()
            .max(2)
            .min(seg.fixes.len())
    }

    /// All residual rows at `p`, whitened by `sigma`. With `jacobian`, their
    /// derivatives: the nuisance parameters' analytically (they only move
    /// and turn the relative reckoning), the globals' by central
    /// differences of the reckoning. The globals enter through the heading
    /// chain, a tangent and a division at every sample; one difference per
    /// global costs two reckonings of the segment, cheap next to a fit over
    /// the whole drive, and cannot disagree with the reckoning it
    /// differentiates (steps of 1e-6 relative, 1e-7 rad: truncation and
    /// rounding both below 1e-7 m on a 60 s segment of a road car).
    fn rows(&self, fit: &Fit, horizon_s: f64, jacobian: bool) -> Vec<Row> {
        let p = &fit.p;
        let g: Vec<f64> = p.rows(0, N_GLOBAL).iter().copied().collect();
        let mut rows = Vec::new();
        for (si, seg) in self.segments.iter().enumerate() {
            let n = self.in_horizon(seg, horizon_s);
            let base = N_GLOBAL + N_LOCAL * si;
            let (x0, y0) = (p[base], p[base + 1]);
            for src in (0..3).filter(|&s| self.active[s]) {
                let th_col = base + 2 + src;
                let th0 = p[th_col];
                let rel = self.reckon(seg, src, &g, n);
                let mut drel: Vec<(usize, Vec<[f64; 3]>)> = Vec::new();
                if jacobian {
                    for &gi in DEPS[src].iter().filter(|&&gi| !fit.fixed[gi]) {
                        let h = FD_STEP[gi];
                        let mut gp = g.clone();
                        gp[gi] += h;
                        let plus = self.reckon(seg, src, &gp, n);
                        gp[gi] = g[gi] - h;
                        let minus = self.reckon(seg, src, &gp, n);
                        let d = plus
                            .iter()
                            .zip(&minus)
                            .map(|(a, b)| [0, 1, 2].map(|c| (a[c] - b[c]) / (2.0 * h)))
                            .collect();
                        drel.push((gi, d));
                    }
                }
                let (sn, cs) = th0.sin_cos();
                let sh = fit.sigma[src * 2 + 1];
                for (j, rj) in rel.iter().enumerate() {
                    let fix = &self.fixes[seg.fixes[j]];
                    let scale = self.fix_scale[seg.fixes[j]];
                    let sp = fit.sigma[src * 2] * scale;
                    let px = x0 + cs * rj[0] - sn * rj[1];
                    let py = y0 + sn * rj[0] + cs * rj[1];
                    let mut jx = Vec::new();
                    let mut jy = Vec::new();
                    if jacobian {
                        jx.push((base, 1.0 / sp));
                        jx.push((th_col, (-sn * rj[0] - cs * rj[1]) / sp));
                        jy.push((base + 1, 1.0 / sp));
                        jy.push((th_col, (cs * rj[0] - sn * rj[1]) / sp));
                        for (gi, d) in &drel {
                            let dj = d[j];
                            jx.push((*gi, (cs * dj[0] - sn * dj[1]) / sp));
                            jy.push((*gi, (sn * dj[0] + cs * dj[1]) / sp));
                        }
                    }
                    let fix_index = seg.fixes[j];
                    let [wp, wh] = [0, 1].map(|k| fit.weights[fix_index][src * 2 + k].sqrt());
                    for (component, raw, mut jac) in [(0, px - fix.x_m, jx), (1, py - fix.y_m, jy)]
                    {
                        for e in &mut jac {
                            e.1 *= wp;
                        }
                        rows.push(Row {
                            fix: fix_index,
                            group: src * 2,
                            r: wp * raw / sp,
                            jac,
                            raw,
                            segment: si,
                            component,
                            scale,
                        });
                    }
                    if let Some(h) = fix.heading_rad {
                        let raw = wrap(th0 + rj[2] - h);
                        let mut jac = Vec::new();
                        if jacobian {
                            jac.push((th_col, wh / sh));
                            for (gi, d) in &drel {
                                jac.push((*gi, wh * d[j][2] / sh));
                            }
                        }
                        rows.push(Row {
                            fix: fix_index,
                            group: src * 2 + 1,
                            r: wh * raw / sh,
                            jac,
                            raw,
                            segment: si,
                            component: 2,
                            scale: 1.0,
                        });
                    }
                }
            }
        }
        rows
    }

    fn prior_cost(&self, fit: &Fit) -> f64 {
        (0..N_GLOBAL)
            .filter(|&i| !fit.fixed[i])
            .map(|i| ((fit.p[i] - self.in_use[i]) / self.prior_sigma[i]).powi(2))
            .sum()
    }

    fn cost(&self, fit: &Fit, horizon_s: f64) -> f64 {
        self.rows(fit, horizon_s, false)
            .iter()
            .map(|r| r.r * r.r)
            .sum::<f64>()
            + self.prior_cost(fit)
    }

    /// The Gauss–Newton matrix (data and priors, without ridge) and gradient.
    fn normal(&self, fit: &Fit, rows: &[Row]) -> (DMatrix<f64>, DVector<f64>) {
        let n = self.n_params();
        let mut h = DMatrix::zeros(n, n);
        let mut grad = DVector::zeros(n);
        for row in rows {
            for &(a, ja) in &row.jac {
                grad[a] += ja * row.r;
                for &(b, jb) in &row.jac {
                    h[(a, b)] += ja * jb;
                }
            }
        }
        for i in 0..N_GLOBAL {
            if fit.fixed[i] {
                h[(i, i)] = 1.0;
                grad[i] = 0.0;
            } else {
                let w = 1.0 / self.prior_sigma[i].powi(2);
                h[(i, i)] += w;
                grad[i] += w * (fit.p[i] - self.in_use[i]);
            }
        }
        (h, grad)
    }

    fn with_ridge(&self, mut h: DMatrix<f64>) -> DMatrix<f64> {
        for si in 0..self.segments.len() {
            for src in 0..3 {
                let c = N_GLOBAL + N_LOCAL * si + 2 + src;
                h[(c, c)] += HEADING_RIDGE;
            }
            for c in 0..2 {
                h[(N_GLOBAL + N_LOCAL * si + c, N_GLOBAL + N_LOCAL * si + c)] += POSITION_RIDGE;
            }
        }
        h
    }

    /// Levenberg–Marquardt at fixed σ and horizon.
    fn levenberg_marquardt(&self, fit: &mut Fit, horizon_s: f64) -> Result<()> {
        let mut lambda = 1e-3;
        let mut cost = self.cost(fit, horizon_s);
        for _ in 0..100 {
            let rows = self.rows(fit, horizon_s, true);
            let (h, grad) = self.normal(fit, &rows);
            let h = self.with_ridge(h);
            let mut improved = false;
            for _ in 0..20 {
                let mut damped = h.clone();
                for i in 0..damped.nrows() {
                    damped[(i, i)] += lambda * h[(i, i)];
                }
                let step = damped
                    .cholesky()
                    .ok_or(Error::Numerical {
                        context: "drive calibration: normal equations",
                    })?
                    .solve(&(-&grad));
                let mut p = &fit.p + &step;
                p[LATENCY] = p[LATENCY].clamp(-self.latency_bound_s, self.latency_bound_s);
                let trial = Fit {
                    p,
                    sigma: fit.sigma,
                    fixed: fit.fixed,
                    weights: fit.weights.clone(),
                };
                let trial_cost = self.cost(&trial, horizon_s);
                if trial_cost.is_finite() && trial_cost <= cost {
                    // Converged when the step is far below the parameters'
                    // uncertainty and the cost no longer moves.
                    let size = (0..step.len())
                        .map(|i| step[i].abs() * h[(i, i)].sqrt())
                        .fold(0.0, f64::max);
                    let done = size < 1e-6 || cost - trial_cost <= 1e-12 * cost.max(1e-300);
                    fit.p = trial.p;
                    cost = trial_cost;
                    lambda = (lambda / 4.0).max(1e-9);
                    improved = true;
                    if done {
                        return Ok(());
                    }
                    break;
                }
                lambda *= 8.0;
            }
            if !improved {
                // No descent left at any damping: a minimum to rounding.
                return Ok(());
            }
        }
        Ok(())
    }

    /// Re-estimates each group's σ from the residuals (variance components).
    fn update_sigma(&self, fit: &mut Fit, horizon_s: f64) {
        let rows = self.rows(fit, horizon_s, false);
        let n_seg = self.segments.len() as f64;
        for group in 0..N_GROUP {
            let (src, heading) = (group / 2, group % 2 == 1);
            if !self.active[src] {
                continue;
            }
            // Weighted by the robust loss's weights: a down-weighted fix
            // does not inflate the scatter the others are judged by.
            let (n, ssr) =
                rows.iter()
                    .filter(|r| r.group == group)
                    .fold((0.0, 0.0), |(n, s), r| {
                        let w = fit.weights[r.fix][group];
                        (n + w, s + w * (r.raw / r.scale).powi(2))
                    });
            fit.sigma[group] = if heading {
                if n < 5.0 {
                    HEADING_SIGMA_DEFAULT_RAD
                } else {
                    (ssr / n).sqrt().max(HEADING_SIGMA_FLOOR_RAD)
                }
            } else {
                // Fitted per source: a start heading per segment, a share of
                // the start position and the source's globals.
                let k = n_seg * 2.0 + DEPS[src].len() as f64;
                (ssr / (n - k).max(0.5 * n)).sqrt().max(POS_SIGMA_FLOOR_M)
            };
        }
    }

    /// Start headings of every source and segment by rotating the reckoning
    /// onto the fixes (the angle of the 2-D Procrustes fit), or from the
    /// first fix's heading when the segment barely moved.
    fn init_headings(&self, fit: &mut Fit, horizon_s: f64) {
        let g: Vec<f64> = fit.p.rows(0, N_GLOBAL).iter().copied().collect();
        for (si, seg) in self.segments.iter().enumerate() {
            let n = self.in_horizon(seg, horizon_s);
            let base = N_GLOBAL + N_LOCAL * si;
            let f0 = &self.fixes[seg.fixes[0]];
            fit.p[base] = f0.x_m;
            fit.p[base + 1] = f0.y_m;
            for src in 0..3 {
                let th = if self.active[src] {
                    let rel = self.reckon(seg, src, &g, n);
                    let (mut dot, mut cross, mut scale) = (0.0, 0.0, 0.0);
                    for (j, rj) in rel.iter().enumerate() {
                        let f = &self.fixes[seg.fixes[j]];
                        let (fx, fy) = (f.x_m - f0.x_m, f.y_m - f0.y_m);
                        dot += rj[0] * fx + rj[1] * fy;
                        cross += rj[0] * fy - rj[1] * fx;
                        scale += rj[0].hypot(rj[1]) * fx.hypot(fy);
                    }
                    if scale > 1.0 {
                        cross.atan2(dot)
                    } else {
                        f0.heading_rad.unwrap_or(0.0)
                    }
                } else {
                    0.0
                };
                fit.p[base + 2 + src] = th;
            }
        }
    }

    fn fit(&self, fit: &mut Fit) -> Result<()> {
        let longest = self
            .segments
            .iter()
            .map(|s| self.fixes[s.fixes[s.fixes.len() - 1]].t_s - self.fixes[s.fixes[0]].t_s)
            .fold(0.0, f64::max);
        let mut horizon = 10.0_f64;
        self.init_headings(fit, horizon);
        loop {
            let h = if horizon >= longest {
                f64::INFINITY
            } else {
                horizon
            };
            self.levenberg_marquardt(fit, h)?;
            self.update_weights(fit, h);
            self.update_sigma(fit, h);
            self.levenberg_marquardt(fit, h)?;
            if h.is_infinite() {
                break;
            }
            horizon *= 2.0;
        }
        // Reweighting until the weights settle (Cauchy's IRLS converges in a
        // few rounds from a start that already down-weights the jumps).
        for _ in 0..4 {
            self.update_weights(fit, f64::INFINITY);
            self.update_sigma(fit, f64::INFINITY);
            self.levenberg_marquardt(fit, f64::INFINITY)?;
        }
        Ok(())
    }

    fn solve(&self) -> Result<DriveCalibration> {
        let mut p = DVector::zeros(self.n_params());
        for (i, v) in self.in_use.iter().enumerate() {
            p[i] = *v;
        }
        let mut fit = Fit {
            p,
            sigma: [
                0.5,
                HEADING_SIGMA_DEFAULT_RAD,
                0.5,
                HEADING_SIGMA_DEFAULT_RAD,
                0.5,
                HEADING_SIGMA_DEFAULT_RAD,
            ],
            fixed: [false; N_GLOBAL],
            weights: vec![[1.0; N_GROUP]; self.fixes.len()],
        };
        for (i, fixed) in fit.fixed.iter_mut().enumerate() {
            *fixed = !self.source_uses(i);
        }
        fit.fixed[LATENCY] |= matches!(self.options.latency, FixesLatency::Given(_));
        fit.fixed[TREAD] |= !self.turns_both_ways();
        self.fit(&mut fit)?;
        let (observable, noise_sigma) = self.hold_what_is_not_told(&mut fit)?;
        let mut sigma = noise_sigma;
        let jackknife = self.jackknife_sigma(&fit)?;
        for i in (0..N_GLOBAL).filter(|&i| observable[i]) {
            sigma[i] = sigma[i].max(jackknife[i]);
        }
        for (i, s) in sigma.iter().enumerate() {
            crate::error::finite("drive calibration: σ", *s)?;
            crate::error::finite("drive calibration: estimate", fit.p[i])?;
        }
        let est = |i: usize| Estimate {
            value: fit.p[i],
            sigma: sigma[i],
            observable: observable[i],
        };
        let rows = self.rows(&fit, f64::INFINITY, false);
        let residual_rms_m = std::array::from_fn(|src| {
            self.active[src].then(|| {
                let (n, ssr) = rows
                    .iter()
                    .filter(|r| r.group == src * 2)
                    .fold((0.0_f64, 0.0_f64), |(n, s), r| (n + 0.5, s + r.raw * r.raw));
                (ssr / n.max(0.5)).sqrt()
            })
        });
        let weighted_rms_m = std::array::from_fn(|src| {
            self.active[src].then(|| {
                let (n, ssr) = rows.iter().filter(|r| r.group == src * 2).fold(
                    (0.0_f64, 0.0_f64),
                    |(n, s), r| {
                        let w = fit.weights[r.fix][src * 2];
                        (n + 0.5 * w, s + w * r.raw * r.raw)
                    },
                );
                (ssr / n.max(1e-9)).sqrt()
            })
        });
        let (fixes_sigma_m, fixes_sigma_stated) = self.fixes_sigma(&fit, &rows, &weighted_rms_m);
        // A source past the misfit check's smallest limit is judged on its
        // own best fit: the joint fit's shared values (speed scale,
        // latency) are a compromise between the sources, and a source the
        // compromise leaves far off may still be one that its own values fit.
        let mut own_fit_rms_m = weighted_rms_m;
        // The joint values are one set of that source's values, so its own
        // best leaves no more (a refit that fails or lands worse keeps them).
        for (src, own) in own_fit_rms_m.iter_mut().enumerate() {
            if let Some(r) = own.filter(|r| !r.is_finite() || *r > MISFIT_RMS_M)
                && let Ok(alone) = self.alone_rms_m(&fit, src)
            {
                *own = Some(alone.min(r));
            }
        }
        Ok(DriveCalibration {
            own_fit_rms_m,
            fixes_sigma_m,
            fixes_sigma_stated,
            rear_tread: est(TREAD),
            turns_rad: self.turns_rad,
            fixes_latency_s: match self.options.latency {
                FixesLatency::Given(latency_s) => Estimate {
                    value: latency_s,
                    sigma: 0.0,
                    observable: false,
                },
                FixesLatency::Estimate { .. } => est(LATENCY),
            },
            latency_given: matches!(self.options.latency, FixesLatency::Given(_)),
            down_weighted: self.down_weighted(&fit, &rows),
            weighted_rms_m,
            refused: Vec::new(),
            speed_scale: est(SPEED),
            rear_ratio: est(RATIO),
            steer_offset_rad: self.active[STEER].then(|| est(OFFSET)),
            steer_gain: self.active[STEER].then(|| est(GAIN)),
            yaw_bias_radps: self.active[YAW].then(|| est(BIAS)),
            yaw_scale: self.active[YAW].then(|| est(SCALE)),
            yaw_bias_noise_sigma_radps: self.active[YAW].then_some(noise_sigma[BIAS]),
            fixes_used: self.segments.iter().map(|s| s.fixes.len()).sum(),
            distance_m: self.distance_m(&fit),
            residual_rms_m,
        })
    }

    /// Source `src`'s weighted RMS position residual, metres, when its
    /// reckoning alone is fitted to the fixes (the other sources off), from
    /// the joint fit `fit`: what no parameter values of that source can
    /// remove.
    fn alone_rms_m(&self, fit: &Fit, src: usize) -> Result<f64> {
        let mut alone = self.clone();
        alone.active = [false; 3];
        alone.active[src] = true;
        let mut own = fit.clone();
        for (i, fixed) in own.fixed.iter_mut().enumerate() {
            *fixed |= !alone.source_uses(i);
        }
        alone.fit(&mut own)?;
        let (n, ssr) = alone
            .rows(&own, f64::INFINITY, false)
            .iter()
            .filter(|r| r.group == src * 2)
            .fold((0.0_f64, 0.0_f64), |(n, s), r| {
                let w = own.weights[r.fix][src * 2];
                (n + 0.5 * w, s + w * r.raw * r.raw)
            });
        Ok((ssr / n.max(1e-9)).sqrt())
    }

    /// The fixes' 1σ error per axis, metres, and whether their source
    /// stated it. Stated: the RMS of the σ of the used fixes that the best
    /// fitting source kept (a fix stating none counted at the median stated
    /// σ). Not stated: estimated from that source's residuals, robustly,
    /// `√(median e² / (2 ln 2))` over the fixes it kept (`e` a fix's
    /// horizontal residual): the median and the kept fixes only, so that
    /// neither a receiver's jumps nor a stretch the reckoning gets wrong
    /// passes for the fixes' own noise.
    fn fixes_sigma(
        &self,
        fit: &Fit,
        rows: &[Row],
        weighted_rms_m: &[Option<f64>; 3],
    ) -> (f64, bool) {
        let best = (0..3)
            .filter_map(|src| weighted_rms_m[src].map(|r| (src, r)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map_or(REAR, |(src, _)| src);
        let group = best * 2;
        let mut e2: Vec<(usize, f64)> = Vec::new();
        for r in rows.iter().filter(|r| r.group == group) {
            match e2.last_mut() {
                Some((f, e)) if *f == r.fix => *e += r.raw * r.raw,
                _ => e2.push((r.fix, r.raw * r.raw)),
            }
        }
        let kept: Vec<(usize, f64)> = e2
            .iter()
            .copied()
            .filter(|&(f, _)| fit.weights[f][group] >= robust::DOWN_WEIGHTED)
            .collect();
        let kept = if kept.is_empty() { e2 } else { kept };
        if let Some(reference) = stated_sigma_m(self.fixes) {
            let n = kept.len().max(1) as f64;
            let mean2 = kept
                .iter()
                .map(|&(f, _)| self.fixes[f].sigma_m.unwrap_or(reference).powi(2))
                .sum::<f64>()
                / n;
            return (mean2.sqrt(), true);
        }
        let mut sorted: Vec<f64> = kept.iter().map(|e| e.1).collect();
        sorted.sort_by(f64::total_cmp);
        let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
        ((median / MEDIAN_CHI2_2).sqrt(), false)
    }

    /// Whether the drive turned enough each way to tell the tread.
    fn turns_both_ways(&self) -> bool {
        self.turns_rad[0].min(self.turns_rad[1]) >= self.options.min_turn_each_way_rad
    }

    /// Whether an active source's reckoning depends on global `i`.
    fn source_uses(&self, i: usize) -> bool {
        (0..3).any(|src| self.active[src] && DEPS[src].contains(&i))
    }

    /// Distance from the first used fix to the last, gaps between
    /// segments included.
    fn distance_m(&self, fit: &Fit) -> f64 {
        let (s, r) = (fit.p[SPEED], fit.p[RATIO]);
        let (k_r, k_l) = (s * 2.0 * r / (1.0 + r), s * 2.0 / (1.0 + r));
        let (Some(first), Some(last)) = (self.segments.first(), self.segments.last()) else {
            return 0.0;
        };
        let (first_at, last_at) = (
            self.at(first, fit.p[LATENCY])[0],
            self.at(last, fit.p[LATENCY])[last.fixes.len() - 1],
        );
        (first_at.0 + 1..=last_at.0 + 1)
            .map(|k| (0.5 * (k_r * self.prep.dr[k] + k_l * self.prep.dl[k])).abs())
            .sum()
    }
}

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_sigma;
