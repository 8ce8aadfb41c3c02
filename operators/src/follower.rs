//! `follower`: executes the scorer's path and emits exactly one action per step. A thin shell
//! around [`activemap_planning::executor::PathExecutor`], the one path executor (the
//! in-process explorer runs it too): greedy following (SPEC §6), the start-up look-around,
//! the look turn at the end of a path, the map's replan triggers, stuck detection, the bumper
//! (forward moves that do not move the tracked pose) and turning on the spot while tracking
//! is lost are all the executor's. This operator adds the wiring: the per-step join of grid
//! and pose, the replan requests (the executor's reason as the wire enum, [`reason_to_wire`])
//! answered by a path of the same frame, `max_replans_per_step`, and `Stop` when the planner
//! ends the episode (its goal stream, hence the path stream, closes).

use activemap_geometry::PlanarPose;
use activemap_geometry::RobotModel;
use activemap_geometry::frames::planar_from_camera_pose;
use activemap_planning::OccupancyGrid as PlanGrid;
use activemap_planning::executor::{self, ExecutorConfig, ExecutorCounters, PathExecutor};
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, check_config_as,
};
use activemap_schemas::{
    Action, ActionKind, LostReason, MessageKind as K, Path, PoseEstimate, ReplanReason,
    ReplanRequest, TrackingStatus,
};

use crate::Registered;
use crate::convert::{pose_from_wire, read_grid};
use crate::join::FrameJoin;

/// Config (defaults: [`ExecutorConfig::default`]).
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
    /// Turns of the look-around at the start of the episode (72 × 5° = 360°). 0 disables it.
    #[serde(default = "default_spin")]
    pub initial_spin_steps: usize,
    /// At the end of a path, the turn toward the frontier is skipped when it is already within
    /// this many degrees of the heading. 0 always turns.
    #[serde(default = "default_look_skip")]
    pub look_skip_half_angle_deg: f64,
    /// Forward moves in a row that leave the tracked position within half of the robot's
    /// forward step before the follower replans. 0 disables it.
    #[serde(default = "default_bumps")]
    pub bumps_to_replan: usize,
    /// Blocked replans in a row at one spot after which the follower asks as stuck (the goal
    /// failed) instead (3). 0 never does.
    #[serde(default = "default_blocked_replans_to_stuck")]
    pub blocked_replans_to_stuck: usize,
    /// While tracking is lost the robot turns on the spot; back after fewer lost frames in a
    /// row than this, it resumes its path, after as many or more it asks for a new one
    /// (`TrackingLost`). 1 always asks.
    #[serde(default = "default_lost_replan_after")]
    pub lost_replan_after: usize,
    /// Losses of tracking in a row that begin at one spot of a path after which the follower
    /// asks as stuck (the goal failed) once tracking is back (3). 0 never does.
    #[serde(default = "default_lost_flaps_to_stuck")]
    pub lost_flaps_to_stuck: usize,
    /// The robot (radius for the clearance, forward step for the bumper; any field left out
    /// keeps its default).
    #[serde(default)]
    pub robot: RobotModel,
}

fn default_window() -> usize {
    ExecutorConfig::default().stuck_window
}
fn default_improvement() -> f64 {
    ExecutorConfig::default().stuck_min_improvement_m
}
fn default_replans() -> usize {
    activemap_planning::executor::MAX_REPLANS_PER_STEP
}
fn default_spin() -> usize {
    ExecutorConfig::default().initial_spin_steps
}
fn default_look_skip() -> f64 {
    ExecutorConfig::default()
        .look_skip_half_angle_rad
        .to_degrees()
}
fn default_bumps() -> usize {
    ExecutorConfig::default().bumps_to_replan
}
fn default_blocked_replans_to_stuck() -> usize {
    ExecutorConfig::default().blocked_replans_to_stuck
}
fn default_lost_replan_after() -> usize {
    ExecutorConfig::default().lost_replan_after
}
fn default_lost_flaps_to_stuck() -> usize {
    ExecutorConfig::default().lost_flaps_to_stuck
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
            blocked_replans_to_stuck: default_blocked_replans_to_stuck(),
            lost_replan_after: default_lost_replan_after(),
            lost_flaps_to_stuck: default_lost_flaps_to_stuck(),
            robot: RobotModel::default(),
        }
    }
}

