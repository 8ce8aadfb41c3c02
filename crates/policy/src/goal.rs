//! The long-horizon goal choice: which frontier to explore when the path executor asks for a
//! new path (the `planner` operator's decision).
//!
//! Policy `fbe` (frontier-based exploration, SPEC §6 baseline): [`FbePlanner`], the library's
//! [`activemap_planning::fbe::FbePlanner`] on the frontier operator's regions (ranking:
//! `utility` = size / (path + turn cost + offset) by default, or `nearest` / `largest`;
//! strikes: a reached goal one, or two when its region did not shrink, a failed goal (no path,
//! stuck) two; amnesty once per growth of the map). The path distances come with the regions
//! (`FrontierRegion::path_distance_m`), so a choice costs no search.
//!
//! Policy `llm` (SPEC §7): [`crate::llm::LlmPolicy`], the multimodal-LLM planner choosing among
//! the regions FBE's strikes leave eligible.
//!
//! With no reachable frontier left, `when_no_frontier` ([`NoFrontier`]) says what happens:
//! `end` (the default, FBE) ends the episode; `refine` sends a goal with target −1
//! ([`REFINE_TARGET`]), the path choice's refine mode (SPEC §6: refine what is mapped), and
//! asks again at the next replan. The model's −1 sends the same refine goal.

use activemap_geometry::PlanarPose;
use activemap_llm::LlmConfig;
use activemap_llm::provider::RecordedReply;
use activemap_planning::OccupancyGrid;
use activemap_planning::fbe::{FbeConfig, FbePolicy, FbeState};
use activemap_schemas::{Frontiers, Goal, LlmExchange, ReplanReason, ReplanRequest};
use nalgebra::Point2;

use crate::llm::LlmPolicy;
use crate::wire::{reason_from_wire, regions_from_wire};
use crate::{Log, MapSnapshot, log_to_stderr};

/// The goal-choice policy, checked once when the config is read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Policy {
    /// Frontier-based exploration.
    #[default]
    Fbe,
    /// The multimodal-LLM planner (SPEC §7), settings in `llm:`.
    Llm,
}

/// Which frontier FBE picks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Choice {
    /// Shortest path.
    Nearest,
    /// Most cells.
    Largest,
    /// Size over path-plus-turn cost (the default: doorways before wall pockets).
    Utility,
}

/// What the goal choice does when no reachable frontier is left (even after forgiving
/// strikes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NoFrontier {
    /// End the episode (FBE: nothing left to explore).
    #[default]
    End,
    /// Send a refine goal (target −1) and keep going: the path choice refines what is mapped.
    Refine,
}

/// The goal target that asks the path choice to refine the map instead of exploring a
/// frontier (SPEC §7: the LLM's −1).
pub const REFINE_TARGET: i32 = -1;

/// The goal choice's settings (the `planner` operator's config).
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GoalConfig {
    /// `fbe` (default) or `llm`.
    #[serde(default)]
    pub policy: Policy,
    /// FBE choice (policy `fbe`).
    #[serde(default = "default_choice")]
    pub frontier: Choice,
    /// Struck goals ban approach cells within this many cells.
    #[serde(default = "default_exclusion")]
    pub exclusion_radius_cells: f64,
    /// No reachable frontier left: `end` the episode (default) or send a `refine` goal.
    #[serde(default)]
    pub when_no_frontier: NoFrontier,
    /// Policy `llm`: the planner's settings ([`activemap_llm::LlmConfig`]: prompt, provider,
    /// BEV, when to ask, budget). Absent: the offline default.
    #[serde(default)]
    pub llm: Option<serde_json::Value>,
    /// Policy `llm`: map lag L in frames; the BEV of the decision of frame k shows the map
    /// snapshot of frame k − 1 − L. Must equal the mapper's `map_lag`.
    #[serde(default)]
    pub map_lag: u64,
}

impl GoalConfig {
    /// The LLM settings (`llm:`, defaults when absent), checked.
    pub fn llm_config(&self) -> Result<LlmConfig, String> {
        match &self.llm {
            None => Ok(LlmConfig::default()),
            Some(v) => LlmConfig::from_value(v).map_err(|e| format!("llm: {e}")),
        }
    }

    /// True when the LLM policy needs map snapshots (a provider with the image prompt).
    pub fn needs_map(&self, llm: &LlmConfig) -> bool {
        self.policy == Policy::Llm && llm.provider.is_some() && llm.prompt.sends_image()
    }

