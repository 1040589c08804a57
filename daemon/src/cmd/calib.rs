//! `canodom calib`: the operator's client of the live calibration. It sends
//! one `CALIB_CMD` per invocation and reports the daemon's answer, or shows
//! `CALIB_STATUS` as a guide in plain words (what to drive next, progress of
//! the current run, counts, results).
//!
//! Everything that decides what to send or what to show is pure
//! ([`command_for`], [`GuideState::apply`], [`render_guide`],
//! [`render_line`], [`reason_text`]) and unit-tested; the I/O shell only
//! moves frames between SocketCAN and those functions.

use anyhow::Context as _;
use canodom_can::bus::{BusEvent, FrameSink, FrameSource, IdFilter, open_socketcan};
use canodom_pipeline::config::Config;
use canodom_protocol::calib_wire::{
    CalibWire, CmdCode, Command, Counts, InstructionCode, ParamsAssembler, Progress, Reason, State,
    StatusPage, WireDirection, Writeback,
};
use std::fmt::Write as _;
use std::io::{IsTerminal as _, Write as _};
use std::path::PathBuf;
use std::time::Duration;
use tokio::time::Instant;

/// How long `status` collects pages: page 0 comes every cycle and the
/// others in turn, so 1.2 s holds at least one full cycle while a session is
/// active.
const STATUS_COLLECT: Duration = Duration::from_millis(1200);

/// At idle the daemon sends one page pair per second and pages 1..=5 in
/// turn, so a given page can be 5 s away; once status frames are seen the
/// client waits this long for the page it needs.
const PAGE_CYCLE: Duration = Duration::from_secs(6);

/// Arguments of `calib`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Example session (the daemon runs with the same config):\n  \
canodom calib --config car.toml start --track-radius 1.5 --runs 5\n  \
canodom calib --config car.toml watch          # drive as it says; Ctrl-C to leave\n  \
canodom calib --config car.toml end-run        # only if a run did not end by itself\n  \
canodom calib --config car.toml end-pose --dx-mm 12 --dy-mm -30 --dtheta-deg 1.5   # when asked\n  \
canodom calib --config car.toml compute\n  \
canodom calib --config car.toml status         # review the result and its uncertainty\n  \
canodom calib --config car.toml commit         # or abort; rollback undoes a commit\n\n\
Each command prints `done` (exit 0) or `refused: REASON (why)` (exit 1); exit 2 when the \
daemon does not answer. Commands go out as CALIB_CMD on [calibration] command_id with the \
configured arming code, rolling counter and CRC-8; answers are read from CALIB_STATUS at \
[output] base_id + 0x11."
)]
pub struct CalibArgs {
    /// The daemon's configuration file (interface, base id, arming code);
    /// before or after the action (`calib status --config car.toml`).
    #[arg(long, global = true)]
    pub config: Option<PathBuf>,
    /// How long to wait for the daemon, seconds.
    #[arg(long, global = true, default_value_t = 2.0, value_parser = parse_timeout)]
    pub timeout_s: f64,
    /// Print the command as a `cansend` line (id, counter, arming code and
    /// CRC filled in) instead of sending it; needs no interface.
    #[arg(long, global = true)]
    pub print_frame: bool,
    /// With --print-frame: the rolling counter, 0..=15 (default: from the
    /// clock, as a sent command takes it). The daemon refuses a counter equal
    /// to the previous command's, so successive lines need different ones.
    #[arg(long, global = true, requires = "print_frame",
          value_parser = clap::value_parser!(u8).range(0..=15))]
    pub counter: Option<u8>,
    /// What to do.
    #[command(subcommand)]
    pub action: Action,
}

/// One `calib` subcommand.
#[derive(Debug, Clone, PartialEq, clap::Subcommand)]
pub enum Action {
    /// Start a session on the stadium track of semicircle radius ρ (metres; straights 2ρ).
    Start {
        /// The track's semicircle radius ρ, metres (straights 2ρ, lap (4 + 2π)·ρ; README: the track on the ground).
        #[arg(long, allow_negative_numbers = true, value_parser = parse_radius)]
        track_radius: f64,
        /// Runs per direction, 1..=15.
        #[arg(long, default_value_t = canodom_protocol::calib_wire::DEFAULT_RUNS_PER_DIRECTION,
              value_parser = clap::value_parser!(u8).range(1..=15))]
        runs: u8,
    },
    /// Start the steering calibration (after a committed rear calibration).
    StartSteering,
    /// Start recording a drive for calibration against the position fixes
    /// the bus carries (`[calibration.fixes]`); then drive, `compute`, `commit`.
    StartDrive,
    /// Start recording the next run now (instead of on moving off).
    StartRun,
    /// End the current run now.
    EndRun,
    /// The measured real end pose of the last run, relative to its start pose.
    EndPose {
        /// Forward offset, mm (−8192..=8191).
        #[arg(long, allow_negative_numbers = true,
              value_parser = clap::value_parser!(i16).range(-8192..=8191))]
        dx_mm: i16,
        /// Leftward offset, mm (−8192..=8191).
        #[arg(long, allow_negative_numbers = true,
              value_parser = clap::value_parser!(i16).range(-8192..=8191))]
        dy_mm: i16,
        /// Heading offset, degrees (0.1° resolution, −204.8..=204.7).
        #[arg(long, allow_negative_numbers = true, value_parser = parse_dtheta)]
        dtheta_deg: f64,
    },
    /// Drop the session.
    Abort,
    /// Compute the calibration from the accepted runs.
    Compute,
    /// Commit the computed set (applied live, persisted, written back).
    Commit,
    /// Roll back to the previous parameter set.
    Rollback,
    /// Ask for the set in use and print it (CALIB_PARAMS).
    Params,
    /// Print one decoded full status.
    Status,
    /// Show CALIB_STATUS as a live guide until Ctrl-C.
    Watch {
        /// The track's semicircle radius ρ, metres, for the run's progress bar.
        #[arg(long, value_parser = parse_radius)]
        track_radius: Option<f64>,
        /// Stop after this many CALIB_STATUS frames (for scripts).
        #[arg(long)]
        count: Option<u64>,
    },
}

fn parse_timeout(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("`{s}` is not a number"))?;
    if v.is_finite() && v > 0.0 && v <= 600.0 {
        Ok(v)
    } else {
        Err(format!("timeout must be in (0, 600] s, got {s}"))
    }
}

