//! Gaussian insertion from a keyframe's depth (SPEC §4): back-project a seeded random
//! fraction of the depth pixels that lie in UNOBSERVED areas (SPEC's 1/64 at 640×480; at other
//! resolutions the same number of samples per full image, see [`InsertConfig`]), colour from the
//! pixel, opacity 0.8 (see [`InsertConfig::opacity`]), identity rotation and isotropic scale,
//! or, with [`InsertConfig::normal_thickness`], a flat disc lying in the surface whose normal
//! the depth image shows around the pixel ([`surface_normal`]).
//!
//! Unobserved (decision documented here): a pixel with a depth reading is unobserved when the
//! current map, rendered at the keyframe pose without unknown-space Gaussians, covers it with
//! opacity below `min_opacity` (0.5), or when the map's normalised depth `D̂/o` disagrees with
//! the reading by more than `max(depth_tolerance, depth_tolerance_fraction·D)` (5 cm, 5 %):
//! then the map shows a different surface there, either behind the reading (new geometry in
//! front of what the map shows, [`PixelCoverage::Nearer`]) or in front of it (the map shows
//! something the camera sees through, [`PixelCoverage::Farther`]; a source of new Gaussians
//! unless [`InsertConfig::insert_behind_map`] is off, SplaTAM's choice). The mapper logs each
//! keyframe's unexplained pixels by cause.
//!
//! Scale (default): `scale_factor` (0.5) × the depth-based pixel footprint `z/f` × the expected
//! sample spacing `1/√fraction` pixels (`fraction` from [`effective_fraction`]).
//! Alternatively, as 3DGS, `s = √(mean squared distance to the 3 nearest new points)`. Both
//! are clamped to `[min_scale, max_scale]`. The neighbour search is brute force over the new points of the
//! keyframe (at most a few thousand), which is simple and exact.

