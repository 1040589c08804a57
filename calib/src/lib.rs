//! Kinematic parameter calibration of a car-like vehicle (Lee, Chung & Yoo,
//! *Mechatronics* 2010) with the corrections and the exact refinement of
//! `docs/calibration-math.md`, camera-free steering calibration, and
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
//! - [`drift`]: the drift watch: a learnt value against the set in use, with hysteresis.
//! - [`drive`]: rear wheels, tread, steering map and yaw-rate sensor from an
//!   ordinary drive with sparse position fixes (robust least squares over the
//!   drive, the fixes' latency with them).
//! - [`session`]: the guided-session state machine (runs on the track).
//! - [`arcs`]: the steering calibration as driven: constant-command arcs and their fit.
//! - [`drive_record`]: a drive recorded against position fixes, and its fitting job.
//! - [`drive_gate`]: the quality a drive's fit must show before it is committed.
//! - [`standstill`]: whether the vehicle stands still.
//! - [`calibrator`]: the whole calibration state of a running vehicle (session,
//!   arcs, drive, history, standstill), the state machine the daemon drives.
//! - [`history`]: calibrated parameter values, their bounds, and the file of
//!   committed sets with commit and rollback.
//! - [`synth`]: a noise-free run generator for tests and benchmarks.
//!
//! # Example: a guided session as the daemon drives it
//!
//! ```
//! use canodom_calib::session::{Action, Event, Phase, Session, SessionConfig};
//! use canodom_calib::steering::SteeringProvenance;
//! use canodom_calib::{Direction, RevSample, Track, synth};
//! use canodom_fusion::VehicleParams;
//!
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let truth = VehicleParams::nominal(0.25, 0.285, 0.09, 1000)?;
//! let in_use = VehicleParams::nominal(0.25, 0.30, 0.09, 1000)?;
//! let mut session = Session::new(in_use, SteeringProvenance::Independent, SessionConfig::default());
//! let mut t_s = 0.0;
//! let mut feed = |session: Session, event: Event| {
//!     let (next, actions) = session.on_event(event);
//!     // The daemon sends instructions and refusals as status frames here,
//!     // and runs the job when asked to compute.
//!     let computed = actions
//!         .contains(&Action::Compute)
//!         .then(|| next.calibration_job().map(|job| job.run()))
//!         .flatten();
//!     match computed {
//!         Some(outcome) => next.on_event(Event::Computed(outcome)).0,
//!         None => next,
//!     }
//! };
//! session = feed(session, Event::StartSession { radius_m: 0.78, runs_per_direction: 1 });
//! let track = Track::new(0.78)?;
//! for dir in Direction::BOTH {
//!     let still = RevSample { t_s: 0.0, rear_left_rev: 0.0, rear_right_rev: 0.0, front_rev: None, steer_signal: 0.0 };
//!     let lap = synth::lap(&truth, track, dir, 0.1, 5.0)?;
//!     // Stand still, drive the lap, stand still: the run starts and ends by itself.
//!     for s in std::iter::repeat_n(still, 8).chain(lap).chain(std::iter::repeat_n(still, 8)) {
//!         t_s += 0.2;
//!         session = feed(session, Event::Sample(RevSample { t_s, ..s }));
//!     }
//! }
//! assert_eq!(session.phase(), Phase::Ready);
//! session = feed(session, Event::Compute);
//! let tread_m = session.result().map(|r| r.tread_m()).unwrap_or_default();
//! assert!((tread_m - 0.285).abs() < 1e-5);
//! let (session, actions) = session.on_event(Event::Commit);
//! assert!(matches!(actions[0], Action::ApplyParams(_)));
//! assert!((session.params().rear_tread_m() - 0.285).abs() < 1e-5);
//! # Ok(())
//! # }
//! ```

pub mod arcs;
pub mod calibrator;
pub mod drift;
pub mod drive;
pub mod drive_gate;
pub mod drive_record;
pub mod error;
pub mod front_ratio;
pub mod history;
pub mod methods;
pub mod run;
pub mod session;
pub mod standstill;
pub mod steering;
pub mod synth;
pub mod track;

pub use error::{Error, Result};
pub use methods::{CalibrationResult, Method};
pub use run::{RearParams, RevSample, Run, RunRecorder};
pub use track::{Direction, Track};
