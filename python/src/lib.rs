//! The native module of the `canodom` Python package (`canodom._canodom`):
//! thin wrappers that run canodom's Rust code with the GIL released and hand
//! the results to Python as Arrow tables through the Arrow C data interface
//! (the arrow crate's pyarrow interface: no copy through Python objects).
//!
//! The work itself is the library crates': [`canodom_offline`] (replay, a
//! drive's calibration, logs by path), [`canodom_dbc`] (decoding) and
//! [`canodom_can`] (every log format), the same code as the `canodom` CLI.
//! Every failure is a Python exception naming the file, line, key or signal.

mod columns;
mod messages;
mod stream;

use arrow_array::RecordBatch;
use arrow_pyarrow::{IntoPyArrow, Table};
use canodom_offline::Error as OfflineError;
use canodom_pipeline::config::Config;
use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyFileNotFoundError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::{Path, PathBuf};

create_exception!(
    _canodom,
    CanodomError,
    PyException,
    "Base class of every error canodom raises for its input."
);
create_exception!(
    _canodom,
    LogError,
    CanodomError,
    "A CAN log cannot be read: a format not read, a corrupt file, no usable frame."
);
create_exception!(
    _canodom,
    DbcError,
    CanodomError,
    "A DBC file is refused (a message that cannot be decoded under strict=True, a syntax error)."
);
create_exception!(
    _canodom,
    ConfigError,
    CanodomError,
    "A configuration (or parameter file) is refused: an unknown key, a bad value, a signal not in its DBC."
);
create_exception!(
    _canodom,
    CalibrationError,
    CanodomError,
    "Position fixes cannot be read, or the drive's calibration failed."
);

/// A library error as the Python exception of its kind.
fn to_py(e: &OfflineError) -> PyErr {
    let text = e.to_string();
    match e {
        OfflineError::File { source, .. } if source.kind() == std::io::ErrorKind::NotFound => {
            PyFileNotFoundError::new_err(text)
        }
        OfflineError::File { .. } | OfflineError::Log(_) | OfflineError::Read { .. } => {
            LogError::new_err(text)
        }
        OfflineError::Config(_) | OfflineError::Params(_) | OfflineError::Filter { .. } => {
            ConfigError::new_err(text)
        }
        OfflineError::Calibration(_) => CalibrationError::new_err(text),
        OfflineError::Io(_) | OfflineError::Mcap(_) | OfflineError::FilterThread => {
            CanodomError::new_err(text)
        }
    }
}

/// What the native side returns before it holds the GIL again.
type Work<T> = Result<T, WorkError>;

/// An error met with the GIL released, turned into a Python exception once it is held.
enum WorkError {
    Offline(OfflineError),
    Dbc(String),
    Value(String),
    Arrow(arrow_schema::ArrowError),
}

impl WorkError {
    /// A log's read error as the library names it (with the file).
    fn read(path: &std::path::Path, e: canodom_can::candump::ReadError) -> Self {
        Self::Offline(OfflineError::Read {
            path: path.display().to_string(),
            source: e,
        })
    }
}

impl From<OfflineError> for WorkError {
    fn from(e: OfflineError) -> Self {
        Self::Offline(e)
    }
}

impl From<arrow_schema::ArrowError> for WorkError {
    fn from(e: arrow_schema::ArrowError) -> Self {
        Self::Arrow(e)
    }
}

impl From<WorkError> for PyErr {
    fn from(e: WorkError) -> Self {
        match e {
            WorkError::Offline(e) => to_py(&e),
            WorkError::Dbc(text) => DbcError::new_err(text),
            WorkError::Value(text) => PyValueError::new_err(text),
            WorkError::Arrow(e) => CanodomError::new_err(format!("arrow: {e}")),
        }
    }
}

/// The configuration at `path`, validated as `canodom run` validates it.
fn load_config(path: &Path) -> Work<Config> {
    Config::load(path).map_err(|e| WorkError::Offline(OfflineError::Config(e)))
}

/// `batches` as a `pyarrow.Table`.
fn table(
    py: Python<'_>,
    batches: Vec<RecordBatch>,
    schema: arrow_schema::SchemaRef,
) -> PyResult<Py<PyAny>> {
    let table = Table::try_new(batches, schema)
        .map_err(|e| CanodomError::new_err(format!("arrow: {e}")))?;
    Ok(table.into_pyarrow(py)?.unbind())
}

