//! `follower`: executes the scorer's path with the greedy rule of SPEC §6 and emits exactly
//! one action per step. It asks the planner for a new goal when the path is done (after
//! turning to face the frontier it came for, unless the frontier is already in view), when the map shows an obstacle on the remaining
//! path or close ahead, when the goal turns occupied, when no path was found, and when the
//! robot is stuck (no progress along the path over `stuck_window` steps: the goal then counts
//! as failed). It also notices a blocked robot at once, as a bumper would: when
//! `bumps_to_replan` forward moves in a row leave the tracked position within half a step of
//! where it was, something is in the way (an obstacle the map does not show, or a corner of
//! one the robot grazes after cutting toward its next waypoint), and it asks for a new path. Wraps `activemap_planning::{follower, replan, stuck}`. The episode starts with a
//! 360° look-around; while the tracker reports the pose lost the robot only turns on the spot,
//! and asks for a new plan once tracking is back. When the planner ends the episode (its goal
//! stream, hence the path stream, closes) it sends `Stop`.

use activemap_geometry::PlanarPose;
use activemap_geometry::frames::planar_from_camera_pose;
use activemap_planning::OccupancyGrid as PlanGrid;
use activemap_planning::clearance::{ClearanceConfig, ClearanceMap};
use activemap_planning::dynamics::Action as PlanAction;
use activemap_planning::follower::{
    FollowerConfig, GreedyFollower, greedy_action, look_turn_needed,
};
use activemap_planning::replan::{ReplanConfig, ReplanReason as PlanReason, check_replan};
use activemap_planning::stuck::ProgressMonitor;
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, PortSpec, check_config_as,
};
use activemap_schemas::{
    Action, ActionKind, MessageKind as K, Path, PoseEstimate, ReplanReason, ReplanRequest,
    TrackingStatus,
};
use nalgebra::Point2;

use crate::Registered;
use crate::convert::{pose_from_wire, read_grid, robot_clearance};
use crate::join::FrameJoin;

/// Config.
#[derive(Debug, Clone, Copy, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// Steps without progress before the robot counts as stuck.
    #[serde(default = "default_window")]
    pub stuck_window: usize,
    /// Progress (metres of remaining path) that resets the stuck counter.
    #[serde(default = "default_improvement")]
    pub stuck_min_improvement: f64,
    /// Replan requests allowed within one step before the follower turns in place instead.
    #[serde(default = "default_replans")]
    pub max_replans_per_step: usize,
    /// Turns of the look-around at the start of the episode (72 × 5° = 360°): the camera
    /// sees nothing closer than ~0.9 m ahead, so the robot maps its surroundings before the
    /// first plan. 0 disables it.
    #[serde(default = "default_spin")]
    pub initial_spin_steps: usize,
    /// At the end of a path, the turn toward the frontier is skipped when it is already within
    /// this many degrees of the heading (the camera's half hfov is 45°; 25° keeps it well in
    /// view, as the in-process explorer's default). 0 always turns.
    #[serde(default = "default_look_skip")]
    pub look_skip_half_angle_deg: f64,
    /// Forward moves in a row that leave the tracked position within half of
    /// `forward_step_m` before the follower replans (see the module doc). 0 disables it.
    #[serde(default = "default_bumps")]
    pub bumps_to_replan: usize,
    /// Length of a forward step, metres (SPEC §1: 0.05).
    #[serde(default = "default_forward_step")]
    pub forward_step_m: f64,
}

fn default_window() -> usize {
    40
}
fn default_improvement() -> f64 {
    0.02
}
fn default_replans() -> usize {
    6
}
fn default_spin() -> usize {
    72
}
fn default_look_skip() -> f64 {
    25.0
}
fn default_bumps() -> usize {
    2
}
fn default_forward_step() -> f64 {
    activemap_planning::dynamics::ActionModel::default().forward_m
}

impl Default for Config {
    fn default() -> Self {
        Self {
            stuck_window: default_window(),
            stuck_min_improvement: default_improvement(),
            max_replans_per_step: default_replans(),
            initial_spin_steps: default_spin(),
            look_skip_half_angle_deg: default_look_skip(),
            bumps_to_replan: default_bumps(),
            forward_step_m: default_forward_step(),
        }
    }
}

