//! The native side's work, with the GIL released: logs, decoded messages,
//! replay steps and a drive's calibration as Arrow columns (or JSON for the
//! calibration's small result).

use crate::{Work, WorkError};
use arrow_array::builder::{
    ArrayBuilder, BinaryBuilder, BooleanBuilder, Float64Builder, Int64Builder, StringBuilder,
    UInt32Builder,
};
use arrow_array::{
    ArrayRef, Decimal128Array, Float64Array, Int64Array, RecordBatch, StringArray, UInt8Array,
    UInt16Array, UInt64Array,
};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use canodom_can::candump::ReadError;
use canodom_can::frame::FrameKind;
use canodom_dbc::{Database, Value};
use canodom_offline::Error as OfflineError;
use canodom_offline::log::open_log;
use canodom_offline::replay::{ReplayOptions, replay_rows};
use canodom_pipeline::config::Config;
use canodom_pipeline::stats::Reject;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;
use std::sync::Arc;

/// A log's read error as the library names it.
fn read_error(path: &Path, e: ReadError) -> WorkError {
    WorkError::Offline(OfflineError::Read {
        path: path.display().to_string(),
        source: e,
    })
}

/// Seconds from a timestamp, exactly as the CLI prints them (`secs.micros`
/// read back as a float: the micros' quotient is correctly rounded too).
fn seconds(t: canodom_can::time::Timestamp) -> f64 {
    t.as_micros() as f64 / 1e6
}

/// Every frame of the log at `path` as one record batch.
pub fn read_frames(path: &Path) -> Work<(Vec<RecordBatch>, SchemaRef)> {
    let mut reader = open_log(path, None, false)?;
    let timed = reader.has_time();
    let mut t = Float64Builder::new();
    let mut channel = StringBuilder::new();
    let mut id = UInt32Builder::new();
    let mut extended = BooleanBuilder::new();
    let mut fd = BooleanBuilder::new();
    let mut data = BinaryBuilder::new();
    let mut malformed = 0u64;
    loop {
        match reader.next_record() {
            Ok(Some(r)) => {
                t.append_option(timed.then(|| seconds(r.timestamp)));
                channel.append_value(r.iface);
                id.append_value(r.frame.id().raw());
                extended.append_value(r.frame.id().is_extended());
                fd.append_value(matches!(r.frame.kind(), FrameKind::Fd { .. }));
                data.append_value(r.frame.data());
            }
            Ok(None) => break,
            Err(ReadError::Malformed(_)) => malformed += 1,
            Err(e) => return Err(read_error(path, e)),
        }
    }
    let schema = Arc::new(Schema::new_with_metadata(
        vec![
            Field::new("t_unix_s", DataType::Float64, true),
            Field::new("channel", DataType::Utf8, false),
            Field::new("id", DataType::UInt32, false),
            Field::new("extended", DataType::Boolean, false),
            Field::new("fd", DataType::Boolean, false),
            Field::new("data", DataType::Binary, false),
        ],
        HashMap::from([("canodom.malformed".to_owned(), malformed.to_string())]),
    ));
    let columns: Vec<ArrayRef> = vec![
        Arc::new(t.finish()),
        Arc::new(channel.finish()),
        Arc::new(id.finish()),
        Arc::new(extended.finish()),
        Arc::new(fd.finish()),
        Arc::new(data.finish()),
    ];
    let batch = RecordBatch::try_new(schema.clone(), columns)?;
    Ok((vec![batch], schema))
}

/// One signal's values as decoded, absent (null) where a multiplexer did
/// not select it.
struct SignalColumn {
    name: String,
    values: Values,
}

/// A signal's values kept as compact as their kind allows while they come:
/// int64 while every integer fits, float64 from the first float (integers
/// then read as floats: the column's type is float64 either way), the exact
/// values only once an integer leaves int64. A `Value` is 32 bytes (an
/// i128 in an option), an int64 or float64 8: decode's peak memory over its
/// output was 2.8x the output's size on the RAV4 log with the exact values
/// kept for every signal (python/bench/decode_vs_cantools.py).
enum Values {
    Int(Int64Builder),
    Float(Float64Builder),
    Exact(Vec<Option<Value>>),
}

impl Values {
    fn len(&self) -> usize {
        match self {
            Self::Int(b) => b.len(),
            Self::Float(b) => b.len(),
            Self::Exact(v) => v.len(),
        }
    }

