//! A 2D grid on the motion plane (SPEC §6: 5 cm cells by default).
//!
//! Cell `(x, y)` covers world `[origin_x + x·r, origin_x + (x+1)·r) × [origin_y + y·r, ...)`,
//! so its centre is `origin + (i + ½)·r`. Storage is row-major with row `y = 0` at the lowest
//! world y (a PNG writer must flip rows to show +y up).

use nalgebra::Point2;
use serde::{Deserialize, Serialize};

use crate::error::PlanningError;

/// Largest number of cells a grid may hold (keeps a bad bound from allocating gigabytes).
pub const MAX_CELLS: usize = 1 << 26;

/// What the robot knows about one cell of the motion plane. The byte values match
/// `activemap_schemas::occupancy::CellState` (Free 0, Occupied 1, Unknown 2).
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
pub enum CellState {
    /// Observed and traversable.
    Free = 0,
    /// Holds an obstacle in the robot's height band.
    Occupied = 1,
    /// Never observed.
    #[default]
    Unknown = 2,
}

impl CellState {
    /// The state stored as byte `b` (see the type doc); `None` for other values.
    pub fn from_byte(b: u8) -> Option<Self> {
        match b {
            0 => Some(Self::Free),
            1 => Some(Self::Occupied),
            2 => Some(Self::Unknown),
            _ => None,
        }
    }
}

/// Integer cell coordinates (column `x`, row `y`); may lie outside a grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Cell {
    /// Column.
    pub x: i32,
    /// Row.
    pub y: i32,
}

impl Cell {
    /// Creates a cell coordinate.
    pub const fn new(x: i32, y: i32) -> Self {
        Self { x, y }
    }

    /// Euclidean distance between cell centres, in cells.
    pub fn distance(&self, other: &Cell) -> f64 {
        let dx = (self.x - other.x) as f64;
        let dy = (self.y - other.y) as f64;
        (dx * dx + dy * dy).sqrt()
    }

    /// The cell shifted by `(dx, dy)`.
    pub fn offset(&self, dx: i32, dy: i32) -> Cell {
        Cell::new(self.x + dx, self.y + dy)
    }
}

/// Placement and size of a grid: origin (world corner of cell (0, 0)), resolution, size.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GridGeometry {
    /// World x of the lower-left corner of cell (0, 0), metres.
    pub origin_x: f64,
    /// World y of the lower-left corner of cell (0, 0), metres.
    pub origin_y: f64,
    /// Cell side, metres.
    pub resolution: f64,
    /// Number of columns.
    pub width: usize,
    /// Number of rows.
    pub height: usize,
}

impl GridGeometry {
    /// A grid placement, validated (finite origin, positive resolution, non-empty, bounded size).
    pub fn new(
        origin_x: f64,
        origin_y: f64,
        resolution: f64,
        width: usize,
        height: usize,
    ) -> Result<Self, PlanningError> {
        if !(origin_x.is_finite() && origin_y.is_finite()) {
            return Err(PlanningError::NonFinite {
                what: "grid origin",
            });
        }
        if !(resolution.is_finite() && resolution > 0.0) {
            return Err(PlanningError::InvalidGrid(format!(
                "resolution must be positive and finite, got {resolution}"
            )));
        }
        if width == 0 || height == 0 || width.saturating_mul(height) > MAX_CELLS {
            return Err(PlanningError::InvalidGrid(format!(
                "size {width}×{height} must be non-empty and at most {MAX_CELLS} cells"
            )));
        }
        if width > i32::MAX as usize / 2 || height > i32::MAX as usize / 2 {
            return Err(PlanningError::InvalidGrid("size too large".into()));
        }
        Ok(Self {
            origin_x,
            origin_y,
            resolution,
            width,
            height,
        })
    }

    /// The smallest grid of the given resolution covering the box `[min, max]` plus `margin`
    /// metres on every side, with its origin on a multiple of the resolution (so grids built
    /// from different bounds share cell boundaries).
    pub fn from_bounds(
        min: Point2<f64>,
        max: Point2<f64>,
        resolution: f64,
        margin: f64,
    ) -> Result<Self, PlanningError> {
        if !(min
            .coords
            .iter()
            .chain(max.coords.iter())
            .all(|v| v.is_finite())
            && margin.is_finite())
        {
            return Err(PlanningError::NonFinite {
                what: "grid bounds",
            });
        }
        if !(resolution.is_finite() && resolution > 0.0) {
            return Err(PlanningError::InvalidGrid(format!(
                "resolution must be positive and finite, got {resolution}"
            )));
        }
        if min.x > max.x || min.y > max.y || margin < 0.0 {
            return Err(PlanningError::InvalidGrid(format!(
                "bounds min {min:?} exceed max {max:?} or negative margin {margin}"
            )));
        }
        let x0 = ((min.x - margin) / resolution).floor();
        let y0 = ((min.y - margin) / resolution).floor();
        let x1 = ((max.x + margin) / resolution).floor() + 1.0;
        let y1 = ((max.y + margin) / resolution).floor() + 1.0;
        let (w, h) = (x1 - x0, y1 - y0);
        if w * h > MAX_CELLS as f64 {
            return Err(PlanningError::InvalidGrid(format!(
                "bounds need {w}×{h} cells, more than {MAX_CELLS}"
            )));
        }
        Self::new(
            x0 * resolution,
            y0 * resolution,
            resolution,
            w as usize,
            h as usize,
        )
    }

