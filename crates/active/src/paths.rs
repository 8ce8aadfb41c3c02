//! Paths to the top candidates and their scores (SPEC §5 "Path EIG", "Path objective"; §6
//! "A*", "Follower").
//!
//! A path is the planning library's shortest path (A* with 3-cell moves, robot-width clearance
//! and proximity cost, then shortcutting) to the candidate's cell, its last waypoint facing the
//! goal point. Its future poses `x_1..x_T` are those the robot would visit: the planning
//! library's [`PathExecutor`] (the follower operator's own state machine: greedy turns and
//! moves, the look turn at the end) driven with the robot's forward model on the current grid.
//! Every `stride`-th pose (and the last) is scored, optionally only up to `max_actions`.

use std::collections::HashMap;

use activemap_geometry::{PlanarPose, RobotModel};
use activemap_planning::OccupancyGrid;
use activemap_planning::astar::AstarConfig;
use activemap_planning::clearance::ClearanceMap;
use activemap_planning::executor::{Decision, ExecutorConfig, PathExecutor};
use activemap_planning::path::{PlannedPath, shortest_path_on};
use nalgebra::Point2;

use crate::ActiveError;
use crate::config::{FisherConfig, PathObjective};
use crate::information::{Diagonal, Prior, ViewInformation, eig, localisation_cost};

/// A candidate's path and the poses the robot would visit following it.
#[derive(Debug, Clone, PartialEq)]
pub struct FuturePath {
    /// The path as the follower gets it.
    pub path: PlannedPath,
    /// The pose after each action, in order (`x_1..x_T`).
    pub poses: Vec<PlanarPose>,
}

/// The path from `start` to the cell of `goal`, facing `focus` at the end, and its future
/// poses (at most `max_steps` actions); `None` when A* finds no path or the goal is off the
/// grid. `clear` is the clearance map of `grid` (built once for all the paths of a replan).
pub fn future_path(
    grid: &OccupancyGrid,
    clear: &ClearanceMap,
    start: &PlanarPose,
    goal: &PlanarPose,
    focus: Point2<f64>,
    robot: &RobotModel,
    max_steps: usize,
) -> Result<Option<FuturePath>, ActiveError> {
    let cell = grid.geometry.cell_of(Point2::new(goal.x, goal.y));
    if !grid.geometry.contains(cell) {
        return Ok(None);
    }
    let Some(path) = shortest_path_on(
        clear,
        grid,
        Point2::new(start.x, start.y),
        cell,
        focus,
        &AstarConfig::default(),
    )?
    else {
        return Ok(None);
    };
    let poses = follow(grid, start, &path.waypoints, robot, max_steps)?;
    Ok(Some(FuturePath { path, poses }))
}

/// The poses the follower's executor visits on `waypoints` from `start` under the forward
/// model (no spin at the start; it stops at its first replan request or after `max_steps`).
/// An empty path gives no pose.
pub fn follow(
    grid: &OccupancyGrid,
    start: &PlanarPose,
    waypoints: &[PlanarPose],
    robot: &RobotModel,
    max_steps: usize,
) -> Result<Vec<PlanarPose>, ActiveError> {
    if waypoints.is_empty() {
        return Ok(Vec::new());
    }
    let mut executor = PathExecutor::new(
        ExecutorConfig {
            initial_spin_steps: 0,
            ..ExecutorConfig::default()
        },
        *robot,
    )?;
    executor.set_path(waypoints)?;
    let mut pose = *start;
    let mut poses = Vec::new();
    for _ in 0..max_steps {
        match executor.decide(&pose, grid, false)? {
            Decision::Replan(_) => break,
            Decision::Act(a) => {
                pose = robot.apply(&pose, a);
                poses.push(pose);
            }
        }
    }
    Ok(poses)
}

/// The 1-based steps of a path of `actions` actions that are scored: every `stride`-th up to
/// `max_actions` (when set), and the last step of that range.
pub fn scored_steps(actions: usize, stride: usize, max_actions: Option<usize>) -> Vec<usize> {
    let end = max_actions.map_or(actions, |m| m.min(actions));
    let stride = stride.max(1);
    let mut steps: Vec<usize> = (stride..=end).step_by(stride).collect();
    if end > 0 && steps.last() != Some(&end) {
        steps.push(end);
    }
    steps
}

