//! A simulated vehicle on the CAN bus: the fusion crate's ground-truth
//! simulator, its samples encoded with the configured DBC into the
//! configured input messages (valid counters and checksums), written as a
//! candump log or sent through a transport in real time, and a driver that
//! follows canodom's guided calibration over CAN.
//!
//! Layout:
//! - [`vehicle`]: the drives offered, the true vehicle, the sample encoder.
//! - [`drive`]: a simulator for a configuration; logs and real-time drives.
//! - [`error`]: the crate's error type.
//! - [`follow`]: the closed-loop vehicle that drives a guided calibration session.

pub mod drive;
pub mod error;
pub mod follow;
pub mod vehicle;
