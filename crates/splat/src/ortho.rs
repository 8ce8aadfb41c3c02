//! Orthographic top-down forward render of the map: the floor plan for the bird's-eye view of
//! the LLM planner (SPEC §7).
//!
//! The camera looks down world −z (world z up, SPEC §2); image right is world +x, image up is
//! world +y, at a constant scale of [`OrthoWindow::metres_per_pixel`]. The paper's release
//! renders a perspective view from 10 m above the map centre instead; the orthographic view
//! keeps the exact floor-plan scale everywhere (walls do not lean outwards, distances in pixels
//! are distances in metres).
//!
//! Per Gaussian, the 2D footprint is the xy marginal of its 3D covariance `Σ = R S² Rᵀ` (exact
//! for an orthographic projection along z), in pixel units, plus the 3DGS low-pass
//! [`LOW_PASS`]·I. Compositing is the one of the perspective renderer (SPEC §3, the same tile
//! loop, [`crate::rasterize`]): `α = min(0.99, o·exp(−½ dᵀΣ⁻¹d))`, skipped below 1/255, front
//! to back in order of decreasing mean z (the highest first: the top of a wall hides the floor
//! under it; ties by index), a pixel stops before its transmittance would drop below 1e-4, and
//! the background is white. Colours are `0.5 + C0·sh_dc` clamped to [0, 1] for display.
//! Pixel centres sit at integer coordinates, as in the perspective renderer.
//!
//! A [`Selection`] keeps the Gaussians that are drawn: below a height (the ceiling cut), no
//! larger than a size limit, and without excluded flags.
//! [`mean_bounds`] and [`OrthoWindow::covering`] compute a window that crops the image to the
//! mapped area. The result does not depend on the rayon thread count.

use crate::SplatError;
use crate::gaussians::{FLAG_UNKNOWN_SPACE, Gaussians, SH_C0, sigmoid};
use crate::project::{ALPHA_MIN, LOW_PASS, Splat, rotation_matrix};
use crate::rasterize::{TileOut, raster_tile};
use crate::tiles::{TILE, bin};
use crate::walk::TILE_PIXELS;
use rayon::prelude::*;

/// Default long side of a fitted window, pixels (the paper's BEV size).
pub const DEFAULT_LONG_SIDE_PX: usize = 800;

/// Default fraction of the selected means ignored on each side of each axis by
/// [`mean_bounds`]: 0.1 %, so that a few stray Gaussians far outside the map do not shrink it
/// in the image.
pub const DEFAULT_TRIM_FRACTION: f64 = 0.001;

/// The world rectangle an orthographic image covers.
///
/// Pixel `(u, v)` (column, row) covers the world square of side `metres_per_pixel` centred at
/// `x = min[0] + (u + ½)·m`, `y = min[1] + (height − v − ½)·m`: row 0 is the top (largest y).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrthoWindow {
    /// World (x, y) of the bottom-left image corner (the pixel edge, not a centre), metres.
    pub min: [f64; 2],
    /// Side of one pixel, metres.
    pub metres_per_pixel: f64,
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
}

impl OrthoWindow {
    /// The window of the given size whose centre is the centre of the box `[min, max]` and
    /// whose long side is `long_side_px` pixels spanning the box's long side; the short side
    /// gets the rounded number of pixels its extent needs (at least 1). The box must be finite
    /// with `max ≥ min` and a positive long side.
    pub fn covering(min: [f64; 2], max: [f64; 2], long_side_px: usize) -> Result<Self, SplatError> {
        let bad = |why: String| Err(SplatError::Ortho(why));
        if !min.iter().chain(&max).all(|v| v.is_finite()) {
            return bad(format!("window box {min:?}..{max:?} is not finite"));
        }
        if long_side_px == 0 {
            return bad("window long side of 0 pixels".into());
        }
        let extent = [max[0] - min[0], max[1] - min[1]];
        let long = extent[0].max(extent[1]);
        if extent[0] < 0.0 || extent[1] < 0.0 || long <= 0.0 {
            return bad(format!("window box {min:?}..{max:?} is empty"));
        }
        let metres_per_pixel = long / long_side_px as f64;
        let size = extent.map(|e| ((e / metres_per_pixel).round() as usize).clamp(1, long_side_px));
        let centre = [0.5 * (min[0] + max[0]), 0.5 * (min[1] + max[1])];
        Ok(Self {
            min: [
                centre[0] - 0.5 * size[0] as f64 * metres_per_pixel,
                centre[1] - 0.5 * size[1] as f64 * metres_per_pixel,
            ],
            metres_per_pixel,
            width: size[0],
            height: size[1],
        })
    }

