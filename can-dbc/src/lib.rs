//! DBC loading and a compiled CAN signal codec, with rolling counters and checksums.
//!
//! A DBC file is parsed once with the crates.io `can-dbc` parser (its AST stays private:
//! it changes between majors) and compiled, as cantools does, into per-signal bit layouts
//! and scalings. Decoding is then lookup, extract and scale, in the directions named
//! `raw_to_scaled` and `scaled_to_raw`; decoded values are bit-identical to cantools'.
//!
//! # Layout
//! - [`database`]: loading and compiling; [`Database`] with O(1) lookup by [`FrameId`]
//!   and [`Database::signal`]`("MESSAGE.SIGNAL")`.
//! - [`message`]: [`Message`], decoding a whole payload without allocating (multiplexing
//!   honoured) and encoding.
//! - [`signal`]: [`Signal`] metadata and the `Copy` [`SignalHandle`] for hot paths.
//! - [`integrity`]: [`CounterCheck`] and [`Checksum`] (CRC-8 SAE J1850, configurable
//!   CRC-8, sum, XOR).
//! - [`checksums`]: the carmakers' own checksums (Toyota, Honda, Subaru, Tesla, VW MQB and
//!   PQ, Chrysler, Hyundai CAN FD) as opendbc's packer writes them.
//! - [`describe`]: the whole database as data and as a text listing (`canodom dbc dump`).
//! - [`frame_id`]: [`FrameId`], standard or extended.
//! - [`error`]: the crate's [`Error`].
//!
//! # Example
//! ```
//! use canodom_dbc::{Checksum, CounterCheck, CounterStatus, Database, FrameId};
//!
//! let db = Database::parse(
//!     r#"VERSION ""
//! BO_ 256 WHEEL_ENC_REAR: 8 ECU
//!  SG_ RL_TICKS : 0|16@1+ (1,0) [0|65535] "ticks" ODOM
//!  SG_ RR_TICKS : 16|16@1+ (1,0) [0|65535] "ticks" ODOM
//!  SG_ COUNTER : 48|4@1+ (1,0) [0|15] "" ODOM
//!  SG_ CHECKSUM : 56|8@1+ (1,0) [0|255] "" ODOM
//! "#,
//!     "example.dbc",
//! )?;
//!
//! // Encode a frame the way a sender must: values, then counter, then CRC.
//! let msg = db.message_by_name("WHEEL_ENC_REAR").unwrap();
//! let mut frame = msg.encode(&[
//!     ("RL_TICKS", 1200.0),
//!     ("RR_TICKS", 1210.0),
//!     ("COUNTER", 3.0),
//!     ("CHECKSUM", 0.0),
//! ])?;
//! let crc = Checksum::rc_car(); // CRC-8 SAE J1850 over bytes 0..=6 into byte 7
//! crc.apply(&mut frame)?;
//!
//! // Receive: look up by ID, check integrity, decode everything or one signal.
//! let id = FrameId::standard(256)?;
//! let m = db.message_by_id(id).unwrap();
//! assert!(crc.verify(&frame)?);
//! let counter = db.signal("WHEEL_ENC_REAR.COUNTER")?;
//! let mut seq = CounterCheck::new(counter.size())?;
//! assert_eq!(seq.observe(counter.raw(&frame).unwrap()), CounterStatus::First);
//! for (signal, value) in m.decode(&frame)? {
//!     println!("{} = {value} {}", signal.name(), signal.unit());
//! }
//! let rl = db.signal("WHEEL_ENC_REAR.RL_TICKS")?; // Copy, allocation-free
//! assert_eq!(rl.decode(&frame), Some(1200.0));
//! assert!(m.decode(&frame[..7]).is_err()); // short frame: DLC fault, never read past end
//! # Ok::<(), canodom_dbc::Error>(())
//! ```
#![deny(missing_docs)]

pub mod checksums;
pub mod database;
pub mod describe;
pub mod error;
pub mod frame_id;
pub mod integrity;
mod layout;
pub mod message;
pub mod signal;

pub use checksums::{FrameChecksum, Maker, MakerChecksum};
pub use database::{Database, LoadMode, LoadWarning};
pub use error::{Error, Result};
pub use frame_id::FrameId;
pub use integrity::{Checksum, ChecksumAlgorithm, CounterCheck, CounterStatus};
pub use message::{Decoded, Message};
pub use signal::{ByteOrder, Signal, SignalHandle, Value, ValueType};
