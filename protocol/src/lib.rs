//! canodom's own CAN protocol: the frames canodom sends and listens to,
//! described by its own DBC (`protocol/dbc/canodom.dbc`) at a configurable
//! base id.
//!
//! Layout:
//! - [`own_dbc`]: the DBC, its id map and the base id.
//! - [`pose_frames`]: the published pose ([`pose_frames::PoseOutput`]) encoded into pose frames.
//! - [`guide`]: the calibration's status in words, as an operator's client shows it.
//! - [`calib_wire`]: the calibration commands, status and parameter frames as typed values.
//! - [`secoc`]: authenticated commands and write-back (SecOC profile 3: CMAC, epoch and counter freshness, announcements).
//! - [`secoc_keys`]: a key per message and direction, derived from a master key (HKDF-SHA256).

pub mod calib_wire;
pub mod guide;
pub mod own_dbc;
pub mod pose_frames;
pub mod secoc;
pub mod secoc_keys;
