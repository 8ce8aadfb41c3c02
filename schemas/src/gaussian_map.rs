//! Gaussian map snapshot (SPEC §3): `#[repr(C)]` header, then the 14 parameters per Gaussian as
//! structure-of-arrays f32 slices: means (3), colours (3), rotations (4, xyzw unnormalised),
//! opacities (1, pre-sigmoid), log-scales (3).

use std::borrow::Cow;

use bytemuck::{Pod, Zeroable};

use crate::SchemaError;
use crate::layout::{Layout, cast_mut, cast_or_copy, check_len, read_header};

const WHAT: &str = "GaussianMap";
/// Floats per Gaussian in each section, in payload order.
const SECTION_WIDTHS: [usize; 5] = [3, 3, 4, 1, 3];

/// Fixed header of a Gaussian map payload.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct GaussianMapHeader {
    /// [`GaussianMapHeader::MAGIC`].
    pub magic: u32,
    /// [`GaussianMapHeader::VERSION`] of the writer.
    pub schema_version: u32,
    /// Time of the snapshot, seconds.
    pub stamp: f64,
    /// Frame id of the keyframe that produced this snapshot.
    pub frame_id: u64,
    /// Number of Gaussians.
    pub count: u64,
}

impl GaussianMapHeader {
    /// Magic number "GMAP".
    pub const MAGIC: u32 = u32::from_le_bytes(*b"GMAP");
    /// Current schema version.
    pub const VERSION: u32 = 1;

    /// A header with magic and version filled in.
    pub fn new(stamp: f64, frame_id: u64, count: u64) -> Self {
        Self {
            magic: Self::MAGIC,
            schema_version: Self::VERSION,
            stamp,
            frame_id,
            count,
        }
    }

    fn layout(&self) -> Result<Layout, SchemaError> {
        let n = usize::try_from(self.count).ok();
        let sections = SECTION_WIDTHS.map(|w| n.and_then(|n| n.checked_mul(w * 4)));
        Layout::new(WHAT, core::mem::size_of::<Self>(), &sections)
    }

    /// Total payload size in bytes.
    pub fn payload_len(&self) -> Result<usize, SchemaError> {
        Ok(self.layout()?.total)
    }
}

/// Owned Gaussian map (structure of arrays).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct GaussianMap {
    /// Stamp of the snapshot, seconds.
    pub stamp: f64,
    /// Keyframe id.
    pub frame_id: u64,
    /// Means, xyz per Gaussian, world frame, metres.
    pub means: Vec<f32>,
    /// Colours, RGB per Gaussian (SH degree 0).
    pub colors: Vec<f32>,
    /// Rotations, quaternion xyzw per Gaussian (unnormalised).
    pub rotations: Vec<f32>,
    /// Opacity logits (through a sigmoid).
    pub opacities: Vec<f32>,
    /// Log-scales (through exp), xyz per Gaussian.
    pub log_scales: Vec<f32>,
}

impl GaussianMap {
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.opacities.len()
    }

    /// True when the map holds no Gaussian.
    pub fn is_empty(&self) -> bool {
        self.opacities.is_empty()
    }

    fn sections(&self) -> [&[f32]; 5] {
        [
            &self.means,
            &self.colors,
            &self.rotations,
            &self.opacities,
            &self.log_scales,
        ]
    }

    /// Encode into a fresh byte vector.
    pub fn encode(&self) -> Result<Vec<u8>, SchemaError> {
        let n = self.len();
        for (s, w) in self.sections().iter().zip(SECTION_WIDTHS) {
            if s.len() != n * w {
                return Err(SchemaError::InvalidHeader {
                    what: WHAT,
                    reason: format!(
                        "a section has {} floats, {n} Gaussians need {}",
                        s.len(),
                        n * w
                    ),
                });
            }
        }
        let header = GaussianMapHeader::new(self.stamp, self.frame_id, n as u64);
        let layout = header.layout()?;
        let mut out = vec![0u8; layout.total];
        out[..core::mem::size_of::<GaussianMapHeader>()]
            .copy_from_slice(bytemuck::bytes_of(&header));
        for (i, s) in self.sections().iter().enumerate() {
            out[layout.range(i)].copy_from_slice(bytemuck::cast_slice(s));
        }
        Ok(out)
    }

    /// Decode (copying) from a payload.
    pub fn decode(bytes: &[u8]) -> Result<Self, SchemaError> {
        let v = GaussianMapView::parse(bytes)?;
        Ok(Self {
            stamp: v.header.stamp,
            frame_id: v.header.frame_id,
            means: v.section(0).into_owned(),
            colors: v.section(1).into_owned(),
            rotations: v.section(2).into_owned(),
            opacities: v.section(3).into_owned(),
            log_scales: v.section(4).into_owned(),
        })
    }
}

/// Read view of a Gaussian map payload.
#[derive(Debug, Clone)]
pub struct GaussianMapView<'a> {
    /// The header.
    pub header: GaussianMapHeader,
    sections: [&'a [u8]; 5],
}

