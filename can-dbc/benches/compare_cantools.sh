#!/usr/bin/env bash
# Run the criterion benches and the cantools timing on the same frames, one after the
# other, and print ns/frame and the speed-up. Usage (from the workspace root):
#   can-dbc/benches/compare_cantools.sh [path/to/python-with-cantools]
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/../.."
python=${1:-python3}
target=${CARGO_TARGET_DIR:-target}
cargo bench -p canodom-dbc --bench decode -- --noplot >&2
"$python" can-dbc/benches/cantools_timing.py > "$target/cantools_timing.jsonl"
"$python" - "$target" <<'PY'
import json, sys
target = sys.argv[1]
frames = 1024
def ours(group, bench):
    with open(f"{target}/criterion/{group}/{bench}/new/estimates.json") as f:
        return json.load(f)["mean"]["point_estimate"] / frames
py = {r["bench"]: r for r in map(json.loads, open(f"{target}/cantools_timing.jsonl"))}
rows = [
    ("wheel_speeds: 4 handles", ours("wheel_speeds_4_signals", "handles"), py["wheel_speeds"]),
    ("wheel_speeds: whole message (%d signals)" % py["wheel_speeds"]["signals_decoded"],
     ours("wheel_speeds_4_signals", "message_decode"), py["wheel_speeds"]),
    ("wheel_speeds: whole message, decode_each",
     ours("wheel_speeds_4_signals", "message_decode_each"), py["wheel_speeds"]),
    ("lookup + decode among 500 (iterator)", ours("lookup_decode_500_messages", "database_decode"), py["lookup_500"]),
    ("lookup + decode among 500 (decode_each)", ours("lookup_decode_500_messages", "database_decode_each"), py["lookup_500"]),
]
print(f"lookup only (500 messages, 1/5 extended): {ours('lookup_decode_500_messages', 'lookup_only'):.1f} ns/frame")
for name, ns, ref in rows:
    c = ref["cantools_ns_per_frame"]
    print(f"{name:45s} canodom {ns:8.1f} ns/frame   cantools {c:9.0f} ns/frame   {c / ns:7.0f}x")
PY
