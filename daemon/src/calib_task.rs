//! The calibration task: owns the [`LiveCalibration`] and carries out what
//! it asks for, away from the odometry task's frame path.
//!
//! The odometry task forwards the calibration's frames (`CALIB_CMD`,
//! `CALIB_ACK`, the bus's position fixes), every filter step and every input
//! fault over one bounded channel, in bus order; this task answers on the
//! bus, sends status and parameter frames, hands sets to apply back over a
//! second bounded channel, and publishes the standstill judgement the
//! odometry's RESET_POSE needs. Storing the parameter file (`fsync`) and
//! computing a calibration run on tokio's blocking pool; the calibration
//! refuses commands as busy until they are done, so at most one is out.
//!
//! The online calibration's refits (#46: the drift watch) run on the
//! blocking pool too, at most one at a time and beside a store or a job:
//! a refit of three minutes of the drive takes a good part of a second,
//! and the steps, fixes and commands keep coming meanwhile. A flag that
//! rises or clears is a warning (an info line) in the log, in the words of
//! `replay --fixes`.
//!
//! Shutdown: when the odometry task has drained its frames it drops its
//! sender; this task handles everything still queued, waits for a store in
//! flight (a commit is stored whole or not at all), and returns.

use canodom_calib::calibrator::{Job, JobOutcome};
use canodom_calib::session::Phase;
use canodom_calib::standstill::Standstill;
use canodom_can::bus::{BusError, FrameSink};
use canodom_can::frame::CanFrame;
use canodom_can::time::Timestamp;
use canodom_live::drift_watch::{DriftReport, RefitJob};
use canodom_live::{LiveCalibration, Output};
use canodom_offline::online::Epoch;
use canodom_params::persist::{ParamFile, ParamValues};
use canodom_pipeline::config::Config;
use canodom_pipeline::gate::SecurityGate;
use canodom_protocol::calib_wire::GnssStatus;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;
use tokio::time::{Instant, MissedTickBehavior};
use tracing::{debug, info, warn};

/// How often the live calibration's clock runs (status periods and ACK
/// timeouts are multiples of it).
const CALIB_TICK: Duration = Duration::from_millis(50);

/// What the odometry task forwards, in bus order.
#[derive(Debug, Clone, Copy)]
pub enum CalibInput {
    /// A `CALIB_CMD` frame.
    Command(Timestamp, CanFrame),
    /// A `CALIB_ACK` frame.
    Ack(Timestamp, CanFrame),
    /// A position fix: local x/y in metres or (geodetic) latitude/longitude.
    Fix {
        /// Bus time.
        t: Timestamp,
        /// x or latitude.
        first: f64,
        /// y or longitude.
        second: f64,
        /// Whether the fix is latitude/longitude.
        geodetic: bool,
        /// The 1σ error per axis its source states (gpsd, ROS 2), metres.
        sigma_m: Option<f64>,
    },
    /// The input path refused or faulted a wheel frame.
    Fault(Timestamp, u8),
    /// A filter step.
    Step {
        /// Bus time.
        t: Timestamp,
        /// Rear wheel revolutions (left, right) since the previous step.
        rear_rev: (f64, f64),
        /// Front wheel revolutions (left, right), when the front was fresh.
        front_rev: Option<(f64, f64)>,
        /// The steering signal.
        steer_signal: Option<f64>,
        /// The yaw rate the filter used.
        yaw_rate_radps: Option<f64>,
        /// What the filter's correction window did at this step.
        window: canodom_fusion::ekf::WindowOutcome,
    },
}

/// A set the odometry must put into the filter (version, values).
pub type ApplyParams = (u16, ParamValues);

/// The bus clock the odometry task keeps: the last frame's bus timestamp and
/// when it arrived.
pub type BusClock = watch::Receiver<Option<(Timestamp, Instant)>>;

/// A slow effect carried out on the blocking pool.
enum Effect {
    Persisted(Result<(), String>),
    Computed(Box<JobOutcome>),
}

