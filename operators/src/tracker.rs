//! `tracker`: camera tracking against the latest Gaussian map (SPEC §4), wrapping
//! `activemap_slam::track`. Never sees ground truth: the world is anchored at the start pose
//! (floor at z = 0, [`crate::convert::start_anchor`]) and each frame is predicted from the
//! previous estimate and the commanded action (or constant velocity).
//!
//! Lockstep determinism: frame k is tracked only once the map snapshot of frame k − 1 − L (the
//! mapper publishes one per frame; L = `map_lag`, [`crate::mapper::required_snapshot`]) and the
//! action of step k − 1 have arrived, and always against exactly that snapshot, so the result
//! never depends on message timing. Exactly one pose estimate per frame. The dense tracker
//! aligns to its own reference keyframes (the newest, plus older ones of the same place when
//! the robot comes back, `activemap_slam::references`) under the ground-robot motion prior
//! (`DenseConfig::for_ground_robot`), and needs the map only for its Lost signal, so a lag of
//! a few frames costs little while mapping runs in the background.

use std::collections::BTreeMap;

use activemap_geometry::{Isometry3, PlanarPose, camera_pose_from_planar};
use activemap_planning::dynamics::{Action as PlanAction, ActionModel};
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, PortSpec, check_config_as,
};
use activemap_schemas::{
    Action, ActionKind, MessageKind as K, PoseEstimate, RgbdFrameView, TrackingStatus,
};
use activemap_slam::dense::DenseReference;
use activemap_slam::{
    Frame, ReferenceConfig, References, TrackerConfig, TrackingStatus as SlamStatus, track,
};
use activemap_splat::Gaussians;

use crate::Registered;
use crate::convert::{CAMERA_HEIGHT_M, pose_to_wire, read_map, slam_frame, start_anchor};
use crate::mapper::required_snapshot;

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
    /// Camera height above the floor, metres (the robot's own mount).
    #[serde(default = "default_height")]
    pub camera_height: f64,
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
}

fn default_rereference() -> f64 {
    0.85
}

fn default_height() -> f64 {
    CAMERA_HEIGHT_M
}
fn default_prior() -> Prior {
    Prior::Action
}

/// `T_prev_current` of the camera for one commanded action (forward dynamics of SPEC §6).
pub fn action_motion(action: ActionKind, camera_height: f64) -> Isometry3<f64> {
    let model = ActionModel::default();
    let a = match action {
        ActionKind::Forward => PlanAction::Forward,
        ActionKind::TurnLeft => PlanAction::TurnLeft,
        ActionKind::TurnRight => PlanAction::TurnRight,
        ActionKind::Stop => return Isometry3::identity(),
    };
    let origin = PlanarPose::new(0.0, 0.0, 0.0);
    let before = camera_pose_from_planar(&origin, 0.0, camera_height);
    let after = camera_pose_from_planar(&model.apply(&origin, a), 0.0, camera_height);
    before.inverse() * after
}

/// The operator's state (also driven directly by tests).
pub struct Tracker {
    config: Config,
    tracker: TrackerConfig,
    /// Map snapshots by the frame they include, from the one the next frame needs on.
    maps: BTreeMap<u64, Gaussians<f32>>,
    frames: BTreeMap<u64, Frame>,
    actions: BTreeMap<u64, ActionKind>,
    next: u64,
    pose: Isometry3<f64>,
    velocity: Isometry3<f64>,
    exposure: [f64; 2],
    /// The dense tracker's reference keyframes (past tracked frames at their estimates): the
    /// newest, and older ones aligned to again when the robot comes back to their place.
    references: References,
}

