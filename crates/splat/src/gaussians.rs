//! The Gaussian map as a structure of arrays: the 14 parameters of SPEC §3 per Gaussian plus
//! a flag byte the renderer can filter on.
//!
//! Parameter conventions (fixed here, used by render, gradients, Fisher, Adam and PLY):
//! - `means`: world position (metres);
//! - `sh_dc`: degree-0 spherical-harmonic coefficient per RGB channel, the 3DGS `f_dc`
//!   convention: rendered colour `c = 0.5 + C0·sh_dc` with `C0 = 0.28209479177387814`
//!   (no clamping, so the colour is smooth in the parameter). Storing `f_dc` makes PLY
//!   export/import bit-exact; use [`Gaussians::push`] / [`Gaussians::colour`] to work in RGB;
//! - `rotations`: unnormalised quaternion `[w, x, y, z]` (3DGS `rot_0..3` order);
//! - `opacity_logits`: opacity `o = sigmoid(logit)`;
//! - `log_scales`: per-axis standard deviation `s = exp(log_scale)` (metres).

use crate::real::Real;

/// The SH degree-0 constant `1 / (2√π)` of the 3DGS colour convention.
pub const SH_C0: f64 = 0.282_094_791_773_878_14;

/// Number of parameters per Gaussian (SPEC §3).
pub const PARAMS_PER_GAUSSIAN: usize = 14;

/// Offsets of the parameter groups inside a 14-vector `[mean 3, sh_dc 3, rotation 4, opacity
/// logit 1, log-scale 3]`, the layout of Fisher diagonals and flattened gradients.
pub mod layout {
    /// First index of the mean (x, y, z).
    pub const MEAN: usize = 0;
    /// First index of the colour coefficients `sh_dc` (r, g, b).
    pub const COLOUR: usize = 3;
    /// First index of the quaternion (w, x, y, z).
    pub const ROTATION: usize = 6;
    /// Index of the opacity logit.
    pub const OPACITY: usize = 10;
    /// First index of the log-scales.
    pub const LOG_SCALE: usize = 11;
}

/// Flag bit: a Gaussian that stands for unexplored space (SPEC §5); evaluation renders exclude it.
pub const FLAG_UNKNOWN_SPACE: u8 = 1;

/// A set of Gaussians, one entry per Gaussian in each array (structure of arrays).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Gaussians<T: Real = f32> {
    /// World-frame means, metres.
    pub means: Vec<[T; 3]>,
    /// Degree-0 SH coefficients (3DGS `f_dc`), see the module doc.
    pub sh_dc: Vec<[T; 3]>,
    /// Unnormalised quaternions `[w, x, y, z]`.
    pub rotations: Vec<[T; 4]>,
    /// Opacity logits; opacity = sigmoid(logit).
    pub opacity_logits: Vec<T>,
    /// Natural logarithms of the per-axis scales.
    pub log_scales: Vec<[T; 3]>,
    /// Per-Gaussian flag bits (e.g. [`FLAG_UNKNOWN_SPACE`]); `RenderOptions::exclude_flags`
    /// leaves out the Gaussians whose flags intersect it.
    pub flags: Vec<u8>,
}

/// Converts an RGB colour to the stored `sh_dc` coefficient.
pub fn rgb_to_sh_dc(c: f64) -> f64 {
    (c - 0.5) / SH_C0
}

/// Converts a stored `sh_dc` coefficient to the rendered colour.
pub fn sh_dc_to_rgb(sh: f64) -> f64 {
    0.5 + SH_C0 * sh
}

/// Inverse of the sigmoid (for initialising opacities), clamped away from 0 and 1.
pub fn logit(p: f64) -> f64 {
    let p = p.clamp(1e-7, 1.0 - 1e-7);
    (p / (1.0 - p)).ln()
}

/// The logistic sigmoid.
pub fn sigmoid<T: Real>(x: T) -> T {
    T::one() / (T::one() + (-x).exp())
}

