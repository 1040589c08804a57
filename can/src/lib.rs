//! CAN on the wire and on disk, for canodom: the frame value type, log
//! timestamps, the CAN log formats it reads (`candump -L` and the rest), and the transports frames travel
//! through (an in-process bus for tests and demos, SocketCAN for vehicles).
//!
//! It knows nothing of what frames mean: decoding is `canodom-dbc`'s job,
//! canodom's own frames are `canodom-protocol`'s.
//!
//! Layout:
//! - [`frame`]: the CAN frame value type (classic, FD, remote, error frames).
//! - [`time`]: [`time::Timestamp`], microseconds since the epoch, the time of every frame.
//! - [`candump`]: the `candump -L` log format, streaming parser and formatter, and the
//!   interfaces a log reader met and filters (shared by every reader).
//! - [`log_format`]: which CAN log format a file is, from its first bytes.
//! - [`any_log`]: one reader for every log format read, through gzip/zstd compression.
//! - [`candump_plain`], [`vector_asc`], [`vector_blf`], [`mdf4`]: plain candump output, Vector ASC
//!   and BLF, ASAM MDF 4 bus logging.
//! - [`log_lines`]: what the text readers share (bounded lines) and what a reader tells of its interfaces.
//! - [`bus`]: the transport trait, with the in-process bus and SocketCAN.

pub mod any_log;
pub mod bus;
pub mod candump;
pub mod candump_plain;
pub mod frame;
pub mod log_format;
pub mod log_lines;
pub mod mdf4;
pub mod time;
pub mod vector_asc;
pub mod vector_blf;
