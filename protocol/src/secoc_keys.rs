//! A key per role and direction (issue #33), derived from one master key
//! with HKDF-SHA256 (RFC 5869, RustCrypto `hkdf` + `sha2`).
//!
//! Each secured message has one sender and one receiver, and its own key:
//!
//! | role | message | direction | held by |
//! |---|---|---|---|
//! | [`Role::OdomCmd`] | `ODOM_CMD` | operator → canodom | operator, canodom |
//! | [`Role::CalibCmd`] | `CALIB_CMD` | operator → canodom | operator, canodom |
//! | [`Role::CalibParams`] | `CALIB_PARAMS` | canodom → parameter store | canodom, parameter store |
//! | [`Role::CalibAck`] | `CALIB_ACK` | parameter store → canodom | canodom, parameter store |
//!
//! so an operator's laptop can sign commands but neither a parameter set
//! nor an acknowledgement, and the parameter store cannot sign commands.
//! The HKDF `info` names the profile, the message, the direction and the
//! vehicle, so keys of two vehicles derived from one master key differ and
//! a frame of one is refused by the other:
//!
//! ```text
//! key = HKDF-SHA256(salt = "canodom SecOC profile 2", ikm = master,
//!                   info = "canodom-secoc-2" 0x00 message 0x00 direction 0x00 vehicle)[..16]
//! ```
//!
//! A *key file* holds the keys of one party, one `role hex` line each,
//! with the vehicle and the party named for the reader:
//!
//! ```text
//! # canodom SecOC keys (profile 2) ...
//! vehicle rc-car-7
//! party operator
//! odom_cmd 1f0c...
//! calib_cmd 9a4e...
//! ```
//!
//! `canodom keys derive` writes the three files from the master key; the
//! master key itself stays off the vehicle.

use crate::secoc::{KEY_LEN, Key};
use std::fmt::Write as _;
use zeroize::Zeroizing;

/// Salt of the derivation (fixed: the master key is the secret).
const SALT: &[u8] = b"canodom SecOC profile 2";

/// Prefix of every `info`.
const INFO_PREFIX: &[u8] = b"canodom-secoc-2";

/// A secured message and its direction: what a key is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Role {
    /// `ODOM_CMD`, operator → canodom.
    OdomCmd,
    /// `CALIB_CMD`, operator → canodom.
    CalibCmd,
    /// `CALIB_PARAMS`, canodom → parameter store.
    CalibParams,
    /// `CALIB_ACK`, parameter store → canodom.
    CalibAck,
}

impl Role {
    /// Every role, in key-file order.
    pub const ALL: [Self; 4] = [
        Self::OdomCmd,
        Self::CalibCmd,
        Self::CalibParams,
        Self::CalibAck,
    ];

    /// The name in key files (`odom_cmd`, ...).
    pub fn name(self) -> &'static str {
        match self {
            Self::OdomCmd => "odom_cmd",
            Self::CalibCmd => "calib_cmd",
            Self::CalibParams => "calib_params",
            Self::CalibAck => "calib_ack",
        }
    }

    /// The message label of the derivation.
    fn message(self) -> &'static str {
        match self {
            Self::OdomCmd => "ODOM_CMD",
            Self::CalibCmd => "CALIB_CMD",
            Self::CalibParams => "CALIB_PARAMS",
            Self::CalibAck => "CALIB_ACK",
        }
    }

    /// The direction label of the derivation: sender, receiver.
    fn direction(self) -> &'static str {
        match self {
            Self::OdomCmd | Self::CalibCmd => "operator->canodom",
            Self::CalibParams => "canodom->param_store",
            Self::CalibAck => "param_store->canodom",
        }
    }

    fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|r| r.name() == name)
    }
}

/// Who holds a key file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Party {
    /// The daemon: verifies commands and acknowledgements, signs parameter sets.
    Canodom,
    /// `canodom calib` on an operator's machine: signs commands only.
    Operator,
    /// The ECU that stores parameter sets: verifies them, signs acknowledgements.
    ParamStore,
}

impl Party {
    /// Every party.
    pub const ALL: [Self; 3] = [Self::Canodom, Self::Operator, Self::ParamStore];

    /// The name in key files and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Canodom => "canodom",
            Self::Operator => "operator",
            Self::ParamStore => "param-store",
        }
    }

    /// The roles whose keys this party holds.
    pub fn roles(self) -> &'static [Role] {
        match self {
            Self::Canodom => &Role::ALL,
            Self::Operator => &[Role::OdomCmd, Role::CalibCmd],
            Self::ParamStore => &[Role::CalibParams, Role::CalibAck],
        }
    }

    /// The party named `name`.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|p| p.name() == name)
    }
}

