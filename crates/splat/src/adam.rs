//! Adam (Kingma & Ba) with a learning rate per parameter group, for the map (SPEC §4) and for
//! small vectors such as the pose τ and the exposure.

use crate::SplatError;
use crate::backward::Gradients;
use crate::gaussians::{Gaussians, PARAMS_PER_GAUSSIAN, layout};
use crate::real::Real;

/// Hyper-parameters of [`GaussianAdam`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdamConfig {
    /// Learning rate of the means (metres per step scale).
    pub lr_mean: f64,
    /// Learning rate of the colour coefficients `sh_dc`.
    pub lr_colour: f64,
    /// Learning rate of the quaternions.
    pub lr_rotation: f64,
    /// Learning rate of the opacity logits.
    pub lr_opacity: f64,
    /// Learning rate of the log-scales.
    pub lr_scale: f64,
    /// First-moment decay.
    pub beta1: f64,
    /// Second-moment decay.
    pub beta2: f64,
    /// Denominator guard.
    pub eps: f64,
}

impl Default for AdamConfig {
    /// The 3DGS/MonoGS defaults (mean rate for a room-sized scene).
    fn default() -> Self {
        Self {
            lr_mean: 1e-3,
            lr_colour: 2.5e-3,
            lr_rotation: 1e-3,
            lr_opacity: 5e-2,
            lr_scale: 5e-3,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-15,
        }
    }
}

impl AdamConfig {
    /// Learning rate of parameter `k` in the [`layout`] order.
    pub fn lr_of(&self, k: usize) -> f64 {
        match k {
            _ if k < layout::COLOUR => self.lr_mean,
            _ if k < layout::ROTATION => self.lr_colour,
            _ if k < layout::OPACITY => self.lr_rotation,
            layout::OPACITY => self.lr_opacity,
            _ => self.lr_scale,
        }
    }
}

/// Adam moments of a flat parameter vector; every entry keeps its own step count, so entries
/// appended later (densification) get the right bias correction. A non-finite gradient entry
/// counts as zero, so one bad pixel cannot poison the moments for good.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct AdamState {
    m: Vec<f64>,
    v: Vec<f64>,
    steps: Vec<u32>,
}

impl AdamState {
    /// Empty state; it grows to the parameter length on the first step.
    pub fn new() -> Self {
        Self::default()
    }

    /// Number of parameters tracked.
    pub fn len(&self) -> usize {
        self.m.len()
    }

    /// True when no parameter is tracked yet.
    pub fn is_empty(&self) -> bool {
        self.m.is_empty()
    }

    /// One Adam step on entry `k` with learning rate `lr`: returns the parameter change.
    #[inline]
    fn delta(&mut self, k: usize, grad: f64, lr: f64, beta1: f64, beta2: f64, eps: f64) -> f64 {
        let t = self.steps[k] as i32 + 1;
        let correction = (1.0 - beta1.powi(t), 1.0 - beta2.powi(t));
        self.delta_corrected(k, grad, lr, beta1, beta2, eps, correction)
    }

    /// [`AdamState::delta`] with the bias corrections `(1 − β₁ᵗ, 1 − β₂ᵗ)` of the entry's next
    /// step given, so entries stepped together (one Gaussian's) compute them once.
    #[inline]
    #[allow(clippy::too_many_arguments)]
    fn delta_corrected(
        &mut self,
        k: usize,
        grad: f64,
        lr: f64,
        beta1: f64,
        beta2: f64,
        eps: f64,
        correction: (f64, f64),
    ) -> f64 {
        let grad = if grad.is_finite() { grad } else { 0.0 };
        self.steps[k] += 1;
        self.m[k] = beta1 * self.m[k] + (1.0 - beta1) * grad;
        self.v[k] = beta2 * self.v[k] + (1.0 - beta2) * grad * grad;
        let m_hat = self.m[k] / correction.0;
        let v_hat = self.v[k] / correction.1;
        -lr * m_hat / (v_hat.sqrt() + eps)
    }

    fn grow(&mut self, len: usize) {
        if self.m.len() < len {
            self.m.resize(len, 0.0);
            self.v.resize(len, 0.0);
            self.steps.resize(len, 0);
        }
    }