impl Config {
    /// The executor's settings.
    pub fn executor(&self) -> ExecutorConfig {
        ExecutorConfig {
            stuck_window: self.stuck_window,
            stuck_min_improvement_m: self.stuck_min_improvement,
            initial_spin_steps: self.initial_spin_steps,
            look_skip_half_angle_rad: self.look_skip_half_angle_deg.to_radians(),
            bumps_to_replan: self.bumps_to_replan,
            blocked_replans_to_stuck: self.blocked_replans_to_stuck,
            lost_replan_after: self.lost_replan_after,
            lost_flaps_to_stuck: self.lost_flaps_to_stuck,
            ..ExecutorConfig::default()
        }
    }
}

/// The replan reasons on the wire and back (the policies' conversions, [`activemap_policy::wire`]).
pub use activemap_policy::wire::{reason_from_wire, reason_to_wire};

/// What the follower wants this step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Decision {
    /// Send this action.
    Act(ActionKind),
    /// Ask the planner for a new goal.
    Replan(ReplanReason),
}

/// The executor on wire messages, without transport.
pub struct FollowerCore {
    executor: PathExecutor,
}

impl FollowerCore {
    /// A follower that starts with the look-around (or by asking for a plan).
    pub fn new(config: &Config) -> anyhow::Result<Self> {
        Ok(Self {
            executor: PathExecutor::new(config.executor(), config.robot)
                .map_err(|e| anyhow::anyhow!("follower: {e}"))?,
        })
    }

    /// The executor (its counters, the path being followed).
    pub fn executor(&self) -> &PathExecutor {
        &self.executor
    }

    /// What happened so far.
    pub fn counters(&self) -> ExecutorCounters {
        self.executor.counters
    }

    /// Takes a new path (an empty one means the scorer found none).
    pub fn set_path(&mut self, path: &Path) -> anyhow::Result<()> {
        let waypoints: Vec<PlanarPose> = path
            .waypoints
            .iter()
            .map(|w| PlanarPose::new(w.x, w.y, w.yaw))
            .collect();
        Ok(self.executor.set_path(&waypoints)?)
    }

    /// The decision for the robot at `pose` (tracked, or a prediction when `tracking_lost`)
    /// with the current `grid`.
    pub fn decide(
        &mut self,
        pose: &PlanarPose,
        grid: &PlanGrid,
        tracking_lost: bool,
    ) -> anyhow::Result<Decision> {
        Ok(match self.executor.decide(pose, grid, tracking_lost)? {
            executor::Decision::Act(a) => Decision::Act(ActionKind::from(a)),
            executor::Decision::Replan(r) => Decision::Replan(reason_to_wire(r)),
        })
    }
}

/// The inputs of one step.
#[derive(Default)]
struct Slot {
    grid: Option<PlanGrid>,
    pose: Option<(PlanarPose, bool)>,
}

/// A message the follower sends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Output {
    /// On `replan`: a new goal is needed for this frame (the path of the same frame answers).
    Replan(ReplanRequest),
    /// On `action`: the step's action.
    Action(Action),
}

