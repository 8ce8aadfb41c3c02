//! Gaussian map snapshot (SPEC §3): `#[repr(C)]` header, then the 14 parameters per Gaussian as
//! structure-of-arrays f32 slices: means (3), colours (3), rotations (4, xyzw unnormalised),
//! opacities (1, pre-sigmoid), log-scales (3); then the mapper's stable id of each Gaussian
//! (u64, increasing as Gaussians are added, surviving pruning), so that a consumer can follow
//! a Gaussian across snapshots (the Fisher scorer keeps its model information per id). Every
//! section starts on an 8-byte boundary, so the u64 ids are aligned whenever the buffer is.
//!
//! Version 2 added the ids section and the header's `keyframe_id`.

use std::borrow::Cow;

use bytemuck::{Pod, Zeroable};

use crate::SchemaError;
use crate::layout::{Layout, cast_mut, cast_or_copy, read_header};

const WHAT: &str = "GaussianMap";
/// Floats per Gaussian in each f32 section, in payload order: means, colors, rotations,
/// opacities, log_scales (the sixth section holds one u64 id per Gaussian).
pub const SECTION_WIDTHS: [usize; 5] = [3, 3, 4, 1, 3];
/// Index of the ids section in the layout.
const IDS: usize = 5;

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
    /// The last frame the snapshot includes (the mapper publishes one snapshot per frame).
    pub frame_id: u64,
    /// Number of Gaussians.
    pub count: u64,
    /// Frame id of the newest keyframe the map includes, i.e. the snapshot at which the map
    /// last changed ([`GaussianMapHeader::NO_KEYFRAME`] before the first keyframe). Snapshots
    /// with the same `keyframe_id` hold the same map.
    pub keyframe_id: u64,
}

impl GaussianMapHeader {
    /// Magic number "GMAP".
    pub const MAGIC: u32 = u32::from_le_bytes(*b"GMAP");
    /// Current schema version.
    pub const VERSION: u32 = 2;
    /// `keyframe_id` of a map no keyframe has changed yet (the empty start map).
    pub const NO_KEYFRAME: u64 = u64::MAX;

    /// A header with magic and version filled in; `keyframe_id` `None` is written as
    /// [`Self::NO_KEYFRAME`].
    pub fn new(stamp: f64, frame_id: u64, count: u64, keyframe_id: Option<u64>) -> Self {
        Self {
            magic: Self::MAGIC,
            schema_version: Self::VERSION,
            stamp,
            frame_id,
            count,
            keyframe_id: keyframe_id.unwrap_or(Self::NO_KEYFRAME),
        }
    }

    /// The newest keyframe the map includes, `None` before the first.
    pub fn keyframe(&self) -> Option<u64> {
        (self.keyframe_id != Self::NO_KEYFRAME).then_some(self.keyframe_id)
    }

    fn layout(&self) -> Result<Layout, SchemaError> {
        let n = usize::try_from(self.count).ok();
        let floats = SECTION_WIDTHS.map(|w| n.and_then(|n| n.checked_mul(w * 4)));
        let ids = n.and_then(|n| n.checked_mul(8));
        let sections = [floats[0], floats[1], floats[2], floats[3], floats[4], ids];
        Layout::new(WHAT, core::mem::size_of::<Self>(), &sections)
    }

    /// Total payload size in bytes.
    pub fn payload_len(&self) -> Result<usize, SchemaError> {
        Ok(self.layout()?.total)
    }

    /// Byte ranges of the six sections in a payload with this header: the five f32 sections of
    /// [`SECTION_WIDTHS`] then the u64 ids. Sections start 8-byte aligned; the bytes between
    /// them (and after the last) are padding.
    pub fn section_ranges(&self) -> Result<[core::ops::Range<usize>; 6], SchemaError> {
        let layout = self.layout()?;
        Ok(core::array::from_fn(|i| layout.range(i)))
    }

    /// Read and check (magic, version) the header at the start of a payload, without the rest.
    pub fn read(bytes: &[u8]) -> Result<Self, SchemaError> {
        read_header(
            WHAT,
            bytes,
            |h: &GaussianMapHeader| (h.magic, h.schema_version),
            Self::MAGIC,
            Self::VERSION,
        )
    }
}

