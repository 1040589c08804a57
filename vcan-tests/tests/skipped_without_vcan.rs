//! Without the `vcan` feature the scenarios are not compiled; this says so in
//! the test output instead of passing silently.

#[cfg(not(feature = "vcan"))]
#[test]
#[ignore = "needs real vcan interfaces: run `bash vcan-tests/run-vm.sh` (boots a qemu guest)"]
fn vcan_scenarios_run_in_the_vm() {
    unreachable!("ignored on hosts without CAN; the VM runs the scenarios in tests/*.rs");
}