/// Why a master key or key file's text is refused. Messages never repeat
/// key material.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum KeySetError {
    /// The master key is not 32 or 64 hexadecimal digits.
    #[error(
        "master key: expected 32 or 64 hexadecimal digits (128 or 256 bits) and nothing else, got {got}"
    )]
    Master {
        /// A length or a character class, never the text.
        got: String,
    },
    /// A vehicle identity that cannot be written on one line.
    #[error("vehicle identity: expected 1 to 64 printable characters without spaces, got {got}")]
    Vehicle {
        /// What was wrong with it.
        got: String,
    },
    /// A line of a key file that is not `vehicle ID`, `party NAME` or `role HEX`.
    #[error("line {line}: {what}")]
    Line {
        /// 1-based line number.
        line: usize,
        /// What is wrong (never the key).
        what: String,
    },
    /// A key of profile 1 (one key for every role): derive the per-role files.
    #[error(
        "this is a single key of SecOC profile 1 (one key for every role); profile 2 keeps a key per \
         role: treat it as the master key and write the key files with `canodom keys derive`"
    )]
    SingleKey,
}

/// A master key: 16 or 32 bytes, wiped when dropped.
pub struct MasterKey(Zeroizing<Vec<u8>>);

impl std::fmt::Debug for MasterKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("MasterKey(<redacted>)")
    }
}

impl MasterKey {
    /// Parses 32 or 64 hexadecimal digits (surrounding whitespace allowed).
    ///
    /// # Errors
    /// [`KeySetError::Master`]; an all-zero key too.
    pub fn parse(text: &str) -> Result<Self, KeySetError> {
        let t = text.trim();
        if t.len() != 32 && t.len() != 64 {
            return Err(KeySetError::Master {
                got: format!("{} characters", t.chars().count()),
            });
        }
        let bytes = decode_hex(t).ok_or_else(|| KeySetError::Master {
            got: "a character that is not a hexadecimal digit".into(),
        })?;
        if bytes.iter().all(|&b| b == 0) {
            return Err(KeySetError::Master {
                got: "all zeros (a placeholder, not a secret)".into(),
            });
        }
        Ok(Self(bytes))
    }

    /// The key of `role` on `vehicle` (see the module doc).
    pub fn derive(&self, vehicle: &str, role: Role) -> Key {
        let hk = hkdf::Hkdf::<sha2::Sha256>::new(Some(SALT), &self.0);
        let mut info = Vec::with_capacity(64);
        for (i, part) in [
            INFO_PREFIX,
            role.message().as_bytes(),
            role.direction().as_bytes(),
            vehicle.as_bytes(),
        ]
        .into_iter()
        .enumerate()
        {
            if i > 0 {
                info.push(0);
            }
            info.extend_from_slice(part);
        }
        let mut okm = Zeroizing::new([0u8; KEY_LEN]);
        // 16 bytes is far below HKDF-SHA256's limit of 255 × 32.
        hk.expand(&info, okm.as_mut_slice())
            .unwrap_or_else(|_| unreachable!("16 bytes <= 255 * 32"));
        Key::from_bytes(*okm)
    }

    /// The key file of `party` on `vehicle`.
    ///
    /// # Errors
    /// [`KeySetError::Vehicle`] for an identity that cannot be a key-file line.
    pub fn key_file(&self, vehicle: &str, party: Party) -> Result<Zeroizing<String>, KeySetError> {
        check_vehicle(vehicle)?;
        let mut s = Zeroizing::new(String::new());
        let _ = writeln!(
            s,
            "# canodom SecOC keys (profile 2) of the {} for vehicle {vehicle},\n\
             # derived with HKDF-SHA256 from the master key (`canodom keys derive`).\n\
             # Secret: mode 0600, owned by the user that reads it.",
            party.name()
        );
        let _ = writeln!(s, "vehicle {vehicle}\nparty {}", party.name());
        for &role in party.roles() {
            let key = self.derive(vehicle, role);
            let _ = write!(s, "{} ", role.name());
            for b in key.bytes() {
                let _ = write!(s, "{b:02x}");
            }
            s.push('\n');
        }
        Ok(s)
    }
}

