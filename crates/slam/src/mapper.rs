//! Keyframe mapping (SPEC §4): on each keyframe insert Gaussians in unobserved areas
//! ([`crate::insert`]; by default as discs lying in the surface the depth shows, a deviation
//! from the SPEC's round ones), optimise the map over a window of the most recent keyframes plus
//! a few random older ones (mapping loss, plus the SPEC's isotropic regulariser
//! `w·mean|s − mean(s)|` when `isotropic_weight > 0`, off with discs, or the flat one of
//! [`MapperConfig::flat_weight`]), then prune and densify.
//!
//! The map holds observed Gaussians only. The unknown-space Gaussians of SPEC §5 serve the
//! Fisher computation alone and are renewed at each replan, so the active-mapping scorer
//! (`activemap_active::unknown`) seeds its own set and the mapper never holds them.
//!
//! Pruning: after every keyframe's optimisation, Gaussians with opacity below
//! `prune_opacity_early` (0.005) go; Gaussians visible in the window that have had at least
//! `prune_min_age` (30) optimisation steps and still have opacity below
//! `prune_opacity_window` go too, as do Gaussians larger than `prune_max_scale`. The window
//! threshold is 0.1, not MonoGS's `gaussian_th` 0.7: MonoGS applies 0.7 only at its periodic
//! densify/prune steps after hundreds of GPU iterations; with ~10 CPU iterations per keyframe a
//! Gaussian inserted below 0.7 has not yet climbed there, and 0.7 deleted most of the young
//! map (measured: held-out PSNR 26.6 → 27.4 dB and depth residual 3.8 → 1.5 cm at 160² over
//! 40 frames when lowered to 0.1; `tests/mapping_quality.rs`).
//!
//! Each iteration renders the newest keyframe plus `views_per_iteration − 1` (2) views drawn at
//! random from the rest of the window (MonoGS also samples its window), not every window view.
//! Densification (3DGS): Gaussians whose mean screen-space gradient (in NDC units, i.e. the
//! pixel gradient × width/2) exceeds `densify_grad` (6e-4) are cloned when small
//! (max scale ≤ `densify_split_scale`) and split in two (scales / 1.6, means sampled from the
//! Gaussian) when large.
//! Keyframe poses are the tracker's (they are not refined here); a non-finite pose is an input
//! error. When the tracker's pose graph corrects its keyframes, [`Mapper::move_keyframes`]
//! moves each mapper keyframe rigidly, with every Gaussian anchored to it: a Gaussian's anchor
//! is the keyframe whose insertion made it (clones and splits inherit their parent's), the
//! same rule as submap-based loop closure, which moves each submap's Gaussians with its
//! keyframe. Gaussians with a NaN or infinite parameter are dropped before and after every
//! optimisation and counted ([`MappingReport::dropped_non_finite`]), so a snapshot of the map
//! never carries them.

