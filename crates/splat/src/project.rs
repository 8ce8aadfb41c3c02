//! EWA projection of one Gaussian into the image (SPEC §3) and its vector-Jacobian product.
//!
//! Forward: `p_c = R_cw·μ + t_cw`; cull `z ≤ near`; `Σ = (R(q)·S)(R(q)·S)ᵀ`, `Σ_c = W Σ Wᵀ`
//! (`W = R_cw`); `Σ' = J Σ_c Jᵀ + 0.3·I` with the pinhole Jacobian `J` evaluated at `x/z`, `y/z`
//! clamped to 1.3× the field of view (as 3DGS/gsplat); conic `Q = Σ'⁻¹`; mean
//! `(fx·x/z + cx, fy·y/z + cy)`.
//!
//! Support: a Gaussian touches the pixels of the axis-aligned box of half-widths
//! `√Σ'ₓₓ·min(3, √(2 ln(255·o)))` (and the same in y) around its mean, i.e. the bounding box of
//! its 3σ ellipse, shrunk to where `α ≥ 1/255` can still happen. Pixels outside that box get
//! nothing from it. Unlike 3DGS (which truncates at tile granularity) this makes the image
//! independent of the tile size.
//!
//! Backward: for upstream gradients on `u = (mean_x, mean_y, Q_xx, Q_xy, Q_yy, z)` it returns
//! the gradients on the mean, quaternion, log-scale and the camera pose τ = [ρ, θ] for the left
//! update `T_cw ← Exp(τ)·T_cw` (SPEC §3: `∂p_c/∂ρ = I`, `∂p_c/∂θ = −[p_c]×`, `∂(W v)/∂θ = −[W v]×`).

use crate::camera::CameraT;
use crate::gaussians::{Gaussians, SH_C0, sigmoid};
use crate::real::Real;
use nalgebra::{Matrix2, Matrix2x3, Matrix3, Vector3};

/// EWA low-pass added to the 2D covariance (pixels², SPEC §3).
pub const LOW_PASS: f64 = 0.3;
/// Smallest alpha that is composited (SPEC §3).
pub const ALPHA_MIN: f64 = 1.0 / 255.0;
/// Largest alpha (SPEC §3).
pub const ALPHA_MAX: f64 = 0.99;
/// Compositing stops before transmittance would drop below this (SPEC §3).
pub const T_MIN: f64 = 1e-4;

/// A Gaussian projected into the image: what the rasteriser needs.
#[derive(Debug, Clone, Copy, Default)]
pub struct Splat<T: Real> {
    /// Projected mean, pixels.
    pub mean: [T; 2],
    /// Conic `Σ'⁻¹` as `(Q_xx, Q_xy, Q_yy)`.
    pub conic: [T; 3],
    /// Opacity `sigmoid(logit)`.
    pub opacity: T,
    /// Camera-frame depth z, metres.
    pub depth: T,
    /// Depth slope `s` (metres per pixel) of [`crate::DepthModel::Plane`]: the splat's depth at a
    /// pixel is `depth + s·(pixel − mean)`; zero under [`crate::DepthModel::Centre`].
    pub depth_slope: [T; 2],
    /// RGB colour `0.5 + C0·sh_dc`.
    pub colour: [T; 3],
    /// Inclusive pixel box `[x0, x1] × [y0, y1]` of the support, clipped to the image.
    pub bbox: [u32; 4],
}

/// Intermediate values of the projection, shared by forward and backward.
pub(crate) struct Chain<T: Real> {
    p_c: Vector3<T>,
    q_n: [T; 4],
    q_norm: T,
    rq: Matrix3<T>,
    s: Vector3<T>,
    m: Matrix3<T>,
    w: Matrix3<T>,
    sigma_c: Matrix3<T>,
    j: Matrix2x3<T>,
    clamped: [bool; 2],
    t_xy: [T; 2],
    cov: Matrix2<T>,
    conic: Matrix2<T>,
}

/// Rotation matrix of a unit quaternion `[w, x, y, z]`.
pub(crate) fn rotation_matrix<T: Real>(q: &[T; 4]) -> Matrix3<T> {
    let [w, x, y, z] = *q;
    let one = T::one();
    let two = T::of(2.0);
    Matrix3::new(
        one - two * (y * y + z * z),
        two * (x * y - w * z),
        two * (x * z + w * y),
        two * (x * y + w * z),
        one - two * (x * x + z * z),
        two * (y * z - w * x),
        two * (x * z - w * y),
        two * (y * z + w * x),
        one - two * (x * x + y * y),
    )
}

