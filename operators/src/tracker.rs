//! `tracker`: camera tracking against the latest Gaussian map (SPEC §4). A thin shell around
//! [`activemap_slam::TrackingSession`], which holds the whole per-frame logic (prediction,
//! lagged map snapshots, reference keyframes, lost/skipped frames; see its module doc); the
//! in-process driver of `activemap bench slam` holds the same session. Never sees ground
//! truth: the world is anchored at the start pose (floor at z = 0,
//! [`crate::convert::start_anchor`]) and each frame is predicted from the previous estimate and
//! the commanded action (or constant velocity). Exactly one pose estimate per frame.

use std::sync::Arc;

use activemap_geometry::{Isometry3, RobotModel};
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, check_config_as,
};
use activemap_schemas::{
    Action, ActionKind, MessageKind as K, PoseEstimate, RgbdFrameView, TrackingStatus,
};
use activemap_slam::{
    Frame, KeyframeGraphConfig, MotionPrior, TrackedFrame, TrackingConfig, TrackingSession,
    TrackingStatus as SlamStatus,
};
use activemap_splat::Gaussians;

use crate::Registered;
use crate::convert::{corrections_to_wire, pose_to_wire, read_map, slam_frame, start_anchor};

/// How the tracker predicts the next pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Prior {
    /// The commanded action's motion (collisions make it wrong; tracking corrects it).
    Action,
    /// Repeat the last frame-to-frame motion.
    ConstantVelocity,
    /// Start from the previous pose.
    None,
}

/// Config.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// The robot (camera height for the anchor, step and turn sizes for the motion prior;
    /// any field left out keeps its default).
    #[serde(default)]
    pub robot: RobotModel,
    /// Motion prior.
    #[serde(default = "default_prior")]
    pub motion_prior: Prior,
    /// Tracking image downscale factor (1 = full resolution).
    #[serde(default)]
    pub downscale: Option<usize>,
    /// Maximum Adam iterations per frame (SPEC §4: 100).
    #[serde(default)]
    pub max_iterations: Option<usize>,
    /// The dense tracker re-references (the tracked frame becomes its reference keyframe)
    /// once the overlap with the current reference falls below this fraction.
    #[serde(default = "default_rereference")]
    pub rereference_below: f64,
    /// Map lag L in frames: frame k is tracked against the snapshot of frame k − 1 − L. Must
    /// equal the mapper's `map_lag`.
    #[serde(default)]
    pub map_lag: u64,
    /// The keyframe pose graph over the dense tracker's references
    /// (`activemap_slam::KeyframeGraph`): loop closures correct every reference between the
    /// loop's ends, not only the current pose, and the estimate of the closing frame carries
    /// each keyframe's correction (`keyframe_corrections`) so that the mapper moves its
    /// keyframes and their Gaussians with them.
    #[serde(default)]
    pub pose_graph: bool,
    /// A tracked frame whose estimate lies farther than this (metres) from where the
    /// commanded action should have taken the previous estimate is logged as a suspect
    /// tracking event (`tracker: frame K: …`): a jump the actuation cannot explain. A blocked
    /// forward move disagrees by one forward step (5 cm); realistic actuation by about 1 cm.
    #[serde(default = "default_suspect_m")]
    pub suspect_jump_m: f64,
    /// The same for the rotation, degrees.
    #[serde(default = "default_suspect_deg")]
    pub suspect_turn_deg: f64,
}

fn default_suspect_m() -> f64 {
    0.08
}

fn default_suspect_deg() -> f64 {
    10.0
}

/// How far the estimate `current` lies from where the commanded camera motion `commanded`
/// (`T_prev_current`, [`action_motion`]) takes the previous estimate `previous`: the
/// translation (metres) and rotation angle (radians) of `(T_prev · M)⁻¹ · T_current`.
pub fn motion_disagreement(
    previous: &Isometry3<f64>,
    current: &Isometry3<f64>,
    commanded: &Isometry3<f64>,
) -> (f64, f64) {
    let d = (previous * commanded).inverse() * current;
    (d.translation.vector.norm(), d.rotation.angle())
}

fn default_rereference() -> f64 {
    TrackingConfig::default().rereference_below
}

fn default_prior() -> Prior {
    Prior::Action
}

/// `T_prev_current` of the camera for one commanded action of `robot`
/// ([`RobotModel::camera_motion`]; `Stop` does not move).
pub fn action_motion(action: ActionKind, robot: &RobotModel) -> Isometry3<f64> {
    action
        .robot_action()
        .map_or(Isometry3::identity(), |a| robot.camera_motion(a))
}

