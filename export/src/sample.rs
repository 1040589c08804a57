//! What one filter step contributes to a recording: the step, the pose
//! sample published at it, the filter's covariance and the counts so far;
//! and the raw CAN frames received since the previous step (the step's own
//! last).

use canodom_can::frame::FrameId;
use canodom_can::time::Timestamp;
use canodom_fusion::Pose;
use canodom_fusion::ekf::WindowOutcome;
use canodom_pipeline::pipeline::{Pipeline, PoseOutput, Step};
use canodom_pipeline::stats::Stats;

/// One filter step as the recordings carry it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepSample {
    /// The step's time on the log's (bus) clock, µs since the Unix epoch.
    pub t_unix_us: i64,
    /// The fused pose (heading unwrapped).
    pub fused: Pose,
    /// Rear-wheel-only odometry (heading unwrapped).
    pub rear_only: Pose,
    /// The pose sample published at this step (speed, yaw rate, flags,
    /// standard deviations, parameter version).
    pub output: PoseOutput,
    /// The filter's covariance of (x, y, θ), row-major.
    pub covariance: [f64; 9],
    /// The rear (left, right) wheel distances of the step, metres: the
    /// twist's covariance follows from them (the filter's own input noise).
    pub rear_m: [f64; 2],
    /// The step's interval, seconds (0 when unknown: the first step, or no motion).
    pub dt_s: f64,
    /// What the filter's correction window did at this step.
    pub correction: WindowOutcome,
    /// The pipeline's counts after this step.
    pub counts: Counts,
    /// The guided calibration's phase at this step (`idle`, `recording`, …:
    /// `canodom_calib::session::Phase::as_str`); a replay has no session.
    pub calibration_phase: &'static str,
    /// The live GNSS source's state (`[gnss]`, #46); `None` without one
    /// (and in a replay).
    pub gnss: Option<GnssState>,
    /// The live drift watch's state (#46 item 3); `None` before its first
    /// refit, without fixes, and in a replay.
    pub drift: Option<DriftState>,
}

/// The most parameters a [`DriftState`] carries. The drift watch judges
/// eight (`canodom_calib::drift::Param::ALL`); the spare one keeps a new
/// parameter from being dropped before this is raised. A fixed array keeps
/// [`StepSample`] `Copy`: it is copied per pose into the live outputs'
/// queue, where a `Vec` would allocate at every step.
pub const DRIFT_PARAMS: usize = 9;

/// The drift watch's state as the diagnostics show it (#46 item 3): the
/// daemon's `DriftReport` in plain values (this crate does not know the
/// calibration's crates).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DriftState {
    /// Refits judged so far.
    pub refits: u64,
    /// Distance driven at the last judged refit, m.
    pub distance_m: f64,
    /// A learnt set is offered for COMMIT.
    pub candidate: bool,
    /// The parameters the last refit read or the watch flags, in the
    /// watch's order; the unused tail is `None`.
    pub params: [Option<DriftParam>; DRIFT_PARAMS],
}

/// One parameter of a [`DriftState`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DriftParam {
    /// Its name (`canodom_calib::drift::Param::name`: the state file's and
    /// the log's).
    pub name: &'static str,
    /// The watch flags it.
    pub flagged: bool,
    /// What the last refit learnt of it; `None` when that refit did not
    /// tell it (a flag stays until a refit clears it).
    pub reading: Option<DriftReading>,
}

/// A parameter as a refit learnt it, against the set in use.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DriftReading {
    /// The learnt value (the parameter's unit; relative ones relative to
    /// the set the drive was recorded with).
    pub learnt: f64,
    /// Its σ.
    pub sigma: f64,
    /// The set in use's value on the same scale (for `front_ratio`, which
    /// no set carries, the watch's first reading of it).
    pub in_use: f64,
}

impl DriftState {
    /// A state of `refits`, `distance_m` and `candidate` with `params`
    /// (those past [`DRIFT_PARAMS`] are left out).
    pub fn new(
        refits: u64,
        distance_m: f64,
        candidate: bool,
        params: impl IntoIterator<Item = DriftParam>,
    ) -> Self {
        let mut slots = [None; DRIFT_PARAMS];
        for (slot, p) in slots.iter_mut().zip(params) {
            *slot = Some(p);
        }
        Self {
            refits,
            distance_m,
            candidate,
            params: slots,
        }
    }

    /// The parameters carried.
    pub fn params(&self) -> impl Iterator<Item = &DriftParam> {
        self.params.iter().flatten()
    }

    /// The flagged parameters.
    pub fn flagged(&self) -> impl Iterator<Item = &DriftParam> {
        self.params().filter(|p| p.flagged)
    }

    /// Any parameter flagged (CALIB_STATUS's DRIFT).
    pub fn any_flagged(&self) -> bool {
        self.flagged().next().is_some()
    }
}

