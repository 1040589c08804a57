//! canodom on ROS 2 without ROS installed (issue #43): the pose as
//! `nav_msgs/Odometry`, the `odom → base_link` transform as
//! `tf2_msgs/TFMessage` and the daemon's health as
//! `diagnostic_msgs/DiagnosticArray`, over DDS-RTPS as a ROS 2 node puts
//! them (topic `rt/odom`, type `nav_msgs::msg::dds_::Odometry_`, CDR).
//!
//! # Layout
//! - [`msg`]: the messages in CDR and their DDS type names.
//! - [`config`]: the `[ros2]` section and ROS 2's environment.
//! - [`node`]: the DDS participant on a thread of its own, fed through a
//!   bounded queue that never holds up the caller.
//! - [`replay`]: `replay --ros2`, a log published at its recorded pace.
//! - [`fixes`]: GNSS fixes taken from a `sensor_msgs/NavSatFix` topic.
//!
//! # Why RustDDS
//! Three pure-Rust stacks were looked at (Nov 2026), against what the issue
//! asks: wire compatibility with Cyclone DDS and Fast DDS, discovery over
//! loopback with unicast peers only (CI and the VM may send to 127.0.0.1
//! and nowhere else), build time, binary size.
//! - **`rustdds` 0.15** (Atostek, Apache-2.0, maintained, used by
//!   `ros2-client` and tested by its authors against Cyclone and Fast DDS):
//!   `DomainParticipantBuilder::with_only_networks([127.0.0.1])` opens no
//!   multicast socket on a loopback without the MULTICAST flag (Linux's
//!   `lo`), advertises 127.0.0.1 only, and `same_host_loopback` announces
//!   SPDP to the well-known unicast ports on 127.0.0.1: the
//!   `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST` behaviour. Chosen.
//! - **`dust_dds` 0.16**: its UDP transport always announces to the
//!   multicast group 239.255.0.1 and has no initial-peers list (its
//!   configuration has a domain tag, an interface name and a fragment
//!   size): no discovery where multicast is not allowed.
//! - **`ros2-client` 0.12** (on RustDDS): a whole `rclcpp`-like API (nodes,
//!   services, actions, parameters) for what is here three writers of
//!   messages already in CDR; not taken, RustDDS is used directly.
//!
//! What it cost, measured on the project's 2-core machine (Nov 2026,
//! release profile, `cargo build --timings`): 52 new compilation units
//! (RustDDS 0.15.1 and what it pulls in: speedy, cdr-encoding, mio 0.6,
//! netdev with netlink-packet-route, ...), 138 s of compiler time in all,
//! most of it netlink-packet-route (57 s) and rustdds (43 s), whose chain
//! (netlink-packet-route → netdev → rustdds → this crate) adds about
//! 110 s to a cold build's wall time; the `canodom` binary grows by
//! 3.4 MB stripped (10.4 → 13.8 MB, +33 %; 82 → 108 MB with the release
//! profile's debug info). At run time the node is one thread of ours plus
//! RustDDS's event-loop thread, idle between poses.
//!
//! Wire compatibility, measured with `ros2/tests/cyclone.sh` (Cyclone DDS
//! 11.0.1 from PyPI, loopback, unicast discovery): the RAV4 minute's 4,974
//! steps at the recorded pace reach a reliable and a best-effort Cyclone
//! reader, 4,974 each, at 82.9 Hz (the log's 82.9 Hz), poses equal to the
//! CSV's (0 m; heading 6e-17 rad, the quaternion's rounding); with
//! sensor-data QoS the best-effort reader gets them and the reliable one,
//! as DDS wants, does not match. Fast DDS 2.9 (Debian's libfastrtps, a C++
//! subscriber, `ros2/tests/fastdds.sh`, same loopback setup): its reliable
//! and best-effort readers get all 4,974 steps at 4x the pace, poses equal
//! to the CSV's; its test takes 26 s (g++, the replay at 4x) plus ~5 s of apt.
//!
//! At full CAN load (`cargo bench --bench load`: the RAV4 frames fed at
//! 4,000 frames/s, a 500 kbit/s bus of 8-byte frames, 370 poses/s, through
//! the pipeline in-process; a RustDDS reader in another process on
//! loopback), three runs on the shared 2-core machine (load 1-2): from the
//! frame entering the pipeline to the `/odom` sample at the reader p50
//! 0.35-0.51 ms, p99 1.6-3.7 ms, every step received; the publishing
//! process used 4.6-5.2 % of a core with `[ros2]` off and 9.9-16.0 % on
//! (+4.9 to +10.8 points: encoding, the DDS thread and RustDDS's loop).
//!
//! Messages are encoded by hand (as `canodom-export` does for MCAP) and
//! handed to RustDDS as bytes ([`node::RawCdrAdapter`]): no serde types to
//! keep in step with the ROS 2 definitions, and `/odom` carries exactly the
//! bytes of the MCAP recording's `/odom`.

#![deny(missing_docs)]

pub mod config;
pub mod fixes;
pub mod msg;
pub mod node;
pub mod replay;

/// The log filter directive for the DDS stack's own log (`tracing`'s
/// `EnvFilter` syntax): errors only. RustDDS warns at every discovery round
/// about its own announcements heard back on 127.0.0.1 and similar noise;
/// what matters to canodom (a participant that cannot start, a write
/// refused) comes back as an [`Error`] or in [`node::NodeStats`].
pub const LOG_FILTER: &str = "rustdds=error";

/// What can go wrong with ROS 2.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The `[ros2]` section or ROS 2's environment is not valid.
    #[error("{0}")]
    Config(String),
    /// DDS could not start or refused an entity (no network, port in use).
    #[error("DDS: {0}")]
    Dds(String),
    /// A received message could not be decoded.
    #[error("decoding a ROS 2 message: {0}")]
    Decode(&'static str),
    /// The replay could not run (pipeline, parameters, pace).
    #[error("replay: {0}")]
    Replay(String),
    /// The log could not be read.
    #[error(transparent)]
    Log(#[from] canodom_offline::Error),
}

/// The crate's result.
pub type Result<T> = std::result::Result<T, Error>;
