//! Vehicle geometry and the steering map, validated once at construction.

use crate::error::{Error, Result};
use crate::{Wheel, WheelSet};

/// The steering map from the steering signal `u` the vehicle reports (or is
/// commanded with) to the road-wheel angle of the equivalent centre wheel:
/// `φ = gain · u + offset_rad` (left positive, `docs/calibration-math.md` §1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SteeringMap {
    /// Radians of road-wheel angle per unit of the steering signal.
    pub gain: f64,
    /// Road-wheel angle at a zero steering signal, in radians.
    pub offset_rad: f64,
}

impl SteeringMap {
    /// The identity map: the steering signal already is the road-wheel angle in radians.
    pub const IDENTITY: Self = Self {
        gain: 1.0,
        offset_rad: 0.0,
    };

    /// The road-wheel angle for a steering signal.
    pub fn angle_rad(&self, signal: f64) -> f64 {
        self.gain.mul_add(signal, self.offset_rad)
    }

    /// The steering signal that gives a road-wheel angle (the inverse map).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] when the gain is zero, where no inverse exists.
    pub fn signal_for(&self, steer_angle_rad: f64) -> Result<f64> {
        if self.gain == 0.0 || !self.gain.is_finite() {
            return Err(Error::InvalidParameter {
                name: "steering_gain",
                value: self.gain,
            });
        }
        Ok((steer_angle_rad - self.offset_rad) / self.gain)
    }
}

/// The kinematic parameters of a car-like vehicle with Ackermann front steering.
///
/// Fields are private so that every value in use has passed [`VehicleParams::new`]:
/// all lengths finite and strictly positive, at least one encoder tick per
/// revolution, a finite steering map with a non-zero gain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleParams {
    wheelbase_m: f64,
    rear_tread_m: f64,
    front_tread_m: f64,
    wheel_diameters_m: WheelSet<f64>,
    encoder_ticks_per_rev: u32,
    steering: SteeringMap,
}

fn positive(name: &'static str, value: f64) -> Result<f64> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(Error::InvalidParameter { name, value })
    }
}

impl VehicleParams {
    /// Builds and validates a parameter set.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the first parameter that is not finite
    /// and strictly positive (or a zero tick count, or a zero/non-finite steering gain).
    pub fn new(
        wheelbase_m: f64,
        rear_tread_m: f64,
        front_tread_m: f64,
        wheel_diameters_m: WheelSet<f64>,
        encoder_ticks_per_rev: u32,
        steering: SteeringMap,
    ) -> Result<Self> {
        positive("wheelbase_m", wheelbase_m)?;
        positive("rear_tread_m", rear_tread_m)?;
        positive("front_tread_m", front_tread_m)?;
        for wheel in Wheel::ALL {
            positive(wheel.diameter_name(), wheel_diameters_m[wheel])?;
        }
        if encoder_ticks_per_rev == 0 {
            return Err(Error::InvalidParameter {
                name: "encoder_ticks_per_rev",
                value: 0.0,
            });
        }
        if !(steering.gain.is_finite() && steering.gain != 0.0) {
            return Err(Error::InvalidParameter {
                name: "steering_gain",
                value: steering.gain,
            });
        }
        if !steering.offset_rad.is_finite() {
            return Err(Error::InvalidParameter {
                name: "steering_offset_rad",
                value: steering.offset_rad,
            });
        }
        Ok(Self {
            wheelbase_m,
            rear_tread_m,
            front_tread_m,
            wheel_diameters_m,
            encoder_ticks_per_rev,
            steering,
        })
    }

    /// A vehicle with equal treads, four equal wheels and the identity steering map.
    ///
    /// # Errors
    /// As [`VehicleParams::new`].
    pub fn nominal(
        wheelbase_m: f64,
        tread_m: f64,
        wheel_diameter_m: f64,
        encoder_ticks_per_rev: u32,
    ) -> Result<Self> {
        Self::new(
            wheelbase_m,
            tread_m,
            tread_m,
            WheelSet::splat(wheel_diameter_m),
            encoder_ticks_per_rev,
            SteeringMap::IDENTITY,
        )
    }

    /// The same vehicle with new rear-axle parameters (a calibration result).
    ///
    /// # Errors
    /// As [`VehicleParams::new`].
    pub fn with_rear(
        &self,
        rear_tread_m: f64,
        rear_left_diameter_m: f64,
        rear_right_diameter_m: f64,
    ) -> Result<Self> {
        let mut diameters = self.wheel_diameters_m;
        diameters.rear_left = rear_left_diameter_m;
        diameters.rear_right = rear_right_diameter_m;
        Self::new(
            self.wheelbase_m,
            rear_tread_m,
            self.front_tread_m,
            diameters,
            self.encoder_ticks_per_rev,
            self.steering,
        )
    }

    /// The same vehicle with another steering map.
    ///
    /// # Errors
    /// As [`VehicleParams::new`].
    pub fn with_steering(&self, steering: SteeringMap) -> Result<Self> {
        Self::new(
            self.wheelbase_m,
            self.rear_tread_m,
            self.front_tread_m,
            self.wheel_diameters_m,
            self.encoder_ticks_per_rev,
            steering,
        )
    }

