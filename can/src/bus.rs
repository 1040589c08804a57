//! The transport the daemon runs on: a small receive/send abstraction with
//! two implementations, an in-process bus (for `demo` and host tests) and
//! SocketCAN (for vehicles).
//!
//! Shape: opening a transport yields a receiving half ([`FrameSource`]) and a
//! sending half ([`FrameSink`]), because the daemon's rx task and its
//! publishing tasks run concurrently and must not share a `&mut`.
//!
//! Faults are never hidden. Frames lost to a slow receiver arrive as
//! [`BusEvent::Lost`] with their count; controller error frames (bus-off,
//! error-passive, overflow, …) as [`BusEvent::Error`]; an interface that goes
//! down or disappears ends the endpoint with a [`BusError`] whose
//! [`BusError::is_transient`] tells the caller to reopen after a backoff.
//!
//! Filters follow the kernel's `CAN_RAW_FILTER` semantics on both transports,
//! so a configuration behaves the same in `demo` and on a vehicle.

use crate::frame::{CanFrame, ErrorFrame, FrameId, FrameKind, MAX_EXTENDED_ID};
use crate::time::Timestamp;
use std::future::Future;
use std::io;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, SystemTime, UNIX_EPOCH};
use tokio::sync::{broadcast, watch};

/// A frame and the time it was received (kernel receive timestamp on
/// SocketCAN, bus clock on the in-process bus).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Received {
    /// Receive time, µs since the Unix epoch.
    pub timestamp: Timestamp,
    /// The frame (never an error frame: those arrive as [`BusEvent::Error`]).
    pub frame: CanFrame,
}

/// What a receive yields.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BusEvent {
    /// A data, FD or remote frame that passed the filters.
    Frame(Received),
    /// An error frame from the controller; the caller acts on
    /// [`ErrorFrame::severity`] (e.g. backs off on bus-off).
    Error {
        /// Receive time.
        timestamp: Timestamp,
        /// Class and detail bytes.
        error: ErrorFrame,
    },
    /// This many frames were lost because the receiver fell behind.
    Lost {
        /// Number of frames dropped.
        count: u64,
    },
}

/// Why an endpoint cannot go on.
#[derive(Debug, thiserror::Error)]
pub enum BusError {
    /// The interface exists but is down (`ENETDOWN`).
    #[error("CAN interface {iface} is down")]
    InterfaceDown {
        /// Interface name.
        iface: String,
    },
    /// The interface does not exist, or disappeared (`ENODEV`/`ENXIO`).
    #[error("CAN interface {iface} does not exist")]
    NoSuchInterface {
        /// Interface name.
        iface: String,
    },
    /// The kernel's transmit queue is full (`ENOBUFS`): typically nobody
    /// acknowledges our frames (alone on the bus) or the controller is
    /// bus-off. The frame is dropped; later sends may succeed.
    #[error("CAN interface {iface}: transmit queue full")]
    TxQueueFull {
        /// Interface name.
        iface: String,
    },
    /// Every handle and sender of the in-process bus was dropped.
    #[error("in-process bus closed")]
    Closed,
    /// Error frames cannot be sent.
    #[error("error frames cannot be sent")]
    Unsendable,
    /// Any other socket error.
    #[error("CAN interface {iface}: {source}")]
    Io {
        /// Interface name.
        iface: String,
        /// The OS error.
        #[source]
        source: io::Error,
    },
}

impl BusError {
    /// Whether a send error means the link itself is gone (the receiver
    /// must reopen): the socket error that tells of it is shared by both
    /// halves of a raw CAN socket, and a send that meets it consumes it.
    pub fn is_link_loss(&self) -> bool {
        matches!(
            self,
            BusError::InterfaceDown { .. } | BusError::NoSuchInterface { .. }
        )
    }

    /// Whether reopening the interface later may succeed (the caller retries
    /// with backoff); `false` when the in-process bus is gone for good or
    /// for programming errors such as sending an error frame.
    pub fn is_transient(&self) -> bool {
        !matches!(self, Self::Unsendable | Self::Closed)
    }

    /// What the operator can do about it, for the errors a setup causes.
    pub fn hint(&self) -> Option<String> {
        match self {
            Self::NoSuchInterface { iface } => Some(format!(
                "is CAN support in this kernel (`modprobe can_raw`), and does {iface} exist \
                 (`ip link show {iface}`)? A real one comes with its driver; a virtual one for \
                 tests: `ip link add dev {iface} type vcan && ip link set {iface} up`"
            )),
            Self::InterfaceDown { iface } => Some(format!(
                "bring it up at the bus's bit rate: `ip link set {iface} up type can bitrate 500000` \
                 (or `ip link set {iface} up` for vcan)"
            )),
            _ => None,
        }
    }

