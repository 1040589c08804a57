//! The daemon's SecOC end (issues #22, #33): [`SecurityGate`], the one
//! object the daemon asks about every received frame and hands every
//! calibration frame it sends, and [`Signer`], a sender's end (`canodom
//! calib`, parameter stores in tests). The profile is
//! [`canodom_protocol::secoc`]'s, the keys per role
//! [`canodom_protocol::secoc_keys`]'s; the configuration is
//! [`crate::security`]'s.

use crate::security::{SecurityConfig, data_id, receive_links};
use canodom_can::bus::Received;
use canodom_can::frame::{CanFrame, FrameId};
use canodom_params::freshness::FreshnessFile;
use canodom_protocol::calib_wire::CalibWire;
use canodom_protocol::own_dbc::{BaseId, OwnFrame};
use canodom_protocol::secoc::{
    AuthFailure, Authenticator, FailureCounts, Key, Link, Lockout, Receiver, SecuredId, Verdict,
    next_tx_freshness,
};
use canodom_protocol::secoc_keys::{KeySet, Role};
use std::path::Path;

/// Why the gate cannot start.
#[derive(Debug, thiserror::Error)]
pub enum GateError {
    /// The freshness file is unreadable or damaged.
    #[error("security.freshness_file: {0}")]
    Freshness(#[from] canodom_params::freshness::FreshnessError),
    /// The shipped DBC lacks a signal (protocol's tests prove it does not).
    #[error("canodom.dbc: {0}")]
    Dbc(#[from] canodom_protocol::calib_wire::WireError),
    /// The key file is another party's: the daemon needs all four keys.
    #[error(
        "security.key_file holds the keys of the {party} (vehicle {vehicle}), not canodom's: \
         give the daemon the `canodom` file of `canodom keys derive`"
    )]
    WrongParty {
        /// The party named in the file.
        party: &'static str,
        /// Its vehicle.
        vehicle: String,
    },
}

/// What to do with a received frame.
#[derive(Debug, Clone, PartialEq)]
pub enum Admit {
    /// Not a secured frame, or no key configured: handle it as it is.
    Pass,
    /// Authenticated: handle this frame (the secured frame alone) instead.
    Authentic(CanFrame),
    /// Held for its authenticator: nothing to do yet.
    Held,
    /// Refused: drop it. `log` is true for the first refusal of this reason
    /// since the last [`SecurityGate::new_period`] (the rest are counted only).
    Refused {
        /// Why.
        reason: AuthFailure,
        /// Whether to log it.
        log: bool,
        /// The receiver's last accepted freshness value of that id (ms), for
        /// the log line of a `Replayed` refusal.
        last_accepted: Option<u64>,
    },
}

/// The daemon's SecOC end: verifies what it receives with the command and
/// acknowledgement keys, signs the `CALIB_PARAMS` it sends with the
/// parameter key.
#[derive(Debug)]
pub struct SecurityGate {
    /// `None` without a key: everything passes, nothing is signed.
    keyed: Option<Keyed>,
    logged: [bool; AuthFailure::ALL.len()],
}

#[derive(Debug)]
struct Keyed {
    receiver: Receiver,
    store: FreshnessFile,
    signer: Authenticator,
    wire: CalibWire,
    /// The secured ids received and their authenticators (kernel filters).
    links: [Link; 3],
    params_auth_id: FrameId,
    /// The last freshness value sent on `CALIB_PARAMS`, ms.
    tx_last: Option<u64>,
    /// `CALIB_PARAMS` pages not sent because their freshness value could
    /// not be stored (never sent unsigned).
    unsent: u64,
}

/// Values reserved ahead for sending: one store write per this many ms of
/// freshness (a set's four pages take four).
const TX_RESERVE_MS: u64 = 64;

/// The role of each link of [`receive_links`], in its order.
const RECEIVE_ROLES: [Role; 3] = [Role::OdomCmd, Role::CalibCmd, Role::CalibAck];

impl SecurityGate {
    /// The gate of a validated configuration (its `[security]`, base id
    /// and `CALIB_CMD` id).
    ///
    /// # Errors
    /// [`GateError`] when the freshness file is unreadable or damaged, or
    /// the key file is not canodom's.
    pub fn for_config(config: &crate::config::Config) -> Result<Self, GateError> {
        Self::new(
            &config.security,
            config.output.base_id,
            config.calibration.command_id,
        )
    }

