//! canodom's calibrated-parameter file: the parameter values a calibration
//! produces, the bounds they must stay within, the history of committed sets
//! for rollback, and their atomic, durable storage as TOML.
//!
//! Layout:
//! - [`persist`]: values, bounds, the history file, load and store.
//! - [`atomic_file`]: atomic, durable file replacement (parameters, state, reports).
//! - [`freshness`]: SecOC freshness values, written ahead so a restart refuses old frames.

pub mod atomic_file;
pub mod freshness;
pub mod persist;
