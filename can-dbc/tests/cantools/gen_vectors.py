#!/usr/bin/env python3
"""Produce the cantools differential-test vectors for canodom-dbc.

For every message of every DBC file in data/dbc/, N payloads (default 10,000) are
drawn from splitmix64 seeded with FNV-1a-64 of "<file name>:<DBC message id>" (the Rust
test regenerates the same payloads, so none are stored), decoded by cantools with
scaling on and choices off, and summarised per message as:

  crc32  - zlib CRC-32 of the stream, over all payloads in order, of
           [u32 LE signal index (DBC order), u64 LE f64 bits of the value] for every
           decoded signal in DBC order, then u32 LE 0xFFFFFFFF after each payload
           (NaN written as 0x7FF8000000000000);
  values - count of (signal, value) pairs in that stream;
  first  - the full decoded values of the first payloads, for diagnosis.

When cantools rejects a multiplexor value that selects nothing ("expected multiplexer id
..."), the payload's root (non-multiplexed) signals are decoded with cantools' own root
codec, which is what a frame with such a value carries; `mux_unknown` counts those.
cantools cannot build a codec for a message whose signals overlap (Toyota and VW load
only with strict=False); such messages are decoded signal by signal with cantools'
single-signal codecs (`per_signal` in the vectors).

Usage (from can-dbc/): python3 tests/cantools/gen_vectors.py [--payloads N] [--first K]
"""

import argparse
import json
import os
import struct
import sys
import zlib

import cantools
from cantools.database.errors import DecodeError
from cantools.database.utils import create_encode_decode_formats, decode_data

HERE = os.path.dirname(os.path.abspath(__file__))
DBC_DIR = os.path.normpath(os.path.join(HERE, "..", "..", "..", "data", "dbc"))
OUT_DIR = os.path.join(HERE, "vectors")
MASK64 = (1 << 64) - 1
NAN_BITS = 0x7FF8000000000000
END = struct.pack("<I", 0xFFFFFFFF)


def fnv1a64(text):
    h = 0xCBF29CE484222325
    for b in text.encode():
        h = ((h ^ b) * 0x100000001B3) & MASK64
    return h


class SplitMix64:
    def __init__(self, seed):
        self.state = seed & MASK64

    def next(self):
        self.state = (self.state + 0x9E3779B97F4A7C15) & MASK64
        z = self.state
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK64
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK64
        return z ^ (z >> 31)

    def payload(self, length):
        words = (length + 7) // 8
        return b"".join(self.next().to_bytes(8, "little") for _ in range(words))[:length]


def f64_bits(value):
    value = float(value)
    if value != value:
        return NAN_BITS
    return struct.unpack("<Q", struct.pack("<d", value))[0]


def dbc_id(msg):
    return msg.frame_id | (0x80000000 if msg.is_extended_frame else 0)


def decode(msg, data, per_signal):
    if per_signal is not None:
        out = {}
        for signal, formats in per_signal:
            out.update(decode_data(data, msg.length, [signal], formats, False, True, False, True))
        return out, False
    try:
        return msg.decode(data, decode_choices=False, scaling=True), False
    except DecodeError as e:
        if "multiplexer id" not in str(e):
            raise
        root = msg._codecs
        return decode_data(data, msg.length, root["signals"], root["formats"],
                           False, True, False, True), True


def per_signal_codecs(msg, data):
    """cantools cannot build one codec for a message whose signals overlap (it loads such
    files only with strict=False, then fails with "unpacking failed"); decode each signal
    with its own single-signal cantools codec instead."""
    try:
        msg.decode(data, decode_choices=False, scaling=True)
        return None
    except DecodeError as e:
        if "unpacking failed" not in str(e) or msg.is_multiplexed():
            if "multiplexer id" in str(e):
                return None
            raise
    return [(s, create_encode_decode_formats([s], msg.length)) for s in msg.signals]


def load(path, **kw):
    try:
        return cantools.database.load_file(path, strict=True, **kw), True
    except Exception:  # noqa: BLE001 - cantools raises several types for strict checks
        return cantools.database.load_file(path, strict=False, **kw), False


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--payloads", type=int, default=10_000)
    ap.add_argument("--first", type=int, default=50)
    ap.add_argument("files", nargs="*")
    args = ap.parse_args()
    os.makedirs(OUT_DIR, exist_ok=True)
    files = args.files or sorted(f for f in os.listdir(DBC_DIR) if f.endswith(".dbc"))
    for name in files:
        # Decode with cantools' default signal sorting: its codecs assume it (decoding with
        # sort_signals=None fails with "unpacking failed" on cantools_multiplex.dbc). The
        # unsorted load only supplies each signal's index in DBC order.
        db, strict = load(os.path.join(DBC_DIR, name))
        in_file_order, _ = load(os.path.join(DBC_DIR, name), sort_signals=None)
        out = {"file": name, "cantools": cantools.__version__, "strict": strict,
               "payloads": args.payloads, "messages": []}
        for msg in db.messages:
            ident = dbc_id(msg)
            rng = SplitMix64(fnv1a64(f"{name}:{ident}"))
            unsorted = in_file_order.get_message_by_frame_id(msg.frame_id, msg.is_extended_frame)
            index = {s.name: i for i, s in enumerate(unsorted.signals)}
            crc, count, unknown, first = 0, 0, 0, []
            per_signal = per_signal_codecs(msg, bytes(msg.length))
            for p in range(args.payloads):
                data = rng.payload(msg.length)
                decoded, was_unknown = decode(msg, data, per_signal)
                unknown += was_unknown
                pairs = sorted((index[n], f64_bits(v)) for n, v in decoded.items())
                blob = b"".join(struct.pack("<IQ", i, b) for i, b in pairs) + END
                crc = zlib.crc32(blob, crc)
                count += len(pairs)
                if p < args.first:
                    first.append([data.hex(), [[i, f"{b:016x}"] for i, b in pairs]])
            out["messages"].append({"name": msg.name, "dbc_id": ident, "length": msg.length,
                                    "signals": len(unsorted.signals), "crc32": crc,
                                    "values": count, "mux_unknown": unknown,
                                    "per_signal": per_signal is not None, "first": first})
        with open(os.path.join(OUT_DIR, name.replace(".dbc", ".json")), "w") as f:
            json.dump(out, f, separators=(",", ":"))
            f.write("\n")
        print(f"{name}: {len(db.messages)} messages, strict={strict}", file=sys.stderr)


if __name__ == "__main__":
    main()