use crate::error::SlamError;
use crate::frame::Frame;
use crate::insert::{
    CoverageCounts, InsertConfig, explained_mask, pixel_coverage, sample_new_gaussians,
    unobserved_mask,
};
use crate::loss::{MappingDepth, mapping_loss, rgb_mask};
use activemap_geometry::Isometry3;
use activemap_splat::{
    AdamConfig, Camera, DepthModel, FLAG_UNKNOWN_SPACE, GaussianAdam, Gaussians, Gradients,
    RenderOptions, backward, render,
};
use nalgebra::{UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

/// Mapper settings; defaults follow SPEC §4 where it names a value.
#[derive(Debug, Clone, PartialEq)]
pub struct MapperConfig {
    /// Insertion settings.
    pub insert: InsertConfig,
    /// Number of most recent keyframes optimised together (10).
    pub window: usize,
    /// Random older keyframes added to the window (2).
    pub random_older: usize,
    /// Optimisation iterations per keyframe (20). Measured against 10 under FBE on houses 1, 3
    /// and 9 run to the end of exploration (benchmarks/mapper-iterations-explored.yaml) and with
    /// the realistic sensor (benchmarks/mapper-iterations.yaml): docs/src/slam.md, "Mapping
    /// iterations per keyframe".
    pub iterations: usize,
    /// Views rendered per iteration: the newest keyframe plus `views_per_iteration − 1` views
    /// drawn at random from the rest of the window (MonoGS samples its window the same way);
    /// 0 renders every window view in every iteration.
    pub views_per_iteration: usize,
    /// Of the `iterations`, how many run first on the keyframes at half resolution
    /// (coarse-to-fine: a quarter of the pixels; 0 = all at full resolution). Default 5: with 10
    /// iterations, measured −20 % CPU per keyframe and +0.2 dB held-out at 160²
    /// (crates/bench/tests/mapping_quality.rs).
    pub coarse_iterations: usize,
    /// Weight α of the colour term of the mapping loss.
    pub alpha: f32,
    /// The depth term of the mapping loss ([`MappingDepth`]).
    pub depth_loss: MappingDepth,
    /// `Σ RGB` threshold of the colour mask.
    pub rgb_boundary: f32,
    /// Weight of the isotropic regulariser `w·mean|s − mean(s)|`: 0, since the mapper inserts
    /// discs lying in the surface ([`InsertConfig::normal_thickness`]), which this regulariser
    /// would pull round again (SPEC §4: 10, with round insertion).
    pub isotropic_weight: f32,
    /// Weight `w` of the flat regulariser `w·mean_i min_k s_ik` (issue 33: shrinks each
    /// Gaussian's thinnest axis, so it can become a disc on the surface); 0 = off. With
    /// `isotropic_weight` 0 and this 10 under the plane depth model, `activemap bench slam
    /// --cases 200x500` gains against the default (surface offset −2.93 → −2.71 cm, p90 8.88 →
    /// 7.83 cm, depth MAE 3.58 → 3.24 cm noise-free; −2.96 → −2.41 cm, 9.41 → 8.96 cm, 4.99 →
    /// 4.74 cm realistic), but in episodes (`benchmarks/depth-model*.yaml`, FBE, houses 1, 3,
    /// 9, seeds 1–2) its discs render worse from the test views: PSNR −0.3 dB and depth MAE
    /// +1.8 cm against the default, both in 6 of 6 pairs noise-free, for +0.9 to +1.3 points
    /// of completeness. So off.
    pub flat_weight: f32,
    /// Largest ratio of a Gaussian's largest scale to its middle one, enforced after every
    /// optimisation step on the Gaussians it moved (issue 33; 0 = off): the largest log-scale
    /// is lowered to the middle one's plus `ln` of this. A disc may be stretched along a
    /// grazing ray at insertion ([`InsertConfig::max_grazing_stretch`]), and the views that see
    /// it at that angle cannot tell how far it reaches along the ray, so the optimisation can
    /// stretch it further; past the end of its surface (a door frame's side, a wall's end) the
    /// overhang renders in front of what lies behind from any other view. Off: on the README's
    /// main-run trajectory (`activemap replay … --node mapper --set
    /// mapper.tuning.max_in_plane_ratio=3`) it read PSNR +0.26 dB, depth MAE −0.45 cm,
    /// completeness −0.28 points; with the insertion stretch also at 1.5 it added nothing to
    /// that stretch alone (`docs/src/slam.md`, "Where a stretched disc reaches past its
    /// surface").
    pub max_in_plane_ratio: f64,
    /// Adam learning rates per parameter group (MonoGS/3DGS values; mean 0.002 m per step).
    pub learning_rates: AdamConfig,
    /// Opacity below which any Gaussian is pruned (0.005).
    pub prune_opacity_early: f64,
    /// Opacity below which an old-enough Gaussian visible in the window is pruned (0.1; see
    /// the module doc for why not MonoGS's 0.7).
    pub prune_opacity_window: f64,
    /// Optimisation steps a Gaussian must have had before the window threshold applies.
    pub prune_min_age: u32,
    /// Largest allowed scale, metres.
    pub prune_max_scale: f64,
    /// Densification threshold on the mean NDC-space gradient of the projected mean (6e-4;
    /// 3DGS uses 2e-4, which with the dense insertion here doubled the map for +0.3 dB).
    pub densify_grad: f64,
    /// Split (rather than clone) Gaussians whose largest scale exceeds this, metres.
    pub densify_split_scale: f64,
    /// No densification once the map holds this many Gaussians.
    pub max_gaussians: usize,
    /// Snap band, metres (issue 33; 0 = off): after each keyframe's optimisation, a Gaussian
    /// whose centre projects onto a depth reading `D` of the newest keyframe and lies behind it
    /// along the ray by less than this (`D < z < D + band`) is moved along its ray onto the
    /// reading (`z = D`): the reading says the surface is there, so a centre just behind it sits
    /// on no surface this view sees. Off by default: measured on `activemap bench slam --cases
    /// 200x250` at 0.15 m, surface offset −2.81 → −1.73 cm, p90 9.82 → 4.87 cm, held-out PSNR
    /// 28.10 → 29.09 dB, but 3× the Gaussians (35k → 104k) and about twice the mapping time
    /// per keyframe; 0.08 m gave −1.71 cm, p90 5.70 cm. On 200x500 with the flat regulariser:
    /// −1.49 cm, p90 4.34 cm, within 2 cm 53 % (floor −1.11 cm), but held-out PSNR 27.32 dB,
    /// depth MAE 6.72 cm, 216k Gaussians, mapping time per keyframe 1.33×.
    pub snap_behind_m: f64,
    /// With [`MapperConfig::snap_behind_m`], also move the centres that lie in front of the
    /// reading by less than the band (`D − band < z < D`) onto it: free space the view sees
    /// through. (Measured at 0.15 m on 200x250: −2.18 cm, worse than behind only.)
    pub snap_in_front: bool,
    /// Free-space carving margin, metres (0 = off): after each keyframe's optimisation, a
    /// Gaussian whose centre projects into the newest keyframe in front of every reading of the
    /// 3×3 pixels around it by more than `max(margin, carve_margin_fraction · D)` is removed:
    /// the keyframe saw through the place where it sits, so it is a floater. The 3×3 minimum
    /// (all nine readings valid) keeps thin structures and silhouettes that a pixel of pose or
    /// projection error would otherwise carve.
    pub carve_margin_m: f64,
    /// The relative part of the carving margin ([`MapperConfig::carve_margin_m`]): a share of
    /// the nearest reading, so that depth noise growing with distance carves nothing real.
    pub carve_margin_fraction: f64,
    /// The per-pixel depth of a Gaussian in the mapping renders, and so the model the map is
    /// fitted under; every render of the map should use the same (the default,
    /// [`DepthModel::Plane`]; SPEC §3 is [`DepthModel::Centre`]). Against the centre model,
    /// side by side: `activemap bench slam --cases 200x500` surface offset −3.24 → −2.93 cm,
    /// p90 9.62 → 8.88 cm, held-out PSNR 27.60 → 27.67 dB, depth MAE 3.46 → 3.58 cm, mapping
    /// time per keyframe 0.86× (realistic: −3.01 → −2.96 cm, 10.05 → 9.41 cm, 27.19 → 27.11
    /// dB, 4.70 → 4.99 cm, 0.93×); in FBE episodes (`benchmarks/depth-model*.yaml`, 6 pairs
    /// each) completeness +0.9 points (6 of 6 pairs) noise-free and +0.6 realistic, depth MAE
    /// −0.4 and −0.7 cm, PSNR +0.04 and +0.00 dB.
    pub depth_model: DepthModel,
    /// Seed of every random choice of the mapper.
    pub seed: u64,
}

impl Default for MapperConfig {
    fn default() -> Self {
        Self {
            insert: InsertConfig::default(),
            window: 10,
            random_older: 2,
            iterations: 20,
            views_per_iteration: 3,
            coarse_iterations: 5,
            alpha: 0.95,
            depth_loss: MappingDepth::default(),
            rgb_boundary: 0.01,
            isotropic_weight: 0.0,
            flat_weight: 0.0,
            max_in_plane_ratio: 0.0,
            learning_rates: AdamConfig {
                lr_mean: 0.002,
                lr_colour: 0.0025,
                lr_rotation: 0.001,
                lr_opacity: 0.05,
                lr_scale: 0.005,
                ..AdamConfig::default()
            },
            prune_opacity_early: 0.005,
            prune_opacity_window: 0.1,
            prune_min_age: 30,
            prune_max_scale: 0.5,
            densify_grad: 6e-4,
            densify_split_scale: 0.05,
            max_gaussians: 150_000,
            snap_behind_m: 0.0,
            snap_in_front: false,
            carve_margin_m: 0.0,
            carve_margin_fraction: 0.05,
            depth_model: DepthModel::default(),
            seed: 0,
        }
    }
}

impl MapperConfig {
    /// Checks ranges; names the offending field.
    pub fn validate(&self) -> Result<(), SlamError> {
        let f = self.insert.sample_fraction;
        if !(f > 0.0 && f <= 1.0) {
            return Err(SlamError::Config {
                field: "insert.sample_fraction",
                value: f.to_string(),
                reason: "must be in (0, 1]",
            });
        }
        if self.window == 0 {
            return Err(SlamError::Config {
                field: "window",
                value: "0".into(),
                reason: "must be ≥ 1",
            });
        }
        if !(0.0..=1.0).contains(&self.alpha) {
            return Err(SlamError::Config {
                field: "alpha",
                value: self.alpha.to_string(),
                reason: "must be in [0, 1]",
            });
        }
        if !self.carve_margin_m.is_finite() {
            return Err(SlamError::Config {
                field: "carve_margin_m",
                value: self.carve_margin_m.to_string(),
                reason: "must be finite (0 or less: no carving)",
            });
        }
        let t = self.insert.normal_thickness;
        if !(0.0..=1.0).contains(&t) {
            return Err(SlamError::Config {
                field: "insert.normal_thickness",
                value: t.to_string(),
                reason: "must be in [0, 1] (0: isotropic insertion)",
            });
        }
        let stretch = self.insert.max_grazing_stretch;
        if !(stretch.is_finite() && stretch >= 1.0) {
            return Err(SlamError::Config {
                field: "insert.max_grazing_stretch",
                value: stretch.to_string(),
                reason: "must be finite and ≥ 1 (1: round discs)",
            });
        }
        let support = self.insert.stretch_support_sigmas;
        if !(support.is_finite() && support >= 0.0) {
            return Err(SlamError::Config {
                field: "insert.stretch_support_sigmas",
                value: support.to_string(),
                reason: "must be finite and ≥ 0 (0: off)",
            });
        }
        let ratio = self.max_in_plane_ratio;
        if !(ratio == 0.0 || (ratio.is_finite() && ratio >= 1.0)) {
            return Err(SlamError::Config {
                field: "max_in_plane_ratio",
                value: ratio.to_string(),
                reason: "must be 0 (off) or finite and ≥ 1",
            });
        }
        if !(0.0..1.0).contains(&self.carve_margin_fraction) {
            return Err(SlamError::Config {
                field: "carve_margin_fraction",
                value: self.carve_margin_fraction.to_string(),
                reason: "must be in [0, 1)",
            });
        }
        Ok(())
    }
}

/// A keyframe kept for mapping: the frame (mapping resolution), its pose and exposure.
#[derive(Debug, Clone)]
pub struct Keyframe {
    /// The observed frame.
    pub frame: Frame,
    /// `T_world_camera` from the tracker.
    pub pose: Isometry3<f64>,
    /// Exposure (a, b) from the tracker.
    pub exposure: [f64; 2],
    /// Colour mask of the mapping loss.
    pub rgb_mask: Vec<bool>,
    /// The frame at half resolution and its colour mask, for the coarse iterations.
    pub coarse: Option<(Frame, Vec<bool>)>,
    /// Far plane of the keyframe's renders ([`far_plane`]).
    pub far: f64,
}

/// Margin of the far plane beyond a keyframe's deepest reading, metres: a Gaussian whose centre
/// lies a little behind the farthest surface can still reach it (inserted scales are ≤ 0.2 m).
pub const FAR_PLANE_MARGIN: f64 = 0.25;

/// The far plane a keyframe is rendered with while mapping: [`FAR_PLANE_MARGIN`] beyond its
/// deepest depth reading when at most 1 % of its pixels lack depth (every other pixel sees a
/// surface nearer than that, so the Gaussians beyond are occluded and change no pixel), else
/// none (infinite). Culling them keeps the cost of a mapping step bounded by what the window
/// sees rather than by the size of the whole map (measured in the exploration loop: mapping
/// time per keyframe grew with the map, 1.8 s at 33k to 3.8 s at 168k Gaussians).
pub fn far_plane(frame: &Frame) -> f64 {
    let missing = frame
        .depth
        .iter()
        .filter(|d| d.partial_cmp(&&0.0) != Some(std::cmp::Ordering::Greater))
        .count();
    if missing * 100 > frame.depth.len() {
        return f64::INFINITY;
    }
    let deepest = frame
        .depth
        .iter()
        .copied()
        .filter(|d| d.is_finite())
        .fold(0f32, f32::max);
    deepest as f64 + FAR_PLANE_MARGIN
}

/// What one keyframe's mapping did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MappingReport {
    /// Gaussians inserted from depth.
    pub inserted: usize,
    /// The keyframe's pixels the map did not explain before insertion, by cause: the
    /// population `inserted` was sampled from (without `insert.insert_behind_map`, the
    /// `farther` ones are counted but not sampled).
    pub unobserved: CoverageCounts,
    /// Gaussians pruned.
    pub pruned: usize,
    /// Gaussians removed by free-space carving ([`MapperConfig::carve_margin_m`]).
    pub carved: usize,
    /// Gaussians added by densification.
    pub densified: usize,
    /// Views in the optimisation window.
    pub window_views: usize,
    /// Mean mapping loss over the window at the last iteration.
    pub final_loss: f64,
    /// Map size afterwards.
    pub gaussians: usize,
    /// Gaussians dropped because a parameter (mean, colour, rotation, opacity or scale) was
    /// NaN or infinite.
    pub dropped_non_finite: usize,
}

