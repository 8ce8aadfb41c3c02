//! Levenberg–Marquardt pose refinement (a faster alternative to SPEC §4's Adam tracker, chosen
//! by [`crate::tracker::TrackerMethod`]): the same rendered residuals, but in least squares,
//! `L = ½ Σ_p [w_c·Σ_ch ρ(Î − I) + w_d·ρ(D̂/o − D)]` with the truncated square
//! `ρ(r) = min(r², r_max²)` (outliers such as unmapped surfaces and occlusion edges get no
//! gradient), over the pixels the map covers (`o > 0.95`) and, for colour, the MonoGS
//! photometric mask.
//!
//! The per-pixel Jacobians `J = ∂(Î, D̂/o)/∂τ` come from forward differences of six extra
//! renders (a 1 mm / 1 mrad probe per axis of τ; forward passes only, no backward), so the
//! normal equations `H = Σ w·JᵀJ`, `g = Σ w·Jᵀr` cover exactly the inlier pixels of the loss
//! (pixels whose value jumps under a probe, i.e. edges, are left out). A step
//! `τ = −(H + λ·diag H)⁻¹ g` is applied as the left update of SPEC §2 and accepted only when the
//! loss over the pixels covered both before and after the step drops ([`paired_costs`]; λ
//! shrinks), else λ grows. Levels run coarse to fine (block-averaged frames from
//! [`Frame::downscale`]). Exposure is held at the prediction.
//!
//! Motion prior (SPEC §4 allows the commanded action, never ground truth): the start pose is
//! the prediction, and `½ eᵀΛe` with `e = log(T_cw · T_cw,pred⁻¹)` and a diagonal `Λ` from
//! `prior_*_sigma` is added to the loss, so weakly observed directions stay near the
//! prediction instead of wandering; strong image evidence (a collision) still overrides it.

use crate::error::SlamError;
use crate::frame::Frame;
use crate::loss::{MIN_DEPTH, TRACK_OPACITY_MIN, rgb_mask};
use activemap_geometry::Isometry3;
use activemap_geometry::se3;
use activemap_splat::{Camera, FLAG_UNKNOWN_SPACE, Gaussians, Render, RenderOptions, render};
use nalgebra::{Matrix6, Vector6};

/// Damping increases tried per iteration before the level is declared converged.
const MAX_TRIALS: usize = 5;

/// Settings of the Levenberg–Marquardt tracker.
#[derive(Debug, Clone, PartialEq)]
pub struct GaussNewtonConfig {
    /// Downscale factors (relative to the tracking frame) run in order, coarse to fine.
    pub pyramid: Vec<usize>,
    /// Iteration cap per level (each iteration = one backward pass plus ≥ 1 render).
    pub iterations_per_level: usize,
    /// Weight of a squared colour residual (per channel).
    pub colour_weight: f64,
    /// Weight of a squared depth residual (metres²).
    pub depth_weight: f64,
    /// Colour residuals beyond this get no gradient (truncated square).
    pub colour_outlier: f64,
    /// Depth residuals beyond this (metres) get no gradient.
    pub depth_outlier: f64,
    /// Initial damping λ (relative to diag H).
    pub initial_damping: f64,
    /// Stop a level once the step's norm falls below this.
    pub convergence: f64,
    /// Standard deviation of the motion prior's translation, metres (0 = no prior term).
    pub prior_translation_sigma: f64,
    /// Standard deviation of the motion prior's rotation, radians (0 = no prior term).
    pub prior_rotation_sigma: f64,
}

impl Default for GaussNewtonConfig {
    fn default() -> Self {
        Self {
            pyramid: vec![2, 1],
            iterations_per_level: 6,
            colour_weight: 1.0,
            depth_weight: 10.0,
            colour_outlier: 0.3,
            depth_outlier: 0.1,
            initial_damping: 1e-3,
            convergence: 1e-5,
            prior_translation_sigma: 0.01,
            prior_rotation_sigma: 0.5f64.to_radians(),
        }
    }
}

