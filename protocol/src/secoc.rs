//! Authenticated commands and write-back in the manner of AUTOSAR SecOC
//! (issues #22, #33): a truncated CMAC-AES-128 over the frame id, the
//! payload and a freshness value bound to time, with a key per message and
//! direction ([`crate::secoc_keys`]) that never travels on the bus.
//!
//! # The profile ("canodom SecOC profile 2")
//!
//! A *secured* frame is one of `ODOM_CMD`, `CALIB_CMD`, `CALIB_PARAMS` and
//! `CALIB_ACK`. Its 8-byte payload (the *authentic PDU*: the frame as it was
//! before, with its rolling counter and CRC-8) is unchanged, so every tool
//! that decodes it still does. The *cryptographic PDU* is 8 bytes:
//!
//! | bytes | signal | content |
//! |---|---|---|
//! | 0..=3 | `FRESHNESS` (bits 0..31, Intel) | the low 32 bits of the freshness value, little-endian |
//! | 4..=7 | `MAC` (bits 32..63, Intel) | the first 4 bytes of the CMAC, in CMAC order |
//!
//! The MAC is CMAC-AES-128 (NIST SP 800-38B) over *DataToAuthenticator* =
//! the secured frame's id (4 bytes big-endian, bit 31 set for an extended
//! id) ‖ the 8 payload bytes ‖ the **full 64-bit** freshness value (8
//! bytes big-endian), truncated to its 32 most significant bits as SecOC
//! truncates.
//!
//! On classic CAN the cryptographic PDU travels as its own frame on the
//! secured frame's *authenticator id* (`*_AUTH` in `canodom.dbc`: base
//! +0x04, +0x14, +0x15, +0x16), sent right after the secured frame. A
//! receiver keeps up to [`MAX_PENDING`] secured frames of the linked id
//! received within [`PAIR_TIMEOUT_US`] and pairs an authenticator with the
//! one whose MAC it matches, so a plain frame slipped in between a command
//! and its authenticator neither replaces the command nor makes its
//! authenticator fail. On CAN FD the two travel together as one 16-byte
//! frame on the secured id: bytes 0..=7 the payload, 8..=15 the
//! cryptographic PDU.
//!
//! # Freshness: bound to time, used once
//!
//! As in the Toyota scheme (opendbc `car/secoc.py`), the frame carries only
//! the low bits of a longer freshness value and the MAC covers all of it.
//! The freshness value is the sender's clock in **milliseconds since the
//! Unix epoch**, made unique per id by `max(last + 1, now)`
//! ([`next_tx_freshness`]). The receiver rebuilds the full value as the one
//! nearest its own clock with those low 32 bits ([`reconstruct`]; they wrap
//! every 49.7 days, far beyond any window) and accepts it only
//! ([`check_freshness`])
//!
//! - within `±window` of its own clock (default [`DEFAULT_WINDOW_MS`]):
//!   a frame recorded earlier — a command kept from its receiver, a signed
//!   `--print-frame` line, a two-year-old recording — is refused as
//!   [`AuthFailure::Stale`] once the window has passed, whatever the
//!   receiver remembers; a value recorded 49.7·k days ago rebuilds to
//!   today's and fails its MAC;
//! - above the last value accepted on that id, kept durably *before* the
//!   frame is acted on (write-ahead): a replay inside the window, at once
//!   or after a restart, is refused as [`AuthFailure::Replayed`].
//!
//! A remembered value further ahead than the window (a receiver clock that
//! was wrong and has been corrected) is brought back to `now + window`, so
//! it refuses new frames for at most one window instead of for good.
//! Senders and receiver need clocks within the window of each other (NTP,
//! or the vehicle's time master).
//!
//! # Lockout
//!
//! Only a MAC that does not match counts as a failure (a guess at the MAC);
//! unpaired, late, stale or short frames are refused and counted but cannot
//! be guesses. [`Lockout`] is kept per secured id: `max_failures` bad MACs
//! on one id within `window_us` lock that id out for `duration_us`
//! (refused as [`AuthFailure::LockedOut`] without computing a MAC); other
//! ids go on. An id marked `lockable = false` (`CALIB_ACK`, whose sender is
//! the parameter store) is never locked. Time is an argument: the receiver
//! passes the bus timestamps (kernel receive time, Unix epoch).

use aes::Aes128;
use canodom_can::frame::FrameId;
use cmac::{Cmac, Mac as _};
use zeroize::{Zeroize as _, ZeroizeOnDrop};

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

/// Secured frames of one id waiting for their authenticator at once: the
/// command and up to three frames slipped in after it within
/// [`PAIR_TIMEOUT_US`].
pub const MAX_PENDING: usize = 4;

/// The default acceptance window around the receiver's clock, ms.
pub const DEFAULT_WINDOW_MS: u64 = 5_000;

/// How far ahead of its clock a sender's remembered counter may be before
/// the sender drops it and starts again from its clock, ms (a counter
/// further ahead would only be refused as stale).
pub const MAX_SENDER_LEAD_MS: u64 = 60_000;

/// Bytes of an AES-128 key.
pub const KEY_LEN: usize = 16;

