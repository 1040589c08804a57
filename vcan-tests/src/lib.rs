//! End-to-end tests of canodom on real `vcan` interfaces.
//!
//! The host kernel of the development and CI machines has no CAN, so the
//! scenarios (integration tests in `tests/`, compiled only with the `vcan`
//! feature) run inside a qemu guest booting Debian's stock kernel:
//! `bash vcan-tests/run-vm.sh` builds them, packs them into an initramfs with
//! the release binaries and can-utils, boots the guest and prints one
//! `vcan-result:` line per scenario and the summary `vcan: N passed, M failed`.
//!
//! This library holds what the scenarios share: running the guest's tools
//! with a time limit, finding the fixtures inside the guest, and reading
//! the daemon's MCAP recordings back ([`recording`]).

pub mod recording;

use canodom_can::candump::{LogReader, ReadError};
use canodom_can::frame::{CanFrame, FrameId};
use canodom_dbc::{Checksum, Database, SignalHandle};
use std::fmt::Write as _;
use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Output, Stdio};
use std::time::{Duration, Instant};

/// Every wait in a scenario has a limit; this is the default one.
pub const DEFAULT_WAIT: Duration = Duration::from_secs(10);

/// Runs a command to completion and returns its output, failing with the
/// command line and its stderr when it cannot start or exits non-zero.
///
/// # Errors
/// A message naming the command and what went wrong.
pub fn run(program: &str, args: &[&str]) -> Result<Output, String> {
    let output = Command::new(program)
        .args(args)
        .output()
        .map_err(|e| format!("cannot start `{program} {}`: {e}", args.join(" ")))?;
    if output.status.success() {
        Ok(output)
    } else {
        Err(format!(
            "`{program} {}` exited with {}: {}",
            args.join(" "),
            output.status,
            String::from_utf8_lossy(&output.stderr).trim()
        ))
    }
}

/// Sends one classic frame on `iface` with can-utils' `cansend`, as an
/// operator at a shell would (standard id, data as hex bytes).
///
/// # Errors
/// As [`run`].
pub fn cansend(iface: &str, id: u32, data: &[u8]) -> Result<(), String> {
    let mut frame = format!("{id:03X}#");
    for b in data {
        // Writing to a String cannot fail.
        let _ = write!(frame, "{b:02X}");
    }
    run("cansend", &[iface, &frame]).map(|_| ())
}

/// Runs `ip` with the given arguments (busybox `ip` in the guest).
///
/// # Errors
/// As [`run`].
pub fn ip(args: &[&str]) -> Result<(), String> {
    run("ip", args).map(|_| ())
}

/// A path as a command-line argument.
pub fn path_arg(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

/// Now, in microseconds since the Unix epoch (the clock candump stamps with).
pub fn unix_now_us() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64)
}

/// Where the guest keeps the repository's fixtures (`CANODOM_REPO`), falling
/// back to the source tree when the scenarios run on a machine with CAN.
pub fn repo_dir() -> PathBuf {
    std::env::var_os("CANODOM_REPO").map_or_else(
        || PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/..")),
        PathBuf::from,
    )
}

/// Prints a measured figure in the form the VM harness copies to its log.
pub fn metric(name: &str, value: impl std::fmt::Display) {
    println!("vcan-metric: {name} = {value}");
}

/// The `canodom` binary: `CANODOM_BIN` in the guest, else from `PATH`.
pub fn canodom_bin() -> PathBuf {
    std::env::var_os("CANODOM_BIN").map_or_else(|| PathBuf::from("canodom"), PathBuf::from)
}

/// A configuration shipped with the repository (`daemon/examples/…`,
/// `vcan-tests/fixtures/…`), by its path relative to the repository root.
pub fn repo_file(relative: &str) -> PathBuf {
    repo_dir().join(relative)
}

/// The rc_car example's commented bench lines (issue #44: the shipped
/// examples authenticate by default).
const EXAMPLE_BENCH: &str = "# [security]\n# allow_without_key = true ";

/// The same lines active: a vcan scenario without keys is a bench.
const BENCH: &str = "[security]\nallow_without_key = true ";

