//! Issue 7 scenario 4 (hostile bus) with scenario 5's SIGTERM and issue 8's
//! live cost and latency, in one run of the real binaries on `vcan0`:
//!
//! - an injector (a thread of this test, one raw socket, paced by the clock)
//!   sends a simulated figure eight's wheel and steering frames at their
//!   100 Hz, at least 8,000 unrelated frames per second (random standard
//!   ids, and extended ids that share the wheel ids' numbers), and on the
//!   wheel ids a known number of garbage frames, short DLCs, broken
//!   checksums, repeated counters and skipped counters;
//! - `canodom run --state-file` receives it, publishing a pose after every
//!   filter step; `candump vcan0 > /dev/null` receives everything beside it
//!   as the peer of issue 8; a filtered `candump -L` records the wheel and
//!   pose frames with their kernel timestamps;
//! - SIGTERM the moment the injector is done: exit 0, and the state file's
//!   statistics count each reject kind exactly as injected, every frame sent
//!   on the daemon's ids counted, no kernel drop, and its pose is the pose
//!   `canodom replay` computes from the recording.
//!
//! Duration: `VCAN_LOAD_S` seconds of load (default 30, the issue 7 figure;
//! issue 8 asks 60, which with the rest of the suite stays under the 10
//! minutes only on an idle machine: `VCAN_LOAD_S=60 bash vcan-tests/run-vm.sh`
//! measures it; the script passes the variable into the guest).
#![cfg(feature = "vcan")]
#![allow(clippy::unwrap_used, clippy::too_many_lines)]

use canodom_can::candump::parse_line;
use canodom_can::frame::{CanFrame, FrameId};
use canodom_dbc::{Checksum, CounterCheck, CounterStatus};
use canodom_vcan_tests::{
    PoseDecoder, Spawned, angle_diff, canodom_bin, canodom_replay, metric, path_arg, read,
    read_candump, read_csv, repo_file, run, scratch_dir, wait_until,
};
use nix::errno::Errno;
use nix::sys::socket::{MsgFlags, MultiHeaders, sendmmsg};
use socketcan::Socket;
use std::io::IoSlice;
use std::os::fd::AsRawFd;
use std::path::Path;
use std::time::{Duration, Instant};

const REAR_ID: u16 = 0x100;
const FRONT_ID: u16 = 0x101;
const STEER_ID: u16 = 0x110;
const POSE_BASE: u16 = 0x600;
const LOG_EPOCH_US: u64 = 1_700_000_000_000_000;
/// Unrelated frames per second, on top of the vehicle's 300: the schedule
/// offers 8,800 frames/s so that the rate reached stays at the 8,000
/// when the emulated guest's sender falls a little behind (measured: 7,700 to
/// 8,200 frames/s reached from an 8,300 schedule on a host busy compiling).
const UNRELATED_FPS: u64 = 8_500;
/// The full classic-CAN load: a run below it fails. Since the
/// injector sends with `sendmmsg`, the guest on an idle host sends the whole
/// 8,812 frames/s schedule in 30.0 s; on a host busy with other builds it
/// fell to 5,800, where frames also arrive bunched and the exact counts
/// below would fail anyway. Checked before the counts, so such a run names
/// the host, not the daemon.
const MIN_FPS: f64 = 8_000.0;

/// A small deterministic generator (the scenario must know what it sent).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        self.0 >> 33
    }
}

#[derive(Default, Debug)]
struct Expected {
    truncated: u64,
    bad_checksum: u64,
    bad_counter: u64,
    /// Frames on the daemon's input ids (genuine and injected).
    on_input_ids: u64,
}

fn data(id: FrameId, bytes: &[u8]) -> CanFrame {
    CanFrame::new_data(id, bytes).unwrap()
}

