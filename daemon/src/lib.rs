//! The canodom daemon: live fused odometry from SocketCAN, published on CAN;
//! decode and replay of candump logs; guided calibration over CAN.
//!
//! Layout:
//! - [`atomic_file`]: atomic, durable file replacement (parameters, state, reports).
//! - [`frame`]: the CAN frame value type shared by every transport and log.
//! - [`candump`]: the `candump -L` log format, streaming parser and formatter.
//! - [`bus`]: the transport trait, with the in-process bus and SocketCAN.
//! - [`calib_wire`]: the calibration frames as typed values, encode/decode.
//! - [`own_dbc`]: canodom's own frames (`dbc/canodom.dbc`), id map and base id.
//! - [`persist`]: the calibrated-parameter file, atomic and durable.
//! - [`cmd`]: the subcommands (run, decode, replay, simulate, demo).
//! - [`config`]: the TOML configuration, validated once into typed values.
//! - [`pipeline`]: the pure frame → EKF core shared by run, replay and demo.
//! - [`pose_frames`]: pose samples encoded into canodom's own frames.
//! - [`vehicle`]: the simulator encoded with the configured DBC (simulate, demo, tests).
//! - [`report`]: calibration reports, an SVG picture and a JSON file of every number.
//! - [`drive_report`]: the report of a calibration from a drive with position fixes.
//! - [`float_text`]: `f64` written as `{}` writes it, fast (replay output).
//! - [`progress`]: a progress line on terminals for long offline work.
//! - [`state_file`]: the end state `run --state-file` saves on SIGTERM.
//! - [`stats`]: reject reasons and counters.
//! - [`server`]: the async daemon (link and pipeline tasks), generic over the transport.
//! - [`sd_notify`]: systemd readiness and watchdog notifications.

pub mod atomic_file;
pub mod bus;
pub mod calib_wire;
pub mod candump;
pub mod cmd;
pub mod config;
pub mod drive_report;
pub mod float_text;
pub mod frame;
pub mod live_calib;
pub mod own_dbc;
pub mod persist;
pub mod pipeline;
pub mod pose_frames;
pub mod progress;
pub mod report;
pub mod sd_notify;
pub mod server;
pub mod state_file;
pub mod stats;
pub mod steering_report;
pub mod vehicle;
