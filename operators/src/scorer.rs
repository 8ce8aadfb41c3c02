//! `scorer`: turns the planner's goal into a path ([`ScorerMode`]).
//!
//! - `shortest` (what FBE needs): [`activemap_planning::path::shortest_path`] (A* with 3-cell
//!   moves, robot-width clearance and proximity cost, then shortcutting, SPEC §6; the
//!   in-process explorer calls it too) to the chosen region's closest reachable cell; the last
//!   waypoint faces the frontier centroid ([`path_for_goal`]). No path → an empty path (the
//!   follower reports it).
//! - `fisher` (the paper, SPEC §5–§6): [`activemap_active::FisherScorer`] with the node's
//!   `fisher:` settings ([`FisherConfig`], every field optional) proposes candidates around the
//!   goal's frontier (or, for a refine goal, target −1, around the least-known part of the map),
//!   plans paths to the best and picks the one that minimises the objective; each replan goes
//!   out on `report` ([`FisherReport`], recorded with the run). The scorer never sees frames:
//!   `camera:` ([`CameraConfig`]) must describe the simulator's camera, which `activemap
//!   validate` checks. It reads the mapper's `map` with the Gaussians' stable ids and, for the
//!   goal of frame k, waits for exactly the snapshot of frame k − 1 − L (L = `map_lag`, the
//!   mapper's, [`crate::mapper::required_snapshot`]), as the tracker and occupancy do, so a
//!   seeded run stays deterministic. A snapshot whose `keyframe_id` is new announces a keyframe:
//!   the scorer tells the library ([`FisherScorer::add_keyframe`]) with the tracker's estimate of
//!   that frame, before the first replan that uses the snapshot. When the library finds no
//!   path ([`ReplanOutcome::path`] `None`) the scorer falls back, so that the lockstep loop
//!   always gets a path and keeps stepping: for a frontier goal the `shortest` path, for a refine
//!   goal a look-around ([`look_around`]: turn 90° left on the spot); the report says so.
//!
//! In `shortest` mode a refine goal also gets the look-around.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use activemap_active::scorer::{ScoringMap, StageTimings};
use activemap_active::{FisherConfig, FisherScorer, GoalRequest, ReplanInput, ReplanOutcome};
use activemap_geometry::frames::planar_from_camera_pose;
use activemap_geometry::robot::wrap_angle;
use activemap_geometry::{Intrinsics, Isometry3, PlanarPose, RobotModel};
use activemap_planning::OccupancyGrid as PlanGrid;
use activemap_planning::astar::AstarConfig;
use activemap_planning::grid::Cell;
use activemap_planning::path::{PlannedPath, shortest_path};
use activemap_runtime::{Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl};
use activemap_schemas::{
    FisherCandidate, FisherPath, FisherReport, FisherTimings, Frontiers, GaussianMapView, Goal,
    MessageKind as K, OccupancyGridView, Path, PlanarPose2, PoseEstimate,
};
use nalgebra::Point2;

use crate::Registered;
use crate::convert::{pose_from_wire, read_grid, read_map_with_ids, robot_clearance};
use crate::join::FrameJoin;
use crate::mapper::required_snapshot;
use crate::planner::REFINE_TARGET;

/// How the scorer makes a path (see the module doc). Checked once, when the config is read
/// (`activemap validate` and the node's start alike): an unknown name is an error naming the
/// modes there are.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(try_from = "String")]
pub enum ScorerMode {
    /// The shortest collision-free path to the goal's frontier (FBE).
    #[default]
    Shortest,
    /// The Fisher-information path choice of the paper (SPEC §5–§6).
    Fisher,
}

impl TryFrom<String> for ScorerMode {
    type Error = String;

    fn try_from(name: String) -> Result<Self, String> {
        match name.as_str() {
            "shortest" => Ok(Self::Shortest),
            "fisher" => Ok(Self::Fisher),
            other => Err(format!(
                "unknown mode `{other}`: the scorer has `shortest` (FBE) and `fisher` (SPEC §5)"
            )),
        }
    }
}

/// The camera of the frames the map was built from (the scorer never sees a frame; its
/// scoring renders scale these intrinsics to `fisher.scoring_width`). Must equal the `sim`
/// node's `width`, `height` and `hfov_deg`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// Image width, pixels.
    #[serde(default = "default_camera_size")]
    pub width: u32,
    /// Image height, pixels.
    #[serde(default = "default_camera_size")]
    pub height: u32,
    /// Horizontal field of view, degrees.
    #[serde(default = "default_hfov")]
    pub hfov_deg: f64,
}

fn default_camera_size() -> u32 {
    160
}
fn default_hfov() -> f64 {
    90.0
}

impl Default for CameraConfig {
    fn default() -> Self {
        Self {
            width: default_camera_size(),
            height: default_camera_size(),
            hfov_deg: default_hfov(),
        }
    }
}