    /// Updates `params` in place from `grads` with `lr(k)` per entry (β = 0.9, 0.999, ε = 1e-15
    /// unless given through [`AdamConfig`] by [`GaussianAdam`]).
    pub fn step<T: Real>(
        &mut self,
        params: &mut [T],
        grads: &[T],
        lr: impl Fn(usize) -> f64,
    ) -> Result<(), SplatError> {
        self.step_with(params, grads, lr, 0.9, 0.999, 1e-15)
    }

    /// [`AdamState::step`] with explicit β₁, β₂, ε.
    pub fn step_with<T: Real>(
        &mut self,
        params: &mut [T],
        grads: &[T],
        lr: impl Fn(usize) -> f64,
        beta1: f64,
        beta2: f64,
        eps: f64,
    ) -> Result<(), SplatError> {
        if params.len() != grads.len() {
            return Err(SplatError::Length {
                what: "adam gradients",
                expected: params.len(),
                got: grads.len(),
            });
        }
        self.grow(params.len());
        for (k, (p, g)) in params.iter_mut().zip(grads).enumerate() {
            let d = self.delta(k, g.to_f64(), lr(k), beta1, beta2, eps);
            *p = T::of(p.to_f64() + d);
        }
        Ok(())
    }

    /// Keeps the blocks of `stride` entries whose `keep` flag is set (mirrors pruning).
    pub fn retain_blocks(&mut self, keep: &[bool], stride: usize) {
        let mut idx = 0;
        let mut filter = |v: &mut Vec<f64>| {
            idx = 0;
            v.retain(|_| {
                let k = keep.get(idx / stride).copied().unwrap_or(false);
                idx += 1;
                k
            });
        };
        filter(&mut self.m);
        filter(&mut self.v);
        let mut j = 0;
        self.steps.retain(|_| {
            let k = keep.get(j / stride).copied().unwrap_or(false);
            j += 1;
            k
        });
    }
}

/// Adam over all Gaussians, one learning rate per parameter group. Every Gaussian keeps its own
/// step count (its bias correction), so Gaussians inserted later, or left out of some steps
/// through [`GaussianAdam::step_active`], start from fresh, correctly corrected moments.
#[derive(Debug, Clone, PartialEq)]
pub struct GaussianAdam {
    /// Hyper-parameters.
    pub config: AdamConfig,
    state: AdamState,
}

impl GaussianAdam {
    /// A fresh optimiser.
    pub fn new(config: AdamConfig) -> Self {
        Self {
            config,
            state: AdamState::new(),
        }
    }

    /// Number of Gaussians with optimiser state.
    pub fn len(&self) -> usize {
        self.state.len() / PARAMS_PER_GAUSSIAN
    }

    /// True when no Gaussian has optimiser state yet.
    pub fn is_empty(&self) -> bool {
        self.state.is_empty()
    }

    /// Number of Adam steps Gaussian `i` has had (0 when out of range): its age for pruning.
    pub fn steps(&self, i: usize) -> u32 {
        // All entries of a Gaussian are stepped together, so its first entry holds the count.
        self.state
            .steps
            .get(i * PARAMS_PER_GAUSSIAN)
            .copied()
            .unwrap_or(0)
    }

    /// Adds fresh state (zero moments, zero steps) for `count` Gaussians appended to the map.
    /// Optional: [`GaussianAdam::step`] also grows to the map size.
    pub fn grow(&mut self, count: usize) {
        self.state
            .grow(self.state.len() + count * PARAMS_PER_GAUSSIAN);
    }

    /// One step on every Gaussian. New Gaussians (appended since the last step) start with
    /// zero moments.
    pub fn step<T: Real>(
        &mut self,
        gaussians: &mut Gaussians<T>,
        grads: &Gradients<T>,
    ) -> Result<(), SplatError> {
        self.step_where(gaussians, grads, |_| true)
    }

    /// One step on the Gaussians with `active[i]`; the others keep their parameters, moments
    /// and step counts (e.g. Gaussians unseen in every view of a mapping window).
    pub fn step_active<T: Real>(
        &mut self,
        gaussians: &mut Gaussians<T>,
        grads: &Gradients<T>,
        active: &[bool],
    ) -> Result<(), SplatError> {
        if active.len() != gaussians.len() {
            return Err(SplatError::Length {
                what: "adam active mask",
                expected: gaussians.len(),
                got: active.len(),
            });
        }
        self.step_where(gaussians, grads, |i| active[i])
    }

