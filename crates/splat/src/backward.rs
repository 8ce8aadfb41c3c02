//! The backward pass: analytic gradients of any per-pixel loss, given its gradients on the
//! rendered colour (after exposure), depth and opacity images, with respect to all 14
//! parameters of every Gaussian, the camera pose τ = [ρ, θ] (left update, SPEC §2–§3) and the
//! exposure `(a, b)`.
//!
//! Per pixel and Gaussian `i` (transmittance `T_i` in front of it, `S` the colour/depth
//! composited behind it): `∂C/∂c_i = α_i T_i`, `∂C/∂α_i = c_i T_i − S_C/(1 − α_i)`,
//! `∂D/∂α_i = z_i T_i − S_D/(1 − α_i)`, `∂O/∂α_i = T_final/(1 − α_i)`; `α = o·e^{−σ}` (zero
//! gradient where the 0.99 clamp is active). Tiles are walked back to front, Gaussian-major, by
//! the traversal shared with the Fisher pass ([`crate::walk`]); each (tile, Gaussian) pair
//! writes its own partial sums, reduced afterwards in a fixed order, so the result does not
//! depend on the number of threads.

use crate::SplatError;
use crate::gaussians::{Gaussians, SH_C0};
use crate::project::{Splat, chain, project_vjp};
use crate::rasterize::Render;
use crate::real::Real;
use crate::walk::{
    BackSink, LANES, Lanes, PADDED, lane_sum, lanes, reduce_slots, walk_back, walk_tiles,
};
use nalgebra::Vector6;
use rayon::prelude::*;

/// Gradients of a loss on the rendered images (row-major, one entry per pixel).
#[derive(Debug, Clone, PartialEq)]
pub struct PixelGrads<T: Real> {
    /// ∂L/∂(output colour, after exposure).
    pub colour: Vec<[T; 3]>,
    /// ∂L/∂depth.
    pub depth: Vec<T>,
    /// ∂L/∂opacity.
    pub opacity: Vec<T>,
}

impl<T: Real> PixelGrads<T> {
    /// All-zero gradients for an image of `pixels` pixels.
    pub fn zeros(pixels: usize) -> Self {
        Self {
            colour: vec![[T::zero(); 3]; pixels],
            depth: vec![T::zero(); pixels],
            opacity: vec![T::zero(); pixels],
        }
    }
}

/// Gradients of the loss, laid out like [`Gaussians`].
#[derive(Debug, Clone, PartialEq)]
pub struct Gradients<T: Real> {
    /// ∂L/∂mean.
    pub means: Vec<[T; 3]>,
    /// ∂L/∂sh_dc.
    pub sh_dc: Vec<[T; 3]>,
    /// ∂L/∂quaternion (unnormalised).
    pub rotations: Vec<[T; 4]>,
    /// ∂L/∂opacity logit.
    pub opacity_logits: Vec<T>,
    /// ∂L/∂log-scale.
    pub log_scales: Vec<[T; 3]>,
    /// |∂L/∂(projected mean)| in pixels⁻¹: the 3DGS densification statistic.
    pub mean2d_norm: Vec<T>,
    /// ∂L/∂τ, τ = [ρ, θ] of the left update `T_cw ← Exp(τ)·T_cw`.
    pub pose: Vector6<f64>,
    /// ∂L/∂(a, b) of the exposure `e^a·colour + b`.
    pub exposure: [f64; 2],
}

impl<T: Real> Gradients<T> {
    /// The 14 gradients of Gaussian `i` in the [`crate::gaussians::layout`] order.
    pub fn params(&self, i: usize) -> [T; 14] {
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
}

/// Values per (tile, Gaussian) pair: ∂L/∂(mean_x, mean_y, Q_xx, Q_xy, Q_yy, z, opacity, r, g, b)
/// and ∂L/∂(depth slope) ([`crate::DepthModel::Plane`]).
const SLOT: usize = 12;

/// Checks that per-pixel images have the right length.
pub(crate) fn check_pixels(
    what: &'static str,
    got: usize,
    expected: usize,
) -> Result<(), SplatError> {
    if got == expected {
        Ok(())
    } else {
        Err(SplatError::Length {
            what,
            expected,
            got,
        })
    }
}

/// What the backward pass accumulates along the shared back-to-front walk
/// ([`crate::walk::walk_back`]): per pixel the upstream gradients, per (tile, Gaussian) pair
/// the [`SLOT`] partial sums.
struct BackwardSink<'a, T: Real> {
    pixel_grads: &'a PixelGrads<T>,
    final_transmittance: &'a [T],
    gain: T,
    /// ∂L/∂(raw colour) = e^a·∂L/∂(output colour), per tile-local pixel.
    g_col: [[T; PADDED]; 3],
    /// ∂L/∂depth.
    g_dep: [T; PADDED],
    /// ∂L/∂opacity · T_final (∂O/∂α_i = T_final/(1 − α_i)).
    g_t: [T; PADDED],
    /// The current pair's splat.
    splat: Splat<T>,
    /// Per-lane row sums of ∂L/∂σ·dx^i, i = 0, 1, 2, and of ∂L/∂z_pixel·dx^i, i = 0, 1 (the
    /// pixel depth `z − s·d` of the plane model); the dy factors are applied per row.
    row: [[T; LANES]; 5],
    /// Per-lane pair sums of ∂L/∂(r, g, b), ∂L/∂z, ∂L/∂o.
    pair: [[T; LANES]; 5],
    /// ∂L/∂(mean_x, mean_y, Q_xx, Q_xy, Q_yy) and ∂L/∂(depth slope) of the current pair.
    geo: [T; 7],
    /// This tile's pair slots.
    slots: &'a mut [T],
}

