//! Scripted-trajectory evaluation (issue 5): the simulator drives a fixed loop of actions
//! through a procedural house; SLAM sees only the frames and the commanded actions (as a
//! motion prior); the true poses go to the metrics only (SPEC §1).
//!
//! The loop: laps of a rectangle inset `margin` metres inside the room the house starts in,
//! each side `forward` steps then 18 × 5° left turns, until `frames` frames. The world is
//! anchored at the true start pose (the robot's known origin), so the map and the truth share
//! a frame up to drift; ATE is still reported after Umeyama alignment (SPEC §8).
//! Metrics (from `activemap-eval`, SPEC §8): ATE RMSE over all frames ([`activemap_eval::ate`],
//! Umeyama SE(3) alignment), training-view PSNR (map rendered
//! at the estimated keyframe poses against the keyframe images), held-out PSNR (map rendered
//! at poses never given to SLAM: every `held_out_every`-th loop pose shifted 2.5 cm forward
//! and turned 2.5°, against the simulator's image there), tracking frames per second, mapping
//! seconds per keyframe and the Gaussian count.

use crate::error::SlamError;
use crate::frame::Frame;
use crate::slam::{MotionPrior, Slam, SlamConfig};
use crate::tracker::TrackingStatus;
use activemap_eval::{AteOptions, ImageView};
use activemap_geometry::tum::Trajectory;
use activemap_geometry::{Isometry3, PlanarPose, UnitQuaternion, Vector3, camera_pose_from_planar};
use activemap_sim::house::{HouseConfig, generate};
use activemap_sim::{Action, SimConfig, Simulator};
use activemap_splat::{Camera, FLAG_UNKNOWN_SPACE, Gaussians, RenderOptions, render};
use nalgebra::Translation3;

/// Settings of one scripted loop.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopConfig {
    /// Square image side, pixels (90° FOV).
    pub resolution: u32,
    /// Frames to run.
    pub frames: usize,
    /// Procedural house seed.
    pub house_seed: u64,
    /// Inset of the loop from the room's walls, metres.
    pub margin: f64,
    /// Held-out view every this many frames.
    pub held_out_every: usize,
    /// SLAM settings.
    pub slam: SlamConfig,
    /// Print one line per frame to stderr (status, iterations, keyframe, pose error against the
    /// truth in the shared start-anchored frame), for diagnosis.
    pub trace: bool,
}

impl LoopConfig {
    /// Defaults for a resolution and length: tracking at half resolution above 160 px.
    pub fn new(resolution: u32, frames: usize) -> Self {
        let mut slam = SlamConfig::default();
        slam.tracker.downscale = if resolution > 160 { 2 } else { 1 };
        slam.mapping_downscale = if resolution > 200 { 2 } else { 1 };
        slam.tracker.dense = slam.tracker.dense.for_ground_robot();
        Self {
            resolution,
            frames,
            house_seed: 3,
            margin: 0.7,
            held_out_every: 10,
            slam,
            trace: false,
        }
    }
}

/// Metrics of one scripted loop.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopResult {
    /// Frames processed.
    pub frames: usize,
    /// ATE RMSE after Umeyama alignment, centimetres.
    pub ate_cm: f64,
    /// Mean PSNR at the keyframes (estimated poses), dB.
    pub psnr_train: f64,
    /// Mean PSNR at held-out poses, dB.
    pub psnr_test: f64,
    /// Tracked frames per second (tracking wall time only).
    pub track_fps: f64,
    /// Mean mapping wall time per keyframe, seconds.
    pub map_seconds_per_keyframe: f64,
    /// Final number of Gaussians.
    pub gaussians: usize,
    /// Keyframes taken.
    pub keyframes: usize,
    /// Frames reported lost.
    pub lost: usize,
}

/// The commanded motion of the camera for an action, `T_prev_current` in the optical frame:
/// forward moves along +z, a left turn rotates by −angle about the optical y axis (y points
/// down, so that is +angle about the world's up axis).
pub fn commanded_motion(action: Action, forward_step: f64, turn_angle: f64) -> Isometry3<f64> {
    match action {
        Action::Forward => Isometry3::from_parts(
            Translation3::new(0.0, 0.0, forward_step),
            UnitQuaternion::identity(),
        ),
        Action::TurnLeft => Isometry3::from_parts(
            Translation3::identity(),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -turn_angle),
        ),
        Action::TurnRight => Isometry3::from_parts(
            Translation3::identity(),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), turn_angle),
        ),
    }
}

/// The start pose and the action list of a rectangular loop in the rectangle `[min, max]`.
pub fn rectangle_loop(
    min: [f64; 2],
    max: [f64; 2],
    margin: f64,
    frames: usize,
) -> (PlanarPose, Vec<Action>) {
    let (x0, y0, x1, y1) = (
        min[0] + margin,
        min[1] + margin,
        max[0] - margin,
        max[1] - margin,
    );
    let sides = [((x1 - x0).max(0.0)), ((y1 - y0).max(0.0))];
    let mut actions = Vec::with_capacity(frames);
    let mut side = 0;
    while actions.len() < frames {
        let steps = (sides[side % 2] / 0.05).round() as usize;
        actions.extend(std::iter::repeat_n(Action::Forward, steps.max(1)));
        actions.extend(std::iter::repeat_n(Action::TurnLeft, 18));
        side += 1;
    }
    actions.truncate(frames.saturating_sub(1));
    (PlanarPose::new(x0, y0, 0.0), actions)
}

