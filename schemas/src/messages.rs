//! The small (serde + postcard) messages of the pipeline, SPEC §1.

use activemap_geometry::robot::Action as RobotAction;
use serde::{Deserialize, Serialize};

use crate::small::SmallMessage;

macro_rules! small_message {
    ($ty:ident, $version:expr) => {
        impl SmallMessage for $ty {
            const TYPE_NAME: &'static str = stringify!($ty);
            const VERSION: u16 = $version;
        }
    };
}

/// A rigid pose `T_world_camera` (SPEC §2): translation in metres and unit quaternion (x, y, z, w).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Translation, metres.
    pub translation: [f64; 3],
    /// Rotation quaternion, (x, y, z, w) as in TUM files.
    pub rotation_xyzw: [f64; 4],
}

impl Pose {
    /// The identity pose.
    pub const IDENTITY: Self = Self {
        translation: [0.0; 3],
        rotation_xyzw: [0.0, 0.0, 0.0, 1.0],
    };
}

/// A pose on the motion plane: x, y in metres (world frame) and yaw in radians about world z.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PlanarPose2 {
    /// World x, metres.
    pub x: f64,
    /// World y, metres.
    pub y: f64,
    /// Heading about world z, radians.
    pub yaw: f64,
}

/// What the follower tells the robot for one step on the wire (SPEC §1): one of the robot's
/// actions ([`activemap_geometry::robot::Action`]: forward 5 cm, turn 5° left or right), or
/// stop (the episode is over). The variants mirror the robot action's in order, so the two
/// convert through [`ActionKind::robot_action`] and `From` alone.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ActionKind {
    /// Move forward one step.
    Forward,
    /// Turn left one step.
    TurnLeft,
    /// Turn right one step.
    TurnRight,
    /// End the episode.
    Stop,
}

impl ActionKind {
    /// The robot action to execute; `None` for [`ActionKind::Stop`].
    pub fn robot_action(self) -> Option<RobotAction> {
        match self {
            ActionKind::Forward => Some(RobotAction::Forward),
            ActionKind::TurnLeft => Some(RobotAction::TurnLeft),
            ActionKind::TurnRight => Some(RobotAction::TurnRight),
            ActionKind::Stop => None,
        }
    }
}

impl From<RobotAction> for ActionKind {
    fn from(a: RobotAction) -> Self {
        match a {
            RobotAction::Forward => ActionKind::Forward,
            RobotAction::TurnLeft => ActionKind::TurnLeft,
            RobotAction::TurnRight => ActionKind::TurnRight,
        }
    }
}

/// The follower's action for one simulator step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Action {
    /// Step index the action answers (frame id of the frame it was computed from).
    pub step: u64,
    /// What to do.
    pub action: ActionKind,
}
small_message!(Action, 1);

/// Tracker outcome for one frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum TrackingStatus {
    /// The optimisation converged.
    Ok,
    /// Tracking failed; the pose is a prediction.
    Lost,
    /// The frame was not tracked (e.g. the map is still empty).
    Skipped,
}

/// Why the tracker reported a frame [`TrackingStatus::Lost`]: the check that failed and what it
/// measured (`activemap_slam` decides it).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum LostReason {
    /// Too few valid-depth pixels overlap the references or the map: the fraction that does.
    LowOverlap {
        /// The overlapping fraction.
        fraction: f64,
    },
    /// The depth residual of the solution, metres, beyond its limit.
    DepthResidual {
        /// The residual, metres.
        metres: f64,
    },
    /// The colour residual of the map's render beyond its limit.
    ColourResidual {
        /// The mean absolute colour residual.
        residual: f64,
    },
    /// The solution lies beyond what the commanded action and the actuation noise allow; the
    /// estimate is the prediction.
    MotionMismatch {
        /// Distance from the feasible motions, metres.
        translation_m: f64,
        /// Angle from the commanded rotation, degrees.
        rotation_deg: f64,
    },
    /// The optimiser returned a non-finite pose.
    NonFinite,
}