    /// Nulls up to `rows` values.
    fn pad(&mut self, rows: usize) {
        let missing = rows.saturating_sub(self.len());
        match self {
            Self::Int(b) => b.append_nulls(missing),
            Self::Float(b) => b.append_nulls(missing),
            Self::Exact(v) => v.resize(rows, None),
        }
    }

    fn push(&mut self, value: Value) {
        match (&mut *self, value) {
            (Self::Int(b), Value::Integer(i)) => {
                if let Ok(i) = i64::try_from(i) {
                    b.append_value(i);
                } else {
                    let mut exact: Vec<Option<Value>> = b
                        .finish()
                        .iter()
                        .map(|v| v.map(|i| Value::Integer(i128::from(i))))
                        .collect();
                    exact.push(Some(value));
                    *self = Self::Exact(exact);
                }
            }
            (Self::Int(b), Value::Float(f)) => {
                let mut floats = Float64Builder::with_capacity(b.len() + 1);
                floats.extend(b.finish().iter().map(|v| v.map(|i| i as f64)));
                floats.append_value(f);
                *self = Self::Float(floats);
            }
            (Self::Float(b), Value::Integer(i)) => b.append_value(i as f64),
            (Self::Float(b), Value::Float(f)) => b.append_value(f),
            (Self::Exact(v), value) => v.push(Some(value)),
        }
    }
}

impl SignalColumn {
    /// The column as Arrow: exact integers as int64, else uint64, else
    /// decimal128(38, 0); any float makes it float64 (as the CLI prints it).
    fn finish(self) -> Work<(Field, ArrayRef)> {
        let exact = match self.values {
            Values::Int(mut b) => {
                return Ok((
                    Field::new(self.name, DataType::Int64, true),
                    Arc::new(b.finish()),
                ));
            }
            Values::Float(mut b) => {
                return Ok((
                    Field::new(self.name, DataType::Float64, true),
                    Arc::new(b.finish()),
                ));
            }
            Values::Exact(v) => v,
        };
        let all_int = exact
            .iter()
            .flatten()
            .all(|v| matches!(v, Value::Integer(_)));
        let ints = || {
            exact.iter().map(|v| match v {
                Some(Value::Integer(i)) => Some(*i),
                _ => None,
            })
        };
        let (data_type, array): (DataType, ArrayRef) = if !all_int {
            let a: Float64Array = exact
                .iter()
                .map(|v| {
                    v.map(|v| match v {
                        Value::Integer(i) => i as f64,
                        Value::Float(f) => f,
                    })
                })
                .collect();
            (DataType::Float64, Arc::new(a))
        } else if ints().flatten().all(|i| i64::try_from(i).is_ok()) {
            let a: Int64Array = ints()
                .map(|i| i.and_then(|i| i64::try_from(i).ok()))
                .collect();
            (DataType::Int64, Arc::new(a))
        } else if ints().flatten().all(|i| u64::try_from(i).is_ok()) {
            let a: UInt64Array = ints()
                .map(|i| i.and_then(|i| u64::try_from(i).ok()))
                .collect();
            (DataType::UInt64, Arc::new(a))
        } else {
            let a = ints()
                .collect::<Decimal128Array>()
                .with_precision_and_scale(38, 0)?;
            (DataType::Decimal128(38, 0), Arc::new(a))
        };
        Ok((Field::new(self.name, data_type, true), array))
    }
}

/// One message's frames decoded: times and a column per signal.
struct MessageColumns {
    t_unix_s: Vec<Option<f64>>,
    signals: Vec<SignalColumn>,
}