/// Whether every parameter of Gaussian `i` of `map` (mean, colour, rotation, opacity,
/// log-scales) is finite.
pub fn is_finite_gaussian(map: &Gaussians<f32>, i: usize) -> bool {
    map.params(i).iter().all(|v| v.is_finite())
}

/// Per Gaussian of `map`: true when all its parameters are finite ([`is_finite_gaussian`]).
pub fn finite_mask(map: &Gaussians<f32>) -> Vec<bool> {
    (0..map.len()).map(|i| is_finite_gaussian(map, i)).collect()
}

/// Removes the Gaussians of `map` that have a NaN or infinite parameter; returns how many.
pub fn drop_non_finite(map: &mut Gaussians<f32>) -> Result<usize, SlamError> {
    let keep = finite_mask(map);
    let dropped = keep.iter().filter(|k| !**k).count();
    if dropped > 0 {
        map.retain(&keep)?;
    }
    Ok(dropped)
}

/// Refuses a non-finite keyframe pose, naming it.
fn require_finite_pose(pose: &Isometry3<f64>) -> Result<(), SlamError> {
    if crate::session::finite_pose(pose) {
        return Ok(());
    }
    Err(SlamError::Input {
        what: "keyframe pose",
        reason: format!(
            "not finite (translation {:?}, rotation {:?}); the frame cannot be mapped",
            pose.translation.vector.as_slice(),
            pose.rotation.coords.as_slice()
        ),
    })
}

/// The mapper: the Gaussian map, its optimiser state and the keyframes.
#[derive(Debug, Clone)]
pub struct Mapper {
    config: MapperConfig,
    map: Gaussians<f32>,
    ids: Vec<u64>,
    /// Per Gaussian (parallel to `map`): the index of the keyframe it is anchored to.
    anchors: Vec<u32>,
    next_id: u64,
    adam: GaussianAdam,
    keyframes: Vec<Keyframe>,
    rng: ChaCha8Rng,
}

