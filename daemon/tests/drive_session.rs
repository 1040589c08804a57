//! Calibration without a track over the in-process bus (issue #23 item 4):
//! the bus carries position fixes (a GNSS message named in
//! `[calibration.fixes]`); the operator sends START_DRIVE, the simulated car
//! drives a random course whose right rear tyre is 1 % large, then COMPUTE
//! and COMMIT: the committed set carries the true diameter ratio.

use crate::util::tmp_dir;
use canodom::server::{InProcessDaemon, Observers};
use canodom_can::bus::FrameSink;
use canodom_fusion::sim::{Plan, simulate};
use canodom_pipeline::pipeline::Pipeline;
use canodom_protocol::calib_wire::{CalibWire, Command};
use canodom_sim::vehicle::sim_config;
use std::sync::Arc;
use std::time::Duration;

/// rc_car.dbc with a GNSS message: the rear-axle centre in a local frame, mm.
#[tokio::test(start_paused = true)]
async fn a_drive_with_fixes_on_the_bus_commits_the_true_ratio() {
    let dir = tmp_dir("drive-session");
    let config = crate::util::rc_car_with_fixes(&dir, "");
    let nominal = *Pipeline::new(&config).unwrap().params();
    let mut d = nominal.wheel_diameters_m();
    d.rear_right *= 1.01;
    let truth = nominal.with_diameters(d).unwrap();
    let run = simulate(
        &sim_config(&config, truth),
        &Plan::random_drive(5, 25.0, 0.8).unwrap(),
        5,
    )
    .unwrap();
    let config = Arc::new(config);
    let daemon = InProcessDaemon::spawn(Arc::clone(&config), 65536, Observers::default());
    let (_rx, tx) = daemon.bus.open().unwrap();
    tokio::time::sleep(Duration::from_millis(20)).await;
    let wire = CalibWire::new(config.output.base_id).unwrap();
    let send_cmd = |command: Command, counter: u8| {
        let data = wire.encode_command(
            command,
            config.calibration.arming_code.unwrap_or(0),
            counter,
        );
        CalibWire::frame(wire.cmd_id(), &data).unwrap()
    };
    tx.send(&send_cmd(Command::StartDrive, 1)).await.unwrap();
    crate::util::send_drive_with_fixes(&tx, &config, &run, 100).await;
    tx.send(&send_cmd(Command::Compute, 2)).await.unwrap();
    tokio::time::sleep(Duration::from_millis(50)).await;
    tx.send(&send_cmd(Command::Commit, 3)).await.unwrap();
    tokio::time::sleep(Duration::from_millis(50)).await;
    daemon.stop().await.unwrap();
    let file = canodom_params::persist::load(&dir.join("params.toml"), &config.calibration.bounds)
        .unwrap();
    let set = file.current.unwrap();
    assert_eq!(set.method, "drive");
    let ratio = set.values.rear_right_diameter_m / set.values.rear_left_diameter_m;
    let want = d.rear_right / d.rear_left;
    println!(
        "committed ratio {ratio:.6}, true {want:.6} ({} samples)",
        run.samples.len()
    );
    assert!((ratio - want).abs() < 1e-3, "{ratio} vs {want}");
}
