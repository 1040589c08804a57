//! `[security]`: the SecOC keys, the freshness files and the acceptance
//! window (issues #22, #33, #44), validated once at load (the gate that
//! uses them is [`crate::gate`]).
//!
//! ```toml
//! [security]
//! key_file = "canodom.keys"    # this party's key file from `canodom keys derive`, mode 0600
//!                              # default: $CREDENTIALS_DIRECTORY/canodom.keys (systemd LoadCredential=)
//! freshness_file = "canodom-freshness"        # default: beside the parameter file
//! operator_freshness_file = "operator-freshness"  # `canodom calib`'s counter (default: ~/.local/state/canodom/)
//! freshness_window_s = 5.0     # a frame is accepted this long after the SECOC_SYNC it was signed by
//! allow_without_key = false    # true: a bench without keys (nothing authenticated)
//! ```
//!
//! Secure by default: a `[security]` section without a key is refused at
//! load, and `canodom run` refuses to start without a key unless
//! `allow_without_key = true` says this is a bench. Without a key nothing
//! is authenticated: commands are judged by their CRC, rolling counter and
//! the optional arming code only, which stop mistakes, not an attacker.

use canodom_can::frame::FrameId;
use canodom_protocol::own_dbc::{BaseId, OwnFrame};
use canodom_protocol::secoc::Link;
use canodom_protocol::secoc_keys::{KeySet, KeySetError};
use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::time::Duration;
use zeroize::Zeroizing;

/// Default name of the daemon's freshness file, beside the parameter file.
pub const DEFAULT_FRESHNESS_FILE: &str = "canodom-freshness";

/// The credential name the key file is looked up under in
/// `$CREDENTIALS_DIRECTORY` when `key_file` is not set (systemd's
/// `LoadCredential=canodom.keys:/etc/canodom/canodom.keys`).
pub const KEY_CREDENTIAL: &str = "canodom.keys";

/// Largest key file read, bytes (a key file is a few hundred).
const MAX_KEY_FILE: u64 = 16 * 1024;

/// `[security]` as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct RawSecurity {
    key_file: Option<PathBuf>,
    freshness_file: Option<PathBuf>,
    operator_freshness_file: Option<PathBuf>,
    freshness_window_s: f64,
    allow_without_key: bool,
}

impl Default for RawSecurity {
    fn default() -> Self {
        Self {
            key_file: None,
            freshness_file: None,
            operator_freshness_file: None,
            freshness_window_s: f64::from(canodom_protocol::secoc::DEFAULT_WINDOW_TICKS)
                * canodom_protocol::secoc::SYNC_PERIOD_US as f64
                / 1e6,
            allow_without_key: false,
        }
    }
}

/// The validated `[security]` section.
#[derive(Clone, Debug, PartialEq)]
pub struct SecurityConfig {
    /// This party's keys, read and checked at load; `None`: nothing is
    /// authenticated (only with `allow_without_key`, or without a
    /// `[security]` section, which `canodom run` then refuses).
    pub keys: Option<KeySet>,
    /// Where the keys came from (for messages).
    pub key_file: Option<PathBuf>,
    /// `allow_without_key = true`: a bench that runs without keys on purpose.
    pub allow_without_key: bool,
    /// The daemon's freshness values (default beside the parameter file).
    pub freshness_file: PathBuf,
    /// `canodom calib`'s own counter: as configured, else
    /// `$XDG_STATE_HOME/canodom/operator-freshness`, else
    /// `$HOME/.local/state/canodom/operator-freshness`, else beside the
    /// configuration (its folder is created when the client first signs).
    pub operator_freshness_file: PathBuf,
    /// How long after the `SECOC_SYNC` it was signed by a secured frame
    /// is accepted (on the daemon's monotonic clock; whole announcement
    /// periods, at least one).
    pub freshness_window: Duration,
}

impl SecurityConfig {
    /// The acceptance window in announcements ([`Self::freshness_window`]
    /// rounded up to whole [`canodom_protocol::secoc::SYNC_PERIOD_US`]).
    pub fn window_ticks(&self) -> u32 {
        let period = canodom_protocol::secoc::SYNC_PERIOD_US as u128;
        (self.freshness_window.as_micros().div_ceil(period)).clamp(1, u128::from(u32::MAX)) as u32
    }
}

