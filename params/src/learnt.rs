//! What the odometry filter learnt online, as a state file keeps it
//! (`canodom run --state-file`): each value with the bounds a restart takes
//! it back within, so a damaged file or a value learnt from nonsense starts
//! the filter from its priors instead.

use serde::{Deserialize, Serialize};

/// What the filter learnt online, as saved (see [`canodom_fusion::ekf::Learnt`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SavedLearnt {
    /// The steering sensor's offset, road-wheel radians.
    pub steer_offset_rad: f64,
    /// Its standard deviation (0: not learnt yet).
    pub steer_offset_sigma_rad: f64,
    /// The front wheels' distance factor.
    pub front_scale: f64,
    /// Its standard deviation (0: not learnt yet).
    pub front_scale_sigma: f64,
    /// The yaw-rate sensor's bias, rad/s (with a yaw-rate sensor only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub yaw_bias_radps: Option<f64>,
    /// Its standard deviation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub yaw_bias_sigma_radps: Option<f64>,
    /// The rear diameter ratio's relative error.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rear_ratio_err: Option<f64>,
    /// Its standard deviation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rear_ratio_sigma: Option<f64>,
    /// The effective rear tread's relative error (learnt against the
    /// yaw-rate sensor in turns).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tread_err: Option<f64>,
    /// Its standard deviation.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tread_sigma: Option<f64>,
    /// The wheel the scale learner takes to read off, once it has used a
    /// window (absent in files of older versions).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wheel_fault: Option<SavedWheelFault>,
}

/// The wheel-scale learner's leading explanation, as saved (see
/// [`canodom_fusion::ekf::LearntWheelFault`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SavedWheelFault {
    /// `none`, `rear_left`, `rear_right`, `front_left`, `front_right` or `front_axle`.
    pub wheel: SavedFault,
    /// That wheel's (or axle's) scale: it reads `scale` times what it rolled.
    pub scale: f64,
    /// Its standard deviation.
    pub scale_sigma: f64,
    /// How far this explanation led the next, nats.
    pub lead_log_odds: f64,
    /// Windows the learner had used.
    pub windows: u32,
}

/// A [`canodom_fusion::ekf::Fault`] in the file, by its name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SavedFault(pub canodom_fusion::ekf::Fault);

impl Serialize for SavedFault {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.0.as_str())
    }
}

impl<'de> Deserialize<'de> for SavedFault {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        use canodom_fusion::ekf::Fault;
        let name = String::deserialize(d)?;
        Fault::from_name(&name).map(Self).ok_or_else(|| {
            let known: Vec<&str> = Fault::ALL.iter().map(|f| f.as_str()).collect();
            serde::de::Error::custom(format!(
                "unknown wheel {name:?} (one of {})",
                known.join(", ")
            ))
        })
    }
}

/// The largest learnt values a restart takes back: beyond them a saved
/// value is damaged or learnt from nonsense (openpilot has shipped both
/// bugs), and the filter starts from its priors instead.
pub mod learnt_bounds {
    /// Steering offset, road-wheel radians (5°).
    pub const STEER_OFFSET_RAD: f64 = 5.0 * std::f64::consts::PI / 180.0;
    /// Front distance factor's distance from 1 (5 %).
    pub const FRONT_SCALE: f64 = 0.05;
    /// Yaw-rate bias, rad/s (5°/s).
    pub const YAW_BIAS_RADPS: f64 = crate::persist::YAW_BIAS_MAX_RADPS;
    /// Rear ratio error (1 %).
    pub const REAR_RATIO_ERR: f64 = 0.01;
    /// Effective rear tread error (20 %).
    pub const TREAD_ERR: f64 = 0.2;
    /// A wheel's scale's distance from 1 (5 %).
    pub const WHEEL_SCALE: f64 = 0.05;
}

/// A saved learnt value a restart refuses.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error("saved {name} = {value} is outside ±{bound} (or not finite)")]
pub struct LearntOutOfBounds {
    /// The value's name as in the file.
    pub name: &'static str,
    /// The saved value.
    pub value: f64,
    /// The bound it broke.
    pub bound: f64,
}

