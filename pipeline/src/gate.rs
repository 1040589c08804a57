//! The daemon's SecOC end (issue #22): [`SecurityGate`], the one object the
//! daemon asks about every received frame and hands every calibration frame
//! it sends, and [`Signer`], a sender's end (`canodom calib`, parameter
//! stores in tests). The profile is [`canodom_protocol::secoc`]'s; the
//! configuration is [`crate::security`]'s.

use crate::security::{SecurityConfig, data_id, receive_links};
use canodom_can::bus::Received;
use canodom_can::frame::{CanFrame, FrameId};
use canodom_params::freshness::FreshnessFile;
use canodom_protocol::calib_wire::CalibWire;
use canodom_protocol::own_dbc::{BaseId, OwnFrame};
use canodom_protocol::secoc::{
    AuthFailure, Authenticator, FailureCounts, Key, Link, Lockout, Receiver, Verdict,
    next_tx_freshness,
};
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
        /// The receiver's last accepted freshness value of that id, for the
        /// log line of a `Replayed` refusal (the sender's resynchronisation).
        last_accepted: Option<u32>,
    },
}

/// The daemon's SecOC end: verifies what it receives, signs the
/// `CALIB_PARAMS` it sends, stamps the lockout on `CALIB_STATUS`.
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
    /// The last freshness value sent on `CALIB_PARAMS`.
    tx_last: Option<u32>,
    /// The bus time of the last received frame, µs (the lockout's clock).
    now_us: u64,
    /// `CALIB_PARAMS` sent without an authenticator (freshness not stored).
    unsigned: u64,
}

/// Values reserved ahead for sending: one store write per this many sends.
const TX_RESERVE: u32 = 64;

