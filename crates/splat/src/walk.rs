//! The per-pixel loops of the rasteriser, shared by the forward pass, the backward pass and the
//! Fisher pass (SPEC §3), written for speed:
//!
//! - a tile's per-pixel state lives in structure-of-arrays stack buffers (`TILE²` pixels plus
//!   [`LANES`] of padding), rows of a Gaussian's box are processed [`LANES`] pixels at a time,
//!   branch-free (masks and selects, [`Real::exp_fast`]), so the compiler vectorises them;
//! - on x86-64 the same code is also compiled for AVX-512 (32 vector registers; the forward
//!   pass's 16 lanes in one register) and for AVX2 with FMA, and the best build the CPU runs is
//!   picked at run time ([`simd_level`]). All builds do the same operations in the same order; the
//!   sinks' accumulations use `mul_add`, which is correctly rounded everywhere (an FMA
//!   instruction, or the library `fma` on CPUs without one, much slower but equal), and
//!   nothing else is fused, so the results are identical; they do not depend on the thread
//!   count either.
//!
//! [`alpha_at`] is the one definition of `α = min(0.99, o·e^{−σ})` and of the compositing
//! tests, so forward, backward and Fisher agree bit for bit. [`walk_back`] is the one
//! back-to-front traversal; the backward and Fisher passes plug in what they accumulate through
//! [`BackSink`].

use crate::project::{ALPHA_MAX, ALPHA_MIN, SigmaRow, Splat};
use crate::rasterize::{ForwardContext, clip_box, pixel_depth, row_depth};
use crate::real::Real;
use crate::tiles::{TILE, split_by_offsets};
use rayon::prelude::*;

/// Pixels the backward pass processes together along a row (8 × f32 = one AVX2 register). Its
/// boxes are often narrower than a tile row at the mapping resolutions (160–200 px), where 16
/// lanes made it 18 % slower. The walk is generic over the lane count (the Fisher pass uses
/// its own).
pub(crate) const LANES: usize = 8;
/// Pixels the forward pass processes together: a whole tile row (16 × f32 = one AVX-512
/// register). It has fewer accumulators per lane, and 16 lanes made it 18 % (200 px, 10k
/// Gaussians) to 36 % (800 px, 100k) faster than 8 on the 2-core machine. The lanes are
/// independent pixels, so the images do not depend on the lane count.
pub(crate) const FORWARD_LANES: usize = 16;
const _: () = assert!(LANES.is_power_of_two(), "lane sums halve the lanes");
/// Pixels of a tile.
pub(crate) const TILE_PIXELS: usize = TILE * TILE;
/// Length of the per-tile state buffers: a chunk of either lane count may start at any pixel
/// of the tile.
pub(crate) const PADDED: usize = TILE_PIXELS + FORWARD_LANES;

/// The `N` entries of a per-tile buffer starting at tile-local pixel `base`.
#[inline(always)]
pub(crate) fn lanes_n_mut<V, const N: usize>(buffer: &mut [V; PADDED], base: usize) -> &mut [V; N] {
    (&mut buffer[base..base + N])
        .try_into()
        .expect("chunk starts inside the tile")
}

/// Read-only version of [`lanes_n_mut`].
#[inline(always)]
pub(crate) fn lanes_n<V, const N: usize>(buffer: &[V; PADDED], base: usize) -> &[V; N] {
    (&buffer[base..base + N])
        .try_into()
        .expect("chunk starts inside the tile")
}

/// [`lanes_n`] with the walks' [`LANES`].
#[inline(always)]
pub(crate) fn lanes<V>(buffer: &[V; PADDED], base: usize) -> &[V; LANES] {
    lanes_n(buffer, base)
}

/// `[0, 1, …, N − 1]` in `T`: pixel offsets of the lanes.
#[inline(always)]
pub(crate) fn lane_offsets<T: Real, const N: usize>() -> [T; N] {
    std::array::from_fn(|l| T::of(l as f64))
}

/// Opacity of a splat at horizontal offset `dx = mean_x − pixel_x` of a row (SPEC §3):
/// returns `(e^{−σ}, o·e^{−σ}, α = min(0.99, o·e^{−σ}), composited)` where `composited` is
/// `σ ≥ 0 ∧ α ≥ 1/255`.
#[inline(always)]
pub(crate) fn alpha_at<T: Real>(row: &SigmaRow<T>, opacity: T, dx: T) -> (T, T, T, bool) {
    let sigma = row.sigma(dx);
    let gauss = (-sigma).exp_fast();
    let raw = opacity * gauss;
    let alpha = raw.min(T::of(ALPHA_MAX));
    (
        gauss,
        raw,
        alpha,
        (sigma >= T::zero()) & (alpha >= T::of(ALPHA_MIN)),
    )
}

