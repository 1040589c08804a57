//! Issues #22 and #33 end to end on the in-process bus, whose clock starts
//! at the wall-clock time as the kernel's receive timestamps do: the real
//! daemon with its own key file carries out a command that the real
//! `canodom calib` signed with the operator's key file (its
//! `--print-frame` lines), and does nothing for the same frames replayed,
//! for a copy with the counter rolled and the CRC recomputed, for a plain
//! command, for the replay after a restart, for a command kept back by an
//! interleaved plain frame and replayed an hour later, for a two-year-old
//! recording after its freshness file was deleted; junk authenticators do
//! not keep valid commands out; an acknowledgement counts only when the
//! parameter store signed it for the set written back.

use crate::util::{manifest, tmp_dir};
use canodom::server::{InProcessDaemon, Observers};
use canodom_can::bus::{BusEvent, FrameSink, FrameSource, InProcessBus, Received};
use canodom_can::frame::{CanFrame, FrameId};
use canodom_pipeline::config::Config;
use canodom_pipeline::gate::Signer;
use canodom_protocol::calib_wire::{
    Ack, AckStatus, CalibWire, Command, ParamsAssembler, StatusPage, Writeback,
};
use canodom_protocol::own_dbc::OwnFrame;
use canodom_protocol::secoc::{Authenticator, Key};
use canodom_protocol::secoc_keys::{MasterKey, Party, Role};
use std::os::unix::fs::PermissionsExt as _;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;

const MASTER_HEX: &str = "9f2c4e1a7b3d5f60718293a4b5c6d7e8";
const VEHICLE: &str = "test-car-1";

fn master() -> MasterKey {
    MasterKey::parse(MASTER_HEX).unwrap()
}

fn role_key(role: Role) -> Key {
    master().derive(VEHICLE, role)
}

/// rc_car.toml with absolute paths, `party`'s 0600 key file and
/// `[security]` lines `security` in `dir`, written as `name`.
fn config_for(dir: &Path, party: Party, name: &str, security: &str) -> PathBuf {
    let key = dir.join(format!("{}.keys", party.name()));
    let _ = std::fs::remove_file(&key);
    std::fs::write(&key, master().key_file(VEHICLE, party).unwrap().as_bytes()).unwrap();
    std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o600)).unwrap();
    let text = std::fs::read_to_string(manifest().join("examples/rc_car.toml")).unwrap();
    let bench = "allow_without_key = true             # a bench: NOTHING is authenticated\n";
    assert!(text.contains(bench), "rc_car.toml lost its bench line");
    let dbc = manifest().join("../data/dbc/rc_car.dbc");
    let text = text
        .replace(
            "dbc = \"../../data/dbc/rc_car.dbc\"",
            &format!("dbc = {:?}", dbc.display().to_string()),
        )
        .replace(
            bench,
            &format!(
                "key_file = {:?}\noperator_freshness_file = \"operator-freshness\"\n{security}",
                key.display().to_string()
            ),
        )
        .replace(
            "[calibration]\n",
            "[calibration]\nparam_file = \"params.toml\"\n",
        );
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

