#!/usr/bin/env python3
"""One drive on CommonRoad's multi-body vehicle model, as a Toyota's CAN bus sends it.

A drive is made from (vehicle, seed): a route and speed plan, a driver that follows it
through the model's two inputs (front steering velocity, longitudinal acceleration),
events (hard braking that locks wheels, drive-torque wheel spin, standstills), and the
car's sensors with per-seed errors, encoded with the Toyota DBC into a `candump -L` log.
The truth is the rear-axle midpoint (canodom's pose reference) and the body yaw.

The physics is `vehiclemodels.vehicle_dynamics_mb` (commonroad-vehicle-models 3.0.2, TUM,
BSD-3) unchanged; this file only drives it, integrates it and reads it. Conventions found
by reading the package source and checked by `checks.py`:

- State (0-based): 0 x, 1 y (centre of gravity, global), 2 front road-wheel angle,
  3 vx (body), 4 yaw, 5 yaw rate, 10 vy (body), 23..26 wheel angular speeds in the
  order the source calls LF, RF, LR, RR, ... Inputs: [steering velocity rad/s,
  longitudinal acceleration m/s^2] (the model's own limits are applied inside it).
- Yaw and steering are positive to the left (x' = v cos(yaw + beta), y' = v sin(...)).
- The source's "left" wheels are at y = -T/2 in its own yaw convention: their free-rolling
  speed is vx + T/2 * yaw_rate, so they spin FASTER in a left turn, and the yaw moment
  term (F_x_LR - F_x_RR) * T_r / 2 is positive for them. Physically they are the RIGHT
  wheels. This generator therefore reports state 23 as FR, 24 as FL, 25 as RR, 26 as RL.
- Below vx = 0.1 m/s the model switches to a kinematic model but leaves the lateral
  velocities and wheel spins to equations without tyre forces (they drift, and the switch
  back throws the car); there they are held at the kinematic model's values
  (`hold_kinematic`).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import pickle
import sys
import time
from pathlib import Path

import numpy as np

from vehiclemodels.init_mb import init_mb
from vehiclemodels.parameters_vehicle1 import parameters_vehicle1
from vehiclemodels.parameters_vehicle2 import parameters_vehicle2
from vehiclemodels.parameters_vehicle3 import parameters_vehicle3
from vehiclemodels.vehicle_dynamics_mb import vehicle_dynamics_mb

# How hard the events are. `--harsh` (issue #30's "a wheel slips hard": drives the
# estimator has not been tuned on) locks for longer, lets a spinning wheel run to 2.5 times
# the car's speed, and gives nearly every drive both kinds.
EVENTS = {"p_lock": 0.5, "p_spin": 0.45, "lock_s": (0.8, 1.6), "spin_ratio": 1.35}
HARSH_EVENTS = {"p_lock": 0.9, "p_spin": 0.9, "lock_s": (1.5, 3.0), "spin_ratio": 2.5}
# The yaw-rate sensor's draws: its scale error within ±scale_max and its white noise within
# noise_dps. Noise of 0.05 °/s and more dithers the 0.244 °/s steps; below that the rounding
# of a steady rate stays (see --yaw-noise-dps). Each setting draws from the seed's stream
# the same way, so the drives of one seed differ in nothing else.
GYRO = {"scale_max": 0.005, "noise_dps": (0.05, 0.15)}
# Each wheel's radius error beyond the common one, within ±spread_max (see
# draw_sensor_errors for what it does to the rear wheels' heading, and --wheel-spread-max).
WHEELS = {"spread_max": 0.00025}
# One tyre larger than the others by a share (a new tyre beside worn ones, a pressure
# difference; --tyre-large): {"wheel": "RL", "rel": 0.003}, or None. Applied after the
# seed's draws, so a drive differs from its twin only in that wheel's speed frames.
TYRE = {"large": None}
# One tyre that changes mid-drive (a pressure drop, a puncture's slow leak; --tyre-change-at-s):
# {"at_s": 600.0, "wheel": "RL", "rel": -0.005}, or None. From at_s on that wheel's effective
# radius is 1 + rel times what it was (its frames read 1/(1 + rel) of before), the drift the
# daemon's drift watch is to flag (issue #46). No draw depends on it: the drive without it is
# the same drive up to at_s, bit for bit.
TYRE_CHANGE = {"change": None}
# Long drives (--minutes): the route is chained, turn after straight as for a short drive,
# until the time its segments plan (length / speed) reaches this many minutes; None keeps
# the ~1.1 km drives. The draws of a short drive are unchanged (the same seed gives the
# same drive), a long drive only draws more segments after them.
ROUTE = {"minutes": None}

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
DBC = REPO / "data" / "dbc" / "opendbc_toyota_2017.dbc"

# Index of each physical wheel in the model's state (see the module doc).
WHEEL_STATE = {"FL": 24, "FR": 23, "RL": 26, "RR": 25}

# Largest RK4 step (s); smaller where the wheel-spin equations are stiff (low speed).
# checks.py compares it with scipy's LSODA at tight tolerances.
DT_MAX_S = float(os.environ.get("MB_DT_MAX_S", "0.002"))


@dataclasses.dataclass(frozen=True)
class Vehicle:
    """A published CommonRoad parameter set and what a user would configure for it."""

    key: str
    name: str
    params: object
    # Not in the parameter sets: a plausible data-sheet steering ratio for the car.
    steering_ratio_nominal: float


def vehicles() -> dict[str, Vehicle]:
    return {
        "escort": Vehicle("escort", "Ford Escort (CommonRoad vehicle 1)", parameters_vehicle1(), 17.5),
        "bmw320i": Vehicle("bmw320i", "BMW 320i (CommonRoad vehicle 2)", parameters_vehicle2(), 15.4),
        "vanagon": Vehicle("vanagon", "VW Vanagon (CommonRoad vehicle 3)", parameters_vehicle3(), 19.0),
    }


# --------------------------------------------------------------------------- plan


@dataclasses.dataclass
class Segment:
    """A piece of route: constant curvature after a clothoid ramp from the last one."""

    length_m: float
    curvature_1pm: float
    speed_mps: float  # the speed to hold on it (reached before it starts)
    ramp_m: float = 0.0


@dataclasses.dataclass
class Event:
    """Something the driver does at a distance along the route."""

    kind: str  # "stop", "brake_lock", "spin"
    s_m: float
    duration_s: float
    accel_mps2: float
    hold_s: float = 0.0


def make_plan(rng: np.random.Generator, veh: Vehicle):
    """Route segments, events, and how the drive starts."""
    start_standing = bool(rng.random() < 0.4)
    v0 = 0.0 if start_standing else float(rng.uniform(8.0, 12.0))
    straight_start_s = float(rng.uniform(3.5, 5.0))
    target_m = float(rng.uniform(1080.0, 1230.0))
    segs: list[Segment] = []
    # The opening straight: long enough that the first 3-5 s are straight at any speed.
    first_len = max(60.0, (v0 if v0 > 0 else 6.0) * straight_start_s + 30.0)
    segs.append(Segment(first_len, 0.0, float(rng.uniform(9.0, 13.0))))
    total = first_len
    turn_dir = 1.0 if rng.random() < 0.5 else -1.0
    planned_s = first_len / segs[0].speed_mps
    minutes = ROUTE["minutes"]
    while total < target_m or (minutes is not None and planned_s < 60.0 * minutes):
        # A turn: speed, lateral acceleration (<= 3.8 m/s^2), angle.
        v_turn = float(rng.uniform(5.5, 12.0))
        a_lat = float(rng.uniform(1.2, 3.4))
        radius = max(8.0, v_turn**2 / a_lat)
        kappa = 1.0 / radius
        angle = float(rng.uniform(0.4, 2.6))
        if rng.random() < 0.65:
            turn_dir = -turn_dir
        ramp = float(rng.uniform(8.0, 18.0))
        arc = max(5.0, angle * radius - ramp)
        segs.append(Segment(arc, turn_dir * kappa, v_turn, ramp))
        total += arc + ramp
        planned_s += (arc + ramp) / v_turn
        # A straight or a gentle bend at a higher speed.
        if rng.random() < 0.75:
            length = float(rng.uniform(40.0, 160.0))
            k2 = 0.0 if rng.random() < 0.6 else float(rng.uniform(-1, 1)) / 250.0
            segs.append(Segment(length, k2, float(rng.uniform(9.0, 16.0)), float(rng.uniform(8.0, 15.0))))
            total += length
            planned_s += length / segs[-1].speed_mps
    if minutes is not None:
        target_m = total
    # Trim so the route ends near the target.
    excess = total - target_m
    if excess > 0 and segs[-1].length_m - excess > 10:
        segs[-1].length_m -= excess

    # Events: the kinds this drive has, drawn by seed.
    events: list[Event] = []
    has_stop = start_standing or rng.random() < 0.5
    has_lock = rng.random() < EVENTS["p_lock"]
    has_spin = rng.random() < EVENTS["p_spin"]
    starts = np.cumsum([0.0] + [s.length_m + s.ramp_m for s in segs])
    straights = [
        (starts[i] + segs[i].ramp_m, starts[i + 1])
        for i in range(1, len(segs))
        if abs(segs[i].curvature_1pm) < 1.0 / 200 and segs[i].length_m > 50
    ]
    turns = [
        (starts[i] + segs[i].ramp_m, starts[i + 1], segs[i])
        for i in range(1, len(segs))
        if abs(segs[i].curvature_1pm) > 1.0 / 150 and segs[i].length_m > 25
    ]
    used: list[tuple[float, float]] = []

    def free(a: float, b: float) -> bool:
        return all(b < u0 - 40 or a > u1 + 40 for u0, u1 in used) and b < target_m - 60

    order = list(rng.permutation(len(straights))) if straights else []
    if has_stop:
        for _ in range(int(rng.integers(1, 3))):
            for i in order:
                # Braking starts here and ends on the same straight (<= 16 m/s at 1.5 m/s^2).
                a, b = straights[i]
                s = a + 5.0
                decel = float(rng.uniform(1.5, 2.8))
                if b - s > 16.0**2 / (2 * decel) + 15 and free(s - 10, b):
                    events.append(Event("stop", s, float(rng.uniform(3.0, 6.0)), decel))
                    used.append((s - 10, b))
                    break
    if has_lock:
        for _ in range(int(rng.integers(1, 3))):
            # Lock on a straight or in a gentle part of a turn (the inner rear unloads).
            cands = [(a + 0.3 * (b - a), "straight") for a, b in straights]
            # Gentle turns only: at >= 11 m/s a radius of 45 m is 2.7 m/s^2.
            cands += [(a + 0.2 * (b - a), "turn") for a, b, seg in turns if abs(seg.curvature_1pm) < 1 / 45]
            for j in rng.permutation(len(cands)) if cands else []:
                s, _ = cands[j]
                if free(s - 20, s + 60):
                    events.append(Event("brake_lock", s, float(rng.uniform(*EVENTS["lock_s"])), -float(rng.uniform(9.0, 11.5))))
                    used.append((s - 20, s + 60))
                    break
    if has_spin:
        # On straights: a spin in a turn speeds the car past the turn's lateral limit.
        cands = [(a + 0.1 * (b - a)) for a, b in straights]
        for j in rng.permutation(len(cands)) if cands else []:
            s = cands[j]
            if free(s - 30, s + 60):
                events.append(Event("spin", s, float(rng.uniform(1.0, 2.0)), float(rng.uniform(5.0, 8.0))))
                used.append((s - 30, s + 60))
                break
    events.sort(key=lambda e: e.s_m)
    return segs, events, v0, straight_start_s, target_m


class Route:
    """Curvature, heading and speed limit as functions of distance."""

    def __init__(self, segs: list[Segment]):
        self.segs = segs
        ss = [0.0]
        ks = [segs[0].curvature_1pm]
        for seg in segs:
            if seg.ramp_m > 0:
                ss.append(ss[-1] + seg.ramp_m)
                ks.append(seg.curvature_1pm)
            ss.append(ss[-1] + seg.length_m)
            ks.append(seg.curvature_1pm)
        self.s = np.array(ss)
        self.k = np.array(ks)
        grid = np.arange(0.0, self.s[-1] + 200.0, 0.25)
        kap = np.interp(grid, self.s, self.k)
        self.grid = grid
        self.kap = kap
        self.psi = np.concatenate([[0.0], np.cumsum(0.5 * (kap[1:] + kap[:-1]) * np.diff(grid))])
        # Speed limit per point: the segment's speed over its curved part and ramp.
        vlim = np.full_like(grid, 16.0)
        seg_start = 0.0
        for seg in segs:
            end = seg_start + seg.ramp_m + seg.length_m
            m = (grid >= seg_start) & (grid < end)
            vlim[m] = seg.speed_mps
            seg_start = end
        vlim[grid >= seg_start] = segs[-1].speed_mps
        # Brake ahead of slower parts at 1.5 m/s^2, speed up at most at 1.5 m/s^2.
        for i in range(len(grid) - 2, -1, -1):
            vlim[i] = min(vlim[i], math.sqrt(vlim[i + 1] ** 2 + 2 * 1.5 * 0.25))
        self.vlim = vlim
        self.length_m = float(self.s[-1])

    def at(self, s: float):
        i = min(max(int(s / 0.25), 0), len(self.grid) - 1)
        return self.kap[i], self.psi[i], self.vlim[i]


# --------------------------------------------------------------------------- driver


class Driver:
    """Heading-and-curvature steering, speed tracking, and the planned events."""

    def __init__(self, p, route: Route, events: list[Event], v0: float, standing_s: float):
        self.p = p
        self.route = route
        self.events = list(events)
        self.L = p.a + p.b
        self.active: Event | None = None
        self.t_event = 0.0
        self.phase = ""
        self.standing_until = standing_s if v0 == 0.0 else -1.0
        self.log: list[dict] = []
        self.v_hold = 0.0

    def command(self, t: float, x, s: float):
        p = self.p
        kap, psi_ref, vlim = self.route.at(s + x[3] * 0.3)
        kap_here, psi_here, _ = self.route.at(s)
        v = x[3]
        # Steering: feed-forward of the route's curvature (with a little understeer),
        # heading error and yaw-rate error feedback.
        delta_ff = math.atan(self.L * kap) * (1.0 + 0.0015 * v * v)
        e_psi = psi_here - x[4]
        delta_cmd = delta_ff + 0.6 * e_psi
        if v > 1.0:
            delta_cmd += 0.08 * (v * kap_here - x[5]) * self.L / v * 5.0
        delta_cmd = max(-0.5, min(0.5, delta_cmd))
        u_steer = max(-0.4, min(0.4, 6.0 * (delta_cmd - x[2])))
        if v < 0.3:
            u_steer = 0.0  # no steering at a standstill

        # Longitudinal: events first.
        if t < self.standing_until:
            return u_steer, (-2.0 * v if v > 0 else 0.0), "standing"
        if self.active is None and self.events and s >= self.events[0].s_m:
            self.active = self.events.pop(0)
            self.t_event = t
            self.phase = "start"
            self.v_hold = v
            self.log.append({"kind": self.active.kind, "t_start": t, "s_m": s, "v_start": float(v)})
        ev = self.active
        if ev is not None:
            dt_ev = t - self.t_event
            if ev.kind in ("brake_lock", "spin") and self.phase == "start":
                # Bring the speed into the event's range first: locks from >= 11 m/s,
                # spins from <= 8 m/s (so that the spin ends below 16 m/s).
                if ev.kind == "brake_lock" and v < 11.0:
                    return u_steer, 1.5, "prepare"
                if ev.kind == "spin" and v > 8.0:
                    return u_steer, -2.0, "prepare"
                self.phase = "go"
                self.t_event = t
                self.log[-1]["t_go"] = t
                self.log[-1]["v_go"] = float(v)
                dt_ev = 0.0
            if ev.kind in ("brake_lock", "spin"):
                going = dt_ev < ev.duration_s and (
                    (ev.kind == "brake_lock" and v > 4.0)
                    or (ev.kind == "spin" and v < min(15.0, self.log[-1]["v_go"] + 4.0))
                )
                if going and ev.kind == "spin":
                    # The model's drive torque does not fall with wheel speed (no engine
                    # curve): a driver feels the wheels spin and eases off past ~35 % slip (150 % with --harsh),
                    # as the wheel speed would otherwise run away.
                    driven = (23, 24) if self.p.T_se > 0.5 else (25, 26)
                    wheel = max(x[i] for i in driven) * self.p.R_w
                    if wheel > EVENTS["spin_ratio"] * v + 1.0:
                        return u_steer, 0.5, ev.kind
                    return u_steer, ev.accel_mps2, ev.kind
                if going:
                    return u_steer, ev.accel_mps2, ev.kind
                self.log[-1]["t_end"] = t
                self.log[-1]["v_end"] = float(v)
                self.active = None
            elif ev.kind == "stop":
                if self.phase == "start":
                    if v > 0.4:
                        return u_steer, -ev.accel_mps2, "stopping"
                    if v > 1e-4:
                        return u_steer, -v / 0.15, "stopping"
                    self.phase = "stand"
                    self.t_event = t
                    dt_ev = 0.0
                    self.log[-1]["t_stand"] = t
                if self.phase == "stand":
                    if dt_ev < ev.duration_s:
                        return 0.0, (-v / 0.15 if v > 0 else 0.0), "standing"
                    self.log[-1]["t_end"] = t
                    self.active = None
        # Normal driving: track the speed limit ahead, gentle accelerations.
        a = 0.8 * (vlim - v)
        a = max(-3.0, min(1.8, a))
        return u_steer, a, "drive"


# --------------------------------------------------------------------------- integration


def slip_rate_bound(p) -> float:
    """Largest eigenvalue magnitude of the wheel-spin equations at 1 m/s (1/s):
    R_w^2 * dF_x/ds / (I_y_w * v), with dF_x/ds = p_kx1 * F_z at the heaviest static wheel."""
    g = 9.81
    fz = max(p.m_s * g * p.b / (p.a + p.b) + p.m_uf * g, p.m_s * g * p.a / (p.a + p.b) + p.m_ur * g) / 2
    return p.R_w**2 * abs(p.tire.p_kx1) * fz * 1.6 / p.I_y_w


def step_bound(x: np.ndarray, lam1: float) -> float:
    """RK4 is stable for h * lambda < 2.78: keep a margin of 2. Below the model's
    kinematic switch (vx < 0.1 m/s) the wheels are held at their rolling speed and the
    wheel-spin equations do not act, so only the suspension's (slower) modes bound h."""
    if x[3] < 0.09:
        return 1.0
    return 1.4 / (lam1 / max(abs(x[3]), 0.1))


