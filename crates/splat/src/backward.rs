//! The backward pass: analytic gradients of any per-pixel loss, given its gradients on the
//! rendered colour (after exposure), depth and opacity images, with respect to all 14
//! parameters of every Gaussian, the camera pose τ = [ρ, θ] (left update, SPEC §2–§3) and the
//! exposure `(a, b)`.
//!
//! Per pixel and Gaussian `i` (transmittance `T_i` in front of it, `S` the colour/depth
//! composited behind it): `∂C/∂c_i = α_i T_i`, `∂C/∂α_i = c_i T_i − S_C/(1 − α_i)`,
//! `∂D/∂α_i = z_i T_i − S_D/(1 − α_i)`, `∂O/∂α_i = T_final/(1 − α_i)`; `α = o·e^{−σ}` (zero
//! gradient where the 0.99 clamp is active). Tiles are walked back to front, Gaussian-major;
//! each (tile, Gaussian) pair writes its own partial sums, reduced afterwards in a fixed order,
//! so the result does not depend on the number of threads.

use crate::SplatError;
use crate::gaussians::{Gaussians, SH_C0};
use crate::project::{ALPHA_MAX, ALPHA_MIN, SigmaRow, Splat, chain, project_vjp};
use crate::rasterize::{ForwardContext, Render, clip_box};
use crate::real::Real;
use crate::tiles::split_by_offsets;
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

/// Values per (tile, Gaussian) pair: ∂L/∂(mean_x, mean_y, Q_xx, Q_xy, Q_yy, z, opacity, r, g, b).
const SLOT: usize = 10;

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

/// Per-pixel state of the backward walk.
#[derive(Clone, Copy)]
struct BackPixel<T: Real> {
    /// Transmittance behind the current Gaussian (starts at T_final).
    t: T,
    /// Number of composited list entries.
    last: usize,
    /// ∂L/∂(raw colour) = e^a·∂L/∂(output colour).
    g_col: [T; 3],
    g_dep: T,
    /// ∂L/∂opacity · T_final.
    g_t: T,
    /// Colour and depth composited behind the current Gaussian.
    s_col: [T; 3],
    s_dep: T,
}

/// Back-to-front walk of one tile writing the pair slots.
#[allow(clippy::too_many_arguments)]
fn backward_tile<T: Real>(
    splats: &[Splat<T>],
    list: &[u32],
    rect: [usize; 4],
    width: usize,
    ctx: &ForwardContext<T>,
    grads: &PixelGrads<T>,
    gain: T,
    slots: &mut [T],
) {
    let tw = rect[1] - rect[0];
    let mut pixels = Vec::with_capacity(tw * (rect[3] - rect[2]));
    for py in rect[2]..rect[3] {
        for px in rect[0]..rect[1] {
            let i = py * width + px;
            pixels.push(BackPixel {
                t: ctx.final_transmittance[i],
                last: ctx.contributors[i] as usize,
                g_col: grads.colour[i].map(|g| g * gain),
                g_dep: grads.depth[i],
                // ∂O/∂α_i = T_final/(1 − α_i): keep gO·T_final.
                g_t: grads.opacity[i] * ctx.final_transmittance[i],
                s_col: [T::zero(); 3],
                s_dep: T::zero(),
            });
        }
    }
    let kmax = pixels.iter().map(|p| p.last).max().unwrap_or(0);
    let (half, alpha_min, alpha_max) = (T::of(0.5), T::of(ALPHA_MIN), T::of(ALPHA_MAX));
    for k in (0..kmax).rev() {
        let s = &splats[list[k] as usize];
        let Some([bx0, bx1, by0, by1]) = clip_box(s, &rect) else {
            continue;
        };
        let [qa, qb, qc] = s.conic;
        let mut acc = [T::zero(); SLOT];
        for py in by0..=by1 {
            let dy = s.mean[1] - T::of(py as f64);
            let row_sigma = SigmaRow::new(s, dy);
            let start = (py - rect[2]) * tw + bx0 - rect[0];
            // Row sums of ∂L/∂σ·dx^i; the dy factors are applied once per row.
            let mut row = [T::zero(); 3];
            let mut pxf = T::of(bx0 as f64);
            for st in &mut pixels[start..start + (bx1 - bx0 + 1)] {
                let dx = s.mean[0] - pxf;
                pxf += T::one();
                if k >= st.last {
                    continue;
                }
                let sigma = row_sigma.sigma(dx);
                if sigma < T::zero() {
                    continue;
                }
                let gauss = (-sigma).exp();
                let raw = s.opacity * gauss;
                let alpha = raw.min(alpha_max);
                if alpha < alpha_min {
                    continue;
                }
                let inv_one_minus = T::one() / (T::one() - alpha);
                let t_i = st.t * inv_one_minus;
                let weight = alpha * t_i;
                let gc = st.g_col;
                let mut d_alpha =
                    st.g_dep * (s.depth * t_i - st.s_dep * inv_one_minus) + st.g_t * inv_one_minus;
                for ch in 0..3 {
                    d_alpha += gc[ch] * (s.colour[ch] * t_i - st.s_col[ch] * inv_one_minus);
                    acc[7 + ch] += gc[ch] * weight;
                    st.s_col[ch] += s.colour[ch] * weight;
                }
                acc[5] += st.g_dep * weight;
                st.s_dep += s.depth * weight;
                st.t = t_i;
                if raw < alpha_max {
                    acc[6] += d_alpha * gauss;
                    let d_sigma = -d_alpha * alpha;
                    row[0] += d_sigma;
                    row[1] += d_sigma * dx;
                    row[2] += d_sigma * dx * dx;
                }
            }
            // ∂σ/∂mean = (Q_xx dx + Q_xy dy, Q_xy dx + Q_yy dy), ∂σ/∂Q = (½dx², dx dy, ½dy²).
            acc[0] += qa * row[1] + qb * dy * row[0];
            acc[1] += qb * row[1] + qc * dy * row[0];
            acc[2] += half * row[2];
            acc[3] += dy * row[1];
            acc[4] += half * dy * dy * row[0];
        }
        slots[k * SLOT..(k + 1) * SLOT].copy_from_slice(&acc);
    }
}

/// Sums the pair slots per Gaussian, in pair order (deterministic).
pub(crate) fn reduce_pairs<T: Real, const N: usize>(
    ids: &[u32],
    slots: &[T],
    gaussians: usize,
) -> Vec<[T; N]> {
    let mut out = vec![[T::zero(); N]; gaussians];
    for (pair, &id) in ids.iter().enumerate() {
        let dst = &mut out[id as usize];
        for (d, s) in dst.iter_mut().zip(&slots[pair * N..(pair + 1) * N]) {
            *d += *s;
        }
    }
    out
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
    let bins = &ctx.bins;
    let mut slots = vec![T::zero(); bins.pair_count() * SLOT];
    {
        let pieces = split_by_offsets(&mut slots, &bins.offsets, SLOT);
        pieces
            .into_par_iter()
            .with_max_len(1)
            .enumerate()
            .for_each(|(t, piece)| {
                let rect = bins.tile_rect(t, render.width, render.height);
                backward_tile(
                    &ctx.splats,
                    bins.tile(t),
                    rect,
                    render.width,
                    ctx,
                    pixel_grads,
                    gain,
                    piece,
                );
            });
    }
    let per_gaussian: Vec<[T; SLOT]> = reduce_pairs(&bins.ids, &slots, gaussians.len());
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
                let pg = project_vjp(&c, &ctx.cam, &up);
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
