//! The path executor: the one state machine that turns a path into one action per step, used
//! by the `follower` operator (what `activemap run` runs) and by the in-process
//! `activemap_policy::explorer::Explorer`. Each step it either acts or asks for a new path:
//!
//! - the episode starts with a look-around of [`ExecutorConfig::initial_spin_steps`] left turns
//!   (72 × 5° = 360°: the camera sees nothing closer than ~0.9 m ahead, so the robot maps its
//!   surroundings before the first plan), then asks ([`ReplanReason::Startup`]);
//! - along a path it follows the waypoints with the greedy rule of SPEC §6
//!   ([`GreedyFollower::next_action_checked`]: a reached waypoint is left early only along a
//!   clear line), and asks for a new path when [`check_replan`] sees an obstacle on the
//!   remaining path, close ahead or at the goal (only obstacles that appeared since the path's
//!   first grid count), when the robot is stuck (no progress along the path over
//!   [`ExecutorConfig::stuck_window`] steps: the goal then counts as failed), and when
//!   [`ExecutorConfig::bumps_to_replan`] forward moves in a row left the (tracked) position
//!   within half a step, as a bumper would notice ([`forward_was_blocked`]); when that happens
//!   [`ExecutorConfig::blocked_replans_to_stuck`] times in a row at one spot (the new paths
//!   keep running into an obstacle the map does not show), it asks as stuck instead, so the
//!   goal counts as failed rather than being asked for again and again;
//! - at the end of the path it turns to face the frontier it came for (the last waypoint's
//!   yaw) unless that bearing is already within [`ExecutorConfig::look_skip_half_angle_rad`]
//!   of the heading, then asks ([`ReplanReason::PathDone`]);
//! - an empty path means the planner found none ([`ReplanReason::NoPath`]);
//! - while tracking is lost it only turns on the spot (no translation on a pose that may be
//!   wrong) and asks for a new path once tracking is back ([`ReplanReason::TrackingLost`]).
//!
//! No transport and no simulator here: the caller feeds the pose and grid of each step and
//! answers a replan request with [`PathExecutor::set_path`] before asking again.

use activemap_geometry::PlanarPose;
use nalgebra::{Point2, Vector2};
use serde::{Deserialize, Serialize};

use crate::clearance::{ClearanceConfig, ClearanceMap};
use crate::dynamics::{Action, RobotModel, forward_was_blocked};
use crate::error::{PlanningError, require};
use crate::follower::{FollowerConfig, GreedyFollower, greedy_action, look_turn_needed};
use crate::grid::OccupancyGrid;
use crate::replan::{ReplanConfig, ReplanReason, check_replan};
use crate::stuck::ProgressMonitor;

/// Replan requests answered within one step before the robot turns left instead: the
/// default of the `follower` operator's `max_replans_per_step` and of the explorer's (a
/// planner that keeps choosing unreachable goals cannot stall a step forever).
pub const MAX_REPLANS_PER_STEP: usize = 6;

/// Every setting of the executor (defaults: what the `follower` operator runs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ExecutorConfig {
    /// The greedy follower (SPEC §6: 5° turn threshold).
    pub follower: FollowerConfig,
    /// The map triggers; its turn threshold must be the follower's.
    pub replan: ReplanConfig,
    /// Steps without progress along the path before the robot counts as stuck (more than
    /// the 36 turns of a half circle, which make no progress).
    pub stuck_window: usize,
    /// Progress (metres of remaining path) that resets the stuck counter.
    pub stuck_min_improvement_m: f64,
    /// Left turns of the look-around at the start of the episode (72 × 5° = 360°); 0 asks
    /// for a path at once.
    pub initial_spin_steps: usize,
    /// At the end of a path the turn toward the frontier is skipped when its bearing is
    /// within this angle of the heading, radians (the camera's half hfov is 45°; 25° keeps
    /// the frontier well inside the view, 40° measured worse on `house:4`). 0 always turns.
    pub look_skip_half_angle_rad: f64,
    /// Forward moves in a row that leave the position within half of the robot's forward
    /// step before the executor asks for a new path ([`ReplanReason::Blocked`]); 0 disables it.
    pub bumps_to_replan: usize,
    /// Blocked replans in a row from within one forward step of the same spot after which the
    /// executor asks as stuck ([`ReplanReason::Stuck`], the goal failed) instead of blocked
    /// (3); 0 never does. Without it, a path through an obstacle the map does not show (seen
    /// on the furnished house at 800×800: 380 steps in place, a blocked replan every 2 steps)
    /// is planned again and again, since each new path resets the stuck window.
    #[serde(default = "default_blocked_replans_to_stuck")]
    pub blocked_replans_to_stuck: usize,
    /// While tracking is lost the robot turns on the spot; once it is back after fewer lost
    /// frames in a row than this, the robot resumes its path (a frame the tracker rejected and
    /// kept at the prediction does not cost a new plan), after as many or more it asks for a
    /// new one ([`ReplanReason::TrackingLost`]). 1 always asks.
    pub lost_replan_after: usize,
    /// Losses of tracking in a row that begin within one forward step of the same spot while a
    /// path is followed, after which the executor asks as stuck ([`ReplanReason::Stuck`], the
    /// goal failed) once tracking is back (3); 0 never does. Without it, a view the tracker
    /// rejects every other frame makes a livelock: lost, the robot turns left; back after one
    /// frame, it resumes its path and turns right into the same view (seen on the README's
    /// main run with discs: 78 steps in place, until the progress monitor's window ran out).
    #[serde(default = "default_lost_flaps_to_stuck")]
    pub lost_flaps_to_stuck: usize,
}

