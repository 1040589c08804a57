use super::wheels::{Axle, LAUNCH_ACCEL_MPS2};
use super::*;
use crate::odometry::rear_increment;
use crate::params::SteeringMap;
use crate::params::VehicleParams;
use nalgebra::Matrix3x2;
use proptest::prelude::*;

fn car() -> VehicleParams {
    VehicleParams::new(
        0.25,
        0.30,
        0.30,
        WheelSet::splat(0.09),
        1000,
        SteeringMap::IDENTITY,
    )
    .unwrap()
}

/// Wheel distances of an exact arc step of the rear-axle centre.
fn arc_input(p: &VehicleParams, ds: f64, phi: f64) -> OdometryInput {
    let [g_rl, g_rr, g_fl, g_fr] = wheel_distance_factors(p, phi);
    OdometryInput {
        wheel_m: WheelSet {
            rear_left: ds * g_rl,
            rear_right: ds * g_rr,
            front_left: ds * g_fl,
            front_right: ds * g_fr,
        },
        front_valid: true,
        steer_angle_rad: phi,
        zero_is_floor: false,
        yaw_rate_radps: None,
        dt_s: 0.0,
    }
}

#[test]
fn a_gyro_dropped_before_it_led_leaves_the_wheels_pose_as_it_was() {
    // Exact wheels on an arc, the gyro reading the arc's rate: the aided
    // filter runs beside the wheels and does not take the lead. Dropping the
    // gyro (found at fault) keeps the wheels-only filter's pose, whatever
    // pose the caller offers.
    let p = car();
    let ekf = Ekf::new(EkfConfig::new(p)).unwrap();
    // 0.01 m a 0.01 s sample: 1 m/s.
    let rate = 0.05f64.tan() / p.wheelbase_m();
    let driven = (0..200).fold(State::origin(), |s, _| {
        let mut input = arc_input(&p, 0.01, 0.05);
        input.dt_s = 0.01;
        input.yaw_rate_radps = Some(rate);
        ekf.step(&s, &input).unwrap()
    });
    assert!(driven.yaw_aided() && !driven.aided_leads());
    let dropped = driven.without_yaw_rate(Pose::default());
    assert!(!dropped.yaw_aided());
    assert_eq!(dropped.pose(), driven.pose());
    assert_eq!(dropped.pose_unwrapped(), driven.pose_unwrapped());
    assert_eq!(dropped.covariance(), driven.covariance());
}

#[test]
fn rebased_state_starts_at_the_origin_and_keeps_what_was_learnt() {
    let p = car();
    // The default configuration learns the steering offset.
    let ekf = Ekf::new(EkfConfig::new(p)).unwrap();
    // A left arc with a 0.02 rad steering error, so an offset is learnt.
    let drive = |from: State| {
        (0..400).fold(from, |s, _| {
            let mut input = arc_input(&p, 0.01, 0.05);
            input.steer_angle_rad += 0.02;
            ekf.step(&s, &input).unwrap()
        })
    };
    let driven = drive(State::origin());
    assert!(driven.pose().x_m > 3.0, "{:?}", driven.pose());
    assert!(driven.covariance().norm() > 0.0);
    assert!(driven.steer_offset_rad().abs() > 1e-3, "{driven:?}");
    let rebased = driven.rebased_at_origin();
    assert_eq!(rebased.pose(), Pose::default());
    assert_eq!(rebased.covariance(), Mat3::zeros());
    assert_eq!(rebased.steer_offset_rad(), driven.steer_offset_rad());
    assert_eq!(rebased.front_scale(), driven.front_scale());
    assert_eq!(rebased.stats, driven.stats);
    assert_eq!(rebased.slip_counts, driven.slip_counts);
    // From the new origin the same drive ends where a filter that had
    // learnt the same would: nearer the first end than an untaught one.
    let again = drive(rebased).pose();
    let first = driven.pose();
    let error = |q: Pose| (q.x_m - first.x_m).hypot(q.y_m - first.y_m);
    assert!(error(again) < 0.05, "{again:?} vs {first:?}");
}

