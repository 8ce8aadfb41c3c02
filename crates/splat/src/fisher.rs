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
use crate::backward::{CHUNK, check_pixels};
use crate::gaussians::{Gaussians, SH_C0, layout};
use crate::project::{Splat, chain, project_vjp};
use crate::rasterize::Render;
use crate::real::Real;
use crate::walk::{
    BackSink, LANES, Lanes, PADDED, TILE_PIXELS, lane_sum, lanes_mut, reduce_slots, walk_back,
    walk_tiles,
};
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

/// Per-Gaussian Jacobian `geo[k][p] = ∂u_k/∂w_p` (p over mean 3, quaternion 4, log-scale 3)
/// of the 6 geometric entries of `u`.
type GeoJacobian<T> = [[T; 10]; 6];

/// What the pixel walk needs of a Gaussian's pose Jacobian `pose[k][j] = ∂u_k/∂τ_j`.
#[derive(Clone, Copy, Default)]
struct PoseRows<T: Real> {
    /// `pose_l[m][j] = Σ_k L[k][m]·pose[k][j]`: the pose rows folded with [`l_matrix`], so
    /// that `(∂u/∂τ)ᵀ ∂α/∂u = α·Σ_m pose_l[m]·mono[m]`.
    pose_l: [[T; 6]; 6],
    /// `∂z/∂τ`.
    depth: [T; 6],
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
fn project_diag<T: Real>(m: &[T; PACKED], geo: &GeoJacobian<T>) -> ([T; 10], T) {
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
            let jk = geo[k][p];
            let mut row = T::zero();
            for l in 0..6 {
                row += full[k][l] * geo[l][p];
            }
            acc += jk * row;
        }
        *d = acc;
    }
    (diag, full[6][6])
}

/// What the Fisher pass accumulates along the shared back-to-front walk
/// ([`crate::walk::walk_back`]): per pixel its pose Jacobians, per (tile, Gaussian) pair the
/// [`SLOT`] moment sums.
struct FisherSink<'a, T: Real> {
    pose_rows: &'a [PoseRows<T>],
    gain: T,
    mode: FisherMode,
    /// ∂(colour channel)/∂τ per tile-local pixel, `[channel][τ component][pixel]`, summed over
    /// the Gaussians walked so far.
    jt_col: [[[T; PADDED]; 6]; 3],
    /// ∂depth/∂τ per pixel.
    jt_dep: [[T; PADDED]; 6],
    /// The current pair's splat and pose rows.
    splat: Splat<T>,
    rows: PoseRows<T>,
    /// Row coefficients of `v = (∂u/∂τ)ᵀ ∂α/∂u / α = r + dx·q + dx²·pose_l[3]`.
    r: [T; 6],
    q: [T; 6],
    /// Per-lane row sums `Σ e·dx^i` of the colour and depth streams and of the depth cross term.
    row_col: [[T; LANES]; 5],
    row_dep: [[T; LANES]; 5],
    row_cross: [[T; LANES]; 3],
    /// Per-lane pair sums of `weight²` and `(∂C/∂sh)²`.
    weight_sq: [T; LANES],
    colour_sq: [T; LANES],
    /// The pair's moments (see [`moments_to_packed`]).
    mom_col: [T; MOMENTS],
    mom_dep: [T; MOMENTS],
    cross: [T; 6],
    /// This tile's pair slots.
    slots: &'a mut [T],
}

impl<'a, T: Real> FisherSink<'a, T> {
    fn new(pose_rows: &'a [PoseRows<T>], gain: T, mode: FisherMode, slots: &'a mut [T]) -> Self {
        let z = T::zero();
        Self {
            pose_rows,
            gain,
            mode,
            jt_col: [[[z; PADDED]; 6]; 3],
            jt_dep: [[z; PADDED]; 6],
            splat: Splat::default(),
            rows: PoseRows::default(),
            r: [z; 6],
            q: [z; 6],
            row_col: [[z; LANES]; 5],
            row_dep: [[z; LANES]; 5],
            row_cross: [[z; LANES]; 3],
            weight_sq: [z; LANES],
            colour_sq: [z; LANES],
            mom_col: [z; MOMENTS],
            mom_dep: [z; MOMENTS],
            cross: [z; 6],
            slots,
        }
    }