impl CameraConfig {
    /// The pinhole intrinsics, as the simulator makes them; fails on the ranges the `sim`
    /// node refuses.
    pub fn intrinsics(&self) -> anyhow::Result<Intrinsics> {
        let (w, h, fov) = (self.width, self.height, self.hfov_deg);
        anyhow::ensure!(
            w > 0 && h > 0 && w <= 4096 && h <= 4096,
            "scorer: camera width/height must be in 1..=4096, got {w}×{h}"
        );
        anyhow::ensure!(
            fov.is_finite() && fov > 1.0 && fov < 179.0,
            "scorer: camera hfov_deg must be in (1, 179), got {fov}"
        );
        Ok(Intrinsics::from_hfov(w, h, fov.to_radians()))
    }
}

/// Config.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// `shortest` (default) or `fisher`.
    #[serde(default)]
    pub mode: ScorerMode,
    /// The robot (its radius gives the path's clearance; any field left out keeps its default).
    #[serde(default)]
    pub robot: RobotModel,
    /// `fisher` mode: the Fisher scorer's settings (any field left out keeps the paper's
    /// default; unknown fields are refused).
    #[serde(default)]
    pub fisher: FisherConfig,
    /// `fisher` mode: the frames' camera (default 160×160, 90°).
    #[serde(default)]
    pub camera: CameraConfig,
    /// `fisher` mode: map lag L in frames; the goal of frame k is scored on the map snapshot
    /// of frame k − 1 − L. Must equal the mapper's `map_lag`.
    #[serde(default)]
    pub map_lag: u64,
}

impl Config {
    /// Checks what the mode uses; the message names the field.
    pub fn validate(&self) -> anyhow::Result<()> {
        self.robot
            .validate()
            .map_err(|e| anyhow::anyhow!("scorer: {e}"))?;
        if self.mode == ScorerMode::Fisher {
            self.fisher
                .validate()
                .map_err(|e| anyhow::anyhow!("scorer: {e}"))?;
            self.camera.intrinsics()?;
        }
        Ok(())
    }
}

fn check_config(value: &serde_json::Value) -> Result<(), String> {
    let config: Config = activemap_runtime::catalog::config_from_value(value)?;
    config.validate().map_err(|e| e.to_string())
}

/// A planned path as the wire path of frame `frame_id`.
pub fn path_to_wire(frame_id: u64, path: &PlannedPath) -> Path {
    Path {
        frame_id,
        waypoints: path
            .waypoints
            .iter()
            .map(|w| PlanarPose2 {
                x: w.x,
                y: w.y,
                yaw: w.yaw,
            })
            .collect(),
        objective: path.cost,
    }
}

/// The path answering `goal` (transport-free): the shortest path on `grid` from `robot` to the
/// closest reachable cell of the goal's region among `frontiers`, facing the goal's focus at
/// the end; an empty path (objective +∞) when A* finds none. Fails when the goal names a
/// region the frame does not have.
pub fn path_for_goal(
    grid: &PlanGrid,
    robot: Point2<f64>,
    frontiers: &Frontiers,
    goal: &Goal,
    robot_model: &RobotModel,
) -> anyhow::Result<Path> {
    let k = goal.frame_id;
    let region = frontiers
        .regions
        .iter()
        .find(|r| r.id as i32 == goal.target)
        .ok_or_else(|| {
            anyhow::anyhow!(
                "scorer: goal frontier {} is not among frame {k}'s regions",
                goal.target
            )
        })?;
    let cell = Cell::new(
        region.closest_reachable_cell[0],
        region.closest_reachable_cell[1],
    );
    let look_at = Point2::new(goal.focus[0], goal.focus[1]);
    let clearance = robot_clearance(robot_model, grid.geometry.resolution)?;
    Ok(
        match shortest_path(
            grid,
            robot,
            cell,
            look_at,
            &clearance,
            &AstarConfig::default(),
        )? {
            Some(path) => path_to_wire(k, &path),
            None => Path {
                frame_id: k,
                waypoints: Vec::new(),
                objective: f64::INFINITY,
            },
        },
    )
}

/// The refine fallback (and the answer to a refine goal in `shortest` mode): one waypoint at
/// the robot's own position facing 90° to the left of its heading, so the follower turns on
/// the spot (about 18 turns of 5°), sees something new and asks again; the loop keeps stepping.
pub fn look_around(frame_id: u64, robot: &PlanarPose) -> Path {
    Path {
        frame_id,
        waypoints: vec![PlanarPose2 {
            x: robot.x,
            y: robot.y,
            yaw: wrap_angle(robot.yaw + std::f64::consts::FRAC_PI_2),
        }],
        objective: f64::INFINITY,
    }
}

