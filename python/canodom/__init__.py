"""canodom for Python: CAN logs, DBC decoding, odometry replay and drive
calibration as Arrow tables, run by canodom's Rust core with the GIL released.

    import canodom
    frames = canodom.read_log("drive.log")                 # pyarrow.Table of frames
    messages = canodom.decode("drive.log", "car.dbc")      # {message name: pyarrow.Table}
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
    read_log,
    replay,
)

__all__ = [
    "CalibrationError",
    "CanodomError",
    "ConfigError",
    "DbcError",
    "LogError",
    "__version__",
    "calibrate_fixes",
    "decode",
    "read_log",
    "replay",
]
