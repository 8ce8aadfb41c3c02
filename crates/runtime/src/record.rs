//! Recording every message of a run to MCAP (dataflow file and schemas embedded), reading it back,
//! and replaying one operator on its recorded inputs.
//!
//! The recorder never drops silently: Zenoh topics use a blocking FIFO (back-pressure up to the
//! producer), and shared-memory topics are checked for gaps in the producers' sequence numbers;
//! any gap is counted and reported per topic.
//!
//! Large payloads are stored delta-encoded against the previous payload of their channel
//! ([`crate::delta`], encoding [`DELTA_ENCODING`]). The Gaussian maps of built-in operators are
//! stored by default as digests only ([`DIGEST_ENCODING`], [`MapRecording`]): they are a
//! deterministic function of the mapper's recorded inputs, so a reader that needs them
//! regenerates them by replaying the mapper ([`RecordingReader::regenerate_with`]) and checks
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
use activemap_view::topics::VIEW_ENCODING;
use activemap_view::{ViewConverter, ViewSettings, ViewTopic};

use crate::RuntimeError;
use crate::dataflow::{Dataflow, DropPolicy};
use crate::node::{RecordedInput, RunInfo, shm_limits};
use crate::transport::{ShmSubscriber, ZenohSubscriber, iox_node, topic_key};

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
/// ([`Producer`]) and check each against its digest. The recorder uses it for the Gaussian maps
/// of built-in operators ([`MapRecording::Regenerated`]).
pub const DIGEST_ENCODING: &str = "activemap/digest-v1";

/// True for the encodings of the exact (replay) channels; false for the view channels, which
/// readers of this module skip.
pub fn is_replay_encoding(encoding: &str) -> bool {
    encoding.starts_with(SMALL_ENCODING)
        || encoding == LARGE_ENCODING
        || encoding == DELTA_ENCODING
        || encoding == DIGEST_ENCODING
}

/// How the recorder stores the Gaussian maps of built-in operators (`--record-maps`).
///
/// Maps are most of a recording's bytes (the README's main episode: 312 of 375 MB stored in
/// full), and they are a deterministic function of the mapper's recorded inputs, so by default
/// only their digests are written and readers remake them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum MapRecording {
    /// Each map's length and 128-bit hash only ([`DIGEST_ENCODING`]); `activemap replay`
    /// regenerates the maps by replaying the mapper on its recorded inputs and checks every one
    /// against its digest. Replay then costs the mapper's time, and needs the same build (a
    /// build whose mapper computes differently is told so at the first map).
    #[default]
    Regenerated,
    /// Every map, delta-encoded against the previous one ([`DELTA_ENCODING`]): larger files
    /// whose maps read back without rerunning anything (e.g. to replay with another build).
    Full,
}

impl std::str::FromStr for MapRecording {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "regenerated" => Ok(Self::Regenerated),
            "full" => Ok(Self::Full),
            _ => Err(format!(
                "`{s}` is not a map recording mode (`regenerated` or `full`)"
            )),
        }
    }
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

/// What the recorder saw.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RecorderStats {
    /// Messages written (including end-of-stream markers).
    pub messages: u64,
    /// Payload bytes received.
    pub bytes: u64,
    /// Bytes written for them (large payloads are delta-encoded, so this can be far smaller).
    pub written_bytes: u64,
    /// Messages lost per topic (gaps in sequence numbers). Empty when nothing was lost.
    pub dropped: BTreeMap<String, u64>,
    /// View messages made (Foxglove schemas, for the file's view channels and the live view).
    pub view_messages: u64,
    /// Bytes of those view messages.
    pub view_bytes: u64,
    /// Pipeline messages that could not be shown (each reported once per topic on stderr).
    pub view_errors: u64,
    /// Pipeline messages not shown because the view thread was behind (the exact channels
    /// never wait for the view).
    pub view_dropped: u64,
}

impl RecorderStats {
    /// `Some(self)` when a file was written.
    pub fn into_recorded(self, recorded: bool) -> Option<Self> {
        recorded.then_some(self)
    }
}

/// What the recorder thread writes and serves.
pub struct RecorderOutputs {
    /// The MCAP file to write (exact channels and view channels); `None` with `--no-record`.
    pub file: Option<std::path::PathBuf>,
    /// The live view to feed (`--view`), if any.
    pub live: Option<activemap_view::LiveView>,
    /// How Gaussian maps are stored in the file.
    pub maps: MapRecording,
}

/// A running recorder thread.
pub struct Recorder {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<RecorderStats, RuntimeError>>>,
}

impl Recorder {
    /// Subscribe to every topic of the flow and start writing `outputs.file` and feeding
    /// `outputs.live`. Returns once every subscription exists, so no message sent after that is
    /// missed.
    pub fn start(
        outputs: RecorderOutputs,
        dataflow: &Dataflow,
        run: &RunInfo,
        session: zenoh::Session,
        machine: Option<&str>,
    ) -> Result<Self, RuntimeError> {
        let machine = machine.map(str::to_string);
        // A file-size limit (`ulimit -f`) must make a write fail with EFBIG, reported below,
        // rather than kill the launcher with SIGXFSZ and leave its nodes behind.
        // SAFETY: setting a signal's disposition to "ignore" has no handler to race with.
        unsafe {
            libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
        }
        let file = outputs.file.clone();
        let stop = Arc::new(AtomicBool::new(false));
        let (ready_tx, ready_rx) = std::sync::mpsc::sync_channel(1);
        let dataflow = dataflow.clone();
        let run = run.clone();
        let stop2 = stop.clone();
        let thread = std::thread::Builder::new()
            .name("recorder".into())
            .spawn(move || {
                record_loop(
                    outputs,
                    &dataflow,
                    &run,
                    machine.as_deref(),
                    session,
                    &stop2,
                    ready_tx,
                )
                .map_err(|e| match &file {
                    Some(path) => RuntimeError::Other(format!("recording {}: {e}", path.display())),
                    None => e,
                })
            })
            .map_err(|e| RuntimeError::Other(format!("cannot start the recorder thread: {e}")))?;
        match ready_rx.recv_timeout(Duration::from_secs(30)) {
            Ok(Ok(())) => Ok(Self {
                stop,
                thread: Some(thread),
            }),
            Ok(Err(e)) => Err(RuntimeError::Other(format!("recorder: {e}"))),
            Err(_) => match thread.join() {
                Ok(Err(e)) => Err(e),
                _ => Err(RuntimeError::Other("recorder did not start".into())),
            },
        }
    }

