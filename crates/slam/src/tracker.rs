//! Tracking. The default ([`TrackerMethod::Dense`]) aligns the frame densely to the last
//! keyframe's RGB-D image ([`crate::dense`]); the alternatives track against renders of the
//! map. SPEC §4's frame-to-map tracking: Adam on the pose increment τ = [ρ, θ] of the left update
//! `T_cw ← Exp(τ)·T_cw` and on the exposure (a, b), minimising the tracking loss of
//! [`crate::loss::tracking_loss`]. Like MonoGS, τ is folded into the pose after every step
//! (and reset to 0) while the Adam moments persist; the loop stops once |τ| < `convergence`.
//!
//! The tracking-quality signal. With [`TrackerMethod::Dense`] it comes from the alignment to
//! the reference keyframes (the map's observations): the frame is `Lost` when their RMS
//! point-to-plane distance exceeds `dense.lost_max_rms`, or when too few of its depth pixels
//! associate with them (`lost_min_coverage`) and the map's render at the solution contradicts
//! the frame where it covers it (depth or colour residual: a covered lens), or nothing at all
//! associates. A frame that turns into new, unmapped space (little overlap with the references,
//! none with the map) or into mapped space the references do not show (the map covers it and
//! agrees) is not lost: it must be tracked and mapped, which is what exploration is for. (Taking
//! every low overlap for lost had a robot turning into an unmapped room lose tracking, turn back
//! on the spot, regain it, turn in again, for 80 steps of the README's main run.) With the
//! render-based methods, the render is compared with the frame ([`Residuals`]): `Lost` when
//! the map covers too little of it, or when the covered part disagrees in depth or colour
//! beyond the configured limits. The map residuals are reported in every case. Unknown-space Gaussians (SPEC §5) are never rendered for tracking.

use crate::dense::{DenseConfig, DenseReference, align_many};
use crate::error::SlamError;
use crate::frame::{Frame, SkipReason};
use crate::gauss_newton::{GaussNewtonConfig, refine};
use crate::loss::{Residuals, residuals, rgb_mask, tracking_loss};
use activemap_geometry::Isometry3;
use activemap_geometry::se3;
use activemap_splat::{
    AdamState, Camera, DepthModel, FLAG_UNKNOWN_SPACE, Gaussians, RenderOptions, backward, render,
};
use nalgebra::Vector6;

/// How the pose is optimised.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrackerMethod {
    /// SPEC §4 verbatim: Adam on τ and the exposure, L1 loss (slow on the CPU: ~100 renders).
    Adam,
    /// Coarse-to-fine Levenberg–Marquardt on τ ([`crate::gauss_newton`]): a handful of renders.
    GaussNewton,
    /// Dense RGB-D alignment (point-to-plane ICP plus photometric) to the last keyframe
    /// ([`crate::dense`]), one render for the status; the default. Without a reference
    /// keyframe it falls back to [`TrackerMethod::GaussNewton`].
    Dense,
}

