//! `planner`: chooses the frontier to explore when the follower asks for a replan. Policy
//! `fbe` (frontier-based exploration, SPEC §6 baseline) via `activemap_planning::fbe`: the
//! nearest reachable region by path length, or the largest. The LLM policy (SPEC §7) is a later
//! issue: any other `policy` is a config error. Goals visited count one strike, goals that
//! failed (no path, stuck) two; a region whose approach cell has two strikes nearby is skipped.
//! The path distances come with the regions (`FrontierRegion::path_distance_m`), so a replan
//! costs no search here. With no reachable frontier left (after forgiving the strikes once per
//! growth of the map) the planner ends the episode (end of its `goal` stream).

use activemap_planning::OccupancyGrid as PlanGrid;
use activemap_planning::fbe::{FbePolicy, choose_frontier};
use activemap_planning::frontier::{Approach, FrontierRegion as PlanRegion};
use activemap_planning::grid::{Cell, CellState};
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, PortSpec,
};
use activemap_schemas::{
    Frontiers, Goal, MessageKind as K, OccupancyGridView, ReplanReason, ReplanRequest,
};
use nalgebra::Point2;

use crate::Registered;
use crate::convert::read_grid;
use crate::join::FrameJoin;

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
    let config: Config = activemap_runtime::catalog::config_from_value(value)?;
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
    /// Free cells of the grid when the strikes were last forgiven.
    free_at_last_amnesty: usize,
    /// Times every reachable frontier was banned and the strikes were forgiven.
    pub amnesties: usize,
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
            free_at_last_amnesty: 0,
            amnesties: 0,
        }
    }

    /// Records the outcome of the last goal from the follower's replan reason: reached counts
    /// one strike (a frontier still there after a second visit cannot be seen from its
    /// approach cell), failed (no path, stuck) two.
    pub fn record(&mut self, reason: ReplanReason) {
        let Some(goal) = self.last_goal.take() else {
            return;
        };
        match reason {
            ReplanReason::PathDone => self.strikes.push(goal),
            ReplanReason::NoPath | ReplanReason::Stuck => self.strikes.extend([goal, goal]),
            ReplanReason::ObstacleAhead | ReplanReason::Startup | ReplanReason::TrackingLost => {}
        }
    }

    /// Chooses among the reachable `frontiers` of `grid`: the region id and its centroid;
    /// `None` when no reachable region is left. When every reachable region is banned but the
    /// map grew since the last time that happened, the strikes are forgiven once (estimated
    /// poses shift the map, so a goal that failed may work now).
    pub fn choose(
        &mut self,
        grid: &PlanGrid,
        frontiers: &Frontiers,
    ) -> anyhow::Result<Option<(u32, Point2<f64>)>> {
        // Library regions from the wire summaries (the FBE ranking only reads the size and the
        // approach cell with its path distance).
        let regions: Vec<PlanRegion> = frontiers
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
            .collect();
        let mut choice = self.choose_among(grid, &regions);
        if choice.is_none() && !self.strikes.is_empty() {
            let free = grid.count(CellState::Free);
            if free > self.free_at_last_amnesty {
                self.free_at_last_amnesty = free;
                self.strikes.clear();
                self.amnesties += 1;
                choice = self.choose_among(grid, &regions);
            }
        }
        let Some(choice) = choice else {
            return Ok(None);
        };
        self.last_goal = Some(grid.geometry.center(choice.cell));
        let region = &frontiers.regions[choice.region];
        Ok(Some((
            region.id,
            Point2::new(region.centroid[0], region.centroid[1]),
        )))
    }

    fn choose_among(
        &self,
        grid: &PlanGrid,
        regions: &[PlanRegion],
    ) -> Option<activemap_planning::fbe::FbeGoal> {
        let excluded: Vec<Cell> = self
            .strikes
            .iter()
            .map(|p| grid.geometry.cell_of(*p))
            .collect();
        choose_frontier(
            regions,
            self.policy,
            &excluded,
            self.exclusion_radius_cells,
            2,
        )
    }
}

/// The inputs of one frame (the grid stays encoded until a replan request needs it).
#[derive(Default)]
struct Slot {
    grid: Option<Vec<u8>>,
    regions: Option<Frontiers>,
}

/// The operator.
pub struct Planner {
    fbe: FbePlanner,
    join: FrameJoin<Slot>,
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
                "pose" | "map" => {}
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
            }) = self.join.get(k)
            else {
                break;
            };
            let (_, grid) = read_grid(grid)?;
            self.requests.remove(0);
            self.fbe.record(request.reason);
            match self.fbe.choose(&grid, frontiers)? {
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
            summary: "Goal choice on replan: FBE nearest/largest frontier now, LLM later (SPEC §6, §7)",
            inputs: INPUTS,
            outputs: OUTPUTS,
            evaluation: false,
            check_config,
        },
        implementation: Some(OperatorImpl::of::<Planner>()),
    }
}
