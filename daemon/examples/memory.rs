//! Resident memory of the daemon after an hour of 100 Hz traffic.
//!
//! A simulated 1:10 car drives for one hour (360 000 samples, 1.08 M input
//! frames) on an in-process bus; the daemon's run loop (`server::run`, the
//! code `canodom run` uses) reads them and publishes 50 Hz pose frames. Time
//! is tokio's paused clock, so the hour passes in seconds. Prints VmRSS and
//! VmHWM from /proc/self/status every ten simulated minutes: the figure must
//! stay flat (no growth with traffic) and under 20 MB.
//!
//! `cargo run --release -p canodom --example memory`

use canodom::server::{InProcessDaemon, Observers};
use canodom_fusion::sim::{Plan, Simulator};
use canodom_pipeline::config::Config;
use canodom_sim::drive::drive;
use canodom_sim::vehicle::sim_config;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;
use tokio_util::sync::CancellationToken;

fn status_kb(key: &str) -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with(key))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|v| v.parse().ok())
        })
        .unwrap_or(0)
}

fn main() -> anyhow::Result<()> {
    let path = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/examples/rc_car.toml"));
    let config = Arc::new(Config::load(&path)?);
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .start_paused(true)
        .build()?;
    println!(
        "before: VmRSS {} kB, VmHWM {} kB",
        status_kb("VmRSS:"),
        status_kb("VmHWM:")
    );
    let started = std::time::Instant::now();
    let summary = rt.block_on(async {
        let daemon = InProcessDaemon::spawn(Arc::clone(&config), 4096, Observers::default());
        let bus = daemon.bus.clone();
        tokio::time::sleep(Duration::from_millis(10)).await;
        let (_rx, tx) = bus.open()?;
        // One hour at 0.1 m/s is 360 m of smooth random driving.
        let plan = Plan::random_drive(7, 360.0, 0.5)?;
        let sim = Simulator::new(&sim_config(&config, config.params), &plan, 7)?;
        let mut next_report_s = 0.0;
        drive(&config, sim, &tx, 100.0, CancellationToken::new(), |s| {
            if s.t_s >= next_report_s {
                println!(
                    "t = {:6.0} s: VmRSS {} kB, VmHWM {} kB",
                    s.t_s,
                    status_kb("VmRSS:"),
                    status_kb("VmHWM:")
                );
                next_report_s += 600.0;
            }
        })
        .await?;
        tokio::time::sleep(Duration::from_millis(100)).await;
        anyhow::Ok(daemon.stop().await?)
    })?;
    println!(
        "after {} frames ({} steps, {} poses published) in {:.1} s of real time: \
         VmRSS {} kB, VmHWM {} kB",
        summary.stats.frames,
        summary.stats.steps,
        summary.poses_published,
        started.elapsed().as_secs_f64(),
        status_kb("VmRSS:"),
        status_kb("VmHWM:")
    );
    Ok(())
}
