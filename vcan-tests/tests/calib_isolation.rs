//! Scenario 6 of issue 7, isolation: a calibration command on the wrong id,
//! with a bad CRC or with a wrong arming code changes nothing. The real
//! `canodom run` on `vcan0` with an arming code set; commands sent raw with
//! `cansend`; the daemon's `CALIB_STATUS` pages read live from the bus and,
//! afterwards, from the `candump -L` recording of the same traffic. A correct
//! command last proves that the refusals are not merely a deaf daemon.
#![cfg(feature = "vcan")]
// Test code: the scenario reads top to bottom as the story it checks.
#![allow(clippy::unwrap_used, clippy::too_many_lines)]

use canodom_can::bus::{BusEvent, FrameSource, IdFilter, open_socketcan};
use canodom_can::frame::FrameId;
use canodom_protocol::calib_wire::{CalibWire, Command, Counts, Reason, State, StatusPage};
use canodom_protocol::own_dbc::BaseId;
use canodom_vcan_tests::{
    Spawned, calibration_config, canodom_bin, metric, read, read_candump, repo_file, scratch_dir,
    wait_until,
};
use std::path::Path;
use std::time::{Duration, Instant};
use tokio::time::timeout;

/// Base id of the daemon's own frames (the rc_car example's default).
const BASE: u32 = 0x600;
/// `CALIB_CMD` at the default offset (base + 0x10).
const CMD_ID: u32 = BASE + 0x10;
/// A free id near it: the wrong one.
const WRONG_ID: u32 = BASE + 0x20;
/// The arming code the daemon is configured with.
const ARMING: u8 = 0x5A;

fn cansend(id: u32, data: &[u8]) {
    canodom_vcan_tests::cansend("vcan0", id, data).unwrap();
}

/// The status pages seen live, in order.
struct StatusReader<R> {
    rx: R,
    wire: CalibWire,
}

impl<R: FrameSource> StatusReader<R> {
    /// The next status page, or `None` once `deadline` has passed.
    async fn next(&mut self, deadline: Instant) -> Option<StatusPage> {
        loop {
            let left = deadline.checked_duration_since(Instant::now())?;
            let event = timeout(left, self.rx.recv()).await.ok()?.unwrap();
            if let BusEvent::Frame(r) = event
                && r.frame.id() == self.wire.status_id()
            {
                return Some(self.wire.decode_status(r.frame.data()).unwrap().0);
            }
        }
    }

    /// Page 1 with `cmd_seq == seq`, within `limit`; with `idle`, every
    /// progress page before it must be IDLE (nothing started a session).
    async fn counts_with_seq(&mut self, seq: u8, limit: Duration, idle: bool) -> Counts {
        let deadline = Instant::now() + limit;
        while let Some(page) = self.next(deadline).await {
            match page {
                StatusPage::Counts(c) if c.cmd_seq == seq => return c,
                StatusPage::Progress(p) if idle => assert_eq!(p.state, State::Idle, "{p:?}"),
                _ => {}
            }
        }
        panic!("no CALIB_STATUS page 1 with CMD_SEQ {seq} within {limit:?}");
    }
}