/// One Fisher replan as its wire report; `fallback` says what the operator sent instead of a
/// Fisher path, when it did.
pub fn report_from_outcome(outcome: &ReplanOutcome, fallback: Option<String>) -> FisherReport {
    let count = |n: usize| u32::try_from(n).unwrap_or(u32::MAX);
    let StageTimings {
        unknown_ms,
        model_ms,
        candidates_ms,
        paths_ms,
        path_scores_ms,
        total_ms,
    } = outcome.timings;
    FisherReport {
        frame_id: outcome.frame_id,
        refine: outcome.refine,
        focus: outcome.focus,
        candidates: outcome
            .candidates
            .iter()
            .map(|c| FisherCandidate {
                x: c.pose.x,
                y: c.pose.y,
                yaw: c.pose.yaw,
                eig: c.eig,
            })
            .collect(),
        paths: outcome
            .paths
            .iter()
            .map(|p| FisherPath {
                goal: PlanarPose2 {
                    x: p.goal.x,
                    y: p.goal.y,
                    yaw: p.goal.yaw,
                },
                waypoints: count(p.waypoints.len()),
                actions: count(p.actions),
                scored_steps: p.scored_steps.iter().map(|&s| count(s)).collect(),
                eig: p.eig.clone(),
                c_local: p.c_local.clone(),
                objective: p.objective,
            })
            .collect(),
        chosen: outcome
            .chosen
            .and_then(|i| i32::try_from(i).ok())
            .unwrap_or(-1),
        gaussians: outcome.gaussians as u64,
        unknown_gaussians: outcome.unknown_gaussians as u64,
        model_reused: outcome.model_reused,
        note: outcome.note.clone(),
        timings: FisherTimings {
            unknown_ms,
            model_ms,
            candidates_ms,
            paths_ms,
            path_scores_ms,
            total_ms,
        },
        fallback,
    }
}

/// The `fisher` mode without transport: the library scorer, the map snapshots by frame, the
/// keyframes they announce and the estimated poses those need.
pub struct FisherPaths {
    scorer: FisherScorer,
    robot: RobotModel,
    lag: u64,
    /// Map snapshots by the last frame they include, from the one the next goal may need on;
    /// snapshots of the same keyframe share one decoded map.
    maps: BTreeMap<u64, Arc<ScoringMap>>,
    /// Keyframes announced by the snapshots and not yet told to the library.
    keyframes: BTreeSet<u64>,
    /// The newest keyframe announced so far.
    newest_keyframe: Option<u64>,
    /// Estimated camera poses by frame, from the oldest keyframe not yet told on.
    poses: BTreeMap<u64, Isometry3<f64>>,
}

impl FisherPaths {
    /// The scorer of `config` (its `fisher`, `camera`, `robot` and `map_lag`).
    pub fn new(config: &Config) -> anyhow::Result<Self> {
        let camera = config.camera.intrinsics()?;
        let scorer = FisherScorer::new(config.fisher.clone(), config.robot, camera)
            .map_err(|e| anyhow::anyhow!("scorer: {e}"))?;
        Ok(Self {
            scorer,
            robot: config.robot,
            lag: config.map_lag,
            maps: BTreeMap::new(),
            keyframes: BTreeSet::new(),
            newest_keyframe: None,
            poses: BTreeMap::new(),
        })
    }

    /// Stores a wire map snapshot (decoded only when its keyframe is new: snapshots of the
    /// same keyframe hold the same map) and notes the keyframe it announces.
    pub fn add_map(&mut self, bytes: &[u8]) -> anyhow::Result<()> {
        let header = GaussianMapView::parse(bytes)?.header;
        let k = header.frame_id;
        let keyframe = header.keyframe();
        let reuse = self.maps.values().next_back().filter(|m| {
            keyframe.is_some_and(|j| m.frame_id == j) && m.gaussians.len() as u64 == header.count
        });
        let map = match reuse {
            Some(m) => m.clone(),
            None => {
                let (_, gaussians, ids) = read_map_with_ids(bytes)?;
                let map = ScoringMap {
                    gaussians: Arc::new(gaussians),
                    ids: Arc::new(ids),
                    // The map's version: the keyframe that made it (the snapshot of that frame).
                    frame_id: keyframe.unwrap_or(k),
                };
                map.validate()
                    .map_err(|e| anyhow::anyhow!("scorer: map snapshot of frame {k}: {e}"))?;
                Arc::new(map)
            }
        };
        if let Some(j) = keyframe
            && self.newest_keyframe.is_none_or(|n| j > n)
        {
            self.newest_keyframe = Some(j);
            self.keyframes.insert(j);
        }
        self.maps.insert(k, map);
        Ok(())
    }

    /// Stores the tracker's estimate `T_world_camera` of frame `k`.
    pub fn add_pose(&mut self, k: u64, pose: Isometry3<f64>) {
        self.poses.insert(k, pose);
    }

    /// Keyframes the snapshots announced that the library has not been told of yet, in
    /// frame order (each is told before the first replan whose snapshot includes it).
    pub fn pending_keyframes(&self) -> Vec<u64> {
        self.keyframes.iter().copied().collect()
    }

