//! The simulator: a scene, an agent moving Habitat-style on its floor, and an RGB-D camera.

use crate::error::{Result, SimError};
use crate::navigation::{AgentShape, Navigation, estimate_floor_z};
use crate::noise::{ActuationNoiseSampler, NoiseConfig, SensorNoiseSampler};
use crate::render::{DepthRange, Renderer, RgbdFrame};
use crate::scene::Scene;
use activemap_geometry::{Intrinsics, Isometry3, PlanarPose, RobotModel, camera_pose_from_planar};

/// A discrete action, as in Habitat: the project's one robot action
/// ([`activemap_geometry::robot::Action`]); sizes from [`SimConfig::robot`].
pub use activemap_geometry::robot::Action;

/// What happened on a step (no pose: the true pose is ground truth, see [`Simulator::true_pose`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StepResult {
    /// The motion was obstructed (the agent stopped or slid).
    pub collided: bool,
}

/// Simulator settings. Defaults follow the paper's Habitat setup (SPEC §1).
#[derive(Debug, Clone, PartialEq)]
pub struct SimConfig {
    /// Camera image size and pinhole (default 800×800, 90° FOV).
    pub intrinsics: Intrinsics,
    /// Near plane and maximum depth reading.
    pub depth_range: DepthRange,
    /// The robot (camera height 0.88 m, radius 0.1 m, forward step 0.05 m, turn 5°): the one
    /// model the tracker, the planners and the evaluator read too.
    pub robot: RobotModel,
    /// Height and climb of the collision cylinder; its radius is the robot's
    /// ([`RobotModel::radius_m`]), whatever `agent.radius` says.
    pub agent: AgentShape,
    /// Slide along walls on an obstructed forward step (Habitat's default) instead of stopping.
    pub allow_sliding: bool,
    /// Navigable-map cell size, metres (0.05).
    pub nav_cell_size: f64,
    /// Sensor and actuation noise (none by default). Renders of [`Simulator::render_at`] stay
    /// noise-free; the true pose follows the noisy motion.
    pub noise: NoiseConfig,
    /// Seed of the noise: sensor and actuation draw from separate ChaCha8 streams of it
    /// ([`crate::noise::SENSOR_STREAM`], [`crate::noise::ACTUATION_STREAM`]).
    pub seed: u64,
    /// Floor height; `None` = the scene's own, else estimated from the mesh.
    pub floor_z: Option<f64>,
    /// Start pose; `None` = the scene's own, else derived from the navigable map.
    pub start: Option<PlanarPose>,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            intrinsics: Intrinsics::from_hfov(800, 800, std::f64::consts::FRAC_PI_2),
            depth_range: DepthRange::default(),
            robot: RobotModel::default(),
            agent: AgentShape::default(),
            allow_sliding: true,
            nav_cell_size: 0.05,
            noise: NoiseConfig::none(),
            seed: 0,
            floor_z: None,
            start: None,
        }
    }
}

impl SimConfig {
    /// The default configuration with a square image of `size` pixels at 90° FOV.
    pub fn with_resolution(width: u32, height: u32) -> Self {
        Self {
            intrinsics: Intrinsics::from_hfov(width, height, std::f64::consts::FRAC_PI_2),
            ..Self::default()
        }
    }

    pub(crate) fn validate(&self) -> Result<()> {
        let bad = |field, value: f64, reason| {
            Err(SimError::InvalidConfig {
                field,
                value: value.to_string(),
                reason,
            })
        };
        let k = &self.intrinsics;
        if k.width == 0 || k.height == 0 {
            return bad("intrinsics.width/height", 0.0, "image must be at least 1×1");
        }
        if !(k.fx.is_finite() && k.fy.is_finite() && k.fx != 0.0 && k.fy != 0.0) {
            return bad(
                "intrinsics.fx/fy",
                k.fx,
                "focal lengths must be finite and non-zero",
            );
        }
        if !self.depth_range.near.is_finite() || self.depth_range.near <= 0.0 {
            return bad("depth_range.near", self.depth_range.near, "must be > 0");
        }
        if self.depth_range.max_depth.is_nan()
            || self.depth_range.max_depth <= self.depth_range.near
        {
            return bad(
                "depth_range.max_depth",
                self.depth_range.max_depth,
                "must exceed near",
            );
        }
        if let Err(reason) = self.robot.validate() {
            return Err(SimError::InvalidConfig {
                field: "robot",
                value: reason,
                reason: "every robot field must be in range",
            });
        }
        self.noise.validate()
    }
}

/// The simulator: call [`Simulator::step`] with actions and [`Simulator::render`] for frames.
#[derive(Debug)]
pub struct Simulator {
    scene: Scene,
    config: SimConfig,
    navigation: Navigation,
    pose: PlanarPose,
    renderer: Renderer,
    sensor_noise: SensorNoiseSampler,
    actuation_noise: ActuationNoiseSampler,
    steps: u64,
}

