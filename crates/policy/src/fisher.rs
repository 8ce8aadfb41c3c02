//! The Fisher path choice's bookkeeping (SPEC §5–§6) around
//! [`activemap_active::FisherScorer`], which proposes candidates around the goal's frontier
//! (or, for a refine goal, target −1, around the least-known part of the map), plans paths to
//! the best and picks the one that minimises the objective; each replan gives a
//! [`FisherReport`]. For the goal of frame k it scores on exactly the snapshot of frame
//! k − 1 − L (L = `map_lag`, the mapper's), as the tracker and occupancy do, so a seeded run
//! stays deterministic. A snapshot whose `keyframe` is new announces a keyframe: the library is
//! told ([`FisherScorer::add_keyframe`]) with the estimate of that frame, before the first
//! replan that uses the snapshot. When the library finds no path
//! ([`activemap_active::ReplanOutcome::path`]
//! `None`) it falls back, so that the lockstep loop always gets a path and keeps stepping: for
//! a frontier goal the shortest path, for a refine goal the look-around
//! ([`crate::path::look_around`]); the report says so.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use activemap_active::scorer::ScoringMap;
use activemap_active::{FisherConfig, FisherScorer, GoalRequest, ReplanInput};
use activemap_geometry::frames::planar_from_camera_pose;
use activemap_geometry::snapshots::LaggedSnapshots;
use activemap_geometry::{Intrinsics, Isometry3, RobotModel};
use activemap_planning::OccupancyGrid as PlanGrid;
use activemap_planning::astar::AstarConfig;
use activemap_schemas::{FisherReport, Frontiers, Goal, Path};
use nalgebra::Point2;

use crate::MapSnapshot;
use crate::goal::REFINE_TARGET;
use crate::path::{look_around, path_for_goal};
use crate::wire::path_to_wire;

/// The `fisher` path choice: the library scorer, the map snapshots by frame, the
/// keyframes they announce and the estimated poses those need.
pub struct FisherPaths {
    scorer: FisherScorer,
    robot: RobotModel,
    /// Map snapshots by the last frame they include, from the one the next goal may need on;
    /// snapshots of the same keyframe share one decoded map.
    maps: LaggedSnapshots<Arc<ScoringMap>>,
    /// Keyframes announced by the snapshots and not yet told to the library.
    keyframes: BTreeSet<u64>,
    /// The newest keyframe announced so far.
    newest_keyframe: Option<u64>,
    /// Estimated camera poses by frame, from the oldest keyframe not yet told on.
    poses: BTreeMap<u64, Isometry3<f64>>,
}

impl FisherPaths {
    /// The scorer with settings `fisher` for `robot`, whose map was built from frames of
    /// `camera`, scoring the goal of frame k on the snapshot of frame k − 1 − `map_lag`.
    pub fn new(
        fisher: FisherConfig,
        robot: RobotModel,
        camera: Intrinsics,
        map_lag: u64,
    ) -> anyhow::Result<Self> {
        let scorer =
            FisherScorer::new(fisher, robot, camera).map_err(|e| anyhow::anyhow!("scorer: {e}"))?;
        Ok(Self {
            scorer,
            robot,
            maps: LaggedSnapshots::new(map_lag),
            keyframes: BTreeSet::new(),
            newest_keyframe: None,
            poses: BTreeMap::new(),
        })
    }