impl Tracker {
    /// A tracker at the start anchor with an empty map.
    pub fn from_config(config: Config) -> anyhow::Result<Self> {
        anyhow::ensure!(
            config.camera_height.is_finite() && config.camera_height > 0.0,
            "tracker: camera_height must be > 0"
        );
        anyhow::ensure!(
            (0.0..=1.0).contains(&config.rereference_below),
            "tracker: rereference_below must be in [0, 1], got {}",
            config.rereference_below
        );
        let mut tracker = TrackerConfig::default();
        tracker.dense = tracker.dense.for_ground_robot();
        if let Some(d) = config.downscale {
            tracker.downscale = d;
        }
        if let Some(n) = config.max_iterations {
            tracker.max_iterations = n;
        }
        tracker.validate()?;
        Ok(Self {
            pose: start_anchor(config.camera_height),
            config,
            tracker,
            maps: BTreeMap::new(),
            frames: BTreeMap::new(),
            actions: BTreeMap::new(),
            next: 0,
            velocity: Isometry3::identity(),
            exposure: [0.0, 0.0],
            references: References::new(ReferenceConfig::default())?,
        })
    }

    /// Stores a map snapshot (of frame `frame_id`).
    pub fn set_map(&mut self, frame_id: u64, map: Gaussians<f32>) {
        self.maps.insert(frame_id, map);
    }

    /// Stores an RGB-D frame to track.
    pub fn add_frame(&mut self, frame_id: u64, frame: Frame) {
        self.frames.insert(frame_id, frame);
    }

    /// Stores the action taken at step `step`.
    pub fn add_action(&mut self, step: u64, action: ActionKind) {
        self.actions.insert(step, action);
    }

    /// Tracks every frame whose inputs are complete, in order; returns their estimates.
    pub fn process_ready(&mut self) -> anyhow::Result<Vec<PoseEstimate>> {
        let mut out = Vec::new();
        while let Some(frame) = self.frames.get(&self.next) {
            let k = self.next;
            if k == 0 {
                let small = frame.downscale(self.tracker.downscale);
                self.references
                    .push(DenseReference::new(&small, self.pose, &self.tracker.dense));
                out.push(estimate(
                    k,
                    frame.stamp,
                    &self.pose,
                    TrackingStatus::Ok,
                    0.0,
                    0.0,
                    0,
                ));
            } else {
                let needed = required_snapshot(k, self.config.map_lag);
                let Some(map) = self.maps.get(&needed) else {
                    break;
                };
                let Some(&action) = self.actions.get(&(k - 1)) else {
                    break;
                };
                let previous = self.pose;
                let predicted = match self.config.motion_prior {
                    Prior::Action => previous * action_motion(action, self.config.camera_height),
                    Prior::ConstantVelocity => previous * self.velocity,
                    Prior::None => previous,
                };
                let small = frame.downscale(self.tracker.downscale);
                let references = self.references.select(&predicted);
                let t = track(
                    &self.tracker,
                    map,
                    &small,
                    &predicted,
                    self.exposure,
                    &references,
                )?;
                let status = match t.status {
                    SlamStatus::Ok => TrackingStatus::Ok,
                    SlamStatus::Lost => TrackingStatus::Lost,
                    SlamStatus::Skipped(_) => TrackingStatus::Skipped,
                };
                self.pose = t.pose;
                if status == TrackingStatus::Ok {
                    self.velocity = previous.inverse() * t.pose;
                    self.exposure = t.exposure;
                    if t.reference_overlap < self.config.rereference_below {
                        self.references.push(DenseReference::new(
                            &small,
                            t.pose,
                            &self.tracker.dense,
                        ));
                    }
                }
                out.push(estimate(
                    k,
                    frame.stamp,
                    &self.pose,
                    status,
                    t.residuals.photometric,
                    t.residuals.depth_median,
                    t.iterations as u32,
                ));
                self.actions.remove(&(k - 1));
                self.maps = self.maps.split_off(&needed);
            }
            self.frames.remove(&k);
            self.next += 1;
        }
        Ok(out)
    }
}

