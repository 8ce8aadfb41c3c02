//! RGB-D frame (SPEC §1 step 1): `#[repr(C)]` header, then RGB8 (row-major, 3 bytes a pixel) and depth
//! in metres (f32, 0 = no reading, SPEC §2), each section 8-byte aligned.

use std::borrow::Cow;

use bytemuck::{Pod, Zeroable};

use crate::SchemaError;
use crate::layout::{Layout, cast_mut, cast_or_copy, check_len, mul, read_header};

const WHAT: &str = "RgbdFrame";

/// Fixed header of an RGB-D frame payload. Magic and schema version come first, as in every large
/// payload, so a reader can reject a foreign or outdated payload before trusting any size.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct RgbdFrameHeader {
    /// [`RgbdFrameHeader::MAGIC`].
    pub magic: u32,
    /// [`RgbdFrameHeader::VERSION`] of the writer.
    pub schema_version: u32,
    /// Monotonic frame number within the episode.
    pub frame_id: u64,
    /// Capture time in seconds.
    pub stamp: f64,
    /// Pinhole intrinsics (OpenCV optical frame, SPEC §2): focal length x, pixels.
    pub fx: f64,
    /// Focal length y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
}

impl RgbdFrameHeader {
    /// Magic number "RGBD" (little-endian).
    pub const MAGIC: u32 = u32::from_le_bytes(*b"RGBD");
    /// Current schema version of the RGB-D payload.
    pub const VERSION: u32 = 1;

    /// A header with magic and version filled in.
    pub fn new(frame_id: u64, stamp: f64, intrinsics: [f64; 4], width: u32, height: u32) -> Self {
        let [fx, fy, cx, cy] = intrinsics;
        Self {
            magic: Self::MAGIC,
            schema_version: Self::VERSION,
            frame_id,
            stamp,
            fx,
            fy,
            cx,
            cy,
            width,
            height,
        }
    }

    fn layout(&self) -> Result<Layout, SchemaError> {
        let (w, h) = (self.width as usize, self.height as usize);
        Layout::new(
            WHAT,
            core::mem::size_of::<Self>(),
            &[mul(w, h, 3), mul(w, h, 4)],
        )
    }

    /// Total payload size in bytes for this header's image size.
    pub fn payload_len(&self) -> Result<usize, SchemaError> {
        Ok(self.layout()?.total)
    }
}

/// Zero-copy read view of an RGB-D payload.
#[derive(Debug, Clone, Copy)]
pub struct RgbdFrameView<'a> {
    /// The header.
    pub header: RgbdFrameHeader,
    /// RGB8 pixels, row-major, `width * height * 3` bytes.
    pub rgb: &'a [u8],
    depth_bytes: &'a [u8],
}

impl<'a> RgbdFrameView<'a> {
    /// Parse a payload, checking magic, version and lengths.
    pub fn parse(bytes: &'a [u8]) -> Result<Self, SchemaError> {
        let header: RgbdFrameHeader = read_header(
            WHAT,
            bytes,
            |h: &RgbdFrameHeader| (h.magic, h.schema_version),
            RgbdFrameHeader::MAGIC,
            RgbdFrameHeader::VERSION,
        )?;
        let layout = header.layout()?;
        check_len(WHAT, bytes, layout.total)?;
        Ok(Self {
            header,
            rgb: &bytes[layout.range(0)],
            depth_bytes: &bytes[layout.range(1)],
        })
    }

    /// Depth in metres, borrowed when the payload is 4-byte aligned (shared memory) and copied otherwise.
    pub fn depth(&self) -> Cow<'a, [f32]> {
        cast_or_copy(self.depth_bytes)
    }

    /// An owned copy.
    pub fn to_owned_frame(&self) -> RgbdFrame {
        RgbdFrame {
            header: self.header,
            rgb: self.rgb.to_vec(),
            depth: self.depth().into_owned(),
        }
    }
}

/// Mutable in-place view of an RGB-D payload: write the header once, then fill the slices directly
/// in a loaned shared-memory buffer (no intermediate copy).
#[derive(Debug)]
pub struct RgbdFrameMut<'a> {
    /// RGB8 pixels to fill.
    pub rgb: &'a mut [u8],
    /// Depth in metres to fill.
    pub depth: &'a mut [f32],
}

impl<'a> RgbdFrameMut<'a> {
    /// Write `header` at the start of `buf` and return the slices to fill. `buf` must be exactly
    /// [`RgbdFrameHeader::payload_len`] bytes and 8-byte aligned.
    pub fn init(buf: &'a mut [u8], header: RgbdFrameHeader) -> Result<Self, SchemaError> {
        let layout = header.layout()?;
        if buf.len() != layout.total {
            return Err(SchemaError::Buffer {
                what: WHAT,
                reason: format!(
                    "buffer has {} bytes, payload needs {}",
                    buf.len(),
                    layout.total
                ),
            });
        }
        let header_len = core::mem::size_of::<RgbdFrameHeader>();
        buf[..header_len].copy_from_slice(bytemuck::bytes_of(&header));
        layout.zero_padding(buf, header_len);
        let (_, rest) = buf.split_at_mut(layout.offsets[0]);
        let (rgb, rest) = rest.split_at_mut(layout.offsets[1] - layout.offsets[0]);
        let rgb = &mut rgb[..layout.lengths[0]];
        let depth = cast_mut::<f32>(WHAT, &mut rest[..layout.lengths[1]])?;
        Ok(Self { rgb, depth })
    }
}

