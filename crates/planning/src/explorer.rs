//! The whole frontier-based exploration loop of issue 6 in one synchronous object, for the
//! library's own end-to-end tests and benchmark, and as the reference the operators split up:
//! occupancy update → replan triggers / stuck check → (frontiers → FBE goal → A* → shortcut)
//! → greedy follower action. The episode starts with a 360° look-around. Once at a goal, the
//! robot turns to face the frontier cell it came to look at, unless that cell is already within
//! [`ExplorerConfig::look_skip_half_angle_rad`] of its heading (in the camera's view). Goal
//! choice, strikes and amnesty are [`FbeState`]'s (the `planner` operator uses the same): when
//! every frontier is banned, the robot forgives the strikes and looks around again, as long as
//! the map grew since the last such spin.

use std::time::{Duration, Instant};

use activemap_geometry::{Intrinsics, Isometry3, PlanarPose};
use nalgebra::Point2;
use serde::{Deserialize, Serialize};

use crate::astar::{AstarConfig, plan};
use crate::clearance::{ClearanceConfig, ClearanceMap};
use crate::dynamics::Action;
use crate::error::PlanningError;
use crate::fbe::{FbeConfig, FbeState, GoalOutcome};
use crate::follower::{FollowerConfig, GreedyFollower, greedy_action, look_turn_needed};
use crate::frontier::{FrontierConfig, Frontiers, extract_frontiers};
use crate::grid::{Cell, OccupancyGrid};
use crate::occupancy::{OccupancyConfig, OccupancyMapper};
use crate::replan::{ReplanConfig, ReplanReason, check_replan};
use crate::shortcut::shortcut;
use crate::stuck::ProgressMonitor;

/// Every setting of the loop.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ExplorerConfig {
    /// Occupancy mapping.
    pub occupancy: OccupancyConfig,
    /// Robot width and unknown handling for planning.
    pub clearance: ClearanceConfig,
    /// A*.
    pub astar: AstarConfig,
    /// Frontier extraction.
    pub frontier: FrontierConfig,
    /// Greedy follower.
    pub follower: FollowerConfig,
    /// Replan triggers.
    pub replan: ReplanConfig,
    /// Goal ranking, strikes and amnesty.
    pub fbe: FbeConfig,
    /// Radius (metres) around the robot always marked free (its own footprint).
    pub footprint_radius_m: f64,
    /// Steps without progress before the robot counts as stuck.
    pub stuck_window: usize,
    /// Progress needed to reset the stuck counter, metres.
    pub stuck_min_improvement_m: f64,
    /// At a goal, the look turn toward the frontier is skipped when the frontier's bearing is
    /// within this angle of the heading (radians; the camera's half hfov is 45°; the default
    /// 25° keeps the frontier well inside the view: 40° measured worse on `house:4`, see
    /// `house_episode`). 0 always turns.
    pub look_skip_half_angle_rad: f64,
    /// Turns of a full look-around (72 × 5° = 360°), done at the start of the episode and
    /// when every frontier got banned while the map still grows.
    pub spin_steps: usize,
    /// When stuck, an obstacle cell is put this far (metres) ahead of the robot. It must lie
    /// beyond `footprint_radius_m`, or the next step's footprint clears it again.
    pub bump_obstacle_ahead_m: f64,
}

impl Default for ExplorerConfig {
    fn default() -> Self {
        Self {
            occupancy: OccupancyConfig::default(),
            clearance: ClearanceConfig::default(),
            astar: AstarConfig::default(),
            frontier: FrontierConfig::default(),
            follower: FollowerConfig::default(),
            replan: ReplanConfig::default(),
            fbe: FbeConfig::default(),
            footprint_radius_m: 0.15,
            stuck_window: 40,
            stuck_min_improvement_m: 0.02,
            look_skip_half_angle_rad: 25f64.to_radians(),
            spin_steps: 72,
            bump_obstacle_ahead_m: 0.2,
        }
    }
}

/// What the loop decided this step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Decision {
    /// Execute this action.
    Act(Action),
    /// No reachable frontier is left: the episode is over.
    Finished,
}

/// Time spent per stage, summed over steps (for the benchmark's time shares).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StageTimes {
    /// Occupancy update and grid extraction.
    pub occupancy: Duration,
    /// Replan checks and stuck detection.
    pub triggers: Duration,
    /// Frontier extraction and goal choice.
    pub frontiers: Duration,
    /// A* and shortcutting.
    pub planning: Duration,
}

