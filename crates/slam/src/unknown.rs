//! "Unknown space" Gaussians (SPEC §5): for every frontier cell, `per_cell` (200) Gaussians
//! uniform in the box above it (x, y inside the cell, z in the given height band), colour and
//! opacity uniform in [0, 1], per-axis scale uniform in (0, `max_scale_fraction · cell`]
//! (the release bounds it by 0.05·cell), identity rotation, flagged [`FLAG_UNKNOWN_SPACE`] so
//! tracking, mapping and evaluation renders leave them out while Fisher scoring sees them.
//!
//! They are replaced as observations arrive: a keyframe removes every unknown-space Gaussian
//! that projects onto one of its valid depth pixels at a camera depth no farther than the
//! reading plus `margin` (that space is now observed free space or surface; the real
//! Gaussians inserted from the same keyframe take over).

use crate::frame::Frame;
use activemap_geometry::{Isometry3, Point3};
use activemap_splat::{FLAG_UNKNOWN_SPACE, Gaussians};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Where to seed: a frontier cell of the occupancy grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrontierCell {
    /// Cell centre (world x, y), metres.
    pub centre: [f64; 2],
    /// Cell side, metres (5 cm by default, SPEC §6).
    pub size: f64,
    /// Height band `[z_min, z_max]` of the box above the cell, metres (world z).
    pub z_range: [f64; 2],
}

/// Seeding settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnknownSpaceConfig {
    /// Gaussians per cell (200).
    pub per_cell: usize,
    /// Largest scale as a fraction of the cell side (0.05, the release's bound).
    pub max_scale_fraction: f64,
    /// Tolerance behind a depth reading within which an unknown Gaussian counts as observed.
    pub margin: f64,
}

impl Default for UnknownSpaceConfig {
    fn default() -> Self {
        Self {
            per_cell: 200,
            max_scale_fraction: 0.05,
            margin: 0.05,
        }
    }
}

/// Appends the unknown-space Gaussians of `cells` to `map` (seeded); returns how many.
pub fn seed(
    map: &mut Gaussians<f32>,
    cells: &[FrontierCell],
    config: &UnknownSpaceConfig,
    seed: u64,
) -> usize {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut added = 0;
    for cell in cells {
        let half = 0.5 * cell.size;
        let max_scale = (config.max_scale_fraction * cell.size).max(1e-6);
        for _ in 0..config.per_cell {
            let mean = [
                cell.centre[0] + rng.random_range(-half..=half),
                cell.centre[1] + rng.random_range(-half..=half),
                rng.random_range(cell.z_range[0]..=cell.z_range[1]),
            ];
            let rgb = [
                rng.random::<f64>(),
                rng.random::<f64>(),
                rng.random::<f64>(),
            ];
            let opacity = rng.random::<f64>();
            let scale = [0; 3].map(|_| max_scale * (1.0 - rng.random::<f64>()));
            map.push(mean, rgb, [1.0, 0.0, 0.0, 0.0], opacity, scale);
            *map.flags.last_mut().expect("just pushed") |= FLAG_UNKNOWN_SPACE;
            added += 1;
        }
    }
    added
}

/// Checks that every cell is finite with a positive size and an ordered height band.
pub fn validate_cells(cells: &[FrontierCell]) -> Result<(), crate::SlamError> {
    for (i, c) in cells.iter().enumerate() {
        let finite = c
            .centre
            .iter()
            .chain(c.z_range.iter())
            .chain([c.size].iter())
            .all(|v| v.is_finite());
        if !finite || c.size <= 0.0 || c.z_range[0] > c.z_range[1] {
            return Err(crate::SlamError::Input {
                what: "frontier cell",
                reason: format!("cell {i} is invalid: {c:?}"),
            });
        }
    }
    Ok(())
}

/// Per Gaussian: true for unknown-space Gaussians that the keyframe (`frame` at
/// `T_world_camera = pose`) observes (see the module doc).
pub fn observed_unknown(
    map: &Gaussians<f32>,
    frame: &Frame,
    pose: &Isometry3<f64>,
    margin: f64,
) -> Vec<bool> {
    let camera_from_world = pose.inverse();
    let k = &frame.intrinsics;
    let (w, h) = (frame.width() as f64, frame.height() as f64);
    (0..map.len())
        .map(|i| {
            if map.flags[i] & FLAG_UNKNOWN_SPACE == 0 {
                return false;
            }
            let m = map.means[i];
            let pc = camera_from_world * Point3::new(m[0] as f64, m[1] as f64, m[2] as f64);
            let Some(uv) = k.project(&pc) else {
                return false;
            };
            let (u, v) = (uv.x.round(), uv.y.round());
            if pc.z <= 0.01 || u < 0.0 || v < 0.0 || u >= w || v >= h {
                return false;
            }
            let d = frame.depth[v as usize * frame.width() + u as usize] as f64;
            d > 0.0 && pc.z <= d + margin
        })
        .collect()
}