/// The rc_car example as a keyless bench with its DBC by absolute path,
/// written once to the temporary folder (the shipped example refuses to run
/// without keys); returns its path.
///
/// # Panics
/// The example cannot be read, has lost its bench lines, or the copy
/// cannot be written.
pub fn rc_car_bench_config() -> PathBuf {
    let example = std::fs::read_to_string(repo_file("daemon/examples/rc_car.toml"))
        .expect("daemon/examples/rc_car.toml");
    assert!(
        example.contains(EXAMPLE_BENCH),
        "rc_car.toml lost its bench lines"
    );
    let dbc = repo_file("data/dbc/rc_car.dbc");
    let text = example.replace(EXAMPLE_BENCH, BENCH).replace(
        "dbc = \"../../data/dbc/rc_car.dbc\"",
        &format!("dbc = \"{}\"", dbc.display()),
    );
    let path = std::env::temp_dir().join("vcan-rc-car-bench.toml");
    std::fs::write(&path, text).expect("write the bench configuration");
    path
}

/// Writes `dir/canodom.toml` for a calibration scenario: the rc_car example
/// with `dbc` (absolute, since the configuration moves), the parameter file
/// `dir/params.toml` and `arming_code`, as a keyless bench (its
/// `[security]` lines uncommented); returns its path.
///
/// # Errors
/// The example cannot be read, no longer has the lines this edits, or the
/// file cannot be written.
pub fn calibration_config(dir: &Path, dbc: &Path, arming_code: u8) -> Result<PathBuf, String> {
    let example_path = repo_file("daemon/examples/rc_car.toml");
    let example = std::fs::read_to_string(&example_path)
        .map_err(|e| format!("{}: {e}", example_path.display()))?;
    let mut config = example.replace(
        "dbc = \"../../data/dbc/rc_car.dbc\"",
        &format!("dbc = \"{}\"", dbc.display()),
    );
    if config == example {
        return Err(format!("{}: the dbc line moved", example_path.display()));
    }
    if !config.contains("\n[calibration]\n") {
        return Err(format!("{}: [calibration] is gone", example_path.display()));
    }
    config = config.replace(
        "\n[calibration]\n",
        &format!(
            "\n[calibration]\nparam_file = \"{}\"\narming_code = {arming_code:#04x}\n",
            dir.join("params.toml").display()
        ),
    );
    if !config.contains(EXAMPLE_BENCH) {
        return Err(format!("{}: the bench lines moved", example_path.display()));
    }
    config = config.replace(EXAMPLE_BENCH, BENCH);
    let path = dir.join("canodom.toml");
    std::fs::write(&path, config).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(path)
}