/// The operator: the per-step join around [`FollowerCore`]. Transport-free except for
/// [`Operator::on_event`], so it can be driven in process ([`Follower::poll`]).
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
    /// A follower at step 0.
    pub fn from_config(config: &Config) -> anyhow::Result<Self> {
        anyhow::ensure!(
            config.max_replans_per_step >= 1,
            "follower: max_replans_per_step must be ≥ 1"
        );
        Ok(Self {
            core: FollowerCore::new(config)?,
            max_replans: config.max_replans_per_step,
            step: 0,
            replans_this_step: 0,
            awaiting_path: false,
            join: FrameJoin::new(),
            paths: Vec::new(),
        })
    }

    /// The executor and its wire wrapper.
    pub fn core(&self) -> &FollowerCore {
        &self.core
    }

    /// The step whose action comes next.
    pub fn step(&self) -> u64 {
        self.step
    }

    /// Stores the grid of frame `k`.
    pub fn add_grid(&mut self, k: u64, grid: PlanGrid) {
        self.join.slot(k).grid = Some(grid);
    }

    /// Stores the pose of frame `k` and whether tracking was lost there.
    pub fn add_pose(&mut self, k: u64, pose: PlanarPose, tracking_lost: bool) {
        self.join.slot(k).pose = Some((pose, tracking_lost));
    }

    /// Stores a path from the scorer.
    pub fn add_path(&mut self, path: Path) {
        self.paths.push(path);
    }

    /// Runs the current step as far as the inputs allow: the messages to send, in order. A
    /// replan request leaves the step waiting for the path of the same frame; after
    /// `max_replans_per_step` requests in one step the robot turns left instead.
    pub fn poll(&mut self) -> anyhow::Result<Vec<Output>> {
        let mut out = Vec::new();
        loop {
            let k = self.step;
            let Some(Slot {
                grid: Some(grid),
                pose: Some((pose, lost)),
            }) = self.join.get(k)
            else {
                return Ok(out);
            };
            if self.awaiting_path {
                let Some(i) = self.paths.iter().position(|p| p.frame_id == k) else {
                    return Ok(out);
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
                    out.push(Output::Replan(ReplanRequest {
                        frame_id: k,
                        reason,
                    }));
                    continue;
                }
                Decision::Replan(_) => ActionKind::TurnLeft,
            };
            out.push(Output::Action(Action { step: k, action }));
            self.join.take(k);
            self.step += 1;
            self.replans_this_step = 0;
        }
    }
}

/// Whether the estimate `e` makes the robot stop following its path and look around: tracking
/// is lost, unless the only failure is a solution the tracker's motion check rejected (the
/// estimate is then the commanded motion's prediction, good for the next steps; turning away
/// and back for it would keep a robot whose tracker rejects every other frame from moving).
pub fn stops_the_robot(e: &PoseEstimate) -> bool {
    e.status == TrackingStatus::Lost
        && !matches!(e.lost_reason, Some(LostReason::MotionMismatch { .. }))
}

impl Operator for Follower {
    type Config = Config;

    fn new(config: Config, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        Self::from_config(&config)
    }

    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        match event {
            Event::Input(input) => match input.port {
                inputs::GRID => {
                    let (k, g) = read_grid(input.bytes)?;
                    self.add_grid(k, g);
                }
                inputs::POSE => {
                    let e: PoseEstimate = input.decode()?;
                    let pose = planar_from_camera_pose(&pose_from_wire(&e.t_world_camera)?);
                    self.add_pose(e.frame_id, pose, stops_the_robot(&e));
                }
                inputs::PATH => self.add_path(input.decode()?),
                other => anyhow::bail!("follower: unexpected input `{other}`"),
            },
            Event::InputClosed { port: inputs::PATH } => {
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
            Event::InputClosed { port: inputs::POSE } => return Ok(Flow::Stop),
            _ => return Ok(Flow::Continue),
        }
        for output in self.poll()? {
            match output {
                Output::Replan(request) => ctx.send(outputs::REPLAN, &request)?,
                Output::Action(action) => ctx.send(outputs::ACTION, &action)?,
            }
        }
        Ok(Flow::Continue)
    }
}

/// The operator's input ports, named once for registration and dispatch.
pub mod inputs {
    activemap_runtime::ports! {
        PATH = "path": super::K::Path,
        POSE = "pose": super::K::PoseEstimate,
        GRID = "grid": super::K::OccupancyGrid
    }
}

