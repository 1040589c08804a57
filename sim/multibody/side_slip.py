#!/usr/bin/env python3
"""How much the rear axle's side slip costs the odometry on a drive, from its truth alone.

Issue 46 names a cause no fit learns today: in a curve the rear axle's velocity is not along
the body (tyre side slip), while the odometry integrates along it. This measures, on a drive's
truth.csv (the rear-axle midpoint and the body yaw at 50 Hz):

- the slip angle beta (the rear axle's velocity against the body heading) against the lateral
  acceleration a_y = v * yaw rate, above --min-speed-mps: the least-squares slope in degrees per
  m/s^2, the residual's spread and the 95th percentiles of |beta| and |a_y|;
- the relative pose error (rpe.py's windows) of the truth's own heading and distance integrated
  along the body, i.e. a perfect odometry without a side-slip term, and the same with the
  fitted slope applied (beta = slope * a_y): what a learnt cornering-stiffness term could gain
  at most on this drive.

Example:
    side_slip.py /tmp/mb-long/bmw320i/seed-101
"""
from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import rpe  # noqa: E402


def reckon(t, x, y, h, slope_deg_per_mps2: float):
    """The truth's distance per sample along its mid heading plus slope * a_y: (t, x, y, h) rows."""
    ds = np.hypot(np.diff(x), np.diff(y))
    dt = np.diff(t)
    hm = 0.5 * (h[1:] + h[:-1])
    ay = ds / dt * np.diff(h) / dt
    beta = np.radians(slope_deg_per_mps2) * ay
    nx = np.concatenate([[x[0]], x[0] + np.cumsum(ds * np.cos(hm + beta))])
    ny = np.concatenate([[y[0]], y[0] + np.cumsum(ds * np.sin(hm + beta))])
    return list(zip(t.tolist(), nx.tolist(), ny.tolist(), h.tolist()))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog=__doc__.split("\n\n", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("drive", type=Path, help="a drive folder holding truth.csv")
    ap.add_argument("--min-speed-mps", type=float, default=3.0, help="samples slower than this are left out of the fit (3)")
    ap.add_argument("--from-s", type=float, default=600.0)
    ap.add_argument("--to-s", type=float, default=1200.0)
    ap.add_argument("--window-s", type=float, default=120.0)
    ap.add_argument("--step-s", type=float, default=30.0)
    a = ap.parse_args(argv)
    d = np.genfromtxt(a.drive / "truth.csv", delimiter=",", names=True)
    t, x, y, h = d["t_unix_s"], d["x_m"], d["y_m"], d["heading_rad"]
    dt = np.diff(t)
    vx, vy = np.diff(x) / dt, np.diff(y) / dt
    v = np.hypot(vx, vy)
    hm = 0.5 * (h[1:] + h[:-1])
    beta = np.degrees(np.angle(np.exp(1j * (np.arctan2(vy, vx) - hm))))
    ay = v * np.diff(h) / dt
    m = v > a.min_speed_mps
    if m.sum() < 10:
        print("side_slip.py: too few samples above --min-speed-mps", file=sys.stderr)
        return 1
    slope, intercept = np.polyfit(ay[m], beta[m], 1)
    resid = beta[m] - (slope * ay[m] + intercept)
    print(f"{a.drive}: rear slip angle {slope:+.4f} deg per m/s^2 of lateral acceleration "
          f"(intercept {intercept:+.4f} deg, residual sd {resid.std():.3f} deg); "
          f"95th percentile |beta| {np.percentile(np.abs(beta[m]), 95):.2f} deg, |a_y| {np.percentile(np.abs(ay[m]), 95):.2f} m/s^2")
    truth = list(zip(t.tolist(), x.tolist(), y.tolist(), h.tolist()))
    for label, s in (("along the body (no slip term)", 0.0), (f"with {slope:+.3f} deg per m/s^2", slope)):
        ws = rpe.windows(truth, reckon(t, x, y, h, s), a.from_s, a.to_s, a.window_s, a.step_s, 50.0)
        errs = [w["error_pct"] for w in ws]
        print(f"  the truth's heading and distance {label}: {len(ws)} windows, median "
              f"{statistics.median(errs):.3f} %, worst {max(errs):.3f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
