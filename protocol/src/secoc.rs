//! Authenticated commands and write-back in the manner of AUTOSAR SecOC
//! (issues #22, #33, #44): a truncated CMAC-AES-128 over the frame id, the
//! payload and a freshness value that the *receiver* owns, with a key per
//! message and direction ([`crate::secoc_keys`]) that never travels on the
//! bus.
//!
//! # The profile ("canodom SecOC profile 3")
//!
//! A *secured* frame is one of `ODOM_CMD`, `CALIB_CMD`, `CALIB_PARAMS` and
//! `CALIB_ACK`. Its 8-byte payload (the *authentic PDU*: the frame as it was
//! before, with its rolling counter and CRC-8) is unchanged, so every tool
//! that decodes it still does. The *cryptographic PDU* is 8 bytes:
//!
//! | bytes | signal | content |
//! |---|---|---|
//! | 0..=1 | `FRESHNESS` (bits 0..15, Intel) | the low 16 bits of the freshness counter, little-endian |
//! | 2..=7 | `MAC` (bits 16..63, Intel) | the first 6 bytes (48 bits) of the CMAC, in CMAC order |
//!
//! The MAC is CMAC-AES-128 (NIST SP 800-38B) over *DataToAuthenticator* =
//! the secured frame's id (4 bytes big-endian, bit 31 set for an extended
//! id) ‖ the 8 payload bytes ‖ the **full 64-bit** freshness value (8
//! bytes big-endian), truncated to its 48 most significant bits.
//!
//! On classic CAN the cryptographic PDU travels as its own frame on the
//! secured frame's *authenticator id* (`*_AUTH` in `canodom.dbc`), sent
//! right after the secured frame. A receiver keeps up to [`MAX_PENDING`]
//! secured frames of the linked id received within [`PAIR_TIMEOUT_US`]
//! and pairs an authenticator with the one whose MAC it matches, so a plain
//! frame slipped in between a command and its authenticator neither
//! replaces the command nor makes its authenticator fail. On CAN FD the two
//! travel together as one 16-byte frame on the secured id.
//!
//! # Freshness: the receiver's epoch and counter, no clock
//!
//! Profile 2 bound freshness to the sender's wall clock and checked it
//! against the receiver's: a receiver clock set back reopened every command
//! accepted since (issue #44). Profile 3 uses no wall clock at all, as
//! AUTOSAR's freshness value manager with a trip counter does. The
//! freshness value is `epoch << 32 | counter` ([`freshness`]):
//!
//! - the **epoch** is the receiver's (the daemon's): drawn anew at every
//!   start, one above the last one stored durably, or from the operating
//!   system's random source when there is none; a frame recorded in an
//!   earlier epoch — before a restart, a clock step, a deleted store — has
//!   a MAC over another epoch and fails;
//! - the **counter** is above every counter accepted on that id in this
//!   epoch ([`AuthFailure::Replayed`] otherwise) and not below the floor
//!   the receiver announced [`Receiver::window_ticks`] announcements ago
//!   ([`AuthFailure::Stale`]): the receiver raises its floor by one at each
//!   [`Receiver::tick`] (every [`SYNC_PERIOD_US`] on its monotonic clock),
//!   so a command kept from its receiver and sent later is refused once
//!   that many announcements have passed.
//!
//! Senders learn the epoch and the floor from the receiver's `SECOC_SYNC`
//! frame ([`Sync`]), sent at every tick and right after each accepted
//! frame, authenticated like any secured frame (one authenticator with the
//! operators' `calib_cmd` key, one with the parameter store's
//! `calib_params` key); they sign with a counter at or above the floor
//! ([`next_freshness`]). A sender never trusts an unauthenticated value, and
//! a replayed old `SECOC_SYNC` only makes its frames fail: it can deny
//! service, which anyone on a bus can, but never opens a replay. The frame
//! carries the counter's low 16 bits; the receiver rebuilds the counter as
//! the one nearest its floor ([`rebuild`]).
//!
//! The state a frame can change — a counter's mark, the floor — changes
//! only after its MAC is verified, lives in memory only (the next start is
//! a new epoch), and only moves forward.
//!
//! # No lockout
//!
//! Anyone can send a bad MAC, so any lockout counting them is a denial of
//! service without a key (issue #44). Profile 3 has none: every refusal is
//! only counted by reason. An online guess succeeds with probability
//! 2⁻⁴⁸ per payload tried; at 8,000 frames/s, each authenticator tried
//! against up to [`MAX_PENDING`] held payloads, the expected time to one
//! forgery is 2⁴⁸ / 32,000 s ≈ 280 years per id, `CALIB_ACK` included.

use aes::Aes128;
use canodom_can::frame::FrameId;
use cmac::{Cmac, Mac as _};
use zeroize::{Zeroize as _, ZeroizeOnDrop};

/// Bytes of the truncated MAC.
pub const MAC_LEN: usize = 6;

