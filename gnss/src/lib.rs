//! Live GNSS receivers for canodom (#46): position fixes from gpsd, or from a
//! receiver's NMEA on a serial port.
//!
//! On a vehicle computer the receiver is read by gpsd (JSON on TCP port 2947),
//! not sent on the CAN bus. This crate's one job is to turn that stream into
//! accepted fixes with a 1σ error and two times (the receiver's GNSS time and
//! the receipt time), plus a status the daemon can publish.
//!
//! # Layout
//! - [`protocol`]: gpsd's JSON lines (pure): `?WATCH`, VERSION/DEVICES/WATCH/TPV/SKY.
//! - [`nmea`]: NMEA 0183 GGA/RMC/GST sentences (pure), and a live stream's
//!   sentences gathered into one gpsd-style report per epoch.
//! - [`accept`]: which TPV reports become fixes, and why the others are refused (pure).
//! - [`backoff`]: the reconnect schedule (pure).
//! - [`status`]: the source's status: connected, fixes/s, last error, refusals (pure).
//! - [`serial`]: the I/O shell of a receiver on a serial port (NMEA without
//!   gpsd), on a thread of its own behind the same queue as [`client`].
//! - [`client`]: the I/O shell: a thread of its own on a `std` `TcpStream`,
//!   sending into a bounded channel that drops the oldest when full, so the CAN
//!   pipeline is never blocked by a slow consumer.

pub mod accept;
pub mod backoff;
pub mod client;
pub mod nmea;
pub mod protocol;
pub mod serial;
pub mod status;

pub use accept::{Acceptance, Fix, Judge, OutcomeChanges, Refusal};
pub use backoff::Backoff;
pub use client::{Event, GpsdClient, GpsdClientConfig};
pub use protocol::{Message, Tpv};
pub use serial::{NmeaDevice, NmeaDeviceConfig};
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
    /// A serial receiver's thread could not start.
    #[error("GNSS receiver at {path}: {source}")]
    Device {
        /// The device path.
        path: String,
        /// The underlying error.
        source: std::io::Error,
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
