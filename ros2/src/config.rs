//! The `[ros2]` section: off by default; domain id, node name and namespace,
//! topic names, frame ids (REP-105), QoS, discovery range. The domain id and
//! the discovery range are read from the environment as ROS 2 reads them
//! (`ROS_DOMAIN_ID`, `ROS_AUTOMATIC_DISCOVERY_RANGE`, the older
//! `ROS_LOCALHOST_ONLY`) when the section does not set them.

use crate::{Error, Result};
use serde::Deserialize;

/// The highest domain id whose ports fit in 16 bits (7400 + 250·d + 10 + 2·i).
pub const MAX_DOMAIN_ID: u16 = 232;

/// Which QoS the publishers offer.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum QosProfile {
    /// ROS 2's default: reliable, volatile, keep last 10. Reliable and
    /// best-effort subscribers both match it.
    #[default]
    Default,
    /// ROS 2's sensor-data profile: best effort, volatile, keep last 5. Only
    /// best-effort subscribers match it.
    SensorData,
}

/// Whom discovery reaches.
#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum DiscoveryRange {
    /// This host only: the loopback interface, no multicast, discovery
    /// announced to the well-known unicast ports on 127.0.0.1 (ROS 2's
    /// `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`). Nothing is sent but to
    /// 127.0.0.1.
    Localhost,
    /// ROS 2's usual discovery: multicast on the host's interfaces.
    Subnet,
}

/// The `[ros2]` section as written.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct Ros2Config {
    /// Publish at all (default false).
    pub enabled: bool,
    /// The DDS domain (default: `ROS_DOMAIN_ID`, else 0).
    pub domain_id: Option<u16>,
    /// Discovery range (default: `ROS_AUTOMATIC_DISCOVERY_RANGE` or
    /// `ROS_LOCALHOST_ONLY`, else subnet).
    pub discovery: Option<DiscoveryRange>,
    /// The node's name (default `canodom`).
    pub node_name: String,
    /// The node's namespace (default `/`): relative topic names go in it.
    pub namespace: String,
    /// `nav_msgs/Odometry` topic (default `odom`, in the namespace).
    pub odom_topic: String,
    /// `tf2_msgs/TFMessage` topic (default `/tf`).
    pub tf_topic: String,
    /// `diagnostic_msgs/DiagnosticArray` topic (default `/diagnostics`).
    pub diagnostics_topic: String,
    /// A `sensor_msgs/NavSatFix` topic to take fixes from (default none).
    pub fix_topic: Option<String>,
    /// The pose's fixed frame (default `odom`).
    pub odom_frame: String,
    /// The vehicle's frame (default `base_link`).
    pub base_frame: String,
    /// QoS of `/odom` (default: ROS 2's default). `/tf` and `/diagnostics`
    /// are always reliable (as `tf2_ros` and `diagnostic_updater` publish
    /// them), keep last 100 and 10.
    pub qos: QosProfile,
    /// Poses queued for the DDS thread at most; more are dropped and counted
    /// (default 64).
    pub queue: usize,
    /// Bytes of a GID on ROS 2's graph topic `ros_discovery_info`: 16 for
    /// Iron and later (Jazzy, the default), 24 for Humble. Only the tools'
    /// view of the node (`ros2 node list`) depends on it, not the topics.
    pub graph_gid_bytes: u8,
}

impl Default for Ros2Config {
    fn default() -> Self {
        Self {
            enabled: false,
            domain_id: None,
            discovery: None,
            node_name: "canodom".to_owned(),
            namespace: "/".to_owned(),
            odom_topic: "odom".to_owned(),
            tf_topic: "/tf".to_owned(),
            diagnostics_topic: "/diagnostics".to_owned(),
            fix_topic: None,
            odom_frame: "odom".to_owned(),
            base_frame: "base_link".to_owned(),
            qos: QosProfile::Default,
            queue: 64,
            graph_gid_bytes: 16,
        }
    }
}

/// A configuration checked and completed from the environment.
#[derive(Clone, Debug, PartialEq)]
pub struct Resolved {
    /// The DDS domain.
    pub domain_id: u16,
    /// Whom discovery reaches.
    pub discovery: DiscoveryRange,
    /// The node's name.
    pub node_name: String,
    /// The node's namespace (absolute, no trailing `/` but for `/` itself).
    pub namespace: String,
    /// DDS topic of the odometry (`rt/odom`).
    pub odom_topic: String,
    /// DDS topic of the transforms (`rt/tf`).
    pub tf_topic: String,
    /// DDS topic of the diagnostics (`rt/diagnostics`).
    pub diagnostics_topic: String,
    /// DDS topic of the fixes taken, if any.
    pub fix_topic: Option<String>,
    /// Frame names.
    pub frames: crate::msg::Frames,
    /// `/odom`'s QoS.
    pub qos: QosProfile,
    /// The queue's capacity.
    pub queue: usize,
    /// A GID's size on the graph topic.
    pub graph_gid_bytes: crate::msg::GidBytes,
}

