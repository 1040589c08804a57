//! Position fixes in the formats receivers and users write (issue #31),
//! told apart by their content, not their file name:
//!
//! - a CSV in local metres, `t_unix_s,x_m,y_m[,heading_rad]`
//!   ([`canodom_calib::drive::parse_fixes`]);
//! - a CSV of geodetic positions, `t_unix_s,lat_deg,lon_deg[,alt_m]`
//!   (WGS-84), turned into a local east/north frame at the first fix;
//! - an NMEA 0183 log (lines starting with `$`): GGA and RMC sentences,
//!   checksums checked, their UTC times (RMC's date) on the Unix clock the
//!   logs use; a sentence with an invalid fix is left out, other sentences
//!   (GSV, VTG, ...) are counted and skipped.
//!
//! Each fix's 1σ horizontal error per axis ([`Fix::sigma_m`]) as its source
//! states it: a CSV's `horiz_std_m` column; in NMEA, the GST sentence of the
//! same epoch (the receiver's own error estimate), else GGA's HDOP times
//! [`HDOP_UERE_M`]. Without any, the fit estimates it from its residuals.
//!
//! The sentences are read by `canodom_gnss::nmea`, which the live serial
//! reader shares (why by hand: see there).
//!
//! The geodetic-to-local conversion is `map_3d`'s `geodetic2enu` on WGS-84
//! (exact ECEF differences rotated into the tangent plane), not a flat-earth
//! scale: over a 1 km drive the two differ by centimetres, but the crate
//! costs nothing and is right anywhere.

use crate::{Error, Result};
use canodom_calib::drive::{Fix, FixRow, FixRowsError, fix_rows};
use canodom_gnss::nmea::{self, Position};
use chrono::{NaiveTime, Timelike as _};

/// The 1σ per axis of a fix at HDOP 1 (see [`canodom_gnss::nmea::HDOP_UERE_M`]).
pub use canodom_gnss::nmea::HDOP_UERE_M;

/// What a fixes file held.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FixesFormat {
    /// CSV in local metres.
    LocalCsv,
    /// CSV of latitude and longitude, converted to metres around the first fix.
    GeodeticCsv,
    /// NMEA 0183 GGA/RMC, converted to metres around the first fix.
    Nmea,
}

impl FixesFormat {
    /// The format's name for messages.
    pub fn name(self) -> &'static str {
        match self {
            Self::LocalCsv => "CSV in local metres (t_unix_s,x_m,y_m)",
            Self::GeodeticCsv => "CSV of latitude/longitude (t_unix_s,lat_deg,lon_deg)",
            Self::Nmea => "NMEA 0183 (GGA/RMC)",
        }
    }
}

/// Reads the fixes in `text` (`name` names the file in errors), telling the
/// format from the content.
///
/// # Errors
/// [`Error::Calibration`] naming the file, the format it saw and the line
/// at fault; a text in none of the formats is refused naming what it looked like.
pub fn parse_fixes_any(text: &str, name: &str) -> Result<(Vec<Fix>, FixesFormat)> {
    let err = |m: String| Error::Calibration(format!("{name}: {m}"));
    let Some(first) = text.lines().map(str::trim).find(|l| !l.is_empty()) else {
        return Err(err("empty: no fixes".to_owned()));
    };
    if first.starts_with('$') || first.starts_with('!') {
        return Ok((parse_nmea(text, name)?, FixesFormat::Nmea));
    }
    let columns: Vec<&str> = first.split(',').map(str::trim).collect();
    let has = |c: &str| columns.contains(&c);
    if has("lat_deg") || has("lon_deg") {
        return Ok((parse_geodetic_csv(text, name)?, FixesFormat::GeodeticCsv));
    }
    if has("x_m") || has("y_m") || has("t_unix_s") {
        let fixes = canodom_calib::drive::parse_fixes(text, name).map_err(|e| {
            Error::Calibration(format!("{e} (read as {})", FixesFormat::LocalCsv.name()))
        })?;
        return Ok((fixes, FixesFormat::LocalCsv));
    }
    let shown: String = first.chars().take(60).collect();
    Err(err(format!(
        "not a fixes file: its first line {shown:?} is neither a CSV header naming \
         t_unix_s,x_m,y_m or t_unix_s,lat_deg,lon_deg nor an NMEA sentence ($GPGGA, $GNRMC, ...)"
    )))
}

/// One geodetic fix before the local frame.
struct Geodetic {
    t_s: f64,
    lat_deg: f64,
    lon_deg: f64,
    alt_m: f64,
    sigma_m: Option<f64>,
}

