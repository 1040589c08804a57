//! Integration tests of the canodom daemon, one binary with topic modules
//! (ripgrep's layout).

// Test helpers outside #[test] functions unwrap too: a failure is a test failure.
#![allow(clippy::unwrap_used)]

mod architecture;
mod auth_daemon;
mod bad_input;
mod calib_client;
mod calib_session;
mod calibrate;
mod cantools_decode;
mod cars;
mod cli;
mod config_errors;
mod dbc_tools;
mod drift_live;
mod drive_session;
mod follow_session;
mod gnss_drive;
mod gnss_live;
mod gnss_ros2;
mod install;
mod live_outputs;
mod log_refusal;
mod messages;
mod rav4;
mod replay_fixes;
mod replay_mcap;
mod run_loop;
mod state_file;
mod trajectory;
mod util;
