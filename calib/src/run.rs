//! A recorded calibration run and its validation.
//!
//! The core representation is what the wheels *did*, independent of the
//! parameters in use: per sample, each wheel's revolutions since the previous
//! sample (ticks / Re, or speed · dt / (π D_used)), the timestamp and the
//! steering signal. Replaying a run with any candidate (tread, D_L, D_R)
//! gives its odometry, so every calibration method is a pure function of
//! (accepted runs, parameters used while recording).

use std::f64::consts::PI;

use canodom_fusion::{Pose, VehicleParams, Wheel, odometry, params::rear_diameters_for_ratio};

use crate::error::{Error, Result, positive};
use crate::track::{Direction, Track};

/// The rear-axle parameters a replay uses: the quantities calibration changes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RearParams {
    /// Rear tread b in metres.
    pub tread_m: f64,
    /// Rear left wheel diameter D_L in metres.
    pub left_diameter_m: f64,
    /// Rear right wheel diameter D_R in metres.
    pub right_diameter_m: f64,
}

impl RearParams {
    /// Checked constructor.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] unless all three are finite and > 0.
    pub fn new(tread_m: f64, left_diameter_m: f64, right_diameter_m: f64) -> Result<Self> {
        Ok(Self {
            tread_m: positive("tread_m", tread_m)?,
            left_diameter_m: positive("left_diameter_m", left_diameter_m)?,
            right_diameter_m: positive("right_diameter_m", right_diameter_m)?,
        })
    }

    /// The rear parameters of a vehicle parameter set.
    pub fn of(params: &VehicleParams) -> Self {
        Self {
            tread_m: params.rear_tread_m(),
            left_diameter_m: params.wheel_diameter_m(Wheel::RearLeft),
            right_diameter_m: params.wheel_diameter_m(Wheel::RearRight),
        }
    }

    /// Tread `tread_m` and diameters with ratio E = D_R/D_L around the mean
    /// `mean_diameter_m` (§7: calibration keeps the mean).
    ///
    /// # Errors
    /// As [`RearParams::new`].
    pub fn from_ratio(tread_m: f64, mean_diameter_m: f64, ratio: f64) -> Result<Self> {
        positive("ratio", ratio)?;
        let (left, right) = rear_diameters_for_ratio(mean_diameter_m, ratio);
        Self::new(tread_m, left, right)
    }

    /// E = D_R / D_L.
    pub fn ratio(&self) -> f64 {
        self.right_diameter_m / self.left_diameter_m
    }

    /// D̄ = (D_R + D_L) / 2.
    pub fn mean_diameter_m(&self) -> f64 {
        0.5 * (self.left_diameter_m + self.right_diameter_m)
    }

    /// `params` with these rear values.
    ///
    /// # Errors
    /// As [`VehicleParams::with_rear`].
    pub fn apply_to(&self, params: &VehicleParams) -> Result<VehicleParams> {
        Ok(params.with_rear(self.tread_m, self.left_diameter_m, self.right_diameter_m)?)
    }
}

/// One sample of a run: what each wheel turned since the previous sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RevSample {
    /// Timestamp in seconds (any origin, increasing).
    pub t_s: f64,
    /// Rear left wheel revolutions since the previous sample.
    pub rear_left_rev: f64,
    /// Rear right wheel revolutions since the previous sample.
    pub rear_right_rev: f64,
    /// Front (left, right) wheel revolutions, when the vehicle has front encoders.
    pub front_rev: Option<[f64; 2]>,
    /// The steering signal `u` as the vehicle reports it (mapped to an angle
    /// by the parameters' steering map).
    pub steer_signal: f64,
}

impl RevSample {
    /// A sample from tick increments: revolutions = N / Re.
    pub fn from_ticks(
        params: &VehicleParams,
        t_s: f64,
        rear_ticks: [f64; 2],
        front_ticks: Option<[f64; 2]>,
        steer_signal: f64,
    ) -> Self {
        let re = f64::from(params.encoder_ticks_per_rev());
        Self {
            t_s,
            rear_left_rev: rear_ticks[0] / re,
            rear_right_rev: rear_ticks[1] / re,
            front_rev: front_ticks.map(|[l, r]| [l / re, r / re]),
            steer_signal,
        }
    }