impl Mapper {
    /// An empty map.
    pub fn new(config: MapperConfig) -> Result<Self, SlamError> {
        config.validate()?;
        let rng = ChaCha8Rng::seed_from_u64(config.seed);
        let adam = GaussianAdam::new(config.learning_rates);
        Ok(Self {
            config,
            map: Gaussians::new(),
            ids: Vec::new(),
            anchors: Vec::new(),
            next_id: 0,
            adam,
            keyframes: Vec::new(),
            rng,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &MapperConfig {
        &self.config
    }

    /// The current map.
    pub fn map(&self) -> &Gaussians<f32> {
        &self.map
    }

    /// Stable ids of the map's Gaussians (parallel to the map; survive pruning).
    pub fn ids(&self) -> &[u64] {
        &self.ids
    }

    /// Per Gaussian (parallel to the map): the index into [`Mapper::keyframes`] of the keyframe
    /// it is anchored to, the one whose insertion made it or its parent (an index equal to the
    /// number of keyframes: inserted by [`Mapper::insert_from`] outside a keyframe).
    pub fn anchors(&self) -> &[u32] {
        &self.anchors
    }

    /// The keyframes so far.
    pub fn keyframes(&self) -> &[Keyframe] {
        &self.keyframes
    }

    /// Moves keyframe `j` by the world-frame rigid motion `moves[j]` (its pose becomes
    /// `moves[j] · pose`), and every Gaussian anchored to it with it (mean `R·μ + t`, rotation
    /// `R·q`; scales, colours and opacities are unchanged, so a render from the moved pose
    /// equals the render from the old one). One move per keyframe; an identity leaves a
    /// keyframe alone. Fails, changing nothing, on a wrong count or a non-finite move. The
    /// optimiser's moments stay as they are. Returns the number of Gaussians moved.
    pub fn move_keyframes(&mut self, moves: &[Isometry3<f64>]) -> Result<usize, SlamError> {
        if moves.len() != self.keyframes.len() {
            return Err(SlamError::Input {
                what: "keyframe moves",
                reason: format!(
                    "{} moves for {} keyframes",
                    moves.len(),
                    self.keyframes.len()
                ),
            });
        }
        if let Some(j) = moves.iter().position(|m| !crate::session::finite_pose(m)) {
            return Err(SlamError::Input {
                what: "keyframe moves",
                reason: format!("the move of keyframe {j} is not finite"),
            });
        }
        let moved: Vec<bool> = moves.iter().map(|m| *m != Isometry3::identity()).collect();
        for ((keyframe, m), &moves_it) in self.keyframes.iter_mut().zip(moves).zip(&moved) {
            if moves_it {
                keyframe.pose = activemap_geometry::se3::normalized(&(m * keyframe.pose));
            }
        }
        let mut count = 0;
        for (i, &anchor) in self.anchors.iter().enumerate() {
            let a = anchor as usize;
            if !moved.get(a).copied().unwrap_or(false) {
                continue;
            }
            let m = &moves[a];
            let mean = self.map.means[i].map(|v| v as f64);
            let p = m * nalgebra::Point3::new(mean[0], mean[1], mean[2]);
            self.map.means[i] = [p.x as f32, p.y as f32, p.z as f32];
            let q = self.map.rotations[i].map(|v| v as f64);
            let rotated =
                m.rotation.quaternion() * nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]);
            self.map.rotations[i] = [rotated.w, rotated.i, rotated.j, rotated.k].map(|v| v as f32);
            count += 1;
        }
        Ok(count)
    }

    /// Appends Gaussians anchored to keyframe `anchors[i]`, keeping ids, anchors and optimiser
    /// state in step.
    fn append(&mut self, added: &Gaussians<f32>, anchors: &[u32]) {
        debug_assert_eq!(added.len(), anchors.len());
        self.anchors.extend_from_slice(anchors);
        self.map.extend_from(added);
        self.adam.grow(added.len());
        self.ids
            .extend(self.next_id..self.next_id + added.len() as u64);
        self.next_id += added.len() as u64;
    }

    /// Removes Gaussians (`keep[i] == false`) from the map, ids and optimiser state.
    fn retain(&mut self, keep: &[bool]) -> Result<usize, SlamError> {
        let before = self.map.len();
        self.map.retain(keep)?;
        self.adam.retain(keep);
        let mut k = keep.iter();
        self.ids.retain(|_| *k.next().unwrap_or(&false));
        let mut k = keep.iter();
        self.anchors.retain(|_| *k.next().unwrap_or(&false));
        Ok(before - self.map.len())
    }

    /// Removes the Gaussians with a NaN or infinite parameter (with their ids and optimiser
    /// state); returns how many.
    fn drop_non_finite(&mut self) -> Result<usize, SlamError> {
        let keep = finite_mask(&self.map);
        if keep.iter().all(|k| *k) {
            return Ok(0);
        }
        self.retain(&keep)
    }

    /// Inserts Gaussians from `frame` at `pose` where the map does not explain the depth;
    /// fails on a non-finite pose. Returns how many.
    pub fn insert_from(
        &mut self,
        frame: &Frame,
        pose: &Isometry3<f64>,
    ) -> Result<usize, SlamError> {
        Ok(self.insert_with_causes(frame, pose)?.0)
    }

    /// [`Mapper::insert_from`], also returning the unexplained pixels by cause.
    pub fn insert_with_causes(
        &mut self,
        frame: &Frame,
        pose: &Isometry3<f64>,
    ) -> Result<(usize, CoverageCounts), SlamError> {
        require_finite_pose(pose)?;
        let camera = Camera::from_world_pose(frame.intrinsics, pose).with_far(far_plane(frame));
        let options = RenderOptions {
            exposure: [0.0, 0.0],
            exclude_flags: FLAG_UNKNOWN_SPACE,
            depth: self.config.depth_model,
        };
        let rendered = render(&self.map, &camera, &options)?;
        let insert = &self.config.insert;
        let coverage = pixel_coverage(&rendered, frame, insert);
        let counts = CoverageCounts::of(&coverage);
        let mask = unobserved_mask(&coverage, insert);
        let new = sample_new_gaussians(frame, pose, &mask, insert, &mut self.rng);
        let mut added = Gaussians::new();
        let mut push = |new: &[crate::insert::NewGaussian], opacity: f64| {
            for g in new {
                added.push(g.mean, g.rgb, g.rotation, opacity, g.scales);
            }
        };
        push(&new, insert.opacity);
        let mut count = new.len();
        if insert.refresh_fraction > 0.0 {
            let refresh = InsertConfig {
                sample_fraction: insert.refresh_fraction,
                target_samples: 0,
                ..insert.clone()
            };
            let explained = explained_mask(frame, &mask);
            let fresh = sample_new_gaussians(frame, pose, &explained, &refresh, &mut self.rng);
            push(&fresh, insert.refresh_opacity);
            count += fresh.len();
        }
        let anchor = self.keyframes.len() as u32;
        self.append(&added, &vec![anchor; added.len()]);
        Ok((count, counts))
    }

    /// Processes a keyframe: insertion, window optimisation, pruning, densification. Fails on
    /// a non-finite pose or exposure (the map is then unchanged).
    pub fn add_keyframe(
        &mut self,
        frame: Frame,
        pose: Isometry3<f64>,
        exposure: [f64; 2],
    ) -> Result<MappingReport, SlamError> {
        require_finite_pose(&pose)?;
        if !exposure.iter().all(|v| v.is_finite()) {
            return Err(SlamError::Input {
                what: "keyframe exposure",
                reason: format!("not finite: {exposure:?}"),
            });
        }
        let (inserted, unobserved) = self.insert_with_causes(&frame, &pose)?;
        let mut report = MappingReport {
            inserted,
            unobserved,
            ..Default::default()
        };
        let mask = rgb_mask(&frame, self.config.rgb_boundary, 0.0);
        let coarse = (self.config.coarse_iterations > 0).then(|| {
            let small = frame.downscale(2);
            let small_mask = rgb_mask(&small, self.config.rgb_boundary, 0.0);
            (small, small_mask)
        });
        self.keyframes.push(Keyframe {
            far: far_plane(&frame),
            frame,
            pose,
            exposure,
            rgb_mask: mask,
            coarse,
        });
        let refined = self.optimise(self.config.iterations)?;
        self.snap_to_newest();
        let carved = self.carve_free_space()?;
        report.window_views = refined.window_views;
        report.final_loss = refined.final_loss;
        report.pruned = refined.pruned;
        report.carved = carved;
        report.densified = refined.densified;
        report.dropped_non_finite = refined.dropped_non_finite;
        report.gaussians = self.map.len();
        Ok(report)
    }

    /// Runs `iterations` optimisation steps over the current window (the most recent
    /// keyframes plus random older ones), then prunes and densifies. `add_keyframe` calls it;
    /// callers may also call it to refine the map between keyframes. Gaussians with a
    /// non-finite parameter are dropped first (one would spread NaN through the renders) and
    /// again at the end; the report counts them.
    pub fn optimise(&mut self, iterations: usize) -> Result<MappingReport, SlamError> {
        let mut report = MappingReport {
            dropped_non_finite: self.drop_non_finite()?,
            ..Default::default()
        };
        if self.keyframes.is_empty() {
            report.gaussians = self.map.len();
            return Ok(report);
        }
        let window = self.window_indices();
        report.window_views = window.len();
        let mut grad_sum = vec![0f64; self.map.len()];
        let mut grad_count = vec![0u32; self.map.len()];
        let mut in_window = vec![false; self.map.len()];
        for iteration in 0..iterations {
            let views = self.iteration_views(&window);
            let coarse = iteration < self.config.coarse_iterations;
            report.final_loss = self.optimise_once(
                &views,
                coarse,
                &mut grad_sum,
                &mut grad_count,
                &mut in_window,
            )?;
        }
        if iterations > 0 {
            let (pruned, densified) = self.prune_and_densify(&grad_sum, &grad_count, &in_window)?;
            report.pruned = pruned;
            report.densified = densified;
        }
        report.dropped_non_finite += self.drop_non_finite()?;
        report.gaussians = self.map.len();
        Ok(report)
    }

    /// The window: the `window` most recent keyframes plus `random_older` random older ones.
    fn window_indices(&mut self) -> Vec<usize> {
        let n = self.keyframes.len();
        let start = n.saturating_sub(self.config.window);
        let mut out: Vec<usize> = (start..n).collect();
        let mut older: Vec<usize> = (0..start).collect();
        for _ in 0..self.config.random_older.min(older.len()) {
            let j = self.rng.random_range(0..older.len());
            out.push(older.swap_remove(j));
        }
        out
    }

    /// The views of one iteration: the newest keyframe (last of the recent part of `window`)
    /// plus `views_per_iteration − 1` others drawn without replacement from the window.
    fn iteration_views(&mut self, window: &[usize]) -> Vec<usize> {
        let per_iteration = self.config.views_per_iteration;
        if per_iteration == 0 || per_iteration >= window.len() {
            return window.to_vec();
        }
        let newest = self.keyframes.len() - 1;
        let mut others: Vec<usize> = window.iter().copied().filter(|&k| k != newest).collect();
        let mut out = vec![newest];
        for _ in 0..(per_iteration - 1).min(others.len()) {
            let j = self.rng.random_range(0..others.len());
            out.push(others.swap_remove(j));
        }
        out
    }

    /// One optimisation step over the given views (at half resolution when `coarse` and the
    /// keyframe has a coarse copy); returns the mean loss over the views.
    fn optimise_once(
        &mut self,
        window: &[usize],
        coarse: bool,
        grad_sum: &mut [f64],
        grad_count: &mut [u32],
        in_window: &mut [bool],
    ) -> Result<f64, SlamError> {
        let n = self.map.len();
        let mut total: Option<Gradients<f32>> = None;
        let mut active = vec![false; n];
        let mut loss_sum = 0.0;
        for &kf in window {
            let keyframe = &self.keyframes[kf];
            let (frame, mask) = match (&keyframe.coarse, coarse) {
                (Some((small, small_mask)), true) => (small, small_mask),
                _ => (&keyframe.frame, &keyframe.rgb_mask),
            };
            let camera =
                Camera::from_world_pose(frame.intrinsics, &keyframe.pose).with_far(keyframe.far);
            let options = RenderOptions {
                exposure: keyframe.exposure,
                exclude_flags: FLAG_UNKNOWN_SPACE,
                depth: self.config.depth_model,
            };
            let rendered = render(&self.map, &camera, &options)?;
            let loss = mapping_loss(
                &rendered,
                frame,
                mask,
                self.config.alpha,
                self.config.depth_loss,
            );
            loss_sum += loss.value;
            let grads = backward(&self.map, &rendered, &loss.grads)?;
            let ndc = 0.5 * frame.width() as f64;
            for i in 0..n {
                if rendered.context.visible[i] {
                    active[i] = true;
                    in_window[i] = true;
                    grad_sum[i] += grads.mean2d_norm[i] as f64 * ndc;
                    grad_count[i] += 1;
                }
            }
            match &mut total {
                None => total = Some(grads),
                Some(t) => add_gradients(t, &grads),
            }
        }
        let Some(mut total) = total else {
            return Ok(0.0);
        };
        self.add_isotropic_gradient(&mut total, &active);
        self.add_flat_gradient(&mut total, &active);
        self.adam.step_active(&mut self.map, &total, &active)?;
        self.limit_in_plane_ratio(&active);
        Ok(loss_sum / window.len().max(1) as f64)
    }

    /// Lowers the largest log-scale of each active Gaussian to at most the middle one's plus
    /// `ln(max_in_plane_ratio)` ([`MapperConfig::max_in_plane_ratio`]; nothing when 0).
    fn limit_in_plane_ratio(&mut self, active: &[bool]) {
        let ratio = self.config.max_in_plane_ratio;
        if ratio == 0.0 {
            return;
        }
        let limit = ratio.ln() as f32;
        for (scales, _) in self
            .map
            .log_scales
            .iter_mut()
            .zip(active)
            .filter(|(_, a)| **a)
        {
            let largest = (0..3)
                .max_by(|&a, &b| scales[a].total_cmp(&scales[b]))
                .expect("three axes");
            let middle = (0..3)
                .filter(|&k| k != largest)
                .map(|k| scales[k])
                .fold(f32::NEG_INFINITY, f32::max);
            scales[largest] = scales[largest].min(middle + limit);
        }
    }

    /// Adds ∂/∂log-scale of `w·mean_{i,k}|s_ik − s̄_i|` over the active Gaussians.
    fn add_isotropic_gradient(&self, grads: &mut Gradients<f32>, active: &[bool]) {
        let count = active.iter().filter(|&&a| a).count();
        if count == 0 || self.config.isotropic_weight == 0.0 {
            return;
        }
        let scale = self.config.isotropic_weight / (3 * count) as f32;
        for i in 0..self.map.len() {
            if !active[i] {
                continue;
            }
            let s = self.map.log_scales[i].map(f32::exp);
            let mean = (s[0] + s[1] + s[2]) / 3.0;
            let signs = s.map(|v| {
                if v > mean {
                    1.0
                } else if v < mean {
                    -1.0
                } else {
                    0.0
                }
            });
            let sign_mean = (signs[0] + signs[1] + signs[2]) / 3.0;
            for j in 0..3 {
                // ∂/∂s_j Σ_k |s_k − s̄| = sign_j − mean(sign); chain through s = e^{log s}.
                grads.log_scales[i][j] += scale * (signs[j] - sign_mean) * s[j];
            }
        }
    }

    /// Moves the centres just behind the newest keyframe's readings onto them
    /// ([`MapperConfig::snap_behind_m`]); returns how many moved.
    fn snap_to_newest(&mut self) -> usize {
        let band = self.config.snap_behind_m;
        let Some(keyframe) = self.keyframes.last() else {
            return 0;
        };
        if band <= 0.0 {
            return 0;
        }
        let frame = &keyframe.frame;
        let camera_from_world = keyframe.pose.inverse();
        let mut moved = 0;
        for mean in &mut self.map.means {
            let Some((p, u, v)) = pixel_of(frame, &camera_from_world, mean, 0) else {
                continue;
            };
            let d = f64::from(frame.depth[v * frame.width() + u]);
            let low = if self.config.snap_in_front {
                d - band
            } else {
                d
            };
            let reading = d > f64::from(crate::loss::MIN_DEPTH);
            if !reading || p.z <= low || p.z >= d + band {
                continue;
            }
            let on = keyframe.pose * nalgebra::Point3::from(p.coords * (d / p.z));
            *mean = [on.x as f32, on.y as f32, on.z as f32];
            moved += 1;
        }
        moved
    }

    /// Removes the Gaussians that the newest keyframe sees through
    /// ([`MapperConfig::carve_margin_m`]); returns how many.
    fn carve_free_space(&mut self) -> Result<usize, SlamError> {
        let margin = self.config.carve_margin_m;
        let Some(keyframe) = self.keyframes.last() else {
            return Ok(0);
        };
        if margin <= 0.0 {
            return Ok(0);
        }
        let fraction = self.config.carve_margin_fraction;
        let frame = &keyframe.frame;
        let w = frame.width();
        let camera_from_world = keyframe.pose.inverse();
        let keep: Vec<bool> = self
            .map
            .means
            .par_iter()
            .zip(&self.map.flags)
            .map(|(mean, &flags)| {
                if flags & FLAG_UNKNOWN_SPACE != 0 {
                    return true;
                }
                let Some((p, u, v)) = pixel_of(frame, &camera_from_world, mean, 1) else {
                    return true;
                };
                let mut nearest = f64::INFINITY;
                for row in v - 1..=v + 1 {
                    for d in &frame.depth[row * w + u - 1..=row * w + u + 1] {
                        if *d <= crate::loss::MIN_DEPTH {
                            return true;
                        }
                        nearest = nearest.min(f64::from(*d));
                    }
                }
                p.z >= nearest - margin.max(fraction * nearest)
            })
            .collect();
        self.retain(&keep)
    }

    /// Adds ∂/∂log-scale of `w·mean_i min_k s_ik` over the active Gaussians (the flat
    /// regulariser, [`MapperConfig::flat_weight`]): `w/count · s_min` on the thinnest axis.
    fn add_flat_gradient(&self, grads: &mut Gradients<f32>, active: &[bool]) {
        let count = active.iter().filter(|&&a| a).count();
        if count == 0 || self.config.flat_weight == 0.0 {
            return;
        }
        let scale = self.config.flat_weight / count as f32;
        for (i, _) in active.iter().enumerate().filter(|(_, a)| **a) {
            let l = self.map.log_scales[i];
            let k = (0..3).fold(0, |best, j| if l[j] < l[best] { j } else { best });
            grads.log_scales[i][k] += scale * l[k].exp();
        }
    }

    /// Prunes by opacity and size and densifies by gradient (see the module doc); returns
    /// (pruned, added by densification). Statistics index the map before this call.
    fn prune_and_densify(
        &mut self,
        grad_sum: &[f64],
        grad_count: &[u32],
        in_window: &[bool],
    ) -> Result<(usize, usize), SlamError> {
        let n = self.map.len();
        let cfg = &self.config;
        let mut keep: Vec<bool> = (0..n)
            .map(|i| {
                let o = self.map.opacity(i);
                let old = self.adam.steps(i) >= cfg.prune_min_age;
                let weak_in_window = in_window.get(i).copied().unwrap_or(false)
                    && old
                    && o < cfg.prune_opacity_window;
                o >= cfg.prune_opacity_early
                    && !weak_in_window
                    && max_scale(&self.map, i) <= cfg.prune_max_scale
            })
            .collect();
        let pruned = keep.iter().filter(|k| !**k).count();
        let mut added = Gaussians::<f32>::new();
        let mut added_anchors = Vec::new();
        for i in 0..n {
            if n + added.len() >= cfg.max_gaussians {
                break;
            }
            let count = grad_count.get(i).copied().unwrap_or(0);
            if !keep[i] || count == 0 {
                continue;
            }
            if grad_sum[i] / (count as f64) <= cfg.densify_grad {
                continue;
            }
            if max_scale(&self.map, i) <= cfg.densify_split_scale {
                copy_gaussian(&self.map, i, &mut added);
                added_anchors.push(self.anchors[i]);
            } else {
                // Split: two samples from the Gaussian, scales / 1.6; the original goes.
                keep[i] = false;
                let q = self.map.rotations[i];
                let rotation = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
                    q[0] as f64,
                    q[1] as f64,
                    q[2] as f64,
                    q[3] as f64,
                ));
                let s = self.map.log_scales[i].map(|v| (v as f64).exp());
                for _ in 0..2 {
                    let z: [f64; 3] = [0; 3].map(|_| StandardNormal.sample(&mut self.rng));
                    let offset = rotation * Vector3::new(z[0] * s[0], z[1] * s[1], z[2] * s[2]);
                    copy_gaussian(&self.map, i, &mut added);
                    added_anchors.push(self.anchors[i]);
                    let last = added.len() - 1;
                    for k in 0..3 {
                        added.means[last][k] += offset[k] as f32;
                        added.log_scales[last][k] -= 1.6f32.ln();
                    }
                }
            }
        }
        let densified = added.len();
        self.retain(&keep)?;
        self.append(&added, &added_anchors);
        Ok((pruned, densified))
    }
}