    /// The library's FBE settings of this config.
    pub fn fbe(&self) -> FbeConfig {
        FbeConfig {
            policy: match self.frontier {
                Choice::Nearest => FbePolicy::Nearest,
                Choice::Largest => FbePolicy::Largest,
                Choice::Utility => FbePolicy::Utility,
            },
            exclusion_radius_cells: self.exclusion_radius_cells,
            ..FbeConfig::default()
        }
    }

    /// Checks what the policy uses; the message names the field.
    pub fn validate(&self) -> Result<(), String> {
        self.fbe().validate().map_err(|e| e.to_string())?;
        self.llm_config()?;
        if self.policy == Policy::Fbe && self.llm.is_some() {
            return Err("`llm:` settings need `policy: llm`".into());
        }
        Ok(())
    }
}

fn default_choice() -> Choice {
    Choice::Utility
}
fn default_exclusion() -> f64 {
    FbeConfig::default().exclusion_radius_cells
}

/// The FBE decision on the frontier operator's regions: the library's
/// [`activemap_planning::fbe::FbePlanner`], with one log line per decision.
pub struct FbePlanner {
    pub(crate) planner: activemap_planning::fbe::FbePlanner,
    pub(crate) log: Log,
}

impl FbePlanner {
    /// A planner with no strikes (settings [`GoalConfig::fbe`]), logging to standard error.
    pub fn new(config: &GoalConfig) -> anyhow::Result<Self> {
        Self::from_fbe(config.fbe())
    }

    /// A planner with no strikes with the library's settings `fbe`.
    pub fn from_fbe(fbe: FbeConfig) -> anyhow::Result<Self> {
        Ok(Self {
            planner: activemap_planning::fbe::FbePlanner::new(fbe)?,
            log: log_to_stderr,
        })
    }

    /// The same planner writing its decisions to `log`.
    pub fn with_log(self, log: Log) -> Self {
        Self { log, ..self }
    }

    /// The shared decision state (strikes, amnesties).
    pub fn state(&self) -> &FbeState {
        self.planner.state()
    }

    /// Judges the last goal by the follower's `reason` against the current `frontiers`, then
    /// chooses among the reachable ones for the robot at `robot`: the region id and its
    /// centroid; `None` when no reachable region is left even after forgiving the strikes
    /// (once per growth of the map).
    pub fn choose(
        &mut self,
        reason: ReplanReason,
        grid: &OccupancyGrid,
        frontiers: &Frontiers,
        robot: &PlanarPose,
    ) -> anyhow::Result<Option<(u32, Point2<f64>)>> {
        let regions = regions_from_wire(frontiers);
        let choice = self
            .planner
            .choose(reason_from_wire(reason), grid, &regions, robot);
        // One line per decision in the node's log: what was on offer and what was banned.
        let offered: Vec<String> = frontiers
            .regions
            .iter()
            .take(8)
            .map(|r| format!("{}:{}c@{:.1}m", r.id, r.size_cells, r.path_distance_m))
            .collect();
        (self.log)(&format!(
            "planner: frame {} after {reason:?}: {} of {} regions [{}], {} strikes",
            frontiers.frame_id,
            choice.map_or("none".to_string(), |c| format!(
                "region {}",
                frontiers.regions[c.region].id
            )),
            frontiers.regions.len(),
            offered.join(" "),
            self.state().strikes().len()
        ));
        let Some(choice) = choice else {
            return Ok(None);
        };
        Ok(Some((frontiers.regions[choice.region].id, choice.focus)))
    }
}

/// The goal for one replan request: the FBE choice, or with no reachable frontier left a
/// refine goal (target [`REFINE_TARGET`], focused on the robot's position) when
/// `when_no_frontier` is `refine`; `None` ends the episode.
pub fn goal_for_request(
    fbe: &mut FbePlanner,
    when_no_frontier: NoFrontier,
    request: &ReplanRequest,
    grid: &OccupancyGrid,
    frontiers: &Frontiers,
    pose: &PlanarPose,
) -> anyhow::Result<Option<Goal>> {
    let k = request.frame_id;
    let choice = fbe.choose(request.reason, grid, frontiers, pose)?;
    Ok(match choice {
        Some((target, focus)) => Some(Goal {
            frame_id: k,
            target: target as i32,
            focus: [focus.x, focus.y],
        }),
        None => no_frontier_goal(when_no_frontier, k, pose, fbe.log),
    })
}