impl LostReason {
    /// The reason's name in reports and tallies: `low_overlap`, `depth_residual`,
    /// `colour_residual`, `motion_mismatch`, `non_finite`.
    pub fn key(&self) -> &'static str {
        match self {
            Self::LowOverlap { .. } => "low_overlap",
            Self::DepthResidual { .. } => "depth_residual",
            Self::ColourResidual { .. } => "colour_residual",
            Self::MotionMismatch { .. } => "motion_mismatch",
            Self::NonFinite => "non_finite",
        }
    }
}

impl std::fmt::Display for LostReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::LowOverlap { fraction } => write!(
                f,
                "only {:.0} % of the depth pixels overlap the map",
                100.0 * fraction
            ),
            Self::DepthResidual { metres } => {
                write!(f, "depth residual {:.1} cm", 100.0 * metres)
            }
            Self::ColourResidual { residual } => write!(f, "colour residual {residual:.3}"),
            Self::MotionMismatch {
                translation_m,
                rotation_deg,
            } => write!(
                f,
                "the solution lies {:.1} cm and {rotation_deg:.1}° from any motion the commanded \
                 action could have made",
                100.0 * translation_m
            ),
            Self::NonFinite => write!(f, "the optimiser returned a non-finite pose"),
        }
    }
}

impl std::fmt::Display for Relocalisation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "took a solution {:.1} cm and {:.1}° from the commanded motion, after {} consecutive \
             solutions agreed with each other",
            100.0 * self.translation_m,
            self.rotation_deg,
            self.frames
        )
    }
}

/// A solution the tracker's motion check had rejected and then took, once consecutive
/// solutions agreed with each other: the jump of the estimate it made.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Relocalisation {
    /// Distance of the taken solution from the motions the commanded action allows, metres.
    pub translation_m: f64,
    /// Angle from the commanded rotation, degrees.
    pub rotation_deg: f64,
    /// The agreeing consecutive solutions that confirmed it.
    pub frames: u32,
}

/// How the tracker's keyframe pose graph moved the keyframe made from frame `frame_id` when it
/// was re-optimised: the world-frame rigid motion `T_after · T_before⁻¹`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct KeyframeCorrection {
    /// The frame the graph keyframe was made from.
    pub frame_id: u64,
    /// `T_after · T_before⁻¹` (world frame).
    pub correction: Pose,
}

/// The tracker's pose estimate for one frame (SPEC §4). Version 2 added `graph_anchor` and
/// `keyframe_corrections`, version 3 `lost_reason` and `relocalised`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PoseEstimate {
    /// Frame the estimate belongs to.
    pub frame_id: u64,
    /// Frame stamp, seconds.
    pub stamp: f64,
    /// Estimated `T_world_camera`.
    pub t_world_camera: Pose,
    /// Tracking status.
    pub status: TrackingStatus,
    /// Final photometric residual (mean absolute).
    pub residual_rgb: f64,
    /// Final depth residual (mean absolute, metres).
    pub residual_depth: f64,
    /// Optimiser iterations used.
    pub iterations: u32,
    /// With the tracker's pose graph: the frame of the graph keyframe this estimate hangs on
    /// (the newest one when the frame was tracked). `None` without the graph.
    pub graph_anchor: Option<u64>,
    /// When this frame closed a loop and the pose graph was re-optimised: the graph keyframes
    /// that moved (beyond a small threshold) since their last correction, in frame order; the
    /// mapper moves its keyframes hung on them, and their Gaussians, before mapping this frame.
    /// Empty otherwise, and always without the graph.
    pub keyframe_corrections: Vec<KeyframeCorrection>,
    /// Why the frame is `Lost` (`None` for every other status).
    pub lost_reason: Option<LostReason>,
    /// When this frame's estimate jumped to a solution the motion check had rejected before.
    pub relocalised: Option<Relocalisation>,
}
small_message!(PoseEstimate, 3);

