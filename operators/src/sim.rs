//! `sim`: the RGB-D simulator of `activemap-sim` as a dataflow node (SPEC §1 step 1).
//!
//! Lockstep (default): the first timer tick publishes frame 0 at the start pose; after that,
//! every `action` input is applied and answered with exactly one frame, so a seeded run is
//! reproducible. Real-time: every timer tick applies the latest action received (if any) and
//! publishes a frame. Each frame goes out as an [`RgbdFrame`](activemap_schemas::RgbdFrame)
//! written into a loaned shared-memory sample, with the ground-truth pose (evaluation only) and
//! the episode status. The episode ends at `max_steps` (config, or `--max-steps`) or on a
//! `Stop` action.

use activemap_geometry::Isometry3;
use activemap_geometry::RobotModel;
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, check_config_as,
};
use activemap_schemas::{
    Action, ActionKind, EpisodeState, EpisodeStatus, MessageKind as K, RgbdFrameHeader,
    RgbdFrameMut, TruePose,
};
use activemap_sim::{
    Floor, NoiseConfig, Placement, SceneSpec, SimConfig, Simulator, Transform, UpAxis,
};

use crate::Registered;
use crate::convert::pose_to_wire;

/// The noise-free simulator of `scene` at `width`×`height` pixels and `hfov_deg` with `robot`
/// (the `sim` node's camera and robot; the evaluator builds the same scene for its ground truth).
pub fn simulator(
    scene: &SceneSpec,
    width: u32,
    height: u32,
    hfov_deg: f64,
    robot: &RobotModel,
) -> anyhow::Result<Simulator> {
    simulator_with_noise(
        scene,
        width,
        height,
        hfov_deg,
        robot,
        &NoiseConfig::none(),
        0,
    )
}

/// [`simulator`] with sensor and actuation `noise` drawn from streams of `seed` (the `sim`
/// node passes its config's `noise` and episode `seed`).
pub fn simulator_with_noise(
    scene: &SceneSpec,
    width: u32,
    height: u32,
    hfov_deg: f64,
    robot: &RobotModel,
    noise: &NoiseConfig,
    seed: u64,
) -> anyhow::Result<Simulator> {
    anyhow::ensure!(
        width > 0 && height > 0 && width <= 4096 && height <= 4096,
        "sim: width/height must be in 1..=4096, got {width}×{height}"
    );
    anyhow::ensure!(
        hfov_deg.is_finite() && hfov_deg > 1.0 && hfov_deg < 179.0,
        "sim: hfov_deg must be in (1, 179), got {hfov_deg}"
    );
    robot.validate().map_err(|e| anyhow::anyhow!("sim: {e}"))?;
    let mut config = SimConfig::with_resolution(width, height);
    config.robot = *robot;
    config.intrinsics =
        activemap_geometry::Intrinsics::from_hfov(width, height, hfov_deg.to_radians());
    config.noise = *noise;
    config.seed = seed;
    scene
        .simulator(config)
        .map_err(|e| anyhow::anyhow!("sim: scene `{}`: {e}", scene.scene))
}

fn default_scene() -> String {
    "house:7".into()
}

