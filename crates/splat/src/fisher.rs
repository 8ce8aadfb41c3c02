//! Fisher information of a view (SPEC §5), accumulated in one back-to-front traversal like the
//! backward pass, without building per-pixel Jacobians in memory:
//!
//! - per Gaussian, the diagonal `Σ_pixels (∂f/∂w)²` over its 14 parameters, separately for the
//!   colour outputs `f ∈ {R, G, B}` (after exposure) and the depth output `f = D`. The colour
//!   square is per channel ([`FisherMode::PerChannel`], `Σ_ch (∂f_ch/∂w)²`) or of the channel
//!   sum ([`FisherMode::ChannelSum`], `(Σ_ch ∂f_ch/∂w)²`, as FisherRF);
//! - the 6×6 pose information `J_τᵀ J_τ` for the left update τ = [ρ, θ], summed over pixels and
//!   channels (always per channel), separately for colour and depth.
//!
//! How: per pixel, `∂f/∂u_i = w_f·∂α_i/∂u_i (+ α_i T_i on z for depth)` with
//! `u = (mean_x, mean_y, Q_xx, Q_xy, Q_yy, z, logit)` and the per-pixel scalars `w_f = ∂f/∂α_i`,
//! so each (tile, Gaussian) pair accumulates the 7×7 matrix `Σ_px (∂f/∂u)(∂f/∂u)ᵀ`, and
//! `diag(J_uᵀ M J_u)` with the per-Gaussian projection Jacobian `J_u` gives the parameter
//! diagonal. For the pose, each pixel sums `∂f/∂τ = Σ_i (∂u_i/∂τ)ᵀ ∂f/∂u_i` over its
//! Gaussians in registers, then adds its outer product.

use crate::SplatError;
use crate::backward::{CHUNK, check_pixels, reduce_pairs};
use crate::gaussians::{Gaussians, SH_C0, layout};
use crate::project::{ALPHA_MAX, ALPHA_MIN, SigmaRow, Splat, chain, project_vjp};
use crate::rasterize::{ForwardContext, Render, clip_box};
use crate::real::Real;
use crate::tiles::split_by_offsets;
use nalgebra::Matrix6;
use rayon::prelude::*;

/// How the colour channels enter the per-Gaussian diagonal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FisherMode {
    /// `Σ_ch (∂f_ch/∂w)²`: every channel is an observation.
    #[default]
    PerChannel,
    /// `(Σ_ch ∂f_ch/∂w)²`: FisherRF's convention (sum RGB, then square).
    ChannelSum,
}

/// Fisher information of one view.
#[derive(Debug, Clone, PartialEq)]
pub struct FisherOutput<T: Real> {
    /// Per Gaussian, the colour diagonal in the [`layout`] order.
    pub colour: Vec<[T; 14]>,
    /// Per Gaussian, the depth diagonal in the [`layout`] order (colour entries are 0).
    pub depth: Vec<[T; 14]>,
    /// `J_τᵀ J_τ` of the RGB outputs.
    pub pose_colour: Matrix6<f64>,
    /// `J_τᵀ J_τ` of the depth output.
    pub pose_depth: Matrix6<f64>,
}

impl<T: Real> FisherOutput<T> {
    /// Colour plus `depth_weight` × depth diagonal of Gaussian `i`.
    pub fn combined(&self, i: usize, depth_weight: f64) -> [f64; 14] {
        let mut out = [0.0; 14];
        for (k, o) in out.iter_mut().enumerate() {
            *o = self.colour[i][k].to_f64() + depth_weight * self.depth[i][k].to_f64();
        }
        out
    }

    /// Colour plus `depth_weight` × depth pose information.
    pub fn pose(&self, depth_weight: f64) -> Matrix6<f64> {
        self.pose_colour + self.pose_depth * depth_weight
    }
}

/// Dimension of the intermediate vector `u` (with the opacity logit last).
const U: usize = 7;
/// Packed upper triangle of a 7×7 symmetric matrix.
const PACKED: usize = U * (U + 1) / 2;
/// Slot per pair: colour moments, depth moments, depth cross moments, Σ weight², Σ (∂C/∂sh)².
const SLOT: usize = 2 * MOMENTS + 6 + 2;

