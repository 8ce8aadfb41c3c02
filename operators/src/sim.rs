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
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, PortSpec, check_config_as,
};
use activemap_schemas::{
    Action, ActionKind, EpisodeState, EpisodeStatus, MessageKind as K, RgbdFrameHeader,
    RgbdFrameMut, TruePose,
};
use activemap_sim::{SceneSpec, SimConfig, Simulator, UpAxis};

use crate::Registered;
use crate::convert::pose_to_wire;

/// The simulator of `scene` at `width`×`height` pixels and `hfov_deg` with `robot` (the `sim`
/// node's camera and robot; the evaluator builds the same scene for its ground truth).
pub fn simulator(
    scene: &SceneSpec,
    width: u32,
    height: u32,
    hfov_deg: f64,
    robot: &RobotModel,
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
    /// Up axis of a scene file: `y` (glTF/OBJ default) or `z` (PLY default; z-up glTF exports).
    #[serde(default, deserialize_with = "up_axis_from_name")]
    pub up_axis: Option<UpAxis>,
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
}

impl Config {
    /// The scene part of the config.
    pub fn scene_spec(&self) -> SceneSpec {
        SceneSpec {
            scene: self.scene.clone(),
            max_rooms: self.max_rooms,
            max_area: self.max_area,
            up_axis: self.up_axis,
        }
    }
}

/// Reads `up_axis: y | z`; anything else is a config error naming the accepted values.
pub(crate) fn up_axis_from_name<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> Result<Option<UpAxis>, D::Error> {
    use serde::Deserialize as _;
    let name: Option<String> = Option::deserialize(d)?;
    name.map(|n| {
        UpAxis::from_name(&n).ok_or_else(|| {
            serde::de::Error::custom(format!("up_axis must be `y` or `z`, got \"{n}\""))
        })
    })
    .transpose()
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
        let sim = &mut self.sim;
        // Rendered straight into the loaned shared-memory sample: no intermediate frame.
        ctx.loan("rgbd", header.payload_len()?, |buf| {
            let out = RgbdFrameMut::init(buf, header)?;
            sim.render_into(out.rgb, out.depth)?;
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
        let mut sim = simulator(
            &config.scene_spec(),
            config.width,
            config.height,
            config.hfov_deg,
            &config.robot,
        )?;
        if config.seed != 0 {
            let start = sim
                .navigation()
                .random_start(&sim.true_planar_pose(), config.seed)
                .ok_or_else(|| anyhow::anyhow!("sim: the scene's start is not navigable"))?;
            sim.set_planar_pose(start)?;
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
            Event::Input(input) if input.port == "action" => {
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

const INPUTS: &[PortSpec] = &[PortSpec {
    name: "action",
    kind: K::Action,
}];
const OUTPUTS: &[PortSpec] = &[
    PortSpec {
        name: "rgbd",
        kind: K::RgbdFrame,
    },
    PortSpec {
        name: "true_pose",
        kind: K::TruePose,
    },
    PortSpec {
        name: "episode",
        kind: K::EpisodeStatus,
    },
];

/// Registry entry.
pub fn registered() -> Registered {
    Registered {
        descriptor: OperatorDescriptor {
            name: "sim",
            summary: "RGB-D simulator: renders at the true pose, applies actions, lockstep (SPEC §1.1)",
            inputs: INPUTS,
            outputs: OUTPUTS,
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

    #[test]
    fn up_axis_accepts_y_and_z_and_names_bad_values() {
        check(serde_json::json!({ "scene": "room.glb", "up_axis": "z" })).unwrap();
        check(serde_json::json!({ "scene": "room.glb", "up_axis": "Y" })).unwrap();
        let err = check(serde_json::json!({ "scene": "room.glb", "up_axis": "x" })).unwrap_err();
        assert!(
            err.contains("up_axis must be `y` or `z`") && err.contains("\"x\""),
            "{err}"
        );
        let config: Config =
            serde_json::from_value(serde_json::json!({ "up_axis": "z-up" })).unwrap();
        assert_eq!(config.up_axis, Some(UpAxis::Z));
        let config: Config = serde_json::from_value(serde_json::json!({})).unwrap();
        assert_eq!(config.up_axis, None);
    }

    #[test]
    fn up_axis_is_refused_for_procedural_houses() {
        let scene = SceneSpec {
            up_axis: Some(UpAxis::Z),
            ..SceneSpec::new("house:1")
        };
        let err = simulator(&scene, 8, 8, 90.0, &RobotModel::default())
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("up_axis") && err.contains("applies to scene files"),
            "{err}"
        );
    }
}
