//! GNSS fixes from ROS 2: a `sensor_msgs/NavSatFix` subscription on a
//! thread of its own, the fixes handed over through a bounded queue (full:
//! dropped and counted), and the geodetic CSV `calibrate --fixes` reads
//! (`t_unix_s,lat_deg,lon_deg,alt_m`, turned into local metres there).
//!
//! The reader is best effort: it matches a GNSS driver's sensor-data
//! publisher and a reliable one alike. A fix without a position
//! (`status.status` −1, NaN latitude or longitude) is counted and left out.
//!
//! The fix's covariance, when its type is known, goes into the CSV as a
//! fifth column `horiz_std_m` (empty when unknown): the geodetic CSV's
//! reader takes it as each fix's σ (`Fix::sigma_m`): `calibrate` weighs
//! the fixes by it and its quality gate allows the residual it explains.

use crate::config::Resolved;
use crate::msg::{self, NavSatFix};
use crate::node::{RawCdr, RawCdrAdapter, dds, participant};
use crate::{Error, Result};
use rustdds::policy::{Durability, History, Reliability};
use rustdds::{QosPolicyBuilder, TopicKind};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, TrySendError};
use std::time::Duration;

/// Fixes queued for the consumer at most.
pub const FIX_QUEUE: usize = 256;

/// What the subscription has seen.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FixStats {
    /// Messages received.
    pub received: u64,
    /// Messages that did not decode as a `NavSatFix`.
    pub undecodable: u64,
    /// Fixes without a position (no fix, NaN).
    pub no_fix: u64,
    /// Fixes dropped because the consumer's queue was full.
    pub dropped: u64,
}

#[derive(Default)]
struct Counts {
    received: AtomicU64,
    undecodable: AtomicU64,
    no_fix: AtomicU64,
    dropped: AtomicU64,
    stop: AtomicBool,
}

