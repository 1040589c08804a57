//! The I/O shell of a receiver on a serial port: NMEA 0183 read on a thread
//! of its own, without gpsd.
//!
//! A USB receiver (u-blox, most others) appears as `/dev/ttyACM0` or
//! `/dev/ttyUSB0` and writes NMEA sentences. The device is opened raw (no
//! echo, no line editing: `cfmakeraw`) at the configured baud rate (a USB
//! CDC-ACM receiver ignores it; a UART receiver needs its own, often 9600
//! or 38400); a path that is not a terminal (a named pipe, for tests and
//! bridges) is read as it is. Sentences are gathered into epochs by
//! [`EpochAssembler`] and judged by the same [`Acceptance`] as gpsd's
//! reports, then queued as the gpsd client's are (drop-oldest, counted).
//! A device that disappears (unplugged, the pipe's writer gone) is reopened
//! with [`Backoff`]; the log says so once, not per attempt.

use crate::Error;
use crate::accept::Judge;
use crate::backoff::Backoff;
use crate::client::{Event, Shared, Worker, log_outcome, sleep_unless_stopped};
use crate::nmea::EpochAssembler;
use crate::status::SourceStatus;
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::sys::termios::{self, BaudRate, ControlFlags, SetArg};
use std::fs::{File, OpenOptions};
use std::io::{ErrorKind, Read as _};
use std::os::fd::AsFd as _;
use std::os::unix::fs::OpenOptionsExt as _;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// The default limit on an epoch's 95 % error estimate, metres, for a
/// receiver read directly: 2.448 × [`crate::nmea::HDOP_UERE_M`] × 6.3 ≈ 32 m,
/// so that, like gpsd's default ([`crate::client::DEFAULT_MAX_ERROR_M`],
/// 120 m on gpsd's `eph = HDOP × 19 m`), fixes of HDOP ≤ 6.3 pass and poor
/// geometry (HDOP 10–20 in an urban canyon) is refused. A receiver stating
/// its own error in GST sentences is judged on that instead.
pub const DEFAULT_MAX_ERROR_M: f64 = 32.0;

/// How long the line must be quiet before a gathered epoch is complete:
/// a receiver sends an epoch's sentences back to back (at 9600 baud eight
/// sentences take about 0.6 s, without pauses between them), then is silent
/// until the next epoch (1–10 Hz). An epoch is also complete as soon as a
/// sentence of the next one arrives, so a 10 Hz receiver loses nothing here.
pub const QUIET: Duration = Duration::from_millis(200);

/// The baud rates a serial receiver is set to (termios's standard rates
/// from 4800 up).
pub const BAUD_RATES: [u32; 9] = [
    4800, 9600, 19_200, 38_400, 57_600, 115_200, 230_400, 460_800, 921_600,
];

fn baud_rate(baud: u32) -> Option<BaudRate> {
    Some(match baud {
        4800 => BaudRate::B4800,
        9600 => BaudRate::B9600,
        19_200 => BaudRate::B19200,
        38_400 => BaudRate::B38400,
        57_600 => BaudRate::B57600,
        115_200 => BaudRate::B115200,
        230_400 => BaudRate::B230400,
        460_800 => BaudRate::B460800,
        921_600 => BaudRate::B921600,
        _ => return None,
    })
}

/// What the reader needs to run.
#[derive(Debug, Clone)]
pub struct NmeaDeviceConfig {
    /// The device, e.g. `/dev/ttyACM0` (a named pipe is read too).
    pub path: PathBuf,
    /// The baud rate to set on a terminal; `None` leaves the device's.
    pub baud: Option<u32>,
    /// Largest accepted 95 % error estimate, metres.
    pub max_error_m: f64,
    /// Events kept for a slow consumer before the oldest is dropped.
    pub queue_len: usize,
    /// The reopen schedule.
    pub backoff: Backoff,
}

impl NmeaDeviceConfig {
    /// A configuration with the defaults, checked.
    ///
    /// # Errors
    /// [`Error::Config`] naming the key: an empty path, a baud rate not in
    /// [`BAUD_RATES`], a `max_error_m` not positive and finite.
    pub fn new(path: &Path, baud: Option<u32>, max_error_m: f64) -> Result<Self, Error> {
        if path.as_os_str().is_empty() {
            return Err(Error::Config {
                key: "device",
                reason: "is empty".into(),
            });
        }
        if let Some(b) = baud.filter(|b| baud_rate(*b).is_none()) {
            return Err(Error::Config {
                key: "baud",
                reason: format!("{b} is not one of {BAUD_RATES:?}"),
            });
        }
        if !(max_error_m.is_finite() && max_error_m > 0.0) {
            return Err(Error::Config {
                key: "max_error_m",
                reason: format!("must be a positive number of metres, got {max_error_m}"),
            });
        }
        Ok(Self {
            path: path.to_owned(),
            baud,
            max_error_m,
            queue_len: 256,
            backoff: Backoff::default(),
        })
    }
}

