//! `canodom replay --ros2`: a recorded drive through the daemon's pipeline,
//! each filter step published on ROS 2 at the log's own pace (or a multiple
//! of it), so a ROS 2 stack can be fed from a log.
//!
//! The steps are those of `replay`'s CSV (the same pipeline over the same
//! frames in the same order); the interoperability test compares the two.

use crate::config::Ros2Config;
use crate::node::{Node, NodeStats};
use crate::{Error, Result};
use canodom_export::sample::StepSample;
use canodom_offline::log::LogFrames;
use canodom_pipeline::config::Config;
use canodom_pipeline::pipeline::Pipeline;
use std::path::Path;
use std::time::{Duration, Instant};

/// How long `--ros2-wait` waits for its subscribers at most.
pub const WAIT_LIMIT: Duration = Duration::from_secs(60);

/// `replay`'s ROS 2 options (flattened into the daemon's `replay` arguments).
#[derive(Clone, Debug, Default, clap::Args)]
pub struct Ros2ReplayArgs {
    /// Publish the drive on ROS 2 (DDS) at its recorded pace instead of
    /// writing a file: `nav_msgs/Odometry`, `/tf`, `/diagnostics`. Where and
    /// how: the configuration's `[ros2]` section (its `enabled` aside) and
    /// ROS 2's environment (`ROS_DOMAIN_ID`, `ROS_AUTOMATIC_DISCOVERY_RANGE`).
    #[arg(long, conflicts_with_all = ["out", "format", "truth"])]
    pub ros2: bool,
    /// With --ros2: first wait (up to a minute) until this many subscribers
    /// match `/odom`, so that none misses the drive's start.
    #[arg(long, requires = "ros2", default_value_t = 0, value_name = "N")]
    pub ros2_wait: u32,
    /// With --ros2: the pace as a multiple of the recorded one (2: twice as fast).
    #[arg(long, requires = "ros2", default_value_t = 1.0, value_name = "FACTOR")]
    pub ros2_speed: f64,
}

/// What a paced replay did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PacedSummary {
    /// Filter steps taken (and handed to the node).
    pub steps: u64,
    /// Frames read.
    pub frames: u64,
    /// The drive's length on the log's clock, seconds (first frame to last step).
    pub log_s: f64,
    /// Wall-clock time from the first step to the last, seconds.
    pub wall_s: f64,
    /// The node's counts at the end.
    pub node: NodeStats,
}

/// A fresh pipeline for `config`, with `params` in use from the first frame.
fn new_pipeline(
    config: &Config,
    params: Option<&canodom_params::persist::ParamSet>,
) -> Result<Pipeline> {
    let mut pipeline =
        Pipeline::new(config).map_err(|e| Error::Replay(format!("the configured vehicle: {e}")))?;
    if let Some(set) = params {
        pipeline
            .apply_params(Some((set.version, &set.values)))
            .map_err(|e| Error::Replay(format!("parameter set version {}: {e}", set.version)))?;
    }
    Ok(pipeline)
}

/// Replays the log at `log` through a fresh pipeline, handing each step to
/// `node` when the log's clock, run `speed` times as fast, reaches it.
///
/// # Errors
/// Pipeline construction, an unreadable log, a pace that is not a positive
/// number.
pub fn replay_paced(
    config: &Config,
    params: Option<&canodom_params::persist::ParamSet>,
    (log, interface): (&Path, Option<&str>),
    node: &Node,
    speed: f64,
) -> Result<PacedSummary> {
    if !(speed.is_finite() && speed > 0.0) {
        return Err(Error::Replay(format!(
            "--ros2-speed {speed}: the pace must be a positive number"
        )));
    }
    let mut pipeline = new_pipeline(config, params)?;
    let mut frames = LogFrames::open(log, "replay", interface)?;
    let mut start: Option<(Instant, i64)> = None;
    let mut last_t_us = 0i64;
    let mut steps = 0u64;
    let mut read = 0u64;
    while let Some((t, frame)) = frames.next_frame()? {
        read += 1;
        let Some(step) = pipeline.push(t, &frame).step().copied() else {
            continue;
        };
        let output = pipeline.pose_output(t);
        let sample = StepSample::of(&pipeline, &step, output);
        let (wall0, log0) = *start.get_or_insert((Instant::now(), sample.t_unix_us));
        let due = (sample.t_unix_us - log0).max(0) as f64 / 1e6 / speed;
        let now = wall0.elapsed().as_secs_f64();
        if due > now {
            std::thread::sleep(Duration::from_secs_f64(due - now));
        }
        node.publish_pose(&sample, pipeline.params());
        last_t_us = sample.t_unix_us;
        steps += 1;
    }
    if let Some(warning) = frames.finish(pipeline.stats().frames)? {
        eprintln!("replay: warning: {warning}");
    }
    let t0 = pipeline
        .first_frame_time()
        .map_or(0, |t| t.as_micros() as i64);
    Ok(PacedSummary {
        steps,
        frames: read,
        log_s: (last_t_us - t0).max(0) as f64 / 1e6,
        wall_s: start.map_or(0.0, |(w, _)| w.elapsed().as_secs_f64()),
        node: node.stats(),
    })
}

/// `replay --ros2`: starts the node the configuration's `[ros2]` section
/// and the environment describe, waits for `--ros2-wait` subscribers,
/// replays the log at its pace and reports on stderr.
///
/// # Errors
/// The `[ros2]` section, DDS could not start (here an error: publishing is
/// all this command does), the replay's own errors.
pub fn execute(
    args: &Ros2ReplayArgs,
    config: &Config,
    params: Option<&canodom_params::persist::ParamSet>,
    (log, interface): (&Path, Option<&str>),
) -> Result<PacedSummary> {
    let ros2 = Ros2Config::from_section(config.ros2.as_ref())?.resolve()?;
    let node = Node::start(&ros2, config.ekf.k_rear_m)?;
    eprintln!(
        "replay: ROS 2 node up ({}): odometry on {}, {}, {}",
        node.describe, ros2.odom_topic, ros2.tf_topic, ros2.diagnostics_topic
    );
    if args.ros2_wait > 0 {
        if node.wait_for_subscribers(args.ros2_wait, WAIT_LIMIT) {
            eprintln!(
                "replay: {} subscriber(s) matched",
                node.odometry_subscribers()
            );
        } else {
            eprintln!(
                "replay: warning: {} of {} subscribers matched in {} s; publishing anyway",
                node.odometry_subscribers(),
                args.ros2_wait,
                WAIT_LIMIT.as_secs()
            );
        }
    }
    let mut summary = replay_paced(config, params, (log, interface), &node, args.ros2_speed)?;
    summary.node = node.finish();
    let n = summary.node;
    eprintln!(
        "replay: {} frames, {} steps over {:.3} s of log in {:.3} s; odometry written {}, \
         diagnostics {}, dropped {}, write errors {}",
        summary.frames,
        summary.steps,
        summary.log_s,
        summary.wall_s,
        n.odometry,
        n.diagnostics,
        n.dropped,
        n.write_errors
    );
    Ok(summary)
}
