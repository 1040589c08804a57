//! Shared helpers: configurations, simulated logs, pipelines.

use canodom_can::candump::LogReader;
use canodom_can::frame::CanFrame;
use canodom_can::time::Timestamp;
use canodom_pipeline::config::Config;
use canodom_sim::drive::{simulator, write_log};
use canodom_sim::vehicle::PathKind;
use std::path::PathBuf;

pub fn manifest() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

pub fn rc_car_toml() -> PathBuf {
    manifest().join("examples/rc_car.toml")
}

pub fn toyota_toml() -> PathBuf {
    manifest().join("examples/toyota.toml")
}

pub fn rc_car() -> Config {
    Config::load(&rc_car_toml()).unwrap()
}

/// The rc_car example with one line of it replaced (which must be there).
pub fn rc_car_with(line: &str, replacement: &str) -> Config {
    let path = rc_car_toml();
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(text.contains(line), "rc_car.toml lost {line:?}");
    Config::from_toml(&text.replace(line, replacement), &path).unwrap()
}

/// A simulated drive as a candump log (bytes) and its truth CSV.
pub fn simulated_log(config: &Config, path: PathKind, seed: u64) -> (Vec<u8>, String) {
    let mut sim = simulator(config, path, None, seed, false).unwrap();
    let mut log = Vec::new();
    let mut truth = Vec::new();
    write_log(config, &mut sim, &mut log, Some(&mut truth)).unwrap();
    (log, String::from_utf8(truth).unwrap())
}

/// A simulated drive of `path` with `seed` replayed from `config`: the
/// truth's distance, the fused and the rear-only end errors (m), and the
/// replay's summary.
pub fn replayed_end_errors(
    config: &Config,
    path: PathKind,
    seed: u64,
) -> (f64, f64, f64, canodom::cmd::replay::ReplaySummary) {
    let (log, truth_csv) = simulated_log(config, path, seed);
    let mut csv = Vec::new();
    let summary =
        canodom::cmd::replay::replay(config, &log[..], &mut csv, &mut std::io::sink()).unwrap();
    let rows = csv_rows(&String::from_utf8(csv).unwrap());
    let truth = csv_rows(&truth_csv);
    let distance_m: f64 = truth
        .windows(2)
        .map(|w| (w[1][1] - w[0][1]).hypot(w[1][2] - w[0][2]))
        .sum();
    let (last, t) = (rows.last().unwrap(), truth.last().unwrap());
    let fused = (last[1] - t[1]).hypot(last[2] - t[2]);
    let rear = (last[4] - t[1]).hypot(last[5] - t[2]);
    (distance_m, fused, rear, summary)
}

/// The records of a log as (timestamp, frame).
pub fn frames_of(log: &[u8]) -> Vec<(Timestamp, CanFrame)> {
    let mut r = LogReader::new(log);
    let mut out = Vec::new();
    while let Some(rec) = r.next_record().unwrap() {
        out.push((rec.timestamp, rec.frame));
    }
    out
}

/// Parses a CSV with a header into rows of floats; replay's text column
/// `correction` is left out.
pub fn csv_rows(text: &str) -> Vec<Vec<f64>> {
    let text_column = text
        .lines()
        .next()
        .and_then(|h| h.split(',').position(|name| name == "correction"));
    text.lines()
        .skip(1)
        .map(|l| {
            l.split(',')
                .enumerate()
                .filter(|(k, _)| Some(*k) != text_column)
                .map(|(_, v)| v.parse().unwrap())
                .collect()
        })
        .collect()
}

/// The `correction` column of replay's CSV, one entry a row.
pub fn csv_corrections(text: &str) -> Vec<String> {
    let column = text
        .lines()
        .next()
        .and_then(|h| h.split(',').position(|name| name == "correction"))
        .unwrap();
    text.lines()
        .skip(1)
        .map(|l| l.split(',').nth(column).unwrap_or("").to_string())
        .collect()
}