    /// The gate of `[security]` for frames at `base` and `CALIB_CMD` at
    /// `calib_cmd_id`; loads the freshness file.
    ///
    /// # Errors
    /// [`GateError`] when the freshness file is unreadable or damaged, or
    /// the key file is not canodom's.
    pub fn new(
        security: &SecurityConfig,
        base: BaseId,
        calib_cmd_id: FrameId,
    ) -> Result<Self, GateError> {
        let logged = [false; AuthFailure::ALL.len()];
        let Some(keys) = &security.keys else {
            return Ok(Self {
                keyed: None,
                logged,
            });
        };
        let key = |role: Role| -> Result<&Key, GateError> {
            keys.key(role).ok_or_else(|| GateError::WrongParty {
                party: keys.party.name(),
                vehicle: keys.vehicle.clone(),
            })
        };
        let params_key = key(Role::CalibParams)?;
        let store = FreshnessFile::load(&security.freshness_file)?;
        let links = receive_links(base, calib_cmd_id);
        let mut ids = Vec::with_capacity(links.len());
        for (link, role) in links.into_iter().zip(RECEIVE_ROLES) {
            ids.push(SecuredId {
                link,
                key: key(role)?.clone(),
                last_accepted: store.rx(data_id(link.secured)),
                // The parameter store's acknowledgement is never locked
                // out: junk on the bus must not fail a write-back.
                lockable: role != Role::CalibAck,
            });
        }
        let lockout = Lockout::new(
            security.lockout_failures,
            security.lockout_window.as_micros() as u64,
            security.lockout.as_micros() as u64,
        );
        let params_id = OwnFrame::CalibParams.id(base);
        let wire = CalibWire::new(base)?;
        Ok(Self {
            keyed: Some(Keyed {
                receiver: Receiver::new(
                    &ids,
                    &lockout,
                    security.freshness_window.as_millis() as u64,
                ),
                tx_last: store.tx(data_id(params_id)),
                store,
                signer: Authenticator::new(params_key),
                wire,
                links,
                params_auth_id: OwnFrame::CalibParamsAuth.id(base),
                unsent: 0,
            }),
            logged,
        })
    }

    /// Whether a key is configured.
    pub fn is_keyed(&self) -> bool {
        self.keyed.is_some()
    }

    /// The authenticator ids to receive (for kernel filters); none without a key.
    pub fn receive_ids(&self) -> Vec<FrameId> {
        self.keyed
            .iter()
            .flat_map(|k| k.links.iter().map(|l| l.authenticator))
            .collect()
    }

    /// Judges a received frame (see [`Admit`]); its timestamp (µs since the
    /// Unix epoch: the kernel's receive time) is the receiver's clock.
    pub fn admit(&mut self, r: &Received) -> Admit {
        let Some(k) = &mut self.keyed else {
            return Admit::Pass;
        };
        let now_us = r.timestamp.as_micros();
        let Keyed {
            receiver, store, ..
        } = k;
        let verdict = receiver.on_frame(now_us, r.frame.id(), r.frame.data(), |id, fv| {
            store.record_rx(data_id(id), fv)
        });
        match verdict {
            Verdict::NotSecured => Admit::Pass,
            Verdict::Held => Admit::Held,
            Verdict::Accepted { id, payload, .. } => match CanFrame::new_data(id, &payload) {
                Ok(f) => Admit::Authentic(f),
                Err(_) => Admit::Held,
            },
            Verdict::Refused(reason) => Admit::Refused {
                reason,
                log: !std::mem::replace(&mut self.logged[reason.index()], true),
                last_accepted: receiver.last_accepted(r.frame.id()),
            },
        }
    }

    /// The frames to send for `frame` at `now_ms` (the bus clock, ms since
    /// the Unix epoch): a `CALIB_PARAMS` page followed by its authenticator,
    /// signed with a freshness value stored first — or nothing at all when
    /// it cannot be stored (a page is never sent unsigned; the write-back
    /// retries and ends FAILED); anything else as it is. `CALIB_STATUS`
    /// carries no lockout hint: its `AUTH_LOCKOUT` bit stays 0.
    pub fn outgoing(&mut self, frame: &CanFrame, now_ms: u64) -> Vec<CanFrame> {
        let Some(k) = &mut self.keyed else {
            return vec![*frame];
        };
        if frame.id() != k.wire.params_id() {
            return vec![*frame];
        }
        let Ok(payload) = <[u8; 8]>::try_from(frame.data()) else {
            k.unsent += 1;
            return Vec::new();
        };
        let fv = next_tx_freshness(k.tx_last, now_ms);
        let id = data_id(frame.id());
        if k.store.tx(id).is_none_or(|reserved| fv > reserved)
            && k.store
                .reserve_tx(id, fv.saturating_add(TX_RESERVE_MS))
                .is_err()
        {
            k.unsent += 1;
            return Vec::new();
        }
        k.tx_last = Some(fv);
        let auth = k.signer.sign(frame.id(), &payload, fv);
        #[allow(clippy::single_match_else)]
        match CanFrame::new_data(k.params_auth_id, &auth) {
            Ok(a) => vec![*frame, a],
            Err(_) => {
                k.unsent += 1;
                Vec::new()
            }
        }
    }

    /// Refusals so far, by reason (all zero without a key).
    pub fn counts(&self) -> FailureCounts {
        self.keyed
            .as_ref()
            .map(|k| k.receiver.counts())
            .unwrap_or_default()
    }

    /// Lockouts started since start (all ids together).
    pub fn lockouts(&self) -> u64 {
        self.keyed.as_ref().map_or(0, |k| k.receiver.lockouts())
    }

    /// `CALIB_PARAMS` pages not sent because their freshness value could
    /// not be stored.
    pub fn unsent_params(&self) -> u64 {
        self.keyed.as_ref().map_or(0, |k| k.unsent)
    }

    /// Refuses as `missing_authenticator` every secured frame that waited
    /// longer than the pairing timeout at `now_us` (µs since the Unix
    /// epoch): without a later frame to trigger it, the last one would
    /// otherwise never be counted.
    pub fn expire(&mut self, now_us: u64) {
        if let Some(k) = self.keyed.as_mut() {
            k.receiver.expire(now_us);
        }
    }