/// Decodes the log at `path` with the DBC at `dbc`, as `canodom decode` does.
pub fn decode(
    path: &Path,
    dbc: &Path,
    strict: bool,
) -> Work<BTreeMap<String, (RecordBatch, SchemaRef)>> {
    let db = Database::from_file(dbc).map_err(|e| WorkError::Dbc(e.to_string()))?;
    let warnings = db.warnings();
    if strict && !warnings.is_empty() {
        let list: Vec<String> = warnings.iter().map(ToString::to_string).collect();
        return Err(WorkError::Dbc(format!(
            "strict: {} message(s) of {} cannot be decoded:\n  {}",
            warnings.len(),
            db.source_name(),
            list.join("\n  ")
        )));
    }
    let mut reader = open_log(path, None, false)?;
    let timed = reader.has_time();
    // By the message's index in the database: one lookup a frame.
    let mut messages: HashMap<*const canodom_dbc::Message, MessageColumns> = HashMap::new();
    let mut frames = 0u64;
    let mut known = 0u64;
    let mut scratch: Vec<(usize, Value)> = Vec::new();
    loop {
        let record = match reader.next_record() {
            Ok(Some(r)) => r,
            Ok(None) => break,
            Err(ReadError::Malformed(m)) => {
                if strict {
                    return Err(WorkError::Offline(OfflineError::Log(format!(
                        "{}: {m}",
                        path.display()
                    ))));
                }
                continue;
            }
            Err(e) => return Err(read_error(path, e)),
        };
        frames += 1;
        let frame = record.frame;
        let Some(message) = db.message_by_id(frame.id()) else {
            continue;
        };
        known += 1;
        if !matches!(frame.kind(), FrameKind::Data { .. } | FrameKind::Fd { .. }) {
            continue;
        }
        let columns = messages
            .entry(std::ptr::from_ref(message))
            .or_insert_with(|| MessageColumns {
                t_unix_s: Vec::new(),
                signals: message
                    .signals()
                    .iter()
                    .map(|s| SignalColumn {
                        name: s.name().to_owned(),
                        values: Values::Int(Int64Builder::new()),
                    })
                    .collect(),
            });
        let row = columns.t_unix_s.len();
        let first = message.signals().as_ptr() as usize;
        let size = std::mem::size_of::<canodom_dbc::Signal>().max(1);
        // A frame's values are kept only once it decoded whole.
        scratch.clear();
        let decoded = message.decode_each_value(frame.data(), |s, v| {
            // The signal's place in the message: its address in the slice
            // `signals()` hands out (decode_each_value walks that slice).
            scratch.push((
                (std::ptr::from_ref(s) as usize).wrapping_sub(first) / size,
                v,
            ));
        });
        if decoded.is_err() {
            // Too short for its message: skipped, as `canodom decode` does.
            continue;
        }
        for &(index, v) in &scratch {
            if let Some(column) = columns.signals.get_mut(index) {
                column.values.pad(row);
                column.values.push(v);
            }
        }
        columns
            .t_unix_s
            .push(timed.then(|| seconds(record.timestamp)));
    }
    if frames > 0 && known == 0 {
        return Err(WorkError::Value(format!(
            "{}: none of its {frames} frames has an id of {}: is this the vehicle's DBC?",
            path.display(),
            db.source_name()
        )));
    }
    if frames == 0 {
        return Err(WorkError::Offline(OfflineError::Log(format!(
            "{}: no frame read",
            path.display()
        ))));
    }
    message_tables(&db, messages)
}

/// Each decoded message's columns as a record batch, by name.
fn message_tables(
    db: &Database,
    mut messages: HashMap<*const canodom_dbc::Message, MessageColumns>,
) -> Work<BTreeMap<String, (RecordBatch, SchemaRef)>> {
    let mut out = BTreeMap::new();
    for message in db.messages() {
        let Some(columns) = messages.remove(&std::ptr::from_ref(message)) else {
            continue;
        };
        let rows = columns.t_unix_s.len();
        let mut fields = vec![Field::new("t_unix_s", DataType::Float64, true)];
        let mut arrays: Vec<ArrayRef> = vec![Arc::new(
            columns.t_unix_s.into_iter().collect::<Float64Array>(),
        )];
        for mut signal in columns.signals {
            signal.values.pad(rows);
            let (field, array) = signal.finish()?;
            fields.push(field);
            arrays.push(array);
        }
        let schema = Arc::new(Schema::new(fields));
        let batch = RecordBatch::try_new(schema.clone(), arrays)?;
        out.insert(message.name().to_owned(), (batch, schema));
    }
    Ok(out)
}

/// The parameter file's current set, as `replay --params` loads it.
fn load_params(
    path: Option<&Path>,
    config: &Config,
) -> Work<Option<canodom_params::persist::ParamSet>> {
    let Some(path) = path else {
        return Ok(None);
    };
    let file = canodom_params::persist::load(path, &config.calibration.bounds)
        .map_err(|e| WorkError::Offline(OfflineError::Params(format!("params: {e}"))))?;
    match file.current {
        Some(set) => Ok(Some(set)),
        None => Err(WorkError::Offline(OfflineError::Params(format!(
            "params {}: the file has no current set (rolled back to nominal)",
            path.display()
        )))),
    }
}

