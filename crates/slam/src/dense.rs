//! Dense RGB-D alignment of a frame against a reference keyframe (the default tracker of
//! [`crate::tracker::TrackerMethod::Dense`]): Gauss–Newton on the relative pose
//! `T_ref_cur` (a left update `T ← Exp(δ)·T`, δ = [ρ, θ] as SPEC §2), minimising
//!
//! `E(T) = Σ_p w_d·h(N·(T·X_p − V(π(T·X_p)))) + w_c·h(I_ref(π(T·X_p)) − I_cur(p)) + ½ eᵀΛe`
//!
//! - the first term is point-to-plane ICP with projective association (KinectFusion): `X_p` is
//!   the current frame's back-projected depth, `V` and `N` the reference's vertex and normal at
//!   the nearest pixel of the projection, `N·Δ` the distance to the reference's tangent plane;
//! - the second is the photometric error of direct RGB-D odometry (Kerl et al. 2013) on the
//!   grey level `I = (R + G + B)/3`, bilinearly sampled with its gradient in the reference;
//! - `h` is the Huber norm (robust to occlusion edges and moving content), with
//!   `w_d = 1/σ_d²`, `w_c = 1/σ_c²`; pairs farther apart than the gate, or with normals that
//!   disagree, are outliers and left out of both terms;
//! - the last term is the motion prior of SPEC §4 (the commanded action, never ground truth):
//!   `e = log(T·T_pred⁻¹)`, `Λ = diag(1/σ_t², 1/σ_r²)`.
//!
//! Jacobians are analytic: for `Y = T·X`, `∂Y/∂δ = [I | −[Y]×]`, so a residual `a·Y + c`
//! has the row `[a, Y × a]`: `a = N` for ICP and `a = ∇I_ref·∂π/∂Y` for colour. Levels run
//! coarse to fine on validity-aware downscaled images ([`Frame::downscale`]).
//!
//! Why not render the map at every iteration (SPEC §4's Adam, or [`crate::gauss_newton`])?
//! Measured on the procedural house at 160 px: a map that CPU mapping budgets can afford
//! renders depth 1–5 % short on slanted surfaces (front-to-back blending of overlapping
//! Gaussians), and tracking the very keyframe the map was built from then settles 1.5–2.5 cm
//! away from its true pose; each iteration also costs several renders. The keyframe images
//! are the map's raw observations: aligning to them costs O(pixels) per iteration with no
//! render, and the map still decides whether the frame is explained (the `Lost` signal of
//! [`crate::tracker`]).

use crate::error::SlamError;
use crate::frame::Frame;
use crate::gauss_newton::prior_information;
use activemap_geometry::{Intrinsics, Isometry3, se3};
use nalgebra::{Matrix6, Vector3, Vector6};
use rayon::prelude::*;

/// Rows per parallel work item; partial sums are added in row order, so the result does not
/// depend on the thread count.
const ROWS_PER_CHUNK: usize = 8;

/// Settings of the dense aligner.
#[derive(Debug, Clone, PartialEq)]
pub struct DenseConfig {
    /// Downscale factors (relative to the tracking frame), run coarse to fine.
    pub pyramid: Vec<usize>,
    /// Gauss–Newton iterations per level (cap).
    pub iterations_per_level: usize,
    /// Scale of the point-to-plane residual, metres (`w_d = 1/σ_d²`).
    pub depth_sigma: f64,
    /// Scale of the grey-level residual (`w_c = 1/σ_c²`); 0 = geometry only.
    pub colour_sigma: f64,
    /// Huber threshold, in units of σ.
    pub huber: f64,
    /// Association gate at the finest level: pairs farther apart are outliers, metres (it
    /// grows with the level's downscale factor).
    pub max_distance: f64,
    /// Smallest cosine between the reference normal and the rotated current normal.
    pub min_normal_cosine: f64,
    /// Stop a level once |δ| falls below this.
    pub convergence: f64,
    /// Motion prior: translation standard deviation, metres (0 = no prior).
    pub prior_translation_sigma: f64,
    /// Motion prior: rotation standard deviation, radians (0 = no prior).
    pub prior_rotation_sigma: f64,
    /// The tracker reports `Lost` when the inliers' RMS point-to-plane distance exceeds
    /// this, metres (a misalignment, or a reference that no longer matches the scene).
    pub lost_max_rms: f64,
}