impl<T: Real> BackSink<T, LANES> for BackwardSink<'_, T> {
    #[inline(always)]
    fn init_pixel(&mut self, local: usize, pixel: usize) {
        let g = self.pixel_grads.colour[pixel];
        for ch in 0..3 {
            self.g_col[ch][local] = g[ch] * self.gain;
        }
        self.g_dep[local] = self.pixel_grads.depth[pixel];
        self.g_t[local] = self.pixel_grads.opacity[pixel] * self.final_transmittance[pixel];
    }

    #[inline(always)]
    fn begin_pair(&mut self, _id: usize, splat: &Splat<T>) {
        self.splat = *splat;
        self.pair = [[T::zero(); LANES]; 5];
        self.geo = [T::zero(); 7];
    }

    #[inline(always)]
    fn begin_row(&mut self, _dy: T) {
        self.row = [[T::zero(); LANES]; 5];
    }

    #[inline(always)]
    fn step(&mut self, base: usize, _chunk: usize, ln: &Lanes<T, LANES>) {
        let s = &self.splat;
        let g_col = [
            *lanes(&self.g_col[0], base),
            *lanes(&self.g_col[1], base),
            *lanes(&self.g_col[2], base),
        ];
        let g_dep = lanes(&self.g_dep, base);
        let g_t = lanes(&self.g_t, base);
        // Local copies of the accumulators keep the lane loop free of aliasing, so it vectorises.
        let mut pair = self.pair;
        let mut row = self.row;
        for l in 0..LANES {
            let (t_i, inv, weight) = (ln.t_i[l], ln.inv[l], ln.weight[l]);
            let mut d_alpha =
                g_dep[l].mul_add(ln.depth[l].mul_add(t_i, -(ln.s_dep[l] * inv)), g_t[l] * inv);
            for ch in 0..3 {
                let behind = s.colour[ch].mul_add(t_i, -(ln.s_col[ch][l] * inv));
                d_alpha = g_col[ch][l].mul_add(behind, d_alpha);
                pair[ch][l] = g_col[ch][l].mul_add(weight, pair[ch][l]);
            }
            pair[3][l] = g_dep[l].mul_add(weight, pair[3][l]);
            let d_depth = g_dep[l] * weight;
            let d_alpha = d_alpha * ln.grad[l];
            pair[4][l] = d_alpha.mul_add(ln.gauss[l], pair[4][l]);
            let d_sigma = -d_alpha * ln.alpha[l];
            let dx = ln.dx[l];
            let d_sigma_dx = d_sigma * dx;
            row[0][l] += d_sigma;
            row[1][l] += d_sigma_dx;
            row[2][l] = d_sigma_dx.mul_add(dx, row[2][l]);
            row[3][l] += d_depth;
            row[4][l] = d_depth.mul_add(dx, row[4][l]);
        }
        self.pair = pair;
        self.row = row;
    }

    #[inline(always)]
    fn end_row(&mut self, dy: T) {
        let [qa, qb, qc] = self.splat.conic;
        let row = self.row.map(|r| lane_sum(&r));
        // ∂σ/∂mean = (Q_xx dx + Q_xy dy, Q_xy dx + Q_yy dy), ∂σ/∂Q = (½dx², dx dy, ½dy²).
        let half = T::of(0.5);
        self.geo[0] += qa * row[1] + qb * dy * row[0];
        self.geo[1] += qb * row[1] + qc * dy * row[0];
        self.geo[2] += half * row[2];
        self.geo[3] += dy * row[1];
        self.geo[4] += half * dy * dy * row[0];
        // z_pixel = z − s·d with d = (dx, dy): ∂z_pixel/∂s = −d.
        self.geo[5] -= row[4];
        self.geo[6] -= dy * row[3];
    }

    #[inline(always)]
    fn end_pair(&mut self, k: usize) {
        let p = self.pair.map(|v| lane_sum(&v));
        let g = self.geo;
        // z_pixel = z − s·(mean − pixel): ∂z_pixel/∂mean = −s (zero under the centre model).
        let slope = self.splat.depth_slope;
        let (mean_x, mean_y) = (g[0] - slope[0] * p[3], g[1] - slope[1] * p[3]);
        self.slots[k * SLOT..(k + 1) * SLOT].copy_from_slice(&[
            mean_x, mean_y, g[2], g[3], g[4], p[3], p[4], p[0], p[1], p[2], g[5], g[6],
        ]);
    }
}