    /// Maps an OS error on `iface` to the typed variants. A raw CAN socket
    /// reports `ENETDOWN` once when its interface goes down and `ENODEV`
    /// when it is unregistered; the socket stays usable after the former,
    /// so the caller may keep it or reopen after a backoff.
    pub fn from_io(iface: &str, source: io::Error) -> Self {
        let iface = iface.to_owned();
        match source.raw_os_error() {
            Some(code) if code == libc::ENETDOWN => Self::InterfaceDown { iface },
            Some(code) if code == libc::ENODEV || code == libc::ENXIO => {
                Self::NoSuchInterface { iface }
            }
            Some(code) if code == libc::ENOBUFS => Self::TxQueueFull { iface },
            _ => Self::Io { iface, source },
        }
    }
}

/// A receive filter with `CAN_RAW_FILTER` semantics: a data frame passes
/// when it has the filter's format and `frame_id & mask == id & mask`.
/// Remote frames pass only [`IdFilter::accept_all`], as with the kernel
/// filters this is translated into (RTR bit in the mask).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IdFilter {
    id: FrameId,
    mask: u32,
    accept_all: bool,
}

impl IdFilter {
    /// Exactly this identifier (data and FD frames).
    pub fn exact(id: FrameId) -> Self {
        Self {
            id,
            mask: MAX_EXTENDED_ID,
            accept_all: false,
        }
    }

    /// Identifiers equal to `id` on the bits of `mask`.
    pub fn masked(id: FrameId, mask: u32) -> Self {
        Self {
            id,
            mask: mask & MAX_EXTENDED_ID,
            accept_all: false,
        }
    }

    /// Every frame.
    pub fn accept_all() -> Self {
        Self {
            id: FrameId::Standard(0),
            mask: 0,
            accept_all: true,
        }
    }

    /// Whether `frame` passes this filter.
    pub fn matches(&self, frame: &CanFrame) -> bool {
        if self.accept_all {
            return true;
        }
        let id = frame.id();
        frame.is_data()
            && id.is_extended() == self.id.is_extended()
            && id.raw() & self.mask == self.id.raw() & self.mask
    }
}

/// Whether `frame` passes any of `filters` (none: nothing passes, as with
/// an empty kernel filter list).
pub fn passes(filters: &[IdFilter], frame: &CanFrame) -> bool {
    filters.iter().any(|f| f.matches(frame))
}

/// The receiving half of a transport.
pub trait FrameSource: Send {
    /// The next event. Cancel-safe: dropping the future loses no frame.
    fn recv(&mut self) -> impl Future<Output = Result<BusEvent, BusError>> + Send;

    /// Replaces the receive filters (error frames always pass).
    ///
    /// # Errors
    /// The kernel refused the filter list.
    fn set_filters(&mut self, filters: &[IdFilter]) -> Result<(), BusError>;
}

/// The sending half of a transport.
pub trait FrameSink: Send + Sync {
    /// Sends one frame.
    fn send(&self, frame: &CanFrame) -> impl Future<Output = Result<(), BusError>> + Send;
}

/// Link state of the in-process bus, for fault-injection tests.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinkState {
    /// Frames flow.
    Up,
    /// Like `ip link set down`: endpoints fail with `InterfaceDown`.
    Down,
    /// Like `ip link del`: endpoints fail with `NoSuchInterface`.
    Gone,
}

#[derive(Clone, Copy, Debug)]
struct Envelope {
    /// Endpoint that sent it; 0 for the simulated controller (error frames).
    sender: u64,
    timestamp: Timestamp,
    frame: CanFrame,
}

/// An in-process CAN bus: every endpoint sees the frames the others send
/// (not its own, as a raw socket without `CAN_RAW_RECV_OWN_MSGS`).
///
/// Sending never blocks, like putting a frame on a wire: a receiver that
/// falls more than `capacity` frames behind loses the oldest and is told how
/// many with [`BusEvent::Lost`]. Time stamps come from tokio's clock (so
/// paused-time tests are deterministic) offset to the wall-clock epoch
/// chosen at creation.
#[derive(Clone, Debug)]
pub struct InProcessBus {
    inner: Arc<BusInner>,
}

#[derive(Debug)]
struct BusInner {
    name: String,
    frames: broadcast::Sender<Envelope>,
    link: watch::Sender<LinkState>,
    next_endpoint: AtomicU64,
    epoch: Timestamp,
    start: tokio::time::Instant,
}

impl InProcessBus {
    /// A bus named `name` whose receivers may lag `capacity` frames, with
    /// time stamps starting at the current wall-clock time.
    pub fn new(name: &str, capacity: usize) -> Self {
        let now = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .unwrap_or(Duration::ZERO);
        Self::with_epoch(
            name,
            capacity,
            Timestamp::from_micros(now.as_micros() as u64),
        )
    }