/// The daemon's configuration (its own key file) and the operator's (the
/// operator's key file: command keys only), both in `dir`.
fn configs(dir: &Path, security: &str) -> (PathBuf, PathBuf) {
    for f in ["canodom-freshness", "operator-freshness", "params.toml"] {
        let _ = std::fs::remove_file(dir.join(f));
    }
    (
        config_for(dir, Party::Canodom, "car.toml", security),
        config_for(dir, Party::Operator, "operator.toml", ""),
    )
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

/// What the daemon sent, as a listener on the bus saw it.
#[derive(Default)]
struct Seen {
    cmd_seq: Vec<u8>,
    auth_lockout: Vec<bool>,
    writeback: Vec<Writeback>,
    params: Vec<Received>,
    params_auth: Vec<Received>,
}

/// The daemon on a bus whose clock starts now (wall clock), and a
/// listener recording what it sends.
struct Bench {
    daemon: InProcessDaemon,
    tx: canodom_can::bus::InProcessTx,
    seen: Arc<Mutex<Seen>>,
    listener: tokio::task::JoinHandle<()>,
    config: Arc<Config>,
}

impl Bench {
    async fn start(config: &Arc<Config>) -> Self {
        let bus = InProcessBus::new(&config.interface, 4096);
        let daemon = InProcessDaemon::spawn_on(Arc::clone(config), bus, Observers::default());
        let (mut rx, tx) = daemon.bus.open().unwrap();
        let seen = Arc::new(Mutex::new(Seen::default()));
        let listener = {
            let seen = Arc::clone(&seen);
            let wire = CalibWire::new(config.output.base_id).unwrap();
            let params_auth = OwnFrame::CalibParamsAuth.id(config.output.base_id);
            tokio::spawn(async move {
                while let Ok(ev) = rx.recv().await {
                    let BusEvent::Frame(r) = ev else { continue };
                    let mut s = seen.lock().unwrap();
                    if r.frame.id() == wire.status_id() {
                        if let Some(l) = wire.auth_lockout(r.frame.data()) {
                            s.auth_lockout.push(l);
                        }
                        match wire.decode_status(r.frame.data()) {
                            Ok((StatusPage::Counts(c), _)) => s.cmd_seq.push(c.cmd_seq),
                            Ok((StatusPage::Progress(p), _)) => s.writeback.push(p.writeback),
                            _ => {}
                        }
                    } else if r.frame.id() == wire.params_id() {
                        s.params.push(r);
                    } else if r.frame.id() == params_auth {
                        s.params_auth.push(r);
                    }
                }
            })
        };
        // The daemon opens its end of the bus once it runs: let it; a frame
        // starts its bus clock, and two page cycles show CMD_SEQ.
        tokio::time::sleep(Duration::from_millis(500)).await;
        let b = Self {
            daemon,
            tx,
            seen,
            listener,
            config: Arc::clone(config),
        };
        b.send(&[CanFrame::new_data(FrameId::Standard(0x100), &[0; 8]).unwrap()])
            .await;
        tokio::time::sleep(Duration::from_secs(12)).await;
        b
    }

    /// The bus clock now, ms since the Unix epoch.
    fn now_ms(&self) -> u64 {
        self.daemon.bus.now().as_micros() / 1000
    }

    async fn send(&self, frames: &[CanFrame]) {
        for f in frames {
            self.tx.send(f).await.unwrap();
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
    }

    /// Commands answered so far: CMD_SEQ (modulo 8) counted up over every
    /// page 1 seen (each answer sends one at once).
    fn answered(&self) -> u64 {
        let s = self.seen.lock().unwrap();
        let mut n = 0u64;
        for w in s.cmd_seq.windows(2) {
            n += u64::from(w[1].wrapping_sub(w[0]) & 7);
        }
        n + u64::from(s.cmd_seq.first().copied().unwrap_or(0))
    }

    /// Stops the daemon; every CALIB_PARAMS page it sent was followed by
    /// an authenticator that the parameter store's key verifies.
    async fn stop(self) {
        self.daemon.stop().await.unwrap();
        self.listener.abort();
        let s = self.seen.lock().unwrap();
        let verifier = Authenticator::new(&role_key(Role::CalibParams));
        let params_id = OwnFrame::CalibParams.id(self.config.output.base_id);
        assert_eq!(s.params.len(), s.params_auth.len());
        for (p, a) in s.params.iter().zip(&s.params_auth) {
            let (pd, ad): ([u8; 8], [u8; 8]) = (
                p.frame.data().try_into().unwrap(),
                a.frame.data().try_into().unwrap(),
            );
            assert!(verifier.verify(params_id, &pd, &ad, a.timestamp.as_micros() / 1000));
        }
    }
}

/// The operator's signer (command key only), as `canodom calib` signs.
fn operator_signer(dir: &Path, config: &Config) -> Signer {
    Signer::new(
        &role_key(Role::CalibCmd),
        &dir.join("test-operator-freshness"),
        OwnFrame::CalibCmdAuth.id(config.output.base_id),
        None,
    )
    .unwrap()
}

/// A CALIB_CMD and its authenticator signed at `now_ms`.
fn signed_command(
    signer: &mut Signer,
    config: &Config,
    cmd: Command,
    counter: u8,
    now_ms: u64,
) -> [CanFrame; 2] {
    let wire = CalibWire::new(config.output.base_id).unwrap();
    let data = wire.encode_command(cmd, 0, counter);
    let id = config.calibration.command_id;
    [
        CanFrame::new_data(id, &data).unwrap(),
        signer.sign(id, &data, now_ms).unwrap(),
    ]
}

#[tokio::test(start_paused = true)]
async fn auth_commands_signed_by_canodom_calib_are_accepted_and_replays_and_forgeries_are_not() {
    let dir = tmp_dir("auth-daemon");
    // The printed lines are signed on the wall clock and the steps below
    // take 72 s of the daemon's (virtual) clock: a window that holds them.
    let (path, operator) = configs(&dir, "freshness_window_s = 300\n");
    let config = Arc::new(Config::load(&path).unwrap());
    let signed = printed_frames(&operator, "params");
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
    let next = printed_frames(&operator, "abort");
    let bench = Bench::start(&config).await;
    let mut answers = vec![bench.answered()];
    for frames in [&signed, &signed, &rolled, &plain, &next] {
        bench.send(frames).await;
        tokio::time::sleep(Duration::from_secs(12)).await;
        answers.push(bench.answered());
    }
    let params_sent = !bench.seen.lock().unwrap().params.is_empty();
    bench.stop().await;
    assert_eq!(
        answers,
        [0, 1, 1, 1, 1, 2],
        "signed, replay, rolled, plain, next"
    );
    assert!(params_sent, "REQUEST_PARAMS sends CALIB_PARAMS");
    // A restart: the recording of the first command is refused after it.
    let bench = Bench::start(&config).await;
    bench.send(&signed).await;
    bench.send(&rolled).await;
    tokio::time::sleep(Duration::from_secs(12)).await;
    assert_eq!(bench.answered(), 0, "replayed after a restart");
    bench.stop().await;
}

#[tokio::test(start_paused = true)]
async fn auth_a_command_kept_back_by_an_interleaved_plain_frame_is_not_accepted_an_hour_later() {
    let dir = tmp_dir("auth-interleave");
    let (path, _) = configs(&dir, "");
    let config = Arc::new(Config::load(&path).unwrap());
    let mut op = operator_signer(&dir, &config);
    let wire = CalibWire::new(config.output.base_id).unwrap();
    let bench = Bench::start(&config).await;
    // The attacker slips a plain frame in between a command and its
    // authenticator: the command is still carried out.
    let [cmd, auth] = signed_command(&mut op, &config, Command::Abort, 1, bench.now_ms());
    let slipped =
        CanFrame::new_data(cmd.id(), &wire.encode_command(Command::Commit, 0, 2)).unwrap();
    bench.send(&[cmd, slipped, auth]).await;
    tokio::time::sleep(Duration::from_secs(12)).await;
    assert_eq!(
        bench.answered(),
        1,
        "the command went through the interleaving"
    );
    // A command whose authenticator the attacker kept from the daemon (an
    // error frame over it, say), replayed whole an hour later.
    let [kept, kept_auth] = signed_command(&mut op, &config, Command::Commit, 3, bench.now_ms());
    bench.send(&[kept, slipped]).await;
    tokio::time::sleep(Duration::from_secs(3600)).await;
    bench.send(&[kept, kept_auth]).await;
    tokio::time::sleep(Duration::from_secs(12)).await;
    assert_eq!(
        bench.answered(),
        1,
        "the kept-back command was refused as stale"
    );
    // The operator's next command still passes.
    let [next, next_auth] = signed_command(&mut op, &config, Command::Abort, 4, bench.now_ms());
    bench.send(&[next, next_auth]).await;
    tokio::time::sleep(Duration::from_secs(12)).await;
    assert_eq!(bench.answered(), 2);
    bench.stop().await;
}

#[tokio::test(start_paused = true)]
async fn auth_junk_authenticators_at_0_2_per_second_for_30_minutes_keep_no_valid_command_out() {
    let dir = tmp_dir("auth-junk");
    let (path, _) = configs(&dir, "");
    let config = Arc::new(Config::load(&path).unwrap());
    let mut op = operator_signer(&dir, &config);
    let aid = OwnFrame::CalibCmdAuth.id(config.output.base_id);
    let bench = Bench::start(&config).await;
    let mut seed = 0x5EC0_C0DEu64;
    let mut junk = |now_ms: u64| {
        seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        let mut a = [0u8; 8];
        a[..4].copy_from_slice(&(now_ms as u32).to_le_bytes());
        a[4..].copy_from_slice(&((seed >> 32) as u32).to_le_bytes());
        CanFrame::new_data(aid, &a).unwrap()
    };
    // 30 simulated minutes: a valid command every 5 s; a junk authenticator
    // every 5 s (0.2 frames/s), every other one slipped in between a
    // command and its own authenticator, the others 2.5 s after it.
    let start = bench.answered();
    for k in 0..360u32 {
        let [cmd, auth] = signed_command(
            &mut op,
            &config,
            Command::Abort,
            (k % 15 + 1) as u8,
            bench.now_ms(),
        );
        if k % 2 == 1 {
            let j = junk(bench.now_ms());
            bench.send(&[cmd, j, auth]).await;
            tokio::time::sleep(Duration::from_millis(4_997)).await;
        } else {
            bench.send(&[cmd, auth]).await;
            tokio::time::sleep(Duration::from_millis(2_500)).await;
            let j = junk(bench.now_ms());
            bench.send(&[j]).await;
            tokio::time::sleep(Duration::from_millis(2_497)).await;
        }
    }
    tokio::time::sleep(Duration::from_secs(12)).await;
    let accepted = bench.answered() - start;
    eprintln!("junk at 0.2/s for 30 min: {accepted} of 360 valid commands answered");
    assert_eq!(accepted, 360);
    assert!(
        !bench.seen.lock().unwrap().auth_lockout.contains(&true),
        "AUTH_LOCKOUT is never set"
    );
    bench.stop().await;
}

#[tokio::test(start_paused = true)]
async fn auth_guessed_macs_lock_calib_cmd_out_for_a_while_and_the_bus_is_not_told() {
    let dir = tmp_dir("auth-lockout");
    let (path, _) = configs(
        &dir,
        "lockout_failures = 3\nlockout_window_s = 5\nlockout_s = 30\n",
    );
    let config = Arc::new(Config::load(&path).unwrap());
    let base = config.output.base_id;
    let wire = CalibWire::new(base).unwrap();
    let mut op = operator_signer(&dir, &config);
    let bench = Bench::start(&config).await;
    // Three guessed MACs within the window.
    let cmd = wire.encode_command(Command::Commit, 0, 3);
    for k in 0..3u8 {
        let now = bench.now_ms() as u32;
        let mut guess = [0, 0, 0, 0, k, 0x5A, 0xA5, k];
        guess[..4].copy_from_slice(&now.to_le_bytes());
        bench
            .send(&[
                CanFrame::new_data(config.calibration.command_id, &cmd).unwrap(),
                CanFrame::new_data(OwnFrame::CalibCmdAuth.id(base), &guess).unwrap(),
            ])
            .await;
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    // A correctly signed command during the lockout is refused unseen ...
    let signed = signed_command(&mut op, &config, Command::Abort, 4, bench.now_ms());
    bench.send(&signed).await;
    tokio::time::sleep(Duration::from_secs(12)).await;
    assert_eq!(bench.answered(), 0, "nothing answered during the lockout");
    // ... and one after it is carried out.
    tokio::time::sleep(Duration::from_secs(20)).await;
    let signed = signed_command(&mut op, &config, Command::Abort, 5, bench.now_ms());
    bench.send(&signed).await;
    tokio::time::sleep(Duration::from_secs(12)).await;
    assert_eq!(bench.answered(), 1, "answered after the lockout");
    let lockout = bench.seen.lock().unwrap().auth_lockout.clone();
    assert!(
        !lockout.is_empty() && !lockout.contains(&true),
        "AUTH_LOCKOUT tells no one"
    );
    bench.stop().await;
}

#[tokio::test(start_paused = true)]
async fn auth_a_deleted_freshness_file_then_a_two_year_old_recording_is_not_carried_out() {
    let dir = tmp_dir("auth-old-recording");
    let (path, _) = configs(&dir, "");
    let config = Arc::new(Config::load(&path).unwrap());
    let mut op = operator_signer(&dir, &config);
    let two_years_ms = 2 * 365 * 86_400_000;
    let then = InProcessBus::new("x", 1).now().as_micros() / 1000 - two_years_ms;
    let recording: Vec<[CanFrame; 2]> = (0..5u8)
        .map(|k| {
            signed_command(
                &mut op,
                &config,
                Command::Abort,
                k + 1,
                then + u64::from(k) * 5_000,
            )
        })
        .collect();
    let _ = std::fs::remove_file(&config.security.freshness_file);
    let bench = Bench::start(&config).await;
    for frames in &recording {
        bench.send(frames).await;
        tokio::time::sleep(Duration::from_secs(5)).await;
    }
    tokio::time::sleep(Duration::from_secs(12)).await;
    assert_eq!(bench.answered(), 0, "none of the 5 old frames was accepted");
    let fresh = signed_command(&mut op, &config, Command::Abort, 7, bench.now_ms());
    bench.send(&fresh).await;
    tokio::time::sleep(Duration::from_secs(12)).await;
    assert_eq!(bench.answered(), 1);
    bench.stop().await;
}

#[allow(clippy::too_many_lines)]
#[tokio::test(start_paused = true)]
async fn auth_only_the_parameter_stores_signed_ack_of_the_set_ends_the_write_back() {
    use canodom_params::persist::{ParamFile, ParamValues, store};
    let dir = tmp_dir("auth-ack");
    let (path, _) = configs(&dir, "");
    // A statistics line every half second: each takes the gate's figures
    // while the gate is in use (a second lock in the line once hung the daemon).
    let text = std::fs::read_to_string(&path).unwrap();
    std::fs::write(
        &path,
        text.replace("stats_interval_s = 10.0", "stats_interval_s = 0.5"),
    )
    .unwrap();
    let _log = tracing::subscriber::set_default(
        tracing_subscriber::fmt()
            .with_writer(std::io::sink)
            .finish(),
    );
    // Two committed sets: ROLLBACK writes set 1's values back (as version 3).
    let values = |tread_m| ParamValues {
        steering_gain: 1f64.to_radians(),
        ..ParamValues::plain(tread_m, 0.09)
    };
    let mut file = ParamFile::default();
    file.commit(values(0.30), "exact", 1, 10);
    file.commit(values(0.31), "exact", 2, 10);
    store(&dir.join("params.toml"), &file).unwrap();
    let config = Arc::new(Config::load(&path).unwrap());
    let wire = CalibWire::new(config.output.base_id).unwrap();
    let mut op = operator_signer(&dir, &config);
    let bench = Bench::start(&config).await;
    let rollback = signed_command(&mut op, &config, Command::Rollback, 1, bench.now_ms());
    bench.send(&rollback).await;
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(
        bench.seen.lock().unwrap().writeback.last(),
        Some(&Writeback::Pending),
        "the signed rollback started the write-back"
    );
    // What the parameter store received.
    let mut asm = ParamsAssembler::default();
    let set = bench
        .seen
        .lock()
        .unwrap()
        .params
        .iter()
        .filter_map(|r| asm.push(&wire, wire.decode_params(r.frame.data()).ok()?.0))
        .last()
        .expect("a whole set")
        .expect("its SET_CRC matches");
    assert_eq!(set.version, 3, "a rollback writes back under a new version");
    let ack_of = |version, set_crc| {
        wire.encode_ack(
            Ack {
                version,
                status: AckStatus::Stored,
                set_crc,
            },
            0,
        )
    };
    let crc = wire.set_crc(&set).unwrap();
    let ack = ack_of(set.version, crc);
    let ack_frame = CanFrame::new_data(wire.ack_id(), &ack).unwrap();
    let ack_auth_id = OwnFrame::CalibAckAuth.id(config.output.base_id);
    let auth_frame = |key: &Key, data: &[u8; 8], now_ms| {
        CanFrame::new_data(
            ack_auth_id,
            &Authenticator::new(key).sign(wire.ack_id(), data, now_ms),
        )
        .unwrap()
    };
    // Forged with another key; unsigned; signed with the operator's command
    // key; the store's key on an ACK of the same version for another set.
    let other = Key::parse("00112233445566778899aabbccddeeff").unwrap();
    let wrong_set = ack_of(set.version, crc ^ 0x0101);
    let attempts = [
        vec![ack_frame, auth_frame(&other, &ack, bench.now_ms())],
        vec![ack_frame],
        vec![
            ack_frame,
            auth_frame(&role_key(Role::CalibCmd), &ack, bench.now_ms()),
        ],
        vec![
            CanFrame::new_data(wire.ack_id(), &wrong_set).unwrap(),
            auth_frame(&role_key(Role::CalibAck), &wrong_set, bench.now_ms()),
        ],
    ];
    for frames in &attempts {
        bench.send(frames).await;
        tokio::time::sleep(Duration::from_millis(150)).await;
    }
    let before = bench.seen.lock().unwrap().writeback.clone();
    assert!(
        !before.contains(&Writeback::Acked),
        "a forged, unsigned, operator-signed or other-set CALIB_ACK counted: {before:?}"
    );
    assert_eq!(before.last(), Some(&Writeback::Pending));
    // The parameter store's own signed ACK of this set ends the write-back.
    bench
        .send(&[
            ack_frame,
            auth_frame(&role_key(Role::CalibAck), &ack, bench.now_ms()),
        ])
        .await;
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(
        bench.seen.lock().unwrap().writeback.last(),
        Some(&Writeback::Acked)
    );
    bench.stop().await;
}

#[test]
fn auth_keys_derive_writes_each_partys_file_0600_and_never_overwrites() {
    use canodom_protocol::secoc_keys::KeySet;
    use std::os::unix::fs::MetadataExt as _;
    let dir = tmp_dir("keys-derive");
    let out = dir.join("keys");
    let _ = std::fs::remove_dir_all(&out);
    let master_path = dir.join("master.key");
    let _ = std::fs::remove_file(&master_path);
    std::fs::write(&master_path, format!("{MASTER_HEX}\n")).unwrap();
    std::fs::set_permissions(&master_path, std::fs::Permissions::from_mode(0o600)).unwrap();
    let derive = |extra: &[&str]| {
        let mut args = vec![
            "keys",
            "derive",
            "--master",
            master_path.to_str().unwrap(),
            "--vehicle",
            VEHICLE,
        ];
        args.extend_from_slice(extra);
        std::process::Command::new(env!("CARGO_BIN_EXE_canodom"))
            .args(&args)
            .output()
            .unwrap()
    };
    let o = derive(&["--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for party in Party::ALL {
        let path = out.join(format!("{}.keys", party.name()));
        assert_eq!(
            std::fs::metadata(&path).unwrap().mode() & 0o777,
            0o600,
            "{}",
            path.display()
        );
        let keys = KeySet::parse(&std::fs::read_to_string(&path).unwrap()).unwrap();
        assert_eq!((keys.party, keys.vehicle.as_str()), (party, VEHICLE));
        for role in Role::ALL {
            assert_eq!(
                keys.key(role).is_some(),
                party.roles().contains(&role),
                "{} {role:?}",
                party.name()
            );
            if let Some(k) = keys.key(role) {
                assert_eq!(k, &role_key(role));
            }
        }
    }
    // Again: refused, the files untouched.
    let before = std::fs::read(out.join("operator.keys")).unwrap();
    let o = derive(&["--out", out.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("never overwritten"));
    assert_eq!(std::fs::read(out.join("operator.keys")).unwrap(), before);
    // One party to stdout.
    let o = derive(&["--party", "operator"]);
    let text = String::from_utf8(o.stdout).unwrap();
    assert_eq!(text.as_bytes(), before.as_slice());
    // A master key others may read is refused, naming the file.
    std::fs::set_permissions(&master_path, std::fs::Permissions::from_mode(0o644)).unwrap();
    let o = derive(&["--party", "operator"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("master.key") && err.contains("0644"),
        "{err}"
    );
}
