//! A recording of a running daemon: MCAP files rotated by size or by time,
//! each finished (summary, footer) when it is rotated or the recorder is
//! closed, and each flushed chunk by chunk at least every
//! [`RecorderOptions::flush_every_s`] so that a file whose daemon was killed
//! still holds everything up to its last flush.

use crate::mcap_file::{McapOptions, StepWriter};
use crate::sample::{FrameSource, StepSample};
use crate::{Error, Result};
use canodom_fusion::VehicleParams;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// How a recording is written.
#[derive(Clone, Debug, PartialEq)]
pub struct RecorderOptions {
    /// The file; with rotation, `<stem>-0001.mcap`, `<stem>-0002.mcap`, … beside it.
    pub path: PathBuf,
    /// Start a new file once this many bytes are written.
    pub max_bytes: Option<u64>,
    /// Start a new file once a file spans this many seconds (bus time).
    pub max_seconds: Option<f64>,
    /// Write the current chunk out at least this often (bus time): what a kill can lose.
    pub flush_every_s: f64,
    /// The files' chunks.
    pub mcap: McapOptions,
}

impl RecorderOptions {
    /// Options for `path` without rotation, flushing every second.
    pub fn new(path: PathBuf) -> Self {
        Self {
            path,
            max_bytes: None,
            max_seconds: None,
            flush_every_s: 1.0,
            mcap: McapOptions::default(),
        }
    }

    fn rotates(&self) -> bool {
        self.max_bytes.is_some() || self.max_seconds.is_some()
    }

    /// The `n`th file's path (from 1).
    pub fn file(&self, n: u32) -> PathBuf {
        if !self.rotates() {
            return self.path.clone();
        }
        let stem = self
            .path
            .file_stem()
            .map_or_else(|| "canodom".into(), |s| s.to_string_lossy().into_owned());
        let ext = self
            .path
            .extension()
            .map_or_else(|| "mcap".into(), |s| s.to_string_lossy().into_owned());
        self.path.with_file_name(format!("{stem}-{n:04}.{ext}"))
    }
}

/// The open file and when it began.
struct Current {
    writer: StepWriter<BufWriter<File>>,
    path: PathBuf,
    first_us: i64,
    flushed_us: i64,
}

/// Writes steps into rotated MCAP files.
pub struct Recorder {
    options: RecorderOptions,
    k_rear_m: f64,
    current: Option<Current>,
    /// Files finished so far.
    done: Vec<PathBuf>,
    next: u32,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("options", &self.options)
            .field("done", &self.done)
            .finish_non_exhaustive()
    }
}

impl Recorder {
    /// A recorder that opens its first file at the first step; `k_rear_m`
    /// is the filter's rear noise (the twist covariance's).
    pub fn new(options: RecorderOptions, k_rear_m: f64) -> Self {
        Self {
            options,
            k_rear_m,
            current: None,
            done: Vec::new(),
            next: 1,
        }
    }

    fn open(&mut self, t_us: i64) -> Result<&mut Current> {
        let path = self.options.file(self.next);
        self.next += 1;
        let file = File::create(&path).map_err(|source| Error::Io {
            path: path.clone(),
            source,
        })?;
        let writer = StepWriter::new(
            BufWriter::with_capacity(1 << 16, file),
            self.options.mcap,
            self.k_rear_m,
        )?;
        Ok(self.current.insert(Current {
            writer,
            path,
            first_us: t_us,
            flushed_us: t_us,
        }))
    }

    /// Writes one step with its raw frames (all of `frames`); rotates and
    /// flushes as the options say.
    ///
    /// # Errors
    /// Creating or writing a file.
    pub fn write(
        &mut self,
        sample: &StepSample,
        params: &VehicleParams,
        frames: &impl FrameSource,
    ) -> Result<()> {
        let t = sample.t_unix_us;
        let rotate = self.current.as_ref().is_some_and(|c| {
            let span_s = (t - c.first_us) as f64 / 1e6;
            self.options.max_seconds.is_some_and(|max| span_s >= max)
                || self
                    .options
                    .max_bytes
                    .is_some_and(|max| c.writer.bytes_written() >= max)
        });
        if rotate {
            self.finish_current()?;
        }
        let flush_every_us = (self.options.flush_every_s * 1e6) as i64;
        let current = match self.current.take() {
            Some(c) => self.current.insert(c),
            None => self.open(t)?,
        };
        current
            .writer
            .write_step(sample, params, (frames, 0, frames.frame_count()))?;
        if t - current.flushed_us >= flush_every_us {
            current.writer.flush()?;
            current.flushed_us = t;
        }
        Ok(())
    }

    fn finish_current(&mut self) -> Result<()> {
        if let Some(c) = self.current.take() {
            c.writer.finish()?;
            self.done.push(c.path);
        }
        Ok(())
    }

    /// Finishes the open file; returns every file written.
    ///
    /// # Errors
    /// Finishing the file.
    pub fn close(mut self) -> Result<Vec<PathBuf>> {
        self.finish_current()?;
        Ok(std::mem::take(&mut self.done))
    }

    /// The file being written, if any.
    pub fn current_file(&self) -> Option<&Path> {
        self.current.as_ref().map(|c| c.path.as_path())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mcap_file::tests::sample;
    use crate::sample::FrameBuffer;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("canodom-rec-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn time_rotation_finishes_every_file_and_loses_no_step() {
        let d = dir("time");
        let mut options = RecorderOptions::new(d.join("drive.mcap"));
        // Steps are 10 ms apart: 2 s files hold 200 steps each.
        options.max_seconds = Some(2.0);
        let params = canodom_fusion::VehicleParams::nominal(0.25, 0.30, 0.09, 1000).unwrap();
        let mut rec = Recorder::new(options, 1e-5);
        for k in 0..1000 {
            rec.write(&sample(k), &params, &FrameBuffer::default())
                .unwrap();
        }
        let files = rec.close().unwrap();
        assert_eq!(files.len(), 5);
        assert_eq!(files[0], d.join("drive-0001.mcap"));
        let mut total = 0;
        for f in &files {
            let bytes = std::fs::read(f).unwrap();
            let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
            let n = summary.stats.unwrap().message_count;
            assert_eq!(n, 200 * 9, "{}", f.display());
            total += n;
        }
        assert_eq!(total, 1000 * 9);
    }

    #[test]
    fn size_rotation_keeps_files_near_the_limit() {
        let d = dir("size");
        let mut options = RecorderOptions::new(d.join("drive.mcap"));
        options.max_bytes = Some(64 << 10);
        options.flush_every_s = 0.1;
        let params = canodom_fusion::VehicleParams::nominal(0.25, 0.30, 0.09, 1000).unwrap();
        let mut rec = Recorder::new(options, 1e-5);
        for k in 0..3000 {
            rec.write(&sample(k), &params, &FrameBuffer::default())
                .unwrap();
        }
        let files = rec.close().unwrap();
        assert!(files.len() > 2, "{} files", files.len());
        let mut total = 0;
        for f in &files {
            let bytes = std::fs::read(f).unwrap();
            // Rotated at the first flush past the limit: one flush's chunk over at most.
            assert!(
                bytes.len() < 96 << 10,
                "{}: {} bytes",
                f.display(),
                bytes.len()
            );
            total += mcap::Summary::read(&bytes)
                .unwrap()
                .unwrap()
                .stats
                .unwrap()
                .message_count;
        }
        assert_eq!(total, 3000 * 9);
    }
}
