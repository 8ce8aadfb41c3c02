//! Ground truth of what can be seen (issue 36): which ground-truth surface samples some camera
//! pose of the robot could observe, so that completeness is measured over what exploration can
//! reach, not over roof tops, outward faces of exterior walls or the floor under a wardrobe.
//!
//! A sample is **observable** when, from at least one camera site, it is
//! 1. within the camera's vertical field of view for some yaw: the camera is level at the
//!    robot's camera height, so facing the sample the condition is `|Δz| ≤ r·tan(vfov/2)` with
//!    `r` the horizontal distance (any yaw is allowed, so the horizontal field of view never
//!    excludes a sample);
//! 2. within the depth range: `r ≤ max_depth` (the z-depth when facing it);
//! 3. not occluded by the mesh: in a depth render of the scene from the site, towards the
//!    sample, nothing lies in front of it by more than a tolerance
//!    ([`ObservabilityConfig::occlusion_tolerance`]: 2 cm plus half a pixel's footprint at the
//!    sample's incidence, since the sample sits between pixel centres).
//!
//! Camera sites are the robot's possible positions: the navigable cells reachable from the
//! start, on a lattice of [`ObservabilityConfig::spacing_m`]. Eight occlusion views per site at
//! yaws 45° apart cover every direction; each is 45° wide plus a margin and tall enough for
//! condition 1 at its edges. The result depends on the scene and the robot only, not on a run,
//! so callers cache it ([`load_cached`], [`store_cached`]).

use crate::error::EvalError;
use activemap_geometry::{Intrinsics, Isometry3, PlanarPose, camera_pose_from_planar};
use activemap_sim::{DepthRange, NavigableMap, Renderer, Scene};
use nalgebra::{Point3, Vector3};
use rayon::prelude::*;
use std::hash::{Hash, Hasher};
use std::path::{Path, PathBuf};

/// Occlusion views per camera site (yaws `k·360°/8`).
const SITE_VIEWS: usize = 8;
/// Horizontal margin of each occlusion view beyond its 45° share, radians (1°).
const VIEW_MARGIN: f64 = 0.017_453_292_519_943_295;

/// Settings of the observability test.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObservabilityConfig {
    /// Lattice spacing of the camera sites, metres (0.25: a robot's footprint; the share of
    /// observable samples moves by well under a point when it is halved, see the tests).
    pub spacing_m: f64,
    /// Camera height above the floor, metres.
    pub camera_height_m: f64,
    /// Half the vertical field of view, radians.
    pub vfov_half_rad: f64,
    /// Depth range of the sensor, metres (Habitat's 10 m).
    pub max_depth_m: f64,
    /// Angular size of an occlusion view's pixel, radians (0.5°).
    pub pixel_angle_rad: f64,
}

impl ObservabilityConfig {
    /// The camera of a robot `camera_height_m` high with a `width × height` image of horizontal
    /// field of view `hfov_rad`, the other settings at their defaults.
    pub fn for_camera(camera_height_m: f64, width: u32, height: u32, hfov_rad: f64) -> Self {
        let vfov_half_rad = ((0.5 * hfov_rad).tan() * height as f64 / width as f64).atan();
        Self {
            spacing_m: 0.25,
            camera_height_m,
            vfov_half_rad,
            max_depth_m: 10.0,
            pixel_angle_rad: 0.5f64.to_radians(),
        }
    }

    /// How far a sample may lie behind the rendered depth at its pixel and still count as
    /// seen, metres: 2 cm plus half a pixel's footprint at z-depth `z` on a surface whose
    /// normal makes angle θ with the ray (`cos_incidence` = |cos θ|; tan θ capped at 5).
    pub fn occlusion_tolerance(&self, z: f64, cos_incidence: f64) -> f64 {
        let c = cos_incidence.clamp(1e-6, 1.0);
        let tan = ((1.0 - c * c).sqrt() / c).min(5.0);
        0.02 + 0.5 * z * self.pixel_angle_rad * tan
    }

    fn check(&self) -> Result<(), EvalError> {
        let ok = |v: f64| v.is_finite() && v > 0.0;
        if ok(self.spacing_m)
            && self.camera_height_m.is_finite()
            && ok(self.vfov_half_rad)
            && self.vfov_half_rad < 1.5
            && ok(self.max_depth_m)
            && ok(self.pixel_angle_rad)
        {
            Ok(())
        } else {
            Err(EvalError::InvalidParameter {
                metric: "observability",
                detail: format!("settings out of range: {self:?}"),
            })
        }
    }