    /// Stores a map snapshot (decoded only when its keyframe is new: snapshots of the same
    /// keyframe hold the same map) and notes the keyframe it announces.
    pub fn add_map(&mut self, snapshot: &MapSnapshot<'_>) -> anyhow::Result<()> {
        let k = snapshot.frame_id;
        let keyframe = snapshot.keyframe;
        self.maps.insert_reusing(
            k,
            |m| {
                keyframe.is_some_and(|j| m.frame_id == j)
                    && m.gaussians.len() as u64 == snapshot.count
            },
            || {
                let (gaussians, ids) = (snapshot.decode)()?;
                let map = ScoringMap {
                    gaussians: Arc::new(gaussians),
                    ids: Arc::new(ids),
                    // The map's version: the keyframe that made it (the snapshot of that frame).
                    frame_id: keyframe.unwrap_or(k),
                };
                map.validate()
                    .map_err(|e| anyhow::anyhow!("scorer: map snapshot of frame {k}: {e}"))?;
                Ok::<_, anyhow::Error>(Arc::new(map))
            },
        )?;
        if let Some(j) = keyframe
            && self.newest_keyframe.is_none_or(|n| j > n)
        {
            self.newest_keyframe = Some(j);
            self.keyframes.insert(j);
        }
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
        self.maps.for_frame(k)
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
        let needed = self.maps.needed(k);
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
                    &AstarConfig::default(),
                )?;
                let what = if path.waypoints.is_empty() {
                    "shortest path to the frontier (none found either)"
                } else {
                    "shortest path to the frontier"
                };
                (path, Some(format!("{what}: no Fisher path")))
            }
        };
        // Later goals are of later frames: older snapshots and poses are no longer needed.
        self.maps.retain_needed_from(k);
        self.poses = self.poses.split_off(&(needed + 1));
        let report = FisherReport {
            fallback,
            ..FisherReport::from(&outcome)
        };
        Ok((path, report))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_geometry::PlanarPose;
    use activemap_planning::grid::{Cell, CellState, GridGeometry};
    use activemap_schemas::{FisherTimings, FrontierRegion};

    /// A map snapshot of frame `frame` whose newest keyframe is `keyframe`, `n` Gaussians on
    /// a wall at x = 2 m with ids `first_id..`; `decoded` counts the decodings.
    fn add_wall(
        fisher: &mut FisherPaths,
        frame: u64,
        keyframe: Option<u64>,
        n: usize,
        first_id: u64,
    ) -> anyhow::Result<()> {
        let decode = || {
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
            Ok((g, (first_id..first_id + n as u64).collect()))
        };
        fisher.add_map(&MapSnapshot {
            frame_id: frame,
            keyframe,
            count: n as u64,
            decode: &decode,
        })
    }

    fn fisher_paths(map_lag: u64) -> FisherPaths {
        let config: FisherConfig = serde_json::from_value(serde_json::json!({
            "candidates": 24, "top_candidates": 3, "mc_poses": 4, "mc_refresh": 2, "scoring_width": 16
        }))
        .unwrap();
        let camera = Intrinsics::from_hfov(64, 64, std::f64::consts::FRAC_PI_2);
        FisherPaths::new(config, RobotModel::default(), camera, map_lag).unwrap()
    }

    /// The goal of frame k waits for exactly snapshot k − 1 − L (never a newer or older one
    /// that happens to be there); snapshots of the same keyframe share one decoded map, whose
    /// version is the keyframe's frame; each new keyframe is announced once; a map whose ids
    /// do not fit is refused naming its frame.
    #[test]
    fn goals_wait_for_their_lagged_snapshot_and_keyframes_are_noted_once() {
        let mut fisher = fisher_paths(2);
        add_wall(&mut fisher, 0, None, 0, 0).unwrap();
        add_wall(&mut fisher, 1, Some(1), 40, 0).unwrap();
        add_wall(&mut fisher, 2, Some(1), 40, 0).unwrap();
        add_wall(&mut fisher, 3, Some(1), 40, 0).unwrap();
        assert!(
            fisher.snapshot_for(7).is_none(),
            "snapshot 4 has not arrived"
        );
        add_wall(&mut fisher, 4, Some(4), 60, 0).unwrap();
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
        let bad = activemap_active::unknown::UNKNOWN_ID_BASE;
        let e = add_wall(&mut fisher, 5, Some(5), 3, bad)
            .unwrap_err()
            .to_string();
        assert!(e.contains("frame 5") && e.contains("unknown-space"), "{e}");
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
            let mut fisher = fisher_paths(0);
            for k in 0..=19 {
                fisher.add_pose(k, pose);
                let keyframe = if k >= 5 { 5 } else { 0 };
                add_wall(
                    &mut fisher,
                    k,
                    Some(keyframe),
                    if k >= 5 { 120 } else { 60 },
                    0,
                )
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
                        let shortest = path_for_goal(
                            &grid,
                            Point2::new(0.5, 1.0),
                            &frontiers,
                            &goal,
                            &robot,
                            &AstarConfig::default(),
                        )
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
}