use crate::frame::Frame;
use activemap_geometry::{Isometry3, Point3};
use activemap_splat::Render;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// Insertion settings.
#[derive(Debug, Clone, PartialEq)]
pub struct InsertConfig {
    /// Fraction of the unobserved depth pixels back-projected (SPEC: 1/64, for 640×480).
    /// The fraction used is the larger of this and `target_samples / pixels`.
    pub sample_fraction: f64,
    /// Samples a full unobserved image would give (4800 = 640·480/64): keeps the angular
    /// density of SPEC's 1/64 at 640×480 at any resolution (0.19 at 160², 0.12 at 200²).
    /// 0 uses `sample_fraction` alone.
    pub target_samples: usize,
    /// Rendered opacity below which a pixel is unobserved (0.5).
    pub min_opacity: f32,
    /// Absolute depth disagreement that makes a covered pixel unobserved, metres (0.05).
    pub depth_tolerance: f32,
    /// Relative depth disagreement that makes a covered pixel unobserved (0.05).
    pub depth_tolerance_fraction: f32,
    /// Initial opacity (0.8; SPEC says 0.5: with few CPU iterations per keyframe a start at
    /// 0.8 covers the view at once and measured +0.1 dB held-out, see tests/mapping_quality.rs).
    pub opacity: f64,
    /// Initial scale = `scale_factor ×` the nearest-neighbour distance (3DGS: 1), or with
    /// `footprint_scale`, `scale_factor ×` the spacing of the samples on the surface (0.5:
    /// neighbours still overlap at 1σ, each pixel is covered by ~4× fewer Gaussians than at 1,
    /// which made rendering ~3× faster and biased depth less; measured in
    /// tests/mapping_quality.rs).
    pub scale_factor: f64,
    /// Scale from the depth-based pixel footprint `z / f / √fraction` (the expected
    /// spacing of the samples) instead of the nearest-neighbour search: O(n), and it does not
    /// leave isolated samples with huge scales.
    pub footprint_scale: bool,
    /// Smallest initial scale, metres.
    pub min_scale: f64,
    /// Largest initial scale, metres.
    pub max_scale: f64,
    /// Upper bound on Gaussians inserted per keyframe (keeps the neighbour search bounded).
    pub max_per_keyframe: usize,
    /// Fraction of the depth pixels the map already explains that are back-projected at every
    /// keyframe as well (MonoGS inserts a random 1/64 of all valid depth pixels each keyframe,
    /// SPEC §4), so an already covered surface gets fresh on-surface Gaussians (issue 33);
    /// 0 = off (default: only unobserved pixels are sampled). Measured at 1/64 on `activemap
    /// bench slam --cases 200x250`: surface offset −2.81 → −3.04 cm (no help), held-out PSNR
    /// 28.10 → 28.96 dB, depth MAE 3.17 → 2.51 cm, but 2.5× the Gaussians and ~3× the mapping
    /// time per keyframe.
    pub refresh_fraction: f64,
    /// Initial opacity of the refresh Gaussians (SPEC §4: 0.5).
    pub refresh_opacity: f64,
    /// Whether a reading behind the map's surface ([`PixelCoverage::Farther`]) is a source of
    /// new Gaussians (true: the rule is symmetric). SplaTAM inserts only where the reading lies
    /// in front of the rendered surface.
    pub insert_behind_map: bool,
    /// Thickness of an inserted Gaussian along the surface normal, as a share of its in-plane
    /// scale (issue 33; 0.1, a deviation from SPEC §4); 0 = off: isotropic, identity rotation
    /// (SPEC §4). When on, each sample whose depth neighbourhood is locally planar
    /// ([`surface_normal`]) becomes a disc lying in the surface: its third axis along the normal
    /// estimated from the depth image, this share of the scale thick, and its in-plane axis
    /// along the viewing direction stretched by
    /// `1/cos(incidence)` (at most [`InsertConfig::max_grazing_stretch`]) so that the samples,
    /// evenly spaced in pixels, still cover a surface seen at a grazing angle. A round Gaussian
    /// that a grazing ray meets renders the surface in front of the reading, and ten iterations
    /// per keyframe cannot flatten it; a disc renders the surface where it is (measured in
    /// `docs/src/slam.md`, "Discs in the surface": on `benchmarks/disc-insertion*.yaml`, FBE on
    /// three houses and two seeds, noise-free, every pair gained PSNR, SSIM, LPIPS, depth MAE
    /// and completeness). Use it with the mapper's `isotropic_weight` at 0 (its default), which
    /// would pull the discs round again.
    pub normal_thickness: f64,
    /// Largest stretch of an oriented Gaussian's in-plane axis along the viewing direction
    /// (3: the `1/cos(incidence)` of [`InsertConfig::normal_thickness`] reaches 3 at about 70°
    /// incidence); 1 = round discs. The stretched scale may exceed `max_scale` (the mapper's
    /// `prune_max_scale` still bounds it).
    pub max_grazing_stretch: f64,
    /// How far, in its stretched scales, a disc's stretched axis must find its own plane in the
    /// depth image at both ends before it is stretched (issue 33; 0 = off, the stretch of
    /// [`InsertConfig::max_grazing_stretch`] regardless). A surface seen at a grazing angle
    /// packs many centimetres into a pixel, so a stretched disc near the surface's far or near
    /// end (a door frame's side, a wall's end) reaches past it; the view that inserts it cannot
    /// see the overhang (it lies along the ray), but every test view close by sees it as a
    /// surface in front of what lies behind. With this on, such a disc gets the largest of the
    /// full stretch, half of it, or none ([`supported_stretch`]) whose ends the depth image
    /// confirms. Off by default: at 2, in closed-loop FBE episodes
    /// (`benchmarks/grazing-stretch-noise-free.yaml`, 6 pairs) completeness +0.58 points (6 of
    /// 6), PSNR +0.11 dB and depth MAE −0.8 cm (3 of 6 each); with the realistic sensor
    /// (`benchmarks/grazing-stretch.yaml`) nothing (PSNR −0.06 dB, depth MAE +0.4 cm); on the
    /// README's main-run trajectory PSNR −0.20 dB and depth MAE +1.0 cm (`docs/src/slam.md`).
    pub stretch_support_sigmas: f64,
}

