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

use crate::error::{Error, Result, positive};
use crate::history::ParamValues;
use nalgebra::{DMatrix, DVector};
use std::f64::consts::PI;

/// One odometry sample of an ordinary drive, as the daemon's pipeline
/// produces it (one per rear-wheel frame, ~10-100 Hz).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriveSample {
    /// Time on the fixes' clock.
    pub t_s: f64,
    /// Rear-left distance since the previous sample, with the parameters in use.
    pub rear_left_m: f64,
    /// Rear-right distance since the previous sample, with the parameters in use.
    pub rear_right_m: f64,
    /// Road-wheel angle through the steering map in use (left positive), at `t_s`.
    pub steer_angle_rad: Option<f64>,
    /// Yaw-rate sensor as measured (rad/s, left positive), uncorrected: the
    /// mean over the interval since the previous sample.
    pub yaw_rate_radps: Option<f64>,
    /// A rear wheel slipped (locked under braking, spun under drive) within
    /// this sample's interval, as the pipeline's gate judged it: its
    /// distance is not the vehicle's, so no segment reckons across it (the
    /// fixes after it start a new one).
    pub rear_slip: bool,
}

/// A position fix of the rear-axle centre in a local metric frame (x
/// east/forward, y left), its time on the samples' clock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fix {
    /// Time on the samples' clock.
    pub t_s: f64,
    /// Position, x.
    pub x_m: f64,
    /// Position, y.
    pub y_m: f64,
    /// The vehicle's heading (CCW from +x), when the source gives one.
    pub heading_rad: Option<f64>,
}

/// Reads a fixes CSV: a header naming `t_unix_s`, `x_m`, `y_m` and
/// optionally `heading_rad` (any order, other columns ignored), then one fix
/// a line; times on the log's clock (Unix seconds, as candump -L writes).
/// `name` names the file in errors.
///
/// # Errors
/// [`Error::FixesText`] for a missing column, a line that is not numbers, or
/// times that do not increase, naming `name` and the line.
pub fn parse_fixes(text: &str, name: &str) -> Result<Vec<Fix>> {
    let err = |line: usize, reason: String| Error::FixesText {
        name: name.to_owned(),
        line,
        reason,
    };
    let rows = fix_rows(text, ["t_unix_s", "x_m", "y_m"], "heading_rad", |_| Ok(())).map_err(
        |e| match e {
            FixRowsError::Empty => err(
                0,
                "empty; expected a header t_unix_s,x_m,y_m[,heading_rad]".to_owned(),
            ),
            FixRowsError::Header { header, .. } => err(
                1,
                format!(
                    "the header {header:?} lacks t_unix_s, x_m or y_m \
                     (expected t_unix_s,x_m,y_m[,heading_rad])"
                ),
            ),
            FixRowsError::Line { line, reason } => err(line, reason),
        },
    )?;
    Ok(rows
        .into_iter()
        .map(|r| Fix {
            t_s: r.values[0],
            x_m: r.values[1],
            y_m: r.values[2],
            heading_rad: r.optional,
        })
        .collect())
}

/// One line of a fixes CSV read by [`fix_rows`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FixRow {
    /// The line's number, from 1.
    pub line: usize,
    /// The required columns' values, in the order they were asked for (the
    /// first is the time).
    pub values: [f64; 3],
    /// The optional column's value, when the header has it.
    pub optional: Option<f64>,
}

/// Why [`fix_rows`] refused a text.
#[derive(Debug, Clone, PartialEq)]
pub enum FixRowsError {
    /// No line but blank ones.
    Empty,
    /// The header lacks a required column.
    Header {
        /// The header's line number, from 1.
        line: usize,
        /// The header as written.
        header: String,
    },
    /// A line is not numbers, its time does not increase, or `check` refused it.
    Line {
        /// The line's number, from 1.
        line: usize,
        /// What is wrong, naming the column.
        reason: String,
    },
}

