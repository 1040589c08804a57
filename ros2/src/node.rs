//! The DDS side of canodom as a ROS 2 node: a thread of its own holding the
//! DDS participant and its writers, fed through a bounded queue. The caller
//! (the CAN pipeline, a replay) never waits on DDS: [`Node::publish_pose`]
//! hands the step over or, the queue full, drops it and counts the drop.
//!
//! Published: `nav_msgs/Odometry` and `tf2_msgs/TFMessage` at every step
//! handed over, `diagnostic_msgs/DiagnosticArray` once a second (link,
//! filter, pose quality, calibration, and the node's own drops).
//!
//! The node shows itself to ROS 2's tools as rmw does: one sample on
//! `ros_discovery_info` (reliable, transient-local, keep last 1, so a tool
//! started later still gets it) naming the participant's GUID and, for the
//! node, its name, namespace and its writers' GUIDs; `ros2 node list` and
//! `ros2 topic info -v` read that. Not done: the participant's user data
//! `enclave=/;` that rmw sets (RustDDS 0.15 has no participant user data;
//! rmw reads the enclave only for security, a node without one is listed).

use crate::config::{DiscoveryRange, QosProfile, Resolved};
use crate::msg::{self, Level, Status};
use crate::{Error, Result};
use canodom_export::sample::StepSample;
use canodom_fusion::VehicleParams;
use rustdds::no_key::{DataWriter, SerializerAdapter};
use rustdds::policy::{Durability, History, Reliability};
use rustdds::{
    DataWriterStatus, DomainParticipant, DomainParticipantBuilder, QosPolicies, QosPolicyBuilder,
    RTPSEntity, RepresentationIdentifier, StatusEvented, TopicKind,
};
use std::sync::Arc;
use std::sync::atomic::{AtomicI32, AtomicU64, Ordering};
use std::sync::mpsc::{self, RecvTimeoutError, SyncSender, TrySendError};
use std::time::{Duration, Instant};

/// How long [`Node::wait_for_subscribers`] waits once the subscriptions
/// are matched here, for them to match the writer on their side: Cyclone DDS
/// dropped the first sample of a replay without it (loopback, 2 readers).
pub const MATCH_GRACE: Duration = Duration::from_millis(300);

/// How long the DDS thread stays up after its last write: the last
/// best-effort samples were lost without it (Cyclone, sensor-data QoS).
pub const LINGER: Duration = Duration::from_millis(300);

/// A message already in CDR, its 4-byte encapsulation header first.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RawCdr(pub Vec<u8>);

/// Hands [`RawCdr`]'s bytes to RustDDS as they are (it writes the
/// encapsulation header itself, from [`SerializerAdapter::output_encoding`]).
pub struct RawCdrAdapter;

impl SerializerAdapter<RawCdr> for RawCdrAdapter {
    type Error = std::convert::Infallible;

    fn output_encoding() -> RepresentationIdentifier {
        RepresentationIdentifier::CDR_LE
    }

    fn to_bytes(value: &RawCdr) -> std::result::Result<rustdds::bytes::Bytes, Self::Error> {
        Ok(rustdds::bytes::Bytes::copy_from_slice(
            value.0.get(4..).unwrap_or_default(),
        ))
    }
}

/// Takes any CDR message as [`RawCdr`], its encapsulation header put back
/// (RustDDS hands the payload and its representation apart).
#[derive(Clone, Copy, Debug)]
pub struct RawCdrDecoder;

impl rustdds::no_key::DeserializerAdapter<RawCdr> for RawCdrAdapter {
    type Error = std::convert::Infallible;
    type Decoded = RawCdr;

    fn supported_encodings() -> &'static [RepresentationIdentifier] {
        &[
            RepresentationIdentifier::CDR_LE,
            RepresentationIdentifier::CDR_BE,
        ]
    }

    fn transform_decoded(decoded: RawCdr) -> RawCdr {
        decoded
    }
}

impl rustdds::no_key::DefaultDecoder<RawCdr> for RawCdrAdapter {
    type Decoder = RawCdrDecoder;
    const DECODER: Self::Decoder = RawCdrDecoder;
}

