#!/usr/bin/env python3
"""Independent checks of the multi-body drives and of how they are made.

Model checks (no drive needed):
- wheel naming: in a left turn (positive steering, yaw growing), which wheel states spin
  faster; the generator calls the faster (outer) ones the RIGHT wheels;
- integration: the generator's RK4 against itself at an eighth of the step over a
  manoeuvre with a turn, hard braking (wheels lock) and drive torque (and with --lsoda
  against scipy's LSODA, slow);
- energy: on a straight with constant drive torque the kinetic energy (body + four
  wheels) grows by the work of the drive torque less the tyres' slip losses (small).

Drive checks (each drive folder given): decoded with cantools, independently of canodom:
- yaw-rate sign and scale: the decoded yaw rate against the truth's heading change;
- wheel speeds against the truth's speed; a locked wheel shows as 0 km/h at speed;
- rear-wheel odometry (mean rear speed, heading from the rear differential and from the
  truth) integrates to the truth's distance;
- speeds and lateral accelerations of the ordinary driving (from meta.json).
Exit status 1 when a check fails.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

sys.path.insert(0, str(Path(__file__).resolve().parent))
import evaluate  # noqa: E402
import generate  # noqa: E402
from vehiclemodels.init_mb import init_mb  # noqa: E402
from vehiclemodels.vehicle_dynamics_mb import vehicle_dynamics_mb  # noqa: E402

FAILURES: list[str] = []
DT_MAX = generate.DT_MAX_S


def check(ok: bool, what: str) -> None:
    print(("ok   " if ok else "FAIL ") + what)
    if not ok:
        FAILURES.append(what)


def wheel_naming() -> None:
    for key, veh in generate.vehicles().items():
        p = veh.params
        x = np.array(init_mb([0, 0, 0, 10.0, 0, 0, 0], p))
        for _ in range(3000):
            u = max(-0.4, min(0.4, 4.0 * (0.05 - x[2])))
            x = generate.rk4_step(x, [u, 0.0], p, 1e-3)
        left_turn = x[5] > 0 and x[4] > 0 and x[1] > 0
        fr, fl, rr, rl = (x[generate.WHEEL_STATE[w]] for w in ("FR", "FL", "RR", "RL"))
        check(left_turn and fr > fl and rr > rl,
              f"{key}: positive steering turns left (yaw rate {math.degrees(x[5]):.1f} deg/s) and the "
              f"wheels named right spin faster: FR {fr * p.R_w:.3f} > FL {fl * p.R_w:.3f}, "
              f"RR {rr * p.R_w:.3f} > RL {rl * p.R_w:.3f} m/s (states 23, 25 = the source's LF, LR)")
        # The rear speed difference matches the turn: (v_RR - v_RL) / T_r = yaw rate.
        est = (rr - rl) * p.R_w / p.T_r
        check(abs(est - x[5]) < 0.05 * abs(x[5]),
              f"{key}: rear differential {math.degrees(est):.2f} deg/s vs yaw rate {math.degrees(x[5]):.2f} deg/s")


def manoeuvre_inputs(t: float):
    """Turn in and out, brake hard (wheels lock), drive torque in a turn (wheels spin)."""
    if t < 2.0:
        return [0.2, 0.0] if t < 0.25 else ([-0.2, 0.0] if 1.5 <= t < 1.75 else [0.0, 0.0])
    if t < 3.0:
        return [0.0, -10.0]
    if t < 4.0:
        return [0.1, 0.0] if t < 3.5 else [0.0, 0.0]
    if t < 4.6:
        return [0.0, 6.0]
    return [0.0, 0.0]


def _run(p, x0, grid, step):
    """Integrate with inputs held over each interval of grid; step(x, u, a, b) -> x."""
    x = x0.copy()
    out = [x.copy()]
    for a, b in zip(grid[:-1], grid[1:]):
        x = step(x, manoeuvre_inputs(a), a, b)
        x[23:27] = np.maximum(x[23:27], 0.0)
        out.append(x.copy())
    return np.array(out)


def _rk4(p, dt_max):
    lam1 = generate.slip_rate_bound(p)

    def step(x, u, a, b):
        t = a
        while t < b - 1e-12:
            h = min(dt_max, b - t, generate.step_bound(x, lam1))
            x = generate.rk4_step(x, u, p, h)
            x[23:27] = np.maximum(x[23:27], 0.0)
            t += h
        return x

    return step


def _lsoda(p, rtol):
    def step(x, u, a, b):
        sol = solve_ivp(lambda _t, y: vehicle_dynamics_mb(list(y), u, p), (a, b), x, method="LSODA",
                        rtol=rtol, atol=rtol * 1e-2)
        return sol.y[:, -1].copy()

    return step


def _compare(p, a, b, what):
    dpos = float(np.max(np.hypot(a[:, 0] - b[:, 0], a[:, 1] - b[:, 1])))
    dyaw = float(np.degrees(np.max(np.abs(a[:, 4] - b[:, 4]))))
    dw = float(np.max(np.abs(a[:, 23:27] - b[:, 23:27])) * p.R_w)
    locked = bool(np.any(b[:, 23:27].min(axis=1) == 0.0))
    # What the truth needs: far below the centimetres per second that odometry errs by.
    check(dpos < 0.01 and dyaw < 0.01 and dw < 0.05,
          f"{what}: position {dpos * 1000:.2f} mm, yaw {dyaw:.4f} deg, wheel speed {dw:.4f} m/s apart at most "
          f"(wheels locked in it: {locked})")


def integration_accuracy(lsoda: bool = False) -> None:
    """The generator's RK4 against itself at an eighth of the step (a 7 s turn, hard braking
    that locks the rear wheels, drive torque), and against scipy's LSODA (an implicit/explicit
    switching multistep method, not written here) over the turn and the lock."""
    p = generate.vehicles()["bmw320i"].params
    x0 = np.array(init_mb([0, 0, 0, 14.0, 0, 0, 0], p))
    grid = np.round(np.arange(0.0, 7.0 + 1e-9, 0.01), 6)
    coarse = _run(p, x0, grid, _rk4(p, DT_MAX))
    fine = _run(p, x0, grid, _rk4(p, DT_MAX / 8))
    _compare(p, coarse, fine, f"RK4 h <= {DT_MAX * 1e3:g} ms vs h <= {DT_MAX * 1e3 / 8:g} ms over a 7 s turn/lock/spin")
    if not lsoda:
        return
    # Slow: scipy's LSODA on the pure-Python model with finite-difference Jacobians did not
    # finish 3.5 s within 20 minutes on a loaded 2-core machine.
    short = grid[grid <= 3.5]
    ref = _run(p, x0, short, _lsoda(p, 1e-7))
    _compare(p, coarse[: len(short)], ref, f"RK4 h <= {DT_MAX * 1e3:g} ms vs LSODA rtol 1e-7 over the 3.5 s turn and lock")


def energy() -> None:
    veh = generate.vehicles()["vanagon"]
    p = veh.params
    x = np.array(init_mb([0, 0, 0, 8.0, 0, 0, 0], p))
    u_acc = 1.5

    def ke(x):
        return 0.5 * p.m * (x[3] ** 2 + x[10] ** 2) + 0.5 * p.I_y_w * float(np.sum(x[23:27] ** 2))

    e0 = ke(x)
    work = 0.0
    h = 1e-3
    for _ in range(4000):
        # Drive torque T_E = m R_w u on the driven wheels: power = T_E * omega split.
        te = p.m * p.R_w * u_acc
        w_front = 0.5 * p.T_se * te * (x[23] + x[24])
        w_rear = 0.5 * (1 - p.T_se) * te * (x[25] + x[26])
        work += h * (w_front + w_rear)
        x = generate.rk4_step(x, [0.0, u_acc], p, h)
    gain = ke(x) - e0
    check(0.9 * work < gain <= work * 1.001,
          f"energy: drive-torque work {work / 1000:.1f} kJ, kinetic energy gained {gain / 1000:.1f} kJ "
          f"({100 * (1 - gain / work):.2f} % lost in tyre slip)")


def drive_checks(d: Path) -> None:
    meta = json.loads((d / "meta.json").read_text())
    name = f"{meta['vehicle']} seed {meta['seed']}"
    truth = evaluate.read_truth(d / "truth.csv")
    tt, xt, yt, ht = truth
    tw, vr, tk, yr = evaluate.decode_sensors(evaluate.find_log(d))
    # Yaw-rate sign and scale: fit decoded yaw rate = k * d(heading)/dt + c.
    dh = np.gradient(ht, tt)
    ref = np.interp(tk, tt, dh)
    k, c = np.polyfit(ref, yr, 1)
    err = meta["sensor_errors"]
    check(abs(k - err["yaw_scale"]) < 0.01 and abs(math.degrees(c) - err["yaw_bias_dps"]) < 0.05,
          f"{name}: decoded yaw rate = {k:.4f} x truth heading rate + {math.degrees(c):.3f} deg/s "
          f"(drawn: scale {err['yaw_scale']:.4f}, bias {err['yaw_bias_dps']:.3f} deg/s); left turns positive")
    # Speeds and lateral acceleration of the ordinary driving.
    st = meta["stats"]
    lo, hi = st["speed_mps_range_ordinary"]
    check(st["lat_accel_mps2_max_ordinary"] <= 4.0,
          f"{name}: lateral acceleration <= 4 m/s^2 in ordinary driving ({st['lat_accel_mps2_max_ordinary']:.2f}; "
          f"with events {st['lat_accel_mps2_max_all']:.2f})")
    check(hi <= 16.5, f"{name}: top speed {hi:.1f} m/s (<= 16.5)")
    check(1000 <= st["distance_m"] <= 1300, f"{name}: {st['distance_m']:.0f} m driven (1.0-1.3 km)")
    # Truth speed of the rear axle midpoint vs the decoded rear mean speed.
    vt = np.hypot(np.gradient(xt, tt), np.gradient(yt, tt))
    vtw = np.interp(tw, tt, vt)
    locked_s = sum(meta["stats"]["wheel_locked_s"][w] for w in ("RL", "RR"))
    spin_s = sum(meta["stats"]["wheel_spinning_s"][w] for w in ("RL", "RR"))
    dist_wheels = float(np.sum(vr[1:] * np.diff(tw)))
    dist_truth = evaluate.path_length(truth, tw[0], tw[-1])
    rel = dist_wheels / dist_truth - 1
    if locked_s < 0.05 and spin_s < 0.05:
        check(abs(rel) < 0.01, f"{name}: rear wheel speeds integrate to {dist_wheels:.1f} m, truth {dist_truth:.1f} m "
                               f"({100 * rel:+.2f} %; no rear lock or spin)")
    else:
        print(f"info {name}: rear wheel distance {dist_wheels:.1f} m vs truth {dist_truth:.1f} m ({100 * rel:+.2f} %; "
              f"rear locked {locked_s:.1f} s, spinning {spin_s:.1f} s)")
    # Rear-wheel heading (configured tread) against the truth: the drift a user would see.
    veh = generate.vehicles()[meta["vehicle"]]
    rl, rr = decode_rear_pair(evaluate.find_log(d))
    h_rear = float(np.sum((rr[1][1:] - rl[1][1:]) * np.diff(rr[0]))) / veh.params.T_r
    h_true = float(np.interp(rr[0][-1], tt, ht) - np.interp(rr[0][0], tt, ht))
    spread = err["wheel_scale"]["RR"] - err["wheel_scale"]["RL"]
    print(f"info {name}: rear-wheel heading turns {math.degrees(h_rear):.1f} deg, truth {math.degrees(h_true):.1f} deg "
          f"({math.degrees(h_rear - h_true):+.1f} deg; drawn RR - RL scale {100 * spread:+.3f} %)")
    # A locked wheel in the log: 0 km/h while the car moves > 3 m/s.
    import cantools

    db = cantools.database.load_file(str(evaluate.DBC), strict=False)
    ws = db.get_message_by_name("WHEEL_SPEEDS")
    zero_at_speed = {w: 0 for w in ("FL", "FR", "RL", "RR")}
    for line in evaluate.read_log_text(evaluate.find_log(d)).splitlines():
        ts, _, frame = line.split()
        ident, data = frame.split("#")
        if int(ident, 16) != ws.frame_id:
            continue
        t = float(ts[1:-1])
        v = float(np.interp(t, tt, vt))
        if v > 3.0:
            dec = ws.decode(bytes.fromhex(data))
            for w in zero_at_speed:
                zero_at_speed[w] += dec[f"WHEEL_SPEED_{w}"] == 0.0
    locked_model = {w: s for w, s in meta["stats"]["wheel_locked_s"].items() if s > 0.05}
    frames = {w: n for w, n in zero_at_speed.items() if n}
    check(set(frames) == set(locked_model),
          f"{name}: wheels locked in the model {_fmt(locked_model, 's')} read 0 km/h at speed in the log "
          f"{_fmt(frames, ' frames')}")
    # A true standstill: every wheel frame 0 for a time while the truth stands.
    if st["true_standstill_s"] > 0:
        check(st["true_standstill_s"] >= 2.0, f"{name}: true standstill {st['true_standstill_s']:.1f} s")
    # The first 3 s are straight (the baseline's bias window).
    m = tt < tt[0] + 3.0
    check(np.ptp(ht[m]) < math.radians(0.2),
          f"{name}: heading changes {math.degrees(np.ptp(ht[m])):.3f} deg over the first 3 s")


def decode_rear_pair(log: Path):
    """(t, RL m/s) and (t, RR m/s) from the log's WHEEL_SPEEDS frames."""
    import cantools

    db = cantools.database.load_file(str(evaluate.DBC), strict=False)
    ws = db.get_message_by_name("WHEEL_SPEEDS")
    t, l, r = [], [], []
    for line in evaluate.read_log_text(log).splitlines():
        ts, _, frame = line.split()
        ident, data = frame.split("#")
        if int(ident, 16) == ws.frame_id:
            dec = ws.decode(bytes.fromhex(data))
            t.append(float(ts[1:-1]))
            l.append(dec["WHEEL_SPEED_RL"] / 3.6)
            r.append(dec["WHEEL_SPEED_RR"] / 3.6)
    t = np.array(t)
    return (t, np.array(l)), (t, np.array(r))


def _fmt(d: dict, unit: str) -> str:
    return "{" + ", ".join(f"{k} {v:.2f}{unit}" if isinstance(v, float) else f"{k} {v}{unit}"
                           for k, v in d.items()) + "}" if d else "{none}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("drives", nargs="*", type=Path, help="drive folders or roots to search for meta.json")
    ap.add_argument("--skip-model", action="store_true", help="only the drive checks")
    ap.add_argument("--lsoda", action="store_true",
                    help="also compare the RK4 with scipy's LSODA over 3.5 s (slow: more than 20 minutes)")
    args = ap.parse_args(argv)
    if not args.skip_model:
        wheel_naming()
        energy()
        integration_accuracy(args.lsoda)
    for p in args.drives:
        dirs = [p] if (p / "meta.json").exists() else sorted({m.parent for m in p.rglob("meta.json")})
        for d in dirs:
            drive_checks(d)
    print(f"{len(FAILURES)} failed")
    return 1 if FAILURES else 0


if __name__ == "__main__":
    sys.exit(main())
