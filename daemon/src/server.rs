//! The daemon proper (`canodom run`, and the far end of `canodom demo`):
//! three tasks joined by bounded channels, generic over the transport so the
//! tests and the demo run this very code on the in-process bus.
//!
//! - `LinkTask` owns the connection: opens it with kernel filters for the
//!   configured ids, forwards frames, and on an interface going down or away,
//!   or a bus-off, logs, waits with exponential backoff (watching the
//!   shutdown token) and reopens. It hands each new sending half to the
//!   other tasks through a `watch` channel (`None` while disconnected).
//! - `OdometryTask` owns the [`Pipeline`]: feeds it every wheel frame,
//!   publishes the pose at the configured rate (and after each step with
//!   `publish_on_update`, and on an `ODOM_CMD` PUBLISH_NOW request), moves
//!   the pose to the origin on `ODOM_CMD` RESET_POSE at standstill, applies
//!   the sets the calibration hands back, logs one line of statistics
//!   periodically, and pets the systemd watchdog. The calibration's frames,
//!   its filter steps and input faults go on to the calibration task.
//! - [`CalibTask`] owns the live calibration (see [`crate::calib_task`]).
//!
//! Shutdown (tokio's guide): one `CancellationToken` cloned into each task,
//! watched at every await, tasks spawned on a `TaskTracker` that `run` closes
//! and waits for under a timeout. On cancel the link task stops reading and
//! drops its sender; the odometry task drains every frame already queued
//! and then drops its sender to the calibration task, which handles what is
//! queued and finishes a store in flight before it returns, so nothing
//! received is lost.

use crate::calib_task::{CalibInput, CalibTask, OdometryLinks, lock, still_at};
use crate::sd_notify::Notifier;
use canodom_can::bus::{
    BusError, BusEvent, FrameSink, FrameSource, IdFilter, InProcessBus, Received,
};
use canodom_can::frame::{CanFrame, ErrorSeverity, FrameId};
use canodom_can::time::Timestamp;
use canodom_dbc::{Checksum, Database, SignalHandle};
use canodom_live::LiveCalibration;
use canodom_pipeline::config::{Config, FixSignals};
use canodom_pipeline::gate::{Admit, SecurityGate};
use canodom_pipeline::pipeline::{Outcome, Pipeline, Step};
use canodom_pipeline::stats::{Reasons, Reject, Stats};
use canodom_protocol::calib_wire::CalibWire;
use canodom_protocol::own_dbc::{OwnDbc, OwnFrame};
use canodom_protocol::pose_frames::PoseEncoder;
use std::future::Future;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::{mpsc, watch};
use tokio::time::{Instant, MissedTickBehavior};
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;
use tracing::{debug, error, info, instrument, warn};

/// Opens the transport (SocketCAN on a vehicle, the in-process bus in tests).
pub trait Connector: Send + Sync + 'static {
    /// Receiving half.
    type Rx: FrameSource + 'static;
    /// Sending half.
    type Tx: FrameSink + Clone + 'static;
    /// Opens an endpoint with these receive filters.
    ///
    /// # Errors
    /// The interface is missing, down, or refused an option.
    fn connect(&self, filters: &[IdFilter]) -> Result<(Self::Rx, Self::Tx), BusError>;
    /// Interface name for logs.
    fn name(&self) -> String;
}

impl Connector for InProcessBus {
    type Rx = canodom_can::bus::InProcessRx;
    type Tx = canodom_can::bus::InProcessTx;
    fn connect(&self, filters: &[IdFilter]) -> Result<(Self::Rx, Self::Tx), BusError> {
        let (mut rx, tx) = self.open()?;
        rx.set_filters(filters)?;
        Ok((rx, tx))
    }
    fn name(&self) -> String {
        "in-process".to_owned()
    }
}

/// SocketCAN on a named interface.
#[derive(Clone, Debug)]
pub struct SocketCan {
    /// Interface name, e.g. `can0`.
    pub iface: String,
}

impl Connector for SocketCan {
    type Rx = canodom_can::bus::SocketCanRx;
    type Tx = canodom_can::bus::SocketCanTx;
    fn connect(&self, filters: &[IdFilter]) -> Result<(Self::Rx, Self::Tx), BusError> {
        canodom_can::bus::open_socketcan(&self.iface, filters)
    }
    fn name(&self) -> String {
        self.iface.clone()
    }
}

pub use crate::summary::Summary;