/// A map point `mean` (world) in `frame`'s camera (`camera_from_world`), and the pixel it falls
/// on (rounded), when it projects at least `border` pixels inside the image: what the newest
/// keyframe's snapping and carving compare with that keyframe's readings.
fn pixel_of(
    frame: &Frame,
    camera_from_world: &Isometry3<f64>,
    mean: &[f32; 3],
    border: usize,
) -> Option<(nalgebra::Point3<f64>, usize, usize)> {
    let p = camera_from_world * nalgebra::Point3::from(mean.map(f64::from));
    let (u, v) = frame.pixel_of(&p, border)?;
    Some((p, u, v))
}

/// Largest per-axis scale of Gaussian `i`, metres.
fn max_scale(map: &Gaussians<f32>, i: usize) -> f64 {
    map.log_scales[i]
        .iter()
        .fold(f32::MIN, |a, &b| a.max(b))
        .exp() as f64
}

/// Appends a copy of Gaussian `i` of `src` (raw parameters) to `dst`.
pub(crate) fn copy_gaussian(src: &Gaussians<f32>, i: usize, dst: &mut Gaussians<f32>) {
    dst.means.push(src.means[i]);
    dst.sh_dc.push(src.sh_dc[i]);
    dst.rotations.push(src.rotations[i]);
    dst.opacity_logits.push(src.opacity_logits[i]);
    dst.log_scales.push(src.log_scales[i]);
    dst.flags.push(src.flags[i]);
}

