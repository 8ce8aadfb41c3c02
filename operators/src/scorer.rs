//! `scorer`: turns the planner's goal into a path. Mode `shortest` (what FBE needs): A* with
//! 3-cell moves, robot-width clearance and proximity cost, then shortcutting
//! (`activemap_planning::astar`, `shortcut`, SPEC §6) to the chosen region's closest reachable
//! cell; the last waypoint faces the frontier centroid. The Fisher mode (SPEC §5) is a later
//! issue: any other `mode` is a config error. No path → an empty path (the follower reports it).

use activemap_geometry::frames::planar_from_camera_pose;
use activemap_planning::OccupancyGrid as PlanGrid;
use activemap_planning::astar::{AstarConfig, plan};
use activemap_planning::clearance::ClearanceMap;
use activemap_planning::grid::Cell;
use activemap_planning::shortcut::shortcut;
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, PortSpec,
};
use activemap_schemas::{
    Frontiers, Goal, MessageKind as K, OccupancyGridView, Path, PlanarPose2, PoseEstimate,
};
use nalgebra::Point2;

use crate::Registered;
use crate::convert::{pose_from_wire, read_grid, robot_clearance};
use crate::join::FrameJoin;

/// Config.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// `shortest` (only mode built so far).
    #[serde(default = "default_mode")]
    pub mode: String,
}

fn default_mode() -> String {
    "shortest".into()
}

fn check_config(value: &serde_json::Value) -> Result<(), String> {
    let config: Config = activemap_runtime::catalog::config_from_value(value)?;
    if config.mode != "shortest" {
        return Err(format!(
            "mode `{}` is not built yet: only `shortest` (the Fisher scorer of SPEC §5 comes later)",
            config.mode
        ));
    }
    Ok(())
}

/// The shortest collision-free path from `robot` to cell `goal`, shortcut, as waypoints (the
/// robot's own cell excluded); the last waypoint's yaw faces `look_at`. `None` when A* finds none.
pub fn shortest_path(
    grid: &PlanGrid,
    robot: Point2<f64>,
    goal: Cell,
    look_at: Point2<f64>,
) -> anyhow::Result<Option<(Vec<PlanarPose2>, f64)>> {
    let map = ClearanceMap::new(grid, &robot_clearance(grid.geometry.resolution)?)?;
    let start = grid.geometry.require_cell(robot, "robot position")?;
    let Some(path) = plan(&map, start, goal, &AstarConfig::default())? else {
        return Ok(None);
    };
    let cells = shortcut(&map, &path.cells);
    let mut previous = robot;
    let mut waypoints = Vec::new();
    for c in cells.iter().skip(1) {
        let p = grid.geometry.center(*c);
        waypoints.push(PlanarPose2 {
            x: p.x,
            y: p.y,
            yaw: (p.y - previous.y).atan2(p.x - previous.x),
        });
        previous = p;
    }
    if let Some(last) = waypoints.last_mut() {
        last.yaw = (look_at.y - last.y).atan2(look_at.x - last.x);
    }
    Ok(Some((waypoints, path.cost)))
}

/// The inputs of one frame (the grid stays encoded until a goal needs it).
#[derive(Default)]
struct Slot {
    grid: Option<Vec<u8>>,
    robot: Option<Point2<f64>>,
    regions: Option<Frontiers>,
}

/// The operator.
pub struct Scorer {
    join: FrameJoin<Slot>,
    goals: Vec<Goal>,
}

impl Operator for Scorer {
    type Config = Config;

    fn new(config: Config, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        anyhow::ensure!(
            config.mode == "shortest",
            "scorer: mode `{}` is not built yet (only `shortest`)",
            config.mode
        );
        Ok(Self {
            join: FrameJoin::new(),
            goals: Vec::new(),
        })
    }

    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        match event {
            Event::Input(input) => match input.port {
                "grid" => {
                    let k = OccupancyGridView::parse(input.bytes)?.header.frame_id;
                    self.join.slot(k).grid = Some(input.bytes.to_vec());
                }
                "pose" => {
                    let e: PoseEstimate = input.decode()?;
                    let p = planar_from_camera_pose(&pose_from_wire(&e.t_world_camera)?);
                    self.join.slot(e.frame_id).robot = Some(Point2::new(p.x, p.y));
                }
                "regions" => {
                    let f: Frontiers = input.decode()?;
                    let frame = f.frame_id;
                    self.join.slot(frame).regions = Some(f);
                }
                "goal" => self.goals.push(input.decode()?),
                "map" => {}
                other => anyhow::bail!("scorer: unexpected input `{other}`"),
            },
            // The planner ended the episode, or the loop is shutting down.
            Event::InputClosed {
                port: "goal" | "pose",
            } => return Ok(Flow::Stop),
            _ => return Ok(Flow::Continue),
        }
        while let Some(goal) = self.goals.first().cloned() {
            let k = goal.frame_id;
            let Some(Slot {
                grid: Some(grid),
                robot: Some(robot),
                regions: Some(frontiers),
            }) = self.join.get(k)
            else {
                break;
            };
            let (_, grid) = read_grid(grid)?;
            self.goals.remove(0);
            let region = frontiers
                .regions
                .iter()
                .find(|r| r.id as i32 == goal.target)
                .ok_or_else(|| {
                    anyhow::anyhow!(
                        "scorer: goal frontier {} is not among frame {k}'s regions",
                        goal.target
                    )
                })?;
            let cell = Cell::new(
                region.closest_reachable_cell[0],
                region.closest_reachable_cell[1],
            );
            let look_at = Point2::new(goal.focus[0], goal.focus[1]);
            let (waypoints, objective) =
                shortest_path(&grid, *robot, cell, look_at)?.unwrap_or((Vec::new(), f64::INFINITY));
            ctx.send(
                "path",
                &Path {
                    frame_id: k,
                    waypoints,
                    objective,
                },
            )?;
            self.join.discard_before(k);
        }
        Ok(Flow::Continue)
    }
}

/// Registry entry.
pub fn registered() -> Registered {
    const INPUTS: &[PortSpec] = &[
        PortSpec {
            name: "goal",
            kind: K::Goal,
        },
        PortSpec {
            name: "map",
            kind: K::GaussianMap,
        },
        PortSpec {
            name: "grid",
            kind: K::OccupancyGrid,
        },
        PortSpec {
            name: "pose",
            kind: K::PoseEstimate,
        },
        PortSpec {
            name: "regions",
            kind: K::Frontiers,
        },
    ];
    const OUTPUTS: &[PortSpec] = &[PortSpec {
        name: "path",
        kind: K::Path,
    }];
    Registered {
        descriptor: OperatorDescriptor {
            name: "scorer",
            summary: "Path to the planner's goal: shortest A* + shortcut now, Fisher scoring later (SPEC §5, §6)",
            inputs: INPUTS,
            outputs: OUTPUTS,
            evaluation: false,
            check_config,
        },
        implementation: Some(OperatorImpl::of::<Scorer>()),
    }
}
