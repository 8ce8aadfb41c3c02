//! The model Fisher `I(w)` (SPEC §5), per Gaussian id, so it survives the mapper adding and
//! pruning Gaussians (ids, not positions or indices, identify them).
//!
//! - `mc_free_space` (the paper): `I(w) ≈ Σ_{n=1}^{N} H(x_n)`, `x_n` uniform in the estimated
//!   free space with a uniform yaw. The scorer keeps the views of the last N poses; when the
//!   map changed it draws `mc_refresh` fresh poses on the current map and drops the oldest.
//!   A Gaussian seen by only `c < N` of the kept poses (it was added after the others were
//!   drawn) is estimated from those: `I = (N/c)·Σ_{its poses} H`, the same estimator of
//!   `N·E[H]` on fewer samples. Unknown-space Gaussians, renewed at each replan, are
//!   estimated from the poses drawn for their generation.
//! - `keyframes` (the release): `I(w) = Σ_keyframes H(x_kf)`, each keyframe's view added once,
//!   on the map of the replan that first sees it (earlier keyframes are not re-rendered when
//!   Gaussians are added later; the release re-renders all, which costs a view per keyframe
//!   per replan). Unknown-space Gaussians have no keyframe views: their prior is λ alone.
//! - `both`: the two sums added, kept as two estimates (the scorer holds the keyframe one
//!   beside this Monte-Carlo one): a Gaussian the robot has seen keeps the information of
//!   its keyframes whatever the draw, one only free-space poses see gets theirs.
//!
//! Between replans on an unchanged map (same snapshot, same unknown-space generation) the
//! estimate is reused as it is.

use std::collections::{HashMap, VecDeque};

use activemap_geometry::Isometry3;

use crate::config::{FisherConfig, ModelFisherSource};
use crate::information::{Diagonal, PARAMS, ViewInformation};
use crate::unknown::UNKNOWN_ID_BASE;

/// The generation of an unknown-space id (`UNKNOWN_ID_BASE + (generation << 32) + index`).
pub fn unknown_generation(id: u64) -> Option<u32> {
    (id >= UNKNOWN_ID_BASE).then(|| ((id - UNKNOWN_ID_BASE) >> 32) as u32)
}

/// One view's diagonal by Gaussian id, and what existed when it was taken.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelSample {
    /// `(id, H diagonal)` of every Gaussian the view informs.
    pub diagonal: Vec<(u64, [f32; PARAMS])>,
    /// The largest real (mapper) id of the map it was rendered on; `None` for an empty map.
    pub max_real_id: Option<u64>,
    /// The unknown-space generation it was rendered with.
    pub generation: u32,
}

impl ModelSample {
    /// The sample of `view`, rendered on the map whose ids are `ids` (indices of `view` index
    /// `ids`), with unknown-space generation `generation`.
    pub fn from_view(view: &ViewInformation, ids: &[u64], generation: u32) -> Self {
        Self {
            diagonal: view
                .diagonal
                .iter()
                .map(|(i, d)| (ids[*i as usize], d.map(|v| v as f32)))
                .collect(),
            max_real_id: ids.iter().copied().filter(|&id| id < UNKNOWN_ID_BASE).max(),
            generation,
        }
    }
}

/// The model Fisher across replans.
#[derive(Debug, Clone)]
pub struct ModelFisher {
    source: ModelFisherSource,
    poses: usize,
    /// `mc_free_space`: the kept views, oldest first.
    samples: VecDeque<ModelSample>,
    /// Σ of the kept views (or of every keyframe view) per id.
    sums: HashMap<u64, Diagonal>,
    /// `max_real_id` of the kept views, oldest first (non-decreasing: ids only grow).
    sample_max_ids: Vec<Option<u64>>,
    /// How many kept views have each generation.
    generation_counts: HashMap<u32, usize>,
    /// `keyframes`: keyframes announced but not yet rendered.
    pending_keyframes: Vec<(u64, Isometry3<f64>)>,
    /// `keyframes`: how many keyframe views are in `sums`.
    keyframe_views: usize,
    /// The (map frame, generation) the estimate was last brought up to date for.
    current: Option<(u64, u32)>,
    /// Views dropped so far (`mc_free_space`).
    evictions: usize,
}

impl ModelFisher {
    /// An empty model Fisher with the source and pose count of `config` (`both`: its
    /// Monte-Carlo half; the scorer keeps a second, keyframe, estimate beside it).
    pub fn new(config: &FisherConfig) -> Self {
        Self::with_source(config, config.model_fisher)
    }

