//! The pose and covariance algebra of the filter's steps: propagation by an
//! increment, composition onto the anchor, the Joseph update and a symmetric
//! inverse, each written out entry by entry for the step's cost (the reasons
//! stand at each function).
#![allow(non_snake_case)]

use super::{Mat3, Vec3};
use crate::odometry::Increment;
use crate::rotation::{SMALL_ANGLE_RAD, small_sin_cos};
use crate::wrap_angle;
use nalgebra::Matrix2;

pub(super) fn symmetrise(p: &Mat3) -> Mat3 {
    (p + p.transpose()) * 0.5
}

/// Propagates a pose `w` and covariance by an increment with input covariance `q`.
#[cfg(test)]
pub(super) fn propagate(w: &Vec3, p: &Mat3, inc: Increment, q: &Matrix2<f64>) -> (Vec3, Mat3) {
    let (s, c) = (w.z + 0.5 * inc.dtheta_rad).sin_cos();
    propagate_with(w, p, inc, q, s, c)
}

/// [`propagate`] with `sin m`, `cos m` of the mid heading already computed.
///
/// `A = I + a e₃ᵀ` with `a = (−Δd sin m, Δd cos m, 0)`, so
/// `A P Aᵀ = P + a cᵀ + c aᵀ + P₃₃ a aᵀ` with `c = P e₃`: a dozen products
/// instead of two general 3×3 multiplications (this runs every sample).
pub(super) fn propagate_with(
    w: &Vec3,
    p: &Mat3,
    inc: Increment,
    q: &Matrix2<f64>,
    s: f64,
    c: f64,
) -> (Vec3, Mat3) {
    let d = inc.distance_m;
    let (ax, ay) = (-d * s, d * c);
    let (cx, cy, cz) = (p[(0, 2)], p[(1, 2)], p[(2, 2)]);
    // B = [[c, −(Δd/2) s], [s, (Δd/2) c], [0, 1]]; B Q Bᵀ entry by entry.
    let (q11, q12, q22) = (q[(0, 0)], 0.5 * (q[(0, 1)] + q[(1, 0)]), q[(1, 1)]);
    let (b11, b12, b21, b22) = (c, 0.5 * ax, s, 0.5 * ay);
    // Q times B's first two rows, shared by the three x-y entries of B Q Bᵀ.
    let (t11, t12) = (q11 * b11 + q12 * b12, q12 * b11 + q22 * b12);
    let (t21, t22) = (q11 * b21 + q12 * b22, q12 * b21 + q22 * b22);
    let m00 = p[(0, 0)] + 2.0 * ax * cx + cz * ax * ax + (b11 * t11 + b12 * t12);
    let m01 = p[(0, 1)] + ax * cy + ay * cx + cz * ax * ay + (b11 * t21 + b12 * t22);
    let m11 = p[(1, 1)] + 2.0 * ay * cy + cz * ay * ay + (b21 * t21 + b22 * t22);
    let m02 = cx + ax * cz + b12 * q22 + b11 * q12;
    let m12 = cy + ay * cz + b22 * q22 + b21 * q12;
    let m22 = cz + q22;
    let p_new = Mat3::new(m00, m01, m02, m01, m11, m12, m02, m12, m22);
    let w_new = Vec3::new(w.x + d * c, w.y + d * s, w.z + inc.dtheta_rad);
    (w_new, p_new)
}

/// `(cos, sin)` of the anchor heading after it turned by `turn_rad` from the
/// heading whose `(cos, sin)` is `(c, s)`; `heading_rad` is the new heading.
///
/// A library `sin_cos` per correction was a tenth of a step: a small turn
/// (every window at 100 Hz on a slow car) rotates the pair by the series
/// instead, renormalised by one Newton step; its rounding random-walks at
/// ~1e-16 rad per window, far below anything the filter resolves. A large
/// turn would cost a library call anyway, so it recomputes from the heading
/// itself, which also clears what the rotations accumulated.
pub(super) fn turned_cos_sin((c, s): (f64, f64), turn_rad: f64, heading_rad: f64) -> (f64, f64) {
    if turn_rad.abs() > SMALL_ANGLE_RAD {
        let (s, c) = heading_rad.sin_cos();
        return (c, s);
    }
    let (st, ct) = small_sin_cos(turn_rad);
    let (c1, s1) = (c * ct - s * st, s * ct + c * st);
    let norm = 1.5 - 0.5 * (c1 * c1 + s1 * s1);
    (c1 * norm, s1 * norm)
}

/// Propagates the sensitivity `v = ∂w/∂b` of a window pose to a bias `b`
/// whose effect on the increment is `j = ∂[Δd, Δθ]/∂b` (`v' = A v + B j`,
/// with the A, B of the prediction at mid heading `m`).
pub(super) fn propagate_sensitivity(
    v: &Vec3,
    inc: Increment,
    j: (f64, f64),
    s: f64,
    c: f64,
) -> Vec3 {
    let d = inc.distance_m;
    Vec3::new(
        v.x - d * s * v.z + c * j.0 - 0.5 * d * s * j.1,
        v.y + d * c * v.z + s * j.0 + 0.5 * d * c * j.1,
        v.z + j.1,
    )
}

