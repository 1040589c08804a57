//! The I/O shell: a gpsd client on a thread of its own.
//!
//! `std::net::TcpStream` with a read timeout (like `ros2/` runs RustDDS on its
//! own thread): the async CAN pipeline never waits on gpsd. Accepted fixes and
//! status changes go into a bounded queue; when the consumer falls behind the
//! oldest event is dropped and counted, so a stalled consumer costs old fixes,
//! never a blocked thread. An unreachable gpsd is logged and retried with
//! [`Backoff`], never a failure.

use crate::Error;
use crate::accept::{Acceptance, Fix};
use crate::backoff::Backoff;
use crate::protocol::{self, Message, WATCH_COMMAND};
use crate::status::{RateWindow, SourceStatus};
use std::collections::VecDeque;
use std::io::{BufRead, BufReader, ErrorKind, Write};
use std::net::{TcpStream, ToSocketAddrs};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// The default gpsd address.
pub const DEFAULT_ADDRESS: &str = "localhost:2947";
/// The default limit on gpsd's 95 % error estimate, metres: a consumer
/// receiver shows 3–8 m in the open; beyond 25 m (urban canyon, a cold start)
/// a fix says little about a car's metre-scale calibration.
pub const DEFAULT_MAX_ERROR_M: f64 = 25.0;

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

struct Shared {
    queue: Mutex<(VecDeque<Event>, u64)>,
    ready: Condvar,
    stop: AtomicBool,
}

impl Shared {
    /// Queues `event`, dropping the oldest when full; returns the drop count.
    fn push(&self, event: Event, cap: usize) -> u64 {
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
}

/// A running gpsd client; dropping it stops the thread.
pub struct GpsdClient {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
    epoch: Instant,
}

impl GpsdClient {
    /// Starts the client thread. Receipt times are seconds since `epoch` (the
    /// caller's clock, so they can be placed on the CAN frames' time base).
    ///
    /// # Errors
    /// [`Error::Io`] only when the thread cannot be spawned; gpsd being down is not an error.
    pub fn spawn(config: GpsdClientConfig, epoch: Instant) -> Result<Self, Error> {
        let shared = Arc::new(Shared {
            queue: Mutex::new((VecDeque::new(), 0)),
            ready: Condvar::new(),
            stop: AtomicBool::new(false),
        });
        let thread_shared = Arc::clone(&shared);
        let address = config.address.clone();
        let thread = std::thread::Builder::new()
            .name("gpsd".into())
            .spawn(move || run(&config, &thread_shared, epoch))
            .map_err(|source| Error::Io { address, source })?;
        Ok(Self {
            shared,
            thread: Some(thread),
            epoch,
        })
    }

    /// The clock receipt times are measured on.
    pub fn epoch(&self) -> Instant {
        self.epoch
    }

    /// The next event, waiting up to `timeout`.
    pub fn recv_timeout(&self, timeout: Duration) -> Option<Event> {
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
    pub fn drain(&self) -> Vec<Event> {
        let mut q = self
            .shared
            .queue
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        q.0.drain(..).collect()
    }
}

impl Drop for GpsdClient {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            // The thread checks `stop` at least every read timeout (200 ms).
            let _ = t.join();
        }
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

fn sleep_unless_stopped(shared: &Shared, total: Duration) {
    let until = Instant::now() + total;
    while !shared.stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        if now >= until {
            return;
        }
        std::thread::sleep((until - now).min(Duration::from_millis(100)));
    }
}

fn run(config: &GpsdClientConfig, shared: &Shared, epoch: Instant) {
    let mut backoff = config.backoff.clone();
    let mut acceptance = Acceptance::new(config.max_error_m);
    let mut rate = RateWindow::default();
    let mut status = SourceStatus::default();
    let mut attempts = 0u64;
    while !shared.stop.load(Ordering::Relaxed) {
        if attempts > 0 {
            status.reconnects += 1;
            let delay = backoff.next_delay();
            tracing::info!(address = %config.address, delay_s = delay.as_secs_f64(), reconnects = status.reconnects, "gpsd: reconnecting");
            sleep_unless_stopped(shared, delay);
            if shared.stop.load(Ordering::Relaxed) {
                break;
            }
        }
        attempts += 1;
        let outcome = session(
            config,
            shared,
            epoch,
            &mut acceptance,
            &mut rate,
            &mut status,
            &mut backoff,
        );
        status.connected = false;
        status.fixes_per_s = 0.0;
        if let Err(e) = outcome {
            tracing::warn!(address = %config.address, error = %e, "gpsd: connection lost or refused");
            status.last_error = Some(e.to_string());
        }
        status.dropped = shared.push(Event::Status(status.clone()), config.queue_len);
    }
}

/// One connection: `?WATCH`, then reports until it fails or the client stops.
fn session(
    config: &GpsdClientConfig,
    shared: &Shared,
    epoch: Instant,
    acceptance: &mut Acceptance,
    rate: &mut RateWindow,
    status: &mut SourceStatus,
    backoff: &mut Backoff,
) -> Result<(), Error> {
    let io = |source| Error::Io {
        address: config.address.clone(),
        source,
    };
    let mut stream = connect(&config.address).map_err(io)?;
    stream.set_read_timeout(Some(READ_TIMEOUT)).map_err(io)?;
    stream.write_all(WATCH_COMMAND.as_bytes()).map_err(io)?;
    status.connected = true;
    tracing::info!(address = %config.address, "gpsd: connected");
    status.dropped = shared.push(Event::Status(status.clone()), config.queue_len);
    let mut reader = BufReader::new(stream);
    let mut line = String::new();
    let mut last_status = Instant::now();
    let mut malformed_logged: Option<Instant> = None;
    while !shared.stop.load(Ordering::Relaxed) {
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
                        backoff.reset();
                        status.last_error_m = Acceptance::error_estimate_m(&tpv);
                        if let Ok(fix) = acceptance.judge(&tpv, now_s) {
                            rate.push(now_s);
                            status.dropped = shared.push(Event::Fix(fix), config.queue_len);
                        }
                        status.accepted = acceptance.accepted;
                        status.refused = acceptance.refused;
                    }
                    Ok(Message::Version { release }) => tracing::info!(release, "gpsd: version"),
                    Ok(_) => {}
                    // One bad line is not a reason to drop the connection; logged at most every 10 s.
                    Err(e) => {
                        if malformed_logged.is_none_or(|t| t.elapsed() > Duration::from_secs(10)) {
                            tracing::warn!(error = %e, "gpsd: line ignored");
                            malformed_logged = Some(Instant::now());
                        }
                        status.last_error = Some(e.to_string());
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
            status.fixes_per_s = rate.rate(epoch.elapsed().as_secs_f64());
            status.dropped = shared.push(Event::Status(status.clone()), config.queue_len);
            last_status = Instant::now();
        }
    }
    Ok(())
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
        let shared = Shared {
            queue: Mutex::new((VecDeque::new(), 0)),
            ready: Condvar::new(),
            stop: AtomicBool::new(false),
        };
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
