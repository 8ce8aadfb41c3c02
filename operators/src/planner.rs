//! `planner`: chooses the frontier to explore when the follower asks for a replan. Policy
//! `fbe` (frontier-based exploration, SPEC §6 baseline): a thin wrapper around
//! [`activemap_planning::fbe::FbePlanner`], the decision the in-process explorer makes too
//! (ranking: `utility` = size / (path + turn cost + offset) by default, or `nearest` / `largest`;
//! strikes: a reached goal one, or two when its region did not shrink, a failed goal (no path,
//! stuck) two; amnesty once per growth of the map). The path distances come with the regions
//! (`FrontierRegion::path_distance_m`), so a replan costs no search here. The LLM policy
//! (SPEC §7) is a later issue: `policy: llm` is a config error ([`Policy`]). With no reachable
//! frontier left, `when_no_frontier` ([`NoFrontier`]) says what happens: `end` (the default,
//! FBE) ends the episode (end of its `goal` stream); `refine` sends a goal with target −1, the
//! scorer's refine mode (SPEC §6: refine what is mapped), and asks again at the next replan, so
//! an episode with Fisher paths runs to its step budget (the simulator ends it at `max_steps`).

use activemap_geometry::PlanarPose;
use activemap_geometry::frames::planar_from_camera_pose;
use activemap_planning::OccupancyGrid as PlanGrid;
use activemap_planning::fbe::{FbeConfig, FbePolicy, FbeState};
use activemap_planning::frontier::{Approach, FrontierRegion as PlanRegion};
use activemap_planning::grid::Cell;
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, PortSpec,
};
use activemap_schemas::{
    Frontiers, Goal, MessageKind as K, OccupancyGridView, PoseEstimate, ReplanReason, ReplanRequest,
};
use nalgebra::Point2;

use crate::Registered;
use crate::convert::{pose_from_wire, read_grid};
use crate::follower::reason_from_wire;
use crate::join::FrameJoin;

/// The goal-choice policy. Only FBE is built; `llm` (SPEC §7) is refused when the config is
/// read, the one place it is checked (`activemap validate` and the node's start alike).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(try_from = "String")]
pub enum Policy {
    /// Frontier-based exploration.
    #[default]
    Fbe,
}

impl TryFrom<String> for Policy {
    type Error = String;

    fn try_from(name: String) -> Result<Self, String> {
        match name.as_str() {
            "fbe" => Ok(Self::Fbe),
            "llm" => Err(
                "policy `llm` is not built yet: only `fbe` (the LLM policy of SPEC §7 comes later)"
                    .into(),
            ),
            other => Err(format!(
                "unknown policy `{other}`: only `fbe` is built (`llm`, SPEC §7, comes later)"
            )),
        }
    }
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

/// What the planner does when no reachable frontier is left (even after forgiving strikes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NoFrontier {
    /// End the episode (FBE: nothing left to explore).
    #[default]
    End,
    /// Send a refine goal (target −1) and keep going: the scorer refines what is mapped.
    Refine,
}

/// The goal target that asks the scorer to refine the map instead of exploring a frontier
/// (SPEC §7: the LLM's −1).
pub const REFINE_TARGET: i32 = -1;

/// Config.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// `fbe` (the only policy built so far).
    #[serde(default)]
    pub policy: Policy,
    /// FBE choice.
    #[serde(default = "default_choice")]
    pub frontier: Choice,
    /// Struck goals ban approach cells within this many cells.
    #[serde(default = "default_exclusion")]
    pub exclusion_radius_cells: f64,
    /// No reachable frontier left: `end` the episode (default) or send a `refine` goal.
    #[serde(default)]
    pub when_no_frontier: NoFrontier,
}

fn default_choice() -> Choice {
    Choice::Utility
}
fn default_exclusion() -> f64 {
    FbeConfig::default().exclusion_radius_cells
}

fn check_config(value: &serde_json::Value) -> Result<(), String> {
    let config: Config = activemap_runtime::catalog::config_from_value(value)?;
    fbe_config(&config).validate().map_err(|e| e.to_string())
}