/// The goal when no reachable frontier is left at frame `k`: `None` (the episode is over), or
/// a refine goal at the robot's position; said on `log`.
pub(crate) fn no_frontier_goal(
    when_no_frontier: NoFrontier,
    k: u64,
    pose: &PlanarPose,
    log: Log,
) -> Option<Goal> {
    match when_no_frontier {
        NoFrontier::End => {
            log(&format!(
                "planner: no reachable frontier left at frame {k}: episode over"
            ));
            None
        }
        NoFrontier::Refine => {
            log(&format!(
                "planner: no reachable frontier left at frame {k}: refine goal"
            ));
            Some(Goal {
                frame_id: k,
                target: REFINE_TARGET,
                focus: [pose.x, pose.y],
            })
        }
    }
}

/// What one goal choice sees: the request of frame k and that frame's grid, frontier regions
/// and pose estimate.
pub struct GoalInput<'a> {
    /// The follower's request (its frame and why it asks).
    pub request: ReplanRequest,
    /// The occupancy grid of the request's frame.
    pub grid: &'a OccupancyGrid,
    /// The frontier regions of that frame (ids 0..N−1, largest first).
    pub frontiers: &'a Frontiers,
    /// The robot's estimated planar pose at that frame.
    pub pose: PlanarPose,
    /// The camera's estimated height at that frame (the BEV's ceiling cut).
    pub camera_z: f64,
}

/// What one goal choice decided.
#[derive(Debug, Clone, PartialEq)]
pub struct GoalDecision {
    /// The goal; `None` ends the episode.
    pub goal: Option<Goal>,
    /// The LLM exchange to record, when a query was made.
    pub exchange: Option<LlmExchange>,
}

/// Reads the replies a `recorded` LLM provider serves: (recording path, node whose exchanges
/// to serve) → replies in order. The operators read a run's recording; a caller without
/// recordings passes one that fails.
pub type RecordedLoader<'a> =
    &'a dyn Fn(&std::path::Path, &str) -> anyhow::Result<Vec<RecordedReply>>;

/// A goal-choice policy: FBE, or the LLM on FBE's eligible frontiers.
pub struct GoalPolicy {
    kind: GoalKind,
    when_no_frontier: NoFrontier,
}

enum GoalKind {
    Fbe(FbePlanner),
    Llm(Box<LlmPolicy>),
}

impl GoalPolicy {
    /// The policy of `config` for node `node` (`max_steps`: the run's `--max-steps`, the LLM's
    /// step budget; `recorded` reads a recording's replies for a `recorded` provider).
    pub fn new(
        config: &GoalConfig,
        node: &str,
        max_steps: Option<u64>,
        recorded: RecordedLoader<'_>,
    ) -> anyhow::Result<Self> {
        let kind = match config.policy {
            Policy::Fbe => GoalKind::Fbe(FbePlanner::new(config)?),
            Policy::Llm => {
                GoalKind::Llm(Box::new(LlmPolicy::new(config, node, max_steps, recorded)?))
            }
        };
        Ok(Self {
            kind,
            when_no_frontier: config.when_no_frontier,
        })
    }

    /// FBE with the library's settings `fbe` (what the explorer runs by default).
    pub fn fbe(fbe: FbeConfig, when_no_frontier: NoFrontier) -> anyhow::Result<Self> {
        Ok(Self {
            kind: GoalKind::Fbe(FbePlanner::from_fbe(fbe)?),
            when_no_frontier,
        })
    }

    /// The same policy writing its decisions to `log`.
    pub fn with_log(self, log: Log) -> Self {
        let kind = match self.kind {
            GoalKind::Fbe(f) => GoalKind::Fbe(f.with_log(log)),
            GoalKind::Llm(l) => GoalKind::Llm(Box::new(l.with_log(log))),
        };
        Self { kind, ..self }
    }

    /// What the LLM policy says of itself at start (`None` for FBE).
    pub fn describe(&self) -> Option<String> {
        match &self.kind {
            GoalKind::Fbe(_) => None,
            GoalKind::Llm(l) => Some(l.describe()),
        }
    }

    /// The FBE decision state (strikes, amnesties; the LLM's eligibility for `llm`).
    pub fn fbe_state(&self) -> &FbeState {
        match &self.kind {
            GoalKind::Fbe(f) => f.state(),
            GoalKind::Llm(l) => l.fbe_state(),
        }
    }

    /// The LLM policy, for `llm`.
    pub fn llm(&self) -> Option<&LlmPolicy> {
        match &self.kind {
            GoalKind::Fbe(_) => None,
            GoalKind::Llm(l) => Some(l),
        }
    }