/// East/north metres around the first fix (its altitude as the plane's).
fn to_local(geo: &[Geodetic]) -> Vec<Fix> {
    let Some(origin) = geo.first() else {
        return Vec::new();
    };
    let (lat0, lon0, alt0) = (
        origin.lat_deg.to_radians(),
        origin.lon_deg.to_radians(),
        origin.alt_m,
    );
    geo.iter()
        .map(|g| {
            let (e, n, _) = map_3d::geodetic2enu(
                g.lat_deg.to_radians(),
                g.lon_deg.to_radians(),
                g.alt_m,
                lat0,
                lon0,
                alt0,
                map_3d::Ellipsoid::WGS84,
            );
            Fix {
                t_s: g.t_s,
                x_m: e,
                y_m: n,
                heading_rad: None,
                sigma_m: g.sigma_m,
            }
        })
        .collect()
}

fn parse_geodetic_csv(text: &str, name: &str) -> Result<Vec<Fix>> {
    let format = FixesFormat::GeodeticCsv.name();
    let err = |line: usize, m: String| {
        Error::Calibration(format!("{name}:{line}: {m} (read as {format})"))
    };
    let in_range = |r: &FixRow| {
        let [_, lat_deg, lon_deg] = r.values;
        if lat_deg.abs() > 90.0 || lon_deg.abs() > 180.0 {
            Err(format!(
                "latitude {lat_deg} / longitude {lon_deg} outside ±90° / ±180°"
            ))
        } else {
            Ok(())
        }
    };
    let rows = fix_rows(text, ["t_unix_s", "lat_deg", "lon_deg"], "alt_m", in_range).map_err(
        |e| match e {
            FixRowsError::Empty => err(0, "empty".to_owned()),
            FixRowsError::Header { line, header } => err(
                line,
                format!("the header {header:?} lacks t_unix_s, lat_deg or lon_deg"),
            ),
            FixRowsError::Line { line, reason } => err(line, reason),
        },
    )?;
    let geo: Vec<Geodetic> = rows
        .iter()
        .map(|r| Geodetic {
            t_s: r.values[0],
            lat_deg: r.values[1],
            lon_deg: r.values[2],
            alt_m: r.optional.unwrap_or(0.0),
            sigma_m: r.sigma_m,
        })
        .collect();
    Ok(to_local(&geo))
}

/// One NMEA position sentence and the line it is on.
struct Sentence {
    line: usize,
    position: Position,
}

