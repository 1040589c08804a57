//! Wheel inputs as real vehicles send them, turned into checked distance increments.
//!
//! Two kinds exist on real vehicles:
//! - **cumulative tick counters** of any width (1..=64 bits) that wrap around
//!   and count down when the wheel turns backwards ([`TickDecoder`]): the
//!   increment is the signed shortest difference modulo `2^bits`;
//! - **wheel speeds** in m/s or km/h ([`SpeedDecoder`]), integrated over the
//!   samples' timestamps.
//!
//! Each decoder checks every sample and reports an [`InputFault`] (and counts
//! it in [`FaultCounts`]) for a timestamp going backwards, a duplicated
//! sample, missed samples, and a jump larger than the configured maximum
//! wheel speed allows. A faulty sample is never integrated as a huge step.
//!
//! The shortest-delta rule is ambiguous once a wheel can turn more than half
//! the counter range between two samples; [`TickDecoder::new`] refuses a
//! configuration where that can happen within one nominal period.

use crate::error::{Error, Result, require_positive};

// The fault type lives with the crate's error enum, which carries it.
pub use crate::error::InputFault;

/// How many faults of each kind a decoder has seen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FaultCounts {
    /// [`InputFault::TimestampBackwards`].
    pub timestamp_backwards: u64,
    /// [`InputFault::DuplicateSample`].
    pub duplicate: u64,
    /// [`InputFault::MissedSamples`] events (not lost samples).
    pub missed: u64,
    /// [`InputFault::ImplausibleJump`].
    pub implausible_jump: u64,
    /// [`InputFault::NonFinite`].
    pub non_finite: u64,
}

impl FaultCounts {
    fn count(&mut self, fault: &InputFault) {
        match fault {
            InputFault::TimestampBackwards { .. } => self.timestamp_backwards += 1,
            InputFault::DuplicateSample { .. } => self.duplicate += 1,
            InputFault::MissedSamples { .. } => self.missed += 1,
            InputFault::ImplausibleJump { .. } => self.implausible_jump += 1,
            InputFault::NonFinite { .. } => self.non_finite += 1,
        }
    }

    /// The total number of faults.
    pub fn total(&self) -> u64 {
        self.timestamp_backwards
            + self.duplicate
            + self.missed
            + self.implausible_jump
            + self.non_finite
    }
}

/// Checks shared by both decoders.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InputConfig {
    /// The period at which the vehicle sends the wheel message.
    pub nominal_period_s: f64,
    /// A gap longer than `gap_factor × nominal_period_s` is reported as missed samples.
    pub gap_factor: f64,
    /// The fastest a wheel can physically roll; larger increments are faults.
    pub max_wheel_speed_mps: f64,
}

impl InputConfig {
    /// 100 Hz messages, gaps over 1.5 periods reported, 5 m/s maximum (a 1:10 car).
    pub const RC_CAR: Self = Self {
        nominal_period_s: 0.01,
        gap_factor: 1.5,
        max_wheel_speed_mps: 5.0,
    };

    /// 50 Hz messages, gaps over 1.5 periods reported, 70 m/s maximum (a road car).
    pub const ROAD_CAR: Self = Self {
        nominal_period_s: 0.02,
        gap_factor: 1.5,
        max_wheel_speed_mps: 70.0,
    };

    fn validate(&self) -> Result<()> {
        for (name, v) in [
            ("nominal_period_s", self.nominal_period_s),
            ("gap_factor", self.gap_factor),
            ("max_wheel_speed_mps", self.max_wheel_speed_mps),
        ] {
            require_positive(name, v)?;
        }
        if self.gap_factor < 1.0 {
            return Err(Error::InvalidConfig {
                name: "gap_factor",
                reason: format!("must be >= 1, got {}", self.gap_factor),
            });
        }
        Ok(())
    }

