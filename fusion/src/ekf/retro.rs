//! The pose's retro-correction by the learnt wheel scales
//! (`docs/calibration-math.md` §15).
//!
//! The learner ([`super::scales`]) tells a rear tyre from the front one on
//! its side only after the car has turned tightly both ways, 150–250 m into
//! a drive; a correction applied from then on would leave the heading the
//! fault turned before (0.3–0.6 rad for a 0.3–0.5 % tyre). So the windows'
//! global displacements are kept as moments of the rear distance driven
//! before them, and when the applied scales change the anchor moves to where
//! they would have put it had they applied from the start: exact in the
//! heading, in position to the series' order (7·10⁻⁴ of the displacement at
//! 0.6 rad). On the opendbc Honda drives with one rear tyre 0.3–0.5 % off
//! this ended 0.003–0.06 % of the distance off where the true scale applied
//! from the first sample ended 0.004–0.07 %.

use super::State;
use crate::wrap_angle;

/// The highest power of the rear pair's moments: the correction's series in
/// `β·S` is cut after it, which leaves `(β·S)¹⁷/17!` of the displacement:
/// 5·10⁻⁵ at [`RETRO_MAX_TURN_RAD`], 2·10⁻¹⁶ at 0.6 rad. Each order adds four
/// numbers to the state.
pub(super) const RETRO_ORDER: usize = 16;

/// The least change of the rear pair's scale difference, `|Δ ln s_RR −
/// Δ ln s_RL|`, that moves the history: a decision (a wheel found off,
/// 0.2 % or more), not the learner's refinements of it. Each refinement
/// (1–10·10⁻⁵ per window after a decision) rotated the whole history by
/// up to 0.07 rad, and over a 20-minute multi-body drive without a gyro
/// the pose random-walked to 10⁷ m where the rear wheels ended 0.5 km
/// away; applied from then on, they change where the car goes, not where
/// it went.
const RETRO_MIN_CHANGE: f64 = 5e-4;

/// The largest turn, rad, that a change may give the history (`Δβ·S`): a
/// 0.3 % tyre told within 2 km on a 1.5 m tread. Without a yaw-rate sensor
/// the multi-body cars, whose tyres slip in every curve, tell a rear tyre
/// 0.3 % large from the front one on its side only 490–760 m into a drive
/// (a history turned by 1.3–2.1 rad); with the history cut at 1 rad, as
/// the order-5 series needed, those decisions were applied from then on,
/// and the six such drives of 1.1 km ended 22–77 % of their distance off,
/// as rear-only did; moved back to the start, 1.8–16 %. A decision later
/// still is applied from then on, and the history restarts so that a later
/// decision is judged on what follows.
const RETRO_MAX_TURN_RAD: f64 = 4.0;

/// Adds a window's global displacement `moved` to the rear pair's moments,
/// at the middle of its rear distance and turn `rear` (`None` when the
/// window's increment came from the front: its heading carries the bias of
/// the windows before, not its own).
pub(super) fn add_rear_moments(st: &mut State, moved: [f64; 2], rear: Option<(f64, f64)>) {
    let (rear_m, turn_rad) = rear.unwrap_or((0.0, 0.0));
    let s_mid = st.rear_distance_m + 0.5 * rear_m;
    let turn_mid = st.rear_turn_rad + 0.5 * turn_rad;
    st.rear_distance_m += rear_m;
    st.rear_turn_rad += turn_rad;
    let mut power = 1.0;
    for (m, n) in st.rear_moments.iter_mut().zip(&mut st.rear_turn_moments) {
        for k in 0..2 {
            m[k] += power * moved[k];
            n[k] += power * turn_mid * moved[k];
        }
        power *= s_mid;
    }
}

/// `Σ_k (−Δβ)^k/k! J^k M_{n+k}` for each n (J the quarter turn), times
/// `scale`: the moments of the history rotated by `−Δβ·S` and scaled.
fn rotated_moments(
    m: &[[f64; 2]; RETRO_ORDER + 1],
    d_beta: f64,
    scale: f64,
) -> [[f64; 2]; RETRO_ORDER + 1] {
    let mut out = [[0.0; 2]; RETRO_ORDER + 1];
    for (n, o) in out.iter_mut().enumerate() {
        let mut coef = 1.0;
        for (k, mk) in m[n..].iter().enumerate() {
            if k > 0 {
                coef *= -d_beta / k as f64;
            }
            // J^k (x, y): (x, y), (−y, x), (−x, −y), (y, −x).
            let (x, y) = match k % 4 {
                0 => (mk[0], mk[1]),
                1 => (-mk[1], mk[0]),
                2 => (-mk[0], -mk[1]),
                _ => (mk[1], -mk[0]),
            };
            o[0] += coef * x;
            o[1] += coef * y;
        }
        o[0] *= scale;
        o[1] *= scale;
    }
    out
}

