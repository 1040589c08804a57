//! The canodom daemon: live fused odometry from SocketCAN, published on CAN;
//! decode and replay of candump logs; guided calibration over CAN.
//!
//! Layout:
//! - [`frame`]: the CAN frame value type shared by every transport and log.
//! - [`candump`]: the `candump -L` log format, streaming parser and formatter.
//! - [`bus`]: the transport trait, with the in-process bus and SocketCAN.
//! - [`own_dbc`]: canodom's own frames (`dbc/canodom.dbc`), id map and base id.
//! - [`persist`]: the calibrated-parameter file, atomic and durable.
//! - [`sd_notify`]: systemd readiness and watchdog notifications.

pub mod bus;
pub mod candump;
pub mod frame;
pub mod own_dbc;
pub mod persist;
pub mod sd_notify;
