#!/usr/bin/env python3
"""Packs frames with opendbc's own CANPacker for every message with a
checksum opendbc computes, on every platform DBC canodom verifies, and
writes them as a fixture (packed.json) for the Rust test
can-dbc/tests/opendbc_packer.rs, which recomputes each checksum with
canodom_dbc::MakerChecksum and requires every one bit for bit.

Each fixture entry carries the message's own DBC lines (the BO_ line and
its CHECKSUM and COUNTER signals), so the test needs no DBC file from
opendbc. Run by check_packer.sh (which installs opendbc from PyPI):

    python3 check_packer.py OUT.json [--check EXISTING.json]

--check compares a fresh packing with the committed fixture and exits 1 on
any difference (what CI runs).
"""
import json
import random
import re
import sys

import opendbc
from opendbc import get_generated_dbcs
from opendbc.can.dbc import DBC, SignalType
from opendbc.can.packer import CANPacker

# (platform, opendbc DBC name, canodom's algorithm name)
PLATFORMS = [
    ("Toyota / Lexus", "toyota_nodsu_pt_generated", "toyota"),
    ("Toyota TNGA-K", "toyota_tnga_k_pt_generated", "toyota"),
    ("Honda Civic (Nidec)", "honda_civic_touring_2016_can_generated", "honda"),
    ("Honda (Bosch)", "honda_civic_hatchback_ex_2017_can_generated", "honda"),
    ("Acura RDX 2020", "acura_rdx_2020_can_generated", "honda"),
    ("Subaru (global)", "subaru_global_2017_generated", "subaru"),
    ("Chrysler Pacifica", "chrysler_pacifica_2017_hybrid_generated", "chrysler"),
    ("Ram 1500 (DT)", "chrysler_ram_dt_generated", "chrysler"),
    ("Tesla Model 3/Y", "tesla_model3_party", "tesla"),
    ("VW MQB", "vw_mqb", "volkswagen_mqb"),
    ("VW PQ", "vw_pq", "volkswagen_pq"),
    ("Hyundai/Kia CAN FD", "hyundai_canfd_generated", "hyundai_canfd"),
]

FRAMES_PER_MESSAGE = 8
SG_NAME = re.compile(r"^\s*SG_\s+(\w+)")


def dbc_text(name):
    gen = get_generated_dbcs()
    if name in gen:
        return gen[name]
    with open(f"{opendbc.DBC_PATH}/{name}.dbc") as f:
        return f.read()


def message_lines(text):
    """{address: (BO_ line, {signal name: SG_ line})}"""
    out = {}
    current = None
    for line in text.splitlines():
        s = line.strip()
        if s.startswith("BO_ "):
            m = re.match(r"^BO_ (\w+) ", s)
            current = int(m.group(1), 0)
            out[current] = (s, {})
        elif s.startswith("SG_ ") and current is not None:
            m = SG_NAME.match(s)
            if m:
                out[current][1][m.group(1)] = s
        elif not s:
            current = None
    return out


def main():
    out_path = sys.argv[1]
    check = sys.argv[3] if len(sys.argv) > 3 and sys.argv[2] == "--check" else None
    rng = random.Random(32)
    entries = []
    for platform, name, algorithm in PLATFORMS:
        dbc = DBC(name)
        lines = message_lines(dbc_text(name))
        packer = CANPacker(name)
        for address in sorted(dbc.msgs):
            msg = dbc.msgs[address]
            sums = [s for s in msg.sigs.values() if s.type > SignalType.COUNTER and s.calc_checksum]
            if not sums:
                continue
            checksum = sums[0]
            counters = [s for s in msg.sigs.values() if s.type == SignalType.COUNTER or s.name == "COUNTER"]
            bo, sgs = lines[address]
            keep = [sgs[checksum.name]] + [sgs[c.name] for c in counters if c.name in sgs]
            frames = []
            for _ in range(FRAMES_PER_MESSAGE):
                values = {}
                for s in msg.sigs.values():
                    if s is checksum or s in counters:
                        continue
                    raw = rng.randrange(0, 1 << min(s.size, 62))
                    if s.is_signed and raw >= 1 << (s.size - 1):
                        raw -= 1 << s.size
                    values[s.name] = raw * s.factor + s.offset
                frames.append(packer.pack(address, values).hex())
            entries.append({
                "platform": platform,
                "dbc": name,
                "algorithm": algorithm,
                "message": msg.name,
                "address": address,
                "dbc_lines": [bo] + keep,
                "frames": frames,
            })
    doc = {
        "generator": "can-dbc/tests/opendbc/check_packer.py",
        "opendbc_version": getattr(opendbc, "__version__", None) or pkg_version(),
        "messages": entries,
    }
    text = json.dumps(doc, indent=1) + "\n"
    with open(out_path, "w") as f:
        f.write(text)
    total = sum(len(e["frames"]) for e in entries)
    print(f"{len(entries)} checksummed messages, {total} frames packed by opendbc -> {out_path}")
    if check:
        with open(check) as f:
            old = json.load(f)
        if old["messages"] != entries:
            print(f"the packing differs from {check}: regenerate it with check_packer.sh", file=sys.stderr)
            sys.exit(1)
        print(f"identical to {check}")


def pkg_version():
    from importlib.metadata import version
    return version("opendbc")


if __name__ == "__main__":
    main()