impl Default for InsertConfig {
    fn default() -> Self {
        Self {
            sample_fraction: 1.0 / 64.0,
            target_samples: 4800,
            min_opacity: 0.5,
            depth_tolerance: 0.05,
            depth_tolerance_fraction: 0.05,
            opacity: 0.8,
            scale_factor: 0.5,
            footprint_scale: true,
            min_scale: 0.002,
            max_scale: 0.2,
            max_per_keyframe: 8000,
            refresh_fraction: 0.0,
            refresh_opacity: 0.5,
            insert_behind_map: true,
            normal_thickness: 0.1,
            max_grazing_stretch: 3.0,
            stretch_support_sigmas: 0.0,
        }
    }
}

/// Why a pixel with a depth reading is (or is not) explained by the rendered map (see the
/// module doc): the insertion decision, per pixel, with its cause.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelCoverage {
    /// No depth reading: never a source of new Gaussians.
    NoReading,
    /// The map covers the pixel and its normalised depth agrees with the reading.
    Explained,
    /// Rendered opacity below `min_opacity`: the map has nothing there yet.
    Transparent,
    /// The reading lies in front of the map's surface by more than the tolerance: new geometry
    /// in front of what the map shows.
    Nearer,
    /// The reading lies behind the map's surface by more than the tolerance: the map shows
    /// something (a floater, a surface that is not there) in front of the real one.
    Farther,
}

impl PixelCoverage {
    /// Whether the pixel is a source of new Gaussians under `config`
    /// ([`InsertConfig::insert_behind_map`] decides for [`PixelCoverage::Farther`]).
    pub fn unobserved(self, config: &InsertConfig) -> bool {
        match self {
            Self::NoReading | Self::Explained => false,
            Self::Transparent | Self::Nearer => true,
            Self::Farther => config.insert_behind_map,
        }
    }
}

/// Per pixel: how the rendered map explains the frame's depth (see [`PixelCoverage`]).
pub fn pixel_coverage(
    render: &Render<f32>,
    frame: &Frame,
    config: &InsertConfig,
) -> Vec<PixelCoverage> {
    frame
        .depth
        .iter()
        .enumerate()
        .map(|(p, &d)| {
            if d <= 0.0 {
                return PixelCoverage::NoReading;
            }
            let o = render.opacity[p];
            if o < config.min_opacity {
                return PixelCoverage::Transparent;
            }
            let rendered = render.depth[p] / o;
            let tolerance = config
                .depth_tolerance
                .max(config.depth_tolerance_fraction * d);
            if d < rendered - tolerance {
                PixelCoverage::Nearer
            } else if d > rendered + tolerance {
                PixelCoverage::Farther
            } else {
                PixelCoverage::Explained
            }
        })
        .collect()
}

/// How many pixels of each insertion cause a keyframe had (see [`PixelCoverage`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CoverageCounts {
    /// [`PixelCoverage::Transparent`] pixels.
    pub transparent: usize,
    /// [`PixelCoverage::Nearer`] pixels.
    pub nearer: usize,
    /// [`PixelCoverage::Farther`] pixels.
    pub farther: usize,
}

impl CoverageCounts {
    /// Counts the causes of `coverage`.
    pub fn of(coverage: &[PixelCoverage]) -> Self {
        let mut counts = Self::default();
        for c in coverage {
            match c {
                PixelCoverage::Transparent => counts.transparent += 1,
                PixelCoverage::Nearer => counts.nearer += 1,
                PixelCoverage::Farther => counts.farther += 1,
                PixelCoverage::NoReading | PixelCoverage::Explained => {}
            }
        }
        counts
    }
}

/// Per pixel: true where the frame has depth that the rendered map does not explain, from the
/// pixels' [`pixel_coverage`] (the sources of new Gaussians under `config`).
pub fn unobserved_mask(coverage: &[PixelCoverage], config: &InsertConfig) -> Vec<bool> {
    coverage.iter().map(|c| c.unobserved(config)).collect()
}