/// The prior along a path: `I + λ` plus the views already planned (SPEC §5:
/// `I_{P,i} = I + Σ_{t<i} H(x_t)`), kept as a sparse overlay on the shared dense prior.
pub struct PathPrior<'a> {
    base: &'a [Diagonal],
    added: HashMap<u32, Diagonal>,
}

impl<'a> PathPrior<'a> {
    /// The prior before any view of the path.
    pub fn new(base: &'a [Diagonal]) -> Self {
        Self {
            base,
            added: HashMap::new(),
        }
    }

    /// Counts `view` as observed (the next pose's EIG is against it too).
    pub fn observe(&mut self, view: &ViewInformation) {
        for (i, h) in &view.diagonal {
            let entry = self.added.entry(*i).or_insert([0.0; 14]);
            for (e, v) in entry.iter_mut().zip(h) {
                *e += v;
            }
        }
    }
}

impl Prior for PathPrior<'_> {
    fn prior(&self, index: u32) -> Diagonal {
        let mut p = self.base[index as usize];
        if let Some(a) = self.added.get(&index) {
            for (p, a) in p.iter_mut().zip(a) {
                *p += a;
            }
        }
        p
    }
}

/// Path EIG (against the accumulating prior) and C_local of each view of a path, in order.
pub fn path_terms<V: std::borrow::Borrow<ViewInformation>>(
    views: &[V],
    prior: &[Diagonal],
    degenerate_ratio: f64,
) -> (Vec<f64>, Vec<f64>) {
    let mut along = PathPrior::new(prior);
    let mut eigs = Vec::with_capacity(views.len());
    let mut costs = Vec::with_capacity(views.len());
    for v in views {
        let v = v.borrow();
        eigs.push(eig(v, &along));
        costs.push(match (&v.pose, v.is_empty()) {
            (Some(pose), false) => localisation_cost(pose, degenerate_ratio),
            _ => f64::INFINITY,
        });
        along.observe(v);
    }
    (eigs, costs)
}

/// The smallest EIG the `eig_only` objective takes the log of: a blind pose is very costly
/// there, but does not refuse the whole path (the paper objective refuses it through C_local).
pub const EIG_FLOOR: f64 = 1e-12;

