//! Authenticated commands and write-back in the manner of AUTOSAR SecOC
//! (issue #22): a truncated CMAC-AES-128 over the frame id, the payload and
//! a freshness value, with a key that never travels on the bus.
//!
//! # The profile ("canodom SecOC profile 1")
//!
//! A *secured* frame is one of `ODOM_CMD`, `CALIB_CMD`, `CALIB_PARAMS` and
//! `CALIB_ACK`. Its 8-byte payload (the *authentic PDU*: the frame as it was
//! before, with its rolling counter and CRC-8) is unchanged, so every tool
//! that decodes it still does. The *cryptographic PDU* is 8 bytes:
//!
//! | bytes | signal | content |
//! |---|---|---|
//! | 0..=3 | `FRESHNESS` (bits 0..31, Intel) | the full 32-bit freshness value, little-endian |
//! | 4..=7 | `MAC` (bits 32..63, Intel) | the first 4 bytes of the CMAC, in CMAC order |
//!
//! The MAC is CMAC-AES-128 (NIST SP 800-38B) over *DataToAuthenticator* =
//! the secured frame's id (4 bytes big-endian, bit 31 set for an extended
//! id) ‖ the 8 payload bytes ‖ the freshness value (4 bytes big-endian),
//! truncated to its 32 most significant bits as SecOC truncates.
//!
//! On classic CAN the cryptographic PDU travels as its own frame on the
//! secured frame's *authenticator id* (`*_AUTH` in `canodom.dbc`: base
//! +0x04, +0x14, +0x15, +0x16), sent right after the secured frame; a
//! receiver pairs it with the last secured frame of the linked id received
//! within [`PAIR_TIMEOUT_US`] (AUTOSAR's secured PDU collection with a
//! message link). On CAN FD the two travel together as one 16-byte frame on
//! the secured id: bytes 0..=7 the payload, 8..=15 the cryptographic PDU.
//!
//! # Freshness
//!
//! Each secured id has one sender in the DBC, and each sender keeps a
//! monotonic 32-bit counter per id, persisted before a value is used
//! ([`next_tx_freshness`] seeds it from the clock too). A receiver keeps the
//! last value it accepted per id, persisted *before* it acts on a frame
//! (write-ahead), and accepts a frame only if its freshness value is
//! greater ([`check_freshness`]): the acceptance window is `(last,
//! u32::MAX]`. A replay, at once or after a restart, is refused as
//! [`AuthFailure::Replayed`].
//!
//! Resynchronisation: a sender takes `max(own last + 1, Unix seconds)`, so
//! a sender that lost its counter file is ahead of every value it sent
//! before as soon as its clock has passed them (it sent at most one frame a
//! second on average); a sender whose clock is behind the receiver's mark
//! is refused as `Replayed`, the receiver logs its mark, and the sender
//! continues above it (`canodom calib --freshness-floor N`).
//!
//! # Lockout
//!
//! [`Lockout`] counts authentication failures; `max_failures` of them
//! within `window_us` lock every secured frame out for `duration_us`
//! (refused as [`AuthFailure::LockedOut`] without computing a MAC). Time is
//! an argument: the receiver passes the bus timestamps.

use aes::Aes128;
use canodom_can::frame::FrameId;
use cmac::{Cmac, Mac as _};

/// Bytes of the truncated MAC.
pub const MAC_LEN: usize = 4;

/// Bytes of the cryptographic PDU (freshness + MAC).
pub const AUTH_LEN: usize = 8;

/// Bytes of the authentic PDU (every secured frame is 8 bytes).
pub const PAYLOAD_LEN: usize = 8;

/// Length of a CAN FD frame carrying both PDUs.
pub const FD_LEN: usize = PAYLOAD_LEN + AUTH_LEN;

/// How long a secured frame waits for its authenticator frame, µs.
pub const PAIR_TIMEOUT_US: u64 = 100_000;

/// Bytes of an AES-128 key.
pub const KEY_LEN: usize = 16;

/// A 128-bit key. Its `Debug` shows no byte of it.
#[derive(Clone, PartialEq, Eq)]
pub struct Key([u8; KEY_LEN]);

impl std::fmt::Debug for Key {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Key(<redacted>)")
    }
}

/// Why a key file's text is not a key.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum KeyError {
    /// Not 32 hexadecimal digits.
    #[error("expected 32 hexadecimal digits (a 128-bit AES key) and nothing else, got {got}")]
    Malformed {
        /// What was found, without the key material: a length or a character class.
        got: String,
    },
    /// All bytes zero: a placeholder, not a key.
    #[error("the key is all zeros (a placeholder, not a secret)")]
    AllZero,
}

impl Key {
    /// A key from its bytes.
    pub fn from_bytes(bytes: [u8; KEY_LEN]) -> Self {
        Self(bytes)
    }

