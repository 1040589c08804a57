//! `[gnss]` (#46): a live GNSS source beside the bus's own fixes
//! (`[calibration.fixes]`): gpsd on TCP, or a ROS 2 `sensor_msgs/NavSatFix`
//! topic. Off unless the section is written.

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

/// Where live fixes come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum GnssSource {
    /// gpsd's JSON protocol over TCP.
    Gpsd {
        /// gpsd's `host:port`.
        address: String,
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
    /// `max(epx, epy)`, else `eph`; a NavSatFix's 2.448 σ of its covariance).
    pub max_error_m: f64,
}

/// `[gnss]` as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawGnss {
    source: String,
    address: Option<String>,
    topic: Option<String>,
    max_error_m: Option<f64>,
}

impl Validator<'_> {
    /// `[gnss]`: each key checked against the source it belongs to.
    pub(super) fn gnss(&self, raw: Option<&RawGnss>) -> Result<Option<GnssConfig>, ConfigError> {
        let Some(raw) = raw else { return Ok(None) };
        let max_error_m = self.positive(
            "gnss.max_error_m",
            raw.max_error_m.unwrap_or(DEFAULT_MAX_ERROR_M),
        )?;
        let only = |key: &str, source: &str| {
            self.err(
                key,
                &format!("no `{key}` with this source (it belongs to source = \"{source}\")"),
                format!("source = {:?}", raw.source),
            )
        };
        let source = match raw.source.as_str() {
            "gpsd" => {
                if raw.topic.is_some() {
                    return Err(only("gnss.topic", "ros2"));
                }
                let address = raw.address.as_deref().unwrap_or(DEFAULT_GPSD_ADDRESS);
                if !valid_address(address) {
                    return Err(self.err(
                        "gnss.address",
                        "\"HOST:PORT\" with a port 1..65535 (default \"localhost:2947\")",
                        format!("{address:?}"),
                    ));
                }
                GnssSource::Gpsd {
                    address: address.to_owned(),
                }
            }
            "ros2" => {
                if raw.address.is_some() {
                    return Err(only("gnss.address", "gpsd"));
                }
                let topic = raw.topic.as_deref().unwrap_or_default();
                if !valid_topic(topic) {
                    return Err(self.err(
                        "gnss.topic",
                        "a ROS 2 topic name of a sensor_msgs/NavSatFix, e.g. \"/fix\"",
                        format!("{topic:?}"),
                    ));
                }
                GnssSource::Ros2 {
                    topic: topic.to_owned(),
                }
            }
            other => {
                return Err(self.err("gnss.source", "\"gpsd\" or \"ros2\"", format!("{other:?}")));
            }
        };
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