/// Per pixel: true where the frame has depth that [`unobserved_mask`]'s `unobserved` leaves
/// out, i.e. what the map already explains (the candidates of the refresh insertion).
pub fn explained_mask(frame: &Frame, unobserved: &[bool]) -> Vec<bool> {
    frame
        .depth
        .iter()
        .zip(unobserved)
        .map(|(&d, &u)| d > 0.0 && !u)
        .collect()
}

/// The sampling fraction used for an image of `pixels` pixels (see [`InsertConfig`]).
pub fn effective_fraction(config: &InsertConfig, pixels: usize) -> f64 {
    let target = config.target_samples as f64 / pixels.max(1) as f64;
    config.sample_fraction.max(target).min(1.0)
}

/// A Gaussian to insert, in natural units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewGaussian {
    /// World position, metres.
    pub mean: [f64; 3],
    /// RGB in [0, 1].
    pub rgb: [f64; 3],
    /// Rotation `[w, x, y, z]` (world from Gaussian axes); identity when isotropic.
    pub rotation: [f64; 4],
    /// Scales along the Gaussian's three axes, metres (equal when isotropic; the third is the
    /// surface normal's when [`InsertConfig::normal_thickness`] oriented it).
    pub scales: [f64; 3],
}

/// Pixels on each side of a sample that [`surface_normal`] differences over (2: at 160² the
/// stencil spans 4 pixels, which averages sensor noise while staying on one surface).
pub const NORMAL_STENCIL_PX: usize = 2;

/// Largest second difference of inverse depth across the stencil, relative to the sample's,
/// that still counts as one plane: the inverse depth of a plane is affine in the pixel
/// coordinates, so its second difference vanishes; a step or a corner breaks it.
pub const PLANARITY_TOLERANCE: f64 = 0.05;

/// The unit normal, in the camera frame and facing the camera, of the surface the depth
/// image shows around pixel `(u, v)`: the cross product of the back-projected central
/// differences over [`NORMAL_STENCIL_PX`] along each image axis. `None` where a neighbour is
/// outside the image or has no reading, or where the neighbourhood is not one plane
/// ([`PLANARITY_TOLERANCE`] on each axis).
pub fn surface_normal(frame: &Frame, u: usize, v: usize) -> Option<nalgebra::Vector3<f64>> {
    let d = NORMAL_STENCIL_PX;
    let (w, h) = (frame.width(), frame.height());
    if u < d || v < d || u + d >= w || v + d >= h {
        return None;
    }
    let depth = |x: usize, y: usize| {
        let z = frame.depth[y * w + x] as f64;
        (z.is_finite() && z > 0.0).then_some(z)
    };
    let centre = 1.0 / depth(u, v)?;
    let point = |x: usize, y: usize| -> Option<nalgebra::Vector3<f64>> {
        let z = depth(x, y)?;
        Some(frame.intrinsics.unproject(x as f64, y as f64, z).coords)
    };
    let planar = |a: usize, b: usize, c: usize, e: usize| -> Option<()> {
        let second = 1.0 / depth(a, b)? + 1.0 / depth(c, e)? - 2.0 * centre;
        (second.abs() <= PLANARITY_TOLERANCE * centre).then_some(())
    };
    planar(u - d, v, u + d, v)?;
    planar(u, v - d, u, v + d)?;
    let along_u = point(u + d, v)? - point(u - d, v)?;
    let along_v = point(u, v + d)? - point(u, v - d)?;
    let normal = along_u.cross(&along_v).try_normalize(1e-12)?;
    let ray = point(u, v)?;
    Some(if normal.dot(&ray) > 0.0 {
        -normal
    } else {
        normal
    })
}

