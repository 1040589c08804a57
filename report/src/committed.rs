//! The report of a committed live calibration, whichever part it calibrated.

use crate::files::{ReportError, ReportFiles};
use crate::report::CalibrationReport;
use crate::steering_report::SteeringReport;

/// The report of a committed live calibration: of the rear parameters or
/// of the steering map.
#[derive(Debug, Clone, PartialEq)]
// It travels boxed (`live_calib::Output::Report`), so the sizes do not matter.
#[allow(clippy::large_enum_variant)]
pub enum Report {
    /// Tread and wheel diameters (the track runs).
    Rear(CalibrationReport),
    /// The steering map (the constant-command arcs).
    Steering(SteeringReport),
}

impl ReportFiles for Report {
    fn json(&self) -> Result<String, ReportError> {
        match self {
            Self::Rear(r) => r.json(),
            Self::Steering(r) => r.json(),
        }
    }
    fn svg(&self) -> Result<String, ReportError> {
        match self {
            Self::Rear(r) => r.svg(),
            Self::Steering(r) => r.svg(),
        }
    }
}
