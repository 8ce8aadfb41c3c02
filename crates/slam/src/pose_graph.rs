//! Keyframe pose graph: the tracker's reference keyframes as nodes (`T_world_keyframe`), and
//! relative-pose measurements between them as edges, solved by Levenberg–Marquardt with a sparse
//! Cholesky factorisation of the normal equations (faer).
//!
//! Why: the dense tracker aligns each frame to the newest reference and to older ones of the
//! same place ([`crate::references`]); the second is a loop closure, but it moves only the
//! current estimate. The references between the two ends of the loop keep the drift of their
//! time, and a later frame aligned to one of them inherits it again. The graph spreads the
//! correction along the whole chain, weighted by how well each pair was aligned.
//!
//! An edge from node i to node j measures `Z = T_i⁻¹·T_j` (the pose of j in the frame of i)
//! and the information `Ω` (inverse covariance) of its residual. The residual is `r = Log(Z⁻¹·T_i⁻¹·T_j)` (SPEC §2 tangent, τ = [ρ, θ]); with
//! the left update `T ← Exp(δ)·T` of SPEC §2,
//!
//! - `∂r/∂δ_j = J_r⁻¹(r)·Ad(T_j⁻¹)` and `∂r/∂δ_i = −J_r⁻¹(r)·Ad(T_j⁻¹)`,
//!
//! since `Exp(δ)·T_j = T_j·Exp(Ad(T_j⁻¹)·δ)` and `Log(Exp(r)·Exp(ε)) ≈ r + J_r⁻¹(r)·ε`
//! ([`se3::se3_right_jacobian_inv`]). The cost is `Σ ρ(rᵀΩr)` with a Huber `ρ` on the
//! Mahalanobis distance (a wrong loop edge pulls linearly, not quadratically). Node 0 is held
//! fixed: it anchors the world, as the first frame does for the tracker.

use std::collections::BTreeMap;

use activemap_geometry::{Isometry3, se3};
use faer::linalg::solvers::Solve;
use faer::sparse::{SparseColMat, Triplet};
use faer::{Mat, Side};
use nalgebra::{Matrix6, Vector6};

use crate::error::SlamError;
use crate::session::finite_pose;

/// The 6×6 blocks of the normal equations' lower triangle, by (row, column) variable block.
type Blocks = BTreeMap<(usize, usize), Matrix6<f64>>;

/// Settings of [`PoseGraph::optimise`].
#[derive(Debug, Clone, PartialEq)]
pub struct PoseGraphConfig {
    /// Most Levenberg–Marquardt iterations per optimisation.
    pub max_iterations: usize,
    /// Stop once the largest step component falls below this (metres or radians).
    pub convergence: f64,
    /// Huber threshold on an edge's Mahalanobis distance `√(rᵀΩr)` (∞ = plain least squares).
    pub huber: f64,
}

impl Default for PoseGraphConfig {
    fn default() -> Self {
        Self {
            max_iterations: 20,
            convergence: 1e-7,
            huber: 3.0,
        }
    }
}

impl PoseGraphConfig {
    /// Checks ranges; names the offending field.
    pub fn validate(&self) -> Result<(), SlamError> {
        SlamError::require_positive(&[("pose_graph.convergence", self.convergence)])?;
        if self.huber.is_nan() || self.huber <= 0.0 {
            return Err(SlamError::Config {
                field: "pose_graph.huber",
                value: self.huber.to_string(),
                reason: "must be > 0 (∞ for no robust kernel)",
            });
        }
        if self.max_iterations == 0 {
            return Err(SlamError::Config {
                field: "pose_graph.max_iterations",
                value: "0".into(),
                reason: "must be at least 1",
            });
        }
        Ok(())
    }
}

/// A relative-pose measurement between two nodes.
#[derive(Debug, Clone, PartialEq)]
pub struct Edge {
    /// Node i.
    pub from: usize,
    /// Node j.
    pub to: usize,
    /// Measured `Z = T_i⁻¹·T_j`.
    pub measured: Isometry3<f64>,
    /// Information of the residual `Log(Z⁻¹·T_i⁻¹·T_j)` (symmetric, positive semi-definite).
    pub information: Matrix6<f64>,
}