    /// True when the recorder thread ended before [`Self::finish`] asked it to: it failed (e.g.
    /// the disk is full), and [`Self::finish`] returns the error. The launcher then stops the
    /// run rather than go on unrecorded.
    pub fn failed(&self) -> bool {
        !self.stop.load(Ordering::Relaxed)
            && self.thread.as_ref().is_some_and(JoinHandle::is_finished)
    }

    /// Drain what is in flight, finish the file and return the statistics.
    pub fn finish(mut self) -> Result<RecorderStats, RuntimeError> {
        self.stop.store(true, Ordering::Relaxed);
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(r)) => r,
            _ => Err(RuntimeError::Other("recorder thread panicked".into())),
        }
    }
}

enum Source {
    Shm(ShmSubscriber),
    Zenoh(ZenohSubscriber),
}

fn mcap_err(e: mcap::McapError) -> RuntimeError {
    let mcap::McapError::Io(io) = &e else {
        return RuntimeError::Other(format!("mcap: {e}"));
    };
    let full = matches!(
        io.kind(),
        std::io::ErrorKind::StorageFull
            | std::io::ErrorKind::FileTooLarge
            | std::io::ErrorKind::QuotaExceeded
    );
    let hint = if full {
        " (the disk is full or a file-size limit was reached; the file keeps what was written \
         before and reads back up to there)"
    } else {
        ""
    };
    RuntimeError::Other(format!("mcap: I/O error: {io}{hint}"))
}

fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

type McapWriter = mcap::Writer<BufWriter<File>>;

/// The MCAP writer of a recording: chunked and zstd-compressed (chunks of [`CHUNK_SIZE`]).
/// Compression runs on the writing thread: no worker threads competing with the operators.
fn open_writer(file: File) -> Result<McapWriter, RuntimeError> {
    mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .compression_threads(0)
        .use_chunks(true)
        .chunk_size(Some(CHUNK_SIZE))
        .profile("activemap")
        .create(BufWriter::new(file))
        .map_err(mcap_err)
}

/// How a recorded channel stores its payloads.
#[derive(Debug)]
enum Stored {
    /// As they are (small messages).
    Plain,
    /// Delta-encoded against the channel's last non-empty payload, held here.
    Delta(Vec<u8>),
    /// Their digests only ([`DIGEST_ENCODING`]).
    Digest,
}

/// Write one message, stored as `stored` says. Returns the bytes written for the message.
fn write_message(
    writer: &mut McapWriter,
    header: &mcap::records::MessageHeader,
    kind: MessageKind,
    bytes: &[u8],
    stored: &mut Stored,
    encoded: &mut Vec<u8>,
) -> Result<usize, mcap::McapError> {
    let record: &[u8] = match stored {
        // The end-of-stream marker stays empty on every channel.
        Stored::Digest if bytes.is_empty() => bytes,
        Stored::Digest => {
            encoded.clear();
            encoded.extend_from_slice(&encode_digest(digest(bytes)));
            encoded
        }
        Stored::Delta(prev) => {
            let base = (!prev.is_empty()).then_some(prev.as_slice());
            if kind == MessageKind::GaussianMap {
                crate::delta::encode_map(base, bytes, encoded);
            } else {
                crate::delta::encode(base, bytes, encoded);
            }
            if !bytes.is_empty() {
                crate::delta::update_base(prev, bytes, encoded);
            }
            encoded
        }
        Stored::Plain => bytes,
    };
    writer.write_to_known_channel(header, record)?;
    Ok(record.len())
}

/// One recorded topic: where its messages come from and what the writer keeps for it.
struct RecordedTopic {
    topic: String,
    kind: MessageKind,
    channel: u16,
    source: Source,
    last_seq: u64,
    /// How its payloads are stored (a delta channel keeps its last payload here).
    stored: Stored,
    /// Keyframe of the last map of this topic handed to the view.
    view_keyframe: Option<u64>,
}

/// How output `kind` of node `node` is stored: the Gaussian maps of a built-in operator as
/// digests unless `maps` asks for them in full (an external executable's output cannot be
/// regenerated), other large payloads delta-encoded, small messages as they are.
fn stored_as(kind: MessageKind, node: &crate::dataflow::NodeSpec, maps: MapRecording) -> Stored {
    let built_in = matches!(node.implementation, crate::dataflow::NodeImpl::Operator(_));
    match kind.transport_class() {
        TransportClass::SharedMemory
            if kind == MessageKind::GaussianMap
                && built_in
                && maps == MapRecording::Regenerated =>
        {
            Stored::Digest
        }
        TransportClass::SharedMemory => Stored::Delta(Vec::new()),
        TransportClass::Small => Stored::Plain,
    }
}