fn colour_psnr(
    map: &Gaussians<f32>,
    frame: &Frame,
    pose: &Isometry3<f64>,
) -> Result<f64, SlamError> {
    let camera = Camera::from_world_pose(frame.intrinsics, pose);
    let out = render(
        map,
        &camera,
        &RenderOptions {
            exposure: [0.0, 0.0],
            exclude_flags: FLAG_UNKNOWN_SPACE,
        },
    )?;
    let rendered: Vec<f32> = out
        .colour
        .iter()
        .flat_map(|c| c.map(|v| v.clamp(0.0, 1.0)))
        .collect();
    let (width, height) = (frame.width(), frame.height());
    Ok(activemap_eval::psnr(
        ImageView::rgb(&rendered, width, height)?,
        ImageView::rgb(frame.rgb.as_flattened(), width, height)?,
        1.0,
    )?)
}

/// The held-out view near the simulator's current pose: 2.5 cm forward and turned 2.5° left
/// (a `T_world_camera` SLAM never saw), for held-out PSNR.
pub fn held_out_pose(sim: &Simulator) -> Isometry3<f64> {
    let p = sim.true_planar_pose();
    let shifted = PlanarPose::new(
        p.x + 0.025 * p.yaw.cos(),
        p.y + 0.025 * p.yaw.sin(),
        p.yaw + 2.5f64.to_radians(),
    );
    camera_pose_from_planar(
        &shifted,
        sim.navigation().floor_z(),
        sim.config().camera_height,
    )
}

/// Runs the scripted loop and measures it (see the module doc).
pub fn run_loop(config: &LoopConfig) -> Result<LoopResult, SlamError> {
    let house = generate(config.house_seed, &HouseConfig::default())?;
    let room = *house.start_room().ok_or_else(|| SlamError::Input {
        what: "house",
        reason: "no room".into(),
    })?;
    let (start, actions) = rectangle_loop(room.min, room.max, config.margin, config.frames);
    let sim_config = SimConfig {
        start: Some(start),
        ..SimConfig::with_resolution(config.resolution, config.resolution)
    };
    let (forward, turn) = (sim_config.forward_step, sim_config.turn_angle);
    let mut sim = Simulator::new(house.scene, sim_config)?;
    let mut slam_config = config.slam.clone();
    slam_config.initial_pose = sim.true_pose();
    let mut slam = Slam::new(slam_config)?;
    let (mut truth, mut estimate) = (Trajectory::default(), Trajectory::default());
    let (mut track_seconds, mut tracked, mut map_seconds, mut lost) = (0.0, 0usize, 0.0, 0usize);
    let mut held_out = Vec::new();
    for i in 0..config.frames {
        let motion = if i == 0 {
            MotionPrior::None
        } else {
            let action = actions[(i - 1).min(actions.len().saturating_sub(1))];
            sim.step(action);
            MotionPrior::Relative(commanded_motion(action, forward, turn))
        };
        let rgbd = sim.render();
        let frame = Frame::from_rgb8(rgbd.intrinsics, &rgbd.rgb, rgbd.depth, i as f64 * 0.1)?;
        let out = slam.process(&frame, motion)?;
        if i > 0 {
            track_seconds += out.track_seconds;
            tracked += 1;
        }
        map_seconds += out.map_seconds;
        if out.status == TrackingStatus::Lost {
            lost += 1;
        }
        if config.trace {
            let (t, a) = activemap_geometry::se3::pose_error(&out.pose, &sim.true_pose());
            eprintln!(
                "frame {i:4} {:?} it {:2} kf {} track {:.3}s map {:.2}s err {:.2} cm {:.2}° truth {:.3?} est {:.3?} {:?}",
                out.status,
                out.iterations,
                out.map_updated,
                out.track_seconds,
                out.map_seconds,
                t * 100.0,
                a.to_degrees(),
                sim.true_pose().translation.vector.as_slice(),
                out.pose.translation.vector.as_slice(),
                out.residuals
            );
        }
        truth.push(frame.stamp, sim.true_pose());
        estimate.push(frame.stamp, out.pose);
        if i % config.held_out_every.max(1) == config.held_out_every / 2 {
            held_out.push(held_out_pose(&sim));
        }
    }
    let ate_rmse = activemap_eval::ate(&truth, &estimate, AteOptions::default())?.rmse;
    let map = slam.map();
    let keyframes = slam.mapper().keyframes();
    let mut train = Vec::new();
    for kf in keyframes {
        train.push(colour_psnr(map, &kf.frame, &kf.pose)?);
    }
    let mut test = Vec::new();
    for pose in &held_out {
        let rgbd = sim.render_at(pose);
        let frame = Frame::from_rgb8(rgbd.intrinsics, &rgbd.rgb, rgbd.depth, 0.0)?;
        test.push(colour_psnr(map, &frame, pose)?);
    }
    let mean = |v: &[f64]| {
        if v.is_empty() {
            f64::NAN
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    };
    Ok(LoopResult {
        frames: config.frames,
        ate_cm: ate_rmse * 100.0,
        psnr_train: mean(&train),
        psnr_test: mean(&test),
        track_fps: if track_seconds > 0.0 {
            tracked as f64 / track_seconds
        } else {
            f64::NAN
        },
        map_seconds_per_keyframe: map_seconds / keyframes.len().max(1) as f64,
        gaussians: map.len(),
        keyframes: keyframes.len(),
        lost,
    })
}

/// The value of environment variable `name` parsed as `T`, else `default`: the knobs of the
/// development drivers (`RES`, `FRAMES`, …) in the scripted-loop and mapping-quality tests.
pub fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}
