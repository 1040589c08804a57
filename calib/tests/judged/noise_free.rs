//! Noise-free simulator runs: every method recovers the effective tread and
//! the ratio to 1e-5 (§9). "Noise-free" means no path noise, no slip and no
//! encoder quantisation worth the name: the truth's encoders count 10^6
//! ticks per revolution on 32-bit counters. With the §9 car's 1000 ticks per
//! revolution the laps only close to ~0.2 mm (printed for comparison).

use crate::common::{RHO_M, effective, laps, nominal, truth};
use canodom_calib::methods::{ExactOptions, PaperOptions, PaperVariant, exact, heading, paper};
use canodom_calib::{CalibrationResult, RearParams, Run, Track};
use canodom_fusion::VehicleParams;
use canodom_fusion::sim::SimConfig;

fn all_methods(runs: &[Run], used: &RearParams) -> Vec<CalibrationResult> {
    let track = Track::new(RHO_M).unwrap();
    let iterated = |variant| PaperOptions {
        variant,
        max_iterations: 40,
    };
    vec![
        paper(runs, used, track, iterated(PaperVariant::X)).unwrap(),
        paper(runs, used, track, iterated(PaperVariant::Y)).unwrap(),
        paper(runs, used, track, iterated(PaperVariant::LeastSquares)).unwrap(),
        heading(runs, used, track).unwrap(),
        exact(runs, used, track, ExactOptions::default()).unwrap(),
    ]
}

fn fine_encoders(p: &VehicleParams) -> VehicleParams {
    VehicleParams::new(
        p.wheelbase_m(),
        p.rear_tread_m(),
        p.front_tread_m(),
        p.wheel_diameters_m(),
        1_000_000,
        p.steering(),
    )
    .unwrap()
}

#[test]
fn noise_free_every_method_recovers_effective_tread_and_ratio() {
    println!("\nnoise-free simulator, 1+1 laps, relative errors against (b_eff, E):");
    println!(
        "{:<8} {:<18} {:>10} {:>10} {:>6}   {:>10} {:>10}",
        "case", "method", "b err", "E err", "iters", "b (1000t)", "E (1000t)"
    );
    for (case, (tl, tr)) in [(false, false), (false, true), (true, false), (true, true)]
        .iter()
        .enumerate()
    {
        let t = truth(*tl, *tr);
        let used_coarse = nominal();
        let used_fine = fine_encoders(&used_coarse);
        let mut cfg = SimConfig::noise_free(fine_encoders(&t));
        cfg.wheel_output.counter_bits = 32;
        let fine = laps(&cfg, &used_fine, 1, 100 + case as u64, false);
        let coarse = laps(
            &SimConfig::noise_free(t),
            &used_coarse,
            1,
            100 + case as u64,
            false,
        );
        let used = RearParams::of(&used_coarse);
        let (b_eff, e_true) = effective(&t, &used);
        for (r, rc) in all_methods(&fine, &used)
            .iter()
            .zip(all_methods(&coarse, &used))
        {
            let eb = r.tread_m() / b_eff - 1.0;
            let ee = r.ratio() / e_true - 1.0;
            println!(
                "{:<8} {:<18} {:>10.2e} {:>10.2e} {:>6}   {:>10.2e} {:>10.2e}",
                case + 1,
                format!("{:?}", r.method),
                eb,
                ee,
                r.iterations,
                rc.tread_m() / b_eff - 1.0,
                rc.ratio() / e_true - 1.0
            );
            assert!(eb.abs() < 1e-5 && ee.abs() < 1e-5, "{r:?}");
            assert!(r.converged);
        }
    }
}
