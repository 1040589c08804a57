//! The crate's one error type: every variant names what was being loaded,
//! looked up or encoded, so a daemon log line is enough to find the fault.

use std::path::PathBuf;

/// Everything that can go wrong while loading a DBC file or using its codecs.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// The DBC file could not be read.
    #[error("cannot read DBC file {path}: {source}")]
    Io {
        /// The file that was asked for.
        path: PathBuf,
        /// Why the operating system refused.
        source: std::io::Error,
    },

    /// The DBC text does not parse.
    #[error("{source_name}:{}: DBC syntax error: {detail}", location(*.line, *.column))]
    Parse {
        /// File name (or caller-chosen name) of the text.
        source_name: String,
        /// 1-based line of the fault, when the parser reports one.
        line: Option<usize>,
        /// 1-based column of the fault, when the parser reports one.
        column: Option<usize>,
        /// The parser's own description, including the text near the fault.
        detail: String,
    },

    /// A message definition cannot be used (bad frame ID, bad length, duplicate ID).
    #[error("{source_name}: message {message}: {reason}")]
    InvalidMessage {
        /// File name (or caller-chosen name) of the text.
        source_name: String,
        /// Name of the message at fault.
        message: String,
        /// What is wrong with it.
        reason: String,
    },

    /// A signal cannot be compiled (size 0 or above 64, past the frame end, bad float size,
    /// unresolvable multiplexing).
    #[error("{source_name}: message {message}, signal {signal}: {reason}")]
    InvalidSignal {
        /// File name (or caller-chosen name) of the text.
        source_name: String,
        /// Name of the message holding the signal.
        message: String,
        /// Name of the signal at fault.
        signal: String,
        /// What is wrong with it.
        reason: String,
    },

    /// `Database::signal` was asked for a name that is not `MESSAGE.SIGNAL` or does not exist.
    #[error("unknown signal {looked_for:?}: {reason}")]
    UnknownSignal {
        /// The full name that was looked for.
        looked_for: String,
        /// Which part was missing.
        reason: String,
    },

    /// `Database::signal` was asked for a signal of a message that was left out at load
    /// because it cannot be compiled (see [`crate::LoadWarning`]).
    #[error("{looked_for:?} cannot be used: {warning}")]
    LeftOut {
        /// The full name that was looked for.
        looked_for: String,
        /// Why its message was left out: file, message, signal and reason.
        warning: crate::LoadWarning,
    },

    /// A message name that is not in the database.
    #[error("unknown message {0:?}")]
    UnknownMessage(String),

    /// The frame is shorter than the message's length (its DLC is too small).
    #[error("message {message}: frame has {got} data bytes, the message needs {expected}")]
    ShortFrame {
        /// Name of the message the frame was decoded as.
        message: String,
        /// Length the DBC gives the message, in bytes.
        expected: usize,
        /// Length of the frame that arrived, in bytes.
        got: usize,
    },

    /// A physical value whose raw value does not fit the signal's bits (or is NaN).
    #[error(
        "message {message}, signal {signal}: value {value} is outside the encodable range [{min}, {max}]"
    )]
    OutOfRange {
        /// Name of the message holding the signal.
        message: String,
        /// Name of the signal.
        signal: String,
        /// The physical value that was asked for.
        value: f64,
        /// Smallest encodable physical value.
        min: f64,
        /// Largest encodable physical value.
        max: f64,
    },

    /// `Message::encode` was not given a value for a signal the frame carries.
    #[error("message {message}: no value given for signal {signal}")]
    MissingSignal {
        /// Name of the message being encoded.
        message: String,
        /// The signal that needs a value.
        signal: String,
    },

    /// A value was given for a multiplexed signal that the multiplexor value does not select.
    #[error("message {message}: signal {signal} is not selected by the multiplexor value")]
    InactiveSignal {
        /// Name of the message being encoded.
        message: String,
        /// The signal the multiplexor does not select.
        signal: String,
    },

    /// A counter or checksum description that cannot work (bad bit count, byte range, …).
    #[error("invalid frame check: {0}")]
    InvalidCheck(String),
}

fn location(line: Option<usize>, column: Option<usize>) -> String {
    match (line, column) {
        (Some(l), Some(c)) => format!("{l}:{c}"),
        (Some(l), None) => format!("{l}"),
        _ => "?".to_owned(),
    }
}

/// The crate's result type.
pub type Result<T> = std::result::Result<T, Error>;
