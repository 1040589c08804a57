//! canodom's result writers: calibration reports (an SVG picture and a JSON
//! file of every number), and fast text formatting of floats for CSV output.
//!
//! Layout:
//! - [`files`]: what every report shares: its two files, their durable writing, errors, colours.
//! - [`report`]: the track calibration report (rear tread and wheel diameters).
//! - [`steering_report`]: the steering calibration report.
//! - [`drive_report`]: the report of a calibration from a drive with position fixes.
//! - [`committed`]: the report of a committed live calibration, rear or steering.
//! - [`truth`]: a replay against a reference trajectory (`replay --truth`).
//! - [`float_text`]: `f64` written as `{}` writes it, fast (replay output).

pub mod committed;
pub mod drive_report;
pub mod files;
pub mod float_text;
pub mod report;
pub mod steering_report;
pub mod truth;
