//! A slide on locked wheels: every wheel stops turning while the car goes
//! on, and no wheel can say how far.
//!
//! **What the sensors show.** Braking hard without ABS locks the wheels:
//! each wheel's speed falls to 0 within a tenth of a second, far faster than
//! tyres can slow a car (about 1 g). On the multi-body Escort (seed 103) all
//! four wheels fell from 11.1 m/s to 0 in 0.25 s, the car slid on at 8 m/s²
//! and the wheels rolled again 0.9 s later at 3.9 m/s: 6.8 m the wheels never
//! read, 0.6 % of that drive's distance per stop, in every estimator that
//! takes its distance from the wheels (the fused pose lost 10 m in two
//! such stops).
//!
//! **What this does.** The car's speed is followed as the wheels tell it,
//! changing no faster than a car can brake or accelerate
//! ([`EkfConfig::max_accel_mps2`]). When three or four wheels fall below
//! half that speed or out of that envelope, the car is sliding: its speed
//! is taken to fall at a locked tyre's friction
//! ([`EkfConfig::slide_decel_mps2`]) and each wheel is given the distance
//! the car covers times its share of the car's speed before the slide,
//! with the along-track variance of that prior: a slide in a turn goes on
//! along the curve it was on (with equal distances it went straight, and a
//! three-wheel lock in a 13°/s turn left the wheels-only heading 7° off on
//! the multi-body BMW, seed 205 of `generate.py --harsh`). When two
//! wheels roll together again, their speed is the car's: the slide
//! is taken as a constant deceleration from its start to that speed, and
//! the distance the prior got wrong is added in that sample. A slide that
//! ends in a stop (the wheels never roll again) ends when the prior's speed
//! reaches 0.
//!
//! Only for wheel-speed sensors with every wheel present: an encoder's
//! count per sample jumps by its quantum, and two wheels alone cannot tell
//! a lock from a stop.

use super::EkfConfig;
use super::wheels::Axle;
use crate::WheelSet;

/// Every wheel below this share of the car's speed is locked: a lock
/// drops a wheel to 0 within a tenth of a second.
const LOCKED_SHARE: f64 = 0.5;

/// How far below the car's envelope a wheel must fall to be locked, m/s:
/// a speed sensor's frame (25–40 ms) at the hardest braking, which a step
/// between two frames sees at once.
const ENVELOPE_MARGIN_MPS: f64 = 0.5;

/// A slide is this many wheels locked: with three locked, the fourth is
/// braked hard too and carries neither the distance nor the turn (the
/// multi-body BMW 320i, seed 101, locked three for a second; its fourth
/// read half the car's speed); one or two are left to the slip logic, which
/// has the other axle.
const MIN_LOCKED: usize = 3;

/// The wheels roll together again when the slowest reads at least this
/// share of the fastest (a 5 m circle's inner rear and outer front wheels
/// read 0.67 of each other; a wheel still locked reads 0).
const ROLLING_TOGETHER: f64 = 0.5;

/// How long the wheels must roll together before their speed is the
/// car's: a released wheel spins up over a few of its sensor's frames (the
/// multi-body Escort's rear wheels read 1.3 then 3.3 m/s 25 ms apart), and
/// a step's distance averages two readings.
const SETTLE_S: f64 = 0.1;

/// Time constant of each wheel's share of the car's speed, s: long enough
/// to smooth the speed signals' quantum, short enough to be the turn the
/// car was in when the wheels locked.
const SHARE_TAU_S: f64 = 0.25;

