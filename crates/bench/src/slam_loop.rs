//! The scripted SLAM loop: the simulator drives a fixed loop of actions through a procedural
//! house; SLAM sees only the frames and the commanded actions (as a motion prior); the true
//! poses go to the metrics only (SPEC §1). SLAM runs through
//! [`activemap_slam::LockstepSlam`], i.e. the tracking and mapping sessions the `tracker` and
//! `mapper` operators hold, fed frame by frame in the operators' order with their map lag.
//!
//! The loop: laps of a rectangle inset `margin` metres inside the room the house starts in,
//! each side `forward` steps then 18 × 5° left turns, until `frames` frames. The SLAM world is
//! anchored where the tracker's config anchors it (the `tracker` operator: the robot's start
//! at the planar origin, floor at z = 0); the metrics map the true poses into that frame
//! through the known start (a rigid transform, no fitting), and ATE is still reported after
//! Umeyama alignment (SPEC §8).
//! Metrics (from `activemap-eval`, SPEC §8): ATE RMSE over all frames ([`activemap_eval::ate`],
//! Umeyama SE(3) alignment), training-view PSNR (map rendered at the estimated keyframe poses
//! against the keyframe images), held-out PSNR (map rendered at poses never given to SLAM:
//! every `held_out_every`-th loop pose shifted 2.5 cm forward and turned 2.5°, against the
//! simulator's image there) and held-out depth MAE (SPEC §8, the un-normalised rendered depth as
//! the evaluator reads it), tracking frames per second, mapping seconds per keyframe, the
//! Gaussian count, and the surface offset of the final map (issue 33,
//! [`activemap_eval::offset`]: the Gaussian centres, mapped into the true frame through the known
//! start, against samples of the house's mesh every ~2 cm, normals turned towards the true
//! camera centres).

use activemap_eval::{AteOptions, ImageView};
use activemap_geometry::tum::Trajectory;
use activemap_geometry::{Isometry3, PlanarPose};
use activemap_sim::house::{HouseConfig, generate};
use activemap_sim::{Action, NoiseConfig, SimConfig, Simulator};
use activemap_slam::{Frame, LockstepSlam, MotionPrior, SlamConfig};
use activemap_splat::{Camera, DepthModel, FLAG_UNKNOWN_SPACE, Gaussians, RenderOptions, render};
use anyhow::Context as _;

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
    /// SLAM settings (the benchmark passes the dataflow's tracker and mapper settings).
    pub slam: SlamConfig,
    /// Keep every frame, action and estimate in the result's [`LoopTrace`] (for the
    /// equivalence test against the operators; costs memory).
    pub keep_trace: bool,
    /// Sensor and actuation noise of the simulator (none by default; `activemap bench slam
    /// --noise realistic` sets the `realistic` preset). The tracker's motion prior stays the
    /// commanded action, so actuation noise is error it must correct; the held-out views are
    /// rendered noise-free.
    pub noise: NoiseConfig,
    /// Seed of the noise streams.
    pub noise_seed: u64,
    /// Print one line per frame to stderr (status, iterations, keyframe, pose error against the
    /// truth in the shared start-anchored frame), for diagnosis.
    pub trace: bool,
}

impl LoopConfig {
    /// A loop of `frames` frames at `resolution`² with the given SLAM settings.
    pub fn new(resolution: u32, frames: usize, slam: SlamConfig) -> Self {
        Self {
            resolution,
            frames,
            house_seed: 3,
            margin: 0.7,
            held_out_every: 10,
            slam,
            keep_trace: false,
            noise: NoiseConfig::none(),
            noise_seed: 1,
            trace: false,
        }
    }
}

/// The benchmark's image-size profile: where a node config leaves the resolution of tracking or
/// mapping unset (`None`), track at half resolution above 160 px and map keyframes at half
/// resolution above 200 px (the same `downscale` settings the operators take).
pub fn resolution_profile(
    resolution: u32,
    tracking_downscale: Option<usize>,
    mapping_downscale: Option<usize>,
) -> (usize, usize) {
    (
        tracking_downscale.unwrap_or(if resolution > 160 { 2 } else { 1 }),
        mapping_downscale.unwrap_or(if resolution > 200 { 2 } else { 1 }),
    )
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
    /// Mean depth MAE at held-out poses (un-normalised rendered depth, SPEC §8), centimetres.
    pub depth_mae_test_cm: f64,
    /// Signed offset of the final map's Gaussian centres from the true surface (issue 33).
    pub surface: activemap_eval::SurfaceOffsets,
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
    /// Lost frames at the end of the loop that no tracked frame followed (0: every loss was
    /// recovered).
    pub lost_unrecovered: usize,
}

