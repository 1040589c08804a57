//! The SecOC freshness values that must survive a restart (issue #22): per
//! secured frame id, the last value a receiver accepted (`rx`) and the
//! highest value a sender reserved (`tx`).
//!
//! Every change is written ahead: the file is replaced atomically and
//! durably ([`crate::atomic_file`]) *before* the caller acts on the value,
//! and the value in memory changes only once the file holds it. A crash at
//! any instant therefore leaves a file whose `rx` is at least every value
//! acted on and whose `tx` is at least every value sent, so a frame
//! captured before a restart is refused after it and a sender never reuses
//! a value.
//!
//! The format is a line per id, readable with `cat`:
//!
//! ```text
//! # canodom SecOC freshness values ...
//! rx 0x00000610 1764000123456
//! tx 0x00000612 1764000190064
//! ```
//!
//! Values are SecOC profile 2 freshness values: milliseconds since the
//! Unix epoch (issue #33). A file of profile 1 (seconds, below 2^32) loads
//! as values far in the past, which refuse nothing that the acceptance
//! window does not refuse anyway.
//!
//! The id is the SecOC DataId (bit 31 set for an extended id). A missing
//! file is an empty store (a first start): since a value is accepted only
//! within a few seconds of the receiver's clock, losing the file reopens at
//! most the frames of that last window, never an old recording. A damaged
//! file is an error naming the file and the line, never silently an empty
//! store.

use crate::atomic_file::{self, AtomicWriteError};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Why the freshness file cannot be read or written.
#[derive(Debug, thiserror::Error)]
pub enum FreshnessError {
    /// Reading failed (other than a missing file).
    #[error("{}: cannot read: {source}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// A line is not `rx|tx 0xID VALUE`.
    #[error(
        "{}: line {line}: expected `rx 0xID VALUE` or `tx 0xID VALUE`, got {got:?} \
         (the file is damaged; removing it reopens the frames of the last few seconds only)",
        path.display()
    )]
    Malformed {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// The line.
        got: String,
    },
    /// Writing failed; the value was not stored.
    #[error("freshness file: {0}")]
    Write(#[from] AtomicWriteError),
}

/// Direction of a stored value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Dir {
    Rx,
    Tx,
}

/// The freshness file and its values (see the module doc).
#[derive(Debug, Clone)]
pub struct FreshnessFile {
    path: PathBuf,
    values: BTreeMap<(Dir, u32), u64>,
}

