#!/usr/bin/env python3
"""Where a window's heading error comes from: the fused heading against the gyro's and the wheels'.

For every window of --window-s seconds (every --step-s seconds from --from-s to --to-s), the
heading turn of the truth and, in % of it (degrees in brackets), the error of the turn of
- `fused`: the replay's fused heading (`heading_rad` of `canodom replay --out`);
- `gyro`: the drive's yaw-rate frames integrated alone, less --bias-dps and divided by --scale
  (what a filter that trusted the gyro with those values would turn; give the learnt values,
  e.g. from `replay --learnt-out`);
- `gyro-truth`: the same with the model's true bias and scale (meta.json): the gyro's floor;
- `rear`: the rear wheels alone (`odo_heading_rad`).

A fused error well beyond the gyro's shows the filter moving the heading away from its gyro (a
measurement of the wheels, a prior, a bias it re-learnt); one that the gyro shares is the gyro's
calibration. The yaw-rate frames are read from drive.log.zst as generate.py writes them: the
Toyota `KINEMATICS` (0x024) `YAW_RATE`, 10 bits from bit 1 big-endian, 0.244 deg/s, offset -125.

Example:
    heading_trace.py /tmp/mb-long/bmw320i/seed-101 pose.csv --bias-dps 0.1285 --scale 0.99964
"""
from __future__ import annotations

import argparse
import bisect
import csv
import io
import json
import math
import sys
from pathlib import Path

KINEMATICS_ID = "024"
YAW_STEP_DPS = 0.244
YAW_OFFSET_DPS = -125.0


def read_log_lines(path: Path) -> list[str]:
    raw = path.read_bytes()
    if path.suffix == ".zst":
        import zstandard

        raw = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(raw)).read()
    return raw.decode().splitlines()


def yaw_frames(lines: list[str]) -> tuple[list[float], list[float]]:
    """(t, yaw rate deg/s) of every KINEMATICS frame of a candump -L log."""
    ts, rates = [], []
    for line in lines:
        parts = line.split()
        if len(parts) != 3 or "#" not in parts[2]:
            continue
        cid, data = parts[2].split("#", 1)
        if cid != KINEMATICS_ID or len(data) < 4:
            continue
        b = bytes.fromhex(data)
        raw = ((b[0] & 0x3) << 8) | b[1]
        ts.append(float(parts[0].strip("()")))
        rates.append(raw * YAW_STEP_DPS + YAW_OFFSET_DPS)
    return ts, rates


def integrate(ts: list[float], rates: list[float], bias_dps: float, scale: float) -> list[float]:
    """The heading, rad, of the rates less the bias divided by the scale (each rate held until the
    next frame)."""
    h = [0.0]
    for k in range(1, len(ts)):
        h.append(h[-1] + math.radians((rates[k - 1] - bias_dps) / scale) * (ts[k] - ts[k - 1]))
    return h


def at(ts: list[float], vs: list[float], t: float) -> float:
    return vs[min(bisect.bisect_left(ts, t), len(vs) - 1)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog=__doc__.split("\n\n", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("drive", type=Path, help="a drive folder: drive.log.zst, truth.csv, meta.json")
    ap.add_argument("pose", help="canodom replay's pose CSV")
    ap.add_argument("--bias-dps", type=float, required=True, help="the gyro's bias to subtract, deg/s")
    ap.add_argument("--scale", type=float, default=1.0, help="the gyro's scale to divide by (1)")
    ap.add_argument("--from-s", type=float, default=600.0)
    ap.add_argument("--to-s", type=float, default=1200.0)
    ap.add_argument("--window-s", type=float, default=120.0)
    ap.add_argument("--step-s", type=float, default=30.0)
    a = ap.parse_args(argv)
    if a.scale <= 0 or a.window_s <= 0 or a.step_s <= 0:
        ap.error("--scale, --window-s and --step-s must be positive")
    log = a.drive / "drive.log.zst"
    if not log.exists():
        log = a.drive / "drive.log"
    yt, yr = yaw_frames(read_log_lines(log))
    if len(yt) < 2:
        print(f"heading_trace.py: no KINEMATICS frames in {log}", file=sys.stderr)
        return 1
    meta = json.loads((a.drive / "meta.json").read_text())["sensor_errors"]
    h_given = integrate(yt, yr, a.bias_dps, a.scale)
    h_true = integrate(yt, yr, meta["yaw_bias_dps"], meta["yaw_scale"])
    with open(a.drive / "truth.csv", newline="") as f:
        tr = list(csv.DictReader(f))
    tt = [float(r["t_unix_s"]) for r in tr]
    th = [float(r["heading_rad"]) for r in tr]
    with open(a.pose, newline="") as f:
        ps = list(csv.DictReader(f))
    pt = [float(r["t_unix_s"]) for r in ps]
    fused = [float(r["heading_rad"]) for r in ps]
    rear = [float(r["odo_heading_rad"]) for r in ps]
    t0 = tt[0]
    print(f"{'start':>7} {'truth':>8}  {'fused':>15} {'gyro':>15} {'gyro-truth':>15} {'rear':>15}"
          "   (turn error, % of the truth's turn (deg))")
    k = 0
    while a.from_s + k * a.step_s + a.window_s <= a.to_s + 1e-6:
        s = t0 + a.from_s + k * a.step_s
        e = s + a.window_s
        k += 1
        turn = math.degrees(at(tt, th, e) - at(tt, th, s))

        def err(ts, vs):
            d = math.degrees(at(ts, vs, e) - at(ts, vs, s)) - turn
            pct = 100 * d / turn if abs(turn) > 1 else float("nan")
            return f"{pct:+7.2f}({d:+6.2f})"

        print(f"{s - t0:7.1f} {turn:8.1f}  {err(pt, fused)} {err(yt, h_given)} {err(yt, h_true)} {err(pt, rear)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