/// A receiver being read; dropping it stops the thread.
pub struct NmeaDevice {
    worker: Worker,
    epoch: Instant,
}

impl NmeaDevice {
    /// Starts the reader thread. Receipt times are seconds since `epoch`
    /// (the caller's clock).
    ///
    /// # Errors
    /// [`Error::Device`] only when the thread cannot be spawned; a device
    /// that is missing is retried, not an error.
    pub fn spawn(config: NmeaDeviceConfig, epoch: Instant) -> Result<Self, Error> {
        let path = config.path.display().to_string();
        let worker = Worker::spawn("gnss-serial", move |shared| run(&config, shared, epoch))
            .map_err(|source| Error::Device { path, source })?;
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

    /// Stops the thread and returns what it still queued (its last fixes
    /// and final status).
    pub fn finish(&mut self) -> Vec<Event> {
        self.worker.halt();
        self.worker.drain()
    }
}

/// Opens the device raw at `baud` (a terminal), or as it is (a named pipe).
fn open(path: &Path, baud: Option<u32>) -> std::io::Result<File> {
    let meta = std::fs::metadata(path)?;
    if meta.file_type().is_file() {
        // Read to its end it would be "lost" and read again from the start.
        return Err(std::io::Error::new(
            ErrorKind::InvalidInput,
            "a regular file, not a receiver (replay a log with `canodom replay --fixes`)",
        ));
    }
    let file = OpenOptions::new()
        .read(true)
        .custom_flags(libc_flags())
        .open(path)?;
    match termios::tcgetattr(file.as_fd()) {
        Ok(mut t) => {
            termios::cfmakeraw(&mut t);
            t.control_flags |= ControlFlags::CLOCAL | ControlFlags::CREAD;
            if let Some(rate) = baud.and_then(baud_rate) {
                termios::cfsetspeed(&mut t, rate)?;
            }
            termios::tcsetattr(file.as_fd(), SetArg::TCSANOW, &t)?;
        }
        // A named pipe: no line settings to make.
        Err(nix::errno::Errno::ENOTTY) => {}
        Err(e) => return Err(e.into()),
    }
    Ok(file)
}

/// Non-blocking (the thread polls), and never the controlling terminal.
fn libc_flags() -> i32 {
    nix::fcntl::OFlag::O_NONBLOCK.bits() | nix::fcntl::OFlag::O_NOCTTY.bits()
}

fn utc_now_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

fn run(config: &NmeaDeviceConfig, shared: &Shared, epoch: Instant) {
    let path = config.path.display().to_string();
    let mut st = Reading {
        judge: Judge::new(config.max_error_m),
        status: SourceStatus::default(),
        assembler: EpochAssembler::default(),
        malformed_logged: None,
        line: Vec::with_capacity(MAX_LINE),
        backoff: config.backoff.clone(),
    };
    let mut attempts = 0u64;
    // As the gpsd client: a loss and the first retry are logged, later
    // failed attempts go to debug until the device is back.
    let mut quiet = false;
    while !shared.stopped() {
        if attempts > 0 {
            st.status.reconnects += 1;
            let delay = st.backoff.next_delay();
            if quiet {
                tracing::debug!(device = %path, delay_s = delay.as_secs_f64(), "GNSS receiver: reopening");
            } else {
                tracing::info!(device = %path, delay_s = delay.as_secs_f64(),
                    "GNSS receiver: reopening in {:.1} s (then backing off to {:.0} s)",
                    delay.as_secs_f64(), config.backoff.max().as_secs_f64());
                quiet = true;
            }
            sleep_unless_stopped(shared, delay);
            if shared.stopped() {
                break;
            }
        }
        attempts += 1;
        let outcome = match open(&config.path, config.baud) {
            Ok(file) => {
                st.status.connected = true;
                tracing::info!(device = %path, baud = ?config.baud, "GNSS receiver: opened");
                st.status.dropped = shared.push(Event::Status(st.status.clone()), config.queue_len);
                read_until_lost(file, config, shared, epoch, &mut st)
            }
            Err(e) => Err(e),
        };
        // What the last epoch gathered before the loss still counts.
        if let Some(e) = st.assembler.flush() {
            st.judge(&e.tpv, e.receipt_s, config, shared);
        }
        if std::mem::replace(&mut st.status.connected, false) {
            quiet = false;
        }
        st.status.fixes_per_s = 0.0;
        if let Err(e) = outcome {
            if quiet {
                tracing::debug!(device = %path, error = %e, "GNSS receiver: still missing");
            } else {
                tracing::warn!(device = %path, error = %e, "GNSS receiver: lost or cannot be opened");
            }
            st.status.last_error = Some(e.to_string());
        }
        st.status.dropped = shared.push(Event::Status(st.status.clone()), config.queue_len);
    }
}

/// What the reader keeps across reopenings.
struct Reading {
    judge: Judge,
    status: SourceStatus,
    assembler: EpochAssembler,
    /// When a damaged sentence was last logged.
    malformed_logged: Option<Instant>,
    /// The line being received (up to [`MAX_LINE`] bytes).
    line: Vec<u8>,
    /// The reopen schedule, reset by each complete epoch.
    backoff: Backoff,
}

impl Reading {
    /// Judges one epoch and queues it when accepted.
    fn judge(
        &mut self,
        tpv: &crate::Tpv,
        receipt_s: f64,
        config: &NmeaDeviceConfig,
        shared: &Shared,
    ) {
        let (verdict, changed) = self.judge.judge(tpv, receipt_s, &mut self.status);
        if changed {
            let estimate = self.status.last_error_m;
            log_outcome("GNSS receiver", verdict.err(), estimate, config.max_error_m);
        }
        if let Ok(fix) = verdict {
            self.status.dropped = shared.push(Event::Fix(fix), config.queue_len);
        }
    }
}

/// Longest line kept: an NMEA sentence is at most 82 characters; a longer
/// run without a newline is noise (a wrong baud rate) and is dropped.
const MAX_LINE: usize = 256;

/// Reads sentences until the device is lost or the thread is stopped.
fn read_until_lost(
    mut file: File,
    config: &NmeaDeviceConfig,
    shared: &Shared,
    epoch: Instant,
    st: &mut Reading,
) -> std::io::Result<()> {
    // A partial line from before a loss is not part of this device's stream.
    st.line.clear();
    let mut last_status = Instant::now();
    let quiet_ms = u16::try_from(QUIET.as_millis()).unwrap_or(u16::MAX);
    while !shared.stopped() {
        let ready = {
            let mut fds = [PollFd::new(file.as_fd(), PollFlags::POLLIN)];
            match poll(&mut fds, PollTimeout::from(quiet_ms)) {
                Ok(n) => n > 0,
                Err(nix::errno::Errno::EINTR) => false,
                Err(e) => return Err(e.into()),
            }
        };
        if ready {
            read_available(&mut file, config, shared, epoch, st)?;
        } else if let Some(e) = st.assembler.flush() {
            // The line fell quiet: the epoch gathered is complete.
            st.judge(&e.tpv, e.receipt_s, config, shared);
        }
        if last_status.elapsed() >= Duration::from_secs(1) {
            st.status.fixes_per_s = st.judge.rate.rate(epoch.elapsed().as_secs_f64());
            st.status.dropped = shared.push(Event::Status(st.status.clone()), config.queue_len);
            last_status = Instant::now();
        }
    }
    Ok(())
}

/// Reads what the device has and feeds each complete line to the epochs.
fn read_available(
    file: &mut File,
    config: &NmeaDeviceConfig,
    shared: &Shared,
    epoch: Instant,
    st: &mut Reading,
) -> std::io::Result<()> {
    let mut buf = [0_u8; 1024];
    let n = match file.read(&mut buf) {
        Ok(0) => {
            return Err(std::io::Error::new(
                ErrorKind::UnexpectedEof,
                "the device closed (unplugged, or the pipe's writer left)",
            ));
        }
        Ok(n) => n,
        Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::Interrupted) => 0,
        Err(e) => return Err(e),
    };
    let receipt_s = epoch.elapsed().as_secs_f64();
    let utc = utc_now_s();
    for &b in &buf[..n] {
        if b != b'\n' {
            if st.line.len() < MAX_LINE {
                st.line.push(b);
            }
            continue;
        }
        let line = std::mem::take(&mut st.line);
        let text = String::from_utf8_lossy(&line);
        let text = text.trim();
        if !text.is_empty() {
            match st.assembler.push(text, receipt_s, utc) {
                Ok(Some(e)) => {
                    st.backoff.reset();
                    st.judge(&e.tpv, e.receipt_s, config, shared);
                }
                Ok(None) => {}
                // A damaged sentence is not a reason to reopen; logged at most every 10 s.
                Err(e) => {
                    if st
                        .malformed_logged
                        .is_none_or(|t| t.elapsed() > Duration::from_secs(10))
                    {
                        tracing::warn!(device = %config.path.display(), error = %e,
                            "GNSS receiver: sentence ignored");
                        st.malformed_logged = Some(Instant::now());
                    }
                    st.status.last_error = Some(e);
                }
            }
        }
        st.line = line;
        st.line.clear();
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_errors_name_the_key() {
        let e = NmeaDeviceConfig::new(Path::new("/dev/ttyACM0"), Some(9601), 30.0)
            .expect_err("odd baud");
        assert!(
            e.to_string().contains("baud") && e.to_string().contains("9601"),
            "{e}"
        );
        let e = NmeaDeviceConfig::new(Path::new(""), None, 30.0).expect_err("empty");
        assert!(e.to_string().contains("device"), "{e}");
        let e = NmeaDeviceConfig::new(Path::new("/dev/x"), None, f64::NAN).expect_err("nan");
        assert!(e.to_string().contains("max_error_m"), "{e}");
        for b in BAUD_RATES {
            assert!(NmeaDeviceConfig::new(Path::new("/dev/x"), Some(b), 30.0).is_ok());
        }
    }
}
