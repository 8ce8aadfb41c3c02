//! A* on a lattice of 3-cell moves in 8 directions (SPEC §6, release: 0.15 m neighbours "to
//! prevent a twisted path"), with the robot-width swept collision check of
//! [`ClearanceMap`] and an extra cost near obstacles from the distance transform.
//!
//! Edge cost (metres): `len · (1 + w · mean_c max(0, 1 − d(c)/influence))` over the cells `c`
//! of the move's supercover except its first, `d` the distance to the nearest blocked cell.
//! The heuristic `max(0, |n − goal| − tolerance)` (metres) never overestimates, so the path is
//! optimal on the lattice among paths ending within the goal tolerance.
//!
//! The lattice keeps `x mod 3` and `y mod 3` of every node fixed, so it cannot thread a
//! passage whose only clear cells lie off it. When the lattice finds nothing, the search runs
//! again with 1-cell moves ([`AstarConfig::fine_fallback`]); from the same first moves
//! ([`ClearanceMap::escape_targets`]) that is the graph the frontier path distances use, so a
//! frontier reported reachable always gets a path (shortcutting then straightens it).

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use nalgebra::Point2;
use serde::{Deserialize, Serialize};

use crate::clearance::ClearanceMap;
use crate::error::{PlanningError, require};
use crate::grid::{Cell, GridGeometry};
use crate::segment::for_each_supercover_cell;

/// Settings of the A* planner.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AstarConfig {
    /// Move length in cells along each axis (release: 3 = 0.15 m at 5 cm cells).
    pub step_cells: i32,
    /// Weight `w` of the proximity cost (0 = shortest path).
    pub proximity_weight: f64,
    /// Distance (metres) from a blocked cell beyond which no extra cost applies.
    pub proximity_influence_m: f64,
    /// A node within this many cells of the goal ends the search (1.5 reaches every cell from
    /// a 3-cell lattice).
    pub goal_tolerance_cells: f64,
    /// Connect to the exact goal cell: from any node within one diagonal move (`step·√2`
    /// cells) a direct collision-free move to the goal also ends the search, and a path ending
    /// within the tolerance gets the goal appended when that last move is collision-free.
    /// This reaches goals whose lattice neighbours are all too close to obstacles.
    pub snap_to_goal: bool,
    /// Give up (no path) after this many node expansions.
    pub max_expansions: usize,
    /// When the lattice finds no path, search again with 1-cell moves (see the module doc).
    pub fine_fallback: bool,
}

impl Default for AstarConfig {
    fn default() -> Self {
        Self {
            step_cells: 3,
            proximity_weight: 1.0,
            proximity_influence_m: 0.3,
            goal_tolerance_cells: 1.5,
            snap_to_goal: true,
            max_expansions: 2_000_000,
            fine_fallback: true,
        }
    }
}

impl AstarConfig {
    /// Checks the ranges of every field.
    pub fn validate(&self) -> Result<(), PlanningError> {
        require(
            self.step_cells >= 1,
            "AstarConfig::step_cells",
            "must be at least 1",
        )?;
        require(
            self.proximity_weight.is_finite() && self.proximity_weight >= 0.0,
            "AstarConfig::proximity_weight",
            "must be finite and non-negative",
        )?;
        require(
            self.proximity_influence_m.is_finite() && self.proximity_influence_m > 0.0,
            "AstarConfig::proximity_influence_m",
            "must be finite and positive",
        )?;
        require(
            self.goal_tolerance_cells.is_finite() && self.goal_tolerance_cells >= 0.0,
            "AstarConfig::goal_tolerance_cells",
            "must be finite and non-negative",
        )
    }
}

/// A path of cell waypoints from the start and its total cost (metres, proximity included).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GridPath {
    /// Waypoints, the start first.
    pub cells: Vec<Cell>,
    /// Sum of [`edge_cost`] over consecutive waypoints.
    pub cost: f64,
}

impl GridPath {
    /// The waypoints as world points (cell centres).
    pub fn to_world(&self, geometry: &GridGeometry) -> Vec<Point2<f64>> {
        self.cells.iter().map(|c| geometry.center(*c)).collect()
    }

