//! Issues #22, #33 and #44 on vcan: a sniffed session must not start, commit or
//! roll back a calibration. The real `canodom run` with its key file
//! (`canodom keys derive`'s `canodom` file) on `vcan0`; a whole guided
//! session (the operator's `canodom calib` start, compute and commit signed
//! with the operator's key file, `canodom simulate --follow-calibration`
//! driving the runs, an ECU emulator with the parameter store's key file
//! that checks `CALIB_PARAMS_AUTH` and signs its `CALIB_ACK`) is recorded
//! with `candump -L`. The daemon restarts, and an attacker replays the
//! whole recording with `canplayer`, then a copy of its commands and
//! acknowledgements with the counters rolled and the CRCs recomputed (their
//! authenticators kept: the attacker has no key). Judged: no new session,
//! the parameter file byte for byte and the live parameters (ODOM_QUALITY,
//! CALIB_STATUS) unchanged, and every replayed secured frame counted by
//! reason in the daemon's statistics: `bad_mac` (signed in the daemon's
//! previous epoch), its secured frame `missing_authenticator`. Then the
//! clock of the VM is set back an hour (issue #44), the daemon restarted
//! once more and the recording replayed again: the same, nothing changes.
#![cfg(feature = "vcan")]
// Test code: the scenario reads top to bottom as the story it checks.
#![allow(clippy::unwrap_used, clippy::too_many_lines)]

use canodom_can::bus::{BusEvent, FrameSink, FrameSource, IdFilter, open_socketcan};
use canodom_can::frame::{CanFrame, FrameId};
use canodom_dbc::{Checksum, Database};
use canodom_pipeline::gate::Signer;
use canodom_protocol::calib_wire::{
    Ack, AckStatus, CalibWire, Counts, ParamsAssembler, Progress, State, StatusPage, Writeback,
};
use canodom_protocol::own_dbc::{BaseId, OwnFrame};
use canodom_protocol::secoc::{Authenticator, Sync, freshness, split_freshness};
use canodom_protocol::secoc_keys::{MasterKey, Party, Role};
use canodom_vcan_tests::{
    Spawned, calibration_config, canodom_bin, metric, read, read_candump, repo_file, run,
    scratch_dir, start_daemon, wait_until,
};
use std::fmt::Write as _;
use std::os::unix::fs::PermissionsExt as _;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

const BASE: u32 = 0x600;
const ARMING: u8 = 0x5A;
const MASTER_HEX: &str = "5e1f0c2a9b7d4e3f60718293a4b5c6d7";
const VEHICLE: &str = "vcan-car";

fn master() -> MasterKey {
    MasterKey::parse(MASTER_HEX).unwrap()
}

/// Writes `party`'s key file into `dir`, 0600, as `canodom keys derive` does.
fn key_file(dir: &Path, party: Party) -> PathBuf {
    let path = dir.join(format!("{}.keys", party.name()));
    std::fs::write(&path, master().key_file(VEHICLE, party).unwrap().as_bytes()).unwrap();
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)).unwrap();
    path
}

fn base() -> BaseId {
    BaseId::new(BASE, false).unwrap()
}

/// The calibration scenario's configuration (input cycle times declared
/// 40 ms, see calib_over_can.rs) with the daemon's key file and
/// `[security]`, and the operator's twin holding the operator's key file.
fn write_config(dir: &Path) -> (PathBuf, PathBuf) {
    let mut dbc = read(&repo_file("data/dbc/rc_car.dbc"));
    for id in [256, 257, 272] {
        dbc = dbc.replace(
            &format!("BA_ \"GenMsgCycleTime\" BO_ {id} 10;"),
            &format!("BA_ \"GenMsgCycleTime\" BO_ {id} 40;"),
        );
    }
    let dbc_path = dir.join("rc_car_40ms.dbc");
    std::fs::write(&dbc_path, dbc).unwrap();
    let config = calibration_config(dir, &dbc_path, ARMING).unwrap();
    let bench = "[security]\nallow_without_key = true ";
    let text = read(&config);
    assert!(text.contains(bench), "the example is a bench: {text}");
    let with_key = |party| {
        let mut section = String::from("[security]\n");
        let _ = write!(
            section,
            "key_file = {:?}\nfreshness_file = {:?}\noperator_freshness_file = {:?}\n\
             # allow_without_key = false ",
            key_file(dir, party).display().to_string(),
            dir.join("daemon-freshness").display().to_string(),
            dir.join("operator-freshness").display().to_string(),
        );
        text.replace(bench, &section)
    };
    std::fs::write(&config, with_key(Party::Canodom)).unwrap();
    let operator = dir.join("operator.toml");
    std::fs::write(&operator, with_key(Party::Operator)).unwrap();
    (config, operator)
}