    /// An empty model Fisher of `source` (`both` counts as `mc_free_space`) with the pose
    /// count of `config`.
    pub fn with_source(config: &FisherConfig, source: ModelFisherSource) -> Self {
        let source = match source {
            ModelFisherSource::Both => ModelFisherSource::McFreeSpace,
            s => s,
        };
        Self {
            source,
            poses: config.mc_poses,
            samples: VecDeque::new(),
            sums: HashMap::new(),
            sample_max_ids: Vec::new(),
            generation_counts: HashMap::new(),
            pending_keyframes: Vec::new(),
            keyframe_views: 0,
            current: None,
            evictions: 0,
        }
    }

    /// Where the estimate comes from.
    pub fn source(&self) -> ModelFisherSource {
        self.source
    }

    /// Whether the estimate is up to date for map snapshot `map_frame` with unknown-space
    /// generation `generation` (then a replan reuses it as it is).
    pub fn is_current(&self, map_frame: u64, generation: u32) -> bool {
        self.current == Some((map_frame, generation))
            && (self.source == ModelFisherSource::McFreeSpace || self.pending_keyframes.is_empty())
    }

    /// Marks the estimate up to date for `(map_frame, generation)`.
    pub fn mark_current(&mut self, map_frame: u64, generation: u32) {
        self.current = Some((map_frame, generation));
    }

    /// Views kept (`mc_free_space`) or keyframe views summed (`keyframes`).
    pub fn views(&self) -> usize {
        match self.source {
            ModelFisherSource::McFreeSpace | ModelFisherSource::Both => self.samples.len(),
            ModelFisherSource::Keyframes => self.keyframe_views,
        }
    }

    /// Announces keyframe `frame_id` at `pose` (`keyframes` source; ignored otherwise).
    pub fn add_keyframe(&mut self, frame_id: u64, pose: Isometry3<f64>) {
        if self.source == ModelFisherSource::Keyframes
            && !self.pending_keyframes.iter().any(|(f, _)| *f == frame_id)
        {
            self.pending_keyframes.push((frame_id, pose));
        }
    }

    /// Takes the keyframes announced since the last call, in frame order.
    pub fn take_pending_keyframes(&mut self) -> Vec<(u64, Isometry3<f64>)> {
        let mut out = std::mem::take(&mut self.pending_keyframes);
        out.sort_by_key(|(f, _)| *f);
        out
    }

    /// Adds one view: a Monte-Carlo pose (`mc_free_space`, dropping the oldest beyond N) or a
    /// keyframe (`keyframes`).
    pub fn push(&mut self, sample: ModelSample) {
        add_into(&mut self.sums, &sample, 1.0);
        match self.source {
            ModelFisherSource::Keyframes => self.keyframe_views += 1,
            ModelFisherSource::McFreeSpace | ModelFisherSource::Both => {
                *self.generation_counts.entry(sample.generation).or_default() += 1;
                self.sample_max_ids.push(sample.max_real_id);
                self.samples.push_back(sample);
                if self.samples.len() > self.poses {
                    let old = self.samples.pop_front().expect("non-empty");
                    self.sample_max_ids.remove(0);
                    add_into(&mut self.sums, &old, -1.0);
                    if let Some(c) = self.generation_counts.get_mut(&old.generation) {
                        *c -= 1;
                        if *c == 0 {
                            self.generation_counts.remove(&old.generation);
                        }
                    }
                    // Every N evictions, sum afresh: drops the ids no kept view mentions any
                    // more (pruned Gaussians, old generations) and the subtractions' rounding.
                    self.evictions += 1;
                    if self.evictions.is_multiple_of(self.poses) {
                        self.rebuild();
                    }
                }
            }
        }
    }

    /// Recomputes the sums from the kept views (removes rounding and dead ids).
    fn rebuild(&mut self) {
        self.sums.clear();
        for s in &self.samples {
            add_into(&mut self.sums, s, 1.0);
        }
    }

    /// How many kept views were taken while Gaussian `id` existed.
    fn views_of(&self, id: u64) -> usize {
        match unknown_generation(id) {
            Some(g) => self.generation_counts.get(&g).copied().unwrap_or(0),
            None => {
                // Views are in time order and their max ids never decrease: those whose max
                // id reaches `id` form a suffix.
                let first = self
                    .sample_max_ids
                    .partition_point(|m| m.is_none_or(|m| m < id));
                self.sample_max_ids.len() - first
            }
        }
    }