#[test]
fn inlined_front_conversion_matches_odometry_module() {
    use crate::odometry::{front_increment_differential, front_increment_exact};
    let p = VehicleParams::new(
        0.25,
        0.30,
        0.27,
        WheelSet::splat(0.09),
        1000,
        SteeringMap::IDENTITY,
    )
    .unwrap();
    for phi in [-0.5f64, -0.1, 0.0, 0.3] {
        let terms = SteerTerms::at(&Derived::new(&EkfConfig::new(p)), phi);
        assert_eq!(terms.tan_phi, phi.tan());
        assert!((terms.cos_phi - phi.cos()).abs() < 1e-15);
        assert!((terms.sin_phi - phi.sin()).abs() < 1e-15);
        let g = terms.g;
        let r = wheel_distance_factors(&p, phi);
        for k in 0..4 {
            assert!((g[k] - r[k]).abs() < 1e-14);
        }
        for (heading, reference) in [
            (
                FrontHeading::Steering,
                front_increment_exact(&p, 0.011, 0.012, phi).unwrap(),
            ),
            (
                FrontHeading::WheelDifference,
                front_increment_differential(&p, 0.011, 0.012, phi).unwrap(),
            ),
        ] {
            let ekf = Ekf::new(EkfConfig {
                front_heading: heading,
                ..EkfConfig::new(p)
            })
            .unwrap();
            let (inc, _, _) = ekf.front(0.011, 0.012, &terms);
            assert!((inc.distance_m - reference.distance_m).abs() < 1e-15);
            assert!((inc.dtheta_rad - reference.dtheta_rad).abs() < 1e-14);
        }
    }
}

#[test]
fn rotated_anchor_heading_tracks_the_heading() {
    // Every window's turn is small here, so the anchor's (cos, sin) is
    // only ever rotated: after 20,000 windows it must still match.
    let p = car();
    let ekf = Ekf::new(EkfConfig {
        correct_every: 1,
        ..EkfConfig::new(p)
    })
    .unwrap();
    let mut st = State::origin();
    for k in 0..20_000 {
        let phi = 0.4 * (f64::from(k) * 1e-3).sin();
        st = ekf.step(&st, &arc_input(&p, 0.002, phi)).unwrap();
    }
    assert!(st.pose_unwrapped().heading_rad.abs() > 1.0);
    let (c, s) = st.anchor_cos_sin;
    assert!((c - st.anchor.z.cos()).abs() < 1e-12 && (s - st.anchor.z.sin()).abs() < 1e-12);
}

proptest! {
    #[test]
    fn structured_composition_equals_the_general_form(
        la in prop::collection::vec(-1.0f64..1.0, 6), lw in prop::collection::vec(-1.0f64..1.0, 6),
        h in -3.0f64..3.0, wx in -2.0f64..2.0, wy in -2.0f64..2.0,
    ) {
        let tri = |l: &[f64]| nalgebra::Matrix3::new(l[0], 0.0, 0.0, l[1], l[2], 0.0, l[3], l[4], l[5]);
        let (La, Lw) = (tri(&la), tri(&lw));
        let (Pa, Pw) = (La * La.transpose(), Lw * Lw.transpose());
        let w = Vec3::new(wx, wy, 0.1);
        let (s, c) = h.sin_cos();
        let fast = compose_covariance(&Pa, (c, s), &w, &Pw);
        let (dx, dy) = (c * wx - s * wy, s * wx + c * wy);
        let Ja = Mat3::new(1.0, 0.0, -dy, 0.0, 1.0, dx, 0.0, 0.0, 1.0);
        let R = Mat3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
        let general = Ja * Pa * Ja.transpose() + R * Pw * R.transpose();
        prop_assert!((fast - general).abs().max() < 1e-12, "{fast} vs {general}");
    }

    #[test]
    fn structured_propagation_equals_the_general_form(
        d in -0.1f64..0.1, dth in -0.2f64..0.2, h in -3.0f64..3.0,
        l in prop::collection::vec(-1.0f64..1.0, 6), q in prop::collection::vec(0.0f64..1.0, 3),
    ) {
        let L = nalgebra::Matrix3::new(l[0], 0.0, 0.0, l[1], l[2], 0.0, l[3], l[4], l[5]);
        let P = L * L.transpose();
        let Q = Matrix2::new(q[0], 0.1 * q[1], 0.1 * q[1], q[2]);
        let w = Vec3::new(0.3, -0.2, h);
        let inc = Increment { distance_m: d, dtheta_rad: dth };
        let (w1, p1) = propagate(&w, &P, inc, &Q);
        let (s, c) = (h + 0.5 * dth).sin_cos();
        let A = Mat3::new(1.0, 0.0, -d * s, 0.0, 1.0, d * c, 0.0, 0.0, 1.0);
        let B = Matrix3x2::new(c, -0.5 * d * s, s, 0.5 * d * c, 0.0, 1.0);
        let p2 = A * P * A.transpose() + B * Q * B.transpose();
        prop_assert!((p1 - p2).abs().max() < 1e-12, "{p1} vs {p2}");
        prop_assert!((w1 - Vec3::new(0.3 + d * c, -0.2 + d * s, h + dth)).abs().max() < 1e-15);
    }
}

