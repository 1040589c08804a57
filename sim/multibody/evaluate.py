#!/usr/bin/env python3
"""Judge canodom on multi-body drives: issue 30's table, gate rejections and NEES.

For every drive folder (holding drive.log[.zst], truth.csv, meta.json; the vehicle's
config.toml and config_yaw.toml one level up), this runs

    canodom replay --config <cfg> <log> --out <work>/pose.csv --truth truth.csv

without and with the yaw-rate sensor and reports the end error in % of the distance for
- rear-only: the CSV's `odo_*` columns (rear-wheel odometry),
- fused, wheels + steering: the CSV's fused pose, config.toml,
- fused, + yaw-rate sensor: the same with config_yaw.toml,
- the ten-line baseline: heading from the yaw-rate sensor with its bias taken as its mean
  over the log's first 3 s, distance from the rear wheels' mean speed (decoded here with
  cantools, independently of canodom).
Both canodom poses start at (0, 0, 0) at the first wheel sample; they are placed on the
truth's pose at that instant. Gate rejections are the rows whose `correction` column says
the gate rejected the window (`kept_rear`, `used_front`). NEES uses the CSV's `pos_std_m`
(square root of the largest eigenvalue of the position covariance, so |e|^2 / pos_std^2 is
a lower bound of the 2-D NEES, whose mean is 2 when consistent) and `heading_std_rad`
(mean 1 when consistent).
"""
from __future__ import annotations

import argparse
import csv
import io
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
DBC = REPO / "data" / "dbc" / "opendbc_toyota_2017.dbc"
REJECTED = ("kept_rear", "used_front")


def read_log_text(path: Path) -> str:
    raw = path.read_bytes()
    if path.suffix == ".zst":
        import zstandard

        raw = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(raw)).read()
    return raw.decode()


def decode_sensors(log: Path):
    """Rear wheel speeds (m/s) and yaw rate (rad/s) with their times, via cantools."""
    import cantools

    db = cantools.database.load_file(str(DBC), strict=False)
    ws = db.get_message_by_name("WHEEL_SPEEDS")
    kin = db.get_message_by_name("KINEMATICS")
    tw, vr, tk, yr = [], [], [], []
    for line in read_log_text(log).splitlines():
        if not line:
            continue
        ts, _iface, frame = line.split()
        t = float(ts[1:-1])
        ident, data = frame.split("#")
        fid = int(ident, 16)
        if fid == ws.frame_id:
            d = ws.decode(bytes.fromhex(data))
            tw.append(t)
            vr.append(0.5 * (d["WHEEL_SPEED_RL"] + d["WHEEL_SPEED_RR"]) / 3.6)
        elif fid == kin.frame_id:
            d = kin.decode(bytes.fromhex(data))
            tk.append(t)
            yr.append(math.radians(d["YAW_RATE"]))
    return np.array(tw), np.array(vr), np.array(tk), np.array(yr)


def read_truth(path: Path):
    a = np.genfromtxt(path, delimiter=",", names=True)
    return a["t_unix_s"], a["x_m"], a["y_m"], np.unwrap(a["heading_rad"])


def truth_at(truth, t):
    tt, x, y, h = truth
    return np.interp(t, tt, x), np.interp(t, tt, y), np.interp(t, tt, h)


def path_length(truth, t0: float, t1: float) -> float:
    tt, x, y, _ = truth
    m = (tt >= t0) & (tt <= t1)
    return float(np.sum(np.hypot(np.diff(x[m]), np.diff(y[m]))))


def baseline(log: Path, truth):
    """The issue's ten lines: gyro heading (bias = mean of the first 3 s), rear mean speed."""
    tw, vr, tk, yr = decode_sensors(log)
    t_first = min(tw[0], tk[0])
    bias = yr[tk < t_first + 3.0].mean()
    heading = np.concatenate([[0.0], np.cumsum((yr[1:] - bias) * np.diff(tk))])
    x0, y0, h0 = truth_at(truth, tw[0])
    h = h0 + np.interp(tw, tk, heading) - np.interp(tw[0], tk, heading)
    dt = np.diff(tw)
    x = x0 + np.concatenate([[0.0], np.cumsum(vr[1:] * dt * np.cos(h[1:]))])
    y = y0 + np.concatenate([[0.0], np.cumsum(vr[1:] * dt * np.sin(h[1:]))])
    xt, yt, _ = truth_at(truth, tw[-1])
    return math.hypot(x[-1] - xt, y[-1] - yt), tw[0], tw[-1], bias


