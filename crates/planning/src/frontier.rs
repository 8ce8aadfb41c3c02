//! Frontiers (SPEC §6): `(3×3 dilation of the free space connected to the robot − free space)
//! ∩ unknown`, grouped into 8-connected regions of more than `min_region_cells` cells. Each
//! region gets its size, centroid and the reachable cell closest to the robot by path length
//! from which the robot can look into it (its *approach* cell): preferably within the
//! approach radius of the region's middle cell (its *anchor*), else of any of its cells, and
//! always with a line of sight to that cell.
//!
//! Reachability for the approach uses the robot-width check of [`ClearanceMap`]: a path
//! distance is an 8-connected Dijkstra distance over swept-clear moves, after the escape move
//! A* also makes when the robot is inside the clearance margin ([`path_distances`]).

use std::cmp::Ordering;
use std::collections::{BinaryHeap, VecDeque};

use nalgebra::Point2;
use serde::{Deserialize, Serialize};

use crate::clearance::ClearanceMap;
use crate::error::{PlanningError, require};
use crate::grid::{Cell, CellState, Grid, OccupancyGrid};
use crate::segment::for_each_supercover_cell;

/// Settings of the frontier extraction.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrontierConfig {
    /// Regions need MORE than this many cells (SPEC: 5).
    pub min_region_cells: usize,
    /// The approach cell lies within this many cells (Euclidean) of a cell of the region.
    pub approach_radius_cells: f64,
}

impl Default for FrontierConfig {
    fn default() -> Self {
        Self {
            min_region_cells: 5,
            approach_radius_cells: 4.0,
        }
    }
}

/// The cell from which the robot reaches a region, and its path distance from the robot.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Approach {
    /// A clear, reachable cell near the region.
    pub cell: Cell,
    /// Path length from the robot to it, metres.
    pub path_distance_m: f64,
}

/// One connected frontier region.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrontierRegion {
    /// Its cells, in row-major order.
    pub cells: Vec<Cell>,
    /// Mean of the cell centres, world metres.
    pub centroid: Point2<f64>,
    /// The region cell nearest the centroid (a representative cell on the frontier itself,
    /// e.g. to label the region on a map).
    pub anchor: Cell,
    /// The closest reachable approach cell; `None` when the robot cannot get near it.
    pub approach: Option<Approach>,
}

impl FrontierRegion {
    /// Number of cells.
    pub fn size(&self) -> usize {
        self.cells.len()
    }
}

/// Everything the frontier extraction found.
#[derive(Debug, Clone, PartialEq)]
pub struct Frontiers {
    /// Every frontier cell (including those of regions too small to keep).
    pub is_frontier: Grid<bool>,
    /// Free cells 8-connected to the robot.
    pub reachable_free: Grid<bool>,
    /// Path distance (metres) from the robot over clear cells; +∞ where unreachable.
    pub path_distance_m: Grid<f64>,
    /// Regions larger than the minimum size, in row-major order of their first cell.
    pub regions: Vec<FrontierRegion>,
}

const NEIGHBOURS8: [(i32, i32); 8] = [
    (1, 0),
    (-1, 0),
    (0, 1),
    (0, -1),
    (1, 1),
    (1, -1),
    (-1, 1),
    (-1, -1),
];

#[derive(PartialEq)]
struct Queued(f64, usize);
impl Eq for Queued {}
impl Ord for Queued {
    fn cmp(&self, o: &Self) -> Ordering {
        o.0.total_cmp(&self.0).then(o.1.cmp(&self.1))
    }
}
impl PartialOrd for Queued {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}