    /// The intrinsics of one occlusion view.
    fn view_intrinsics(&self) -> Intrinsics {
        let f = 1.0 / self.pixel_angle_rad.tan();
        let half_w = (std::f64::consts::PI / SITE_VIEWS as f64 + VIEW_MARGIN).tan();
        // At the view's side edges a sample at the top of the field of view projects higher.
        let half_h = self.vfov_half_rad.tan()
            / (std::f64::consts::PI / SITE_VIEWS as f64 + VIEW_MARGIN).cos()
            + 2.0 / f;
        let width = (2.0 * f * half_w).ceil() as u32;
        let height = (2.0 * f * half_h).ceil() as u32;
        Intrinsics {
            width,
            height,
            fx: f,
            fy: f,
            cx: 0.5 * width as f64 - 0.5,
            cy: 0.5 * height as f64 - 0.5,
        }
    }
}

/// The camera sites: centres of the `reachable` cells of `map` on a lattice of `spacing_m`.
pub fn camera_sites(map: &NavigableMap, reachable: &[bool], spacing_m: f64) -> Vec<[f64; 2]> {
    let frame = map.frame;
    let stride = ((spacing_m / frame.cell_size).round() as usize).max(1);
    let mut sites = Vec::new();
    for j in (0..frame.height).step_by(stride) {
        for i in (0..frame.width).step_by(stride) {
            if reachable.get(j * frame.width + i).copied().unwrap_or(false) {
                let (x, y) = frame.centre(i, j);
                sites.push([x, y]);
            }
        }
    }
    sites
}

/// Per sample (`points` with their triangle `normals`, any sign): whether some camera site of
/// `sites` (world x, y on the floor at `floor_z`) observes it in `scene` (see the module doc).
pub fn observable_samples(
    scene: &Scene,
    sites: &[[f64; 2]],
    floor_z: f64,
    config: &ObservabilityConfig,
    points: &[Point3<f64>],
    normals: &[Vector3<f64>],
) -> Result<Vec<bool>, EvalError> {
    config.check()?;
    if points.len() != normals.len() {
        return Err(EvalError::SizeMismatch {
            metric: "observability",
            detail: format!("{} samples but {} normals", points.len(), normals.len()),
        });
    }
    let k = config.view_intrinsics();
    let range = DepthRange {
        near: 0.01,
        max_depth: 1e4,
    };
    let tan_v = config.vfov_half_rad.tan();
    let step = 2.0 * std::f64::consts::PI / SITE_VIEWS as f64;
    let seen = sites
        .par_iter()
        .map_init(Renderer::new, |renderer, site| {
            let cameras: Vec<Isometry3<f64>> = (0..SITE_VIEWS)
                .map(|v| {
                    let pose = PlanarPose::new(site[0], site[1], v as f64 * step);
                    camera_pose_from_planar(&pose, floor_z, config.camera_height_m)
                })
                .collect();
            let eye = Point3::new(site[0], site[1], floor_z + config.camera_height_m);
            let depths: Vec<Vec<f32>> = cameras
                .iter()
                .map(|t| renderer.render(scene, &k, t, range).depth)
                .collect();
            let to_camera: Vec<Isometry3<f64>> = cameras.iter().map(|t| t.inverse()).collect();
            points
                .iter()
                .zip(normals)
                .map(|(p, n)| {
                    let d = p - eye;
                    let r = d.x.hypot(d.y);
                    if r < 1e-6 || r > config.max_depth_m || d.z.abs() > r * tan_v {
                        return false;
                    }
                    let yaw = d.y.atan2(d.x).rem_euclid(2.0 * std::f64::consts::PI);
                    let view = ((yaw / step).round() as usize) % SITE_VIEWS;
                    let pc = to_camera[view] * p;
                    if pc.z <= range.near {
                        return false;
                    }
                    let u = (k.fx * pc.x / pc.z + k.cx).round();
                    let v = (k.fy * pc.y / pc.z + k.cy).round();
                    if u < 0.0 || v < 0.0 || u >= k.width as f64 || v >= k.height as f64 {
                        return false;
                    }
                    let rendered = depths[view][v as usize * k.width as usize + u as usize];
                    if rendered <= 0.0 {
                        // Nothing drawn at this pixel: nothing in front of the sample either.
                        return true;
                    }
                    let cos = (n.dot(&d) / d.norm()).abs();
                    f64::from(rendered) >= pc.z - config.occlusion_tolerance(pc.z, cos)
                })
                .collect::<Vec<bool>>()
        })
        .reduce(
            || vec![false; points.len()],
            |mut a, b| {
                for (x, y) in a.iter_mut().zip(b) {
                    *x |= y;
                }
                a
            },
        );
    Ok(seen)
}

