//! Column-wise delta of Gaussian-map payloads in recordings: the layout codec this crate registers
//! with the runtime's recorder under tag [`MAP_COLUMNS_TAG`] ([`register_recording_codecs`];
//! `activemap_runtime::delta`).
//!
//! Why: at each keyframe the map grows (new Gaussians appended), some Gaussians are pruned and
//! the optimised ones move a little, so the payload's length changes and the byte-run delta
//! stores it in full: on the README's main episode those full maps were most of the recording.
//! Gaussians keep their id for life, so this codec matches each Gaussian of the new map to the
//! previous map's Gaussian of the same id and stores, per f32 column, the XOR of the two bit
//! patterns (zero for an untouched Gaussian; sign, exponent and top mantissa bits zero for a
//! slightly moved one), with the bytes of each column split into planes (byte 0 of every value,
//! then byte 1, …) so that the zeros line up for the chunk compressor. Ids are stored as
//! differences to the previous id (1 for consecutive ids), in planes too. Nothing is lost: the
//! header, the padding bytes and every value come back bit for bit.
//!
//! Layout after the tag and the payload length (u64): the header region (the header and its
//! padding), the id section (planes of the wrapping id differences), the bytes after it, then
//! each f32 section (planes of the XORs) followed by the padding bytes before the next section.
//! Both sides take as base the previous payload only when it parses as a map; otherwise every
//! Gaussian is stored against zero.

use std::collections::HashMap;
use std::ops::Range;

use activemap_schemas::{GaussianMapHeader, GaussianMapView, SECTION_WIDTHS};

use activemap_runtime::delta::{DeltaError, LayoutCodec};

/// The delta tag of Gaussian maps stored column by column (tag 2 since recordings first had it,
/// so older recordings read back unchanged).
pub const MAP_COLUMNS_TAG: u8 = 2;

/// The Gaussian-map codec (a unit type: the registry holds a `'static` reference to it).
pub struct GaussianMapColumns;

/// The one instance the registry refers to.
static MAP_COLUMNS: GaussianMapColumns = GaussianMapColumns;

impl LayoutCodec for GaussianMapColumns {
    fn encode(&self, previous: Option<&[u8]>, next: &[u8], out: &mut Vec<u8>) -> bool {
        encode(previous, next, out)
    }
    fn decode(&self, previous: Option<&[u8]>, body: &[u8]) -> Result<Vec<u8>, DeltaError> {
        decode(previous, body)
    }
}

/// Registers the recording codecs of this crate's message layouts (the Gaussian map's) with the
/// runtime, for the whole process. Call it before recording or reading a recording: the CLI does
/// at start, and a reader without it is told which tag it lacks. Idempotent.
pub fn register_recording_codecs() {
    activemap_runtime::delta::register_codec(
        MAP_COLUMNS_TAG,
        activemap_schemas::MessageKind::GaussianMap,
        &MAP_COLUMNS,
    )
    .expect("tag 2 and Gaussian maps are this codec's alone");
}

fn invalid(message: String) -> DeltaError {
    DeltaError::InvalidLayout {
        tag: MAP_COLUMNS_TAG,
        message,
    }
}

/// A payload's sections as the codec sees them.
struct MapLayout {
    count: usize,
    /// The five f32 sections then the ids.
    ranges: [Range<usize>; 6],
}

/// The layout of a payload that is a whole, valid Gaussian map; `None` otherwise.
fn layout_of(payload: &[u8]) -> Option<MapLayout> {
    let view = GaussianMapView::parse(payload).ok()?;
    let ranges = view.header.section_ranges().ok()?;
    Some(MapLayout {
        count: view.header.count as usize,
        ranges,
    })
}

fn u32_at(bytes: &[u8], k: usize) -> u32 {
    u32::from_le_bytes(bytes[4 * k..4 * k + 4].try_into().unwrap_or([0; 4]))
}

fn u64_at(bytes: &[u8], k: usize) -> u64 {
    u64::from_le_bytes(bytes[8 * k..8 * k + 8].try_into().unwrap_or([0; 8]))
}

/// For each Gaussian of `next_ids`, the index of the Gaussian with the same id in `prev_ids`.
/// Both are usually ascending (ids are handed out in order): then a merge walk; otherwise a
/// hash map (the last of a repeated id wins, on both sides alike).
fn match_ids(prev_ids: &[u64], next_ids: &[u64]) -> Vec<Option<usize>> {
    let ascending = |ids: &[u64]| ids.windows(2).all(|w| w[0] < w[1]);
    if ascending(prev_ids) && ascending(next_ids) {
        let mut j = 0;
        next_ids
            .iter()
            .map(|id| {
                while j < prev_ids.len() && prev_ids[j] < *id {
                    j += 1;
                }
                (j < prev_ids.len() && prev_ids[j] == *id).then_some(j)
            })
            .collect()
    } else {
        let index: HashMap<u64, usize> = prev_ids
            .iter()
            .enumerate()
            .map(|(j, &id)| (id, j))
            .collect();
        next_ids.iter().map(|id| index.get(id).copied()).collect()
    }
}

