//! When to replan (SPEC §1, issue 6): the path is done, the map now shows an obstacle on the
//! remaining path or close ahead of the robot, or the goal cell turned occupied. Stuck
//! detection lives in [`crate::stuck`].

use activemap_geometry::PlanarPose;
use nalgebra::Point2;
use serde::{Deserialize, Serialize};

use crate::clearance::ClearanceMap;
use crate::error::{PlanningError, require};
use crate::follower::heading_error;
use crate::grid::{Cell, CellState, OccupancyGrid};

/// Why a new plan is needed: the map triggers [`check_replan`] reports (path done, goal
/// occupied, path blocked, obstacle ahead) and the executor's own reasons (start-up, no path,
/// stuck, bumper, tracking recovered; [`crate::executor::PathExecutor`]). The planner judges
/// the last goal by it ([`crate::fbe::outcome`]); the `follower` operator maps it onto the wire
/// enum `activemap_schemas::ReplanReason` (the three obstacle triggers become `ObstacleAhead`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ReplanReason {
    /// No path yet (the episode starts, after the initial look-around).
    Startup,
    /// Every waypoint has been reached (and the look turn, if any, is done).
    PathDone,
    /// The goal cell is now occupied.
    GoalOccupied,
    /// The remaining move starting at this waypoint index (0 = from the robot to the first
    /// remaining waypoint) now fails the swept check.
    PathBlocked {
        /// Index of the move's first waypoint in the remaining path (0 = the robot).
        segment: usize,
    },
    /// An occupied cell lies in the robot's corridor within the look-ahead distance.
    ObstacleAhead,
    /// The planner found no path to the goal (an empty path).
    NoPath,
    /// No progress along the path over the stuck window: the goal counts as failed.
    Stuck,
    /// Tracking was lost and has recovered: the old path was planned on a pose that may be
    /// wrong.
    TrackingLost,
    /// Forward moves did not move the robot (the bumper): something the map does not show is
    /// in the way. The goal is not at fault.
    Blocked,
}

impl ReplanReason {
    /// Whether the map showed an obstacle on or ahead of the path, or at the goal.
    pub fn is_obstacle(self) -> bool {
        matches!(
            self,
            Self::GoalOccupied | Self::PathBlocked { .. } | Self::ObstacleAhead
        )
    }
}

/// Settings of the replan triggers.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ReplanConfig {
    /// Length of the corridor ahead of the robot that must stay free, metres.
    pub lookahead_m: f64,
    /// Half-width of that corridor, metres (default: the 3-cell robot's half width).
    pub corridor_half_width_m: f64,
    /// The corridor only counts when the heading error to the next waypoint is within this
    /// (the follower's turn threshold, SPEC §6: 5°), i.e. when the robot will move forward.
    pub turn_threshold_rad: f64,
}

impl Default for ReplanConfig {
    fn default() -> Self {
        Self {
            lookahead_m: 0.25,
            corridor_half_width_m: 0.075,
            turn_threshold_rad: 5f64.to_radians(),
        }
    }
}

impl ReplanConfig {
    /// Checks the ranges of every field.
    pub fn validate(&self) -> Result<(), PlanningError> {
        require(
            self.lookahead_m.is_finite() && self.lookahead_m >= 0.0,
            "ReplanConfig::lookahead_m",
            "must be finite and non-negative",
        )?;
        require(
            self.corridor_half_width_m.is_finite() && self.corridor_half_width_m >= 0.0,
            "ReplanConfig::corridor_half_width_m",
            "must be finite and non-negative",
        )
    }
}

/// Whether an occupied cell's centre lies in the corridor ahead of `pose`: in front of the
/// robot's own cell, at most `config.lookahead_m` ahead and `corridor_half_width_m` sideways.
pub fn obstacle_ahead(grid: &OccupancyGrid, pose: &PlanarPose, config: &ReplanConfig) -> bool {
    obstacle_within(
        grid,
        pose,
        config.lookahead_m,
        config.corridor_half_width_m,
        None,
    )
}

