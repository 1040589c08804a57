//! NMEA 0183 sentences (pure): GGA, RMC and GST read, checksums checked, and
//! a live stream's sentences gathered into one fix per epoch.
//!
//! Two readers share the sentence parser: `canodom-offline` reads NMEA logs
//! (`--fixes drive.nmea`), and [`crate::serial`] reads a receiver on a
//! serial port live. A live epoch becomes a gpsd-style [`Tpv`], so that one
//! acceptance rule ([`crate::Acceptance`]) judges gpsd's reports, ROS 2's
//! and a serial receiver's alike, with the σ the offline reader gives the
//! same sentences.
//!
//! The sentences are read here by hand, and why: the `nmea` crate (0.7 and
//! 0.8) declares `serde_with ~3.9`/`~3.11` as an optional dependency, which
//! Cargo's resolver counts even unused and which conflicts with foxglove's
//! `serde_with ^3.14` (no lock file resolves); `nmea-parser` (0.10) drops
//! GGA's fractions of a second and dates GGA with today's date, while a
//! receiver's 0.2 s latency is what these readers must keep.

use crate::accept::{HORIZONTAL_95_TO_SIGMA, PER_AXIS_95_TO_SIGMA};
use crate::protocol::Tpv;
use chrono::{DateTime, NaiveDate, NaiveTime, Timelike as _};

/// The 1σ error per horizontal axis, metres, of a consumer receiver's fix
/// at HDOP 1, by which GGA's HDOP becomes a σ when no GST sentence states
/// one (`σ = HDOP × HDOP_UERE_M`). From u-blox's NEO-M8 data sheet
/// (UBX-15031086): 2.5 m CEP horizontal (GPS + GLONASS, 24 h static, open
/// sky, where HDOP is near 1); CEP is 1.1774 σ for a circular normal error,
/// so σ ≈ 2.1 m per axis. A receiver with SBAS or RTK does better and says
/// so in GST; this is what a plain receiver's HDOP alone supports.
pub const HDOP_UERE_M: f64 = 2.1;

/// A GGA or RMC sentence's position fix.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Position {
    /// UTC time of day of the fix.
    pub time: NaiveTime,
    /// RMC's UTC date (GGA carries none).
    pub date: Option<NaiveDate>,
    /// Latitude, degrees (south negative).
    pub lat_deg: f64,
    /// Longitude, degrees (west negative).
    pub lon_deg: f64,
    /// GGA's altitude above mean sea level, metres.
    pub alt_m: Option<f64>,
    /// GGA's horizontal dilution of precision (`None` when empty or 0: a
    /// receiver that does not compute it).
    pub hdop: Option<f64>,
}

/// What one sentence holds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Sentence {
    /// A sentence other than GGA/RMC/GST (GSV, VTG, ...), or a GST without
    /// an error estimate.
    Other,
    /// A GGA/RMC without a valid fix (quality 0, status V, empty position).
    NoFix {
        /// Its UTC time of day, when it has one.
        time: Option<NaiveTime>,
    },
    /// A GGA (`alt_m`, `hdop`) or RMC (`date`) with a valid fix.
    Fix(Position),
    /// A GST sentence: the receiver's own 1σ error per horizontal axis,
    /// `√((σ_lat² + σ_lon²)/2)`, at a time of day.
    Gst {
        /// UTC time of day.
        time: NaiveTime,
        /// 1σ per axis, metres.
        sigma_m: f64,
    },
}

