"""The fleet job's frames/s on 1 and 2 CPUs of a local Ray, and the per-log
overhead of a Ray task.

    python python/bench/fleet_scaling.py [--logs 4] [--laps 400] [--runs 3]

Makes --logs simulated drives (`canodom simulate` of $CANODOM_BIN, else
target/release/canodom), then runs the fleet job on them --runs times with 1
and with 2 CPUs, each run in a fresh interpreter and a fresh local Ray. The
job's time is taken after `ray.init` (Ray's start-up, printed apart, is the
same for any number of logs): frames/s of each, their ratio (the scaling),
medians over the runs; then the same job again in the same interpreter, on
the workers the first run warmed (Ray Data and canodom imported: ~3 s of the
first run), the throughput of a long job after its first logs. The per-log overhead of a Ray task comes from tiny
logs (one lap of the course): the job on 4N of them against the job on N, on
1 CPU, less the difference of the work inside the tasks, per extra log.
"""

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
RC_CAR = REPO / "daemon/examples/rc_car.toml"

JOB = """
import json, sys, time, contextlib, io
import ray
started = time.perf_counter()
ray.init(num_cpus=int(sys.argv[3]), include_dashboard=False, log_to_driver=False)
init_s = time.perf_counter() - started
from canodom.fleet import run
from pathlib import Path
started = time.perf_counter()
with contextlib.redirect_stdout(io.StringIO()):
    tables = run(Path(sys.argv[1]), Path(sys.argv[2]))
job_s = time.perf_counter() - started
summary = tables["summary"].to_pylist()
warm_s = None
if sys.argv[4] == "warm":
    # The same job again on the same Ray: its workers have imported Ray Data
    # and canodom, as in a long job after its first logs.
    import shutil
    shutil.rmtree(sys.argv[2])
    started = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        run(Path(sys.argv[1]), Path(sys.argv[2]))
    warm_s = time.perf_counter() - started
print(json.dumps({"init_s": init_s, "job_s": job_s, "warm_s": warm_s, "frames": sum(r["frames"] for r in summary),
                  "task_s": sum(r["seconds"] for r in summary),
                  "errors": sum(1 for r in summary if r["error"])}))
"""


def uptime():
    """`uptime`'s load averages (1, 5, 15 min): the other work on the machine."""
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def simulate(cli, out, seed, laps):
    subprocess.run([cli, "simulate", "--config", str(RC_CAR), "--log", str(out), "--path", "random",
                    "--seed", str(seed), "--laps", str(laps)], check=True, capture_output=True)


def job(manifest, out, cpus, warm=False):
    done = subprocess.run([sys.executable, "-c", JOB, str(manifest), str(out), str(cpus), "warm" if warm else "cold"],
                          capture_output=True, text=True, check=True)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["errors"] == 0, result
    return result


def manifest_of(d, kind, count, laps, cli):
    lines = ["vehicle_id,log,config"]
    for i in range(count):
        log = d / f"{kind}{i}.log"
        if not log.exists():
            simulate(cli, log, 1000 + i, laps)
        lines.append(f"car-{i},{log},{RC_CAR}")
    manifest = d / f"{kind}-{count}.csv"
    manifest.write_text("\n".join(lines) + "\n")
    return manifest


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--logs", type=int, default=4)
    p.add_argument("--laps", type=int, default=400, help="work per log; Ray Data's ~5 s start must be small beside it")
    p.add_argument("--runs", type=int, default=3)
    a = p.parse_args()
    cli = os.environ.get("CANODOM_BIN", str(REPO / "target/release/canodom"))
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        long = manifest_of(d, "long", a.logs, a.laps, cli)
        rates = {1: [], 2: []}
        ratios, warm_ratios = [], []
        for run in range(a.runs):
            got = {}
            for cpus in (1, 2):
                before = uptime()
                r = job(long, d / f"out-{run}-{cpus}", cpus, warm=True)
                shutil.rmtree(d / f"out-{run}-{cpus}")  # 400 laps: ~0.5 GB of poses per log
                got[cpus] = r
                rates[cpus].append(r["frames"] / r["job_s"])
                print(f"run {run + 1}, {cpus} CPU(s): {a.logs} logs, {r['frames']} frames in {r['job_s']:.1f} s "
                      f"({r['frames'] / r['job_s']:,.0f} frames/s; ray.init {r['init_s']:.1f} s apart; "
                      f"{r['task_s']:.1f} s inside the tasks; the same job again on warm workers {r['warm_s']:.1f} s); "
                      f"load before: {before}; after: {uptime()}", flush=True)
            ratios.append(got[1]["job_s"] / got[2]["job_s"])
            warm_ratios.append(got[1]["warm_s"] / got[2]["warm_s"])
        print(f"median: 1 CPU {statistics.median(rates[1]):,.0f} frames/s, 2 CPUs {statistics.median(rates[2]):,.0f} "
              f"frames/s, scaling {statistics.median(ratios):.2f}x (runs: {', '.join(f'{x:.2f}' for x in ratios)}; "
              f"goal >= 1.8x); on warm workers {statistics.median(warm_ratios):.2f}x "
              f"(runs: {', '.join(f'{x:.2f}' for x in warm_ratios)})")
        few = manifest_of(d, "tiny", a.logs, 1, cli)
        many = manifest_of(d, "tiny", 4 * a.logs, 1, cli)
        overheads = []
        for run in range(a.runs):
            r1 = job(few, d / f"tiny-{run}-1", 1)
            r4 = job(many, d / f"tiny-{run}-4", 1)
            extra = (r4["job_s"] - r1["job_s"]) - (r4["task_s"] - r1["task_s"])
            overheads.append(extra / (3 * a.logs))
            print(f"run {run + 1}: {a.logs} tiny logs {r1['job_s']:.2f} s, {4 * a.logs} tiny logs "
                  f"{r4['job_s']:.2f} s (work inside the tasks {r1['task_s']:.2f} s, {r4['task_s']:.2f} s): "
                  f"{overheads[-1] * 1000:.0f} ms per log", flush=True)
        print(f"median per-log overhead of a Ray task (1 CPU): {statistics.median(overheads) * 1000:.0f} ms")


if __name__ == "__main__":
    main()