/// `anchor ⊕ w` for the pose.
pub(super) fn compose(anchor: &Vec3, (c, s): (f64, f64), w: &Vec3) -> Vec3 {
    Vec3::new(
        anchor.x + c * w.x - s * w.y,
        anchor.y + s * w.x + c * w.y,
        wrap_angle(anchor.z + w.z),
    )
}

/// The covariance of `anchor ⊕ w`: `J_a P_a J_aᵀ + R P_w Rᵀ`.
///
/// Written out: `J_a = I + a e₃ᵀ` with `a = (−Δy, Δx, 0)` (as the prediction's
/// `A`) and `R` a rotation of the x-y block, so both terms are a few products.
/// Only the upper triangles are read: every covariance here is built
/// symmetric entry by entry (`State::new` symmetrises the caller's).
pub(super) fn compose_covariance(p_a: &Mat3, (c, s): (f64, f64), w: &Vec3, p_w: &Mat3) -> Mat3 {
    let dx = c * w.x - s * w.y;
    let dy = s * w.x + c * w.y;
    let (ax, ay) = (-dy, dx);
    let (cx, cy, cz) = (p_a[(0, 2)], p_a[(1, 2)], p_a[(2, 2)]);
    let (a11, a22, a33) = (p_w[(0, 0)], p_w[(1, 1)], p_w[(2, 2)]);
    let (a12, a13, a23) = (p_w[(0, 1)], p_w[(0, 2)], p_w[(1, 2)]);
    let (cc, ss, cs) = (c * c, s * s, c * s);
    let xx = p_a[(0, 0)] + 2.0 * ax * cx + cz * ax * ax + cc * a11 - 2.0 * cs * a12 + ss * a22;
    let xy = p_a[(0, 1)] + ax * cy + ay * cx + cz * ax * ay + cs * (a11 - a22) + (cc - ss) * a12;
    let yy = p_a[(1, 1)] + 2.0 * ay * cy + cz * ay * ay + ss * a11 + 2.0 * cs * a12 + cc * a22;
    let xz = cx + ax * cz + c * a13 - s * a23;
    let yz = cy + ay * cz + s * a13 + c * a23;
    let zz = cz + a33;
    Mat3::new(xx, xy, xz, xy, yy, yz, xz, yz, zz)
}

/// Joseph-form update `(I−K) P (I−K)ᵀ + K R Kᵀ` with gain `K`, prior `P` and
/// measurement covariance `R`, both symmetric.
///
/// Written out because it ran on every correction as four general 3×3
/// products and a symmetrisation (a fifth of a step's instructions): the
/// result is symmetric, so only its six distinct entries are formed from
/// `(I−K)P` and `KR`, and it is symmetric by construction.
pub(super) fn joseph(K: &Mat3, P: &Mat3, R: &Mat3) -> Mat3 {
    // Plain arrays (row-major here): nalgebra's operators copied whole
    // matrices between the products.
    let k = |i: usize, j: usize| K[(i, j)];
    let m = |i: usize, j: usize| if i == j { 1.0 - k(i, j) } else { -k(i, j) };
    let (mut mp, mut kr) = ([[0.0; 3]; 3], [[0.0; 3]; 3]);
    for i in 0..3 {
        for j in 0..3 {
            mp[i][j] = m(i, 0) * P[(0, j)] + m(i, 1) * P[(1, j)] + m(i, 2) * P[(2, j)];
            kr[i][j] = k(i, 0) * R[(0, j)] + k(i, 1) * R[(1, j)] + k(i, 2) * R[(2, j)];
        }
    }
    let entry = |i: usize, j: usize| {
        mp[i][0] * m(j, 0)
            + mp[i][1] * m(j, 1)
            + mp[i][2] * m(j, 2)
            + (kr[i][0] * k(j, 0) + kr[i][1] * k(j, 1) + kr[i][2] * k(j, 2))
    };
    let (xx, xy, xz) = (entry(0, 0), entry(0, 1), entry(0, 2));
    let (yy, yz, zz) = (entry(1, 1), entry(1, 2), entry(2, 2));
    Mat3::new(xx, xy, xz, xy, yy, yz, xz, yz, zz)
}

/// The symmetric matrix with this upper triangle.
pub(super) fn symmetric(xx: f64, xy: f64, xz: f64, yy: f64, yz: f64, zz: f64) -> Mat3 {
    Mat3::new(xx, xy, xz, xy, yy, yz, xz, yz, zz)
}

/// The inverse of a symmetric 3×3 matrix by its six distinct cofactors
/// (nalgebra's general inverse forms nine); `None` if singular.
pub(super) fn symmetric_inverse(S: &Mat3) -> Option<Mat3> {
    let (a, b, c) = (S[(0, 0)], S[(1, 1)], S[(2, 2)]);
    let (d, e, f) = (S[(0, 1)], S[(0, 2)], S[(1, 2)]);
    let (c00, c01, c02) = (b * c - f * f, e * f - d * c, d * f - e * b);
    let (c11, c12, c22) = (a * c - e * e, d * e - a * f, a * b - d * d);
    let det = a * c00 + d * c01 + e * c02;
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv_det = 1.0 / det;
    let (i00, i01, i02) = (c00 * inv_det, c01 * inv_det, c02 * inv_det);
    let (i11, i12, i22) = (c11 * inv_det, c12 * inv_det, c22 * inv_det);
    Some(Mat3::new(i00, i01, i02, i01, i11, i12, i02, i12, i22))
}