/// Reads one sentence (`$GPGGA,...*hh`, surrounding white space allowed),
/// its checksum checked.
///
/// # Errors
/// A line that is not a sentence, a missing or wrong checksum, or a
/// malformed field, in words.
pub fn parse_sentence(line: &str) -> Result<Sentence, String> {
    let line = line.trim();
    let Some(body) = line.strip_prefix('$').or_else(|| line.strip_prefix('!')) else {
        return Err("not an NMEA sentence (no leading $)".to_owned());
    };
    let Some((data, sum)) = body.rsplit_once('*') else {
        return Err("no checksum (*hh)".to_owned());
    };
    let want =
        u8::from_str_radix(sum.trim(), 16).map_err(|_| format!("checksum {sum:?} is not hex"))?;
    let got = data.bytes().fold(0_u8, |a, b| a ^ b);
    if got != want {
        return Err(format!(
            "checksum {want:02X} but the sentence sums to {got:02X}"
        ));
    }
    let fields: Vec<&str> = data.split(',').collect();
    let kind = fields[0].get(2..).unwrap_or("");
    let field = |k: usize| fields.get(k).copied().unwrap_or("");
    let (time, lat, ns, lon, ew) = match kind {
        "GGA" => (field(1), field(2), field(3), field(4), field(5)),
        "RMC" => (field(1), field(3), field(4), field(5), field(6)),
        "GST" => return gst(&fields),
        _ => return Ok(Sentence::Other),
    };
    let valid = match kind {
        "GGA" => !matches!(field(6), "" | "0"),
        _ => field(2) == "A" || field(2) == "D",
    };
    if !valid || time.is_empty() || lat.is_empty() || lon.is_empty() {
        return Ok(Sentence::NoFix {
            time: time_of_day(time).ok(),
        });
    }
    let time = time_of_day(time)?;
    let lat_deg = angle(lat, 2, ns, "N", "S")?;
    let lon_deg = angle(lon, 3, ew, "E", "W")?;
    // An HDOP of 0 is a receiver that does not compute it: no σ.
    let hdop = match (kind, field(8)) {
        ("GGA", h) if !h.is_empty() => h
            .parse::<f64>()
            .ok()
            .filter(|h| h.is_finite() && *h >= 0.0)
            .ok_or_else(|| format!("HDOP {h:?} is not a number ≥ 0"))
            .map(|h| (h > 0.0).then_some(h))?,
        _ => None,
    };
    let (date, alt_m) = if kind == "RMC" {
        let d = field(9);
        let date = NaiveDate::parse_from_str(d, "%d%m%y")
            .map_err(|_| format!("date {d:?} is not ddmmyy"))?;
        (Some(date), None)
    } else {
        let a = field(9);
        let alt_m = if a.is_empty() {
            None
        } else {
            Some(
                a.parse::<f64>()
                    .ok()
                    .filter(|a| a.is_finite())
                    .ok_or_else(|| format!("altitude {a:?} is not a number"))?,
            )
        };
        (None, alt_m)
    };
    Ok(Sentence::Fix(Position {
        time,
        date,
        lat_deg,
        lon_deg,
        alt_m,
        hdop,
    }))
}

/// `hhmmss[.sss]`.
fn time_of_day(text: &str) -> Result<NaiveTime, String> {
    NaiveTime::parse_from_str(text, "%H%M%S%.f")
        .or_else(|_| NaiveTime::parse_from_str(text, "%H%M%S"))
        .map_err(|_| format!("time {text:?} is not hhmmss.ss"))
}

/// `d..dmm.mmm` with its hemisphere letter, in signed degrees.
fn angle(
    text: &str,
    degree_digits: usize,
    hemisphere: &str,
    positive: &str,
    negative: &str,
) -> Result<f64, String> {
    let bad = || format!("{text:?} {hemisphere:?} is not a d..dmm.mmm angle");
    let (deg, min) = (
        text.get(..degree_digits).ok_or_else(bad)?,
        text.get(degree_digits..).ok_or_else(bad)?,
    );
    let minutes = min.parse::<f64>().map_err(|_| bad())?;
    if !(0.0..60.0).contains(&minutes) {
        return Err(bad());
    }
    let value = deg.parse::<u16>().map_err(|_| bad())? as f64 + minutes / 60.0;
    let limit = if degree_digits == 2 { 90.0 } else { 180.0 };
    if value > limit {
        return Err(bad());
    }
    match hemisphere {
        h if h == positive => Ok(value),
        h if h == negative => Ok(-value),
        _ => Err(bad()),
    }
}