/// Takes the learner's scales as the ones applied, and moves the anchor to
/// where they would have put it had they applied from the start. Called at a
/// window's close, when the anchor holds every sample.
pub(super) fn reapply_rear_pair(st: &mut State, inv_rear_tread: f64) {
    let now = st.scales.ln_scale();
    if now == st.applied_ln_scale {
        return;
    }
    let [rl0, rr0, _, _] = st.applied_ln_scale;
    let [rl, rr, _, _] = now;
    // The corrected rear heading turns less by (Δ ln s_RR − Δ ln s_RL)/b per
    // metre and by the mean's change per radian the wheels turned; every
    // rear distance shrinks by the mean's change.
    let (d_right, d_left) = (rr - rr0, rl - rl0);
    let d_beta = (d_right - d_left) * inv_rear_tread;
    let d_mean = 0.5 * (d_right + d_left);
    let too_late = (d_beta * st.rear_distance_m).abs() > RETRO_MAX_TURN_RAD;
    if (d_right - d_left).abs() < RETRO_MIN_CHANGE || too_late {
        if too_late {
            st.rear_moments = [[0.0; 2]; RETRO_ORDER + 1];
            st.rear_turn_moments = [[0.0; 2]; RETRO_ORDER + 1];
            st.rear_distance_m = 0.0;
            st.rear_turn_rad = 0.0;
        }
        st.applied_ln_scale = now;
        st.applied_factor = now.map(|l| (-l).exp());
        return;
    }
    let scale = (-d_mean).exp();
    let rot_m = rotated_moments(&st.rear_moments, d_beta, scale);
    let rot_n = rotated_moments(&st.rear_turn_moments, d_beta, scale);
    let mut next_m = rot_m;
    let mut next_n = rot_n;
    for k in 0..=RETRO_ORDER {
        // − Δμ J N_n (J: the quarter turn), and N's own Θ moved by the change.
        next_m[k][0] += d_mean * rot_n[k][1];
        next_m[k][1] -= d_mean * rot_n[k][0];
        let higher = if k < RETRO_ORDER {
            rot_m[k + 1]
        } else {
            [0.0; 2]
        };
        next_n[k][0] = (1.0 - d_mean) * rot_n[k][0] - d_beta * higher[0];
        next_n[k][1] = (1.0 - d_mean) * rot_n[k][1] - d_beta * higher[1];
    }
    let turn = -d_beta * st.rear_distance_m - d_mean * st.rear_turn_rad;
    st.anchor.x += next_m[0][0] - st.rear_moments[0][0];
    st.anchor.y += next_m[0][1] - st.rear_moments[0][1];
    st.anchor_heading_unwrapped_rad += turn;
    st.anchor.z = wrap_angle(st.anchor.z + turn);
    let (s, c) = st.anchor.z.sin_cos();
    st.anchor_cos_sin = (c, s);
    st.rear_moments = next_m;
    st.rear_turn_moments = next_n;
    st.rear_turn_rad += turn;
    st.rear_distance_m *= scale;
    st.applied_ln_scale = now;
    st.applied_factor = now.map(|l| (-l).exp());
}

#[cfg(test)]
mod tests {
    use super::super::{Fault, LearntWheelFault};
    use super::*;

    const INV_TREAD: f64 = 1.0 / 1.5;

    /// A state that drove `distance_m` straight along x in 10 m windows,
    /// its learner holding the rear-left wheel `scale` times the others
    /// (nothing applied yet when `applied` is false).
    fn driven(distance_m: f64, scale: f64, applied: bool) -> State {
        let mut st = State::origin();
        let windows = (distance_m / 10.0) as usize;
        for _ in 0..windows {
            add_rear_moments(&mut st, [10.0, 0.0], Some((10.0, 0.0)));
        }
        st.anchor.x = distance_m;
        st.scales.restore(&LearntWheelFault {
            fault: Fault::RearLeft,
            scale,
            sigma: 1e-4,
            lead_log_odds: 20.0,
            windows: 500,
        });
        if applied {
            st.applied_ln_scale = st.scales.ln_scale();
            st.applied_factor = st.applied_ln_scale.map(|l| (-l).exp());
        }
        st
    }

    #[test]
    fn a_decision_early_in_a_drive_moves_the_history() {
        // 0.3 % at 200 m turns the history by 0.4 rad.
        let mut st = driven(200.0, 1.003, false);
        assert_ne!(st.scales.ln_scale(), [0.0; 4], "the learner decided");
        reapply_rear_pair(&mut st, INV_TREAD);
        assert!(st.anchor.z.abs() > 0.3, "heading {}", st.anchor.z);
        assert!(st.anchor.y.abs() > 10.0, "y {}", st.anchor.y);
        assert_eq!(st.applied_ln_scale, st.scales.ln_scale());
    }