    /// A placement given by the world position of the CENTRE of cell (0, 0) (the convention
    /// of the occupancy-grid message), converted to this type's corner origin.
    pub fn from_center_origin(
        center_x: f64,
        center_y: f64,
        resolution: f64,
        width: usize,
        height: usize,
    ) -> Result<Self, PlanningError> {
        Self::new(
            center_x - 0.5 * resolution,
            center_y - 0.5 * resolution,
            resolution,
            width,
            height,
        )
    }

    /// World position of the centre of cell (0, 0) (the occupancy-grid message's origin).
    pub fn center_origin(&self) -> Point2<f64> {
        self.center(Cell::new(0, 0))
    }

    /// Number of cells.
    pub fn len(&self) -> usize {
        self.width * self.height
    }

    /// Always false: a valid grid has at least one cell.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The cell holding world point `p` (possibly outside the grid).
    pub fn cell_of(&self, p: Point2<f64>) -> Cell {
        let fx = ((p.x - self.origin_x) / self.resolution).floor();
        let fy = ((p.y - self.origin_y) / self.resolution).floor();
        Cell::new(
            fx.clamp(i32::MIN as f64, i32::MAX as f64) as i32,
            fy.clamp(i32::MIN as f64, i32::MAX as f64) as i32,
        )
    }

    /// Continuous grid coordinates of `p`, in cells, with cell centres at integers.
    pub fn to_cell_units(&self, p: Point2<f64>) -> Point2<f64> {
        Point2::new(
            (p.x - self.origin_x) / self.resolution - 0.5,
            (p.y - self.origin_y) / self.resolution - 0.5,
        )
    }

    /// World position of the centre of `cell`.
    pub fn center(&self, cell: Cell) -> Point2<f64> {
        Point2::new(
            self.origin_x + (cell.x as f64 + 0.5) * self.resolution,
            self.origin_y + (cell.y as f64 + 0.5) * self.resolution,
        )
    }

    /// Whether `cell` lies on the grid.
    pub fn contains(&self, cell: Cell) -> bool {
        cell.x >= 0
            && cell.y >= 0
            && (cell.x as usize) < self.width
            && (cell.y as usize) < self.height
    }

    /// Row-major index of `cell`, `None` outside the grid.
    pub fn index(&self, cell: Cell) -> Option<usize> {
        self.contains(cell)
            .then(|| cell.y as usize * self.width + cell.x as usize)
    }

    /// The cell at row-major index `i` (no bounds check beyond arithmetic).
    pub fn cell_at(&self, i: usize) -> Cell {
        Cell::new((i % self.width) as i32, (i / self.width) as i32)
    }

    /// The cell holding `p`, or an [`PlanningError::OutsideGrid`] naming `what`.
    pub fn require_cell(&self, p: Point2<f64>, what: &'static str) -> Result<Cell, PlanningError> {
        if !(p.x.is_finite() && p.y.is_finite()) {
            return Err(PlanningError::NonFinite { what });
        }
        let c = self.cell_of(p);
        if self.contains(c) {
            Ok(c)
        } else {
            Err(PlanningError::OutsideGrid {
                what,
                x: p.x,
                y: p.y,
            })
        }
    }

    /// A grid of the same resolution that also covers the box `[min, max]` (plus `margin`),
    /// and the shift `(dx, dy)` in cells from old to new coordinates (`new = old + shift`).
    /// Returns `self` and a zero shift when the box already fits.
    pub fn grown_to_include(
        &self,
        min: Point2<f64>,
        max: Point2<f64>,
        margin: f64,
    ) -> Result<(GridGeometry, Cell), PlanningError> {
        let lo = self.cell_of(min);
        let hi = self.cell_of(max);
        if self.contains(lo) && self.contains(hi) {
            return Ok((*self, Cell::new(0, 0)));
        }
        let m = (margin / self.resolution).ceil().max(0.0) as i64;
        let x0 = (lo.x as i64 - m).min(0);
        let y0 = (lo.y as i64 - m).min(0);
        let x1 = (hi.x as i64 + 1 + m).max(self.width as i64);
        let y1 = (hi.y as i64 + 1 + m).max(self.height as i64);
        let (w, h) = ((x1 - x0) as usize, (y1 - y0) as usize);
        let g = GridGeometry::new(
            self.origin_x + x0 as f64 * self.resolution,
            self.origin_y + y0 as f64 * self.resolution,
            self.resolution,
            w,
            h,
        )?;
        Ok((g, Cell::new(-x0 as i32, -y0 as i32)))
    }
}