fn default_blocked_replans_to_stuck() -> usize {
    3
}

fn default_lost_flaps_to_stuck() -> usize {
    3
}

/// Counts one more occurrence of a trouble (a blocked replan, a loss of tracking) at `here`:
/// `record` holds where the last one happened and how many in a row happened within `radius`
/// of it. True when this one makes `limit` in a row (the record is then cleared); `limit` 0
/// never is.
fn repeated_at_spot(
    record: &mut Option<(Point2<f64>, usize)>,
    here: Point2<f64>,
    radius: f64,
    limit: usize,
) -> bool {
    let in_row = match *record {
        Some((at, n)) if (at - here).norm() < radius => n + 1,
        _ => 1,
    };
    if limit > 0 && in_row >= limit {
        *record = None;
        true
    } else {
        *record = Some((here, in_row));
        false
    }
}

impl Default for ExecutorConfig {
    fn default() -> Self {
        let follower = FollowerConfig::default();
        Self {
            follower,
            replan: ReplanConfig {
                turn_threshold_rad: follower.turn_threshold_rad,
                ..ReplanConfig::default()
            },
            stuck_window: 40,
            stuck_min_improvement_m: 0.02,
            initial_spin_steps: 72,
            look_skip_half_angle_rad: 25f64.to_radians(),
            bumps_to_replan: 2,
            blocked_replans_to_stuck: default_blocked_replans_to_stuck(),
            lost_replan_after: 3,
            lost_flaps_to_stuck: default_lost_flaps_to_stuck(),
        }
    }
}

impl ExecutorConfig {
    /// Checks the ranges of every field.
    pub fn validate(&self) -> Result<(), PlanningError> {
        self.follower.validate()?;
        self.replan.validate()?;
        require(
            self.replan.turn_threshold_rad == self.follower.turn_threshold_rad,
            "ExecutorConfig::replan.turn_threshold_rad",
            "must equal follower.turn_threshold_rad (the corridor counts when the robot moves)",
        )?;
        require(
            self.look_skip_half_angle_rad.is_finite()
                && (0.0..=std::f64::consts::PI).contains(&self.look_skip_half_angle_rad),
            "ExecutorConfig::look_skip_half_angle_rad",
            "must be in [0, π]",
        )?;
        require(
            self.lost_replan_after >= 1,
            "ExecutorConfig::lost_replan_after",
            "must be ≥ 1 (1 always asks for a new path)",
        )?;
        ProgressMonitor::new(self.stuck_window, self.stuck_min_improvement_m).map(|_| ())
    }
}

/// What the executor wants this step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Decision {
    /// Execute this action.
    Act(Action),
    /// Ask the planner for a new path (answer with [`PathExecutor::set_path`]).
    Replan(ReplanReason),
}

/// Counters of what the executor did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ExecutorCounters {
    /// Paths received (empty ones included).
    pub paths: usize,
    /// Empty paths received (the planner found none).
    pub no_path: usize,
    /// Replans because the map showed an obstacle on or ahead of the path, or at the goal.
    pub obstacle_replans: usize,
    /// Stuck detections.
    pub stuck: usize,
    /// Steps taken while tracking was lost.
    pub lost_steps: usize,
    /// Paths ended without the look turn (the frontier was already in view).
    pub looks_skipped: usize,
    /// Forward moves that did not move the robot.
    pub bumps: usize,
    /// Replans because forward moves kept not moving the robot.
    pub blocked_replans: usize,
}