/// Adds `b` into `a` (same map).
fn add_gradients(a: &mut Gradients<f32>, b: &Gradients<f32>) {
    for i in 0..a.means.len() {
        for k in 0..3 {
            a.means[i][k] += b.means[i][k];
            a.sh_dc[i][k] += b.sh_dc[i][k];
            a.log_scales[i][k] += b.log_scales[i][k];
        }
        for k in 0..4 {
            a.rotations[i][k] += b.rotations[i][k];
        }
        a.opacity_logits[i] += b.opacity_logits[i];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_geometry::Intrinsics;

    /// A 32×32, 90° camera facing a textured plane; `depth_at(x, y)` gives the depth per pixel.
    fn plane_frame(depth_at: impl Fn(usize, usize) -> f32) -> Frame {
        let k = Intrinsics::from_hfov(32, 32, std::f64::consts::FRAC_PI_2);
        let mut rgb = Vec::new();
        let mut depth = Vec::new();
        for y in 0..32 {
            for x in 0..32 {
                let c = if (x / 4 + y / 4) % 2 == 0 { 0.8 } else { 0.2 };
                rgb.push([c, 0.5, 1.0 - c]);
                depth.push(depth_at(x, y));
            }
        }
        Frame::new(k, rgb, depth, 0.0).unwrap()
    }

    fn dense_config() -> MapperConfig {
        let mut c = MapperConfig {
            iterations: 0,
            ..MapperConfig::default()
        };
        c.insert.sample_fraction = 0.5;
        c
    }

    /// Grey, half-opaque, unrotated Gaussians at x = 0, 1, 2, … (z = 1), with the given scales.
    fn gaussians_in_a_row(scales: &[[f64; 3]]) -> Gaussians<f32> {
        let mut added = Gaussians::new();
        for (i, s) in scales.iter().enumerate() {
            added.push(
                [i as f64, 0.0, 1.0],
                [0.5; 3],
                [1.0, 0.0, 0.0, 0.0],
                0.5,
                *s,
            );
        }
        added
    }

    /// `max_in_plane_ratio` lowers the largest scale of each active Gaussian to at most that
    /// ratio times its middle one, whichever axis is the largest, and leaves the other axes,
    /// the inactive Gaussians and (at 0) every Gaussian as they were.
    #[test]
    fn the_in_plane_ratio_limit_shortens_the_longest_axis_of_active_gaussians_only() {
        let scales = [[0.10, 0.02, 0.002], [0.001, 0.03, 0.01], [0.04, 0.005, 0.4]];
        let added = gaussians_in_a_row(&scales);
        let active = [true, true, false];
        let limited = |ratio: f64| {
            let mut mapper = Mapper::new(MapperConfig {
                max_in_plane_ratio: ratio,
                ..MapperConfig::default()
            })
            .unwrap();
            mapper.append(&added, &[0, 0, 0]);
            mapper.limit_in_plane_ratio(&active);
            mapper
                .map
                .log_scales
                .iter()
                .map(|l| l.map(|v| f64::from(v).exp()))
                .collect::<Vec<_>>()
        };
        let close = |a: [f64; 3], b: [f64; 3]| a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-6);
        let out = limited(1.5);
        assert!(close(out[0], [0.03, 0.02, 0.002]), "{:?}", out[0]);
        // The largest axis of the second is its middle one in memory.
        assert!(close(out[1], [0.001, 0.015, 0.01]), "{:?}", out[1]);
        assert!(close(out[2], scales[2]), "inactive: {:?}", out[2]);
        let off = limited(0.0);
        for (got, want) in off.iter().zip(&scales) {
            assert!(close(*got, *want), "{got:?}");
        }
        let bad = MapperConfig {
            max_in_plane_ratio: 0.5,
            ..MapperConfig::default()
        };
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("max_in_plane_ratio")
        );
    }

    /// The flat regulariser's log-scale gradient equals central finite differences (in f64) of
    /// its value `w·mean_i min_k s_ik` over the active Gaussians; inactive ones get none.
    #[test]
    fn flat_regulariser_gradient_matches_finite_differences() {
        let mut mapper = Mapper::new(MapperConfig {
            flat_weight: 3.0,
            ..MapperConfig::default()
        })
        .unwrap();
        let scales = [[0.05, 0.02, 0.08], [0.01, 0.03, 0.02], [0.04, 0.04, 0.004]];
        let added = gaussians_in_a_row(&scales);
        mapper.append(&added, &[0, 0, 0]);
        let active = [true, true, false];
        let value = |log_scales: &[[f64; 3]]| {
            let sum: f64 = log_scales
                .iter()
                .zip(&active)
                .filter(|(_, a)| **a)
                .map(|(l, _)| l.iter().map(|v| v.exp()).fold(f64::INFINITY, f64::min))
                .sum();
            3.0 * sum / 2.0
        };
        let mut grads = Gradients {
            means: vec![[0.0; 3]; 3],
            sh_dc: vec![[0.0; 3]; 3],
            rotations: vec![[0.0; 4]; 3],
            opacity_logits: vec![0.0; 3],
            log_scales: vec![[0.0; 3]; 3],
            mean2d_norm: vec![0.0; 3],
            pose: nalgebra::Vector6::zeros(),
            exposure: [0.0; 2],
        };
        mapper.add_flat_gradient(&mut grads, &active);
        let base: Vec<[f64; 3]> = scales.iter().map(|s| s.map(f64::ln)).collect();
        let h = 1e-6;
        for i in 0..3 {
            for k in 0..3 {
                let (mut up, mut down) = (base.clone(), base.clone());
                up[i][k] += h;
                down[i][k] -= h;
                let fd = (value(&up) - value(&down)) / (2.0 * h);
                let analytic = f64::from(grads.log_scales[i][k]);
                assert!((fd - analytic).abs() < 1e-5, "{i} {k}: {fd} vs {analytic}");
            }
        }
    }

    #[test]
    fn the_far_plane_lies_beyond_the_deepest_reading_unless_depth_is_missing() {
        let k = Intrinsics::from_hfov(10, 10, std::f64::consts::FRAC_PI_2);
        let mut depth: Vec<f32> = (0..100).map(|i| 1.0 + 0.03 * i as f32).collect();
        let frame = Frame::new(k, vec![[0.5; 3]; 100], depth.clone(), 0.0).unwrap();
        let expected = (1.0f32 + 0.03 * 99.0) as f64 + FAR_PLANE_MARGIN;
        assert!((far_plane(&frame) - expected).abs() < 1e-12);
        // One pixel in a hundred without depth is tolerated; two are not (the far Gaussians
        // could show through them).
        depth[5] = 0.0;
        let one = Frame::new(k, vec![[0.5; 3]; 100], depth.clone(), 0.0).unwrap();
        assert!((far_plane(&one) - expected).abs() < 1e-12);
        depth[6] = 0.0;
        let two = Frame::new(k, vec![[0.5; 3]; 100], depth, 0.0).unwrap();
        assert_eq!(far_plane(&two), f64::INFINITY);
    }

    /// The causes of an unexplained pixel: a reading in front of the map's surface (Nearer),
    /// behind it (Farther, inserted only with `insert_behind_map`), or where the map has
    /// nothing (Transparent).
    #[test]
    fn unexplained_pixels_are_counted_by_cause_and_readings_behind_the_map_can_be_left_out() {
        let wall = plane_frame(|_, _| 2.0);
        // Left third nearer than the wall, right third behind it, middle unchanged.
        let moved = plane_frame(|x, _| match x {
            0..=9 => 1.5,
            10..=21 => 2.0,
            _ => 3.0,
        });
        for behind in [true, false] {
            let mut config = dense_config();
            config.insert.insert_behind_map = behind;
            let mut mapper = Mapper::new(config).unwrap();
            let (_, first) = mapper
                .insert_with_causes(&wall, &Isometry3::identity())
                .unwrap();
            assert_eq!(first.transparent, 32 * 32);
            assert_eq!((first.nearer, first.farther), (0, 0));
            let before = mapper.map().len();
            let (added, counts) = mapper
                .insert_with_causes(&moved, &Isometry3::identity())
                .unwrap();
            // Away from the borders of the regions (where the rendered blobs blend), every
            // pixel of a region has its region's cause.
            assert!(
                counts.nearer >= 32 * 8 && counts.nearer <= 32 * 11,
                "{counts:?}"
            );
            assert!(
                counts.farther >= 32 * 8 && counts.farther <= 32 * 11,
                "{counts:?}"
            );
            assert!(counts.transparent < 32, "{counts:?}");
            let depths: Vec<f32> = mapper.map().means[before..].iter().map(|m| m[2]).collect();
            assert_eq!(depths.len(), added);
            assert!(depths.iter().any(|&z| (z - 1.5).abs() < 1e-3));
            assert_eq!(
                depths.iter().any(|&z| (z - 3.0).abs() < 1e-3),
                behind,
                "readings behind the map inserted: {behind}"
            );
        }
    }

    /// Free-space carving removes a Gaussian the newest keyframe sees through, keeps those on
    /// or just in front of the surface (within the margin) and those next to a thin structure
    /// the 3×3 window contains, and is off at margin 0.
    #[test]
    fn carving_removes_what_the_newest_keyframe_sees_through() {
        // A wall at 2 m with a one-pixel-wide pole at 1 m in column 16.
        let view = plane_frame(|x, _| if x == 16 { 1.0 } else { 2.0 });
        let k = view.intrinsics;
        let at = |u: f64, v: f64, z: f64| {
            let p = k.unproject(u, v, z);
            [p.x, p.y, p.z]
        };
        let floaters = [
            at(8.0, 8.0, 1.0),    // 1 m in front of the wall: carved
            at(24.0, 20.0, 1.85), // 15 cm in front: carved (margin max(5 cm, 5 % of 2 m))
            at(8.0, 20.0, 1.93),  // 7 cm in front: within the margin, kept
            at(17.0, 12.0, 1.0),  // beside the pole at the pole's depth: kept
            at(0.0, 12.0, 1.0),   // on the border (no full 3×3 window): kept
        ];
        let kept = [false, false, true, true, true];
        for margin in [0.05, 0.0] {
            let mut config = dense_config();
            config.carve_margin_m = margin;
            let mut mapper = Mapper::new(config).unwrap();
            let mut extra = Gaussians::<f32>::new();
            for f in floaters {
                extra.push(f, [0.5; 3], [1.0, 0.0, 0.0, 0.0], 0.9, [0.01; 3]);
            }
            mapper.append(&extra, &[0; 5]);
            let ids = mapper.ids().to_vec();
            let report = mapper
                .add_keyframe(view.clone(), Isometry3::identity(), [0.0, 0.0])
                .unwrap();
            let survivors: Vec<bool> = ids.iter().map(|id| mapper.ids().contains(id)).collect();
            if margin > 0.0 {
                assert_eq!(survivors, kept);
                assert_eq!(report.carved, 2);
                // The Gaussians the keyframe inserted sit on its readings: none is carved.
                assert_eq!(mapper.map().len(), 3 + report.inserted);
            } else {
                assert_eq!(survivors, vec![true; 5]);
                assert_eq!(report.carved, 0);
            }
        }
    }

    #[test]
    fn insertion_happens_in_unobserved_areas_only() {
        let mut mapper = Mapper::new(dense_config()).unwrap();
        let wall = plane_frame(|_, _| 2.0);
        let first = mapper.insert_from(&wall, &Isometry3::identity()).unwrap();
        assert!(first > 300, "{first}");
        // The same view again: everything is explained, nothing is added.
        assert_eq!(
            mapper.insert_from(&wall, &Isometry3::identity()).unwrap(),
            0
        );
        // A box appears in front of the left half: new Gaussians there only, at its depth.
        let with_box = plane_frame(|x, _| if x < 16 { 1.0 } else { 2.0 });
        let before = mapper.map().len();
        let added = mapper
            .insert_from(&with_box, &Isometry3::identity())
            .unwrap();
        assert!(added > 100, "{added}");
        for i in before..mapper.map().len() {
            let m = mapper.map().means[i];
            assert!(
                (m[2] - 1.0).abs() < 1e-3 && m[0] < 0.0,
                "new Gaussian at {m:?} outside the box"
            );
        }
        // Ids stay parallel and unique.
        assert_eq!(mapper.ids().len(), mapper.map().len());
        assert_eq!(*mapper.ids().last().unwrap(), mapper.map().len() as u64 - 1);
        // The map holds observed Gaussians only (unknown space lives in the active scorer).
        assert!(mapper.map().flags.iter().all(|&f| f == 0));
    }

    #[test]
    fn pruning_removes_transparent_and_weak_old_gaussians() {
        let mut mapper = Mapper::new(dense_config()).unwrap();
        let wall = plane_frame(|_, _| 2.0);
        mapper
            .add_keyframe(wall, Isometry3::identity(), [0.0, 0.0])
            .unwrap();
        let n = mapper.map().len();
        // Gaussian 0 nearly transparent, Gaussian 1 at 0.5 opacity (weak, but young).
        mapper.map.opacity_logits[0] = activemap_splat::gaussians::logit(0.001) as f32;
        let id0 = mapper.ids()[0];
        let report = mapper.optimise(1).unwrap();
        assert!(
            !mapper.ids().contains(&id0),
            "the transparent Gaussian survived"
        );
        assert!(report.pruned >= 1 && mapper.map().len() < n + report.densified);
        // A weak (0.05) but young Gaussian survives the window rule: with 1 Adam step it is
        // far below `prune_min_age` (the old rule deleted Gaussians before they could fit).
        let mut young_mapper = Mapper::new(dense_config()).unwrap();
        young_mapper
            .add_keyframe(plane_frame(|_, _| 2.0), Isometry3::identity(), [0.0, 0.0])
            .unwrap();
        let young = young_mapper.ids()[5];
        young_mapper.map.opacity_logits[5] = activemap_splat::gaussians::logit(0.05) as f32;
        young_mapper.optimise(1).unwrap();
        assert!(young_mapper.ids().contains(&young));
        // Once old enough, Gaussians below the window threshold (0.1) are pruned.
        let cfg = MapperConfig {
            prune_min_age: 1,
            ..dense_config()
        };
        let mut mapper2 = Mapper::new(cfg).unwrap();
        mapper2
            .add_keyframe(plane_frame(|_, _| 2.0), Isometry3::identity(), [0.0, 0.0])
            .unwrap();
        let weak = mapper2.ids()[5];
        mapper2.map.opacity_logits[5] = activemap_splat::gaussians::logit(0.05) as f32;
        mapper2.optimise(1).unwrap();
        assert!(!mapper2.ids().contains(&weak));
        let above_threshold = (0..mapper2.map().len())
            .filter(|&i| mapper2.map().opacity(i) >= 0.1)
            .count();
        assert_eq!(above_threshold, mapper2.map().len());
    }
    /// Bad numbers (issue 18): Gaussians whose mean, colour, rotation, opacity or scale is NaN
    /// or infinite are dropped (with their ids) before they can spread NaN through a render,
    /// and counted in the report; the rest of the map stays finite and keeps optimising.
    #[test]
    fn non_finite_gaussians_are_dropped_and_counted() {
        let config = MapperConfig {
            iterations: 2,
            coarse_iterations: 1,
            ..dense_config()
        };
        let mut mapper = Mapper::new(config).unwrap();
        mapper
            .add_keyframe(plane_frame(|_, _| 2.0), Isometry3::identity(), [0.0, 0.0])
            .unwrap();
        let n = mapper.map().len();
        // (Gaussian, parameter in the layout order, value): mean x, mean z, colour, rotation,
        // opacity, log-scale.
        let bad = [
            (3, 0, f32::NAN),
            (10, 2, f32::NEG_INFINITY),
            (20, 4, f32::NAN),
            (30, 7, f32::INFINITY),
            (40, 10, f32::NAN),
            (50, 12, f32::INFINITY),
        ];
        let bad_ids: Vec<u64> = bad.iter().map(|(i, _, _)| mapper.ids()[*i]).collect();
        for (i, k, v) in bad {
            *mapper.map.param_mut(i, k) = v;
        }
        assert_eq!(finite_mask(mapper.map()).iter().filter(|f| !**f).count(), 6);
        let report = mapper.optimise(2).unwrap();
        assert_eq!(report.dropped_non_finite, bad.len(), "{report:?}");
        assert!(report.final_loss.is_finite(), "{report:?}");
        assert!(bad_ids.iter().all(|id| !mapper.ids().contains(id)));
        assert_eq!(mapper.ids().len(), mapper.map().len());
        assert!(finite_mask(mapper.map()).iter().all(|f| *f));
        assert!(mapper.map().len() >= n - bad.len() - report.pruned);
        // Through a keyframe: the count reaches the keyframe's report.
        *mapper.map.param_mut(0, 1) = f32::NAN;
        let report = mapper
            .add_keyframe(plane_frame(|_, _| 2.0), Isometry3::identity(), [0.0, 0.0])
            .unwrap();
        assert_eq!(report.dropped_non_finite, 1);
        assert!(finite_mask(mapper.map()).iter().all(|f| *f));
        // The free function does the same on a bare map.
        let mut map = mapper.map().clone();
        map.log_scales[2][0] = f32::NAN;
        assert_eq!(drop_non_finite(&mut map).unwrap(), 1);
        assert_eq!(map.len(), mapper.map().len() - 1);
    }

    /// The Gaussians of `map` anchored to keyframe `anchor`.
    fn anchored_to(mapper: &Mapper, anchor: u32) -> Gaussians<f32> {
        let mut out = Gaussians::new();
        for (i, a) in mapper.anchors().iter().enumerate() {
            if *a == anchor {
                copy_gaussian(mapper.map(), i, &mut out);
            }
        }
        out
    }

    /// Moving a keyframe (the pose graph's correction) moves exactly the Gaussians anchored to
    /// it, rigidly: rendered from the moved pose, they give the image they gave from the old
    /// one (checked with random rotations and anisotropic scales, so that a wrong rotation
    /// convention would show), while the other keyframe's Gaussians do not move at all. A
    /// wrong count or a non-finite move is refused and changes nothing.
    #[test]
    fn moving_a_keyframe_moves_its_gaussians_rigidly() {
        let mut mapper = Mapper::new(dense_config()).unwrap();
        let wall = plane_frame(|_, _| 2.0);
        let first = Isometry3::identity();
        let second = Isometry3::translation(2.5, 0.0, 0.0);
        mapper
            .add_keyframe(wall.clone(), first, [0.0, 0.0])
            .unwrap();
        mapper
            .add_keyframe(wall.clone(), second, [0.0, 0.0])
            .unwrap();
        assert_eq!(mapper.anchors().len(), mapper.map().len());
        let counts = [0u32, 1].map(|a| mapper.anchors().iter().filter(|x| **x == a).count());
        assert!(counts[0] > 100 && counts[1] > 100, "{counts:?}");
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for i in 0..mapper.map.len() {
            mapper.map.rotations[i] = [0; 4].map(|_| rng.random_range(-1.0f32..1.0));
            mapper.map.log_scales[i] = [0; 3].map(|_| rng.random_range(-4.5f32..-3.0));
            // Off the plane, so that no two share a depth and rounding in the moved depths
            // cannot swap their blending order.
            mapper.map.means[i][2] += rng.random_range(-0.1f32..0.1);
        }
        let before = mapper.clone();
        let refused = [
            mapper.move_keyframes(&[Isometry3::identity()]),
            mapper.move_keyframes(&[
                Isometry3::identity(),
                Isometry3::translation(f64::NAN, 0.0, 0.0),
            ]),
        ];
        assert!(refused.iter().all(|r| r.is_err()));
        assert_eq!(mapper.map().means, before.map().means);

        let correction = Isometry3::from_parts(
            nalgebra::Translation3::new(0.07, -0.02, 0.05),
            UnitQuaternion::from_euler_angles(0.03, -0.12, 0.05),
        );
        let moved = mapper
            .move_keyframes(&[Isometry3::identity(), correction])
            .unwrap();
        assert_eq!(moved, counts[1]);
        assert_eq!(mapper.keyframes()[0].pose, first);
        let (dt, da) = activemap_geometry::se3::pose_error(
            &mapper.keyframes()[1].pose,
            &(correction * second),
        );
        assert!(dt < 1e-12 && da < 1e-12);
        let unmoved = anchored_to(&mapper, 0);
        assert_eq!(unmoved.means, anchored_to(&before, 0).means);
        assert_eq!(unmoved.rotations, anchored_to(&before, 0).rotations);

        let options = RenderOptions::default();
        let k = wall.intrinsics;
        let old = render(
            &anchored_to(&before, 1),
            &Camera::from_world_pose(k, &second),
            &options,
        )
        .unwrap();
        let new = render(
            &anchored_to(&mapper, 1),
            &Camera::from_world_pose(k, &(correction * second)),
            &options,
        )
        .unwrap();
        let covered = old.opacity.iter().filter(|o| **o > 0.5).count();
        assert!(covered > 200, "{covered} pixels covered");
        for p in 0..old.opacity.len() {
            assert!((old.opacity[p] - new.opacity[p]).abs() < 1e-3, "pixel {p}");
            assert!((old.depth[p] - new.depth[p]).abs() < 1e-3, "pixel {p}");
            for c in 0..3 {
                assert!(
                    (old.colour[p][c] - new.colour[p][c]).abs() < 1e-3,
                    "pixel {p}: {:?} {:?} opacity {} {}",
                    old.colour[p],
                    new.colour[p],
                    old.opacity[p],
                    new.opacity[p]
                );
            }
        }
        // The same rendering without moving the Gaussians differs: the check can fail.
        let stale = render(
            &anchored_to(&before, 1),
            &Camera::from_world_pose(k, &(correction * second)),
            &options,
        )
        .unwrap();
        let differing = (0..old.depth.len())
            .filter(|&p| (old.depth[p] - stale.depth[p]).abs() > 1e-2)
            .count();
        assert!(differing > 100, "{differing}");
    }

    /// A non-finite keyframe pose or exposure is an input error naming it, and the map is left
    /// as it was (no Gaussian inserted at NaN).
    #[test]
    fn a_non_finite_keyframe_pose_is_refused() {
        let mut mapper = Mapper::new(dense_config()).unwrap();
        mapper
            .add_keyframe(plane_frame(|_, _| 2.0), Isometry3::identity(), [0.0, 0.0])
            .unwrap();
        let (n, keyframes) = (mapper.map().len(), mapper.keyframes().len());
        let nan = Isometry3::translation(0.0, f64::NAN, 0.0);
        let e = mapper
            .add_keyframe(plane_frame(|_, _| 1.0), nan, [0.0, 0.0])
            .unwrap_err()
            .to_string();
        assert!(e.contains("keyframe pose") && e.contains("NaN"), "{e}");
        let e = mapper
            .insert_from(&plane_frame(|_, _| 1.0), &nan)
            .unwrap_err()
            .to_string();
        assert!(e.contains("keyframe pose"), "{e}");
        let e = mapper
            .add_keyframe(
                plane_frame(|_, _| 1.0),
                Isometry3::identity(),
                [f64::NAN, 0.0],
            )
            .unwrap_err()
            .to_string();
        assert!(e.contains("exposure"), "{e}");
        assert_eq!(
            (mapper.map().len(), mapper.keyframes().len()),
            (n, keyframes)
        );
    }
}

