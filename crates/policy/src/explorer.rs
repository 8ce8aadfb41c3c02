//! The exploration loop in one synchronous object: a thin in-process driver of the very pieces
//! the pipeline's operators run, in the pipeline's order, so that both take the same actions
//! on the same frames and map snapshots (the `activemap-operators` tests
//! `explorer_and_pipeline_take_the_same_actions` (FBE) and
//! `fisher_explorer_and_pipeline_take_the_same_actions` check it on a house). Per step k:
//!
//! 1. occupancy, as the `occupancy` operator: the depth rays of frame k at its pose, the map
//!    points last given ([`Explorer::mapper_mut`]), the robot's footprint marked free
//!    ([`ExplorerConfig::footprint_radius_m`]);
//! 2. the [`PathExecutor`] (the `follower` operator) decides on grid k and pose k;
//! 3. when it asks for a new path: the reachable frontier regions of grid k
//!    ([`reachable_regions`], the `frontier` operator, as wire regions), the goal of the
//!    [`GoalPolicy`] (the `planner` operator; `None` ends the episode), the path of the
//!    [`PathPolicy`] (the `scorer` operator), handed to the executor, which decides again on the
//!    same grid and pose; after [`ExplorerConfig::max_replans_per_step`] requests in one step
//!    the robot turns left instead, as the follower does.
//!
//! Any policy runs: FBE with the shortest path ([`Explorer::new`]), or the goal and path
//! policies of the `planner` and `scorer` configs ([`Explorer::with_policies`]: `fisher`,
//! `fisher_eig_only`, `llm`). Map snapshots ([`Explorer::add_map`]) go to both policies, as the
//! mapper's `map` goes to the planner and the scorer. Poses are taken as given (true ones in
//! the benchmark, estimates in the pipeline): no SLAM and no transport here, and tracking is
//! never lost.

use std::time::{Duration, Instant};

use activemap_geometry::frames::planar_from_camera_pose;
use activemap_geometry::{Intrinsics, Isometry3, PlanarPose};
use nalgebra::Point2;
use serde::{Deserialize, Serialize};

use activemap_planning::astar::AstarConfig;
use activemap_planning::clearance::ClearanceConfig;
use activemap_planning::dynamics::{Action, RobotModel};
use activemap_planning::executor::{self, ExecutorConfig, ExecutorCounters, PathExecutor};
use activemap_planning::fbe::{FbeConfig, FbeState};
use activemap_planning::frontier::{FrontierConfig, FrontierRegion, reachable_regions};
use activemap_planning::grid::OccupancyGrid;
use activemap_planning::occupancy::{OccupancyConfig, OccupancyMapper};
use activemap_schemas::{FisherReport, Frontiers, LlmExchange, ReplanRequest};

use crate::goal::{GoalInput, GoalPolicy, NoFrontier};
use crate::path::{PathInput, PathPolicy};
use crate::wire::{reason_to_wire, regions_to_wire};
use crate::{GoalChoice, MapSnapshot, PathChoice, no_log};

/// Every setting of the loop (defaults: those of the operators in `dataflow.yaml`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ExplorerConfig {
    /// Occupancy mapping (the `occupancy` operator's `cell_size`, `point_threshold`,
    /// `pixel_stride`).
    pub occupancy: OccupancyConfig,
    /// Radius (metres) around the robot always marked free: its own footprint (the
    /// `occupancy` operator's `footprint_radius`, default the robot's radius).
    pub footprint_radius_m: f64,
    /// The robot: its radius gives the one clearance ([`ClearanceConfig::for_disc`]) of the
    /// frontiers' reachability, A* and the executor's triggers, as in the operators; its
    /// forward step the executor's bumper.
    pub robot: RobotModel,
    /// Frontier extraction.
    pub frontier: FrontierConfig,
    /// A* of the shortest-path policy [`Explorer::new`] runs.
    pub astar: AstarConfig,
    /// Goal ranking, strikes and amnesty of the FBE policy [`Explorer::new`] runs.
    pub fbe: FbeConfig,
    /// Path execution.
    pub executor: ExecutorConfig,
    /// Replan requests answered within one step before the robot turns left instead (the
    /// `follower` operator's `max_replans_per_step`).
    pub max_replans_per_step: usize,
}

