//! Atomic, durable file replacement, the one way canodom writes a file that
//! must survive a crash or power loss whole: the parameter file, the state
//! file and calibration reports. A temporary file in the same directory is
//! written and `fsync`ed, renamed over the target (atomic on POSIX file
//! systems), and the directory is `fsync`ed so the rename itself is durable.
//! At any instant the target is the old file or the new one, complete.
//!
//! Kept beside `tempfile`'s `NamedTempFile::persist` (issue #21), which is
//! only the rename: durability needs the same `sync_all` of the file and of
//! the directory by hand, so the crate would save no line here. It would
//! change behaviour (`cargo run --manifest-path
//! bench/crate-probes/Cargo.toml --bin tempfile_persist`, tempfile 3.27):
//! the persisted file is mode 600 where ours is 644 (less umask), so a
//! parameter or report file would stop being readable by other users; each
//! crashed attempt leaves another randomly named `.tmpXXXXXX` behind where
//! ours reuses and truncates its one fixed `.{name}.tmp` (which the state
//! file's tests rely on); and it would add fastrand, rustix and
//! linux-raw-sys to the daemon's dependency tree (`cargo tree -p canodom -e
//! normal`).

use std::fs::{self, File, OpenOptions};
use std::io::Write as _;
use std::os::unix::fs::OpenOptionsExt as _;
use std::path::{Path, PathBuf};

/// An I/O failure of [`write`](fn@write), naming the path that failed (the
/// temporary file, the target or the directory); the previous target is then
/// untouched.
#[derive(Debug, thiserror::Error)]
#[error("{}: {source}", path.display())]
pub struct AtomicWriteError {
    /// The path whose operation failed.
    pub path: PathBuf,
    /// The OS error.
    pub source: std::io::Error,
}

/// The temporary file [`write`](fn@write) uses for `path`: hidden, same directory.
pub fn temp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map_or_else(|| "file".into(), |n| n.to_string_lossy());
    path.with_file_name(format!(".{name}.tmp"))
}

/// Replaces `path` by `bytes` atomically and durably (see the module doc).
///
/// Each file has one writer (one daemon, one report per version), so a fixed
/// temporary name is safe; truncation discards the half-written leftover of
/// a crashed earlier attempt.
///
/// # Errors
/// [`AtomicWriteError`] naming the path that failed.
pub fn write(path: &Path, bytes: &[u8]) -> Result<(), AtomicWriteError> {
    let failed = |p: &Path| {
        let p = p.to_owned();
        move |source| AtomicWriteError { path: p, source }
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_owned(),
        _ => PathBuf::from("."),
    };
    let tmp = temp_path(path);
    let mut f = OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .mode(0o644)
        .open(&tmp)
        .map_err(failed(&tmp))?;
    f.write_all(bytes).map_err(failed(&tmp))?;
    f.sync_all().map_err(failed(&tmp))?;
    drop(f);
    fs::rename(&tmp, path).map_err(failed(path))?;
    File::open(&dir)
        .and_then(|d| d.sync_all())
        .map_err(failed(&dir))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(tag: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("canodom-atomic-{tag}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn replaces_the_file_and_leaves_no_temporary() {
        let dir = scratch("replace");
        let path = dir.join("a.toml");
        write(&path, b"old\n").unwrap();
        write(&path, b"new\n").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"new\n");
        assert!(!temp_path(&path).exists());
    }

    #[test]
    fn a_failure_names_the_path_and_keeps_the_old_file() {
        let dir = scratch("fail");
        let path = dir.join("missing-dir").join("a.toml");
        let e = write(&path, b"x").unwrap_err();
        assert!(e.to_string().contains("missing-dir"), "{e}");
    }
}
