//! The path to a goal cell as the `scorer` operator (mode `shortest`) and the in-process
//! [`crate::explorer::Explorer`] make it: A* with the robot-width clearance and proximity cost,
//! then shortcutting (SPEC §6), as waypoints with headings; the last one faces the point the
//! robot came to look at (the frontier's centroid), which is where the follower's look turn at
//! the end of the path aims.

use activemap_geometry::PlanarPose;
use nalgebra::Point2;

use crate::astar::{AstarConfig, plan};
use crate::clearance::{ClearanceConfig, ClearanceMap};
use crate::error::PlanningError;
use crate::grid::{Cell, OccupancyGrid};
use crate::shortcut::shortcut;

/// A path ready to follow.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PlannedPath {
    /// Waypoints (world), the robot's own cell excluded. Each yaw is the heading of the move
    /// that ends there, except the last, which faces the look-at point.
    pub waypoints: Vec<PlanarPose>,
    /// A* cost of the path before shortcutting (metres plus proximity cost).
    pub cost: f64,
}

/// The shortest collision-free path from `robot` to cell `goal` on `grid` (clearance
/// `clearance`, search `astar`), shortcut, as waypoints; the last waypoint's yaw faces
/// `look_at`. `None` when A* finds none. Fails when the robot is off the grid.
pub fn shortest_path(
    grid: &OccupancyGrid,
    robot: Point2<f64>,
    goal: Cell,
    look_at: Point2<f64>,
    clearance: &ClearanceConfig,
    astar: &AstarConfig,
) -> Result<Option<PlannedPath>, PlanningError> {
    let map = ClearanceMap::new(grid, clearance)?;
    shortest_path_on(&map, grid, robot, goal, look_at, astar)
}

/// [`shortest_path`] on the clearance map `map`, built beforehand from `grid`: a caller that
/// plans many paths on one grid (the Fisher scorer's paths to its top candidates) computes
/// the distance transform once.
pub fn shortest_path_on(
    map: &ClearanceMap,
    grid: &OccupancyGrid,
    robot: Point2<f64>,
    goal: Cell,
    look_at: Point2<f64>,
    astar: &AstarConfig,
) -> Result<Option<PlannedPath>, PlanningError> {
    let start = grid.geometry.require_cell(robot, "robot position")?;
    let Some(path) = plan(map, start, goal, astar)? else {
        return Ok(None);
    };
    let cells = shortcut(map, &path.cells);
    let mut previous = robot;
    let mut waypoints = Vec::new();
    for c in cells.iter().skip(1) {
        let p = grid.geometry.center(*c);
        waypoints.push(PlanarPose::new(
            p.x,
            p.y,
            (p.y - previous.y).atan2(p.x - previous.x),
        ));
        previous = p;
    }
    if let Some(last) = waypoints.last_mut() {
        last.yaw = (look_at.y - last.y).atan2(look_at.x - last.x);
    }
    Ok(Some(PlannedPath {
        waypoints,
        cost: path.cost,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::CellState;

    /// In an open room the path ends at the goal cell, every waypoint but the last heads along
    /// its move, and the last faces the look-at point.
    #[test]
    fn the_last_waypoint_faces_the_look_at_point() {
        let geometry = crate::GridGeometry::new(0.0, 0.0, 0.05, 60, 60).unwrap();
        let grid = OccupancyGrid::filled(geometry, CellState::Free);
        let robot = Point2::new(0.5, 0.5);
        let goal = Cell::new(40, 30);
        let look_at = Point2::new(2.0, 2.5);
        let p = shortest_path(
            &grid,
            robot,
            goal,
            look_at,
            &ClearanceConfig::default(),
            &AstarConfig::default(),
        )
        .unwrap()
        .unwrap();
        let last = *p.waypoints.last().unwrap();
        let end = geometry.center(goal);
        assert!((last.x - end.x).abs() < 1e-12 && (last.y - end.y).abs() < 1e-12);
        let facing = (look_at.y - last.y).atan2(look_at.x - last.x);
        assert!((last.yaw - facing).abs() < 1e-12);
        let mut previous = robot;
        for w in &p.waypoints[..p.waypoints.len() - 1] {
            assert!((w.yaw - (w.y - previous.y).atan2(w.x - previous.x)).abs() < 1e-12);
            previous = Point2::new(w.x, w.y);
        }
        assert!(p.cost.is_finite() && p.cost > 0.0);
    }
}
