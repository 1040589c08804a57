//! `[ros2]` at full CAN load (#43): the latency from a CAN frame entering the
//! pipeline to the `nav_msgs/Odometry` sample it produced reaching a DDS
//! reader in another process, and the publishing process's CPU with the ROS 2
//! node on and off over the same frames at the same pace.
//!
//! The frames are the RAV4 drive's (`data/comma2k19-rav4/drive.log`), held
//! in memory and fed at `--frames-per-s` (default 4,000/s, a 500 kbit/s bus
//! full of 8-byte frames) by compressing the log's own clock, through the
//! path `replay --ros2` and `canodom run` share: `Pipeline::push`, the step's
//! `StepSample`, `Node::publish_pose` (SocketCAN is not on this kernel, so no
//! socket read: the bus is in-process). Each step's feed time (wall clock,
//! `SystemTime`) is taken as the frame that completed it enters the pipeline;
//! the reader, this binary run again as `load reader DOMAIN`, stamps each
//! sample's arrival with the same clock and prints it.
//!
//! CPU: the sum of every thread's on-CPU time of this process
//! (`/proc/self/task/*/schedstat`, ns), pipeline, pacing and (when on) the
//! node's and RustDDS's threads; the reader's process is not counted.
//!
//!     cargo bench -p canodom-ros2 --bench load -- [--frames-per-s 4000] [--seconds 20]

use canodom_export::sample::StepSample;
use canodom_pipeline::config::Config;
use canodom_pipeline::pipeline::Pipeline;
use canodom_ros2::config::{DiscoveryRange, Ros2Config};
use canodom_ros2::node::{Node, RawCdr, RawCdrAdapter, participant};
use rustdds::policy::{Durability, History, Reliability};
use rustdds::{QosPolicyBuilder, TopicKind};
use std::collections::HashMap;
use std::io::{BufRead, Read, Write};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// The bench's own DDS domain.
const DOMAIN: u16 = 161;

type Bench<T> = Result<T, Box<dyn std::error::Error>>;

fn now_ns() -> i128 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i128)
}

/// This process's on-CPU time so far, over all its threads (ns).
fn cpu_ns() -> Bench<u64> {
    let mut total = 0;
    for task in std::fs::read_dir("/proc/self/task")? {
        let text = std::fs::read_to_string(task?.path().join("schedstat")).unwrap_or_default();
        total += text
            .split_whitespace()
            .next()
            .and_then(|v| v.parse::<u64>().ok())
            .unwrap_or(0);
    }
    Ok(total)
}

/// The reader process: prints `stamp_ns arrival_ns` for every `/odom` sample
/// until its standard input closes.
fn reader(domain: u16) -> Bench<()> {
    let participant = participant(domain, DiscoveryRange::Localhost)?;
    let qos = QosPolicyBuilder::new()
        .reliability(Reliability::Reliable {
            max_blocking_time: rustdds::Duration::from_millis(100),
        })
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 1000 })
        .build();
    let topic = participant.create_topic(
        "rt/odom".to_owned(),
        canodom_ros2::msg::ODOMETRY_TYPE.to_owned(),
        &qos,
        TopicKind::NoKey,
    )?;
    let subscriber = participant.create_subscriber(&qos)?;
    let mut odom =
        subscriber.create_datareader_no_key::<RawCdr, RawCdrAdapter>(&topic, Some(qos))?;
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let stop_in = std::sync::Arc::clone(&stop);
    std::thread::spawn(move || {
        let mut sink = Vec::new();
        let _ = std::io::stdin().read_to_end(&mut sink);
        stop_in.store(true, std::sync::atomic::Ordering::Relaxed);
    });
    let out = std::io::stdout();
    let mut out = out.lock();
    while !stop.load(std::sync::atomic::Ordering::Relaxed) {
        while let Ok(Some(s)) = odom.take_next_sample() {
            let arrival = now_ns();
            let b = &s.value().0;
            // The header's stamp: sec (i32), nanosec (u32) after the 4-byte encapsulation.
            if let (Some(sec), Some(ns)) = (b.get(4..8), b.get(8..12)) {
                let sec = i32::from_le_bytes(sec.try_into()?);
                let ns = u32::from_le_bytes(ns.try_into()?);
                writeln!(
                    out,
                    "{} {arrival}",
                    i128::from(sec) * 1_000_000_000 + i128::from(ns)
                )?;
            }
        }
        std::thread::sleep(Duration::from_micros(200));
    }
    out.flush()?;
    Ok(())
}

