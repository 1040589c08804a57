//! gpsd's JSON protocol (pure): one JSON object per line, told apart by `class`.
//!
//! Only what canodom needs is decoded: TPV (time-position-velocity) fields
//! `mode`, `time`, `lat`, `lon`, `alt`, `eph`, `epx`, `epy`, `ept`. VERSION,
//! DEVICES, WATCH and SKY are recognised (so a log can say what gpsd is), any
//! other class and any unknown field are ignored: gpsd adds fields between
//! releases and a newer gpsd must not break canodom.

use crate::Error;
use serde_json::{Map, Value};

/// The command that makes gpsd stream JSON reports.
pub const WATCH_COMMAND: &str = "?WATCH={\"enable\":true,\"json\":true};\n";

/// One decoded line from gpsd.
#[derive(Debug, Clone, PartialEq)]
pub enum Message {
    /// gpsd's banner: its release.
    Version {
        /// gpsd's release string (`"3.25"`).
        release: String,
    },
    /// The devices gpsd reads (their paths).
    Devices(Vec<String>),
    /// gpsd acknowledged `?WATCH`; `enable` as it reports it.
    Watch {
        /// Whether streaming is on.
        enable: bool,
    },
    /// A time-position-velocity report.
    Tpv(Tpv),
    /// A sky view; counted, not used (its `hdop` is not read: TPV has the estimates).
    Sky,
    /// Any other class (ERROR, PPS, TOFF, ATT, ...), ignored.
    Other(String),
}

/// A TPV report, fields as gpsd sends them (metres, degrees, seconds).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Tpv {
    /// Fix mode: 0 unknown, 1 no fix, 2 2-D, 3 3-D.
    pub mode: u8,
    /// GNSS time as seconds since the Unix epoch (UTC), if sent.
    pub time_unix_s: Option<f64>,
    /// Latitude, degrees.
    pub lat_deg: Option<f64>,
    /// Longitude, degrees.
    pub lon_deg: Option<f64>,
    /// Altitude, metres.
    pub alt_m: Option<f64>,
    /// Horizontal position error estimate, metres (gpsd: 95 % confidence).
    pub eph_m: Option<f64>,
    /// Longitude error estimate, metres (gpsd: 95 % confidence).
    pub epx_m: Option<f64>,
    /// Latitude error estimate, metres (gpsd: 95 % confidence).
    pub epy_m: Option<f64>,
    /// Time error estimate, seconds (gpsd: 95 % confidence).
    pub ept_s: Option<f64>,
}

fn malformed(line: &str, reason: impl Into<String>) -> Error {
    Error::Malformed {
        line: line.chars().take(200).collect(),
        reason: reason.into(),
    }
}

/// A finite number under `key`, or `None` when absent or not a number.
///
/// A non-numeric value is treated as absent rather than an error: gpsd never
/// sends one, and a fix without that field is then judged by [`crate::accept`].
fn number(obj: &Map<String, Value>, key: &str) -> Option<f64> {
    obj.get(key)
        .and_then(Value::as_f64)
        .filter(|v| v.is_finite())
}

/// Decodes one line from gpsd.
///
/// # Errors
/// [`Error::Malformed`] (naming the line) when it is not a JSON object with a
/// string `class`, or a TPV without an integer `mode` 0–3;
/// [`Error::BadTime`] when a TPV's `time` is not ISO 8601 UTC.
pub fn parse_line(line: &str) -> Result<Message, Error> {
    let value: Value =
        serde_json::from_str(line.trim()).map_err(|e| malformed(line, e.to_string()))?;
    let Value::Object(obj) = value else {
        return Err(malformed(line, "not a JSON object"));
    };
    let Some(class) = obj.get("class").and_then(Value::as_str) else {
        return Err(malformed(line, "no string \"class\""));
    };
    Ok(match class {
        "VERSION" => Message::Version {
            release: obj
                .get("release")
                .and_then(Value::as_str)
                .unwrap_or_default()
                .to_owned(),
        },
        "DEVICES" => Message::Devices(
            obj.get("devices")
                .and_then(Value::as_array)
                .map(|devices| {
                    devices
                        .iter()
                        .filter_map(|d| d.get("path").and_then(Value::as_str))
                        .map(str::to_owned)
                        .collect()
                })
                .unwrap_or_default(),
        ),
        "WATCH" => Message::Watch {
            enable: obj.get("enable").and_then(Value::as_bool).unwrap_or(false),
        },
        "SKY" => Message::Sky,
        "TPV" => Message::Tpv(parse_tpv(line, &obj)?),
        other => Message::Other(other.to_owned()),
    })
}

