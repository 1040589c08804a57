//! From a vehicle's CAN frames to the fused pose: the configuration (TOML,
//! validated once into typed values against the DBC), the pipeline that
//! decodes the configured signals and drives the EKF, the counts of frames
//! it rejected and why, and the SecOC gate. No transport, no async, no
//! clock; the only files touched after loading are the gate's freshness
//! values, stored before a secured frame is acted on.
//!
//! Layout:
//! - [`config`]: the TOML configuration, validated once into typed values.
//! - [`pipeline`]: the frame → EKF core shared by run, replay, calibrate and demo.
//! - [`param_set`]: the identity of the parameter set in use, and which learnt
//!   values a new set resets.
//! - [`signal_forms`]: a quantity's signals: magnitude and sign, sums, units, the reversing signal.
//! - [`step`]: one filter step, what every consumer of the pipeline gets.
//! - [`plausibility`]: run-time checks that name a confidently wrong signal (sign, unit, algorithm, kind).
//! - [`stats`]: reject reasons and counters.
//! - [`security`]: `[security]`: the SecOC key, freshness files and window, validated.
//! - [`gate`]: the SecOC gate the daemon passes its calibration frames through.

pub mod config;
pub mod gate;
pub mod param_set;
pub mod pipeline;
pub mod plausibility;
pub mod security;
pub mod signal_forms;
pub mod stats;
pub mod step;
