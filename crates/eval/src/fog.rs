//! 2D coverage as the authors' release computes it (`coverage_fog`, issue 36): a fog of war on
//! the navigable top-down map, lifted by the true pose at every step. From the robot's cell,
//! rays fan over the camera's horizontal field of view (90°) out to 10 m; each ray marks the
//! cells it crosses until it leaves the map or meets a cell that is not navigable (Habitat's
//! `reveal_fog_of_war` on its top-down map). The coverage is the share of the navigable cells
//! reachable from the start that were ever marked. Unlike `coverage_2d` (what the map's
//! occupancy grid knows), it depends on the trajectory only, not on the map.

use crate::error::EvalError;
use activemap_geometry::PlanarPose;
use activemap_sim::NavigableMap;
use rayon::prelude::*;

/// Settings of the fog of war.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FogConfig {
    /// Horizontal field of view, radians (the release: 90°).
    pub fov_rad: f64,
    /// Length of each ray, metres (the release: 10 m).
    pub range_m: f64,
}

impl Default for FogConfig {
    fn default() -> Self {
        Self {
            fov_rad: std::f64::consts::FRAC_PI_2,
            range_m: 10.0,
        }
    }
}

/// The cells of `map` revealed by the poses (row-major like `map.cells`).
pub fn fog_seen(map: &NavigableMap, poses: &[PlanarPose], config: &FogConfig) -> Vec<bool> {
    let frame = map.frame;
    let cell = frame.cell_size;
    // Rays about one cell apart at the far end; steps of half a cell along each ray.
    let rays = ((config.fov_rad * config.range_m / cell).ceil() as usize).max(1);
    let steps = (2.0 * config.range_m / cell).ceil() as usize;
    poses
        .par_iter()
        .fold(
            || vec![false; map.cells.len()],
            |mut seen, pose| {
                for r in 0..=rays {
                    let angle =
                        pose.yaw - 0.5 * config.fov_rad + config.fov_rad * r as f64 / rays as f64;
                    let (dx, dy) = (angle.cos() * 0.5 * cell, angle.sin() * 0.5 * cell);
                    for s in 0..=steps {
                        let (x, y) = (pose.x + dx * s as f64, pose.y + dy * s as f64);
                        let Some((i, j)) = frame.cell_of(x, y) else {
                            break;
                        };
                        if !map.is_navigable(i, j) {
                            break;
                        }
                        seen[j * frame.width + i] = true;
                    }
                }
                seen
            },
        )
        .reduce(
            || vec![false; map.cells.len()],
            |mut a, b| {
                for (x, y) in a.iter_mut().zip(b) {
                    *x |= y;
                }
                a
            },
        )
}

/// The fog-of-war coverage of `poses`: revealed ∩ `reachable` over `reachable` (see the module
/// doc). Fails when nothing is reachable or the mask does not fit the map.
pub fn coverage_fog(
    map: &NavigableMap,
    reachable: &[bool],
    poses: &[PlanarPose],
    config: &FogConfig,
) -> Result<f64, EvalError> {
    let seen = fog_seen(map, poses, config);
    crate::coverage_2d(&seen, reachable, map.frame.width, map.frame.height)
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_sim::navigation::GridFrame;

    /// An open 8 × 8 m map (5 cm cells) with a wall: the column of cells at x ∈ [5, 5.05) m for
    /// y ≥ 4 m is not navigable.
    fn map() -> NavigableMap {
        let (w, h) = (160, 160);
        let cells = (0..w * h).map(|c| !(c % w == 100 && c / w >= 80)).collect();
        NavigableMap {
            frame: GridFrame {
                origin_x: 0.0,
                origin_y: 0.0,
                cell_size: 0.05,
                width: w,
                height: h,
            },
            cells,
        }
    }

    #[test]
    fn the_fog_lifts_over_the_field_of_view_up_to_walls() {
        let map = map();
        // At (1, 4) facing +x.
        let pose = PlanarPose::new(1.0, 4.025, 0.0);
        let seen = fog_seen(&map, &[pose], &FogConfig::default());
        for j in 0..160 {
            for i in 0..160 {
                let (x, y) = map.frame.centre(i, j);
                let (dx, dy) = (x - pose.x, y - pose.y);
                let angle = dy.atan2(dx).abs().to_degrees();
                let cell = seen[j * 160 + i];
                if dx.hypot(dy) > 1.0 && angle > 47.0 {
                    assert!(!cell, "({x}, {y}) outside the field of view is seen");
                }
                // Behind the wall (x > 5.05 where a ray from the pose crosses y ≥ 4).
                let crosses_wall = dx > 0.0 && pose.y + dy * (5.0 - pose.x) / dx >= 4.0;
                if x > 5.1 && crosses_wall && dy >= 0.0 {
                    assert!(!cell, "({x}, {y}) behind the wall is seen");
                }
                if angle < 40.0 && dx > 0.2 && (x < 4.9 || dy < -0.2) {
                    assert!(cell, "({x}, {y}) in plain view is not seen");
                }
            }
        }
        // Turning round reveals the rest of the row of cells behind the start.
        let all: Vec<bool> = map.cells.clone();
        let one = coverage_fog(&map, &all, &[pose], &FogConfig::default()).unwrap();
        let back = PlanarPose::new(1.0, 4.025, std::f64::consts::PI);
        let two = coverage_fog(&map, &all, &[pose, back], &FogConfig::default()).unwrap();
        assert!(0.0 < one && one < two && two < 1.0, "{one} {two}");
    }

    #[test]
    fn the_range_bounds_the_rays() {
        let map = map();
        let pose = PlanarPose::new(0.025, 1.025, 0.0);
        let config = FogConfig {
            fov_rad: 0.01,
            range_m: 2.0,
        };
        let seen = fog_seen(&map, &[pose], &config);
        let row: Vec<bool> = (0..160).map(|i| seen[20 * 160 + i]).collect();
        // Cells 0..=40 (0 to 2.025 m) seen, none from 2.1 m on.
        assert!(row[..40].iter().all(|&s| s), "{row:?}");
        assert!(row[42..].iter().all(|&s| !s), "{row:?}");
    }
}
