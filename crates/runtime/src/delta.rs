//! Delta encoding of the large (shared-memory) payloads in recordings.
//!
//! Why: the mapper publishes its whole map every frame, and between keyframes the map does not
//! change, so most map messages repeat the previous one but for their header (measured on a
//! 300-step run of `dataflow.yaml`: 227 of 301 map messages, 617 of 800 MB). Each large message is
//! stored against the previous message of the same channel: when the lengths agree and the change
//! is small, only the changed blocks are written. Nothing is lost: decoding gives back every
//! payload byte for byte.
//!
//! Layout of one encoded message (integers little-endian):
//! - empty: an empty payload (the end-of-stream marker), stored as is;
//! - `0` then the payload: stored in full;
//! - `1`, then the payload length (u64), then runs of `offset (u64), length (u64), bytes` that
//!   replace the previous payload's bytes at those offsets;
//! - `2` or higher, then the payload stored by the [`LayoutCodec`] registered under that tag
//!   ([`register_codec`]): a codec that knows one message kind's layout (activemap-operators
//!   registers tag 2, Gaussian maps stored column by column against the previous map).
//!
//! Why a registry: the runtime moves bytes and knows no message's layout; whoever knows one (the
//! operators) registers a codec for it before recording or reading, and a reader without the
//! codec says which tag it lacks.

use std::sync::RwLock;

use activemap_schemas::MessageKind;
use thiserror::Error;

/// Tag of a payload stored in full.
const FULL: u8 = 0;
/// Tag of a payload stored as changed runs.
const RUNS: u8 = 1;
/// The first tag a [`LayoutCodec`] may be registered under.
pub const FIRST_CODEC_TAG: u8 = 2;
/// Payloads are compared in blocks of this many bytes; a run covers whole blocks.
const BLOCK: usize = 64;
/// Bytes of a run header (offset and length).
const RUN_HEADER: usize = 16;

/// A delta-encoded message that cannot be decoded.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum DeltaError {
    /// The message ends inside a field.
    #[error("delta message cut short: {0}")]
    Truncated(&'static str),
    /// A run-encoded message with no earlier message on its channel, or one of another length.
    #[error("delta message of {expected} bytes refers to a previous payload of {previous:?} bytes")]
    NoBase {
        /// Length the message declares.
        expected: u64,
        /// Length of the previous payload, if any.
        previous: Option<usize>,
    },
    /// A message of a layout codec whose body does not add up.
    #[error("delta message of codec tag {tag}: {message}")]
    InvalidLayout {
        /// The codec's tag.
        tag: u8,
        /// What does not add up.
        message: String,
    },
    /// A message of a layout codec this program has not registered.
    #[error("delta tag {0} is a layout codec this program has not registered")]
    NoCodec(u8),
    /// A run reaches past the end of the payload.
    #[error("delta run at {offset} of {len} bytes ends past the payload's {total} bytes")]
    RunOutOfRange {
        /// Run offset.
        offset: u64,
        /// Run length.
        len: u64,
        /// Payload length.
        total: u64,
    },
}

/// Encodes `next` against `previous` (the last non-empty payload of the same channel, if any)
/// into `out` (cleared first).
pub fn encode(previous: Option<&[u8]>, next: &[u8], out: &mut Vec<u8>) {
    out.clear();
    if next.is_empty() {
        return;
    }
    if let Some(prev) = previous.filter(|p| p.len() == next.len()) {
        out.push(RUNS);
        out.extend_from_slice(&(next.len() as u64).to_le_bytes());
        let mut start = 0;
        while start < next.len() {
            let end = (start + BLOCK).min(next.len());
            if prev[start..end] == next[start..end] {
                start = end;
                continue;
            }
            // A run of consecutive differing blocks (an equal block costs more to copy than a
            // new run header).
            let mut stop = end;
            while stop < next.len() {
                let block_end = (stop + BLOCK).min(next.len());
                if prev[stop..block_end] == next[stop..block_end] {
                    break;
                }
                stop = block_end;
            }
            out.extend_from_slice(&(start as u64).to_le_bytes());
            out.extend_from_slice(&((stop - start) as u64).to_le_bytes());
            out.extend_from_slice(&next[start..stop]);
            if out.len() > next.len() {
                break; // the runs already cost more than the payload
            }
            start = stop;
        }
        if out.len() <= next.len() {
            return;
        }
        out.clear();
    }
    out.push(FULL);
    out.extend_from_slice(next);
}

