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

/// The objective of a path from its terms (lower is better, +∞ refuses it, never NaN), SPEC §5
/// "Path objective": `paper` (and the `random` and `first` ablations, which choose
/// differently) `Σ_i [C_local_i − η·ln EIG_i − w_low·low_i] + w_end·(C_local_T − η·ln EIG_T)`;
/// `eig_only` the same without C_local and with `ln max(EIG_i, EIG_FLOOR)`; `release`
/// `−[mean_i(−0.2·C_local_i + ln EIG_i + w_low·low_i) + 60·EIG_T]`. `low` is each scored
/// pose's low-opacity pixel count (scaled to the frame, see [`FisherConfig::low_opacity_weight`];
/// empty: none), `w_low` and `w_end` the config's `low_opacity_weight` and `end_weight`. A path
/// with no scored pose costs +∞.
pub fn objective(eigs: &[f64], costs: &[f64], low: &[f64], config: &FisherConfig) -> f64 {
    if eigs.is_empty() {
        return f64::INFINITY;
    }
    let w_low = config.low_opacity_weight;
    let coverage = |i: usize| {
        if w_low == 0.0 {
            0.0
        } else {
            w_low * low.get(i).copied().unwrap_or(0.0)
        }
    };
    let last = eigs.len() - 1;
    let value = match config.objective {
        PathObjective::Paper | PathObjective::Random | PathObjective::First => {
            let term = |e: f64, c: f64| {
                if e > 0.0 && c.is_finite() {
                    c - config.eta * e.ln()
                } else {
                    f64::INFINITY
                }
            };
            let mut sum = 0.0;
            for (i, (e, c)) in eigs.iter().zip(costs).enumerate() {
                sum += term(*e, *c) - coverage(i);
            }
            if config.end_weight != 0.0 {
                sum += config.end_weight * term(eigs[last], costs[last]);
            }
            sum
        }
        PathObjective::EigOnly => {
            let term = |e: f64| -config.eta * e.max(EIG_FLOOR).ln();
            let mut sum = 0.0;
            for (i, e) in eigs.iter().enumerate() {
                sum += term(*e) - coverage(i);
            }
            if config.end_weight != 0.0 {
                sum += config.end_weight * term(eigs[last]);
            }
            sum
        }
        PathObjective::Release => {
            let mut sum = 0.0;
            for (i, (e, c)) in eigs.iter().zip(costs).enumerate() {
                if !(*e > 0.0 && c.is_finite()) {
                    return f64::INFINITY;
                }
                sum += -0.2 * c + e.ln() + coverage(i);
            }
            -(sum / eigs.len() as f64 + 60.0 * eigs[last])
        }
    };
    if value.is_nan() { f64::INFINITY } else { value }
}

