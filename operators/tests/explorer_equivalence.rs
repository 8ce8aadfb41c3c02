//! The in-process explorer (`activemap_policy::explorer::Explorer`, what `bench planning`
//! and the library's tests run) and the operator pipeline (what `activemap run` runs) take the
//! same actions: both are fed the same frames and poses of one simulator, step by step, and
//! must agree on every action.
//!
//! The pipeline is driven in process through the operators' transport-free cores, in the
//! order the lockstep dataflow delivers messages within a step k (`dataflow.yaml`): occupancy
//! grid k ([`Occupancy::process_ready`]), frontier regions k ([`frontier_regions`]), then the
//! follower's per-step join ([`Follower::poll`]); each replan request is answered by the
//! planner ([`FbePlanner::choose`]) and the scorer ([`path_for_goal`]) on frame k, and the
//! follower decides again. Every message goes through its wire encoding, as over transport.
//! Poses are the simulator's true ones (SLAM is not under test), sent as the tracker's
//! `PoseEstimate`s. The `fisher` comparison adds the map snapshots of one in-process mapping
//! session, the same to both.

use activemap_geometry::frames::planar_from_camera_pose;
use activemap_operators::convert::{
    pose_from_wire, pose_to_wire, read_grid, with_map_snapshot, write_map,
};
use activemap_operators::follower::{self, Follower, Output};
use activemap_operators::frontier::{self, frontier_regions};
use activemap_operators::mapper::Mapper;
use activemap_operators::occupancy::{self, Occupancy};
use activemap_operators::planner::{self, FbePlanner};
use activemap_operators::scorer::{self, path_for_goal};
use activemap_planning::astar::AstarConfig;
use activemap_policy::explorer::{Decision, Explorer, ExplorerConfig, ExplorerCounters};
use activemap_policy::{GoalInput, GoalPolicy, MapSnapshot, PathInput, PathPolicy};
use activemap_schemas::{
    ActionKind, FisherReport, Frontiers, Goal, Path, Payload, PoseEstimate, ReplanRequest,
    TrackingStatus,
};
use activemap_sim::simulator::SimConfig;
use activemap_sim::{Action as SimAction, scene_spec::SceneSpec};
use nalgebra::Point2;

/// A message through its wire encoding and back, as transport delivers it.
fn wire<T: Payload>(message: &T) -> T {
    T::from_bytes(&message.to_bytes().unwrap()).unwrap()
}

/// An operator config as `dataflow.yaml` leaves it (every field at its default).
fn defaults<T: serde::de::DeserializeOwned>() -> T {
    serde_json::from_value(serde_json::json!({})).unwrap()
}

/// How a comparison ended.
#[derive(Debug)]
struct Comparison {
    /// Steps on which both took the same action (or both ended the episode).
    agreed: usize,
    /// The first step on which the actions or the executors' event counters (paths, replans
    /// by cause, bumps, stuck, ...) differ: (step, explorer's action, pipeline's action);
    /// `None` = never.
    diverged: Option<(usize, Option<ActionKind>, Option<ActionKind>)>,
    /// The step at which both ended the episode, if they did.
    finished: Option<usize>,
    /// The explorer's and the follower's executor counters at the end.
    counters: (
        activemap_planning::executor::ExecutorCounters,
        activemap_planning::executor::ExecutorCounters,
    ),
    /// Replan requests the pipeline's follower sent.
    replans: usize,
}

/// What the occupancy and frontier operators make of frame k: the tracker's estimate (the true
/// pose through its wire encoding), occupancy grid k (no Gaussian map: SLAM is not under test,
/// every snapshot is empty) and frontier regions k.
struct Perceived {
    camera: activemap_geometry::Isometry3<f64>,
    pose: activemap_geometry::PlanarPose,
    grid: activemap_planning::OccupancyGrid,
    frontiers: Frontiers,
}

/// The `occupancy` and `frontier` operators' cores.
struct Front {
    occupancy: Occupancy,
    frontier: frontier::Config,
}

impl Front {
    fn new() -> Self {
        Self {
            occupancy: Occupancy::from_config(defaults::<occupancy::Config>()).unwrap(),
            frontier: defaults(),
        }
    }