    /// The map snapshot the goal of frame `k` is scored on (frame k − 1 − L), once it arrived.
    pub fn snapshot_for(&self, k: u64) -> Option<&Arc<ScoringMap>> {
        self.maps.get(&required_snapshot(k, self.lag))
    }

    /// Scores `goal` (of frame k) on the grid of frame k with the robot at `pose` (the
    /// estimate of frame k) and the snapshot [`Self::snapshot_for`] (which must have arrived):
    /// the path to send and the report. `frontiers` (frame k's) are needed for a frontier goal
    /// only, by the fallback.
    pub fn replan(
        &mut self,
        goal: &Goal,
        grid: &PlanGrid,
        pose: &Isometry3<f64>,
        frontiers: Option<&Frontiers>,
    ) -> anyhow::Result<(Path, FisherReport)> {
        let k = goal.frame_id;
        let needed = required_snapshot(k, self.lag);
        let map = self.snapshot_for(k).cloned().ok_or_else(|| {
            anyhow::anyhow!(
                "scorer: the goal of frame {k} needs map snapshot {needed}, which has not arrived"
            )
        })?;
        // Keyframes the snapshot includes, in frame order, each with its own estimate.
        let told: Vec<u64> = self.keyframes.range(..=needed).copied().collect();
        for j in told {
            let keyframe_pose = self.poses.get(&j).copied().ok_or_else(|| {
                anyhow::anyhow!("scorer: no pose estimate of keyframe {j} (goal of frame {k})")
            })?;
            self.scorer.add_keyframe(j, keyframe_pose);
            self.keyframes.remove(&j);
        }
        let request = if goal.target == REFINE_TARGET {
            GoalRequest::Refine
        } else {
            GoalRequest::Frontier {
                focus: Point2::new(goal.focus[0], goal.focus[1]),
            }
        };
        let outcome = self
            .scorer
            .replan(&ReplanInput {
                frame_id: k,
                grid,
                pose: *pose,
                map: &map,
                goal: request,
            })
            .map_err(|e| anyhow::anyhow!("scorer: Fisher replan of frame {k}: {e}"))?;
        let planar = planar_from_camera_pose(pose);
        let (path, fallback) = match &outcome.path {
            Some(p) => {
                let mut path = path_to_wire(k, p);
                if let Some(chosen) = outcome.chosen.and_then(|i| outcome.paths.get(i)) {
                    path.objective = chosen.objective;
                }
                (path, None)
            }
            None if matches!(request, GoalRequest::Refine) => (
                look_around(k, &planar),
                Some("look-around: no Fisher path for the refine goal".to_string()),
            ),
            None => {
                let frontiers = frontiers.ok_or_else(|| {
                    anyhow::anyhow!("scorer: frontier goal of frame {k} without its regions")
                })?;
                let path = path_for_goal(
                    grid,
                    Point2::new(planar.x, planar.y),
                    frontiers,
                    goal,
                    &self.robot,
                )?;
                let what = if path.waypoints.is_empty() {
                    "shortest path to the frontier (none found either)"
                } else {
                    "shortest path to the frontier"
                };
                (path, Some(format!("{what}: no Fisher path")))
            }
        };
        if let Some(f) = &fallback {
            eprintln!(
                "scorer: frame {k}: {f} ({})",
                outcome.note.as_deref().unwrap_or("no note")
            );
        }
        // Later goals are of later frames: older snapshots and poses are no longer needed.
        self.maps = self.maps.split_off(&needed);
        self.poses = self.poses.split_off(&(needed + 1));
        Ok((path, report_from_outcome(&outcome, fallback)))
    }
}

/// The inputs of one frame (the grid stays encoded until a goal needs it).
#[derive(Default)]
struct Slot {
    grid: Option<Vec<u8>>,
    pose: Option<Isometry3<f64>>,
    regions: Option<Frontiers>,
}

/// The operator.
pub struct Scorer {
    robot: RobotModel,
    fisher: Option<FisherPaths>,
    join: FrameJoin<Slot>,
    goals: Vec<Goal>,
}

impl Scorer {
    /// The path (and in `fisher` mode the report) for the oldest goal, once everything it
    /// needs of its frame has arrived; `None` while something is missing.
    fn answer_oldest(&mut self) -> anyhow::Result<Option<(Path, Option<FisherReport>)>> {
        let Some(goal) = self.goals.first().cloned() else {
            return Ok(None);
        };
        let k = goal.frame_id;
        let refine = goal.target == REFINE_TARGET;
        let Some(Slot {
            grid: Some(grid),
            pose: Some(pose),
            regions,
        }) = self.join.get(k)
        else {
            return Ok(None);
        };
        if !refine && regions.is_none() {
            return Ok(None);
        }
        if let Some(fisher) = &self.fisher
            && fisher.snapshot_for(k).is_none()
        {
            return Ok(None);
        }
        let (_, grid) = read_grid(grid)?;
        let pose = *pose;
        let regions = regions.clone();
        self.goals.remove(0);
        self.join.discard_before(k);
        let planar = planar_from_camera_pose(&pose);
        Ok(Some(match &mut self.fisher {
            Some(fisher) => {
                let (path, report) = fisher.replan(&goal, &grid, &pose, regions.as_ref())?;
                (path, Some(report))
            }
            None if refine => (look_around(k, &planar), None),
            None => {
                let frontiers = regions.expect("checked above");
                let robot = Point2::new(planar.x, planar.y);
                let path = path_for_goal(&grid, robot, &frontiers, &goal, &self.robot)?;
                (path, None)
            }
        }))
    }
}

