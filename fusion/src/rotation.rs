//! Headings carried as `(cos, sin)` pairs and turned by rotation: the
//! library's `sin_cos` per step was the largest single cost of a filter step
//! and of the rear-only odometry beside it, while their turns per step are
//! small enough for a short series.

/// Below this an angle's sine and cosine come from [`small_sin_cos`]'s series.
pub(crate) const SMALL_ANGLE_RAD: f64 = 0.01;

/// `(sin, cos)` of a small angle by its Taylor series (exact to rounding for
/// |x| ≤ 0.01), falling back to the library call for larger ones.
pub(crate) fn small_sin_cos(x: f64) -> (f64, f64) {
    if x.abs() > SMALL_ANGLE_RAD {
        return x.sin_cos();
    }
    // Products by constant reciprocals: the divisions by 6, 20, … were
    // fourteen divisions a step (the compiler may not turn them into products).
    // The cosine's x⁸/8! term (< 3e-21 here) is below half an ulp of 1.
    let x2 = x * x;
    let sin = x * (1.0 - x2 * (1.0 / 6.0) * (1.0 - x2 * (1.0 / 20.0) * (1.0 - x2 * (1.0 / 42.0))));
    let cos = 1.0 - x2 * 0.5 * (1.0 - x2 * (1.0 / 12.0) * (1.0 - x2 * (1.0 / 30.0)));
    (sin, cos)
}

/// Given `(cos θ, sin θ)` of a window heading and a step turning `Δθ`,
/// returns `(sin m, cos m)` of the mid heading `m = θ + Δθ/2` and
/// `(cos, sin)` of `θ + Δθ`, by rotation instead of trigonometric calls
/// (they dominate a step's cost). One Newton step keeps the pair on the
/// unit circle however long the window.
pub(crate) fn advance_heading((c, s): (f64, f64), dtheta_rad: f64) -> ((f64, f64), (f64, f64)) {
    let (sh, ch) = small_sin_cos(0.5 * dtheta_rad);
    let (s_m, c_m) = (s * ch + c * sh, c * ch - s * sh);
    let (s_full, c_full) = (s_m * ch + c_m * sh, c_m * ch - s_m * sh);
    let norm = 1.5 - 0.5 * (c_full * c_full + s_full * s_full);
    ((s_m, c_m), (c_full * norm, s_full * norm))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn small_sin_cos_matches_the_library(x in -0.012f64..0.012) {
            let (s, c) = small_sin_cos(x);
            let (es, ec) = x.sin_cos();
            prop_assert!((s - es).abs() <= 2.0 * f64::EPSILON * es.abs(), "{s} vs {es}");
            prop_assert!((c - ec).abs() <= 2.0 * f64::EPSILON, "{c} vs {ec}");
        }

        #[test]
        fn rotated_headings_match_trigonometry(steps in prop::collection::vec(-0.05f64..0.05, 1..500)) {
            let mut cs = (1.0, 0.0);
            let mut theta = 0.0f64;
            for dth in steps {
                let ((s_m, c_m), next) = advance_heading(cs, dth);
                let (es, ec) = (theta + 0.5 * dth).sin_cos();
                prop_assert!((s_m - es).abs() < 1e-12 && (c_m - ec).abs() < 1e-12);
                theta += dth;
                cs = next;
            }
            prop_assert!((cs.0 - theta.cos()).abs() < 1e-12 && (cs.1 - theta.sin()).abs() < 1e-12);
        }
    }
}
