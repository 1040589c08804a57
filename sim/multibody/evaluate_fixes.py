#!/usr/bin/env python3
"""Issue 31's must-show: calibration from a drive's first minute with GNSS-like fixes.

For every drive folder (drive.log[.zst], truth.csv, meta.json; the vehicle's config_yaw.toml
one level up) and for two kinds of fixes made by `fixes.py` from the truth -- `gnss` (1 Hz,
σ 0.3 m, 0.2 s latency, two 15 m jumps over the first 60 s) and `clean` (the truth at 1 Hz) --
this runs

    canodom calibrate --config config_yaw.toml --fixes FIXES --out params.toml first.log
    canodom replay --config config_yaw.toml --params params.toml drive.log --out pose.csv

where first.log is the log cut at --split-s (60 s), FIXES the fixes in local metres (or, with
--format, their lat/lon CSV or pynmea2's NMEA), and reports
- the held-out rest (after the split) dead-reckoned from the truth's pose at the split, as
  the end error in % of the truth's distance over the rest, for the calibrated replay and for
  a replay without calibration (`replay` of the nominal configuration);
- the fitted parameters against the model's truth (meta.json), with the σ calibrate printed.

With --oracle it also replays the whole log with the model's true parameters (meta.json,
written as a committed set): the held-out rest then shows the fused filter's own floor on
the drive, which no calibration can go below. At the end, the z-scores of the fitted
parameters against the truth (share within 2σ and 3σ), over all drives.

With several --seed, every drive is run with each draw of the fixes and the summaries pool
them; a last line gives how far calibrating raised the rest over the uncalibrated replay.

`--check` exits 1 when a drive's held-out error with the GNSS-like fixes is above --bar-pct
(issue 31: 0.5 %).
"""
from __future__ import annotations

import argparse
import collections
import io
import json
import math
import os
import re
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import fixes as fixes_mod  # noqa: E402


def read_log_text(path: Path) -> str:
    raw = path.read_bytes()
    if path.suffix == ".zst":
        import zstandard

        raw = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(raw)).read()
    return raw.decode()


def find_log(d: Path) -> Path:
    for name in ("drive.log.zst", "drive.log"):
        if (d / name).exists():
            return d / name
    raise FileNotFoundError(f"{d}: no drive.log.zst or drive.log")


def cut_log(log: Path, split_s: float, out: Path) -> float:
    """The log's lines within split_s of its first frame, to out; returns the first time."""
    lines = read_log_text(log).splitlines()
    t0 = float(lines[0].split()[0][1:-1])
    kept = [ln for ln in lines if ln and float(ln.split()[0][1:-1]) - t0 < split_s]
    out.write_text("\n".join(kept) + "\n")
    return t0


def run(cmd: list[str]) -> subprocess.CompletedProcess:
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stdout}\n{r.stderr}")
    return r


def read_pose(path: Path, prefix: str = ""):
    a = np.genfromtxt(path, delimiter=",", names=True)
    return a["t_unix_s"], a[prefix + "x_m"], a[prefix + "y_m"], a[prefix + "heading_rad"]


def held_out(pose, truth, t_split: float):
    """End error (m) of the pose's motion after t_split placed on the truth there, and the distance."""
    t, x, y, h = pose
    tt, tx, ty, th = truth
    a = int(np.argmin(np.abs(t - t_split)))
    b = len(t) - 1
    c, s = math.cos(-h[a]), math.sin(-h[a])
    dx, dy = x[b] - x[a], y[b] - y[a]
    bx, by = c * dx - s * dy, s * dx + c * dy
    x0, y0, h0 = (float(np.interp(t[a], tt, v)) for v in (tx, ty, th))
    px = x0 + math.cos(h0) * bx - math.sin(h0) * by
    py = y0 + math.sin(h0) * bx + math.cos(h0) * by
    ex, ey = float(np.interp(t[b], tt, tx)), float(np.interp(t[b], tt, ty))
    m = (tt >= t[a]) & (tt <= t[b])
    dist = float(np.sum(np.hypot(np.diff(tx[m]), np.diff(ty[m]))))
    return math.hypot(px - ex, py - ey), dist


# calibrate's report lines: "  <name>  <value><unit> ± <sigma><unit>" (or "held: ...").
LINE = re.compile(r"^  (?P<name>[a-z][^±0-9+]*?)\s+(?P<v>[+-][0-9.]+)(?P<u>[^ ±]*) ± (?P<s>[0-9.]+)")