/// A live GNSS source's state as the diagnostics show it (#46): the
/// daemon's summary of its source, in plain values (this crate does not
/// know the source's crate).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GnssState {
    /// Connected (gpsd), or fixes arriving (a ROS 2 topic).
    pub connected: bool,
    /// Accepted fixes per second over the source's last few seconds.
    pub fixes_per_s: f64,
    /// The last report's 95 % horizontal error estimate, metres.
    pub last_error_m: Option<f64>,
    /// Fixes accepted so far.
    pub accepted: u64,
    /// Reports refused so far: no fix, no position, error estimate beyond the limit.
    pub refused: [u64; 3],
    /// Fixes handed to the calibration.
    pub forwarded: u64,
    /// Fixes dropped (a full queue, or before the first CAN frame).
    pub dropped: u64,
    /// Reconnect attempts (gpsd).
    pub reconnects: u64,
    /// The last fix's bus receipt time minus its GNSS time, seconds: the
    /// receiver's and gpsd's latency when the bus clock is the realtime
    /// clock (SocketCAN), for the latency estimate #46 asks for.
    pub last_latency_s: Option<f64>,
}

/// The pipeline's counts carried by the quality channel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counts {
    /// Frames offered.
    pub frames: u64,
    /// Frames used.
    pub used: u64,
    /// Filter steps.
    pub steps: u64,
    /// Steps without a valid front window.
    pub steps_without_front: u64,
    /// Gate rejections that kept the rear increment.
    pub gate_kept_rear: u64,
    /// Gate rejections that took the front increment.
    pub gate_used_front: u64,
}

impl From<&Stats> for Counts {
    fn from(s: &Stats) -> Self {
        Self {
            frames: s.frames,
            used: s.used,
            steps: s.steps,
            steps_without_front: s.steps_without_front,
            gate_kept_rear: s.gate.kept_rear,
            gate_used_front: s.gate.used_front,
        }
    }
}

impl StepSample {
    /// The sample of `step`, which `pipeline` has just taken, with `output`
    /// the pose sample taken right after it.
    pub fn of(pipeline: &Pipeline, step: &Step, output: PoseOutput) -> Self {
        let t0_us = pipeline
            .first_frame_time()
            .map_or(0, |t| t.as_micros() as i64);
        let p = pipeline.state().covariance();
        let params = pipeline.params();
        let metres = |rev: f64, w| rev * std::f64::consts::PI * params.wheel_diameter_m(w);
        let rear_m = [
            metres(step.rear_rev.0, canodom_fusion::Wheel::RearLeft),
            metres(step.rear_rev.1, canodom_fusion::Wheel::RearRight),
        ];
        // The pipeline's speed is the step's mean rear distance over its
        // interval: the interval, back from them (a pose published between
        // steps must not take its own interval for the step's).
        let mean_m = 0.5 * (rear_m[0] + rear_m[1]);
        let dt_s = if output.speed_mps.abs() > 0.0 && mean_m.abs() > 0.0 {
            (mean_m / output.speed_mps).abs()
        } else {
            0.0
        };
        Self {
            t_unix_us: t0_us + step.t_us,
            fused: step.fused,
            rear_only: step.odometry,
            output,
            covariance: std::array::from_fn(|k| p[(k / 3, k % 3)]),
            rear_m,
            dt_s,
            correction: step.correction,
            counts: Counts::from(pipeline.stats()),
            calibration_phase: "idle",
            gnss: None,
            drift: None,
        }
    }
}

/// A raw CAN frame as the recordings carry it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameRef<'a> {
    /// Receive time.
    pub timestamp: Timestamp,
    /// The identifier.
    pub id: FrameId,
    /// The payload.
    pub data: &'a [u8],
}

/// Frames in order, indexed: a batch of a replay, or the frames a live
/// daemon received since its last pose.
pub trait FrameSource {
    /// How many frames there are.
    fn frame_count(&self) -> usize;
    /// The frame at `index` (`None` past the end).
    fn frame(&self, index: usize) -> Option<FrameRef<'_>>;
}

/// A frame kept past the batch it came in (up to 64 payload bytes: CAN FD).
#[derive(Clone, Copy, Debug)]
pub(crate) struct OwnedFrame {
    timestamp: Timestamp,
    id: FrameId,
    len: u8,
    data: [u8; 64],
}

impl OwnedFrame {
    /// A copy of `f` (a payload over 64 bytes is cut: CAN has none).
    pub(crate) fn of(f: FrameRef<'_>) -> Self {
        let len = f.data.len().min(64);
        let mut data = [0; 64];
        data[..len].copy_from_slice(&f.data[..len]);
        Self {
            timestamp: f.timestamp,
            id: f.id,
            len: len as u8,
            data,
        }
    }

    /// The frame as a [`FrameRef`].
    pub(crate) fn as_ref(&self) -> FrameRef<'_> {
        FrameRef {
            timestamp: self.timestamp,
            id: self.id,
            data: &self.data[..usize::from(self.len)],
        }
    }
}

/// Frames held in memory: what a live daemon gathers between poses.
#[derive(Clone, Debug, Default)]
pub struct FrameBuffer {
    frames: Vec<OwnedFrame>,
}

impl FrameBuffer {
    /// Keeps a copy of `frame`.
    pub fn push(&mut self, frame: FrameRef<'_>) {
        self.frames.push(OwnedFrame::of(frame));
    }

    /// Forgets every frame (the allocation stays).
    pub fn clear(&mut self) {
        self.frames.clear();
    }
}

impl FrameSource for FrameBuffer {
    fn frame_count(&self) -> usize {
        self.frames.len()
    }

    fn frame(&self, index: usize) -> Option<FrameRef<'_>> {
        self.frames.get(index).map(OwnedFrame::as_ref)
    }
}
