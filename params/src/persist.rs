//! The calibrated-parameter file: the set in use plus the history of
//! previous sets for rollback, in TOML, written atomically and durably.
//!
//! Durability: [`store`] writes a temporary file in the same directory,
//! `fsync`s it, renames it over the target and `fsync`s the directory, so a
//! crash at any instant leaves either the complete old file or the complete
//! new one (rename is atomic within a file system; the directory `fsync`
//! makes the rename itself survive power loss).
//!
//! Integrity: every set carries a CRC-32 over its exact values (the bit
//! patterns of the floats, so the TOML text round trip is part of what is
//! checked); [`load`] verifies every checksum and the bounds of the set in
//! use and returns a typed [`PersistError`]: the caller falls back to the
//! nominal parameters with a warning.

pub use canodom_calib::history::{
    BoundsError, DEFAULT_MAX_HISTORY, ParamBounds, ParamFile, ParamSet, ParamValues,
    YAW_BIAS_MAX_RADPS,
};
use serde::{Deserialize, Serialize};
use std::fs;
use std::io;
use std::path::{Path, PathBuf};

/// Version of the file layout written by this code.
pub const FORMAT_VERSION: u32 = 1;

/// Why the parameter file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum PersistError {
    /// No file yet: the normal state before the first commit.
    #[error("{path}: no calibrated parameter file")]
    Missing {
        /// File path.
        path: PathBuf,
    },
    /// Reading or writing failed.
    #[error("{path}: {source}")]
    Io {
        /// File path.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: io::Error,
    },
    /// Not valid TOML, or not this layout.
    #[error("{path}: {source}")]
    Parse {
        /// File path.
        path: PathBuf,
        /// The parser's message.
        #[source]
        source: Box<toml::de::Error>,
    },
    /// Written by a newer canodom.
    #[error("{path}: format_version {found} is not supported (expected {FORMAT_VERSION})")]
    Format {
        /// File path.
        path: PathBuf,
        /// Version found.
        found: u32,
    },
    /// A stored checksum does not match its set.
    #[error(
        "{path}: checksum of {which} (version {version}) is {stored:08x}, computed {computed:08x}"
    )]
    Checksum {
        /// File path.
        path: PathBuf,
        /// `current` or `history[i]`.
        which: String,
        /// The set's version.
        version: u16,
        /// Checksum in the file.
        stored: u32,
        /// Checksum of the values read.
        computed: u32,
    },
    /// Version numbers are inconsistent (0, or above `last_version`).
    #[error("{path}: {reason}")]
    Inconsistent {
        /// File path.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// The set in use is outside the configured bounds.
    #[error("{path}: set version {version}: {source}")]
    OutOfBounds {
        /// File path.
        path: PathBuf,
        /// The set's version.
        version: u16,
        /// Which value.
        #[source]
        source: BoundsError,
    },
    /// Serializing failed (cannot happen for finite values; kept typed).
    #[error("serializing parameters: {0}")]
    Serialize(#[from] toml::ser::Error),
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFile {
    format_version: u32,
    last_version: u16,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    current: Option<RawSet>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    history: Vec<RawSet>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSet {
    version: u16,
    created_unix_s: u64,
    method: String,
    #[serde(flatten)]
    values: ParamValues,
    /// Hex text: TOML integers are signed 64-bit and a hex string reads
    /// better beside `crc32` tools.
    checksum: String,
}

impl From<&ParamSet> for RawSet {
    fn from(set: &ParamSet) -> Self {
        Self {
            version: set.version,
            created_unix_s: set.created_unix_s,
            method: set.method.clone(),
            values: set.values,
            checksum: format!("{:08x}", set.checksum()),
        }
    }
}

const HEADER: &str = "# canodom calibrated parameters, written by canodom.\n\
# Every set has a checksum: an edited set is refused and the nominal values are used.\n\n";

/// The file's TOML text.
///
/// # Errors
/// [`PersistError::Serialize`].
pub fn to_toml(file: &ParamFile) -> Result<String, PersistError> {
    let raw = RawFile {
        format_version: FORMAT_VERSION,
        last_version: file.last_version,
        current: file.current.as_ref().map(RawSet::from),
        history: file.history.iter().map(RawSet::from).collect(),
    };
    Ok(format!("{HEADER}{}", toml::to_string(&raw)?))
}

/// Parses and verifies file text (checksums and version consistency, not
/// bounds).
///
/// # Errors
/// Typed [`PersistError`] naming `path`.
pub fn from_toml(path: &Path, text: &str) -> Result<ParamFile, PersistError> {
    let raw: RawFile = toml::from_str(text).map_err(|e| PersistError::Parse {
        path: path.to_owned(),
        source: Box::new(e),
    })?;
    if raw.format_version != FORMAT_VERSION {
        return Err(PersistError::Format {
            path: path.to_owned(),
            found: raw.format_version,
        });
    }
    let check = |which: String, r: RawSet| -> Result<ParamSet, PersistError> {
        let set = ParamSet {
            version: r.version,
            created_unix_s: r.created_unix_s,
            method: r.method,
            values: r.values,
        };
        let computed = set.checksum();
        let stored = u32::from_str_radix(&r.checksum, 16).ok();
        if stored != Some(computed) || r.checksum.len() != 8 {
            return Err(PersistError::Checksum {
                path: path.to_owned(),
                which,
                version: set.version,
                stored: stored.unwrap_or(0),
                computed,
            });
        }
        if set.version == 0 {
            return Err(PersistError::Inconsistent {
                path: path.to_owned(),
                reason: format!("{which} has version 0, reserved for nominal parameters"),
            });
        }
        Ok(set)
    };
    let current = raw
        .current
        .map(|r| check("current".to_owned(), r))
        .transpose()?;
    let history = raw
        .history
        .into_iter()
        .enumerate()
        .map(|(i, r)| check(format!("history[{i}]"), r))
        .collect::<Result<Vec<_>, _>>()?;
    if current.is_none() && !history.is_empty() {
        return Err(PersistError::Inconsistent {
            path: path.to_owned(),
            reason: "history without a current set".to_owned(),
        });
    }
    Ok(ParamFile {
        last_version: raw.last_version,
        current,
        history,
    })
}

/// Loads, verifies and bounds-checks the file at `path`.
///
/// # Errors
/// [`PersistError::Missing`] when there is no file; any other variant
/// means the file is damaged or unusable.
pub fn load(path: &Path, bounds: &ParamBounds) -> Result<ParamFile, PersistError> {
    let text = match fs::read_to_string(path) {
        Ok(text) => text,
        Err(e) if e.kind() == io::ErrorKind::NotFound => {
            return Err(PersistError::Missing {
                path: path.to_owned(),
            });
        }
        Err(source) => {
            return Err(PersistError::Io {
                path: path.to_owned(),
                source,
            });
        }
    };
    let file = from_toml(path, &text)?;
    if let Some(set) = &file.current {
        bounds
            .check(&set.values)
            .map_err(|source| PersistError::OutOfBounds {
                path: path.to_owned(),
                version: set.version,
                source,
            })?;
    }
    Ok(file)
}

/// Writes the file atomically and durably (see the module doc).
///
/// # Errors
/// [`PersistError::Io`] naming the path that failed; the previous file is
/// then untouched.
pub fn store(path: &Path, file: &ParamFile) -> Result<(), PersistError> {
    let text = to_toml(file)?;
    write_atomic(path, text.as_bytes())
}

/// Temporary file used by [`store`] for `path`: hidden, same directory.
pub fn temp_path(path: &Path) -> PathBuf {
    crate::atomic_file::temp_path(path)
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), PersistError> {
    crate::atomic_file::write(path, bytes).map_err(|e| PersistError::Io {
        path: e.path,
        source: e.source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{BufRead, BufReader, Write};
    use std::process::{Command, Stdio};
    use std::time::{Duration, Instant};

    /// A distinct, in-bounds set per version `k` (the crash test commits
    /// tens of thousands).
    fn values(k: u32) -> ParamValues {
        let wave = f64::from(k % 1000);
        let k = f64::from(k);
        ParamValues {
            rear_tread_m: 0.30 + 1e-5 * wave,
            rear_left_diameter_m: 0.09 - 1e-6 * wave,
            rear_right_diameter_m: 0.09 + 1e-6 * wave,
            steering_gain: 1.0 + 1e-3 * (k / 7.0).sin(),
            steering_offset_rad: 0.01 * (k / 3.0).cos() / 3.0,
            yaw_rate_bias_radps: None,
            yaw_rate_scale: None,
            yaw_rate_bias_sigma_radps: None,
        }
    }

    fn bounds() -> ParamBounds {
        ParamBounds::around(0.30, 0.09, 0.3, 0.1)
    }

    fn temp_dir(tag: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!(
            "canodom-persist-{tag}-{}-{:?}",
            std::process::id(),
            std::thread::current().id()
        ));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn commit_store_load_round_trips_exactly() {
        let dir = temp_dir("roundtrip");
        let path = dir.join("params.toml");
        let mut file = ParamFile::default();
        for k in 1..=4 {
            file.commit(values(k), "exact", 1_700_000_000 + u64::from(k), 3);
        }
        assert_eq!(file.current.as_ref().unwrap().version, 4);
        assert_eq!(file.history.len(), 3);
        assert_eq!(file.history[0].version, 1);
        store(&path, &file).unwrap();
        let loaded = load(&path, &bounds()).unwrap();
        assert_eq!(loaded, file);
        assert!(!temp_path(&path).exists());
        let text = fs::read_to_string(&path).unwrap();
        assert!(
            text.contains("[current]") && text.contains("[[history]]"),
            "{text}"
        );
        fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn yaw_rate_values_round_trip_are_checked_and_bounded() {
        let dir = temp_dir("yaw");
        let path = dir.join("params.toml");
        let mut file = ParamFile::default();
        // A set written before the yaw-rate values existed keeps its checksum.
        let old = ParamSet {
            version: 1,
            created_unix_s: 5,
            method: "exact".into(),
            values: values(1),
        };
        let with_yaw = ParamValues {
            yaw_rate_bias_radps: Some(-0.007),
            yaw_rate_scale: Some(1.01),
            yaw_rate_bias_sigma_radps: None,
            ..values(2)
        };
        assert_ne!(
            ParamSet {
                values: with_yaw,
                ..old.clone()
            }
            .checksum(),
            old.checksum()
        );
        file.commit(values(1), "exact", 5, 10);
        file.commit(with_yaw, "drive", 6, 10);
        store(&path, &file).unwrap();
        let text = fs::read_to_string(&path).unwrap();
        assert!(text.contains("yaw_rate_bias_radps = -0.007"), "{text}");
        assert_eq!(load(&path, &bounds()).unwrap(), file);
        // Edited: refused by its checksum.
        fs::write(
            &path,
            text.replace("yaw_rate_scale = 1.01", "yaw_rate_scale = 1.02"),
        )
        .unwrap();
        assert!(matches!(
            load(&path, &bounds()),
            Err(PersistError::Checksum { .. })
        ));
        // A gyro bias beyond 5°/s is a broken sensor, not a calibration.
        let mut far = ParamFile::default();
        far.commit(
            ParamValues {
                yaw_rate_bias_radps: Some(0.1),
                ..with_yaw
            },
            "drive",
            7,
            10,
        );
        store(&path, &far).unwrap();
        let err = load(&path, &bounds()).unwrap_err();
        assert!(err.to_string().contains("yaw_rate_bias_radps"), "{err}");
        fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn commit_keeps_bounded_history_and_rollback_restores() {
        let mut file = ParamFile::default();
        assert!(file.rollback().is_none());
        for k in 1..=5 {
            file.commit(values(k), "exact", 0, 2);
        }
        assert_eq!(
            file.history.iter().map(|s| s.version).collect::<Vec<_>>(),
            [3, 4]
        );
        // The values of 4, then of 3, each under a new version (#33).
        let back = file.rollback().unwrap();
        assert_eq!((back.version, back.values), (6, values(4)));
        let back = file.rollback().unwrap();
        assert_eq!((back.version, back.values), (7, values(3)));
        assert!(file.rollback().is_none());
        assert_eq!(file.current.as_ref().unwrap().version, 7);
        // Versions stay unique after a rollback.
        assert_eq!(file.commit(values(9), "exact", 0, 2).version, 8);
        file.last_version = u16::MAX;
        assert_eq!(file.commit(values(9), "exact", 0, 2).version, 1);
    }

    #[test]
    fn tampering_is_detected_with_a_typed_error() {
        let dir = temp_dir("tamper");
        let path = dir.join("params.toml");
        let mut file = ParamFile::default();
        file.commit(values(1), "exact", 5, 10);
        file.commit(values(2), "exact", 6, 10);
        store(&path, &file).unwrap();
        let text = fs::read_to_string(&path).unwrap();
        // The newline keeps one value from matching as a prefix of another.
        let tread = format!("rear_tread_m = {}\n", values(2).rear_tread_m);
        assert!(text.contains(&tread), "{text}");
        fs::write(&path, text.replace(&tread, "rear_tread_m = 0.31\n")).unwrap();
        match load(&path, &bounds()) {
            Err(PersistError::Checksum { which, version, .. }) => {
                assert_eq!((which.as_str(), version), ("current", 2));
            }
            other => panic!("{other:?}"),
        }
        let hist = format!("rear_tread_m = {}\n", values(1).rear_tread_m);
        assert!(text.contains(&hist), "{hist} not in {text}");
        fs::write(&path, text.replace(&hist, "rear_tread_m = 0.2\n")).unwrap();
        match load(&path, &bounds()) {
            Err(PersistError::Checksum { which, version, .. }) => {
                assert_eq!((which.as_str(), version), ("history[0]", 1));
            }
            other => panic!("{other:?}"),
        }
        fs::write(&path, &text[..text.len() / 2]).unwrap();
        assert!(matches!(
            load(&path, &bounds()),
            Err(PersistError::Parse { .. })
        ));
        fs::write(
            &path,
            text.replace("format_version = 1", "format_version = 2"),
        )
        .unwrap();
        assert!(matches!(
            load(&path, &bounds()),
            Err(PersistError::Format { found: 2, .. })
        ));
        fs::write(&path, format!("{text}\nunknown_key = 1\n")).unwrap();
        assert!(matches!(
            load(&path, &bounds()),
            Err(PersistError::Parse { .. })
        ));
        fs::remove_file(&path).unwrap();
        assert!(matches!(
            load(&path, &bounds()),
            Err(PersistError::Missing { .. })
        ));
        fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn out_of_bounds_sets_are_refused() {
        let dir = temp_dir("bounds");
        let path = dir.join("params.toml");
        let mut file = ParamFile::default();
        let mut v = values(1);
        v.rear_tread_m = 0.5;
        file.commit(v, "exact", 0, 10);
        store(&path, &file).unwrap();
        match load(&path, &bounds()) {
            Err(PersistError::OutOfBounds {
                version: 1, source, ..
            }) => {
                assert_eq!(source.field, "rear_tread_m");
                assert_eq!(source.value, 0.5);
            }
            other => panic!("{other:?}"),
        }
        let mut nan = values(1);
        nan.steering_offset_rad = f64::NAN;
        assert_eq!(
            bounds().check(&nan).unwrap_err().field,
            "steering_offset_rad"
        );
        assert!(bounds().check(&values(3)).is_ok());
        fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn checksum_covers_every_field() {
        let base = ParamSet {
            version: 3,
            created_unix_s: 9,
            method: "exact".into(),
            values: values(3),
        };
        let mut variants = vec![base.clone(); 8];
        variants[0].version = 4;
        variants[1].created_unix_s = 10;
        variants[2].method = "paper".into();
        variants[3].values.rear_tread_m = f64::from_bits(base.values.rear_tread_m.to_bits() + 1);
        variants[4].values.rear_left_diameter_m += 1e-9;
        variants[5].values.rear_right_diameter_m += 1e-9;
        variants[6].values.steering_gain += 1e-9;
        variants[7].values.steering_offset_rad += 1e-9;
        for v in &variants {
            assert_ne!(v.checksum(), base.checksum(), "{v:?}");
        }
    }

    const CHILD_ENV: &str = "CANODOM_PERSIST_CRASH_FILE";
    const CHILD_TEST: &str = "persist::tests::crash_child_commits_forever";

    /// Not a test: the child process of `sigkill_during_commit_leaves_old_or_new`.
    /// It commits set after set to the file named by the environment and
    /// reports each step on stdout, until killed.
    #[test]
    #[ignore = "helper process, run by sigkill_during_commit_leaves_old_or_new"]
    fn crash_child_commits_forever() {
        let Some(path) = std::env::var_os(CHILD_ENV).map(PathBuf::from) else {
            return;
        };
        let mut out = io::stdout().lock();
        let mut file = load(&path, &bounds()).unwrap();
        writeln!(out, "CRASH ready").unwrap();
        out.flush().unwrap();
        let deadline = Instant::now() + Duration::from_secs(20);
        while Instant::now() < deadline {
            let next = u32::from(file.last_version) + 1;
            writeln!(out, "CRASH begin {next}").unwrap();
            out.flush().unwrap();
            file.commit(values(next), "exact", u64::from(next), 4);
            store(&path, &file).unwrap();
            writeln!(out, "CRASH done {next}").unwrap();
            out.flush().unwrap();
        }
    }

    /// SplitMix64: a fixed, printed seed makes the kill instants reproducible.
    fn splitmix(state: &mut u64) -> u64 {
        *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = *state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// The file is complete and equal to set `v` with history `v-4..v`.
    fn assert_is_set(file: &ParamFile, v: u16) {
        let current = file.current.as_ref().unwrap();
        assert_eq!(current.version, v);
        assert_eq!(current.values, values(u32::from(v)));
        let expected: Vec<u16> = (v.saturating_sub(4).max(1)..v).collect();
        let got: Vec<u16> = file.history.iter().map(|s| s.version).collect();
        assert_eq!(got, expected);
        for s in &file.history {
            assert_eq!(s.values, values(u32::from(s.version)));
        }
    }

    #[test]
    fn sigkill_during_commit_leaves_old_or_new() {
        const ITERATIONS: usize = 200;
        let dir = temp_dir("crash");
        let path = dir.join("params.toml");
        let mut file = ParamFile::default();
        file.commit(values(1), "exact", 1, 4);
        store(&path, &file).unwrap();
        let exe = std::env::current_exe().unwrap();
        let seed = 0x00C0_FFEE_u64;
        let mut rng = seed;
        let (mut old, mut new, mut mid_commit, mut commits) = (0, 0, 0, 0u64);
        let started = Instant::now();
        // Kill instants uniform over a few commits' time on this machine
        // (one commit with its two fsyncs takes ~1 to 10 ms here).
        let max_delay_us = 20_000u64;
        for i in 0..ITERATIONS {
            let mut child = Command::new(&exe)
                .args([
                    CHILD_TEST,
                    "--exact",
                    "--ignored",
                    "--nocapture",
                    "--test-threads=1",
                ])
                .env(CHILD_ENV, &path)
                .stdout(Stdio::piped())
                .stderr(Stdio::null())
                .spawn()
                .unwrap();
            let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
            // Wait until the child has loaded the file, so every kill lands
            // in the commit loop rather than in process start-up.
            loop {
                let line = lines.next().expect("child exited before ready").unwrap();
                // libtest may print "test <name> ... " on the same line first.
                if line.ends_with("CRASH ready") {
                    break;
                }
            }
            let delay_us = splitmix(&mut rng) % max_delay_us;
            std::thread::sleep(Duration::from_micros(delay_us));
            child.kill().unwrap();
            child.wait().unwrap();
            let (mut begun, mut done) = (None, None);
            for line in lines {
                let line = line.unwrap();
                let line = line.find("CRASH ").map_or("", |i| &line[i..]);
                if let Some(v) = line.strip_prefix("CRASH begin ") {
                    begun = Some(v.parse::<u16>().unwrap());
                } else if let Some(v) = line.strip_prefix("CRASH done ") {
                    done = Some(v.parse::<u16>().unwrap());
                    commits += 1;
                }
            }
            let before = file.last_version;
            let loaded = load(&path, &bounds())
                .unwrap_or_else(|e| panic!("iteration {i} (seed {seed:#x}): {e}"));
            let v = loaded.current.as_ref().unwrap().version;
            // Old: the last completed commit (or the file before the child).
            let old_v = done.unwrap_or(before);
            // New: the commit in flight when the kill landed, if any.
            let new_v = begun.filter(|&b| Some(b) != done);
            if new_v.is_some() {
                mid_commit += 1;
            }
            if v == old_v {
                old += 1;
            } else if Some(v) == new_v {
                new += 1;
            } else {
                panic!("iteration {i}: file has version {v}, expected {old_v} or {new_v:?}");
            }
            assert_is_set(&loaded, v);
            file = loaded;
            // Stay clear of the u16 version wrap, which assert_is_set's
            // history arithmetic does not model.
            if file.last_version > 50_000 {
                file = ParamFile::default();
                file.commit(values(1), "exact", 1, 4);
                store(&path, &file).unwrap();
            }
        }
        println!(
            "persist crash test: {ITERATIONS} SIGKILLs (seed {seed:#x}), {commits} commits completed, \
             {mid_commit} kills during a commit; file was the old set {old} times, the new set {new} times; \
             {:.1} s",
            started.elapsed().as_secs_f64()
        );
        assert_eq!(old + new, ITERATIONS);
        // The test must actually hit commits in flight, or it proves nothing.
        assert!(
            mid_commit > ITERATIONS / 4,
            "only {mid_commit} kills hit a commit"
        );
        fs::remove_dir_all(dir).unwrap();
    }
}
