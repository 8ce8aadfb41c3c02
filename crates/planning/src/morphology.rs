//! 3×3 binary morphology on grid masks (SPEC §6: the occupancy grid gets a 3×3 opening).
//! Cells outside the grid count as not in the mask.

/// Erosion: a cell stays set when all 9 cells of its 3×3 block are set.
pub fn erode3(mask: &[bool], width: usize, height: usize) -> Vec<bool> {
    let mut out = vec![false; mask.len()];
    for y in 1..height.saturating_sub(1) {
        for x in 1..width.saturating_sub(1) {
            out[y * width + x] = (y - 1..=y + 1).all(|yy| {
                mask[yy * width + x - 1..=yy * width + x + 1]
                    .iter()
                    .all(|m| *m)
            });
        }
    }
    out
}

/// Dilation: a cell is set when any cell of its 3×3 block is set.
pub fn dilate3(mask: &[bool], width: usize, height: usize) -> Vec<bool> {
    let mut out = vec![false; mask.len()];
    for y in 0..height {
        for x in 0..width {
            if mask[y * width + x] {
                for yy in y.saturating_sub(1)..(y + 2).min(height) {
                    for xx in x.saturating_sub(1)..(x + 2).min(width) {
                        out[yy * width + xx] = true;
                    }
                }
            }
        }
    }
    out
}

/// Opening (erosion then dilation): removes every part of the mask that no full 3×3 block
/// fits in (specks and strips narrower than 3 cells), keeps the rest unchanged.
pub fn open3(mask: &[bool], width: usize, height: usize) -> Vec<bool> {
    dilate3(&erode3(mask, width, height), width, height)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(rows: &[&str]) -> (Vec<bool>, usize, usize) {
        let w = rows[0].len();
        (
            rows.iter()
                .flat_map(|r| r.chars().map(|c| c == '#'))
                .collect(),
            w,
            rows.len(),
        )
    }

    #[test]
    fn opening_removes_specks_and_thin_strips_and_keeps_blocks() {
        let (m, w, h) = parse(&[
            "#.......#", //
            "...###..#", //
            "...###..#", //
            "...###..#", //
            "........#", //
            ".#......#",
        ]);
        let (want, _, _) = parse(&[
            ".........", //
            "...###...", //
            "...###...", //
            "...###...", //
            ".........", //
            ".........",
        ]);
        assert_eq!(open3(&m, w, h), want);
        // Opening is idempotent and never adds cells.
        let once = open3(&m, w, h);
        assert_eq!(open3(&once, w, h), once);
        assert!(once.iter().zip(&m).all(|(o, i)| !*o || *i));
    }
}