def rk4_step(x: np.ndarray, u, p, h: float) -> np.ndarray:
    f = vehicle_dynamics_mb
    k1 = np.asarray(f(x.tolist(), u, p))
    k2 = np.asarray(f((x + 0.5 * h * k1).tolist(), u, p))
    k3 = np.asarray(f((x + 0.5 * h * k2).tolist(), u, p))
    k4 = np.asarray(f((x + h * k3).tolist(), u, p))
    return x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def hold_kinematic(x: np.ndarray, p) -> None:
    """Below the model's kinematic switch (vx < 0.1 m/s) the source moves the car by the
    kinematic single-track model but leaves the lateral velocities and the wheel spins to
    equations in which no tyre force acts: they drift at a standstill and, at the switch
    back, a slip angle of tens of degrees or a free-spun wheel throws the car (one rear
    wheel at 7 m/s for 0.3 s at a launch, seen before this hold). Here they are held at
    the kinematic model's values: yaw rate vx tan(delta) / l, slip at the centre of
    gravity beta = atan(b tan(delta) / l), wheels at their rolling speeds."""
    vx, d = x[3], x[2]
    lwb = p.a + p.b
    beta = math.atan(p.b * math.tan(d) / lwb)
    r = vx * math.cos(beta) * math.tan(d) / lwb
    vy = vx * math.tan(beta)
    x[5] = r
    x[10] = vy
    x[15] = vy + p.a * r
    x[20] = vy - p.b * r
    u_lf = (vx + 0.5 * p.T_f * r) * math.cos(d) + (vy + p.a * r) * math.sin(d)
    u_rf = (vx - 0.5 * p.T_f * r) * math.cos(d) + (vy + p.a * r) * math.sin(d)
    u_lr = vx + 0.5 * p.T_r * r
    u_rr = vx - 0.5 * p.T_r * r
    x[23:27] = np.maximum([u_lf, u_rf, u_lr, u_rr], 0.0) / p.R_w