impl Operator for Scorer {
    type Config = Config;

    fn new(config: Config, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        config.validate()?;
        let fisher = match config.mode {
            ScorerMode::Shortest => None,
            ScorerMode::Fisher => Some(FisherPaths::new(&config)?),
        };
        Ok(Self {
            robot: config.robot,
            fisher,
            join: FrameJoin::new(),
            goals: Vec::new(),
        })
    }

    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        match event {
            Event::Input(input) => match input.port {
                inputs::GRID => {
                    let k = OccupancyGridView::parse(input.bytes)?.header.frame_id;
                    self.join.slot(k).grid = Some(input.bytes.to_vec());
                }
                inputs::POSE => {
                    let e: PoseEstimate = input.decode()?;
                    let pose = pose_from_wire(&e.t_world_camera)?;
                    if let Some(fisher) = &mut self.fisher {
                        fisher.add_pose(e.frame_id, pose);
                    }
                    self.join.slot(e.frame_id).pose = Some(pose);
                }
                inputs::REGIONS => {
                    let f: Frontiers = input.decode()?;
                    let frame = f.frame_id;
                    self.join.slot(frame).regions = Some(f);
                }
                inputs::GOAL => self.goals.push(input.decode()?),
                inputs::MAP => {
                    if let Some(fisher) = &mut self.fisher {
                        fisher.add_map(input.bytes)?;
                    }
                }
                other => anyhow::bail!("scorer: unexpected input `{other}`"),
            },
            // The planner ended the episode, or the loop is shutting down.
            Event::InputClosed {
                port: inputs::GOAL | inputs::POSE,
            } => return Ok(Flow::Stop),
            _ => return Ok(Flow::Continue),
        }
        while let Some((path, report)) = self.answer_oldest()? {
            if let Some(report) = report {
                ctx.send(outputs::REPORT, &report)?;
            }
            ctx.send(outputs::PATH, &path)?;
        }
        Ok(Flow::Continue)
    }
}

/// The operator's input ports, named once for registration and dispatch.
pub mod inputs {
    activemap_runtime::ports! {
        GOAL = "goal": super::K::Goal,
        MAP = "map": super::K::GaussianMap,
        GRID = "grid": super::K::OccupancyGrid,
        POSE = "pose": super::K::PoseEstimate,
        REGIONS = "regions": super::K::Frontiers
    }
}

/// The operator's output ports, named once for registration and dispatch.
pub mod outputs {
    activemap_runtime::ports! {
        PATH = "path": super::K::Path,
        REPORT = "report": super::K::FisherReport
    }
}

