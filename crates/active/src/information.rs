//! The Fisher information of one view (SPEC §5), as the scorer uses it: a scoring render at
//! its own resolution, the per-Gaussian diagonal `H(x)` and the 6×6 pose information, both
//! normalised per pixel (see [`crate::config`] for why), the view EIG against a prior and the
//! localisation cost.
//!
//! A view renders only the Gaussians that can reach its image: those in front of the camera,
//! nearer than the far plane and inside the field of view widened by their own extent (a
//! cheap pre-cull, so a 150k-Gaussian house costs per view what the part it sees costs). The
//! cull changes no pixel: a culled Gaussian's 3σ footprint misses the image, or it lies behind
//! the far plane, which the render would cull too.

use activemap_geometry::{Intrinsics, Isometry3, Point3};
use activemap_splat::{
    Camera, DepthModel, FLAG_UNKNOWN_SPACE, FisherMode, Gaussians, Real, Render, RenderOptions,
    fisher_sparse, render,
};
use nalgebra::{Matrix6, SymmetricEigen};

use crate::ActiveError;
use crate::config::LocalisationInformation;

/// Parameters per Gaussian in a diagonal (SPEC §3: 14).
pub const PARAMS: usize = 14;

/// A per-Gaussian diagonal (or prior) over the 14 parameters, in `activemap_splat::layout`
/// order.
pub type Diagonal = [f64; PARAMS];

/// How a view is rendered and weighed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewSettings {
    /// The scoring camera (the frame's intrinsics scaled to the scoring width).
    pub intrinsics: Intrinsics,
    /// Far plane, metres.
    pub far_m: f64,
    /// Weight of depth against the colour channels.
    pub depth_weight: f64,
    /// Which pose information a view with [`ViewParts::DiagonalAndPose`] carries.
    pub localisation: LocalisationInformation,
}

impl ViewSettings {
    /// The frame camera `camera` scaled to `width` pixels (height by its aspect, at least 1).
    pub fn scaled(camera: &Intrinsics, width: u32, far_m: f64, depth_weight: f64) -> Self {
        let height =
            ((camera.height as f64 * width as f64 / camera.width as f64).round() as u32).max(1);
        Self {
            intrinsics: camera.scaled(width, height),
            far_m,
            depth_weight,
            localisation: LocalisationInformation::Paper,
        }
    }
}

/// The information one view carries about the map.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ViewInformation {
    /// `(index into the map, H diagonal)` for every Gaussian with a non-zero diagonal,
    /// ascending by index: `(1/P)·Σ_px [Σ_ch (∂c_ch/∂w)² + depth_weight·(∂D/∂w)²]`.
    pub diagonal: Vec<(u32, Diagonal)>,
    /// `(1/P)·(J_rgbᵀJ_rgb + depth_weight·J_Dᵀ J_D)` for the left pose update τ = [ρ, θ]
    /// (`None` when computed with [`ViewParts::Diagonal`]).
    pub pose: Option<Matrix6<f64>>,
    /// Pixels of the scoring render whose accumulated opacity is below
    /// [`LOW_OPACITY`] (the release's coverage term counts them); every pixel when nothing is
    /// seen.
    pub low_opacity_pixels: u32,
}

/// Rendered opacity under which a pixel counts as uncovered (the release's 0.5).
pub const LOW_OPACITY: f64 = 0.5;

/// Which parts of a view's information to compute.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ViewParts {
    /// The per-Gaussian diagonal only: what the EIG needs (the candidates, the model Fisher).
    /// Skips the per-pixel pose Jacobians, most of the Fisher walk's work.
    Diagonal,
    /// The diagonal and the 6×6 pose information: what C_local needs (the path poses).
    DiagonalAndPose,
}

impl ViewInformation {
    /// Whether the view sees no Gaussian at all.
    pub fn is_empty(&self) -> bool {
        self.diagonal.is_empty()
    }
}