/// The whole send schedule: (µs after the start, frame), in time order.
fn schedule(lines: &[String], load_s: u64, exp: &mut Expected) -> Vec<(u64, CanFrame)> {
    let crc = Checksum::rc_car();
    let mut rng = Lcg(7);
    let mut out = Vec::new();
    let mut per_id = [0u64; 2];
    let mut fault = 0u64;
    for l in lines {
        let r = parse_line(l.as_bytes()).unwrap();
        let t = r.timestamp.as_micros() - LOG_EPOCH_US;
        let id = r.frame.id();
        let wheel = match id {
            FrameId::Standard(REAR_ID) => Some(0),
            FrameId::Standard(FRONT_ID) => Some(1),
            _ => None,
        };
        let Some(w) = wheel else {
            out.push((t, r.frame));
            exp.on_input_ids += 1;
            continue;
        };
        per_id[w] += 1;
        // Every 10th frame of each wheel id carries a fault.
        if per_id[w] % 10 != 5 {
            out.push((t, r.frame));
            exp.on_input_ids += 1;
            continue;
        }
        let genuine = r.frame.data();
        fault += 1;
        match fault % 5 {
            0 => {
                // Garbage: random length and bytes.
                out.push((t, r.frame));
                let len = (rng.next() % 9) as usize;
                let mut b: Vec<u8> = (0..len).map(|_| rng.next() as u8).collect();
                if len == 8 {
                    if crc.verify(&b).unwrap_or(false) {
                        b[0] ^= 0xFF;
                    }
                    exp.bad_checksum += 1;
                } else {
                    exp.truncated += 1;
                }
                out.push((t, data(id, &b)));
                exp.on_input_ids += 2;
            }
            1 => {
                // A short DLC (the only wrong DLC a classic 8-byte message can have).
                out.push((t, r.frame));
                out.push((t, data(id, &genuine[..5])));
                exp.truncated += 1;
                exp.on_input_ids += 2;
            }
            2 => {
                // One byte inverted: CRC-8 catches every single-byte error.
                out.push((t, r.frame));
                let mut b = genuine.to_vec();
                b[0] ^= 0xFF;
                out.push((t, data(id, &b)));
                exp.bad_checksum += 1;
                exp.on_input_ids += 2;
            }
            3 => {
                // The frame repeated: its counter does not advance.
                out.push((t, r.frame));
                out.push((t, r.frame));
                exp.bad_counter += 1;
                exp.on_input_ids += 2;
            }
            _ => {
                // The frame withheld: the next one's counter jumps by two.
                exp.bad_counter += 1;
            }
        }
    }
    // Unrelated traffic, evenly spread; every 8th an extended id, half of
    // those with the wheel ids' numbers (the kernel filter must keep them out).
    let n = UNRELATED_FPS * load_s;
    for k in 0..n {
        let t = k * 1_000_000 / UNRELATED_FPS;
        let id = if k % 8 == 7 {
            let raw = match k % 16 {
                7 => u32::from(REAR_ID),
                _ => 0x1800_0000 | (rng.next() as u32 & 0xFFFFF),
            };
            FrameId::Extended(raw)
        } else {
            // 0x200..=0x5FF: clear of the inputs (0x100–0x120) and the pose ids.
            FrameId::Standard(0x200 + (rng.next() % 0x400) as u16)
        };
        let len = (rng.next() % 9) as usize;
        let b: Vec<u8> = (0..len).map(|_| rng.next() as u8).collect();
        out.push((t, data(id, &b)));
    }
    out.sort_by_key(|(t, _)| *t);
    out
}

/// `struct can_frame` of linux/can.h as bytes: what one `sendmmsg` entry
/// carries (id with the extended flag, length, three reserved bytes, data).
fn to_raw(f: &CanFrame) -> [u8; 16] {
    let can_id = match f.id() {
        FrameId::Standard(raw) => u32::from(raw),
        FrameId::Extended(raw) => raw | libc::CAN_EFF_FLAG,
    };
    let mut raw = [0u8; 16];
    raw[..4].copy_from_slice(&can_id.to_ne_bytes());
    raw[4] = u8::try_from(f.data().len()).unwrap();
    raw[8..8 + f.data().len()].copy_from_slice(f.data());
    raw
}

