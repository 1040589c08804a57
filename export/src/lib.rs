//! canodom's recordings: the filter's steps as MCAP files that Foxglove,
//! `ros2 bag` and the MCAP and `rosbags` libraries read (issue #25).
//! Synchronous: the daemon runs it on a thread of its own.
//!
//! # Layout
//! - [`sample`]: what one step contributes (pose, covariance, counts, raw frames).
//! - [`encode`]: the channels ([`encode::Topic`]) and a step's message on each.
//! - [`cdr`]: ROS 2 `Odometry` and `TFMessage` in CDR, with their schemas.
//! - [`mcap_file`]: an MCAP file of steps.

#![deny(missing_docs)]

pub mod cdr;
pub mod encode;
pub mod mcap_file;
pub mod sample;

/// What can go wrong writing a recording.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The file or folder could not be written.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder.
        path: std::path::PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The MCAP writer failed (an I/O error underneath, mostly).
    #[error("MCAP: {0}")]
    Mcap(Box<mcap::McapError>),
}

impl Error {
    /// Boxes an MCAP error (it is large).
    pub(crate) fn mcap(e: mcap::McapError) -> Self {
        Self::Mcap(Box::new(e))
    }
}

/// The crate's result.
pub type Result<T> = std::result::Result<T, Error>;