impl Default for ExplorerConfig {
    fn default() -> Self {
        Self {
            occupancy: OccupancyConfig::default(),
            footprint_radius_m: RobotModel::default().radius_m,
            robot: RobotModel::default(),
            frontier: FrontierConfig::default(),
            astar: AstarConfig::default(),
            fbe: FbeConfig::default(),
            executor: ExecutorConfig::default(),
            max_replans_per_step: executor::MAX_REPLANS_PER_STEP,
        }
    }
}

/// What the loop decided this step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Decision {
    /// Execute this action.
    Act(Action),
    /// The goal policy ended the episode (no reachable frontier left; the pipeline's `Stop`).
    Finished,
}

/// Time spent per stage, summed over steps (for the benchmark's time shares).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StageTimes {
    /// Occupancy update and grid extraction.
    pub occupancy: Duration,
    /// The executor's decisions (replan triggers, stuck detection, the follower).
    pub triggers: Duration,
    /// Frontier extraction and goal choice.
    pub frontiers: Duration,
    /// The path choice (A* and shortcutting, or the Fisher replan).
    pub planning: Duration,
}

/// Counters of what happened during an episode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct ExplorerCounters {
    /// Replan requests answered (goal chosen and path made, or the episode ended).
    pub replans: usize,
    /// Paths handed to the executor that had waypoints.
    pub plans: usize,
    /// Goals A* could not reach.
    pub unreachable_goals: usize,
    /// Steps that turned left because `max_replans_per_step` requests were used up.
    pub replan_limit_turns: usize,
    /// Times every frontier was banned and the strikes were forgiven.
    pub amnesties: usize,
    /// Goals reached whose frontier did not shrink (banned at once).
    pub unobservable_goals: usize,
    /// The executor's counters (stuck, bumps, obstacle replans, skipped look turns, ...).
    pub executor: ExecutorCounters,
}

/// The loop state, running the goal choice `G` and the path choice `P` (by default the
/// built-in policies).
pub struct Explorer<G = GoalPolicy, P = PathPolicy> {
    config: ExplorerConfig,
    mapper: OccupancyMapper,
    executor: PathExecutor,
    goals: G,
    paths: P,
    /// The frame of the next step.
    frame: u64,
    grid: Option<OccupancyGrid>,
    regions: Option<Vec<FrontierRegion>>,
    /// The wire regions of the last step that asked for a path (what the policies see).
    frontiers: Option<Frontiers>,
    /// The last LLM exchange and Fisher report, when the policies made them.
    exchange: Option<LlmExchange>,
    report: Option<FisherReport>,
    counters: ExplorerCounters,
    /// Time per stage.
    pub times: StageTimes,
}

impl Explorer {
    /// The FBE loop (goal choice `config.fbe`, the episode ends with no frontier left, the
    /// shortest path with `config.astar`; no log) with an empty map initially covering
    /// `[min, max]` (it grows; the `occupancy` operator starts with (−2, −2)–(2, 2) in the
    /// start-anchored frame).
    pub fn new(config: ExplorerConfig, min: Point2<f64>, max: Point2<f64>) -> anyhow::Result<Self> {
        let goals = GoalPolicy::fbe(config.fbe, NoFrontier::End)?.with_log(no_log);
        let paths = PathPolicy::shortest(config.robot, config.astar);
        Self::with_policies(config, min, max, goals, paths)
    }
}

impl<P> Explorer<GoalPolicy, P> {
    /// The FBE decision state (strikes, amnesties; for `llm`, its eligibility).
    pub fn fbe(&self) -> &FbeState {
        self.goals.fbe_state()
    }
}