/// The calibration task (see the module doc).
pub struct CalibTask<Tx> {
    /// The calibration over CAN.
    pub live: LiveCalibration,
    /// Inputs from the odometry task.
    pub inputs: mpsc::Receiver<CalibInput>,
    /// Sets to apply, to the odometry task.
    pub apply: mpsc::Sender<ApplyParams>,
    /// The standstill judgement, to the odometry task.
    pub standstill: watch::Sender<Standstill>,
    /// The guided session's phase, to the odometry task (its recordings).
    pub phase: watch::Sender<Phase>,
    /// The bus clock.
    pub clock: BusClock,
    /// The sending half of the transport (`None` while disconnected).
    pub sink: watch::Receiver<Option<Tx>>,
    /// SecOC: signs `CALIB_PARAMS` (nothing is sent when it cannot be signed).
    pub security: Arc<Mutex<SecurityGate>>,
    /// Tells the link task of a link loss a send met.
    pub link_lost: mpsc::Sender<BusError>,
    /// The parameter file.
    pub param_file: PathBuf,
    /// Where reports of committed sets go (one folder per version).
    pub report_root: PathBuf,
    /// Fixes of a live GNSS source (`[gnss]`), on a channel of their own so
    /// that they never take room the odometry task's inputs need.
    pub gnss: Option<mpsc::Receiver<CalibInput>>,
    /// The live GNSS source's `CALIB_STATUS` page 6 as its forwarder keeps
    /// it (set by [`CalibTask::watch_gnss`]).
    gnss_status: Option<watch::Receiver<GnssStatus>>,
    /// The configuration the online calibration's refits fit with.
    pub refit_config: Arc<Config>,
    /// The drift watch's report, to the odometry task (state file, diagnostics).
    pub drift: watch::Sender<DriftReport>,
    /// The refit in flight and what it refits.
    refit: Option<(JoinHandle<Epoch>, Arc<RefitJob>)>,
}

/// The odometry task's ends of the channels to the calibration task.
#[derive(Debug)]
pub struct OdometryLinks {
    /// Inputs to the calibration (bounded: the odometry waits, nothing is dropped).
    pub inputs: mpsc::Sender<CalibInput>,
    /// Sets to apply.
    pub apply: mpsc::Receiver<ApplyParams>,
    /// The bus clock the odometry keeps.
    pub clock: watch::Sender<Option<(Timestamp, Instant)>>,
    /// The calibration's standstill judgement.
    pub standstill: watch::Receiver<Standstill>,
    /// The guided session's phase.
    pub phase: watch::Receiver<Phase>,
    /// The drift watch's report.
    pub drift: watch::Receiver<DriftReport>,
}

impl<Tx: FrameSink + Clone> CalibTask<Tx> {
    /// The task over `live`, and the odometry task's ends of its channels.
    pub fn new(
        live: LiveCalibration,
        security: Arc<Mutex<SecurityGate>>,
        sink: watch::Receiver<Option<Tx>>,
        link_lost: mpsc::Sender<BusError>,
        param_file: PathBuf,
        report_root: PathBuf,
        refit_config: Arc<Config>,
    ) -> (Self, OdometryLinks) {
        // Bounded both ways: calibration inputs wait for the calibration
        // task (nothing it needs may be dropped), and sets to apply are few.
        let (inputs_tx, inputs) = mpsc::channel(1024);
        let (apply, apply_rx) = mpsc::channel(4);
        let (clock_tx, clock) = watch::channel(None);
        let (standstill, standstill_rx) = watch::channel(live.standstill());
        let (phase, phase_rx) = watch::channel(live.phase());
        let (drift, drift_rx) = watch::channel(live.drift());
        let task = Self {
            live,
            inputs,
            apply,
            standstill,
            phase,
            clock,
            sink,
            security,
            link_lost,
            param_file,
            report_root,
            gnss: None,
            gnss_status: None,
            refit_config,
            drift,
            refit: None,
        };
        let links = OdometryLinks {
            inputs: inputs_tx,
            apply: apply_rx,
            clock: clock_tx,
            standstill: standstill_rx,
            phase: phase_rx,
            drift: drift_rx,
        };
        (task, links)
    }