impl Default for DenseConfig {
    fn default() -> Self {
        Self {
            pyramid: vec![4, 2, 1],
            iterations_per_level: 10,
            depth_sigma: 0.005,
            colour_sigma: 0.05,
            huber: 2.0,
            max_distance: 0.05,
            min_normal_cosine: 0.7,
            convergence: 1e-6,
            prior_translation_sigma: 0.05,
            prior_rotation_sigma: 3f64.to_radians(),
            lost_max_rms: 0.02,
        }
    }
}

impl DenseConfig {
    /// Checks ranges; names the offending field.
    pub fn validate(&self) -> Result<(), SlamError> {
        if self.pyramid.is_empty() || self.pyramid.contains(&0) {
            return Err(SlamError::Config {
                field: "dense.pyramid",
                value: format!("{:?}", self.pyramid),
                reason: "must be non-empty factors ≥ 1",
            });
        }
        SlamError::require_positive(&[
            ("dense.depth_sigma", self.depth_sigma),
            ("dense.huber", self.huber),
            ("dense.max_distance", self.max_distance),
            ("dense.convergence", self.convergence),
            ("dense.lost_max_rms", self.lost_max_rms),
        ])?;
        for (field, v) in [
            ("dense.colour_sigma", self.colour_sigma),
            (
                "dense.prior_translation_sigma",
                self.prior_translation_sigma,
            ),
            ("dense.prior_rotation_sigma", self.prior_rotation_sigma),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SlamError::Config {
                    field,
                    value: v.to_string(),
                    reason: "must be finite and ≥ 0",
                });
            }
        }
        if !(-1.0..=1.0).contains(&self.min_normal_cosine) {
            return Err(SlamError::Config {
                field: "dense.min_normal_cosine",
                value: self.min_normal_cosine.to_string(),
                reason: "must be in [-1, 1]",
            });
        }
        Ok(())
    }
}

/// One pyramid level of an image prepared for alignment: camera-frame vertices and normals
/// (zero where invalid), the grey level and, for references, its gradient.
#[derive(Debug, Clone)]
struct Level {
    intrinsics: Intrinsics,
    width: usize,
    height: usize,
    points: Vec<Vector3<f32>>,
    normals: Vec<Vector3<f32>>,
    grey: Vec<f32>,
    gradient: Vec<[f32; 2]>,
}

impl Level {
    fn new(frame: &Frame, with_gradient: bool) -> Self {
        let k = frame.intrinsics;
        let (width, height) = (frame.width(), frame.height());
        let points: Vec<Vector3<f32>> = (0..width * height)
            .map(|i| {
                let d = frame.depth[i];
                if d > 0.0 {
                    let p = k.unproject((i % width) as f64, (i / width) as f64, d as f64);
                    Vector3::new(p.x as f32, p.y as f32, p.z as f32)
                } else {
                    Vector3::zeros()
                }
            })
            .collect();
        let normals = normals(&points, width, height);
        let grey: Vec<f32> = frame
            .rgb
            .iter()
            .map(|c| (c[0] + c[1] + c[2]) / 3.0)
            .collect();
        let gradient = if with_gradient {
            (0..width * height)
                .map(|i| {
                    let (x, y) = (i % width, i / width);
                    let at = |x: usize, y: usize| grey[y * width + x];
                    let gx = if x > 0 && x + 1 < width {
                        0.5 * (at(x + 1, y) - at(x - 1, y))
                    } else {
                        0.0
                    };
                    let gy = if y > 0 && y + 1 < height {
                        0.5 * (at(x, y + 1) - at(x, y - 1))
                    } else {
                        0.0
                    };
                    [gx, gy]
                })
                .collect()
        } else {
            Vec::new()
        };
        Self {
            intrinsics: k,
            width,
            height,
            points,
            normals,
            grey,
            gradient,
        }
    }

