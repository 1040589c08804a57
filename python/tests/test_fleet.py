"""The fleet job on a local Ray: 22 simulated vehicles (some with a true
calibration error, given fixes) and one corrupt log. The summary's end poses
equal the CLI's replay of each log, the corrupt log has its error row, the
miscalibrated vehicles' drift is flagged and the others' is not, and 1 and 2
CPUs give identical tables."""

import gzip
import subprocess
import sys

import pandas as pd
import pyarrow.dataset as pads
import pyarrow.parquet as pq
import pytest

from conftest import RC_CAR, fixes_from_truth, run_cli, simulate

VEHICLES = 22
#: Vehicles whose true right rear wheel is 1.5 % larger than configured (a
#: wheel of another size), and one whose both rear wheels are 2 % larger
#: (new tyres): their drift must be flagged.
RATIO_ERROR = {3: 1.015, 11: 1.015, 17: 1.015}
SCALE_ERROR = {8: 1.02}
NOMINAL_D = 0.09


@pytest.fixture(scope="module")
def fleet(tmp_path_factory, canodom_cli):
    root = tmp_path_factory.mktemp("fleet")
    lines = ["vehicle_id,log,config,fixes"]
    for v in range(VEHICLES):
        true = ""
        if v in RATIO_ERROR:
            true = f"rear_right_diameter_m = {NOMINAL_D * RATIO_ERROR[v]}\n"
        if v in SCALE_ERROR:
            d = NOMINAL_D * SCALE_ERROR[v]
            true = f"rear_left_diameter_m = {d}\nrear_right_diameter_m = {d}\n"
        log = simulate(canodom_cli, root / f"v{v:02d}", seed=100 + v, path="random", laps=2, true_params=true, speed_mps=0.5)
        # Every third correctly calibrated vehicle and every miscalibrated one has fixes.
        fixes = ""
        if v % 3 == 0 or v in RATIO_ERROR or v in SCALE_ERROR:
            fixes = str(fixes_from_truth(root / f"v{v:02d}" / "truth.csv", root / f"v{v:02d}" / "fixes.csv", every_s=0.5))
        lines.append(f"car-{v:02d},{log},{RC_CAR},{fixes}")
    # A corrupt log: a gzip file cut in the middle.
    good = (root / "v00" / "drive.log").read_bytes()
    packed = gzip.compress(good)
    corrupt = root / "corrupt.log.gz"
    corrupt.write_bytes(packed[: len(packed) // 2])
    lines.append(f"car-00,{corrupt},{RC_CAR},")
    manifest = root / "manifest.csv"
    manifest.write_text("\n".join(lines) + "\n")
    out2 = root / "out2"
    done = subprocess.run(
        [sys.executable, "-m", "canodom.fleet", str(manifest), "--out", str(out2), "--num-cpus", "2"],
        capture_output=True, text=True, timeout=900,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert "1 of 23 logs failed" in done.stdout, done.stdout
    out1 = root / "out1"
    done1 = subprocess.run(
        [sys.executable, "-m", "canodom.fleet", str(manifest), "--out", str(out1), "--num-cpus", "1"],
        capture_output=True, text=True, timeout=900,
    )
    assert done1.returncode == 0, done1.stderr[-3000:]
    return {"root": root, "out1": out1, "out2": out2, "manifest": manifest, "corrupt": corrupt}


def test_end_poses_equal_the_cli_replay_of_each_log(fleet, canodom_cli):
    summary = pq.read_table(fleet["out2"] / "summary.parquet").to_pylist()
    assert len(summary) == VEHICLES + 1
    checked = 0
    for row in summary:
        if row["error"]:
            continue
        csv = fleet["root"] / f"pose-{checked}.csv"
        run_cli(canodom_cli, "replay", "--config", row["config"], row["log"], "--out", csv)
        expected = pd.read_csv(csv, float_precision="round_trip").iloc[-1]
        assert row["end_x_m"] == expected["x_m"]
        assert row["end_y_m"] == expected["y_m"]
        assert row["end_heading_rad"] == expected["heading_rad"]
        assert row["rear_end_x_m"] == expected["odo_x_m"]
        assert row["rear_end_y_m"] == expected["odo_y_m"]
        assert row["rear_end_heading_rad"] == expected["odo_heading_rad"]
        assert row["duration_s"] == expected["t_s"]
        assert row["steps"] == len(pd.read_csv(csv))
        checked += 1
    assert checked == VEHICLES


def test_the_corrupt_log_has_its_error_row(fleet):
    summary = pq.read_table(fleet["out2"] / "summary.parquet").to_pylist()
    failed = [r for r in summary if r["error"]]
    assert [r["log"] for r in failed] == [str(fleet["corrupt"])]
    assert "corrupt.log.gz" in failed[0]["error"]


def test_miscalibrated_vehicles_are_flagged_and_the_others_not(fleet):
    vehicles = {v["vehicle_id"]: v for v in pq.read_table(fleet["out2"] / "vehicles.parquet").to_pylist()}
    assert len(vehicles) == VEHICLES
    for v in range(VEHICLES):
        rec = vehicles[f"car-{v:02d}"]
        if v in RATIO_ERROR:
            assert "rear_ratio" in rec["flagged"], rec
            assert abs(rec["rear_ratio"] - RATIO_ERROR[v]) < 0.003, rec
        elif v in SCALE_ERROR:
            assert "speed_scale" in rec["flagged"], rec
            assert abs(rec["speed_scale"] - SCALE_ERROR[v]) < 0.005, rec
        else:
            assert rec["flagged"] == "", rec
            if v % 3 == 0:
                assert rec["calibrated_logs"] == 1 and rec["rear_ratio"] is not None, rec


def test_one_and_two_cpus_give_identical_tables(fleet):
    for name in ("summary.parquet", "vehicles.parquet"):
        a = pq.read_table(fleet["out1"] / name)
        b = pq.read_table(fleet["out2"] / name)
        if "seconds" in a.column_names:
            a, b = a.drop_columns(["seconds"]), b.drop_columns(["seconds"])
        assert a.schema == b.schema, name
        # pandas' equals: NaN (the failed log's poses) equals NaN.
        assert a.to_pandas().equals(b.to_pandas()), name
    poses = [
        pads.dataset(fleet[o] / "poses", partitioning="hive").to_table().sort_by([("log", "ascending"), ("t_s", "ascending")])
        for o in ("out1", "out2")
    ]
    assert poses[0].num_rows > 0 and poses[0].to_pandas().equals(poses[1].to_pandas())
    assert set(poses[0].column("vehicle_id").to_pylist()) == {f"car-{v:02d}" for v in range(VEHICLES)}