    /// Parses a key file's text: 32 hexadecimal digits, surrounding
    /// whitespace (a trailing newline) allowed, nothing else.
    ///
    /// # Errors
    /// [`KeyError`]; the message never repeats the text.
    pub fn parse(text: &str) -> Result<Self, KeyError> {
        let t = text.trim();
        if t.len() != 2 * KEY_LEN {
            return Err(KeyError::Malformed {
                got: format!("{} characters", t.chars().count()),
            });
        }
        if !t.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(KeyError::Malformed {
                got: "a character that is not a hexadecimal digit".into(),
            });
        }
        let mut key = [0u8; KEY_LEN];
        for (i, byte) in key.iter_mut().enumerate() {
            *byte =
                u8::from_str_radix(&t[2 * i..2 * i + 2], 16).map_err(|_| KeyError::Malformed {
                    got: "a character that is not a hexadecimal digit".into(),
                })?;
        }
        if key == [0; KEY_LEN] {
            return Err(KeyError::AllZero);
        }
        Ok(Self(key))
    }
}

/// The DataId of a frame id: 4 bytes big-endian, bit 31 for extended ids.
fn data_id(id: FrameId) -> [u8; 4] {
    match id {
        FrameId::Standard(s) => u32::from(s).to_be_bytes(),
        FrameId::Extended(e) => (e | 0x8000_0000).to_be_bytes(),
    }
}

/// CMAC-AES-128 with the key schedule and subkeys computed once.
#[derive(Clone)]
pub struct Authenticator {
    prepared: Cmac<Aes128>,
}

impl std::fmt::Debug for Authenticator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Authenticator(<key redacted>)")
    }
}

impl Authenticator {
    /// The authenticator of `key`.
    pub fn new(key: &Key) -> Self {
        Self {
            prepared: <Cmac<Aes128> as cmac::digest::KeyInit>::new(&key.0.into()),
        }
    }

    /// The truncated MAC of a secured frame (see the module doc).
    pub fn mac(&self, id: FrameId, payload: &[u8; PAYLOAD_LEN], freshness: u32) -> [u8; MAC_LEN] {
        let mut m = self.prepared.clone();
        let mut input = [0u8; 16];
        input[..4].copy_from_slice(&data_id(id));
        input[4..12].copy_from_slice(payload);
        input[12..].copy_from_slice(&freshness.to_be_bytes());
        m.update(&input);
        let full = m.finalize().into_bytes();
        let mut out = [0u8; MAC_LEN];
        out.copy_from_slice(&full[..MAC_LEN]);
        out
    }

    /// The cryptographic PDU of a secured frame sent with `freshness`.
    pub fn sign(&self, id: FrameId, payload: &[u8; PAYLOAD_LEN], freshness: u32) -> [u8; AUTH_LEN] {
        let mut out = [0u8; AUTH_LEN];
        out[..4].copy_from_slice(&freshness.to_le_bytes());
        out[4..].copy_from_slice(&self.mac(id, payload, freshness));
        out
    }

    /// Whether `auth` is the cryptographic PDU of `payload` at `id` (the
    /// MAC compared in constant time); freshness is not judged here.
    pub fn verify(&self, id: FrameId, payload: &[u8; PAYLOAD_LEN], auth: &[u8; AUTH_LEN]) -> bool {
        let (freshness, mac) = split_auth(auth);
        let expected = self.mac(id, payload, freshness);
        // Constant time: no early exit on the first differing byte.
        expected
            .iter()
            .zip(mac)
            .fold(0u8, |acc, (a, b)| acc | (a ^ b))
            == 0
    }
}

/// The freshness value and MAC of a cryptographic PDU.
pub fn split_auth(auth: &[u8; AUTH_LEN]) -> (u32, [u8; MAC_LEN]) {
    let mut fv = [0u8; 4];
    fv.copy_from_slice(&auth[..4]);
    let mut mac = [0u8; MAC_LEN];
    mac.copy_from_slice(&auth[4..]);
    (u32::from_le_bytes(fv), mac)
}

/// Why a secured frame was refused. Every refusal is counted by its kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AuthFailure {
    /// The MAC does not match: no key, a changed payload (a rolled counter
    /// and recomputed CRC), another id, or a guessed MAC.
    BadMac,
    /// The freshness value is not above the last accepted one: a replay, at
    /// once or after a restart, or a sender that fell behind.
    Replayed,
    /// A secured frame without its authenticator: a plain frame from a
    /// sender without the key, or its authenticator came too late.
    MissingAuthenticator,
    /// An authenticator frame with no secured frame to pair with.
    Unpaired,
    /// A secured or authenticator frame of the wrong length.
    BadLength,
    /// Refused unseen during a lockout.
    LockedOut,
    /// The freshness value could not be persisted: refused, since accepting
    /// it would let the frame be replayed after a restart.
    StoreFailed,
}