impl<G: GoalChoice, P: PathChoice> Explorer<G, P> {
    /// The loop running the goal choice `goals` and the path choice `paths` (e.g. the
    /// [`GoalPolicy`] and [`PathPolicy`] of the `planner` and `scorer` configs), with an empty
    /// map initially covering `[min, max]`.
    pub fn with_policies(
        config: ExplorerConfig,
        min: Point2<f64>,
        max: Point2<f64>,
        goals: G,
        paths: P,
    ) -> anyhow::Result<Self> {
        config.astar.validate()?;
        anyhow::ensure!(
            config.footprint_radius_m.is_finite() && config.footprint_radius_m >= 0.0,
            "invalid configuration `ExplorerConfig::footprint_radius_m`: must be finite and non-negative"
        );
        anyhow::ensure!(
            config.max_replans_per_step >= 1,
            "invalid configuration `ExplorerConfig::max_replans_per_step`: must be at least 1"
        );
        ClearanceConfig::for_disc(config.robot.radius_m, config.occupancy.resolution)?;
        Ok(Self {
            mapper: OccupancyMapper::new(config.occupancy, min, max)?,
            executor: PathExecutor::new(config.executor, config.robot)?,
            goals,
            paths,
            config,
            frame: 0,
            grid: None,
            regions: None,
            frontiers: None,
            exchange: None,
            report: None,
            counters: ExplorerCounters::default(),
            times: StageTimes::default(),
        })
    }

    /// The latest occupancy grid.
    pub fn grid(&self) -> Option<&OccupancyGrid> {
        self.grid.as_ref()
    }

    /// The reachable frontier regions of the last step that asked for a path, largest first.
    pub fn regions(&self) -> Option<&[FrontierRegion]> {
        self.regions.as_deref()
    }

    /// The waypoints (world) of the path being followed that are not reached yet; `None`
    /// when no path is being followed.
    pub fn remaining_path(&self) -> Option<&[Point2<f64>]> {
        self.executor.remaining()
    }

    /// The end of the path being followed and the yaw the robot will face there (toward the
    /// frontier); `None` unless a path is being followed.
    pub fn goal(&self) -> Option<(Point2<f64>, f64)> {
        self.executor.goal()
    }

    /// The goal choice.
    pub fn goals(&self) -> &G {
        &self.goals
    }

    /// The path choice.
    pub fn paths(&self) -> &P {
        &self.paths
    }

    /// The wire frontier regions of the last step that asked for a path.
    pub fn frontiers(&self) -> Option<&Frontiers> {
        self.frontiers.as_ref()
    }

    /// The last LLM exchange (policy `llm` with a provider).
    pub fn last_exchange(&self) -> Option<&LlmExchange> {
        self.exchange.as_ref()
    }

    /// The last Fisher report (path policy `fisher`).
    pub fn last_report(&self) -> Option<&FisherReport> {
        self.report.as_ref()
    }

    /// Hands a map snapshot to both policies (the LLM's BEV and the Fisher scorer read the
    /// snapshot of frame k − 1 − L at step k; it must be there by then).
    pub fn add_map(&mut self, map: &MapSnapshot<'_>) -> anyhow::Result<()> {
        self.goals.add_map(map)?;
        self.paths.add_map(map)
    }

    /// The path executor.
    pub fn executor(&self) -> &PathExecutor {
        &self.executor
    }

    /// What happened so far.
    pub fn counters(&self) -> ExplorerCounters {
        ExplorerCounters {
            amnesties: self.goals.fbe_state().map_or(0, |s| s.amnesties),
            unobservable_goals: self.goals.fbe_state().map_or(0, |s| s.unobservable_goals),
            executor: self.executor.counters,
            ..self.counters
        }
    }

    /// The occupancy mapper (to feed map points, which count from the next step on).
    pub fn mapper_mut(&mut self) -> &mut OccupancyMapper {
        &mut self.mapper
    }

    /// One step (frame k = the number of steps before): integrate the depth frame taken at
    /// camera pose `t_world_camera` (the robot's planar pose is derived from it, as every
    /// operator does), then decide.
    pub fn step(
        &mut self,
        depth: &[f32],
        intrinsics: &Intrinsics,
        t_world_camera: &Isometry3<f64>,
    ) -> anyhow::Result<Decision> {
        let k = self.frame;
        self.frame += 1;
        let t0 = Instant::now();
        self.mapper
            .integrate_depth(depth, intrinsics, t_world_camera)?;
        let pose = planar_from_camera_pose(t_world_camera);
        self.mapper
            .mark_free_disc(Point2::new(pose.x, pose.y), self.config.footprint_radius_m)?;
        let grid = self.mapper.grid();
        self.times.occupancy += t0.elapsed();
        self.goals.add_pose(&pose);
        self.paths.add_pose(k, *t_world_camera);
        let decision = self.decide(k, t_world_camera, &pose, &grid);
        self.grid = Some(grid);
        decision
    }

