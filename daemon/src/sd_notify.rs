//! systemd readiness, watchdog and stopping notifications (`sd_notify(3)`)
//! over the datagram socket named by `$NOTIFY_SOCKET`.
//!
//! Written here rather than with the `sd-notify` crate because that crate
//! reads the environment on every call, while the daemon reads it once at
//! start ([`Notifier::from_env`]) and hands a value to its tasks, and because
//! a value can be tested against a socket in a temporary directory without
//! mutating the process environment (which edition 2024 makes `unsafe`,
//! forbidden in this workspace). The protocol is one datagram of
//! `KEY=VALUE` lines; paths starting with `@` are Linux abstract sockets.
//!
//! Weighed again for issue #21 against `sd-notify` 0.5.0 (libc only; its
//! `fdstore` feature, which canodom does not need, adds `sendfd`), with a
//! probe outside the workspace that sets the variables and calls the crate
//! (`cargo run --manifest-path bench/crate-probes/Cargo.toml --bin
//! sd_notify`): `NOTIFY_SOCKET=@name` fails with `ENOENT` and the manager receives
//! nothing (it connects to a file path named `@name`, no abstract sockets);
//! `WATCHDOG_USEC=0` gives `watchdog_enabled() == Some(0ns)` where this
//! module turns the watchdog off; `STATUS=a\nREADY=1` goes out as two keys,
//! a false `READY=1`, where [`Notifier::status`] joins the lines; and each
//! `notify` opens, connects and closes a new socket where a [`Notifier`]
//! sends one datagram on the socket it keeps. Replacing this module would
//! change behaviour, so it stays.

use std::ffi::OsStr;
use std::io;
use std::os::linux::net::SocketAddrExt;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::net::{SocketAddr, UnixDatagram};
use std::time::Duration;

/// A connection to the service manager's notification socket.
#[derive(Debug)]
pub struct Notifier {
    socket: UnixDatagram,
    addr: SocketAddr,
    watchdog_timeout: Option<Duration>,
}

impl Notifier {
    /// The notifier systemd asked for through this process's environment
    /// (`NOTIFY_SOCKET`, `WATCHDOG_USEC`, `WATCHDOG_PID`), or `None` when not
    /// started with `Type=notify`. Read once, at start.
    ///
    /// # Errors
    /// The socket named by `NOTIFY_SOCKET` cannot be addressed.
    pub fn from_env() -> io::Result<Option<Self>> {
        let socket = std::env::var_os("NOTIFY_SOCKET");
        let usec = std::env::var("WATCHDOG_USEC").ok();
        let pid = std::env::var("WATCHDOG_PID").ok();
        Self::from_vars(
            socket.as_deref(),
            usec.as_deref(),
            pid.as_deref(),
            std::process::id(),
        )
    }

    /// As [`Notifier::from_env`] from explicit values: the watchdog applies
    /// when `WATCHDOG_USEC` is a positive integer and `WATCHDOG_PID` is
    /// absent or equal to `own_pid` (it may be meant for a parent).
    ///
    /// # Errors
    /// As [`Notifier::connect`].
    pub fn from_vars(
        notify_socket: Option<&OsStr>,
        watchdog_usec: Option<&str>,
        watchdog_pid: Option<&str>,
        own_pid: u32,
    ) -> io::Result<Option<Self>> {
        let Some(path) = notify_socket.filter(|p| !p.is_empty()) else {
            return Ok(None);
        };
        let for_us = watchdog_pid.is_none_or(|p| p.parse::<u32>().ok() == Some(own_pid));
        let timeout = watchdog_usec
            .and_then(|u| u.parse::<u64>().ok())
            .filter(|&u| u > 0 && for_us)
            .map(Duration::from_micros);
        Self::connect(path, timeout).map(Some)
    }

    /// A notifier for the socket at `path` (`@name` for an abstract socket).
    ///
    /// # Errors
    /// The local socket cannot be created or the address is invalid.
    pub fn connect(path: &OsStr, watchdog_timeout: Option<Duration>) -> io::Result<Self> {
        let bytes = path.as_bytes();
        let addr = match bytes.strip_prefix(b"@") {
            Some(name) => SocketAddr::from_abstract_name(name)?,
            None => SocketAddr::from_pathname(path)?,
        };
        Ok(Self {
            socket: UnixDatagram::unbound()?,
            addr,
            watchdog_timeout,
        })
    }

    /// How often to send [`Notifier::watchdog`]: half the manager's timeout,
    /// as `sd_watchdog_enabled(3)` recommends; `None` without a watchdog.
    pub fn watchdog_interval(&self) -> Option<Duration> {
        self.watchdog_timeout.map(|t| t / 2)
    }

