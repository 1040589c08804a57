"""Type stubs of canodom's native module (see the docstrings of each function)."""

from os import PathLike
from typing import Any, Dict, Optional, Union

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

def replay(path: _Path, config: _Path, *, params: Optional[_Path] = None) -> pyarrow.Table:
    """The daemon's pipeline over a log: the replay CSV's columns, one row per filter step."""

def calibrate_fixes(
    path: _Path, config: _Path, fixes: _Path, *, params: Optional[_Path] = None
) -> Dict[str, Any]:
    """A drive calibrated against position fixes: estimates with σ, what it could not tell."""
