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
use activemap_sim::ActuationNoise;
use activemap_slam::{
    Frame, KeyframeGraphConfig, LostReason, MotionCheck, MotionPrior, TrackedFrame, TrackingConfig,
    TrackingSession, TrackingStatus as SlamStatus, YawSearch,
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
    /// Which overlap `rereference_below` is compared with: `associated` (the pixels the aligner
    /// pairs with the reference, the default) or `covisible` (the pixels the reference also
    /// sees, which depth noise does not lower; `activemap_slam::ReferenceOverlap`).
    #[serde(default)]
    pub rereference_overlap: activemap_slam::ReferenceOverlap,
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
    /// The check of each solution against the commanded action (`activemap_slam::MotionCheck`,
    /// with `motion_prior: action` only): a solution farther than `max_translation_m` or
    /// `max_rotation_deg` from every motion the action could have made (a blocked step moves
    /// less) is a tracking failure (`Lost`, reason `MotionMismatch`) and the frame keeps the
    /// prediction; `confirm_frames` consecutive agreeing solutions are taken (a
    /// relocalisation). `null` turns the check off.
    #[serde(default = "default_motion_check")]
    pub motion_check: Option<MotionCheckConfig>,
    /// The relocaliser of a lost frame (`activemap_slam::YawSearch`): a frame lost for its
    /// depth or colour residual or its overlap is aligned again from `yaw_hypotheses` evenly
    /// spaced yaws about the prediction's position; a solution the alignment accepts on its own,
    /// confirmed by `confirm_frames` consecutive agreeing frames, is taken (a relocalisation:
    /// the robot spun or slid on a turn without the tracker knowing). `null` turns it off.
    #[serde(default = "default_yaw_search")]
    pub yaw_search: Option<YawSearch>,
    /// The per-pixel depth of a Gaussian in the tracker's renders (`centre` or `plane`); must
    /// match the mapper's `tuning.depth_model` (library default when absent).
    #[serde(default)]
    pub depth_model: Option<activemap_splat::DepthModel>,
    /// The dense aligner's depth-noise model and normals (`activemap_slam::DenseConfig`); any
    /// field left out keeps the library default.
    #[serde(default)]
    pub dense: DenseTuning,
}

/// The `tracker` node's `dense` key: the parts of `activemap_slam::DenseConfig` a sensor calls
/// for.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DenseTuning {
    /// σ_d at depth 0, metres (`depth_sigma`, 0.005).
    pub depth_sigma: Option<f64>,
    /// Quadratic growth of σ_d with depth, 1/metres (`depth_sigma_z2`, 0; the RealSense D435:
    /// 0.0036).
    pub depth_sigma_z2: Option<f64>,
    /// Baseline of the normals' central differences, pixels (`normal_step`, 1).
    pub normal_step: Option<usize>,
    /// Grey-level residuals whose reference interpolation cell spans more than this range are
    /// left out (`colour_edge_range`, 0: none; an image sampled at pixel centres has edges that
    /// do not move with sub-pixel motion).
    pub colour_edge_range: Option<f64>,
    /// Standard deviations of the motion prior between consecutive frames, per camera axis
    /// (`DenseConfig::prior_axis_sigmas`); any field left out keeps the ground-robot default.
    /// Unset, a flow whose simulator perturbs the actions implies [`motion_sigmas_for`] its
    /// actuation noise (`crate::checks::implied_overrides`).
    pub motion_sigmas: Option<MotionSigmas>,
}

/// The `tracker` node's `dense.motion_sigmas`: how far one frame's motion may differ from the
/// commanded one, per axis of the camera (optical frame: x right, y down, z forward).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MotionSigmas {
    /// Sideways (x), metres (`activemap_slam::dense::GROUND_LATERAL_SIGMA`, 0.01).
    pub lateral_m: Option<f64>,
    /// Height (y), metres (`activemap_slam::dense::GROUND_VERTICAL_SIGMA`, 0.003).
    pub vertical_m: Option<f64>,
    /// Along the view (z), metres (`prior_translation_sigma`, 0.05).
    pub forward_m: Option<f64>,
    /// Pitch and roll, degrees (`activemap_slam::dense::GROUND_TILT_SIGMA_DEG`, 0.25).
    pub tilt_deg: Option<f64>,
    /// Yaw (about y), degrees (`prior_rotation_sigma`, 3).
    pub yaw_deg: Option<f64>,
}

