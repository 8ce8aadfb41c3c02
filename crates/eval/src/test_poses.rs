//! The test poses of SPEC §8: drawn uniformly on the navigable plane with a random yaw and a
//! fixed seed, so every method is rendered from the same 2000 views. The plane is a boolean grid
//! with the occupancy-grid convention of `activemap-schemas` (row-major, row = y index, `origin`
//! = world (x, y) of the centre of cell (0, 0), square cells of `resolution` metres).

use crate::error::EvalError;
use activemap_geometry::PlanarPose;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::PI;

/// The paper's number of test views.
pub const TEST_VIEW_COUNT: usize = 2000;

/// A navigable lattice on the motion plane.
#[derive(Debug, Clone, Copy)]
pub struct NavigableGrid<'a> {
    /// `width × height` cells, row-major, true = navigable.
    pub cells: &'a [bool],
    /// Columns (x).
    pub width: usize,
    /// Rows (y).
    pub height: usize,
    /// World (x, y) of the centre of cell (0, 0), metres.
    pub origin: [f64; 2],
    /// Cell side, metres.
    pub resolution: f64,
}

/// `count` planar poses uniform over the navigable area (a navigable cell uniformly, then a
/// uniform point inside it) with yaw uniform in [−π, π), from `seed` (ChaCha8).
pub fn sample_test_poses(
    grid: NavigableGrid<'_>,
    count: usize,
    seed: u64,
) -> Result<Vec<PlanarPose>, EvalError> {
    let metric = "test poses";
    if grid.width.checked_mul(grid.height) != Some(grid.cells.len()) {
        return Err(EvalError::SizeMismatch {
            metric,
            detail: format!(
                "a {}×{} grid needs {} cells, got {}",
                grid.width,
                grid.height,
                grid.width.saturating_mul(grid.height),
                grid.cells.len()
            ),
        });
    }
    let valid_resolution = grid.resolution.is_finite() && grid.resolution > 0.0;
    let valid_origin = grid.origin.iter().all(|v| v.is_finite());
    if !valid_resolution || !valid_origin {
        return Err(EvalError::InvalidParameter {
            metric,
            detail: format!(
                "resolution must be positive and origin finite, got {} and {:?}",
                grid.resolution, grid.origin
            ),
        });
    }
    let navigable: Vec<usize> = (0..grid.cells.len()).filter(|&i| grid.cells[i]).collect();
    if navigable.is_empty() {
        return Err(EvalError::Empty {
            metric,
            detail: "the grid has no navigable cell".into(),
        });
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    Ok((0..count)
        .map(|_| {
            let cell = navigable[rng.random_range(0..navigable.len())];
            let (ix, iy) = (cell % grid.width, cell / grid.width);
            let dx: f64 = rng.random_range(-0.5..0.5);
            let dy: f64 = rng.random_range(-0.5..0.5);
            PlanarPose::new(
                grid.origin[0] + (ix as f64 + dx) * grid.resolution,
                grid.origin[1] + (iy as f64 + dy) * grid.resolution,
                rng.random_range(-PI..PI),
            )
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poses_fall_in_navigable_cells_in_proportion_to_area() {
        // 10×4 grid, 0.05 m cells, origin (1, −2): navigable = column 0 (4 cells) and the block
        // x 6..10, y 0..3 (12 cells) → 1/4 of the poses in column 0.
        let (w, h) = (10, 4);
        let cells: Vec<bool> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                x == 0 || (x >= 6 && y < 3)
            })
            .collect();
        let grid = NavigableGrid {
            cells: &cells,
            width: w,
            height: h,
            origin: [1.0, -2.0],
            resolution: 0.05,
        };
        let poses = sample_test_poses(grid, TEST_VIEW_COUNT, 42).unwrap();
        assert_eq!(poses.len(), TEST_VIEW_COUNT);
        let mut in_column = 0;
        for p in &poses {
            let ix = ((p.x - 1.0) / 0.05 + 0.5).floor() as usize;
            let iy = ((p.y + 2.0) / 0.05 + 0.5).floor() as usize;
            assert!(cells[iy * w + ix], "pose {p:?} in cell ({ix}, {iy})");
            assert!((-PI..PI).contains(&p.yaw));
            in_column += usize::from(ix == 0);
        }
        // binomial(2000, 0.25): σ ≈ 19.4; 5σ tolerance
        assert!((in_column as f64 - 500.0).abs() < 97.0, "{in_column}");
        // yaw spread over the circle: mean of cos close to 0
        let mean_cos = poses.iter().map(|p| p.yaw.cos()).sum::<f64>() / poses.len() as f64;
        assert!(mean_cos.abs() < 0.08, "{mean_cos}");
        assert_eq!(poses, sample_test_poses(grid, TEST_VIEW_COUNT, 42).unwrap());
        assert_ne!(poses, sample_test_poses(grid, TEST_VIEW_COUNT, 43).unwrap());
    }

    #[test]
    fn bad_grids_are_refused() {
        let cells = [false; 6];
        let grid = NavigableGrid {
            cells: &cells,
            width: 3,
            height: 2,
            origin: [0.0, 0.0],
            resolution: 0.05,
        };
        let e = sample_test_poses(grid, 5, 0).unwrap_err().to_string();
        assert!(e.contains("no navigable cell"), "{e}");
        let e = sample_test_poses(NavigableGrid { width: 4, ..grid }, 5, 0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("4×2 grid needs 8 cells, got 6"), "{e}");
        let e = sample_test_poses(
            NavigableGrid {
                resolution: 0.0,
                ..grid
            },
            5,
            0,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("resolution"), "{e}");
    }
}
