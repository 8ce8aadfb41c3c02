//! Gaussian insertion from a keyframe's depth (SPEC §4): back-project a seeded random
//! fraction of the depth pixels that lie in UNOBSERVED areas (SPEC's 1/64 at 640×480; at other
//! resolutions the same number of samples per full image, see [`InsertConfig`]), colour from the
//! pixel, opacity 0.8 (see [`InsertConfig::opacity`]), identity rotation, isotropic scale.
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
    /// Isotropic scale, metres.
    pub scale: f64,
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
        let world = pose * camera_point;
        points.push((world, frame.rgb[p].map(|c| c as f64), frame.depth[p] as f64));
    }
    if points.len() > config.max_per_keyframe {
        // Uniform random subset (partial Fisher–Yates), so the cap does not favour any region.
        for i in 0..config.max_per_keyframe {
            let j = rng.random_range(i..points.len());
            points.swap(i, j);
        }
        points.truncate(config.max_per_keyframe);
    }
    let positions: Vec<[f64; 3]> = points.iter().map(|(p, _, _)| [p.x, p.y, p.z]).collect();
    let scales = if config.footprint_scale {
        let focal = 0.5 * (k.fx.abs() + k.fy.abs());
        let spacing = 1.0 / fraction.sqrt();
        points.iter().map(|(_, _, z)| z / focal * spacing).collect()
    } else {
        nearest_neighbour_scales(&positions, 3)
    };
    points
        .iter()
        .zip(scales)
        .map(|((p, rgb, _), s)| NewGaussian {
            mean: [p.x, p.y, p.z],
            rgb: *rgb,
            scale: if s.is_finite() {
                (s * config.scale_factor).clamp(config.min_scale, config.max_scale)
            } else {
                config.max_scale
            },
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