#[derive(Debug, Clone)]
enum Phase {
    /// Turning left on the spot for this many more steps, then asking for a plan.
    Spin(usize),
    /// Tracking is lost (for `steps` frames so far): turn on the spot until it recovers; then
    /// resume the `interrupted` phase after a short run, or ask for a new plan after a long
    /// one ([`ExecutorConfig::lost_replan_after`]).
    Lost {
        interrupted: Box<Phase>,
        steps: usize,
    },
    /// Waiting for a path.
    Idle(ReplanReason),
    Follow {
        follower: GreedyFollower,
        goal: Point2<f64>,
        look_yaw: f64,
    },
    /// At the end of the path, turning to face `yaw`.
    Look { yaw: f64 },
}

impl Phase {
    /// The phase itself, or while tracking is lost the phase it will resume.
    fn resumable(&self) -> &Phase {
        match self {
            Phase::Lost { interrupted, .. } => interrupted,
            phase => phase,
        }
    }
}

/// The executor's state (see the module doc).
#[derive(Debug, Clone)]
pub struct PathExecutor {
    config: ExecutorConfig,
    /// The robot: its radius (the triggers' swept check) and forward step (the bumper).
    robot: RobotModel,
    monitor: ProgressMonitor,
    phase: Phase,
    /// The grid the current path was planned on (the first grid seen after it arrived): only
    /// obstacles that appeared since then trigger an obstacle-ahead replan.
    plan_grid: Option<OccupancyGrid>,
    /// The occupied-only clearance map of the triggers' checks and the grid it was built from:
    /// rebuilt only when the grid changes (a rollout on one grid, the Fisher scorer's future
    /// poses, would otherwise repeat the distance transform at every step).
    occupied_only: Option<(OccupancyGrid, ClearanceMap)>,
    /// Where the robot was when it last moved forward (cleared by any other decision).
    forward_from: Option<Point2<f64>>,
    /// Forward moves in a row that did not move the robot.
    bumps_in_row: usize,
    /// Where the last blocked replan was asked for, and how many in a row were asked for
    /// within one forward step of it.
    blocked_at: Option<(Point2<f64>, usize)>,
    /// Where the last loss of tracking during a path began, and how many in a row began
    /// within one forward step of it.
    lost_at: Option<(Point2<f64>, usize)>,
    /// What happened so far.
    pub counters: ExecutorCounters,
}

impl PathExecutor {
    /// An executor for `robot` that starts with the look-around (or by asking for a path when
    /// `initial_spin_steps` is 0).
    pub fn new(config: ExecutorConfig, robot: RobotModel) -> Result<Self, PlanningError> {
        config.validate()?;
        robot
            .validate()
            .map_err(|reason| PlanningError::InvalidConfig {
                field: "PathExecutor robot",
                reason,
            })?;
        Ok(Self {
            monitor: ProgressMonitor::new(config.stuck_window, config.stuck_min_improvement_m)?,
            phase: if config.initial_spin_steps > 0 {
                Phase::Spin(config.initial_spin_steps)
            } else {
                Phase::Idle(ReplanReason::Startup)
            },
            config,
            robot,
            plan_grid: None,
            occupied_only: None,
            forward_from: None,
            bumps_in_row: 0,
            blocked_at: None,
            lost_at: None,
            counters: ExecutorCounters::default(),
        })
    }

    /// The settings.
    pub fn config(&self) -> &ExecutorConfig {
        &self.config
    }

    /// Takes the answer to a replan request: waypoints as [`crate::path::PlannedPath`] makes
    /// them (world, the last yaw faces the frontier); an empty slice means no path was found.
    pub fn set_path(&mut self, waypoints: &[PlanarPose]) -> Result<(), PlanningError> {
        self.counters.paths += 1;
        let Some(last) = waypoints.last() else {
            self.counters.no_path += 1;
            self.phase = Phase::Idle(ReplanReason::NoPath);
            return Ok(());
        };
        let points = waypoints.iter().map(|w| Point2::new(w.x, w.y)).collect();
        self.phase = Phase::Follow {
            follower: GreedyFollower::new(self.config.follower, points)?,
            goal: Point2::new(last.x, last.y),
            look_yaw: last.yaw,
        };
        self.plan_grid = None;
        self.monitor.reset();
        Ok(())
    }