#[test]
fn learns_a_steering_offset_from_the_rear_wheels() {
    let p = car();
    // Blending, so that the offset shows in the pose; the default learns
    // it the same way (it then matters in windows the gate gives the front).
    let blending = EkfConfig {
        blend_accepted: true,
        ..EkfConfig::new(p)
    };
    let ekf = Ekf::new(blending).unwrap();
    let no_learning = Ekf::new(EkfConfig {
        steer_offset_drift_rad: None,
        ..blending
    })
    .unwrap();
    let default = Ekf::new(EkfConfig::new(p)).unwrap();
    let mut d = State::origin();
    let bias = 1f64.to_radians();
    let (mut a, mut b) = (State::origin(), State::origin());
    for k in 0..20_000 {
        let phi = 0.3 * (f64::from(k) * 2e-4).sin();
        let mut inp = arc_input(&p, 0.001, phi);
        inp.steer_angle_rad += bias;
        a = ekf.step(&a, &inp).unwrap();
        b = no_learning.step(&b, &inp).unwrap();
        d = default.step(&d, &inp).unwrap();
    }
    for learnt in [a.steer_offset_rad(), d.steer_offset_rad()] {
        assert!((learnt - bias).abs() < 0.05 * bias, "{learnt}");
    }
    assert_eq!(b.steer_offset_rad(), 0.0);
    // The truth is the rear odometry here (exact arcs): learning keeps the
    // fused pose on it, the bias without learning pulls it away.
    let rear = Ekf::new(EkfConfig::rear_only(p)).unwrap();
    let mut r = State::origin();
    for k in 0..20_000 {
        let phi = 0.3 * (f64::from(k) * 2e-4).sin();
        r = rear.step(&r, &arc_input(&p, 0.001, phi)).unwrap();
    }
    let err = |s: &State| (s.pose().x_m - r.pose().x_m).hypot(s.pose().y_m - r.pose().y_m);
    assert!(err(&a) < err(&b), "{} vs {}", err(&a), err(&b));
}

#[test]
fn a_wheel_at_the_speed_sensors_floor_is_filled_from_the_others() {
    let p = car();
    let ekf = Ekf::new(EkfConfig::rear_only(p)).unwrap();
    let start = State::origin();
    let exact = arc_input(&p, 0.003, 0.2);
    let mut inner_zero = exact;
    inner_zero.wheel_m.rear_left = 0.0;
    let heading = |inp: &OdometryInput| ekf.step(&start, inp).unwrap().pose().heading_rad;
    let want = heading(&exact);
    // A speed sensor below its floor: filled through the geometry, exactly.
    let floor = OdometryInput {
        zero_is_floor: true,
        ..inner_zero
    };
    assert!((heading(&floor) - want).abs() < 1e-12);
    // An encoder's zero step is quantisation: left as it is.
    assert!((heading(&inner_zero) - want).abs() > 1e-3);
    // Standing still, or wheels moving both ways: nothing to fill.
    let still = OdometryInput {
        wheel_m: WheelSet::splat(0.0),
        ..floor
    };
    assert_eq!(ekf.step(&start, &still).unwrap().pose(), start.pose());
    let mut both_ways = floor;
    both_ways.wheel_m.rear_right = -both_ways.wheel_m.rear_right;
    let unfilled = OdometryInput {
        zero_is_floor: false,
        ..both_ways
    };
    assert_eq!(heading(&both_ways), heading(&unfilled));
}

#[test]
fn learns_the_front_distance_scale() {
    let p = car();
    let ekf = Ekf::new(EkfConfig {
        front_scale_drift: Some(1e-5),
        ..EkfConfig::new(p)
    })
    .unwrap();
    let mut st = State::origin();
    for k in 0..20_000 {
        let mut inp = arc_input(&p, 0.001, 0.2 * (f64::from(k) * 3e-4).sin());
        inp.wheel_m.front_left *= 1.01;
        inp.wheel_m.front_right *= 1.01;
        st = ekf.step(&st, &inp).unwrap();
    }
    assert!(
        (st.front_scale() * 1.01 - 1.0).abs() < 1e-3,
        "{}",
        st.front_scale()
    );
    assert_eq!(State::origin().front_scale(), 1.0);
}

#[test]
fn rear_only_is_plain_rear_odometry() {
    let p = car();
    let ekf = Ekf::new(EkfConfig::rear_only(p)).unwrap();
    let mut st = State::origin();
    let mut pose = Pose::default();
    for k in 0..1000 {
        let phi = 0.3 * (f64::from(k) * 0.01).sin();
        let mut inp = arc_input(&p, 0.001, phi);
        inp.wheel_m.rear_left *= 1.01;
        st = ekf.step(&st, &inp).unwrap();
        pose = pose
            .advanced(rear_increment(&p, inp.wheel_m.rear_left, inp.wheel_m.rear_right).unwrap());
    }
    let e = st.pose_unwrapped();
    assert!((e.x_m - pose.x_m).abs() < 1e-12 && (e.y_m - pose.y_m).abs() < 1e-12);
    assert!((e.heading_rad - pose.heading_rad).abs() < 1e-12);
    assert_eq!(st.stats.corrections, 0);
}

