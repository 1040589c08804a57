"""calibrate_fixes() against `canodom calibrate --fixes` on the real RAV4 drive
(README's example: fixes over its first 30 s)."""

import re

import pytest

import canodom
from conftest import RAV4, run_cli


@pytest.fixture(scope="module")
def first_30s(tmp_path_factory):
    d = tmp_path_factory.mktemp("rav4")
    t0 = 1533245256.58
    log = d / "first.log"
    log.write_text("".join(
        line for line in (RAV4 / "drive.log").open() if float(line[1:18]) - t0 < 30
    ))
    rows = (RAV4 / "truth.csv").read_text().splitlines()
    fixes = d / "fixes.csv"
    fixes.write_text("\n".join(
        [rows[0]] + [r for n, r in enumerate(rows[1:], start=2)
                     if n % 20 == 2 and float(r.split(",")[0]) - 1533245256.547 <= 30]
    ) + "\n")
    return log, fixes, d


def test_calibrate_fixes_equals_the_cli(first_30s, canodom_cli):
    log, fixes, d = first_30s
    config = RAV4 / "config_yaw.toml"
    done = run_cli(canodom_cli, "calibrate", "--config", config, "--fixes", fixes,
                   "--out", d / "params.toml", log)
    fit = canodom.calibrate_fixes(log, config, fixes)
    printed = {
        "rear_ratio": r"rear ratio \(R/L\)\s+([+-][0-9.]+) ± ([0-9.]+)",
        "speed_scale": r"speed scale\s+([+-][0-9.]+) ± ([0-9.]+)",
    }
    for name, pattern in printed.items():
        m = re.search(pattern, done.stdout)
        assert m, done.stdout
        e = fit["estimates"][name]
        assert f"{e['value']:+.6f}" == m.group(1) and f"{e['sigma']:.6f}" == m.group(2), (name, e)
    assert "rear_tread_m" in fit["not_told"]
    held = re.findall(r"^\s+(.+?)\s+held:", done.stdout, re.M)
    names = {"steering offset": "steering_offset_rad", "steering gain": "steering_gain",
             "yaw-rate bias": "yaw_rate_bias_radps", "yaw-rate scale": "yaw_rate_scale"}
    # The CLI names a parameter's form in brackets ("steering gain (× the one
    # in use)"); the name before them is the parameter.
    assert {names[h.split(" (")[0]] for h in held} == set(fit["not_told"]) - {"rear_tread_m"}
    assert fit["out_of_bounds"] is None
    assert fit["fixes_used"] > 20


def test_fixes_that_are_not_csv_are_a_calibration_error(first_30s, tmp_path):
    log, _, _ = first_30s
    bad = tmp_path / "fixes.csv"
    bad.write_text("t_unix_s,x_m,y_m\n1533245257.0,1.0,oops\n")
    with pytest.raises(canodom.CalibrationError, match="fixes.csv"):
        canodom.calibrate_fixes(log, RAV4 / "config_yaw.toml", bad)
