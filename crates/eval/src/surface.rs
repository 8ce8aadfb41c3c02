//! Surface completeness (SPEC §8, Active Neural Mapping): the map's surface is reconstructed
//! and compared with the ground-truth mesh, point sets against point sets.
//!
//! 1. **Depth views of the map** ([`DepthView`]): the map rendered at a set of camera poses.
//!    A pixel counts only where the rendered opacity is at least
//!    [`SurfaceConfig::min_opacity`]; its depth is the composited depth divided by the opacity
//!    (SPEC §3's depth is `Σ z α T`, un-normalised, so a half-transparent pixel would otherwise
//!    read half as deep). A pixel whose depth steps from a 4-neighbour's by more than
//!    [`SurfaceConfig::max_depth_step`] of the nearer one is dropped too: at a silhouette the
//!    composited depth blends the object's and the background's, a reading in mid-air between
//!    them (fused from many views, such pixels draw streaks along the view rays). A pixel whose
//!    normalised depth departs from its median depth (where the transmittance halves,
//!    `activemap_splat::median_depth`) by more than [`SurfaceConfig::max_mixed_depth`] of the
//!    median is dropped as well: it blends surfaces at different depths smoothly, which the step
//!    test cannot see (the faint tails of Gaussians next to the camera over a far wall put
//!    whole walls in mid-air).
//! 2. **Fusion** ([`Tsdf`]): a truncated signed distance field on a sparse voxel grid
//!    ([`SurfaceConfig::voxel_m`]), KinectFusion-style: each voxel of the blocks near a view's
//!    readings is projected into the view and takes the projective distance `D − z` to the
//!    reading at its pixel (positive in front of the surface), truncated to the band and
//!    averaged over views.
//! 3. **Extraction** ([`Tsdf::surface_points`]): one point per grid cube whose eight corners were
//!    all observed and whose distances change sign, at the mean of its edges' zero crossings
//!    (naive surface nets: the vertices of the iso-surface mesh, about one per voxel of surface).
//! 4. **Metrics** ([`surface_metrics`]): completeness = the share of ground-truth samples with a
//!    reconstructed point within 5 cm; accuracy = the mean distance from the reconstruction's
//!    points to the nearest of a dense draw of ground-truth samples (one per (2 cm)² of mesh,
//!    [`accuracy_sample_count`], so a point on the surface reads about 1 cm); completion error =
//!    the mean distance from the ground-truth samples to the nearest reconstructed point (both in
//!    centimetres).
//!
//! No transport, no I/O.

use crate::completeness::{PointGrid, complete_fraction};
use crate::error::EvalError;
use activemap_geometry::{Intrinsics, Isometry3};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Point3, Vector3};
use rand::SeedableRng;
use rand::seq::index::sample;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use rustc_hash::{FxHashMap, FxHashSet};

/// Voxels along each side of a block of the sparse grid.
const BLOCK: usize = 8;
/// Voxels in a block.
const BLOCK_VOXELS: usize = BLOCK * BLOCK * BLOCK;
/// Shares of the views fused apart and then added ([`fuse_jobs`]): fixed, so the sums
/// come out the same on any number of threads.
pub const FUSION_CHUNKS: usize = 4;

/// Settings of the surface reconstruction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceConfig {
    /// Voxel side, metres. 2 cm: well below the 5 cm completeness radius, so the surface
    /// points (about one per voxel) leave no gap that the metric could see.
    pub voxel_m: f64,
    /// Half-width of the truncation band, in voxels (3: a band of ±6 cm at 2 cm voxels, wide
    /// enough for the spread of a splat's composited depth, narrow enough to keep thin
    /// furniture apart).
    pub truncation_voxels: f64,
    /// Smallest rendered opacity of a kept pixel (`1 − T_final`).
    pub min_opacity: f32,
    /// Readings farther than this z-depth are dropped, metres (the sensor's 10 m).
    pub max_depth_m: f64,
    /// Largest depth step from a pixel to any of its 4-neighbours with a reading, as a fraction
    /// of the nearer of the two; a pixel beyond it is dropped as a silhouette pixel. 0.05 keeps
    /// every surface seen at more than about 3° of grazing at 160 px and 90° (the step between
    /// neighbours is the depth times the pixel angle over the tangent of the grazing angle);
    /// `f64::INFINITY` keeps every pixel.
    pub max_depth_step: f64,
    /// Largest gap between a pixel's normalised depth and its median depth, as a fraction of the
    /// median, in views that carry a median ([`DepthView::median_depth`]); a pixel beyond it,
    /// or without a median, is dropped as a blend of surfaces. 0.05, the step rule's fraction:
    /// on the README's main run with discs, 12 % of the reconstructed points lay more than
    /// 20 cm from the mesh without it (accuracy 7.2 cm, 2.4 cm with it); `f64::INFINITY` keeps
    /// every pixel.
    pub max_mixed_depth: f64,
}

impl Default for SurfaceConfig {
    fn default() -> Self {
        Self {
            voxel_m: 0.02,
            truncation_voxels: 3.0,
            min_opacity: 0.8,
            max_depth_m: 10.0,
            max_depth_step: 0.05,
            max_mixed_depth: 0.05,
        }
    }
}