impl MotionSigmas {
    /// Each key with its value, the prior's axes it sets (τ = [ρx, ρy, ρz, θx, θy, θz]:
    /// sideways, height, forward, pitch, yaw, roll) and the factor to the prior's units.
    fn entries(&self) -> [(&'static str, Option<f64>, &'static [usize], f64); 5] {
        let degree = 1f64.to_radians();
        [
            ("lateral_m", self.lateral_m, &[0], 1.0),
            ("vertical_m", self.vertical_m, &[1], 1.0),
            ("forward_m", self.forward_m, &[2], 1.0),
            ("tilt_deg", self.tilt_deg, &[3, 5], degree),
            ("yaw_deg", self.yaw_deg, &[4], degree),
        ]
    }

    /// The flow-file form of the keys that are set, `{lateral_m: 0.002, yaw_deg: 1.32}`.
    pub fn to_yaml(&self) -> String {
        let fields: Vec<String> = self
            .entries()
            .into_iter()
            .filter_map(|(key, v, _, _)| v.map(|v| format!("{key}: {v}")))
            .collect();
        format!("{{{}}}", fields.join(", "))
    }
}

/// The slack of [`motion_sigmas_for`]: each axis of the prior allows this many standard
/// deviations of the actuation noise on it.
pub const ACTUATION_SIGMAS: f64 = 2.0;
/// The smallest translation σ [`motion_sigmas_for`] gives, metres: wheel slip and the
/// estimate's own frame-to-frame error, which the actuation model leaves out (sideways it has
/// no noise at all).
pub const MIN_TRANSLATION_SIGMA_M: f64 = 0.002;

/// The motion prior of a robot whose actions carry `actuation` noise (SPEC §4's prior, at the
/// platform's own odometry noise rather than the ground-robot default): forward
/// [`ACTUATION_SIGMAS`]·σ of a step's length, sideways the heading noise's drift over a step,
/// each at least [`MIN_TRANSLATION_SIGMA_M`], and yaw [`ACTUATION_SIGMAS`]·σ of the larger of a
/// turn's and a step's heading noise (one σ serves both actions). Height and tilt keep the
/// ground-robot default. The realistic preset gives 2 mm sideways, 5.6 mm forward and 1.32° of
/// yaw (default: 1 cm, 5 cm, 3°); measured in docs/src/slam.md ("The motion prior at the
/// actuation noise"). `None` for exact actions.
pub fn motion_sigmas_for(actuation: &ActuationNoise, robot: &RobotModel) -> Option<MotionSigmas> {
    if !actuation.is_active() {
        return None;
    }
    let step = robot.forward_step_m;
    let sideways = step * actuation.heading_sigma_deg.to_radians().sin();
    let translation = |sigma: f64| (ACTUATION_SIGMAS * sigma).max(MIN_TRANSLATION_SIGMA_M);
    Some(MotionSigmas {
        lateral_m: Some(translation(sideways)),
        vertical_m: None,
        forward_m: Some(translation(actuation.forward_sigma(step))),
        tilt_deg: None,
        yaw_deg: Some(ACTUATION_SIGMAS * actuation.turn_sigma_deg.max(actuation.heading_sigma_deg))
            .filter(|y| *y > 0.0),
    })
}

/// The `tracker` node's `motion_check` (defaults: [`MotionCheck::default`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MotionCheckConfig {
    /// Largest distance from the feasible motions, metres (0.04).
    pub max_translation_m: f64,
    /// Largest angle from the commanded rotation, degrees (3).
    pub max_rotation_deg: f64,
    /// Agreeing rejected solutions after which one is taken (3).
    pub confirm_frames: u32,
}

impl Default for MotionCheckConfig {
    fn default() -> Self {
        let c = MotionCheck::default();
        Self {
            max_translation_m: c.max_translation_m,
            max_rotation_deg: c.max_rotation_rad.to_degrees(),
            confirm_frames: c.confirm_frames,
        }
    }
}

fn default_yaw_search() -> Option<YawSearch> {
    Some(YawSearch::default())
}

