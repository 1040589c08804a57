#!/usr/bin/env python3
"""GNSS-like position fixes from a multi-body drive's truth (issue 31).

A receiver's fixes are not the truth: they are noisy, late, and now and then jump. This
makes them from a drive's `truth.csv` (the rear-axle midpoint at 50 Hz on the log's clock):

- one fix every 1 / --rate-hz seconds over the first --window-s seconds of the drive;
- each fix is stamped when it arrives, --latency-s after the instant it describes (the
  receiver's solution and its transport), so a fix stamped t holds the position at t - latency;
- white noise of --sigma-m per axis;
- --jumps episodes of --jump-m metres (a multipath or a wrong ambiguity fix), each lasting
  1 to 3 fixes, in a random direction, drawn after the first 5 and before the last 5 fixes;
- --gap START LENGTH: no fix describes an instant from START to START + LENGTH seconds after
  the drive's start (a tunnel, a garage); the gap is cut after everything is drawn, so a drive's
  fixes with and without it agree outside it (a jump drawn inside it is lost with it);
- everything drawn from --seed, so the same arguments give the same files.

`--clean` makes the fixes a perfect receiver would give (no noise, latency or jumps).

Written to --out:
- `fixes.csv`: `t_unix_s,x_m,y_m`, local metres in the truth's frame (what `canodom calibrate
  --fixes` has always read);
- `fixes_geo.csv`: `t_unix_s,lat_deg,lon_deg,alt_m,horiz_std_m`, the same fixes placed on the
  WGS-84 ellipsoid around --origin (truth's x east, y north), converted with pymap3d, with
  --sigma-m as each fix's stated σ (what `canodom ros2-fixes` writes from a known covariance);
- `fixes.nmea`: the same fixes as NMEA 0183 GGA, GST and RMC sentences with their UTC times
  and checksums, written by pynmea2 (a tool this project did not write): GST states --sigma-m
  as the latitude and longitude errors, GGA's HDOP is --sigma-m / HDOP_UERE_M (canodom's
  constant for a receiver that sends no GST); `--no-gst` leaves GST out;
- `fixes.json`: what was drawn (the jumps' times and offsets, the origin, the settings).
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import sys
from pathlib import Path

import numpy as np


def read_truth(path: Path):
    a = np.genfromtxt(path, delimiter=",", names=True)
    return a["t_unix_s"], a["x_m"], a["y_m"], np.unwrap(a["heading_rad"])


def make_fixes(truth, *, seed: int, window_s: float = 60.0, rate_hz: float = 1.0, sigma_m: float = 0.3,
               latency_s: float = 0.2, jumps: int = 2, jump_m: float = 15.0, clean: bool = False,
               gap: tuple[float, float] | None = None):
    """The fixes (t_unix_s, x_m, y_m arrays) and a record of what was drawn."""
    tt, x, y, _ = truth
    rng = np.random.default_rng(seed)
    if clean:
        sigma_m, latency_s, jumps = 0.0, 0.0, 0
    t_start = tt[0]
    period = 1.0 / rate_hz
    # Stamps (arrival on the log's clock) within the window and the truth's span.
    n = int(math.floor((min(window_s, tt[-1] - t_start) - latency_s) / period)) + 1
    described = t_start + period * np.arange(n)
    stamped = described + latency_s
    fx = np.interp(described, tt, x) + rng.normal(0.0, 1.0, n) * sigma_m
    fy = np.interp(described, tt, y) + rng.normal(0.0, 1.0, n) * sigma_m
    drawn = []
    taken: set[int] = set()
    for _ in range(jumps):
        for _attempt in range(100):
            length = int(rng.integers(1, 4))
            first = int(rng.integers(5, max(6, n - 5 - length)))
            span = set(range(first - 2, first + length + 2))
            if not span & taken:
                break
        taken |= span
        angle = float(rng.uniform(-math.pi, math.pi))
        dx, dy = jump_m * math.cos(angle), jump_m * math.sin(angle)
        idx = list(range(first, min(n, first + length)))
        fx[idx] += dx
        fy[idx] += dy
        drawn.append({"t_unix_s": [float(stamped[i]) for i in idx], "dx_m": dx, "dy_m": dy})
    if gap is not None:
        keep = ~((described >= t_start + gap[0]) & (described < t_start + gap[0] + gap[1]))
        stamped, fx, fy = stamped[keep], fx[keep], fy[keep]
        kept = set(np.round(stamped, 6).tolist())
        drawn = [j for j in drawn if round(j["t_unix_s"][0], 6) in kept]
    record = {"seed": seed, "window_s": window_s, "rate_hz": rate_hz, "sigma_m": sigma_m,
              "latency_s": latency_s, "jump_m": jump_m, "jumps": drawn, "fixes": int(len(stamped)),
              "gap_s": list(gap) if gap is not None else None}
    return stamped, fx, fy, record


def nmea_lat(lat_deg: float) -> tuple[str, str]:
    a = abs(lat_deg)
    d = int(a)
    return f"{d:02d}{(a - d) * 60.0:010.7f}", "N" if lat_deg >= 0 else "S"


def nmea_lon(lon_deg: float) -> tuple[str, str]:
    a = abs(lon_deg)
    d = int(a)
    return f"{d:03d}{(a - d) * 60.0:010.7f}", "E" if lon_deg >= 0 else "W"


# canodom's σ per axis at HDOP 1 (offline/src/fixes.rs HDOP_UERE_M), so that a reader of the
# HDOP alone finds the σ the fixes were drawn with.
HDOP_UERE_M = 2.1


def nmea_lines(t, lat, lon, alt, sigma_m: float, gst: bool = True) -> list[str]:
    """GGA (GST) and RMC for each fix, through pynmea2 (its own field layout and checksum)."""
    import pynmea2

    out = []
    for i in range(len(t)):
        when = dt.datetime.fromtimestamp(float(t[i]), tz=dt.timezone.utc)
        hms = when.strftime("%H%M%S") + f".{when.microsecond // 10000:02d}"
        la, ns = nmea_lat(float(lat[i]))
        lo, ew = nmea_lon(float(lon[i]))
        hdop = f"{max(0.5, sigma_m / HDOP_UERE_M):.2f}"
        gga = pynmea2.GGA("GP", "GGA", (hms, la, ns, lo, ew, "1", "09", hdop, f"{alt[i]:.3f}", "M",
                                         "47.0", "M", "", ""))
        if i + 1 < len(t):
            j0, j1 = i, i + 1
        else:
            j0, j1 = max(0, i - 1), i
        out.append(str(gga))
        if gst:
            s = f"{sigma_m:.2f}"
            out.append(str(pynmea2.GST("GP", "GST", (hms, f"{sigma_m * 1.4142:.2f}", s, s, "0.0", s, s,
                                                     f"{1.5 * sigma_m:.2f}"))))
        # Course and speed over ground from the neighbouring fixes (what a receiver reports).
        import pymap3d

        e, nth, _ = pymap3d.geodetic2enu(lat[j1], lon[j1], alt[j1], lat[j0], lon[j0], alt[j0])
        span = max(1e-9, float(t[j1] - t[j0]))
        knots = math.hypot(e, nth) / span / 0.514444
        course = math.degrees(math.atan2(e, nth)) % 360.0
        rmc = pynmea2.RMC("GP", "RMC", (hms, "A", la, ns, lo, ew, f"{knots:.2f}", f"{course:.1f}",
                                         when.strftime("%d%m%y"), "", "", "A"))
        out.append(str(rmc))
    return out


def write_all(out: Path, t, x, y, record: dict, origin=(48.1500, 11.5800, 520.0), gst: bool = True) -> None:
    import pymap3d

    out.mkdir(parents=True, exist_ok=True)
    with open(out / "fixes.csv", "w") as f:
        f.write("t_unix_s,x_m,y_m\n")
        for ti, xi, yi in zip(t, x, y):
            f.write(f"{ti:.3f},{xi:.4f},{yi:.4f}\n")
    lat, lon, alt = pymap3d.enu2geodetic(np.asarray(x), np.asarray(y), np.zeros(len(x)), *origin)
    with open(out / "fixes_geo.csv", "w") as f:
        f.write("t_unix_s,lat_deg,lon_deg,alt_m,horiz_std_m\n")
        for ti, a, b, c in zip(t, lat, lon, alt):
            f.write(f"{ti:.3f},{a:.9f},{b:.9f},{c:.3f},{record['sigma_m']:.3f}\n")
    lines = nmea_lines(t, lat, lon, alt, record["sigma_m"], gst)
    (out / "fixes.nmea").write_text("\r\n".join(lines) + "\r\n")
    (out / "fixes.json").write_text(json.dumps(record | {"origin": list(origin)}, indent=1) + "\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("drive", type=Path, help="a drive folder holding truth.csv")
    ap.add_argument("--out", type=Path, required=True, help="folder for fixes.csv, fixes_geo.csv, fixes.nmea")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--window-s", type=float, default=60.0)
    ap.add_argument("--rate-hz", type=float, default=1.0)
    ap.add_argument("--sigma-m", type=float, default=0.3)
    ap.add_argument("--latency-s", type=float, default=0.2)
    ap.add_argument("--jumps", type=int, default=2)
    ap.add_argument("--jump-m", type=float, default=15.0)
    ap.add_argument("--clean", action="store_true", help="no noise, latency or jumps")
    ap.add_argument("--gap", type=float, nargs=2, metavar=("START_S", "LENGTH_S"),
                    help="no fixes from START_S to START_S + LENGTH_S after the drive's start (e.g. 240 120)")
    ap.add_argument("--no-gst", action="store_true", help="no GST sentences: the σ only from GGA's HDOP")
    ap.add_argument("--origin", type=float, nargs=3, default=(48.15, 11.58, 520.0),
                    metavar=("LAT", "LON", "ALT"), help="where the truth's origin lies on the globe")
    a = ap.parse_args(argv)
    if a.gap and (a.gap[1] <= 0 or a.gap[0] < 0):
        ap.error("--gap wants START_S >= 0 and LENGTH_S > 0")
    truth = read_truth(a.drive / "truth.csv")
    t, x, y, record = make_fixes(truth, seed=a.seed, window_s=a.window_s, rate_hz=a.rate_hz, sigma_m=a.sigma_m,
                                 latency_s=a.latency_s, jumps=a.jumps, jump_m=a.jump_m, clean=a.clean,
                                 gap=tuple(a.gap) if a.gap else None)
    write_all(a.out, t, x, y, record, tuple(a.origin), gst=not a.no_gst)
    print(f"{a.out}: {len(t)} fixes, jumps at {[j['t_unix_s'] for j in record['jumps']]}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
