//! Live GNSS (`[gnss]`, #46 item 1, #43 item 2): the configured source —
//! gpsd (`canodom-gnss`'s client), a receiver's NMEA on a serial port
//! (`canodom-gnss`'s serial reader) or a ROS 2 `NavSatFix` subscription
//! (`canodom-ros2`'s) — read on a thread of the blocking pool, each accepted
//! fix handed to the calibration task as [`CalibInput::Fix`] on the bus clock.
//!
//! The CAN pipeline never waits on it: the odometry task does not touch it,
//! and the fixes reach the calibration task over a channel of their own,
//! bounded, filled with `try_send` (a full channel drops the fix and counts
//! it); the sources queue too, counted when full (gpsd's client drops the
//! oldest, the ROS 2 subscription the newest). The source starts on the
//! blocking pool (a DDS participant takes up to seconds), and one that
//! cannot start is a warning: the daemon runs on without it.
//!
//! Time: a fix is stamped when it arrives, on the bus clock — the last CAN
//! frame's timestamp plus the time since that frame arrived, as the
//! calibration task's own clock is — so it lines up with the wheel steps
//! whatever the bus stamps with (SocketCAN: the realtime clock; the
//! in-process bus: its own epoch). The receiver's GNSS time is kept beside
//! it: the last fix's latency (bus receipt − GNSS time, meaningful when the
//! bus clock is the realtime clock) is in the summary and the diagnostics.

use crate::calib_task::{BusClock, CalibInput};
use canodom_can::time::Timestamp;
use canodom_gnss::accept::HORIZONTAL_95_TO_SIGMA;
use canodom_gnss::{
    Event, GpsdClient, GpsdClientConfig, Judge, NmeaDevice, NmeaDeviceConfig, SourceStatus, Tpv,
};
use canodom_pipeline::config::{Config, GnssConfig, GnssSource};
use canodom_protocol::calib_wire::{GnssSourceKind, GnssStatus};
use canodom_ros2::fixes::FixSubscriber;
use canodom_ros2::msg::NavSatFix;
use std::time::{Duration, Instant};
use tokio::sync::mpsc::{self, error::TrySendError};
use tokio::sync::watch;
use tokio_util::sync::CancellationToken;
use tracing::{debug, info, warn};

/// Fixes queued for the calibration task at most: a minute of a 1 Hz
/// receiver, while the calibration task takes each in microseconds.
pub const FIX_QUEUE: usize = 64;

/// How long the forwarder waits for the source before looking at the
/// shutdown token again.
const POLL: Duration = Duration::from_millis(200);

/// What the GNSS source did: the run's summary and the diagnostics.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GnssSummary {
    /// The source, for messages (`gpsd localhost:2947`, `ros2 /fix`).
    pub source: String,
    /// The source's own status (connection, fixes/s, error estimate, refusals).
    pub status: SourceStatus,
    /// Connections made (gpsd; 1 + reconnects that succeeded).
    pub connections: u64,
    /// Accepted fixes the source delivered.
    pub received: u64,
    /// Fixes handed to the calibration task.
    pub forwarded: u64,
    /// Fixes dropped because the calibration task's channel was full (or,
    /// at shutdown, already closed).
    pub dropped: u64,
    /// Fixes received before the first CAN frame (no bus time yet): not used.
    pub before_bus: u64,
    /// The last fix's latency, seconds: its bus receipt time minus its GNSS time.
    pub last_latency_s: Option<f64>,
}

impl GnssSummary {
    /// The state the diagnostics show (ROS 2 `/diagnostics`).
    pub fn state(&self) -> canodom_export::sample::GnssState {
        let s = &self.status;
        canodom_export::sample::GnssState {
            connected: s.connected,
            fixes_per_s: s.fixes_per_s,
            last_error_m: s.last_error_m,
            accepted: s.accepted,
            refused: s.refused,
            forwarded: self.forwarded,
            dropped: self.dropped + self.before_bus + s.dropped,
            reconnects: s.reconnects,
            last_latency_s: self.last_latency_s,
        }
    }
}

/// The kind of `source` as `CALIB_STATUS` page 6 names it.
fn wire_kind(source: &GnssSource) -> GnssSourceKind {
    match source {
        GnssSource::Gpsd { .. } => GnssSourceKind::Gpsd,
        GnssSource::Nmea { .. } => GnssSourceKind::Nmea,
        GnssSource::Ros2 { .. } => GnssSourceKind::Ros2,
    }
}

