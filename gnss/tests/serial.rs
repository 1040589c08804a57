//! The serial reader against a pseudo-terminal (a real tty: raw mode and the
//! baud rate are set on it) and a named pipe whose writer leaves and comes
//! back (a receiver unplugged and plugged in again).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use canodom_gnss::backoff::Backoff;
use canodom_gnss::{Event, Fix, NmeaDevice, NmeaDeviceConfig};
use std::io::Write as _;
use std::os::fd::AsRawFd as _;
use std::path::Path;
use std::time::{Duration, Instant};

/// A sentence with its checksum and CR LF.
fn sentence(body: &str) -> String {
    canodom_gnss::nmea::with_checksum(body) + "\r\n"
}

/// One epoch as a u-blox receiver sends it: RMC, GGA (HDOP given), GSV,
/// and a GST every other epoch. `k` moves the car 0.001' north each epoch.
fn epoch(k: u32) -> String {
    let (h, m, s) = (12, 6 + (40 + k) / 60, (40 + k) % 60);
    let time = format!("{h:02}{m:02}{s:02}.20");
    let lat = format!("4809.{:07}", 10_000 * k);
    let mut out = sentence(&format!(
        "GPRMC,{time},A,{lat},N,01134.8000000,E,20.0,0.0,151123,,,A"
    ));
    out += &sentence(&format!(
        "GPGGA,{time},{lat},N,01134.8000000,E,1,09,1.5,520.0,M,47.0,M,,"
    ));
    out += &sentence("GPGSV,1,1,01,05,45,120,40");
    if k.is_multiple_of(2) {
        out += &sentence(&format!("GPGST,{time},2.0,1.7,1.1,30.0,1.2,1.6,2.5"));
    }
    out
}

fn expected_lat(k: u32) -> f64 {
    48.0 + (9.0 + f64::from(k) * 0.001) / 60.0
}

/// Fixes until `n` arrived (`n` = 0: until `timeout`) or `timeout`; the
/// statuses beside them.
fn collect(dev: &NmeaDevice, n: usize, timeout: Duration) -> (Vec<Fix>, Vec<Event>) {
    let until = Instant::now() + timeout;
    let (mut fixes, mut other) = (Vec::new(), Vec::new());
    while (n == 0 || fixes.len() < n) && Instant::now() < until {
        match dev.recv_timeout(Duration::from_millis(50)) {
            Some(Event::Fix(f)) => fixes.push(f),
            Some(e) => other.push(e),
            None => {}
        }
    }
    (fixes, other)
}

fn check(fixes: &[Fix], from: u32) {
    for (i, f) in fixes.iter().enumerate() {
        let k = from + i as u32;
        assert!(
            (f.lat_deg - expected_lat(k)).abs() < 1e-9,
            "epoch {k}: {f:?}"
        );
        assert_eq!(f.mode, 3);
        // 15 Nov 2023 12:06:40.20 UTC + k s.
        let t = f.gnss_time_unix_s.expect("time");
        assert!((t - (1_700_050_000.2 + f64::from(k))).abs() < 1e-6, "{t}");
        let sigma = f.sigma_m.expect("σ");
        let want = if k.is_multiple_of(2) {
            2.0_f64.sqrt()
        } else {
            1.5 * 2.1
        };
        assert!((sigma - want).abs() < 1e-9, "epoch {k}: σ {sigma}");
    }
}

