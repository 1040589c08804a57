//! The report of a committed steering map (`docs/calibration-math.md` §10): every
//! arc's command and measured road-wheel angle, the fitted line beside the
//! map used while driving, and the fit's uncertainty, as JSON and as an SVG
//! plot of angle against command, so that a person sees whether the arcs lie
//! on a line at all.
//!
//! [`SteeringReport::build`] is pure; [`crate::files::write_report`] writes
//! it (atomically, like the rear report).

use crate::files::{AFTER_COLOUR, BEFORE_COLOUR, PlotResult, PlottedReport, draw_line};
use canodom_calib::steering::SteeringFit;
use canodom_fusion::SteeringMap;
use plotters::coord::Shift;
use plotters::prelude::*;
use serde::Serialize;

/// A steering map as reported.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ReportSteering {
    /// Road-wheel radians per unit of the steering signal.
    pub gain: f64,
    /// Road-wheel angle at a zero signal, radians.
    pub offset_rad: f64,
}

impl From<SteeringMap> for ReportSteering {
    fn from(m: SteeringMap) -> Self {
        Self {
            gain: m.gain,
            offset_rad: m.offset_rad,
        }
    }
}

impl ReportSteering {
    fn angle_rad(self, command: f64) -> f64 {
        self.gain.mul_add(command, self.offset_rad)
    }
}

/// One constant-command arc the fit used.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ReportArc {
    /// Mean steering signal over the arc.
    pub command: f64,
    /// Road-wheel angle measured by the calibrated rear odometry, radians.
    pub steer_angle_rad: f64,
    /// The arc's curvature, 1/m (left positive).
    pub curvature_per_m: f64,
    /// Distance used, m.
    pub distance_m: f64,
    /// Measured angle minus the fitted line's, radians.
    pub residual_rad: f64,
}

/// Everything a steering calibration produced.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SteeringReport {
    /// Always `steering`, beside the rear report's method names.
    pub method: &'static str,
    /// The map in use while the arcs were driven.
    pub before: ReportSteering,
    /// The fitted map.
    pub calibrated: ReportSteering,
    /// Standard deviation of the gain, relative to the nominal gain (as
    /// `CALIB_STATUS` shows it).
    pub gain_std_rel: f64,
    /// Standard deviation of the offset, radians.
    pub offset_std_rad: f64,
    /// Root mean square of the residuals, radians.
    pub rms_rad: f64,
    /// Arcs left out because their curvature varied (slip, nonlinear map).
    pub dropped_varying: usize,
    /// The arcs the fit used.
    pub arcs: Vec<ReportArc>,
}

impl SteeringReport {
    /// The report of `fit`, driven with the map `before`, with the
    /// uncertainties the commit was judged by.
    pub fn build(
        fit: &SteeringFit,
        before: SteeringMap,
        gain_std_rel: f64,
        offset_std_rad: f64,
    ) -> Self {
        Self {
            method: "steering",
            before: before.into(),
            calibrated: fit.map().into(),
            gain_std_rel,
            offset_std_rad,
            rms_rad: fit.rms_rad,
            dropped_varying: fit.dropped_varying,
            arcs: fit
                .arcs
                .iter()
                .zip(&fit.residuals_rad)
                .map(|(a, &residual_rad)| ReportArc {
                    command: a.command,
                    steer_angle_rad: a.steer_angle_rad,
                    curvature_per_m: a.curvature_per_m,
                    distance_m: a.distance_m,
                    residual_rad,
                })
                .collect(),
        }
    }
}

const SVG_W: u32 = 900;
const SVG_H: u32 = 600;

impl PlottedReport for SteeringReport {
    const SVG_SIZE_PX: (u32, u32) = (SVG_W, SVG_H);