/// Runs the projection chain of Gaussian `i`; `None` when culled by the near plane or when
/// degenerate (zero quaternion, non-positive 2D covariance, non-finite values).
pub(crate) fn chain<T: Real>(cam: &CameraT<T>, g: &Gaussians<T>, i: usize) -> Option<Chain<T>> {
    let mu = g.means[i];
    let r = &cam.r;
    let p = |k: usize| r[k][0] * mu[0] + r[k][1] * mu[1] + r[k][2] * mu[2] + cam.t[k];
    let p_c = Vector3::new(p(0), p(1), p(2));
    if p_c.z.partial_cmp(&cam.near) != Some(std::cmp::Ordering::Greater)
        || !p_c.x.is_finite()
        || !p_c.y.is_finite()
    {
        return None;
    }
    let q = g.rotations[i];
    let q_norm = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    if q_norm.partial_cmp(&T::zero()) != Some(std::cmp::Ordering::Greater) || !q_norm.is_finite() {
        return None;
    }
    let q_n = q.map(|v| v / q_norm);
    let rq = rotation_matrix(&q_n);
    let ls = g.log_scales[i];
    let s = Vector3::new(ls[0].exp(), ls[1].exp(), ls[2].exp());
    let m = rq * Matrix3::from_diagonal(&s);
    let w = Matrix3::new(
        r[0][0], r[0][1], r[0][2], r[1][0], r[1][1], r[1][2], r[2][0], r[2][1], r[2][2],
    );
    let wm = w * m;
    let sigma_c = wm * wm.transpose();
    let iz = T::one() / p_c.z;
    let mut clamped = [false; 2];
    let mut t_xy = [p_c.x, p_c.y];
    for (k, lim) in [cam.lim_x, cam.lim_y].iter().enumerate() {
        let ratio = t_xy[k] * iz;
        if ratio < lim[0] || ratio > lim[1] {
            clamped[k] = true;
            t_xy[k] = ratio.max(lim[0]).min(lim[1]) * p_c.z;
        }
    }
    let iz2 = iz * iz;
    let j = Matrix2x3::new(
        cam.fx * iz,
        T::zero(),
        -cam.fx * t_xy[0] * iz2,
        T::zero(),
        cam.fy * iz,
        -cam.fy * t_xy[1] * iz2,
    );
    let low_pass = T::of(LOW_PASS);
    let cov = j * sigma_c * j.transpose() + Matrix2::new(low_pass, T::zero(), T::zero(), low_pass);
    let det = cov[(0, 0)] * cov[(1, 1)] - cov[(0, 1)] * cov[(1, 0)];
    if det.partial_cmp(&T::zero()) != Some(std::cmp::Ordering::Greater) || !det.is_finite() {
        return None;
    }
    let conic = Matrix2::new(
        cov[(1, 1)] / det,
        -cov[(0, 1)] / det,
        -cov[(1, 0)] / det,
        cov[(0, 0)] / det,
    );
    Some(Chain {
        p_c,
        q_n,
        q_norm,
        rq,
        s,
        m,
        w,
        sigma_c,
        j,
        clamped,
        t_xy,
        cov,
        conic,
    })
}

/// A cheap test run before the projection chain: true when Gaussian `i` lies beyond the far
/// plane, or (conservatively) when its screen box is certainly empty because its projected mean
/// lies farther outside the image than its footprint can reach. The footprint's half-width is `extent·√cov_xx` with `extent ≤ 3` and
/// `cov_xx = j₀ᵀΣj₀ + LOW_PASS ≤ (f/z)²(1 + L²)·s_max² + LOW_PASS`, where `s_max` is the largest
/// scale (the largest eigenvalue of Σ is `s_max²`) and `L` the Jacobian clamp limit of `x/z`
/// (resp. `y/z`). The bound gets 0.1 % and one pixel of slack for rounding, so culling here
/// never changes a render; it saves the covariance work for the (many) Gaussians in front of
/// the camera but outside its field of view. Non-finite values return false (the chain decides).
#[inline]
fn culled_early<T: Real>(cam: &CameraT<T>, g: &Gaussians<T>, i: usize) -> bool {
    let mu = g.means[i];
    let r = &cam.r;
    let p = |k: usize| r[k][0] * mu[0] + r[k][1] * mu[1] + r[k][2] * mu[2] + cam.t[k];
    let z = p(2);
    if z > cam.far {
        return true;
    }
    if z.partial_cmp(&cam.near) != Some(std::cmp::Ordering::Greater) {
        return false;
    }
    let ls = g.log_scales[i];
    let s_max = ls[0].max(ls[1]).max(ls[2]).exp();
    let iz = T::one() / z;
    let low_pass = T::of(LOW_PASS);
    let slack = T::of(3.0 * 1.001);
    let axes = [
        (p(0), cam.fx, cam.cx, cam.lim_x, cam.width),
        (p(1), cam.fy, cam.cy, cam.lim_y, cam.height),
    ];
    for (x, f, c, lim, size) in axes {
        let limit2 = (lim[0] * lim[0]).max(lim[1] * lim[1]);
        let reach = f * iz * s_max;
        let bound = slack * (reach * reach * (T::one() + limit2) + low_pass).sqrt() + T::one();
        let u = f * x * iz + c;
        if u + bound < T::zero() || u - bound > T::of(size as f64 - 1.0) {
            return true;
        }
    }
    false
}