/// Owned Gaussian map (structure of arrays).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct GaussianMap {
    /// Stamp of the snapshot, seconds.
    pub stamp: f64,
    /// The last frame the snapshot includes.
    pub frame_id: u64,
    /// The newest keyframe the map includes (`None` before the first).
    pub keyframe_id: Option<u64>,
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
    /// The mapper's stable id of each Gaussian.
    pub ids: Vec<u64>,
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
        const NAMES: [&str; 5] = ["means", "colors", "rotations", "opacities", "log_scales"];
        for ((s, w), name) in self.sections().iter().zip(SECTION_WIDTHS).zip(NAMES) {
            if s.len() != n * w {
                return Err(SchemaError::InvalidHeader {
                    what: WHAT,
                    reason: format!(
                        "section `{name}` has {} floats, {n} Gaussians need {}",
                        s.len(),
                        n * w
                    ),
                });
            }
        }
        if self.ids.len() != n {
            return Err(SchemaError::InvalidHeader {
                what: WHAT,
                reason: format!("{} ids for {n} Gaussians", self.ids.len()),
            });
        }
        let header = GaussianMapHeader::new(self.stamp, self.frame_id, n as u64, self.keyframe_id);
        let layout = header.layout()?;
        let mut out = vec![0u8; layout.total];
        out[..core::mem::size_of::<GaussianMapHeader>()]
            .copy_from_slice(bytemuck::bytes_of(&header));
        for (i, s) in self.sections().iter().enumerate() {
            out[layout.range(i)].copy_from_slice(bytemuck::cast_slice(s));
        }
        out[layout.range(IDS)].copy_from_slice(bytemuck::cast_slice(&self.ids));
        Ok(out)
    }

    /// Decode (copying) from a payload.
    pub fn decode(bytes: &[u8]) -> Result<Self, SchemaError> {
        let v = GaussianMapView::parse(bytes)?;
        Ok(Self {
            stamp: v.header.stamp,
            frame_id: v.header.frame_id,
            keyframe_id: v.header.keyframe(),
            means: v.section(0).into_owned(),
            colors: v.section(1).into_owned(),
            rotations: v.section(2).into_owned(),
            opacities: v.section(3).into_owned(),
            log_scales: v.section(4).into_owned(),
            ids: v.ids().into_owned(),
        })
    }
}

/// Read view of a Gaussian map payload.
#[derive(Debug, Clone)]
pub struct GaussianMapView<'a> {
    /// The header.
    pub header: GaussianMapHeader,
    sections: [&'a [u8]; 6],
}

