//! What the daemon's run loop hands back when it stops, and what the state
//! file is written from while it runs ([`crate::state_file`]).

use canodom_fusion::ekf::State;
use canodom_pipeline::param_set::{ParamIdentity, ParamsInUse};
use canodom_pipeline::pipeline::Step;
use canodom_pipeline::stats::Stats;

/// What `run` hands back when it stops.
#[derive(Clone, Debug)]
pub struct Summary {
    /// Pipeline statistics.
    pub stats: Stats,
    /// The filter's final state (bit-for-bit comparison with replay).
    pub state: State,
    /// The last filter step.
    pub last_step: Option<Step>,
    /// Pose samples published.
    pub poses_published: u64,
    /// Frames the transport reported lost.
    pub frames_lost: u64,
    /// Connections opened (1 + reconnects).
    pub connections: u64,
    /// Outages seen: the interface went down, disappeared or went bus-off
    /// (noticed by the receiver or by a pose send).
    pub outages: u64,
    /// The parameters in use.
    pub params: ParamsInUse,
    /// The parameter set the filter's learnt values are learnt on.
    pub param_identity: ParamIdentity,
    /// How the last write of the state file went (`None`: no state file).
    pub state_file: Option<Result<(), String>>,
    /// What the live GNSS source did (`None`: no `[gnss]`; a source that did
    /// not start has its error in `status.last_error`).
    pub gnss: Option<crate::gnss_task::GnssSummary>,
    /// What the drift watch knows (`None` before its first refit).
    pub drift: Option<canodom_live::drift_watch::DriftReport>,
}
