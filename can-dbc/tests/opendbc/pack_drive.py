#!/usr/bin/env python3
"""A drive packed by opendbc's own CANPacker with each platform's
conventions, replayed by canodom from `canodom config init --car`'s
configuration (issue #32).

The drive is a kinematic route of the rear-axle centre (no tyre slip): a
standstill, a straight, a full left circle, a full right circle, seeded
constant-curvature segments, optionally a stop, a reversing manoeuvre in
gear R and a drive off. From it come each wheel's speed (rear wheels
v·(1 ∓ κ·tread/2), front wheels |v|·√((1 ∓ κ·tread/2)² + (κ·L)²)), the
steering-wheel angle atan(κ·L)·ratio and the yaw rate v·κ, every one left
turns positive, which are then written the way opendbc's
`car/<maker>/carstate.py` reads them (magnitudes, sign bits, direction bits,
negative factors, kph or m/s) and packed by `opendbc.can.packer.CANPacker`
with its counters and checksums. Nothing of canodom's is used to make the
frames.

    python3 pack_drive.py PLATFORM LOG TRUTH [--seed N] [--reverse]
        [--tight] [--out-and-back] [--smooth]
        [--wheelbase M --rear-tread M --front-tread M --ratio R]
        [--tyre RL=1.003 ...] [--steer-offset-deg D]
        [--gyro-bias-dps B] [--gyro-scale K] [--gyro-noise-dps S] [--gyro-stuck-s T]

writes LOG (candump -L, interface can0, CAN FD frames as `##0`) and TRUTH
(CSV t_s,x_m,y_m,heading_rad of the rear-axle centre). `drives.py` runs it
for every platform and replays the result.

The vehicle given is the true car the drive is made with (drives.py scales
the preset's to make a car wider or with another steering ratio than the
preset states). The sensors' faults, each as a real car has them:
`--tyre W=F` makes wheel W's sensor read F times its true speed (a tyre of
another size, wear or pressure); `--steer-offset-deg` is added to the
steering-wheel angle; the yaw-rate sensor reads the true rate plus
`--gyro-bias-dps` plus white noise of `--gyro-noise-dps` per sample. Every
value is clipped to what its DBC signal can encode (a sensor holds its
range's end: opendbc's packer would wrap it), so a turn past a gyro's
range reads the range's end.
"""
import argparse
import math
import random
import sys

from opendbc.can.dbc import DBC
from opendbc.can.packer import CANPacker

KPH = 3.6


def gear_value(dbc, message, signal, name):
    """The raw value of `name` in the signal's VAL_ table."""
    address = dbc.name_to_msg[message].address
    for v in dbc.vals:
        if v.address == address and v.name == signal:
            words = v.def_val.split()
            for raw, label in zip(words[0::2], words[1::2]):
                if label == name:
                    return int(raw)
    raise KeyError(f"{message}.{signal} has no value {name}")


def mag_sign(x):
    """A magnitude and a VW-style sign bit (1 = negative)."""
    return abs(x), 1 if x < 0 else 0


# Each platform: the opendbc DBC its carstate.py parses, the vehicle its
# `config init` configuration states, and the messages: (name, period s,
# function of the state -> values). State: wheel speeds fl/fr/rl/rr in m/s
# (signed: negative when reversing), steer_deg (steering wheel, left
# positive), yaw_dps (left positive), reverse (gear R).
def toyota_steer(a):
    coarse = round(a / 1.5) * 1.5
    fine = max(-0.7, min(0.7, round((a - coarse) / 0.1) * 0.1))
    return {"STEER_ANGLE": coarse, "STEER_FRACTION": fine}


