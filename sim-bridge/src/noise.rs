//! Optional, seeded sensor noise: Gaussian depth noise proportional to depth (as structured-light
//! sensors), Gaussian colour noise, and random depth dropouts.

use crate::error::{Result, SimError};
use crate::render::RgbdFrame;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Noise model; all zero (noise-free) by default.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SensorNoise {
    /// Depth noise standard deviation per metre of depth (σ = k·z); e.g. 0.01.
    pub depth_sigma_per_metre: f64,
    /// Colour noise standard deviation, in 8-bit levels; e.g. 2.0.
    pub rgb_sigma: f64,
    /// Probability that a valid depth pixel reads 0 (no return).
    pub depth_dropout: f64,
}

impl SensorNoise {
    /// Whether any noise is configured.
    pub fn is_active(&self) -> bool {
        self.depth_sigma_per_metre > 0.0 || self.rgb_sigma > 0.0 || self.depth_dropout > 0.0
    }

    pub(crate) fn validate(&self) -> Result<()> {
        let check = |field, v: f64, ok: bool| {
            if ok {
                Ok(())
            } else {
                Err(SimError::InvalidConfig {
                    field,
                    value: v.to_string(),
                    reason: "must be finite, >= 0 (dropout <= 1)",
                })
            }
        };
        let d = self.depth_sigma_per_metre;
        check("noise.depth_sigma_per_metre", d, d.is_finite() && d >= 0.0)?;
        check(
            "noise.rgb_sigma",
            self.rgb_sigma,
            self.rgb_sigma.is_finite() && self.rgb_sigma >= 0.0,
        )?;
        let p = self.depth_dropout;
        check("noise.depth_dropout", p, (0.0..=1.0).contains(&p))
    }

    /// Adds noise to a frame in place, drawing from `rng` in pixel order (deterministic).
    pub fn apply(&self, frame: &mut RgbdFrame, rng: &mut ChaCha8Rng) {
        self.apply_to(&mut frame.rgb, &mut frame.depth, rng);
    }

    /// Adds noise in place to RGB8 and depth buffers (e.g. a loaned shared-memory frame), with
    /// the same draws as [`SensorNoise::apply`].
    pub fn apply_to(&self, rgb: &mut [u8], depth: &mut [f32], rng: &mut ChaCha8Rng) {
        if !self.is_active() {
            return;
        }
        let std = Normal::new(0.0f64, 1.0).expect("unit normal is valid");
        if self.depth_sigma_per_metre > 0.0 || self.depth_dropout > 0.0 {
            for d in depth.iter_mut().filter(|d| **d > 0.0) {
                if self.depth_dropout > 0.0 && rng.random::<f64>() < self.depth_dropout {
                    *d = 0.0;
                    continue;
                }
                if self.depth_sigma_per_metre > 0.0 {
                    let z = *d as f64;
                    *d = (z + self.depth_sigma_per_metre * z * std.sample(rng)).max(1e-4) as f32;
                }
            }
        }
        if self.rgb_sigma > 0.0 {
            for c in rgb.iter_mut() {
                let v = *c as f64 + self.rgb_sigma * std.sample(rng);
                *c = v.round().clamp(0.0, 255.0) as u8;
            }
        }
    }
}