impl Config {
    /// The tracking session's settings for this node (library defaults where unset).
    pub fn tracking_config(&self) -> anyhow::Result<TrackingConfig> {
        self.robot
            .validate()
            .map_err(|e| anyhow::anyhow!("tracker: {e}"))?;
        let mut config = TrackingConfig {
            rereference_below: self.rereference_below,
            map_lag: self.map_lag,
            initial_pose: start_anchor(&self.robot),
            pose_graph: self.pose_graph.then(KeyframeGraphConfig::default),
            ..TrackingConfig::default()
        };
        if let Some(d) = self.downscale {
            config.tracker.downscale = d;
        }
        if let Some(n) = self.max_iterations {
            config.tracker.max_iterations = n;
        }
        config
            .validate()
            .map_err(|e| anyhow::anyhow!("tracker: {e}"))?;
        Ok(config)
    }

    /// The motion prior from one frame to the next after `action`.
    fn motion(&self, action: ActionKind) -> MotionPrior {
        match self.motion_prior {
            Prior::Action => MotionPrior::Relative(action_motion(action, &self.robot)),
            Prior::ConstantVelocity => MotionPrior::ConstantVelocity,
            Prior::None => MotionPrior::None,
        }
    }
}

/// The operator's state (also driven directly by tests): the session and the node config.
pub struct Tracker {
    config: Config,
    session: TrackingSession,
    /// Commanded camera motion from frame `step` to `step + 1`, until that frame is tracked.
    commanded: std::collections::BTreeMap<u64, Isometry3<f64>>,
    /// The last estimate (frame, pose), for the suspect-jump check.
    last: Option<(u64, Isometry3<f64>)>,
    /// Frames logged as suspect tracking events so far.
    suspect_frames: u64,
}

impl Tracker {
    /// A tracker at the start anchor with an empty map.
    pub fn from_config(config: Config) -> anyhow::Result<Self> {
        anyhow::ensure!(
            config.suspect_jump_m > 0.0 && config.suspect_turn_deg > 0.0,
            "tracker: suspect_jump_m and suspect_turn_deg must be positive, got {} and {}",
            config.suspect_jump_m,
            config.suspect_turn_deg
        );
        Ok(Self {
            session: TrackingSession::new(config.tracking_config()?)?,
            config,
            commanded: Default::default(),
            last: None,
            suspect_frames: 0,
        })
    }

    /// Stores a map snapshot (of frame `frame_id`) without its Gaussians that have a NaN or
    /// infinite parameter; logs and returns how many were dropped.
    pub fn set_map(&mut self, frame_id: u64, map: Gaussians<f32>) -> usize {
        let dropped = self.session.add_map(frame_id, Arc::new(map));
        if dropped > 0 {
            eprintln!(
                "tracker: dropped {dropped} Gaussians with non-finite parameters from the map \
                 of frame {frame_id}"
            );
        }
        dropped
    }

    /// Stores an RGB-D frame to track.
    pub fn add_frame(&mut self, frame_id: u64, frame: Frame) {
        self.session.add_frame(frame_id, frame);
    }

    /// Stores the action taken at step `step` (the motion from frame `step` to `step + 1`).
    pub fn add_action(&mut self, step: u64, action: ActionKind) {
        let motion = self.config.motion(action);
        self.session.add_motion(step, motion);
        self.commanded
            .insert(step, action_motion(action, &self.config.robot));
    }

    /// Frames logged as suspect tracking events so far ([`Tracker::suspect_event`]).
    pub fn suspect_frames(&self) -> u64 {
        self.suspect_frames
    }

    /// The log line of a suspect tracking event for `frame`, or `None`: a frame tracked `Ok`,
    /// not closing a loop, whose estimate disagrees with the commanded motion from the
    /// previous estimate by more than `suspect_jump_m` or `suspect_turn_deg`.
    pub fn suspect_event(
        &self,
        frame: &TrackedFrame,
        commanded: &Isometry3<f64>,
    ) -> Option<String> {
        let (prev_id, prev) = self.last?;
        if prev_id + 1 != frame.frame_id
            || frame.status != SlamStatus::Ok
            || frame.loop_closure.is_some()
        {
            return None;
        }
        let (metres, radians) = motion_disagreement(&prev, &frame.pose, commanded);
        (metres > self.config.suspect_jump_m || radians.to_degrees() > self.config.suspect_turn_deg)
            .then(|| {
                format!(
                    "tracker: frame {}: suspect tracking event: the estimate lies {:.1} cm and \
                     {:.1}° from where the commanded motion takes frame {prev_id}'s \
                     (thresholds {:.1} cm, {:.1}°)",
                    frame.frame_id,
                    100.0 * metres,
                    radians.to_degrees(),
                    100.0 * self.config.suspect_jump_m,
                    self.config.suspect_turn_deg
                )
            })
    }