/// A dense grid of values of type `T`, row-major, with its placement.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Grid<T> {
    /// Placement and size.
    pub geometry: GridGeometry,
    /// Row-major values, `geometry.len()` of them.
    pub data: Vec<T>,
}

/// The occupancy grid: each cell free, occupied or unknown.
pub type OccupancyGrid = Grid<CellState>;

impl<T: Clone> Grid<T> {
    /// A grid filled with `value`.
    pub fn filled(geometry: GridGeometry, value: T) -> Self {
        Self {
            data: vec![value; geometry.len()],
            geometry,
        }
    }

    /// Wraps existing row-major data; fails when the length does not match the geometry.
    pub fn from_data(geometry: GridGeometry, data: Vec<T>) -> Result<Self, PlanningError> {
        if data.len() != geometry.len() {
            return Err(PlanningError::SizeMismatch {
                what: "grid data",
                expected: geometry.len(),
                got: data.len(),
            });
        }
        Ok(Self { geometry, data })
    }

    /// The value at `cell`, `None` outside the grid.
    pub fn get(&self, cell: Cell) -> Option<&T> {
        self.geometry.index(cell).map(|i| &self.data[i])
    }

    /// Sets the value at `cell`; returns false (and changes nothing) outside the grid.
    pub fn set(&mut self, cell: Cell, value: T) -> bool {
        match self.geometry.index(cell) {
            Some(i) => {
                self.data[i] = value;
                true
            }
            None => false,
        }
    }

    /// Re-places the grid on `geometry` (same resolution), moving each value by `shift` cells
    /// and filling new cells with `fill` (used to grow a map as the robot explores).
    pub fn reshaped(&self, geometry: GridGeometry, shift: Cell, fill: T) -> Self {
        let mut out = Self::filled(geometry, fill);
        for y in 0..self.geometry.height {
            for x in 0..self.geometry.width {
                let to = Cell::new(x as i32 + shift.x, y as i32 + shift.y);
                if let Some(j) = geometry.index(to) {
                    out.data[j] = self.data[y * self.geometry.width + x].clone();
                }
            }
        }
        out
    }
}

impl OccupancyGrid {
    /// Parses a grid from text rows (top row = highest y): `.` free, `#` occupied, `?` unknown.
    /// For tests and examples; fails on ragged rows or other characters.
    pub fn from_ascii(rows: &[&str], resolution: f64) -> Result<Self, PlanningError> {
        let height = rows.len();
        let width = rows.first().map_or(0, |r| r.chars().count());
        let geometry = GridGeometry::new(0.0, 0.0, resolution, width, height)?;
        let mut grid = Self::filled(geometry, CellState::Unknown);
        for (r, row) in rows.iter().enumerate() {
            if row.chars().count() != width {
                return Err(PlanningError::InvalidGrid(format!(
                    "ascii row {r} has {} characters, expected {width}",
                    row.chars().count()
                )));
            }
            let y = (height - 1 - r) as i32;
            for (x, ch) in row.chars().enumerate() {
                let state = match ch {
                    '.' => CellState::Free,
                    '#' => CellState::Occupied,
                    '?' => CellState::Unknown,
                    other => {
                        return Err(PlanningError::InvalidGrid(format!(
                            "ascii row {r} column {x}: unexpected character {other:?}"
                        )));
                    }
                };
                grid.set(Cell::new(x as i32, y), state);
            }
        }
        Ok(grid)
    }