    /// Bilinear grey level and gradient at (u, v); `None` outside the interpolable area.
    fn sample(&self, u: f64, v: f64) -> Option<(f64, [f64; 2])> {
        if !(u >= 0.0 && v >= 0.0) {
            return None;
        }
        let (x0, y0) = (u.floor() as usize, v.floor() as usize);
        if x0 + 1 >= self.width || y0 + 1 >= self.height {
            return None;
        }
        let (fx, fy) = (u - x0 as f64, v - y0 as f64);
        let i = y0 * self.width + x0;
        let corners = [i, i + 1, i + self.width, i + self.width + 1];
        let weights = [
            (1.0 - fx) * (1.0 - fy),
            fx * (1.0 - fy),
            (1.0 - fx) * fy,
            fx * fy,
        ];
        let (mut value, mut grad) = (0.0, [0.0; 2]);
        for (&c, w) in corners.iter().zip(weights) {
            value += w * self.grey[c] as f64;
            grad[0] += w * self.gradient[c][0] as f64;
            grad[1] += w * self.gradient[c][1] as f64;
        }
        Some((value, grad))
    }
}

/// Unit normals from central differences of the vertex map, facing the camera; zero where a
/// neighbour is missing or the neighbourhood spans a depth discontinuity (> 5 % of depth).
fn normals(points: &[Vector3<f32>], width: usize, height: usize) -> Vec<Vector3<f32>> {
    let mut out = vec![Vector3::zeros(); width * height];
    for y in 1..height.saturating_sub(1) {
        for x in 1..width.saturating_sub(1) {
            let i = y * width + x;
            let c = points[i];
            let [l, r, u, d] = [i - 1, i + 1, i - width, i + width].map(|j| points[j]);
            if [c, l, r, u, d].iter().any(|p| p.z <= 0.0) {
                continue;
            }
            let limit = 0.05 * c.z;
            if [l, r, u, d].iter().any(|p| (p.z - c.z).abs() > limit) {
                continue;
            }
            let n = (r - l).cross(&(d - u));
            let norm = n.norm();
            if norm > 0.0 {
                let n = n / norm;
                out[i] = if n.dot(&c) > 0.0 { -n } else { n };
            }
        }
    }
    out
}

/// A keyframe prepared as an alignment reference: its pyramid and its estimated pose.
#[derive(Debug, Clone)]
pub struct DenseReference {
    /// `T_world_camera` of the reference keyframe (its SLAM estimate).
    pub pose: Isometry3<f64>,
    factors: Vec<usize>,
    levels: Vec<Level>,
}

impl DenseReference {
    /// Prepares `frame` (at tracking resolution), seen from `pose`, for the levels of `config`.
    pub fn new(frame: &Frame, pose: Isometry3<f64>, config: &DenseConfig) -> Self {
        let levels = config
            .pyramid
            .iter()
            .map(|&f| Level::new(&frame.downscale(f), true))
            .collect();
        Self {
            pose,
            factors: config.pyramid.clone(),
            levels,
        }
    }
}

/// Result of [`align`].
#[derive(Debug, Clone, PartialEq)]
pub struct Aligned {
    /// Estimated `T_world_camera` of the frame.
    pub pose: Isometry3<f64>,
    /// Gauss–Newton iterations over all levels.
    pub iterations: usize,
    /// Fraction of the frame's valid-depth pixels associated with the reference (finest level).
    pub inlier_fraction: f64,
    /// RMS point-to-plane distance of the inliers at the finest level, metres.
    pub rms_distance: f64,
    /// Whether the finest level's step fell below the threshold.
    pub converged: bool,
}

/// Normal equations of one linearisation.
#[derive(Clone, Copy)]
struct Normal {
    h: Matrix6<f64>,
    g: Vector6<f64>,
    inliers: usize,
    valid: usize,
    squared_distance: f64,
}