impl AuthFailure {
    /// Every reason, in [`Self::index`] order.
    pub const ALL: [Self; 7] = [
        Self::BadMac,
        Self::Replayed,
        Self::MissingAuthenticator,
        Self::Unpaired,
        Self::BadLength,
        Self::LockedOut,
        Self::StoreFailed,
    ];

    /// Position in [`Self::ALL`], for counters.
    pub fn index(self) -> usize {
        match self {
            Self::BadMac => 0,
            Self::Replayed => 1,
            Self::MissingAuthenticator => 2,
            Self::Unpaired => 3,
            Self::BadLength => 4,
            Self::LockedOut => 5,
            Self::StoreFailed => 6,
        }
    }

    /// The name in logs and the statistics line.
    pub fn name(self) -> &'static str {
        match self {
            Self::BadMac => "bad_mac",
            Self::Replayed => "replayed",
            Self::MissingAuthenticator => "missing_authenticator",
            Self::Unpaired => "unpaired_authenticator",
            Self::BadLength => "bad_length",
            Self::LockedOut => "locked_out",
            Self::StoreFailed => "freshness_store_failed",
        }
    }

    /// Whether it counts towards the lockout (every failure an attacker can
    /// cause by sending, not the refusals of the lockout itself nor a disk
    /// failure).
    pub fn counts_for_lockout(self) -> bool {
        !matches!(self, Self::LockedOut | Self::StoreFailed)
    }
}

impl std::fmt::Display for AuthFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The acceptance window: a frame is fresh when its value is above the
/// last accepted one (any value when none was accepted yet).
///
/// # Errors
/// [`AuthFailure::Replayed`].
pub fn check_freshness(last_accepted: Option<u32>, freshness: u32) -> Result<(), AuthFailure> {
    match last_accepted {
        Some(last) if freshness <= last => Err(AuthFailure::Replayed),
        _ => Ok(()),
    }
}

/// A sender's next freshness value: above the last one it used, and at
/// least the Unix time in seconds (the resynchronisation of a sender that
/// lost its counter; see the module doc). `None` when the counter is spent.
pub fn next_tx_freshness(last_used: Option<u32>, unix_s: u64) -> Option<u32> {
    let clock = u32::try_from(unix_s).unwrap_or(u32::MAX);
    match last_used {
        None => Some(clock.max(1)),
        Some(u32::MAX) => None,
        Some(last) => Some((last + 1).max(clock)),
    }
}

/// Lockout after too many failures in a window (pure: time is an argument).
#[derive(Debug, Clone)]
pub struct Lockout {
    max_failures: usize,
    window_us: u64,
    duration_us: u64,
    /// Times of the last `max_failures` counted failures, oldest first.
    recent: std::collections::VecDeque<u64>,
    /// End of the lockout in force, if any.
    until_us: Option<u64>,
    /// Lockouts started so far.
    trips: u64,
}

impl Lockout {
    /// `max_failures` (≥ 1) within `window_us` lock out for `duration_us`.
    pub fn new(max_failures: u32, window_us: u64, duration_us: u64) -> Self {
        let n = max_failures.max(1) as usize;
        Self {
            max_failures: n,
            window_us,
            duration_us,
            recent: std::collections::VecDeque::with_capacity(n.min(64)),
            until_us: None,
            trips: 0,
        }
    }

    /// Whether secured frames are locked out at `now_us`.
    pub fn is_locked(&self, now_us: u64) -> bool {
        self.until_us.is_some_and(|until| now_us < until)
    }

    /// Lockouts started since start.
    pub fn trips(&self) -> u64 {
        self.trips
    }

    /// Counts a failure at `now_us`; true when it starts a lockout.
    pub fn record_failure(&mut self, now_us: u64) -> bool {
        if self.is_locked(now_us) {
            return false;
        }
        if self.recent.len() == self.max_failures {
            self.recent.pop_front();
        }
        self.recent.push_back(now_us);
        let oldest = self.recent.front().copied().unwrap_or(now_us);
        if self.recent.len() == self.max_failures && now_us.saturating_sub(oldest) <= self.window_us
        {
            self.until_us = Some(now_us.saturating_add(self.duration_us));
            self.recent.clear();
            self.trips += 1;
            return true;
        }
        false
    }
}

/// What the receiver decided about one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Not a secured or authenticator id: handle it as before.
    NotSecured,
    /// A secured frame held until its authenticator arrives.
    Held,
    /// Authenticated and fresh (its freshness value already persisted):
    /// handle `payload` as a frame at `id`.
    Accepted {
        /// The secured frame's id.
        id: FrameId,
        /// Its payload.
        payload: [u8; PAYLOAD_LEN],
        /// Its freshness value.
        freshness: u32,
    },
    /// Refused.
    Refused(AuthFailure),
}