/// A lossless codec for the payloads of one message kind that knows their layout (e.g. a
/// Gaussian map stored column by column, Gaussian by id), used where the byte-run delta of
/// [`encode`] does poorly (a payload whose length changes).
pub trait LayoutCodec: Send + Sync {
    /// Appends `next`, encoded against `previous` (the channel's previous payload, if any), to
    /// `out`, which already holds the codec's tag. Returns false, with `out` left as it may be,
    /// when `next` is not a payload this codec understands.
    fn encode(&self, previous: Option<&[u8]>, next: &[u8], out: &mut Vec<u8>) -> bool;
    /// Decodes `body` (a message of [`LayoutCodec::encode`] without its tag) against `previous`;
    /// an error says what does not add up ([`DeltaError::InvalidLayout`]).
    fn decode(&self, previous: Option<&[u8]>, body: &[u8]) -> Result<Vec<u8>, DeltaError>;
}

/// One registered codec: its tag in encoded messages and the message kind it encodes.
#[derive(Clone, Copy)]
struct Registered {
    tag: u8,
    kind: MessageKind,
    codec: &'static dyn LayoutCodec,
}

static CODECS: RwLock<Vec<Registered>> = RwLock::new(Vec::new());

/// Registers `codec` for the payloads of `kind`, under `tag` (at least [`FIRST_CODEC_TAG`]), for
/// the whole process: recorders encode `kind` with it and readers decode `tag` with it.
/// Registering the same codec again is a no-op; another codec for a taken tag or kind is refused.
pub fn register_codec(
    tag: u8,
    kind: MessageKind,
    codec: &'static dyn LayoutCodec,
) -> Result<(), String> {
    if tag < FIRST_CODEC_TAG {
        return Err(format!(
            "delta tag {tag} is reserved (codecs start at {FIRST_CODEC_TAG})"
        ));
    }
    let mut codecs = CODECS.write().unwrap_or_else(|e| e.into_inner());
    if let Some(r) = codecs.iter().find(|r| r.tag == tag || r.kind == kind) {
        let same = r.tag == tag
            && r.kind == kind
            && std::ptr::addr_eq(r.codec as *const dyn LayoutCodec, codec);
        return if same {
            Ok(())
        } else {
            Err(format!(
                "delta tag {} is already the codec of {}",
                r.tag,
                r.kind.name()
            ))
        };
    }
    codecs.push(Registered { tag, kind, codec });
    Ok(())
}

fn codec_where(pred: impl Fn(&Registered) -> bool) -> Option<Registered> {
    let codecs = CODECS.read().unwrap_or_else(|e| e.into_inner());
    codecs.iter().find(|r| pred(r)).copied()
}

/// Encodes a payload of message kind `kind`: as changed runs when only a little changed (e.g. a
/// map republished between keyframes), otherwise with the codec registered for `kind`, if any;
/// a kind without one, or a payload its codec does not understand, goes through [`encode`].
pub fn encode_kind(kind: MessageKind, previous: Option<&[u8]>, next: &[u8], out: &mut Vec<u8>) {
    encode(previous, next, out);
    if out.len() <= next.len() / 4 {
        return;
    }
    let Some(r) = codec_where(|r| r.kind == kind) else {
        return;
    };
    out.clear();
    out.push(r.tag);
    if !r.codec.encode(previous, next, out) {
        encode(previous, next, out);
    }
}

/// Makes `base` equal to `next` after `next` was encoded into `encoded` against `base`:
/// for a run-encoded message only the changed runs are copied (a map republished between
/// keyframes costs its few changed blocks, not a copy of the whole map every frame).
pub fn update_base(base: &mut Vec<u8>, next: &[u8], encoded: &[u8]) {
    if encoded.first() == Some(&RUNS) && base.len() == next.len() {
        let mut at = 9;
        while at + RUN_HEADER <= encoded.len() {
            let offset = read_u64(encoded, at, "").unwrap_or(0) as usize;
            let len = read_u64(encoded, at + 8, "").unwrap_or(0) as usize;
            at += RUN_HEADER + len;
            base[offset..offset + len].copy_from_slice(&next[offset..offset + len]);
        }
        return;
    }
    base.clear();
    base.extend_from_slice(next);
}

fn read_u64(data: &[u8], at: usize, what: &'static str) -> Result<u64, DeltaError> {
    data.get(at..at + 8)
        .map(|b| u64::from_le_bytes(b.try_into().unwrap_or([0; 8])))
        .ok_or(DeltaError::Truncated(what))
}

