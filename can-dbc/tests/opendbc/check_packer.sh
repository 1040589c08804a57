#!/usr/bin/env bash
# The carmaker checksums against opendbc's own packer (#32): installs
# opendbc (PyPI, MIT) into a venv under the target folder (once), packs frames
# for every checksummed message of every platform check_packer.py lists, and
# checks that the committed fixture (can-dbc/tests/opendbc/packed.json, which
# `cargo test -p canodom-dbc` compares with canodom's checksums) is what
# opendbc packs today.
#
#   can-dbc/tests/opendbc/check_packer.sh            # check (CI)
#   can-dbc/tests/opendbc/check_packer.sh --write    # regenerate the fixture
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)
cd "$root"
target=${CARGO_TARGET_DIR:-$root/target}
venv=$target/opendbc-venv
here=can-dbc/tests/opendbc
# The fixture was packed by this opendbc; another version may pack differently.
version=0.3.1
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c 'import opendbc.can.packer' 2>/dev/null; then
    echo "== venv with opendbc $version in $venv" >&2
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet "opendbc==$version" >&2
fi
if [ "${1:-}" = "--write" ]; then
    "$venv/bin/python" "$here/check_packer.py" "$here/packed.json"
else
    "$venv/bin/python" "$here/check_packer.py" "$target/opendbc-packed.json" --check "$here/packed.json"
fi
# canodom's side: every frame's checksum recomputed (the fixture test).
# The test binary as `cargo test --workspace` built it (no second build in CI), run from its
# package's directory as cargo runs it.
tests_bin=$(CARGO_TARGET_DIR=$target python3 .ci/test-artifact.py can-dbc test tests)
(cd can-dbc && "$tests_bin" -q opendbc_packer)