def simulate(veh: Vehicle, seed: int, dt_max: float | None = None, control_dt: float = 0.01, t_limit: float = 400.0):
    p = veh.params
    dt_max = DT_MAX_S if dt_max is None else dt_max
    rng = np.random.default_rng(seed)
    segs, events, v0, straight_s, target_m = make_plan(rng, veh)
    if ROUTE["minutes"] is not None:
        # The driver slows for events and stops: leave room beyond the planned time.
        t_limit = max(t_limit, 60.0 * ROUTE["minutes"] * 1.6 + 60.0)
    route = Route(segs)
    standing_s = straight_s if v0 == 0.0 else 0.0
    driver = Driver(p, route, events, v0, standing_s)
    x = np.array(init_mb([0.0, 0.0, 0.0, v0, 0.0, 0.0, 0.0], p), dtype=float)
    lam1 = slip_rate_bound(p)
    t = 0.0
    s = 0.0
    out_t = [0.0]
    out_x = [x.copy()]
    out_u = [(0.0, 0.0)]
    out_mode = ["start"]
    out_s = [0.0]
    while t < t_limit:
        u_steer, u_acc, mode = driver.command(t, x, s)
        t_next = t + control_dt
        while t < t_next - 1e-12:
            # RK4 stays stable for h * lambda < 2.78; keep a margin of 2.
            h = min(dt_max, t_next - t, step_bound(x, lam1))
            xn = rk4_step(x, [u_steer, u_acc], p, h)
            xn[23:27] = np.maximum(xn[23:27], 0.0)
            if xn[3] < 0.1 and u_acc <= 0.0 and xn[3] < x[3]:
                xn[3] = max(xn[3], 0.0)
            if xn[3] < 0.1:
                hold_kinematic(xn, p)
            vel = math.hypot(x[3], x[10])
            s += h * vel
            x = xn
            t += h
        if not np.all(np.isfinite(x)):
            raise RuntimeError(f"{veh.key} seed {seed}: the integration diverged at t={t:.2f} s")
        out_t.append(t)
        out_x.append(x.copy())
        out_u.append((u_steer, u_acc))
        out_mode.append(mode)
        out_s.append(s)
        if s >= target_m and driver.active is None:
            break
    return {
        "t": np.array(out_t),
        "x": np.array(out_x),
        "u": np.array(out_u),
        "mode": out_mode,
        "s": np.array(out_s),
        "plan": {
            "segments": [dataclasses.asdict(g) for g in segs],
            "events_planned": [dataclasses.asdict(e) for e in events],
            "v0_mps": v0,
            "straight_start_s": straight_s,
            "target_m": target_m,
        },
        "events": driver.log,
    }