/// The depth slope of [`crate::DepthModel::Plane`]: in the EWA ray space, linearised at the
/// mean, the Gaussian is a 3D Gaussian over (pixel, depth) with covariance
/// `[[Σ', JΣ_c e_z], [e_zᵀΣ_c Jᵀ, Σ_c,zz]]`; the densest point along a pixel's ray is the
/// conditional mean of the depth given the pixel, `z + (Σ'⁻¹·JΣ_c e_z)·(pixel − mean)` (the
/// ray–Gaussian intersection depth of RaDe-GS). Returns `Q·c` with `c = JΣ_c e_z`.
fn depth_slope<T: Real>(c: &Chain<T>) -> [T; 2] {
    let col = c.j * c.sigma_c.column(2);
    let slope = c.conic * col;
    [slope.x, slope.y]
}

/// Projects Gaussian `i`; `None` when it cannot touch any pixel. `plane_depth` selects
/// [`crate::DepthModel::Plane`] (the splat gets its [`depth_slope`]).
pub(crate) fn project_one<T: Real>(
    cam: &CameraT<T>,
    g: &Gaussians<T>,
    i: usize,
    plane_depth: bool,
) -> Option<Splat<T>> {
    let opacity = sigmoid(g.opacity_logits[i]);
    if !opacity.is_finite() || opacity < T::of(ALPHA_MIN) {
        return None;
    }
    if culled_early(cam, g, i) {
        return None;
    }
    let c = chain(cam, g, i)?;
    let iz = T::one() / c.p_c.z;
    let mean = [
        cam.fx * c.p_c.x * iz + cam.cx,
        cam.fy * c.p_c.y * iz + cam.cy,
    ];
    let extent = T::of(3.0).min(
        (T::of(2.0) * (T::of(255.0) * opacity).ln())
            .max(T::zero())
            .sqrt(),
    );
    let half = [c.cov[(0, 0)].sqrt() * extent, c.cov[(1, 1)].sqrt() * extent];
    let mut bbox = [0u32; 4];
    for k in 0..2 {
        let size = if k == 0 { cam.width } else { cam.height };
        let lo = (mean[k] - half[k]).ceil().max(T::zero());
        let hi = (mean[k] + half[k]).floor().min(T::of(size as f64 - 1.0));
        if !lo.is_finite() || !hi.is_finite() || lo > hi {
            return None;
        }
        bbox[2 * k] = lo.to_f64() as u32;
        bbox[2 * k + 1] = hi.to_f64() as u32;
    }
    let c0 = T::of(SH_C0);
    let half_one = T::of(0.5);
    Some(Splat {
        mean,
        conic: [c.conic[(0, 0)], c.conic[(0, 1)], c.conic[(1, 1)]],
        opacity,
        depth: c.p_c.z,
        depth_slope: if plane_depth {
            depth_slope(&c)
        } else {
            [T::zero(); 2]
        },
        colour: g.sh_dc[i].map(|v| half_one + c0 * v),
        bbox: [bbox[0], bbox[1], bbox[2], bbox[3]],
    })
}

/// Gradients of one Gaussian's projection, from upstream gradients on `u`.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct ProjectionGrads<T: Real> {
    pub mean: [T; 3],
    pub rotation: [T; 4],
    pub log_scale: [T; 3],
    /// `[ρ, θ]` of the left pose update.
    pub pose: [T; 6],
}

/// Vector-Jacobian product of the projection of Gaussian `i`: `up` holds the gradients on
/// `(mean_x, mean_y, Q_xx, Q_xy, Q_yy, z)` where `Q_xy` is the single off-diagonal coefficient
/// of `σ = ½Q_xx dx² + Q_xy dx dy + ½Q_yy dy²`, and `slope_up` those on the
/// [`Splat::depth_slope`] (zero under the centre-depth model).
pub(crate) fn project_vjp<T: Real>(
    c: &Chain<T>,
    cam: &CameraT<T>,
    up: &[T; 6],
    slope_up: [T; 2],
) -> ProjectionGrads<T> {
    let prep = ConicPrep::new(c);
    if slope_up == [T::zero(); 2] {
        return project_vjp_with(c, &prep, cam, up);
    }
    // The slope s = Q·c with c = J·Σ_c·e_z: ∂L/∂Q = g_s·cᵀ (only its symmetric part acts on the
    // symmetric conic), ∂L/∂c = Q·g_s.
    let col = prep.c.column(2);
    let gs = nalgebra::Vector2::new(slope_up[0], slope_up[1]);
    let mut up = *up;
    up[2] += gs.x * col.x;
    up[3] += gs.x * col.y + gs.y * col.x;
    up[4] += gs.y * col.y;
    let mut out = project_vjp_with(c, &prep, cam, &up);
    let gc = c.conic * gs;
    // c = J·(Σ_c e_z): ∂L/∂J = g_c·(Σ_c e_z)ᵀ, ∂L/∂Σ_c = sym(Jᵀg_c e_zᵀ).
    let sz = c.sigma_c.column(2);
    let mut dp = Vector3::zeros();
    add_jacobian_grad(c, cam, |r, k| gc[r] * sz[k], &mut dp);
    let jg = c.j.transpose() * gc;
    let half = T::of(0.5);
    let mut g_sigma = Matrix3::zeros();
    for k in 0..3 {
        g_sigma[(k, 2)] += half * jg[k];
        g_sigma[(2, k)] += half * jg[k];
    }
    let two = T::of(2.0);
    // Σ_c = W Σ Wᵀ, Σ = M Mᵀ: ∂L/∂M = 2·Wᵀ(∂L/∂Σ_c)W·M.
    let dm = c.w.transpose() * g_sigma * c.w * c.m * two;
    let (rotation, log_scale) = shape_grads(c, |i, j| dm[(i, j)]);
    let mean_grad = c.w.transpose() * dp;
    let pose = pose_grad(c, &dp, &(c.sigma_c * g_sigma));
    for k in 0..3 {
        out.mean[k] += mean_grad[k];
        out.log_scale[k] += log_scale[k];
    }
    for k in 0..4 {
        out.rotation[k] += rotation[k];
    }
    for k in 0..6 {
        out.pose[k] += pose[k];
    }
    out
}