    /// World (x, y) of the top-right image corner, metres.
    pub fn max(&self) -> [f64; 2] {
        [
            self.min[0] + self.width as f64 * self.metres_per_pixel,
            self.min[1] + self.height as f64 * self.metres_per_pixel,
        ]
    }

    /// Continuous pixel coordinates `[column, row]` of a world point (pixel centres at
    /// integers; the image spans `[−½, width − ½] × [−½, height − ½]`).
    pub fn pixel_of(&self, world: [f64; 2]) -> [f64; 2] {
        let m = self.metres_per_pixel;
        [
            (world[0] - self.min[0]) / m - 0.5,
            (self.max()[1] - world[1]) / m - 0.5,
        ]
    }

    /// World (x, y) of continuous pixel coordinates, the inverse of [`Self::pixel_of`].
    pub fn world_of(&self, pixel: [f64; 2]) -> [f64; 2] {
        let m = self.metres_per_pixel;
        [
            self.min[0] + (pixel[0] + 0.5) * m,
            self.max()[1] - (pixel[1] + 0.5) * m,
        ]
    }

    /// Checks that the window is finite, non-empty and has a positive scale.
    pub fn validate(&self) -> Result<(), SplatError> {
        let m = self.metres_per_pixel;
        if !(self.min.iter().all(|v| v.is_finite()) && m.is_finite() && m > 0.0) {
            return Err(SplatError::Ortho(format!(
                "window origin {:?} or scale {m} m/px is not finite and positive",
                self.min
            )));
        }
        if self.width == 0 || self.height == 0 {
            return Err(SplatError::Ortho(format!(
                "window size {}x{} is empty",
                self.width, self.height
            )));
        }
        Ok(())
    }
}

/// Which Gaussians an orthographic render draws.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Selection {
    /// The ceiling cut: only Gaussians whose mean z is strictly below this (world metres).
    pub max_height_m: f64,
    /// Only Gaussians whose largest scale `exp(max log-scale)` is at most this (metres).
    pub max_scale_m: f64,
    /// Gaussians whose `flags & exclude_flags != 0` are left out.
    pub exclude_flags: u8,
}

impl Default for Selection {
    /// Every Gaussian except those flagged [`FLAG_UNKNOWN_SPACE`].
    fn default() -> Self {
        Self {
            max_height_m: f64::INFINITY,
            max_scale_m: f64::INFINITY,
            exclude_flags: FLAG_UNKNOWN_SPACE,
        }
    }
}

impl Selection {
    /// Whether Gaussian `i` is drawn (its mean must also be finite).
    pub fn selects(&self, g: &Gaussians<f32>, i: usize) -> bool {
        let m = g.means[i];
        let ls = g.log_scales[i];
        let max_scale = (ls[0].max(ls[1]).max(ls[2]) as f64).exp();
        g.flags[i] & self.exclude_flags == 0
            && m.iter().all(|v| v.is_finite())
            && (m[2] as f64) < self.max_height_m
            && max_scale <= self.max_scale_m
    }
}

/// Options of [`render_ortho`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrthoOptions {
    /// The world rectangle and image size.
    pub window: OrthoWindow,
    /// The Gaussians drawn.
    pub selection: Selection,
}

/// An orthographic render: 8-bit RGB, row-major, row 0 at the top (largest world y).
#[derive(Debug, Clone, PartialEq)]
pub struct OrthoImage {
    /// `width × height × 3` bytes.
    pub rgb: Vec<u8>,
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// The window rendered (the world ↔ pixel mapping).
    pub window: OrthoWindow,
}

impl OrthoImage {
    /// The RGB bytes of pixel `(x, y)` (column, row).
    pub fn pixel(&self, x: usize, y: usize) -> [u8; 3] {
        let k = 3 * (y * self.width + x);
        [self.rgb[k], self.rgb[k + 1], self.rgb[k + 2]]
    }
}

/// An axis-aligned box in the world xy plane, metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct XyBox {
    /// Smallest x and y.
    pub min: [f64; 2],
    /// Largest x and y.
    pub max: [f64; 2],
}