# --------------------------------------------------------------------------- sensors


@dataclasses.dataclass
class SensorErrors:
    steer_offset_road_deg: float
    steer_ratio_true: float
    steer_ratio_nominal: float
    wheel_scale: dict
    yaw_bias_dps: float
    yaw_scale: float
    yaw_noise_dps: float
    wheel_noise_kmh: float
    wheel_floor_kmh: float
    t0_unix_s: float


def draw_sensor_errors(rng: np.random.Generator, veh: Vehicle, seed: int) -> SensorErrors:
    return SensorErrors(
        steer_offset_road_deg=float(rng.uniform(-0.4, 0.4)),
        steer_ratio_true=float(veh.steering_ratio_nominal * (1.0 + rng.uniform(-0.05, 0.05))),
        steer_ratio_nominal=veh.steering_ratio_nominal,
        # A common tyre-radius error (wear, pressure) and a small left/right spread: a
        # 0.05 % spread between the rear wheels alone turns the rear-wheel heading by
        # 0.2 deg/s at 10 m/s (25 deg in two minutes).
        wheel_scale=_wheel_scales(rng),
        yaw_bias_dps=float(rng.uniform(-0.4, 0.4)),
        yaw_scale=float(1.0 + rng.uniform(-GYRO["scale_max"], GYRO["scale_max"])),
        yaw_noise_dps=float(rng.uniform(*GYRO["noise_dps"])),
        wheel_noise_kmh=0.02,
        wheel_floor_kmh=float(rng.uniform(1.8, 2.2)),
        t0_unix_s=1_700_000_000.0 + 10_000.0 * seed,
    )