/// Products of the projection chain that every vector-Jacobian product through the conic
/// reuses: `A = J·W`, `B = A·M` and `C = J·Σ_c` (2×3 each), so that with `G = ∂L/∂Σ'`:
/// `∂L/∂Σ_c = JᵀGJ`, `Wᵀ(JᵀGJ)W·M = AᵀG·B`, `Σ_c·JᵀGJ = CᵀG·J` and `G·J·Σ_c = G·C`.
pub(crate) struct ConicPrep<T: Real> {
    a: Matrix2x3<T>,
    b: Matrix2x3<T>,
    c: Matrix2x3<T>,
}

impl<T: Real> ConicPrep<T> {
    /// The products of chain `c`.
    pub(crate) fn new(c: &Chain<T>) -> Self {
        let a = c.j * c.w;
        Self {
            a,
            b: a * c.m,
            c: c.j * c.sigma_c,
        }
    }
}

/// [`project_vjp`] with the chain products `prep` given (they are shared with
/// [`projection_jacobian`]).
pub(crate) fn project_vjp_with<T: Real>(
    c: &Chain<T>,
    prep: &ConicPrep<T>,
    cam: &CameraT<T>,
    up: &[T; 6],
) -> ProjectionGrads<T> {
    let two = T::of(2.0);
    let half = T::of(0.5);
    let (fx, fy) = (cam.fx, cam.fy);
    let (x, y, z) = (c.p_c.x, c.p_c.y, c.p_c.z);
    let iz = T::one() / z;
    let iz2 = iz * iz;
    let mut dp = Vector3::new(
        up[0] * fx * iz,
        up[1] * fy * iz,
        -up[0] * fx * x * iz2 - up[1] * fy * y * iz2 + up[5],
    );
    if up[2] == T::zero() && up[3] == T::zero() && up[4] == T::zero() {
        // No gradient on the conic: every covariance term below is zero, only the mean path
        // remains.
        let mean_grad = c.w.transpose() * dp;
        let cross = c.p_c.cross(&dp);
        return ProjectionGrads {
            mean: [mean_grad.x, mean_grad.y, mean_grad.z],
            rotation: [T::zero(); 4],
            log_scale: [T::zero(); 3],
            pose: [dp.x, dp.y, dp.z, cross.x, cross.y, cross.z],
        };
    }
    // Conic → 2D covariance: dQ = −Q dΣ' Q.
    let gq = Matrix2::new(up[2], up[3] * half, up[3] * half, up[4]);
    let gs = -(c.conic * gq * c.conic);
    // Σ' = J Σ_c Jᵀ: ∂L/∂Σ_c = Jᵀ·gs·J, ∂L/∂J = 2·gs·J·Σ_c.
    let dj = gs * prep.c * two;
    add_jacobian_grad(c, cam, |r, k| dj[(r, k)], &mut dp);
    let mean_grad = c.w.transpose() * dp;
    // Σ_c = W Σ Wᵀ, Σ = M Mᵀ, M = R(q) S.
    // ∂L/∂Σ = Wᵀ(∂L/∂Σ_c)W = Aᵀ·gs·A; ∂L/∂M = 2·(∂L/∂Σ)·M = 2·Aᵀ·gs·B.
    let dm = prep.a.transpose() * (gs * prep.b) * two;
    let (rotation, log_scale) = shape_grads(c, |i, j| dm[(i, j)]);
    // Σ_c·(∂L/∂Σ_c) = Σ_c·Jᵀ·gs·J = Cᵀ·gs·J.
    let pose = pose_grad(c, &dp, &(prep.c.transpose() * (gs * c.j)));
    ProjectionGrads {
        mean: [mean_grad.x, mean_grad.y, mean_grad.z],
        rotation,
        log_scale,
        pose,
    }
}