    /// Geometric length in metres.
    pub fn length_m(&self, geometry: &GridGeometry) -> f64 {
        self.cells
            .windows(2)
            .map(|w| w[0].distance(&w[1]) * geometry.resolution)
            .sum()
    }
}

/// The 8 lattice moves of `step` cells.
pub fn lattice_moves(step: i32) -> [(i32, i32); 8] {
    [
        (step, 0),
        (-step, 0),
        (0, step),
        (0, -step),
        (step, step),
        (step, -step),
        (-step, step),
        (-step, -step),
    ]
}

/// Cost of moving from `a` to `b` (see the module doc).
pub fn edge_cost(map: &ClearanceMap, a: Cell, b: Cell, config: &AstarConfig) -> f64 {
    let res = map.geometry().resolution;
    let length = a.distance(&b) * res;
    if config.proximity_weight == 0.0 {
        return length;
    }
    let (mut sum, mut n) = (0.0, 0usize);
    for_each_supercover_cell(a, b, |c| {
        if c != a {
            let d = map.distance().distance_m(c);
            sum += (1.0 - d / config.proximity_influence_m).max(0.0);
            n += 1;
        }
        true
    });
    let mean = if n > 0 { sum / n as f64 } else { 0.0 };
    length * (1.0 + config.proximity_weight * mean)
}

/// Whether the move `a → b` is allowed for a search that started at `start`: the swept check,
/// or the escape rule of [`ClearanceMap::escape_segment_is_ok`] for the first move out of a
/// start inside the clearance margin.
pub fn move_is_allowed(map: &ClearanceMap, start: Cell, a: Cell, b: Cell) -> bool {
    if a == start && !map.is_clear(start) {
        map.escape_segment_is_ok(a, b)
    } else {
        map.segment_is_clear(a, b)
    }
}

#[derive(PartialEq)]
struct Open {
    f: f64,
    g: f64,
    index: usize,
}

impl Eq for Open {}

impl Ord for Open {
    fn cmp(&self, other: &Self) -> Ordering {
        // Min-heap on f, then prefer deeper nodes (larger g), then the index for determinism.
        other
            .f
            .total_cmp(&self.f)
            .then(self.g.total_cmp(&other.g))
            .then(other.index.cmp(&self.index))
    }
}