/// `CALIB_STATUS` page 6 of a source of kind `kind` whose latest summary is
/// `summary` (`None`: it has not reported yet, so not connected). Counts
/// that the page cannot hold saturate (refusals, reconnects) or wrap
/// (forwarded, modulo 65536).
fn wire_status(kind: GnssSourceKind, summary: Option<&GnssSummary>) -> GnssStatus {
    let Some(summary) = summary else {
        return GnssStatus {
            source: kind,
            connected: false,
            fixes_per_s: 0.0,
            error_95_m: None,
            forwarded: 0,
            refused: 0,
            reconnects: 0,
        };
    };
    let state = summary.state();
    GnssStatus {
        source: kind,
        connected: state.connected,
        fixes_per_s: state.fixes_per_s,
        error_95_m: state.last_error_m,
        forwarded: (state.forwarded % 65_536) as u16,
        refused: u8::try_from(state.refused.iter().sum::<u64>()).unwrap_or(u8::MAX),
        reconnects: u8::try_from(state.reconnects.min(3)).unwrap_or(3),
    }
}

/// The bus time of an instant `receipt`: the last frame's bus timestamp
/// plus the time from that frame's arrival to `receipt` (minus, when
/// `receipt` came first). `None` before the first frame.
pub fn bus_time(last_frame: Option<(Timestamp, Instant)>, receipt: Instant) -> Option<Timestamp> {
    let (t, at) = last_frame?;
    let us = match receipt.checked_duration_since(at) {
        Some(after) => t.as_micros().saturating_add(after.as_micros() as u64),
        None => t
            .as_micros()
            .saturating_sub(at.duration_since(receipt).as_micros() as u64),
    };
    Some(Timestamp::from_micros(us))
}

/// A NavSatFix as a gpsd TPV report, so that one acceptance rule judges
/// both sources: no fix (status −1) is mode 1, a fix with an altitude 3-D;
/// the 95 % horizontal estimate is 2.448 σ of its covariance (unknown
/// covariance: none, accepted as gpsd's reports without one are).
pub fn tpv_of(fix: &NavSatFix) -> Tpv {
    let mode = if fix.status < 0 {
        1
    } else if fix.altitude.is_finite() {
        3
    } else {
        2
    };
    let finite = |v: f64| v.is_finite().then_some(v);
    Tpv {
        mode,
        time_unix_s: Some(f64::from(fix.stamp.sec) + f64::from(fix.stamp.nanosec) * 1e-9),
        lat_deg: finite(fix.latitude),
        lon_deg: finite(fix.longitude),
        alt_m: finite(fix.altitude),
        eph_m: canodom_ros2::fixes::horizontal_std_m(fix).map(|s| s * HORIZONTAL_95_TO_SIGMA),
        ..Tpv::default()
    }
}

/// A `NavSatFix` subscription judged as gpsd's reports are.
struct Ros2Source {
    subscriber: FixSubscriber,
    judge: Judge,
    status: SourceStatus,
    epoch: Instant,
    last_status: Instant,
}

impl Ros2Source {
    fn next(&mut self, timeout: Duration) -> Option<Event> {
        if let Some(nav) = self.subscriber.recv_timeout(timeout) {
            let now_s = self.epoch.elapsed().as_secs_f64();
            let tpv = tpv_of(&nav);
            let (verdict, changed) = self.judge.judge(&tpv, now_s, &mut self.status);
            if changed {
                match verdict.err() {
                    None => info!("ROS 2 fixes: accepted"),
                    Some(r) => {
                        warn!(reason = r.name(), error_estimate_m = ?self.status.last_error_m,
                        max_error_m = self.judge.acceptance.max_error_m, "ROS 2 fixes: refused");
                    }
                }
            }
            if let Ok(fix) = verdict {
                return Some(Event::Fix(fix));
            }
        }
        if self.last_status.elapsed() < Duration::from_secs(1) {
            return None;
        }
        self.last_status = Instant::now();
        self.status.fixes_per_s = self.judge.rate.rate(self.epoch.elapsed().as_secs_f64());
        // A topic has no connection: "connected" is fixes arriving.
        let connected = self.status.fixes_per_s > 0.0;
        if connected != self.status.connected {
            if connected {
                info!("ROS 2 fixes: arriving");
            } else {
                warn!(
                    window_s = canodom_gnss::status::RATE_WINDOW_S,
                    "ROS 2 fixes: none in the window"
                );
            }
        }
        self.status.connected = connected;
        self.status.dropped = self.subscriber.stats().dropped;
        Some(Event::Status(self.status.clone()))
    }
}

