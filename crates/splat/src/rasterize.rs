//! The forward pass (SPEC §3): project, bin, then per tile composite front to back with
//! `α = min(0.99, o·exp(−σ))`, `σ = ½ dᵀ Σ'⁻¹ d`, `d = mean − pixel` (pixel centres at integer
//! coordinates, as `activemap_geometry::Intrinsics`), skipping `α < 1/255` and stopping before
//! the transmittance would fall below 1e-4. Outputs colour `e^a·Σ c α T + b`, depth `Σ z α T`
//! (un-normalised, as MonoGS) and opacity `1 − T_final`.

use crate::SplatError;
use crate::camera::{Camera, CameraT};
use crate::gaussians::Gaussians;
use crate::project::{SigmaRow, Splat, T_MIN, project_one};
use crate::real::Real;
use crate::tiles::{TILE, TileBins, bin};
use crate::walk::{FORWARD_LANES, PADDED, TILE_PIXELS, alpha_at, lane_offsets, lanes_n_mut};
use rayon::prelude::*;

/// Which depth a Gaussian contributes at a pixel. The default is the model every map of the
/// pipeline is fitted and rendered under ([`DepthModel::Plane`], issue 33); the Fisher pass
/// needs [`DepthModel::Centre`] renders.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DepthModel {
    /// The camera-frame depth of its centre at every pixel (SPEC §3, 3DGS, MonoGS).
    Centre,
    /// The depth of its densest point along the pixel's ray, linearised at the centre: a plane
    /// `z + s·(pixel − mean)` over the splat ([`Splat::depth_slope`]). A flat Gaussian on a
    /// surface seen at a grazing angle then renders the surface's depth at every pixel it
    /// covers, where the centre model renders its centre's depth over the whole footprint, short
    /// of the surface on one side, which the depth loss answers by pushing the Gaussian behind
    /// the surface (not in the SPEC; the ray–Gaussian intersection depth of RaDe-GS).
    #[default]
    Plane,
}

/// Options of one render.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RenderOptions {
    /// Exposure `(a, b)`: output colour `e^a·colour + b` (SPEC §4), `(0, 0)` = identity.
    pub exposure: [f64; 2],
    /// Gaussians whose `flags & exclude_flags != 0` are left out of the render.
    pub exclude_flags: u8,
    /// The per-pixel depth of a Gaussian (the map's model by default).
    pub depth: DepthModel,
}

/// What the backward and Fisher passes reuse from the forward pass.
#[derive(Debug, Clone)]
pub struct ForwardContext<T: Real> {
    /// The camera rendered from.
    pub camera: Camera,
    pub(crate) cam: CameraT<T>,
    /// The options rendered with.
    pub options: RenderOptions,
    /// Projection of every Gaussian (meaningful where `visible`).
    pub splats: Vec<Splat<T>>,
    /// Whether Gaussian `i` touches the image (not culled, not excluded).
    pub visible: Vec<bool>,
    /// Per-tile depth-sorted lists.
    pub bins: TileBins,
    /// Per pixel, the transmittance left after compositing.
    pub final_transmittance: Vec<T>,
    /// Per pixel, how many entries of its tile list were composited (index of the last
    /// contributing Gaussian + 1); backward starts there.
    pub contributors: Vec<u32>,
    /// Colour before exposure, `Σ c α T`, per pixel.
    pub raw_colour: Vec<[T; 3]>,
    /// Prefix sums over tiles of how many list entries any pixel of the tile composited: the
    /// pairs the backward walks visit get slots `walked_offsets[t]..walked_offsets[t + 1]`.
    pub(crate) walked_offsets: Vec<usize>,
}

impl<T: Real> ForwardContext<T> {
    /// How many entries of tile `t`'s list the backward walk visits.
    pub(crate) fn walked(&self, t: usize) -> usize {
        self.walked_offsets[t + 1] - self.walked_offsets[t]
    }

    /// Per Gaussian: whether it lies in the walked part of some tile's list (at or before the
    /// last Gaussian a pixel of that tile composited), i.e. whether the backward and Fisher
    /// walks visit one of its pairs. Every other Gaussian has a zero gradient and Fisher.
    pub fn walked_mask(&self) -> Vec<bool> {
        let mut out = vec![false; self.splats.len()];
        for t in 0..self.bins.tile_count() {
            for &i in &self.bins.tile(t)[..self.walked(t)] {
                out[i as usize] = true;
            }
        }
        out
    }
}

/// Output of [`render`]: images (row-major, `width × height`) and the context for backward.
#[derive(Debug, Clone)]
pub struct Render<T: Real> {
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// RGB after exposure.
    pub colour: Vec<[T; 3]>,
    /// Depth `Σ z α T`, metres (un-normalised).
    pub depth: Vec<T>,
    /// Accumulated opacity `1 − T_final`.
    pub opacity: Vec<T>,
    /// Saved state for [`crate::backward`] and [`crate::fisher`].
    pub context: ForwardContext<T>,
}