    /// Stores a map snapshot (the LLM's BEV needs it; FBE ignores it).
    pub fn add_map(&mut self, map: &MapSnapshot<'_>) -> anyhow::Result<()> {
        match &mut self.kind {
            GoalKind::Fbe(_) => Ok(()),
            GoalKind::Llm(l) => l.add_map(map),
        }
    }

    /// Notes the estimated pose of the next frame (frames come in order; the LLM's BEV draws
    /// the visited path).
    pub fn add_pose(&mut self, pose: &PlanarPose) {
        if let GoalKind::Llm(l) = &mut self.kind {
            l.add_position(pose);
        }
    }

    /// True once what the decision of frame `k` needs (besides its grid, regions and pose)
    /// has arrived.
    pub fn ready(&self, k: u64) -> bool {
        match &self.kind {
            GoalKind::Fbe(_) => true,
            GoalKind::Llm(l) => l.ready(k),
        }
    }

    /// Ends the episode: the LLM policy's `background` question still being asked, if any,
    /// waited for and returned for the recording (never taken up).
    pub fn finish(&mut self) -> anyhow::Result<Option<LlmExchange>> {
        match &mut self.kind {
            GoalKind::Fbe(_) => Ok(None),
            GoalKind::Llm(l) => l.finish(),
        }
    }

