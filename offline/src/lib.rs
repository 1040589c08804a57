//! The offline work canodom does on recorded logs, as library functions:
//! the `canodom` binary's `replay` and `calibrate --fixes` commands and the
//! Python package (`python/`) both call these, so the CLI and Python give
//! the same results from the same code.
//!
//! Layout:
//! - [`log`]: a log opened by path and its format judged from its content.
//! - [`replay`]: the daemon's pipeline over a log: CSV text, MCAP, or rows as values.
//! - [`drive`]: a drive's filter steps as samples, and its calibration against position fixes.
//! - [`online`]: that calibration refitted as fixes come, for `replay --fixes`.

pub mod drive;
pub mod fixes;
pub mod log;
pub mod online;
pub mod replay;

use std::path::Path;

/// Why an offline job failed, in words naming the file, line or key at fault.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file cannot be opened or read.
    #[error("{path}: cannot {what}: {source}")]
    File {
        /// The file.
        path: String,
        /// `open`, `read`, ...
        what: &'static str,
        /// The system's reason.
        source: std::io::Error,
    },
    /// The log is of a format not read, or holds nothing usable, with the way forward.
    #[error("{0}")]
    Log(String),
    /// A log's bytes cannot be read or decompressed, or its structure is corrupt.
    #[error("{path}: {source}")]
    Read {
        /// The log.
        path: String,
        /// What went wrong where.
        source: canodom_can::candump::ReadError,
    },
    /// Writing the output failed.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// The configuration (or its DBC) is refused.
    #[error(transparent)]
    Config(#[from] canodom_pipeline::config::ConfigError),
    /// The filter refused the configuration's vehicle or a parameter set.
    #[error("{context}: {source}")]
    Filter {
        /// What was being set up.
        context: String,
        /// The filter's reason.
        source: canodom_fusion::Error,
    },
    /// A parameter file is damaged, out of bounds or has no current set.
    #[error("{0}")]
    Params(String),
    /// The MCAP output failed.
    #[error(transparent)]
    Mcap(#[from] canodom_export::Error),
    /// Position fixes cannot be read, or the fit failed.
    #[error("{0}")]
    Calibration(String),
    /// The filter thread of a replay stopped (it panicked: a bug).
    #[error("replay: the filter thread stopped")]
    FilterThread,
}

/// A `Result` of this crate.
pub type Result<T> = std::result::Result<T, Error>;

/// A path as the errors name it.
pub(crate) fn shown(path: &Path) -> String {
    path.display().to_string()
}
