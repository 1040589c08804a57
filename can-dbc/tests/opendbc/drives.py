#!/usr/bin/env python3
"""Every `config init` platform driven through opendbc's packer and replayed
by canodom (issue #32): for each platform, `canodom config init --car P`
writes the configuration and its DBC, `pack_drive.py` packs a drive with
opendbc's CANPacker under that platform's conventions (the vehicle from the
configuration's [vehicle] section), `canodom replay` replays it, and the end
of the fused and the rear-only pose are compared with the route's truth.

    python3 drives.py CANODOM [--seeds 0 1] [--reverse] [--platforms a b]

Prints a markdown table and exits 1 when a platform misses what a user
needs: a checksum or counter reject, a warning, fused worse than rear-only,
or fused more than 1 % of the distance off. Run by drives.sh.
"""
import argparse
import math
import os
import re
import subprocess
import sys
import tempfile
import tomllib

from opendbc.can.dbc import DBC
from pack_drive import PLATFORMS

# Fused and rear-only sum the same rear increments when the gate accepts
# every window (no yaw-rate sensor, no slip): their ends then differ by float
# rounding only, far below a millimetre. A tie is not "worse".
TIE_M = 1e-6
HERE = os.path.dirname(os.path.abspath(__file__))


def rows(path):
    out = []
    with open(path) as f:
        next(f)
        for line in f:
            cols = line.strip().split(",")
            out.append([float(c) if c and re.fullmatch(r"[-+0-9.eE]+", c) else c for c in cols])
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("canodom")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--reverse", action="store_true")
    ap.add_argument("--smooth", action="store_true")
    ap.add_argument("--platforms", nargs="+", default=sorted(PLATFORMS))
    a = ap.parse_args()
    failed = []
    print("| platform | DBC | messages | frames | checksum-verified frames | rejects (checksum/counter) | seed | distance | rear-only end error | fused end error | fused − rear-only | verdict |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for platform in a.platforms:
            d = os.path.join(tmp, platform)
            os.makedirs(d)
            config = os.path.join(d, "car.toml")
            subprocess.run([a.canodom, "config", "init", "--car", platform, "--out", config],
                           check=True, capture_output=True)
            with open(config, "rb") as f:
                c = tomllib.load(f)
            veh = c["vehicle"]
            dbc = c["can"]["dbc"]
            for seed in a.seeds:
                log, truth, pose = (os.path.join(d, f"{n}{seed}") for n in ("drive.log", "truth.csv", "pose.csv"))
                cmd = [sys.executable, os.path.join(HERE, "pack_drive.py"), platform, log, truth,
                       "--seed", str(seed), "--wheelbase", str(veh["wheelbase_m"]),
                       "--rear-tread", str(veh["rear_tread_m"]), "--front-tread", str(veh["front_tread_m"]),
                       "--ratio", str(veh.get("steering_ratio", 1.0))]
                if a.reverse:
                    cmd.append("--reverse")
                if a.smooth:
                    cmd.append("--smooth")
                subprocess.run(cmd, check=True)
                r = subprocess.run([a.canodom, "replay", "--config", config, log, "--out", pose],
                                   capture_output=True, text=True)
                if r.returncode != 0:
                    print(r.stderr, file=sys.stderr)
                    failed.append(f"{platform} seed {seed}: replay failed")
                    continue
                stats = r.stderr
                lines = open(log).read().split()
                frames = sum(1 for w in lines if "#" in w)
                # Frames whose checksum canodom verified (messages with a
                # [checks] checksum), each packed by opendbc's packer.
                checked = {DBC(PLATFORMS[platform][0]).name_to_msg[m].address
                           for m, chk in c.get("checks", {}).items() if "checksum" in chk}
                verified = sum(1 for w in lines if "#" in w and int(w.split("#")[0], 16) in checked)
                bad = {k: int(m.group(1)) if (m := re.search(rf"\b{k}=(\d+)", stats)) else 0
                       for k in ("bad_checksum", "bad_counter")}
                warnings = [l for l in stats.splitlines() if "warning" in l]
                tr = rows(truth)
                dist = sum(math.hypot(q[1] - p[1], q[2] - p[2]) for p, q in zip(tr, tr[1:]))
                last, end = rows(pose)[-1], tr[-1]
                fused = math.hypot(last[1] - end[1], last[2] - end[2])
                rear = math.hypot(last[4] - end[1], last[5] - end[2])
                ok = (bad["bad_checksum"] == 0 and bad["bad_counter"] == 0 and not warnings
                      and fused <= rear + TIE_M and fused <= 0.01 * dist)
                msgs = ", ".join(m[0] for m in PLATFORMS[platform][1])
                print(f"| {platform} | {os.path.basename(dbc)} | {msgs} | {frames} | {verified} | "
                      f"{bad['bad_checksum']}/{bad['bad_counter']} | {seed} | {dist:.0f} m | "
                      f"{rear:.3f} m ({100 * rear / dist:.3f} %) | {fused:.3f} m ({100 * fused / dist:.3f} %) | "
                      f"{100 * (fused - rear) / dist:+.3f} % | {'ok' if ok else 'NOT MET'} |")
                for w in warnings:
                    print(f"  {platform} seed {seed}: {w}", file=sys.stderr)
                if not ok:
                    failed.append(f"{platform} seed {seed}")
    if failed:
        print("not met: " + "; ".join(failed), file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