    /// `I(w)` of Gaussian `id` (without λ).
    pub fn information(&self, id: u64) -> Diagonal {
        let Some(sum) = self.sums.get(&id) else {
            return [0.0; PARAMS];
        };
        match self.source {
            ModelFisherSource::Keyframes => sum.map(|v| v.max(0.0)),
            ModelFisherSource::McFreeSpace | ModelFisherSource::Both => {
                let c = self.views_of(id);
                if c == 0 {
                    return [0.0; PARAMS];
                }
                let scale = self.poses as f64 / c as f64;
                sum.map(|v| (v * scale).max(0.0))
            }
        }
    }

    /// The prior `I(w) + λ` of every Gaussian, by index into `ids`.
    pub fn prior(&self, ids: &[u64], lambda: f64) -> Vec<Diagonal> {
        ids.iter()
            .map(|&id| self.information(id).map(|v| v + lambda))
            .collect()
    }
}

fn add_into(sums: &mut HashMap<u64, Diagonal>, sample: &ModelSample, sign: f64) {
    for (id, d) in &sample.diagonal {
        let entry = sums.entry(*id).or_insert([0.0; PARAMS]);
        for (e, v) in entry.iter_mut().zip(d) {
            *e += sign * *v as f64;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(ids: &[(u64, f32)], max: u64, generation: u32) -> ModelSample {
        ModelSample {
            diagonal: ids.iter().map(|(id, v)| (*id, [*v; PARAMS])).collect(),
            max_real_id: Some(max),
            generation,
        }
    }

    /// N = 4 kept views: a Gaussian seen since the start sums its 4 views; one added after
    /// two views is scaled by 4/2; old views fall out; unknown-space ids count the views of
    /// their generation only.
    #[test]
    fn ids_added_later_are_rescaled_to_n_views() {
        let config = FisherConfig {
            model_fisher: ModelFisherSource::McFreeSpace,
            mc_poses: 4,
            ..FisherConfig::default()
        };
        let mut m = ModelFisher::new(&config);
        let u1 = UNKNOWN_ID_BASE + (1 << 32) + 5;
        m.push(sample(&[(0, 1.0)], 0, 0));
        m.push(sample(&[(0, 2.0)], 0, 0));
        m.push(sample(&[(0, 3.0), (1, 10.0), (u1, 7.0)], 1, 1));
        m.push(sample(&[(0, 4.0), (1, 20.0), (u1, 9.0)], 1, 1));
        assert_eq!(m.information(0)[0], 10.0);
        assert_eq!(m.information(1)[3], 4.0 / 2.0 * 30.0);
        assert_eq!(m.information(u1)[0], 4.0 / 2.0 * 16.0);
        // A fifth view drops the first.
        m.push(sample(&[(0, 5.0), (1, 30.0)], 1, 2));
        assert_eq!(m.views(), 4);
        assert_eq!(m.information(0)[0], 14.0);
        assert_eq!(m.information(1)[0], 4.0 / 3.0 * 60.0);
        // Generation 1 keeps its two views; a Gaussian nobody saw has none.
        assert_eq!(m.information(u1)[0], 2.0 * 16.0);
        assert_eq!(m.information(99), [0.0; PARAMS]);
        let prior = m.prior(&[0, 99], 1e-6);
        assert_eq!(prior[1][0], 1e-6);
        assert!((prior[0][0] - (14.0 + 1e-6)).abs() < 1e-12);
    }

    /// Keyframe views add up without rescaling; unknown-space ids have none.
    #[test]
    fn keyframe_views_sum() {
        let config = FisherConfig {
            model_fisher: ModelFisherSource::Keyframes,
            mc_poses: 2,
            ..FisherConfig::default()
        };
        let mut m = ModelFisher::new(&config);
        m.add_keyframe(5, Isometry3::identity());
        m.add_keyframe(3, Isometry3::identity());
        m.add_keyframe(5, Isometry3::identity());
        assert!(!m.is_current(0, 0));
        let pending = m.take_pending_keyframes();
        assert_eq!(pending.iter().map(|p| p.0).collect::<Vec<_>>(), vec![3, 5]);
        for v in [1.0, 2.0, 3.0] {
            m.push(sample(&[(7, v)], 7, 0));
        }
        assert_eq!(m.views(), 3);
        assert_eq!(m.information(7)[0], 6.0);
        m.mark_current(10, 0);
        assert!(m.is_current(10, 0) && !m.is_current(11, 0));
    }
}