/// read_log(path)
/// --
///
/// Every frame of a CAN log as a pyarrow.Table with the columns t_unix_s
/// (float64 seconds on the log's clock; null for plain candump output,
/// which has no time), channel (the interface or ASC/BLF channel, string),
/// id (uint32), extended (bool), fd (bool) and data (binary).
///
/// Reads every format canodom reads, told apart by content: candump -L,
/// plain and timed candump output, Vector ASC and BLF, each also gzip- or
/// zstd-compressed. Malformed lines are skipped (their count is in the
/// table's schema metadata, key b"canodom.malformed").
///
/// Raises FileNotFoundError for a missing file and canodom.LogError for a
/// format not read (its name and the conversion command) or a corrupt file.
#[pyfunction]
fn read_log(py: Python<'_>, path: PathBuf) -> PyResult<Py<PyAny>> {
    let (batches, schema) = py.detach(|| columns::read_frames(&path))?;
    table(py, batches, schema)
}

/// decode(path, dbc, *, strict=False)
/// --
///
/// Decodes a CAN log with a DBC file: a dict from message name to a
/// pyarrow.Table with t_unix_s and a column per signal, the values `canodom
/// decode` prints. Each column's type follows from its signal's DBC
/// definition, so a message has the same schema in every log: a signal
/// whose values are exact integers (integer raw value, whole factor and
/// offset) is int64 when every value its bits can give fits int64, else
/// uint64 when they all fit that, else decimal128(38, 0); others float64.
/// A multiplexed signal is null in the frames whose multiplexer does not
/// select it. Frames of ids the DBC does not know, and frames too short for
/// their message, are skipped as in `canodom decode`.
///
/// strict=True refuses a DBC with a message that cannot be decoded (instead
/// of leaving the message out) and ends at the first malformed log line.
///
/// For a log larger than memory, decode_batches gives the same tables as
/// a stream of record batches.
///
/// Raises FileNotFoundError, canodom.LogError, canodom.DbcError.
#[pyfunction]
#[pyo3(signature = (path, dbc, *, strict = false))]
fn decode(py: Python<'_>, path: PathBuf, dbc: PathBuf, strict: bool) -> PyResult<Py<PyAny>> {
    let messages = py.detach(|| messages::decode(&path, &dbc, strict))?;
    let out = PyDict::new(py);
    for (name, (batch, schema)) in messages {
        out.set_item(name, table(py, vec![batch], schema)?)?;
    }
    Ok(out.into_any().unbind())
}

/// read_log_batches(path, *, batch_rows=65536)
/// --
///
/// The frames of a CAN log as read_log gives them, as an iterator of
/// pyarrow.RecordBatch of at most batch_rows rows each, read on a thread of
/// its own with the GIL released: memory is a few batches, whatever the
/// log's length. Its `schema` attribute is every batch's schema (without
/// read_log's malformed-line count: malformed lines are skipped).
/// canodom.read_log_batches wraps it in a pyarrow.RecordBatchReader.
///
/// Raises FileNotFoundError and canodom.LogError (a format not read) at
/// the call, canodom.LogError (a corrupt file, naming it) while iterating.
#[pyfunction]
#[pyo3(signature = (path, *, batch_rows = 65536))]
fn read_log_batches(
    py: Python<'_>,
    path: PathBuf,
    batch_rows: usize,
) -> PyResult<stream::FrameBatches> {
    Ok(py.detach(|| stream::FrameBatches::open(path, batch_rows))?)
}

/// decode_batches(path, dbc, *, strict=False, batch_rows=16384)
/// --
///
/// decode() as a stream, for logs larger than memory: an iterator of
/// (message name, pyarrow.RecordBatch) pairs, decoded on a thread of its
/// own with the GIL released. A message's batches come in the log's order,
/// each of batch_rows rows, but the last of each message, which come when
/// the log ends (in DBC order). Each message's batches concatenated are
/// decode()'s table of it, value for value and of the same schema. Memory:
/// at most batch_rows rows per message, whatever the log's length.
///
/// Raises FileNotFoundError, canodom.LogError (a format not read) and
/// canodom.DbcError at the call; canodom.LogError (a corrupt file, under
/// strict a malformed line, naming it) and ValueError (no frame has an id
/// of the DBC) while iterating.
#[pyfunction]
#[pyo3(signature = (path, dbc, *, strict = false, batch_rows = 16384))]
fn decode_batches(
    py: Python<'_>,
    path: PathBuf,
    dbc: PathBuf,
    strict: bool,
    batch_rows: usize,
) -> PyResult<stream::DecodeBatches> {
    Ok(py.detach(|| stream::DecodeBatches::open(path, dbc, strict, batch_rows))?)
}