/// Path distances (metres) from `start`: a straight move to each of
/// [`ClearanceMap::escape_targets`] (the start itself when it is clear), then 8-connected
/// moves (diagonal √2) that pass the swept check. These are the first moves and the 1-cell
/// moves of A*, so every cell with a finite distance is one [`crate::astar::plan`] reaches.
pub fn path_distances(map: &ClearanceMap, start: Cell) -> Grid<f64> {
    let g = *map.geometry();
    let mut dist = Grid::filled(g, f64::INFINITY);
    let Some(s) = g.index(start) else { return dist };
    let mut heap = BinaryHeap::new();
    dist.data[s] = 0.0;
    for t in map.escape_targets(start) {
        if let Some(j) = g.index(t) {
            let d = t.distance(&start) * g.resolution;
            dist.data[j] = d;
            heap.push(Queued(d, j));
        }
    }
    while let Some(Queued(d, i)) = heap.pop() {
        if d > dist.data[i] {
            continue;
        }
        let c = g.cell_at(i);
        for (dx, dy) in NEIGHBOURS8 {
            let n = c.offset(dx, dy);
            let Some(j) = g.index(n) else { continue };
            if !map.segment_is_clear(c, n) {
                continue;
            }
            let step = if dx != 0 && dy != 0 {
                std::f64::consts::SQRT_2
            } else {
                1.0
            };
            let nd = d + step * g.resolution;
            if nd < dist.data[j] {
                dist.data[j] = nd;
                heap.push(Queued(nd, j));
            }
        }
    }
    dist
}

/// The regions a planner chooses among, as the `frontier` operator publishes them: those of
/// [`extract_frontiers`] (robot-width check `clearance`) that have an approach cell, largest
/// first (a stable sort, so equal sizes keep the row-major order). The in-process explorer and
/// the operator both call this, so their FBE decisions see the same list in the same order.
pub fn reachable_regions(
    grid: &OccupancyGrid,
    robot: Point2<f64>,
    clearance: &crate::clearance::ClearanceConfig,
    config: &FrontierConfig,
) -> Result<Vec<FrontierRegion>, PlanningError> {
    let map = ClearanceMap::new(grid, clearance)?;
    let found = extract_frontiers(grid, &map, robot, config)?;
    let mut regions: Vec<FrontierRegion> = found
        .regions
        .into_iter()
        .filter(|r| r.approach.is_some())
        .collect();
    regions.sort_by_key(|r| std::cmp::Reverse(r.size()));
    Ok(regions)
}

/// Extracts the frontier regions of `grid` as seen from the robot at `robot` (world metres).
/// `map` must be built from the same grid.
pub fn extract_frontiers(
    grid: &OccupancyGrid,
    map: &ClearanceMap,
    robot: Point2<f64>,
    config: &FrontierConfig,
) -> Result<Frontiers, PlanningError> {
    require(
        config.approach_radius_cells.is_finite() && config.approach_radius_cells >= 0.0,
        "FrontierConfig::approach_radius_cells",
        "must be finite and non-negative",
    )?;
    let g = grid.geometry;
    if *map.geometry() != g {
        return Err(PlanningError::InvalidGrid(
            "clearance map was built on a different grid than the occupancy grid".into(),
        ));
    }
    let start = g.require_cell(robot, "robot position")?;
    // Free space connected to the robot (the robot's own cell always counts).
    let mut reachable = Grid::filled(g, false);
    let mut queue = VecDeque::new();
    if let Some(i) = g.index(start) {
        reachable.data[i] = true;
        queue.push_back(start);
    }
    while let Some(c) = queue.pop_front() {
        for (dx, dy) in NEIGHBOURS8 {
            let n = c.offset(dx, dy);
            if let Some(j) = g.index(n)
                && !reachable.data[j]
                && grid.data[j] == CellState::Free
            {
                reachable.data[j] = true;
                queue.push_back(n);
            }
        }
    }
    // Unknown cells in the 3×3 dilation of the reachable free space.
    let mut is_frontier = Grid::filled(g, false);
    for i in 0..g.len() {
        if grid.data[i] != CellState::Unknown {
            continue;
        }
        let c = g.cell_at(i);
        is_frontier.data[i] = NEIGHBOURS8
            .iter()
            .any(|(dx, dy)| reachable.get(c.offset(*dx, *dy)).copied().unwrap_or(false));
    }
    let path_distance_m = path_distances(map, start);
    // 8-connected components of frontier cells.
    let mut visited = Grid::filled(g, false);
    let mut regions = Vec::new();
    for i in 0..g.len() {
        if !is_frontier.data[i] || visited.data[i] {
            continue;
        }
        let mut cells = Vec::new();
        visited.data[i] = true;
        queue.push_back(g.cell_at(i));
        while let Some(c) = queue.pop_front() {
            cells.push(c);
            for (dx, dy) in NEIGHBOURS8 {
                let n = c.offset(dx, dy);
                if let Some(j) = g.index(n)
                    && is_frontier.data[j]
                    && !visited.data[j]
                {
                    visited.data[j] = true;
                    queue.push_back(n);
                }
            }
        }
        if cells.len() <= config.min_region_cells {
            continue;
        }
        cells.sort_by_key(|c| (c.y, c.x));
        let n = cells.len() as f64;
        let sum = cells.iter().fold(nalgebra::Vector2::zeros(), |acc, c| {
            acc + g.center(*c).coords
        });
        let centroid = Point2::from(sum / n);
        let anchor = *cells
            .iter()
            .min_by(|a, b| {
                let da = (g.center(**a) - centroid).norm();
                let db = (g.center(**b) - centroid).norm();
                da.total_cmp(&db)
            })
            .unwrap_or(&cells[0]);
        // Prefer an approach near the middle of the region (from there the robot sees most
        // of it); fall back to any cell of the region.
        let r = config.approach_radius_cells;
        let approach = closest_approach(grid, &[anchor], &path_distance_m, r)
            .or_else(|| closest_approach(grid, &cells, &path_distance_m, r));
        regions.push(FrontierRegion {
            centroid,
            anchor,
            cells,
            approach,
        });
    }
    Ok(Frontiers {
        is_frontier,
        reachable_free: reachable,
        path_distance_m,
        regions,
    })
}

