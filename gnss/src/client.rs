//! The I/O shell: a gpsd client on a thread of its own.
//!
//! `std::net::TcpStream` with a read timeout (like `ros2/` runs RustDDS on its
//! own thread): the async CAN pipeline never waits on gpsd. Accepted fixes and
//! status changes go into a bounded queue; when the consumer falls behind the
//! oldest event is dropped and counted, so a stalled consumer costs old fixes,
//! never a blocked thread. An unreachable gpsd is logged and retried with
//! [`Backoff`], never a failure.

use crate::Error;
use crate::accept::{Fix, Judge, Refusal};
use crate::backoff::Backoff;
use crate::protocol::{self, Message, WATCH_COMMAND};
use crate::status::SourceStatus;
use std::collections::VecDeque;
use std::io::{BufRead, BufReader, ErrorKind, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// The default gpsd address.
pub const DEFAULT_ADDRESS: &str = "localhost:2947";
/// The default limit on gpsd's 95 % error estimate, metres.
///
/// For a receiver that speaks NMEA only, gpsd has no error estimate of the
/// receiver's own and derives `eph = HDOP × 19 m` (gpsd 3.22's UERE without
/// DGPS), with no `epx`/`epy`. Measured under gpsfake (`tests/gpsfake.sh`):
/// NMEA of HDOP 3.0, as `sim/multibody/fixes.py` writes for fixes of
/// σ 1.5 m, arrives as `eph` 57 m; the former 25 m refused every such fix
/// (it passes HDOP ≤ 1.3 only). 120 m passes HDOP ≤ 6.3, ordinary fixes of
/// a consumer receiver (σ 1–3 m on that scale), and refuses poor geometry
/// (HDOP 10–20 in an urban canyon: `eph` 190–380 m). A receiver reporting its
/// own estimate (GST, u-blox binary: `epx`/`epy` of a few metres) is hardly
/// limited by it; configure a lower limit for one. The daemon's `[gnss]
/// max_error_m` default is the same value (a test of the daemon checks).
pub const DEFAULT_MAX_ERROR_M: f64 = 120.0;

/// What the client needs to run.
#[derive(Debug, Clone)]
pub struct GpsdClientConfig {
    /// gpsd's `host:port`.
    pub address: String,
    /// Largest accepted 95 % error estimate, metres.
    pub max_error_m: f64,
    /// Events kept for a slow consumer before the oldest is dropped.
    pub queue_len: usize,
    /// The reconnect schedule.
    pub backoff: Backoff,
}

impl GpsdClientConfig {
    /// A configuration with the defaults, checked.
    ///
    /// # Errors
    /// [`Error::Config`] naming the key when `max_error_m` is not positive and finite
    /// or the address is empty.
    pub fn new(address: &str, max_error_m: f64) -> Result<Self, Error> {
        if address.trim().is_empty() {
            return Err(Error::Config {
                key: "address",
                reason: "is empty".into(),
            });
        }
        if !(max_error_m.is_finite() && max_error_m > 0.0) {
            return Err(Error::Config {
                key: "max_error_m",
                reason: format!("must be a positive number of metres, got {max_error_m}"),
            });
        }
        Ok(Self {
            address: address.to_owned(),
            max_error_m,
            queue_len: 256,
            backoff: Backoff::default(),
        })
    }
}

/// What the client delivers.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// An accepted fix.
    Fix(Fix),
    /// The status after a connection change (also sent once a second while connected).
    Status(SourceStatus),
}

/// The queue between a source's thread and its consumer, and the stop flag.
pub(crate) struct Shared {
    queue: Mutex<(VecDeque<Event>, u64)>,
    ready: Condvar,
    stop: AtomicBool,
}

impl Shared {
    fn new() -> Self {
        Self {
            queue: Mutex::new((VecDeque::new(), 0)),
            ready: Condvar::new(),
            stop: AtomicBool::new(false),
        }
    }

    /// Queues `event`, dropping the oldest when full; returns the drop count.
    pub(crate) fn push(&self, event: Event, cap: usize) -> u64 {
        let mut q = self.queue.lock().unwrap_or_else(PoisonError::into_inner);
        if q.0.len() >= cap.max(1) {
            q.0.pop_front();
            q.1 += 1;
        }
        q.0.push_back(event);
        let dropped = q.1;
        drop(q);
        self.ready.notify_one();
        dropped
    }

    /// Whether the consumer asked the thread to stop.
    pub(crate) fn stopped(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }
}

/// A source's thread and its queue: what [`GpsdClient`] and
/// [`crate::serial::NmeaDevice`] share.
pub(crate) struct Worker {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl Worker {
    /// Starts `run` on a thread named `name`.
    pub(crate) fn spawn(
        name: &str,
        run: impl FnOnce(&Shared) + Send + 'static,
    ) -> std::io::Result<Self> {
        let shared = Arc::new(Shared::new());
        let thread_shared = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || run(&thread_shared))?;
        Ok(Self {
            shared,
            thread: Some(thread),
        })
    }

