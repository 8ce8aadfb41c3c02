//! `evaluator` (evaluation only: the one node that reads ground truth): writes the run
//! folder's results — `trajectory_est.tum` and `trajectory_true.tum` (TUM), `map.ply` (3DGS
//! PLY of the last map without its unknown-space Gaussians, which only stand for unobserved
//! volume and would read as surfaces in any PLY viewer), `bev.png` (bird's-eye view of the
//! last occupancy grid with the estimated path in green, the true path in blue and the
//! frontier centroids in red), `coverage.csv` (2D coverage per step, SPEC §8: seen floor /
//! reachable navigable floor), `summary.json` (steps, coverage, ATE, path length, blocked
//! forward moves, whether `recording.mcap` is present) and, when the optional `fisher` input
//! (the scorer's `report`) brought at least one `FisherReport`, `fisher.csv`: one row per
//! Fisher replan ([`fisher_row`]). A run without Fisher replans (policy `fbe`, or a `fisher`
//! run too short to replan) has no `fisher.csv`, so an absent file means "no replan".
//! The optional `llm` input (the LLM planner's exchanges) is written as it arrives: one line
//! of `llm.jsonl` per query and its BEV as `llm/bev_NNNN_step_K.png`; `summary.json` then
//! holds the totals (queries, calls, fallbacks by kind, tokens, model latency).
//!
//! A forward action is *blocked* when the true position it led to lies less than half the
//! forward step (SPEC §1: 5 cm) from the one it started at: the robot drove into something.
//! This needs only the actions and the true poses, so it also counts for an external simulator.
//!
//! The loop's world is anchored at the robot's start pose; coverage maps each reachable
//! navigable cell of the scene (ground truth) into that frame with the true start pose.
//!
//! No silent nonsense (issue 16, `activemap_eval::validity`): at the end the evaluator checks
//! that the start pose saw something (the first frame of the optional `rgbd` input has at least
//! 1 % valid depth), that the robot could move (not ≥ 90 % of ≥ 20 forward moves blocked, not
//! under one forward step of true path after 200 steps), that the map is not empty (an observed
//! Gaussian) and that some floor is reachable (≥ 1 m²). Each failed check is a warning in
//! `summary.json` (`warnings`, `"valid": false`) and a line
//! `warning: RUN_DIR: invalid run: CODE: MESSAGE` on stderr.

use std::path::PathBuf;

use activemap_eval::CorrectedTrajectory;
use activemap_eval::run_folder::{
    CoverageRow, FisherRow, LLM_OUTCOME_HORIZON_STEPS, LlmFollowUpRecord, LlmRecord, LlmSummary,
    RunFolder,
};
use activemap_eval::step_metrics::{
    CoverageTruth, FrameReport, ate_rmse, bev, blocked_forwards, observed_only, path_length_m,
    run_warnings, tracking_summary,
};
use activemap_eval::validity::{self, RunWarning};
use activemap_geometry::RobotModel;
use activemap_geometry::frames::planar_from_camera_pose;
use activemap_geometry::tum::Trajectory;
use activemap_geometry::{Isometry3, PlanarPose};
use activemap_planning::OccupancyGrid as PlanGrid;
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, check_config_as,
};
use activemap_schemas::{
    Action, ActionKind, EpisodeStatus, FisherReport, Frontiers, LlmExchange, MessageKind as K,
    PoseEstimate, RgbdFrameView, TruePose,
};
use activemap_splat::Gaussians;
use nalgebra::Point2;

use crate::Registered;
use crate::convert::{pose_from_wire, read_grid, read_map};
use activemap_sim::{Floor, Placement, SceneSpec, Transform, UpAxis};

/// Config.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// The scene the `sim` node runs (same keys), for the ground-truth navigable floor.
    #[serde(default = "default_scene")]
    pub scene: String,
    /// As in `sim`.
    #[serde(default)]
    pub max_rooms: Option<u32>,
    /// As in `sim`.
    #[serde(default)]
    pub max_area: Option<f64>,
    /// As in `sim` (`x`, `-x`, `y`, `-y`, `z`, `-z` or `auto`, for scene files).
    #[serde(default)]
    pub up_axis: Option<UpAxis>,
    /// As in `sim` (a scene file's scale, rotation and translation).
    #[serde(default)]
    pub transform: Option<Transform>,
    /// As in `sim` (`none`, `auto` or a floor height, for scene files).
    #[serde(default)]
    pub floor: Floor,
    /// Output folder; default the run folder (`ACTIVEMAP_RUN_DIR`), else the working directory.
    #[serde(default)]
    pub out: Option<PathBuf>,
    /// Pixels per grid cell in `bev.png`.
    #[serde(default = "default_scale")]
    pub bev_pixels_per_cell: u32,
    /// The robot (as the `sim` node's): a forward action that moves the robot less than half
    /// of its forward step counts as blocked; written to `summary.json` for `activemap eval`.
    #[serde(default)]
    pub robot: RobotModel,
    /// Steps after which the results so far are also written as a checkpoint
    /// (`checkpoints/step_NNNNNN/`, a run folder `activemap eval` evaluates with the run), so a
    /// benchmark can compare methods at several budgets from the same episodes. Increasing,
    /// each ≥ 1; a step the episode never reaches writes nothing.
    #[serde(default)]
    pub checkpoints: Vec<u64>,
    /// The depth model of the mapper's map (`centre` or `plane`; the library default when
    /// absent), written to `summary.json` so the evaluation renders the map as it was fitted.
    /// The flow check ties it to the mapper's `tuning.depth_model`.
    #[serde(default)]
    pub depth_model: Option<activemap_splat::DepthModel>,
}