fn parse_nmea(text: &str, name: &str) -> Result<Vec<Fix>> {
    let format = FixesFormat::Nmea.name();
    let err = |m: String| Error::Calibration(format!("{name}: {m} (read as {format})"));
    let mut sentences: Vec<Sentence> = Vec::new();
    // GST's σ by time of day: a receiver sends it before or after the epoch's GGA.
    let mut gst_sigma = std::collections::HashMap::<NaiveTime, f64>::new();
    let (mut other, mut invalid, mut bad) = (0_usize, 0_usize, Vec::<String>::new());
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.is_empty() {
            continue;
        }
        if !line.starts_with('$') && !line.starts_with('!') {
            return Err(err(format!(
                "line {} is not an NMEA sentence: {:?}",
                i + 1,
                line.chars().take(60).collect::<String>()
            )));
        }
        match nmea::parse_sentence(line) {
            Ok(nmea::Sentence::Fix(position)) => sentences.push(Sentence {
                line: i + 1,
                position,
            }),
            Ok(nmea::Sentence::Gst { time, sigma_m }) => {
                gst_sigma.insert(time, sigma_m);
            }
            Ok(nmea::Sentence::NoFix { .. }) => invalid += 1,
            Ok(nmea::Sentence::Other) => other += 1,
            Err(e) => bad.push(format!("line {}: {e}", i + 1)),
        }
    }
    if !bad.is_empty() {
        return Err(err(format!(
            "{} sentence(s) cannot be parsed (a damaged log?), first {}",
            bad.len(),
            bad[0]
        )));
    }
    let Some(first_date) = sentences.iter().find_map(|s| s.position.date) else {
        return Err(err(format!(
            "no RMC sentence with a date and a valid fix ({} GGA/RMC with a fix, {invalid} without, \
             {other} other sentences): GGA carries the time of day only",
            sentences.len()
        )));
    };
    // Each sentence's UTC date: the last RMC's (the first's before it), a
    // day later when the time of day wraps past midnight.
    let mut date = first_date;
    let mut previous: Option<NaiveTime> = None;
    let mut geo: Vec<Geodetic> = Vec::new();
    let mut altitude: Option<f64> = None;
    for Sentence { line, position: s } in &sentences {
        if let Some(d) = s.date {
            date = d;
        } else if previous.is_some_and(|p| {
            s.time.num_seconds_from_midnight() + 43_200 < p.num_seconds_from_midnight()
        }) {
            date = date.succ_opt().unwrap_or(date);
        }
        previous = Some(s.time);
        let t_s = nmea::unix_s(date, s.time);
        altitude = s.alt_m.or(altitude);
        let sigma_m = nmea::epoch_sigma_m(gst_sigma.get(&s.time).copied(), s.hdop);
        // One fix an epoch: GGA and RMC of the same instant are one.
        match geo.last_mut() {
            Some(last) if (last.t_s - t_s).abs() < 1e-6 => {
                if s.alt_m.is_some() {
                    (last.lat_deg, last.lon_deg, last.alt_m) =
                        (s.lat_deg, s.lon_deg, altitude.unwrap_or(0.0));
                }
                last.sigma_m = last.sigma_m.or(sigma_m);
            }
            Some(last) if t_s < last.t_s => {
                return Err(err(format!(
                    "line {line}: the time {} goes back before the previous fix's",
                    s.time
                )));
            }
            _ => geo.push(Geodetic {
                t_s,
                lat_deg: s.lat_deg,
                lon_deg: s.lon_deg,
                alt_m: altitude.unwrap_or(0.0),
                sigma_m,
            }),
        }
    }
    Ok(to_local(&geo))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    use canodom_gnss::nmea::with_checksum as sentence;

    #[test]
    fn nmea_gga_and_rmc_become_local_metres_on_the_unix_clock() {
        // 15 Nov 2023 12:06:40.20 UTC = 1700050000.2; then one second later,
        // 0.001' of latitude (1.853 m) north.
        let text = [
            sentence("GPGGA,120640.20,4809.0000000,N,01134.8000000,E,1,09,0.6,520.0,M,47.0,M,,"),
            sentence("GPRMC,120640.20,A,4809.0000000,N,01134.8000000,E,20.0,90.0,151123,,,A"),
            sentence("GPGSV,1,1,01,05,45,120,40"),
            sentence("GPGGA,120641.20,4809.0010000,N,01134.8000000,E,1,09,0.6,520.0,M,47.0,M,,"),
            sentence("GPRMC,120641.20,A,4809.0010000,N,01134.8000000,E,20.0,90.0,151123,,,A"),
            sentence("GPGGA,120642.20,4809.0010000,N,01134.8000000,E,0,00,,,M,,M,,"),
        ]
        .join("\r\n");
        let (fixes, format) = parse_fixes_any(&text, "f.nmea").unwrap();
        assert_eq!(format, FixesFormat::Nmea);
        assert_eq!(fixes.len(), 2, "{fixes:?}");
        assert!(
            (fixes[0].t_s - 1_700_050_000.2).abs() < 1e-6,
            "{}",
            fixes[0].t_s
        );
        assert!((fixes[1].t_s - fixes[0].t_s - 1.0).abs() < 1e-6);
        assert_eq!((fixes[0].x_m, fixes[0].y_m), (0.0, 0.0));
        assert!(fixes[1].x_m.abs() < 1e-6, "{:?}", fixes[1]);
        // 0.001' of latitude at 48.15° on WGS-84: 1.8532 m.
        assert!((fixes[1].y_m - 1.8532).abs() < 1e-3, "{:?}", fixes[1]);
    }

    #[test]
    fn nmea_sigma_from_gst_when_present_else_from_hdop() {
        // Epoch 1: GGA HDOP 0.8 and a GST of σ_lat 1.2 m, σ_lon 1.6 m (sent
        // after the GGA); epoch 2: HDOP 1.5, no GST; epoch 3: GST before
        // the GGA, its lat/lon errors empty, the ellipse's axes 2 and 1 m.
        let text = [
            sentence("GPGGA,120640.20,4809.0000000,N,01134.8000000,E,1,09,0.8,520.0,M,47.0,M,,"),
            sentence("GPGST,120640.20,2.0,1.7,1.1,30.0,1.2,1.6,2.5"),
            sentence("GPRMC,120640.20,A,4809.0000000,N,01134.8000000,E,20.0,90.0,151123,,,A"),
            sentence("GPGGA,120641.20,4809.0010000,N,01134.8000000,E,1,09,1.5,520.0,M,47.0,M,,"),
            sentence("GPRMC,120641.20,A,4809.0010000,N,01134.8000000,E,20.0,90.0,151123,,,A"),
            sentence("GNGST,120642.20,2.0,2.0,1.0,30.0,,,"),
            sentence("GPGGA,120642.20,4809.0020000,N,01134.8000000,E,1,09,0.9,520.0,M,47.0,M,,"),
            sentence("GPRMC,120642.20,A,4809.0020000,N,01134.8000000,E,20.0,90.0,151123,,,A"),
        ]
        .join("\r\n");
        let (fixes, _) = parse_fixes_any(&text, "f.nmea").unwrap();
        let sigma: Vec<Option<f64>> = fixes.iter().map(|f| f.sigma_m).collect();
        let close = |got: Option<f64>, want: f64| got.is_some_and(|g| (g - want).abs() < 1e-9);
        // √((1.2² + 1.6²)/2) = √2 m.
        assert!(close(sigma[0], 2.0_f64.sqrt()), "{sigma:?}");
        assert!(close(sigma[1], 1.5 * HDOP_UERE_M), "{sigma:?}");
        // √((2² + 1²)/2) = √2.5 m.
        assert!(close(sigma[2], 2.5_f64.sqrt()), "{sigma:?}");
        // Without HDOP or GST a fix states none; a bad HDOP is named.
        let plain = [
            sentence("GPGGA,120640.20,4809.0,N,01134.8,E,1,09,,520.0,M,47.0,M,,"),
            sentence("GPRMC,120640.20,A,4809.0,N,01134.8,E,20.0,90.0,151123,,,A"),
        ]
        .join("\n");
        assert_eq!(parse_fixes_any(&plain, "f").unwrap().0[0].sigma_m, None);
        let bad = sentence("GPGGA,120640.20,4809.0,N,01134.8,E,1,09,x,520.0,M,47.0,M,,");
        let e = parse_fixes_any(&bad, "f").unwrap_err().to_string();
        assert!(e.contains("HDOP") && e.contains("line 1"), "{e}");
    }

    #[test]
    fn csv_sigma_from_the_horiz_std_m_column() {
        // What `canodom ros2-fixes` writes: empty when the covariance is unknown.
        let text = "t_unix_s,lat_deg,lon_deg,alt_m,horiz_std_m\n\
                    10,48.15,11.58,520,1.250\n11,48.15001,11.58,520,\n12,48.15002,11.58,520,0\n";
        let (fixes, _) = parse_fixes_any(text, "g.csv").unwrap();
        let sigma: Vec<Option<f64>> = fixes.iter().map(|f| f.sigma_m).collect();
        assert_eq!(sigma, [Some(1.25), None, None]);
        let (local, format) =
            parse_fixes_any("t_unix_s,x_m,y_m,horiz_std_m\n1,0,0,2.5\n", "l.csv").unwrap();
        assert_eq!(format, FixesFormat::LocalCsv);
        assert_eq!(local[0].sigma_m, Some(2.5));
        let e = parse_fixes_any("t_unix_s,x_m,y_m,horiz_std_m\n1,0,0,-1\n", "l.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("l.csv:2") && e.contains("horiz_std_m"), "{e}");
        let e = parse_fixes_any("t_unix_s,x_m,y_m,horiz_std_m\n1,0,0,abc\n", "l.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("l.csv:2") && e.contains("not a number"), "{e}");
    }

    #[test]
    fn geodetic_csv_turns_around_the_first_fix_and_the_west_is_negative() {
        let text = "t_unix_s,lat_deg,lon_deg,alt_m\n10,-33.9,-70.6,500\n11,-33.9,-70.59999,500\n";
        let (fixes, format) = parse_fixes_any(text, "g.csv").unwrap();
        assert_eq!(format, FixesFormat::GeodeticCsv);
        // 1e-5° of longitude at 33.9° S: 0.9249 m east.
        assert!((fixes[1].x_m - 0.9249).abs() < 1e-3, "{:?}", fixes[1]);
        assert!(fixes[1].y_m.abs() < 1e-3);
        let e = parse_fixes_any("t_unix_s,lat_deg,lon_deg\n1,95,0\n", "g.csv")
            .unwrap_err()
            .to_string();
        assert!(e.contains("g.csv:2") && e.contains("latitude"), "{e}");
    }

    #[test]
    fn what_cannot_be_read_is_refused_naming_the_format_seen() {
        let e = |t: &str| parse_fixes_any(t, "f").unwrap_err().to_string();
        let gga_only = sentence("GPGGA,120640.20,4809.0,N,01134.8,E,1,09,0.6,520.0,M,47.0,M,,");
        assert!(
            e(&gga_only).contains("no RMC") && e(&gga_only).contains("NMEA"),
            "{}",
            e(&gga_only)
        );
        let damaged = "$GPRMC,120640.20,A,4809.0,N,01134.8,E,20.0,90.0,151123,,,A*00";
        assert!(
            e(damaged).contains("cannot be parsed") && e(damaged).contains("line 1"),
            "{}",
            e(damaged)
        );
        assert!(e("time,east,north\n1,2,3\n").contains("not a fixes file"));
        assert!(e("t_unix_s,lat_deg\n1,2\n").contains("lon_deg"));
        assert!(e("t_unix_s,x_m\n1,2\n").contains("local metres"));
        assert!(e("").contains("empty"));
    }
}
