//! A partly explored house, built deterministically with the product's own pieces, for the
//! Fisher benchmarks (`activemap bench scorer`, `activemap bench eig-psnr`):
//!
//! - the trajectory: an FBE episode of the in-process [`Explorer`] (the operators' occupancy,
//!   frontier, planner, scorer and follower pieces) on the simulator's `house:<seed>`, with the
//!   simulator's collisions and slides;
//! - the map: every frame goes to the mapping session's [`KeyframeMapper`] (the keyframe rule,
//!   the mapper's own Gaussian insertion, window optimisation, pruning and densification), with
//!   the mapping settings the caller passes (the CLI takes the flow's `mapper` node);
//!   [`HouseMapConfig::insert_fraction`] only changes the insertion's sampling density through
//!   its config, to reach a large map in fewer frames;
//! - the grid: the occupancy mapper of the planning library (what the `occupancy` operator
//!   runs): each frame's depth rays plus the map's Gaussian means, reloaded after every
//!   keyframe as the operator reloads each new map snapshot.
//!
//! Poses are the simulator's TRUE ones: these benchmarks measure the scorer, not localisation.
//! With [`HouseMapConfig::tracking`] a tracking session also tracks every frame (the commanded
//! action as its motion prior, the map of the frame before as its snapshot), without steering
//! anything: `activemap bench clocal-error` moves it on from the last frame. The build stops when the map holds
//! [`HouseMapConfig::target_gaussians`], after [`HouseMapConfig::max_steps`], or when no
//! frontier is left.

use std::sync::Arc;
use std::time::Instant;

use activemap_active::scorer::ScoringMap;
use activemap_active::{GoalRequest, ReplanInput};
use activemap_geometry::Isometry3;
use activemap_planning::OccupancyGrid;
use activemap_planning::dynamics::Action;
use activemap_policy::explorer::{Decision, Explorer, ExplorerConfig};
use activemap_sim::NoiseConfig;
use activemap_sim::{Action as SimAction, SceneSpec, SimConfig, Simulator};
use activemap_slam::{
    Frame, KeyframeMapper, MappingConfig, MotionPrior, PoseQuality, TrackingConfig, TrackingSession,
};
use activemap_splat::Gaussians;
use anyhow::Context as _;
use nalgebra::Point2;

/// How to build the house map.
#[derive(Debug, Clone, PartialEq)]
pub struct HouseMapConfig {
    /// The house seed (`house:<seed>`).
    pub house: u64,
    /// Square camera image side, pixels (90° hfov).
    pub resolution: u32,
    /// Step budget of the exploration.
    pub max_steps: usize,
    /// Stop as soon as the map holds at least this many Gaussians (`None`: run the budget).
    pub target_gaussians: Option<usize>,
    /// The mapping session's settings (keyframe rule, insertion, optimisation).
    pub mapping: MappingConfig,
    /// Insertion sampling fraction of the unobserved depth pixels, overriding the mapper's
    /// default density (`None`: the mapper's own, SPEC's 1/64 at 640×480, i.e. about 0.19 at
    /// 160²); the per-keyframe cap is raised to one Gaussian per pixel.
    pub insert_fraction: Option<f64>,
    /// The exploration loop's settings (the operators' defaults).
    pub explorer: ExplorerConfig,
    /// Print progress to stderr every this many steps (0: never).
    pub progress_every: usize,
    /// Sensor and actuation noise of the simulator (none by default), seeded by `seed`.
    pub noise: NoiseConfig,
    /// The simulator's noise seed.
    pub seed: u64,
    /// A tracking session to run beside the build (its `initial_pose` is replaced by the
    /// simulator's first true pose, so estimates and truth share a frame); `None`: none.
    pub tracking: Option<TrackingConfig>,
}

impl HouseMapConfig {
    /// A house map of `house:<house>` at `resolution`² with the mapping settings `mapping`,
    /// at most `max_steps` steps.
    pub fn new(house: u64, resolution: u32, max_steps: usize, mapping: MappingConfig) -> Self {
        Self {
            house,
            resolution,
            max_steps,
            target_gaussians: None,
            mapping,
            insert_fraction: None,
            explorer: ExplorerConfig::default(),
            progress_every: 0,
            noise: NoiseConfig::default(),
            seed: 0,
            tracking: None,
        }
    }