/// What the follower wants this step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Decision {
    /// Send this action.
    Act(ActionKind),
    /// Ask the planner for a new goal.
    Replan(ReplanReason),
}

enum Phase {
    /// Turning left on the spot for this many more steps, then asking for a plan.
    Spin(usize),
    /// Tracking is lost: turn on the spot (no translation, so no collision on a wrong pose)
    /// until it recovers, then ask for a new plan.
    Lost,
    Idle(ReplanReason),
    Follow {
        follower: GreedyFollower,
        goal: Point2<f64>,
        look_yaw: f64,
    },
    Look {
        yaw: f64,
    },
}

/// Counters of what the follower did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    /// Paths received.
    pub paths: usize,
    /// Replans because the map showed an obstacle on or ahead of the path, or at the goal.
    pub obstacle_replans: usize,
    /// Stuck detections.
    pub stuck: usize,
    /// Empty paths received.
    pub no_path: usize,
    /// Steps taken while tracking was lost.
    pub lost_steps: usize,
    /// Paths ended without the look turn (the frontier was already in view).
    pub looks_skipped: usize,
    /// Forward moves that did not move the robot.
    pub bumps: usize,
    /// Replans because forward moves kept not moving the robot.
    pub blocked_replans: usize,
}

/// The follower's state machine, without transport.
pub struct FollowerCore {
    config: FollowerConfig,
    replan: ReplanConfig,
    monitor: ProgressMonitor,
    phase: Phase,
    /// Skip the look turn within this angle of the heading, radians.
    look_skip_half_angle: f64,
    /// The grid the current path was planned on (the first grid seen after it arrived): only
    /// obstacles that appeared since then trigger an obstacle-ahead replan.
    plan_grid: Option<PlanGrid>,
    /// Where the robot was when it last moved forward (cleared by any other decision).
    forward_from: Option<Point2<f64>>,
    /// Forward moves in a row that did not move the robot.
    bumps_in_row: usize,
    bumps_to_replan: usize,
    forward_step_m: f64,
    /// What happened so far.
    pub counters: Counters,
}

fn to_kind(a: PlanAction) -> ActionKind {
    match a {
        PlanAction::Forward => ActionKind::Forward,
        PlanAction::TurnLeft => ActionKind::TurnLeft,
        PlanAction::TurnRight => ActionKind::TurnRight,
    }
}

impl FollowerCore {
    /// A follower that starts by asking for a plan.
    pub fn new(config: &Config) -> anyhow::Result<Self> {
        let follower = FollowerConfig::default();
        anyhow::ensure!(
            config.look_skip_half_angle_deg.is_finite()
                && (0.0..=180.0).contains(&config.look_skip_half_angle_deg),
            "follower: look_skip_half_angle_deg must be in [0, 180], got {}",
            config.look_skip_half_angle_deg
        );
        anyhow::ensure!(
            config.forward_step_m.is_finite() && config.forward_step_m > 0.0,
            "follower: forward_step_m must be finite and positive, got {}",
            config.forward_step_m
        );
        Ok(Self {
            forward_from: None,
            bumps_in_row: 0,
            bumps_to_replan: config.bumps_to_replan,
            forward_step_m: config.forward_step_m,
            look_skip_half_angle: config.look_skip_half_angle_deg.to_radians(),
            config: follower,
            replan: ReplanConfig {
                turn_threshold_rad: follower.turn_threshold_rad,
                ..ReplanConfig::default()
            },
            plan_grid: None,
            monitor: ProgressMonitor::new(config.stuck_window, config.stuck_min_improvement)?,
            phase: if config.initial_spin_steps > 0 {
                Phase::Spin(config.initial_spin_steps)
            } else {
                Phase::Idle(ReplanReason::Startup)
            },
            counters: Counters::default(),
        })
    }

    /// Takes a new path (an empty one means the scorer found none).
    pub fn set_path(&mut self, path: &Path) -> anyhow::Result<()> {
        self.counters.paths += 1;
        let Some(last) = path.waypoints.last() else {
            self.counters.no_path += 1;
            self.phase = Phase::Idle(ReplanReason::NoPath);
            return Ok(());
        };
        let points = path
            .waypoints
            .iter()
            .map(|w| Point2::new(w.x, w.y))
            .collect();
        self.phase = Phase::Follow {
            follower: GreedyFollower::new(self.config, points)?,
            goal: Point2::new(last.x, last.y),
            look_yaw: last.yaw,
        };
        self.plan_grid = None;
        self.monitor.reset();
        Ok(())
    }

