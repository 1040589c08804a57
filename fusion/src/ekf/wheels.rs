//! What the four wheels tell about themselves: a speed sensor's floor
//! (it reads 0 below about 2 km/h), a launch from below it, and which wheel
//! a rejected window blames.

use super::{OdometryInput, State};
use crate::{Wheel, WheelSet};

/// The fastest a wheel beside one reading 0 may go for that 0 to be the
/// speed sensors' floor (about 2 km/h, 0.6 m/s) rather than a lock, m/s.
pub(super) const MAX_FLOOR_FILL_MPS: f64 = 1.5;

/// The gentlest launch assumed, m/s²: a car that left a standstill unseen
/// by wheel-speed sensors (they read 0 below their floor) and is first seen
/// at `v` has crept at most `v²/(2a)` (0.28 m at 0.75 m/s). The multi-body
/// Escort (seed 3) crept 0.10 m before its first reading, 0.75 m/s,
/// 1.9 m/s² later.
pub(super) const LAUNCH_ACCEL_MPS2: f64 = 1.0;

/// Every wheel (the front pair only when valid) reads 0 in `w`: a car that
/// stands, or crawls below its wheel sensors' floor.
pub(super) fn every_wheel_reads_zero(input: &OdometryInput, w: &WheelSet<f64>) -> bool {
    w.rear_left == 0.0
        && w.rear_right == 0.0
        && (!input.front_valid || (w.front_left == 0.0 && w.front_right == 0.0))
}

/// The along-track variance, m², of what a car crept unseen before this
/// step: non-zero only on wheel-speed sensors ([`OdometryInput::zero_is_floor`])
/// in the first step that moves after one in which every wheel read 0.
/// The creep is taken as anywhere between 0 and `v²/(2a)` (second moment
/// of that range; its mean is not added to the pose, which would move a
/// car that truly stood until the sensors woke).
pub(super) fn launch_variance(st: &mut State, input: &OdometryInput, w: &WheelSet<f64>) -> f64 {
    let zero = every_wheel_reads_zero(input, w);
    let launched = input.zero_is_floor && st.wheels_were_zero && !zero;
    st.wheels_were_zero = zero;
    if !launched || input.dt_s.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return 0.0;
    }
    let speed_mps = 0.5 * (w.rear_left.abs() + w.rear_right.abs()) / input.dt_s;
    if speed_mps > MAX_FLOOR_FILL_MPS {
        // Not a floor's exit: the log's first step, or a gap in the wheels.
        return 0.0;
    }
    let creep_max_m = speed_mps * speed_mps / (2.0 * LAUNCH_ACCEL_MPS2);
    creep_max_m * creep_max_m / 3.0
}

/// The median of four values: the mean of the middle two.
fn median4(v: [f64; 4]) -> f64 {
    let mut s = v;
    s.sort_by(f64::total_cmp);
    0.5 * (s[1] + s[2])
}

/// Which wheel's implied centre distance is farthest from the median of the four.
fn consensus_outlier(centre_m: [f64; 4]) -> Wheel {
    let med = median4(centre_m);
    let mut worst = 0;
    for k in 1..4 {
        if (centre_m[k] - med).abs() > (centre_m[worst] - med).abs() {
            worst = k;
        }
    }
    WHEEL_ORDER[worst]
}

/// The wheel to blame. An axle that changed speed faster than a car can
/// while the other did not ([`AxleWatch`]) is the one slipping: its wheel
/// farther from the other axle is blamed. Otherwise both wheels of an axle
/// below half the other axle's mean are that axle locked (two wheels at 0
/// leave the median of four between the axles, where it blamed a rolling
/// front wheel and kept the locked rear: the multi-body BMW 320i, seed 5,
/// lost 4.7 m and 3.5° in one window); otherwise the wheel farthest from
/// the median of the four.
pub(super) fn blamed_wheel(centre_m: [f64; 4], suspect: Option<Axle>) -> Wheel {
    let [rl, rr, fl, fr] = centre_m.map(f64::abs);
    let (rear, front) = (0.5 * (rl + rr), 0.5 * (fl + fr));
    // Of a pair, the wheel farther from the other axle's mean.
    let farther = |(a, wa): (f64, Wheel), (b, wb): (f64, Wheel), other: f64| {
        if (a - other).abs() >= (b - other).abs() {
            wa
        } else {
            wb
        }
    };
    match suspect {
        Some(Axle::Rear) => {
            return farther((rl, Wheel::RearLeft), (rr, Wheel::RearRight), front);
        }
        Some(Axle::Front) => {
            return farther((fl, Wheel::FrontLeft), (fr, Wheel::FrontRight), rear);
        }
        None => {}
    }
    if rl.max(rr) < LOCKED_AXLE_SHARE * front {
        Wheel::RearLeft
    } else if fl.max(fr) < LOCKED_AXLE_SHARE * rear {
        Wheel::FrontLeft
    } else {
        consensus_outlier(centre_m)
    }
}

