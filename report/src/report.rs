//! Calibration reports (issue 6): every number of a calibration in a JSON
//! file and a picture of it in an SVG, so that a person sees at a glance
//! whether the calibration worked.
//!
//! The picture shows, in the track's world frame (S_CCW at the origin,
//! S_CW at (2ρ, 0), the loop at +y for both directions, see
//! `canodom_calib::Track::run_to_world`):
//! - the reference track;
//! - every run's rear odometry replayed with the parameters used while
//!   recording ("before") and with the calibrated ones ("after");
//! - below, one zoomed panel per start point with the end positions before
//!   and after and their centres of gravity, labelled with their distance
//!   from the start: the paper's E_max, shrinking is the whole point.
//!
//! Both files are written atomically (temporary file, `fsync`, rename,
//! `fsync` of the directory), so a reader, or a crash, never sees half a
//! report. [`CalibrationReport::build`] is pure; only [`write_report`] does
//! I/O, which is why the live daemon can build a report on commit and hand
//! the writing to a blocking task. A committed steering map has its own
//! report ([`SteeringReport`]), written the same way.
//!
//! [`write_report`]: crate::files::write_report
//! [`SteeringReport`]: crate::steering_report::SteeringReport

use crate::files::{
    AFTER_COLOUR, BEFORE_COLOUR, MetreAxes, PlotResult, ReportError, ReportFiles, json_line,
    svg_text, xy_chart,
};
use canodom_calib::methods::centroids;
use canodom_calib::{CalibrationResult, Direction, Method, RearParams, Run, Track};
use canodom_fusion::Pose;
use plotters::coord::Shift;
use plotters::prelude::*;
use serde::Serialize;
use std::f64::consts::PI;

/// Paths are thinned to at most this many points: enough for a smooth line
/// at any zoom a lap needs, small enough that twenty runs stay well under a
/// megabyte.
const MAX_PATH_POINTS: usize = 400;

/// A rear parameter set as reported.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ReportParams {
    /// Rear tread b (the effective one after calibration), metres.
    pub rear_tread_m: f64,
    /// Rear-left wheel diameter, metres.
    pub rear_left_diameter_m: f64,
    /// Rear-right wheel diameter, metres.
    pub rear_right_diameter_m: f64,
    /// Right over left diameter.
    pub diameter_ratio: f64,
    /// Standard deviation of the tread, when the method gives one.
    pub rear_tread_std_m: Option<f64>,
    /// Standard deviation of the ratio, when the method gives one.
    pub diameter_ratio_std: Option<f64>,
}

impl ReportParams {
    fn of(rear: &RearParams, tread_std_m: Option<f64>, ratio_std: Option<f64>) -> Self {
        Self {
            rear_tread_m: rear.tread_m,
            rear_left_diameter_m: rear.left_diameter_m,
            rear_right_diameter_m: rear.right_diameter_m,
            diameter_ratio: rear.ratio(),
            rear_tread_std_m: tread_std_m,
            diameter_ratio_std: ratio_std,
        }
    }
}

/// Centres of gravity of the end errors (odometry end − real end, run
/// frame) per direction, and their distances from the start.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ReportCentres {
    /// CCW centre of gravity (x, y) in the CCW run frame, metres.
    pub ccw_m: [f64; 2],
    /// CW centre of gravity (x, y) in the CW run frame, metres.
    pub cw_m: [f64; 2],
    /// |ccw_m|.
    pub ccw_distance_m: f64,
    /// |cw_m|.
    pub cw_distance_m: f64,
    /// The larger of the two distances (E_max of the paper).
    pub e_max_m: f64,
}

impl ReportCentres {
    fn of(runs: &[Run], rear: &RearParams) -> Self {
        let c = centroids(runs, rear);
        let d = |v: [f64; 2]| v[0].hypot(v[1]);
        Self {
            ccw_m: c.ccw_m,
            cw_m: c.cw_m,
            ccw_distance_m: d(c.ccw_m),
            cw_distance_m: d(c.cw_m),
            e_max_m: c.e_max_m(),
        }
    }

    fn of_direction(&self, direction: Direction) -> ([f64; 2], f64) {
        match direction {
            Direction::Ccw => (self.ccw_m, self.ccw_distance_m),
            Direction::Cw => (self.cw_m, self.cw_distance_m),
        }
    }
}