/// The scoring map with what every view's cull needs, computed once per replan: each
/// Gaussian's 3σ extent, and buckets of Gaussians on a horizontal grid so a view visits only
/// the buckets its frustum can reach (a 150k-Gaussian house costs a view what the part it
/// sees costs, not a pass over the whole map).
#[derive(Debug, Clone)]
pub struct ScoringScene<T: Real = f32> {
    /// The Gaussians.
    pub map: Gaussians<T>,
    /// Per Gaussian: three times its largest scale, metres.
    extent: Vec<f64>,
    /// Bucket side, metres.
    bucket_m: f64,
    /// Per bucket: its xy cell, z range of its means, largest extent, and members
    /// (ascending).
    buckets: Vec<Bucket>,
}

#[derive(Debug, Clone)]
struct Bucket {
    cell: [i64; 2],
    z: [f64; 2],
    extent: f64,
    members: Vec<u32>,
}

/// Side of the cull buckets, metres.
const BUCKET_M: f64 = 0.5;

impl<T: Real> ScoringScene<T> {
    /// Indexes `map`.
    pub fn new(map: Gaussians<T>) -> Self {
        let extent: Vec<f64> = map
            .log_scales
            .iter()
            .map(|s| {
                3.0 * s
                    .iter()
                    .map(|v| v.to_f64())
                    .fold(f64::NEG_INFINITY, f64::max)
                    .exp()
            })
            .collect();
        let mut by_cell: std::collections::BTreeMap<[i64; 2], Bucket> = Default::default();
        for (i, m) in map.means.iter().enumerate() {
            let (x, y, z) = (m[0].to_f64(), m[1].to_f64(), m[2].to_f64());
            // Non-finite means go to one bucket that every view visits (the precise test
            // then rejects them), so nothing is silently dropped or misplaced.
            let cell = if x.is_finite() && y.is_finite() {
                [(x / BUCKET_M).floor() as i64, (y / BUCKET_M).floor() as i64]
            } else {
                [i64::MIN, i64::MIN]
            };
            let b = by_cell.entry(cell).or_insert(Bucket {
                cell,
                z: [f64::INFINITY, f64::NEG_INFINITY],
                extent: 0.0,
                members: Vec::new(),
            });
            b.z = [b.z[0].min(z), b.z[1].max(z)];
            b.extent = b.extent.max(extent[i]);
            b.members.push(i as u32);
        }
        Self {
            map,
            extent,
            bucket_m: BUCKET_M,
            buckets: by_cell.into_values().collect(),
        }
    }

    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.map.len()
    }

    /// Whether the scene holds no Gaussian.
    pub fn is_empty(&self) -> bool {
        self.map.is_empty()
    }

    /// Indices (ascending) of the Gaussians that may touch the image of the camera at
    /// `world_from_camera`: in front of it (beyond the near plane, nearer than `far_m`) and
    /// inside the field of view widened by their 3σ extent and the renderer's low-pass.
    pub fn visible(
        &self,
        intrinsics: &Intrinsics,
        world_from_camera: &Isometry3<f64>,
        far_m: f64,
    ) -> Vec<u32> {
        let frustum = Frustum::new(intrinsics, world_from_camera, far_m);
        let mut out = Vec::new();
        for b in &self.buckets {
            if b.cell[0] != i64::MIN {
                let lo = [
                    b.cell[0] as f64 * self.bucket_m - b.extent,
                    b.cell[1] as f64 * self.bucket_m - b.extent,
                    b.z[0] - b.extent,
                ];
                let hi = [
                    (b.cell[0] + 1) as f64 * self.bucket_m + b.extent,
                    (b.cell[1] + 1) as f64 * self.bucket_m + b.extent,
                    b.z[1] + b.extent,
                ];
                if !frustum.box_may_intersect(lo, hi) {
                    continue;
                }
            }
            for &i in &b.members {
                let m = self.map.means[i as usize];
                let p = Point3::new(m[0].to_f64(), m[1].to_f64(), m[2].to_f64());
                if frustum.point_may_touch(&p, self.extent[i as usize]) {
                    out.push(i);
                }
            }
        }
        out.sort_unstable();
        out
    }
}

