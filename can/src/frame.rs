//! CAN frames as canodom handles them: one plain, `Copy` value type for
//! classical data, remote, CAN FD and error frames.
//!
//! The daemon needs a frame type that is the same whether a frame came from a
//! SocketCAN socket, from the in-process bus or from a candump log, so that
//! `run`, `replay` and `demo` share one pipeline bit for bit. socketcan's own
//! frame types wrap the kernel structs and cannot be built without the
//! kernel ABI in mind; this type is a small value with checked constructors
//! and a fixed 64-byte payload array, so copying it never allocates.
//!
//! Invariant kept by every constructor: payload bytes past `len` are zero, so
//! the derived `PartialEq` compares exactly what a frame means.

use std::fmt;

/// `CAN_ERR_FLAG` of `<linux/can.h>`: set in the identifier of an error frame.
pub const CAN_ERR_FLAG: u32 = 0x2000_0000;
/// Largest standard (11-bit) identifier.
pub const MAX_STANDARD_ID: u32 = 0x7FF;
/// Largest extended (29-bit) identifier.
pub const MAX_EXTENDED_ID: u32 = 0x1FFF_FFFF;
/// Payload bytes of a classical CAN frame.
pub const CLASSIC_MAX_LEN: usize = 8;
/// Payload bytes of a CAN FD frame.
pub const FD_MAX_LEN: usize = 64;
/// Payload length of every kernel error frame (`CAN_ERR_DLC`).
pub const ERROR_FRAME_LEN: usize = 8;

/// The CAN identifier is the DBC crate's: one type for an id on the bus, in a
/// log and in a DBC file, so no conversion stands between a frame and its message.
pub use canodom_dbc::FrameId;

/// What kind of frame this is, with the per-kind details.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FrameKind {
    /// Classical data frame.
    Data {
        /// Raw DLC 9..=15 sent with an 8-byte payload (`len8_dlc` of
        /// `struct can_frame`); `None` for the usual DLC = length.
        len8_dlc: Option<u8>,
    },
    /// Classical remote (RTR) frame; `len` is the requested DLC, no payload.
    Remote {
        /// Raw DLC 9..=15 when the requested length is 8, as for data frames.
        len8_dlc: Option<u8>,
    },
    /// CAN FD frame.
    Fd {
        /// `canfd_frame.flags` nibble: BRS = 0x1, ESI = 0x2, FDF = 0x4.
        flags: u8,
    },
    /// Error frame reported by the controller driver; see [`ErrorFrame`].
    Error,
}

/// Why a frame could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// Payload longer than the frame kind allows.
    #[error("payload of {len} bytes exceeds {max} bytes")]
    TooLong {
        /// Offending length.
        len: usize,
        /// Maximum for the kind.
        max: usize,
    },
    /// CAN FD length that no DLC encodes (valid: 0..=8, 12, 16, 20, 24, 32, 48, 64).
    #[error("{0} bytes is not a CAN FD length")]
    BadFdLength(usize),
    /// FD flags outside the low nibble.
    #[error("CAN FD flags {0:#x} do not fit in one hex digit")]
    BadFdFlags(u8),
    /// `len8_dlc` outside 9..=15 or given with a length other than 8.
    #[error("raw DLC {0} is only valid (9..=15) with an 8-byte frame")]
    BadLen8Dlc(u8),
    /// Error class bits beyond the 29-bit identifier field.
    #[error("error class {0:#x} has bits outside the 29-bit field")]
    BadErrorClass(u32),
}

/// A CAN frame (classical, remote, FD or error). See the module doc for the
/// payload invariant.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct CanFrame {
    /// For error frames: the error class bits (`can_id` without `CAN_ERR_FLAG`),
    /// stored as `Extended`.
    id: FrameId,
    kind: FrameKind,
    len: u8,
    data: [u8; FD_MAX_LEN],
}

/// Whether `len` is a payload length some CAN FD DLC encodes.
pub fn is_fd_len(len: usize) -> bool {
    matches!(len, 0..=8 | 12 | 16 | 20 | 24 | 32 | 48 | 64)
}

#[inline]
fn check_len8_dlc(len: usize, len8_dlc: Option<u8>) -> Result<(), FrameError> {
    match len8_dlc {
        None => Ok(()),
        Some(dlc) if len == CLASSIC_MAX_LEN && (9..=15).contains(&dlc) => Ok(()),
        Some(dlc) => Err(FrameError::BadLen8Dlc(dlc)),
    }
}

#[inline]
fn payload(bytes: &[u8]) -> [u8; FD_MAX_LEN] {
    let mut data = [0; FD_MAX_LEN];
    data[..bytes.len()].copy_from_slice(bytes);
    data
}