/// replay(path, config, *, params=None)
/// --
///
/// The daemon's pipeline over a CAN log, as `canodom replay --config CONFIG
/// [--params PARAMS] LOG` runs it: a pyarrow.Table with the replay CSV's
/// columns (t_s, x_m, y_m, heading_rad, odo_x_m, odo_y_m, odo_heading_rad,
/// correction, t_unix_s, speed_mps, pos_std_m, heading_std_rad, pose_valid,
/// quality) and the values its rows hold, one row per filter step.
///
/// The schema metadata key b"canodom.summary" holds a JSON object of what
/// the replay did: frames, used, steps, malformed lines, the rejects by
/// reason and the gate's counts.
///
/// Raises FileNotFoundError, canodom.LogError, canodom.ConfigError (a
/// configuration or parameter file refused, naming the file, line and key).
#[pyfunction]
#[pyo3(signature = (path, config, *, params = None))]
fn replay(
    py: Python<'_>,
    path: PathBuf,
    config: PathBuf,
    params: Option<PathBuf>,
) -> PyResult<Py<PyAny>> {
    let (batch, schema) = py.detach(|| -> Work<_> {
        let config = load_config(&config)?;
        columns::replay(&path, &config, params.as_deref())
    })?;
    table(py, vec![batch], schema)
}

/// calibrate_fixes(path, config, fixes, *, params=None)
/// --
///
/// Calibrates the vehicle from an ordinary drive with position fixes, as
/// `canodom calibrate --config CONFIG --fixes FIXES LOG` does (nothing is
/// written). fixes is a CSV t_unix_s,x_m,y_m[,heading_rad], a CSV
/// t_unix_s,lat_deg,lon_deg[,alt_m] or an NMEA 0183 log (GGA/RMC), on the
/// log's clock. Returns a dict:
///
/// - "estimates": name -> {"value", "sigma", "observable"} for speed_scale,
///   rear_ratio, steering_offset_rad, steering_gain, yaw_rate_bias_radps,
///   yaw_rate_scale (those the log has data for), rear_tread_rel and
///   fixes_latency_s (with "given");
/// - "not_told": the names the drive could not tell (held at the values in use);
/// - "configured" and "calibrated": the parameter sets (rear_tread_m,
///   rear_left_diameter_m, rear_right_diameter_m, steering_gain,
///   steering_offset_rad, yaw_rate_bias_radps, yaw_rate_scale);
/// - "out_of_bounds": why the calibrated set is outside the configuration's
///   bounds, or None;
/// - "down_weighted": the fixes the robust loss down-weighted
///   ({"t_unix_s", "residual_m", "weight"});
/// - "refused": what the quality gate kept at its previous value
///   ({"parameter", "reason"});
/// - "fixes_used", "fixes_outside", "distance_m", "residual_rms_m", "steps",
///   "malformed".
///
/// Raises FileNotFoundError, canodom.LogError, canodom.ConfigError,
/// canodom.CalibrationError.
#[pyfunction]
#[pyo3(signature = (path, config, fixes, *, params = None))]
fn calibrate_fixes(
    py: Python<'_>,
    path: PathBuf,
    config: PathBuf,
    fixes: PathBuf,
    params: Option<PathBuf>,
) -> PyResult<Py<PyAny>> {
    let json = py.detach(|| -> Work<String> {
        let config = load_config(&config)?;
        columns::calibrate_fixes(&path, &config, &fixes, params.as_deref())
    })?;
    let loads = py.import("json")?.getattr("loads")?;
    Ok(loads.call1((json,))?.unbind())
}

/// canodom's native module: logs, decoding, replay and drive calibration.
#[pymodule]
fn _canodom(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("CanodomError", py.get_type::<CanodomError>())?;
    m.add("LogError", py.get_type::<LogError>())?;
    m.add("DbcError", py.get_type::<DbcError>())?;
    m.add("ConfigError", py.get_type::<ConfigError>())?;
    m.add("CalibrationError", py.get_type::<CalibrationError>())?;
    m.add_function(wrap_pyfunction!(read_log, m)?)?;
    m.add_function(wrap_pyfunction!(decode, m)?)?;
    m.add_function(wrap_pyfunction!(replay, m)?)?;
    m.add_function(wrap_pyfunction!(read_log_batches, m)?)?;
    m.add_function(wrap_pyfunction!(decode_batches, m)?)?;
    m.add_class::<stream::FrameBatches>()?;
    m.add_class::<stream::DecodeBatches>()?;
    m.add_function(wrap_pyfunction!(calibrate_fixes, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