#[test]
fn consensus_blames_the_slipping_wheel() {
    let p = car();
    let ekf = Ekf::new(EkfConfig::new(p)).unwrap();
    for (slipping, expect_front) in [(Wheel::RearLeft, true), (Wheel::FrontRight, false)] {
        let mut st = State::origin();
        for _ in 0..50 {
            let mut inp = arc_input(&p, 0.001, 0.2);
            inp.wheel_m[slipping] *= 1.5;
            st = ekf.step(&st, &inp).unwrap();
        }
        assert!(st.slip_flags[slipping], "{slipping:?}: {:?}", st.stats);
        assert_eq!(st.slip_counts[slipping], 1);
        assert_eq!(st.stats.rejected_used_front, u64::from(expect_front));
        assert_eq!(st.stats.rejected_kept_rear, u64::from(!expect_front));
        // The clean axle's increment was kept: the pose is the true arc.
        let kappa = 0.2f64.tan() / 0.25;
        let theta = kappa * 0.05;
        assert!(
            (st.pose().heading_rad - theta).abs() < 1e-8,
            "{:?}",
            st.pose()
        );
        assert!((st.pose().x_m - theta.sin() / kappa).abs() < 1e-8);
    }
}

#[test]
fn agreeing_axles_are_accepted_and_shrink_the_covariance() {
    let p = car();
    let blending = Ekf::new(EkfConfig {
        blend_accepted: true,
        ..EkfConfig::new(p)
    })
    .unwrap();
    let default = Ekf::new(EkfConfig::new(p)).unwrap();
    let rear = Ekf::new(EkfConfig::rear_only(p)).unwrap();
    let (mut a, mut b, mut d) = (State::origin(), State::origin(), State::origin());
    for _ in 0..500 {
        let inp = arc_input(&p, 0.001, 0.1);
        a = blending.step(&a, &inp).unwrap();
        b = rear.step(&b, &inp).unwrap();
        d = default.step(&d, &inp).unwrap();
    }
    assert_eq!((a.stats.corrections, a.stats.accepted), (10, 10));
    assert!(a.covariance().trace() < b.covariance().trace());
    assert!((a.pose().x_m - b.pose().x_m).abs() < 1e-9);
    // The default checks agreeing windows and keeps the rear increment.
    assert_eq!((d.stats.corrections, d.stats.accepted), (10, 10));
    assert_eq!(d.pose(), b.pose());
    assert_eq!(d.covariance(), b.covariance());
}

#[test]
fn step_into_is_step_bit_for_bit() {
    // Two buffers flipped on success, as the daemon's pipeline keeps them,
    // against states returned by value; errors in between leave `prev`.
    let p = car();
    let ekf = Ekf::new(EkfConfig::new(p)).unwrap();
    let mut by_value = State::origin();
    let mut buffers = [State::origin(), State::origin()];
    let mut current = 0;
    for k in 0..3_000 {
        let phi = 0.5 * (f64::from(k) * 3e-3).sin();
        let mut input = arc_input(&p, 0.003, phi);
        if k % 97 == 5 {
            input.wheel_m.rear_left = f64::NAN;
        }
        let expected = ekf.step(&by_value, &input);
        let (prev, next) = if current == 0 {
            let [a, b] = &mut buffers;
            (&*a, b)
        } else {
            let [a, b] = &mut buffers;
            (&*b, a)
        };
        let got = ekf.step_into(prev, next, &input);
        assert_eq!(got.is_ok(), expected.is_ok(), "step {k}");
        if let Ok(state) = expected {
            by_value = state;
            current ^= 1;
        }
        assert_eq!(
            format!("{:?}", buffers[current]),
            format!("{by_value:?}"),
            "step {k}"
        );
    }
    assert!(by_value.stats.corrections > 10);
}

proptest! {
    /// The steering terms kept from the last step are exactly what the
    /// step would compute afresh: a filter that forgets them before
    /// every step ends bit for bit where the one reusing them does.
    #[test]
    fn reused_steering_terms_change_nothing(
        steps in prop::collection::vec((0usize..4, 0.0f64..0.004, prop::bool::weighted(0.995)), 1..400)
    ) {
        let p = car();
        let ekf = Ekf::new(EkfConfig::new(p)).unwrap();
        // Few distinct angles, so most steps repeat the one before; the
        // steering signal reads 0.02 rad high, so the learnt offset (and
        // with it the angle the terms are for) moves at every correction
        // (a window with a front sample missing is not corrected: rare here).
        let angles = [0.0, 0.2, -0.35, 0.2 + 1e-12];
        let (mut reusing, mut fresh) = (State::origin(), State::origin());
        for (i, ds, front_valid) in steps {
            let input = OdometryInput {
                front_valid,
                steer_angle_rad: angles[i] + 0.02,
                ..arc_input(&p, ds, angles[i])
            };
            fresh.steer_terms = SteerTerms::NONE;
            reusing = ekf.step(&reusing, &input).unwrap();
            fresh = ekf.step(&fresh, &input).unwrap();
            prop_assert_eq!(reusing, fresh);
        }
    }
}

