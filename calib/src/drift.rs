//! The drift watch (issue #46 item 3): whether what the car's drive says
//! of a parameter now differs from the set in use by more than the
//! parameter's tolerance and more than `k` of the learnt value's σ, with
//! hysteresis so that a flag clears once the car agrees again and does not
//! flicker on the way.
//!
//! Pure: the readings come from a drive fit ([`readings`]) and the judge
//! ([`Watch::judge`]) returns the next state and what changed; logging,
//! the state file and the status frames are the caller's.

use crate::drive::{DriveCalibration, Estimate};
use crate::front_ratio::FrontRatio;
use crate::history::ParamValues;

/// How many parameters the drift watch judges.
pub const PARAMS: usize = 8;

/// A parameter the drift watch judges.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Param {
    /// The mean effective rear wheel diameter, relative (a speed scale).
    SpeedScale,
    /// The rear wheels' right/left diameter ratio, relative.
    RearRatio,
    /// The effective rear tread, relative.
    RearTread,
    /// The steering map's gain, relative.
    SteerGain,
    /// The steering map's offset, rad.
    SteerOffset,
    /// The yaw-rate sensor's bias, rad/s.
    YawBias,
    /// The yaw-rate sensor's scale, relative.
    YawScale,
    /// The front wheels' right/left diameter ratio, relative
    /// ([`crate::front_ratio`]). No parameter set carries the front
    /// tyres, so it is judged against its value at the watch's first
    /// reading ([`Watcher::front_reading`]): a front tyre losing pressure.
    FrontRatio,
}

impl Param {
    /// Every parameter, in the order they are reported.
    pub const ALL: [Self; PARAMS] = [
        Self::SpeedScale,
        Self::RearRatio,
        Self::RearTread,
        Self::SteerGain,
        Self::SteerOffset,
        Self::YawBias,
        Self::YawScale,
        Self::FrontRatio,
    ];

    /// The name logs, the state file and the learnt CSV use (the online
    /// calibration's estimate names, so a flag and its estimate match).
    pub fn name(self) -> &'static str {
        match self {
            Self::SpeedScale => "speed_scale",
            Self::RearRatio => "rear_ratio",
            Self::RearTread => "rear_tread",
            Self::SteerGain => "steer_gain",
            Self::SteerOffset => "steer_offset_rad",
            Self::YawBias => "yaw_bias_radps",
            Self::YawScale => "yaw_scale",
            Self::FrontRatio => "front_ratio",
        }
    }

    /// The parameter of `name` ([`Param::name`]), if it is one.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|p| p.name() == name)
    }

    /// Its index in [`Param::ALL`].
    fn index(self) -> usize {
        self as usize
    }
}

/// The tolerances and the σ multiple of the watch (`[calibration.drift]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriftConfig {
    /// A difference must exceed this many of the learnt value's σ (default 4).
    pub k_sigma: f64,
    /// Each parameter's tolerance, in its unit ([`Param`]), indexed as
    /// [`Param::ALL`]: a difference must exceed it.
    pub tolerance: [f64; PARAMS],
}

/// The share of its tolerance a flagged parameter's difference must fall
/// to before its flag clears. Half: a value that wanders around its
/// tolerance (σ of a refit a third of it, as the defaults make it) crosses
/// the tolerance now and then but rarely half of it, so a flag does not
/// flicker; and a car that really agrees again (a tyre pumped back up, a
/// set committed) lands well inside half.
pub const CLEAR_SHARE: f64 = 0.5;

/// The share of `window_s` a refit's fixes must span before the watch
/// judges it. The tolerances and `k_sigma` are set against what a refit of
/// the whole window tells ([`DriftConfig::default`]); a refit of the first
/// minute of fixes — at the start of a drive, or after an outage longer
/// than the window — sees too few turns for its σ to be honest: on the
/// multi-body BMW 320i of seed 125 the first refit, on 61 fixes, flagged
/// the steering gain of a car whose steering had not changed, and the next
/// refit cleared it. Nine tenths rather than all: fixes at 1 Hz span a
/// second less than the window they fill.
pub const FULL_WINDOW_SHARE: f64 = 0.9;

/// The time `fixes` span: the last one's time minus the first's, s (0 for
/// fewer than two).
pub fn fixes_span_s(fixes: &[crate::drive::Fix]) -> f64 {
    match (fixes.first(), fixes.last()) {
        (Some(a), Some(b)) => (b.t_s - a.t_s).max(0.0),
        _ => 0.0,
    }
}

