//! `replay --fixes`: the drive calibrated against its fixes as it goes
//! ([`canodom_offline::online`]), each set learnt handed to the replay to be
//! taken into use from the time it was learnt.

use anyhow::Context as _;
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
    /// `--learnt-out`.
    pub learnt_out: Option<&'a Path>,
}

/// Learns from the fixes at `args.path` over the drive of `args.log`
/// (recorded with `params` in use), prints each refit, writes
/// `--learnt-out`, and returns the sets to take into use with their times.
///
/// # Errors
/// Unreadable fixes or log, a `--fixes-every-s` that is not a positive
/// number, an unwritable `--learnt-out`.
pub fn learn(
    args: &FixesArgs<'_>,
    config: &Config,
    params: Option<&ParamSet>,
) -> anyhow::Result<Vec<(Timestamp, ParamSet)>> {
    if !(args.every_s.is_finite() && args.every_s > 0.0) {
        anyhow::bail!(
            "--fixes-every-s {}: must be a positive number of seconds",
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
    );
    if epochs.is_empty() {
        anyhow::bail!(
            "--fixes {}: none of its {} fixes lies within the log's time: are they on the log's \
             clock (Unix seconds, as candump -L writes)?",
            path.display(),
            fixes.len()
        );
    }
    for e in &epochs {
        eprintln!("replay: {}", describe(e));
    }
    if let Some(out) = args.learnt_out {
        std::fs::write(out, online::learnt_csv(&epochs))
            .with_context(|| format!("--learnt-out {}", out.display()))?;
    }
    Ok(switches(params, &epochs))
}

/// One refit in a line: when, how many fixes, what it told, and whether
/// its set was taken into use.
fn describe(e: &Epoch) -> String {
    let told: Vec<String> = e
        .estimates
        .iter()
        .filter(|(_, _, _, passed)| *passed)
        .map(|(name, value, sigma, _)| format!("{name} {value:.6} ± {sigma:.6}"))
        .collect();
    let told = if told.is_empty() {
        "nothing told".to_owned()
    } else {
        told.join(", ")
    };
    match &e.refused {
        None => format!(
            "online calibration at t={:.1} s ({} fixes): {told}; taken into use from here",
            e.t_s, e.fixes
        ),
        Some(why) => format!(
            "online calibration at t={:.1} s ({} fixes): {told}; not taken into use: {why}",
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
