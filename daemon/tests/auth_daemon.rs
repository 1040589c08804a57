//! Issue #22 end to end on the in-process bus: the real daemon with a key
//! carries out a command that the real `canodom calib` signed (its
//! `--print-frame` lines), and does nothing for the same frames replayed,
//! for a copy with the counter rolled and the CRC recomputed, for a plain
//! command without an authenticator, nor for the replay after a restart.

use crate::util::{manifest, tmp_dir};
use canodom::server::{InProcessDaemon, Observers};
use canodom_can::bus::{BusEvent, FrameSink, FrameSource};
use canodom_can::frame::{CanFrame, FrameId};
use canodom_pipeline::config::Config;
use canodom_protocol::calib_wire::{CalibWire, Command, StatusPage};
use canodom_protocol::own_dbc::OwnFrame;
use canodom_protocol::secoc::{Authenticator, Key, split_auth};
use std::os::unix::fs::PermissionsExt as _;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;

const KEY_HEX: &str = "9f2c4e1a7b3d5f60718293a4b5c6d7e8";

/// rc_car.toml with absolute paths, a 0600 key and `[security]` in `dir`.
fn keyed_config(dir: &Path) -> PathBuf {
    keyed_config_with(dir, "")
}

/// As [`keyed_config`] with more `[security]` lines.
fn keyed_config_with(dir: &Path, security: &str) -> PathBuf {
    let key = dir.join("canodom.key");
    std::fs::write(&key, format!("{KEY_HEX}\n")).unwrap();
    std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o600)).unwrap();
    let text = std::fs::read_to_string(manifest().join("examples/rc_car.toml")).unwrap();
    let dbc = manifest().join("../data/dbc/rc_car.dbc");
    let text = text.replace(
        "dbc = \"../../data/dbc/rc_car.dbc\"",
        &format!("dbc = {:?}", dbc.display().to_string()),
    ) + &format!(
        "\n[security]\nkey_file = {:?}\noperator_freshness_file = \"operator-freshness\"\n{security}",
        key.display().to_string()
    );
    let text = text.replace(
        "[calibration]\n",
        "[calibration]\nparam_file = \"params.toml\"\n",
    );
    let path = dir.join("car.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// The frames of `canodom calib --print-frame ACTION` (one `cansend` line
/// per frame, joined by `&&`).
fn printed_frames(config: &Path, action: &str) -> Vec<CanFrame> {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_canodom"))
        .args([
            "calib",
            "--config",
            config.to_str().unwrap(),
            "--print-frame",
            action,
        ])
        .output()
        .unwrap();
    let stdout = String::from_utf8(out.stdout).unwrap();
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
        .split("&&")
        .map(|cmd| {
            let spec = cmd.split_whitespace().last().unwrap();
            let (id, hex) = spec.split_once('#').unwrap();
            let id = FrameId::standard(u16::from_str_radix(id, 16).unwrap()).unwrap();
            let bytes: Vec<u8> = (0..hex.len() / 2)
                .map(|i| u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).unwrap())
                .collect();
            CanFrame::new_data(id, &bytes).unwrap()
        })
        .collect()
}

/// Collects CMD_SEQ of CALIB_STATUS page 1 and the CALIB_PARAMS(_AUTH) frames.
#[derive(Default)]
struct Seen {
    cmd_seq: Vec<u8>,
    params: Vec<CanFrame>,
    params_auth: Vec<CanFrame>,
}

