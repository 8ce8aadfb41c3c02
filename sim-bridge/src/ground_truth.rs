//! Ground truth for evaluation only (SPEC §8): surface samples of the mesh for completeness,
//! navigable test poses with random yaw for rendering metrics, and the navigable top-down map
//! for 2D coverage. Nothing here may feed the mapping or planning nodes.

use crate::navigation::{NavigableMap, Navigation};
use crate::scene::Scene;
use activemap_geometry::{Isometry3, PlanarPose, Point3, Vector3, camera_pose_from_planar};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `n` points sampled uniformly over the mesh surface (area-weighted), seeded. Default use:
/// ≈ 200 000 points, as Active-Neural-Mapping's completeness metric.
pub fn surface_samples(scene: &Scene, n: usize, seed: u64) -> Vec<Point3<f64>> {
    oriented_surface_samples(scene, n, seed)
        .into_iter()
        .map(|s| s.point)
        .collect()
}

/// A mesh surface sample and the unit normal of the triangle it lies on (sign as the mesh's
/// winding gives it, which scene files do not keep consistent).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceSample {
    /// The point on the surface, world frame, metres.
    pub point: Point3<f64>,
    /// Unit normal of its triangle.
    pub normal: Vector3<f64>,
}

/// [`surface_samples`] with each point's triangle normal (the same points for the same seed), so
/// that completeness can be broken down by kind of surface (floor, walls by height, ceiling).
pub fn oriented_surface_samples(scene: &Scene, n: usize, seed: u64) -> Vec<SurfaceSample> {
    let cumulative = cumulative_areas(scene);
    let total = cumulative.last().copied().unwrap_or(0.0);
    if total <= 0.0 {
        return Vec::new();
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let r = rng.random::<f64>() * total;
            let i = cumulative
                .partition_point(|&c| c <= r)
                .min(cumulative.len() - 1);
            let triangle = &scene.triangles[i];
            let [a, b, c] = scene.corners(triangle);
            let s = rng.random::<f64>().sqrt();
            let r2 = rng.random::<f64>();
            SurfaceSample {
                point: Point3::from(
                    (1.0 - s) * a.coords + s * (1.0 - r2) * b.coords + s * r2 * c.coords,
                ),
                // A triangle of zero area is never drawn (its cumulative area equals the one
                // before it), so the normal is defined.
                normal: scene
                    .scaled_normal(triangle)
                    .try_normalize(0.0)
                    .unwrap_or_else(Vector3::z),
            }
        })
        .collect()
}

/// The mesh's surface area, m² (both faces of a triangle count once): with it, a sample count
/// gives a sampling density.
pub fn surface_area(scene: &Scene) -> f64 {
    cumulative_areas(scene).last().copied().unwrap_or(0.0)
}

/// The running sum of the triangles' areas, in triangle order.
fn cumulative_areas(scene: &Scene) -> Vec<f64> {
    let mut total = 0.0;
    scene
        .triangles
        .iter()
        .map(|t| {
            total += 0.5 * scene.scaled_normal(t).norm();
            total
        })
        .collect()
}

/// `n` planar poses drawn uniformly over the navigable area (a random navigable cell, then a
/// random point in it that is itself navigable, else the cell centre), with yaw uniform in
/// [−π, π), seeded. Empty if nothing is navigable.
pub fn test_poses(navigation: &Navigation, n: usize, seed: u64) -> Vec<PlanarPose> {
    let map = navigation.map();
    let f = map.frame;
    let cells: Vec<usize> = (0..map.cells.len()).filter(|&c| map.cells[c]).collect();
    if cells.is_empty() {
        return Vec::new();
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let c = cells[rng.random_range(0..cells.len())];
            let (cx, cy) = f.centre(c % f.width, c / f.width);
            let x = cx + (rng.random::<f64>() - 0.5) * f.cell_size;
            let y = cy + (rng.random::<f64>() - 0.5) * f.cell_size;
            let yaw = (rng.random::<f64>() * 2.0 - 1.0) * std::f64::consts::PI;
            if navigation.is_navigable(x, y) {
                PlanarPose::new(x, y, yaw)
            } else {
                PlanarPose::new(cx, cy, yaw)
            }
        })
        .collect()
}

/// The camera poses `T_world_camera` of [`test_poses`] for a camera `camera_height` above the
/// floor.
pub fn test_camera_poses(
    navigation: &Navigation,
    camera_height: f64,
    n: usize,
    seed: u64,
) -> Vec<Isometry3<f64>> {
    test_poses(navigation, n, seed)
        .iter()
        .map(|p| camera_pose_from_planar(p, navigation.floor_z(), camera_height))
        .collect()
}

/// The navigable top-down map (for 2D coverage: seen floor area / navigable area).
pub fn navigable_map(navigation: &Navigation) -> NavigableMap {
    navigation.map().clone()
}