/// The scoring camera's frustum in its own frame, widened for the renderer's footprints.
struct Frustum {
    camera_from_world: Isometry3<f64>,
    /// Half-extents of the image plane at unit depth: left, right, top, bottom.
    slopes: [f64; 4],
    near: f64,
    far: f64,
}

impl Frustum {
    fn new(k: &Intrinsics, world_from_camera: &Isometry3<f64>, far: f64) -> Self {
        // Two and a half pixels of margin: the image edge is half a pixel beyond the outer
        // pixel centres, and the renderer's 0.3 px² low-pass widens every footprint by up to
        // 3·√0.3 ≈ 1.7 px.
        let margin = 2.5;
        Self {
            camera_from_world: world_from_camera.inverse(),
            slopes: [
                (k.cx + margin) / k.fx,
                (k.width as f64 - 1.0 + margin - k.cx) / k.fx,
                (k.cy + margin) / k.fy,
                (k.height as f64 - 1.0 + margin - k.cy) / k.fy,
            ],
            near: activemap_splat::DEFAULT_NEAR,
            far,
        }
    }

    /// Whether a sphere of radius `extent` at world point `p` may reach the image.
    fn point_may_touch(&self, p: &Point3<f64>, extent: f64) -> bool {
        let p = self.camera_from_world * p;
        if !(p.z + extent > self.near && p.z - extent <= self.far) {
            return false;
        }
        let [left, right, top, bottom] = self.slopes;
        let z = p.z;
        // Inside the widened pyramid: x ∈ [−left·z − e·√(1+left²), right·z + e·√(1+right²)].
        let within = |v: f64, lo: f64, hi: f64| {
            v >= -lo * z - extent * (1.0 + lo * lo).sqrt()
                && v <= hi * z + extent * (1.0 + hi * hi).sqrt()
        };
        within(p.x, left, right) && within(p.y, top, bottom)
    }

    /// Whether the world box `[lo, hi]` may intersect the frustum: false only when all eight
    /// corners lie outside one of its planes (conservative).
    fn box_may_intersect(&self, lo: [f64; 3], hi: [f64; 3]) -> bool {
        let corners: Vec<Point3<f64>> = (0..8)
            .map(|c| {
                let pick = |axis: usize| {
                    if c >> axis & 1 == 0 {
                        lo[axis]
                    } else {
                        hi[axis]
                    }
                };
                self.camera_from_world * Point3::new(pick(0), pick(1), pick(2))
            })
            .collect();
        // Per plane: the signed excess of a point beyond it (positive = outside).
        let planes: [fn(&Point3<f64>, &Self) -> f64; 6] = [
            |p, f| f.near - p.z,
            |p, f| p.z - f.far,
            |p, f| -f.slopes[0] * p.z - p.x,
            |p, f| p.x - f.slopes[1] * p.z,
            |p, f| -f.slopes[2] * p.z - p.y,
            |p, f| p.y - f.slopes[3] * p.z,
        ];
        !planes
            .iter()
            .any(|excess| corners.iter().all(|p| excess(p, self) >= 0.0))
    }
}

/// The Gaussians of `map` at `indices`, in that order.
pub fn subset<T: Real>(map: &Gaussians<T>, indices: &[u32]) -> Gaussians<T> {
    // Gathered array by array into exact-size vectors: a view culls in ~80k Gaussians, and
    // growing six vectors by push cost reallocations, copies and fresh pages every view.
    fn gather<V: Copy>(from: &[V], indices: &[u32]) -> Vec<V> {
        indices.iter().map(|&i| from[i as usize]).collect()
    }
    Gaussians {
        means: gather(&map.means, indices),
        sh_dc: gather(&map.sh_dc, indices),
        rotations: gather(&map.rotations, indices),
        opacity_logits: gather(&map.opacity_logits, indices),
        log_scales: gather(&map.log_scales, indices),
        flags: gather(&map.flags, indices),
    }
}