fn check_vehicle(vehicle: &str) -> Result<(), KeySetError> {
    let n = vehicle.chars().count();
    if n == 0 || n > 64 {
        return Err(KeySetError::Vehicle {
            got: format!("{n} characters"),
        });
    }
    if !vehicle.chars().all(|c| c.is_ascii_graphic()) {
        return Err(KeySetError::Vehicle {
            got: "a space, a control or a non-ASCII character".into(),
        });
    }
    Ok(())
}

fn decode_hex(t: &str) -> Option<Zeroizing<Vec<u8>>> {
    if !t.len().is_multiple_of(2) || !t.bytes().all(|b| b.is_ascii_hexdigit()) {
        return None;
    }
    let mut out = Zeroizing::new(Vec::with_capacity(t.len() / 2));
    for i in (0..t.len()).step_by(2) {
        out.push(u8::from_str_radix(&t[i..i + 2], 16).ok()?);
    }
    Some(out)
}

/// The keys of one party, read from its key file.
#[derive(Clone, PartialEq, Eq, Debug)]
pub struct KeySet {
    /// The vehicle the keys were derived for.
    pub vehicle: String,
    /// The party named in the file.
    pub party: Party,
    keys: Vec<(Role, Key)>,
}

impl KeySet {
    /// Parses a key file (see the module doc).
    ///
    /// # Errors
    /// [`KeySetError`] naming the line; a single 32-digit key (profile 1)
    /// is [`KeySetError::SingleKey`].
    pub fn parse(text: &str) -> Result<Self, KeySetError> {
        let meaningful: Vec<(usize, &str)> = text
            .lines()
            .enumerate()
            .map(|(i, l)| (i + 1, l.trim()))
            .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
            .collect();
        if let [(_, only)] = meaningful.as_slice()
            && only.len() == 2 * KEY_LEN
            && only.bytes().all(|b| b.is_ascii_hexdigit())
        {
            return Err(KeySetError::SingleKey);
        }
        let mut vehicle = None;
        let mut party = None;
        let mut keys: Vec<(Role, Key)> = Vec::new();
        for (line, l) in meaningful {
            let bad = |what: String| KeySetError::Line { line, what };
            let mut it = l.split_whitespace();
            let (Some(name), Some(value), None) = (it.next(), it.next(), it.next()) else {
                return Err(bad(
                    "expected `vehicle ID`, `party NAME` or `ROLE KEY` (two words)".into(),
                ));
            };
            match name {
                "vehicle" => {
                    check_vehicle(value).map_err(|e| bad(e.to_string()))?;
                    vehicle = Some(value.to_owned());
                }
                "party" => {
                    party = Some(Party::from_name(value).ok_or_else(|| {
                        bad(format!(
                            "unknown party {value:?} (canodom, operator or param-store)"
                        ))
                    })?);
                }
                _ => {
                    let role = Role::from_name(name).ok_or_else(|| {
                        bad(format!(
                            "unknown role {name:?} (odom_cmd, calib_cmd, calib_params or calib_ack)"
                        ))
                    })?;
                    if keys.iter().any(|(r, _)| *r == role) {
                        return Err(bad(format!("{name} given twice")));
                    }
                    let key = Key::parse(value).map_err(|e| bad(format!("{name}: {e}")))?;
                    keys.push((role, key));
                }
            }
        }
        let (Some(vehicle), Some(party)) = (vehicle, party) else {
            return Err(KeySetError::Line {
                line: text.lines().count(),
                what: "a key file names its `vehicle` and its `party`".into(),
            });
        };
        for &role in party.roles() {
            if !keys.iter().any(|(r, _)| *r == role) {
                return Err(KeySetError::Line {
                    line: text.lines().count(),
                    what: format!("the {} needs a {} key", party.name(), role.name()),
                });
            }
        }
        if let Some((role, _)) = keys.iter().find(|(r, _)| !party.roles().contains(r)) {
            return Err(KeySetError::Line {
                line: text.lines().count(),
                what: format!(
                    "the {} must not hold the {} key (a key per role: give each party only its own file)",
                    party.name(),
                    role.name()
                ),
            });
        }
        Ok(Self {
            vehicle,
            party,
            keys,
        })
    }