/// Whether a refit whose fixes span `fixes_span_s` (its last fix's time
/// minus its first's) is judged by a watch refitting `window_s`
/// ([`FULL_WINDOW_SHARE`]). An unbounded window is judged at any span.
pub fn window_is_full(fixes_span_s: f64, window_s: f64) -> bool {
    !window_s.is_finite() || fixes_span_s >= FULL_WINDOW_SHARE * window_s
}

impl Default for DriftConfig {
    /// What a user of the odometry needs, against what a refit of three
    /// minutes of consumer fixes (σ 1.5 m) can tell:
    /// - speed scale 0.2 %: 2 m a kilometre, the drive gate's σ bound
    ///   (`max_speed_scale_std`), and the least wheel error the filter
    ///   applies by itself (the kinematic model's misfit on real tyres
    ///   reaches 0.1 %); a tyre 0.5 % soft moves it by 0.25 %.
    /// - rear ratio 0.2 %: on a 1.5 m tread a heading drift of 0.08° a
    ///   metre turns the rear wheels' pose a third of the distance off
    ///   (README: a rear tyre 0.3 % off), the same bound as the filter's.
    /// - rear tread 2 %: every turn's angle 2 % off on the wheels alone. A
    ///   refit's effective tread is that of the turns in its window (the
    ///   tyres' side slip in curves, issue #46): on a steady multi-body BMW
    ///   it scattered from −1.3 % to +0.9 % between 3-minute refits, each
    ///   with a σ of 0.2–0.3 %, and at 1 % it raised a flag on a car that
    ///   had not changed; the tread is not what a tyre's pressure or wear
    ///   changes.
    /// - steering gain 1 % and offset 0.2° (road wheel): the steering is the
    ///   third heading source; 0.2° at 10 m/s on a 2.7 m wheelbase is
    ///   0.7 °/s of turn the steering gets wrong, a few times the gate's σ.
    /// - yaw-rate bias 0.05 °/s: a degree in 20 s of driving blind, the
    ///   drive gate's σ bound (`max_yaw_bias_std_dps`).
    /// - yaw-rate scale 0.2 %: 0.7° a full circle; the gyro of
    ///   0.5 % is 2.5 times it.
    /// - front ratio 0.2 %: as the rear's (a tyre 0.5 % soft is 2.5
    ///   tolerances). Its reading is steadier than a refit's: on nine
    ///   steady 20-minute multi-body drives it stayed within 0.05 % of
    ///   its first 3-minute window, with a σ of 0.0005–0.011 %.
    ///
    /// And `k_sigma` 4, from the false flags a user can live with: none in
    /// many hours of steady driving (issue #46: none in an hour). The
    /// watch judges seven parameters at every refit whose σ can reach
    /// their tolerance (the front ratio's is a twentieth of it or less), once a
    /// minute over 3-minute windows, so about 20 independent judgements an
    /// hour each, 140 in all. At 3 σ each crosses by noise alone with a chance of
    /// 0.27 %: a false flag every 2.6 hours wherever k σ rather than the
    /// tolerance decides (the speed scale's σ of 0.1–0.15 % makes 3 σ
    /// 0.3–0.45 %, past its 0.2 % tolerance); at 4 σ, 6.3·10⁻⁵: one in
    /// 110 hours. Measured at 3 σ on nine 20-minute multi-body drives, the
    /// BMW 320i of seed 106 flagged its speed scale at −0.44 % ± 0.14 %
    /// (3.1 σ); at 4 σ nothing is flagged on them, and the tyre changes
    /// (0.5 %: 2.5 rear-ratio tolerances, tens of σ) are flagged as early.
    fn default() -> Self {
        Self {
            k_sigma: 4.0,
            tolerance: [
                0.002,
                0.002,
                0.02,
                0.01,
                0.2f64.to_radians(),
                0.05f64.to_radians(),
                0.002,
                0.002,
            ],
        }
    }
}

impl DriftConfig {
    /// The tolerance of `p`, in its unit.
    pub fn tolerance(&self, p: Param) -> f64 {
        self.tolerance[p.index()]
    }
}

/// One parameter as a refit learnt it, against the set in use.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reading {
    /// Which.
    pub param: Param,
    /// The learnt value, in the parameter's unit on the scale of `in_use`
    /// (relative parameters relative to the set the drive was recorded with).
    pub learnt: f64,
    /// Its σ.
    pub sigma: f64,
    /// The set in use's value on the same scale (for
    /// [`Param::FrontRatio`], which no set carries, the watch's first
    /// reading of it: [`Watcher::front_reading`]).
    pub in_use: f64,
}