/// Whether `name` is a valid ROS 2 name segment list (letters, digits, `_`, `/`).
fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '/')
        && !name.contains("//")
        && !name
            .split('/')
            .any(|seg| seg.starts_with(|c: char| c.is_ascii_digit()))
}

/// The DDS topic of ROS 2 topic `name` in `namespace`: `rt` then the fully
/// qualified name (a relative name goes in the namespace).
///
/// # Errors
/// A name ROS 2 would refuse.
pub fn dds_topic(namespace: &str, name: &str) -> Result<String> {
    let bad = || {
        Error::Config(format!(
            "[ros2]: topic name `{name}` is not a valid ROS 2 name"
        ))
    };
    if !valid_name(name) || name.ends_with('/') {
        return Err(bad());
    }
    let full = if name.starts_with('/') {
        name.to_owned()
    } else if namespace == "/" {
        format!("/{name}")
    } else {
        format!("{namespace}/{name}")
    };
    Ok(format!("rt{full}"))
}

impl Ros2Config {
    /// The `[ros2]` section as the pipeline's configuration keeps it (its
    /// defaults without one).
    ///
    /// # Errors
    /// An unknown key, a value of the wrong type.
    pub fn from_section(section: Option<&toml::Table>) -> Result<Self> {
        match section {
            None => Ok(Self::default()),
            Some(table) => toml::Value::Table(table.clone())
                .try_into()
                .map_err(|e| Error::Config(format!("[ros2]: {e}"))),
        }
    }

    /// The configuration completed from the process's environment.
    ///
    /// # Errors
    /// As [`Self::resolve_with`].
    pub fn resolve(&self) -> Result<Resolved> {
        self.resolve_with(|k| std::env::var(k).ok())
    }