/// One rendered depth image of the map with its camera: the input of [`Tsdf::integrate`].
#[derive(Debug, Clone)]
pub struct DepthView {
    /// Pinhole intrinsics; `depth` holds `width × height` values.
    pub intrinsics: Intrinsics,
    /// Camera pose in the frame the reconstruction is built in (OpenCV optical axes).
    pub t_world_camera: Isometry3<f64>,
    /// Composited z-depth `Σ z α T`, metres, row-major.
    pub depth: Vec<f32>,
    /// Accumulated opacity `1 − T_final`, row-major.
    pub opacity: Vec<f32>,
    /// The median depth per pixel (`activemap_splat::median_depth`, NaN where the
    /// transmittance never halves), row-major, for the mixed-pixel test
    /// ([`SurfaceConfig::max_mixed_depth`]); `None` skips that test (a view with one surface
    /// per pixel, such as a ray-cast one).
    pub median_depth: Option<Vec<f32>>,
}

impl DepthView {
    /// The normalised depth of pixel `i` (depth / opacity) where the opacity reaches
    /// `min_opacity` and the result is a positive finite reading; `None` elsewhere.
    pub fn reading(&self, i: usize, min_opacity: f32) -> Option<f64> {
        let o = self.opacity[i];
        // A NaN opacity is refused along with a thin one.
        if o.is_nan() || o < min_opacity {
            return None;
        }
        let d = f64::from(self.depth[i]) / f64::from(o);
        (d.is_finite() && d > 0.0).then_some(d)
    }

    /// Whether pixel `i`'s normalised depth `d` lies within `max_gap` of its median depth, as
    /// a fraction of the median (always, without a median image; never, where the pixel has no
    /// median).
    pub fn agrees_with_median(&self, i: usize, d: f64, max_gap: f64) -> bool {
        let Some(median) = &self.median_depth else {
            return true;
        };
        let m = f64::from(median[i]);
        m.is_finite() && m > 0.0 && (d - m).abs() <= max_gap * m
    }

    fn check(&self) -> Result<(), EvalError> {
        let n = self.intrinsics.width as usize * self.intrinsics.height as usize;
        let medians = self.median_depth.as_ref().map_or(n, Vec::len);
        if self.depth.len() != n || self.opacity.len() != n || medians != n {
            return Err(EvalError::SizeMismatch {
                metric: "surface reconstruction",
                detail: format!(
                    "a {}×{} view needs {n} depth, opacity and median values, got {}, {} and {medians}",
                    self.intrinsics.width,
                    self.intrinsics.height,
                    self.depth.len(),
                    self.opacity.len()
                ),
            });
        }
        Ok(())
    }
}

/// Runs `job(0..jobs)` and fuses the depth view each job returns (if any) into one field, the
/// jobs split into [`FUSION_CHUNKS`] consecutive shares run in parallel, each share's jobs in
/// order into its own field, the fields then added in order: the field does not depend on the
/// thread count, and views are fused as they are made instead of being held all at once.
/// Returns the field and each job's other output, in job order.
pub fn fuse_jobs<T, E, F>(config: SurfaceConfig, jobs: usize, job: F) -> Result<(Tsdf, Vec<T>), E>
where
    T: Send,
    E: From<EvalError> + Send,
    F: Fn(usize) -> Result<(Option<DepthView>, T), E> + Sync,
{
    let chunk = jobs.div_ceil(FUSION_CHUNKS).max(1);
    let starts: Vec<usize> = (0..jobs).step_by(chunk).collect();
    let parts = starts
        .par_iter()
        .map(|&start| {
            let mut part = Tsdf::new(config)?;
            let mut outputs = Vec::new();
            for i in start..(start + chunk).min(jobs) {
                let (view, output) = job(i)?;
                if let Some(view) = view {
                    part.integrate(&view)?;
                }
                outputs.push(output);
            }
            Ok((part, outputs))
        })
        .collect::<Result<Vec<_>, E>>()?;
    let mut field = Tsdf::new(config)?;
    let mut outputs = Vec::with_capacity(jobs);
    for (part, out) in parts {
        field = field.merged(part);
        outputs.extend(out);
    }
    Ok((field, outputs))
}

/// The voxels of one block: summed truncated distances (in units of the band) and weights.
#[derive(Clone)]
struct Block {
    sdf_sum: [f32; BLOCK_VOXELS],
    weight: [f32; BLOCK_VOXELS],
}

impl Block {
    fn empty() -> Box<Self> {
        Box::new(Self {
            sdf_sum: [0.0; BLOCK_VOXELS],
            weight: [0.0; BLOCK_VOXELS],
        })
    }
}

/// A truncated signed distance field on a sparse grid of voxel blocks (see the module doc).
#[derive(Clone)]
pub struct Tsdf {
    config: SurfaceConfig,
    blocks: FxHashMap<[i32; 3], Box<Block>>,
    /// Time spent in [`Tsdf::integrate`], summed over threads, seconds.
    fusion_seconds: f64,
}

/// Splits a global voxel coordinate into its block key and the index inside the block.
fn split(v: [i64; 3]) -> ([i32; 3], usize) {
    let b = BLOCK as i64;
    let key = v.map(|c| c.div_euclid(b) as i32);
    let [x, y, z] = v.map(|c| c.rem_euclid(b) as usize);
    (key, x + BLOCK * (y + BLOCK * z))
}

impl Tsdf {
    /// An empty field; fails on a non-positive voxel, band or depth limit.
    pub fn new(config: SurfaceConfig) -> Result<Self, EvalError> {
        let ok = |v: f64| v.is_finite() && v > 0.0;
        if !(ok(config.voxel_m)
            && ok(config.truncation_voxels)
            && ok(config.max_depth_m)
            && config.max_depth_step > 0.0
            && config.max_mixed_depth > 0.0
            && config.min_opacity.is_finite())
        {
            return Err(EvalError::InvalidParameter {
                metric: "surface reconstruction",
                detail: format!(
                    "voxel, truncation and depth limit must be finite and positive, the depth step and the mixed-depth gap positive, got {config:?}"
                ),
            });
        }
        Ok(Self {
            config,
            blocks: FxHashMap::default(),
            fusion_seconds: 0.0,
        })
    }