def report_name(name: str) -> str:
    """calibrate's name without its unit's remark: "steering gain (× the one in use)" ->
    "steering gain"; "rear ratio (R/L)" stays (the truth's names are these)."""
    name = name.strip()
    return name if name == "rear ratio (R/L)" else re.sub(r"\s*\(.*\)$", "", name)


# A value the quality gate refused: "  <name>  held: refused by the quality gate (fitted <v> ± <σ>; below)".
REFUSED = re.compile(r"^  (?P<name>[a-z][^±0-9+]*?)\s{2,}held: refused by the quality gate "
                     r"\(fitted (?P<v>[+-]?[0-9.]+)(?P<u>[^ ±]*) ± (?P<s>[0-9.]+)")


def parse_report(text: str) -> dict:
    """Each parameter's (value, σ, committed) from calibrate's report; None when the drive
    could not tell it."""
    got = {}
    for ln in text.splitlines():
        r = REFUSED.match(ln)
        m = None if r else LINE.match(ln)
        if r:
            got[report_name(r["name"])] = (float(r["v"]), float(r["s"]), False)
        elif m:
            got[report_name(m["name"])] = (float(m["v"]), float(m["s"]), True)
        elif ln.startswith("  ") and "held" in ln:
            name = re.split(r"\s{2,}", ln.strip())[0]
            got[report_name(name)] = None
    return got


def truth_params(meta: dict) -> dict:
    """The model's truth in calibrate's terms (against the nominal configuration)."""
    e = meta["sensor_errors"]
    ws = e["wheel_scale"]
    return {
        # Distances read by the wheels are true × scale: the true correction divides them.
        "speed scale": 2.0 / (ws["RL"] + ws["RR"]),
        "rear ratio (R/L)": ws["RL"] / ws["RR"],
        # φ = u / ratio_true − offset, u the steering wheel angle; the map in use is u / ratio_nominal.
        "steering offset": -e["steer_offset_road_deg"],
        "steering gain": e["steer_ratio_nominal"] / e["steer_ratio_true"],
        "yaw-rate bias": e["yaw_bias_dps"],
        "yaw-rate scale": e["yaw_scale"],
    }


def config_number(text: str, key: str) -> float:
    m = re.search(rf"^{key}\s*=\s*([0-9.eE+-]+)", text, re.M)
    if not m:
        raise ValueError(f"configuration has no {key}")
    return float(m.group(1))


def oracle_set(meta: dict, config_text: str) -> str:
    """The model's true parameters as a committed parameter set (the text `calibrate --out`
    writes; its checksum is calib/src/history.rs's ParamSet::checksum, CRC-32/ISO-HDLC over
    the version, time, method and the values' bits, little-endian; `replay` refuses a set
    whose checksum does not match, so a drift of that format fails loudly here).

    The rear tread is the configuration's (the model's geometric one); the yaw-rate bias's σ
    is 0.01°/s (the truth, as sure as a long calibration would make it)."""
    e = meta["sensor_errors"]
    diameter = config_number(config_text, "wheel_diameter_m")
    values = [
        ("rear_tread_m", config_number(config_text, "rear_tread_m")),
        # A wheel reading true × scale is a wheel of diameter nominal / scale.
        ("rear_left_diameter_m", diameter / e["wheel_scale"]["RL"]),
        ("rear_right_diameter_m", diameter / e["wheel_scale"]["RR"]),
        ("steering_gain", math.radians(1.0) / e["steer_ratio_true"]),
        ("steering_offset_rad", -math.radians(e["steer_offset_road_deg"])),
    ]
    optional = [
        ("yaw_rate_bias_radps", math.radians(e["yaw_bias_dps"])),
        ("yaw_rate_scale", e["yaw_scale"]),
        ("yaw_rate_bias_sigma_radps", math.radians(0.01)),
    ]
    version, created, method = 1, int(e.get("t0_unix_s", 0)), "oracle"
    raw = struct.pack("<HQQ", version, created, len(method)) + method.encode()
    raw += b"".join(struct.pack("<d", v) for _, v in values)
    raw += b"".join(n.encode() + struct.pack("<d", v) for n, v in optional)
    lines = ["# The model's true parameters (evaluate_fixes.py --oracle).", "format_version = 1",
             "last_version = 1", "", "[current]", f"version = {version}", f"created_unix_s = {created}",
             f'method = "{method}"'] + [f"{n} = {v!r}" for n, v in values + optional]
    lines.append(f'checksum = "{zlib.crc32(raw) & 0xFFFFFFFF:08x}"')
    return "\n".join(lines) + "\n"