/// The track radius goes on the wire in whole millimetres (u16).
fn parse_radius(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .parse()
        .map_err(|_| format!("`{s}` is not a number of metres"))?;
    if !v.is_finite() || v <= 0.0 {
        return Err(format!("the track radius must be positive, got {s} m"));
    }
    if !(0.001..=65.535).contains(&v) {
        return Err(format!(
            "the track radius must lie in 0.001..=65.535 m (millimetres on the wire), got {s} m"
        ));
    }
    Ok(v)
}

fn parse_dtheta(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .parse()
        .map_err(|_| format!("`{s}` is not a number of degrees"))?;
    if v.is_finite() && (-204.8..=204.7).contains(&v) {
        Ok(v)
    } else {
        Err(format!(
            "the heading offset must lie in -204.8..=204.7 degrees, got {s}"
        ))
    }
}

/// The `CALIB_CMD` an action sends; `None` for the read-only ones
/// (`status`, `watch`).
pub fn command_for(action: &Action) -> Option<Command> {
    Some(match *action {
        Action::Start { track_radius, runs } => Command::StartSession {
            // parse_radius bounds it to the u16 range.
            track_radius_mm: (track_radius * 1000.0).round().clamp(1.0, 65535.0) as u16,
            runs_per_direction: runs,
        },
        Action::StartSteering => Command::StartSteering,
        Action::StartDrive => Command::StartDrive,
        Action::StartRun => Command::StartRun,
        Action::EndRun => Command::EndRun,
        Action::EndPose {
            dx_mm,
            dy_mm,
            dtheta_deg,
        } => Command::EndPose {
            dx_mm,
            dy_mm,
            dtheta_decideg: (dtheta_deg * 10.0).round().clamp(-2048.0, 2047.0) as i16,
        },
        Action::Abort => Command::Abort,
        Action::Compute => Command::Compute,
        Action::Commit => Command::Commit,
        Action::Rollback => Command::Rollback,
        Action::Params => Command::RequestParams,
        Action::Status | Action::Watch { .. } => return None,
    })
}

/// Track length of the calibration track, `(4 + 2π)·ρ`
/// (`docs/calibration-math.md`, the track of `canodom_calib::track`).
pub fn track_length_m(radius_m: f64) -> f64 {
    (4.0 + 2.0 * std::f64::consts::PI) * radius_m
}

/// Why a command was refused or a run rejected, in words an operator can act on.
pub fn reason_text(reason: Reason) -> &'static str {
    match reason {
        Reason::None => "accepted",
        Reason::NoSession => "no session is active; start one with `canodom calib start`",
        Reason::SessionActive => "a session is already active; finish it or abort it first",
        Reason::InvalidArgument => "an argument is out of range for this command",
        Reason::AlreadyRecording => "a run is already being recorded",
        Reason::NotRecording => "no run is being recorded, so there is none to end",
        Reason::NoRunForEndPose => "there is no finished run waiting for its end pose",
        Reason::EndPoseRequired => {
            "the last run's measured end pose must be sent first (`canodom calib end-pose`)"
        }
        Reason::RunsIncomplete => "not all runs have been accepted yet; keep driving",
        Reason::NotComputing => "no computation is running",
        Reason::NothingToCommit => "there is no computed result to commit; compute first",
        Reason::NothingToRollback => "there is no previous parameter set to roll back to",
        Reason::Busy => "the daemon is busy computing; wait and try again",
        Reason::AllRunsDone => "all runs are done; compute instead of starting another",
        Reason::TooFewSamples => "the run was too short in time to judge; drive it again",
        Reason::LengthOff => "the distance was not within ±10 % of the track length",
        Reason::TurnOff => "the total turn was not one full lap in the announced direction",
        Reason::InputFault => "a wheel or steering input failed during the run",
        Reason::SteeringInconsistent => "the steering did not follow the track's segments",
        Reason::BadArmingCode => {
            "the arming code differs from the daemon's [calibration] arming_code"
        }
        Reason::BadChecksum => "the frame's CRC-8 was wrong (corrupted on the bus)",
        Reason::BadCounter => "the rolling counter repeated the previous command's (a duplicate)",
        Reason::UnknownCommand => "the daemon does not know this command code",
        Reason::NotAtStandstill => "parameters change only at standstill; stop the vehicle",
        Reason::OutOfBounds => "the result lies outside the configured bounds around nominal",
        Reason::UncertaintyTooHigh => {
            "the result's uncertainty exceeds the configured limit; drive more or better runs"
        }
        Reason::ComputeFailed => "the calibration failed numerically; compute again or abort",
        Reason::PersistFailed => "the parameter file could not be written; nothing changed",
        Reason::NotSupported => "this daemon does not carry out that command",
        Reason::WritebackBusy => "the previous write-back still waits for its acknowledgement",
    }
}

/// What a session state means.
pub fn state_text(state: State) -> &'static str {
    match state {
        State::Idle => "no session",
        State::Positioning => "positioning for the next run",
        State::Recording => "recording a run",
        State::AwaitingEndPose => "waiting for the measured end pose",
        State::Ready => "all runs accepted",
        State::Computing => "computing",
        State::Computed => "result ready for review",
    }
}

/// What the write-back state means.
pub fn writeback_text(writeback: Writeback) -> &'static str {
    match writeback {
        Writeback::Idle => "nothing sent",
        Writeback::Pending => "sent, waiting for the parameter store's acknowledgement",
        Writeback::Acked => "stored and acknowledged",
        Writeback::Failed => "no acknowledgement after the retries; the set stays applied here",
    }
}

fn direction_words(d: WireDirection) -> &'static str {
    match d {
        WireDirection::None => "in no particular direction",
        WireDirection::Cw => "clockwise",
        WireDirection::Ccw => "counter-clockwise",
    }
}

/// The instruction of a progress page in plain words.
pub fn instruction_text(p: &Progress) -> String {
    let (k, n, dir, start) = (
        p.run_index,
        p.runs_total,
        direction_words(p.direction),
        p.start_point,
    );
    match p.instruction {
        InstructionCode::None => {
            "No session: start one with `canodom calib start --track-radius R_M`".to_owned()
        }
        InstructionCode::RefitSteering => {
            "Refit the steering map: send `canodom calib start-steering`".to_owned()
        }
        InstructionCode::GoToStart => {
            format!("Drive to {start} and stop there: run {k} of {n} goes {dir}")
        }
        InstructionCode::Go => format!("Drive run {k} of {n} {dir} from {start}"),
        InstructionCode::Drive => format!("Keep following the track: run {k} of {n}, {dir}"),
        InstructionCode::Stop => "Stop at the start point".to_owned(),
        InstructionCode::MeasureEndPose => format!(
            "Measure the real end pose of run {k} and send it with `canodom calib end-pose`"
        ),
        InstructionCode::ReadyToCompute => "Ready: send `canodom calib compute`".to_owned(),
        InstructionCode::Wait => "Wait: computing the calibration".to_owned(),
        InstructionCode::ReviewResult => "Review the result: commit or abort".to_owned(),
    }
}

