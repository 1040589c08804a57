"""MF4 (ASAM MDF 4 bus logging, #34): a file written by python-can's MF4Writer
(asammdf) from a candump log reads as the same frames and replays to exactly
the poses of its original, through the CLI and through Python; a truncated
or damaged one is a clear error naming the file and the block."""

import math

import can
import pytest

import canodom
from conftest import RAV4, RC_CAR, run_cli, simulate


def write_mf4(candump, out, level=2):
    """The frames of a candump -L log, written by python-can's MF4Writer."""
    writer = can.MF4Writer(str(out), compression_level=level)
    for m in can.LogReader(str(candump)):
        writer.on_message_received(m)
    writer.stop()
    return out


def assert_same_rows(a, b):
    assert a.column_names == b.column_names
    assert a.num_rows == b.num_rows > 0
    for name in a.column_names:
        x, y = a.column(name).to_pylist(), b.column(name).to_pylist()
        same = all(p == q or (isinstance(p, float) and math.isnan(p) and math.isnan(q)) for p, q in zip(x, y))
        assert same, name


@pytest.fixture(scope="module")
def rav4_mf4(tmp_path_factory):
    """The RAV4 log through MF4Writer's default (transposed, deflated ##DZ); written once."""
    return write_mf4(RAV4 / "drive.log", tmp_path_factory.mktemp("mf4") / "drive.mf4")


def test_an_mf4_of_the_rav4_log_replays_to_exactly_its_poses(rav4_mf4, canodom_cli, tmp_path):
    mf4 = rav4_mf4
    config = RAV4 / "config.toml"
    assert_same_rows(canodom.replay(mf4, config), canodom.replay(RAV4 / "drive.log", config))
    # The CLI too: its CSV, byte for byte.
    run_cli(canodom_cli, "replay", "--config", config, mf4, "--out", tmp_path / "mf4.csv")
    run_cli(canodom_cli, "replay", "--config", config, RAV4 / "drive.log", "--out", tmp_path / "log.csv")
    assert (tmp_path / "mf4.csv").read_bytes() == (tmp_path / "log.csv").read_bytes()


def test_an_mf4_of_a_simulated_drive_replays_and_reads_alike(canodom_cli, tmp_path):
    log = simulate(canodom_cli, tmp_path / "sim", seed=7, path="figure-eight")
    mf4 = write_mf4(log, tmp_path / "sim.mf4", level=0)  # uncompressed: ##DT
    assert_same_rows(canodom.replay(mf4, RC_CAR), canodom.replay(log, RC_CAR))
    ours, original = canodom.read_log(mf4), canodom.read_log(log)
    for name in ("t_unix_s", "id", "extended", "fd", "data"):
        assert ours.column(name).equals(original.column(name)), name
    # python-can's MF4Writer keeps channels as integers: vcan0 -> 0.
    assert set(ours.column("channel").to_pylist()) == {"0"}


def test_a_truncated_mf4_names_the_file_and_the_block(rav4_mf4, tmp_path):
    whole = rav4_mf4.read_bytes()
    cut = tmp_path / "cut.mf4"
    cut.write_bytes(whole[: len(whole) * 2 // 3])
    with pytest.raises(canodom.LogError) as raised:
        canodom.read_log(cut)
    message = str(raised.value)
    assert "cut.mf4" in message and "MF4 block ##" in message and "byte offset" in message, message
    with pytest.raises(canodom.LogError, match=r"cut\.mf4.*MF4 block"):
        canodom.replay(cut, RAV4 / "config.toml")
    # A damaged deflate stream: the ##DZ block by its offset.
    dz = whole.index(b"##DZ")
    bad = bytearray(whole)
    bad[dz + 80: dz + 120] = bytes(40)
    damaged = tmp_path / "damaged.mf4"
    damaged.write_bytes(bytes(bad))
    with pytest.raises(canodom.LogError, match=rf"damaged\.mf4.*##DZ at byte offset {dz}"):
        canodom.read_log(damaged)
