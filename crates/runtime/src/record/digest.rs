//! Digests of payloads: what the maps are recorded as, and what the replay compares.

/// A payload as the streaming replay compares it: its length and its 128-bit XXH3 hash.
pub type Digest = (usize, u128);

/// The 24-byte record of a digest on a [`super::DIGEST_ENCODING`] channel.
pub(super) fn encode_digest((len, hash): Digest) -> [u8; 24] {
    let mut out = [0u8; 24];
    out[..8].copy_from_slice(&(len as u64).to_le_bytes());
    out[8..].copy_from_slice(&hash.to_le_bytes());
    out
}

/// The digest in a [`DIGEST_ENCODING`] record (`None` unless it is exactly 24 bytes).
pub fn parse_digest(record: &[u8]) -> Option<Digest> {
    let record: &[u8; 24] = record.try_into().ok()?;
    let len = u64::from_le_bytes(record[..8].try_into().ok()?);
    let hash = u128::from_le_bytes(record[8..].try_into().ok()?);
    Some((usize::try_from(len).ok()?, hash))
}

/// The digest of `bytes` (what replay compares and [`DIGEST_ENCODING`] channels store).
///
/// XXH3-128 (not a cryptographic hash: it guards against accidents, not adversaries). The
/// recorder hashes every map it receives, so speed matters: measured on this machine, 17 GB/s
/// against 6 GB/s for the SipHash-1-3 used before.
pub fn digest(bytes: &[u8]) -> Digest {
    (bytes.len(), twox_hash::xxh3::hash128(bytes))
}