/// The result pages, collected.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Results {
    geometry: Option<[f64; 3]>,
    quality: Option<[f64; 3]>,
    steering: Option<[f64; 3]>,
    extra: Option<(f64, u16)>,
}

/// What the guide knows from the status pages received so far.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GuideState {
    /// The latest progress page.
    pub progress: Option<Progress>,
    /// The latest counts page.
    pub counts: Option<Counts>,
    results: Results,
    /// Track length, m, when the radius is known.
    pub track_length_m: Option<f64>,
}

impl GuideState {
    /// An empty guide; `track_length_m` draws the run's progress bar.
    pub fn new(track_length_m: Option<f64>) -> Self {
        Self {
            track_length_m,
            ..Self::default()
        }
    }

    /// Takes in one page; returns whether anything shown changed.
    pub fn apply(&mut self, page: &StatusPage) -> bool {
        let before = self.clone();
        match *page {
            StatusPage::Progress(p) => {
                // A new session or an abort makes old results meaningless.
                if matches!(p.state, State::Idle | State::Positioning | State::Recording) {
                    self.results = Results::default();
                }
                self.progress = Some(p);
            }
            StatusPage::Counts(c) => self.counts = Some(c),
            StatusPage::ResultGeometry {
                rear_tread_m,
                rear_tread_std_m,
                diameter_ratio,
            } => self.results.geometry = Some([rear_tread_m, rear_tread_std_m, diameter_ratio]),
            StatusPage::ResultQuality {
                diameter_ratio_std,
                end_err_before_m,
                end_err_after_m,
            } => {
                self.results.quality =
                    Some([diameter_ratio_std, end_err_before_m, end_err_after_m]);
            }
            StatusPage::ResultSteering {
                steer_gain,
                steer_gain_std,
                steer_offset_rad,
            } => self.results.steering = Some([steer_gain, steer_gain_std, steer_offset_rad]),
            StatusPage::ResultExtra {
                steer_offset_std_rad,
                version,
            } => self.results.extra = Some((steer_offset_std_rad, version)),
        }
        *self != before
    }

    fn shows_results(&self) -> bool {
        self.progress
            .is_some_and(|p| matches!(p.state, State::Computed))
    }
}

/// A text progress bar of `done_m` against `total_m`.
pub fn progress_bar(done_m: f64, total_m: f64, width: usize) -> String {
    let frac = if total_m > 0.0 {
        (done_m / total_m).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let filled = (frac * width as f64).round() as usize;
    format!(
        "[{}{}] {done_m:.2} m of {total_m:.2} m ({:.0} %)",
        "#".repeat(filled),
        ".".repeat(width - filled),
        100.0 * done_m / total_m.max(f64::MIN_POSITIVE)
    )
}

fn answer_text(code: u8, reason: Reason) -> String {
    if code == CmdCode::None.code() && reason == Reason::None {
        return "none yet".to_owned();
    }
    let name = CmdCode::from_code(code).map_or_else(|| format!("code {code}"), |c| c.to_string());
    if reason == Reason::None {
        format!("{name} done")
    } else {
        format!("{name} refused: {reason} ({})", reason_text(reason))
    }
}

/// The guide as a block of lines (for a terminal, redrawn in place).
pub fn render_guide(g: &GuideState) -> String {
    let mut s = String::new();
    let Some(p) = g.progress else {
        return "Waiting for CALIB_STATUS from canodom…\n".to_owned();
    };
    let _ = writeln!(s, "▶ {}", instruction_text(&p));
    let _ = writeln!(
        s,
        "  state: {} ({}){}",
        p.state,
        state_text(p.state),
        if p.standstill {
            ", standing still"
        } else {
            ", moving"
        }
    );
    if p.state == State::Recording || p.run_distance_m > 0.0 {
        match g.track_length_m {
            Some(len) => {
                let _ = writeln!(s, "  run:   {}", progress_bar(p.run_distance_m, len, 30));
            }
            None => {
                let _ = writeln!(s, "  run:   {:.2} m driven", p.run_distance_m);
            }
        }
    }
    if let Some(c) = g.counts {
        let _ = writeln!(
            s,
            "  runs:  CW {} accepted, {} rejected · CCW {} accepted, {} rejected",
            c.cw_accepted, c.cw_rejected, c.ccw_accepted, c.ccw_rejected
        );
        if c.reject_reason != Reason::None {
            let _ = writeln!(
                s,
                "  last rejection: {} ({}); drive that run again",
                c.reject_reason,
                reason_text(c.reject_reason)
            );
        }
        let _ = writeln!(
            s,
            "  last command: {}",
            answer_text(c.last_cmd, c.cmd_reason)
        );
        let _ = writeln!(
            s,
            "  parameters in use: {}",
            if c.active_version == 0 {
                "nominal".to_owned()
            } else {
                format!("version {}", c.active_version)
            }
        );
    }
    let _ = write!(
        s,
        "  write-back: {} ({})",
        p.writeback,
        writeback_text(p.writeback)
    );
    if p.writeback_attempts > 0 {
        let _ = write!(s, ", {} send(s)", p.writeback_attempts);
    }
    s.push('\n');
    if g.shows_results() {
        let r = &g.results;
        if let Some([t, ts, ratio]) = r.geometry {
            let ratio_std = r
                .quality
                .map_or(String::new(), |q| format!(" ± {:.5}", q[0]));
            let _ = writeln!(
                s,
                "  result: rear tread {t:.4} m ± {ts:.4} m, diameter ratio (R/L) {ratio:.5}{ratio_std}"
            );
        }
        if let Some([_, before, after]) = r.quality {
            let _ = writeln!(
                s,
                "          end error {before:.3} m with nominal → {after:.3} m calibrated"
            );
        }
        if let Some([gain, gain_std, off]) = r.steering {
            let off_std = r.extra.map_or(String::new(), |(sd, _)| {
                format!(" ± {:.2}°", sd.to_degrees())
            });
            let _ = writeln!(
                s,
                "          steering gain {gain:.4} ± {gain_std:.4}, offset {:.2}°{off_std}",
                off.to_degrees()
            );
        }
        if let Some((_, v)) = r.extra {
            let _ = writeln!(s, "          committed as version {v}");
        }
    }
    s
}

/// The guide in one line (when standard output is not a terminal).
pub fn render_line(g: &GuideState) -> String {
    let Some(p) = g.progress else {
        return "waiting for CALIB_STATUS".to_owned();
    };
    let mut s = format!("{} | {}", p.state, instruction_text(&p));
    if p.state == State::Recording {
        let _ = match g.track_length_m {
            Some(len) => write!(s, " | {:.2}/{len:.2} m", p.run_distance_m),
            None => write!(s, " | {:.2} m", p.run_distance_m),
        };
    }
    if let Some(c) = g.counts {
        let _ = write!(
            s,
            " | CW {}/{} CCW {}/{} (accepted/rejected)",
            c.cw_accepted, c.cw_rejected, c.ccw_accepted, c.ccw_rejected
        );
        if c.reject_reason != Reason::None {
            let _ = write!(s, " | last rejection {}", c.reject_reason);
        }
    }
    let _ = write!(s, " | write-back {}", p.writeback);
    if g.shows_results()
        && let Some([t, ts, ratio]) = g.results.geometry
    {
        let _ = write!(s, " | tread {t:.4}±{ts:.4} m ratio {ratio:.5}");
    }
    s
}

/// The answer to a sent command, judged from a counts page.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Answer {
    /// Not an answer to this command (yet).
    Pending,
    /// Carried out.
    Done,
    /// Refused with this reason.
    Refused(Reason),
}

