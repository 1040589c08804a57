#!/usr/bin/env python3
"""Time cantools on the frames benches/decode.rs decodes (same splitmix64 payloads, same
generated 500-message DBC text), and print nanoseconds per frame as JSON lines.

Usage (from can-dbc/): python3 benches/cantools_timing.py
"""

import json
import os
import time

import cantools

HERE = os.path.dirname(os.path.abspath(__file__))
TOYOTA = os.path.normpath(os.path.join(HERE, "..", "..", "data", "dbc",
                                       "opendbc_toyota_2017.dbc"))
FRAMES = 1024
MASK64 = (1 << 64) - 1


class SplitMix64:
    def __init__(self, seed):
        self.state = seed

    def next(self):
        self.state = (self.state + 0x9E3779B97F4A7C15) & MASK64
        z = self.state
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK64
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK64
        return z ^ (z >> 31)


def dbc_500():
    t = 'VERSION ""\n\nNS_ :\n\nBS_:\n\nBU_: ECU\n\n'
    for k in range(500):
        ident = (0x80000000 | (0x18F00000 + k)) if k % 5 == 4 else 0x100 + k
        t += f"BO_ {ident} MSG_{k}: 8 ECU\n"
        for s in range(4):
            start, order = (16 * s, 1) if s % 2 == 0 else (16 * s + 7, 0)
            t += f' SG_ SIG_{k}_{s} : {start}|16@{order}+ (0.01,-{k}) [0|655] "km/h" ECU\n'
        t += "\n"
    return t


def best_ns_per_frame(fn, frames, repeats=7):
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter_ns()
        for f in frames:
            fn(f)
        best = min(best, (time.perf_counter_ns() - t0) / len(frames))
    return best


def main():
    db = cantools.database.load_file(TOYOTA, strict=False)
    msg = db.get_message_by_frame_id(0xAA)
    rng = SplitMix64(0xAA)
    frames = [rng.next().to_bytes(8, "little") for _ in range(FRAMES)]
    ns = best_ns_per_frame(lambda f: msg.decode(f, decode_choices=False), frames)
    print(json.dumps({"bench": "wheel_speeds", "cantools_ns_per_frame": ns,
                      "signals_decoded": len(msg.signals), "cantools": cantools.__version__}))

    db500 = cantools.database.load_string(dbc_500(), strict=False)
    assert len(db500.messages) == 500
    rng = SplitMix64(500)
    frames500 = []
    for _ in range(FRAMES):
        k = rng.next() % 500
        frames500.append((db500.messages[k].frame_id, rng.next().to_bytes(8, "little")))
    ns = best_ns_per_frame(lambda f: db500.decode_message(f[0], f[1], decode_choices=False),
                           frames500)
    print(json.dumps({"bench": "lookup_500", "cantools_ns_per_frame": ns}))


if __name__ == "__main__":
    main()
