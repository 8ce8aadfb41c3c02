//! The short-horizon path choice: the path to the goal (the `scorer` operator's decision,
//! [`ScorerMode`]).
//!
//! - `shortest` (what FBE needs): [`activemap_planning::path::shortest_path`] (A* with 3-cell
//!   moves, robot-width clearance and proximity cost, then shortcutting, SPEC §6) to the chosen
//!   region's closest reachable cell; the last waypoint faces the frontier centroid
//!   ([`path_for_goal`]). No path → an empty path (the follower reports it). A refine goal gets
//!   the look-around ([`look_around`]).
//! - `fisher` (the paper, SPEC §5–§6): [`crate::fisher::FisherPaths`], the library's
//!   [`activemap_active::FisherScorer`] with the `fisher:` settings ([`FisherConfig`], every
//!   field optional) and its bookkeeping, a report per replan. The scorer never sees frames:
//!   `camera:` ([`CameraConfig`]) must describe the simulator's camera.

use activemap_active::FisherConfig;
use activemap_geometry::frames::planar_from_camera_pose;
use activemap_geometry::robot::wrap_angle;
use activemap_geometry::{Intrinsics, Isometry3, PlanarPose, RobotModel};
use activemap_planning::OccupancyGrid as PlanGrid;
use activemap_planning::astar::AstarConfig;
use activemap_planning::clearance::ClearanceConfig;
use activemap_planning::grid::Cell;
use activemap_planning::path::shortest_path;
use activemap_schemas::{FisherReport, Frontiers, Goal, Path, PlanarPose2};
use nalgebra::Point2;

use crate::MapSnapshot;
use crate::fisher::FisherPaths;
use crate::goal::REFINE_TARGET;
use crate::wire::path_to_wire;

/// How the scorer makes a path (see the module doc). Checked once, when the config is read
/// (`activemap validate` and the node's start alike): an unknown name is an error naming the
/// modes there are.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(try_from = "String")]
pub enum ScorerMode {
    /// The shortest collision-free path to the goal's frontier (FBE).
    #[default]
    Shortest,
    /// The Fisher-information path choice of the paper (SPEC §5–§6).
    Fisher,
}

impl TryFrom<String> for ScorerMode {
    type Error = String;

    fn try_from(name: String) -> Result<Self, String> {
        match name.as_str() {
            "shortest" => Ok(Self::Shortest),
            "fisher" => Ok(Self::Fisher),
            other => Err(format!(
                "unknown mode `{other}`: the scorer has `shortest` (FBE) and `fisher` (SPEC §5)"
            )),
        }
    }
}

/// The camera of the frames the map was built from (the scorer never sees a frame; its
/// scoring renders scale these intrinsics to `fisher.scoring_width`). Must equal the `sim`
/// node's `width`, `height` and `hfov_deg`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// Image width, pixels.
    #[serde(default = "default_camera_size")]
    pub width: u32,
    /// Image height, pixels.
    #[serde(default = "default_camera_size")]
    pub height: u32,
    /// Horizontal field of view, degrees.
    #[serde(default = "default_hfov")]
    pub hfov_deg: f64,
}

fn default_camera_size() -> u32 {
    160
}
fn default_hfov() -> f64 {
    90.0
}

impl Default for CameraConfig {
    fn default() -> Self {
        Self {
            width: default_camera_size(),
            height: default_camera_size(),
            hfov_deg: default_hfov(),
        }
    }
}

impl CameraConfig {
    /// The pinhole intrinsics, as the simulator makes them; fails on the ranges the `sim`
    /// node refuses.
    pub fn intrinsics(&self) -> anyhow::Result<Intrinsics> {
        let (w, h, fov) = (self.width, self.height, self.hfov_deg);
        anyhow::ensure!(
            w > 0 && h > 0 && w <= 4096 && h <= 4096,
            "scorer: camera width/height must be in 1..=4096, got {w}×{h}"
        );
        anyhow::ensure!(
            fov.is_finite() && fov > 1.0 && fov < 179.0,
            "scorer: camera hfov_deg must be in (1, 179), got {fov}"
        );
        Ok(Intrinsics::from_hfov(w, h, fov.to_radians()))
    }
}