/// A secured id and the id of its authenticator frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Link {
    /// The secured frame's id.
    pub secured: FrameId,
    /// Its authenticator frame's id (classic CAN).
    pub authenticator: FrameId,
}

#[derive(Debug, Clone)]
struct RxLink {
    link: Link,
    last_accepted: Option<u32>,
    /// A secured frame waiting for its authenticator: arrival time, payload.
    pending: Option<(u64, [u8; PAYLOAD_LEN])>,
}

/// Refusal counts by reason.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FailureCounts(pub [u64; AuthFailure::ALL.len()]);

impl FailureCounts {
    /// The count of one reason.
    pub fn of(&self, reason: AuthFailure) -> u64 {
        self.0[reason.index()]
    }

    /// All refusals.
    pub fn total(&self) -> u64 {
        self.0.iter().sum()
    }
}

impl std::fmt::Display for FailureCounts {
    /// `reason=count` for each non-zero reason, `0` when none.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut any = false;
        for r in AuthFailure::ALL {
            let n = self.of(r);
            if n > 0 {
                if any {
                    f.write_str(" ")?;
                }
                write!(f, "{r}={n}")?;
                any = true;
            }
        }
        if !any {
            f.write_str("0")?;
        }
        Ok(())
    }
}

/// The receiving end: pairs, verifies, judges freshness, locks out, counts.
#[derive(Debug, Clone)]
pub struct Receiver {
    auth: Authenticator,
    links: Vec<RxLink>,
    lockout: Lockout,
    counts: FailureCounts,
}

impl Receiver {
    /// A receiver of `links`, each with the last freshness value accepted
    /// before (from the persisted store; `None` for a fresh start).
    pub fn new(key: &Key, links: &[(Link, Option<u32>)], lockout: Lockout) -> Self {
        Self {
            auth: Authenticator::new(key),
            links: links
                .iter()
                .map(|&(link, last_accepted)| RxLink {
                    link,
                    last_accepted,
                    pending: None,
                })
                .collect(),
            lockout,
            counts: FailureCounts::default(),
        }
    }

    /// Refusals so far, by reason.
    pub fn counts(&self) -> FailureCounts {
        self.counts
    }

    /// Whether secured frames are locked out at `now_us`.
    pub fn is_locked(&self, now_us: u64) -> bool {
        self.lockout.is_locked(now_us)
    }

    /// Lockouts started since start.
    pub fn lockouts(&self) -> u64 {
        self.lockout.trips()
    }

    /// The last accepted freshness value of a secured id (or of the secured
    /// id an authenticator id belongs to).
    pub fn last_accepted(&self, id: FrameId) -> Option<u32> {
        self.links
            .iter()
            .find(|l| l.link.secured == id || l.link.authenticator == id)
            .and_then(|l| l.last_accepted)
    }

    fn refuse(&mut self, now_us: u64, reason: AuthFailure) -> Verdict {
        self.counts.0[reason.index()] += 1;
        if reason.counts_for_lockout() {
            self.lockout.record_failure(now_us);
        }
        Verdict::Refused(reason)
    }

    /// Secured frames that waited longer than [`PAIR_TIMEOUT_US`] are
    /// refused as [`AuthFailure::MissingAuthenticator`]; returns how many.
    pub fn expire(&mut self, now_us: u64) -> usize {
        let mut n = 0;
        for i in 0..self.links.len() {
            if let Some((t, _)) = self.links[i].pending
                && now_us.saturating_sub(t) > PAIR_TIMEOUT_US
            {
                self.links[i].pending = None;
                self.refuse(now_us, AuthFailure::MissingAuthenticator);
                n += 1;
            }
        }
        n
    }