/// A 128-bit key. Its `Debug` shows no byte of it; wiped when dropped.
#[derive(Clone, PartialEq, Eq, ZeroizeOnDrop)]
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

    /// The key's bytes (to write a key file).
    pub fn bytes(&self) -> &[u8; KEY_LEN] {
        &self.0
    }

    /// Parses 32 hexadecimal digits, surrounding whitespace (a trailing
    /// newline) allowed, nothing else.
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
        let mut key = Self([0u8; KEY_LEN]);
        for (i, byte) in key.0.iter_mut().enumerate() {
            *byte =
                u8::from_str_radix(&t[2 * i..2 * i + 2], 16).map_err(|_| KeyError::Malformed {
                    got: "a character that is not a hexadecimal digit".into(),
                })?;
        }
        if key.0 == [0; KEY_LEN] {
            return Err(KeyError::AllZero);
        }
        Ok(key)
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
        let mut bytes = key.0;
        let prepared = <Cmac<Aes128> as cmac::digest::KeyInit>::new(&bytes.into());
        bytes.zeroize();
        Self { prepared }
    }

    /// The truncated MAC of a secured frame with the full freshness value
    /// (see the module doc).
    pub fn mac(&self, id: FrameId, payload: &[u8; PAYLOAD_LEN], freshness: u64) -> [u8; MAC_LEN] {
        let mut m = self.prepared.clone();
        let mut input = [0u8; 20];
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
    pub fn sign(&self, id: FrameId, payload: &[u8; PAYLOAD_LEN], freshness: u64) -> [u8; AUTH_LEN] {
        let mut out = [0u8; AUTH_LEN];
        out[..4].copy_from_slice(&(freshness as u32).to_le_bytes());
        out[4..].copy_from_slice(&self.mac(id, payload, freshness));
        out
    }

    /// Whether `mac` is the MAC of `payload` at `id` with the full
    /// `freshness` value (compared in constant time); freshness is not
    /// judged here.
    pub fn verify_full(
        &self,
        id: FrameId,
        payload: &[u8; PAYLOAD_LEN],
        freshness: u64,
        mac: &[u8; MAC_LEN],
    ) -> bool {
        let expected = self.mac(id, payload, freshness);
        // Constant time: no early exit on the first differing byte.
        expected
            .iter()
            .zip(mac)
            .fold(0u8, |acc, (a, b)| acc | (a ^ b))
            == 0
    }

    /// Whether `auth` is the cryptographic PDU of `payload` at `id`, its
    /// freshness rebuilt around `now_ms` ([`reconstruct`]).
    pub fn verify(
        &self,
        id: FrameId,
        payload: &[u8; PAYLOAD_LEN],
        auth: &[u8; AUTH_LEN],
        now_ms: u64,
    ) -> bool {
        let (low, mac) = split_auth(auth);
        self.verify_full(id, payload, reconstruct(low, now_ms), &mac)
    }
}

/// The transmitted low 32 bits of the freshness value and the MAC of a
/// cryptographic PDU.
pub fn split_auth(auth: &[u8; AUTH_LEN]) -> (u32, [u8; MAC_LEN]) {
    let mut fv = [0u8; 4];
    fv.copy_from_slice(&auth[..4]);
    let mut mac = [0u8; MAC_LEN];
    mac.copy_from_slice(&auth[4..]);
    (u32::from_le_bytes(fv), mac)
}

/// The full freshness value nearest the receiver's clock `now_ms` whose
/// low 32 bits are `low` (the Toyota scheme's reconstruction: the frame
/// carries the low bits, the receiver supplies the rest).
pub fn reconstruct(low: u32, now_ms: u64) -> u64 {
    const SPAN: u64 = 1 << 32;
    let base = now_ms & !(SPAN - 1);
    let candidates = [
        base.checked_sub(SPAN).map(|b| b | u64::from(low)),
        Some(base | u64::from(low)),
        base.checked_add(SPAN).map(|b| b | u64::from(low)),
    ];
    candidates
        .into_iter()
        .flatten()
        .min_by_key(|c| c.abs_diff(now_ms))
        .unwrap_or(u64::from(low))
}

/// Why a secured frame was refused. Every refusal is counted by its kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AuthFailure {
    /// The MAC does not match: no key, another role's or vehicle's key, a
    /// changed payload (a rolled counter and recomputed CRC), another id,
    /// or a guessed MAC. The only reason that counts towards the lockout.
    BadMac,
    /// Inside the window but not above the last accepted value: a replay,
    /// at once or after a restart.
    Replayed,
    /// Outside the window around the receiver's clock: recorded earlier (a
    /// kept-back command, an old recording) or a sender whose clock is off.
    Stale,
    /// A secured frame without its authenticator: a plain frame from a
    /// sender without the key, or its authenticator came too late.
    MissingAuthenticator,
    /// An authenticator frame with no secured frame to pair with.
    Unpaired,
    /// A secured or authenticator frame of the wrong length.
    BadLength,
    /// Refused unseen while its id is locked out.
    LockedOut,
    /// The freshness value could not be persisted: refused, since accepting
    /// it would let the frame be replayed after a restart.
    StoreFailed,
}

impl AuthFailure {
    /// Every reason, in [`Self::index`] order.
    pub const ALL: [Self; 8] = [
        Self::BadMac,
        Self::Replayed,
        Self::Stale,
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
            Self::Stale => 2,
            Self::MissingAuthenticator => 3,
            Self::Unpaired => 4,
            Self::BadLength => 5,
            Self::LockedOut => 6,
            Self::StoreFailed => 7,
        }
    }

    /// The name in logs and the statistics line.
    pub fn name(self) -> &'static str {
        match self {
            Self::BadMac => "bad_mac",
            Self::Replayed => "replayed",
            Self::Stale => "stale",
            Self::MissingAuthenticator => "missing_authenticator",
            Self::Unpaired => "unpaired_authenticator",
            Self::BadLength => "bad_length",
            Self::LockedOut => "locked_out",
            Self::StoreFailed => "freshness_store_failed",
        }
    }

    /// Whether it counts towards the lockout: only a MAC that was checked
    /// and did not match is a guess; the other refusals cost an attacker
    /// nothing and would let anyone lock the receiver out cheaply.
    pub fn counts_for_lockout(self) -> bool {
        matches!(self, Self::BadMac)
    }
}