/// A running `NavSatFix` subscription.
pub struct FixSubscriber {
    fixes: Receiver<NavSatFix>,
    counts: Arc<Counts>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl std::fmt::Debug for FixSubscriber {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FixSubscriber")
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

/// Whether `fix` has a position.
pub fn has_position(fix: &NavSatFix) -> bool {
    fix.status >= 0 && fix.latitude.is_finite() && fix.longitude.is_finite()
}

/// `sensor_msgs/NavSatFix`'s `COVARIANCE_TYPE_UNKNOWN`.
pub const COVARIANCE_TYPE_UNKNOWN: u8 = 0;

/// The fix's horizontal standard deviation (m): the root of the mean of
/// its east and north variances (`position_covariance[0]` and `[4]`, ENU
/// as REP-145 has it), whether the driver gave the diagonal only
/// (`DIAGONAL_KNOWN`), the whole matrix or an approximation from the DOP
/// (`APPROXIMATED`). `None` when the type is unknown or the variances are
/// not finite and non-negative.
pub fn horizontal_std_m(fix: &NavSatFix) -> Option<f64> {
    if fix.position_covariance_type == COVARIANCE_TYPE_UNKNOWN {
        return None;
    }
    let (east, north) = (fix.position_covariance[0], fix.position_covariance[4]);
    let ok = |v: f64| v.is_finite() && v >= 0.0;
    (ok(east) && ok(north)).then(|| (0.5 * (east + north)).sqrt())
}

/// `fix` as a line of the geodetic CSV `calibrate --fixes` reads
/// (`t_unix_s,lat_deg,lon_deg,alt_m,horiz_std_m`; an unknown altitude as 0,
/// an unknown σ as an empty field).
pub fn csv_line(fix: &NavSatFix) -> String {
    let t = f64::from(fix.stamp.sec) + f64::from(fix.stamp.nanosec) * 1e-9;
    let alt = if fix.altitude.is_finite() {
        fix.altitude
    } else {
        0.0
    };
    let std = horizontal_std_m(fix)
        .map(|s| format!("{s:.3}"))
        .unwrap_or_default();
    // Latitude and longitude in the shortest form that reads back to the
    // same double: nine decimals (0.1 mm) moved the σ of what a drive
    // cannot tell by 0.03 % against the same fixes in NMEA (the RAV4's
    // first 30 s, `ros2/tests/cyclone_subscriber.py`); the file should
    // carry what the receiver stated, not a rounding of it.
    format!("{t:.9},{},{},{alt:.3},{std}", fix.latitude, fix.longitude)
}

/// The CSV's header line.
pub const CSV_HEADER: &str = "t_unix_s,lat_deg,lon_deg,alt_m,horiz_std_m";

impl FixSubscriber {
    /// Subscribes to `config.fix_topic` on its own participant and thread.
    ///
    /// # Errors
    /// No fix topic configured, or DDS could not start.
    pub fn start(config: &Resolved) -> Result<Self> {
        let topic = config
            .fix_topic
            .clone()
            .ok_or_else(|| Error::Config("[ros2] has no fix_topic to take fixes from".into()))?;
        let (tx, fixes) = mpsc::sync_channel(FIX_QUEUE);
        let (ready_tx, ready_rx) = mpsc::channel();
        let counts = Arc::new(Counts::default());
        let thread_counts = Arc::clone(&counts);
        let (domain, discovery) = (config.domain_id, config.discovery);
        let thread = std::thread::Builder::new()
            .name("ros2-fixes".into())
            .spawn(move || {
                let setup = || -> Result<_> {
                    let participant = participant(domain, discovery)?;
                    let qos = QosPolicyBuilder::new()
                        .reliability(Reliability::BestEffort)
                        .durability(Durability::Volatile)
                        .history(History::KeepLast { depth: 10 })
                        .build();
                    let t = participant
                        .create_topic(
                            topic.clone(),
                            msg::NAV_SAT_FIX_TYPE.to_owned(),
                            &qos,
                            TopicKind::NoKey,
                        )
                        .map_err(|e| dds(&topic, &e))?;
                    let subscriber = participant
                        .create_subscriber(&qos)
                        .map_err(|e| dds("subscriber", &e))?;
                    let reader = subscriber
                        .create_datareader_no_key::<RawCdr, RawCdrAdapter>(&t, Some(qos))
                        .map_err(|e| dds(&topic, &e))?;
                    Ok((participant, reader))
                };
                let (participant, mut reader) = match setup() {
                    Ok(x) => {
                        let _ = ready_tx.send(Ok(()));
                        x
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                        return;
                    }
                };
                let c = &thread_counts;
                while !c.stop.load(Ordering::Relaxed) {
                    while let Ok(Some(sample)) = reader.take_next_sample() {
                        c.received.fetch_add(1, Ordering::Relaxed);
                        let Ok(fix) = msg::decode_nav_sat_fix(&sample.into_value().0) else {
                            c.undecodable.fetch_add(1, Ordering::Relaxed);
                            continue;
                        };
                        if !has_position(&fix) {
                            c.no_fix.fetch_add(1, Ordering::Relaxed);
                            continue;
                        }
                        if let Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) =
                            tx.try_send(fix)
                        {
                            c.dropped.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                    std::thread::sleep(Duration::from_millis(5));
                }
                drop(reader);
                drop(participant);
            })
            .map_err(|e| Error::Dds(format!("starting the fix thread: {e}")))?;
        match ready_rx.recv_timeout(Duration::from_secs(20)) {
            Ok(Ok(())) => Ok(Self {
                fixes,
                counts,
                thread: Some(thread),
            }),
            Ok(Err(e)) => {
                let _ = thread.join();
                Err(e)
            }
            Err(_) => Err(Error::Dds(
                "the fix subscription did not start in 20 s".into(),
            )),
        }
    }

    /// The next fix, waiting up to `timeout`.
    pub fn recv_timeout(&self, timeout: Duration) -> Option<NavSatFix> {
        self.fixes.recv_timeout(timeout).ok()
    }

    /// What the subscription has seen so far.
    pub fn stats(&self) -> FixStats {
        let c = &self.counts;
        FixStats {
            received: c.received.load(Ordering::Relaxed),
            undecodable: c.undecodable.load(Ordering::Relaxed),
            no_fix: c.no_fix.load(Ordering::Relaxed),
            dropped: c.dropped.load(Ordering::Relaxed),
        }
    }
}

impl Drop for FixSubscriber {
    fn drop(&mut self) {
        self.counts.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// `canodom ros2-fixes`: GNSS fixes taken from ROS 2 into the CSV
/// `calibrate --fixes` reads.
#[derive(Clone, Debug, clap::Args)]
#[command(
    after_help = "Example:\n  canodom ros2-fixes --config car.toml --out fixes.csv --seconds 600\n  \
canodom calibrate --config car.toml drive.log --fixes fixes.csv\n\n\
The topic, domain and discovery range are `[ros2]`'s (`fix_topic`, `domain_id`, `discovery`) \
and ROS 2's environment's (`ROS_DOMAIN_ID`, `ROS_AUTOMATIC_DISCOVERY_RANGE`)."
)]
pub struct FixesArgs {
    /// The configuration file: its `[ros2]` section names the topic.
    #[arg(long)]
    pub config: std::path::PathBuf,
    /// The topic, overriding `[ros2] fix_topic` (a ROS 2 name: `/fix`).
    #[arg(long)]
    pub topic: Option<String>,
    /// Where the CSV goes (`t_unix_s,lat_deg,lon_deg,alt_m,horiz_std_m`).
    #[arg(long)]
    pub out: std::path::PathBuf,
    /// Stop this many seconds after the start.
    #[arg(long, default_value_t = 60.0)]
    pub seconds: f64,
    /// Stop once this many fixes are written.
    #[arg(long)]
    pub count: Option<u64>,
}

/// Runs `ros2-fixes`: subscribes, writes each fix with a position as a
/// CSV line (flushed as it comes), stops after `--seconds` or `--count`.
/// Returns the fixes written.
///
/// # Errors
/// The configuration, DDS could not start, the file could not be written.
pub fn execute(args: &FixesArgs) -> Result<u64> {
    use std::io::Write as _;
    let config = canodom_pipeline::config::Config::load(&args.config)
        .map_err(|e| Error::Config(e.to_string()))?;
    let mut section = crate::config::Ros2Config::from_section(config.ros2.as_ref())?;
    if let Some(topic) = &args.topic {
        section.fix_topic = Some(topic.clone());
    }
    let resolved = section.resolve()?;
    if !(args.seconds.is_finite() && args.seconds > 0.0) {
        return Err(Error::Config(format!(
            "--seconds {}: not a positive number",
            args.seconds
        )));
    }
    let subscriber = FixSubscriber::start(&resolved)?;
    let io = |e: std::io::Error| Error::Config(format!("{}: {e}", args.out.display()));
    let mut out = std::fs::File::create(&args.out).map_err(io)?;
    writeln!(out, "{CSV_HEADER}").map_err(io)?;
    eprintln!(
        "ros2-fixes: taking {} (domain {}) into {}",
        resolved.fix_topic.as_deref().unwrap_or_default(),
        resolved.domain_id,
        args.out.display()
    );
    let until = std::time::Instant::now() + Duration::from_secs_f64(args.seconds);
    let mut written = 0u64;
    while args.count.is_none_or(|n| written < n) {
        let left = until.saturating_duration_since(std::time::Instant::now());
        if left.is_zero() {
            break;
        }
        if let Some(fix) = subscriber.recv_timeout(left.min(Duration::from_millis(200))) {
            writeln!(out, "{}", csv_line(&fix)).map_err(io)?;
            written += 1;
        }
    }
    out.flush().map_err(io)?;
    let s = subscriber.stats();
    eprintln!(
        "ros2-fixes: {written} fixes written; {} received, {} without a position, {} undecodable, {} dropped",
        s.received, s.no_fix, s.undecodable, s.dropped
    );
    Ok(written)
}