PLATFORMS = {
    # carstate: WHEEL_SPEEDS signed kph; STEER_ANGLE + STEER_FRACTION.
    "toyota": ("toyota_nodsu_pt_generated", [
        ("WHEEL_SPEEDS", 0.0125, lambda s: {f"WHEEL_SPEED_{w}": s[w] * KPH for w in ("FL", "FR", "RL", "RR")}),
        ("STEER_ANGLE_SENSOR", 0.0125, lambda s: toyota_steer(s["steer_deg"])),
        # KINEMATICS.YAW_RATE: deg/s, left positive (the sign checked on the
        # RAV4 drive of data/comma2k19-rav4); 0.244 deg/s steps offset by
        # -125, so 0 deg/s is not encodable; 10 bits: -125 .. 124.6 deg/s.
        ("KINEMATICS", 0.02, lambda s: {"YAW_RATE": s["yaw_dps"]}),
    ]),
    # carstate: WHEEL_SPEEDS kph magnitudes, STEERING_SENSORS.STEER_ANGLE
    # (factor -0.1), GEARBOX_AUTO.GEAR_SHIFTER.
    "honda": ("honda_civic_touring_2016_can_generated", [
        ("WHEEL_SPEEDS", 0.02, lambda s: {f"WHEEL_SPEED_{w}": abs(s[w]) * KPH for w in ("FL", "FR", "RL", "RR")}),
        ("STEERING_SENSORS", 0.01, lambda s: {"STEER_ANGLE": s["steer_deg"]}),
        ("GEARBOX_AUTO", 0.1, lambda s: {"GEAR_SHIFTER": s["gear"]("GEARBOX_AUTO", "GEAR_SHIFTER")}),
    ]),
    # The Civic with a CVT (openpilot's TransmissionType.cvt): the gear in
    # GEARBOX_CVT (0x191) instead of GEARBOX_AUTO; replayed with the honda
    # preset (see PRESET).
    "honda_cvt": ("honda_civic_touring_2016_can_generated", [
        ("WHEEL_SPEEDS", 0.02, lambda s: {f"WHEEL_SPEED_{w}": abs(s[w]) * KPH for w in ("FL", "FR", "RL", "RR")}),
        ("STEERING_SENSORS", 0.01, lambda s: {"STEER_ANGLE": s["steer_deg"]}),
        ("GEARBOX_CVT", 0.1, lambda s: {"GEAR_SHIFTER": s["gear"]("GEARBOX_CVT", "GEAR_SHIFTER")}),
    ]),
    # carstate (MQB): ESP_19 kph magnitudes, LWI_01 magnitude * (1, -1)[sign],
    # Gateway_73.GE_Fahrstufe; ESP_02 yaw rate magnitude + sign bit.
    "vw_mqb": ("vw_mqb", [
        ("ESP_19", 0.02, lambda s: {
            "ESP_HL_Radgeschw_02": abs(s["RL"]) * KPH, "ESP_HR_Radgeschw_02": abs(s["RR"]) * KPH,
            "ESP_VL_Radgeschw_02": abs(s["FL"]) * KPH, "ESP_VR_Radgeschw_02": abs(s["FR"]) * KPH}),
        ("LWI_01", 0.01, lambda s: dict(zip(("LWI_Lenkradwinkel", "LWI_VZ_Lenkradwinkel"), mag_sign(s["steer_deg"])))),
        ("ESP_02", 0.02, lambda s: dict(zip(("ESP_Gierrate", "ESP_VZ_Gierrate"), mag_sign(s["yaw_dps"])))),
        ("Gateway_73", 0.1, lambda s: {"GE_Fahrstufe": s["gear"]("Gateway_73", "GE_Fahrstufe")}),
    ]),
    # carstate (classic CAN): WHL_SPD11 kph magnitudes, SAS11.SAS_Angle,
    # LVR12.CF_Lvr_Gear (its default gear source).
    "hyundai": ("hyundai_kia_generic", [
        ("WHL_SPD11", 0.02, lambda s: {f"WHL_SPD_{w}": abs(s[w]) * KPH for w in ("FL", "FR", "RL", "RR")}),
        ("SAS11", 0.01, lambda s: {"SAS_Angle": s["steer_deg"]}),
        ("LVR12", 0.1, lambda s: {"CF_Lvr_Gear": s["gear"]("LVR12", "CF_Lvr_Gear")}),
        # ESP12.YAW_RATE: 0.01 steps offset by -40.95, no unit in the DBC:
        # deg/s, left positive; its range ends at +-40.95 deg/s.
        ("ESP12", 0.02, lambda s: {"YAW_RATE": s["yaw_dps"]}),
    ]),
    # carstate (CAN FD): WHEEL_SPEEDS WHL_Spd??Val kph magnitudes,
    # STEERING_SENSORS.STEERING_ANGLE, GEAR_SHIFTER.GEAR.
    "hyundai_canfd": ("hyundai_canfd_generated", [
        ("WHEEL_SPEEDS", 0.02, lambda s: {f"WHL_Spd{w}Val": abs(s[w]) * KPH for w in ("FL", "FR", "RL", "RR")}),
        ("STEERING_SENSORS", 0.01, lambda s: {"STEERING_ANGLE": s["steer_deg"]}),
        ("GEAR_SHIFTER", 0.1, lambda s: {"GEAR": s["gear"]("GEAR_SHIFTER", "GEAR")}),
        # ESC_02_10ms.ESC_YawRtVal: Deg/s, 0.005 steps, +-163.84, left positive.
        ("ESC_02_10ms", 0.01, lambda s: {"ESC_YawRtVal": s["yaw_dps"]}),
    ]),
    # carstate (global): Wheel_Speeds kph magnitudes, Steering_Torque.Steering_Angle
    # (factor -0.0217, no unit), Transmission.Gear.
    "subaru": ("subaru_global_2017_generated", [
        ("Wheel_Speeds", 0.02, lambda s: {w: abs(s[w]) * KPH for w in ("FL", "FR", "RL", "RR")}),
        ("Steering_Torque", 0.02, lambda s: {"Steering_Angle": s["steer_deg"]}),
        ("Transmission", 0.1, lambda s: {"Gear": s["gear"]("Transmission", "Gear")}),
    ]),
    # carstate (CUSW): WHEEL_SPEEDS_FRONT/REAR with unit=1 (m/s, the DBC
    # gives no unit), STEERING.STEER_ANGLE, GEAR.PRNDL.
    "chrysler": ("chrysler_cusw", [
        ("WHEEL_SPEEDS_FRONT", 0.02, lambda s: {"WHEEL_SPEED_FL": abs(s["FL"]), "WHEEL_SPEED_FR": abs(s["FR"])}),
        ("WHEEL_SPEEDS_REAR", 0.02, lambda s: {"WHEEL_SPEED_RL": abs(s["RL"]), "WHEEL_SPEED_RR": abs(s["RR"])}),
        ("STEERING", 0.01, lambda s: {"STEER_ANGLE": s["steer_deg"]}),
        ("GEAR", 0.1, lambda s: {"PRNDL": s["gear"]("GEAR", "PRNDL")}),
    ]),
    # carstate: EBCMWheelSpdFront/Rear km/h magnitudes signed by
    # RLWheelDir/RRWheelDir (2 = reverse), PSCMSteeringAngle.SteeringWheelAngle.
    "gm": ("gm_global_a_powertrain_generated", [
        ("EBCMWheelSpdFront", 0.02, lambda s: {"FLWheelSpd": abs(s["FL"]) * KPH, "FRWheelSpd": abs(s["FR"]) * KPH}),
        ("EBCMWheelSpdRear", 0.02, lambda s: {
            "RLWheelSpd": abs(s["RL"]) * KPH, "RRWheelSpd": abs(s["RR"]) * KPH,
            "RLWheelDir": 2 if s["reverse"] else 1, "RRWheelDir": 2 if s["reverse"] else 1}),
        ("PSCMSteeringAngle", 0.01, lambda s: {"SteeringWheelAngle": s["steer_deg"]}),
        # EBCMVehicleDynamic.YawRate2: "grad/s" (German for deg/s), signed
        # 12 bits of 0.0625: +-128 deg/s, left positive.
        ("EBCMVehicleDynamic", 0.02, lambda s: {"YawRate2": s["yaw_dps"]}),
    ]),
    # carstate: WHEEL_SPEEDS_FRONT/REAR KPH magnitudes,
    # STEER_ANGLE_SENSOR.STEER_ANGLE (factor -0.1, no unit), GEARBOX.GEAR_SHIFTER.
    "nissan": ("nissan_x_trail_2017_generated", [
        ("WHEEL_SPEEDS_FRONT", 0.02, lambda s: {"WHEEL_SPEED_FL": abs(s["FL"]) * KPH, "WHEEL_SPEED_FR": abs(s["FR"]) * KPH}),
        ("WHEEL_SPEEDS_REAR", 0.02, lambda s: {"WHEEL_SPEED_RL": abs(s["RL"]) * KPH, "WHEEL_SPEED_RR": abs(s["RR"]) * KPH}),
        ("STEER_ANGLE_SENSOR", 0.01, lambda s: {"STEER_ANGLE": s["steer_deg"]}),
        ("GEARBOX", 0.1, lambda s: {"GEAR_SHIFTER": s["gear"]("GEARBOX", "GEAR_SHIFTER")}),
    ]),
    # carstate: WHEEL_SPEEDS FL/FR/RL/RR kph (offset -100: signed),
    # STEER.STEER_ANGLE.
    "mazda": ("mazda_2017", [
        ("WHEEL_SPEEDS", 0.02, lambda s: {w: s[w] * KPH for w in ("FL", "FR", "RL", "RR")}),
        ("STEER", 0.01, lambda s: {"STEER_ANGLE": s["steer_deg"]}),
    ]),
    # carstate: Dyn4_FRE km/h magnitudes, STEERING_ALT.ANGLE,
    # Dat_BSI.P103_Com_bRevGear (on its camera bus; here on the one log).
    "psa": ("psa_aee2010_r3", [
        ("Dat_BSI", 0.1, lambda s: {"P103_Com_bRevGear": 1 if s["reverse"] else 0}),
        ("Dyn4_FRE", 0.02, lambda s: {
            "P263_VehV_VPsvValWhlFrtL": abs(s["FL"]) * KPH, "P264_VehV_VPsvValWhlFrtR": abs(s["FR"]) * KPH,
            "P265_VehV_VPsvValWhlBckL": abs(s["RL"]) * KPH, "P266_VehV_VPsvValWhlBckR": abs(s["RR"]) * KPH}),
        ("STEERING_ALT", 0.01, lambda s: {"ANGLE": s["steer_deg"]}),
    ]),
}