impl PartialOrd for Open {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// Plans from cell `start` to within the goal tolerance of cell `goal`: on the lattice of
/// [`AstarConfig::step_cells`] moves, then, if that fails and [`AstarConfig::fine_fallback`]
/// is set, with 1-cell moves. The first move out of a start inside the clearance margin goes
/// to one of [`ClearanceMap::escape_targets`]. `Ok(None)` when no path exists (or the
/// expansion budget runs out); errors on cells outside the grid or a bad configuration.
pub fn plan(
    map: &ClearanceMap,
    start: Cell,
    goal: Cell,
    config: &AstarConfig,
) -> Result<Option<GridPath>, PlanningError> {
    config.validate()?;
    let found = search(map, start, goal, config, config.step_cells)?;
    if found.is_some() || !config.fine_fallback || config.step_cells == 1 {
        return Ok(found);
    }
    search(map, start, goal, config, 1)
}

/// One A* search with moves of `step` cells (see [`plan`]).
fn search(
    map: &ClearanceMap,
    start: Cell,
    goal: Cell,
    config: &AstarConfig,
    step: i32,
) -> Result<Option<GridPath>, PlanningError> {
    let geom = *map.geometry();
    let start_index = geom.index(start).ok_or(PlanningError::OutsideGrid {
        what: "A* start",
        x: geom.center(start).x,
        y: geom.center(start).y,
    })?;
    if !geom.contains(goal) {
        let p = geom.center(goal);
        return Err(PlanningError::OutsideGrid {
            what: "A* goal",
            x: p.x,
            y: p.y,
        });
    }
    let res = geom.resolution;
    let heuristic = |c: Cell| ((c.distance(&goal) - config.goal_tolerance_cells).max(0.0)) * res;
    let mut g = vec![f64::INFINITY; geom.len()];
    let mut parent = vec![usize::MAX; geom.len()];
    let mut closed = vec![false; geom.len()];
    let mut open = BinaryHeap::new();
    g[start_index] = 0.0;
    open.push(Open {
        f: heuristic(start),
        g: 0.0,
        index: start_index,
    });
    let lattice = lattice_moves(step);
    // From a start inside the margin, the first moves are the escape moves.
    let escapes: Option<Vec<(i32, i32)>> = (!map.is_clear(start)).then(|| {
        map.escape_targets(start)
            .into_iter()
            .map(|c| (c.x - start.x, c.y - start.y))
            .collect()
    });
    let snap_reach = step as f64 * std::f64::consts::SQRT_2 + 1e-9;
    let goal_index = geom.index(goal).unwrap_or(start_index);
    let mut expansions = 0usize;
    let mut reached = None;
    while let Some(Open { g: gn, index, .. }) = open.pop() {
        if closed[index] || gn > g[index] {
            continue;
        }
        closed[index] = true;
        let cell = geom.cell_at(index);
        if cell == goal || cell.distance(&goal) <= config.goal_tolerance_cells {
            reached = Some(index);
            break;
        }
        expansions += 1;
        if expansions > config.max_expansions {
            return Ok(None);
        }
        let moves: &[(i32, i32)] = match &escapes {
            Some(escapes) if cell == start => escapes,
            _ => &lattice,
        };
        for &(dx, dy) in moves {
            let next = cell.offset(dx, dy);
            let Some(ni) = geom.index(next) else { continue };
            if closed[ni] || !move_is_allowed(map, start, cell, next) {
                continue;
            }
            let cand = gn + edge_cost(map, cell, next, config);
            if cand < g[ni] {
                g[ni] = cand;
                parent[ni] = index;
                open.push(Open {
                    f: cand + heuristic(next),
                    g: cand,
                    index: ni,
                });
            }
        }
        if config.snap_to_goal
            && cell.distance(&goal) <= snap_reach
            && !closed[goal_index]
            && move_is_allowed(map, start, cell, goal)
        {
            let cand = gn + edge_cost(map, cell, goal, config);
            if cand < g[goal_index] {
                g[goal_index] = cand;
                parent[goal_index] = index;
                open.push(Open {
                    f: cand,
                    g: cand,
                    index: goal_index,
                });
            }
        }
    }
    let Some(end) = reached else { return Ok(None) };
    let mut cells = vec![geom.cell_at(end)];
    let mut i = end;
    while parent[i] != usize::MAX {
        i = parent[i];
        cells.push(geom.cell_at(i));
    }
    cells.reverse();
    let mut cost = g[end];
    let last = *cells.last().unwrap_or(&start);
    if config.snap_to_goal && last != goal && move_is_allowed(map, start, last, goal) {
        cost += edge_cost(map, last, goal, config);
        cells.push(goal);
    }
    Ok(Some(GridPath { cells, cost }))
}

/// [`plan`] between world points (each mapped to the cell that holds it).
pub fn plan_world(
    map: &ClearanceMap,
    start: Point2<f64>,
    goal: Point2<f64>,
    config: &AstarConfig,
) -> Result<Option<GridPath>, PlanningError> {
    let geom = map.geometry();
    let s = geom.require_cell(start, "A* start")?;
    let g = geom.require_cell(goal, "A* goal")?;
    plan(map, s, g, config)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clearance::ClearanceConfig;
    use crate::grid::{CellState, OccupancyGrid};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use std::collections::HashMap;

    fn random_grid(rng: &mut ChaCha8Rng, w: usize, h: usize, density: f64) -> OccupancyGrid {
        let g = GridGeometry::new(0.0, 0.0, 0.05, w, h).unwrap();
        let mut grid = OccupancyGrid::filled(g, CellState::Free);
        // Random rectangles of obstacles and a sprinkle of unknown cells.
        let n = (density * (w * h) as f64 / 6.0) as usize;
        for _ in 0..n {
            let (x, y) = (rng.random_range(0..w), rng.random_range(0..h));
            let (rw, rh) = (rng.random_range(1..4), rng.random_range(1..4));
            for yy in y..(y + rh).min(h) {
                for xx in x..(x + rw).min(w) {
                    grid.data[yy * w + xx] = CellState::Occupied;
                }
            }
        }
        for s in grid.data.iter_mut() {
            if *s == CellState::Free && rng.random_bool(0.03) {
                *s = CellState::Unknown;
            }
        }
        grid
    }

    /// Reference: plain Dijkstra over the same lattice (a sorted frontier scan, no heap, no
    /// heuristic), goal = any node within the tolerance.
    fn dijkstra_cost(
        map: &ClearanceMap,
        start: Cell,
        goal: Cell,
        cfg: &AstarConfig,
    ) -> Option<f64> {
        let geom = map.geometry();
        let mut dist: HashMap<Cell, f64> = HashMap::from([(start, 0.0)]);
        let mut done: Vec<Cell> = Vec::new();
        loop {
            let next = dist
                .iter()
                .filter(|(c, _)| !done.contains(c))
                .min_by(|a, b| a.1.total_cmp(b.1).then(a.0.cmp(b.0)))
                .map(|(c, d)| (*c, *d));
            let (c, d) = next?;
            if c.distance(&goal) <= cfg.goal_tolerance_cells {
                return Some(d);
            }
            done.push(c);
            let next: Vec<Cell> = if c == start && !map.is_clear(start) {
                map.escape_targets(start)
            } else {
                lattice_moves(cfg.step_cells)
                    .iter()
                    .map(|(dx, dy)| c.offset(*dx, *dy))
                    .collect()
            };
            for n in next {
                if !geom.contains(n) || !move_is_allowed(map, start, c, n) {
                    continue;
                }
                let nd = d + edge_cost(map, c, n, cfg);
                if dist.get(&n).is_none_or(|old| nd < *old) {
                    dist.insert(n, nd);
                }
            }
        }
    }

    /// Brute force: no blocked cell centre within the robot radius of any point of the path
    /// (dense samples, each in the cell that holds it, checked against every blocked cell).
    fn path_keeps_clearance(grid: &OccupancyGrid, path: &[Cell], radius: f64, unknown: bool) {
        let blocked: Vec<Cell> = (0..grid.data.len())
            .filter(|i| match grid.data[*i] {
                CellState::Occupied => true,
                CellState::Unknown => unknown,
                CellState::Free => false,
            })
            .map(|i| grid.geometry.cell_at(i))
            .collect();
        for (k, w) in path.windows(2).enumerate() {
            if k == 0 {
                continue; // the first move may use the escape rule
            }
            for s in 0..=400 {
                let t = s as f64 / 400.0;
                let x = w[0].x as f64 + t * (w[1].x - w[0].x) as f64;
                let y = w[0].y as f64 + t * (w[1].y - w[0].y) as f64;
                let c = Cell::new(x.round() as i32, y.round() as i32);
                for b in &blocked {
                    assert!(
                        c.distance(b) > radius,
                        "path {path:?} passes {c:?} near {b:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn astar_is_optimal_against_dijkstra_on_small_random_grids() {
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        let mut found = 0;
        for trial in 0..150 {
            let (w, h) = (rng.random_range(6..22), rng.random_range(6..22));
            let grid = random_grid(&mut rng, w, h, 0.25);
            let cc = ClearanceConfig {
                robot_width_cells: [3.0, 1.0, 0.0][trial % 3],
                unknown_is_blocked: trial % 4 != 0,
            };
            let map = ClearanceMap::new(&grid, &cc).unwrap();
            let cfg = AstarConfig {
                step_cells: [3, 1, 2][trial % 3],
                proximity_weight: [1.0, 0.0, 3.0][trial % 3],
                snap_to_goal: false,
                fine_fallback: false,
                ..Default::default()
            };
            let s = Cell::new(rng.random_range(0..w as i32), rng.random_range(0..h as i32));
            let g = Cell::new(rng.random_range(0..w as i32), rng.random_range(0..h as i32));
            let got = plan(&map, s, g, &cfg).unwrap();
            let want = dijkstra_cost(&map, s, g, &cfg);
            match (&got, want) {
                (None, None) => {}
                (Some(p), Some(c)) => {
                    found += 1;
                    assert!(
                        (p.cost - c).abs() < 1e-9,
                        "trial {trial}: A* {} vs {c}",
                        p.cost
                    );
                    let resum: f64 = p
                        .cells
                        .windows(2)
                        .map(|m| edge_cost(&map, m[0], m[1], &cfg))
                        .sum();
                    assert!((resum - p.cost).abs() < 1e-9);
                    assert_eq!(p.cells[0], s);
                    assert!(p.cells.last().unwrap().distance(&g) <= cfg.goal_tolerance_cells);
                    for m in p.cells.windows(2) {
                        assert!(move_is_allowed(&map, s, m[0], m[1]));
                        if m[0] == s && !map.is_clear(s) {
                            continue; // an escape move
                        }
                        let (dx, dy) = ((m[1].x - m[0].x).abs(), (m[1].y - m[0].y).abs());
                        assert!(dx == 0 || dx == cfg.step_cells);
                        assert!(dy == 0 || dy == cfg.step_cells);
                    }
                    path_keeps_clearance(
                        &grid,
                        &p.cells,
                        cc.robot_width_cells / 2.0,
                        cc.unknown_is_blocked,
                    );
                }
                _ => panic!("trial {trial}: A* {got:?} but Dijkstra {want:?}"),
            }
        }
        assert!(
            found > 40,
            "too few solvable cases ({found}) to mean anything"
        );
    }

    #[test]
    fn never_cuts_a_corner_between_diagonal_obstacles() {
        // A diagonal wall of single cells: crossing it needs a diagonal move between two
        // corner-touching obstacle cells, which the supercover check forbids even for a
        // zero-width robot.
        let g = GridGeometry::new(0.0, 0.0, 0.05, 8, 8).unwrap();
        let mut grid = OccupancyGrid::filled(g, CellState::Free);
        for i in 0..8 {
            grid.set(Cell::new(i, i), CellState::Occupied);
        }
        let cc = ClearanceConfig {
            robot_width_cells: 0.0,
            unknown_is_blocked: true,
        };
        let map = ClearanceMap::new(&grid, &cc).unwrap();
        let cfg = AstarConfig {
            step_cells: 1,
            goal_tolerance_cells: 0.0,
            ..Default::default()
        };
        assert_eq!(
            plan(&map, Cell::new(0, 7), Cell::new(7, 0), &cfg).unwrap(),
            None
        );
        // Same side: found.
        let p = plan(&map, Cell::new(0, 7), Cell::new(6, 7), &cfg)
            .unwrap()
            .unwrap();
        assert_eq!(*p.cells.last().unwrap(), Cell::new(6, 7));
        // Opening one gap of a full cell lets it through, orthogonally.
        grid.set(Cell::new(4, 4), CellState::Free);
        let map = ClearanceMap::new(&grid, &cc).unwrap();
        let p = plan(&map, Cell::new(0, 7), Cell::new(7, 0), &cfg)
            .unwrap()
            .unwrap();
        assert!(p.cells.contains(&Cell::new(4, 4)));
    }

    #[test]
    fn goes_around_a_wall_with_the_robot_width_and_snaps_to_the_goal() {
        let grid = OccupancyGrid::from_ascii(
            &[
                "....................", //
                "....................", //
                "....................", //
                "....................", //
                "....................", //
                "....................", //
                "..........#.........", //
                "..........#.........", //
                "..........#.........", //
                "..........#.........", //
                "..........#.........", //
                "..........#.........", //
                "..........#.........",
            ],
            0.05,
        )
        .unwrap();
        let map = ClearanceMap::new(&grid, &ClearanceConfig::default()).unwrap();
        let (s, g) = (Cell::new(2, 1), Cell::new(16, 1));
        let p = plan(&map, s, g, &AstarConfig::default()).unwrap().unwrap();
        assert_eq!(*p.cells.last().unwrap(), g, "snapped to the exact goal");
        // Going around the wall top (y = 6 is the wall's end) needs y ≥ 8 for clearance; the
        // lattice from y = 1 offers y = 10.
        assert!(p.cells.iter().any(|c| c.y >= 8), "{:?}", p.cells);
        path_keeps_clearance(&grid, &p.cells, 1.5, true);
        assert!(p.cost >= p.length_m(&grid.geometry) - 1e-12);
        // With the proximity cost off, cost equals length.
        let flat = AstarConfig {
            proximity_weight: 0.0,
            ..Default::default()
        };
        let q = plan(&map, s, g, &flat).unwrap().unwrap();
        assert!((q.cost - q.length_m(&grid.geometry)).abs() < 1e-12);
    }

    #[test]
    fn snapping_reaches_a_goal_whose_lattice_neighbours_are_blocked() {
        // A free pocket: the goal (9, 4) is clear, but every lattice node from (0, 4) within
        // 1.5 cells of it is too close to the walls; only a direct 2-cell move reaches it.
        let grid = OccupancyGrid::from_ascii(
            &[
                "##############", //
                "........######", //
                "..............", //
                "..............", //
                "..............", //
                "..............", //
                "..............", //
                "........######", //
                "##############",
            ],
            0.05,
        )
        .unwrap();
        let map = ClearanceMap::new(&grid, &ClearanceConfig::default()).unwrap();
        let (s, g) = (Cell::new(0, 4), Cell::new(11, 4));
        assert!(map.is_clear(g));
        let plain = AstarConfig {
            snap_to_goal: false,
            fine_fallback: false,
            ..Default::default()
        };
        let snapping = AstarConfig::default();
        // Lattice x = 0, 3, 6, 9, 12: (9, 4) and (12, 4) are clear but 2 and 1 cells from
        // the goal; with a tolerance of 1.5 only (12, 4) counts, and it is clear too, so use
        // tolerance 0 to isolate the snap move.
        let strict = AstarConfig {
            goal_tolerance_cells: 0.0,
            ..plain
        };
        assert_eq!(plan(&map, s, g, &strict).unwrap(), None);
        let snap = AstarConfig {
            goal_tolerance_cells: 0.0,
            ..snapping
        };
        let p = plan(&map, s, g, &snap).unwrap().unwrap();
        assert_eq!(*p.cells.last().unwrap(), g);
        for m in p.cells.windows(2) {
            assert!(move_is_allowed(&map, s, m[0], m[1]));
        }
    }

    #[test]
    fn unknown_space_blocks_only_when_configured() {
        let grid = OccupancyGrid::from_ascii(
            &[
                "..........", //
                "..........", //
                "..........", //
                "??????????", //
                "??????????", //
                "??????????", //
                "..........", //
                "..........", //
                "..........",
            ],
            0.05,
        )
        .unwrap();
        let (s, g) = (Cell::new(1, 1), Cell::new(7, 7));
        let strict = ClearanceMap::new(&grid, &ClearanceConfig::default()).unwrap();
        assert_eq!(plan(&strict, s, g, &AstarConfig::default()).unwrap(), None);
        let lax = ClearanceMap::new(
            &grid,
            &ClearanceConfig {
                unknown_is_blocked: false,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(plan(&lax, s, g, &AstarConfig::default()).unwrap().is_some());
    }

    #[test]
    fn bad_input_is_an_error_and_trivial_plans_are_trivial() {
        let grid = OccupancyGrid::from_ascii(&["......"; 6], 0.05).unwrap();
        let map = ClearanceMap::new(&grid, &ClearanceConfig::default()).unwrap();
        let cfg = AstarConfig::default();
        assert!(matches!(
            plan(&map, Cell::new(0, 0), Cell::new(9, 0), &cfg),
            Err(PlanningError::OutsideGrid {
                what: "A* goal",
                ..
            })
        ));
        assert!(matches!(
            plan_world(&map, Point2::new(-1.0, 0.0), Point2::new(0.1, 0.1), &cfg),
            Err(PlanningError::OutsideGrid {
                what: "A* start",
                ..
            })
        ));
        let bad = AstarConfig {
            step_cells: 0,
            ..cfg
        };
        assert!(matches!(
            plan(&map, Cell::new(2, 2), Cell::new(3, 3), &bad),
            Err(PlanningError::InvalidConfig { .. })
        ));
        let p = plan(&map, Cell::new(2, 2), Cell::new(2, 2), &cfg)
            .unwrap()
            .unwrap();
        assert_eq!((p.cells, p.cost), (vec![Cell::new(2, 2)], 0.0));
    }

    #[test]
    fn a_start_inside_the_margin_escapes() {
        let grid = OccupancyGrid::from_ascii(
            &[
                "............", //
                "............", //
                "............", //
                "............", //
                "#...........", //
                "............",
            ],
            0.05,
        )
        .unwrap();
        let map = ClearanceMap::new(&grid, &ClearanceConfig::default()).unwrap();
        let s = Cell::new(1, 1);
        assert!(!map.is_clear(s));
        let p = plan(&map, s, Cell::new(10, 3), &AstarConfig::default()).unwrap();
        assert!(p.is_some());
    }

    #[test]
    fn a_passage_off_the_lattice_is_found_by_the_fine_fallback() {
        // A wall with a doorway whose only clear column is x = 7: the lattice from x = 2 visits
        // x = 2, 5, 8, … and cannot pass; the 1-cell search can.
        let mut rows = vec!["..............."; 5];
        rows.push("#####...#######");
        rows.extend(vec!["..............."; 5]);
        let grid = OccupancyGrid::from_ascii(&rows, 0.05).unwrap();
        let map = ClearanceMap::new(&grid, &ClearanceConfig::default()).unwrap();
        let (s, g) = (Cell::new(2, 1), Cell::new(2, 9));
        assert!(map.is_clear(Cell::new(6, 5)) && !map.is_clear(Cell::new(5, 5)));
        let lattice_only = AstarConfig {
            fine_fallback: false,
            ..Default::default()
        };
        assert_eq!(plan(&map, s, g, &lattice_only).unwrap(), None);
        let p = plan(&map, s, g, &AstarConfig::default()).unwrap().unwrap();
        assert_eq!(*p.cells.last().unwrap(), g);
        assert!(p.cells.contains(&Cell::new(6, 5)), "{:?}", p.cells);
        for m in p.cells.windows(2) {
            assert!(move_is_allowed(&map, s, m[0], m[1]));
        }
        path_keeps_clearance(&grid, &p.cells, 1.5, true);
    }

    #[test]
    fn a_path_exists_exactly_where_the_frontier_path_distances_are_finite() {
        // The frontier operator calls a region reachable when its approach cell has a finite
        // path distance; the scorer then plans to it with A*. The two must agree, also from a
        // start inside the clearance margin.
        let mut rng = ChaCha8Rng::seed_from_u64(29);
        let (mut reachable, mut unreachable, mut margin_starts) = (0, 0, 0);
        for trial in 0..60 {
            let (w, h) = (rng.random_range(10..30), rng.random_range(10..30));
            let grid = random_grid(&mut rng, w, h, 0.12);
            let cc = if trial % 2 == 0 {
                ClearanceConfig::default()
            } else {
                ClearanceConfig::for_disc(0.1, 0.05).unwrap()
            };
            let map = ClearanceMap::new(&grid, &cc).unwrap();
            let unblocked: Vec<Cell> = (0..grid.data.len())
                .map(|i| grid.geometry.cell_at(i))
                .filter(|c| !map.is_blocked(*c))
                .collect();
            if unblocked.is_empty() {
                continue;
            }
            let s = unblocked[rng.random_range(0..unblocked.len())];
            margin_starts += usize::from(!map.is_clear(s));
            let dist = crate::frontier::path_distances(&map, s);
            let cfg = AstarConfig {
                goal_tolerance_cells: 0.0,
                ..Default::default()
            };
            for _ in 0..12 {
                let g = Cell::new(rng.random_range(0..w as i32), rng.random_range(0..h as i32));
                let finite = dist.get(g).is_some_and(|d| d.is_finite());
                let p = plan(&map, s, g, &cfg).unwrap();
                assert_eq!(
                    p.is_some(),
                    finite,
                    "trial {trial}: start {s:?} goal {g:?}: path {p:?}, distance finite {finite}"
                );
                if let Some(p) = p {
                    reachable += 1;
                    assert_eq!(*p.cells.last().unwrap(), g);
                    for m in p.cells.windows(2) {
                        assert!(move_is_allowed(&map, s, m[0], m[1]));
                    }
                } else {
                    unreachable += 1;
                }
            }
        }
        assert!(
            reachable > 100 && unreachable > 100 && margin_starts > 5,
            "too few cases: {reachable} reachable, {unreachable} not, {margin_starts} margin starts"
        );
    }
}