    /// Shows the live GNSS source on `CALIB_STATUS` page 6, as its
    /// forwarder keeps it in `status`.
    pub fn watch_gnss(&mut self, mut status: watch::Receiver<GnssStatus>) {
        self.live.set_gnss_status(*status.borrow_and_update());
        self.gnss_status = Some(status);
    }

    /// Takes the GNSS source's latest page into the status pages.
    fn refresh_gnss(&mut self) {
        if let Some(rx) = &mut self.gnss_status
            && rx.has_changed().unwrap_or(false)
        {
            let status = *rx.borrow_and_update();
            self.live.set_gnss_status(status);
        }
    }

    /// Runs until the odometry task closes the input channel.
    pub async fn run(mut self) {
        let mut tick = tokio::time::interval(CALIB_TICK);
        tick.set_missed_tick_behavior(MissedTickBehavior::Delay);
        let mut effect: Option<JoinHandle<Effect>> = None;
        loop {
            tokio::select! {
                biased;
                done = finish(&mut effect), if effect.is_some() => {
                    let out = self.finished(done);
                    self.drift.send_replace(self.live.drift());
                    effect = self.carry_out(out).await;
                }
                done = finish_refit(&mut self.refit), if self.refit.is_some() => {
                    let out = self.refitted(done);
                    if let Some(h) = self.carry_out(out).await {
                        effect = Some(h);
                    }
                }
                input = self.inputs.recv() => match input {
                    Some(input) => {
                        let out = self.handle(input);
                        if let Some(h) = self.carry_out(out).await {
                            effect = Some(h);
                        }
                    }
                    None => break,
                },
                fix = next_fix(&mut self.gnss), if self.gnss.is_some() => match fix {
                    Some(input) => {
                        let out = self.handle(input);
                        if let Some(h) = self.carry_out(out).await {
                            effect = Some(h);
                        }
                    }
                    // The source stopped: the calibration goes on without it.
                    None => self.gnss = None,
                },
                _ = tick.tick() => {
                    self.refresh_gnss();
                    if let Some(now) = self.now() {
                        let out = self.live.tick(now);
                        if let Some(h) = self.carry_out(out).await {
                            effect = Some(h);
                        }
                    }
                }
            }
        }
        // The odometry stopped: a store in flight still completes, and its
        // answer goes out if the bus is still there.
        while let Some(h) = effect.take() {
            let out = self.finished(h.await);
            effect = self.carry_out(out).await;
        }
    }

    fn handle(&mut self, input: CalibInput) -> Vec<Output> {
        match input {
            CalibInput::Command(t, frame) => self.live.on_command(t, &frame),
            CalibInput::Ack(t, frame) => self.live.on_ack(t, &frame),
            CalibInput::Fix {
                t,
                first,
                second,
                geodetic,
                sigma_m,
            } => self.live.on_fix(t, first, second, geodetic, sigma_m),
            CalibInput::Fault(t, code) => {
                self.live.on_fault(t, code);
                Vec::new()
            }
            CalibInput::Step {
                t,
                rear_rev,
                front_rev,
                steer_signal,
                yaw_rate_radps,
                window,
            } => {
                let out = self.live.on_step_with_front(
                    t,
                    rear_rev,
                    front_rev,
                    steer_signal,
                    yaw_rate_radps,
                );
                self.live.on_window(window);
                self.standstill.send_replace(self.live.standstill());
                out
            }
        }
    }

    /// A store or a computation came back: the calibration hears of it.
    fn finished(&mut self, done: Result<Effect, tokio::task::JoinError>) -> Vec<Output> {
        let now = self.now().unwrap_or(Timestamp::from_micros(0));
        match done {
            Ok(Effect::Persisted(stored)) => self.live.on_persisted(now, &stored),
            Ok(Effect::Computed(outcome)) => self.live.on_computed(now, *outcome),
            // A panic in the store or the job: the command fails whole.
            Err(e) if self.live.is_storing() => self
                .live
                .on_persisted(now, &Err(format!("store task failed: {e}"))),
            Err(e) => {
                warn!(cause = %e, "calibration job failed");
                self.live.on_computed(
                    now,
                    JobOutcome::Rear(Err(canodom_calib::Error::Numerical {
                        context: "the calibration job panicked",
                    })),
                )
            }
        }
    }