    /// Tracks every frame whose inputs are complete, in order; returns their estimates. Logs
    /// each loop closure of the pose graph that moved a keyframe by a centimetre or more.
    pub fn process_ready(&mut self) -> anyhow::Result<Vec<PoseEstimate>> {
        let tracked = self.session.process_ready()?;
        for t in &tracked {
            if let Some(commanded) = t
                .frame_id
                .checked_sub(1)
                .and_then(|k| self.commanded.get(&k).copied())
                && let Some(line) = self.suspect_event(t, &commanded)
            {
                self.suspect_frames += 1;
                eprintln!("{line}");
            }
            self.commanded = self.commanded.split_off(&t.frame_id);
            self.last = Some((t.frame_id, t.pose));
            if let Some(c) = t
                .loop_closure
                .as_ref()
                .filter(|c| c.largest_shift_m >= 0.01)
            {
                eprintln!(
                    "tracker: frame {}: loop closure ({} loop edge(s)); pose graph of {} keyframes \
                     re-optimised, keyframes moved up to {:.1} cm",
                    t.frame_id,
                    c.loop_edges,
                    c.keyframes,
                    100.0 * c.largest_shift_m
                );
            }
        }
        Ok(tracked.iter().map(estimate).collect())
    }
}

/// The wire estimate of a tracked frame.
pub fn estimate(t: &TrackedFrame) -> PoseEstimate {
    PoseEstimate {
        frame_id: t.frame_id,
        stamp: t.stamp,
        t_world_camera: pose_to_wire(&t.pose),
        status: match t.status {
            SlamStatus::Ok => TrackingStatus::Ok,
            SlamStatus::Lost => TrackingStatus::Lost,
            SlamStatus::Skipped(_) => TrackingStatus::Skipped,
        },
        residual_rgb: t.residuals.photometric,
        residual_depth: t.residuals.depth_median,
        iterations: t.iterations as u32,
        graph_anchor: t.graph_anchor,
        keyframe_corrections: t
            .loop_closure
            .as_ref()
            .map_or_else(Vec::new, |c| corrections_to_wire(&c.corrections)),
    }
}

impl Operator for Tracker {
    type Config = Config;

    fn new(config: Config, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        Self::from_config(config)
    }

    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        match event {
            Event::Input(input) => match input.port {
                inputs::RGBD => {
                    let view = RgbdFrameView::parse(input.bytes)?;
                    self.add_frame(view.header.frame_id, slam_frame(&view)?);
                }
                inputs::MAP => {
                    let (header, map) = read_map(input.bytes)?;
                    self.set_map(header.frame_id, map);
                }
                inputs::ACTION => {
                    let a: Action = input.decode()?;
                    self.add_action(a.step, a.action);
                }
                other => anyhow::bail!("tracker: unexpected input `{other}`"),
            },
            Event::InputClosed { port: inputs::RGBD } => return Ok(Flow::Stop),
            _ => return Ok(Flow::Continue),
        }
        for e in self.process_ready()? {
            ctx.send(outputs::POSE, &e)?;
        }
        Ok(Flow::Continue)
    }
}

/// The operator's input ports, named once for registration and dispatch.
pub mod inputs {
    activemap_runtime::ports! {
        RGBD = "rgbd": super::K::RgbdFrame,
        MAP = "map": super::K::GaussianMap,
        ACTION = "action": super::K::Action
    }
}

/// The operator's output ports, named once for registration and dispatch.
pub mod outputs {
    activemap_runtime::ports! {
        POSE = "pose": super::K::PoseEstimate
    }
}