# The `config init` preset each drive is replayed with (its own name if absent).
PRESET = {"honda_cvt": "honda"}

# The yaw-rate signal of each platform that packs one: (message, signal,
# the signal is a magnitude with a sign bit).
YAW = {
    "toyota": ("KINEMATICS", "YAW_RATE", False),
    "hyundai": ("ESP12", "YAW_RATE", False),
    "hyundai_canfd": ("ESC_02_10ms", "ESC_YawRtVal", False),
    "gm": ("EBCMVehicleDynamic", "YawRate2", False),
    "vw_mqb": ("ESP_02", "ESP_Gierrate", True),
}

# The route's largest lateral acceleration, m/s² (0.7 g); the driver's
# wander about a leg's speed and curvature adds a few percent.
MAX_LATERAL_MPS2 = 0.7 * 9.81

# The driver's acceleration, m/s², and steering rate, curvature (1/m) per s.
ACCEL_MPS2, KAPPA_RATE = 2.0, 0.05

# The tight turn's radius at the rear axle (a car's full lock is about 5 m).
TIGHT_RADIUS_M = 6.0


def encodable(sig):
    """The physical range a DBC signal can encode (raw bits, factor, offset)."""
    lo, hi = (-(1 << (sig.size - 1)), (1 << (sig.size - 1)) - 1) if sig.is_signed else (0, (1 << sig.size) - 1)
    ends = sorted((lo * sig.factor + sig.offset, hi * sig.factor + sig.offset))
    return ends[0], ends[1]