impl Reading {
    /// Learnt minus in use.
    pub fn difference(&self) -> f64 {
        self.learnt - self.in_use
    }
}

/// The readings of a drive fit `cal`, made of samples recorded with `base`
/// in use, against the set `in_use` (which may since differ from `base`):
/// one per parameter the drive told and the gate passed (the others say
/// nothing about drift). Relative parameters are relative to `base`.
pub fn readings(base: &ParamValues, cal: &DriveCalibration, in_use: &ParamValues) -> Vec<Reading> {
    let mut out = Vec::new();
    let mut push = |param, e: &Estimate, learnt: f64, sigma: f64, in_use: f64| {
        if e.observable && learnt.is_finite() && sigma.is_finite() && in_use.is_finite() {
            out.push(Reading {
                param,
                learnt,
                sigma,
                in_use,
            });
        }
    };
    // The wheels: k_L = s·2/(1+r), k_R = s·2r/(1+r) multiply base's diameters.
    let k_l = in_use.rear_left_diameter_m / base.rear_left_diameter_m;
    let k_r = in_use.rear_right_diameter_m / base.rear_right_diameter_m;
    let s = &cal.speed_scale;
    push(Param::SpeedScale, s, s.value, s.sigma, 0.5 * (k_l + k_r));
    let r = &cal.rear_ratio;
    push(Param::RearRatio, r, r.value, r.sigma, k_r / k_l);
    let t = &cal.rear_tread;
    push(
        Param::RearTread,
        t,
        t.value,
        t.sigma,
        in_use.rear_tread_m / base.rear_tread_m,
    );
    // φ = g·(gain·u + offset) + o: the learnt map's gain relative to base's
    // and its offset in radians of road-wheel angle.
    let g = cal
        .steer_gain
        .filter(|e| e.observable)
        .map_or(1.0, |e| e.value);
    if let Some(e) = &cal.steer_gain {
        push(
            Param::SteerGain,
            e,
            e.value,
            e.sigma,
            in_use.steering_gain / base.steering_gain,
        );
    }
    if let Some(e) = &cal.steer_offset_rad {
        push(
            Param::SteerOffset,
            e,
            g * base.steering_offset_rad + e.value,
            e.sigma,
            in_use.steering_offset_rad,
        );
    }
    // The samples carried ω_raw / c0 (c0 the scale in use when recorded):
    // ω_raw = c0·c·ω + c0·b, so the sensor's own bias and scale are c0·b, c0·c.
    let c0 = base.yaw_rate_scale.unwrap_or(1.0);
    if let Some(e) = &cal.yaw_bias_radps {
        push(
            Param::YawBias,
            e,
            c0 * e.value,
            c0 * e.sigma,
            in_use.yaw_rate_bias_radps.unwrap_or(0.0),
        );
    }
    if let Some(e) = &cal.yaw_scale {
        push(
            Param::YawScale,
            e,
            c0 * e.value,
            c0 * e.sigma,
            in_use.yaw_rate_scale.unwrap_or(1.0),
        );
    }
    out
}

/// How many of a parameter's past refits [`SigmaFloor`] remembers.
pub const SIGMA_HISTORY: usize = 5;

/// A refit's σ is itself an estimate (the jackknife over a window's few
/// stretches), and now and then it comes out well below what the window's
/// driving can tell: on the multi-body drives the refits that raised false
/// flags reported σ far under their neighbours' (Escort 121: speed scale
/// ± 0.11 % against a median ± 0.16 %, steering gain ± 0.12 % against
/// ± 0.25 %). What a window of ordinary driving tells changes little from
/// one refit to the next, and a changed tyre moves the value, not how well
/// it is told; so each reading is judged with at least the median σ of the
/// parameter's last [`SIGMA_HISTORY`] readings.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SigmaFloor {
    past: [Vec<f64>; PARAMS],
}

impl SigmaFloor {
    /// `readings` with each σ raised to the median of its parameter's last
    /// readings' σ (none before the first), then remembered.
    pub fn apply(&mut self, readings: &[Reading]) -> Vec<Reading> {
        readings
            .iter()
            .map(|r| {
                let past = &mut self.past[r.param.index()];
                let floor = median(past);
                past.push(r.sigma);
                if past.len() > SIGMA_HISTORY {
                    past.remove(0);
                }
                Reading {
                    sigma: r.sigma.max(floor),
                    ..*r
                }
            })
            .collect()
    }
}

