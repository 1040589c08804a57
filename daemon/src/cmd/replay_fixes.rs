//! `replay --fixes`: the drive calibrated against its fixes as it goes
//! ([`canodom_offline::online`]), each set learnt handed to the replay to be
//! taken into use from the time it was learnt.

use anyhow::Context as _;
use canodom_calib::drift::Watch;
use canodom_can::time::Timestamp;
use canodom_offline::online::{self, Epoch};
use canodom_params::persist::ParamSet;
use canodom_pipeline::config::Config;
use std::path::Path;

/// What `replay --fixes` was told.
pub struct FixesArgs<'a> {
    /// The fixes (`--fixes`).
    pub path: &'a Path,
    /// The drive's log and the interface to read of it.
    pub log: &'a Path,
    /// `--interface`.
    pub interface: Option<&'a str>,
    /// `--fixes-every-s`.
    pub every_s: f64,
    /// `--fixes-window-s` (`None`: all of the drive so far).
    pub window_s: Option<f64>,
    /// `--learnt-out`.
    pub learnt_out: Option<&'a Path>,
}

/// What `replay --fixes` learnt.
#[derive(Default)]
pub struct Learnt {
    /// The sets to take into use, each with its time.
    pub switches: Vec<(Timestamp, ParamSet)>,
    /// The drift watch in a line: how far the drive went until the first
    /// flag, or that nothing was flagged.
    pub drift_summary: Option<String>,
}

/// Learns from the fixes at `args.path` over the drive of `args.log`
/// (recorded with `params` in use), prints each refit and each drift flag
/// that rises or clears, writes `--learnt-out`, and returns the sets to take
/// into use with their times and the drift watch's summary.
///
/// # Errors
/// Unreadable fixes or log, a `--fixes-every-s` or `--fixes-window-s` that
/// is not a positive number, a window shorter than the interval, an
/// unwritable `--learnt-out`.
pub fn learn(
    args: &FixesArgs<'_>,
    config: &Config,
    params: Option<&ParamSet>,
) -> anyhow::Result<Learnt> {
    for (flag, v) in [
        ("--fixes-every-s", Some(args.every_s)),
        ("--fixes-window-s", args.window_s),
    ] {
        if let Some(v) = v.filter(|v| !(v.is_finite() && *v > 0.0)) {
            anyhow::bail!("{flag} {v}: must be a positive number of seconds");
        }
    }
    if let Some(w) = args.window_s.filter(|w| *w < args.every_s) {
        anyhow::bail!(
            "--fixes-window-s {w} is shorter than --fixes-every-s {}: fixes between refits would \
             be seen by none",
            args.every_s
        );
    }
    let path = args.path;
    let fixes = canodom_offline::drive::read_fixes(path)?;
    let drive = super::calibrate_drive::samples_from_log(config, params, args.log, args.interface)?;
    let base = canodom_offline::drive::values_in_use(config, params);
    let epochs = online::learn(
        config,
        base,
        &drive,
        &fixes,
        &canodom_calib::drive::DriveOptions::default(),
        args.every_s,
        args.window_s.unwrap_or(f64::INFINITY),
    );
    if epochs.is_empty() {
        anyhow::bail!(
            "--fixes {}: none of its {} fixes lies within the log's time: are they on the log's \
             clock (Unix seconds, as candump -L writes)?",
            path.display(),
            fixes.len()
        );
    }
    // The drift watch refits on its own, shorter window: a long fit keeps
    // the value from before a change until the change fills most of it.
    let drift = &config.calibration.drift;
    let checks = online::learn(
        config,
        base,
        &drive,
        &fixes,
        &canodom_calib::drive::DriveOptions::default(),
        drift.every_s,
        drift.window_s,
    );
    let watches = online::drift_watch(&checks, &base, &base, &drift.judge, drift.window_s);
    // The refits and the flags in time order (a flag before a refit of
    // the same time).
    let mut lines: Vec<(f64, String)> = epochs.iter().map(|e| (e.t_s, describe(e))).collect();
    let mut first_flag = None;
    for (check, (_, changes)) in checks.iter().zip(&watches) {
        for c in changes {
            lines.push((check.t_s, describe_change(c, check.distance_m)));
            if c.raised && first_flag.is_none() {
                first_flag = Some((c.reading.param.name(), check.t_s, check.distance_m));
            }
        }
    }
    lines.sort_by(|a, b| a.0.total_cmp(&b.0));
    for (_, line) in &lines {
        eprintln!("replay: {line}");
    }
    // Each refit's row shows the watch as it stood at the refit's time.
    let as_of: Vec<Watch> = epochs
        .iter()
        .map(|e| {
            let n = checks.partition_point(|c| c.t_s <= e.t_s);
            n.checked_sub(1)
                .map_or_else(Watch::default, |i| watches[i].0)
        })
        .collect();
    if let Some(out) = args.learnt_out {
        std::fs::write(out, online::learnt_csv(&epochs, &as_of))
            .with_context(|| format!("--learnt-out {}", out.display()))?;
    }
    let distance_m = epochs.last().map_or(0.0, |e| e.distance_m);
    // Refits of fewer fixes than fill the window are not judged: say how
    // many were, so a short drive's "no flag" is not read as "no drift".
    let judged = checks
        .iter()
        .filter(|c| canodom_calib::drift::window_is_full(c.fixes_span_s, drift.window_s))
        .count();
    let refits = format!(
        "{judged} of {} refits judged, each over {:.0} s of fixes",
        checks.len(),
        drift.window_s
    );
    let drift_summary = Some(match first_flag {
        Some((name, t_s, d)) => format!(
            "drift watch: first flag ({name}) at t={t_s:.1} s, {d:.0} m into the drive \
             (of {distance_m:.0} m, {refits})"
        ),
        None if judged == 0 => format!(
            "drift watch: nothing judged over {distance_m:.0} m ({refits}: the fixes never \
             spanned {:.0} % of [calibration.drift] window_s)",
            100.0 * canodom_calib::drift::FULL_WINDOW_SHARE
        ),
        None => format!("drift watch: no flag over {distance_m:.0} m ({refits})"),
    });
    Ok(Learnt {
        switches: switches(params, &epochs),
        drift_summary,
    })
}