    fn perceive(&mut self, k: u64, depth: &[f32], sim: &activemap_sim::Simulator) -> Perceived {
        let stamp = k as f64 * 0.1;
        let estimate = wire(&estimate(k, stamp, sim));
        let camera = pose_from_wire(&estimate.t_world_camera).unwrap();
        let pose = planar_from_camera_pose(&camera);
        self.occupancy.add_map(k, Vec::new(), Vec::new());
        self.occupancy
            .add_depth(k, depth.to_vec(), sim.config().intrinsics, stamp);
        self.occupancy.add_pose(k, camera, estimate.status);
        let grids = self.occupancy.process_ready().unwrap();
        assert_eq!(grids.len(), 1, "one grid per frame");
        let (gk, grid) = read_grid(&grids[0].to_bytes().unwrap()).unwrap();
        assert_eq!(gk, k);
        let robot = Point2::new(pose.x, pose.y);
        let frontiers = wire(&Frontiers {
            frame_id: k,
            stamp,
            regions: frontier_regions(&grid, robot, &self.frontier).unwrap(),
        });
        Perceived {
            camera,
            pose,
            grid,
            frontiers,
        }
    }
}

/// The pipeline's decision for frame `k`: `None` when the planner ends the episode (the
/// follower then sends `Stop`).
struct Pipeline {
    front: Front,
    follower: Follower,
    planner: FbePlanner,
    replans: usize,
}

impl Pipeline {
    fn new() -> Self {
        Self {
            front: Front::new(),
            follower: Follower::from_config(&defaults::<follower::Config>()).unwrap(),
            planner: FbePlanner::new(&defaults::<planner::Config>()).unwrap(),
            replans: 0,
        }
    }

    fn step(
        &mut self,
        k: u64,
        depth: &[f32],
        sim: &activemap_sim::Simulator,
    ) -> Option<ActionKind> {
        let Perceived {
            camera: _,
            pose,
            grid,
            frontiers,
        } = self.front.perceive(k, depth, sim);
        let robot = Point2::new(pose.x, pose.y);
        // follower, with the planner and the scorer answering its requests on frame k.
        self.follower.add_grid(k, grid.clone());
        self.follower.add_pose(k, pose, false);
        let mut pending: std::collections::VecDeque<Output> = self.follower.poll().unwrap().into();
        let mut action = None;
        while let Some(output) = pending.pop_front() {
            match output {
                Output::Replan(request) => {
                    self.replans += 1;
                    let request: ReplanRequest = wire(&request);
                    assert_eq!(request.frame_id, k);
                    let (target, focus) = self
                        .planner
                        .choose(request.reason, &grid, &frontiers, &pose)
                        .unwrap()?;
                    let goal = wire(&Goal {
                        frame_id: k,
                        target: target as i32,
                        focus: [focus.x, focus.y],
                    });
                    let path: Path = wire(
                        &path_for_goal(
                            &grid,
                            robot,
                            &frontiers,
                            &goal,
                            &activemap_geometry::RobotModel::default(),
                            &AstarConfig::default(),
                        )
                        .unwrap(),
                    );
                    self.follower.add_path(path);
                    pending.extend(self.follower.poll().unwrap());
                }
                Output::Action(a) => {
                    assert_eq!(a.step, k);
                    assert!(action.is_none(), "two actions in step {k}");
                    action = Some(a.action);
                }
            }
        }
        assert!(action.is_some(), "the follower did not act in step {k}");
        action
    }
}

/// Runs both on one simulator of a small house for up to `steps` steps; the `blocked`-th
/// forward moves (counted from 0) do not move the robot, as if an obstacle neither map shows
/// were in the way (both see the same frames, so both feel the bump). `mutate` changes the
/// explorer's settings (to check that the comparison notices).
fn compare(steps: usize, blocked: &[usize], mutate: impl Fn(&mut ExplorerConfig)) -> Comparison {
    let spec = SceneSpec {
        max_rooms: Some(3),
        max_area: Some(40.0),
        ..SceneSpec::new("house:7")
    };
    let mut sim = spec.simulator(SimConfig::with_resolution(80, 80)).unwrap();
    let mut config = ExplorerConfig::default();
    mutate(&mut config);
    // The occupancy operator's initial extent.
    let mut explorer =
        Explorer::new(config, Point2::new(-2.0, -2.0), Point2::new(2.0, 2.0)).unwrap();
    let mut pipeline = Pipeline::new();
    let mut forward = 0;
    let mut out = Comparison {
        agreed: 0,
        diverged: None,
        finished: None,
        counters: Default::default(),
        replans: 0,
    };
    for k in 0..steps {
        let frame = sim.render();
        let camera = pose_from_wire(&pose_to_wire(&sim.true_pose())).unwrap();
        let ours = match explorer
            .step(&frame.depth, &frame.intrinsics, &camera)
            .unwrap()
        {
            Decision::Act(a) => Some(ActionKind::from(a)),
            Decision::Finished => None,
        };
        let theirs = pipeline.step(k as u64, &frame.depth, &sim);
        out.counters = (
            explorer.executor().counters,
            pipeline.follower.core().counters(),
        );
        out.replans = pipeline.replans;
        if ours != theirs || out.counters.0 != out.counters.1 {
            out.diverged = Some((k, ours, theirs));
            return out;
        }
        out.agreed += 1;
        let Some(action) = ours else {
            out.finished = Some(k);
            return out;
        };
        let action = match action {
            ActionKind::Forward => {
                forward += 1;
                if blocked.contains(&(forward - 1)) {
                    continue;
                }
                SimAction::Forward
            }
            ActionKind::TurnLeft => SimAction::TurnLeft,
            ActionKind::TurnRight => SimAction::TurnRight,
            ActionKind::Stop => unreachable!("Stop is the end of the episode"),
        };
        sim.step(action);
    }
    out
}