/// Config of the `sim` node.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// `house:<seed>` for a procedural house, or a scene file path.
    #[serde(default = "default_scene")]
    pub scene: String,
    /// Largest number of rooms of a procedural house.
    #[serde(default)]
    pub max_rooms: Option<u32>,
    /// Largest floor area of a procedural house, m².
    #[serde(default)]
    pub max_area: Option<f64>,
    /// Up axis of a scene file: `x`, `-x`, `y` (glTF/OBJ default), `-y` (a scan in its camera's
    /// frame, y down), `z` (PLY default; z-up glTF exports), `-z`, or `auto` (found from the
    /// mesh's floor and walls at any tilt; with `floor: auto` a scan needs nothing else).
    #[serde(default)]
    pub up_axis: Option<UpAxis>,
    /// Scale, rotation and translation of a scene file after its up axis:
    /// `{ scale: 0.01, rotate_deg: [roll, pitch, yaw], translate: [x, y, z] }` or
    /// `{ matrix: [16 numbers, row-major 4×4] }` (see `activemap_sim::load::placement`).
    #[serde(default)]
    pub transform: Option<Transform>,
    /// Floor of a scene file: `none` (default), `auto` (find the floor plane, level the scene
    /// on it at z = 0; the tilt removed goes to the log) or a known floor height, metres.
    #[serde(default)]
    pub floor: Floor,
    /// Image width, pixels.
    #[serde(default = "default_size")]
    pub width: u32,
    /// Image height, pixels.
    #[serde(default = "default_size")]
    pub height: u32,
    /// Horizontal field of view, degrees.
    #[serde(default = "default_hfov")]
    pub hfov_deg: f64,
    /// One frame per action (true) or one frame per timer tick (false).
    #[serde(default = "default_true")]
    pub lockstep: bool,
    /// Step budget; `--max-steps` overrides it.
    #[serde(default = "default_max_steps")]
    pub max_steps: u64,
    /// Episode seed: 0 starts at the scene's own start pose; any other value starts at a
    /// seeded random pose on the floor reachable from it (`activemap bench results` sets it
    /// per cell, so that seeds are different episodes).
    #[serde(default)]
    pub seed: u64,
    /// The robot (camera height, radius, step and turn sizes; any field left out keeps its
    /// default): the nodes that need it (tracker, occupancy, frontier, scorer, follower,
    /// evaluator) must say the same, which `activemap validate` checks.
    #[serde(default)]
    pub robot: RobotModel,
    /// Sensor and actuation noise: `none` (default), `realistic` (RealSense D435 depth,
    /// LoCoBot-derived motion), or a map such as `{ preset: realistic, depth: { sigma_z2:
    /// 0.003 } }` (see `activemap_sim::noise`). Its streams are seeded by `seed`, so seeds are
    /// different episodes (seed 0 too is reproducible); ground-truth renders stay noise-free.
    #[serde(default)]
    pub noise: NoiseConfig,
    /// Faults injected into the episode to test how the loop reacts to tracking failures
    /// (issue 34): frames whose lens is covered or blacked out, spins the tracker is not told
    /// of. Empty by default; the ground truth the evaluator gets is the true pose whatever the
    /// fault.
    #[serde(default)]
    pub faults: Vec<Fault>,
}

/// A fault injected by the `sim` node ([`Config::faults`]), from frame `from_frame` on for
/// `frames` frames. (Unknown keys are refused by [`FaultKind`], which gets every key but
/// these two: serde's `flatten` rules out `deny_unknown_fields` here.)
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize)]
pub struct Fault {
    /// The first frame it affects.
    pub from_frame: u64,
    /// How many frames it lasts (1).
    #[serde(default = "one")]
    pub frames: u64,
    /// What happens.
    #[serde(flatten)]
    pub kind: FaultKind,
}

fn one() -> u64 {
    1
}

/// What a [`Fault`] does to a frame.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum FaultKind {
    /// Something textureless covers the lens at `distance_m` (a wall right in front, a hand):
    /// uniform grey, every depth reading at that distance, nothing of the map in view.
    Cover {
        /// The covering surface's distance, metres (within the depth range: readings stay
        /// valid).
        distance_m: f64,
    },
    /// The camera delivers black frames without depth.
    Blackout,
    /// The robot turns by `degrees` (counter-clockwise) about its vertical axis before each
    /// affected frame, on top of the commanded action: a spin the tracker is not told of.
    Spin {
        /// The extra turn per affected frame, degrees.
        degrees: f64,
    },
}

impl Fault {
    /// Whether the fault affects frame `frame_id`.
    pub fn affects(&self, frame_id: u64) -> bool {
        frame_id >= self.from_frame && frame_id - self.from_frame < self.frames
    }

    fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(self.frames >= 1, "sim: a fault's `frames` must be ≥ 1");
        match self.kind {
            FaultKind::Cover { distance_m } => anyhow::ensure!(
                distance_m.is_finite() && distance_m > 0.0,
                "sim: a cover fault's distance_m must be positive, got {distance_m}"
            ),
            FaultKind::Spin { degrees } => anyhow::ensure!(
                degrees.is_finite() && degrees.abs() < 360.0,
                "sim: a spin fault's degrees must be in (−360, 360), got {degrees}"
            ),
            FaultKind::Blackout => {}
        }
        Ok(())
    }
}