    /// A sample from wheel distances computed with `params` (e.g. integrated
    /// wheel speeds): revolutions = d / (π D_used).
    pub fn from_distances(
        params: &VehicleParams,
        t_s: f64,
        rear_m: [f64; 2],
        front_m: Option<[f64; 2]>,
        steer_signal: f64,
    ) -> Self {
        let rev = |wheel: Wheel, d: f64| d / (PI * params.wheel_diameter_m(wheel));
        Self {
            t_s,
            rear_left_rev: rev(Wheel::RearLeft, rear_m[0]),
            rear_right_rev: rev(Wheel::RearRight, rear_m[1]),
            front_rev: front_m.map(|[l, r]| [rev(Wheel::FrontLeft, l), rev(Wheel::FrontRight, r)]),
            steer_signal,
        }
    }

    fn is_finite(&self) -> bool {
        self.t_s.is_finite()
            && self.rear_left_rev.is_finite()
            && self.rear_right_rev.is_finite()
            && self.steer_signal.is_finite()
            && self
                .front_rev
                .is_none_or(|[l, r]| l.is_finite() && r.is_finite())
    }
}

/// An input fault seen while recording a run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum InputFault {
    /// No sample for longer than the allowed gap.
    Gap {
        /// The time without samples, in seconds.
        gap_s: f64,
    },
    /// A timestamp earlier than or equal to the previous one.
    TimestampNotIncreasing,
    /// A NaN or infinite value in a sample.
    NonFinite,
    /// The wheel decoder upstream reported a fault (counter glitch, stale
    /// signal, ...); the code is the decoder's own.
    Decoder {
        /// The upstream fault code.
        code: u8,
    },
}

/// Records a run sample by sample, noting every input fault.
#[derive(Debug, Clone, PartialEq)]
pub struct RunRecorder {
    direction: Direction,
    max_gap_s: f64,
    samples: Vec<RevSample>,
    faults: Vec<(f64, InputFault)>,
    last_t_s: Option<f64>,
}

impl RunRecorder {
    /// Starts recording a run in `direction`; a time between samples above
    /// `max_gap_s` is a fault.
    pub fn new(direction: Direction, max_gap_s: f64) -> Self {
        Self {
            direction,
            max_gap_s,
            samples: Vec::new(),
            faults: Vec::new(),
            last_t_s: None,
        }
    }

    /// Adds a sample; a faulty one is noted and not integrated.
    pub fn push(&mut self, sample: RevSample) {
        if !sample.is_finite() {
            self.faults
                .push((self.last_t_s.unwrap_or(0.0), InputFault::NonFinite));
            return;
        }
        if let Some(prev) = self.last_t_s {
            if sample.t_s <= prev {
                self.faults
                    .push((sample.t_s, InputFault::TimestampNotIncreasing));
                return;
            }
            let gap_s = sample.t_s - prev;
            if gap_s > self.max_gap_s {
                self.faults.push((sample.t_s, InputFault::Gap { gap_s }));
            }
        }
        self.last_t_s = Some(sample.t_s);
        self.samples.push(sample);
    }

    /// Notes a fault reported upstream at time `t_s`.
    pub fn push_fault(&mut self, t_s: f64, fault: InputFault) {
        self.faults.push((t_s, fault));
    }

    /// The direction announced for the run.
    pub fn direction(&self) -> Direction {
        self.direction
    }

    /// Samples recorded so far.
    pub fn samples(&self) -> &[RevSample] {
        &self.samples
    }

    /// Ends the recording; `measured_end` is the real end pose in the run
    /// frame when the operator measured it.
    pub fn finish(self, measured_end: Option<Pose>) -> Run {
        Run {
            direction: self.direction,
            samples: self.samples,
            faults: self.faults,
            measured_end,
        }
    }
}

/// The odometry of a replayed run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunOdometry {
    /// End pose in the run frame, heading unwrapped (the total turn).
    pub end: Pose,
    /// Path length: the sum of |Δd|.
    pub length_m: f64,
}