/// The path choice's settings (the `scorer` operator's config).
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PathConfig {
    /// `shortest` (default) or `fisher`.
    #[serde(default)]
    pub mode: ScorerMode,
    /// The robot (its radius gives the path's clearance; any field left out keeps its default).
    #[serde(default)]
    pub robot: RobotModel,
    /// `fisher` mode: the Fisher scorer's settings (any field left out keeps the paper's
    /// default; unknown fields are refused).
    #[serde(default)]
    pub fisher: FisherConfig,
    /// `fisher` mode: the frames' camera (default 160×160, 90°).
    #[serde(default)]
    pub camera: CameraConfig,
    /// `fisher` mode: map lag L in frames; the goal of frame k is scored on the map snapshot
    /// of frame k − 1 − L. Must equal the mapper's `map_lag`.
    #[serde(default)]
    pub map_lag: u64,
}

impl PathConfig {
    /// Checks what the mode uses; the message names the field.
    pub fn validate(&self) -> anyhow::Result<()> {
        self.robot
            .validate()
            .map_err(|e| anyhow::anyhow!("scorer: {e}"))?;
        if self.mode == ScorerMode::Fisher {
            self.fisher
                .validate()
                .map_err(|e| anyhow::anyhow!("scorer: {e}"))?;
            self.camera.intrinsics()?;
        }
        Ok(())
    }
}

/// The path answering `goal`: the shortest path on `grid` from `robot` to the
/// closest reachable cell of the goal's region among `frontiers`, facing the goal's focus at
/// the end (A* settings `astar`); an empty path (objective +∞) when A* finds none. Fails when the goal names a
/// region the frame does not have.
pub fn path_for_goal(
    grid: &PlanGrid,
    robot: Point2<f64>,
    frontiers: &Frontiers,
    goal: &Goal,
    robot_model: &RobotModel,
    astar: &AstarConfig,
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
    let clearance = ClearanceConfig::for_disc(robot_model.radius_m, grid.geometry.resolution)?;
    Ok(
        match shortest_path(grid, robot, cell, look_at, &clearance, astar)? {
            Some(path) => path_to_wire(k, &path),
            None => Path {
                frame_id: k,
                waypoints: Vec::new(),
                objective: f64::INFINITY,
            },
        },
    )
}

/// The refine fallback (and the answer to a refine goal in `shortest` mode): one waypoint at
/// the robot's own position facing 90° to the left of its heading, so the follower turns on
/// the spot (about 18 turns of 5°), sees something new and asks again; the loop keeps stepping.
pub fn look_around(frame_id: u64, robot: &PlanarPose) -> Path {
    Path {
        frame_id,
        waypoints: vec![PlanarPose2 {
            x: robot.x,
            y: robot.y,
            yaw: wrap_angle(robot.yaw + std::f64::consts::FRAC_PI_2),
        }],
        objective: f64::INFINITY,
    }
}

/// What one path choice sees: the goal of frame k and that frame's grid, pose estimate and
/// frontier regions.
pub struct PathInput<'a> {
    /// The goal (its frame, its region or [`REFINE_TARGET`], its focus).
    pub goal: &'a Goal,
    /// The occupancy grid of the goal's frame.
    pub grid: &'a PlanGrid,
    /// The camera's estimated pose `T_world_camera` at that frame.
    pub pose: Isometry3<f64>,
    /// The frontier regions of that frame (needed for a frontier goal only).
    pub frontiers: Option<&'a Frontiers>,
}

/// What one path choice decided.
#[derive(Debug, Clone, PartialEq)]
pub struct PathDecision {
    /// The path to follow (empty when none was found).
    pub path: Path,
    /// The Fisher replan's report, in `fisher` mode.
    pub report: Option<FisherReport>,
}

/// A path-choice policy: the shortest path, or the Fisher path.
pub struct PathPolicy {
    robot: RobotModel,
    astar: AstarConfig,
    fisher: Option<FisherPaths>,
}

impl PathPolicy {
    /// The policy of `config` (checked).
    pub fn new(config: &PathConfig) -> anyhow::Result<Self> {
        config.validate()?;
        let fisher = match config.mode {
            ScorerMode::Shortest => None,
            ScorerMode::Fisher => Some(FisherPaths::new(
                config.fisher.clone(),
                config.robot,
                config.camera.intrinsics()?,
                config.map_lag,
            )?),
        };
        Ok(Self {
            robot: config.robot,
            astar: AstarConfig::default(),
            fisher,
        })
    }