/// Tracker settings; defaults are SPEC §4's except the optimiser (see [`TrackerMethod`]).
#[derive(Debug, Clone, PartialEq)]
pub struct TrackerConfig {
    /// Optimiser of the pose.
    pub method: TrackerMethod,
    /// Settings of [`TrackerMethod::GaussNewton`].
    pub gauss_newton: GaussNewtonConfig,
    /// Settings of [`TrackerMethod::Dense`].
    pub dense: DenseConfig,
    /// Adam learning rate of the translation part ρ (0.001).
    pub lr_translation: f64,
    /// Adam learning rate of the rotation part θ (0.003).
    pub lr_rotation: f64,
    /// Adam learning rate of the exposure a, b (0.01).
    pub lr_exposure: f64,
    /// Whether the exposure is optimised at all.
    pub optimise_exposure: bool,
    /// Iteration cap (100).
    pub max_iterations: usize,
    /// Stop once the step |τ| falls below this (1e-4).
    pub convergence: f64,
    /// Weight α of the colour term (0.95 synthetic, 0.9 real sensors).
    pub alpha: f32,
    /// `Σ RGB` above which a pixel counts for the colour term (0.01).
    pub rgb_boundary: f32,
    /// Colour pixels need an image gradient above this × the median (MonoGS edge threshold);
    /// 0 keeps every pixel.
    pub edge_factor: f32,
    /// Compare depth readings with the normalised render `D̂/o` (see
    /// [`crate::loss::tracking_loss`]; true by default, false = SPEC §4 verbatim).
    pub normalise_depth: bool,
    /// Track on a frame downscaled by this integer factor (speed; 1 = full resolution).
    pub downscale: usize,
    /// `Lost` when the map covers less than this fraction of the valid-depth pixels.
    pub lost_min_coverage: f64,
    /// `Lost` when the median depth residual exceeds this fraction of the median depth.
    pub lost_max_depth_residual: f64,
    /// `Lost` when the mean colour residual over covered pixels exceeds this.
    pub lost_max_photometric: f64,
    /// The per-pixel depth of a Gaussian in the tracker's renders (the status render and the
    /// Adam method; the Gauss–Newton Jacobians use the centre model): the map's model
    /// ([`crate::MapperConfig::depth_model`]).
    pub depth_model: DepthModel,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            method: TrackerMethod::Dense,
            gauss_newton: GaussNewtonConfig::default(),
            dense: DenseConfig::default(),
            lr_translation: 0.001,
            lr_rotation: 0.003,
            lr_exposure: 0.01,
            optimise_exposure: true,
            max_iterations: 100,
            convergence: 1e-4,
            alpha: 0.95,
            rgb_boundary: 0.01,
            edge_factor: 1.1,
            normalise_depth: true,
            downscale: 1,
            lost_min_coverage: 0.3,
            lost_max_depth_residual: 0.1,
            lost_max_photometric: 0.3,
            depth_model: DepthModel::default(),
        }
    }
}

impl TrackerConfig {
    /// Checks ranges; names the offending field.
    pub fn validate(&self) -> Result<(), SlamError> {
        let positive = [
            ("lr_translation", self.lr_translation),
            ("lr_rotation", self.lr_rotation),
            ("lr_exposure", self.lr_exposure),
            ("convergence", self.convergence),
        ];
        SlamError::require_positive(&positive)?;
        if !(0.0..=1.0).contains(&self.alpha) {
            return Err(SlamError::Config {
                field: "alpha",
                value: self.alpha.to_string(),
                reason: "must be in [0, 1]",
            });
        }
        self.gauss_newton.validate()?;
        self.dense.validate()?;
        if self.downscale == 0 {
            return Err(SlamError::Config {
                field: "downscale",
                value: "0".into(),
                reason: "must be ≥ 1",
            });
        }
        Ok(())
    }
}

/// Tracking outcome of one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TrackingStatus {
    /// The map explains the frame at the estimated pose.
    Ok,
    /// Tracking failed for the reason given (the pose is a guess).
    Lost(LostReason),
    /// The frame was unusable and not tracked (the pose is the prediction).
    Skipped(SkipReason),
}

impl TrackingStatus {
    /// Whether tracking failed ([`TrackingStatus::Lost`], whatever the reason).
    pub fn is_lost(&self) -> bool {
        matches!(self, Self::Lost(_))
    }
}

/// Why a frame is [`TrackingStatus::Lost`]: the wire type itself, so that the reason a log
/// line, a report and a recording show is the one the session decided.
pub use activemap_schemas::LostReason;