/// Bytes of the transmitted low part of the freshness counter.
pub const FRESHNESS_LEN: usize = 2;

/// Bytes of the cryptographic PDU (freshness + MAC).
pub const AUTH_LEN: usize = FRESHNESS_LEN + MAC_LEN;

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

/// The receiver's announcement period (`SECOC_SYNC`, [`Receiver::tick`]),
/// µs on its monotonic clock.
pub const SYNC_PERIOD_US: u64 = 1_000_000;

/// The default acceptance window in announcements: a counter is accepted
/// for this many [`SYNC_PERIOD_US`] after the floor it was signed above.
pub const DEFAULT_WINDOW_TICKS: u32 = 5;

/// How far from the receiver's floor a counter is rebuilt from its low 16
/// bits ([`rebuild`]).
pub const REBUILD_SPAN: u32 = 1 << 15;

/// A floor this close to the end of the counter space asks for a new
/// epoch ([`Receiver::exhausted`]).
const EXHAUSTED_AT: u32 = u32::MAX - 4 * REBUILD_SPAN;

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

/// The 64-bit freshness value of a counter in an epoch.
pub fn freshness(epoch: u32, counter: u32) -> u64 {
    (u64::from(epoch) << 32) | u64::from(counter)
}

/// The epoch and counter of a freshness value.
pub fn split_freshness(fv: u64) -> (u32, u32) {
    ((fv >> 32) as u32, fv as u32)
}

/// CMAC-AES-128 with the key schedule and subkeys computed once (wiped
/// when dropped: the `zeroize` features of `aes` and `cmac`).
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
        out[..FRESHNESS_LEN].copy_from_slice(&(freshness as u16).to_le_bytes());
        out[FRESHNESS_LEN..].copy_from_slice(&self.mac(id, payload, freshness));
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

    /// The full freshness value of `auth` for `payload` at `id` when its
    /// MAC verifies, its counter rebuilt around `near` (a freshness value
    /// of the same epoch: a receiver's mark). For receivers outside the
    /// daemon (a parameter store, tests).
    pub fn verify_near(
        &self,
        id: FrameId,
        payload: &[u8; PAYLOAD_LEN],
        auth: &[u8; AUTH_LEN],
        near: u64,
    ) -> Option<u64> {
        let (low, mac) = split_auth(auth);
        let (epoch, counter) = split_freshness(near);
        let fv = freshness(epoch, rebuild(low, counter));
        self.verify_full(id, payload, fv, &mac).then_some(fv)
    }
}

/// The transmitted low 16 bits of the freshness counter and the MAC of a
/// cryptographic PDU.
pub fn split_auth(auth: &[u8; AUTH_LEN]) -> (u16, [u8; MAC_LEN]) {
    let low = u16::from_le_bytes([auth[0], auth[1]]);
    let mut mac = [0u8; MAC_LEN];
    mac.copy_from_slice(&auth[FRESHNESS_LEN..]);
    (low, mac)
}

/// The counter nearest `floor` whose low 16 bits are `low` (AUTOSAR's
/// reconstruction from the transmitted part), within the epoch's counter
/// space: a counter within [`REBUILD_SPAN`] of the floor is rebuilt
/// exactly; one further away rebuilds to another value and fails its MAC.
pub fn rebuild(low: u16, floor: u32) -> u32 {
    const SPAN: u32 = 1 << 16;
    let base = floor & !(SPAN - 1);
    let low = u32::from(low);
    [
        base.checked_sub(SPAN).map(|b| b | low),
        Some(base | low),
        base.checked_add(SPAN).map(|b| b | low),
    ]
    .into_iter()
    .flatten()
    .min_by_key(|c| c.abs_diff(floor))
    .unwrap_or(low)
}

/// The receiver's announcement (`SECOC_SYNC`): its epoch and the floor,
/// the lowest counter a sender should sign with now. Payload: epoch (u32
/// little-endian) ‖ floor (u32 little-endian); its own freshness value is
/// [`Sync::freshness`], so an announcement signs itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sync {
    /// The receiver's epoch.
    pub epoch: u32,
    /// The lowest counter to sign with.
    pub floor: u32,
}

impl Sync {
    /// The 8-byte payload.
    pub fn payload(self) -> [u8; PAYLOAD_LEN] {
        let mut p = [0u8; PAYLOAD_LEN];
        p[..4].copy_from_slice(&self.epoch.to_le_bytes());
        p[4..].copy_from_slice(&self.floor.to_le_bytes());
        p
    }

    /// The announcement of a payload.
    pub fn from_payload(p: &[u8; PAYLOAD_LEN]) -> Self {
        Self {
            epoch: u32::from_le_bytes([p[0], p[1], p[2], p[3]]),
            floor: u32::from_le_bytes([p[4], p[5], p[6], p[7]]),
        }
    }

    /// The freshness value the announcement is signed with.
    pub fn freshness(self) -> u64 {
        freshness(self.epoch, self.floor)
    }