/// Why the daemon stopped abnormally.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The pipeline could not be built.
    #[error("pipeline: {0}")]
    Pipeline(#[from] canodom_fusion::Error),
    /// The pose encoder could not be built.
    #[error("{0}")]
    Encoder(#[from] canodom_protocol::pose_frames::PoseEncodeError),
    /// The transport failed for good.
    #[error("{0}")]
    Bus(#[from] BusError),
    /// A task panicked or did not stop in time.
    #[error("task: {0}")]
    Task(String),
    /// The calibration frames cannot be built at the configured base id.
    #[error("calibration frames: {0}")]
    Calibration(#[from] canodom_protocol::calib_wire::WireError),
    /// The SecOC freshness file is unreadable or damaged.
    #[error("{0}")]
    Security(#[from] canodom_pipeline::gate::GateError),
}

/// Optional observers (the demo's display, tests).
#[derive(Clone, Debug, Default)]
pub struct Observers {
    /// Receives every filter step (latest value only).
    pub steps: Option<watch::Sender<Option<Step>>>,
    /// Receives the pipeline statistics after every frame batch.
    pub stats: Option<watch::Sender<Stats>>,
    /// What a previous run learnt, put into the filter before the first
    /// frame (over what `state_file` restores). Not an observer: it and
    /// `state_file` ride here until the daemon's start-up options get a
    /// struct of their own.
    pub restore_learnt: Option<canodom_fusion::ekf::Learnt>,
    /// The state file (`run --state-file`): learnt values restored from it
    /// at start when they were learnt on the parameter set in use, and the
    /// state written to it periodically, after each applied set and at the
    /// end (see [`crate::state_file`]).
    pub state_file: Option<crate::state_file::StateFileOptions>,
    /// Gets every frame and published pose for `run --record` / `--foxglove` (never blocks).
    pub tap: Option<canodom_export::live::Tap>,
}

enum LinkEvent {
    Frame(Received),
    Lost(u64),
}

/// Backoff bounds for reopening the interface.
const BACKOFF_MIN: Duration = Duration::from_millis(100);
const BACKOFF_MAX: Duration = Duration::from_secs(5);
/// Backoff cap while the interface is down or missing: a vehicle's CAN
/// interface coming back (link up, driver reloaded, USB adapter replugged)
/// must be picked up within the 1 s, and trying to open a missing
/// interface is one cheap syscall, so there is nothing to save by waiting
/// longer. Other errors still back off up to [`BACKOFF_MAX`].
const BACKOFF_MAX_LINK: Duration = Duration::from_millis(500);

/// After the first few, one failed open in this many is logged (with the
/// 500 ms retry cap, one line every 30 s).
const OPEN_FAILURES_LOG_EVERY: u64 = 60;

/// The next backoff after `current` failed with `cause`.
fn next_backoff(current: Duration, cause: Option<&BusError>) -> Duration {
    let cap = match cause {
        Some(BusError::InterfaceDown { .. } | BusError::NoSuchInterface { .. }) => BACKOFF_MAX_LINK,
        _ => BACKOFF_MAX,
    };
    (current * 2).min(cap)
}

/// What the kernel passes: only what the daemon reads (wheels, steering,
/// its own commands and acknowledgements, authenticators, position fixes).
fn kernel_filters(
    config: &Config,
    own_ids: &[FrameId],
    gate: &SecurityGate,
    fix_id: Option<FrameId>,
) -> Vec<IdFilter> {
    let ids = config
        .input_ids()
        .into_iter()
        .chain(own_ids.iter().copied());
    ids.chain(gate.receive_ids())
        .chain(fix_id)
        .map(IdFilter::exact)
        .collect()
}

/// The daemon's run loop on an in-process bus, with no CAN hardware: how
/// `canodom demo`, the simulated-vehicle tests and the integration tests
/// drive it, one frame source and sink per [`InProcessBus::open`].
pub struct InProcessDaemon {
    /// The bus the daemon listens and publishes on.
    pub bus: InProcessBus,
    stop: CancellationToken,
    task: tokio::task::JoinHandle<Result<Summary, RunError>>,
}

impl InProcessDaemon {
    /// Starts [`run`] on a new bus named after the configured interface,
    /// whose clock starts at the simulator's log epoch (so bus timestamps
    /// equal those of a simulated candump log); each receiver queues up to
    /// `capacity` frames.
    #[must_use]
    pub fn spawn(config: Arc<Config>, capacity: usize, observers: Observers) -> Self {
        let bus = InProcessBus::with_epoch(
            &config.interface,
            capacity,
            Timestamp::from_micros(canodom_sim::drive::LOG_EPOCH_US),
        );
        Self::spawn_on(config, bus, observers)
    }

    /// As [`Self::spawn`] on a bus of the caller's, e.g. one whose clock
    /// starts at the wall-clock time (SecOC freshness is judged against
    /// the bus clock, as against the kernel's receive time on SocketCAN).
    #[must_use]
    pub fn spawn_on(config: Arc<Config>, bus: InProcessBus, observers: Observers) -> Self {
        let stop = CancellationToken::new();
        let task = tokio::spawn(run(
            config,
            bus.clone(),
            stop.clone().cancelled_owned(),
            observers,
        ));
        Self { bus, stop, task }
    }

    /// Stops the daemon as SIGTERM would (frames already queued are still
    /// used) and returns its summary.
    ///
    /// # Errors
    /// As [`run`].
    ///
    /// # Panics
    /// Re-raises a panic of the run loop, as if it had run on this task.
    pub async fn stop(self) -> Result<Summary, RunError> {
        self.stop.cancel();
        match self.task.await {
            Ok(result) => result,
            Err(e) => std::panic::resume_unwind(e.into_panic()),
        }
    }
}

/// Runs the daemon until `shutdown` completes or the transport fails for good.
///
/// # Errors
/// [`RunError`].
#[allow(clippy::too_many_lines)] // the tasks are wired in one place, as mini-redis does
pub async fn run<C: Connector>(
    config: Arc<Config>,
    connector: C,
    shutdown: impl Future<Output = ()>,
    observers: Observers,
) -> Result<Summary, RunError> {
    let token = CancellationToken::new();
    let tracker = TaskTracker::new();
    let mut pipeline = Pipeline::new(&config)?;
    let nominal = *pipeline.params();
    apply_param_file(&mut pipeline, &config.calibration);
    if let Some(options) = &observers.state_file
        && let Some(learnt) =
            crate::state_file::restore_logged(&options.path, &pipeline.param_identity())
    {
        pipeline.restore_learnt(&learnt);
    }
    if let Some(learnt) = &observers.restore_learnt {
        pipeline.restore_learnt(learnt);
    }
    // canodom's own DBC, rewritten for the base id and parsed once for the
    // pose encoder, the calibration wire and the ODOM_CMD checks.
    let own = OwnDbc::new(config.output.base_id)
        .map_err(canodom_protocol::pose_frames::PoseEncodeError::from)?;
    let (mut live, calib_ack_id) = live_calibration(&config, &own, nominal)?;
    if let Some(options) = &observers.state_file
        && let Ok(state) = crate::state_file::load(&options.path)
        && let Some(front) = crate::state_file::saved_front_baseline(&state)
    {
        if live.restore_front_baseline(front) {
            info!(
                file = %options.path.display(),
                front_ratio = front.value,
                "drift watch: the front tyres are judged against the ratio the last run read"
            );
        } else {
            warn!(
                file = %options.path.display(),
                front_ratio = front.value,
                "drift watch: the front tyres' ratio of the last run is not plausible; it is read anew"
            );
        }
    }
    let calib_cmd_id = config.calibration.command_id;
    let encoder = PoseEncoder::with_dbc(&own)?;
    let cmd_id = OwnFrame::OdomCmd.id(config.output.base_id);
    let gate = SecurityGate::for_config(&config)?;
    let fix_id = |f: &FixSignals| config.db.messages()[f.message_index].id();
    let fixes = config.calibration.fixes.map(|f| (fix_id(&f), f));
    let own_ids = [cmd_id, calib_cmd_id, calib_ack_id];
    let filters = kernel_filters(&config, &own_ids, &gate, fixes.map(|(id, _)| id));
    let security = Arc::new(Mutex::new(gate));
    let notifier = Notifier::from_env().unwrap_or_else(|e| {
        warn!(cause = %e, "sd_notify socket unusable; running without systemd notifications");
        None
    });
    let (frames_tx, frames_rx) = mpsc::channel(1024);
    let (sink_tx, sink_rx) = watch::channel(None);
    let (lost_tx, lost_rx) = mpsc::channel(1);
    let outages = Arc::new(AtomicU64::new(0));
    let connections = Arc::new(AtomicU64::new(0));
    let link = LinkTask {
        connector,
        filters,
        frames: frames_tx,
        sink: sink_tx,
        link_lost: lost_rx,
        outages: Arc::clone(&outages),
        connections: Arc::clone(&connections),
        token: token.clone(),
    };
    let link_handle = tracker.spawn(link.run());
    let odom_commands = OdomCommands::new(own.database(), config.calibration.arming_code)
        .map_err(canodom_protocol::pose_frames::PoseEncodeError::from)?;
    let (mut calib, links) = CalibTask::new(
        live,
        Arc::clone(&security),
        sink_rx.clone(),
        lost_tx.clone(),
        config.calibration.param_file.clone(),
        report_root(&config.calibration.param_file),
        Arc::clone(&config),
    );
    // `[gnss]`: its source starts on the blocking pool (a failure is a
    // warning there, and the daemon goes on).
    let (gnss_handle, gnss_status) = config
        .gnss
        .as_ref()
        .map(|g| {
            let (forwarder, gnss_links) = crate::gnss_task::Forwarder::new(
                &config,
                g,
                links.clock.subscribe(),
                token.clone(),
            );
            calib.gnss = Some(gnss_links.fixes);
            calib.watch_gnss(gnss_links.page);
            (
                tracker.spawn_blocking(move || forwarder.run()),
                gnss_links.status,
            )
        })
        .unzip();
    let calib_handle = tracker.spawn(calib.run());
    let (state_out, state_handle) = match &observers.state_file {
        None => (None, None),
        Some(options) => {
            let (tx, rx) = watch::channel(None);
            let writer =
                crate::state_file::write_latest(Arc::clone(&config), options.path.clone(), rx);
            (Some((tx, options.every)), Some(tracker.spawn(writer)))
        }
    };
    let task = OdometryTask {
        pipeline,
        encoder,
        frames: frames_rx,
        sink: sink_rx,
        token: token.clone(),
        pose_period: Duration::from_secs_f64(1.0 / config.output.pose_rate_hz),
        stats_period: Duration::from_secs_f64(config.output.stats_interval_s),
        publish_on_update: config.output.publish_on_update,
        cmd_id,
        fixes,
        odom_commands,
        odom_refusals: OdomRefusals::default(),
        security: Arc::clone(&security),
        mono_start: Instant::now(),
        notifier,
        observers,
        published: 0,
        lost: 0,
        plausibility_logged: 0,
        link_lost: lost_tx,
        outages: Arc::clone(&outages),
        connections: Arc::clone(&connections),
        state_out,
        links,
        calib_cmd_id,
        calib_ack_id,
        gnss: gnss_status,
    };
    let pipeline_handle = tracker.spawn(task.run());
    tracker.close();

    tokio::select! {
        () = shutdown => info!("shutdown requested"),
        () = token.cancelled() => {}
    }
    token.cancel();
    if tokio::time::timeout(Duration::from_secs(5), tracker.wait())
        .await
        .is_err()
    {
        return Err(RunError::Task("tasks did not stop within 5 s".into()));
    }
    let connections = link_handle
        .await
        .map_err(|e| RunError::Task(e.to_string()))??;
    let mut summary = pipeline_handle
        .await
        .map_err(|e| RunError::Task(e.to_string()))?;
    calib_handle
        .await
        .map_err(|e| RunError::Task(e.to_string()))?;
    if let Some(handle) = state_handle {
        summary.state_file = handle.await.map_err(|e| RunError::Task(e.to_string()))?;
    }
    if let Some(handle) = gnss_handle {
        summary.gnss = Some(handle.await.map_err(|e| RunError::Task(e.to_string()))?);
    }
    summary.connections = connections;
    summary.outages = outages.load(Ordering::Relaxed);
    Ok(summary)
}

/// The live calibration over the parameter file (re-read: `apply_param_file`
/// already judged it; a damaged file starts an empty history) and the
/// `CALIB_ACK` id.
fn live_calibration(
    config: &Config,
    own: &OwnDbc,
    nominal: canodom_fusion::VehicleParams,
) -> Result<(LiveCalibration, FrameId), RunError> {
    let cal = &config.calibration;
    let file = canodom_params::persist::load(&cal.param_file, &cal.bounds).unwrap_or_default();
    let wire = CalibWire::with_dbc(own)?;
    let ack_id = wire.ack_id();
    Ok((
        LiveCalibration::new(wire, cal.clone(), nominal, file),
        ack_id,
    ))
}

/// Reports of committed sessions go to `<param file stem>-reports/<version>/`
/// beside the parameter file.
fn report_root(param_file: &std::path::Path) -> std::path::PathBuf {
    let stem = param_file
        .file_stem()
        .map_or_else(|| "canodom-params".into(), |s| s.to_string_lossy());
    param_file.with_file_name(format!("{stem}-reports"))
}

/// Which parameters the daemon started with.
#[derive(Debug)]
pub enum ParamStart {
    /// No parameter file yet: the nominal parameters.
    Nominal,
    /// The file's current set, this version, is in use.
    Loaded(u16),
    /// The file is damaged (or out of bounds): the nominal parameters, and a
    /// warning naming the file was logged.
    Fallback(canodom_params::persist::PersistError),
}

/// Loads the calibrated-parameter file (checksums and bounds checked) and
/// applies its current set to `pipeline`; falls back to the nominal
/// parameters with a warning naming the file when it is damaged.
pub fn apply_param_file(
    pipeline: &mut Pipeline,
    calibration: &canodom_pipeline::config::CalibrationConfig,
) -> ParamStart {
    use canodom_params::persist::{PersistError, load};
    let path = &calibration.param_file;
    let fallback = |pipeline: &mut Pipeline, e: PersistError| {
        warn!(file = %path.display(), cause = %e, "calibrated parameter file unusable; using the nominal parameters");
        // Nominal parameters cannot be refused: the pipeline was built with them.
        let _ = pipeline.apply_params(None);
        ParamStart::Fallback(e)
    };
    match load(path, &calibration.bounds) {
        Err(PersistError::Missing { .. }) => {
            info!(file = %path.display(), "no calibrated parameter file; using the nominal parameters");
            ParamStart::Nominal
        }
        Err(e) => fallback(pipeline, e),
        Ok(file) => match &file.current {
            None => ParamStart::Nominal,
            Some(set) => match pipeline.apply_params(Some((set.version, &set.values))) {
                Ok(()) => {
                    info!(file = %path.display(), version = set.version, "calibrated parameters in use");
                    ParamStart::Loaded(set.version)
                }
                Err(e) => fallback(
                    pipeline,
                    PersistError::Inconsistent {
                        path: path.clone(),
                        reason: format!("set version {}: {e}", set.version),
                    },
                ),
            },
        },
    }
}

/// Owns the connection (see the module doc).
struct LinkTask<C: Connector> {
    connector: C,
    filters: Vec<IdFilter>,
    /// Bounded: a slow pipeline slows the reader, and the kernel queue (or
    /// the in-process bus) counts what overflows as lost.
    frames: mpsc::Sender<LinkEvent>,
    sink: watch::Sender<Option<C::Tx>>,
    /// Link losses the pipeline task met while sending (see [`BusError::is_link_loss`]).
    link_lost: mpsc::Receiver<BusError>,
    outages: Arc<AtomicU64>,
    /// Connections opened, for the state file's periodic writes.
    connections: Arc<AtomicU64>,
    token: CancellationToken,
}

impl<C: Connector> LinkTask<C> {
    #[instrument(skip(self), fields(iface = %self.connector.name()))]
    async fn run(mut self) -> Result<u64, BusError> {
        let mut backoff = BACKOFF_MIN;
        let mut connections = 0u64;
        // Failed opens in a row: the first few are logged (the first with a
        // hint), then one in OPEN_FAILURES_LOG_EVERY, so a missing interface
        // does not fill the journal at the retry rate.
        let mut failed_opens = 0u64;
        loop {
            if self.token.is_cancelled() {
                return Ok(connections);
            }
            let mut cause = None;
            match self.connector.connect(&self.filters) {
                Ok((mut rx, tx)) => {
                    failed_opens = 0;
                    connections += 1;
                    self.connections.store(connections, Ordering::Relaxed);
                    info!(connections, "CAN interface open");
                    // A loss reported by a send on the previous socket is over.
                    while self.link_lost.try_recv().is_ok() {}
                    self.sink.send_replace(Some(tx));
                    let outcome = self.pump(&mut rx).await;
                    self.sink.send_replace(None);
                    match outcome {
                        Ok(true) => return Ok(connections),
                        Ok(false) => {
                            self.outages.fetch_add(1, Ordering::Relaxed);
                            backoff = BACKOFF_MIN;
                        }
                        Err(e) if e.is_transient() => {
                            self.outages.fetch_add(1, Ordering::Relaxed);
                            warn!(cause = %e, "CAN interface lost; reopening");
                            backoff = BACKOFF_MIN;
                            cause = Some(e);
                        }
                        Err(e) => {
                            error!(cause = %e, "CAN transport failed for good");
                            self.token.cancel();
                            return Err(e);
                        }
                    }
                }
                Err(e) if e.is_transient() => {
                    failed_opens += 1;
                    let retry_in_ms = backoff.as_millis() as u64;
                    match e.hint() {
                        Some(hint) if failed_opens == 1 => {
                            warn!(cause = %e, retry_in_ms, hint, "cannot open CAN interface");
                        }
                        _ if failed_opens <= 5
                            || failed_opens.is_multiple_of(OPEN_FAILURES_LOG_EVERY) =>
                        {
                            warn!(cause = %e, retry_in_ms, failed_opens, "cannot open CAN interface");
                        }
                        _ => {}
                    }
                    cause = Some(e);
                }
                Err(e) => {
                    error!(cause = %e, "cannot open CAN interface");
                    self.token.cancel();
                    return Err(e);
                }
            }
            // The token is watched during the backoff too: SIGTERM is never
            // held up by a missing interface.
            tokio::select! {
                () = self.token.cancelled() => return Ok(connections),
                () = tokio::time::sleep(backoff) => {}
            }
            backoff = next_backoff(backoff, cause.as_ref());
        }
    }

    /// Forwards events; `Ok(true)` on shutdown, `Ok(false)` on bus-off
    /// (reopen), `Err` when the link is lost, seen here or by a send.
    async fn pump(&mut self, rx: &mut C::Rx) -> Result<bool, BusError> {
        loop {
            let event = tokio::select! {
                () = self.token.cancelled() => return Ok(true),
                Some(e) = self.link_lost.recv() => return Err(e),
                event = rx.recv() => event?,
            };
            let out = match event {
                BusEvent::Frame(r) => LinkEvent::Frame(r),
                BusEvent::Lost { count } => {
                    warn!(count, "frames lost: the pipeline fell behind");
                    LinkEvent::Lost(count)
                }
                BusEvent::Error { error, .. } => {
                    let severity = error.severity();
                    if severity == ErrorSeverity::BusOff {
                        warn!("CAN controller bus-off; reopening after a backoff");
                        return Ok(false);
                    }
                    debug!(error = severity.as_str(), "CAN error frame");
                    continue;
                }
            };
            tokio::select! {
                () = self.token.cancelled() => return Ok(true),
                sent = self.frames.send(out) => if sent.is_err() { return Ok(true) },
            }
        }
    }
}

/// What a checked `ODOM_CMD` asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum OdomRequest {
    /// NONE: nothing (a sender that transmits ODOM_CMD cyclically sends
    /// this between requests).
    Nothing,
    /// Publish the pose now.
    PublishNow,
    /// Move the pose to the origin (the vehicle stands still).
    ResetPose,
}

/// Why an `ODOM_CMD` frame was not carried out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
enum OdomRefusal {
    /// The CRC-8 in byte 7 does not match.
    #[error("bad checksum")]
    BadChecksum,
    /// The same rolling counter as the frame before: a repeat, not a new command.
    #[error("repeated counter {0}")]
    RepeatedCounter(u64),
    /// RESET_POSE without the configured arming code.
    #[error("RESET_POSE with a wrong arming code")]
    BadArmingCode,
    /// RESET_POSE while the vehicle moves: the origin would be a blur.
    #[error("RESET_POSE while the vehicle moves")]
    Moving,
    /// An `ODOM_REQUEST` value this daemon does not know.
    #[error("request {0} is not one of NONE (0), PUBLISH_NOW (1), RESET_POSE (2)")]
    Unknown(u64),
}

impl OdomRefusal {
    /// Kinds of refusal, for [`OdomRefusals`].
    const KINDS: usize = 5;

    /// This refusal's kind, `0..KINDS`, whatever counter or request it carries.
    fn kind(self) -> usize {
        match self {
            Self::BadChecksum => 0,
            Self::RepeatedCounter(_) => 1,
            Self::BadArmingCode => 2,
            Self::Moving => 3,
            Self::Unknown(_) => 4,
        }
    }
}

/// Refused `ODOM_CMD` frames: all counted (the DBC promises that frames
/// failing a check are dropped and counted), but each kind logged only the
/// first time in a statistics period, so a sender that gets every frame
/// wrong at bus rate cannot flood the log.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct OdomRefusals {
    /// Refusals since start.
    total: u64,
    /// The kinds already logged in this period.
    logged: [bool; OdomRefusal::KINDS],
}

impl OdomRefusals {
    /// Counts `refusal`; true when it is the first of its kind this period
    /// and so is to be logged.
    fn count(&mut self, refusal: OdomRefusal) -> bool {
        self.total += 1;
        !std::mem::replace(&mut self.logged[refusal.kind()], true)
    }

    /// A statistics line was written: every kind may be logged again.
    fn new_period(&mut self) {
        self.logged = [false; OdomRefusal::KINDS];
    }
}

/// The checks of `ODOM_CMD` (pure: frame bytes in, decision out).
#[derive(Debug, Clone)]
struct OdomCommands {
    request: SignalHandle,
    arming: SignalHandle,
    counter: SignalHandle,
    /// ODOM_CMD's CRC-8 (canodom.dbc's layout, the rc-car one).
    crc: Checksum,
    arming_code: Option<u8>,
    last_counter: Option<u64>,
}

impl OdomCommands {
    fn new(own_db: &Database, arming_code: Option<u8>) -> canodom_dbc::Result<Self> {
        Ok(Self {
            request: own_db.signal("ODOM_CMD.ODOM_REQUEST")?,
            arming: own_db.signal("ODOM_CMD.ARMING_CODE")?,
            counter: own_db.signal("ODOM_CMD.COUNTER")?,
            crc: Checksum::rc_car(),
            arming_code,
            last_counter: None,
        })
    }

    /// Checks a frame in the order the DBC states: CRC, counter, then what
    /// it asks. A frame with a bad CRC does not move the counter on.
    fn judge(&mut self, data: &[u8], standstill: bool) -> Result<OdomRequest, OdomRefusal> {
        if !self.crc.is_valid(data) {
            return Err(OdomRefusal::BadChecksum);
        }
        let counter = self.counter.raw(data).ok_or(OdomRefusal::BadChecksum)?;
        if self.last_counter.replace(counter) == Some(counter) {
            return Err(OdomRefusal::RepeatedCounter(counter));
        }
        match self.request.raw(data).ok_or(OdomRefusal::BadChecksum)? {
            0 => Ok(OdomRequest::Nothing),
            1 => Ok(OdomRequest::PublishNow),
            2 if self
                .arming_code
                .is_some_and(|code| self.arming.raw(data) != Some(u64::from(code))) =>
            {
                Err(OdomRefusal::BadArmingCode)
            }
            2 if !standstill => Err(OdomRefusal::Moving),
            2 => Ok(OdomRequest::ResetPose),
            other => Err(OdomRefusal::Unknown(other)),
        }
    }
}

/// The input faults the live calibration is told of, by code (the index
/// here, from 1): a run that meets one is cut there.
const FAULT_CODES: [Reject; 5] = [
    Reject::WheelFault,
    Reject::WheelGap,
    Reject::BadCounter,
    Reject::BadChecksum,
    Reject::NonFinite,
];

/// The calibration's fault code of a frame that came with `reasons`: the
/// first of [`FAULT_CODES`] among them (a frame can earn several).
fn fault_code(reasons: Reasons) -> Option<u8> {
    FAULT_CODES
        .iter()
        .position(|&r| reasons.contains(r))
        .and_then(|i| u8::try_from(i + 1).ok())
}

/// Owns the pipeline (see the module doc).
struct OdometryTask<Tx> {
    pipeline: Pipeline,
    encoder: PoseEncoder,
    frames: mpsc::Receiver<LinkEvent>,
    sink: watch::Receiver<Option<Tx>>,
    token: CancellationToken,
    pose_period: Duration,
    stats_period: Duration,
    publish_on_update: bool,
    cmd_id: FrameId,
    /// The bus's position fixes (`[calibration.fixes]`): their id and signals.
    fixes: Option<(FrameId, FixSignals)>,
    odom_commands: OdomCommands,
    odom_refusals: OdomRefusals,
    /// SecOC: verifies secured frames before anything acts on them; the
    /// calibration task signs its `CALIB_PARAMS` with the same gate.
    security: Arc<Mutex<SecurityGate>>,
    /// The start of the gate's clock (tokio's: monotonic, virtual in paused
    /// tests): pairing and announcements run on it, never on the wall clock.
    mono_start: Instant,
    notifier: Option<Notifier>,
    observers: Observers,
    published: u64,
    lost: u64,
    /// Plausibility warnings already logged (#32): each is logged once, at
    /// the pose sample whose ODOM_QUALITY first says INPUT_IMPLAUSIBLE.
    plausibility_logged: usize,
    /// Tells the link task of a link loss a send met (see [`BusError::is_link_loss`]).
    link_lost: mpsc::Sender<BusError>,
    outages: Arc<AtomicU64>,
    connections: Arc<AtomicU64>,
    /// The state file's writer and the period of its writes: handed a copy
    /// of the state, never waited for (see [`crate::state_file::write_latest`]).
    state_out: Option<(watch::Sender<Option<Summary>>, Duration)>,
    /// The channels to the calibration task (its input sender is dropped
    /// with this task, after the last frame). The bus clock it keeps there
    /// is the last frame's bus timestamp and when it arrived: the pose flags
    /// are judged on the bus clock, whatever clock this process runs on.
    links: OdometryLinks,
    calib_cmd_id: FrameId,
    calib_ack_id: FrameId,
    /// The live GNSS source's latest summary, for the diagnostics (never waited on).
    gnss: Option<watch::Receiver<Option<crate::gnss_task::GnssSummary>>>,
}

impl<Tx: FrameSink + Clone> OdometryTask<Tx> {
    #[instrument(skip(self))]
    async fn run(mut self) -> Summary {
        let mut pose_tick = tokio::time::interval(self.pose_period);
        pose_tick.set_missed_tick_behavior(MissedTickBehavior::Delay);
        let mut stats_tick = tokio::time::interval(self.stats_period);
        stats_tick.set_missed_tick_behavior(MissedTickBehavior::Delay);
        stats_tick.tick().await;
        let watchdog = self.notifier.as_ref().and_then(Notifier::watchdog_interval);
        let mut watchdog_tick =
            tokio::time::interval(watchdog.unwrap_or(Duration::from_secs(3600)));
        if let Some(n) = &self.notifier
            && let Err(e) = n.ready("canodom running")
        {
            warn!(cause = %e, "sd_notify READY failed");
        }
        let mut last_stats = *self.pipeline.stats();
        let mut last_stats_at = Instant::now();
        let state_every = self.state_out.as_ref().map(|(_, every)| *every);
        // (At least 10 ms: `interval` refuses a zero period.)
        let mut state_tick = tokio::time::interval(
            state_every
                .unwrap_or(Duration::from_secs(3600))
                .max(Duration::from_millis(10)),
        );
        state_tick.set_missed_tick_behavior(MissedTickBehavior::Delay);
        // Not at once: the file still holds the previous run's state until
        // there is something new.
        state_tick.tick().await;
        // SecOC announcements (SECOC_SYNC): at once, then every period.
        let keyed = lock(&self.security).is_keyed();
        let mut sync_tick = tokio::time::interval(Duration::from_micros(
            canodom_protocol::secoc::SYNC_PERIOD_US,
        ));
        sync_tick.set_missed_tick_behavior(MissedTickBehavior::Delay);
        // The drift watch's flags and candidate last written: a flag that
        // rises or clears is in the file at once, not a period later (#46
        // item 3; the period may be minutes).
        let mut drift_open = true;
        let mut drift_seen = drift_flags(&self.links.drift.borrow_and_update());
        loop {
            tokio::select! {
                biased;
                Some((version, values)) = self.links.apply.recv() => {
                    self.apply_params(version, &values);
                    // What the set reset, and the set's identity, at once.
                    self.save_state();
                }
                event = self.frames.recv() => match event {
                    Some(event) => self.handle(event).await,
                    None => break,
                },
                _ = pose_tick.tick() => self.publish().await,
                _ = sync_tick.tick(), if keyed => self.announce(true).await,
                _ = stats_tick.tick() => {
                    // One lock for the line: a second lock() in the same
                    // statement would wait on the first's guard forever.
                    let (auth_refused, auth_epochs) = {
                        let mut gate = lock(&self.security);
                        gate.expire(self.mono_us());
                        let figures = (gate.counts(), gate.epochs());
                        gate.new_period();
                        figures
                    };
                    let s = *self.pipeline.stats();
                    let secs = last_stats_at.elapsed().as_secs_f64().max(1e-9);
                    info!(
                        fps = format!("{:.1}", (s.frames - last_stats.frames) as f64 / secs),
                        stats = %s, lost = self.lost, poses = self.published,
                        outages = self.outages.load(Ordering::Relaxed),
                        odom_cmd_refused = self.odom_refusals.total,
                        auth_refused = %auth_refused,
                        auth_epochs,
                        "statistics"
                    );
                    self.odom_refusals.new_period();
                    last_stats = s;
                    last_stats_at = Instant::now();
                }
                _ = watchdog_tick.tick(), if watchdog.is_some() => {
                    if let Some(n) = &self.notifier { let _ = n.watchdog(); }
                }
                _ = state_tick.tick(), if state_every.is_some() => self.save_state(),
                changed = self.links.drift.changed(), if drift_open => {
                    // Err: the calibration task has stopped, nothing will change.
                    drift_open = changed.is_ok();
                    self.save_on_drift_change(&mut drift_seen);
                }
                () = self.token.cancelled() => {
                    // Drain what the link task already queued: nothing received is lost.
                    while let Ok(event) = self.frames.try_recv() {
                        self.handle(event).await;
                    }
                    break;
                }
            }
        }
        // The calibration task handles what it was sent, and ends when this
        // task (its input sender with it) is gone.
        if let Some(n) = &self.notifier {
            let _ = n.stopping();
        }
        // A secured frame still waiting for its authenticator when the bus
        // went quiet is refused now, so the last count is complete.
        let end = self.mono_us() + protocol_pair_timeout_us();
        lock(&self.security).expire(end);
        info!(
            stats = %self.pipeline.stats(),
            odom_cmd_refused = self.odom_refusals.total,
            auth_refused = %lock(&self.security).counts(),
            "pipeline stopped"
        );
        // The end state, for the writer's last write.
        self.save_state();
        self.summary()
    }

    /// Where the run stands now.
    fn summary(&self) -> Summary {
        Summary {
            stats: *self.pipeline.stats(),
            state: *self.pipeline.state(),
            last_step: self.pipeline.last_step(),
            poses_published: self.published,
            frames_lost: self.lost,
            connections: self.connections.load(Ordering::Relaxed),
            outages: self.outages.load(Ordering::Relaxed),
            params: self.pipeline.params_in_use(),
            param_identity: self.pipeline.param_identity(),
            state_file: None,
            gnss: None,
            // Before its first refit the watch has nothing to say, unless
            // it holds the front tyres' first reading from a previous run.
            drift: Some(self.links.drift.borrow().clone())
                .filter(|d| d.refits > 0 || d.front_baseline.is_some()),
        }
    }

    /// Hands the state file's writer a copy of where the run stands (it
    /// replaces one not yet written: only the newest matters).
    fn save_state(&self) {
        if let Some((tx, _)) = &self.state_out {
            tx.send_replace(Some(self.summary()));
        }
    }

    /// Writes the state file when the drift watch's flags or candidate
    /// differ from `seen` (and remembers them).
    fn save_on_drift_change(&mut self, seen: &mut DriftFlags) {
        let now = drift_flags(&self.links.drift.borrow_and_update());
        if now != *seen {
            *seen = now;
            self.save_state();
        }
    }

    /// Hands an input to the calibration task; waits when it is behind
    /// (it needs every step of a run), and drops nothing.
    async fn to_calibration(&self, input: CalibInput) {
        if self.links.inputs.send(input).await.is_err() {
            debug!("calibration task stopped; input dropped");
        }
    }

    /// µs on the gate's monotonic clock.
    fn mono_us(&self) -> u64 {
        self.mono_start.elapsed().as_micros() as u64
    }

    /// Sends the gate's announcement (`SECOC_SYNC` and its authenticators);
    /// `tick`: one period has passed, the floor moves up.
    async fn announce(&mut self, tick: bool) {
        let frames = match lock(&self.security).announce(tick) {
            Ok(f) => f,
            Err(e) => {
                warn!(cause = %e, "SecOC: a new epoch could not be stored; the current one goes on");
                return;
            }
        };
        let _ = self.send_frames(&frames, "SecOC announcement").await;
    }

    /// Sends `frames` in order on the bus, if it is up
    /// ([`crate::calib_task::send_all`]).
    async fn send_frames(&self, frames: &[CanFrame], what: &str) -> bool {
        let tx = self.sink.borrow().clone();
        crate::calib_task::send_all(tx.as_ref(), frames, &self.link_lost, what).await
    }

    /// Passes a received frame through the SecOC gate: `false` when nothing
    /// may act on it (refused, counted and logged once a period, or held
    /// until its authenticator arrives); an authenticated frame replaces it,
    /// and the second `true` asks for the new floor to be announced.
    fn admit(&self, r: &mut Received) -> (bool, bool) {
        let mut gate = lock(&self.security);
        match gate.admit(&r.frame, self.mono_us()) {
            Admit::Pass => (true, false),
            Admit::Authentic(frame) => {
                r.frame = frame;
                (true, true)
            }
            Admit::Held => (false, false),
            Admit::Refused {
                reason,
                log,
                last_accepted,
            } => {
                if log {
                    warn!(%reason, id = %r.frame.id(), last_accepted, refused = %gate.counts(),
                        "secured frame refused (more of this reason are only counted until the next statistics line)");
                }
                (false, false)
            }
        }
    }

    async fn handle(&mut self, event: LinkEvent) {
        match event {
            LinkEvent::Lost(n) => self.lost += n,
            LinkEvent::Frame(mut r) => {
                (self.links.clock).send_replace(Some((r.timestamp, Instant::now())));
                if let Some(tap) = &mut self.observers.tap {
                    tap.frame(r.timestamp, &r.frame);
                }
                let (admitted, announce) = self.admit(&mut r);
                if announce {
                    // The floor moved above the accepted counter: say so at
                    // once, so the next sender need not wait for a period.
                    self.announce(false).await;
                }
                if !admitted {
                    return;
                }
                let id = r.frame.id();
                if id == self.calib_cmd_id {
                    self.to_calibration(CalibInput::Command(r.timestamp, r.frame))
                        .await;
                    return;
                }
                if id == self.calib_ack_id {
                    self.to_calibration(CalibInput::Ack(r.timestamp, r.frame))
                        .await;
                    return;
                }
                if id == self.cmd_id {
                    self.command(r.timestamp, &r.frame).await;
                    return;
                }
                if let Some((fix_id, f)) = &self.fixes
                    && id == *fix_id
                {
                    let data = r.frame.data();
                    if let (Some(first), Some(second)) =
                        (f.first.decode(data), f.second.decode(data))
                    {
                        let geodetic = f.geodetic;
                        self.to_calibration(CalibInput::Fix {
                            t: r.timestamp,
                            first,
                            second,
                            geodetic,
                            // The bus's fixes state no error.
                            sigma_m: None,
                        })
                        .await;
                    }
                    return;
                }
                let outcome = self.pipeline.push(r.timestamp, &r.frame);
                if let Some(code) = fault_code(outcome.reasons()) {
                    self.to_calibration(CalibInput::Fault(r.timestamp, code))
                        .await;
                }
                if let Outcome::Step(step, _) = outcome {
                    self.to_calibration(CalibInput::Step {
                        t: r.timestamp,
                        rear_rev: step.rear_rev,
                        front_rev: step.front_rev,
                        steer_signal: step.steer_signal,
                        yaw_rate_radps: step.yaw_rate_radps,
                        window: step.correction,
                    })
                    .await;
                    if let Some(w) = &self.observers.steps {
                        w.send_replace(Some(step));
                    }
                    if self.publish_on_update {
                        self.publish().await;
                    }
                }
                if let Some(w) = &self.observers.stats {
                    w.send_replace(*self.pipeline.stats());
                }
            }
        }
    }

    /// `ODOM_CMD`: PUBLISH_NOW publishes at once; RESET_POSE moves the pose
    /// to the origin (at standstill) and publishes it; NONE does nothing;
    /// anything refused is counted, and logged with its reason (see
    /// [`OdomRefusals`]).
    async fn command(&mut self, t: Timestamp, frame: &CanFrame) {
        let standstill = still_at(&self.links.standstill, t);
        match self.odom_commands.judge(frame.data(), standstill) {
            Ok(OdomRequest::Nothing) => {}
            Ok(OdomRequest::PublishNow) => self.publish().await,
            Ok(OdomRequest::ResetPose) => {
                self.pipeline.reset_pose();
                info!("pose reset to the origin by ODOM_CMD RESET_POSE");
                self.publish().await;
            }
            Err(refusal) => {
                if self.odom_refusals.count(refusal) {
                    warn!(
                        %refusal,
                        refused_since_start = self.odom_refusals.total,
                        "ODOM_CMD ignored (more of this kind are only counted until the next statistics line)"
                    );
                }
            }
        }
    }

    /// The bus clock now: the last frame's timestamp plus the time since.
    fn now(&self) -> Option<Timestamp> {
        let (t, at) = (*self.links.clock.borrow())?;
        Some(Timestamp::from_micros(
            t.as_micros() + at.elapsed().as_micros() as u64,
        ))
    }

    /// A set the calibration committed or rolled back to, at standstill.
    fn apply_params(&mut self, version: u16, values: &canodom_params::persist::ParamValues) {
        match self.pipeline.apply_params(Some((version, values))) {
            Ok(()) => info!(version, "calibrated parameters applied"),
            Err(e) => {
                error!(version, cause = %e, "calibrated parameters refused by the filter");
            }
        }
    }

    async fn publish(&mut self) {
        let Some(now) = self.now() else { return };
        let pose = self.pipeline.pose_output(now);
        let warnings = self.pipeline.plausibility_warnings();
        for w in warnings.iter().skip(self.plausibility_logged) {
            warn!(
                signal = w.signal,
                suspect = %w.suspicion,
                flag = "ODOM_QUALITY.INPUT_IMPLAUSIBLE",
                "implausible input: {w}"
            );
        }
        self.plausibility_logged = warnings.len();
        if let Some(tap) = &mut self.observers.tap {
            let gnss = self.gnss.as_ref().and_then(|g| {
                g.borrow()
                    .as_ref()
                    .map(crate::gnss_task::GnssSummary::state)
            });
            let drift = crate::calib_task::drift_state(&self.links.drift.borrow());
            tap.pose(
                &self.pipeline,
                pose,
                self.links.phase.borrow().as_str(),
                gnss,
                drift,
            );
        }
        let Ok(frames) = self.encoder.encode(&pose) else {
            return;
        };
        if self.send_frames(&frames, "pose frame").await {
            self.published += 1;
        }
    }
}

/// What of the drift watch's report writes the state file when it
/// changes: the flags, and the candidate (the file shows the set a COMMIT
/// would store, not one a later refit replaced).
fn drift_flags(d: &canodom_live::drift_watch::DriftReport) -> DriftFlags {
    (d.flagged.clone(), d.candidate)
}

/// See [`drift_flags`].
type DriftFlags = (
    Vec<canodom_calib::drift::Param>,
    Option<canodom_params::persist::ParamValues>,
);

/// How long a secured frame waits for its authenticator, µs; at stop every
/// waiting frame has waited its last.
fn protocol_pair_timeout_us() -> u64 {
    canodom_protocol::secoc::PAIR_TIMEOUT_US + 1
}

#[cfg(test)]
mod tests {
    use super::*;
    use canodom_params::persist::{ParamFile, ParamValues, store};

    fn rc_car(param_file: &str) -> (Config, std::path::PathBuf) {
        let p = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/examples/rc_car.toml"));
        let mut c = Config::load(p).unwrap();
        let dir =
            std::env::temp_dir().join(format!("canodom-live-{}-{param_file}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        c.calibration.param_file = dir.join(param_file);
        let _ = std::fs::remove_file(&c.calibration.param_file);
        (c, dir)
    }

    /// A set with the rc_car's steering map (degrees in, radians out).
    fn values(tread_m: f64) -> ParamValues {
        ParamValues {
            rear_tread_m: tread_m,
            rear_left_diameter_m: 0.09,
            rear_right_diameter_m: 0.0915,
            steering_gain: 1f64.to_radians(),
            steering_offset_rad: 0.0,
            yaw_rate_bias_radps: None,
            yaw_rate_scale: None,
            yaw_rate_bias_sigma_radps: None,
        }
    }

    /// An ODOM_CMD payload with a valid CRC.
    fn odom_cmd(request: u8, arming_code: u8, counter: u8) -> [u8; 8] {
        let mut d = [0u8; 8];
        d[0] = (request & 0x0F) | (arming_code << 4);
        d[1] = arming_code >> 4;
        d[6] = (counter & 0x0F) << 4;
        Checksum::rc_car().apply(&mut d).unwrap();
        d
    }

    #[test]
    fn odom_commands_are_checked_for_crc_counter_arming_and_standstill() {
        let base = canodom_protocol::own_dbc::BaseId::new(0x600, false).unwrap();
        let db = Database::parse(
            &canodom_protocol::own_dbc::dbc_for_base(base),
            "canodom.dbc",
        )
        .unwrap();
        let mut open = OdomCommands::new(&db, None).unwrap();
        assert_eq!(
            open.judge(&odom_cmd(1, 0, 0), false),
            Ok(OdomRequest::PublishNow)
        );
        // The same counter again is a repeat, the next one is new.
        assert_eq!(
            open.judge(&odom_cmd(1, 0, 0), false),
            Err(OdomRefusal::RepeatedCounter(0))
        );
        assert_eq!(
            open.judge(&odom_cmd(2, 0x77, 1), true),
            Ok(OdomRequest::ResetPose),
            "no arming code configured: any is accepted"
        );
        assert_eq!(
            open.judge(&odom_cmd(2, 0, 2), false),
            Err(OdomRefusal::Moving)
        );
        assert_eq!(
            open.judge(&odom_cmd(7, 0, 3), true),
            Err(OdomRefusal::Unknown(7))
        );
        // NONE, as a cyclic sender sends between requests: nothing to do,
        // nothing refused (moving or not), and it takes its counter.
        assert_eq!(
            open.judge(&odom_cmd(0, 0, 5), false),
            Ok(OdomRequest::Nothing)
        );
        assert_eq!(
            open.judge(&odom_cmd(0, 0, 5), false),
            Err(OdomRefusal::RepeatedCounter(5))
        );
        let mut bad = odom_cmd(2, 0, 4);
        bad[7] ^= 1;
        assert_eq!(open.judge(&bad, true), Err(OdomRefusal::BadChecksum));
        // A bad CRC did not take the counter: the good frame with it passes.
        assert_eq!(
            open.judge(&odom_cmd(2, 0, 4), true),
            Ok(OdomRequest::ResetPose)
        );
        assert_eq!(open.judge(&[0; 3], true), Err(OdomRefusal::BadChecksum));

        let mut armed = OdomCommands::new(&db, Some(0xA5)).unwrap();
        assert_eq!(
            armed.judge(&odom_cmd(2, 0xA4, 0), true),
            Err(OdomRefusal::BadArmingCode)
        );
        assert_eq!(
            armed.judge(&odom_cmd(2, 0xA5, 1), true),
            Ok(OdomRequest::ResetPose)
        );
        // PUBLISH_NOW needs no arming code.
        assert_eq!(
            armed.judge(&odom_cmd(1, 0, 2), false),
            Ok(OdomRequest::PublishNow)
        );
    }

    #[test]
    fn odom_refusals_are_all_counted_and_each_kind_logged_once_a_period() {
        let mut refusals = OdomRefusals::default();
        // A sender with a broken CRC at bus rate: one line, every frame counted.
        let logged = (0..1000)
            .filter(|_| refusals.count(OdomRefusal::BadChecksum))
            .count();
        assert_eq!((logged, refusals.total), (1, 1000));
        // Another kind in the same period is news; its counter value is not a kind.
        assert!(refusals.count(OdomRefusal::RepeatedCounter(3)));
        assert!(!refusals.count(OdomRefusal::RepeatedCounter(4)));
        assert!(refusals.count(OdomRefusal::Moving));
        assert!(refusals.count(OdomRefusal::BadArmingCode));
        assert!(refusals.count(OdomRefusal::Unknown(9)));
        assert!(!refusals.count(OdomRefusal::Unknown(10)));
        // After a statistics line each kind is logged again; the total runs on.
        refusals.new_period();
        assert!(refusals.count(OdomRefusal::BadChecksum));
        assert!(!refusals.count(OdomRefusal::BadChecksum));
        assert_eq!(refusals.total, 1008);
    }

    #[test]
    fn a_stored_set_is_applied_at_start_and_a_damaged_file_falls_back_to_nominal() {
        let (c, dir) = rc_car("params.toml");
        let mut p = Pipeline::new(&c).unwrap();
        assert!(matches!(
            apply_param_file(&mut p, &c.calibration),
            ParamStart::Nominal
        ));
        let mut file = ParamFile::default();
        file.commit(values(0.31), "exact", 0, 10);
        file.commit(values(0.305), "exact", 1, 10);
        store(&c.calibration.param_file, &file).unwrap();
        assert!(matches!(
            apply_param_file(&mut p, &c.calibration),
            ParamStart::Loaded(2)
        ));
        assert_eq!(p.param_version(), Some(2));
        assert!((p.params().rear_tread_m() - 0.305).abs() < 1e-12);
        let out = p.pose_output(canodom_can::time::Timestamp::from_micros(0));
        assert_eq!((out.param_version, out.flags.nominal_params), (2, false));
        // One flipped digit in a value: the checksum no longer matches.
        let text = std::fs::read_to_string(&c.calibration.param_file).unwrap();
        let damaged = text.replacen("0.305", "0.306", 1);
        assert_ne!(text, damaged);
        std::fs::write(&c.calibration.param_file, damaged).unwrap();
        let start = apply_param_file(&mut p, &c.calibration);
        let ParamStart::Fallback(e) = start else {
            panic!("{start:?}")
        };
        assert!(e.to_string().contains("params.toml"), "{e}");
        assert_eq!(p.param_version(), None);
        assert!((p.params().rear_tread_m() - 0.30).abs() < 1e-12);
        let out = p.pose_output(canodom_can::time::Timestamp::from_micros(0));
        assert_eq!((out.param_version, out.flags.nominal_params), (0, true));
        // A set outside the configured bounds (±30 %) is refused at start too.
        let mut far = ParamFile::default();
        far.commit(values(0.5), "exact", 0, 10);
        store(&c.calibration.param_file, &far).unwrap();
        assert!(matches!(
            apply_param_file(&mut p, &c.calibration),
            ParamStart::Fallback(canodom_params::persist::PersistError::OutOfBounds { .. })
        ));
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn calibration_defaults_follow_the_base_id_and_the_nominal_parameters() {
        let (c, _dir) = rc_car("defaults.toml");
        let cal = &c.calibration;
        assert_eq!(cal.command_id, OwnFrame::CalibCmd.id(c.output.base_id));
        assert_eq!(cal.arming_code, None);
        assert_eq!(cal.ack_timeout, Duration::from_millis(500));
        assert_eq!(cal.writeback_retries, 3);
        let (lo, hi) = cal.bounds.rear_tread_m;
        assert!((lo - 0.21).abs() < 1e-12 && (hi - 0.39).abs() < 1e-12);
    }

    #[test]
    fn backoff_stays_short_while_the_interface_is_missing_or_down() {
        let down = BusError::InterfaceDown {
            iface: "vcan0".into(),
        };
        let gone = BusError::NoSuchInterface {
            iface: "vcan0".into(),
        };
        let other = BusError::Io {
            iface: "vcan0".into(),
            source: std::io::Error::from_raw_os_error(libc::EACCES),
        };
        for cause in [&down, &gone] {
            let mut b = BACKOFF_MIN;
            for _ in 0..20 {
                b = next_backoff(b, Some(cause));
                assert!(b <= Duration::from_millis(500), "{b:?}");
            }
            assert_eq!(b, BACKOFF_MAX_LINK);
        }
        let mut b = BACKOFF_MIN;
        for _ in 0..20 {
            b = next_backoff(b, Some(&other));
        }
        assert_eq!(b, BACKOFF_MAX);
        assert!(down.is_link_loss() && gone.is_link_loss() && !other.is_link_loss());
        assert!(
            !BusError::TxQueueFull {
                iface: "vcan0".into()
            }
            .is_link_loss()
        );
    }
}