impl Config {
    /// The scene part of the config (the same keys as the `sim` node's).
    pub fn scene_spec(&self) -> SceneSpec {
        SceneSpec {
            scene: self.scene.clone(),
            max_rooms: self.max_rooms,
            max_area: self.max_area,
            placement: Placement {
                up_axis: self.up_axis,
                transform: self.transform,
                floor: self.floor,
            },
        }
    }
}

fn default_scene() -> String {
    "house:7".into()
}
fn default_scale() -> u32 {
    4
}

/// What the evaluator measured: `summary.json`, defined with the rest of the run folder in
/// `activemap-eval` ([`RunFolder`]).
pub use activemap_eval::run_folder::Summary;

/// The operator.
pub struct Evaluator {
    out: RunFolder,
    scene: SceneSpec,
    scale: u32,
    truth: Option<(CoverageTruth, PlanarPose, Isometry3<f64>)>,
    estimated: Trajectory,
    /// What the tracker said of each estimate (lost and why, relocalised, loop closure).
    reports: Vec<FrameReport>,
    /// The estimates moved by the pose graph's later corrections (when the graph is on).
    corrected: CorrectedTrajectory,
    true_traj: Trajectory,
    coverage: Vec<CoverageRow>,
    grid: Option<PlanGrid>,
    regions: Option<Frontiers>,
    map: Option<Gaussians<f32>>,
    episode: String,
    pending_grids: Vec<(u64, PlanGrid)>,
    written: bool,
    /// True planar position per frame id.
    true_positions: std::collections::BTreeMap<u64, Point2<f64>>,
    /// Forward actions received, by the frame id they were computed from.
    forward_steps: Vec<u64>,
    /// The robot (forward step of the blocked count; recorded in `summary.json`).
    robot: RobotModel,
    /// The map's depth model (recorded in `summary.json`).
    depth_model: activemap_splat::DepthModel,
    /// One row per `FisherReport` received, in arrival order (`fisher.csv`).
    fisher: Vec<FisherRow>,
    /// One record per `LlmExchange` received (appended to `llm.jsonl` as it arrives).
    llm: Vec<LlmRecord>,
    /// The earliest RGB-D frame received (optional `rgbd` input): its id and the fraction of
    /// its depth pixels that are valid.
    start_depth: Option<(u64, f64)>,
    /// Step counts at which to write a checkpoint ([`Config::checkpoints`]).
    checkpoints: Vec<u64>,
}

/// The `llm.jsonl` record of an exchange whose BEV was written at `bev` (relative path).
pub fn llm_record(e: &LlmExchange, bev: Option<String>) -> LlmRecord {
    LlmRecord {
        step: Some(e.frame_id),
        system: Some(e.system.clone()),
        prompt: Some(e.prompt.clone()),
        bev,
        provider: Some(e.provider.clone()).filter(|p| !p.is_empty()),
        model: Some(e.model.clone()).filter(|m| !m.is_empty()),
        candidates: Some(e.candidates),
        http_status: e.http_status,
        attempts: Some(e.attempts),
        latency_ms: Some(e.latency_ms),
        prompt_tokens: e.prompt_tokens,
        completion_tokens: e.completion_tokens,
        reply: Some(e.reply.clone()),
        target: e.target.map(i64::from),
        reason: e.reason.clone(),
        decision: Some(i64::from(e.decision)),
        fallback_target: (e.fallback_target >= 0).then_some(i64::from(e.fallback_target)),
        answered_step: e.answered_frame,
        stale: e.stale.clone(),
        failure: e.failure.clone(),
        failure_detail: e.failure_detail.clone(),
        finish_reason: e.finish_reason.clone(),
        reasoning: Some(e.reasoning.clone()).filter(|r| !r.is_empty()),
        thinking: thinking(&e.reply),
        schema_refused: Some(e.schema_refused),
        follow_up: e.follow_up.as_ref().map(|f| LlmFollowUpRecord {
            cause: Some(f.cause.clone()),
            prompt: Some(f.prompt.clone()),
            http_status: f.http_status,
            attempts: Some(f.attempts),
            latency_ms: Some(f.latency_ms),
            prompt_tokens: f.prompt_tokens,
            completion_tokens: f.completion_tokens,
            reply: Some(f.reply.clone()),
            finish_reason: f.finish_reason.clone(),
            reasoning: Some(f.reasoning.clone()).filter(|r| !r.is_empty()),
            thinking: thinking(&f.reply),
            schema_refused: Some(f.schema_refused),
        }),
    }
}

/// The `<think>` blocks of a reply, joined; `None` when it has none.
fn thinking(reply: &str) -> Option<String> {
    let blocks = activemap_llm::parse::split_thinking(reply).thinking;
    (!blocks.is_empty()).then(|| blocks.join("\n\n"))
}

/// What the tracker said of one frame ([`PoseEstimate`]), as the tracking summary counts it
/// (`activemap_eval::step_metrics::tracking_summary`): the evaluator's and `activemap replay
/// --node tracker`'s reading of the same estimate.
pub fn frame_report(e: &PoseEstimate) -> FrameReport {
    FrameReport {
        frame_id: e.frame_id,
        skipped: e.status == activemap_schemas::TrackingStatus::Skipped,
        lost: e
            .lost_reason
            .map(|r| r.key())
            .or((e.status == activemap_schemas::TrackingStatus::Lost).then_some("unknown")),
        relocalised: e.relocalised.is_some(),
        loop_closure: !e.keyframe_corrections.is_empty(),
    }
}