/// The library settings for an operator config.
fn fbe_config(config: &Config) -> FbeConfig {
    FbeConfig {
        policy: match config.frontier {
            Choice::Nearest => FbePolicy::Nearest,
            Choice::Largest => FbePolicy::Largest,
            Choice::Utility => FbePolicy::Utility,
        },
        exclusion_radius_cells: config.exclusion_radius_cells,
        ..FbeConfig::default()
    }
}

/// Library regions from the wire summaries (the FBE decision reads the size, the centroid and
/// the approach cell with its path distance).
pub fn regions_from_wire(frontiers: &Frontiers) -> Vec<PlanRegion> {
    frontiers
        .regions
        .iter()
        .map(|r| {
            let cell = Cell::new(r.closest_reachable_cell[0], r.closest_reachable_cell[1]);
            PlanRegion {
                cells: vec![cell; r.size_cells as usize],
                centroid: Point2::new(r.centroid[0], r.centroid[1]),
                anchor: cell,
                approach: r.path_distance_m.is_finite().then_some(Approach {
                    cell,
                    path_distance_m: r.path_distance_m,
                }),
            }
        })
        .collect()
}

/// The FBE decision on wire messages (testable without transport): the library's
/// [`activemap_planning::fbe::FbePlanner`] on the regions of the `frontier` operator.
pub struct FbePlanner {
    planner: activemap_planning::fbe::FbePlanner,
}

impl FbePlanner {
    /// A planner with no strikes.
    pub fn new(config: &Config) -> anyhow::Result<Self> {
        Ok(Self {
            planner: activemap_planning::fbe::FbePlanner::new(fbe_config(config))?,
        })
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
        grid: &PlanGrid,
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
        eprintln!(
            "planner: frame {} after {reason:?}: {} of {} regions [{}], {} strikes",
            frontiers.frame_id,
            choice.map_or("none".to_string(), |c| format!(
                "region {}",
                frontiers.regions[c.region].id
            )),
            frontiers.regions.len(),
            offered.join(" "),
            self.state().strikes().len()
        );
        let Some(choice) = choice else {
            return Ok(None);
        };
        Ok(Some((frontiers.regions[choice.region].id, choice.focus)))
    }
}

/// The inputs of one frame (the grid stays encoded until a replan request needs it).
#[derive(Default)]
struct Slot {
    grid: Option<Vec<u8>>,
    regions: Option<Frontiers>,
    pose: Option<PlanarPose>,
}

/// The goal for one replan request (transport-free): the FBE choice, or with no reachable
/// frontier left a refine goal (target [`REFINE_TARGET`], focused on the robot's position)
/// when `when_no_frontier` is `refine`; `None` ends the episode.
pub fn goal_for_request(
    fbe: &mut FbePlanner,
    when_no_frontier: NoFrontier,
    request: &ReplanRequest,
    grid: &PlanGrid,
    frontiers: &Frontiers,
    pose: &PlanarPose,
) -> anyhow::Result<Option<Goal>> {
    let k = request.frame_id;
    Ok(
        match (
            fbe.choose(request.reason, grid, frontiers, pose)?,
            when_no_frontier,
        ) {
            (Some((target, focus)), _) => Some(Goal {
                frame_id: k,
                target: target as i32,
                focus: [focus.x, focus.y],
            }),
            (None, NoFrontier::End) => {
                eprintln!("planner: no reachable frontier left at frame {k}: episode over");
                None
            }
            (None, NoFrontier::Refine) => {
                eprintln!("planner: no reachable frontier left at frame {k}: refine goal");
                Some(Goal {
                    frame_id: k,
                    target: REFINE_TARGET,
                    focus: [pose.x, pose.y],
                })
            }
        },
    )
}

/// The operator.
pub struct Planner {
    fbe: FbePlanner,
    when_no_frontier: NoFrontier,
    join: FrameJoin<Slot>,
    requests: Vec<ReplanRequest>,
}

impl Operator for Planner {
    type Config = Config;