impl GaussNewtonConfig {
    /// Checks ranges; names the offending field.
    pub fn validate(&self) -> Result<(), SlamError> {
        if self.pyramid.is_empty() || self.pyramid.contains(&0) {
            return Err(SlamError::Config {
                field: "gauss_newton.pyramid",
                value: format!("{:?}", self.pyramid),
                reason: "must be non-empty factors ≥ 1",
            });
        }
        let positive = [
            ("gauss_newton.colour_outlier", self.colour_outlier),
            ("gauss_newton.depth_outlier", self.depth_outlier),
            ("gauss_newton.initial_damping", self.initial_damping),
            ("gauss_newton.convergence", self.convergence),
        ];
        SlamError::require_positive(&positive)?;
        SlamError::require_non_negative(&[
            ("gauss_newton.colour_weight", self.colour_weight),
            ("gauss_newton.depth_weight", self.depth_weight),
            (
                "gauss_newton.prior_translation_sigma",
                self.prior_translation_sigma,
            ),
            (
                "gauss_newton.prior_rotation_sigma",
                self.prior_rotation_sigma,
            ),
        ])
    }
}

/// The truncated least-squares loss of the module doc (without the prior term).
pub fn least_squares_cost(
    config: &GaussNewtonConfig,
    render: &Render<f32>,
    frame: &Frame,
    rgb_mask: &[bool],
) -> f64 {
    let (wc, wd) = (config.colour_weight, config.depth_weight);
    let (cmax2, dmax2) = (config.colour_outlier.powi(2), config.depth_outlier.powi(2));
    let mut value = 0.0;
    for p in 0..frame.depth.len() {
        let o = render.opacity[p];
        let (d, d_hat) = (frame.depth[p], render.depth[p]);
        let covered = o > TRACK_OPACITY_MIN && d_hat > MIN_DEPTH;
        // Pixels the map does not cover cost as much as an outlier, so that the optimiser
        // cannot lower the loss by sliding the view off the map.
        if rgb_mask[p] && wc > 0.0 {
            if covered {
                for ch in 0..3 {
                    let r = (render.colour[p][ch] - frame.rgb[p][ch]) as f64;
                    value += 0.5 * wc * (r * r).min(cmax2);
                }
            } else {
                value += 1.5 * wc * cmax2;
            }
        }
        if wd > 0.0 && d > MIN_DEPTH {
            if covered {
                // Normalised depth D̂/o (see `crate::loss::tracking_loss`).
                let r = (d_hat / o - d) as f64;
                value += 0.5 * wd * (r * r).min(dmax2);
            } else {
                value += 0.5 * wd * dmax2;
            }
        }
    }
    value
}

/// The truncated costs of two renders over the pixels BOTH cover (opacity > 0.95, depth), so
/// that a step is judged on the same pixels before and after it: coverage changes at the map's
/// borders neither reward sliding off the map nor make the comparison jump.
pub fn paired_costs(
    config: &GaussNewtonConfig,
    before: &Render<f32>,
    after: &Render<f32>,
    frame: &Frame,
    rgb_mask: &[bool],
) -> (f64, f64) {
    let (wc, wd) = (config.colour_weight, config.depth_weight);
    let (cmax2, dmax2) = (config.colour_outlier.powi(2), config.depth_outlier.powi(2));
    let covered =
        |r: &Render<f32>, p: usize| r.opacity[p] > TRACK_OPACITY_MIN && r.depth[p] > MIN_DEPTH;
    let cost = |r: &Render<f32>, p: usize| {
        let mut c = 0.0;
        if rgb_mask[p] {
            for ch in 0..3 {
                let e = (r.colour[p][ch] - frame.rgb[p][ch]) as f64;
                c += 0.5 * wc * (e * e).min(cmax2);
            }
        }
        if frame.depth[p] > MIN_DEPTH {
            let e = (r.depth[p] / r.opacity[p] - frame.depth[p]) as f64;
            c += 0.5 * wd * (e * e).min(dmax2);
        }
        c
    };
    let (mut a, mut b) = (0.0, 0.0);
    for p in 0..frame.depth.len() {
        if covered(before, p) && covered(after, p) {
            a += cost(before, p);
            b += cost(after, p);
        }
    }
    (a, b)
}