/// The result of tracking one frame.
#[derive(Debug, Clone)]
pub struct TrackOutput {
    /// Estimated `T_world_camera`.
    pub pose: Isometry3<f64>,
    /// Estimated exposure (a, b): rendered colour `e^a·c + b` matches the frame.
    pub exposure: [f64; 2],
    /// Ok / lost / skipped.
    pub status: TrackingStatus,
    /// Residuals of the final render (they justify the status).
    pub residuals: Residuals,
    /// Optimisation iterations run.
    pub iterations: usize,
    /// Whether the step fell below the convergence threshold.
    pub converged: bool,
    /// Final tracking loss.
    pub loss: f64,
    /// Which map Gaussians the final render saw (index into the map), for co-visibility.
    pub visible: Vec<bool>,
    /// [`TrackerMethod::Dense`]: the fraction of the frame's valid-depth pixels associated
    /// with the reference keyframe (a falling overlap asks for a new reference); 1 otherwise.
    pub reference_overlap: f64,
    /// [`TrackerMethod::Dense`]: the fraction of the frame's valid-depth pixels the reference
    /// keyframe also sees ([`crate::dense::Aligned::covisible_fraction`]); 1 otherwise.
    pub reference_covisible: f64,
}

/// Decides the status from residuals (see the module doc); a lost frame names the first check
/// that failed.
pub fn classify(config: &TrackerConfig, r: &Residuals, median_depth: f64) -> TrackingStatus {
    let depth_limit = config.lost_max_depth_residual * median_depth.max(0.1);
    if r.coverage < config.lost_min_coverage {
        TrackingStatus::Lost(LostReason::LowOverlap {
            fraction: r.coverage,
        })
    } else if !(r.depth_median.is_finite() && r.depth_median <= depth_limit) {
        TrackingStatus::Lost(LostReason::DepthResidual {
            metres: r.depth_median,
        })
    } else if r.photometric > config.lost_max_photometric {
        TrackingStatus::Lost(LostReason::ColourResidual {
            residual: r.photometric,
        })
    } else {
        TrackingStatus::Ok
    }
}