impl FreshnessFile {
    /// Loads `path`; a missing file is an empty store.
    ///
    /// # Errors
    /// [`FreshnessError::Read`], [`FreshnessError::Malformed`].
    pub fn load(path: &Path) -> Result<Self, FreshnessError> {
        let text = match std::fs::read_to_string(path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => String::new(),
            Err(source) => {
                return Err(FreshnessError::Read {
                    path: path.to_owned(),
                    source,
                });
            }
        };
        let mut values = BTreeMap::new();
        for (i, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let bad = || FreshnessError::Malformed {
                path: path.to_owned(),
                line: i + 1,
                got: line.to_owned(),
            };
            let mut it = line.split_whitespace();
            let dir = match it.next() {
                Some("rx") => Dir::Rx,
                Some("tx") => Dir::Tx,
                _ => return Err(bad()),
            };
            let id = it
                .next()
                .and_then(|t| t.strip_prefix("0x"))
                .and_then(|h| u32::from_str_radix(h, 16).ok())
                .ok_or_else(bad)?;
            let value = it
                .next()
                .and_then(|t| t.parse::<u64>().ok())
                .ok_or_else(bad)?;
            if it.next().is_some() || values.insert((dir, id), value).is_some() {
                return Err(bad());
            }
        }
        Ok(Self {
            path: path.to_owned(),
            values,
        })
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The last value accepted from `data_id`.
    pub fn rx(&self, data_id: u32) -> Option<u64> {
        self.values.get(&(Dir::Rx, data_id)).copied()
    }

    /// The highest value reserved for sending on `data_id`.
    pub fn tx(&self, data_id: u32) -> Option<u64> {
        self.values.get(&(Dir::Tx, data_id)).copied()
    }

    /// Stores `value` as the last accepted from `data_id`, durably, before
    /// the caller accepts the frame.
    ///
    /// # Errors
    /// [`FreshnessError::Write`]; the store is then unchanged.
    pub fn record_rx(&mut self, data_id: u32, value: u64) -> Result<(), FreshnessError> {
        self.set(Dir::Rx, data_id, value)
    }

    /// Stores `value` as reserved for sending on `data_id`, durably, before
    /// the caller sends any value up to it.
    ///
    /// # Errors
    /// [`FreshnessError::Write`]; the store is then unchanged.
    pub fn reserve_tx(&mut self, data_id: u32, value: u64) -> Result<(), FreshnessError> {
        self.set(Dir::Tx, data_id, value)
    }

    fn set(&mut self, dir: Dir, data_id: u32, value: u64) -> Result<(), FreshnessError> {
        let mut next = self.values.clone();
        next.insert((dir, data_id), value);
        atomic_file::write(&self.path, render(&next).as_bytes())?;
        self.values = next;
        Ok(())
    }
}

fn render(values: &BTreeMap<(Dir, u32), u64>) -> String {
    let mut s = String::from(
        "# canodom SecOC freshness values (issue #22), replaced atomically before each use.\n\
         # rx: last value accepted per secured id; tx: highest value reserved for sending.\n\
         # Values are ms since the Unix epoch (SecOC profile 2, issue #33).\n",
    );
    for (&(dir, id), value) in values {
        let d = match dir {
            Dir::Rx => "rx",
            Dir::Tx => "tx",
        };
        let _ = writeln!(s, "{d} {id:#010x} {value}");
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(tag: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("canodom-freshness-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir.join("canodom-freshness")
    }

    #[test]
    fn auth_freshness_values_survive_a_reload_and_a_missing_file_is_empty() {
        let path = scratch("reload");
        let mut f = FreshnessFile::load(&path).unwrap();
        assert_eq!((f.rx(0x610), f.tx(0x612)), (None, None));
        f.record_rx(0x610, 41).unwrap();
        f.record_rx(0x610, 42).unwrap();
        f.reserve_tx(0x612, 1_764_000_000_123).unwrap();
        f.record_rx(0x8000_0613, 7).unwrap();
        let back = FreshnessFile::load(&path).unwrap();
        assert_eq!(back.rx(0x610), Some(42));
        assert_eq!(back.tx(0x612), Some(1_764_000_000_123));
        assert_eq!(back.rx(0x8000_0613), Some(7));
        assert_eq!(back.rx(0x612), None, "rx and tx are kept apart");
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.contains("rx 0x00000610 42\n"), "{text}");
    }

    #[test]
    fn auth_a_failed_write_leaves_the_value_unstored() {
        let path = scratch("fail").with_file_name("no-such-dir").join("f");
        let mut f = FreshnessFile::load(&path).unwrap();
        let e = f.record_rx(0x610, 5).unwrap_err();
        assert!(e.to_string().contains("no-such-dir"), "{e}");
        assert_eq!(f.rx(0x610), None);
    }

    #[test]
    fn auth_a_damaged_freshness_file_is_an_error_naming_the_line() {
        let path = scratch("damaged");
        for (text, line) in [
            ("rx 0x610 5\nrx 0x610 zz\n", 2),
            ("# c\nxx 0x610 5\n", 2),
            ("rx 610 5\n", 1),
            ("rx 0x610 5 6\n", 1),
            ("rx 0x610 5\nrx 0x610 6\n", 2),
            ("tx 0x610 99999999999999999999\n", 1),
        ] {
            std::fs::write(&path, text).unwrap();
            match FreshnessFile::load(&path) {
                Err(FreshnessError::Malformed { line: l, .. }) => assert_eq!(l, line, "{text}"),
                other => panic!("{text:?}: {other:?}"),
            }
        }
    }
}