    /// Start-up finished (`READY=1`) with a status line.
    ///
    /// # Errors
    /// The datagram could not be sent.
    pub fn ready(&self, status: &str) -> io::Result<()> {
        self.send(&["READY=1", &status_line(status)])
    }

    /// Still alive (`WATCHDOG=1`).
    ///
    /// # Errors
    /// The datagram could not be sent.
    pub fn watchdog(&self) -> io::Result<()> {
        self.send(&["WATCHDOG=1"])
    }

    /// Shutting down (`STOPPING=1`).
    ///
    /// # Errors
    /// The datagram could not be sent.
    pub fn stopping(&self) -> io::Result<()> {
        self.send(&["STOPPING=1"])
    }

    /// A free-form status line shown by `systemctl status`.
    ///
    /// # Errors
    /// The datagram could not be sent.
    pub fn status(&self, status: &str) -> io::Result<()> {
        self.send(&[&status_line(status)])
    }

    fn send(&self, lines: &[&str]) -> io::Result<()> {
        let mut msg = String::with_capacity(64);
        for line in lines {
            msg.push_str(line);
            msg.push('\n');
        }
        let sent = self.socket.send_to_addr(msg.as_bytes(), &self.addr)?;
        if sent == msg.len() {
            Ok(())
        } else {
            Err(io::Error::new(
                io::ErrorKind::WriteZero,
                "truncated sd_notify datagram",
            ))
        }
    }
}

/// `STATUS=` with line breaks removed: a newline would start a new key.
fn status_line(status: &str) -> String {
    format!("STATUS={}", status.replace(['\n', '\r'], " "))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    fn recv(sock: &UnixDatagram) -> String {
        let mut buf = [0u8; 512];
        sock.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        let n = sock.recv(&mut buf).unwrap();
        String::from_utf8(buf[..n].to_vec()).unwrap()
    }

    fn temp_socket(tag: &str) -> (PathBuf, PathBuf) {
        let dir = std::env::temp_dir().join(format!("canodom-sdn-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("notify.sock");
        (dir, path)
    }

    #[test]
    fn sends_protocol_datagrams_to_a_path_socket() {
        let (dir, path) = temp_socket("path");
        let manager = UnixDatagram::bind(&path).unwrap();
        let n = Notifier::from_vars(Some(path.as_os_str()), Some("3000000"), None, 42)
            .unwrap()
            .unwrap();
        assert_eq!(n.watchdog_interval(), Some(Duration::from_millis(1500)));
        n.ready("publishing on can0\nat 50 Hz").unwrap();
        assert_eq!(
            recv(&manager),
            "READY=1\nSTATUS=publishing on can0 at 50 Hz\n"
        );
        n.watchdog().unwrap();
        assert_eq!(recv(&manager), "WATCHDOG=1\n");
        n.status("can0 down, retrying").unwrap();
        assert_eq!(recv(&manager), "STATUS=can0 down, retrying\n");
        n.stopping().unwrap();
        assert_eq!(recv(&manager), "STOPPING=1\n");
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn abstract_sockets_are_supported() {
        let name = format!("canodom-test-{}", std::process::id());
        let addr = SocketAddr::from_abstract_name(name.as_bytes()).unwrap();
        let manager = UnixDatagram::bind_addr(&addr).unwrap();
        let n = Notifier::connect(OsStr::new(&format!("@{name}")), None).unwrap();
        assert_eq!(n.watchdog_interval(), None);
        n.ready("ok").unwrap();
        assert_eq!(recv(&manager), "READY=1\nSTATUS=ok\n");
    }

    #[test]
    fn environment_rules() {
        let (dir, path) = temp_socket("env");
        let _manager = UnixDatagram::bind(&path).unwrap();
        let p = Some(path.as_os_str());
        assert!(
            Notifier::from_vars(None, Some("1000"), None, 1)
                .unwrap()
                .is_none()
        );
        assert!(
            Notifier::from_vars(Some(OsStr::new("")), None, None, 1)
                .unwrap()
                .is_none()
        );
        let wd = |usec, pid| {
            Notifier::from_vars(p, usec, pid, 7)
                .unwrap()
                .unwrap()
                .watchdog_interval()
        };
        assert_eq!(
            wd(Some("1000"), Some("7")),
            Some(Duration::from_micros(500))
        );
        assert_eq!(
            wd(Some("1000"), Some("8")),
            None,
            "watchdog meant for another pid"
        );
        assert_eq!(wd(Some("0"), None), None);
        assert_eq!(wd(Some("soon"), None), None);
        assert_eq!(wd(None, None), None);
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn a_missing_manager_socket_is_an_error_not_a_panic() {
        let (dir, path) = temp_socket("missing");
        let n = Notifier::connect(path.as_os_str(), None).unwrap();
        assert!(n.ready("x").is_err());
        std::fs::remove_dir_all(dir).unwrap();
    }
}
