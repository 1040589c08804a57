//! The guided session driven by a simulated vehicle, as the daemon would:
//! samples decoded from the simulator's wrapping tick counters, the driver
//! following the instructions, the operator entering measured end poses.

use crate::common::{RHO_M, effective, nominal, sim_direction, truth};
use canodom_calib::session::{Action, Event, Instruction, Phase, Session, SessionConfig};
use canodom_calib::steering::SteeringProvenance;
use canodom_calib::{Direction, RearParams, RevSample};
use canodom_fusion::sim::{self, Plan, SimConfig};
use canodom_fusion::wheel::{InputConfig, TickDecoder};
use canodom_fusion::{VehicleParams, Wheel};

struct Daemon {
    session: Option<Session>,
    clock_s: f64,
    log: Vec<Action>,
}

impl Daemon {
    fn send(&mut self, e: Event) -> Vec<Action> {
        let (s, actions) = self.session.take().unwrap().on_event(e);
        assert!(s.invariant_violation().is_none());
        let mut out = actions.clone();
        self.session = Some(s);
        // Carry out a compute request at once, as the daemon's worker would.
        if actions.contains(&Action::Compute) {
            let job = self.s().calibration_job().unwrap();
            out.extend(self.send(Event::Computed(job.run())));
        }
        self.log.extend(actions);
        out
    }
    fn s(&self) -> &Session {
        self.session.as_ref().unwrap()
    }
    /// Streams one simulated drive into the session, decoding its counters
    /// with the parameters the session uses.
    fn drive(&mut self, run: &sim::Run, params: &VehicleParams) {
        let mut decoders = [Wheel::RearLeft, Wheel::RearRight].map(|w| {
            TickDecoder::new(16, params.tick_distance_m(w, 1.0), InputConfig::RC_CAR).unwrap()
        });
        let t0 = self.clock_s;
        for (k, s) in run.samples.iter().enumerate() {
            let dl = decoders[0].push(s.t_s, s.ticks.rear_left).distance_m;
            let dr = decoders[1].push(s.t_s, s.ticks.rear_right).distance_m;
            self.clock_s = t0 + s.t_s;
            if k == 0 {
                continue;
            }
            let sample =
                RevSample::from_distances(params, self.clock_s, [dl, dr], None, s.steer_signal);
            self.send(Event::Sample(sample));
        }
        self.clock_s += 0.01;
    }
}

#[test]
fn a_simulated_car_completes_a_guided_session_through_the_trap() {
    let t = truth(true, false);
    let mut cfg = SimConfig::rc_car(t);
    cfg.standstill_s = 1.5;
    let params = nominal();
    let mut d = Daemon {
        session: Some(Session::new(
            params,
            SteeringProvenance::UncalibratedOdometry,
            SessionConfig::default(),
        )),
        clock_s: 0.0,
        log: Vec::new(),
    };
    d.send(Event::StartSession {
        radius_m: RHO_M,
        runs_per_direction: 3,
    });
    let mut seed = 40;
    let mut measured_ends = 0;
    while matches!(d.s().phase(), Phase::Positioning) {
        let direction = match d.s().instruction() {
            Instruction::GoToStart { direction, .. } | Instruction::Go { direction, .. } => {
                direction
            }
            other => panic!("unexpected instruction {other:?}"),
        };
        let plan = Plan::track(RHO_M, sim_direction(direction), 1).unwrap();
        let run = sim::simulate(&cfg, &plan, seed).unwrap();
        seed += 1;
        d.drive(&run, &params);
        assert_eq!(d.s().phase(), Phase::AwaitingEndPose, "{:?}", d.log.last());
        d.send(Event::MeasuredEndPose(run.true_end));
        measured_ends += 1;
    }
    assert_eq!(measured_ends, 6);
    assert!(
        d.log
            .iter()
            .filter(|a| matches!(a, Action::RunAccepted { .. }))
            .count()
            == 6
    );
    let runs = d.s().accepted_runs();
    assert_eq!(
        runs.iter().filter(|r| r.direction == Direction::Cw).count(),
        3
    );
    let out = d.send(Event::Compute);
    let Some(Action::ResultReady(result)) =
        out.iter().find(|a| matches!(a, Action::ResultReady(_)))
    else {
        panic!("{out:?}")
    };
    let (b_eff, e_true) = effective(&t, &RearParams::of(&params));
    println!(
        "\nguided session on the simulator (left tape, trap provenance, 3+3 runs): tread {:.2} cm (eff {:.2}), E {:.4} (true {:.4}), E_max {:.1} → {:.2} cm",
        100.0 * result.tread_m(),
        100.0 * b_eff,
        result.ratio(),
        e_true,
        100.0 * result.e_max_before_m,
        100.0 * result.e_max_after_m
    );
    assert!((result.tread_m() / b_eff - 1.0).abs() < 0.003);
    assert!((result.ratio() / e_true - 1.0).abs() < 6e-4);
    let out = d.send(Event::Commit);
    assert!(matches!(out[0], Action::ApplyParams(p) if p == result.rear));
    assert_eq!(d.s().instruction(), Instruction::RefitSteering);
    assert!((d.s().params().rear_tread_m() - result.tread_m()).abs() < 1e-15);
}