/// The Fisher information of the view from `world_from_camera` (`T_world_camera`) on `map`
/// (SPEC §5): colour per channel plus `depth_weight` × depth, normalised per pixel. Every
/// Gaussian counts, the unknown-space ones included (nothing is excluded by flag).
pub fn view_information<T: Real>(
    scene: &ScoringScene<T>,
    world_from_camera: &Isometry3<f64>,
    settings: &ViewSettings,
    parts: ViewParts,
) -> Result<ViewInformation, ActiveError> {
    let map = &scene.map;
    let with_pose = parts == ViewParts::DiagonalAndPose;
    let indices = scene.visible(&settings.intrinsics, world_from_camera, settings.far_m);
    if indices.is_empty() {
        // Nothing seen: no diagonal, and (when asked for) a zero pose information.
        return Ok(ViewInformation {
            diagonal: Vec::new(),
            pose: with_pose.then(Matrix6::zeros),
            low_opacity_pixels: settings.intrinsics.pixel_count() as u32,
        });
    }
    let part = subset(map, &indices);
    let camera =
        Camera::from_world_pose(settings.intrinsics, world_from_camera).with_far(settings.far_m);
    // The Fisher pass differentiates the centre depth model (SPEC §3): the map's plane model
    // adds the slope's dependence on the shape, which the information leaves out.
    let image = render(
        &part,
        &camera,
        &RenderOptions {
            depth: DepthModel::Centre,
            ..RenderOptions::default()
        },
    )?;
    // Only the Gaussians the pixels composite carry information; the sparse pass prepares
    // and returns those alone (behind a wall or in the depth of an unknown-space cloud most
    // of the culled set is hidden).
    let info = fisher_sparse(&part, &image, FisherMode::PerChannel, with_pose)?;
    let scale = 1.0 / settings.intrinsics.pixel_count() as f64;
    let mut diagonal = Vec::with_capacity(info.ids.len());
    for (k, &j) in info.ids.iter().enumerate() {
        let d = info.combined(k, settings.depth_weight);
        if d.iter().any(|v| *v != 0.0) {
            diagonal.push((indices[j as usize], d.map(|v| v * scale)));
        }
    }
    let low_opacity_pixels = image
        .opacity
        .iter()
        .filter(|o| o.to_f64() < LOW_OPACITY)
        .count() as u32;
    let pose = match (with_pose, settings.localisation) {
        (false, _) => None,
        (true, LocalisationInformation::Paper) => {
            info.pose(settings.depth_weight).map(|p| p * scale)
        }
        (true, LocalisationInformation::Depth) => {
            // The map's own surfaces only: unknown-space Gaussians are no geometry to align to.
            let surfaces = render(
                &part,
                &camera,
                &RenderOptions {
                    exclude_flags: FLAG_UNKNOWN_SPACE,
                    ..RenderOptions::default()
                },
            )?;
            Some(depth_pose_information(
                &surface_depth(&surfaces),
                &settings.intrinsics,
                &DepthNoiseModel::default(),
            ))
        }
    };
    Ok(ViewInformation {
        diagonal,
        pose,
        low_opacity_pixels,
    })
}

/// Something that gives the prior information `I_k + λ` (positive) of a Gaussian's parameters
/// by its index in the scoring map.
pub trait Prior {
    /// The prior diagonal of Gaussian `index`.
    fn prior(&self, index: u32) -> Diagonal;
}

/// A dense prior: one diagonal per Gaussian of the scoring map.
impl Prior for [Diagonal] {
    fn prior(&self, index: u32) -> Diagonal {
        self[index as usize]
    }
}

/// The view EIG `tr(H(x)·I⁻¹) = Σ_k H_k(x)/I_k` (SPEC §5) of `view` against `prior`.
pub fn eig<P: Prior + ?Sized>(view: &ViewInformation, prior: &P) -> f64 {
    view.diagonal
        .iter()
        .map(|(i, h)| {
            let p = prior.prior(*i);
            h.iter().zip(p.iter()).map(|(h, p)| h / p).sum::<f64>()
        })
        .sum()
}

