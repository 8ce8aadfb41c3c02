//! Cells touched by straight segments: the exact supercover of a segment between cell centres
//! (for collision checks: every cell whose closed square the segment touches, so a diagonal
//! move through a corner checks both corner cells and never cuts it), and a DDA traversal of a
//! continuous segment (for depth rays).

use nalgebra::Point2;

use crate::grid::{Cell, GridGeometry};

fn floor_div(a: i64, b: i64) -> i64 {
    a.div_euclid(b)
}

fn ceil_div(a: i64, b: i64) -> i64 {
    -((-a).div_euclid(b))
}

/// Calls `visit` on every cell whose closed square touches the segment between the centres of
/// `a` and `b`, in exact integer arithmetic; stops early (returning false) when `visit` does.
/// Cells are visited column by column; each cell once.
pub fn for_each_supercover_cell(a: Cell, b: Cell, mut visit: impl FnMut(Cell) -> bool) -> bool {
    let (a, b) = if a.x <= b.x { (a, b) } else { (b, a) };
    let dx = (b.x - a.x) as i64;
    let dy = (b.y - a.y) as i64;
    if dx == 0 {
        let (lo, hi) = (a.y.min(b.y), a.y.max(b.y));
        return (lo..=hi).all(|y| visit(Cell::new(a.x, y)));
    }
    // Doubled x coordinates X = 2x keep cell borders (half-integers) integral; along the
    // segment, P(X) = 2·dx·y = 2·dx·y0 + (X − 2·x0)·dy is an integer too.
    let p_at = |xx: i64| 2 * dx * a.y as i64 + (xx - 2 * a.x as i64) * dy;
    for i in a.x..=b.x {
        let xa = (2 * i as i64 - 1).max(2 * a.x as i64);
        let xb = (2 * i as i64 + 1).min(2 * b.x as i64);
        let (pa, pb) = (p_at(xa), p_at(xb));
        let (plo, phi) = (pa.min(pb), pa.max(pb));
        // Rows j with j − ½ ≤ y_hi and j + ½ ≥ y_lo, y = P / (2·dx).
        let j_lo = ceil_div(plo - dx, 2 * dx);
        let j_hi = floor_div(phi + dx, 2 * dx);
        for j in j_lo..=j_hi {
            if !visit(Cell::new(i, j as i32)) {
                return false;
            }
        }
    }
    true
}

/// The supercover of the segment between the centres of `a` and `b` (see
/// [`for_each_supercover_cell`]).
pub fn supercover_cells(a: Cell, b: Cell) -> Vec<Cell> {
    let mut out = Vec::new();
    for_each_supercover_cell(a, b, |c| {
        out.push(c);
        true
    });
    out
}