/// The drift watch as a caller keeps it between refits: the flags, the
/// σ floor their judgements use, and the front tyres' ratio its first
/// reading found.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Watcher {
    watch: Watch,
    floor: SigmaFloor,
    front_baseline: Option<FrontRatio>,
}

impl Watcher {
    /// The flags now.
    pub fn watch(&self) -> Watch {
        self.watch
    }

    /// The front tyres' ratio the watch judges against (its first reading,
    /// or one restored), if it has one.
    pub fn front_baseline(&self) -> Option<FrontRatio> {
        self.front_baseline
    }

    /// Takes `baseline` as the front tyres' first reading (what a previous
    /// run of the daemon judged against, from its state file), so that a
    /// front tyre changed while the car stood is judged as one changed
    /// while it drove. A baseline that is not a plausible ratio (not
    /// finite, beyond ±10 %, a σ not finite) is ignored; returns whether it
    /// was taken.
    pub fn restore_front_baseline(&mut self, baseline: FrontRatio) -> bool {
        let plausible = (baseline.value - 1.0).abs() < 0.1
            && baseline.sigma.is_finite()
            && baseline.sigma >= 0.0;
        if plausible {
            self.front_baseline = Some(baseline);
        }
        plausible
    }

    /// A refit's readings: those of its fit `cal` (made of samples recorded
    /// with `base`, against `in_use`: [`readings`]) and of the front tyres'
    /// ratio it read ([`Self::front_reading`]); none of a fit not judged.
    pub fn refit_readings(
        &mut self,
        base: &ParamValues,
        cal: Option<&DriveCalibration>,
        front: Option<&FrontRatio>,
        in_use: &ParamValues,
    ) -> Vec<Reading> {
        let mut read = cal
            .map(|cal| readings(base, cal, in_use))
            .unwrap_or_default();
        read.extend(front.map(|f| self.front_reading(f)));
        read
    }

    /// A refit's front tyres' ratio as a reading to judge
    /// ([`Param::FrontRatio`]). No parameter set carries the front tyres,
    /// so what it is judged against is the ratio of the watch's first
    /// reading (the car as the watch found it: a pair of front tyres that
    /// already differ is no drift), with that reading's σ added to this
    /// one's. The first reading itself is judged against itself.
    pub fn front_reading(&mut self, front: &FrontRatio) -> Reading {
        let base = *self.front_baseline.get_or_insert(*front);
        Reading {
            param: Param::FrontRatio,
            learnt: front.value,
            sigma: front.sigma.hypot(base.sigma),
            in_use: base.value,
        }
    }

    /// Judges a refit's `readings` ([`SigmaFloor`], then [`Watch::judge`]):
    /// what changed.
    pub fn judge(&mut self, readings: &[Reading], config: &DriftConfig) -> Vec<Change> {
        let floored = self.floor.apply(readings);
        let (next, changes) = self.watch.judge(&floored, config);
        self.watch = next;
        changes
    }
}

/// The median of `values` (0 when empty).
fn median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => 0.0,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

/// What a judgement changed for one parameter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Change {
    /// The reading that changed it.
    pub reading: Reading,
    /// True: the flag rose; false: it cleared.
    pub raised: bool,
}

/// The drift flags, one per parameter.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Watch {
    flags: [bool; PARAMS],
}

impl Watch {
    /// Whether `p` is flagged.
    pub fn flagged(&self, p: Param) -> bool {
        self.flags[p.index()]
    }

    /// Whether any parameter is flagged.
    pub fn any(&self) -> bool {
        self.flags.iter().any(|f| *f)
    }

    /// The flagged parameters, in [`Param::ALL`]'s order.
    pub fn flagged_params(&self) -> Vec<Param> {
        Param::ALL
            .into_iter()
            .filter(|p| self.flagged(*p))
            .collect()
    }

    /// The watch with the flags of `params` set (a state taken back from
    /// the state file).
    pub fn with_flags(params: &[Param]) -> Self {
        let mut w = Self::default();
        for p in params {
            w.flags[p.index()] = true;
        }
        w
    }