    /// The goal for one request.
    pub fn goal(&mut self, input: &GoalInput<'_>) -> anyhow::Result<GoalDecision> {
        Ok(match &mut self.kind {
            GoalKind::Fbe(fbe) => GoalDecision {
                goal: goal_for_request(
                    fbe,
                    self.when_no_frontier,
                    &input.request,
                    input.grid,
                    input.frontiers,
                    &input.pose,
                )?,
                exchange: None,
            },
            GoalKind::Llm(llm) => {
                let (goal, exchange) = llm.goal(
                    &input.request,
                    input.grid,
                    input.frontiers,
                    &input.pose,
                    input.camera_z,
                )?;
                GoalDecision { goal, exchange }
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_planning::GridGeometry;
    use activemap_planning::grid::CellState;
    use activemap_schemas::FrontierRegion;

    type Config = GoalConfig;
    type PlanGrid = OccupancyGrid;

    /// The config as the operator reads it, checked.
    fn check_config(value: &serde_json::Value) -> Result<(), String> {
        let config: Config = serde_json::from_value(value.clone()).map_err(|e| e.to_string())?;
        config.validate()
    }

    fn wire(id: u32, size: u32, cell: [i32; 2], distance: f64) -> FrontierRegion {
        FrontierRegion {
            id,
            size_cells: size,
            centroid: [cell[0] as f64 * 0.05, cell[1] as f64 * 0.05 + 0.3],
            closest_reachable_cell: cell,
            path_distance_m: distance,
            anchor: [cell[0] as f64 * 0.05, cell[1] as f64 * 0.05 + 0.1],
        }
    }

    fn frontiers(regions: Vec<FrontierRegion>) -> Frontiers {
        Frontiers {
            frame_id: 0,
            stamp: 0.0,
            regions,
        }
    }

    /// The wrapper keeps the library's rules: with `nearest`, a pocket reached and still there
    /// at full size is banned at once (the doorway comes next), a failed goal is banned too,
    /// and when everything is banned the strikes are forgiven once per growth of the map.
    #[test]
    fn planner_bans_an_unshrunk_pocket_after_one_visit() {
        let geometry = GridGeometry::new(0.0, 0.0, 0.05, 100, 100).unwrap();
        let mut grid = PlanGrid::filled(geometry, CellState::Unknown);
        grid.data[0] = CellState::Free;
        let config = Config {
            policy: Policy::Fbe,
            frontier: Choice::Nearest,
            exclusion_radius_cells: 3.0,
            when_no_frontier: NoFrontier::End,
            llm: None,
            map_lag: 0,
        };
        let mut planner = FbePlanner::new(&config).unwrap();
        let robot = PlanarPose::new(0.5, 0.5, 0.0);
        let f = frontiers(vec![wire(7, 40, [60, 10], 3.0), wire(3, 12, [20, 10], 1.0)]);
        let first = planner
            .choose(ReplanReason::Startup, &grid, &f, &robot)
            .unwrap();
        assert_eq!(first.unwrap().0, 3, "nearest first");
        let second = planner
            .choose(ReplanReason::PathDone, &grid, &f, &robot)
            .unwrap();
        assert_eq!(
            second.unwrap().0,
            7,
            "the unshrunk pocket is banned after one visit"
        );
        assert_eq!(planner.state().unobservable_goals, 1);
        let none = planner
            .choose(ReplanReason::Stuck, &grid, &f, &robot)
            .unwrap();
        assert_eq!(
            none.map(|c| c.0),
            Some(3),
            "amnesty: the map has free cells"
        );
        assert_eq!(planner.state().amnesties, 1);
        let again = planner
            .choose(ReplanReason::NoPath, &grid, &f, &robot)
            .unwrap();
        assert_eq!(again.map(|c| c.0), Some(7));
        let over = planner
            .choose(ReplanReason::NoPath, &grid, &f, &robot)
            .unwrap();
        assert!(
            over.is_none(),
            "no growth since the amnesty: the episode is over"
        );
    }

    /// With no reachable frontier left, `end` (the default) ends the episode and `refine`
    /// sends a refine goal (target −1 at the robot) instead, at every such request; a frontier
    /// that appears again is chosen as before (the FBE decision itself is unchanged).
    #[test]
    fn no_frontier_ends_the_episode_or_asks_to_refine() {
        let config: Config = serde_json::from_value(serde_json::json!({})).unwrap();
        assert_eq!(config.when_no_frontier, NoFrontier::End);
        let refine: Config = serde_json::from_value(
            serde_json::json!({ "frontier": "largest", "when_no_frontier": "refine" }),
        )
        .unwrap();
        assert_eq!(refine.when_no_frontier, NoFrontier::Refine);
        let e = check_config(&serde_json::json!({ "when_no_frontier": "spin" })).unwrap_err();
        assert!(e.contains("spin") && e.contains("refine"), "{e}");

        let geometry = GridGeometry::new(0.0, 0.0, 0.05, 100, 100).unwrap();
        let grid = PlanGrid::filled(geometry, CellState::Free);
        let robot = PlanarPose::new(0.5, 0.75, 1.0);
        let request = |frame_id, reason| ReplanRequest { frame_id, reason };
        let none = Frontiers {
            frame_id: 40,
            ..frontiers(vec![])
        };
        let mut fbe = FbePlanner::new(&config).unwrap();
        let end = goal_for_request(
            &mut fbe,
            config.when_no_frontier,
            &request(40, ReplanReason::Startup),
            &grid,
            &none,
            &robot,
        )
        .unwrap();
        assert_eq!(end, None);

        let mut fbe = FbePlanner::new(&refine).unwrap();
        for (k, reason) in [(40, ReplanReason::Startup), (90, ReplanReason::PathDone)] {
            let goal = goal_for_request(
                &mut fbe,
                refine.when_no_frontier,
                &request(k, reason),
                &grid,
                &none,
                &robot,
            )
            .unwrap();
            assert_eq!(
                goal,
                Some(Goal {
                    frame_id: k,
                    target: REFINE_TARGET,
                    focus: [0.5, 0.75]
                })
            );
        }
        assert!(
            fbe.state().strikes().is_empty(),
            "a refine goal strikes nothing"
        );
        let some = frontiers(vec![wire(4, 30, [60, 10], 3.0)]);
        let goal = goal_for_request(
            &mut fbe,
            refine.when_no_frontier,
            &request(120, ReplanReason::PathDone),
            &grid,
            &some,
            &robot,
        )
        .unwrap()
        .unwrap();
        assert_eq!((goal.frame_id, goal.target), (120, 4));
        assert_eq!(goal.focus, some.regions[0].centroid);
    }

    /// The default ranking is the utility: a large frontier beats a small nearer one.
    #[test]
    fn default_ranking_is_the_utility() {
        let config: Config = serde_json::from_value(serde_json::json!({})).unwrap();
        assert_eq!(config.frontier, Choice::Utility);
        let geometry = GridGeometry::new(0.0, 0.0, 0.05, 100, 100).unwrap();
        let grid = PlanGrid::filled(geometry, CellState::Free);
        let mut planner = FbePlanner::new(&config).unwrap();
        // Robot at (0.5, 0.5) facing +x; both approach cells lie ahead of it (y = 0.5).
        let f = frontiers(vec![wire(1, 6, [14, 10], 0.2), wire(2, 40, [70, 10], 3.0)]);
        let robot = PlanarPose::new(0.5, 0.5, 0.0);
        let c = planner
            .choose(ReplanReason::Startup, &grid, &f, &robot)
            .unwrap();
        assert_eq!(c.unwrap().0, 2);
        assert!(check_config(&serde_json::json!({ "frontier": "utility" })).is_ok());
        assert!(check_config(&serde_json::json!({ "frontier": "widest" })).is_err());
    }
}