def run_replay(canodom: str, config: Path, log: Path, truth: Path, out: Path):
    out.parent.mkdir(parents=True, exist_ok=True)
    cmd = [canodom, "replay", "--config", str(config), str(log), "--out", str(out), "--truth", str(truth)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stderr}")
    rows = list(csv.DictReader(open(out)))
    cols = {k: np.array([float(rw[k]) for rw in rows]) for k in (
        "x_m", "y_m", "heading_rad", "odo_x_m", "odo_y_m", "odo_heading_rad", "t_unix_s",
        "pos_std_m", "heading_std_rad")}
    cols["correction"] = [rw["correction"] for rw in rows]
    return cols, r.stderr, " ".join(cmd)


def place(cols, truth, prefix: str):
    """The replay's track (starting at 0,0,0) in the truth's frame."""
    t = cols["t_unix_s"]
    x0, y0, h0 = truth_at(truth, t[0])
    xe, ye, he = cols[prefix + "x_m"], cols[prefix + "y_m"], cols[prefix + "heading_rad"]
    c, s = math.cos(h0), math.sin(h0)
    return x0 + c * xe - s * ye, y0 + s * xe + c * ye, h0 + he


def end_error(cols, truth, prefix: str) -> float:
    x, y, _ = place(cols, truth, prefix)
    xt, yt, _ = truth_at(truth, cols["t_unix_s"][-1])
    return math.hypot(x[-1] - xt, y[-1] - yt)


def nees(cols, truth):
    x, y, h = place(cols, truth, "")
    xt, yt, ht = truth_at(truth, cols["t_unix_s"])
    ep2 = (x - xt) ** 2 + (y - yt) ** 2
    eh = h - ht
    sp, sh = cols["pos_std_m"], cols["heading_std_rad"]
    # NEES is undefined where sigma is 0 (e.g. a launch below the wheel-speed floor, where
    # the car moves and the filter sees nothing): those steps count in the 3-sigma share
    # (outside unless the error is 0 too) and are left out of the means.
    mp = sp > 0
    mh = sh > 0
    return {
        "pos_nees_mean": float(np.mean(ep2[mp] / sp[mp] ** 2)) if mp.any() else float("nan"),
        "pos_nees_median": float(np.median(ep2[mp] / sp[mp] ** 2)) if mp.any() else float("nan"),
        "pos_in_3sigma": float(np.mean(ep2 <= 9 * sp**2)),
        "head_nees_mean": float(np.mean(eh[mh] ** 2 / sh[mh] ** 2)) if mh.any() else float("nan"),
        "head_nees_median": float(np.median(eh[mh] ** 2 / sh[mh] ** 2)) if mh.any() else float("nan"),
        "head_in_3sigma": float(np.mean(np.abs(eh) <= 3 * sh)),
        "zero_sigma_with_error": int(np.sum((sp == 0) & (ep2 > 1e-4))),
        "end_pos_err_m": float(math.sqrt(ep2[-1])),
        "end_pos_std_m": float(sp[-1]),
        "end_head_err_deg": float(np.degrees(eh[-1])),
        "end_head_std_deg": float(np.degrees(sh[-1])),
    }


def find_log(d: Path) -> Path:
    for name in ("drive.log.zst", "drive.log"):
        if (d / name).exists():
            return d / name
    raise FileNotFoundError(f"{d}: no drive.log.zst or drive.log")


def evaluate_drive(d: Path, canodom: str, work: Path) -> dict:
    meta = json.loads((d / "meta.json").read_text())
    log = find_log(d)
    truth_path = d / "truth.csv"
    truth = read_truth(truth_path)
    res = {"drive": f"{meta['vehicle']} seed {meta['seed']}", "meta": meta}
    tag = f"{meta['vehicle']}-{meta['seed']}"
    plain, err_plain, cmd_plain = run_replay(canodom, d.parent / "config.toml", log, truth_path, work / tag / "pose.csv")
    yaw, err_yaw, cmd_yaw = run_replay(canodom, d.parent / "config_yaw.toml", log, truth_path, work / tag / "pose_yaw.csv")
    t0, t1 = plain["t_unix_s"][0], plain["t_unix_s"][-1]
    dist = path_length(truth, t0, t1)
    res["distance_m"] = dist
    res["rear_only_pct"] = 100 * end_error(plain, truth, "odo_") / dist
    res["fused_pct"] = 100 * end_error(plain, truth, "") / dist
    res["fused_yaw_pct"] = 100 * end_error(yaw, truth, "") / dist
    b_err, bt0, bt1, bias = baseline(log, truth)
    res["baseline_pct"] = 100 * b_err / path_length(truth, bt0, bt1)
    res["baseline_bias_dps"] = math.degrees(bias)
    res["rejections"] = sum(c in REJECTED for c in plain["correction"])
    res["rejections_yaw"] = sum(c in REJECTED for c in yaw["correction"])
    res["nees_plain"] = nees(plain, truth)
    res["nees_yaw"] = nees(yaw, truth)
    res["stderr_plain"] = err_plain
    res["stderr_yaw"] = err_yaw
    res["commands"] = [cmd_plain, cmd_yaw]
    return res