#[cfg(test)]
mod box_room {
    use super::*;
    use crate::dense::tests::{box_frame, camera_at};
    use activemap_geometry::Intrinsics;
    use activemap_splat::{Camera, render};

    /// Signed distance of a point to the room's nearest face, metres: positive inside the room
    /// (in front of the surface), negative behind it.
    fn signed_distance(p: [f32; 3]) -> f64 {
        let [x, y, z] = p.map(f64::from);
        (2.0 - x.abs()).min(2.0 - y.abs()).min(z).min(3.0 - z)
    }

    /// Opacity-weighted median of `values` (value, weight).
    fn weighted_median(mut values: Vec<(f64, f64)>) -> f64 {
        values.sort_by(|a, b| a.0.total_cmp(&b.0));
        let total: f64 = values.iter().map(|v| v.1).sum();
        let mut cumulative = 0.0;
        for (v, w) in values {
            cumulative += w;
            if cumulative >= 0.5 * total {
                return v;
            }
        }
        f64::NAN
    }

    fn psnr(mapper: &Mapper, k: Intrinsics, pose: &Isometry3<f64>) -> f64 {
        let frame = box_frame(k, pose);
        let camera = Camera::from_world_pose(k, pose);
        let out = render(mapper.map(), &camera, &RenderOptions::default()).unwrap();
        let mut sum = 0.0;
        for (r, t) in out.colour.iter().zip(&frame.rgb) {
            for c in 0..3 {
                sum += f64::from(r[c].clamp(0.0, 1.0) - t[c]).powi(2);
            }
        }
        -10.0 * (sum / (3 * frame.rgb.len()) as f64).log10()
    }