    /// As [`InProcessBus::new`] with time stamps starting at `epoch`
    /// (reproducible tests).
    pub fn with_epoch(name: &str, capacity: usize, epoch: Timestamp) -> Self {
        let (frames, _) = broadcast::channel(capacity.max(1));
        let (link, _) = watch::channel(LinkState::Up);
        Self {
            inner: Arc::new(BusInner {
                name: name.to_owned(),
                frames,
                link,
                next_endpoint: AtomicU64::new(1),
                epoch,
                start: tokio::time::Instant::now(),
            }),
        }
    }

    /// The bus clock now.
    pub fn now(&self) -> Timestamp {
        let elapsed = self.inner.start.elapsed().as_micros() as u64;
        Timestamp::from_micros(self.inner.epoch.as_micros().saturating_add(elapsed))
    }

    /// A new endpoint accepting every frame, or the link's error when the
    /// link is not up (as opening a socket on a missing interface fails).
    ///
    /// # Errors
    /// [`BusError::InterfaceDown`] / [`BusError::NoSuchInterface`].
    pub fn open(&self) -> Result<(InProcessRx, InProcessTx), BusError> {
        self.link_error()?;
        let id = self.inner.next_endpoint.fetch_add(1, Ordering::Relaxed);
        let rx = InProcessRx {
            name: self.inner.name.clone(),
            id,
            frames: self.inner.frames.subscribe(),
            link: self.inner.link.subscribe(),
            link_alive: true,
            filters: vec![IdFilter::accept_all()],
        };
        let tx = InProcessTx {
            bus: self.clone(),
            id,
        };
        Ok((rx, tx))
    }

    /// Sets the link state; endpoints notice at once.
    pub fn set_link(&self, state: LinkState) {
        self.inner.link.send_replace(state);
    }

    /// Delivers an error frame to every endpoint, as a controller would.
    pub fn inject_error(&self, error: ErrorFrame) {
        if let Ok(frame) = CanFrame::new_error(error.class, error.detail) {
            self.deliver(0, frame);
        }
    }

    fn deliver(&self, sender: u64, frame: CanFrame) {
        // No receiver at all is not an error: nobody listens on the wire.
        let _ = self.inner.frames.send(Envelope {
            sender,
            timestamp: self.now(),
            frame,
        });
    }

    fn link_error(&self) -> Result<(), BusError> {
        link_result(*self.inner.link.borrow(), &self.inner.name)
    }
}

fn link_result(state: LinkState, name: &str) -> Result<(), BusError> {
    match state {
        LinkState::Up => Ok(()),
        LinkState::Down => Err(BusError::InterfaceDown {
            iface: name.to_owned(),
        }),
        LinkState::Gone => Err(BusError::NoSuchInterface {
            iface: name.to_owned(),
        }),
    }
}

/// Receiving half of an in-process endpoint.
#[derive(Debug)]
pub struct InProcessRx {
    /// Only the name: holding the bus would keep it open forever, and a
    /// receiver must see [`BusError::Closed`] once every sender is gone.
    name: String,
    id: u64,
    frames: broadcast::Receiver<Envelope>,
    link: watch::Receiver<LinkState>,
    link_alive: bool,
    filters: Vec<IdFilter>,
}

impl FrameSource for InProcessRx {
    async fn recv(&mut self) -> Result<BusEvent, BusError> {
        loop {
            // A link change wins over queued frames: a socket on a downed
            // interface reports ENETDOWN even with data in its queue.
            let state = *self.link.borrow_and_update();
            link_result(state, &self.name)?;
            let envelope = tokio::select! {
                biased;
                changed = self.link.changed(), if self.link_alive => {
                    // The bus is being dropped: deliver what is queued, then
                    // the frame channel reports the close.
                    self.link_alive = changed.is_ok();
                    continue;
                }
                received = self.frames.recv() => match received {
                    Ok(envelope) => envelope,
                    Err(broadcast::error::RecvError::Lagged(count)) => {
                        return Ok(BusEvent::Lost { count });
                    }
                    Err(broadcast::error::RecvError::Closed) => return Err(BusError::Closed),
                },
            };
            if envelope.sender == self.id {
                continue;
            }
            if let Some(error) = envelope.frame.as_error() {
                return Ok(BusEvent::Error {
                    timestamp: envelope.timestamp,
                    error,
                });
            }
            if passes(&self.filters, &envelope.frame) {
                return Ok(BusEvent::Frame(Received {
                    timestamp: envelope.timestamp,
                    frame: envelope.frame,
                }));
            }
        }
    }