/// Registry entry.
pub fn registered() -> Registered {
    Registered {
        descriptor: OperatorDescriptor {
            name: "scorer",
            summary: "Path to the planner's goal: shortest A* + shortcut, or the Fisher-information path choice with a report per replan (SPEC §5, §6)",
            inputs: inputs::ALL,
            outputs: outputs::ALL,
            evaluation: false,
            check_config,
        },
        implementation: Some(OperatorImpl::of::<Scorer>()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_planning::grid::{CellState, GridGeometry};
    use activemap_schemas::FrontierRegion;

    /// `mode` is checked once, when the config is read: `shortest` (the default) and
    /// `fisher` are built, anything else is refused naming both; in `fisher` mode the
    /// `fisher:` block is the library's config (unknown fields and bad values refused, naming
    /// the field) and the camera must be one the simulator accepts.
    #[test]
    fn modes_and_their_settings_are_checked_when_the_config_is_read() {
        let check = |v: serde_json::Value| check_config(&v);
        let config: Config = serde_json::from_value(serde_json::json!({})).unwrap();
        assert_eq!(config.mode, ScorerMode::Shortest);
        assert_eq!(config.camera, CameraConfig::default());
        assert_eq!(config.fisher, FisherConfig::default());
        assert!(check(serde_json::json!({ "mode": "shortest" })).is_ok());
        assert!(check(serde_json::json!({ "mode": "fisher" })).is_ok());
        let eig_only: Config = serde_json::from_value(serde_json::json!({
            "mode": "fisher",
            "map_lag": 10,
            "fisher": { "objective": "eig_only", "mc_poses": 16 },
            "camera": { "width": 64, "height": 48 }
        }))
        .unwrap();
        assert_eq!(eig_only.mode, ScorerMode::Fisher);
        assert_eq!(
            eig_only.fisher.objective,
            activemap_active::PathObjective::EigOnly
        );
        assert_eq!(eig_only.fisher.mc_poses, 16);
        assert_eq!(eig_only.fisher.eta, FisherConfig::default().eta);
        assert_eq!((eig_only.camera.width, eig_only.camera.height), (64, 48));
        assert_eq!(eig_only.camera.hfov_deg, 90.0);
        let other = check(serde_json::json!({ "mode": "random" })).unwrap_err();
        assert!(
            other.contains("`random`") && other.contains("shortest") && other.contains("fisher"),
            "{other}"
        );
        let unknown =
            check(serde_json::json!({ "mode": "fisher", "fisher": { "etaa": 5 } })).unwrap_err();
        assert!(unknown.contains("etaa"), "{unknown}");
        let lambda = check(serde_json::json!({ "mode": "fisher", "fisher": { "lambda": -1.0 } }))
            .unwrap_err();
        assert!(lambda.contains("fisher.lambda"), "{lambda}");
        let fov = check(serde_json::json!({ "mode": "fisher", "camera": { "hfov_deg": 0.5 } }))
            .unwrap_err();
        assert!(fov.contains("hfov_deg"), "{fov}");
        let field = check(serde_json::json!({ "camera": { "fov": 90 } })).unwrap_err();
        assert!(field.contains("fov"), "{field}");
    }

    /// A wire map snapshot of frame `frame` whose newest keyframe is `keyframe`, `n`
    /// Gaussians on a wall at x = 2 m with ids `first_id..`.
    fn wire_map(frame: u64, keyframe: Option<u64>, n: usize, first_id: u64) -> Vec<u8> {
        let mut g = activemap_splat::Gaussians::<f32>::new();
        for i in 0..n {
            let (y, z) = ((i % 20) as f64 * 0.1, 0.2 + (i / 20) as f64 * 0.1);
            g.push(
                [2.0, y, z],
                [0.2 + 0.03 * (i % 20) as f64, 0.5, 0.3],
                [1.0, 0.0, 0.0, 0.0],
                0.9,
                [0.05; 3],
            );
        }
        let header = crate::convert::map_header(&g, frame, frame as f64, keyframe);
        let ids: Vec<u64> = (first_id..first_id + n as u64).collect();
        let mut storage = vec![0u64; header.payload_len().unwrap() / 8];
        let buf: &mut [u8] = bytemuck::cast_slice_mut(&mut storage);
        crate::convert::write_map(buf, header, &g, &ids).unwrap();
        buf.to_vec()
    }

    fn fisher_config(map_lag: u64) -> Config {
        serde_json::from_value(serde_json::json!({
            "mode": "fisher",
            "map_lag": map_lag,
            "camera": { "width": 64, "height": 64 },
            "fisher": { "candidates": 24, "top_candidates": 3, "mc_poses": 4, "mc_refresh": 2, "scoring_width": 16 }
        }))
        .unwrap()
    }

    /// The goal of frame k waits for exactly snapshot k − 1 − L (never a newer or older one
    /// that happens to be there); snapshots of the same keyframe share one decoded map, whose
    /// version is the keyframe's frame; each new keyframe is announced once; a map whose ids
    /// do not fit is refused naming its frame.
    #[test]
    fn goals_wait_for_their_lagged_snapshot_and_keyframes_are_noted_once() {
        let mut fisher = FisherPaths::new(&fisher_config(2)).unwrap();
        fisher.add_map(&wire_map(0, None, 0, 0)).unwrap();
        fisher.add_map(&wire_map(1, Some(1), 40, 0)).unwrap();
        fisher.add_map(&wire_map(2, Some(1), 40, 0)).unwrap();
        fisher.add_map(&wire_map(3, Some(1), 40, 0)).unwrap();
        assert!(
            fisher.snapshot_for(7).is_none(),
            "snapshot 4 has not arrived"
        );
        fisher.add_map(&wire_map(4, Some(4), 60, 0)).unwrap();
        let for_7 = fisher.snapshot_for(7).unwrap();
        assert_eq!((for_7.frame_id, for_7.gaussians.len()), (4, 60));
        let (a, b) = (
            fisher.snapshot_for(4).unwrap(),
            fisher.snapshot_for(6).unwrap(),
        );
        assert!(
            Arc::ptr_eq(a, b),
            "snapshots 1 and 3 share the map of keyframe 1"
        );
        assert_eq!((a.frame_id, a.ids.len(), a.ids[39]), (1, 40, 39));
        assert_eq!(fisher.snapshot_for(1).unwrap().gaussians.len(), 0);
        assert_eq!(fisher.snapshot_for(1).unwrap().frame_id, 0);
        assert_eq!(fisher.pending_keyframes(), vec![1, 4]);
        let bad = wire_map(5, Some(5), 3, activemap_active::unknown::UNKNOWN_ID_BASE);
        let e = fisher.add_map(&bad).unwrap_err().to_string();
        assert!(e.contains("frame 5") && e.contains("unknown-space"), "{e}");
    }

    /// The refine fallback turns the robot 90° left on the spot (wrapped to (−π, π]).
    #[test]
    fn the_look_around_turns_left_on_the_spot() {
        let p = look_around(12, &PlanarPose::new(1.0, -2.0, 3.0));
        assert_eq!(p.frame_id, 12);
        assert_eq!(p.waypoints.len(), 1);
        let w = p.waypoints[0];
        assert_eq!((w.x, w.y), (1.0, -2.0));
        let want = 3.0 + std::f64::consts::FRAC_PI_2 - 2.0 * std::f64::consts::PI;
        assert!((w.yaw - want).abs() < 1e-12, "{}", w.yaw);
    }

    /// The report carries every candidate, path term and timing of the outcome, −1 when none
    /// was chosen, +∞ terms unchanged, and the fallback; it goes through the wire as it is.
    #[test]
    fn the_report_mirrors_the_outcome() {
        use activemap_active::scorer::{CandidateScore, PathScore};
        let pose = PlanarPose::new(1.0, 2.0, 0.5);
        let mut outcome = ReplanOutcome {
            frame_id: 80,
            refine: true,
            focus: Some([1.5, 2.5]),
            path: None,
            chosen: None,
            candidates: vec![CandidateScore { pose, eig: 3.5 }],
            paths: vec![PathScore {
                goal: pose,
                waypoints: vec![pose, pose],
                actions: 14,
                scored_steps: vec![5, 10, 14],
                eig: vec![3.0, 2.0, 1.0],
                c_local: vec![-20.0, f64::INFINITY, -19.0],
                low_opacity: vec![0.0; 3],
                objective: f64::INFINITY,
            }],
            gaussians: 1200,
            unknown_gaussians: 200,
            model_reused: false,
            distinct_path_views: 3,
            note: Some("no path has a finite objective".into()),
            timings: StageTimings {
                unknown_ms: 1.0,
                model_ms: 2.0,
                candidates_ms: 3.0,
                paths_ms: 4.0,
                path_scores_ms: 5.0,
                total_ms: 15.0,
            },
        };
        let r = report_from_outcome(&outcome, Some("look-around".into()));
        assert_eq!(
            (r.frame_id, r.refine, r.focus, r.chosen),
            (80, true, Some([1.5, 2.5]), -1)
        );
        assert_eq!(
            r.candidates,
            vec![FisherCandidate {
                x: 1.0,
                y: 2.0,
                yaw: 0.5,
                eig: 3.5
            }]
        );
        let p = &r.paths[0];
        assert_eq!(
            (p.waypoints, p.actions, p.scored_steps.clone()),
            (2, 14, vec![5, 10, 14])
        );
        assert_eq!(p.c_local[1], f64::INFINITY);
        assert_eq!(p.objective, f64::INFINITY);
        assert_eq!(
            (r.gaussians, r.unknown_gaussians, r.model_reused),
            (1200, 200, false)
        );
        assert_eq!(r.timings.path_scores_ms, 5.0);
        assert_eq!(r.timings.total_ms, 15.0);
        assert_eq!(r.fallback.as_deref(), Some("look-around"));
        let back: FisherReport = activemap_schemas::Payload::from_bytes(
            &activemap_schemas::Payload::to_bytes(&r).unwrap(),
        )
        .unwrap();
        assert_eq!(back, r);
        outcome.chosen = Some(0);
        assert_eq!(report_from_outcome(&outcome, None).chosen, 0);
    }

    /// A room 3 m × 2 m, free up to x = 1.5 m and unknown beyond (the frontier), walls
    /// around; the robot at (0.5, 1.0) facing +x.
    fn room() -> (PlanGrid, Frontiers, PlanarPose) {
        let geometry = GridGeometry::new(0.0, 0.0, 0.05, 60, 40).unwrap();
        let mut grid = PlanGrid::filled(geometry, CellState::Unknown);
        for x in 0..60 {
            for y in 0..40 {
                let wall = x == 0 || y == 0 || x == 59 || y == 39;
                let state = if wall {
                    CellState::Occupied
                } else if x < 30 {
                    CellState::Free
                } else {
                    CellState::Unknown
                };
                grid.set(Cell::new(x, y), state);
            }
        }
        let frontiers = Frontiers {
            frame_id: 20,
            stamp: 0.0,
            regions: vec![FrontierRegion {
                id: 0,
                size_cells: 38,
                centroid: [1.5, 1.0],
                closest_reachable_cell: [27, 20],
                path_distance_m: 1.1,
                anchor: [1.5, 1.0],
            }],
        };
        (grid, frontiers, PlanarPose::new(0.5, 1.0, 0.0))
    }

    /// One Fisher replan per goal kind through the operator's core: a frontier goal and a
    /// refine goal each get a non-empty path of their frame (a Fisher path, or the fallback the
    /// report names: the shortest path, or the look-around), the report of the same frame, and
    /// two scorers fed the same inputs give the same paths and reports (seeded sampling).
    #[test]
    fn fisher_replans_answer_every_goal_deterministically() {
        let (grid, frontiers, planar) = room();
        let robot = RobotModel::default();
        let pose = robot.camera_pose(&planar, 0.0);
        let run = || {
            let mut fisher = FisherPaths::new(&fisher_config(0)).unwrap();
            for k in 0..=19 {
                fisher.add_pose(k, pose);
                let keyframe = if k >= 5 { 5 } else { 0 };
                fisher
                    .add_map(&wire_map(
                        k,
                        Some(keyframe),
                        if k >= 5 { 120 } else { 60 },
                        0,
                    ))
                    .unwrap();
            }
            fisher.add_pose(20, pose);
            let mut out = Vec::new();
            for target in [0, REFINE_TARGET] {
                let goal = Goal {
                    frame_id: 20,
                    target,
                    focus: [1.5, 1.0],
                };
                let (path, mut report) = fisher
                    .replan(&goal, &grid, &pose, Some(&frontiers))
                    .unwrap();
                assert!(
                    fisher.pending_keyframes().is_empty(),
                    "keyframes 0 and 5 told"
                );
                assert_eq!((path.frame_id, report.frame_id), (20, 20));
                assert!(!path.waypoints.is_empty(), "{report:?}");
                assert_eq!(report.refine, target == REFINE_TARGET);
                match (&report.fallback, target) {
                    (None, _) => {
                        let chosen = usize::try_from(report.chosen).expect("a chosen path");
                        assert_eq!(path.objective, report.paths[chosen].objective);
                        assert!(path.objective.is_finite());
                    }
                    (Some(_), REFINE_TARGET) => {
                        assert_eq!(path, look_around(20, &planar));
                    }
                    (Some(_), _) => {
                        let shortest =
                            path_for_goal(&grid, Point2::new(0.5, 1.0), &frontiers, &goal, &robot)
                                .unwrap();
                        assert_eq!(path, shortest);
                    }
                }
                eprintln!(
                    "target {target}: {} candidates, {} paths, chosen {}, fallback {:?}, note {:?}",
                    report.candidates.len(),
                    report.paths.len(),
                    report.chosen,
                    report.fallback,
                    report.note
                );
                report.timings = FisherTimings::default();
                out.push((path, report));
            }
            out
        };
        let (first, second) = (run(), run());
        assert_eq!(first, second, "seeded replans repeat exactly");
    }

    /// A goal gets a path to its region's closest reachable cell, facing the focus; a goal
    /// on an unknown region is an error, and a walled-off cell an empty path.
    #[test]
    fn a_goal_gets_a_path_to_its_region() {
        let geometry = GridGeometry::new(0.0, 0.0, 0.05, 60, 60).unwrap();
        let mut grid = PlanGrid::filled(geometry, CellState::Free);
        let region = |id, cell: [i32; 2]| FrontierRegion {
            id,
            size_cells: 10,
            centroid: [2.5, 2.5],
            closest_reachable_cell: cell,
            path_distance_m: 1.0,
            anchor: [2.5, 2.5],
        };
        let frontiers = Frontiers {
            frame_id: 3,
            stamp: 0.0,
            regions: vec![region(0, [40, 30]), region(1, [55, 55])],
        };
        let goal = |target| Goal {
            frame_id: 3,
            target,
            focus: [2.5, 2.5],
        };
        let robot = Point2::new(0.5, 0.5);
        let p = path_for_goal(&grid, robot, &frontiers, &goal(0), &RobotModel::default()).unwrap();
        let last = p.waypoints.last().unwrap();
        let end = geometry.center(Cell::new(40, 30));
        assert_eq!(p.frame_id, 3);
        assert!((last.x - end.x).abs() < 1e-12 && (last.y - end.y).abs() < 1e-12);
        assert!((last.yaw - (2.5 - last.y).atan2(2.5 - last.x)).abs() < 1e-12);
        assert!(path_for_goal(&grid, robot, &frontiers, &goal(7), &RobotModel::default()).is_err());
        for x in 50..60 {
            grid.set(Cell::new(x, 50), CellState::Occupied);
        }
        for y in 50..60 {
            grid.set(Cell::new(50, y), CellState::Occupied);
        }
        let none =
            path_for_goal(&grid, robot, &frontiers, &goal(1), &RobotModel::default()).unwrap();
        assert!(none.waypoints.is_empty() && none.objective.is_infinite());
    }
}
