"""replay() equals `canodom replay`'s CSV exactly, and read_log() reads every format."""

import gzip
import io
import math

import can
import pandas as pd
import pytest

import canodom
from conftest import RAV4, RC_CAR, run_cli, simulate


def assert_replay_equals_cli(cli, log, config, tmp_path, params=None):
    out = tmp_path / "pose.csv"
    args = ["replay", "--config", config, log, "--out", out]
    if params:
        args += ["--params", params]
    run_cli(cli, *args)
    expected = pd.read_csv(out, float_precision="round_trip", keep_default_na=False, dtype={"correction": str})
    table = canodom.replay(log, config, params=params)
    got = table.to_pandas()
    assert list(got.columns) == list(expected.columns)
    assert len(got) == len(expected) > 0
    for c in expected.columns:
        a, b = got[c].tolist(), expected[c].tolist()
        if c == "correction":
            assert a == b
        else:
            assert all(x == y or (math.isnan(x) and math.isnan(y)) for x, y in zip(a, b)), c
    return table


@pytest.mark.parametrize("config", ["config.toml", "config_yaw.toml"])
def test_replay_equals_the_cli_on_the_rav4_log(config, canodom_cli, tmp_path):
    table = assert_replay_equals_cli(canodom_cli, RAV4 / "drive.log", RAV4 / config, tmp_path)
    assert b"canodom.summary" in table.schema.metadata


def test_replay_equals_the_cli_on_a_simulated_drive(canodom_cli, tmp_path):
    log = simulate(canodom_cli, tmp_path / "sim", seed=3, path="figure-eight")
    assert_replay_equals_cli(canodom_cli, log, RC_CAR, tmp_path)


def test_read_log_reads_every_format_alike(tmp_path):
    lines = (RAV4 / "drive.log").read_text().splitlines()[:3000]
    candump = tmp_path / "part.log"
    candump.write_text("\n".join(lines) + "\n")
    reference = canodom.read_log(candump)
    assert reference.column_names == ["t_unix_s", "channel", "id", "extended", "fd", "data"]
    assert reference.num_rows == 3000
    # The same frames through python-can's writers, and compressed.
    messages = list(can.LogReader(str(candump)))
    for suffix in (".asc", ".blf"):
        path = tmp_path / f"part{suffix}"
        with can.Logger(str(path)) as writer:
            for m in messages:
                writer.on_message_received(m)
        table = canodom.read_log(path)
        assert table.num_rows == reference.num_rows, suffix
        assert table.column("id").to_pylist() == reference.column("id").to_pylist(), suffix
        assert table.column("data").to_pylist() == reference.column("data").to_pylist(), suffix
        got, want = table.column("t_unix_s").to_pylist(), reference.column("t_unix_s").to_pylist()
        # ASC's header date holds milliseconds: its start may be up to 1 ms off, the
        # frames' times from it are microseconds.
        assert abs(got[0] - want[0]) < 1e-3, suffix
        for a, b in zip(got, want):
            assert abs((a - got[0]) - (b - want[0])) < 2e-6, suffix
    gz = tmp_path / "part.log.gz"
    gz.write_bytes(gzip.compress(candump.read_bytes()))
    assert canodom.read_log(gz).equals(reference)