/// An axle whose wheels both read below this share of the other axle's is
/// locked: a spinning axle reads above the car, and a locked one 0.
const LOCKED_AXLE_SHARE: f64 = 0.5;

/// An axle of the car.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Axle {
    /// The rear axle (index 0 of [`AxleWatch`]'s pairs).
    Rear = 0,
    /// The front axle (index 1).
    Front = 1,
}

impl Axle {
    /// The axle of index `k` in [`AxleWatch`]'s pairs (rear, front).
    const BY_INDEX: [Axle; 2] = [Axle::Rear, Axle::Front];
}

/// How far an axle's speed may run from where the car's acceleration could
/// have taken it before it counts as slipping, m/s: the wheel-speed
/// signals' noise and a bump stay well within it, a lock (11 m/s to 0 in a
/// quarter second) or a spin (8 to 20 m/s in a tenth) far outside.
const AXLE_JUMP_MARGIN_MPS: f64 = 0.5;

/// The axles agree again when their speeds are this share apart, or
/// [`AXLE_AGREE_MPS`]: a turn's longer front arc and the tyres' slip
/// angles stay within it.
const AXLE_AGREE_SHARE: f64 = 0.1;
const AXLE_AGREE_MPS: f64 = 0.3;

/// Which axle slips, from how each axle's speed changes: the car's speed
/// cannot change faster than [`super::EkfConfig::max_accel_mps2`], so an
/// axle whose speed runs away from a tracker limited to that rate, while
/// the other's does not, is spinning or locking, and stays suspect until
/// the axles agree again.
///
/// Why the windowed filter needs it: a rejected window blames one wheel and
/// takes the other pair. With both driven wheels spinning at two to four
/// times the car's speed, the rolling front axle reads below half the rear,
/// which looks like a locked front: the multi-body Vanagon (seed 202 of
/// `generate.py --harsh`) kept its spinning rear for one window and turned
/// 79° in 0.6 s. A lock and a spin look alike in one window's distances;
/// how they began does not.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(super) struct AxleWatch {
    /// Each axle's speed (rear, front) as a car could have followed it:
    /// changing by at most the car's acceleration per step, m/s.
    tracked_mps: [f64; 2],
    /// What each axle read last, m/s.
    last_mps: [f64; 2],
    /// How far each axle read from its tracker at the last step, m/s
    /// (positive: faster than the car could have become).
    gap_mps: [f64; 2],
    /// A step has set `tracked_mps`.
    seen: bool,
    /// An axle under suspicion now.
    suspect: [bool; 2],
    /// An axle under suspicion at any step of the current window.
    in_window: [bool; 2],
    /// Each axle's largest distance from its tracker in the window, m/s.
    window_gap_mps: [f64; 2],
}

impl AxleWatch {
    /// One step's wheels (`w`, after the floor fill, before a slide's
    /// bridge replaces them). Wheel-speed sensors with all four wheels
    /// only: an encoder's count per sample jumps by its quantum, which is
    /// no change of speed.
    pub(super) fn watch(&mut self, input: &OdometryInput, w: &WheelSet<f64>, max_accel_mps2: f64) {
        if input.zero_is_floor && input.front_valid {
            let axle_m = [w.rear_left + w.rear_right, w.front_left + w.front_right];
            self.step(
                axle_m.map(|d| 0.5 * d.abs() / input.dt_s),
                input.dt_s,
                max_accel_mps2,
            );
        }
    }