#[test]
fn non_finite_inputs_are_errors_and_leave_the_state() {
    let p = car();
    let ekf = Ekf::new(EkfConfig::new(p)).unwrap();
    let st = State::origin();
    let mut inp = arc_input(&p, 0.001, 0.1);
    inp.wheel_m.front_left = f64::NAN;
    assert!(matches!(
        ekf.step(&st, &inp),
        Err(Error::NonFiniteInput {
            name: "front_left_m",
            ..
        })
    ));
    inp.front_valid = false;
    assert!(
        ekf.step(&st, &inp).is_ok(),
        "a stale front sample is not read"
    );
    // The sum test's slow path names the culprit, and finite inputs whose
    // sum overflows are not reported as non-finite.
    let mut rear = inp;
    rear.wheel_m.rear_right = f64::NAN;
    assert!(matches!(
        ekf.step(&st, &rear),
        Err(Error::NonFiniteInput {
            name: "rear_right_m",
            ..
        })
    ));
    rear.wheel_m.rear_right = f64::MAX;
    rear.wheel_m.rear_left = f64::MAX;
    assert!(!matches!(
        ekf.step(&st, &rear),
        Err(Error::NonFiniteInput { .. })
    ));
    inp.steer_angle_rad = f64::INFINITY;
    assert!(ekf.step(&st, &inp).is_err());
    inp.steer_angle_rad = 1.6;
    assert!(matches!(
        ekf.step(&st, &inp),
        Err(Error::SteeringOutOfRange { .. })
    ));
    assert!(
        Ekf::new(EkfConfig {
            correct_every: 0,
            ..EkfConfig::new(p)
        })
        .is_err()
    );
    assert!(
        Ekf::new(EkfConfig {
            k_rear_m: f64::NAN,
            ..EkfConfig::new(p)
        })
        .is_err()
    );
    assert!(
        State::new(
            Pose {
                x_m: f64::NAN,
                ..Pose::default()
            },
            Mat3::zeros()
        )
        .is_err()
    );
}

#[test]
fn heading_stays_wrapped_and_unwrapped_counts_turns() {
    let p = car();
    let ekf = Ekf::new(EkfConfig::new(p)).unwrap();
    let mut st = State::origin();
    let kappa = 0.3f64.tan() / 0.25;
    let n = (3.0 * std::f64::consts::TAU / kappa / 0.002).round() as usize;
    for _ in 0..n {
        st = ekf.step(&st, &arc_input(&p, 0.002, 0.3)).unwrap();
        let h = st.pose().heading_rad;
        assert!(h > -std::f64::consts::PI && h <= std::f64::consts::PI);
    }
    assert!((st.pose_unwrapped().heading_rad - 3.0 * std::f64::consts::TAU).abs() < 0.01);
}

proptest! {
    #[test]
    fn covariance_stays_symmetric_psd_and_finite(
        steps in prop::collection::vec((-0.01f64..0.02, -0.5f64..0.5, -0.5f64..0.5, any::<bool>()), 1..300),
        literal in any::<bool>(),
    ) {
        let p = car();
        let cfg = if literal { EkfConfig::paper_literal(p) } else { EkfConfig::new(p) };
        let ekf = Ekf::new(cfg).unwrap();
        let mut st = State::origin();
        for (ds, phi, slip, front) in steps {
            let mut inp = arc_input(&p, ds, phi);
            inp.wheel_m.rear_left *= 1.0 + slip;
            inp.front_valid = front;
            st = ekf.step(&st, &inp).unwrap();
            let P = st.covariance();
            prop_assert!(P.iter().all(|v| v.is_finite()));
            prop_assert!((P - P.transpose()).abs().max() < 1e-15);
            let eig = P.symmetric_eigenvalues();
            prop_assert!(eig.min() > -1e-12, "{eig:?}");
            prop_assert!(st.pose().x_m.is_finite() && st.pose().heading_rad.is_finite());
        }
    }
}

