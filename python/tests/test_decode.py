"""decode() against `canodom decode`, value for value: the real DBC files of
data/dbc with a log of random frames of every message each, and the RAV4 log."""

import json
import math
import random
import re
from pathlib import Path

import pyarrow as pa
import pytest

import canodom
from conftest import DATA, RAV4, run_cli

DBCS = sorted((DATA / "dbc").glob("*.dbc"))


# A message's id and length, straight from its `BO_` line: the log needs no
# more, and cantools cannot load every file here (opendbc's Honda file has a
# comment cantools's grammar refuses), so it must not decide which are tested.
BO_LINE = re.compile(r"^BO_\s+(\d+)\s+\w+\s*:\s*(\d+)", re.MULTILINE)


def messages(dbc: Path):
    """(id, is_extended, length) of every message `dbc` defines."""
    out = []
    for raw_id, length in BO_LINE.findall(dbc.read_text(encoding="latin-1")):
        raw = int(raw_id)
        if raw == 0xC0000000:  # VECTOR__INDEPENDENT_SIG_MSG: not a frame
            continue
        out.append((raw & 0x1FFFFFFF, bool(raw & 0x80000000), int(length)))
    return out


def random_log(dbc: Path, out: Path, frames_per_message: int = 40, seed: int = 7) -> Path:
    """A candump -L log with random data for every message of `dbc`."""
    rng = random.Random(seed)
    lines, t = [], 1_600_000_000.0
    found = messages(dbc)
    assert found, f"{dbc}: no BO_ line read"
    for _ in range(frames_per_message):
        for frame_id, extended, length in found:
            t += 0.000173
            data = bytes(rng.randrange(256) for _ in range(length))
            ident = f"{frame_id:08X}" if extended else f"{frame_id:03X}"
            sep = "##0" if length > 8 else "#"
            lines.append(f"({t:.6f}) can0 {ident}{sep}{data.hex().upper()}")
    out.write_text("\n".join(lines) + "\n")
    return out


def cli_decode(cli, log: Path, dbc: Path):
    """`canodom decode` parsed: message name -> list of (t, signals)."""
    done = run_cli(cli, "decode", "--dbc", dbc, log)
    by_message = {}
    for line in done.stdout.splitlines():
        obj = json.loads(line)
        by_message.setdefault(obj["name"], []).append(obj)
    return by_message


def assert_same(tables, expected):
    assert sorted(tables) == sorted(expected)
    for name, rows in expected.items():
        table = tables[name]
        assert table.num_rows == len(rows), name
        columns = {c: table.column(c).to_pylist() for c in table.column_names}
        assert columns["t_unix_s"] == [r["t"] for r in rows], name
        for c, values in columns.items():
            if c == "t_unix_s":
                continue
            for i, (got, row) in enumerate(zip(values, rows)):
                want = row["signals"].get(c, "absent")
                if want == "absent":
                    assert got is None, (name, c, i)
                elif want is None:  # NaN or infinite: JSON null
                    assert got is not None and not math.isfinite(got), (name, c, i, got)
                else:
                    # JSON reads an integral float (`1200`) as an int: the
                    # value is compared; int columns are checked apart.
                    assert got == want, (name, c, i, got, want)
                    if isinstance(got, int):
                        assert isinstance(want, int), (name, c, i, got, want)


@pytest.mark.parametrize("dbc", DBCS, ids=lambda p: p.stem)
def test_decode_equals_the_cli_on_every_real_dbc(dbc, tmp_path, canodom_cli):
    log = random_log(dbc, tmp_path / "random.log")
    expected = cli_decode(canodom_cli, log, dbc)
    assert expected, "the CLI decoded nothing: the test would compare nothing"
    assert_same(canodom.decode(log, dbc), expected)


def test_decode_equals_the_cli_on_the_rav4_log(canodom_cli):
    dbc = DATA / "dbc" / "opendbc_toyota_2017.dbc"
    expected = cli_decode(canodom_cli, RAV4 / "drive.log", dbc)
    tables = canodom.decode(str(RAV4 / "drive.log"), str(dbc))
    assert_same(tables, expected)
    assert sum(t.num_rows for t in tables.values()) > 10_000


def test_exact_integers_are_int64_and_floats_float64():
    dbc = DATA / "dbc" / "opendbc_toyota_2017.dbc"
    tables = canodom.decode(RAV4 / "drive.log", dbc)
    speeds = tables["WHEEL_SPEEDS"]
    assert speeds.schema.field("WHEEL_SPEED_RL").type == pa.float64()
    types = {f.type for t in tables.values() for f in t.schema}
    assert pa.int64() in types