    /// Time spent fusing views so far, summed over threads, seconds (for the evaluation's
    /// timing line).
    pub fn fusion_seconds(&self) -> f64 {
        self.fusion_seconds
    }

    /// The settings.
    pub fn config(&self) -> &SurfaceConfig {
        &self.config
    }

    /// Number of voxels observed at least once.
    pub fn observed_voxels(&self) -> usize {
        self.blocks
            .values()
            .map(|b| b.weight.iter().filter(|&&w| w > 0.0).count())
            .sum()
    }

    /// Fuses one depth view, projectively: the blocks that the truncation bands of the kept
    /// pixels' readings pass through are found first; every voxel of them is then projected into
    /// the view and, where its pixel has a reading `D` and the voxel lies in front of it or at
    /// most a band behind, takes the truncated distance `min((D − z) / band, 1)`.
    pub fn integrate(&mut self, view: &DepthView) -> Result<(), EvalError> {
        view.check()?;
        let started = std::time::Instant::now();
        let k = view.intrinsics;
        let (w, h) = (k.width as usize, k.height as usize);
        let voxel = self.config.voxel_m;
        let band = voxel * self.config.truncation_voxels;
        let block_side = voxel * BLOCK as f64;
        let readings: Vec<Option<f64>> = (0..w * h)
            .map(|i| {
                view.reading(i, self.config.min_opacity).filter(|&d| {
                    d <= self.config.max_depth_m
                        && view.agrees_with_median(i, d, self.config.max_mixed_depth)
                })
            })
            .collect();
        let readings = without_silhouettes(&readings, w, h, self.config.max_depth_step);
        // 1. The blocks the bands pass through (band ends and reading; a band is shorter than a
        //    block, so no block between them is skipped).
        let mut touched: FxHashSet<[i32; 3]> = FxHashSet::default();
        let origin = view.t_world_camera.translation.vector;
        let rot = view.t_world_camera.rotation;
        for v in 0..h {
            for u in 0..w {
                let Some(d) = readings[u + w * v] else {
                    continue;
                };
                // Pixel centres at integer coordinates, as the splat renderer's.
                let ray =
                    rot * Vector3::new((u as f64 - k.cx) / k.fx, (v as f64 - k.cy) / k.fy, 1.0);
                for z in [(d - band).max(0.0), d, d + band] {
                    let p = origin + ray * z;
                    touched.insert([
                        (p.x / block_side).floor() as i32,
                        (p.y / block_side).floor() as i32,
                        (p.z / block_side).floor() as i32,
                    ]);
                }
            }
        }
        // 2. Every voxel of those blocks, projected.
        let t_cw = view.t_world_camera.inverse();
        for key in touched {
            let block = self.blocks.entry(key).or_insert_with(Block::empty);
            for i in 0..BLOCK_VOXELS {
                let local = [i % BLOCK, (i / BLOCK) % BLOCK, i / (BLOCK * BLOCK)];
                let centre = Point3::new(
                    (f64::from(key[0]) * BLOCK as f64 + local[0] as f64 + 0.5) * voxel,
                    (f64::from(key[1]) * BLOCK as f64 + local[1] as f64 + 0.5) * voxel,
                    (f64::from(key[2]) * BLOCK as f64 + local[2] as f64 + 0.5) * voxel,
                );
                let pc = t_cw * centre;
                if pc.z <= 1e-6 {
                    continue;
                }
                let u = (k.fx * pc.x / pc.z + k.cx).round();
                let v = (k.fy * pc.y / pc.z + k.cy).round();
                if u < 0.0 || v < 0.0 || u >= w as f64 || v >= h as f64 {
                    continue;
                }
                let Some(d) = readings[u as usize + w * v as usize] else {
                    continue;
                };
                let sdf = (d - pc.z) / band;
                if sdf < -1.0 {
                    continue;
                }
                block.sdf_sum[i] += sdf.min(1.0) as f32;
                block.weight[i] += 1.0;
            }
        }
        self.fusion_seconds += started.elapsed().as_secs_f64();
        Ok(())
    }

    /// The sum of two fields of the same settings.
    fn merged(self, other: Tsdf) -> Tsdf {
        let (mut big, small) = if self.blocks.len() >= other.blocks.len() {
            (self, other)
        } else {
            (other, self)
        };
        big.fusion_seconds += small.fusion_seconds;
        for (key, block) in small.blocks {
            match big.blocks.get_mut(&key) {
                Some(b) => {
                    for i in 0..BLOCK_VOXELS {
                        b.sdf_sum[i] += block.sdf_sum[i];
                        b.weight[i] += block.weight[i];
                    }
                }
                None => {
                    big.blocks.insert(key, block);
                }
            }
        }
        big
    }

    /// The mean truncated distance of voxel `v` (in units of the band) if it was observed.
    fn value(&self, v: [i64; 3]) -> Option<f32> {
        let (key, i) = split(v);
        let block = self.blocks.get(&key)?;
        (block.weight[i] > 0.0).then(|| block.sdf_sum[i] / block.weight[i])
    }