/// The reached cell within `radius` of a cell of `cells`, with a line of sight to it (no
/// occupied cell on the supercover between them), with the smallest path distance (ties:
/// lowest row, then column).
fn closest_approach(
    grid: &OccupancyGrid,
    cells: &[Cell],
    dist: &Grid<f64>,
    radius: f64,
) -> Option<Approach> {
    let g = dist.geometry;
    let r = radius.floor() as i32;
    let mut best: Option<Approach> = None;
    for c in cells {
        for dy in -r..=r {
            for dx in -r..=r {
                if ((dx * dx + dy * dy) as f64) > radius * radius {
                    continue;
                }
                let n = c.offset(dx, dy);
                let Some(i) = g.index(n) else { continue };
                let d = dist.data[i];
                if !d.is_finite() {
                    continue;
                }
                let better = match best {
                    None => true,
                    Some(b) => {
                        d < b.path_distance_m
                            || (d == b.path_distance_m && (n.y, n.x) < (b.cell.y, b.cell.x))
                    }
                };
                let sees = || {
                    for_each_supercover_cell(n, *c, |x| grid.get(x) != Some(&CellState::Occupied))
                };
                if better && sees() {
                    best = Some(Approach {
                        cell: n,
                        path_distance_m: d,
                    });
                }
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clearance::ClearanceConfig;

    fn setup(rows: &[&str]) -> (OccupancyGrid, ClearanceMap) {
        let grid = OccupancyGrid::from_ascii(rows, 0.05).unwrap();
        let map = ClearanceMap::new(&grid, &ClearanceConfig::default()).unwrap();
        (grid, map)
    }

    #[test]
    fn frontier_regions_on_a_hand_made_room() {
        // A closed room whose right wall has an 8-cell opening onto unknown space, plus an
        // unknown pocket behind a wall (not adjacent to reachable free space: no frontier) and a
        // small unknown speck inside the room (frontier of 1 cell: below the size limit).
        let rows = [
            "##############????", //
            "#............#????", //
            "#............#????", //
            "#............?????", //
            "#............?????", //
            "#.....?......?????", //
            "#............?????", //
            "#............?????", //
            "#............?????", //
            "#............?????", //
            "#............#????", //
            "##############????", //
            "??????????????????",
        ];
        let (grid, map) = setup(&rows);
        let robot = grid.geometry.center(Cell::new(3, 6));
        let f = extract_frontiers(&grid, &map, robot, &FrontierConfig::default()).unwrap();
        assert_eq!(f.regions.len(), 1, "{:?}", f.regions);
        let region = &f.regions[0];
        // The opening: column 13, rows y = 3..=9 (ascii rows 3..=9 of 13); column 14 does not
        // touch the free space.
        let want: Vec<Cell> = (3..=9).map(|y| Cell::new(13, y)).collect();
        assert_eq!(region.cells, want);
        assert_eq!(region.size(), 7);
        let c = grid.geometry.center(Cell::new(13, 6));
        assert!((region.centroid - c).norm() < 1e-9);
        // The speck (1 cell) is a frontier cell but no region.
        assert!(f.is_frontier.get(Cell::new(6, 7)).copied().unwrap());
        assert_eq!(f.is_frontier.data.iter().filter(|v| **v).count(), 8);
        // The approach is clear and within 4 cells of the region.
        let a = region.approach.expect("reachable");
        assert!(map.is_clear(a.cell));
        assert!(
            (a.path_distance_m - f.path_distance_m.get(a.cell).copied().unwrap()).abs() < 1e-12
        );
        assert!(region.cells.iter().any(|c| c.distance(&a.cell) <= 4.0));
        // By hand: the anchor is the middle cell (13, 6); clear cells keep 2 cells from blocked
        // ones, so the speck (6, 7) closes row 6 at x = 5..=7; the nearest cell within 4 of
        // the anchor is (9, 6), reached by (3,6) → (4,5) diagonally, 4 cells along row 5,
        // and a diagonal up: 0.05·(4 + 2√2) m.
        assert_eq!(region.anchor, Cell::new(13, 6));
        assert_eq!(a.cell, Cell::new(9, 6));
        assert!((a.path_distance_m - 0.05 * (4.0 + 2.0 * std::f64::consts::SQRT_2)).abs() < 1e-9);
    }

    #[test]
    fn two_regions_and_unreachable_free_space() {
        // Left room reachable; right room free but walled off: its boundary with unknown is not
        // a frontier. Two openings on the left room (top and bottom) give two regions.
        let rows = [
            "????????????????????", //
            "#..........#########", //
            "#..........#.......#", //
            "#..........#.......?", //
            "#..........#.......?", //
            "#..........#.......?", //
            "#..........#.......#", //
            "#..........#########", //
            "????????????????????",
        ];
        let (grid, map) = setup(&rows);
        let robot = grid.geometry.center(Cell::new(5, 4));
        let f = extract_frontiers(&grid, &map, robot, &FrontierConfig::default()).unwrap();
        assert_eq!(f.regions.len(), 2);
        // Bottom (y = 0) first in row-major order: unknown cells x = 0..=11 touch free x 1..=10.
        assert_eq!(
            f.regions[0].cells,
            (0..=11).map(|x| Cell::new(x, 0)).collect::<Vec<_>>()
        );
        assert_eq!(
            f.regions[1].cells,
            (0..=11).map(|x| Cell::new(x, 8)).collect::<Vec<_>>()
        );
        assert!(!f.is_frontier.get(Cell::new(19, 4)).copied().unwrap());
        // Smaller minimum size removes nothing; a larger one removes both.
        let big = FrontierConfig {
            min_region_cells: 12,
            ..Default::default()
        };
        assert!(
            extract_frontiers(&grid, &map, robot, &big)
                .unwrap()
                .regions
                .is_empty()
        );
    }

    #[test]
    fn the_approach_cell_sees_its_region_through_no_wall() {
        // The frontier lies behind a 2-cell wall, 3 cells from the free cells below it, but
        // the only line of sight is through the door on the left.
        let rows = [
            "?????????????????", //
            "?????????????????", //
            "......???????????", //
            "......???????????", //
            "......###########", //
            "......###########", //
            ".................", //
            ".................", //
            ".................", //
            ".................", //
            ".................",
        ];
        let (grid, map) = setup(&rows);
        let robot = grid.geometry.center(Cell::new(12, 2));
        let f = extract_frontiers(&grid, &map, robot, &FrontierConfig::default()).unwrap();
        for r in &f.regions {
            let a = r.approach.unwrap();
            // Cells right below the wall (y ≤ 4, x ≥ 8) are within 4 of the region cells at
            // y = 7..8 only through the wall; the approach must be on the door side (x ≤ 5).
            assert!(
                a.cell.x <= 5 || a.cell.y >= 7,
                "approach {a:?} looks through the wall"
            );
        }
    }

    #[test]
    fn outside_robot_is_an_error() {
        let (grid, map) = setup(&["...", "..."]);
        assert!(matches!(
            extract_frontiers(
                &grid,
                &map,
                Point2::new(5.0, 5.0),
                &FrontierConfig::default()
            ),
            Err(PlanningError::OutsideGrid { .. })
        ));
    }
}
