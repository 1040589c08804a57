//! The parameter set a filter runs with, as far as what it learns online
//! depends on it: its identity (which a state file records, so learnt values
//! are never restored onto another set) and what changing it does to the
//! learnt values (a commit resets those of the parameters it sets).
//!
//! Why reset: every learnt value is a correction *relative to* a parameter.
//! The rear ratio error is the part of the diameter ratio the calibration
//! missed; a new ratio makes it wrong by the whole change. Kept, it would
//! correct a second time what the new set already corrected, and the filter
//! would take it with the small σ it had earned on the old set. Reset to its
//! prior, the filter learns it again from the new set with an honest σ.

use canodom_fusion::VehicleParams;
use canodom_fusion::ekf::{EkfConfig, Learnt, LearntPair};

const CRC32: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// The parameters in use: the vehicle geometry (nominal or with a calibrated
/// set's rear wheels, tread and steering map) and the set's yaw-rate
/// calibration, if it has one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParamsInUse {
    /// The vehicle parameters the filter and the decoders use.
    pub params: VehicleParams,
    /// The calibrated yaw-rate bias, rad/s (`None`: not calibrated).
    pub yaw_rate_bias_radps: Option<f64>,
    /// The calibrated yaw-rate scale (`None`: not calibrated).
    pub yaw_rate_scale: Option<f64>,
}

impl ParamsInUse {
    /// CRC-32/ISO-HDLC over the bit patterns of every value, little-endian,
    /// each optional value preceded by whether it is present: any change of
    /// any value changes it (the same checksum the parameter file uses).
    pub fn values_crc32(&self) -> u32 {
        let p = &self.params;
        let d = p.wheel_diameters_m();
        let s = p.steering();
        let mut digest = CRC32.digest();
        for v in [
            p.wheelbase_m(),
            p.rear_tread_m(),
            p.front_tread_m(),
            d.rear_left,
            d.rear_right,
            d.front_left,
            d.front_right,
            s.gain,
            s.offset_rad,
        ] {
            digest.update(&v.to_bits().to_le_bytes());
        }
        digest.update(&p.encoder_ticks_per_rev().to_le_bytes());
        for v in [self.yaw_rate_bias_radps, self.yaw_rate_scale] {
            match v {
                None => digest.update(&[0]),
                Some(v) => {
                    digest.update(&[1]);
                    digest.update(&v.to_bits().to_le_bytes());
                }
            }
        }
        digest.finalize()
    }
}

/// Which parameter set values were learnt on: the calibrated set's version
/// (`None` for the nominal parameters of the configuration) and a checksum
/// of the values in use, which also tells an edited configuration or a
/// rewritten set with a reused version.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ParamIdentity {
    /// The calibrated set's version; `None`: the nominal parameters.
    pub version: Option<u16>,
    /// [`ParamsInUse::values_crc32`].
    pub values_crc32: u32,
}

impl ParamIdentity {
    /// The identity of `in_use`, set `version` (`None` for nominal).
    pub fn of(version: Option<u16>, in_use: &ParamsInUse) -> Self {
        Self {
            version,
            values_crc32: in_use.values_crc32(),
        }
    }
}

impl std::fmt::Display for ParamIdentity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.version {
            Some(v) => write!(f, "calibrated set version {v}")?,
            None => write!(f, "nominal parameters")?,
        }
        write!(f, " (values crc32 {:08x})", self.values_crc32)
    }
}

/// Which groups of parameters a new set changes against the one in use,
/// each the reference of some learnt values.
// One flag per kind of parameter a set can change: they are independent.
#[allow(clippy::struct_excessive_bools)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ParamChanges {
    /// A rear wheel diameter: the rear ratio error, the front scale (the
    /// front wheels' distance relative to the rear's) and the wheels' scales.
    pub rear_diameters: bool,
    /// The rear tread: the effective tread error.
    pub rear_tread: bool,
    /// The steering map (gain or offset): the steering offset.
    pub steering: bool,
    /// The yaw-rate calibration (bias or scale): the yaw-rate bias.
    pub yaw_rate: bool,
}