/// Per-Gaussian Jacobians: `geo[k][p] = ∂u_k/∂w_p` (p over mean 3, quaternion 4, log-scale 3)
/// and `pose[k][j] = ∂u_k/∂τ_j`, for the 6 geometric entries of `u`.
#[derive(Clone, Copy, Default)]
struct Prep<T: Real> {
    geo: [[T; 10]; 6],
    pose: [[T; 6]; 6],
    /// `pose_l[m][j] = Σ_k L[k][m]·pose[k][j]`: the pose rows folded with [`l_matrix`], so
    /// that `(∂u/∂τ)ᵀ ∂α/∂u = α·Σ_m pose_l[m]·mono[m]`.
    pose_l: [[T; 6]; 6],
}

/// Number of monomials `dx^i·dy^j` with `i + j ≤ 4`.
const MOMENTS: usize = 15;

/// Index of the monomial `dx^i·dy^j` in the moment arrays (degree-major, then by `j`).
const fn moment_index(i: usize, j: usize) -> usize {
    let d = i + j;
    d * (d + 1) / 2 + j
}

/// Exponents of the 6 monomials `m = (1, dx, dy, dx², dx·dy, dy²)`.
const MONO_EXP: [(usize, usize); 6] = [(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)];

/// `L` with `∂α/∂u = α·L·m` (unclamped alpha), rows over `u`, columns over `m`:
/// `∂σ/∂mean = (Q_xx dx + Q_xy dy, Q_xy dx + Q_yy dy)`, `∂σ/∂Q = (½dx², dx dy, ½dy²)`,
/// `∂α/∂σ = −α`, `∂α/∂logit = α(1 − o)`.
fn l_matrix<T: Real>(s: &Splat<T>) -> [[T; 6]; U] {
    let z = T::zero();
    let [qa, qb, qc] = s.conic;
    let h = T::of(0.5);
    [
        [z, -qa, -qb, z, z, z],
        [z, -qb, -qc, z, z, z],
        [z, z, z, -h, z, z],
        [z, z, z, z, -T::one(), z],
        [z, z, z, z, z, -h],
        [z; 6],
        [T::one() - s.opacity, z, z, z, z, z],
    ]
}

/// Rebuilds `Σ e·(∂α/∂u)(∂α/∂u)ᵀ = L·(Σ e·α²·m mᵀ)·Lᵀ` from the moments, plus the depth terms
/// `c e₅ᵀ + e₅ cᵀ` (with `c = L·cross`) and `weight_sq·e₅e₅ᵀ`, packed upper-triangular.
fn moments_to_packed<T: Real>(
    mom: &[T; MOMENTS],
    l: &[[T; 6]; U],
    cross: &[T; 6],
    weight_sq: T,
) -> [T; PACKED] {
    let mut mm = [[T::zero(); 6]; 6];
    for (a, ea) in MONO_EXP.iter().enumerate() {
        for (b, eb) in MONO_EXP.iter().enumerate() {
            mm[a][b] = mom[moment_index(ea.0 + eb.0, ea.1 + eb.1)];
        }
    }
    let mut lm = [[T::zero(); 6]; U];
    for k in 0..U {
        for b in 0..6 {
            let mut acc = T::zero();
            for a in 0..6 {
                acc += l[k][a] * mm[a][b];
            }
            lm[k][b] = acc;
        }
    }
    let mut c = [T::zero(); U];
    for k in 0..U {
        for a in 0..6 {
            c[k] += l[k][a] * cross[a];
        }
    }
    let mut out = [T::zero(); PACKED];
    let mut idx = 0;
    for k in 0..U {
        for q in k..U {
            let mut acc = T::zero();
            for b in 0..6 {
                acc += lm[k][b] * l[q][b];
            }
            if q == 5 {
                acc += c[k];
            }
            if k == 5 {
                acc += c[q];
            }
            if k == 5 && q == 5 {
                acc += weight_sq;
            }
            out[idx] = acc;
            idx += 1;
        }
    }
    out
}

/// `diag(Jᵀ M J)` over the geometric parameters plus the logit entry `M_66`.
fn project_diag<T: Real>(m: &[T; PACKED], prep: &Prep<T>) -> ([T; 10], T) {
    let mut full = [[T::zero(); U]; U];
    let mut idx = 0;
    for k in 0..U {
        for l in k..U {
            full[k][l] = m[idx];
            full[l][k] = m[idx];
            idx += 1;
        }
    }
    let mut diag = [T::zero(); 10];
    for (p, d) in diag.iter_mut().enumerate() {
        let mut acc = T::zero();
        for k in 0..6 {
            let jk = prep.geo[k][p];
            let mut row = T::zero();
            for l in 0..6 {
                row += full[k][l] * prep.geo[l][p];
            }
            acc += jk * row;
        }
        *d = acc;
    }
    (diag, full[6][6])
}