/// The running source.
enum Source {
    Gpsd(GpsdClient),
    Nmea(NmeaDevice),
    Ros2(Box<Ros2Source>),
}

impl Source {
    fn start(
        gnss: &GnssConfig,
        ros2: Option<&toml::Table>,
        epoch: Instant,
    ) -> Result<Self, String> {
        match &gnss.source {
            GnssSource::Gpsd { address } => {
                let client_config =
                    GpsdClientConfig::new(address, gnss.max_error_m).map_err(|e| e.to_string())?;
                GpsdClient::spawn(client_config, epoch)
                    .map(Self::Gpsd)
                    .map_err(|e| e.to_string())
            }
            GnssSource::Nmea { device, baud } => {
                let device_config = NmeaDeviceConfig::new(device, *baud, gnss.max_error_m)
                    .map_err(|e| e.to_string())?;
                NmeaDevice::spawn(device_config, epoch)
                    .map(Self::Nmea)
                    .map_err(|e| e.to_string())
            }
            GnssSource::Ros2 { topic } => {
                let err = |e: canodom_ros2::Error| e.to_string();
                let mut resolved = canodom_ros2::config::Ros2Config::from_section(ros2)
                    .and_then(|c| c.resolve())
                    .map_err(err)?;
                resolved.fix_topic =
                    Some(canodom_ros2::config::dds_topic(&resolved.namespace, topic).map_err(err)?);
                let subscriber = FixSubscriber::start(&resolved).map_err(err)?;
                Ok(Self::Ros2(Box::new(Ros2Source {
                    subscriber,
                    judge: Judge::new(gnss.max_error_m),
                    status: SourceStatus::default(),
                    epoch,
                    last_status: Instant::now(),
                })))
            }
        }
    }

    fn next(&mut self, timeout: Duration) -> Option<Event> {
        match self {
            Self::Gpsd(client) => client.recv_timeout(timeout),
            Self::Nmea(device) => device.recv_timeout(timeout),
            Self::Ros2(source) => source.next(timeout),
        }
    }
}

/// The GNSS source and where its fixes go (see the module doc).
pub struct Forwarder {
    /// What to start (on the blocking pool: a DDS participant takes up to
    /// seconds to come up, which the service's start must not wait for).
    gnss: GnssConfig,
    /// `[ros2]` as written: the domain and discovery of a ROS 2 source.
    ros2: Option<toml::Table>,
    epoch: Instant,
    fixes: mpsc::Sender<CalibInput>,
    clock: BusClock,
    status: watch::Sender<Option<GnssSummary>>,
    /// The summary as `CALIB_STATUS` page 6 carries it.
    page: watch::Sender<GnssStatus>,
    kind: GnssSourceKind,
    token: CancellationToken,
    summary: GnssSummary,
}

/// The calibration task's and the observers' ends of a [`Forwarder`].
#[derive(Debug)]
pub struct GnssLinks {
    /// Fixes for the calibration task.
    pub fixes: mpsc::Receiver<CalibInput>,
    /// The latest summary, updated at each event of the source.
    pub status: watch::Receiver<Option<GnssSummary>>,
    /// The latest summary as `CALIB_STATUS` page 6 (not connected before
    /// the source's first report).
    pub page: watch::Receiver<GnssStatus>,
}

impl Forwarder {
    /// The forwarder of `gnss` (its source starts in [`Self::run`]);
    /// `clock` is the odometry task's bus clock, `token` the daemon's shutdown.
    pub fn new(
        config: &Config,
        gnss: &GnssConfig,
        clock: BusClock,
        token: CancellationToken,
    ) -> (Self, GnssLinks) {
        let name = match &gnss.source {
            GnssSource::Gpsd { address } => format!("gpsd {address}"),
            GnssSource::Nmea { device, .. } => format!("nmea {}", device.display()),
            GnssSource::Ros2 { topic } => format!("ros2 {topic}"),
        };
        let (fixes, fixes_rx) = mpsc::channel(FIX_QUEUE);
        let (status, status_rx) = watch::channel(None);
        let kind = wire_kind(&gnss.source);
        let (page, page_rx) = watch::channel(wire_status(kind, None));
        let forwarder = Self {
            gnss: gnss.clone(),
            ros2: config.ros2.clone(),
            epoch: Instant::now(),
            fixes,
            clock,
            status,
            page,
            kind,
            token,
            summary: GnssSummary {
                source: name,
                ..GnssSummary::default()
            },
        };
        (
            forwarder,
            GnssLinks {
                fixes: fixes_rx,
                status: status_rx,
                page: page_rx,
            },
        )
    }

