//! Live GNSS receivers for canodom (#46): position fixes from gpsd.
//!
//! On a vehicle computer the receiver is read by gpsd (JSON on TCP port 2947),
//! not sent on the CAN bus. This crate's one job is to turn that stream into
//! accepted fixes with a 1σ error and two times (the receiver's GNSS time and
//! the receipt time), plus a status the daemon can publish.
//!
//! # Layout
//! - [`protocol`]: gpsd's JSON lines (pure): `?WATCH`, VERSION/DEVICES/WATCH/TPV/SKY.
//! - [`accept`]: which TPV reports become fixes, and why the others are refused (pure).
//! - [`backoff`]: the reconnect schedule (pure).
//! - [`status`]: the source's status: connected, fixes/s, last error, refusals (pure).
//! - [`client`]: the I/O shell: a thread of its own on a `std` `TcpStream`,
//!   sending into a bounded channel that drops the oldest when full, so the CAN
//!   pipeline is never blocked by a slow consumer.

pub mod accept;
pub mod backoff;
pub mod client;
pub mod protocol;
pub mod status;

pub use accept::{Acceptance, Fix, OutcomeChanges, Refusal};
pub use backoff::Backoff;
pub use client::{Event, GpsdClient, GpsdClientConfig};
pub use protocol::{Message, Tpv};
pub use status::SourceStatus;

/// Everything that can go wrong in this crate.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A line from gpsd is not a JSON object with a string `class`.
    #[error("gpsd sent a malformed line ({reason}): {line:?}")]
    Malformed {
        /// The line as received (cut to 200 characters).
        line: String,
        /// What was wrong with it.
        reason: String,
    },
    /// A TPV's `time` is not the ISO 8601 UTC time gpsd writes.
    #[error("gpsd sent a TPV time that is not ISO 8601 UTC: {0:?}")]
    BadTime(String),
    /// A configuration value is out of range; names the key.
    #[error("[gnss] {key}: {reason}")]
    Config {
        /// The key, as written in the configuration.
        key: &'static str,
        /// Why it was refused.
        reason: String,
    },
    /// Socket I/O.
    #[error("gpsd at {address}: {source}")]
    Io {
        /// The address connected to.
        address: String,
        /// The underlying error.
        source: std::io::Error,
    },
}