#[test]
fn a_launch_from_below_the_wheel_sensors_floor_widens_the_position_only_then() {
    let input = |speed_mps: f64, zero_is_floor: bool| OdometryInput {
        wheel_m: WheelSet::splat(speed_mps * 0.01),
        front_valid: true,
        zero_is_floor,
        dt_s: 0.01,
        ..OdometryInput::default()
    };
    let mut st = State::origin();
    // Standing, then first seen at 0.75 m/s: crept anywhere in 0..v²/2a.
    assert_eq!(
        launch_variance(&mut st, &input(0.0, true), &input(0.0, true).wheel_m),
        0.0
    );
    let moving = input(0.75, true);
    let var = launch_variance(&mut st, &moving, &moving.wheel_m);
    let creep_max_m = 0.75 * 0.75 / (2.0 * LAUNCH_ACCEL_MPS2);
    assert!(
        (var - creep_max_m * creep_max_m / 3.0).abs() < 1e-12,
        "{var}"
    );
    // Moving on: no launch.
    assert_eq!(launch_variance(&mut st, &moving, &moving.wheel_m), 0.0);

    // The log's first step at speed after a zero is not a floor's exit.
    let mut st = State::origin();
    let _ = launch_variance(&mut st, &input(0.0, true), &input(0.0, true).wheel_m);
    let fast = input(11.5, true);
    assert_eq!(launch_variance(&mut st, &fast, &fast.wheel_m), 0.0);

    // Encoders read every crawl: no floor, no creep.
    let mut st = State::origin();
    let _ = launch_variance(&mut st, &input(0.0, false), &input(0.0, false).wheel_m);
    let ticks = input(0.75, false);
    assert_eq!(launch_variance(&mut st, &ticks, &ticks.wheel_m), 0.0);
}

#[test]
fn a_locked_axle_is_blamed_not_a_rolling_wheel_beside_it() {
    // Both rear wheels locked for most of a window: the median of the four
    // lies between the axles, and the farthest wheel was a rolling front.
    assert!(blamed_wheel([0.4, 0.5, 4.6, 4.7], None).is_rear());
    // Both fronts locked: a front is blamed and the rear kept.
    assert!(!blamed_wheel([4.6, 4.7, 0.3, 0.2], None).is_rear());
    // One wheel off: the farthest from the median, as before.
    assert_eq!(blamed_wheel([4.6, 6.0, 4.7, 4.65], None), Wheel::RearRight);
    assert_eq!(blamed_wheel([4.6, 4.6, 4.7, 2.0], None), Wheel::FrontRight);
}

#[test]
fn an_axle_that_changed_speed_faster_than_a_car_is_blamed() {
    // Both rear wheels spinning at 2.5 times the car: by the distances alone
    // the rolling front reads below half the rear, like a locked front.
    let spinning = [11.0, 12.5, 4.7, 4.6];
    assert!(!blamed_wheel(spinning, None).is_rear());
    assert_eq!(blamed_wheel(spinning, Some(Axle::Rear)), Wheel::RearRight);
    // The same with the roles swapped: a front axle that jumped.
    assert_eq!(
        blamed_wheel([4.6, 4.7, 9.0, 12.0], Some(Axle::Front)),
        Wheel::FrontRight
    );
}

/// An [`AxleWatch`] fed `rear` and `front` speeds (m/s) at 12 ms steps.
fn watched(speeds: impl IntoIterator<Item = (f64, f64)>) -> AxleWatch {
    let mut watch = AxleWatch::default();
    for (rear, front) in speeds {
        watch.step([rear, front], 0.012, 12.0);
    }
    watch
}

#[test]
fn the_axle_watch_tells_a_spin_and_a_lock_from_the_car_braking() {
    let steady = std::iter::repeat_n((8.0, 8.0), 20);
    // The driven axle spins up from 8 to 20 m/s within 0.1 s.
    let spin = (1..=8).map(|k| (8.0 + 1.5 * f64::from(k), 8.0));
    assert_eq!(
        watched(steady.chain(spin)).window_suspect(),
        Some(Axle::Rear)
    );
    // A front axle locking, 11 m/s to 0 in a quarter second, while the rear
    // brakes at 8 m/s².
    let lock = (1..=20).map(|k| {
        (
            11.0 - 0.25 * f64::from(k),
            (11.0 - 0.55 * f64::from(k)).max(0.0),
        )
    });
    assert_eq!(
        watched(std::iter::once((11.0, 11.0)).chain(lock)).window_suspect(),
        Some(Axle::Front)
    );
    // The car braking at 10 m/s² on both axles, with 0.05 m/s of noise on
    // one: nothing is suspect.
    let braking = (0..100).map(|k| {
        let v = 20.0 - 10.0 * 0.012 * f64::from(k);
        (v, v + if k % 2 == 0 { 0.05 } else { -0.05 })
    });
    assert_eq!(watched(braking).window_suspect(), None);
    // Both axles at once (all four wheels locking): no single axle.
    let all = (1..=10).map(|k| {
        (
            (11.0 - 1.1 * f64::from(k)).max(0.0),
            (11.0 - 1.1 * f64::from(k)).max(0.0),
        )
    });
    assert_eq!(
        watched(std::iter::once((11.0, 11.0)).chain(all)).window_suspect(),
        None
    );
}