/// The rows of a CSV of fixes whose header names its columns (any order,
/// others ignored): three `required` columns, the first the time, and one
/// `optional`; every value a finite number, the times increasing, and each
/// row passed to `check` (its refusal is that line's error). The one reader
/// of the local-metre and the latitude/longitude CSVs.
///
/// # Errors
/// [`FixRowsError`], naming the line.
pub fn fix_rows(
    text: &str,
    required: [&str; 3],
    optional: &str,
    mut check: impl FnMut(&FixRow) -> std::result::Result<(), String>,
) -> std::result::Result<Vec<FixRow>, FixRowsError> {
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let Some((h, header)) = lines.next() else {
        return Err(FixRowsError::Empty);
    };
    let columns: Vec<&str> = header.split(',').map(str::trim).collect();
    let column = |want: &str| columns.iter().position(|c| *c == want);
    let (Some(a), Some(b), Some(c)) = (
        column(required[0]),
        column(required[1]),
        column(required[2]),
    ) else {
        return Err(FixRowsError::Header {
            line: h + 1,
            header: header.to_owned(),
        });
    };
    let extra = column(optional);
    let mut rows: Vec<FixRow> = Vec::new();
    for (i, line) in lines {
        let bad = |reason: String| FixRowsError::Line {
            line: i + 1,
            reason,
        };
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let number = |k: usize, what: &str| -> std::result::Result<f64, FixRowsError> {
            let text = fields
                .get(k)
                .ok_or_else(|| bad(format!("no {what} column")))?;
            let v: f64 = text
                .parse()
                .map_err(|_| bad(format!("{what} {text:?} is not a number")))?;
            if !v.is_finite() {
                return Err(bad(format!("{what} {text:?} is not finite")));
            }
            Ok(v)
        };
        let row = FixRow {
            line: i + 1,
            values: [
                number(a, required[0])?,
                number(b, required[1])?,
                number(c, required[2])?,
            ],
            optional: extra.map(|e| number(e, optional)).transpose()?,
        };
        check(&row).map_err(bad)?;
        if rows
            .last()
            .is_some_and(|prev| row.values[0] <= prev.values[0])
        {
            return Err(bad("the fixes' times must increase".to_owned()));
        }
        rows.push(row);
    }
    Ok(rows)
}

/// The geometry in use.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriveModel {
    /// Rear tread (distance between the rear wheels' contact points).
    pub rear_tread_m: f64,
    /// Wheelbase (rear axle to front axle).
    pub wheelbase_m: f64,
}

/// One estimated parameter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// The estimate; the value in use (1 or 0) when not observable.
    pub value: f64,
    /// Its posterior standard deviation.
    pub sigma: f64,
    /// Whether the drive told this parameter (posterior σ well below the
    /// prior σ). When false the daemon keeps the value in use.
    pub observable: bool,
}

/// A parameter the gate kept at its previous value, and why.
#[derive(Debug, Clone, PartialEq)]
pub struct GateRefusal {
    /// The parameter (as the report names it).
    pub parameter: &'static str,
    /// Why, with the numbers.
    pub reason: String,
}

/// A fix the robust loss down-weighted: it disagrees with every source's
/// reckoning far beyond the others' scatter (a receiver's jump).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DownWeighted {
    /// The fix's time (its stamp, on the log's clock).
    pub t_s: f64,
    /// Its position residual against the source that agrees best, metres.
    pub residual_m: f64,
    /// Its weight in that source (1 = in full).
    pub weight: f64,
}

