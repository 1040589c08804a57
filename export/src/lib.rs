//! canodom's recordings: the filter's steps as MCAP files that Foxglove,
//! `ros2 bag` and the MCAP and `rosbags` libraries read (issue #25).
//! Synchronous: the daemon runs it on a thread of its own.
//!
//! # Layout
//! - [`sample`]: what one step contributes (pose, covariance, counts, raw frames).
//! - [`encode`]: the channels ([`encode::Topic`]) and a step's message on each.
//! - [`cdr`]: ROS 2 `Odometry` and `TFMessage`, Foxglove `PoseInFrame` and
//!   `FrameTransform` (`foxglove_msgs`) in CDR, with their schemas.
//! - [`mcap_file`]: an MCAP file of steps.
//! - [`recorder`]: MCAP files rotated by size or time, flushed as they go.
//! - [`live`]: a running daemon's poses to a recording and a Foxglove
//!   WebSocket view, through a queue that never holds up the pipeline.

#![deny(missing_docs)]

pub mod cdr;
pub mod encode;
pub mod live;
pub mod mcap_file;
pub mod recorder;
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
    /// The live view could not start.
    #[error("live view: {0}")]
    Live(String),
    /// The recording's output refused a write.
    #[error("writing the recording: {0}")]
    Write(std::io::Error),
}

impl Error {
    /// A failed write to the output.
    pub(crate) fn write(e: std::io::Error) -> Self {
        Self::Write(e)
    }
}

/// The crate's result.
pub type Result<T> = std::result::Result<T, Error>;