/// Judges a counts page: an answer to `sent` when CMD_SEQ moved since
/// `seq_before` and LAST_CMD is the command.
pub fn judge(counts: &Counts, seq_before: u8, sent: CmdCode) -> Answer {
    if counts.cmd_seq == seq_before || counts.last_cmd != sent.code() {
        Answer::Pending
    } else if counts.cmd_reason == Reason::None {
        Answer::Done
    } else {
        Answer::Refused(counts.cmd_reason)
    }
}

/// A counter start that differs between invocations a moment apart
/// (≥ 64 ms); a collision is caught by the daemon as BAD_COUNTER and
/// retried with the next value.
fn initial_counter() -> u8 {
    let ms = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis());
    ((ms / 64) % 16) as u8
}

/// The `cansend` line of the CALIB_CMD frame `action` sends, with
/// `counter` (or one from the clock), the configured arming code and the CRC.
///
/// # Errors
/// An action that sends no command (status, watch), or a base id the
/// calibration frames do not fit.
pub fn cansend_line(
    config: &Config,
    action: &Action,
    counter: Option<u8>,
) -> anyhow::Result<String> {
    let Some(cmd) = command_for(action) else {
        anyhow::bail!(
            "--print-frame: this action sends no command, it reads CALIB_STATUS \
             (`candump {} | canodom decode --dbc canodom.dbc -` shows it)",
            config.interface
        );
    };
    let wire = CalibWire::new(config.output.base_id)?;
    let data = wire.encode_command(
        cmd,
        config.calibration.arming_code.unwrap_or(0),
        counter.unwrap_or_else(initial_counter),
    );
    let id = match config.calibration.command_id {
        canodom_can::frame::FrameId::Standard(id) => format!("{id:03X}"),
        canodom_can::frame::FrameId::Extended(id) => format!("{id:08X}"),
    };
    let mut line = format!("cansend {} {id}#", config.interface);
    for b in data {
        use std::fmt::Write as _;
        let _ = write!(line, "{b:02X}");
    }
    Ok(line)
}

/// Exit code when the daemon does not answer.
const EXIT_NO_ANSWER: i32 = 2;

/// The daemon did not answer in time (exit code 2).
#[derive(Debug, thiserror::Error)]
#[error(
    "no {what} from canodom on {iface} within {timeout_s} s — is the daemon running with this config?"
)]
pub struct NoAnswer {
    /// What was awaited.
    pub what: String,
    /// The interface.
    pub iface: String,
    /// The wait, seconds.
    pub timeout_s: f64,
}

/// The client's end of the bus: generic so tests drive it on the in-process bus.
struct Link<R, T> {
    rx: R,
    tx: T,
    wire: CalibWire,
    iface: String,
    timeout: Duration,
    /// `CALIB_PARAMS` pages that arrived while a command waited for its
    /// answer: a daemon may send the result ahead of the answer, and
    /// [`Link::params`] must still see them.
    early_params: Vec<canodom_protocol::calib_wire::ParamsPage>,
}

enum Incoming {
    Status(StatusPage),
    Params(canodom_protocol::calib_wire::ParamsPage),
}

impl Link<canodom_can::bus::SocketCanRx, canodom_can::bus::SocketCanTx> {
    fn open(config: &Config, timeout: Duration) -> anyhow::Result<Self> {
        let wire = CalibWire::new(config.output.base_id)?;
        let iface = config.interface.clone();
        let filters = [
            IdFilter::exact(wire.status_id()),
            IdFilter::exact(wire.params_id()),
        ];
        let (rx, tx) = open_socketcan(&iface, &filters).map_err(|e| {
            anyhow::anyhow!(
                "SocketCAN interface {iface} is unavailable ({e}): is CAN support in this \
                 kernel and is {iface} up (`ip link show {iface}`)?"
            )
        })?;
        Ok(Self {
            rx,
            tx,
            wire,
            iface,
            timeout,
            early_params: Vec::new(),
        })
    }
}

impl<R: FrameSource, T: FrameSink> Link<R, T> {
    /// The next calibration frame before `deadline`, `None` at the deadline.
    async fn next(&mut self, deadline: Instant) -> anyhow::Result<Option<Incoming>> {
        loop {
            let ev = match tokio::time::timeout_at(deadline, self.rx.recv()).await {
                Err(_) => return Ok(None),
                Ok(ev) => ev.with_context(|| format!("receiving on {}", self.iface))?,
            };
            let BusEvent::Frame(r) = ev else { continue };
            let data = r.frame.data();
            if r.frame.id() == self.wire.status_id() {
                if let Ok((page, _)) = self.wire.decode_status(data) {
                    return Ok(Some(Incoming::Status(page)));
                }
            } else if r.frame.id() == self.wire.params_id()
                && let Ok((page, _)) = self.wire.decode_params(data)
            {
                return Ok(Some(Incoming::Params(page)));
            }
        }
    }

    fn no_answer(&self, what: &str) -> anyhow::Error {
        NoAnswer {
            what: what.to_owned(),
            iface: self.iface.clone(),
            timeout_s: self.timeout.as_secs_f64(),
        }
        .into()
    }

