//! `scorer`: turns the planner's goal into a path: a shell around the path policy of
//! `activemap-policy` ([`activemap_policy::path`]: the `shortest` path for FBE, or the paper's
//! `fisher` path with a report per replan, SPEC §5–§6), which the in-process explorer runs too.
//! The shell joins each goal with its frame's grid, pose and (for a frontier goal) regions,
//! hands the map snapshots and poses to the policy, and sends the path on `path` and, in
//! `fisher` mode, the report ([`FisherReport`]) on `report`. It reads the mapper's `map` with
//! the Gaussians' stable ids and, for the goal of frame k, waits for exactly the snapshot of
//! frame k − 1 − L (L = `map_lag`, the mapper's, [`crate::mapper::required_snapshot`]). The
//! scorer never sees frames: `camera:` ([`CameraConfig`]) must describe the simulator's
//! camera, which `activemap validate` checks.

use activemap_geometry::Isometry3;
use activemap_policy::PathInput;
use activemap_policy::path::PathPolicy;
use activemap_runtime::{Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl};
use activemap_schemas::{
    FisherReport, Frontiers, Goal, MessageKind as K, OccupancyGridView, Path, PoseEstimate,
};

pub use activemap_policy::path::{
    CameraConfig, PathConfig as Config, ScorerMode, look_around, path_for_goal,
};
pub use activemap_policy::wire::path_to_wire;

use crate::Registered;
use crate::convert::{pose_from_wire, read_grid, with_map_snapshot};
use crate::join::FrameJoin;
use crate::planner::REFINE_TARGET;

fn check_config(value: &serde_json::Value) -> Result<(), String> {
    let config: Config = activemap_runtime::config_from_value(value)?;
    config.validate().map_err(|e| e.to_string())
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
    paths: PathPolicy,
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
        let Some(Slot {
            grid: Some(grid),
            pose: Some(pose),
            regions,
        }) = self.join.get(k)
        else {
            return Ok(None);
        };
        if goal.target != REFINE_TARGET && regions.is_none() || !self.paths.ready(k) {
            return Ok(None);
        }
        let (_, grid) = read_grid(grid)?;
        let pose = *pose;
        let regions = regions.clone();
        self.goals.remove(0);
        self.join.discard_before(k);
        let answer = self.paths.path(&PathInput {
            goal: &goal,
            grid: &grid,
            pose,
            frontiers: regions.as_ref(),
        })?;
        if let Some(report) = &answer.report
            && let Some(fallback) = &report.fallback
        {
            eprintln!(
                "scorer: frame {k}: {fallback} ({})",
                report.note.as_deref().unwrap_or("no note")
            );
        }
        Ok(Some((answer.path, answer.report)))
    }
}

impl Operator for Scorer {
    type Config = Config;

    fn new(config: Config, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        Ok(Self {
            paths: PathPolicy::new(&config)?,
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
                    self.paths.add_pose(e.frame_id, pose);
                    self.join.slot(e.frame_id).pose = Some(pose);
                }
                inputs::REGIONS => {
                    let f: Frontiers = input.decode()?;
                    let frame = f.frame_id;
                    self.join.slot(frame).regions = Some(f);
                }
                inputs::GOAL => self.goals.push(input.decode()?),
                inputs::MAP => with_map_snapshot(input.bytes, |map| self.paths.add_map(map))?,
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
    use activemap_active::FisherConfig;

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
}