/// Counters of what happened during an episode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct ExplorerCounters {
    /// Plans made.
    pub plans: usize,
    /// Replans because the remaining path crossed a new obstacle.
    pub path_blocked: usize,
    /// Replans because an obstacle appeared close ahead.
    pub obstacle_ahead: usize,
    /// Replans because the goal turned occupied.
    pub goal_occupied: usize,
    /// Stuck detections.
    pub stuck: usize,
    /// Goals A* could not reach.
    pub unreachable_goals: usize,
    /// Look-around spins after every frontier got banned.
    pub recovery_spins: usize,
    /// Goals reached without the look turn (the frontier was already in view).
    pub looks_skipped: usize,
    /// Goals reached whose frontier did not shrink (banned at once).
    pub unobservable_goals: usize,
}

enum Phase {
    Idle,
    /// Turning on the spot for this many more steps (initial look-around or recovery).
    Spin(usize),
    Follow {
        follower: GreedyFollower,
        goal: Cell,
        look_at: Point2<f64>,
    },
    Look {
        look_at: Point2<f64>,
    },
}

/// The FBE loop state.
pub struct Explorer {
    config: ExplorerConfig,
    mapper: OccupancyMapper,
    phase: Phase,
    monitor: ProgressMonitor,
    fbe: FbeState,
    /// How the last goal ended (judged at the next plan, against the new frontiers).
    outcome: GoalOutcome,
    grid: Option<OccupancyGrid>,
    frontiers: Option<Frontiers>,
    plan_grid: Option<OccupancyGrid>,
    /// Time per stage.
    pub times: StageTimes,
    /// Event counters.
    pub counters: ExplorerCounters,
}

impl Explorer {
    /// A loop with an empty map initially covering `[min, max]` (it grows).
    pub fn new(
        config: ExplorerConfig,
        min: Point2<f64>,
        max: Point2<f64>,
    ) -> Result<Self, PlanningError> {
        config.clearance.validate()?;
        config.astar.validate()?;
        config.follower.validate()?;
        config.replan.validate()?;
        crate::error::require(
            config.bump_obstacle_ahead_m.is_finite()
                && config.bump_obstacle_ahead_m > config.footprint_radius_m,
            "ExplorerConfig::bump_obstacle_ahead_m",
            "must be finite and beyond footprint_radius_m (the footprint would clear the bump)",
        )?;
        Ok(Self {
            mapper: OccupancyMapper::new(config.occupancy, min, max)?,
            monitor: ProgressMonitor::new(config.stuck_window, config.stuck_min_improvement_m)?,
            phase: Phase::Spin(config.spin_steps),
            config,
            fbe: FbeState::new(config.fbe)?,
            outcome: GoalOutcome::Abandoned,
            grid: None,
            frontiers: None,
            plan_grid: None,
            times: StageTimes::default(),
            counters: ExplorerCounters::default(),
        })
    }

    /// The latest occupancy grid.
    pub fn grid(&self) -> Option<&OccupancyGrid> {
        self.grid.as_ref()
    }

    /// The latest frontiers (from the last plan).
    pub fn frontiers(&self) -> Option<&Frontiers> {
        self.frontiers.as_ref()
    }

    /// The waypoints (world) of the path being followed that are not reached yet; `None`
    /// when no path is being followed.
    pub fn remaining_path(&self) -> Option<&[Point2<f64>]> {
        match &self.phase {
            Phase::Follow { follower, .. } => Some(follower.remaining()),
            _ => None,
        }
    }

    /// The goal (world centre of the approach cell) and the frontier point being driven to;
    /// `None` unless a path is being followed.
    pub fn goal(&self) -> Option<(Point2<f64>, Point2<f64>)> {
        match (&self.phase, &self.grid) {
            (Phase::Follow { goal, look_at, .. }, Some(g)) => {
                Some((g.geometry.center(*goal), *look_at))
            }
            _ => None,
        }
    }

    /// The FBE decision state (strikes, amnesties).
    pub fn fbe(&self) -> &FbeState {
        &self.fbe
    }

    /// The occupancy mapper (to feed map points too).
    pub fn mapper_mut(&mut self) -> &mut OccupancyMapper {
        &mut self.mapper
    }

