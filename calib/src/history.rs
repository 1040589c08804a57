//! The history model of calibrated parameters: the values a calibration
//! produces, the bounds they must stay within, and the file of committed sets
//! (the set in use and the previous ones, for rollback) with its versions.
//!
//! Pure: the calibration session commits and rolls back on a [`ParamFile`]
//! value; storing it (TOML, atomically and durably) is `canodom-params`'s job.

use serde::{Deserialize, Serialize};

/// The largest yaw-rate bias a set may carry, rad/s (5°/s).
pub const YAW_BIAS_MAX_RADPS: f64 = 5.0 * std::f64::consts::PI / 180.0;

/// Default number of previous sets kept for rollback.
pub const DEFAULT_MAX_HISTORY: usize = 10;

const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// The physical parameters a calibration produces.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParamValues {
    /// Effective rear tread.
    pub rear_tread_m: f64,
    /// Effective rear-left wheel diameter.
    pub rear_left_diameter_m: f64,
    /// Effective rear-right wheel diameter.
    pub rear_right_diameter_m: f64,
    /// Road-wheel angle = gain × measured angle + offset.
    pub steering_gain: f64,
    /// Road-wheel angle offset.
    pub steering_offset_rad: f64,
    /// The yaw-rate sensor's bias (measured = scale · true + bias), rad/s:
    /// from a drive calibration with position fixes; absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub yaw_rate_bias_radps: Option<f64>,
    /// The yaw-rate sensor's scale, with the bias.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub yaw_rate_scale: Option<f64>,
    /// The standard deviation of `yaw_rate_bias_radps` as its calibration
    /// found it, rad/s: the filter starts from it as the prior of the bias
    /// it learns next (absent: a fixed tenth of a degree per second).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub yaw_rate_bias_sigma_radps: Option<f64>,
}

impl ParamValues {
    /// A set with this tread and both rear diameters equal, a steering map
    /// of gain 1 and no offset, and no yaw-rate correction.
    pub fn plain(rear_tread_m: f64, rear_diameter_m: f64) -> Self {
        Self {
            rear_tread_m,
            rear_left_diameter_m: rear_diameter_m,
            rear_right_diameter_m: rear_diameter_m,
            steering_gain: 1.0,
            steering_offset_rad: 0.0,
            yaw_rate_bias_radps: None,
            yaw_rate_scale: None,
            yaw_rate_bias_sigma_radps: None,
        }
    }

    /// The set a vehicle's nominal parameters describe: their tread, rear
    /// diameters and steering map, no yaw-rate correction (what is in use
    /// before any calibration is committed).
    pub fn nominal(p: &canodom_fusion::VehicleParams) -> Self {
        let steer = p.steering();
        Self {
            rear_tread_m: p.rear_tread_m(),
            rear_left_diameter_m: p.wheel_diameter_m(canodom_fusion::Wheel::RearLeft),
            rear_right_diameter_m: p.wheel_diameter_m(canodom_fusion::Wheel::RearRight),
            steering_gain: steer.gain,
            steering_offset_rad: steer.offset_rad,
            yaw_rate_bias_radps: None,
            yaw_rate_scale: None,
            yaw_rate_bias_sigma_radps: None,
        }
    }

    /// Rear wheel diameter ratio, right over left.
    pub fn diameter_ratio(&self) -> f64 {
        self.rear_right_diameter_m / self.rear_left_diameter_m
    }

    /// The steering map of this set.
    pub fn steering_map(&self) -> canodom_fusion::SteeringMap {
        canodom_fusion::SteeringMap {
            gain: self.steering_gain,
            offset_rad: self.steering_offset_rad,
        }
    }

    fn fields(&self) -> [(&'static str, f64); 5] {
        [
            ("rear_tread_m", self.rear_tread_m),
            ("rear_left_diameter_m", self.rear_left_diameter_m),
            ("rear_right_diameter_m", self.rear_right_diameter_m),
            ("steering_gain", self.steering_gain),
            ("steering_offset_rad", self.steering_offset_rad),
        ]
    }

    /// The optional values that are present (a set written before they
    /// existed checks as it did).
    fn optional_fields(&self) -> impl Iterator<Item = (&'static str, f64)> {
        [
            ("yaw_rate_bias_radps", self.yaw_rate_bias_radps),
            ("yaw_rate_scale", self.yaw_rate_scale),
            ("yaw_rate_bias_sigma_radps", self.yaw_rate_bias_sigma_radps),
        ]
        .into_iter()
        .filter_map(|(name, v)| v.map(|v| (name, v)))
    }
}

/// A committed parameter set.
#[derive(Clone, Debug, PartialEq)]
pub struct ParamSet {
    /// Version number; sent on CAN as `PARAM_VERSION` (16 bits), never 0
    /// (0 means "nominal" on the wire).
    pub version: u16,
    /// When it was committed, seconds since the Unix epoch.
    pub created_unix_s: u64,
    /// How it was computed (e.g. `exact`), for reports.
    pub method: String,
    /// The values.
    pub values: ParamValues,
}

impl ParamSet {
    /// CRC-32/ISO-HDLC over the version, time, method and the values' bit
    /// patterns, little-endian, in declaration order.
    pub fn checksum(&self) -> u32 {
        let mut digest = CRC32.digest();
        digest.update(&self.version.to_le_bytes());
        digest.update(&self.created_unix_s.to_le_bytes());
        digest.update(&(self.method.len() as u64).to_le_bytes());
        digest.update(self.method.as_bytes());
        for (_, v) in self.values.fields() {
            digest.update(&v.to_bits().to_le_bytes());
        }
        for (name, v) in self.values.optional_fields() {
            digest.update(name.as_bytes());
            digest.update(&v.to_bits().to_le_bytes());
        }
        digest.finalize()
    }
}

/// Inclusive bounds for each value; a set outside them is not applied.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParamBounds {
    /// Rear tread range, m.
    pub rear_tread_m: (f64, f64),
    /// Range of each rear diameter, m.
    pub diameter_m: (f64, f64),
    /// Steering gain range.
    pub steering_gain: (f64, f64),
    /// Steering offset range, rad.
    pub steering_offset_rad: (f64, f64),
    /// Yaw-rate bias range, rad/s.
    pub yaw_rate_bias_radps: (f64, f64),
    /// Yaw-rate scale range.
    pub yaw_rate_scale: (f64, f64),
}