    /// Forwards until the shutdown token is cancelled or the calibration
    /// task is gone (blocking: run it on the blocking pool); the summary,
    /// with the source's final status.
    pub fn run(mut self) -> GnssSummary {
        let mut source = match Source::start(&self.gnss, self.ros2.as_ref(), self.epoch) {
            Ok(source) => source,
            Err(e) => {
                warn!(source = %self.summary.source, error = %e,
                    "GNSS source not started: the daemon goes on without it");
                self.summary.status.last_error = Some(e);
                return self.summary;
            }
        };
        info!(source = %self.summary.source, max_error_m = self.gnss.max_error_m,
            "GNSS: fixes go to the calibration");
        while !self.token.is_cancelled() {
            let Some(event) = source.next(POLL) else {
                continue;
            };
            if !self.handle(event) {
                break;
            }
        }
        // What the source still queued is handed on while the calibration
        // task still takes fixes; once it has stopped, counted as dropped.
        let rest = match &mut source {
            Source::Gpsd(client) => client.finish(),
            Source::Nmea(device) => device.finish(),
            // Its counts as of the last fix (a status goes out once a second).
            Source::Ros2(source) => vec![Event::Status(source.status.clone())],
        };
        let mut open = true;
        for event in rest {
            match event {
                Event::Fix(fix) if open => {
                    self.summary.received += 1;
                    open = self.forward(&fix);
                }
                Event::Fix(_) => {
                    self.summary.received += 1;
                    self.summary.dropped += 1;
                }
                Event::Status(status) => self.summary.status = status,
            }
        }
        self.summary
    }

    /// One event of the source; false when the calibration task is gone.
    fn handle(&mut self, event: Event) -> bool {
        match event {
            Event::Fix(fix) => {
                self.summary.received += 1;
                if !self.forward(&fix) {
                    return false;
                }
            }
            Event::Status(status) => {
                if status.connected && !self.summary.status.connected {
                    self.summary.connections += 1;
                }
                self.summary.status = status;
            }
        }
        self.status.send_replace(Some(self.summary.clone()));
        self.page
            .send_replace(wire_status(self.kind, Some(&self.summary)));
        true
    }

