//! `planner`: chooses the frontier to explore when the follower asks for a replan. Policy
//! `fbe` (frontier-based exploration, SPEC §6 baseline) via `activemap_planning::fbe`: the
//! nearest reachable region by path length, or the largest. The LLM policy (SPEC §7) is a later
//! issue: any other `policy` is a config error. Goals visited count one strike, goals that
//! failed (no path, stuck) two; a region whose approach cell has two strikes nearby is skipped.
//! With no reachable frontier left the planner ends the episode (end of its `goal` stream).

use std::collections::BTreeMap;

use activemap_geometry::frames::planar_from_camera_pose;
use activemap_planning::OccupancyGrid as PlanGrid;
use activemap_planning::clearance::{ClearanceConfig, ClearanceMap};
use activemap_planning::fbe::{FbePolicy, choose_frontier};
use activemap_planning::frontier::{Approach, FrontierRegion as PlanRegion, path_distances};
use activemap_planning::grid::Cell;
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, PortSpec, check_config_as,
};
use activemap_schemas::{
    Frontiers, Goal, MessageKind as K, PoseEstimate, ReplanReason, ReplanRequest,
};
use nalgebra::Point2;

use crate::Registered;
use crate::convert::{pose_from_wire, read_grid};

/// Which frontier FBE picks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Choice {
    /// Shortest path.
    Nearest,
    /// Most cells.
    Largest,
}

/// Config.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// `fbe` (only policy built so far).
    #[serde(default = "default_policy")]
    pub policy: String,
    /// FBE choice.
    #[serde(default = "default_choice")]
    pub frontier: Choice,
    /// Struck goals ban approach cells within this many cells.
    #[serde(default = "default_exclusion")]
    pub exclusion_radius_cells: f64,
}

fn default_policy() -> String {
    "fbe".into()
}
fn default_choice() -> Choice {
    Choice::Nearest
}
fn default_exclusion() -> f64 {
    3.0
}

fn check_config(value: &serde_json::Value) -> Result<(), String> {
    check_config_as::<Config>(value)?;
    let config: Config = serde_json::from_value(if value.is_null() {
        serde_json::json!({})
    } else {
        value.clone()
    })
    .map_err(|e| e.to_string())?;
    if config.policy != "fbe" {
        return Err(format!(
            "policy `{}` is not built yet: only `fbe` (the LLM policy of SPEC §7 comes later)",
            config.policy
        ));
    }
    Ok(())
}

/// The FBE decision state (testable without transport).
pub struct FbePlanner {
    policy: FbePolicy,
    exclusion_radius_cells: f64,
    /// Struck goals, world (x, y), one entry per strike.
    pub strikes: Vec<Point2<f64>>,
    last_goal: Option<Point2<f64>>,
}

impl FbePlanner {
    /// A planner with no strikes.
    pub fn new(choice: Choice, exclusion_radius_cells: f64) -> Self {
        Self {
            policy: match choice {
                Choice::Nearest => FbePolicy::Nearest,
                Choice::Largest => FbePolicy::Largest,
            },
            exclusion_radius_cells,
            strikes: Vec::new(),
            last_goal: None,
        }
    }

    /// Records the outcome of the last goal from the follower's replan reason.
    pub fn record(&mut self, reason: ReplanReason) {
        let Some(goal) = self.last_goal.take() else {
            return;
        };
        match reason {
            ReplanReason::PathDone => self.strikes.push(goal),
            ReplanReason::NoPath => self.strikes.extend([goal, goal]),
            ReplanReason::ObstacleAhead | ReplanReason::Startup => {}
        }
    }