/// The bits a value is stored against: component `c` of the matched previous Gaussian `j` in
/// its section (of `w` floats per Gaussian), or zero for a new Gaussian or without a base.
fn reference(prev_section: Option<&[u8]>, j: Option<usize>, w: usize, c: usize) -> u32 {
    match (j, prev_section) {
        (Some(j), Some(prev)) => u32_at(prev, j * w + c),
        _ => 0,
    }
}

fn ids_of(payload: &[u8], layout: &MapLayout) -> Vec<u64> {
    let section = &payload[layout.ranges[5].clone()];
    (0..layout.count).map(|k| u64_at(section, k)).collect()
}

/// Encodes `next` (which must be a valid map: returns false and writes nothing otherwise)
/// against `previous`, appending the tag-less body to `out`.
fn encode(previous: Option<&[u8]>, next: &[u8], out: &mut Vec<u8>) -> bool {
    let Some(layout) = layout_of(next) else {
        return false;
    };
    let base = previous.and_then(|p| layout_of(p).map(|l| (p, l)));
    let n = layout.count;
    let next_ids = ids_of(next, &layout);
    let matched = match &base {
        Some((p, l)) => match_ids(&ids_of(p, l), &next_ids),
        None => vec![None; n],
    };
    let r = &layout.ranges;
    out.extend_from_slice(&(next.len() as u64).to_le_bytes());
    out.extend_from_slice(&next[..r[0].start]);
    // Ids: wrapping differences, in 8 planes.
    let start = out.len();
    out.resize(start + 8 * n, 0);
    let mut last = 0u64;
    for (k, &id) in next_ids.iter().enumerate() {
        let d = id.wrapping_sub(last).to_le_bytes();
        last = id;
        for (b, byte) in d.into_iter().enumerate() {
            out[start + b * n + k] = byte;
        }
    }
    out.extend_from_slice(&next[r[5].end..]);
    // f32 sections: XOR against the matched Gaussian, in 4 planes, then the padding after.
    for (s, &w) in SECTION_WIDTHS.iter().enumerate() {
        let cur = &next[r[s].clone()];
        let prev_section = base.as_ref().map(|(p, l)| &p[l.ranges[s].clone()]);
        let values = n * w;
        let start = out.len();
        out.resize(start + 4 * values, 0);
        for (i, j) in matched.iter().enumerate() {
            for c in 0..w {
                let k = i * w + c;
                let x = (u32_at(cur, k) ^ reference(prev_section, *j, w, c)).to_le_bytes();
                for (b, byte) in x.into_iter().enumerate() {
                    out[start + b * values + k] = byte;
                }
            }
        }
        out.extend_from_slice(&next[r[s].end..r[s + 1].start]);
    }
    true
}

/// Reads `len` bytes at `*at` of `data`, advancing `at`.
fn take<'a>(
    data: &'a [u8],
    at: &mut usize,
    len: usize,
    what: &'static str,
) -> Result<&'a [u8], DeltaError> {
    let bytes = at
        .checked_add(len)
        .and_then(|end| data.get(*at..end))
        .ok_or(DeltaError::Truncated(what))?;
    *at += len;
    Ok(bytes)
}