impl<T: Real> Gaussians<T> {
    /// An empty set.
    pub fn new() -> Self {
        Self {
            means: Vec::new(),
            sh_dc: Vec::new(),
            rotations: Vec::new(),
            opacity_logits: Vec::new(),
            log_scales: Vec::new(),
            flags: Vec::new(),
        }
    }

    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.means.len()
    }

    /// True when there are no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }

    /// Appends a Gaussian given in natural units: mean (m), RGB colour, unnormalised
    /// quaternion `[w, x, y, z]`, opacity in (0, 1), per-axis scale (m). Flags are 0.
    pub fn push(
        &mut self,
        mean: [f64; 3],
        rgb: [f64; 3],
        rotation: [f64; 4],
        opacity: f64,
        scale: [f64; 3],
    ) {
        self.means.push(mean.map(T::of));
        self.sh_dc.push(rgb.map(|c| T::of(rgb_to_sh_dc(c))));
        self.rotations.push(rotation.map(T::of));
        self.opacity_logits.push(T::of(logit(opacity)));
        self.log_scales.push(scale.map(|s| T::of(s.ln())));
        self.flags.push(0);
    }

    /// Rendered RGB colour of Gaussian `i` (see the module doc).
    pub fn colour(&self, i: usize) -> [f64; 3] {
        self.sh_dc[i].map(|s| sh_dc_to_rgb(s.to_f64()))
    }

    /// Opacity of Gaussian `i`.
    pub fn opacity(&self, i: usize) -> f64 {
        sigmoid(self.opacity_logits[i].to_f64())
    }

    /// Checks that every array has the same length; names the first one that does not.
    pub fn validate(&self) -> Result<(), crate::SplatError> {
        let n = self.means.len();
        let lens = [
            ("sh_dc", self.sh_dc.len()),
            ("rotations", self.rotations.len()),
            ("opacity_logits", self.opacity_logits.len()),
            ("log_scales", self.log_scales.len()),
            ("flags", self.flags.len()),
        ];
        for (name, len) in lens {
            if len != n {
                return Err(crate::SplatError::Length {
                    what: name,
                    expected: n,
                    got: len,
                });
            }
        }
        Ok(())
    }

    /// Keeps the Gaussians whose `keep` entry is true (pruning), preserving order.
    pub fn retain(&mut self, keep: &[bool]) -> Result<(), crate::SplatError> {
        if keep.len() != self.len() {
            return Err(crate::SplatError::Length {
                what: "keep mask",
                expected: self.len(),
                got: keep.len(),
            });
        }
        fn filter<V: Copy>(v: &mut Vec<V>, keep: &[bool]) {
            let mut k = keep.iter();
            v.retain(|_| *k.next().unwrap_or(&false));
        }
        filter(&mut self.means, keep);
        filter(&mut self.sh_dc, keep);
        filter(&mut self.rotations, keep);
        filter(&mut self.opacity_logits, keep);
        filter(&mut self.log_scales, keep);
        filter(&mut self.flags, keep);
        Ok(())
    }

    /// Appends all Gaussians of `other`.
    pub fn extend_from(&mut self, other: &Gaussians<T>) {
        self.means.extend_from_slice(&other.means);
        self.sh_dc.extend_from_slice(&other.sh_dc);
        self.rotations.extend_from_slice(&other.rotations);
        self.opacity_logits.extend_from_slice(&other.opacity_logits);
        self.log_scales.extend_from_slice(&other.log_scales);
        self.flags.extend_from_slice(&other.flags);
    }

    /// The 14 parameters of Gaussian `i` in the [`layout`] order.
    pub fn params(&self, i: usize) -> [T; PARAMS_PER_GAUSSIAN] {
        let (m, c, q, s) = (
            self.means[i],
            self.sh_dc[i],
            self.rotations[i],
            self.log_scales[i],
        );
        [
            m[0],
            m[1],
            m[2],
            c[0],
            c[1],
            c[2],
            q[0],
            q[1],
            q[2],
            q[3],
            self.opacity_logits[i],
            s[0],
            s[1],
            s[2],
        ]
    }

    /// Mutable access to parameter `k` (in the [`layout`] order) of Gaussian `i`.
    pub fn param_mut(&mut self, i: usize, k: usize) -> &mut T {
        match k {
            0..=2 => &mut self.means[i][k],
            3..=5 => &mut self.sh_dc[i][k - 3],
            6..=9 => &mut self.rotations[i][k - 6],
            10 => &mut self.opacity_logits[i],
            _ => &mut self.log_scales[i][k - 11],
        }
    }

    /// Converts to another scalar type (e.g. `f32` maps to `f64` for gradient checks).
    pub fn cast<U: Real>(&self) -> Gaussians<U> {
        let c = |x: T| U::of(x.to_f64());
        Gaussians {
            means: self.means.iter().map(|a| a.map(c)).collect(),
            sh_dc: self.sh_dc.iter().map(|a| a.map(c)).collect(),
            rotations: self.rotations.iter().map(|a| a.map(c)).collect(),
            opacity_logits: self.opacity_logits.iter().map(|&a| c(a)).collect(),
            log_scales: self.log_scales.iter().map(|a| a.map(c)).collect(),
            flags: self.flags.clone(),
        }
    }
}