/// What SLAM saw and estimated, frame by frame (with [`LoopConfig::keep_trace`]).
#[derive(Debug, Clone, Default)]
pub struct LoopTrace {
    /// The frames, in order.
    pub frames: Vec<Frame>,
    /// The action taken after each frame but the last.
    pub actions: Vec<Action>,
    /// The estimates, one per frame.
    pub estimates: Vec<activemap_slam::TrackedFrame>,
    /// The final map.
    pub map: Gaussians<f32>,
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

/// PSNR of the map's colour render at `pose` against `frame`, and depth MAE of its depth render
/// (un-normalised, as the evaluator reads it) in metres.
fn view_errors(
    map: &Gaussians<f32>,
    depth: DepthModel,
    frame: &Frame,
    pose: &Isometry3<f64>,
) -> anyhow::Result<(f64, f64)> {
    let camera = Camera::from_world_pose(frame.intrinsics, pose);
    let out = render(
        map,
        &camera,
        &RenderOptions {
            exposure: [0.0, 0.0],
            exclude_flags: FLAG_UNKNOWN_SPACE,
            depth,
        },
    )?;
    let rendered: Vec<f32> = out
        .colour
        .iter()
        .flat_map(|c| c.map(|v| v.clamp(0.0, 1.0)))
        .collect();
    let (width, height) = (frame.width(), frame.height());
    let psnr = activemap_eval::psnr(
        ImageView::rgb(&rendered, width, height)?,
        ImageView::rgb(frame.rgb.as_flattened(), width, height)?,
        1.0,
    )?;
    let depth = activemap_eval::depth_mae(
        ImageView::depth(&out.depth, width, height)?,
        ImageView::depth(&frame.depth, width, height)?,
    )?;
    Ok((psnr, depth))
}

/// Spacing of the ground-truth surface samples of the surface offset, metres.
const SURFACE_SAMPLE_SPACING_M: f64 = 0.02;
/// Most ground-truth surface samples of the surface offset.
const SURFACE_SAMPLES_MAX: usize = 3_000_000;

/// The surface offsets of `map` (SLAM frame) against `sim`'s scene, with `true_from_slam`
/// taking the map into the scene's frame and the normals turned towards `cameras` (true camera
/// centres).
fn map_surface_offsets(
    map: &Gaussians<f32>,
    sim: &Simulator,
    true_from_slam: &Isometry3<f64>,
    cameras: &[nalgebra::Point3<f64>],
) -> anyhow::Result<activemap_eval::SurfaceOffsets> {
    let scene = sim.scene();
    let count = ((scene.surface_area() / SURFACE_SAMPLE_SPACING_M.powi(2)) as usize)
        .clamp(1, SURFACE_SAMPLES_MAX);
    let (samples, mut normals): (Vec<_>, Vec<_>) =
        activemap_sim::ground_truth::oriented_surface_samples(scene, count, 0)
            .into_iter()
            .map(|s| (s.point, s.normal))
            .unzip();
    activemap_eval::orient_towards(&samples, &mut normals, cameras);
    let ceiling_z = samples
        .iter()
        .map(|p| p.z)
        .fold(f64::NEG_INFINITY, f64::max);
    let centres: Vec<_> = map
        .means
        .iter()
        .map(|m| true_from_slam * nalgebra::Point3::from(m.map(f64::from)))
        .collect();
    let weights: Vec<f64> = (0..map.len())
        .map(|i| {
            if map.flags[i] & FLAG_UNKNOWN_SPACE != 0 {
                0.0
            } else {
                map.opacity(i)
            }
        })
        .collect();
    Ok(activemap_eval::surface_offsets(
        &centres,
        &weights,
        &samples,
        &normals,
        sim.navigation().floor_z(),
        ceiling_z,
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
    sim.config()
        .robot
        .camera_pose(&shifted, sim.navigation().floor_z())
}

/// Runs the scripted loop and measures it (see the module doc).
pub fn run_loop(config: &LoopConfig) -> anyhow::Result<LoopResult> {
    Ok(run_loop_traced(config)?.0)
}

/// [`run_loop`], also returning the trace when [`LoopConfig::keep_trace`] is set.
pub fn run_loop_traced(config: &LoopConfig) -> anyhow::Result<(LoopResult, LoopTrace)> {
    let house = generate(config.house_seed, &HouseConfig::default())?;
    let room = *house.start_room().context("the house has no room")?;
    let (start, actions) = rectangle_loop(room.min, room.max, config.margin, config.frames);
    let sim_config = SimConfig {
        start: Some(start),
        noise: config.noise,
        seed: config.noise_seed,
        ..SimConfig::with_resolution(config.resolution, config.resolution)
    };
    let robot = sim_config.robot;
    let mut sim = Simulator::new(house.scene, sim_config)?;
    // True poses into the SLAM frame: the true start maps onto the anchor.
    let slam_from_true = config.slam.tracking.initial_pose * sim.true_pose().inverse();
    let mut slam = LockstepSlam::new(config.slam.clone())?;
    let mut trace = LoopTrace::default();
    let (mut truth, mut estimate) = (Trajectory::default(), Trajectory::default());
    let (mut track_seconds, mut tracked, mut lost) = (0.0, 0usize, 0usize);
    let mut lost_in_row = 0usize;
    let mut held_out = Vec::new();
    for i in 0..config.frames {
        let motion = if i == 0 {
            MotionPrior::None
        } else {
            let action = actions[(i - 1).min(actions.len().saturating_sub(1))];
            if config.keep_trace {
                trace.actions.push(action);
            }
            sim.step(action);
            MotionPrior::Relative(robot.camera_motion(action))
        };
        let rgbd = sim.render();
        let frame = Frame::from_rgb8(rgbd.intrinsics, &rgbd.rgb, rgbd.depth, i as f64 * 0.1)?;
        let stamp = frame.stamp;
        let keyframes_before = slam.keyframe_events().len();
        if config.keep_trace {
            trace.frames.push(frame.clone());
        }
        let out = slam.process(frame, motion)?;
        if i > 0 {
            track_seconds += out.seconds;
            tracked += 1;
        }
        if out.status.is_lost() {
            lost += 1;
            lost_in_row += 1;
        } else {
            lost_in_row = 0;
        }
        if config.trace {
            let true_here = slam_from_true * sim.true_pose();
            let (t, a) = activemap_geometry::se3::pose_error(&out.pose, &true_here);
            eprintln!(
                "frame {i:4} {:?} it {:2} keyframes done {} track {:.3}s err {:.2} cm {:.2}° truth {:.3?} est {:.3?} {:?}",
                out.status,
                out.iterations,
                slam.keyframe_events().len() - keyframes_before,
                out.seconds,
                t * 100.0,
                a.to_degrees(),
                true_here.translation.vector.as_slice(),
                out.pose.translation.vector.as_slice(),
                out.residuals
            );
        }
        truth.push(stamp, sim.true_pose());
        estimate.push(stamp, out.pose);
        if i % config.held_out_every.max(1) == config.held_out_every / 2 {
            held_out.push(held_out_pose(&sim));
        }
        if config.keep_trace {
            trace.estimates.push(out);
        }
    }
    let (mapping, events) = slam.finish()?;
    let map_seconds: f64 = events.iter().map(|(_, e)| e.seconds).sum();
    let ate_rmse = activemap_eval::ate(&truth, &estimate, AteOptions::default())?.rmse;
    let map = mapping.map();
    let keyframes = mapping.mapper().keyframes();
    let depth_model = mapping.mapper().config().depth_model;
    let mut train = Vec::new();
    for kf in keyframes {
        train.push(view_errors(map, depth_model, &kf.frame, &kf.pose)?.0);
    }
    let (mut test, mut test_depth) = (Vec::new(), Vec::new());
    for pose in &held_out {
        let rgbd = sim.render_at(pose);
        let frame = Frame::from_rgb8(rgbd.intrinsics, &rgbd.rgb, rgbd.depth, 0.0)?;
        let (psnr, depth) = view_errors(map, depth_model, &frame, &(slam_from_true * pose))?;
        test.push(psnr);
        test_depth.push(depth);
    }
    let cameras: Vec<_> = truth
        .poses
        .iter()
        .map(|p| nalgebra::Point3::from(p.translation.vector))
        .collect();
    let surface = map_surface_offsets(map, &sim, &slam_from_true.inverse(), &cameras)?;
    let mean = |v: &[f64]| {
        if v.is_empty() {
            f64::NAN
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    };
    if config.keep_trace {
        trace.map = map.clone();
    }
    let result = LoopResult {
        frames: config.frames,
        ate_cm: ate_rmse * 100.0,
        psnr_train: mean(&train),
        psnr_test: mean(&test),
        depth_mae_test_cm: mean(&test_depth) * 100.0,
        surface,
        track_fps: if track_seconds > 0.0 {
            tracked as f64 / track_seconds
        } else {
            f64::NAN
        },
        map_seconds_per_keyframe: map_seconds / keyframes.len().max(1) as f64,
        gaussians: map.len(),
        keyframes: keyframes.len(),
        lost,
        lost_unrecovered: lost_in_row,
    };
    Ok((result, trace))
}

/// The value of environment variable `name` parsed as `T`, else `default`: the knobs of the
/// development drivers (`RES`, `FRAMES`, …) in the scripted-loop and mapping-quality tests.
pub fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}
