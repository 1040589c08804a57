"""Shared fixtures: the repository, the `canodom` CLI to compare with, and
simulated drives made by `canodom simulate`."""

import os
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DATA = REPO / "data"
RAV4 = DATA / "comma2k19-rav4"
RC_CAR = REPO / "daemon" / "examples" / "rc_car.toml"
#: `canodom simulate`'s logs start at this Unix time (sim::drive::LOG_EPOCH_US).
SIM_EPOCH_S = 1_700_000_000


@pytest.fixture(scope="session")
def canodom_cli() -> Path:
    """The `canodom` binary: $CANODOM_BIN, else built here (debug, as `cargo test` builds it)."""
    given = os.environ.get("CANODOM_BIN")
    if given:
        return Path(given)
    subprocess.run(["cargo", "build", "-q", "-p", "canodom"], cwd=REPO, check=True)
    target = Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target"))
    return target / "debug" / "canodom"


def run_cli(cli: Path, *args, **kwargs) -> subprocess.CompletedProcess:
    """Runs the CLI; fails the test with its stderr when it fails."""
    done = subprocess.run([str(cli), *map(str, args)], capture_output=True, text=True, **kwargs)
    assert done.returncode == 0, f"canodom {' '.join(map(str, args))}: {done.stderr}"
    return done


def simulate(cli: Path, out: Path, seed: int, path: str = "random", laps: int = 1, true_params: str = "",
             speed_mps: float = 0.0) -> Path:
    """A simulated drive of the 1:10 car: out/drive.log and out/truth.csv."""
    out.mkdir(parents=True, exist_ok=True)
    args = ["simulate", "--config", RC_CAR, "--log", out / "drive.log", "--path", path,
            "--seed", seed, "--laps", laps, "--truth", out / "truth.csv"]
    if speed_mps:
        args += ["--speed-mps", speed_mps]
    if true_params:
        (out / "true.toml").write_text(true_params)
        args += ["--true-params", out / "true.toml"]
    run_cli(cli, *args)
    return out / "drive.log"


def fixes_from_truth(truth: Path, out: Path, every_s: float = 1.0) -> Path:
    """Position fixes at `every_s` from a simulated truth CSV, on the log's clock."""
    lines = truth.read_text().splitlines()
    rows = [line.split(",") for line in lines[1:]]
    kept, next_t = [], 0.0
    for r in rows:
        t = float(r[0])
        if t >= next_t:
            kept.append(f"{SIM_EPOCH_S + t:.6f},{r[1]},{r[2]}")
            next_t = t + every_s
    out.write_text("t_unix_s,x_m,y_m\n" + "\n".join(kept) + "\n")
    return out