/// Per-lane quantities of one Gaussian at `L` pixels of a row, back-to-front. Lanes the
/// Gaussian does not composite into have `alpha = gauss = weight = grad = 0`, `inv = 1`, so
/// that sinks can use them unmasked.
#[derive(Clone, Copy)]
pub(crate) struct Lanes<T: Real, const L: usize> {
    /// `mean_x − pixel_x`.
    pub dx: [T; L],
    /// `α_i`.
    pub alpha: [T; L],
    /// `e^{−σ}`.
    pub gauss: [T; L],
    /// 1 where `α_i` is composited and below the 0.99 clamp (gradients flow through it), else 0.
    pub grad: [T; L],
    /// `1/(1 − α_i)`.
    pub inv: [T; L],
    /// Transmittance in front of the Gaussian, `T_i`.
    pub t_i: [T; L],
    /// `α_i T_i`.
    pub weight: [T; L],
    /// The Gaussian's depth at the pixel ([`crate::DepthModel`]).
    pub depth: [T; L],
    /// Colour composited behind the Gaussian.
    pub s_col: [[T; L]; 3],
    /// Depth composited behind the Gaussian.
    pub s_dep: [T; L],
}

/// What a back-to-front walk accumulates (the backward pass, the Fisher pass).
pub(crate) trait BackSink<T: Real, const L: usize> {
    /// Initialises the sink's state of tile-local pixel `local` = image pixel `pixel`.
    fn init_pixel(&mut self, local: usize, pixel: usize);
    /// A new (tile, Gaussian) pair: Gaussian `id`, projected as `splat`.
    fn begin_pair(&mut self, id: usize, splat: &Splat<T>);
    /// A new pixel row at vertical offset `dy = mean_y − pixel_y`.
    fn begin_row(&mut self, dy: T);
    /// `L` pixels starting at tile-local pixel `base`, the `chunk`-th (`< 16 / L`, rounded up)
    /// of the pair's row: chunk `c` starts at the same column (`dx`) on every row of a pair.
    fn step(&mut self, base: usize, chunk: usize, lanes: &Lanes<T, L>);
    /// End of the row begun with `dy`.
    fn end_row(&mut self, dy: T);
    /// End of the pair at position `k` of the tile's list.
    fn end_pair(&mut self, k: usize);
    /// End of the tile: per-tile work that should run in the same (SIMD) build as the walk.
    fn end_tile(&mut self) {}
}

/// The instruction sets a build of the pixel loops may use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub(crate) enum SimdLevel {
    /// Plain Rust, no target features.
    Portable,
    /// AVX2 and FMA.
    Avx2,
    /// AVX-512 F and VL (with AVX2 and FMA).
    Avx512,
}

/// The best build this CPU runs (capped in the test that compares the builds).
#[inline(always)]
pub(crate) fn simd_level() -> SimdLevel {
    #[cfg(target_arch = "x86_64")]
    let detected = if std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512vl")
        && std::arch::is_x86_feature_detected!("avx2")
        && std::arch::is_x86_feature_detected!("fma")
    {
        SimdLevel::Avx512
    } else if std::arch::is_x86_feature_detected!("avx2")
        && std::arch::is_x86_feature_detected!("fma")
    {
        SimdLevel::Avx2
    } else {
        SimdLevel::Portable
    };
    #[cfg(not(target_arch = "x86_64"))]
    let detected = SimdLevel::Portable;
    #[cfg(test)]
    {
        detected.min(tests::simd_cap())
    }
    #[cfg(not(test))]
    {
        detected
    }
}

