#!/usr/bin/env bash
# `canodom replay --ros2` against eProsima Fast DDS (#43), the other DDS ROS 2
# ships: installs Debian's libfastrtps-dev (2.9) when missing, compiles
# fastdds_subscriber.cpp with g++, and has its reliable and best-effort
# readers receive /odom of the RAV4 drive, compared with replay's CSV.
# Loopback only: unicast discovery to 127.0.0.1, no multicast, domain 78.
#
#   ros2/tests/fastdds.sh [--speed 4] [--domain 78]
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$root"
target=${CARGO_TARGET_DIR:-$root/target}
speed=4
domain=78
while [ $# -gt 0 ]; do
    case $1 in
        --speed) speed=$2; shift 2 ;;
        --domain) domain=$2; shift 2 ;;
        *) echo "unknown option $1" >&2; exit 2 ;;
    esac
done
if [ ! -f /usr/include/fastdds/dds/domain/DomainParticipant.hpp ]; then
    echo "== apt: libfastrtps-dev" >&2
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends \
        libfastrtps-dev g++ >/dev/null
fi
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
echo "== compile the Fast DDS subscriber" >&2
g++ -std=c++17 -O1 -o "$work/sub" ros2/tests/fastdds_subscriber.cpp -lfastrtps -lfastcdr
echo "== build" >&2
# The release binary the README's main command builds: CI builds nothing here (.ci/test-artifact.py says why).
CARGO_TARGET_DIR=$target cargo build --release -q -p canodom
canodom=$target/release/canodom
data=data/comma2k19-rav4
sed "s|^dbc *= *\"\\([^\"]*\\)\"|dbc = \"$root/$data/\\1\"|" $data/config.toml >"$work/config.toml"
printf '\n[ros2]\ndomain_id = %s\ndiscovery = "localhost"\n' "$domain" >>"$work/config.toml"
"$canodom" replay --config $data/config.toml $data/drive.log --out "$work/reference.csv" 2>/dev/null
"$work/sub" "$domain" 3 >"$work/received.csv" 2>"$work/sub.log" &
sub=$!
env -u CYCLONEDDS_URI "$canodom" replay --config "$work/config.toml" $data/drive.log --ros2 \
    --ros2-wait 2 --ros2-speed "$speed" 2>"$work/replay.log" || {
    cat "$work/replay.log" >&2
    kill "$sub" 2>/dev/null
    exit 1
}
grep "replay:" "$work/replay.log" | sed 's/^/   canodom: /'
wait "$sub" || { echo "FAIL: the Fast DDS subscriber: $(cat "$work/sub.log")" >&2; exit 1; }
python3 - "$work/reference.csv" "$work/received.csv" "$speed" <<'EOF'
import csv, math, sys
ref = {}
with open(sys.argv[1]) as f:
    for r in csv.DictReader(f):
        ref[round(float(r["t_unix_s"]) * 1e6)] = (float(r["x_m"]), float(r["y_m"]), float(r["heading_rad"]))
got = {"reliable": [], "best_effort": []}
for line in open(sys.argv[2]):
    p = line.strip().split(",")
    got.setdefault(p[0], []).append(p[1:])
fail = []
print(f"== Fast DDS 2.9 subscriber, /odom of {len(ref)} steps at x{sys.argv[3]} the log's pace")
for name, rows in got.items():
    bad = [r for r in rows if r == ["undecodable"]]
    rows = [r for r in rows if r != ["undecodable"]]
    dpos = dhead = 0.0
    unknown = 0
    frames = set()
    for sec, ns, frame, child, x, y, qz, qw in rows:
        key = int(sec) * 1_000_000 + int(ns) // 1000
        frames.add((frame, child))
        if key not in ref:
            unknown += 1
            continue
        rx, ry, rh = ref[key]
        dpos = max(dpos, abs(float(x) - rx), abs(float(y) - ry))
        h = 2 * math.atan2(float(qz), float(qw)) - rh
        dhead = max(dhead, abs(math.atan2(math.sin(h), math.cos(h))))
    print(f"  {name:11} reader: {len(rows)} of {len(ref)} samples, max |dx|,|dy| {dpos:.3g} m, "
          f"max heading diff {dhead:.3g} rad, stamps not in the CSV {unknown}, undecodable {len(bad)}, frames {sorted(frames)}")
    least = len(ref) if name == "reliable" else int(0.95 * len(ref))
    if len(rows) < least:
        fail.append(f"{name}: {len(rows)} of {len(ref)} samples (want >= {least})")
    if bad or unknown or dpos > 1e-9 or dhead > 1e-9:
        fail.append(f"{name}: poses differ from the CSV ({dpos}, {dhead}), {unknown} unknown stamps, {len(bad)} undecodable")
for f in fail:
    print("FAIL:", f)
sys.exit(1 if fail else 0)
EOF