/// Registry entry.
pub fn registered() -> Registered {
    Registered {
        descriptor: OperatorDescriptor {
            name: "tracker",
            summary: "3DGS tracking of each frame against the latest map, no ground truth (SPEC §4)",
            inputs: inputs::ALL,
            outputs: outputs::ALL,
            evaluation: false,
            check_config: check_config_as::<Config>,
        },
        implementation: Some(OperatorImpl::of::<Tracker>()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The commanded motion is the camera-frame motion of the robot: forward = +z (optical
    /// axis) by 5 cm; a left turn rotates the optical axis toward camera −x (left) by 5°.
    #[test]
    fn action_motion_matches_the_camera_frame() {
        let f = action_motion(ActionKind::Forward, &RobotModel::default());
        assert!((f.translation.vector - nalgebra::Vector3::new(0.0, 0.0, 0.05)).norm() < 1e-12);
        assert!(f.rotation.angle() < 1e-12);
        let l = action_motion(ActionKind::TurnLeft, &RobotModel::default());
        assert!(l.translation.vector.norm() < 1e-12);
        assert!((l.rotation.angle() - 5f64.to_radians()).abs() < 1e-12);
        let fwd = l.rotation * nalgebra::Vector3::z();
        assert!(
            fwd.x < -0.08,
            "left turn must swing the optical axis to camera −x: {fwd:?}"
        );
        let r = action_motion(ActionKind::TurnRight, &RobotModel::default());
        assert!((r * l).rotation.angle() < 1e-12);
    }
    /// Bad numbers (issue 18): a map message whose Gaussians carry NaN / inf parameters
    /// reaches the tracking session without them; `set_map` counts them (and logs).
    #[test]
    fn a_map_message_with_non_finite_parameters_loses_those_gaussians() {
        use crate::convert::{map_header, write_map};
        let mut g = Gaussians::<f32>::new();
        for i in 0..5 {
            let y = 0.1 * i as f64;
            g.push(
                [1.0, y, 0.5],
                [0.5; 3],
                [1.0, 0.0, 0.0, 0.0],
                0.9,
                [0.05; 3],
            );
        }
        g.means[1][0] = f32::NAN;
        g.opacity_logits[2] = f32::INFINITY;
        g.sh_dc[3][1] = f32::NEG_INFINITY;
        let header = map_header(&g, 0, 0.0, None);
        let mut storage = vec![0u64; header.payload_len().unwrap() / 8];
        let buf: &mut [u8] = bytemuck::cast_slice_mut(&mut storage);
        write_map(buf, header, &g, &[0, 1, 2, 3, 4]).unwrap();
        let (h, map) = read_map(buf).unwrap();
        let mut tracker = Tracker::from_config(Config {
            robot: RobotModel::default(),
            motion_prior: Prior::Action,
            downscale: None,
            max_iterations: None,
            rereference_below: default_rereference(),
            map_lag: 0,
            pose_graph: false,
            suspect_jump_m: default_suspect_m(),
            suspect_turn_deg: default_suspect_deg(),
        })
        .unwrap();
        assert_eq!(tracker.set_map(h.frame_id, map), 3);
    }

    /// Issue 34: a jump the commanded motion cannot explain is a suspect tracking event; a
    /// step as commanded, a blocked step (5 cm short) and a loop closure's correction are not.
    #[test]
    fn an_estimate_far_from_the_commanded_motion_is_a_suspect_tracking_event() {
        let robot = RobotModel::default();
        let config: Config = serde_json::from_value(serde_json::json!({})).unwrap();
        assert_eq!(
            (config.suspect_jump_m, config.suspect_turn_deg),
            (0.08, 10.0)
        );
        let mut tracker = Tracker::from_config(config).unwrap();
        let start = start_anchor(&robot);
        let forward = action_motion(ActionKind::Forward, &robot);
        let frame = |id: u64, pose: Isometry3<f64>| TrackedFrame {
            frame_id: id,
            stamp: id as f64,
            pose,
            status: SlamStatus::Ok,
            residuals: Default::default(),
            iterations: 10,
            seconds: 0.0,
            loop_closure: None,
            graph_anchor: None,
        };
        // No previous estimate yet: nothing to compare with.
        assert!(tracker.suspect_event(&frame(1, start), &forward).is_none());
        tracker.last = Some((0, start));
        let (d, a) = motion_disagreement(&start, &(start * forward), &forward);
        assert!(d < 1e-12 && a < 1e-12);
        assert!(
            tracker
                .suspect_event(&frame(1, start * forward), &forward)
                .is_none()
        );
        // Blocked: the robot stayed, 5 cm short of the command.
        let (d, _) = motion_disagreement(&start, &start, &forward);
        assert!((d - 0.05).abs() < 1e-12);
        assert!(tracker.suspect_event(&frame(1, start), &forward).is_none());
        // A 32 cm jump sideways (the house-3 episode of the issue), and a 15° twist.
        let jump = start * forward * Isometry3::translation(0.32, 0.0, 0.0);
        let line = tracker.suspect_event(&frame(1, jump), &forward).unwrap();
        assert!(
            line.starts_with("tracker: frame 1: suspect tracking event"),
            "{line}"
        );
        assert!(line.contains("32.0 cm"), "{line}");
        let twist =
            start * forward * Isometry3::rotation(nalgebra::Vector3::y() * 15f64.to_radians());
        assert!(tracker.suspect_event(&frame(1, twist), &forward).is_some());
        // Not for a frame that is not the next one, a lost frame or a loop closure's.
        assert!(tracker.suspect_event(&frame(2, jump), &forward).is_none());
        let mut lost = frame(1, jump);
        lost.status = SlamStatus::Lost;
        assert!(tracker.suspect_event(&lost, &forward).is_none());
        let bad = serde_json::json!({ "suspect_jump_m": 0.0 });
        let e = Tracker::from_config(serde_json::from_value(bad).unwrap())
            .err()
            .unwrap();
        assert!(e.to_string().contains("suspect_jump_m"), "{e}");
    }
}