/// Walks tile `tile` of the render in `ctx` back to front (from each pixel's last composited
/// Gaussian), feeding `sink`.
pub(crate) fn walk_back<T: Real, S: BackSink<T, L>, const L: usize>(
    ctx: &ForwardContext<T>,
    tile: usize,
    sink: &mut S,
) {
    match simd_level() {
        // SAFETY: the CPU supports AVX-512 F and VL, AVX2 and FMA (checked by `simd_level`).
        #[cfg(target_arch = "x86_64")]
        SimdLevel::Avx512 => unsafe { walk_back_avx512(ctx, tile, sink) },
        // SAFETY: the CPU supports AVX2 and FMA (checked by `simd_level`).
        #[cfg(target_arch = "x86_64")]
        SimdLevel::Avx2 => unsafe { walk_back_avx2(ctx, tile, sink) },
        _ => walk_back_impl(ctx, tile, sink),
    }
}

/// [`walk_back_impl`] compiled with AVX-512 (F and VL), AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
unsafe fn walk_back_avx512<T: Real, S: BackSink<T, L>, const L: usize>(
    ctx: &ForwardContext<T>,
    tile: usize,
    sink: &mut S,
) {
    walk_back_impl(ctx, tile, sink);
}

/// [`walk_back_impl`] compiled with AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn walk_back_avx2<T: Real, S: BackSink<T, L>, const L: usize>(
    ctx: &ForwardContext<T>,
    tile: usize,
    sink: &mut S,
) {
    walk_back_impl(ctx, tile, sink);
}

#[inline(always)]
fn walk_back_impl<T: Real, S: BackSink<T, L>, const L: usize>(
    ctx: &ForwardContext<T>,
    tile: usize,
    sink: &mut S,
) {
    let (width, height) = (ctx.cam.width, ctx.cam.height);
    let rect = ctx.bins.tile_rect(tile, width, height);
    let list = ctx.bins.tile(tile);
    let mut t = [T::one(); PADDED];
    let mut last = [0u32; PADDED];
    let mut s_col = [[T::zero(); PADDED]; 3];
    let mut s_dep = [T::zero(); PADDED];
    for py in rect[2]..rect[3] {
        for px in rect[0]..rect[1] {
            let local = (py - rect[2]) * TILE + px - rect[0];
            let pixel = py * width + px;
            t[local] = ctx.final_transmittance[pixel];
            last[local] = ctx.contributors[pixel];
            sink.init_pixel(local, pixel);
        }
    }
    let offsets = lane_offsets::<T, L>();
    for k in (0..ctx.walked(tile)).rev() {
        let id = list[k] as usize;
        let s = &ctx.splats[id];
        let Some([bx0, bx1, by0, by1]) = clip_box(s, &rect) else {
            continue;
        };
        sink.begin_pair(id, s);
        let k_u32 = k as u32;
        for py in by0..=by1 {
            let dy = s.mean[1] - T::of(py as f64);
            let row = SigmaRow::new(s, dy);
            let row_z = row_depth(s, dy);
            sink.begin_row(dy);
            let mut x = bx0;
            while x <= bx1 {
                let base = (py - rect[2]) * TILE + x - rect[0];
                let valid = (bx1 + 1 - x).min(L);
                let dx0 = s.mean[0] - T::of(x as f64);
                let last_l: &[u32; L] = lanes_n(&last, base);
                // Lanes past the box (`l >= valid`) never composite this splat.
                if (0..L).fold(0, |most, l| most.max(if l < valid { last_l[l] } else { 0 }))
                    <= k_u32
                {
                    // The Gaussian is behind the last composited one of every pixel of the
                    // chunk inside its box.
                    x += L;
                    continue;
                }
                let t_l = lanes_n_mut::<_, L>(&mut t, base);
                let mut ln = Lanes {
                    dx: [T::zero(); L],
                    alpha: [T::zero(); L],
                    gauss: [T::zero(); L],
                    grad: [T::zero(); L],
                    inv: [T::one(); L],
                    t_i: [T::zero(); L],
                    weight: [T::zero(); L],
                    depth: [T::zero(); L],
                    s_col: [
                        *lanes_n(&s_col[0], base),
                        *lanes_n(&s_col[1], base),
                        *lanes_n(&s_col[2], base),
                    ],
                    s_dep: *lanes_n(&s_dep, base),
                };
                for l in 0..L {
                    let dx = dx0 - offsets[l];
                    let (gauss, raw, alpha, composited) = alpha_at(&row, s.opacity, dx);
                    let on = composited & (l < valid) & (k_u32 < last_l[l]);
                    let alpha = if on { alpha } else { T::zero() };
                    let inv = T::one() / (T::one() - alpha);
                    let t_i = t_l[l] * inv;
                    ln.dx[l] = dx;
                    ln.alpha[l] = alpha;
                    ln.gauss[l] = if on { gauss } else { T::zero() };
                    ln.grad[l] = if on & (raw < T::of(ALPHA_MAX)) {
                        T::one()
                    } else {
                        T::zero()
                    };
                    ln.inv[l] = inv;
                    ln.t_i[l] = t_i;
                    ln.weight[l] = alpha * t_i;
                    ln.depth[l] = pixel_depth(s, row_z, dx);
                }
                if !ln
                    .alpha
                    .iter()
                    .fold(false, |any, a| any | (*a != T::zero()))
                {
                    // No lane composites this Gaussian: nothing to accumulate, and the
                    // transmittance and the colour behind stay as they are.
                    x += L;
                    continue;
                }
                sink.step(base, (x - bx0) / L, &ln);
                *t_l = ln.t_i;
                for ch in 0..3 {
                    let sc = lanes_n_mut::<_, L>(&mut s_col[ch], base);
                    for l in 0..L {
                        sc[l] += s.colour[ch] * ln.weight[l];
                    }
                }
                let sd = lanes_n_mut::<_, L>(&mut s_dep, base);
                for l in 0..L {
                    sd[l] += ln.depth[l] * ln.weight[l];
                }
                x += L;
            }
            sink.end_row(dy);
        }
        sink.end_pair(k);
    }
    sink.end_tile();
}