/// The cache key of an observability result: a hash of everything it depends on (the scene's
/// content hash, the samples, the sites, the floor and the settings). `std`'s `DefaultHasher::new()`: the same for every instance, though
/// not promised across Rust releases, which is all a cache needs (a new toolchain at worst
/// recomputes).
pub fn cache_key(
    scene: &Scene,
    sites: &[[f64; 2]],
    floor_z: f64,
    config: &ObservabilityConfig,
    points: &[Point3<f64>],
) -> u64 {
    let mut h = std::hash::DefaultHasher::new();
    (scene.content_hash(), points.len()).hash(&mut h);
    for p in points {
        for c in p.coords.iter() {
            c.to_bits().hash(&mut h);
        }
    }
    for s in sites {
        s.map(f64::to_bits).hash(&mut h);
    }
    for v in [
        floor_z,
        config.spacing_m,
        config.camera_height_m,
        config.vfov_half_rad,
        config.max_depth_m,
        config.pixel_angle_rad,
    ] {
        v.to_bits().hash(&mut h);
    }
    h.finish()
}

/// First line of a cache file.
const CACHE_MAGIC: &[u8] = b"activemap observable v1\n";

/// The cache file of `key` in `dir`.
pub fn cache_path(dir: &Path, key: u64) -> PathBuf {
    dir.join(format!("observable-{key:016x}.bin"))
}

/// The flags cached under `key` in `dir`, if a valid file of `len` flags is there (a missing,
/// short or foreign file is a miss, never an error: the flags are recomputed).
pub fn load_cached(dir: &Path, key: u64, len: usize) -> Option<Vec<bool>> {
    let bytes = std::fs::read(cache_path(dir, key)).ok()?;
    let body = bytes.strip_prefix(CACHE_MAGIC)?;
    let (count, bits) = body.split_at_checked(8)?;
    let count = u64::from_le_bytes(count.try_into().ok()?) as usize;
    if count != len || bits.len() != len.div_ceil(8) {
        return None;
    }
    Some((0..len).map(|i| bits[i / 8] >> (i % 8) & 1 == 1).collect())
}

/// Writes `flags` under `key` in `dir` (created if needed), through a temporary file renamed
/// into place so a reader never sees half a file.
pub fn store_cached(dir: &Path, key: u64, flags: &[bool]) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let mut bytes = CACHE_MAGIC.to_vec();
    bytes.extend_from_slice(&(flags.len() as u64).to_le_bytes());
    let mut bits = vec![0u8; flags.len().div_ceil(8)];
    for (i, &f) in flags.iter().enumerate() {
        bits[i / 8] |= u8::from(f) << (i % 8);
    }
    bytes.extend_from_slice(&bits);
    let path = cache_path(dir, key);
    let tmp = path.with_extension(format!("tmp{}", std::process::id()));
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, &path)
}