fn record_loop(
    outputs: RecorderOutputs,
    dataflow: &Dataflow,
    run: &RunInfo,
    machine: Option<&str>,
    session: zenoh::Session,
    stop: &AtomicBool,
    ready: std::sync::mpsc::SyncSender<Result<(), String>>,
) -> Result<RecorderStats, RuntimeError> {
    let RecorderOutputs { file, live, maps } = outputs;
    let setup = || -> Result<_, RuntimeError> {
        let mut writer = match &file {
            Some(path) => {
                let f = File::create(path).map_err(|e| RuntimeError::io(path, e))?;
                Some(open_writer(f)?)
            }
            None => None,
        };
        if let Some(writer) = &mut writer {
            let mut meta = BTreeMap::new();
            meta.insert("run_id".to_string(), run.run_id.clone());
            meta.insert("dataflow_file".to_string(), dataflow.file.clone());
            meta.insert("dataflow_yaml".to_string(), dataflow.source.clone());
            if let Some(n) = run.max_steps {
                meta.insert("max_steps".to_string(), n.to_string());
            }
            writer
                .write_metadata(&mcap::records::Metadata {
                    name: "activemap.dataflow".into(),
                    metadata: meta,
                })
                .map_err(mcap_err)?;
        }
        let iox = if dataflow.nodes.iter().any(|n| {
            n.outputs
                .iter()
                .any(|o| o.kind.transport_class() == TransportClass::SharedMemory)
        }) {
            Some(iox_node(&format!("activemap-{}-recorder", run.run_id))?)
        } else {
            None
        };
        let mut schemas = BTreeMap::new();
        let mut sources = Vec::new();
        for n in &dataflow.nodes {
            for o in &n.outputs {
                let kind = o.kind;
                let topic = format!("{}/{}", n.id, o.name);
                let stored = stored_as(kind, n, maps);
                let channel = match &mut writer {
                    Some(writer) => {
                        let schema_id = match schemas.get(&kind) {
                            Some(id) => *id,
                            None => {
                                let id = writer
                                    .add_schema(
                                        kind.name(),
                                        "activemap/text",
                                        format!(
                                            "{} v{}: {}",
                                            kind.name(),
                                            kind.schema_version(),
                                            kind.description()
                                        )
                                        .as_bytes(),
                                    )
                                    .map_err(mcap_err)?;
                                schemas.insert(kind, id);
                                id
                            }
                        };
                        let mut ch_meta = BTreeMap::new();
                        ch_meta.insert("kind".to_string(), kind.name().to_string());
                        ch_meta.insert(
                            "schema_version".to_string(),
                            kind.schema_version().to_string(),
                        );
                        let encoding = match &stored {
                            Stored::Digest => DIGEST_ENCODING.to_string(),
                            Stored::Delta(_) => DELTA_ENCODING.to_string(),
                            Stored::Plain => format!("{SMALL_ENCODING}{}", kind.schema_version()),
                        };
                        writer
                            .add_channel(schema_id, &topic, &encoding, &ch_meta)
                            .map_err(mcap_err)?
                    }
                    None => 0,
                };
                let key = topic_key(&run.run_id, &n.id, &o.name);
                // Shared memory only from a built-in producer on the recorder's machine; an
                // external node or another machine's node publishes on Zenoh.
                let from_shm =
                    crate::node::readable_from_shm(dataflow, &n.id, machine.unwrap_or(&n.machine));
                let source = match (&iox, kind.transport_class()) {
                    (Some(iox), TransportClass::SharedMemory) if from_shm => {
                        let limits = shm_limits(dataflow, &n.id, &o.name);
                        Source::Shm(ShmSubscriber::create(iox, &key, limits, limits.buffer)?)
                    }
                    _ => Source::Zenoh(ZenohSubscriber::create(
                        &session,
                        &key,
                        4096,
                        DropPolicy::Block,
                    )?),
                };
                sources.push(RecordedTopic {
                    topic,
                    kind,
                    channel,
                    source,
                    last_seq: 0,
                    stored,
                    view_keyframe: None,
                });
            }
        }
        // The view channels, in Foxglove's well-known schemas (activemap_view).
        let mut view_channels = BTreeMap::new();
        if let Some(writer) = &mut writer {
            for topic in ViewTopic::ALL {
                let schema = topic.schema();
                let schema_id = writer
                    .add_schema(&schema.name, &schema.encoding, &schema.data)
                    .map_err(mcap_err)?;
                let channel = writer
                    .add_channel(schema_id, topic.topic(), VIEW_ENCODING, &BTreeMap::new())
                    .map_err(mcap_err)?;
                view_channels.insert(topic, channel);
            }
            writer.flush().map_err(mcap_err)?;
        }
        Ok((writer, iox, sources, view_channels))
    };
    let (mut writer, _iox, mut sources, view_channels) = match setup() {
        Ok(s) => {
            let _ = ready.send(Ok(()));
            s
        }
        Err(e) => {
            let _ = ready.send(Err(e.to_string()));
            return Err(e);
        }
    };
    let mut stats = RecorderStats::default();
    let mut stop_seen: Option<Instant> = None;
    let mut last_flush = Instant::now();
    const IDLE_MIN: Duration = Duration::from_micros(200);
    const IDLE_MAX: Duration = Duration::from_millis(2);
    let mut idle = IDLE_MIN;
    let mut encoded: Vec<u8> = Vec::new();
    let mut view_sequence = 0u32;
    type ViewItem = (String, MessageKind, Vec<u8>, u64);
    let (view_tx, view_rx) = std::sync::mpsc::sync_channel::<ViewItem>(64);
    let (shown_tx, shown_rx) = std::sync::mpsc::channel::<activemap_view::ViewMessage>();
    let view_thread = std::thread::Builder::new()
        .name("recorder-view".into())
        .spawn(move || {
            let mut view = ViewConverter::new(ViewSettings::default());
            let mut failed = BTreeSet::new();
            let mut errors = 0u64;
            for (topic, kind, bytes, t) in view_rx {
                match view.convert(&topic, kind, &bytes, t) {
                    Ok(shown) => {
                        for m in shown {
                            if let Some(live) = &live {
                                live.publish(&m);
                            }
                            let _ = shown_tx.send(m);
                        }
                    }
                    Err(e) => {
                        errors += 1;
                        if failed.insert(topic) {
                            eprintln!("activemap: recorder: view: {e} (shown once per topic)");
                        }
                    }
                }
            }
            if let Some(live) = live {
                live.stop();
            }
            errors
        })
        .map_err(|e| RuntimeError::Other(format!("cannot start the view thread: {e}")))?;
    let write_view = |writer: &mut Option<McapWriter>,
                      stats: &mut RecorderStats,
                      view_sequence: &mut u32,
                      m: activemap_view::ViewMessage|
     -> Result<(), RuntimeError> {
        stats.view_messages += 1;
        stats.view_bytes += m.data.len() as u64;
        if let (Some(writer), Some(&channel_id)) = (writer, view_channels.get(&m.topic)) {
            *view_sequence = view_sequence.wrapping_add(1);
            let header = mcap::records::MessageHeader {
                channel_id,
                sequence: *view_sequence,
                log_time: m.log_time_ns,
                publish_time: m.log_time_ns,
            };
            writer
                .write_to_known_channel(&header, &m.data)
                .map_err(mcap_err)?;
            stats.written_bytes += m.data.len() as u64;
        }
        Ok(())
    };
    loop {
        let mut busy = false;
        for rt in &mut sources {
            let mut write_err = None;
            let mut handle = |seq: u64, bytes: &[u8]| {
                if seq > rt.last_seq + 1 && rt.last_seq > 0 {
                    *stats.dropped.entry(rt.topic.clone()).or_default() += seq - rt.last_seq - 1;
                } else if rt.last_seq == 0 && seq > 1 {
                    *stats.dropped.entry(rt.topic.clone()).or_default() += seq - 1;
                }
                rt.last_seq = seq;
                let t = now_ns();
                stats.messages += 1;
                stats.bytes += bytes.len() as u64;
                if let Some(writer) = &mut writer {
                    let header = mcap::records::MessageHeader {
                        channel_id: rt.channel,
                        sequence: seq as u32,
                        log_time: t,
                        publish_time: t,
                    };
                    match write_message(
                        writer,
                        &header,
                        rt.kind,
                        bytes,
                        &mut rt.stored,
                        &mut encoded,
                    ) {
                        Ok(written) => stats.written_bytes += written as u64,
                        Err(e) => {
                            write_err = Some(e);
                            return;
                        }
                    }
                }
                // The view is made on its own thread: image encoding must never slow the
                // exact channels (a slow recorder loses shared-memory samples). A full queue
                // drops the view message, never an exact one. A map goes only when its
                // keyframe changed (the converter shows nothing else).
                if !bytes.is_empty() {
                    let keyframe = (rt.kind == MessageKind::GaussianMap)
                        .then(|| activemap_schemas::GaussianMapHeader::read(bytes).ok())
                        .flatten()
                        .map(|h| h.keyframe_id);
                    if keyframe.is_none() || keyframe != rt.view_keyframe {
                        rt.view_keyframe = keyframe;
                        let item = (rt.topic.clone(), rt.kind, bytes.to_vec(), t);
                        if view_tx.try_send(item).is_err() {
                            stats.view_dropped += 1;
                        }
                    }
                }
            };
            let got = match &mut rt.source {
                Source::Shm(s) => s.try_recv(&mut handle)?,
                Source::Zenoh(z) => z.try_recv(&mut handle)?,
            };
            if let Some(e) = write_err {
                return Err(mcap_err(e));
            }
            busy |= got;
        }
        while let Ok(m) = shown_rx.try_recv() {
            write_view(&mut writer, &mut stats, &mut view_sequence, m)?;
        }
        if last_flush.elapsed() > FLUSH_INTERVAL {
            if let Some(writer) = &mut writer {
                writer.flush().map_err(mcap_err)?;
            }
            last_flush = Instant::now();
        }
        if stop.load(Ordering::Relaxed) {
            let since = *stop_seen.get_or_insert_with(Instant::now);
            // Drain: stop once nothing arrived for a while after the stop request.
            if !busy && since.elapsed() > Duration::from_millis(300) {
                break;
            }
        }
        // Idle: back off from 200 µs to 2 ms. Waking every 200 µs cost the launcher a quarter
        // of its CPU samples in context switches; 2 ms is far within the shared-memory
        // subscribers' buffers at any frame rate the loop reaches.
        if busy {
            idle = IDLE_MIN;
        } else {
            std::thread::sleep(idle);
            idle = (idle * 2).min(IDLE_MAX);
        }
    }
    drop(view_tx);
    stats.view_errors = view_thread.join().unwrap_or(0);
    while let Ok(m) = shown_rx.try_recv() {
        write_view(&mut writer, &mut stats, &mut view_sequence, m)?;
    }
    if let Some(writer) = &mut writer {
        writer.finish().map_err(mcap_err)?;
    }
    Ok(stats)
}