/// Inclusive intersection of a splat's pixel box with a tile rectangle `[x0, x1) × [y0, y1)`.
#[inline(always)]
pub(crate) fn clip_box<T: Real>(s: &Splat<T>, rect: &[usize; 4]) -> Option<[usize; 4]> {
    let bx0 = (s.bbox[0] as usize).max(rect[0]);
    let bx1 = (s.bbox[1] as usize).min(rect[1] - 1);
    let by0 = (s.bbox[2] as usize).max(rect[2]);
    let by1 = (s.bbox[3] as usize).min(rect[3] - 1);
    (bx0 <= bx1 && by0 <= by1).then_some([bx0, bx1, by0, by1])
}

/// A splat's depth along the pixel row at vertical offset `dy = mean_y − pixel_y`, at the
/// row's `dx = 0` (its centre depth under the centre model, whose slope is zero).
#[inline(always)]
pub(crate) fn row_depth<T: Real>(s: &Splat<T>, dy: T) -> T {
    s.depth - s.depth_slope[1] * dy
}

/// A splat's depth at horizontal offset `dx = mean_x − pixel_x` of the row of [`row_depth`].
#[inline(always)]
pub(crate) fn pixel_depth<T: Real>(s: &Splat<T>, row_depth: T, dx: T) -> T {
    row_depth - s.depth_slope[0] * dx
}

/// One tile's forward result, tile-local pixel order (`TILE` pixels per row), `TILE_PIXELS`
/// entries each (also used by the orthographic render, [`crate::ortho`]).
pub(crate) struct TileOut<'a, T: Real> {
    pub(crate) colour: &'a mut [[T; 3]],
    pub(crate) depth: &'a mut [T],
    pub(crate) transmittance: &'a mut [T],
    pub(crate) contributors: &'a mut [u32],
}

/// Composites tile `rect` front to back (dispatches to the best SIMD build the CPU runs; all
/// builds give identical results, see [`crate::walk`]).
pub(crate) fn raster_tile<T: Real>(
    splats: &[Splat<T>],
    list: &[u32],
    rect: [usize; 4],
    out: TileOut<'_, T>,
) {
    use crate::walk::SimdLevel;
    match crate::walk::simd_level() {
        // SAFETY: the CPU supports AVX-512 F and VL, AVX2 and FMA (checked by `simd_level`).
        #[cfg(target_arch = "x86_64")]
        SimdLevel::Avx512 => unsafe { raster_tile_avx512(splats, list, rect, out) },
        // SAFETY: the CPU supports AVX2 and FMA (checked by `simd_level`).
        #[cfg(target_arch = "x86_64")]
        SimdLevel::Avx2 => unsafe { raster_tile_avx2(splats, list, rect, out) },
        _ => raster_tile_impl(splats, list, rect, out),
    }
}

/// [`raster_tile_impl`] compiled with AVX-512 (F and VL), AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,avx2,fma")]
unsafe fn raster_tile_avx512<T: Real>(
    splats: &[Splat<T>],
    list: &[u32],
    rect: [usize; 4],
    out: TileOut<'_, T>,
) {
    raster_tile_impl(splats, list, rect, out);
}

/// [`raster_tile_impl`] compiled with AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn raster_tile_avx2<T: Real>(
    splats: &[Splat<T>],
    list: &[u32],
    rect: [usize; 4],
    out: TileOut<'_, T>,
) {
    raster_tile_impl(splats, list, rect, out);
}