    /// Hands `fix` on; false when the calibration task is gone.
    fn forward(&mut self, fix: &canodom_gnss::Fix) -> bool {
        let receipt = self.epoch + Duration::from_secs_f64(fix.receipt_time_s.max(0.0));
        let last_frame = (*self.clock.borrow()).map(|(t, at)| (t, at.into_std()));
        let Some(t) = bus_time(last_frame, receipt) else {
            if self.summary.before_bus == 0 {
                info!("GNSS: fixes before the first CAN frame have no bus time and are not used");
            }
            self.summary.before_bus += 1;
            return true;
        };
        self.summary.last_latency_s = fix
            .gnss_time_unix_s
            .map(|g| t.as_micros() as f64 * 1e-6 - g);
        let input = CalibInput::Fix {
            t,
            first: fix.lat_deg,
            second: fix.lon_deg,
            geodetic: true,
            sigma_m: fix.sigma_m,
        };
        match self.fixes.try_send(input) {
            Ok(()) => {
                // Per fix, so debug: what reached the calibration, for tests and field checks.
                debug!(gnss_time_unix_s = ?fix.gnss_time_unix_s, lat_deg = fix.lat_deg, lon_deg = fix.lon_deg,
                    bus_time_us = t.as_micros(), "GNSS fix to the calibration");
                self.summary.forwarded += 1;
            }
            Err(TrySendError::Full(_)) => {
                if self.summary.dropped == 0 {
                    warn!("GNSS: the calibration task is behind; fixes dropped (counted)");
                }
                debug!("GNSS fix dropped: the calibration's channel is full");
                self.summary.dropped += 1;
            }
            Err(TrySendError::Closed(_)) => {
                self.summary.dropped += 1;
                return false;
            }
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use canodom_export::cdr::RosTime;
    use canodom_gnss::Acceptance;

    #[test]
    fn receipt_times_go_onto_the_bus_clock() {
        let at = Instant::now();
        let t = Timestamp::from_micros(1_700_000_000_000_000);
        assert_eq!(bus_time(None, at), None);
        let later = at + Duration::from_millis(250);
        assert_eq!(
            bus_time(Some((t, at)), later),
            Some(Timestamp::from_micros(1_700_000_000_250_000))
        );
        // A fix received before the last frame arrived (the forwarder ran late).
        assert_eq!(
            bus_time(Some((t, later)), at),
            Some(Timestamp::from_micros(1_699_999_999_750_000))
        );
    }

    #[test]
    fn the_diagnostics_state_counts_every_fix_not_used_as_dropped() {
        let summary = GnssSummary {
            status: SourceStatus {
                connected: true,
                fixes_per_s: 1.0,
                last_error_m: Some(57.0),
                accepted: 10,
                refused: [1, 0, 4],
                dropped: 2,
                reconnects: 3,
                ..SourceStatus::default()
            },
            received: 8,
            forwarded: 5,
            dropped: 2,
            before_bus: 1,
            last_latency_s: Some(0.2),
            ..GnssSummary::default()
        };
        let s = summary.state();
        assert!(s.connected);
        assert_eq!((s.accepted, s.refused, s.forwarded), (10, [1, 0, 4], 5));
        // The client's queue, the calibration's channel, before the bus.
        assert_eq!(s.dropped, 5);
        assert_eq!((s.last_error_m, s.last_latency_s), (Some(57.0), Some(0.2)));
        assert_eq!(s.reconnects, 3);
    }

    #[test]
    fn the_daemon_and_the_client_default_to_one_error_limit() {
        assert_eq!(
            canodom_pipeline::config::DEFAULT_MAX_ERROR_M,
            canodom_gnss::client::DEFAULT_MAX_ERROR_M
        );
        assert_eq!(
            canodom_pipeline::config::DEFAULT_GPSD_ADDRESS,
            canodom_gnss::client::DEFAULT_ADDRESS
        );
        assert_eq!(
            canodom_pipeline::config::DEFAULT_NMEA_MAX_ERROR_M,
            canodom_gnss::serial::DEFAULT_MAX_ERROR_M
        );
        assert_eq!(
            canodom_pipeline::config::NMEA_BAUD_RATES,
            canodom_gnss::serial::BAUD_RATES
        );
    }

    #[test]
    fn a_nav_sat_fix_is_judged_as_a_gpsd_report() {
        let mut nav = NavSatFix {
            stamp: RosTime {
                sec: 1_700_000_000,
                nanosec: 500_000_000,
            },
            frame_id: "gnss".into(),
            status: 0,
            service: 1,
            latitude: 48.1,
            longitude: 11.5,
            altitude: 520.0,
            position_covariance: [2.25, 0.0, 0.0, 0.0, 2.25, 0.0, 0.0, 0.0, 9.0],
            position_covariance_type: 2,
        };
        let mut a = Acceptance::new(120.0);
        let fix = a.judge(&tpv_of(&nav), 3.0).expect("a fix of σ 1.5 m");
        assert_eq!((fix.mode, fix.lat_deg, fix.lon_deg), (3, 48.1, 11.5));
        assert!((fix.sigma_m.expect("σ") - 1.5).abs() < 1e-12);
        assert_eq!(fix.gnss_time_unix_s, Some(1_700_000_000.5));
        // σ 50 m: a 95 % radius of 122 m, beyond the limit.
        nav.position_covariance[0] = 2500.0;
        nav.position_covariance[4] = 2500.0;
        assert_eq!(
            a.judge(&tpv_of(&nav), 4.0),
            Err(canodom_gnss::Refusal::ErrorTooLarge)
        );
        nav.status = -1;
        assert_eq!(
            a.judge(&tpv_of(&nav), 5.0),
            Err(canodom_gnss::Refusal::NoFix)
        );
        // No altitude: 2-D; unknown covariance: accepted without σ.
        nav.status = 0;
        nav.altitude = f64::NAN;
        nav.position_covariance_type = 0;
        let fix = a.judge(&tpv_of(&nav), 6.0).expect("2-D");
        assert_eq!((fix.mode, fix.sigma_m, fix.alt_m), (2, None, None));
    }
}
