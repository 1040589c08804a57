//! The report of a drive calibration (`calibrate --fixes --report DIR`):
//! `calibration.svg`, the fixes with the drive dead-reckoned from the first
//! fix before and after the calibration (rear wheels; the yaw-rate sensor
//! when the car has one), and `calibration.json`, every number of the
//! result.

use crate::files::TRAJECTORY_AXES;
use crate::files::{
    PlotResult, PlottedReport, ReportError, draw_legend, draw_line, square_view, write_report,
    xy_chart,
};
use canodom_calib::drive::{DriveCalibration, DriveSample, Estimate, Fix};
use canodom_params::persist::ParamValues;
use plotters::coord::Shift;
use plotters::prelude::*;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Most points of a drawn path (a long drive at 100 Hz has tens of thousands).
const MAX_POINTS: usize = 2000;

/// One estimate as the JSON carries it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ReportEstimate {
    /// The estimate (the value in use when not observable).
    pub value: f64,
    /// Its standard deviation.
    pub sigma: f64,
    /// Whether the drive told it.
    pub observable: bool,
}

impl From<Estimate> for ReportEstimate {
    fn from(e: Estimate) -> Self {
        Self {
            value: e.value,
            sigma: e.sigma,
            observable: e.observable,
        }
    }
}

/// The report of one drive calibration.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DriveReport {
    /// Fixes used and the distance they span.
    pub fixes_used: usize,
    /// Metres driven over the used fixes.
    pub distance_m: f64,
    /// The estimates (corrections of the values in use).
    pub speed_scale: ReportEstimate,
    /// Right/left rear distance ratio correction.
    pub rear_ratio: ReportEstimate,
    /// Steering offset correction, rad.
    pub steer_offset_rad: Option<ReportEstimate>,
    /// Steering gain correction.
    pub steer_gain: Option<ReportEstimate>,
    /// Yaw-rate sensor bias, rad/s.
    pub yaw_bias_radps: Option<ReportEstimate>,
    /// Yaw-rate sensor scale.
    pub yaw_scale: Option<ReportEstimate>,
    /// RMS position residual of each heading source (rear wheels, yaw rate, steering).
    pub residual_rms_m: [Option<f64>; 3],
    /// The values in use while recording and the committed ones.
    pub before: ParamValues,
    /// The committed values.
    pub after: ParamValues,
    /// The fixes, x/y.
    pub fixes: Vec<[f64; 2]>,
    /// Rear-wheel dead reckoning with the values before, from the first fix.
    pub rear_before: Vec<[f64; 2]>,
    /// The same with the calibrated values.
    pub rear_after: Vec<[f64; 2]>,
    /// Yaw-rate heading with the calibrated bias and scale, calibrated distances.
    pub yaw_after: Option<Vec<[f64; 2]>>,
    /// At each fix: seconds since the first fix and the distance of each
    /// reckoning from the fix (rear before, rear after, yaw rate after), metres.
    pub errors_at_fixes: Vec<[f64; 4]>,
}

/// Dead reckoning of `samples` from `start` (x, y, heading) with rear
/// distance factors `k` and the heading from the rear wheels, or from
/// `yaw` (bias, scale) when given. Only samples from the start's time on.
fn reckon(
    samples: &[DriveSample],
    start: (f64, f64, f64, f64),
    k: (f64, f64),
    tread_m: f64,
    yaw: Option<(f64, f64)>,
) -> Vec<[f64; 3]> {
    let (t0, mut x, mut y, mut th) = start;
    let mut out = vec![[t0, x, y]];
    let mut prev_t = t0;
    for s in samples.iter().filter(|s| s.t_s > t0) {
        let (dl, dr) = (s.rear_left_m * k.0, s.rear_right_m * k.1);
        let d = 0.5 * (dl + dr);
        let dth = match (yaw, s.yaw_rate_radps) {
            (Some((bias, scale)), Some(w)) => (w - bias) / scale * (s.t_s - prev_t),
            _ => (dr - dl) / tread_m,
        };
        prev_t = s.t_s;
        let mid = th + 0.5 * dth;
        x += d * mid.cos();
        y += d * mid.sin();
        th += dth;
        out.push([s.t_s, x, y]);
    }
    out
}