#[inline(always)]
fn raster_tile_impl<T: Real>(
    splats: &[Splat<T>],
    list: &[u32],
    rect: [usize; 4],
    out: TileOut<'_, T>,
) {
    let mut colour = [[T::zero(); PADDED]; 3];
    let mut depth = [T::zero(); PADDED];
    let mut t = [T::one(); PADDED];
    let mut contributors = [0u32; PADDED];
    // 1 once the pixel has stopped (its next Gaussian would drop T below 1e-4).
    let mut done = [0u32; PADDED];
    let mut remaining = (rect[1] - rect[0]) * (rect[3] - rect[2]);
    let offsets = lane_offsets::<T, FORWARD_LANES>();
    let t_min = T::of(T_MIN);
    for (k, &id) in list.iter().enumerate() {
        let s = &splats[id as usize];
        let Some([bx0, bx1, by0, by1]) = clip_box(s, &rect) else {
            continue;
        };
        let k_next = k as u32 + 1;
        for py in by0..=by1 {
            let dy = s.mean[1] - T::of(py as f64);
            let row = SigmaRow::new(s, dy);
            let row_depth = row_depth(s, dy);
            let mut x = bx0;
            while x <= bx1 {
                let base = (py - rect[2]) * TILE + x - rect[0];
                let valid = (bx1 + 1 - x).min(FORWARD_LANES);
                let dx0 = s.mean[0] - T::of(x as f64);
                let done_l = lanes_n_mut::<_, FORWARD_LANES>(&mut done, base);
                // Lanes past the box (`l >= valid`) never composite this splat, whether their
                // pixels (the rest of the row, the next row, the padding) have stopped or not.
                if (0..FORWARD_LANES).fold(1, |all, l| all & (done_l[l] | (l >= valid) as u32)) == 1
                {
                    // Every pixel of the chunk inside the box has stopped.
                    x += FORWARD_LANES;
                    continue;
                }
                let t_l = lanes_n_mut::<_, FORWARD_LANES>(&mut t, base);
                let contrib_l = lanes_n_mut::<_, FORWARD_LANES>(&mut contributors, base);
                let mut weight = [T::zero(); FORWARD_LANES];
                let mut stopped = 0u32;
                for l in 0..FORWARD_LANES {
                    let (_, _, alpha, composited) = alpha_at(&row, s.opacity, dx0 - offsets[l]);
                    let on = composited & (l < valid) & (done_l[l] == 0);
                    let t_next = t_l[l] * (T::one() - alpha);
                    let stop = on & (t_next < t_min);
                    let add = on & !stop;
                    weight[l] = if add { alpha * t_l[l] } else { T::zero() };
                    t_l[l] = if add { t_next } else { t_l[l] };
                    contrib_l[l] = if add { k_next } else { contrib_l[l] };
                    done_l[l] |= stop as u32;
                    stopped = stopped.wrapping_add(stop as u32);
                }
                for ch in 0..3 {
                    let c = lanes_n_mut::<_, FORWARD_LANES>(&mut colour[ch], base);
                    for l in 0..FORWARD_LANES {
                        c[l] += s.colour[ch] * weight[l];
                    }
                }
                let d = lanes_n_mut::<_, FORWARD_LANES>(&mut depth, base);
                for l in 0..FORWARD_LANES {
                    d[l] += pixel_depth(s, row_depth, dx0 - offsets[l]) * weight[l];
                }
                remaining -= stopped as usize;
                x += FORWARD_LANES;
            }
        }
        if remaining == 0 {
            break;
        }
    }
    for p in 0..TILE_PIXELS {
        out.colour[p] = [colour[0][p], colour[1][p], colour[2][p]];
    }
    out.depth.copy_from_slice(&depth[..TILE_PIXELS]);
    out.transmittance.copy_from_slice(&t[..TILE_PIXELS]);
    out.contributors
        .copy_from_slice(&contributors[..TILE_PIXELS]);
}

/// The transmittance at which [`median_depth`] reads a pixel's depth.
pub const MEDIAN_TRANSMITTANCE: f64 = 0.5;

/// Per pixel of `render` (row-major), its median depth: the depth, under the render's depth
/// model, of the Gaussian whose compositing first brings the pixel's transmittance to
/// [`MEDIAN_TRANSMITTANCE`] or below, front to back with the forward pass's alphas; NaN where
/// the transmittance never falls that far. Where the composited depth `Σ z α T / (1 − T)`
/// blends surfaces at different depths (a silhouette; the faint tails of Gaussians next to the
/// camera in front of a far wall), the median is the depth of the one surface that covers most
/// of the pixel (the depth 2DGS and RaDe-GS fuse meshes from). Not in the SPEC; the evaluation's
/// surface reconstruction uses it to find such blended pixels.
pub fn median_depth<T: Real>(render: &Render<T>) -> Vec<T> {
    let ctx = &render.context;
    let (width, height) = (render.width, render.height);
    let half = T::of(MEDIAN_TRANSMITTANCE);
    let per_tile: Vec<Vec<T>> = (0..ctx.bins.tile_count())
        .into_par_iter()
        .map(|t| {
            let rect = ctx.bins.tile_rect(t, width, height);
            let list = ctx.bins.tile(t);
            let mut out = Vec::with_capacity((rect[1] - rect[0]) * (rect[3] - rect[2]));
            for py in rect[2]..rect[3] {
                for px in rect[0]..rect[1] {
                    let mut transmittance = T::one();
                    let mut median = T::of(f64::NAN);
                    for &id in list {
                        let s = &ctx.splats[id as usize];
                        if clip_box(s, &[px, px + 1, py, py + 1]).is_none() {
                            continue;
                        }
                        let dy = s.mean[1] - T::of(py as f64);
                        let dx = s.mean[0] - T::of(px as f64);
                        let row = SigmaRow::new(s, dy);
                        let (_, _, alpha, composited) = alpha_at(&row, s.opacity, dx);
                        if !composited {
                            continue;
                        }
                        transmittance *= T::one() - alpha;
                        if transmittance <= half {
                            median = pixel_depth(s, row_depth(s, dy), dx);
                            break;
                        }
                    }
                    out.push(median);
                }
            }
            out
        })
        .collect();
    let mut median = vec![T::of(f64::NAN); width * height];
    for (t, tile) in per_tile.iter().enumerate() {
        let rect = ctx.bins.tile_rect(t, width, height);
        let tw = rect[1] - rect[0];
        for (r, py) in (rect[2]..rect[3]).enumerate() {
            median[py * width + rect[0]..py * width + rect[1]]
                .copy_from_slice(&tile[r * tw..(r + 1) * tw]);
        }
    }
    median
}