def describe(meta: dict) -> str:
    st = meta["stats"]
    bits = []
    locked = {w: v for w, v in st["wheel_locked_s"].items() if v >= 0.1}
    if locked:
        bits.append("locks " + ",".join(f"{w} {v:.1f} s" for w, v in locked.items()))
    spin = {w: v for w, v in st["wheel_spinning_s"].items() if v >= 0.1}
    if spin:
        bits.append("spins " + ",".join(f"{w} {v:.1f} s" for w, v in spin.items()))
    if st["true_standstill_s"] >= 1.0:
        bits.append(f"standstill {st['true_standstill_s']:.0f} s")
    return "; ".join(bits) or "no slip, no stop"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="canodom against multi-body drives (issue 30's table).")
    ap.add_argument("drives", nargs="+", type=Path,
                    help="drive folders (with drive.log[.zst], truth.csv, meta.json), or roots to search")
    ap.add_argument("--canodom", default=os.environ.get("CANODOM", "canodom"), help="the canodom binary")
    ap.add_argument("--work", type=Path, default=Path("/tmp/mb-eval"), help="where pose CSVs go")
    ap.add_argument("--json", type=Path, help="write every figure here too")
    ap.add_argument("--check", action="store_true",
                    help="exit with status 1 when a drive misses one of issue 30's acceptance figures")
    args = ap.parse_args(argv)
    dirs: list[Path] = []
    for p in args.drives:
        dirs += sorted({m.parent for m in p.rglob("meta.json")}) if not (p / "meta.json").exists() else [p]
    results = []
    for d in dirs:
        r = evaluate_drive(d, args.canodom, args.work)
        results.append(r)
        print(f"# {d}: done", file=sys.stderr, flush=True)
    print("| drive | events | km | rear-only | fused, wheels + steering | fused, + yaw-rate sensor "
          "| ten-line baseline | gate rejections (no gyro / gyro) |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for r in results:
        print(f"| {r['drive']} | {describe(r['meta'])} | {r['distance_m'] / 1000:.2f} | {r['rear_only_pct']:.2f} % "
              f"| {r['fused_pct']:.2f} % | {r['fused_yaw_pct']:.2f} % | {r['baseline_pct']:.2f} % "
              f"| {r['rejections']} / {r['rejections_yaw']} |")
    print()
    print("| drive | config | position NEES mean / median (lower bound; 2 if consistent) | inside 3 sigma "
          "| heading NEES mean / median (1 if consistent) | inside 3 sigma | steps with sigma 0 and error > 1 cm "
          "| end error / sigma: position m, heading deg |")
    print("|---|---|---:|---:|---:|---:|---:|---|")
    for r in results:
        for key, name in (("nees_plain", "no gyro"), ("nees_yaw", "gyro")):
            n = r[key]
            print(f"| {r['drive']} | {name} | {n['pos_nees_mean']:.3g} / {n['pos_nees_median']:.3g} "
                  f"| {100 * n['pos_in_3sigma']:.0f} % "
                  f"| {n['head_nees_mean']:.3g} / {n['head_nees_median']:.3g} | {100 * n['head_in_3sigma']:.0f} % "
                  f"| {n['zero_sigma_with_error']} "
                  f"| {n['end_pos_err_m']:.1f} / {n['end_pos_std_m']:.2f}, "
                  f"{n['end_head_err_deg']:.2f} / {n['end_head_std_deg']:.2f} |")
    # Issue 30's acceptance figures, drive by drive.
    criteria = [
        ("with the gyro, fused <= 1.0 % of the distance", lambda r: r["fused_yaw_pct"] <= 1.0),
        ("with the gyro, fused <= the better of rear-only and the gyro baseline",
         lambda r: r["fused_yaw_pct"] <= min(r["rear_only_pct"], r["baseline_pct"])),
        ("without the gyro, fused <= rear-only + 0.05 %", lambda r: r["fused_pct"] <= r["rear_only_pct"] + 0.05),
    ]
    print()
    failed = False
    for text, ok in criteria:
        bad = [r["drive"] for r in results if not ok(r)]
        failed |= bool(bad)
        print(f"{len(results) - len(bad)} of {len(results)} drives: {text}" + (f" (not: {', '.join(bad)})" if bad else ""))
    if args.json:
        slim = [{k: v for k, v in r.items() if k != "meta"} | {"events": describe(r["meta"])} for r in results]
        args.json.write_text(json.dumps(slim, indent=1) + "\n")
    return 1 if failed and args.check else 0


if __name__ == "__main__":
    sys.exit(main())