impl Config {
    /// The scene part of the config.
    pub fn scene_spec(&self) -> SceneSpec {
        SceneSpec {
            scene: self.scene.clone(),
            max_rooms: self.max_rooms,
            max_area: self.max_area,
            placement: self.placement(),
        }
    }

    /// The placement keys of the config (`up_axis`, `transform`, `floor`).
    pub fn placement(&self) -> Placement {
        Placement {
            up_axis: self.up_axis,
            transform: self.transform,
            floor: self.floor,
        }
    }
}

fn default_size() -> u32 {
    800
}
fn default_hfov() -> f64 {
    90.0
}
fn default_true() -> bool {
    true
}
fn default_max_steps() -> u64 {
    2000
}

/// Simulated time per step, seconds (frame stamps).
pub const STEP_SECONDS: f64 = 0.1;

/// The operator.
pub struct Sim {
    sim: Simulator,
    lockstep: bool,
    max_steps: u64,
    /// Frames published so far (the next frame's id).
    published: u64,
    pending: Option<ActionKind>,
    finished: bool,
    /// The faults to inject ([`Config::faults`]).
    faults: Vec<Fault>,
}

impl Sim {
    /// Publishes frame `self.published` at the current true pose, plus ground truth and status.
    fn publish(
        &mut self,
        ctx: &mut Context<'_>,
        state: EpisodeState,
        message: &str,
    ) -> anyhow::Result<()> {
        let frame_id = self.published;
        let stamp = frame_id as f64 * STEP_SECONDS;
        let k = self.sim.config().intrinsics;
        let header =
            RgbdFrameHeader::new(frame_id, stamp, [k.fx, k.fy, k.cx, k.cy], k.width, k.height);
        let faults: Vec<FaultKind> = self
            .faults
            .iter()
            .filter(|f| f.affects(frame_id))
            .map(|f| f.kind)
            .collect();
        for fault in &faults {
            if let FaultKind::Spin { degrees } = fault {
                let mut pose = self.sim.true_planar_pose();
                pose.yaw = activemap_geometry::robot::wrap_angle(pose.yaw + degrees.to_radians());
                self.sim.set_planar_pose(pose)?;
            }
        }
        let sim = &mut self.sim;
        // Rendered straight into the loaned shared-memory sample: no intermediate frame.
        ctx.loan(outputs::RGBD, header.payload_len()?, |buf| {
            let out = RgbdFrameMut::init(buf, header)?;
            sim.render_into(out.rgb, out.depth)?;
            for fault in &faults {
                match fault {
                    FaultKind::Cover { distance_m } => {
                        out.rgb.fill(128);
                        out.depth.fill(*distance_m as f32);
                    }
                    FaultKind::Blackout => {
                        out.rgb.fill(0);
                        out.depth.fill(0.0);
                    }
                    FaultKind::Spin { .. } => {}
                }
            }
            Ok(())
        })?;
        let truth: Isometry3<f64> = self.sim.true_pose();
        ctx.send(
            "true_pose",
            &TruePose {
                frame_id,
                stamp,
                t_world_camera: pose_to_wire(&truth),
            },
        )?;
        ctx.send(
            "episode",
            &EpisodeStatus {
                step: frame_id,
                max_steps: self.max_steps,
                state,
                message: message.to_string(),
            },
        )?;
        self.published += 1;
        Ok(())
    }

    /// Applies `action` and publishes the next frame; returns Stop when the episode is over.
    fn advance(
        &mut self,
        action: Option<ActionKind>,
        ctx: &mut Context<'_>,
    ) -> anyhow::Result<Flow> {
        let sim_action = match action {
            Some(ActionKind::Stop) => {
                self.finished = true;
                ctx.send(
                    "episode",
                    &EpisodeStatus {
                        step: self.sim.steps(),
                        max_steps: self.max_steps,
                        state: EpisodeState::Finished,
                        message: "stop action (no reachable frontier left)".into(),
                    },
                )?;
                return Ok(Flow::Stop);
            }
            Some(kind) => kind.robot_action(),
            None => None,
        };
        if let Some(a) = sim_action {
            self.sim.step(a);
        }
        let done = self.sim.steps() >= self.max_steps;
        if done {
            self.finished = true;
            self.publish(ctx, EpisodeState::Finished, "max_steps reached")?;
            return Ok(Flow::Stop);
        }
        self.publish(ctx, EpisodeState::Running, "")?;
        Ok(Flow::Continue)
    }
}

