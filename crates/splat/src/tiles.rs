//! Binning of projected Gaussians into 16×16-pixel tiles and the per-tile depth sort.
//! Deterministic: tiles are filled in Gaussian index order and sorted by (depth, index).

use crate::project::Splat;
use crate::real::Real;
use rayon::prelude::*;

/// Tile edge length, pixels.
pub const TILE: usize = 16;

/// For every tile, the Gaussians touching it, front to back.
#[derive(Debug, Clone, Default)]
pub struct TileBins {
    /// Tiles per image row.
    pub tiles_x: usize,
    /// Tiles per image column.
    pub tiles_y: usize,
    /// `ids[offsets[t]..offsets[t + 1]]` are the Gaussians of tile `t` (row-major tile index).
    pub offsets: Vec<usize>,
    /// Gaussian indices, grouped by tile, sorted by depth then index inside a tile.
    pub ids: Vec<u32>,
}

impl TileBins {
    /// Number of tiles.
    pub fn tile_count(&self) -> usize {
        self.tiles_x * self.tiles_y
    }

    /// Number of (tile, Gaussian) pairs.
    pub fn pair_count(&self) -> usize {
        self.ids.len()
    }

    /// The Gaussians of tile `t`, front to back.
    pub fn tile(&self, t: usize) -> &[u32] {
        &self.ids[self.offsets[t]..self.offsets[t + 1]]
    }

    /// Pixel rectangle `[x0, x1) × [y0, y1)` of tile `t`.
    pub fn tile_rect(&self, t: usize, width: usize, height: usize) -> [usize; 4] {
        let (tx, ty) = (t % self.tiles_x, t / self.tiles_x);
        [
            tx * TILE,
            ((tx + 1) * TILE).min(width),
            ty * TILE,
            ((ty + 1) * TILE).min(height),
        ]
    }
}

/// Tile range `[tx0, tx1] × [ty0, ty1]` (inclusive) of a splat's pixel box.
fn tile_range<T: Real>(s: &Splat<T>) -> [usize; 4] {
    let b = s.bbox.map(|v| v as usize / TILE);
    [b[0], b[1], b[2], b[3]]
}

/// Bins the visible splats (`visible[i]` true) into tiles of an image of the given size.
pub fn bin<T: Real>(
    splats: &[Splat<T>],
    visible: &[bool],
    width: usize,
    height: usize,
) -> TileBins {
    let tiles_x = width.div_ceil(TILE);
    let tiles_y = height.div_ceil(TILE);
    let mut counts = vec![0usize; tiles_x * tiles_y + 1];
    for (s, _) in splats.iter().zip(visible).filter(|(_, v)| **v) {
        let [x0, x1, y0, y1] = tile_range(s);
        for ty in y0..=y1 {
            for c in &mut counts[ty * tiles_x + x0..=ty * tiles_x + x1] {
                *c += 1;
            }
        }
    }
    let mut offsets = Vec::with_capacity(counts.len());
    let mut total = 0;
    for c in &counts {
        offsets.push(total);
        total += c;
    }
    offsets.truncate(tiles_x * tiles_y + 1);
    let mut cursor = offsets.clone();
    let mut ids = vec![0u32; total];
    for (i, s) in splats.iter().enumerate().filter(|(i, _)| visible[*i]) {
        let [x0, x1, y0, y1] = tile_range(s);
        for ty in y0..=y1 {
            for tx in x0..=x1 {
                let t = ty * tiles_x + tx;
                ids[cursor[t]] = i as u32;
                cursor[t] += 1;
            }
        }
    }
    let slices = split_by_offsets(&mut ids, &offsets, 1);
    slices.into_par_iter().for_each(|list| {
        // Integer keys (depth in a bit pattern that orders as the value, then index) sort
        // several times faster than a float comparator.
        let mut keyed: Vec<(u64, u32)> = list
            .iter()
            .map(|&i| (depth_key(splats[i as usize].depth.to_f64()), i))
            .collect();
        keyed.sort_unstable();
        for (dst, (_, i)) in list.iter_mut().zip(keyed) {
            *dst = i;
        }
    });
    TileBins {
        tiles_x,
        tiles_y,
        offsets,
        ids,
    }
}

/// The bits of `depth` as an unsigned integer ordered as `f64::total_cmp` orders the values
/// (for the finite depths of projected splats: as their values).
fn depth_key(depth: f64) -> u64 {
    let bits = depth.to_bits();
    if bits >> 63 == 1 {
        !bits
    } else {
        bits | 1 << 63
    }
}

/// Splits `data` into consecutive pieces `[offsets[t]·stride, offsets[t + 1]·stride)`.
pub(crate) fn split_by_offsets<'a, V>(
    mut data: &'a mut [V],
    offsets: &[usize],
    stride: usize,
) -> Vec<&'a mut [V]> {
    let mut out = Vec::with_capacity(offsets.len().saturating_sub(1));
    for w in offsets.windows(2) {
        let (head, tail) = data.split_at_mut((w[1] - w[0]) * stride);
        out.push(head);
        data = tail;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The integer depth key orders values as `f64::total_cmp` does, across signs, zeros,
    /// subnormals, infinities and the range of f32 depths.
    #[test]
    fn depth_keys_order_as_the_values() {
        let mut values = vec![
            f64::NEG_INFINITY,
            -1e300,
            -2.5,
            -f64::MIN_POSITIVE,
            -0.0,
            0.0,
            f64::MIN_POSITIVE / 4.0,
            1e-9,
            0.01,
            0.010000001,
            1.0,
            f32::MAX as f64,
            f64::INFINITY,
        ];
        let mut x = 0.37f64;
        for _ in 0..200 {
            x = (x * 3.9 * (1.0 - x)).abs();
            values.push((x - 0.5) * 40.0);
            values.push(x as f32 as f64);
        }
        for a in &values {
            for b in &values {
                assert_eq!(
                    depth_key(*a).cmp(&depth_key(*b)),
                    a.total_cmp(b),
                    "{a} vs {b}"
                );
            }
        }
    }
}