impl Normal {
    fn zero() -> Self {
        Self {
            h: Matrix6::zeros(),
            g: Vector6::zeros(),
            inliers: 0,
            valid: 0,
            squared_distance: 0.0,
        }
    }

    fn add(mut self, o: &Normal) -> Self {
        self.h += o.h;
        self.g += o.g;
        self.inliers += o.inliers;
        self.valid += o.valid;
        self.squared_distance += o.squared_distance;
        self
    }

    /// Adds a residual `r` with row `[a, Y × a]`, scale σ, Huber threshold `k` (in σ).
    fn residual(&mut self, a: &Vector3<f64>, y: &Vector3<f64>, r: f64, sigma: f64, k: f64) {
        let j = {
            let b = y.cross(a);
            Vector6::new(a.x, a.y, a.z, b.x, b.y, b.z)
        };
        let s = (r / sigma).abs();
        let huber = if s <= k { 1.0 } else { k / s };
        let w = huber / (sigma * sigma);
        self.h += w * j * j.transpose();
        self.g += w * r * j;
    }
}

/// One linearisation of the level at `t_ref_cur` (see the module doc).
fn linearise(
    config: &DenseConfig,
    reference: &Level,
    current: &Level,
    t_ref_cur: &Isometry3<f64>,
    gate: f64,
) -> Normal {
    let rotation = t_ref_cur.rotation.to_rotation_matrix();
    let translation = t_ref_cur.translation.vector;
    let k = reference.intrinsics;
    let rows: Vec<usize> = (0..current.height).step_by(ROWS_PER_CHUNK).collect();
    let parts: Vec<Normal> = rows
        .par_iter()
        .map(|&row0| {
            let mut acc = Normal::zero();
            for y in row0..(row0 + ROWS_PER_CHUNK).min(current.height) {
                for x in 0..current.width {
                    let i = y * current.width + x;
                    let n_cur = current.normals[i];
                    if n_cur == Vector3::zeros() {
                        continue;
                    }
                    acc.valid += 1;
                    let p = current.points[i].cast::<f64>();
                    let q = rotation * p + translation;
                    if q.z <= 1e-6 {
                        continue;
                    }
                    let (u, v) = (k.fx * q.x / q.z + k.cx, k.fy * q.y / q.z + k.cy);
                    let (xr, yr) = (u.round(), v.round());
                    if xr < 0.0
                        || yr < 0.0
                        || xr >= reference.width as f64
                        || yr >= reference.height as f64
                    {
                        continue;
                    }
                    let j = yr as usize * reference.width + xr as usize;
                    let n_ref = reference.normals[j].cast::<f64>();
                    if n_ref == Vector3::zeros() {
                        continue;
                    }
                    let delta = q - reference.points[j].cast::<f64>();
                    if delta.norm() > gate
                        || n_ref.dot(&(rotation * n_cur.cast::<f64>())) < config.min_normal_cosine
                    {
                        continue;
                    }
                    let r = n_ref.dot(&delta);
                    acc.inliers += 1;
                    acc.squared_distance += r * r;
                    acc.residual(&n_ref, &q, r, config.depth_sigma, config.huber);
                    if config.colour_sigma > 0.0
                        && let Some((value, grad)) = reference.sample(u, v)
                    {
                        let iz = 1.0 / q.z;
                        let (gx, gy) = (grad[0] * k.fx * iz, grad[1] * k.fy * iz);
                        let a = Vector3::new(gx, gy, -(gx * q.x + gy * q.y) * iz);
                        let r = value - current.grey[i] as f64;
                        acc.residual(&a, &q, r, config.colour_sigma, config.huber);
                    }
                }
            }
            acc
        })
        .collect();
    parts.iter().fold(Normal::zero(), |a, b| a.add(b))
}

