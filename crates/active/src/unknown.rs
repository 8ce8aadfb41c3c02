//! Unknown-space Gaussians (SPEC §5 "Unknown space", paper appendix "Implementation
//! Details"): for every frontier cell of the 2D occupancy grid, `per_cell` (200) Gaussians
//! uniform in the box above it, so that unexplored space carries information in the Fisher
//! computation. x, y are uniform inside the cell's square, z uniform in the given height band
//! (the release: `[cam_h − 1, cam_h)`), colour and opacity uniform in [0, 1], per-axis scale
//! uniform in (0, `max_scale_fraction · cell side`] (the release bounds it by 0.05·cell),
//! identity rotation, each flagged [`FLAG_UNKNOWN_SPACE`].
//!
//! They are used in the Fisher computation only, never in tracking, mapping or evaluation,
//! and are renewed at each replan: the mapper never holds them; the scorer seeds a fresh
//! [`UnknownSpace`] (a new `generation`) from the current grid at every replan and drops the
//! previous one. Ids sit above [`UNKNOWN_ID_BASE`], out of the mapper's id range, with the
//! generation in bits 32.. so two replans' sets never share an id.

use activemap_planning::morphology::dilate3;
use activemap_planning::{Cell, CellState, OccupancyGrid};
use activemap_splat::{FLAG_UNKNOWN_SPACE, Gaussians};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::ActiveError;

/// Ids of unknown-space Gaussians start here (the mapper's ids stay below), SPEC §5.
pub const UNKNOWN_ID_BASE: u64 = 1 << 62;

/// Largest generation whose ids still fit in a `u64` (`UNKNOWN_ID_BASE + (generation << 32)
/// + index` with `index < 2³²`), SPEC §5.
pub const MAX_GENERATION: u32 = ((u64::MAX - UNKNOWN_ID_BASE) >> 32) as u32;

/// The unknown-space Gaussians of one replan, with their ids (SPEC §5 "Unknown space").
#[derive(Debug, Clone, Default)]
pub struct UnknownSpace {
    /// The Gaussians, flagged `FLAG_UNKNOWN_SPACE`.
    pub gaussians: Gaussians<f32>,
    /// Their ids: `UNKNOWN_ID_BASE + (generation << 32) + index`.
    pub ids: Vec<u64>,
    /// The generation (one per replan that renewed them).
    pub generation: u32,
}

/// Frontier cells of `grid` (SPEC §6 "Frontiers" without the connectivity and size filters):
/// unknown cells 8-adjacent to a free cell, i.e. (3×3 dilation of free − free) ∩ unknown, in
/// row-major order. Unlike the frontier *regions* of `activemap_planning::frontier`, which
/// dilate only the free space connected to the robot, this uses all free space: unknown space
/// next to any observed free cell is seeded, reachable or not (its information still counts
/// for views that see it).
pub fn frontier_cells(grid: &OccupancyGrid) -> Vec<Cell> {
    let g = grid.geometry;
    let free: Vec<bool> = grid.data.iter().map(|s| *s == CellState::Free).collect();
    let near_free = dilate3(&free, g.width, g.height);
    (0..g.len())
        .filter(|&i| near_free[i] && grid.data[i] == CellState::Unknown)
        .map(|i| g.cell_at(i))
        .collect()
}

/// The cells of the frontier regions the robot at `robot` sees (SPEC §6 "Frontiers": the
/// 3×3 dilation of the free space connected to the robot, minus the free space, within the
/// unknown, in regions of more than `min_region_cells`), in row-major order: what the scorer
/// seeds. Unknown space that borders only free cells the robot cannot reach (seen through a
/// window or a gap too narrow for it) is left out, as the planner leaves it out.
pub fn frontier_region_cells(
    grid: &OccupancyGrid,
    clear: &activemap_planning::clearance::ClearanceMap,
    robot: nalgebra::Point2<f64>,
) -> Result<Vec<Cell>, ActiveError> {
    let found = activemap_planning::frontier::extract_frontiers(
        grid,
        clear,
        robot,
        &activemap_planning::frontier::FrontierConfig::default(),
    )?;
    let mut cells: Vec<Cell> = found.regions.into_iter().flat_map(|r| r.cells).collect();
    cells.sort_by_key(|c| (c.y, c.x));
    Ok(cells)
}