    /// The next event, waiting up to `timeout`.
    pub(crate) fn recv_timeout(&self, timeout: Duration) -> Option<Event> {
        let q = self
            .shared
            .queue
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let (mut q, _) = self
            .shared
            .ready
            .wait_timeout_while(q, timeout, |q| q.0.is_empty())
            .unwrap_or_else(PoisonError::into_inner);
        q.0.pop_front()
    }

    /// Every queued event, without waiting.
    pub(crate) fn drain(&self) -> Vec<Event> {
        let mut q = self
            .shared
            .queue
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        q.0.drain(..).collect()
    }

    /// Stops the thread (it looks at the flag at least every read timeout,
    /// 200 ms) and waits for it.
    pub(crate) fn halt(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        self.halt();
    }
}

/// A running gpsd client; dropping it stops the thread.
pub struct GpsdClient {
    worker: Worker,
    epoch: Instant,
}

impl GpsdClient {
    /// Starts the client thread. Receipt times are seconds since `epoch` (the
    /// caller's clock, so they can be placed on the CAN frames' time base).
    ///
    /// # Errors
    /// [`Error::Io`] only when the thread cannot be spawned; gpsd being down is not an error.
    pub fn spawn(config: GpsdClientConfig, epoch: Instant) -> Result<Self, Error> {
        let address = config.address.clone();
        let worker = Worker::spawn("gpsd", move |shared| run(&config, shared, epoch))
            .map_err(|source| Error::Io { address, source })?;
        Ok(Self { worker, epoch })
    }

    /// The clock receipt times are measured on.
    pub fn epoch(&self) -> Instant {
        self.epoch
    }

    /// The next event, waiting up to `timeout`.
    pub fn recv_timeout(&self, timeout: Duration) -> Option<Event> {
        self.worker.recv_timeout(timeout)
    }

    /// Every queued event, without waiting.
    pub fn drain(&self) -> Vec<Event> {
        self.worker.drain()
    }

    /// Stops the thread and returns what it still queued: the last fixes
    /// and its final status (whose counts then cover every fix it sent).
    pub fn finish(&mut self) -> Vec<Event> {
        self.worker.halt();
        self.worker.drain()
    }
}

const READ_TIMEOUT: Duration = Duration::from_millis(200);

fn connect(address: &str) -> std::io::Result<TcpStream> {
    let mut last = std::io::Error::new(ErrorKind::NotFound, "no address");
    for addr in address.to_socket_addrs()? {
        match TcpStream::connect_timeout(&addr, Duration::from_secs(2)) {
            Ok(s) => return Ok(s),
            Err(e) => last = e,
        }
    }
    Err(last)
}

/// Sleeps `total`, waking early when the consumer asks the thread to stop.
pub(crate) fn sleep_unless_stopped(shared: &Shared, total: Duration) {
    let until = Instant::now() + total;
    while !shared.stopped() {
        let now = Instant::now();
        if now >= until {
            return;
        }
        std::thread::sleep((until - now).min(Duration::from_millis(100)));
    }
}

fn run(config: &GpsdClientConfig, shared: &Shared, epoch: Instant) {
    let mut backoff = config.backoff.clone();
    let mut judge = Judge::new(config.max_error_m);
    let mut status = SourceStatus::default();
    let mut attempts = 0u64;
    // Set once a loss (or the first failed attempt) and the reconnect after it
    // are logged: later failed attempts go to debug, so a gpsd that stays down
    // writes two lines, not one per attempt. Cleared by a connection.
    let mut quiet = false;
    while !shared.stopped() {
        if attempts > 0 {
            status.reconnects += 1;
            let delay = backoff.next_delay();
            if quiet {
                tracing::debug!(address = %config.address, delay_s = delay.as_secs_f64(), reconnects = status.reconnects, "gpsd: reconnecting");
            } else {
                tracing::info!(address = %config.address, delay_s = delay.as_secs_f64(), reconnects = status.reconnects,
                    "gpsd: reconnecting in {:.1} s (then backing off to {:.0} s)", delay.as_secs_f64(), config.backoff.max().as_secs_f64());
                quiet = true;
            }
            sleep_unless_stopped(shared, delay);
            if shared.stopped() {
                break;
            }
        }
        attempts += 1;
        let outcome = session(
            config,
            shared,
            epoch,
            &mut Session {
                judge: &mut judge,
                status: &mut status,
                backoff: &mut backoff,
            },
        );
        if std::mem::replace(&mut status.connected, false) {
            quiet = false;
        }
        status.fixes_per_s = 0.0;
        if let Err(e) = outcome {
            if quiet {
                tracing::debug!(address = %config.address, error = %e, "gpsd: still unreachable");
            } else {
                tracing::warn!(address = %config.address, error = %e, "gpsd: connection lost or refused");
            }
            status.last_error = Some(e.to_string());
        }
        status.dropped = shared.push(Event::Status(status.clone()), config.queue_len);
    }
}

