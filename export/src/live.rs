//! A running daemon's poses to a recording and to a live Foxglove view,
//! without ever holding up the pipeline.
//!
//! The pipeline task owns a [`Tap`]: it copies each received frame into a
//! buffer ([`Tap::frame`]) and, at each published pose, hands the pose, the
//! step, the parameters and those frames to a bounded queue with
//! `try_send` ([`Tap::pose`]). A full queue drops the sample and counts it:
//! a slow disk or viewer loses samples, never delays a pose. The
//! [`LiveOutputs`] thread takes them off the queue and writes them to the
//! [`Recorder`] and to the Foxglove SDK's WebSocket server, whose own
//! per-client queues drop messages for a client that reads too slowly.

use crate::encode::{SliceSink, StepEncoder, Topic};
use crate::recorder::{Recorder, RecorderOptions};
use crate::sample::{FrameBuffer, FrameRef, FrameSource, StepSample};
use crate::{Error, Result};
use canodom_can::frame::CanFrame;
use canodom_can::time::Timestamp;
use canodom_fusion::VehicleParams;
use canodom_pipeline::pipeline::{Pipeline, PoseOutput};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc;

/// Frames a tap keeps between two poses at most (the oldest are dropped
/// beyond: a daemon publishing no pose must not grow without bound).
const MAX_FRAMES_PER_POSE: usize = 4096;

/// One pose with what it came from.
#[derive(Debug)]
struct Packet {
    sample: StepSample,
    params: VehicleParams,
    frames: FrameBuffer,
}

/// The pipeline's end of the live outputs (see the module doc).
#[derive(Clone, Debug)]
pub struct Tap {
    frames: FrameBuffer,
    queue: mpsc::SyncSender<Packet>,
    dropped: Arc<AtomicU64>,
}

impl Tap {
    /// Keeps a copy of a received frame for the next pose's raw frames.
    pub fn frame(&mut self, t: Timestamp, frame: &CanFrame) {
        if self.frames.frame_count() >= MAX_FRAMES_PER_POSE {
            self.frames.clear();
        }
        self.frames.push(FrameRef {
            timestamp: t,
            id: frame.id(),
            data: frame.data(),
        });
    }

    /// Queues the pose `output` just published by `pipeline` with the
    /// frames since the previous one, the guided calibration's
    /// `calibration_phase`, the live GNSS source's state and the drift
    /// watch's; never waits (a full queue drops it).
    pub fn pose(
        &mut self,
        pipeline: &Pipeline,
        output: PoseOutput,
        calibration_phase: &'static str,
        gnss: Option<crate::sample::GnssState>,
        drift: Option<crate::sample::DriftState>,
    ) {
        let Some(step) = pipeline.last_step() else {
            return;
        };
        let packet = Packet {
            sample: StepSample {
                calibration_phase,
                gnss,
                drift,
                ..StepSample::of(pipeline, &step, output)
            },
            params: *pipeline.params(),
            frames: std::mem::take(&mut self.frames),
        };
        if let Err(mpsc::TrySendError::Full(_)) = self.queue.try_send(packet) {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// Where every queued pose also goes, on the live thread: the ROS 2 node
/// (#43). It must not block (the node's `publish_pose` queues or drops).
pub type Forward = Arc<dyn Fn(&StepSample, &VehicleParams) + Send + Sync>;

/// What the live outputs do.
#[derive(Clone)]
pub struct LiveOptions {
    /// Record to these files.
    pub record: Option<RecorderOptions>,
    /// Serve the Foxglove WebSocket protocol at this address.
    pub foxglove: Option<SocketAddr>,
    /// The filter's rear noise (the twist covariance's).
    pub k_rear_m: f64,
    /// Poses queued at most between the pipeline and the outputs.
    pub queue: usize,
    /// Hands each pose on as well (ROS 2).
    pub forward: Option<Forward>,
}

impl std::fmt::Debug for LiveOptions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveOptions")
            .field("record", &self.record)
            .field("foxglove", &self.foxglove)
            .field("k_rear_m", &self.k_rear_m)
            .field("queue", &self.queue)
            .field("forward", &self.forward.is_some())
            .finish()
    }
}

/// What the live outputs did, when they stopped.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct LiveReport {
    /// Poses written (to the files and the view).
    pub poses: u64,
    /// Poses dropped because the queue was full.
    pub dropped: u64,
    /// The recording's files.
    pub files: Vec<PathBuf>,
}

/// The Foxglove WebSocket server and a raw channel per topic.
struct View {
    /// The channels' context: the server holds it weakly, so it lives here.
    _context: Arc<foxglove::Context>,
    server: foxglove::WebSocketServerHandle,
    channels: Vec<Arc<foxglove::RawChannel>>,
}