    /// Its authenticator frame's data, signed by `auth` for `sync_id`.
    pub fn sign(self, auth: &Authenticator, sync_id: FrameId) -> [u8; AUTH_LEN] {
        auth.sign(sync_id, &self.payload(), self.freshness())
    }

    /// The announcement of `payload` when `pdu` is its authenticator under
    /// `auth` (the sender's key of that direction), else `None`.
    pub fn verify(
        auth: &Authenticator,
        sync_id: FrameId,
        payload: &[u8; PAYLOAD_LEN],
        pdu: &[u8; AUTH_LEN],
    ) -> Option<Self> {
        let s = Self::from_payload(payload);
        let (low, mac) = split_auth(pdu);
        (low == s.floor as u16 && auth.verify_full(sync_id, payload, s.freshness(), &mac))
            .then_some(s)
    }
}

/// A sender's next freshness value: at or above the receiver's announced
/// floor, and above the last value it used itself in that epoch while that
/// stays within reach of the floor (further ahead it starts at the floor
/// again: its frames above were never accepted, and go stale).
pub fn next_freshness(sync: Sync, last_used: Option<u64>) -> u64 {
    let floor = sync.floor.max(1);
    let counter = match last_used.map(split_freshness) {
        Some((epoch, c)) if epoch == sync.epoch => {
            let next = c.saturating_add(1);
            if next >= floor && next - floor < REBUILD_SPAN / 2 {
                next
            } else {
                floor
            }
        }
        _ => floor,
    };
    freshness(sync.epoch, counter)
}

/// Why a secured frame was refused. Every refusal is counted by its kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AuthFailure {
    /// The MAC does not match: no key, another role's or vehicle's key, a
    /// changed payload (a rolled counter and recomputed CRC), another id,
    /// another epoch (a frame from before a restart), or a guessed MAC.
    BadMac,
    /// Not above the last counter accepted on that id in this epoch: a
    /// replay.
    Replayed,
    /// Below the floor announced a window ago: a frame kept back and sent
    /// late, or a sender that has not heard the receiver's announcement.
    Stale,
    /// A secured frame without its authenticator: a plain frame from a
    /// sender without the key, or its authenticator came too late.
    MissingAuthenticator,
    /// An authenticator frame with no secured frame to pair with.
    Unpaired,
    /// A secured or authenticator frame of the wrong length.
    BadLength,
}

impl AuthFailure {
    /// Every reason, in [`Self::index`] order.
    pub const ALL: [Self; 6] = [
        Self::BadMac,
        Self::Replayed,
        Self::Stale,
        Self::MissingAuthenticator,
        Self::Unpaired,
        Self::BadLength,
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
        }
    }
}

impl std::fmt::Display for AuthFailure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// What the receiver decided about one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Not a secured or authenticator id: handle it as before.
    NotSecured,
    /// A secured frame held until its authenticator arrives.
    Held,
    /// Authenticated and fresh: handle `payload` as a frame at `id`.
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
}

#[derive(Debug, Clone)]
struct RxLink {
    link: Link,
    auth: Authenticator,
    /// The last counter accepted in this epoch (0: none yet).
    mark: u32,
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

/// The receiving end: pairs, verifies, judges freshness in its own epoch,
/// counts. Time (`now_us`) only ages the pairing of a secured frame with
/// its authenticator; the caller passes a monotonic clock.
#[derive(Debug, Clone)]
pub struct Receiver {
    links: Vec<RxLink>,
    epoch: u32,
    /// The lowest counter a sender should sign with: above every mark.
    floor: u32,
    /// The floors of the last `window_ticks` announcements, oldest first:
    /// the oldest is the lowest counter accepted.
    announced: std::collections::VecDeque<u32>,
    window_ticks: usize,
    counts: FailureCounts,
}

impl Receiver {
    /// A receiver of `ids` in `epoch` (a new one at every start: see the
    /// module doc), accepting a counter for `window_ticks` (≥ 1)
    /// announcements after the floor it was signed above.
    pub fn new(ids: &[SecuredId], epoch: u32, window_ticks: u32) -> Self {
        let window_ticks = window_ticks.max(1) as usize;
        let mut announced = std::collections::VecDeque::with_capacity(window_ticks);
        announced.push_back(1);
        Self {
            links: ids
                .iter()
                .map(|s| RxLink {
                    link: s.link,
                    auth: Authenticator::new(&s.key),
                    mark: 0,
                    pending: std::collections::VecDeque::with_capacity(MAX_PENDING),
                })
                .collect(),
            epoch,
            floor: 1,
            announced,
            window_ticks,
            counts: FailureCounts::default(),
        }
    }

    /// The same ids, window and counts in a new `epoch` (its counters
    /// start again: nothing of the old epoch is accepted in it).
    #[must_use]
    pub fn new_epoch(&self, epoch: u32) -> Self {
        let mut next = self.clone();
        next.epoch = epoch;
        next.floor = 1;
        next.announced.clear();
        next.announced.push_back(1);
        for l in &mut next.links {
            l.mark = 0;
            l.pending.clear();
        }
        next
    }

