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
use canodom_pipeline::gate::Signer;
use canodom_protocol::calib_wire::{
    CalibWire, Command, Counts, ParamsAssembler, Reason, StatusPage,
};
use canodom_protocol::guide::{
    Answer, GuideState, judge, reason_text, render_guide, render_line, track_length_m,
};
use canodom_protocol::own_dbc::OwnFrame;
use canodom_protocol::secoc_keys::Role;
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
configured arming code, rolling counter and CRC-8, each followed by its CALIB_CMD_AUTH \
(SecOC: freshness from the clock and CMAC with the operator's calib_cmd key) when [security] \
key_file is set; answers are read from CALIB_STATUS at [output] base_id + 0x11. \
CALIB_STATUS and CALIB_PARAMS are not authenticated towards the operator (who holds only the \
command key): what `status`, `watch` and `params` show could come from any node on the bus."
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
    /// CRC filled in) instead of sending it; with a key it first hears the
    /// daemon's `SECOC_SYNC` on the interface (valid for its window).
    #[arg(long, global = true)]
    pub print_frame: bool,
    /// With --print-frame: the rolling counter, 0..=15 (default: from the
    /// clock, as a sent command takes it). The daemon refuses a counter equal
    /// to the previous command's, so successive lines need different ones.
    // Not `requires = "print_frame"`: clap checks that inside the
    // subcommand, where a --print-frame given before the action is not
    // seen, so `--print-frame start --counter 3` failed; run() checks it.
    #[arg(long, global = true,
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
    signer: Option<&mut Signer>,
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
    // cansend takes the frame as candump -L writes it.
    let frame = CalibWire::frame(config.calibration.command_id, &data)?;
    let mut line = format!("cansend {} ", config.interface).into_bytes();
    canodom_can::candump::format_frame(&mut line, &frame);
    if let Some(signer) = signer {
        // The authenticator follows at once (SecOC): a second cansend line.
        let auth = signer.sign(frame.id(), &data)?;
        line.extend_from_slice(format!(" && cansend {} ", config.interface).as_bytes());
        canodom_can::candump::format_frame(&mut line, &auth);
    }
    Ok(String::from_utf8_lossy(&line).into_owned())
}

/// The signer of `CALIB_CMD` when `[security] key_file` is set: the
/// operator's `calib_cmd` key (the daemon's own key file holds it too).
fn operator_signer(config: &Config) -> anyhow::Result<Option<Signer>> {
    let Some(keys) = &config.security.keys else {
        return Ok(None);
    };
    let Some(key) = keys.key(Role::CalibCmd) else {
        anyhow::bail!(
            "{}: the key file of the {} holds no calib_cmd key; `canodom calib` signs with the \
             operator's file of `canodom keys derive`",
            config
                .security
                .key_file
                .as_deref()
                .unwrap_or(std::path::Path::new("key file"))
                .display(),
            keys.party.name()
        );
    };
    Ok(Some(Signer::new(
        key,
        &config.security.operator_freshness_file,
        OwnFrame::CalibCmdAuth.id(config.output.base_id),
        config.output.base_id,
    )?))
}

/// Said once when a keyed client reads what the daemon sends.
const UNAUTHENTICATED_NOTE: &str = "note: CALIB_STATUS and CALIB_PARAMS are not authenticated \
towards canodom calib (an operator holds only the command key): what is shown could come from \
any node on the bus; commands and the write-back to the parameter store are authenticated";

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
    /// Signs each command with the key (SecOC), when one is configured.
    signer: Option<Signer>,
}

enum Incoming {
    Status(StatusPage),
    Params(canodom_protocol::calib_wire::ParamsPage),
}