/// A recorded lap of the track.
#[derive(Debug, Clone, PartialEq)]
pub struct Run {
    /// The direction announced for the run.
    pub direction: Direction,
    /// The samples, in time order.
    pub samples: Vec<RevSample>,
    /// Input faults seen while recording, with their times.
    pub faults: Vec<(f64, InputFault)>,
    /// The real end pose in the run frame, when the operator measured it;
    /// its heading is the offset from the start heading (wrapped or not:
    /// the true total turn is taken as ±2π plus its wrapped value).
    pub measured_end: Option<Pose>,
}

/// cos and sin of a small angle `h`: Taylor series where they are exact
/// to rounding (|h| < 0.01: the first omitted terms are below 2e-15
/// relative), `sin_cos` beyond.
#[inline]
fn small_sin_cos(h: f64) -> (f64, f64) {
    if h.abs() < 0.01 {
        let h2 = h * h;
        let c = 1.0 - h2 * (0.5 - h2 * (1.0 / 24.0 - h2 / 720.0));
        let s = h * (1.0 - h2 * (1.0 / 6.0 - h2 / 120.0));
        (s, c)
    } else {
        h.sin_cos()
    }
}

/// Rear odometry over the samples with the given parameters: the step of
/// `canodom_fusion::odometry::rear_increment` + `Pose::advanced`
/// (Δd = (d_R+d_L)/2, Δθ = (d_R−d_L)/b, x += Δd cos(θ+Δθ/2), ...), inlined
/// because calibration replays runs thousands of times. The direction
/// (cos, sin) is carried by rotating it by Δθ/2 twice per step instead of
/// evaluating sin_cos; the heading itself is summed exactly. The two agree
/// to 1e-12 m over a lap (tested).
pub(crate) fn replay_rear(samples: &[RevSample], rear: &RearParams) -> RunOdometry {
    let kl = PI * rear.left_diameter_m;
    let kr = PI * rear.right_diameter_m;
    let inv_b = 1.0 / rear.tread_m;
    let (mut x, mut y, mut th, mut len) = (0.0_f64, 0.0_f64, 0.0_f64, 0.0_f64);
    let (mut c, mut s) = (1.0_f64, 0.0_f64);
    for smp in samples {
        let dl = kl * smp.rear_left_rev;
        let dr = kr * smp.rear_right_rev;
        let dd = 0.5 * (dl + dr);
        let dth = (dr - dl) * inv_b;
        let (sh, ch) = small_sin_cos(0.5 * dth);
        // Direction at the middle of the step, then at its end.
        let (cm, sm) = (c * ch - s * sh, s * ch + c * sh);
        x = dd.mul_add(cm, x);
        y = dd.mul_add(sm, y);
        (c, s) = (cm * ch - sm * sh, sm * ch + cm * sh);
        th += dth;
        len += dd.abs();
    }
    RunOdometry {
        end: Pose {
            x_m: x,
            y_m: y,
            heading_rad: th,
        },
        length_m: len,
    }
}

impl Run {
    /// The rear odometry of this run replayed with `rear`.
    pub fn rear_odometry(&self, rear: &RearParams) -> RunOdometry {
        replay_rear(&self.samples, rear)
    }

    /// The front odometry converted to the rear axle (exact conversion of
    /// `docs/calibration-math.md` §3) with `params`, or `None` without front encoders.
    ///
    /// # Errors
    /// A steering angle at or beyond ±90° (fusion's error).
    pub fn front_odometry(&self, params: &VehicleParams) -> Result<Option<RunOdometry>> {
        let mut pose = Pose::default();
        let mut len = 0.0;
        for s in &self.samples {
            let Some([l, r]) = s.front_rev else {
                return Ok(None);
            };
            let phi = params.steering().angle_rad(s.steer_signal);
            let inc = odometry::front_increment_exact(
                params,
                PI * params.wheel_diameter_m(Wheel::FrontLeft) * l,
                PI * params.wheel_diameter_m(Wheel::FrontRight) * r,
                phi,
            )?;
            pose = pose.advanced(inc);
            len += inc.distance_m.abs();
        }
        Ok(Some(RunOdometry {
            end: pose,
            length_m: len,
        }))
    }