    #[test]
    fn a_refinement_of_a_decision_is_applied_from_then_on() {
        // A 5·10⁻⁵ refinement after 10 km rotated the whole history by
        // 0.3 rad each time; the pose random-walked away.
        let mut st = driven(10_000.0, 1.003, true);
        let before = st.anchor;
        st.scales.restore(&LearntWheelFault {
            fault: Fault::RearLeft,
            scale: 1.00305,
            sigma: 1e-4,
            lead_log_odds: 20.0,
            windows: 501,
        });
        assert_ne!(st.scales.ln_scale(), st.applied_ln_scale);
        reapply_rear_pair(&mut st, INV_TREAD);
        assert_eq!(st.anchor, before, "a refinement moved the history");
        assert_eq!(st.applied_ln_scale, st.scales.ln_scale());
        assert!((st.rear_distance_m - 10_000.0).abs() < 1e-6, "history kept");
    }

    /// A state that drove `windows` windows of 10 m turning by
    /// `turn_of(k)` each (the rear wheels' turn, integrated at the mid
    /// heading), its learner holding the rear-left wheel 0.3 % large,
    /// nothing applied yet; and each window's displacement, mid distance
    /// and mid turn.
    fn curved(windows: usize, turn_of: impl Fn(usize) -> f64) -> (State, Vec<[f64; 4]>) {
        let mut st = driven(0.0, 1.003, false);
        let (mut heading, mut x, mut y) = (0.0_f64, 0.0, 0.0);
        let mut history = Vec::with_capacity(windows);
        for k in 0..windows {
            let turn = turn_of(k);
            let mid = heading + 0.5 * turn;
            let moved = [10.0 * mid.cos(), 10.0 * mid.sin()];
            history.push([moved[0], moved[1], 10.0 * k as f64 + 5.0, mid]);
            add_rear_moments(&mut st, moved, Some((10.0, turn)));
            heading += turn;
            x += moved[0];
            y += moved[1];
        }
        st.anchor.x = x;
        st.anchor.y = y;
        st.anchor.z = wrap_angle(heading);
        st.anchor_heading_unwrapped_rad = heading;
        (st, history)
    }

    #[test]
    fn a_late_decision_moves_a_winding_history_as_if_applied_from_the_start() {
        // 1.5 km of bends both ways: 0.3 % turns that history by 3 rad,
        // beyond where the order-5 series held (1 rad).
        let (mut st, history) = curved(150, |k| 0.12 * ((k as f64) * 0.21).sin());
        let history_turn = st.anchor_heading_unwrapped_rad;
        let [rl0, rr0, _, _] = st.applied_ln_scale;
        let [rl, rr, _, _] = st.scales.ln_scale();
        let d_beta = ((rr - rr0) - (rl - rl0)) * INV_TREAD;
        let d_mean = 0.5 * ((rr - rr0) + (rl - rl0));
        assert!(
            (d_beta * 1500.0).abs() > 2.5,
            "history turn {}",
            d_beta * 1500.0
        );
        reapply_rear_pair(&mut st, INV_TREAD);
        // Each window's displacement turned by −Δβ·s − Δμ·Θ at its middle
        // and scaled by e^(−Δμ): what the scales would have given.
        let scale = (-d_mean).exp();
        let (mut x, mut y) = (0.0, 0.0);
        for [mx, my, s_mid, theta_mid] in &history {
            let (sin, cos) = (-d_beta * s_mid - d_mean * theta_mid).sin_cos();
            x += scale * (cos * mx - sin * my);
            y += scale * (sin * mx + cos * my);
        }
        let miss = (st.anchor.x - x).hypot(st.anchor.y - y);
        // The truncation leaves (3 rad)¹⁷/17! of 1.5 km; the first-order
        // turn by Δμ·Θ leaves (Δμ·Θ)²/2 of it.
        assert!(
            miss < 0.05,
            "anchor ({}, {}) vs exact ({x}, {y}): {miss} m",
            st.anchor.x,
            st.anchor.y
        );
        let turned = st.anchor_heading_unwrapped_rad;
        let exact = history_turn * (1.0 - d_mean) - d_beta * 1500.0;
        assert!((turned - exact).abs() < 1e-9, "heading {turned} vs {exact}");
    }

    #[test]
    fn a_decision_too_late_for_the_series_restarts_the_history() {
        // 0.3 % after 3 km: 6 rad, past where the cut series holds.
        let mut st = driven(3_000.0, 1.003, false);
        let before = st.anchor;
        reapply_rear_pair(&mut st, INV_TREAD);
        assert_eq!(
            st.anchor, before,
            "the history was moved past the series' range"
        );
        assert_eq!(st.rear_distance_m, 0.0);
        assert_eq!(st.rear_moments, [[0.0; 2]; RETRO_ORDER + 1]);
        assert_eq!(st.applied_ln_scale, st.scales.ln_scale());
    }
}