    /// The decision for the robot at `pose` (tracked, or a prediction when `tracking_lost`)
    /// with the current `grid`.
    pub fn decide(
        &mut self,
        pose: &PlanarPose,
        grid: &PlanGrid,
        tracking_lost: bool,
    ) -> anyhow::Result<Decision> {
        let decision = self.decide_inner(pose, grid, tracking_lost)?;
        self.forward_from = (decision == Decision::Act(ActionKind::Forward) && !tracking_lost)
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
        if !activemap_planning::dynamics::forward_was_blocked(from, here, self.forward_step_m) {
            self.bumps_in_row = 0;
            return false;
        }
        self.counters.bumps += 1;
        self.bumps_in_row += 1;
        if self.bumps_to_replan > 0 && self.bumps_in_row >= self.bumps_to_replan {
            self.bumps_in_row = 0;
            return true;
        }
        false
    }

    fn decide_inner(
        &mut self,
        pose: &PlanarPose,
        grid: &PlanGrid,
        tracking_lost: bool,
    ) -> anyhow::Result<Decision> {
        let here = Point2::new(pose.x, pose.y);
        if self.blocked(here, tracking_lost) && matches!(self.phase, Phase::Follow { .. }) {
            self.counters.blocked_replans += 1;
            self.phase = Phase::Idle(ReplanReason::Blocked);
        }
        let threshold = self.config.turn_threshold_rad;
        if tracking_lost {
            self.counters.lost_steps += 1;
            if !matches!(self.phase, Phase::Spin(_)) {
                self.phase = Phase::Lost;
            }
        } else if matches!(self.phase, Phase::Lost) {
            self.phase = Phase::Idle(ReplanReason::TrackingLost);
        }
        for _ in 0..4 {
            match &mut self.phase {
                Phase::Spin(left) => {
                    if *left > 0 {
                        *left -= 1;
                        return Ok(Decision::Act(ActionKind::TurnLeft));
                    }
                    self.phase = Phase::Idle(ReplanReason::Startup);
                }
                Phase::Lost => return Ok(Decision::Act(ActionKind::TurnLeft)),
                Phase::Idle(reason) => return Ok(Decision::Replan(*reason)),
                Phase::Look { yaw } => {
                    let target = here + nalgebra::Vector2::new(yaw.cos(), yaw.sin());
                    let a = greedy_action(pose, &target, threshold);
                    if a != PlanAction::Forward {
                        return Ok(Decision::Act(to_kind(a)));
                    }
                    self.phase = Phase::Idle(ReplanReason::PathDone);
                }
                Phase::Follow {
                    follower,
                    goal,
                    look_yaw,
                } => {
                    let occupied_only = ClearanceMap::new(
                        grid,
                        &ClearanceConfig {
                            unknown_is_blocked: false,
                            ..robot_clearance(grid.geometry.resolution)?
                        },
                    )?;
                    let plan_grid = self.plan_grid.get_or_insert_with(|| grid.clone());
                    let reason = check_replan(
                        grid,
                        &occupied_only,
                        pose,
                        follower.remaining(),
                        Some(*goal),
                        &self.replan,
                        Some(plan_grid),
                    )?;
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
                        Some(PlanReason::PathDone) => {
                            self.arrive(pose, yaw);
                            continue;
                        }
                        Some(_) => {
                            self.counters.obstacle_replans += 1;
                            self.phase = Phase::Idle(ReplanReason::ObstacleAhead);
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
                        Some(a) => return Ok(Decision::Act(to_kind(a))),
                        None => self.arrive(pose, yaw),
                    }
                }
            }
        }
        Ok(Decision::Act(ActionKind::TurnLeft))
    }

    /// At the end of the path: turn to face the frontier (`look_yaw`) unless it is in view.
    fn arrive(&mut self, pose: &PlanarPose, look_yaw: f64) {
        if look_turn_needed(pose.yaw, look_yaw, self.look_skip_half_angle) {
            self.phase = Phase::Look { yaw: look_yaw };
        } else {
            self.counters.looks_skipped += 1;
            self.phase = Phase::Idle(ReplanReason::PathDone);
        }
    }
}