/// What one [`PoseGraph::optimise`] did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Optimised {
    /// Iterations run (accepted or not).
    pub iterations: usize,
    /// Robust cost before.
    pub initial_cost: f64,
    /// Robust cost after.
    pub final_cost: f64,
    /// Whether the step fell below the threshold.
    pub converged: bool,
}

/// The graph (see the module doc).
#[derive(Debug, Clone, Default)]
pub struct PoseGraph {
    poses: Vec<Isometry3<f64>>,
    edges: Vec<Edge>,
}

impl PoseGraph {
    /// An empty graph.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a node at `pose`; returns its index (node 0 is the fixed anchor).
    pub fn add_node(&mut self, pose: Isometry3<f64>) -> Result<usize, SlamError> {
        if !finite_pose(&pose) {
            return Err(SlamError::Input {
                what: "pose graph node",
                reason: format!("node {} has a non-finite pose", self.poses.len()),
            });
        }
        self.poses.push(se3::normalized(&pose));
        Ok(self.poses.len() - 1)
    }

    /// Adds a measurement; refuses unknown nodes, a self-loop, and non-finite values.
    pub fn add_edge(&mut self, edge: Edge) -> Result<(), SlamError> {
        let n = self.poses.len();
        let bad = |reason: String| {
            Err(SlamError::Input {
                what: "pose graph edge",
                reason,
            })
        };
        if edge.from >= n || edge.to >= n || edge.from == edge.to {
            return bad(format!(
                "edge {} → {} in a graph of {n} nodes",
                edge.from, edge.to
            ));
        }
        if !finite_pose(&edge.measured) || edge.information.iter().any(|v| !v.is_finite()) {
            return bad(format!(
                "edge {} → {} has a non-finite measurement or information",
                edge.from, edge.to
            ));
        }
        self.edges.push(Edge {
            measured: se3::normalized(&edge.measured),
            information: (edge.information + edge.information.transpose()) * 0.5,
            ..edge
        });
        Ok(())
    }

    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// Whether the graph has no node.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// The current estimate of node `i`.
    pub fn pose(&self, i: usize) -> Isometry3<f64> {
        self.poses[i]
    }

    /// All node estimates, by index.
    pub fn poses(&self) -> &[Isometry3<f64>] {
        &self.poses
    }

    /// The edges, in the order added.
    pub fn edges(&self) -> &[Edge] {
        &self.edges
    }

    /// The residual `Log(Z⁻¹·T_i⁻¹·T_j)` of `edge` at the poses `poses`.
    pub fn residual_at(poses: &[Isometry3<f64>], edge: &Edge) -> Vector6<f64> {
        se3::log(&(edge.measured.inverse() * poses[edge.from].inverse() * poses[edge.to]))
    }

    /// The residual of `edge` at the current estimate.
    pub fn residual(&self, edge: &Edge) -> Vector6<f64> {
        Self::residual_at(&self.poses, edge)
    }

    /// `(∂r/∂δ_i, ∂r/∂δ_j)` of `edge` at `poses` (see the module doc).
    pub fn jacobians_at(poses: &[Isometry3<f64>], edge: &Edge) -> (Matrix6<f64>, Matrix6<f64>) {
        Self::jacobians_with_residual(poses, edge, &Self::residual_at(poses, edge))
    }

    /// [`PoseGraph::jacobians_at`] given the edge's residual `r` at `poses` (computed once by
    /// the caller that also needs it).
    fn jacobians_with_residual(
        poses: &[Isometry3<f64>],
        edge: &Edge,
        r: &Vector6<f64>,
    ) -> (Matrix6<f64>, Matrix6<f64>) {
        let to_j = se3::se3_right_jacobian_inv(r) * se3::adjoint(&poses[edge.to].inverse());
        (-to_j, to_j)
    }