/// Same house, same frames: the explorer and the pipeline agree on every action of the whole
/// episode (it ends by itself, for both at the same step: 715 today, so well over 300 steps),
/// and their executors count the same events on every step (11 paths, an obstacle replan, 8
/// bumps of which 6 are real ones against the house, 4 blocked replans). Two forward moves swallowed by an unseen obstacle exercise
/// the bumper. The comparison is sharp: an explorer whose look-around is one turn shorter, or
/// whose bumper waits for a third bump, is caught; so is one without a bumper, by its actions
/// alone, when the unseen obstacle stays (it gives up on the goal after the stuck window while
/// the pipeline's bumper keeps asking for new paths to it).
#[test]
fn explorer_and_pipeline_take_the_same_actions() {
    let blocked = [30, 31];
    let same = compare(1500, &blocked, |_| {});
    eprintln!("{same:?}");
    assert_eq!(same.diverged, None, "{same:?}");
    assert!(
        same.finished.is_some(),
        "no end within 1500 steps: {same:?}"
    );
    assert!(same.agreed >= 300, "only {} steps", same.agreed);
    let (ours, _) = same.counters;
    assert!(ours.paths >= 3, "too few paths to compare: {ours:?}");
    assert!(ours.blocked_replans >= 1 && ours.bumps >= 2, "{ours:?}");

    let short_spin = compare(400, &blocked, |c| c.executor.initial_spin_steps -= 1);
    assert_eq!(short_spin.diverged.map(|d| d.0), Some(71), "{short_spin:?}");
    let lazy_bumper = compare(400, &blocked, |c| c.executor.bumps_to_replan = 3);
    assert!(lazy_bumper.diverged.is_some(), "{lazy_bumper:?}");
    let wall: Vec<usize> = (30..80).collect();
    let no_bumper = compare(400, &wall, |c| c.executor.bumps_to_replan = 0);
    let (step, ours, theirs) = no_bumper.diverged.expect("no divergence without a bumper");
    assert_ne!(
        ours, theirs,
        "the actions differ at step {step}: {no_bumper:?}"
    );
}

/// Reads no recording: the `fisher` flow's planner has no LLM provider.
fn no_recordings(
    _: &std::path::Path,
    _: &str,
) -> anyhow::Result<Vec<activemap_llm::provider::RecordedReply>> {
    anyhow::bail!("no recordings here")
}

/// The `fisher` flow's planner and scorer configs (`flows/fisher.yaml`), the scorer's camera
/// and Fisher settings small enough for a test: the camera of `size`² pixels, map lag `lag`.
fn fisher_configs(size: u32, lag: u64) -> (planner::Config, scorer::Config) {
    let planner = serde_json::from_value(serde_json::json!({
        "policy": "fbe", "frontier": "largest", "when_no_frontier": "refine"
    }))
    .unwrap();
    let scorer = serde_json::from_value(serde_json::json!({
        "mode": "fisher",
        "map_lag": lag,
        "camera": { "width": size, "height": size, "hfov_deg": 90 },
        "fisher": { "objective": "paper", "candidates": 64, "top_candidates": 4,
                    "mc_poses": 8, "scoring_width": 24 }
    }))
    .unwrap();
    (planner, scorer)
}

/// The `fisher` pipeline: the FBE pipeline's occupancy, frontier and follower, with the
/// planner's and the scorer's policies fed as their shells feed them (map snapshots as wire
/// bytes, poses as the tracker's estimates).
struct FisherPipeline {
    front: Front,
    follower: Follower,
    goals: GoalPolicy,
    paths: PathPolicy,
    /// The scorer's reports, in order.
    reports: Vec<FisherReport>,
}

