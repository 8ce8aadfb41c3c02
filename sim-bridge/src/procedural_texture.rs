//! Seeded, tileable procedural textures for generated houses (wood floors, tiles, carpet,
//! plaster, wallpaper, fabric). Only integer hashing and f32 `+ − × ÷` are used, so the same
//! seed gives the same texels on every platform. The textures carry structure at several
//! scales (seams, grain, blotches) so that photometric tracking has gradients to work with.

use crate::scene::{Texture, Wrap};

/// The kinds of surfaces the generator paints.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TextureKind {
    /// Floor planks with grain and dark seams.
    WoodPlanks,
    /// Square floor tiles with grout lines.
    Tiles,
    /// Speckled carpet.
    Carpet,
    /// Blotchy plaster wall.
    Plaster,
    /// Striped wallpaper with a dot motif.
    Wallpaper,
    /// Woven fabric (upholstery).
    Fabric,
    /// Smooth painted ceiling with faint noise.
    Ceiling,
}

/// A 32-bit integer hash (lowbias32 by C. Wellons), platform independent.
fn hash(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^= x >> 16;
    x
}

fn hash3(a: u32, b: u32, seed: u32) -> u32 {
    hash(a ^ hash(b ^ hash(seed)))
}

/// Uniform value in [0, 1) from a hash.
fn unit(h: u32) -> f32 {
    (h >> 8) as f32 / 16_777_216.0
}

/// Tileable 2D value noise with period `period` lattice cells, in [0, 1).
fn value_noise(x: f32, y: f32, period: u32, seed: u32) -> f32 {
    let (xf, yf) = (x.floor(), y.floor());
    let (tx, ty) = (x - xf, y - yf);
    let (sx, sy) = (tx * tx * (3.0 - 2.0 * tx), ty * ty * (3.0 - 2.0 * ty));
    let p = period as i64;
    let (xi, yi) = (
        (xf as i64).rem_euclid(p) as u32,
        (yf as i64).rem_euclid(p) as u32,
    );
    let (xj, yj) = ((xi + 1) % period, (yi + 1) % period);
    let v = |a, b| unit(hash3(a, b, seed));
    let top = v(xi, yi) + (v(xj, yi) - v(xi, yi)) * sx;
    let bottom = v(xi, yj) + (v(xj, yj) - v(xi, yj)) * sx;
    top + (bottom - top) * sy
}

/// Fractal sum of `octaves` value-noise layers, base period `period` cells over the image.
fn fbm(u: f32, v: f32, period: u32, octaves: u32, seed: u32) -> f32 {
    let (mut sum, mut amp, mut norm, mut p) = (0.0, 1.0, 0.0, period);
    for o in 0..octaves {
        sum += amp * value_noise(u * p as f32, v * p as f32, p, seed.wrapping_add(o * 7919));
        norm += amp;
        amp *= 0.5;
        p *= 2;
    }
    sum / norm
}

fn mix(a: [f32; 3], b: [f32; 3], t: f32) -> [f32; 3] {
    std::array::from_fn(|k| a[k] + (b[k] - a[k]) * t)
}

fn scale(a: [f32; 3], s: f32) -> [f32; 3] {
    a.map(|c| c * s)
}

/// A random colour from a palette of plausible interior colours, jittered.
pub fn palette_colour(kind: TextureKind, h: u32) -> [f32; 3] {
    let palettes: &[[f32; 3]] = match kind {
        TextureKind::WoodPlanks => &[
            [0.55, 0.38, 0.22],
            [0.70, 0.52, 0.33],
            [0.42, 0.28, 0.17],
            [0.78, 0.64, 0.45],
        ],
        TextureKind::Tiles => &[
            [0.85, 0.84, 0.80],
            [0.55, 0.58, 0.62],
            [0.72, 0.62, 0.50],
            [0.30, 0.32, 0.35],
        ],
        TextureKind::Carpet => &[
            [0.45, 0.20, 0.18],
            [0.25, 0.32, 0.45],
            [0.50, 0.48, 0.42],
            [0.30, 0.40, 0.28],
        ],
        TextureKind::Plaster => &[
            [0.90, 0.88, 0.82],
            [0.80, 0.86, 0.88],
            [0.92, 0.84, 0.72],
            [0.78, 0.84, 0.74],
        ],
        TextureKind::Wallpaper => &[
            [0.82, 0.76, 0.62],
            [0.62, 0.72, 0.80],
            [0.80, 0.66, 0.66],
            [0.70, 0.78, 0.62],
        ],
        TextureKind::Fabric => &[
            [0.35, 0.38, 0.55],
            [0.60, 0.30, 0.25],
            [0.45, 0.50, 0.40],
            [0.25, 0.25, 0.28],
        ],
        TextureKind::Ceiling => &[[0.95, 0.95, 0.93], [0.92, 0.92, 0.95]],
    };
    let base = palettes[(h % palettes.len() as u32) as usize];
    let j = |k: u32| 0.9 + 0.2 * unit(hash(h ^ k));
    [base[0] * j(1), base[1] * j(2), base[2] * j(3)].map(|c| c.min(1.0))
}

