//! canodom's result writers: calibration reports (an SVG picture and a JSON
//! file of every number), and fast text formatting of floats for CSV output.
//!
//! Layout:
//! - [`report`]: the track calibration report and the shared writing helpers.
//! - [`steering_report`]: the steering calibration report.
//! - [`drive_report`]: the report of a calibration from a drive with position fixes.
//! - [`float_text`]: `f64` written as `{}` writes it, fast (replay output).

pub mod drive_report;
pub mod float_text;
pub mod report;
pub mod steering_report;