/// The inputs of one step.
#[derive(Default)]
struct Slot {
    grid: Option<PlanGrid>,
    pose: Option<(PlanarPose, bool)>,
}

/// The operator.
pub struct Follower {
    core: FollowerCore,
    max_replans: usize,
    step: u64,
    replans_this_step: usize,
    awaiting_path: bool,
    join: FrameJoin<Slot>,
    paths: Vec<Path>,
}

impl Follower {
    /// Runs the current step as far as the inputs allow.
    fn run(&mut self, ctx: &mut Context<'_>) -> anyhow::Result<()> {
        loop {
            let k = self.step;
            let Some(Slot {
                grid: Some(grid),
                pose: Some((pose, lost)),
            }) = self.join.get(k)
            else {
                return Ok(());
            };
            if self.awaiting_path {
                let Some(i) = self.paths.iter().position(|p| p.frame_id == k) else {
                    return Ok(());
                };
                let path = self.paths.remove(i);
                self.core.set_path(&path)?;
                self.awaiting_path = false;
            }
            let action = match self.core.decide(pose, grid, *lost)? {
                Decision::Act(a) => a,
                Decision::Replan(reason) if self.replans_this_step < self.max_replans => {
                    self.replans_this_step += 1;
                    self.awaiting_path = true;
                    ctx.send(
                        "replan",
                        &ReplanRequest {
                            frame_id: k,
                            reason,
                        },
                    )?;
                    continue;
                }
                Decision::Replan(_) => ActionKind::TurnLeft,
            };
            ctx.send("action", &Action { step: k, action })?;
            self.join.take(k);
            self.step += 1;
            self.replans_this_step = 0;
        }
    }
}

impl Operator for Follower {
    type Config = Config;

    fn new(config: Config, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        anyhow::ensure!(
            config.max_replans_per_step >= 1,
            "follower: max_replans_per_step must be ≥ 1"
        );
        Ok(Self {
            core: FollowerCore::new(&config)?,
            max_replans: config.max_replans_per_step,
            step: 0,
            replans_this_step: 0,
            awaiting_path: false,
            join: FrameJoin::new(),
            paths: Vec::new(),
        })
    }

    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        match event {
            Event::Input(input) => match input.port {
                "grid" => {
                    let (k, g) = read_grid(input.bytes)?;
                    self.join.slot(k).grid = Some(g);
                }
                "pose" => {
                    let e: PoseEstimate = input.decode()?;
                    let pose = planar_from_camera_pose(&pose_from_wire(&e.t_world_camera)?);
                    self.join.slot(e.frame_id).pose =
                        Some((pose, e.status == TrackingStatus::Lost));
                }
                "path" => self.paths.push(input.decode()?),
                other => anyhow::bail!("follower: unexpected input `{other}`"),
            },
            Event::InputClosed { port: "path" } => {
                // The planner ended the episode: no reachable frontier is left.
                ctx.send(
                    "action",
                    &Action {
                        step: self.step,
                        action: ActionKind::Stop,
                    },
                )?;
                return Ok(Flow::Stop);
            }
            Event::InputClosed { port: "pose" } => return Ok(Flow::Stop),
            _ => return Ok(Flow::Continue),
        }
        self.run(ctx)?;
        Ok(Flow::Continue)
    }
}