/// The slide tracker's state: the car's speed as the wheels last told it
/// and, during a slide, what was bridged. `Copy`, no allocation.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct Slide {
    /// The car's speed, m/s (magnitude), as the wheels tell it within
    /// [`EkfConfig::max_accel_mps2`]; during a slide, the prior's.
    speed_mps: f64,
    /// The direction of travel: +1 forwards, −1 backwards.
    sign: f64,
    /// The last speed the wheels told within [`EkfConfig::max_accel_mps2`] of the one
    /// before, m/s; the time since, s; and the distance the wheels gave
    /// since, m.
    anchor_mps: f64,
    anchor_s: f64,
    anchor_m: f64,
    /// A sample has set `speed_mps`.
    seen: bool,
    /// The car is sliding on locked wheels.
    sliding: bool,
    /// The slide's duration so far, s.
    elapsed_s: f64,
    /// The speed at the slide's start, m/s.
    entry_mps: f64,
    /// The distance given to the wheels during the slide, m.
    bridged_m: f64,
    /// How long the wheels have rolled together during the slide, s.
    rolling_s: f64,
    /// Each wheel's speed over the car's, smoothed over the samples in
    /// which no axle slipped (in the order of the distances: RL, RR, FL,
    /// FR); `shares_seen` once one has set it.
    shares: [f64; 4],
    shares_seen: bool,
}

/// A sample's wheels after the slide tracker.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Bridged {
    /// The wheel distances to use, m.
    pub(crate) wheel_m: WheelSet<f64>,
    /// The along-track variance this sample adds, m².
    pub(crate) var_m2: f64,
}

/// The second largest of four values: one spinning wheel cannot raise it,
/// two locked ones cannot lower it.
fn second_largest(v: [f64; 4]) -> f64 {
    let mut s = v;
    s.sort_by(f64::total_cmp);
    s[2]
}

impl Slide {
    /// Is a slide being bridged?
    #[cfg(test)]
    pub(crate) fn sliding(&self) -> bool {
        self.sliding
    }

