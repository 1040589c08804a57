//! The one error type of the calib crate.

/// Everything that can go wrong while calibrating.
///
/// Variants carry the offending value and what was being done, so that a
/// message read in a log explains itself without the source at hand.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Error {
    /// An argument is outside its valid range (not finite, not positive, ...).
    #[error("invalid argument `{name}`: {value} ({reason})")]
    InvalidArgument {
        /// The argument's name, with its unit.
        name: &'static str,
        /// The rejected value.
        value: f64,
        /// What was expected.
        reason: &'static str,
    },
    /// A method needs runs that were not supplied.
    #[error("not enough runs: {needed} (got {got} CCW and {got_cw} CW)")]
    NotEnoughRuns {
        /// What the method needs, in words.
        needed: &'static str,
        /// Counter-clockwise runs supplied.
        got: usize,
        /// Clockwise runs supplied.
        got_cw: usize,
    },
    /// A linear system was singular or a result was not finite.
    #[error("numerical failure in {context}")]
    Numerical {
        /// What was being computed.
        context: &'static str,
    },
    /// The refinement closed the runs' positions with a wrong number of
    /// turns (`docs/calibration-math.md` §7): the odometry turn of one run is more
    /// than π/2 away from the true turn.
    #[error("false closure on run {run}: odometry turn off by {turn_error_rad} rad")]
    FalseClosure {
        /// Index of the offending run in the input.
        run: usize,
        /// θ_odo − Θ of that run.
        turn_error_rad: f64,
    },
    /// A drive calibration got too few position fixes (in all, or left in
    /// segments long enough to use).
    #[error("not enough position fixes: {got} {what}, at least {needed} needed")]
    NotEnoughFixes {
        /// Which fixes were counted, in words.
        what: &'static str,
        /// How many there were.
        got: usize,
        /// How many the estimator needs.
        needed: usize,
    },
    /// A drive calibration got fewer than two odometry samples.
    #[error("not enough odometry samples: {got}, at least 2 needed")]
    NotEnoughSamples {
        /// How many there were.
        got: usize,
    },
    /// A value of a drive sample or a fix is not finite.
    #[error("{what} {index}: `{field}` is not finite ({value})")]
    NotFinite {
        /// "sample" or "fix".
        what: &'static str,
        /// Its index in the input.
        index: usize,
        /// The field, with its unit.
        field: &'static str,
        /// The rejected value.
        value: f64,
    },
    /// Times of samples or fixes do not strictly increase.
    #[error("{what} {index}: time {t_s} s does not follow the previous one ({previous_s} s)")]
    NotIncreasing {
        /// "sample" or "fix".
        what: &'static str,
        /// Index of the offending entry.
        index: usize,
        /// Its time.
        t_s: f64,
        /// The previous entry's time.
        previous_s: f64,
    },
    /// A fix lies outside the time span the odometry samples cover.
    #[error("fix {index} at {t_s} s lies outside the samples' span {first_s}..{last_s} s")]
    FixOutsideSamples {
        /// Index of the fix.
        index: usize,
        /// Its time.
        t_s: f64,
        /// The first sample's time.
        first_s: f64,
        /// The last sample's time.
        last_s: f64,
    },
    /// A fixes (or reference trajectory) CSV that cannot be read.
    #[error("{name}{}: {reason}", if *line > 0 { format!(":{line}") } else { String::new() })]
    FixesText {
        /// The file, as the user named it.
        name: String,
        /// 1-based line (1: the header; 0: the file as a whole).
        line: usize,
        /// What is wrong there.
        reason: String,
    },
    /// A vehicle parameter set could not be built from the result.
    #[error(transparent)]
    Fusion(#[from] canodom_fusion::Error),
}

/// The calib crate's result type.
pub type Result<T> = std::result::Result<T, Error>;

/// `Ok(value)` when finite, else [`Error::Numerical`].
pub(crate) fn finite(context: &'static str, value: f64) -> Result<f64> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(Error::Numerical { context })
    }
}

/// `Ok(value)` when finite and > 0, else [`Error::InvalidArgument`].
pub(crate) fn positive(name: &'static str, value: f64) -> Result<f64> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(Error::InvalidArgument {
            name,
            value,
            reason: "must be finite and > 0",
        })
    }
}