/// Ground-truth camera pose from the simulator. Evaluation-only: no operator of the loop may read it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TruePose {
    /// Frame the pose belongs to.
    pub frame_id: u64,
    /// Frame stamp, seconds.
    pub stamp: f64,
    /// True `T_world_camera`.
    pub t_world_camera: Pose,
}
small_message!(TruePose, 1);

/// One frontier region: connected free cells bordering unknown space (SPEC §6).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrontierRegion {
    /// Index shown to the LLM (0..N−1).
    pub id: u32,
    /// Number of cells in the region.
    pub size_cells: u32,
    /// Centroid in world (x, y), metres.
    pub centroid: [f64; 2],
    /// Grid cell (ix, iy) of the region closest to the robot that is reachable.
    pub closest_reachable_cell: [i32; 2],
    /// Path length (metres) from the robot to `closest_reachable_cell` over cells the robot
    /// fits in (what FBE "nearest" ranks by, SPEC §6).
    pub path_distance_m: f64,
    /// World (x, y), metres, of the region's frontier cell nearest its centroid (where the
    /// LLM's BEV draws its number, SPEC §7).
    pub anchor: [f64; 2],
}

/// The frontier regions of one occupancy grid.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Frontiers {
    /// Frame the grid was built from.
    pub frame_id: u64,
    /// Stamp, seconds.
    pub stamp: f64,
    /// The regions, largest first.
    pub regions: Vec<FrontierRegion>,
}
small_message!(Frontiers, 3);

/// The planner's choice: a frontier to explore (or −1: refine the existing map, SPEC §7).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Goal {
    /// Frame the decision was made on.
    pub frame_id: u64,
    /// Chosen frontier id, or −1 for "refine".
    pub target: i32,
    /// Centre the scorer samples candidate poses around.
    pub focus: [f64; 2],
}
small_message!(Goal, 1);

/// A path of planar waypoints from the Fisher scorer (SPEC §5, §6).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Path {
    /// Frame the path was planned on.
    pub frame_id: u64,
    /// Waypoints from the robot to the goal.
    pub waypoints: Vec<PlanarPose2>,
    /// The scorer's value of the path, lower is better: its Fisher objective (e.g.
    /// Σ C_local − η·log EIG) in `fisher` mode, the A* cost in `shortest` mode, +∞ for an
    /// empty path (none found) or a look-around.
    pub objective: f64,
}
small_message!(Path, 1);

/// Why a replan is requested (SPEC §1: path done, or an obstacle appeared).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ReplanReason {
    /// No path yet.
    Startup,
    /// The current path was completed.
    PathDone,
    /// The map now shows an obstacle close to the path.
    ObstacleAhead,
    /// The planner found no path.
    NoPath,
    /// The robot made no progress along its path for too many steps (a collision, a slide,
    /// or an estimate that disagrees with the world): the goal counts as failed.
    Stuck,
    /// Tracking was lost and has recovered: the old path was planned on a pose that may be
    /// wrong.
    TrackingLost,
    /// Forward moves did not move the robot (by the tracked pose): something the map does not
    /// show, or the robot grazing an obstacle's margin, blocks the way. The goal is not at
    /// fault (stuck detection still judges a goal that keeps failing this way).
    Blocked,
}

/// Request from the follower to plan again.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ReplanRequest {
    /// Frame at which the request was made.
    pub frame_id: u64,
    /// Why.
    pub reason: ReplanReason,
}
small_message!(ReplanRequest, 3);

/// Episode state.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum EpisodeState {
    /// Steps remain.
    Running,
    /// `max_steps` reached or a stop action taken.
    Finished,
    /// The simulator failed.
    Failed,
}

/// Progress of the episode, published by the simulator each step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeStatus {
    /// Steps taken so far.
    pub step: u64,
    /// Step budget.
    pub max_steps: u64,
    /// State.
    pub state: EpisodeState,
    /// Human-readable note (scene, reason for failure).
    pub message: String,
}
small_message!(EpisodeStatus, 1);