    /// One step: integrate the depth frame taken at the (estimated) pose, then decide.
    pub fn step(
        &mut self,
        pose: &PlanarPose,
        depth: &[f32],
        intrinsics: &Intrinsics,
        t_world_camera: &Isometry3<f64>,
    ) -> Result<Decision, PlanningError> {
        let t0 = Instant::now();
        self.mapper
            .integrate_depth(depth, intrinsics, t_world_camera)?;
        let here = Point2::new(pose.x, pose.y);
        self.mapper
            .mark_free_disc(here, self.config.footprint_radius_m)?;
        let grid = self.mapper.grid();
        self.times.occupancy += t0.elapsed();
        let decision = self.decide(pose, &grid);
        self.grid = Some(grid);
        decision
    }

    fn decide(
        &mut self,
        pose: &PlanarPose,
        grid: &OccupancyGrid,
    ) -> Result<Decision, PlanningError> {
        let here = Point2::new(pose.x, pose.y);
        let threshold = self.config.follower.turn_threshold_rad;
        // Up to a few phase changes per step (a finished path hands over to a new plan).
        for _ in 0..4 {
            match &mut self.phase {
                Phase::Spin(left) => {
                    if *left > 0 {
                        *left -= 1;
                        return Ok(Decision::Act(Action::TurnLeft));
                    }
                    self.phase = Phase::Idle;
                }
                Phase::Idle => {
                    if !self.make_plan(pose, grid)? {
                        // Every reachable frontier is banned or none is left. If the map grew
                        // since the last look-around, forgive the strikes and look around once
                        // more; otherwise the episode is over.
                        let free = grid.count(crate::grid::CellState::Free);
                        if self.fbe.forgive(free) {
                            self.counters.recovery_spins += 1;
                            self.phase = Phase::Spin(self.config.spin_steps);
                            continue;
                        }
                        return Ok(Decision::Finished);
                    }
                }
                Phase::Look { look_at } => {
                    let a = greedy_action(pose, look_at, threshold);
                    if a != Action::Forward {
                        return Ok(Decision::Act(a));
                    }
                    // Reached: the strikes are counted at the next plan, against the frontiers
                    // seen from here.
                    self.outcome = GoalOutcome::Reached;
                    self.phase = Phase::Idle;
                }
                Phase::Follow {
                    follower,
                    goal,
                    look_at,
                } => {
                    let (goal, look_at) = (*goal, *look_at);
                    let t = Instant::now();
                    let occupied_only = ClearanceMap::new(
                        grid,
                        &ClearanceConfig {
                            unknown_is_blocked: false,
                            ..self.config.clearance
                        },
                    )?;
                    let goal_world = grid.geometry.center(goal);
                    let reason = check_replan(
                        grid,
                        &occupied_only,
                        pose,
                        follower.remaining(),
                        Some(goal_world),
                        &self.config.replan,
                        self.plan_grid.as_ref(),
                    )?;
                    // Progress = the remaining path length shrinking (a detour that first moves
                    // away from the goal is still progress).
                    let mut left = 0.0;
                    let mut prev = here;
                    for w in follower.remaining() {
                        left += (w - prev).norm();
                        prev = *w;
                    }
                    let stuck = self.monitor.observe(left);
                    self.times.triggers += t.elapsed();
                    if stuck {
                        // No progress: something unseen (too close or too low for the camera)
                        // may block the way; put it on the map right ahead of the robot.
                        self.counters.stuck += 1;
                        let ahead = here
                            + nalgebra::Vector2::new(pose.yaw.cos(), pose.yaw.sin())
                                * self.config.bump_obstacle_ahead_m;
                        self.mapper
                            .mark_occupied_disc(ahead, 0.5 * grid.geometry.resolution)?;
                        self.fbe.record(GoalOutcome::Failed, &[], &grid.geometry);
                        self.outcome = GoalOutcome::Abandoned;
                        self.phase = Phase::Idle;
                        continue;
                    }
                    match reason {
                        None => {}
                        Some(ReplanReason::PathDone) => {
                            self.arrive(pose, look_at);
                            continue;
                        }
                        Some(r) => {
                            match r {
                                ReplanReason::PathBlocked { .. } => self.counters.path_blocked += 1,
                                ReplanReason::ObstacleAhead => self.counters.obstacle_ahead += 1,
                                _ => self.counters.goal_occupied += 1,
                            }
                            self.outcome = GoalOutcome::Abandoned;
                            self.phase = Phase::Idle;
                            continue;
                        }
                    }
                    match follower.next_action(pose) {
                        Some(a) => return Ok(Decision::Act(a)),
                        None => self.arrive(pose, look_at),
                    }
                }
            }
        }
        // Still undecided after several phase changes: turn in place to look around.
        Ok(Decision::Act(Action::TurnLeft))
    }