impl Link<canodom_can::bus::SocketCanRx, canodom_can::bus::SocketCanTx> {
    fn open(config: &Config, timeout: Duration, signer: Option<Signer>) -> anyhow::Result<Self> {
        let wire = CalibWire::new(config.output.base_id)?;
        let iface = config.interface.clone();
        let mut filters = vec![
            IdFilter::exact(wire.status_id()),
            IdFilter::exact(wire.params_id()),
        ];
        // The daemon's SecOC announcements, which a signer needs.
        filters.extend(
            signer
                .iter()
                .flat_map(|s| s.sync_ids().map(IdFilter::exact)),
        );
        let (rx, tx) = open_socketcan(&iface, &filters).map_err(|e| {
            let hint = e
                .hint()
                .unwrap_or_else(|| format!("`ip link show {iface}`"));
            anyhow::anyhow!("SocketCAN interface {iface} is unavailable ({e}): {hint}")
        })?;
        Ok(Self {
            rx,
            tx,
            wire,
            iface,
            timeout,
            early_params: Vec::new(),
            signer,
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
            if let Some(signer) = &mut self.signer {
                // A SecOC announcement: the epoch and floor to sign above.
                let _ = signer.observe(&r.frame);
            }
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

    /// With a signer: waits (up to the timeout) until a `SECOC_SYNC` of
    /// the daemon was verified with the key; without one, returns at once.
    async fn await_sync(&mut self) -> anyhow::Result<()> {
        // The daemon announces every second: two periods at least.
        let deadline = Instant::now() + self.timeout.max(Duration::from_secs(2));
        while self
            .signer
            .as_ref()
            .is_some_and(|s| s.last_sync().is_none())
        {
            match self.next(deadline).await? {
                None => return Err(self.no_answer("SECOC_SYNC verified with this key")),
                Some(Incoming::Params(page)) => self.early_params.push(page),
                Some(Incoming::Status(_)) => {}
            }
        }
        Ok(())
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
        // Before the command goes out: its authenticator must follow within 100 ms.
        self.await_sync().await?;
        for attempt in 0..2 {
            let data = self.wire.encode_command(cmd, arming, counter);
            let frame = CalibWire::frame(cmd_id, &data)?;
            self.tx
                .send(&frame)
                .await
                .with_context(|| format!("sending CALIB_CMD on {}", self.iface))?;
            if let Some(signer) = &mut self.signer {
                let auth = signer.sign(cmd_id, &data)?;
                self.tx
                    .send(&auth)
                    .await
                    .with_context(|| format!("sending CALIB_CMD_AUTH on {}", self.iface))?;
            }
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
    if args.counter.is_some() && !args.print_frame {
        anyhow::bail!(
            "--counter goes with --print-frame (a sent command takes its counter from the clock)"
        );
    }
    let config = Config::load(config_path)?;
    let signer = operator_signer(&config)?;
    let timeout = Duration::from_secs_f64(args.timeout_s);
    if args.print_frame && signer.is_none() {
        println!(
            "{}",
            cansend_line(&config, &args.action, args.counter, None)?
        );
        return Ok(());
    }
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async {
        let mut link = Link::open(&config, timeout, signer)?;
        if args.print_frame {
            // Signed: the daemon's epoch and floor first (SecOC profile 3).
            link.await_sync().await?;
            let line = cansend_line(&config, &args.action, args.counter, link.signer.as_mut())?;
            println!("{line}");
            return Ok(());
        }
        if link.signer.is_some()
            && matches!(
                args.action,
                Action::Status | Action::Watch { .. } | Action::Params
            )
        {
            eprintln!("{UNAUTHENTICATED_NOTE}");
        }
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
    use canodom_protocol::calib_wire::{
        CmdCode, InstructionCode, Progress, State, WireDirection, Writeback,
    };
    use clap::Parser as _;

    #[derive(Debug, clap::Parser)]
    struct Cli {
        #[command(flatten)]
        args: CalibArgs,
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
            drift: false,
            drift_candidate: false,
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

    fn parse(args: &[&str]) -> Result<CalibArgs, clap::Error> {
        Cli::try_parse_from(std::iter::once("calib").chain(args.iter().copied())).map(|c| c.args)
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
    fn print_frame_and_counter_go_before_or_after_the_action() {
        for argv in [
            &["--print-frame", "--counter", "3", "commit"][..],
            &["--print-frame", "commit", "--counter", "3"],
            &["commit", "--print-frame", "--counter", "3"],
            &["--counter", "3", "commit", "--print-frame"],
        ] {
            let mut full = vec!["--config", "x.toml"];
            full.extend_from_slice(argv);
            let args = parse(&full).unwrap_or_else(|e| panic!("{argv:?}: {e}"));
            assert!(args.print_frame, "{argv:?}");
            assert_eq!(args.counter, Some(3), "{argv:?}");
        }
        // Without --print-frame, run() refuses the counter before anything.
        let args = parse(&["--config", "x.toml", "commit", "--counter", "3"]).unwrap();
        let e = run(&args).unwrap_err().to_string();
        assert!(e.contains("--counter goes with --print-frame"), "{e}");
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
            signer: None,
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