#[derive(Default)]
struct Heard {
    progress: Option<Progress>,
    counts: Option<Counts>,
    /// (PARAM_VERSION, NOMINAL_PARAMS) of the latest ODOM_QUALITY.
    quality: Option<(u64, u64)>,
    /// CALIB_PARAMS pages whose authenticator the ECU verified / refused.
    params_verified: u64,
    params_refused: u64,
}

/// Listens to status and pose quality, and plays the parameter store ECU:
/// each `CALIB_PARAMS` page counts only with a valid `CALIB_PARAMS_AUTH`,
/// and a complete set is acknowledged with a signed `CALIB_ACK`.
fn listen_and_ack(dir: &Path, heard: Arc<Mutex<Heard>>) -> tokio::task::JoinHandle<()> {
    let wire = CalibWire::new(base()).unwrap();
    let quality_id = FrameId::Standard((BASE + 2) as u16);
    let params_auth = OwnFrame::CalibParamsAuth.id(base());
    let db = Database::parse(&read(&repo_file("protocol/dbc/canodom.dbc")), "canodom.dbc").unwrap();
    let version = db.signal("ODOM_QUALITY.PARAM_VERSION").unwrap();
    let nominal = db.signal("ODOM_QUALITY.NOMINAL_PARAMS").unwrap();
    let store_keys = master();
    let params_key = store_keys.derive(VEHICLE, Role::CalibParams);
    let verifier = Authenticator::new(&params_key);
    // The store's mark: the last CALIB_PARAMS freshness value accepted.
    let mut last_params: Option<u64> = None;
    let mut signer = Signer::new(
        &store_keys.derive(VEHICLE, Role::CalibAck),
        &dir.join("ecu-freshness"),
        OwnFrame::CalibAckAuth.id(base()),
        base(),
    )
    .unwrap()
    .hearing_with(&params_key);
    let sync_ids = signer.sync_ids();
    let (mut rx, tx) = open_socketcan(
        "vcan0",
        &[
            IdFilter::exact(wire.status_id()),
            IdFilter::exact(wire.params_id()),
            IdFilter::exact(params_auth),
            IdFilter::exact(quality_id),
            IdFilter::exact(sync_ids[0]),
            IdFilter::exact(sync_ids[1]),
        ],
    )
    .expect("open vcan0");
    tokio::spawn(async move {
        let mut assembler = ParamsAssembler::default();
        let mut page: Option<[u8; 8]> = None;
        let mut ack_counter = 0u8;
        while let Ok(ev) = rx.recv().await {
            let BusEvent::Frame(r) = ev else { continue };
            let (id, data) = (r.frame.id(), r.frame.data());
            // The daemon's announcement: its epoch, verified with the key.
            if signer.observe(&r.frame).is_some() {
                continue;
            }
            if id == wire.status_id() {
                match wire.decode_status(data) {
                    Ok((StatusPage::Progress(p), _)) => heard.lock().unwrap().progress = Some(p),
                    Ok((StatusPage::Counts(c), _)) => heard.lock().unwrap().counts = Some(c),
                    _ => {}
                }
            } else if id == quality_id {
                heard.lock().unwrap().quality = version.raw(data).zip(nominal.raw(data));
            } else if id == wire.params_id() {
                page = data.try_into().ok();
            } else if id == params_auth
                && let Some(p) = page.take()
            {
                let auth: [u8; 8] = data.try_into().unwrap();
                // As a store does: in the epoch the daemon announced, the
                // counter rebuilt around its mark, the MAC, and only once.
                let Some(epoch) = signer.last_sync().map(|s: Sync| s.epoch) else {
                    heard.lock().unwrap().params_refused += 1;
                    continue;
                };
                let mark = last_params
                    .filter(|m| split_freshness(*m).0 == epoch)
                    .unwrap_or(freshness(epoch, 0));
                let Some(fv) = verifier
                    .verify_near(wire.params_id(), &p, &auth, mark)
                    .filter(|fv| *fv > mark)
                else {
                    heard.lock().unwrap().params_refused += 1;
                    continue;
                };
                last_params = Some(fv);
                heard.lock().unwrap().params_verified += 1;
                if let Ok((pg, _)) = wire.decode_params(&p)
                    && let Some(Ok(set)) = assembler.push(&wire, pg)
                {
                    assembler = ParamsAssembler::default();
                    let ack = wire.encode_ack(
                        Ack {
                            version: set.version,
                            status: AckStatus::Stored,
                            set_crc: wire.set_crc(&set).unwrap(),
                        },
                        ack_counter,
                    );
                    ack_counter = ack_counter.wrapping_add(1);
                    let auth = signer.sign(wire.ack_id(), &ack).unwrap();
                    let _ = tx
                        .send(&CanFrame::new_data(wire.ack_id(), &ack).unwrap())
                        .await;
                    let _ = tx.send(&auth).await;
                }
            }
        }
    })
}

