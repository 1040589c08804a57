//! Shared helpers: the §9 vehicles, and simulator runs turned into calib runs
//! through the fusion crate's tick decoders (the daemon's chain).

use canodom_calib::run::{InputFault, Tolerances};
use canodom_calib::{Direction, RearParams, RevSample, Run, RunRecorder};
use canodom_fusion::sim::{self, Plan, SimConfig};
use canodom_fusion::wheel::{InputConfig, TickDecoder};
use canodom_fusion::{SteeringMap, VehicleParams, Wheel};

pub const RHO_M: f64 = 0.78;
pub const DEG: f64 = std::f64::consts::PI / 180.0;

/// §10's true steering map: φ = 0.93 u + 0.80°, u in degrees.
pub fn true_steering() -> SteeringMap {
    SteeringMap {
        gain: 0.93 * DEG,
        offset_rad: 0.80 * DEG,
    }
}

/// §9's truth: b = 28.5 cm, E = 1.005 around 9 cm, with a 3.5 % tape on
/// the left and/or right rear wheel.
pub fn truth(tape_left: bool, tape_right: bool) -> VehicleParams {
    canodom_calib::synth::section9_truth(tape_left, tape_right)
        .unwrap()
        .with_steering(true_steering())
        .unwrap()
}

/// The nominal parameters the odometry uses before calibration (§9).
pub fn nominal() -> VehicleParams {
    VehicleParams::nominal(0.25, 0.30, 0.09, 1000)
        .unwrap()
        .with_steering(true_steering())
        .unwrap()
}

/// (b_eff, E) of `truth` seen with the mean diameter of `used` (§4).
pub fn effective(truth: &VehicleParams, used: &RearParams) -> (f64, f64) {
    let t = RearParams::of(truth);
    (
        t.tread_m * used.mean_diameter_m() / t.mean_diameter_m(),
        t.ratio(),
    )
}

pub fn sim_direction(d: Direction) -> sim::Direction {
    match d {
        Direction::Ccw => sim::Direction::Ccw,
        Direction::Cw => sim::Direction::Cw,
    }
}

/// Decodes a simulated run's wheel counters with `params` as the daemon
/// would and records it; `measured` attaches the true end pose as the
/// operator's measurement.
pub fn record(
    run: &sim::Run,
    dir: Direction,
    params: &VehicleParams,
    measured: bool,
    counter_bits: u32,
) -> Run {
    let mut decoders = Wheel::ALL.map(|w| {
        TickDecoder::new(
            counter_bits,
            params.tick_distance_m(w, 1.0),
            InputConfig::RC_CAR,
        )
        .unwrap()
    });
    let mut rec = RunRecorder::new(dir, Tolerances::default().max_gap_s);
    for (k, s) in run.samples.iter().enumerate() {
        let mut d = [0.0; 4];
        let mut fault = false;
        for (i, w) in Wheel::ALL.iter().enumerate() {
            let step = decoders[i].push(s.t_s, s.ticks[*w]);
            d[i] = step.distance_m;
            fault |= step.fault.is_some();
        }
        if k == 0 {
            continue;
        }
        if fault {
            rec.push_fault(s.t_s, InputFault::Decoder { code: 0 });
        }
        rec.push(RevSample::from_distances(
            params,
            s.t_s,
            [d[0], d[1]],
            Some([d[2], d[3]]),
            s.steer_signal,
        ));
    }
    rec.finish(measured.then_some(run.true_end))
}

/// `n` laps each way, seeds `seed0..`, recorded with `params`.
pub fn laps(
    cfg: &SimConfig,
    params: &VehicleParams,
    per_dir: usize,
    seed0: u64,
    measured: bool,
) -> Vec<Run> {
    let mut out = Vec::new();
    for (j, dir) in Direction::BOTH.iter().enumerate() {
        for k in 0..per_dir {
            let plan = Plan::track(RHO_M, sim_direction(*dir), 1).unwrap();
            let seed = seed0 + (j * per_dir + k) as u64;
            let run = sim::simulate(cfg, &plan, seed).unwrap();
            out.push(record(
                &run,
                *dir,
                params,
                measured,
                cfg.wheel_output.counter_bits,
            ));
        }
    }
    out
}

pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}