/// Path EIG and C_local of many paths at once, the same numbers as [`path_terms`] on each
/// (bit for bit), with the work of shared prefixes done once (SPEC §5 "Path EIG"). `views` are
/// the distinct scored views; each path is a sequence of indices into them. Paths to nearby
/// candidates start with the same moves from the same pose, so their sequences share
/// prefixes: the sequences form a trie, walked depth first with one dense accumulator
/// `Σ_{t<i} H(x_t)` per Gaussian; a node's EIG is computed once for every path through it,
/// and leaving a node restores the entries it changed (saved, not subtracted, so no rounding
/// creeps in). Work: one pass over a view's diagonal per trie node, not per path and pose.
/// `C_local` is a view's own, computed once per distinct view.
pub fn shared_path_terms(
    views: &[ViewInformation],
    sequences: &[Vec<usize>],
    prior: &[Diagonal],
    degenerate_ratio: f64,
) -> Vec<(Vec<f64>, Vec<f64>)> {
    let costs: Vec<f64> = views
        .iter()
        .map(|v| match (&v.pose, v.is_empty()) {
            (Some(pose), false) => localisation_cost(pose, degenerate_ratio),
            _ => f64::INFINITY,
        })
        .collect();
    // The trie: node 0 is the root (no view); a node's children by view index.
    let mut slot = vec![usize::MAX];
    let mut children: Vec<Vec<(usize, usize)>> = vec![Vec::new()];
    let mut nodes_of: Vec<Vec<usize>> = Vec::with_capacity(sequences.len());
    for seq in sequences {
        let mut at = 0;
        let mut nodes = Vec::with_capacity(seq.len());
        for &k in seq {
            at = match children[at].iter().find(|(v, _)| *v == k) {
                Some(&(_, child)) => child,
                None => {
                    let child = slot.len();
                    slot.push(k);
                    children.push(Vec::new());
                    children[at].push((k, child));
                    child
                }
            };
            nodes.push(at);
        }
        nodes_of.push(nodes);
    }
    let mut node_eig = vec![0.0; slot.len()];
    let mut added: Vec<Diagonal> = vec![[0.0; crate::information::PARAMS]; prior.len()];
    let mut undo: Vec<(u32, Diagonal)> = Vec::new();
    // Depth-first: Enter(node) computes its EIG and, when it has children, observes its view;
    // Leave(mark) restores what the node changed.
    enum Step {
        Enter(usize),
        Leave(usize),
    }
    let mut stack: Vec<Step> = children[0]
        .iter()
        .rev()
        .map(|&(_, c)| Step::Enter(c))
        .collect();
    while let Some(step) = stack.pop() {
        match step {
            Step::Enter(node) => {
                let view = &views[slot[node]];
                node_eig[node] = view
                    .diagonal
                    .iter()
                    .map(|(i, h)| {
                        let (base, a) = (&prior[*i as usize], &added[*i as usize]);
                        let mut sum = 0.0;
                        for p in 0..h.len() {
                            sum += h[p] / (base[p] + a[p]);
                        }
                        sum
                    })
                    .sum();
                if !children[node].is_empty() {
                    stack.push(Step::Leave(undo.len()));
                    for (i, h) in &view.diagonal {
                        let a = &mut added[*i as usize];
                        undo.push((*i, *a));
                        for (a, h) in a.iter_mut().zip(h) {
                            *a += h;
                        }
                    }
                    stack.extend(children[node].iter().rev().map(|&(_, c)| Step::Enter(c)));
                }
            }
            Step::Leave(mark) => {
                for (i, old) in undo.drain(mark..).rev() {
                    added[i as usize] = old;
                }
            }
        }
    }
    sequences
        .iter()
        .zip(&nodes_of)
        .map(|(seq, nodes)| {
            (
                nodes.iter().map(|&n| node_eig[n]).collect(),
                seq.iter().map(|&k| costs[k]).collect(),
            )
        })
        .collect()
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
            low_opacity_pixels: 0,
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
        let paper = objective(&eigs, &costs, &[], &config);
        assert!((paper - (-3.0 - 5.0 * 2f64.ln() + 1.0 - 5.0 * 0.5f64.ln())).abs() < 1e-12);
        assert_eq!(objective(&[2.0, 0.0], &costs, &[], &config), f64::INFINITY);
        assert_eq!(
            objective(&eigs, &[-3.0, f64::INFINITY], &[], &config),
            f64::INFINITY
        );
        assert_eq!(objective(&[], &[], &[], &config), f64::INFINITY);
        config.objective = PathObjective::EigOnly;
        let only = objective(&eigs, &[f64::INFINITY; 2], &[], &config);
        assert!((only - (-5.0 * (2f64.ln() + 0.5f64.ln()))).abs() < 1e-12);
        let blind = objective(&[0.0], &[f64::INFINITY], &[], &config);
        assert!((blind - (-5.0 * EIG_FLOOR.ln())).abs() < 1e-9);
        config.objective = PathObjective::Release;
        let release = objective(&eigs, &costs, &[], &config);
        let mean = ((0.6 + 2f64.ln()) + (-0.2 + 0.5f64.ln())) / 2.0;
        assert!((release + mean + 60.0 * 0.5).abs() < 1e-12);
        // The release's coverage term: each scored pose's low-opacity pixels, weighted.
        config.low_opacity_weight = 1e-4;
        let covered = objective(&eigs, &costs, &[1000.0, 3000.0], &config);
        let mean = mean + 1e-4 * (1000.0 + 3000.0) / 2.0;
        assert!((covered + mean + 60.0 * 0.5).abs() < 1e-12);
        // The paper with an end-pose weight and the coverage term.
        config.objective = PathObjective::Paper;
        config.end_weight = 60.0;
        let end = 1.0 - 5.0 * 0.5f64.ln();
        let weighted = objective(&eigs, &costs, &[1000.0, 3000.0], &config);
        assert!((weighted - (paper + 60.0 * end - 1e-4 * 4000.0)).abs() < 1e-9);
    }

    /// The prefix-shared terms are exactly the per-path ones, on sequences that share
    /// prefixes, repeat a view and diverge (overlapping Gaussians, so the order matters).
    #[test]
    fn shared_path_terms_equal_the_per_path_ones() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let n = 40;
        let prior: Vec<Diagonal> = (0..n)
            .map(|_| std::array::from_fn(|_| rng.random_range(0.01..1.0)))
            .collect();
        let views: Vec<ViewInformation> = (0..6)
            .map(|v| {
                let mut diagonal = Vec::new();
                for i in 0..n as u32 {
                    if rng.random_bool(0.5) {
                        diagonal.push((i, std::array::from_fn(|_| rng.random_range(0.0..2.0))));
                    }
                }
                ViewInformation {
                    diagonal,
                    pose: Some(Matrix6::identity() * (1.0 + v as f64)),
                    low_opacity_pixels: 0,
                }
            })
            .collect();
        let sequences = vec![
            vec![0, 1, 2, 3],
            vec![0, 1, 2, 4, 5],
            vec![0, 1, 5],
            vec![0, 1, 2, 3],
            vec![2, 2, 0],
            vec![0],
        ];
        let shared = shared_path_terms(&views, &sequences, &prior, 1e-9);
        for (seq, got) in sequences.iter().zip(&shared) {
            let own: Vec<&ViewInformation> = seq.iter().map(|&k| &views[k]).collect();
            assert_eq!(*got, path_terms(&own, &prior, 1e-9), "{seq:?}");
        }
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