fn default_motion_check() -> Option<MotionCheckConfig> {
    Some(MotionCheckConfig::default())
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
            rereference_overlap: self.rereference_overlap,
            map_lag: self.map_lag,
            initial_pose: start_anchor(&self.robot),
            pose_graph: self.pose_graph.then(KeyframeGraphConfig::default),
            motion_check: self
                .motion_check
                .filter(|_| self.motion_prior == Prior::Action)
                .map(|c| MotionCheck {
                    max_translation_m: c.max_translation_m,
                    max_rotation_rad: c.max_rotation_deg.to_radians(),
                    confirm_frames: c.confirm_frames,
                }),
            yaw_search: self.yaw_search,
            ..TrackingConfig::default()
        };
        if let Some(d) = self.downscale {
            config.tracker.downscale = d;
        }
        if let Some(d) = self.depth_model {
            config.tracker.depth_model = d;
        }
        if let Some(n) = self.max_iterations {
            config.tracker.max_iterations = n;
        }
        let dense = &mut config.tracker.dense;
        if let Some(v) = self.dense.depth_sigma {
            dense.depth_sigma = v;
        }
        if let Some(v) = self.dense.depth_sigma_z2 {
            dense.depth_sigma_z2 = v;
        }
        if let Some(v) = self.dense.normal_step {
            dense.normal_step = v;
        }
        if let Some(v) = self.dense.colour_edge_range {
            dense.colour_edge_range = v;
        }
        if let Some(m) = self.dense.motion_sigmas {
            let sigmas = &mut dense.prior_axis_sigmas;
            for (key, value, indices, to_internal) in m.entries() {
                let Some(v) = value else { continue };
                if !(v.is_finite() && v > 0.0) {
                    anyhow::bail!(
                        "tracker: dense.motion_sigmas.{key} = {v}: must be finite and > 0 \
                         (leave it out for the default)"
                    );
                }
                for &i in indices {
                    sigmas[i] = v * to_internal;
                }
            }
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
    /// Tracking failures and relocalisations so far.
    events: TrackingEvents,
    /// The input ports closed so far.
    closed: std::collections::BTreeSet<String>,
}

/// What the tracker reported of its own failures over an episode: the log's tally.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TrackingEvents {
    /// Frames reported `Lost`.
    pub lost_frames: u64,
    /// Runs of consecutive lost frames (each logged when it begins).
    pub lost_runs: u64,
    /// Frames whose estimate jumped to a solution the motion check had rejected.
    pub relocalisations: u64,
    /// The current run of lost frames (0 while tracking).
    lost_in_row: u64,
    /// The reason of the last lost frame of the current run.
    last_reason: Option<LostReason>,
}

