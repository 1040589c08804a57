//! Prints the fixes a receiver on a serial port delivers through
//! [`canodom_gnss::NmeaDevice`], as `gpsd_fixes` does for gpsd: one CSV line
//! each (`fix,gnss_time_unix_s,lat_deg,lon_deg,sigma_m`), and status changes
//! (`status,connected,reconnects,accepted`). Check a receiver with it before
//! naming it in `[gnss]`.
//!
//! Usage: `nmea_fixes DEVICE SECONDS [BAUD] [MAX_ERROR_M]`, e.g.
//! `cargo run -p canodom-gnss --example nmea_fixes -- /dev/ttyACM0 10 9600`.

use canodom_gnss::{NmeaDevice, NmeaDeviceConfig};
use std::path::Path;
use std::time::Instant;

mod common;

const USAGE: &str = "usage: nmea_fixes DEVICE SECONDS [BAUD] [MAX_ERROR_M]";

fn main() -> Result<(), Box<dyn std::error::Error>> {
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_ansi(false)
        .init();
    let mut args = std::env::args().skip(1);
    let device = args.next().ok_or(USAGE)?;
    let seconds: f64 = args.next().ok_or(USAGE)?.parse()?;
    let baud: Option<u32> = args.next().map(|a| a.parse()).transpose()?;
    let max_error_m: f64 = args
        .next()
        .map_or(Ok(canodom_gnss::serial::DEFAULT_MAX_ERROR_M), |a| a.parse())?;
    let start = Instant::now();
    let config = NmeaDeviceConfig::new(Path::new(&device), baud, max_error_m)?;
    let dev = NmeaDevice::spawn(config, start)?;
    common::print_events(start, seconds, |wait| dev.recv_timeout(wait));
    Ok(())
}
