//! `[gnss]` (#46): a live GNSS source beside the bus's own fixes
//! (`[calibration.fixes]`): gpsd on TCP, a receiver's NMEA on a serial port
//! read directly, or a ROS 2 `sensor_msgs/NavSatFix` topic. Off unless the
//! section is written.

use super::ConfigError;
use super::validator::Validator;
use serde::Deserialize;

/// gpsd's address when `[gnss] address` is not given (gpsd's own default port).
pub const DEFAULT_GPSD_ADDRESS: &str = "localhost:2947";

/// The largest 95 % horizontal error estimate a fix may state, metres, when
/// `[gnss] max_error_m` is not given.
///
/// Why 120 m, when a consumer receiver is good to a few metres: the limit is
/// compared with what gpsd reports, and for a receiver that speaks NMEA only
/// (most USB receivers) gpsd has no error estimate from it and derives
/// `eph` from the HDOP times its UERE, `eph = HDOP × 19 m` (gpsd 3.22,
/// `P_UERE_NO_DGPS`). Measured under gpsfake (`gnss/tests/gpsfake.sh`):
/// NMEA with HDOP 3.0, which the simulated receiver of σ 1.5 m writes
/// (`sim/multibody/fixes.py`: HDOP = σ / 0.5 m), comes out as `eph` 57 m and
/// no `epx`/`epy`; so the former 25 m limit refused every one of them
/// (it would pass HDOP ≤ 1.3 only). 120 m passes HDOP ≤ 6.3: ordinary
/// fixes, σ 1–3 m on that scale, open sky to a street with trees; and it
/// refuses fixes of poor geometry (HDOP ≥ 6.4, e.g. four satellites in an
/// urban canyon, where HDOP 10–20 gives `eph` 190–380 m). A receiver that
/// reports its own estimate (GST sentences, u-blox binary: `epx`/`epy` of a
/// few metres) is then hardly limited: lower `max_error_m` for it.
pub const DEFAULT_MAX_ERROR_M: f64 = 120.0;

/// The default `max_error_m` of a receiver read directly (`source =
/// "nmea"`), metres: there the 95 % estimate is canodom's own, 2.448 σ with
/// σ = HDOP × 2.1 m (or the receiver's GST σ), not gpsd's `HDOP × 19 m`; 32 m
/// passes HDOP ≤ 6.3 as gpsd's default does (`canodom_gnss::serial`'s
/// default, which a test of the daemon checks).
pub const DEFAULT_NMEA_MAX_ERROR_M: f64 = 32.0;

/// The baud rates `[gnss] baud` takes (termios's standard rates from 4800).
pub const NMEA_BAUD_RATES: [u32; 9] = [
    4800, 9600, 19_200, 38_400, 57_600, 115_200, 230_400, 460_800, 921_600,
];

/// Where live fixes come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum GnssSource {
    /// gpsd's JSON protocol over TCP.
    Gpsd {
        /// gpsd's `host:port`.
        address: String,
    },
    /// A receiver's NMEA 0183 (GGA, RMC, GST) read from a serial device,
    /// without gpsd.
    Nmea {
        /// The device, absolute (`/dev/ttyACM0`; `/dev/serial/by-id/...`
        /// keeps its name across replugs).
        device: std::path::PathBuf,
        /// The baud rate set on it; `None` leaves the device's (a USB
        /// CDC-ACM receiver ignores it).
        baud: Option<u32>,
    },
    /// A ROS 2 `sensor_msgs/NavSatFix` topic (the domain, discovery and
    /// namespace are `[ros2]`'s).
    Ros2 {
        /// The ROS 2 topic name, e.g. `/fix`.
        topic: String,
    },
}

/// The validated `[gnss]` section.
#[derive(Clone, Debug, PartialEq)]
pub struct GnssConfig {
    /// The source.
    pub source: GnssSource,
    /// Largest accepted 95 % horizontal error estimate, metres (gpsd's
    /// `max(epx, epy)`, else `eph`; a NavSatFix's 2.448 σ of its covariance;
    /// a serial receiver's 1.96 σ of its GST, else 2.448 × HDOP × 2.1 m).
    pub max_error_m: f64,
}

/// `[gnss]` as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawGnss {
    source: String,
    address: Option<String>,
    topic: Option<String>,
    device: Option<String>,
    baud: Option<u32>,
    max_error_m: Option<f64>,
}