/// A fresh, empty scratch directory for one scenario.
///
/// # Errors
/// The directory cannot be emptied or created.
pub fn scratch_dir(name: &str) -> Result<PathBuf, String> {
    let dir = std::env::temp_dir().join(format!("vcan-{name}"));
    if dir.exists() {
        std::fs::remove_dir_all(&dir)
            .map_err(|e| format!("cannot empty {}: {e}", dir.display()))?;
    }
    std::fs::create_dir_all(&dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    Ok(dir)
}

/// A child process that is killed (SIGKILL) and reaped when dropped, so a
/// failing scenario leaves nothing running for the next one.
#[derive(Debug)]
pub struct Spawned {
    name: String,
    child: Option<Child>,
}

impl Spawned {
    /// Starts `program` with `args`, its stdout and stderr written to the
    /// given files (discarded when `None`).
    ///
    /// # Errors
    /// The program or an output file cannot be opened.
    pub fn start(
        program: &Path,
        args: &[&str],
        stdout: Option<&Path>,
        stderr: Option<&Path>,
    ) -> Result<Self, String> {
        let name = format!("{} {}", program.display(), args.join(" "));
        let out = |p: Option<&Path>| -> Result<Stdio, String> {
            match p {
                Some(p) => File::create(p)
                    .map(Stdio::from)
                    .map_err(|e| format!("cannot create {}: {e}", p.display())),
                None => Ok(Stdio::null()),
            }
        };
        let child = Command::new(program)
            .args(args)
            .stdin(Stdio::null())
            .stdout(out(stdout)?)
            .stderr(out(stderr)?)
            .spawn()
            .map_err(|e| format!("cannot start `{name}`: {e}"))?;
        Ok(Self {
            name,
            child: Some(child),
        })
    }

    /// Sends a signal by name (`TERM`, `INT`) with the guest's `kill`.
    ///
    /// # Errors
    /// The process is gone or `kill` failed.
    pub fn signal(&self, signal: &str) -> Result<(), String> {
        let child = self.child.as_ref().ok_or("process already reaped")?;
        run("kill", &["-s", signal, &child.id().to_string()]).map(|_| ())
    }

    /// The process id, while it runs.
    pub fn id(&self) -> Option<u32> {
        self.child.as_ref().map(Child::id)
    }

    /// Whether the process is still running.
    pub fn is_running(&mut self) -> bool {
        self.child
            .as_mut()
            .is_some_and(|c| matches!(c.try_wait(), Ok(None)))
    }

    /// Waits for the process to exit, at most `limit`.
    ///
    /// # Errors
    /// It did not exit in time (it is then killed by the drop), or waiting failed.
    pub fn wait_timeout(&mut self, limit: Duration) -> Result<ExitStatus, String> {
        let deadline = Instant::now() + limit;
        let child = self.child.as_mut().ok_or("process already reaped")?;
        loop {
            match child.try_wait() {
                Ok(Some(status)) => {
                    self.child = None;
                    return Ok(status);
                }
                Ok(None) if Instant::now() >= deadline => {
                    return Err(format!("`{}` still running after {limit:?}", self.name));
                }
                Ok(None) => std::thread::sleep(Duration::from_millis(20)),
                Err(e) => return Err(format!("waiting for `{}`: {e}", self.name)),
            }
        }
    }

    /// Sends `signal`, then waits at most `limit` for the exit.
    ///
    /// # Errors
    /// As [`Spawned::signal`] and [`Spawned::wait_timeout`].
    pub fn stop(&mut self, signal: &str, limit: Duration) -> Result<ExitStatus, String> {
        self.signal(signal)?;
        self.wait_timeout(limit)
    }
}

impl Drop for Spawned {
    fn drop(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// Polls `condition` every 100 ms until it holds, at most `limit` (the
/// guest has two emulated cores: a busier poll would slow what it waits for).
///
/// # Errors
/// `what` did not happen in time.
pub fn wait_until(
    what: &str,
    limit: Duration,
    mut condition: impl FnMut() -> bool,
) -> Result<Duration, String> {
    let started = Instant::now();
    loop {
        if condition() {
            return Ok(started.elapsed());
        }
        if started.elapsed() >= limit {
            return Err(format!("{what}: not within {limit:?}"));
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// A file's text, empty while it does not exist yet (a log a program has
/// not written to).
pub fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_default()
}

/// `canodom run --config CONFIG`, its stderr in `log`, once its socket on
/// vcan0 is open.
///
/// # Errors
/// It could not be started, it exited (the error holds its log), or its
/// socket did not open within 15 s.
pub fn start_daemon(config: &Path, log: &Path) -> Result<Spawned, String> {
    start_daemon_with(config, &[], log)
}

/// As [`start_daemon`], with more arguments after the configuration
/// (`--record FILE.mcap`, ...).
///
/// # Errors
/// As [`start_daemon`].
pub fn start_daemon_with(config: &Path, args: &[&str], log: &Path) -> Result<Spawned, String> {
    let config = config.to_string_lossy();
    let mut all = vec!["run", "--config", &config];
    all.extend_from_slice(args);
    let mut daemon = Spawned::start(&canodom_bin(), &all, None, Some(log))?;
    let mut exited = false;
    wait_until("the daemon opens vcan0", Duration::from_secs(15), || {
        exited = !daemon.is_running();
        exited || read(log).contains("CAN interface open")
    })?;
    if exited {
        return Err(format!("daemon exited: {}", read(log)));
    }
    Ok(daemon)
}

/// One frame of a candump log.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Logged {
    /// Receive time, microseconds since the epoch.
    pub t_us: u64,
    /// The frame.
    pub frame: CanFrame,
}

/// Reads a `candump -L` log with canodom's parser. A recording stopped by
/// a signal may end in a torn line; malformed lines are counted, not fatal.
///
/// # Errors
/// The file cannot be read.
pub fn read_candump(path: &Path) -> Result<(Vec<Logged>, u64), String> {
    let file = File::open(path).map_err(|e| format!("cannot open {}: {e}", path.display()))?;
    let mut reader = LogReader::new(BufReader::new(file));
    let mut frames = Vec::new();
    let mut malformed = 0;
    loop {
        match reader.next_record() {
            Ok(Some(r)) => frames.push(Logged {
                t_us: r.timestamp.as_micros(),
                frame: r.frame,
            }),
            Ok(None) => return Ok((frames, malformed)),
            Err(ReadError::Malformed(_)) => malformed += 1,
            Err(e) => return Err(format!("{}: {e}", path.display())),
        }
    }
}

/// Reads a CSV of numbers with one header line (the truth of `canodom
/// simulate --truth`, the poses of `canodom replay --out`); the text column
/// `correction` of replay's CSV is left out.
///
/// # Errors
/// Unreadable file or a field that is not a number.
pub fn read_csv(path: &Path) -> Result<Vec<Vec<f64>>, String> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let text_column = text
        .lines()
        .next()
        .and_then(|header| header.split(',').position(|name| name == "correction"));
    text.lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .enumerate()
        .map(|(i, line)| {
            line.split(',')
                .enumerate()
                .filter(|(k, _)| Some(*k) != text_column)
                .map(|(_, f)| {
                    f.trim()
                        .parse::<f64>()
                        .map_err(|e| format!("{} row {}: {f:?}: {e}", path.display(), i + 2))
                })
                .collect()
        })
        .collect()
}

/// Runs `canodom replay` of `log` and returns its pose rows
/// (`t_s,x_m,y_m,heading_rad,odo_x_m,odo_y_m,odo_heading_rad`, then
/// `t_unix_s,speed_mps,pos_std_m,heading_std_rad,pose_valid,quality`; the
/// `correction` column left out) and its stderr.
///
/// # Errors
/// The command failed or its CSV cannot be read.
pub fn canodom_replay(
    config: &Path,
    log: &Path,
    out: &Path,
) -> Result<(Vec<Vec<f64>>, String), String> {
    let bin = canodom_bin();
    let output = run(
        &bin.to_string_lossy(),
        &[
            "replay",
            "--config",
            &config.to_string_lossy(),
            &log.to_string_lossy(),
            "--out",
            &out.to_string_lossy(),
        ],
    )?;
    Ok((
        read_csv(out)?,
        String::from_utf8_lossy(&output.stderr).into_owned(),
    ))
}

/// `a − b` wrapped to (−π, π].
pub fn angle_diff(a_rad: f64, b_rad: f64) -> f64 {
    let d = (a_rad - b_rad).rem_euclid(std::f64::consts::TAU);
    if d > std::f64::consts::PI {
        d - std::f64::consts::TAU
    } else {
        d
    }
}

/// Resolution of `ODOM_POSITION.POS_X/POS_Y` (canodom.dbc).
pub const POSITION_QUANTUM_M: f64 = 0.001;
/// Resolution of `ODOM_MOTION.HEADING` (canodom.dbc).
pub const HEADING_QUANTUM_RAD: f64 = 0.0001;

/// One pose sample as published: the three frames sharing one counter.
// Each flag is one bit of ODOM_QUALITY, as in the daemon's own PoseFlags.
#[allow(clippy::struct_excessive_bools)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseSample {
    /// Receive time of its `ODOM_POSITION` frame, microseconds.
    pub t_us: u64,
    /// Index of that frame in the log (to count what came before it).
    pub log_index: usize,
    /// Rolling counter shared by the three frames.
    pub counter: u8,
    /// `POS_X`, metres.
    pub x_m: f64,
    /// `POS_Y`, metres.
    pub y_m: f64,
    /// `HEADING`, radians in (−π, π].
    pub heading_rad: f64,
    /// `SPEED`, m/s.
    pub speed_mps: f64,
    /// `POSE_VALID`.
    pub pose_valid: bool,
    /// `REAR_STALE`.
    pub rear_stale: bool,
    /// `FRONT_STALE`.
    pub front_stale: bool,
    /// `STEER_STALE`.
    pub steer_stale: bool,
    /// `POS_STD`, metres.
    pub pos_std_m: f64,
}

impl PoseSample {
    /// Whether this published pose is `(x, y, heading)` as the frame's
    /// resolution represents it (rounding to the nearest step).
    pub fn encodes(&self, x_m: f64, y_m: f64, heading_rad: f64) -> bool {
        let slack = 1e-9;
        (self.x_m - x_m).abs() <= 0.5 * POSITION_QUANTUM_M + slack
            && (self.y_m - y_m).abs() <= 0.5 * POSITION_QUANTUM_M + slack
            && angle_diff(self.heading_rad, heading_rad).abs() <= 0.5 * HEADING_QUANTUM_RAD + slack
    }
}

/// Decodes canodom's pose frames with the project's `protocol/dbc/canodom.dbc`
/// (written for base id 0x600; another base shifts every id alike).
#[derive(Debug)]
pub struct PoseDecoder {
    base_id: u32,
    handles: [SignalHandle; 9],
    counters: [SignalHandle; 3],
    crc: Checksum,
}

/// What [`PoseDecoder::decode`] found in a log.
#[derive(Clone, Debug, Default)]
pub struct PoseLog {
    /// Complete samples, in log order.
    pub samples: Vec<PoseSample>,
    /// Pose frames that did not form a complete sample (a publish cut by an outage).
    pub incomplete: u64,
}

impl PoseDecoder {
    /// Loads `protocol/dbc/canodom.dbc` for pose frames at `base_id` (standard ids).
    ///
    /// # Errors
    /// The DBC cannot be read or lacks a signal.
    pub fn load(base_id: u32) -> Result<Self, String> {
        let path = repo_file("protocol/dbc/canodom.dbc");
        let text = std::fs::read_to_string(&path)
            .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        let db = Database::parse(&text, "canodom.dbc").map_err(|e| e.to_string())?;
        let s = |p: &str| db.signal(p).map_err(|e| format!("canodom.dbc: {p}: {e}"));
        Ok(Self {
            base_id,
            handles: [
                s("ODOM_POSITION.POS_X")?,
                s("ODOM_POSITION.POS_Y")?,
                s("ODOM_MOTION.HEADING")?,
                s("ODOM_MOTION.SPEED")?,
                s("ODOM_QUALITY.POSE_VALID")?,
                s("ODOM_QUALITY.REAR_STALE")?,
                s("ODOM_QUALITY.FRONT_STALE")?,
                s("ODOM_QUALITY.STEER_STALE")?,
                s("ODOM_QUALITY.POS_STD")?,
            ],
            counters: [
                s("ODOM_POSITION.COUNTER")?,
                s("ODOM_MOTION.COUNTER")?,
                s("ODOM_QUALITY.COUNTER")?,
            ],
            crc: Checksum::rc_car(),
        })
    }

    /// Offset of a pose frame's id from the base (0 position, 1 motion,
    /// 2 quality), `None` for any other frame.
    pub fn pose_part(&self, frame: &CanFrame) -> Option<usize> {
        match frame.id() {
            FrameId::Standard(id) => {
                let off = u32::from(id).checked_sub(self.base_id)?;
                (off < 3).then_some(off as usize)
            }
            FrameId::Extended(_) => None,
        }
    }

    /// Every complete pose sample of `log`. A pose frame with a bad CRC, a
    /// wrong length or an undecodable signal is an error: the daemon never
    /// sends one.
    ///
    /// # Errors
    /// A malformed pose frame, naming its index.
    pub fn decode(&self, log: &[Logged]) -> Result<PoseLog, String> {
        let mut out = PoseLog::default();
        // (position frame index, counter, values so far, parts seen)
        let mut pending: Option<(usize, u64, [f64; 9], [bool; 3])> = None;
        for (i, l) in log.iter().enumerate() {
            let Some(part) = self.pose_part(&l.frame) else {
                continue;
            };
            let data = l.frame.data();
            if data.len() != 8 || !self.crc.verify(data).unwrap_or(false) {
                return Err(format!(
                    "pose frame {i} ({:?}) fails its length or CRC",
                    l.frame
                ));
            }
            let counter = self.counters[part]
                .raw(data)
                .ok_or_else(|| format!("pose frame {i}: no counter"))?;
            if part == 0 {
                if pending.take().is_some() {
                    out.incomplete += 1;
                }
                pending = Some((i, counter, [0.0; 9], [false; 3]));
            }
            let Some((_, c, values, seen)) = pending.as_mut() else {
                out.incomplete += 1;
                continue;
            };
            if *c != counter {
                out.incomplete += 1;
                pending = None;
                continue;
            }
            let range = match part {
                0 => 0..2,
                1 => 2..4,
                _ => 4..9,
            };
            for k in range {
                values[k] = self.handles[k]
                    .decode(data)
                    .ok_or_else(|| format!("pose frame {i}: signal {k} does not decode"))?;
            }
            seen[part] = true;
            if seen.iter().all(|&s| s)
                && let Some((at, c, v, _)) = pending.take()
            {
                out.samples.push(PoseSample {
                    t_us: log[at].t_us,
                    log_index: at,
                    counter: c as u8,
                    x_m: v[0],
                    y_m: v[1],
                    heading_rad: v[2],
                    speed_mps: v[3],
                    pose_valid: v[4] != 0.0,
                    rear_stale: v[5] != 0.0,
                    front_stale: v[6] != 0.0,
                    steer_stale: v[7] != 0.0,
                    pos_std_m: v[8],
                });
            }
        }
        if pending.is_some() {
            out.incomplete += 1;
        }
        Ok(out)
    }
}