impl rustdds::no_key::Decode<'_, RawCdr> for RawCdrDecoder {
    type Error = std::convert::Infallible;

    fn decode_bytes(
        self,
        input_bytes: &[u8],
        encoding: RepresentationIdentifier,
    ) -> std::result::Result<RawCdr, Self::Error> {
        let mut bytes = Vec::with_capacity(4 + input_bytes.len());
        bytes.extend_from_slice(&encoding.to_bytes());
        bytes.extend_from_slice(&[0, 0]);
        bytes.extend_from_slice(input_bytes);
        Ok(RawCdr(bytes))
    }
}

type Writer = DataWriter<RawCdr, RawCdrAdapter>;

/// What the node has done so far.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NodeStats {
    /// Steps handed to the DDS thread.
    pub queued: u64,
    /// Steps dropped because the queue was full (or the DDS thread gone).
    pub dropped: u64,
    /// `Odometry` samples written.
    pub odometry: u64,
    /// `DiagnosticArray` samples written.
    pub diagnostics: u64,
    /// Writes DDS refused.
    pub write_errors: u64,
}

#[derive(Default)]
struct Shared {
    queued: AtomicU64,
    dropped: AtomicU64,
    odometry: AtomicU64,
    diagnostics: AtomicU64,
    write_errors: AtomicU64,
    /// Subscriptions matched to the odometry writer now.
    odom_matched: AtomicI32,
}

enum Message {
    Pose(Box<(StepSample, VehicleParams)>),
    Stop,
}

/// A running ROS 2 publisher: the DDS thread and the queue to it. Dropping
/// it stops the thread (after giving reliable subscribers up to a second to
/// acknowledge what was written).
pub struct Node {
    tx: SyncSender<Message>,
    shared: Arc<Shared>,
    thread: Option<std::thread::JoinHandle<()>>,
    /// The DDS domain and discovery range, for messages.
    pub describe: String,
}

impl std::fmt::Debug for Node {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Node")
            .field("describe", &self.describe)
            .finish_non_exhaustive()
    }
}

/// ROS 2's QoS of `profile`.
fn qos(reliable: bool, depth: i32) -> QosPolicies {
    QosPolicyBuilder::new()
        .reliability(if reliable {
            Reliability::Reliable {
                max_blocking_time: rustdds::Duration::from_millis(100),
            }
        } else {
            Reliability::BestEffort
        })
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth })
        .build()
}

struct Writers {
    odom: Writer,
    tf: Writer,
    diagnostics: Writer,
    /// `ros_discovery_info`: written once, kept for late joiners.
    graph: Writer,
    // Last: fields drop in order, and the writers go before their participant.
    _participant: DomainParticipant,
}

/// A DDS participant on `domain_id` with ROS 2's discovery `range`: the
/// node's, the fix reader's and the tests' peers are all made here.
///
/// # Errors
/// [`Error::Dds`] when the stack cannot open its sockets (no network, the
/// domain's ports in use).
pub fn participant(domain_id: u16, range: DiscoveryRange) -> Result<DomainParticipant> {
    let mut builder = DomainParticipantBuilder::new(domain_id);
    if range == DiscoveryRange::Localhost {
        // Loopback only: no multicast socket (Linux's `lo` has no MULTICAST
        // flag), locators advertised 127.0.0.1 only, and discovery announced
        // to the well-known unicast ports on 127.0.0.1.
        builder = builder
            .with_only_networks([std::net::IpAddr::V4(std::net::Ipv4Addr::LOCALHOST)])
            .same_host_loopback(true);
    }
    builder
        .build()
        .map_err(|e| dds("creating the participant", &e))
}

/// An error of the DDS stack while doing `what`.
pub(crate) fn dds(what: &str, e: &dyn std::fmt::Display) -> Error {
    Error::Dds(format!("{what}: {e}"))
}