/// Information (inverse covariance, diagonal) of a motion prior on τ = [ρ, θ] with the given
/// standard deviations (metres, radians); zero where a sigma is 0 (disabled). Shared by the
/// Gauss–Newton and dense trackers.
pub(crate) fn prior_information(translation_sigma: f64, rotation_sigma: f64) -> Vector6<f64> {
    let inv = |s: f64| if s > 0.0 { 1.0 / (s * s) } else { 0.0 };
    let (t, r) = (inv(translation_sigma), inv(rotation_sigma));
    Vector6::new(t, t, t, r, r, r)
}

/// The prior's cost `½ eᵀΛe` with `e = log(T_cw · T_cw,pred⁻¹)` and its residual `e`.
fn prior_cost(
    information: &Vector6<f64>,
    pose: &Isometry3<f64>,
    predicted: &Isometry3<f64>,
) -> (f64, Vector6<f64>) {
    let e = se3::log(&(pose * predicted.inverse()));
    (0.5 * e.component_mul(information).dot(&e), e)
}

/// Result of [`refine`].
#[derive(Debug, Clone)]
pub struct Refined {
    /// Refined `T_camera_world`.
    pub camera_from_world: Isometry3<f64>,
    /// Linearisations (Jacobian evaluations) run over all levels.
    pub iterations: usize,
    /// Whether the finest level converged (step below the threshold or no further descent).
    pub converged: bool,
}

/// Per-pixel outputs the residuals are built from: colour and normalised depth `D̂/o`.
struct Sampled {
    colour: Vec<[f64; 3]>,
    depth: Vec<f64>,
    covered: Vec<bool>,
}

fn sample(render: &Render<f32>) -> Sampled {
    let n = render.depth.len();
    let mut out = Sampled {
        colour: Vec::with_capacity(n),
        depth: Vec::with_capacity(n),
        covered: Vec::with_capacity(n),
    };
    for p in 0..n {
        let o = render.opacity[p];
        out.colour.push(render.colour[p].map(|c| c as f64));
        let covered = o > TRACK_OPACITY_MIN && render.depth[p] > MIN_DEPTH;
        out.covered.push(covered);
        out.depth.push(if covered {
            (render.depth[p] / o) as f64
        } else {
            0.0
        });
    }
    out
}

/// Normal equations `H = Σ w JᵀJ`, `b = Σ w Jᵀr` of the truncated loss at `base`, with the
/// Jacobians `J` by forward differences of renders at `Exp(h·e_k)·T` (`h` = 1 mm / 1 mrad).
/// Pixels whose output jumps under the probe (occlusion edges, coverage changes) are left out.
fn normal_equations(
    config: &GaussNewtonConfig,
    map: &Gaussians<f32>,
    frame: &Frame,
    mask: &[bool],
    pose: &Isometry3<f64>,
    base: &Sampled,
    options: &RenderOptions,
) -> Result<(Matrix6<f64>, Vector6<f64>), SlamError> {
    const PROBE: f64 = 1e-3;
    let n = frame.depth.len();
    let mut probes = Vec::with_capacity(6);
    for k in 0..6 {
        let mut tau = Vector6::zeros();
        tau[k] = PROBE;
        let moved = se3::left_update(pose, &tau);
        probes.push(sample(&render(
            map,
            &Camera::new(frame.intrinsics, moved),
            options,
        )?));
    }
    let (wc, wd) = (config.colour_weight, config.depth_weight);
    let (cmax, dmax) = (config.colour_outlier, config.depth_outlier);
    // A 1 mm / 1 mrad probe moves a smooth surface by millimetres; more is an edge.
    let (depth_jump, colour_jump) = (0.02, 0.2);
    let mut h = Matrix6::zeros();
    let mut b = Vector6::zeros();
    for p in 0..n {
        if !base.covered[p] {
            continue;
        }
        if wd > 0.0 && frame.depth[p] > MIN_DEPTH {
            let r = base.depth[p] - frame.depth[p] as f64;
            if r.abs() < dmax && probes.iter().all(|s| s.covered[p]) {
                let diffs: Vec<f64> = probes.iter().map(|s| s.depth[p] - base.depth[p]).collect();
                if diffs.iter().all(|d| d.abs() < depth_jump) {
                    let j = Vector6::from_iterator(diffs.iter().map(|d| d / PROBE));
                    h += wd * j * j.transpose();
                    b += wd * r * j;
                }
            }
        }
        if wc > 0.0 && mask[p] {
            for ch in 0..3 {
                let r = base.colour[p][ch] - frame.rgb[p][ch] as f64;
                if r.abs() >= cmax {
                    continue;
                }
                let diffs: Vec<f64> = probes
                    .iter()
                    .map(|s| s.colour[p][ch] - base.colour[p][ch])
                    .collect();
                if diffs.iter().all(|d| d.abs() < colour_jump) {
                    let j = Vector6::from_iterator(diffs.iter().map(|d| d / PROBE));
                    h += wc * j * j.transpose();
                    b += wc * r * j;
                }
            }
        }
    }
    Ok((h, b))
}