/// A candidate goal pose of a Fisher replan and its EIG against the model Fisher (SPEC §6).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FisherCandidate {
    /// World x, metres.
    pub x: f64,
    /// World y, metres.
    pub y: f64,
    /// Heading (facing the focus), radians.
    pub yaw: f64,
    /// `EIG(x) = Σ_k H_k(x)/I_k`.
    pub eig: f64,
}

/// A path to one of the top candidates of a Fisher replan, with the terms of its objective
/// (SPEC §5). Non-finite values (+∞ for a pose that sees nothing) go through as they are.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FisherPath {
    /// The candidate it leads to.
    pub goal: PlanarPose2,
    /// Number of waypoints of the path.
    pub waypoints: u32,
    /// Actions of the follower's rollout along it (before any cut).
    pub actions: u32,
    /// Index (1-based, in actions) of each scored pose.
    pub scored_steps: Vec<u32>,
    /// Path EIG of each scored pose (against `I` plus the views planned before it).
    pub eig: Vec<f64>,
    /// `C_local` of each scored pose.
    pub c_local: Vec<f64>,
    /// The objective (lower is better; +∞ refuses the path).
    pub objective: f64,
}

/// Wall-clock milliseconds of the stages of one Fisher replan.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct FisherTimings {
    /// Unknown-space seeding.
    pub unknown_ms: f64,
    /// Model Fisher update (0 when reused).
    pub model_ms: f64,
    /// Candidate sampling and their EIG.
    pub candidates_ms: f64,
    /// A* to the top candidates and the rollouts.
    pub paths_ms: f64,
    /// Path EIG and `C_local` along the paths.
    pub path_scores_ms: f64,
    /// The whole replan.
    pub total_ms: f64,
}

/// What one replan of the scorer in `fisher` mode decided, with its intermediates (SPEC §5,
/// §6; issue 14 "what the user sees"): published on the scorer's `report` port and recorded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FisherReport {
    /// Frame of the replan (the goal's).
    pub frame_id: u64,
    /// True for a refine replan (no frontier, goal target −1).
    pub refine: bool,
    /// The point the candidates face (frontier centroid or refine cluster centre).
    pub focus: Option<[f64; 2]>,
    /// The candidates that survived the free-space test, best EIG first.
    pub candidates: Vec<FisherCandidate>,
    /// The paths to the top candidates.
    pub paths: Vec<FisherPath>,
    /// Index into `paths` of the chosen one, −1 when none was chosen.
    pub chosen: i32,
    /// Gaussians of the map scored.
    pub gaussians: u64,
    /// Unknown-space Gaussians added for this replan.
    pub unknown_gaussians: u64,
    /// Whether the model Fisher was reused unchanged from the previous replan.
    pub model_reused: bool,
    /// The scorer library's note on why it found no path, when it did not.
    pub note: Option<String>,
    /// Stage timings.
    pub timings: FisherTimings,
    /// Set when the operator sent its fallback path instead of a Fisher path (which one and
    /// why).
    pub fallback: Option<String>,
}
small_message!(FisherReport, 1);