impl std::fmt::Display for AuthFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The acceptance rule: `freshness` within `window_ms` of the receiver's
/// clock `now_ms`, and above the last accepted value (any value inside the
/// window when none was accepted yet).
///
/// # Errors
/// [`AuthFailure::Stale`] outside the window, [`AuthFailure::Replayed`]
/// not above the last accepted value.
pub fn check_freshness(
    last_accepted: Option<u64>,
    freshness: u64,
    now_ms: u64,
    window_ms: u64,
) -> Result<(), AuthFailure> {
    if freshness.abs_diff(now_ms) > window_ms {
        return Err(AuthFailure::Stale);
    }
    match last_accepted {
        Some(last) if freshness <= last => Err(AuthFailure::Replayed),
        _ => Ok(()),
    }
}

/// A sender's next freshness value: its clock in ms, and above the last
/// value it used on that id. A remembered value more than
/// [`MAX_SENDER_LEAD_MS`] ahead of the clock (a clock set back, a damaged
/// counter) is dropped: continuing above it would only be refused as stale.
pub fn next_tx_freshness(last_used: Option<u64>, now_ms: u64) -> u64 {
    match last_used {
        Some(last) if last < now_ms.saturating_add(MAX_SENDER_LEAD_MS) => {
            last.saturating_add(1).max(now_ms)
        }
        _ => now_ms.max(1),
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

    /// Whether it is locked at `now_us`.
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
        /// Its full freshness value.
        freshness: u64,
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

/// A secured id as a receiver knows it.
#[derive(Debug, Clone)]
pub struct SecuredId {
    /// The ids.
    pub link: Link,
    /// The key of its role (see [`crate::secoc_keys`]).
    pub key: Key,
    /// The last freshness value accepted before (from the persisted store;
    /// `None` for a fresh start).
    pub last_accepted: Option<u64>,
    /// Whether bad MACs may lock it out (`false` for `CALIB_ACK`: a
    /// write-back must not fail because someone sent junk).
    pub lockable: bool,
}

#[derive(Debug, Clone)]
struct RxLink {
    link: Link,
    auth: Authenticator,
    last_accepted: Option<u64>,
    lockout: Option<Lockout>,
    /// Secured frames waiting for their authenticator: arrival time, payload; oldest first.
    pending: std::collections::VecDeque<(u64, [u8; PAYLOAD_LEN])>,
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
    links: Vec<RxLink>,
    window_ms: u64,
    counts: FailureCounts,
}

impl Receiver {
    /// A receiver of `ids`, each lockable one with its own copy of
    /// `lockout`, accepting freshness values within `window_ms` of its clock.
    pub fn new(ids: &[SecuredId], lockout: &Lockout, window_ms: u64) -> Self {
        Self {
            links: ids
                .iter()
                .map(|s| RxLink {
                    link: s.link,
                    auth: Authenticator::new(&s.key),
                    last_accepted: s.last_accepted,
                    lockout: s.lockable.then(|| lockout.clone()),
                    pending: std::collections::VecDeque::with_capacity(MAX_PENDING),
                })
                .collect(),
            window_ms,
            counts: FailureCounts::default(),
        }
    }

    /// Refusals so far, by reason.
    pub fn counts(&self) -> FailureCounts {
        self.counts
    }

    /// The acceptance window, ms.
    pub fn window_ms(&self) -> u64 {
        self.window_ms
    }

    /// Whether the secured id `id` (or the one an authenticator id belongs
    /// to) is locked out at `now_us`.
    pub fn is_locked(&self, id: FrameId, now_us: u64) -> bool {
        self.links
            .iter()
            .find(|l| l.link.secured == id || l.link.authenticator == id)
            .and_then(|l| l.lockout.as_ref())
            .is_some_and(|l| l.is_locked(now_us))
    }

    /// Lockouts started since start, all ids together.
    pub fn lockouts(&self) -> u64 {
        self.links
            .iter()
            .filter_map(|l| l.lockout.as_ref())
            .map(Lockout::trips)
            .sum()
    }

    /// The last accepted freshness value of a secured id (or of the secured
    /// id an authenticator id belongs to).
    pub fn last_accepted(&self, id: FrameId) -> Option<u64> {
        self.links
            .iter()
            .find(|l| l.link.secured == id || l.link.authenticator == id)
            .and_then(|l| l.last_accepted)
    }

    fn refuse(&mut self, reason: AuthFailure) -> Verdict {
        self.counts.0[reason.index()] += 1;
        Verdict::Refused(reason)
    }

    /// Secured frames that waited longer than [`PAIR_TIMEOUT_US`] are
    /// refused as [`AuthFailure::MissingAuthenticator`]; returns how many.
    pub fn expire(&mut self, now_us: u64) -> usize {
        let mut n = 0;
        for l in &mut self.links {
            while l
                .pending
                .front()
                .is_some_and(|&(t, _)| now_us.saturating_sub(t) > PAIR_TIMEOUT_US)
            {
                l.pending.pop_front();
                n += 1;
            }
        }
        self.counts.0[AuthFailure::MissingAuthenticator.index()] += n as u64;
        n
    }

    /// Judges one received frame at bus time `now_us` (µs since the Unix
    /// epoch). `persist` stores a secured id's new last-accepted freshness
    /// value durably; it is called before a frame is accepted, and a
    /// failure refuses the frame (write-ahead: a crash can never re-open a
    /// value once acted on).
    pub fn on_frame<E>(
        &mut self,
        now_us: u64,
        id: FrameId,
        data: &[u8],
        persist: impl FnOnce(FrameId, u64) -> Result<(), E>,
    ) -> Verdict {
        self.expire(now_us);
        if let Some(i) = self.links.iter().position(|l| l.link.secured == id) {
            if self.is_locked(id, now_us) {
                return self.refuse(AuthFailure::LockedOut);
            }
            return match data.len() {
                PAYLOAD_LEN => {
                    let mut payload = [0u8; PAYLOAD_LEN];
                    payload.copy_from_slice(data);
                    let pending = &mut self.links[i].pending;
                    let overflow = pending.len() == MAX_PENDING;
                    if overflow {
                        pending.pop_front();
                    }
                    pending.push_back((now_us, payload));
                    if overflow {
                        // The oldest one never got its authenticator.
                        self.counts.0[AuthFailure::MissingAuthenticator.index()] += 1;
                    }
                    Verdict::Held
                }
                FD_LEN => {
                    let mut payload = [0u8; PAYLOAD_LEN];
                    payload.copy_from_slice(&data[..PAYLOAD_LEN]);
                    let mut auth = [0u8; AUTH_LEN];
                    auth.copy_from_slice(&data[PAYLOAD_LEN..]);
                    self.judge(now_us, i, Some(payload), auth, persist)
                }
                _ => self.refuse(AuthFailure::BadLength),
            };
        }
        let Some(i) = self.links.iter().position(|l| l.link.authenticator == id) else {
            return Verdict::NotSecured;
        };
        if self.is_locked(id, now_us) {
            return self.refuse(AuthFailure::LockedOut);
        }
        let Ok(auth) = <[u8; AUTH_LEN]>::try_from(data) else {
            return self.refuse(AuthFailure::BadLength);
        };
        if self.links[i].pending.is_empty() {
            return self.refuse(AuthFailure::Unpaired);
        }
        self.judge(now_us, i, None, auth, persist)
    }

    /// Judges `auth` against the FD payload `fd`, or else against the
    /// pending frames of link `i` (oldest first; the one it matches is
    /// taken, the others wait on for their own authenticators).
    fn judge<E>(
        &mut self,
        now_us: u64,
        i: usize,
        fd: Option<[u8; PAYLOAD_LEN]>,
        auth: [u8; AUTH_LEN],
        persist: impl FnOnce(FrameId, u64) -> Result<(), E>,
    ) -> Verdict {
        let now_ms = now_us / 1000;
        let window_ms = self.window_ms;
        let l = &mut self.links[i];
        let id = l.link.secured;
        // A mark from a clock that was ahead refuses for one window at most.
        if let Some(last) = l.last_accepted {
            l.last_accepted = Some(last.min(now_ms.saturating_add(window_ms)));
        }
        let (low, mac) = split_auth(&auth);
        let freshness = reconstruct(low, now_ms);
        if let Err(reason) = check_freshness(l.last_accepted, freshness, now_ms, window_ms) {
            return self.refuse(reason);
        }
        let matched = match fd {
            Some(payload) => l
                .auth
                .verify_full(id, &payload, freshness, &mac)
                .then_some((None, payload)),
            None => l
                .pending
                .iter()
                .position(|(_, p)| l.auth.verify_full(id, p, freshness, &mac))
                .map(|k| (Some(k), l.pending[k].1)),
        };
        let Some((k, payload)) = matched else {
            // Each payload tried was one guess at the MAC.
            let guesses = if fd.is_some() { 1 } else { l.pending.len() };
            if let Some(lockout) = &mut l.lockout {
                for _ in 0..guesses {
                    lockout.record_failure(now_us);
                }
            }
            return self.refuse(AuthFailure::BadMac);
        };
        if let Some(k) = k {
            l.pending.remove(k);
        }
        if persist(id, freshness).is_err() {
            return self.refuse(AuthFailure::StoreFailed);
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

    /// 2025-11-24 16:00 UTC in µs: the receiver's clock in these tests.
    const T0_US: u64 = 1_764_000_000_000_000;
    const T0_MS: u64 = T0_US / 1000;
    const HOUR_US: u64 = 3_600_000_000;

    fn key() -> Key {
        Key::parse(KEY_HEX).unwrap()
    }

    fn link() -> Link {
        Link {
            secured: FrameId::Standard(0x610),
            authenticator: FrameId::Standard(0x614),
        }
    }

    fn ack_link() -> Link {
        Link {
            secured: FrameId::Standard(0x613),
            authenticator: FrameId::Standard(0x616),
        }
    }

    fn spec(link: Link, last: Option<u64>, lockable: bool) -> SecuredId {
        SecuredId {
            link,
            key: key(),
            last_accepted: last,
            lockable,
        }
    }

    fn receiver(last: Option<u64>) -> Receiver {
        Receiver::new(
            &[spec(link(), last, true), spec(ack_link(), None, false)],
            &Lockout::new(10, 10_000_000, 60_000_000),
            DEFAULT_WINDOW_MS,
        )
    }

    /// A store that always succeeds (the `persist` argument's shape).
    #[allow(clippy::unnecessary_wraps)]
    fn ok(_: FrameId, _: u64) -> Result<(), ()> {
        Ok(())
    }

    /// A secured payload's authenticator at `fv` (ms).
    fn signed(payload: [u8; 8], fv: u64) -> [u8; 8] {
        Authenticator::new(&key()).sign(link().secured, &payload, fv)
    }

    fn send(rx: &mut Receiver, t: u64, payload: [u8; 8], auth: [u8; 8]) -> Verdict {
        assert_eq!(rx.on_frame(t, link().secured, &payload, ok), Verdict::Held);
        rx.on_frame(t + 100, link().authenticator, &auth, ok)
    }

    fn hex(s: &str) -> Vec<u8> {
        (0..s.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
            .collect()
    }

    #[test]
    fn auth_cmac_matches_all_four_rfc4493_examples() {
        // RFC 4493 section 4 (= SP 800-38B D.1), key 2b7e1516...: the
        // empty message, 16, 40 and 64 bytes of the same text.
        let text = "6bc1bee22e409f96e93d7e117393172aae2d8a571e03ac9c9eb76fac45af8e51\
                    30c81c46a35ce411e5fbc1191a0a52eff69f2445df4f9b17ad2b417be66c3710";
        for (len, expected) in [
            (0, "bb1d6929e95937287fa37d129b756746"),
            (16, "070a16b46b4d4144f79bdd9dd04a287c"),
            (40, "dfa66747de9ae63030ca32611497c827"),
            (64, "51f0bebf7e3b9d92fc49741779363cfe"),
        ] {
            let mut c = <Cmac<Aes128> as cmac::digest::KeyInit>::new(&key().0.into());
            c.update(&hex(text)[..len]);
            assert_eq!(
                c.finalize().into_bytes().as_slice(),
                hex(expected),
                "{len}-byte example"
            );
        }
    }

    #[test]
    fn auth_the_mac_covers_id_payload_and_the_full_64_bit_freshness() {
        // Our MAC is the first 4 bytes of the CMAC of DataId ‖ payload ‖
        // FV (8 bytes big-endian), computed here independently.
        let payload = [1, 2, 3, 4, 5, 6, 7, 8];
        let fv: u64 = 0x0000_019A_B3C4_D5E6;
        let mut m = vec![0x8B, 0xC1, 0xBE, 0xE2];
        m.extend_from_slice(&payload);
        m.extend_from_slice(&fv.to_be_bytes());
        let mut c = <Cmac<Aes128> as cmac::digest::KeyInit>::new(&key().0.into());
        c.update(&m);
        let expected = c.finalize().into_bytes();
        let a = Authenticator::new(&key());
        let ext = FrameId::Extended(0x0bc1_bee2);
        assert_eq!(a.mac(ext, &payload, fv), expected[..4]);
        let auth = a.sign(ext, &payload, fv);
        assert_eq!(
            auth[..4],
            (fv as u32).to_le_bytes(),
            "the low 32 bits travel"
        );
        assert_eq!(auth[4..], expected[..4]);
        // The same low bits 2^32 ms (49.7 days) earlier: another MAC.
        assert_ne!(
            a.mac(ext, &payload, fv - (1 << 32)),
            a.mac(ext, &payload, fv)
        );
    }

    #[test]
    fn auth_reconstruct_takes_the_value_nearest_the_clock_across_a_wrap() {
        let now = 0x19A_FFFF_FF00u64;
        assert_eq!(reconstruct(0xFFFF_FF00, now), now);
        // 0x200 ms later, past the wrap of the low 32 bits.
        assert_eq!(reconstruct(0x0000_0100, now), 0x19B_0000_0100);
        // And 0x200 ms earlier than a clock just past the wrap.
        assert_eq!(reconstruct(0xFFFF_FF00, 0x19B_0000_0100), now);
        assert_eq!(reconstruct(5, 0), 5);
    }

    #[test]
    fn auth_a_signed_command_is_accepted_once_and_its_replay_refused() {
        let mut rx = receiver(None);
        let payload = [1, 0xC0, 0x30, 0x50, 0, 0, 0x10, 0xF4];
        let auth = signed(payload, T0_MS);
        assert_eq!(
            send(&mut rx, T0_US, payload, auth),
            Verdict::Accepted {
                id: link().secured,
                payload,
                freshness: T0_MS
            }
        );
        // The same pair again inside the window: replayed; an hour later: stale.
        assert_eq!(
            send(&mut rx, T0_US + 1_000, payload, auth),
            Verdict::Refused(AuthFailure::Replayed)
        );
        assert_eq!(
            send(&mut rx, T0_US + HOUR_US, payload, auth),
            Verdict::Refused(AuthFailure::Stale)
        );
        // An older value signed with the key is refused too; a newer one passes.
        assert_eq!(
            send(&mut rx, T0_US + 2_000, payload, signed(payload, T0_MS - 1)),
            Verdict::Refused(AuthFailure::Replayed)
        );
        assert!(matches!(
            send(&mut rx, T0_US + 3_000, payload, signed(payload, T0_MS + 1)),
            Verdict::Accepted { .. }
        ));
        let c = rx.counts();
        assert_eq!(
            (c.of(AuthFailure::Replayed), c.of(AuthFailure::Stale)),
            (2, 1)
        );
    }

    #[test]
    fn auth_an_interleaved_plain_frame_neither_blocks_the_command_nor_keeps_it_for_later() {
        // Issue #33 item 1: command, a plain frame on the same id slipped in
        // by an attacker, the command's authenticator.
        let mut rx = receiver(None);
        let cmd = [7, 0, 0, 0, 0, 0, 0x70, 0x11];
        let plain = [7, 0, 0, 0, 0, 0, 0x80, 0x22];
        let auth = signed(cmd, T0_MS);
        assert_eq!(rx.on_frame(T0_US, link().secured, &cmd, ok), Verdict::Held);
        assert_eq!(
            rx.on_frame(T0_US + 50, link().secured, &plain, ok),
            Verdict::Held
        );
        assert_eq!(
            rx.on_frame(T0_US + 100, link().authenticator, &auth, ok),
            Verdict::Accepted {
                id: link().secured,
                payload: cmd,
                freshness: T0_MS
            }
        );
        // The attacker who also blocked the authenticator (say, by an error
        // frame) replays the recorded pair one hour later: stale.
        let mut blocked = receiver(None);
        assert_eq!(
            blocked.on_frame(T0_US, link().secured, &cmd, ok),
            Verdict::Held
        );
        let later = T0_US + HOUR_US;
        assert_eq!(
            send(&mut blocked, later, cmd, auth),
            Verdict::Refused(AuthFailure::Stale)
        );
        assert_eq!(
            send(&mut blocked, later + 3_600_000_000, cmd, auth),
            Verdict::Refused(AuthFailure::Stale)
        );
        assert_eq!(blocked.counts().of(AuthFailure::BadMac), 0);
        // A junk authenticator between the command and its own does not
        // consume the command either.
        let mut rx = receiver(None);
        assert_eq!(rx.on_frame(T0_US, link().secured, &cmd, ok), Verdict::Held);
        let mut junk = auth;
        junk[5] ^= 0x40;
        assert_eq!(
            rx.on_frame(T0_US + 40, link().authenticator, &junk, ok),
            Verdict::Refused(AuthFailure::BadMac)
        );
        assert!(matches!(
            rx.on_frame(T0_US + 80, link().authenticator, &auth, ok),
            Verdict::Accepted { .. }
        ));
    }

    #[test]
    fn auth_junk_authenticators_at_0_2_per_second_for_30_minutes_block_no_valid_command() {
        // Issue #33 item 3: junk authenticator frames at 0.2 frames/s, some
        // right after a command's secured frame, while a valid command
        // arrives every 5 s for 30 simulated minutes.
        let mut rx = receiver(None);
        let mut seed = 33u64;
        let mut accepted = 0;
        let mut commands = 0;
        let step_us = 5_000_000;
        for k in 0..(30 * 60 / 5) {
            let t = T0_US + k * step_us;
            let cmd = [3, 0, 0, 0, 0, 0, (k % 16) as u8, k as u8];
            let r = splitmix(&mut seed);
            let mut junk = [0u8; 8];
            junk[..4].copy_from_slice(&((t / 1000) as u32).to_le_bytes());
            junk[4..].copy_from_slice(&(r as u32).to_le_bytes());
            // Command frame, junk between it and its authenticator, then the
            // authenticator; on even steps the junk comes alone 2.5 s later.
            assert_eq!(rx.on_frame(t, link().secured, &cmd, ok), Verdict::Held);
            if k % 2 == 1 {
                let _ = rx.on_frame(t + 10, link().authenticator, &junk, ok);
            }
            let v = rx.on_frame(t + 20, link().authenticator, &signed(cmd, t / 1000), ok);
            commands += 1;
            if matches!(v, Verdict::Accepted { .. }) {
                accepted += 1;
            }
            if k % 2 == 0 {
                let _ = rx.on_frame(t + 2_500_000, link().authenticator, &junk, ok);
            }
        }
        assert_eq!(commands, 360);
        assert_eq!(accepted, 360, "{}", rx.counts());
        assert_eq!(rx.lockouts(), 0);
        let c = rx.counts();
        assert_eq!(
            (c.of(AuthFailure::BadMac), c.of(AuthFailure::Unpaired)),
            (180, 180),
            "{c}"
        );
    }

    #[test]
    fn auth_bad_macs_lock_out_only_their_id_and_never_calib_ack() {
        let mut rx = receiver(None);
        let payload = [5, 0, 0, 0, 0, 0, 0x50, 0x07];
        let ack_auth = |p: [u8; 8], fv| Authenticator::new(&key()).sign(ack_link().secured, &p, fv);
        // 10 bad MACs within 10 s on the command id and on CALIB_ACK.
        for k in 0..10u64 {
            let t = T0_US + k * 100_000;
            let mut bad = signed(payload, t / 1000);
            bad[7] ^= 1;
            assert_eq!(
                send(&mut rx, t, payload, bad),
                Verdict::Refused(AuthFailure::BadMac)
            );
            let mut bad_ack = ack_auth(payload, t / 1000);
            bad_ack[7] ^= 1;
            let _ = rx.on_frame(t + 200, ack_link().secured, &payload, ok);
            let _ = rx.on_frame(t + 300, ack_link().authenticator, &bad_ack, ok);
        }
        assert_eq!(rx.lockouts(), 1);
        let t = T0_US + 2_000_000;
        assert!(rx.is_locked(link().secured, t));
        assert!(!rx.is_locked(ack_link().secured, t));
        // A valid command is refused unseen; a valid ACK is accepted.
        assert_eq!(
            rx.on_frame(t, link().secured, &payload, ok),
            Verdict::Refused(AuthFailure::LockedOut)
        );
        assert_eq!(
            rx.on_frame(t, ack_link().secured, &payload, ok),
            Verdict::Held
        );
        assert!(matches!(
            rx.on_frame(
                t + 10,
                ack_link().authenticator,
                &ack_auth(payload, t / 1000),
                ok
            ),
            Verdict::Accepted { .. }
        ));
        // After lockout_s the command id is open again.
        let after = T0_US + 62_000_000;
        assert!(matches!(
            send(&mut rx, after, payload, signed(payload, after / 1000)),
            Verdict::Accepted { .. }
        ));
        // Unpaired, stale, replayed and short frames never lock.
        let mut rx = receiver(None);
        for k in 0..1000u64 {
            let t = T0_US + k * 1_000;
            let _ = rx.on_frame(t, link().authenticator, &[0; 8], ok);
            let _ = send(
                &mut rx,
                t + 200,
                payload,
                signed(payload, T0_MS - HOUR_US / 1000),
            );
            let _ = rx.on_frame(t + 400, link().secured, &payload[..5], ok);
        }
        assert_eq!(rx.lockouts(), 0, "{}", rx.counts());
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
        let mut open = Receiver::new(
            &[spec(link(), None, true)],
            &Lockout::new(u32::MAX, 0, 0),
            DEFAULT_WINDOW_MS,
        );
        let mut accepted = 0;
        for k in 0..1_000_000u64 {
            let t = T0_US + k * 1000;
            let r = splitmix(&mut seed);
            let mut auth = [0u8; 8];
            auth[..4].copy_from_slice(&((t / 1000) as u32).to_le_bytes());
            auth[4..].copy_from_slice(&(r as u32).to_le_bytes());
            if matches!(send(&mut open, t, payload, auth), Verdict::Accepted { .. }) {
                accepted += 1;
            }
        }
        assert_eq!(accepted, 0);
        assert_eq!(open.counts().of(AuthFailure::BadMac), 1_000_000);
        // With a lockout of 10 failures in 10 s for 60 s: it trips, and the
        // rest are refused unseen; none is accepted either way.
        let mut rx = receiver(None);
        for k in 0..1_000_000u64 {
            let t = T0_US + k * 1000;
            let r = splitmix(&mut seed);
            let mut auth = [0u8; 8];
            auth[..4].copy_from_slice(&((t / 1000) as u32).to_le_bytes());
            auth[4..].copy_from_slice(&(r as u32).to_le_bytes());
            let _ = rx.on_frame(t, link().secured, &payload, ok);
            let v = rx.on_frame(t + 100, link().authenticator, &auth, ok);
            assert!(!matches!(v, Verdict::Accepted { .. }));
        }
        let c = rx.counts();
        // 1,000 s of attack: a lockout every 60 s plus the time to trip it.
        assert_eq!(rx.lockouts(), 17, "{c}");
        // A secured frame whose authenticator failed waits on (its own may
        // follow), so the next authenticator is tried against 2, then 3,
        // then 4 of them: each payload tried is one guess, and 1 + 2 + 3 + 4
        // guesses trip the lockout after 4 refused authenticators.
        assert_eq!(c.of(AuthFailure::BadMac), 17 * 4, "{c}");
        assert!(c.of(AuthFailure::LockedOut) > 1_900_000, "{c}");
    }

    #[test]
    fn auth_a_frame_accepted_before_a_restart_is_refused_after_it() {
        let payload = [7, 0, 0, 0, 0, 0, 0x60, 0x10];
        let auth = signed(payload, T0_MS);
        let mut stored = None;
        let mut before = receiver(None);
        assert_eq!(
            before.on_frame(T0_US, link().secured, &payload, ok),
            Verdict::Held
        );
        let v = before.on_frame(T0_US + 50, link().authenticator, &auth, |_, fv| {
            stored = Some(fv);
            Ok::<(), ()>(())
        });
        assert!(matches!(v, Verdict::Accepted { .. }));
        // The restart, within the window: a new receiver from what was persisted.
        let mut after = receiver(stored);
        assert_eq!(
            send(&mut after, T0_US + 2_000_000, payload, auth),
            Verdict::Refused(AuthFailure::Replayed)
        );
    }

    #[test]
    fn auth_a_lost_freshness_store_does_not_reopen_an_old_recording() {
        // Issue #33 item 5: the store is gone (a fresh receiver) and a
        // recording two years old is played back: every frame is stale.
        let mut rx = receiver(None);
        let two_years_ms = 2 * 365 * 24 * 3_600_000u64;
        let then = T0_MS - two_years_ms;
        for k in 0..5u64 {
            let payload = [k as u8, 0, 0, 0, 0, 0, 0x10, 0x20];
            let auth = signed(payload, then + k * 1000);
            assert_eq!(
                send(&mut rx, T0_US + k * 1_000_000, payload, auth),
                Verdict::Refused(AuthFailure::Stale)
            );
        }
        // Even one whose low 32 bits happen to match the clock now: its MAC
        // was made over the full value of two years ago.
        let payload = [9, 0, 0, 0, 0, 0, 0x10, 0x20];
        let aligned = T0_MS - (T0_MS - then).div_ceil(1 << 32) * (1 << 32);
        let auth = signed(payload, aligned);
        assert_eq!(
            send(&mut rx, T0_US, payload, auth),
            Verdict::Refused(AuthFailure::BadMac)
        );
    }

    #[test]
    fn auth_a_far_future_freshness_never_locks_an_id_for_good() {
        let payload = [4, 0, 0, 0, 0, 0, 0x40, 0x44];
        let mut rx = receiver(None);
        // Signed with the key but far ahead (u32::MAX, a wrong sender clock): refused.
        for fv in [u64::from(u32::MAX), T0_MS + 3_600_000, u64::MAX - 1] {
            assert_eq!(
                send(&mut rx, T0_US, payload, signed(payload, fv)),
                Verdict::Refused(AuthFailure::Stale),
                "{fv}"
            );
        }
        assert_eq!(rx.last_accepted(link().secured), None);
        assert!(matches!(
            send(&mut rx, T0_US + 1000, payload, signed(payload, T0_MS)),
            Verdict::Accepted { .. }
        ));
        // A mark a year ahead (stored while the receiver's clock was wrong)
        // refuses new frames for one window at most.
        let mut rx = receiver(Some(T0_MS + 365 * 24 * 3_600_000));
        assert_eq!(
            send(&mut rx, T0_US, payload, signed(payload, T0_MS)),
            Verdict::Refused(AuthFailure::Replayed)
        );
        let t = T0_US + (DEFAULT_WINDOW_MS + 1) * 1000;
        assert!(matches!(
            send(&mut rx, t, payload, signed(payload, t / 1000)),
            Verdict::Accepted { .. }
        ));
    }

    #[test]
    fn auth_a_frame_whose_freshness_cannot_be_stored_is_refused_and_not_remembered() {
        let payload = [7, 0, 0, 0, 0, 0, 0x60, 0x10];
        let auth = signed(payload, T0_MS);
        let mut rx = receiver(None);
        assert_eq!(
            rx.on_frame(T0_US, link().secured, &payload, ok),
            Verdict::Held
        );
        let v = rx.on_frame(T0_US + 1, link().authenticator, &auth, |_, _| {
            Err("disk full")
        });
        assert_eq!(v, Verdict::Refused(AuthFailure::StoreFailed));
        assert_eq!(rx.last_accepted(link().secured), None);
        assert!(matches!(
            send(&mut rx, T0_US + 5, payload, auth),
            Verdict::Accepted { .. }
        ));
    }

    #[test]
    fn auth_plain_unpaired_late_and_short_frames_are_refused_by_reason() {
        let mut rx = receiver(None);
        let payload = [9, 0, 0, 0, 0, 0, 0x90, 0x6E];
        // Five plain frames: the oldest is dropped when a fifth waits.
        for k in 0..5 {
            assert_eq!(
                rx.on_frame(T0_US + k, link().secured, &payload, ok),
                Verdict::Held
            );
        }
        // The other four time out on the next frame after the pairing window.
        assert_eq!(
            rx.on_frame(
                T0_US + 10 + PAIR_TIMEOUT_US,
                FrameId::Standard(0x100),
                &[0; 8],
                ok
            ),
            Verdict::NotSecured
        );
        // A valid authenticator with nothing to pair with.
        let t = T0_US + 200_000;
        let auth = signed(payload, t / 1000);
        assert_eq!(
            rx.on_frame(t, link().authenticator, &auth, ok),
            Verdict::Refused(AuthFailure::Unpaired)
        );
        // A late authenticator: its frame expired first.
        assert_eq!(
            rx.on_frame(t + 100_000, link().secured, &payload, ok),
            Verdict::Held
        );
        assert_eq!(
            rx.on_frame(
                t + 100_000 + PAIR_TIMEOUT_US + 5,
                link().authenticator,
                &auth,
                ok
            ),
            Verdict::Refused(AuthFailure::Unpaired)
        );
        assert_eq!(
            rx.on_frame(t + 400_000, link().authenticator, &auth[..7], ok),
            Verdict::Refused(AuthFailure::BadLength)
        );
        let c = rx.counts();
        assert_eq!(c.of(AuthFailure::MissingAuthenticator), 6, "{c}");
        assert_eq!(c.of(AuthFailure::Unpaired), 2, "{c}");
        assert_eq!(c.of(AuthFailure::BadLength), 1, "{c}");
        assert_eq!(
            c.to_string(),
            "missing_authenticator=6 unpaired_authenticator=2 bad_length=1"
        );
        assert_eq!(rx.lockouts(), 0);
    }

    #[test]
    fn auth_a_can_fd_frame_carries_both_pdus() {
        let mut rx = receiver(None);
        let payload = [2, 0, 0, 0, 0, 0, 0x20, 0x37];
        let mut fd = payload.to_vec();
        fd.extend_from_slice(&signed(payload, T0_MS));
        assert!(matches!(
            rx.on_frame(T0_US, link().secured, &fd, ok),
            Verdict::Accepted {
                freshness: T0_MS,
                ..
            }
        ));
        assert_eq!(
            rx.on_frame(T0_US + 1, link().secured, &fd, ok),
            Verdict::Refused(AuthFailure::Replayed)
        );
        assert_eq!(
            rx.on_frame(T0_US + 2, link().secured, &fd[..12], ok),
            Verdict::Refused(AuthFailure::BadLength)
        );
    }

    #[test]
    fn auth_the_key_schedule_and_subkeys_are_wiped_when_dropped() {
        // Issue #44: without the `zeroize` features of `aes` and `cmac` the
        // expanded key (from which the key follows) stayed in freed memory.
        fn wiped<T: zeroize::ZeroizeOnDrop>() {}
        wiped::<Aes128>();
        wiped::<cmac::CmacCore<Aes128>>();
        wiped::<Key>();
    }

    #[test]
    fn auth_the_mac_binds_the_frame_id() {
        let a = Authenticator::new(&key());
        let p = [0u8; 8];
        let auth = a.sign(FrameId::Standard(0x603), &p, T0_MS);
        assert!(a.verify(FrameId::Standard(0x603), &p, &auth, T0_MS));
        assert!(!a.verify(FrameId::Standard(0x610), &p, &auth, T0_MS));
        assert!(!a.verify(FrameId::Extended(0x603), &p, &auth, T0_MS));
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
    fn auth_sender_freshness_is_the_clock_in_ms_and_unique() {
        assert_eq!(next_tx_freshness(None, T0_MS), T0_MS);
        assert_eq!(next_tx_freshness(Some(T0_MS), T0_MS), T0_MS + 1);
        assert_eq!(next_tx_freshness(Some(T0_MS - 10), T0_MS), T0_MS);
        // A counter from a clock far ahead is dropped, not continued.
        assert_eq!(next_tx_freshness(Some(T0_MS + 3_600_000), T0_MS), T0_MS);
        assert_eq!(next_tx_freshness(Some(u64::MAX), T0_MS), T0_MS);
        assert_eq!(next_tx_freshness(None, 0), 1);
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
        fn auth_any_flipped_bit_is_refused(payload in any::<[u8; 8]>(), fv in 1u64.., bit in 0usize..128) {
            let a = Authenticator::new(&key());
            let auth = a.sign(link().secured, &payload, fv);
            let mut p = payload;
            let mut x = auth;
            if bit < 64 { p[bit / 8] ^= 1 << (bit % 8); } else { x[(bit - 64) / 8] ^= 1 << (bit % 8); }
            prop_assert!(a.verify(link().secured, &payload, &auth, fv));
            prop_assert!(!a.verify(link().secured, &p, &x, fv));
        }
    }
}