    /// The refit in flight came back: judged, each flag that rose or
    /// cleared logged, the report handed on.
    fn refitted(&mut self, done: Result<Epoch, tokio::task::JoinError>) -> Vec<Output> {
        let Some((_, job)) = self.refit.take() else {
            return Vec::new();
        };
        let epoch = done
            .inspect_err(|e| warn!(cause = %e, "online calibration refit failed"))
            .ok();
        if let Some(e) = &epoch {
            debug!(t_s = e.t_s, fixes = e.fixes, refused = ?e.refused, "online calibration refit");
        }
        let now = self.now().unwrap_or(Timestamp::from_micros(0));
        let (out, judged) = self.live.on_refit(now, &job, epoch.as_ref());
        let offered = self.live.drift().candidate.is_some();
        for c in judged
            .iter()
            .flat_map(|j| j.changes.iter().map(move |c| (c, j.distance_m)))
        {
            let line = crate::cmd::replay_fixes::describe_change(c.0, c.1);
            let parameter = c.0.reading.param.name();
            if c.0.raised && offered {
                warn!(parameter, "{line}; the learnt set awaits COMMIT");
            } else if c.0.raised {
                warn!(parameter, "{line}");
            } else {
                info!(parameter, "{line}");
            }
        }
        self.drift.send_replace(self.live.drift());
        out
    }

    /// Runs `job` on the blocking pool ([`canodom_offline::online::refit`]).
    fn start_refit(&mut self, job: RefitJob) {
        if self.refit.is_some() {
            // The watch asks for one at a time: never reached.
            return;
        }
        let job = Arc::new(job);
        let (config, for_pool) = (Arc::clone(&self.refit_config), Arc::clone(&job));
        let handle = tokio::task::spawn_blocking(move || {
            let w = &for_pool.window;
            canodom_offline::online::refit(
                &config,
                w.base,
                &w.samples,
                &w.fixes,
                &canodom_calib::drive::DriveOptions::default(),
                for_pool.t_s,
            )
        });
        self.refit = Some((handle, job));
    }

    /// The bus clock now: the last frame's timestamp plus the time since.
    fn now(&self) -> Option<Timestamp> {
        let (t, at) = (*self.clock.borrow())?;
        Some(Timestamp::from_micros(
            t.as_micros() + at.elapsed().as_micros() as u64,
        ))
    }

    /// Does what the live calibration asks: frames, applies, reports; a
    /// store or a job goes to the blocking pool and its handle comes back.
    async fn carry_out(&mut self, outputs: Vec<Output>) -> Option<JoinHandle<Effect>> {
        // Every event passes here: whatever moved the session, the
        // odometry task's recordings see its phase from now on.
        let phase = self.live.phase();
        self.phase
            .send_if_modified(|p| std::mem::replace(p, phase) != phase);
        let mut effect = None;
        for o in outputs {
            match o {
                Output::Send(f) => self.send(&f).await,
                Output::Apply(version, values) => {
                    // Lossless: the odometry task takes sets as they come.
                    if self.apply.send((version, values)).await.is_err() {
                        debug!(version, "odometry stopped; set not applied");
                    }
                }
                Output::Report(version, report) => {
                    let dir = self.report_root.join(version.to_string());
                    // SVG rendering is file work: keep it off the frame path.
                    tokio::task::spawn_blocking(move || match canodom_report::files::write_report(
                        &dir, &*report,
                    ) {
                        Ok((svg, _)) => {
                            info!(report = %svg.display(), "calibration report written");
                        }
                        Err(e) => warn!(cause = %e, "calibration report not written"),
                    });
                }
                Output::Persist(file) => effect = Some(self.store(file)),
                Output::Compute(job) => effect = Some(Self::compute(job)),
                Output::Refit(job) => self.start_refit(*job),
            }
        }
        effect
    }

    fn store(&self, file: ParamFile) -> JoinHandle<Effect> {
        let path = self.param_file.clone();
        tokio::task::spawn_blocking(move || {
            Effect::Persisted(
                canodom_params::persist::store(&path, &file).map_err(|e| e.to_string()),
            )
        })
    }

