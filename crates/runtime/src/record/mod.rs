//! Recording every message of a run to MCAP (dataflow file and schemas embedded), reading it back,
//! and replaying one operator on its recorded inputs.
//!
//! The recorder never drops silently: Zenoh topics use a blocking FIFO (back-pressure up to the
//! producer), and shared-memory topics are checked for gaps in the producers' sequence numbers;
//! any gap is counted and reported per topic.
//!
//! Large payloads are stored delta-encoded against the previous payload of their channel
//! ([`crate::delta`], encoding [`DELTA_ENCODING`]). The outputs of built-in operators whose
//! kinds the launcher names ([`RecorderOutputs::digests`]; the CLI names Gaussian maps unless
//! `--record-maps full`) are stored as digests only ([`DIGEST_ENCODING`]): they are a
//! deterministic function of their producer's recorded inputs, so a reader that needs them
//! regenerates them by replaying the producer ([`RecordingReader::regenerate_with`]) and checks
//! each against its digest. [`read_recording`] gives back every other payload byte for byte, and
//! still reads recordings of plain [`LARGE_ENCODING`] channels.
//!
//! On top of that the file is chunked and each chunk is zstd-compressed (lossless, so replay stays
//! bit-exact): chunks of [`CHUNK_SIZE`] uncompressed bytes, closed at least every
//! [`FLUSH_INTERVAL`]. The writer holds the chunk being filled in memory, so a recorder killed
//! (SIGKILL) loses at most that chunk: the last second of the run, at most [`CHUNK_SIZE`] bytes.
//! Whatever reached the file reads back up to the cut, with [`Recording::truncated`] set.
//!
//! Readers stream: [`RecordingReader`] reads the file piece by piece, decompresses chunk by chunk
//! and keeps only the last payload of each channel it reads, so memory is about the largest
//! message, not the file; [`replay_recording`] feeds an operator input by input from it.
//! [`read_recording`] (everything in memory) is a convenience on top, for small recordings.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use activemap_schemas::{MessageKind, TransportClass};

use crate::RuntimeError;
use crate::dataflow::{Dataflow, DropPolicy};
use crate::derived::{Derived, DerivedMessage};
use crate::node::{RecordedInput, RunInfo, shm_limits};
use crate::transport::{ShmSubscriber, ZenohSubscriber, iox_node, topic_key};

mod digest;
mod reader;
mod replay;
mod writer;

pub use digest::*;
pub use reader::*;
pub use replay::*;
pub use writer::*;

/// Message encoding of small messages in recordings.
pub const SMALL_ENCODING: &str = "activemap/postcard-v";
/// Message encoding of large payloads stored as they are (recordings before delta encoding).
pub const LARGE_ENCODING: &str = "activemap/repr-c";
/// Message encoding of large payloads stored with [`crate::delta`] against the channel's previous
/// payload.
pub const DELTA_ENCODING: &str = "activemap/repr-c-delta";

/// Message encoding of a channel recorded as digests only: each payload is stored as its length
/// (u64, little endian) and 128-bit hash (u128, little endian), 24 bytes. Readers that need the
/// payloads regenerate them by replaying the channel's producer on its own recorded inputs
/// ([`Producer`]) and check each against its digest. The recorder uses it for the outputs of
/// built-in operators of the kinds in [`RecorderOutputs::digests`].
pub const DIGEST_ENCODING: &str = "activemap/digest-v1";

/// True for the encodings of the exact (replay) channels; false for the view channels, which
/// readers of this module skip.
pub fn is_replay_encoding(encoding: &str) -> bool {
    encoding.starts_with(SMALL_ENCODING)
        || encoding == LARGE_ENCODING
        || encoding == DELTA_ENCODING
        || encoding == DIGEST_ENCODING
}

/// Target uncompressed size of one chunk of a recording, in bytes.
///
/// 4 MiB: big enough for zstd to find the repetition between consecutive small messages and
/// inside the delta-encoded map runs, small enough that the writer's buffered chunk and the
/// reader's decompressed data stay a few MB. A message larger than this gets a chunk of its own.
pub const CHUNK_SIZE: u64 = 4 * 1024 * 1024;

/// The recorder closes the current chunk (and flushes the file) at least this often, so a crash
/// loses at most this much of the run, or [`CHUNK_SIZE`] bytes of messages, whichever is less.
pub const FLUSH_INTERVAL: Duration = Duration::from_secs(1);