    /// Checks the time step; `Err` carries the fault for a sample not to integrate.
    fn check_time(
        &self,
        prev_t_s: f64,
        t_s: f64,
    ) -> std::result::Result<Option<InputFault>, InputFault> {
        if !t_s.is_finite() {
            return Err(InputFault::NonFinite { value: t_s });
        }
        if t_s < prev_t_s {
            return Err(InputFault::TimestampBackwards { prev_t_s, t_s });
        }
        if t_s == prev_t_s {
            return Err(InputFault::DuplicateSample { t_s });
        }
        let gap_s = t_s - prev_t_s;
        if gap_s > self.gap_factor * self.nominal_period_s {
            let missed = ((gap_s / self.nominal_period_s).round() as u64)
                .saturating_sub(1)
                .max(1);
            return Ok(Some(InputFault::MissedSamples { gap_s, missed }));
        }
        Ok(None)
    }
}

/// The signed shortest difference `raw − prev_raw` of a counter that wraps at
/// `2^bits`, in `[−2^(bits−1), 2^(bits−1))`. Bits above `bits` are ignored.
///
/// # Errors
/// [`Error::InvalidCounterWidth`] unless `1 <= bits <= 64`.
pub fn wrapping_delta(prev_raw: u64, raw: u64, bits: u32) -> Result<i64> {
    if !(1..=64).contains(&bits) {
        return Err(Error::InvalidCounterWidth { bits });
    }
    let diff = raw.wrapping_sub(prev_raw);
    if bits == 64 {
        return Ok(diff as i64);
    }
    // Sign-extend the low `bits` bits: shift them to the top and back arithmetically.
    let shift = 64 - bits;
    Ok(((diff << shift) as i64) >> shift)
}

/// A decoded wheel sample.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct WheelStep {
    /// The wheel's distance since the previous integrated sample (0 on a fault that skips it).
    pub distance_m: f64,
    /// The tick increment (0 for speed inputs).
    pub ticks: i64,
    /// The time since the previous sample that this step covers (0 when skipped).
    pub dt_s: f64,
    /// What was wrong with the sample, if anything.
    pub fault: Option<InputFault>,
}

/// Decodes one wheel's cumulative, wrapping tick counter.
#[derive(Debug, Clone, PartialEq)]
pub struct TickDecoder {
    bits: u32,
    distance_per_tick_m: f64,
    config: InputConfig,
    last: Option<(f64, u64)>,
    cumulative_ticks: i64,
    faults: FaultCounts,
}

impl TickDecoder {
    /// A decoder for a `bits`-wide counter of a wheel that rolls
    /// `distance_per_tick_m` per tick (π D / Re, see [`crate::VehicleParams::tick_distance_m`]).
    ///
    /// # Errors
    /// [`Error::InvalidCounterWidth`], or [`Error::InvalidConfig`] for a
    /// non-positive value, or when the maximum wheel speed could turn the
    /// counter by half its range within one nominal period (the shortest
    /// delta would then be ambiguous).
    pub fn new(bits: u32, distance_per_tick_m: f64, config: InputConfig) -> Result<Self> {
        if !(1..=64).contains(&bits) {
            return Err(Error::InvalidCounterWidth { bits });
        }
        config.validate()?;
        require_positive("distance_per_tick_m", distance_per_tick_m)?;
        let max_ticks = config.max_wheel_speed_mps * config.nominal_period_s / distance_per_tick_m;
        let half_range = 2f64.powi(bits as i32 - 1);
        if max_ticks >= half_range {
            return Err(Error::InvalidConfig {
                name: "max_wheel_speed_mps",
                reason: format!(
                    "{max_ticks:.0} ticks per period can exceed half of a {bits}-bit counter; \
                     the wrap-around would be ambiguous"
                ),
            });
        }
        Ok(Self {
            bits,
            distance_per_tick_m,
            config,
            last: None,
            cumulative_ticks: 0,
            faults: FaultCounts::default(),
        })
    }