    /// The mapping settings with [`Self::insert_fraction`] applied.
    pub fn effective_mapping(&self) -> anyhow::Result<MappingConfig> {
        let mut mapping = self.mapping.clone();
        if let Some(f) = self.insert_fraction {
            anyhow::ensure!(
                f.is_finite() && f > 0.0 && f <= 1.0,
                "insert fraction must be in (0, 1], got {f}"
            );
            let insert = &mut mapping.mapper.insert;
            insert.sample_fraction = f;
            insert.target_samples = 0;
            let pixels = self.resolution as usize * self.resolution as usize;
            insert.max_per_keyframe = insert.max_per_keyframe.max(pixels);
        }
        mapping.validate().context("house map: mapping settings")?;
        Ok(mapping)
    }
}

/// The built house: the simulator (at the last pose, for ground-truth renders), the map with
/// its ids, the occupancy grid and the last camera pose.
pub struct HouseMap {
    /// The simulator, still at the pose of the last frame.
    pub sim: Simulator,
    /// The map's Gaussians.
    pub gaussians: Arc<Gaussians<f32>>,
    /// The mapper's stable id of each Gaussian.
    pub ids: Arc<Vec<u64>>,
    /// The occupancy grid after the last frame (its depth and the final map's points).
    pub grid: OccupancyGrid,
    /// The camera pose `T_world_camera` of the last frame (the simulator's true pose).
    pub pose: Isometry3<f64>,
    /// Id of the last frame (frames are numbered from 0).
    pub frame_id: u64,
    /// Frames rendered and mapped.
    pub frames: usize,
    /// Keyframes the mapper took.
    pub keyframes: usize,
    /// Frame id and camera pose (the simulator's true one, as every pose of the build) of each
    /// frame the mapper mapped, in order (for the `keyframes` model Fisher).
    pub keyframe_poses: Vec<(u64, Isometry3<f64>)>,
    /// Whether the exploration ran out of frontiers.
    pub finished: bool,
    /// Wall-clock seconds of the whole build.
    pub build_seconds: f64,
    /// Of which in the mapper.
    pub mapping_seconds: f64,
    /// The settings it was built with (insertion density applied).
    pub mapping: MappingConfig,
    /// The tracking session after the last frame ([`HouseMapConfig::tracking`]).
    pub tracking: Option<TrackingSession>,
    /// The scene and simulator settings of the build, for simulators of the same house.
    pub scene: SceneSpec,
    /// The simulator settings of the build.
    pub sim_config: SimConfig,
}

impl HouseMap {
    /// The map as the scorer takes it (the Gaussians with their ids, at the last frame).
    pub fn scoring_map(&self) -> ScoringMap {
        ScoringMap {
            gaussians: self.gaussians.clone(),
            ids: self.ids.clone(),
            frame_id: self.frame_id,
        }
    }

    /// A replan of the last frame on this house's grid and pose, with `map` (from
    /// [`Self::scoring_map`]) and `goal`.
    pub fn replan_input<'a>(&'a self, map: &'a ScoringMap, goal: GoalRequest) -> ReplanInput<'a> {
        ReplanInput {
            frame_id: self.frame_id,
            grid: &self.grid,
            pose: self.pose,
            map,
            goal,
        }
    }

    /// One line saying how the map was built (for the benchmarks' headers).
    pub fn describe(&self, config: &HouseMapConfig) -> String {
        let insert = &self.mapping.mapper.insert;
        let density = match config.insert_fraction {
            Some(f) => format!("insertion fraction {f} (denser than the mapper's default)"),
            None => format!(
                "the mapper's default insertion ({} samples per full image)",
                insert.target_samples
            ),
        };
        let tracked = match &self.tracking {
            Some(_) => "; a tracking session tracked every frame beside it",
            None => " (no SLAM tracking: the benchmark times the planning, not localisation)",
        };
        format!(
            "house:{} at {res}×{res}: FBE exploration with the simulator's TRUE poses{tracked}, \
             {} frames, {} keyframes, {} Gaussians, {density}; built in {:.1} s ({:.1} s mapping){}",
            config.house,
            self.frames,
            self.keyframes,
            self.gaussians.len(),
            self.build_seconds,
            self.mapping_seconds,
            if self.finished {
                "; no frontier left"
            } else {
                ""
            },
            res = config.resolution,
        )
    }
}

/// The map points the occupancy operator reads from a map: means and post-sigmoid opacities.
fn map_points(map: &Gaussians<f32>) -> (Vec<[f32; 3]>, Vec<f32>) {
    let opacities = (0..map.len()).map(|i| map.opacity(i) as f32).collect();
    (map.means.clone(), opacities)
}