/// One paced run: CPU used (ns), wall time (s), frames fed, and each step's
/// feed time by its stamp (ns).
struct Run {
    cpu_ns: u64,
    wall_s: f64,
    frames: usize,
    fed: HashMap<i128, i128>,
}

fn paced(
    config: &Config,
    frames: &[(canodom_can::time::Timestamp, canodom_can::frame::CanFrame)],
    speed: f64,
    node: Option<&Node>,
) -> Bench<Run> {
    let mut pipeline = Pipeline::new(config)?;
    let mut fed = HashMap::new();
    let t0 = frames.first().map_or(0, |(t, _)| t.as_micros() as i64);
    let cpu0 = cpu_ns()?;
    let wall0 = Instant::now();
    for (t, frame) in frames {
        let due = (t.as_micros() as i64 - t0) as f64 / 1e6 / speed;
        let now = wall0.elapsed().as_secs_f64();
        if due > now {
            std::thread::sleep(Duration::from_secs_f64(due - now));
        }
        let entered = now_ns();
        let Some(step) = pipeline.push(*t, frame).step().copied() else {
            continue;
        };
        let output = pipeline.pose_output(*t);
        let sample = StepSample::of(&pipeline, &step, output);
        fed.insert(i128::from(sample.t_unix_us) * 1000, entered);
        if let Some(node) = node {
            node.publish_pose(&sample, pipeline.params());
        }
    }
    Ok(Run {
        cpu_ns: cpu_ns()? - cpu0,
        wall_s: wall0.elapsed().as_secs_f64(),
        frames: frames.len(),
        fed,
    })
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

/// The paced run with the node on and a reader in another process: the run,
/// the node's counts and each received step's latency (ms).
fn with_node(
    config: &Config,
    frames: &[(canodom_can::time::Timestamp, canodom_can::frame::CanFrame)],
    speed: f64,
) -> Bench<(Run, canodom_ros2::node::NodeStats, Vec<f64>)> {
    let resolved = Ros2Config {
        enabled: true,
        domain_id: Some(DOMAIN),
        discovery: Some(DiscoveryRange::Localhost),
        ..Ros2Config::default()
    }
    .resolve_with(|_| None)?;
    let mut child = Command::new(std::env::current_exe()?)
        .args(["reader", &DOMAIN.to_string()])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()?;
    // Its lines are read as they come: a pipe left unread fills (64 KiB,
    // ~1,600 lines) and would hold the reader up.
    let out = child.stdout.take().ok_or("the reader's stdout")?;
    let collect = std::thread::spawn(move || {
        std::io::BufReader::new(out)
            .lines()
            .map_while(Result::ok)
            .collect::<Vec<String>>()
    });
    let node = Node::start(&resolved, config.ekf.k_rear_m)?;
    if !node.wait_for_subscribers(1, Duration::from_secs(30)) {
        let _ = child.kill();
        return Err("the reader did not match in 30 s".into());
    }
    let on = paced(config, frames, speed, Some(&node))?;
    let stats = node.finish();
    std::thread::sleep(Duration::from_millis(500));
    drop(child.stdin.take());
    let lines = collect
        .join()
        .map_err(|_| "the reader's collector panicked")?;
    child.wait()?;
    let latencies_ms: Vec<f64> = lines
        .iter()
        .filter_map(|l| {
            let mut it = l.split_whitespace().map(|v| v.parse::<i128>().ok());
            let (stamp, arrival) = (it.next()??, it.next()??);
            on.fed.get(&stamp).map(|fed| (arrival - fed) as f64 / 1e6)
        })
        .collect();
    Ok((on, stats, latencies_ms))
}

fn main() -> Bench<()> {
    let args: Vec<String> = std::env::args().collect();
    if args.get(1).map(String::as_str) == Some("reader") {
        let domain = args.get(2).and_then(|d| d.parse().ok()).unwrap_or(DOMAIN);
        return reader(domain);
    }
    let opt = |name: &str, default: f64| -> f64 {
        args.iter()
            .position(|a| a == name)
            .and_then(|k| args.get(k + 1))
            .and_then(|v| v.parse().ok())
            .unwrap_or(default)
    };
    let frames_per_s = opt("--frames-per-s", 4000.0);
    let seconds = opt("--seconds", 20.0);

    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/comma2k19-rav4");
    let config = Config::load(&root.join("config.toml"))?;
    let log = root.join("drive.log");
    let mut reader_frames = canodom_offline::log::LogFrames::open(&log, "bench", None)?;
    let mut all = Vec::new();
    while let Some(f) = reader_frames.next_frame()? {
        all.push(f);
    }
    let (first, last) = match (all.first(), all.last()) {
        (Some(a), Some(b)) => (a.0.as_micros(), b.0.as_micros()),
        _ => return Err("the log has no frames".into()),
    };
    let log_rate = all.len() as f64 / ((last - first) as f64 / 1e6);
    let speed = frames_per_s / log_rate;
    let n = ((frames_per_s * seconds) as usize).min(all.len());
    let frames = &all[..n];
    println!(
        "load: the RAV4 log's {log_rate:.0} frames/s run x{speed:.2} = {frames_per_s:.0} frames/s; \
         {n} frames ({:.1} s); machine load {}",
        n as f64 / frames_per_s,
        std::fs::read_to_string("/proc/loadavg")
            .unwrap_or_default()
            .trim()
    );

    let off = paced(&config, frames, speed, None)?;
    println!(
        "[ros2] off: {} frames in {:.2} s ({:.0}/s), {} steps; CPU {:.3} s = {:.1} % of a core",
        off.frames,
        off.wall_s,
        off.frames as f64 / off.wall_s,
        off.fed.len(),
        off.cpu_ns as f64 / 1e9,
        100.0 * off.cpu_ns as f64 / 1e9 / off.wall_s
    );

    let (on, stats, mut latencies_ms) = with_node(&config, frames, speed)?;
    latencies_ms.sort_by(f64::total_cmp);
    println!(
        "[ros2] on:  {} frames in {:.2} s ({:.0}/s), {} steps; CPU {:.3} s = {:.1} % of a core; \
         node: odometry written {}, dropped {}, write errors {}",
        on.frames,
        on.wall_s,
        on.frames as f64 / on.wall_s,
        on.fed.len(),
        on.cpu_ns as f64 / 1e9,
        100.0 * on.cpu_ns as f64 / 1e9 / on.wall_s,
        stats.odometry,
        stats.dropped,
        stats.write_errors
    );
    println!(
        "frame -> DDS sample in another process: {} of {} steps received; p50 {:.3} ms, \
         p90 {:.3} ms, p99 {:.3} ms, max {:.3} ms",
        latencies_ms.len(),
        on.fed.len(),
        percentile(&latencies_ms, 0.5),
        percentile(&latencies_ms, 0.9),
        percentile(&latencies_ms, 0.99),
        latencies_ms.last().copied().unwrap_or(f64::NAN)
    );
    println!(
        "CPU added by [ros2]: {:.1} percentage points of a core ({:.3} s over {:.1} s)",
        100.0 * (on.cpu_ns as f64 - off.cpu_ns as f64) / 1e9 / on.wall_s,
        (on.cpu_ns as f64 - off.cpu_ns as f64) / 1e9,
        on.wall_s
    );
    Ok(())
}
