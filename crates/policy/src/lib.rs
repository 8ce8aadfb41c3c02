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
//! The seams are two traits, [`GoalChoice`] and [`PathChoice`], which the built-in policies
//! implement and the explorer runs. Inputs are the occupancy grid, the frontier regions, map
//! snapshots ([`MapSnapshot`]), poses and the operators' configs; outputs are the messages of
//! `activemap-schemas` (`Goal`, `Path`, `FisherReport`, `LlmExchange`), one definition of each.

pub mod explorer;
pub mod fisher;
pub mod goal;
pub mod llm;
pub mod path;
pub mod wire;

use activemap_geometry::{Isometry3, PlanarPose};
use activemap_planning::fbe::FbeState;
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

/// A long-horizon goal choice: what the `planner` operator and the [`Explorer`] ask when the
/// path executor wants a new path. [`GoalPolicy`] is the built-in one (FBE, the LLM); a
/// policy of one's own implements this to run in the explorer.
pub trait GoalChoice {
    /// Stores a map snapshot (a policy that reads no map ignores it).
    fn add_map(&mut self, _map: &MapSnapshot<'_>) -> anyhow::Result<()> {
        Ok(())
    }

    /// Notes the estimated planar pose of the next frame (frames come in order).
    fn add_pose(&mut self, _pose: &PlanarPose) {}

    /// True once what the decision of frame `k` needs, besides its grid, regions and pose, has
    /// arrived (a lagged map snapshot, say).
    fn ready(&self, _k: u64) -> bool {
        true
    }

    /// The goal for one request; a `None` goal ends the episode.
    fn goal(&mut self, input: &GoalInput<'_>) -> anyhow::Result<GoalDecision>;

    /// FBE's strikes and amnesties, for a policy built on FBE (the explorer counts them).
    fn fbe_state(&self) -> Option<&FbeState> {
        None
    }
}

/// A short-horizon path choice: what the `scorer` operator and the [`Explorer`] ask for each
/// goal. [`PathPolicy`] is the built-in one (shortest, Fisher).
pub trait PathChoice {
    /// Stores a map snapshot (a policy that reads no map ignores it).
    fn add_map(&mut self, _map: &MapSnapshot<'_>) -> anyhow::Result<()> {
        Ok(())
    }

    /// Stores the camera's estimated pose `T_world_camera` of frame `k`.
    fn add_pose(&mut self, _k: u64, _pose: Isometry3<f64>) {}

    /// True once what the path of frame `k` needs, besides its grid, pose and regions, has
    /// arrived.
    fn ready(&self, _k: u64) -> bool {
        true
    }

    /// The path for one goal (empty when none was found).
    fn path(&mut self, input: &PathInput<'_>) -> anyhow::Result<PathDecision>;
}

impl GoalChoice for GoalPolicy {
    fn add_map(&mut self, map: &MapSnapshot<'_>) -> anyhow::Result<()> {
        GoalPolicy::add_map(self, map)
    }

    fn add_pose(&mut self, pose: &PlanarPose) {
        GoalPolicy::add_pose(self, pose)
    }

    fn ready(&self, k: u64) -> bool {
        GoalPolicy::ready(self, k)
    }

    fn goal(&mut self, input: &GoalInput<'_>) -> anyhow::Result<GoalDecision> {
        GoalPolicy::goal(self, input)
    }

    fn fbe_state(&self) -> Option<&FbeState> {
        Some(GoalPolicy::fbe_state(self))
    }
}

impl PathChoice for PathPolicy {
    fn add_map(&mut self, map: &MapSnapshot<'_>) -> anyhow::Result<()> {
        PathPolicy::add_map(self, map)
    }

    fn add_pose(&mut self, k: u64, pose: Isometry3<f64>) {
        PathPolicy::add_pose(self, k, pose)
    }

    fn ready(&self, k: u64) -> bool {
        PathPolicy::ready(self, k)
    }

    fn path(&mut self, input: &PathInput<'_>) -> anyhow::Result<PathDecision> {
        PathPolicy::path(self, input)
    }
}
