//! `follower`: executes the scorer's path with the greedy rule of SPEC §6 and emits exactly
//! one action per step. It asks the planner for a new goal when the path is done (after
//! turning to face the frontier it came for), when the map shows an obstacle on the remaining
//! path or close ahead, when the goal turns occupied, when no path was found, and when the
//! robot is stuck (no progress along the path over `stuck_window` steps: the goal then counts
//! as failed). Wraps `activemap_planning::{follower, replan, stuck}`. When the planner ends the
//! episode (its goal stream, hence the path stream, closes) it sends `Stop`.

use std::collections::BTreeMap;

use activemap_geometry::PlanarPose;
use activemap_geometry::frames::planar_from_camera_pose;
use activemap_planning::OccupancyGrid as PlanGrid;
use activemap_planning::clearance::{ClearanceConfig, ClearanceMap};
use activemap_planning::dynamics::Action as PlanAction;
use activemap_planning::follower::{FollowerConfig, GreedyFollower, greedy_action};
use activemap_planning::replan::{ReplanConfig, ReplanReason as PlanReason, check_replan};
use activemap_planning::stuck::ProgressMonitor;
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, PortSpec, check_config_as,
};
use activemap_schemas::{
    Action, ActionKind, MessageKind as K, Path, PoseEstimate, ReplanReason, ReplanRequest,
};
use nalgebra::Point2;

use crate::Registered;
use crate::convert::{pose_from_wire, read_grid};

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

impl Default for Config {
    fn default() -> Self {
        Self {
            stuck_window: default_window(),
            stuck_min_improvement: default_improvement(),
            max_replans_per_step: default_replans(),
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
}

/// The follower's state machine, without transport.
pub struct FollowerCore {
    config: FollowerConfig,
    replan: ReplanConfig,
    monitor: ProgressMonitor,
    phase: Phase,
    /// The grid the current path was planned on (the first grid seen after it arrived): only
    /// obstacles that appeared since then trigger an obstacle-ahead replan.
    plan_grid: Option<PlanGrid>,
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
        Ok(Self {
            config: follower,
            replan: ReplanConfig {
                turn_threshold_rad: follower.turn_threshold_rad,
                ..ReplanConfig::default()
            },
            plan_grid: None,
            monitor: ProgressMonitor::new(config.stuck_window, config.stuck_min_improvement)?,
            phase: Phase::Idle(ReplanReason::Startup),
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

    /// The decision for the robot at `pose` with the current `grid`.
    pub fn decide(&mut self, pose: &PlanarPose, grid: &PlanGrid) -> anyhow::Result<Decision> {
        let here = Point2::new(pose.x, pose.y);
        let threshold = self.config.turn_threshold_rad;
        for _ in 0..4 {
            match &mut self.phase {
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
                            ..ClearanceConfig::default()
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
                        self.phase = Phase::Idle(ReplanReason::NoPath);
                        continue;
                    }
                    let yaw = *look_yaw;
                    match reason {
                        None => {}
                        Some(PlanReason::PathDone) => {
                            self.phase = Phase::Look { yaw };
                            continue;
                        }
                        Some(_) => {
                            self.counters.obstacle_replans += 1;
                            self.phase = Phase::Idle(ReplanReason::ObstacleAhead);
                            continue;
                        }
                    }
                    match follower.next_action(pose) {
                        Some(a) => return Ok(Decision::Act(to_kind(a))),
                        None => self.phase = Phase::Look { yaw },
                    }
                }
            }
        }
        Ok(Decision::Act(ActionKind::TurnLeft))
    }
}

/// The operator.
pub struct Follower {
    core: FollowerCore,
    max_replans: usize,
    step: u64,
    replans_this_step: usize,
    awaiting_path: bool,
    grids: BTreeMap<u64, PlanGrid>,
    poses: BTreeMap<u64, PlanarPose>,
    paths: Vec<Path>,
}

impl Follower {
    /// Runs the current step as far as the inputs allow.
    fn run(&mut self, ctx: &mut Context<'_>) -> anyhow::Result<()> {
        loop {
            let k = self.step;
            let (Some(grid), Some(pose)) = (self.grids.get(&k), self.poses.get(&k)) else {
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
            let action = match self.core.decide(pose, grid)? {
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
            self.grids.remove(&k);
            self.poses.remove(&k);
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
            grids: BTreeMap::new(),
            poses: BTreeMap::new(),
            paths: Vec::new(),
        })
    }

    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        match event {
            Event::Input(input) => match input.port {
                "grid" => {
                    let (k, g) = read_grid(input.bytes)?;
                    self.grids.insert(k, g);
                }
                "pose" => {
                    let e: PoseEstimate = input.decode()?;
                    self.poses.insert(
                        e.frame_id,
                        planar_from_camera_pose(&pose_from_wire(&e.t_world_camera)?),
                    );
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
