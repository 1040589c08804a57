//! The calibration's status in words: what `canodom calib` shows an
//! operator. Refusal and rejection reasons, states and instructions as
//! sentences; CALIB_STATUS pages gathered into a guide (what to drive next,
//! the run's progress, counts, results) rendered as a screen or one line;
//! and whether a counts page answers a command. Pure, so any client (a
//! terminal, a dashboard) shows the same words.

use crate::calib_wire::{
    CmdCode, Counts, GnssSourceKind, GnssStatus, InstructionCode, Progress, Reason, State,
    StatusPage, WireDirection, Writeback,
};
use std::fmt::Write as _;

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
    /// The latest GNSS page (sent while `[gnss]` is configured).
    pub gnss: Option<GnssStatus>,
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
            StatusPage::Gnss(g) => self.gnss = Some(g),
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

/// The drift watch's line, while it flags a parameter.
fn drift_text(p: &Progress) -> Option<String> {
    p.drift.then(|| {
        format!(
            "drift: a parameter differs from the set in use (see the daemon's log){}",
            if p.drift_candidate {
                "; the learnt set awaits COMMIT"
            } else {
                ""
            }
        )
    })
}

/// The live GNSS source's line.
pub fn gnss_text(g: &GnssStatus) -> String {
    let source = match g.source {
        GnssSourceKind::None => "none",
        GnssSourceKind::Gpsd => "gpsd",
        GnssSourceKind::Nmea => "serial NMEA",
        GnssSourceKind::Ros2 => "ROS 2",
    };
    let error = g.error_95_m.map_or("no error estimate".to_owned(), |e| {
        format!("95 % error {e:.1} m")
    });
    format!(
        "GNSS ({source}): {}, {:.1} fixes/s, {error}, {} forwarded (mod 65536), {}{} refused, {}{} reconnects",
        if g.connected {
            "connected"
        } else {
            "not connected"
        },
        g.fixes_per_s,
        g.forwarded,
        g.refused,
        if g.refused == u8::MAX { "+" } else { "" },
        g.reconnects,
        if g.reconnects >= 3 { "+" } else { "" },
    )
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
    if let Some(line) = drift_text(&p) {
        let _ = writeln!(s, "  {line}");
    }
    if let Some(gnss) = &g.gnss {
        let _ = writeln!(s, "  {}", gnss_text(gnss));
    }
    if g.shows_results() {
        render_results(&mut s, &g.results);
    }
    s
}

/// The results of the last compute, as lines.
fn render_results(s: &mut String, r: &Results) {
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
    if let Some(gnss) = &g.gnss {
        let _ = write!(
            s,
            " | GNSS {} {:.1}/s",
            if gnss.connected { "up" } else { "down" },
            gnss.fixes_per_s
        );
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    fn progress(state: State, instruction: InstructionCode) -> Progress {
        Progress {
            state,
            instruction,
            run_index: 3,
            runs_total: 5,
            direction: WireDirection::Ccw,
            start_point: crate::calib_wire::StartPoint::SCcw,
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
    fn the_guide_names_a_drift_and_a_candidate_awaiting_commit() {
        let mut g = GuideState::new(None);
        let mut p = progress(State::Idle, InstructionCode::None);
        g.apply(&StatusPage::Progress(p));
        assert!(!render_guide(&g).contains("drift"));
        p.drift = true;
        assert!(g.apply(&StatusPage::Progress(p)));
        let block = render_guide(&g);
        assert!(block.contains("drift: a parameter differs"), "{block}");
        assert!(!block.contains("awaits COMMIT"), "{block}");
        p.drift_candidate = true;
        assert!(g.apply(&StatusPage::Progress(p)));
        assert!(render_guide(&g).contains("the learnt set awaits COMMIT"));
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
    fn the_gnss_page_is_a_line_of_the_guide_and_a_field_of_the_one_line_form() {
        let mut g = GuideState::new(None);
        g.apply(&StatusPage::Progress(progress(
            State::Idle,
            InstructionCode::None,
        )));
        assert!(!render_guide(&g).contains("GNSS"));
        let gnss = GnssStatus {
            source: GnssSourceKind::Nmea,
            connected: true,
            fixes_per_s: 1.0,
            error_95_m: Some(7.3),
            forwarded: 612,
            refused: 255,
            reconnects: 3,
        };
        assert!(g.apply(&StatusPage::Gnss(gnss)));
        let screen = render_guide(&g);
        assert!(
            screen.contains(
                "GNSS (serial NMEA): connected, 1.0 fixes/s, 95 % error 7.3 m, 612 forwarded \
                 (mod 65536), 255+ refused, 3+ reconnects"
            ),
            "{screen}"
        );
        assert!(
            render_line(&g).contains("| GNSS up 1.0/s"),
            "{}",
            render_line(&g)
        );
        let silent = GnssStatus {
            connected: false,
            error_95_m: None,
            fixes_per_s: 0.0,
            ..gnss
        };
        g.apply(&StatusPage::Gnss(silent));
        assert!(
            render_guide(&g).contains("not connected, 0.0 fixes/s, no error estimate"),
            "{}",
            render_guide(&g)
        );
    }

    #[test]
    fn the_progress_bar_is_bounded() {
        assert_eq!(progress_bar(0.0, 10.0, 4), "[....] 0.00 m of 10.00 m (0 %)");
        assert_eq!(
            progress_bar(12.0, 10.0, 4),
            "[####] 12.00 m of 10.00 m (120 %)"
        );
    }
}
