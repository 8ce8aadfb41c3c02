//! Recording every message of a run to MCAP (dataflow file and schemas embedded), reading it back,
//! and replaying one operator on its recorded inputs.
//!
//! The recorder never drops silently: Zenoh topics use a blocking FIFO (back-pressure up to the
//! producer), and shared-memory topics are checked for gaps in the producers' sequence numbers;
//! any gap is counted and reported per topic.
//!
//! Large payloads are stored delta-encoded against the previous payload of their channel
//! ([`crate::delta`], encoding [`DELTA_ENCODING`]): the map is published every frame but changes
//! only at keyframes. [`read_recording`] gives back every payload byte for byte, and still reads
//! recordings of plain [`LARGE_ENCODING`] channels.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use activemap_schemas::TransportClass;

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
}

/// A running recorder thread.
pub struct Recorder {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<RecorderStats, RuntimeError>>>,
}

impl Recorder {
    /// Subscribe to every topic of the flow and start writing `path`. Returns once every
    /// subscription exists, so no message sent after that is missed.
    pub fn start(
        path: &Path,
        dataflow: &Dataflow,
        run: &RunInfo,
        session: zenoh::Session,
        machine: Option<&str>,
    ) -> Result<Self, RuntimeError> {
        let machine = machine.map(str::to_string);
        let stop = Arc::new(AtomicBool::new(false));
        let (ready_tx, ready_rx) = std::sync::mpsc::sync_channel(1);
        let dataflow = dataflow.clone();
        let run = run.clone();
        let path = path.to_path_buf();
        let stop2 = stop.clone();
        let thread = std::thread::Builder::new()
            .name("recorder".into())
            .spawn(move || {
                record_loop(
                    &path,
                    &dataflow,
                    &run,
                    machine.as_deref(),
                    session,
                    &stop2,
                    ready_tx,
                )
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
    RuntimeError::Other(format!("mcap: {e}"))
}

fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

fn record_loop(
    path: &Path,
    dataflow: &Dataflow,
    run: &RunInfo,
    machine: Option<&str>,
    session: zenoh::Session,
    stop: &AtomicBool,
    ready: std::sync::mpsc::SyncSender<Result<(), String>>,
) -> Result<RecorderStats, RuntimeError> {
    let setup = || -> Result<_, RuntimeError> {
        let file = File::create(path).map_err(|e| RuntimeError::io(path, e))?;
        // Unchunked and uncompressed: every message is a self-contained record, so a file cut short
        // (launcher killed) still reads up to its last complete record.
        let mut writer = mcap::WriteOptions::new()
            .compression(None)
            .use_chunks(false)
            .profile("activemap")
            .create(BufWriter::new(file))
            .map_err(mcap_err)?;
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
                let topic = format!("{}/{}", n.id, o.name);
                let mut ch_meta = BTreeMap::new();
                ch_meta.insert("kind".to_string(), kind.name().to_string());
                ch_meta.insert(
                    "schema_version".to_string(),
                    kind.schema_version().to_string(),
                );
                let encoding = match kind.transport_class() {
                    TransportClass::SharedMemory => DELTA_ENCODING.to_string(),
                    TransportClass::Small => format!("{SMALL_ENCODING}{}", kind.schema_version()),
                };
                let channel = writer
                    .add_channel(schema_id, &topic, &encoding, &ch_meta)
                    .map_err(mcap_err)?;
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
                // Large channels keep their previous payload for the delta encoding.
                let previous =
                    (kind.transport_class() == TransportClass::SharedMemory).then(Vec::<u8>::new);
                sources.push((topic, channel, source, 0u64, previous));
            }
        }
        writer.flush().map_err(mcap_err)?;
        Ok((writer, iox, sources))
    };
    let (mut writer, _iox, mut sources) = match setup() {
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
    let mut mcap_sequence = 0u32;
    let mut encoded: Vec<u8> = Vec::new();
    loop {
        let mut busy = false;
        for (topic, channel, source, last_seq, previous) in &mut sources {
            let mut write_err = None;
            let mut handle = |seq: u64, bytes: &[u8]| {
                if seq > *last_seq + 1 && *last_seq > 0 {
                    *stats.dropped.entry(topic.clone()).or_default() += seq - *last_seq - 1;
                } else if *last_seq == 0 && seq > 1 {
                    *stats.dropped.entry(topic.clone()).or_default() += seq - 1;
                }
                *last_seq = seq;
                mcap_sequence = mcap_sequence.wrapping_add(1);
                let t = now_ns();
                let header = mcap::records::MessageHeader {
                    channel_id: *channel,
                    sequence: seq as u32,
                    log_time: t,
                    publish_time: t,
                };
                let record: &[u8] = match previous {
                    Some(prev) => {
                        let base = (!prev.is_empty()).then_some(prev.as_slice());
                        crate::delta::encode(base, bytes, &mut encoded);
                        if !bytes.is_empty() {
                            prev.clear();
                            prev.extend_from_slice(bytes);
                        }
                        &encoded
                    }
                    None => bytes,
                };
                if let Err(e) = writer.write_to_known_channel(&header, record) {
                    write_err = Some(e);
                }
                stats.messages += 1;
                stats.bytes += bytes.len() as u64;
                stats.written_bytes += record.len() as u64;
            };
            let got = match source {
                Source::Shm(s) => s.try_recv(&mut handle)?,
                Source::Zenoh(z) => z.try_recv(&mut handle)?,
            };
            if let Some(e) = write_err {
                return Err(mcap_err(e));
            }
            busy |= got;
        }
        if last_flush.elapsed() > Duration::from_millis(200) {
            writer.flush().map_err(mcap_err)?;
            last_flush = Instant::now();
        }
        if stop.load(Ordering::Relaxed) {
            let since = *stop_seen.get_or_insert_with(Instant::now);
            // Drain: stop once nothing arrived for a while after the stop request.
            if !busy && since.elapsed() > Duration::from_millis(300) {
                break;
            }
        }
        if !busy {
            std::thread::sleep(Duration::from_micros(200));
        }
    }
    writer.finish().map_err(mcap_err)?;
    Ok(stats)
}

/// One message read back from a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedMessage {
    /// `node/output`.
    pub topic: String,
    /// Producer sequence number (low 32 bits).
    pub seq: u64,
    /// Payload (empty = end of stream).
    pub bytes: Vec<u8>,
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

/// Read a recording, tolerating a file cut short by a crash; delta-encoded payloads are decoded
/// (a payload that does not decode is an error naming the topic and its sequence number).
pub fn read_recording(path: &Path) -> Result<Recording, RuntimeError> {
    let data = std::fs::read(path).map_err(|e| RuntimeError::io(path, e))?;
    let mut dataflow_yaml = String::new();
    let mut messages: Vec<RecordedMessage> = Vec::new();
    let mut truncated = false;
    let mut max_steps = None;
    // Per channel: topic, whether it is delta-encoded, and its last decoded non-empty payload.
    let mut channels: BTreeMap<u16, (String, bool, Option<usize>)> = BTreeMap::new();
    let reader = mcap::read::LinearReader::new_with_options(
        &data,
        mcap::read::Options::IgnoreEndMagic.into(),
    )
    .map_err(|e| RuntimeError::Other(format!("{}: not an MCAP file: {e}", path.display())))?;
    for record in reader {
        let record = match record {
            Ok(r) => r,
            Err(_) => {
                truncated = true;
                break;
            }
        };
        match record {
            mcap::records::Record::Metadata(m) if m.name == "activemap.dataflow" => {
                dataflow_yaml = m.metadata.get("dataflow_yaml").cloned().unwrap_or_default();
                max_steps = m.metadata.get("max_steps").and_then(|v| v.parse().ok());
            }
            mcap::records::Record::Channel(c) => {
                let delta = c.message_encoding == DELTA_ENCODING;
                channels.insert(c.id, (c.topic.clone(), delta, None));
            }
            mcap::records::Record::Message { header, data } => {
                let (topic, delta, last) = channels
                    .get_mut(&header.channel_id)
                    .map(|(t, d, l)| (t.clone(), *d, l))
                    .ok_or_else(|| {
                        RuntimeError::Other(format!(
                            "{}: a message on channel {} that was never declared",
                            path.display(),
                            header.channel_id
                        ))
                    })?;
                let bytes = if delta {
                    let previous = last.map(|i: usize| messages[i].bytes.as_slice());
                    crate::delta::decode(previous, &data).map_err(|e| {
                        RuntimeError::Other(format!(
                            "{}: message {} of `{topic}`: {e}",
                            path.display(),
                            header.sequence
                        ))
                    })?
                } else {
                    data.into_owned()
                };
                if !bytes.is_empty() {
                    *last = Some(messages.len());
                }
                messages.push(RecordedMessage {
                    topic,
                    seq: header.sequence.into(),
                    bytes,
                });
            }
            mcap::records::Record::DataEnd(_) => break,
            _ => {}
        }
    }
    Ok(Recording {
        dataflow_yaml,
        messages,
        truncated,
        max_steps,
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
            if m.topic == format!("{}/{}", i.source_node, i.source_output) {
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