    /// The same vehicle with other wheel diameters.
    ///
    /// # Errors
    /// As [`VehicleParams::new`].
    pub fn with_diameters(&self, wheel_diameters_m: WheelSet<f64>) -> Result<Self> {
        Self::new(
            self.wheelbase_m,
            self.rear_tread_m,
            self.front_tread_m,
            wheel_diameters_m,
            self.encoder_ticks_per_rev,
            self.steering,
        )
    }

    /// The same vehicle with other treads.
    ///
    /// # Errors
    /// As [`VehicleParams::new`].
    pub fn with_treads(&self, rear_tread_m: f64, front_tread_m: f64) -> Result<Self> {
        Self::new(
            self.wheelbase_m,
            rear_tread_m,
            front_tread_m,
            self.wheel_diameters_m,
            self.encoder_ticks_per_rev,
            self.steering,
        )
    }

    /// Wheelbase L: rear axle to front axle.
    pub fn wheelbase_m(&self) -> f64 {
        self.wheelbase_m
    }
    /// Rear tread b: distance between the rear wheels' contact points.
    pub fn rear_tread_m(&self) -> f64 {
        self.rear_tread_m
    }
    /// Front tread b_f.
    pub fn front_tread_m(&self) -> f64 {
        self.front_tread_m
    }
    /// The four wheel diameters.
    pub fn wheel_diameters_m(&self) -> WheelSet<f64> {
        self.wheel_diameters_m
    }
    /// One wheel's diameter.
    pub fn wheel_diameter_m(&self, wheel: Wheel) -> f64 {
        self.wheel_diameters_m[wheel]
    }
    /// Encoder ticks per wheel revolution (Re).
    pub fn encoder_ticks_per_rev(&self) -> u32 {
        self.encoder_ticks_per_rev
    }
    /// The steering map.
    pub fn steering(&self) -> SteeringMap {
        self.steering
    }
    /// The rear diameter ratio E = D_R / D_L.
    pub fn rear_diameter_ratio(&self) -> f64 {
        self.wheel_diameters_m.rear_right / self.wheel_diameters_m.rear_left
    }
    /// The mean rear diameter D̄ = (D_R + D_L) / 2.
    pub fn rear_mean_diameter_m(&self) -> f64 {
        0.5 * (self.wheel_diameters_m.rear_right + self.wheel_diameters_m.rear_left)
    }
    /// Distance travelled by a wheel for a tick increment: d = π D N / Re.
    pub fn tick_distance_m(&self, wheel: Wheel, ticks: f64) -> f64 {
        std::f64::consts::PI * self.wheel_diameters_m[wheel] * ticks
            / f64::from(self.encoder_ticks_per_rev)
    }
}

/// Rear diameters `(left, right)` with a given ratio E = D_R/D_L and mean D̄,
/// as `docs/calibration-math.md` §7 keeps the mean: D_R = 2D̄E/(1+E), D_L = 2D̄/(1+E).
pub fn rear_diameters_for_ratio(mean_diameter_m: f64, ratio: f64) -> (f64, f64) {
    let left = 2.0 * mean_diameter_m / (1.0 + ratio);
    (left, left * ratio)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rc_car() -> VehicleParams {
        VehicleParams::nominal(0.25, 0.30, 0.09, 1000).unwrap()
    }

    #[test]
    fn rejects_non_finite_zero_and_negative_sizes_by_name() {
        for bad in [0.0, -0.1, f64::NAN, f64::INFINITY] {
            let err = VehicleParams::nominal(bad, 0.3, 0.09, 1000).unwrap_err();
            assert!(err.to_string().contains("wheelbase_m"), "{err}");
            let err = VehicleParams::nominal(0.25, bad, 0.09, 1000).unwrap_err();
            assert!(err.to_string().contains("rear_tread_m"), "{err}");
            let err = VehicleParams::nominal(0.25, 0.3, bad, 1000).unwrap_err();
            assert!(err.to_string().contains("rear_left_diameter_m"), "{err}");
        }
        let err = VehicleParams::nominal(0.25, 0.3, 0.09, 0).unwrap_err();
        assert!(err.to_string().contains("encoder_ticks_per_rev"));
        let zero_gain = SteeringMap {
            gain: 0.0,
            offset_rad: 0.0,
        };
        let err = rc_car().with_steering(zero_gain).unwrap_err();
        assert!(err.to_string().contains("steering_gain"));
    }

    #[test]
    fn tick_distance_is_pi_d_n_over_re() {
        let p = rc_car();
        let d = p.tick_distance_m(Wheel::RearLeft, 1000.0);
        assert!((d - std::f64::consts::PI * 0.09).abs() < 1e-15);
    }

    #[test]
    fn ratio_split_keeps_the_mean() {
        let (l, r) = rear_diameters_for_ratio(0.09, 1.035);
        assert!((f64::midpoint(l, r) - 0.09).abs() < 1e-15);
        assert!((r / l - 1.035).abs() < 1e-14);
    }

    #[test]
    fn steering_map_inverts() {
        let m = SteeringMap {
            gain: 0.93,
            offset_rad: 0.014,
        };
        let u = m.signal_for(0.2).unwrap();
        assert!((m.angle_rad(u) - 0.2).abs() < 1e-15);
    }
}
