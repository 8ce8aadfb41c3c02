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
    /// The narrowest robot width (in cells) for which a robot DISC of `radius_m` centred on any
    /// clear cell overlaps no blocked cell's square, on a grid of `resolution_m` cells (unknown
    /// cells block). A blocked cell at integer offset (dx, dy) from the robot's cell comes as
    /// close as √(max(|dx|−½,0)² + max(|dy|−½,0)²) cells to the robot's centre; every offset
    /// closer than the radius must lie within the clearance radius, so the clearance radius is
    /// the largest centre distance √(dx²+dy²) among those offsets (plus a hair for rounding).
    /// Why: SPEC §6's 3 cells (0.15 m) lets the centre come within 2 cells (0.10 m) of a
    /// blocked cell's centre, i.e. 0.075 m of its edge, so the simulator's 0.1 m-radius agent
    /// would touch walls the map shows; 0.1 m at 5 cm cells gives √5·2 ≈ 4.47 cells.
    pub fn for_disc(radius_m: f64, resolution_m: f64) -> Result<Self, PlanningError> {
        require(
            radius_m.is_finite() && radius_m >= 0.0,
            "ClearanceConfig::for_disc radius",
            "must be finite and non-negative",
        )?;
        require(
            resolution_m.is_finite() && resolution_m > 0.0,
            "ClearanceConfig::for_disc resolution",
            "must be finite and positive",
        )?;
        let r = radius_m / resolution_m;
        let reach = r.ceil() as i64 + 1;
        let mut radius_cells = 0.0f64;
        for dx in 0..=reach {
            for dy in 0..=reach {
                let gap = |d: i64| (d as f64 - 0.5).max(0.0);
                if gap(dx).hypot(gap(dy)) < r {
                    radius_cells = radius_cells.max((dx as f64).hypot(dy as f64));
                }
            }
        }
        Ok(Self {
            robot_width_cells: 2.0 * (radius_cells + 1e-6),
            unknown_is_blocked: true,
        })
    }

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

    /// How far (cells) one escape move may go: the clearance radius plus one cell, enough to
    /// leave the margin from any cell next to an obstacle.
    pub fn escape_radius_cells(&self) -> f64 {
        self.radius_cells + 1.0
    }

    /// The relaxed check used when the robot starts inside the clearance margin (after a
    /// slide or a map update): the segment may not touch a blocked cell other than `a` itself,
    /// it must end on a clear cell, so the robot can only move out of the margin, and it is at
    /// most [`ClearanceMap::escape_radius_cells`] long, so it cannot graze a wall for long.
    pub fn escape_segment_is_ok(&self, a: Cell, b: Cell) -> bool {
        a.distance(&b) <= self.escape_radius_cells()
            && self.is_clear(b)
            && for_each_supercover_cell(a, b, |c| c == a || !self.is_blocked(c))
    }

    /// Where a search from `start` may go first: `start` itself when it is clear, otherwise
    /// every cell one escape move away ([`ClearanceMap::escape_segment_is_ok`]), in row-major
    /// order. A* and the frontier path distances both begin here, so a frontier reported
    /// reachable is one A* can plan to.
    pub fn escape_targets(&self, start: Cell) -> Vec<Cell> {
        if self.is_clear(start) {
            return vec![start];
        }
        let r = self.escape_radius_cells();
        let reach = r.floor() as i32;
        let mut out = Vec::new();
        for dy in -reach..=reach {
            for dx in -reach..=reach {
                let b = start.offset(dx, dy);
                if b != start && self.escape_segment_is_ok(start, b) {
                    out.push(b);
                }
            }
        }
        out
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

    /// Independent geometric check of [`ClearanceConfig::for_disc`]: on seeded random grids, a
    /// 0.1 m disc around every clear cell's centre misses every blocked cell's square (exact
    /// point-to-square distance), while the SPEC's 3-cell width lets the disc touch walls, and
    /// the width is the narrowest that works (the next smaller offset distance fails).
    #[test]
    fn disc_clearance_keeps_the_agent_disc_off_every_blocked_cell() {
        use rand::{Rng, SeedableRng};
        let (radius, res) = (0.1, 0.05);
        let config = ClearanceConfig::for_disc(radius, res).unwrap();
        assert!((config.robot_width_cells - 2.0 * 5f64.sqrt()).abs() < 1e-5);
        let touches = |map: &ClearanceMap, grid: &OccupancyGrid| {
            let g = grid.geometry;
            let mut touched = false;
            for y in 0..g.height as i64 {
                for x in 0..g.width as i64 {
                    if !map.is_clear(Cell::new(x as i32, y as i32)) {
                        continue;
                    }
                    for by in 0..g.height as i64 {
                        for bx in 0..g.width as i64 {
                            if !map.is_blocked(Cell::new(bx as i32, by as i32)) {
                                continue;
                            }
                            let gap = |d: i64| ((d.abs() as f64) - 0.5).max(0.0) * res;
                            if gap(bx - x).hypot(gap(by - y)) < radius - 1e-12 {
                                touched = true;
                            }
                        }
                    }
                }
            }
            touched
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(6);
        let mut narrow_touched = 0;
        for _ in 0..20 {
            let rows: Vec<String> = (0..14)
                .map(|_| {
                    (0..14)
                        .map(|_| if rng.random::<f64>() < 0.03 { '#' } else { '.' })
                        .collect()
                })
                .collect();
            let rows: Vec<&str> = rows.iter().map(|r| r.as_str()).collect();
            let grid = OccupancyGrid::from_ascii(&rows, res).unwrap();
            let map = ClearanceMap::new(&grid, &config).unwrap();
            assert!(
                !touches(&map, &grid),
                "disc touches a blocked cell:\n{rows:?}"
            );
            let narrow = ClearanceConfig {
                robot_width_cells: 2.0 * 2.0,
                ..config
            };
            if touches(&ClearanceMap::new(&grid, &narrow).unwrap(), &grid) {
                narrow_touched += 1;
            }
            let spec = ClearanceMap::new(&grid, &ClearanceConfig::default()).unwrap();
            assert!(touches(&spec, &grid) || rows.iter().all(|r| !r.contains('#')));
        }
        assert!(narrow_touched > 0, "a radius of 2 cells must be too small");
        assert!(ClearanceConfig::for_disc(-1.0, res).is_err());
        assert!(ClearanceConfig::for_disc(radius, 0.0).is_err());
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
        assert!(map.escape_segment_is_ok(start, Cell::new(3, 2)));
        assert!(
            map.is_clear(Cell::new(4, 2)) && !map.escape_segment_is_ok(start, Cell::new(4, 2)),
            "longer than the escape radius"
        );
        assert_eq!(map.escape_radius_cells(), 2.5);
        let targets = map.escape_targets(start);
        assert!(targets.contains(&Cell::new(3, 2)) && !targets.contains(&Cell::new(1, 1)));
        assert!(targets.iter().all(|t| map.escape_segment_is_ok(start, *t)));
        assert_eq!(map.escape_targets(Cell::new(4, 2)), vec![Cell::new(4, 2)]);
        assert!(
            !map.escape_segment_is_ok(start, Cell::new(1, 1)),
            "ends unclear"
        );
        assert!(!map.escape_segment_is_ok(Cell::new(3, 2), Cell::new(-1, 2)));
    }
}
