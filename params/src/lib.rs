//! canodom's calibrated-parameter file: the history of committed sets
//! (`canodom_calib::history`: values, bounds, commit and rollback) stored as
//! TOML with a checksum per set, atomically and durably.
//!
//! Layout:
//! - [`persist`]: the file's TOML layout, load (with every check) and store;
//!   re-exports the history types.
//! - [`atomic_file`]: atomic, durable file replacement (parameters, state, reports).
//! - [`freshness`]: SecOC freshness values, written ahead so a restart refuses old frames.

pub mod atomic_file;
pub mod freshness;
pub mod learnt;
pub mod persist;
