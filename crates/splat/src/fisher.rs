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
//! so each (tile, Gaussian) pair accumulates the 7×7 matrix `M = Σ_px (∂f/∂u)(∂f/∂u)ᵀ`, and
//! `diag(J_uᵀ M J_u)` with the per-Gaussian projection Jacobian `J_u` gives the parameter
//! diagonal. Since `∂α/∂u = α·L·m` with the monomials `m` of `(dx, dy)` up to degree 2, `M`
//! follows from the moments `Σ e·dx^i·dy^j` (`i + j ≤ 4`): the walk sums `e·dy^j` per pixel
//! column (a chunk's `dx` is the same on every row) and applies the `dx^i` once per pair.
//! For the pose, each pixel sums `∂f/∂τ = Σ_i (∂u_i/∂τ)ᵀ ∂f/∂u_i` over its Gaussians in
//! per-pixel accumulators, and the tile adds their outer products at its end.
//!
//! Cost (measured by `activemap bench splat`): about 1.5× one backward pass at 800×800 with
//! 100k Gaussians; the pose Jacobians (24 accumulators per pixel) are most of the extra work.

use crate::SplatError;
use crate::backward::{CHUNK, check_pixels};
use crate::gaussians::{Gaussians, SH_C0, layout};
use crate::project::{ConicPrep, Splat, chain, projection_jacobian};
use crate::rasterize::{ForwardContext, Render};
use crate::real::Real;
use crate::tiles::TILE;
use crate::walk::{
    BackSink, Lanes, PADDED, TILE_PIXELS, lane_sum, lanes_n, lanes_n_mut, reduce_slots_by,
    walk_back, walk_tiles,
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

/// Images at least this wide are walked 16 pixels at a time (a whole tile row, one AVX-512
/// register), narrower ones 8 at a time. Measured against each other (1 thread): 16 lanes made
/// the pass 10–20 % faster at 800 px with 100k Gaussians and 8–15 % slower at 200 px with 10k,
/// where the boxes are narrower than a tile row. Lane sums group differently, so the two
/// give results that differ in the last bits; each is deterministic.
const WIDE_IMAGE: usize = 400;
/// Most chunks of 8 pixels a pair's row can have (a box row inside a tile).
const ROW_CHUNKS: usize = TILE.div_ceil(8);

/// Dimension of the intermediate vector `u` (with the opacity logit last).
const U: usize = 7;
/// Packed upper triangle of a 7×7 symmetric matrix.
const PACKED: usize = U * (U + 1) / 2;
/// Slot per pair: colour moments, depth moments, depth cross moments, Σ weight².
const SLOT: usize = 2 * MOMENTS + 6 + 1;

/// Per-Gaussian Jacobian `geo[k][p] = ∂u_k/∂w_p` (p over mean 3, quaternion 4, log-scale 3)
/// of the 6 geometric entries of `u`.
type GeoJacobian<T> = [[T; 10]; 6];

/// What the pixel walk needs of a Gaussian's pose Jacobian `pose[k][j] = ∂u_k/∂τ_j`.
#[derive(Clone, Copy, Default)]
struct PoseRows<T: Real> {
    /// `pose_l[m][j] = Σ_k L[k][m]·pose[k][j]`: the pose rows folded with `L` ([`l_times`]), so
    /// that `(∂u/∂τ)ᵀ ∂α/∂u = α·Σ_m pose_l[m]·mono[m]`.
    pose_l: [[T; 6]; 6],
    /// Entries 2, 3, 4 (ρ_z, θ_x, θ_y) of `∂z/∂τ = (0, 0, 1, y_c, −x_c, 0)` (SPEC §3:
    /// `∂p_c/∂ρ = I`, `∂p_c/∂θ = −[p_c]×`); the others are zero.
    depth: [T; 3],
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

/// `L·v` for a vector `v` over the monomials, where `∂α/∂u = α·L·m` (unclamped alpha), rows
/// over `u`, columns over `m`: `∂σ/∂mean = (Q_xx dx + Q_xy dy, Q_xy dx + Q_yy dy)`,
/// `∂σ/∂Q = (½dx², dx dy, ½dy²)`, `∂α/∂σ = −α`, `∂α/∂logit = α(1 − o)`. `L` is sparse; its
/// structure is written out here once.
#[inline(always)]
fn l_times<T: Real>(s: &Splat<T>, v: &[T; 6]) -> [T; U] {
    let [qa, qb, qc] = s.conic;
    let h = T::of(0.5);
    [
        -(qa * v[1] + qb * v[2]),
        -(qb * v[1] + qc * v[2]),
        -(h * v[3]),
        -v[4],
        -(h * v[5]),
        T::zero(),
        (T::one() - s.opacity) * v[0],
    ]
}

/// `Lᵀ·w` for a vector `w` over `u` (see [`l_times`]).
#[inline(always)]
fn l_transpose_times<T: Real>(s: &Splat<T>, w: &[T; U]) -> [T; 6] {
    let [qa, qb, qc] = s.conic;
    let h = T::of(0.5);
    [
        (T::one() - s.opacity) * w[6],
        -(qa * w[0] + qb * w[1]),
        -(qb * w[0] + qc * w[1]),
        -(h * w[2]),
        -w[3],
        -(h * w[4]),
    ]
}

/// `MOMENT_OF_PRODUCT[a][b]`: index of the moment of `m_a·m_b`.
const MOMENT_OF_PRODUCT: [[usize; 6]; 6] = {
    let mut table = [[0; 6]; 6];
    let mut a = 0;
    while a < 6 {
        let mut b = 0;
        while b < 6 {
            table[a][b] =
                moment_index(MONO_EXP[a].0 + MONO_EXP[b].0, MONO_EXP[a].1 + MONO_EXP[b].1);
            b += 1;
        }
        a += 1;
    }
    table
};

/// Rebuilds `Σ e·(∂α/∂u)(∂α/∂u)ᵀ = L·(Σ e·α²·m mᵀ)·Lᵀ` from the moments, plus the depth terms
/// `c e₅ᵀ + e₅ cᵀ` (with `c = L·cross`) and `weight_sq·e₅e₅ᵀ`, packed upper-triangular.
fn moments_to_packed<T: Real>(
    mom: &[T; MOMENTS],
    s: &Splat<T>,
    cross: &[T; 6],
    weight_sq: T,
) -> [T; PACKED] {
    // mm is symmetric: its column b is its row b.
    let lm: [[T; U]; 6] = std::array::from_fn(|b| {
        let column: [T; 6] = std::array::from_fn(|a| mom[MOMENT_OF_PRODUCT[a][b]]);
        l_times(s, &column)
    });
    let c = l_times(s, cross);
    let mut out = [T::zero(); PACKED];
    let mut idx = 0;
    for k in 0..U {
        let row: [T; 6] = std::array::from_fn(|b| lm[b][k]);
        let m_row = l_times(s, &row);
        for q in k..U {
            let mut acc = m_row[q];
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

/// `diag(Jᵀ M J)` over the geometric parameters plus the logit entry `M_66`, for the colour
/// and the depth matrix at once (they share the products of `J`'s columns).
fn project_diag<T: Real>(
    m_col: &[T; PACKED],
    m_dep: &[T; PACKED],
    geo: &GeoJacobian<T>,
) -> (([T; 10], T), ([T; 10], T)) {
    let mut col = [T::zero(); 10];
    let mut dep = [T::zero(); 10];
    let mut idx = 0;
    for k in 0..6 {
        for l in k..U {
            if l < 6 {
                let twice = if k == l { T::one() } else { T::of(2.0) };
                let (mc, md) = (twice * m_col[idx], twice * m_dep[idx]);
                for p in 0..10 {
                    let g = geo[k][p] * geo[l][p];
                    col[p] += mc * g;
                    dep[p] += md * g;
                }
            }
            idx += 1;
        }
    }
    ((col, m_col[PACKED - 1]), (dep, m_dep[PACKED - 1]))
}

/// What the Fisher pass accumulates along the shared back-to-front walk
/// ([`crate::walk::walk_back`]): per pixel its pose Jacobians, per (tile, Gaussian) pair the
/// [`SLOT`] moment sums. `POSE` asks for the pose information too (else the per-pixel pose
/// Jacobians, most of the walk's work, are skipped). `PER_CHANNEL` is [`FisherMode::PerChannel`], fixed at compile time so
/// that the lane loop carries no mode select.
///
/// The colour quantities leave out the exposure gain `e^a`: every colour output is linear in
/// it, so the colour diagonal and `J_τᵀ J_τ` are scaled by `e^{2a}` once at the end.
struct FisherSink<'a, T: Real, const PER_CHANNEL: bool, const POSE: bool, const L: usize> {
    /// Pose rows of the walked Gaussians, by compact index.
    pose_rows: &'a [PoseRows<T>],
    /// Compact index of each Gaussian (meaningful for the walked ones).
    dense: &'a [u32],
    /// ∂(raw colour channel)/∂τ per tile-local pixel, `[channel][τ component][pixel]`, summed
    /// over the Gaussians walked so far.
    jt_col: [[[T; PADDED]; 6]; 3],
    /// ∂depth/∂τ per pixel.
    jt_dep: [[T; PADDED]; 6],
    /// The current pair's splat and pose rows.
    splat: Splat<T>,
    rows: PoseRows<T>,
    /// Row coefficients of `v = (∂u/∂τ)ᵀ ∂α/∂u / α = r + dx·q + dx²·pose_l[3]`.
    r: [T; 6],
    q: [T; 6],
    /// `dy^j`, j = 0..4, of the current row.
    dy_pow: [T; 5],
    /// Per chunk of the pair's rows and lane, the column sums `Σ_rows e·dy^j` of the colour
    /// and depth streams (j ≤ 4) and of the depth cross term (j ≤ 2). A chunk's lanes keep
    /// their `dx` on every row, so the `dx^i` factors are applied once per pair.
    col_sums: [[[T; L]; 5]; ROW_CHUNKS],
    dep_sums: [[[T; L]; 5]; ROW_CHUNKS],
    cross_sums: [[[T; L]; 3]; ROW_CHUNKS],
    /// `dx` of each chunk's lanes.
    chunk_dx: [[T; L]; ROW_CHUNKS],
    /// How many chunks (from the first) the pair's rows have used so far.
    chunks_used: usize,
    /// Per-lane pair sums of `weight²` (`∂C/∂sh = e^a·C0·weight`).
    weight_sq: [T; L],
    /// This tile's pair slots.
    slots: &'a mut [T],
    /// The tile's pose matrices, set by [`BackSink::end_tile`].
    pose: PosePart,
}

impl<'a, T: Real, const PER_CHANNEL: bool, const POSE: bool, const L: usize>
    FisherSink<'a, T, PER_CHANNEL, POSE, L>
{
    fn new(pose_rows: &'a [PoseRows<T>], dense: &'a [u32], slots: &'a mut [T]) -> Self {
        let z = T::zero();
        Self {
            pose_rows,
            dense,
            jt_col: [[[z; PADDED]; 6]; 3],
            jt_dep: [[z; PADDED]; 6],
            splat: Splat::default(),
            rows: PoseRows::default(),
            r: [z; 6],
            q: [z; 6],
            dy_pow: [z; 5],
            col_sums: [[[z; L]; 5]; ROW_CHUNKS],
            dep_sums: [[[z; L]; 5]; ROW_CHUNKS],
            cross_sums: [[[z; L]; 3]; ROW_CHUNKS],
            chunk_dx: [[z; L]; ROW_CHUNKS],
            chunks_used: 0,
            weight_sq: [z; L],
            slots,
            pose: ([0.0; 36], [0.0; 36]),
        }
    }

    /// The two 6×6 pose matrices of the tile, `Σ_px Σ_ch J_chᵀ J_ch` (without the exposure
    /// gain) and `Σ_px J_Dᵀ J_D`, packed row-major. Pixels are summed lane-wise in a fixed
    /// order, then the lanes (deterministic, and vectorised).
    #[inline(always)]
    fn pose_part(&self) -> PosePart {
        let mut pose_col = [0.0f64; 36];
        let mut pose_dep = [0.0f64; 36];
        for a in 0..6 {
            for b in a..6 {
                let mut c = [T::zero(); L];
                let mut d = [T::zero(); L];
                for base in (0..TILE_PIXELS).step_by(L) {
                    for ch in 0..3 {
                        let (ja, jb) = (
                            lanes_n::<_, L>(&self.jt_col[ch][a], base),
                            lanes_n::<_, L>(&self.jt_col[ch][b], base),
                        );
                        for l in 0..L {
                            c[l] = ja[l].mul_add(jb[l], c[l]);
                        }
                    }
                    let (ja, jb) = (
                        lanes_n::<_, L>(&self.jt_dep[a], base),
                        lanes_n::<_, L>(&self.jt_dep[b], base),
                    );
                    for l in 0..L {
                        d[l] = ja[l].mul_add(jb[l], d[l]);
                    }
                }
                let (c, d) = (lane_sum(&c).to_f64(), lane_sum(&d).to_f64());
                for (i, j) in [(a, b), (b, a)] {
                    pose_col[i * 6 + j] = c;
                    pose_dep[i * 6 + j] = d;
                }
            }
        }
        (pose_col, pose_dep)
    }
}

impl<T: Real, const PER_CHANNEL: bool, const POSE: bool, const L: usize> BackSink<T, L>
    for FisherSink<'_, T, PER_CHANNEL, POSE, L>
{
    #[inline(always)]
    fn init_pixel(&mut self, _local: usize, _pixel: usize) {}

    #[inline(always)]
    fn begin_pair(&mut self, id: usize, splat: &Splat<T>) {
        self.splat = *splat;
        if POSE {
            self.rows = self.pose_rows[self.dense[id] as usize];
        }
        self.weight_sq = [T::zero(); L];
        self.col_sums = [[[T::zero(); L]; 5]; ROW_CHUNKS];
        self.dep_sums = [[[T::zero(); L]; 5]; ROW_CHUNKS];
        self.cross_sums = [[[T::zero(); L]; 3]; ROW_CHUNKS];
        self.chunk_dx = [[T::zero(); L]; ROW_CHUNKS];
        self.chunks_used = 0;
    }

    #[inline(always)]
    fn begin_row(&mut self, dy: T) {
        let dy2 = dy * dy;
        if POSE {
            let pl = &self.rows.pose_l;
            self.r = std::array::from_fn(|j| pl[2][j] * dy + pl[5][j] * dy2);
            self.q = std::array::from_fn(|j| pl[1][j] + pl[4][j] * dy);
        }
        self.dy_pow = [T::one(), dy, dy2, dy2 * dy, dy2 * dy2];
    }

    #[inline(always)]
    fn step(&mut self, base: usize, chunk: usize, ln: &Lanes<T, L>) {
        let s = self.splat;
        // `W = α·∂f/∂α` for the raw colour channels and depth, where the clamp is inactive
        // (`grad` masks it): then `∂f/∂u = W·L·m` and `∂f/∂τ = W·v'`.
        let mut w_col = [[T::zero(); L]; 3];
        let mut w_dep = [T::zero(); L];
        let mut e_col = [T::zero(); L];
        let mut e_dep = [T::zero(); L];
        let mut e_cross = [T::zero(); L];
        let mut v = [[T::zero(); L]; 6];
        let (r, q, p3, dy_pow) = (self.r, self.q, self.rows.pose_l[3], self.dy_pow);
        for l in 0..L {
            let weight = ln.weight[l];
            let ag = ln.alpha[l] * ln.grad[l];
            let (t_ag, inv_ag) = (ln.t_i[l] * ag, ln.inv[l] * ag);
            for ch in 0..3 {
                w_col[ch][l] = s.colour[ch].mul_add(t_ag, -(ln.s_col[ch][l] * inv_ag));
            }
            w_dep[l] = s.depth.mul_add(t_ag, -(ln.s_dep[l] * inv_ag));
            let [w0, w1, w2] = [w_col[0][l], w_col[1][l], w_col[2][l]];
            e_col[l] = if PER_CHANNEL {
                w0.mul_add(w0, w1.mul_add(w1, w2 * w2))
            } else {
                let sum = w0 + w1 + w2;
                sum * sum
            };
            e_dep[l] = w_dep[l] * w_dep[l];
            e_cross[l] = w_dep[l] * weight;
            // Pose: v' = (∂u/∂τ)ᵀ ∂α/∂u / α = Σ_m pose_l[m]·mono[m].
            if POSE {
                let dx = ln.dx[l];
                let dx2 = dx * dx;
                for j in 0..6 {
                    v[j][l] = dx2.mul_add(p3[j], dx.mul_add(q[j], r[j]));
                }
            }
        }
        // The accumulators are updated in place (one load, FMA and store each).
        for l in 0..L {
            self.weight_sq[l] = ln.weight[l].mul_add(ln.weight[l], self.weight_sq[l]);
        }
        let (col_sums, dep_sums, cross_sums) = (
            &mut self.col_sums[chunk],
            &mut self.dep_sums[chunk],
            &mut self.cross_sums[chunk],
        );
        for j in 0..5 {
            for l in 0..L {
                col_sums[j][l] = e_col[l].mul_add(dy_pow[j], col_sums[j][l]);
                dep_sums[j][l] = e_dep[l].mul_add(dy_pow[j], dep_sums[j][l]);
            }
        }
        for j in 0..3 {
            for l in 0..L {
                cross_sums[j][l] = e_cross[l].mul_add(dy_pow[j], cross_sums[j][l]);
            }
        }
        self.chunk_dx[chunk] = ln.dx;
        self.chunks_used = self.chunks_used.max(chunk + 1);
        if !POSE {
            return;
        }
        for ch in 0..3 {
            for j in 0..6 {
                let jt = lanes_n_mut::<_, L>(&mut self.jt_col[ch][j], base);
                for l in 0..L {
                    jt[l] = w_col[ch][l].mul_add(v[j][l], jt[l]);
                }
            }
        }
        // ∂D/∂τ also has `Σ_i weight_i·∂z_i/∂τ`; `∂z/∂τ` is zero on ρ_x, ρ_y, θ_z.
        for j in [0, 1, 5] {
            let jt = lanes_n_mut::<_, L>(&mut self.jt_dep[j], base);
            for l in 0..L {
                jt[l] = w_dep[l].mul_add(v[j][l], jt[l]);
            }
        }
        for (j, dz) in (2..5).zip(self.rows.depth) {
            let jt = lanes_n_mut::<_, L>(&mut self.jt_dep[j], base);
            for l in 0..L {
                jt[l] = ln.weight[l].mul_add(dz, w_dep[l].mul_add(v[j][l], jt[l]));
            }
        }
    }

    #[inline(always)]
    fn end_row(&mut self, _dy: T) {}

    #[inline(always)]
    fn end_pair(&mut self, k: usize) {
        // Moments Σ e·dx^i·dy^j = Σ_chunks Σ_lanes dx^i·(Σ_rows e·dy^j), per lane, then summed.
        let mut mom_col = [[T::zero(); L]; MOMENTS];
        let mut mom_dep = [[T::zero(); L]; MOMENTS];
        let mut cross = [[T::zero(); L]; 6];
        for c in 0..self.chunks_used {
            let dx = &self.chunk_dx[c];
            let (col, dep, crs) = (&self.col_sums[c], &self.dep_sums[c], &self.cross_sums[c]);
            // dx^i per lane, i = 0..4; the lane loops innermost so that they vectorise.
            let mut dx_pow = [[T::one(); L]; 5];
            for l in 0..L {
                let dx2 = dx[l] * dx[l];
                dx_pow[1][l] = dx[l];
                dx_pow[2][l] = dx2;
                dx_pow[3][l] = dx2 * dx[l];
                dx_pow[4][l] = dx2 * dx2;
            }
            for i in 0..5 {
                for j in 0..5 - i {
                    let m = moment_index(i, j);
                    for l in 0..L {
                        mom_col[m][l] = col[j][l].mul_add(dx_pow[i][l], mom_col[m][l]);
                        mom_dep[m][l] = dep[j][l].mul_add(dx_pow[i][l], mom_dep[m][l]);
                    }
                }
            }
            // cross over m = (1, dx, dy, dx², dx·dy, dy²).
            for (m, (i, j)) in MONO_EXP.iter().enumerate() {
                for l in 0..L {
                    cross[m][l] = crs[*j][l].mul_add(dx_pow[*i][l], cross[m][l]);
                }
            }
        }
        let slot = &mut self.slots[k * SLOT..(k + 1) * SLOT];
        for m in 0..MOMENTS {
            slot[m] = lane_tree_sum(&mom_col[m]);
            slot[MOMENTS + m] = lane_tree_sum(&mom_dep[m]);
        }
        for m in 0..6 {
            slot[2 * MOMENTS + m] = lane_tree_sum(&cross[m]);
        }
        slot[SLOT - 1] = lane_tree_sum(&self.weight_sq);
    }

    #[inline(always)]
    fn end_tile(&mut self) {
        if POSE {
            self.pose = self.pose_part();
        }
    }
}

/// Sum of the lanes as a fixed pairwise tree (deterministic; fewer dependent adds than
/// [`lane_sum`], which matters in the per-row reductions).
#[inline(always)]
fn lane_tree_sum<T: Real, const L: usize>(v: &[T; L]) -> T {
    let mut acc = *v;
    let mut width = L;
    while width > 1 {
        width /= 2;
        for l in 0..width {
            acc[l] += acc[l + width];
        }
    }
    acc[0]
}

/// Walks every tile with a [`FisherSink`]: the pair slots and the per-tile pose matrices.
fn walk_fisher<T: Real, const PER_CHANNEL: bool, const POSE: bool, const L: usize>(
    ctx: &ForwardContext<T>,
    pose_rows: &[PoseRows<T>],
    dense: &[u32],
) -> (Vec<T>, Vec<PosePart>) {
    walk_tiles(ctx, SLOT, |t, piece| {
        let mut sink = FisherSink::<T, PER_CHANNEL, POSE, L>::new(pose_rows, dense, piece);
        walk_back(ctx, t, &mut sink);
        sink.pose
    })
}

/// Per-tile result: the two packed 6×6 pose matrices.
type PosePart = ([f64; 36], [f64; 36]);

/// The projection Jacobians of Gaussian `i` of the render: `∂u_k/∂w` over the 10 geometric
/// parameters (mean, quaternion, log-scale) and, `with_pose`, `∂u_k/∂τ` over the pose (else
/// zero), for the 6 geometric entries of `u`; zero when the projection chain is degenerate.
fn projection_jacobians<T: Real>(
    ctx: &ForwardContext<T>,
    gaussians: &Gaussians<T>,
    i: usize,
    with_pose: bool,
) -> (GeoJacobian<T>, [[T; 6]; 6]) {
    match chain(&ctx.cam, gaussians, i) {
        Some(c) => projection_jacobian(&c, &ConicPrep::new(&c), &ctx.cam, with_pose),
        None => (GeoJacobian::<T>::default(), [[T::zero(); 6]; 6]),
    }
}

/// What the pixel walk needs of a Gaussian's pose Jacobian `pose[k][j] = ∂u_k/∂τ_j`.
fn pose_rows_of<T: Real>(splat: &Splat<T>, pose: &[[T; 6]; 6]) -> PoseRows<T> {
    let mut rows = PoseRows::<T>::default();
    // pose_l[·][j] = Lᵀ·(∂u/∂τ_j) (z and the logit have no L entry / no pose).
    for j in 0..6 {
        let column: [T; U] = std::array::from_fn(|k| if k < 5 { pose[k][j] } else { T::zero() });
        let folded = l_transpose_times(splat, &column);
        for (m, v) in folded.into_iter().enumerate() {
            rows.pose_l[m][j] = v;
        }
    }
    rows.depth = [pose[5][2], pose[5][3], pose[5][4]];
    rows
}

/// Fisher information of the view rendered in `render` (SPEC §5), for the Gaussians the walk
/// reaches only: the compact form of [`FisherOutput`]. Every Gaussian it leaves out (culled,
/// or behind what each pixel of its tiles composited) has an exactly zero diagonal.
#[derive(Debug, Clone, PartialEq)]
pub struct SparseFisher<T: Real> {
    /// Indices (into the rendered set, ascending) of the Gaussians with an entry.
    pub ids: Vec<u32>,
    /// Colour diagonal of each of `ids`, in the [`layout`] order.
    pub colour: Vec<[T; 14]>,
    /// Depth diagonal of each of `ids` (colour entries are 0).
    pub depth: Vec<[T; 14]>,
    /// `J_τᵀ J_τ` of the RGB outputs (`None` when not asked for).
    pub pose_colour: Option<Matrix6<f64>>,
    /// `J_τᵀ J_τ` of the depth output (`None` when not asked for).
    pub pose_depth: Option<Matrix6<f64>>,
}

impl<T: Real> SparseFisher<T> {
    /// Colour plus `depth_weight` × depth diagonal of entry `k` (Gaussian `ids[k]`).
    pub fn combined(&self, k: usize, depth_weight: f64) -> [f64; 14] {
        std::array::from_fn(|p| {
            self.colour[k][p].to_f64() + depth_weight * self.depth[k][p].to_f64()
        })
    }

    /// Colour plus `depth_weight` × depth pose information (`None` when not asked for).
    pub fn pose(&self, depth_weight: f64) -> Option<Matrix6<f64>> {
        Some(self.pose_colour? + self.pose_depth? * depth_weight)
    }

    /// The dense form: one diagonal per Gaussian of a set of `n`, zero where there is no entry
    /// (the pose matrices zero when they were not asked for).
    pub fn into_dense(self, n: usize) -> FisherOutput<T> {
        let mut colour = vec![[T::zero(); 14]; n];
        let mut depth = vec![[T::zero(); 14]; n];
        for (k, &i) in self.ids.iter().enumerate() {
            colour[i as usize] = self.colour[k];
            depth[i as usize] = self.depth[k];
        }
        FisherOutput {
            colour,
            depth,
            pose_colour: self.pose_colour.unwrap_or_else(Matrix6::zeros),
            pose_depth: self.pose_depth.unwrap_or_else(Matrix6::zeros),
        }
    }
}

/// Fisher information of the view rendered in `render` (SPEC §5). `gaussians` must be the set
/// `render` was computed from. Cost: a small multiple of one [`crate::backward`] pass.
pub fn fisher<T: Real>(
    gaussians: &Gaussians<T>,
    render: &Render<T>,
    mode: FisherMode,
) -> Result<FisherOutput<T>, SplatError> {
    Ok(fisher_sparse(gaussians, render, mode, true)?.into_dense(gaussians.len()))
}

/// [`fisher`] in compact form: only the Gaussians the walk reaches get an entry, so a view
/// that sees a little of a large set costs (in time and memory) what it composites. With
/// `with_pose` false the 6×6 pose information is not computed (`None`): a view scored by its
/// EIG alone skips the per-pixel pose Jacobians, most of the walk's work.
pub fn fisher_sparse<T: Real>(
    gaussians: &Gaussians<T>,
    render: &Render<T>,
    mode: FisherMode,
    with_pose: bool,
) -> Result<SparseFisher<T>, SplatError> {
    let wide = render.context.cam.width >= WIDE_IMAGE;
    fisher_with_lanes(gaussians, render, mode, wide, with_pose)
}

/// [`fisher_sparse`], walking 16 lanes at a time when `wide`, else 8.
pub(crate) fn fisher_with_lanes<T: Real>(
    gaussians: &Gaussians<T>,
    render: &Render<T>,
    mode: FisherMode,
    wide: bool,
    with_pose: bool,
) -> Result<SparseFisher<T>, SplatError> {
    let ctx = &render.context;
    if ctx.options.depth != crate::DepthModel::Centre {
        return Err(SplatError::Unsupported(
            "the Fisher pass needs a render with the centre depth model (DepthModel::Centre)",
        ));
    }
    check_pixels(
        "gaussians (vs. the render)",
        gaussians.len(),
        ctx.splats.len(),
    )?;
    let n = gaussians.len();
    // Only the Gaussians some tile walks get pair slots; every other one has a zero Fisher, so
    // their Jacobians are never needed. Behind a wall or inside a dense cloud that is most of
    // the visible set. They get compact indices, ascending with the Gaussian index.
    let walked = ctx.walked_mask();
    let mut ids = Vec::new();
    let mut dense = vec![u32::MAX; n];
    for (i, w) in walked.iter().enumerate() {
        if *w {
            dense[i] = ids.len() as u32;
            ids.push(i as u32);
        }
    }
    let m = ids.len();
    // Per walked Gaussian: ∂u/∂w over the 10 geometric parameters and ∂u/∂τ over the pose.
    let jacobians: Vec<(GeoJacobian<T>, [[T; 6]; 6])> = ids
        .par_iter()
        .with_min_len(CHUNK)
        .map(|&i| projection_jacobians(ctx, gaussians, i as usize, with_pose))
        .collect();
    let pose_rows: Vec<PoseRows<T>> = if with_pose {
        jacobians
            .par_iter()
            .zip(&ids)
            .with_min_len(CHUNK)
            .map(|((_, pose), &i)| pose_rows_of(&ctx.splats[i as usize], pose))
            .collect()
    } else {
        Vec::new()
    };
    let gain_sq_f64 = (2.0 * ctx.options.exposure[0]).exp();
    let gain_sq = T::of(gain_sq_f64);
    let (rows, d) = (pose_rows.as_slice(), dense.as_slice());
    let (slots, parts) = match (mode, with_pose, wide) {
        (FisherMode::PerChannel, true, true) => walk_fisher::<T, true, true, 16>(ctx, rows, d),
        (FisherMode::PerChannel, true, false) => walk_fisher::<T, true, true, 8>(ctx, rows, d),
        (FisherMode::PerChannel, false, true) => walk_fisher::<T, true, false, 16>(ctx, rows, d),
        (FisherMode::PerChannel, false, false) => walk_fisher::<T, true, false, 8>(ctx, rows, d),
        (FisherMode::ChannelSum, true, true) => walk_fisher::<T, false, true, 16>(ctx, rows, d),
        (FisherMode::ChannelSum, true, false) => walk_fisher::<T, false, true, 8>(ctx, rows, d),
        (FisherMode::ChannelSum, false, true) => walk_fisher::<T, false, false, 16>(ctx, rows, d),
        (FisherMode::ChannelSum, false, false) => walk_fisher::<T, false, false, 8>(ctx, rows, d),
    };
    let per_gaussian: Vec<[T; SLOT]> =
        reduce_slots_by(ctx, &slots, m, |id| dense[id as usize] as usize);
    let mut colour = vec![[T::zero(); 14]; m];
    let mut depth = vec![[T::zero(); 14]; m];
    colour
        .par_chunks_mut(CHUNK)
        .zip(depth.par_chunks_mut(CHUNK))
        .enumerate()
        .for_each(|(chunk, (col, dep))| {
            for j in 0..col.len() {
                let k = chunk * CHUNK + j;
                let i = ids[k] as usize;
                let acc = &per_gaussian[k];
                // The colour moments carry the exposure gain squared (see [`FisherSink`]).
                let col_moments: [T; MOMENTS] = std::array::from_fn(|q| acc[q] * gain_sq);
                let dep_moments: [T; MOMENTS] = std::array::from_fn(|q| acc[MOMENTS + q]);
                let cross: [T; 6] = std::array::from_fn(|q| acc[2 * MOMENTS + q]);
                let weight_sq = acc[SLOT - 1];
                let m_col =
                    moments_to_packed(&col_moments, &ctx.splats[i], &[T::zero(); 6], T::zero());
                let m_dep = moments_to_packed(&dep_moments, &ctx.splats[i], &cross, weight_sq);
                // ∂C_ch/∂sh_ch = e^a·C0·weight.
                let colour_v = gain_sq * T::of(SH_C0 * SH_C0) * weight_sq;
                let (diag_col, diag_dep) = project_diag(&m_col, &m_dep, &jacobians[k].0);
                for (out, (geo, logit_v), colour_v) in [
                    (&mut col[j], diag_col, colour_v),
                    (&mut dep[j], diag_dep, T::zero()),
                ] {
                    out[layout::MEAN..layout::MEAN + 3].copy_from_slice(&geo[0..3]);
                    out[layout::COLOUR..layout::COLOUR + 3].fill(colour_v);
                    out[layout::ROTATION..layout::ROTATION + 4].copy_from_slice(&geo[3..7]);
                    out[layout::OPACITY] = logit_v;
                    out[layout::LOG_SCALE..layout::LOG_SCALE + 3].copy_from_slice(&geo[7..10]);
                }
            }
        });
    let (pose_colour, pose_depth) = if with_pose {
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
        (Some(pose_colour * gain_sq_f64), Some(pose_depth))
    } else {
        (None, None)
    };
    Ok(SparseFisher {
        ids,
        colour,
        depth,
        pose_colour,
        pose_depth,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bench::{camera, scene};
    use crate::{DepthModel, RenderOptions, render};

    /// Render options with the centre depth model, which the Fisher pass needs.
    fn centre_depth() -> RenderOptions {
        RenderOptions {
            depth: DepthModel::Centre,
            ..RenderOptions::default()
        }
    }

    /// A render with the plane depth model is refused with a message naming the fix.
    #[test]
    fn a_plane_depth_render_is_refused() {
        let g = scene(200);
        let out = render(&g, &camera(32), &RenderOptions::default()).unwrap();
        let e = fisher(&g, &out, FisherMode::PerChannel).unwrap_err();
        assert!(e.to_string().contains("DepthModel::Centre"), "{e}");
    }

    /// The sparse pass holds exactly the walked Gaussians, and its entries are the dense
    /// pass's (the others are zero there); without the pose it computes the same diagonals
    /// bit for bit and no pose matrix.
    #[test]
    fn the_sparse_pass_and_the_diagonal_alone_agree_with_the_dense_one() {
        let mut g = scene(3000);
        // An opaque wall (three layers) over the left half of the view hides what lies behind.
        for layer in 0..3 {
            for j in 0..30 {
                for h in 0..30 {
                    g.push(
                        [
                            -0.82 + 0.028 * j as f64,
                            -0.82 + 0.057 * h as f64,
                            0.8 + 0.02 * layer as f64,
                        ],
                        [0.4, 0.5, 0.6],
                        [1.0, 0.0, 0.0, 0.0],
                        0.98,
                        [0.03, 0.03, 0.01],
                    );
                }
            }
        }
        let out = render(&g, &camera(64), &centre_depth()).unwrap();
        let walked = out.context.walked_mask();
        let visible = out.context.visible.iter().filter(|v| **v).count();
        let dense = fisher(&g, &out, FisherMode::PerChannel).unwrap();
        let sparse = fisher_sparse(&g, &out, FisherMode::PerChannel, true).unwrap();
        let diagonal = fisher_sparse(&g, &out, FisherMode::PerChannel, false).unwrap();
        let expected: Vec<u32> = (0..g.len() as u32)
            .filter(|&i| walked[i as usize])
            .collect();
        assert_eq!(sparse.ids, expected);
        assert!(
            !expected.is_empty() && expected.len() < visible,
            "{} walked of {visible} visible: the scene should hide some",
            expected.len()
        );
        for i in 0..g.len() {
            match sparse.ids.binary_search(&(i as u32)) {
                Ok(k) => {
                    assert_eq!(dense.colour[i], sparse.colour[k]);
                    assert_eq!(dense.depth[i], sparse.depth[k]);
                }
                Err(_) => {
                    assert!(dense.colour[i].iter().all(|v| *v == 0.0));
                    assert!(dense.depth[i].iter().all(|v| *v == 0.0));
                }
            }
        }
        assert_eq!(sparse.pose_colour, Some(dense.pose_colour));
        assert_eq!(sparse.pose_depth, Some(dense.pose_depth));
        assert_eq!(diagonal.ids, sparse.ids);
        assert_eq!(diagonal.colour, sparse.colour);
        assert_eq!(diagonal.depth, sparse.depth);
        assert_eq!((diagonal.pose_colour, diagonal.pose_depth), (None, None));
        assert_eq!(diagonal.pose(0.5), None);
    }

    /// The 16-lane walk (wide images) sums the same terms as the 8-lane one (checked against
    /// brute force in tests/gradients.rs), grouped differently: equal up to rounding.
    #[test]
    fn sixteen_and_eight_lane_walks_agree() {
        let g = scene(2000);
        let out = render(&g, &camera(96), &centre_depth()).unwrap();
        for mode in [FisherMode::PerChannel, FisherMode::ChannelSum] {
            let narrow = fisher_with_lanes(&g, &out, mode, false, true)
                .unwrap()
                .into_dense(g.len());
            let wide = fisher_with_lanes(&g, &out, mode, true, true)
                .unwrap()
                .into_dense(g.len());
            let close = |a: f64, b: f64, scale: f64| (a - b).abs() <= 1e-4 * scale + 1e-12;
            for (pn, pw) in [
                (narrow.pose_colour, wide.pose_colour),
                (narrow.pose_depth, wide.pose_depth),
            ] {
                assert!(pn.norm() > 0.0);
                for (a, b) in pn.iter().zip(pw.iter()) {
                    assert!(close(*a, *b, pn.norm()), "pose {a} vs {b}");
                }
            }
            let mut nonzero = 0;
            for i in 0..g.len() {
                for (a, b) in narrow.colour[i].iter().zip(&wide.colour[i]) {
                    let (a, b) = (a.to_f64(), b.to_f64());
                    assert!(
                        close(a, b, a.abs().max(b.abs())),
                        "Gaussian {i}: {a} vs {b}"
                    );
                    nonzero += (a != 0.0) as usize;
                }
                for (a, b) in narrow.depth[i].iter().zip(&wide.depth[i]) {
                    let (a, b) = (a.to_f64(), b.to_f64());
                    assert!(
                        close(a, b, a.abs().max(b.abs())),
                        "Gaussian {i}: {a} vs {b}"
                    );
                }
            }
            assert!(nonzero > 1000, "{nonzero}");
        }
    }
}