    /// The follower's per-step loop: decide; answer each replan request with a goal and a
    /// path on the same grid and pose (of frame `k`), at most `max_replans_per_step` times.
    fn decide(
        &mut self,
        k: u64,
        camera: &Isometry3<f64>,
        pose: &PlanarPose,
        grid: &OccupancyGrid,
    ) -> anyhow::Result<Decision> {
        let here = Point2::new(pose.x, pose.y);
        let clearance =
            ClearanceConfig::for_disc(self.config.robot.radius_m, grid.geometry.resolution)?;
        let mut replans = 0;
        loop {
            let t = Instant::now();
            let decision = self.executor.decide(pose, grid, false)?;
            self.times.triggers += t.elapsed();
            let reason = match decision {
                executor::Decision::Act(a) => return Ok(Decision::Act(a)),
                executor::Decision::Replan(_) if replans >= self.config.max_replans_per_step => {
                    self.counters.replan_limit_turns += 1;
                    return Ok(Decision::Act(Action::TurnLeft));
                }
                executor::Decision::Replan(reason) => reason,
            };
            replans += 1;
            self.counters.replans += 1;
            let t = Instant::now();
            // The frontier operator's regions of this frame, extracted once per step.
            if replans == 1 {
                let regions = reachable_regions(grid, here, &clearance, &self.config.frontier)?;
                self.frontiers = Some(Frontiers {
                    frame_id: k,
                    stamp: 0.0,
                    regions: regions_to_wire(grid, &regions),
                });
                self.regions = Some(regions);
            }
            let frontiers = self.frontiers.as_ref().expect("extracted above");
            let choice = self.goals.goal(&GoalInput {
                request: ReplanRequest {
                    frame_id: k,
                    reason: reason_to_wire(reason),
                },
                grid,
                frontiers,
                pose: *pose,
                camera_z: camera.translation.z,
            })?;
            self.times.frontiers += t.elapsed();
            if choice.exchange.is_some() {
                self.exchange = choice.exchange;
            }
            let Some(goal) = choice.goal else {
                return Ok(Decision::Finished);
            };
            let t = Instant::now();
            let answer = self.paths.path(&PathInput {
                goal: &goal,
                grid,
                pose: *camera,
                frontiers: Some(frontiers),
            })?;
            self.times.planning += t.elapsed();
            if answer.report.is_some() {
                self.report = answer.report;
            }
            let waypoints: Vec<PlanarPose> = answer
                .path
                .waypoints
                .iter()
                .map(|w| PlanarPose::new(w.x, w.y, w.yaw))
                .collect();
            // No path found: an empty path of infinite objective (a path to the robot's own
            // cell is empty too, at a finite cost).
            if waypoints.is_empty() && answer.path.objective == f64::INFINITY {
                self.counters.unreachable_goals += 1;
            }
            if !waypoints.is_empty() {
                self.counters.plans += 1;
            }
            self.executor.set_path(&waypoints)?;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::goal::GoalConfig;
    use activemap_geometry::camera_pose_from_planar;
    use activemap_llm::provider::{Completion, RecordedReply, Usage};
    use activemap_planning::grid::Cell;
    use activemap_planning::synthetic::SyntheticWorld;

    /// The point `dist` metres along the polyline from `from` through `path`, if it is at least
    /// 0.25 m shorter than the polyline.
    fn point_along(from: Point2<f64>, path: &[Point2<f64>], dist: f64) -> Option<Point2<f64>> {
        let total: f64 = std::iter::once(from)
            .chain(path.iter().copied())
            .collect::<Vec<_>>()
            .windows(2)
            .map(|w| (w[1] - w[0]).norm())
            .sum();
        if total < dist + 0.25 {
            return None;
        }
        let mut left = dist;
        let mut prev = from;
        for w in path {
            let l = (w - prev).norm();
            if l >= left {
                return Some(prev + (w - prev) * (left / l));
            }
            left -= l;
            prev = *w;
        }
        None
    }

    /// An obstacle appears on the path while the robot follows it: the loop replans around it
    /// and never drives into it.
    #[test]
    fn a_new_obstacle_on_the_path_triggers_a_replan() {
        let mut world = SyntheticWorld::procedural_house(3, 2, 1, 3.0).unwrap();
        let k = Intrinsics::from_hfov(64, 64, std::f64::consts::FRAC_PI_2);
        let model = RobotModel::default();
        let mut ex = Explorer::new(
            ExplorerConfig::default(),
            Point2::new(0.0, 0.0),
            Point2::new(6.0, 3.0),
        )
        .unwrap();
        let mut pose = world.start;
        let mut placed = None;
        let mut bumps = 0;
        for _ in 0..600 {
            let cam = camera_pose_from_planar(&pose, 0.0, 0.88);
            let depth = world.render_depth(&k, &cam);
            let dec = ex.step(&depth, &k, &cam).unwrap();
            let Decision::Act(a) = dec else {
                break;
            };
            // Once the robot drives along a path with at least 1.45 m to go, drop a 0.3 m box
            // 1.2 m ahead of it on the path (in view: the camera sees the floor from 0.88 m).
            if placed.is_none() && a == Action::Forward {
                let here = Point2::new(pose.x, pose.y);
                if let Some(c) = ex.remaining_path().and_then(|p| point_along(here, p, 1.2)) {
                    let g = world.heights.geometry;
                    let r = nalgebra::Vector2::new(0.15, 0.15);
                    let (lo, hi) = (g.cell_of(c - r), g.cell_of(c + r));
                    for y in lo.y..=hi.y {
                        for x in lo.x..=hi.x {
                            world.heights.set(Cell::new(x, y), 0.6);
                        }
                    }
                    placed = Some(ex.counters());
                }
            }
            let next = world.step(&pose, a, &model, 0.05);
            if a == Action::Forward && next == pose {
                bumps += 1;
            }
            pose = next;
        }
        let before = placed.expect("the robot never followed a long enough path");
        let replans = |c: &ExplorerCounters| c.executor.obstacle_replans;
        assert!(
            replans(&ex.counters()) > replans(&before),
            "{:?} -> {:?}",
            before,
            ex.counters()
        );
        assert_eq!(bumps, 0, "drove into the new obstacle");
    }

    /// End to end on a 2×2-room procedural house with true poses: FBE explores until no
    /// reachable frontier is left, covers ≥ 80 % of the navigable floor, never sits stuck
    /// against a wall for long, and the map-driven replans happen.
    #[test]
    fn fbe_explores_a_small_house() {
        let world = SyntheticWorld::procedural_house(7, 2, 2, 3.0).unwrap();
        let k = Intrinsics::from_hfov(64, 64, std::f64::consts::FRAC_PI_2);
        let model = RobotModel::default();
        let mut ex = Explorer::new(
            ExplorerConfig::default(),
            Point2::new(world.start.x - 1.0, world.start.y - 1.0),
            Point2::new(world.start.x + 1.0, world.start.y + 1.0),
        )
        .unwrap();
        let mut pose = world.start;
        let mut finished_at = None;
        let mut blocked_forward = 0usize;
        for step in 0..3000 {
            let cam = camera_pose_from_planar(&pose, 0.0, 0.88);
            let depth = world.render_depth(&k, &cam);
            match ex.step(&depth, &k, &cam).unwrap() {
                Decision::Finished => {
                    finished_at = Some(step);
                    break;
                }
                Decision::Act(a) => {
                    let next = world.step(&pose, a, &model, 0.05);
                    if a == Action::Forward && next == pose {
                        blocked_forward += 1;
                    }
                    pose = next;
                }
            }
        }
        let coverage = world.coverage(ex.grid().unwrap());
        if std::env::var("PLANNING_DEBUG").is_ok() {
            let g = ex.grid().unwrap();
            let mut txt = String::new();
            for y in (0..g.geometry.height).rev() {
                for x in 0..g.geometry.width {
                    let c = Cell::new(x as i32, y as i32);
                    txt.push(match g.get(c).unwrap() {
                        activemap_planning::grid::CellState::Free => '.',
                        activemap_planning::grid::CellState::Occupied => '#',
                        activemap_planning::grid::CellState::Unknown => ' ',
                    });
                }
                txt.push('\n');
            }
            std::fs::write("/tmp/planning_grid.txt", txt).unwrap();
            for r in ex.regions().unwrap() {
                eprintln!(
                    "region size {} first {:?} approach {:?}",
                    r.size(),
                    r.cells[0],
                    r.approach
                );
            }
            eprintln!("strikes {:?}", ex.fbe().strikes());
        }
        eprintln!(
            "finished at {finished_at:?}, coverage {coverage:.3}, blocked forward {blocked_forward}, {:?}",
            ex.counters()
        );
        assert!(finished_at.is_some(), "no end within 3000 steps");
        assert!(coverage >= 0.8, "coverage {coverage}");
        assert!(
            blocked_forward < 40,
            "bumped into walls {blocked_forward} times"
        );
    }

    /// Runs `explorer` on the 2×2-room house with true poses for at most `steps` steps.
    fn run_on_small_house(explorer: &mut Explorer, steps: usize) {
        let world = SyntheticWorld::procedural_house(7, 2, 2, 3.0).unwrap();
        let k = Intrinsics::from_hfov(64, 64, std::f64::consts::FRAC_PI_2);
        let mut pose = world.start;
        for _ in 0..steps {
            let cam = camera_pose_from_planar(&pose, 0.0, 0.88);
            let depth = world.render_depth(&k, &cam);
            match explorer.step(&depth, &k, &cam).unwrap() {
                Decision::Finished => break,
                Decision::Act(a) => pose = world.step(&pose, a, &RobotModel::default(), 0.05),
            }
        }
    }

    /// The `llm` goal policy runs in process, with the offline heuristic (no provider) and
    /// with a recorded provider serving replies (text prompt: no map needed); the shortest
    /// path answers its goals, and the recorded exchanges come back out.
    #[test]
    fn the_llm_policy_runs_in_process_offline_and_recorded() {
        let fail = |_: &std::path::Path, _: &str| anyhow::bail!("no recordings");
        let offline: GoalConfig =
            serde_json::from_value(serde_json::json!({ "policy": "llm" })).unwrap();
        let recorded: GoalConfig = serde_json::from_value(serde_json::json!({
            "policy": "llm",
            "llm": { "prompt": "text", "provider": { "kind": "recorded", "recording": "r.mcap" } }
        }))
        .unwrap();
        let reply = || RecordedReply {
            system: String::new(),
            user: String::new(),
            completion: Completion {
                provider: "openai".into(),
                model: "m".into(),
                request: "{}".into(),
                http_status: Some(200),
                attempts: 1,
                latency_ms: 1.0,
                usage: Usage::default(),
                reply: "{\"target\": 0, \"reason\": \"the largest\"}".into(),
                finish_reason: Some("stop".into()),
                reasoning: String::new(),
                schema_refused: false,
                failure: None,
            },
            follow_up: None,
            background: false,
            answered_frame: None,
        };
        let replies = |_: &std::path::Path, node: &str| {
            assert_eq!(node, "planner");
            Ok((0..100).map(|_| reply()).collect())
        };
        for (config, load) in [
            (offline, &fail as crate::goal::RecordedLoader<'_>),
            (recorded, &replies),
        ] {
            let goals = GoalPolicy::new(&config, "planner", Some(300), load)
                .unwrap()
                .with_log(no_log);
            let paths = PathPolicy::shortest(RobotModel::default(), AstarConfig::default());
            let world = SyntheticWorld::procedural_house(7, 2, 2, 3.0).unwrap();
            let (s, r) = (world.start, 1.0);
            let mut ex = Explorer::with_policies(
                ExplorerConfig::default(),
                Point2::new(s.x - r, s.y - r),
                Point2::new(s.x + r, s.y + r),
                goals,
                paths,
            )
            .unwrap();
            run_on_small_house(&mut ex, 300);
            let c = ex.counters();
            assert!(c.plans >= 2, "{c:?}");
            let llm = ex.goals().llm().expect("the llm policy");
            match config.llm {
                None => assert!(ex.last_exchange().is_none()),
                Some(_) => {
                    assert!(llm.stats().calls >= 1);
                    let e = ex.last_exchange().expect("a recorded exchange");
                    assert_eq!(
                        (e.target, e.reason.as_deref()),
                        (Some(0), Some("the largest"))
                    );
                }
            }
        }
    }
}
