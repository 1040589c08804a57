//! §9's convergence grid: noise-free simulator runs (one lap each way),
//! starting parameters off the truth by −50..+50 % in tread (10 % steps) and
//! −30..+30 % in ratio (2.5 % steps). Success: within 1e-4 of the truth for
//! methods that claim the solution (heading law, iterated forms, LM), E_max
//! at least halved for the one-shot closed forms (§9's criterion). The
//! simulator's encoders count whole ticks, so the truth itself closes the
//! laps only to ~0.2 mm.

use crate::common::{RHO_M, laps, truth};
use canodom_calib::methods::{
    ExactOptions, ExactStart, PaperOptions, PaperVariant, exact, heading, paper,
};
use canodom_calib::{CalibrationResult, RearParams, Result, Run, Track};
use canodom_fusion::sim::SimConfig;

const TREAD_STEPS: i32 = 5; // ±5 × 10 %
const RATIO_STEPS: i32 = 12; // ±12 × 2.5 %

struct MethodDef {
    name: &'static str,
    one_shot: bool,
    run: fn(&[Run], &RearParams, Track) -> Result<CalibrationResult>,
}

fn methods() -> Vec<MethodDef> {
    fn one(v: PaperVariant) -> PaperOptions {
        PaperOptions {
            variant: v,
            max_iterations: 1,
        }
    }
    fn many(v: PaperVariant) -> PaperOptions {
        PaperOptions {
            variant: v,
            max_iterations: 40,
        }
    }
    vec![
        MethodDef {
            name: "paper x one-shot (halves E_max)",
            one_shot: true,
            run: |r, u, t| paper(r, u, t, one(PaperVariant::X)),
        },
        MethodDef {
            name: "paper LS one-shot (halves E_max)",
            one_shot: true,
            run: |r, u, t| paper(r, u, t, one(PaperVariant::LeastSquares)),
        },
        MethodDef {
            name: "paper y one-shot (halves E_max)",
            one_shot: true,
            run: |r, u, t| paper(r, u, t, one(PaperVariant::Y)),
        },
        MethodDef {
            name: "heading law one-shot",
            one_shot: false,
            run: heading,
        },
        MethodDef {
            name: "paper x iterated",
            one_shot: false,
            run: |r, u, t| paper(r, u, t, many(PaperVariant::X)),
        },
        MethodDef {
            name: "paper y iterated",
            one_shot: false,
            run: |r, u, t| paper(r, u, t, many(PaperVariant::Y)),
        },
        MethodDef {
            name: "paper LS iterated",
            one_shot: false,
            run: |r, u, t| paper(r, u, t, many(PaperVariant::LeastSquares)),
        },
        MethodDef {
            name: "LM position only, from nominal",
            one_shot: false,
            run: |r, u, t| {
                let o = ExactOptions {
                    start: ExactStart::Used,
                    heading_residuals: false,
                    max_iterations: 100,
                };
                exact(r, u, t, o)
            },
        },
        MethodDef {
            name: "LM + heading, from nominal",
            one_shot: false,
            run: |r, u, t| {
                let o = ExactOptions {
                    start: ExactStart::Used,
                    heading_residuals: true,
                    max_iterations: 100,
                };
                exact(r, u, t, o)
            },
        },
        MethodDef {
            name: "exact (LM + heading, from heading law)",
            one_shot: false,
            run: |r, u, t| exact(r, u, t, ExactOptions::default()),
        },
    ]
}

/// Success of every method at one grid point.
fn point(
    runs: &[Run],
    truth_rear: &RearParams,
    i: i32,
    j: i32,
    methods: &[MethodDef],
) -> Vec<bool> {
    let track = Track::new(RHO_M).unwrap();
    let used = RearParams::from_ratio(
        truth_rear.tread_m * (1.0 + 0.1 * f64::from(i)),
        truth_rear.mean_diameter_m(),
        truth_rear.ratio() * (1.0 + 0.025 * f64::from(j)),
    )
    .unwrap();
    methods
        .iter()
        .map(|m| match (m.run)(runs, &used, track) {
            // At the truth there is nothing to halve: the tick quantisation
            // alone leaves ~0.2 mm, so under 1 mm counts as success.
            Ok(r) if m.one_shot => {
                r.e_max_after_m <= 0.5 * r.e_max_before_m || r.e_max_after_m < 1e-3
            }
            Ok(r) => {
                (r.tread_m() / truth_rear.tread_m - 1.0).abs() < 1e-4
                    && (r.ratio() / truth_rear.ratio() - 1.0).abs() < 1e-4
            }
            Err(_) => false,
        })
        .collect()
}