#[test]
fn a_suspect_axle_stays_suspect_until_the_axles_agree() {
    let mut watch = watched(
        std::iter::repeat_n((8.0, 8.0), 5).chain((1..=8).map(|k| (8.0 + 1.5 * f64::from(k), 8.0))),
    );
    // Still spinning in the next window, without a new jump.
    watch.new_window();
    for _ in 0..50 {
        watch.step([20.0, 8.2], 0.012, 12.0);
    }
    assert_eq!(watch.window_suspect(), Some(Axle::Rear));
    // The spin ends (the axle falls back faster than a car brakes, which
    // does not move the suspicion to the front) and the axles agree.
    watch.step([8.3, 8.25], 0.012, 12.0);
    watch.new_window();
    for _ in 0..50 {
        watch.step([8.3, 8.3], 0.012, 12.0);
    }
    assert_eq!(watch.window_suspect(), None);
}

/// Straight at 11 m/s, every wheel locked for 0.9 s while the car slides at
/// 8 m/s² down to 3.8 m/s, then rolling at 3.8 m/s for 1 s: where each filter
/// ends, against the true 21.2 + 6.7 + 3.8 m.
fn after_a_locked_slide(yaw_rate_radps: Option<f64>) -> f64 {
    let ekf = Ekf::new(EkfConfig::new(car())).unwrap();
    let mut st = State::origin();
    let dt = 0.02;
    let mut truth = 0.0;
    let mut v: f64 = 11.0;
    let step = |st: &mut State, wheel_mps: f64, car_mps: f64| {
        let input = OdometryInput {
            wheel_m: WheelSet::splat(wheel_mps * dt),
            front_valid: true,
            steer_angle_rad: 0.0,
            zero_is_floor: true,
            yaw_rate_radps,
            dt_s: dt,
        };
        *st = ekf.step(st, &input).unwrap();
        car_mps * dt
    };
    for _ in 0..96 {
        truth += step(&mut st, v, v);
    }
    for _ in 0..45 {
        let next = v - 8.0 * dt;
        truth += step(&mut st, 0.0, 0.5 * (v + next));
        v = next;
    }
    for _ in 0..50 {
        truth += step(&mut st, v, v);
    }
    st.pose().x_m - truth
}

#[test]
fn a_slide_on_four_locked_wheels_is_bridged_in_both_filters() {
    // The wheels alone lose the 6.7 m the car slid; the bridge's prior
    // (7.5 m/s²) is corrected to the speed the wheels roll again at.
    for yaw in [None, Some(0.0)] {
        let off = after_a_locked_slide(yaw);
        assert!(off.abs() < 0.3, "gyro {yaw:?}: {off:+.2} m");
    }
}

/// Straight at 8 m/s with wheel-speed sensors, then the rear axle spinning
/// for 0.8 s (the right wheel at three times the car's speed, the left at
/// twice), then rolling again: the pose at the end, against the truth.
fn after_a_spin(yaw_rate_radps: Option<f64>) -> Pose {
    let ekf = Ekf::new(EkfConfig::new(car())).unwrap();
    let mut st = State::origin();
    let dt = 0.012;
    let v = 8.0;
    let mut step = |rear_left: f64, rear_right: f64| {
        let input = OdometryInput {
            wheel_m: WheelSet {
                rear_left: rear_left * dt,
                rear_right: rear_right * dt,
                front_left: v * dt,
                front_right: v * dt,
            },
            front_valid: true,
            steer_angle_rad: 0.0,
            zero_is_floor: true,
            yaw_rate_radps,
            dt_s: dt,
        };
        st = ekf.step(&st, &input).unwrap();
    };
    for _ in 0..100 {
        step(v, v);
    }
    for k in 1..=67 {
        // The spin builds up over 0.1 s, as a driven wheel's does.
        let share = (f64::from(k) / 8.0).min(1.0);
        step(v * (1.0 + share), v * (1.0 + 2.0 * share));
    }
    for _ in 0..100 {
        step(v, v);
    }
    st.pose()
}

#[test]
fn a_spinning_driven_axle_is_not_taken_for_a_locked_front() {
    // The rolling front reads below half the spinning rear: by the
    // distances alone that was a locked front, and the rear's turn
    // (1.3 rad a second here) was kept.
    let truth_m = 267.0 * 0.012 * 8.0;
    for yaw in [None, Some(0.0)] {
        let pose = after_a_spin(yaw);
        assert!(
            (pose.x_m - truth_m).abs() < 0.3 && pose.y_m.abs() < 0.3,
            "gyro {yaw:?}: {pose:?}, truth x {truth_m:.2} m"
        );
        assert!(pose.heading_rad.abs() < 0.02, "gyro {yaw:?}: {pose:?}");
    }
}