    /// Feeds one sample: the counter's raw value at time `t_s`. The first
    /// sample only anchors the counter (distance 0).
    pub fn push(&mut self, t_s: f64, raw: u64) -> WheelStep {
        let Some((prev_t_s, prev_raw)) = self.last else {
            if !t_s.is_finite() {
                return self.fault(InputFault::NonFinite { value: t_s });
            }
            self.last = Some((t_s, raw));
            return WheelStep::default();
        };
        let gap = match self.config.check_time(prev_t_s, t_s) {
            Ok(gap) => gap,
            Err(fault) => return self.fault(fault),
        };
        // The width was validated in `new`, so this cannot fail.
        let ticks = wrapping_delta(prev_raw, raw, self.bits).unwrap_or(0);
        let dt_s = t_s - prev_t_s;
        let distance_m = ticks as f64 * self.distance_per_tick_m;
        // The counter is cumulative, so its delta is real distance however the
        // frames were bunched on the way: what bounds it is the time the
        // sender had, at least one nominal period per frame, not the receive
        // gap (a busy host or canplayer delivers frames microseconds apart).
        // One tick of quantisation is allowed on top of the speed limit.
        let max_distance_m = self.config.max_wheel_speed_mps
            * dt_s.max(self.config.nominal_period_s)
            + self.distance_per_tick_m;
        self.last = Some((t_s, raw));
        if distance_m.abs() > max_distance_m {
            return self.fault(InputFault::ImplausibleJump {
                distance_m,
                dt_s,
                max_distance_m,
            });
        }
        self.cumulative_ticks += ticks;
        if let Some(f) = &gap {
            self.faults.count(f);
        }
        WheelStep {
            distance_m,
            ticks,
            dt_s,
            fault: gap,
        }
    }

    fn fault(&mut self, fault: InputFault) -> WheelStep {
        self.faults.count(&fault);
        WheelStep {
            fault: Some(fault),
            ..WheelStep::default()
        }
    }

    /// The ticks integrated since the first sample (faulty jumps excluded).
    pub fn cumulative_ticks(&self) -> i64 {
        self.cumulative_ticks
    }

    /// The faults seen so far.
    pub fn faults(&self) -> FaultCounts {
        self.faults
    }

    /// Forgets the last sample: the next one only anchors again (after a bus outage).
    pub fn reset(&mut self) {
        self.last = None;
    }
}

/// The unit of a wheel-speed signal.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SpeedUnit {
    /// Metres per second.
    MetresPerSecond,
    /// Kilometres per hour (production cars, e.g. the Toyota file's `WHEEL_SPEEDS`).
    KilometresPerHour,
}

impl SpeedUnit {
    /// Converts a speed in this unit to m/s.
    pub fn to_mps(self, speed: f64) -> f64 {
        match self {
            SpeedUnit::MetresPerSecond => speed,
            SpeedUnit::KilometresPerHour => speed / 3.6,
        }
    }

    /// Converts a speed in m/s to this unit.
    pub fn from_mps(self, speed_mps: f64) -> f64 {
        match self {
            SpeedUnit::MetresPerSecond => speed_mps,
            SpeedUnit::KilometresPerHour => speed_mps * 3.6,
        }
    }
}

/// How a sampled speed is integrated into distance between two timestamps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SpeedIntegration {
    /// `(v_prev + v) / 2 · dt`: exact for speeds varying linearly between
    /// samples, second-order accurate otherwise. The default, because wheel
    /// speeds sampled at instants (as the simulator and most ABS units give
    /// them) are best interpolated; it costs half a period of delay.
    Trapezoid,
    /// `v_prev · dt`: the speed holds until the next sample. Right when the
    /// ECU sends a speed that it then holds, and causal without delay.
    PreviousHold,
}

/// Decodes one wheel's speed signal into distance increments.
#[derive(Debug, Clone, PartialEq)]
pub struct SpeedDecoder {
    unit: SpeedUnit,
    integration: SpeedIntegration,
    config: InputConfig,
    last: Option<(f64, f64)>,
    faults: FaultCounts,
}

impl SpeedDecoder {
    /// A decoder for speeds in `unit`.
    ///
    /// # Errors
    /// [`Error::InvalidConfig`] for a non-positive configuration value.
    pub fn new(
        unit: SpeedUnit,
        integration: SpeedIntegration,
        config: InputConfig,
    ) -> Result<Self> {
        config.validate()?;
        Ok(Self {
            unit,
            integration,
            config,
            last: None,
            faults: FaultCounts::default(),
        })
    }