    /// Refusals so far, by reason.
    pub fn counts(&self) -> FailureCounts {
        self.counts
    }

    /// The epoch.
    pub fn epoch(&self) -> u32 {
        self.epoch
    }

    /// The acceptance window, in announcements.
    pub fn window_ticks(&self) -> u32 {
        self.window_ticks as u32
    }

    /// The announcement to send now (after an accepted frame: the floor
    /// above it at once, so the next sender need not wait for a tick).
    pub fn sync(&self) -> Sync {
        Sync {
            epoch: self.epoch,
            floor: self.floor,
        }
    }

    /// One announcement period has passed: the floor moves up by one, the
    /// oldest floor of the window drops out (frames signed above it alone
    /// are now stale). Returns the announcement to send.
    pub fn tick(&mut self) -> Sync {
        self.floor = self.floor.saturating_add(1);
        if self.announced.len() == self.window_ticks {
            self.announced.pop_front();
        }
        self.announced.push_back(self.floor);
        self.sync()
    }

    /// Whether the counters near the end of their space: the owner should
    /// start a new epoch (never reached at one tick a second and any
    /// command rate a bus carries, but a key holder could push it).
    pub fn exhausted(&self) -> bool {
        self.floor >= EXHAUSTED_AT
    }

    /// The last accepted freshness value of a secured id (or of the secured
    /// id an authenticator id belongs to) in this epoch.
    pub fn last_accepted(&self, id: FrameId) -> Option<u64> {
        self.links
            .iter()
            .find(|l| l.link.secured == id || l.link.authenticator == id)
            .filter(|l| l.mark > 0)
            .map(|l| freshness(self.epoch, l.mark))
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

    /// Judges one received frame at `now_us` (µs on the caller's monotonic
    /// clock: only the pairing timeout uses it).
    pub fn on_frame(&mut self, now_us: u64, id: FrameId, data: &[u8]) -> Verdict {
        self.expire(now_us);
        if let Some(i) = self.links.iter().position(|l| l.link.secured == id) {
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
                    self.judge(i, Some(payload), auth)
                }
                _ => self.refuse(AuthFailure::BadLength),
            };
        }
        let Some(i) = self.links.iter().position(|l| l.link.authenticator == id) else {
            return Verdict::NotSecured;
        };
        let Ok(auth) = <[u8; AUTH_LEN]>::try_from(data) else {
            return self.refuse(AuthFailure::BadLength);
        };
        if self.links[i].pending.is_empty() {
            return self.refuse(AuthFailure::Unpaired);
        }
        self.judge(i, None, auth)
    }