/// One run as reported.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReportRun {
    /// A name for the run (its log file, or "CW 3").
    pub label: String,
    /// `"cw"` or `"ccw"`.
    pub direction: &'static str,
    /// The rear odometry path with the parameters used while recording,
    /// world frame, metres (thinned to at most a few hundred points; the
    /// last point is the exact end).
    pub path_before_m: Vec<[f64; 2]>,
    /// The same with the calibrated parameters.
    pub path_after_m: Vec<[f64; 2]>,
    /// End position before, world frame.
    pub end_before_m: [f64; 2],
    /// End position after, world frame.
    pub end_after_m: [f64; 2],
    /// End error (odometry end − real end) before, run frame.
    pub end_error_before_m: [f64; 2],
    /// End error after, run frame.
    pub end_error_after_m: [f64; 2],
    /// Total turn of the odometry before, radians (±2π ideally).
    pub total_turn_before_rad: f64,
    /// Total turn after.
    pub total_turn_after_rad: f64,
    /// Path length before, metres.
    pub length_before_m: f64,
    /// Path length after, metres.
    pub length_after_m: f64,
    /// The measured real end pose (x, y in metres, heading in radians, run
    /// frame), when the operator gave one; the start otherwise.
    pub measured_end: Option<[f64; 3]>,
}

/// The reference track.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReportTrack {
    /// Radius ρ of the semicircles, metres.
    pub radius_m: f64,
    /// Length of one lap, metres.
    pub length_m: f64,
    /// Start of the CCW runs, world frame (x, y, heading).
    pub start_ccw: [f64; 3],
    /// Start of the CW runs, world frame.
    pub start_cw: [f64; 3],
    /// The lap as a polyline, world frame (both directions drive this loop).
    pub path_m: Vec<[f64; 2]>,
}

/// Everything a calibration produced, ready to be written as JSON and SVG.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CalibrationReport {
    /// The method's name, as in the TOML (`paper`, `heading`, `exact`, ...).
    pub method: &'static str,
    /// The reference track.
    pub track: ReportTrack,
    /// Parameters used while recording (the nominal ones, or the set in use).
    pub nominal: ReportParams,
    /// The calibrated parameters with their uncertainties.
    pub calibrated: ReportParams,
    /// α of the method (heading error on the straights), radians.
    pub alpha_rad: f64,
    /// β of the method (heading error on the turns), radians.
    pub beta_rad: f64,
    /// E_max with the parameters used (the TOML's `end_error_before_m`).
    pub end_error_before_m: f64,
    /// E_max with the calibrated parameters (`end_error_after_m`).
    pub end_error_after_m: f64,
    /// Centres of gravity of the end errors before.
    pub centres_before: ReportCentres,
    /// Centres of gravity after.
    pub centres_after: ReportCentres,
    /// Iterations of the method.
    pub iterations: u32,
    /// Whether the method converged.
    pub converged: bool,
    /// Every run.
    pub runs: Vec<ReportRun>,
}

/// The method's name as `canodom calibrate` prints it.
pub fn method_name(method: Method) -> &'static str {
    match method {
        Method::PaperX => "paper-x",
        Method::PaperY => "paper-y",
        Method::PaperLeastSquares => "paper",
        Method::Heading => "heading",
        Method::Exact => "exact",
    }
}

fn direction_name(direction: Direction) -> &'static str {
    match direction {
        Direction::Cw => "cw",
        Direction::Ccw => "ccw",
    }
}

/// The rear odometry of `run` with `rear`, every step, in the run frame:
/// the same update as the calib crate's replay (Δd = (d_R+d_L)/2,
/// Δθ = (d_R−d_L)/b, midpoint heading).
fn replay_path(run: &Run, rear: &RearParams) -> (Vec<Pose>, f64) {
    let kl = PI * rear.left_diameter_m;
    let kr = PI * rear.right_diameter_m;
    let mut pose = Pose::default();
    let mut length_m = 0.0;
    let mut out = Vec::with_capacity(run.samples.len() + 1);
    out.push(pose);
    for s in &run.samples {
        let dl = kl * s.rear_left_rev;
        let dr = kr * s.rear_right_rev;
        let inc = canodom_fusion::odometry::Increment {
            distance_m: 0.5 * (dl + dr),
            dtheta_rad: (dr - dl) / rear.tread_m,
        };
        pose = pose.advanced(inc);
        length_m += inc.distance_m.abs();
        out.push(pose);
    }
    (out, length_m)
}