#[tokio::test]
async fn calibration_commands_on_wrong_id_bad_crc_or_wrong_arming_change_nothing() {
    let dir = scratch_dir("calib-isolation").unwrap();
    let params = dir.join("params.toml");
    let config_path = calibration_config(&dir, &repo_file("data/dbc/rc_car.dbc"), ARMING).unwrap();

    let wire = CalibWire::new(BaseId::new(BASE, false).unwrap()).unwrap();
    let (rx, _tx) =
        open_socketcan("vcan0", &[IdFilter::exact(wire.status_id())]).expect("open vcan0");
    let mut status = StatusReader { rx, wire };
    let candump = Spawned::start(
        Path::new("candump"),
        &["-L", "vcan0"],
        Some(&dir.join("bus.log")),
        Some(&dir.join("candump.err")),
    )
    .unwrap();

    let log = dir.join("daemon.log");
    let mut daemon = Spawned::start(
        &canodom_bin(),
        &["run", "--config", &config_path.to_string_lossy()],
        None,
        Some(&log),
    )
    .unwrap();
    wait_until("the daemon opens vcan0", Duration::from_secs(15), || {
        assert!(daemon.is_running(), "daemon exited: {}", read(&log));
        read(&log).contains("CAN interface open")
    })
    .unwrap();

    // A fresh daemon has answered no command: CMD_SEQ 0. It publishes
    // status only once bus time runs (its first frame), so the answers'
    // CMD_SEQ, not a periodic page, tells which commands were answered.
    let seq0 = 0u8;
    let start = Command::StartSession {
        track_radius_mm: 1500,
        runs_per_direction: 2,
    };

    // (a) A valid START_SESSION on the wrong id: not a command at all, so
    // no answer (any page 1 keeps CMD_SEQ 0, and (b)'s answer is CMD_SEQ 1).
    cansend(WRONG_ID, &status.wire.encode_command(start, ARMING, 0));
    let deadline = Instant::now() + Duration::from_millis(2500);
    let mut pages_1 = 0;
    while let Some(page) = status.next(deadline).await {
        match page {
            StatusPage::Counts(c) => {
                assert_eq!(c.cmd_seq, seq0, "answered a command on {WRONG_ID:#x}");
                pages_1 += 1;
            }
            StatusPage::Progress(p) => assert_eq!(p.state, State::Idle),
            _ => {}
        }
    }
    println!("status pages 1 after (a): {pages_1}");
    assert!(!params.exists(), "parameter file created by (a)");

    // (b) The right id, the CRC byte corrupted: refused BAD_CHECKSUM.
    let mut bad_crc = status.wire.encode_command(start, ARMING, 1);
    bad_crc[7] ^= 0x01;
    cansend(CMD_ID, &bad_crc);
    let c = status
        .counts_with_seq((seq0 + 1) % 8, Duration::from_secs(5), true)
        .await;
    assert_eq!(c.cmd_reason, Reason::BadChecksum, "{c:?}");
    assert_eq!(c.last_cmd, start.code().code(), "{c:?}");
    assert_eq!(c.active_version, 0);
    assert!(!params.exists(), "parameter file created by (b)");

    // (c) The right id and CRC, the wrong arming code: BAD_ARMING_CODE.
    cansend(CMD_ID, &status.wire.encode_command(start, ARMING ^ 0xFF, 2));
    let c = status
        .counts_with_seq((seq0 + 2) % 8, Duration::from_secs(5), true)
        .await;
    assert_eq!(c.cmd_reason, Reason::BadArmingCode, "{c:?}");
    assert_eq!(c.active_version, 0);
    // One more idle period: the refusals started nothing.
    let deadline = Instant::now() + Duration::from_millis(1500);
    while let Some(page) = status.next(deadline).await {
        if let StatusPage::Progress(p) = page {
            assert_eq!(p.state, State::Idle, "{p:?}");
        }
    }
    assert!(!params.exists(), "parameter file created by (c)");

    // (d) The same command done right is carried out: the checks above are
    // what refused, not a daemon deaf to commands.
    let sent = Instant::now();
    cansend(CMD_ID, &status.wire.encode_command(start, ARMING, 3));
    let c = status
        .counts_with_seq((seq0 + 3) % 8, Duration::from_secs(5), false)
        .await;
    assert_eq!(c.cmd_reason, Reason::None, "{c:?}");
    let deadline = Instant::now() + Duration::from_secs(3);
    let state = loop {
        match status.next(deadline).await {
            Some(StatusPage::Progress(p)) if p.state != State::Idle => break p.state,
            Some(_) => {}
            None => panic!("state still IDLE 3 s after a correct START_SESSION"),
        }
    };
    metric("calib_isolation_accept_ms", sent.elapsed().as_millis());
    println!("after the correct START_SESSION: state {state:?}");
    assert!(daemon.is_running(), "{}", read(&log));
    drop(daemon);
    let mut candump = candump;
    candump.stop("INT", Duration::from_secs(5)).unwrap();

    // The recording agrees: exactly three commands answered (seq0+1..=3),
    // each once per reason, and no state but IDLE before the correct one.
    let (frames, _) = read_candump(&dir.join("bus.log")).unwrap();
    let status_id = status.wire.status_id();
    let cmd_id = FrameId::Standard(CMD_ID as u16);
    let wrong_id = FrameId::Standard(WRONG_ID as u16);
    let sends: Vec<usize> = frames
        .iter()
        .enumerate()
        .filter(|(_, l)| l.frame.id() == cmd_id || l.frame.id() == wrong_id)
        .map(|(i, _)| i)
        .collect();
    assert_eq!(sends.len(), 4, "commands recorded");
    let mut answers = Vec::new();
    for (i, l) in frames.iter().enumerate() {
        if l.frame.id() != status_id {
            continue;
        }
        match status.wire.decode_status(l.frame.data()).unwrap().0 {
            StatusPage::Counts(c) if answers.last().is_none_or(|(s, _)| *s != c.cmd_seq) => {
                answers.push((c.cmd_seq, c.cmd_reason));
            }
            StatusPage::Progress(p) if i < sends[3] => assert_eq!(p.state, State::Idle),
            _ => {}
        }
    }
    let expected = [
        ((seq0 + 1) % 8, Reason::BadChecksum),
        ((seq0 + 2) % 8, Reason::BadArmingCode),
        ((seq0 + 3) % 8, Reason::None),
    ];
    assert_eq!(
        answers, expected,
        "CMD_SEQ/CMD_REASON sequence in the recording"
    );
    println!("recorded answers (CMD_SEQ, CMD_REASON): {answers:?}");
}