impl SecurityGate {
    /// The gate of a validated configuration (its `[security]`, base id
    /// and `CALIB_CMD` id).
    ///
    /// # Errors
    /// [`GateError`] when the freshness file is unreadable or damaged.
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
    /// [`GateError`] when the freshness file is unreadable or damaged.
    pub fn new(
        security: &SecurityConfig,
        base: BaseId,
        calib_cmd_id: FrameId,
    ) -> Result<Self, GateError> {
        let logged = [false; AuthFailure::ALL.len()];
        let Some(key) = &security.key else {
            return Ok(Self {
                keyed: None,
                logged,
            });
        };
        let store = FreshnessFile::load(&security.freshness_file)?;
        let links: Vec<(Link, Option<u32>)> = receive_links(base, calib_cmd_id)
            .into_iter()
            .map(|l| (l, store.rx(data_id(l.secured))))
            .collect();
        let lockout = Lockout::new(
            security.lockout_failures,
            security.lockout_window.as_micros() as u64,
            security.lockout.as_micros() as u64,
        );
        let params_id = OwnFrame::CalibParams.id(base);
        let wire = CalibWire::new(base)?;
        Ok(Self {
            keyed: Some(Keyed {
                receiver: Receiver::new(key, &links, lockout),
                tx_last: store.tx(data_id(params_id)),
                store,
                signer: Authenticator::new(key),
                wire,
                links: receive_links(base, calib_cmd_id),
                params_auth_id: OwnFrame::CalibParamsAuth.id(base),
                now_us: 0,
                unsigned: 0,
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

    /// Judges a received frame (see [`Admit`]).
    pub fn admit(&mut self, r: &Received) -> Admit {
        let Some(k) = &mut self.keyed else {
            return Admit::Pass;
        };
        let now_us = r.timestamp.as_micros();
        k.now_us = now_us;
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

    /// The frames to send for `frame`: a page-0 `CALIB_STATUS` with
    /// `AUTH_LOCKOUT` stamped; a `CALIB_PARAMS` page followed by its
    /// authenticator, signed with a freshness value reserved in the store
    /// first (`unix_s`: the wall clock, for [`next_tx_freshness`]); anything
    /// else as it is.
    pub fn outgoing(&mut self, frame: &CanFrame, unix_s: u64) -> Vec<CanFrame> {
        let Some(k) = &mut self.keyed else {
            return vec![*frame];
        };
        let Ok(mut payload) = <[u8; 8]>::try_from(frame.data()) else {
            return vec![*frame];
        };
        if frame.id() == k.wire.status_id() {
            let locked = k.receiver.is_locked(k.now_us);
            if k.wire.stamp_auth_lockout(&mut payload, locked)
                && let Ok(f) = CanFrame::new_data(frame.id(), &payload)
            {
                return vec![f];
            }
            return vec![*frame];
        }
        if frame.id() != k.wire.params_id() {
            return vec![*frame];
        }
        let Some(fv) = next_tx_freshness(k.tx_last, unix_s) else {
            k.unsigned += 1;
            return vec![*frame];
        };
        let id = data_id(frame.id());
        if k.store.tx(id).is_none_or(|reserved| fv > reserved)
            && k.store
                .reserve_tx(id, fv.saturating_add(TX_RESERVE))
                .is_err()
        {
            k.unsigned += 1;
            return vec![*frame];
        }
        k.tx_last = Some(fv);
        let auth = k.signer.sign(frame.id(), &payload, fv);
        match CanFrame::new_data(k.params_auth_id, &auth) {
            Ok(a) => vec![*frame, a],
            Err(_) => vec![*frame],
        }
    }

    /// Refusals so far, by reason (all zero without a key).
    pub fn counts(&self) -> FailureCounts {
        self.keyed
            .as_ref()
            .map(|k| k.receiver.counts())
            .unwrap_or_default()
    }

    /// Lockouts started since start.
    pub fn lockouts(&self) -> u64 {
        self.keyed.as_ref().map_or(0, |k| k.receiver.lockouts())
    }

    /// `CALIB_PARAMS` pages sent without an authenticator because their
    /// freshness value could not be reserved.
    pub fn unsigned_sends(&self) -> u64 {
        self.keyed.as_ref().map_or(0, |k| k.unsigned)
    }

    /// A statistics line was written: each reason may be logged again.
    pub fn new_period(&mut self) {
        self.logged = [false; AuthFailure::ALL.len()];
    }
}

/// `canodom calib`'s freshness: the next value for `secured`, reserved in
/// `store` before it is returned (the caller sends it or loses it, never
/// reuses it).
///
/// # Errors
/// The store could not be written, or the counter is spent.
pub fn operator_next_freshness(
    store: &mut FreshnessFile,
    secured: FrameId,
    unix_s: u64,
    floor: Option<u32>,
) -> Result<u32, canodom_params::freshness::FreshnessError> {
    let id = data_id(secured);
    let last = match (store.tx(id), floor) {
        (Some(a), Some(b)) => Some(a.max(b)),
        (a, b) => a.or(b),
    };
    let fv = next_tx_freshness(last, unix_s).ok_or_else(|| {
        canodom_params::freshness::FreshnessError::Read {
            path: store.path().to_owned(),
            source: std::io::Error::other("the freshness counter is spent (u32::MAX)"),
        }
    })?;
    store.reserve_tx(id, fv)?;
    Ok(fv)
}

/// A sender's end for one authenticator id: signs each secured frame with
/// the next freshness value, reserved in its store first (`canodom calib`,
/// and test parameter stores).
#[derive(Debug)]
pub struct Signer {
    auth: Authenticator,
    store: FreshnessFile,
    authenticator_id: FrameId,
    /// The receiver's mark a resynchronising sender must continue above.
    floor: Option<u32>,
}

impl Signer {
    /// A signer with `key` whose counter lives in `freshness_file`, sending
    /// authenticators on `authenticator_id`; `floor` resynchronises a
    /// sender that fell behind (see [`canodom_protocol::secoc`]).
    ///
    /// # Errors
    /// The freshness file is unreadable or damaged.
    pub fn new(
        key: &Key,
        freshness_file: &Path,
        authenticator_id: FrameId,
        floor: Option<u32>,
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

    /// The authenticator frame of `data` sent at `secured` (`unix_s`: the
    /// wall clock), its freshness value stored before it is returned.
    ///
    /// # Errors
    /// The freshness value could not be stored (then nothing may be sent).
    pub fn sign(
        &mut self,
        secured: FrameId,
        data: &[u8; 8],
        unix_s: u64,
    ) -> Result<CanFrame, canodom_params::freshness::FreshnessError> {
        let fv = operator_next_freshness(&mut self.store, secured, unix_s, self.floor)?;
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
    use std::os::unix::fs::PermissionsExt as _;
    use std::path::PathBuf;

    const KEY_HEX: &str = "000102030405060708090a0b0c0d0e0f";

    /// A scratch folder holding the rc_car DBC's config, a key file of
    /// `mode` and `[security]` lines `extra`.
    fn setup(tag: &str, mode: u32, key_text: &str, extra: &str) -> (PathBuf, String) {
        let dir = std::env::temp_dir().join(format!("canodom-sec-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let key = dir.join("canodom.key");
        std::fs::write(&key, key_text).unwrap();
        std::fs::set_permissions(&key, std::fs::Permissions::from_mode(mode)).unwrap();
        let dbc = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/dbc/rc_car.dbc");
        let text = crate::config::tests::RC_CAR
            .replace("dbc = \"rc_car.dbc\"", &format!("dbc = {dbc:?}"))
            + &format!(
                "\n[calibration]\nparam_file = \"params.toml\"\n\n[security]\nkey_file = \"canodom.key\"\n\
                 operator_freshness_file = \"operator-freshness\"\n{extra}"
            );
        (dir, text)
    }

    fn load(dir: &Path, text: &str) -> Result<Config, ConfigError> {
        Config::from_toml(text, &dir.join("car.toml"))
    }

    #[test]
    fn auth_key_file_is_refused_when_group_or_others_may_read_it_or_it_is_malformed() {
        for (tag, mode, text, needle) in [
            ("g", 0o640, KEY_HEX, "mode 0640"),
            ("o", 0o604, KEY_HEX, "mode 0604"),
            ("w", 0o620, KEY_HEX, "chmod 600"),
            ("short", 0o600, "0102", "32 hexadecimal digits"),
            (
                "junk",
                0o600,
                "not a key at all, not hex, thirtytwo",
                "hexadecimal",
            ),
            (
                "zero",
                0o600,
                "00000000000000000000000000000000",
                "all zeros",
            ),
        ] {
            let (dir, cfg) = setup(&format!("key-{tag}"), mode, text, "");
            let e = load(&dir, &cfg).unwrap_err().to_string();
            assert!(e.contains("security.key_file"), "{tag}: {e}");
            assert!(e.contains("canodom.key"), "{tag}: names the file: {e}");
            assert!(e.contains(needle), "{tag}: {e}");
            assert!(
                !e.contains("0102030405"),
                "{tag}: the key is never echoed: {e}"
            );
        }
        let (dir, cfg) = setup("key-missing", 0o600, KEY_HEX, "");
        std::fs::remove_file(dir.join("canodom.key")).unwrap();
        let e = load(&dir, &cfg).unwrap_err().to_string();
        assert!(e.contains("cannot read"), "{e}");
        let (dir, cfg) = setup("key-ok", 0o400, &format!("{KEY_HEX}\n"), "");
        let c = load(&dir, &cfg).unwrap();
        assert!(c.security.key.is_some());
        assert_eq!(c.security.freshness_file, dir.join(DEFAULT_FRESHNESS_FILE));
        assert_eq!(
            (c.security.lockout_failures, c.security.lockout.as_secs()),
            (10, 60)
        );
    }

    #[test]
    fn auth_security_keys_are_validated() {
        let (dir, cfg) = setup("keys", 0o600, KEY_HEX, "lockout_failures = 0\n");
        assert!(
            load(&dir, &cfg)
                .unwrap_err()
                .to_string()
                .contains("lockout_failures")
        );
        let (dir, cfg) = setup("keys2", 0o600, KEY_HEX, "lockout_window_s = -1\n");
        assert!(
            load(&dir, &cfg)
                .unwrap_err()
                .to_string()
                .contains("lockout_window_s")
        );
        let (dir, cfg) = setup(
            "keys3",
            0o600,
            KEY_HEX,
            "lockout_s = 5\nlockout_failures = 3\nlockout_window_s = 2\n",
        );
        let c = load(&dir, &cfg).unwrap();
        assert_eq!(
            (
                c.security.lockout_failures,
                c.security.lockout_window.as_secs(),
                c.security.lockout.as_secs()
            ),
            (3, 2, 5)
        );
        let no_key = cfg.replace(
            "key_file = \"canodom.key\"\n",
            "allow_without_key = false\n",
        );
        let e = load(&dir, &no_key).unwrap_err().to_string();
        assert!(
            e.contains("security.key_file") && e.contains("allow_without_key"),
            "{e}"
        );
        let bench = cfg.replace("key_file = \"canodom.key\"\n", "");
        assert_eq!(load(&dir, &bench).unwrap().security.key, None);
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

    /// Operator side: a CALIB_CMD and its authenticator as `canodom calib` sends them.
    fn operator_frames(
        c: &Config,
        store: &mut FreshnessFile,
        cmd: Command,
        counter: u8,
    ) -> [(FrameId, [u8; 8]); 2] {
        let wire = CalibWire::new(c.output.base_id).unwrap();
        let data = wire.encode_command(cmd, 0, counter);
        let id = c.calibration.command_id;
        let fv = operator_next_freshness(store, id, 1_764_000_000, None).unwrap();
        let auth = Authenticator::new(c.security.key.as_ref().unwrap()).sign(id, &data, fv);
        [
            (id, data),
            (OwnFrame::CalibCmdAuth.id(c.output.base_id), auth),
        ]
    }

    #[test]
    fn auth_a_signed_calib_command_is_accepted_and_replays_before_and_after_a_restart_are_not() {
        let (dir, cfg) = setup("gate", 0o600, KEY_HEX, "");
        let c = load(&dir, &cfg).unwrap();
        let mut gate =
            SecurityGate::new(&c.security, c.output.base_id, c.calibration.command_id).unwrap();
        let mut op = FreshnessFile::load(&c.security.operator_freshness_file).unwrap();
        let [(id, data), (aid, auth)] = operator_frames(&c, &mut op, Command::Commit, 1);
        assert_eq!(gate.admit(&rx(0, id, &data)), Admit::Held);
        assert_eq!(
            gate.admit(&rx(300, aid, &auth)),
            Admit::Authentic(CanFrame::new_data(id, &data).unwrap())
        );
        // The operator's next command is fresh too (same second, counter + 1).
        let [(id2, data2), (aid2, auth2)] = operator_frames(&c, &mut op, Command::Rollback, 2);
        assert_eq!(gate.admit(&rx(1_000, id2, &data2)), Admit::Held);
        assert!(matches!(
            gate.admit(&rx(1_300, aid2, &auth2)),
            Admit::Authentic(_)
        ));
        // Replayed at once: refused, logged once, then only counted.
        assert_eq!(gate.admit(&rx(2_000, id, &data)), Admit::Held);
        assert!(matches!(
            gate.admit(&rx(2_300, aid, &auth)),
            Admit::Refused {
                reason: AuthFailure::Replayed,
                log: true,
                last_accepted: Some(_)
            }
        ));
        assert_eq!(gate.admit(&rx(3_000, id2, &data2)), Admit::Held);
        assert!(matches!(
            gate.admit(&rx(3_300, aid2, &auth2)),
            Admit::Refused {
                reason: AuthFailure::Replayed,
                log: false,
                ..
            }
        ));
        // A restart: a new gate from the same files refuses both.
        drop(gate);
        let mut gate =
            SecurityGate::new(&c.security, c.output.base_id, c.calibration.command_id).unwrap();
        for (t, (i, d)) in [(id, data), (aid, auth), (id2, data2), (aid2, auth2)]
            .into_iter()
            .enumerate()
        {
            let v = gate.admit(&rx(10_000 + t as u64 * 10, i, &d));
            assert!(!matches!(v, Admit::Authentic(_)), "{v:?}");
        }
        assert_eq!(gate.counts().of(AuthFailure::Replayed), 2);
        // Other frames pass untouched.
        assert_eq!(
            gate.admit(&rx(20_000, FrameId::Standard(0x100), &[0; 8])),
            Admit::Pass
        );
    }

    #[test]
    fn auth_a_forged_calib_ack_is_not_passed_on_and_a_signed_one_is() {
        let (dir, cfg) = setup("ack", 0o600, KEY_HEX, "");
        let c = load(&dir, &cfg).unwrap();
        let base = c.output.base_id;
        let mut gate = SecurityGate::new(&c.security, base, c.calibration.command_id).unwrap();
        let wire = CalibWire::new(base).unwrap();
        let ack = wire.encode_ack(
            Ack {
                version: 3,
                status: AckStatus::Stored,
            },
            0,
        );
        let ack_id = wire.ack_id();
        // A plain ACK (any node can send one) is held, then refused unpaired.
        assert_eq!(gate.admit(&rx(0, ack_id, &ack)), Admit::Held);
        assert!(matches!(
            gate.admit(&rx(200_000, FrameId::Standard(0x100), &[0; 8])),
            Admit::Pass
        ));
        assert_eq!(gate.counts().of(AuthFailure::MissingAuthenticator), 1);
        // With a guessed authenticator: refused.
        assert_eq!(gate.admit(&rx(300_000, ack_id, &ack)), Admit::Held);
        let forged = [0xFF, 0xFF, 0xFF, 0x7F, 1, 2, 3, 4];
        assert!(matches!(
            gate.admit(&rx(300_100, OwnFrame::CalibAckAuth.id(base), &forged)),
            Admit::Refused {
                reason: AuthFailure::BadMac,
                ..
            }
        ));
        // The parameter store's signed ACK passes.
        let auth = Authenticator::new(c.security.key.as_ref().unwrap()).sign(ack_id, &ack, 5);
        assert_eq!(gate.admit(&rx(400_000, ack_id, &ack)), Admit::Held);
        assert!(matches!(
            gate.admit(&rx(400_100, OwnFrame::CalibAckAuth.id(base), &auth)),
            Admit::Authentic(_)
        ));
    }

    #[test]
    fn auth_calib_params_are_signed_and_calib_status_carries_the_lockout() {
        let (dir, cfg) = setup("tx", 0o600, KEY_HEX, "lockout_failures = 2\n");
        let c = load(&dir, &cfg).unwrap();
        let base = c.output.base_id;
        let mut gate = SecurityGate::new(&c.security, base, c.calibration.command_id).unwrap();
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
        let key = c.security.key.clone().unwrap();
        let verifier = Authenticator::new(&key);
        let mut fvs = Vec::new();
        for page in wire.encode_params(&set, 0).unwrap() {
            let out = gate.outgoing(
                &CanFrame::new_data(wire.params_id(), &page).unwrap(),
                1_764_000_000,
            );
            assert_eq!(out.len(), 2);
            assert_eq!(out[1].id(), OwnFrame::CalibParamsAuth.id(base));
            let auth: [u8; 8] = out[1].data().try_into().unwrap();
            assert!(verifier.verify(wire.params_id(), &page, &auth));
            fvs.push(canodom_protocol::secoc::split_auth(&auth).0);
        }
        assert_eq!(
            fvs,
            [1_764_000_000, 1_764_000_001, 1_764_000_002, 1_764_000_003]
        );
        // After a restart the daemon continues above what it reserved.
        let mut again = SecurityGate::new(&c.security, base, c.calibration.command_id).unwrap();
        let page = wire.encode_params(&set, 0).unwrap()[0];
        let out = again.outgoing(
            &CanFrame::new_data(wire.params_id(), &page).unwrap(),
            1_764_000_000,
        );
        let fv = canodom_protocol::secoc::split_auth(&out[1].data().try_into().unwrap()).0;
        assert!(fv > 1_764_000_003, "{fv}");
        // Two bad MACs lock out; page 0 of CALIB_STATUS says so.
        let status = wire.encode_status(
            &canodom_protocol::calib_wire::StatusPage::Progress(
                canodom_protocol::calib_wire::Progress {
                    state: canodom_protocol::calib_wire::State::Idle,
                    instruction: canodom_protocol::calib_wire::InstructionCode::None,
                    run_index: 0,
                    runs_total: 0,
                    direction: canodom_protocol::calib_wire::WireDirection::None,
                    start_point: canodom_protocol::calib_wire::StartPoint::None,
                    run_distance_m: 0.0,
                    writeback: canodom_protocol::calib_wire::Writeback::Idle,
                    standstill: true,
                    writeback_attempts: 0,
                },
            ),
            0,
        );
        let status_frame = CanFrame::new_data(wire.status_id(), &status).unwrap();
        assert_eq!(
            wire.auth_lockout(gate.outgoing(&status_frame, 0)[0].data()),
            Some(false)
        );
        let cmd = wire.encode_command(Command::Abort, 0, 1);
        for t in [0, 1_000] {
            let _ = gate.admit(&rx(t, c.calibration.command_id, &cmd));
            let _ = gate.admit(&rx(t + 10, OwnFrame::CalibCmdAuth.id(base), &[0; 8]));
        }
        assert_eq!(gate.lockouts(), 1);
        assert_eq!(
            wire.auth_lockout(gate.outgoing(&status_frame, 0)[0].data()),
            Some(true)
        );
    }

    #[test]
    fn auth_a_sender_that_fell_behind_resynchronises_above_the_floor() {
        let (dir, cfg) = setup("resync", 0o600, KEY_HEX, "");
        let c = load(&dir, &cfg).unwrap();
        let id = c.calibration.command_id;
        let mut store = FreshnessFile::load(&dir.join("sender")).unwrap();
        // A clock far behind the receiver's mark: refused as a replay ...
        let mut gate = SecurityGate::for_config(&c).unwrap();
        let key = c.security.key.clone().unwrap();
        let wire = CalibWire::new(c.output.base_id).unwrap();
        let data = wire.encode_command(Command::Abort, 0, 1);
        let aid = OwnFrame::CalibCmdAuth.id(c.output.base_id);
        let signed = |fv: u32| Authenticator::new(&key).sign(id, &data, fv);
        let _ = gate.admit(&rx(0, id, &data));
        assert!(matches!(
            gate.admit(&rx(10, aid, &signed(1_800_000_000))),
            Admit::Authentic(_)
        ));
        let behind = operator_next_freshness(&mut store, id, 1_700_000_000, None).unwrap();
        let _ = gate.admit(&rx(1_000, id, &data));
        let Admit::Refused {
            reason: AuthFailure::Replayed,
            last_accepted: Some(mark),
            ..
        } = gate.admit(&rx(1_010, aid, &signed(behind)))
        else {
            panic!("a value behind the mark must be refused as a replay");
        };
        // ... and with the mark from the refusal as the floor, accepted.
        let next = operator_next_freshness(&mut store, id, 1_700_000_000, Some(mark)).unwrap();
        assert_eq!(next, mark + 1);
        let _ = gate.admit(&rx(2_000, id, &data));
        assert!(matches!(
            gate.admit(&rx(2_010, aid, &signed(next))),
            Admit::Authentic(_)
        ));
        // The store keeps the new value: the next one continues above it.
        assert_eq!(
            operator_next_freshness(&mut store, id, 0, None).unwrap(),
            mark + 2
        );
    }

    #[test]
    fn auth_odom_cmd_is_secured_like_calib_cmd() {
        let (dir, cfg) = setup("odom", 0o600, KEY_HEX, "");
        let c = load(&dir, &cfg).unwrap();
        let base = c.output.base_id;
        let mut gate = SecurityGate::for_config(&c).unwrap();
        let (id, aid) = (OwnFrame::OdomCmd.id(base), OwnFrame::OdomCmdAuth.id(base));
        // RESET_POSE (request 2), counter 1, CRC-8 in byte 7.
        let mut reset = [2, 0, 0, 0, 0, 0, 0x10, 0];
        let _ = canodom_dbc::Checksum::rc_car().apply(&mut reset);
        // Plain: held, then refused for its missing authenticator.
        assert_eq!(gate.admit(&rx(0, id, &reset)), Admit::Held);
        let _ = gate.admit(&rx(200_000, FrameId::Standard(0x100), &[0; 8]));
        assert_eq!(gate.counts().of(AuthFailure::MissingAuthenticator), 1);
        // An authenticator made for CALIB_CMD does not pass for ODOM_CMD.
        let key = c.security.key.clone().unwrap();
        let for_calib = Authenticator::new(&key).sign(c.calibration.command_id, &reset, 9);
        assert_eq!(gate.admit(&rx(300_000, id, &reset)), Admit::Held);
        assert!(matches!(
            gate.admit(&rx(300_010, aid, &for_calib)),
            Admit::Refused {
                reason: AuthFailure::BadMac,
                ..
            }
        ));
        let signed = Authenticator::new(&key).sign(id, &reset, 9);
        assert_eq!(gate.admit(&rx(400_000, id, &reset)), Admit::Held);
        assert_eq!(
            gate.admit(&rx(400_010, aid, &signed)),
            Admit::Authentic(CanFrame::new_data(id, &reset).unwrap())
        );
    }

    #[test]
    fn auth_without_a_key_everything_passes_and_nothing_is_signed() {
        let (dir, cfg) = setup("nokey", 0o600, KEY_HEX, "");
        let c = load(&dir, &cfg.replace("key_file = \"canodom.key\"\n", "")).unwrap();
        let mut gate =
            SecurityGate::new(&c.security, c.output.base_id, c.calibration.command_id).unwrap();
        assert!(!gate.is_keyed());
        let f = CanFrame::new_data(c.calibration.command_id, &[0; 8]).unwrap();
        assert_eq!(gate.admit(&rx(0, f.id(), f.data())), Admit::Pass);
        assert_eq!(gate.outgoing(&f, 0), vec![f]);
        assert!(!c.security.freshness_file.exists());
    }
}