/// The localisation cost `C_local = −log det(J_τᵀJ_τ)` (SPEC §5) of a 6×6 pose information:
/// +∞ for a view that sees nothing, a matrix with a non-finite entry, or one that is not
/// positive definite (its smallest eigenvalue at most `degenerate_ratio` × its largest, so a
/// direction the view leaves unconstrained never looks merely expensive). Never NaN.
pub fn localisation_cost(pose: &Matrix6<f64>, degenerate_ratio: f64) -> f64 {
    if pose.iter().any(|v| !v.is_finite()) {
        return f64::INFINITY;
    }
    let symmetric = (pose + pose.transpose()) * 0.5;
    let eigen = SymmetricEigen::new(symmetric);
    let values = eigen.eigenvalues;
    let max = values.max();
    let min = values.min();
    // Positive definite and well conditioned (NaN eigenvalues fail every comparison).
    let usable = max > 0.0 && min > degenerate_ratio * max && min.is_finite();
    if !usable {
        return f64::INFINITY;
    }
    let cost = -values.iter().map(|v| v.ln()).sum::<f64>();
    if cost.is_nan() { f64::INFINITY } else { cost }
}

/// The depth noise model the [`depth_pose_information`] weights by: σ(z) = σ0 + c2·z² metres
/// (`activemap_sim::noise`'s realistic preset, a RealSense D435: σ0 = 1 mm, c2 = 0.0036 m⁻¹).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthNoiseModel {
    /// σ0, metres.
    pub sigma_0: f64,
    /// c2, per metre.
    pub sigma_z2: f64,
}

impl Default for DepthNoiseModel {
    fn default() -> Self {
        Self {
            sigma_0: 0.001,
            sigma_z2: 0.0036,
        }
    }
}

/// The depth of the surfaces a render shows: the composited depth over the rendered opacity
/// where the opacity reaches [`LOW_OPACITY`], 0 (no reading) elsewhere; the input of
/// [`depth_pose_information`].
pub fn surface_depth<T: Real>(render: &Render<T>) -> Vec<f32> {
    render
        .depth
        .iter()
        .zip(&render.opacity)
        .map(|(d, o)| {
            let o = o.to_f64();
            if o >= LOW_OPACITY {
                (d.to_f64() / o) as f32
            } else {
                0.0
            }
        })
        .collect()
}

