//! The drive prepared for the fit: samples and fixes checked, gaps in the
//! steering and yaw rate held, the inputs' white noise measured, and the
//! fixes cut into segments short enough to keep the reckoning nearly linear.

use super::inputs::{DriveSample, Fix};
use super::options::DriveOptions;
use crate::error::{Error, Result};

/// Inputs checked and arranged for the reckonings.
#[derive(Clone)]
pub(super) struct Prepared {
    pub(super) t: Vec<f64>,
    pub(super) dl: Vec<f64>,
    pub(super) dr: Vec<f64>,
    /// Steering angle at each sample, held from the last known value.
    pub(super) steer: Option<Vec<f64>>,
    /// Yaw rate of each sample's interval, held from the last known value.
    pub(super) yaw: Option<Vec<f64>>,
    /// White noise of each input signal per value, `[unused, yaw, steer]`.
    pub(super) noise: [f64; 3],
    /// Slipping samples up to each sample (a prefix count).
    pub(super) slips: Vec<usize>,
}

/// The white noise of a signal from its values in order: the robust σ
/// (1.4826 × median absolute value) of second differences, divided by √6.
/// Second differences cancel the signal's own trends and the median ignores
/// its kinks (a step of the yaw rate, a steering ramp's ends); what remains
/// is noise and quantisation, which integrate into a heading random walk.
pub(super) fn white_noise(values: impl Iterator<Item = Option<f64>>) -> f64 {
    let v: Vec<f64> = values.flatten().collect();
    let mut d2: Vec<f64> = v
        .windows(3)
        .map(|w| (w[2] - 2.0 * w[1] + w[0]).abs())
        .collect();
    if d2.is_empty() {
        return 0.0;
    }
    d2.sort_by(f64::total_cmp);
    1.4826 * d2[d2.len() / 2] / 6.0_f64.sqrt()
}

/// Fills gaps with the last known value (the first known one before it).
pub(super) fn held(values: impl Iterator<Item = Option<f64>>) -> Option<Vec<f64>> {
    let raw: Vec<Option<f64>> = values.collect();
    let first = raw.iter().flatten().copied().next()?;
    let mut last = first;
    Some(
        raw.into_iter()
            .map(|v| {
                if let Some(v) = v {
                    last = v;
                }
                last
            })
            .collect(),
    )
}

/// One segment: fixes `fixes` (indices into the fix list, at least three),
/// the sample range its reckoning needs and each fix's interpolation.
#[derive(Clone)]
pub(super) struct Segment {
    pub(super) fixes: Vec<usize>,
    /// First sample of the reckoning (at or before the first fix, less the
    /// largest latency).
    pub(super) start: usize,
    /// Last sample the reckoning may need (at or after the last fix, plus
    /// the largest latency).
    pub(super) end: usize,
}

/// Checks the samples and fixes: enough of them, finite, in time order,
/// every fix within the samples' span.
pub(super) fn check(samples: &[DriveSample], fixes: &[Fix]) -> Result<()> {
    if samples.len() < 2 {
        return Err(Error::NotEnoughSamples { got: samples.len() });
    }
    for (index, s) in samples.iter().enumerate() {
        let fields = [
            ("t_s", Some(s.t_s)),
            ("rear_left_m", Some(s.rear_left_m)),
            ("rear_right_m", Some(s.rear_right_m)),
            ("steer_angle_rad", s.steer_angle_rad),
            ("yaw_rate_radps", s.yaw_rate_radps),
        ];
        let previous_s = index.checked_sub(1).map(|i| samples[i].t_s);
        check_row("sample", index, &fields, s.t_s, previous_s)?;
    }
    if fixes.len() < 3 {
        return Err(Error::NotEnoughFixes {
            what: "in all",
            got: fixes.len(),
            needed: 3,
        });
    }
    let (first_s, last_s) = (samples[0].t_s, samples[samples.len() - 1].t_s);
    for (index, f) in fixes.iter().enumerate() {
        let fields = [
            ("t_s", Some(f.t_s)),
            ("x_m", Some(f.x_m)),
            ("y_m", Some(f.y_m)),
            ("heading_rad", f.heading_rad),
            ("sigma_m", f.sigma_m),
        ];
        let previous_s = index.checked_sub(1).map(|i| fixes[i].t_s);
        check_row("fix", index, &fields, f.t_s, previous_s)?;
        if let Some(sigma) = f.sigma_m.filter(|s| *s <= 0.0) {
            return Err(Error::InvalidArgument {
                name: "fix sigma_m",
                value: sigma,
                reason: "a fix's stated σ must be positive (None when not known)",
            });
        }
        if f.t_s < first_s || f.t_s > last_s {
            return Err(Error::FixOutsideSamples {
                index,
                t_s: f.t_s,
                first_s,
                last_s,
            });
        }
    }
    Ok(())
}