def _wheel_scales(rng: np.random.Generator) -> dict:
    common = rng.uniform(-0.003, 0.003)
    spread = WHEELS["spread_max"]
    scales = {w: float(1.0 + common + rng.uniform(-spread, spread)) for w in ("FL", "FR", "RL", "RR")}
    if TYRE["large"] is not None:
        # A tyre larger by rel turns 1 + rel times slower for the same distance; the ECU
        # turns its spin into a speed with the nominal radius, so it reads 1/(1 + rel).
        scales[TYRE["large"]["wheel"]] /= 1.0 + TYRE["large"]["rel"]
    return scales


def frame_times(rng: np.random.Generator, t_end: float, period: float) -> np.ndarray:
    n = int(t_end / period) + 1
    tt = rng.uniform(0, period) + period * np.arange(n) + rng.normal(0, 0.0002, n)
    tt = np.sort(tt)
    return tt[(tt > 0) & (tt < t_end)]


def encode_log(sim: dict, veh: Vehicle, err: SensorErrors, rng: np.random.Generator) -> list[tuple[float, str]]:
    import cantools

    db = cantools.database.load_file(str(DBC), strict=False)
    m_ws = db.get_message_by_name("WHEEL_SPEEDS")
    m_st = db.get_message_by_name("STEER_ANGLE_SENSOR")
    m_kin = db.get_message_by_name("KINEMATICS")
    p = veh.params
    t, x = sim["t"], sim["x"]
    t_end = float(t[-1])
    lines: list[tuple[float, str]] = []

    def interp(col: int, tt: np.ndarray) -> np.ndarray:
        return np.interp(tt, t, x[:, col])

    # Wheel speeds: |omega| * effective rolling radius, 0.01 km/h, zero under the floor.
    tw = frame_times(rng, t_end, 0.012)
    ws = {}
    for w, col in WHEEL_STATE.items():
        kmh = interp(col, tw) * p.R_w * err.wheel_scale[w] * 3.6
        change = TYRE_CHANGE["change"]
        if change is not None and change["wheel"] == w:
            kmh = kmh * np.where(tw >= change["at_s"], 1.0 / (1.0 + change["rel"]), 1.0)
        kmh = kmh + rng.normal(0.0, err.wheel_noise_kmh, kmh.shape)
        kmh = np.abs(kmh)
        kmh[kmh < err.wheel_floor_kmh] = 0.0
        ws[w] = np.round((kmh + 67.67) / 0.01) * 0.01 - 67.67
    for i, tt in enumerate(tw):
        data = m_ws.encode(
            {
                "WHEEL_SPEED_FR": ws["FR"][i], "WHEEL_SPEED_FL": ws["FL"][i],
                "WHEEL_SPEED_RR": ws["RR"][i], "WHEEL_SPEED_RL": ws["RL"][i],
                "WHEEL_SPEED_FR_FAULT": 0, "WHEEL_SPEED_FL_FAULT": 0,
                "WHEEL_SPEED_RR_FAULT": 0, "WHEEL_SPEED_RL_FAULT": 0,
            },
            scaling=True, strict=False,
        )
        lines.append((tt, f"{m_ws.frame_id:03X}#{data.hex().upper()}"))

    # Steering wheel: road-wheel angle plus offset, times the true ratio; 1.5 deg + 0.1 deg.
    ts = frame_times(rng, t_end, 0.012)
    sw_deg = (np.degrees(interp(2, ts)) + err.steer_offset_road_deg) * err.steer_ratio_true
    tenths = np.round(sw_deg * 10.0).astype(int)
    coarse = np.round(tenths / 15.0).astype(int)
    fine = tenths - 15 * coarse
    rate = np.gradient(sw_deg, ts)
    for i, tt in enumerate(ts):
        data = m_st.encode(
            {"STEER_ANGLE": coarse[i] * 1.5, "STEER_FRACTION": fine[i] * 0.1,
             "STEER_RATE": float(np.clip(np.round(rate[i]), -2000, 2000))},
            scaling=True, strict=False,
        )
        lines.append((tt, f"{m_st.frame_id:03X}#{data.hex().upper()}"))

    # Yaw rate: left positive (as the RAV4's), scale and bias, white noise, 0.244 deg/s steps.
    tk = frame_times(rng, t_end, 0.012)
    yaw_dps = np.degrees(interp(5, tk)) * err.yaw_scale + err.yaw_bias_dps
    yaw_dps = yaw_dps + rng.normal(0.0, err.yaw_noise_dps, yaw_dps.shape)
    yaw_raw = np.clip(np.round((yaw_dps + 125.0) / 0.244), 0, 1023)
    ax = np.gradient(interp(3, tk), tk)
    ay = interp(3, tk) * interp(5, tk) + np.gradient(interp(10, tk), tk)
    for i, tt in enumerate(tk):
        data = m_kin.encode(
            {"YAW_RATE": yaw_raw[i] * 0.244 - 125.0,
             "ACCEL_X": float(np.clip(np.round((ax[i] + 18.375) / 0.03589), 0, 1023) * 0.03589 - 18.375),
             "ACCEL_Y": float(np.clip(np.round((ay[i] + 18.375) / 0.03589), 0, 1023) * 0.03589 - 18.375)},
            scaling=True, strict=False,
        )
        lines.append((tt, f"{m_kin.frame_id:03X}#{data.hex().upper()}"))
    lines.sort(key=lambda r: r[0])
    return lines


