//! Batches of a log made on a thread of their own and handed to Python one
//! at a time: `read_log_batches` and `decode_batches`.
//!
//! The log readers are not `Send` (their sources are boxed `BufRead`s, which
//! may be standard input's lock in the CLI), so a reader cannot live in a
//! Python object that any Python thread may use, nor cross into the
//! GIL-free closure of `Python::detach`. Each stream's reader is therefore
//! made and used on one thread of its own, which hands its batches (plain,
//! `Send` data) through a channel of [`DEPTH`] batches: memory stays a few
//! batches whatever the log's length, the reading runs without the GIL and
//! beside the Python code consuming the previous batch, and a stream dropped
//! early ends its thread at its next batch.

use crate::columns::FrameStream;
use crate::messages::DecodeStream;
use crate::{Work, WorkError};
use arrow_array::RecordBatch;
use arrow_pyarrow::ToPyArrow;
use arrow_schema::SchemaRef;
use pyo3::exceptions::PyStopIteration;
use pyo3::prelude::*;
use std::path::PathBuf;
use std::sync::Mutex;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};

/// Batches made ahead of the consumer: one being read by Python, one ready.
const DEPTH: usize = 2;

/// What a stream's thread sends: first whether the log opened, then its
/// batches, then `None` at the end (or an error, after which it stops).
type Message<T> = Work<Option<T>>;

/// A stream's end of the channel, `None` once it ended.
type Channel<T> = Mutex<Option<Receiver<Message<T>>>>;

/// Runs `open` then `next` until the end on a new thread; the receiver of
/// what it makes, after the opening's outcome (an error of the opening is
/// returned here, so a missing file raises at the call, not at the first
/// batch).
fn spawn<S, T>(
    name: &str,
    open: impl FnOnce() -> Work<S> + Send + 'static,
    mut next: impl FnMut(&mut S) -> Work<Option<T>> + Send + 'static,
) -> Work<Receiver<Message<T>>>
where
    T: Send + 'static,
{
    let (tx, rx): (SyncSender<Message<T>>, _) = sync_channel(DEPTH);
    std::thread::Builder::new()
        .name(name.to_owned())
        .spawn(move || {
            let mut stream = match open() {
                Ok(s) => s,
                Err(e) => {
                    let _ = tx.send(Err(e));
                    return;
                }
            };
            // The opening's outcome: the caller waits for it.
            if tx.send(Ok(None)).is_err() {
                return;
            }
            loop {
                let item = next(&mut stream);
                let last = !matches!(item, Ok(Some(_)));
                // A send fails when the consumer is gone: nothing more to do.
                if tx.send(item).is_err() || last {
                    return;
                }
            }
        })
        .map_err(|e| WorkError::Value(format!("cannot start a reading thread: {e}")))?;
    match rx.recv() {
        Ok(Ok(_)) => Ok(rx),
        Ok(Err(e)) => Err(e),
        Err(_) => Err(WorkError::Value(
            "the reading thread ended without a word".to_owned(),
        )),
    }
}

/// The next item from a stream's thread, waiting with the GIL released.
fn receive<T: Send>(py: Python<'_>, rx: &Channel<T>) -> Work<Option<T>> {
    py.detach(|| {
        let mut guard = rx
            .lock()
            .map_err(|_| WorkError::Value("the stream was poisoned by a panic".to_owned()))?;
        let Some(receiver) = guard.as_ref() else {
            return Ok(None);
        };
        let item = receiver.recv().unwrap_or_else(|_| {
            Err(WorkError::Value(
                "the reading thread ended before the log's end".to_owned(),
            ))
        });
        if !matches!(item, Ok(Some(_))) {
            // Ended (or failed): later calls give StopIteration.
            *guard = None;
        }
        item
    })
}

/// An iterator of a log's frames as `pyarrow.RecordBatch`es (see
/// `canodom.read_log_batches`, which wraps it in a
/// `pyarrow.RecordBatchReader`).
#[pyclass(module = "canodom._canodom")]
pub struct FrameBatches {
    schema: SchemaRef,
    rx: Channel<RecordBatch>,
}

impl FrameBatches {
    /// Opens the log at `path` on a thread of its own.
    pub(crate) fn open(path: PathBuf, batch_rows: usize) -> Work<Self> {
        let schema = FrameStream::schema();
        let each = schema.clone();
        let rx = spawn(
            "canodom-read-log",
            move || FrameStream::open(&path, batch_rows),
            move |s: &mut FrameStream| s.next_batch(&each),
        )?;
        Ok(Self {
            schema,
            rx: Mutex::new(Some(rx)),
        })
    }
}

#[pymethods]
impl FrameBatches {
    /// The schema of every batch: t_unix_s, channel, id, extended, fd, data.
    #[getter]
    fn schema(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        Ok(self.schema.to_pyarrow(py)?.unbind())
    }

    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__(&self, py: Python<'_>) -> PyResult<Py<PyAny>> {
        match receive(py, &self.rx)? {
            Some(batch) => Ok(batch.to_pyarrow(py)?.unbind()),
            None => Err(PyStopIteration::new_err(())),
        }
    }
}

/// An iterator of `(message name, pyarrow.RecordBatch)` pairs: a log
/// decoded with a DBC (see `canodom.decode_batches`).
#[pyclass(module = "canodom._canodom")]
pub struct DecodeBatches {
    rx: Channel<(String, RecordBatch)>,
}

impl DecodeBatches {
    /// Loads the DBC and opens the log at `path` on a thread of their own.
    pub(crate) fn open(path: PathBuf, dbc: PathBuf, strict: bool, batch_rows: usize) -> Work<Self> {
        let rx = spawn(
            "canodom-decode",
            move || DecodeStream::open(&path, &dbc, strict, batch_rows),
            DecodeStream::next_batch,
        )?;
        Ok(Self {
            rx: Mutex::new(Some(rx)),
        })
    }
}

#[pymethods]
impl DecodeBatches {
    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__(&self, py: Python<'_>) -> PyResult<(String, Py<PyAny>)> {
        match receive(py, &self.rx)? {
            Some((name, batch)) => Ok((name, batch.to_pyarrow(py)?.unbind())),
            None => Err(PyStopIteration::new_err(())),
        }
    }
}