/// One exchange with the multimodal LLM (SPEC §7), recorded for inspection and replay: the
/// request as sent (never a secret; the image replaced by a placeholder), the BEV, the raw
/// reply, the HTTP facts, the token usage, the decision and any fallback reason. A `recorded`
/// provider serves these back in order.
///
/// Version 2 added everything after `bev_png` but `reply`, `target`; version 3 the finish
/// reason, the reasoning, `schema_refused` and the follow-up turn; version 4
/// `fallback_target`, `answered_frame` and `stale`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LlmExchange {
    /// Frame the decision was made on.
    pub frame_id: u64,
    /// System message sent.
    pub system: String,
    /// User message text sent.
    pub prompt: String,
    /// Annotated BEV image sent, PNG bytes (empty for the text prompt or without a request).
    pub bev_png: Vec<u8>,
    /// `openai`, `ollama` (empty when no request was made).
    pub provider: String,
    /// Model asked.
    pub model: String,
    /// Request body as sent, without secrets, the image as `<bev.png: N bytes>`.
    pub request: String,
    /// Candidates offered (numbers 0..N−1).
    pub candidates: u32,
    /// Status of the last HTTP attempt, if an answer came.
    pub http_status: Option<u16>,
    /// HTTP attempts.
    pub attempts: u32,
    /// Model latency, retries and waits included, milliseconds.
    pub latency_ms: f64,
    /// Prompt tokens reported.
    pub prompt_tokens: Option<u64>,
    /// Completion tokens reported.
    pub completion_tokens: Option<u64>,
    /// Raw reply text (on a failure, the body excerpt, at most 64 KiB).
    pub reply: String,
    /// Parsed target, if the reply held a valid one.
    pub target: Option<i32>,
    /// The model's reason, if the reply held a valid answer.
    pub reason: Option<String>,
    /// The target decided: the model's, or the largest frontier's on a fallback (−1: refine).
    pub decision: i32,
    /// The largest frontier's number: what the fallback would have decided without the model
    /// (−1 when no candidate was offered).
    pub fallback_target: i32,
    /// Kind of failure that made the planner fall back (`timeout`, `no_json`, …), if any.
    pub failure: Option<String>,
    /// What exactly failed.
    pub failure_detail: Option<String>,
    /// Why the model stopped, as the server said (`stop`, `length`, …).
    pub finish_reason: Option<String>,
    /// The reasoning the server returned beside the reply (`reasoning_content`, Ollama's
    /// `thinking`); empty when none. `<think>` blocks stay in `reply`.
    pub reasoning: String,
    /// The server refused the JSON schema of the reply and the request went again without.
    pub schema_refused: bool,
    /// The follow-up turn, when the reply was cut or held no JSON answer; `target`, `reason`
    /// and `failure` are then its outcome.
    pub follow_up: Option<LlmFollowUp>,
    /// The frame whose replan took the answer up: `frame_id` itself when the replan waited
    /// for it (`ask.mode: blocking`), a later frame in `background` mode, `None` when the
    /// episode ended before the answer came.
    pub answered_frame: Option<u64>,
    /// Why a `background` answer was not applied (the question too old, the chosen frontier
    /// gone, the episode over first); `decision` is then not what the robot did.
    pub stale: Option<String>,
}
small_message!(LlmExchange, 4);

/// The follow-up turn of an [`LlmExchange`]: the conversation again, with the model's first
/// reply as the assistant's message and a user message asking only for the JSON.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LlmFollowUp {
    /// Why it was asked (`no_json: …`, with the finish reason when the reply was cut).
    pub cause: String,
    /// The user message of the turn.
    pub prompt: String,
    /// Request body as sent, without secrets, the image as `<bev.png: N bytes>`.
    pub request: String,
    /// Status of the last HTTP attempt, if an answer came.
    pub http_status: Option<u16>,
    /// HTTP attempts.
    pub attempts: u32,
    /// Model latency, milliseconds.
    pub latency_ms: f64,
    /// Prompt tokens reported.
    pub prompt_tokens: Option<u64>,
    /// Completion tokens reported.
    pub completion_tokens: Option<u64>,
    /// Raw reply text (on a failure, the body excerpt).
    pub reply: String,
    /// Why the model stopped.
    pub finish_reason: Option<String>,
    /// Reasoning returned beside the reply.
    pub reasoning: String,
    /// The server refused the JSON schema and the turn went again without.
    pub schema_refused: bool,
    /// Kind of the transport or body failure of the turn (`timeout`, `bad_body`, …), if any;
    /// a reply that does not parse is the exchange's `failure`, not this.
    pub failure: Option<String>,
    /// What exactly failed.
    pub failure_detail: Option<String>,
}