    /// Judges one received frame at bus time `now_us`. `persist` stores a
    /// secured id's new last-accepted freshness value durably; it is called
    /// before a frame is accepted, and a failure refuses the frame
    /// (write-ahead: a crash can never re-open a value once acted on).
    pub fn on_frame<E>(
        &mut self,
        now_us: u64,
        id: FrameId,
        data: &[u8],
        persist: impl FnOnce(FrameId, u32) -> Result<(), E>,
    ) -> Verdict {
        self.expire(now_us);
        if let Some(i) = self.links.iter().position(|l| l.link.secured == id) {
            if self.lockout.is_locked(now_us) {
                self.links[i].pending = None;
                return self.refuse(now_us, AuthFailure::LockedOut);
            }
            return match data.len() {
                PAYLOAD_LEN => {
                    let mut payload = [0u8; PAYLOAD_LEN];
                    payload.copy_from_slice(data);
                    if self.links[i].pending.replace((now_us, payload)).is_some() {
                        // The previous one never got its authenticator.
                        self.refuse(now_us, AuthFailure::MissingAuthenticator);
                    }
                    Verdict::Held
                }
                FD_LEN => {
                    let mut payload = [0u8; PAYLOAD_LEN];
                    payload.copy_from_slice(&data[..PAYLOAD_LEN]);
                    let mut auth = [0u8; AUTH_LEN];
                    auth.copy_from_slice(&data[PAYLOAD_LEN..]);
                    self.judge(now_us, i, payload, auth, persist)
                }
                _ => self.refuse(now_us, AuthFailure::BadLength),
            };
        }
        let Some(i) = self.links.iter().position(|l| l.link.authenticator == id) else {
            return Verdict::NotSecured;
        };
        if self.lockout.is_locked(now_us) {
            self.links[i].pending = None;
            return self.refuse(now_us, AuthFailure::LockedOut);
        }
        let Ok(auth) = <[u8; AUTH_LEN]>::try_from(data) else {
            return self.refuse(now_us, AuthFailure::BadLength);
        };
        let Some((_, payload)) = self.links[i].pending.take() else {
            return self.refuse(now_us, AuthFailure::Unpaired);
        };
        self.judge(now_us, i, payload, auth, persist)
    }

