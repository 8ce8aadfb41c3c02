//! The path to a goal cell as the `scorer` operator (mode `shortest`) and the in-process
//! `activemap_policy::explorer::Explorer` make it: A* with the robot-width clearance and proximity cost,
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
/// `look_at`. `None` when A* finds none. Fails when the robot is off the grid or the robot or
/// `look_at` is not finite (a NaN look-at point would give the last waypoint a NaN yaw).
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
    if !(look_at.x.is_finite() && look_at.y.is_finite()) {
        return Err(PlanningError::NonFinite {
            what: "look-at point of the path",
        });
    }
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
    /// Bad numbers (issue 18): a NaN / inf robot position, goal or look-at point is refused
    /// by the frontier extraction, A* and the path maker, never turned into a NaN waypoint;
    /// the paths they do make are finite.
    #[test]
    fn non_finite_points_are_refused_and_waypoints_are_finite() {
        use crate::astar::plan_world;
        use crate::frontier::{FrontierConfig, reachable_regions};
        let geometry = crate::GridGeometry::new(0.0, 0.0, 0.05, 60, 60).unwrap();
        let mut grid = OccupancyGrid::filled(geometry, CellState::Free);
        for y in 0..60 {
            for x in 45..60 {
                grid.data[y * 60 + x] = CellState::Unknown;
            }
        }
        let (clearance, astar) = (ClearanceConfig::default(), AstarConfig::default());
        let map = ClearanceMap::new(&grid, &clearance).unwrap();
        let good = Point2::new(0.5, 0.5);
        let regions = reachable_regions(&grid, good, &clearance, &FrontierConfig::default());
        let regions = regions.unwrap();
        assert!(!regions.is_empty());
        let goal = regions[0].approach.unwrap().cell;
        let look_at = regions[0].centroid;
        assert!(look_at.x.is_finite() && look_at.y.is_finite());
        for bad in [Point2::new(f64::NAN, 0.5), Point2::new(0.5, f64::INFINITY)] {
            let non_finite = |e: PlanningError| matches!(e, PlanningError::NonFinite { .. });
            let frontier = reachable_regions(&grid, bad, &clearance, &FrontierConfig::default());
            assert!(non_finite(frontier.unwrap_err()));
            assert!(non_finite(plan_world(&map, bad, good, &astar).unwrap_err()));
            assert!(non_finite(plan_world(&map, good, bad, &astar).unwrap_err()));
            let robot = shortest_path(&grid, bad, goal, look_at, &clearance, &astar);
            assert!(non_finite(robot.unwrap_err()));
            let look = shortest_path(&grid, good, goal, bad, &clearance, &astar);
            assert!(non_finite(look.unwrap_err()));
        }
        let path = shortest_path(&grid, good, goal, look_at, &clearance, &astar)
            .unwrap()
            .unwrap();
        assert!(!path.waypoints.is_empty());
        assert!(
            path.waypoints
                .iter()
                .all(|w| w.x.is_finite() && w.y.is_finite() && w.yaw.is_finite())
        );
    }
}