/// `[ρ, θ]` gradients of the left pose update (SPEC §3): `∂p_c/∂ρ = I`, `∂p_c/∂θ = −[p_c]×`,
/// and through `Σ_c = W Σ Wᵀ` with `∂(W v)/∂θ = −[W v]×`, given `dp = ∂L/∂p_c` and
/// `p = Σ_c·(∂L/∂Σ_c)` for a symmetric `∂L/∂Σ_c` (only its antisymmetric part enters).
#[inline(always)]
fn pose_grad<T: Real>(c: &Chain<T>, dp: &Vector3<T>, p: &Matrix3<T>) -> [T; 6] {
    let two = T::of(2.0);
    let cross = c.p_c.cross(dp);
    [
        dp.x,
        dp.y,
        dp.z,
        cross.x + two * (p[(1, 2)] - p[(2, 1)]),
        cross.y + two * (p[(2, 0)] - p[(0, 2)]),
        cross.z + two * (p[(0, 1)] - p[(1, 0)]),
    ]
}

/// Adds to `dp = ∂L/∂p_c` what flows through the pinhole Jacobian `J` (evaluated at the
/// clamped `x/z`, `y/z`), given `dj(r, k) = ∂L/∂J_rk`.
#[inline(always)]
fn add_jacobian_grad<T: Real>(
    c: &Chain<T>,
    cam: &CameraT<T>,
    dj: impl Fn(usize, usize) -> T,
    dp: &mut Vector3<T>,
) {
    let two = T::of(2.0);
    let iz = T::one() / c.p_c.z;
    let iz2 = iz * iz;
    let iz3 = iz2 * iz;
    let focal = [cam.fx, cam.fy];
    dp.z += dj(0, 0) * (-focal[0] * iz2) + dj(1, 1) * (-focal[1] * iz2);
    for (k, f) in focal.iter().enumerate() {
        let d = dj(k, 2);
        if c.clamped[k] {
            dp.z += d * *f * c.t_xy[k] * iz3;
        } else {
            dp[k] += d * (-*f * iz2);
            dp.z += d * two * *f * c.t_xy[k] * iz3;
        }
    }
}

/// The gradients on the raw quaternion and the log-scales, given `dm(i, j) = ∂L/∂M_ij` for
/// `M = R(q/|q|)·S` (SPEC §3).
#[inline(always)]
fn shape_grads<T: Real>(c: &Chain<T>, dm: impl Fn(usize, usize) -> T) -> ([T; 4], [T; 3]) {
    let two = T::of(2.0);
    let four = T::of(4.0);
    let mut d_rq = [[T::zero(); 3]; 3];
    let mut log_scale = [T::zero(); 3];
    for jj in 0..3 {
        let mut ds = T::zero();
        for (ii, row) in d_rq.iter_mut().enumerate() {
            let v = dm(ii, jj);
            row[jj] = v * c.s[jj];
            ds += v * c.rq[(ii, jj)];
        }
        log_scale[jj] = ds * c.s[jj];
    }
    let g = |a: usize, b: usize| d_rq[a][b];
    let [w, qx, qy, qz] = c.q_n;
    let dqn = [
        two * (-qz * g(0, 1) + qy * g(0, 2) + qz * g(1, 0) - qx * g(1, 2) - qy * g(2, 0)
            + qx * g(2, 1)),
        two * (qy * g(0, 1) + qz * g(0, 2) + qy * g(1, 0) - w * g(1, 2)
            + qz * g(2, 0)
            + w * g(2, 1))
            - four * qx * (g(1, 1) + g(2, 2)),
        two * (qx * g(0, 1) + w * g(0, 2) + qx * g(1, 0) + qz * g(1, 2) - w * g(2, 0)
            + qz * g(2, 1))
            - four * qy * (g(0, 0) + g(2, 2)),
        two * (-w * g(0, 1)
            + qx * g(0, 2)
            + w * g(1, 0)
            + qy * g(1, 2)
            + qx * g(2, 0)
            + qy * g(2, 1))
            - four * qz * (g(0, 0) + g(1, 1)),
    ];
    let dot = dqn[0] * w + dqn[1] * qx + dqn[2] * qy + dqn[3] * qz;
    let rotation = [0, 1, 2, 3].map(|k| (dqn[k] - c.q_n[k] * dot) / c.q_norm);
    (rotation, log_scale)
}