/// A GST sentence (`$--GST,time,rms,major,minor,orient,lat_err,lon_err,alt_err`):
/// the 1σ error per horizontal axis, `√((σ_lat² + σ_lon²)/2)`, or from the
/// error ellipse's axes when the latitude and longitude errors are empty (the
/// same trace). A GST without either is [`Sentence::Other`].
fn gst(fields: &[&str]) -> Result<Sentence, String> {
    let field = |k: usize| fields.get(k).copied().unwrap_or("");
    let time = field(1);
    let number = |k: usize| -> Result<Option<f64>, String> {
        let text = field(k);
        if text.is_empty() {
            return Ok(None);
        }
        text.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite() && *v >= 0.0)
            .map(Some)
            .ok_or_else(|| format!("GST field {k} {text:?} is not a σ in metres"))
    };
    let pair = match (number(6)?, number(7)?) {
        (Some(a), Some(b)) => Some((a, b)),
        _ => number(3)?.zip(number(4)?),
    };
    let (Some((a, b)), false) = (pair, time.is_empty()) else {
        return Ok(Sentence::Other);
    };
    let time = time_of_day(time)?;
    let sigma_m = a.hypot(b) / std::f64::consts::SQRT_2;
    // A σ of 0 is a receiver that does not know (as a driver's empty covariance).
    Ok(if sigma_m > 0.0 {
        Sentence::Gst { time, sigma_m }
    } else {
        Sentence::Other
    })
}

/// `$body*HH`: a sentence body (`GPGGA,...`, without `$`) with its
/// checksum, as a receiver writes it (tests, simulators, bridges).
pub fn with_checksum(body: &str) -> String {
    let sum = body.bytes().fold(0_u8, |a, b| a ^ b);
    format!("${body}*{sum:02X}")
}

/// The 1σ per axis of an epoch: its GST's, else its HDOP's (× [`HDOP_UERE_M`]).
pub fn epoch_sigma_m(gst_sigma_m: Option<f64>, hdop: Option<f64>) -> Option<f64> {
    gst_sigma_m.or(hdop.map(|h| h * HDOP_UERE_M))
}

/// Seconds since the Unix epoch of `time` on `date` (UTC).
pub fn unix_s(date: NaiveDate, time: NaiveTime) -> f64 {
    date.and_time(time).and_utc().timestamp() as f64
        + f64::from(time.nanosecond() % 1_000_000_000) * 1e-9
}

/// The UTC instant of a time of day read live: on the epoch's RMC date when
/// it sent one, else on the day (of the three around `utc_now_s`) that puts
/// it nearest `utc_now_s` (GGA carries the time of day only; a receiver's
/// fix is never hours old, so midnight is crossed the right way).
pub fn live_unix_s(time: NaiveTime, date: Option<NaiveDate>, utc_now_s: f64) -> Option<f64> {
    if let Some(d) = date {
        return Some(unix_s(d, time));
    }
    let today = DateTime::from_timestamp(utc_now_s.floor() as i64, 0)?.date_naive();
    [today.pred_opt(), Some(today), today.succ_opt()]
        .into_iter()
        .flatten()
        .map(|d| unix_s(d, time))
        .min_by(|a, b| (a - utc_now_s).abs().total_cmp(&(b - utc_now_s).abs()))
}

/// One epoch being gathered from a live stream.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Pending {
    time: NaiveTime,
    position: Option<Position>,
    /// The fix's altitude (GGA's) and HDOP, kept when an RMC of the same
    /// epoch follows.
    alt_m: Option<f64>,
    hdop: Option<f64>,
    date: Option<NaiveDate>,
    gst_sigma_m: Option<f64>,
    /// The receipt time of the epoch's first position sentence.
    receipt_s: Option<f64>,
    /// The epoch's UTC "now" at that receipt, to date a GGA without RMC.
    utc_now_s: f64,
    /// A GGA/RMC of this epoch said there is no fix.
    no_fix: bool,
}