def gyro_range_dps(dbc, platform):
    """The largest yaw rate the platform's gyro signal reads, deg/s (None: no gyro)."""
    if platform not in YAW:
        return None
    message, signal, magnitude = YAW[platform]
    lo, hi = encodable(dbc.name_to_msg[message].sigs[signal])
    return hi if magnitude else min(-lo, hi)


def route(rng, reverse, tight_speed=None, out_and_back=False):
    """[(duration s, speed m/s (negative: reversing), curvature 1/m)]."""
    if out_and_back:
        # About 30 m out at 3 m/s and 30 m back in reverse at 2 m/s (at
        # 2 m/s² the ramps up and down cover what they take from the time).
        return [(2.0, 0.0, 0.0), (10.0, 3.0, 0.0), (4.0, 0.0, 0.0), (15.0, -2.0, 0.0), (4.0, 0.0, 0.0)]
    legs = [(2.0, 0.0, 0.0), (6.0, 10.0, 0.0)]
    # Full circles left (R 15 m) and right (R 20 m) at 8 m/s.
    legs += [(2 * math.pi * 15 / 8, 8.0, 1 / 15), (3.0, 8.0, 0.0), (2 * math.pi * 20 / 8, 8.0, -1 / 20)]
    for _ in range(8):
        duration, speed, kappa = rng.uniform(4, 8), rng.uniform(5, 12), rng.choice((-1, 1)) * rng.uniform(0, 1 / 12)
        # At most 0.7 g (issue #45: a road car's turns; 12 m/s on a 12 m
        # radius was 1.2 g, past what tyres hold and past Hyundai's gyro).
        kappa = math.copysign(min(abs(kappa), MAX_LATERAL_MPS2 / speed**2), kappa)
        legs.append((duration, speed, kappa))
    if tight_speed is not None:
        # A full circle tight enough that the gyro's range ends before the
        # car's yaw rate: the reading is held at the range's end. The
        # straight before it reaches the speed (2 m/s² from at most 12 m/s),
        # the circle's leg adds the steering's ramp to the curvature
        # (KAPPA_RATE) to a full turn.
        ramp_s = (1 / TIGHT_RADIUS_M) / KAPPA_RATE
        legs += [(2.0 + abs(12.0 - tight_speed) / ACCEL_MPS2, tight_speed, 0.0),
                 (ramp_s + 2 * math.pi * TIGHT_RADIUS_M / tight_speed, tight_speed, 1 / TIGHT_RADIUS_M),
                 (ramp_s + 2.0, tight_speed, 0.0)]
    legs.append((4.0, 0.0, 0.0))
    if reverse:
        legs += [(2.0, 0.0, 0.0), (8.0, -2.5, rng.choice((-1, 1)) / 10), (3.0, 0.0, 0.0), (8.0, 8.0, 0.0), (4.0, 0.0, 0.0)]
    return legs


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("platform", choices=sorted(PLATFORMS))
    ap.add_argument("log")
    ap.add_argument("truth")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--reverse", action="store_true")
    ap.add_argument("--smooth", action="store_true",
                    help="no driver: speed and curvature exactly the legs' (each wheel speed then sits on one"
                         " rounding of the DBC's quantum for a whole circle, a bias no real drive has)")
    ap.add_argument("--wheelbase", type=float, required=True)
    ap.add_argument("--rear-tread", type=float, required=True)
    ap.add_argument("--front-tread", type=float, required=True)
    ap.add_argument("--ratio", type=float, required=True)
    ap.add_argument("--tyre", action="append", default=[], metavar="W=F",
                    help="wheel W (FL, FR, RL, RR) reads F times its true speed; repeatable")
    ap.add_argument("--steer-offset-deg", type=float, default=0.0, help="steering-wheel angle sensor offset, deg")
    ap.add_argument("--gyro-bias-dps", type=float, default=0.0, help="yaw-rate sensor bias, deg/s")
    ap.add_argument("--gyro-scale", type=float, default=1.0, help="yaw-rate sensor scale (reads scale × the true rate)")
    ap.add_argument("--gyro-noise-dps", type=float, default=0.0, help="yaw-rate sensor white noise per sample, deg/s")
    ap.add_argument("--tight", action="store_true",
                    help=f"add a slow {TIGHT_RADIUS_M:.0f} m circle whose yaw rate is 1.2 times the gyro's range")
    ap.add_argument("--gyro-stuck-s", type=float, default=0.0,
                    help="the gyro reads its range's end for this long from the middle of the drive (a stuck sensor)")
    ap.add_argument("--out-and-back", action="store_true",
                    help="only 30 m forward and 30 m back in reverse (the gear's sign)")
    a = ap.parse_args()
    tyre = {"FL": 1.0, "FR": 1.0, "RL": 1.0, "RR": 1.0}
    for t in a.tyre:
        wheel, _, factor = t.partition("=")
        if wheel not in tyre:
            ap.error(f"--tyre {t}: the wheel is one of FL, FR, RL, RR")
        tyre[wheel] = float(factor)
    dbc_name, messages = PLATFORMS[a.platform]
    dbc = DBC(dbc_name)
    packer = CANPacker(dbc_name)
    rng = random.Random(a.seed)
    # A separate stream for the gyro's noise: the route stays the seed's.
    gyro_rng = random.Random(a.seed + 1_000_003)
    tight_speed = None
    if a.tight:
        limit = gyro_range_dps(dbc, a.platform)
        if limit is None:
            ap.error(f"--tight: {a.platform} packs no yaw-rate sensor")
        tight_speed = 1.2 * math.radians(limit) * TIGHT_RADIUS_M
        print(f"{a.platform}: tight turn {1.2 * limit:.1f} deg/s on a {TIGHT_RADIUS_M:.0f} m circle at "
              f"{tight_speed:.1f} m/s ({tight_speed**2 / TIGHT_RADIUS_M / 9.81:.2f} g)", file=sys.stderr)
    stuck = None
    if a.gyro_stuck_s:
        limit = gyro_range_dps(dbc, a.platform)
        if limit is None:
            ap.error(f"--gyro-stuck-s: {a.platform} packs no yaw-rate sensor")
        legs_s = sum(d for d, _, _ in route(random.Random(a.seed), a.reverse, tight_speed, a.out_and_back))
        stuck = (legs_s / 2, legs_s / 2 + a.gyro_stuck_s, limit)
    # Each signal's encodable range: a value beyond it is held at its end.
    clip = {(m, n): encodable(sig) for m, _, _ in messages for n, sig in dbc.name_to_msg[m].sigs.items()}
    L, tr, tf, ratio = a.wheelbase, a.rear_tread, a.front_tread, a.ratio
    dt = 0.001
    accel, kappa_rate = ACCEL_MPS2, KAPPA_RATE
    t, x, y, th, v, k = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    t0 = 1_700_000_000.0
    next_send = {m[0]: 0.0 for m in messages}
    periods = {m[0]: m[1] for m in messages}
    log, truth = [], ["t_s,x_m,y_m,heading_rad"]
    next_truth = 0.0
    reverse = False
    # The driver: speed and curvature wander about the leg's (first-order
    # random walks pulled back in 2 s; ±0.3 m/s and ±0.002 1/m typical), as
    # no one holds a speed to the DBC's quantum.
    dv_drv, dk_drv = 0.0, 0.0
    driver = 0.0 if a.smooth else 1.0
    for duration, v_target, k_target in route(rng, a.reverse, tight_speed, a.out_and_back):
        end = t + duration
        while t < end:
            dv_drv += -dv_drv / 2.0 * dt + driver * 0.3 * math.sqrt(dt) * rng.gauss(0, 1)
            dk_drv += -dk_drv / 2.0 * dt + driver * 0.002 * math.sqrt(dt) * rng.gauss(0, 1)
            # The gear follows the wanted direction once the car stands.
            if abs(v) < 1e-9 and v_target != 0:
                reverse = v_target < 0
            want_v = v_target + dv_drv if v_target else 0.0
            dv = max(-accel * dt, min(accel * dt, want_v - v))
            if v_target == 0.0 and abs(v) < accel * dt:
                dv = -v
            v += dv
            want_k = k_target + (dk_drv if v_target else 0.0)
            k += max(-kappa_rate * dt, min(kappa_rate * dt, want_k - k))
            w = v * k
            th_mid = th + 0.5 * w * dt
            x += v * math.cos(th_mid) * dt
            y += v * math.sin(th_mid) * dt
            th += w * dt
            t += dt
            if t >= next_truth - 1e-9:
                truth.append(f"{t:.3f},{x:.6f},{y:.6f},{th:.8f}")
                next_truth += 0.01
            state = {
                "RL": tyre["RL"] * v * (1 - k * tr / 2),
                "RR": tyre["RR"] * v * (1 + k * tr / 2),
                "FL": tyre["FL"] * v * math.hypot(1 - k * tf / 2, k * L),
                "FR": tyre["FR"] * v * math.hypot(1 + k * tf / 2, k * L),
                "steer_deg": math.degrees(math.atan(k * L)) * ratio + a.steer_offset_deg,
                "yaw_dps": (stuck[2] if stuck and stuck[0] <= t < stuck[1] else
                            a.gyro_scale * math.degrees(w) + a.gyro_bias_dps + a.gyro_noise_dps * gyro_rng.gauss(0, 1)),
                "reverse": reverse,
                "gear": lambda m, sg: gear_value(dbc, m, sg, "R" if reverse else "D"),
            }
            for name, _, values_of in messages:
                if t >= next_send[name] - 1e-9:
                    next_send[name] += periods[name]
                    address = dbc.name_to_msg[name].address
                    values = {n: min(max(x, clip[name, n][0]), clip[name, n][1]) for n, x in values_of(state).items()}
                    data = packer.pack(address, values)
                    sep = "#" if len(data) <= 8 else "##0"
                    ident = f"{address:03X}" if address <= 0x7FF else f"{address:08X}"
                    log.append(f"({t0 + t:.6f}) can0 {ident}{sep}{data.hex().upper()}")
    with open(a.log, "w") as f:
        f.write("\n".join(log) + "\n")
    with open(a.truth, "w") as f:
        f.write("\n".join(truth) + "\n")


if __name__ == "__main__":
    main()
