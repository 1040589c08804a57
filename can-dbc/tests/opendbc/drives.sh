#!/usr/bin/env bash
# Every `config init` platform: a drive packed by opendbc's own packer with
# that platform's conventions, replayed from `canodom config init --car`'s
# configuration (issue #32). Installs opendbc into the venv check_packer.sh
# uses, builds canodom (release), prints the table; exits 1 when a platform misses
# (a checksum or counter reject, a warning, fused worse than rear-only or more
# than 1 % of the distance off).
#
#   can-dbc/tests/opendbc/drives.sh [--seeds 0 1 2] [--reverse] [--smooth] [--platforms subaru gm]
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)
cd "$root"
target=${CARGO_TARGET_DIR:-$root/target}
venv=$target/opendbc-venv
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c 'import opendbc.can.packer' 2>/dev/null; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet "opendbc==0.3.1" >&2
fi
# The release binary the README's main command builds: CI builds nothing here (.ci/test-artifact.py says why).
CARGO_TARGET_DIR=$target cargo build --release -q -p canodom
cd can-dbc/tests/opendbc
"$venv/bin/python" drives.py "$target/release/canodom" "$@"