impl CanFrame {
    /// A classical data frame of up to 8 bytes.
    ///
    /// # Errors
    /// [`FrameError`] when the arguments break the kind's limits.
    pub fn new_data(id: FrameId, bytes: &[u8]) -> Result<Self, FrameError> {
        Self::new_data_with_dlc(id, bytes, None)
    }

    /// A classical data frame with an optional raw DLC 9..=15 (8 bytes only).
    ///
    /// # Errors
    /// [`FrameError`] when the arguments break the kind's limits.
    #[inline]
    pub fn new_data_with_dlc(
        id: FrameId,
        bytes: &[u8],
        len8_dlc: Option<u8>,
    ) -> Result<Self, FrameError> {
        if bytes.len() > CLASSIC_MAX_LEN {
            return Err(FrameError::TooLong {
                len: bytes.len(),
                max: CLASSIC_MAX_LEN,
            });
        }
        check_len8_dlc(bytes.len(), len8_dlc)?;
        Ok(Self {
            id,
            kind: FrameKind::Data { len8_dlc },
            len: bytes.len() as u8,
            data: payload(bytes),
        })
    }

    /// A remote frame requesting `len` bytes (0..=8), optional raw DLC as above.
    ///
    /// # Errors
    /// [`FrameError`] when the arguments break the kind's limits.
    pub fn new_remote(id: FrameId, len: usize, len8_dlc: Option<u8>) -> Result<Self, FrameError> {
        if len > CLASSIC_MAX_LEN {
            return Err(FrameError::TooLong {
                len,
                max: CLASSIC_MAX_LEN,
            });
        }
        check_len8_dlc(len, len8_dlc)?;
        Ok(Self {
            id,
            kind: FrameKind::Remote { len8_dlc },
            len: len as u8,
            data: [0; FD_MAX_LEN],
        })
    }

    /// A CAN FD frame; `bytes.len()` must be a valid FD length.
    ///
    /// # Errors
    /// [`FrameError`] when the arguments break the kind's limits.
    #[inline]
    pub fn new_fd(id: FrameId, flags: u8, bytes: &[u8]) -> Result<Self, FrameError> {
        if bytes.len() > FD_MAX_LEN {
            return Err(FrameError::TooLong {
                len: bytes.len(),
                max: FD_MAX_LEN,
            });
        }
        if !is_fd_len(bytes.len()) {
            return Err(FrameError::BadFdLength(bytes.len()));
        }
        if flags > 0xF {
            return Err(FrameError::BadFdFlags(flags));
        }
        Ok(Self {
            id,
            kind: FrameKind::Fd { flags },
            len: bytes.len() as u8,
            data: payload(bytes),
        })
    }

    /// An error frame with error `class` bits (`CAN_ERR_*`, without
    /// `CAN_ERR_FLAG`) and the 8 error detail bytes.
    ///
    /// # Errors
    /// [`FrameError`] when the arguments break the kind's limits.
    pub fn new_error(class: u32, detail: [u8; ERROR_FRAME_LEN]) -> Result<Self, FrameError> {
        if class > MAX_EXTENDED_ID {
            return Err(FrameError::BadErrorClass(class));
        }
        Ok(Self {
            id: FrameId::Extended(class),
            kind: FrameKind::Error,
            len: ERROR_FRAME_LEN as u8,
            data: payload(&detail),
        })
    }

    /// The identifier (for error frames, the error class bits; prefer
    /// [`CanFrame::as_error`]).
    pub fn id(&self) -> FrameId {
        self.id
    }

    /// The frame kind.
    pub fn kind(&self) -> FrameKind {
        self.kind
    }

    /// Payload length in bytes (for remote frames: the requested length).
    pub fn len(&self) -> usize {
        usize::from(self.len)
    }

    /// Whether the frame carries no payload bytes.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The payload (empty for remote frames).
    pub fn data(&self) -> &[u8] {
        match self.kind {
            FrameKind::Remote { .. } => &[],
            _ => &self.data[..self.len()],
        }
    }

    /// Whether this is a classical or FD data frame (what decoders consume).
    pub fn is_data(&self) -> bool {
        matches!(self.kind, FrameKind::Data { .. } | FrameKind::Fd { .. })
    }

    /// The error frame view, for error frames only.
    pub fn as_error(&self) -> Option<ErrorFrame> {
        match self.kind {
            FrameKind::Error => {
                let mut detail = [0; ERROR_FRAME_LEN];
                detail.copy_from_slice(&self.data[..ERROR_FRAME_LEN]);
                Some(ErrorFrame {
                    class: self.id.raw(),
                    detail,
                })
            }
            _ => None,
        }
    }
}

impl fmt::Debug for CanFrame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("CanFrame")
            .field("id", &self.id)
            .field("kind", &self.kind)
            .field("len", &self.len)
            .field("data", &self.data())
            .finish()
    }
}

