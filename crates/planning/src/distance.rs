//! Exact Euclidean distance transform (Felzenszwalb & Huttenlocher 2012): for every cell, the
//! distance between its centre and the centre of the nearest obstacle cell. The planner turns
//! it into the robot-width collision check and the extra cost near obstacles (SPEC §6).

use crate::grid::{Cell, Grid, GridGeometry};

/// Squared distance of a cell that has no obstacle anywhere on the grid.
const FAR: f64 = f64::INFINITY;

/// 1D squared distance transform of the sampled function `f` (lower envelope of parabolas
/// rooted at the finite samples); `v`, `z` are scratch buffers of length n and n + 1.
fn transform_1d(f: &[f64], out: &mut [f64], v: &mut [usize], z: &mut [f64]) {
    let n = f.len();
    let mut k: isize = -1;
    for q in 0..n {
        if !f[q].is_finite() {
            continue;
        }
        let fq = f[q] + (q * q) as f64;
        loop {
            if k < 0 {
                break;
            }
            let p = v[k as usize];
            let s = (fq - (f[p] + (p * p) as f64)) / (2.0 * (q as f64 - p as f64));
            if s <= z[k as usize] {
                k -= 1;
            } else {
                break;
            }
        }
        if k < 0 {
            k = 0;
            v[0] = q;
            z[0] = f64::NEG_INFINITY;
            z[1] = f64::INFINITY;
        } else {
            let p = v[k as usize];
            let s = (fq - (f[p] + (p * p) as f64)) / (2.0 * (q as f64 - p as f64));
            k += 1;
            v[k as usize] = q;
            z[k as usize] = s;
            z[k as usize + 1] = f64::INFINITY;
        }
    }
    if k < 0 {
        out.iter_mut().for_each(|o| *o = FAR);
        return;
    }
    let mut j = 0usize;
    for (q, o) in out.iter_mut().enumerate() {
        while z[j + 1] < q as f64 {
            j += 1;
        }
        let d = q as f64 - v[j] as f64;
        *o = d * d + f[v[j]];
    }
}

/// Squared Euclidean distances, in cells², from each cell centre to the nearest cell where
/// `is_obstacle` holds (0 on obstacles, +∞ when there is none). Row-major, `width × height`.
pub fn squared_distance_transform(is_obstacle: &[bool], width: usize, height: usize) -> Vec<f64> {
    assert_eq!(is_obstacle.len(), width * height, "mask size");
    let n = width.max(height);
    let mut v = vec![0usize; n];
    let mut z = vec![0f64; n + 1];
    let mut col_in = vec![0f64; height];
    let mut col_out = vec![0f64; height];
    let mut tmp = vec![FAR; width * height];
    // Columns first: distance along y to the nearest obstacle in the same column.
    for x in 0..width {
        for y in 0..height {
            col_in[y] = if is_obstacle[y * width + x] { 0.0 } else { FAR };
        }
        transform_1d(&col_in, &mut col_out, &mut v, &mut z);
        for y in 0..height {
            tmp[y * width + x] = col_out[y];
        }
    }
    // Then rows over the column results.
    let mut out = vec![FAR; width * height];
    for y in 0..height {
        let row = &tmp[y * width..(y + 1) * width];
        transform_1d(row, &mut out[y * width..(y + 1) * width], &mut v, &mut z);
    }
    out
}

/// Distance (cells) from each cell centre to the nearest obstacle cell centre.
#[derive(Debug, Clone, PartialEq)]
pub struct DistanceField {
    /// Distances in cells, row-major; +∞ where no obstacle exists.
    pub cells: Grid<f32>,
}

impl DistanceField {
    /// The exact Euclidean distance transform of the obstacle mask on `geometry`.
    pub fn from_mask(geometry: GridGeometry, is_obstacle: &[bool]) -> Self {
        let sq = squared_distance_transform(is_obstacle, geometry.width, geometry.height);
        let data = sq.into_iter().map(|d| d.sqrt() as f32).collect();
        Self {
            cells: Grid { geometry, data },
        }
    }

    /// Distance in cells at `cell`; 0 outside the grid (the outside counts as an obstacle).
    pub fn distance_cells(&self, cell: Cell) -> f32 {
        self.cells.get(cell).copied().unwrap_or(0.0)
    }

    /// Distance in metres at `cell`; 0 outside the grid.
    pub fn distance_m(&self, cell: Cell) -> f64 {
        self.distance_cells(cell) as f64 * self.cells.geometry.resolution
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn matches_brute_force_on_random_masks() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for trial in 0..30 {
            let w = rng.random_range(1..25);
            let h = rng.random_range(1..25);
            let density = [0.0, 0.02, 0.1, 0.5, 1.0][trial % 5];
            let mask: Vec<bool> = (0..w * h).map(|_| rng.random_bool(density)).collect();
            let got = squared_distance_transform(&mask, w, h);
            for y in 0..h {
                for x in 0..w {
                    let mut best = f64::INFINITY;
                    for yy in 0..h {
                        for xx in 0..w {
                            if mask[yy * w + xx] {
                                let dx = x as f64 - xx as f64;
                                let dy = y as f64 - yy as f64;
                                best = best.min(dx * dx + dy * dy);
                            }
                        }
                    }
                    assert_eq!(got[y * w + x], best, "trial {trial} cell ({x},{y})");
                }
            }
        }
    }

    #[test]
    fn distance_field_reports_metres_and_treats_outside_as_obstacle() {
        let g = GridGeometry::new(0.0, 0.0, 0.05, 7, 1).unwrap();
        let mut mask = vec![false; 7];
        mask[0] = true;
        let df = DistanceField::from_mask(g, &mask);
        assert!((df.distance_m(Cell::new(4, 0)) - 0.2).abs() < 1e-6);
        assert_eq!(df.distance_cells(Cell::new(-1, 0)), 0.0);
    }
}
