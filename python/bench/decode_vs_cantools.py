"""Decode to Arrow with canodom against cantools + pandas, same log, same run.

    python python/bench/decode_vs_cantools.py [LOG] [DBC] [--repeat N]

Defaults: the RAV4 log (data/comma2k19-rav4) repeated --repeat times into one
file (a longer log with the same content), opendbc_toyota_2017.dbc. Prints
frames/s of each (wall and CPU time: canodom.decode runs on the calling
thread, one core), their ratio, each --runs times after --warmup uncounted
runs of both, and the median; then
canodom's peak memory (VmHWM of a fresh interpreter, over the same
interpreter's after its imports) for logs of 1x, 4x, 16x and 64x the length,
beside the size of the tables it returns: decode returns every decoded
value, so what can be flat is the memory beyond its output; and the same
for decode_batches, the stream, whose batches are dropped as they come:
its peak is what a consumer of a log larger than memory needs.
"""

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def canodom_decode(log, dbc):
    import canodom

    start, cpu = time.perf_counter(), time.process_time()
    tables = canodom.decode(log, dbc)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    return wall, cpu, sum(t.num_rows for t in tables.values())


def cantools_decode(log, dbc):
    """What users do today: cantools over the candump log into pandas frames per message."""
    import cantools
    import pandas as pd

    start, cpu = time.perf_counter(), time.process_time()
    db = cantools.database.load_file(str(dbc), strict=False)
    by_id = {m.frame_id: m for m in db.messages}
    rows = {}
    with open(log) as f:
        for line in f:
            t, _, frame = line.split()
            ident, _, data = frame.partition("#")
            m = by_id.get(int(ident, 16))
            if m is None:
                continue
            try:
                values = m.decode(bytes.fromhex(data), decode_choices=False)
            except Exception:
                continue
            values["t_unix_s"] = float(t[1:-1])
            rows.setdefault(m.name, []).append(values)
    frames = {name: pd.DataFrame(r) for name, r in rows.items()}
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    return wall, cpu, sum(len(f) for f in frames.values())


def peak_rss_mb(log, dbc, stream=False):
    """(peak RSS growth over the interpreter after its imports, size of the
    output), MB: decode's tables, or (stream) decode_batches' batches, each
    dropped once counted, as a consumer writing them on would."""
    # VmHWM, not ru_maxrss: a child's ru_maxrss starts at its parent's peak
    # (it survives fork and exec), this bench's own, which holds the logs' text.
    work = (f"size = 0\nfor _, b in canodom.decode_batches({str(log)!r}, {str(dbc)!r}):\n    size += b.nbytes\n"
            if stream else
            f"tables = canodom.decode({str(log)!r}, {str(dbc)!r})\n"
            "size = sum(t.nbytes for t in tables.values())\n")
    code = ("import canodom, pyarrow\n"
            "hwm = lambda: int(open('/proc/self/status').read().split('VmHWM:')[1].split()[0])\n"
            "before = hwm()\n"
            + work +
            "peak = hwm()\n"
            "print((peak - before) / 1024, size / 2**20)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    grown, output = map(float, out.split())
    return grown, output


def main():
    p = argparse.ArgumentParser()
    p.add_argument("log", nargs="?", default=str(REPO / "data/comma2k19-rav4/drive.log"))
    p.add_argument("dbc", nargs="?", default=str(REPO / "data/dbc/opendbc_toyota_2017.dbc"))
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--warmup", type=int, default=1, help="runs of both first, not counted (page cache, allocator)")
    a = p.parse_args()
    text = Path(a.log).read_text()
    with tempfile.TemporaryDirectory() as d:
        log = Path(d) / "long.log"
        log.write_text(text * a.repeat)
        frames = sum(1 for _ in open(log))
        print(f"log: {frames} frames; load (uptime): {os.getloadavg()}")
        for _ in range(a.warmup):
            canodom_decode(log, a.dbc)
            cantools_decode(log, a.dbc)
        ratios, ours, theirs = [], [], []
        for run in range(a.runs):
            c_wall, c_cpu, c_rows = canodom_decode(log, a.dbc)
            t_wall, t_cpu, t_rows = cantools_decode(log, a.dbc)
            assert c_rows == t_rows, (c_rows, t_rows)
            ours.append(frames / c_cpu)
            theirs.append(frames / t_cpu)
            ratios.append(t_cpu / c_cpu)
            print(f"run {run + 1}: canodom.decode {frames / c_wall:,.0f} frames/s wall, {frames / c_cpu:,.0f} per "
                  f"CPU second; cantools + pandas {frames / t_wall:,.0f} wall, {frames / t_cpu:,.0f} per CPU second; "
                  f"ratio {t_wall / c_wall:.1f}x wall, {t_cpu / c_cpu:.1f}x CPU ({c_rows} rows decoded); load {os.getloadavg()[0]:.2f}", flush=True)
        print(f"median: canodom.decode {statistics.median(ours):,.0f} frames per CPU second, cantools + pandas "
              f"{statistics.median(theirs):,.0f}, ratio {statistics.median(ratios):.1f}x (goal >= 30x); "
              f"load (uptime) now {os.getloadavg()}", flush=True)
        for times in (1, 4, 16, 64):
            big = Path(d) / f"long{times}.log"
            big.write_text(text * a.repeat * times)
            grown, output = peak_rss_mb(big, a.dbc)
            print(f"memory, {times * frames} frames ({big.stat().st_size / 2**20:.0f} MB log): decode's peak grew "
                  f"{grown:.0f} MB, tables returned {output:.0f} MB, beyond them {grown - output:.0f} MB")
            grown, output = peak_rss_mb(big, a.dbc, stream=True)
            print(f"  decode_batches, each batch dropped once counted: peak grew {grown:.0f} MB "
                  f"({output:.0f} MB of batches went through)", flush=True)
            big.unlink()


if __name__ == "__main__":
    main()