/// Registry entry.
pub fn registered() -> Registered {
    const INPUTS: &[PortSpec] = &[
        PortSpec {
            name: "path",
            kind: K::Path,
        },
        PortSpec {
            name: "pose",
            kind: K::PoseEstimate,
        },
        PortSpec {
            name: "grid",
            kind: K::OccupancyGrid,
        },
    ];
    const OUTPUTS: &[PortSpec] = &[
        PortSpec {
            name: "action",
            kind: K::Action,
        },
        PortSpec {
            name: "replan",
            kind: K::ReplanRequest,
        },
    ];
    Registered {
        descriptor: OperatorDescriptor {
            name: "follower",
            summary: "Greedy path follower: one action per step, replan requests, stuck recovery (SPEC §6)",
            inputs: INPUTS,
            outputs: OUTPUTS,
            evaluation: false,
            check_config: check_config_as::<Config>,
        },
        implementation: Some(OperatorImpl::of::<Follower>()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_planning::frontier::path_distances;
    use activemap_planning::occupancy::{OccupancyConfig, OccupancyMapper};
    use activemap_sim::{
        Action as SimAction, Material, Scene, SimConfig, Simulator, Triangle, Vertex,
    };

    /// Drives a 0.5 m straight path along +x on an all-free grid and returns the actions sent
    /// until the replan request, whose reason must be "path done".
    fn actions_to_the_end(look_yaw: f64, look_skip_deg: f64) -> Vec<ActionKind> {
        let geometry = activemap_planning::GridGeometry::new(-2.0, -2.0, 0.05, 80, 80).unwrap();
        let grid = PlanGrid::filled(geometry, activemap_planning::CellState::Free);
        let mut core = FollowerCore::new(&Config {
            initial_spin_steps: 0,
            look_skip_half_angle_deg: look_skip_deg,
            ..Config::default()
        })
        .unwrap();
        let waypoint = |x, yaw| activemap_schemas::PlanarPose2 { x, y: 0.0, yaw };
        core.set_path(&Path {
            frame_id: 0,
            waypoints: vec![waypoint(0.25, 0.0), waypoint(0.5, look_yaw)],
            objective: 0.0,
        })
        .unwrap();
        let model = activemap_planning::dynamics::ActionModel::default();
        let mut pose = PlanarPose::new(0.0, 0.0, 0.0);
        let mut actions = Vec::new();
        for _ in 0..200 {
            match core.decide(&pose, &grid, false).unwrap() {
                Decision::Replan(reason) => {
                    assert_eq!(reason, ReplanReason::PathDone);
                    return actions;
                }
                Decision::Act(kind) => {
                    let a = match kind {
                        ActionKind::Forward => PlanAction::Forward,
                        ActionKind::TurnLeft => PlanAction::TurnLeft,
                        _ => PlanAction::TurnRight,
                    };
                    pose = model.apply(&pose, a);
                    actions.push(kind);
                }
            }
        }
        panic!("no replan request within 200 steps: {actions:?}");
    }

    /// A wall the grid does not show stops the robot 0.2 m along a 0.5 m path: the tracked pose
    /// stops advancing, and the follower asks for a new path (blocked) at the second forward
    /// move that did not move it, not after the stuck window. Driving freely counts no bump.
    #[test]
    fn forward_moves_that_do_not_move_the_robot_ask_for_a_new_path() {
        let geometry = activemap_planning::GridGeometry::new(-2.0, -2.0, 0.05, 80, 80).unwrap();
        let grid = PlanGrid::filled(geometry, activemap_planning::CellState::Free);
        let model = activemap_planning::dynamics::ActionModel::default();
        let run = |wall_x: f64, bumps_to_replan: usize| {
            let mut core = FollowerCore::new(&Config {
                initial_spin_steps: 0,
                bumps_to_replan,
                ..Config::default()
            })
            .unwrap();
            let waypoint = |x| activemap_schemas::PlanarPose2 {
                x,
                y: 0.0,
                yaw: 0.0,
            };
            core.set_path(&Path {
                frame_id: 0,
                waypoints: vec![waypoint(0.25), waypoint(0.5)],
                objective: 0.0,
            })
            .unwrap();
            let mut pose = PlanarPose::new(0.0, 0.0, 0.0);
            let mut forwards = 0;
            for _ in 0..100 {
                match core.decide(&pose, &grid, false).unwrap() {
                    Decision::Replan(reason) => return (reason, forwards, core.counters),
                    Decision::Act(kind) => {
                        assert_eq!(kind, ActionKind::Forward);
                        forwards += 1;
                        let next = model.apply(&pose, PlanAction::Forward);
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

    /// At the end of the path the follower turns to the frontier only when it is out of view:
    /// a frontier 20° to the left is already seen (no turn); one behind (180°) costs about 36
    /// turns of 5°; with the skip disabled, the 32° turn is made (6 turns: 2° left, within the
    /// 5° threshold).
    #[test]
    fn the_look_turn_is_skipped_when_the_frontier_is_in_view() {
        let count = |actions: &[ActionKind]| {
            actions
                .iter()
                .filter(|a| matches!(a, ActionKind::TurnLeft | ActionKind::TurnRight))
                .count()
        };
        let in_view = actions_to_the_end(20f64.to_radians(), 25.0);
        assert_eq!(count(&in_view), 0, "{in_view:?}");
        assert!(in_view.iter().all(|a| *a == ActionKind::Forward));
        let behind = actions_to_the_end(std::f64::consts::PI, 25.0);
        assert!(count(&behind) >= 35, "{behind:?}");
        let always = actions_to_the_end(32f64.to_radians(), 0.0);
        assert_eq!(count(&always), 6, "{always:?}");
    }

    /// Adds a closed box [lo, hi] (world metres) to `scene` in one flat colour.
    fn add_box(scene: &mut Scene, lo: [f32; 3], hi: [f32; 3]) {
        scene.materials.push(Material {
            name: "obstacle".into(),
            base_color: [0.8, 0.2, 0.1],
            texture: None,
        });
        let material = (scene.materials.len() - 1) as u32;
        let base = scene.vertices.len() as u32;
        for i in 0..8u32 {
            let pick = |bit: u32, a: usize| if i & bit == 0 { lo[a] } else { hi[a] };
            scene.vertices.push(Vertex {
                position: [pick(1, 0), pick(2, 1), pick(4, 2)],
                uv: [0.0, 0.0],
                color: [1.0; 3],
            });
        }
        // Corner index = x + 2y + 4z; two triangles per face.
        let faces = [
            [0, 2, 6, 4],
            [1, 3, 7, 5],
            [0, 1, 5, 4],
            [2, 3, 7, 6],
            [0, 1, 3, 2],
            [4, 5, 7, 6],
        ];
        for f in faces {
            for t in [[f[0], f[1], f[2]], [f[0], f[2], f[3]]] {
                scene.triangles.push(Triangle {
                    vertices: t.map(|v| base + v),
                    material,
                });
            }
        }
    }

    fn plan_action(kind: ActionKind) -> SimAction {
        match kind {
            ActionKind::Forward => SimAction::Forward,
            ActionKind::TurnLeft => SimAction::TurnLeft,
            ActionKind::TurnRight | ActionKind::Stop => SimAction::TurnRight,
        }
    }

    /// In the simulator (a procedural house, true poses so only the follower is tested): the
    /// robot maps its room with the start-up look-around, gets a path to the farthest reachable
    /// cell, and once it drives along it a box appears on the path 1 m ahead. The follower
    /// must ask for a replan (obstacle ahead) before touching the box.
    #[test]
    fn a_replan_happens_when_an_obstacle_appears_on_the_path() {
        let scene = activemap_sim::house::generate(3, &{
            let mut hc = activemap_sim::house::HouseConfig::default();
            hc.max_rooms = 2;
            hc.min_rooms = hc.min_rooms.min(2);
            hc.max_area = 30.0;
            hc.min_area = hc.min_area.min(30.0);
            hc
        })
        .unwrap()
        .scene;
        let config = SimConfig::with_resolution(64, 64);
        let mut sim = Simulator::new(scene.clone(), config.clone()).unwrap();
        let start = sim.true_planar_pose();
        let mut occupancy = OccupancyMapper::new(
            OccupancyConfig::default(),
            Point2::new(start.x - 2.0, start.y - 2.0),
            Point2::new(start.x + 2.0, start.y + 2.0),
        )
        .unwrap();
        let observe = |sim: &mut Simulator, occupancy: &mut OccupancyMapper| {
            let frame = sim.render();
            let cam = sim.true_pose();
            occupancy
                .integrate_depth(&frame.depth, &frame.intrinsics, &cam)
                .unwrap();
            let p = sim.true_planar_pose();
            occupancy
                .mark_free_disc(Point2::new(p.x, p.y), 0.15)
                .unwrap();
            (p, occupancy.grid())
        };
        let mut core = FollowerCore::new(&Config {
            initial_spin_steps: 72,
            ..Config::default()
        })
        .unwrap();
        // The look-around: 72 left turns, then a plan request.
        let (mut pose, mut grid) = observe(&mut sim, &mut occupancy);
        let mut turns = 0;
        loop {
            match core.decide(&pose, &grid, false).unwrap() {
                Decision::Act(a) => {
                    assert_eq!(a, ActionKind::TurnLeft, "only turns during the look-around");
                    turns += 1;
                    sim.step(plan_action(a));
                    (pose, grid) = observe(&mut sim, &mut occupancy);
                }
                Decision::Replan(reason) => {
                    assert_eq!(reason, ReplanReason::Startup);
                    break;
                }
            }
        }
        assert_eq!(turns, 72);
        // A path to the farthest reachable cell of the mapped area (re-made whenever the
        // follower asks before the box appears: the map grows as the robot drives).
        let replan_far = |core: &mut FollowerCore, pose: &PlanarPose, grid: &PlanGrid| -> f64 {
            let clearance = crate::convert::robot_clearance(grid.geometry.resolution).unwrap();
            let map = ClearanceMap::new(grid, &clearance).unwrap();
            let here = Point2::new(pose.x, pose.y);
            let distances = path_distances(&map, grid.geometry.cell_of(here));
            let (far, d) = distances
                .data
                .iter()
                .enumerate()
                .filter(|(i, d)| d.is_finite() && map.is_clear(grid.geometry.cell_at(*i)))
                .max_by(|a, b| a.1.total_cmp(b.1))
                .map(|(i, d)| (grid.geometry.cell_at(i), *d))
                .unwrap();
            let look_at = grid.geometry.center(far);
            let (waypoints, _) = crate::scorer::shortest_path(grid, here, far, look_at)
                .unwrap()
                .unwrap();
            core.set_path(&Path {
                frame_id: 0,
                waypoints,
                objective: 0.0,
            })
            .unwrap();
            d
        };
        let d = replan_far(&mut core, &pose, &grid);
        assert!(d > 1.8, "the room is too small for the test: {d} m");
        let mut replans_before = core.counters.obstacle_replans;
        let mut forward = 0;
        let mut placed: Option<Point2<f64>> = None;
        for _ in 0..400 {
            let a = match core.decide(&pose, &grid, false).unwrap() {
                Decision::Act(a) => a,
                Decision::Replan(_) if placed.is_none() => {
                    replan_far(&mut core, &pose, &grid);
                    replans_before = core.counters.obstacle_replans;
                    forward = 0;
                    continue;
                }
                Decision::Replan(reason) => {
                    assert_eq!(reason, ReplanReason::ObstacleAhead);
                    break;
                }
            };
            if a == ActionKind::Forward {
                forward += 1;
            }
            // After 6 forward steps (0.3 m) a 0.3 m box appears on the path 1 m ahead.
            if placed.is_none() && forward == 6 {
                let Phase::Follow { follower, .. } = &core.phase else {
                    panic!("not following a path");
                };
                let mut left = 1.0;
                let mut previous = Point2::new(pose.x, pose.y);
                let mut at = None;
                for w in follower.remaining() {
                    let l = (w - previous).norm();
                    if l >= left {
                        at = Some(previous + (w - previous) * (left / l));
                        break;
                    }
                    left -= l;
                    previous = *w;
                }
                let c = at.expect("the path is longer than 1.3 m");
                let mut with_box = scene.clone();
                let floor = sim.true_pose().translation.z as f32 - 0.88;
                add_box(
                    &mut with_box,
                    [c.x as f32 - 0.15, c.y as f32 - 0.15, floor],
                    [c.x as f32 + 0.15, c.y as f32 + 0.15, floor + 0.6],
                );
                let here = sim.true_planar_pose();
                sim = Simulator::new(with_box, config.clone()).unwrap();
                sim.set_planar_pose(here).unwrap();
                placed = Some(c);
            }
            let result = sim.step(plan_action(a));
            assert!(!result.collided, "drove into something at {pose:?}");
            (pose, grid) = observe(&mut sim, &mut occupancy);
            if let Some(c) = placed {
                assert!(
                    (Point2::new(pose.x, pose.y) - c).norm() > 0.25,
                    "the robot reached the box without replanning"
                );
            }
        }
        assert!(
            placed.is_some(),
            "the robot never drove 0.3 m along the path"
        );
        assert_eq!(core.counters.obstacle_replans, replans_before + 1);
    }
}