/// A drift flag that rose or cleared, in a line: the parameter, its learnt
/// value with σ, the value in use and the distance driven so far. The
/// front tyres' ratio, which no set carries, is judged against its first
/// reading, and its flag says what to check.
pub(crate) fn describe_change(c: &canodom_calib::drift::Change, distance_m: f64) -> String {
    use canodom_calib::drift::Param;
    let r = &c.reading;
    let (against, hint) = match (r.param, c.raised) {
        (Param::FrontRatio, true) => (
            "as first read",
            " — a front tyre's size changed: check its pressure",
        ),
        (Param::FrontRatio, false) => ("as first read", ""),
        _ => ("in use", ""),
    };
    format!(
        "drift: {} {}: learnt {:.6} ± {:.6}, {against} {:.6} ({:.0} m driven){hint}",
        r.param.name(),
        if c.raised { "flagged" } else { "cleared" },
        r.learnt,
        r.sigma,
        r.in_use,
        distance_m
    )
}

/// One refit in a line: when, how many fixes, what it told, and whether
/// its set was taken into use. The front tyres' ratio, which no set
/// carries, is told apart: it is watched, never taken into use.
fn describe(e: &Epoch) -> String {
    let front = canodom_calib::drift::Param::FrontRatio.name();
    let told: Vec<String> = e
        .estimates
        .iter()
        .filter(|(name, _, _, passed)| *passed && *name != front)
        .map(|(name, value, sigma, _)| format!("{name} {value:.6} ± {sigma:.6}"))
        .collect();
    let told = if told.is_empty() {
        "nothing told".to_owned()
    } else {
        told.join(", ")
    };
    let watched = e
        .front_ratio
        .map(|f| {
            format!(
                " (the front tyres' ratio {:.6} ± {:.6}, watched only)",
                f.value, f.sigma
            )
        })
        .unwrap_or_default();
    match &e.refused {
        None => format!(
            "online calibration at t={:.1} s ({} fixes): {told}; taken into use from here{watched}",
            e.t_s, e.fixes
        ),
        Some(why) => format!(
            "online calibration at t={:.1} s ({} fixes): {told}; not taken into use: {why}{watched}",
            e.t_s, e.fixes
        ),
    }
}

/// The accepted refits as parameter sets, numbered on from `params`'s
/// version, each taken into use at its refit's time; a refit that learnt
/// the set already in use adds none.
fn switches(params: Option<&ParamSet>, epochs: &[Epoch]) -> Vec<(Timestamp, ParamSet)> {
    let mut version = params.map_or(0, |p| p.version);
    let mut in_use = params.map(|p| p.values);
    let mut out = Vec::new();
    for e in epochs {
        let Some(values) = e.accepted() else { continue };
        if in_use == Some(*values) {
            continue;
        }
        version = version.saturating_add(1).max(1);
        in_use = Some(*values);
        // The log's clock is Unix seconds: a timestamp in microseconds.
        let micros = (e.t_s * 1e6).round().max(0.0) as u64;
        out.push((
            Timestamp::from_micros(micros),
            ParamSet {
                version,
                created_unix_s: e.t_s.max(0.0) as u64,
                method: "online".to_owned(),
                values: *values,
            },
        ));
    }
    out
}