    /// Number of cells in `state`.
    pub fn count(&self, state: CellState) -> usize {
        self.data.iter().filter(|s| **s == state).count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn world_cell_round_trip_and_edges() {
        let g = GridGeometry::new(-1.0, 2.0, 0.05, 40, 20).unwrap();
        let c = g.cell_of(Point2::new(-1.0, 2.0));
        assert_eq!(c, Cell::new(0, 0));
        // Just below a boundary stays in the lower cell; the boundary itself opens the next.
        assert_eq!(g.cell_of(Point2::new(-0.95 - 1e-9, 2.0)), Cell::new(0, 0));
        assert_eq!(g.cell_of(Point2::new(-0.95 + 1e-9, 2.0)), Cell::new(1, 0));
        let centre = g.center(Cell::new(3, 7));
        assert!((centre.x - (-1.0 + 3.5 * 0.05)).abs() < 1e-12);
        assert!((centre.y - (2.0 + 7.5 * 0.05)).abs() < 1e-12);
        assert_eq!(g.cell_of(centre), Cell::new(3, 7));
        assert_eq!(g.index(Cell::new(3, 7)), Some(7 * 40 + 3));
        assert_eq!(g.cell_at(7 * 40 + 3), Cell::new(3, 7));
        assert!(g.index(Cell::new(40, 0)).is_none() && g.index(Cell::new(0, -1)).is_none());
        let u = g.to_cell_units(centre);
        assert!((u.x - 3.0).abs() < 1e-9 && (u.y - 7.0).abs() < 1e-9);
    }

    #[test]
    fn centre_origin_conversion_and_byte_values() {
        let g = GridGeometry::from_center_origin(1.025, -0.975, 0.05, 3, 3).unwrap();
        assert!((g.origin_x - 1.0).abs() < 1e-12 && (g.origin_y + 1.0).abs() < 1e-12);
        let c = g.center_origin();
        assert!((c.x - 1.025).abs() < 1e-12 && (c.y + 0.975).abs() < 1e-12);
        for s in [CellState::Free, CellState::Occupied, CellState::Unknown] {
            assert_eq!(CellState::from_byte(s as u8), Some(s));
        }
        assert_eq!(CellState::from_byte(3), None);
        assert_eq!(CellState::default(), CellState::Unknown);
    }

    #[test]
    fn bad_geometry_is_refused() {
        assert!(GridGeometry::new(0.0, 0.0, 0.0, 4, 4).is_err());
        assert!(GridGeometry::new(0.0, 0.0, 0.05, 0, 4).is_err());
        assert!(GridGeometry::new(f64::NAN, 0.0, 0.05, 4, 4).is_err());
        assert!(GridGeometry::new(0.0, 0.0, 0.05, 1 << 20, 1 << 20).is_err());
        assert!(
            GridGeometry::from_bounds(Point2::new(1.0, 0.0), Point2::new(0.0, 1.0), 0.05, 0.0)
                .is_err()
        );
    }

    #[test]
    fn from_bounds_covers_the_box_on_aligned_cells() {
        let g =
            GridGeometry::from_bounds(Point2::new(-0.12, 0.31), Point2::new(1.0, 0.4), 0.05, 0.1)
                .unwrap();
        assert!((g.origin_x / 0.05 - (g.origin_x / 0.05).round()).abs() < 1e-9);
        for p in [Point2::new(-0.22, 0.21), Point2::new(1.1, 0.5)] {
            assert!(g.contains(g.cell_of(p)), "{p:?} not covered by {g:?}");
        }
    }

    #[test]
    fn growing_keeps_values_at_their_world_positions() {
        let g = GridGeometry::new(0.0, 0.0, 0.1, 5, 5).unwrap();
        let mut grid = Grid::filled(g, 0u8);
        grid.set(Cell::new(2, 3), 7);
        let p = g.center(Cell::new(2, 3));
        let (g2, shift) = g
            .grown_to_include(Point2::new(-0.55, 0.2), Point2::new(0.3, 1.21), 0.0)
            .unwrap();
        let grown = grid.reshaped(g2, shift, 0);
        assert_eq!(grown.get(g2.cell_of(p)), Some(&7));
        assert!(g2.contains(g2.cell_of(Point2::new(-0.55, 1.21))));
        assert_eq!(grown.data.iter().filter(|v| **v == 7).count(), 1);
        // A box that already fits changes nothing.
        let (same, zero) = g2
            .grown_to_include(Point2::new(0.0, 0.0), Point2::new(0.1, 0.1), 1.0)
            .unwrap();
        assert_eq!((same, zero), (g2, Cell::new(0, 0)));
    }

    #[test]
    fn ascii_grids_parse_with_top_row_highest() {
        let g = OccupancyGrid::from_ascii(&["#?", ".."], 0.05).unwrap();
        assert_eq!(g.get(Cell::new(0, 1)), Some(&CellState::Occupied));
        assert_eq!(g.get(Cell::new(1, 1)), Some(&CellState::Unknown));
        assert_eq!(g.get(Cell::new(0, 0)), Some(&CellState::Free));
        assert!(OccupancyGrid::from_ascii(&["#?", "."], 0.05).is_err());
        assert!(OccupancyGrid::from_ascii(&["#x"], 0.05).is_err());
    }
}