/// One message read back from a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedMessage {
    /// `node/output`.
    pub topic: String,
    /// Producer sequence number (low 32 bits).
    pub seq: u64,
    /// Payload (empty = end of stream); with `digest_only`, the payload's 24-byte digest.
    pub bytes: Vec<u8>,
    /// True for a message of a [`DIGEST_ENCODING`] channel that was not regenerated: `bytes`
    /// holds the digest ([`parse_digest`]), not the payload.
    pub digest_only: bool,
}

/// A recording read back.
#[derive(Debug, Clone, PartialEq)]
pub struct Recording {
    /// The dataflow file text embedded at record time.
    pub dataflow_yaml: String,
    /// Messages in the order they were recorded.
    pub messages: Vec<RecordedMessage>,
    /// True when the file ended early (writer killed); messages up to the cut are still returned.
    pub truncated: bool,
    /// The run's `--max-steps`, if it was given.
    pub max_steps: Option<u64>,
}

/// One message of a recording as [`RecordingReader`] yields it, borrowed from the reader until
/// its next read.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MessageRef<'a> {
    /// `node/output`.
    pub topic: &'a str,
    /// Producer sequence number (low 32 bits).
    pub seq: u64,
    /// Payload, delta encoding undone or regenerated (empty = end of stream); with
    /// `digest_only`, the payload's 24-byte digest.
    pub bytes: &'a [u8],
    /// True for a message of a [`DIGEST_ENCODING`] channel the reader was not asked to
    /// regenerate ([`RecordingReader::regenerate_with`]).
    pub digest_only: bool,
}

impl MessageRef<'_> {
    /// An owned copy.
    pub fn to_message(&self) -> RecordedMessage {
        RecordedMessage {
            topic: self.topic.to_string(),
            seq: self.seq,
            bytes: self.bytes.to_vec(),
            digest_only: self.digest_only,
        }
    }
}

/// A built-in operator that can remake the payloads of one of its outputs recorded as digests:
/// its node spec (with any replay config applied), the output port and its replay entry point.
#[derive(Clone)]
pub struct Producer {
    /// The producing node, as the recorded dataflow declares it.
    pub spec: crate::dataflow::NodeSpec,
    /// The output port whose payloads are remade.
    pub port: String,
    /// The operator's replay entry point.
    pub replay: crate::node::ReplayFn,
}