    /// The waypoints of the path being followed not reached yet; `None` when no path is
    /// being followed.
    pub fn remaining(&self) -> Option<&[Point2<f64>]> {
        match self.phase.resumable() {
            Phase::Follow { follower, .. } => Some(follower.remaining()),
            _ => None,
        }
    }

    /// The end of the path being followed and the yaw to face there; `None` when no path is
    /// being followed.
    pub fn goal(&self) -> Option<(Point2<f64>, f64)> {
        match self.phase.resumable() {
            Phase::Follow { goal, look_yaw, .. } => Some((*goal, *look_yaw)),
            _ => None,
        }
    }

    /// The decision for the robot at `pose` (tracked, or a prediction when `tracking_lost`)
    /// with the current `grid`. A [`Decision::Replan`] is repeated until a path is set.
    pub fn decide(
        &mut self,
        pose: &PlanarPose,
        grid: &OccupancyGrid,
        tracking_lost: bool,
    ) -> Result<Decision, PlanningError> {
        let decision = self.decide_inner(pose, grid, tracking_lost)?;
        self.forward_from = (decision == Decision::Act(Action::Forward) && !tracking_lost)
            .then_some(Point2::new(pose.x, pose.y));
        Ok(decision)
    }

    /// Counts a forward move that left the robot where it was; true when `bumps_to_replan`
    /// happened in a row.
    fn blocked(&mut self, here: Point2<f64>, tracking_lost: bool) -> bool {
        let Some(from) = self.forward_from.filter(|_| !tracking_lost) else {
            self.bumps_in_row = 0;
            return false;
        };
        if !forward_was_blocked(from, here, self.robot.forward_step_m) {
            self.bumps_in_row = 0;
            return false;
        }
        self.counters.bumps += 1;
        self.bumps_in_row += 1;
        if self.config.bumps_to_replan > 0 && self.bumps_in_row >= self.config.bumps_to_replan {
            self.bumps_in_row = 0;
            return true;
        }
        false
    }

