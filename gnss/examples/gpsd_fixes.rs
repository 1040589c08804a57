//! Prints the fixes a gpsd delivers through [`canodom_gnss::GpsdClient`], one CSV
//! line each (`fix,gnss_time_unix_s,lat_deg,lon_deg,sigma_m`), and status
//! changes (`status,connected,reconnects,accepted`), for `gnss/tests/gpsfake.sh`.
//!
//! Usage: `gpsd_fixes ADDRESS SECONDS [MAX_ERROR_M]` (default `DEFAULT_MAX_ERROR_M`, gpsd's 95 % estimate).

use canodom_gnss::{GpsdClient, GpsdClientConfig};
use std::time::Instant;

mod common;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    tracing_subscriber_init();
    let mut args = std::env::args().skip(1);
    let address = args.next().ok_or("usage: gpsd_fixes ADDRESS SECONDS")?;
    let seconds: f64 = args
        .next()
        .ok_or("usage: gpsd_fixes ADDRESS SECONDS")?
        .parse()?;
    let max_error_m: f64 = args
        .next()
        .map_or(Ok(canodom_gnss::client::DEFAULT_MAX_ERROR_M), |a| a.parse())?;
    let start = Instant::now();
    let client = GpsdClient::spawn(GpsdClientConfig::new(&address, max_error_m)?, start)?;
    common::print_events(start, seconds, |wait| client.recv_timeout(wait));
    Ok(())
}

/// The client's log (connects, losses, reconnects) to stderr, where the script reads it.
fn tracing_subscriber_init() {
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_ansi(false)
        .init();
}
