//! Path shortcutting (SPEC §6, release): for each waypoint `w_i`, while the move
//! `w_i → w_{i+2}` passes the same swept collision check as A*, drop `w_{i+1}`. A replaced
//! pair of moves is only ever swapped for one clear move, so no collision is ever added.

use crate::astar::move_is_allowed;
use crate::clearance::ClearanceMap;
use crate::grid::Cell;

/// The shortcut path of `waypoints` (the first and last waypoints are kept). The first
/// waypoint is taken as the start for the escape rule of [`move_is_allowed`].
pub fn shortcut(map: &ClearanceMap, waypoints: &[Cell]) -> Vec<Cell> {
    let Some(&start) = waypoints.first() else {
        return Vec::new();
    };
    let mut out: Vec<Cell> = vec![start];
    let mut i = 0usize;
    // `anchor` is the last kept waypoint; try to reach as far ahead as possible one step at a
    // time (dropping w_{i+1} whenever w_i → w_{i+2} is clear).
    while i + 1 < waypoints.len() {
        let anchor = *out.last().unwrap_or(&start);
        let mut j = i + 1;
        while j + 1 < waypoints.len() && move_is_allowed(map, start, anchor, waypoints[j + 1]) {
            j += 1;
        }
        out.push(waypoints[j]);
        i = j;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::astar::{AstarConfig, plan};
    use crate::clearance::ClearanceConfig;
    use crate::grid::{CellState, GridGeometry, OccupancyGrid};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_grid(rng: &mut ChaCha8Rng, w: usize, h: usize, density: f64) -> OccupancyGrid {
        let g = GridGeometry::new(0.0, 0.0, 0.05, w, h).unwrap();
        let mut grid = OccupancyGrid::filled(g, CellState::Free);
        for s in grid.data.iter_mut() {
            let r: f64 = rng.random();
            *s = if r < density {
                CellState::Occupied
            } else if r < density * 1.3 {
                CellState::Unknown
            } else {
                CellState::Free
            };
        }
        grid
    }

    #[test]
    fn straight_corridor_collapses_to_two_waypoints() {
        let grid = OccupancyGrid::from_ascii(&["..........."; 7], 0.05).unwrap();
        let map = ClearanceMap::new(&grid, &ClearanceConfig::default()).unwrap();
        let zigzag = [
            Cell::new(1, 3),
            Cell::new(3, 4),
            Cell::new(5, 2),
            Cell::new(7, 4),
            Cell::new(9, 3),
        ];
        assert_eq!(
            shortcut(&map, &zigzag),
            vec![Cell::new(1, 3), Cell::new(9, 3)]
        );
        assert!(shortcut(&map, &[]).is_empty());
        assert_eq!(shortcut(&map, &[Cell::new(2, 2)]), vec![Cell::new(2, 2)]);
    }

    #[test]
    fn shortcut_keeps_the_corner_around_a_wall() {
        let grid = OccupancyGrid::from_ascii(
            &[
                "...........", //
                "...........", //
                "...........", //
                "#######....", //
                "...........", //
                "...........", //
                "...........",
            ],
            0.05,
        )
        .unwrap();
        let map = ClearanceMap::new(&grid, &ClearanceConfig::default()).unwrap();
        let path = [
            Cell::new(1, 1),
            Cell::new(9, 1),
            Cell::new(9, 5),
            Cell::new(1, 5),
        ];
        let out = shortcut(&map, &path);
        assert_eq!(out.len(), 4, "{out:?}");
    }

    /// Property: on random grids, for random polylines (colliding or not) and for A* paths, every
    /// move of the shortcut path is either a move of the input or passes the swept check, so the
    /// shortcut never adds a collision; endpoints are kept and the waypoints are a subsequence.
    #[test]
    fn shortcut_never_adds_a_collision() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for trial in 0..300 {
            let (w, h) = (rng.random_range(8..30), rng.random_range(8..30));
            let grid = random_grid(&mut rng, w, h, [0.02, 0.08, 0.2][trial % 3]);
            let map = ClearanceMap::new(
                &grid,
                &ClearanceConfig {
                    robot_width_cells: [0.0, 1.0, 3.0][trial % 3],
                    unknown_is_blocked: trial % 2 == 0,
                },
            )
            .unwrap();
            let n = rng.random_range(2..9);
            let mut path: Vec<Cell> = (0..n)
                .map(|_| Cell::new(rng.random_range(0..w as i32), rng.random_range(0..h as i32)))
                .collect();
            if trial % 2 == 1
                && let Ok(Some(p)) = plan(&map, path[0], path[n - 1], &AstarConfig::default())
            {
                path = p.cells;
            }
            let out = shortcut(&map, &path);
            assert_eq!(out.first(), path.first());
            assert_eq!(out.last(), path.last());
            let mut k = 0;
            for c in &out {
                while k < path.len() && path[k] != *c {
                    k += 1;
                }
                assert!(
                    k < path.len(),
                    "shortcut waypoint {c:?} not from the input in order"
                );
            }
            let input_moves: Vec<(Cell, Cell)> = path.windows(2).map(|p| (p[0], p[1])).collect();
            let colliding = |moves: &[(Cell, Cell)]| {
                moves
                    .iter()
                    .filter(|(a, b)| !move_is_allowed(&map, path[0], *a, *b))
                    .count()
            };
            let out_moves: Vec<(Cell, Cell)> = out.windows(2).map(|p| (p[0], p[1])).collect();
            for m in &out_moves {
                assert!(
                    input_moves.contains(m) || move_is_allowed(&map, path[0], m.0, m.1),
                    "trial {trial}: new move {m:?} collides"
                );
            }
            assert!(colliding(&out_moves) <= colliding(&input_moves));
        }
    }
}
