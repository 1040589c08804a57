//! Probe of sd-notify 0.5.0 against canodom's sd_notify.rs semantics (#21).
use std::os::linux::net::SocketAddrExt;
use std::os::unix::net::{SocketAddr, UnixDatagram};
use std::time::Duration;

fn main() {
    // 1. Abstract socket "@name", as systemd may hand out.
    let name = format!("sdn-probe-{}", std::process::id());
    let addr = SocketAddr::from_abstract_name(name.as_bytes()).unwrap();
    let manager = UnixDatagram::bind_addr(&addr).unwrap();
    manager
        .set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    std::env::set_var("NOTIFY_SOCKET", format!("@{name}"));
    let r = sd_notify::notify(&[sd_notify::NotifyState::Ready]);
    let mut buf = [0u8; 256];
    let got = manager
        .recv(&mut buf)
        .map(|n| String::from_utf8_lossy(&buf[..n]).into_owned());
    println!("abstract @socket: notify -> {r:?}; manager received -> {got:?}");

    // 2. WATCHDOG_USEC=0
    std::env::set_var("WATCHDOG_USEC", "0");
    std::env::remove_var("WATCHDOG_PID");
    println!(
        "WATCHDOG_USEC=0: watchdog_enabled -> {:?}",
        sd_notify::watchdog_enabled()
    );

    // 3. STATUS with a newline
    let dir = std::env::temp_dir().join(format!("sdn-probe-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("n.sock");
    let m2 = UnixDatagram::bind(&path).unwrap();
    std::env::set_var("NOTIFY_SOCKET", &path);
    sd_notify::notify(&[sd_notify::NotifyState::Status("a\nREADY=1")]).unwrap();
    let n = m2.recv(&mut buf).unwrap();
    println!(
        "STATUS with newline -> {:?}",
        String::from_utf8_lossy(&buf[..n])
    );
    std::fs::remove_dir_all(dir).unwrap();
}