/// Generates a `size × size` tileable texture of `kind` (size a power of two ≥ 32).
pub fn generate(kind: TextureKind, size: u32, seed: u32) -> Texture {
    let base = palette_colour(kind, hash(seed ^ 0x5bd1_e995));
    let accent = palette_colour(kind, hash(seed ^ 0x1b87_3593));
    let mut texels = Vec::with_capacity((size * size) as usize);
    let n = size as f32;
    for y in 0..size {
        for x in 0..size {
            let (u, v) = (x as f32 / n, y as f32 / n);
            let c = match kind {
                TextureKind::WoodPlanks => {
                    // 8 planks across; each row offset by a random length.
                    let row = (v * 8.0).floor() as u32;
                    let along = u + unit(hash3(row, 1, seed));
                    let along = along - along.floor();
                    let board = (along * 2.0).floor() as u32;
                    let tint = 0.8 + 0.35 * unit(hash3(row, board + 10, seed));
                    let grain = fbm(u * 0.25, v * 2.0, 8, 3, seed ^ row);
                    let streak = fbm(u, v, 16, 2, seed.wrapping_add(99));
                    let seam_v = (v * 8.0 - row as f32) < 1.5 / n * 8.0;
                    let seam_u = (along * 2.0 - board as f32) < 1.5 / n * 2.0;
                    let c = scale(mix(base, accent, 0.3 * streak), tint * (0.75 + 0.5 * grain));
                    if seam_u || seam_v { scale(c, 0.45) } else { c }
                }
                TextureKind::Tiles => {
                    let (tu, tv) = (u * 4.0, v * 4.0);
                    let (iu, iv) = (tu.floor() as u32, tv.floor() as u32);
                    let grout =
                        (tu - iu as f32) < 3.0 / n * 4.0 || (tv - iv as f32) < 3.0 / n * 4.0;
                    let tint = 0.85 + 0.25 * unit(hash3(iu, iv, seed));
                    let marble = fbm(u, v, 8, 4, seed);
                    if grout {
                        [0.35, 0.34, 0.32]
                    } else {
                        scale(mix(base, accent, 0.5 * marble), tint)
                    }
                }
                TextureKind::Carpet => {
                    let fine = unit(hash3(x, y, seed));
                    let blotch = fbm(u, v, 4, 4, seed);
                    scale(
                        mix(base, accent, 0.4 * blotch),
                        0.7 + 0.3 * fine + 0.2 * blotch,
                    )
                }
                TextureKind::Plaster => {
                    let blotch = fbm(u, v, 4, 5, seed);
                    let speck = unit(hash3(x, y, seed)) - 0.5;
                    scale(
                        mix(base, accent, 0.35 * blotch),
                        0.78 + 0.35 * blotch + 0.08 * speck,
                    )
                }
                TextureKind::Wallpaper => {
                    let stripe = (u * 8.0).floor() as u32;
                    let band = if stripe.is_multiple_of(2) {
                        base
                    } else {
                        accent
                    };
                    let cu = u * 8.0 - stripe as f32 - 0.5;
                    let cv = v * 8.0 - (v * 8.0).floor() - 0.5;
                    let dot = cu * cu + cv * cv < 0.06;
                    let paper = fbm(u, v, 8, 3, seed);
                    let c = scale(band, 0.8 + 0.3 * paper);
                    if dot { scale(c, 0.55) } else { c }
                }
                TextureKind::Fabric => {
                    let weave = if (x / 2 + y / 2) % 2 == 0 { 1.0 } else { 0.82 };
                    let mottle = fbm(u, v, 4, 4, seed);
                    scale(
                        mix(base, accent, 0.3 * mottle),
                        weave * (0.75 + 0.4 * mottle),
                    )
                }
                TextureKind::Ceiling => {
                    let n1 = fbm(u, v, 4, 4, seed);
                    scale(base, 0.85 + 0.15 * n1)
                }
            };
            texels.push(c.map(|k| (k.clamp(0.0, 1.0) * 255.0 + 0.5) as u8));
        }
    }
    Texture {
        name: format!("procedural {kind:?} {seed:08x}"),
        width: size,
        height: size,
        texels,
        wrap_u: Wrap::Repeat,
        wrap_v: Wrap::Repeat,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_tiles_across_the_period() {
        for (x, y) in [(0.25f32, 0.75f32), (2.5, 1.375)] {
            let a = value_noise(x, y, 4, 7);
            let b = value_noise(x + 4.0, y - 8.0, 4, 7);
            assert_eq!(a, b);
        }
    }

    #[test]
    fn textures_are_deterministic_and_textured() {
        for kind in [
            TextureKind::WoodPlanks,
            TextureKind::Tiles,
            TextureKind::Wallpaper,
            TextureKind::Plaster,
        ] {
            let a = generate(kind, 64, 42);
            assert_eq!(a, generate(kind, 64, 42));
            assert_ne!(a.texels, generate(kind, 64, 43).texels);
            // Enough contrast for photometric tracking: luminance spread over the image.
            let lum: Vec<f32> = a
                .texels
                .iter()
                .map(|t| (t[0] as f32 + t[1] as f32 + t[2] as f32) / 3.0)
                .collect();
            let mean = lum.iter().sum::<f32>() / lum.len() as f32;
            let var = lum.iter().map(|l| (l - mean) * (l - mean)).sum::<f32>() / lum.len() as f32;
            assert!(var.sqrt() > 4.0, "{kind:?} too flat: std {}", var.sqrt());
        }
    }
}