def evaluate(d: Path, canodom: str, work: Path, split_s: float, seed: int, fmt: str,
             oracle: bool = False) -> dict:
    meta = json.loads((d / "meta.json").read_text())
    tag = f"{meta['vehicle']}-{meta['seed']}"
    w = work / tag
    w.mkdir(parents=True, exist_ok=True)
    log = find_log(d)
    config = d.parent / "config_yaw.toml"
    truth = fixes_mod.read_truth(d / "truth.csv")
    first = w / "first.log"
    t0 = cut_log(log, split_s, first)
    res = {"drive": f"{meta['vehicle']} seed {meta['seed']}", "truth": truth_params(meta)}
    plain = w / "plain.csv"
    run([canodom, "replay", "--config", str(config), str(log), "--out", str(plain)])
    err, dist = held_out(read_pose(plain), truth, t0 + split_s)
    res["uncalibrated_pct"] = 100 * err / dist
    res["distance_m"] = dist
    if oracle:
        oracle_params = w / "oracle.toml"
        oracle_params.write_text(oracle_set(meta, config.read_text()))
        oracle_pose = w / "oracle.csv"
        run([canodom, "replay", "--config", str(config), "--params", str(oracle_params), str(log),
             "--out", str(oracle_pose)])
        err, _ = held_out(read_pose(oracle_pose), truth, t0 + split_s)
        res["oracle_pct"] = 100 * err / dist
    for kind in ("gnss", "clean"):
        fx_dir = w / kind
        t, x, y, record = fixes_mod.make_fixes(truth, seed=seed * 1000 + meta["seed"], window_s=split_s,
                                               clean=kind == "clean")
        fixes_mod.write_all(fx_dir, t, x, y, record)
        fixes = fx_dir / {"csv": "fixes.csv", "geo": "fixes_geo.csv", "nmea": "fixes.nmea"}[fmt]
        params = w / f"params-{kind}.toml"
        params.unlink(missing_ok=True)
        r = subprocess.run([canodom, "calibrate", "--config", str(config), "--fixes", str(fixes), "--out",
                            str(params), str(first)], capture_output=True, text=True)
        (w / f"calibrate-{kind}.txt").write_text(r.stdout + r.stderr)
        refused = "nothing passed the quality gate" in r.stderr
        if r.returncode != 0 and not refused:
            raise RuntimeError(f"calibrate failed ({r.returncode}):\n{r.stdout}\n{r.stderr}")
        pose = w / f"pose-{kind}.csv"
        # A refused fit leaves the parameters as they were: the rest is then
        # the uncalibrated replay, which is what the user would drive on.
        with_params = [] if refused else ["--params", str(params)]
        run([canodom, "replay", "--config", str(config), *with_params, str(log), "--out", str(pose)])
        err, _ = held_out(read_pose(pose), truth, t0 + split_s)
        rear, _ = held_out(read_pose(pose, "odo_"), truth, t0 + split_s)
        res[kind] = {"held_out_pct": 100 * err / dist, "rear_only_pct": 100 * rear / dist,
                     "fit": parse_report(r.stdout), "report": r.stdout, "jumps": record["jumps"],
                     "refused": refused}
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="issue 31's must-show on multi-body drives")
    ap.add_argument("drives", nargs="+", type=Path, help="drive folders, or roots to search for meta.json")
    ap.add_argument("--canodom", default=os.environ.get("CANODOM", "canodom"))
    ap.add_argument("--work", type=Path, default=Path("/tmp/mb-fixes"))
    ap.add_argument("--split-s", type=float, default=60.0)
    ap.add_argument("--seed", type=int, nargs="+", default=[31],
                    help="the fixes' seeds (each combined with the drive's); several: every drive with "
                         "each draw, the z-scores pooled over all")
    ap.add_argument("--format", choices=("csv", "geo", "nmea"), default="csv",
                    help="which of fixes.py's files calibrate reads")
    ap.add_argument("--bar-pct", type=float, default=0.5)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--check", action="store_true")
    ap.add_argument("--oracle", action="store_true",
                    help="also replay with the model's true parameters (the filter's floor)")
    ap.add_argument("--verbose", action="store_true", help="print calibrate's reports")
    a = ap.parse_args(argv)
    dirs: list[Path] = []
    for p in a.drives:
        dirs += [p] if (p / "meta.json").exists() else sorted({m.parent for m in p.rglob("meta.json")})
    results = []
    for seed in a.seed:
        work = a.work if len(a.seed) == 1 else a.work / f"fixes-{seed}"
        for d in dirs:
            r = evaluate(d, a.canodom, work, a.split_s, seed, a.format, a.oracle)
            r["fixes_seed"] = seed
            if len(a.seed) > 1:
                r["drive"] += f" (fixes {seed})"
            results.append(r)
    floor = " true parameters |" if a.oracle else ""
    print(f"| drive | rest km | uncalibrated |{floor} GNSS-like fixes: fused / rear-only | clean fixes: fused / rear-only |")
    print("|---|---:|---:|" + ("---:|" if a.oracle else "") + "---:|---:|")
    for r in results:
        g, c = r["gnss"], r["clean"]
        floor = f" {r['oracle_pct']:.2f} % |" if a.oracle else ""
        print(f"| {r['drive']} | {r['distance_m'] / 1000:.2f} | {r['uncalibrated_pct']:.2f} % |{floor}"
              f" {g['held_out_pct']:.2f} % / {g['rear_only_pct']:.2f} %{' (refused)' if g['refused'] else ''} "
              f"| {c['held_out_pct']:.2f} % / {c['rear_only_pct']:.2f} % |")
    print()
    names = list(results[0]["truth"]) if results else []
    print("| drive | fixes | " + " | ".join(names) + " |")
    print("|---|---|" + "---:|" * len(names))
    for r in results:
        print(f"| {r['drive']} | truth | " + " | ".join(f"{r['truth'][n]:+.5f}" for n in names) + " |")
        for kind in ("gnss", "clean"):
            fit = r[kind]["fit"]
            cells = []
            for n in names:
                v = fit.get(n)
                if v is None:
                    cells.append("held")
                else:
                    z = (v[0] - r["truth"][n]) / v[1] if v[1] > 0 else float("inf")
                    cells.append(f"{v[0]:+.5f} ± {v[1]:.5f} ({z:+.1f}σ{'' if v[2] else ', refused'})")
            print(f"| {r['drive']} | {kind} | " + " | ".join(cells) + " |")
    print()
    print("| fixes | parameter | fitted | within 2σ | within 3σ | RMS z | largest \\|z\\| |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for kind in ("gnss", "clean"):
        z = collections.defaultdict(list)
        for r in results:
            for n in names:
                v = r[kind]["fit"].get(n)
                if v is not None and v[1] > 0:
                    z[n].append(abs(v[0] - r["truth"][n]) / v[1])
        for n in names:
            if z[n]:
                zz = np.array(z[n])
                print(f"| {kind} | {n} | {len(zz)} | {100 * np.mean(zz <= 2):.0f} % | {100 * np.mean(zz <= 3):.0f} % "
                      f"| {np.sqrt(np.mean(zz * zz)):.2f} | {zz.max():.1f} |")
    if a.verbose:
        for r in results:
            for kind in ("gnss", "clean"):
                print(f"\n## {r['drive']}, {kind}\n{r[kind]['report']}")
    bad = [r["drive"] for r in results if r["gnss"]["held_out_pct"] > a.bar_pct]
    print(f"\n{len(results) - len(bad)} of {len(results)} drives: held-out with GNSS-like fixes <= {a.bar_pct} %"
          + (f" (not: {', '.join(bad)})" if bad else ""))
    # A calibration that hurts: the calibrated rest against the uncalibrated one.
    rise = sorted(((r["gnss"]["held_out_pct"] - r["uncalibrated_pct"], r["drive"]) for r in results), reverse=True)
    if rise:
        print(f"calibrated minus uncalibrated (GNSS-like): largest {rise[0][0]:+.2f} % ({rise[0][1]}); "
              f"{sum(x > 0.1 for x, _ in rise)} of {len(rise)} above +0.10 %")
    if a.oracle:
        floor = [r["drive"] for r in results if r["oracle_pct"] > a.bar_pct]
        print(f"with the true parameters, {len(floor)} of {len(results)} above {a.bar_pct} %"
              + (f" ({', '.join(floor)})" if floor else ""))
    if a.json:
        a.json.write_text(json.dumps(results, indent=1) + "\n")
    return 1 if bad and a.check else 0


if __name__ == "__main__":
    sys.exit(main())