    fn new(config: Config, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        Ok(Self {
            fbe: FbePlanner::new(&config)?,
            when_no_frontier: config.when_no_frontier,
            join: FrameJoin::new(),
            requests: Vec::new(),
        })
    }

    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        match event {
            Event::Input(input) => match input.port {
                "grid" => {
                    let k = OccupancyGridView::parse(input.bytes)?.header.frame_id;
                    self.join.slot(k).grid = Some(input.bytes.to_vec());
                }
                "regions" => {
                    let f: Frontiers = input.decode()?;
                    let frame = f.frame_id;
                    self.join.slot(frame).regions = Some(f);
                }
                "replan" => self.requests.push(input.decode()?),
                "pose" => {
                    let e: PoseEstimate = input.decode()?;
                    let pose = planar_from_camera_pose(&pose_from_wire(&e.t_world_camera)?);
                    self.join.slot(e.frame_id).pose = Some(pose);
                }
                "map" => {}
                other => anyhow::bail!("planner: unexpected input `{other}`"),
            },
            Event::InputClosed { port: "pose" } => return Ok(Flow::Stop),
            _ => return Ok(Flow::Continue),
        }
        while let Some(request) = self.requests.first().copied() {
            let k = request.frame_id;
            let Some(Slot {
                grid: Some(grid),
                regions: Some(frontiers),
                pose: Some(pose),
            }) = self.join.get(k)
            else {
                break;
            };
            let (_, grid) = read_grid(grid)?;
            self.requests.remove(0);
            match goal_for_request(
                &mut self.fbe,
                self.when_no_frontier,
                &request,
                &grid,
                frontiers,
                pose,
            )? {
                Some(goal) => ctx.send("goal", &goal)?,
                None => return Ok(Flow::Stop),
            }
            // Older frames are no longer needed (requests come in frame order).
            self.join.discard_before(k);
        }
        Ok(Flow::Continue)
    }
}

/// Registry entry.
pub fn registered() -> Registered {
    const INPUTS: &[PortSpec] = &[
        PortSpec {
            name: "map",
            kind: K::GaussianMap,
        },
        PortSpec {
            name: "regions",
            kind: K::Frontiers,
        },
        PortSpec {
            name: "pose",
            kind: K::PoseEstimate,
        },
        PortSpec {
            name: "replan",
            kind: K::ReplanRequest,
        },
        PortSpec {
            name: "grid",
            kind: K::OccupancyGrid,
        },
    ];
    const OUTPUTS: &[PortSpec] = &[
        PortSpec {
            name: "goal",
            kind: K::Goal,
        },
        PortSpec {
            name: "llm",
            kind: K::LlmExchange,
        },
    ];
    Registered {
        descriptor: OperatorDescriptor {
            name: "planner",
            summary: "Goal choice on replan: FBE utility/nearest/largest frontier (or refine, -1, when none is left) now, LLM later (SPEC §6, §7)",
            inputs: INPUTS,
            outputs: OUTPUTS,
            evaluation: false,
            check_config,
        },
        implementation: Some(OperatorImpl::of::<Planner>()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_planning::GridGeometry;
    use activemap_planning::grid::CellState;
    use activemap_schemas::FrontierRegion;

    fn wire(id: u32, size: u32, cell: [i32; 2], distance: f64) -> FrontierRegion {
        FrontierRegion {
            id,
            size_cells: size,
            centroid: [cell[0] as f64 * 0.05, cell[1] as f64 * 0.05 + 0.3],
            closest_reachable_cell: cell,
            path_distance_m: distance,
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

    /// `policy` is checked once, when the config is read: `fbe` (the default) is built, `llm`
    /// is refused as not built yet, anything else as unknown (naming both).
    #[test]
    fn only_the_fbe_policy_is_built() {
        let config: Config = serde_json::from_value(serde_json::json!({})).unwrap();
        assert_eq!(config.policy, Policy::Fbe);
        assert!(check_config(&serde_json::json!({ "policy": "fbe" })).is_ok());
        let llm = check_config(&serde_json::json!({ "policy": "llm" })).unwrap_err();
        assert!(llm.contains("`llm` is not built yet"), "{llm}");
        let other = check_config(&serde_json::json!({ "policy": "random" })).unwrap_err();
        assert!(
            other.contains("`random`") && other.contains("llm"),
            "{other}"
        );
    }
}
