//! `scorer`: turns the planner's goal into a path. Mode `shortest` (what FBE needs):
//! [`activemap_planning::path::shortest_path`] (A* with 3-cell moves, robot-width clearance and
//! proximity cost, then shortcutting, SPEC §6; the in-process explorer calls it too) to the
//! chosen region's closest reachable cell; the last waypoint faces the frontier centroid. The
//! Fisher mode (SPEC §5) is a later issue: `mode: fisher` is a config error ([`ScorerMode`]).
//! No path → an empty path (the follower reports it).

use activemap_geometry::RobotModel;
use activemap_geometry::frames::planar_from_camera_pose;
use activemap_planning::OccupancyGrid as PlanGrid;
use activemap_planning::astar::AstarConfig;
use activemap_planning::grid::Cell;
use activemap_planning::path::{PlannedPath, shortest_path};
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, PortSpec, check_config_as,
};
use activemap_schemas::{
    Frontiers, Goal, MessageKind as K, OccupancyGridView, Path, PlanarPose2, PoseEstimate,
};
use nalgebra::Point2;

use crate::Registered;
use crate::convert::{pose_from_wire, read_grid, robot_clearance};
use crate::join::FrameJoin;

/// How the scorer makes a path. Only `shortest` is built; `fisher` (SPEC §5) is refused when
/// the config is read, the one place it is checked (`activemap validate` and the node's start
/// alike).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(try_from = "String")]
pub enum ScorerMode {
    /// The shortest collision-free path.
    #[default]
    Shortest,
}

impl TryFrom<String> for ScorerMode {
    type Error = String;

    fn try_from(name: String) -> Result<Self, String> {
        match name.as_str() {
            "shortest" => Ok(Self::Shortest),
            "fisher" => Err(
                "mode `fisher` is not built yet: only `shortest` (the Fisher scorer of SPEC §5 comes later)"
                    .into(),
            ),
            other => Err(format!(
                "unknown mode `{other}`: only `shortest` is built (`fisher`, SPEC §5, comes later)"
            )),
        }
    }
}

/// Config.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// `shortest` (the only mode built so far).
    #[serde(default)]
    pub mode: ScorerMode,
    /// The robot (its radius gives the path's clearance; any field left out keeps its default).
    #[serde(default)]
    pub robot: RobotModel,
}

/// A planned path as the wire path of frame `frame_id`.
pub fn path_to_wire(frame_id: u64, path: &PlannedPath) -> Path {
    Path {
        frame_id,
        waypoints: path
            .waypoints
            .iter()
            .map(|w| PlanarPose2 {
                x: w.x,
                y: w.y,
                yaw: w.yaw,
            })
            .collect(),
        objective: path.cost,
    }
}

/// The path answering `goal` (transport-free): the shortest path on `grid` from `robot` to the
/// closest reachable cell of the goal's region among `frontiers`, facing the goal's focus at
/// the end; an empty path (objective +∞) when A* finds none. Fails when the goal names a
/// region the frame does not have.
pub fn path_for_goal(
    grid: &PlanGrid,
    robot: Point2<f64>,
    frontiers: &Frontiers,
    goal: &Goal,
    robot_model: &RobotModel,
) -> anyhow::Result<Path> {
    let k = goal.frame_id;
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
    let clearance = robot_clearance(robot_model, grid.geometry.resolution)?;
    Ok(
        match shortest_path(
            grid,
            robot,
            cell,
            look_at,
            &clearance,
            &AstarConfig::default(),
        )? {
            Some(path) => path_to_wire(k, &path),
            None => Path {
                frame_id: k,
                waypoints: Vec::new(),
                objective: f64::INFINITY,
            },
        },
    )
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
    robot: RobotModel,
    join: FrameJoin<Slot>,
    goals: Vec<Goal>,
}

impl Operator for Scorer {
    type Config = Config;

    fn new(config: Config, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        // `mode` is `shortest`, the only one that deserialises.
        let ScorerMode::Shortest = config.mode;
        config
            .robot
            .validate()
            .map_err(|e| anyhow::anyhow!("scorer: {e}"))?;
        Ok(Self {
            robot: config.robot,
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
            ctx.send(
                "path",
                &path_for_goal(&grid, *robot, frontiers, &goal, &self.robot)?,
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
            check_config: check_config_as::<Config>,
        },
        implementation: Some(OperatorImpl::of::<Scorer>()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_planning::grid::{CellState, GridGeometry};
    use activemap_schemas::FrontierRegion;

    /// `mode` is checked once, when the config is read: `shortest` (the default) is built,
    /// `fisher` is refused as not built yet, anything else as unknown (naming both).
    #[test]
    fn only_the_shortest_mode_is_built() {
        let check = |v: serde_json::Value| check_config_as::<Config>(&v);
        let config: Config = serde_json::from_value(serde_json::json!({})).unwrap();
        assert_eq!(config.mode, ScorerMode::Shortest);
        assert!(check(serde_json::json!({ "mode": "shortest" })).is_ok());
        let fisher = check(serde_json::json!({ "mode": "fisher" })).unwrap_err();
        assert!(fisher.contains("`fisher` is not built yet"), "{fisher}");
        let other = check(serde_json::json!({ "mode": "random" })).unwrap_err();
        assert!(
            other.contains("`random`") && other.contains("fisher"),
            "{other}"
        );
    }

    /// A goal gets a path to its region's closest reachable cell, facing the focus; a goal
    /// on an unknown region is an error, and a walled-off cell an empty path.
    #[test]
    fn a_goal_gets_a_path_to_its_region() {
        let geometry = GridGeometry::new(0.0, 0.0, 0.05, 60, 60).unwrap();
        let mut grid = PlanGrid::filled(geometry, CellState::Free);
        let region = |id, cell: [i32; 2]| FrontierRegion {
            id,
            size_cells: 10,
            centroid: [2.5, 2.5],
            closest_reachable_cell: cell,
            path_distance_m: 1.0,
        };
        let frontiers = Frontiers {
            frame_id: 3,
            stamp: 0.0,
            regions: vec![region(0, [40, 30]), region(1, [55, 55])],
        };
        let goal = |target| Goal {
            frame_id: 3,
            target,
            focus: [2.5, 2.5],
        };
        let robot = Point2::new(0.5, 0.5);
        let p = path_for_goal(&grid, robot, &frontiers, &goal(0), &RobotModel::default()).unwrap();
        let last = p.waypoints.last().unwrap();
        let end = geometry.center(Cell::new(40, 30));
        assert_eq!(p.frame_id, 3);
        assert!((last.x - end.x).abs() < 1e-12 && (last.y - end.y).abs() < 1e-12);
        assert!((last.yaw - (2.5 - last.y).atan2(2.5 - last.x)).abs() < 1e-12);
        assert!(path_for_goal(&grid, robot, &frontiers, &goal(7), &RobotModel::default()).is_err());
        for x in 50..60 {
            grid.set(Cell::new(x, 50), CellState::Occupied);
        }
        for y in 50..60 {
            grid.set(Cell::new(50, y), CellState::Occupied);
        }
        let none =
            path_for_goal(&grid, robot, &frontiers, &goal(1), &RobotModel::default()).unwrap();
        assert!(none.waypoints.is_empty() && none.objective.is_infinite());
    }
}