impl Validator<'_> {
    /// `[gnss]`: each key checked against the source it belongs to.
    pub(super) fn gnss(&self, raw: Option<&RawGnss>) -> Result<Option<GnssConfig>, ConfigError> {
        let Some(raw) = raw else { return Ok(None) };
        let only = |key: &str, source: &str| {
            self.err(
                key,
                &format!("no `{key}` with this source (it belongs to source = \"{source}\")"),
                format!("source = {:?}", raw.source),
            )
        };
        // Each key belongs to one source.
        let owners = [
            ("gnss.address", raw.address.is_some(), "gpsd"),
            ("gnss.device", raw.device.is_some(), "nmea"),
            ("gnss.baud", raw.baud.is_some(), "nmea"),
            ("gnss.topic", raw.topic.is_some(), "ros2"),
        ];
        if ["gpsd", "nmea", "ros2"].contains(&raw.source.as_str())
            && let Some((key, _, owner)) = owners
                .iter()
                .find(|(_, given, owner)| *given && *owner != raw.source)
        {
            return Err(only(key, owner));
        }
        let (source, default_max_error_m) = match raw.source.as_str() {
            "gpsd" => {
                let address = raw.address.as_deref().unwrap_or(DEFAULT_GPSD_ADDRESS);
                if !valid_address(address) {
                    return Err(self.err(
                        "gnss.address",
                        "\"HOST:PORT\" with a port 1..65535 (default \"localhost:2947\")",
                        format!("{address:?}"),
                    ));
                }
                let source = GnssSource::Gpsd {
                    address: address.to_owned(),
                };
                (source, DEFAULT_MAX_ERROR_M)
            }
            "nmea" => {
                let device = raw.device.as_deref().unwrap_or_default();
                if !device.starts_with('/') || device.ends_with('/') {
                    return Err(self.err(
                        "gnss.device",
                        "the receiver's device, an absolute path such as \"/dev/ttyACM0\" \
                         (\"/dev/serial/by-id/...\" keeps its name across replugs)",
                        format!("{device:?}"),
                    ));
                }
                if let Some(b) = raw.baud.filter(|b| !NMEA_BAUD_RATES.contains(b)) {
                    return Err(self.err(
                        "gnss.baud",
                        &format!("one of {NMEA_BAUD_RATES:?} (or no `baud`: the device's own)"),
                        b.to_string(),
                    ));
                }
                let source = GnssSource::Nmea {
                    device: std::path::PathBuf::from(device),
                    baud: raw.baud,
                };
                (source, DEFAULT_NMEA_MAX_ERROR_M)
            }
            "ros2" => {
                let topic = raw.topic.as_deref().unwrap_or_default();
                if !valid_topic(topic) {
                    return Err(self.err(
                        "gnss.topic",
                        "a ROS 2 topic name of a sensor_msgs/NavSatFix, e.g. \"/fix\"",
                        format!("{topic:?}"),
                    ));
                }
                let source = GnssSource::Ros2 {
                    topic: topic.to_owned(),
                };
                (source, DEFAULT_MAX_ERROR_M)
            }
            other => {
                return Err(self.err(
                    "gnss.source",
                    "\"gpsd\", \"nmea\" (a serial receiver) or \"ros2\"",
                    format!("{other:?}"),
                ));
            }
        };
        let max_error_m = self.positive(
            "gnss.max_error_m",
            raw.max_error_m.unwrap_or(default_max_error_m),
        )?;
        Ok(Some(GnssConfig {
            source,
            max_error_m,
        }))
    }
}

/// `HOST:PORT` (a bracketed IPv6 host too) with a non-zero port; the host is
/// resolved when connecting, so a name that does not resolve yet is allowed.
fn valid_address(address: &str) -> bool {
    address.rsplit_once(':').is_some_and(|(host, port)| {
        !host.trim().is_empty() && port.parse::<u16>().is_ok_and(|p| p > 0)
    })
}

/// A ROS 2 topic name: segments of letters, digits and `_`, none starting
/// with a digit (ROS 2's rule; `canodom-ros2` checks it again when it subscribes).
fn valid_topic(topic: &str) -> bool {
    !topic.is_empty()
        && !topic.ends_with('/')
        && !topic.contains("//")
        && topic
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '/')
        && !topic
            .split('/')
            .any(|seg| seg.starts_with(|c: char| c.is_ascii_digit()))
}
