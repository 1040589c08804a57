#!/usr/bin/env python3
"""Checks that cantools (the reference DBC tool) accepts canodom.dbc in strict
mode and that every message, for every multiplexer value, round-trips example
values through encode/decode within one LSB, with a valid CRC-8 in byte 7
(the SecOC *_AUTH authenticators and SECOC_SYNC excepted: a freshness value
and a MAC, an epoch and a floor).

    python3 -m venv /tmp/venv && /tmp/venv/bin/pip install cantools
    /tmp/venv/bin/python protocol/dbc/check_cantools.py [DBC] [--write-vectors JSON]

Prints one line per checked frame (id, name, mux, hex payload) and a final
"N passed, 0 failed" line; exits non-zero on any failure. With
--write-vectors it also writes the frames and cantools' decoded values as
JSON (committed as canodom_vectors.json, read by the Rust tests).
"""
import json
import os
import sys

import cantools


def crc8_sae_j1850(data):
    crc = 0xFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


def example(signal, k):
    """A value inside the signal's range, different per signal index k."""
    lo, hi = signal.minimum, signal.maximum
    frac = (0.137 + 0.31 * k) % 1.0
    raw = round((lo + frac * (hi - lo) - signal.offset) / signal.scale)
    return raw * signal.scale + signal.offset


def main():
    args = sys.argv[1:]
    vectors_path = None
    if "--write-vectors" in args:
        i = args.index("--write-vectors")
        vectors_path = args[i + 1]
        del args[i : i + 2]
    path = args[0] if args else os.path.join(os.path.dirname(__file__), "canodom.dbc")
    vectors = []
    db = cantools.database.load_file(path, strict=True)
    passed = failed = 0
    for msg in db.messages:
        mux = next((s for s in msg.signals if s.is_multiplexer), None)
        cases = [None]
        if mux is not None:
            cases = sorted({v for s in msg.signals for v in (s.multiplexer_ids or [])})
        for counter, case in enumerate(cases):
            values = {}
            for k, s in enumerate(msg.signals):
                if s.multiplexer_ids and case not in s.multiplexer_ids:
                    continue
                values[s.name] = example(s, k)
            if mux is not None:
                values[mux.name] = case
            # The SecOC authenticators (*_AUTH) carry a freshness value and a
            # MAC, SECOC_SYNC an epoch and a floor: no counter or CRC.
            secoc = msg.name.endswith("_AUTH") or msg.name.startswith("SECOC_")
            if not secoc:
                values["COUNTER"] = counter % 16
                values["CHECKSUM"] = 0
            data = bytearray(msg.encode(values, strict=True))
            if not secoc:
                data[7] = crc8_sae_j1850(data[:7])
            decoded = msg.decode(bytes(data), decode_choices=False)
            ok = secoc or decoded["CHECKSUM"] == crc8_sae_j1850(data[:7])
            for name, v in values.items():
                if name == "CHECKSUM":
                    continue
                sig = msg.get_signal_by_name(name)
                ok &= abs(decoded[name] - v) <= abs(sig.scale) / 2 + 1e-12
            vectors.append({
                "name": msg.name,
                "id": msg.frame_id,
                "data": data.hex(),
                "signals": {k: float(v) for k, v in decoded.items()},
            })
            print(f"{'ok  ' if ok else 'FAIL'} {msg.frame_id:#05x} {msg.name:<14} mux={case} {data.hex()}")
            passed += ok
            failed += not ok
    if vectors_path:
        with open(vectors_path, "w") as f:
            json.dump({"generator": "cantools " + cantools.__version__, "frames": vectors}, f, indent=1)
            f.write("\n")
    print(f"{passed} passed, {failed} failed")
    return 0 if failed == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