    /// Chooses among `regions` of `grid` for a robot at `robot`: the region id and its centroid.
    pub fn choose(
        &mut self,
        grid: &PlanGrid,
        robot: Point2<f64>,
        frontiers: &Frontiers,
    ) -> anyhow::Result<Option<(u32, Point2<f64>)>> {
        let map = ClearanceMap::new(grid, &ClearanceConfig::default())?;
        let start = grid.geometry.require_cell(robot, "robot position")?;
        let distances = path_distances(&map, start);
        // Library regions from the wire summaries (the FBE ranking only reads the size and the
        // approach cell with its path distance).
        let regions: Vec<PlanRegion> = frontiers
            .regions
            .iter()
            .map(|r| {
                let cell = Cell::new(r.closest_reachable_cell[0], r.closest_reachable_cell[1]);
                let d = distances.get(cell).copied().unwrap_or(f64::INFINITY);
                PlanRegion {
                    cells: vec![cell; r.size_cells as usize],
                    centroid: Point2::new(r.centroid[0], r.centroid[1]),
                    anchor: cell,
                    approach: d.is_finite().then_some(Approach {
                        cell,
                        path_distance_m: d,
                    }),
                }
            })
            .collect();
        let excluded: Vec<Cell> = self
            .strikes
            .iter()
            .map(|p| grid.geometry.cell_of(*p))
            .collect();
        let Some(choice) = choose_frontier(
            &regions,
            self.policy,
            &excluded,
            self.exclusion_radius_cells,
            2,
        ) else {
            return Ok(None);
        };
        let goal = grid.geometry.center(choice.cell);
        self.last_goal = Some(goal);
        let region = &frontiers.regions[choice.region];
        Ok(Some((
            region.id,
            Point2::new(region.centroid[0], region.centroid[1]),
        )))
    }
}

/// The operator.
pub struct Planner {
    fbe: FbePlanner,
    grids: BTreeMap<u64, PlanGrid>,
    poses: BTreeMap<u64, Point2<f64>>,
    regions: BTreeMap<u64, Frontiers>,
    requests: Vec<ReplanRequest>,
}

impl Operator for Planner {
    type Config = Config;

    fn new(config: Config, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        anyhow::ensure!(
            config.policy == "fbe",
            "planner: policy `{}` is not built yet (only `fbe`)",
            config.policy
        );
        Ok(Self {
            fbe: FbePlanner::new(config.frontier, config.exclusion_radius_cells),
            grids: BTreeMap::new(),
            poses: BTreeMap::new(),
            regions: BTreeMap::new(),
            requests: Vec::new(),
        })
    }

    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        match event {
            Event::Input(input) => match input.port {
                "grid" => {
                    let (k, g) = read_grid(input.bytes)?;
                    self.grids.insert(k, g);
                }
                "pose" => {
                    let e: PoseEstimate = input.decode()?;
                    let p = planar_from_camera_pose(&pose_from_wire(&e.t_world_camera)?);
                    self.poses.insert(e.frame_id, Point2::new(p.x, p.y));
                }
                "regions" => {
                    let f: Frontiers = input.decode()?;
                    self.regions.insert(f.frame_id, f);
                }
                "replan" => self.requests.push(input.decode()?),
                "map" => {}
                other => anyhow::bail!("planner: unexpected input `{other}`"),
            },
            Event::InputClosed { port: "pose" } => return Ok(Flow::Stop),
            _ => return Ok(Flow::Continue),
        }
        while let Some(request) = self.requests.first().copied() {
            let k = request.frame_id;
            let (Some(grid), Some(robot), Some(frontiers)) =
                (self.grids.get(&k), self.poses.get(&k), self.regions.get(&k))
            else {
                break;
            };
            self.requests.remove(0);
            self.fbe.record(request.reason);
            match self.fbe.choose(grid, *robot, frontiers)? {
                Some((target, focus)) => ctx.send(
                    "goal",
                    &Goal {
                        frame_id: k,
                        target: target as i32,
                        focus: [focus.x, focus.y],
                    },
                )?,
                None => {
                    eprintln!("planner: no reachable frontier left at frame {k}: episode over");
                    return Ok(Flow::Stop);
                }
            }
            // Older frames are no longer needed.
            self.grids = self.grids.split_off(&k);
            self.poses = self.poses.split_off(&k);
            self.regions = self.regions.split_off(&k);
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
            summary: "Goal choice on replan: FBE nearest/largest frontier now, LLM later (SPEC §6, §7)",
            inputs: INPUTS,
            outputs: OUTPUTS,
            evaluation: false,
            check_config,
        },
        implementation: Some(OperatorImpl::of::<Planner>()),
    }
}