    fn compute(job: Job) -> JoinHandle<Effect> {
        tokio::task::spawn_blocking(move || Effect::Computed(Box::new(job.run())))
    }

    async fn send(&mut self, frame: &CanFrame) {
        let tx = self.sink.borrow().clone();
        let frames = lock(&self.security).outgoing(frame);
        let _ = send_all(tx.as_ref(), &frames, &self.link_lost, "calibration frame").await;
    }
}

/// Sends `frames` in order on `tx` (nothing when the bus is down); false at
/// the first that fails. A link loss is handed to the link task, which may
/// never see it itself, so the outage is logged, counted and the socket
/// reopened.
pub(crate) async fn send_all<Tx: FrameSink>(
    tx: Option<&Tx>,
    frames: &[CanFrame],
    link_lost: &mpsc::Sender<BusError>,
    what: &str,
) -> bool {
    let Some(tx) = tx else { return false };
    for f in frames {
        if let Err(e) = tx.send(f).await {
            if e.is_link_loss() {
                let _ = link_lost.try_send(e);
            } else {
                debug!(cause = %e, "{what} not sent");
            }
            return false;
        }
    }
    true
}

/// The next fix of the GNSS source (never without one).
async fn next_fix(gnss: &mut Option<mpsc::Receiver<CalibInput>>) -> Option<CalibInput> {
    match gnss {
        Some(rx) => rx.recv().await,
        None => std::future::pending().await,
    }
}

/// The refit in flight, when it finishes (never without one).
async fn finish_refit(
    refit: &mut Option<(JoinHandle<Epoch>, Arc<RefitJob>)>,
) -> Result<Epoch, tokio::task::JoinError> {
    match refit {
        Some((handle, _)) => handle.await,
        None => std::future::pending().await,
    }
}

/// The effect in flight, when it finishes (never without one).
async fn finish(effect: &mut Option<JoinHandle<Effect>>) -> Result<Effect, tokio::task::JoinError> {
    match effect {
        Some(handle) => handle.await,
        None => std::future::pending().await,
    }
}

/// Whether the odometry may move the pose now (RESET_POSE) by the
/// calibration's standstill judgement at bus time `t`.
pub fn still_at(judge: &watch::Receiver<Standstill>, t: Timestamp) -> bool {
    judge.borrow().is_still(t.as_micros() as f64 * 1e-6)
}

/// The SecOC gate both tasks share: held for one frame's check or signing,
/// never across an await. A task that panicked while holding it left the
/// gate's counters as they were, which are still the best knowledge.
pub fn lock(gate: &Mutex<SecurityGate>) -> std::sync::MutexGuard<'_, SecurityGate> {
    gate.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

// Every parameter the watch judges fits the diagnostics' slots: checked
// when the daemon is built, so a new parameter cannot be dropped silently.
const _: () = assert!(canodom_calib::drift::PARAMS <= canodom_export::sample::DRIFT_PARAMS);

/// The drift watch's report as the diagnostics show it (the recordings'
/// calibration channel, Foxglove, ROS 2 `/diagnostics`); `None` before its
/// first refit, as in the state file.
pub fn drift_state(d: &DriftReport) -> Option<canodom_export::sample::DriftState> {
    use canodom_export::sample::{DriftParam, DriftReading, DriftState};
    if d.refits == 0 {
        return None;
    }
    let read = d.readings.iter().map(|r| DriftParam {
        name: r.param.name(),
        flagged: d.flagged.contains(&r.param),
        reading: Some(DriftReading {
            learnt: r.learnt,
            sigma: r.sigma,
            in_use: r.in_use,
        }),
    });
    // A flag stays until a refit that reads the parameter clears it: one
    // the last refit did not read is still shown, without a reading.
    let unread = d
        .flagged
        .iter()
        .filter(|p| !d.readings.iter().any(|r| r.param == **p))
        .map(|p| DriftParam {
            name: p.name(),
            flagged: true,
            reading: None,
        });
    Some(DriftState::new(
        d.refits,
        d.distance_m,
        d.candidate.is_some(),
        read.chain(unread),
    ))
}