    /// One sample of four wheel-speed sensors' distances `w` over `dt_s`
    /// seconds. `None` when the wheels are used as they are (nearly
    /// always); `floor_mps` is the speed below which a wheel-speed sensor
    /// may read 0 with the wheel turning, where a drop to 0 is a stop.
    /// `calm`: no axle slips (the shares of the car's speed learn only
    /// then). `spinning` is an axle spinning under drive torque
    /// ([`super::wheels::AxleWatch::spinning`]): the other axle then tells the car's speed,
    /// and no slide begins (two spinning wheels are the two fastest, and a
    /// car speed taken from them left the rolling pair below the envelope:
    /// the multi-body Escort, seed 204 of `generate.py --harsh`, bridged a
    /// spin as a slide at 7.5 m/s² while it accelerated).
    pub(crate) fn step(
        &mut self,
        cfg: &EkfConfig,
        w: &WheelSet<f64>,
        dt_s: f64,
        floor_mps: f64,
        calm: bool,
        spinning: Option<Axle>,
    ) -> Option<Bridged> {
        if !(dt_s > 0.0 && dt_s.is_finite()) {
            return None;
        }
        let d = [w.rear_left, w.rear_right, w.front_left, w.front_right];
        let speeds = d.map(|x| x.abs() / dt_s);
        // The speed the wheels tell.
        let told = match spinning {
            Some(Axle::Rear) => speeds[2].max(speeds[3]),
            Some(Axle::Front) => speeds[0].max(speeds[1]),
            None => second_largest(speeds),
        };
        if !self.sliding {
            // The speed the wheels last told within what a car can do, and
            // how far it may have changed since: the wheels' frames come
            // slower than the steps, so a change lands in one short step.
            let since_s = self.anchor_s + dt_s;
            let lo = (self.anchor_mps - cfg.max_accel_mps2 * since_s).max(0.0);
            let hi = self.anchor_mps + cfg.max_accel_mps2 * since_s;
            let car_mps = if self.seen { told.clamp(lo, hi) } else { told };
            // A wheel below half the car's speed is locked, and so is one
            // that fell out of the car's envelope: the lock shows there
            // first (a rear wheel at 0 beside one at speed turns the
            // wheels' heading by 20° in a fifth of a second).
            let floor_of_envelope = lo - ENVELOPE_MARGIN_MPS;
            let locked = speeds
                .iter()
                .filter(|v| **v < LOCKED_SHARE * car_mps || **v < floor_of_envelope)
                .count();
            let all_locked =
                spinning.is_none() && self.seen && car_mps > floor_mps && locked >= MIN_LOCKED;
            if !all_locked {
                if calm && told > floor_mps {
                    self.learn_shares(speeds, told, dt_s);
                }
                if !self.seen || (lo..=hi).contains(&told) {
                    self.anchor_mps = told;
                    self.anchor_s = 0.0;
                    self.anchor_m = 0.0;
                } else {
                    self.anchor_s = since_s;
                    self.anchor_m += told * dt_s;
                }
                self.speed_mps = car_mps;
                self.seen = true;
                let sum: f64 = d.iter().sum();
                if sum != 0.0 {
                    self.sign = sum.signum();
                }
                return None;
            }
            // The slide began when the wheels last told a speed a car can
            // have: what they read since is in the filter already.
            self.sliding = true;
            self.entry_mps = self.anchor_mps;
            self.elapsed_s = self.anchor_s;
            self.bridged_m = self.anchor_m;
            self.rolling_s = 0.0;
            self.speed_mps = (self.anchor_mps - cfg.slide_decel_mps2 * self.anchor_s).max(0.0);
        }
        let fastest = speeds.iter().fold(0.0f64, |m, v| m.max(*v));
        // The wheels roll again at a speed the car can have reached by now.
        let reachable = self.entry_mps - cfg.max_accel_mps2 * (self.elapsed_s + dt_s);
        // Two wheels rolling together at a speed the car can have now carry
        // the distance again (the slip logic has them); a slide of three
        // locked wheels or four goes on.
        let rolling_wheels = speeds
            .iter()
            .filter(|v| **v > 0.0 && **v >= ROLLING_TOGETHER * fastest && **v >= reachable)
            .count();
        let rolling = rolling_wheels >= 2 && told >= reachable;
        self.rolling_s = if rolling { self.rolling_s + dt_s } else { 0.0 };
        if self.rolling_s >= SETTLE_S {
            // A constant deceleration from the slide's start to this speed,
            // reached when the wheels began to roll together.
            let release_mps = told.min(self.entry_mps);
            let rolled_s = (self.rolling_s - dt_s).clamp(0.0, self.elapsed_s);
            let slid_m = 0.5 * (self.entry_mps + release_mps) * (self.elapsed_s - rolled_s)
                + release_mps * rolled_s;
            let missing_m = self.sign * (slid_m - self.bridged_m);
            self.sliding = false;
            self.speed_mps = told;
            self.anchor_mps = told;
            self.anchor_s = 0.0;
            return Some(Bridged {
                wheel_m: self.with_shares(missing_m, Some(w)),
                var_m2: 0.0,
            });
        }
        let before = self.speed_mps;
        let after = (before - cfg.slide_decel_mps2 * dt_s).max(0.0);
        // The prior's distance error grows as σ_a·t²/2: this sample's share
        // of its variance.
        let t0 = self.elapsed_s;
        let t1 = t0 + dt_s;
        let sd = |t: f64| 0.5 * cfg.slide_decel_sigma_mps2 * t * t;
        let var_m2 = sd(t1).powi(2) - sd(t0).powi(2);
        let step_m = if after > 0.0 {
            0.5 * (before + after) * dt_s
        } else {
            // Stopped within the sample.
            0.5 * before * before / cfg.slide_decel_mps2
        };
        self.speed_mps = after;
        self.elapsed_s = t1;
        self.bridged_m += step_m;
        if after == 0.0 {
            // The prior's car has stopped: the wheels at 0 are a standstill.
            self.sliding = false;
            self.anchor_mps = 0.0;
            self.anchor_s = 0.0;
        }
        Some(Bridged {
            wheel_m: self.with_shares(self.sign * step_m, None),
            var_m2,
        })
    }