    /// The two 6×6 pose matrices of the tile, `Σ_px Σ_ch J_chᵀ J_ch` and `Σ_px J_Dᵀ J_D`, packed
    /// row-major; pixels are summed in a fixed order.
    fn pose_part(&self) -> PosePart {
        let mut pose_col = [0.0f64; 36];
        let mut pose_dep = [0.0f64; 36];
        for a in 0..6 {
            for b in a..6 {
                let mut c = T::zero();
                let mut d = T::zero();
                for p in 0..TILE_PIXELS {
                    for ch in 0..3 {
                        c += self.jt_col[ch][a][p] * self.jt_col[ch][b][p];
                    }
                    d += self.jt_dep[a][p] * self.jt_dep[b][p];
                }
                for (i, j) in [(a, b), (b, a)] {
                    pose_col[i * 6 + j] = c.to_f64();
                    pose_dep[i * 6 + j] = d.to_f64();
                }
            }
        }
        (pose_col, pose_dep)
    }
}

impl<T: Real> BackSink<T> for FisherSink<'_, T> {
    #[inline(always)]
    fn init_pixel(&mut self, _local: usize, _pixel: usize) {}

    #[inline(always)]
    fn begin_pair(&mut self, id: usize, splat: &Splat<T>) {
        self.splat = *splat;
        self.rows = self.pose_rows[id];
        self.weight_sq = [T::zero(); LANES];
        self.colour_sq = [T::zero(); LANES];
        self.mom_col = [T::zero(); MOMENTS];
        self.mom_dep = [T::zero(); MOMENTS];
        self.cross = [T::zero(); 6];
    }

    #[inline(always)]
    fn begin_row(&mut self, dy: T) {
        let pl = &self.rows.pose_l;
        let dy2 = dy * dy;
        self.r = std::array::from_fn(|j| pl[2][j] * dy + pl[5][j] * dy2);
        self.q = std::array::from_fn(|j| pl[1][j] + pl[4][j] * dy);
        self.row_col = [[T::zero(); LANES]; 5];
        self.row_dep = [[T::zero(); LANES]; 5];
        self.row_cross = [[T::zero(); LANES]; 3];
    }

    #[inline(always)]
    fn step(&mut self, base: usize, ln: &Lanes<T>) {
        let s = self.splat;
        let (gain, colour_scale) = (self.gain, self.gain * T::of(SH_C0));
        let per_channel = self.mode == FisherMode::PerChannel;
        let mut w = [[T::zero(); LANES]; 3];
        let mut w_d = [T::zero(); LANES];
        let mut v = [[T::zero(); LANES]; 6];
        // Local copies of the accumulators keep the lane loop free of aliasing, so it vectorises.
        let (r, q, p3) = (self.r, self.q, self.rows.pose_l[3]);
        let mut colour_sq = self.colour_sq;
        let mut weight_sq = self.weight_sq;
        let mut row_col = self.row_col;
        let mut row_dep = self.row_dep;
        let mut row_cross = self.row_cross;
        for l in 0..LANES {
            let (t_i, inv, weight) = (ln.t_i[l], ln.inv[l], ln.weight[l]);
            for ch in 0..3 {
                w[ch][l] = gain * s.colour[ch].mul_add(t_i, -(ln.s_col[ch][l] * inv));
            }
            w_d[l] = s.depth.mul_add(t_i, -(ln.s_dep[l] * inv));
            let cw = colour_scale * weight;
            colour_sq[l] = cw.mul_add(cw, colour_sq[l]);
            weight_sq[l] = weight.mul_add(weight, weight_sq[l]);
            let per_channel_weight =
                w[0][l].mul_add(w[0][l], w[1][l].mul_add(w[1][l], w[2][l] * w[2][l]));
            let sum = w[0][l] + w[1][l] + w[2][l];
            let colour_weight = if per_channel {
                per_channel_weight
            } else {
                sum * sum
            };
            // ∂α/∂u is zero where α is clamped or not composited: `grad` masks it.
            let ag = ln.alpha[l] * ln.grad[l];
            let a2 = ag * ag;
            let e_col = colour_weight * a2;
            let e_dep = w_d[l] * w_d[l] * a2;
            let e_cross = w_d[l] * weight * ag;
            let dx = ln.dx[l];
            let dx2 = dx * dx;
            let powers = [T::one(), dx, dx2, dx2 * dx, dx2 * dx2];
            for i in 0..5 {
                row_col[i][l] = e_col.mul_add(powers[i], row_col[i][l]);
                row_dep[i][l] = e_dep.mul_add(powers[i], row_dep[i][l]);
            }
            for i in 0..3 {
                row_cross[i][l] = e_cross.mul_add(powers[i], row_cross[i][l]);
            }
            // Pose: v = (∂u/∂τ)ᵀ ∂α/∂u = α·Σ_m pose_l[m]·mono[m].
            for j in 0..6 {
                v[j][l] = ag * dx2.mul_add(p3[j], dx.mul_add(q[j], r[j]));
            }
        }
        self.colour_sq = colour_sq;
        self.weight_sq = weight_sq;
        self.row_col = row_col;
        self.row_dep = row_dep;
        self.row_cross = row_cross;
        for ch in 0..3 {
            for j in 0..6 {
                let jt = lanes_mut(&mut self.jt_col[ch][j], base);
                for l in 0..LANES {
                    jt[l] = w[ch][l].mul_add(v[j][l], jt[l]);
                }
            }
        }
        for j in 0..6 {
            let jt = lanes_mut(&mut self.jt_dep[j], base);
            let dz = self.rows.depth[j];
            for l in 0..LANES {
                jt[l] = w_d[l].mul_add(v[j][l], ln.weight[l].mul_add(dz, jt[l]));
            }
        }
    }

    #[inline(always)]
    fn end_row(&mut self, dy: T) {
        let row_col = self.row_col.map(|r| lane_sum(&r));
        let row_dep = self.row_dep.map(|r| lane_sum(&r));
        let row_cross = self.row_cross.map(|r| lane_sum(&r));
        let dy2 = dy * dy;
        let dy_pow = [T::one(), dy, dy2, dy2 * dy, dy2 * dy2];
        for i in 0..5 {
            for j in 0..5 - i {
                self.mom_col[moment_index(i, j)] += row_col[i] * dy_pow[j];
                self.mom_dep[moment_index(i, j)] += row_dep[i] * dy_pow[j];
            }
        }
        // cross over m = (1, dx, dy, dx², dx·dy, dy²).
        self.cross[0] += row_cross[0];
        self.cross[1] += row_cross[1];
        self.cross[2] += row_cross[0] * dy;
        self.cross[3] += row_cross[2];
        self.cross[4] += row_cross[1] * dy;
        self.cross[5] += row_cross[0] * dy2;
    }

    #[inline(always)]
    fn end_pair(&mut self, k: usize) {
        let slot = &mut self.slots[k * SLOT..(k + 1) * SLOT];
        slot[..MOMENTS].copy_from_slice(&self.mom_col);
        slot[MOMENTS..2 * MOMENTS].copy_from_slice(&self.mom_dep);
        slot[2 * MOMENTS..2 * MOMENTS + 6].copy_from_slice(&self.cross);
        slot[SLOT - 2] = lane_sum(&self.weight_sq);
        slot[SLOT - 1] = lane_sum(&self.colour_sq);
    }
}