pub fn tmp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("canodom-test-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The text of a zstd-compressed log.
pub fn zstd_text(path: &std::path::Path) -> String {
    let raw = std::fs::read(path).unwrap();
    String::from_utf8(zstd::stream::decode_all(raw.as_slice()).unwrap()).unwrap()
}

/// The log lines of the daemon (the test thread's subscriber: the
/// in-process daemon runs on the test's current-thread runtime).
#[derive(Clone, Default)]
pub struct Logs(std::sync::Arc<std::sync::Mutex<Vec<u8>>>);

impl std::io::Write for Logs {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Logs {
    pub fn capture() -> (Self, tracing::subscriber::DefaultGuard) {
        let logs = Self::default();
        let writer = logs.clone();
        let guard = tracing::subscriber::set_default(
            tracing_subscriber::fmt()
                .with_ansi(false)
                .with_writer(move || writer.clone())
                .finish(),
        );
        (logs, guard)
    }

    /// The lines logged since the last call.
    pub fn take(&self) -> String {
        String::from_utf8(std::mem::take(&mut *self.0.lock().unwrap())).unwrap()
    }
}

/// Sends a simulated drive's frames on `tx` in real time (10 ms per
/// sample), with a `GNSS_LOCAL` fix of the true position every
/// `fix_every` samples (the test DBC's message 768); returns the encoder,
/// whose counters a caller that sends on goes on from.
pub async fn send_drive_with_fixes(
    tx: &impl canodom_can::bus::FrameSink,
    config: &Config,
    run: &canodom_fusion::sim::Run,
    fix_every: usize,
) -> canodom_sim::vehicle::SampleEncoder {
    let gnss = config
        .db
        .messages()
        .iter()
        .find(|m| m.name() == "GNSS_LOCAL")
        .unwrap();
    let mut encoder = canodom_sim::vehicle::SampleEncoder::new(config);
    let mut frames = Vec::new();
    for (k, s) in run.samples.iter().enumerate() {
        frames.clear();
        encoder.encode(s, &mut frames);
        if k % fix_every == 0 {
            let data = gnss
                .encode(&[("X", s.true_pose.x_m), ("Y", s.true_pose.y_m)])
                .unwrap();
            frames.push(
                CanFrame::new_data(canodom_can::frame::FrameId::Standard(768), &data).unwrap(),
            );
        }
        for f in &frames {
            tx.send(f).await.unwrap();
        }
        tokio::time::sleep(std::time::Duration::from_millis(10)).await;
    }
    encoder
}

/// The RC car's configuration in `dir` with position fixes on the bus (a
/// `GNSS_LOCAL` message added to its DBC), a parameter file beside it, and
/// `extra` TOML appended.
pub fn rc_car_with_fixes(dir: &std::path::Path, extra: &str) -> Config {
    let dbc = std::fs::read_to_string(manifest().join("../data/dbc/rc_car.dbc")).unwrap();
    let gnss = "BO_ 768 GNSS_LOCAL: 8 GNSS\n SG_ X : 0|32@1- (0.001,0) [-1000000|1000000] \"m\" ODOM\n \
                SG_ Y : 32|32@1- (0.001,0) [-1000000|1000000] \"m\" ODOM\n\n";
    let at = dbc.find("CM_ ").unwrap();
    std::fs::write(
        dir.join("car.dbc"),
        format!("{}{gnss}{}", &dbc[..at], &dbc[at..]),
    )
    .unwrap();
    let example = std::fs::read_to_string(rc_car_toml()).unwrap();
    let text = example.replace("../../data/dbc/rc_car.dbc", "car.dbc")
        + "\n[calibration.fixes]\nx = \"GNSS_LOCAL.X\"\ny = \"GNSS_LOCAL.Y\"\n"
        + extra;
    let text = text.replacen(
        "[calibration]",
        "[calibration]\nparam_file = \"params.toml\"",
        1,
    );
    let cfg_path = dir.join("car.toml");
    std::fs::write(&cfg_path, &text).unwrap();
    Config::load(&cfg_path).unwrap()
}

/// The live outputs recording every pose to `path` (`run --record`), with
/// no Foxglove server or ROS 2 forward: the tap to hand the daemon, and
/// the outputs to join.
pub fn recording_to(
    path: &std::path::Path,
    config: &Config,
) -> (canodom_export::live::Tap, canodom_export::live::LiveOutputs) {
    canodom_export::live::LiveOutputs::start(canodom_export::live::LiveOptions {
        record: Some(canodom_export::recorder::RecorderOptions::new(
            path.to_path_buf(),
        )),
        foxglove: None,
        k_rear_m: config.ekf.k_rear_m,
        queue: 1 << 16,
        forward: None,
    })
    .unwrap()
}

/// The frame an ECU answers a complete written-back `set` with: stored,
/// its acknowledgement counter `counter`.
pub fn stored_ack(
    wire: &canodom_protocol::calib_wire::CalibWire,
    set: &canodom_protocol::calib_wire::ParamSet,
    counter: u8,
) -> CanFrame {
    use canodom_protocol::calib_wire::{Ack, AckStatus, CalibWire};
    let ack = Ack {
        version: set.version,
        status: AckStatus::Stored,
        set_crc: wire.set_crc(set).unwrap(),
    };
    CalibWire::frame(wire.ack_id(), &wire.encode_ack(ack, counter)).unwrap()
}