/// The rotation `[w, x, y, z]` and scales of a disc of in-plane scale `scale` lying in the
/// surface of camera-frame normal `normal` at camera-frame point `point`, in the world of
/// `pose` (see [`InsertConfig::normal_thickness`]).
fn oriented_disc(
    frame: &Frame,
    pose: &Isometry3<f64>,
    point: &nalgebra::Vector3<f64>,
    normal: &nalgebra::Vector3<f64>,
    scale: f64,
    config: &InsertConfig,
) -> ([f64; 4], [f64; 3]) {
    let ray = point.normalize();
    let cos_incidence = normal.dot(&ray).abs();
    // The in-plane direction the viewing ray leans along; any in-plane axis when head-on.
    let lean = ray - normal * normal.dot(&ray);
    let first = lean.try_normalize(1e-9).unwrap_or_else(|| {
        let helper = if normal.x.abs() < 0.9 {
            nalgebra::Vector3::x()
        } else {
            nalgebra::Vector3::y()
        };
        normal.cross(&helper).normalize()
    });
    let second = normal.cross(&first);
    let camera_axes = nalgebra::Matrix3::from_columns(&[first, second, *normal]);
    let world_axes = pose.rotation.to_rotation_matrix().matrix() * camera_axes;
    let rotation = nalgebra::UnitQuaternion::from_rotation_matrix(
        &nalgebra::Rotation3::from_matrix_unchecked(world_axes),
    );
    let stretch = (1.0 / cos_incidence.max(1e-9)).min(config.max_grazing_stretch);
    let stretch = supported_stretch(
        frame,
        point,
        normal,
        &first,
        scale,
        stretch,
        config.stretch_support_sigmas,
    );
    (
        [rotation.w, rotation.i, rotation.j, rotation.k],
        [scale * stretch, scale, scale * config.normal_thickness],
    )
}

/// Relative depth disagreement within which a pixel lies on a disc's plane
/// ([`supported_stretch`]).
pub const STRETCH_SUPPORT_TOLERANCE: f64 = 0.05;

/// The stretch a disc at camera-frame `point` (plane normal `normal`, stretched in-plane axis
/// `axis`, in-plane scale `scale`) may take, at most `stretch`: the first of `stretch`,
/// `(1 + stretch) / 2` and 1 whose two ends `point ± sigmas · stretch · scale · axis` the
/// depth image confirms. An end is confirmed when it projects into the image onto a pixel whose
/// reading lies on the disc's plane, along that pixel's ray, within
/// [`STRETCH_SUPPORT_TOLERANCE`] of the plane's depth. `sigmas` 0 returns `stretch`.
pub fn supported_stretch(
    frame: &Frame,
    point: &nalgebra::Vector3<f64>,
    normal: &nalgebra::Vector3<f64>,
    axis: &nalgebra::Vector3<f64>,
    scale: f64,
    stretch: f64,
    sigmas: f64,
) -> f64 {
    if sigmas <= 0.0 || stretch <= 1.0 {
        return stretch;
    }
    let plane_offset = normal.dot(point);
    let on_plane = |end: nalgebra::Vector3<f64>| -> bool {
        let Some((u, v)) = frame.pixel_of(&Point3::from(end), 0) else {
            return false;
        };
        // Frame::new has turned every non-finite or negative reading into 0 (no reading).
        let reading = frame.depth[v * frame.width() + u] as f64;
        if reading <= 0.0 {
            return false;
        }
        // The plane's z-depth along the pixel's ray (the ray at unit z-depth).
        let ray = frame.intrinsics.unproject(u as f64, v as f64, 1.0).coords;
        let along = normal.dot(&ray);
        if along.abs() < 1e-9 {
            return false;
        }
        let plane_depth = plane_offset / along;
        plane_depth > 0.0
            && (reading - plane_depth).abs() <= STRETCH_SUPPORT_TOLERANCE * plane_depth
    };
    for candidate in [stretch, 0.5 * (1.0 + stretch)] {
        let reach = axis * (sigmas * candidate * scale);
        if on_plane(point + reach) && on_plane(point - reach) {
            return candidate;
        }
    }
    1.0
}