/// Most frames one `sendmmsg` call carries: a burst no larger than this
/// cannot overflow a receiver's socket buffer (about 260 frames by default).
const MAX_BATCH: usize = 32;

/// Sends the schedule in real time; returns (frames sent, seconds taken).
///
/// Every frame due (or due within 1 ms) goes out in one `sendmmsg` call of
/// up to [`MAX_BATCH`] frames: in the emulated guest a system call per
/// frame cost so much that the sender fell behind 8,000 frames/s whenever
/// the host was busy, and the rate was then the sender's, not the bus's.
fn inject(events: &[(u64, CanFrame)]) -> (u64, f64) {
    let sock = socketcan::CanSocket::open("vcan0").unwrap();
    let fd = sock.as_raw_fd();
    let frames: Vec<[u8; 16]> = events.iter().map(|(_, f)| to_raw(f)).collect();
    let slices: Vec<[IoSlice<'_>; 1]> = frames.iter().map(|f| [IoSlice::new(f)]).collect();
    let no_addresses = [None::<()>; MAX_BATCH];
    let mut headers = MultiHeaders::<()>::preallocate(MAX_BATCH, None);
    let start = Instant::now();
    let mut next = 0;
    while next < events.len() {
        let due = Duration::from_micros(events[next].0);
        let now = start.elapsed();
        if let Some(ahead) = due.checked_sub(now)
            && ahead > Duration::from_millis(1)
        {
            std::thread::sleep(ahead);
        }
        let horizon_us = u64::try_from(start.elapsed().as_micros()).unwrap() + 1_000;
        let batch = 1 + events[next + 1..]
            .iter()
            .take(MAX_BATCH - 1)
            .take_while(|(t_us, _)| *t_us <= horizon_us)
            .count();
        match sendmmsg(
            fd,
            &mut headers,
            &slices[next..next + batch],
            &no_addresses[..batch],
            [],
            MsgFlags::empty(),
        ) {
            Ok(sent) => next += sent.count(),
            // ENOBUFS: the socket's send buffer is full for a moment.
            Err(Errno::ENOBUFS) => std::thread::sleep(Duration::from_micros(200)),
            Err(e) => panic!("injector: {e}"),
        }
    }
    (next as u64, start.elapsed().as_secs_f64())
}

/// utime + stime of a process, in clock ticks (100 Hz on Debian's kernel).
fn cpu_ticks(pid: u32) -> u64 {
    let stat = read(Path::new(&format!("/proc/{pid}/stat")));
    // Fields after the command name (which may hold spaces) in parentheses.
    let rest = &stat[stat.rfind(')').unwrap() + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    f[11].parse::<u64>().unwrap() + f[12].parse::<u64>().unwrap()
}

fn vm_hwm_kb(pid: u32) -> u64 {
    read(Path::new(&format!("/proc/{pid}/status")))
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .unwrap()
}

/// A number after `"key":` in the state file (pretty JSON).
fn percentile(sorted: &[u64], p: f64) -> u64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

#[test]
fn hostile_bus_at_8000_fps_rejects_counted_exactly_no_drops_then_sigterm_saves_the_state() {
    // run-vm.sh passes VCAN_LOAD_S in; a value that does not parse fails the
    // scenario rather than quietly measuring the default 30 s.
    let load_s: u64 = std::env::var("VCAN_LOAD_S").map_or(30, |v| {
        v.parse()
            .unwrap_or_else(|e| panic!("VCAN_LOAD_S: {v:?}: {e}"))
    });
    println!("vcan-metric: load_s = {load_s}");
    let dir = scratch_dir("hostile").unwrap();
    let config = repo_file("vcan-tests/fixtures/rc_car_hostile.toml");
    let full = dir.join("full.log");
    let truth_path = dir.join("truth.csv");
    run(
        &path_arg(&canodom_bin()),
        &[
            "simulate",
            "--config",
            &path_arg(&config),
            "--log",
            &path_arg(&full),
            "--truth",
            &path_arg(&truth_path),
            "--path",
            "figure-eight",
        ],
    )
    .unwrap();
    let end_us = LOG_EPOCH_US + load_s * 1_000_000;
    let lines: Vec<String> = read(&full)
        .lines()
        .filter(|l| parse_line(l.as_bytes()).unwrap().timestamp.as_micros() < end_us)
        .map(str::to_owned)
        .collect();
    let mut exp = Expected::default();
    let events = schedule(&lines, load_s, &mut exp);

    let state = dir.join("state.json");
    let daemon_log = dir.join("daemon.log");
    let mut daemon = Spawned::start(
        &canodom_bin(),
        &[
            "run",
            "--config",
            &path_arg(&config),
            "--state-file",
            &path_arg(&state),
        ],
        None,
        Some(&daemon_log),
    )
    .unwrap();
    wait_until("the daemon opens vcan0", Duration::from_secs(15), || {
        read(&daemon_log).contains("CAN interface open")
    })
    .unwrap();
    let recorder = Spawned::start(
        Path::new("candump"),
        &["-L", "vcan0,100:7FF,101:7FF,110:7FF,600:7FC"],
        Some(&dir.join("bus.log")),
        Some(&dir.join("candump.err")),
    )
    .unwrap();
    let peer = Spawned::start(Path::new("candump"), &["vcan0"], None, None).unwrap();
    std::thread::sleep(Duration::from_millis(500));
    let (dpid, ppid) = (daemon.id().unwrap(), peer.id().unwrap());
    let (d0, p0) = (cpu_ticks(dpid), cpu_ticks(ppid));

    let (sent, took_s) = inject(&events);

    let (d1, p1) = (cpu_ticks(dpid), cpu_ticks(ppid));
    let (d_hwm, p_hwm) = (vm_hwm_kb(dpid), vm_hwm_kb(ppid));
    // SIGTERM at once: frames the daemon received but not yet used must
    // still be counted in the saved state.
    let status = daemon.stop("TERM", Duration::from_secs(10)).unwrap();
    let log = read(&daemon_log);
    assert!(status.success(), "daemon exit {status}:\n{log}");
    std::thread::sleep(Duration::from_millis(300));
    let mut recorder = recorder;
    recorder.stop("INT", Duration::from_secs(5)).unwrap();
    drop(peer);

    let fps = sent as f64 / took_s;
    metric("hostile_frames_sent", sent);
    metric("hostile_send_s", format!("{took_s:.1}"));
    metric("hostile_fps", format!("{fps:.0}"));
    assert_eq!(sent, events.len() as u64);
    metric(
        "hostile_offered_fps",
        format!("{:.0}", events.len() as f64 / load_s as f64),
    );
    // First: when the guest cannot keep real time, the wheel frames arrive
    // bunched, the daemon rightly sees gaps and resets its counter checks,
    // and every exact count below would fail for the host's sake, not the
    // daemon's.
    assert!(
        fps >= MIN_FPS,
        "the injector reached only {fps:.0} of {MIN_FPS} frames/s: the emulated guest could not keep \
         real time (is the host busy?); the counts below assume frames arrive when they are due"
    );

    // The state file: complete (it parses, every field there), and the
    // daemon's exact counts.
    let saved: SavedState =
        serde_json::from_str(&read(&state)).unwrap_or_else(|e| panic!("{e}:\n{}", read(&state)));
    let rejects = &saved.stats.rejects;
    let reject = |k: &str| {
        *rejects
            .get(k)
            .unwrap_or_else(|| panic!("no reject count {k:?} in {rejects:?}"))
    };
    metric("state_frames", saved.stats.frames);
    metric("expected_frames_on_input_ids", exp.on_input_ids);
    metric("expected_truncated", exp.truncated);
    metric("expected_bad_checksum", exp.bad_checksum);
    metric("expected_bad_counter", exp.bad_counter);
    assert_eq!(
        saved.stats.frames, exp.on_input_ids,
        "frames on the daemon's ids: {saved:?}"
    );
    assert_eq!(reject("truncated"), exp.truncated, "{rejects:?}");
    assert_eq!(reject("bad_checksum"), exp.bad_checksum, "{rejects:?}");
    assert_eq!(reject("bad_counter"), exp.bad_counter, "{rejects:?}");
    for k in [
        "wrong_dlc",
        "unknown_id",
        "not_data",
        "non_finite",
        "filter_error",
    ] {
        assert_eq!(reject(k), 0, "{k}: {rejects:?}");
    }
    assert_eq!(saved.frames_lost, 0, "{saved:?}");
    let drops_line = log
        .lines()
        .rev()
        .find(|l| l.contains("CAN socket closed"))
        .unwrap_or_else(|| panic!("no socket close line:\n{log}"));
    let kernel_drops: u64 = drops_line
        .split_whitespace()
        .find_map(|w| w.strip_prefix("kernel_drops=")?.parse().ok())
        .unwrap_or_else(|| panic!("{drops_line}"));
    metric("daemon_kernel_drops", kernel_drops);
    assert_eq!(kernel_drops, 0);
    metric("wheel_gap", reject("wheel_gap"));
    metric("wheel_fault", reject("wheel_fault"));

    // Poses: decoded, valid once trusted, and exactly replay's.
    let (rec, malformed) = read_candump(&dir.join("bus.log")).unwrap();
    assert!(malformed <= 1);
    let decoder = PoseDecoder::load(u32::from(POSE_BASE)).unwrap();
    let poses = decoder.decode(&rec).unwrap();
    assert!(poses.samples.len() > 1000, "{} poses", poses.samples.len());
    let first_valid = poses.samples.iter().position(|p| p.pose_valid).unwrap();
    let invalid_later = poses.samples[first_valid..]
        .iter()
        .filter(|p| !p.pose_valid)
        .count();
    metric("invalid_poses_after_first_valid", invalid_later);
    assert_eq!(invalid_later, 0, "faults made a pose invalid");
    let wheel_on_bus = rec
        .iter()
        .filter(|l| {
            matches!(
                l.frame.id(),
                FrameId::Standard(REAR_ID | FRONT_ID | STEER_ID)
            )
        })
        .count() as u64;
    assert_eq!(
        wheel_on_bus, exp.on_input_ids,
        "the recording holds every frame sent on the input ids"
    );
    let (rows, replay_err) =
        canodom_replay(&config, &dir.join("bus.log"), &dir.join("replay.csv")).unwrap();
    let last = poses.samples.last().unwrap();
    let row = rows.last().unwrap();
    assert!(
        last.encodes(row[1], row[2], row[3]),
        "daemon's last pose {last:?} vs replay {row:?}"
    );
    // Replay's heading is the total turn, as the state's unwrapped one; the
    // state's `heading_rad` is the same angle in (−π, π] (past half a turn
    // of the drive the two differ by whole turns).
    let pose = saved
        .pose
        .as_ref()
        .unwrap_or_else(|| panic!("no pose saved: {saved:?}"));
    assert!(
        (pose.x_m - row[1]).abs() < 1e-5
            && (pose.y_m - row[2]).abs() < 1e-5
            && (pose.heading_unwrapped_rad - row[3]).abs() < 1e-4
            && angle_diff(pose.heading_rad, row[3]).abs() < 1e-4,
        "state pose {pose:?} vs replay {row:?}"
    );
    assert_eq!(saved.stats.steps, rows.len() as u64, "{replay_err}");
    // And against the simulator's truth at the end of the drive.
    let truth = read_csv(&truth_path).unwrap();
    let t = truth
        .iter()
        .rev()
        .find(|r| r[0] < load_s as f64 - 0.005)
        .unwrap();
    let path_m: f64 = truth
        .windows(2)
        .take_while(|w| w[1][0] <= t[0])
        .map(|w| (w[1][1] - w[0][1]).hypot(w[1][2] - w[0][2]))
        .sum();
    let end_m = (pose.x_m - t[1]).hypot(pose.y_m - t[2]);
    metric("hostile_path_m", format!("{path_m:.2}"));
    metric("hostile_end_error_m", format!("{end_m:.4}"));
    assert!(
        end_m < 0.01 * path_m,
        "end error {end_m} m over {path_m} m (1 % bar: a tenth of the rear steps were faulted)"
    );

    // Issue 8: cost against candump receiving the same traffic.
    let (d_cpu, p_cpu) = (d1 - d0, p1 - p0);
    metric("daemon_cpu_ticks", d_cpu);
    metric("candump_cpu_ticks", p_cpu);
    metric(
        "daemon_over_candump_cpu",
        format!("{:.3}", d_cpu as f64 / p_cpu.max(1) as f64),
    );
    metric("daemon_vm_hwm_kb", d_hwm);
    metric("candump_vm_hwm_kb", p_hwm);
    // Latency: each rear-wheel frame that made a filter step to the pose
    // frame it caused. A rear frame the daemon rejects causes none: counted,
    // its "latency" was the wait for the next good frame 10 ms later (2 % of
    // the rear frames, after each withheld one, so it set the p99). The
    // frames are judged as the pipeline does (length, CRC-8, then the
    // counter against the last one that passed the CRC), and the count of
    // steps this finds must be the daemon's.
    let crc = Checksum::rc_car();
    // COUNTER: the 4 bits from bit 48 of WHEEL_ENC_REAR.
    let mut counter = CounterCheck::new(4).unwrap();
    let mut steps_on_bus = 0u64;
    let mut lat: Vec<u64> = Vec::new();
    let mut pending: Option<u64> = None;
    for l in &rec {
        match l.frame.id() {
            FrameId::Standard(REAR_ID) => {
                let d = l.frame.data();
                if d.len() != 8 || !crc.verify(d).unwrap_or(false) {
                    continue;
                }
                let in_sequence = !matches!(
                    counter.observe(u64::from(d[6] & 0x0F)),
                    CounterStatus::Gap { .. }
                );
                if in_sequence {
                    steps_on_bus += 1;
                    if pending.is_none() {
                        pending = Some(l.t_us);
                    }
                }
            }
            FrameId::Standard(POSE_BASE) => {
                if let Some(t0) = pending.take() {
                    lat.push(l.t_us.saturating_sub(t0));
                }
            }
            _ => {}
        }
    }
    assert_eq!(
        steps_on_bus, saved.stats.steps,
        "rear frames judged as the daemon judges them"
    );
    lat.sort_unstable();
    assert!(lat.len() > 1000);
    metric("latency_samples", lat.len());
    metric("latency_median_us", percentile(&lat, 0.5));
    metric("latency_p99_us", percentile(&lat, 0.99));
    metric("latency_max_us", lat.last().copied().unwrap_or(0));
}

/// The part of `run --state-file`'s JSON these checks read, parsed here
/// rather than with the daemon's own reader so the file is judged as any
/// other program would read it.
#[derive(Debug, serde::Deserialize)]
struct SavedState {
    frames_lost: u64,
    pose: Option<SavedPose>,
    stats: SavedStats,
}

/// The pose table of the state file.
#[derive(Debug, serde::Deserialize)]
struct SavedPose {
    x_m: f64,
    y_m: f64,
    heading_rad: f64,
    heading_unwrapped_rad: f64,
}

/// The statistics table of the state file.
#[derive(Debug, serde::Deserialize)]
struct SavedStats {
    frames: u64,
    steps: u64,
    rejects: std::collections::BTreeMap<String, u64>,
}
