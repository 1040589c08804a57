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
//! with a time limit and finding the fixtures inside the guest.

use std::path::PathBuf;
use std::process::{Command, Output};
use std::time::Duration;

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

/// Runs `ip` with the given arguments (busybox `ip` in the guest).
///
/// # Errors
/// As [`run`].
pub fn ip(args: &[&str]) -> Result<(), String> {
    run("ip", args).map(|_| ())
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