#[test]
fn a_brake_onset_on_the_front_does_not_outweigh_a_rear_locking() {
    // The multi-body Escort (seed 104): the front dips 2 m/s in one sample
    // as the brakes bite and recovers; then the rear falls from 14 m/s to 0
    // in a quarter second. Both ran from the car's envelope; the rear by far
    // more, and a locked axle is never taken for a spinning one.
    let mut speeds = vec![(14.5, 14.6); 10];
    speeds.push((14.0, 12.7));
    speeds.push((13.7, 12.4));
    speeds.extend((1..=20).map(|k| {
        (
            (13.5 - 0.7 * f64::from(k)).max(0.0),
            12.4 - 0.12 * f64::from(k),
        )
    }));
    let watch = watched(speeds);
    assert_eq!(watch.window_suspect(), Some(Axle::Rear));
    assert!(watch.slipped_in_window(Axle::Front));
    assert_eq!(watch.spinning(), None);
}

proptest! {
    /// Driving a car can do is never a slip: speeds changing at up to
    /// 10 m/s² (the tracker allows 12), the front axle up to 3 % off the
    /// rear (a turn's longer arc, tyre sizes), 0.05 m/s of noise on each,
    /// frames every 10–40 ms. No axle is ever suspect, and the slide
    /// tracker's shares keep learning.
    #[test]
    fn driving_a_car_can_do_never_makes_an_axle_suspect(
        accels in prop::collection::vec(-10.0f64..10.0, 1..40),
        front_share in 0.97f64..1.03,
        noise in prop::collection::vec(-0.05f64..0.05, 64),
        dt in 0.01f64..0.04,
    ) {
        let mut watch = AxleWatch::default();
        let mut v: f64 = 12.0;
        let mut k = 0;
        for a in accels {
            // Each acceleration held for half a second.
            for _ in 0..(0.5 / dt) as usize {
                v = (v + a * dt).clamp(0.0, 40.0);
                let rear = v + noise[k % 64];
                let front = v * front_share + noise[(k + 7) % 64];
                k += 1;
                watch.step([rear.max(0.0), front.max(0.0)], dt, 12.0);
                prop_assert_eq!(watch.window_suspect(), None, "v {} a {}", v, a);
                prop_assert!(watch.calm());
            }
        }
    }
}

/// A road car stands 5 s, then drives a 20 s arc at 8 m/s turning at
/// `rate_dps`, its gyro rounding to Toyota's 0.244°/s steps without noise
/// to dither them; the wheels are exact. The end heading's error and σ, rad.
fn after_an_undithered_turn(rate_dps: f64) -> (f64, f64) {
    let mut cfg = road_car();
    cfg.yaw_quantum_radps = 0.244f64.to_radians();
    let p = cfg.params;
    let ekf = Ekf::new(cfg).unwrap();
    let q = 0.244;
    let read = |true_dps: f64| Some(((true_dps / q).round() * q).to_radians());
    let dt = 0.01;
    let input = |ds: f64, phi: f64, true_dps: f64| OdometryInput {
        zero_is_floor: true,
        yaw_rate_radps: read(true_dps),
        dt_s: dt,
        ..arc_input(&p, ds, phi)
    };
    let mut st = State::origin();
    for _ in 0..500 {
        st = ekf.step(&st, &input(0.0, 0.0, 0.0)).unwrap();
    }
    let v = 8.0;
    let phi = (rate_dps.to_radians() / v * p.wheelbase_m()).atan();
    for _ in 0..2000 {
        st = ekf.step(&st, &input(v * dt, phi, rate_dps)).unwrap();
    }
    let truth = rate_dps.to_radians() * 20.0;
    (
        st.pose().heading_rad - truth,
        st.covariance()[(2, 2)].sqrt(),
    )
}

#[test]
fn an_undithered_gyro_s_rounding_in_a_turn_stays_inside_the_heading_sigma() {
    // Rates across one step: the rounding holds the reading up to 0.122°/s
    // off for the whole turn, 2.4° in 20 s. Counted as white noise only, the
    // heading's σ was 0.39° where the error was 1.41° (at 2.502°/s); as a
    // walk over a curve's steady part it is covered.
    for k in 0..=8 {
        let rate_dps = 10.0 * 0.244 + 0.244 * f64::from(k) / 8.0 + 0.001;
        let (err, sigma) = after_an_undithered_turn(rate_dps);
        assert!(
            err.abs() <= 3.0 * sigma,
            "{rate_dps:.3}°/s: error {:.2}°, σ {:.2}°",
            err.to_degrees(),
            sigma.to_degrees()
        );
    }
}