async fn until(heard: &Mutex<Heard>, what: &str, limit: Duration, ok: impl Fn(&Heard) -> bool) {
    let start = Instant::now();
    while !ok(&heard.lock().unwrap()) {
        let h = heard.lock().unwrap();
        assert!(
            start.elapsed() < limit,
            "{what}: not within {limit:?}; last {:?} {:?}",
            h.progress,
            h.counts
        );
        drop(h);
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

fn calib(config: &Path, args: &[&str]) -> String {
    let mut all = vec![
        "calib",
        "--config",
        config.to_str().unwrap(),
        "--timeout-s",
        "5",
    ];
    all.extend_from_slice(args);
    let out = std::process::Command::new(canodom_bin())
        .args(&all)
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    println!("$ canodom {}\n{}", all.join(" "), text.trim_end());
    assert!(out.status.success() && text.contains("done"), "{text}");
    text
}

/// The count of `reason=N` in the daemon's last line naming `auth_refused`.
fn refused(log: &str, reason: &str) -> u64 {
    let Some(line) = log.lines().rev().find(|l| l.contains("auth_refused")) else {
        return 0;
    };
    let needle = format!("{reason}=");
    line.find(&needle)
        .map(|at| &line[at + needle.len()..])
        .and_then(|rest| rest.split(|c: char| !c.is_ascii_digit()).next())
        .and_then(|n| n.parse().ok())
        .unwrap_or(0)
}

/// The `candump -L` line `line` with its CAN frame replaced.
fn relog(line: &str, id: u32, data: &[u8]) -> String {
    let head: Vec<&str> = line.split_whitespace().take(2).collect();
    let hex = data.iter().fold(String::new(), |mut s, b| {
        let _ = write!(s, "{b:02X}");
        s
    });
    format!("{} {} {id:03X}#{hex}", head[0], head[1])
}

#[tokio::test]
async fn secoc_replayed_and_edited_session_changes_nothing_and_is_counted_by_reason() {
    let dir = scratch_dir("secoc-replay").unwrap();
    let (config, operator) = write_config(&dir);
    let params = dir.join("params.toml");
    let truth = dir.join("truth.toml");
    std::fs::write(
        &truth,
        format!(
            "rear_tread_m = {}\nrear_right_diameter_m = {}\n",
            0.30 * 31.0 / 30.0,
            0.09 * 1.015
        ),
    )
    .unwrap();
    let heard = Arc::new(Mutex::new(Heard::default()));
    let listener = listen_and_ack(&dir, Arc::clone(&heard));

    // 1. A real session, recorded.
    let session_log = dir.join("session.log");
    let mut candump = Spawned::start(
        Path::new("candump"),
        &["-L", "vcan0"],
        Some(&session_log),
        Some(&dir.join("candump.err")),
    )
    .unwrap();
    let daemon_log = dir.join("daemon.log");
    let mut daemon = start_daemon(&config, &daemon_log).unwrap();
    let vehicle_out = dir.join("vehicle.out");
    let mut vehicle = Spawned::start(
        &canodom_bin(),
        &[
            "simulate",
            "--config",
            &config.to_string_lossy(),
            "--iface",
            "vcan0",
            "--follow-calibration",
            "--true-params",
            &truth.to_string_lossy(),
            "--speed-mps",
            "1.5",
            "--time-limit-s",
            "80",
        ],
        Some(&vehicle_out),
        Some(&vehicle_out.with_extension("err")),
    )
    .unwrap();
    wait_until("the vehicle listens", Duration::from_secs(15), || {
        read(&vehicle_out).contains("standing still until")
    })
    .unwrap();
    until(
        &heard,
        "a first CALIB_STATUS",
        Duration::from_secs(10),
        |h| h.progress.is_some(),
    )
    .await;
    let started = Instant::now();
    calib(
        &operator,
        &["start", "--track-radius", "0.78", "--runs", "2"],
    );
    until(&heard, "READY", Duration::from_secs(70), |h| {
        h.progress.is_some_and(|p| p.state == State::Ready)
    })
    .await;
    calib(&operator, &["compute"]);
    until(&heard, "COMPUTED", Duration::from_secs(10), |h| {
        h.progress.is_some_and(|p| p.state == State::Computed)
    })
    .await;
    calib(&operator, &["commit"]);
    until(&heard, "WRITEBACK ACKED", Duration::from_secs(10), |h| {
        h.progress.is_some_and(|p| p.writeback == Writeback::Acked)
    })
    .await;
    metric(
        "secoc_session_s",
        format!("{:.1}", started.elapsed().as_secs_f64()),
    );
    assert!(
        vehicle
            .wait_timeout(Duration::from_secs(15))
            .unwrap()
            .success()
    );
    let status = daemon.stop("TERM", Duration::from_secs(10)).unwrap();
    assert!(status.success(), "{}", read(&daemon_log));
    candump.stop("INT", Duration::from_secs(5)).unwrap();
    let phase1 = read(&daemon_log);
    assert_eq!(
        refused(&phase1, "bad_mac") + refused(&phase1, "replayed") + refused(&phase1, "stale"),
        0,
        "{phase1}"
    );
    let (verified, refused_pages) = {
        let h = heard.lock().unwrap();
        (h.params_verified, h.params_refused)
    };
    assert!(
        verified >= 4 && refused_pages == 0,
        "the ECU checked CALIB_PARAMS"
    );
    let file_before = std::fs::read(&params).unwrap();
    let stored = canodom_params::persist::from_toml(&params, &read(&params)).unwrap();
    assert_eq!(stored.current.as_ref().map(|c| c.version), Some(1));

    // The secured frames in the recording, and the attacker's edit of them.
    let (frames, _) = read_candump(&session_log).unwrap();
    let id_of = |f: OwnFrame| f.id(base());
    let count = |id: FrameId| frames.iter().filter(|l| l.frame.id() == id).count() as u64;
    let (cmds, cmd_auths) = (
        count(id_of(OwnFrame::CalibCmd)),
        count(id_of(OwnFrame::CalibCmdAuth)),
    );
    let (acks, ack_auths) = (
        count(id_of(OwnFrame::CalibAck)),
        count(id_of(OwnFrame::CalibAckAuth)),
    );
    println!(
        "recorded: {} frames, CALIB_CMD {cmds} (+{cmd_auths} auth), CALIB_ACK {acks} (+{ack_auths} auth)",
        frames.len()
    );
    assert!(cmds >= 3 && cmds == cmd_auths && acks >= 1 && acks == ack_auths);
    let crc = Checksum::rc_car();
    let mut edited = String::new();
    for line in read(&session_log).lines() {
        let Some(spec) = line.split_whitespace().nth(2) else {
            continue;
        };
        let Some((id, hex)) = spec.split_once('#') else {
            continue;
        };
        let id = u32::from_str_radix(id, 16).unwrap_or(0);
        let secured = [BASE + 0x10, BASE + 0x13];
        if secured.contains(&id) {
            let mut d: Vec<u8> = (0..hex.len() / 2)
                .map(|i| u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).unwrap())
                .collect();
            // COUNTER (bits 52..55) + 1, CRC-8 recomputed.
            d[6] = (d[6] & 0x0F) | (((d[6] >> 4) + 1) & 0x0F) << 4;
            let _ = crc.apply(&mut d);
            edited.push_str(&relog(line, id, &d));
            edited.push('\n');
        } else if [BASE + 0x14, BASE + 0x16].contains(&id) {
            edited.push_str(line);
            edited.push('\n');
        }
    }
    let edited_log = dir.join("edited.log");
    std::fs::write(&edited_log, &edited).unwrap();

    // 2. The daemon restarts; the attacker replays. 3. Again with the
    // clock set back an hour before the restart (issue #44).
    let attack = Attack {
        config: &config,
        session_log: &session_log,
        edited_log: &edited_log,
        params: &params,
        file_before: &file_before,
        heard: &heard,
        secured: 2 * (cmds + acks),
    };
    attack.run(&dir.join("daemon-attacked.log"), "").await;
    let real = nix::time::clock_gettime(nix::time::ClockId::CLOCK_REALTIME).unwrap();
    let back = nix::sys::time::TimeSpec::new(real.tv_sec() - 3600, real.tv_nsec());
    nix::time::clock_settime(nix::time::ClockId::CLOCK_REALTIME, back)
        .expect("set the VM's clock back an hour (the scenarios run as root in the VM)");
    let stepped = Instant::now();
    attack
        .run(&dir.join("daemon-clock-back.log"), "_clock_back_1h")
        .await;
    let restored = nix::sys::time::TimeSpec::new(
        real.tv_sec() + stepped.elapsed().as_secs() as i64,
        real.tv_nsec(),
    );
    nix::time::clock_settime(nix::time::ClockId::CLOCK_REALTIME, restored).unwrap();
    listener.abort();
}

/// The attacker's replay of a recorded session against a restarted daemon.
struct Attack<'a> {
    config: &'a Path,
    session_log: &'a Path,
    edited_log: &'a Path,
    params: &'a Path,
    file_before: &'a [u8],
    heard: &'a Mutex<Heard>,
    /// Secured frames replayed in all (the recording's and the edited ones).
    secured: u64,
}