    /// The true total turn Θ: ±2π, plus the measured end heading's wrapped
    /// offset when the end pose was measured.
    pub fn true_total_turn_rad(&self) -> f64 {
        let base = self.direction.sign() * 2.0 * PI;
        match self.measured_end {
            Some(p) => base + canodom_fusion::wrap_angle(p.heading_rad),
            None => base,
        }
    }

    /// The real end position: measured, or the start as the paper assumes.
    pub fn real_end_m(&self) -> [f64; 2] {
        self.measured_end.map_or([0.0, 0.0], |p| [p.x_m, p.y_m])
    }

    /// End error e = odometry end − real end, in the run frame (§2).
    pub fn end_error_m(&self, rear: &RearParams) -> [f64; 2] {
        let odo = self.rear_odometry(rear);
        let real = self.real_end_m();
        [odo.end.x_m - real[0], odo.end.y_m - real[1]]
    }

    /// Duration from the first to the last sample, in seconds.
    pub fn duration_s(&self) -> f64 {
        match (self.samples.first(), self.samples.last()) {
            (Some(a), Some(b)) => b.t_s - a.t_s,
            _ => 0.0,
        }
    }

    /// Every reason to reject this run (empty when it is accepted), judged
    /// with the parameters used while recording.
    pub fn validate(
        &self,
        track: Track,
        params: &VehicleParams,
        tolerances: &Tolerances,
    ) -> Vec<Rejection> {
        let mut reasons = Vec::new();
        if self.samples.len() < 2 {
            reasons.push(Rejection::TooFewSamples {
                samples: self.samples.len(),
            });
            return reasons;
        }
        if let Some(&(t_s, fault)) = self.faults.first() {
            reasons.push(Rejection::InputFault {
                count: self.faults.len(),
                first_t_s: t_s,
                first: fault,
            });
        }
        let odo = self.rear_odometry(&RearParams::of(params));
        let expected_m = track.length_m();
        if (odo.length_m - expected_m).abs() > tolerances.length_rel * expected_m {
            reasons.push(Rejection::LengthOff {
                length_m: odo.length_m,
                expected_m,
            });
        }
        let expected_rad = track.total_turn_rad(self.direction);
        if (odo.end.heading_rad - expected_rad).abs() > tolerances.turn_rad {
            reasons.push(Rejection::TurnOff {
                total_turn_rad: odo.end.heading_rad,
                expected_rad,
            });
        }
        if let Some(r) = self.steering_check(track, params, tolerances, odo.length_m) {
            reasons.push(r);
        }
        reasons
    }

    /// Compares the mean steering angle over the central part of each segment
    /// (located by odometry distance, normalised to the run's own length so
    /// a scale error does not matter) with the track's geometry.
    fn steering_check(
        &self,
        track: Track,
        params: &VehicleParams,
        tol: &Tolerances,
        length_m: f64,
    ) -> Option<Rejection> {
        if length_m <= 0.0 {
            return None;
        }
        let segments = track.segments(self.direction);
        let arc_angle = (params.wheelbase_m() / track.radius_m()).atan();
        let map = params.steering();
        let rear = RearParams::of(params);
        let scale = track.length_m() / length_m;
        let mut sums = [(0.0_f64, 0usize); 4];
        let mut s_m = 0.0;
        for smp in &self.samples {
            let dd = 0.5
                * PI
                * (rear.left_diameter_m * smp.rear_left_rev
                    + rear.right_diameter_m * smp.rear_right_rev);
            s_m += dd.abs();
            let s_track = s_m * scale;
            let mut start = 0.0;
            for (i, seg) in segments.iter().enumerate() {
                let margin = 0.25 * seg.length_m;
                if s_track > start + margin && s_track < start + seg.length_m - margin {
                    sums[i].0 += map.angle_rad(smp.steer_signal);
                    sums[i].1 += 1;
                }
                start += seg.length_m;
            }
        }
        for (i, seg) in segments.iter().enumerate() {
            let (sum, n) = sums[i];
            let expected_rad = if seg.is_arc() {
                self.direction.sign() * arc_angle
            } else {
                0.0
            };
            let mean = if n == 0 { f64::NAN } else { sum / n as f64 };
            let ok = mean.is_finite()
                && (mean - expected_rad).abs() <= tol.steer_rel * arc_angle
                && (!seg.is_arc() || mean * expected_rad > 0.0);
            if !ok {
                return Some(Rejection::SteeringInconsistent {
                    segment: i as u8,
                    mean_angle_rad: mean,
                    expected_rad,
                });
            }
        }
        None
    }
}