    /// Judges `auth` against the FD payload `fd`, or else against the
    /// pending frames of link `i` (oldest first; the one it matches is
    /// taken, the others wait on for their own authenticators). Nothing
    /// but the counts changes unless the MAC verifies.
    fn judge(&mut self, i: usize, fd: Option<[u8; PAYLOAD_LEN]>, auth: [u8; AUTH_LEN]) -> Verdict {
        let (low, mac) = split_auth(&auth);
        let counter = rebuild(low, self.floor);
        let oldest = self.announced.front().copied().unwrap_or(self.floor);
        let l = &self.links[i];
        if counter < oldest {
            return self.refuse(AuthFailure::Stale);
        }
        if counter <= l.mark {
            return self.refuse(AuthFailure::Replayed);
        }
        let fv = freshness(self.epoch, counter);
        let id = l.link.secured;
        let matched = match fd {
            Some(payload) => l
                .auth
                .verify_full(id, &payload, fv, &mac)
                .then_some((None, payload)),
            None => l
                .pending
                .iter()
                .position(|(_, p)| l.auth.verify_full(id, p, fv, &mac))
                .map(|k| (Some(k), l.pending[k].1)),
        };
        let Some((k, payload)) = matched else {
            return self.refuse(AuthFailure::BadMac);
        };
        let l = &mut self.links[i];
        if let Some(k) = k {
            l.pending.remove(k);
        }
        l.mark = counter;
        self.floor = self.floor.max(counter.saturating_add(1));
        Verdict::Accepted {
            id,
            payload,
            freshness: fv,
        }
    }
}
#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const KEY_HEX: &str = "2b7e151628aed2a6abf7158809cf4f3c";
    const EPOCH: u32 = 0x5EC0_C003;
    /// The receiver's monotonic clock in these tests, µs.
    const T0_US: u64 = 1_000_000_000;

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

    fn odom_link() -> Link {
        Link {
            secured: FrameId::Standard(0x603),
            authenticator: FrameId::Standard(0x604),
        }
    }

    fn receiver_in(epoch: u32) -> Receiver {
        let ids: Vec<SecuredId> = [link(), ack_link(), odom_link()]
            .into_iter()
            .map(|link| SecuredId { link, key: key() })
            .collect();
        Receiver::new(&ids, epoch, DEFAULT_WINDOW_TICKS)
    }

    fn receiver() -> Receiver {
        receiver_in(EPOCH)
    }

    /// A secured payload's authenticator on `l` at `fv`.
    fn signed_on(l: Link, payload: [u8; 8], fv: u64) -> [u8; 8] {
        Authenticator::new(&key()).sign(l.secured, &payload, fv)
    }

    fn signed(payload: [u8; 8], fv: u64) -> [u8; 8] {
        signed_on(link(), payload, fv)
    }

    fn send_on(rx: &mut Receiver, l: Link, t: u64, payload: [u8; 8], auth: [u8; 8]) -> Verdict {
        assert_eq!(rx.on_frame(t, l.secured, &payload), Verdict::Held);
        rx.on_frame(t + 100, l.authenticator, &auth)
    }

    fn send(rx: &mut Receiver, t: u64, payload: [u8; 8], auth: [u8; 8]) -> Verdict {
        send_on(rx, link(), t, payload, auth)
    }

    /// What a sender who heard the receiver's last announcement signs with.
    fn fresh(rx: &Receiver) -> u64 {
        next_freshness(rx.sync(), None)
    }

    fn hex(s: &str) -> Vec<u8> {
        (0..s.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
            .collect()
    }

    /// splitmix64: reproducible random MACs without a dependency.
    fn splitmix(state: &mut u64) -> u64 {
        *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = *state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn junk(seed: &mut u64) -> [u8; 8] {
        splitmix(seed).to_le_bytes()
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
        // Our MAC is the first 6 bytes of the CMAC of DataId ‖ payload ‖
        // FV (8 bytes big-endian), computed here independently.
        let payload = [1, 2, 3, 4, 5, 6, 7, 8];
        let fv: u64 = 0x5EC0_C003_0001_D5E6;
        let mut m = vec![0x8B, 0xC1, 0xBE, 0xE2];
        m.extend_from_slice(&payload);
        m.extend_from_slice(&fv.to_be_bytes());
        let mut c = <Cmac<Aes128> as cmac::digest::KeyInit>::new(&key().0.into());
        c.update(&m);
        let expected = c.finalize().into_bytes();
        let a = Authenticator::new(&key());
        let ext = FrameId::Extended(0x0bc1_bee2);
        assert_eq!(a.mac(ext, &payload, fv), expected[..6]);
        let auth = a.sign(ext, &payload, fv);
        assert_eq!(auth[..2], [0xE6, 0xD5], "the low 16 bits travel");
        assert_eq!(auth[2..], expected[..6]);
        // The same counter in another epoch: another MAC.
        assert_ne!(
            a.mac(ext, &payload, fv ^ (1 << 40)),
            a.mac(ext, &payload, fv)
        );
    }

    #[test]
    fn auth_rebuild_takes_the_counter_nearest_the_floor_across_a_wrap() {
        assert_eq!(rebuild(0xFF00, 0x3_FF00), 0x3_FF00);
        assert_eq!(rebuild(0x0100, 0x3_FF00), 0x4_0100);
        assert_eq!(rebuild(0xFF00, 0x4_0100), 0x3_FF00);
        assert_eq!(rebuild(5, 0), 5);
        assert_eq!(rebuild(0xFFFF, 1), 0xFFFF, "no counter below zero");
        assert_eq!(rebuild(0, u32::MAX), 0xFFFF_0000, "none past the end");
    }

    #[test]
    fn auth_a_signed_command_is_accepted_once_and_its_replay_refused() {
        let mut rx = receiver();
        let payload = [1, 0xC0, 0x30, 0x50, 0, 0, 0x10, 0xF4];
        let fv = fresh(&rx);
        let auth = signed(payload, fv);
        assert_eq!(
            send(&mut rx, T0_US, payload, auth),
            Verdict::Accepted {
                id: link().secured,
                payload,
                freshness: fv
            }
        );
        assert_eq!(
            rx.sync().floor,
            split_freshness(fv).1 + 1,
            "the floor moves above it"
        );
        assert_eq!(
            send(&mut rx, T0_US + 1_000, payload, auth),
            Verdict::Refused(AuthFailure::Replayed)
        );
        // The next one from a sender who heard the new announcement passes.
        let next = next_freshness(rx.sync(), Some(fv));
        assert!(matches!(
            send(&mut rx, T0_US + 2_000, payload, signed(payload, next)),
            Verdict::Accepted { .. }
        ));
        assert_eq!(rx.counts().of(AuthFailure::Replayed), 1);
    }

    #[test]
    fn auth_a_command_kept_back_goes_stale_after_the_window_and_not_before() {
        let mut rx = receiver();
        let payload = [2, 0, 0, 0, 0, 0, 0x20, 0x37];
        let kept = signed(payload, fresh(&rx));
        for _ in 0..DEFAULT_WINDOW_TICKS - 1 {
            rx.tick();
        }
        let mut early = rx.clone();
        assert!(matches!(
            send(&mut early, T0_US, payload, kept),
            Verdict::Accepted { .. }
        ));
        rx.tick();
        assert_eq!(
            send(&mut rx, T0_US, payload, kept),
            Verdict::Refused(AuthFailure::Stale)
        );
        // A sender who heard the last announcement is accepted at once.
        let auth = signed(payload, fresh(&rx));
        assert!(matches!(
            send(&mut rx, T0_US + 1000, payload, auth),
            Verdict::Accepted { .. }
        ));
    }

    #[test]
    fn auth_frames_of_an_earlier_epoch_are_refused_whatever_the_clocks_say() {
        // Issue #44: a restart is a new epoch, so commands accepted before it
        // (recorded, replayed after the clock was set back an hour or two
        // years, with the store kept or deleted) all fail their MAC; no
        // clock is read.
        let mut before = receiver_in(EPOCH);
        let mut recorded = Vec::new();
        for k in 0..2u8 {
            let payload = [k, 0, 0, 0, 0, 0, 0x60, 0x10];
            let auth = signed(payload, fresh(&before));
            assert!(matches!(
                send(&mut before, T0_US, payload, auth),
                Verdict::Accepted { .. }
            ));
            recorded.push((payload, auth));
        }
        for epoch in [EPOCH + 1, 0x1234_5678] {
            let mut after = receiver_in(epoch);
            for (payload, auth) in &recorded {
                assert_eq!(
                    send(&mut after, T0_US, *payload, *auth),
                    Verdict::Refused(AuthFailure::BadMac)
                );
            }
            assert_eq!(after.last_accepted(link().secured), None);
            assert_eq!(after.sync().floor, 1, "nothing moved");
        }
    }

    #[test]
    fn auth_an_interleaved_plain_frame_neither_blocks_the_command_nor_keeps_it_for_later() {
        let mut rx = receiver();
        let cmd = [7, 0, 0, 0, 0, 0, 0x70, 0x11];
        let plain = [7, 0, 0, 0, 0, 0, 0x80, 0x22];
        let fv = fresh(&rx);
        let auth = signed(cmd, fv);
        assert_eq!(rx.on_frame(T0_US, link().secured, &cmd), Verdict::Held);
        assert_eq!(
            rx.on_frame(T0_US + 50, link().secured, &plain),
            Verdict::Held
        );
        assert_eq!(
            rx.on_frame(T0_US + 100, link().authenticator, &auth),
            Verdict::Accepted {
                id: link().secured,
                payload: cmd,
                freshness: fv
            }
        );
        // The attacker who also blocked the authenticator replays the pair
        // after the window: stale.
        let mut blocked = receiver();
        let auth = signed(cmd, fresh(&blocked));
        assert_eq!(blocked.on_frame(T0_US, link().secured, &cmd), Verdict::Held);
        for _ in 0..DEFAULT_WINDOW_TICKS {
            blocked.tick();
        }
        assert_eq!(
            send(&mut blocked, T0_US + 10_000_000, cmd, auth),
            Verdict::Refused(AuthFailure::Stale)
        );
        // A junk authenticator between the command and its own does not
        // consume the command either.
        let mut rx = receiver();
        let auth = signed(cmd, fresh(&rx));
        assert_eq!(rx.on_frame(T0_US, link().secured, &cmd), Verdict::Held);
        let mut junk = auth;
        junk[5] ^= 0x40;
        assert_eq!(
            rx.on_frame(T0_US + 40, link().authenticator, &junk),
            Verdict::Refused(AuthFailure::BadMac)
        );
        assert!(matches!(
            rx.on_frame(T0_US + 80, link().authenticator, &auth),
            Verdict::Accepted { .. }
        ));
    }

    /// 30 minutes with a valid command every 5 s on `CALIB_CMD` while a
    /// keyless sender sends `burst` frames every `every_s` seconds on every
    /// secured id (plain frames and junk authenticators, some right between
    /// a command and its authenticator); returns the commands accepted.
    fn keyless_30_minutes(burst: u64, every_s: u64) -> u64 {
        let mut rx = receiver();
        let mut seed = 44u64;
        let mut accepted = 0;
        let mut last = None;
        for s in 0..30 * 60u64 {
            let t = T0_US + s * 1_000_000;
            if s % every_s == 0 {
                for b in 0..burst {
                    for l in [link(), ack_link(), odom_link()] {
                        let tb = t + 200_000 + b * 1000;
                        if b % 2 == 0 {
                            let _ = rx.on_frame(tb, l.secured, &junk(&mut seed));
                        } else {
                            let _ = rx.on_frame(tb, l.authenticator, &junk(&mut seed));
                        }
                    }
                }
            }
            if s % 5 == 0 {
                let cmd = [3, 0, 0, 0, 0, 0, (s % 16) as u8, s as u8];
                let fv = next_freshness(rx.sync(), last);
                assert_eq!(rx.on_frame(t, link().secured, &cmd), Verdict::Held);
                // Junk slipped in between the command and its authenticator.
                let _ = rx.on_frame(t + 10, link().secured, &junk(&mut seed));
                let _ = rx.on_frame(t + 20, link().authenticator, &junk(&mut seed));
                if matches!(
                    rx.on_frame(t + 30, link().authenticator, &signed(cmd, fv)),
                    Verdict::Accepted { .. }
                ) {
                    accepted += 1;
                    last = Some(fv);
                }
            }
            rx.tick();
        }
        assert!(rx.counts().of(AuthFailure::BadMac) > 0, "{}", rx.counts());
        accepted
    }

    #[test]
    fn auth_keyless_bursts_on_every_secured_id_keep_no_valid_command_out() {
        // Issue #44: 7 keyless frames a minute (the burst that locked an id
        // for 60 s in profile 2) and 1 a second on every secured id.
        assert_eq!(keyless_30_minutes(7, 60), 360);
        assert_eq!(keyless_30_minutes(1, 1), 360);
    }

    #[test]
    fn auth_a_million_random_macs_are_never_accepted_and_change_nothing() {
        let payload = [6, 0, 0, 0, 0, 0, 0x50, 0x07];
        let mut seed = 22u64;
        let mut rx = receiver();
        let before = rx.sync();
        for k in 0..1_000_000u64 {
            let t = T0_US + k * 1000;
            let mut auth = junk(&mut seed);
            // Half of them with the counter the receiver expects.
            if k % 2 == 0 {
                auth[..2].copy_from_slice(&(before.floor as u16).to_le_bytes());
            }
            let l = if k % 3 == 0 { ack_link() } else { link() };
            assert!(!matches!(
                send_on(&mut rx, l, t, payload, auth),
                Verdict::Accepted { .. }
            ));
        }
        assert_eq!(rx.sync(), before, "nothing a refused frame does is kept");
        assert_eq!(rx.last_accepted(link().secured), None);
        let c = rx.counts();
        assert!(c.of(AuthFailure::BadMac) > 900_000, "{c}");
        // And the next valid command, and ACK, pass at once.
        let t = T0_US + 1_000_000_000;
        let auth = signed(payload, fresh(&rx));
        assert!(matches!(
            send(&mut rx, t, payload, auth),
            Verdict::Accepted { .. }
        ));
        let fv = fresh(&rx);
        assert!(matches!(
            send_on(
                &mut rx,
                ack_link(),
                t + 500,
                payload,
                signed_on(ack_link(), payload, fv)
            ),
            Verdict::Accepted { .. }
        ));
    }

    #[test]
    fn auth_an_online_brute_force_outlasts_a_vehicle_on_every_id_calib_ack_included() {
        // Issue #44: no lockout, so the MAC alone bounds a forgery. At 8,000
        // frames/s, each authenticator tried against MAX_PENDING payloads,
        // the expected time to one accepted forgery, on any id (CALIB_ACK is
        // judged as every other: no id is treated differently).
        let guesses_per_s = 8_000.0 * MAX_PENDING as f64;
        let expected_s = 2f64.powi(8 * MAC_LEN as i32) / guesses_per_s;
        let years = expected_s / (365.25 * 86_400.0);
        // A vehicle's life: 30 years. Profile 2 (32-bit MAC): 1.6 days.
        assert!(years > 30.0, "{years} years");
        assert!(
            (years - 278.9).abs() < 1.0,
            "{years} years: the README's figure"
        );
    }

    #[test]
    fn auth_an_announcement_verifies_only_with_its_key_and_unchanged() {
        let sync_id = FrameId::Standard(0x617);
        let a = Authenticator::new(&key());
        let s = Sync {
            epoch: EPOCH,
            floor: 0x1_2345,
        };
        let pdu = s.sign(&a, sync_id);
        assert_eq!(Sync::verify(&a, sync_id, &s.payload(), &pdu), Some(s));
        let other = Authenticator::new(&Key::parse("00112233445566778899aabbccddeeff").unwrap());
        assert_eq!(Sync::verify(&other, sync_id, &s.payload(), &pdu), None);
        let mut p = s.payload();
        p[4] ^= 1;
        assert_eq!(Sync::verify(&a, sync_id, &p, &pdu), None);
        assert_eq!(
            Sync::verify(&a, FrameId::Standard(0x610), &s.payload(), &pdu),
            None
        );
    }

    #[test]
    fn auth_sender_freshness_continues_above_the_floor_and_its_own_last() {
        let s = Sync {
            epoch: EPOCH,
            floor: 100,
        };
        assert_eq!(next_freshness(s, None), freshness(EPOCH, 100));
        assert_eq!(
            next_freshness(s, Some(freshness(EPOCH, 100))),
            freshness(EPOCH, 101)
        );
        assert_eq!(
            next_freshness(s, Some(freshness(EPOCH, 10))),
            freshness(EPOCH, 100)
        );
        // Another epoch's counter, or one far ahead, is not continued.
        assert_eq!(
            next_freshness(s, Some(freshness(EPOCH - 1, 500))),
            freshness(EPOCH, 100)
        );
        assert_eq!(
            next_freshness(s, Some(freshness(EPOCH, 90_000))),
            freshness(EPOCH, 100)
        );
        assert_eq!(
            next_freshness(Sync { epoch: 1, floor: 0 }, None),
            freshness(1, 1)
        );
    }

    #[test]
    fn auth_plain_unpaired_late_and_short_frames_are_refused_by_reason() {
        let mut rx = receiver();
        let payload = [9, 0, 0, 0, 0, 0, 0x90, 0x6E];
        // Five plain frames: the oldest is dropped when a fifth waits.
        for k in 0..5 {
            assert_eq!(
                rx.on_frame(T0_US + k, link().secured, &payload),
                Verdict::Held
            );
        }
        // The other four time out on the next frame after the pairing window.
        assert_eq!(
            rx.on_frame(
                T0_US + 10 + PAIR_TIMEOUT_US,
                FrameId::Standard(0x100),
                &[0; 8]
            ),
            Verdict::NotSecured
        );
        let t = T0_US + 200_000;
        let auth = signed(payload, fresh(&rx));
        assert_eq!(
            rx.on_frame(t, link().authenticator, &auth),
            Verdict::Refused(AuthFailure::Unpaired)
        );
        assert_eq!(
            rx.on_frame(t + 100_000, link().secured, &payload),
            Verdict::Held
        );
        assert_eq!(
            rx.on_frame(
                t + 100_000 + PAIR_TIMEOUT_US + 5,
                link().authenticator,
                &auth
            ),
            Verdict::Refused(AuthFailure::Unpaired)
        );
        assert_eq!(
            rx.on_frame(t + 400_000, link().authenticator, &auth[..7]),
            Verdict::Refused(AuthFailure::BadLength)
        );
        let c = rx.counts();
        assert_eq!(
            c.to_string(),
            "missing_authenticator=6 unpaired_authenticator=2 bad_length=1"
        );
    }

    #[test]
    fn auth_a_can_fd_frame_carries_both_pdus() {
        let mut rx = receiver();
        let payload = [2, 0, 0, 0, 0, 0, 0x20, 0x37];
        let fv = fresh(&rx);
        let mut fd = payload.to_vec();
        fd.extend_from_slice(&signed(payload, fv));
        assert!(matches!(
            rx.on_frame(T0_US, link().secured, &fd),
            Verdict::Accepted { freshness, .. } if freshness == fv
        ));
        assert_eq!(
            rx.on_frame(T0_US + 1, link().secured, &fd),
            Verdict::Refused(AuthFailure::Replayed)
        );
        assert_eq!(
            rx.on_frame(T0_US + 2, link().secured, &fd[..12]),
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
        let fv = freshness(EPOCH, 7);
        let auth = a.sign(FrameId::Standard(0x603), &p, fv);
        assert_eq!(
            a.verify_near(FrameId::Standard(0x603), &p, &auth, fv - 3),
            Some(fv)
        );
        assert_eq!(a.verify_near(FrameId::Standard(0x610), &p, &auth, fv), None);
        assert_eq!(a.verify_near(FrameId::Extended(0x603), &p, &auth, fv), None);
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
            prop_assert_eq!(a.verify_near(link().secured, &payload, &auth, fv), Some(fv));
            prop_assert_eq!(a.verify_near(link().secured, &p, &x, fv), None);
        }

        /// Whatever keyless frames arrive, in any order, the receiver's
        /// floor and marks never move, and never move backwards after.
        #[test]
        fn auth_keyless_frames_never_move_the_marks(frames in proptest::collection::vec((0usize..6, any::<[u8; 8]>()), 1..60)) {
            let mut rx = receiver();
            let ids = [link().secured, link().authenticator, ack_link().secured,
                       ack_link().authenticator, odom_link().secured, odom_link().authenticator];
            let payload = [1, 0, 0, 0, 0, 0, 0, 1];
            let fv = fresh(&rx);
            let first = send(&mut rx, T0_US, payload, signed(payload, fv));
            prop_assert!(matches!(first, Verdict::Accepted { .. }), "{:?}", first);
            let (sync, mark) = (rx.sync(), rx.last_accepted(link().secured));
            for (k, (which, data)) in frames.iter().enumerate() {
                let _ = rx.on_frame(T0_US + 1000 + k as u64, ids[*which], data);
            }
            prop_assert_eq!(rx.sync(), sync);
            prop_assert_eq!(rx.last_accepted(link().secured), mark);
        }
    }
}