# --------------------------------------------------------------------------- outputs


def truth_rows(sim: dict, veh: Vehicle, rate_hz: float = 50.0):
    """Rear-axle midpoint and body yaw (unwrapped), on the log's clock."""
    p = veh.params
    t, x = sim["t"], sim["x"]
    tt = np.arange(0.0, t[-1], 1.0 / rate_hz)
    xc, yc, yaw = (np.interp(tt, t, x[:, i]) for i in (0, 1, 4))
    xr = xc - p.b * np.cos(yaw)
    yr = yc - p.b * np.sin(yaw)
    return tt, xr, yr, yaw


def stats(sim: dict, veh: Vehicle, err: SensorErrors) -> dict:
    p = veh.params
    t, x = sim["t"], sim["x"]
    vx = x[:, 3]
    ay = vx * x[:, 5] + np.gradient(x[:, 10], t)
    mode = np.array(sim["mode"])
    ordinary = mode == "drive"
    wheel_v = {w: x[:, c] * p.R_w for w, c in WHEEL_STATE.items()}
    # Locked: a wheel turning at under 10 % of the body's speed while moving > 3 m/s.
    # Spinning: a wheel faster than the body by > 15 %, > 1 m/s.
    rear_pt = {w: vx + (0.5 if w[1] == "R" else -0.5) * (p.T_r if w[0] == "R" else p.T_f) * x[:, 5]
               for w in wheel_v}
    locked = {w: float(np.sum(np.diff(t)[(wheel_v[w][1:] < 0.1 * vx[1:]) & (vx[1:] > 3)])) for w in wheel_v}
    spin = {w: float(np.sum(np.diff(t)[(wheel_v[w][1:] > 1.15 * rear_pt[w][1:] + 1.0)])) for w in wheel_v}
    seg = np.hypot(np.diff(x[:, 0]), np.diff(x[:, 1]))
    standstill = float(np.sum(np.diff(t)[(np.max(x[1:, 23:27], axis=1) * p.R_w < 1e-3) & (vx[1:] < 1e-3)]))
    return {
        "duration_s": float(t[-1]),
        "distance_m": float(np.sum(seg)),
        "speed_mps_min_max_moving": [float(vx[vx > 1].min()), float(vx.max())],
        "speed_mps_range_ordinary": [float(vx[ordinary & (vx > 1)].min()) if np.any(ordinary & (vx > 1)) else None,
                                     float(vx[ordinary].max())],
        # Above 1 m/s: at the model's kinematic switch vy jumps (no acceleration of the car).
        "lat_accel_mps2_max_ordinary": float(np.max(np.abs(ay[ordinary & (vx > 1.0)]))),
        "lat_accel_mps2_max_all": float(np.max(np.abs(ay[vx > 1.0]))),
        "net_turn_deg": float(np.degrees(x[-1, 4] - x[0, 4])),
        "total_turn_deg": float(np.degrees(np.sum(np.abs(np.diff(x[:, 4]))))),
        "wheel_locked_s": locked,
        "wheel_spinning_s": spin,
        "true_standstill_s": standstill,
        "max_roll_deg": float(np.degrees(np.max(np.abs(x[:, 6])))),
    }