/// The whole projection Jacobian of one Gaussian, row by row: `geo[k] = ∂u_k/∂w` over the 10
/// geometric parameters (mean, quaternion, log-scale) and `pose[k] = ∂u_k/∂τ` (zero unless
/// `with_pose`), for `u = (mean_x, mean_y, Q_xx, Q_xy, Q_yy, z)`. Row `k` equals
/// [`project_vjp_with`] with the unit upstream vector `e_k`, computed jointly: the three conic
/// rows have `G = ∂u_k/∂Σ' = −½(a·bᵀ + b·aᵀ)` with `a`, `b` columns of `Q`, so their products
/// with the chain (`2·G·C`, `2·AᵀG·B`, `CᵀG·J`) are sums of outer products of a few 3-vectors
/// shared by the rows, not 2×2×3 matrix chains per row (the Fisher pass's per-Gaussian cost).
pub(crate) fn projection_jacobian<T: Real>(
    c: &Chain<T>,
    prep: &ConicPrep<T>,
    cam: &CameraT<T>,
    with_pose: bool,
) -> ([[T; 10]; 6], [[T; 6]; 6]) {
    let two = T::of(2.0);
    let half = T::of(0.5);
    let (fx, fy) = (cam.fx, cam.fy);
    let iz = T::one() / c.p_c.z;
    let iz2 = iz * iz;
    let mut geo = [[T::zero(); 10]; 6];
    let mut pose = [[T::zero(); 6]; 6];
    // The mean rows (and z): no conic term, only the mean path.
    let mean_rows = [
        (0, Vector3::new(fx * iz, T::zero(), -fx * c.p_c.x * iz2)),
        (1, Vector3::new(T::zero(), fy * iz, -fy * c.p_c.y * iz2)),
        (5, Vector3::new(T::zero(), T::zero(), T::one())),
    ];
    for (k, dp) in mean_rows {
        let mean_grad = c.w.transpose() * dp;
        geo[k][0..3].copy_from_slice(&[mean_grad.x, mean_grad.y, mean_grad.z]);
        if with_pose {
            let cross = c.p_c.cross(&dp);
            pose[k] = [dp.x, dp.y, dp.z, cross.x, cross.y, cross.z];
        }
    }
    // Columns of the (symmetric) conic and their products with the chain's 2×3 factors.
    let q = [
        nalgebra::Vector2::new(c.conic[(0, 0)], c.conic[(1, 0)]),
        nalgebra::Vector2::new(c.conic[(0, 1)], c.conic[(1, 1)]),
    ];
    let aq = q.map(|v| prep.a.transpose() * v);
    let bq = q.map(|v| prep.b.transpose() * v);
    let cq = q.map(|v| prep.c.transpose() * v);
    let jq = q.map(|v| c.j.transpose() * v);
    // Row k = 2 + r with (a, b) = (q0, q0), (q0, q1), (q1, q1).
    for (r, (ia, ib)) in [(0usize, 0usize), (0, 1), (1, 1)].into_iter().enumerate() {
        let k = 2 + r;
        let (ua, ub) = (q[ia], q[ib]);
        // 2·G·C = −(a·(Cᵀb)ᵀ + b·(Cᵀa)ᵀ).
        let dj = |row: usize, col: usize| -(ua[row] * cq[ib][col] + ub[row] * cq[ia][col]);
        let mut dp = Vector3::zeros();
        add_jacobian_grad(c, cam, dj, &mut dp);
        let mean_grad = c.w.transpose() * dp;
        // 2·AᵀG·B = −(Aᵀa·(Bᵀb)ᵀ + Aᵀb·(Bᵀa)ᵀ).
        let dm = |i: usize, j: usize| -(aq[ia][i] * bq[ib][j] + aq[ib][i] * bq[ia][j]);
        let (rotation, log_scale) = shape_grads(c, dm);
        geo[k] = [
            mean_grad.x,
            mean_grad.y,
            mean_grad.z,
            rotation[0],
            rotation[1],
            rotation[2],
            rotation[3],
            log_scale[0],
            log_scale[1],
            log_scale[2],
        ];
        if with_pose {
            let cross = c.p_c.cross(&dp);
            // CᵀG·J = −½(Cᵀa·(Jᵀb)ᵀ + Cᵀb·(Jᵀa)ᵀ); only its antisymmetric part enters.
            let p = |i: usize, j: usize| -half * (cq[ia][i] * jq[ib][j] + cq[ib][i] * jq[ia][j]);
            pose[k] = [
                dp.x,
                dp.y,
                dp.z,
                cross.x + two * (p(1, 2) - p(2, 1)),
                cross.y + two * (p(2, 0) - p(0, 2)),
                cross.z + two * (p(0, 1) - p(1, 0)),
            ];
        }
    }
    (geo, pose)
}

/// Row-wise evaluation of `σ = ½Q_xx dx² + Q_xy dx dy + ½Q_yy dy²` (SPEC §3): the terms in
/// `dy` are computed once per pixel row. Forward, backward and Fisher share it, so they agree
/// bit for bit on every alpha and threshold test.
#[derive(Debug, Clone, Copy)]
pub(crate) struct SigmaRow<T: Real> {
    half_qa: T,
    b: T,
    c: T,
}

