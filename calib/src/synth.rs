//! A noise-free run generator from exact kinematics (`docs/calibration-math.md`
//! §3): the vehicle follows the track (or a constant steering command)
//! exactly, each wheel rolls `g_i · ds` without slip, and the encoders count
//! real revolutions `g_i · ds / (π D_i,true)` (no tick quantisation).
//!
//! It is a test and benchmark helper: the realistic judge is the fusion
//! crate's simulator (path-following noise, slips, quantised ticks). Here a
//! replay with the true parameters reproduces the true path to the midpoint
//! rule's accuracy, so methods can be checked to 1e-7.

use std::f64::consts::PI;

use canodom_fusion::params::rear_diameters_for_ratio;
use canodom_fusion::{VehicleParams, WheelSet, odometry::wheel_distance_factors};

use crate::error::Result;
use crate::run::RevSample;
use crate::track::{Direction, Track};

/// The vehicle of `docs/calibration-math.md` §9: wheelbase 25 cm, true effective
/// rear tread 28.5 cm, rear diameter ratio 1.005 around 9 cm, with a 3.5 %
/// tape on the left and/or right rear wheel (Table 2's four cases).
///
/// # Errors
/// Never for these constants; the type says the parameters were validated.
pub fn section9_truth(tape_left: bool, tape_right: bool) -> Result<VehicleParams> {
    let (left_m, right_m) = rear_diameters_for_ratio(0.09, 1.005);
    let tape = |d: f64, on: bool| if on { d * 1.035 } else { d };
    let mut diameters_m = WheelSet::splat(0.09);
    diameters_m.rear_left = tape(left_m, tape_left);
    diameters_m.rear_right = tape(right_m, tape_right);
    Ok(VehicleParams::nominal(0.25, 0.285, 0.09, 1000)?.with_diameters(diameters_m)?)
}

/// Wheel revolutions of one piece of constant curvature.
fn piece(truth: &VehicleParams, curvature_per_m: f64, ds_m: f64) -> [f64; 4] {
    let phi = (truth.wheelbase_m() * curvature_per_m).atan();
    let g = wheel_distance_factors(truth, phi);
    let d = truth.wheel_diameters_m();
    [
        g[0] * ds_m / (PI * d.rear_left),
        g[1] * ds_m / (PI * d.rear_right),
        g[2] * ds_m / (PI * d.front_left),
        g[3] * ds_m / (PI * d.front_right),
    ]
}

/// One lap of `track` in `direction` at `speed_mps`, sampled at `rate_hz`,
/// as the truth vehicle's encoders see it. The steering signal is the one
/// that gives the segment's curvature through the truth's steering map.
///
/// # Errors
/// A non-positive speed or rate, or a steering map without inverse.
pub fn lap(
    truth: &VehicleParams,
    track: Track,
    direction: Direction,
    speed_mps: f64,
    rate_hz: f64,
) -> Result<Vec<RevSample>> {
    crate::error::positive("speed_mps", speed_mps)?;
    crate::error::positive("rate_hz", rate_hz)?;
    let step_m = speed_mps / rate_hz;
    let total_m = track.length_m();
    let n = (total_m / step_m).ceil() as usize;
    let segments = track.segments(direction);
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        let s0 = k as f64 * step_m;
        let s1 = (s0 + step_m).min(total_m);
        let mut revs = [0.0; 4];
        let mut start = 0.0;
        for seg in &segments {
            let lo = s0.max(start);
            let hi = s1.min(start + seg.length_m);
            if hi > lo {
                let r = piece(truth, seg.curvature_per_m, hi - lo);
                for i in 0..4 {
                    revs[i] += r[i];
                }
            }
            start += seg.length_m;
        }
        let (_, seg) = track.segment_at(direction, 0.5 * (s0 + s1));
        let phi = (truth.wheelbase_m() * seg.curvature_per_m).atan();
        out.push(RevSample {
            t_s: (k + 1) as f64 / rate_hz,
            rear_left_rev: revs[0],
            rear_right_rev: revs[1],
            front_rev: Some([revs[2], revs[3]]),
            steer_signal: truth.steering().signal_for(phi)?,
        });
    }
    Ok(out)
}

/// A drive of `distance_m` at the constant steering signal `steer_signal`.
///
/// # Errors
/// A non-positive speed, rate or distance.
pub fn arc(
    truth: &VehicleParams,
    steer_signal: f64,
    distance_m: f64,
    speed_mps: f64,
    rate_hz: f64,
) -> Result<Vec<RevSample>> {
    crate::error::positive("distance_m", distance_m)?;
    crate::error::positive("speed_mps", speed_mps)?;
    crate::error::positive("rate_hz", rate_hz)?;
    let step_m = speed_mps / rate_hz;
    let kappa = truth.steering().angle_rad(steer_signal).tan() / truth.wheelbase_m();
    let n = (distance_m / step_m).ceil() as usize;
    let r = piece(truth, kappa, step_m);
    Ok((0..n)
        .map(|k| RevSample {
            t_s: (k + 1) as f64 / rate_hz,
            rear_left_rev: r[0],
            rear_right_rev: r[1],
            front_rev: Some([r[2], r[3]]),
            steer_signal,
        })
        .collect())
}