    /// The reconstructed surface as points (see the module doc, step 3), in the frame of the
    /// views, sorted so the result does not depend on hash order.
    pub fn surface_points(&self) -> Vec<Point3<f64>> {
        const CORNERS: [[i64; 3]; 8] = [
            [0, 0, 0],
            [1, 0, 0],
            [0, 1, 0],
            [1, 1, 0],
            [0, 0, 1],
            [1, 0, 1],
            [0, 1, 1],
            [1, 1, 1],
        ];
        // The 12 edges of a cube as pairs of corner indices (corners differ in one bit).
        const EDGES: [(usize, usize); 12] = [
            (0, 1),
            (2, 3),
            (4, 5),
            (6, 7),
            (0, 2),
            (1, 3),
            (4, 6),
            (5, 7),
            (0, 4),
            (1, 5),
            (2, 6),
            (3, 7),
        ];
        let voxel = self.config.voxel_m;
        let mut keys: Vec<&[i32; 3]> = self.blocks.keys().collect();
        keys.sort_unstable();
        keys.par_iter()
            .flat_map_iter(|key| {
                let base = key.map(|c| i64::from(c) * BLOCK as i64);
                let mut out = Vec::new();
                for i in 0..BLOCK_VOXELS {
                    let local = [
                        (i % BLOCK) as i64,
                        ((i / BLOCK) % BLOCK) as i64,
                        (i / (BLOCK * BLOCK)) as i64,
                    ];
                    let v0 = [base[0] + local[0], base[1] + local[1], base[2] + local[2]];
                    let mut values = [0f32; 8];
                    let mut complete = true;
                    for (c, off) in CORNERS.iter().enumerate() {
                        match self.value([v0[0] + off[0], v0[1] + off[1], v0[2] + off[2]]) {
                            Some(s) => values[c] = s,
                            None => {
                                complete = false;
                                break;
                            }
                        }
                    }
                    if !complete {
                        continue;
                    }
                    let mut sum = Vector3::zeros();
                    let mut crossings = 0;
                    for &(a, b) in &EDGES {
                        let (sa, sb) = (values[a], values[b]);
                        if (sa < 0.0) == (sb < 0.0) {
                            continue;
                        }
                        // Both ends saturated: no reading put the surface between them (the
                        // back of one band meeting the front of another).
                        if sa.abs() >= 0.999 && sb.abs() >= 0.999 {
                            continue;
                        }
                        let t = f64::from(sa / (sa - sb));
                        let pa = Vector3::from(CORNERS[a].map(|c| c as f64));
                        let pb = Vector3::from(CORNERS[b].map(|c| c as f64));
                        sum += pa + (pb - pa) * t;
                        crossings += 1;
                    }
                    if crossings == 0 {
                        continue;
                    }
                    let local_point = sum / crossings as f64;
                    // Voxel values sit at voxel centres.
                    out.push(Point3::from(
                        (Vector3::from(v0.map(|c| c as f64 + 0.5)) + local_point) * voxel,
                    ));
                }
                out
            })
            .collect()
    }
}

/// `readings` (row-major, `w × h`) without the pixels whose depth steps from a 4-neighbour's
/// reading by more than `max_step` times the nearer of the two ([`SurfaceConfig::max_depth_step`]).
fn without_silhouettes(
    readings: &[Option<f64>],
    w: usize,
    h: usize,
    max_step: f64,
) -> Vec<Option<f64>> {
    (0..w * h)
        .map(|i| {
            let d = readings[i]?;
            let (u, v) = (i % w, i / w);
            let neighbours = [
                (u > 0).then(|| i - 1),
                (u + 1 < w).then(|| i + 1),
                (v > 0).then(|| i - w),
                (v + 1 < h).then(|| i + w),
            ];
            let steps = neighbours
                .into_iter()
                .flatten()
                .filter_map(|n| readings[n])
                .any(|e| (d - e).abs() > max_step * d.min(e));
            (!steps).then_some(d)
        })
        .collect()
}

/// The surface metrics of a reconstruction against ground-truth samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceMetrics {
    /// Share of the considered ground-truth samples with a reconstructed point within the
    /// threshold, in [0, 1].
    pub completeness: f64,
    /// Mean distance from the reconstruction's points to the nearest ground-truth sample,
    /// centimetres (`None` without reconstructed points).
    pub accuracy_cm: Option<f64>,
    /// Mean distance from the considered ground-truth samples to the nearest reconstructed
    /// point, centimetres (`None` without reconstructed points).
    pub completion_error_cm: Option<f64>,
}

/// Spacing of the ground-truth samples accuracy measures to, metres: one sample per (2 cm)²
/// of mesh area ([`accuracy_sample_count`]), so a point on the surface lies about 1 cm from the
/// nearest one.
pub const ACCURACY_SAMPLE_SPACING_M: f64 = 0.02;

/// Most ground-truth samples accuracy measures to (memory: 8M points, ~200 MB with the tree).
pub const MAX_ACCURACY_SAMPLES: usize = 8_000_000;

/// Ground-truth samples for accuracy on a mesh of `area_m2`: one per
/// [`ACCURACY_SAMPLE_SPACING_M`]², at least `at_least` (the completeness samples) and at most
/// [`MAX_ACCURACY_SAMPLES`].
pub fn accuracy_sample_count(area_m2: f64, at_least: usize) -> usize {
    let dense = (area_m2.max(0.0) / (ACCURACY_SAMPLE_SPACING_M * ACCURACY_SAMPLE_SPACING_M)).ceil();
    (dense.min(MAX_ACCURACY_SAMPLES as f64) as usize).max(at_least)
}

