//! The exploration policies as a library, without transport: what the `planner` and `scorer`
//! operators decide, with explicit inputs and outputs, so that the operators are thin shells
//! around them and the in-process [`explorer`] runs the very same decisions.
//!
//! - [`goal`]: the long-horizon goal choice (SPEC §6–§7): FBE's ranking with strikes and
//!   amnesty, the LLM planner choosing among the frontiers FBE leaves eligible, or a refine
//!   goal when none is left ([`goal::GoalPolicy`]);
//! - [`llm`]: the LLM policy's bookkeeping (lagged map snapshots, the visited path, the wire
//!   record of each exchange and the recorded provider's replies);
//! - [`path`]: the short-horizon path choice (SPEC §5–§6): the shortest path to the goal's
//!   frontier, or the Fisher path ([`path::PathPolicy`]);
//! - [`fisher`]: the Fisher path choice's bookkeeping (keyframes, lagged snapshots, the
//!   fallbacks and the look-around);
//! - [`wire`]: the conversions between the planning library's types and the messages the
//!   policies take and give (frontier regions, replan reasons, paths);
//! - [`explorer`]: the whole loop in process (occupancy, the path executor, a goal policy and a
//!   path policy), taking the same actions as the operators.
//!
//! Inputs are the occupancy grid, the frontier regions, map snapshots ([`MapSnapshot`]), poses
//! and the operators' configs; outputs are the messages of `activemap-schemas` (`Goal`, `Path`,
//! `FisherReport`, `LlmExchange`), one definition of each.

pub mod explorer;
pub mod fisher;
pub mod goal;
pub mod llm;
pub mod path;
pub mod wire;

use activemap_splat::Gaussians;

pub use explorer::{Decision, Explorer, ExplorerConfig};
pub use goal::{GoalConfig, GoalDecision, GoalInput, GoalPolicy};
pub use path::{PathConfig, PathDecision, PathInput, PathPolicy};

/// A Gaussian map and the stable id of each Gaussian (what the Fisher scorer keys its model
/// Fisher by).
pub type MapWithIds = (Gaussians<f32>, Vec<u64>);

/// A map snapshot as a policy receives it: what its header says, and its Gaussians decoded
/// only when a policy keeps a new map (snapshots of one keyframe share one decoded map).
pub struct MapSnapshot<'a> {
    /// The last frame the snapshot includes.
    pub frame_id: u64,
    /// The newest keyframe the map holds (`None`: no keyframe yet).
    pub keyframe: Option<u64>,
    /// How many Gaussians it holds.
    pub count: u64,
    /// Decodes the Gaussians and their ids.
    pub decode: &'a dyn Fn() -> anyhow::Result<MapWithIds>,
}

/// Where a policy writes its one line per decision: the operators' standard error (the node's
/// log), or nowhere (benchmarks).
pub type Log = fn(&str);

/// The node's log: standard error.
pub fn log_to_stderr(line: &str) {
    eprintln!("{line}");
}

/// No log.
pub fn no_log(_: &str) {}
