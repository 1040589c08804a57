//! `[security]`: the SecOC key, the freshness files and the lockout
//! (issue #22), validated once at load (the gate that uses them is
//! [`crate::gate`]).
//!
//! ```toml
//! [security]
//! key_file = "canodom.key"     # 32 hex digits, mode 0600 (refused if group or others may read it)
//! freshness_file = "canodom-freshness"        # default: beside the parameter file
//! operator_freshness_file = "operator-freshness"  # `canodom calib`'s counter (default: ~/.local/state/canodom/)
//! lockout_failures = 10        # this many failed authentications ...
//! lockout_window_s = 10.0      # ... within this window ...
//! lockout_s = 60.0             # ... lock secured frames out this long
//! allow_without_key = true     # false: a configuration without key_file is refused
//! ```
//!
//! Without `key_file` nothing is authenticated: commands are judged by
//! their CRC, rolling counter and the optional arming code only, which stop
//! mistakes, not an attacker (see the README).

use canodom_can::frame::FrameId;
use canodom_protocol::own_dbc::{BaseId, OwnFrame};
use canodom_protocol::secoc::{Key, Link};
use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Default name of the daemon's freshness file, beside the parameter file.
pub const DEFAULT_FRESHNESS_FILE: &str = "canodom-freshness";

/// `[security]` as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct RawSecurity {
    key_file: Option<PathBuf>,
    freshness_file: Option<PathBuf>,
    operator_freshness_file: Option<PathBuf>,
    lockout_failures: u32,
    lockout_window_s: f64,
    lockout_s: f64,
    allow_without_key: bool,
}

impl Default for RawSecurity {
    fn default() -> Self {
        Self {
            key_file: None,
            freshness_file: None,
            operator_freshness_file: None,
            lockout_failures: 10,
            lockout_window_s: 10.0,
            lockout_s: 60.0,
            allow_without_key: true,
        }
    }
}

/// The validated `[security]` section.
#[derive(Clone, Debug, PartialEq)]
pub struct SecurityConfig {
    /// The key, read and checked at load; `None`: nothing is authenticated.
    pub key: Option<Key>,
    /// Where the key came from (for messages).
    pub key_file: Option<PathBuf>,
    /// The daemon's freshness values (default beside the parameter file).
    pub freshness_file: PathBuf,
    /// `canodom calib`'s own counter: as configured, else
    /// `$XDG_STATE_HOME/canodom/operator-freshness`, else
    /// `$HOME/.local/state/canodom/operator-freshness`, else beside the
    /// configuration (its folder is created when the client first signs).
    pub operator_freshness_file: PathBuf,
    /// Failed authentications within [`Self::lockout_window`] that lock out (≥ 1).
    pub lockout_failures: u32,
    /// The window the failures are counted in.
    pub lockout_window: Duration,
    /// How long a lockout lasts.
    pub lockout: Duration,
}

/// Why a key file is refused.
#[derive(Debug, thiserror::Error)]
pub enum KeyFileError {
    /// Cannot be read.
    #[error("cannot read: {0}")]
    Io(#[from] std::io::Error),
    /// Not a regular file.
    #[error("not a regular file")]
    NotAFile,
    /// Group or others have any access.
    #[error(
        "mode {mode:04o} lets group or others access the key (a key others can read is no secret): chmod 600 it"
    )]
    Permissions {
        /// The file's permission bits.
        mode: u32,
    },
    /// The content is not a key.
    #[error("{0}")]
    Malformed(#[from] canodom_protocol::secoc::KeyError),
}

/// Reads a key file: a regular file, no access for group or others
/// (`mode & 0o077 == 0`), 32 hexadecimal digits.
///
/// # Errors
/// [`KeyFileError`].
pub fn read_key_file(path: &Path) -> Result<Key, KeyFileError> {
    use std::os::unix::fs::PermissionsExt as _;
    let meta = std::fs::metadata(path)?;
    if !meta.is_file() {
        return Err(KeyFileError::NotAFile);
    }
    let mode = meta.permissions().mode() & 0o7777;
    if mode & 0o077 != 0 {
        return Err(KeyFileError::Permissions { mode });
    }
    let text = std::fs::read_to_string(path)?;
    Ok(Key::parse(&text)?)
}

/// A `[security]` value that cannot be used; the configuration names its file.
#[derive(Debug)]
pub(crate) enum SecurityError {
    /// A value out of its range: key, what was expected, what was found.
    Invalid(String, String, String),
    /// The key file and why it is refused.
    KeyFile(PathBuf, String),
}

/// Validates `[security]`; relative paths are taken from the configuration's
/// folder, the default freshness file goes beside `param_file`.
pub(crate) fn validate(
    file: &Path,
    raw: &RawSecurity,
    param_file: &Path,
) -> Result<SecurityConfig, SecurityError> {
    let invalid = |key: &str, expected: &str, got: String| {
        SecurityError::Invalid(key.to_owned(), expected.to_owned(), got)
    };
    let beside = |p: &Path| file.parent().unwrap_or(Path::new(".")).join(p);
    if raw.lockout_failures == 0 {
        return Err(invalid(
            "security.lockout_failures",
            "an integer >= 1",
            "0".into(),
        ));
    }
    let secs = |key: &str, v: f64| {
        if v.is_finite() && v > 0.0 && v < 1e9 {
            Ok(Duration::from_secs_f64(v))
        } else {
            Err(invalid(key, "a number of seconds > 0", v.to_string()))
        }
    };
    let key_file = raw.key_file.as_deref().map(beside);
    let key = match &key_file {
        Some(path) => Some(
            read_key_file(path).map_err(|e| SecurityError::KeyFile(path.clone(), e.to_string()))?,
        ),
        None if !raw.allow_without_key => {
            return Err(invalid(
                "security.key_file",
                "a key file (allow_without_key = false refuses to run without one)",
                "none".into(),
            ));
        }
        None => None,
    };
    Ok(SecurityConfig {
        key,
        key_file,
        freshness_file: raw
            .freshness_file
            .as_deref()
            .map_or_else(|| param_file.with_file_name(DEFAULT_FRESHNESS_FILE), beside),
        operator_freshness_file: raw.operator_freshness_file.as_deref().map_or_else(
            || {
                std::env::var_os("XDG_STATE_HOME")
                    .map(PathBuf::from)
                    .or_else(|| {
                        std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".local/state"))
                    })
                    .map_or_else(
                        || beside(Path::new("operator-freshness")),
                        |state| state.join("canodom/operator-freshness"),
                    )
            },
            beside,
        ),
        lockout_failures: raw.lockout_failures,
        lockout_window: secs("security.lockout_window_s", raw.lockout_window_s)?,
        lockout: secs("security.lockout_s", raw.lockout_s)?,
    })
}

/// The SecOC DataId of an id as the freshness file keys it.
pub fn data_id(id: FrameId) -> u32 {
    match id {
        FrameId::Standard(s) => u32::from(s),
        FrameId::Extended(e) => e | 0x8000_0000,
    }
}

/// The secured frames canodom receives and their authenticators.
pub fn receive_links(base: BaseId, calib_cmd_id: FrameId) -> [Link; 3] {
    [
        Link {
            secured: OwnFrame::OdomCmd.id(base),
            authenticator: OwnFrame::OdomCmdAuth.id(base),
        },
        Link {
            secured: calib_cmd_id,
            authenticator: OwnFrame::CalibCmdAuth.id(base),
        },
        Link {
            secured: OwnFrame::CalibAck.id(base),
            authenticator: OwnFrame::CalibAckAuth.id(base),
        },
    ]
}