    /// Twelve keyframes at the true poses, a look-around in 30° turns from two points of the
    /// room (64×64, camera 1.2 m up, level), with the default mapper (the plane depth model,
    /// discs in the surface). The goal is a median within 1 cm of the surfaces; this is
    /// where the map sinks without tracking or noise, a guard at today's level: opacity-weighted
    /// median of the signed distance −2.37 cm (behind the surfaces), of its magnitude 2.42 cm,
    /// held-out PSNR (a view turned 15° from every keyframe, from a point between them)
    /// 31.15 dB, 11 s (round insertion with the isotropic regulariser: −2.31 cm, 30.84 dB).
    /// Screened here with round insertion (same measures): the centre depth model −2.45 cm; no
    /// depth term (α = 1) −1.05 cm, so the colour term alone sinks the centres by a centimetre;
    /// 30 iterations per keyframe −3.42 cm (more optimisation, more sinking); the
    /// opacity-weighted depth term −1.84 cm; no densification −2.30 cm; `snap_behind_m` 0.15
    /// −0.25 cm and 31.46 dB, which on the house loop of `bench slam` costs 0.54 dB of held-out
    /// PSNR and 1.5 cm of depth MAE (the SLAM chapter of the book).
    #[test]
    fn a_box_room_mapped_from_known_poses_stays_within_3_cm_of_its_surfaces() {
        let k = Intrinsics::from_hfov(64, 64, std::f64::consts::FRAC_PI_2);
        let mut mapper = Mapper::new(MapperConfig::default()).unwrap();
        let poses: Vec<Isometry3<f64>> = (0..12)
            .map(|i| {
                let (x, y) = if i % 2 == 0 { (0.5, -0.3) } else { (-0.4, 0.3) };
                camera_at(x, y, (30.0 * i as f64).to_radians())
            })
            .collect();
        for pose in &poses {
            mapper
                .add_keyframe(box_frame(k, pose), *pose, [0.0, 0.0])
                .unwrap();
        }
        let map = mapper.map();
        let signed: Vec<(f64, f64)> = (0..map.len())
            .map(|i| (signed_distance(map.means[i]), map.opacity(i)))
            .collect();
        let median = weighted_median(signed.clone());
        let median_abs = weighted_median(signed.iter().map(|(d, w)| (d.abs(), *w)).collect());
        let held_out = psnr(&mapper, k, &camera_at(0.05, 0.0, 15f64.to_radians()));
        let last = psnr(&mapper, k, poses.last().unwrap());
        let summary = format!(
            "{} Gaussians, signed median {:.2} cm, |d| median {:.2} cm, held-out PSNR {held_out:.2} dB, keyframe PSNR {last:.2} dB",
            map.len(),
            median * 100.0,
            median_abs * 100.0
        );
        eprintln!("box room: {summary}");
        assert!(median.abs() <= 0.03, "{summary}");
        assert!(median_abs <= 0.03, "{summary}");
        assert!(held_out >= 29.0, "{summary}");
    }
}
