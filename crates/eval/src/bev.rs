//! The bird's-eye view of a run (`bev.png`): the last occupancy grid with the true and the
//! estimated paths and the frontier centroids ([`Bev`]), drawn as an RGB image
//! ([`Bev::render`]); the run folder writes it ([`RunFolder::write_bev`]).

use crate::run_folder::RunFolder;

/// One cell of the bird's-eye view.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BevCell {
    /// Observed free (white).
    Free,
    /// Observed occupied (black).
    Occupied,
    /// Not observed (grey).
    Unknown,
}

/// What `bev.png` shows: the last occupancy grid (free white, occupied black, unknown grey),
/// the true path (blue), the estimated path (green, drawn over it) and the frontier centroids
/// (red squares). Positions are in grid cell units (the centre of cell (i, j) at (i, j), as
/// `GridGeometry::to_cell_units` of `activemap-planning` gives them); image up = +y.
#[derive(Debug, Clone, PartialEq)]
pub struct Bev {
    /// Grid width, cells.
    pub width: usize,
    /// Grid height, cells.
    pub height: usize,
    /// Row-major cells, row 0 at the lowest y.
    pub cells: Vec<BevCell>,
    /// The true path, mapped into the grid's frame.
    pub truth: Vec<[f64; 2]>,
    /// The estimated path.
    pub estimated: Vec<[f64; 2]>,
    /// Frontier centroids.
    pub frontiers: Vec<[f64; 2]>,
    /// Pixels per cell side, 1..=16.
    pub pixels_per_cell: u32,
}

impl Bev {
    /// Colour of free cells.
    pub const FREE: [u8; 3] = [255, 255, 255];
    /// Colour of occupied cells.
    pub const OCCUPIED: [u8; 3] = [0, 0, 0];
    /// Colour of unknown cells.
    pub const UNKNOWN: [u8; 3] = [160, 160, 160];
    /// Colour of the true path.
    pub const TRUTH: [u8; 3] = [40, 80, 255];
    /// Colour of the estimated path.
    pub const ESTIMATED: [u8; 3] = [0, 170, 0];
    /// Colour of the frontier centroids.
    pub const FRONTIER: [u8; 3] = [230, 0, 0];

    /// The image; an error when the scale or the cell count is wrong.
    pub fn render(&self) -> Result<image::RgbImage, String> {
        let scale = self.pixels_per_cell;
        if !(1..=16).contains(&scale) {
            return Err(format!(
                "{}: pixels per cell must be in 1..=16, got {scale}",
                RunFolder::BEV
            ));
        }
        if self.cells.len() != self.width * self.height || self.cells.is_empty() {
            return Err(format!(
                "{}: {} cells for a {}×{} grid",
                RunFolder::BEV,
                self.cells.len(),
                self.width,
                self.height
            ));
        }
        let (w, h) = (self.width as u32 * scale, self.height as u32 * scale);
        let mut img = image::RgbImage::new(w, h);
        for (i, state) in self.cells.iter().enumerate() {
            let (cx, cy) = ((i % self.width) as u32, (i / self.width) as u32);
            let colour = match state {
                BevCell::Free => Self::FREE,
                BevCell::Occupied => Self::OCCUPIED,
                BevCell::Unknown => Self::UNKNOWN,
            };
            for dy in 0..scale {
                for dx in 0..scale {
                    img.put_pixel(
                        cx * scale + dx,
                        h - 1 - (cy * scale + dy),
                        image::Rgb(colour),
                    );
                }
            }
        }
        let mut dot = |p: [f64; 2], colour: [u8; 3], radius: i64| {
            let (cx, cy) = (
                (p[0] * scale as f64) as i64,
                h as i64 - 1 - (p[1] * scale as f64) as i64,
            );
            for y in cy - radius..=cy + radius {
                for x in cx - radius..=cx + radius {
                    if x >= 0 && y >= 0 && (x as u32) < w && (y as u32) < h {
                        img.put_pixel(x as u32, y as u32, image::Rgb(colour));
                    }
                }
            }
        };
        self.truth.iter().for_each(|p| dot(*p, Self::TRUTH, 0));
        self.estimated
            .iter()
            .for_each(|p| dot(*p, Self::ESTIMATED, 0));
        self.frontiers
            .iter()
            .for_each(|p| dot(*p, Self::FRONTIER, scale as i64));
        Ok(img)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The drawing: cells as blocks with +y up, paths over the grid, frontiers as squares.
    #[test]
    fn bev_draws_cells_paths_and_frontiers() {
        let dir = tempfile::tempdir().unwrap();
        let run = RunFolder::new(dir.path());
        // 3×2 grid: bottom row free, free, occupied; top row unknown.
        let bev = Bev {
            width: 3,
            height: 2,
            cells: vec![
                BevCell::Free,
                BevCell::Free,
                BevCell::Occupied,
                BevCell::Unknown,
                BevCell::Unknown,
                BevCell::Unknown,
            ],
            truth: vec![[0.0, 0.0]],
            estimated: vec![[1.0, 0.0]],
            frontiers: vec![[2.0, 1.5]],
            pixels_per_cell: 2,
        };
        run.write_bev(&bev).unwrap();
        let img = image::open(run.path(RunFolder::BEV)).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (6, 4));
        let px = |x, y| img.get_pixel(x, y).0;
        // The bottom grid row is image rows 2..4; a point at cell units (x, y) lands on pixel
        // (2x, 3 − 2y).
        assert_eq!(px(0, 3), Bev::TRUTH);
        assert_eq!(px(1, 2), Bev::FREE);
        assert_eq!(px(2, 3), Bev::ESTIMATED);
        assert_eq!(px(5, 3), Bev::OCCUPIED);
        assert_eq!(px(0, 0), Bev::UNKNOWN);
        // The frontier at (2, 1.5): a square of radius 2 around pixel (4, 0).
        assert_eq!(px(3, 0), Bev::FRONTIER);
        assert_eq!(px(5, 2), Bev::FRONTIER);
        assert_eq!(px(1, 0), Bev::UNKNOWN);
        let bad = Bev {
            pixels_per_cell: 0,
            ..bev.clone()
        };
        let e = run.write_bev(&bad).unwrap_err().to_string();
        assert!(e.contains("bev.png") && e.contains("1..=16"), "{e}");
        let bad = Bev {
            cells: vec![BevCell::Free],
            ..bev
        };
        assert!(run.write_bev(&bad).is_err());
    }
}