    /// One calm sample's wheel speeds against the car's (`told`), into
    /// each wheel's smoothed share.
    fn learn_shares(&mut self, speeds: [f64; 4], told: f64, dt_s: f64) {
        let alpha = if self.shares_seen {
            (dt_s / SHARE_TAU_S).min(1.0)
        } else {
            1.0
        };
        for (share, v) in self.shares.iter_mut().zip(speeds) {
            *share += alpha * (v / told - *share);
        }
        self.shares_seen = true;
    }

    /// `centre_m` of the rear axle's centre given to each wheel by its
    /// share of the car's speed before the slide (the rear pair's mean
    /// share is 1; 1 each before any calm sample), added to `to`'s.
    fn with_shares(&self, centre_m: f64, to: Option<&WheelSet<f64>>) -> WheelSet<f64> {
        let rear = 0.5 * (self.shares[0] + self.shares[1]);
        let [rl, rr, fl, fr] = if self.shares_seen && rear > 0.0 {
            self.shares.map(|s| s / rear)
        } else {
            [1.0; 4]
        };
        let base = to.copied().unwrap_or(WheelSet::splat(0.0));
        WheelSet {
            rear_left: base.rear_left + centre_m * rl,
            rear_right: base.rear_right + centre_m * rr,
            front_left: base.front_left + centre_m * fl,
            front_right: base.front_right + centre_m * fr,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::road_car as cfg;
    use super::*;

    const DT: f64 = 0.02;

    /// Feeds `speeds` (m/s, each wheel) for `n` samples and collects the
    /// centre distance the filter would use.
    fn run(s: &mut Slide, speeds: [f64; 4], n: usize, total: &mut f64, var: &mut f64) {
        for _ in 0..n {
            let w = WheelSet {
                rear_left: speeds[0] * DT,
                rear_right: speeds[1] * DT,
                front_left: speeds[2] * DT,
                front_right: speeds[3] * DT,
            };
            let used = s
                .step(&cfg(), &w, DT, 1.5, true, None)
                .map_or((w, 0.0), |b| (b.wheel_m, b.var_m2));
            *total += 0.5 * (used.0.rear_left + used.0.rear_right);
            *var += used.1;
        }
    }

    #[test]
    fn a_locked_slide_is_bridged_to_the_speed_the_wheels_roll_again_at() {
        // 11 m/s, every wheel locks, the car slides 1.0 s at 6 m/s² (not the
        // prior's 7.5) and the wheels roll again at 5 m/s.
        let mut s = Slide::default();
        let (mut total, mut var) = (0.0, 0.0);
        run(&mut s, [11.0; 4], 50, &mut total, &mut var);
        let before = total;
        run(&mut s, [0.0; 4], 50, &mut total, &mut var);
        assert!(!s.sliding() || total > before, "nothing bridged");
        run(&mut s, [5.0; 4], 4, &mut total, &mut var);
        assert!(
            s.sliding(),
            "the wheels' first frames at 5 m/s ended the slide"
        );
        run(&mut s, [5.0; 4], 2, &mut total, &mut var);
        assert!(!s.sliding());
        // True: 8 m in the slide plus six samples at 5 m/s, 0.6 m.
        let slid = total - before;
        assert!((slid - 8.6).abs() < 0.15, "slid {slid} m");
        assert!(var > 0.0);
    }

    #[test]
    fn a_slide_in_a_turn_goes_on_along_the_curve_it_was_on() {
        // A left turn: the right wheels 3 % faster than the left. The
        // bridged distances keep each wheel's share, so the rear pair's
        // difference (the wheels' turn) goes on; equal distances went
        // straight. A share learns only while no axle slips.
        let turning = [9.7, 10.3, 9.9, 10.5];
        for calm in [true, false] {
            let mut s = Slide::default();
            for _ in 0..50 {
                let w = WheelSet {
                    rear_left: turning[0] * DT,
                    rear_right: turning[1] * DT,
                    front_left: turning[2] * DT,
                    front_right: turning[3] * DT,
                };
                assert!(s.step(&cfg(), &w, DT, 1.5, calm, None).is_none());
            }
            let b = s
                .step(&cfg(), &WheelSet::splat(0.0), DT, 1.5, calm, None)
                .expect("every wheel locked at 10 m/s is a slide");
            let w = b.wheel_m;
            let centre = 0.5 * (w.rear_left + w.rear_right);
            let share = |d: f64| d / centre;
            if calm {
                assert!((share(w.rear_right) - 10.3 / 10.0).abs() < 1e-9, "{w:?}");
                assert!((share(w.front_left) - 9.9 / 10.0).abs() < 1e-9, "{w:?}");
            } else {
                assert_eq!(w, WheelSet::splat(centre));
            }
        }
    }

    #[test]
    fn a_slide_that_ends_standing_takes_the_priors_distance() {
        let mut s = Slide::default();
        let (mut total, mut var) = (0.0, 0.0);
        run(&mut s, [10.0; 4], 50, &mut total, &mut var);
        let before = total;
        run(&mut s, [0.0; 4], 200, &mut total, &mut var);
        assert!(!s.sliding());
        let slid = total - before;
        let prior = 100.0 / (2.0 * cfg().slide_decel_mps2);
        assert!((slid - prior).abs() < 0.2, "slid {slid} m, prior {prior} m");
        // σ at the stop (1.33 s): 2.2 m, which covers 0.5–1 g.
        assert!(var.sqrt() > 1.5 && var.sqrt() < 3.0, "σ {} m", var.sqrt());
    }

    #[test]
    fn braking_a_car_can_do_and_a_stop_below_the_floor_are_not_slides() {
        // 1 g to a stop: the wheels slow with the car.
        let mut s = Slide::default();
        let (mut total, mut var) = (0.0, 0.0);
        let mut v: f64 = 12.0;
        while v > 0.0 {
            run(&mut s, [v; 4], 1, &mut total, &mut var);
            assert!(!s.sliding(), "at {v} m/s");
            v = (v - 9.81 * DT).max(0.0);
        }
        // The wheels drop to 0 from the sensors' floor (0.55 m/s).
        run(&mut s, [0.55; 4], 3, &mut total, &mut var);
        run(&mut s, [0.0; 4], 10, &mut total, &mut var);
        assert!(!s.sliding());
        assert_eq!(var, 0.0);
    }

    #[test]
    fn two_locked_wheels_are_left_to_the_slip_logic() {
        let mut s = Slide::default();
        let (mut total, mut var) = (0.0, 0.0);
        run(&mut s, [10.0; 4], 50, &mut total, &mut var);
        run(&mut s, [0.0, 0.0, 9.9, 9.9], 20, &mut total, &mut var);
        assert!(!s.sliding());
        assert_eq!(var, 0.0);
    }

    #[test]
    fn wheels_still_slipping_below_any_reachable_speed_do_not_end_the_slide() {
        // Every wheel rolls at 1 m/s 0.2 s after locking at 15 m/s: the car
        // cannot be that slow yet (at most 2.4 m/s less), so they still slip.
        let mut s = Slide::default();
        let (mut total, mut var) = (0.0, 0.0);
        run(&mut s, [15.0; 4], 50, &mut total, &mut var);
        run(&mut s, [0.0; 4], 5, &mut total, &mut var);
        run(&mut s, [1.0; 4], 5, &mut total, &mut var);
        assert!(s.sliding());
    }

    #[test]
    fn reversing_slides_backwards() {
        let mut s = Slide::default();
        let (mut total, mut var) = (0.0, 0.0);
        run(&mut s, [-4.0; 4], 50, &mut total, &mut var);
        let before = total;
        run(&mut s, [0.0; 4], 100, &mut total, &mut var);
        assert!(total - before < -0.5, "{}", total - before);
    }
}