fn create(config: &Resolved) -> Result<Writers> {
    let participant = participant(config.domain_id, config.discovery)?;
    let publisher = participant
        .create_publisher(&QosPolicies::qos_none())
        .map_err(|e| dds("creating the publisher", &e))?;
    let writer = |topic: &str, ty: &str, q: QosPolicies| -> Result<Writer> {
        let t = participant
            .create_topic(topic.to_owned(), ty.to_owned(), &q, TopicKind::NoKey)
            .map_err(|e| dds(topic, &e))?;
        publisher
            .create_datawriter_no_key::<RawCdr, RawCdrAdapter>(&t, Some(q))
            .map_err(|e| dds(topic, &e))
    };
    let odom_qos = match config.qos {
        QosProfile::Default => qos(true, 10),
        QosProfile::SensorData => qos(false, 5),
    };
    let odom = writer(&config.odom_topic, msg::ODOMETRY_TYPE, odom_qos)?;
    let tf = writer(&config.tf_topic, msg::TF_TYPE, qos(true, 100))?;
    let diagnostics = writer(
        &config.diagnostics_topic,
        msg::DIAGNOSTICS_TYPE,
        qos(true, 10),
    )?;
    // rmw's graph topic QoS: reliable, transient-local, keep last 1.
    let graph_qos = QosPolicyBuilder::new()
        .reliability(Reliability::Reliable {
            max_blocking_time: rustdds::Duration::from_millis(100),
        })
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth: 1 })
        .build();
    let graph = writer(
        msg::GRAPH_TOPIC,
        msg::PARTICIPANT_ENTITIES_INFO_TYPE,
        graph_qos,
    )?;
    let mut buf = Vec::with_capacity(256);
    msg::encode_participant_entities(
        participant.guid().to_bytes(),
        &[graph_entry(config, &[&odom, &tf, &diagnostics])],
        config.graph_gid_bytes,
        &mut buf,
    );
    graph
        .write(RawCdr(buf), None)
        .map_err(|e| dds("writing ros_discovery_info", &e))?;
    Ok(Writers {
        odom,
        tf,
        diagnostics,
        graph,
        _participant: participant,
    })
}

/// The node's entry on ROS 2's graph topic: its name, namespace and writers.
fn graph_entry(config: &Resolved, writers: &[&Writer]) -> msg::NodeEntities {
    msg::NodeEntities {
        namespace: config.namespace.clone(),
        name: config.node_name.clone(),
        readers: Vec::new(),
        writers: writers.iter().map(|w| w.guid().to_bytes()).collect(),
    }
}

impl Node {
    /// Creates the DDS participant and writers on a thread of their own.
    /// `k_rear_m` is the filter's rear wheel noise (the twist covariance's).
    ///
    /// # Errors
    /// The participant or a writer could not be made (no network, ports in
    /// use): the caller warns and goes on without ROS 2.
    pub fn start(config: &Resolved, k_rear_m: f64) -> Result<Self> {
        let (tx, rx) = mpsc::sync_channel(config.queue);
        let (ready_tx, ready_rx) = mpsc::channel();
        let shared = Arc::new(Shared::default());
        let thread_shared = Arc::clone(&shared);
        let thread_config = config.clone();
        let thread = std::thread::Builder::new()
            .name("ros2".into())
            .spawn(move || match create(&thread_config) {
                Ok(writers) => {
                    let _ = ready_tx.send(Ok(()));
                    run(&writers, &thread_config, k_rear_m, &rx, &thread_shared);
                    // RustDDS sends from its own event loop: the last
                    // best-effort samples leave within this, and reliable
                    // subscribers get to acknowledge theirs.
                    std::thread::sleep(LINGER);
                    for w in [
                        &writers.odom,
                        &writers.tf,
                        &writers.diagnostics,
                        &writers.graph,
                    ] {
                        let _ = w.wait_for_acknowledgments(Duration::from_secs(1));
                    }
                }
                Err(e) => {
                    let _ = ready_tx.send(Err(e));
                }
            })
            .map_err(|e| Error::Dds(format!("starting the DDS thread: {e}")))?;
        match ready_rx.recv_timeout(Duration::from_secs(20)) {
            Ok(Ok(())) => Ok(Self {
                tx,
                shared,
                thread: Some(thread),
                describe: format!(
                    "domain {}, {} discovery, node /{}{}",
                    config.domain_id,
                    match config.discovery {
                        DiscoveryRange::Localhost => "localhost",
                        DiscoveryRange::Subnet => "subnet",
                    },
                    if config.namespace == "/" {
                        String::new()
                    } else {
                        format!("{}/", config.namespace.trim_start_matches('/'))
                    },
                    config.node_name
                ),
            }),
            Ok(Err(e)) => {
                let _ = thread.join();
                Err(e)
            }
            Err(_) => Err(Error::Dds(
                "the DDS participant did not start within 20 s".into(),
            )),
        }
    }