/// Samples the new Gaussians of a keyframe at `T_world_camera = pose` (see the module doc).
pub fn sample_new_gaussians(
    frame: &Frame,
    pose: &Isometry3<f64>,
    mask: &[bool],
    config: &InsertConfig,
    rng: &mut ChaCha8Rng,
) -> Vec<NewGaussian> {
    let w = frame.width();
    let k = &frame.intrinsics;
    let fraction = effective_fraction(config, mask.len());
    let mut points = Vec::new();
    for (p, &unobserved) in mask.iter().enumerate() {
        // Draw for every pixel so the stream of random numbers does not depend on the mask.
        let pick = rng.random::<f64>() < fraction;
        if !unobserved || !pick {
            continue;
        }
        let (u, v) = ((p % w) as f64, (p / w) as f64);
        let camera_point: Point3<f64> = k.unproject(u, v, frame.depth[p] as f64);
        points.push((p, camera_point, pose * camera_point));
    }
    if points.len() > config.max_per_keyframe {
        // Uniform random subset (partial Fisher–Yates), so the cap does not favour any region.
        for i in 0..config.max_per_keyframe {
            let j = rng.random_range(i..points.len());
            points.swap(i, j);
        }
        points.truncate(config.max_per_keyframe);
    }
    let positions: Vec<[f64; 3]> = points.iter().map(|(_, _, q)| [q.x, q.y, q.z]).collect();
    let scales = if config.footprint_scale {
        let focal = 0.5 * (k.fx.abs() + k.fy.abs());
        let spacing = 1.0 / fraction.sqrt();
        points
            .iter()
            .map(|(p, _, _)| frame.depth[*p] as f64 / focal * spacing)
            .collect()
    } else {
        nearest_neighbour_scales(&positions, 3)
    };
    points
        .iter()
        .zip(scales)
        .map(|((p, camera_point, world), s)| {
            let scale = if s.is_finite() {
                (s * config.scale_factor).clamp(config.min_scale, config.max_scale)
            } else {
                config.max_scale
            };
            let normal = (config.normal_thickness > 0.0)
                .then(|| surface_normal(frame, p % w, p / w))
                .flatten();
            let (rotation, scales) = match normal {
                Some(n) => oriented_disc(frame, pose, &camera_point.coords, &n, scale, config),
                None => ([1.0, 0.0, 0.0, 0.0], [scale; 3]),
            };
            NewGaussian {
                mean: [world.x, world.y, world.z],
                rgb: frame.rgb[*p].map(|c| c as f64),
                rotation,
                scales,
            }
        })
        .collect()
}