/// Every `k`-th point plus the last, so the end stays exact.
fn thin(points: &[[f64; 2]]) -> Vec<[f64; 2]> {
    if points.len() <= MAX_PATH_POINTS {
        return points.to_vec();
    }
    let step = points.len().div_ceil(MAX_PATH_POINTS - 1);
    let mut out: Vec<[f64; 2]> = points.iter().step_by(step).copied().collect();
    if let Some(&last) = points.last()
        && out.last() != Some(&last)
    {
        out.push(last);
    }
    out
}

fn xy(p: Pose) -> [f64; 2] {
    [p.x_m, p.y_m]
}

fn report_run(
    run: &Run,
    label: String,
    used: &RearParams,
    rear: &RearParams,
    track: Track,
) -> ReportRun {
    let dir = run.direction;
    let world = |poses: &[Pose]| -> Vec<[f64; 2]> {
        poses
            .iter()
            .map(|&p| xy(track.run_to_world(dir, p)))
            .collect()
    };
    let (before, length_before_m) = replay_path(run, used);
    let (after, length_after_m) = replay_path(run, rear);
    let end = |poses: &[Pose]| poses.last().copied().unwrap_or_default();
    let (end_b, end_a) = (end(&before), end(&after));
    let real = run.real_end_m();
    ReportRun {
        label,
        direction: direction_name(dir),
        path_before_m: thin(&world(&before)),
        path_after_m: thin(&world(&after)),
        end_before_m: xy(track.run_to_world(dir, end_b)),
        end_after_m: xy(track.run_to_world(dir, end_a)),
        end_error_before_m: [end_b.x_m - real[0], end_b.y_m - real[1]],
        end_error_after_m: [end_a.x_m - real[0], end_a.y_m - real[1]],
        total_turn_before_rad: end_b.heading_rad,
        total_turn_after_rad: end_a.heading_rad,
        length_before_m,
        length_after_m,
        measured_end: run.measured_end.map(|p| [p.x_m, p.y_m, p.heading_rad]),
    }
}

impl CalibrationReport {
    /// The report of `result`, computed from `runs` on `track` (the runs the
    /// result was computed from, in any order). `labels` names the runs in
    /// the same order; missing labels become "CW 1", "CCW 2", ...
    pub fn build(
        result: &CalibrationResult,
        track: Track,
        runs: &[Run],
        labels: &[String],
    ) -> Self {
        let mut counts = [0usize; 2];
        let report_runs = runs
            .iter()
            .enumerate()
            .map(|(i, run)| {
                let k = &mut counts[usize::from(run.direction == Direction::Cw)];
                *k += 1;
                let label = labels.get(i).cloned().unwrap_or_else(|| {
                    format!("{} {k}", direction_name(run.direction).to_uppercase())
                });
                report_run(run, label, &result.used, &result.rear, track)
            })
            .collect();
        let pose3 = |p: Pose| [p.x_m, p.y_m, p.heading_rad];
        Self {
            method: method_name(result.method),
            track: ReportTrack {
                radius_m: track.radius_m(),
                length_m: track.length_m(),
                start_ccw: pose3(track.start_pose_world(Direction::Ccw)),
                start_cw: pose3(track.start_pose_world(Direction::Cw)),
                path_m: track
                    .reference_path_world(Direction::Ccw, 241)
                    .into_iter()
                    .map(xy)
                    .collect(),
            },
            nominal: ReportParams::of(&result.used, None, None),
            calibrated: ReportParams {
                // The ratio as the TOML prints it (the result's own, not recomputed).
                diameter_ratio: result.ratio(),
                ..ReportParams::of(&result.rear, result.tread_std_m, result.ratio_std)
            },
            alpha_rad: result.alpha_rad,
            beta_rad: result.beta_rad,
            end_error_before_m: result.e_max_before_m,
            end_error_after_m: result.e_max_after_m,
            centres_before: ReportCentres::of(runs, &result.used),
            centres_after: ReportCentres::of(runs, &result.rear),
            iterations: result.iterations,
            converged: result.converged,
            runs: report_runs,
        }
    }

    /// The report as JSON (compact: the paths make it long).
    ///
    /// # Errors
    /// A value serde cannot write (a non-finite number is written as null,
    /// so in practice none).
    pub fn to_json(&self) -> Result<String, ReportError> {
        json_line(self)
    }

