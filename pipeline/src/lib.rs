//! From a vehicle's CAN frames to the fused pose, without I/O: the
//! configuration (TOML, validated once into typed values against the DBC),
//! the pipeline that decodes the configured signals and drives the EKF, and
//! the counts of frames it rejected and why.
//!
//! Layout:
//! - [`config`]: the TOML configuration, validated once into typed values.
//! - [`pipeline`]: the frame → EKF core shared by run, replay, calibrate and demo.
//! - [`stats`]: reject reasons and counters.
//! - [`security`]: `[security]`: the SecOC key, freshness files and lockout, validated.
//! - [`gate`]: the SecOC gate the daemon passes its calibration frames through.

pub mod config;
pub mod gate;
pub mod pipeline;
pub mod security;
pub mod stats;