/// Why a key file is refused.
#[derive(Debug, thiserror::Error)]
pub enum KeyFileError {
    /// Cannot be opened or read.
    #[error("cannot read: {0}")]
    Io(#[from] std::io::Error),
    /// A symbolic link, or a path through a linked folder: refused rather
    /// than followed (it could be swapped between a check and the read).
    #[error(
        "is a symbolic link or lies in a linked folder; give the real path (a key file is \
         opened without following any link)"
    )]
    Symlink,
    /// Not a regular file (a FIFO, a device, a folder): refused at once,
    /// never read from.
    #[error("not a regular file")]
    NotAFile,
    /// Owned by another user than the one reading it (or root).
    #[error("owned by uid {owner}, not by the user reading it (uid {reader}) or root: chown it")]
    Owner {
        /// The file's owner.
        owner: u32,
        /// The effective uid of this process.
        reader: u32,
    },
    /// Group or others have any access.
    #[error(
        "mode {mode:04o} lets group or others access the key (a key others can read is no secret): chmod 600 it"
    )]
    Permissions {
        /// The file's permission bits.
        mode: u32,
    },
    /// Larger than any key file.
    #[error("{0} bytes: too large for a key file")]
    TooLarge(u64),
    /// The content is not a key file.
    #[error("{0}")]
    Malformed(#[from] KeySetError),
}

/// Reads a key file safely (see [`read_secret_file`]) and parses it as a
/// [`KeySet`].
///
/// # Errors
/// [`KeyFileError`].
pub fn read_key_file(path: &Path) -> Result<KeySet, KeyFileError> {
    let text = read_secret_file(path, Access::OwnerOnly)?;
    Ok(KeySet::parse(&text)?)
}

/// Who besides the owner may hold a read permission on a secret.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// No access for group or others at all (`chmod 600`).
    OwnerOnly,
    /// systemd's credentials (`LoadCredential=`): a root-owned 0400 file to
    /// which systemd adds an ACL entry for the service's user, which `stat`
    /// shows as the group read bit (the ACL mask). The folder is private to
    /// the service; group write or any access for others is still refused.
    SystemdCredential,
}

/// Reads a key file that systemd passed as a credential (see
/// [`Access::SystemdCredential`]).
///
/// # Errors
/// [`KeyFileError`].
pub fn read_credential_key_file(path: &Path) -> Result<KeySet, KeyFileError> {
    let text = read_secret_file(path, Access::SystemdCredential)?;
    Ok(KeySet::parse(&text)?)
}

/// Reads a secret (a key file, a master key): opened without following a
/// symbolic link anywhere on its path (`openat2` with
/// `RESOLVE_NO_SYMLINKS`: a linked folder is refused as a linked file is,
/// since whoever can swap either can swap the key) and without blocking
/// (`O_NONBLOCK`: a FIFO or a device opens at once and is refused by the
/// check below instead of stalling the start), then checked on the open
/// descriptor (`fstat`: a regular file, owned by this process's user or
/// root, no access for group or others), read into memory that is wiped
/// when the returned text is dropped. `access` says which permission bits
/// besides the owner's are tolerated.
///
/// # Errors
/// [`KeyFileError`].
pub fn read_secret_file(path: &Path, access: Access) -> Result<Zeroizing<String>, KeyFileError> {
    use std::io::Read as _;
    use std::os::unix::fs::MetadataExt as _;
    let mut file = open_no_symlinks(path)?;
    let meta = file.metadata()?;
    if !meta.is_file() {
        return Err(KeyFileError::NotAFile);
    }
    let reader = nix::unistd::geteuid().as_raw();
    if meta.uid() != reader && meta.uid() != 0 {
        return Err(KeyFileError::Owner {
            owner: meta.uid(),
            reader,
        });
    }
    let mode = meta.mode() & 0o7777;
    let tolerated = match access {
        Access::OwnerOnly => 0,
        Access::SystemdCredential => 0o040,
    };
    if mode & 0o077 & !tolerated != 0 {
        return Err(KeyFileError::Permissions { mode });
    }
    if meta.len() > MAX_KEY_FILE {
        return Err(KeyFileError::TooLarge(meta.len()));
    }
    // Room for all of it up front: no reallocation leaves a copy behind.
    let mut bytes = Zeroizing::new(Vec::with_capacity(MAX_KEY_FILE as usize + 1));
    file.by_ref()
        .take(MAX_KEY_FILE + 1)
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > MAX_KEY_FILE {
        return Err(KeyFileError::TooLarge(bytes.len() as u64));
    }
    if std::str::from_utf8(&bytes).is_err() {
        return Err(KeyFileError::Malformed(KeySetError::Line {
            line: 1,
            what: "not UTF-8 text".into(),
        }));
    }
    let mut text = Zeroizing::new(String::with_capacity(bytes.len()));
    text.push_str(std::str::from_utf8(&bytes).unwrap_or_default());
    Ok(text)
}