/// Per-pixel state of the Fisher walk.
#[derive(Clone, Copy)]
struct FisherPixel<T: Real> {
    /// Transmittance behind the current Gaussian (starts at T_final).
    t: T,
    /// Number of composited list entries.
    last: usize,
    /// Colour and depth composited behind the current Gaussian.
    s_col: [T; 3],
    s_dep: T,
    /// ∂(colour channel)/∂τ and ∂depth/∂τ of this pixel, summed over its Gaussians.
    jt_col: [[T; 6]; 3],
    jt_dep: [T; 6],
}

/// Per-tile result: the two packed 6×6 pose matrices.
type PosePart = ([f64; 36], [f64; 36]);

#[allow(clippy::too_many_arguments)]
fn fisher_tile<T: Real>(
    splats: &[Splat<T>],
    preps: &[Prep<T>],
    list: &[u32],
    rect: [usize; 4],
    width: usize,
    ctx: &ForwardContext<T>,
    gain: T,
    mode: FisherMode,
    slots: &mut [T],
) -> PosePart {
    let tw = rect[1] - rect[0];
    let n = tw * (rect[3] - rect[2]);
    let mut pixels = Vec::with_capacity(n);
    for py in rect[2]..rect[3] {
        for px in rect[0]..rect[1] {
            pixels.push(FisherPixel {
                t: ctx.final_transmittance[py * width + px],
                last: ctx.contributors[py * width + px] as usize,
                s_col: [T::zero(); 3],
                s_dep: T::zero(),
                jt_col: [[T::zero(); 6]; 3],
                jt_dep: [T::zero(); 6],
            });
        }
    }
    let kmax = pixels.iter().map(|p| p.last).max().unwrap_or(0);
    let (alpha_min, alpha_max) = (T::of(ALPHA_MIN), T::of(ALPHA_MAX));
    let colour_scale = gain * T::of(SH_C0);
    for k in (0..kmax).rev() {
        let id = list[k] as usize;
        let s = &splats[id];
        let prep = &preps[id];
        let Some([bx0, bx1, by0, by1]) = clip_box(s, &rect) else {
            continue;
        };
        // Moments Σ e·dx^i·dy^j (i + j ≤ 4) per stream, see `moments_to_packed`.
        let mut mom_col = [T::zero(); MOMENTS];
        let mut mom_dep = [T::zero(); MOMENTS];
        let mut cross = [T::zero(); 6];
        let mut weight_sq = T::zero();
        let mut colour_acc = T::zero();
        let pl = &prep.pose_l;
        for py in by0..=by1 {
            let dy = s.mean[1] - T::of(py as f64);
            let row_sigma = SigmaRow::new(s, dy);
            let row = (py - rect[2]) * tw;
            let dy2 = dy * dy;
            // Per-row sums Σ_px e·dx^i; the dy powers are applied once per row below.
            let mut row_col = [T::zero(); 5];
            let mut row_dep = [T::zero(); 5];
            let mut row_cross = [T::zero(); 3];
            // v = Σ_m pl[m]·mono[m] = r + dx·q + dx²·pl[3] with per-row r, q.
            let r: [T; 6] = std::array::from_fn(|j| pl[2][j] * dy + pl[5][j] * dy2);
            let q: [T; 6] = std::array::from_fn(|j| pl[1][j] + pl[4][j] * dy);
            let mut pxf = T::of(bx0 as f64);
            for st in &mut pixels[row + bx0 - rect[0]..=row + bx1 - rect[0]] {
                let dx = s.mean[0] - pxf;
                pxf += T::one();
                if k >= st.last {
                    continue;
                }
                let sigma = row_sigma.sigma(dx);
                if sigma < T::zero() {
                    continue;
                }
                let raw = s.opacity * (-sigma).exp();
                let alpha = raw.min(alpha_max);
                if alpha < alpha_min {
                    continue;
                }
                let inv_one_minus = T::one() / (T::one() - alpha);
                let t_i = st.t * inv_one_minus;
                let weight = alpha * t_i;
                let mut w = [T::zero(); 3];
                for ch in 0..3 {
                    w[ch] = gain * (s.colour[ch] * t_i - st.s_col[ch] * inv_one_minus);
                    st.s_col[ch] += s.colour[ch] * weight;
                }
                let w_d = s.depth * t_i - st.s_dep * inv_one_minus;
                st.s_dep += s.depth * weight;
                st.t = t_i;
                let cw = colour_scale * weight;
                colour_acc += cw * cw;
                weight_sq += weight * weight;
                if raw >= alpha_max {
                    // Clamped alpha: only the depth value itself depends on the parameters.
                    for j in 0..6 {
                        st.jt_dep[j] += weight * prep.pose[5][j];
                    }
                    continue;
                }
                let colour_weight = match mode {
                    FisherMode::PerChannel => w[0] * w[0] + w[1] * w[1] + w[2] * w[2],
                    FisherMode::ChannelSum => {
                        let sum = w[0] + w[1] + w[2];
                        sum * sum
                    }
                };
                let a2 = alpha * alpha;
                let e_col = colour_weight * a2;
                let e_dep = w_d * w_d * a2;
                let e_cross = w_d * weight * alpha;
                let dx2 = dx * dx;
                let powers = [T::one(), dx, dx2, dx2 * dx, dx2 * dx2];
                for i in 0..5 {
                    row_col[i] += e_col * powers[i];
                    row_dep[i] += e_dep * powers[i];
                }
                for i in 0..3 {
                    row_cross[i] += e_cross * powers[i];
                }
                // Pose: v = (∂u/∂τ)ᵀ ∂α/∂u = α·Σ_m pl[m]·mono[m].
                let mut v = [T::zero(); 6];
                for j in 0..6 {
                    v[j] = alpha * (r[j] + dx * q[j] + dx2 * pl[3][j]);
                }
                for ch in 0..3 {
                    for j in 0..6 {
                        st.jt_col[ch][j] += w[ch] * v[j];
                    }
                }
                for j in 0..6 {
                    st.jt_dep[j] += w_d * v[j] + weight * prep.pose[5][j];
                }
            }
            let dy_pow = [T::one(), dy, dy2, dy2 * dy, dy2 * dy2];
            for i in 0..5 {
                for j in 0..5 - i {
                    mom_col[moment_index(i, j)] += row_col[i] * dy_pow[j];
                    mom_dep[moment_index(i, j)] += row_dep[i] * dy_pow[j];
                }
            }
            // cross over m = (1, dx, dy, dx², dx·dy, dy²).
            cross[0] += row_cross[0];
            cross[1] += row_cross[1];
            cross[2] += row_cross[0] * dy;
            cross[3] += row_cross[2];
            cross[4] += row_cross[1] * dy;
            cross[5] += row_cross[0] * dy2;
        }
        let slot = &mut slots[k * SLOT..(k + 1) * SLOT];
        slot[..MOMENTS].copy_from_slice(&mom_col);
        slot[MOMENTS..2 * MOMENTS].copy_from_slice(&mom_dep);
        slot[2 * MOMENTS..2 * MOMENTS + 6].copy_from_slice(&cross);
        slot[SLOT - 2] = weight_sq;
        slot[SLOT - 1] = colour_acc;
    }
    let mut pose_col = [T::zero(); 36];
    let mut pose_dep = [T::zero(); 36];
    for st in &pixels {
        for a in 0..6 {
            for b in 0..6 {
                let mut c = T::zero();
                for ch in 0..3 {
                    c += st.jt_col[ch][a] * st.jt_col[ch][b];
                }
                pose_col[a * 6 + b] += c;
                pose_dep[a * 6 + b] += st.jt_dep[a] * st.jt_dep[b];
            }
        }
    }
    (pose_col.map(|v| v.to_f64()), pose_dep.map(|v| v.to_f64()))
}