async fn run_daemon(config: &Arc<Config>, steps: &[Vec<CanFrame>]) -> Vec<Option<u8>> {
    let daemon = InProcessDaemon::spawn(Arc::clone(config), 4096, Observers::default());
    let bus = daemon.bus.clone();
    let wire = CalibWire::new(config.output.base_id).unwrap();
    let seen = Arc::new(Mutex::new(Seen::default()));
    let (mut rx, tx) = bus.open().unwrap();
    let listener = {
        let seen = Arc::clone(&seen);
        let params_auth = OwnFrame::CalibParamsAuth.id(config.output.base_id);
        tokio::spawn(async move {
            while let Ok(ev) = rx.recv().await {
                let BusEvent::Frame(r) = ev else { continue };
                let mut s = seen.lock().unwrap();
                if r.frame.id() == wire.status_id() {
                    if let Ok((StatusPage::Counts(c), _)) = wire.decode_status(r.frame.data()) {
                        s.cmd_seq.push(c.cmd_seq);
                    }
                } else if r.frame.id() == wire.params_id() {
                    s.params.push(r.frame);
                } else if r.frame.id() == params_auth {
                    s.params_auth.push(r.frame);
                }
            }
        })
    };
    // The daemon opens its end of the bus once it runs: let it. A frame
    // starts its bus clock; then the answer of each step: the last CMD_SEQ
    // seen 12 s (two page cycles) after it.
    tokio::time::sleep(Duration::from_millis(500)).await;
    tx.send(&CanFrame::new_data(FrameId::Standard(0x100), &[0; 8]).unwrap())
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_secs(12)).await;
    let mut answers = vec![seen.lock().unwrap().cmd_seq.last().copied()];
    for frames in steps {
        for f in frames {
            tx.send(f).await.unwrap();
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        tokio::time::sleep(Duration::from_secs(12)).await;
        answers.push(seen.lock().unwrap().cmd_seq.last().copied());
    }
    daemon.stop().await.unwrap();
    listener.abort();
    let s = seen.lock().unwrap();
    // Every CALIB_PARAMS page the daemon sent is followed by its valid authenticator.
    let auth = Authenticator::new(&Key::parse(KEY_HEX).unwrap());
    assert_eq!(s.params.len(), s.params_auth.len());
    if answers.iter().any(|a| a.is_some_and(|seq| seq > 0)) {
        assert!(!s.params.is_empty(), "REQUEST_PARAMS sends CALIB_PARAMS");
    }
    for (p, a) in s.params.iter().zip(&s.params_auth) {
        let (p, a): ([u8; 8], [u8; 8]) =
            (p.data().try_into().unwrap(), a.data().try_into().unwrap());
        assert!(
            auth.verify(wire_params_id(config), &p, &a),
            "{:?}",
            split_auth(&a)
        );
    }
    answers
}

fn wire_params_id(config: &Config) -> FrameId {
    OwnFrame::CalibParams.id(config.output.base_id)
}

#[tokio::test(start_paused = true)]
async fn auth_commands_signed_by_canodom_calib_are_accepted_and_replays_and_forgeries_are_not() {
    let dir = tmp_dir("auth-daemon");
    let _ = std::fs::remove_file(dir.join("canodom-freshness"));
    let _ = std::fs::remove_file(dir.join("operator-freshness"));
    let path = keyed_config(&dir);
    let config = Arc::new(Config::load(&path).unwrap());
    let signed = printed_frames(&path, "params");
    assert_eq!(signed.len(), 2, "the command and its authenticator");
    assert_eq!(
        signed[1].id(),
        OwnFrame::CalibCmdAuth.id(config.output.base_id)
    );
    let wire = CalibWire::new(config.output.base_id).unwrap();
    // The same command with the counter rolled and the CRC recomputed.
    let back = wire.decode_command(signed[0].data()).unwrap();
    let rolled = wire.encode_command(Command::RequestParams, 0, back.counter.wrapping_add(1));
    let rolled = vec![
        CanFrame::new_data(signed[0].id(), &rolled).unwrap(),
        signed[1],
    ];
    let plain = vec![
        CanFrame::new_data(
            signed[0].id(),
            &wire.encode_command(Command::Abort, 0, back.counter.wrapping_add(2)),
        )
        .unwrap(),
    ];
    let next = printed_frames(&path, "abort");
    let answers = run_daemon(
        &config,
        &[signed.clone(), signed.clone(), rolled.clone(), plain, next],
    )
    .await;
    // CMD_SEQ counts the commands answered: 0 at start.
    let [
        idle,
        first,
        replay,
        rolled_answer,
        plain_answer,
        next_answer,
    ] = answers[..]
    else {
        panic!("{answers:?}");
    };
    assert_eq!(idle, Some(0), "{answers:?}");
    assert_eq!(
        first,
        Some(1),
        "the signed command was answered: {answers:?}"
    );
    assert_eq!(replay, first, "the replay was ignored: {answers:?}");
    assert_eq!(
        rolled_answer, first,
        "the rolled copy was ignored: {answers:?}"
    );
    assert_eq!(
        plain_answer, first,
        "the unsigned command was ignored: {answers:?}"
    );
    assert_eq!(
        next_answer,
        Some(2),
        "a new signed command is answered: {answers:?}"
    );
    // A restart: the recording of the first command is refused after it.
    let answers = run_daemon(&config, &[signed, rolled]).await;
    assert_eq!(
        answers[..],
        [Some(0), Some(0), Some(0)],
        "replayed after a restart: {answers:?}"
    );
}