/// A live epoch: the fix as a gpsd TPV report and when its first position
/// sentence arrived.
#[derive(Debug, Clone, PartialEq)]
pub struct Epoch {
    /// The epoch as gpsd would report it: mode 3 with an altitude, 2
    /// without, 1 when the receiver said it has no fix; the 1σ per axis as a
    /// 95 % estimate (`epx`/`epy` = 1.96 σ from GST, `eph` = 2.448 σ from
    /// HDOP), so that [`crate::Acceptance::sigma_m`] gives back the σ the
    /// offline reader gives the same sentences.
    pub tpv: Tpv,
    /// Receipt time (the caller's clock) of the epoch's first GGA/RMC.
    pub receipt_s: f64,
}

/// Gathers a live stream's sentences into epochs: a receiver sends an
/// epoch's GGA, RMC and GST in a burst, in an order of its own, with the
/// same time of day. An epoch is complete when a sentence of another time
/// arrives, or when the stream falls quiet ([`Self::flush`], called by the
/// reader after a pause shorter than the receiver's period).
#[derive(Debug, Clone, Default)]
pub struct EpochAssembler {
    pending: Option<Pending>,
    /// Sentences refused for a bad checksum or field, since the start.
    pub malformed: u64,
    /// Sentences other than GGA/RMC/GST, since the start.
    pub other: u64,
}

impl EpochAssembler {
    /// Feeds one line received at `receipt_s` (the caller's clock) when the
    /// UTC clock read `utc_now_s`; the epoch it completes, if any.
    ///
    /// # Errors
    /// The line's fault in words (the line is counted in
    /// [`Self::malformed`] and otherwise ignored).
    pub fn push(
        &mut self,
        line: &str,
        receipt_s: f64,
        utc_now_s: f64,
    ) -> Result<Option<Epoch>, String> {
        let sentence = match parse_sentence(line) {
            Ok(s) => s,
            Err(e) => {
                self.malformed += 1;
                return Err(e);
            }
        };
        let time = match sentence {
            Sentence::Other => {
                self.other += 1;
                return Ok(None);
            }
            Sentence::NoFix { time: None } => return Ok(None),
            Sentence::NoFix { time: Some(t) } => t,
            Sentence::Fix(p) => p.time,
            Sentence::Gst { time, .. } => time,
        };
        let done = match self.pending {
            Some(p) if p.time != time => self.flush(),
            _ => None,
        };
        let p = self.pending.get_or_insert(Pending {
            time,
            position: None,
            alt_m: None,
            hdop: None,
            date: None,
            gst_sigma_m: None,
            receipt_s: None,
            utc_now_s,
            no_fix: false,
        });
        match sentence {
            Sentence::Fix(pos) => {
                if p.receipt_s.is_none() {
                    p.receipt_s = Some(receipt_s);
                    p.utc_now_s = utc_now_s;
                }
                p.date = p.date.or(pos.date);
                p.hdop = p.hdop.or(pos.hdop);
                // GGA's position (with its altitude) over RMC's: the same
                // fix, but GGA's carries the altitude the mode needs.
                if pos.alt_m.is_some() || p.position.is_none() {
                    p.position = Some(pos);
                }
                p.alt_m = p.alt_m.or(pos.alt_m);
            }
            Sentence::NoFix { .. } => {
                p.no_fix = true;
                if p.receipt_s.is_none() {
                    p.receipt_s = Some(receipt_s);
                    p.utc_now_s = utc_now_s;
                }
            }
            Sentence::Gst { sigma_m, .. } => p.gst_sigma_m = Some(sigma_m),
            Sentence::Other => {}
        }
        Ok(done)
    }