/// Refines `camera_from_world` against `map` on `frame` (already at tracking resolution) with
/// the coarse-to-fine Levenberg–Marquardt of the module doc.
pub fn refine(
    config: &GaussNewtonConfig,
    map: &Gaussians<f32>,
    frame: &Frame,
    camera_from_world: Isometry3<f64>,
    exposure: [f64; 2],
    rgb_boundary: f32,
    edge_factor: f32,
) -> Result<Refined, SlamError> {
    config.validate()?;
    let options = RenderOptions {
        exposure,
        exclude_flags: FLAG_UNKNOWN_SPACE,
        ..Default::default()
    };
    let mut pose = camera_from_world;
    let predicted = camera_from_world;
    let information =
        prior_information(config.prior_translation_sigma, config.prior_rotation_sigma);
    let mut iterations = 0;
    let mut converged = false;
    for &factor in &config.pyramid {
        let level = frame.downscale(factor);
        let mask = rgb_mask(&level, rgb_boundary, edge_factor);
        let mut current = render(map, &Camera::new(level.intrinsics, pose), &options)?;
        let mut lambda = config.initial_damping;
        converged = false;
        for _ in 0..config.iterations_per_level {
            let base = sample(&current);
            let (mut h, mut g) =
                normal_equations(config, map, &level, &mask, &pose, &base, &options)?;
            // Prior: e' ≈ e + τ to first order under the left update.
            let e = prior_cost(&information, &pose, &predicted).1;
            for k in 0..6 {
                h[(k, k)] += information[k];
            }
            g += e.component_mul(&information);
            iterations += 1;
            let mut accepted = false;
            for _ in 0..MAX_TRIALS {
                let mut a = h;
                for k in 0..6 {
                    a[(k, k)] += lambda * h[(k, k)] + 1e-9;
                }
                let Some(chol) = a.cholesky() else {
                    lambda *= 4.0;
                    continue;
                };
                let step = -chol.solve(&g);
                if !step.iter().all(|v| v.is_finite()) {
                    break;
                }
                let candidate = se3::left_update(&pose, &step);
                let rendered = render(map, &Camera::new(level.intrinsics, candidate), &options)?;
                let (before, after) = paired_costs(config, &current, &rendered, &level, &mask);
                let before = before + prior_cost(&information, &pose, &predicted).0;
                let after = after + prior_cost(&information, &candidate, &predicted).0;
                if after < before {
                    pose = candidate;
                    current = rendered;
                    lambda = (lambda / 3.0).max(1e-7);
                    accepted = true;
                    if step.norm() < config.convergence {
                        converged = true;
                    }
                    break;
                }
                lambda *= 10.0;
            }
            if !accepted {
                // No descent at any tried damping: the level is at its minimum.
                converged = true;
            }
            if converged {
                break;
            }
        }
    }
    Ok(Refined {
        camera_from_world: pose,
        iterations,
        converged,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_geometry::Intrinsics;
    use activemap_geometry::se3::pose_error;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A box corner in front of the identity camera (optical frame): a wall at z = 2, a side
    /// wall at x = 0.9 and a floor at y = 0.7, tiled with opaque Gaussians coloured by a smooth
    /// random pattern (a few sinusoids of position), so that every direction of τ is
    /// observable and the images are smooth at the pixel scale.
    fn corner_map() -> Gaussians<f32> {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let waves: Vec<([f64; 3], f64)> = (0..3)
            .map(|_| {
                let dir = [0; 3].map(|_| rng.random_range(-12.0..12.0));
                (dir, rng.random_range(0.0..std::f64::consts::TAU))
            })
            .collect();
        let mut map = Gaussians::new();
        let step = 0.05;
        let mut add = |p: [f64; 3], _: &mut ChaCha8Rng| {
            let rgb: [f64; 3] = std::array::from_fn(|c| {
                let (d, phase) = waves[c];
                0.5 + 0.35 * (d[0] * p[0] + d[1] * p[1] + d[2] * p[2] + phase).sin()
            });
            map.push(p, rgb, [1.0, 0.0, 0.0, 0.0], 0.99, [0.035; 3]);
        };
        for i in 0..40 {
            for j in 0..36 {
                let (a, b) = (-1.1 + i as f64 * step, -1.0 + j as f64 * step);
                add([a, b, 2.0], &mut rng);
                add([0.9, b, 0.2 + i as f64 * step], &mut rng);
                add([a, 0.7, 0.2 + j as f64 * step], &mut rng);
            }
        }
        map
    }

    /// The map rendered at `T_world_camera = pose` as an observed frame (depth = D̂/o).
    fn observe(map: &Gaussians<f32>, k: Intrinsics, pose: &Isometry3<f64>) -> Frame {
        let out = render(
            map,
            &Camera::from_world_pose(k, pose),
            &RenderOptions::default(),
        )
        .unwrap();
        let depth = (0..out.depth.len())
            .map(|p| {
                if out.opacity[p] > 0.5 {
                    out.depth[p] / out.opacity[p]
                } else {
                    0.0
                }
            })
            .collect();
        Frame::new(k, out.colour.clone(), depth, 0.0).unwrap()
    }

    #[test]
    fn recovers_an_offset_pose_on_a_self_consistent_map() {
        let map = corner_map();
        let k = Intrinsics::from_hfov(64, 64, std::f64::consts::FRAC_PI_2);
        let truth = Isometry3::identity();
        let frame = observe(&map, k, &truth);
        let offset = Isometry3::from_parts(
            Translation3::new(0.02, -0.015, 0.025),
            UnitQuaternion::from_axis_angle(
                &nalgebra::Unit::new_normalize(Vector3::new(0.2, 1.0, -0.3)),
                2f64.to_radians(),
            ),
        );
        let start = truth * offset;
        // No prior: the start is an arbitrary perturbation here, not a motion prediction.
        // One full-resolution level: on this 64-px scene the 32-px coarse level of the default
        // pyramid stalls at ≈1.5 cm / 0.85° (the coarse image is too small for this offset).
        let config = GaussNewtonConfig {
            prior_translation_sigma: 0.0,
            prior_rotation_sigma: 0.0,
            iterations_per_level: 10,
            pyramid: vec![1],
            ..GaussNewtonConfig::default()
        };
        let r = refine(&config, &map, &frame, start.inverse(), [0.0; 2], 0.01, 0.0).unwrap();
        let (t, a) = pose_error(&r.camera_from_world.inverse(), &truth);
        assert!(
            t < 0.002 && a.to_degrees() < 0.1,
            "error {t} m {}° after {} iterations",
            a.to_degrees(),
            r.iterations
        );
    }

    #[test]
    fn a_strong_prior_holds_the_prediction_and_bad_config_is_named() {
        let map = corner_map();
        let k = Intrinsics::from_hfov(32, 32, std::f64::consts::FRAC_PI_2);
        let frame = observe(&map, k, &Isometry3::identity());
        let predicted = Isometry3::translation(0.03, 0.0, 0.0);
        // σ = 10 µm / 10 µrad: the prior outweighs the image; the pose barely moves.
        let config = GaussNewtonConfig {
            prior_translation_sigma: 1e-5,
            prior_rotation_sigma: 1e-5,
            ..GaussNewtonConfig::default()
        };
        let r = refine(
            &config,
            &map,
            &frame,
            predicted.inverse(),
            [0.0; 2],
            0.01,
            0.0,
        )
        .unwrap();
        let (t, _) = pose_error(&r.camera_from_world.inverse(), &predicted);
        assert!(t < 0.003, "moved {t} m against the prior");
        let bad = GaussNewtonConfig {
            pyramid: vec![],
            ..GaussNewtonConfig::default()
        };
        let err = bad.validate().unwrap_err().to_string();
        assert!(err.contains("pyramid"), "{err}");
    }
}