def write_drive(veh: Vehicle, seed: int, out_dir: Path, compress: bool = True) -> dict:
    t_wall = time.time()
    cache = os.environ.get("MB_SIM_CACHE")
    long_tag = f"-{ROUTE['minutes']:g}min" if ROUTE["minutes"] is not None else ""
    cached = Path(cache) / f"{veh.key}-{seed}{long_tag}.pkl" if cache else None
    if cached is not None and cached.exists():
        sim = pickle.loads(cached.read_bytes())
    else:
        sim = simulate(veh, seed)
        if cached is not None:
            cached.parent.mkdir(parents=True, exist_ok=True)
            cached.write_bytes(pickle.dumps(sim))
    t_sim = time.time() - t_wall
    rng = np.random.default_rng([seed, 7])
    err = draw_sensor_errors(rng, veh, seed)
    lines = encode_log(sim, veh, err, rng)
    out_dir.mkdir(parents=True, exist_ok=True)
    text = "".join(f"({err.t0_unix_s + tt:.6f}) can0 {frame}\n" for tt, frame in lines)
    if compress:
        import zstandard

        (out_dir / "drive.log.zst").write_bytes(zstandard.ZstdCompressor(level=19).compress(text.encode()))
    else:
        (out_dir / "drive.log").write_text(text)
    tt, xr, yr, yaw = truth_rows(sim, veh)
    with open(out_dir / "truth.csv", "w") as f:
        f.write("t_unix_s,x_m,y_m,heading_rad\n")
        for row in zip(tt, xr, yr, yaw):
            f.write(f"{err.t0_unix_s + row[0]:.6f},{row[1]:.4f},{row[2]:.4f},{row[3]:.6f}\n")
    st = stats(sim, veh, err)
    meta = {
        "vehicle": veh.key,
        "vehicle_name": veh.name,
        "seed": seed,
        "generator": "sim/multibody/generate.py",
        "events_setting": dict(EVENTS),
        "gyro_setting": dict(GYRO),
        "wheels_setting": dict(WHEELS),
        "tyre_setting": dict(TYRE),
        "tyre_change_setting": dict(TYRE_CHANGE),
        "route_setting": dict(ROUTE),
        "model": "commonroad-vehicle-models 3.0.2 vehicle_dynamics_mb",
        "sensor_errors": dataclasses.asdict(err),
        "plan": sim["plan"],
        "events": sim["events"],
        "stats": st,
        "sim_wall_s": round(t_sim, 1),
    }
    (out_dir / "meta.json").write_text(json.dumps(meta, indent=1) + "\n")
    return meta


def write_configs(veh: Vehicle, out_dir: Path) -> None:
    """The nominal data-sheet geometry a user would configure (no per-seed errors)."""
    p = veh.params
    # Relative inside the repository (the configs move with it), absolute outside.
    rel = Path(os.path.relpath(DBC, out_dir.resolve())) if _inside_repo(out_dir) else DBC
    base = f"""# {veh.name}: nominal geometry from the CommonRoad parameter set
# (wheelbase a + b, treads T_f / T_r, wheel diameter 2 R_w); the steering ratio is a
# plausible data-sheet value (the parameter sets carry none); each drive's true ratio
# differs from it by up to 5 % (see the drive's meta.json).
[can]
interface = "can0"
dbc = "{rel.as_posix()}"

[vehicle]
wheelbase_m = {p.a + p.b:.4f}
rear_tread_m = {p.T_r:.4f}
front_tread_m = {p.T_f:.4f}
wheel_diameter_m = {2 * p.R_w:.4f}
steering_ratio = {veh.steering_ratio_nominal}

[signals]
rear_left = "WHEEL_SPEEDS.WHEEL_SPEED_RL"
rear_right = "WHEEL_SPEEDS.WHEEL_SPEED_RR"
front_left = "WHEEL_SPEEDS.WHEEL_SPEED_FL"
front_right = "WHEEL_SPEEDS.WHEEL_SPEED_FR"
steering = "STEER_ANGLE_SENSOR.STEER_ANGLE"
steering_fine = "STEER_ANGLE_SENSOR.STEER_FRACTION"
wheel_kind = "speed"
steering_kind = "steering_wheel"
"""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "config.toml").write_text(base)
    (out_dir / "config_yaw.toml").write_text(base + 'yaw_rate = "KINEMATICS.YAW_RATE"\n')