/// The default cache folder: `ACTIVEMAP_CACHE_DIR`, else `$XDG_CACHE_HOME/activemap`, else
/// `$HOME/.cache/activemap`; `None` when none is set.
pub fn default_cache_dir() -> Option<PathBuf> {
    let var = |name: &str| std::env::var_os(name).filter(|v| !v.is_empty());
    var("ACTIVEMAP_CACHE_DIR")
        .map(PathBuf::from)
        .or_else(|| var("XDG_CACHE_HOME").map(|d| PathBuf::from(d).join("activemap")))
        .or_else(|| var("HOME").map(|d| PathBuf::from(d).join(".cache/activemap")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::box_scene;
    use activemap_sim::navigation::GridFrame;

    fn config() -> ObservabilityConfig {
        ObservabilityConfig::for_camera(0.88, 160, 160, 90f64.to_radians())
    }

    /// A lattice of samples on the face `x = x0` of a slab, `y` in [−0.9, 0.9], `z` in
    /// [0.1, 1.4], with the face's normal.
    fn face(x0: f64, normal: f64) -> (Vec<Point3<f64>>, Vec<Vector3<f64>>) {
        let points: Vec<Point3<f64>> = (0..10)
            .flat_map(|i| {
                (0..6).map(move |j| Point3::new(x0, -0.9 + 0.2 * i as f64, 0.1 + 0.26 * j as f64))
            })
            .collect();
        let normals = vec![Vector3::new(normal, 0.0, 0.0); points.len()];
        (points, normals)
    }

    #[test]
    fn a_slab_is_seen_from_its_side_and_not_from_behind_or_above() {
        // A 40 cm slab, 1.5 m high, 2 m in front of the sites.
        let scene = box_scene(&[([2.0, -1.0, 0.0], [2.4, 1.0, 1.5])]);
        let sites = [[0.0, 0.0], [0.5, 0.3]];
        let (front, front_n) = face(2.0, -1.0);
        let (back, back_n) = face(2.4, 1.0);
        let seen = |p: &[Point3<f64>], n: &[Vector3<f64>]| {
            observable_samples(&scene, &sites, 0.0, &config(), p, n).unwrap()
        };
        assert!(
            seen(&front, &front_n).iter().all(|&s| s),
            "the near face is seen"
        );
        assert!(seen(&back, &back_n).iter().all(|&s| !s), "its back is not");
        // The top face, 0.62 m above the camera: only visible from above.
        let top: Vec<Point3<f64>> = (0..9)
            .map(|i| Point3::new(2.2, -0.8 + 0.2 * i as f64, 1.5))
            .collect();
        let up = vec![Vector3::z(); top.len()];
        assert!(seen(&top, &up).iter().all(|&s| !s), "its top is not");
        // From a site behind the slab the back is seen instead.
        let behind =
            observable_samples(&scene, &[[4.5, 0.0]], 0.0, &config(), &back, &back_n).unwrap();
        assert!(behind.iter().all(|&s| s));
    }

    #[test]
    fn the_field_of_view_and_the_depth_range_limit_what_is_seen() {
        let scene = box_scene(&[]);
        let points = [
            // 1 m away, 0.9 m above the camera: inside the 45° half field of view.
            Point3::new(1.0, 0.0, 1.78),
            // 1 m away, 1.1 m above it: outside.
            Point3::new(1.0, 0.0, 1.98),
            // Behind the robot: any yaw is allowed, so seen.
            Point3::new(-3.0, 0.5, 0.5),
            // 10.5 m away: beyond the depth range.
            Point3::new(10.5, 0.0, 0.88),
        ];
        let normals = [Vector3::x(); 4];
        let seen =
            observable_samples(&scene, &[[0.0, 0.0]], 0.0, &config(), &points, &normals).unwrap();
        assert_eq!(seen, [true, false, true, false]);
    }

    #[test]
    fn sites_follow_the_lattice_over_reachable_cells() {
        let frame = GridFrame {
            origin_x: 0.0,
            origin_y: 0.0,
            cell_size: 0.05,
            width: 20,
            height: 10,
        };
        let map = NavigableMap {
            frame,
            cells: vec![true; 200],
        };
        // Only the left half reachable.
        let reachable: Vec<bool> = (0..200).map(|c| c % 20 < 10).collect();
        let sites = camera_sites(&map, &reachable, 0.25);
        // Columns 0 and 5, rows 0 and 5.
        assert_eq!(sites.len(), 4, "{sites:?}");
        assert!(sites.iter().all(|s| s[0] < 0.5));
        assert!((sites[1][0] - 0.275).abs() < 1e-12, "{sites:?}");
    }

    #[test]
    fn the_cache_returns_what_was_stored_and_ignores_foreign_files() {
        let dir = tempfile::tempdir().unwrap();
        let flags: Vec<bool> = (0..19).map(|i| i % 3 == 0).collect();
        store_cached(dir.path(), 42, &flags).unwrap();
        assert_eq!(load_cached(dir.path(), 42, 19), Some(flags));
        assert_eq!(load_cached(dir.path(), 42, 20), None, "other sample count");
        assert_eq!(load_cached(dir.path(), 7, 19), None, "other key");
        std::fs::write(cache_path(dir.path(), 9), b"not a cache").unwrap();
        assert_eq!(load_cached(dir.path(), 9, 19), None);
        let scene = box_scene(&[([0.0; 3], [1.0; 3])]);
        let c = config();
        let p = [Point3::new(1.0, 0.5, 0.5)];
        let key = cache_key(&scene, &[[0.0, 0.0]], 0.0, &c, &p);
        assert_eq!(key, cache_key(&scene, &[[0.0, 0.0]], 0.0, &c, &p));
        assert_ne!(key, cache_key(&scene, &[[0.0, 0.25]], 0.0, &c, &p));
        let other = box_scene(&[([0.0; 3], [1.0, 1.0, 2.0])]);
        assert_ne!(key, cache_key(&other, &[[0.0, 0.0]], 0.0, &c, &p));
    }
}
