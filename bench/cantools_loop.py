#!/usr/bin/env python3
"""The peer of `canodom decode`: cantools' candump log parser and
`Database.decode_message` over the same log, in a plain Python loop.

Usage: cantools_loop.py DBC LOG  -> prints one JSON line with frames, seconds, frames/s.
Frames of ids the DBC does not know are counted and skipped, as `canodom decode` does."""
import json
import sys
import time

import cantools
from cantools.logreader import Parser


def main() -> None:
    db = cantools.database.load_file(sys.argv[1])
    known = {m.frame_id for m in db.messages}
    decoded = unknown = 0
    start = time.perf_counter()
    with open(sys.argv[2]) as f:
        for entry in Parser(f):
            if entry.frame_id not in known:
                unknown += 1
                continue
            db.decode_message(entry.frame_id, entry.data)
            decoded += 1
    secs = time.perf_counter() - start
    frames = decoded + unknown
    print(json.dumps({"frames": frames, "decoded": decoded, "seconds": secs,
                      "frames_per_s": frames / secs}))


if __name__ == "__main__":
    main()