impl FisherPipeline {
    fn new(planner: &planner::Config, scorer: &scorer::Config) -> Self {
        Self {
            front: Front::new(),
            follower: Follower::from_config(&defaults::<follower::Config>()).unwrap(),
            goals: GoalPolicy::new(planner, "planner", None, &no_recordings)
                .unwrap()
                .with_log(activemap_policy::no_log),
            paths: PathPolicy::new(scorer).unwrap(),
            reports: Vec::new(),
        }
    }

    /// The mapper's snapshot as its `map` message, to the planner and the scorer.
    fn add_map(&mut self, bytes: &[u8]) {
        with_map_snapshot(bytes, |map| self.goals.add_map(map)).unwrap();
        with_map_snapshot(bytes, |map| self.paths.add_map(map)).unwrap();
    }

    fn step(
        &mut self,
        k: u64,
        depth: &[f32],
        sim: &activemap_sim::Simulator,
    ) -> Option<ActionKind> {
        let Perceived {
            camera,
            pose,
            grid,
            frontiers,
        } = self.front.perceive(k, depth, sim);
        self.goals.add_pose(&pose);
        self.paths.add_pose(k, camera);
        self.follower.add_grid(k, grid.clone());
        self.follower.add_pose(k, pose, false);
        let mut pending: std::collections::VecDeque<Output> = self.follower.poll().unwrap().into();
        let mut action = None;
        while let Some(output) = pending.pop_front() {
            match output {
                Output::Replan(request) => {
                    let request: ReplanRequest = wire(&request);
                    assert!(self.goals.ready(k) && self.paths.ready(k));
                    let decision = self
                        .goals
                        .goal(&GoalInput {
                            request,
                            grid: &grid,
                            frontiers: &frontiers,
                            pose,
                            camera_z: camera.translation.z,
                        })
                        .unwrap();
                    let goal = wire(&decision.goal?);
                    let answer = self
                        .paths
                        .path(&PathInput {
                            goal: &goal,
                            grid: &grid,
                            pose: camera,
                            frontiers: Some(&frontiers),
                        })
                        .unwrap();
                    self.reports
                        .push(wire(&answer.report.expect("fisher mode")));
                    self.follower.add_path(wire(&answer.path));
                    pending.extend(self.follower.poll().unwrap());
                }
                Output::Action(a) => {
                    assert!(action.is_none(), "two actions in step {k}");
                    action = Some(a.action);
                }
            }
        }
        action
    }
}

/// The tracker's estimate of frame `k`: the simulator's true pose.
fn estimate(k: u64, stamp: f64, sim: &activemap_sim::Simulator) -> PoseEstimate {
    PoseEstimate {
        frame_id: k,
        stamp,
        t_world_camera: pose_to_wire(&sim.true_pose()),
        status: TrackingStatus::Ok,
        residual_rgb: 0.0,
        residual_depth: 0.0,
        iterations: 0,
        graph_anchor: None,
        keyframe_corrections: Vec::new(),
        lost_reason: None,
        relocalised: None,
    }
}

/// A report without its wall times (the only part that is not deterministic).
fn untimed(mut report: FisherReport) -> FisherReport {
    report.timings = Default::default();
    report
}