impl View {
    fn start(addr: SocketAddr) -> Result<Self> {
        let ctx = foxglove::Context::new();
        let mut channels = Vec::new();
        for topic in Topic::ALL {
            let schema = topic.schema();
            let channel = foxglove::ChannelBuilder::new(topic.name())
                .message_encoding(topic.message_encoding())
                .schema(foxglove::Schema::new(
                    schema.name,
                    schema.encoding,
                    schema.data,
                ))
                .context(&ctx)
                .build_raw()
                .map_err(|e| Error::Live(e.to_string()))?;
            channels.push(channel);
        }
        let server = foxglove::WebSocketServer::new()
            .name("canodom")
            .context(&ctx)
            .bind(addr.ip().to_string(), addr.port())
            .start_blocking()
            .map_err(|e| Error::Live(format!("{addr}: {e}")))?;
        Ok(Self {
            _context: ctx,
            server,
            channels,
        })
    }
}

/// The thread writing queued poses to the recording and the view.
#[derive(Debug)]
pub struct LiveOutputs {
    thread: std::thread::JoinHandle<Result<LiveReport>>,
    dropped: Arc<AtomicU64>,
    /// The view's port (the one bound when asked for port 0).
    port: Option<u16>,
}

impl LiveOutputs {
    /// Starts the view's server (if asked) and the writing thread; returns
    /// the pipeline's [`Tap`] with it. The outputs stop when every tap is dropped.
    ///
    /// # Errors
    /// The view's address cannot be bound.
    pub fn start(options: LiveOptions) -> Result<(Tap, Self)> {
        let (queue, inbox) = mpsc::sync_channel::<Packet>(options.queue.max(1));
        let dropped = Arc::new(AtomicU64::new(0));
        let (started, port) = mpsc::sync_channel(1);
        // The view starts on the thread: the SDK's blocking start runs its own
        // runtime, which it refuses to do inside an async context (the daemon's).
        let thread = std::thread::Builder::new()
            .name("canodom-live".into())
            .spawn(move || {
                let view = options.foxglove.map(View::start).transpose();
                let view = match view {
                    Ok(view) => {
                        let _ = started.send(Ok(view.as_ref().map(|v| v.server.port())));
                        view
                    }
                    Err(e) => {
                        let _ = started.send(Err(e));
                        return Ok(LiveReport::default());
                    }
                };
                serve(&options, view, &inbox)
            })
            .map_err(|e| Error::Live(e.to_string()))?;
        let port = port
            .recv()
            .map_err(|_| Error::Live("the live thread stopped at start".into()))??;
        let tap = Tap {
            frames: FrameBuffer::default(),
            queue,
            dropped: Arc::clone(&dropped),
        };
        Ok((
            tap,
            Self {
                thread,
                dropped,
                port,
            },
        ))
    }

    /// The port the view listens on.
    pub fn port(&self) -> Option<u16> {
        self.port
    }

    /// Poses dropped so far.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Waits for the thread (it ends once every tap is dropped), the last
    /// file finished.
    ///
    /// # Errors
    /// A file that could not be written.
    pub fn join(self) -> Result<LiveReport> {
        let mut report = self
            .thread
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic))?;
        report.dropped = self.dropped.load(Ordering::Relaxed);
        Ok(report)
    }
}

fn serve(
    options: &LiveOptions,
    view: Option<View>,
    inbox: &mpsc::Receiver<Packet>,
) -> Result<LiveReport> {
    let mut recorder = options
        .record
        .clone()
        .map(|o| Recorder::new(o, options.k_rear_m));
    let mut encoder = StepEncoder::new(options.k_rear_m);
    let mut report = LiveReport::default();
    let mut failed = None;
    let mut view_sink = view.as_ref().map(|view| {
        SliceSink::new(|topic: Topic, t_ns, data: &[u8]| {
            view.channels[topic as usize].log_with_meta(
                data,
                foxglove::PartialMetadata {
                    log_time: Some(t_ns),
                },
            );
        })
    });
    for packet in inbox {
        if let Some(forward) = &options.forward {
            forward(&packet.sample, &packet.params);
        }
        if let Some(rec) = recorder.as_mut()
            && let Err(e) = rec.write(&packet.sample, &packet.params, &packet.frames)
        {
            // Recording stops at the first failure; the view goes on.
            failed = Some(e);
            recorder = None;
        }
        if let Some(sink) = view_sink.as_mut() {
            let n = packet.frames.frame_count();
            encoder.encode(&packet.sample, &packet.params, (&packet.frames, 0, n), sink);
        }
        report.poses += 1;
    }
    drop(view_sink);
    if let Some(view) = view {
        drop(view.server.stop());
    }
    if let Some(rec) = recorder {
        report.files = rec.close()?;
    }
    match failed {
        Some(e) => Err(e),
        None => Ok(report),
    }
}