fn estimate(
    frame_id: u64,
    stamp: f64,
    pose: &Isometry3<f64>,
    status: TrackingStatus,
    residual_rgb: f64,
    residual_depth: f64,
    iterations: u32,
) -> PoseEstimate {
    PoseEstimate {
        frame_id,
        stamp,
        t_world_camera: pose_to_wire(pose),
        status,
        residual_rgb,
        residual_depth,
        iterations,
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
                "rgbd" => {
                    let view = RgbdFrameView::parse(input.bytes)?;
                    self.add_frame(view.header.frame_id, slam_frame(&view)?);
                }
                "map" => {
                    let (header, map) = read_map(input.bytes)?;
                    self.set_map(header.frame_id, map);
                }
                "action" => {
                    let a: Action = input.decode()?;
                    self.add_action(a.step, a.action);
                }
                other => anyhow::bail!("tracker: unexpected input `{other}`"),
            },
            Event::InputClosed { port: "rgbd" } => return Ok(Flow::Stop),
            _ => return Ok(Flow::Continue),
        }
        for e in self.process_ready()? {
            ctx.send("pose", &e)?;
        }
        Ok(Flow::Continue)
    }
}

/// Registry entry.
pub fn registered() -> Registered {
    const INPUTS: &[PortSpec] = &[
        PortSpec {
            name: "rgbd",
            kind: K::RgbdFrame,
        },
        PortSpec {
            name: "map",
            kind: K::GaussianMap,
        },
        PortSpec {
            name: "action",
            kind: K::Action,
        },
    ];
    const OUTPUTS: &[PortSpec] = &[PortSpec {
        name: "pose",
        kind: K::PoseEstimate,
    }];
    Registered {
        descriptor: OperatorDescriptor {
            name: "tracker",
            summary: "3DGS tracking of each frame against the latest map, no ground truth (SPEC §4)",
            inputs: INPUTS,
            outputs: OUTPUTS,
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
        let f = action_motion(ActionKind::Forward, 0.88);
        assert!((f.translation.vector - nalgebra::Vector3::new(0.0, 0.0, 0.05)).norm() < 1e-12);
        assert!(f.rotation.angle() < 1e-12);
        let l = action_motion(ActionKind::TurnLeft, 0.88);
        assert!(l.translation.vector.norm() < 1e-12);
        assert!((l.rotation.angle() - 5f64.to_radians()).abs() < 1e-12);
        let fwd = l.rotation * nalgebra::Vector3::z();
        assert!(
            fwd.x < -0.08,
            "left turn must swing the optical axis to camera −x: {fwd:?}"
        );
        let r = action_motion(ActionKind::TurnRight, 0.88);
        assert!((r * l).rotation.angle() < 1e-12);
    }

    /// With map lag L = 3, frame k is tracked once the snapshot of frame k − 4 is there: with
    /// only snapshot 0, frames 0–4 come out and frame 5 waits; snapshot 1 releases it. Each
    /// frame is tracked exactly once, in order.
    #[test]
    fn tracking_waits_only_for_the_lagged_snapshot() {
        let frames = crate::mapper::tests::sequence(6);
        let mut tracker = Tracker::from_config(Config {
            camera_height: CAMERA_HEIGHT_M,
            motion_prior: Prior::None,
            downscale: Some(1),
            max_iterations: Some(5),
            rereference_below: 0.85,
            map_lag: 3,
        })
        .unwrap();
        for (k, (frame, _)) in frames.iter().enumerate() {
            tracker.add_frame(k as u64, frame.clone());
            tracker.add_action(k as u64, ActionKind::TurnLeft);
        }
        assert!(
            tracker.process_ready().unwrap().len() == 1,
            "frame 0 needs no map"
        );
        tracker.set_map(0, Gaussians::new());
        let ids: Vec<u64> = tracker
            .process_ready()
            .unwrap()
            .iter()
            .map(|e| e.frame_id)
            .collect();
        assert_eq!(ids, vec![1, 2, 3, 4]);
        tracker.set_map(1, Gaussians::new());
        let ids: Vec<u64> = tracker
            .process_ready()
            .unwrap()
            .iter()
            .map(|e| e.frame_id)
            .collect();
        assert_eq!(ids, vec![5]);
        assert!(tracker.process_ready().unwrap().is_empty());
    }
}