    fn step_where<T: Real>(
        &mut self,
        gaussians: &mut Gaussians<T>,
        grads: &Gradients<T>,
        active: impl Fn(usize) -> bool,
    ) -> Result<(), SplatError> {
        let n = gaussians.len();
        if grads.means.len() != n {
            return Err(SplatError::Length {
                what: "gradients",
                expected: n,
                got: grads.means.len(),
            });
        }
        self.state.grow(n * PARAMS_PER_GAUSSIAN);
        let c = self.config;
        for i in (0..n).filter(|&i| active(i)) {
            let g = grads.params(i);
            // All entries of a Gaussian share their step count (see `steps`).
            let t = self.state.steps[i * PARAMS_PER_GAUSSIAN] as i32 + 1;
            let correction = (1.0 - c.beta1.powi(t), 1.0 - c.beta2.powi(t));
            for (k, gk) in g.iter().enumerate() {
                let d = self.state.delta_corrected(
                    i * PARAMS_PER_GAUSSIAN + k,
                    gk.to_f64(),
                    c.lr_of(k),
                    c.beta1,
                    c.beta2,
                    c.eps,
                    correction,
                );
                let p = gaussians.param_mut(i, k);
                *p = T::of(p.to_f64() + d);
            }
        }
        Ok(())
    }