/// The producers a reader may use, by topic (`node/output`).
pub type Producers = BTreeMap<String, Producer>;

/// Remakes the payloads of one digest channel: a thread replays the producer on its recorded
/// inputs (from a second reader of the same file) and hands over the outputs of the port, in
/// order, through a queue of two; each is checked against the recorded digest.
struct Regenerator {
    topic: String,
    producer: String,
    rx: Option<std::sync::mpsc::Receiver<Result<Vec<u8>, RuntimeError>>>,
    /// Outputs of the port received so far (the n-th has sequence number n).
    received: u64,
    cancel: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Regenerator {
    /// Start replaying `producer` on the recording at `path`; `stack` holds the topics being
    /// regenerated by the readers above this one (a cycle is an error, not a hang).
    fn start(
        path: &Path,
        topic: &str,
        producer: &Producer,
        producers: &Producers,
        stack: &[String],
    ) -> Result<Self, RuntimeError> {
        if stack.iter().any(|t| t == topic) {
            return Err(RuntimeError::Other(format!(
                "{}: cannot regenerate `{topic}`: it depends on itself ({} → {topic})",
                path.display(),
                stack.join(" → ")
            )));
        }
        let (tx, rx) = std::sync::mpsc::sync_channel(2);
        let cancel = Arc::new(AtomicBool::new(false));
        let producer_id = producer.spec.id.clone();
        let (path, producer, producers) = (path.to_path_buf(), producer.clone(), producers.clone());
        let mut stack = stack.to_vec();
        stack.push(topic.to_string());
        let stop = cancel.clone();
        let thread = std::thread::Builder::new()
            .name(format!("regenerate {topic}"))
            .spawn(move || {
                let run = || -> Result<(), RuntimeError> {
                    let mut reader = RecordingReader::open(&path)?;
                    reader.stack = stack;
                    reader.only_topics(
                        producer
                            .spec
                            .inputs
                            .iter()
                            .map(|i| i.source_topic())
                            .collect(),
                    );
                    reader.regenerate_with(producers, BTreeSet::new());
                    let max_steps = reader.max_steps();
                    let mut emit = |port: &str, bytes: &[u8]| {
                        if port == producer.port && !bytes.is_empty() {
                            tx.send(Ok(bytes.to_vec())).map_err(|_| cancelled())?;
                        }
                        Ok(())
                    };
                    feed_inputs(
                        &mut reader,
                        &producer.spec,
                        producer.replay,
                        &mut emit,
                        max_steps,
                        |_| Ok(()),
                        Some(&stop),
                    )?;
                    Ok(())
                };
                if let Err(e) = run()
                    && !stop.load(Ordering::Relaxed)
                {
                    let _ = tx.send(Err(e));
                }
            })
            .map_err(|e| RuntimeError::Other(format!("cannot start a regeneration thread: {e}")))?;
        Ok(Self {
            topic: topic.to_string(),
            producer: producer_id,
            rx: Some(rx),
            received: 0,
            cancel,
            thread: Some(thread),
        })
    }

    /// The regenerated payload recorded with sequence number `seq` (low 32 bits) and digest
    /// `want`, checked against it. Outputs the recording lacks (a gap the recorder counted) are
    /// skipped.
    fn payload(&mut self, path: &Path, seq: u64, want: Digest) -> Result<Vec<u8>, RuntimeError> {
        let rx = self.rx.as_ref().expect("receiver held until drop");
        loop {
            let bytes = match rx.recv() {
                Ok(r) => r.map_err(|e| {
                    RuntimeError::Other(format!(
                        "{}: regenerating `{}` by replaying `{}`: {e}",
                        path.display(),
                        self.topic,
                        self.producer
                    ))
                })?,
                Err(_) => {
                    return Err(RuntimeError::Other(format!(
                        "{}: regenerating `{}`: the replay of `{}` made {} outputs, but the \
                         recording has one with sequence number {seq}",
                        path.display(),
                        self.topic,
                        self.producer,
                        self.received
                    )));
                }
            };
            self.received += 1;
            if self.received as u32 != seq as u32 {
                continue;
            }
            let got = digest(&bytes);
            if got != want {
                return Err(RuntimeError::Other(format!(
                    "{}: message {seq} of `{}`: the map regenerated by replaying `{}` differs from \
                     the recorded digest ({} bytes recorded, {} regenerated): this build does \
                     not reproduce the recorded run; record with `--record-maps full` to replay \
                     across builds",
                    path.display(),
                    self.topic,
                    self.producer,
                    want.0,
                    got.0
                )));
            }
            return Ok(bytes);
        }
    }
}

impl Drop for Regenerator {
    fn drop(&mut self) {
        self.cancel.store(true, Ordering::Relaxed);
        // Dropping the receiver unblocks a producer waiting to hand over an output.
        self.rx = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn cancelled() -> RuntimeError {
    RuntimeError::Other("regeneration no longer needed".into())
}

/// What the reader keeps per channel: its last payload, which the next delta applies to.
struct ChannelState {
    topic: String,
    delta: bool,
    /// A [`DIGEST_ENCODING`] channel.
    digest: bool,
    /// Its regenerator, started at its first message when a producer is known.
    regen: Option<Regenerator>,
    /// False for a view channel, which is never read.
    replay: bool,
    wanted: bool,
    /// Last non-empty payload (empty before the first one).
    last: Vec<u8>,
}

/// A message found by [`RecordingReader::advance`]: channel id, sequence number, and whether the
/// payload is empty (otherwise it is the channel's `last`).
type Found = (u16, u64, bool);

/// Reads a recording front to back in bounded memory: the file is read piece by piece, chunks are
/// decompressed as they stream past, and each channel keeps only its last payload (for the delta
/// encoding). Memory is about the largest message per read channel plus one read buffer, not the
/// file. A file cut short by a crash reads up to the cut, then [`Self::truncated`] is true.
pub struct RecordingReader {
    path: std::path::PathBuf,
    file: File,
    reader: mcap::sans_io::linear_reader::LinearReader,
    channels: BTreeMap<u16, ChannelState>,
    topics: Option<BTreeSet<String>>,
    dataflow_yaml: String,
    max_steps: Option<u64>,
    /// Set once the first record (the header) was read: errors after it mean a cut file.
    started: bool,
    truncated: bool,
    done: bool,
    /// A message read ahead while looking for the metadata.
    pending: Option<Found>,
    /// Producers that remake digest channels' payloads ([`Self::regenerate_with`]).
    producers: Producers,
    /// Digest channels yielded as digests even when a producer is known.
    kept_as_digests: BTreeSet<String>,
    /// Topics being regenerated by the readers above this one (cycle check).
    stack: Vec<String>,
}

impl RecordingReader {
    /// Open `path` and read up to the embedded dataflow (the first record after the header).
    /// Every topic is read; see [`Self::only_topics`].
    pub fn open(path: &Path) -> Result<Self, RuntimeError> {
        let file = File::open(path).map_err(|e| RuntimeError::io(path, e))?;
        let mut reader = Self {
            path: path.to_path_buf(),
            file,
            reader: mcap::sans_io::linear_reader::LinearReader::new(),
            channels: BTreeMap::new(),
            topics: None,
            dataflow_yaml: String::new(),
            max_steps: None,
            started: false,
            truncated: false,
            done: false,
            pending: None,
            producers: Producers::new(),
            kept_as_digests: BTreeSet::new(),
            stack: Vec::new(),
        };
        reader.pending = reader.advance(true)?;
        Ok(reader)
    }

    /// From now on yield only messages of these topics (`node/output`); the others are skipped
    /// without decoding them.
    pub fn only_topics(&mut self, topics: BTreeSet<String>) {
        for ch in self.channels.values_mut() {
            ch.wanted = ch.replay && topics.contains(&ch.topic);
        }
        if let Some((id, ..)) = self.pending
            && !self.channels.get(&id).is_some_and(|c| c.wanted)
        {
            self.pending = None;
        }
        self.topics = Some(topics);
    }

    /// Regenerate the payloads of the digest channels (maps recorded with
    /// [`MapRecording::Regenerated`]) whose topic has a producer here: each is remade by
    /// replaying the producer on its recorded inputs, on a thread of its own, and checked
    /// against its digest; a mismatch is an error naming the topic and message. Other digest
    /// channels, and those in `except`, yield their digests (`digest_only`). A producer whose
    /// own inputs are digests has them regenerated the same way, with the same producers.
    pub fn regenerate_with(&mut self, producers: Producers, except: BTreeSet<String>) {
        self.producers = producers;
        self.kept_as_digests = except;
    }

    /// The dataflow file text embedded at record time (empty if the file has none).
    pub fn dataflow_yaml(&self) -> &str {
        &self.dataflow_yaml
    }

    /// The recorded run's `--max-steps`, if it was given.
    pub fn max_steps(&self) -> Option<u64> {
        self.max_steps
    }

    /// True once the reader found the file cut short (writer killed).
    pub fn truncated(&self) -> bool {
        self.truncated
    }

    /// The next message in recorded order, or `None` at the end of the data (or at the cut of a
    /// truncated file). A payload that does not decode is an error naming the topic and its
    /// sequence number.
    pub fn next_message(&mut self) -> Result<Option<MessageRef<'_>>, RuntimeError> {
        let found = match self.pending.take() {
            Some(f) => Some(f),
            None => self.advance(false)?,
        };
        Ok(found.map(|(id, seq, empty)| {
            let ch = &self.channels[&id];
            MessageRef {
                topic: &ch.topic,
                seq,
                bytes: if empty { &[] } else { &ch.last },
                digest_only: ch.digest && ch.regen.is_none() && !empty,
            }
        }))
    }

    /// Read records up to the next wanted message (or, with `until_metadata`, up to the
    /// dataflow metadata, returning `None` there).
    fn advance(&mut self, until_metadata: bool) -> Result<Option<Found>, RuntimeError> {
        use mcap::records::Record;
        use mcap::sans_io::linear_reader::LinearReadEvent;
        while !self.done {
            let event = match self.reader.next_event() {
                None => {
                    self.done = true;
                    break;
                }
                Some(Ok(event)) => event,
                Some(Err(e)) if !self.started => {
                    return Err(RuntimeError::Other(format!(
                        "{}: not an MCAP file: {e}",
                        self.path.display()
                    )));
                }
                Some(Err(_)) => {
                    self.truncated = true;
                    self.done = true;
                    break;
                }
            };
            let (opcode, data) = match event {
                LinearReadEvent::ReadRequest(need) => {
                    let buf = self.reader.insert(need);
                    let n = loop {
                        match std::io::Read::read(&mut self.file, buf) {
                            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                            r => break r.map_err(|e| RuntimeError::io(&self.path, e))?,
                        }
                    };
                    self.reader.notify_read(n);
                    continue;
                }
                LinearReadEvent::Record { opcode, data } => (opcode, data),
            };
            self.started = true;
            let Ok(record) = mcap::parse_record(opcode, data) else {
                self.truncated = true;
                self.done = true;
                break;
            };
            match record {
                Record::Metadata(m) if m.name == "activemap.dataflow" => {
                    self.dataflow_yaml =
                        m.metadata.get("dataflow_yaml").cloned().unwrap_or_default();
                    self.max_steps = m.metadata.get("max_steps").and_then(|v| v.parse().ok());
                    if until_metadata {
                        return Ok(None);
                    }
                }
                Record::Channel(c) => {
                    // Chunks repeat the channels they use: keep the state of a known one.
                    // The view channels (Foxglove schemas) are for viewers: never read here.
                    let ours = is_replay_encoding(&c.message_encoding);
                    let wanted = ours && self.topics.as_ref().is_none_or(|t| t.contains(&c.topic));
                    self.channels.entry(c.id).or_insert_with(|| ChannelState {
                        topic: c.topic.clone(),
                        delta: c.message_encoding == DELTA_ENCODING,
                        digest: c.message_encoding == DIGEST_ENCODING,
                        regen: None,
                        replay: ours,
                        wanted,
                        last: Vec::new(),
                    });
                }
                Record::Message { header, data } => {
                    let id = header.channel_id;
                    let Some(ch) = self.channels.get_mut(&id) else {
                        return Err(RuntimeError::Other(format!(
                            "{}: a message on channel {id} that was never declared",
                            self.path.display()
                        )));
                    };
                    if !ch.wanted {
                        continue;
                    }
                    let seq = header.sequence.into();
                    if data.is_empty() {
                        return Ok(Some((id, seq, true)));
                    }
                    if ch.digest {
                        let want = parse_digest(&data).ok_or_else(|| {
                            RuntimeError::Other(format!(
                                "{}: message {} of `{}`: a digest record of {} bytes, not 24",
                                self.path.display(),
                                header.sequence,
                                ch.topic,
                                data.len()
                            ))
                        })?;
                        if ch.regen.is_none()
                            && !self.kept_as_digests.contains(&ch.topic)
                            && let Some(producer) = self.producers.get(&ch.topic)
                        {
                            ch.regen = Some(Regenerator::start(
                                &self.path,
                                &ch.topic,
                                producer,
                                &self.producers,
                                &self.stack,
                            )?);
                        }
                        ch.last = match &mut ch.regen {
                            Some(regen) => regen.payload(&self.path, seq, want)?,
                            None => data.to_vec(),
                        };
                    } else if ch.delta {
                        let base = (!ch.last.is_empty()).then_some(ch.last.as_slice());
                        ch.last = crate::delta::decode(base, &data).map_err(|e| {
                            RuntimeError::Other(format!(
                                "{}: message {} of `{}`: {e}",
                                self.path.display(),
                                header.sequence,
                                ch.topic
                            ))
                        })?;
                    } else {
                        ch.last.clear();
                        ch.last.extend_from_slice(&data);
                    }
                    return Ok(Some((id, seq, ch.last.is_empty())));
                }
                Record::DataEnd(_) => self.done = true,
                _ => {}
            }
        }
        Ok(None)
    }
}

/// Read a whole recording into memory, tolerating a file cut short by a crash; delta-encoded
/// payloads are decoded (a payload that does not decode is an error naming the topic and its
/// sequence number). Built on [`RecordingReader`], which reads without holding the file.
pub fn read_recording(path: &Path) -> Result<Recording, RuntimeError> {
    let mut reader = RecordingReader::open(path)?;
    let mut messages = Vec::new();
    while let Some(m) = reader.next_message()? {
        messages.push(m.to_message());
    }
    Ok(Recording {
        dataflow_yaml: reader.dataflow_yaml,
        messages,
        truncated: reader.truncated,
        max_steps: reader.max_steps,
    })
}

/// The inputs node `node` received during the recorded run, in recorded order.
pub fn recorded_inputs(
    recording: &Recording,
    dataflow: &Dataflow,
    node: &str,
) -> Result<Vec<RecordedInput>, RuntimeError> {
    let spec = dataflow
        .node(node)
        .ok_or_else(|| RuntimeError::UnknownNode(node.into()))?;
    let mut out = Vec::new();
    for m in &recording.messages {
        for i in &spec.inputs {
            if m.topic == i.source_topic() {
                out.push(RecordedInput {
                    port: i.name.clone(),
                    seq: m.seq,
                    bytes: m.bytes.clone(),
                });
            }
        }
    }
    Ok(out)
}

/// Outcome of a replay comparison.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ReplayReport {
    /// Outputs compared per port: (matched, recorded, produced).
    pub per_port: BTreeMap<String, (usize, usize, usize)>,
}

impl ReplayReport {
    /// Total matched outputs.
    pub fn matched(&self) -> usize {
        self.per_port.values().map(|v| v.0).sum()
    }
    /// Total recorded outputs.
    pub fn recorded(&self) -> usize {
        self.per_port.values().map(|v| v.1).sum()
    }
    /// Total produced outputs.
    pub fn produced(&self) -> usize {
        self.per_port.values().map(|v| v.2).sum()
    }
    /// True when every recorded output was reproduced byte for byte and nothing extra was produced.
    pub fn all_match(&self) -> bool {
        self.per_port.values().all(|(m, r, p)| m == r && r == p)
    }
}

/// Compare the outputs produced by a replay with the recorded ones, port by port, in order.
pub fn compare_outputs(
    recording: &Recording,
    node: &str,
    produced: &[crate::node::ProducedOutput],
) -> ReplayReport {
    let mut report = ReplayReport::default();
    let mut recorded: BTreeMap<String, Vec<&[u8]>> = BTreeMap::new();
    let prefix = format!("{node}/");
    for m in &recording.messages {
        if let Some(port) = m.topic.strip_prefix(&prefix)
            && !m.bytes.is_empty()
        {
            recorded.entry(port.to_string()).or_default().push(&m.bytes);
        }
    }
    let mut made: BTreeMap<String, Vec<&[u8]>> = BTreeMap::new();
    for p in produced {
        made.entry(p.port.clone()).or_default().push(&p.bytes);
    }
    let ports: std::collections::BTreeSet<_> =
        recorded.keys().chain(made.keys()).cloned().collect();
    for port in ports {
        let r = recorded.get(&port).map(Vec::as_slice).unwrap_or_default();
        let p = made.get(&port).map(Vec::as_slice).unwrap_or_default();
        let matched = r.iter().zip(p).filter(|(a, b)| a == b).count();
        report.per_port.insert(port, (matched, r.len(), p.len()));
    }
    report
}

/// A payload as the streaming replay compares it: its length and its 128-bit XXH3 hash.
pub type Digest = (usize, u128);

/// The 24-byte record of a digest on a [`DIGEST_ENCODING`] channel.
fn encode_digest((len, hash): Digest) -> [u8; 24] {
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

/// Recorded and produced outputs of one port not yet paired, and the counts so far.
#[derive(Default)]
struct PortMatch {
    recorded: VecDeque<Digest>,
    produced: VecDeque<Digest>,
    matched: usize,
    recorded_count: usize,
    produced_count: usize,
}

impl PortMatch {
    /// Pair the oldest unpaired outputs of each side, in order (as [`compare_outputs`] does).
    fn pair(&mut self) {
        while !self.recorded.is_empty() && !self.produced.is_empty() {
            let (r, p) = (self.recorded.pop_front(), self.produced.pop_front());
            self.matched += usize::from(r == p);
        }
    }
}

/// Outcome of [`replay_recording`].
#[derive(Debug, Clone, PartialEq, Default)]
pub struct StreamedReplay {
    /// The output comparison.
    pub report: ReplayReport,
    /// Recorded inputs fed to the operator.
    pub inputs: usize,
    /// True when the recording ends early (writer killed).
    pub truncated: bool,
}

/// Feed node `spec` its recorded inputs from `reader`, input by input in recorded order, through
/// `replay`; `on_message` sees every message the reader yields (the caller chooses which with
/// [`RecordingReader::only_topics`]), and an error from it ends the feed. An input recorded as a digest that the reader could not
/// regenerate is an error naming it. With `cancel` set, the feed ends with an error at the next
/// input. Returns the number of inputs fed.
fn feed_inputs(
    reader: &mut RecordingReader,
    spec: &crate::dataflow::NodeSpec,
    replay: crate::node::ReplayFn,
    emit: &mut crate::node::OutputCallback<'_>,
    max_steps: Option<u64>,
    mut on_message: impl FnMut(&MessageRef<'_>) -> Result<(), RuntimeError>,
    cancel: Option<&AtomicBool>,
) -> Result<usize, RuntimeError> {
    let mut ports_of: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for i in &spec.inputs {
        ports_of
            .entry(i.source_topic())
            .or_default()
            .push(i.name.clone());
    }
    let mut inputs = 0usize;
    let mut queued: VecDeque<RecordedInput> = VecDeque::new();
    // The input source borrows `inputs` mutably: its own scope ends the borrow.
    {
        let mut source = std::iter::from_fn(|| {
            loop {
                if cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
                    return Some(Err(cancelled()));
                }
                if let Some(input) = queued.pop_front() {
                    inputs += 1;
                    return Some(Ok(input));
                }
                let m = match reader.next_message() {
                    Ok(Some(m)) => m,
                    Ok(None) => return None,
                    Err(e) => return Some(Err(e)),
                };
                if let Err(e) = on_message(&m) {
                    return Some(Err(e));
                }
                let Some(ports) = ports_of.get(m.topic) else {
                    continue;
                };
                if m.digest_only {
                    return Some(Err(RuntimeError::Other(format!(
                        "`{}` was recorded as digests (`--record-maps regenerated`) and its producer \
                     cannot be replayed here, so node `{}` cannot be fed its input",
                        m.topic, spec.id
                    ))));
                }
                for port in ports {
                    queued.push_back(RecordedInput {
                        port: port.clone(),
                        seq: m.seq,
                        bytes: m.bytes.to_vec(),
                    });
                }
            }
        });
        replay(spec, &mut source, emit, max_steps)?;
    }
    Ok(inputs)
}

/// Replay node `spec` with `replay` on the recording `reader` is reading, streaming: each input
/// is fed to the operator as it is read, and the node's outputs are compared with the recorded
/// ones port by port, in order, on their length and 128-bit hash (a mismatch that keeps both
/// length and hash has odds of about 2^-128); an output recorded as a digest is compared with
/// it. Inputs recorded as digests are regenerated with `producers` (see
/// [`RecordingReader::regenerate_with`]). Memory holds the current message of each read channel
/// and the hashes of outputs not yet paired, never the recording's payloads.
pub fn replay_recording(
    mut reader: RecordingReader,
    spec: &crate::dataflow::NodeSpec,
    replay: crate::node::ReplayFn,
    producers: &Producers,
) -> Result<StreamedReplay, RuntimeError> {
    let prefix = format!("{}/", spec.id);
    let own_outputs: BTreeSet<String> = spec
        .outputs
        .iter()
        .map(|o| format!("{prefix}{}", o.name))
        .collect();
    let mut topics: BTreeSet<String> = spec.inputs.iter().map(|i| i.source_topic()).collect();
    topics.extend(own_outputs.iter().cloned());
    reader.only_topics(topics);
    // The node's own outputs are compared with their digests, never regenerated.
    reader.regenerate_with(producers.clone(), own_outputs);
    let max_steps = reader.max_steps();
    let matches = std::cell::RefCell::new(BTreeMap::<String, PortMatch>::new());
    let record_output = |m: &MessageRef<'_>| -> Result<(), RuntimeError> {
        if let Some(port) = m.topic.strip_prefix(&prefix)
            && !m.bytes.is_empty()
        {
            let recorded = if m.digest_only {
                parse_digest(m.bytes).ok_or_else(|| {
                    RuntimeError::Other(format!("message {} of `{}`: bad digest", m.seq, m.topic))
                })?
            } else {
                digest(m.bytes)
            };
            let mut matches = matches.borrow_mut();
            let pm = matches.entry(port.to_string()).or_default();
            pm.recorded.push_back(recorded);
            pm.recorded_count += 1;
            pm.pair();
        }
        Ok(())
    };
    let mut emit = |port: &str, bytes: &[u8]| {
        let mut matches = matches.borrow_mut();
        let m = matches.entry(port.to_string()).or_default();
        m.produced.push_back(digest(bytes));
        m.produced_count += 1;
        m.pair();
        Ok(())
    };
    let inputs = feed_inputs(
        &mut reader,
        spec,
        replay,
        &mut emit,
        max_steps,
        &record_output,
        None,
    )?;
    // The operator may stop before the end: count the recorded outputs left.
    while let Some(m) = reader.next_message()? {
        record_output(&m)?;
    }
    let report = ReplayReport {
        per_port: matches
            .into_inner()
            .into_iter()
            .map(|(port, m)| (port, (m.matched, m.recorded_count, m.produced_count)))
            .collect(),
    };
    Ok(StreamedReplay {
        report,
        inputs,
        truncated: reader.truncated(),
    })
}

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
        // Large test payloads go through the map codec's entry point, which stores anything
        // that is not a valid map as the byte-run delta does.
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