    /// The current counts page: any status within the timeout, then a page 1
    /// within a page cycle.
    async fn counts(&mut self) -> anyhow::Result<Counts> {
        let start = Instant::now();
        let mut alive = false;
        loop {
            let deadline = start
                + if alive {
                    PAGE_CYCLE.max(self.timeout)
                } else {
                    self.timeout
                };
            match self.next(deadline).await? {
                None if alive => return Err(self.no_answer("CALIB_STATUS page 1 (counts)")),
                None => return Err(self.no_answer("CALIB_STATUS")),
                Some(Incoming::Status(StatusPage::Counts(c))) => return Ok(c),
                Some(Incoming::Status(_)) => alive = true,
                Some(Incoming::Params(_)) => {}
            }
        }
    }

    /// Sends `cmd` and waits for its answer; one retry with the next counter
    /// when the daemon took it for a duplicate.
    async fn command(
        &mut self,
        cmd: Command,
        cmd_id: canodom_can::frame::FrameId,
        arming: u8,
        mut counter: u8,
    ) -> anyhow::Result<Answer> {
        let mut seq_before = self.counts().await?.cmd_seq;
        for attempt in 0..2 {
            let data = self.wire.encode_command(cmd, arming, counter);
            let frame = CalibWire::frame(cmd_id, &data)?;
            self.tx
                .send(&frame)
                .await
                .with_context(|| format!("sending CALIB_CMD on {}", self.iface))?;
            let deadline = Instant::now() + PAGE_CYCLE.max(self.timeout);
            let answer = loop {
                match self.next(deadline).await? {
                    None => return Err(self.no_answer(&format!("answer to {}", cmd.code()))),
                    Some(Incoming::Status(StatusPage::Counts(c))) => {
                        match judge(&c, seq_before, cmd.code()) {
                            Answer::Pending => {}
                            a => {
                                seq_before = c.cmd_seq;
                                break a;
                            }
                        }
                    }
                    Some(Incoming::Params(page)) => self.early_params.push(page),
                    Some(Incoming::Status(_)) => {}
                }
            };
            if answer == Answer::Refused(Reason::BadCounter) && attempt == 0 {
                counter = counter.wrapping_add(1) & 0x0F;
                continue;
            }
            return Ok(answer);
        }
        unreachable!("the loop returns on its second pass")
    }

    /// A full status: pages for [`STATUS_COLLECT`], longer until progress
    /// and counts are both known.
    async fn status(&mut self) -> anyhow::Result<GuideState> {
        let mut g = GuideState::new(None);
        let start = Instant::now();
        let mut deadline = start + STATUS_COLLECT.min(self.timeout.max(STATUS_COLLECT));
        loop {
            match self.next(deadline).await? {
                Some(Incoming::Status(page)) => {
                    g.apply(&page);
                    deadline = start
                        + if g.progress.is_some() && g.counts.is_some() {
                            STATUS_COLLECT
                        } else {
                            PAGE_CYCLE
                        };
                }
                Some(Incoming::Params(_)) => {}
                None if g.progress.is_none() && g.counts.is_none() => {
                    if Instant::now() >= start + self.timeout {
                        return Err(self.no_answer("CALIB_STATUS"));
                    }
                    deadline = start + self.timeout;
                }
                None => return Ok(g),
            }
        }
    }

    /// The CALIB_PARAMS set that follows a REQUEST_PARAMS.
    async fn params(
        &mut self,
    ) -> anyhow::Result<
        Option<
            Result<canodom_protocol::calib_wire::ParamSet, canodom_protocol::calib_wire::ParamSet>,
        >,
    > {
        let mut asm = ParamsAssembler::default();
        for page in std::mem::take(&mut self.early_params) {
            if let Some(set) = asm.push(&self.wire, page) {
                return Ok(Some(set));
            }
        }
        let deadline = Instant::now() + self.timeout;
        loop {
            match self.next(deadline).await? {
                None => return Ok(None),
                Some(Incoming::Params(page)) => {
                    if let Some(set) = asm.push(&self.wire, page) {
                        return Ok(Some(set));
                    }
                }
                Some(Incoming::Status(_)) => {}
            }
        }
    }

    /// Draws the guide on `out` (in place when `tty`) until Ctrl-C or
    /// `count` status frames.
    async fn watch(
        &mut self,
        track_length_m: Option<f64>,
        count: Option<u64>,
        out: &mut impl std::io::Write,
        tty: bool,
    ) -> anyhow::Result<()> {
        let mut g = GuideState::new(track_length_m);
        let mut drawn_lines = 0usize;
        let mut frames = 0u64;
        let ctrl_c = tokio::signal::ctrl_c();
        tokio::pin!(ctrl_c);
        loop {
            let deadline = Instant::now() + self.timeout;
            let next = tokio::select! {
                _ = &mut ctrl_c => return Ok(()),
                n = self.next(deadline) => n?,
            };
            let page = match next {
                None => {
                    writeln!(
                        out,
                        "(no CALIB_STATUS from canodom on {} for {} s — is the daemon running?)",
                        self.iface,
                        self.timeout.as_secs_f64()
                    )?;
                    drawn_lines = 0;
                    continue;
                }
                Some(Incoming::Status(page)) => page,
                Some(Incoming::Params(_)) => continue,
            };
            frames += 1;
            if g.apply(&page) && g.progress.is_some() {
                if tty {
                    let block = render_guide(&g);
                    if drawn_lines > 0 {
                        // Cursor up over the previous block, clear to the end.
                        write!(out, "\x1b[{drawn_lines}A\x1b[J")?;
                    }
                    out.write_all(block.as_bytes())?;
                    drawn_lines = block.lines().count();
                } else {
                    writeln!(out, "{}", render_line(&g))?;
                }
                out.flush()?;
            }
            if count.is_some_and(|n| frames >= n) {
                return Ok(());
            }
        }
    }
}

/// Runs `canodom calib`.
///
/// # Errors
/// Configuration or SocketCAN unavailable. Refusals exit with 1 and no
/// answer with 2 after printing why.
pub fn execute(args: &CalibArgs) -> anyhow::Result<()> {
    match run(args) {
        Err(e) if e.downcast_ref::<NoAnswer>().is_some() => {
            eprintln!("{e}");
            std::process::exit(EXIT_NO_ANSWER);
        }
        other => other,
    }
}