    fn set_filters(&mut self, filters: &[IdFilter]) -> Result<(), BusError> {
        filters.clone_into(&mut self.filters);
        Ok(())
    }
}

/// Sending half of an in-process endpoint.
#[derive(Clone, Debug)]
pub struct InProcessTx {
    bus: InProcessBus,
    id: u64,
}

impl FrameSink for InProcessTx {
    async fn send(&self, frame: &CanFrame) -> Result<(), BusError> {
        if matches!(frame.kind(), FrameKind::Error) {
            return Err(BusError::Unsendable);
        }
        self.bus.link_error()?;
        self.bus.deliver(self.id, *frame);
        Ok(())
    }
}

pub use self::socketcan_bus::{SocketCanRx, SocketCanTx, open_socketcan};

/// `SO_MEMINFO` (`asm-generic/socket.h`, the value on x86-64 and arm64):
/// `getsockopt` fills `u32[SK_MEMINFO_VARS]` with the socket's memory
/// counters, among them `sk_drops`.
const SO_MEMINFO: libc::c_int = 55;

/// Size of the `SO_MEMINFO` answer we need: up to and including
/// `SK_MEMINFO_DROPS` (index 8, Linux 4.12 and later).
pub const MEMINFO_LEN: usize = (libc::SK_MEMINFO_DROPS as usize + 1) * 4;

/// The socket's drop counter (`sk_drops`: frames the kernel discarded
/// because the socket's receive queue was full) from an `SO_MEMINFO`
/// answer of `len` bytes, `None` when the kernel's answer is too short to
/// hold it.
pub fn drops_from_meminfo(buf: &[u8], len: usize) -> Option<u64> {
    let at = libc::SK_MEMINFO_DROPS as usize * 4;
    if len < at + 4 || buf.len() < at + 4 {
        return None;
    }
    let bytes: [u8; 4] = buf[at..at + 4].try_into().ok()?;
    Some(u64::from(u32::from_ne_bytes(bytes)))
}

/// SocketCAN through the socketcan crate's tokio socket. Cannot run on a
/// host without CAN in its kernel; exercised by the vcan VM tests.
mod socketcan_bus {
    use super::{
        BusError, BusEvent, FrameSink, FrameSource, IdFilter, MEMINFO_LEN, Received, SO_MEMINFO,
        drops_from_meminfo,
    };
    use crate::frame::{CanFrame, FrameId, FrameKind, MAX_EXTENDED_ID};
    use crate::time::Timestamp;
    use socketcan::{
        CanAnyFrame, CanDataFrame, CanFdFrame, CanFilter, CanRemoteFrame, EmbeddedFrame, Id,
        SocketOptions, id::FdFlags, tokio::CanFdSocket,
    };
    use std::io;
    use std::sync::Arc;
    use std::time::{Duration, SystemTime, UNIX_EPOCH};

    const CAN_EFF_FLAG: u32 = 0x8000_0000;
    const CAN_RTR_FLAG: u32 = 0x4000_0000;
    const CAN_ERR_MASK: u32 = 0x1FFF_FFFF;

    /// Receiving half of a SocketCAN endpoint.
    ///
    /// Frames the kernel drops because this socket's receive queue is full
    /// are counted by the kernel (`sk_drops`, read with `SO_MEMINFO`, which
    /// is the counter `SO_RXQ_OVFL` reports too); every increase is handed
    /// to the caller as [`BusEvent::Lost`] before the next frame, and the
    /// total is logged when the endpoint closes.
    #[derive(Debug)]
    pub struct SocketCanRx {
        iface: String,
        socket: Arc<CanFdSocket>,
        /// `sk_drops` when the socket was opened (it starts at 0; kept in
        /// case a kernel ever does not) and when last reported.
        drops_at_open: u64,
        drops_reported: u64,
        /// Frames read since the drop counter was last looked at.
        frames_since_drop_check: u32,
        /// The kernel lacks `SO_MEMINFO` (before 4.12): drops cannot be counted.
        drops_unknown: bool,
    }

    /// Sending half of a SocketCAN endpoint (shares the socket).
    #[derive(Clone, Debug)]
    pub struct SocketCanTx {
        iface: String,
        socket: Arc<CanFdSocket>,
    }