impl SavedLearnt {
    /// What `state` learnt.
    pub fn from_state(state: &canodom_fusion::ekf::State) -> Self {
        let l = state.learnt();
        Self {
            steer_offset_rad: l.steer_offset_rad,
            steer_offset_sigma_rad: l.steer_offset_sigma_rad,
            front_scale: l.front_scale,
            front_scale_sigma: l.front_scale_sigma,
            yaw_bias_radps: l.yaw_bias.map(|y| y.yaw_bias_radps),
            yaw_bias_sigma_radps: l.yaw_bias.map(|y| y.yaw_bias_sigma_radps),
            rear_ratio_err: l.yaw_bias.map(|y| y.rear_ratio_err),
            rear_ratio_sigma: l.yaw_bias.map(|y| y.rear_ratio_sigma),
            tread_err: l.yaw_bias.map(|y| y.tread_err),
            tread_sigma: l.yaw_bias.map(|y| y.tread_sigma),
            wheel_fault: l.wheel_fault.map(|f| SavedWheelFault {
                wheel: SavedFault(f.fault),
                scale: f.scale,
                scale_sigma: f.sigma,
                lead_log_odds: f.lead_log_odds,
                windows: f.windows,
            }),
        }
    }

    /// The values to restore, each checked against [`learnt_bounds`] (and
    /// every standard deviation finite and not negative).
    ///
    /// # Errors
    /// [`LearntOutOfBounds`] naming the first value refused.
    pub fn checked(&self) -> Result<canodom_fusion::ekf::Learnt, LearntOutOfBounds> {
        use learnt_bounds as b;
        let within = |name: &'static str, value: f64, center: f64, bound: f64| {
            if (value - center).abs() <= bound {
                Ok(value)
            } else {
                Err(LearntOutOfBounds { name, value, bound })
            }
        };
        let sigma = |name: &'static str, value: f64| {
            if value.is_finite() && value >= 0.0 {
                Ok(value)
            } else {
                Err(LearntOutOfBounds {
                    name,
                    value,
                    bound: f64::INFINITY,
                })
            }
        };
        let yaw = match (
            self.yaw_bias_radps,
            self.yaw_bias_sigma_radps,
            self.rear_ratio_err,
            self.rear_ratio_sigma,
        ) {
            (Some(bias), Some(bias_sigma), Some(err), Some(err_sigma)) => {
                Some(canodom_fusion::ekf::LearntPair {
                    yaw_bias_radps: within("yaw_bias_radps", bias, 0.0, b::YAW_BIAS_RADPS)?,
                    yaw_bias_sigma_radps: sigma("yaw_bias_sigma_radps", bias_sigma)?,
                    rear_ratio_err: within("rear_ratio_err", err, 0.0, b::REAR_RATIO_ERR)?,
                    rear_ratio_sigma: sigma("rear_ratio_sigma", err_sigma)?,
                    // Files written before the tread was learnt: not learnt.
                    tread_err: within(
                        "tread_err",
                        self.tread_err.unwrap_or(0.0),
                        0.0,
                        b::TREAD_ERR,
                    )?,
                    tread_sigma: sigma("tread_sigma", self.tread_sigma.unwrap_or(0.0))?,
                })
            }
            _ => None,
        };
        let wheel_fault = match self.wheel_fault {
            None => None,
            Some(f) => Some(canodom_fusion::ekf::LearntWheelFault {
                fault: f.wheel.0,
                scale: within("wheel_fault.scale", f.scale, 1.0, b::WHEEL_SCALE)?,
                sigma: sigma("wheel_fault.scale_sigma", f.scale_sigma)?,
                lead_log_odds: sigma("wheel_fault.lead_log_odds", f.lead_log_odds)?,
                windows: f.windows,
            }),
        };
        Ok(canodom_fusion::ekf::Learnt {
            steer_offset_rad: within(
                "steer_offset_rad",
                self.steer_offset_rad,
                0.0,
                b::STEER_OFFSET_RAD,
            )?,
            steer_offset_sigma_rad: sigma("steer_offset_sigma_rad", self.steer_offset_sigma_rad)?,
            front_scale: within("front_scale", self.front_scale, 1.0, b::FRONT_SCALE)?,
            front_scale_sigma: sigma("front_scale_sigma", self.front_scale_sigma)?,
            yaw_bias: yaw,
            wheel_fault,
        })
    }
}