#[tokio::test(start_paused = true)]
async fn auth_guessed_macs_lock_out_secured_frames_and_calib_status_says_so() {
    let dir = tmp_dir("auth-lockout");
    let _ = std::fs::remove_file(dir.join("canodom-freshness"));
    let _ = std::fs::remove_file(dir.join("operator-freshness"));
    let path = keyed_config_with(
        &dir,
        "lockout_failures = 3\nlockout_window_s = 5\nlockout_s = 30\n",
    );
    let config = Arc::new(Config::load(&path).unwrap());
    let base = config.output.base_id;
    let wire = CalibWire::new(base).unwrap();
    let signed = printed_frames(&path, "params");
    let daemon = InProcessDaemon::spawn(Arc::clone(&config), 4096, Observers::default());
    let (mut rx, tx) = daemon.bus.open().unwrap();
    let lockout = Arc::new(Mutex::new(Vec::<bool>::new()));
    let seq = Arc::new(Mutex::new(Vec::<u8>::new()));
    let listener = {
        let (lockout, seq) = (Arc::clone(&lockout), Arc::clone(&seq));
        let wire = CalibWire::new(base).unwrap();
        tokio::spawn(async move {
            while let Ok(ev) = rx.recv().await {
                let BusEvent::Frame(r) = ev else { continue };
                if r.frame.id() != wire.status_id() {
                    continue;
                }
                if let Some(l) = wire.auth_lockout(r.frame.data()) {
                    lockout.lock().unwrap().push(l);
                }
                if let Ok((StatusPage::Counts(c), _)) = wire.decode_status(r.frame.data()) {
                    seq.lock().unwrap().push(c.cmd_seq);
                }
            }
        })
    };
    // The daemon opens its end of the bus once it runs: let it, then a
    // frame starts its bus clock (status is sent on that clock).
    tokio::time::sleep(Duration::from_millis(500)).await;
    tx.send(&CanFrame::new_data(FrameId::Standard(0x100), &[0; 8]).unwrap())
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert_eq!(
        lockout.lock().unwrap().last(),
        Some(&false),
        "no lockout yet"
    );
    // Three guessed authenticators within the window.
    let cmd = wire.encode_command(Command::Commit, 0, 3);
    for k in 0..3u8 {
        tx.send(&CanFrame::new_data(config.calibration.command_id, &cmd).unwrap())
            .await
            .unwrap();
        let guess = [0xF0, 0xFF, 0xFF, 0x7F, k, 0x5A, 0xA5, k];
        tx.send(&CanFrame::new_data(OwnFrame::CalibCmdAuth.id(base), &guess).unwrap())
            .await
            .unwrap();
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    tokio::time::sleep(Duration::from_secs(3)).await;
    assert_eq!(
        lockout.lock().unwrap().last(),
        Some(&true),
        "AUTH_LOCKOUT = 1"
    );
    // A correctly signed command during the lockout is refused unseen ...
    for f in &signed {
        tx.send(f).await.unwrap();
    }
    tokio::time::sleep(Duration::from_secs(12)).await;
    assert!(
        seq.lock().unwrap().iter().all(|&s| s == 0),
        "nothing answered during the lockout: {:?}",
        seq.lock().unwrap()
    );
    // ... and after it the flag clears and a fresh one is carried out.
    tokio::time::sleep(Duration::from_secs(20)).await;
    // The daemon's bus clock moves with frames: one frame after the lockout.
    tx.send(&CanFrame::new_data(FrameId::Standard(0x100), &[0; 8]).unwrap())
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert_eq!(
        lockout.lock().unwrap().last(),
        Some(&false),
        "AUTH_LOCKOUT back to 0"
    );
    for f in printed_frames(&path, "params") {
        tx.send(&f).await.unwrap();
    }
    tokio::time::sleep(Duration::from_secs(12)).await;
    assert_eq!(
        seq.lock().unwrap().last(),
        Some(&1),
        "answered after the lockout"
    );
    daemon.stop().await.unwrap();
    listener.abort();
}

/// The write-back states CALIB_STATUS page 0 showed, in order.
fn writeback_states(
    wire: &CalibWire,
    seen: &Mutex<Vec<canodom_protocol::calib_wire::Writeback>>,
    r: &canodom_can::bus::Received,
) {
    if r.frame.id() == wire.status_id()
        && let Ok((StatusPage::Progress(p), _)) = wire.decode_status(r.frame.data())
    {
        seen.lock().unwrap().push(p.writeback);
    }
}

#[tokio::test(start_paused = true)]
async fn auth_a_forged_calib_ack_leaves_the_write_back_pending_and_a_signed_one_ends_it() {
    use canodom_params::persist::{ParamFile, ParamValues, store};
    use canodom_protocol::calib_wire::{Ack, AckStatus, Writeback};
    let dir = tmp_dir("auth-ack");
    for f in ["canodom-freshness", "operator-freshness", "params.toml"] {
        let _ = std::fs::remove_file(dir.join(f));
    }
    let path = keyed_config(&dir);
    // A statistics line every half second: each takes the gate's figures
    // while the gate is in use (a second lock in the line once hung the daemon).
    let text = std::fs::read_to_string(&path).unwrap();
    let text = text.replace("stats_interval_s = 10.0", "stats_interval_s = 0.5");
    std::fs::write(&path, text).unwrap();
    // Logged as a service logs: tracing evaluates a line's fields only when
    // a subscriber takes it.
    let _log = tracing::subscriber::set_default(
        tracing_subscriber::fmt()
            .with_writer(std::io::sink)
            .finish(),
    );
    // Two committed sets: ROLLBACK writes set 1 back and waits for its ACK.
    let values = |tread_m| ParamValues {
        steering_gain: 1f64.to_radians(),
        ..ParamValues::plain(tread_m, 0.09)
    };
    let mut file = ParamFile::default();
    file.commit(values(0.30), "exact", 1, 10);
    file.commit(values(0.31), "exact", 2, 10);
    store(&dir.join("params.toml"), &file).unwrap();
    let config = Arc::new(Config::load(&path).unwrap());
    let rollback = printed_frames(&path, "rollback");
    let wire = CalibWire::new(config.output.base_id).unwrap();
    let daemon = InProcessDaemon::spawn(Arc::clone(&config), 4096, Observers::default());
    let (mut rx, tx) = daemon.bus.clone().open().unwrap();
    let states = Arc::new(Mutex::new(Vec::new()));
    let listener = {
        let (states, wire) = (
            Arc::clone(&states),
            CalibWire::new(config.output.base_id).unwrap(),
        );
        tokio::spawn(async move {
            while let Ok(ev) = rx.recv().await {
                if let BusEvent::Frame(r) = ev {
                    writeback_states(&wire, &states, &r);
                }
            }
        })
    };
    tokio::time::sleep(Duration::from_millis(500)).await;
    tx.send(&CanFrame::new_data(FrameId::Standard(0x100), &[0; 8]).unwrap())
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_secs(2)).await;
    for f in &rollback {
        tx.send(f).await.unwrap();
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(
        states.lock().unwrap().last(),
        Some(&Writeback::Pending),
        "the signed rollback started the write-back"
    );
    let ack = wire.encode_ack(
        Ack {
            version: 1,
            status: AckStatus::Stored,
        },
        0,
    );
    let ack_frame = CanFrame::new_data(wire.ack_id(), &ack).unwrap();
    let ack_auth_id = OwnFrame::CalibAckAuth.id(config.output.base_id);
    // Forged: signed with another key; and an ACK with no authenticator.
    let forger = Authenticator::new(&Key::parse("00112233445566778899aabbccddeeff").unwrap());
    let forged = forger.sign(wire.ack_id(), &ack, 1_000);
    for frames in [
        vec![ack_frame, CanFrame::new_data(ack_auth_id, &forged).unwrap()],
        vec![ack_frame],
    ] {
        for f in &frames {
            tx.send(f).await.unwrap();
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let before_signed = states.lock().unwrap().clone();
    assert!(
        !before_signed.contains(&Writeback::Acked),
        "a forged or unsigned CALIB_ACK counted as acknowledgement: {before_signed:?}"
    );
    assert_eq!(before_signed.last(), Some(&Writeback::Pending));
    // The parameter store's own signed ACK ends the write-back.
    let real = Authenticator::new(&Key::parse(KEY_HEX).unwrap());
    let signed = real.sign(wire.ack_id(), &ack, 1_001);
    tx.send(&ack_frame).await.unwrap();
    tokio::time::sleep(Duration::from_millis(1)).await;
    tx.send(&CanFrame::new_data(ack_auth_id, &signed).unwrap())
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(states.lock().unwrap().last(), Some(&Writeback::Acked));
    daemon.stop().await.unwrap();
    listener.abort();
}