    /// The shortest path for `robot` with A* settings `astar` (what the explorer runs by
    /// default).
    pub fn shortest(robot: RobotModel, astar: AstarConfig) -> Self {
        Self {
            robot,
            astar,
            fisher: None,
        }
    }

    /// The Fisher bookkeeping, in `fisher` mode.
    pub fn fisher(&self) -> Option<&FisherPaths> {
        self.fisher.as_ref()
    }

    /// Stores a map snapshot (the Fisher scorer needs it; `shortest` ignores it).
    pub fn add_map(&mut self, map: &MapSnapshot<'_>) -> anyhow::Result<()> {
        match &mut self.fisher {
            Some(f) => f.add_map(map),
            None => Ok(()),
        }
    }

    /// Stores the estimate `T_world_camera` of frame `k` (the Fisher scorer's keyframes need
    /// their poses).
    pub fn add_pose(&mut self, k: u64, pose: Isometry3<f64>) {
        if let Some(f) = &mut self.fisher {
            f.add_pose(k, pose);
        }
    }

    /// True once what the path of frame `k` needs (besides its grid, pose and regions) has
    /// arrived: the lagged map snapshot, in `fisher` mode.
    pub fn ready(&self, k: u64) -> bool {
        self.fisher
            .as_ref()
            .is_none_or(|f| f.snapshot_for(k).is_some())
    }

    /// The path for one goal.
    pub fn path(&mut self, input: &PathInput<'_>) -> anyhow::Result<PathDecision> {
        let goal = input.goal;
        let planar = planar_from_camera_pose(&input.pose);
        Ok(match &mut self.fisher {
            Some(fisher) => {
                let (path, report) =
                    fisher.replan(goal, input.grid, &input.pose, input.frontiers)?;
                PathDecision {
                    path,
                    report: Some(report),
                }
            }
            None if goal.target == REFINE_TARGET => PathDecision {
                path: look_around(goal.frame_id, &planar),
                report: None,
            },
            None => {
                let frontiers = input.frontiers.ok_or_else(|| {
                    anyhow::anyhow!(
                        "scorer: frontier goal of frame {} without its regions",
                        goal.frame_id
                    )
                })?;
                let robot = Point2::new(planar.x, planar.y);
                PathDecision {
                    path: path_for_goal(
                        input.grid,
                        robot,
                        frontiers,
                        goal,
                        &self.robot,
                        &self.astar,
                    )?,
                    report: None,
                }
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_planning::grid::{CellState, GridGeometry};
    use activemap_schemas::FrontierRegion;

    /// The refine fallback turns the robot 90° left on the spot (wrapped to (−π, π]).
    #[test]
    fn the_look_around_turns_left_on_the_spot() {
        let p = look_around(12, &PlanarPose::new(1.0, -2.0, 3.0));
        assert_eq!(p.frame_id, 12);
        assert_eq!(p.waypoints.len(), 1);
        let w = p.waypoints[0];
        assert_eq!((w.x, w.y), (1.0, -2.0));
        let want = 3.0 + std::f64::consts::FRAC_PI_2 - 2.0 * std::f64::consts::PI;
        assert!((w.yaw - want).abs() < 1e-12, "{}", w.yaw);
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
            anchor: [2.5, 2.5],
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
        let p = path_for_goal(
            &grid,
            robot,
            &frontiers,
            &goal(0),
            &RobotModel::default(),
            &AstarConfig::default(),
        )
        .unwrap();
        let last = p.waypoints.last().unwrap();
        let end = geometry.center(Cell::new(40, 30));
        assert_eq!(p.frame_id, 3);
        assert!((last.x - end.x).abs() < 1e-12 && (last.y - end.y).abs() < 1e-12);
        assert!((last.yaw - (2.5 - last.y).atan2(2.5 - last.x)).abs() < 1e-12);
        assert!(
            path_for_goal(
                &grid,
                robot,
                &frontiers,
                &goal(7),
                &RobotModel::default(),
                &AstarConfig::default()
            )
            .is_err()
        );
        for x in 50..60 {
            grid.set(Cell::new(x, 50), CellState::Occupied);
        }
        for y in 50..60 {
            grid.set(Cell::new(50, y), CellState::Occupied);
        }
        let none = path_for_goal(
            &grid,
            robot,
            &frontiers,
            &goal(1),
            &RobotModel::default(),
            &AstarConfig::default(),
        )
        .unwrap();
        assert!(none.waypoints.is_empty() && none.objective.is_infinite());
    }
}