impl ParamChanges {
    /// What differs from `before` to `after`, bit for bit (a value written
    /// back unchanged keeps what was learnt on it).
    pub fn between(before: &ParamsInUse, after: &ParamsInUse) -> Self {
        let same = |a: f64, b: f64| a.to_bits() == b.to_bits();
        let same_opt = |a: Option<f64>, b: Option<f64>| match (a, b) {
            (None, None) => true,
            (Some(a), Some(b)) => same(a, b),
            _ => false,
        };
        let (b, a) = (&before.params, &after.params);
        let (db, da) = (b.wheel_diameters_m(), a.wheel_diameters_m());
        let (sb, sa) = (b.steering(), a.steering());
        Self {
            rear_diameters: !(same(db.rear_left, da.rear_left)
                && same(db.rear_right, da.rear_right)),
            rear_tread: !same(b.rear_tread_m(), a.rear_tread_m()),
            steering: !(same(sb.gain, sa.gain) && same(sb.offset_rad, sa.offset_rad)),
            yaw_rate: !(same_opt(before.yaw_rate_bias_radps, after.yaw_rate_bias_radps)
                && same_opt(before.yaw_rate_scale, after.yaw_rate_scale)),
        }
    }

    /// True when anything changed.
    pub fn any(&self) -> bool {
        self.rear_diameters || self.rear_tread || self.steering || self.yaw_rate
    }
}