/// Error class bits of `<linux/can/error.h>` (`can_id` of an error frame).
pub mod err_class {
    /// TX timeout (by netdevice driver).
    pub const TX_TIMEOUT: u32 = 0x001;
    /// Lost arbitration; detail byte 0 is the bit number.
    pub const LOST_ARBITRATION: u32 = 0x002;
    /// Controller problems; detail byte 1 (see [`super::ctrl`]).
    pub const CONTROLLER: u32 = 0x004;
    /// Protocol violations; detail bytes 2 and 3.
    pub const PROTOCOL: u32 = 0x008;
    /// Transceiver status; detail byte 4.
    pub const TRANSCEIVER: u32 = 0x010;
    /// No ACK received on transmission.
    pub const NO_ACK: u32 = 0x020;
    /// Bus off.
    pub const BUS_OFF: u32 = 0x040;
    /// Bus error (may flood).
    pub const BUS_ERROR: u32 = 0x080;
    /// Controller restarted (after bus-off).
    pub const RESTARTED: u32 = 0x100;
    /// TX / RX error counters in detail bytes 6 and 7.
    pub const COUNTERS: u32 = 0x200;
}

/// Controller status bits of detail byte 1 (`CAN_ERR_CRTL_*`).
pub mod ctrl {
    /// RX buffer overflow.
    pub const RX_OVERFLOW: u8 = 0x01;
    /// TX buffer overflow.
    pub const TX_OVERFLOW: u8 = 0x02;
    /// Reached warning level for RX errors.
    pub const RX_WARNING: u8 = 0x04;
    /// Reached warning level for TX errors.
    pub const TX_WARNING: u8 = 0x08;
    /// Reached error-passive status RX.
    pub const RX_PASSIVE: u8 = 0x10;
    /// Reached error-passive status TX.
    pub const TX_PASSIVE: u8 = 0x20;
    /// Recovered to error-active state.
    pub const ACTIVE: u8 = 0x40;
}

/// What an error frame means for the daemon, most severe first: the caller
/// backs off on `BusOff`, and counts the others under their name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ErrorSeverity {
    /// The controller left the bus; nothing is sent or received until restart.
    BusOff,
    /// Error-passive (TX or RX error counter ≥ 128).
    ErrorPassive,
    /// Error counters reached the warning level (≥ 96).
    ErrorWarning,
    /// Frames were lost: RX/TX buffer overflow.
    Overflow,
    /// Faults on the wire: protocol violation, bus error, missing ACK,
    /// transceiver fault, TX timeout, lost arbitration.
    BusFault,
    /// The controller restarted or recovered to error-active.
    Recovered,
    /// No known class bit set.
    Unknown,
}

impl ErrorSeverity {
    /// Stable snake_case name, used as a statistics key.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::BusOff => "bus_off",
            Self::ErrorPassive => "error_passive",
            Self::ErrorWarning => "error_warning",
            Self::Overflow => "overflow",
            Self::BusFault => "bus_fault",
            Self::Recovered => "recovered",
            Self::Unknown => "unknown_error",
        }
    }
}

/// An error frame's class bits and detail bytes (`<linux/can/error.h>`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ErrorFrame {
    /// `CAN_ERR_*` class bits (see [`err_class`]).
    pub class: u32,
    /// The 8 detail bytes.
    pub detail: [u8; ERROR_FRAME_LEN],
}

impl ErrorFrame {
    /// Whether any of `bits` (from [`err_class`]) is set.
    pub fn has(&self, bits: u32) -> bool {
        self.class & bits != 0
    }

    /// Controller status byte (detail 1), meaningful with `CONTROLLER`.
    pub fn controller_status(&self) -> u8 {
        if self.has(err_class::CONTROLLER) {
            self.detail[1]
        } else {
            0
        }
    }

    /// TX and RX error counters, when the driver reported them.
    pub fn error_counters(&self) -> Option<(u8, u8)> {
        self.has(err_class::COUNTERS)
            .then_some((self.detail[6], self.detail[7]))
    }

    /// The most severe condition this frame reports (one frame often carries
    /// several; the caller acts on the worst).
    pub fn severity(&self) -> ErrorSeverity {
        let status = self.controller_status();
        if self.has(err_class::BUS_OFF) {
            ErrorSeverity::BusOff
        } else if status & (ctrl::RX_PASSIVE | ctrl::TX_PASSIVE) != 0 {
            ErrorSeverity::ErrorPassive
        } else if status & (ctrl::RX_WARNING | ctrl::TX_WARNING) != 0 {
            ErrorSeverity::ErrorWarning
        } else if status & (ctrl::RX_OVERFLOW | ctrl::TX_OVERFLOW) != 0 {
            ErrorSeverity::Overflow
        } else if self.has(
            err_class::PROTOCOL
                | err_class::BUS_ERROR
                | err_class::NO_ACK
                | err_class::TRANSCEIVER
                | err_class::TX_TIMEOUT
                | err_class::LOST_ARBITRATION,
        ) {
            ErrorSeverity::BusFault
        } else if self.has(err_class::RESTARTED) || status & ctrl::ACTIVE != 0 {
            ErrorSeverity::Recovered
        } else {
            ErrorSeverity::Unknown
        }
    }
}

