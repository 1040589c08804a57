//! Decoding a CAN log with a DBC into Arrow record batches, one stream of
//! batches per message, by a plan compiled once per message (as cantools
//! compiles its database once): each signal's column type is chosen from the
//! DBC before any frame, messages are found by their place in the database
//! (no hashing per frame), and each frame's values go straight into their
//! columns. Whole tables (`decode`) and batches of a bounded size
//! (`decode_batches`) come from the same [`DecodeStream`].

use crate::{Work, WorkError};
use arrow_array::builder::{
    ArrayBuilder, Decimal128Builder, Float64Builder, Int64Builder, UInt64Builder,
};
use arrow_array::{ArrayRef, Float64Array, RecordBatch};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use canodom_can::any_log::AnyLogReader;
use canodom_can::candump::ReadError;
use canodom_can::frame::FrameKind;
use canodom_can::time::Timestamp;
use canodom_dbc::{Database, FrameId, Message, Signal, Value};
use canodom_offline::Error as OfflineError;
use canodom_offline::log::open_log;
use std::collections::{BTreeMap, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Seconds from a timestamp, exactly as the CLI prints them (`secs.micros`
/// read back as a float: the micros' quotient is correctly rounded too).
pub(crate) fn seconds(t: Timestamp) -> f64 {
    t.as_micros() as f64 / 1e6
}

/// One signal's values, in the Arrow type its DBC definition gives every
/// value it can have ([`Signal::integer_range`]): int64 for integers that
/// all fit it, else uint64, else decimal128(38, 0); float64 for the others.
/// Chosen from the DBC, a message has the same schema in every log and in
/// every batch of a stream.
enum Column {
    Int(Int64Builder),
    UInt(UInt64Builder),
    Wide(Decimal128Builder),
    Float(Float64Builder),
}

impl Column {
    fn for_signal(signal: &Signal) -> Self {
        match signal.integer_range() {
            None => Self::Float(Float64Builder::new()),
            Some((lo, hi)) if lo >= i128::from(i64::MIN) && hi <= i128::from(i64::MAX) => {
                Self::Int(Int64Builder::new())
            }
            Some((lo, hi)) if lo >= 0 && hi <= i128::from(u64::MAX) => {
                Self::UInt(UInt64Builder::new())
            }
            Some(_) => {
                Self::Wide(Decimal128Builder::new().with_data_type(DataType::Decimal128(38, 0)))
            }
        }
    }

    fn data_type(&self) -> DataType {
        match self {
            Self::Int(_) => DataType::Int64,
            Self::UInt(_) => DataType::UInt64,
            Self::Wide(_) => DataType::Decimal128(38, 0),
            Self::Float(_) => DataType::Float64,
        }
    }

    #[inline]
    fn len(&self) -> usize {
        match self {
            Self::Int(b) => b.len(),
            Self::UInt(b) => b.len(),
            Self::Wide(b) => b.len(),
            Self::Float(b) => b.len(),
        }
    }

    /// Nulls up to `rows` values: a multiplexed signal in the frames its
    /// multiplexer did not select.
    #[inline]
    fn pad(&mut self, rows: usize) {
        let missing = rows.saturating_sub(self.len());
        if missing == 0 {
            return;
        }
        match self {
            Self::Int(b) => b.append_nulls(missing),
            Self::UInt(b) => b.append_nulls(missing),
            Self::Wide(b) => b.append_nulls(missing),
            Self::Float(b) => b.append_nulls(missing),
        }
    }

    /// Appends `value` as row `row`, nulls before it where rows were skipped.
    #[inline]
    fn push(&mut self, row: usize, value: Value) {
        self.pad(row);
        match (self, value) {
            // In range by construction (`for_signal`): the casts are exact.
            (Self::Int(b), Value::Integer(i)) => b.append_value(i as i64),
            (Self::UInt(b), Value::Integer(i)) => b.append_value(i as u64),
            (Self::Wide(b), Value::Integer(i)) => b.append_value(i),
            (Self::Float(b), v) => b.append_value(v.as_f64()),
            // A float in an integer column: impossible by `integer_range`'s
            // contract; a null rather than a wrong number if it ever were.
            (Self::Int(b), Value::Float(_)) => b.append_null(),
            (Self::UInt(b), Value::Float(_)) => b.append_null(),
            (Self::Wide(b), Value::Float(_)) => b.append_null(),
        }
    }

    /// The values so far as an array (the builder starts again empty).
    fn finish(&mut self) -> ArrayRef {
        match self {
            Self::Int(b) => Arc::new(b.finish()),
            Self::UInt(b) => Arc::new(b.finish()),
            Self::Wide(b) => Arc::new(b.finish()),
            Self::Float(b) => Arc::new(b.finish()),
        }
    }
}

/// One message's compiled plan and the rows not yet handed out.
struct MessagePlan {
    schema: SchemaRef,
    /// The message's payload length: a shorter frame is skipped.
    length: usize,
    t_unix_s: Vec<f64>,
    signals: Vec<Column>,
    /// Whether a batch of it was handed out already (a message seen only in
    /// frames too short for it still gives its empty table once).
    handed_out: bool,
}

impl MessagePlan {
    fn new(message: &Message) -> Self {
        let signals: Vec<Column> = message.signals().iter().map(Column::for_signal).collect();
        let mut fields = vec![Field::new("t_unix_s", DataType::Float64, true)];
        fields.extend(
            message
                .signals()
                .iter()
                .zip(&signals)
                .map(|(s, c)| Field::new(s.name(), c.data_type(), true)),
        );
        Self {
            schema: Arc::new(Schema::new(fields)),
            length: message.length(),
            t_unix_s: Vec::new(),
            signals,
            handed_out: false,
        }
    }

    /// The rows so far as a record batch (the plan starts again empty).
    fn finish(&mut self, timed: bool) -> Work<RecordBatch> {
        let rows = self.t_unix_s.len();
        let t_unix_s = std::mem::take(&mut self.t_unix_s);
        let mut arrays: Vec<ArrayRef> = Vec::with_capacity(self.signals.len() + 1);
        arrays.push(if timed {
            Arc::new(Float64Array::from(t_unix_s))
        } else {
            Arc::new(Float64Array::new_null(rows))
        });
        for column in &mut self.signals {
            column.pad(rows);
            arrays.push(column.finish());
        }
        self.handed_out = true;
        Ok(RecordBatch::try_new(self.schema.clone(), arrays)?)
    }
}

/// The decoding state apart from the log reader (so a record borrowed from
/// the reader can be decoded into it).
struct Decoder {
    db: Database,
    /// By the message's place in `db.messages()`; made at its first frame.
    plans: Vec<Option<MessagePlan>>,
    batch_rows: usize,
    frames: u64,
    known: u64,
}

impl Decoder {
    /// Decodes one data frame into its message's columns; the message's
    /// place when it holds `batch_rows` rows.
    #[inline]
    fn frame(&mut self, t: Timestamp, id: FrameId, data: &[u8]) -> Option<usize> {
        let index = self.db.message_index(id)?;
        self.known += 1;
        let message = &self.db.messages()[index];
        let plan = self.plans[index].get_or_insert_with(|| MessagePlan::new(message));
        if data.len() < plan.length {
            // Too short for its message: skipped, as `canodom decode` does.
            return None;
        }
        let row = plan.t_unix_s.len();
        let signals = &mut plan.signals;
        // The length is checked above, the one error decode_each_value has.
        let _ = message.decode_each_value(data, |s, v| {
            if let Some(column) = signals.get_mut(s.index()) {
                column.push(row, v);
            }
        });
        plan.t_unix_s.push(seconds(t));
        (plan.t_unix_s.len() >= self.batch_rows).then_some(index)
    }
}

/// A log decoded with a DBC as a stream of record batches, each of one
/// message: a message's batches come in the log's order, each at most
/// `batch_rows` rows (the last of each message when the log ends, in DBC
/// order). Memory: at most `batch_rows` rows per message, whatever the
/// log's length.
pub struct DecodeStream {
    decoder: Decoder,
    reader: AnyLogReader<'static>,
    timed: bool,
    strict: bool,
    path: PathBuf,
    /// The batches of the log's end, not yet handed out.
    ending: VecDeque<(String, RecordBatch)>,
    ended: bool,
}

impl DecodeStream {
    /// Loads the DBC and opens the log.
    ///
    /// # Errors
    /// The DBC is refused (under `strict`, also for a message it cannot
    /// decode), the log cannot be opened or its format is not read.
    pub fn open(path: &Path, dbc: &Path, strict: bool, batch_rows: usize) -> Work<Self> {
        if batch_rows == 0 {
            return Err(WorkError::Value("batch_rows must be at least 1".to_owned()));
        }
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
        let reader = open_log(path, None, false)?;
        let timed = reader.has_time();
        let plans = std::iter::repeat_with(|| None)
            .take(db.messages().len())
            .collect();
        Ok(Self {
            decoder: Decoder {
                db,
                plans,
                batch_rows,
                frames: 0,
                known: 0,
            },
            reader,
            timed,
            strict,
            path: path.to_owned(),
            ending: VecDeque::new(),
            ended: false,
        })
    }

    /// The next batch and its message's name; `None` at the end.
    ///
    /// # Errors
    /// A read error (naming the file), under `strict` a malformed line
    /// (naming it), or a log of which no frame was read or none had an id
    /// of the DBC.
    pub fn next_batch(&mut self) -> Work<Option<(String, RecordBatch)>> {
        if self.ended {
            return Ok(self.ending.pop_front());
        }
        loop {
            // `candump -L`'s fast path first: no CanFrame is built.
            if let Some(c) = self.reader.next_classic() {
                self.decoder.frames += 1;
                if let Some(full) = self.decoder.frame(c.timestamp, c.id, c.payload()) {
                    return self.hand_out(full).map(Some);
                }
                continue;
            }
            let record = match self.reader.next_record_general() {
                Ok(Some(r)) => r,
                Ok(None) => break,
                Err(ReadError::Malformed(m)) => {
                    if self.strict {
                        return Err(WorkError::Offline(OfflineError::Log(format!(
                            "{}: {m}",
                            self.path.display()
                        ))));
                    }
                    continue;
                }
                Err(e) => return Err(WorkError::read(&self.path, e)),
            };
            self.decoder.frames += 1;
            let (t, frame) = (record.timestamp, record.frame);
            if !matches!(frame.kind(), FrameKind::Data { .. } | FrameKind::Fd { .. }) {
                // Known or not, as `canodom decode` counts it.
                self.decoder.known +=
                    u64::from(self.decoder.db.message_by_id(frame.id()).is_some());
                continue;
            }
            if let Some(full) = self.decoder.frame(t, frame.id(), frame.data()) {
                return self.hand_out(full).map(Some);
            }
        }
        self.end()?;
        Ok(self.ending.pop_front())
    }

    /// The batch of the message at `index` in the database.
    fn hand_out(&mut self, index: usize) -> Work<(String, RecordBatch)> {
        let name = self.decoder.db.messages()[index].name().to_owned();
        let plan = self.decoder.plans[index]
            .as_mut()
            .ok_or_else(|| WorkError::Value(format!("{name}: no rows to hand out")))?;
        Ok((name, plan.finish(self.timed)?))
    }

    /// The log's end: its checks, then each message's last rows.
    fn end(&mut self) -> Work<()> {
        self.ended = true;
        let (frames, known) = (self.decoder.frames, self.decoder.known);
        if frames == 0 {
            return Err(WorkError::Offline(OfflineError::Log(format!(
                "{}: no frame read",
                self.path.display()
            ))));
        }
        if known == 0 {
            return Err(WorkError::Value(format!(
                "{}: none of its {frames} frames has an id of {}: is this the vehicle's DBC?",
                self.path.display(),
                self.decoder.db.source_name()
            )));
        }
        for (message, plan) in self
            .decoder
            .db
            .messages()
            .iter()
            .zip(&mut self.decoder.plans)
        {
            let Some(plan) = plan else { continue };
            if plan.t_unix_s.is_empty() && plan.handed_out {
                continue;
            }
            let batch = plan.finish(self.timed)?;
            self.ending.push_back((message.name().to_owned(), batch));
        }
        Ok(())
    }
}

/// Decodes the log at `path` with the DBC at `dbc`, as `canodom decode`
/// does: one record batch per message (of every frame), by name.
pub fn decode(
    path: &Path,
    dbc: &Path,
    strict: bool,
) -> Work<BTreeMap<String, (RecordBatch, SchemaRef)>> {
    let mut stream = DecodeStream::open(path, dbc, strict, usize::MAX)?;
    let mut out = BTreeMap::new();
    while let Some((name, batch)) = stream.next_batch()? {
        let schema = batch.schema();
        out.insert(name, (batch, schema));
    }
    Ok(out)
}