impl ParamBounds {
    /// Bounds of ± `rel` (e.g. 0.3) around the nominal tread, diameter and
    /// gain, and ± `max_offset_rad` for the steering offset (nominal 0).
    pub fn around(
        nominal_tread_m: f64,
        nominal_diameter_m: f64,
        rel: f64,
        max_offset_rad: f64,
    ) -> Self {
        let span = |x: f64| (x * (1.0 - rel), x * (1.0 + rel));
        Self {
            rear_tread_m: span(nominal_tread_m),
            diameter_m: span(nominal_diameter_m),
            steering_gain: span(1.0),
            steering_offset_rad: (-max_offset_rad, max_offset_rad),
            // A production gyro: biases of tenths of a degree per second,
            // a few per cent of scale; beyond these it is broken.
            yaw_rate_bias_radps: (-YAW_BIAS_MAX_RADPS, YAW_BIAS_MAX_RADPS),
            yaw_rate_scale: (0.8, 1.2),
        }
    }

    /// Checks every value is finite and within its bounds.
    ///
    /// # Errors
    /// [`BoundsError`] naming the first offending field.
    pub fn check(&self, values: &ParamValues) -> Result<(), BoundsError> {
        let ranges = [
            self.rear_tread_m,
            self.diameter_m,
            self.diameter_m,
            self.steering_gain,
            self.steering_offset_rad,
        ];
        let optional = values.optional_fields().map(|(field, value)| {
            let range = match field {
                "yaw_rate_scale" => self.yaw_rate_scale,
                // A σ: positive, and no larger than the bias may be.
                "yaw_rate_bias_sigma_radps" => (f64::MIN_POSITIVE, self.yaw_rate_bias_radps.1),
                _ => self.yaw_rate_bias_radps,
            };
            ((field, value), range)
        });
        for ((field, value), (min, max)) in values.fields().into_iter().zip(ranges).chain(optional)
        {
            // `!(a <= b)` also catches NaN.
            if !(value >= min && value <= max) {
                return Err(BoundsError {
                    field,
                    value,
                    min,
                    max,
                });
            }
        }
        Ok(())
    }
}

/// A value outside its bounds (or not finite).
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error("{field} = {value} is outside [{min}, {max}]")]
pub struct BoundsError {
    /// Field name as in the file.
    pub field: &'static str,
    /// Offending value.
    pub value: f64,
    /// Lower bound.
    pub min: f64,
    /// Upper bound.
    pub max: f64,
}

/// The whole file: the set in use and previous sets, oldest first.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct ParamFile {
    /// Highest version ever issued, so versions stay unique after rollback.
    pub last_version: u16,
    /// The set in use; `None` means nominal parameters.
    pub current: Option<ParamSet>,
    /// Previous sets, oldest first.
    pub history: Vec<ParamSet>,
}

impl ParamFile {
    /// Makes `values` the current set with the next version, moving the
    /// previous current set into the history (keeping at most `max_history`).
    pub fn commit(
        &mut self,
        values: ParamValues,
        method: &str,
        created_unix_s: u64,
        max_history: usize,
    ) -> &ParamSet {
        // Versions are 1..=u16::MAX on the wire (0 = nominal), so wrap to 1.
        self.last_version = self.last_version.checked_add(1).unwrap_or(1);
        let set = ParamSet {
            version: self.last_version,
            created_unix_s,
            method: method.to_owned(),
            values,
        };
        if let Some(previous) = self.current.take() {
            self.history.push(previous);
        }
        let excess = self.history.len().saturating_sub(max_history);
        self.history.drain(..excess);
        self.current.insert(set)
    }

    /// Restores the values of the most recent previous set under the next
    /// version (issue #33: a version is never re-used for a set written
    /// back again, so an acknowledgement of its first write-back can never
    /// count for this one); `None`, and no change, when there is none.
    pub fn rollback(&mut self) -> Option<&ParamSet> {
        let mut previous = self.history.pop()?;
        self.last_version = self.last_version.checked_add(1).unwrap_or(1);
        previous.version = self.last_version;
        Some(self.current.insert(previous))
    }
}