/// Renders colour, depth and opacity of `gaussians` seen by `camera` (SPEC §3).
pub fn render<T: Real>(
    gaussians: &Gaussians<T>,
    camera: &Camera,
    options: &RenderOptions,
) -> Result<Render<T>, SplatError> {
    gaussians.validate()?;
    camera.validate()?;
    let cam = CameraT::<T>::new(camera);
    let (width, height) = (cam.width, cam.height);
    let projected: Vec<Option<Splat<T>>> = (0..gaussians.len())
        .into_par_iter()
        .with_min_len(1024)
        .map(|i| {
            if gaussians.flags[i] & options.exclude_flags != 0 {
                None
            } else {
                project_one(&cam, gaussians, i, options.depth == DepthModel::Plane)
            }
        })
        .collect();
    let visible: Vec<bool> = projected.iter().map(Option::is_some).collect();
    let splats: Vec<Splat<T>> = projected
        .into_iter()
        .map(Option::unwrap_or_default)
        .collect();
    let bins = bin(&splats, &visible, width, height);
    // Tile-major staging buffers, one `TILE_PIXELS` chunk per tile.
    let staged = bins.tile_count() * TILE_PIXELS;
    let mut tile_colour = vec![[T::zero(); 3]; staged];
    let mut tile_depth = vec![T::zero(); staged];
    let mut tile_t = vec![T::one(); staged];
    let mut tile_contrib = vec![0u32; staged];
    tile_colour
        .par_chunks_mut(TILE_PIXELS)
        .zip(tile_depth.par_chunks_mut(TILE_PIXELS))
        .zip(tile_t.par_chunks_mut(TILE_PIXELS))
        .zip(tile_contrib.par_chunks_mut(TILE_PIXELS))
        .with_max_len(1)
        .enumerate()
        .for_each(|(t, (((colour, depth), transmittance), contributors))| {
            let out = TileOut {
                colour,
                depth,
                transmittance,
                contributors,
            };
            raster_tile(&splats, bins.tile(t), bins.tile_rect(t, width, height), out);
        });
    let mut walked_offsets = Vec::with_capacity(bins.tile_count() + 1);
    walked_offsets.push(0);
    for (t, chunk) in tile_contrib.chunks(TILE_PIXELS).enumerate() {
        let walked = chunk.iter().copied().max().unwrap_or(0) as usize;
        walked_offsets.push(walked_offsets[t] + walked);
    }
    let n = width * height;
    let mut raw_colour = vec![[T::zero(); 3]; n];
    let mut depth = vec![T::zero(); n];
    let mut final_transmittance = vec![T::one(); n];
    let mut contributors = vec![0u32; n];
    for t in 0..bins.tile_count() {
        let rect = bins.tile_rect(t, width, height);
        let tw = rect[1] - rect[0];
        for py in rect[2]..rect[3] {
            let src = t * TILE_PIXELS + (py - rect[2]) * TILE;
            let src = src..src + tw;
            let dst = py * width + rect[0]..py * width + rect[1];
            raw_colour[dst.clone()].copy_from_slice(&tile_colour[src.clone()]);
            depth[dst.clone()].copy_from_slice(&tile_depth[src.clone()]);
            final_transmittance[dst.clone()].copy_from_slice(&tile_t[src.clone()]);
            contributors[dst].copy_from_slice(&tile_contrib[src]);
        }
    }
    let gain = T::of(options.exposure[0].exp());
    let offset = T::of(options.exposure[1]);
    let colour = raw_colour
        .iter()
        .map(|c| c.map(|v| gain * v + offset))
        .collect();
    let opacity = final_transmittance.iter().map(|&t| T::one() - t).collect();
    Ok(Render {
        width,
        height,
        colour,
        depth,
        opacity,
        context: ForwardContext {
            camera: *camera,
            cam,
            options: *options,
            splats,
            visible,
            bins,
            final_transmittance,
            contributors,
            raw_colour,
            walked_offsets,
        },
    })
}