    /// The configuration completed from the environment `env` gives.
    ///
    /// # Errors
    /// A domain id past [`MAX_DOMAIN_ID`], an invalid name, namespace or
    /// frame, an empty queue, an environment variable ROS 2 would refuse.
    pub fn resolve_with(&self, env: impl Fn(&str) -> Option<String>) -> Result<Resolved> {
        let domain_id = match (self.domain_id, env("ROS_DOMAIN_ID")) {
            (Some(d), _) => d,
            (None, Some(text)) if !text.trim().is_empty() => text
                .trim()
                .parse::<u16>()
                .map_err(|_| Error::Config(format!("ROS_DOMAIN_ID `{text}` is not a domain id")))?,
            (None, _) => 0,
        };
        if domain_id > MAX_DOMAIN_ID {
            return Err(Error::Config(format!(
                "[ros2] domain id {domain_id} is past {MAX_DOMAIN_ID}, the last whose ports fit"
            )));
        }
        let discovery = match self.discovery {
            Some(d) => d,
            None => match env("ROS_AUTOMATIC_DISCOVERY_RANGE")
                .map(|s| s.trim().to_ascii_uppercase())
                .as_deref()
            {
                Some("LOCALHOST") => DiscoveryRange::Localhost,
                Some("SUBNET" | "SYSTEM_DEFAULT" | "") | None => {
                    if env("ROS_LOCALHOST_ONLY").as_deref().map(str::trim) == Some("1") {
                        DiscoveryRange::Localhost
                    } else {
                        DiscoveryRange::Subnet
                    }
                }
                Some(other) => {
                    return Err(Error::Config(format!(
                        "ROS_AUTOMATIC_DISCOVERY_RANGE `{other}`: canodom knows LOCALHOST, \
                         SUBNET and SYSTEM_DEFAULT"
                    )));
                }
            },
        };
        let namespace = if self.namespace == "/" {
            "/".to_owned()
        } else {
            let ns = self.namespace.trim_end_matches('/');
            if !ns.starts_with('/') || !valid_name(ns) {
                return Err(Error::Config(format!(
                    "[ros2] namespace `{}` is not an absolute ROS 2 name",
                    self.namespace
                )));
            }
            ns.to_owned()
        };
        if !valid_name(&self.node_name) || self.node_name.contains('/') {
            return Err(Error::Config(format!(
                "[ros2] node name `{}` is not a valid ROS 2 node name",
                self.node_name
            )));
        }
        for frame in [&self.odom_frame, &self.base_frame] {
            if frame.is_empty() || frame.contains(char::is_whitespace) {
                return Err(Error::Config(format!(
                    "[ros2] frame id `{frame}` is empty or has a space"
                )));
            }
        }
        let graph_gid_bytes = match self.graph_gid_bytes {
            16 => crate::msg::GidBytes::Sixteen,
            24 => crate::msg::GidBytes::TwentyFour,
            other => {
                return Err(Error::Config(format!(
                    "[ros2] graph_gid_bytes {other}: ROS 2 has 16 (Iron and later) or 24 (Humble)"
                )));
            }
        };
        if self.queue == 0 {
            return Err(Error::Config(
                "[ros2] queue must hold at least 1 pose".into(),
            ));
        }
        Ok(Resolved {
            domain_id,
            discovery,
            node_name: self.node_name.clone(),
            odom_topic: dds_topic(&namespace, &self.odom_topic)?,
            tf_topic: dds_topic(&namespace, &self.tf_topic)?,
            diagnostics_topic: dds_topic(&namespace, &self.diagnostics_topic)?,
            fix_topic: self
                .fix_topic
                .as_deref()
                .map(|t| dds_topic(&namespace, t))
                .transpose()?,
            namespace,
            frames: crate::msg::Frames {
                odom: self.odom_frame.clone(),
                base: self.base_frame.clone(),
            },
            qos: self.qos,
            queue: self.queue,
            graph_gid_bytes,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn no_env(_: &str) -> Option<String> {
        None
    }

    #[test]
    fn defaults_are_ros2s_names() {
        let r = Ros2Config::default().resolve_with(no_env).expect("valid");
        assert_eq!(r.domain_id, 0);
        assert_eq!(r.discovery, DiscoveryRange::Subnet);
        assert_eq!(r.odom_topic, "rt/odom");
        assert_eq!(r.tf_topic, "rt/tf");
        assert_eq!(r.diagnostics_topic, "rt/diagnostics");
        assert_eq!(r.frames.odom, "odom");
        assert_eq!(r.frames.base, "base_link");
        assert!(!Ros2Config::default().enabled);
    }

    #[test]
    fn relative_names_go_in_the_namespace() {
        assert_eq!(dds_topic("/car1", "odom").expect("ok"), "rt/car1/odom");
        assert_eq!(dds_topic("/car1", "/tf").expect("ok"), "rt/tf");
        assert!(dds_topic("/", "odom/").is_err());
        assert!(dds_topic("/", "o dom").is_err());
        assert!(dds_topic("/", "1odom").is_err());
        let c: Ros2Config =
            toml::from_str("namespace = \"/car1/\"\nodom_topic = \"wheel/odom\"").expect("parses");
        assert_eq!(
            c.resolve_with(no_env).expect("ok").odom_topic,
            "rt/car1/wheel/odom"
        );
    }

    #[test]
    fn the_environment_is_read_as_ros2_reads_it_and_the_file_wins() {
        let env = |k: &str| match k {
            "ROS_DOMAIN_ID" => Some("42".to_owned()),
            "ROS_AUTOMATIC_DISCOVERY_RANGE" => Some("localhost".to_owned()),
            _ => None,
        };
        let r = Ros2Config::default().resolve_with(env).expect("ok");
        assert_eq!((r.domain_id, r.discovery), (42, DiscoveryRange::Localhost));
        let c: Ros2Config =
            toml::from_str("domain_id = 7\ndiscovery = \"subnet\"").expect("parses");
        let r = c.resolve_with(env).expect("ok");
        assert_eq!((r.domain_id, r.discovery), (7, DiscoveryRange::Subnet));
        let old = |k: &str| (k == "ROS_LOCALHOST_ONLY").then(|| "1".to_owned());
        let r = Ros2Config::default().resolve_with(old).expect("ok");
        assert_eq!(r.discovery, DiscoveryRange::Localhost);
        let bad = |k: &str| (k == "ROS_DOMAIN_ID").then(|| "x".to_owned());
        assert!(Ros2Config::default().resolve_with(bad).is_err());
    }

    #[test]
    fn refusals() {
        for text in [
            "domain_id = 233",
            "namespace = \"car\"",
            "node_name = \"a/b\"",
            "odom_frame = \"\"",
            "queue = 0",
            "qos = \"fast\"",
            "unknown = 1",
        ] {
            let parsed: std::result::Result<Ros2Config, _> = toml::from_str(text);
            match parsed {
                Err(_) => {}
                Ok(c) => assert!(c.resolve_with(no_env).is_err(), "{text} was accepted"),
            }
        }
        let c: Ros2Config = toml::from_str("qos = \"sensor_data\"").expect("parses");
        assert_eq!(c.qos, QosProfile::SensorData);
    }
}