/// Runs the `fisher` explorer and pipeline for `steps` steps on one simulator of a small
/// house, the explorer's scorer with Fisher objective `objective` (the pipeline's: `paper`):
/// the explorer's counters and the pipeline's reports, or where they first differ (actions,
/// executor counters or the report of a replan).
fn compare_fisher(
    steps: u64,
    objective: &str,
) -> Result<(ExplorerCounters, Vec<FisherReport>), String> {
    const SIZE: u32 = 48;
    const LAG: u64 = 2;
    let spec = SceneSpec {
        max_rooms: Some(3),
        max_area: Some(40.0),
        ..SceneSpec::new("house:7")
    };
    let mut sim = spec
        .simulator(SimConfig::with_resolution(SIZE, SIZE))
        .unwrap();
    let (planner_config, scorer_config) = fisher_configs(SIZE, LAG);
    let mut explorer_scorer = scorer_config.clone();
    explorer_scorer.fisher.objective =
        serde_json::from_value(serde_json::json!(objective)).unwrap();
    let mut mapper = Mapper::from_config(
        serde_json::from_value(serde_json::json!({
            "map_lag": LAG, "keyframe_min_interval": 10, "iterations": 3
        }))
        .unwrap(),
    )
    .unwrap();
    let mut explorer = Explorer::with_policies(
        ExplorerConfig::default(),
        Point2::new(-2.0, -2.0),
        Point2::new(2.0, 2.0),
        GoalPolicy::new(&planner_config, "planner", None, &no_recordings)
            .unwrap()
            .with_log(activemap_policy::no_log),
        PathPolicy::new(&explorer_scorer).unwrap(),
    )
    .unwrap();
    let mut pipeline = FisherPipeline::new(&planner_config, &scorer_config);
    let mut replans = 0;
    for k in 0..steps {
        let frame = sim.render();
        let camera = pose_from_wire(&pose_to_wire(&sim.true_pose())).unwrap();
        let stamp = k as f64 * 0.1;
        // The mapper: frame k at its (true) estimate; the snapshots frame k lets out.
        let slam_frame = activemap_slam::Frame::from_rgb8(
            frame.intrinsics,
            &frame.rgb,
            frame.depth.clone(),
            stamp,
        )
        .unwrap();
        mapper.add_frame(k, slam_frame);
        mapper.add_pose(wire(&estimate(k, stamp, &sim))).unwrap();
        for s in mapper.process_ready(false).unwrap() {
            let header = mapper.wire_header(&s);
            let len = header.payload_len().unwrap();
            let mut storage = vec![0u64; len.div_ceil(8)];
            let buf = &mut bytemuck::cast_slice_mut::<u64, u8>(&mut storage)[..len];
            write_map(buf, header, &s.map, &s.ids).unwrap();
            pipeline.add_map(buf);
            let decode = || Ok(((*s.map).clone(), (*s.ids).clone()));
            explorer
                .add_map(&MapSnapshot {
                    frame_id: s.frame_id,
                    keyframe: header.keyframe(),
                    count: s.map.len() as u64,
                    decode: &decode,
                })
                .unwrap();
        }
        let ours = match explorer
            .step(&frame.depth, &frame.intrinsics, &camera)
            .unwrap()
        {
            Decision::Act(a) => Some(ActionKind::from(a)),
            Decision::Finished => None,
        };
        let theirs = pipeline.step(k, &frame.depth, &sim);
        let counters = (
            explorer.executor().counters,
            pipeline.follower.core().counters(),
        );
        if ours != theirs || counters.0 != counters.1 {
            return Err(format!(
                "step {k}: {ours:?} against {theirs:?}, {counters:?}"
            ));
        }
        if explorer.counters().replans > replans {
            replans = explorer.counters().replans;
            let ours = explorer.last_report().cloned().map(untimed);
            let theirs = pipeline.reports.last().cloned().map(untimed);
            if ours != theirs {
                return Err(format!("report of step {k}: {ours:?} against {theirs:?}"));
            }
        }
        let Some(action) = ours else {
            return Err(format!(
                "the episode ended at step {k} (refine never ends it)"
            ));
        };
        sim.step(match action {
            ActionKind::Forward => SimAction::Forward,
            ActionKind::TurnLeft => SimAction::TurnLeft,
            ActionKind::TurnRight => SimAction::TurnRight,
            ActionKind::Stop => unreachable!("Stop is the end of the episode"),
        });
    }
    Ok((explorer.counters(), pipeline.reports))
}

/// The paper's method without the LLM (`fisher`: largest frontier, refine when none is left,
/// Fisher paths): the explorer running the planner's and the scorer's policies and the
/// pipeline agree on every action, every executor counter and every Fisher report, step by
/// step. Both get the map snapshots of one in-process mapping session (the `mapper`
/// operator's core, fed the simulator's true poses: SLAM is not under test) with map lag 2,
/// the pipeline as wire messages, the explorer as the session's maps. The comparison is sharp:
/// an explorer whose scorer drops the localisation term (`eig_only`) is caught.
#[test]
fn fisher_explorer_and_pipeline_take_the_same_actions() {
    let (counters, reports) = compare_fisher(200, "paper").unwrap();
    eprintln!("fisher: {counters:?}, {} reports", reports.len());
    assert_eq!(counters.replans, reports.len(), "one report per replan");
    assert!(
        counters.plans >= 3,
        "too few paths to compare: {counters:?}"
    );
    assert!(
        reports.iter().any(|r| r.fallback.is_none()),
        "no replan chose a Fisher path"
    );
    let eig_only = compare_fisher(200, "eig_only").expect_err("eig_only goes unnoticed");
    assert!(eig_only.starts_with("report of step"), "{eig_only}");
}
