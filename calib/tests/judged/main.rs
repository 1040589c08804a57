//! Integration tests of the calib crate, judged by the fusion crate's
//! ground-truth simulator (`canodom_fusion::sim`). One binary, topic modules.
//! Run with `--nocapture` to see the printed tables.

// Helpers here are test code: a failed unwrap is a failed test.
#![allow(clippy::unwrap_used, clippy::missing_panics_doc)]

mod common;
mod drive;
mod grid;
mod noise_free;
mod sim_session;
mod steering_sim;
mod table2;