/// The tolerances of run validation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tolerances {
    /// Allowed relative error of the odometry length against (4+2π)ρ (0.10).
    pub length_rel: f64,
    /// Allowed error of the odometry total turn against ±2π, in radians
    /// (default 3π/4). Uncalibrated odometry is off by about 1.4 rad on a
    /// lap with §9's right-wheel tape (E 4 % off) and more with worse
    /// wheels, while a lap in the wrong direction is off by 4π and a missed
    /// semicircle by π (and 20 % in length).
    pub turn_rad: f64,
    /// Allowed error of a segment's mean steering angle, as a fraction of the
    /// semicircles' angle atan(L/ρ) (0.5).
    pub steer_rel: f64,
    /// The longest time between samples that is not a gap, in seconds.
    pub max_gap_s: f64,
}

impl Default for Tolerances {
    fn default() -> Self {
        Self {
            length_rel: 0.10,
            turn_rad: 0.75 * PI,
            steer_rel: 0.5,
            max_gap_s: 0.25,
        }
    }
}

/// Why a run was rejected. Each has a stable numeric [`Rejection::code`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Rejection {
    /// Fewer than two samples.
    TooFewSamples {
        /// Samples recorded.
        samples: usize,
    },
    /// The odometry length is off (4+2π)ρ by more than the tolerance.
    LengthOff {
        /// Odometry path length.
        length_m: f64,
        /// (4+2π)ρ.
        expected_m: f64,
    },
    /// The odometry total turn is not ±2π in the announced direction.
    TurnOff {
        /// Odometry total turn, unwrapped.
        total_turn_rad: f64,
        /// ±2π.
        expected_rad: f64,
    },
    /// Input gaps or faults inside the run.
    InputFault {
        /// How many faults.
        count: usize,
        /// Time of the first.
        first_t_s: f64,
        /// The first fault.
        first: InputFault,
    },
    /// The steering did not follow the track's segments.
    SteeringInconsistent {
        /// The segment (0..4) where it did not.
        segment: u8,
        /// Mean steering angle over its central half (NaN: no samples there).
        mean_angle_rad: f64,
        /// What the track's geometry needs.
        expected_rad: f64,
    },
}

impl Rejection {
    /// Stable numeric code for status frames.
    pub fn code(&self) -> u8 {
        match self {
            Rejection::TooFewSamples { .. } => 1,
            Rejection::LengthOff { .. } => 2,
            Rejection::TurnOff { .. } => 3,
            Rejection::InputFault { .. } => 4,
            Rejection::SteeringInconsistent { .. } => 5,
        }
    }
}

impl std::fmt::Display for InputFault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Gap { gap_s } => write!(f, "no sample for {gap_s:.2} s"),
            Self::TimestampNotIncreasing => write!(f, "a timestamp did not increase"),
            Self::NonFinite => write!(f, "a NaN or infinite value"),
            Self::Decoder { code } => write!(f, "the wheel decoder reported fault {code}"),
        }
    }
}

/// The track's segments in driving order, for messages.
const SEGMENT_NAMES: [&str; 4] = [
    "the first straight",
    "the first semicircle",
    "the second straight",
    "the second semicircle",
];