/// Seeds `per_cell` Gaussians uniform in the box above each of `cells` (SPEC §5 "Unknown
/// space"): x, y uniform in the cell's square of `grid`'s geometry, z uniform in
/// `[z_range[0], z_range[1])` (world metres), RGB and opacity uniform in [0, 1], per-axis
/// scale uniform in (0, `max_scale_fraction` · cell side], identity rotation, flagged
/// [`FLAG_UNKNOWN_SPACE`]. Ids are `UNKNOWN_ID_BASE + (generation << 32) + index` in seeding
/// order (cell by cell). Deterministic: one `ChaCha8Rng` seeded with `seed`.
///
/// Errors: a non-finite or reversed `z_range`, a `max_scale_fraction` that is not finite and
/// positive, more than 2³² Gaussians, or a generation above [`MAX_GENERATION`].
pub fn seed_unknown_space(
    grid: &OccupancyGrid,
    cells: &[Cell],
    z_range: [f64; 2],
    per_cell: usize,
    max_scale_fraction: f64,
    generation: u32,
    seed: u64,
) -> Result<UnknownSpace, ActiveError> {
    let [z0, z1] = z_range;
    if !(z0.is_finite() && z1.is_finite() && z0 <= z1) {
        return Err(ActiveError::Input {
            what: "unknown-space height band",
            reason: format!("must be finite with min <= max, got [{z0}, {z1}]"),
        });
    }
    if !(max_scale_fraction.is_finite() && max_scale_fraction > 0.0) {
        return Err(ActiveError::Input {
            what: "unknown-space max scale fraction",
            reason: format!("must be finite and positive, got {max_scale_fraction}"),
        });
    }
    if generation > MAX_GENERATION {
        return Err(ActiveError::Input {
            what: "unknown-space generation",
            reason: format!("{generation} is above {MAX_GENERATION}: its ids overflow u64"),
        });
    }
    let total = cells
        .len()
        .checked_mul(per_cell)
        .filter(|&n| (n as u64) <= 1 << 32)
        .ok_or_else(|| ActiveError::Input {
            what: "unknown-space cells",
            reason: format!(
                "{} cells × {per_cell} Gaussians exceed 2³² ids per generation",
                cells.len()
            ),
        })?;
    let side = grid.geometry.resolution;
    let max_scale = max_scale_fraction * side;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut gaussians = Gaussians::new();
    for &cell in cells {
        let centre = grid.geometry.center(cell);
        let (x0, y0) = (centre.x - 0.5 * side, centre.y - 0.5 * side);
        for _ in 0..per_cell {
            let mean = [
                x0 + side * rng.random::<f64>(),
                y0 + side * rng.random::<f64>(),
                z0 + (z1 - z0) * rng.random::<f64>(),
            ];
            let rgb: [f64; 3] = [0; 3].map(|_| rng.random::<f64>());
            let opacity = rng.random::<f64>();
            // 1 − u with u in [0, 1) is in (0, 1]: a scale is never zero.
            let scale = [0; 3].map(|_| max_scale * (1.0 - rng.random::<f64>()));
            gaussians.push(mean, rgb, [1.0, 0.0, 0.0, 0.0], opacity, scale);
        }
    }
    for f in &mut gaussians.flags {
        *f |= FLAG_UNKNOWN_SPACE;
    }
    let first = UNKNOWN_ID_BASE + ((generation as u64) << 32);
    let ids = (0..total as u64).map(|i| first + i).collect();
    Ok(UnknownSpace {
        gaussians,
        ids,
        generation,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_splat::gaussians::sh_dc_to_rgb;
    use std::collections::HashSet;

    fn grid() -> OccupancyGrid {
        // Rows from the top (y = 4) down; columns x = 0..5.
        //   y=4  ??????
        //   y=3  ?...#?
        //   y=2  ?.#..?
        //   y=1  ??#.??
        //   y=0  ??????
        OccupancyGrid::from_ascii(&["??????", "?...#?", "?.#..?", "??#.??", "??????"], 0.05)
            .unwrap()
    }

    #[test]
    fn frontier_cells_are_the_unknown_cells_next_to_free_space() {
        // Hand count of the unknown cells with a free cell among their 8 neighbours
        // (free: (1..=3, 3), (1, 2), (3, 2), (4, 2), (3, 1)):
        //   y=4: x = 0..=4 (touch row 3's free cells; (5, 4) sees only '#' and '?') → 5
        //   y=3: (0, 3) next to (1, 3); (5, 3) diagonal to (4, 2) → 2
        //   y=2: (0, 2) next to (1, 2); (5, 2) next to (4, 2) → 2
        //   y=1: (0, 1), (1, 1) next to (1, 2); (4, 1), (5, 1) next to (4, 2) → 4
        //   y=0: (2..=4, 0) next to (3, 1); (0, 0), (1, 0), (5, 0) are not → 3
        let expected: HashSet<(i32, i32)> = [
            (0, 4),
            (1, 4),
            (2, 4),
            (3, 4),
            (4, 4),
            (0, 3),
            (5, 3),
            (0, 2),
            (5, 2),
            (0, 1),
            (1, 1),
            (4, 1),
            (5, 1),
            (2, 0),
            (3, 0),
            (4, 0),
        ]
        .into_iter()
        .collect();
        let ordered = frontier_cells(&grid());
        let cells: HashSet<(i32, i32)> = ordered.iter().map(|c| (c.x, c.y)).collect();
        assert_eq!(cells, expected);
        // Row-major order, no duplicates.
        assert_eq!(ordered.len(), 16);
        assert!(
            ordered
                .windows(2)
                .all(|w| (w[0].y, w[0].x) < (w[1].y, w[1].x))
        );
        // No free cell: no frontier; all free: no frontier either.
        let unknown = OccupancyGrid::from_ascii(&["???", "???"], 0.05).unwrap();
        assert!(frontier_cells(&unknown).is_empty());
        let free = OccupancyGrid::from_ascii(&["...", "..."], 0.05).unwrap();
        assert!(frontier_cells(&free).is_empty());
    }

    /// The scorer seeds the frontier regions of the robot's free space only: unknown cells
    /// next to a free pocket behind a wall (seen through it, unreachable) are left out.
    #[test]
    fn frontier_regions_follow_the_robots_free_space() {
        let rows = [
            "##############",
            "#......#....??",
            "#......#....??",
            "#......?######",
            "#......?######",
            "#......???????",
            "#......???????",
            "#......???????",
            "#......???????",
            "##############",
        ];
        let grid = OccupancyGrid::from_ascii(&rows, 0.05).unwrap();
        let clear = activemap_planning::clearance::ClearanceMap::new(
            &grid,
            &activemap_planning::clearance::ClearanceConfig::default(),
        )
        .unwrap();
        let robot = grid.geometry.center(Cell::new(3, 4));
        let cells = frontier_region_cells(&grid, &clear, robot).unwrap();
        assert!(!cells.is_empty());
        // Every seeded cell is unknown and touches the robot's room (columns 1..=6, plus the
        // diagonal neighbour column 7), never the pocket's own border (columns 12, 13).
        for c in &cells {
            assert_eq!(grid.get(*c), Some(&CellState::Unknown));
            assert!(c.x <= 7, "{c:?} borders only the unreachable pocket");
        }
        let all = frontier_cells(&grid);
        assert!(all.iter().any(|c| c.x >= 12) && all.len() > cells.len());
        assert!(
            cells
                .windows(2)
                .all(|w| (w[0].y, w[0].x) < (w[1].y, w[1].x))
        );
    }

    #[test]
    fn seeded_gaussians_fill_the_boxes_with_flagged_unique_ids() {
        let grid = grid();
        let cells = frontier_cells(&grid);
        let (per_cell, fraction, generation) = (200, 0.05, 7u32);
        let z = [0.3, 1.3];
        let u = seed_unknown_space(&grid, &cells, z, per_cell, fraction, generation, 11).unwrap();
        let n = cells.len() * per_cell;
        assert_eq!(u.gaussians.len(), n);
        assert_eq!(u.ids.len(), n);
        assert_eq!(u.generation, generation);
        u.gaussians.validate().unwrap();
        let r = grid.geometry.resolution;
        let max_scale = fraction * r;
        for (k, &cell) in cells.iter().enumerate() {
            // Cell (x, y) covers [x·r, (x+1)·r) × [y·r, (y+1)·r) (origin 0).
            let (x0, y0) = (cell.x as f64 * r, cell.y as f64 * r);
            for i in k * per_cell..(k + 1) * per_cell {
                let m = u.gaussians.means[i].map(|v| v as f64);
                let tol = 1e-6;
                assert!(
                    m[0] >= x0 - tol && m[0] <= x0 + r + tol,
                    "{m:?} outside {cell:?}"
                );
                assert!(
                    m[1] >= y0 - tol && m[1] <= y0 + r + tol,
                    "{m:?} outside {cell:?}"
                );
                assert!(
                    m[2] >= z[0] - tol && m[2] <= z[1] + tol,
                    "{m:?} outside the band"
                );
                let rgb = u.gaussians.colour(i);
                assert!(
                    rgb.iter().all(|c| (-1e-6..=1.0 + 1e-6).contains(c)),
                    "{rgb:?}"
                );
                let o = u.gaussians.opacity(i);
                assert!((0.0..=1.0).contains(&o));
                for s in u.gaussians.log_scales[i] {
                    let s = (s as f64).exp();
                    assert!(s > 0.0 && s <= max_scale * (1.0 + 1e-6), "scale {s}");
                }
                assert_eq!(u.gaussians.rotations[i], [1.0, 0.0, 0.0, 0.0]);
                assert_ne!(u.gaussians.flags[i] & FLAG_UNKNOWN_SPACE, 0);
            }
        }
        // The draws spread over the whole box, not a corner of it: per axis the sample mean of
        // a uniform lies within a few standard errors of the box centre.
        let mean_z: f64 = u.gaussians.means.iter().map(|m| m[2] as f64).sum::<f64>() / n as f64;
        let se = (z[1] - z[0]) / (12.0 * n as f64).sqrt();
        assert!((mean_z - 0.8).abs() < 4.0 * se, "{mean_z}");
        let mean_red = (0..n)
            .map(|i| sh_dc_to_rgb(u.gaussians.sh_dc[i][0] as f64))
            .sum::<f64>()
            / n as f64;
        assert!((mean_red - 0.5).abs() < 4.0 / (12.0 * n as f64).sqrt());
        // Ids: unique, consecutive from this generation's base, all above the mapper's range.
        let base = UNKNOWN_ID_BASE + ((generation as u64) << 32);
        assert_eq!(u.ids, (base..base + n as u64).collect::<Vec<_>>());
        assert_eq!(u.ids.iter().collect::<HashSet<_>>().len(), n);
        assert!(u.ids.iter().all(|&id| id >= UNKNOWN_ID_BASE));
        // The next generation's ids never meet these.
        let next = seed_unknown_space(&grid, &cells, z, per_cell, fraction, 8, 11).unwrap();
        assert!(next.ids[0] > *u.ids.last().unwrap());
    }

    #[test]
    fn the_same_seed_gives_the_same_gaussians_and_another_seed_does_not() {
        let grid = grid();
        let cells = frontier_cells(&grid);
        let a = seed_unknown_space(&grid, &cells, [0.0, 1.0], 20, 0.05, 0, 3).unwrap();
        let b = seed_unknown_space(&grid, &cells, [0.0, 1.0], 20, 0.05, 0, 3).unwrap();
        assert_eq!(a.gaussians, b.gaussians);
        assert_eq!(a.ids, b.ids);
        let c = seed_unknown_space(&grid, &cells, [0.0, 1.0], 20, 0.05, 0, 4).unwrap();
        assert_ne!(a.gaussians.means, c.gaussians.means);
    }

    #[test]
    fn bad_inputs_are_refused_by_name() {
        let grid = grid();
        let cells = frontier_cells(&grid);
        let err = |r: Result<UnknownSpace, ActiveError>| r.unwrap_err().to_string();
        let e = err(seed_unknown_space(&grid, &cells, [1.0, 0.0], 2, 0.05, 0, 0));
        assert!(e.contains("height band"), "{e}");
        let e = err(seed_unknown_space(
            &grid,
            &cells,
            [0.0, f64::NAN],
            2,
            0.05,
            0,
            0,
        ));
        assert!(e.contains("height band"), "{e}");
        let e = err(seed_unknown_space(&grid, &cells, [0.0, 1.0], 2, 0.0, 0, 0));
        assert!(e.contains("max scale"), "{e}");
        let e = err(seed_unknown_space(
            &grid,
            &cells,
            [0.0, 1.0],
            2,
            0.05,
            MAX_GENERATION + 1,
            0,
        ));
        assert!(e.contains("generation"), "{e}");
        // The last generation still fits; no cells give an empty set.
        let last =
            seed_unknown_space(&grid, &cells[..1], [0.0, 1.0], 2, 0.05, MAX_GENERATION, 0).unwrap();
        assert!(last.ids[1] > last.ids[0]);
        let empty = seed_unknown_space(&grid, &[], [0.0, 1.0], 200, 0.05, 1, 0).unwrap();
        assert!(empty.gaussians.is_empty() && empty.ids.is_empty());
    }
}