/// [`obstacle_ahead`] with an explicit corridor length and half-width (metres); cells that
/// were already occupied in `known` (the grid the current plan was made on) do not count, so
/// only obstacles the map shows since the plan trigger it.
pub fn obstacle_within(
    grid: &OccupancyGrid,
    pose: &PlanarPose,
    length: f64,
    half_width: f64,
    known: Option<&OccupancyGrid>,
) -> bool {
    let config = ReplanConfig {
        lookahead_m: length,
        corridor_half_width_m: half_width,
        ..ReplanConfig::default()
    };
    let g = grid.geometry;
    let here = Point2::new(pose.x, pose.y);
    let own = g.cell_of(here);
    let (fwd, left) = (
        nalgebra::Vector2::new(pose.yaw.cos(), pose.yaw.sin()),
        nalgebra::Vector2::new(-pose.yaw.sin(), pose.yaw.cos()),
    );
    let reach = config.lookahead_m + config.corridor_half_width_m + g.resolution;
    let (lo, hi) = (
        g.cell_of(here - nalgebra::Vector2::new(reach, reach)),
        g.cell_of(here + nalgebra::Vector2::new(reach, reach)),
    );
    for y in lo.y..=hi.y {
        for x in lo.x..=hi.x {
            let c = Cell::new(x, y);
            if c == own || grid.get(c) != Some(&CellState::Occupied) {
                continue;
            }
            if let Some(k) = known
                && k.get(k.geometry.cell_of(g.center(c))) == Some(&CellState::Occupied)
            {
                continue;
            }
            let d = g.center(c) - here;
            let ahead = d.dot(&fwd);
            if ahead > 0.0
                && ahead <= config.lookahead_m
                && d.dot(&left).abs() <= config.corridor_half_width_m
            {
                return true;
            }
        }
    }
    false
}