    fn decide_inner(
        &mut self,
        pose: &PlanarPose,
        grid: &OccupancyGrid,
        tracking_lost: bool,
    ) -> Result<Decision, PlanningError> {
        let here = Point2::new(pose.x, pose.y);
        if self.blocked(here, tracking_lost) && matches!(self.phase, Phase::Follow { .. }) {
            self.counters.blocked_replans += 1;
            self.phase = if repeated_at_spot(
                &mut self.blocked_at,
                here,
                self.robot.forward_step_m,
                self.config.blocked_replans_to_stuck,
            ) {
                self.counters.stuck += 1;
                Phase::Idle(ReplanReason::Stuck)
            } else {
                Phase::Idle(ReplanReason::Blocked)
            };
        }
        let threshold = self.config.follower.turn_threshold_rad;
        if tracking_lost {
            self.counters.lost_steps += 1;
            match &mut self.phase {
                Phase::Spin(_) => {}
                Phase::Lost { steps, .. } => *steps += 1,
                phase => {
                    let mut interrupted =
                        std::mem::replace(phase, Phase::Idle(ReplanReason::TrackingLost));
                    if matches!(interrupted, Phase::Follow { .. })
                        && repeated_at_spot(
                            &mut self.lost_at,
                            here,
                            self.robot.forward_step_m,
                            self.config.lost_flaps_to_stuck,
                        )
                    {
                        // The path keeps leading into a view the tracker rejects: the goal
                        // failed (asked once tracking is back).
                        self.counters.stuck += 1;
                        interrupted = Phase::Idle(ReplanReason::Stuck);
                    }
                    self.phase = Phase::Lost {
                        interrupted: Box::new(interrupted),
                        steps: 1,
                    };
                }
            }
        } else if let Phase::Lost { interrupted, steps } = &mut self.phase {
            self.phase = if *steps < self.config.lost_replan_after {
                std::mem::replace(
                    interrupted.as_mut(),
                    Phase::Idle(ReplanReason::TrackingLost),
                )
            } else {
                Phase::Idle(ReplanReason::TrackingLost)
            };
        }
        // Up to a few phase changes per step (a finished path hands over to the look turn).
        for _ in 0..4 {
            match &mut self.phase {
                Phase::Spin(left) => {
                    if *left > 0 {
                        *left -= 1;
                        return Ok(Decision::Act(Action::TurnLeft));
                    }
                    self.phase = Phase::Idle(ReplanReason::Startup);
                }
                Phase::Lost { .. } => return Ok(Decision::Act(Action::TurnLeft)),
                Phase::Idle(reason) => return Ok(Decision::Replan(*reason)),
                Phase::Look { yaw } => {
                    let target = here + Vector2::new(yaw.cos(), yaw.sin());
                    let a = greedy_action(pose, &target, threshold);
                    if a != Action::Forward {
                        return Ok(Decision::Act(a));
                    }
                    self.phase = Phase::Idle(ReplanReason::PathDone);
                }
                Phase::Follow {
                    follower,
                    goal,
                    look_yaw,
                } => {
                    if self.occupied_only.as_ref().is_none_or(|(g, _)| g != grid) {
                        let map = ClearanceMap::new(
                            grid,
                            &ClearanceConfig {
                                unknown_is_blocked: false,
                                ..ClearanceConfig::for_disc(
                                    self.robot.radius_m,
                                    grid.geometry.resolution,
                                )?
                            },
                        )?;
                        self.occupied_only = Some((grid.clone(), map));
                    }
                    let occupied_only = &self.occupied_only.as_ref().expect("just built").1;
                    let plan_grid = self.plan_grid.get_or_insert_with(|| grid.clone());
                    let reason = check_replan(
                        grid,
                        occupied_only,
                        pose,
                        follower.remaining(),
                        Some(*goal),
                        &self.config.replan,
                        Some(plan_grid),
                    )?;
                    // Progress = the remaining path shrinking (a detour that first moves away
                    // from the goal is still progress).
                    let mut left = 0.0;
                    let mut previous = here;
                    for w in follower.remaining() {
                        left += (w - previous).norm();
                        previous = *w;
                    }
                    if self.monitor.observe(left) {
                        self.counters.stuck += 1;
                        self.phase = Phase::Idle(ReplanReason::Stuck);
                        continue;
                    }
                    let yaw = *look_yaw;
                    match reason {
                        None => {}
                        Some(ReplanReason::PathDone) => {
                            self.arrive(pose, yaw);
                            continue;
                        }
                        Some(r) => {
                            self.counters.obstacle_replans += 1;
                            self.phase = Phase::Idle(r);
                            continue;
                        }
                    }
                    // Leave a reached waypoint early only along a clear line (the robot's
                    // own margin aside: from inside it no line is clear, so it closes in).
                    let geometry = grid.geometry;
                    let line_is_clear = |a: Point2<f64>, b: Point2<f64>| {
                        occupied_only.segment_is_clear(geometry.cell_of(a), geometry.cell_of(b))
                    };
                    match follower.next_action_checked(pose, line_is_clear) {
                        Some(a) => return Ok(Decision::Act(a)),
                        None => self.arrive(pose, yaw),
                    }
                }
            }
        }
        Ok(Decision::Act(Action::TurnLeft))
    }