impl std::fmt::Display for Rejection {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::TooFewSamples { samples } => {
                write!(f, "only {samples} samples: too short to be a run")
            }
            Self::LengthOff {
                length_m,
                expected_m,
            } => write!(
                f,
                "the odometry path is {length_m:.3} m long where the track is {expected_m:.3} m \
                 ({:+.1} %): not one lap of this track",
                100.0 * (length_m / expected_m - 1.0)
            ),
            Self::TurnOff {
                total_turn_rad,
                expected_rad,
            } => write!(
                f,
                "the run turned {:.0}° where a lap turns {:.0}°",
                total_turn_rad.to_degrees(),
                expected_rad.to_degrees()
            ),
            Self::InputFault {
                count,
                first_t_s,
                first,
            } => write!(
                f,
                "{count} input fault(s) during the run, the first at {first_t_s:.2} s: {first}"
            ),
            Self::SteeringInconsistent {
                segment,
                mean_angle_rad,
                expected_rad,
            } => {
                let name = SEGMENT_NAMES
                    .get(usize::from(*segment))
                    .unwrap_or(&"a segment");
                if mean_angle_rad.is_finite() {
                    write!(
                        f,
                        "the steering averaged {:.1}° on {name} where the track needs {:.1}°",
                        mean_angle_rad.to_degrees(),
                        expected_rad.to_degrees()
                    )
                } else {
                    write!(f, "no steering sample on the middle half of {name}")
                }
            }
        }
    }
}

/// Checks that the runs hold at least `per_direction` runs each way.
pub(crate) fn count_directions(runs: &[Run]) -> (usize, usize) {
    let ccw = runs
        .iter()
        .filter(|r| r.direction == Direction::Ccw)
        .count();
    (ccw, runs.len() - ccw)
}

