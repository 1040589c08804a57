#!/usr/bin/env bash
# Reads canodom's MCAP files with independent readers from PyPI (#25):
# installs mcap, mcap-ros2-support and rosbags into a
# venv under the target folder (once), replays a simulated lap to CSV and to
# MCAP (LZ4 and uncompressed), checks each file against the CSV with
# check_mcap.py, does the same for the real RAV4 drive, then kills a replay
# of a longer drive mid-file (SIGKILL) and reads what it left with a streaming reader: every complete chunk.
#
#   export/tests/check_mcap.sh            # needs python3 with venv and pip (PyPI)
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$root"
target=${CARGO_TARGET_DIR:-$root/target}
work=$target/check-mcap
venv=$target/mcap-venv
mkdir -p "$work"
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c 'import mcap, mcap_ros2, rosbags' 2>/dev/null; then
    echo "== venv with the readers in $venv" >&2
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet mcap mcap-ros2-support rosbags >&2
fi
echo "== build" >&2
# The release binary the README's main command builds: CI builds nothing here (.ci/test-artifact.py says why).
CARGO_TARGET_DIR=$target cargo build --release -q -p canodom
bin=$target/release/canodom
config=daemon/examples/rc_car.toml

"$bin" simulate --config "$config" --log "$work/lap.log" --laps 1 2>/dev/null
frames=$(wc -l < "$work/lap.log")
"$bin" replay --config "$config" "$work/lap.log" --out "$work/lap.csv" 2>/dev/null
steps=$(($(wc -l < "$work/lap.csv") - 1))
for compression in lz4 none; do
    "$bin" replay --config "$config" "$work/lap.log" --out "$work/lap-$compression.mcap" \
        --compression "$compression" 2>/dev/null
    "$venv/bin/python" export/tests/check_mcap.py "$work/lap-$compression.mcap" "$work/lap.csv" "$steps" "$frames"
done

# A real car's drive (data/comma2k19-rav4: a RAV4 minute, real CAN): its
# covariances, a real bus's other frames on /canodom/can (every frame up to
# the last step's), with wheel speeds only and with the yaw-rate sensor.
rav4=data/comma2k19-rav4
for rav4_config in config config_yaw; do
    "$bin" replay --config "$rav4/$rav4_config.toml" "$rav4/drive.log" --out "$work/rav4.csv" 2>/dev/null
    "$bin" replay --config "$rav4/$rav4_config.toml" "$rav4/drive.log" --out "$work/rav4.mcap" 2>/dev/null
    steps=$(($(wc -l < "$work/rav4.csv") - 1))
    frames=$("$venv/bin/python" - "$work/rav4.csv" "$rav4/drive.log" <<'PY'
import csv, sys
last = list(csv.DictReader(open(sys.argv[1])))[-1]["t_unix_s"]
print(sum(1 for line in open(sys.argv[2]) if float(line[1:line.index(")")]) <= float(last)))
PY
)
    echo "rav4 $rav4_config: $steps steps, $frames frames up to the last step" >&2
    "$venv/bin/python" export/tests/check_mcap.py "$work/rav4.mcap" "$work/rav4.csv" "$steps" "$frames"
done

# A replay killed mid-file: everything up to its last complete chunk reads back.
"$bin" simulate --config "$config" --log "$work/long.log" --laps 12 2>/dev/null
"$bin" replay --config "$config" "$work/long.log" --out "$work/killed.mcap" 2>/dev/null &
pid=$!
for _ in $(seq 3000); do
    [ "$(stat -c %s "$work/killed.mcap" 2>/dev/null || echo 0)" -gt 2000000 ] && break
    kill -0 "$pid" 2>/dev/null || { echo "the replay ended before it could be killed" >&2; exit 1; }
    sleep 0.01
done
kill -9 "$pid"
wait "$pid" 2>/dev/null || true
"$venv/bin/python" - "$work/killed.mcap" <<'PY'
import sys
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader
from mcap_ros2.decoder import DecoderFactory

n, decode, counts = 0, DecoderFactory(), {}
try:
    with open(sys.argv[1], "rb") as f:
        for schema, channel, message in NonSeekingReader(f).iter_messages(log_time_order=False):
            if channel.topic == "/odom":
                decode.decoder_for(channel.message_encoding, schema)(message.data)
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            n += 1
except (McapError, EOFError) as e:  # the cut: the reader stops at the last whole record
    print(f"killed file: the reader stopped at the cut ({type(e).__name__})")
assert n > 0, "nothing readable in the killed file"
assert len(set(counts.values())) == 1, f"channels differ after the kill: {counts}"
print(f"check_mcap: ok: killed file: {n} messages in whole chunks, {n // 9} steps on each of 9 channels")
PY
echo "check_mcap: all passed"