    fn draw(&self, root: &DrawingArea<SVGBackend<'_>, Shift>) -> PlotResult {
        root.fill(&WHITE)?;
        let (u0, u1) = self
            .arcs
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), a| {
                (lo.min(a.command), hi.max(a.command))
            });
        let (u0, u1) = if u0.is_finite() && u1 > u0 {
            let pad = 0.1 * (u1 - u0);
            (u0 - pad, u1 + pad)
        } else {
            (-1.0, 1.0)
        };
        let lines = [
            (self.before, BEFORE_COLOUR),
            (self.calibrated, AFTER_COLOUR),
        ];
        let deg = f64::to_degrees;
        let angles = self
            .arcs
            .iter()
            .map(|a| deg(a.steer_angle_rad))
            .chain(
                lines
                    .iter()
                    .flat_map(|(m, _)| [u0, u1].map(|u| deg(m.angle_rad(u)))),
            )
            .filter(|v| v.is_finite());
        let (a0, a1) = angles.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
        let (a0, a1) = if a1 > a0 {
            let pad = 0.05 * (a1 - a0);
            (a0 - pad, a1 + pad)
        } else {
            (-1.0, 1.0)
        };
        let caption = format!(
            "canodom steering map, {} arcs: φ = {:.5} rad · u + {:.3}° (± {:.2}°), rms {:.2}°",
            self.arcs.len(),
            self.calibrated.gain,
            deg(self.calibrated.offset_rad),
            deg(self.offset_std_rad),
            deg(self.rms_rad),
        );
        let mut chart = ChartBuilder::on(root)
            .caption(caption, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(55)
            .build_cartesian_2d(u0..u1, a0..a1)?;
        chart
            .configure_mesh()
            .x_desc("steering signal")
            .y_desc("road-wheel angle (°)")
            .draw()?;
        for (map, colour, label) in [
            (self.before, BEFORE_COLOUR, "map used while driving"),
            (self.calibrated, AFTER_COLOUR, "fitted map"),
        ] {
            draw_line(
                &mut chart,
                [u0, u1].map(|u| (u, deg(map.angle_rad(u)))),
                colour,
                label,
            )?;
        }
        chart
            .draw_series(
                self.arcs
                    .iter()
                    .map(|a| Circle::new((a.command, deg(a.steer_angle_rad)), 4, BLACK.filled())),
            )?
            .label("arcs (calibrated rear odometry)")
            .legend(|(x, y)| Circle::new((x + 10, y), 4, BLACK.filled()));
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::files::ReportFiles;
    use canodom_calib::steering::{ArcEstimate, fit_steering};

    fn arc(command: f64, steer_angle_rad: f64) -> ArcEstimate {
        ArcEstimate {
            command,
            curvature_per_m: steer_angle_rad.tan() / 0.26,
            steer_angle_rad,
            distance_m: 2.0,
            curvature_spread_per_m: 0.0,
            varying: false,
        }
    }

    #[test]
    fn report_numbers_are_the_fit_and_the_plot_has_a_dot_per_arc() {
        // φ = 0.0163 u + 0.8°, one arc 0.3° off the line.
        let truth = |u: f64| 0.0163f64.mul_add(u, 0.8f64.to_radians());
        let arcs: Vec<_> = [-20.0, -8.0, 5.0, 18.0]
            .into_iter()
            .enumerate()
            .map(|(i, u)| arc(u, truth(u) + if i == 1 { 0.3f64.to_radians() } else { 0.0 }))
            .collect();
        let fit = fit_steering(&arcs, false).unwrap();
        let before = SteeringMap {
            gain: 0.0175,
            offset_rad: 0.0,
        };
        let report = SteeringReport::build(&fit, before, 0.004, 0.002);
        assert_eq!(report.method, "steering");
        assert_eq!(report.before, before.into());
        assert_eq!(report.calibrated, fit.map().into());
        assert_eq!((report.gain_std_rel, report.offset_std_rad), (0.004, 0.002));
        assert_eq!(report.arcs.len(), 4);
        for (r, a) in report.arcs.iter().zip(&arcs) {
            assert_eq!(
                (r.command, r.steer_angle_rad),
                (a.command, a.steer_angle_rad)
            );
            let line = report.calibrated.angle_rad(r.command);
            assert!((r.residual_rad - (a.steer_angle_rad - line)).abs() < 1e-12);
        }
        assert!(report.arcs[1].residual_rad > 0.1f64.to_radians());
        let json: serde_json::Value = serde_json::from_str(&report.json().unwrap()).unwrap();
        assert_eq!(json["arcs"].as_array().map(Vec::len), Some(4));
        assert_eq!(json["calibrated"]["gain"], fit.gain);
        let svg = report.svg().unwrap();
        // Four arcs and the legend's dot.
        assert_eq!(svg.matches("<circle").count(), 5, "{svg}");
        assert!(svg.contains("fitted map") && svg.contains("map used while driving"));
    }
}
