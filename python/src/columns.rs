//! The native side's work, with the GIL released: logs, replay steps and a
//! drive's calibration as Arrow columns (or JSON for the calibration's small
//! result); decoding is [`crate::messages`]'s.

use crate::messages::seconds;
use crate::{Work, WorkError};
use arrow_array::builder::{
    ArrayBuilder, BinaryBuilder, BooleanBuilder, Float64Builder, StringBuilder, UInt32Builder,
};
use arrow_array::{ArrayRef, Float64Array, RecordBatch, StringArray, UInt8Array, UInt16Array};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use canodom_can::any_log::AnyLogReader;
use canodom_can::candump::{ReadError, Record};
use canodom_can::frame::FrameKind;
use canodom_offline::Error as OfflineError;
use canodom_offline::log::open_log;
use canodom_offline::replay::{ReplayOptions, replay_rows};
use canodom_pipeline::config::Config;
use canodom_pipeline::stats::Reject;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// The frames' columns as they come (`read_log`'s table, or one batch of
/// `read_log_batches`).
struct FrameColumns {
    timed: bool,
    t: Float64Builder,
    channel: StringBuilder,
    id: UInt32Builder,
    extended: BooleanBuilder,
    fd: BooleanBuilder,
    data: BinaryBuilder,
}

impl FrameColumns {
    fn new(timed: bool) -> Self {
        Self {
            timed,
            t: Float64Builder::new(),
            channel: StringBuilder::new(),
            id: UInt32Builder::new(),
            extended: BooleanBuilder::new(),
            fd: BooleanBuilder::new(),
            data: BinaryBuilder::new(),
        }
    }

    fn rows(&self) -> usize {
        self.id.len()
    }

    fn push(&mut self, r: &Record<'_>) {
        self.t
            .append_option(self.timed.then(|| seconds(r.timestamp)));
        self.channel.append_value(r.iface);
        self.id.append_value(r.frame.id().raw());
        self.extended.append_value(r.frame.id().is_extended());
        self.fd
            .append_value(matches!(r.frame.kind(), FrameKind::Fd { .. }));
        self.data.append_value(r.frame.data());
    }

    /// The rows so far as a record batch of `schema` (the builders start again).
    fn finish(&mut self, schema: SchemaRef) -> Work<RecordBatch> {
        let columns: Vec<ArrayRef> = vec![
            Arc::new(self.t.finish()),
            Arc::new(self.channel.finish()),
            Arc::new(self.id.finish()),
            Arc::new(self.extended.finish()),
            Arc::new(self.fd.finish()),
            Arc::new(self.data.finish()),
        ];
        Ok(RecordBatch::try_new(schema, columns)?)
    }
}

/// The frames' schema, with `metadata`.
fn frame_schema(metadata: HashMap<String, String>) -> SchemaRef {
    Arc::new(Schema::new_with_metadata(
        vec![
            Field::new("t_unix_s", DataType::Float64, true),
            Field::new("channel", DataType::Utf8, false),
            Field::new("id", DataType::UInt32, false),
            Field::new("extended", DataType::Boolean, false),
            Field::new("fd", DataType::Boolean, false),
            Field::new("data", DataType::Binary, false),
        ],
        metadata,
    ))
}

/// A log's frames as record batches of at most `batch_rows` rows each:
/// memory is one batch, whatever the log's length. Malformed lines are
/// skipped and counted.
pub struct FrameStream {
    reader: AnyLogReader<'static>,
    path: PathBuf,
    batch_rows: usize,
    columns: FrameColumns,
    malformed: u64,
    ended: bool,
}

impl FrameStream {
    /// Opens the log at `path`.
    ///
    /// # Errors
    /// The log cannot be opened, or its format is not read.
    pub fn open(path: &Path, batch_rows: usize) -> Work<Self> {
        if batch_rows == 0 {
            return Err(WorkError::Value("batch_rows must be at least 1".to_owned()));
        }
        let reader = open_log(path, None, false)?;
        let timed = reader.has_time();
        Ok(Self {
            reader,
            path: path.to_owned(),
            batch_rows,
            columns: FrameColumns::new(timed),
            malformed: 0,
            ended: false,
        })
    }

    /// The schema of every batch (no metadata: the malformed lines are
    /// known only at the end, [`Self::malformed`]).
    pub fn schema() -> SchemaRef {
        frame_schema(HashMap::new())
    }

    /// Malformed lines skipped so far.
    pub fn malformed(&self) -> u64 {
        self.malformed
    }

    /// The next batch of frames; `None` at the end.
    ///
    /// # Errors
    /// A read error, naming the file.
    pub fn next_batch(&mut self, schema: &SchemaRef) -> Work<Option<RecordBatch>> {
        if self.ended {
            return Ok(None);
        }
        while self.columns.rows() < self.batch_rows {
            match self.reader.next_record() {
                Ok(Some(r)) => self.columns.push(&r),
                Ok(None) => {
                    self.ended = true;
                    break;
                }
                Err(ReadError::Malformed(_)) => self.malformed += 1,
                Err(e) => return Err(WorkError::read(&self.path, e)),
            }
        }
        if self.ended && self.columns.rows() == 0 {
            return Ok(None);
        }
        self.columns.finish(schema.clone()).map(Some)
    }
}

/// Every frame of the log at `path` as one record batch.
pub fn read_frames(path: &Path) -> Work<(Vec<RecordBatch>, SchemaRef)> {
    let mut stream = FrameStream::open(path, usize::MAX)?;
    let plain = FrameStream::schema();
    let batch = stream.next_batch(&plain)?;
    let schema = frame_schema(HashMap::from([(
        "canodom.malformed".to_owned(),
        stream.malformed().to_string(),
    )]));
    let batch = match batch {
        Some(b) => b.with_schema(schema.clone())?,
        None => RecordBatch::new_empty(schema.clone()),
    };
    Ok((vec![batch], schema))
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