/// The `fisher.csv` row of one Fisher replan: counts, the chosen path's objective, EIG (summed
/// over its scored poses, and of the first) and `C_local` sum, and the replan time. An error
/// names the frame when the report does not hold together (a chosen index out of range, a NaN
/// term: the row [`FisherRow::check`] refuses).
pub fn fisher_row(report: &FisherReport) -> anyhow::Result<FisherRow> {
    let chosen = match usize::try_from(report.chosen) {
        Ok(i) => Some(report.paths.get(i).ok_or_else(|| {
            anyhow::anyhow!(
                "evaluator: FisherReport of frame {}: chosen path {i} of {} paths",
                report.frame_id,
                report.paths.len()
            )
        })?),
        Err(_) => None,
    };
    let row = FisherRow {
        step: report.frame_id,
        refine: report.refine,
        candidates: report.candidates.len() as u64,
        paths: report.paths.len() as u64,
        chosen: i64::from(report.chosen),
        objective: chosen.map(|p| p.objective),
        eig_sum: chosen.map(|p| p.eig.iter().sum()),
        eig_first: chosen.and_then(|p| p.eig.first().copied()),
        c_local_sum: chosen.map(|p| p.c_local.iter().sum()),
        actions: chosen.map(|p| p.actions),
        total_ms: report.timings.total_ms,
        model_reused: report.model_reused,
        fallback: report.fallback.is_some(),
    };
    row.check().map_err(|e| {
        anyhow::anyhow!("evaluator: FisherReport of frame {}: {e}", report.frame_id)
    })?;
    Ok(row)
}

impl Evaluator {
    /// Why the run is invalid (`activemap_eval::validity`), from what the evaluator saw: the
    /// first frame's valid depth (when the `rgbd` input is connected), the motion counts of
    /// `summary`, the final map's observed Gaussians and the reachable floor.
    pub fn warnings(&self, summary: &Summary) -> Vec<RunWarning> {
        run_warnings(
            self.start_depth,
            summary,
            self.robot.forward_step_m,
            self.map.as_ref(),
            self.truth
                .as_ref()
                .map(|(truth, _, _)| truth.reachable_area_m2()),
        )
    }

    fn score_pending(&mut self) -> anyhow::Result<()> {
        let Some((truth, start, _)) = &self.truth else {
            return Ok(());
        };
        for (k, grid) in self.pending_grids.drain(..) {
            self.coverage.push(CoverageRow {
                step: k,
                coverage: truth.coverage(&grid, start)?,
            });
            self.grid = Some(grid);
        }
        Ok(())
    }

    /// Writes every output file; returns the summary.
    pub fn write_outputs(&mut self) -> anyhow::Result<Summary> {
        let out = self.out.clone();
        let episode = self.episode.clone();
        self.write_folder(&out, episode)
    }

    /// Writes the checkpoint after `step` steps: the run folder's results as they stand now,
    /// in [`RunFolder::checkpoint`] (the map is the last one received, which the mapper's lag
    /// may leave a few steps behind the trajectory).
    pub fn write_checkpoint(&mut self, step: u64) -> anyhow::Result<Summary> {
        let out = self.out.checkpoint(step);
        self.write_folder(&out, format!("checkpoint at step {step}"))
    }

    /// Writes every output file into `out` with `episode` as the summary's episode status.
    fn write_folder(&self, out: &RunFolder, episode: String) -> anyhow::Result<Summary> {
        out.create()?;
        out.write_trajectory(RunFolder::TRAJECTORY_EST, &self.estimated)?;
        out.write_trajectory(RunFolder::TRAJECTORY_TRUE, &self.true_traj)?;
        if let Some(corrected) = self.corrected.trajectory() {
            out.write_trajectory(RunFolder::TRAJECTORY_FINAL, corrected)?;
        }
        out.write_coverage(&self.coverage)?;
        if !self.fisher.is_empty() {
            out.write_fisher(&self.fisher)?;
        }
        if let Some(map) = &self.map {
            out.write_map(&observed_only(map)?)?;
        }
        if let (Some(grid), Some((_, _, anchor))) = (&self.grid, &self.truth) {
            let frontiers: Vec<[f64; 2]> = self
                .regions
                .as_ref()
                .map_or_else(Vec::new, |f| f.regions.iter().map(|r| r.centroid).collect());
            out.write_bev(&bev(
                grid,
                &self.estimated,
                &self.true_traj,
                anchor,
                &frontiers,
                self.scale,
            ))?;
        }
        let ate_m = ate_rmse(&self.true_traj, &self.estimated)?;
        let ate_final_m = match self.corrected.trajectory() {
            Some(t) => ate_rmse(&self.true_traj, t)?,
            None => None,
        };
        let path_length_m = path_length_m(&self.true_traj);
        let (forward_actions, blocked) = blocked_forwards(
            &self.forward_steps,
            &self.true_positions,
            self.robot.forward_step_m,
        );
        let mut summary = Summary {
            steps: self.estimated.len() as u64,
            coverage: Some(self.coverage.last().map_or(0.0, |c| c.coverage)),
            ate_m,
            ate_final_m,
            path_length_m,
            forward_actions,
            blocked_forwards: blocked,
            episode,
            recording_present: out.has_recording(),
            map_gaussians: self.map.as_ref().map_or(0, |m| m.len()),
            scene: Some(self.scene.scene.clone()),
            max_rooms: self.scene.max_rooms,
            max_area: self.scene.max_area,
            up_axis: self.scene.placement.up_axis.map(|up| up.name().to_string()),
            transform: self.scene.placement.transform,
            floor: Some(self.scene.placement.floor).filter(|f| !f.is_none()),
            robot: Some(self.robot),
            llm: (!self.llm.is_empty())
                .then(|| LlmSummary::of_run(&self.llm, &self.coverage, LLM_OUTCOME_HORIZON_STEPS)),
            tracking: Some(tracking_summary(
                &self.true_traj,
                &self.estimated,
                &self.reports,
            )),
            map_depth_model: Some(self.depth_model),
            warnings: Vec::new(),
        };
        summary.warnings = self.warnings(&summary);
        out.write_summary(&summary)?;
        eprintln!(
            "evaluator: {} steps, coverage {:.1} %, ATE {}, path {:.2} m, {} of {} forward moves blocked → {}",
            summary.steps,
            summary.coverage.unwrap_or(0.0) * 100.0,
            summary
                .ate_m
                .map_or("n/a".into(), |a| format!("{:.2} cm", a * 100.0))
                + &summary.ate_final_m.map_or(String::new(), |a| format!(
                    " ({:.2} cm after the pose graph's corrections)",
                    a * 100.0
                )),
            summary.path_length_m,
            summary.blocked_forwards,
            summary.forward_actions,
            out.dir().display()
        );
        if let Some(t) = &summary.tracking {
            eprintln!("evaluator: tracking: {}", t.line());
        }
        for w in &summary.warnings {
            eprintln!("{}", w.log_line(out.dir()));
        }
        Ok(summary)
    }
}