/// Sum of the lanes in a fixed order (deterministic).
#[inline(always)]
pub(crate) fn lane_sum<T: Real, const L: usize>(v: &[T; L]) -> T {
    let mut acc = T::zero();
    for x in v {
        acc += *x;
    }
    acc
}

/// Walks every tile in parallel: `per_tile(tile, slots)` gets the tile's piece of a zeroed slot
/// array with `slot` values per walked pair (the first [`ForwardContext::walked`] entries of
/// the tile's list). Returns the slots and the per-tile results, in tile order.
pub(crate) fn walk_tiles<T: Real, R: Send>(
    ctx: &ForwardContext<T>,
    slot: usize,
    per_tile: impl Fn(usize, &mut [T]) -> R + Sync + Send,
) -> (Vec<T>, Vec<R>) {
    let mut slots = vec![T::zero(); ctx.walked_offsets.last().copied().unwrap_or(0) * slot];
    let results = split_by_offsets(&mut slots, &ctx.walked_offsets, slot)
        .into_par_iter()
        .with_max_len(1)
        .enumerate()
        .map(|(t, piece)| per_tile(t, piece))
        .collect();
    (slots, results)
}

/// Sums the pair slots of [`walk_tiles`] per Gaussian, in pair (tile) order, so the result
/// does not depend on the thread count. The pairs of each Gaussian are first listed (counting
/// sort over the Gaussian ids), then the Gaussians are summed in parallel.
pub(crate) fn reduce_slots<T: Real, const N: usize>(
    ctx: &ForwardContext<T>,
    slots: &[T],
    gaussians: usize,
) -> Vec<[T; N]> {
    reduce_slots_by(ctx, slots, gaussians, |id| id as usize)
}

/// [`reduce_slots`] into `count` sums, the pairs of Gaussian `id` going to sum `index(id)`
/// (`< count`): a compact output when only some Gaussians are walked.
pub(crate) fn reduce_slots_by<T: Real, const N: usize>(
    ctx: &ForwardContext<T>,
    slots: &[T],
    count: usize,
    index: impl Fn(u32) -> usize,
) -> Vec<[T; N]> {
    let gaussians = count;
    let tiles = ctx.bins.tile_count();
    let walked_ids = |t: usize| &ctx.bins.tile(t)[..ctx.walked(t)];
    let mut starts = vec![0usize; gaussians + 1];
    for t in 0..tiles {
        for &id in walked_ids(t) {
            starts[index(id) + 1] += 1;
        }
    }
    for i in 0..gaussians {
        starts[i + 1] += starts[i];
    }
    let mut fill = starts.clone();
    let mut pairs = vec![0usize; starts[gaussians]];
    for t in 0..tiles {
        let first = ctx.walked_offsets[t];
        for (k, &id) in walked_ids(t).iter().enumerate() {
            let at = &mut fill[index(id)];
            pairs[*at] = first + k;
            *at += 1;
        }
    }
    let mut out = vec![[T::zero(); N]; gaussians];
    out.par_chunks_mut(REDUCE_CHUNK)
        .enumerate()
        .for_each(|(chunk, part)| {
            for (j, sum) in part.iter_mut().enumerate() {
                let i = chunk * REDUCE_CHUNK + j;
                for p in starts[i]..starts[i + 1] {
                    // The slots are read in Gaussian order, scattered over the pair array:
                    // fetching a few pairs ahead hides the memory latency.
                    if let Some(&ahead) = pairs.get(p + PREFETCH_PAIRS) {
                        prefetch(&slots[ahead * N..(ahead + 1) * N]);
                    }
                    let pair = pairs[p];
                    let src = &slots[pair * N..(pair + 1) * N];
                    for (d, v) in sum.iter_mut().zip(src) {
                        *d += *v;
                    }
                }
            }
        });
    out
}

