//! The simulated vehicle's one error type.

use crate::vehicle::TrueParamsError;

/// Why a simulated drive could not be built, written or driven.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The `--true-params` file cannot be used.
    #[error(transparent)]
    TrueParams(#[from] TrueParamsError),
    /// The fusion crate refused the vehicle or the drive.
    #[error(transparent)]
    Fusion(#[from] canodom_fusion::Error),
    /// The log, the truth file or the progress output cannot be written.
    #[error("cannot write: {0}")]
    Io(#[from] std::io::Error),
    /// canodom's calibration frames cannot be built for the configured base id.
    #[error(transparent)]
    Wire(#[from] canodom_protocol::calib_wire::WireError),
    /// The transport failed for good while following a session.
    #[error(transparent)]
    Bus(#[from] canodom_can::bus::BusError),
    /// The drive asked for does not fit the configuration.
    #[error("{0}")]
    Invalid(String),
}

/// A result of this crate.
pub type Result<T> = std::result::Result<T, Error>;