    /// The watch after a refit's `readings`: a flag rises when the
    /// difference exceeds both the tolerance and `k_sigma` σ, and clears
    /// when it is back within [`CLEAR_SHARE`] of the tolerance. A parameter
    /// without a reading keeps its flag: a refit that cannot tell it says
    /// nothing about it.
    pub fn judge(self, readings: &[Reading], config: &DriftConfig) -> (Self, Vec<Change>) {
        let mut next = self;
        let mut changes = Vec::new();
        for r in readings {
            let d = r.difference().abs();
            let tol = config.tolerance(r.param);
            let i = r.param.index();
            let was = next.flags[i];
            let now = if was {
                d > CLEAR_SHARE * tol
            } else {
                d > tol && d > config.k_sigma * r.sigma
            };
            if now != was {
                next.flags[i] = now;
                changes.push(Change {
                    reading: *r,
                    raised: now,
                });
            }
        }
        (next, changes)
    }
}

/// How far one automatic commit (`[calibration] auto_commit = true`) may
/// move each parameter, in its drift tolerances. A refit can be wrong
/// without the gate seeing it (the steady drives' closest call, the tread
/// at 1.24 %, would have raised a flag at a 1 % tolerance), and nobody
/// looks at an automatic commit: two tolerances bound what one wrong refit
/// does to the odometry to twice what the watch itself lets pass, while a
/// real change of a tyre (0.5 % soft: 2.5 speed-scale tolerances) is
/// followed in two commits, the second after the next refit confirms it.
pub const AUTO_STEP_TOLERANCES: f64 = 2.0;

