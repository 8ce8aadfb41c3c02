//! Replaying one operator on its recorded inputs and comparing its outputs with the recording.

use super::*;

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

/// Recorded and produced outputs of one port not yet paired, and the counts so far.
#[derive(Default)]
pub(super) struct PortMatch {
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
pub(super) fn feed_inputs(
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
    reader: RecordingReader,
    spec: &crate::dataflow::NodeSpec,
    replay: crate::node::ReplayFn,
    producers: &Producers,
) -> Result<StreamedReplay, RuntimeError> {
    replay_recording_observed(reader, spec, replay, producers, &mut |_, _| {})
}

/// [`replay_recording`], handing every output the operator produces (port, payload) to
/// `observe` as it is produced: for a replay whose outputs are kept rather than only compared
/// (e.g. the last map of a mapper replayed with another configuration).
pub fn replay_recording_observed(
    mut reader: RecordingReader,
    spec: &crate::dataflow::NodeSpec,
    replay: crate::node::ReplayFn,
    producers: &Producers,
    observe: &mut dyn FnMut(&str, &[u8]),
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
        observe(port, bytes);
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
