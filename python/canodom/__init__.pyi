from os import PathLike
from typing import Union

import pyarrow

from ._canodom import (
    CalibrationError as CalibrationError,
    CanodomError as CanodomError,
    ConfigError as ConfigError,
    DbcError as DbcError,
    LogError as LogError,
    __version__ as __version__,
    calibrate_fixes as calibrate_fixes,
    decode as decode,
    decode_batches as decode_batches,
    read_log as read_log,
    replay as replay,
)

def read_log_batches(path: Union[str, "PathLike[str]"], *, batch_rows: int = 65536) -> pyarrow.RecordBatchReader:
    """read_log's frames as a RecordBatchReader of at most batch_rows rows per batch (flat memory)."""