/// The first reason to replan, checked in the order done, goal occupied, path blocked,
/// obstacle ahead (only these four [`ReplanReason`]s come from here); `None` to keep following. The obstacle-ahead corridor only counts when the
/// robot is about to move forward (heading error to the next waypoint within
/// `config.turn_threshold_rad`) and only up to that waypoint (the path may turn there), and only for
/// cells not already occupied in `plan_grid` (the grid the plan was made on, if given). `remaining` are the waypoints not reached yet
/// (world), `goal` the final goal; `occupied_only` must be built from `grid` with unknown cells
/// NOT blocking (the path was planned through free cells; only new obstacles matter). The
/// move from the robot only needs unoccupied cells, so a robot inside the margin, or a plan
/// that began with an escape move, is not re-triggered; later moves need full clearance.
pub fn check_replan(
    grid: &OccupancyGrid,
    occupied_only: &ClearanceMap,
    pose: &PlanarPose,
    remaining: &[Point2<f64>],
    goal: Option<Point2<f64>>,
    config: &ReplanConfig,
    plan_grid: Option<&OccupancyGrid>,
) -> Result<Option<ReplanReason>, PlanningError> {
    config.validate()?;
    let Some(next) = remaining.first() else {
        return Ok(Some(ReplanReason::PathDone));
    };
    let g = grid.geometry;
    if let Some(goal) = goal
        && grid.get(g.cell_of(goal)) == Some(&CellState::Occupied)
    {
        return Ok(Some(ReplanReason::GoalOccupied));
    }
    let robot = g.cell_of(Point2::new(pose.x, pose.y));
    let mut prev = robot;
    for (k, w) in remaining.iter().enumerate() {
        let c = g.cell_of(*w);
        let ok = if k == 0 {
            // The move from where the robot actually is: only its cells must be unoccupied
            // (the robot may sit inside the margin after a slide, or its plan may have
            // started with an escape move; neither is a new obstacle).
            crate::segment::for_each_supercover_cell(prev, c, |x| {
                x == robot || !occupied_only.is_blocked(x)
            })
        } else {
            occupied_only.segment_is_clear(prev, c)
        };
        if !ok {
            return Ok(Some(ReplanReason::PathBlocked { segment: k }));
        }
        prev = c;
    }
    let to_next = (next - Point2::new(pose.x, pose.y)).norm();
    let aligned = heading_error(pose, next).abs() <= config.turn_threshold_rad;
    let length = config.lookahead_m.min(to_next);
    if aligned && obstacle_within(grid, pose, length, config.corridor_half_width_m, plan_grid) {
        return Ok(Some(ReplanReason::ObstacleAhead));
    }
    Ok(None)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clearance::ClearanceConfig;

    fn occupied_only(grid: &OccupancyGrid) -> ClearanceMap {
        ClearanceMap::new(
            grid,
            &ClearanceConfig {
                unknown_is_blocked: false,
                ..Default::default()
            },
        )
        .unwrap()
    }

    #[test]
    fn each_trigger_fires_on_its_own_situation() {
        let rows = vec!["...................."; 9];
        let mut grid = OccupancyGrid::from_ascii(&rows, 0.05).unwrap();
        let g = grid.geometry;
        let pose = PlanarPose::new(
            g.center(Cell::new(2, 4)).x,
            g.center(Cell::new(2, 4)).y,
            0.0,
        );
        let path = vec![g.center(Cell::new(10, 4)), g.center(Cell::new(17, 4))];
        let goal = Some(path[1]);
        let cfg = ReplanConfig::default();
        let check = |grid: &OccupancyGrid| {
            check_replan(grid, &occupied_only(grid), &pose, &path, goal, &cfg, None).unwrap()
        };
        assert_eq!(check(&grid), None, "free corridor: keep going");
        assert_eq!(
            check_replan(&grid, &occupied_only(&grid), &pose, &[], goal, &cfg, None).unwrap(),
            Some(ReplanReason::PathDone)
        );
        // An obstacle appears on the second move of the path.
        grid.set(Cell::new(14, 5), CellState::Occupied);
        assert_eq!(check(&grid), Some(ReplanReason::PathBlocked { segment: 1 }));
        // The goal turns occupied: reported first.
        grid.set(Cell::new(17, 4), CellState::Occupied);
        assert_eq!(check(&grid), Some(ReplanReason::GoalOccupied));
        // Unknown cells appearing do not block (the map only gains obstacles that matter).
        let mut g2 = OccupancyGrid::from_ascii(&rows, 0.05).unwrap();
        g2.set(Cell::new(6, 4), CellState::Unknown);
        assert_eq!(check(&g2), None);
        // An obstacle 0.2 m ahead, off the path's cells' clearance but in the corridor:
        // the robot heads +x at (2,4); obstacle at (6, 4) is 4 cells = 0.2 m ahead.
        let mut g3 = OccupancyGrid::from_ascii(&rows, 0.05).unwrap();
        g3.set(Cell::new(6, 4), CellState::Occupied);
        assert!(obstacle_ahead(&g3, &pose, &cfg));
        // Behind or beside the corridor: no trigger.
        let mut g4 = OccupancyGrid::from_ascii(&rows, 0.05).unwrap();
        g4.set(Cell::new(0, 4), CellState::Occupied);
        g4.set(Cell::new(4, 7), CellState::Occupied);
        g4.set(Cell::new(9, 4), CellState::Occupied);
        assert!(
            !obstacle_ahead(&g4, &pose, &cfg),
            "behind, 3 cells aside, 0.35 m ahead"
        );
        // The same cells ahead of a robot facing −x are behind it.
        let back = PlanarPose::new(pose.x, pose.y, std::f64::consts::PI);
        assert!(!obstacle_ahead(&g3, &back, &cfg));
        // Through check_replan: the obstacle 0.2 m ahead is off the path's clearance only if
        // the path avoids it; a path turning left at (4, 4) → (4, 8) stops the corridor at
        // 0.1 m, so (6, 4) no longer counts; heading along the path to (10, 4) it does.
        let turn = vec![g.center(Cell::new(4, 4)), g.center(Cell::new(4, 8))];
        let map3 = occupied_only(&g3);
        assert_eq!(
            check_replan(&g3, &map3, &pose, &turn, None, &cfg, None).unwrap(),
            None
        );
        let straight = vec![g.center(Cell::new(10, 4))];
        assert_eq!(
            check_replan(&g3, &map3, &pose, &straight, None, &cfg, None).unwrap(),
            Some(ReplanReason::PathBlocked { segment: 0 })
        );
        // A robot still turning toward its next waypoint does not trigger the corridor.
        let up = vec![g.center(Cell::new(2, 8))];
        let mut g5 = OccupancyGrid::from_ascii(&rows, 0.05).unwrap();
        g5.set(Cell::new(5, 4), CellState::Occupied);
        assert!(obstacle_ahead(&g5, &pose, &cfg));
        let map5 = occupied_only(&g5);
        assert_eq!(
            check_replan(&g5, &map5, &pose, &up, None, &cfg, None).unwrap(),
            None
        );
        let facing_up = PlanarPose::new(pose.x, pose.y, std::f64::consts::FRAC_PI_2);
        g5.set(Cell::new(2, 6), CellState::Occupied);
        let map5 = occupied_only(&g5);
        assert_eq!(
            check_replan(&g5, &map5, &facing_up, &up, None, &cfg, None).unwrap(),
            Some(ReplanReason::PathBlocked { segment: 0 })
        );
    }

    #[test]
    fn robot_inside_the_margin_is_not_retriggered_but_a_blocked_first_move_is() {
        let rows = vec!["...................."; 9];
        let mut grid = OccupancyGrid::from_ascii(&rows, 0.05).unwrap();
        grid.set(Cell::new(2, 5), CellState::Occupied); // beside the robot at (2, 4)
        let g = grid.geometry;
        let pose = PlanarPose::new(
            g.center(Cell::new(2, 4)).x,
            g.center(Cell::new(2, 4)).y,
            0.0,
        );
        let path = vec![g.center(Cell::new(10, 4))];
        let cfg = ReplanConfig::default();
        let map = occupied_only(&grid);
        assert_eq!(
            check_replan(&grid, &map, &pose, &path, None, &cfg, None).unwrap(),
            None
        );
        let up = vec![g.center(Cell::new(2, 8))];
        assert_eq!(
            check_replan(&grid, &map, &pose, &up, None, &cfg, None).unwrap(),
            Some(ReplanReason::PathBlocked { segment: 0 })
        );
    }
}