    /// The node the configuration's `[ros2]` section asks for: `None` when
    /// it is absent or not `enabled`.
    ///
    /// # Errors
    /// The section is not valid, or DDS could not start (the daemon warns
    /// and goes on without ROS 2).
    pub fn from_config(config: &canodom_pipeline::config::Config) -> Result<Option<Self>> {
        let section = crate::config::Ros2Config::from_section(config.ros2.as_ref())?;
        if !section.enabled {
            return Ok(None);
        }
        Self::start(&section.resolve()?, config.ekf.k_rear_m).map(Some)
    }

    /// The node as the live outputs' hook: each pose they take is handed
    /// over without waiting; the node stops when the outputs drop the hook.
    pub fn into_forward(self) -> canodom_export::live::Forward {
        let node = Arc::new(self);
        Arc::new(move |sample, params| {
            node.publish_pose(sample, params);
        })
    }

    /// Hands the step `sample`, taken with parameters `params`, to the DDS
    /// thread without waiting: `false` when it was dropped (queue full, or
    /// the DDS thread gone), which [`NodeStats::dropped`] counts.
    pub fn publish_pose(&self, sample: &StepSample, params: &VehicleParams) -> bool {
        match self
            .tx
            .try_send(Message::Pose(Box::new((*sample, *params))))
        {
            Ok(()) => {
                self.shared.queued.fetch_add(1, Ordering::Relaxed);
                true
            }
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => {
                self.shared.dropped.fetch_add(1, Ordering::Relaxed);
                false
            }
        }
    }

    /// What the node has done so far.
    pub fn stats(&self) -> NodeStats {
        let s = &self.shared;
        NodeStats {
            queued: s.queued.load(Ordering::Relaxed),
            dropped: s.dropped.load(Ordering::Relaxed),
            odometry: s.odometry.load(Ordering::Relaxed),
            diagnostics: s.diagnostics.load(Ordering::Relaxed),
            write_errors: s.write_errors.load(Ordering::Relaxed),
        }
    }

    /// Subscriptions matched to the odometry writer now.
    pub fn odometry_subscribers(&self) -> u32 {
        self.shared.odom_matched.load(Ordering::Relaxed).max(0) as u32
    }