impl Tracker {
    /// A tracker at the start anchor with an empty map.
    pub fn from_config(config: Config) -> anyhow::Result<Self> {
        Ok(Self {
            session: TrackingSession::new(config.tracking_config()?)?,
            config,
            events: TrackingEvents::default(),
            closed: Default::default(),
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
    }

    /// Whether the node is done: no frame will come any more (`rgbd` closed) and every frame
    /// received has its estimate, or the snapshots or motions a waiting frame needs will not
    /// come either (`map` or `action` closed). Stopping as soon as `rgbd` closed lost the last
    /// frame's estimate whenever its map snapshot was still on its way.
    pub fn done(&self) -> bool {
        self.closed.contains(inputs::RGBD)
            && (self.session.pending_frames() == 0
                || self.closed.contains(inputs::MAP)
                || self.closed.contains(inputs::ACTION))
    }

    /// The tracking failures and relocalisations reported so far.
    pub fn events(&self) -> &TrackingEvents {
        &self.events
    }

    /// The log lines of `frame`'s tracking events (issue 34: tracking never fails silently):
    /// the first frame of a run of lost frames, with the reason; a lost frame whose reason
    /// differs in kind from the previous frame's; the first frame tracked again after a run,
    /// with its length; a relocalisation. Counts the events; call it once per frame, in order
    /// (a skipped frame neither starts nor ends a run).
    pub fn event_lines(&mut self, frame: &TrackedFrame) -> Vec<String> {
        let id = frame.frame_id;
        let mut lines = Vec::new();
        let events = &mut self.events;
        match frame.status {
            SlamStatus::Lost(reason) => {
                events.lost_frames += 1;
                events.lost_in_row += 1;
                let same_kind = matches!(events.last_reason, Some(p)
                    if std::mem::discriminant(&p) == std::mem::discriminant(&reason));
                if events.lost_in_row == 1 {
                    events.lost_runs += 1;
                    lines.push(format!("tracker: frame {id}: tracking lost: {reason}"));
                } else if !same_kind {
                    lines.push(format!(
                        "tracker: frame {id}: still lost ({} frames): {reason}",
                        events.lost_in_row
                    ));
                }
                events.last_reason = Some(reason);
            }
            SlamStatus::Ok => {
                let run = std::mem::take(&mut events.lost_in_row);
                events.last_reason = None;
                if run > 0 {
                    lines.push(format!(
                        "tracker: frame {id}: tracking regained after {run} lost frame(s)"
                    ));
                }
            }
            SlamStatus::Skipped(_) => {}
        }
        if let Some(r) = &frame.relocalised {
            events.relocalisations += 1;
            lines.push(format!("tracker: frame {id}: relocalised: {r}"));
        }
        lines
    }

    /// Tracks every frame whose inputs are complete, in order; returns their estimates. Logs
    /// each loop closure of the pose graph that moved a keyframe by a centimetre or more.
    pub fn process_ready(&mut self) -> anyhow::Result<Vec<PoseEstimate>> {
        let tracked = self.session.process_ready()?;
        for t in &tracked {
            for line in self.event_lines(t) {
                eprintln!("{line}");
            }
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
            SlamStatus::Lost(_) => TrackingStatus::Lost,
            SlamStatus::Skipped(_) => TrackingStatus::Skipped,
        },
        lost_reason: match t.status {
            SlamStatus::Lost(r) => Some(r),
            _ => None,
        },
        relocalised: t.relocalised,
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
            Event::InputClosed { port } => {
                self.closed.insert(port.to_string());
            }
            _ => return Ok(Flow::Continue),
        }
        for e in self.process_ready()? {
            ctx.send(outputs::POSE, &e)?;
        }
        Ok(if self.done() {
            Flow::Stop
        } else {
            Flow::Continue
        })
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

    /// The node's `dense` key reaches the aligner, fields left out keep the library's
    /// defaults, and a bad value is refused naming its field.
    #[test]
    fn the_dense_key_sets_the_aligners_noise_model() {
        let config: Config = serde_json::from_value(serde_json::json!({
            "dense": { "depth_sigma_z2": 0.0036, "normal_step": 2, "colour_edge_range": 0.05 }
        }))
        .unwrap();
        let dense = config.tracking_config().unwrap().tracker.dense;
        assert_eq!(
            (
                dense.depth_sigma,
                dense.depth_sigma_z2,
                dense.normal_step,
                dense.colour_edge_range
            ),
            (0.005, 0.0036, 2, 0.05)
        );
        let bad: Config =
            serde_json::from_value(serde_json::json!({ "dense": { "depth_sigma_z2": -1.0 } }))
                .unwrap();
        let e = bad.tracking_config().unwrap_err().to_string();
        assert!(e.contains("dense.depth_sigma_z2"), "{e}");
        let zero: Config =
            serde_json::from_value(serde_json::json!({ "dense": { "normal_step": 0 } })).unwrap();
        assert!(zero.tracking_config().is_err());
        assert!(
            serde_json::from_value::<Config>(serde_json::json!({ "dense": { "sigma": 1 } }))
                .is_err()
        );
    }

    /// `rereference_overlap` reaches the session (`associated` when absent); an unknown
    /// measure is refused.
    #[test]
    fn the_rereference_overlap_key_picks_the_measure() {
        let parse = |v| serde_json::from_value::<Config>(v);
        let default = parse(serde_json::json!({})).unwrap();
        assert_eq!(
            default.tracking_config().unwrap().rereference_overlap,
            activemap_slam::ReferenceOverlap::Associated
        );
        let covisible = parse(serde_json::json!({ "rereference_overlap": "covisible" })).unwrap();
        assert_eq!(
            covisible.tracking_config().unwrap().rereference_overlap,
            activemap_slam::ReferenceOverlap::Covisible
        );
        let e = parse(serde_json::json!({ "rereference_overlap": "visible" })).unwrap_err();
        assert!(e.to_string().contains("covisible"), "{e}");
    }

    /// `dense.motion_sigmas` sets the motion prior's per-axis σ (degrees read as radians, tilt
    /// on pitch and roll), leaves the axes it omits at the ground-robot default, and refuses a
    /// σ that is not positive, naming the key.
    #[test]
    fn motion_sigmas_set_the_prior_per_axis() {
        let parse = |v| {
            serde_json::from_value::<Config>(v)
                .unwrap()
                .tracking_config()
        };
        let default = parse(serde_json::json!({})).unwrap().tracker.dense;
        let set = parse(serde_json::json!({
            "dense": { "motion_sigmas": { "lateral_m": 0.002, "yaw_deg": 1.0, "tilt_deg": 0.5 } }
        }))
        .unwrap()
        .tracker
        .dense;
        let sigmas = set.prior_axis_sigmas;
        assert_eq!(sigmas[0], 0.002);
        assert_eq!(sigmas[1], default.prior_axis_sigmas[1]);
        assert_eq!(sigmas[2], default.prior_axis_sigmas[2]);
        assert!((sigmas[3] - 0.5f64.to_radians()).abs() < 1e-15);
        assert!((sigmas[4] - 1f64.to_radians()).abs() < 1e-15);
        assert_eq!(sigmas[3], sigmas[5]);
        for bad in [0.0, -0.001] {
            let e =
                parse(serde_json::json!({ "dense": { "motion_sigmas": { "forward_m": bad } } }))
                    .unwrap_err();
            assert!(
                e.to_string().contains("dense.motion_sigmas.forward_m"),
                "{e}"
            );
        }
        let e = serde_json::from_value::<Config>(serde_json::json!({
            "dense": { "motion_sigmas": { "sideways_m": 0.002 } }
        }))
        .unwrap_err();
        assert!(e.to_string().contains("lateral_m"), "{e}");
    }

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
            rereference_overlap: Default::default(),
            map_lag: 0,
            pose_graph: false,
            motion_check: default_motion_check(),
            yaw_search: default_yaw_search(),
            depth_model: None,
            dense: DenseTuning::default(),
        })
        .unwrap();
        assert_eq!(tracker.set_map(h.frame_id, map), 3);
    }

    /// The node stops once no frame will come and every frame received has its estimate: a
    /// frame still waiting for its map snapshot when `rgbd` closes is tracked when the
    /// snapshot comes (the last frame's estimate used to be lost in that race), and a frame
    /// whose snapshot will never come (`map` closed) does not keep the node alive.
    #[test]
    fn the_node_stops_only_when_every_received_frame_is_tracked_or_cannot_be() {
        let config: Config = serde_json::from_value(serde_json::json!({})).unwrap();
        let mut tracker = Tracker::from_config(config).unwrap();
        let k = activemap_geometry::Intrinsics::from_hfov(16, 16, std::f64::consts::FRAC_PI_2);
        let frame = |stamp| {
            let rgb = (0..256)
                .map(|i| [0.2 + 0.002 * i as f32, 0.5, 0.3])
                .collect();
            Frame::new(k, rgb, vec![2.0; 256], stamp).unwrap()
        };
        tracker.add_frame(0, frame(0.0));
        assert_eq!(
            tracker.process_ready().unwrap().len(),
            1,
            "frame 0 needs no map"
        );
        tracker.add_frame(1, frame(0.1));
        tracker.add_action(0, ActionKind::TurnLeft);
        assert!(
            tracker.process_ready().unwrap().is_empty(),
            "frame 1 waits for map 0"
        );
        tracker.closed.insert(inputs::RGBD.to_string());
        assert!(!tracker.done(), "frame 1 is still to be tracked");
        tracker.set_map(0, Gaussians::new());
        assert_eq!(tracker.process_ready().unwrap().len(), 1);
        assert!(tracker.done());
        // A frame whose snapshot will never come.
        let mut tracker =
            Tracker::from_config(serde_json::from_value(serde_json::json!({})).unwrap()).unwrap();
        tracker.add_frame(0, frame(0.0));
        tracker.add_frame(1, frame(0.1));
        tracker.add_action(0, ActionKind::Forward);
        tracker.process_ready().unwrap();
        tracker.closed.insert(inputs::RGBD.to_string());
        assert!(!tracker.done());
        tracker.closed.insert(inputs::MAP.to_string());
        assert!(tracker.done());
    }

    /// Issue 34: tracking never fails silently. A run of lost frames is logged when it begins
    /// (with its reason), when the reason changes kind and when it ends; a relocalisation is
    /// logged; the wire estimate carries the reason. The motion check is on by default and
    /// off with `motion_check: null` or another motion prior; the yaw search likewise.
    #[test]
    fn lost_runs_regains_and_relocalisations_are_logged_and_carried_on_the_wire() {
        let config: Config = serde_json::from_value(serde_json::json!({})).unwrap();
        let check = config.tracking_config().unwrap().motion_check.unwrap();
        let default = MotionCheck::default();
        assert_eq!(check.max_translation_m, default.max_translation_m);
        assert!((check.max_rotation_rad - default.max_rotation_rad).abs() < 1e-12);
        assert_eq!(check.confirm_frames, default.confirm_frames);
        let off: Config =
            serde_json::from_value(serde_json::json!({ "motion_check": null })).unwrap();
        assert_eq!(off.tracking_config().unwrap().motion_check, None);
        let cv: Config =
            serde_json::from_value(serde_json::json!({ "motion_prior": "constant_velocity" }))
                .unwrap();
        assert_eq!(cv.tracking_config().unwrap().motion_check, None);
        let bad = serde_json::json!({ "motion_check": { "max_translation_m": 0.0 } });
        let e = Tracker::from_config(serde_json::from_value(bad).unwrap())
            .err()
            .unwrap();
        assert!(e.to_string().contains("max_translation_m"), "{e}");
        // The yaw search: on by default, off with `null`, checked.
        assert_eq!(
            config.tracking_config().unwrap().yaw_search,
            Some(YawSearch::default())
        );
        let off: Config =
            serde_json::from_value(serde_json::json!({ "yaw_search": null })).unwrap();
        assert_eq!(off.tracking_config().unwrap().yaw_search, None);
        let one = serde_json::json!({ "yaw_search": { "yaw_hypotheses": 1 } });
        let e = Tracker::from_config(serde_json::from_value(one).unwrap())
            .err()
            .unwrap();
        assert!(e.to_string().contains("yaw_hypotheses"), "{e}");

        let mut tracker = Tracker::from_config(config).unwrap();
        let frame = |id: u64, status: SlamStatus| TrackedFrame {
            frame_id: id,
            stamp: id as f64,
            pose: Isometry3::identity(),
            status,
            residuals: Default::default(),
            iterations: 10,
            seconds: 0.0,
            loop_closure: None,
            graph_anchor: None,
            relocalised: None,
        };
        let overlap = SlamStatus::Lost(LostReason::LowOverlap { fraction: 0.12 });
        let jump = SlamStatus::Lost(LostReason::MotionMismatch {
            translation_m: 0.32,
            rotation_deg: 1.0,
        });
        let statuses = [
            SlamStatus::Ok,
            overlap,
            SlamStatus::Lost(LostReason::LowOverlap { fraction: 0.05 }),
            SlamStatus::Skipped(activemap_slam::SkipReason::NoDepth),
            jump,
            SlamStatus::Ok,
            SlamStatus::Ok,
        ];
        let lines: Vec<Vec<String>> = statuses
            .iter()
            .enumerate()
            .map(|(k, s)| tracker.event_lines(&frame(k as u64, *s)))
            .collect();
        assert!(lines[0].is_empty() && lines[2].is_empty() && lines[3].is_empty());
        assert!(lines[6].is_empty());
        assert_eq!(
            lines[1],
            ["tracker: frame 1: tracking lost: only 12 % of the depth pixels overlap the map"]
        );
        assert!(
            lines[4][0]
                .starts_with("tracker: frame 4: still lost (3 frames): the solution lies 32.0 cm"),
            "{:?}",
            lines[4]
        );
        assert_eq!(
            lines[5],
            ["tracker: frame 5: tracking regained after 3 lost frame(s)"]
        );
        let mut relocated = frame(7, SlamStatus::Ok);
        relocated.relocalised = Some(activemap_slam::Relocalisation {
            translation_m: 0.3,
            rotation_deg: 0.0,
            frames: 3,
        });
        let line = tracker.event_lines(&relocated);
        assert!(line[0].starts_with("tracker: frame 7: relocalised: took a solution 30.0 cm"));
        assert_eq!(
            (tracker.events().lost_frames, tracker.events().lost_runs),
            (3, 1)
        );
        assert_eq!(tracker.events().relocalisations, 1);
        let wire = estimate(&frame(4, jump));
        assert_eq!(wire.status, TrackingStatus::Lost);
        assert_eq!(
            wire.lost_reason,
            Some(LostReason::MotionMismatch {
                translation_m: 0.32,
                rotation_deg: 1.0
            })
        );
        assert_eq!(estimate(&relocated).relocalised.unwrap().frames, 3);
        assert_eq!(estimate(&frame(5, SlamStatus::Ok)).lost_reason, None);
    }
}
