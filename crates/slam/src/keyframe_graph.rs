//! The tracking session's keyframe pose graph (SPEC §4): one node per reference keyframe the
//! session makes, an odometry edge from each to its predecessor and a loop edge wherever a
//! frame is aligned to an older keyframe of the same place, optimised with
//! [`crate::pose_graph`] when a loop joins; the corrections it makes to the published keyframe
//! poses are what the mapper applies to its own keyframes.
//!
//! Split from [`crate::session`] so the tracking session reads as prediction, snapshots and
//! references, and the graph's bookkeeping (edge weights, loop gating, corrections) is read and
//! tested on its own.

use std::collections::BTreeMap;

use activemap_geometry::{Isometry3, se3};
use nalgebra::{Matrix6, Vector6};

use crate::dense::{DenseReference, align};
use crate::error::SlamError;
use crate::frame::Frame;
use crate::pose_graph::{Edge, PoseGraph, PoseGraphConfig};
use crate::tracker::TrackerConfig;

/// Settings of the tracker's keyframe pose graph ([`KeyframeGraph`]).
#[derive(Debug, Clone, PartialEq)]
pub struct KeyframeGraphConfig {
    /// The solver.
    pub solver: PoseGraphConfig,
    /// A loop edge is left out when its measurement disagrees with the graph's current
    /// estimate by more than this translation, metres (a wrong association), ...
    pub max_loop_disagreement_m: f64,
    /// ... or by more than this rotation, radians.
    pub max_loop_disagreement_rad: f64,
    /// Standard deviations of the weak prior added to every edge's information, metres and
    /// radians: it keeps a pair that the images leave unconstrained in some direction (a bare
    /// wall) from making the normal equations singular.
    pub edge_floor_sigmas: [f64; 2],
    /// The graph is re-optimised only when a new loop edge disagrees with it by at least this
    /// translation, metres, ...
    pub optimise_above_m: f64,
    /// ... or this rotation, radians. Smaller disagreements stay in the graph as edges and
    /// count at the next optimisation.
    pub optimise_above_rad: f64,
    /// Gauss–Newton iterations per pyramid level of a loop edge's pairwise alignment (`None`:
    /// the tracker's own).
    pub edge_iterations_per_level: Option<usize>,
    /// An older reference gets a new loop edge only once this many keyframes have passed since
    /// its last one (1: every time).
    pub loop_edge_spacing: u64,
    /// A keyframe's correction goes to the mapper ([`LoopClosure::corrections`]) once the
    /// keyframe has moved by at least this translation, metres, since its last correction
    /// sent (or its creation), ...
    pub correct_map_above_m: f64,
    /// ... or this rotation, radians. Smaller moves accumulate until they pass, so the map
    /// ends where the graph is to within these bounds, without moving every Gaussian of the
    /// map at every solve.
    pub correct_map_above_rad: f64,
}

impl Default for KeyframeGraphConfig {
    fn default() -> Self {
        Self {
            // Plain least squares: measured on the box room's full turn, a Huber kernel took
            // the loop edge for the outlier (the chain before it had locked onto a wrong
            // association with high confidence) and undid most of the correction.
            solver: PoseGraphConfig {
                huber: f64::INFINITY,
                ..PoseGraphConfig::default()
            },
            max_loop_disagreement_m: 0.3,
            max_loop_disagreement_rad: 10f64.to_radians(),
            edge_floor_sigmas: [0.5, 0.5],
            // Every loop edge, fully aligned, and a solve at each: the cheaper settings
            // (optimise above 5 mm / 0.25°, 3 iterations per level, an edge per old reference
            // every 5 keyframes, and the odometry edge taken from the tracker's own alignment)
            // brought the tracker's time back to about that without a graph, but
            // the furnished house's 2000-step FBE episode with the realistic preset (seed 1)
            // then ended at 11.7 cm ATE, against 3.2 cm with these defaults and 6–9 cm
            // without a graph. With noisy depth nearly every frame becomes a keyframe, so the
            // loop edges' alignments make the tracker about 1.6× slower.
            optimise_above_m: 0.0,
            optimise_above_rad: 0.0,
            edge_iterations_per_level: None,
            loop_edge_spacing: 1,
            // Well below the noise of a depth reading (σ 1.8 mm at 1 m with the realistic
            // preset) and of a Gaussian's size.
            correct_map_above_m: 1e-3,
            correct_map_above_rad: 0.05f64.to_radians(),
        }
    }
}