/// Decodes one message of [`encode`] given the previous decoded non-empty payload of its
/// channel.
pub fn decode(previous: Option<&[u8]>, data: &[u8]) -> Result<Vec<u8>, DeltaError> {
    let Some((&tag, rest)) = data.split_first() else {
        return Ok(Vec::new());
    };
    match tag {
        FULL => Ok(rest.to_vec()),
        RUNS => {
            let total = read_u64(rest, 0, "payload length")?;
            let mut out = match previous {
                Some(p) if p.len() as u64 == total => p.to_vec(),
                _ => {
                    return Err(DeltaError::NoBase {
                        expected: total,
                        previous: previous.map(<[u8]>::len),
                    });
                }
            };
            let mut at = 8;
            while at < rest.len() {
                let offset = read_u64(rest, at, "run offset")?;
                let len = read_u64(rest, at + 8, "run length")?;
                at += RUN_HEADER;
                let end = offset
                    .checked_add(len)
                    .filter(|e| *e <= total)
                    .ok_or(DeltaError::RunOutOfRange { offset, len, total })?;
                let bytes = rest
                    .get(at..at + len as usize)
                    .ok_or(DeltaError::Truncated("run bytes"))?;
                out[offset as usize..end as usize].copy_from_slice(bytes);
                at += len as usize;
            }
            Ok(out)
        }
        tag => match codec_where(|r| r.tag == tag) {
            Some(r) => r.codec.decode(previous, rest),
            None => Err(DeltaError::NoCodec(tag)),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn roundtrip(prev: Option<&[u8]>, next: &[u8]) -> usize {
        let mut enc = Vec::new();
        encode(prev, next, &mut enc);
        assert_eq!(decode(prev, &enc).unwrap(), next);
        enc.len()
    }

    #[test]
    fn random_edits_round_trip_and_small_edits_stay_small() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut prev: Option<Vec<u8>> = None;
        for step in 0..300 {
            let next: Vec<u8> = match (&prev, step % 5) {
                // A new length: stored in full.
                (None, _) | (_, 0) => {
                    let n = rng.random_range(1..5000);
                    (0..n).map(|_| rng.random()).collect()
                }
                // Unchanged but for a few bytes anywhere, the last included.
                (Some(p), 1 | 2) => {
                    let mut n = p.clone();
                    for _ in 0..rng.random_range(0..4) {
                        let i = rng.random_range(0..n.len());
                        n[i] = n[i].wrapping_add(1);
                    }
                    let last = n.len() - 1;
                    n[last] ^= (step % 2) as u8;
                    n
                }
                // Most bytes changed: falls back to full.
                (Some(p), _) => p.iter().map(|b| b ^ rng.random::<u8>()).collect(),
            };
            let size = roundtrip(prev.as_deref(), &next);
            let changed = prev
                .as_ref()
                .filter(|p| p.len() == next.len())
                .map(|p| p.iter().zip(&next).filter(|(a, b)| a != b).count());
            // Every encoding costs at most one tag byte more than the payload, and a payload
            // with k changed bytes costs at most k runs of one block.
            assert!(size <= next.len() + 1);
            if let Some(k) = changed {
                assert!(size <= 9 + k * (RUN_HEADER + BLOCK), "{k} changes: {size}");
            }
            prev = Some(next);
        }
    }

    #[test]
    fn an_identical_payload_costs_nine_bytes_and_empty_stays_empty() {
        let p: Vec<u8> = (0..10_000u32).map(|i| (i * 7) as u8).collect();
        assert_eq!(roundtrip(Some(&p), &p), 9);
        assert_eq!(roundtrip(Some(&p), &[]), 0);
        assert_eq!(decode(Some(&p), &[]).unwrap(), Vec::<u8>::new());
        // A one-byte change in the last, partial block.
        let mut q = p.clone();
        q[9_999] = 1;
        assert_eq!(roundtrip(Some(&p), &q), 9 + RUN_HEADER + 10_000 % BLOCK);
    }

    #[test]
    fn the_base_follows_the_payloads_run_by_run_or_whole() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let mut base: Vec<u8> = (0..5000).map(|_| rng.random()).collect();
        for step in 0..50 {
            let mut next = base.clone();
            if step % 10 == 9 {
                next = (0..rng.random_range(1..6000))
                    .map(|_| rng.random())
                    .collect();
            } else {
                for _ in 0..rng.random_range(0..5) {
                    let i = rng.random_range(0..next.len());
                    next[i] ^= 0x55;
                }
            }
            let mut enc = Vec::new();
            encode(Some(&base), &next, &mut enc);
            update_base(&mut base, &next, &enc);
            assert_eq!(base, next, "step {step}");
        }
    }

    #[test]
    fn malformed_messages_are_errors_not_panics() {
        let p = vec![0u8; 100];
        let mut enc = Vec::new();
        let mut q = p.clone();
        q[50] = 9;
        encode(Some(&p), &q, &mut enc);
        assert_eq!(
            decode(None, &enc),
            Err(DeltaError::NoBase {
                expected: 100,
                previous: None
            })
        );
        assert!(matches!(
            decode(Some(&p[..99]), &enc),
            Err(DeltaError::NoBase { .. })
        ));
        for cut in 1..enc.len() {
            let r = decode(Some(&p), &enc[..cut]);
            assert!(
                r.is_err() || cut == 9,
                "cut at {cut} decoded to {:?}",
                r.map(|v| v.len())
            );
        }
        assert_eq!(decode(Some(&p), &[7, 1, 2]), Err(DeltaError::NoCodec(7)));
        let mut bad = vec![RUNS];
        bad.extend_from_slice(&100u64.to_le_bytes());
        bad.extend_from_slice(&90u64.to_le_bytes());
        bad.extend_from_slice(&20u64.to_le_bytes());
        bad.extend_from_slice(&[0; 20]);
        assert!(matches!(
            decode(Some(&p), &bad),
            Err(DeltaError::RunOutOfRange { offset: 90, .. })
        ));
        let mut huge = vec![RUNS];
        huge.extend_from_slice(&100u64.to_le_bytes());
        huge.extend_from_slice(&u64::MAX.to_le_bytes());
        huge.extend_from_slice(&2u64.to_le_bytes());
        assert!(matches!(
            decode(Some(&p), &huge),
            Err(DeltaError::RunOutOfRange { .. })
        ));
    }

    /// Stores a payload reversed (a stand-in with a layout of its own: every byte moves).
    struct Reversed;

    impl LayoutCodec for Reversed {
        fn encode(&self, _: Option<&[u8]>, next: &[u8], out: &mut Vec<u8>) -> bool {
            if next.len() < 8 {
                return false; // "not a payload it understands"
            }
            out.extend(next.iter().rev());
            true
        }
        fn decode(&self, _: Option<&[u8]>, body: &[u8]) -> Result<Vec<u8>, DeltaError> {
            Ok(body.iter().rev().copied().collect())
        }
    }

    static REVERSED: Reversed = Reversed;
    static OTHER: Reversed = Reversed;

    #[test]
    fn a_registered_codec_encodes_its_kind_and_decodes_its_tag() {
        let tag = 200;
        let kind = MessageKind::Counter;
        let mut enc = Vec::new();
        let p: Vec<u8> = (0..1000u32).map(|b| b as u8).collect();
        let q: Vec<u8> = (0..1200u32).map(|b| (b * 3) as u8).collect();
        register_codec(tag, kind, &REVERSED).unwrap();
        // Idempotent; a taken tag or kind, or a reserved tag, is refused.
        register_codec(tag, kind, &REVERSED).unwrap();
        assert!(register_codec(tag, MessageKind::Action, &OTHER).is_err());
        assert!(register_codec(201, kind, &OTHER).is_err());
        assert!(register_codec(1, MessageKind::Action, &OTHER).is_err());
        // A changed length: the codec; the same length, little changed (runs of at most a
        // quarter of the payload): runs.
        encode_kind(kind, Some(&p), &q, &mut enc);
        assert_eq!(enc[0], tag);
        assert_eq!(decode(Some(&p), &enc).unwrap(), q);
        let mut r = q.clone();
        r[5] = 0;
        encode_kind(kind, Some(&q), &r, &mut enc);
        assert_eq!(enc[0], RUNS);
        assert_eq!(decode(Some(&q), &enc).unwrap(), r);
        // A payload the codec refuses, and a kind without a codec, go through `encode`.
        encode_kind(kind, None, &[1, 2, 3], &mut enc);
        assert_eq!(enc, [FULL, 1, 2, 3]);
        encode_kind(MessageKind::RgbdFrame, Some(&p), &q, &mut enc);
        assert_eq!(enc[0], FULL);
        // A tag nobody registered names itself.
        let e = decode(None, &[201, 0]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "delta tag 201 is a layout codec this program has not registered"
        );
    }
}