impl<'a> GaussianMapView<'a> {
    /// Parse a payload, checking magic, version and that its length is exactly what the
    /// header's count makes (a corrupted count is an error, never a shifted read).
    pub fn parse(bytes: &'a [u8]) -> Result<Self, SchemaError> {
        let header: GaussianMapHeader = read_header(
            WHAT,
            bytes,
            |h: &GaussianMapHeader| (h.magic, h.schema_version),
            GaussianMapHeader::MAGIC,
            GaussianMapHeader::VERSION,
        )?;
        let layout = header.layout()?;
        if bytes.len() < layout.total {
            return Err(SchemaError::Truncated {
                what: WHAT,
                needed: layout.total,
                got: bytes.len(),
            });
        }
        if bytes.len() > layout.total {
            return Err(SchemaError::InvalidHeader {
                what: WHAT,
                reason: format!(
                    "payload has {} bytes but {} Gaussians (frame {}) make {}",
                    bytes.len(),
                    header.count,
                    header.frame_id,
                    layout.total
                ),
            });
        }
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
    /// The mapper's stable id of each Gaussian (borrowed when the payload is 8-byte aligned,
    /// copied otherwise).
    pub fn ids(&self) -> Cow<'a, [u64]> {
        cast_or_copy(self.sections[IDS])
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
    /// Stable ids to fill.
    pub ids: &'a mut [u64],
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
        let header_len = core::mem::size_of::<GaussianMapHeader>();
        buf[..header_len].copy_from_slice(bytemuck::bytes_of(&header));
        layout.zero_padding(buf, header_len);
        let mut rest = &mut buf[layout.offsets[0]..];
        let mut consumed = layout.offsets[0];
        let mut sections: Vec<&'a mut [u8]> = Vec::with_capacity(6);
        for i in 0..6 {
            let skip = layout.offsets[i] - consumed;
            let (_, tail) = rest.split_at_mut(skip);
            let (section, tail) = tail.split_at_mut(layout.lengths[i]);
            consumed = layout.offsets[i] + layout.lengths[i];
            sections.push(section);
            rest = tail;
        }
        let [means, colors, rotations, opacities, log_scales, ids]: [&'a mut [u8]; 6] =
            sections.try_into().expect("six sections");
        Ok(Self {
            means: cast_mut::<f32>(WHAT, means)?,
            colors: cast_mut::<f32>(WHAT, colors)?,
            rotations: cast_mut::<f32>(WHAT, rotations)?,
            opacities: cast_mut::<f32>(WHAT, opacities)?,
            log_scales: cast_mut::<f32>(WHAT, log_scales)?,
            ids: cast_mut::<u64>(WHAT, ids)?,
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
            keyframe_id: Some(9),
            means: f(3, 0.5),
            colors: f(3, 0.01),
            rotations: f(4, 0.1),
            opacities: f(1, -0.2),
            log_scales: f(3, -0.03),
            // Ids above 2^53 and with gaps (pruned Gaussians): exact u64s on the wire.
            ids: (0..n as u64).map(|i| (1 << 60) + 3 * i).collect(),
        }
    }

    /// Encoding, in-place writing and decoding agree byte for byte, ids and keyframe
    /// included; the view of an aligned payload borrows the ids. Written in place into a buffer
    /// full of old bytes (a reused shared-memory sample), the padding still comes out zero.
    #[test]
    fn round_trip_and_in_place_agree() {
        let map = sample(5);
        let bytes = map.encode().unwrap();
        assert_eq!(GaussianMap::decode(&bytes).unwrap(), map);
        let header = GaussianMapHeader::new(3.5, 11, 5, Some(9));
        let mut storage = vec![0xA5A5_A5A5_A5A5_A5A5u64; header.payload_len().unwrap() / 8];
        let buf: &mut [u8] = bytemuck::cast_slice_mut(&mut storage);
        let m = GaussianMapMut::init(buf, header).unwrap();
        m.means.copy_from_slice(&map.means);
        m.colors.copy_from_slice(&map.colors);
        m.rotations.copy_from_slice(&map.rotations);
        m.opacities.copy_from_slice(&map.opacities);
        m.log_scales.copy_from_slice(&map.log_scales);
        m.ids.copy_from_slice(&map.ids);
        assert_eq!(buf, bytes.as_slice());
        let view = GaussianMapView::parse(buf).unwrap();
        assert!(
            matches!(view.ids(), Cow::Borrowed(_)),
            "aligned ids are borrowed"
        );
        assert_eq!(view.ids().as_ref(), map.ids.as_slice());
        assert_eq!(view.header.keyframe(), Some(9));
    }

    /// The ids section starts on an 8-byte boundary for every count (the f32 sections before
    /// it have odd lengths for odd counts), and a misaligned payload is still read, by copy.
    #[test]
    fn ids_are_aligned_and_a_misaligned_payload_is_copied() {
        for n in [0u64, 1, 3, 7] {
            let layout = GaussianMapHeader::new(0.0, 0, n, None).layout().unwrap();
            assert_eq!(layout.offsets[IDS] % 8, 0, "count {n}");
            assert_eq!(layout.lengths[IDS], 8 * n as usize);
        }
        let map = sample(3);
        let bytes = map.encode().unwrap();
        let mut storage = vec![0u64; bytes.len() / 8 + 1];
        let shifted = &mut bytemuck::cast_slice_mut::<u64, u8>(&mut storage)[1..=bytes.len()];
        shifted.copy_from_slice(&bytes);
        let view = GaussianMapView::parse(shifted).unwrap();
        assert!(matches!(view.ids(), Cow::Owned(_)));
        assert_eq!(GaussianMap::decode(shifted).unwrap(), map);
        // Writing in place needs an aligned buffer: a clear error otherwise.
        let header = GaussianMapHeader::new(0.0, 0, 3, None);
        let e = GaussianMapMut::init(shifted, header).unwrap_err();
        assert!(matches!(e, SchemaError::Buffer { .. }), "{e}");
    }

    #[test]
    fn empty_map_and_bad_payloads() {
        let empty = GaussianMap::default();
        let bytes = empty.encode().unwrap();
        let back = GaussianMap::decode(&bytes).unwrap();
        assert_eq!(back, empty);
        assert_eq!(back.keyframe_id, None, "no keyframe survives as None");
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
        let e = bad.encode().unwrap_err().to_string();
        assert!(e.contains("`rotations`"), "{e}");
        let mut bad = sample(3);
        bad.ids.pop();
        let e = bad.encode().unwrap_err().to_string();
        assert!(e.contains("2 ids for 3 Gaussians"), "{e}");
        // A version-1 payload (no ids) is refused by version, not misread.
        let mut v1 = bytes.clone();
        v1[4..8].copy_from_slice(&1u32.to_le_bytes());
        assert_eq!(
            GaussianMap::decode(&v1).unwrap_err(),
            SchemaError::VersionMismatch {
                what: "GaussianMap",
                expected: 2,
                found: 1
            }
        );
    }

    /// A corrupted count: one more Gaussian than the payload holds is a truncation, one fewer
    /// leaves bytes over, which is refused too (naming both sizes) instead of reading the ids
    /// from the middle of the log-scales.
    #[test]
    fn a_corrupted_count_is_refused_either_way() {
        let bytes = sample(4).encode().unwrap();
        let mut more = bytes.clone();
        more[24..32].copy_from_slice(&5u64.to_le_bytes());
        assert!(matches!(
            GaussianMap::decode(&more),
            Err(SchemaError::Truncated { what: "GaussianMap", got, .. }) if got == bytes.len()
        ));
        let mut fewer = bytes.clone();
        fewer[24..32].copy_from_slice(&3u64.to_le_bytes());
        let e = GaussianMap::decode(&fewer).unwrap_err();
        assert!(matches!(e, SchemaError::InvalidHeader { .. }), "{e}");
        let msg = e.to_string();
        assert!(
            msg.contains(&format!("payload has {} bytes", bytes.len()))
                && msg.contains("3 Gaussians"),
            "{msg}"
        );
    }
}
