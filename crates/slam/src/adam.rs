//! A plain Adam optimiser (Kingma & Ba 2015, β₁ = 0.9, β₂ = 0.999, ε = 1e-15 as 3DGS/MonoGS) over
//! a flat parameter vector with a learning rate per entry. Used for the camera pose and
//! exposure (8 values) and, per Gaussian, for the map (14 values each, see [`crate::map_adam`]).

/// First-moment decay.
pub const BETA1: f64 = 0.9;
/// Second-moment decay.
pub const BETA2: f64 = 0.999;
/// Denominator guard (3DGS uses 1e-15).
pub const EPSILON: f64 = 1e-15;

/// Adam state for `N` parameters with per-parameter learning rates.
#[derive(Debug, Clone, PartialEq)]
pub struct Adam<const N: usize> {
    /// Learning rate of each parameter.
    pub lr: [f64; N],
    m: [f64; N],
    v: [f64; N],
    t: i32,
}

impl<const N: usize> Adam<N> {
    /// Fresh state (zero moments).
    pub fn new(lr: [f64; N]) -> Self {
        Self {
            lr,
            m: [0.0; N],
            v: [0.0; N],
            t: 0,
        }
    }

    /// The step `Δ = −lr·m̂/(√v̂ + ε)` for gradient `g` (the caller adds it to the parameters).
    pub fn step(&mut self, g: &[f64; N]) -> [f64; N] {
        self.t += 1;
        let c1 = 1.0 - BETA1.powi(self.t);
        let c2 = 1.0 - BETA2.powi(self.t);
        let mut delta = [0.0; N];
        for i in 0..N {
            let gi = if g[i].is_finite() { g[i] } else { 0.0 };
            self.m[i] = BETA1 * self.m[i] + (1.0 - BETA1) * gi;
            self.v[i] = BETA2 * self.v[i] + (1.0 - BETA2) * gi * gi;
            delta[i] = -self.lr[i] * (self.m[i] / c1) / ((self.v[i] / c2).sqrt() + EPSILON);
        }
        delta
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_step_is_minus_lr_times_sign() {
        // With zero moments the bias-corrected first step is exactly −lr·sign(g).
        let mut adam = Adam::new([0.1, 0.01]);
        let d = adam.step(&[3.0, -0.002]);
        assert!((d[0] + 0.1).abs() < 1e-12 && (d[1] - 0.01).abs() < 1e-12);
    }

    #[test]
    fn minimises_a_quadratic() {
        let mut x = [2.0, -1.0];
        let mut adam = Adam::new([0.05; 2]);
        for _ in 0..2000 {
            let g = [2.0 * (x[0] - 0.5), 2.0 * (x[1] + 0.25)];
            let d = adam.step(&g);
            x[0] += d[0];
            x[1] += d[1];
        }
        assert!(
            (x[0] - 0.5).abs() < 1e-3 && (x[1] + 0.25).abs() < 1e-3,
            "{x:?}"
        );
    }
}