/// The result of [`calibrate_drive`].
#[derive(Debug, Clone, PartialEq)]
pub struct DriveCalibration {
    /// Multiplies the mean of the two rear distances (both rear diameters) — 1 = unchanged.
    pub speed_scale: Estimate,
    /// Right/left rear distance ratio correction: k_R/k_L (k_R = s·2r/(1+r),
    /// k_L = s·2/(1+r)) — 1 = unchanged.
    pub rear_ratio: Estimate,
    /// φ_true = steer_gain · φ_measured + steer_offset_rad (None when no
    /// sample had steering).
    pub steer_offset_rad: Option<Estimate>,
    /// See `steer_offset_rad`.
    pub steer_gain: Option<Estimate>,
    /// The sensor model: ω_measured = yaw_scale · ω_true + yaw_bias_radps
    /// (None without yaw-rate samples).
    pub yaw_bias_radps: Option<Estimate>,
    /// See `yaw_bias_radps`.
    pub yaw_scale: Option<Estimate>,
    /// The yaw-rate bias's σ from the fixes' and the inputs' noise alone
    /// (the sandwich), rad/s: the live filter's prior on the bias it learns
    /// next. `yaw_bias_radps`'s σ is at least the jackknife's as well, what
    /// the bias's effective value varies along the drive; the filter
    /// follows that variation with its own random walk, and starting it
    /// that unsure sent the RAV4's calibrated rest after 45 s 0.80 % off
    /// instead of 0.65 % (calibration-math §14). None without yaw rate.
    pub yaw_bias_noise_sigma_radps: Option<f64>,
    /// The effective rear tread's correction (multiplies the tread in use):
    /// held at 1, not observable, on a drive without turns both ways.
    pub rear_tread: Estimate,
    /// The turning of the drive's used part (rear wheels), left and right, radians.
    pub turns_rad: [f64; 2],
    /// The fixes' latency on the log's clock: a fix stamped `t` describes
    /// the vehicle at `t − latency`. Observable and with its σ when
    /// estimated; the given value with σ 0 when given.
    pub fixes_latency_s: Estimate,
    /// Whether the latency was given rather than estimated.
    pub latency_given: bool,
    /// The fixes the robust loss down-weighted, in time order.
    pub down_weighted: Vec<DownWeighted>,
    /// The weighted RMS position residual of each source (what the fixes it
    /// kept say), metres; None for a source without data.
    pub weighted_rms_m: [Option<f64>; 3],
    /// What the quality gate (`drive_gate`) refused, and why (empty
    /// before it ran or when everything passed).
    pub refused: Vec<GateRefusal>,
    /// Fixes used (those in segments of at least three fixes).
    pub fixes_used: usize,
    /// Distance driven over the used segments, with the fitted scale.
    pub distance_m: f64,
    /// The RMS position residual at the fixes after the fit of each heading
    /// source (rear wheels, yaw rate, steering), metres; None for a source
    /// without data.
    pub residual_rms_m: [Option<f64>; 3],
}

/// Prior standard deviations around the values in use.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PriorSigmas {
    /// Relative effective rear tread (fitted only from a drive with turns both ways).
    pub rear_tread: f64,
    /// Speed scale (relative).
    pub speed_scale: f64,
    /// Rear ratio correction (relative).
    pub rear_ratio: f64,
    /// Steering offset, radians.
    pub steer_offset_rad: f64,
    /// Steering gain correction (relative).
    pub steer_gain: f64,
    /// Yaw-rate bias, rad/s.
    pub yaw_bias_radps: f64,
    /// Yaw-rate scale (relative).
    pub yaw_scale: f64,
}

impl Default for PriorSigmas {
    /// 5 %, 1 %, 2°, 20 %, 1°/s, 10 %, tread 5 %.
    fn default() -> Self {
        Self {
            rear_tread: 0.05,
            speed_scale: 0.05,
            rear_ratio: 0.01,
            steer_offset_rad: 2.0 * PI / 180.0,
            steer_gain: 0.2,
            yaw_bias_radps: PI / 180.0,
            yaw_scale: 0.1,
        }
    }
}

/// The time between the log's clock and the fixes'.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FixesLatency {
    /// Estimated with the other parameters, within ±`bound_s` (a receiver's
    /// solution and its transport take a few tenths of a second; a clock
    /// more than a second off is a setup error to fix, not to fit).
    Estimate {
        /// The largest offset the fit may find, seconds.
        bound_s: f64,
    },
    /// Known: a fix stamped `t` on the log's clock describes the vehicle at
    /// `t − latency_s`.
    Given(f64),
}