/// The xy bounding box of the means of the selected Gaussians, ignoring the
/// `trim_fraction` (e.g. [`DEFAULT_TRIM_FRACTION`]) most extreme means on each side of each
/// axis (rounded down: with fewer than `1 / trim_fraction` Gaussians it is the plain bounding
/// box). `None` when nothing is selected. The footprints reach beyond the means by up to three
/// times [`Selection::max_scale_m`]; callers add a margin.
pub fn mean_bounds(
    g: &Gaussians<f32>,
    selection: &Selection,
    trim_fraction: f64,
) -> Result<Option<XyBox>, SplatError> {
    g.validate()?;
    if !(0.0..0.5).contains(&trim_fraction) {
        return Err(SplatError::Ortho(format!(
            "trim fraction {trim_fraction} is outside [0, 0.5)"
        )));
    }
    let (mut xs, mut ys): (Vec<f32>, Vec<f32>) = (0..g.len())
        .filter(|&i| selection.selects(g, i))
        .map(|i| (g.means[i][0], g.means[i][1]))
        .unzip();
    let n = xs.len();
    if n == 0 {
        return Ok(None);
    }
    let k = ((n as f64 * trim_fraction).floor() as usize).min((n - 1) / 2);
    let range = |v: &mut Vec<f32>| {
        let lo = *v.select_nth_unstable_by(k, f32::total_cmp).1 as f64;
        let hi = *v.select_nth_unstable_by(n - 1 - k, f32::total_cmp).1 as f64;
        (lo, hi)
    };
    let (x0, x1) = range(&mut xs);
    let (y0, y1) = range(&mut ys);
    Ok(Some(XyBox {
        min: [x0, y0],
        max: [x1, y1],
    }))
}

