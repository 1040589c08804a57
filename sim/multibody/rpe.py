#!/usr/bin/env python3
"""Relative pose error over windows of a drive: a canodom pose CSV against the drive's truth.

Issue 46's measure: every window of --window-s seconds (default 120) starting every --step-s
seconds (default 30) between --from-s and --to-s (default 600..1200 s after the truth's first
sample) is dead-reckoned from the truth at the window's start: the pose's motion over the
window (its end expressed in its start's frame) is compared with the truth's, and the
distance between the two ends is given in % of the distance the truth drove in the window.
Windows in which the truth drives less than --min-distance-m are skipped (a % of a standstill
says nothing).

The pose CSV is `canodom replay --out`'s: t_unix_s with x_m, y_m, heading_rad (the fused
pose) or, with --rear, odo_x_m, odo_y_m, odo_heading_rad (the rear wheels alone). truth.csv is
generate.py's: t_unix_s, x_m, y_m, heading_rad of the rear-axle midpoint at 50 Hz, on the
log's clock. Both are sampled at the first record at or after each window end, so the pose's
own rate (one record per CAN step) sets the resolution.

--verbose prints each window: the error, the truth's and the pose's heading turn and their
difference in % of the truth's turn, and the error along and across the truth's start heading.
--json prints one object (windows, median, worst) for scripts.

Example:
    rpe.py /tmp/mb-long/bmw320i/seed-101/truth.csv pose.csv --verbose
    rpe.py truth.csv pose.csv --rear
"""
from __future__ import annotations

import argparse
import bisect
import csv
import json
import math
import statistics
import sys


def read_truth(path: str) -> list[tuple[float, float, float, float]]:
    """(t, x, y, heading) rows of generate.py's truth.csv."""
    with open(path, newline="") as f:
        rows = csv.DictReader(f)
        return [(float(r["t_unix_s"]), float(r["x_m"]), float(r["y_m"]), float(r["heading_rad"]))
                for r in rows]


def read_pose(path: str, rear: bool) -> list[tuple[float, float, float, float]]:
    """(t, x, y, heading) rows of a replay's pose CSV; the heading unwrapped, as the filter
    may wrap it and a window's turn is a difference of two headings."""
    cols = ("odo_x_m", "odo_y_m", "odo_heading_rad") if rear else ("x_m", "y_m", "heading_rad")
    out: list[tuple[float, float, float, float]] = []
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            h = float(r[cols[2]])
            if out:
                prev = out[-1][3]
                h = prev + math.remainder(h - prev, 2 * math.pi)
            out.append((float(r["t_unix_s"]), float(r[cols[0]]), float(r[cols[1]]), h))
    return out


def sample(rows, times, t):
    """The first row at or after t (the last one past the end)."""
    return rows[min(bisect.bisect_left(times, t), len(rows) - 1)]


def relative(a, b) -> tuple[float, float]:
    """b's position in a's frame (along, across a's heading)."""
    dx, dy = b[1] - a[1], b[2] - a[2]
    c, s = math.cos(a[3]), math.sin(a[3])
    return c * dx + s * dy, -s * dx + c * dy


def path_length(rows, times, t1, t2) -> float:
    i, j = bisect.bisect_left(times, t1), min(bisect.bisect_left(times, t2), len(rows) - 1)
    return sum(math.hypot(rows[k + 1][1] - rows[k][1], rows[k + 1][2] - rows[k][2]) for k in range(i, j))


def windows(truth, pose, t_from, t_to, window, step, min_distance):
    """One dict per window of the relative pose error."""
    tt = [r[0] for r in truth]
    pt = [r[0] for r in pose]
    t0 = truth[0][0]
    out = []
    k = 0
    while True:
        start = t0 + t_from + k * step
        end = start + window
        if end > t0 + t_to + 1e-6:
            break
        k += 1
        distance = path_length(truth, tt, start, end)
        if distance < min_distance:
            continue
        T1, T2 = sample(truth, tt, start), sample(truth, tt, end)
        P1, P2 = sample(pose, pt, start), sample(pose, pt, end)
        et, ep = relative(T1, T2), relative(P1, P2)
        turn_truth = math.degrees(T2[3] - T1[3])
        turn_pose = math.degrees(P2[3] - P1[3])
        out.append({
            "start_s": start - t0,
            "distance_m": distance,
            "error_pct": 100 * math.hypot(et[0] - ep[0], et[1] - ep[1]) / distance,
            "turn_truth_deg": turn_truth,
            "turn_pose_deg": turn_pose,
            "along_m": et[0] - ep[0],
            "across_m": et[1] - ep[1],
        })
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog=__doc__.split("\n\n", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("truth", help="generate.py's truth.csv")
    ap.add_argument("pose", help="canodom replay's pose CSV (--out)")
    ap.add_argument("--from-s", type=float, default=600.0, help="first window's start, s after the truth's start (600)")
    ap.add_argument("--to-s", type=float, default=1200.0, help="last window's end at most, s (1200)")
    ap.add_argument("--window-s", type=float, default=120.0, help="window length, s (120)")
    ap.add_argument("--step-s", type=float, default=30.0, help="between window starts, s (30)")
    ap.add_argument("--min-distance-m", type=float, default=50.0, help="skip windows shorter than this (50)")
    ap.add_argument("--rear", action="store_true", help="the rear wheels alone (odo_* columns)")
    ap.add_argument("--verbose", action="store_true", help="one line per window")
    ap.add_argument("--json", action="store_true", help="one JSON object")
    a = ap.parse_args(argv)
    if a.window_s <= 0 or a.step_s <= 0:
        ap.error("--window-s and --step-s must be positive")
    truth = read_truth(a.truth)
    pose = read_pose(a.pose, a.rear)
    if not truth or not pose:
        print("rpe.py: an empty truth or pose file", file=sys.stderr)
        return 1
    ws = windows(truth, pose, a.from_s, a.to_s, a.window_s, a.step_s, a.min_distance_m)
    if not ws:
        print("rpe.py: no window of the range drives --min-distance-m", file=sys.stderr)
        return 1
    errs = [w["error_pct"] for w in ws]
    median, worst = statistics.median(errs), max(errs)
    if a.json:
        print(json.dumps({"windows": ws, "median_pct": median, "worst_pct": worst}))
        return 0
    if a.verbose:
        for w in ws:
            turn_err = (100 * (w["turn_pose_deg"] - w["turn_truth_deg"]) / w["turn_truth_deg"]
                        if abs(w["turn_truth_deg"]) > 1 else float("nan"))
            print(f"{w['start_s']:7.1f} s  {w['error_pct']:6.3f} % of {w['distance_m']:5.0f} m  "
                  f"turn truth {w['turn_truth_deg']:8.1f} pose {w['turn_pose_deg']:8.1f} deg ({turn_err:+.2f} %)  "
                  f"along {w['along_m']:+6.2f} m across {w['across_m']:+6.2f} m")
    print(f"windows {len(ws)}: median {median:.3f} %, worst {worst:.3f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