    /// Feeds one sample: the signed speed (in the decoder's unit) at time `t_s`.
    /// The first sample only anchors (distance 0). A speed above the maximum
    /// is a fault: the previous speed is held over the interval instead.
    pub fn push(&mut self, t_s: f64, speed: f64) -> WheelStep {
        if !speed.is_finite() {
            return self.fault(InputFault::NonFinite { value: speed });
        }
        let speed_mps = self.unit.to_mps(speed);
        let Some((prev_t_s, prev_mps)) = self.last else {
            if !t_s.is_finite() {
                return self.fault(InputFault::NonFinite { value: t_s });
            }
            if speed_mps.abs() > self.config.max_wheel_speed_mps {
                return self.fault(InputFault::ImplausibleJump {
                    distance_m: speed_mps * self.config.nominal_period_s,
                    dt_s: self.config.nominal_period_s,
                    max_distance_m: self.config.max_wheel_speed_mps * self.config.nominal_period_s,
                });
            }
            self.last = Some((t_s, speed_mps));
            return WheelStep::default();
        };
        let gap = match self.config.check_time(prev_t_s, t_s) {
            Ok(gap) => gap,
            Err(fault) => return self.fault(fault),
        };
        let dt_s = t_s - prev_t_s;
        if speed_mps.abs() > self.config.max_wheel_speed_mps {
            let max_distance_m = self.config.max_wheel_speed_mps * dt_s;
            let fault = InputFault::ImplausibleJump {
                distance_m: speed_mps * dt_s,
                dt_s,
                max_distance_m,
            };
            self.faults.count(&fault);
            self.last = Some((t_s, prev_mps));
            return WheelStep {
                distance_m: prev_mps * dt_s,
                ticks: 0,
                dt_s,
                fault: Some(fault),
            };
        }
        let distance_m = match self.integration {
            SpeedIntegration::Trapezoid => 0.5 * (prev_mps + speed_mps) * dt_s,
            SpeedIntegration::PreviousHold => prev_mps * dt_s,
        };
        self.last = Some((t_s, speed_mps));
        if let Some(f) = &gap {
            self.faults.count(f);
        }
        WheelStep {
            distance_m,
            ticks: 0,
            dt_s,
            fault: gap,
        }
    }

    fn fault(&mut self, fault: InputFault) -> WheelStep {
        self.faults.count(&fault);
        WheelStep {
            fault: Some(fault),
            ..WheelStep::default()
        }
    }

    /// The faults seen so far.
    pub fn faults(&self) -> FaultCounts {
        self.faults
    }