/// Tracks `frame` (already at tracking resolution) against `map` (and, for
/// [`TrackerMethod::Dense`], the `references` keyframes: the newest first, then older ones of
/// the same place, see [`crate::references`]), starting from the predicted
/// `T_world_camera` and exposure. Unusable frames return `Skipped` with the prediction.
pub fn track(
    config: &TrackerConfig,
    map: &Gaussians<f32>,
    frame: &Frame,
    predicted_pose: &Isometry3<f64>,
    predicted_exposure: [f64; 2],
    references: &[&DenseReference],
) -> Result<TrackOutput, SlamError> {
    config.validate()?;
    let pose_ok = predicted_pose
        .translation
        .vector
        .iter()
        .chain(predicted_pose.rotation.coords.iter())
        .all(|v| v.is_finite());
    if !pose_ok {
        return Err(SlamError::Input {
            what: "predicted pose",
            reason: "not finite".into(),
        });
    }
    let skipped = |reason| TrackOutput {
        pose: *predicted_pose,
        exposure: predicted_exposure,
        status: TrackingStatus::Skipped(reason),
        residuals: Residuals::default(),
        iterations: 0,
        converged: false,
        loss: f64::NAN,
        visible: vec![false; map.len()],
        reference_overlap: 0.0,
        reference_covisible: 0.0,
    };
    if let Err(reason) = frame.usability() {
        return Ok(skipped(reason));
    }
    let mask = rgb_mask(frame, config.rgb_boundary, config.edge_factor);
    let median_depth = frame.median_depth().unwrap_or(1.0);
    let options = |exposure| RenderOptions {
        exposure,
        exclude_flags: FLAG_UNKNOWN_SPACE,
        depth: config.depth_model,
    };
    let mut inlier_fraction = 1.0;
    let mut covisible_fraction = 1.0;
    let mut dense_status = None;
    let (camera_from_world, exposure, iterations, converged) = match config.method {
        TrackerMethod::Dense if !references.is_empty() => {
            let a = align_many(&config.dense, references, frame, predicted_pose)?;
            inlier_fraction = a.inlier_fraction;
            covisible_fraction = a.covisible_fraction;
            dense_status = Some(if a.inlier_fraction < config.lost_min_coverage {
                TrackingStatus::Lost(LostReason::LowOverlap {
                    fraction: a.inlier_fraction,
                })
            } else if !(a.rms_distance.is_finite() && a.rms_distance <= config.dense.lost_max_rms) {
                TrackingStatus::Lost(LostReason::DepthResidual {
                    metres: a.rms_distance,
                })
            } else {
                TrackingStatus::Ok
            });
            (
                a.pose.inverse(),
                predicted_exposure,
                a.iterations,
                a.converged,
            )
        }
        TrackerMethod::Adam => adam_refine(
            config,
            map,
            frame,
            &mask,
            predicted_pose,
            predicted_exposure,
        )?,
        TrackerMethod::GaussNewton | TrackerMethod::Dense => {
            let r = refine(
                &config.gauss_newton,
                map,
                frame,
                predicted_pose.inverse(),
                predicted_exposure,
                config.rgb_boundary,
                config.edge_factor,
            )?;
            (
                r.camera_from_world,
                predicted_exposure,
                r.iterations,
                r.converged,
            )
        }
    };
    // Residuals at the final pose (one extra forward pass, no backward).
    let camera = Camera::new(frame.intrinsics, camera_from_world);
    let final_render = render(map, &camera, &options(exposure))?;
    let loss = tracking_loss(
        &final_render,
        frame,
        &mask,
        config.alpha,
        config.normalise_depth,
    )
    .value;
    let res = residuals(&final_render, frame);
    let pose = camera_from_world.inverse();
    let finite = pose
        .translation
        .vector
        .iter()
        .chain(pose.rotation.coords.iter())
        .all(|v| v.is_finite());
    let (pose, status) = if finite {
        let status = match dense_status {
            // Little overlap with the reference keyframes: either the view is new (turning
            // into an unmapped room) or the solution is wrong. The map's render at the solution
            // decides: where it covers the frame, the frame must agree with it.
            Some(TrackingStatus::Lost(LostReason::LowOverlap { fraction })) => {
                match classify(config, &res, median_depth) {
                    // Neither the references nor the map cover the frame: new space, unless
                    // the references' overlap says nothing at all.
                    TrackingStatus::Lost(LostReason::LowOverlap { .. }) if fraction > 0.0 => {
                        TrackingStatus::Ok
                    }
                    TrackingStatus::Lost(LostReason::LowOverlap { .. }) => {
                        TrackingStatus::Lost(LostReason::LowOverlap { fraction })
                    }
                    // The map covers the frame: it agrees (tracked) or contradicts it (lost).
                    map_status => map_status,
                }
            }
            Some(status) => status,
            None => classify(config, &res, median_depth),
        };
        (pose, status)
    } else {
        (*predicted_pose, TrackingStatus::Lost(LostReason::NonFinite))
    };
    Ok(TrackOutput {
        pose,
        exposure,
        status,
        residuals: res,
        iterations,
        converged,
        loss,
        visible: final_render.context.visible,
        reference_overlap: inlier_fraction,
        reference_covisible: covisible_fraction,
    })
}

