#!/usr/bin/env python3
"""Print the path of one executable that `cargo test --workspace` builds.

    python3 .ci/test-artifact.py PACKAGE_DIR KIND NAME
    python3 .ci/test-artifact.py daemon test tests      # daemon/tests/tests.rs
    python3 .ci/test-artifact.py gnss example gpsd_fixes

The scripts CI runs after the README's test command (gpsd under gpsfake, the
daemon with gpsd) use the binaries that command built instead of building
their own with `cargo build -p …` / `cargo test -p …`: a package selected
alone resolves its dependencies' features without the rest of the workspace,
so cargo compiled those crates and everything above them a second time
(after the workspace's test build: 5 min at -j1 for the daemon's test
binary, 3 min for the gpsd example). Run standalone, this builds what is
missing first (`cargo test --workspace --no-run`, progress on stderr).

For the same reason the scripts that need the canodom binary itself (MCAP
readers, Cyclone DDS, Fast DDS, the opendbc drives) run the release build of
the README's main command: a dev `cargo build -p canodom` after the
workspace's tests recompiled 42 crates (7 min at -j1).
"""

import json
import pathlib
import subprocess
import sys


def main() -> int:
    if len(sys.argv) != 4:
        print(__doc__.strip().splitlines()[2], file=sys.stderr)
        return 2
    package_dir, kind, name = sys.argv[1:]
    root = pathlib.Path(__file__).resolve().parent.parent
    want = (root / package_dir / "Cargo.toml").resolve()
    build = subprocess.run(
        ["cargo", "test", "--workspace", "--no-run", "--message-format=json-render-diagnostics"],
        cwd=root,
        stdout=subprocess.PIPE,
        text=True,
        check=False,
    )
    if build.returncode != 0:
        print(f"cargo test --workspace --no-run failed (exit {build.returncode})", file=sys.stderr)
        return 1
    for line in build.stdout.splitlines():
        try:
            message = json.loads(line)
        except json.JSONDecodeError:
            continue
        if message.get("reason") != "compiler-artifact" or not message.get("executable"):
            continue
        target = message["target"]
        if (
            pathlib.Path(message["manifest_path"]).resolve() == want
            and kind in target["kind"]
            and target["name"] == name
        ):
            print(message["executable"])
            return 0
    print(f"cargo test --workspace built no {kind} '{name}' of {package_dir}/", file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main())