/// The objective of a path from its terms (lower is better, +∞ refuses it, never NaN):
/// `paper` (and the `random` and `first` ablations, which choose differently) `Σ_i [C_local_i −
/// η·ln EIG_i]`; `eig_only` `−η·Σ_i ln max(EIG_i, EIG_FLOOR)`;
/// `release` `−[mean_i(−0.2·C_local_i + ln EIG_i) + 60·EIG_T]`. A path with no scored pose
/// costs +∞.
pub fn objective(eigs: &[f64], costs: &[f64], config: &FisherConfig) -> f64 {
    if eigs.is_empty() {
        return f64::INFINITY;
    }
    let value = match config.objective {
        PathObjective::Paper | PathObjective::Random | PathObjective::First => eigs
            .iter()
            .zip(costs)
            .map(|(e, c)| {
                if *e > 0.0 && c.is_finite() {
                    c - config.eta * e.ln()
                } else {
                    f64::INFINITY
                }
            })
            .sum::<f64>(),
        PathObjective::EigOnly => {
            -config.eta * eigs.iter().map(|e| e.max(EIG_FLOOR).ln()).sum::<f64>()
        }
        PathObjective::Release => {
            let mut sum = 0.0;
            for (e, c) in eigs.iter().zip(costs) {
                if !(*e > 0.0 && c.is_finite()) {
                    return f64::INFINITY;
                }
                sum += -0.2 * c + e.ln();
            }
            let end = *eigs.last().expect("non-empty");
            -(sum / eigs.len() as f64 + 60.0 * end)
        }
    };
    if value.is_nan() { f64::INFINITY } else { value }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_planning::clearance::ClearanceConfig;
    use activemap_planning::{CellState, GridGeometry};
    use nalgebra::Matrix6;

    #[test]
    fn scored_steps_follow_the_stride_and_keep_the_last() {
        assert_eq!(scored_steps(12, 5, None), vec![5, 10, 12]);
        assert_eq!(scored_steps(10, 5, None), vec![5, 10]);
        assert_eq!(scored_steps(3, 5, None), vec![3]);
        assert_eq!(scored_steps(40, 5, Some(30)), vec![5, 10, 15, 20, 25, 30]);
        assert_eq!(scored_steps(4, 1, None), vec![1, 2, 3, 4]);
        assert!(scored_steps(0, 5, None).is_empty());
    }

    /// Seeing the same view twice gains strictly less the second time, exactly as the formula
    /// says: EIG_2 = Σ h/(p + h) against EIG_1 = Σ h/p.
    #[test]
    fn the_same_view_twice_gains_less_the_second_time() {
        let view = ViewInformation {
            diagonal: vec![(0, [2.0; 14]), (2, [0.5; 14])],
            pose: Some(Matrix6::identity()),
        };
        let prior = vec![[1.0; 14], [3.0; 14], [0.25; 14]];
        let (eigs, costs) = path_terms(&[view.clone(), view.clone()], &prior, 1e-9);
        let first = 14.0 * (2.0 / 1.0 + 0.5 / 0.25);
        let second = 14.0 * (2.0 / 3.0 + 0.5 / 0.75);
        assert!((eigs[0] - first).abs() < 1e-12);
        assert!((eigs[1] - second).abs() < 1e-12);
        assert!(eigs[1] < eigs[0]);
        assert_eq!(costs, vec![0.0, 0.0]);
        // The empty view: no information, C_local +∞.
        let (e, c) = path_terms(&[ViewInformation::default()], &prior, 1e-9);
        assert_eq!(e, vec![0.0]);
        assert_eq!(c, vec![f64::INFINITY]);
    }

    /// The objectives: the paper's sum, the EIG-only sum with its floor, the release's
    /// mean-plus-end score; +∞ (never NaN) when a pose is blind.
    #[test]
    fn objectives_follow_their_formulas() {
        let mut config = FisherConfig::default();
        let eigs = [2.0, 0.5];
        let costs = [-3.0, 1.0];
        let paper = objective(&eigs, &costs, &config);
        assert!((paper - (-3.0 - 5.0 * 2f64.ln() + 1.0 - 5.0 * 0.5f64.ln())).abs() < 1e-12);
        assert_eq!(objective(&[2.0, 0.0], &costs, &config), f64::INFINITY);
        assert_eq!(
            objective(&eigs, &[-3.0, f64::INFINITY], &config),
            f64::INFINITY
        );
        assert_eq!(objective(&[], &[], &config), f64::INFINITY);
        config.objective = PathObjective::EigOnly;
        let only = objective(&eigs, &[f64::INFINITY; 2], &config);
        assert!((only - (-5.0 * (2f64.ln() + 0.5f64.ln()))).abs() < 1e-12);
        let blind = objective(&[0.0], &[f64::INFINITY], &config);
        assert!((blind - (-5.0 * EIG_FLOOR.ln())).abs() < 1e-9);
        config.objective = PathObjective::Release;
        let release = objective(&eigs, &costs, &config);
        let mean = ((0.6 + 2f64.ln()) + (-0.2 + 0.5f64.ln())) / 2.0;
        assert!((release + mean + 60.0 * 0.5).abs() < 1e-12);
    }

    /// The future poses are the executor's: on an open grid the robot turns toward the first
    /// waypoint, drives, and ends near the goal facing the focus (within the look-turn rule).
    #[test]
    fn future_poses_reach_the_goal() {
        let geometry = GridGeometry::new(-2.0, -2.0, 0.05, 80, 80).unwrap();
        let grid = OccupancyGrid::filled(geometry, CellState::Free);
        let robot = RobotModel::default();
        let start = PlanarPose::new(0.0, 0.0, 0.0);
        let goal = PlanarPose::new(0.0, 1.0, 0.0);
        let focus = Point2::new(1.0, 1.0);
        let clearance = ClearanceConfig::for_disc(robot.radius_m, 0.05).unwrap();
        let clear = ClearanceMap::new(&grid, &clearance).unwrap();
        let f = future_path(&grid, &clear, &start, &goal, focus, &robot, 500)
            .unwrap()
            .unwrap();
        let end = *f.poses.last().unwrap();
        assert!((end.x - 0.0).hypot(end.y - 1.0) < 0.15, "{end:?}");
        let facing = (focus.y - end.y).atan2(focus.x - end.x);
        assert!(activemap_geometry::robot::wrap_angle(end.yaw - facing).abs() < 26f64.to_radians());
        // Turning ~90° left first, then about 20 forward moves, then the look turn.
        assert!(
            f.poses.len() > 20 + 15 && f.poses.len() < 80,
            "{}",
            f.poses.len()
        );
        assert!(follow(&grid, &start, &[], &robot, 10).unwrap().is_empty());
    }
}