/// Reconstructed points used for accuracy at most (Active Neural Mapping samples 200k points on
/// the reconstructed mesh); more are subsampled, seeded.
pub const ACCURACY_SAMPLES: usize = 200_000;

/// Per ground-truth sample: whether a reconstructed point lies within `threshold` metres.
pub fn surface_complete(
    truth: &[Point3<f64>],
    reconstruction: &[Point3<f64>],
    threshold: f64,
) -> Result<Vec<bool>, EvalError> {
    let grid = PointGrid::new(reconstruction, threshold)?;
    Ok(truth.par_iter().map(|p| grid.has_neighbour(p)).collect())
}

/// Completeness, accuracy and completion error (see the module doc) of `reconstruction`
/// against the ground-truth `truth` samples; only the samples with `considered[i]` enter
/// completeness and completion error (the observable ones). Accuracy measures to
/// `accuracy_truth`, samples of the same surface dense enough that their spacing does not
/// dominate the distance (a point on the surface lies on average half the spacing from the
/// nearest sample: 4–5 cm with 200k samples over a large house; see
/// [`ACCURACY_SAMPLE_SPACING_M`]). `threshold` is the completeness radius, metres.
pub fn surface_metrics(
    truth: &[Point3<f64>],
    considered: &[bool],
    reconstruction: &[Point3<f64>],
    accuracy_truth: &[Point3<f64>],
    threshold: f64,
) -> Result<SurfaceMetrics, EvalError> {
    if truth.len() != considered.len() {
        return Err(EvalError::SizeMismatch {
            metric: "surface completeness",
            detail: format!(
                "{} ground-truth samples but {} observability flags",
                truth.len(),
                considered.len()
            ),
        });
    }
    let targets: Vec<Point3<f64>> = truth
        .iter()
        .zip(considered)
        .filter(|(_, c)| **c)
        .map(|(p, _)| *p)
        .collect();
    if targets.is_empty() {
        return Err(EvalError::Empty {
            metric: "surface completeness",
            detail: "no ground-truth sample to compare with".into(),
        });
    }
    let complete = surface_complete(&targets, reconstruction, threshold)?;
    let completeness = complete_fraction(&complete);
    if reconstruction.is_empty() {
        return Ok(SurfaceMetrics {
            completeness,
            accuracy_cm: None,
            completion_error_cm: None,
        });
    }
    let completion = mean_nearest_distance(&targets, reconstruction)?;
    let sampled: Vec<Point3<f64>> = if reconstruction.len() > ACCURACY_SAMPLES {
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let mut idx = sample(&mut rng, reconstruction.len(), ACCURACY_SAMPLES).into_vec();
        idx.sort_unstable();
        idx.into_iter().map(|i| reconstruction[i]).collect()
    } else {
        reconstruction.to_vec()
    };
    let accuracy = mean_nearest_distance(&sampled, accuracy_truth)?;
    Ok(SurfaceMetrics {
        completeness,
        accuracy_cm: Some(accuracy * 100.0),
        completion_error_cm: Some(completion * 100.0),
    })
}

/// Mean over `queries` of the distance to the nearest point of `targets` (a k-d tree).
pub fn mean_nearest_distance(
    queries: &[Point3<f64>],
    targets: &[Point3<f64>],
) -> Result<f64, EvalError> {
    if queries.is_empty() || targets.is_empty() {
        return Err(EvalError::Empty {
            metric: "nearest distance",
            detail: format!(
                "{} query points and {} target points",
                queries.len(),
                targets.len()
            ),
        });
    }
    let points: Vec<[f64; 3]> = targets.iter().map(|p| [p.x, p.y, p.z]).collect();
    let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(&points);
    // Distances in parallel, summed in query order: a parallel sum's association order follows
    // rayon's work stealing, and the same map must evaluate to the same bits on every machine.
    let distances: Vec<f64> = queries
        .par_iter()
        .map(|q| {
            tree.nearest_one::<SquaredEuclidean>(&[q.x, q.y, q.z])
                .distance
                .sqrt()
        })
        .collect();
    Ok(distances.iter().sum::<f64>() / queries.len() as f64)
}