/// A counter sample, for diagnostics and the runtime's own tests.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Counter {
    /// Sequence number.
    pub seq: u64,
    /// Value.
    pub value: i64,
}
small_message!(Counter, 1);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::SchemaError;

    #[test]
    fn small_round_trip_version_and_garbage() {
        let p = Path {
            frame_id: 9,
            waypoints: vec![PlanarPose2 {
                x: 1.0,
                y: -2.0,
                yaw: 0.5,
            }],
            objective: -3.25,
        };
        let bytes = p.encode();
        assert_eq!(&bytes[..2], &[1, 0]);
        assert_eq!(Path::decode(&bytes).unwrap(), p);
        let mut v2 = bytes.clone();
        v2[0] = 2;
        assert_eq!(
            Path::decode(&v2).unwrap_err(),
            SchemaError::VersionMismatch {
                what: "Path",
                expected: 1,
                found: 2
            }
        );
        for cut in 0..bytes.len() {
            assert!(Path::decode(&bytes[..cut]).is_err(), "cut at {cut}");
        }
        let mut trailing = bytes.clone();
        trailing.push(0);
        assert!(matches!(
            Path::decode(&trailing),
            Err(SchemaError::Malformed { .. })
        ));
        // Garbage: a huge declared vector length must be an error, not an allocation or a panic.
        let garbage = [1u8, 0, 9, 0xff, 0xff, 0xff, 0xff, 0x0f];
        assert!(Path::decode(&garbage).is_err());
        // An enum tag out of range.
        assert!(Action::decode(&[1, 0, 3, 9]).is_err());
    }

    /// A Fisher report goes through postcard unchanged, +∞ (a refused path), −∞ and NaN
    /// included: postcard writes f64 as its 8 raw bytes.
    #[test]
    fn fisher_report_round_trips_non_finite_values() {
        let report = FisherReport {
            frame_id: 120,
            refine: false,
            focus: Some([1.5, -0.25]),
            candidates: vec![FisherCandidate {
                x: 1.0,
                y: 0.5,
                yaw: -3.0,
                eig: 1e-9,
            }],
            paths: vec![FisherPath {
                goal: PlanarPose2 {
                    x: 1.0,
                    y: 0.5,
                    yaw: -3.0,
                },
                waypoints: 3,
                actions: 27,
                scored_steps: vec![5, 10, 27],
                eig: vec![4.0, 2.0, 0.0],
                c_local: vec![-30.0, f64::INFINITY, f64::NEG_INFINITY],
                objective: f64::INFINITY,
            }],
            chosen: -1,
            gaussians: 150_000,
            unknown_gaussians: 4_000,
            model_reused: true,
            note: Some("no path has a finite objective".into()),
            timings: FisherTimings {
                total_ms: 812.5,
                ..FisherTimings::default()
            },
            fallback: Some("shortest path to the frontier".into()),
        };
        let bytes = report.encode();
        let back = FisherReport::decode(&bytes).unwrap();
        assert_eq!(back, report);
        assert_eq!(back.paths[0].objective, f64::INFINITY);
        let mut nan = report.clone();
        nan.paths[0].eig[2] = f64::NAN;
        let back = FisherReport::decode(&nan.encode()).unwrap();
        assert!(back.paths[0].eig[2].is_nan());
        for cut in [0, 1, 2, bytes.len() / 2, bytes.len() - 1] {
            assert!(FisherReport::decode(&bytes[..cut]).is_err(), "cut at {cut}");
        }
    }

    #[test]
    fn action_encoding_is_stable() {
        // Pinned bytes: version 1 LE, varint step 300 = [0xac, 0x02], variant TurnRight = 2.
        let a = Action {
            step: 300,
            action: ActionKind::TurnRight,
        };
        assert_eq!(a.encode(), vec![1, 0, 0xac, 0x02, 2]);
    }
}