/// Builds the house map (see the module doc).
pub fn build(config: &HouseMapConfig) -> anyhow::Result<HouseMap> {
    anyhow::ensure!(
        config.max_steps > 0,
        "house map: the step budget must be > 0"
    );
    anyhow::ensure!(
        (16..=4096).contains(&config.resolution),
        "house map: the resolution must be in 16..=4096, got {}",
        config.resolution
    );
    let started = Instant::now();
    let mapping = config.effective_mapping()?;
    let scene = format!("house:{}", config.house);
    let spec = SceneSpec::new(scene.clone());
    let mut sim_config = SimConfig::with_resolution(config.resolution, config.resolution);
    sim_config.noise = config.noise;
    sim_config.seed = config.seed;
    let mut sim = spec
        .simulator(sim_config.clone())
        .with_context(|| format!("house map: scene {scene}"))?;
    let mut tracking = match &config.tracking {
        Some(t) => Some(TrackingSession::new(TrackingConfig {
            initial_pose: sim.true_pose(),
            ..t.clone()
        })?),
        None => None,
    };
    let robot = sim_config.robot;
    let mut snapshot = Arc::new(Gaussians::new());
    let k = sim.config().intrinsics;
    let start = sim.true_planar_pose();
    // The occupancy operator's initial extent, ±2 m around the start.
    let mut explorer = Explorer::new(
        config.explorer,
        Point2::new(start.x - 2.0, start.y - 2.0),
        Point2::new(start.x + 2.0, start.y + 2.0),
    )?;
    let mut mapper = KeyframeMapper::new(mapping.clone())?;
    let mut mapping_seconds = 0.0;
    let mut finished = false;
    let mut frames = 0usize;
    let mut pose = sim.true_pose();
    let mut keyframe_poses = Vec::new();
    for step in 0..config.max_steps {
        let rgbd = sim.render();
        pose = sim.true_pose();
        frames += 1;
        let decision = explorer.step(&rgbd.depth, &k, &pose)?;
        let frame = Frame::from_rgb8(rgbd.intrinsics, &rgbd.rgb, rgbd.depth, step as f64 * 0.1)?;
        if let Some(session) = &mut tracking {
            session.add_frame(step as u64, frame.clone());
            if step > 0 {
                session.add_map(step as u64 - 1, snapshot.clone());
            }
            session.process_ready()?;
        }
        let t = Instant::now();
        let report = mapper.process(None, frame, &pose, PoseQuality::Ok)?;
        mapping_seconds += t.elapsed().as_secs_f64();
        if report.is_some() && tracking.is_some() {
            snapshot = Arc::new(mapper.map().clone());
        }
        if report.is_some() {
            keyframe_poses.push((step as u64, pose));
            let (means, opacities) = map_points(mapper.map());
            explorer.mapper_mut().set_map_points(&means, &opacities)?;
        }
        if config.progress_every > 0 && (step + 1) % config.progress_every == 0 {
            eprintln!(
                "house map: step {} keyframes {} gaussians {} ({:.0} s)",
                step + 1,
                mapper.keyframes(),
                mapper.map().len(),
                started.elapsed().as_secs_f64()
            );
        }
        if config
            .target_gaussians
            .is_some_and(|n| mapper.map().len() >= n)
        {
            break;
        }
        let action = match decision {
            Decision::Finished => {
                finished = true;
                break;
            }
            Decision::Act(a) => a,
        };
        if step + 1 == config.max_steps {
            break;
        }
        if let Some(session) = &mut tracking {
            session.add_motion(
                step as u64,
                MotionPrior::Relative(robot.camera_motion(action)),
            );
        }
        sim.step(match action {
            Action::Forward => SimAction::Forward,
            Action::TurnLeft => SimAction::TurnLeft,
            Action::TurnRight => SimAction::TurnRight,
        });
    }
    // The grid of the last frame with the final map's points (the footprint already marked).
    let grid = explorer.mapper_mut().grid();
    let keyframes = mapper.keyframes();
    let ids = mapper.mapper().ids().to_vec();
    let gaussians = mapper.map().clone();
    Ok(HouseMap {
        sim,
        gaussians: Arc::new(gaussians),
        ids: Arc::new(ids),
        grid,
        pose,
        frame_id: frames.saturating_sub(1) as u64,
        frames,
        keyframes,
        keyframe_poses,
        finished,
        build_seconds: started.elapsed().as_secs_f64(),
        mapping_seconds,
        mapping,
        tracking,
        scene: spec,
        sim_config,
    })
}
