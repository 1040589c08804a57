//! The canodom daemon and its command line: the service that wires the
//! pipeline, the live calibration and the transports together, and the
//! subcommands an operator runs. Everything it does with frames, files and
//! numbers lives in the library crates (see the README's architecture
//! section); this crate only schedules and connects them.
//!
//! Layout:
//! - [`cmd`]: the subcommands (run, decode, replay, calibrate, simulate, demo, calib).
//! - [`server`]: the async daemon (link, odometry and calibration tasks), generic over the transport.
//! - the live calibration on the wire (CAN commands in, the calibrator's outputs as frames) is the `canodom-live` crate.
//! - [`calib_task`]: the calibration task: the live calibration, its stores and jobs off the frame path.
//! - [`gnss_task`]: the live GNSS source (`[gnss]`: gpsd or a ROS 2 topic), its fixes to the calibration task.
//! - [`state_file`]: the state `run --state-file` keeps (periodically, durably) and what a start restores.
//! - [`summary`]: what the run loop hands back, and what the state file is written from.
//! - [`sd_notify`]: systemd readiness and watchdog notifications.
//! - [`progress`]: a progress line on terminals for long offline work.

pub mod calib_task;
pub mod cmd;
pub mod gnss_task;
pub mod progress;
pub mod sd_notify;
pub mod server;
pub mod state_file;
pub mod summary;