/// SPEC §4's Adam loop; returns (T_camera_world, exposure, iterations, converged).
fn adam_refine(
    config: &TrackerConfig,
    map: &Gaussians<f32>,
    frame: &Frame,
    mask: &[bool],
    predicted_pose: &Isometry3<f64>,
    predicted_exposure: [f64; 2],
) -> Result<(Isometry3<f64>, [f64; 2], usize, bool), SlamError> {
    let lr_e = if config.optimise_exposure {
        config.lr_exposure
    } else {
        0.0
    };
    let (lt, lr) = (config.lr_translation, config.lr_rotation);
    let rates = [lt, lt, lt, lr, lr, lr, lr_e, lr_e];
    let mut adam = AdamState::new();
    let mut camera_from_world = predicted_pose.inverse();
    let mut exposure = predicted_exposure;
    let mut iterations = 0;
    let mut converged = false;
    let options = |exposure| RenderOptions {
        exposure,
        exclude_flags: FLAG_UNKNOWN_SPACE,
        depth: config.depth_model,
    };
    while iterations < config.max_iterations {
        let camera = Camera::new(frame.intrinsics, camera_from_world);
        let out = render(map, &camera, &options(exposure))?;
        let loss = tracking_loss(&out, frame, mask, config.alpha, config.normalise_depth);
        let grads = backward(map, &out, &loss.grads)?;
        iterations += 1;
        let g = [
            grads.pose[0],
            grads.pose[1],
            grads.pose[2],
            grads.pose[3],
            grads.pose[4],
            grads.pose[5],
            grads.exposure[0],
            grads.exposure[1],
        ];
        // Adam on a zero vector: the result is the step Δ itself (τ is reset every iteration).
        let mut delta = [0.0; 8];
        adam.step(&mut delta, &g, |k| rates[k])?;
        let tau = Vector6::new(delta[0], delta[1], delta[2], delta[3], delta[4], delta[5]);
        if !tau.iter().all(|v| v.is_finite()) {
            break;
        }
        camera_from_world = se3::left_update(&camera_from_world, &tau);
        if config.optimise_exposure {
            exposure = [exposure[0] + delta[6], exposure[1] + delta[7]];
        }
        if tau.norm() < config.convergence {
            converged = true;
            break;
        }
    }
    Ok((camera_from_world, exposure, iterations, converged))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dense::tests::{box_frame, camera_at, map_of};
    use activemap_geometry::Intrinsics;

    /// The dense tracker's low overlap with its reference keyframes is decided by the map:
    /// a view turned into space neither the references nor the map cover is new, not lost; a
    /// view the map covers and agrees with is tracked; a covered lens, whose depth contradicts
    /// the map where it covers the view, is lost (`depth_residual`).
    #[test]
    fn low_reference_overlap_is_lost_only_where_the_map_contradicts_the_frame() {
        let k = Intrinsics::from_hfov(64, 64, std::f64::consts::FRAC_PI_2);
        let config = TrackerConfig::default();
        let reference_pose = camera_at(0.0, 0.0, 0.0);
        let reference_frame = box_frame(k, &reference_pose);
        let reference = DenseReference::new(&reference_frame, reference_pose, &config.dense);
        let mut map = Gaussians::<f32>::new();
        map_of(&reference_frame, &reference_pose, &mut map);
        let turned = camera_at(0.0, 0.0, 75f64.to_radians());
        let turned_frame = box_frame(k, &turned);
        let status = |map: &Gaussians<f32>, frame: &Frame, pose: &Isometry3<f64>| {
            let out = track(&config, map, frame, pose, [0.0; 2], &[&reference]).unwrap();
            (out.status, out.reference_overlap, out.residuals.coverage)
        };
        // Turned 75° into unmapped space: little overlap with the reference, none with the map.
        let (s, overlap, coverage) = status(&map, &turned_frame, &turned);
        assert!(
            overlap > 0.0 && overlap < config.lost_min_coverage,
            "{overlap}"
        );
        assert!(coverage < config.lost_min_coverage, "{coverage}");
        assert_eq!(s, TrackingStatus::Ok);
        // The same view once mapped: the map covers it and agrees.
        let mut mapped = map.clone();
        map_of(&turned_frame, &turned, &mut mapped);
        let (s, _, coverage) = status(&mapped, &turned_frame, &turned);
        assert!(coverage > 0.9, "{coverage}");
        assert_eq!(s, TrackingStatus::Ok);
        // A lens covered 0.3 m away, looking where the reference looked.
        let mut covered = box_frame(k, &reference_pose);
        covered.depth.iter_mut().for_each(|d| *d = 0.3);
        covered.rgb.iter_mut().for_each(|c| *c = [0.4; 3]);
        let (s, _, _) = status(&map, &covered, &reference_pose);
        assert!(
            matches!(s, TrackingStatus::Lost(LostReason::DepthResidual { .. })),
            "{s:?}"
        );
    }
}