/// The replay CSV's columns, in its order.
const REPLAY_FLOATS: [&str; 6] = [
    "x_m",
    "y_m",
    "heading_rad",
    "odo_x_m",
    "odo_y_m",
    "odo_heading_rad",
];

/// Replays the log at `path` as `canodom replay` does, its rows as columns.
pub fn replay(
    path: &Path,
    config: &Config,
    params: Option<&Path>,
) -> Work<(RecordBatch, SchemaRef)> {
    let set = load_params(params, config)?;
    let input = canodom_offline::log::open_file(path)?;
    let name = path.display().to_string();
    let (rows, summary) = replay_rows(
        config,
        set.as_ref(),
        ReplayOptions {
            log_name: Some(&name),
            ..ReplayOptions::default()
        },
        input,
        &mut std::io::sink(),
    )
    .map_err(|e| match e {
        OfflineError::Log(why) => OfflineError::Log(format!("{name}: {why}")),
        other => other,
    })?;
    canodom_offline::log::check_log_read(path, &summary.seen, None)?;
    if summary.stats.get(Reject::UnknownId) == summary.stats.frames {
        return Err(WorkError::Offline(OfflineError::Log(format!(
            "{name}: none of its {} frames has an id the configuration reads: is this the \
             configured vehicle's log, and {} its DBC?",
            summary.stats.frames,
            config.db.source_name()
        ))));
    }
    let float = |f: &dyn Fn(&canodom_offline::replay::ReplayRow) -> f64| -> ArrayRef {
        Arc::new(rows.iter().map(f).collect::<Float64Array>())
    };
    let mut fields = vec![Field::new("t_s", DataType::Float64, false)];
    let mut arrays = vec![float(&|r| r.t_us as f64 / 1e6)];
    for (k, name) in REPLAY_FLOATS.iter().enumerate() {
        fields.push(Field::new(*name, DataType::Float64, false));
        arrays.push(float(&|r| r.values[k]));
    }
    fields.push(Field::new("correction", DataType::Utf8, false));
    arrays.push(Arc::new(
        rows.iter()
            .map(|r| Some(r.correction.as_str()))
            .collect::<StringArray>(),
    ));
    fields.push(Field::new("t_unix_s", DataType::Float64, false));
    arrays.push(float(&|r| r.t_unix_us as f64 / 1e6));
    for (k, name) in ["speed_mps", "pos_std_m", "heading_std_rad"]
        .iter()
        .enumerate()
    {
        fields.push(Field::new(*name, DataType::Float64, false));
        arrays.push(float(&|r| r.sample[k]));
    }
    fields.push(Field::new("pose_valid", DataType::UInt8, false));
    arrays.push(Arc::new(
        rows.iter()
            .map(|r| Some(u8::from(r.quality & 1 == 1)))
            .collect::<UInt8Array>(),
    ));
    // ODOM_QUALITY's nine flags: INPUT_IMPLAUSIBLE is bit 8.
    fields.push(Field::new("quality", DataType::UInt16, false));
    arrays.push(Arc::new(
        rows.iter()
            .map(|r| Some(r.quality))
            .collect::<UInt16Array>(),
    ));
    let stats = &summary.stats;
    let mut rejects = serde_json::Map::new();
    for reason in Reject::ALL {
        rejects.insert(reason.as_str().to_owned(), stats.get(reason).into());
    }
    let json = serde_json::json!({
        "frames": stats.frames,
        "used": stats.used,
        "steps": stats.steps,
        "steps_without_front": stats.steps_without_front,
        "malformed": summary.malformed,
        "gate_kept_rear": stats.gate.kept_rear,
        "gate_used_front": stats.gate.used_front,
        "gate_yaw_over_rear": stats.gate.yaw_over_rear,
        "gate_yaw_refused": stats.gate.yaw_refused,
        "rejects": rejects,
    });
    let schema = Arc::new(Schema::new_with_metadata(
        fields,
        HashMap::from([("canodom.summary".to_owned(), json.to_string())]),
    ));
    let batch = RecordBatch::try_new(schema.clone(), arrays)?;
    Ok((batch, schema))
}