impl Simulator {
    /// Builds the navigation for `scene` and places the agent at the start pose.
    pub fn new(scene: Scene, config: SimConfig) -> Result<Self> {
        config.validate()?;
        scene.validate()?;
        let floor_z = config
            .floor_z
            .or(scene.floor_z)
            .or_else(|| estimate_floor_z(&scene))
            .ok_or_else(|| SimError::NoNavigableArea(scene.name.clone()))?;
        let agent = AgentShape {
            radius: config.robot.radius_m,
            ..config.agent
        };
        let navigation = Navigation::build(&scene, floor_z, agent, config.nav_cell_size)?;
        if navigation.map().count() == 0 {
            return Err(SimError::NoNavigableArea(scene.name.clone()));
        }
        let pose = match config.start.or(scene.start) {
            Some(p) => p,
            None => navigation.derived_start(&scene.name)?,
        };
        if !navigation.is_navigable(pose.x, pose.y) {
            return Err(SimError::StartNotNavigable {
                x: pose.x,
                y: pose.y,
            });
        }
        Ok(Self {
            sensor_noise: SensorNoiseSampler::new(&config.noise, config.seed),
            actuation_noise: ActuationNoiseSampler::new(&config.noise, config.seed),
            scene,
            config,
            navigation,
            pose,
            renderer: Renderer::new(),
            steps: 0,
        })
    }

    /// Applies one action, with actuation noise if configured: the noisy motion goes through
    /// the collision model (stop or slide), and the true pose follows it.
    pub fn step(&mut self, action: Action) -> StepResult {
        self.steps += 1;
        match action {
            Action::Forward => {
                let (distance, dyaw) = self
                    .actuation_noise
                    .forward(self.config.robot.forward_step_m);
                // Travel along the chord of the arc: the old heading plus half the change.
                let along = PlanarPose {
                    yaw: self.pose.yaw + 0.5 * dyaw,
                    ..self.pose
                };
                let (pose, collided) =
                    self.navigation
                        .try_forward(&along, distance, self.config.allow_sliding);
                let yaw = if dyaw == 0.0 {
                    self.pose.yaw
                } else {
                    wrap_yaw(self.pose.yaw + dyaw)
                };
                self.pose = PlanarPose { yaw, ..pose };
                StepResult { collided }
            }
            Action::TurnLeft | Action::TurnRight => {
                let sign = if action == Action::TurnLeft {
                    1.0
                } else {
                    -1.0
                };
                let angle = self.actuation_noise.turn(self.config.robot.turn_angle_rad);
                self.pose.yaw = wrap_yaw(self.pose.yaw + sign * angle);
                StepResult { collided: false }
            }
        }
    }

    /// Renders RGB-D at the agent's true pose (with sensor noise, if configured).
    pub fn render(&mut self) -> RgbdFrame {
        let pose = self.true_pose();
        let mut frame = self.render_at(&pose);
        self.sensor_noise.apply(&mut frame);
        frame
    }

    /// Renders RGB-D at the agent's true pose (with sensor noise, if configured) straight into
    /// caller-owned buffers, e.g. a loaned shared-memory frame: `rgb` holds `3 × w × h` bytes,
    /// `depth` `w × h` metres. Same pixels as [`Simulator::render`]; no allocation once warm.
    pub fn render_into(&mut self, rgb: &mut [u8], depth: &mut [f32]) -> Result<()> {
        let pose = self.true_pose();
        self.renderer.render_into(
            &self.scene,
            &self.config.intrinsics,
            &pose,
            self.config.depth_range,
            rgb,
            depth,
        )?;
        self.sensor_noise
            .apply_to(rgb, depth, self.config.intrinsics.width as usize);
        Ok(())
    }

    /// Renders RGB-D (noise-free) from any camera pose `T_world_camera`, e.g. evaluation poses.
    pub fn render_at(&mut self, t_world_camera: &Isometry3<f64>) -> RgbdFrame {
        self.renderer.render(
            &self.scene,
            &self.config.intrinsics,
            t_world_camera,
            self.config.depth_range,
        )
    }

    /// Ground truth, for evaluation only: the camera pose `T_world_camera`.
    pub fn true_pose(&self) -> Isometry3<f64> {
        camera_pose_from_planar(
            &self.pose,
            self.navigation.floor_z(),
            self.config.robot.camera_height_m,
        )
    }

    /// Ground truth, for evaluation only: the agent's planar pose.
    pub fn true_planar_pose(&self) -> PlanarPose {
        self.pose
    }

    /// Moves the agent to `pose` (episode reset); refused if it is not navigable.
    pub fn set_planar_pose(&mut self, pose: PlanarPose) -> Result<()> {
        if !self.navigation.is_navigable(pose.x, pose.y) {
            return Err(SimError::StartNotNavigable {
                x: pose.x,
                y: pose.y,
            });
        }
        self.pose = pose;
        Ok(())
    }

    /// Number of actions applied so far.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// The scene.
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// The configuration.
    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    /// Floor, obstacles and navigable map.
    pub fn navigation(&self) -> &Navigation {
        &self.navigation
    }
}

/// Keeps a yaw in [−π, π).
fn wrap_yaw(yaw: f64) -> f64 {
    (yaw + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
}