/// The contiguous range of successes through index 0 along one axis.
fn range(ok: &[(i32, bool)], step_pct: f64) -> String {
    let at = |k: i32| ok.iter().find(|(i, _)| *i == k).is_some_and(|(_, b)| *b);
    if !at(0) {
        return "fails at the truth".into();
    }
    let (mut lo, mut hi) = (0, 0);
    while ok.iter().any(|(i, _)| *i == lo - 1) && at(lo - 1) {
        lo -= 1;
    }
    while ok.iter().any(|(i, _)| *i == hi + 1) && at(hi + 1) {
        hi += 1;
    }
    format!(
        "{:+.1}..{:+.1} %",
        step_pct * f64::from(lo),
        step_pct * f64::from(hi)
    )
}

#[test]
fn convergence_grid_exact_converges_everywhere() {
    let t = truth(false, false);
    let mut cfg = SimConfig::noise_free(t);
    // Exact arcs at any rate: 20 Hz keeps the 275-point grid quick.
    cfg.rate_hz = 20.0;
    let runs = laps(&cfg, &t, 1, 7, false);
    let truth_rear = RearParams::of(&t);
    let defs = methods();
    let points: Vec<(i32, i32)> = (-TREAD_STEPS..=TREAD_STEPS)
        .flat_map(|i| (-RATIO_STEPS..=RATIO_STEPS).map(move |j| (i, j)))
        .collect();
    let results: Vec<((i32, i32), Vec<bool>)> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..2)
            .map(|k| {
                let (runs, defs, points, truth_rear) = (&runs, &defs, &points, &truth_rear);
                s.spawn(move || {
                    points
                        .iter()
                        .skip(k)
                        .step_by(2)
                        .map(|&(i, j)| ((i, j), point(runs, truth_rear, i, j, defs)))
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|h| h.join().unwrap())
            .collect()
    });
    println!(
        "\n§9 convergence grid (noise-free simulator, 1+1 laps; tread −50..+50 % step 10, ratio −30..+30 % step 2.5)\n\
         {:<40} {:>16} {:>16} {:>10}",
        "method", "tread range", "ratio range", "grid"
    );
    let mut exact_all = false;
    for (m, def) in defs.iter().enumerate() {
        let tread_axis: Vec<(i32, bool)> = results
            .iter()
            .filter(|((_, j), _)| *j == 0)
            .map(|((i, _), ok)| (*i, ok[m]))
            .collect();
        let ratio_axis: Vec<(i32, bool)> = results
            .iter()
            .filter(|((i, _), _)| *i == 0)
            .map(|((_, j), ok)| (*j, ok[m]))
            .collect();
        let n_ok = results.iter().filter(|(_, ok)| ok[m]).count();
        println!(
            "{:<40} {:>16} {:>16} {:>6}/{}",
            def.name,
            range(&tread_axis, 10.0),
            range(&ratio_axis, 2.5),
            n_ok,
            results.len()
        );
        if m == defs.len() - 1 {
            exact_all = n_ok == results.len();
        }
    }
    println!(
        "§9 reference: paper one-shot −40..+50 / ±7.5; LS one-shot −50..+30 / −7.5..+10; heading law whole grid;\n\
         iterated paper/LS ±50 / −10..+12.5 / ±12.5; LM position-only ±50 / −10..+12.5; LM+heading from nominal\n\
         ±50 / −22.5..+27.5 %."
    );
    assert!(
        exact_all,
        "the exact method must converge on the whole grid"
    );
}
