//! Adam over the 14 parameters of every Gaussian (SPEC §3 layout), with one learning rate per
//! parameter group and per-Gaussian step counts, so Gaussians inserted later start with fresh,
//! correctly bias-corrected moments. The moments follow the map through [`MapAdam::retain`]
//! (pruning) and [`MapAdam::grow`] (insertion, densification).

use crate::adam::{BETA1, BETA2, EPSILON};
use activemap_splat::{Gaussians, Gradients};

/// Learning rates per parameter group (MonoGS/3DGS defaults, mean in metres per step).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapLearningRates {
    /// Means (metres per step).
    pub mean: f64,
    /// Colour coefficients `sh_dc`.
    pub colour: f64,
    /// Quaternion.
    pub rotation: f64,
    /// Opacity logit.
    pub opacity: f64,
    /// Log-scales.
    pub log_scale: f64,
}

impl Default for MapLearningRates {
    fn default() -> Self {
        Self {
            mean: 0.002,
            colour: 0.0025,
            rotation: 0.001,
            opacity: 0.05,
            log_scale: 0.005,
        }
    }
}

impl MapLearningRates {
    /// Learning rate of parameter `k` in the 14-parameter layout.
    pub fn of(&self, k: usize) -> f64 {
        match k {
            0..=2 => self.mean,
            3..=5 => self.colour,
            6..=9 => self.rotation,
            10 => self.opacity,
            _ => self.log_scale,
        }
    }
}

/// Adam moments for every Gaussian of a map.
#[derive(Debug, Clone, Default)]
pub struct MapAdam {
    m: Vec<[f32; 14]>,
    v: Vec<[f32; 14]>,
    steps: Vec<u32>,
}

impl MapAdam {
    /// Number of Gaussians tracked.
    pub fn len(&self) -> usize {
        self.m.len()
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.m.is_empty()
    }

    /// Number of optimisation steps Gaussian `i` has had (0 when out of range).
    pub fn steps(&self, i: usize) -> u32 {
        self.steps.get(i).copied().unwrap_or(0)
    }

    /// Adds fresh state for `count` new Gaussians at the end.
    pub fn grow(&mut self, count: usize) {
        self.m.extend(std::iter::repeat_n([0.0; 14], count));
        self.v.extend(std::iter::repeat_n([0.0; 14], count));
        self.steps.extend(std::iter::repeat_n(0, count));
    }

    /// Keeps the state of the Gaussians whose `keep` entry is true (same mask as the map).
    pub fn retain(&mut self, keep: &[bool]) {
        let mut k = keep.iter();
        self.m.retain(|_| *k.next().unwrap_or(&false));
        let mut k = keep.iter();
        self.v.retain(|_| *k.next().unwrap_or(&false));
        let mut k = keep.iter();
        self.steps.retain(|_| *k.next().unwrap_or(&false));
    }

    /// One Adam step on the Gaussians with `active[i]` (the others, e.g. unseen in every view
    /// or unknown-space Gaussians, keep their parameters and moments).
    pub fn step(
        &mut self,
        map: &mut Gaussians<f32>,
        grads: &Gradients<f32>,
        active: &[bool],
        lr: &MapLearningRates,
    ) {
        for i in 0..map.len().min(self.m.len()) {
            if !active[i] {
                continue;
            }
            self.steps[i] += 1;
            let t = self.steps[i] as i32;
            let c1 = 1.0 - BETA1.powi(t);
            let c2 = 1.0 - BETA2.powi(t);
            let g = grads.params(i);
            for (k, &gk) in g.iter().enumerate() {
                let gk = if gk.is_finite() { gk as f64 } else { 0.0 };
                let m = BETA1 * self.m[i][k] as f64 + (1.0 - BETA1) * gk;
                let v = BETA2 * self.v[i][k] as f64 + (1.0 - BETA2) * gk * gk;
                self.m[i][k] = m as f32;
                self.v[i][k] = v as f32;
                let delta = -lr.of(k) * (m / c1) / ((v / c2).sqrt() + EPSILON);
                *map.param_mut(i, k) += delta as f32;
            }
        }
    }
}