/// Decodes a body written by [`encode`] (after its tag) given the previous payload.
fn decode(previous: Option<&[u8]>, data: &[u8]) -> Result<Vec<u8>, DeltaError> {
    let mut at = 0;
    let total = u64::from_le_bytes(
        take(data, &mut at, 8, "map payload length")?
            .try_into()
            .unwrap_or([0; 8]),
    );
    let header =
        GaussianMapHeader::read(&data[at..]).map_err(|e| invalid(format!("header: {e}")))?;
    let expected = header.payload_len().map_err(|e| invalid(e.to_string()))?;
    if expected as u64 != total {
        return Err(invalid(format!(
            "the header makes {expected} bytes, the message says {total}"
        )));
    }
    let r = header
        .section_ranges()
        .map_err(|e| invalid(e.to_string()))?;
    let n = header.count as usize;
    // The body is a rearrangement of the payload: exactly as long. Checked before anything is
    // allocated for it.
    if (data.len() - at) as u64 != total {
        return Err(invalid(format!(
            "{} bytes of body for a map of {total} bytes",
            data.len() - at
        )));
    }
    let mut out = vec![0u8; total as usize];
    out[..r[0].start].copy_from_slice(take(data, &mut at, r[0].start, "map header")?);
    let planes = take(data, &mut at, 8 * n, "map ids")?;
    let mut next_ids = Vec::with_capacity(n);
    let mut last = 0u64;
    for k in 0..n {
        let d = u64::from_le_bytes(std::array::from_fn(|b| planes[b * n + k]));
        last = last.wrapping_add(d);
        next_ids.push(last);
        out[r[5].start + 8 * k..r[5].start + 8 * k + 8].copy_from_slice(&last.to_le_bytes());
    }
    let tail = total as usize - r[5].end;
    out[r[5].end..].copy_from_slice(take(data, &mut at, tail, "map tail")?);
    let base = previous.and_then(|p| layout_of(p).map(|l| (p, l)));
    let matched = match &base {
        Some((p, l)) => match_ids(&ids_of(p, l), &next_ids),
        None => vec![None; n],
    };
    for (s, &w) in SECTION_WIDTHS.iter().enumerate() {
        let values = n * w;
        let planes = take(data, &mut at, 4 * values, "map section")?;
        let prev_section = base.as_ref().map(|(p, l)| &p[l.ranges[s].clone()]);
        for (i, j) in matched.iter().enumerate() {
            for c in 0..w {
                let k = i * w + c;
                let x = u32::from_le_bytes(std::array::from_fn(|b| planes[b * values + k]));
                let o = r[s].start + 4 * k;
                let v = x ^ reference(prev_section, *j, w, c);
                out[o..o + 4].copy_from_slice(&v.to_le_bytes());
            }
        }
        let gap = r[s + 1].start - r[s].end;
        out[r[s].end..r[s + 1].start].copy_from_slice(take(data, &mut at, gap, "map padding")?);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_runtime::delta::{decode as decode_any, encode_kind};
    use activemap_schemas::{GaussianMap, MessageKind};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_map(rng: &mut ChaCha8Rng, frame_id: u64, ids: Vec<u64>) -> GaussianMap {
        let n = ids.len();
        let mut floats =
            |k: usize| -> Vec<f32> { (0..k * n).map(|_| rng.random_range(-3.0..3.0)).collect() };
        GaussianMap {
            stamp: frame_id as f64 * 0.1,
            frame_id,
            keyframe_id: Some(frame_id / 5),
            means: floats(3),
            colors: floats(3),
            rotations: floats(4),
            opacities: floats(1),
            log_scales: floats(3),
            ids,
        }
    }

    /// The map encoded, with random bytes in its padding (shared memory does not zero it).
    fn payload(rng: &mut ChaCha8Rng, map: &GaussianMap) -> Vec<u8> {
        let mut bytes = map.encode().unwrap();
        let header = GaussianMapHeader::read(&bytes).unwrap();
        let r = header.section_ranges().unwrap();
        let mut gaps = Vec::new();
        gaps.push(std::mem::size_of::<GaussianMapHeader>()..r[0].start);
        gaps.extend((0..5).map(|s| r[s].end..r[s + 1].start));
        gaps.push(r[5].end..bytes.len());
        for gap in gaps {
            for b in &mut bytes[gap] {
                *b = rng.random();
            }
        }
        bytes
    }

    fn roundtrip(prev: Option<&[u8]>, next: &[u8]) -> Vec<u8> {
        register_recording_codecs();
        let mut enc = Vec::new();
        encode_kind(MessageKind::GaussianMap, prev, next, &mut enc);
        assert_eq!(decode_any(prev, &enc).unwrap(), next, "bit for bit");
        enc
    }

    #[test]
    fn growing_pruned_and_optimised_maps_come_back_bit_for_bit() {
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        let mut map = random_map(&mut rng, 0, (0..400).collect());
        let mut next_id = 400u64;
        let mut prev: Option<Vec<u8>> = None;
        for step in 1..40u64 {
            // Optimised: a third of the Gaussians move a little.
            for v in map
                .means
                .iter_mut()
                .chain(map.colors.iter_mut())
                .chain(map.log_scales.iter_mut())
            {
                if rng.random_bool(0.33) {
                    *v += rng.random_range(-1e-3..1e-3);
                }
            }
            // Pruned: a few go.
            let keep: Vec<bool> = (0..map.len()).map(|_| !rng.random_bool(0.05)).collect();
            let filter = |v: &Vec<f32>, w: usize| -> Vec<f32> {
                v.chunks(w)
                    .zip(&keep)
                    .filter(|(_, k)| **k)
                    .flat_map(|(c, _)| c.to_vec())
                    .collect()
            };
            let ids: Vec<u64> = map
                .ids
                .iter()
                .zip(&keep)
                .filter(|(_, k)| **k)
                .map(|(i, _)| *i)
                .collect();
            let mut kept = GaussianMap {
                stamp: step as f64,
                frame_id: step,
                keyframe_id: Some(step),
                means: filter(&map.means, 3),
                colors: filter(&map.colors, 3),
                rotations: filter(&map.rotations, 4),
                opacities: filter(&map.opacities, 1),
                log_scales: filter(&map.log_scales, 3),
                ids,
            };
            // Grown: new Gaussians appended with fresh ids.
            let fresh: Vec<u64> = (0..rng.random_range(0..60)).map(|k| next_id + k).collect();
            next_id += fresh.len() as u64;
            let new = random_map(&mut rng, step, fresh);
            kept.means.extend(new.means);
            kept.colors.extend(new.colors);
            kept.rotations.extend(new.rotations);
            kept.opacities.extend(new.opacities);
            kept.log_scales.extend(new.log_scales);
            kept.ids.extend(new.ids);
            // Every 7th step the order is shuffled (ids no longer ascending: the hash-map match).
            if step % 7 == 0 {
                kept.ids.reverse();
            }
            map = kept;
            let bytes = payload(&mut rng, &map);
            let enc = roundtrip(prev.as_deref(), &bytes);
            assert_eq!(
                enc[0], MAP_COLUMNS_TAG,
                "step {step}: a changed map goes column-wise"
            );
            // The same map republished with a new frame id: a few bytes of runs.
            let mut again = bytes.clone();
            again[16] ^= 1;
            let small = roundtrip(Some(&bytes), &again);
            assert!(small.len() < 100, "republished: {} bytes", small.len());
            prev = Some(bytes);
        }
    }

    #[test]
    fn untouched_and_slightly_moved_gaussians_become_zero_bytes() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let map = random_map(&mut rng, 1, (0..2000).collect());
        let base = map.encode().unwrap();
        let mut moved = map.clone();
        moved.frame_id = 2;
        // 20 % of the Gaussians move by a relative 1e-4; 200 new ones are appended.
        for (i, v) in moved.means.iter_mut().enumerate() {
            if (i / 3) % 5 == 0 {
                *v *= 1.0 + 1e-4;
            }
        }
        let extra = random_map(&mut rng, 2, (2000..2200).collect());
        moved.means.extend(extra.means);
        moved.colors.extend(extra.colors);
        moved.rotations.extend(extra.rotations);
        moved.opacities.extend(extra.opacities);
        moved.log_scales.extend(extra.log_scales);
        moved.ids.extend(extra.ids);
        let next = moved.encode().unwrap();
        let enc = roundtrip(Some(&base), &next);
        let zeros = |b: &[u8]| b.iter().filter(|&&x| x == 0).count() as f64 / b.len() as f64;
        // Raw floats are rarely zero bytes (the ids are); the column delta is mostly zeros (the new 9 % and
        // the low bytes of the moved ones are what is left).
        assert!(zeros(&next) < 0.2, "raw {:.3}", zeros(&next));
        assert!(zeros(&enc) > 0.8, "column delta {:.3}", zeros(&enc));
    }

    #[test]
    fn malformed_map_messages_are_errors_not_panics() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let a = random_map(&mut rng, 1, (0..50).collect()).encode().unwrap();
        let b = random_map(&mut rng, 2, (10..70).collect())
            .encode()
            .unwrap();
        let enc = roundtrip(Some(&a), &b);
        for cut in 1..enc.len() {
            assert!(decode_any(Some(&a), &enc[..cut]).is_err(), "cut at {cut}");
        }
        let mut longer = enc.clone();
        longer.push(0);
        assert!(matches!(
            decode_any(Some(&a), &longer),
            Err(DeltaError::InvalidLayout { .. })
        ));
        let mut bad_total = enc.clone();
        bad_total[1] ^= 8;
        assert!(matches!(
            decode_any(Some(&a), &bad_total),
            Err(DeltaError::InvalidLayout { .. })
        ));
        // A base that is not a map: stored and read against zero, still exact.
        let not_a_map = vec![7u8; 33];
        roundtrip(Some(&not_a_map), &b);
        roundtrip(None, &b);
        // A payload that is not a map goes through the byte-run delta.
        let enc = roundtrip(Some(&a), &not_a_map);
        assert_ne!(enc[0], MAP_COLUMNS_TAG);
    }
}