/// The loss the fit minimises over the fixes' residuals.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Loss {
    /// Plain least squares: every fix counts in full (a jump of a receiver
    /// pulls the whole fit).
    LeastSquares,
    /// Cauchy's loss by iteratively reweighted least squares: a fix's weight
    /// is `1/(1 + e²/(m c² σ²))` (`e` its residual, `m` its components, `c`
    /// 2.385, 95 % efficient on Gaussian residuals) with `σ` from the
    /// median residual (the data's own scale, not a setting); a fix ten σ
    /// off counts 6 %, and unlike Huber's its pull falls to zero with the
    /// distance, so a 15 m jump moves nothing.
    Cauchy,
}

/// Cauchy's constant (95 % asymptotic efficiency on Gaussian residuals).
const CAUCHY_C: f64 = 2.385;
/// A fix whose weight falls below this in every source is named as down-weighted.
const DOWN_WEIGHTED: f64 = 0.5;

/// Settings of [`calibrate_drive_with`]; [`calibrate_drive`] uses the defaults.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriveOptions {
    /// The time offset between the log and the fixes: estimated or given.
    pub latency: FixesLatency,
    /// The loss over the fixes' residuals.
    pub loss: Loss,
    /// The effective rear tread is fitted only when the drive turns at least
    /// this much each way (summed over its turns), radians; otherwise it is
    /// held (a drive turning one way only cannot tell it from the ratio).
    pub min_turn_each_way_rad: f64,
    /// Longest segment, from its first fix to its last.
    pub max_segment_s: f64,
    /// Most fixes in one segment.
    pub max_segment_fixes: usize,
    /// Priors around the values in use.
    pub priors: PriorSigmas,
    /// A parameter is observable when posterior σ < this × prior σ.
    pub observable_ratio: f64,
}

impl Default for DriveOptions {
    /// Segments of at most 60 s and 60 fixes, the default priors, observable
    /// below 0.3, the latency estimated within ±1 s, Cauchy's loss, the tread
    /// fitted from 60° of turns each way.
    fn default() -> Self {
        Self {
            latency: FixesLatency::Estimate { bound_s: 1.0 },
            loss: Loss::Cauchy,
            min_turn_each_way_rad: 60.0 * PI / 180.0,
            max_segment_s: 60.0,
            max_segment_fixes: 60,
            priors: PriorSigmas::default(),
            observable_ratio: 0.3,
        }
    }
}

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
/// Blocks of the delete-a-block jackknife (see `Problem::jackknife_sigma`):
/// at most this many, each of at least [`JACKKNIFE_MIN_FIXES`] fixes.
const JACKKNIFE_BLOCKS: usize = 6;
/// Fewest fixes in a jackknife block: a block must be longer than the turn
/// or the slip whose model error it is to reveal (ten fixes: ten seconds of
/// a 1 Hz receiver, about one turn of a road car).
const JACKKNIFE_MIN_FIXES: usize = 10;

fn wrap(a: f64) -> f64 {
    let w = a.rem_euclid(2.0 * PI);
    if w > PI { w - 2.0 * PI } else { w }
}

/// Inputs checked and arranged for the reckonings.
struct Prepared {
    t: Vec<f64>,
    dl: Vec<f64>,
    dr: Vec<f64>,
    /// Steering angle at each sample, held from the last known value.
    steer: Option<Vec<f64>>,
    /// Yaw rate of each sample's interval, held from the last known value.
    yaw: Option<Vec<f64>>,
    /// White noise of each input signal per value, `[unused, yaw, steer]`.
    noise: [f64; 3],
    /// Slipping samples up to each sample (a prefix count).
    slips: Vec<usize>,
}

/// The white noise of a signal from its values in order: the robust σ
/// (1.4826 × median absolute value) of second differences, divided by √6.
/// Second differences cancel the signal's own trends and the median ignores
/// its kinks (a step of the yaw rate, a steering ramp's ends); what remains
/// is noise and quantisation, which integrate into a heading random walk.
fn white_noise(values: impl Iterator<Item = Option<f64>>) -> f64 {
    let v: Vec<f64> = values.flatten().collect();
    let mut d2: Vec<f64> = v
        .windows(3)
        .map(|w| (w[2] - 2.0 * w[1] + w[0]).abs())
        .collect();
    if d2.is_empty() {
        return 0.0;
    }
    d2.sort_by(f64::total_cmp);
    1.4826 * d2[d2.len() / 2] / 6.0_f64.sqrt()
}