/// Visits, in order from `from` to `to`, every cell that the continuous world segment passes
/// through (Amanatides–Woo DDA), including both end cells. Cells outside the grid are visited
/// too (the caller filters); a segment touching a corner exactly steps in x first.
pub fn for_each_ray_cell(
    geometry: &GridGeometry,
    from: Point2<f64>,
    to: Point2<f64>,
    mut visit: impl FnMut(Cell),
) {
    let r = geometry.resolution;
    let ux = (from.x - geometry.origin_x) / r;
    let uy = (from.y - geometry.origin_y) / r;
    let vx = (to.x - geometry.origin_x) / r;
    let vy = (to.y - geometry.origin_y) / r;
    let mut cell = geometry.cell_of(from);
    let end = geometry.cell_of(to);
    let (dx, dy) = (vx - ux, vy - uy);
    let step_x = if dx > 0.0 { 1 } else { -1 };
    let step_y = if dy > 0.0 { 1 } else { -1 };
    // Parameter t ∈ [0, 1] along the segment at which the next x (y) border is crossed.
    let next_border = |u: f64, c: i32, step: i32| {
        if step > 0 {
            c as f64 + 1.0 - u
        } else {
            u - c as f64
        }
    };
    let mut t_max_x = if dx != 0.0 {
        next_border(ux, cell.x, step_x) / dx.abs()
    } else {
        f64::INFINITY
    };
    let mut t_max_y = if dy != 0.0 {
        next_border(uy, cell.y, step_y) / dy.abs()
    } else {
        f64::INFINITY
    };
    let t_delta_x = if dx != 0.0 {
        1.0 / dx.abs()
    } else {
        f64::INFINITY
    };
    let t_delta_y = if dy != 0.0 {
        1.0 / dy.abs()
    } else {
        f64::INFINITY
    };
    let max_steps = (end.x - cell.x).unsigned_abs() + (end.y - cell.y).unsigned_abs();
    visit(cell);
    for _ in 0..max_steps {
        if cell == end {
            break;
        }
        if t_max_x <= t_max_y {
            cell.x += step_x;
            t_max_x += t_delta_x;
        } else {
            cell.y += step_y;
            t_max_y += t_delta_y;
        }
        visit(cell);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Independent exact test: does the segment between integer points `a`, `b` touch the closed
    /// square of side 1 centred on `c`? Separating-axis test in doubled integer coordinates.
    fn touches(a: Cell, b: Cell, c: Cell) -> bool {
        let (ax, ay, bx, by) = (
            2 * a.x as i64,
            2 * a.y as i64,
            2 * b.x as i64,
            2 * b.y as i64,
        );
        let (cx, cy) = (2 * c.x as i64, 2 * c.y as i64);
        if ax.max(bx) < cx - 1 || ax.min(bx) > cx + 1 || ay.max(by) < cy - 1 || ay.min(by) > cy + 1
        {
            return false;
        }
        let side = |px: i64, py: i64| ((bx - ax) * (py - ay) - (by - ay) * (px - ax)).signum();
        let corners = [
            side(cx - 1, cy - 1),
            side(cx + 1, cy - 1),
            side(cx - 1, cy + 1),
            side(cx + 1, cy + 1),
        ];
        !(corners.iter().all(|s| *s > 0) || corners.iter().all(|s| *s < 0))
    }

    #[test]
    fn supercover_matches_brute_force_square_intersection() {
        let ends: Vec<Cell> = (-4..=4)
            .flat_map(|x| (-3..=3).map(move |y| Cell::new(x, y)))
            .collect();
        for &a in &ends {
            for &b in &ends {
                let mut got = supercover_cells(a, b);
                got.sort();
                let before = got.len();
                got.dedup();
                assert_eq!(before, got.len(), "duplicate cells for {a:?}->{b:?}");
                let mut want: Vec<Cell> = (-6..=6)
                    .flat_map(|x| (-5..=5).map(move |y| Cell::new(x, y)))
                    .filter(|c| touches(a, b, *c))
                    .collect();
                want.sort();
                assert_eq!(got, want, "segment {a:?} -> {b:?}");
            }
        }
    }

    #[test]
    fn diagonal_move_checks_both_corner_cells() {
        let cells = supercover_cells(Cell::new(0, 0), Cell::new(1, 1));
        for c in [
            Cell::new(0, 0),
            Cell::new(1, 0),
            Cell::new(0, 1),
            Cell::new(1, 1),
        ] {
            assert!(cells.contains(&c), "{c:?} missing");
        }
        assert_eq!(cells.len(), 4);
    }

    #[test]
    fn ray_cells_are_connected_and_end_at_the_end_cell() {
        let g = GridGeometry::new(0.0, 0.0, 0.05, 100, 100).unwrap();
        let from = Point2::new(2.513, 2.487);
        for k in 0..64 {
            let ang = k as f64 * std::f64::consts::TAU / 64.0 + 0.01;
            let to = Point2::new(from.x + 1.7 * ang.cos(), from.y + 1.7 * ang.sin());
            let mut cells = Vec::new();
            for_each_ray_cell(&g, from, to, |c| cells.push(c));
            assert_eq!(cells[0], g.cell_of(from));
            assert_eq!(*cells.last().unwrap(), g.cell_of(to));
            for w in cells.windows(2) {
                let d = (w[1].x - w[0].x).abs() + (w[1].y - w[0].y).abs();
                assert_eq!(d, 1, "cells {:?} not 4-adjacent", w);
            }
            // Every visited cell is crossed by the segment: the distance from its centre to the
            // line is at most half a cell diagonal.
            let dir = (to - from).normalize();
            for c in &cells {
                let q = g.center(*c) - from;
                let perp = (q.x * dir.y - q.y * dir.x).abs();
                assert!(perp <= 0.05 * std::f64::consts::FRAC_1_SQRT_2 + 1e-9);
            }
        }
    }
}