impl<'a> GaussianMapView<'a> {
    /// Parse a payload, checking magic, version and lengths.
    pub fn parse(bytes: &'a [u8]) -> Result<Self, SchemaError> {
        let header: GaussianMapHeader = read_header(
            WHAT,
            bytes,
            |h: &GaussianMapHeader| (h.magic, h.schema_version),
            GaussianMapHeader::MAGIC,
            GaussianMapHeader::VERSION,
        )?;
        let layout = header.layout()?;
        check_len(WHAT, bytes, layout.total)?;
        Ok(Self {
            header,
            sections: core::array::from_fn(|i| &bytes[layout.range(i)]),
        })
    }

    fn section(&self, i: usize) -> Cow<'a, [f32]> {
        cast_or_copy(self.sections[i])
    }

    /// Means, xyz per Gaussian.
    pub fn means(&self) -> Cow<'a, [f32]> {
        self.section(0)
    }
    /// Colours, RGB per Gaussian.
    pub fn colors(&self) -> Cow<'a, [f32]> {
        self.section(1)
    }
    /// Rotations, xyzw per Gaussian.
    pub fn rotations(&self) -> Cow<'a, [f32]> {
        self.section(2)
    }
    /// Opacity logits.
    pub fn opacities(&self) -> Cow<'a, [f32]> {
        self.section(3)
    }
    /// Log-scales, xyz per Gaussian.
    pub fn log_scales(&self) -> Cow<'a, [f32]> {
        self.section(4)
    }
}

/// Mutable in-place view of a Gaussian map payload, for writing into a loaned sample.
#[derive(Debug)]
pub struct GaussianMapMut<'a> {
    /// Means to fill.
    pub means: &'a mut [f32],
    /// Colours to fill.
    pub colors: &'a mut [f32],
    /// Rotations to fill.
    pub rotations: &'a mut [f32],
    /// Opacity logits to fill.
    pub opacities: &'a mut [f32],
    /// Log-scales to fill.
    pub log_scales: &'a mut [f32],
}

impl<'a> GaussianMapMut<'a> {
    /// Write `header` into `buf` (exactly [`GaussianMapHeader::payload_len`] bytes, 8-byte aligned)
    /// and return the slices to fill.
    pub fn init(buf: &'a mut [u8], header: GaussianMapHeader) -> Result<Self, SchemaError> {
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
        buf[..core::mem::size_of::<GaussianMapHeader>()]
            .copy_from_slice(bytemuck::bytes_of(&header));
        let mut rest = &mut buf[layout.offsets[0]..];
        let mut consumed = layout.offsets[0];
        let mut out: Vec<&'a mut [f32]> = Vec::with_capacity(5);
        for i in 0..5 {
            let skip = layout.offsets[i] - consumed;
            let (_, tail) = rest.split_at_mut(skip);
            let (section, tail) = tail.split_at_mut(layout.lengths[i]);
            consumed = layout.offsets[i] + layout.lengths[i];
            out.push(cast_mut::<f32>(WHAT, section)?);
            rest = tail;
        }
        let [means, colors, rotations, opacities, log_scales]: [&'a mut [f32]; 5] =
            out.try_into().expect("five sections");
        Ok(Self {
            means,
            colors,
            rotations,
            opacities,
            log_scales,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(n: usize) -> GaussianMap {
        let f = |k: usize, s: f32| (0..n * k).map(|i| i as f32 * s).collect::<Vec<_>>();
        GaussianMap {
            stamp: 3.5,
            frame_id: 11,
            means: f(3, 0.5),
            colors: f(3, 0.01),
            rotations: f(4, 0.1),
            opacities: f(1, -0.2),
            log_scales: f(3, -0.03),
        }
    }

    #[test]
    fn round_trip_and_in_place_agree() {
        let map = sample(5);
        let bytes = map.encode().unwrap();
        assert_eq!(GaussianMap::decode(&bytes).unwrap(), map);
        let header = GaussianMapHeader::new(3.5, 11, 5);
        let mut storage = vec![0u64; header.payload_len().unwrap() / 8];
        let buf: &mut [u8] = bytemuck::cast_slice_mut(&mut storage);
        let m = GaussianMapMut::init(buf, header).unwrap();
        m.means.copy_from_slice(&map.means);
        m.colors.copy_from_slice(&map.colors);
        m.rotations.copy_from_slice(&map.rotations);
        m.opacities.copy_from_slice(&map.opacities);
        m.log_scales.copy_from_slice(&map.log_scales);
        assert_eq!(buf, bytes.as_slice());
    }

    #[test]
    fn empty_map_and_bad_payloads() {
        let empty = GaussianMap::default();
        assert_eq!(
            GaussianMap::decode(&empty.encode().unwrap()).unwrap(),
            empty
        );
        let bytes = sample(3).encode().unwrap();
        assert!(matches!(
            GaussianMap::decode(&bytes[..bytes.len() - 4]),
            Err(SchemaError::Truncated { .. })
        ));
        let mut huge = bytes.clone();
        huge[24..32].copy_from_slice(&u64::MAX.to_le_bytes());
        assert!(GaussianMap::decode(&huge).is_err());
        let mut bad = sample(3);
        bad.rotations.pop();
        assert!(bad.encode().is_err());
    }
}
