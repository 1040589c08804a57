#!/usr/bin/env bash
# `canodom replay --ros2` against Eclipse Cyclone DDS (#43): installs PyPI's
# cyclonedds into a venv under the target folder (once), builds canodom (dev)
# and runs cyclone_subscriber.py on the real RAV4 drive: reliable and
# best-effort /odom readers, /tf, /diagnostics, compared with replay's CSV.
# Loopback only: unicast discovery to 127.0.0.1, no multicast, domain 77.
#
#   ros2/tests/cyclone.sh [--speed 1] [--sensor-speed 2] [--domain 77]
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$root"
target=${CARGO_TARGET_DIR:-$root/target}
venv=$target/cyclone-venv
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c 'import cyclonedds.domain' 2>/dev/null; then
    echo "== venv with Cyclone DDS in $venv" >&2
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet "cyclonedds==11.0.1" >&2
fi
echo "== build" >&2
# The release binary the README's main command builds: CI builds nothing here (.ci/test-artifact.py says why).
CARGO_TARGET_DIR=$target cargo build --release -q -p canodom
"$venv/bin/python" ros2/tests/cyclone_subscriber.py --canodom "$target/release/canodom" \
    --config data/comma2k19-rav4/config.toml --log data/comma2k19-rav4/drive.log "$@"