/// Fisher information of the view rendered in `render` (SPEC §5). `gaussians` must be the set
/// `render` was computed from. Cost: a small multiple of one [`crate::backward`] pass.
pub fn fisher<T: Real>(
    gaussians: &Gaussians<T>,
    render: &Render<T>,
    mode: FisherMode,
) -> Result<FisherOutput<T>, SplatError> {
    let ctx = &render.context;
    check_pixels(
        "gaussians (vs. the render)",
        gaussians.len(),
        ctx.splats.len(),
    )?;
    let n = gaussians.len();
    let mut preps = vec![Prep::<T>::default(); n];
    preps
        .par_chunks_mut(CHUNK)
        .enumerate()
        .for_each(|(chunk, part)| {
            for (j, prep) in part.iter_mut().enumerate() {
                let i = chunk * CHUNK + j;
                if !ctx.visible[i] {
                    continue;
                }
                let Some(c) = chain(&ctx.cam, gaussians, i) else {
                    continue;
                };
                for k in 0..6 {
                    let mut up = [T::zero(); 6];
                    up[k] = T::one();
                    let g = project_vjp(&c, &ctx.cam, &up);
                    prep.geo[k] = [
                        g.mean[0],
                        g.mean[1],
                        g.mean[2],
                        g.rotation[0],
                        g.rotation[1],
                        g.rotation[2],
                        g.rotation[3],
                        g.log_scale[0],
                        g.log_scale[1],
                        g.log_scale[2],
                    ];
                    prep.pose[k] = g.pose;
                }
                let lmat = l_matrix(&ctx.splats[i]);
                for (m, plm) in prep.pose_l.iter_mut().enumerate() {
                    for (k, lrow) in lmat.iter().take(5).enumerate() {
                        for j in 0..6 {
                            plm[j] += lrow[m] * prep.pose[k][j];
                        }
                    }
                }
            }
        });
    let gain = T::of(ctx.options.exposure[0].exp());
    let bins = &ctx.bins;
    let mut slots = vec![T::zero(); bins.pair_count() * SLOT];
    let parts: Vec<PosePart> = {
        let pieces = split_by_offsets(&mut slots, &bins.offsets, SLOT);
        pieces
            .into_par_iter()
            .with_max_len(1)
            .enumerate()
            .map(|(t, piece)| {
                let rect = bins.tile_rect(t, render.width, render.height);
                fisher_tile(
                    &ctx.splats,
                    &preps,
                    bins.tile(t),
                    rect,
                    render.width,
                    ctx,
                    gain,
                    mode,
                    piece,
                )
            })
            .collect()
    };
    let per_gaussian: Vec<[T; SLOT]> = reduce_pairs(&bins.ids, &slots, n);
    let mut colour = vec![[T::zero(); 14]; n];
    let mut depth = vec![[T::zero(); 14]; n];
    colour
        .par_chunks_mut(CHUNK)
        .zip(depth.par_chunks_mut(CHUNK))
        .enumerate()
        .for_each(|(chunk, (col, dep))| {
            for j in 0..col.len() {
                let i = chunk * CHUNK + j;
                if !ctx.visible[i] {
                    continue;
                }
                let acc = &per_gaussian[i];
                let lmat = l_matrix(&ctx.splats[i]);
                let moments =
                    |from: usize| -> [T; MOMENTS] { std::array::from_fn(|q| acc[from + q]) };
                let cross: [T; 6] = std::array::from_fn(|q| acc[2 * MOMENTS + q]);
                let m_col = moments_to_packed(&moments(0), &lmat, &[T::zero(); 6], T::zero());
                let m_dep = moments_to_packed(&moments(MOMENTS), &lmat, &cross, acc[SLOT - 2]);
                for (out, m, colour_v) in [
                    (&mut col[j], &m_col, acc[SLOT - 1]),
                    (&mut dep[j], &m_dep, T::zero()),
                ] {
                    let (geo, logit_v) = project_diag(m, &preps[i]);
                    out[layout::MEAN..layout::MEAN + 3].copy_from_slice(&geo[0..3]);
                    out[layout::COLOUR..layout::COLOUR + 3].fill(colour_v);
                    out[layout::ROTATION..layout::ROTATION + 4].copy_from_slice(&geo[3..7]);
                    out[layout::OPACITY] = logit_v;
                    out[layout::LOG_SCALE..layout::LOG_SCALE + 3].copy_from_slice(&geo[7..10]);
                }
            }
        });
    let mut pose_colour = Matrix6::zeros();
    let mut pose_depth = Matrix6::zeros();
    for (pc, pd) in parts {
        for a in 0..6 {
            for b in 0..6 {
                pose_colour[(a, b)] += pc[a * 6 + b];
                pose_depth[(a, b)] += pd[a * 6 + b];
            }
        }
    }
    Ok(FisherOutput {
        colour,
        depth,
        pose_colour,
        pose_depth,
    })
}
