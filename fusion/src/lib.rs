//! Pure maths for the odometry of a car-like vehicle (front Ackermann steering):
//! wheel inputs, rear- and front-axle odometry, EKF fusion of the two, and a
//! ground-truth vehicle simulator that judges every other crate's tests.
//!
//! No I/O, no async, no clock: time arrives as timestamps in arguments.
//! Conventions follow `docs/calibration-math.md` §2 (in the repository): the pose is the
//! rear-axle centre `(x, y, θ)`, θ counter-clockwise, left turns positive,
//! the right wheel on the vehicle's −y side.
//!
//! # Layout
//! - [`params`]: [`VehicleParams`] and the [`SteeringMap`], validated once.
//! - [`wheel`]: wheel inputs as real vehicles send them (wrapping tick
//!   counters, wheel speeds) turned into checked distance increments.
//! - [`odometry`]: the rear-axle step (paper eqs. 1–5) and front-axle
//!   odometry converted to the rear axle (eqs. 21–26).
//! - [`ekf`]: the extended Kalman filter fusing rear and front odometry.
//! - [`sim`]: the deterministic ground-truth vehicle simulator.
//!
//! `examples/demo.rs` puts them together: a simulated car drives, and
//! rear-only and fused odometry are compared with the ground truth
//! (`cargo run --release -p canodom-fusion --example demo`).
//! `tests/experiments.rs` reproduces §11 and §12 of the maths document.

pub mod ekf;
pub mod error;
pub mod odometry;
pub mod params;
mod rotation;
pub mod sim;
pub mod wheel;

pub use error::{Error, Result};
pub use odometry::{Increment, Pose};
pub use params::{SteeringMap, VehicleParams};

/// One of the four wheels of a car-like vehicle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Wheel {
    /// Rear left (vehicle +y side).
    RearLeft,
    /// Rear right (vehicle −y side).
    RearRight,
    /// Front left.
    FrontLeft,
    /// Front right.
    FrontRight,
}

impl Wheel {
    /// All four wheels, rear first, left before right.
    pub const ALL: [Wheel; 4] = [
        Wheel::RearLeft,
        Wheel::RearRight,
        Wheel::FrontLeft,
        Wheel::FrontRight,
    ];

    /// True for the two rear wheels.
    pub fn is_rear(self) -> bool {
        matches!(self, Wheel::RearLeft | Wheel::RearRight)
    }

    /// The configuration name of this wheel's diameter, with its unit.
    pub fn diameter_name(self) -> &'static str {
        match self {
            Wheel::RearLeft => "rear_left_diameter_m",
            Wheel::RearRight => "rear_right_diameter_m",
            Wheel::FrontLeft => "front_left_diameter_m",
            Wheel::FrontRight => "front_right_diameter_m",
        }
    }
}

/// One value per wheel, indexable by [`Wheel`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WheelSet<T> {
    /// Rear left.
    pub rear_left: T,
    /// Rear right.
    pub rear_right: T,
    /// Front left.
    pub front_left: T,
    /// Front right.
    pub front_right: T,
}

impl<T: Copy> WheelSet<T> {
    /// The same value for all four wheels.
    pub fn splat(value: T) -> Self {
        Self {
            rear_left: value,
            rear_right: value,
            front_left: value,
            front_right: value,
        }
    }

    /// Applies `f` to each wheel's value.
    pub fn map<U>(self, mut f: impl FnMut(Wheel, T) -> U) -> WheelSet<U> {
        WheelSet {
            rear_left: f(Wheel::RearLeft, self.rear_left),
            rear_right: f(Wheel::RearRight, self.rear_right),
            front_left: f(Wheel::FrontLeft, self.front_left),
            front_right: f(Wheel::FrontRight, self.front_right),
        }
    }
}

impl<T> std::ops::Index<Wheel> for WheelSet<T> {
    type Output = T;
    fn index(&self, wheel: Wheel) -> &T {
        match wheel {
            Wheel::RearLeft => &self.rear_left,
            Wheel::RearRight => &self.rear_right,
            Wheel::FrontLeft => &self.front_left,
            Wheel::FrontRight => &self.front_right,
        }
    }
}

impl<T> std::ops::IndexMut<Wheel> for WheelSet<T> {
    fn index_mut(&mut self, wheel: Wheel) -> &mut T {
        match wheel {
            Wheel::RearLeft => &mut self.rear_left,
            Wheel::RearRight => &mut self.rear_right,
            Wheel::FrontLeft => &mut self.front_left,
            Wheel::FrontRight => &mut self.front_right,
        }
    }
}

/// Wraps an angle to (−π, π].
pub fn wrap_angle(angle_rad: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    // Fast paths: the filter wraps sums of two wrapped angles on every step.
    if angle_rad > -PI && angle_rad <= PI {
        return angle_rad;
    }
    if angle_rad > PI && angle_rad <= 3.0 * PI {
        return angle_rad - TAU;
    }
    if angle_rad > -3.0 * PI && angle_rad <= -PI {
        return angle_rad + TAU;
    }
    let wrapped = (angle_rad + PI).rem_euclid(TAU) - PI;
    if wrapped <= -PI {
        wrapped + TAU
    } else {
        wrapped
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn wrap_angle_lands_in_range_and_keeps_direction(a in -1e4f64..1e4) {
            let w = wrap_angle(a);
            prop_assert!(w > -std::f64::consts::PI && w <= std::f64::consts::PI);
            prop_assert!((w.sin() - a.sin()).abs() < 1e-9 && (w.cos() - a.cos()).abs() < 1e-9);
        }
    }

    #[test]
    fn wheel_set_indexes_each_wheel() {
        let mut s = WheelSet::splat(0);
        for (i, w) in Wheel::ALL.iter().enumerate() {
            s[*w] = i;
        }
        assert_eq!(
            (s.rear_left, s.rear_right, s.front_left, s.front_right),
            (0, 1, 2, 3)
        );
        assert!(Wheel::RearRight.is_rear() && !Wheel::FrontLeft.is_rear());
    }
}