    /// The key of `role`, if this party holds it.
    pub fn key(&self, role: Role) -> Option<&Key> {
        self.keys.iter().find(|(r, _)| *r == role).map(|(_, k)| k)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::secoc::Authenticator;
    use canodom_can::frame::FrameId;

    const MASTER: &str = "000102030405060708090a0b0c0d0e0f";

    #[test]
    fn auth_hkdf_sha256_matches_rfc5869_test_case_1() {
        // RFC 5869 A.1: the crate we derive with, on the RFC's own vector.
        let ikm = [0x0bu8; 22];
        let salt: Vec<u8> = (0u8..=0x0c).collect();
        let info: Vec<u8> = (0xf0u8..=0xf9).collect();
        let hk = hkdf::Hkdf::<sha2::Sha256>::new(Some(&salt), &ikm);
        let mut okm = [0u8; 42];
        hk.expand(&info, &mut okm).unwrap();
        let hex = okm.iter().fold(String::new(), |mut out, b| {
            use std::fmt::Write as _;
            let _ = write!(out, "{b:02x}");
            out
        });
        assert_eq!(
            hex,
            "3cb25f25faacd57a90434f64d0362f2a2d2d0a90cf1a5a4c5db02d56ecc4c5bf34007208d5b887185865"
        );
    }

    #[test]
    fn auth_every_role_and_vehicle_has_its_own_key() {
        let m = MasterKey::parse(MASTER).unwrap();
        let mut seen = Vec::new();
        for v in ["car-1", "car-2"] {
            for r in Role::ALL {
                let k = m.derive(v, r);
                assert!(!seen.contains(&k), "{v} {r:?}");
                seen.push(k);
            }
        }
        // Deterministic: the same inputs give the same key.
        assert_eq!(
            m.derive("car-1", Role::CalibCmd),
            m.derive("car-1", Role::CalibCmd)
        );
        // A frame signed on one car's key fails on the other's.
        let id = FrameId::Standard(0x610);
        let p = [1u8; 8];
        let a1 = Authenticator::new(&m.derive("car-1", Role::CalibCmd));
        let a2 = Authenticator::new(&m.derive("car-2", Role::CalibCmd));
        assert!(!a2.verify_full(id, &p, 5, &a1.mac(id, &p, 5)));
    }

    #[test]
    fn auth_key_files_hold_only_their_partys_keys() {
        let m = MasterKey::parse(MASTER).unwrap();
        let op = KeySet::parse(&m.key_file("car-1", Party::Operator).unwrap()).unwrap();
        assert_eq!(op.party, Party::Operator);
        assert_eq!(op.vehicle, "car-1");
        assert_eq!(
            op.key(Role::CalibCmd),
            Some(&m.derive("car-1", Role::CalibCmd))
        );
        assert!(op.key(Role::CalibParams).is_none() && op.key(Role::CalibAck).is_none());
        let store = KeySet::parse(&m.key_file("car-1", Party::ParamStore).unwrap()).unwrap();
        assert!(store.key(Role::CalibCmd).is_none());
        assert!(store.key(Role::CalibParams).is_some());
        let daemon = KeySet::parse(&m.key_file("car-1", Party::Canodom).unwrap()).unwrap();
        assert!(Role::ALL.iter().all(|&r| daemon.key(r).is_some()));
        // An operator file that was given the params key is refused.
        let mut text = m.key_file("car-1", Party::Operator).unwrap().to_string();
        text.push_str("calib_params 0f0e0d0c0b0a09080706050403020100\n");
        let e = KeySet::parse(&text).unwrap_err().to_string();
        assert!(e.contains("must not hold the calib_params"), "{e}");
        assert!(!e.contains("0f0e0d0c"), "{e}");
    }

    #[test]
    fn auth_key_file_errors_name_the_line_and_never_the_key() {
        assert_eq!(
            KeySet::parse(&format!("{MASTER}\n")),
            Err(KeySetError::SingleKey)
        );
        let e = KeySet::parse("vehicle a\nparty operator\nodom_cmd 0011\n").unwrap_err();
        assert!(matches!(e, KeySetError::Line { line: 3, .. }), "{e}");
        assert!(!e.to_string().contains("0011"), "{e}");
        let e = KeySet::parse("vehicle a\nparty pilot\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2") && e.contains("pilot"), "{e}");
        let e = KeySet::parse("vehicle a\nparty operator\n")
            .unwrap_err()
            .to_string();
        assert!(e.contains("needs a odom_cmd key"), "{e}");
        assert!(MasterKey::parse("00").is_err());
        assert!(MasterKey::parse(&"0".repeat(32)).is_err());
        assert!(MasterKey::parse(&"ab".repeat(32)).is_ok());
        assert!(m_file_err("car one").contains("space"));
    }

    fn m_file_err(vehicle: &str) -> String {
        MasterKey::parse(MASTER)
            .unwrap()
            .key_file(vehicle, Party::Operator)
            .unwrap_err()
            .to_string()
    }
}