impl KeyframeGraphConfig {
    /// Checks ranges; names the offending field.
    pub fn validate(&self) -> Result<(), SlamError> {
        self.solver.validate()?;
        SlamError::require_positive(&[
            (
                "pose_graph.max_loop_disagreement_m",
                self.max_loop_disagreement_m,
            ),
            (
                "pose_graph.max_loop_disagreement_rad",
                self.max_loop_disagreement_rad,
            ),
            ("pose_graph.edge_floor_sigmas[0]", self.edge_floor_sigmas[0]),
            ("pose_graph.edge_floor_sigmas[1]", self.edge_floor_sigmas[1]),
        ])?;
        if self.edge_iterations_per_level == Some(0) {
            return Err(SlamError::Config {
                field: "pose_graph.edge_iterations_per_level",
                value: "0".into(),
                reason: "must be at least 1",
            });
        }
        SlamError::require_non_negative(&[
            ("pose_graph.optimise_above_m", self.optimise_above_m),
            ("pose_graph.optimise_above_rad", self.optimise_above_rad),
            ("pose_graph.correct_map_above_m", self.correct_map_above_m),
            (
                "pose_graph.correct_map_above_rad",
                self.correct_map_above_rad,
            ),
        ])
    }
}

/// The tracker's keyframe pose graph (issue 16; [`crate::pose_graph`]): one node per reference
/// keyframe (node = the reference's serial), an edge from each reference a new keyframe was
/// aligned to (the newest one: odometry; older ones of the same place: loop closures), each
/// measured by aligning the new keyframe to that reference alone ([`align`]) with the
/// alignment's information. When a loop edge joins that disagrees with the graph (by
/// `optimise_above_m` / `optimise_above_rad`), the graph is optimised, every kept reference
/// takes its corrected pose, and so does the new keyframe (the frame's published estimate),
/// so later frames aligned to them no longer inherit the drift of their time. The keyframes the
/// solve moved beyond a small threshold go out with the frame ([`LoopClosure::corrections`])
/// so that the mapper moves its keyframes and their Gaussians with them
/// ([`crate::KeyframeMapper`]).
#[derive(Debug, Clone)]
pub struct KeyframeGraph {
    config: KeyframeGraphConfig,
    graph: PoseGraph,
    /// Loop edges added / refused by the disagreement gate, optimisations run.
    stats: GraphStats,
    /// Per older reference (serial): the node of its latest loop edge.
    last_loop: BTreeMap<u64, u64>,
    /// Per node: the id of the frame it was made from (increasing).
    frame_ids: Vec<u64>,
    /// Per node: its pose as the mapper knows it (at creation, then at its last correction).
    published: Vec<Isometry3<f64>>,
}

/// How the pose graph moved the keyframe made from frame `frame_id` since the mapper last
/// heard of it: the world-frame rigid motion `correction = T_after · T_before⁻¹` (so `T_after =
/// correction · T_before`). Whatever was placed relative to that keyframe (the frames whose
/// [`TrackedFrame::graph_anchor`] it is, and the mapper's Gaussians of their keyframes) moves
/// with it by the same motion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyframeCorrection {
    /// The frame the graph keyframe was made from.
    pub frame_id: u64,
    /// `T_after · T_before⁻¹`, world frame.
    pub correction: Isometry3<f64>,
}

/// A loop closure: the pose graph took new loop edges and was re-optimised.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopClosure {
    /// Loop edges the new keyframe added.
    pub loop_edges: usize,
    /// Keyframes (nodes) in the graph.
    pub keyframes: usize,
    /// Largest move of a keyframe's camera centre by the optimisation, metres.
    pub largest_shift_m: f64,
    /// The graph keyframes that have moved by more than `correct_map_above_m` /
    /// `correct_map_above_rad` since their last correction, each with its move, in frame
    /// order. The new keyframe is never among them: its corrected pose is the frame's
    /// estimate.
    pub corrections: Vec<KeyframeCorrection>,
}

/// Counters of a [`KeyframeGraph`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GraphStats {
    /// Odometry edges (to the newest reference).
    pub odometry_edges: usize,
    /// Loop edges (to older references) added.
    pub loop_edges: usize,
    /// Loop edges refused: the pairwise alignment failed or disagreed beyond the gate.
    pub refused_edges: usize,
    /// Optimisations run.
    pub optimisations: usize,
}

impl KeyframeGraph {
    /// An empty graph.
    pub fn new(config: KeyframeGraphConfig) -> Result<Self, SlamError> {
        config.validate()?;
        Ok(Self {
            config,
            graph: PoseGraph::new(),
            stats: GraphStats::default(),
            last_loop: BTreeMap::new(),
            frame_ids: Vec::new(),
            published: Vec::new(),
        })
    }

    /// The graph.
    pub fn graph(&self) -> &PoseGraph {
        &self.graph
    }

    /// The counters.
    pub fn stats(&self) -> GraphStats {
        self.stats
    }

    /// The weak prior added to every edge's information.
    fn floor(&self) -> Matrix6<f64> {
        let [t, r] = self.config.edge_floor_sigmas;
        let (it, ir) = (1.0 / (t * t), 1.0 / (r * r));
        Matrix6::from_diagonal(&Vector6::new(it, it, it, ir, ir, ir))
    }