/// The path's x/y, thinned for drawing.
fn xy(path: &[[f64; 3]]) -> Vec<[f64; 2]> {
    thin(&path.iter().map(|p| [p[1], p[2]]).collect::<Vec<_>>())
}

/// The distance of `path` (interpolated at the fix's time) from `fix`.
fn error_at(path: &[[f64; 3]], fix: &Fix) -> f64 {
    let i = path.partition_point(|p| p[0] < fix.t_s);
    if path.is_empty() {
        return f64::NAN;
    }
    let (a, b) = (path[i.saturating_sub(1)], path[i.min(path.len() - 1)]);
    let f = if b[0] > a[0] {
        ((fix.t_s - a[0]) / (b[0] - a[0])).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (a[1] + f * (b[1] - a[1]) - fix.x_m).hypot(a[2] + f * (b[2] - a[2]) - fix.y_m)
}

/// At most [`MAX_POINTS`] of `points`, evenly, with the last kept.
fn thin(points: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let step = points.len().div_ceil(MAX_POINTS).max(1);
    let mut out: Vec<[f64; 2]> = points.iter().step_by(step).copied().collect();
    if let Some(last) = points.last()
        && out.last() != Some(last)
    {
        out.push(*last);
    }
    out
}

/// Where the reckoning starts: the first fix, heading towards the first
/// fix at least 10 m away (or the first fix's own heading).
fn start_of(fixes: &[Fix]) -> Option<(f64, f64, f64, f64)> {
    let first = fixes.first()?;
    let heading = first.heading_rad.or_else(|| {
        fixes
            .iter()
            .find(|f| (f.x_m - first.x_m).hypot(f.y_m - first.y_m) >= 10.0)
            .map(|f| (f.y_m - first.y_m).atan2(f.x_m - first.x_m))
    })?;
    Some((first.t_s, first.x_m, first.y_m, heading))
}

impl DriveReport {
    /// Builds the report of `cal`, fitted on `samples` and `fixes` recorded
    /// with `before`, committed as `after`.
    pub fn build(
        samples: &[DriveSample],
        fixes: &[Fix],
        before: &ParamValues,
        after: &ParamValues,
        cal: &DriveCalibration,
    ) -> Self {
        let tread = before.rear_tread_m;
        let k_after = (
            after.rear_left_diameter_m / before.rear_left_diameter_m,
            after.rear_right_diameter_m / before.rear_right_diameter_m,
        );
        let held =
            |e: Option<Estimate>, v: f64| e.map_or(v, |e| if e.observable { e.value } else { v });
        let yaw = cal
            .yaw_bias_radps
            .map(|_| (held(cal.yaw_bias_radps, 0.0), held(cal.yaw_scale, 1.0)));
        let (rear_before, rear_after, yaw_after) = match start_of(fixes) {
            Some(start) => (
                reckon(samples, start, (1.0, 1.0), tread, None),
                reckon(samples, start, k_after, tread, None),
                yaw.map(|y| reckon(samples, start, k_after, tread, Some(y))),
            ),
            None => (Vec::new(), Vec::new(), None),
        };
        let t0 = fixes.first().map_or(0.0, |f| f.t_s);
        let errors_at_fixes = fixes
            .iter()
            .map(|f| {
                [
                    f.t_s - t0,
                    error_at(&rear_before, f),
                    error_at(&rear_after, f),
                    yaw_after.as_ref().map_or(f64::NAN, |p| error_at(p, f)),
                ]
            })
            .collect();
        Self {
            fixes_used: cal.fixes_used,
            distance_m: cal.distance_m,
            speed_scale: cal.speed_scale.into(),
            rear_ratio: cal.rear_ratio.into(),
            steer_offset_rad: cal.steer_offset_rad.map(Into::into),
            steer_gain: cal.steer_gain.map(Into::into),
            yaw_bias_radps: cal.yaw_bias_radps.map(Into::into),
            yaw_scale: cal.yaw_scale.map(Into::into),
            residual_rms_m: cal.residual_rms_m,
            before: *before,
            after: *after,
            fixes: thin(&fixes.iter().map(|f| [f.x_m, f.y_m]).collect::<Vec<_>>()),
            rear_before: xy(&rear_before),
            rear_after: xy(&rear_after),
            yaw_after: yaw_after.as_deref().map(xy),
            errors_at_fixes,
        }
    }

    /// The distance of each reckoning from each fix, over time: what the
    /// trajectory's scale hides on a long straight road.
    fn draw_errors(
        &self,
        area: &DrawingArea<SVGBackend<'_>, plotters::coord::Shift>,
    ) -> PlotResult {
        let t_max = self.errors_at_fixes.last().map_or(1.0, |e| e[0]).max(1.0);
        let e_max = self
            .errors_at_fixes
            .iter()
            .flat_map(|e| e[1..].iter().copied())
            .filter(|e| e.is_finite())
            .fold(0.1f64, f64::max);
        let mut chart = ChartBuilder::on(area)
            .caption("distance from each fix", ("sans-serif", 16))
            .margin(15)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..t_max, 0.0..e_max * 1.05)?;
        chart
            .configure_mesh()
            .x_desc("time since the first fix (s)")
            .y_desc("error (m)")
            .draw()?;
        for (k, colour, label) in [
            (1, RED, "rear wheels, before"),
            (2, BLUE, "rear wheels, calibrated"),
            (3, GREEN, "yaw rate, calibrated"),
        ] {
            let points: Vec<(f64, f64)> = self
                .errors_at_fixes
                .iter()
                .filter(|e| e[k].is_finite())
                .map(|e| (e[0], e[k]))
                .collect();
            if points.is_empty() {
                continue;
            }
            draw_line(&mut chart, points, colour, label)?;
        }
        draw_legend(&mut chart)
    }
}