    /// A statistics line was written: each reason may be logged again.
    pub fn new_period(&mut self) {
        self.logged = [false; AuthFailure::ALL.len()];
    }
}

/// A sender's freshness: the next value for `secured` at `now_ms`,
/// reserved in `store` before it is returned (the caller sends it or loses
/// it, never reuses it); `floor` continues above a receiver's mark.
///
/// # Errors
/// The store could not be written.
pub fn operator_next_freshness(
    store: &mut FreshnessFile,
    secured: FrameId,
    now_ms: u64,
    floor: Option<u64>,
) -> Result<u64, canodom_params::freshness::FreshnessError> {
    let id = data_id(secured);
    let last = match (store.tx(id), floor) {
        (Some(a), Some(b)) => Some(a.max(b)),
        (a, b) => a.or(b),
    };
    let fv = next_tx_freshness(last, now_ms);
    store.reserve_tx(id, fv)?;
    Ok(fv)
}

/// A sender's end for one authenticator id: signs each secured frame with
/// the next freshness value, reserved in its store first (`canodom calib`
/// with the operator's command key, test parameter stores with theirs).
#[derive(Debug)]
pub struct Signer {
    auth: Authenticator,
    store: FreshnessFile,
    authenticator_id: FrameId,
    /// The receiver's mark a resynchronising sender must continue above.
    floor: Option<u64>,
}

impl Signer {
    /// A signer with `key` whose counter lives in `freshness_file`, sending
    /// authenticators on `authenticator_id`; `floor` continues above a
    /// receiver's mark (see [`canodom_protocol::secoc`]).
    ///
    /// # Errors
    /// The freshness file is unreadable or damaged.
    pub fn new(
        key: &Key,
        freshness_file: &Path,
        authenticator_id: FrameId,
        floor: Option<u64>,
    ) -> Result<Self, canodom_params::freshness::FreshnessError> {
        if let Some(dir) = freshness_file
            .parent()
            .filter(|d| !d.as_os_str().is_empty())
        {
            // A missing folder shows as the store's own write error below.
            let _ = std::fs::create_dir_all(dir);
        }
        Ok(Self {
            auth: Authenticator::new(key),
            store: FreshnessFile::load(freshness_file)?,
            authenticator_id,
            floor,
        })
    }

    /// The signer of `role` from a key set, if the set holds its key.
    ///
    /// # Errors
    /// As [`Self::new`].
    pub fn for_role(
        keys: &KeySet,
        role: Role,
        freshness_file: &Path,
        authenticator_id: FrameId,
    ) -> Result<Option<Self>, canodom_params::freshness::FreshnessError> {
        keys.key(role)
            .map(|k| Self::new(k, freshness_file, authenticator_id, None))
            .transpose()
    }