/// The payload length a CAN FD DLC stands for (ISO 11898-1: 0–8, then
/// 12, 16, 20, 24, 32, 48, 64), as the binary log formats store the DLC.
#[must_use]
pub fn fd_dlc_len(dlc: u8) -> usize {
    match dlc {
        0..=8 => usize::from(dlc),
        9 => 12,
        10 => 16,
        11 => 20,
        12 => 24,
        13 => 32,
        14 => 48,
        _ => 64,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constructors_check_lengths() {
        let id = FrameId::Standard(1);
        assert!(CanFrame::new_data(id, &[0; 8]).is_ok());
        assert_eq!(
            CanFrame::new_data(id, &[0; 9]),
            Err(FrameError::TooLong { len: 9, max: 8 })
        );
        assert_eq!(
            CanFrame::new_data_with_dlc(id, &[0; 7], Some(9)),
            Err(FrameError::BadLen8Dlc(9))
        );
        assert_eq!(
            CanFrame::new_data_with_dlc(id, &[0; 8], Some(8)),
            Err(FrameError::BadLen8Dlc(8))
        );
        assert!(CanFrame::new_data_with_dlc(id, &[0; 8], Some(15)).is_ok());
        assert_eq!(
            CanFrame::new_fd(id, 0, &[0; 9]),
            Err(FrameError::BadFdLength(9))
        );
        assert!(CanFrame::new_fd(id, 5, &[0; 64]).is_ok());
        assert_eq!(
            CanFrame::new_fd(id, 0x10, &[]),
            Err(FrameError::BadFdFlags(0x10))
        );
        assert_eq!(
            CanFrame::new_remote(id, 9, None),
            Err(FrameError::TooLong { len: 9, max: 8 })
        );
        assert_eq!(
            CanFrame::new_error(0x2000_0000, [0; 8]),
            Err(FrameError::BadErrorClass(0x2000_0000))
        );
    }

    #[test]
    fn remote_frames_carry_no_payload() {
        let f = CanFrame::new_remote(FrameId::Standard(0x10), 4, None).unwrap();
        assert_eq!(f.len(), 4);
        assert!(f.data().is_empty());
        assert!(!f.is_data());
    }

    #[test]
    fn error_frames_are_classified_by_worst_condition() {
        let sev = |class, d1| {
            let mut d = [0; 8];
            d[1] = d1;
            CanFrame::new_error(class, d)
                .unwrap()
                .as_error()
                .unwrap()
                .severity()
        };
        assert_eq!(
            sev(err_class::BUS_OFF | err_class::CONTROLLER, ctrl::TX_PASSIVE),
            ErrorSeverity::BusOff
        );
        assert_eq!(
            sev(err_class::CONTROLLER, ctrl::RX_PASSIVE | ctrl::RX_WARNING),
            ErrorSeverity::ErrorPassive
        );
        assert_eq!(
            sev(err_class::CONTROLLER, ctrl::TX_WARNING),
            ErrorSeverity::ErrorWarning
        );
        assert_eq!(
            sev(err_class::CONTROLLER, ctrl::RX_OVERFLOW),
            ErrorSeverity::Overflow
        );
        // Detail byte 1 means nothing without the CONTROLLER class bit.
        assert_eq!(
            sev(err_class::NO_ACK, ctrl::TX_PASSIVE),
            ErrorSeverity::BusFault
        );
        assert_eq!(sev(err_class::RESTARTED, 0), ErrorSeverity::Recovered);
        assert_eq!(
            sev(err_class::CONTROLLER, ctrl::ACTIVE),
            ErrorSeverity::Recovered
        );
        assert_eq!(sev(0, 0), ErrorSeverity::Unknown);
    }

    #[test]
    fn error_counters_need_their_class_bit() {
        let mut d = [0; 8];
        d[6] = 130;
        d[7] = 5;
        let with = CanFrame::new_error(err_class::COUNTERS, d).unwrap();
        let without = CanFrame::new_error(err_class::NO_ACK, d).unwrap();
        assert_eq!(with.as_error().unwrap().error_counters(), Some((130, 5)));
        assert_eq!(without.as_error().unwrap().error_counters(), None);
        assert!(
            CanFrame::new_data(FrameId::Standard(1), &[])
                .unwrap()
                .as_error()
                .is_none()
        );
    }
}