/// The point-to-plane information `(1/P)·Σ_px J Jᵀ / σ(z)²` of a depth image for the camera
/// pose: what a dense depth alignment (the tracker's ICP term) can tell about the six pose
/// directions at this view. Each pixel with a finite positive depth whose four neighbours have
/// one too gives a camera-frame point `p` and a normal `n` (the cross product of the central
/// differences, turned toward the camera); its residual `n·(δT·p − q)` has the Jacobian
/// `J = [n, p × n]` for a small camera motion `δT = Exp([ρ, θ])` (translation first, as the
/// tracker's τ), weighted by the inverse depth noise variance at that range. A flat wall
/// leaves the two in-plane translations and the rotation about its normal unconstrained
/// (those eigenvalues are 0), a corner constrains all six.
pub fn depth_pose_information(
    depth: &[f32],
    intrinsics: &Intrinsics,
    noise: &DepthNoiseModel,
) -> Matrix6<f64> {
    let (w, h) = (intrinsics.width as usize, intrinsics.height as usize);
    let mut info = Matrix6::zeros();
    if depth.len() != w * h || w < 3 || h < 3 {
        return info;
    }
    let point = |x: usize, y: usize| -> Option<Point3<f64>> {
        let d = depth[y * w + x];
        (d.is_finite() && d > 0.0).then(|| intrinsics.unproject(x as f64, y as f64, d as f64))
    };
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let (Some(p), Some(l), Some(r), Some(u), Some(d)) = (
                point(x, y),
                point(x - 1, y),
                point(x + 1, y),
                point(x, y - 1),
                point(x, y + 1),
            ) else {
                continue;
            };
            let mut n = (r - l).cross(&(d - u));
            let norm = n.norm();
            if norm.is_nan() || norm <= 0.0 {
                continue;
            }
            n /= norm;
            if n.dot(&p.coords) > 0.0 {
                n = -n;
            }
            let sigma = noise.sigma_0 + noise.sigma_z2 * p.z * p.z;
            let weight = 1.0 / (sigma * sigma);
            let rotation = p.coords.cross(&n);
            let j = nalgebra::Vector6::new(n.x, n.y, n.z, rotation.x, rotation.y, rotation.z);
            info += j * j.transpose() * weight;
        }
    }
    info / (w * h) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The depth pose information against the analytic truth: a wall facing the camera
    /// constrains only the translation along its normal and the two tilts (the in-plane
    /// translations and the roll about the normal have no information), a corner of three
    /// walls constrains all six directions, and the same wall farther away (noisier depth,
    /// smaller lever arms per pixel) carries less.
    #[test]
    fn depth_pose_information_sees_what_a_wall_and_a_corner_constrain() {
        let k = Intrinsics::from_hfov(32, 32, std::f64::consts::FRAC_PI_2);
        let noise = DepthNoiseModel::default();
        let eigen = |m: &Matrix6<f64>| {
            let mut v: Vec<f64> = SymmetricEigen::new(*m)
                .eigenvalues
                .iter()
                .copied()
                .collect();
            v.sort_by(f64::total_cmp);
            v
        };
        let wall = depth_pose_information(&[2.0; 32 * 32], &k, &noise);
        for (i, j) in [(0, 0), (1, 1), (5, 5), (0, 1), (0, 5), (1, 5)] {
            assert!(
                wall[(i, j)].abs() < 1e-9 * wall[(2, 2)],
                "({i},{j}): {wall}"
            );
        }
        let values = eigen(&wall);
        assert!(
            values[2] < 1e-9 * values[5] && values[3] > 1e-3 * values[5],
            "{values:?}"
        );
        // A corner: the walls x = 1 and y = 1 and the back wall z = 3 (camera frame).
        let mut depth = vec![0f32; 32 * 32];
        for y in 0..32 {
            for x in 0..32 {
                let ray = k.unproject(x as f64, y as f64, 1.0);
                let mut t = 3.0f64;
                if ray.x > 0.0 {
                    t = t.min(1.0 / ray.x);
                }
                if ray.y > 0.0 {
                    t = t.min(1.0 / ray.y);
                }
                depth[y * 32 + x] = t as f32;
            }
        }
        let corner = eigen(&depth_pose_information(&depth, &k, &noise));
        assert!(corner[0] > 1e-3 * corner[5], "{corner:?}");
        let far = depth_pose_information(&[4.0; 32 * 32], &k, &noise);
        assert!(
            far[(2, 2)] < wall[(2, 2)] / 4.0,
            "{} against {}",
            far[(2, 2)],
            wall[(2, 2)]
        );
        // No depth, no information; a size mismatch is no information either.
        assert_eq!(
            depth_pose_information(&[0.0; 32 * 32], &k, &noise),
            Matrix6::zeros()
        );
        assert_eq!(
            depth_pose_information(&[2.0; 10], &k, &noise),
            Matrix6::zeros()
        );
    }
    use nalgebra::{UnitQuaternion, Vector3};

    /// `localisation: depth`: a view of a textured wall carries the paper's pose information
    /// in every direction (the colours constrain the slides along the wall), while the depth
    /// alignment's has (nearly) nothing along the wall's plane; it is taken of the map's own
    /// surfaces, so an unknown-space cloud in front of the wall changes it not at all.
    #[test]
    fn the_depth_localisation_information_sees_a_wall_as_a_wall() {
        let mut map = Gaussians::<f64>::new();
        for j in 0..60 {
            for h in 0..40 {
                let shade = if (j / 4 + h / 4) % 2 == 0 { 0.9 } else { 0.1 };
                map.push(
                    [2.0, -1.5 + 0.05 * j as f64, 0.05 + 0.05 * h as f64],
                    [shade, shade, shade],
                    [1.0, 0.0, 0.0, 0.0],
                    0.98,
                    [0.01, 0.04, 0.04],
                );
            }
        }
        let k = Intrinsics::from_hfov(32, 24, 70f64.to_radians());
        let robot = activemap_geometry::RobotModel::default();
        let pose = robot.camera_pose(&activemap_geometry::PlanarPose::new(0.0, 0.0, 0.0), 0.0);
        let settings = |localisation| ViewSettings {
            intrinsics: k,
            far_m: 6.0,
            depth_weight: 0.5,
            localisation,
        };
        let sorted = |m: Matrix6<f64>| {
            let mut v: Vec<f64> = SymmetricEigen::new(m).eigenvalues.iter().copied().collect();
            v.sort_by(f64::total_cmp);
            v
        };
        let info = |map: &Gaussians<f64>, localisation| {
            view_information(
                &ScoringScene::new(map.clone()),
                &pose,
                &settings(localisation),
                ViewParts::DiagonalAndPose,
            )
            .unwrap()
        };
        let paper = sorted(info(&map, LocalisationInformation::Paper).pose.unwrap());
        let depth_view = info(&map, LocalisationInformation::Depth);
        let depth = sorted(depth_view.pose.unwrap());
        assert!(paper[0] > 1e-6 * paper[5], "paper: {paper:?}");
        assert!(depth[2] < 1e-3 * depth[5], "depth: {depth:?}");
        assert!(depth[3] > 1e-3 * depth[5], "depth: {depth:?}");
        let cost = localisation_cost(&depth_view.pose.unwrap(), 1e-9);
        assert!(
            cost > localisation_cost(
                &info(&map, LocalisationInformation::Paper).pose.unwrap(),
                1e-9
            )
        );
        // An unknown-space cloud between the camera and the wall.
        let mut with_cloud = map.clone();
        for j in 0..20 {
            with_cloud.push(
                [1.0, -0.5 + 0.05 * j as f64, 0.9],
                [0.5; 3],
                [1.0, 0.0, 0.0, 0.0],
                0.6,
                [0.05; 3],
            );
            let last = with_cloud.len() - 1;
            with_cloud.flags[last] = activemap_splat::FLAG_UNKNOWN_SPACE;
        }
        assert_eq!(
            info(&with_cloud, LocalisationInformation::Depth).pose,
            depth_view.pose
        );
    }

    /// The pre-cull keeps what the render sees: over a house-sized spread of Gaussians and
    /// several poses, every Gaussian the full render shows passes the cull, and the Fisher
    /// diagonal with the cull equals the one of the whole map, index for index.
    #[test]
    fn the_cull_changes_nothing() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let mut map = Gaussians::<f64>::new();
        for _ in 0..1500 {
            map.push(
                [
                    rng.random_range(-5.0..5.0),
                    rng.random_range(-5.0..5.0),
                    rng.random_range(-0.5..3.0),
                ],
                [rng.random(), rng.random(), rng.random()],
                [1.0, 0.1, 0.0, 0.0],
                rng.random_range(0.2..0.9),
                [
                    rng.random_range(0.01..0.3),
                    rng.random_range(0.01..0.2),
                    rng.random_range(0.01..0.2),
                ],
            );
        }
        // An opaque wall 1 m ahead of the first pose hides most of what lies behind it, so
        // in that view most of the culled set is hidden and left out by the sparse pass.
        for j in 0..40 {
            for h in 0..20 {
                map.push(
                    [1.0, -1.0 + 0.05 * j as f64, 0.05 + 0.1 * h as f64],
                    [0.5, 0.5, 0.5],
                    [1.0, 0.0, 0.0, 0.0],
                    0.98,
                    [0.01, 0.12, 0.12],
                );
            }
        }
        let scene = ScoringScene::new(map.clone());
        let k = Intrinsics::from_hfov(24, 20, 80f64.to_radians());
        let mut hidden_views = 0;
        let settings = ViewSettings {
            intrinsics: k,
            far_m: 4.0,
            depth_weight: 0.5,
            localisation: Default::default(),
        };
        let p = k.pixel_count() as f64;
        for (x, y, yaw) in [(0.1, -0.2, 0.0), (2.0, 1.0, 2.0), (-3.0, 4.0, -1.0)] {
            let robot = activemap_geometry::RobotModel::default();
            let pose = robot.camera_pose(&activemap_geometry::PlanarPose::new(x, y, yaw), 0.0);
            let culled =
                view_information(&scene, &pose, &settings, ViewParts::DiagonalAndPose).unwrap();
            let diagonal_only =
                view_information(&scene, &pose, &settings, ViewParts::Diagonal).unwrap();
            assert_eq!(diagonal_only.diagonal, culled.diagonal);
            assert_eq!(diagonal_only.pose, None);
            let camera = Camera::from_world_pose(k, &pose).with_far(4.0);
            let image = render(
                &map,
                &camera,
                &RenderOptions {
                    depth: DepthModel::Centre,
                    ..RenderOptions::default()
                },
            )
            .unwrap();
            let passed = scene.visible(&k, &pose, 4.0);
            for (i, v) in image.context.visible.iter().enumerate() {
                if *v {
                    assert!(
                        passed.binary_search(&(i as u32)).is_ok(),
                        "Gaussian {i} culled"
                    );
                }
            }
            assert!(
                passed.len() < 1500 / 3 + 800,
                "the cull keeps {}",
                passed.len()
            );
            let shown = image.context.walked_mask();
            let visible = image.context.visible.iter().filter(|v| **v).count();
            hidden_views += usize::from(shown.iter().filter(|c| **c).count() * 10 < visible * 9);
            let full = activemap_splat::fisher(&map, &image, FisherMode::PerChannel).unwrap();
            let mut expected = Vec::new();
            for i in 0..map.len() {
                let d = full.combined(i, 0.5);
                if d.iter().any(|v| *v != 0.0) {
                    expected.push((i as u32, d.map(|v| v / p)));
                }
            }
            assert!(expected.len() > 5);
            assert_eq!(culled.diagonal.len(), expected.len());
            for ((i, a), (j, b)) in culled.diagonal.iter().zip(&expected) {
                assert_eq!(i, j);
                for (x, y) in a.iter().zip(b) {
                    assert!((x - y).abs() <= 1e-9 * y.abs().max(1e-300), "{x} vs {y}");
                }
            }
            let pose_full = full.pose(0.5) / p;
            let culled_pose = culled.pose.unwrap();
            assert!((culled_pose - pose_full).norm() <= 1e-9 * pose_full.norm());
        }
        assert!(hidden_views >= 1, "no view hid most of what it culled in");
    }

    /// C_local is +∞ (never NaN) for an empty, a non-finite and a rank-deficient matrix, and
    /// −Σ log λ for a positive definite one.
    #[test]
    fn localisation_cost_guards() {
        assert_eq!(localisation_cost(&Matrix6::zeros(), 1e-9), f64::INFINITY);
        let mut nan = Matrix6::identity();
        nan[(2, 3)] = f64::NAN;
        assert_eq!(localisation_cost(&nan, 1e-9), f64::INFINITY);
        let mut rank5 = Matrix6::identity() * 3.0;
        rank5[(5, 5)] = 0.0;
        assert_eq!(localisation_cost(&rank5, 1e-9), f64::INFINITY);
        let mut negative = Matrix6::identity();
        negative[(0, 0)] = -1.0;
        assert_eq!(localisation_cost(&negative, 1e-9), f64::INFINITY);
        let d = Matrix6::from_diagonal(&nalgebra::Vector6::new(1.0, 2.0, 3.0, 4.0, 5.0, 6.0));
        let r = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 0.3).to_rotation_matrix();
        let mut q = Matrix6::zeros();
        q.fixed_view_mut::<3, 3>(0, 0).copy_from(r.matrix());
        q.fixed_view_mut::<3, 3>(3, 3).copy_from(r.matrix());
        let m = q * d * q.transpose();
        let expected = -(720f64).ln();
        assert!((localisation_cost(&m, 1e-9) - expected).abs() < 1e-12);
    }
}
