from ._canodom import (
    CalibrationError as CalibrationError,
    CanodomError as CanodomError,
    ConfigError as ConfigError,
    DbcError as DbcError,
    LogError as LogError,
    __version__ as __version__,
    calibrate_fixes as calibrate_fixes,
    decode as decode,
    read_log as read_log,
    replay as replay,
)
