//! The harness shared by the fusion crate's simulator-judged tests: wheel
//! samples decoded as the daemon decodes them, fed to several filters.

// Helpers of a test harness: a failure to set up is a test failure.
#![allow(clippy::unwrap_used, dead_code)]

use canodom_fusion::ekf::{Ekf, OdometryInput, State};
use canodom_fusion::sim::Run;
use canodom_fusion::wheel::{InputConfig, SpeedDecoder, SpeedIntegration, SpeedUnit, TickDecoder};
use canodom_fusion::{VehicleParams, Wheel, WheelSet};

/// Where the wheel distances come from.
pub enum Wheels {
    Ticks(Vec<TickDecoder>),
    Speeds(Vec<SpeedDecoder>),
}

impl Wheels {
    pub fn ticks(p: &VehicleParams, bits: u32) -> Self {
        Wheels::Ticks(
            Wheel::ALL
                .iter()
                .map(|w| {
                    TickDecoder::new(bits, p.tick_distance_m(*w, 1.0), InputConfig::RC_CAR).unwrap()
                })
                .collect(),
        )
    }

    pub fn speeds() -> Self {
        let cfg = InputConfig {
            nominal_period_s: 0.01,
            ..InputConfig::ROAD_CAR
        };
        Wheels::Speeds(
            (0..4)
                .map(|_| {
                    SpeedDecoder::new(
                        SpeedUnit::KilometresPerHour,
                        SpeedIntegration::Trapezoid,
                        cfg,
                    )
                    .unwrap()
                })
                .collect(),
        )
    }

    pub fn distances(&mut self, s: &canodom_fusion::sim::Sample) -> WheelSet<f64> {
        let mut out = WheelSet::splat(0.0);
        for (k, w) in Wheel::ALL.iter().enumerate() {
            let step = match self {
                Wheels::Ticks(d) => d[k].push(s.t_s, s.ticks[*w]),
                Wheels::Speeds(d) => d[k].push(s.t_s, s.wheel_speed[*w]),
            };
            assert_eq!(
                step.fault, None,
                "the simulator's wheels must decode cleanly"
            );
            out[*w] = step.distance_m;
        }
        out
    }
}

/// Runs every filter over one simulated run; returns each filter's final
/// state. Wheel-speed sensors report 0 below their floor and encoders' zero
/// steps are quantisation, so `zero_is_floor` follows the wheels' kind.
pub fn replay(run: &Run, nominal: &VehicleParams, wheels: Wheels, filters: &[Ekf]) -> Vec<State> {
    let zero_is_floor = matches!(wheels, Wheels::Speeds(_));
    replay_with(run, nominal, wheels, filters, zero_is_floor)
}

/// [`replay`] with the inputs' `zero_is_floor` given.
pub fn replay_with(
    run: &Run,
    nominal: &VehicleParams,
    wheels: Wheels,
    filters: &[Ekf],
    zero_is_floor: bool,
) -> Vec<State> {
    replay_full(run, nominal, wheels, filters, zero_is_floor, false)
}

/// [`replay`] with the yaw-rate sensor's samples fed to the filters.
pub fn replay_yaw(
    run: &Run,
    nominal: &VehicleParams,
    wheels: Wheels,
    filters: &[Ekf],
) -> Vec<State> {
    let zero_is_floor = matches!(wheels, Wheels::Speeds(_));
    replay_full(run, nominal, wheels, filters, zero_is_floor, true)
}

fn replay_full(
    run: &Run,
    nominal: &VehicleParams,
    mut wheels: Wheels,
    filters: &[Ekf],
    zero_is_floor: bool,
    yaw: bool,
) -> Vec<State> {
    let mut states = vec![State::origin(); filters.len()];
    for (k, s) in run.samples.iter().enumerate() {
        let wheel_m = wheels.distances(s);
        if k == 0 {
            continue;
        }
        let input = OdometryInput {
            wheel_m,
            front_valid: true,
            steer_angle_rad: nominal.steering().angle_rad(s.steer_signal),
            zero_is_floor,
            yaw_rate_radps: yaw.then_some(s.yaw_rate_radps),
            dt_s: s.t_s - run.samples[k - 1].t_s,
        };
        for (st, f) in states.iter_mut().zip(filters) {
            *st = f.step(st, &input).unwrap();
        }
    }
    states
}