/// The set one automatic commit takes: `candidate`, each value moved from
/// `in_use` by at most [`AUTO_STEP_TOLERANCES`] of its tolerance: the rear
/// diameters relative by the speed scale's, the tread, steering gain and
/// yaw-rate scale relative by theirs, the steering offset and the yaw-rate
/// bias absolute (an absent yaw-rate correction counts as bias 0, scale 1).
pub fn bounded_step(
    in_use: &ParamValues,
    candidate: &ParamValues,
    config: &DriftConfig,
) -> ParamValues {
    let step = |p: Param| AUTO_STEP_TOLERANCES * config.tolerance(p);
    let relative = |from: f64, to: f64, p: Param| {
        let s = step(p);
        (to / from).clamp(1.0 - s, 1.0 + s) * from
    };
    let absolute = |from: f64, to: f64, p: Param| {
        let s = step(p);
        to.clamp(from - s, from + s)
    };
    let optional = |from: Option<f64>, to: Option<f64>, none: f64, f: &dyn Fn(f64, f64) -> f64| {
        to.map(|to| f(from.unwrap_or(none), to))
    };
    ParamValues {
        rear_tread_m: relative(
            in_use.rear_tread_m,
            candidate.rear_tread_m,
            Param::RearTread,
        ),
        rear_left_diameter_m: relative(
            in_use.rear_left_diameter_m,
            candidate.rear_left_diameter_m,
            Param::SpeedScale,
        ),
        rear_right_diameter_m: relative(
            in_use.rear_right_diameter_m,
            candidate.rear_right_diameter_m,
            Param::SpeedScale,
        ),
        steering_gain: relative(
            in_use.steering_gain,
            candidate.steering_gain,
            Param::SteerGain,
        ),
        steering_offset_rad: absolute(
            in_use.steering_offset_rad,
            candidate.steering_offset_rad,
            Param::SteerOffset,
        ),
        yaw_rate_bias_radps: optional(
            in_use.yaw_rate_bias_radps,
            candidate.yaw_rate_bias_radps,
            0.0,
            &|a, b| absolute(a, b, Param::YawBias),
        ),
        yaw_rate_scale: optional(
            in_use.yaw_rate_scale,
            candidate.yaw_rate_scale,
            1.0,
            &|a, b| relative(a, b, Param::YawScale),
        ),
        yaw_rate_bias_sigma_radps: candidate.yaw_rate_bias_sigma_radps,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn reading(param: Param, difference: f64, sigma: f64) -> Reading {
        Reading {
            param,
            learnt: 1.0 + difference,
            sigma,
            in_use: 1.0,
        }
    }

    #[test]
    fn a_difference_beyond_tolerance_and_k_sigma_raises_and_a_small_one_clears() {
        let c = DriftConfig::default();
        let w = Watch::default();
        // 0.3 % of speed scale with σ 0.05 %: beyond 0.2 % and 4σ.
        let (w, ch) = w.judge(&[reading(Param::SpeedScale, 0.003, 0.0005)], &c);
        assert!(w.flagged(Param::SpeedScale) && ch.len() == 1 && ch[0].raised);
        assert_eq!(w.flagged_params(), vec![Param::SpeedScale]);
        // Back to 0.15 %: inside the tolerance, not inside half of it: held.
        let (w, ch) = w.judge(&[reading(Param::SpeedScale, 0.0015, 0.0005)], &c);
        assert!(w.flagged(Param::SpeedScale) && ch.is_empty());
        // No reading: held.
        let (w, ch) = w.judge(&[], &c);
        assert!(w.flagged(Param::SpeedScale) && ch.is_empty());
        // 0.05 %: cleared.
        let (w, ch) = w.judge(&[reading(Param::SpeedScale, -0.0005, 0.0005)], &c);
        assert!(!w.any() && ch.len() == 1 && !ch[0].raised);
    }

    #[test]
    fn a_sigma_far_below_the_last_refits_is_raised_to_their_median() {
        let mut floor = SigmaFloor::default();
        // The first reading has nothing to compare with: kept.
        let out = floor.apply(&[reading(Param::SpeedScale, 0.003, 0.0016)]);
        assert_eq!(out[0].sigma, 0.0016);
        for s in [0.0015, 0.0017, 0.0016] {
            floor.apply(&[reading(Param::SpeedScale, 0.0, s)]);
        }
        // 0.48 % with σ 0.11 % would be 4.4σ beyond; with its neighbours'
        // 0.16 % it is 3σ: not flagged.
        let out = floor.apply(&[reading(Param::SpeedScale, 0.0048, 0.0011)]);
        assert!((out[0].sigma - 0.0016).abs() < 1e-12);
        let (w, _) = Watch::default().judge(&out, &DriftConfig::default());
        assert!(!w.any());
        // A larger σ than the neighbours' is kept; other parameters have
        // their own history.
        let out = floor.apply(&[
            reading(Param::SpeedScale, 0.0, 0.003),
            reading(Param::RearRatio, 0.005, 0.0001),
        ]);
        assert_eq!((out[0].sigma, out[1].sigma), (0.003, 0.0001));
        // Only the last SIGMA_HISTORY readings count.
        let mut floor = SigmaFloor::default();
        for _ in 0..SIGMA_HISTORY {
            floor.apply(&[reading(Param::RearRatio, 0.0, 0.01)]);
        }
        for _ in 0..SIGMA_HISTORY {
            floor.apply(&[reading(Param::RearRatio, 0.0, 0.0001)]);
        }
        let out = floor.apply(&[reading(Param::RearRatio, 0.0, 0.00005)]);
        assert_eq!(out[0].sigma, 0.0001);
    }

    #[test]
    fn only_a_refit_spanning_most_of_its_window_is_judged() {
        // 1 Hz fixes filling a 180 s window span 179 s: judged.
        assert!(window_is_full(179.0, 180.0));
        assert!(window_is_full(162.0, 180.0));
        // The first refits of a drive's fixes, a minute and two in: not.
        assert!(!window_is_full(60.0, 180.0));
        assert!(!window_is_full(161.9, 180.0));
        // A watch refitting everything so far has no window to fill.
        assert!(window_is_full(5.0, f64::INFINITY));
    }

    #[test]
    fn a_difference_beyond_tolerance_within_k_sigma_is_not_flagged() {
        let c = DriftConfig::default();
        // 0.3 % with σ 0.2 %: 1.5σ, the refit cannot tell it.
        let (w, ch) = Watch::default().judge(&[reading(Param::RearRatio, 0.003, 0.002)], &c);
        assert!(!w.any() && ch.is_empty());
    }

    #[test]
    fn the_yaw_bias_reads_as_the_sensors_own_and_a_scale_in_use_is_undone() {
        let base = ParamValues {
            yaw_rate_scale: Some(1.01),
            yaw_rate_bias_radps: Some(0.002),
            ..ParamValues::plain(1.5, 0.6)
        };
        let est = |value, observable| Estimate {
            value,
            sigma: 1e-4,
            observable,
        };
        let cal = DriveCalibration {
            speed_scale: est(1.003, true),
            rear_ratio: est(1.0, false),
            steer_offset_rad: None,
            steer_gain: None,
            yaw_bias_radps: Some(est(0.004, true)),
            yaw_scale: Some(est(0.99, true)),
            yaw_bias_noise_sigma_radps: None,
            rear_tread: est(1.0, false),
            turns_rad: [0.0; 2],
            fixes_latency_s: est(0.2, true),
            latency_given: false,
            down_weighted: Vec::new(),
            weighted_rms_m: [None; 3],
            own_fit_rms_m: [None; 3],
            fixes_sigma_m: 1.5,
            fixes_sigma_stated: true,
            refused: Vec::new(),
            fixes_used: 100,
            distance_m: 1000.0,
            residual_rms_m: [None; 3],
        };
        // In use: the left wheel 0.1 % larger than base's.
        let in_use = ParamValues {
            rear_left_diameter_m: 0.6 * 1.001,
            ..base
        };
        let r = readings(&base, &cal, &in_use);
        let names: Vec<&str> = r.iter().map(|r| r.param.name()).collect();
        assert_eq!(names, ["speed_scale", "yaw_bias_radps", "yaw_scale"]);
        assert!((r[0].in_use - 1.0005).abs() < 1e-12 && (r[0].learnt - 1.003).abs() < 1e-12);
        assert!((r[1].learnt - 1.01 * 0.004).abs() < 1e-12 && (r[1].in_use - 0.002).abs() < 1e-12);
        assert!((r[2].learnt - 1.01 * 0.99).abs() < 1e-12 && (r[2].in_use - 1.01).abs() < 1e-12);
    }

    #[test]
    fn an_automatic_step_moves_each_value_at_most_twice_its_tolerance() {
        let c = DriftConfig::default();
        let in_use = ParamValues::plain(1.5, 0.65);
        let candidate = ParamValues {
            rear_left_diameter_m: 0.65 * 0.99,
            rear_right_diameter_m: 0.65 * 1.001,
            rear_tread_m: 1.5 * 1.01,
            steering_offset_rad: 1f64.to_radians(),
            yaw_rate_bias_radps: Some(0.01f64.to_radians()),
            ..in_use
        };
        let b = bounded_step(&in_use, &candidate, &c);
        // 1 % smaller: held to 0.4 %; 0.1 % and the tread's 1 %: taken whole.
        assert!((b.rear_left_diameter_m / 0.65 - 0.996).abs() < 1e-12);
        assert!((b.rear_right_diameter_m - candidate.rear_right_diameter_m).abs() < 1e-12);
        assert!((b.rear_tread_m - candidate.rear_tread_m).abs() < 1e-12);
        // 1° of offset: 0.4°; the bias from none (0) taken whole.
        assert!((b.steering_offset_rad - 0.4f64.to_radians()).abs() < 1e-12);
        assert_eq!(b.yaw_rate_bias_radps, candidate.yaw_rate_bias_radps);
        assert_eq!(b.yaw_rate_scale, None);
        assert_eq!(bounded_step(&in_use, &in_use, &c), in_use);
    }

    #[test]
    fn the_front_tyres_are_judged_against_their_first_reading() {
        let config = DriftConfig::default();
        let mut w = Watcher::default();
        let front = |value: f64, sigma: f64| FrontRatio {
            value,
            sigma,
            distance_m: 600.0,
        };
        // A pair that already differs by 0.3 % is how the watch found the
        // car: no drift.
        let first = w.front_reading(&front(1.003, 0.00002));
        assert_eq!(
            (first.learnt, first.in_use, first.param),
            (1.003, 1.003, Param::FrontRatio)
        );
        assert!(w.judge(&[first], &config).is_empty());
        let steady = w.front_reading(&front(1.0032, 0.00003));
        assert_eq!(steady.in_use, 1.003);
        assert!((steady.sigma - 0.00002f64.hypot(0.00003)).abs() < 1e-12);
        assert!(w.judge(&[steady], &config).is_empty());
        // The front-left tyre loses 0.5 %: flagged, then cleared once
        // pumped back up.
        let soft = w.front_reading(&front(1.0081, 0.00003));
        let changes = w.judge(&[soft], &config);
        assert!(changes.len() == 1 && changes[0].raised, "{changes:?}");
        assert!(w.watch().flagged(Param::FrontRatio));
        let pumped = w.front_reading(&front(1.0035, 0.00003));
        let changes = w.judge(&[pumped], &config);
        assert!(changes.len() == 1 && !changes[0].raised, "{changes:?}");
        // A change within its window spreads the reading's parts: a σ that
        // wide keeps it from a flag until the window holds the change.
        let mixed = w.front_reading(&front(1.0060, 0.0008));
        assert!(w.judge(&[mixed], &config).is_empty());
    }

    #[test]
    fn a_restored_front_baseline_flags_a_tyre_changed_while_the_car_stood() {
        let config = DriftConfig::default();
        let front = |value: f64| FrontRatio {
            value,
            sigma: 0.00003,
            distance_m: 600.0,
        };
        let mut w = Watcher::default();
        assert!(w.restore_front_baseline(front(1.001)));
        let r = w.front_reading(&front(0.996));
        assert_eq!(r.in_use, 1.001);
        let changes = w.judge(&[r], &config);
        assert!(changes.len() == 1 && changes[0].raised, "{changes:?}");
        // Nonsense from a damaged file is ignored: the first reading is
        // the baseline again.
        for bad in [f64::NAN, 1.5, 0.0] {
            let mut w = Watcher::default();
            assert!(!w.restore_front_baseline(front(bad)));
            assert_eq!(w.front_reading(&front(0.996)).in_use, 0.996);
        }
        let mut w = Watcher::default();
        assert!(!w.restore_front_baseline(FrontRatio {
            sigma: f64::INFINITY,
            ..front(1.0)
        }));
        assert_eq!(w.front_reading(&front(0.996)).in_use, 0.996);
    }

    #[test]
    fn names_round_trip() {
        for p in Param::ALL {
            assert_eq!(Param::from_name(p.name()), Some(p));
        }
        assert_eq!(Param::from_name("tread"), None);
    }

    fn any_param() -> impl Strategy<Value = Param> {
        (0usize..PARAMS).prop_map(|i| Param::ALL[i])
    }

    proptest! {
        /// A flag never rises on a difference within the tolerance or
        /// within k σ, whatever the sign.
        #[test]
        fn no_flag_within_tolerance_or_k_sigma(p in any_param(), share in -1.0f64..1.0, sigma in 0.0f64..0.01, beyond in 1.0f64..3.0) {
            let c = DriftConfig::default();
            let tol = c.tolerance(p);
            let (w, _) = Watch::default().judge(&[reading(p, share * tol, sigma)], &c);
            prop_assert!(!w.any());
            // Beyond the tolerance but within k σ.
            let d = beyond * tol;
            let (w, _) = Watch::default().judge(&[reading(p, d, d / c.k_sigma * 1.0001)], &c);
            prop_assert!(!w.any());
        }

        /// Automatic steps each within their bound reach any candidate.
        #[test]
        fn repeated_automatic_steps_reach_the_candidate(scale in 0.9f64..1.1, offset in -0.05f64..0.05) {
            let c = DriftConfig::default();
            let in_use = ParamValues::plain(1.5, 0.65);
            let candidate = ParamValues {
                rear_left_diameter_m: 0.65 * scale,
                steering_offset_rad: offset,
                ..in_use
            };
            let mut v = in_use;
            for _ in 0..100 {
                let next = bounded_step(&v, &candidate, &c);
                prop_assert!((next.rear_left_diameter_m / v.rear_left_diameter_m - 1.0).abs() <= 0.004 + 1e-12);
                prop_assert!((next.steering_offset_rad - v.steering_offset_rad).abs() <= 0.4f64.to_radians() + 1e-12);
                v = next;
            }
            prop_assert!((v.rear_left_diameter_m - candidate.rear_left_diameter_m).abs() < 1e-12);
            prop_assert!((v.steering_offset_rad - offset).abs() < 1e-12);
        }

        /// Once up, a flag holds for every difference above half the
        /// tolerance, however the σ varies (no flicker), and clears below.
        #[test]
        fn a_raised_flag_holds_above_half_the_tolerance(p in any_param(), seq in proptest::collection::vec((-3.0f64..3.0, 0.0f64..0.05), 1..20)) {
            let c = DriftConfig::default();
            let tol = c.tolerance(p);
            let (mut w, _) = Watch::default().judge(&[reading(p, 2.0 * tol, 0.0)], &c);
            prop_assert!(w.flagged(p));
            for (share, sigma) in seq {
                let before = w.flagged(p);
                let (next, changes) = w.judge(&[reading(p, share * tol, sigma)], &c);
                if before {
                    prop_assert_eq!(next.flagged(p), share.abs() > CLEAR_SHARE);
                } else {
                    prop_assert_eq!(next.flagged(p), share.abs() > 1.0 && share.abs() * tol > c.k_sigma * sigma);
                }
                prop_assert_eq!(changes.len(), usize::from(next.flagged(p) != before));
                // Other parameters are untouched.
                prop_assert_eq!(next.flagged_params().len(), usize::from(next.flagged(p)));
                w = next;
            }
        }
    }
}
