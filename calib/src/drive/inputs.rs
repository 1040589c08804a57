//! What a drive calibration is given: the odometry samples, the position
//! fixes (and the CSV they are read from), and the geometry in use. Kept
//! apart from the fit so that the readers and callers need not see its
//! internals.

use crate::error::{Error, Result};

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
    /// Front (left, right) distances since the previous sample, with the
    /// diameters in use; `None` where the front wheels were not read (not
    /// configured, or stale in part of the interval). The drive fit does not
    /// use them; the drift watch reads the front tyres' ratio from them
    /// ([`crate::front_ratio`]).
    pub front_m: Option<(f64, f64)>,
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
    /// The fix's 1σ horizontal error per axis, metres, when its source
    /// states it (a CSV's `horiz_std_m`, NMEA GST, HDOP). The fit weighs the
    /// fixes by it and the quality gate allows the residual it explains;
    /// when no fix states it, both take it from the fit's own residuals.
    pub sigma_m: Option<f64>,
}

/// The optional column of a fixes CSV that states each fix's 1σ horizontal
/// error per axis, metres (what `canodom ros2-fixes` writes from a
/// `NavSatFix`'s known covariance); an empty field is a fix without one.
pub const SIGMA_COLUMN: &str = "horiz_std_m";

/// Reads a fixes CSV: a header naming `t_unix_s`, `x_m`, `y_m` and
/// optionally `heading_rad` and [`SIGMA_COLUMN`] (any order, other columns
/// ignored), then one fix
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
            sigma_m: r.sigma_m,
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
    /// The fix's stated σ per axis ([`SIGMA_COLUMN`]), when the header has
    /// the column and the line a value in it.
    pub sigma_m: Option<f64>,
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
/// `optional`, and [`SIGMA_COLUMN`] when present; every value a finite
/// number (a σ positive, or empty for none, or 0, which receivers' drivers
/// write for "not known"), the times increasing, and each row passed to
/// `check` (its refusal is that line's error). The one reader of the
/// local-metre and the latitude/longitude CSVs.
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
    let sigma_at = column(SIGMA_COLUMN);
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
            sigma_m: match sigma_at {
                Some(k) if !fields.get(k).is_none_or(|f| f.is_empty()) => {
                    let v = number(k, SIGMA_COLUMN)?;
                    if v < 0.0 {
                        return Err(bad(format!(
                            "{SIGMA_COLUMN} {v} is negative (a σ in metres, or empty)"
                        )));
                    }
                    (v > 0.0).then_some(v)
                }
                _ => None,
            },
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