/// Per-tile result: the two packed 6×6 pose matrices.
type PosePart = ([f64; 36], [f64; 36]);

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
    let mut geos = vec![GeoJacobian::<T>::default(); n];
    let mut pose_rows = vec![PoseRows::<T>::default(); n];
    geos.par_chunks_mut(CHUNK)
        .zip(pose_rows.par_chunks_mut(CHUNK))
        .enumerate()
        .for_each(|(chunk, (geo_part, rows_part))| {
            for (j, (geo, rows)) in geo_part.iter_mut().zip(rows_part).enumerate() {
                let i = chunk * CHUNK + j;
                if !ctx.visible[i] {
                    continue;
                }
                let Some(c) = chain(&ctx.cam, gaussians, i) else {
                    continue;
                };
                let mut pose = [[T::zero(); 6]; 6];
                for k in 0..6 {
                    let mut up = [T::zero(); 6];
                    up[k] = T::one();
                    let g = project_vjp(&c, &ctx.cam, &up);
                    geo[k] = [
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
                    pose[k] = g.pose;
                }
                let lmat = l_matrix(&ctx.splats[i]);
                for (m, plm) in rows.pose_l.iter_mut().enumerate() {
                    for (k, lrow) in lmat.iter().take(5).enumerate() {
                        for j in 0..6 {
                            plm[j] += lrow[m] * pose[k][j];
                        }
                    }
                }
                rows.depth = pose[5];
            }
        });
    let gain = T::of(ctx.options.exposure[0].exp());
    let (slots, parts) = walk_tiles(ctx, SLOT, |t, piece| {
        let mut sink = FisherSink::new(&pose_rows, gain, mode, piece);
        walk_back(ctx, t, &mut sink);
        sink.pose_part()
    });
    let per_gaussian: Vec<[T; SLOT]> = reduce_slots(ctx, &slots, n);
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
                    let (geo, logit_v) = project_diag(m, &geos[i]);
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
