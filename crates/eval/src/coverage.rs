//! 2-D coverage (SPEC §8, as the authors' release logs it): seen floor area / navigable floor
//! area, from two boolean grids on the same lattice. Cells seen but not navigable (walls,
//! furniture) do not count, so the ratio lies in [0, 1].

use crate::error::EvalError;

/// Fraction of navigable cells that are seen. Grids are row-major `width × height`.
pub fn coverage_2d(
    seen: &[bool],
    navigable: &[bool],
    width: usize,
    height: usize,
) -> Result<f64, EvalError> {
    let cells = width.checked_mul(height);
    if cells != Some(seen.len()) || cells != Some(navigable.len()) {
        return Err(EvalError::SizeMismatch {
            metric: "2D coverage",
            detail: format!(
                "a {width}×{height} grid needs {} cells; seen has {}, navigable has {}",
                cells.map_or_else(|| "too many".to_string(), |n| n.to_string()),
                seen.len(),
                navigable.len()
            ),
        });
    }
    let navigable_cells = navigable.iter().filter(|&&n| n).count();
    if navigable_cells == 0 {
        return Err(EvalError::Empty {
            metric: "2D coverage",
            detail: "the navigable grid has no navigable cell".into(),
        });
    }
    let seen_cells = seen
        .iter()
        .zip(navigable)
        .filter(|&(&s, &n)| s && n)
        .count();
    Ok(seen_cells as f64 / navigable_cells as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_seen_navigable_cells_only() {
        // 3×2: navigable = 4 cells; seen covers 2 of them plus one non-navigable cell.
        let navigable = [true, true, false, true, true, false];
        let seen = [true, false, true, false, true, false];
        assert_eq!(coverage_2d(&seen, &navigable, 3, 2).unwrap(), 0.5);
        assert_eq!(coverage_2d(&navigable, &navigable, 3, 2).unwrap(), 1.0);
    }

    #[test]
    fn bad_grids_are_refused() {
        let e = coverage_2d(&[true; 5], &[true; 6], 3, 2)
            .unwrap_err()
            .to_string();
        assert!(e.contains("seen has 5"), "{e}");
        let e = coverage_2d(&[true; 6], &[false; 6], 3, 2)
            .unwrap_err()
            .to_string();
        assert!(e.contains("no navigable cell"), "{e}");
    }
}
