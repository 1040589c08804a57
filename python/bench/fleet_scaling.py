"""The fleet job's frames/s on 1 and 2 CPUs of a local Ray, and the per-log
overhead of a Ray task.

    python python/bench/fleet_scaling.py [--logs 16] [--laps 40]

Makes --logs simulated drives (`canodom simulate`, target/release/canodom or
$CANODOM_BIN), runs the fleet job on them with --num-cpus 1 and 2 (each run a
fresh Ray), and prints frames/s of each and their ratio; then the same job on
as many tiny logs, whose time is almost all overhead.
"""

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
RC_CAR = REPO / "daemon/examples/rc_car.toml"


def simulate(cli, out, seed, laps):
    subprocess.run([cli, "simulate", "--config", str(RC_CAR), "--log", str(out), "--path", "random",
                    "--seed", str(seed), "--laps", str(laps)], check=True, capture_output=True)


def fleet(manifest, out, cpus):
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "canodom.fleet", str(manifest), "--out", str(out),
                           "--num-cpus", str(cpus)], capture_output=True, text=True, check=True)
    return time.perf_counter() - start, done.stdout


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--logs", type=int, default=16)
    p.add_argument("--laps", type=int, default=40)
    a = p.parse_args()
    cli = os.environ.get("CANODOM_BIN", str(REPO / "target/release/canodom"))
    import pyarrow.parquet as pq

    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        for kind, laps in (("long", a.laps), ("tiny", 1)):
            lines = ["vehicle_id,log,config"]
            for i in range(a.logs):
                log = d / f"{kind}{i}.log"
                simulate(cli, log, 1000 + i, laps)
                lines.append(f"car-{i},{log},{RC_CAR}")
            manifest = d / f"{kind}.csv"
            manifest.write_text("\n".join(lines) + "\n")
            results = {}
            for cpus in (1, 2):
                wall, _ = fleet(manifest, d / f"out-{kind}-{cpus}", cpus)
                summary = pq.read_table(d / f"out-{kind}-{cpus}" / "summary.parquet")
                frames = sum(summary.column("frames").to_pylist())
                task_s = sum(summary.column("seconds").to_pylist())
                results[cpus] = (wall, frames, task_s)
                print(f"{kind}: {a.logs} logs, {frames} frames, {cpus} CPU(s): {wall:.1f} s wall "
                      f"(Ray start included), {frames / wall:,.0f} frames/s; in tasks {task_s:.1f} s")
            if kind == "long":
                print(f"scaling 2 vs 1 CPU (wall): {results[1][0] / results[2][0]:.2f}x")
            else:
                wall, _, task_s = results[1]
                print(f"per-log overhead on 1 CPU (wall - work) / logs: {(wall - task_s) / a.logs * 1000:.0f} ms "
                      "(Ray start included; the tiny logs' replay itself is in 'in tasks')")


if __name__ == "__main__":
    main()