/// The operator's output ports, named once for registration and dispatch.
pub mod outputs {
    activemap_runtime::ports! {
        ACTION = "action": super::K::Action,
        REPLAN = "replan": super::K::ReplanRequest
    }
}

/// Registry entry.
pub fn registered() -> Registered {
    Registered {
        descriptor: OperatorDescriptor {
            name: "follower",
            summary: "Greedy path follower: one action per step, replan requests, stuck recovery (SPEC §6)",
            inputs: inputs::ALL,
            outputs: outputs::ALL,
            evaluation: false,
            check_config: check_config_as::<Config>,
        },
        implementation: Some(OperatorImpl::of::<Follower>()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_planning::clearance::ClearanceMap;
    use activemap_planning::frontier::path_distances;
    use activemap_planning::occupancy::{OccupancyConfig, OccupancyMapper};
    use activemap_planning::replan::ReplanReason as PlanReason;
    use activemap_sim::{
        Action as SimAction, Material, Scene, SimConfig, Simulator, Triangle, Vertex,
    };
    use nalgebra::Point2;

    /// The wire reasons: the three map triggers are `ObstacleAhead` on the wire, every other
    /// reason round-trips, and the planner judges a goal the same way from either side.
    #[test]
    fn replan_reasons_map_onto_the_wire() {
        use activemap_planning::fbe::outcome;
        let all = [
            PlanReason::Startup,
            PlanReason::PathDone,
            PlanReason::GoalOccupied,
            PlanReason::PathBlocked { segment: 2 },
            PlanReason::ObstacleAhead,
            PlanReason::NoPath,
            PlanReason::Stuck,
            PlanReason::TrackingLost,
            PlanReason::Blocked,
        ];
        for r in all {
            let wire = reason_to_wire(r);
            assert_eq!(
                wire == ReplanReason::ObstacleAhead,
                r.is_obstacle(),
                "{r:?}"
            );
            if !r.is_obstacle() {
                assert_eq!(reason_from_wire(wire), r);
            }
            assert_eq!(outcome(reason_from_wire(wire)), outcome(r), "{r:?}");
        }
    }

    /// The defaults are the executor's (one source for the operator and the explorer), and
    /// the follower's robot is the planning library's.
    #[test]
    fn defaults_are_the_executors() {
        let config: Config = serde_json::from_value(serde_json::json!({})).unwrap();
        assert_eq!(config.executor(), ExecutorConfig::default());
        assert_eq!(
            config.max_replans_per_step,
            activemap_policy::explorer::ExplorerConfig::default().max_replans_per_step
        );
        assert_eq!(
            config.robot,
            activemap_policy::explorer::ExplorerConfig::default().robot
        );
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
            let clearance =
                crate::convert::robot_clearance(&RobotModel::default(), grid.geometry.resolution)
                    .unwrap();
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
            let path = activemap_planning::path::shortest_path(
                grid,
                here,
                far,
                look_at,
                &clearance,
                &activemap_planning::astar::AstarConfig::default(),
            )
            .unwrap()
            .unwrap();
            core.set_path(&activemap_policy::wire::path_to_wire(0, &path))
                .unwrap();
            d
        };
        let d = replan_far(&mut core, &pose, &grid);
        assert!(d > 1.8, "the room is too small for the test: {d} m");
        let mut replans_before = core.counters().obstacle_replans;
        let mut forward = 0;
        let mut placed: Option<Point2<f64>> = None;
        for _ in 0..400 {
            let a = match core.decide(&pose, &grid, false).unwrap() {
                Decision::Act(a) => a,
                Decision::Replan(_) if placed.is_none() => {
                    replan_far(&mut core, &pose, &grid);
                    replans_before = core.counters().obstacle_replans;
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
                let Some(remaining) = core.executor().remaining() else {
                    panic!("not following a path");
                };
                let mut left = 1.0;
                let mut previous = Point2::new(pose.x, pose.y);
                let mut at = None;
                for w in remaining {
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
        assert_eq!(core.counters().obstacle_replans, replans_before + 1);
    }
}