impl Attack<'_> {
    /// Restarts the daemon (log `log`), replays the recording and the
    /// edited copy, and judges: nothing changed, every replayed
    /// authenticator refused as `bad_mac` (another epoch) or `stale` (below
    /// the floor of a window ago), every secured frame left without one.
    async fn run(&self, log_path: &Path, tag: &str) {
        let mut daemon = start_daemon(self.config, log_path).unwrap();
        tokio::time::sleep(Duration::from_secs(2)).await;
        // The whole recording at its own pace (a flood would only measure
        // the kernel's queues), then the edited commands with gaps over 1 s cut.
        let replay_started = Instant::now();
        run("canplayer", &["-I", self.session_log.to_str().unwrap()]).unwrap();
        run(
            "canplayer",
            &["-I", self.edited_log.to_str().unwrap(), "-s", "1"],
        )
        .unwrap();
        metric(
            &format!("secoc_replay{tag}_s"),
            format!("{:.1}", replay_started.elapsed().as_secs_f64()),
        );
        // The replayed status frames still queued for the listener are
        // stale: judge only what the daemon sends from now on.
        tokio::time::sleep(Duration::from_secs(2)).await;
        *self.heard.lock().unwrap() = Heard::default();
        until(
            self.heard,
            "fresh status and poses",
            Duration::from_secs(10),
            |h| h.progress.is_some() && h.counts.is_some() && h.quality.is_some(),
        )
        .await;
        let (progress, counts, quality) = {
            let h = self.heard.lock().unwrap();
            (h.progress.unwrap(), h.counts.unwrap(), h.quality)
        };
        let status = daemon.stop("TERM", Duration::from_secs(10)).unwrap();
        assert!(status.success(), "{}", read(log_path));
        let log = read(log_path);
        let line = log
            .lines()
            .rev()
            .find(|l| l.contains("auth_refused"))
            .unwrap_or("");
        println!("daemon after the attack{tag}: {line}");
        assert_eq!(
            progress.state,
            State::Idle,
            "no session was started: {progress:?}"
        );
        assert_eq!(counts.active_version, 1, "{counts:?}");
        assert_eq!(quality, Some((1, 0)), "the live parameters are set 1");
        assert_eq!(
            std::fs::read(self.params).unwrap(),
            self.file_before,
            "the parameter file is unchanged"
        );
        let (bad_mac, stale) = (refused(&log, "bad_mac"), refused(&log, "stale"));
        assert_eq!(bad_mac + stale, self.secured, "{line}");
        assert_eq!(
            refused(&log, "missing_authenticator"),
            self.secured,
            "{line}"
        );
        for other in ["replayed", "unpaired_authenticator", "bad_length"] {
            assert_eq!(refused(&log, other), 0, "{other}: {line}");
        }
        metric(&format!("secoc{tag}_refused_bad_mac"), bad_mac);
        metric(&format!("secoc{tag}_refused_stale"), stale);
        metric(
            &format!("secoc{tag}_refused_missing_authenticator"),
            refused(&log, "missing_authenticator"),
        );
    }
}