    /// Opens `iface` as an FD-capable raw socket (classical frames too) with
    /// kernel receive time stamps, all error classes reported, and
    /// `filters` installed in the kernel.
    ///
    /// # Errors
    /// Typed [`BusError`] when the interface is missing, down or refuses an
    /// option.
    pub fn open_socketcan(
        iface: &str,
        filters: &[IdFilter],
    ) -> Result<(SocketCanRx, SocketCanTx), BusError> {
        let err = |e| BusError::from_io(iface, e);
        let socket = CanFdSocket::open(iface).map_err(err)?;
        socket.set_recv_timestamp(true).map_err(err)?;
        socket.set_error_filter_accept_all().map_err(err)?;
        let mut rx = SocketCanRx {
            iface: iface.to_owned(),
            socket: Arc::new(socket),
            drops_at_open: 0,
            drops_reported: 0,
            frames_since_drop_check: 0,
            drops_unknown: false,
        };
        match rx.read_kernel_drops() {
            Ok(n) => (rx.drops_at_open, rx.drops_reported) = (n, n),
            Err(e) => {
                tracing::warn!(iface, cause = %e, "kernel drop counter unreadable; drops not counted");
                rx.drops_unknown = true;
            }
        }
        rx.set_filters(filters)?;
        let tx = SocketCanTx {
            iface: iface.to_owned(),
            socket: Arc::clone(&rx.socket),
        };
        Ok((rx, tx))
    }

    fn kernel_filter(f: &IdFilter) -> CanFilter {
        if f.accept_all {
            return CanFilter::new(0, 0);
        }
        let eff = if f.id.is_extended() { CAN_EFF_FLAG } else { 0 };
        // EFF and RTR in the mask: the format must match and remote frames
        // are refused, as `IdFilter::matches` documents.
        CanFilter::new(f.id.raw() | eff, f.mask | CAN_EFF_FLAG | CAN_RTR_FLAG)
    }

    fn id_of(id: Id) -> FrameId {
        match id {
            Id::Standard(s) => FrameId::Standard(s.as_raw()),
            Id::Extended(e) => FrameId::Extended(e.as_raw()),
        }
    }

