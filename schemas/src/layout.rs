//! Offsets of the slices that follow a `#[repr(C)]` header in a large payload.
//! Every section starts on an 8-byte boundary, so typed views of f32/f64 slices are aligned
//! whenever the buffer itself is 8-byte aligned (iceoryx2 samples are).

use crate::SchemaError;

/// Round `n` up to the next multiple of 8.
pub(crate) fn align8(n: usize) -> usize {
    n.div_ceil(8) * 8
}

/// Byte ranges of the sections of a payload: header first, then each slice.
pub(crate) struct Layout {
    /// Start offset of each section after the header.
    pub offsets: Vec<usize>,
    /// Byte length of each section (unpadded).
    pub lengths: Vec<usize>,
    /// Total byte length including padding.
    pub total: usize,
}

impl Layout {
    /// Layout of a header of `header_len` bytes followed by sections of `section_bytes` bytes.
    pub fn new(
        what: &'static str,
        header_len: usize,
        section_bytes: &[Option<usize>],
    ) -> Result<Self, SchemaError> {
        let mut offset = align8(header_len);
        let mut offsets = Vec::with_capacity(section_bytes.len());
        let mut lengths = Vec::with_capacity(section_bytes.len());
        for bytes in section_bytes {
            let bytes = bytes.ok_or_else(|| SchemaError::InvalidHeader {
                what,
                reason: "slice sizes overflow".into(),
            })?;
            offsets.push(offset);
            lengths.push(bytes);
            offset = offset
                .checked_add(bytes)
                .and_then(|o| o.checked_add(7))
                .map(|o| o / 8 * 8)
                .ok_or_else(|| SchemaError::InvalidHeader {
                    what,
                    reason: "total size overflows".into(),
                })?;
        }
        Ok(Self {
            offsets,
            lengths,
            total: offset,
        })
    }

    /// Byte range of section `i`.
    pub fn range(&self, i: usize) -> core::ops::Range<usize> {
        self.offsets[i]..self.offsets[i] + self.lengths[i]
    }

    /// Zero the padding of `buf` (a payload of this layout whose header is `header_len` bytes):
    /// after the header, between sections and after the last. Producers write in place into
    /// reused shared-memory samples, whose old bytes would otherwise leak into the padding and
    /// make equal payloads differ byte for byte (and break bit-exact replay).
    pub fn zero_padding(&self, buf: &mut [u8], header_len: usize) {
        let mut end = header_len;
        for (&offset, &length) in self.offsets.iter().zip(&self.lengths) {
            buf[end..offset].fill(0);
            end = offset + length;
        }
        buf[end..self.total].fill(0);
    }
}

/// Checked `a * b * c` in usize.
pub(crate) fn mul(a: usize, b: usize, c: usize) -> Option<usize> {
    a.checked_mul(b)?.checked_mul(c)
}

/// Read a Pod header from the start of `bytes` (unaligned read), checking length, magic and version.
pub(crate) fn read_header<H: bytemuck::Pod>(
    what: &'static str,
    bytes: &[u8],
    magic_version: impl Fn(&H) -> (u32, u32),
    expected_magic: u32,
    expected_version: u32,
) -> Result<H, SchemaError> {
    let size = core::mem::size_of::<H>();
    if bytes.len() < 8 {
        return Err(SchemaError::Truncated {
            what,
            needed: size,
            got: bytes.len(),
        });
    }
    // Magic and version are the first two u32 of every header: check them before the length, so a
    // payload from another type or version is named as such.
    let magic = u32::from_le_bytes(bytes[0..4].try_into().expect("4 bytes"));
    if magic != expected_magic {
        return Err(SchemaError::BadMagic {
            what,
            expected: expected_magic,
            found: magic,
        });
    }
    let version = u32::from_le_bytes(bytes[4..8].try_into().expect("4 bytes"));
    if version != expected_version {
        return Err(SchemaError::VersionMismatch {
            what,
            expected: expected_version,
            found: version,
        });
    }
    if bytes.len() < size {
        return Err(SchemaError::Truncated {
            what,
            needed: size,
            got: bytes.len(),
        });
    }
    let header: H = bytemuck::pod_read_unaligned(&bytes[..size]);
    debug_assert_eq!(magic_version(&header), (magic, version));
    Ok(header)
}

/// Check a payload is at least `needed` bytes.
pub(crate) fn check_len(
    what: &'static str,
    bytes: &[u8],
    needed: usize,
) -> Result<(), SchemaError> {
    if bytes.len() < needed {
        return Err(SchemaError::Truncated {
            what,
            needed,
            got: bytes.len(),
        });
    }
    Ok(())
}

/// View `bytes` as a slice of `T`, borrowing when aligned and copying otherwise.
pub(crate) fn cast_or_copy<T: bytemuck::Pod>(bytes: &[u8]) -> std::borrow::Cow<'_, [T]> {
    match bytemuck::try_cast_slice::<u8, T>(bytes) {
        Ok(s) => std::borrow::Cow::Borrowed(s),
        Err(_) => std::borrow::Cow::Owned(
            bytes
                .chunks_exact(core::mem::size_of::<T>())
                .map(bytemuck::pod_read_unaligned)
                .collect(),
        ),
    }
}

/// View a mutable byte range as `&mut [T]`; the buffer must be aligned for `T`.
pub(crate) fn cast_mut<'a, T: bytemuck::Pod>(
    what: &'static str,
    bytes: &'a mut [u8],
) -> Result<&'a mut [T], SchemaError> {
    bytemuck::try_cast_slice_mut(bytes).map_err(|e| SchemaError::Buffer {
        what,
        reason: format!("cannot view as {}: {e}", core::any::type_name::<T>()),
    })
}