/// `learnt` with every value whose reference `changes` moved back at its
/// prior: the value of "nothing learnt" (0, or a scale of 1) with a σ of 0
/// where the filter reads that as "its configured prior" (steering offset,
/// front scale), and the configured prior σ of `priors` for the yaw-rate
/// bias, rear ratio error and effective tread error (a σ of 0 there would
/// keep the σ the filter had earned on the old set). Values of unchanged
/// parameters are kept as they are.
pub fn reset_learnt(learnt: &Learnt, changes: ParamChanges, priors: &EkfConfig) -> Learnt {
    let mut out = *learnt;
    if changes.steering {
        out.steer_offset_rad = 0.0;
        out.steer_offset_sigma_rad = 0.0;
    }
    if changes.rear_diameters {
        out.front_scale = 1.0;
        out.front_scale_sigma = 0.0;
        // The wheels' scales were learnt on the old diameters.
        out.wheel_fault = None;
    }
    out.yaw_bias = learnt.yaw_bias.map(|y| {
        let mut y: LearntPair = y;
        if changes.yaw_rate {
            y.yaw_bias_radps = 0.0;
            y.yaw_bias_sigma_radps = priors.yaw_bias_sigma_radps;
        }
        if changes.rear_diameters {
            y.rear_ratio_err = 0.0;
            y.rear_ratio_sigma = priors.rear_ratio_sigma;
        }
        if changes.rear_tread {
            y.tread_err = 0.0;
            y.tread_sigma = priors.tread_sigma;
        }
        y
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use canodom_fusion::SteeringMap;
    use canodom_fusion::ekf::{Fault, LearntWheelFault};

    fn nominal() -> ParamsInUse {
        ParamsInUse {
            params: VehicleParams::nominal(0.26, 0.30, 0.09, 100).unwrap(),
            yaw_rate_bias_radps: None,
            yaw_rate_scale: None,
        }
    }

    fn learnt() -> Learnt {
        Learnt {
            steer_offset_rad: 0.004,
            steer_offset_sigma_rad: 1e-4,
            front_scale: 1.003,
            front_scale_sigma: 2e-4,
            yaw_bias: Some(LearntPair {
                yaw_bias_radps: -0.007,
                yaw_bias_sigma_radps: 1e-4,
                rear_ratio_err: 5e-4,
                rear_ratio_sigma: 1e-4,
                tread_err: 0.02,
                tread_sigma: 1e-3,
            }),
            wheel_fault: Some(LearntWheelFault {
                fault: Fault::RearLeft,
                scale: 1.003,
                sigma: 1e-5,
                lead_log_odds: 25.0,
                windows: 400,
            }),
        }
    }

    /// Each parameter group, changed alone, with the values its change must
    /// reset.
    fn one_change_each() -> Vec<(&'static str, ParamsInUse)> {
        let n = nominal();
        let p = n.params;
        let mut d = p.wheel_diameters_m();
        d.rear_right *= 1.001;
        vec![
            (
                "rear_diameters",
                ParamsInUse {
                    params: p.with_diameters(d).unwrap(),
                    ..n
                },
            ),
            (
                "rear_tread",
                ParamsInUse {
                    params: p.with_treads(0.301, p.front_tread_m()).unwrap(),
                    ..n
                },
            ),
            (
                "steering",
                ParamsInUse {
                    params: p
                        .with_steering(SteeringMap {
                            gain: 1.0,
                            offset_rad: 0.001,
                        })
                        .unwrap(),
                    ..n
                },
            ),
            (
                "yaw_rate",
                ParamsInUse {
                    yaw_rate_bias_radps: Some(0.002),
                    ..n
                },
            ),
            (
                "yaw_rate",
                ParamsInUse {
                    yaw_rate_scale: Some(1.01),
                    ..n
                },
            ),
        ]
    }

    #[test]
    fn every_value_moves_the_identity_and_an_equal_set_keeps_it() {
        let n = nominal();
        let id = ParamIdentity::of(None, &n);
        assert_eq!(id, ParamIdentity::of(None, &nominal()));
        assert_ne!(id, ParamIdentity::of(Some(1), &n), "the version counts");
        let p = n.params;
        let mut others: Vec<ParamsInUse> = one_change_each().into_iter().map(|(_, s)| s).collect();
        let mut d = p.wheel_diameters_m();
        d.front_left *= 1.0001;
        others.push(ParamsInUse {
            params: p.with_diameters(d).unwrap(),
            ..n
        });
        others.push(ParamsInUse {
            params: p.with_treads(p.rear_tread_m(), 0.2999).unwrap(),
            ..n
        });
        others.push(ParamsInUse {
            params: VehicleParams::nominal(0.2601, 0.30, 0.09, 100).unwrap(),
            ..n
        });
        others.push(ParamsInUse {
            params: VehicleParams::nominal(0.26, 0.30, 0.09, 101).unwrap(),
            ..n
        });
        // A bias of exactly 0 is a calibration, not its absence.
        others.push(ParamsInUse {
            yaw_rate_bias_radps: Some(0.0),
            ..n
        });
        let mut seen = vec![n.values_crc32()];
        for o in &others {
            let crc = o.values_crc32();
            assert!(!seen.contains(&crc), "{o:?} collides");
            seen.push(crc);
        }
        let text = ParamIdentity {
            version: Some(3),
            values_crc32: 0xab,
        }
        .to_string();
        assert_eq!(text, "calibrated set version 3 (values crc32 000000ab)");
        assert!(id.to_string().starts_with("nominal parameters"));
    }

    #[test]
    fn a_change_resets_exactly_the_values_learnt_on_it() {
        let n = nominal();
        let priors = EkfConfig::new(n.params);
        let l = learnt();
        let y = l.yaw_bias.unwrap();
        assert_eq!(ParamChanges::between(&n, &n), ParamChanges::default());
        assert_eq!(
            reset_learnt(&l, ParamChanges::default(), &priors),
            l,
            "nothing changed, nothing reset"
        );
        for (group, after) in one_change_each() {
            let changes = ParamChanges::between(&n, &after);
            assert!(changes.any(), "{group}");
            let r = reset_learnt(&l, changes, &priors);
            let ry = r.yaw_bias.unwrap();
            let expect_steer = if group == "steering" {
                (0.0, 0.0)
            } else {
                (l.steer_offset_rad, l.steer_offset_sigma_rad)
            };
            assert_eq!(
                (r.steer_offset_rad, r.steer_offset_sigma_rad),
                expect_steer,
                "{group}"
            );
            let diam = group == "rear_diameters";
            assert_eq!(
                r.wheel_fault,
                if diam { None } else { l.wheel_fault },
                "{group}"
            );
            assert_eq!(
                (r.front_scale, r.front_scale_sigma),
                if diam {
                    (1.0, 0.0)
                } else {
                    (l.front_scale, l.front_scale_sigma)
                },
                "{group}"
            );
            assert_eq!(
                (ry.rear_ratio_err, ry.rear_ratio_sigma),
                if diam {
                    (0.0, priors.rear_ratio_sigma)
                } else {
                    (y.rear_ratio_err, y.rear_ratio_sigma)
                },
                "{group}"
            );
            assert_eq!(
                (ry.tread_err, ry.tread_sigma),
                if group == "rear_tread" {
                    (0.0, priors.tread_sigma)
                } else {
                    (y.tread_err, y.tread_sigma)
                },
                "{group}"
            );
            assert_eq!(
                (ry.yaw_bias_radps, ry.yaw_bias_sigma_radps),
                if group == "yaw_rate" {
                    (0.0, priors.yaw_bias_sigma_radps)
                } else {
                    (y.yaw_bias_radps, y.yaw_bias_sigma_radps)
                },
                "{group}"
            );
        }
        // Nothing learnt about a yaw-rate sensor: nothing to reset there.
        let no_gyro = Learnt {
            yaw_bias: None,
            ..l
        };
        let all = ParamChanges {
            rear_diameters: true,
            rear_tread: true,
            steering: true,
            yaw_rate: true,
        };
        assert_eq!(reset_learnt(&no_gyro, all, &priors).yaw_bias, None);
    }
}