/// A parameter set as JSON.
fn values_json(v: &canodom_params::persist::ParamValues) -> serde_json::Value {
    serde_json::json!({
        "rear_tread_m": v.rear_tread_m,
        "rear_left_diameter_m": v.rear_left_diameter_m,
        "rear_right_diameter_m": v.rear_right_diameter_m,
        "steering_gain": v.steering_gain,
        "steering_offset_rad": v.steering_offset_rad,
        "yaw_rate_bias_radps": v.yaw_rate_bias_radps,
        "yaw_rate_scale": v.yaw_rate_scale,
    })
}

/// Calibrates from the log at `path` against the fixes at `fixes`, as
/// `canodom calibrate --fixes` does; the result as JSON.
pub fn calibrate_fixes(
    path: &Path,
    config: &Config,
    fixes: &Path,
    params: Option<&Path>,
) -> Work<String> {
    let set = load_params(params, config)?;
    let all_fixes = canodom_offline::drive::read_fixes(fixes)?;
    let base = canodom_offline::drive::values_in_use(config, set.as_ref());
    let frames = canodom_offline::log::LogFrames::open(path, "calibrate_fixes", None)?;
    let name = path.display().to_string();
    let drive = canodom_offline::drive::samples_from_frames(config, set.as_ref(), frames, &name)?;
    let what = format!("{name} against {}", fixes.display());
    let fit = canodom_offline::drive::fit_drive(
        config,
        base,
        &drive,
        &all_fixes,
        &what,
        &canodom_calib::drive::DriveOptions::default(),
    )?;
    let cal = &fit.calibration;
    let mut estimates = serde_json::Map::new();
    let mut not_told = Vec::new();
    for (name, estimate) in [
        ("speed_scale", Some(&cal.speed_scale)),
        ("rear_ratio", Some(&cal.rear_ratio)),
        ("steering_offset_rad", cal.steer_offset_rad.as_ref()),
        ("steering_gain", cal.steer_gain.as_ref()),
        ("yaw_rate_bias_radps", cal.yaw_bias_radps.as_ref()),
        ("yaw_rate_scale", cal.yaw_scale.as_ref()),
    ] {
        let Some(e) = estimate else { continue };
        if !e.observable {
            not_told.push(name);
        }
        estimates.insert(
            name.to_owned(),
            serde_json::json!({"value": e.value, "sigma": e.sigma, "observable": e.observable}),
        );
    }
    // The rear tread's correction is told only by a drive turning both ways.
    estimates.insert(
        "rear_tread_rel".to_owned(),
        serde_json::json!({"value": cal.rear_tread.value, "sigma": cal.rear_tread.sigma,
            "observable": cal.rear_tread.observable}),
    );
    if !cal.rear_tread.observable {
        not_told.push("rear_tread_m");
    }
    let latency = cal.fixes_latency_s;
    estimates.insert(
        "fixes_latency_s".to_owned(),
        serde_json::json!({"value": latency.value, "sigma": latency.sigma,
            "observable": latency.observable, "given": cal.latency_given}),
    );
    let down_weighted: Vec<serde_json::Value> = cal
        .down_weighted
        .iter()
        .map(|d| serde_json::json!({"t_unix_s": d.t_s, "residual_m": d.residual_m, "weight": d.weight}))
        .collect();
    let refused: Vec<serde_json::Value> = fit
        .refused
        .iter()
        .map(|r| serde_json::json!({"parameter": r.parameter, "reason": r.reason}))
        .collect();
    let [rear, yaw, steering] = cal.residual_rms_m;
    let json = serde_json::json!({
        "estimates": estimates,
        "not_told": not_told,
        "configured": values_json(&fit.base),
        "calibrated": values_json(&fit.values),
        "out_of_bounds": fit.out_of_bounds,
        "down_weighted": down_weighted,
        "refused": refused,
        "fixes_used": cal.fixes_used,
        "fixes_outside": fit.fixes_outside,
        "distance_m": cal.distance_m,
        "residual_rms_m": {"rear_wheels": rear, "yaw_rate": yaw, "steering": steering},
        "steps": drive.samples.len(),
        "malformed": drive.malformed,
    });
    Ok(json.to_string())
}