/// Builds the report and writes `calibration.svg` and `calibration.json` into `dir`.
///
/// # Errors
/// As [`write_report`].
pub fn write_drive_report(
    dir: &Path,
    samples: &[DriveSample],
    fixes: &[Fix],
    before: &ParamValues,
    after: &ParamValues,
    cal: &DriveCalibration,
) -> Result<(PathBuf, PathBuf), ReportError> {
    write_report(dir, &DriveReport::build(samples, fixes, before, after, cal))
}

impl PlottedReport for DriveReport {
    const SVG_SIZE_PX: (u32, u32) = (900, 900);

    fn draw(&self, root: &DrawingArea<SVGBackend<'_>, Shift>) -> PlotResult {
        root.fill(&WHITE)?;
        let (xs, ys) = square_view(
            self.fixes
                .iter()
                .chain(&self.rear_before)
                .chain(&self.rear_after)
                .chain(self.yaw_after.iter().flatten()),
        );
        let title = format!(
            "canodom drive calibration: {} fixes over {:.0} m",
            self.fixes_used, self.distance_m
        );
        let root = root.titled(&title, ("sans-serif", 22))?;
        let (top, bottom) = root.split_vertically(430);
        self.draw_errors(&bottom)?;
        let mut chart = xy_chart(
            &top,
            "the drive, dead-reckoned from the first fix",
            &TRAJECTORY_AXES,
            (xs, ys),
        )?;
        let paths = [
            (Some(&self.rear_before), RED, "rear wheels, before"),
            (Some(&self.rear_after), BLUE, "rear wheels, calibrated"),
            (self.yaw_after.as_ref(), GREEN, "yaw rate, calibrated"),
        ];
        for (path, colour, label) in paths {
            let Some(path) = path else { continue };
            draw_line(&mut chart, path.iter().map(|p| (p[0], p[1])), colour, label)?;
        }
        chart
            .draw_series(
                self.fixes
                    .iter()
                    .map(|p| Circle::new((p[0], p[1]), 3, BLACK.filled())),
            )?
            .label("fixes")
            .legend(|(x, y)| Circle::new((x + 10, y), 3, BLACK.filled()));
        draw_legend(&mut chart)
    }
}