    /// The authenticator frame of `data` sent at `secured` at `now_ms`
    /// (the sender's clock, ms since the Unix epoch), its freshness value
    /// stored before it is returned.
    ///
    /// # Errors
    /// The freshness value could not be stored (then nothing may be sent).
    pub fn sign(
        &mut self,
        secured: FrameId,
        data: &[u8; 8],
        now_ms: u64,
    ) -> Result<CanFrame, canodom_params::freshness::FreshnessError> {
        let fv = operator_next_freshness(&mut self.store, secured, now_ms, self.floor)?;
        let auth = self.auth.sign(secured, data, fv);
        CanFrame::new_data(self.authenticator_id, &auth).map_err(|e| {
            canodom_params::freshness::FreshnessError::Read {
                path: self.store.path().to_owned(),
                source: std::io::Error::other(e.to_string()),
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Config, ConfigError};
    use crate::security::DEFAULT_FRESHNESS_FILE;
    use canodom_can::time::Timestamp;
    use canodom_protocol::calib_wire::{Ack, AckStatus, Command};
    use canodom_protocol::secoc_keys::{MasterKey, Party};
    use std::os::unix::fs::{OpenOptionsExt as _, PermissionsExt as _};
    use std::path::PathBuf;

    const MASTER_HEX: &str = "000102030405060708090a0b0c0d0e0f";
    const VEHICLE: &str = "rc-car-7";

    /// 2025-11-24 16:00 UTC, µs: the bus clock of these tests.
    const T0_US: u64 = 1_764_000_000_000_000;
    const T0_MS: u64 = T0_US / 1000;

    fn master() -> MasterKey {
        MasterKey::parse(MASTER_HEX).unwrap()
    }

    fn keys(party: Party) -> KeySet {
        KeySet::parse(&master().key_file(VEHICLE, party).unwrap()).unwrap()
    }

    fn role_key(role: Role) -> Key {
        master().derive(VEHICLE, role)
    }

    /// A scratch folder holding the rc_car DBC's config, a key file of
    /// `mode` with `key_text` and `[security]` lines `extra`.
    fn setup(tag: &str, mode: u32, key_text: &str, extra: &str) -> (PathBuf, String) {
        let dir = std::env::temp_dir().join(format!("canodom-sec-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let key = dir.join("canodom.keys");
        std::fs::write(&key, key_text).unwrap();
        std::fs::set_permissions(&key, std::fs::Permissions::from_mode(mode)).unwrap();
        let dbc = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/dbc/rc_car.dbc");
        let text = crate::config::tests::RC_CAR
            .replace("dbc = \"rc_car.dbc\"", &format!("dbc = {dbc:?}"))
            + &format!(
                "\n[calibration]\nparam_file = \"params.toml\"\n\n[security]\nkey_file = \"canodom.keys\"\n\
                 operator_freshness_file = \"operator-freshness\"\n{extra}"
            );
        (dir, text)
    }

    fn daemon_keys() -> String {
        master()
            .key_file(VEHICLE, Party::Canodom)
            .unwrap()
            .to_string()
    }

    fn load(dir: &Path, text: &str) -> Result<Config, ConfigError> {
        Config::from_toml(text, &dir.join("car.toml"))
    }

    #[test]
    fn auth_key_file_is_refused_when_others_may_read_it_it_is_a_link_or_malformed() {
        let good = daemon_keys();
        for (tag, mode, text, needle) in [
            ("g", 0o640, good.as_str(), "mode 0640"),
            ("o", 0o604, good.as_str(), "mode 0604"),
            ("w", 0o620, good.as_str(), "chmod 600"),
            (
                "short",
                0o600,
                "vehicle a\nparty canodom\nodom_cmd 0102\n",
                "line 3",
            ),
            ("junk", 0o600, "not a key at all", "line 1"),
            (
                "single",
                0o600,
                "2b7e151628aed2a6abf7158809cf4f3c\n",
                "canodom keys derive",
            ),
        ] {
            let (dir, cfg) = setup(&format!("key-{tag}"), mode, text, "");
            let e = load(&dir, &cfg).unwrap_err().to_string();
            assert!(e.contains("security.key_file"), "{tag}: {e}");
            assert!(e.contains("canodom.keys"), "{tag}: names the file: {e}");
            assert!(e.contains(needle), "{tag}: {e}");
            assert!(
                !e.contains("0102030405"),
                "{tag}: the key is never echoed: {e}"
            );
        }
        let (dir, cfg) = setup("key-missing", 0o600, &good, "");
        std::fs::remove_file(dir.join("canodom.keys")).unwrap();
        let e = load(&dir, &cfg).unwrap_err().to_string();
        assert!(e.contains("cannot read"), "{e}");
        // A symbolic link to a good key file is not followed.
        let (dir, cfg) = setup("key-link", 0o600, &good, "");
        std::fs::rename(dir.join("canodom.keys"), dir.join("real.keys")).unwrap();
        std::os::unix::fs::symlink(dir.join("real.keys"), dir.join("canodom.keys")).unwrap();
        let e = load(&dir, &cfg).unwrap_err().to_string();
        assert!(e.contains("symbolic link"), "{e}");
        let (dir, cfg) = setup("key-ok", 0o400, &good, "");
        let c = load(&dir, &cfg).unwrap();
        assert_eq!(c.security.keys.as_ref().unwrap().party, Party::Canodom);
        assert_eq!(c.security.freshness_file, dir.join(DEFAULT_FRESHNESS_FILE));
        assert_eq!(
            (
                c.security.lockout_failures,
                c.security.lockout.as_secs(),
                c.security.freshness_window.as_millis()
            ),
            (10, 60, 5_000)
        );
    }

    #[test]
    fn auth_a_key_file_in_a_linked_folder_is_refused() {
        // Issue #44: the file itself is real, a folder on its path is a link.
        let (dir, _) = setup("key-linked-dir", 0o600, &daemon_keys(), "");
        let real = dir.join("real");
        std::fs::create_dir_all(&real).unwrap();
        std::fs::rename(dir.join("canodom.keys"), real.join("canodom.keys")).unwrap();
        std::os::unix::fs::symlink(&real, dir.join("linked")).unwrap();
        let e = crate::security::read_key_file(&dir.join("linked/canodom.keys")).unwrap_err();
        assert!(matches!(e, crate::security::KeyFileError::Symlink), "{e}");
        assert!(crate::security::read_key_file(&real.join("canodom.keys")).is_ok());
    }

    #[test]
    fn auth_a_fifo_as_key_file_is_refused_at_once() {
        // Issue #44: opening a FIFO for reading blocks until a writer comes;
        // the start must be refused instead. Judged on a thread so that the
        // old behaviour fails the test rather than hanging it.
        let (dir, _) = setup("key-fifo", 0o600, &daemon_keys(), "");
        let fifo = dir.join("fifo.keys");
        nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::from_bits_truncate(0o600)).unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        let path = fifo.clone();
        std::thread::spawn(move || {
            let _ = tx.send(crate::security::read_key_file(&path).map(|_| ()));
        });
        let r = rx
            .recv_timeout(std::time::Duration::from_secs(10))
            .expect("reading a FIFO as key file must not block");
        assert!(
            matches!(r, Err(crate::security::KeyFileError::NotAFile)),
            "{r:?}"
        );
        // Let a thread still blocked on the old code go.
        let _ = std::fs::OpenOptions::new()
            .write(true)
            .custom_flags(libc::O_NONBLOCK)
            .open(&fifo);
    }

    #[test]
    fn auth_secure_defaults_a_security_section_needs_its_key_and_a_bench_says_so() {
        let (dir, cfg) = setup("keys", 0o600, &daemon_keys(), "lockout_failures = 0\n");
        assert!(
            load(&dir, &cfg)
                .unwrap_err()
                .to_string()
                .contains("lockout_failures")
        );
        let (dir, cfg) = setup("keys2", 0o600, &daemon_keys(), "freshness_window_s = 0\n");
        assert!(
            load(&dir, &cfg)
                .unwrap_err()
                .to_string()
                .contains("freshness_window_s")
        );
        let (dir, cfg) = setup(
            "keys3",
            0o600,
            &daemon_keys(),
            "lockout_s = 5\nlockout_failures = 3\nlockout_window_s = 2\nfreshness_window_s = 2.5\n",
        );
        let c = load(&dir, &cfg).unwrap();
        assert_eq!(
            (
                c.security.lockout_failures,
                c.security.lockout_window.as_secs(),
                c.security.lockout.as_secs(),
                c.security.freshness_window.as_millis()
            ),
            (3, 2, 5, 2_500)
        );
        // A [security] section without a key: refused, naming the bench switch.
        let no_key = cfg.replace("key_file = \"canodom.keys\"\n", "");
        let e = load(&dir, &no_key).unwrap_err().to_string();
        assert!(
            e.contains("security.key_file") && e.contains("allow_without_key = true"),
            "{e}"
        );
        // The bench says so explicitly.
        let bench = no_key.clone() + "allow_without_key = true\n";
        let c = load(&dir, &bench).unwrap();
        assert!(c.security.keys.is_none() && c.security.allow_without_key);
        // No section at all: loads (decode, replay need no key), but keyless
        // and not allowed to run without one (`canodom run` refuses).
        let none = crate::config::tests::RC_CAR.replace(
            "dbc = \"rc_car.dbc\"",
            &format!(
                "dbc = {:?}",
                concat!(env!("CARGO_MANIFEST_DIR"), "/../data/dbc/rc_car.dbc")
            ),
        );
        let c = load(&dir, &none).unwrap();
        assert!(c.security.keys.is_none() && !c.security.allow_without_key);
        let typo = cfg.replace("lockout_s", "lockout_sec");
        assert!(
            load(&dir, &typo)
                .unwrap_err()
                .to_string()
                .contains("lockout_sec")
        );
    }

    fn rx(t_us: u64, id: FrameId, data: &[u8]) -> Received {
        Received {
            timestamp: Timestamp::from_micros(t_us),
            frame: CanFrame::new_data(id, data).unwrap(),
        }
    }

    fn keyed(tag: &str, extra: &str) -> (PathBuf, Config) {
        let (dir, cfg) = setup(tag, 0o600, &daemon_keys(), extra);
        let c = load(&dir, &cfg).unwrap();
        (dir, c)
    }

    /// Operator side: a CALIB_CMD and its authenticator as `canodom calib`
    /// sends them, with the operator's own key file, at `now_ms`.
    fn operator_frames(
        c: &Config,
        store: &mut FreshnessFile,
        cmd: Command,
        counter: u8,
        now_ms: u64,
    ) -> [(FrameId, [u8; 8]); 2] {
        let wire = CalibWire::new(c.output.base_id).unwrap();
        let data = wire.encode_command(cmd, 0, counter);
        let id = c.calibration.command_id;
        let fv = operator_next_freshness(store, id, now_ms, None).unwrap();
        let op = keys(Party::Operator);
        let auth = Authenticator::new(op.key(Role::CalibCmd).unwrap()).sign(id, &data, fv);
        [
            (id, data),
            (OwnFrame::CalibCmdAuth.id(c.output.base_id), auth),
        ]
    }

    #[test]
    fn auth_a_signed_calib_command_is_accepted_and_replays_before_and_after_a_restart_are_not() {
        let (_dir, c) = keyed("gate", "");
        let mut gate = SecurityGate::for_config(&c).unwrap();
        let mut op = FreshnessFile::load(&c.security.operator_freshness_file).unwrap();
        let [(id, data), (aid, auth)] = operator_frames(&c, &mut op, Command::Commit, 1, T0_MS);
        assert_eq!(gate.admit(&rx(T0_US, id, &data)), Admit::Held);
        assert_eq!(
            gate.admit(&rx(T0_US + 300, aid, &auth)),
            Admit::Authentic(CanFrame::new_data(id, &data).unwrap())
        );
        // The operator's next command in the same millisecond is fresh too.
        let [(id2, data2), (aid2, auth2)] =
            operator_frames(&c, &mut op, Command::Rollback, 2, T0_MS);
        assert_eq!(gate.admit(&rx(T0_US + 1_000, id2, &data2)), Admit::Held);
        assert!(matches!(
            gate.admit(&rx(T0_US + 1_300, aid2, &auth2)),
            Admit::Authentic(_)
        ));
        // Replayed at once: refused, logged once, then only counted.
        assert_eq!(gate.admit(&rx(T0_US + 2_000, id, &data)), Admit::Held);
        assert!(matches!(
            gate.admit(&rx(T0_US + 2_300, aid, &auth)),
            Admit::Refused {
                reason: AuthFailure::Replayed,
                log: true,
                last_accepted: Some(_)
            }
        ));
        assert_eq!(gate.admit(&rx(T0_US + 3_000, id2, &data2)), Admit::Held);
        assert!(matches!(
            gate.admit(&rx(T0_US + 3_300, aid2, &auth2)),
            Admit::Refused {
                reason: AuthFailure::Replayed,
                log: false,
                ..
            }
        ));
        // A restart within the window: a new gate from the same files refuses both.
        drop(gate);
        let mut gate = SecurityGate::for_config(&c).unwrap();
        for (t, (i, d)) in [(id, data), (aid, auth), (id2, data2), (aid2, auth2)]
            .into_iter()
            .enumerate()
        {
            let v = gate.admit(&rx(T0_US + 10_000 + t as u64 * 10, i, &d));
            assert!(!matches!(v, Admit::Authentic(_)), "{v:?}");
        }
        assert_eq!(gate.counts().of(AuthFailure::Replayed), 2);
        assert_eq!(
            gate.admit(&rx(T0_US + 20_000, FrameId::Standard(0x100), &[0; 8])),
            Admit::Pass
        );
    }

    #[test]
    fn auth_a_deleted_freshness_file_then_a_two_year_old_recording_is_refused() {
        let (_dir, c) = keyed("deleted", "");
        let two_years_ms = 2 * 365 * 86_400_000;
        let mut op = FreshnessFile::load(&c.security.operator_freshness_file).unwrap();
        let recorded: Vec<_> = (0..5u8)
            .map(|k| {
                operator_frames(
                    &c,
                    &mut op,
                    Command::Abort,
                    k,
                    T0_MS - two_years_ms + u64::from(k),
                )
            })
            .collect();
        // The daemon accepted them two years ago; its freshness file is gone.
        let _ = std::fs::remove_file(&c.security.freshness_file);
        let mut gate = SecurityGate::for_config(&c).unwrap();
        for (k, [(id, data), (aid, auth)]) in recorded.iter().enumerate() {
            let t = T0_US + k as u64 * 1_000_000;
            assert_eq!(gate.admit(&rx(t, *id, data)), Admit::Held);
            assert!(
                matches!(
                    gate.admit(&rx(t + 100, *aid, auth)),
                    Admit::Refused {
                        reason: AuthFailure::Stale,
                        ..
                    }
                ),
                "recording {k} accepted"
            );
        }
        assert_eq!(gate.counts().of(AuthFailure::Stale), 5);
        assert!(!c.security.freshness_file.exists(), "nothing was accepted");
    }

    #[test]
    fn auth_operator_and_parameter_store_keys_sign_only_their_own_messages() {
        let (_dir, c) = keyed("roles", "");
        let base = c.output.base_id;
        let wire = CalibWire::new(base).unwrap();
        let mut gate = SecurityGate::for_config(&c).unwrap();
        let op = keys(Party::Operator);
        let store = keys(Party::ParamStore);
        // The operator's file holds no CALIB_PARAMS or CALIB_ACK key at all ...
        assert!(op.key(Role::CalibParams).is_none() && op.key(Role::CalibAck).is_none());
        // ... and what it signs with its command key as CALIB_PARAMS is
        // refused by the parameter store's verifier, as CALIB_ACK by the daemon.
        let set = canodom_protocol::calib_wire::ParamSet {
            version: 9,
            rear_tread_m: 0.5,
            rear_left_diameter_m: 0.09,
            rear_right_diameter_m: 0.09,
            diameter_ratio: 1.0,
            steer_gain: 1.0,
            steer_offset_rad: 0.0,
        };
        let page = wire.encode_params(&set, 0).unwrap()[0];
        let cmd_key = op.key(Role::CalibCmd).unwrap();
        let forged = Authenticator::new(cmd_key).sign(wire.params_id(), &page, T0_MS);
        let store_verifier = Authenticator::new(store.key(Role::CalibParams).unwrap());
        assert!(!store_verifier.verify(wire.params_id(), &page, &forged, T0_MS));
        let ack = wire.encode_ack(
            Ack {
                version: 9,
                status: AckStatus::Stored,
                set_crc: wire.set_crc(&set).unwrap(),
            },
            0,
        );
        let ack_auth = OwnFrame::CalibAckAuth.id(base);
        let by_operator = Authenticator::new(cmd_key).sign(wire.ack_id(), &ack, T0_MS);
        assert_eq!(gate.admit(&rx(T0_US, wire.ack_id(), &ack)), Admit::Held);
        assert!(matches!(
            gate.admit(&rx(T0_US + 100, ack_auth, &by_operator)),
            Admit::Refused {
                reason: AuthFailure::BadMac,
                ..
            }
        ));
        // The store's key signs the ACK the daemon accepts, but no command.
        let by_store = Authenticator::new(store.key(Role::CalibAck).unwrap()).sign(
            wire.ack_id(),
            &ack,
            T0_MS + 1,
        );
        assert_eq!(
            gate.admit(&rx(T0_US + 1_000, wire.ack_id(), &ack)),
            Admit::Held
        );
        assert!(matches!(
            gate.admit(&rx(T0_US + 1_100, ack_auth, &by_store)),
            Admit::Authentic(_)
        ));
        let cmd = wire.encode_command(Command::Commit, 0, 1);
        let store_cmd = Authenticator::new(store.key(Role::CalibAck).unwrap()).sign(
            c.calibration.command_id,
            &cmd,
            T0_MS + 2,
        );
        assert_eq!(
            gate.admit(&rx(T0_US + 2_000, c.calibration.command_id, &cmd)),
            Admit::Held
        );
        assert!(matches!(
            gate.admit(&rx(
                T0_US + 2_100,
                OwnFrame::CalibCmdAuth.id(base),
                &store_cmd
            )),
            Admit::Refused {
                reason: AuthFailure::BadMac,
                ..
            }
        ));
        // Another vehicle's daemon key (same master) signs nothing here.
        let other = master().derive("rc-car-8", Role::CalibCmd);
        let other_cmd = Authenticator::new(&other).sign(c.calibration.command_id, &cmd, T0_MS + 3);
        assert_eq!(
            gate.admit(&rx(T0_US + 3_000, c.calibration.command_id, &cmd)),
            Admit::Held
        );
        assert!(matches!(
            gate.admit(&rx(
                T0_US + 3_100,
                OwnFrame::CalibCmdAuth.id(base),
                &other_cmd
            )),
            Admit::Refused {
                reason: AuthFailure::BadMac,
                ..
            }
        ));
        // The daemon refuses to start on an operator's or a store's key file.
        for party in [Party::Operator, Party::ParamStore] {
            let mut sec = c.security.clone();
            sec.keys = Some(keys(party));
            let e = SecurityGate::new(&sec, base, c.calibration.command_id).unwrap_err();
            assert!(e.to_string().contains(party.name()), "{e}");
        }
    }

    #[test]
    fn auth_calib_params_are_signed_with_the_params_key_and_never_sent_unsigned() {
        let (dir, c) = keyed("tx", "lockout_failures = 2\n");
        let base = c.output.base_id;
        let mut gate = SecurityGate::for_config(&c).unwrap();
        let wire = CalibWire::new(base).unwrap();
        let set = canodom_protocol::calib_wire::ParamSet {
            version: 2,
            rear_tread_m: 0.3,
            rear_left_diameter_m: 0.09,
            rear_right_diameter_m: 0.0905,
            diameter_ratio: 0.0905 / 0.09,
            steer_gain: 1.0,
            steer_offset_rad: 0.0,
        };
        let verifier = Authenticator::new(&role_key(Role::CalibParams));
        let mut fvs = Vec::new();
        for page in wire.encode_params(&set, 0).unwrap() {
            let out = gate.outgoing(&CanFrame::new_data(wire.params_id(), &page).unwrap(), T0_MS);
            assert_eq!(out.len(), 2);
            assert_eq!(out[1].id(), OwnFrame::CalibParamsAuth.id(base));
            let auth: [u8; 8] = out[1].data().try_into().unwrap();
            assert!(verifier.verify(wire.params_id(), &page, &auth, T0_MS));
            fvs.push(canodom_protocol::secoc::reconstruct(
                canodom_protocol::secoc::split_auth(&auth).0,
                T0_MS,
            ));
        }
        assert_eq!(fvs, [T0_MS, T0_MS + 1, T0_MS + 2, T0_MS + 3]);
        // After a restart the daemon continues above what it reserved.
        let mut again = SecurityGate::for_config(&c).unwrap();
        let page = wire.encode_params(&set, 0).unwrap()[0];
        let out = again.outgoing(&CanFrame::new_data(wire.params_id(), &page).unwrap(), T0_MS);
        let low = canodom_protocol::secoc::split_auth(&out[1].data().try_into().unwrap()).0;
        assert!(canodom_protocol::secoc::reconstruct(low, T0_MS) > T0_MS + 3);
        // The freshness file cannot be written (its folder does not exist):
        // nothing is sent, not an unsigned page.
        let mut sec = c.security.clone();
        sec.freshness_file = dir.join("no-such-folder/canodom-freshness");
        let mut stuck = SecurityGate::new(&sec, base, c.calibration.command_id).unwrap();
        let out = stuck.outgoing(&CanFrame::new_data(wire.params_id(), &page).unwrap(), T0_MS);
        assert_eq!(out, Vec::<CanFrame>::new());
        assert_eq!(stuck.unsent_params(), 1);
        // CALIB_STATUS passes untouched: no lockout hint is stamped on it.
        let status = [0x10, 0, 0, 0, 0, 0, 0x30, 0x00];
        let f = CanFrame::new_data(wire.status_id(), &status).unwrap();
        assert_eq!(gate.outgoing(&f, T0_MS), vec![f]);
    }

    #[test]
    fn auth_junk_does_not_lock_out_and_calib_ack_is_never_locked_out() {
        let (_dir, c) = keyed(
            "lock",
            "lockout_failures = 3\nlockout_window_s = 5\nlockout_s = 30\n",
        );
        let base = c.output.base_id;
        let wire = CalibWire::new(base).unwrap();
        let mut gate = SecurityGate::for_config(&c).unwrap();
        let cmd_id = c.calibration.command_id;
        let cmd = wire.encode_command(Command::Abort, 0, 1);
        let aid = OwnFrame::CalibCmdAuth.id(base);
        // Junk that is no MAC guess: unpaired authenticators, short frames,
        // plain commands. None of it locks out.
        for k in 0..100u64 {
            let t = T0_US + k * 10_000;
            let _ = gate.admit(&rx(t, aid, &[0; 8]));
            let _ = gate.admit(&rx(t + 1, aid, &[0; 3]));
            let _ = gate.admit(&rx(t + 2, cmd_id, &cmd));
        }
        assert_eq!(gate.lockouts(), 0, "{}", gate.counts());
        // Three bad MACs on CALIB_CMD lock it; CALIB_ACK stays open.
        let t = T0_US + 2_000_000;
        // A guess carries a fresh freshness value: anything else is refused
        // as stale before a MAC is computed, and is no guess.
        let guess = |t_us: u64, k: u64| {
            let mut g = [0, 0, 0, 0, 5, 6, 7, k as u8];
            g[..4].copy_from_slice(&((t_us / 1000) as u32).to_le_bytes());
            g
        };
        for k in 0..3u64 {
            let _ = gate.admit(&rx(t + k * 1000, cmd_id, &cmd));
            let v = gate.admit(&rx(t + k * 1000 + 10, aid, &guess(t + k * 1000, k)));
            assert!(
                matches!(
                    v,
                    Admit::Refused {
                        reason: AuthFailure::BadMac | AuthFailure::LockedOut,
                        ..
                    }
                ),
                "{v:?}"
            );
        }
        assert_eq!(gate.lockouts(), 1);
        let ack = wire.encode_ack(
            Ack {
                version: 1,
                status: AckStatus::Stored,
                set_crc: 0x1234,
            },
            0,
        );
        let ack_aid = OwnFrame::CalibAckAuth.id(base);
        for k in 0..5u64 {
            let _ = gate.admit(&rx(t + 5_000 + k * 1000, wire.ack_id(), &ack));
            let _ = gate.admit(&rx(
                t + 5_010 + k * 1000,
                ack_aid,
                &guess(t + 5_010 + k * 1000, k),
            ));
        }
        assert_eq!(gate.lockouts(), 1, "CALIB_ACK bad MACs do not lock");
        let t2 = t + 20_000;
        let signed =
            Authenticator::new(&role_key(Role::CalibAck)).sign(wire.ack_id(), &ack, t2 / 1000);
        assert_eq!(gate.admit(&rx(t2, wire.ack_id(), &ack)), Admit::Held);
        assert!(matches!(
            gate.admit(&rx(t2 + 10, ack_aid, &signed)),
            Admit::Authentic(_)
        ));
        assert!(matches!(
            gate.admit(&rx(t2 + 20, cmd_id, &cmd)),
            Admit::Refused {
                reason: AuthFailure::LockedOut,
                ..
            }
        ));
    }

    #[test]
    fn auth_odom_cmd_is_secured_with_its_own_key() {
        let (_dir, c) = keyed("odom", "");
        let base = c.output.base_id;
        let mut gate = SecurityGate::for_config(&c).unwrap();
        let (id, aid) = (OwnFrame::OdomCmd.id(base), OwnFrame::OdomCmdAuth.id(base));
        let mut reset = [2, 0, 0, 0, 0, 0, 0x10, 0];
        let _ = canodom_dbc::Checksum::rc_car().apply(&mut reset);
        // Plain: held, then refused for its missing authenticator.
        assert_eq!(gate.admit(&rx(T0_US, id, &reset)), Admit::Held);
        let _ = gate.admit(&rx(T0_US + 200_000, FrameId::Standard(0x100), &[0; 8]));
        assert_eq!(gate.counts().of(AuthFailure::MissingAuthenticator), 1);
        // Signed with the CALIB_CMD key: refused; with the ODOM_CMD key: accepted.
        let for_calib = Authenticator::new(&role_key(Role::CalibCmd)).sign(id, &reset, T0_MS + 300);
        assert_eq!(gate.admit(&rx(T0_US + 300_000, id, &reset)), Admit::Held);
        assert!(matches!(
            gate.admit(&rx(T0_US + 300_010, aid, &for_calib)),
            Admit::Refused {
                reason: AuthFailure::BadMac,
                ..
            }
        ));
        let signed = Authenticator::new(&role_key(Role::OdomCmd)).sign(id, &reset, T0_MS + 400);
        assert_eq!(gate.admit(&rx(T0_US + 400_000, id, &reset)), Admit::Held);
        assert_eq!(
            gate.admit(&rx(T0_US + 400_010, aid, &signed)),
            Admit::Authentic(CanFrame::new_data(id, &reset).unwrap())
        );
    }

    #[test]
    fn auth_without_a_key_everything_passes_and_nothing_is_signed() {
        let (dir, cfg) = setup("nokey", 0o600, &daemon_keys(), "allow_without_key = true\n");
        let c = load(&dir, &cfg.replace("key_file = \"canodom.keys\"\n", "")).unwrap();
        let mut gate = SecurityGate::for_config(&c).unwrap();
        assert!(!gate.is_keyed());
        let f = CanFrame::new_data(c.calibration.command_id, &[0; 8]).unwrap();
        assert_eq!(gate.admit(&rx(0, f.id(), f.data())), Admit::Pass);
        assert_eq!(gate.outgoing(&f, 0), vec![f]);
        assert!(!c.security.freshness_file.exists());
    }
}