/// Write a recording the way the recorder does (same writer options, metadata and encodings)
/// from `(topic, large, seq, payload)` messages, the topics in `digests` stored as digests: for
/// tests of the readers and the replay.
#[cfg(test)]
pub(crate) fn write_test_recording(
    path: &Path,
    dataflow_yaml: &str,
    max_steps: Option<u64>,
    messages: &[(&str, bool, u64, Vec<u8>)],
    digests: &[&str],
) {
    let mut writer = open_writer(File::create(path).unwrap()).unwrap();
    let mut meta = BTreeMap::new();
    meta.insert("dataflow_yaml".to_string(), dataflow_yaml.to_string());
    if let Some(n) = max_steps {
        meta.insert("max_steps".to_string(), n.to_string());
    }
    writer
        .write_metadata(&mcap::records::Metadata {
            name: "activemap.dataflow".into(),
            metadata: meta,
        })
        .unwrap();
    let schema = writer
        .add_schema("test", "activemap/text", b"test")
        .unwrap();
    let mut channels: BTreeMap<&str, (u16, Stored)> = BTreeMap::new();
    let mut encoded = Vec::new();
    for (topic, large, seq, bytes) in messages {
        let (id, stored) = match channels.get_mut(topic) {
            Some(c) => c,
            None => {
                let (encoding, stored) = if digests.contains(topic) {
                    (DIGEST_ENCODING.to_string(), Stored::Digest)
                } else if *large {
                    (DELTA_ENCODING.to_string(), Stored::Delta(Vec::new()))
                } else {
                    (format!("{SMALL_ENCODING}1"), Stored::Plain)
                };
                let id = writer
                    .add_channel(schema, topic, &encoding, &BTreeMap::new())
                    .unwrap();
                channels.entry(topic).or_insert((id, stored))
            }
        };
        let header = mcap::records::MessageHeader {
            channel_id: *id,
            sequence: *seq as u32,
            log_time: *seq,
            publish_time: *seq,
        };
        // Large test payloads go through the kind-aware entry point as Gaussian maps (no codec
        // is registered in the runtime's own tests, so as the byte-run delta stores them).
        let kind = if *large {
            MessageKind::GaussianMap
        } else {
            MessageKind::Counter
        };
        write_message(&mut writer, &header, kind, bytes, stored, &mut encoded).unwrap();
    }
    writer.finish().unwrap();
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng as _, SeedableRng as _};

    /// 300 steps: a large compressible "map" whose length changes every 50 steps (stored in full
    /// at each change, as runs of changed blocks otherwise), a small counter, then end of stream.
    fn messages() -> Vec<(&'static str, bool, u64, Vec<u8>)> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
        let mut out = Vec::new();
        let mut map = Vec::new();
        for step in 1..=300u64 {
            let len = 100_000 + (step / 50) as usize * 64;
            map.resize(len, 0);
            for (i, b) in map.iter_mut().enumerate().take(len / 2) {
                *b = (i % 251) as u8;
            }
            for _ in 0..20 {
                let i = rng.random_range(0..len);
                map[i] = rng.random();
            }
            out.push(("mapper/map", true, step, map.clone()));
            out.push(("counter/count", false, step, step.to_le_bytes().to_vec()));
        }
        out.push(("mapper/map", true, 301, Vec::new()));
        out
    }

    fn expected(messages: &[(&str, bool, u64, Vec<u8>)]) -> Vec<RecordedMessage> {
        messages
            .iter()
            .map(|(topic, _, seq, bytes)| RecordedMessage {
                topic: topic.to_string(),
                seq: *seq,
                bytes: bytes.clone(),
                digest_only: false,
            })
            .collect()
    }

    #[test]
    fn record_round_trips_bit_exact_through_both_readers_and_compresses() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rec.mcap");
        let messages = messages();
        write_test_recording(&path, "nodes: []\n", Some(300), &messages, &[]);
        let want = expected(&messages);

        let rec = read_recording(&path).unwrap();
        assert_eq!(rec.dataflow_yaml, "nodes: []\n");
        assert_eq!(rec.max_steps, Some(300));
        assert!(!rec.truncated);
        assert_eq!(rec.messages, want);

        let mut reader = RecordingReader::open(&path).unwrap();
        assert_eq!(reader.dataflow_yaml(), "nodes: []\n");
        reader.only_topics(["mapper/map".to_string()].into());
        let mut streamed = Vec::new();
        while let Some(m) = reader.next_message().unwrap() {
            streamed.push(m.to_message());
        }
        let maps: Vec<_> = want
            .iter()
            .filter(|m| m.topic == "mapper/map")
            .cloned()
            .collect();
        assert_eq!(streamed, maps);
        assert!(!reader.truncated());

        // zstd chunks: the file is far smaller than the payloads (most of them stored in full).
        let raw: usize = messages.iter().map(|m| m.3.len()).sum();
        let size = std::fs::metadata(&path).unwrap().len() as usize;
        assert!(
            size * 4 < raw,
            "{size} bytes on disk for {raw} payload bytes"
        );
    }

    #[test]
    fn record_cut_short_reads_up_to_the_cut_and_says_truncated() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rec.mcap");
        let messages = messages();
        write_test_recording(&path, "nodes: []\n", None, &messages, &[]);
        let want = expected(&messages);
        let full = std::fs::read(&path).unwrap();
        let cut = dir.path().join("cut.mcap");
        std::fs::write(&cut, &full[..full.len() * 2 / 3]).unwrap();
        let rec = read_recording(&cut).unwrap();
        assert!(rec.truncated);
        assert_eq!(rec.dataflow_yaml, "nodes: []\n");
        let n = rec.messages.len();
        // The chunks before the cut are complete: at least a third of the messages come back.
        assert!(
            n > want.len() / 3 && n < want.len(),
            "{n} of {}",
            want.len()
        );
        assert_eq!(rec.messages, want[..n]);
        // Not an MCAP file at all is an error, not an empty truncated recording.
        let junk = dir.path().join("junk.mcap");
        std::fs::write(&junk, b"not mcap at all").unwrap();
        let e = read_recording(&junk).unwrap_err().to_string();
        assert!(e.contains("not an MCAP file"), "{e}");
    }
}