    fn judge<E>(
        &mut self,
        now_us: u64,
        i: usize,
        payload: [u8; PAYLOAD_LEN],
        auth: [u8; AUTH_LEN],
        persist: impl FnOnce(FrameId, u32) -> Result<(), E>,
    ) -> Verdict {
        let id = self.links[i].link.secured;
        if !self.auth.verify(id, &payload, &auth) {
            return self.refuse(now_us, AuthFailure::BadMac);
        }
        let (freshness, _) = split_auth(&auth);
        if let Err(reason) = check_freshness(self.links[i].last_accepted, freshness) {
            return self.refuse(now_us, reason);
        }
        if persist(id, freshness).is_err() {
            return self.refuse(now_us, AuthFailure::StoreFailed);
        }
        self.links[i].last_accepted = Some(freshness);
        Verdict::Accepted {
            id,
            payload,
            freshness,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const KEY_HEX: &str = "2b7e151628aed2a6abf7158809cf4f3c";

    fn key() -> Key {
        Key::parse(KEY_HEX).unwrap()
    }

    fn link() -> Link {
        Link {
            secured: FrameId::Standard(0x610),
            authenticator: FrameId::Standard(0x614),
        }
    }

    fn receiver(last: Option<u32>) -> Receiver {
        Receiver::new(
            &key(),
            &[(link(), last)],
            Lockout::new(10, 1_000_000, 60_000_000),
        )
    }

    /// A store that always succeeds (the `persist` argument's shape).
    #[allow(clippy::unnecessary_wraps)]
    fn ok(_: FrameId, _: u32) -> Result<(), ()> {
        Ok(())
    }

    /// A secured payload and its authenticator at `fv`.
    fn signed(payload: [u8; 8], fv: u32) -> [u8; 8] {
        Authenticator::new(&key()).sign(link().secured, &payload, fv)
    }

    fn send(rx: &mut Receiver, t: u64, payload: [u8; 8], auth: [u8; 8]) -> Verdict {
        assert_eq!(rx.on_frame(t, link().secured, &payload, ok), Verdict::Held);
        rx.on_frame(t + 100, link().authenticator, &auth, ok)
    }

    #[test]
    fn auth_cmac_matches_the_nist_sp800_38b_vector_and_our_input_layout() {
        // SP 800-38B D.1 example 2 (16-byte message) with the same key:
        // CMAC = 070a16b4 6b4d4144 f79bdd9d d04a287c.
        let m = hex16("6bc1bee22e409f96e93d7e117393172a");
        let mut c = <Cmac<Aes128> as cmac::digest::KeyInit>::new(&key().0.into());
        c.update(&m);
        let full = c.finalize().into_bytes();
        assert_eq!(full.as_slice(), hex16("070a16b46b4d4144f79bdd9dd04a287c"));
        // Our MAC is the first 4 bytes of the CMAC of DataId ‖ payload ‖ FV:
        // the extended id 0x0bc1bee2 with bit 31 set is 8b c1 be e2.
        let mut m2 = m;
        m2[0] = 0x8B;
        let mut c = <Cmac<Aes128> as cmac::digest::KeyInit>::new(&key().0.into());
        c.update(&m2);
        let expected = c.finalize().into_bytes();
        let payload: [u8; 8] = m[4..12].try_into().unwrap();
        let fv = u32::from_be_bytes(m[12..].try_into().unwrap());
        let a = Authenticator::new(&key());
        let ext = FrameId::Extended(0x0bc1_bee2);
        assert_eq!(a.mac(ext, &payload, fv), expected[..4]);
        let auth = a.sign(ext, &payload, fv);
        assert_eq!(auth[..4], fv.to_le_bytes());
        assert_eq!(auth[4..], expected[..4]);
    }

    fn hex16(s: &str) -> [u8; 16] {
        Key::parse(s).unwrap().0
    }

    #[test]
    fn auth_a_signed_command_is_accepted_once_and_its_replay_refused() {
        let mut rx = receiver(None);
        let payload = [1, 0xC0, 0x30, 0x50, 0, 0, 0x10, 0xF4];
        let auth = signed(payload, 1000);
        assert_eq!(
            send(&mut rx, 0, payload, auth),
            Verdict::Accepted {
                id: link().secured,
                payload,
                freshness: 1000
            }
        );
        // The same pair again, at once and an hour later.
        assert_eq!(
            send(&mut rx, 10, payload, auth),
            Verdict::Refused(AuthFailure::Replayed)
        );
        assert_eq!(
            send(&mut rx, 3_600_000_000, payload, auth),
            Verdict::Refused(AuthFailure::Replayed)
        );
        // An older value signed with the key is stale too; a newer one passes.
        assert_eq!(
            send(&mut rx, 3_600_000_300, payload, signed(payload, 999)),
            Verdict::Refused(AuthFailure::Replayed)
        );
        assert!(matches!(
            send(&mut rx, 3_600_000_600, payload, signed(payload, 1001)),
            Verdict::Accepted { .. }
        ));
        assert_eq!(rx.counts().of(AuthFailure::Replayed), 3);
    }

    #[test]
    fn auth_a_rolled_counter_with_a_recomputed_crc_is_refused_without_the_key() {
        let mut rx = receiver(None);
        let payload = [1, 0xC0, 0x30, 0x50, 0, 0, 0x10, 0xF4];
        let auth = signed(payload, 7);
        let mut rolled = payload;
        rolled[6] = 0x20; // counter 1 → 2
        let crc = canodom_dbc::Checksum::rc_car();
        let _ = crc.apply(&mut rolled);
        assert_ne!(rolled, payload);
        // With the original authenticator, and with a fresher freshness value
        // that the attacker can write but not MAC.
        assert_eq!(
            send(&mut rx, 0, rolled, auth),
            Verdict::Refused(AuthFailure::BadMac)
        );
        let mut later = auth;
        later[..4].copy_from_slice(&8u32.to_le_bytes());
        assert_eq!(
            send(&mut rx, 200, rolled, later),
            Verdict::Refused(AuthFailure::BadMac)
        );
        // Another key signs nothing this receiver accepts.
        let other = Authenticator::new(&Key::from_bytes([7; 16])).sign(link().secured, &rolled, 9);
        assert_eq!(
            send(&mut rx, 400, rolled, other),
            Verdict::Refused(AuthFailure::BadMac)
        );
        assert_eq!(rx.counts().of(AuthFailure::BadMac), 3);
    }

    /// splitmix64: reproducible random MACs without a dependency.
    fn splitmix(state: &mut u64) -> u64 {
        *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = *state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    #[test]
    fn auth_a_million_random_macs_are_never_accepted_and_trip_the_lockout() {
        let payload = [6, 0, 0, 0, 0, 0, 0x50, 0x07];
        let mut seed = 22u64;
        // No lockout in the way: every one of them is verified.
        let mut open = Receiver::new(&key(), &[(link(), None)], Lockout::new(u32::MAX, 0, 0));
        let mut accepted = 0;
        for k in 0..1_000_000u64 {
            let r = splitmix(&mut seed);
            let mut auth = [0u8; 8];
            auth[..4].copy_from_slice(&(k as u32 + 1).to_le_bytes());
            auth[4..].copy_from_slice(&(r as u32).to_le_bytes());
            if matches!(
                send(&mut open, k * 1000, payload, auth),
                Verdict::Accepted { .. }
            ) {
                accepted += 1;
            }
        }
        assert_eq!(accepted, 0);
        assert_eq!(open.counts().of(AuthFailure::BadMac), 1_000_000);
        // With a lockout of 10 failures in 1 s for 60 s: it trips, and the
        // rest are refused unseen; none is accepted either way.
        let mut rx = receiver(None);
        for k in 0..1_000_000u64 {
            let r = splitmix(&mut seed);
            let mut auth = [0u8; 8];
            auth[..4].copy_from_slice(&(k as u32 + 1).to_le_bytes());
            auth[4..].copy_from_slice(&(r as u32).to_le_bytes());
            let _ = rx.on_frame(k * 1000, link().secured, &payload, ok);
            let v = rx.on_frame(k * 1000 + 100, link().authenticator, &auth, ok);
            assert!(!matches!(v, Verdict::Accepted { .. }));
        }
        let c = rx.counts();
        // 1,000 s of attack: a lockout every 60 s plus the 10 ms to trip it.
        assert_eq!(rx.lockouts(), 17, "{c}");
        // 10 failures per lockout; when a lockout ends between a secured
        // frame (refused unseen) and its authenticator, that one is unpaired.
        assert_eq!(
            c.of(AuthFailure::BadMac) + c.of(AuthFailure::Unpaired),
            170,
            "{c}"
        );
        assert!(c.of(AuthFailure::LockedOut) > 1_900_000, "{c}");
        // A valid command during the lockout is refused too, and passes after it.
        let t = 1_000_000_000;
        assert!(rx.is_locked(t));
        let good = signed(payload, 5_000_000);
        assert_eq!(
            rx.on_frame(t, link().secured, &payload, ok),
            Verdict::Refused(AuthFailure::LockedOut)
        );
        let until = (0..100)
            .map(|s| t + s * 1_000_000)
            .find(|&x| !rx.is_locked(x))
            .unwrap();
        assert!(matches!(
            send(&mut rx, until, payload, good),
            Verdict::Accepted { .. }
        ));
    }

    #[test]
    fn auth_a_frame_accepted_before_a_restart_is_refused_after_it() {
        let payload = [7, 0, 0, 0, 0, 0, 0x60, 0x10];
        let auth = signed(payload, 4242);
        let mut stored = None;
        let mut before = receiver(None);
        assert_eq!(
            before.on_frame(0, link().secured, &payload, ok),
            Verdict::Held
        );
        let v = before.on_frame(50, link().authenticator, &auth, |_, fv| {
            stored = Some(fv);
            Ok::<(), ()>(())
        });
        assert!(matches!(v, Verdict::Accepted { .. }));
        // The restart: a new receiver from what was persisted.
        let mut after = receiver(stored);
        assert_eq!(
            send(&mut after, 0, payload, auth),
            Verdict::Refused(AuthFailure::Replayed)
        );
    }

    #[test]
    fn auth_a_frame_whose_freshness_cannot_be_stored_is_refused_and_not_remembered() {
        let payload = [7, 0, 0, 0, 0, 0, 0x60, 0x10];
        let auth = signed(payload, 10);
        let mut rx = receiver(None);
        assert_eq!(rx.on_frame(0, link().secured, &payload, ok), Verdict::Held);
        let v = rx.on_frame(1, link().authenticator, &auth, |_, _| Err("disk full"));
        assert_eq!(v, Verdict::Refused(AuthFailure::StoreFailed));
        assert_eq!(rx.last_accepted(link().secured), None);
        assert!(matches!(
            send(&mut rx, 5, payload, auth),
            Verdict::Accepted { .. }
        ));
    }

    #[test]
    fn auth_plain_unpaired_late_and_short_frames_are_refused_by_reason() {
        let mut rx = receiver(None);
        let payload = [9, 0, 0, 0, 0, 0, 0x90, 0x6E];
        // A plain frame superseded by another: the first lacked its authenticator.
        assert_eq!(rx.on_frame(0, link().secured, &payload, ok), Verdict::Held);
        assert_eq!(rx.on_frame(10, link().secured, &payload, ok), Verdict::Held);
        // The second one times out on the next frame after the pairing window.
        assert_eq!(
            rx.on_frame(
                10 + PAIR_TIMEOUT_US + 1,
                FrameId::Standard(0x100),
                &[0; 8],
                ok
            ),
            Verdict::NotSecured
        );
        // A valid authenticator with nothing to pair with.
        let auth = signed(payload, 3);
        assert_eq!(
            rx.on_frame(200_000, link().authenticator, &auth, ok),
            Verdict::Refused(AuthFailure::Unpaired)
        );
        // A late authenticator: its frame expired first.
        assert_eq!(
            rx.on_frame(300_000, link().secured, &payload, ok),
            Verdict::Held
        );
        assert_eq!(
            rx.on_frame(
                300_000 + PAIR_TIMEOUT_US + 5,
                link().authenticator,
                &auth,
                ok
            ),
            Verdict::Refused(AuthFailure::Unpaired)
        );
        assert_eq!(
            rx.on_frame(600_000, link().authenticator, &auth[..7], ok),
            Verdict::Refused(AuthFailure::BadLength)
        );
        let c = rx.counts();
        assert_eq!(c.of(AuthFailure::MissingAuthenticator), 3, "{c}");
        assert_eq!(c.of(AuthFailure::Unpaired), 2, "{c}");
        assert_eq!(c.of(AuthFailure::BadLength), 1, "{c}");
        assert_eq!(
            c.to_string(),
            "missing_authenticator=3 unpaired_authenticator=2 bad_length=1"
        );
    }

    #[test]
    fn auth_a_can_fd_frame_carries_both_pdus() {
        let mut rx = receiver(None);
        let payload = [2, 0, 0, 0, 0, 0, 0x20, 0x37];
        let mut fd = payload.to_vec();
        fd.extend_from_slice(&signed(payload, 77));
        assert!(matches!(
            rx.on_frame(0, link().secured, &fd, ok),
            Verdict::Accepted { freshness: 77, .. }
        ));
        assert_eq!(
            rx.on_frame(1, link().secured, &fd, ok),
            Verdict::Refused(AuthFailure::Replayed)
        );
        assert_eq!(
            rx.on_frame(2, link().secured, &fd[..12], ok),
            Verdict::Refused(AuthFailure::BadLength)
        );
    }

    #[test]
    fn auth_the_mac_binds_the_frame_id() {
        let a = Authenticator::new(&key());
        let p = [0u8; 8];
        let auth = a.sign(FrameId::Standard(0x603), &p, 1);
        assert!(a.verify(FrameId::Standard(0x603), &p, &auth));
        assert!(!a.verify(FrameId::Standard(0x610), &p, &auth));
        assert!(!a.verify(FrameId::Extended(0x603), &p, &auth));
    }

    #[test]
    fn auth_key_text_is_32_hex_digits_and_errors_never_echo_it() {
        assert_eq!(Key::parse(&format!("{KEY_HEX}\n")).unwrap(), key());
        assert_eq!(Key::parse(&KEY_HEX.to_uppercase()).unwrap(), key());
        let short = Key::parse(&KEY_HEX[..30]).unwrap_err();
        assert!(short.to_string().contains("30 characters"), "{short}");
        let bad = format!("{}zz", &KEY_HEX[..30]);
        let e = Key::parse(&bad).unwrap_err().to_string();
        assert!(
            e.contains("not a hexadecimal digit") && !e.contains(&bad[..8]),
            "{e}"
        );
        assert_eq!(Key::parse(&"0".repeat(32)), Err(KeyError::AllZero));
        assert!(!format!("{:?}", key()).contains("2b7e"));
        assert!(!format!("{:?}", Authenticator::new(&key())).contains("2b7e"));
    }

    #[test]
    fn auth_sender_freshness_is_monotonic_and_seeded_by_the_clock() {
        assert_eq!(next_tx_freshness(None, 1_700_000_000), Some(1_700_000_000));
        assert_eq!(next_tx_freshness(Some(5), 0), Some(6));
        // A sender that lost its counter catches up with its clock.
        assert_eq!(
            next_tx_freshness(Some(10), 1_700_000_000),
            Some(1_700_000_000)
        );
        assert_eq!(
            next_tx_freshness(Some(1_700_000_000), 1_700_000_000),
            Some(1_700_000_001)
        );
        assert_eq!(next_tx_freshness(Some(u32::MAX), 0), None);
        assert_eq!(next_tx_freshness(None, 0), Some(1));
    }

    #[test]
    fn auth_lockout_needs_n_failures_within_the_window_and_ends() {
        let mut l = Lockout::new(3, 1_000, 5_000);
        assert!(!l.record_failure(0));
        assert!(!l.record_failure(600));
        // Third failure 1,200 µs after the first: outside the window.
        assert!(!l.record_failure(1_200));
        assert!(!l.is_locked(1_200));
        assert!(
            l.record_failure(1_500),
            "600, 1200, 1500 lie within 1000 µs"
        );
        assert!(l.is_locked(1_500) && l.is_locked(6_499));
        assert!(
            !l.record_failure(2_000),
            "failures during a lockout do not extend it"
        );
        assert!(!l.is_locked(6_500));
        assert_eq!(l.trips(), 1);
    }

    proptest! {
        #![proptest_config(ProptestConfig { failure_persistence: None, ..ProptestConfig::default() })]

        /// Any change to the payload, the freshness value or the MAC is refused.
        #[test]
        fn auth_any_flipped_bit_is_refused(payload in any::<[u8; 8]>(), fv in 1u32.., bit in 0usize..128) {
            let a = Authenticator::new(&key());
            let auth = a.sign(link().secured, &payload, fv);
            let mut p = payload;
            let mut x = auth;
            if bit < 64 { p[bit / 8] ^= 1 << (bit % 8); } else { x[(bit - 64) / 8] ^= 1 << (bit % 8); }
            prop_assert!(a.verify(link().secured, &payload, &auth));
            prop_assert!(!a.verify(link().secured, &p, &x));
        }
    }
}