def _inside_repo(path: Path) -> bool:
    try:
        path.resolve().relative_to(REPO)
        return True
    except ValueError:
        return False


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description="Make drives on CommonRoad's multi-body model as Toyota CAN logs with truth.",
        epilog="Example: generate.py --vehicle escort --seed 11 --out data/multibody\n"
        "writes data/multibody/escort/config.toml, config_yaw.toml and "
        "data/multibody/escort/seed-11/{drive.log.zst,truth.csv,meta.json}",
    )
    ap.add_argument("--vehicle", required=True, choices=sorted(vehicles()), action="append",
                    help="vehicle parameter set (repeat for several)")
    ap.add_argument("--seed", required=True, type=int, action="append", help="seed (repeat for several)")
    ap.add_argument("--out", required=True, type=Path, help="root folder: <out>/<vehicle>/seed-<seed>/")
    ap.add_argument("--plain", action="store_true", help="write drive.log instead of drive.log.zst")
    ap.add_argument("--harsh", action="store_true",
                    help="harder events: locks of 1.5-3 s, spins to 2.5x the car's speed, both on most drives")
    ap.add_argument("--yaw-scale-max", type=float, default=GYRO["scale_max"], metavar="REL",
                    help="the yaw-rate sensor's scale error is drawn within ±REL (default %(default)s; "
                    "0 for a sensor without one)")
    ap.add_argument("--yaw-noise-dps", type=float, nargs=2, default=GYRO["noise_dps"], metavar=("LO", "HI"),
                    help="its white noise is drawn within LO..HI deg/s (default %(default)s; "
                    "0.04 0.04 for one that barely dithers its 0.244 deg/s steps)")
    ap.add_argument("--wheel-spread-max", type=float, default=WHEELS["spread_max"], metavar="REL",
                    help="each wheel's radius error beyond the common one is drawn within ±REL "
                    "(default %(default)s; 0 for wheels that differ in nothing but the common error)")
    ap.add_argument("--tyre-large", nargs=2, default=None, metavar=("WHEEL", "REL"),
                    help="one tyre (FL, FR, RL or RR) larger than its draw by REL (e.g. RL 0.003): "
                    "its wheel-speed frames read 1/(1 + REL) of its draw")
    ap.add_argument("--tyre-change-at-s", nargs=3, default=None, metavar=("T", "WHEEL", "REL"),
                    help="from T s into the drive one tyre's (FL, FR, RL or RR) effective radius is "
                    "1 + REL times what it was (e.g. 600 RL -0.005: a pressure drop after 10 minutes); "
                    "its frames read 1/(1 + REL) of before. Recorded in meta.json (tyre_change_setting)")
    ap.add_argument("--minutes", type=float, default=None, metavar="MIN",
                    help="a long drive: chain route segments until the plan lasts MIN minutes "
                    "(e.g. 20; default: the ~1.1 km drive). Cost: the simulation's CPU grows with "
                    "the drive's length; set MB_SIM_CACHE to keep the simulation and re-encode sensors")
    args = ap.parse_args(argv)
    if args.minutes is not None and not 1.0 <= args.minutes <= 120.0:
        ap.error(f"--minutes {args.minutes}: expected 1 <= MIN <= 120")
    ROUTE.update(minutes=args.minutes)
    lo, hi = args.yaw_noise_dps
    if not 0.0 <= args.yaw_scale_max < 0.5:
        ap.error(f"--yaw-scale-max {args.yaw_scale_max}: expected 0 <= REL < 0.5")
    if not 0.0 <= lo <= hi:
        ap.error(f"--yaw-noise-dps {lo} {hi}: expected 0 <= LO <= HI")
    if not 0.0 <= args.wheel_spread_max < 0.05:
        ap.error(f"--wheel-spread-max {args.wheel_spread_max}: expected 0 <= REL < 0.05")
    if args.harsh:
        EVENTS.update(HARSH_EVENTS)
    GYRO.update(scale_max=args.yaw_scale_max, noise_dps=(lo, hi))
    if args.tyre_large is not None:
        wheel, rel = args.tyre_large
        try:
            rel = float(rel)
        except ValueError:
            ap.error(f"--tyre-large {wheel} {rel}: REL must be a number")
        if wheel not in ("FL", "FR", "RL", "RR") or not -0.05 < rel < 0.05:
            ap.error(f"--tyre-large {wheel} {rel}: expected FL|FR|RL|RR and -0.05 < REL < 0.05")
        TYRE.update(large={"wheel": wheel, "rel": rel})
    if args.tyre_change_at_s is not None:
        at, wheel, rel = args.tyre_change_at_s
        try:
            at, rel = float(at), float(rel)
        except ValueError:
            ap.error(f"--tyre-change-at-s {at} {wheel} {rel}: T and REL must be numbers")
        if wheel not in ("FL", "FR", "RL", "RR") or not -0.05 < rel < 0.05 or not at >= 0.0:
            ap.error(f"--tyre-change-at-s {at} {wheel} {rel}: expected T >= 0, FL|FR|RL|RR and -0.05 < REL < 0.05")
        TYRE_CHANGE.update(change={"at_s": at, "wheel": wheel, "rel": rel})
    WHEELS.update(spread_max=args.wheel_spread_max)
    vs = vehicles()
    for key in args.vehicle:
        veh = vs[key]
        write_configs(veh, args.out / key)
        for seed in args.seed:
            d = args.out / key / f"seed-{seed}"
            meta = write_drive(veh, seed, d, compress=not args.plain)
            st = meta["stats"]
            print(
                f"{key} seed {seed}: {st['distance_m']:.0f} m in {st['duration_s']:.0f} s, "
                f"v {st['speed_mps_min_max_moving'][0]:.1f}-{st['speed_mps_min_max_moving'][1]:.1f} m/s, "
                f"a_lat max {st['lat_accel_mps2_max_ordinary']:.2f} m/s^2 (all {st['lat_accel_mps2_max_all']:.2f}), "
                f"events {[e['kind'] for e in meta['events']]}, locked {_fmt(st['wheel_locked_s'])}, "
                f"spin {_fmt(st['wheel_spinning_s'])}, standstill {st['true_standstill_s']:.1f} s "
                f"[{meta['sim_wall_s']} s]",
                flush=True,
            )
    return 0


def _fmt(d: dict) -> str:
    return ",".join(f"{k}:{v:.2f}" for k, v in d.items() if v > 0) or "-"


if __name__ == "__main__":
    sys.exit(main())
