//! Occupancy grid on the motion plane (SPEC §1 step 4, §6): `#[repr(C)]` header (origin, resolution,
//! width, height) then one byte per cell, row-major (row = y index), values [`CellState`].

use bytemuck::{Pod, Zeroable};

use crate::SchemaError;
use crate::layout::{Layout, check_len, mul, read_header};

const WHAT: &str = "OccupancyGrid";

/// State of one cell, stored as one byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum CellState {
    /// Depth rays passed through the cell.
    Free = 0,
    /// The map holds an obstacle in the cell's height band.
    Occupied = 1,
    /// Never observed.
    Unknown = 2,
}

impl CellState {
    /// Decode a cell byte; `None` for a value outside the enum.
    pub fn from_byte(b: u8) -> Option<Self> {
        match b {
            0 => Some(Self::Free),
            1 => Some(Self::Occupied),
            2 => Some(Self::Unknown),
            _ => None,
        }
    }
}

/// Fixed header of an occupancy grid payload.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct OccupancyGridHeader {
    /// [`OccupancyGridHeader::MAGIC`].
    pub magic: u32,
    /// [`OccupancyGridHeader::VERSION`] of the writer.
    pub schema_version: u32,
    /// Time of the grid, seconds.
    pub stamp: f64,
    /// World x of the centre of cell (0, 0), metres.
    pub origin_x: f64,
    /// World y of the centre of cell (0, 0), metres.
    pub origin_y: f64,
    /// Cell size, metres (SPEC §6: 0.05).
    pub resolution: f64,
    /// Cells along x.
    pub width: u32,
    /// Cells along y.
    pub height: u32,
    /// Frame id the grid was built from.
    pub frame_id: u64,
}

impl OccupancyGridHeader {
    /// Magic number "OCCG".
    pub const MAGIC: u32 = u32::from_le_bytes(*b"OCCG");
    /// Current schema version.
    pub const VERSION: u32 = 1;

    fn layout(&self) -> Result<Layout, SchemaError> {
        Layout::new(
            WHAT,
            core::mem::size_of::<Self>(),
            &[mul(self.width as usize, self.height as usize, 1)],
        )
    }

    /// Total payload size in bytes.
    pub fn payload_len(&self) -> Result<usize, SchemaError> {
        Ok(self.layout()?.total)
    }
}

/// Owned occupancy grid.
#[derive(Debug, Clone, PartialEq)]
pub struct OccupancyGrid {
    /// Time of the grid, seconds.
    pub stamp: f64,
    /// Frame id the grid was built from.
    pub frame_id: u64,
    /// World (x, y) of the centre of cell (0, 0), metres.
    pub origin: [f64; 2],
    /// Cell size in metres.
    pub resolution: f64,
    /// Cells along x.
    pub width: u32,
    /// Cells along y.
    pub height: u32,
    /// `width * height` cells, row-major, values of [`CellState`].
    pub cells: Vec<u8>,
}

impl OccupancyGrid {
    /// State of cell (ix, iy); `None` outside the grid or for an invalid byte.
    pub fn cell(&self, ix: u32, iy: u32) -> Option<CellState> {
        if ix >= self.width || iy >= self.height {
            return None;
        }
        CellState::from_byte(self.cells[iy as usize * self.width as usize + ix as usize])
    }

    /// Encode into a fresh byte vector.
    pub fn encode(&self) -> Result<Vec<u8>, SchemaError> {
        let header = OccupancyGridHeader {
            magic: OccupancyGridHeader::MAGIC,
            schema_version: OccupancyGridHeader::VERSION,
            stamp: self.stamp,
            origin_x: self.origin[0],
            origin_y: self.origin[1],
            resolution: self.resolution,
            width: self.width,
            height: self.height,
            frame_id: self.frame_id,
        };
        let layout = header.layout()?;
        if self.cells.len() != layout.lengths[0] {
            return Err(SchemaError::InvalidHeader {
                what: WHAT,
                reason: format!(
                    "{}x{} grid needs {} cells, got {}",
                    self.width,
                    self.height,
                    layout.lengths[0],
                    self.cells.len()
                ),
            });
        }
        let mut out = vec![0u8; layout.total];
        out[..core::mem::size_of::<OccupancyGridHeader>()]
            .copy_from_slice(bytemuck::bytes_of(&header));
        out[layout.range(0)].copy_from_slice(&self.cells);
        Ok(out)
    }

    /// Decode (copying) from a payload.
    pub fn decode(bytes: &[u8]) -> Result<Self, SchemaError> {
        let v = OccupancyGridView::parse(bytes)?;
        Ok(Self {
            stamp: v.header.stamp,
            frame_id: v.header.frame_id,
            origin: [v.header.origin_x, v.header.origin_y],
            resolution: v.header.resolution,
            width: v.header.width,
            height: v.header.height,
            cells: v.cells.to_vec(),
        })
    }
}

/// Zero-copy read view of an occupancy grid payload.
#[derive(Debug, Clone, Copy)]
pub struct OccupancyGridView<'a> {
    /// The header.
    pub header: OccupancyGridHeader,
    /// Cells, row-major.
    pub cells: &'a [u8],
}

impl<'a> OccupancyGridView<'a> {
    /// Parse a payload, checking magic, version and lengths.
    pub fn parse(bytes: &'a [u8]) -> Result<Self, SchemaError> {
        let header: OccupancyGridHeader = read_header(
            WHAT,
            bytes,
            |h: &OccupancyGridHeader| (h.magic, h.schema_version),
            OccupancyGridHeader::MAGIC,
            OccupancyGridHeader::VERSION,
        )?;
        let layout = header.layout()?;
        check_len(WHAT, bytes, layout.total)?;
        Ok(Self {
            header,
            cells: &bytes[layout.range(0)],
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_cell_lookup() {
        let grid = OccupancyGrid {
            stamp: 1.0,
            frame_id: 4,
            origin: [-1.0, 2.5],
            resolution: 0.05,
            width: 3,
            height: 2,
            cells: vec![0, 1, 2, 2, 1, 0],
        };
        let bytes = grid.encode().unwrap();
        let back = OccupancyGrid::decode(&bytes).unwrap();
        assert_eq!(back, grid);
        assert_eq!(back.cell(1, 0), Some(CellState::Occupied));
        assert_eq!(back.cell(0, 1), Some(CellState::Unknown));
        assert_eq!(back.cell(3, 0), None);
        assert!(OccupancyGrid::decode(&bytes[..bytes.len() - 8]).is_err());
    }
}
