//! The SecOC values that must survive a restart (issues #22, #33, #44):
//! the receiver's **epoch** (SecOC profile 3: one above the last at every
//! start), and per secured frame id the highest value a sender reserved
//! (`tx`) and, for receivers that keep one, the last value accepted (`rx`).
//!
//! Every change is written ahead: the file is replaced atomically and
//! durably ([`crate::atomic_file`]) *before* the caller uses the value, and
//! the value in memory changes only once the file holds it. A crash at any
//! instant therefore leaves a file whose epoch is at least every epoch used
//! and whose `tx` is at least every value sent, so no epoch and no sent
//! value is ever used twice while the file lives.
//!
//! The format is a line per value, readable with `cat`:
//!
//! ```text
//! # canodom SecOC freshness values ...
//! epoch 0x5ec0c003
//! rx 0x00000610 6791143120455221249
//! tx 0x00000612 6791143120455221300
//! ```
//!
//! The id is the SecOC DataId (bit 31 set for an extended id). A missing
//! file is an empty store (a first start, or a lost file): the daemon then
//! draws its epoch at random, so a recording of an earlier epoch fails its
//! MAC all the same. A damaged file is an error naming the file and the
//! line, never silently an empty store.

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
    /// A line is not `epoch 0xEPOCH` or `rx|tx 0xID VALUE`.
    #[error(
        "{}: line {line}: expected `epoch 0xEPOCH`, `rx 0xID VALUE` or `tx 0xID VALUE`, got \
         {got:?} (the file is damaged; removing it makes the next start draw a random epoch)",
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
    epoch: Option<u32>,
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
        let mut epoch = None;
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
                Some("epoch") => {
                    let e = it
                        .next()
                        .and_then(|t| t.strip_prefix("0x"))
                        .and_then(|h| u32::from_str_radix(h, 16).ok())
                        .ok_or_else(bad)?;
                    if it.next().is_some() || epoch.replace(e).is_some() {
                        return Err(bad());
                    }
                    continue;
                }
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
            epoch,
            values,
        })
    }

    /// The last epoch stored (`None`: a first start or a lost file).
    pub fn epoch(&self) -> Option<u32> {
        self.epoch
    }

    /// Stores `epoch` durably, before the caller uses it.
    ///
    /// # Errors
    /// [`FreshnessError::Write`]; the store is then unchanged.
    pub fn store_epoch(&mut self, epoch: u32) -> Result<(), FreshnessError> {
        atomic_file::write(&self.path, render(Some(epoch), &self.values).as_bytes())?;
        self.epoch = Some(epoch);
        Ok(())
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
        atomic_file::write(&self.path, render(self.epoch, &next).as_bytes())?;
        self.values = next;
        Ok(())
    }
}

fn render(epoch: Option<u32>, values: &BTreeMap<(Dir, u32), u64>) -> String {
    let mut s = String::from(
        "# canodom SecOC freshness values (issues #22, #44), replaced atomically before each use.\n\
         # epoch: the receiver's last epoch (SecOC profile 3: one above it at the next start).\n\
         # rx: last value accepted per secured id; tx: highest value reserved for sending.\n",
    );
    if let Some(e) = epoch {
        let _ = writeln!(s, "epoch {e:#010x}");
    }
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
    fn auth_the_epoch_survives_a_reload_beside_the_values() {
        let path = scratch("epoch");
        let mut f = FreshnessFile::load(&path).unwrap();
        assert_eq!(f.epoch(), None);
        f.reserve_tx(0x612, 9).unwrap();
        f.store_epoch(0x5EC0_C003).unwrap();
        f.reserve_tx(0x612, 10).unwrap();
        let back = FreshnessFile::load(&path).unwrap();
        assert_eq!(
            (back.epoch(), back.tx(0x612)),
            (Some(0x5EC0_C003), Some(10))
        );
        std::fs::write(&path, "epoch 0x1\nepoch 0x2\n").unwrap();
        assert!(matches!(
            FreshnessFile::load(&path),
            Err(FreshnessError::Malformed { line: 2, .. })
        ));
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