/// What one connection updates, kept across connections.
struct Session<'a> {
    judge: &'a mut Judge,
    status: &'a mut SourceStatus,
    backoff: &'a mut Backoff,
}

/// One connection: `?WATCH`, then reports until it fails or the client stops.
fn session(
    config: &GpsdClientConfig,
    shared: &Shared,
    epoch: Instant,
    st: &mut Session<'_>,
) -> Result<(), Error> {
    let io = |source| Error::Io {
        address: config.address.clone(),
        source,
    };
    let mut stream = connect(&config.address).map_err(io)?;
    stream.set_read_timeout(Some(READ_TIMEOUT)).map_err(io)?;
    stream.write_all(WATCH_COMMAND.as_bytes()).map_err(io)?;
    st.status.connected = true;
    tracing::info!(address = %config.address, "gpsd: connected");
    st.status.dropped = shared.push(Event::Status(st.status.clone()), config.queue_len);
    let mut reader = BufReader::new(stream);
    let mut line = String::new();
    let mut last_status = Instant::now();
    let mut malformed_logged: Option<Instant> = None;
    while !shared.stopped() {
        match reader.read_line(&mut line) {
            Ok(0) => {
                return Err(io(std::io::Error::new(
                    ErrorKind::UnexpectedEof,
                    "gpsd closed the connection",
                )));
            }
            Ok(_) if line.ends_with('\n') => {
                let now_s = epoch.elapsed().as_secs_f64();
                match protocol::parse_line(&line) {
                    Ok(Message::Tpv(tpv)) => {
                        st.backoff.reset();
                        let (verdict, changed) = st.judge.judge(&tpv, now_s, st.status);
                        if changed {
                            let estimate = st.status.last_error_m;
                            log_outcome("gpsd", verdict.err(), estimate, config.max_error_m);
                        }
                        if let Ok(fix) = verdict {
                            st.status.dropped = shared.push(Event::Fix(fix), config.queue_len);
                        }
                    }
                    Ok(Message::Version { release }) => tracing::info!(release, "gpsd: version"),
                    Ok(_) => {}
                    // One bad line is not a reason to drop the connection; logged at most every 10 s.
                    Err(e) => {
                        if malformed_logged.is_none_or(|t| t.elapsed() > Duration::from_secs(10)) {
                            tracing::warn!(error = %e, "gpsd: line ignored");
                            malformed_logged = Some(Instant::now());
                        }
                        st.status.last_error = Some(e.to_string());
                    }
                }
                line.clear();
            }
            // A partial line before a timeout stays in `line` and is completed by the next read.
            Ok(_) => {}
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
            Err(e) => return Err(io(e)),
        }
        if last_status.elapsed() >= Duration::from_secs(1) {
            st.status.fixes_per_s = st.judge.rate.rate(epoch.elapsed().as_secs_f64());
            st.status.dropped = shared.push(Event::Status(st.status.clone()), config.queue_len);
            last_status = Instant::now();
        }
    }
    Ok(())
}

/// The log line of a change in what becomes of a source's reports (not
/// one per fix); `source` names it (`gpsd`, `GNSS receiver`).
pub(crate) fn log_outcome(
    source: &str,
    refusal: Option<Refusal>,
    estimate_m: Option<f64>,
    max_error_m: f64,
) {
    match refusal {
        None => tracing::info!(error_estimate_m = ?estimate_m, "{source}: fixes accepted"),
        Some(Refusal::ErrorTooLarge) => tracing::warn!(
            reason = Refusal::ErrorTooLarge.name(),
            error_estimate_m = ?estimate_m,
            max_error_m,
            "{source}: fixes refused: the 95 % error estimate exceeds max_error_m"
        ),
        Some(r) => tracing::warn!(reason = r.name(), "{source}: fixes refused: {}", r.name()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_errors_name_the_key() {
        let e = GpsdClientConfig::new("localhost:2947", -1.0).expect_err("negative");
        assert!(e.to_string().contains("max_error_m"), "{e}");
        let e = GpsdClientConfig::new(" ", 10.0).expect_err("empty");
        assert!(e.to_string().contains("address"), "{e}");
    }

    #[test]
    fn a_full_queue_drops_the_oldest_and_counts() {
        let shared = Shared::new();
        for i in 0..5 {
            shared.push(
                Event::Status(SourceStatus {
                    reconnects: i,
                    ..SourceStatus::default()
                }),
                3,
            );
        }
        let q = shared.queue.lock().expect("lock");
        assert_eq!(q.1, 2);
        assert_eq!(
            q.0.front(),
            Some(&Event::Status(SourceStatus {
                reconnects: 2,
                ..SourceStatus::default()
            }))
        );
    }
}