/// One sample's or fix's `fields` finite, and its time `t_s` after the
/// previous one's (`previous_s`, `None` for the first).
fn check_row(
    what: &'static str,
    index: usize,
    fields: &[(&'static str, Option<f64>)],
    t_s: f64,
    previous_s: Option<f64>,
) -> Result<()> {
    for &(field, value) in fields {
        if let Some(value) = value.filter(|v| !v.is_finite()) {
            return Err(Error::NotFinite {
                what,
                index,
                field,
                value,
            });
        }
    }
    match previous_s {
        Some(previous_s) if t_s <= previous_s => Err(Error::NotIncreasing {
            what,
            index,
            t_s,
            previous_s,
        }),
        _ => Ok(()),
    }
}

/// Splits the fixes into segments of at most `max_segment_s` and
/// `max_segment_fixes`; a group of fewer than three fixes joins the previous
/// segment when the gap allows, else it is dropped.
/// Each segment's reckoning spans its fixes widened by `margin_s` (the
/// largest latency) where the samples allow. A slipping sample (`slips`,
/// the prefix count of slipping samples) between two fixes ends a segment.
pub(super) fn split(
    t: &[f64],
    slips: &[usize],
    fixes: &[Fix],
    options: &DriveOptions,
    margin_s: f64,
) -> Vec<Segment> {
    let slips_until = |ts: f64| {
        let k = t.partition_point(|&s| s <= ts);
        if k == 0 {
            0
        } else {
            slips[(k - 1).min(slips.len() - 1)]
        }
    };
    let mut groups: Vec<Vec<usize>> = Vec::new();
    let mut current: Vec<usize> = Vec::new();
    for (i, f) in fixes.iter().enumerate() {
        let starts_new = current.first().is_some_and(|&first| {
            let last = current[current.len() - 1];
            f.t_s - fixes[first].t_s > options.max_segment_s
                || current.len() >= options.max_segment_fixes
                || slips_until(f.t_s + margin_s) > slips_until(fixes[last].t_s - margin_s)
        });
        if starts_new {
            groups.push(std::mem::take(&mut current));
        }
        current.push(i);
    }
    groups.push(current);
    // A group of fewer than three fixes joins the one before it when the
    // gap between them is within the time limit; otherwise it is dropped.
    let mut merged: Vec<Vec<usize>> = Vec::new();
    for group in groups {
        let joins = group.len() < 3
            && merged.last().is_some_and(|prev: &Vec<usize>| {
                let prev_t = fixes[prev[prev.len() - 1]].t_s;
                fixes[group[0]].t_s - prev_t <= options.max_segment_s
                    && slips_until(fixes[group[group.len() - 1]].t_s + margin_s)
                        == slips_until(prev_t - margin_s)
            });
        match merged.last_mut() {
            Some(prev) if joins => prev.extend(group),
            _ => merged.push(group),
        }
    }
    merged
        .into_iter()
        .filter(|g| g.len() >= 3)
        .map(|fixes_idx| {
            let at: Vec<(usize, f64)> = fixes_idx
                .iter()
                .map(|&f| {
                    let tf = fixes[f].t_s;
                    // First sample at or after the fix; the fix lies in
                    // [t[i], t[i+1]] with i = k − 1 (k ≥ 1).
                    let k = t.partition_point(|&ts| ts < tf).clamp(1, t.len() - 1);
                    let i = k - 1;
                    (i, ((tf - t[i]) / (t[k] - t[i])).clamp(0.0, 1.0))
                })
                .collect();
            let first_t = fixes[fixes_idx[0]].t_s - margin_s;
            let last_t = fixes[fixes_idx[fixes_idx.len() - 1]].t_s + margin_s;
            let start = t.partition_point(|&ts| ts <= first_t).saturating_sub(1);
            let end = t.partition_point(|&ts| ts < last_t).min(t.len() - 1);
            Segment {
                start: start.min(at[0].0),
                end: end.max(at[at.len() - 1].0 + 1).max(start + 1),
                fixes: fixes_idx,
            }
        })
        .collect()
}

/// The rear wheels' turning over the segments' samples, left and right:
/// the heading change of each second (with the tread in use) summed by sign,
/// so a slalom's wiggles and the wheels' noise count little and a turn in full.
pub(super) fn turns(prep: &Prepared, segments: &[Segment], rear_tread_m: f64) -> [f64; 2] {
    let mut out = [0.0; 2];
    for seg in segments {
        let (mut acc, mut t0) = (0.0, prep.t[seg.start]);
        for k in seg.start + 1..=seg.end {
            acc += (prep.dr[k] - prep.dl[k]) / rear_tread_m;
            if prep.t[k] - t0 >= 1.0 || k == seg.end {
                out[usize::from(acc < 0.0)] += acc.abs();
                (acc, t0) = (0.0, prep.t[k]);
            }
        }
    }
    out
}