impl Operator for Evaluator {
    type Config = Config;

    fn new(config: Config, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        config
            .robot
            .validate()
            .map_err(|e| anyhow::anyhow!("evaluator: {e}"))?;
        let out = config
            .out
            .clone()
            .or_else(|| std::env::var_os("ACTIVEMAP_RUN_DIR").map(PathBuf::from))
            .unwrap_or_else(|| PathBuf::from("."));
        anyhow::ensure!(
            config.checkpoints.first().is_none_or(|&s| s >= 1)
                && config.checkpoints.windows(2).all(|w| w[0] < w[1]),
            "evaluator: checkpoints must be increasing step counts >= 1, got {:?}",
            config.checkpoints
        );
        anyhow::ensure!(
            (1..=16).contains(&config.bev_pixels_per_cell),
            "evaluator: bev_pixels_per_cell must be in 1..=16, got {}",
            config.bev_pixels_per_cell
        );
        Ok(Self {
            out: RunFolder::new(out),
            scene: config.scene_spec(),
            scale: config.bev_pixels_per_cell,
            truth: None,
            estimated: Trajectory::default(),
            reports: Vec::new(),
            corrected: CorrectedTrajectory::default(),
            true_traj: Trajectory::default(),
            coverage: Vec::new(),
            grid: None,
            regions: None,
            map: None,
            episode: String::new(),
            pending_grids: Vec::new(),
            written: false,
            true_positions: Default::default(),
            forward_steps: Vec::new(),
            robot: config.robot,
            depth_model: config.depth_model.unwrap_or_default(),
            fisher: Vec::new(),
            llm: Vec::new(),
            start_depth: None,
            checkpoints: config.checkpoints,
        })
    }

    fn on_event(&mut self, event: Event<'_>, _ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        match event {
            Event::Input(input) => match input.port {
                inputs::POSE => {
                    let e: PoseEstimate = input.decode()?;
                    let pose = pose_from_wire(&e.t_world_camera)?;
                    let corrections: Vec<_> = crate::convert::corrections_from_wire(&e)?
                        .into_iter()
                        .map(|c| (c.frame_id, c.correction))
                        .collect();
                    self.corrected
                        .push(e.stamp, pose, e.graph_anchor, &corrections);
                    self.estimated.push(e.stamp, pose);
                    self.reports.push(frame_report(&e));
                    let steps = self.estimated.len() as u64;
                    if self.checkpoints.binary_search(&steps).is_ok() {
                        self.score_pending()?;
                        self.write_checkpoint(steps)?;
                    }
                }
                inputs::TRUE_POSE => {
                    let t: TruePose = input.decode()?;
                    let pose = pose_from_wire(&t.t_world_camera)?;
                    if self.truth.is_none() {
                        let start = planar_from_camera_pose(&pose);
                        let sim = crate::sim::simulator(&self.scene, 16, 16, 90.0, &self.robot)?;
                        let nav = activemap_sim::ground_truth::navigable_map(sim.navigation());
                        let truth = CoverageTruth::new(nav, Point2::new(start.x, start.y));
                        let anchor = crate::convert::start_anchor(&RobotModel {
                            camera_height_m: pose.translation.z - sim.navigation().floor_z(),
                            ..RobotModel::default()
                        });
                        let start_from_world = anchor * pose.inverse();
                        self.truth = Some((truth, start, start_from_world));
                    }
                    let planar = planar_from_camera_pose(&pose);
                    self.true_positions
                        .insert(t.frame_id, Point2::new(planar.x, planar.y));
                    self.true_traj.push(t.stamp, pose);
                }
                inputs::EPISODE => {
                    let s: EpisodeStatus = input.decode()?;
                    self.episode = format!("{:?} at step {}: {}", s.state, s.step, s.message);
                }
                inputs::MAP => self.map = Some(read_map(input.bytes)?.1),
                inputs::GRID => self.pending_grids.push(read_grid(input.bytes)?),
                inputs::REGIONS => self.regions = Some(input.decode()?),
                inputs::RGBD => {
                    // Only the earliest frame matters (the start view); later ones are skipped
                    // after reading their header.
                    let view = RgbdFrameView::parse(input.bytes)?;
                    let id = view.header.frame_id;
                    if self.start_depth.is_none_or(|(first, _)| id < first) {
                        self.start_depth =
                            Some((id, validity::valid_depth_fraction(&view.depth())));
                    }
                }
                inputs::FISHER => self.fisher.push(fisher_row(&input.decode()?)?),
                inputs::LLM => {
                    // Written as it arrives: a crash later loses no exchange.
                    let e: LlmExchange = input.decode()?;
                    self.out.create()?;
                    let bev = (!e.bev_png.is_empty())
                        .then(|| {
                            self.out
                                .write_llm_bev(self.llm.len(), e.frame_id, &e.bev_png)
                        })
                        .transpose()?;
                    let record = llm_record(&e, bev);
                    self.out.append_llm(&record)?;
                    self.llm.push(record);
                }
                inputs::ACTION => {
                    let a: Action = input.decode()?;
                    if a.action == ActionKind::Forward {
                        self.forward_steps.push(a.step);
                    }
                }
                other => anyhow::bail!("evaluator: unexpected input `{other}`"),
            },
            Event::Stop => {
                self.score_pending()?;
                if !self.written {
                    self.written = true;
                    self.write_outputs()?;
                }
                return Ok(Flow::Stop);
            }
            _ => {}
        }
        self.score_pending()?;
        Ok(Flow::Continue)
    }
}