    /// At the end of the path: turn to face the frontier (`look_yaw`) unless it is in view.
    fn arrive(&mut self, pose: &PlanarPose, look_yaw: f64) {
        if look_turn_needed(pose.yaw, look_yaw, self.config.look_skip_half_angle_rad) {
            self.phase = Phase::Look { yaw: look_yaw };
        } else {
            self.counters.looks_skipped += 1;
            self.phase = Phase::Idle(ReplanReason::PathDone);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::{CellState, GridGeometry};

    /// Drives a 0.5 m straight path along +x on an all-free grid and returns the actions sent
    /// until the replan request, whose reason must be "path done".
    fn actions_to_the_end(look_yaw: f64, look_skip_deg: f64) -> Vec<Action> {
        let geometry = GridGeometry::new(-2.0, -2.0, 0.05, 80, 80).unwrap();
        let grid = OccupancyGrid::filled(geometry, CellState::Free);
        let mut core = PathExecutor::new(
            ExecutorConfig {
                initial_spin_steps: 0,
                look_skip_half_angle_rad: look_skip_deg.to_radians(),
                ..ExecutorConfig::default()
            },
            RobotModel::default(),
        )
        .unwrap();
        core.set_path(&[
            PlanarPose::new(0.25, 0.0, 0.0),
            PlanarPose::new(0.5, 0.0, look_yaw),
        ])
        .unwrap();
        let model = RobotModel::default();
        let mut pose = PlanarPose::new(0.0, 0.0, 0.0);
        let mut actions = Vec::new();
        for _ in 0..200 {
            match core.decide(&pose, &grid, false).unwrap() {
                Decision::Replan(reason) => {
                    assert_eq!(reason, ReplanReason::PathDone);
                    return actions;
                }
                Decision::Act(a) => {
                    pose = model.apply(&pose, a);
                    actions.push(a);
                }
            }
        }
        panic!("no replan request within 200 steps: {actions:?}");
    }

    /// A wall the grid does not show stops the robot 0.2 m along a 0.5 m path: the tracked pose
    /// stops advancing, and the executor asks for a new path (blocked) at the second forward
    /// move that did not move it, not after the stuck window. Driving freely counts no bump.
    #[test]
    fn forward_moves_that_do_not_move_the_robot_ask_for_a_new_path() {
        let geometry = GridGeometry::new(-2.0, -2.0, 0.05, 80, 80).unwrap();
        let grid = OccupancyGrid::filled(geometry, CellState::Free);
        let model = RobotModel::default();
        let run = |wall_x: f64, bumps_to_replan: usize| {
            let mut core = PathExecutor::new(
                ExecutorConfig {
                    initial_spin_steps: 0,
                    bumps_to_replan,
                    ..ExecutorConfig::default()
                },
                RobotModel::default(),
            )
            .unwrap();
            core.set_path(&[
                PlanarPose::new(0.25, 0.0, 0.0),
                PlanarPose::new(0.5, 0.0, 0.0),
            ])
            .unwrap();
            let mut pose = PlanarPose::new(0.0, 0.0, 0.0);
            let mut forwards = 0;
            for _ in 0..100 {
                match core.decide(&pose, &grid, false).unwrap() {
                    Decision::Replan(reason) => return (reason, forwards, core.counters),
                    Decision::Act(a) => {
                        assert_eq!(a, Action::Forward);
                        forwards += 1;
                        let next = model.apply(&pose, Action::Forward);
                        if next.x <= wall_x + 1e-9 {
                            pose = next;
                        }
                    }
                }
            }
            panic!("no replan request within 100 steps");
        };
        // Free: 9 forward moves to within the waypoint tolerance of the end, no bump.
        let (reason, forwards, counters) = run(10.0, 2);
        assert_eq!(
            (reason, forwards, counters.bumps),
            (ReplanReason::PathDone, 9, 0)
        );
        // Blocked at 0.2 m: 4 moves get there, the 5th and 6th do not move it.
        let (reason, forwards, counters) = run(0.2, 2);
        assert_eq!(reason, ReplanReason::Blocked);
        assert_eq!(forwards, 6);
        assert_eq!((counters.bumps, counters.blocked_replans), (2, 1));
        // Disabled: only the stuck window (40 steps without progress) ends it.
        let (reason, forwards, counters) = run(0.2, 0);
        assert_eq!(reason, ReplanReason::Stuck);
        assert!(forwards > 40, "{forwards}");
        assert_eq!(counters.blocked_replans, 0);
    }

    /// A free 4 m × 4 m grid around the origin, the default robot and a straight path along +x
    /// from x = 0.25 to 1.5 m (the robot starts at the origin facing +x).
    fn open_floor_and_straight_path() -> (OccupancyGrid, RobotModel, [PlanarPose; 2]) {
        let geometry = GridGeometry::new(-2.0, -2.0, 0.05, 80, 80).unwrap();
        (
            OccupancyGrid::filled(geometry, CellState::Free),
            RobotModel::default(),
            [
                PlanarPose::new(0.25, 0.0, 0.0),
                PlanarPose::new(1.5, 0.0, 0.0),
            ],
        )
    }

    /// The same path into a wall the grid does not show, given again after each blocked
    /// replan: the first two replans are blocked, the third, still at the wall, is stuck (the
    /// goal failed). Blocked replans at different spots do not add up; 0 disables it.
    #[test]
    fn blocked_again_and_again_at_one_spot_counts_as_stuck() {
        let (grid, model, path) = open_floor_and_straight_path();
        // Replan reasons of `replans` requests, the path given again from wherever the robot
        // is; the wall at `wall_x` moves `shift` metres after each request.
        let run = |limit: usize, replans: usize, shift: f64| {
            let mut core = PathExecutor::new(
                ExecutorConfig {
                    initial_spin_steps: 0,
                    blocked_replans_to_stuck: limit,
                    ..ExecutorConfig::default()
                },
                model,
            )
            .unwrap();
            let mut pose = PlanarPose::new(0.0, 0.0, 0.0);
            let mut wall_x = 0.2;
            let mut reasons = Vec::new();
            core.set_path(&path).unwrap();
            for _ in 0..1000 {
                match core.decide(&pose, &grid, false).unwrap() {
                    Decision::Replan(reason) => {
                        reasons.push(reason);
                        if reasons.len() == replans {
                            return (reasons, core.counters);
                        }
                        wall_x += shift;
                        core.set_path(&path).unwrap();
                    }
                    Decision::Act(a) => {
                        let next = model.apply(&pose, a);
                        if next.x <= wall_x + 1e-9 {
                            pose = next;
                        }
                    }
                }
            }
            panic!("{reasons:?}");
        };
        let (reasons, counters) = run(3, 4, 0.0);
        use ReplanReason::{Blocked, Stuck};
        assert_eq!(reasons, [Blocked, Blocked, Stuck, Blocked]);
        assert_eq!((counters.blocked_replans, counters.stuck), (4, 1));
        // The wall gives way by 0.3 m each time: progress, never stuck.
        let (reasons, _) = run(3, 4, 0.3);
        assert_eq!(reasons, [Blocked; 4]);
        let (reasons, counters) = run(0, 4, 0.0);
        assert_eq!(reasons, [Blocked; 4]);
        assert_eq!(counters.stuck, 0);
    }

    /// Tracking lost every other frame at one spot of a path (the tracker rejects the view the
    /// path faces): lost, the robot turns left; back, it resumes the path and turns right into
    /// the same view. The third loss there makes the executor ask as stuck once tracking is
    /// back, instead of turning back and forth until the progress window runs out. Losses at
    /// spots a few steps apart do not add up; 0 disables the rule.
    #[test]
    fn tracking_lost_again_and_again_at_one_spot_counts_as_stuck() {
        let (grid, model, path) = open_floor_and_straight_path();
        // Tracking is lost whenever `lost(step, pose)` says so; returns the first replan
        // reason, the step it came at and the counters.
        let run = |limit: usize, lost: &dyn Fn(usize, &PlanarPose) -> bool| {
            let mut core = PathExecutor::new(
                ExecutorConfig {
                    initial_spin_steps: 0,
                    lost_flaps_to_stuck: limit,
                    ..ExecutorConfig::default()
                },
                model,
            )
            .unwrap();
            core.set_path(&path).unwrap();
            let mut pose = PlanarPose::new(0.0, 0.0, 0.0);
            for step in 0..200 {
                match core.decide(&pose, &grid, lost(step, &pose)).unwrap() {
                    Decision::Replan(reason) => return (reason, step, core.counters),
                    Decision::Act(a) => pose = model.apply(&pose, a),
                }
            }
            panic!("no replan in 200 steps");
        };
        // The view along the path (yaw within 2° of 0) is rejected once the robot is past
        // x = 0.3.
        let flapping = |_: usize, p: &PlanarPose| p.x > 0.3 && p.yaw.abs() < 2f64.to_radians();
        let (reason, step, counters) = run(3, &flapping);
        assert_eq!(reason, ReplanReason::Stuck);
        assert!(step < 20, "asked at step {step}");
        assert_eq!(counters.stuck, 1);
        // Without the rule the robot turns back and forth until the progress window runs out.
        let (reason, step, _) = run(0, &flapping);
        assert_eq!(reason, ReplanReason::Stuck);
        assert!(step > 40, "asked at step {step}");
        // One-frame losses every 4th step while the robot moves on: 3 forward steps apart,
        // never the same spot; it reaches the end of the path.
        let moving = |step: usize, _: &PlanarPose| step % 4 == 3;
        let (reason, _, counters) = run(3, &moving);
        assert_eq!(reason, ReplanReason::PathDone);
        assert_eq!(counters.stuck, 0);
    }

    /// At the end of the path the executor turns to the frontier only when it is out of view:
    /// a frontier 20° to the left is already seen (no turn); one behind (180°) costs about 36
    /// turns of 5°; with the skip disabled, the 32° turn is made (6 turns: 2° left, within the
    /// 5° threshold).
    #[test]
    fn the_look_turn_is_skipped_when_the_frontier_is_in_view() {
        let count = |actions: &[Action]| {
            actions
                .iter()
                .filter(|a| matches!(a, Action::TurnLeft | Action::TurnRight))
                .count()
        };
        let in_view = actions_to_the_end(20f64.to_radians(), 25.0);
        assert_eq!(count(&in_view), 0, "{in_view:?}");
        assert!(in_view.iter().all(|a| *a == Action::Forward));
        let behind = actions_to_the_end(std::f64::consts::PI, 25.0);
        assert!(count(&behind) >= 35, "{behind:?}");
        let always = actions_to_the_end(32f64.to_radians(), 0.0);
        assert_eq!(count(&always), 6, "{always:?}");
    }

    /// The start-up look-around is `initial_spin_steps` left turns, then a start-up request
    /// that repeats until a path comes; an empty path asks again (no path); while tracking is
    /// lost the robot only turns; once tracking is back it resumes its path after a short run
    /// of lost frames and asks for a new one after a long run.
    #[test]
    fn spin_then_startup_request_no_path_and_lost_tracking() {
        let geometry = GridGeometry::new(-2.0, -2.0, 0.05, 80, 80).unwrap();
        let grid = OccupancyGrid::filled(geometry, CellState::Free);
        let mut core = PathExecutor::new(
            ExecutorConfig {
                initial_spin_steps: 3,
                ..ExecutorConfig::default()
            },
            RobotModel::default(),
        )
        .unwrap();
        let pose = PlanarPose::new(0.0, 0.0, 0.0);
        for _ in 0..3 {
            assert_eq!(
                core.decide(&pose, &grid, false).unwrap(),
                Decision::Act(Action::TurnLeft)
            );
        }
        for _ in 0..2 {
            assert_eq!(
                core.decide(&pose, &grid, false).unwrap(),
                Decision::Replan(ReplanReason::Startup)
            );
        }
        core.set_path(&[]).unwrap();
        assert_eq!(
            core.decide(&pose, &grid, false).unwrap(),
            Decision::Replan(ReplanReason::NoPath)
        );
        core.set_path(&[PlanarPose::new(1.0, 0.0, 0.0)]).unwrap();
        assert_eq!(
            core.decide(&pose, &grid, false).unwrap(),
            Decision::Act(Action::Forward)
        );
        // Two lost frames (fewer than `lost_replan_after`): turns, then the path goes on.
        for _ in 0..2 {
            assert_eq!(
                core.decide(&pose, &grid, true).unwrap(),
                Decision::Act(Action::TurnLeft)
            );
        }
        assert_eq!(core.remaining().map(|r| r.len()), Some(1));
        let turned = PlanarPose::new(0.0, 0.0, 10f64.to_radians());
        assert_eq!(
            core.decide(&turned, &grid, false).unwrap(),
            Decision::Act(Action::TurnRight)
        );
        // Three: turns, then a new plan.
        for _ in 0..3 {
            assert_eq!(
                core.decide(&pose, &grid, true).unwrap(),
                Decision::Act(Action::TurnLeft)
            );
        }
        assert_eq!(
            core.decide(&pose, &grid, false).unwrap(),
            Decision::Replan(ReplanReason::TrackingLost)
        );
        assert_eq!(core.remaining(), None);
        assert_eq!(
            (
                core.counters.paths,
                core.counters.no_path,
                core.counters.lost_steps
            ),
            (2, 1, 5)
        );
    }

    /// An obstacle the map shows on the remaining path asks for a new path with the trigger's
    /// own reason; one that was already on the path's first grid does not.
    #[test]
    fn an_obstacle_new_on_the_path_asks_for_a_new_path() {
        let geometry = GridGeometry::new(-2.0, -2.0, 0.05, 80, 80).unwrap();
        let mut grid = OccupancyGrid::filled(geometry, CellState::Free);
        let mut core = PathExecutor::new(
            ExecutorConfig {
                initial_spin_steps: 0,
                ..ExecutorConfig::default()
            },
            RobotModel::default(),
        )
        .unwrap();
        core.set_path(&[PlanarPose::new(1.5, 0.0, 0.0)]).unwrap();
        let pose = PlanarPose::new(0.0, 0.0, 0.0);
        assert_eq!(
            core.decide(&pose, &grid, false).unwrap(),
            Decision::Act(Action::Forward)
        );
        grid.set(geometry.cell_of(Point2::new(0.8, 0.0)), CellState::Occupied);
        let d = core.decide(&pose, &grid, false).unwrap();
        let Decision::Replan(reason) = d else {
            panic!("{d:?}")
        };
        assert!(reason.is_obstacle(), "{reason:?}");
        assert_eq!(core.counters.obstacle_replans, 1);
        assert!(
            ExecutorConfig {
                look_skip_half_angle_rad: -1.0,
                ..ExecutorConfig::default()
            }
            .validate()
            .is_err()
        );
    }
}
