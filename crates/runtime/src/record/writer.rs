//! The recorder: every topic of a run into the MCAP file, with the derived (view) channels.

use super::*;

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
    /// Derived messages made (the view channels of [`crate::derived`]: the file's and the live
    /// view's).
    pub view_messages: u64,
    /// Bytes of those derived messages.
    pub view_bytes: u64,
    /// Pipeline messages that could not be converted (each reported once per topic on stderr).
    pub view_errors: u64,
    /// Pipeline messages not converted because the converter's thread was behind (the exact
    /// channels never wait for it).
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
    /// The MCAP file to write (exact channels and derived channels); `None` with `--no-record`.
    pub file: Option<std::path::PathBuf>,
    /// The derived channels (the view of the run, which may also serve a live view), if any.
    pub derived: Option<Derived>,
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
    /// `outputs.derived`. Returns once every subscription exists, so no message sent after that is
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

pub(super) enum Source {
    Shm(ShmSubscriber),
    Zenoh(ZenohSubscriber),
}

pub(super) fn mcap_err(e: mcap::McapError) -> RuntimeError {
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

pub(super) fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

pub(super) type McapWriter = mcap::Writer<BufWriter<File>>;

/// The MCAP writer of a recording: chunked and zstd-compressed (chunks of [`CHUNK_SIZE`]).
/// Compression runs on the writing thread: no worker threads competing with the operators.
pub(super) fn open_writer(file: File) -> Result<McapWriter, RuntimeError> {
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
pub(super) enum Stored {
    /// As they are (small messages).
    Plain,
    /// Delta-encoded against the channel's last non-empty payload, held here.
    Delta(Vec<u8>),
    /// Their digests only ([`DIGEST_ENCODING`]).
    Digest,
}

/// Write one message, stored as `stored` says. Returns the bytes written for the message.
pub(super) fn write_message(
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
pub(super) struct RecordedTopic {
    topic: String,
    kind: MessageKind,
    channel: u16,
    source: Source,
    last_seq: u64,
    /// How its payloads are stored (a delta channel keeps its last payload here).
    stored: Stored,
}

/// How output `kind` of node `node` is stored: the Gaussian maps of a built-in operator as
/// digests unless `maps` asks for them in full (an external executable's output cannot be
/// regenerated), other large payloads delta-encoded, small messages as they are.
pub(super) fn stored_as(
    kind: MessageKind,
    node: &crate::dataflow::NodeSpec,
    maps: MapRecording,
) -> Stored {
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

pub(super) fn record_loop(
    outputs: RecorderOutputs,
    dataflow: &Dataflow,
    run: &RunInfo,
    machine: Option<&str>,
    session: zenoh::Session,
    stop: &AtomicBool,
    ready: std::sync::mpsc::SyncSender<Result<(), String>>,
) -> Result<RecorderStats, RuntimeError> {
    let RecorderOutputs {
        file,
        derived,
        maps,
    } = outputs;
    let (mut filter, converter) = match derived {
        Some(d) => (Some(d.filter), Some(d.channels)),
        None => (None, None),
    };
    let declared = converter.as_ref().map(|c| c.channels()).unwrap_or_default();
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
                });
            }
        }
        // The derived channels (the view of the run), as their converter declared them.
        let mut view_channels = BTreeMap::new();
        if let Some(writer) = &mut writer {
            for channel in &declared {
                let schema_id = writer
                    .add_schema(
                        &channel.schema_name,
                        &channel.schema_encoding,
                        &channel.schema_data,
                    )
                    .map_err(mcap_err)?;
                let id = writer
                    .add_channel(
                        schema_id,
                        &channel.topic,
                        &channel.message_encoding,
                        &BTreeMap::new(),
                    )
                    .map_err(mcap_err)?;
                view_channels.insert(channel.topic.clone(), id);
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
    let (shown_tx, shown_rx) = std::sync::mpsc::channel::<DerivedMessage>();
    let view_thread = match converter {
        Some(mut converter) => Some(
            std::thread::Builder::new()
                .name("recorder-view".into())
                .spawn(move || {
                    let mut failed = BTreeSet::new();
                    let mut errors = 0u64;
                    for (topic, kind, bytes, t) in view_rx {
                        match converter.convert(&topic, kind, &bytes, t) {
                            Ok(shown) => {
                                for m in shown {
                                    let _ = shown_tx.send(m);
                                }
                            }
                            Err(e) => {
                                errors += 1;
                                if failed.insert(topic) {
                                    eprintln!(
                                        "activemap: recorder: view: {e} (shown once per topic)"
                                    );
                                }
                            }
                        }
                    }
                    converter.finish();
                    errors
                })
                .map_err(|e| RuntimeError::Other(format!("cannot start the view thread: {e}")))?,
        ),
        None => {
            drop(shown_tx);
            None
        }
    };
    let write_view = |writer: &mut Option<McapWriter>,
                      stats: &mut RecorderStats,
                      view_sequence: &mut u32,
                      m: DerivedMessage|
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
                // The derived channels are made on their own thread: image encoding must never
                // slow the exact channels (a slow recorder loses shared-memory samples). A full
                // queue drops the derived message, never an exact one; the filter keeps the
                // copies few (e.g. a map only when its keyframe changed).
                if let Some(filter) = &mut filter
                    && !bytes.is_empty()
                    && filter.wants(&rt.topic, rt.kind, bytes)
                {
                    let item = (rt.topic.clone(), rt.kind, bytes.to_vec(), t);
                    if view_tx.try_send(item).is_err() {
                        stats.view_dropped += 1;
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
    stats.view_errors = view_thread.map_or(0, |t| t.join().unwrap_or(0));
    while let Ok(m) = shown_rx.try_recv() {
        write_view(&mut writer, &mut stats, &mut view_sequence, m)?;
    }
    if let Some(writer) = &mut writer {
        writer.finish().map_err(mcap_err)?;
    }
    Ok(stats)
}