    /// Robust cost `Σ ρ(rᵀΩr)` at `poses`, with Huber threshold `huber`.
    fn cost_at(&self, poses: &[Isometry3<f64>], huber: f64) -> f64 {
        self.edges
            .iter()
            .map(|e| {
                let r = Self::residual_at(poses, e);
                huber_cost((r.transpose() * e.information * r)[0].max(0.0), huber)
            })
            .sum()
    }

    /// Robust cost at the current estimate.
    pub fn cost(&self, config: &PoseGraphConfig) -> f64 {
        self.cost_at(&self.poses, config.huber)
    }

    /// Levenberg–Marquardt on every node but node 0 (see the module doc). A node that no edge
    /// reaches keeps its pose (the damping holds it). Never makes the cost worse: a step that
    /// would is refused and the damping raised.
    pub fn optimise(&mut self, config: &PoseGraphConfig) -> Result<Optimised, SlamError> {
        config.validate()?;
        let initial_cost = self.cost(config);
        let mut out = Optimised {
            iterations: 0,
            initial_cost,
            final_cost: initial_cost,
            converged: false,
        };
        let n = self.poses.len();
        if n < 2 || self.edges.is_empty() {
            out.converged = true;
            return Ok(out);
        }
        let dim = 6 * (n - 1);
        let mut damping = 1e-4;
        let mut cost = initial_cost;
        while out.iterations < config.max_iterations {
            out.iterations += 1;
            let (blocks, gradient) = self.normal_equations(config.huber);
            let step = match solve(&blocks, &gradient, dim, damping) {
                Some(step) => step,
                None => {
                    damping *= 10.0;
                    continue;
                }
            };
            let mut trial = self.poses.clone();
            for (k, pose) in trial.iter_mut().enumerate().skip(1) {
                let d = Vector6::from_iterator(step[6 * (k - 1)..6 * k].iter().copied());
                *pose = se3::left_update(pose, &d);
            }
            let trial_cost = self.cost_at(&trial, config.huber);
            let largest = step.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            if trial_cost <= cost {
                self.poses = trial;
                cost = trial_cost;
                damping = (damping / 3.0).max(1e-9);
                if largest < config.convergence {
                    out.converged = true;
                    break;
                }
            } else if largest < config.convergence {
                // A step too small to matter that rounding made no better: at the minimum.
                out.converged = true;
                break;
            } else {
                damping *= 4.0;
            }
        }
        out.final_cost = cost;
        Ok(out)
    }

    /// The Gauss–Newton blocks `H` (lower triangle, by variable block `(row ≥ col)`) and the
    /// gradient `g` over nodes 1.., with the Huber weights (IRLS).
    fn normal_equations(&self, huber: f64) -> (Blocks, Vec<f64>) {
        let n = self.poses.len();
        let mut blocks = Blocks::new();
        let mut gradient = vec![0.0; 6 * (n - 1)];
        for e in &self.edges {
            let r = self.residual(e);
            let chi2 = (r.transpose() * e.information * r)[0].max(0.0);
            let w = huber_weight(chi2, huber);
            let omega = e.information * w;
            let (ji, jj) = Self::jacobians_with_residual(&self.poses, e, &r);
            let terms = [(e.from, ji), (e.to, jj)];
            for (a, ja) in &terms {
                if *a == 0 {
                    continue;
                }
                let ga = ja.transpose() * omega * r;
                for k in 0..6 {
                    gradient[6 * (a - 1) + k] += ga[k];
                }
                for (b, jb) in &terms {
                    if *b == 0 || b > a {
                        continue;
                    }
                    // Block (a, b) with a ≥ b: Jaᵀ Ω Jb (for a == b once, both terms equal).
                    let block = ja.transpose() * omega * jb;
                    *blocks.entry((a - 1, b - 1)).or_insert_with(Matrix6::zeros) += block;
                }
            }
        }
        (blocks, gradient)
    }
}