/// Gaussians per parallel task of [`reduce_slots`].
const REDUCE_CHUNK: usize = 1024;

/// How many pairs ahead [`reduce_slots`] prefetches.
const PREFETCH_PAIRS: usize = 8;

/// Asks the CPU to bring `data` into the cache (a hint: no effect on results).
#[inline(always)]
fn prefetch<V>(data: &[V]) {
    #[cfg(target_arch = "x86_64")]
    {
        let bytes = std::mem::size_of_val(data);
        let start = data.as_ptr().cast::<i8>();
        for offset in (0..bytes).step_by(64) {
            // SAFETY: `_mm_prefetch` is a hint that never faults; the address is inside `data`.
            unsafe {
                std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                    start.add(offset),
                )
            };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = data;
}

#[cfg(test)]
mod tests {
    use super::SimdLevel;
    use crate::DepthModel;
    use crate::bench::{camera, scene};
    use crate::*;
    use std::sync::atomic::{AtomicU8, Ordering};

    /// Set only by the test below: the best build the pixel loops may use (0 portable, 1 AVX2,
    /// 2 AVX-512).
    static SIMD_CAP: AtomicU8 = AtomicU8::new(2);

    /// The cap [`super::simd_level`] applies in tests.
    pub(crate) fn simd_cap() -> SimdLevel {
        match SIMD_CAP.load(Ordering::Relaxed) {
            0 => SimdLevel::Portable,
            1 => SimdLevel::Avx2,
            _ => SimdLevel::Avx512,
        }
    }

    #[test]
    fn simd_and_portable_builds_agree_bit_for_bit() {
        let g = scene(3000);
        let cam = camera(72);
        let opts = RenderOptions {
            exposure: [0.2, 0.01],
            exclude_flags: 0,
            depth: DepthModel::Centre,
        };
        let run = |cap: u8| {
            SIMD_CAP.store(cap, Ordering::Relaxed);
            let out = render(&g, &cam, &opts).unwrap();
            let mut dl = PixelGrads::zeros(out.colour.len());
            for (i, c) in dl.colour.iter_mut().enumerate() {
                *c = [((i % 7) as f32 - 3.0) * 0.01, 0.02, -0.01];
                dl.depth[i] = ((i % 5) as f32 - 2.0) * 0.1;
                dl.opacity[i] = 0.05;
            }
            let grads = backward(&g, &out, &dl).unwrap();
            let info = fisher(&g, &out, FisherMode::PerChannel).unwrap();
            let wide =
                crate::fisher::fisher_with_lanes(&g, &out, FisherMode::PerChannel, true, true);
            let diagonal = crate::fisher::fisher_sparse(&g, &out, FisherMode::PerChannel, false);
            SIMD_CAP.store(2, Ordering::Relaxed);
            (
                out.colour,
                out.depth,
                grads,
                (info, wide.unwrap(), diagonal.unwrap()),
            )
        };
        eprintln!("this CPU runs the {:?} build", super::simd_level());
        let simd = run(2);
        let avx2 = run(1);
        let portable = run(0);
        assert_eq!(simd.0, avx2.0);
        assert_eq!(simd.1, avx2.1);
        assert_eq!(simd.2, avx2.2);
        assert_eq!(simd.3, avx2.3);
        assert!(simd.2.pose.norm() > 0.0 && simd.3.0.pose_colour.trace() > 0.0);
        assert_eq!(simd.0, portable.0);
        assert_eq!(simd.1, portable.1);
        assert_eq!(simd.2, portable.2);
        assert_eq!(simd.3, portable.3);
    }
}