    fn to_micros(t: SystemTime) -> Timestamp {
        let us = t
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_micros() as u64);
        Timestamp::from_micros(us)
    }

    /// How long a receive waits before checking the socket for an error.
    const SOCKET_ERROR_POLL: Duration = Duration::from_millis(250);

    /// How many frames may be read between two looks at the kernel's drop
    /// counter: a drop is reported at most this many frames late, and the
    /// `getsockopt` costs one syscall per this many reads. While no frame
    /// arrives the counter is read at every [`SOCKET_ERROR_POLL`].
    const DROP_CHECK_EVERY: u32 = 64;

    impl SocketCanRx {
        /// The kernel's count of frames dropped on this socket since it was
        /// opened (its receive queue was full).
        ///
        /// # Errors
        /// The kernel cannot report it (no `SO_MEMINFO`).
        pub fn kernel_drops(&self) -> io::Result<u64> {
            Ok(self.read_kernel_drops()?.saturating_sub(self.drops_at_open))
        }

        fn read_kernel_drops(&self) -> io::Result<u64> {
            let mut buf = [0u8; MEMINFO_LEN];
            let len =
                self.socket
                    .get_socket_option_bytes(libc::SOL_SOCKET, SO_MEMINFO, &mut buf)?;
            drops_from_meminfo(&buf, len).ok_or_else(|| {
                io::Error::new(
                    io::ErrorKind::Unsupported,
                    format!("SO_MEMINFO answered {len} bytes, without the drop counter"),
                )
            })
        }

        /// New kernel drops since the last report, if any.
        fn new_drops(&mut self) -> Option<u64> {
            self.frames_since_drop_check = 0;
            if self.drops_unknown {
                return None;
            }
            let now = self.read_kernel_drops().ok()?;
            let new = now.saturating_sub(self.drops_reported);
            self.drops_reported = self.drops_reported.max(now);
            (new > 0).then_some(new)
        }

        /// Takes (and clears) a pending socket error: `ENETDOWN` after the
        /// interface went down, `ENODEV` after it was deleted.
        fn check_socket_error(&self) -> Result<(), BusError> {
            let code = self
                .socket
                .get_socket_option_int(libc::SOL_SOCKET, libc::SO_ERROR)
                .map_err(|e| BusError::from_io(&self.iface, e))?;
            if code == 0 {
                Ok(())
            } else {
                Err(BusError::from_io(
                    &self.iface,
                    io::Error::from_raw_os_error(code),
                ))
            }
        }
    }

    impl FrameSource for SocketCanRx {
        async fn recv(&mut self) -> Result<BusEvent, BusError> {
            loop {
                if self.frames_since_drop_check >= DROP_CHECK_EVERY
                    && let Some(count) = self.new_drops()
                {
                    return Ok(BusEvent::Lost { count });
                }
                // The kernel reports an interface going down or away through
                // the socket error (EPOLLERR), which tokio does not treat as
                // read readiness: while no frame arrives, poll SO_ERROR.
                let read = tokio::select! {
                    read = self.socket.read_frame_with_timestamp() => read,
                    () = tokio::time::sleep(SOCKET_ERROR_POLL) => {
                        self.check_socket_error()?;
                        if let Some(count) = self.new_drops() {
                            return Ok(BusEvent::Lost { count });
                        }
                        continue;
                    }
                };
                self.frames_since_drop_check += 1;
                let (frame, time) = read.map_err(|e| BusError::from_io(&self.iface, e))?;
                let timestamp = to_micros(time);
                // A frame the kernel hands over that our type rejects (e.g.
                // a bad FD length from a broken driver) is skipped, not fatal.
                let converted = match frame {
                    CanAnyFrame::Normal(f) => CanFrame::new_data(id_of(f.id()), f.data()),
                    CanAnyFrame::Remote(f) => CanFrame::new_remote(id_of(f.id()), f.dlc(), None),
                    CanAnyFrame::Fd(f) => {
                        CanFrame::new_fd(id_of(f.id()), f.flags().bits() & 0xF, f.data())
                    }
                    CanAnyFrame::Error(f) => {
                        let mut detail = [0; 8];
                        let data = f.data();
                        let n = data.len().min(8);
                        detail[..n].copy_from_slice(&data[..n]);
                        CanFrame::new_error(f.error_bits() & CAN_ERR_MASK, detail)
                    }
                };
                let Ok(frame) = converted else { continue };
                return Ok(match frame.as_error() {
                    Some(error) => BusEvent::Error { timestamp, error },
                    None => BusEvent::Frame(Received { timestamp, frame }),
                });
            }
        }

        fn set_filters(&mut self, filters: &[IdFilter]) -> Result<(), BusError> {
            let kernel: Vec<CanFilter> = filters.iter().map(kernel_filter).collect();
            let result = if kernel.is_empty() {
                self.socket.set_filter_drop_all()
            } else {
                self.socket.set_filters(&kernel)
            };
            result.map_err(|e| BusError::from_io(&self.iface, e))
        }
    }

    impl Drop for SocketCanRx {
        fn drop(&mut self) {
            // The total since open, including drops not yet handed over as
            // `Lost`: the figure an operator compares with the statistics.
            match self.kernel_drops() {
                Ok(kernel_drops) if !self.drops_unknown => {
                    tracing::info!(iface = %self.iface, kernel_drops, "CAN socket closed");
                }
                _ => tracing::info!(iface = %self.iface, "CAN socket closed"),
            }
        }
    }

    impl FrameSink for SocketCanTx {
        async fn send(&self, frame: &CanFrame) -> Result<(), BusError> {
            let id: Id = match frame.id() {
                FrameId::Standard(raw) => socketcan::StandardId::new(raw).map(Id::Standard),
                FrameId::Extended(raw) => {
                    socketcan::ExtendedId::new(raw & MAX_EXTENDED_ID).map(Id::Extended)
                }
            }
            .ok_or(BusError::Unsendable)?;
            let io = match frame.kind() {
                FrameKind::Data { .. } => {
                    let f = CanDataFrame::new(id, frame.data()).ok_or(BusError::Unsendable)?;
                    self.socket.write_frame(&f).await
                }
                FrameKind::Remote { .. } => {
                    let f =
                        CanRemoteFrame::new_remote(id, frame.len()).ok_or(BusError::Unsendable)?;
                    self.socket.write_frame(&f).await
                }
                FrameKind::Fd { flags } => {
                    let f = CanFdFrame::with_flags(
                        id,
                        frame.data(),
                        FdFlags::from_bits_truncate(flags),
                    )
                    .ok_or(BusError::Unsendable)?;
                    self.socket.write_frame(&f).await
                }
                FrameKind::Error => return Err(BusError::Unsendable),
            };
            io.map_err(|e| BusError::from_io(&self.iface, e))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{ErrorSeverity, err_class};

    fn data(id: u16, b: &[u8]) -> CanFrame {
        CanFrame::new_data(FrameId::Standard(id), b).unwrap()
    }

    async fn next_frame(rx: &mut InProcessRx) -> Received {
        match rx.recv().await.unwrap() {
            BusEvent::Frame(r) => r,
            other => panic!("expected a frame, got {other:?}"),
        }
    }

    #[test]
    fn setup_errors_carry_a_hint_naming_the_interface() {
        for e in [
            BusError::NoSuchInterface {
                iface: "can7".into(),
            },
            BusError::InterfaceDown {
                iface: "can7".into(),
            },
        ] {
            let hint = e.hint().unwrap();
            assert!(hint.contains("ip link") && hint.contains("can7"), "{hint}");
        }
        assert!(BusError::Closed.hint().is_none());
    }

    #[tokio::test(start_paused = true)]
    async fn every_endpoint_sees_the_others_frames_but_not_its_own() {
        let bus = InProcessBus::with_epoch("sim0", 16, Timestamp::from_micros(1_000_000));
        let (mut rx_a, tx_a) = bus.open().unwrap();
        let (mut rx_b, tx_b) = bus.open().unwrap();
        let (mut rx_c, _tx_c) = bus.open().unwrap();
        tx_a.send(&data(0x100, &[1])).await.unwrap();
        tokio::time::advance(Duration::from_millis(10)).await;
        tx_b.send(&data(0x101, &[2])).await.unwrap();
        let b1 = next_frame(&mut rx_b).await;
        assert_eq!(b1.frame, data(0x100, &[1]));
        assert_eq!(b1.timestamp.as_micros(), 1_000_000);
        let a1 = next_frame(&mut rx_a).await;
        assert_eq!(a1.frame, data(0x101, &[2]));
        assert_eq!(a1.timestamp.as_micros(), 1_010_000);
        assert_eq!(next_frame(&mut rx_c).await.frame, data(0x100, &[1]));
        assert_eq!(next_frame(&mut rx_c).await.frame, data(0x101, &[2]));
        // Nothing else is pending for A: its own frame was not echoed.
        let pending = tokio::time::timeout(Duration::from_millis(50), rx_a.recv()).await;
        assert!(pending.is_err(), "unexpected {pending:?}");
    }

    #[tokio::test(start_paused = true)]
    async fn lag_is_reported_with_its_count() {
        let bus = InProcessBus::new("sim0", 4);
        let (mut slow, _) = bus.open().unwrap();
        let (_, tx) = bus.open().unwrap();
        for i in 0..10u8 {
            tx.send(&data(0x200, &[i])).await.unwrap();
        }
        assert_eq!(slow.recv().await.unwrap(), BusEvent::Lost { count: 6 });
        for i in 6..10u8 {
            assert_eq!(next_frame(&mut slow).await.frame.data(), &[i]);
        }
    }

    #[tokio::test(start_paused = true)]
    async fn filters_follow_kernel_semantics() {
        let bus = InProcessBus::new("sim0", 64);
        let (mut rx, _) = bus.open().unwrap();
        let (_, tx) = bus.open().unwrap();
        rx.set_filters(&[
            IdFilter::exact(FrameId::Standard(0x100)),
            IdFilter::masked(FrameId::Extended(0x1800_0000), 0x1F00_0000),
        ])
        .unwrap();
        let sent = [
            data(0x101, &[0]),                                                 // other id
            CanFrame::new_data(FrameId::Extended(0x100), &[1]).unwrap(),       // wrong format
            CanFrame::new_remote(FrameId::Standard(0x100), 2, None).unwrap(),  // remote
            data(0x100, &[2]),                                                 // passes
            CanFrame::new_data(FrameId::Extended(0x18FE_F100), &[3]).unwrap(), // passes (mask)
            CanFrame::new_data(FrameId::Extended(0x19FE_F100), &[4]).unwrap(), // masked out
            CanFrame::new_fd(FrameId::Standard(0x100), 1, &[5; 12]).unwrap(),  // FD passes
        ];
        for f in &sent {
            tx.send(f).await.unwrap();
        }
        assert_eq!(next_frame(&mut rx).await.frame, sent[3]);
        assert_eq!(next_frame(&mut rx).await.frame, sent[4]);
        assert_eq!(next_frame(&mut rx).await.frame, sent[6]);
        rx.set_filters(&[]).unwrap();
        tx.send(&data(0x100, &[9])).await.unwrap();
        assert!(
            tokio::time::timeout(Duration::from_millis(10), rx.recv())
                .await
                .is_err()
        );
        assert!(passes(&[IdFilter::accept_all()], &sent[2]));
    }

    #[tokio::test(start_paused = true)]
    async fn error_frames_pass_filters_and_cannot_be_sent() {
        let bus = InProcessBus::new("sim0", 8);
        let (mut rx, tx) = bus.open().unwrap();
        rx.set_filters(&[]).unwrap();
        let mut detail = [0; 8];
        detail[1] = crate::frame::ctrl::TX_PASSIVE;
        let err = CanFrame::new_error(err_class::BUS_OFF | err_class::CONTROLLER, detail).unwrap();
        bus.inject_error(err.as_error().unwrap());
        match rx.recv().await.unwrap() {
            BusEvent::Error { error, .. } => assert_eq!(error.severity(), ErrorSeverity::BusOff),
            other => panic!("{other:?}"),
        }
        assert!(matches!(tx.send(&err).await, Err(BusError::Unsendable)));
        assert!(!BusError::Unsendable.is_transient());
    }

    #[tokio::test(start_paused = true)]
    async fn link_down_and_gone_are_typed_and_recoverable() {
        let bus = InProcessBus::new("sim0", 8);
        let (mut rx, tx) = bus.open().unwrap();
        let (_, other_tx) = bus.open().unwrap();
        let waiter = tokio::spawn(async move {
            let r = rx.recv().await;
            (rx, r)
        });
        tokio::time::advance(Duration::from_millis(5)).await;
        bus.set_link(LinkState::Down);
        let (mut rx, r) = waiter.await.unwrap();
        assert!(matches!(r, Err(BusError::InterfaceDown { ref iface }) if iface == "sim0"));
        assert!(matches!(
            tx.send(&data(1, &[])).await,
            Err(BusError::InterfaceDown { .. })
        ));
        assert!(matches!(bus.open(), Err(BusError::InterfaceDown { .. })));
        bus.set_link(LinkState::Gone);
        let e = bus.open().unwrap_err();
        assert!(matches!(e, BusError::NoSuchInterface { .. }) && e.is_transient());
        assert!(matches!(
            rx.recv().await,
            Err(BusError::NoSuchInterface { .. })
        ));
        bus.set_link(LinkState::Up);
        let (mut fresh, _) = bus.open().unwrap();
        other_tx.send(&data(7, &[7])).await.unwrap();
        assert_eq!(next_frame(&mut fresh).await.frame, data(7, &[7]));
        // The old endpoint also resumes once the link is back.
        assert_eq!(next_frame(&mut rx).await.frame, data(7, &[7]));
    }

    #[tokio::test(start_paused = true)]
    async fn receivers_see_the_bus_close() {
        let bus = InProcessBus::new("sim0", 8);
        let (mut rx, _) = bus.open().unwrap();
        let (_, tx) = bus.open().unwrap();
        tx.send(&data(1, &[1])).await.unwrap();
        drop((bus, tx));
        // Queued frames are still delivered, then the end is reported.
        assert_eq!(next_frame(&mut rx).await.frame, data(1, &[1]));
        let closed = rx.recv().await.unwrap_err();
        assert!(matches!(closed, BusError::Closed) && !closed.is_transient());
    }

    #[tokio::test(start_paused = true)]
    async fn recv_is_cancel_safe() {
        let bus = InProcessBus::new("sim0", 8);
        let (mut rx, _) = bus.open().unwrap();
        let (_, tx) = bus.open().unwrap();
        for _ in 0..3 {
            let r = tokio::time::timeout(Duration::from_millis(1), rx.recv()).await;
            assert!(r.is_err());
        }
        tx.send(&data(3, &[3])).await.unwrap();
        assert_eq!(next_frame(&mut rx).await.frame, data(3, &[3]));
    }

    #[test]
    fn os_errors_map_to_typed_variants() {
        let e = BusError::from_io("can0", io::Error::from_raw_os_error(libc::ENETDOWN));
        assert!(matches!(e, BusError::InterfaceDown { .. }));
        let e = BusError::from_io("can0", io::Error::from_raw_os_error(libc::ENODEV));
        assert!(matches!(e, BusError::NoSuchInterface { .. }));
        let e = BusError::from_io("can0", io::Error::from_raw_os_error(libc::ENXIO));
        assert!(matches!(e, BusError::NoSuchInterface { .. }));
        let e = BusError::from_io("can0", io::Error::from_raw_os_error(libc::ENOBUFS));
        assert!(matches!(e, BusError::TxQueueFull { .. }) && e.is_transient());
        let e = BusError::from_io("can0", io::Error::from_raw_os_error(13));
        assert!(matches!(e, BusError::Io { .. }));
        assert_eq!(
            io::Error::from_raw_os_error(libc::ENETDOWN).kind(),
            io::ErrorKind::NetworkDown
        );
    }

    #[test]
    fn the_drop_counter_is_read_from_its_meminfo_slot() {
        let mut buf = [0u8; MEMINFO_LEN];
        buf[32..36].copy_from_slice(&4_000_000_123u32.to_ne_bytes());
        buf[0..4].copy_from_slice(&7u32.to_ne_bytes());
        assert_eq!(drops_from_meminfo(&buf, MEMINFO_LEN), Some(4_000_000_123));
        // An older kernel answers fewer counters: no drop count, not a wrong one.
        assert_eq!(drops_from_meminfo(&buf, 32), None);
        assert_eq!(drops_from_meminfo(&buf[..20], 36), None);
    }

    #[test]
    fn opening_a_missing_socketcan_interface_is_typed() {
        // On the CAN-less host creating the socket fails (EAFNOSUPPORT) and
        // on a CAN kernel the lookup does (ENODEV); neither may panic.
        let r = open_socketcan("canodom-none0", &[IdFilter::accept_all()]);
        assert!(r.is_err());
    }
}