    /// The picture as SVG text.
    ///
    /// # Errors
    /// [`ReportError::Plot`] when plotters refuses to draw.
    pub fn to_svg(&self) -> Result<String, ReportError> {
        svg_text((SVG_W, SVG_H), |root| draw(self, root))
    }
}

/// Colour of the reference track.
pub const TRACK_COLOUR: RGBColor = RGBColor(0x99, 0x99, 0x99);

const SVG_W: u32 = 1000;
const SVG_H: u32 = 1150;
const TOP_H: u32 = 660;
const MARGIN: u32 = 12;
const LABEL_AREA: u32 = 45;

/// Axis ranges centred on the data with equal metres per pixel on both axes.
fn equal_aspect(
    (x0, x1): (f64, f64),
    (y0, y1): (f64, f64),
    (w_px, h_px): (f64, f64),
) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let m_per_px = ((x1 - x0) / w_px).max((y1 - y0) / h_px).max(1e-9);
    let (hx, hy) = (0.5 * m_per_px * w_px, 0.5 * m_per_px * h_px);
    ((cx - hx)..(cx + hx), (cy - hy)..(cy + hy))
}

/// Pixel size of a chart's plotting area (the area minus margins and label
/// areas, as `ChartBuilder` lays it out).
fn plot_px(area: &DrawingArea<SVGBackend<'_>, Shift>, caption: bool) -> (f64, f64) {
    let (w, h) = area.dim_in_pixel();
    let caption_px = if caption { 30 } else { 0 };
    (
        f64::from(w.saturating_sub(2 * MARGIN + LABEL_AREA).max(1)),
        f64::from(
            h.saturating_sub(2 * MARGIN + LABEL_AREA + caption_px)
                .max(1),
        ),
    )
}

fn bounds<'a>(points: impl Iterator<Item = &'a [f64; 2]>) -> ((f64, f64), (f64, f64)) {
    let mut b = (
        (f64::INFINITY, f64::NEG_INFINITY),
        (f64::INFINITY, f64::NEG_INFINITY),
    );
    for p in points.filter(|p| p[0].is_finite() && p[1].is_finite()) {
        b.0 = (b.0.0.min(p[0]), b.0.1.max(p[0]));
        b.1 = (b.1.0.min(p[1]), b.1.1.max(p[1]));
    }
    if !b.0.0.is_finite() {
        return ((-1.0, 1.0), (-1.0, 1.0));
    }
    b
}

fn cm(m: f64) -> String {
    format!("{:.1} cm", m * 100.0)
}

fn draw(report: &CalibrationReport, root: &DrawingArea<SVGBackend<'_>, Shift>) -> PlotResult {
    root.fill(&WHITE)?;
    let title = format!(
        "canodom calibration ({}, {} runs): E_max {} -> {}",
        report.method,
        report.runs.len(),
        cm(report.end_error_before_m),
        cm(report.end_error_after_m)
    );
    let root = root.titled(&title, ("sans-serif", 24))?;
    let (top, bottom) = root.split_vertically(TOP_H);
    draw_paths(report, &top)?;
    let (left, right) = bottom.split_horizontally(SVG_W / 2);
    draw_ends(report, Direction::Ccw, &left)?;
    draw_ends(report, Direction::Cw, &right)?;
    Ok(())
}

/// Picks one of a run's paths.
type PathOf = fn(&ReportRun) -> &[[f64; 2]];

/// The two sets of run paths drawn (before, after): which path, colour,
/// opacity, and the legend entry, which only the first run of a set carries.
fn run_path_sets(report: &CalibrationReport) -> [(PathOf, RGBColor, f64, Option<String>); 2] {
    let label = |what: &str, p: &ReportParams| {
        Some(format!(
            "{what} (b = {:.4} m, D_R/D_L = {:.5})",
            p.rear_tread_m, p.diameter_ratio
        ))
    };
    [
        (
            |r| &r.path_before_m,
            BEFORE_COLOUR,
            0.55,
            label("before: parameters used", &report.nominal),
        ),
        (
            |r| &r.path_after_m,
            AFTER_COLOUR,
            0.8,
            label("after: calibrated", &report.calibrated),
        ),
    ]
}

