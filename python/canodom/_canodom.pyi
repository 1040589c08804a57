"""Type stubs of canodom's native module (see the docstrings of each function)."""

from os import PathLike
from typing import Any, Dict, Iterator, Optional, Tuple, Union

import pyarrow

_Path = Union[str, "PathLike[str]"]

__version__: str

class CanodomError(Exception):
    """Base class of every error canodom raises for its input."""

class LogError(CanodomError):
    """A CAN log cannot be read: a format not read, a corrupt file, no usable frame."""

class DbcError(CanodomError):
    """A DBC file is refused."""

class ConfigError(CanodomError):
    """A configuration or parameter file is refused (naming the file, line and key)."""

class CalibrationError(CanodomError):
    """Position fixes cannot be read, or the drive's calibration failed."""

def read_log(path: _Path) -> pyarrow.Table:
    """Every frame of a CAN log: t_unix_s, channel, id, extended, fd, data."""

def decode(path: _Path, dbc: _Path, *, strict: bool = False) -> Dict[str, pyarrow.Table]:
    """One table per message: t_unix_s and a column per signal, `canodom decode`'s values."""

class FrameBatches(Iterator[pyarrow.RecordBatch]):
    """A log's frames as record batches, read on a thread of its own."""

    @property
    def schema(self) -> pyarrow.Schema:
        """The schema of every batch: t_unix_s, channel, id, extended, fd, data."""
    def __iter__(self) -> "FrameBatches": ...
    def __next__(self) -> pyarrow.RecordBatch: ...

class DecodeBatches(Iterator[Tuple[str, pyarrow.RecordBatch]]):
    """(message name, record batch) pairs of a log decoded with a DBC, on a thread of its own."""

    def __iter__(self) -> "DecodeBatches": ...
    def __next__(self) -> Tuple[str, pyarrow.RecordBatch]: ...

def read_log_batches(path: _Path, *, batch_rows: int = 65536) -> FrameBatches:
    """read_log's frames as batches of at most batch_rows rows (canodom.read_log_batches wraps it)."""

def decode_batches(
    path: _Path, dbc: _Path, *, strict: bool = False, batch_rows: int = 16384
) -> DecodeBatches:
    """decode() as a stream of (message name, RecordBatch): at most batch_rows rows per message in memory."""

def replay(path: _Path, config: _Path, *, params: Optional[_Path] = None) -> pyarrow.Table:
    """The daemon's pipeline over a log: the replay CSV's columns, one row per filter step."""

def calibrate_fixes(
    path: _Path, config: _Path, fixes: _Path, *, params: Optional[_Path] = None
) -> Dict[str, Any]:
    """A drive calibrated against position fixes: estimates with σ, what it could not tell."""