fn parse_tpv(line: &str, obj: &Map<String, Value>) -> Result<Tpv, Error> {
    let mode = obj
        .get("mode")
        .and_then(Value::as_u64)
        .filter(|m| *m <= 3)
        .ok_or_else(|| malformed(line, "TPV without an integer \"mode\" 0-3"))?;
    let time_unix_s = match obj.get("time").and_then(Value::as_str) {
        Some(t) => Some(parse_iso8601_utc(t)?),
        None => None,
    };
    Ok(Tpv {
        mode: mode as u8,
        time_unix_s,
        lat_deg: number(obj, "lat"),
        lon_deg: number(obj, "lon"),
        alt_m: number(obj, "alt"),
        eph_m: number(obj, "eph"),
        epx_m: number(obj, "epx"),
        epy_m: number(obj, "epy"),
        ept_s: number(obj, "ept"),
    })
}

/// Parses gpsd's `YYYY-MM-DDTHH:MM:SS[.fff]Z` into seconds since the Unix
/// epoch (a leap second `:60` as the second after `:59`), with chrono's
/// RFC 3339 parser held to what gpsd writes: UTC as `Z`, an upper-case `T`,
/// at most nanoseconds.
///
/// # Errors
/// [`Error::BadTime`] for anything else.
pub fn parse_iso8601_utc(text: &str) -> Result<f64, Error> {
    let bad = || Error::BadTime(text.chars().take(64).collect());
    let body = text.strip_suffix('Z').ok_or_else(bad)?;
    let fraction_digits = body.split_once('.').map_or(0, |(_, f)| f.len());
    if body.as_bytes().get(10) != Some(&b'T') || fraction_digits > 9 {
        return Err(bad());
    }
    let time = chrono::DateTime::parse_from_rfc3339(text).map_err(|_| bad())?;
    Ok(time.timestamp() as f64 + f64::from(time.timestamp_subsec_nanos()) / 1e9)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn tpv_fields_are_decoded_and_unknown_fields_ignored() {
        let line = r#"{"class":"TPV","device":"/dev/pts/3","mode":3,"time":"2024-05-01T12:00:01.500Z","ept":0.005,"lat":48.1234567,"lon":11.5,"alt":520.5,"epx":3.1,"epy":4.2,"eph":5.0,"speed":1.0,"new_field":[1,2]}"#;
        let Message::Tpv(t) = parse_line(line).expect("valid TPV") else {
            panic!("not a TPV");
        };
        assert_eq!(t.mode, 3);
        assert_eq!(t.lat_deg, Some(48.123_456_7));
        assert_eq!(t.lon_deg, Some(11.5));
        assert_eq!(t.alt_m, Some(520.5));
        assert_eq!(
            (t.epx_m, t.epy_m, t.eph_m, t.ept_s),
            (Some(3.1), Some(4.2), Some(5.0), Some(0.005))
        );
        assert_eq!(t.time_unix_s, Some(1_714_564_801.5));
    }

    #[test]
    fn other_classes_are_recognised() {
        assert_eq!(
            parse_line(r#"{"class":"VERSION","release":"3.25","proto_major":3}"#).ok(),
            Some(Message::Version {
                release: "3.25".into()
            })
        );
        assert_eq!(
            parse_line(
                r#"{"class":"DEVICES","devices":[{"class":"DEVICE","path":"/dev/ttyACM0"}]}"#
            )
            .ok(),
            Some(Message::Devices(vec!["/dev/ttyACM0".into()]))
        );
        assert_eq!(
            parse_line(r#"{"class":"WATCH","enable":true,"json":true}"#).ok(),
            Some(Message::Watch { enable: true })
        );
        assert_eq!(
            parse_line(r#"{"class":"SKY","satellites":[]}"#).ok(),
            Some(Message::Sky)
        );
        assert_eq!(
            parse_line(r#"{"class":"PPS"}"#).ok(),
            Some(Message::Other("PPS".into()))
        );
    }

    #[test]
    fn malformed_lines_are_errors_naming_the_line() {
        for line in [
            "",
            "not json",
            "[1,2]",
            r#"{"mode":3}"#,
            r#"{"class":"TPV"}"#,
            r#"{"class":"TPV","mode":7}"#,
        ] {
            let err = parse_line(line).expect_err(line);
            assert!(matches!(err, Error::Malformed { .. }), "{line}: {err}");
            assert!(err.to_string().contains(&format!("{line:?}")), "{err}");
        }
        assert!(matches!(
            parse_line(r#"{"class":"TPV","mode":3,"time":"yesterday"}"#),
            Err(Error::BadTime(_))
        ));
    }

    #[test]
    fn epoch_and_known_dates() {
        assert_eq!(parse_iso8601_utc("1970-01-01T00:00:00Z").ok(), Some(0.0));
        assert_eq!(
            parse_iso8601_utc("2000-03-01T00:00:00.000Z").ok(),
            Some(951_868_800.0)
        );
        assert!(parse_iso8601_utc("2000-03-01T00:00:00").is_err());
        assert!(parse_iso8601_utc("2000-13-01T00:00:00Z").is_err());
        // A leap second, and what gpsd never writes.
        assert_eq!(
            parse_iso8601_utc("2016-12-31T23:59:60.5Z").ok(),
            Some(1_483_228_800.5)
        );
        for other in [
            "2024-05-01T12:00:01+01:00",
            "2024-05-01 12:00:01Z",
            "2024-05-01t12:00:01Z",
            "2024-05-01T12:00:01.1234567891Z",
            "2024-05-01T12:00:1Z",
        ] {
            assert!(parse_iso8601_utc(other).is_err(), "{other}");
        }
    }

    proptest! {
        #[test]
        fn no_line_panics(line in ".{0,300}") {
            let _ = parse_line(&line);
        }

        #[test]
        fn times_round_trip(secs in 0i64..4_102_444_800, millis in 0u32..1000) {
            let text = chrono::DateTime::from_timestamp(secs, millis * 1_000_000)
                .expect("a time of this century")
                .format("%Y-%m-%dT%H:%M:%S%.3fZ")
                .to_string();
            let parsed = parse_iso8601_utc(&text).expect("formatted time");
            prop_assert!((parsed - (secs as f64 + f64::from(millis) / 1000.0)).abs() < 1e-6, "{text}");
        }

        #[test]
        fn tpv_numbers_survive(lat in -90.0f64..90.0, lon in -180.0f64..180.0, epx in 0.0f64..1e4, mode in 0u8..4) {
            let line = format!(r#"{{"class":"TPV","mode":{mode},"lat":{lat},"lon":{lon},"epx":{epx}}}"#);
            let Ok(Message::Tpv(t)) = parse_line(&line) else { return Err(TestCaseError::fail(line)); };
            prop_assert_eq!(t.mode, mode);
            // serde_json's default float parser may be one ulp off (no `float_roundtrip`):
            // 1e-12° is 0.1 µm, far below gpsd's 9 decimals.
            let close = |got: Option<f64>, want: f64| got.is_some_and(|g| (g - want).abs() <= 1e-12 * want.abs().max(1.0));
            prop_assert!(close(t.lat_deg, lat));
            prop_assert!(close(t.lon_deg, lon));
            prop_assert!(close(t.epx_m, epx));
        }
    }
}
