//! The robot-width collision check shared by A*, shortcutting, frontier reachability and the
//! replan triggers (SPEC §6: robot width 3 cells). A cell is *clear* when no blocked cell's
//! centre lies within the robot radius (width / 2 cells) of its centre, i.e. for width 3 the
//! whole 3×3 block around it is unblocked; a segment is clear when every cell of its
//! supercover is.

use serde::{Deserialize, Serialize};

use crate::distance::DistanceField;
use crate::error::{PlanningError, require};
use crate::grid::{Cell, CellState, GridGeometry, OccupancyGrid};
use crate::segment::for_each_supercover_cell;

/// Which cells block the robot, and how wide it is.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ClearanceConfig {
    /// Robot width in cells (release: 3); the clearance radius is half of it.
    pub robot_width_cells: f64,
    /// Whether unknown cells block like occupied ones (default true: never drive into the
    /// unobserved).
    pub unknown_is_blocked: bool,
}

impl Default for ClearanceConfig {
    fn default() -> Self {
        Self {
            robot_width_cells: 3.0,
            unknown_is_blocked: true,
        }
    }
}

impl ClearanceConfig {
    /// Checks the ranges of every field.
    pub fn validate(&self) -> Result<(), PlanningError> {
        require(
            self.robot_width_cells.is_finite() && self.robot_width_cells >= 0.0,
            "ClearanceConfig::robot_width_cells",
            "must be finite and non-negative",
        )
    }
}

/// Blocked cells of an occupancy grid with their distance transform.
#[derive(Debug, Clone)]
pub struct ClearanceMap {
    blocked: Vec<bool>,
    distance: DistanceField,
    radius_cells: f64,
}

impl ClearanceMap {
    /// Builds the blocked mask and its exact distance transform from `grid`.
    pub fn new(grid: &OccupancyGrid, config: &ClearanceConfig) -> Result<Self, PlanningError> {
        config.validate()?;
        let blocked: Vec<bool> = grid
            .data
            .iter()
            .map(|s| match s {
                CellState::Occupied => true,
                CellState::Unknown => config.unknown_is_blocked,
                CellState::Free => false,
            })
            .collect();
        let distance = DistanceField::from_mask(grid.geometry, &blocked);
        Ok(Self {
            blocked,
            distance,
            radius_cells: 0.5 * config.robot_width_cells,
        })
    }

    /// Placement of the underlying grid.
    pub fn geometry(&self) -> &GridGeometry {
        &self.distance.cells.geometry
    }

    /// The distance transform of the blocked cells.
    pub fn distance(&self) -> &DistanceField {
        &self.distance
    }

    /// The clearance radius in cells (robot width / 2).
    pub fn radius_cells(&self) -> f64 {
        self.radius_cells
    }

    /// Whether `cell` is blocked itself (outside the grid counts as blocked).
    pub fn is_blocked(&self, cell: Cell) -> bool {
        self.geometry().index(cell).is_none_or(|i| self.blocked[i])
    }

    /// Whether the robot centred on `cell` keeps its radius from every blocked cell.
    pub fn is_clear(&self, cell: Cell) -> bool {
        self.geometry().contains(cell)
            && self.distance.distance_cells(cell) as f64 > self.radius_cells
    }

    /// Whether the robot sweeping from the centre of `a` to the centre of `b` stays clear.
    pub fn segment_is_clear(&self, a: Cell, b: Cell) -> bool {
        for_each_supercover_cell(a, b, |c| self.is_clear(c))
    }

    /// The relaxed check used when the robot starts inside the clearance margin (after a
    /// slide or a map update): the segment may not touch a blocked cell other than `a` itself,
    /// and it must end on a clear cell, so the robot can only move out of the margin.
    pub fn escape_segment_is_ok(&self, a: Cell, b: Cell) -> bool {
        self.is_clear(b) && for_each_supercover_cell(a, b, |c| c == a || !self.is_blocked(c))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clear_means_the_whole_three_by_three_block_is_unblocked() {
        let grid = OccupancyGrid::from_ascii(
            &[
                ".......", //
                ".......", //
                "...#...", //
                ".......", //
                ".......",
            ],
            0.05,
        )
        .unwrap();
        let map = ClearanceMap::new(&grid, &ClearanceConfig::default()).unwrap();
        // Obstacle at (3, 2): the 3×3 block around it is not clear, the rest is
        // (except cells whose block leaves the grid: the outside is blocked).
        for y in 0..5 {
            for x in 0..7 {
                let c = Cell::new(x, y);
                let near_obstacle = (x - 3).abs() <= 1 && (y - 2).abs() <= 1;
                let near_border = x == 0 || y == 0 || x == 6 || y == 4;
                // Outside cells are not part of the distance transform, so the border itself
                // is clear unless near the obstacle; only in-grid blocked cells count.
                assert_eq!(
                    map.is_clear(c),
                    !near_obstacle,
                    "cell {c:?} border {near_border}"
                );
            }
        }
        assert!(!map.is_clear(Cell::new(-1, 0)));
        assert!(map.segment_is_clear(Cell::new(0, 0), Cell::new(6, 0)));
        assert!(!map.segment_is_clear(Cell::new(0, 2), Cell::new(6, 2)));
    }

    #[test]
    fn unknown_blocks_only_when_configured() {
        let grid = OccupancyGrid::from_ascii(&["?....", ".....", "....."], 0.05).unwrap();
        let strict = ClearanceMap::new(&grid, &ClearanceConfig::default()).unwrap();
        assert!(!strict.is_clear(Cell::new(1, 1)));
        let lax = ClearanceMap::new(
            &grid,
            &ClearanceConfig {
                unknown_is_blocked: false,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(lax.is_clear(Cell::new(1, 1)));
    }

    #[test]
    fn escape_allows_leaving_the_margin_but_not_crossing_obstacles() {
        let grid = OccupancyGrid::from_ascii(
            &[
                "........", //
                "#.......", //
                "........", //
                "........",
            ],
            0.05,
        )
        .unwrap();
        let map = ClearanceMap::new(&grid, &ClearanceConfig::default()).unwrap();
        let start = Cell::new(1, 2);
        assert!(!map.is_clear(start));
        assert!(map.escape_segment_is_ok(start, Cell::new(4, 2)));
        assert!(
            !map.escape_segment_is_ok(start, Cell::new(1, 1)),
            "ends unclear"
        );
        assert!(!map.escape_segment_is_ok(Cell::new(3, 2), Cell::new(-1, 2)));
    }
}
