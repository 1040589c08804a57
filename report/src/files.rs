//! What every report shares: the two files of a report directory (an SVG
//! picture and a JSON file of every number), their atomic, durable writing,
//! the error type, and the colours "before" and "after" have in every picture.
//! The report kinds ([`crate::report`], [`crate::steering_report`],
//! [`crate::drive_report`]) build on this module and never on each other.

use plotters::coord::Shift;
use plotters::prelude::*;
use serde::Serialize;
use std::path::{Path, PathBuf};

/// File name of the picture inside the report directory.
pub const SVG_NAME: &str = "calibration.svg";
/// File name of the numbers inside the report directory.
pub const JSON_NAME: &str = "calibration.json";

/// Colour of the paths and ends with the parameters used while recording.
pub const BEFORE_COLOUR: RGBColor = RGBColor(0xD6, 0x60, 0x4D);
/// Colour of the paths and ends with the calibrated parameters.
pub const AFTER_COLOUR: RGBColor = RGBColor(0x21, 0x66, 0xAC);

/// Why a report could not be written.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// A file or the directory could not be written.
    #[error("{path}: {source}")]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// The system's reason.
        #[source]
        source: std::io::Error,
    },
    /// plotters refused to draw (its error type is generic over the backend,
    /// so it is kept as text).
    #[error("cannot draw the calibration plot: {0}")]
    Plot(String),
    /// A replay and its reference trajectory cannot be compared.
    #[error("cannot compare with the reference: {0}")]
    Truth(String),
    /// The report could not be serialised.
    #[error("cannot serialise the report: {0}")]
    Json(#[from] serde_json::Error),
}

/// What drawing with plotters returns (its errors are generic over the backend).
pub type PlotResult = Result<(), Box<dyn std::error::Error>>;

/// `value` as one line of JSON (compact: a rear report's paths make it long).
pub(crate) fn json_line(value: &impl Serialize) -> Result<String, ReportError> {
    let mut s = serde_json::to_string(value)?;
    s.push('\n');
    Ok(s)
}

/// The SVG text of a `(width, height)` picture that `draw` paints.
pub(crate) fn svg_text(
    size_px: (u32, u32),
    draw: impl FnOnce(&DrawingArea<SVGBackend<'_>, Shift>) -> PlotResult,
) -> Result<String, ReportError> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size_px).into_drawing_area();
        draw(&root).map_err(|e| ReportError::Plot(e.to_string()))?;
        root.present()
            .map_err(|e| ReportError::Plot(e.to_string()))?;
    }
    Ok(svg)
}

/// Writes `text` to `path` durably and atomically ([`canodom_params::atomic_file`]).
fn write_durable(path: &Path, text: &str) -> Result<(), ReportError> {
    canodom_params::atomic_file::write(path, text.as_bytes()).map_err(|e| ReportError::Io {
        path: e.path,
        source: e.source,
    })
}

/// A report as the two files of its directory: what [`write_report`] writes.
pub trait ReportFiles {
    /// The numbers, as JSON text.
    ///
    /// # Errors
    /// A value serde cannot write.
    fn json(&self) -> Result<String, ReportError>;
    /// The picture, as SVG text.
    ///
    /// # Errors
    /// The plot cannot be drawn.
    fn svg(&self) -> Result<String, ReportError>;
}

/// A report drawn as one SVG picture and written as one line of JSON: every
/// such report is a [`ReportFiles`] through this.
pub trait PlottedReport: Serialize {
    /// The picture's size, (width, height) in pixels.
    const SVG_SIZE_PX: (u32, u32);

    /// Paints the picture on `root`.
    ///
    /// # Errors
    /// What plotters met drawing.
    fn draw(&self, root: &DrawingArea<SVGBackend<'_>, Shift>) -> PlotResult;
}

impl<T: PlottedReport> ReportFiles for T {
    fn json(&self) -> Result<String, ReportError> {
        json_line(self)
    }