/// Owned RGB-D frame, for producers that do not write in place and for tests.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbdFrame {
    /// The header (magic and version are rewritten on encode).
    pub header: RgbdFrameHeader,
    /// RGB8 pixels, `width * height * 3` bytes.
    pub rgb: Vec<u8>,
    /// Depth in metres, `width * height` values.
    pub depth: Vec<f32>,
}

impl RgbdFrame {
    /// Encode into a fresh byte vector.
    pub fn encode(&self) -> Result<Vec<u8>, SchemaError> {
        let header = RgbdFrameHeader {
            magic: RgbdFrameHeader::MAGIC,
            schema_version: RgbdFrameHeader::VERSION,
            ..self.header
        };
        let layout = header.layout()?;
        if self.rgb.len() != layout.lengths[0] || self.depth.len() * 4 != layout.lengths[1] {
            return Err(SchemaError::InvalidHeader {
                what: WHAT,
                reason: format!(
                    "{}x{} frame needs {} rgb bytes and {} depth values, got {} and {}",
                    header.width,
                    header.height,
                    layout.lengths[0],
                    layout.lengths[1] / 4,
                    self.rgb.len(),
                    self.depth.len()
                ),
            });
        }
        let mut out = vec![0u8; layout.total];
        self.encode_into_unchecked(&mut out, &header, &layout);
        Ok(out)
    }

    /// Encode into `buf` (exactly [`RgbdFrameHeader::payload_len`] bytes), e.g. a loaned sample.
    pub fn encode_into(&self, buf: &mut [u8]) -> Result<(), SchemaError> {
        let bytes = self.encode()?;
        if buf.len() != bytes.len() {
            return Err(SchemaError::Buffer {
                what: WHAT,
                reason: format!(
                    "buffer has {} bytes, payload needs {}",
                    buf.len(),
                    bytes.len()
                ),
            });
        }
        buf.copy_from_slice(&bytes);
        Ok(())
    }

    fn encode_into_unchecked(&self, out: &mut [u8], header: &RgbdFrameHeader, layout: &Layout) {
        out[..core::mem::size_of::<RgbdFrameHeader>()].copy_from_slice(bytemuck::bytes_of(header));
        out[layout.range(0)].copy_from_slice(&self.rgb);
        out[layout.range(1)].copy_from_slice(bytemuck::cast_slice(&self.depth));
    }

    /// Decode (copying) from a payload.
    pub fn decode(bytes: &[u8]) -> Result<Self, SchemaError> {
        Ok(RgbdFrameView::parse(bytes)?.to_owned_frame())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(w: u32, h: u32) -> RgbdFrame {
        let n = (w * h) as usize;
        RgbdFrame {
            header: RgbdFrameHeader::new(7, 1.25, [400.0, 401.0, 399.5, 398.5], w, h),
            rgb: (0..n * 3).map(|i| (i * 31 % 251) as u8).collect(),
            depth: (0..n).map(|i| i as f32 * 0.001).collect(),
        }
    }

    #[test]
    fn round_trip_is_bit_exact() {
        let frame = sample(13, 7);
        let bytes = frame.encode().unwrap();
        assert_eq!(bytes.len() % 8, 0);
        assert_eq!(RgbdFrame::decode(&bytes).unwrap(), frame);
    }

    #[test]
    fn in_place_write_matches_owned_encoding() {
        let frame = sample(5, 3);
        let len = frame.header.payload_len().unwrap();
        // u64 backing storage guarantees the 8-byte alignment a shared-memory sample has; its
        // old bytes (a reused sample) must not survive in the padding after the 45 RGB bytes.
        let mut storage = vec![0xA5A5_A5A5_A5A5_A5A5u64; len / 8];
        let buf: &mut [u8] = bytemuck::cast_slice_mut(&mut storage);
        let view = RgbdFrameMut::init(buf, frame.header).unwrap();
        view.rgb.copy_from_slice(&frame.rgb);
        view.depth.copy_from_slice(&frame.depth);
        assert_eq!(buf, frame.encode().unwrap().as_slice());
        let parsed = RgbdFrameView::parse(buf).unwrap();
        assert!(matches!(parsed.depth(), Cow::Borrowed(_)));
    }

    #[test]
    fn truncation_version_and_magic_are_errors() {
        let bytes = sample(4, 4).encode().unwrap();
        for cut in [0, 3, 8, 40, bytes.len() - 1] {
            assert!(matches!(
                RgbdFrame::decode(&bytes[..cut]),
                Err(SchemaError::Truncated { .. })
            ));
        }
        let mut v2 = bytes.clone();
        v2[4] = 2;
        assert_eq!(
            RgbdFrame::decode(&v2).unwrap_err(),
            SchemaError::VersionMismatch {
                what: WHAT,
                expected: 1,
                found: 2
            }
        );
        let mut garbage = bytes.clone();
        garbage[0] ^= 0xff;
        assert!(matches!(
            RgbdFrame::decode(&garbage),
            Err(SchemaError::BadMagic { .. })
        ));
        // Absurd sizes must not overflow or allocate: the header claims a 4G x 4G image.
        let mut huge = bytes;
        huge[56..64].copy_from_slice(&[0xff; 8]);
        assert!(RgbdFrame::decode(&huge).is_err());
    }

    #[test]
    fn mismatched_slices_are_rejected_on_encode() {
        let mut frame = sample(4, 4);
        frame.depth.pop();
        assert!(matches!(
            frame.encode(),
            Err(SchemaError::InvalidHeader { .. })
        ));
    }
}
