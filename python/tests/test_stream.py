"""The streaming API, for logs larger than memory: decode_batches' batches of
each message concatenate to exactly decode()'s table, read_log_batches' to
read_log's; errors are the same exceptions, at the call or while reading;
a stream left early ends its reading thread."""

import gzip
import os
import time
from collections import defaultdict

import pyarrow as pa
import pytest

import canodom
from conftest import DATA, RAV4
from test_decode import random_log

TOYOTA = DATA / "dbc" / "opendbc_toyota_2017.dbc"
FIXTURES = DATA.parent / "can" / "tests" / "fixtures" / "logs"
#: DBCs with multiplexed signals: a batch may end between a multiplexer's
#: values, and the nulls of the signals it did not select must stay in place.
MULTIPLEXED = ["cantools_multiplex", "opendbc_vw_mqb", "opendbc_tesla_model3_party"]


def streamed(log, dbc, batch_rows, strict=False):
    """decode_batches' batches by message, in the order they came."""
    by_message = defaultdict(list)
    for name, batch in canodom.decode_batches(log, dbc, strict=strict, batch_rows=batch_rows):
        assert isinstance(batch, pa.RecordBatch)
        by_message[name].append(batch)
    return by_message


def assert_concatenate_to_decode(log, dbc, batch_rows):
    whole = canodom.decode(log, dbc)
    parts = streamed(log, dbc, batch_rows)
    assert sorted(parts) == sorted(whole)
    for name, batches in parts.items():
        table = pa.Table.from_batches(batches)
        assert table.schema == whole[name].schema, name
        assert table.equals(whole[name]), name
        # Full batches, but the last of each message (handed out at the end).
        assert all(b.num_rows == batch_rows for b in batches[:-1]), name
        assert 0 < batches[-1].num_rows <= batch_rows or len(batches) == 1, name


@pytest.mark.parametrize("batch_rows", [3, 1000, 1 << 20])
def test_decode_batches_concatenate_to_decode_on_the_rav4_log(batch_rows):
    assert_concatenate_to_decode(RAV4 / "drive.log", TOYOTA, batch_rows)


@pytest.mark.parametrize("stem", MULTIPLEXED)
def test_decode_batches_keep_multiplexed_signals_in_place(stem, tmp_path):
    dbc = DATA / "dbc" / f"{stem}.dbc"
    log = random_log(dbc, tmp_path / "random.log", frames_per_message=25)
    for batch_rows in (1, 7, 16):
        assert_concatenate_to_decode(log, dbc, batch_rows)


def test_the_schema_follows_the_dbc_not_the_log(tmp_path):
    # Two logs of other random payloads: every message's schema is the same,
    # so a fleet's batches of one DBC stack into one dataset.
    for dbc in sorted((DATA / "dbc").glob("*.dbc")):
        a = canodom.decode(random_log(dbc, tmp_path / "a.log", 3, seed=1), dbc)
        b = canodom.decode(random_log(dbc, tmp_path / "b.log", 3, seed=2), dbc)
        assert {n: t.schema for n, t in a.items()} == {n: t.schema for n, t in b.items()}, dbc.name


@pytest.mark.parametrize("name", ["drive.log", "drive.asc", "drive.blf", "drive.mf4", "drive.log.zst"])
def test_read_log_batches_read_what_read_log_reads(name):
    log = FIXTURES / name
    reader = canodom.read_log_batches(log, batch_rows=64)
    assert isinstance(reader, pa.RecordBatchReader)
    batches = list(reader)
    assert all(b.num_rows == 64 for b in batches[:-1]) and 0 < batches[-1].num_rows <= 64
    whole = canodom.read_log(log)
    assert pa.Table.from_batches(batches).equals(whole.replace_schema_metadata(None))
    assert whole.num_rows > 64 * 3


def test_a_missing_or_foreign_log_raises_at_the_call(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.log"):
        canodom.read_log_batches(tmp_path / "nope.log")
    with pytest.raises(FileNotFoundError, match="nope.log"):
        canodom.decode_batches(tmp_path / "nope.log", TOYOTA)
    csv = tmp_path / "drive.csv"
    csv.write_text("timestamp,arbitration_id,extended,remote,error,dlc,data\n1700000000.0,0x123,0,0,0,2,0102\n")
    with pytest.raises(canodom.LogError, match=r"drive\.csv.*python-can CSV"):
        canodom.read_log_batches(csv)
    with pytest.raises(canodom.LogError, match=r"drive\.csv.*python-can CSV"):
        canodom.decode_batches(csv, TOYOTA)
    bad = tmp_path / "bad.dbc"
    bad.write_text('VERSION ""\nBO_ 257 BROKEN: 2 ECU\n SG_ TOO_FAR : 12|8@1+ (1,0) [0|255] "" ECU\n')
    with pytest.raises(canodom.DbcError, match="BROKEN"):
        canodom.decode_batches(RAV4 / "drive.log", bad, strict=True)
    with pytest.raises(ValueError, match="batch_rows"):
        canodom.decode_batches(RAV4 / "drive.log", TOYOTA, batch_rows=0)


def test_a_log_cut_short_raises_while_reading_naming_the_file(tmp_path):
    cut = tmp_path / "cut.log.gz"
    packed = gzip.compress((RAV4 / "drive.log").read_bytes())
    cut.write_bytes(packed[: len(packed) // 2])
    rows = 0
    with pytest.raises(canodom.LogError, match=r"cut\.log\.gz"):
        for batch in canodom.read_log_batches(cut, batch_rows=1000):
            rows += batch.num_rows
    assert rows > 0, "the error came before any batch: not a stream"
    rows = 0
    with pytest.raises(canodom.LogError, match=r"cut\.log\.gz"):
        for _, batch in canodom.decode_batches(cut, TOYOTA, batch_rows=100):
            rows += batch.num_rows
    assert rows > 0


def test_a_log_of_no_known_id_raises_value_error_at_its_end(tmp_path):
    log = tmp_path / "other.log"
    log.write_text("(1700000000.000000) can0 7FF#00\n" * 10)
    with pytest.raises(ValueError, match=r"other\.log.*none of its 10 frames"):
        list(canodom.decode_batches(log, TOYOTA))


def _reading_threads():
    """canodom's reading threads of this process, by their names."""
    names = []
    for task in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{task}/comm") as f:
                names.append(f.read().strip())
        except FileNotFoundError:  # a thread that just ended
            pass
    return sum(1 for n in names if n.startswith("canodom-"))


def _until_no_reading_thread(seconds=10):
    """Waits for canodom's reading threads to end (a thread that handed out
    its last batch still takes a moment to exit); how many are left."""
    deadline = time.monotonic() + seconds
    while _reading_threads() > 0 and time.monotonic() < deadline:
        time.sleep(0.01)
    return _reading_threads()


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="reads thread names in /proc")
def test_a_stream_left_early_ends_its_thread():
    assert _until_no_reading_thread() == 0, "a stream of an earlier test did not end"
    stream = canodom.decode_batches(RAV4 / "drive.log", TOYOTA, batch_rows=10)
    frames = canodom.read_log_batches(RAV4 / "drive.log", batch_rows=10)
    next(stream)
    frames.read_next_batch()
    # Both wait on their full channels, far from the log's end.
    assert _reading_threads() == 2
    del stream, frames
    assert _until_no_reading_thread() == 0