    fn svg(&self) -> Result<String, ReportError> {
        svg_text(T::SVG_SIZE_PX, |root| self.draw(root))
    }
}

/// Writes `calibration.svg` and `calibration.json` into `dir` (created if
/// missing), each atomically; returns their paths (SVG, JSON).
///
/// # Errors
/// The directory or a file cannot be written, or the plot cannot be drawn.
pub fn write_report(
    dir: &Path,
    report: &impl ReportFiles,
) -> Result<(PathBuf, PathBuf), ReportError> {
    std::fs::create_dir_all(dir).map_err(|source| ReportError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let svg = report.svg()?;
    let json = report.json()?;
    let (svg_path, json_path) = (dir.join(SVG_NAME), dir.join(JSON_NAME));
    write_durable(&svg_path, &svg)?;
    write_durable(&json_path, &json)?;
    Ok((svg_path, json_path))
}

/// One labelled line of a chart, 2 px wide, with its legend entry.
pub(crate) fn draw_line<'a, 'b: 'a, X, Y>(
    chart: &mut ChartContext<'a, SVGBackend<'b>, Cartesian2d<X, Y>>,
    points: impl IntoIterator<Item = (f64, f64)>,
    colour: RGBColor,
    label: &str,
) -> PlotResult
where
    X: plotters::coord::ranged1d::Ranged<ValueType = f64>,
    Y: plotters::coord::ranged1d::Ranged<ValueType = f64>,
{
    chart
        .draw_series(LineSeries::new(points, colour.stroke_width(2)))?
        .label(label)
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour));
    Ok(())
}

/// How an x-y chart in metres looks: caption size, margin, label areas,
/// how the unit is written and whether minor grid lines are drawn.
#[derive(Debug, Clone, Copy)]
pub(crate) struct MetreAxes {
    pub caption_px: u32,
    pub margin_px: u32,
    pub x_label_area_px: u32,
    pub y_label_area_px: u32,
    /// `"x (m)"` and `"y (m)"`, or the rear report's `"x [m]"` and `"y [m]"`.
    pub descs: (&'static str, &'static str),
    pub minor_lines: bool,
}

/// The look of the drive and reference pictures' x-y charts.
pub(crate) const TRAJECTORY_AXES: MetreAxes = MetreAxes {
    caption_px: 16,
    margin_px: 15,
    x_label_area_px: 40,
    y_label_area_px: 60,
    descs: ("x (m)", "y (m)"),
    minor_lines: true,
};

/// A chart of positions in metres on `area`, under `caption`, with its mesh
/// drawn.
pub(crate) fn xy_chart<'a, 'b>(
    area: &'a DrawingArea<SVGBackend<'b>, Shift>,
    caption: &str,
    axes: &MetreAxes,
    (xs, ys): (std::ops::Range<f64>, std::ops::Range<f64>),
) -> Result<
    ChartContext<
        'a,
        SVGBackend<'b>,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
    Box<dyn std::error::Error>,
> {
    let mut chart = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", axes.caption_px))
        .margin(axes.margin_px)
        .x_label_area_size(axes.x_label_area_px)
        .y_label_area_size(axes.y_label_area_px)
        .build_cartesian_2d(xs, ys)?;
    let mut mesh = chart.configure_mesh();
    mesh.x_desc(axes.descs.0).y_desc(axes.descs.1);
    if !axes.minor_lines {
        mesh.light_line_style(WHITE);
    }
    mesh.draw()?;
    Ok(chart)
}

/// A chart's legend, top left, on a translucent white box.
pub(crate) fn draw_legend<'a, 'b: 'a, X, Y>(
    chart: &mut ChartContext<'a, SVGBackend<'b>, Cartesian2d<X, Y>>,
) -> PlotResult
where
    X: plotters::coord::ranged1d::Ranged<ValueType = f64>,
    Y: plotters::coord::ranged1d::Ranged<ValueType = f64>,
{
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

/// Axis ranges around `points` with equal metres per pixel both ways (a
/// square view), a margin, and at least a metre: for the x-y pictures.
pub(crate) fn square_view<'p>(
    points: impl Iterator<Item = &'p [f64; 2]>,
) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in points.filter(|p| p[0].is_finite() && p[1].is_finite()) {
        (x0, x1, y0, y1) = (x0.min(p[0]), x1.max(p[0]), y0.min(p[1]), y1.max(p[1]));
    }
    if x0 > x1 {
        (x0, x1, y0, y1) = (-1.0, 1.0, -1.0, 1.0);
    }
    let span = (x1 - x0).max(y1 - y0).max(1.0) * 0.55;
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    ((cx - span)..(cx + span), (cy - span)..(cy + span))
}