#[test]
fn a_pseudo_terminal_is_read_raw_at_its_baud_rate_and_its_hangup_is_a_loss() {
    let pty = nix::pty::openpty(None, None).expect("openpty");
    let path = nix::unistd::ttyname(&pty.slave).expect("ttyname");
    let mut config = NmeaDeviceConfig::new(&path, Some(38_400), 32.0).unwrap();
    config.backoff = Backoff::new(Duration::from_millis(50), Duration::from_millis(200));
    let dev = NmeaDevice::spawn(config, Instant::now()).unwrap();
    // Wait until the reader has the device open (its first status).
    let (_, statuses) = collect(&dev, 0, Duration::from_millis(300));
    assert!(
        statuses
            .iter()
            .any(|e| matches!(e, Event::Status(s) if s.connected)),
        "{statuses:?}"
    );
    // The reader set the line raw at 38400 baud.
    let t = nix::sys::termios::tcgetattr(&pty.slave).unwrap();
    assert_eq!(
        nix::sys::termios::cfgetispeed(&t),
        nix::sys::termios::BaudRate::B38400
    );
    assert!(
        !t.local_flags
            .contains(nix::sys::termios::LocalFlags::ICANON)
    );
    let mut master = std::fs::File::from(pty.master);
    for k in 0..5 {
        master.write_all(epoch(k).as_bytes()).unwrap();
        std::thread::sleep(Duration::from_millis(60));
    }
    // Four complete on the next epoch's first sentence, the fifth on the pause.
    let (fixes, _) = collect(&dev, 5, Duration::from_secs(3));
    assert_eq!(fixes.len(), 5, "{fixes:?}");
    check(&fixes, 0);
    // A fix's receipt time is when its first sentence came, not when the
    // epoch completed.
    assert!(fixes[1].receipt_time_s - fixes[0].receipt_time_s < 0.2);
    // The other end hangs up: a loss, told in the status.
    drop(master);
    let (_, statuses) = collect(&dev, 1, Duration::from_secs(2));
    let lost = statuses.iter().find_map(|e| match e {
        Event::Status(s) if !s.connected && s.last_error.is_some() => Some(s.clone()),
        _ => None,
    });
    let lost = lost.expect("a status saying the device was lost");
    assert_eq!(lost.accepted, 5);
    drop(pty.slave);
}

#[test]
fn a_pipe_whose_writer_leaves_and_returns_is_reopened_and_no_epoch_is_lost() {
    let dir = std::env::temp_dir().join(format!("canodom-serial-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let fifo = dir.join("receiver");
    let _ = std::fs::remove_file(&fifo);
    nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::S_IRWXU).unwrap();
    let mut config = NmeaDeviceConfig::new(&fifo, Some(9600), 32.0).unwrap();
    config.backoff = Backoff::new(Duration::from_millis(50), Duration::from_millis(200));
    let dev = NmeaDevice::spawn(config, Instant::now()).unwrap();
    let write = |path: &Path, from: u32, to: u32| {
        let mut w = std::fs::OpenOptions::new().write(true).open(path).unwrap();
        assert!(w.as_raw_fd() >= 0);
        for k in from..to {
            w.write_all(epoch(k).as_bytes()).unwrap();
            std::thread::sleep(Duration::from_millis(40));
        }
    };
    write(&fifo, 0, 4);
    let (first, _) = collect(&dev, 4, Duration::from_secs(3));
    assert_eq!(first.len(), 4, "{first:?}");
    // The writer is gone; it comes back 0.5 s later with the next epochs.
    std::thread::sleep(Duration::from_millis(500));
    write(&fifo, 4, 8);
    let (second, events) = collect(&dev, 4, Duration::from_secs(3));
    assert_eq!(second.len(), 4, "{second:?}");
    check(&first, 0);
    check(&second, 4);
    let reopened = events
        .iter()
        .any(|e| matches!(e, Event::Status(s) if s.connected && s.reconnects >= 1));
    assert!(reopened, "{events:?}");
    // A damaged sentence and a line of noise are skipped, not a loss.
    {
        let mut w = std::fs::OpenOptions::new().write(true).open(&fifo).unwrap();
        let mut text = "$GPGGA,broken*00\r\n".to_owned();
        text.push_str(&"x".repeat(1000));
        text.push_str("\r\n");
        text.push_str(&epoch(8));
        w.write_all(text.as_bytes()).unwrap();
    }
    let (third, _) = collect(&dev, 1, Duration::from_secs(3));
    assert_eq!(third.len(), 1, "{third:?}");
    check(&third, 8);
    drop(dev);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_regular_file_is_refused_with_the_reason() {
    let file = std::env::temp_dir().join(format!("canodom-serial-file-{}", std::process::id()));
    std::fs::write(&file, epoch(0)).unwrap();
    let mut config = NmeaDeviceConfig::new(&file, None, 32.0).unwrap();
    config.backoff = Backoff::new(Duration::from_millis(50), Duration::from_millis(50));
    let dev = NmeaDevice::spawn(config, Instant::now()).unwrap();
    let (fixes, events) = collect(&dev, 1, Duration::from_millis(400));
    assert!(fixes.is_empty());
    let said = events.iter().any(|e| {
        matches!(e, Event::Status(s) if s.last_error.as_deref().is_some_and(|m| m.contains("regular file")))
    });
    assert!(said, "{events:?}");
    let _ = std::fs::remove_file(&file);
}