impl<T: Real> SigmaRow<T> {
    /// Row terms of splat `s` at vertical offset `dy = mean_y − pixel_y`.
    #[inline(always)]
    pub fn new(s: &Splat<T>, dy: T) -> Self {
        let half = T::of(0.5);
        Self {
            half_qa: half * s.conic[0],
            b: s.conic[1] * dy,
            c: half * s.conic[2] * dy * dy,
        }
    }

    /// σ at horizontal offset `dx = mean_x − pixel_x`.
    #[inline(always)]
    pub fn sigma(&self, dx: T) -> T {
        dx * (self.half_qa * dx + self.b) + self.c
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use activemap_geometry::{Intrinsics, Isometry3};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The early cull only ever drops Gaussians the full projection drops too, and it does
    /// drop most of those outside the field of view (else it would be useless).
    #[test]
    fn the_early_cull_drops_only_gaussians_the_projection_drops() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut g = Gaussians::<f32>::new();
        for _ in 0..40_000 {
            let mean = [
                rng.random_range(-6.0..6.0),
                rng.random_range(-6.0..6.0),
                rng.random_range(-1.0..8.0),
            ];
            // Scales from 1 mm to 0.5 m (log-uniform; the mapper prunes larger ones), random
            // rotations.
            let scale = [0; 3].map(|_| 10f64.powf(rng.random_range(-3.0..-0.3)));
            let q = [0; 4].map(|_| rng.random_range(-1.0..1.0));
            g.push(mean, [0.5, 0.4, 0.3], q, rng.random_range(0.05..1.0), scale);
        }
        let mut early_count = 0;
        let mut dropped_outside = 0;
        for (width, height, hfov) in [(160, 160, 90f64), (200, 120, 60.0), (64, 96, 110.0)] {
            let k = Intrinsics::from_hfov(width, height, hfov.to_radians());
            let cam = CameraT::<f32>::new(&Camera::new(k, Isometry3::identity()));
            for i in 0..g.len() {
                let early = culled_early(&cam, &g, i);
                let full = bbox_of(&cam, &g, i);
                if early {
                    early_count += 1;
                    assert!(
                        full.is_none(),
                        "Gaussian {i} culled early but touches {full:?}"
                    );
                }
                if full.is_none() && chain(&cam, &g, i).is_some() {
                    dropped_outside += 1;
                }
            }
        }
        assert!(
            early_count * 10 >= dropped_outside * 9,
            "the early cull caught {early_count} of {dropped_outside} off-screen Gaussians"
        );
    }

    #[test]
    fn the_far_plane_culls_exactly_what_lies_beyond_it() {
        let k = Intrinsics::from_hfov(64, 64, 90f64.to_radians());
        let camera = Camera::new(k, Isometry3::identity());
        let mut g = Gaussians::<f32>::new();
        for z in [1.0, 2.9, 3.1, 8.0] {
            g.push(
                [0.1, -0.1, z],
                [0.5; 3],
                [1.0, 0.0, 0.0, 0.0],
                0.9,
                [0.05; 3],
            );
        }
        let near_only = CameraT::<f32>::new(&camera);
        let with_far = CameraT::<f32>::new(&camera.with_far(3.0));
        let seen = |cam: &CameraT<f32>| -> Vec<bool> {
            (0..g.len())
                .map(|i| project_one(cam, &g, i, false).is_some())
                .collect()
        };
        assert_eq!(seen(&near_only), vec![true; 4]);
        assert_eq!(seen(&with_far), vec![true, true, false, false]);
        assert!(camera.with_far(0.005).validate().is_err());
        assert!(camera.with_far(f64::NAN).validate().is_err());
        assert!(camera.with_far(f64::INFINITY).validate().is_ok());
    }

    /// Random Gaussians in front of a tilted camera (f64): some well inside the view, some
    /// beyond 1.3× its field of view, where the pinhole Jacobian is clamped.
    fn jacobian_scene(seed: u64) -> (CameraT<f64>, Gaussians<f64>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let k = Intrinsics::from_hfov(40, 32, 90f64.to_radians());
        let pose = Isometry3::new(
            nalgebra::Vector3::new(0.2, -0.1, 0.3),
            nalgebra::Vector3::new(0.1, -0.2, 0.05),
        );
        let cam = CameraT::<f64>::new(&Camera::new(k, pose));
        let mut g = Gaussians::<f64>::new();
        for n in 0..60 {
            // Every third lies far off the axis (|x/z| > 1.3·tan 45°): a clamped Jacobian.
            let off = if n % 3 == 0 { 3.0 } else { 0.6 };
            let z: f64 = rng.random_range(1.0..4.0);
            let mean = [
                rng.random_range(-off..off) * z,
                rng.random_range(-0.6..0.6) * z,
                z,
            ];
            let scale = [0; 3].map(|_| 10f64.powf(rng.random_range(-2.5..-0.7)));
            let q = [0; 4].map(|_| rng.random_range(-1.0..1.0));
            g.push(mean, [0.5, 0.4, 0.3], q, rng.random_range(0.2..0.9), scale);
        }
        (cam, g)
    }

