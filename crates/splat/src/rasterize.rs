//! The forward pass (SPEC §3): project, bin, then per tile composite front to back with
//! `α = min(0.99, o·exp(−σ))`, `σ = ½ dᵀ Σ'⁻¹ d`, `d = mean − pixel` (pixel centres at integer
//! coordinates, as `activemap_geometry::Intrinsics`), skipping `α < 1/255` and stopping before
//! the transmittance would fall below 1e-4. Outputs colour `e^a·Σ c α T + b`, depth `Σ z α T`
//! (un-normalised, as MonoGS) and opacity `1 − T_final`.

use crate::SplatError;
use crate::camera::{Camera, CameraT};
use crate::gaussians::Gaussians;
use crate::project::{ALPHA_MAX, ALPHA_MIN, SigmaRow, Splat, T_MIN, project_one};
use crate::real::Real;
use crate::tiles::{TileBins, bin};
use rayon::prelude::*;

/// Options of one render.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RenderOptions {
    /// Exposure `(a, b)`: output colour `e^a·colour + b` (SPEC §4), `(0, 0)` = identity.
    pub exposure: [f64; 2],
    /// Gaussians whose `flags & exclude_flags != 0` are left out of the render.
    pub exclude_flags: u8,
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

/// Per-tile forward result.
struct TileOut<T: Real> {
    colour: Vec<[T; 3]>,
    depth: Vec<T>,
    transmittance: Vec<T>,
    contributors: Vec<u32>,
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

/// Composites one tile front to back.
fn raster_tile<T: Real>(splats: &[Splat<T>], list: &[u32], rect: [usize; 4]) -> TileOut<T> {
    let tw = rect[1] - rect[0];
    let n = tw * (rect[3] - rect[2]);
    let mut out = TileOut {
        colour: vec![[T::zero(); 3]; n],
        depth: vec![T::zero(); n],
        transmittance: vec![T::one(); n],
        contributors: vec![0; n],
    };
    let mut done = vec![false; n];
    let mut remaining = n;
    let (alpha_min, alpha_max, t_min) = (T::of(ALPHA_MIN), T::of(ALPHA_MAX), T::of(T_MIN));
    for (k, &id) in list.iter().enumerate() {
        let s = &splats[id as usize];
        let Some([bx0, bx1, by0, by1]) = clip_box(s, &rect) else {
            continue;
        };
        for py in by0..=by1 {
            let dy = s.mean[1] - T::of(py as f64);
            let row_sigma = SigmaRow::new(s, dy);
            let start = (py - rect[2]) * tw + bx0 - rect[0];
            let len = bx1 - bx0 + 1;
            let mut pxf = T::of(bx0 as f64);
            for (p, is_done) in (start..start + len).zip(&mut done[start..start + len]) {
                let dx = s.mean[0] - pxf;
                pxf += T::one();
                if *is_done {
                    continue;
                }
                let sigma = row_sigma.sigma(dx);
                if sigma < T::zero() {
                    continue;
                }
                let alpha = (s.opacity * (-sigma).exp()).min(alpha_max);
                if alpha < alpha_min {
                    continue;
                }
                let t = out.transmittance[p];
                let t_next = t * (T::one() - alpha);
                if t_next < t_min {
                    *is_done = true;
                    remaining -= 1;
                    continue;
                }
                let weight = alpha * t;
                for ch in 0..3 {
                    out.colour[p][ch] += s.colour[ch] * weight;
                }
                out.depth[p] += s.depth * weight;
                out.transmittance[p] = t_next;
                out.contributors[p] = k as u32 + 1;
            }
        }
        if remaining == 0 {
            break;
        }
    }
    out
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
                project_one(&cam, gaussians, i)
            }
        })
        .collect();
    let visible: Vec<bool> = projected.iter().map(Option::is_some).collect();
    let splats: Vec<Splat<T>> = projected
        .into_iter()
        .map(Option::unwrap_or_default)
        .collect();
    let bins = bin(&splats, &visible, width, height);
    let tiles: Vec<TileOut<T>> = (0..bins.tile_count())
        .into_par_iter()
        .with_max_len(1)
        .map(|t| raster_tile(&splats, bins.tile(t), bins.tile_rect(t, width, height)))
        .collect();
    let n = width * height;
    let mut raw_colour = vec![[T::zero(); 3]; n];
    let mut depth = vec![T::zero(); n];
    let mut final_transmittance = vec![T::one(); n];
    let mut contributors = vec![0u32; n];
    for (t, tile) in tiles.iter().enumerate() {
        let rect = bins.tile_rect(t, width, height);
        let tw = rect[1] - rect[0];
        for py in rect[2]..rect[3] {
            let src = (py - rect[2]) * tw..(py - rect[2] + 1) * tw;
            let dst = py * width + rect[0]..py * width + rect[1];
            raw_colour[dst.clone()].copy_from_slice(&tile.colour[src.clone()]);
            depth[dst.clone()].copy_from_slice(&tile.depth[src.clone()]);
            final_transmittance[dst.clone()].copy_from_slice(&tile.transmittance[src.clone()]);
            contributors[dst].copy_from_slice(&tile.contributors[src]);
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
        },
    })
}
