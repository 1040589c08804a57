//! What `gpsd_fixes` and `nmea_fixes` print: one CSV line per fix
//! (`fix,gnss_time_unix_s,lat_deg,lon_deg,sigma_m`) and one per change of
//! the connection (`status,connected,reconnects,accepted,...`).

use canodom_gnss::Event;
use std::time::{Duration, Instant};

/// Prints the events `next` yields (each call waits up to the given time)
/// until `seconds` have passed since `start`.
pub fn print_events(start: Instant, seconds: f64, next: impl Fn(Duration) -> Option<Event>) {
    let mut last_connected = None;
    while start.elapsed().as_secs_f64() < seconds {
        match next(Duration::from_millis(200)) {
            Some(Event::Fix(f)) => println!(
                "fix,{:.3},{:.9},{:.9},{}",
                f.gnss_time_unix_s.unwrap_or(f64::NAN),
                f.lat_deg,
                f.lon_deg,
                f.sigma_m.map_or(String::new(), |s| format!("{s:.3}"))
            ),
            Some(Event::Status(s)) if last_connected != Some(s.connected) => {
                println!(
                    "status,{},{},{},refused={:?},last_error_m={:?},last_error={:?}",
                    s.connected, s.reconnects, s.accepted, s.refused, s.last_error_m, s.last_error
                );
                last_connected = Some(s.connected);
            }
            _ => {}
        }
    }
}