/// The surface points of `views` fused with `config` ([`fuse_jobs`], [`Tsdf::surface_points`]).
pub fn reconstruct(
    config: SurfaceConfig,
    views: &[DepthView],
) -> Result<Vec<Point3<f64>>, EvalError> {
    let (field, _) = fuse_jobs(config, views.len(), |i| {
        Ok::<_, EvalError>((Some(views[i].clone()), ()))
    })?;
    Ok(field.surface_points())
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_geometry::{PlanarPose, camera_pose_from_planar};
    use nalgebra::{Translation3, UnitQuaternion};

    /// A depth view of the inside of the axis-aligned box `[lo, hi]` (opacity 1), ray-cast
    /// analytically: each pixel reads the z-depth of the first box face its ray meets.
    fn box_view(k: Intrinsics, pose: Isometry3<f64>, lo: [f64; 3], hi: [f64; 3]) -> DepthView {
        let (w, h) = (k.width as usize, k.height as usize);
        let origin = pose.translation.vector;
        let mut depth = vec![0f32; w * h];
        for v in 0..h {
            for u in 0..w {
                let ray_c = Vector3::new((u as f64 - k.cx) / k.fx, (v as f64 - k.cy) / k.fy, 1.0);
                let ray = pose.rotation * ray_c;
                // Exit distance (in units of z) through the box's faces.
                let t = (0..3)
                    .filter(|&a| ray[a].abs() > 1e-12)
                    .map(|a| {
                        let wall = if ray[a] > 0.0 { hi[a] } else { lo[a] };
                        (wall - origin[a]) / ray[a]
                    })
                    .fold(f64::INFINITY, f64::min);
                depth[u + w * v] = t as f32;
            }
        }
        DepthView {
            intrinsics: k,
            t_world_camera: pose,
            opacity: vec![1.0; depth.len()],
            depth,
            median_depth: None,
        }
    }

    /// Samples on the six inner faces of the box `[lo, hi]` on a lattice of `step`.
    fn box_samples(lo: [f64; 3], hi: [f64; 3], step: f64) -> Vec<Point3<f64>> {
        let mut out = Vec::new();
        for axis in 0..3 {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let nu = ((hi[u] - lo[u]) / step).round() as usize;
            let nv = ((hi[v] - lo[v]) / step).round() as usize;
            for side in [lo[axis], hi[axis]] {
                for i in 0..nu {
                    for j in 0..nv {
                        let mut p = [0.0; 3];
                        p[axis] = side;
                        p[u] = lo[u] + (i as f64 + 0.5) * step;
                        p[v] = lo[v] + (j as f64 + 0.5) * step;
                        out.push(Point3::from(p));
                    }
                }
            }
        }
        out
    }

    /// Views from the middle of a room, every 30° of yaw, level and pitched up and down, so
    /// every face is seen.
    fn room_views(lo: [f64; 3], hi: [f64; 3]) -> Vec<DepthView> {
        let k = Intrinsics::from_hfov(64, 64, 90f64.to_radians());
        let centre = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])];
        let mut views = Vec::new();
        for yaw in 0..12 {
            for pitch in [-50.0f64, 0.0, 50.0] {
                let level = camera_pose_from_planar(
                    &PlanarPose::new(centre[0], centre[1], f64::from(yaw) * 30f64.to_radians()),
                    0.0,
                    0.5 * (lo[2] + hi[2]),
                );
                // Pitch about the camera's x axis (OpenCV: x right).
                let tilt = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), pitch.to_radians());
                let pose = level * Isometry3::from_parts(Translation3::identity(), tilt);
                views.push(box_view(k, pose, lo, hi));
            }
        }
        views
    }

    #[test]
    fn normalised_depth_divides_by_the_opacity_and_drops_thin_pixels() {
        let view = DepthView {
            intrinsics: Intrinsics::from_hfov(3, 1, 1.0),
            t_world_camera: Isometry3::identity(),
            depth: vec![1.0, 0.2, 0.0],
            opacity: vec![0.5, 0.1, 1.0],
            median_depth: None,
        };
        assert_eq!(view.reading(0, 0.5), Some(2.0));
        assert_eq!(view.reading(1, 0.5), None);
        assert_eq!(view.reading(2, 0.5), None, "zero depth is no reading");
    }

    #[test]
    fn a_plane_is_reconstructed_on_itself_and_its_back_is_not() {
        // A wall at x = 2 facing a camera at the origin looking along +x.
        let k = Intrinsics::from_hfov(48, 48, 60f64.to_radians());
        let look_x = camera_pose_from_planar(&PlanarPose::new(0.0, 0.0, 0.0), 0.0, 0.0);
        let views: Vec<DepthView> = [-0.2, 0.0, 0.2]
            .iter()
            .map(|&y| {
                let pose = Isometry3::from_parts(Translation3::new(0.0, y, 0.0), look_x.rotation);
                box_view(k, pose, [-10.0, -10.0, -10.0], [2.0, 10.0, 10.0])
            })
            .collect();
        let surface = reconstruct(SurfaceConfig::default(), &views).unwrap();
        assert!(surface.len() > 1000, "{} points", surface.len());
        let worst = surface
            .iter()
            .map(|p| (p.x - 2.0).abs())
            .fold(0.0, f64::max);
        assert!(worst < 0.005, "a surface point {worst} m off the plane");
        // The seen face (x = 2, |y|, |z| < 0.8) and the back of a 10 cm slab (x = 2.1).
        let grid = |x: f64| -> Vec<Point3<f64>> {
            (0..16)
                .flat_map(|i| {
                    (0..16).map(move |j| {
                        Point3::new(x, -0.75 + 0.1 * i as f64, -0.75 + 0.1 * j as f64)
                    })
                })
                .collect()
        };
        let all = vec![true; 256];
        let front = surface_metrics(&grid(2.0), &all, &surface, &grid(2.0), 0.05).unwrap();
        assert_eq!(front.completeness, 1.0);
        assert!(front.completion_error_cm.unwrap() < 1.5, "{front:?}");
        let back = surface_metrics(&grid(2.1), &all, &surface, &grid(2.1), 0.05).unwrap();
        assert_eq!(back.completeness, 0.0);
        assert!(
            (back.completion_error_cm.unwrap() - 10.0).abs() < 0.5,
            "{back:?}"
        );
    }

    /// A wall 2 m ahead covering the left half of the view, one 4 m ahead the right half, and
    /// between them a column of silhouette pixels whose composited depth blends the two (3 m):
    /// kept, they put surface in mid-air; the depth-step rule drops them and keeps both walls.
    #[test]
    fn silhouette_pixels_leave_no_surface_in_mid_air() {
        let k = Intrinsics::from_hfov(48, 48, 60f64.to_radians());
        let look_x = camera_pose_from_planar(&PlanarPose::new(0.0, 0.0, 0.0), 0.0, 0.0);
        let (w, h) = (48, 48);
        let depth: Vec<f32> = (0..w * h)
            .map(|i| match (i % w).cmp(&(w / 2)) {
                std::cmp::Ordering::Less => 2.0,
                std::cmp::Ordering::Equal => 3.0,
                std::cmp::Ordering::Greater => 4.0,
            })
            .collect();
        let view = DepthView {
            intrinsics: k,
            t_world_camera: look_x,
            opacity: vec![1.0; depth.len()],
            depth,
            median_depth: None,
        };
        let mid_air = |config: SurfaceConfig| {
            let surface = reconstruct(config, std::slice::from_ref(&view)).unwrap();
            let on = |x: f64| surface.iter().filter(|p| (p.x - x).abs() < 0.03).count();
            let between = surface.iter().filter(|p| p.x > 2.1 && p.x < 3.9).count();
            (on(2.0), on(4.0), between)
        };
        let kept = SurfaceConfig {
            max_depth_step: f64::INFINITY,
            ..SurfaceConfig::default()
        };
        let (near, far, between) = mid_air(kept);
        assert!(
            near > 100 && far > 100 && between > 10,
            "{near} {far} {between}"
        );
        let (near, far, between) = mid_air(SurfaceConfig::default());
        assert!(near > 100 && far > 100, "{near} {far}");
        assert_eq!(between, 0, "surface points in mid-air");
    }

    /// A wall 4 m ahead fills the view; over the left half, the faint tails of Gaussians 1 m
    /// from the camera blend into it, more towards the left edge (weight 0 at the middle, 0.3 at
    /// the edge), so the normalised depth ramps smoothly from 4 m to 3.1 m and no neighbour
    /// steps by 5 %. The pixels' median depth is the wall's: the mixed-pixel rule drops the
    /// pixels blended beyond 5 % of it, which the step rule keeps, and the wall stays.
    #[test]
    fn blended_pixels_leave_no_surface_in_mid_air() {
        let k = Intrinsics::from_hfov(48, 48, 60f64.to_radians());
        let look_x = camera_pose_from_planar(&PlanarPose::new(0.0, 0.0, 0.0), 0.0, 0.0);
        let (w, h) = (48, 48);
        let depth: Vec<f32> = (0..w * h)
            .map(|i| {
                let near_weight = 0.3 * (1.0 - (i % w) as f64 / (w / 2) as f64).max(0.0);
                (near_weight * 1.0 + (1.0 - near_weight) * 4.0) as f32
            })
            .collect();
        let view = |median: Option<f32>| DepthView {
            intrinsics: k,
            t_world_camera: look_x,
            opacity: vec![1.0; depth.len()],
            depth: depth.clone(),
            median_depth: median.map(|m| vec![m; depth.len()]),
        };
        let mid_air = |config: SurfaceConfig, view: DepthView| {
            let surface = reconstruct(config, std::slice::from_ref(&view)).unwrap();
            let wall = surface.iter().filter(|p| (p.x - 4.0).abs() < 0.03).count();
            // Blends within the 5 % tolerance stay (up to 20 cm in front of the wall).
            let between = surface.iter().filter(|p| p.x < 3.75).count();
            (wall, between)
        };
        let (wall, between) = mid_air(SurfaceConfig::default(), view(None));
        assert!(wall > 100 && between > 100, "{wall} {between}");
        let kept = SurfaceConfig {
            max_mixed_depth: f64::INFINITY,
            ..SurfaceConfig::default()
        };
        let (_, between) = mid_air(kept, view(Some(4.0)));
        assert!(between > 100, "{between}");
        let (wall, between) = mid_air(SurfaceConfig::default(), view(Some(4.0)));
        assert!(wall > 100, "{wall}");
        assert_eq!(between, 0, "surface points in mid-air");
        // No median at a pixel (the transmittance never halves): no reading.
        let (wall, between) = mid_air(SurfaceConfig::default(), view(Some(f32::NAN)));
        assert_eq!((wall, between), (0, 0));
    }

    #[test]
    fn a_box_room_mapped_3cm_inside_is_complete_at_5cm_and_not_at_2cm() {
        let (lo, hi) = ([0.0, 0.0, 0.0], [4.0, 3.0, 2.5]);
        // The map: the same room 3 cm smaller on every side.
        let (mlo, mhi) = (lo.map(|c| c + 0.03), hi.map(|c| c - 0.03));
        let surface = reconstruct(SurfaceConfig::default(), &room_views(mlo, mhi)).unwrap();
        // Every reconstructed point on the map's faces (within 5 mm).
        let off = |p: &Point3<f64>| {
            (0..3)
                .map(|a| (p[a] - mlo[a]).abs().min((p[a] - mhi[a]).abs()))
                .fold(f64::INFINITY, f64::min)
        };
        // Along the room's edges a point averages the crossings on two faces (up to a voxel
        // off each); everywhere else it sits on a face.
        let mut offs: Vec<f64> = surface.iter().map(off).collect();
        offs.sort_by(f64::total_cmp);
        let p95 = offs[offs.len() * 95 / 100];
        assert!(
            p95 < 0.005,
            "95 % of the points within {p95} m of the map's faces"
        );
        assert!(offs[offs.len() - 1] < 0.03, "{:?}", offs.last());
        let truth = box_samples(lo, hi, 0.05);
        let all = vec![true; truth.len()];
        let at5 = surface_metrics(&truth, &all, &surface, &truth, 0.05).unwrap();
        let at2 = surface_metrics(&truth, &all, &surface, &truth, 0.02).unwrap();
        // All but a few samples in the room's corners, where the surface points are pulled
        // inwards (see above).
        assert!(at5.completeness > 0.995, "{at5:?}");
        assert!(at2.completeness < 0.002, "{at2:?}");
        // Truth → map: 3 cm from every face's sample (a little more near the edges).
        let completion = at5.completion_error_cm.unwrap();
        assert!((3.0..3.5).contains(&completion), "{at5:?}");
        // Map → truth: 3 cm off the faces, plus up to half the 5 cm sample spacing sideways.
        let accuracy = at5.accuracy_cm.unwrap();
        assert!((3.0..4.5).contains(&accuracy), "{at5:?}");
        // Only the floor considered: the walls and ceiling do not count.
        let floor: Vec<bool> = truth.iter().map(|p| p.z == 0.0).collect();
        let floor_only = surface_metrics(&truth, &floor, &surface, &truth, 0.05).unwrap();
        assert!(floor_only.completeness > 0.995, "{floor_only:?}");
    }

    #[test]
    fn fusion_does_not_depend_on_the_thread_count() {
        let views = room_views([0.0, 0.0, 0.0], [3.0, 2.0, 2.5]);
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| reconstruct(SurfaceConfig::default(), &views).unwrap())
        };
        assert_eq!(run(1), run(3));
    }

    /// One accuracy sample per (2 cm)² of mesh, no fewer than the completeness samples, no
    /// more than the memory cap; and a surface sampled that densely lies about 1 cm from its
    /// nearest sample, where 200k samples over a large house's ~1500 m² leave it 4–5 cm away.
    #[test]
    fn accuracy_samples_follow_the_mesh_area() {
        use rand::Rng;
        assert_eq!(accuracy_sample_count(100.0, 200_000), 250_000);
        assert_eq!(accuracy_sample_count(1.0, 200_000), 200_000);
        assert_eq!(accuracy_sample_count(1e6, 0), MAX_ACCURACY_SAMPLES);
        // A 2 × 2 m plane at z = 0: uniform random samples, and on-surface query points.
        let plane = |n: usize, seed: u64| -> Vec<Point3<f64>> {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            (0..n)
                .map(|_| Point3::new(rng.random::<f64>() * 2.0, rng.random::<f64>() * 2.0, 0.0))
                .collect()
        };
        let queries: Vec<Point3<f64>> = plane(2000, 2)
            .into_iter()
            .map(|p| Point3::new(0.5 + 0.5 * p.x, 0.5 + 0.5 * p.y, 0.0))
            .collect();
        let dense =
            mean_nearest_distance(&queries, &plane(accuracy_sample_count(4.0, 0), 1)).unwrap();
        assert!((dense - 0.01).abs() < 0.002, "{dense}");
        // 200k samples over 1500 m², as dense as 533 over these 4 m².
        let sparse = mean_nearest_distance(&queries, &plane(533, 1)).unwrap();
        assert!(sparse > 0.035 && sparse < 0.055, "{sparse}");
    }

    #[test]
    fn nearest_distances_match_brute_force() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut cloud = |n: usize| -> Vec<Point3<f64>> {
            use rand::Rng;
            (0..n)
                .map(|_| Point3::new(rng.random(), rng.random(), rng.random()))
                .collect()
        };
        let (queries, targets) = (cloud(300), cloud(500));
        let brute = queries
            .iter()
            .map(|q| {
                targets
                    .iter()
                    .map(|t| (t - q).norm())
                    .fold(f64::INFINITY, f64::min)
            })
            .sum::<f64>()
            / queries.len() as f64;
        let fast = mean_nearest_distance(&queries, &targets).unwrap();
        assert!((fast - brute).abs() < 1e-12, "{fast} against {brute}");
        assert!(mean_nearest_distance(&[], &targets).is_err());
    }

    #[test]
    fn bad_input_is_refused_with_its_name() {
        let e = Tsdf::new(SurfaceConfig {
            voxel_m: 0.0,
            ..SurfaceConfig::default()
        })
        .err()
        .unwrap()
        .to_string();
        assert!(e.contains("voxel"), "{e}");
        for gap in [0.0, f64::NAN] {
            let e = Tsdf::new(SurfaceConfig {
                max_mixed_depth: gap,
                ..SurfaceConfig::default()
            })
            .err()
            .unwrap()
            .to_string();
            assert!(e.contains("mixed-depth gap"), "{e}");
        }
        let mut tsdf = Tsdf::new(SurfaceConfig::default()).unwrap();
        let short = DepthView {
            intrinsics: Intrinsics::from_hfov(4, 4, 1.0),
            t_world_camera: Isometry3::identity(),
            depth: vec![1.0; 3],
            opacity: vec![1.0; 16],
            median_depth: None,
        };
        let e = tsdf.integrate(&short).unwrap_err().to_string();
        assert!(e.contains("4×4") && e.contains("got 3"), "{e}");
        let short_median = DepthView {
            depth: vec![1.0; 16],
            median_depth: Some(vec![1.0; 15]),
            ..short
        };
        let e = tsdf.integrate(&short_median).unwrap_err().to_string();
        assert!(e.contains("median") && e.contains("15"), "{e}");
        let e = surface_metrics(&[Point3::origin()], &[], &[], &[Point3::origin()], 0.05)
            .unwrap_err()
            .to_string();
        assert!(e.contains("observability flags"), "{e}");
    }
}
