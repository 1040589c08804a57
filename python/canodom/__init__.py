"""canodom for Python: CAN logs, DBC decoding, odometry replay and drive
calibration as Arrow tables, run by canodom's Rust core with the GIL released.

    import canodom
    frames = canodom.read_log("drive.log")                 # pyarrow.Table of frames
    messages = canodom.decode("drive.log", "car.dbc")      # {message name: pyarrow.Table}
    for name, batch in canodom.decode_batches("big.log", "car.dbc"):  # logs larger than memory
        ...
    reader = canodom.read_log_batches("big.log")           # pyarrow.RecordBatchReader of frames
    poses = canodom.replay("drive.log", "car.toml")        # the replay CSV as a pyarrow.Table
    fit = canodom.calibrate_fixes("drive.log", "car.toml", "fixes.csv")

The same functions, one log per task, make the fleet job
(``python -m canodom.fleet MANIFEST --out DIR``, on Ray Data).
"""

from ._canodom import (
    CalibrationError,
    CanodomError,
    ConfigError,
    DbcError,
    LogError,
    __version__,
    calibrate_fixes,
    decode,
    decode_batches,
    read_log,
    replay,
)
from ._canodom import read_log_batches as _read_log_batches

__all__ = [
    "CalibrationError",
    "CanodomError",
    "ConfigError",
    "DbcError",
    "LogError",
    "__version__",
    "calibrate_fixes",
    "decode",
    "decode_batches",
    "read_log",
    "read_log_batches",
    "replay",
]


def read_log_batches(path, *, batch_rows=65536):
    """The frames of a CAN log as ``read_log`` gives them, as a
    ``pyarrow.RecordBatchReader`` of batches of at most ``batch_rows`` rows,
    for logs larger than memory: memory stays a few batches, whatever the
    log's length. The log is read on a thread of its own with the GIL
    released, beside the code consuming the batches.

    ``reader.read_all()`` equals ``read_log(path)`` but for the schema's
    metadata (the count of malformed lines, known only at the end; they are
    skipped). Hand it to anything that takes a RecordBatchReader, e.g.
    ``pyarrow.parquet.ParquetWriter``, ``pyarrow.dataset.write_dataset`` or
    DuckDB.

    Raises FileNotFoundError and canodom.LogError (a format not read) at the
    call, canodom.LogError (a corrupt file, naming it) while reading.
    """
    import pyarrow

    batches = _read_log_batches(path, batch_rows=batch_rows)
    return pyarrow.RecordBatchReader.from_batches(batches.schema, batches)