/// Opens `path` read-only, non-blocking, refusing a symbolic link in any
/// component of it (see [`read_secret_file`]).
fn open_no_symlinks(path: &Path) -> Result<std::fs::File, KeyFileError> {
    use nix::fcntl::{OFlag, OpenHow, ResolveFlag, openat2};
    let how = OpenHow::new()
        .flags(
            OFlag::O_RDONLY
                | OFlag::O_NOFOLLOW
                | OFlag::O_CLOEXEC
                | OFlag::O_NOCTTY
                | OFlag::O_NONBLOCK,
        )
        .resolve(ResolveFlag::RESOLVE_NO_SYMLINKS);
    match openat2(nix::fcntl::AT_FDCWD, path, how) {
        Ok(fd) => Ok(std::fs::File::from(fd)),
        Err(nix::errno::Errno::ELOOP) => Err(KeyFileError::Symlink),
        Err(nix::errno::Errno::ENOSYS) => {
            // Linux before 5.6 has no openat2: every folder on the way is
            // checked first (a narrow race with whoever can write to one of
            // them), then the file opened without following a link.
            use std::os::unix::fs::OpenOptionsExt as _;
            let absolute = std::path::absolute(path)?;
            if absolute.ancestors().skip(1).any(|a| {
                a.symlink_metadata()
                    .is_ok_and(|m| m.file_type().is_symlink())
            }) {
                return Err(KeyFileError::Symlink);
            }
            std::fs::OpenOptions::new()
                .read(true)
                .custom_flags(
                    libc::O_NOFOLLOW | libc::O_CLOEXEC | libc::O_NOCTTY | libc::O_NONBLOCK,
                )
                .open(path)
                .map_err(|e| {
                    if e.raw_os_error() == Some(libc::ELOOP) {
                        KeyFileError::Symlink
                    } else {
                        KeyFileError::Io(e)
                    }
                })
        }
        Err(e) => Err(KeyFileError::Io(e.into())),
    }
}

/// A `[security]` value that cannot be used; the configuration names its file.
#[derive(Debug)]
pub(crate) enum SecurityError {
    /// A value out of its range: key, what was expected, what was found.
    Invalid(String, String, String),
    /// The key file and why it is refused.
    KeyFile(PathBuf, String),
}

/// Validates `[security]` (`None`: no section); relative paths are taken
/// from the configuration's folder, the default freshness file goes beside
/// `param_file`, and without `key_file` the key file is
/// `$CREDENTIALS_DIRECTORY/`[`KEY_CREDENTIAL`] when systemd passes one.
pub(crate) fn validate(
    file: &Path,
    section: Option<&RawSecurity>,
    param_file: &Path,
) -> Result<SecurityConfig, SecurityError> {
    let defaults = RawSecurity::default();
    let raw = section.unwrap_or(&defaults);
    let invalid = |key: &str, expected: &str, got: String| {
        SecurityError::Invalid(key.to_owned(), expected.to_owned(), got)
    };
    let beside = |p: &Path| file.parent().unwrap_or(Path::new(".")).join(p);
    let secs = |key: &str, v: f64, max: f64| {
        if v.is_finite() && v > 0.0 && v <= max {
            Ok(Duration::from_secs_f64(v))
        } else {
            Err(invalid(
                key,
                &format!("a number of seconds > 0 and <= {max}"),
                v.to_string(),
            ))
        }
    };
    let credential = std::env::var_os("CREDENTIALS_DIRECTORY")
        .map(|d| PathBuf::from(d).join(KEY_CREDENTIAL))
        .filter(|p| p.symlink_metadata().is_ok());
    #[allow(clippy::type_complexity)]
    let (key_file, read): (Option<PathBuf>, fn(&Path) -> Result<KeySet, KeyFileError>) =
        match raw.key_file.as_deref() {
            Some(p) => (Some(beside(p)), read_key_file),
            None => (credential, read_credential_key_file),
        };
    let keys = match &key_file {
        Some(path) => {
            Some(read(path).map_err(|e| SecurityError::KeyFile(path.clone(), e.to_string()))?)
        }
        None if section.is_some() && !raw.allow_without_key => {
            return Err(invalid(
                "security.key_file",
                "a key file: key_file, or $CREDENTIALS_DIRECTORY/canodom.keys from systemd's \
                 LoadCredential= (a [security] section needs its keys; `allow_without_key = true` \
                 runs a bench without them)",
                "none".into(),
            ));
        }
        None => None,
    };
    Ok(SecurityConfig {
        keys,
        key_file,
        allow_without_key: raw.allow_without_key,
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
        freshness_window: secs("security.freshness_window_s", raw.freshness_window_s, 600.0)?,
    })
}

/// The SecOC DataId of an id as the freshness file keys it.
pub fn data_id(id: FrameId) -> u32 {
    match id {
        FrameId::Standard(s) => u32::from(s),
        FrameId::Extended(e) => e | 0x8000_0000,
    }
}

/// The daemon's announcement (`SECOC_SYNC`) and its authenticators' id.
pub fn sync_link(base: BaseId) -> Link {
    Link {
        secured: OwnFrame::SecocSync.id(base),
        authenticator: OwnFrame::SecocSyncAuth.id(base),
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