/// The operator's input ports, named once for registration and dispatch.
pub mod inputs {
    activemap_runtime::ports! {
        POSE = "pose": super::K::PoseEstimate,
        TRUE_POSE = "true_pose": super::K::TruePose,
        MAP = "map": super::K::GaussianMap,
        EPISODE = "episode": super::K::EpisodeStatus,
        GRID = "grid": super::K::OccupancyGrid,
        REGIONS = "regions": super::K::Frontiers,
        ACTION = "action": super::K::Action,
        FISHER = "fisher": super::K::FisherReport,
        LLM = "llm": super::K::LlmExchange,
        RGBD = "rgbd": super::K::RgbdFrame
    }
}

/// Registry entry.
pub fn registered() -> Registered {
    Registered {
        descriptor: OperatorDescriptor {
            name: "evaluator",
            summary: "Evaluation only: trajectories, map PLY, bird's-eye PNG, 2D coverage, ATE, Fisher replans, LLM exchanges (SPEC §8)",
            inputs: inputs::ALL,
            outputs: &[],
            evaluation: true,
            check_config: check_config_as::<Config>,
        },
        implementation: Some(OperatorImpl::of::<Evaluator>()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_eval::bev::BevCell;
    use activemap_planning::grid::CellState;
    use activemap_sim::NavigableMap;
    use activemap_splat::FLAG_UNKNOWN_SPACE;

    /// The evaluator writes its run folder through the contract: everything it wrote reads
    /// back through `RunFolder` as the same values, and the drawn BEV has the grid's size.
    #[test]
    fn outputs_read_back_through_the_run_folder() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunFolder::new(dir.path());
        let mut estimated = Trajectory::default();
        let mut true_traj = Trajectory::default();
        for k in 0..4 {
            let x = 0.05 * k as f64;
            estimated.push(k as f64, Isometry3::translation(x, 0.0, 0.0));
            true_traj.push(k as f64, Isometry3::translation(x, 1.0, 0.0));
        }
        let geometry =
            activemap_planning::grid::GridGeometry::new(-1.0, -1.0, 0.1, 20, 10).unwrap();
        let mut grid = PlanGrid::filled(geometry, CellState::Unknown);
        grid.data[0] = CellState::Free;
        grid.data[1] = CellState::Occupied;
        let coverage = vec![
            CoverageRow {
                step: 1,
                coverage: 0.25,
            },
            CoverageRow {
                step: 3,
                coverage: 0.5,
            },
        ];
        let mut ev = Evaluator {
            out: run.clone(),
            scene: SceneSpec::new("house:7"),
            scale: 3,
            truth: None,
            estimated,
            reports: Vec::new(),
            corrected: CorrectedTrajectory::default(),
            true_traj,
            coverage: coverage.clone(),
            grid: Some(grid.clone()),
            regions: None,
            map: None,
            episode: "Finished at step 3: test".into(),
            pending_grids: Vec::new(),
            written: false,
            true_positions: Default::default(),
            forward_steps: Vec::new(),
            robot: RobotModel::default(),
            depth_model: Default::default(),
            fisher: Vec::new(),
            llm: Vec::new(),
            start_depth: None,
            checkpoints: vec![4],
        };
        let summary = ev.write_outputs().unwrap();
        assert_eq!(run.read_summary().unwrap(), summary);
        // A checkpoint is a run folder of its own under checkpoints/, listed by step, with the
        // same results so far; the run's own summary stays as it was.
        let at_4 = ev.write_checkpoint(4).unwrap();
        let listed = run.checkpoints().unwrap();
        assert_eq!(listed.len(), 1);
        assert_eq!(listed[0].0, 4);
        assert_eq!(listed[0].1.read_summary().unwrap(), at_4);
        assert_eq!(
            (at_4.steps, at_4.episode.as_str()),
            (4, "checkpoint at step 4")
        );
        assert_eq!(listed[0].1.read_coverage().unwrap().unwrap(), coverage);
        assert_eq!(run.read_summary().unwrap(), summary);
        // No pose graph: no final trajectory, no final ATE.
        assert!(!run.path(RunFolder::TRAJECTORY_FINAL).exists());
        assert_eq!(summary.ate_final_m, None);
        // With one (every estimate hung on keyframe 0, which the last one moves 1 m along
        // y, onto the truth): the final trajectory is written, and its ATE is the truth's.
        for k in 0..4 {
            let x = 0.05 * k as f64;
            let correction = (k == 3).then(|| (0, Isometry3::translation(0.0, 1.0, 0.0)));
            let pose = Isometry3::translation(x, if k == 3 { 1.0 } else { 0.0 }, 0.0);
            ev.corrected
                .push(k as f64, pose, Some(0), correction.as_slice());
        }
        let summary = ev.write_outputs().unwrap();
        let corrected = run.read_trajectory(RunFolder::TRAJECTORY_FINAL).unwrap();
        assert!((corrected.poses[2].translation.y - 1.0).abs() < 1e-9);
        assert!(summary.ate_final_m.unwrap() < 1e-9);
        assert_eq!(run.read_summary().unwrap(), summary);
        // No map arrived: an invalid run, and it says so.
        assert_eq!(summary.warnings.len(), 1);
        assert_eq!(summary.warnings[0].code, validity::code::EMPTY_MAP);
        assert_eq!(summary.coverage, Some(0.5));
        assert_eq!(summary.scene.as_deref(), Some("house:7"));
        assert_eq!(run.read_coverage().unwrap().unwrap(), coverage);
        // No Fisher report arrived: no fisher.csv; one did: its row reads back.
        assert!(run.read_fisher().unwrap().is_none());
        let est = run.read_trajectory(RunFolder::TRAJECTORY_EST).unwrap();
        assert_eq!(est.len(), 4);
        assert!((est.poses[3].translation.x - 0.15).abs() < 1e-9);
        // No truth yet: no BEV; the drawing of the same grid is 20×10 cells at 3 px.
        assert!(!run.path(RunFolder::BEV).exists());
        let b = bev(
            &grid,
            &ev.estimated,
            &ev.true_traj,
            &Isometry3::identity(),
            &[],
            3,
        );
        assert_eq!((b.width, b.height, b.cells[1]), (20, 10, BevCell::Occupied));
        // The start of the estimate (0, 0) is the centre of cell (10, 10) − ½: cell units.
        assert_eq!(b.estimated[0], [9.5, 9.5]);
        run.write_bev(&b).unwrap();
        let img = image::open(run.path(RunFolder::BEV)).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (60, 30));
        let row = fisher_row(&report()).unwrap();
        ev.fisher.push(row);
        ev.write_outputs().unwrap();
        assert_eq!(run.read_fisher().unwrap().unwrap(), [row]);
        // A placed scene file: the summary records the placement and `activemap eval` rebuilds
        // the same scene from it.
        ev.scene = SceneSpec {
            placement: Placement {
                up_axis: Some(UpAxis::NegY),
                transform: Some(Transform {
                    scale: Some(0.01),
                    translate: Some([0.5, 0.0, 0.0]),
                    ..Transform::default()
                }),
                floor: Floor::Auto,
            },
            ..SceneSpec::new("scans/room.obj")
        };
        let summary = ev.write_outputs().unwrap();
        assert_eq!(summary.floor, Some(Floor::Auto));
        let back =
            activemap_eval::run_eval::scene_from_run(dir.path(), &run.read_summary().unwrap());
        assert_eq!(back.unwrap(), ev.scene);
    }

    /// A healthy run's state: a 2 m × 2 m reachable floor, 30 forward moves of 5 cm along x
    /// (frames 0..=30; the move computed on frame k shows in frame k + 1), a first frame with
    /// 80 % valid depth, a map of one observed and one unknown-space Gaussian.
    fn healthy(dir: &std::path::Path) -> Evaluator {
        use activemap_sim::navigation::GridFrame;
        let frame = GridFrame {
            origin_x: -1.0,
            origin_y: -1.0,
            cell_size: 0.05,
            width: 40,
            height: 40,
        };
        let nav = NavigableMap {
            frame,
            cells: vec![true; 1600],
        };
        let truth = CoverageTruth::new(nav, Point2::new(0.0, 0.0));
        let (mut estimated, mut true_traj) = (Trajectory::default(), Trajectory::default());
        let mut true_positions = std::collections::BTreeMap::new();
        for k in 0..=30u64 {
            let x = 0.05 * k as f64;
            estimated.push(k as f64, Isometry3::translation(x, 0.0, 0.0));
            true_traj.push(k as f64, Isometry3::translation(x, 0.0, 0.0));
            true_positions.insert(k, Point2::new(x, 0.0));
        }
        let mut map = Gaussians::<f32>::new();
        for x in [0.0, 1.0] {
            map.push(
                [x, 0.0, 1.0],
                [0.5; 3],
                [1.0, 0.0, 0.0, 0.0],
                0.9,
                [0.05; 3],
            );
        }
        map.flags[1] = FLAG_UNKNOWN_SPACE;
        Evaluator {
            out: RunFolder::new(dir),
            scene: SceneSpec::new("house:7"),
            scale: 3,
            truth: Some((truth, PlanarPose::new(0.0, 0.0, 0.0), Isometry3::identity())),
            estimated,
            reports: Vec::new(),
            corrected: CorrectedTrajectory::default(),
            true_traj,
            coverage: vec![CoverageRow {
                step: 30,
                coverage: 0.5,
            }],
            grid: None,
            regions: None,
            map: Some(map),
            episode: "Finished at step 30: test".into(),
            pending_grids: Vec::new(),
            written: false,
            true_positions,
            forward_steps: (0..30).collect(),
            robot: RobotModel::default(),
            depth_model: Default::default(),
            fisher: Vec::new(),
            llm: Vec::new(),
            start_depth: Some((0, 0.8)),
            checkpoints: Vec::new(),
        }
    }

    /// The codes of the warnings in the summary `ev` writes, checking the file says the same.
    fn codes(ev: &mut Evaluator) -> Vec<String> {
        let summary = ev.write_outputs().unwrap();
        let text = std::fs::read_to_string(ev.out.path(RunFolder::SUMMARY)).unwrap();
        let valid = format!("\"valid\": {}", summary.warnings.is_empty());
        assert!(text.contains(&valid), "{text}");
        assert_eq!(ev.out.read_summary().unwrap(), summary);
        summary.warnings.into_iter().map(|w| w.code).collect()
    }

    /// A healthy run has no warning; a start that sees nothing, a robot whose forward moves are
    /// all blocked, a map without observed Gaussians and a patch of reachable floor each make
    /// the run invalid with their own code and numbers.
    #[test]
    fn each_condition_makes_the_summary_invalid_and_a_healthy_run_is_valid() {
        let dir = tempfile::tempdir().unwrap();
        let mut ev = healthy(dir.path());
        assert_eq!(codes(&mut ev), Vec::<String>::new());

        let mut ev = healthy(dir.path());
        ev.start_depth = Some((0, 0.004));
        assert_eq!(codes(&mut ev), ["start_sees_nothing"]);
        let w = &ev.warnings(&ev.out.read_summary().unwrap())[0];
        assert!(w.message.contains("0.40 % valid depth"), "{w:?}");

        // Boxed in: every position is the start, every forward move blocked.
        let mut ev = healthy(dir.path());
        for (k, p) in ev.true_positions.iter_mut() {
            *p = Point2::new(0.0, 0.0);
            ev.true_traj.poses[*k as usize] = Isometry3::identity();
        }
        assert_eq!(codes(&mut ev), ["robot_cannot_move"]);
        let summary = ev.out.read_summary().unwrap();
        assert!(
            summary.warnings[0]
                .message
                .contains("30 of 30 forward moves blocked (100 %), true path 0.00 m over 31 steps"),
            "{:?}",
            summary.warnings
        );

        let mut ev = healthy(dir.path());
        ev.map.as_mut().unwrap().flags[0] = FLAG_UNKNOWN_SPACE;
        assert_eq!(codes(&mut ev), ["empty_map"]);
        let mut ev = healthy(dir.path());
        ev.map = None;
        assert_eq!(codes(&mut ev), ["empty_map"]);

        // A 0.6 m × 0.6 m patch of floor (coverage would read 100 % of it).
        let mut ev = healthy(dir.path());
        let nav = NavigableMap {
            frame: activemap_sim::navigation::GridFrame {
                origin_x: -0.3,
                origin_y: -0.3,
                cell_size: 0.05,
                width: 12,
                height: 12,
            },
            cells: vec![true; 144],
        };
        let truth = CoverageTruth::new(nav, Point2::new(0.0, 0.0));
        assert!((truth.reachable_area_m2() - 0.36).abs() < 1e-9);
        ev.truth.as_mut().unwrap().0 = truth;
        assert_eq!(codes(&mut ev), ["no_reachable_floor"]);

        // All at once, in a fixed order.
        let mut ev = healthy(dir.path());
        ev.start_depth = Some((0, 0.0));
        ev.map = None;
        ev.forward_steps.clear();
        ev.true_traj
            .poses
            .iter_mut()
            .for_each(|p| *p = Isometry3::identity());
        for k in 31..260u64 {
            ev.estimated.push(k as f64, Isometry3::identity());
        }
        assert_eq!(
            codes(&mut ev),
            ["start_sees_nothing", "robot_cannot_move", "empty_map"]
        );
    }

    /// Stands in for the node's outputs (the evaluator has none).
    struct NoOutputs;

    impl activemap_runtime::OutputSink for NoOutputs {
        fn send(&mut self, _: usize, _: &[u8]) -> Result<(), activemap_runtime::OperatorError> {
            Ok(())
        }
        fn loan(
            &mut self,
            _: usize,
            _: usize,
            _: &mut dyn FnMut(&mut [u8]) -> anyhow::Result<()>,
        ) -> Result<(), activemap_runtime::OperatorError> {
            Ok(())
        }
    }

    /// The `rgbd` input keeps the earliest frame's valid-depth fraction, whatever the arrival
    /// order; a later frame that sees more does not hide an empty start.
    #[test]
    fn the_rgbd_input_measures_the_earliest_frame() {
        use activemap_schemas::{RgbdFrame, RgbdFrameHeader};
        let dir = tempfile::tempdir().unwrap();
        let mut ev = healthy(dir.path());
        ev.start_depth = None;
        let frame = |id: u64, valid: usize| {
            let mut depth = vec![0.0f32; 100];
            depth[..valid].fill(1.5);
            RgbdFrame {
                header: RgbdFrameHeader::new(id, id as f64, [50.0, 50.0, 5.0, 5.0], 10, 10),
                rgb: vec![0; 300],
                depth,
            }
            .encode()
            .unwrap()
        };
        let mut sink = NoOutputs;
        let outputs: Vec<(String, K)> = Vec::new();
        let mut ctx = Context::new("evaluator", &outputs, &mut sink, None);
        for (seq, (id, valid)) in [(3, 90), (0, 0), (5, 100)].into_iter().enumerate() {
            let bytes = frame(id, valid);
            let input = activemap_runtime::Input {
                port: "rgbd",
                kind: K::RgbdFrame,
                seq: seq as u64 + 1,
                bytes: &bytes,
            };
            ev.on_event(Event::Input(input), &mut ctx).unwrap();
        }
        assert_eq!(ev.start_depth, Some((0, 0.0)));
        assert_eq!(codes(&mut ev), ["start_sees_nothing"]);
        assert!(
            registered()
                .descriptor
                .inputs
                .iter()
                .any(|p| p.name == "rgbd")
        );
    }

    /// A replan that chose its second path (EIG 4, 2, 0.5; C_local −30, +∞, −1) after 812.5 ms.
    fn report() -> FisherReport {
        use activemap_schemas::{FisherCandidate, FisherPath, FisherTimings, PlanarPose2};
        let path = |eig: Vec<f64>, c_local: Vec<f64>, objective, actions| FisherPath {
            goal: PlanarPose2 {
                x: 1.0,
                y: 0.5,
                yaw: -3.0,
            },
            waypoints: 3,
            actions,
            scored_steps: (1..=eig.len() as u32).map(|i| 5 * i).collect(),
            eig,
            c_local,
            objective,
        };
        FisherReport {
            frame_id: 120,
            refine: false,
            focus: Some([1.5, -0.25]),
            candidates: vec![
                FisherCandidate {
                    x: 1.0,
                    y: 0.5,
                    yaw: -3.0,
                    eig: 1e-3,
                };
                3
            ],
            paths: vec![
                path(vec![1.0], vec![f64::INFINITY], f64::INFINITY, 9),
                path(
                    vec![4.0, 2.0, 0.5],
                    vec![-30.0, f64::INFINITY, -1.0],
                    -7.5,
                    27,
                ),
            ],
            chosen: 1,
            gaussians: 150_000,
            unknown_gaussians: 4_000,
            model_reused: true,
            note: None,
            timings: FisherTimings {
                total_ms: 812.5,
                model_ms: 100.0,
                ..FisherTimings::default()
            },
            fallback: None,
        }
    }

    /// The row of a report: counts, the chosen path's terms summed (+∞ kept), its first EIG,
    /// and empty chosen-path columns when nothing was chosen; a bad chosen index or a NaN term
    /// is an error naming the frame.
    #[test]
    fn a_fisher_report_becomes_its_csv_row() {
        let row = fisher_row(&report()).unwrap();
        assert_eq!(
            row,
            FisherRow {
                step: 120,
                refine: false,
                candidates: 3,
                paths: 2,
                chosen: 1,
                objective: Some(-7.5),
                eig_sum: Some(6.5),
                eig_first: Some(4.0),
                c_local_sum: Some(f64::INFINITY),
                actions: Some(27),
                total_ms: 812.5,
                model_reused: true,
                fallback: false,
            }
        );
        let mut none = report();
        none.chosen = -1;
        none.refine = true;
        none.fallback = Some("look-around: no Fisher path for the refine goal".into());
        let row = fisher_row(&none).unwrap();
        assert_eq!(
            (row.chosen, row.refine, row.fallback, row.paths),
            (-1, true, true, 2)
        );
        assert_eq!(
            (
                row.objective,
                row.eig_sum,
                row.eig_first,
                row.c_local_sum,
                row.actions
            ),
            (None, None, None, None, None)
        );
        let mut out_of_range = report();
        out_of_range.chosen = 2;
        let e = fisher_row(&out_of_range).unwrap_err().to_string();
        assert!(
            e.contains("frame 120") && e.contains("chosen path 2 of 2"),
            "{e}"
        );
        let mut nan = report();
        nan.paths[1].c_local[0] = f64::NEG_INFINITY;
        let e = fisher_row(&nan).unwrap_err().to_string();
        assert!(
            e.contains("frame 120") && e.contains("c_local_sum NaN"),
            "{e}"
        );
    }

    /// `timings.csv` is written by the node hosts (activemap-runtime) and read through the
    /// run folder contract: same file name, same columns, same values.
    #[test]
    fn node_timings_read_back_through_the_run_folder() {
        use activemap_runtime::node::{StageTiming, TIMINGS_FILE, append_timing};
        assert_eq!(TIMINGS_FILE, RunFolder::TIMINGS);
        let dir = tempfile::tempdir().unwrap();
        for (node, seconds, calls) in [
            ("tracker", 2.5, 10),
            ("mapper", 1.25, 4),
            ("tracker", 0.5, 2),
        ] {
            append_timing(dir.path(), node, StageTiming { seconds, calls }).unwrap();
        }
        let rows = RunFolder::new(dir.path()).read_timings().unwrap().unwrap();
        let summed = activemap_eval::run_folder::StageTime::summed(&rows);
        let got: Vec<(&str, f64, u64)> = summed
            .iter()
            .map(|r| (r.stage.as_str(), r.seconds, r.calls))
            .collect();
        assert_eq!(got, [("tracker", 3.0, 12), ("mapper", 1.25, 4)]);
    }
}