/// Per point, √(mean squared distance to its `k` nearest other points) (∞ for a lone point).
pub fn nearest_neighbour_scales(points: &[[f64; 3]], k: usize) -> Vec<f64> {
    points
        .par_iter()
        .enumerate()
        .map(|(i, a)| {
            let mut best = vec![f64::INFINITY; k];
            for (j, b) in points.iter().enumerate() {
                if i == j {
                    continue;
                }
                let d2 = (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2);
                if d2 < best[k - 1] {
                    best[k - 1] = d2;
                    best.sort_by(f64::total_cmp);
                }
            }
            let finite: Vec<f64> = best.into_iter().filter(|d| d.is_finite()).collect();
            if finite.is_empty() {
                f64::INFINITY
            } else {
                (finite.iter().sum::<f64>() / finite.len() as f64).sqrt()
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_geometry::Intrinsics;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};
    use rand::SeedableRng;

    /// A 32² frame (90° hfov) of the plane `n·X = c` in the camera frame (no reading where the
    /// ray misses it or meets it behind the camera), grey.
    fn plane_frame(n: Vector3<f64>, c: f64) -> Frame {
        let k = Intrinsics::from_hfov(32, 32, std::f64::consts::FRAC_PI_2);
        let mut depth = Vec::new();
        for v in 0..32 {
            for u in 0..32 {
                let ray = k.unproject(u as f64, v as f64, 1.0).coords; // z = 1
                let t = c / n.dot(&ray);
                depth.push(if t > 0.0 { t as f32 } else { 0.0 });
            }
        }
        Frame::new(k, vec![[0.5; 3]; 32 * 32], depth, 0.0).unwrap()
    }

    /// Rotation matrix of a `[w, x, y, z]` quaternion.
    fn axes(q: [f64; 4]) -> nalgebra::Matrix3<f64> {
        UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]))
            .to_rotation_matrix()
            .into_inner()
    }

    /// A disc on a floor that ends in a drop (a far wall 6 m away beyond 2 m) is stretched only
    /// as far as the depth image shows floor at both ends of its stretched axis: not at all
    /// beside the drop, half-way a little farther in, fully well inside; with the check off,
    /// fully everywhere.
    #[test]
    fn a_disc_is_stretched_only_as_far_as_its_surface_reaches() {
        // 64², 90°: f = 32, centre 31.5; the floor 0.5 m below the camera (y down) reads
        // z = 16 / (v − 31.5) on row v, so rows up to 39 (z > 2) see the wall instead.
        let k = Intrinsics::from_hfov(64, 64, std::f64::consts::FRAC_PI_2);
        let floor_depth = |v: usize| 0.5 * k.fy / (v as f64 - k.cy);
        let depth: Vec<f32> = (0..64 * 64)
            .map(|p| {
                let v = p / 64;
                if v as f64 > k.cy && floor_depth(v) <= 2.0 {
                    floor_depth(v) as f32
                } else {
                    6.0
                }
            })
            .collect();
        let frame = Frame::new(k, vec![[0.5; 3]; 64 * 64], depth, 0.0).unwrap();
        let normal = Vector3::new(0.0, -1.0, 0.0);
        let stretch_at = |v: usize, scale: f64, sigmas: f64| {
            let point = k.unproject(31.0, v as f64, floor_depth(v)).coords;
            let ray = point.normalize();
            let axis = (ray - normal * normal.dot(&ray)).normalize();
            supported_stretch(&frame, &point, &normal, &axis, scale, 3.0, sigmas)
        };
        // Row 40 (z 1.88): ±0.3 m and ±0.2 m both reach past 2 m (rows 39 and below).
        assert_eq!(stretch_at(40, 0.05, 2.0), 1.0);
        // Row 42 (z 1.52), scale 8 cm: the full reach (0.48 m) passes the drop, half (0.32) not.
        assert_eq!(stretch_at(42, 0.08, 2.0), 2.0);
        // Row 50 (z 0.87), 2 cm: ±0.12 m lies on the floor.
        assert_eq!(stretch_at(50, 0.02, 2.0), 3.0);
        assert_eq!(stretch_at(40, 0.05, 0.0), 3.0, "off");
        // An end that leaves the image is not confirmed.
        assert_eq!(stretch_at(62, 0.05, 2.0), 1.0);
    }

    #[test]
    fn the_normal_of_a_tilted_plane_is_recovered_and_faces_the_camera() {
        let n = Vector3::new(0.3, -0.5, -1.0).normalize();
        let frame = plane_frame(n, -2.0);
        for (u, v) in [(16, 16), (5, 20), (26, 4)] {
            let got = surface_normal(&frame, u, v).expect("a plane is planar");
            assert!((got - n).norm() < 1e-4, "{got} against {n} at ({u}, {v})");
            let ray = frame.intrinsics.unproject(u as f64, v as f64, 1.0).coords;
            assert!(got.dot(&ray) < 0.0, "faces the camera");
        }
        // The stencil leaves the image at the border.
        assert!(surface_normal(&frame, 1, 16).is_none());
        assert!(surface_normal(&frame, 16, 30).is_none());
    }

    #[test]
    fn a_depth_step_or_a_missing_reading_gives_no_normal() {
        let mut frame = plane_frame(-Vector3::z(), -2.0);
        assert!(surface_normal(&frame, 16, 16).is_some());
        // A box 20 cm in front of the wall right of column 17: the stencil at 16 straddles it.
        for v in 0..32 {
            for u in 18..32 {
                frame.depth[v * 32 + u] = 1.8;
            }
        }
        assert!(surface_normal(&frame, 16, 16).is_none());
        assert!(surface_normal(&frame, 10, 16).is_some());
        frame.depth[16 * 32 + 8] = 0.0;
        assert!(surface_normal(&frame, 10, 16).is_none());
    }

    #[test]
    fn oriented_insertion_lays_discs_in_the_surface_in_the_world_frame() {
        // A floor 0.88 m below a camera looking level along world +x (camera z = world x,
        // camera y = world −z): grazing everywhere.
        let frame = plane_frame(Vector3::y(), 0.88);
        let camera_to_world = nalgebra::Matrix3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0);
        let pose = Isometry3::from_parts(
            Translation3::new(1.0, 2.0, 0.88),
            UnitQuaternion::from_matrix(&camera_to_world),
        );
        let mask: Vec<bool> = frame.depth.iter().map(|&d| d > 0.0).collect();
        let isotropic = InsertConfig {
            normal_thickness: 0.0,
            ..InsertConfig::default()
        };
        let oriented = InsertConfig {
            normal_thickness: 0.1,
            ..InsertConfig::default()
        };
        let draw = |config: &InsertConfig| {
            let mut rng = ChaCha8Rng::seed_from_u64(3);
            sample_new_gaussians(&frame, &pose, &mask, config, &mut rng)
        };
        let (round, discs) = (draw(&isotropic), draw(&oriented));
        assert_eq!(round.len(), discs.len(), "the same samples either way");
        let mut oriented_count = 0;
        for (r, g) in round.iter().zip(&discs) {
            assert_eq!(r.mean, g.mean);
            assert!(g.mean[2].abs() < 1e-6, "on the floor: {:?}", g.mean);
            assert_eq!(r.rotation, [1.0, 0.0, 0.0, 0.0]);
            assert!(r.scales.iter().all(|&s| s == r.scales[0]));
            if g.scales[2] == g.scales[1] {
                continue; // no planar neighbourhood (the image border): left round
            }
            oriented_count += 1;
            let a = axes(g.rotation);
            assert!(
                (a.column(2).z.abs() - 1.0).abs() < 1e-6,
                "third axis vertical: {a}"
            );
            assert!(a.column(0).z.abs() < 1e-6, "first axis in the floor");
            assert!(
                (g.scales[1] - r.scales[0]).abs() < 1e-12,
                "in-plane scale kept"
            );
            assert!((g.scales[2] - 0.1 * r.scales[0]).abs() < 1e-12, "thickness");
            // Stretched along the view, 1/cos(incidence) up to the cap.
            let to_mean = Vector3::from(g.mean) - pose.translation.vector;
            let cos = (to_mean.z / to_mean.norm()).abs();
            let stretch = (1.0 / cos).min(oriented.max_grazing_stretch);
            assert!((g.scales[0] / g.scales[1] - stretch).abs() < 1e-6);
        }
        assert!(
            oriented_count > discs.len() / 2,
            "{oriented_count} of {}",
            discs.len()
        );
    }

    #[test]
    fn nn_scale_on_a_unit_grid() {
        // On a 3×3 planar grid of spacing 0.1 the centre's 3 nearest are at 0.1: scale 0.1;
        // a corner's are 0.1, 0.1 and √2·0.1: √((0.01+0.01+0.02)/3).
        let mut pts = Vec::new();
        for i in 0..3 {
            for j in 0..3 {
                pts.push([i as f64 * 0.1, j as f64 * 0.1, 1.0]);
            }
        }
        let s = nearest_neighbour_scales(&pts, 3);
        assert!((s[4] - 0.1).abs() < 1e-12);
        assert!((s[0] - (0.04f64 / 3.0).sqrt()).abs() < 1e-12);
        assert!(nearest_neighbour_scales(&[[0.0; 3]], 3)[0].is_infinite());
    }
}