    /// Adds the keyframe `frame` (frame `frame_id`, tracking resolution) tracked at `pose` as
    /// node `serial`, with an edge from each of `aligned_to` (serial and reference; the first
    /// is the newest), optimises when a loop edge joined, and returns the keyframe's corrected
    /// pose. Every edge, the odometry one included, is measured by a pairwise alignment started
    /// at `pose` (reusing the tracker's joint alignment for the odometry edge when it had the
    /// newest reference alone was measured worse: its motion prior pulls the estimate toward
    /// the prediction, and the edge then carries that pull with the images' confidence).
    pub(crate) fn add_keyframe(
        &mut self,
        serial: u64,
        frame_id: u64,
        frame: &Frame,
        pose: Isometry3<f64>,
        aligned_to: &[(u64, &DenseReference)],
        tracking: &TrackerConfig,
    ) -> Result<(Isometry3<f64>, Option<LoopClosure>), SlamError> {
        let node = self.graph.add_node(pose)?;
        if node as u64 != serial {
            return Err(SlamError::Input {
                what: "pose graph node",
                reason: format!("node {node} for reference serial {serial}"),
            });
        }
        if self.frame_ids.last().is_some_and(|&last| frame_id <= last) {
            return Err(SlamError::Input {
                what: "pose graph node",
                reason: format!(
                    "frame {frame_id} is not after the previous keyframe's frame {:?}",
                    self.frame_ids.last()
                ),
            });
        }
        self.frame_ids.push(frame_id);
        let mut loops = 0;
        let mut worth_solving = false;
        let dense = crate::dense::DenseConfig {
            iterations_per_level: self
                .config
                .edge_iterations_per_level
                .unwrap_or(tracking.dense.iterations_per_level),
            ..tracking.dense.clone()
        };
        for (k, (from, reference)) in aligned_to.iter().enumerate() {
            if k > 0
                && self
                    .last_loop
                    .get(from)
                    .is_some_and(|&last| serial < last + self.config.loop_edge_spacing.max(1))
            {
                continue;
            }
            let a = align(&dense, reference, frame, &pose)?;
            let usable = a.inlier_fraction >= tracking.lost_min_coverage
                && a.rms_distance <= tracking.dense.lost_max_rms;
            let measured = se3::normalized(&(reference.pose.inverse() * a.pose));
            let from = *from as usize;
            // The odometry edge (k = 0) is kept whatever the pair's quality: the joint
            // alignment accepted this frame, and the chain must stay connected. A loop edge
            // must be a good alignment that roughly agrees with the graph as it stands.
            if k > 0 {
                let current = self.graph.pose(from).inverse() * pose;
                let (dt, da) = se3::pose_error(&current, &measured);
                if !usable
                    || dt > self.config.max_loop_disagreement_m
                    || da > self.config.max_loop_disagreement_rad
                {
                    self.stats.refused_edges += 1;
                    continue;
                }
                worth_solving |=
                    dt >= self.config.optimise_above_m || da >= self.config.optimise_above_rad;
            }
            let ad = se3::adjoint(&measured);
            let information = ad.transpose() * a.information * ad + self.floor();
            self.graph.add_edge(Edge {
                from,
                to: node,
                measured,
                information,
            })?;
            if k == 0 {
                self.stats.odometry_edges += 1;
            } else {
                self.last_loop.insert(from as u64, serial);
                self.stats.loop_edges += 1;
                loops += 1;
            }
        }
        let mut closure = None;
        if loops > 0 && worth_solving {
            let before = self.graph.poses().to_vec();
            self.graph.optimise(&self.config.solver)?;
            self.stats.optimisations += 1;
            let largest_shift_m = before
                .iter()
                .zip(self.graph.poses())
                .map(|(a, b)| (a.translation.vector - b.translation.vector).norm())
                .fold(0.0, f64::max);
            let mut corrections = Vec::new();
            for (n, after) in self.graph.poses().iter().enumerate().take(node) {
                let (dt, da) = se3::pose_error(&self.published[n], after);
                if dt >= self.config.correct_map_above_m || da >= self.config.correct_map_above_rad
                {
                    corrections.push(KeyframeCorrection {
                        frame_id: self.frame_ids[n],
                        correction: se3::normalized(&(after * self.published[n].inverse())),
                    });
                    self.published[n] = *after;
                }
            }
            closure = Some(LoopClosure {
                loop_edges: loops,
                keyframes: self.graph.len(),
                largest_shift_m,
                corrections,
            });
        }
        self.published.push(self.graph.pose(node));
        Ok((self.graph.pose(node), closure))
    }

    /// The frame each graph keyframe (node) was made from, in node order (the last: the
    /// keyframe the frames tracked now hang on).
    pub fn keyframe_frames(&self) -> &[u64] {
        &self.frame_ids
    }
}