/// [`Error::NotEnoughRuns`] unless both directions have a run.
pub(crate) fn need_both_directions(runs: &[Run], needed: &'static str) -> Result<()> {
    let (ccw, cw) = count_directions(runs);
    if ccw == 0 || cw == 0 {
        return Err(Error::NotEnoughRuns {
            needed,
            got: ccw,
            got_cw: cw,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::methods::tests::{truth, used};
    use crate::synth;

    fn record(samples: &[RevSample], dir: Direction) -> Run {
        let mut rec = RunRecorder::new(dir, Tolerances::default().max_gap_s);
        for s in samples {
            rec.push(*s);
        }
        rec.finish(None)
    }

    #[test]
    fn rejections_read_as_words() {
        let texts = [
            Rejection::TooFewSamples { samples: 1 }.to_string(),
            Rejection::LengthOff {
                length_m: 9.0,
                expected_m: 10.0,
            }
            .to_string(),
            Rejection::TurnOff {
                total_turn_rad: PI,
                expected_rad: 2.0 * PI,
            }
            .to_string(),
            Rejection::InputFault {
                count: 1,
                first_t_s: 0.030_935,
                first: InputFault::Decoder { code: 1 },
            }
            .to_string(),
            Rejection::SteeringInconsistent {
                segment: 1,
                mean_angle_rad: f64::NAN,
                expected_rad: 0.2,
            }
            .to_string(),
        ];
        assert!(texts[1].contains("-10.0 %"), "{}", texts[1]);
        assert!(
            texts[2].contains("180°") && texts[2].contains("360°"),
            "{}",
            texts[2]
        );
        assert!(
            texts[3].contains("at 0.03 s: the wheel decoder reported fault 1"),
            "{}",
            texts[3]
        );
        assert!(texts[4].contains("the first semicircle"), "{}", texts[4]);
        for t in &texts {
            // Words, not Rust's debug notation.
            assert!(!t.contains('{') && !t.contains("NaN"), "{t}");
        }
    }

    fn nominal() -> VehicleParams {
        used().apply_to(&truth(false, false)).unwrap()
    }

    #[test]
    fn a_clean_lap_is_accepted_in_both_directions() {
        let track = Track::new(0.78).unwrap();
        for dir in Direction::BOTH {
            let s = synth::lap(&truth(false, false), track, dir, 0.1, 50.0).unwrap();
            let run = record(&s, dir);
            assert!(run.faults.is_empty());
            let reasons = run.validate(track, &nominal(), &Tolerances::default());
            assert!(reasons.is_empty(), "{dir:?}: {reasons:?}");
            assert!(
                (run.duration_s() - 80.2).abs() < 0.1,
                "{}",
                run.duration_s()
            );
            let front = run.front_odometry(&nominal()).unwrap().unwrap();
            assert!((front.length_m / track.length_m() - 1.0).abs() < 0.01);
        }
    }

    #[test]
    fn every_rejection_has_its_reason() {
        let track = Track::new(0.78).unwrap();
        let tol = Tolerances::default();
        let p = nominal();
        let ccw = synth::lap(&truth(false, false), track, Direction::Ccw, 0.1, 50.0).unwrap();
        // Announced CW but driven CCW: the turn and the steering disagree.
        let r = record(&ccw, Direction::Cw).validate(track, &p, &tol);
        assert!(
            r.iter().any(|x| matches!(x, Rejection::TurnOff { .. })),
            "{r:?}"
        );
        assert!(r.iter().any(|x| x.code() == 5), "{r:?}");
        // Stopped after 80 %: too short, and the turn is short too.
        let short = &ccw[..ccw.len() * 8 / 10];
        let r = record(short, Direction::Ccw).validate(track, &p, &tol);
        assert!(
            r.iter().any(|x| matches!(x, Rejection::LengthOff { .. })),
            "{r:?}"
        );
        // A gap, a backwards timestamp and a NaN are faults.
        let mut rec = RunRecorder::new(Direction::Ccw, tol.max_gap_s);
        for (i, s) in ccw.iter().enumerate() {
            let mut s = *s;
            if i >= 100 {
                s.t_s += 1.0;
            }
            if i == 200 {
                s.rear_left_rev = f64::NAN;
            }
            rec.push(s);
            if i == 300 {
                rec.push(s);
            }
        }
        let run = rec.finish(None);
        assert_eq!(run.faults.len(), 3, "{:?}", run.faults);
        let r = run.validate(track, &p, &tol);
        assert!(matches!(
            r.first(),
            Some(Rejection::InputFault {
                first: InputFault::Gap { .. },
                ..
            })
        ));
        // Steering straight all the way: inconsistent on the first semicircle.
        let mut straight_wheel: Vec<RevSample> = ccw.clone();
        for s in &mut straight_wheel {
            s.steer_signal = 0.0;
        }
        let r = record(&straight_wheel, Direction::Ccw).validate(track, &p, &tol);
        assert_eq!(
            r.iter()
                .filter_map(|x| match x {
                    Rejection::SteeringInconsistent { segment, .. } => Some(*segment),
                    _ => None,
                })
                .collect::<Vec<_>>(),
            vec![1]
        );
        assert_eq!(
            record(&ccw[..1], Direction::Ccw).validate(track, &p, &tol)[0].code(),
            1
        );
    }

    #[test]
    fn replay_matches_the_fusion_rear_step() {
        let track = Track::new(0.78).unwrap();
        let s = synth::lap(&truth(true, false), track, Direction::Cw, 0.1, 100.0).unwrap();
        let p = nominal();
        let mut pose = Pose::default();
        for x in &s {
            let inc = odometry::rear_increment(
                &p,
                p.tick_distance_m(Wheel::RearLeft, x.rear_left_rev * 1000.0),
                p.tick_distance_m(Wheel::RearRight, x.rear_right_rev * 1000.0),
            )
            .unwrap();
            pose = pose.advanced(inc);
        }
        let odo = replay_rear(&s, &RearParams::of(&p));
        assert!((odo.end.x_m - pose.x_m).abs() < 1e-9 && (odo.end.y_m - pose.y_m).abs() < 1e-9);
        assert!((odo.end.heading_rad - pose.heading_rad).abs() < 1e-12);
        // Samples from ticks and from distances give the same revolutions.
        let a = RevSample::from_ticks(&p, 0.0, [12.0, 13.0], None, 0.0);
        let b = RevSample::from_distances(
            &p,
            0.0,
            [
                p.tick_distance_m(Wheel::RearLeft, 12.0),
                p.tick_distance_m(Wheel::RearRight, 13.0),
            ],
            None,
            0.0,
        );
        assert!((a.rear_left_rev - b.rear_left_rev).abs() < 1e-15);
        assert!((a.rear_right_rev - b.rear_right_rev).abs() < 1e-15);
    }
}