/// The splat of Gaussian `i` in the window's pixels, `None` when it cannot touch a pixel.
/// Its `depth` is `−z`, so that the tile sort (by increasing depth) puts the highest first.
fn ortho_splat(g: &Gaussians<f32>, i: usize, w: &OrthoWindow) -> Option<Splat<f32>> {
    let opacity = sigmoid(g.opacity_logits[i] as f64);
    if !opacity.is_finite() || opacity < ALPHA_MIN {
        return None;
    }
    let q = g.rotations[i].map(|v| v as f64);
    let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !(norm.is_finite() && norm > 0.0) {
        return None;
    }
    let r = rotation_matrix(&q.map(|v| v / norm));
    let s = g.log_scales[i].map(|v| (v as f64).exp());
    // Rows x and y of M = R·S; the xy marginal of Σ = M Mᵀ is their Gram matrix.
    let (mx, my) = (
        [0, 1, 2].map(|k| r[(0, k)] * s[k]),
        [0, 1, 2].map(|k| r[(1, k)] * s[k]),
    );
    let dot = |a: &[f64; 3], b: &[f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let inv_m2 = 1.0 / (w.metres_per_pixel * w.metres_per_pixel);
    // Pixel rows run along −y, so the off-diagonal term changes sign.
    let a = dot(&mx, &mx) * inv_m2 + LOW_PASS;
    let b = -dot(&mx, &my) * inv_m2;
    let c = dot(&my, &my) * inv_m2 + LOW_PASS;
    let det = a * c - b * b;
    if !(det.is_finite() && det > 0.0) {
        return None;
    }
    let m = g.means[i];
    let mean = w.pixel_of([m[0] as f64, m[1] as f64]);
    let extent = 3f64.min((2.0 * (255.0 * opacity).ln()).max(0.0).sqrt());
    let half = [a.sqrt() * extent, c.sqrt() * extent];
    let size = [w.width, w.height];
    let mut bbox = [0u32; 4];
    for k in 0..2 {
        let lo = (mean[k] - half[k]).ceil().max(0.0);
        let hi = (mean[k] + half[k]).floor().min(size[k] as f64 - 1.0);
        if !lo.is_finite() || !hi.is_finite() || lo > hi {
            return None;
        }
        bbox[2 * k] = lo as u32;
        bbox[2 * k + 1] = hi as u32;
    }
    Some(Splat {
        mean: mean.map(|v| v as f32),
        conic: [(c / det) as f32, (-b / det) as f32, (a / det) as f32],
        opacity: opacity as f32,
        depth: -m[2],
        depth_slope: [0.0; 2],
        colour: g.sh_dc[i].map(|v| (0.5 + SH_C0 as f32 * v).clamp(0.0, 1.0)),
        bbox,
    })
}

/// Renders the selected Gaussians top-down into the window (see the module doc).
pub fn render_ortho(g: &Gaussians<f32>, options: &OrthoOptions) -> Result<OrthoImage, SplatError> {
    g.validate()?;
    let window = options.window;
    window.validate()?;
    let (width, height) = (window.width, window.height);
    let projected: Vec<Option<Splat<f32>>> = (0..g.len())
        .into_par_iter()
        .with_min_len(1024)
        .map(|i| {
            if options.selection.selects(g, i) {
                ortho_splat(g, i, &window)
            } else {
                None
            }
        })
        .collect();
    let visible: Vec<bool> = projected.iter().map(Option::is_some).collect();
    let splats: Vec<Splat<f32>> = projected
        .into_iter()
        .map(Option::unwrap_or_default)
        .collect();
    let bins = bin(&splats, &visible, width, height);
    let mut rgb = vec![0u8; width * height * 3];
    // One band of tile rows per task; per-tile state on the stack.
    rgb.par_chunks_mut(TILE * width * 3)
        .enumerate()
        .for_each(|(ty, band)| {
            let mut colour = [[0f32; 3]; TILE_PIXELS];
            let mut depth = [0f32; TILE_PIXELS];
            let mut transmittance = [0f32; TILE_PIXELS];
            let mut contributors = [0u32; TILE_PIXELS];
            for tx in 0..bins.tiles_x {
                let t = ty * bins.tiles_x + tx;
                let rect = bins.tile_rect(t, width, height);
                let out = TileOut {
                    colour: &mut colour,
                    depth: &mut depth,
                    transmittance: &mut transmittance,
                    contributors: &mut contributors,
                };
                raster_tile(&splats, bins.tile(t), rect, out);
                for py in rect[2]..rect[3] {
                    for px in rect[0]..rect[1] {
                        let local = (py - rect[2]) * TILE + px - rect[0];
                        let dst = 3 * ((py - rect[2]) * width + px);
                        let white = transmittance[local];
                        for ch in 0..3 {
                            let v = (colour[local][ch] + white).clamp(0.0, 1.0);
                            band[dst + ch] = (v * 255.0 + 0.5) as u8;
                        }
                    }
                }
            }
        });
    Ok(OrthoImage {
        rgb,
        width,
        height,
        window,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn window(min: [f64; 2], m: f64, width: usize, height: usize) -> OrthoWindow {
        OrthoWindow {
            min,
            metres_per_pixel: m,
            width,
            height,
        }
    }

    fn options(w: OrthoWindow) -> OrthoOptions {
        OrthoOptions {
            window: w,
            selection: Selection::default(),
        }
    }

    const IDENTITY: [f64; 4] = [1.0, 0.0, 0.0, 0.0];

    /// Pixel centres map to the world points the window doc gives, and back.
    #[test]
    fn ortho_window_maps_world_points_to_the_expected_pixels() {
        let w = window([-2.0, 1.0], 0.05, 80, 40);
        let near =
            |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).abs() < 1e-9 && (a[1] - b[1]).abs() < 1e-9;
        assert!(near(w.max(), [2.0, 3.0]));
        // Pixel (0, 0) is the top-left: centre half a pixel in from (min x, max y).
        assert!(near(w.pixel_of([-2.0 + 0.025, 3.0 - 0.025]), [0.0, 0.0]));
        assert!(near(w.pixel_of([0.0, 2.0]), [39.5, 19.5]));
        let q = w.pixel_of([1.0 + 0.025, 1.0 + 0.025]);
        assert!(near(q, [60.0, 39.0]));
        assert!(near(w.world_of(q), [1.025, 1.025]));
        assert!(near(w.pixel_of(w.world_of([3.25, -7.0])), [3.25, -7.0]));

        // `covering`: the long side gets the requested pixels, the box is centred.
        let c = OrthoWindow::covering([0.0, -1.0], [8.0, 3.0], 800).unwrap();
        assert_eq!((c.width, c.height), (800, 400));
        assert!((c.metres_per_pixel - 0.01).abs() < 1e-15);
        assert!(near(c.pixel_of([0.0, 3.0]), [-0.5, -0.5]));
        assert!(near(c.pixel_of([8.0, -1.0]), [799.5, 399.5]));
        let tall = OrthoWindow::covering([0.0, 0.0], [1.0, 3.0], 300).unwrap();
        assert_eq!((tall.width, tall.height), (100, 300));
        assert!(OrthoWindow::covering([0.0, 0.0], [0.0, 0.0], 800).is_err());
        assert!(OrthoWindow::covering([0.0, 0.0], [f64::NAN, 1.0], 800).is_err());
        assert!(window([0.0, 0.0], 0.0, 10, 10).validate().is_err());
        assert!(window([0.0, 0.0], 0.1, 0, 10).validate().is_err());
    }

    /// A single isotropic Gaussian lands at its pixel with its colour and the analytic falloff
    /// `c·α + (1 − α)` over white, `α = o·exp(−½ r²/(s²/m² + 0.3))`.
    #[test]
    fn ortho_single_gaussian_matches_the_analytic_alpha() {
        let w = window([0.0, 0.0], 0.01, 64, 48);
        // World point of pixel (20, 30).
        let centre = w.world_of([20.0, 30.0]);
        let (rgb, o, s) = ([0.2, 0.6, 0.9], 0.8, 0.03);
        let mut g = Gaussians::<f32>::new();
        g.push([centre[0], centre[1], 0.5], rgb, IDENTITY, o, [s; 3]);
        let img = render_ortho(&g, &options(w)).unwrap();
        assert_eq!(
            (img.width, img.height, img.rgb.len()),
            (64, 48, 64 * 48 * 3)
        );
        let var = (s / 0.01) * (s / 0.01) + 0.3;
        for (dx, dy) in [
            (0i32, 0i32),
            (1, 0),
            (0, -2),
            (3, 4),
            (-5, 1),
            (7, 0),
            (0, 9),
        ] {
            let r2 = (dx * dx + dy * dy) as f64;
            let alpha = o * (-0.5 * r2 / var).exp();
            let alpha = if alpha < 1.0 / 255.0 { 0.0 } else { alpha };
            let px = img.pixel((20 + dx) as usize, (30 + dy) as usize);
            for ch in 0..3 {
                let want = 255.0 * (rgb[ch] * alpha + 1.0 - alpha);
                assert!(
                    (px[ch] as f64 - want).abs() <= 1.0,
                    "offset ({dx}, {dy}) channel {ch}: {} vs {want:.2}",
                    px[ch]
                );
            }
        }
        // Far away: white.
        assert_eq!(img.pixel(60, 2), [255; 3]);
        assert_eq!(img.pixel(2, 47), [255; 3]);
    }

    /// An elongated Gaussian rotated 90° about z spreads along world y = image rows.
    #[test]
    fn ortho_footprint_follows_the_rotation() {
        let w = window([-0.5, -0.5], 0.01, 100, 100);
        let mut g = Gaussians::<f32>::new();
        let half = std::f64::consts::FRAC_1_SQRT_2;
        g.push(
            [0.0, 0.0, 0.0],
            [0.0; 3],
            [half, 0.0, 0.0, half],
            0.9,
            [0.1, 0.01, 0.01],
        );
        let img = render_ortho(&g, &options(w)).unwrap();
        let c = w.pixel_of([0.0, 0.0]).map(|v| v.round() as usize);
        // 15 px (1.5σ) along the rows: dark; 15 px along the columns: white.
        assert!(img.pixel(c[0], c[1] + 15)[0] < 200);
        assert!(img.pixel(c[0], c[1] - 15)[0] < 200);
        assert_eq!(img.pixel(c[0] + 15, c[1]), [255; 3]);
    }

    /// The higher Gaussian is composited first: where both are opaque its colour wins, whatever
    /// the storage order.
    #[test]
    fn ortho_higher_gaussian_occludes_lower_one() {
        let w = window([-0.5, -0.5], 0.01, 100, 100);
        for order in [[0.0, 2.0], [2.0, 0.0]] {
            let mut g = Gaussians::<f32>::new();
            for z in order {
                let rgb = if z > 1.0 {
                    [1.0, 0.0, 0.0]
                } else {
                    [0.0, 0.0, 1.0]
                };
                g.push([0.0, 0.0, z], rgb, IDENTITY, 0.99, [0.1; 3]);
            }
            let img = render_ortho(&g, &options(w)).unwrap();
            let p = img.pixel(50, 50);
            assert!(p[0] >= 250 && p[2] <= 5, "order {order:?}: {p:?}");
        }
    }

    /// The ceiling cut, the size limit and the flag mask each drop a Gaussian.
    #[test]
    fn ortho_selection_drops_ceiling_large_and_flagged_gaussians() {
        let w = window([0.0, 0.0], 0.01, 200, 50);
        let mut g = Gaussians::<f32>::new();
        let at = |u: f64| w.world_of([u, 25.0]);
        let spots = [
            (20.0, 0.5, 0.02),
            (70.0, 2.6, 0.02),
            (120.0, 0.5, 0.15),
            (170.0, 0.5, 0.02),
        ];
        for (u, z, s) in spots {
            let p = at(u);
            g.push(
                [p[0], p[1], z],
                [0.0; 3],
                IDENTITY,
                0.95,
                [s, s * 0.5, s * 0.2],
            );
        }
        g.flags[3] = FLAG_UNKNOWN_SPACE;
        let all = Selection {
            exclude_flags: 0,
            ..Selection::default()
        };
        let cut = Selection {
            max_height_m: 1.0,
            max_scale_m: 0.1,
            exclude_flags: FLAG_UNKNOWN_SPACE,
        };
        let drawn = |selection: Selection| -> Vec<bool> {
            let img = render_ortho(
                &g,
                &OrthoOptions {
                    window: w,
                    selection,
                },
            )
            .unwrap();
            spots
                .iter()
                .map(|s| img.pixel(s.0 as usize, 25) != [255; 3])
                .collect()
        };
        assert_eq!(drawn(all), vec![true; 4]);
        assert_eq!(drawn(cut), vec![true, false, false, false]);
        assert_eq!(drawn(Selection::default()), vec![true, true, true, false]);
        let cut_bounds = mean_bounds(&g, &cut, 0.0).unwrap().unwrap();
        assert_eq!(cut_bounds.min, cut_bounds.max);
        let none = Selection {
            max_height_m: 0.0,
            ..cut
        };
        assert_eq!(mean_bounds(&g, &none, 0.0).unwrap(), None);
    }

    /// The trimmed bounds ignore a stray Gaussian; the untrimmed bounds are the plain box.
    #[test]
    fn ortho_mean_bounds_trims_extreme_means() {
        let mut g = Gaussians::<f32>::new();
        for i in 0..2000 {
            let (x, y) = ((i % 50) as f64 * 0.1, (i / 50) as f64 * 0.1);
            g.push([x, y, 0.0], [0.5; 3], IDENTITY, 0.5, [0.02; 3]);
        }
        g.push([100.0, -50.0, 0.0], [0.5; 3], IDENTITY, 0.5, [0.02; 3]);
        let s = Selection::default();
        let plain = mean_bounds(&g, &s, 0.0).unwrap().unwrap();
        assert_eq!(
            (plain.min, plain.max),
            ([0.0, -50.0], [100.0, 3.9f32 as f64])
        );
        let trimmed = mean_bounds(&g, &s, DEFAULT_TRIM_FRACTION).unwrap().unwrap();
        assert_eq!(trimmed.min, [0.0, 0.0]);
        assert_eq!(trimmed.max, [4.9f32 as f64, 3.9f32 as f64]);
        assert!(mean_bounds(&g, &s, 0.5).is_err());
    }

    /// A few thousand random Gaussians render to the same bytes on 1 thread, on 4 and on the
    /// default pool.
    #[test]
    fn ortho_render_does_not_depend_on_the_thread_count() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut g = Gaussians::<f32>::new();
        for _ in 0..5000 {
            let mean = [
                rng.random_range(0.0..6.0),
                rng.random_range(0.0..4.0),
                rng.random_range(0.0..2.5),
            ];
            let q = [0; 4].map(|_| rng.random_range(-1.0..1.0));
            let scale = [0; 3].map(|_| rng.random_range(0.005..0.08));
            let rgb = [0; 3].map(|_| rng.random_range(0.0..1.0));
            g.push(mean, rgb, q, rng.random_range(0.1..1.0), scale);
        }
        let b = mean_bounds(&g, &Selection::default(), DEFAULT_TRIM_FRACTION)
            .unwrap()
            .unwrap();
        let w = OrthoWindow::covering(b.min, b.max, 300).unwrap();
        let opts = OrthoOptions {
            window: w,
            selection: Selection {
                max_height_m: 2.0,
                ..Selection::default()
            },
        };
        let pool = |n| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .unwrap()
        };
        let one = pool(1).install(|| render_ortho(&g, &opts)).unwrap();
        let four = pool(4).install(|| render_ortho(&g, &opts)).unwrap();
        let default = render_ortho(&g, &opts).unwrap();
        assert_eq!(one, four);
        assert_eq!(one, default);
        assert!(one.rgb.iter().any(|&v| v < 128));
    }

    #[test]
    fn ortho_rejects_mismatched_arrays() {
        let mut g = Gaussians::<f32>::new();
        g.push([0.0; 3], [0.5; 3], IDENTITY, 0.5, [0.02; 3]);
        g.flags.clear();
        let w = window([0.0, 0.0], 0.01, 10, 10);
        assert!(render_ortho(&g, &options(w)).is_err());
    }
}