    /// One step's rear and front axle speeds (m/s, magnitudes) over `dt_s`.
    pub(super) fn step(&mut self, speeds_mps: [f64; 2], dt_s: f64, max_accel_mps2: f64) {
        if !(dt_s > 0.0 && speeds_mps.iter().all(|v| v.is_finite())) {
            return;
        }
        self.last_mps = speeds_mps;
        if !self.seen {
            self.tracked_mps = speeds_mps;
            self.seen = true;
            return;
        }
        let step_mps = max_accel_mps2 * dt_s;
        for ((tracked, gap), speed) in self
            .tracked_mps
            .iter_mut()
            .zip(self.gap_mps.iter_mut())
            .zip(speeds_mps)
        {
            *tracked += (speed - *tracked).clamp(-step_mps, step_mps);
            *gap = speed - *tracked;
        }
        // An axle running from where the car could have gone is slipping;
        // of two, the one at least twice as far (a lock often begins with
        // the front braking a little harder than the car can, and then the
        // rear falls to 0), or both (a four-wheel lock).
        let [rear_gap, front_gap] = self.gap_mps.map(f64::abs);
        let jumped = [rear_gap, front_gap].map(|g| g > AXLE_JUMP_MARGIN_MPS);
        self.suspect = match jumped {
            [false, false] => self.suspect,
            [true, true] if rear_gap >= 2.0 * front_gap => [true, false],
            [true, true] if front_gap >= 2.0 * rear_gap => [false, true],
            jumped => jumped,
        };
        for k in 0..2 {
            self.in_window[k] |= self.suspect[k];
            self.window_gap_mps[k] = self.window_gap_mps[k].max(self.gap_mps[k].abs());
        }
        // The axles agree again: the slip is over, and the trackers start
        // afresh from what the wheels read (the slipping axle's had been
        // left behind at the car's rate).
        let [rear, front] = speeds_mps;
        if self.suspect != [false; 2]
            && (rear - front).abs() <= AXLE_AGREE_SHARE * rear.max(front) + AXLE_AGREE_MPS
        {
            self.suspect = [false; 2];
            self.tracked_mps = speeds_mps;
            self.gap_mps = [0.0; 2];
        }
    }

    /// The axle suspect in the window: the one that was, or of two the one
    /// that ran at least twice as far from where the car could go (a
    /// brake's onset dips the front by 2 m/s in a sample before the rear
    /// locks from 14 m/s to 0).
    pub(super) fn window_suspect(&self) -> Option<Axle> {
        let [rear_gap, front_gap] = self.window_gap_mps;
        match self.in_window {
            [true, false] => Some(Axle::Rear),
            [false, true] => Some(Axle::Front),
            [true, true] if rear_gap >= 2.0 * front_gap => Some(Axle::Rear),
            [true, true] if front_gap >= 2.0 * rear_gap => Some(Axle::Front),
            _ => None,
        }
    }

    /// The axle suspect now, reading faster than the other and faster than
    /// the car could have become: it spins, and the other tells the car's
    /// speed. (A locked axle reads below its tracker: never spinning.)
    pub(super) fn spinning(&self) -> Option<Axle> {
        let k = match self.suspect {
            [true, false] => 0,
            [false, true] => 1,
            _ => return None,
        };
        (self.last_mps[k] > self.last_mps[1 - k] && self.gap_mps[k] > AXLE_JUMP_MARGIN_MPS)
            .then_some(Axle::BY_INDEX[k])
    }

    /// No axle is suspect, and both move as a car can.
    pub(super) fn calm(&self) -> bool {
        self.suspect == [false; 2] && self.gap_mps.iter().all(|g| g.abs() <= AXLE_JUMP_MARGIN_MPS)
    }

    /// Did `axle` run away from where the car could go at some step of
    /// the window?
    pub(super) fn slipped_in_window(&self, axle: Axle) -> bool {
        self.window_gap_mps[axle as usize] > AXLE_JUMP_MARGIN_MPS
    }

    /// A new window begins: it inherits only what is suspect now.
    pub(super) fn new_window(&mut self) {
        self.in_window = self.suspect;
        self.window_gap_mps = self.gap_mps.map(f64::abs);
    }
}

/// How far `wheel`'s implied centre distance lies from the median of the
/// other three, relative to that median.
pub(super) fn outlier_excess(centre_m: [f64; 4], wheel: Wheel) -> f64 {
    let k = WHEEL_ORDER.iter().position(|w| *w == wheel).unwrap_or(0);
    let mut others = [0.0; 3];
    let mut n = 0;
    for (i, c) in centre_m.iter().enumerate() {
        if i != k {
            others[n] = *c;
            n += 1;
        }
    }
    others.sort_by(f64::total_cmp);
    let median = others[1];
    if median.abs() > 1e-12 {
        ((centre_m[k] - median) / median).abs()
    } else {
        f64::INFINITY
    }
}

/// The order of `State::centre_m`: as [`crate::odometry::wheel_distance_factors`] returns them.
const WHEEL_ORDER: [Wheel; 4] = [
    Wheel::RearLeft,
    Wheel::RearRight,
    Wheel::FrontLeft,
    Wheel::FrontRight,
];