    /// Waits until `n` subscriptions match the odometry writer, or `timeout`
    /// passes: whether they did.
    /// A subscription matched here is not yet matched on its side (its
    /// participant learns of the writer a moment later and drops what comes
    /// first): [`MATCH_GRACE`] is given to it after the count is reached.
    pub fn wait_for_subscribers(&self, n: u32, timeout: Duration) -> bool {
        let until = Instant::now() + timeout;
        while self.odometry_subscribers() < n {
            if Instant::now() >= until {
                return false;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        std::thread::sleep(MATCH_GRACE);
        true
    }

    /// Stops the DDS thread once it has written what is queued, and returns
    /// the final counts.
    pub fn finish(mut self) -> NodeStats {
        self.stop();
        self.stats()
    }

    fn stop(&mut self) {
        // A blocking send: the queue's poses go out before the thread stops.
        let _ = self.tx.send(Message::Stop);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for Node {
    fn drop(&mut self) {
        self.stop();
    }
}

/// The DDS thread: writes the poses it is handed, diagnostics once a second.
fn run(
    w: &Writers,
    config: &Resolved,
    k_rear_m: f64,
    rx: &mpsc::Receiver<Message>,
    shared: &Shared,
) {
    let mut latest: Option<(StepSample, VehicleParams)> = None;
    let mut next_diagnostics = Instant::now() + Duration::from_secs(1);
    let write = |writer: &Writer, buf: Vec<u8>| -> bool {
        if writer.write(RawCdr(buf), None).is_ok() {
            true
        } else {
            shared.write_errors.fetch_add(1, Ordering::Relaxed);
            false
        }
    };
    loop {
        let wait = next_diagnostics
            .saturating_duration_since(Instant::now())
            .min(Duration::from_millis(50));
        match rx.recv_timeout(wait) {
            Ok(Message::Pose(p)) => {
                let (sample, params) = *p;
                let mut buf = Vec::with_capacity(768);
                msg::encode_odometry(
                    &sample,
                    &config.frames,
                    (k_rear_m, params.rear_tread_m()),
                    &mut buf,
                );
                if write(&w.odom, buf) {
                    shared.odometry.fetch_add(1, Ordering::Relaxed);
                }
                let mut buf = Vec::with_capacity(128);
                msg::encode_tf(&sample, &config.frames, &mut buf);
                write(&w.tf, buf);
                latest = Some((sample, params));
            }
            Ok(Message::Stop) | Err(RecvTimeoutError::Disconnected) => break,
            Err(RecvTimeoutError::Timeout) => {}
        }
        while let Some(status) = w.odom.try_recv_status() {
            if let DataWriterStatus::PublicationMatched { current, .. } = status {
                shared
                    .odom_matched
                    .store(current.count(), Ordering::Relaxed);
            }
        }
        if Instant::now() >= next_diagnostics {
            next_diagnostics += Duration::from_secs(1);
            if let Some((sample, params)) = &latest {
                let mut buf = Vec::with_capacity(1024);
                let status = diagnostics(sample, params, config, shared);
                msg::encode_diagnostics(msg::stamp_of(sample), "", &status, &mut buf);
                if write(&w.diagnostics, buf) {
                    shared.diagnostics.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
    }
}

/// The levels and summaries of the link's and the pose's statuses.
fn levels(
    f: canodom_pipeline::pipeline::PoseFlags,
) -> ((Level, &'static str), (Level, &'static str)) {
    let link = if f.rear_stale {
        (Level::Error, "rear wheel input stale")
    } else if f.front_stale || f.steer_stale {
        (Level::Warn, "front wheel or steering input stale")
    } else if f.counter_fault || f.checksum_fault {
        (Level::Warn, "counter or checksum faults")
    } else {
        (Level::Ok, "inputs fresh")
    };
    let pose = if !f.pose_valid {
        (Level::Error, "pose not valid")
    } else if f.input_implausible {
        (Level::Warn, "inputs implausible (see the daemon's log)")
    } else if f.gate_reject {
        (Level::Warn, "gate rejected a correction window")
    } else {
        (Level::Ok, "pose valid")
    };
    (link, pose)
}

/// The diagnostics of the latest step: link, filter, pose, calibration, node.
fn diagnostics(
    s: &StepSample,
    params: &VehicleParams,
    config: &Resolved,
    shared: &Shared,
) -> Vec<Status> {
    let f = s.output.flags;
    let c = s.counts;
    let hw = hw_id(config);
    let kv = |pairs: &[(&str, String)]| -> Vec<(String, String)> {
        pairs
            .iter()
            .map(|(k, v)| ((*k).to_owned(), v.clone()))
            .collect()
    };
    let yes = |b: bool| if b { "true" } else { "false" }.to_owned();
    let ((link_level, link_message), (pose_level, pose_message)) = levels(f);
    let dropped = shared.dropped.load(Ordering::Relaxed);
    let mut status = vec![
        Status {
            level: link_level,
            name: "canodom: CAN link".into(),
            message: link_message.into(),
            hardware_id: hw.clone(),
            values: kv(&[
                ("frames", c.frames.to_string()),
                ("frames_used", c.used.to_string()),
                ("rear_stale", yes(f.rear_stale)),
                ("front_stale", yes(f.front_stale)),
                ("steer_stale", yes(f.steer_stale)),
                ("counter_fault", yes(f.counter_fault)),
                ("checksum_fault", yes(f.checksum_fault)),
            ]),
        },
        Status {
            level: pose_level,
            name: "canodom: pose".into(),
            message: pose_message.into(),
            hardware_id: hw.clone(),
            values: kv(&[
                ("pose_valid", yes(f.pose_valid)),
                ("quality", f.bits().to_string()),
                ("pos_std_m", s.output.pos_std_m.to_string()),
                ("heading_std_rad", s.output.heading_std_rad.to_string()),
                ("speed_mps", s.output.speed_mps.to_string()),
                ("input_implausible", yes(f.input_implausible)),
                ("filter_steps", c.steps.to_string()),
                ("steps_without_front", c.steps_without_front.to_string()),
                ("gate_kept_rear", c.gate_kept_rear.to_string()),
                ("gate_used_front", c.gate_used_front.to_string()),
            ]),
        },
        Status {
            level: if f.nominal_params {
                Level::Warn
            } else {
                Level::Ok
            },
            name: "canodom: calibration".into(),
            message: if f.nominal_params {
                "nominal parameters (not calibrated)".into()
            } else {
                format!("parameter set version {}", s.output.param_version)
            },
            hardware_id: hw.clone(),
            values: kv(&[
                ("param_version", s.output.param_version.to_string()),
                ("nominal", yes(f.nominal_params)),
                ("session", s.calibration_phase.to_owned()),
                ("wheelbase_m", params.wheelbase_m().to_string()),
                ("rear_tread_m", params.rear_tread_m().to_string()),
            ]),
        },
        Status {
            level: if dropped > 0 { Level::Warn } else { Level::Ok },
            name: "canodom: ros2".into(),
            message: if dropped > 0 {
                format!("{dropped} poses dropped (DDS too slow)")
            } else {
                "publishing".into()
            },
            hardware_id: hw,
            values: kv(&[
                (
                    "odometry_written",
                    shared.odometry.load(Ordering::Relaxed).to_string(),
                ),
                ("dropped", dropped.to_string()),
                (
                    "odometry_subscribers",
                    shared.odom_matched.load(Ordering::Relaxed).to_string(),
                ),
            ]),
        },
    ];
    if let Some(g) = &s.gnss {
        status.push(gnss_status(g, hw_id(config)));
    }
    if let Some(d) = &s.drift {
        status.push(drift_status(d, hw_id(config)));
    }
    status
}

fn hw_id(config: &Resolved) -> String {
    format!("canodom/{}", config.node_name)
}

/// The live GNSS source's status (#46): a warning while it is not
/// connected or refuses what it gets, an error never (the odometry goes on).
fn gnss_status(g: &canodom_export::sample::GnssState, hardware_id: String) -> Status {
    let [no_fix, no_position, too_large] = g.refused;
    let (level, message) = if !g.connected {
        (Level::Warn, "not connected".to_owned())
    } else if g.fixes_per_s > 0.0 {
        (Level::Ok, format!("{:.1} fixes/s", g.fixes_per_s))
    } else {
        (Level::Warn, "connected, no fix accepted lately".to_owned())
    };
    let opt = |v: Option<f64>| v.map_or_else(String::new, |v| v.to_string());
    Status {
        level,
        name: "canodom: gnss".into(),
        message,
        hardware_id,
        values: [
            ("connected", g.connected.to_string()),
            ("fixes_per_s", g.fixes_per_s.to_string()),
            ("last_error_m", opt(g.last_error_m)),
            ("accepted", g.accepted.to_string()),
            ("refused_no_fix", no_fix.to_string()),
            ("refused_no_position", no_position.to_string()),
            ("refused_error_too_large", too_large.to_string()),
            ("forwarded", g.forwarded.to_string()),
            ("dropped", g.dropped.to_string()),
            ("reconnects", g.reconnects.to_string()),
            ("last_latency_s", opt(g.last_latency_s)),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_owned(), v))
        .collect(),
    }
}

/// The drift watch's status (#46 item 3): a warning while any parameter
/// is flagged (CALIB_STATUS's DRIFT), naming each with what the last refit
/// learnt of it against the value in use; an error never (the set in use
/// goes on until a COMMIT).
fn drift_status(d: &canodom_export::sample::DriftState, hardware_id: String) -> Status {
    let flagged: Vec<&str> = d.flagged().map(|p| p.name).collect();
    let (level, message) = if flagged.is_empty() {
        (Level::Ok, format!("nothing flagged ({} refits)", d.refits))
    } else if d.candidate {
        (
            Level::Warn,
            format!(
                "{} flagged; candidate offered for COMMIT",
                flagged.join(", ")
            ),
        )
    } else {
        (Level::Warn, format!("{} flagged", flagged.join(", ")))
    };
    let mut values = vec![
        ("refits".to_owned(), d.refits.to_string()),
        ("flagged".to_owned(), flagged.join(",")),
        ("candidate".to_owned(), d.candidate.to_string()),
        ("distance_m".to_owned(), d.distance_m.to_string()),
    ];
    // The state file's and the log's words: learnt ± σ against in use.
    values.extend(d.flagged().map(|p| {
        let text = p.reading.map_or_else(
            || "not read by the last refit".to_owned(),
            |r| format!("learnt {} ± {}, in use {}", r.learnt, r.sigma, r.in_use),
        );
        (p.name.to_owned(), text)
    }));
    Status {
        level,
        name: "canodom: calibration drift".into(),
        message,
        hardware_id,
        values,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use canodom_export::sample::{DriftParam, DriftReading, DriftState, GnssState};

    #[test]
    fn the_drift_status_warns_while_flagged_and_names_learnt_sigma_and_in_use() {
        let param = |name, flagged| DriftParam {
            name,
            flagged,
            reading: Some(DriftReading {
                learnt: 1.01,
                sigma: 0.002,
                in_use: 1.0,
            }),
        };
        let quiet = DriftState::new(3, 900.0, false, [param("rear_ratio", false)]);
        let s = drift_status(&quiet, "canodom/test".into());
        assert_eq!(
            (s.level, s.name.as_str(), s.message.as_str()),
            (
                Level::Ok,
                "canodom: calibration drift",
                "nothing flagged (3 refits)"
            )
        );
        let value = |s: &Status, k: &str| {
            s.values
                .iter()
                .find(|(key, _)| key == k)
                .map(|(_, v)| v.clone())
        };
        assert_eq!(value(&s, "flagged").as_deref(), Some(""));
        // Only a flagged parameter gets a line of its own.
        assert_eq!(value(&s, "rear_ratio"), None);

        let flagged = DriftState::new(
            4,
            1200.0,
            true,
            [
                param("speed_scale", false),
                param("rear_ratio", true),
                DriftParam {
                    name: "yaw_bias",
                    flagged: true,
                    reading: None,
                },
            ],
        );
        let s = drift_status(&flagged, String::new());
        assert_eq!(
            (s.level, s.message.as_str()),
            (
                Level::Warn,
                "rear_ratio, yaw_bias flagged; candidate offered for COMMIT"
            )
        );
        assert_eq!(
            value(&s, "rear_ratio").as_deref(),
            Some("learnt 1.01 ± 0.002, in use 1")
        );
        assert_eq!(
            value(&s, "yaw_bias").as_deref(),
            Some("not read by the last refit")
        );
        assert_eq!(value(&s, "speed_scale"), None);
        assert_eq!(value(&s, "candidate").as_deref(), Some("true"));
        assert_eq!(value(&s, "flagged").as_deref(), Some("rear_ratio,yaw_bias"));
        assert_eq!(value(&s, "refits").as_deref(), Some("4"));
        let s = drift_status(
            &DriftState {
                candidate: false,
                ..flagged
            },
            String::new(),
        );
        assert_eq!(s.message, "rear_ratio, yaw_bias flagged");
    }

    #[test]
    fn the_gnss_status_says_connected_rate_and_refusals_by_reason() {
        let mut g = GnssState {
            connected: true,
            fixes_per_s: 1.0,
            last_error_m: Some(57.0),
            accepted: 16,
            refused: [1, 0, 8],
            forwarded: 16,
            dropped: 0,
            reconnects: 7,
            last_latency_s: Some(0.25),
        };
        let s = gnss_status(&g, "canodom/test".into());
        assert_eq!((s.level, s.message.as_str()), (Level::Ok, "1.0 fixes/s"));
        let value = |s: &Status, k: &str| {
            s.values
                .iter()
                .find(|(key, _)| key == k)
                .map(|(_, v)| v.clone())
        };
        assert_eq!(value(&s, "last_error_m").as_deref(), Some("57"));
        assert_eq!(value(&s, "refused_error_too_large").as_deref(), Some("8"));
        assert_eq!(value(&s, "refused_no_fix").as_deref(), Some("1"));
        assert_eq!(value(&s, "reconnects").as_deref(), Some("7"));
        assert_eq!(value(&s, "last_latency_s").as_deref(), Some("0.25"));
        g.fixes_per_s = 0.0;
        assert_eq!(gnss_status(&g, String::new()).level, Level::Warn);
        g.connected = false;
        g.last_error_m = None;
        let s = gnss_status(&g, String::new());
        assert_eq!(
            (s.level, s.message.as_str()),
            (Level::Warn, "not connected")
        );
        assert_eq!(value(&s, "last_error_m").as_deref(), Some(""));
    }
}