    /// At the goal: turn to the frontier unless it is already in view.
    fn arrive(&mut self, pose: &PlanarPose, look_at: Point2<f64>) {
        let look_yaw = (look_at.y - pose.y).atan2(look_at.x - pose.x);
        if look_turn_needed(pose.yaw, look_yaw, self.config.look_skip_half_angle_rad) {
            self.phase = Phase::Look { look_at };
        } else {
            self.counters.looks_skipped += 1;
            self.outcome = GoalOutcome::Reached;
            self.phase = Phase::Idle;
        }
    }

    /// Chooses a frontier and plans to it; false when no reachable frontier is left.
    fn make_plan(
        &mut self,
        pose: &PlanarPose,
        grid: &OccupancyGrid,
    ) -> Result<bool, PlanningError> {
        let here = Point2::new(pose.x, pose.y);
        let t = Instant::now();
        let map = ClearanceMap::new(grid, &self.config.clearance)?;
        let frontiers = extract_frontiers(grid, &map, here, &self.config.frontier)?;
        self.times.frontiers += t.elapsed();
        let start = grid.geometry.require_cell(here, "robot position")?;
        let outcome = std::mem::replace(&mut self.outcome, GoalOutcome::Abandoned);
        self.fbe.record(outcome, &frontiers.regions, &grid.geometry);
        self.counters.unobservable_goals = self.fbe.unobservable_goals;
        let mut result = false;
        loop {
            let t = Instant::now();
            let Some(choice) = self.fbe.choose(&frontiers.regions, &grid.geometry, pose) else {
                break;
            };
            self.times.frontiers += t.elapsed();
            let t = Instant::now();
            let path = plan(&map, start, choice.cell, &self.config.astar)?;
            let Some(path) = path else {
                self.times.planning += t.elapsed();
                self.counters.unreachable_goals += 1;
                self.fbe
                    .record(GoalOutcome::Failed, &frontiers.regions, &grid.geometry);
                continue;
            };
            let short = shortcut(&map, &path.cells);
            self.times.planning += t.elapsed();
            let waypoints = short[1..]
                .iter()
                .map(|c| grid.geometry.center(*c))
                .collect();
            self.phase = Phase::Follow {
                follower: GreedyFollower::new(self.config.follower, waypoints)?,
                goal: choice.cell,
                look_at: grid
                    .geometry
                    .center(frontiers.regions[choice.region].anchor),
            };
            self.monitor.reset();
            self.plan_grid = Some(grid.clone());
            self.counters.plans += 1;
            result = true;
            break;
        }
        self.frontiers = Some(frontiers);
        Ok(result)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamics::ActionModel;
    use crate::synthetic::SyntheticWorld;
    use activemap_geometry::camera_pose_from_planar;

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
        let model = ActionModel::default();
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
            let dec = ex.step(&pose, &depth, &k, &cam).unwrap();
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
                    placed = Some(ex.counters);
                }
            }
            let next = world.step(&pose, a, &model, 0.05);
            if a == Action::Forward && next == pose {
                bumps += 1;
            }
            pose = next;
        }
        let before = placed.expect("the robot never followed a long enough path");
        let replans = |c: &ExplorerCounters| c.path_blocked + c.obstacle_ahead + c.goal_occupied;
        assert!(
            replans(&ex.counters) > replans(&before),
            "{:?} -> {:?}",
            before,
            ex.counters
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
        let model = ActionModel::default();
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
            match ex.step(&pose, &depth, &k, &cam).unwrap() {
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
                        crate::grid::CellState::Free => '.',
                        crate::grid::CellState::Occupied => '#',
                        crate::grid::CellState::Unknown => ' ',
                    });
                }
                txt.push('\n');
            }
            std::fs::write("/tmp/planning_grid.txt", txt).unwrap();
            for r in &ex.frontiers().unwrap().regions {
                eprintln!(
                    "region size {} first {:?} approach {:?}",
                    r.size(),
                    r.cells[0],
                    r.approach
                );
            }
            eprintln!("strikes {:?}", ex.fbe.strikes());
        }
        eprintln!(
            "finished at {finished_at:?}, coverage {coverage:.3}, blocked forward {blocked_forward}, {:?}",
            ex.counters
        );
        assert!(finished_at.is_some(), "no end within 3000 steps");
        assert!(coverage >= 0.8, "coverage {coverage}");
        assert!(
            blocked_forward < 40,
            "bumped into walls {blocked_forward} times"
        );
    }
}
