//! The daemon's SecOC end (issues #22, #33, #44): [`SecurityGate`], the one
//! object the daemon asks about every received frame, hands every
//! calibration frame it sends, and asks for its announcements
//! (`SECOC_SYNC`); and [`Signer`], a sender's end (`canodom calib`,
//! parameter stores in tests), which learns the daemon's epoch and floor
//! from those announcements. The profile is [`canodom_protocol::secoc`]'s,
//! the keys per role [`canodom_protocol::secoc_keys`]'s; the configuration
//! is [`crate::security`]'s.

use crate::security::{SecurityConfig, data_id, receive_links, sync_link};
use canodom_can::frame::{CanFrame, FrameId};
use canodom_params::freshness::{FreshnessError, FreshnessFile};
use canodom_protocol::calib_wire::CalibWire;
use canodom_protocol::own_dbc::{BaseId, OwnFrame};
use canodom_protocol::secoc::{
    AuthFailure, Authenticator, FailureCounts, Key, Link, Receiver, SecuredId, Sync, Verdict,
    freshness, next_freshness,
};
use canodom_protocol::secoc_keys::{KeySet, Role};
use std::path::Path;

/// Why the gate cannot start.
#[derive(Debug, thiserror::Error)]
pub enum GateError {
    /// The freshness file is unreadable, damaged, or its new epoch cannot
    /// be stored.
    #[error("security.freshness_file: {0}")]
    Freshness(#[from] FreshnessError),
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
    /// No epoch stored and the operating system gave no random one.
    #[error("no random epoch from the operating system: {0}")]
    Random(String),
}

/// What to do with a received frame.
#[derive(Debug, Clone, PartialEq)]
pub enum Admit {
    /// Not a secured frame, or no key configured: handle it as it is.
    Pass,
    /// Authenticated: handle this frame (the secured frame alone) instead,
    /// and send [`SecurityGate::announce`]'s frames (the floor moved).
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
        /// The receiver's last accepted freshness value of that id, for
        /// the log line of a `Replayed` refusal.
        last_accepted: Option<u64>,
    },
}

/// The daemon's SecOC end: verifies what it receives with the command and
/// acknowledgement keys in its own epoch, signs the `CALIB_PARAMS` it sends
/// with the parameter key, and announces its epoch and floor.
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
    /// The announcement's signers: the operators' key, the parameter store's.
    sync_signers: [Authenticator; 2],
    sync: Link,
    wire: CalibWire,
    /// The secured ids received and their authenticators (kernel filters).
    links: [Link; 3],
    params_auth_id: FrameId,
    /// The last counter sent on `CALIB_PARAMS` in this epoch.
    tx_counter: u32,
    /// Epochs started since start (the first included).
    epochs: u64,
}

/// The role of each link of [`receive_links`], in its order.
const RECEIVE_ROLES: [Role; 3] = [Role::OdomCmd, Role::CalibCmd, Role::CalibAck];

/// The next epoch after `stored`, or a random one when none was stored (a
/// first start or a lost file: an earlier epoch comes back with chance
/// 2⁻³² per start). Never 0, so a zeroed file is no epoch.
///
/// # Errors
/// [`GateError::Random`] when the operating system has no random source.
pub fn next_epoch(stored: Option<u32>) -> Result<u32, GateError> {
    let e = match stored {
        Some(e) => e.wrapping_add(1),
        None => getrandom::u32().map_err(|e| GateError::Random(e.to_string()))?,
    };
    Ok(e.max(1))
}

/// Starts a new epoch: stored durably before it is used.
fn start_epoch(store: &mut FreshnessFile) -> Result<u32, GateError> {
    let epoch = next_epoch(store.epoch())?;
    store.store_epoch(epoch)?;
    Ok(epoch)
}

impl SecurityGate {
    /// The gate of a validated configuration (its `[security]`, base id
    /// and `CALIB_CMD` id).
    ///
    /// # Errors
    /// [`GateError`] when the freshness file is unreadable, damaged or its
    /// new epoch cannot be stored, or the key file is not canodom's.
    pub fn for_config(config: &crate::config::Config) -> Result<Self, GateError> {
        Self::new(
            &config.security,
            config.output.base_id,
            config.calibration.command_id,
        )
    }