    /// The joint Jacobian is, row by row, the vector-Jacobian product with a unit vector
    /// (geometric and pose parts), to rounding; without the pose its pose part is zero and its
    /// geometric part the same.
    #[test]
    fn the_joint_jacobian_equals_the_products_with_unit_vectors() {
        let (cam, g) = jacobian_scene(11);
        let mut clamped = 0;
        for i in 0..g.len() {
            let Some(c) = chain(&cam, &g, i) else {
                continue;
            };
            clamped += usize::from(c.clamped.iter().any(|v| *v));
            let prep = ConicPrep::new(&c);
            let (geo, pose) = projection_jacobian(&c, &prep, &cam, true);
            let (geo_alone, pose_alone) = projection_jacobian(&c, &prep, &cam, false);
            assert_eq!(geo, geo_alone);
            assert_eq!(pose_alone, [[0.0; 6]; 6]);
            for k in 0..6 {
                let mut up = [0.0; 6];
                up[k] = 1.0;
                let v = project_vjp(&c, &cam, &up, [0.0; 2]);
                let want: Vec<f64> = v
                    .mean
                    .iter()
                    .chain(&v.rotation)
                    .chain(&v.log_scale)
                    .chain(&v.pose)
                    .copied()
                    .collect();
                let got: Vec<f64> = geo[k].iter().chain(&pose[k]).copied().collect();
                let scale = want.iter().fold(1e-9f64, |m, x| m.max(x.abs()));
                for (p, (a, b)) in got.iter().zip(&want).enumerate() {
                    assert!(
                        (a - b).abs() <= 1e-12 * scale,
                        "Gaussian {i} row {k} entry {p}: {a} vs {b}"
                    );
                }
            }
        }
        assert!(clamped > 5, "only {clamped} clamped Gaussians");
    }

    /// The geometric rows against central finite differences of the projection itself (f64):
    /// `u = (mean_x, mean_y, Q_xx, Q_xy, Q_yy, z)` of [`project_one`] under a nudge of each
    /// mean coordinate, quaternion component and log-scale.
    #[test]
    fn the_joint_jacobian_matches_finite_differences_of_the_projection() {
        let (cam, g) = jacobian_scene(12);
        let u_of = |g: &Gaussians<f64>, i: usize| -> Option<[f64; 6]> {
            let s = project_one(&cam, g, i, false)?;
            Some([
                s.mean[0], s.mean[1], s.conic[0], s.conic[1], s.conic[2], s.depth,
            ])
        };
        let mut checked = 0;
        for i in 0..g.len() {
            let Some(c) = chain(&cam, &g, i) else {
                continue;
            };
            if u_of(&g, i).is_none() {
                continue;
            }
            let (geo, _) = projection_jacobian(&c, &ConicPrep::new(&c), &cam, false);
            for p in 0..10 {
                let h = 1e-6;
                let nudged = |d: f64| {
                    let mut h_g = g.clone();
                    match p {
                        0..=2 => h_g.means[i][p] += d,
                        3..=6 => h_g.rotations[i][p - 3] += d,
                        _ => h_g.log_scales[i][p - 7] += d,
                    }
                    u_of(&h_g, i)
                };
                let (Some(plus), Some(minus)) = (nudged(h), nudged(-h)) else {
                    continue;
                };
                for k in 0..6 {
                    let fd = (plus[k] - minus[k]) / (2.0 * h);
                    let tol = 1e-6 * (1.0 + fd.abs().max(geo[k][p].abs()));
                    assert!(
                        (fd - geo[k][p]).abs() <= tol,
                        "Gaussian {i} ∂u_{k}/∂w_{p}: analytic {} vs finite difference {fd}",
                        geo[k][p]
                    );
                }
                checked += 1;
            }
        }
        assert!(checked > 300, "only {checked} columns checked");
    }

    /// The screen box of Gaussian `i` at the largest extent (3, as for an opaque Gaussian),
    /// computed without the early cull.
    fn bbox_of(cam: &CameraT<f32>, g: &Gaussians<f32>, i: usize) -> Option<[u32; 4]> {
        let c = chain(cam, g, i)?;
        let iz = 1.0 / c.p_c.z;
        let mean = [
            cam.fx * c.p_c.x * iz + cam.cx,
            cam.fy * c.p_c.y * iz + cam.cy,
        ];
        let half = [3.0 * c.cov[(0, 0)].sqrt(), 3.0 * c.cov[(1, 1)].sqrt()];
        let mut bbox = [0u32; 4];
        for k in 0..2 {
            let size = if k == 0 { cam.width } else { cam.height };
            let lo = (mean[k] - half[k]).ceil().max(0.0);
            let hi = (mean[k] + half[k]).floor().min(size as f32 - 1.0);
            if lo > hi {
                return None;
            }
            bbox[2 * k] = lo as u32;
            bbox[2 * k + 1] = hi as u32;
        }
        Some(bbox)
    }
}