fn run(args: &CalibArgs) -> anyhow::Result<()> {
    // Global so it may follow the action; clap cannot require a global option.
    let Some(config_path) = &args.config else {
        anyhow::bail!(
            "calib needs the daemon's configuration: --config FILE (before or after the action)"
        );
    };
    let config = Config::load(config_path)?;
    if args.print_frame {
        println!("{}", cansend_line(&config, &args.action, args.counter)?);
        return Ok(());
    }
    let timeout = Duration::from_secs_f64(args.timeout_s);
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async {
        let mut link = Link::open(&config, timeout)?;
        match &args.action {
            Action::Status => {
                let g = link.status().await?;
                print!("{}", render_guide(&g));
                Ok(())
            }
            Action::Watch {
                track_radius,
                count,
            } => {
                let tty = std::io::stdout().is_terminal();
                let mut out = std::io::stdout().lock();
                link.watch(track_radius.map(track_length_m), *count, &mut out, tty)
                    .await
            }
            action => {
                let Some(cmd) = command_for(action) else {
                    unreachable!("every other action sends a command")
                };
                let answer = link
                    .command(
                        cmd,
                        config.calibration.command_id,
                        config.calibration.arming_code.unwrap_or(0),
                        initial_counter(),
                    )
                    .await?;
                match answer {
                    Answer::Done => println!("done"),
                    Answer::Refused(r) => {
                        println!("refused: {r} ({})", reason_text(r));
                        std::io::stdout().flush()?;
                        std::process::exit(1);
                    }
                    Answer::Pending => unreachable!("command() returns only answers"),
                }
                if cmd == Command::RequestParams {
                    match link.params().await? {
                        Some(Ok(set)) => println!(
                            "version {}: rear tread {:.4} m, rear left {:.5} m, rear right {:.5} m, \
                             ratio {:.5}, steering gain {:.4}, offset {:.3}°",
                            set.version,
                            set.rear_tread_m,
                            set.rear_left_diameter_m,
                            set.rear_right_diameter_m,
                            set.diameter_ratio,
                            set.steer_gain,
                            set.steer_offset_rad.to_degrees()
                        ),
                        Some(Err(set)) => anyhow::bail!(
                            "CALIB_PARAMS version {}: SET_CRC mismatch, set not trusted",
                            set.version
                        ),
                        None => return Err(link.no_answer("CALIB_PARAMS")),
                    }
                }
                Ok(())
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser as _;
    use std::collections::HashSet;

    #[derive(Debug, clap::Parser)]
    struct Cli {
        #[command(flatten)]
        args: CalibArgs,
    }

    fn parse(args: &[&str]) -> Result<CalibArgs, clap::Error> {
        Cli::try_parse_from(std::iter::once("calib").chain(args.iter().copied())).map(|c| c.args)
    }

    fn progress(state: State, instruction: InstructionCode) -> Progress {
        Progress {
            state,
            instruction,
            run_index: 3,
            runs_total: 5,
            direction: WireDirection::Ccw,
            start_point: canodom_protocol::calib_wire::StartPoint::SCcw,
            run_distance_m: 4.25,
            writeback: Writeback::Idle,
            standstill: true,
            writeback_attempts: 0,
        }
    }

    fn counts(seq: u8, last: CmdCode, reason: Reason) -> Counts {
        Counts {
            cw_accepted: 2,
            cw_rejected: 1,
            ccw_accepted: 1,
            ccw_rejected: 0,
            reject_reason: Reason::LengthOff,
            last_cmd: last.code(),
            cmd_reason: reason,
            active_version: 0,
            cmd_seq: seq,
        }
    }

    #[test]
    fn every_reason_state_and_writeback_has_its_own_text() {
        let reasons: HashSet<_> = Reason::ALL.iter().map(|&r| reason_text(r)).collect();
        assert_eq!(reasons.len(), Reason::ALL.len());
        assert!(reasons.iter().all(|t| t.len() > 5));
        let states: HashSet<_> = State::ALL.iter().map(|&s| state_text(s)).collect();
        assert_eq!(states.len(), State::ALL.len());
        let wb: HashSet<_> = Writeback::ALL.iter().map(|&w| writeback_text(w)).collect();
        assert_eq!(wb.len(), Writeback::ALL.len());
    }

    #[test]
    fn every_instruction_renders_distinct_words() {
        let texts: HashSet<_> = InstructionCode::ALL
            .iter()
            .map(|&i| instruction_text(&progress(State::Positioning, i)))
            .collect();
        assert_eq!(texts.len(), InstructionCode::ALL.len());
        let p = |i| instruction_text(&progress(State::Positioning, i));
        assert_eq!(
            p(InstructionCode::Go),
            "Drive run 3 of 5 counter-clockwise from S_CCW"
        );
        assert_eq!(p(InstructionCode::Stop), "Stop at the start point");
        assert_eq!(
            p(InstructionCode::MeasureEndPose),
            "Measure the real end pose of run 3 and send it with `canodom calib end-pose`"
        );
        assert_eq!(
            p(InstructionCode::ReadyToCompute),
            "Ready: send `canodom calib compute`"
        );
        assert_eq!(
            p(InstructionCode::ReviewResult),
            "Review the result: commit or abort"
        );
        // Every state × instruction renders a non-empty guide naming the state.
        let mut guides = HashSet::new();
        for &s in State::ALL {
            for &i in InstructionCode::ALL {
                let mut g = GuideState::new(Some(track_length_m(1.0)));
                assert!(g.apply(&StatusPage::Progress(progress(s, i))));
                let block = render_guide(&g);
                assert!(block.contains(s.name()), "{block}");
                assert!(render_line(&g).contains(s.name()));
                guides.insert(block);
            }
        }
        assert_eq!(guides.len(), State::ALL.len() * InstructionCode::ALL.len());
    }

    #[test]
    fn the_guide_shows_progress_counts_rejection_and_results() {
        let len = track_length_m(1.5);
        assert!((len - 15.424_777_960_769_38).abs() < 1e-9);
        let mut g = GuideState::new(Some(len));
        assert!(render_guide(&g).contains("Waiting"));
        let mut p = progress(State::Recording, InstructionCode::Drive);
        p.run_distance_m = len / 2.0;
        p.standstill = false;
        g.apply(&StatusPage::Progress(p));
        g.apply(&StatusPage::Counts(counts(
            3,
            CmdCode::StartSession,
            Reason::None,
        )));
        let block = render_guide(&g);
        assert!(block.contains("(50 %)"), "{block}");
        assert!(block.contains(&"#".repeat(15)), "{block}");
        assert!(block.contains("CW 2 accepted, 1 rejected"), "{block}");
        assert!(block.contains("LENGTH_OFF"), "{block}");
        assert!(block.contains("START_SESSION done"), "{block}");
        // Without the radius: distance only.
        let mut g2 = GuideState::new(None);
        g2.apply(&StatusPage::Progress(p));
        assert!(render_guide(&g2).contains("7.71 m driven"));

        // Results appear only once computed.
        let geom = StatusPage::ResultGeometry {
            rear_tread_m: 0.3123,
            rear_tread_std_m: 0.0007,
            diameter_ratio: 1.004_21,
        };
        g.apply(&geom);
        assert!(!render_guide(&g).contains("result:"));
        g.apply(&StatusPage::Progress(progress(
            State::Computed,
            InstructionCode::ReviewResult,
        )));
        g.apply(&geom);
        g.apply(&StatusPage::ResultQuality {
            diameter_ratio_std: 0.0003,
            end_err_before_m: 0.529,
            end_err_after_m: 0.096,
        });
        let block = render_guide(&g);
        assert!(block.contains("0.3123 m ± 0.0007 m"), "{block}");
        assert!(block.contains("1.00421 ± 0.00030"), "{block}");
        assert!(block.contains("0.529 m with nominal → 0.096 m"), "{block}");
        assert!(render_line(&g).contains("tread 0.3123"));
        // A new session clears them.
        g.apply(&StatusPage::Progress(progress(
            State::Positioning,
            InstructionCode::GoToStart,
        )));
        assert!(!render_guide(&g).contains("result:"));
        // Applying the same page again changes nothing.
        let before = g.clone();
        assert!(!g.apply(&StatusPage::Progress(progress(
            State::Positioning,
            InstructionCode::GoToStart,
        ))));
        assert_eq!(g, before);
    }

    #[test]
    fn an_answer_needs_a_new_sequence_number_and_the_same_command() {
        let c = counts(4, CmdCode::Commit, Reason::None);
        assert_eq!(judge(&c, 4, CmdCode::Commit), Answer::Pending);
        assert_eq!(judge(&c, 3, CmdCode::Abort), Answer::Pending);
        assert_eq!(judge(&c, 3, CmdCode::Commit), Answer::Done);
        let r = counts(0, CmdCode::Commit, Reason::OutOfBounds);
        assert_eq!(
            judge(&r, 7, CmdCode::Commit),
            Answer::Refused(Reason::OutOfBounds)
        );
    }

    #[test]
    fn every_action_maps_to_its_command() {
        let cases: [(&[&str], Option<Command>); 13] = [
            (
                &["start", "--track-radius", "1.5"],
                Some(Command::StartSession {
                    track_radius_mm: 1500,
                    runs_per_direction: 5,
                }),
            ),
            (
                &["start", "--track-radius", "0.75", "--runs", "3"],
                Some(Command::StartSession {
                    track_radius_mm: 750,
                    runs_per_direction: 3,
                }),
            ),
            (&["start-steering"], Some(Command::StartSteering)),
            (&["start-run"], Some(Command::StartRun)),
            (&["end-run"], Some(Command::EndRun)),
            (
                &[
                    "end-pose",
                    "--dx-mm",
                    "-12",
                    "--dy-mm",
                    "30",
                    "--dtheta-deg",
                    "-1.55",
                ],
                Some(Command::EndPose {
                    dx_mm: -12,
                    dy_mm: 30,
                    dtheta_decideg: -16,
                }),
            ),
            (&["abort"], Some(Command::Abort)),
            (&["compute"], Some(Command::Compute)),
            (&["commit"], Some(Command::Commit)),
            (&["rollback"], Some(Command::Rollback)),
            (&["params"], Some(Command::RequestParams)),
            (&["status"], None),
            (&["watch", "--count", "3"], None),
        ];
        for (argv, want) in cases {
            let mut full = vec!["--config", "x.toml"];
            full.extend_from_slice(argv);
            let args = parse(&full).unwrap();
            assert_eq!(command_for(&args.action), want, "{argv:?}");
        }
    }

    #[test]
    fn argument_errors_say_what_is_wrong() {
        let err = |argv: &[&str]| {
            let mut full = vec!["--config", "x.toml"];
            full.extend_from_slice(argv);
            parse(&full).unwrap_err().to_string()
        };
        assert!(err(&["start"]).contains("--track-radius"));
        assert!(err(&["start", "--track-radius", "-1"]).contains("must be positive"));
        assert!(err(&["start", "--track-radius", "0"]).contains("must be positive"));
        assert!(err(&["start", "--track-radius", "70"]).contains("65.535"));
        assert!(err(&["start", "--track-radius", "1", "--runs", "16"]).contains("16"));
        assert!(
            err(&[
                "end-pose",
                "--dx-mm",
                "9000",
                "--dy-mm",
                "0",
                "--dtheta-deg",
                "0"
            ])
            .contains("9000")
        );
        assert!(
            err(&[
                "end-pose",
                "--dx-mm",
                "0",
                "--dy-mm",
                "0",
                "--dtheta-deg",
                "300"
            ])
            .contains("204.7")
        );
        assert!(err(&["--timeout-s", "0", "status"]).contains("timeout"));
    }

    #[test]
    fn the_progress_bar_is_bounded() {
        assert_eq!(progress_bar(0.0, 10.0, 4), "[....] 0.00 m of 10.00 m (0 %)");
        assert_eq!(
            progress_bar(12.0, 10.0, 4),
            "[####] 12.00 m of 10.00 m (120 %)"
        );
    }

    #[test]
    fn commands_round_trip_through_the_wire() {
        let wire =
            CalibWire::new(canodom_protocol::own_dbc::BaseId::new(0x600, false).unwrap()).unwrap();
        let cmd = Command::EndPose {
            dx_mm: -12,
            dy_mm: 30,
            dtheta_decideg: -16,
        };
        let data = wire.encode_command(cmd, 0xA5, initial_counter());
        let back = wire.decode_command(&data).unwrap();
        assert_eq!(back.command, Some(cmd));
        assert_eq!(back.arming_code, 0xA5);
        assert!(back.checksum_ok);
    }
    /// A daemon that answers every command at once (COMMIT refused as out
    /// of bounds, a repeated counter as BAD_COUNTER) and otherwise sends
    /// progress and counts every 100 ms.
    async fn fake_daemon(bus: canodom_can::bus::InProcessBus, wire: CalibWire) {
        let (mut rx, tx) = bus.open().unwrap();
        let mut c = counts(5, CmdCode::None, Reason::None);
        let mut last_counter = None;
        let mut tick = tokio::time::interval(Duration::from_millis(100));
        let mut out = 0u8;
        let mut still = false;
        loop {
            let answer = tokio::select! {
                _ = tick.tick() => false,
                ev = rx.recv() => {
                    let Ok(BusEvent::Frame(r)) = ev else { return };
                    if r.frame.id() != wire.cmd_id() { continue; }
                    let f = wire.decode_command(r.frame.data()).unwrap();
                    c.last_cmd = f.cmd_raw;
                    c.cmd_reason = if last_counter == Some(f.counter) {
                        Reason::BadCounter
                    } else if f.command == Some(Command::Commit) {
                        Reason::OutOfBounds
                    } else {
                        Reason::None
                    };
                    last_counter = Some(f.counter);
                    c.cmd_seq = (c.cmd_seq + 1) % 8;
                    if f.command == Some(Command::RequestParams) {
                        // Result ahead of the answer: the order older
                        // daemons used, which the client must survive.
                        for page in wire.encode_params(&fake_set(), 7).unwrap() {
                            tx.send(&CalibWire::frame(wire.params_id(), &page).unwrap())
                                .await
                                .unwrap();
                        }
                    }
                    true
                }
            };
            let mut pages = vec![StatusPage::Counts(c)];
            if !answer {
                // Standstill toggles so a watcher sees changes.
                let mut p = progress(State::Idle, InstructionCode::None);
                still = !still;
                p.standstill = still;
                pages.push(StatusPage::Progress(p));
            }
            for page in pages {
                out = out.wrapping_add(1);
                let data = wire.encode_status(&page, out);
                tx.send(&CalibWire::frame(wire.status_id(), &data).unwrap())
                    .await
                    .unwrap();
            }
        }
    }

    /// The set the fake daemon reports on REQUEST_PARAMS.
    fn fake_set() -> canodom_protocol::calib_wire::ParamSet {
        canodom_protocol::calib_wire::ParamSet {
            version: 3,
            rear_tread_m: 0.3071,
            rear_left_diameter_m: 0.09,
            rear_right_diameter_m: 0.0914,
            diameter_ratio: 0.0914 / 0.09,
            steer_gain: 1.0,
            steer_offset_rad: 0.0,
        }
    }

    fn base() -> canodom_protocol::own_dbc::BaseId {
        canodom_protocol::own_dbc::BaseId::new(0x600, false).unwrap()
    }

    fn client(
        bus: &canodom_can::bus::InProcessBus,
    ) -> Link<canodom_can::bus::InProcessRx, canodom_can::bus::InProcessTx> {
        let (rx, tx) = bus.open().unwrap();
        Link {
            rx,
            tx,
            wire: CalibWire::new(base()).unwrap(),
            iface: "vcan0".into(),
            timeout: Duration::from_secs(2),
            early_params: Vec::new(),
        }
    }

    #[tokio::test(start_paused = true)]
    async fn commands_are_answered_refused_and_retried_after_a_duplicate_counter() {
        let bus = canodom_can::bus::InProcessBus::new("vcan0", 256);
        let mut link = client(&bus);
        tokio::spawn(fake_daemon(bus.clone(), CalibWire::new(base()).unwrap()));
        let id = link.wire.cmd_id();
        assert_eq!(
            link.command(Command::Abort, id, 0, 3).await.unwrap(),
            Answer::Done
        );
        // Same counter again: the daemon sees a duplicate, the client retries with 4.
        assert_eq!(
            link.command(Command::Compute, id, 0, 3).await.unwrap(),
            Answer::Done
        );
        assert_eq!(
            link.command(Command::Commit, id, 0, 9).await.unwrap(),
            Answer::Refused(Reason::OutOfBounds)
        );
        let g = link.status().await.unwrap();
        assert!(
            render_guide(&g).contains("COMMIT refused: OUT_OF_BOUNDS"),
            "{}",
            render_guide(&g)
        );
    }

    #[tokio::test(start_paused = true)]
    async fn params_sent_ahead_of_the_answer_are_still_the_result() {
        let bus = canodom_can::bus::InProcessBus::new("vcan0", 256);
        let mut link = client(&bus);
        tokio::spawn(fake_daemon(bus.clone(), CalibWire::new(base()).unwrap()));
        let id = link.wire.cmd_id();
        assert_eq!(
            link.command(Command::RequestParams, id, 0, 2)
                .await
                .unwrap(),
            Answer::Done
        );
        let set = link.params().await.unwrap().unwrap().unwrap();
        assert_eq!(set.version, 3);
        assert!((set.rear_tread_m - 0.3071).abs() < 1e-4, "{set:?}");
        assert!((set.rear_right_diameter_m - 0.0914).abs() < 1e-5, "{set:?}");
    }

    #[tokio::test(start_paused = true)]
    async fn a_silent_bus_is_no_answer_naming_the_interface() {
        let bus = canodom_can::bus::InProcessBus::new("vcan0", 16);
        let mut link = client(&bus);
        let err = link
            .command(Command::Abort, link.wire.cmd_id(), 0, 1)
            .await
            .unwrap_err();
        let text = err.to_string();
        assert!(err.downcast_ref::<NoAnswer>().is_some(), "{text}");
        assert_eq!(
            text,
            "no CALIB_STATUS from canodom on vcan0 within 2 s — is the daemon running with this config?"
        );
        assert!(
            link.status()
                .await
                .unwrap_err()
                .downcast_ref::<NoAnswer>()
                .is_some()
        );
    }
    #[tokio::test(start_paused = true)]
    async fn watch_prints_a_line_per_change_or_redraws_in_place() {
        let bus = canodom_can::bus::InProcessBus::new("vcan0", 256);
        tokio::spawn(fake_daemon(bus.clone(), CalibWire::new(base()).unwrap()));
        for tty in [false, true] {
            let mut link = client(&bus);
            let mut out = Vec::new();
            link.watch(Some(track_length_m(1.0)), Some(6), &mut out, tty)
                .await
                .unwrap();
            let text = String::from_utf8(out).unwrap();
            assert!(text.contains("No session"), "{text}");
            if tty {
                assert!(
                    text.contains("\x1b[") && text.contains("A\x1b[J"),
                    "{text:?}"
                );
                assert!(text.contains("runs:  CW 2 accepted"), "{text}");
            } else {
                assert!(!text.contains('\x1b'), "{text:?}");
                // The pages repeat: only changes print, and each is one line.
                let lines: Vec<_> = text.lines().collect();
                assert!((1..6).contains(&lines.len()), "{text}");
                assert!(lines.iter().all(|l| l.starts_with("IDLE | ")), "{text}");
            }
        }
    }
}