    /// The gate of `[security]` for frames at `base` and `CALIB_CMD` at
    /// `calib_cmd_id`: loads the freshness file and starts a new epoch in
    /// it.
    ///
    /// # Errors
    /// As [`Self::for_config`].
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
        let mut store = FreshnessFile::load(&security.freshness_file)?;
        let links = receive_links(base, calib_cmd_id);
        let mut ids = Vec::with_capacity(links.len());
        for (link, role) in links.into_iter().zip(RECEIVE_ROLES) {
            ids.push(SecuredId {
                link,
                key: key(role)?.clone(),
            });
        }
        let epoch = start_epoch(&mut store)?;
        let wire = CalibWire::new(base)?;
        Ok(Self {
            keyed: Some(Keyed {
                receiver: Receiver::new(&ids, epoch, security.window_ticks()),
                store,
                signer: Authenticator::new(params_key),
                sync_signers: [
                    Authenticator::new(key(Role::CalibCmd)?),
                    Authenticator::new(params_key),
                ],
                sync: sync_link(base),
                wire,
                links,
                params_auth_id: OwnFrame::CalibParamsAuth.id(base),
                tx_counter: 0,
                epochs: 1,
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

    /// The current epoch (`None` without a key).
    pub fn epoch(&self) -> Option<u32> {
        self.keyed.as_ref().map(|k| k.receiver.epoch())
    }

    /// Judges a received frame (see [`Admit`]) at `mono_us`, µs on the
    /// daemon's monotonic clock (only the pairing timeout uses it; the
    /// frame's wall-clock timestamp is never used).
    pub fn admit(&mut self, frame: &CanFrame, mono_us: u64) -> Admit {
        let Some(k) = &mut self.keyed else {
            return Admit::Pass;
        };
        match k.receiver.on_frame(mono_us, frame.id(), frame.data()) {
            Verdict::NotSecured => Admit::Pass,
            Verdict::Held => Admit::Held,
            Verdict::Accepted { id, payload, .. } => match CanFrame::new_data(id, &payload) {
                Ok(f) => Admit::Authentic(f),
                Err(_) => Admit::Held,
            },
            Verdict::Refused(reason) => Admit::Refused {
                reason,
                log: !std::mem::replace(&mut self.logged[reason.index()], true),
                last_accepted: k.receiver.last_accepted(frame.id()),
            },
        }
    }

    /// The announcement frames now: `SECOC_SYNC` and its two
    /// authenticators (none without a key). `tick` once per
    /// [`canodom_protocol::secoc::SYNC_PERIOD_US`] of the monotonic clock
    /// moves the floor up (what ages a kept-back frame out); without it
    /// the current floor is announced (after an accepted frame). A counter
    /// space near its end starts a new epoch first.
    ///
    /// # Errors
    /// The new epoch could not be stored (the old one goes on).
    pub fn announce(&mut self, tick: bool) -> Result<Vec<CanFrame>, GateError> {
        let Some(k) = &mut self.keyed else {
            return Ok(Vec::new());
        };
        if k.receiver.exhausted() {
            let epoch = start_epoch(&mut k.store)?;
            k.receiver = Receiver::new_epoch(&k.receiver, epoch);
            k.tx_counter = 0;
            k.epochs += 1;
        }
        let sync = if tick {
            k.receiver.tick()
        } else {
            k.receiver.sync()
        };
        let mut out = Vec::with_capacity(3);
        if let Ok(f) = CanFrame::new_data(k.sync.secured, &sync.payload()) {
            out.push(f);
            for a in &k.sync_signers {
                if let Ok(f) =
                    CanFrame::new_data(k.sync.authenticator, &sync.sign(a, k.sync.secured))
                {
                    out.push(f);
                }
            }
        }
        Ok(out)
    }

    /// The frames to send for `frame`: a `CALIB_PARAMS` page followed by
    /// its authenticator, signed with the next counter of this epoch;
    /// anything else as it is. `CALIB_STATUS` carries no lockout hint: its
    /// `AUTH_LOCKOUT` bit stays 0.
    pub fn outgoing(&mut self, frame: &CanFrame) -> Vec<CanFrame> {
        let Some(k) = &mut self.keyed else {
            return vec![*frame];
        };
        if frame.id() != k.wire.params_id() {
            return vec![*frame];
        }
        let Ok(payload) = <[u8; 8]>::try_from(frame.data()) else {
            return Vec::new();
        };
        k.tx_counter = k.tx_counter.saturating_add(1);
        let fv = freshness(k.receiver.epoch(), k.tx_counter);
        let auth = k.signer.sign(frame.id(), &payload, fv);
        match CanFrame::new_data(k.params_auth_id, &auth) {
            Ok(a) => vec![*frame, a],
            Err(_) => Vec::new(),
        }
    }

    /// Refusals so far, by reason (all zero without a key).
    pub fn counts(&self) -> FailureCounts {
        self.keyed
            .as_ref()
            .map(|k| k.receiver.counts())
            .unwrap_or_default()
    }

    /// Epochs started since start (1 with a key: the start's own).
    pub fn epochs(&self) -> u64 {
        self.keyed.as_ref().map_or(0, |k| k.epochs)
    }

    /// Refuses as `missing_authenticator` every secured frame that waited
    /// longer than the pairing timeout at `mono_us` (the monotonic clock of
    /// [`Self::admit`]): without a later frame to trigger it, the last one
    /// would otherwise never be counted.
    pub fn expire(&mut self, mono_us: u64) {
        if let Some(k) = self.keyed.as_mut() {
            k.receiver.expire(mono_us);
        }
    }

    /// A statistics line was written: each reason may be logged again.
    pub fn new_period(&mut self) {
        self.logged = [false; AuthFailure::ALL.len()];
    }
}

/// Why a sender cannot sign.
#[derive(Debug, thiserror::Error)]
pub enum SignError {
    /// No authenticated `SECOC_SYNC` heard yet: the daemon's epoch and
    /// floor are unknown (it is not running, or not on this bus).
    #[error(
        "no SECOC_SYNC from canodom verified with this key yet: the daemon's epoch is unknown \
         (is it running on this bus, with keys of the same vehicle?)"
    )]
    NoSync,
    /// The sender's own record could not be written (then nothing may be sent).
    #[error("{0}")]
    Store(#[from] FreshnessError),
}

/// A sender's end for one authenticator id: learns the receiver's epoch
/// and floor from its authenticated announcements ([`Self::observe`]) and
/// signs each secured frame with the next counter, recorded in its store
/// first (`canodom calib` with the operator's command key, test parameter
/// stores with theirs).
#[derive(Debug)]
pub struct Signer {
    auth: Authenticator,
    /// Verifies the announcements: the key itself for an operator; the
    /// parameter store's `calib_params` key for its `CALIB_ACK` signer.
    sync_auth: Authenticator,
    store: FreshnessFile,
    authenticator_id: FrameId,
    /// The announcement's ids at the daemon's base.
    sync: Link,
    /// A `SECOC_SYNC` payload waiting for its authenticators.
    heard: Option<[u8; 8]>,
    /// The last announcement verified with this key.
    last_sync: Option<Sync>,
}

impl Signer {
    /// A signer with `key` (whose direction's announcements it verifies)
    /// whose counter lives in `freshness_file`, sending authenticators on
    /// `authenticator_id`, listening to the daemon's announcements at
    /// `base`.
    ///
    /// # Errors
    /// The freshness file is unreadable or damaged.
    pub fn new(
        key: &Key,
        freshness_file: &Path,
        authenticator_id: FrameId,
        base: BaseId,
    ) -> Result<Self, FreshnessError> {
        if let Some(dir) = freshness_file
            .parent()
            .filter(|d| !d.as_os_str().is_empty())
        {
            // A missing folder shows as the store's own write error below.
            let _ = std::fs::create_dir_all(dir);
        }
        Ok(Self {
            auth: Authenticator::new(key),
            sync_auth: Authenticator::new(key),
            store: FreshnessFile::load(freshness_file)?,
            authenticator_id,
            sync: sync_link(base),
            heard: None,
            last_sync: None,
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
        base: BaseId,
    ) -> Result<Option<Self>, FreshnessError> {
        keys.key(role)
            .map(|k| Self::new(k, freshness_file, authenticator_id, base))
            .transpose()
    }

    /// Verifies the announcements with `key` instead of the signing key
    /// (the parameter store signs `CALIB_ACK` with its `calib_ack` key and
    /// hears the daemon with its `calib_params` key).
    #[must_use]
    pub fn hearing_with(mut self, key: &Key) -> Self {
        self.sync_auth = Authenticator::new(key);
        self
    }

    /// The ids of the daemon's announcements (to receive them).
    pub fn sync_ids(&self) -> [FrameId; 2] {
        [self.sync.secured, self.sync.authenticator]
    }

    /// Feeds a received frame: an announcement whose authenticator this
    /// key verifies becomes the one signed with; returns it then. Anything
    /// else (another key's authenticator, a changed payload, other frames)
    /// is ignored: a sender never trusts an unauthenticated value.
    pub fn observe(&mut self, frame: &CanFrame) -> Option<Sync> {
        let data = <[u8; 8]>::try_from(frame.data()).ok()?;
        if frame.id() == self.sync.secured {
            self.heard = Some(data);
            return None;
        }
        if frame.id() != self.sync.authenticator {
            return None;
        }
        let s = Sync::verify(&self.sync_auth, self.sync.secured, &self.heard?, &data)?;
        self.last_sync = Some(s);
        Some(s)
    }

    /// The last announcement verified.
    pub fn last_sync(&self) -> Option<Sync> {
        self.last_sync
    }

    /// The authenticator frame of `data` sent at `secured`, with the next
    /// counter above the announced floor and this sender's last one,
    /// recorded before it is returned.
    ///
    /// # Errors
    /// [`SignError::NoSync`] before an announcement was verified;
    /// [`SignError::Store`] when the counter could not be recorded (then
    /// nothing may be sent).
    pub fn sign(&mut self, secured: FrameId, data: &[u8; 8]) -> Result<CanFrame, SignError> {
        let sync = self.last_sync.ok_or(SignError::NoSync)?;
        let id = data_id(secured);
        let fv = next_freshness(sync, self.store.tx(id));
        self.store.reserve_tx(id, fv)?;
        let auth = self.auth.sign(secured, data, fv);
        CanFrame::new_data(self.authenticator_id, &auth).map_err(|e| {
            SignError::Store(FreshnessError::Read {
                path: self.store.path().to_owned(),
                source: std::io::Error::other(e.to_string()),
            })
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Config, ConfigError};
    use crate::security::DEFAULT_FRESHNESS_FILE;
    use canodom_protocol::calib_wire::{Ack, AckStatus, Command};
    use canodom_protocol::secoc_keys::{MasterKey, Party};
    use std::os::unix::fs::{OpenOptionsExt as _, PermissionsExt as _};
    use std::path::PathBuf;

    const MASTER_HEX: &str = "000102030405060708090a0b0c0d0e0f";
    const VEHICLE: &str = "rc-car-7";

    /// The daemon's monotonic clock in these tests, µs.
    const T0_US: u64 = 5_000_000_000;

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
        assert_eq!(c.security.freshness_window.as_millis(), 5_000);
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
        let (dir, cfg) = setup("keys2", 0o600, &daemon_keys(), "freshness_window_s = 0\n");
        assert!(
            load(&dir, &cfg)
                .unwrap_err()
                .to_string()
                .contains("freshness_window_s")
        );
        let (dir, cfg) = setup("keys3", 0o600, &daemon_keys(), "freshness_window_s = 2.5\n");
        let c = load(&dir, &cfg).unwrap();
        assert_eq!(c.security.freshness_window.as_millis(), 2_500);
        assert_eq!(c.security.window_ticks(), 3, "whole announcement periods");
        // The lockout is gone (issue #44): its keys are unknown now.
        let (dir, old) = setup("keys4", 0o600, &daemon_keys(), "lockout_s = 60\n");
        assert!(
            load(&dir, &old)
                .unwrap_err()
                .to_string()
                .contains("lockout_s")
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
    }

    fn frame(id: FrameId, data: &[u8]) -> CanFrame {
        CanFrame::new_data(id, data).unwrap()
    }

    fn keyed(tag: &str, extra: &str) -> (PathBuf, Config) {
        let (dir, cfg) = setup(tag, 0o600, &daemon_keys(), extra);
        let c = load(&dir, &cfg).unwrap();
        (dir, c)
    }

    /// The operator's signer (`canodom calib`), having heard the gate's
    /// announcement now.
    fn operator(c: &Config, gate: &mut SecurityGate) -> Signer {
        let op = keys(Party::Operator);
        let mut s = Signer::new(
            op.key(Role::CalibCmd).unwrap(),
            &c.security.operator_freshness_file,
            OwnFrame::CalibCmdAuth.id(c.output.base_id),
            c.output.base_id,
        )
        .unwrap();
        hear(&mut s, gate, false);
        s
    }

    /// `signer` hears the gate's announcement (after a tick when `tick`).
    fn hear(signer: &mut Signer, gate: &mut SecurityGate, tick: bool) {
        for f in gate.announce(tick).unwrap() {
            let _ = signer.observe(&f);
        }
    }

    /// A CALIB_CMD and its authenticator as `canodom calib` sends them.
    fn command(c: &Config, signer: &mut Signer, cmd: Command, counter: u8) -> [CanFrame; 2] {
        let wire = CalibWire::new(c.output.base_id).unwrap();
        let data = wire.encode_command(cmd, 0, counter);
        let id = c.calibration.command_id;
        [frame(id, &data), signer.sign(id, &data).unwrap()]
    }

    fn pass(gate: &mut SecurityGate, frames: &[CanFrame], t_us: u64) -> Admit {
        let mut last = Admit::Pass;
        for (k, f) in frames.iter().enumerate() {
            last = gate.admit(f, t_us + k as u64 * 100);
        }
        last
    }

    #[test]
    fn auth_a_signed_calib_command_is_accepted_and_replays_before_and_after_a_restart_are_not() {
        let (_dir, c) = keyed("gate", "");
        let mut gate = SecurityGate::for_config(&c).unwrap();
        let mut op = operator(&c, &mut gate);
        let first = command(&c, &mut op, Command::Commit, 1);
        assert_eq!(pass(&mut gate, &first, T0_US), Admit::Authentic(first[0]));
        // The operator's next command, before any new announcement, is fresh too.
        let second = command(&c, &mut op, Command::Rollback, 2);
        assert!(matches!(
            pass(&mut gate, &second, T0_US + 1_000),
            Admit::Authentic(_)
        ));
        // Replayed at once: refused, logged once, then only counted.
        assert!(matches!(
            pass(&mut gate, &first, T0_US + 2_000),
            Admit::Refused {
                reason: AuthFailure::Replayed,
                log: true,
                last_accepted: Some(_)
            }
        ));
        assert!(matches!(
            pass(&mut gate, &second, T0_US + 3_000),
            Admit::Refused {
                reason: AuthFailure::Replayed,
                log: false,
                ..
            }
        ));
        // A restart: a new epoch, both refused; the operator resynchronises
        // from the new announcement and is accepted at once.
        let epoch = gate.epoch().unwrap();
        drop(gate);
        let mut gate = SecurityGate::for_config(&c).unwrap();
        assert_eq!(gate.epoch(), Some(epoch + 1));
        for (k, f) in [&first, &second].into_iter().enumerate() {
            let v = pass(&mut gate, f, T0_US + 10_000 + k as u64 * 1000);
            assert!(!matches!(v, Admit::Authentic(_)), "{v:?}");
        }
        assert_eq!(gate.counts().of(AuthFailure::BadMac), 2);
        hear(&mut op, &mut gate, false);
        let third = command(&c, &mut op, Command::Abort, 3);
        assert!(matches!(
            pass(&mut gate, &third, T0_US + 20_000),
            Admit::Authentic(_)
        ));
        assert_eq!(
            gate.admit(&frame(FrameId::Standard(0x100), &[0; 8]), T0_US),
            Admit::Pass
        );
    }

    #[test]
    fn auth_a_deleted_freshness_file_draws_a_random_epoch_and_old_frames_fail() {
        let (_dir, c) = keyed("deleted", "");
        let mut gate = SecurityGate::for_config(&c).unwrap();
        let mut op = operator(&c, &mut gate);
        let recorded: Vec<_> = (0..5u8)
            .map(|k| {
                let f = command(&c, &mut op, Command::Abort, k);
                assert!(matches!(
                    pass(&mut gate, &f, T0_US + u64::from(k) * 1000),
                    Admit::Authentic(_)
                ));
                f
            })
            .collect();
        let old = gate.epoch().unwrap();
        drop(gate);
        std::fs::remove_file(&c.security.freshness_file).unwrap();
        let mut gate = SecurityGate::for_config(&c).unwrap();
        assert_ne!(
            gate.epoch(),
            Some(old + 1),
            "drawn at random, not counted on"
        );
        for (k, f) in recorded.iter().enumerate() {
            let v = pass(&mut gate, f, T0_US + k as u64 * 1_000_000);
            assert!(
                matches!(
                    v,
                    Admit::Refused {
                        reason: AuthFailure::BadMac,
                        ..
                    }
                ),
                "recording {k}: {v:?}"
            );
        }
        let text = std::fs::read_to_string(&c.security.freshness_file).unwrap();
        assert!(
            text.contains(&format!("epoch {:#010x}", gate.epoch().unwrap())),
            "{text}"
        );
    }

    #[test]
    fn auth_a_signer_trusts_only_an_announcement_its_key_verifies() {
        let (_dir, c) = keyed("sync", "");
        let mut gate = SecurityGate::for_config(&c).unwrap();
        let frames = gate.announce(true).unwrap();
        assert_eq!(frames.len(), 3, "SECOC_SYNC and one authenticator per key");
        let mut op = operator(&c, &mut gate);
        let heard = op.last_sync().unwrap();
        // A forged announcement (another epoch, no key) changes nothing.
        let forged = Sync {
            epoch: heard.epoch ^ 1,
            floor: 7,
        };
        let other = Authenticator::new(&master().derive("rc-car-8", Role::CalibCmd));
        let _ = op.observe(&frame(frames[0].id(), &forged.payload()));
        let _ = op.observe(&frame(frames[1].id(), &forged.sign(&other, frames[0].id())));
        assert_eq!(op.last_sync(), Some(heard));
        // The parameter store verifies the other authenticator with its key.
        let store = keys(Party::ParamStore);
        let store_signer = |c: &Config| {
            Signer::new(
                store.key(Role::CalibAck).unwrap(),
                &c.security
                    .operator_freshness_file
                    .with_file_name("store-freshness"),
                OwnFrame::CalibAckAuth.id(c.output.base_id),
                c.output.base_id,
            )
            .unwrap()
        };
        let hear_all = |s: &mut Signer| {
            for f in &frames {
                let _ = s.observe(f);
            }
            s.last_sync().map(|s| s.epoch)
        };
        let mut ps = store_signer(&c);
        assert_eq!(
            hear_all(&mut ps),
            None,
            "the ACK key verifies no announcement"
        );
        let mut ps = ps.hearing_with(store.key(Role::CalibParams).unwrap());
        assert_eq!(hear_all(&mut ps), gate.epoch());
        // Without any announcement nothing is signed.
        let mut deaf = store_signer(&c);
        assert!(matches!(
            deaf.sign(FrameId::Standard(0x613), &[0; 8]),
            Err(SignError::NoSync)
        ));
    }

    #[test]
    fn auth_operator_and_parameter_store_keys_sign_only_their_own_messages() {
        let (_dir, c) = keyed("roles", "");
        let base = c.output.base_id;
        let wire = CalibWire::new(base).unwrap();
        let mut gate = SecurityGate::for_config(&c).unwrap();
        let fv = freshness(gate.epoch().unwrap(), 1);
        let op = keys(Party::Operator);
        let store = keys(Party::ParamStore);
        assert!(op.key(Role::CalibParams).is_none() && op.key(Role::CalibAck).is_none());
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
        let forged = Authenticator::new(cmd_key).sign(wire.params_id(), &page, fv);
        let store_verifier = Authenticator::new(store.key(Role::CalibParams).unwrap());
        assert_eq!(
            store_verifier.verify_near(wire.params_id(), &page, &forged, fv),
            None
        );
        let ack = wire.encode_ack(
            Ack {
                version: 9,
                status: AckStatus::Stored,
                set_crc: wire.set_crc(&set).unwrap(),
            },
            0,
        );
        let ack_auth = OwnFrame::CalibAckAuth.id(base);
        let by_operator = Authenticator::new(cmd_key).sign(wire.ack_id(), &ack, fv);
        assert!(matches!(
            pass(
                &mut gate,
                &[frame(wire.ack_id(), &ack), frame(ack_auth, &by_operator)],
                T0_US
            ),
            Admit::Refused {
                reason: AuthFailure::BadMac,
                ..
            }
        ));
        // The store's key signs the ACK the daemon accepts, but no command.
        let by_store =
            Authenticator::new(store.key(Role::CalibAck).unwrap()).sign(wire.ack_id(), &ack, fv);
        assert!(matches!(
            pass(
                &mut gate,
                &[frame(wire.ack_id(), &ack), frame(ack_auth, &by_store)],
                T0_US + 1000
            ),
            Admit::Authentic(_)
        ));
        let cmd = wire.encode_command(Command::Commit, 0, 1);
        let cmd_auth = OwnFrame::CalibCmdAuth.id(base);
        let fv2 = freshness(gate.epoch().unwrap(), 2);
        for key in [
            store.key(Role::CalibAck).unwrap().clone(),
            master().derive("rc-car-8", Role::CalibCmd),
        ] {
            let a = Authenticator::new(&key).sign(c.calibration.command_id, &cmd, fv2);
            assert!(matches!(
                pass(
                    &mut gate,
                    &[frame(c.calibration.command_id, &cmd), frame(cmd_auth, &a)],
                    T0_US + 2000
                ),
                Admit::Refused {
                    reason: AuthFailure::BadMac,
                    ..
                }
            ));
        }
        // The daemon refuses to start on an operator's or a store's key file.
        for party in [Party::Operator, Party::ParamStore] {
            let mut sec = c.security.clone();
            sec.keys = Some(keys(party));
            let e = SecurityGate::new(&sec, base, c.calibration.command_id).unwrap_err();
            assert!(e.to_string().contains(party.name()), "{e}");
        }
    }

    #[test]
    fn auth_calib_params_are_signed_with_the_params_key_in_the_epoch() {
        let (dir, c) = keyed("tx", "");
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
        let epoch = gate.epoch().unwrap();
        let mut mark = freshness(epoch, 0);
        for page in wire.encode_params(&set, 0).unwrap() {
            let out = gate.outgoing(&frame(wire.params_id(), &page));
            assert_eq!(out.len(), 2);
            assert_eq!(out[1].id(), OwnFrame::CalibParamsAuth.id(base));
            let auth: [u8; 8] = out[1].data().try_into().unwrap();
            let fv = verifier
                .verify_near(wire.params_id(), &page, &auth, mark)
                .unwrap();
            assert!(fv > mark, "strictly increasing");
            mark = fv;
        }
        assert_eq!(mark, freshness(epoch, 4));
        // After a restart the daemon signs in a higher epoch.
        let mut again = SecurityGate::for_config(&c).unwrap();
        assert_eq!(again.epoch(), Some(epoch + 1));
        let page = wire.encode_params(&set, 0).unwrap()[0];
        let out = again.outgoing(&frame(wire.params_id(), &page));
        let auth: [u8; 8] = out[1].data().try_into().unwrap();
        assert_eq!(
            verifier.verify_near(wire.params_id(), &page, &auth, freshness(epoch + 1, 0)),
            Some(freshness(epoch + 1, 1))
        );
        // The freshness file cannot be written: the daemon does not start.
        let mut sec = c.security.clone();
        sec.freshness_file = dir.join("no-such-folder/canodom-freshness");
        let e = SecurityGate::new(&sec, base, c.calibration.command_id).unwrap_err();
        assert!(e.to_string().contains("no-such-folder"), "{e}");
        // CALIB_STATUS passes untouched: no lockout hint is stamped on it.
        let status = [0x10, 0, 0, 0, 0, 0, 0x30, 0x00];
        let f = frame(wire.status_id(), &status);
        assert_eq!(gate.outgoing(&f), vec![f]);
    }

    #[test]
    fn auth_no_keyless_frame_locks_anything_and_a_kept_back_command_goes_stale() {
        let (_dir, c) = keyed("lock", "");
        let base = c.output.base_id;
        let wire = CalibWire::new(base).unwrap();
        let mut gate = SecurityGate::for_config(&c).unwrap();
        let mut op = operator(&c, &mut gate);
        let cmd_id = c.calibration.command_id;
        let cmd = wire.encode_command(Command::Abort, 0, 1);
        let aid = OwnFrame::CalibCmdAuth.id(base);
        let ack_aid = OwnFrame::CalibAckAuth.id(base);
        // A thousand bad MACs with the expected counter, on CALIB_CMD and CALIB_ACK.
        let floor = op.last_sync().unwrap().floor as u16;
        for k in 0..1000u64 {
            let t = T0_US + k * 1000;
            let mut guess = [0, 0, 1, 2, 3, 4, 5, k as u8];
            guess[..2].copy_from_slice(&floor.to_le_bytes());
            let _ = pass(&mut gate, &[frame(cmd_id, &cmd), frame(aid, &guess)], t);
            let _ = pass(
                &mut gate,
                &[frame(wire.ack_id(), &cmd), frame(ack_aid, &guess)],
                t + 500,
            );
        }
        assert!(
            gate.counts().of(AuthFailure::BadMac) >= 2000,
            "{}",
            gate.counts()
        );
        let valid = command(&c, &mut op, Command::Abort, 2);
        assert!(matches!(
            pass(&mut gate, &valid, T0_US + 2_000_000),
            Admit::Authentic(_)
        ));
        // A signed command kept back: accepted within the window, stale after.
        let kept = command(&c, &mut op, Command::Compute, 3);
        for _ in 0..c.security.window_ticks() {
            hear(&mut op, &mut gate, true);
        }
        assert!(matches!(
            pass(&mut gate, &kept, T0_US + 9_000_000),
            Admit::Refused {
                reason: AuthFailure::Stale,
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
        assert_eq!(gate.admit(&frame(id, &reset), T0_US), Admit::Held);
        let _ = gate.admit(&frame(FrameId::Standard(0x100), &[0; 8]), T0_US + 200_000);
        assert_eq!(gate.counts().of(AuthFailure::MissingAuthenticator), 1);
        // Signed with the CALIB_CMD key: refused; with the ODOM_CMD key: accepted.
        let fv = freshness(gate.epoch().unwrap(), 1);
        let for_calib = Authenticator::new(&role_key(Role::CalibCmd)).sign(id, &reset, fv);
        assert!(matches!(
            pass(
                &mut gate,
                &[frame(id, &reset), frame(aid, &for_calib)],
                T0_US + 300_000
            ),
            Admit::Refused {
                reason: AuthFailure::BadMac,
                ..
            }
        ));
        let signed = Authenticator::new(&role_key(Role::OdomCmd)).sign(id, &reset, fv);
        assert_eq!(
            pass(
                &mut gate,
                &[frame(id, &reset), frame(aid, &signed)],
                T0_US + 400_000
            ),
            Admit::Authentic(frame(id, &reset))
        );
    }

    #[test]
    fn auth_without_a_key_everything_passes_and_nothing_is_signed() {
        let (dir, cfg) = setup("nokey", 0o600, &daemon_keys(), "allow_without_key = true\n");
        let c = load(&dir, &cfg.replace("key_file = \"canodom.keys\"\n", "")).unwrap();
        let mut gate = SecurityGate::for_config(&c).unwrap();
        assert!(!gate.is_keyed());
        let f = frame(c.calibration.command_id, &[0; 8]);
        assert_eq!(gate.admit(&f, 0), Admit::Pass);
        assert_eq!(gate.outgoing(&f), vec![f]);
        assert_eq!(gate.announce(true).unwrap(), Vec::<CanFrame>::new());
        assert!(!c.security.freshness_file.exists());
    }
}