    /// Forgets the last sample: the next one only anchors again.
    pub fn reset(&mut self) {
        self.last = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn mask(bits: u32) -> u64 {
        if bits == 64 {
            u64::MAX
        } else {
            (1u64 << bits) - 1
        }
    }

    fn decoder(bits: u32) -> TickDecoder {
        // 1 mm per tick, 1 m/s max at 100 Hz: at most 11 ticks per sample, fits 8 bits.
        let cfg = InputConfig {
            nominal_period_s: 0.01,
            gap_factor: 1.5,
            max_wheel_speed_mps: 1.0,
        };
        TickDecoder::new(bits, 0.001, cfg).unwrap()
    }

    #[test]
    fn delta_wraps_forward_and_backward() {
        assert_eq!(wrapping_delta(250, 4, 8).unwrap(), 10);
        assert_eq!(wrapping_delta(4, 250, 8).unwrap(), -10);
        assert_eq!(wrapping_delta(4090, 5, 12).unwrap(), 11);
        assert_eq!(wrapping_delta(65_530, 2, 16).unwrap(), 8);
        assert_eq!(wrapping_delta(1, u64::from(u32::MAX), 32).unwrap(), -2);
        assert_eq!(wrapping_delta(u64::MAX, 0, 64).unwrap(), 1);
        assert_eq!(wrapping_delta(0, 1, 1).unwrap(), -1);
        assert!(wrapping_delta(0, 1, 0).is_err() && wrapping_delta(0, 1, 65).is_err());
    }

    #[test]
    fn ambiguous_configuration_is_refused() {
        let cfg = InputConfig {
            nominal_period_s: 0.01,
            gap_factor: 1.5,
            max_wheel_speed_mps: 20.0,
        };
        // 200 ticks per period against a half range of 128.
        assert!(TickDecoder::new(8, 0.001, cfg).is_err());
        assert!(TickDecoder::new(9, 0.001, cfg).is_ok());
        assert!(TickDecoder::new(16, 0.0, cfg).is_err());
        assert!(
            TickDecoder::new(
                16,
                0.001,
                InputConfig {
                    gap_factor: 0.5,
                    ..cfg
                }
            )
            .is_err()
        );
    }

    #[test]
    fn bunched_frames_keep_every_tick() {
        // 100 Hz frames at 0.4 m/s (4 ticks of 1 mm per period) that reach the
        // host in bursts of five, 20 µs apart: every tick is real distance.
        let mut d = decoder(16);
        let mut t_s = 0.0;
        let mut total = 0;
        d.push(t_s, 0);
        for i in 1..=200u64 {
            t_s += if i % 5 == 0 {
                0.05 - 4.0 * 20e-6
            } else {
                20e-6
            };
            let s = d.push(t_s, (i * 4) & 0xFFFF);
            assert!(s.fault.is_none() || matches!(s.fault, Some(InputFault::MissedSamples { .. })));
            total += s.ticks;
        }
        assert_eq!((total, d.cumulative_ticks()), (800, 800));
        assert_eq!(d.faults().implausible_jump, 0);
    }

    #[test]
    fn genuine_jumps_are_refused_even_when_bunched() {
        let mut d = decoder(16);
        d.push(0.0, 1000);
        // A counter reset (to 0) 20 µs later: 1 m in what can be one period at most.
        let s = d.push(20e-6, 0);
        assert!(matches!(s.fault, Some(InputFault::ImplausibleJump { .. })) && s.ticks == 0);
        // A corrupted value after a normal period.
        d.push(0.01 + 20e-6, 4);
        let s = d.push(0.02 + 20e-6, 4 + 3000);
        assert!(matches!(s.fault, Some(InputFault::ImplausibleJump { .. })) && s.ticks == 0);
        assert_eq!(d.faults().implausible_jump, 2);
        assert_eq!(d.cumulative_ticks(), 4);
    }

    #[test]
    fn faults_are_reported_counted_and_not_integrated() {
        let mut d = decoder(16);
        assert_eq!(d.push(0.0, 100).distance_m, 0.0);
        let s = d.push(0.01, 105);
        assert!((s.distance_m - 0.005).abs() < 1e-15 && s.fault.is_none());
        // Duplicate: same timestamp.
        let s = d.push(0.01, 107);
        assert!(matches!(s.fault, Some(InputFault::DuplicateSample { .. })) && s.distance_m == 0.0);
        // Backwards.
        let s = d.push(0.005, 110);
        assert!(
            matches!(s.fault, Some(InputFault::TimestampBackwards { .. })) && s.distance_m == 0.0
        );
        // The duplicate's movement is not lost: the next delta counts from 105.
        let s = d.push(0.02, 110);
        assert_eq!(s.ticks, 5);
        // A gap of 5 periods with plausible movement: integrated and reported.
        let s = d.push(0.07, 140);
        assert_eq!(s.ticks, 30);
        assert!(matches!(
            s.fault,
            Some(InputFault::MissedSamples { missed: 4, .. })
        ));
        // A jump of 5000 ticks in 10 ms (500 m/s): refused, then re-anchored.
        let s = d.push(0.08, 5140);
        assert!(matches!(s.fault, Some(InputFault::ImplausibleJump { .. })) && s.ticks == 0);
        let s = d.push(0.09, 5145);
        assert_eq!((s.ticks, s.fault), (5, None));
        let f = d.faults();
        assert_eq!(
            (
                f.duplicate,
                f.timestamp_backwards,
                f.missed,
                f.implausible_jump,
                f.total()
            ),
            (1, 1, 1, 1, 4)
        );
        assert_eq!(d.cumulative_ticks(), 5 + 5 + 30 + 5);
        assert!(matches!(
            d.push(f64::NAN, 1).fault,
            Some(InputFault::NonFinite { .. })
        ));
    }

    #[test]
    fn speeds_in_kmh_integrate_by_trapezoid_or_hold() {
        let cfg = InputConfig::ROAD_CAR;
        let mut trap = SpeedDecoder::new(
            SpeedUnit::KilometresPerHour,
            SpeedIntegration::Trapezoid,
            cfg,
        )
        .unwrap();
        let mut hold = SpeedDecoder::new(
            SpeedUnit::KilometresPerHour,
            SpeedIntegration::PreviousHold,
            cfg,
        )
        .unwrap();
        // Speed rising linearly from 0 to 36 km/h (10 m/s) over 1 s: 5 m exactly.
        let (mut dt, mut dh) = (0.0, 0.0);
        for k in 0..=50 {
            let t = f64::from(k) * 0.02;
            dt += trap.push(t, 36.0 * t).distance_m;
            dh += hold.push(t, 36.0 * t).distance_m;
        }
        assert!((dt - 5.0).abs() < 1e-12, "{dt}");
        assert!((dh - 4.9).abs() < 1e-9, "{dh}");
        // 300 km/h is beyond the 70 m/s limit: hold the previous speed and report.
        let s = trap.push(1.02, 300.0);
        assert!(matches!(s.fault, Some(InputFault::ImplausibleJump { .. })));
        assert!((s.distance_m - 0.2).abs() < 1e-12);
        assert!(matches!(
            trap.push(1.02, 36.0).fault,
            Some(InputFault::DuplicateSample { .. })
        ));
        assert!(matches!(
            trap.push(1.04, f64::NAN).fault,
            Some(InputFault::NonFinite { .. })
        ));
        assert_eq!(trap.faults().total(), 3);
    }

    proptest! {
        #[test]
        fn random_sequences_reconstruct_the_true_count(
            bits in prop::sample::select(vec![8u32, 12, 16, 32]),
            start in any::<i64>(),
            steps in prop::collection::vec(-10i64..=10, 1..400),
        ) {
            let mut d = decoder(bits);
            let mut truth = start;
            d.push(0.0, (truth as u64) & mask(bits));
            for (k, step) in steps.iter().enumerate() {
                truth = truth.wrapping_add(*step);
                let s = d.push((k + 1) as f64 * 0.01, (truth as u64) & mask(bits));
                prop_assert_eq!(s.fault, None);
                prop_assert_eq!(s.ticks, *step);
            }
            prop_assert_eq!(d.cumulative_ticks(), truth.wrapping_sub(start));
        }

        #[test]
        fn reversing_across_the_wrap_point_counts_down(bits in prop::sample::select(vec![8u32, 12, 16, 32]), n in 1i64..11) {
            let mut d = decoder(bits);
            let top = mask(bits);
            d.push(0.0, 2);
            // Backwards through zero: 2 → top − (n − 3) …
            let s = d.push(0.01, (2u64.wrapping_sub(n as u64)) & top);
            prop_assert_eq!(s.ticks, -n);
            prop_assert!(s.distance_m < 0.0);
            let s = d.push(0.02, 2);
            prop_assert_eq!(s.ticks, n);
        }

        #[test]
        fn delta_is_the_shortest_signed_difference(bits in 1u32..=64, a in any::<u64>(), b in any::<u64>()) {
            let d = wrapping_delta(a, b, bits).unwrap();
            let m = mask(bits);
            prop_assert_eq!((a.wrapping_add(d as u64)) & m, b & m);
            let half = if bits == 64 { i64::MIN } else { -(1i64 << (bits - 1)) };
            prop_assert!(d >= half && (bits == 64 || d < -half));
        }
    }
}