/// Solves `(H + damping·(diag(H) + I))·x = −g` by sparse Cholesky (faer); `None` when the
/// factorisation fails (not positive definite).
fn solve(blocks: &Blocks, gradient: &[f64], dim: usize, damping: f64) -> Option<Vec<f64>> {
    let mut triplets = Vec::with_capacity(blocks.len() * 36);
    let mut diagonal_seen = vec![false; dim / 6];
    for (&(a, b), m) in blocks {
        for r in 0..6 {
            for c in 0..6 {
                let (row, col) = (6 * a + r, 6 * b + c);
                if row < col {
                    continue;
                }
                let mut v = m[(r, c)];
                if row == col {
                    v += damping * (v + 1.0);
                }
                triplets.push(Triplet::new(row, col, v));
            }
        }
        if a == b {
            diagonal_seen[a] = true;
        }
    }
    // A node no edge reaches: the damping alone (its step is then zero).
    for (k, seen) in diagonal_seen.iter().enumerate() {
        if !seen {
            for r in 0..6 {
                triplets.push(Triplet::new(6 * k + r, 6 * k + r, damping));
            }
        }
    }
    let h = SparseColMat::<usize, f64>::try_new_from_triplets(dim, dim, &triplets).ok()?;
    let llt = h.sp_cholesky(Side::Lower).ok()?;
    let mut rhs = Mat::from_fn(dim, 1, |i, _| -gradient[i]);
    llt.solve_in_place(rhs.as_mut());
    let x: Vec<f64> = (0..dim).map(|i| rhs[(i, 0)]).collect();
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Huber cost of a squared Mahalanobis distance: `χ²` inside the threshold `k`, `2kχ − k²`
/// beyond.
fn huber_cost(chi2: f64, k: f64) -> f64 {
    let chi = chi2.sqrt();
    if chi <= k {
        chi2
    } else {
        2.0 * k * chi - k * k
    }
}

/// IRLS weight of the Huber cost: 1 inside the threshold, `k/χ` beyond.
fn huber_weight(chi2: f64, k: f64) -> f64 {
    let chi = chi2.sqrt();
    if chi <= k { 1.0 } else { k / chi }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_geometry::se3::pose_error;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn pose(x: f64, y: f64, yaw: f64) -> Isometry3<f64> {
        se3::exp(&Vector6::new(x, y, 0.0, 0.0, 0.0, yaw))
    }

    fn random_tangent(rng: &mut ChaCha8Rng, scale: f64) -> Vector6<f64> {
        Vector6::from_fn(|_, _| rng.random_range(-scale..scale))
    }

    /// Norm of the central-difference gradient of the least-squares cost over nodes 1.. (left
    /// perturbations, f64).
    fn numeric_gradient(graph: &PoseGraph) -> f64 {
        let h = 1e-6;
        let mut sum = 0.0;
        for node in 1..graph.len() {
            for k in 0..6 {
                let mut d = Vector6::zeros();
                d[k] = h;
                let mut plus = graph.poses().to_vec();
                plus[node] = se3::exp(&d) * plus[node];
                let mut minus = graph.poses().to_vec();
                minus[node] = se3::exp(&-d) * minus[node];
                let g = (graph.cost_at(&plus, f64::INFINITY)
                    - graph.cost_at(&minus, f64::INFINITY))
                    / (2.0 * h);
                sum += g * g;
            }
        }
        sum.sqrt()
    }

    /// The analytic Jacobians of an edge's residual against central differences (f64), at
    /// poses and a measurement far from agreeing (residual rotation ~0.5 rad).
    #[test]
    fn edge_jacobians_match_finite_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(16);
        for _ in 0..5 {
            let poses = vec![
                se3::exp(&random_tangent(&mut rng, 1.0)),
                se3::exp(&random_tangent(&mut rng, 1.0)),
            ];
            let edge = Edge {
                from: 0,
                to: 1,
                measured: se3::exp(&random_tangent(&mut rng, 0.5)) * poses[0].inverse() * poses[1],
                information: Matrix6::identity(),
            };
            let (ji, jj) = PoseGraph::jacobians_at(&poses, &edge);
            let h = 1e-6;
            for (node, analytic) in [(0, ji), (1, jj)] {
                let mut numeric = Matrix6::zeros();
                for k in 0..6 {
                    let mut d = Vector6::zeros();
                    d[k] = h;
                    let mut plus = poses.clone();
                    plus[node] = se3::exp(&d) * poses[node];
                    let mut minus = poses.clone();
                    minus[node] = se3::exp(&-d) * poses[node];
                    numeric.set_column(
                        k,
                        &((PoseGraph::residual_at(&plus, &edge)
                            - PoseGraph::residual_at(&minus, &edge))
                            / (2.0 * h)),
                    );
                }
                let error = (numeric - analytic).norm() / analytic.norm();
                assert!(error < 1e-7, "node {node}: relative error {error}");
            }
        }
    }

    /// A square loop of four 2 m sides driven with a biased odometry (each turn 3° too
    /// far, each step 1 cm too long): the chain alone ends more than 10 cm off. With the
    /// loop edge (the true relative pose of the last node to the first), the solution is a
    /// stationary point of the cost (finite differences), the last node comes back, and the
    /// worst node's error halves (least squares spreads the biased odometry's error over the
    /// loop; it cannot remove it).
    #[test]
    fn a_loop_edge_removes_drift_along_the_whole_chain() {
        let truth: Vec<Isometry3<f64>> = (0..16)
            .map(|k| {
                let side = k / 4;
                let along = (k % 4) as f64 * 0.5;
                let yaw = side as f64 * std::f64::consts::FRAC_PI_2;
                let corner = [(0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0)][side];
                pose(
                    corner.0 + along * yaw.cos(),
                    corner.1 + along * yaw.sin(),
                    yaw,
                )
            })
            .collect();
        let information = Matrix6::from_diagonal(&Vector6::new(1e4, 1e4, 1e4, 1e5, 1e5, 1e5));
        let mut graph = PoseGraph::new();
        graph.add_node(truth[0]).unwrap();
        let mut odometry = Vec::new();
        for k in 1..truth.len() {
            let relative = truth[k - 1].inverse() * truth[k];
            let bias = if k % 4 == 0 {
                se3::exp(&Vector6::new(0.0, 0.0, 0.0, 0.0, 0.0, 3f64.to_radians()))
            } else {
                se3::exp(&Vector6::new(0.01, 0.0, 0.0, 0.0, 0.0, 0.0))
            };
            let measured = relative * bias;
            odometry.push(measured);
            let chained = graph.pose(k - 1) * measured;
            graph.add_node(chained).unwrap();
            graph
                .add_edge(Edge {
                    from: k - 1,
                    to: k,
                    measured,
                    information,
                })
                .unwrap();
        }
        let last = truth.len() - 1;
        let (drift, _) = pose_error(&graph.pose(last), &truth[last]);
        assert!(drift > 0.1, "the chain drifts {drift} m");
        let worst_before = truth
            .iter()
            .enumerate()
            .map(|(k, t)| pose_error(&graph.pose(k), t).0)
            .fold(0.0, f64::max);
        graph
            .add_edge(Edge {
                from: last,
                to: 0,
                measured: truth[last].inverse() * truth[0],
                information,
            })
            .unwrap();
        let config = PoseGraphConfig {
            huber: f64::INFINITY,
            ..PoseGraphConfig::default()
        };
        let before = graph.cost(&config);
        let gradient_before = numeric_gradient(&graph);
        let report = graph.optimise(&config).unwrap();
        // Independent check of optimality: the finite-difference gradient of the cost
        // vanishes at the solution.
        let gradient_after = numeric_gradient(&graph);
        assert!(
            gradient_after < 1e-6 * gradient_before,
            "gradient {gradient_after} after, {gradient_before} before"
        );
        let (end, _) = pose_error(&graph.pose(last), &truth[last]);
        assert!(
            end < drift / 3.0,
            "the last node ends {end} m off, {drift} m before"
        );
        assert!(report.converged, "{report:?}");
        assert!(report.final_cost < 0.1 * before, "{report:?}");
        let worst_after = truth
            .iter()
            .enumerate()
            .map(|(k, t)| pose_error(&graph.pose(k), t).0)
            .fold(0.0, f64::max);
        assert!(
            worst_after < worst_before / 2.0,
            "worst node {worst_after} m after, {worst_before} m before"
        );
        // The anchor never moves.
        assert_eq!(graph.pose(0), se3::normalized(&truth[0]));
    }

    /// Noise-free measurements of a random graph are solved exactly from a perturbed start;
    /// a wrong loop edge under the Huber kernel moves the solution far less than without.
    #[test]
    fn exact_measurements_are_recovered_and_huber_bounds_a_wrong_edge() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let truth: Vec<Isometry3<f64>> = (0..8)
            .map(|_| se3::exp(&random_tangent(&mut rng, 1.5)))
            .collect();
        let information = Matrix6::identity() * 1e4;
        let build = |wrong: bool, rng: &mut ChaCha8Rng| {
            let mut g = PoseGraph::new();
            for (k, t) in truth.iter().enumerate() {
                let start = if k == 0 {
                    *t
                } else {
                    se3::exp(&random_tangent(rng, 0.1)) * t
                };
                g.add_node(start).unwrap();
            }
            for (i, j) in [
                (0, 1),
                (1, 2),
                (2, 3),
                (3, 4),
                (4, 5),
                (5, 6),
                (6, 7),
                (7, 0),
                (2, 6),
            ] {
                g.add_edge(Edge {
                    from: i,
                    to: j,
                    measured: truth[i].inverse() * truth[j],
                    information,
                })
                .unwrap();
            }
            if wrong {
                g.add_edge(Edge {
                    from: 1,
                    to: 5,
                    measured: se3::exp(&Vector6::new(0.8, 0.0, 0.0, 0.0, 0.0, 0.5))
                        * truth[1].inverse()
                        * truth[5],
                    information,
                })
                .unwrap();
            }
            g
        };
        let mut exact = build(false, &mut rng);
        let report = exact.optimise(&PoseGraphConfig::default()).unwrap();
        assert!(report.converged && report.final_cost < 1e-12, "{report:?}");
        for (k, t) in truth.iter().enumerate() {
            let (dt, da) = pose_error(&exact.pose(k), t);
            assert!(dt < 1e-6 && da < 1e-6, "node {k}: {dt} {da}");
        }
        let worst = |g: &PoseGraph| {
            truth
                .iter()
                .enumerate()
                .map(|(k, t)| pose_error(&g.pose(k), t).0)
                .fold(0.0, f64::max)
        };
        let mut plain = build(true, &mut ChaCha8Rng::seed_from_u64(4));
        plain
            .optimise(&PoseGraphConfig {
                huber: f64::INFINITY,
                ..PoseGraphConfig::default()
            })
            .unwrap();
        let mut robust = build(true, &mut ChaCha8Rng::seed_from_u64(4));
        robust.optimise(&PoseGraphConfig::default()).unwrap();
        assert!(
            worst(&robust) < 0.5 * worst(&plain),
            "Huber {} m against least squares {} m",
            worst(&robust),
            worst(&plain)
        );
    }

    /// Bad input is refused with the edge named; an edgeless graph is already optimal.
    #[test]
    fn bad_edges_are_refused() {
        let mut g = PoseGraph::new();
        g.add_node(Isometry3::identity()).unwrap();
        g.add_node(pose(1.0, 0.0, 0.0)).unwrap();
        let edge = |from, to, x: f64| Edge {
            from,
            to,
            measured: pose(x, 0.0, 0.0),
            information: Matrix6::identity(),
        };
        let e = g.add_edge(edge(0, 2, 1.0)).unwrap_err().to_string();
        assert!(e.contains("edge 0 → 2 in a graph of 2 nodes"), "{e}");
        assert!(g.add_edge(edge(1, 1, 1.0)).is_err());
        let e = g.add_edge(edge(0, 1, f64::NAN)).unwrap_err().to_string();
        assert!(e.contains("non-finite"), "{e}");
        assert!(g.add_node(pose(f64::INFINITY, 0.0, 0.0)).is_err());
        let report = g.optimise(&PoseGraphConfig::default()).unwrap();
        assert_eq!(report.iterations, 0);
        assert_eq!(g.pose(1), pose(1.0, 0.0, 0.0));
    }
}