/// Fills gaps with the last known value (the first known one before it).
fn held(values: impl Iterator<Item = Option<f64>>) -> Option<Vec<f64>> {
    let raw: Vec<Option<f64>> = values.collect();
    let first = raw.iter().flatten().copied().next()?;
    let mut last = first;
    Some(
        raw.into_iter()
            .map(|v| {
                if let Some(v) = v {
                    last = v;
                }
                last
            })
            .collect(),
    )
}

/// One segment: fixes `fixes` (indices into the fix list, at least three),
/// the sample range its reckoning needs and each fix's interpolation.
struct Segment {
    fixes: Vec<usize>,
    /// First sample of the reckoning (at or before the first fix, less the
    /// largest latency).
    start: usize,
    /// Last sample the reckoning may need (at or after the last fix, plus
    /// the largest latency).
    end: usize,
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
}

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
        Ok(Self {
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
                let (sp, sh) = (fit.sigma[src * 2], fit.sigma[src * 2 + 1]);
                for (j, rj) in rel.iter().enumerate() {
                    let fix = &self.fixes[seg.fixes[j]];
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
                        (n + w, s + w * r.raw * r.raw)
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

    /// The robust loss's weights from the residuals at `fit` (iteratively
    /// reweighted least squares): per group, the scale from the median of the
    /// fixes' squared residuals (`σ² = median(e²)/median(χ²_m)`, `m` the
    /// components: robust to any share of jumps below one half), then
    /// Cauchy's weight of each fix. With [`Loss::LeastSquares`] all stay 1.
    fn update_weights(&self, fit: &mut Fit, horizon_s: f64) {
        if self.options.loss == Loss::LeastSquares {
            return;
        }
        let rows = self.rows(fit, horizon_s, false);
        for group in 0..N_GROUP {
            let mut e2: Vec<(usize, f64)> = Vec::new();
            for r in rows.iter().filter(|r| r.group == group) {
                match e2.last_mut() {
                    Some((f, e)) if *f == r.fix => *e += r.raw * r.raw,
                    _ => e2.push((r.fix, r.raw * r.raw)),
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

    /// Covariance of the globals (see the module documentation).
    fn covariance(&self, fit: &Fit) -> Result<DMatrix<f64>> {
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
                    let unit = 1.0 / fit.sigma[row.group];
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
        Ok(DriveCalibration {
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

    /// Which globals the drive tells (sandwich σ below
    /// [`DriveOptions::observable_ratio`] of the prior's); the others are
    /// held at their value in use and the rest refitted. Returns that and
    /// the sandwich σ of the final fit.
    fn hold_what_is_not_told(&self, fit: &mut Fit) -> Result<([bool; N_GLOBAL], [f64; N_GLOBAL])> {
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
    fn jackknife_sigma(&self, fit: &Fit) -> Result<[f64; N_GLOBAL]> {
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

    /// Whether the drive turned enough each way to tell the tread.
    fn turns_both_ways(&self) -> bool {
        self.turns_rad[0].min(self.turns_rad[1]) >= self.options.min_turn_each_way_rad
    }

    /// The fixes every active source down-weighted, with the residual of the
    /// source that agrees best.
    fn down_weighted(&self, fit: &Fit, rows: &[Row]) -> Vec<DownWeighted> {
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

/// Checks the samples and fixes: enough of them, finite, in time order,
/// every fix within the samples' span.
fn check(samples: &[DriveSample], fixes: &[Fix]) -> Result<()> {
    if samples.len() < 2 {
        return Err(Error::NotEnoughSamples { got: samples.len() });
    }
    for (index, s) in samples.iter().enumerate() {
        let fields = [
            ("t_s", Some(s.t_s)),
            ("rear_left_m", Some(s.rear_left_m)),
            ("rear_right_m", Some(s.rear_right_m)),
            ("steer_angle_rad", s.steer_angle_rad),
            ("yaw_rate_radps", s.yaw_rate_radps),
        ];
        for (field, value) in fields {
            if let Some(value) = value.filter(|v| !v.is_finite()) {
                return Err(Error::NotFinite {
                    what: "sample",
                    index,
                    field,
                    value,
                });
            }
        }
        if index > 0 && s.t_s <= samples[index - 1].t_s {
            return Err(Error::NotIncreasing {
                what: "sample",
                index,
                t_s: s.t_s,
                previous_s: samples[index - 1].t_s,
            });
        }
    }
    if fixes.len() < 3 {
        return Err(Error::NotEnoughFixes {
            what: "in all",
            got: fixes.len(),
            needed: 3,
        });
    }
    let (first_s, last_s) = (samples[0].t_s, samples[samples.len() - 1].t_s);
    for (index, f) in fixes.iter().enumerate() {
        let fields = [
            ("t_s", Some(f.t_s)),
            ("x_m", Some(f.x_m)),
            ("y_m", Some(f.y_m)),
            ("heading_rad", f.heading_rad),
        ];
        for (field, value) in fields {
            if let Some(value) = value.filter(|v| !v.is_finite()) {
                return Err(Error::NotFinite {
                    what: "fix",
                    index,
                    field,
                    value,
                });
            }
        }
        if index > 0 && f.t_s <= fixes[index - 1].t_s {
            return Err(Error::NotIncreasing {
                what: "fix",
                index,
                t_s: f.t_s,
                previous_s: fixes[index - 1].t_s,
            });
        }
        if f.t_s < first_s || f.t_s > last_s {
            return Err(Error::FixOutsideSamples {
                index,
                t_s: f.t_s,
                first_s,
                last_s,
            });
        }
    }
    Ok(())
}

/// Splits the fixes into segments of at most `max_segment_s` and
/// `max_segment_fixes`; a group of fewer than three fixes joins the previous
/// segment when the gap allows, else it is dropped.
/// Each segment's reckoning spans its fixes widened by `margin_s` (the
/// largest latency) where the samples allow. A slipping sample (`slips`,
/// the prefix count of slipping samples) between two fixes ends a segment.
fn split(
    t: &[f64],
    slips: &[usize],
    fixes: &[Fix],
    options: &DriveOptions,
    margin_s: f64,
) -> Vec<Segment> {
    let slips_until = |ts: f64| {
        let k = t.partition_point(|&s| s <= ts);
        if k == 0 {
            0
        } else {
            slips[(k - 1).min(slips.len() - 1)]
        }
    };
    let mut groups: Vec<Vec<usize>> = Vec::new();
    let mut current: Vec<usize> = Vec::new();
    for (i, f) in fixes.iter().enumerate() {
        let starts_new = current.first().is_some_and(|&first| {
            let last = current[current.len() - 1];
            f.t_s - fixes[first].t_s > options.max_segment_s
                || current.len() >= options.max_segment_fixes
                || slips_until(f.t_s + margin_s) > slips_until(fixes[last].t_s - margin_s)
        });
        if starts_new {
            groups.push(std::mem::take(&mut current));
        }
        current.push(i);
    }
    groups.push(current);
    // A group of fewer than three fixes joins the one before it when the
    // gap between them is within the time limit; otherwise it is dropped.
    let mut merged: Vec<Vec<usize>> = Vec::new();
    for group in groups {
        let joins = group.len() < 3
            && merged.last().is_some_and(|prev: &Vec<usize>| {
                let prev_t = fixes[prev[prev.len() - 1]].t_s;
                fixes[group[0]].t_s - prev_t <= options.max_segment_s
                    && slips_until(fixes[group[group.len() - 1]].t_s + margin_s)
                        == slips_until(prev_t - margin_s)
            });
        match merged.last_mut() {
            Some(prev) if joins => prev.extend(group),
            _ => merged.push(group),
        }
    }
    merged
        .into_iter()
        .filter(|g| g.len() >= 3)
        .map(|fixes_idx| {
            let at: Vec<(usize, f64)> = fixes_idx
                .iter()
                .map(|&f| {
                    let tf = fixes[f].t_s;
                    // First sample at or after the fix; the fix lies in
                    // [t[i], t[i+1]] with i = k − 1 (k ≥ 1).
                    let k = t.partition_point(|&ts| ts < tf).clamp(1, t.len() - 1);
                    let i = k - 1;
                    (i, ((tf - t[i]) / (t[k] - t[i])).clamp(0.0, 1.0))
                })
                .collect();
            let first_t = fixes[fixes_idx[0]].t_s - margin_s;
            let last_t = fixes[fixes_idx[fixes_idx.len() - 1]].t_s + margin_s;
            let start = t.partition_point(|&ts| ts <= first_t).saturating_sub(1);
            let end = t.partition_point(|&ts| ts < last_t).min(t.len() - 1);
            Segment {
                start: start.min(at[0].0),
                end: end.max(at[at.len() - 1].0 + 1).max(start + 1),
                fixes: fixes_idx,
            }
        })
        .collect()
}

/// The rear wheels' turning over the segments' samples, left and right:
/// the heading change of each second (with the tread in use) summed by sign,
/// so a slalom's wiggles and the wheels' noise count little and a turn in full.
fn turns(prep: &Prepared, segments: &[Segment], rear_tread_m: f64) -> [f64; 2] {
    let mut out = [0.0; 2];
    for seg in segments {
        let (mut acc, mut t0) = (0.0, prep.t[seg.start]);
        for k in seg.start + 1..=seg.end {
            acc += (prep.dr[k] - prep.dl[k]) / rear_tread_m;
            if prep.t[k] - t0 >= 1.0 || k == seg.end {
                out[usize::from(acc < 0.0)] += acc.abs();
                (acc, t0) = (0.0, prep.t[k]);
            }
        }
    }
    out
}

/// The parameter values after the calibration `cal` of a drive recorded
/// with `base`: every observable correction applied, the rest as in `base`.
pub fn calibrated_values(base: &ParamValues, cal: &DriveCalibration) -> ParamValues {
    let mut v = *base;
    let used = |e: &Estimate, held: f64| if e.observable { e.value } else { held };
    let s = used(&cal.speed_scale, 1.0);
    let r = used(&cal.rear_ratio, 1.0);
    v.rear_left_diameter_m *= s * 2.0 / (1.0 + r);
    v.rear_right_diameter_m *= s * 2.0 * r / (1.0 + r);
    v.rear_tread_m *= used(&cal.rear_tread, 1.0);
    // φ = g·(gain·u + offset) + o.
    let g = cal.steer_gain.map_or(1.0, |e| used(&e, 1.0));
    let o = cal.steer_offset_rad.map_or(0.0, |e| used(&e, 0.0));
    v.steering_gain *= g;
    v.steering_offset_rad = g * v.steering_offset_rad + o;
    // The samples carried ω_raw / c0 (c0 the scale in use): ω_raw = c0·c·ω + c0·b.
    let c0 = base.yaw_rate_scale.unwrap_or(1.0);
    let b0 = base.yaw_rate_bias_radps.unwrap_or(0.0);
    if let (Some(bias), Some(scale)) = (cal.yaw_bias_radps, cal.yaw_scale) {
        let c = used(&scale, 1.0);
        if scale.observable || bias.observable {
            v.yaw_rate_scale = Some(c0 * c);
        }
        if bias.observable {
            v.yaw_rate_bias_radps = Some(c0 * bias.value);
            // The filter's prior: the noise's σ (see
            // `DriveCalibration::yaw_bias_noise_sigma_radps`).
            let sigma = cal.yaw_bias_noise_sigma_radps.unwrap_or(bias.sigma);
            v.yaw_rate_bias_sigma_radps = Some(c0 * sigma);
        } else if scale.observable {
            v.yaw_rate_bias_radps = Some(b0);
        }
    }
    v
}

#[cfg(test)]
mod tests;
