"""Decode to Arrow with canodom against cantools + pandas, same log, same run.

    python python/bench/decode_vs_cantools.py [LOG] [DBC] [--repeat N]

Defaults: the RAV4 log (data/comma2k19-rav4) repeated --repeat times into one
file (a longer log with the same content), opendbc_toyota_2017.dbc. Prints
frames/s of each on one core, their ratio, and canodom's peak memory for logs
of 1x and 4x the length (memory flat in the log's size means the growth is
only the output's columns).
"""

import argparse
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def canodom_decode(log, dbc):
    import canodom

    start = time.perf_counter()
    tables = canodom.decode(log, dbc)
    return time.perf_counter() - start, sum(t.num_rows for t in tables.values())


def cantools_decode(log, dbc):
    """What users do today: cantools over the candump log into pandas frames per message."""
    import cantools
    import pandas as pd

    start = time.perf_counter()
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
    return time.perf_counter() - start, sum(len(f) for f in frames.values())


def peak_rss_mb(log, dbc):
    code = (f"import canodom, resource; canodom.decode({str(log)!r}, {str(dbc)!r}); "
            "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)")
    base = "import canodom, resource; print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)"
    used = float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout)
    idle = float(subprocess.run([sys.executable, "-c", base], capture_output=True, text=True, check=True).stdout)
    return used - idle


def main():
    p = argparse.ArgumentParser()
    p.add_argument("log", nargs="?", default=str(REPO / "data/comma2k19-rav4/drive.log"))
    p.add_argument("dbc", nargs="?", default=str(REPO / "data/dbc/opendbc_toyota_2017.dbc"))
    p.add_argument("--repeat", type=int, default=3)
    a = p.parse_args()
    text = Path(a.log).read_text()
    with tempfile.TemporaryDirectory() as d:
        log = Path(d) / "long.log"
        log.write_text(text * a.repeat)
        frames = sum(1 for _ in open(log))
        c_s, c_rows = canodom_decode(log, a.dbc)
        t_s, t_rows = cantools_decode(log, a.dbc)
        assert c_rows == t_rows, (c_rows, t_rows)
        print(f"log: {frames} frames, {c_rows} decoded")
        print(f"canodom.decode   : {frames / c_s:12,.0f} frames/s ({c_s:.3f} s)")
        print(f"cantools + pandas: {frames / t_s:12,.0f} frames/s ({t_s:.3f} s)")
        print(f"ratio            : {t_s / c_s:.1f}x")
        log4 = Path(d) / "long4.log"
        log4.write_text(text * a.repeat * 4)
        m1, m4 = peak_rss_mb(log, a.dbc), peak_rss_mb(log4, a.dbc)
        print(f"peak memory over an idle interpreter: {m1:.0f} MB ({frames} frames), "
              f"{m4:.0f} MB ({4 * frames} frames)")


if __name__ == "__main__":
    main()
