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
..."), the payload is decoded with cantools' own codecs the way Message._decode walks them,
leaving out only the subtree of that multiplexor (for a top-level multiplexor: the root
signals alone), which is what a frame with such a value carries; `mux_unknown` counts those.
cantools cannot build a codec for a message whose signals overlap (Toyota and VW load
only with strict=False); such messages are decoded signal by signal with cantools'
single-signal codecs (`per_signal` in the vectors).

Each message also carries, for the corpus test (tests/corpus.rs):

  names  - cantools' name of the message and of each signal in DBC order (long names
           from SystemMessageLongSymbol / SystemSignalLongSymbol where given);
  typed  - CRC-32 of the stream with each value typed as cantools types it:
           [u32 LE signal index, u8 0, u64 LE f64 bits] for a float,
           [u32 LE signal index, u8 1, i128 LE] for an int (exact at any size),
           then u32 LE 0xFFFFFFFF after each payload;
  ints   - count of int values in it, and `big`, the ints of magnitude above 2^53 written
           out in decimal as [payload, signal index, "text"];
  never  - indices of signals no cantools codec decodes, whatever the payload (a signal
           whose multiplexor cantools does not recognise, e.g. `m` without a number);
  error  - set instead of the values when cantools loads the message but cannot decode it.

A file cantools cannot load at all is written as {"file", "cantools_loads": false, "error"}.

Usage (from can-dbc/): python3 tests/cantools/gen_vectors.py [--payloads N] [--first K]
       python3 tests/cantools/gen_vectors.py --corpus    (tests/corpus, 200 payloads)
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
CORPUS_DIR = os.path.normpath(os.path.join(HERE, "..", "corpus"))
CORPUS_OUT_DIR = os.path.join(HERE, "corpus_vectors")
TWO_POW_53 = 1 << 53
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


def decode_tolerant(msg, node, data):
    """cantools' Message._decode, except that a multiplexor value that selects nothing
    leaves out that multiplexor's subtree instead of failing the whole frame."""
    decoded = decode_data(data, msg.length, node["signals"], node["formats"],
                          False, True, False, True)
    for signal, children in node["multiplexers"].items():
        child = children.get(msg._get_mux_number(decoded, signal))
        if child is not None:
            decoded.update(decode_tolerant(msg, child, data))
    return decoded


def codec_signals(node):
    """Names of every signal cantools' codec tree can decode."""
    names = {s.name for s in node["signals"]}
    for children in node["multiplexers"].values():
        for child in children.values():
            names |= codec_signals(child)
    return names


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
        return decode_tolerant(msg, msg._codecs, data), True


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


def typed_value(i, v):
    """One value of the typed stream: ints exact, as cantools returns them."""
    if isinstance(v, int) and not isinstance(v, bool):
        return struct.pack("<IB", i, 1) + v.to_bytes(16, "little", signed=True)
    return struct.pack("<IBQ", i, 0, f64_bits(v))


def message_vectors(name, msg, unsorted, args):
    ident = dbc_id(msg)
    rng = SplitMix64(fnv1a64(f"{name}:{ident}"))
    index = {s.name: i for i, s in enumerate(unsorted.signals)}
    crc, typed, count, ints, unknown, first, big = 0, 0, 0, 0, 0, [], []
    per_signal = per_signal_codecs(msg, bytes(msg.length))
    for p in range(args.payloads):
        data = rng.payload(msg.length)
        decoded, was_unknown = decode(msg, data, per_signal)
        unknown += was_unknown
        values = sorted((index[n], v) for n, v in decoded.items())
        pairs = [(i, f64_bits(v)) for i, v in values]
        blob = b"".join(struct.pack("<IQ", i, b) for i, b in pairs) + END
        crc = zlib.crc32(blob, crc)
        typed = zlib.crc32(b"".join(typed_value(i, v) for i, v in values) + END, typed)
        count += len(pairs)
        for i, v in values:
            if isinstance(v, int):
                ints += 1
                if abs(v) > TWO_POW_53:
                    big.append([p, i, str(v)])
        if p < args.first:
            first.append([data.hex(), [[i, f"{b:016x}"] for i, b in pairs]])
    return {"name": msg.name, "dbc_id": ident, "length": msg.length,
            "signals": len(unsorted.signals),
            "names": [unsorted.name, [s.name for s in unsorted.signals]],
            "never": sorted(index[n] for n in index
                            if per_signal is None and n not in codec_signals(msg._codecs)),
            "crc32": crc, "typed": typed, "values": count, "ints": ints, "big": big,
            "mux_unknown": unknown, "per_signal": per_signal is not None, "first": first}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--payloads", type=int, default=None)
    ap.add_argument("--first", type=int, default=None)
    ap.add_argument("--corpus", action="store_true",
                    help="the corpus of real files in tests/corpus (200 payloads, 2 kept)")
    ap.add_argument("files", nargs="*")
    args = ap.parse_args()
    dbc_dir, out_dir = (CORPUS_DIR, CORPUS_OUT_DIR) if args.corpus else (DBC_DIR, OUT_DIR)
    if args.payloads is None:
        args.payloads = 200 if args.corpus else 10_000
    if args.first is None:
        args.first = 2 if args.corpus else 50
    os.makedirs(out_dir, exist_ok=True)
    # Corpus files are named by their path below tests/corpus (cantools/x.dbc), which is
    # also the name in the seed.
    files = args.files or sorted(
        os.path.relpath(os.path.join(d, f), dbc_dir)
        for d, _, fs in os.walk(dbc_dir) for f in fs if f.lower().endswith(".dbc"))
    for name in files:
        out_path = os.path.join(out_dir, os.path.splitext(name)[0] + ".json")
        os.makedirs(os.path.dirname(out_path), exist_ok=True)
        # Decode with cantools' default signal sorting: its codecs assume it (decoding with
        # sort_signals=None fails with "unpacking failed" on cantools_multiplex.dbc). The
        # unsorted load only supplies each signal's index in DBC order; both loads list the
        # messages in DBC order, so they pair up even where two messages share an ID.
        try:
            db, strict = load(os.path.join(dbc_dir, name))
            in_file_order, _ = load(os.path.join(dbc_dir, name), sort_signals=None)
        except Exception as e:  # noqa: BLE001 - whatever cantools refuses the file with
            out = {"file": name, "cantools": cantools.__version__, "cantools_loads": False,
                   "error": f"{type(e).__name__}: {e}"}
            print(f"{name}: cantools cannot load it: {e}", file=sys.stderr)
        else:
            out = {"file": name, "cantools": cantools.__version__, "cantools_loads": True,
                   "strict": strict, "payloads": args.payloads, "messages": []}
            for msg, unsorted in zip(db.messages, in_file_order.messages, strict=True):
                try:
                    out["messages"].append(message_vectors(name, msg, unsorted, args))
                except Exception as e:  # noqa: BLE001 - cantools cannot decode this message
                    out["messages"].append({
                        "name": msg.name, "dbc_id": dbc_id(msg), "length": msg.length,
                        "signals": len(unsorted.signals),
                        "names": [unsorted.name, [s.name for s in unsorted.signals]],
                        "error": f"{type(e).__name__}: {e}"})
            print(f"{name}: {len(db.messages)} messages, strict={strict}", file=sys.stderr)
        with open(out_path, "w") as f:
            json.dump(out, f, separators=(",", ":"))
            f.write("\n")


if __name__ == "__main__":
    main()