    /// Drops the moments of pruned Gaussians (call with the mask given to [`Gaussians::retain`]).
    pub fn retain(&mut self, keep: &[bool]) {
        self.state.retain_blocks(keep, PARAMS_PER_GAUSSIAN);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_step_moves_by_the_learning_rate_against_the_gradient_sign() {
        // Bias-corrected m̂/√v̂ = g/|g| on the first step (Kingma & Ba, §2).
        let mut s = AdamState::new();
        let mut p = [1.0f64, -2.0, 0.5];
        s.step(&mut p, &[3.0, -0.001, 0.0], |k| [0.1, 0.2, 0.3][k])
            .unwrap();
        assert!((p[0] - 0.9).abs() < 1e-12 && (p[1] + 1.8).abs() < 1e-12 && p[2] == 0.5);
        assert!(s.step(&mut p, &[1.0], |_| 0.1).is_err());
    }

    #[test]
    fn minimises_a_quadratic_and_uses_group_rates() {
        let mut g = Gaussians::<f64>::new();
        g.push(
            [1.0, -1.0, 2.0],
            [0.5; 3],
            [1.0, 0.0, 0.0, 0.0],
            0.5,
            [1.0; 3],
        );
        let config = AdamConfig {
            lr_mean: 0.05,
            lr_colour: 0.0,
            lr_rotation: 0.0,
            lr_opacity: 0.0,
            lr_scale: 0.0,
            ..Default::default()
        };
        let mut adam = GaussianAdam::new(config);
        for _ in 0..500 {
            // L = |mean − (0.3, 0.2, −0.1)|² + |log_scale|²: only the means may move.
            let target = [0.3, 0.2, -0.1];
            let grads = Gradients {
                means: vec![[0, 1, 2].map(|k| 2.0 * (g.means[0][k] - target[k]))],
                sh_dc: vec![[0.0; 3]],
                rotations: vec![[0.0; 4]],
                opacity_logits: vec![0.0],
                log_scales: vec![g.log_scales[0].map(|v| 2.0 * v)],
                mean2d_norm: vec![0.0],
                pose: nalgebra::Vector6::zeros(),
                exposure: [0.0; 2],
            };
            adam.step(&mut g, &grads).unwrap();
        }
        for (k, t) in [0.3, 0.2, -0.1].iter().enumerate() {
            assert!(
                (g.means[0][k] - t).abs() < 1e-3,
                "mean {k} = {}",
                g.means[0][k]
            );
        }
        assert_eq!(g.log_scales[0], [0.0; 3]);
        adam.retain(&[false]);
        g.retain(&[false]).unwrap();
        assert!(g.is_empty());
    }

    /// Gradients that are zero except `mean_x[i]` on the x coordinate of mean `i`.
    fn mean_x_gradients(mean_x: &[f64]) -> Gradients<f64> {
        let n = mean_x.len();
        Gradients {
            means: mean_x.iter().map(|&g| [g, 0.0, 0.0]).collect(),
            sh_dc: vec![[0.0; 3]; n],
            rotations: vec![[0.0; 4]; n],
            opacity_logits: vec![0.0; n],
            log_scales: vec![[0.0; 3]; n],
            mean2d_norm: vec![0.0; n],
            pose: nalgebra::Vector6::zeros(),
            exposure: [0.0; 2],
        }
    }

    /// Scalar Adam written out from Kingma & Ba, Algorithm 1: the parameter changes for the
    /// gradient sequence `grads` (β₁ = 0.9, β₂ = 0.999, ε = 1e-15).
    fn reference_adam_deltas(grads: &[f64], lr: f64) -> Vec<f64> {
        let (mut m, mut v) = (0.0, 0.0);
        grads
            .iter()
            .enumerate()
            .map(|(t, g)| {
                let t = t as i32 + 1;
                m = 0.9 * m + 0.1 * g;
                v = 0.999 * v + 0.001 * g * g;
                let m_hat = m / (1.0 - 0.9f64.powi(t));
                let v_hat = v / (1.0 - 0.999f64.powi(t));
                -lr * m_hat / (v_hat.sqrt() + 1e-15)
            })
            .collect()
    }

    #[test]
    fn every_gaussian_has_its_own_bias_correction() {
        let lr = 0.01;
        let config = AdamConfig {
            lr_mean: lr,
            ..Default::default()
        };
        let mut adam = GaussianAdam::new(config);
        let mut g = Gaussians::<f64>::new();
        g.push([0.0; 3], [0.5; 3], [1.0, 0.0, 0.0, 0.0], 0.0, [0.0; 3]);
        // Gaussian 0 alone for five steps.
        let early = [0.3, -0.1, 0.7, 0.2, -0.4];
        for &gx in &early {
            adam.step(&mut g, &mean_x_gradients(&[gx])).unwrap();
        }
        assert_eq!((adam.len(), adam.steps(0), adam.steps(1)), (1, 5, 0));
        // Gaussian 1 is inserted later; its first step must be a first step (−lr·sign g), not
        // a sixth one (a shared t = 6 would give −0.522·lr here).
        g.push([0.0; 3], [0.5; 3], [1.0, 0.0, 0.0, 0.0], 0.0, [0.0; 3]);
        adam.grow(1);
        assert_eq!((adam.len(), adam.steps(1)), (2, 0));
        let x0 = g.means[0][0];
        adam.step(&mut g, &mean_x_gradients(&[0.5, 2.0])).unwrap();
        assert!((g.means[1][0] + lr).abs() < 1e-12, "{}", g.means[1][0]);
        let expected0 = reference_adam_deltas(&[0.3, -0.1, 0.7, 0.2, -0.4, 0.5], lr)[5];
        assert!((g.means[0][0] - x0 - expected0).abs() < 1e-12);
        // Gaussian 0 sits one step out: parameters, moments and count untouched; Gaussian 1
        // takes its second step.
        let x0 = g.means[0][0];
        adam.step_active(&mut g, &mean_x_gradients(&[9.0, -1.0]), &[false, true])
            .unwrap();
        assert_eq!(g.means[0][0], x0);
        assert_eq!((adam.steps(0), adam.steps(1)), (6, 2));
        let expected1 = reference_adam_deltas(&[2.0, -1.0], lr);
        assert!((g.means[1][0] - expected1[0] - expected1[1]).abs() < 1e-12);
        // Its next step continues its own sequence (the skipped gradient 9.0 never counted).
        adam.step(&mut g, &mean_x_gradients(&[-0.2, 0.0])).unwrap();
        let expected0 = reference_adam_deltas(&[0.3, -0.1, 0.7, 0.2, -0.4, 0.5, -0.2], lr)[6];
        assert!((g.means[0][0] - x0 - expected0).abs() < 1e-12);
        // Pruning keeps the survivors' counts; a bad mask length is an error, not a panic.
        adam.retain(&[false, true]);
        g.retain(&[false, true]).unwrap();
        assert_eq!((adam.len(), adam.steps(0)), (1, 3));
        assert!(
            adam.step_active(&mut g, &mean_x_gradients(&[1.0]), &[true, true])
                .is_err()
        );
    }

    #[test]
    fn non_finite_gradients_count_as_zero() {
        let mut s = AdamState::new();
        let mut p = [1.0f64, 1.0];
        s.step(&mut p, &[f64::NAN, 1.0], |_| 0.1).unwrap();
        s.step(&mut p, &[f64::INFINITY, 1.0], |_| 0.1).unwrap();
        // Zero gradients with zero moments leave the entry where it was.
        assert_eq!(p[0], 1.0);
        assert!((p[1] - 0.8).abs() < 1e-12);
    }
}