/// Aligns `frame` (at tracking resolution) to `reference`, starting from the predicted
/// `T_world_camera` (see the module doc).
pub fn align(
    config: &DenseConfig,
    reference: &DenseReference,
    frame: &Frame,
    predicted: &Isometry3<f64>,
) -> Result<Aligned, SlamError> {
    config.validate()?;
    if reference.factors != config.pyramid {
        return Err(SlamError::Input {
            what: "dense reference",
            reason: format!(
                "prepared for pyramid {:?}, but the config asks for {:?}",
                reference.factors, config.pyramid
            ),
        });
    }
    let information =
        prior_information(config.prior_translation_sigma, config.prior_rotation_sigma);
    let to_reference = se3::normalized(&reference.pose).inverse();
    let predicted_rel = se3::normalized(&(to_reference * se3::normalized(predicted)));
    let mut t = predicted_rel;
    let mut out = Aligned {
        pose: *predicted,
        iterations: 0,
        inlier_fraction: 0.0,
        rms_distance: f64::NAN,
        converged: false,
    };
    for (level, &factor) in reference.levels.iter().zip(&config.pyramid) {
        let current = Level::new(&frame.downscale(factor), false);
        let gate = config.max_distance * factor as f64;
        out.converged = false;
        for _ in 0..config.iterations_per_level {
            let mut n = linearise(config, level, &current, &t, gate);
            out.iterations += 1;
            out.inlier_fraction = n.inliers as f64 / n.valid.max(1) as f64;
            out.rms_distance = (n.squared_distance / n.inliers.max(1) as f64).sqrt();
            if n.inliers < 6 {
                break;
            }
            let e = se3::log(&(t * predicted_rel.inverse()));
            for i in 0..6 {
                n.h[(i, i)] += information[i];
            }
            n.g += e.component_mul(&information);
            let Some(chol) = n.h.cholesky() else {
                break;
            };
            let step = -chol.solve(&n.g);
            if !step.iter().all(|v| v.is_finite()) {
                break;
            }
            t = se3::left_update(&t, &step);
            if step.norm() < config.convergence {
                out.converged = true;
                break;
            }
        }
    }
    out.pose = se3::normalized(&(reference.pose * t));
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_geometry::se3::pose_error;
    use nalgebra::{Translation3, UnitQuaternion};

    /// A frame of a textured box room seen from `pose` (`T_world_camera`), ray-cast exactly:
    /// walls at x = ±2, y = ±2, z = 0 and z = 3 (world), a grey level that varies smoothly
    /// and differently on each face, so both ICP and colour constrain all six directions.
    fn box_frame(k: Intrinsics, pose: &Isometry3<f64>) -> Frame {
        let (w, h) = (k.width as usize, k.height as usize);
        let mut rgb = vec![[0f32; 3]; w * h];
        let mut depth = vec![0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let dir_cam = k.unproject(x as f64, y as f64, 1.0).coords;
                let dir = pose.rotation * dir_cam;
                let o = pose.translation.vector;
                let mut best = f64::INFINITY;
                let mut hit_face = 0;
                for (axis, bound) in [(0, -2.0), (0, 2.0), (1, -2.0), (1, 2.0), (2, 0.0), (2, 3.0)]
                {
                    if dir[axis].abs() < 1e-12 {
                        continue;
                    }
                    let s = (bound - o[axis]) / dir[axis];
                    if s > 0.0 && s < best {
                        best = s;
                        hit_face = axis * 2 + usize::from(bound > 0.5);
                    }
                }
                let p = o + best * dir;
                let f = hit_face as f64;
                let g = 0.5
                    + 0.2 * (3.1 * p.x + 1.3 * f).sin() * (2.3 * p.y - 0.7 * f).cos()
                    + 0.15 * (4.1 * p.z + 0.9 * p.x + f).sin();
                let i = y * w + x;
                rgb[i] = [g as f32; 3];
                depth[i] = (best * dir_cam.z) as f32;
            }
        }
        Frame::new(k, rgb, depth, 0.0).unwrap()
    }

    fn camera_at(x: f64, y: f64, yaw: f64) -> Isometry3<f64> {
        // Optical frame: z forward (world heading yaw), y down (world −z).
        let base = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw);
        let optical = UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix(
            &nalgebra::Matrix3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0),
        ));
        Isometry3::from_parts(Translation3::new(x, y, 1.2), base * optical)
    }

    #[test]
    fn recovers_a_relative_pose_from_an_offset_start() {
        let k = Intrinsics::from_hfov(96, 96, std::f64::consts::FRAC_PI_2);
        let reference_pose = camera_at(0.0, 0.0, 0.3);
        let truth = camera_at(0.08, 0.03, 0.3 + 6f64.to_radians());
        let config = DenseConfig {
            prior_translation_sigma: 0.0,
            prior_rotation_sigma: 0.0,
            ..DenseConfig::default()
        };
        let reference =
            DenseReference::new(&box_frame(k, &reference_pose), reference_pose, &config);
        let frame = box_frame(k, &truth);
        // Start from the reference pose: 8.5 cm and 6° away from the truth.
        let out = align(&config, &reference, &frame, &reference_pose).unwrap();
        let (t, a) = pose_error(&out.pose, &truth);
        assert!(
            t < 1e-3 && a.to_degrees() < 0.05,
            "error {t} m {}° after {} iterations",
            a.to_degrees(),
            out.iterations
        );
        assert!(out.inlier_fraction > 0.8, "{out:?}");
    }

    #[test]
    fn geometry_alone_and_colour_alone_both_converge() {
        let k = Intrinsics::from_hfov(64, 64, std::f64::consts::FRAC_PI_2);
        let reference_pose = camera_at(0.2, -0.1, -0.5);
        let truth = camera_at(0.23, -0.12, -0.5 - 3f64.to_radians());
        let reference_frame = box_frame(k, &reference_pose);
        let frame = box_frame(k, &truth);
        // Start: 3.6 cm and 3° off. Geometry alone is exact on a ray-cast box; colour alone is
        // limited by bilinear interpolation across the box's creases at 64 px, hence looser.
        for (depth_sigma, colour_sigma, max_t, max_deg) in
            [(0.005, 0.0, 2e-3, 0.1), (1e3, 0.05, 0.015, 0.5)]
        {
            let config = DenseConfig {
                depth_sigma,
                colour_sigma,
                prior_translation_sigma: 0.0,
                prior_rotation_sigma: 0.0,
                iterations_per_level: 20,
                ..DenseConfig::default()
            };
            let reference = DenseReference::new(&reference_frame, reference_pose, &config);
            let out = align(&config, &reference, &frame, &reference_pose).unwrap();
            let (t, a) = pose_error(&out.pose, &truth);
            assert!(
                t < max_t && a.to_degrees() < max_deg,
                "σ_d {depth_sigma} σ_c {colour_sigma}: {t} m {}°",
                a.to_degrees()
            );
        }
    }

    #[test]
    fn one_and_two_threads_agree_and_bad_config_is_named() {
        let k = Intrinsics::from_hfov(48, 48, std::f64::consts::FRAC_PI_2);
        let a = camera_at(0.0, 0.0, 0.0);
        let b = camera_at(0.03, 0.0, 2f64.to_radians());
        let config = DenseConfig::default();
        let reference = DenseReference::new(&box_frame(k, &a), a, &config);
        let frame = box_frame(k, &b);
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| align(&config, &reference, &frame, &a).unwrap())
        };
        assert_eq!(run(1), run(2));
        let bad = DenseConfig {
            pyramid: vec![2, 0],
            ..DenseConfig::default()
        };
        let err = align(&bad, &reference, &frame, &a).unwrap_err().to_string();
        assert!(err.contains("pyramid"), "{err}");
        let other = DenseConfig {
            pyramid: vec![1],
            ..DenseConfig::default()
        };
        let err = align(&other, &reference, &frame, &a)
            .unwrap_err()
            .to_string();
        assert!(err.contains("dense reference"), "{err}");
    }
}