impl Operator for Sim {
    type Config = Config;

    fn new(config: Config, ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        let mut sim = simulator_with_noise(
            &config.scene_spec(),
            config.width,
            config.height,
            config.hfov_deg,
            &config.robot,
            &config.noise,
            config.seed,
        )?;
        if config.seed != 0 {
            let start = sim
                .navigation()
                .random_start(&sim.true_planar_pose(), config.seed)
                .ok_or_else(|| anyhow::anyhow!("sim: the scene's start is not navigable"))?;
            sim.set_planar_pose(start)?;
        }
        for fault in &config.faults {
            fault.validate()?;
        }
        let max_steps = ctx.max_steps().unwrap_or(config.max_steps);
        anyhow::ensure!(max_steps >= 1, "sim: max_steps must be ≥ 1");
        Ok(Self {
            sim,
            lockstep: config.lockstep,
            max_steps,
            published: 0,
            pending: None,
            finished: false,
            faults: config.faults,
        })
    }

    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        if self.finished {
            return Ok(Flow::Stop);
        }
        match event {
            Event::Timer { .. } if self.published == 0 => {
                self.publish(ctx, EpisodeState::Running, "start")?;
            }
            Event::Timer { .. } if !self.lockstep => {
                let action = self.pending.take();
                return self.advance(action, ctx);
            }
            Event::Input(input) if input.port == inputs::ACTION => {
                let action: Action = input.decode()?;
                if self.lockstep {
                    anyhow::ensure!(
                        self.published > 0 && action.step + 1 == self.published,
                        "sim: lockstep action for step {} but the last frame was {}",
                        action.step,
                        self.published.saturating_sub(1)
                    );
                    return self.advance(Some(action.action), ctx);
                }
                if action.action == ActionKind::Stop {
                    return self.advance(Some(ActionKind::Stop), ctx);
                }
                self.pending = Some(action.action);
            }
            Event::InputClosed { .. } => {
                ctx.send(
                    "episode",
                    &EpisodeStatus {
                        step: self.sim.steps(),
                        max_steps: self.max_steps,
                        state: EpisodeState::Failed,
                        message: "the action stream closed".into(),
                    },
                )?;
                return Ok(Flow::Stop);
            }
            _ => {}
        }
        Ok(Flow::Continue)
    }
}

/// The operator's input ports, named once for registration and dispatch.
pub mod inputs {
    activemap_runtime::ports! {
        ACTION = "action": super::K::Action
    }
}

/// The operator's output ports, named once for registration and dispatch.
pub mod outputs {
    activemap_runtime::ports! {
        RGBD = "rgbd": super::K::RgbdFrame,
        TRUE_POSE = "true_pose": super::K::TruePose,
        EPISODE = "episode": super::K::EpisodeStatus
    }
}

/// How a run's progress is read from the simulator's `episode` output: the step, the budget and
/// how the episode ended (`LaunchOptions::progress`; the CLI's progress line).
pub const EPISODE_PROGRESS: activemap_runtime::progress::ProgressSource =
    activemap_runtime::progress::ProgressSource {
        kind: activemap_schemas::MessageKind::EpisodeStatus,
        noun: "episode",
        read: read_episode_progress,
    };

fn read_episode_progress(bytes: &[u8]) -> Option<activemap_runtime::progress::StepStatus> {
    use activemap_runtime::progress::{RunEnd, StepStatus};
    use activemap_schemas::{EpisodeState, EpisodeStatus, SmallMessage as _};
    let status = EpisodeStatus::decode(bytes).ok()?;
    Some(StepStatus {
        step: status.step,
        max_steps: status.max_steps,
        end: match status.state {
            EpisodeState::Running => None,
            EpisodeState::Finished => Some(RunEnd::Finished),
            EpisodeState::Failed => Some(RunEnd::Failed),
        },
        message: status.message,
    })
}

