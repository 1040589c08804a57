//! Kinematic parameter calibration of a car-like vehicle (Lee, Chung & Yoo,
//! *Mechatronics* 2010) with the corrections and the exact refinement of
//! `shared/docs/calibration-math.md`, camera-free steering calibration, and
//! the guided calibration session.
//!
//! Pure: no I/O, no async, no clock; samples and times come in as arguments.
//!
//! # Layout
//! - [`track`]: the test track (geometry, directions, start points).
//! - [`run`]: a recorded run as wheel revolutions, its replayed odometry and
//!   its validation ([`run::Rejection`]).
//! - [`methods`]: the paper's closed form, the heading law and the exact
//!   Levenberg–Marquardt refinement, all returning a [`CalibrationResult`].
//! - [`steering`]: the steering map φ = k·u + c from constant-command arcs (§10).
//! - [`session`]: the guided-session state machine the daemon drives.
//! - [`synth`]: a noise-free run generator for tests and benchmarks.

pub mod error;
pub mod methods;
pub mod run;
pub mod session;
pub mod steering;
pub mod synth;
pub mod track;

pub use error::{Error, Result};
pub use methods::{CalibrationResult, Method};
pub use run::{RearParams, RevSample, Run, RunRecorder};
pub use track::{Direction, Track};