/// Gaussians per chunk in per-Gaussian parallel loops whose partial sums are reduced in order.
pub(crate) const CHUNK: usize = 512;

/// Gradients of a per-pixel loss (given by `pixel_grads`) w.r.t. every parameter, the pose and
/// the exposure. `gaussians` must be the set `render` was computed from.
pub fn backward<T: Real>(
    gaussians: &Gaussians<T>,
    render: &Render<T>,
    pixel_grads: &PixelGrads<T>,
) -> Result<Gradients<T>, SplatError> {
    let ctx = &render.context;
    let n_pix = render.width * render.height;
    check_pixels(
        "gaussians (vs. the render)",
        gaussians.len(),
        ctx.splats.len(),
    )?;
    check_pixels("pixel_grads.colour", pixel_grads.colour.len(), n_pix)?;
    check_pixels("pixel_grads.depth", pixel_grads.depth.len(), n_pix)?;
    check_pixels("pixel_grads.opacity", pixel_grads.opacity.len(), n_pix)?;
    let gain_f64 = ctx.options.exposure[0].exp();
    let gain = T::of(gain_f64);
    let (slots, _) = walk_tiles(ctx, SLOT, |t, piece| {
        let mut sink = BackwardSink {
            pixel_grads,
            final_transmittance: &ctx.final_transmittance,
            gain,
            g_col: [[T::zero(); PADDED]; 3],
            g_dep: [T::zero(); PADDED],
            g_t: [T::zero(); PADDED],
            splat: Splat::default(),
            row: [[T::zero(); LANES]; 5],
            pair: [[T::zero(); LANES]; 5],
            geo: [T::zero(); 7],
            slots: piece,
        };
        walk_back(ctx, t, &mut sink);
    });
    let per_gaussian: Vec<[T; SLOT]> = reduce_slots(ctx, &slots, gaussians.len());
    let n = gaussians.len();
    let mut out = Gradients {
        means: vec![[T::zero(); 3]; n],
        sh_dc: vec![[T::zero(); 3]; n],
        rotations: vec![[T::zero(); 4]; n],
        opacity_logits: vec![T::zero(); n],
        log_scales: vec![[T::zero(); 3]; n],
        mean2d_norm: vec![T::zero(); n],
        pose: Vector6::zeros(),
        exposure: [0.0; 2],
    };
    let c0 = T::of(SH_C0);
    let plane = ctx.options.depth == crate::DepthModel::Plane;
    let pose_parts: Vec<[f64; 6]> = out
        .means
        .par_chunks_mut(CHUNK)
        .zip(out.sh_dc.par_chunks_mut(CHUNK))
        .zip(out.rotations.par_chunks_mut(CHUNK))
        .zip(out.opacity_logits.par_chunks_mut(CHUNK))
        .zip(out.log_scales.par_chunks_mut(CHUNK))
        .zip(out.mean2d_norm.par_chunks_mut(CHUNK))
        .enumerate()
        .map(|(chunk, (((((means, sh), rots), ops), scales), m2d))| {
            let mut pose = [0.0f64; 6];
            for j in 0..means.len() {
                let i = chunk * CHUNK + j;
                if !ctx.visible[i] {
                    continue;
                }
                let acc = &per_gaussian[i];
                let Some(c) = chain(&ctx.cam, gaussians, i) else {
                    continue;
                };
                let up = [acc[0], acc[1], acc[2], acc[3], acc[4], acc[5]];
                // Under the centre model the slope is identically zero, not a function of
                // the parameters: its gradient goes nowhere.
                let slope_up = if plane {
                    [acc[10], acc[11]]
                } else {
                    [T::zero(); 2]
                };
                let pg = project_vjp(&c, &ctx.cam, &up, slope_up);
                means[j] = pg.mean;
                rots[j] = pg.rotation;
                scales[j] = pg.log_scale;
                let o = ctx.splats[i].opacity;
                ops[j] = acc[6] * o * (T::one() - o);
                sh[j] = [acc[7] * c0, acc[8] * c0, acc[9] * c0];
                m2d[j] = (acc[0] * acc[0] + acc[1] * acc[1]).sqrt();
                for (p, g) in pose.iter_mut().zip(pg.pose) {
                    *p += g.to_f64();
                }
            }
            pose
        })
        .collect();
    for part in pose_parts {
        for k in 0..6 {
            out.pose[k] += part[k];
        }
    }
    let (mut da, mut db) = (0.0, 0.0);
    for (g, c) in pixel_grads.colour.iter().zip(&ctx.raw_colour) {
        for ch in 0..3 {
            da += g[ch].to_f64() * gain_f64 * c[ch].to_f64();
            db += g[ch].to_f64();
        }
    }
    out.exposure = [da, db];
    Ok(out)
}