/// The look of a rear report's charts (world metres, no minor lines).
fn world_axes(caption_px: u32) -> MetreAxes {
    MetreAxes {
        caption_px,
        margin_px: MARGIN,
        x_label_area_px: LABEL_AREA,
        y_label_area_px: LABEL_AREA,
        descs: ("x [m]", "y [m]"),
        minor_lines: false,
    }
}

fn draw_paths(report: &CalibrationReport, area: &DrawingArea<SVGBackend<'_>, Shift>) -> PlotResult {
    let all = report.track.path_m.iter().chain(
        report
            .runs
            .iter()
            .flat_map(|r| r.path_before_m.iter().chain(&r.path_after_m)),
    );
    let ((x0, x1), (y0, y1)) = bounds(all);
    let pad = 0.08 * (x1 - x0).max(y1 - y0);
    let (xr, yr) = equal_aspect(
        (x0 - pad, x1 + pad),
        (y0 - pad, y1 + pad),
        plot_px(area, true),
    );
    let mut chart = xy_chart(
        area,
        "odometry paths of every run (world frame): before and after calibration",
        &world_axes(18),
        (xr, yr),
    )?;
    let key = |c: RGBColor| {
        move |(x, y): (i32, i32)| Rectangle::new([(x, y - 4), (x + 18, y + 4)], c.filled())
    };
    chart
        .draw_series(LineSeries::new(
            report.track.path_m.iter().map(|p| (p[0], p[1])),
            TRACK_COLOUR.stroke_width(4),
        ))?
        .label(format!(
            "reference track (R = {:.3} m)",
            report.track.radius_m
        ))
        .legend(key(TRACK_COLOUR));
    for (path_of, colour, opacity, mut label) in run_path_sets(report) {
        for run in &report.runs {
            let s = chart.draw_series(LineSeries::new(
                path_of(run).iter().map(|p| (p[0], p[1])),
                colour.mix(opacity).stroke_width(1),
            ))?;
            if let Some(label) = label.take() {
                s.label(label).legend(key(colour));
            }
        }
    }
    chart.draw_series(report.runs.iter().flat_map(|r| {
        [
            Circle::new(
                (r.end_before_m[0], r.end_before_m[1]),
                3,
                BEFORE_COLOUR.filled(),
            ),
            Circle::new(
                (r.end_after_m[0], r.end_after_m[1]),
                3,
                AFTER_COLOUR.filled(),
            ),
        ]
    }))?;
    for (name, s) in [
        ("S_CCW", report.track.start_ccw),
        ("S_CW", report.track.start_cw),
    ] {
        chart.draw_series(std::iter::once(
            EmptyElement::at((s[0], s[1]))
                + Cross::new((0, 0), 6, BLACK.stroke_width(2))
                + Text::new(name, (6, 6), ("sans-serif", 14)),
        ))?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()?;
    Ok(())
}

/// The end positions of one direction around its start point, with the
/// centres of gravity before and after labelled with their distances.
fn draw_ends(
    report: &CalibrationReport,
    direction: Direction,
    area: &DrawingArea<SVGBackend<'_>, Shift>,
) -> PlotResult {
    let name = direction_name(direction);
    let start = match direction {
        Direction::Ccw => report.track.start_ccw,
        Direction::Cw => report.track.start_cw,
    };
    let track = Track::new(report.track.radius_m).map_err(|e| e.to_string())?;
    let to_world = |e: [f64; 2]| {
        xy(track.run_to_world(
            direction,
            Pose {
                x_m: e[0],
                y_m: e[1],
                heading_rad: 0.0,
            },
        ))
    };
    let runs: Vec<&ReportRun> = report.runs.iter().filter(|r| r.direction == name).collect();
    let (cog_b, dist_b) = report.centres_before.of_direction(direction);
    let (cog_a, dist_a) = report.centres_after.of_direction(direction);
    // Every end as its error drawn from the start, so that measured real
    // ends (not at the start) still cluster around S.
    let ends_b: Vec<[f64; 2]> = runs
        .iter()
        .map(|r| to_world(r.end_error_before_m))
        .collect();
    let ends_a: Vec<[f64; 2]> = runs.iter().map(|r| to_world(r.end_error_after_m)).collect();
    let (cog_bw, cog_aw) = (to_world(cog_b), to_world(cog_a));
    let reach = ends_b
        .iter()
        .chain(&ends_a)
        .chain([&cog_bw, &cog_aw])
        .map(|p| (p[0] - start[0]).hypot(p[1] - start[1]))
        .filter(|d| d.is_finite())
        .fold(0.01_f64, f64::max)
        * 1.25;
    let (xr, yr) = equal_aspect(
        (start[0] - reach, start[0] + reach),
        (start[1] - reach, start[1] + reach),
        plot_px(area, true),
    );
    let caption = format!(
        "{} ends around S_{} (end error from the start)",
        name.to_uppercase(),
        name.to_uppercase()
    );
    let mut chart = xy_chart(area, &caption, &world_axes(16), (xr, yr))?;
    chart.draw_series(std::iter::once(
        EmptyElement::at((start[0], start[1]))
            + Cross::new((0, 0), 7, BLACK.stroke_width(2))
            + Text::new(
                format!("S_{}", name.to_uppercase()),
                (8, 4),
                ("sans-serif", 14),
            ),
    ))?;
    chart.draw_series(
        ends_b
            .iter()
            .map(|p| Circle::new((p[0], p[1]), 4, BEFORE_COLOUR.mix(0.6).filled())),
    )?;
    chart.draw_series(
        ends_a
            .iter()
            .map(|p| Circle::new((p[0], p[1]), 4, AFTER_COLOUR.mix(0.8).filled())),
    )?;
    for (p, colour, what, dist) in [
        (cog_bw, BEFORE_COLOUR, "before", dist_b),
        (cog_aw, AFTER_COLOUR, "after", dist_a),
    ] {
        if runs.is_empty() || !(p[0].is_finite() && p[1].is_finite()) {
            continue;
        }
        chart.draw_series(std::iter::once(
            EmptyElement::at((p[0], p[1]))
                + TriangleMarker::new((0, 0), 9, colour.filled())
                + Text::new(
                    format!("CoG {what}: {} from S", cm(dist)),
                    (10, -14),
                    ("sans-serif", 14).into_font().color(&colour),
                ),
        ))?;
    }
    Ok(())
}

impl ReportFiles for CalibrationReport {
    fn json(&self) -> Result<String, ReportError> {
        self.to_json()
    }
    fn svg(&self) -> Result<String, ReportError> {
        self.to_svg()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::files::{SVG_NAME, write_report};
    use canodom_calib::synth;

    #[test]
    fn thinning_keeps_the_exact_end_and_bounds_the_size() {
        let pts: Vec<[f64; 2]> = (0..1001).map(|i| [f64::from(i), 0.0]).collect();
        let t = thin(&pts);
        assert!(t.len() <= MAX_PATH_POINTS, "{}", t.len());
        assert_eq!(t.first(), Some(&[0.0, 0.0]));
        assert_eq!(t.last(), Some(&[1000.0, 0.0]));
        assert_eq!(thin(&pts[..10]), pts[..10].to_vec());
    }

    #[test]
    fn equal_aspect_gives_equal_metres_per_pixel() {
        let (x, y) = equal_aspect((0.0, 4.0), (-1.0, 0.0), (800.0, 400.0));
        let (mx, my) = ((x.end - x.start) / 800.0, (y.end - y.start) / 400.0);
        assert!((mx - my).abs() < 1e-12, "{mx} {my}");
        assert!(x.start <= 0.0 && x.end >= 4.0 && y.start <= -1.0 && y.end >= 0.0);
    }

    /// Three laps each way of the §9 vehicle with a taped right wheel,
    /// calibrated from the nominal 0.30 m / 0.09 m.
    fn calibrated() -> (CalibrationResult, Track, Vec<Run>) {
        let truth = synth::section9_truth(false, true).unwrap();
        let nominal = canodom_fusion::VehicleParams::nominal(0.25, 0.30, 0.09, 1000).unwrap();
        let track = Track::new(0.78).unwrap();
        let runs: Vec<Run> = [Direction::Cw, Direction::Ccw]
            .into_iter()
            .flat_map(|d| std::iter::repeat_n(d, 3))
            .map(|direction| Run {
                direction,
                samples: synth::lap(&truth, track, direction, 1.0, 50.0).unwrap(),
                faults: Vec::new(),
                measured_end: None,
            })
            .collect();
        let used = RearParams::of(&nominal);
        let result = canodom_calib::methods::exact(
            &runs,
            &used,
            track,
            canodom_calib::methods::ExactOptions::default(),
        )
        .unwrap();
        (result, track, runs)
    }

    #[test]
    fn report_numbers_agree_with_the_result_and_the_calib_replay() {
        let (result, track, runs) = calibrated();
        let report = CalibrationReport::build(&result, track, &runs, &["first.log".to_owned()]);
        assert_eq!(report.runs[0].label, "first.log");
        assert_eq!(report.runs[1].label, "CW 2");
        assert_eq!(report.runs[3].label, "CCW 1");
        assert_eq!(report.end_error_before_m, result.e_max_before_m);
        assert_eq!(report.calibrated.rear_tread_m, result.rear.tread_m);
        // E_max of the centres equals the method's (same definition).
        assert!((report.centres_before.e_max_m - result.e_max_before_m).abs() < 1e-9);
        assert!((report.centres_after.e_max_m - result.e_max_after_m).abs() < 1e-9);
        assert!(report.centres_after.e_max_m < 0.2 * report.centres_before.e_max_m);
        for (r, run) in report.runs.iter().zip(&runs) {
            for (rear, err) in [
                (&result.used, r.end_error_before_m),
                (&result.rear, r.end_error_after_m),
            ] {
                let e = run.end_error_m(rear);
                assert!((e[0] - err[0]).abs() < 1e-9 && (e[1] - err[1]).abs() < 1e-9);
            }
            assert!(r.path_before_m.len() <= MAX_PATH_POINTS);
            assert_eq!(r.path_after_m.last(), Some(&r.end_after_m));
            // Every run starts at its direction's start point in the world frame.
            let s = if run.direction == Direction::Cw {
                report.track.start_cw
            } else {
                report.track.start_ccw
            };
            assert!(
                (r.path_after_m[0][0] - s[0]).abs() < 1e-12 && r.path_after_m[0][1].abs() < 1e-12
            );
            // After calibration the lap follows the reference loop: its
            // farthest point is the top of the loop at y = 2ρ, up to the
            // overall scale (mean diameter), which a closed lap cannot see (§4).
            let top = r.path_after_m.iter().map(|p| p[1]).fold(f64::MIN, f64::max);
            assert!((top / (2.0 * 0.78) - 1.0).abs() < 0.03, "{top}");
        }
    }

    #[test]
    fn svg_has_one_line_per_run_and_phase_and_labelled_centres() {
        let (result, track, runs) = calibrated();
        let report = CalibrationReport::build(&result, track, &runs, &[]);
        let svg = report.to_svg().unwrap();
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        let lines = |c: RGBColor| {
            let stroke = format!("stroke=\"#{:02X}{:02X}{:02X}\"", c.0, c.1, c.2);
            svg.lines()
                .filter(|l| l.contains("<polyline") && l.contains(&stroke))
                .count()
        };
        assert_eq!(lines(BEFORE_COLOUR), runs.len());
        assert_eq!(lines(AFTER_COLOUR), runs.len());
        assert_eq!(lines(TRACK_COLOUR), 1);
        for text in [
            "before: parameters used",
            "after: calibrated",
            "reference track",
            "x [m]",
            "S_CW",
            "S_CCW",
        ] {
            assert!(svg.contains(text), "no {text}");
        }
        let before = cm(report.centres_before.cw_distance_m);
        let after = cm(report.centres_after.cw_distance_m);
        assert!(
            svg.contains(&format!("CoG before: {before} from S")),
            "{before}"
        );
        assert!(
            svg.contains(&format!("CoG after: {after} from S")),
            "{after}"
        );
    }

    #[test]
    fn write_report_writes_both_files_and_leaves_no_temporaries() {
        let (result, track, runs) = calibrated();
        let report = CalibrationReport::build(&result, track, &runs, &[]);
        let dir = std::env::temp_dir().join(format!("canodom-report-unit-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let (svg, json) = write_report(&dir.join("nested"), &report).unwrap();
        assert_eq!(svg.file_name().unwrap(), SVG_NAME);
        let back: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        assert_eq!(
            back["end_error_after_m"].as_f64(),
            Some(result.e_max_after_m)
        );
        assert_eq!(back["runs"].as_array().unwrap().len(), runs.len());
        let names: Vec<_> = std::fs::read_dir(dir.join("nested"))
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names.len(), 2, "{names:?}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