/// Registry entry.
pub fn registered() -> Registered {
    Registered {
        descriptor: OperatorDescriptor {
            name: "sim",
            summary: "RGB-D simulator: renders at the true pose, applies actions, lockstep (SPEC §1.1)",
            inputs: inputs::ALL,
            outputs: outputs::ALL,
            evaluation: false,
            check_config: check_config_as::<Config>,
        },
        implementation: Some(OperatorImpl::of::<Sim>()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(config: serde_json::Value) -> Result<(), String> {
        check_config_as::<Config>(&config)
    }

    /// The fault list of issue 34's reaction test: each kind parses with its keys, `frames`
    /// defaults to 1, a misspelt key or an unknown kind is refused with its name, and a fault
    /// affects exactly its frames.
    #[test]
    fn faults_parse_refuse_typos_and_cover_their_frames() {
        let config: Config = serde_json::from_value(serde_json::json!({ "faults": [
            { "kind": "cover", "distance_m": 0.3, "from_frame": 40, "frames": 4 },
            { "kind": "blackout", "from_frame": 7 },
            { "kind": "spin", "degrees": 30.0, "from_frame": 9, "frames": 2 },
        ] }))
        .unwrap();
        assert_eq!(
            config.faults,
            [
                Fault {
                    from_frame: 40,
                    frames: 4,
                    kind: FaultKind::Cover { distance_m: 0.3 }
                },
                Fault {
                    from_frame: 7,
                    frames: 1,
                    kind: FaultKind::Blackout
                },
                Fault {
                    from_frame: 9,
                    frames: 2,
                    kind: FaultKind::Spin { degrees: 30.0 }
                },
            ]
        );
        let cover = config.faults[0];
        assert!(!cover.affects(39) && cover.affects(40) && cover.affects(43));
        assert!(!cover.affects(44));
        let e = check(serde_json::json!({ "faults": [
            { "kind": "cover", "distance": 0.3, "from_frame": 4 }
        ] }))
        .unwrap_err();
        assert!(e.contains("distance"), "{e}");
        let e = check(serde_json::json!({ "faults": [{ "kind": "smoke", "from_frame": 4 }] }))
            .unwrap_err();
        assert!(e.contains("smoke"), "{e}");
        let bad = Fault {
            from_frame: 1,
            frames: 0,
            kind: FaultKind::Blackout,
        };
        assert!(bad.validate().unwrap_err().to_string().contains("frames"));
    }

    #[test]
    fn up_axis_accepts_the_six_axes_and_names_bad_values() {
        for (name, up) in [
            ("z", UpAxis::Z),
            ("Y", UpAxis::Y),
            ("x", UpAxis::X),
            ("-x", UpAxis::NegX),
            ("-y", UpAxis::NegY),
            ("-Z", UpAxis::NegZ),
            ("z-up", UpAxis::Z),
        ] {
            check(serde_json::json!({ "scene": "room.glb", "up_axis": name })).unwrap();
            let config: Config =
                serde_json::from_value(serde_json::json!({ "up_axis": name })).unwrap();
            assert_eq!(config.up_axis, Some(up), "{name}");
        }
        let err = check(serde_json::json!({ "scene": "room.glb", "up_axis": "w" })).unwrap_err();
        assert!(
            err.contains("up_axis must be x, -x, y, -y, z or -z") && err.contains("\"w\""),
            "{err}"
        );
        let config: Config = serde_json::from_value(serde_json::json!({})).unwrap();
        assert_eq!(config.placement(), Placement::default());
    }

    #[test]
    fn transform_and_floor_read_from_yaml_and_reach_the_scene_spec() {
        let config = from_yaml(
            "scene: scans/room.obj\nup_axis: -y\n\
             transform: { scale: 0.01, rotate_deg: [0, 0, 90], translate: [1, 2, 0] }\n\
             floor: auto\n",
        )
        .unwrap();
        let spec = config.scene_spec();
        assert_eq!(spec.placement.up_axis, Some(UpAxis::NegY));
        assert_eq!(spec.placement.floor, Floor::Auto);
        let t = spec.placement.transform.unwrap();
        assert_eq!(
            (t.scale, t.rotate_deg, t.translate),
            (Some(0.01), Some([0.0, 0.0, 90.0]), Some([1.0, 2.0, 0.0]))
        );
        assert_eq!(from_yaml("floor: 0.25").unwrap().floor, Floor::Height(0.25));
        let m =
            from_yaml("transform: { matrix: [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1] }");
        assert!(m.unwrap().transform.unwrap().matrix.is_some());
        // The config check refuses what loading would: a shear, an unknown floor mode.
        let err =
            from_yaml("transform: { matrix: [1, 0.2, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1] }")
                .unwrap_err();
        assert!(
            err.contains("not a rotation times a positive uniform scale"),
            "{err}"
        );
        let err = check(serde_json::json!({ "floor": "level" })).unwrap_err();
        assert!(err.contains("floor must be `none`, `auto`"), "{err}");
    }

    fn from_yaml(source: &str) -> Result<Config, String> {
        let value = activemap_runtime::yaml::parse(source)
            .map_err(|e| format!("{}: {}", e.loc, e.message))?
            .to_json();
        activemap_runtime::config_from_value::<Config>(&value)
    }

    #[test]
    fn noise_defaults_to_none_and_reads_presets_and_overrides() {
        assert_eq!(
            from_yaml("scene: house:1").unwrap().noise,
            NoiseConfig::none()
        );
        assert_eq!(from_yaml("noise: none").unwrap().noise, NoiseConfig::none());
        assert_eq!(
            from_yaml("noise: realistic").unwrap().noise,
            NoiseConfig::realistic()
        );
        let config =
            from_yaml("noise:\n  preset: realistic\n  depth: { sigma_z2: 0.003 }\n").unwrap();
        let mut expected = NoiseConfig::realistic();
        expected.depth.sigma_z2 = 0.003;
        assert_eq!(config.noise, expected);
        let config = from_yaml("noise: { rgb: { sigma: 4 }, actuation: realistic }").unwrap();
        assert_eq!(config.noise.rgb.sigma, 4.0);
        assert_eq!(config.noise.depth, NoiseConfig::none().depth);
        assert_eq!(config.noise.actuation, NoiseConfig::realistic().actuation);
        // Bad values and keys are refused naming the field.
        let err = from_yaml("noise: { depth: { dropout: 2 } }").unwrap_err();
        assert!(err.contains("noise.depth.dropout"), "{err}");
        let err = check(serde_json::json!({ "noise": { "depth": { "sigma": 0.1 } } })).unwrap_err();
        assert!(
            err.contains("noise.depth") && err.contains("sigma"),
            "{err}"
        );
        let err = check(serde_json::json!({ "noise": "loud" })).unwrap_err();
        assert!(err.contains("realistic"), "{err}");
    }

    #[test]
    fn the_node_seeds_its_noise_and_the_ground_truth_copy_stays_noise_free() {
        let scene = SceneSpec::new("house:1");
        let robot = RobotModel::default();
        let noisy = |seed| {
            let noise = NoiseConfig::realistic();
            simulator_with_noise(&scene, 24, 24, 90.0, &robot, &noise, seed).unwrap()
        };
        let (mut a, mut b, mut c) = (noisy(0), noisy(0), noisy(3));
        assert_eq!(a.render(), b.render());
        assert_ne!(a.render(), c.render());
        let truth = simulator(&scene, 24, 24, 90.0, &robot).unwrap();
        assert_eq!(truth.config().noise, NoiseConfig::none());
        assert_eq!(a.config().noise, NoiseConfig::realistic());
    }

    #[test]
    fn placement_keys_are_refused_for_procedural_houses() {
        for (placement, key) in [
            (
                Placement {
                    up_axis: Some(UpAxis::Z),
                    ..Placement::default()
                },
                "up_axis",
            ),
            (
                Placement {
                    floor: Floor::Auto,
                    ..Placement::default()
                },
                "floor",
            ),
        ] {
            let scene = SceneSpec {
                placement,
                ..SceneSpec::new("house:1")
            };
            let err = simulator(&scene, 8, 8, 90.0, &RobotModel::default())
                .unwrap_err()
                .to_string();
            assert!(
                err.contains(key) && err.contains("applies to scene files"),
                "{err}"
            );
        }
    }
}