    /// Completes the pending epoch, if it has a GGA/RMC (a GST alone is no fix).
    pub fn flush(&mut self) -> Option<Epoch> {
        let p = self.pending.take()?;
        let receipt_s = p.receipt_s?;
        let time_unix_s = live_unix_s(p.time, p.date, p.utc_now_s);
        let tpv = match p.position {
            Some(pos) if !p.no_fix => {
                let sigma = p.gst_sigma_m;
                let hdop_sigma = if sigma.is_none() {
                    epoch_sigma_m(None, p.hdop)
                } else {
                    None
                };
                Tpv {
                    mode: if p.alt_m.is_some() { 3 } else { 2 },
                    time_unix_s,
                    lat_deg: Some(pos.lat_deg),
                    lon_deg: Some(pos.lon_deg),
                    alt_m: p.alt_m,
                    eph_m: hdop_sigma.map(|s| s * HORIZONTAL_95_TO_SIGMA),
                    epx_m: sigma.map(|s| s * PER_AXIS_95_TO_SIGMA),
                    epy_m: sigma.map(|s| s * PER_AXIS_95_TO_SIGMA),
                    ept_s: None,
                }
            }
            _ => Tpv {
                mode: 1,
                time_unix_s,
                ..Tpv::default()
            },
        };
        Some(Epoch { tpv, receipt_s })
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::Acceptance;
    use proptest::prelude::*;

    use super::with_checksum as sentence;

    /// 15 Nov 2023 12:06:40 UTC.
    const T0: f64 = 1_700_050_000.0;

    fn feed(a: &mut EpochAssembler, lines: &[String], receipt_s: f64) -> Vec<Epoch> {
        lines
            .iter()
            .filter_map(|l| a.push(l, receipt_s, receipt_s).unwrap())
            .collect()
    }

    #[test]
    fn an_epochs_gga_rmc_and_gst_become_one_tpv_with_the_gst_sigma() {
        let mut a = EpochAssembler::default();
        let first = [
            sentence("GPRMC,120640.20,A,4809.0000000,N,01134.8000000,E,20.0,90.0,151123,,,A"),
            sentence("GPGSV,1,1,01,05,45,120,40"),
            sentence("GPGGA,120640.20,4809.0000000,N,01134.8000000,E,1,09,0.8,520.0,M,47.0,M,,"),
            sentence("GPGST,120640.20,2.0,1.7,1.1,30.0,1.2,1.6,2.5"),
        ];
        assert!(feed(&mut a, &first, T0 + 0.4).is_empty());
        // The next epoch's first sentence completes the first.
        let next = [sentence(
            "GPGGA,120641.20,4809.0010000,N,01134.8000000,E,1,09,1.5,520.0,M,47.0,M,,",
        )];
        let done = feed(&mut a, &next, T0 + 1.4);
        assert_eq!(done.len(), 1);
        let e = &done[0];
        assert_eq!(e.receipt_s, T0 + 0.4);
        assert_eq!(e.tpv.mode, 3);
        assert!((e.tpv.time_unix_s.unwrap() - (T0 + 0.2)).abs() < 1e-6);
        assert!((e.tpv.lat_deg.unwrap() - 48.15).abs() < 1e-12);
        assert_eq!(e.tpv.alt_m, Some(520.0));
        // √((1.2² + 1.6²)/2) = √2 m, as the offline reader gives it.
        let sigma = Acceptance::sigma_m(&e.tpv).unwrap();
        assert!((sigma - 2.0_f64.sqrt()).abs() < 1e-12, "{sigma}");
        // The second epoch has HDOP 1.5 only, and completes on a pause.
        let e = a.flush().unwrap();
        let sigma = Acceptance::sigma_m(&e.tpv).unwrap();
        assert!((sigma - 1.5 * HDOP_UERE_M).abs() < 1e-12, "{sigma}");
        assert!((e.tpv.time_unix_s.unwrap() - (T0 + 1.2)).abs() < 1e-6);
        assert_eq!(a.flush(), None);
        assert_eq!(a.other, 1);
    }

    #[test]
    fn a_gga_without_rmc_is_dated_by_the_clock_across_midnight() {
        let time = NaiveTime::from_hms_milli_opt(23, 59, 59, 800).unwrap();
        // The clock already reads 00:00:00.1 of 16 Nov: the fix is of 15 Nov.
        let midnight = NaiveDate::from_ymd_opt(2023, 11, 16)
            .unwrap()
            .and_hms_opt(0, 0, 0)
            .unwrap()
            .and_utc()
            .timestamp() as f64;
        let t = live_unix_s(time, None, midnight + 0.1).unwrap();
        assert!((t - (midnight - 0.2)).abs() < 1e-6, "{}", t - midnight);
        // And an early fix read just before midnight is of the next day.
        let early = NaiveTime::from_hms_milli_opt(0, 0, 0, 100).unwrap();
        let t = live_unix_s(early, None, midnight - 0.3).unwrap();
        assert!((t - (midnight + 0.1)).abs() < 1e-6);
    }

    #[test]
    fn a_receiver_without_a_fix_gives_mode_one_and_bad_lines_are_counted() {
        let mut a = EpochAssembler::default();
        let lines = [
            sentence("GPGGA,120642.20,,,,,0,00,,,M,,M,,"),
            sentence("GPRMC,120642.20,V,,,,,,,151123,,,N"),
        ];
        assert!(feed(&mut a, &lines, T0).is_empty());
        let e = a.flush().unwrap();
        assert_eq!(e.tpv.mode, 1);
        assert_eq!(e.tpv.lat_deg, None);
        let mut acceptance = Acceptance::new(120.0);
        assert!(acceptance.judge(&e.tpv, e.receipt_s).is_err());
        let damaged = "$GPRMC,120640.20,A,4809.0,N,01134.8,E,20.0,90.0,151123,,,A*00";
        assert!(a.push(damaged, T0, T0).unwrap_err().contains("checksum"));
        assert!(a.push("garbage", T0, T0).is_err());
        assert_eq!(a.malformed, 2);
        // A GST alone is no epoch.
        a.push(
            &sentence("GPGST,120643.00,2.0,1.7,1.1,30.0,1.2,1.6,2.5"),
            T0,
            T0,
        )
        .unwrap();
        assert_eq!(a.flush(), None);
    }

    #[test]
    fn angles_out_of_range_are_refused() {
        for body in [
            "GPGGA,120640.20,9509.0,N,01134.8,E,1,09,0.6,520.0,M,47.0,M,,",
            "GPGGA,120640.20,4860.5,N,01134.8,E,1,09,0.6,520.0,M,47.0,M,,",
            "GPGGA,120640.20,4809.0,N,18134.8,E,1,09,0.6,520.0,M,47.0,M,,",
            "GPGGA,120640.20,4809.0,X,01134.8,E,1,09,0.6,520.0,M,47.0,M,,",
            "GPGGA,120640.20,-809.0,N,01134.8,E,1,09,0.6,520.0,M,47.0,M,,",
        ] {
            assert!(parse_sentence(&sentence(body)).is_err(), "{body}");
        }
        let south_west = parse_sentence(&sentence(
            "GPGGA,120640.20,3354.0,S,07036.0,W,1,09,0.6,520.0,M,47.0,M,,",
        ))
        .unwrap();
        let Sentence::Fix(p) = south_west else {
            panic!("{south_west:?}")
        };
        assert!((p.lat_deg + 33.9).abs() < 1e-12 && (p.lon_deg + 70.6).abs() < 1e-12);
    }

    proptest! {
        #[test]
        fn no_line_panics_the_reader(line in ".{0,120}", checked in proptest::bool::ANY) {
            let line = if checked { sentence(line.trim_start_matches(['$', '!'])) } else { line };
            let mut a = EpochAssembler::default();
            let _ = a.push(&line, 0.0, T0);
            let _ = a.flush();
        }

        #[test]
        fn any_valid_gga_reads_back_its_position(lat in -89.99f64..89.99, lon in -179.99f64..179.99, hdop in 0.1f64..20.0) {
            let fmt = |v: f64, deg_digits: usize| {
                let a = v.abs();
                let d = a.floor();
                format!("{:0w$}{:010.7}", d as u32, (a - d) * 60.0, w = deg_digits)
            };
            let body = format!(
                "GPGGA,101010.00,{},{},{},{},1,08,{hdop:.2},100.0,M,0,M,,",
                fmt(lat, 2), if lat < 0.0 { "S" } else { "N" },
                fmt(lon, 3), if lon < 0.0 { "W" } else { "E" },
            );
            let Ok(Sentence::Fix(p)) = parse_sentence(&sentence(&body)) else {
                return Err(TestCaseError::fail(body));
            };
            prop_assert!((p.lat_deg - lat).abs() < 1e-8 && (p.lon_deg - lon).abs() < 1e-8, "{body}");
        }
    }
}
