//! The node runner: wires one operator to its inputs, outputs and timers, runs its event loop,
//! and the same driver replays recorded inputs in-process.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use activemap_schemas::{MessageKind, TransportClass};

use crate::RuntimeError;
use crate::dataflow::{Dataflow, DropPolicy, NodeImpl, NodeSpec};
use crate::{Context, Event, Flow, Input, Operator, OperatorError, OutputSink, config_from_value};

/// Poll back-off bounds of the node event loop.
const IDLE_SLEEP_MIN: Duration = Duration::from_micros(20);
const IDLE_SLEEP_MAX: Duration = Duration::from_millis(2);
use crate::transport::{
    ShmLimits, ShmPublisher, ShmSubscriber, ZenohPublisher, ZenohSettings, ZenohSubscriber,
    iox_node, open_zenoh, topic_key,
};

/// Facts of one run shared by the launcher and its nodes (`run.json` in the run folder).
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct RunInfo {
    /// Unique id of the run; prefixes every service and key.
    pub run_id: String,
    /// Zenoh endpoints of each machine's router, which that machine's nodes connect to.
    pub routers: BTreeMap<String, Vec<String>>,
    /// TLS settings per machine, passed through to Zenoh.
    #[serde(default)]
    pub tls: BTreeMap<String, serde_json::Value>,
    /// Step budget from `--max-steps`.
    pub max_steps: Option<u64>,
}

impl RunInfo {
    /// File name inside the run folder.
    pub const FILE: &'static str = "run.json";
    /// File name of the dataflow copy inside the run folder.
    pub const DATAFLOW: &'static str = "dataflow.yaml";

    /// Read `run.json` from a run folder.
    pub fn load(run_dir: &Path) -> Result<Self, RuntimeError> {
        let path = run_dir.join(Self::FILE);
        let text = std::fs::read_to_string(&path).map_err(|e| RuntimeError::io(&path, e))?;
        serde_json::from_str(&text)
            .map_err(|e| RuntimeError::Other(format!("{}: {e}", path.display())))
    }

    /// Write `run.json` into a run folder.
    pub fn save(&self, run_dir: &Path) -> Result<(), RuntimeError> {
        let path = run_dir.join(Self::FILE);
        let text = serde_json::to_string_pretty(self).expect("serialisable");
        std::fs::write(&path, text).map_err(|e| RuntimeError::io(&path, e))
    }

    /// Zenoh settings of a node process on `machine`.
    pub fn client_settings(&self, machine: &str) -> ZenohSettings {
        ZenohSettings {
            mode: "client".into(),
            listen: vec![],
            connect: self.routers.get(machine).cloned().unwrap_or_default(),
            tls: self.tls.get(machine).cloned(),
        }
    }
}

/// Control keys of a run: nodes announce `ready`, the launcher answers `start` (a barrier so no
/// message is sent before every subscriber exists) and may broadcast `stop`.
pub fn control_key(run_id: &str, what: &str) -> String {
    format!("activemap/{run_id}/_ctl/{what}")
}

/// Everything a node process needs to run its operator.
pub struct NodeSetup<'a> {
    /// The validated dataflow.
    pub dataflow: &'a Dataflow,
    /// The run.
    pub run: &'a RunInfo,
    /// This node's id.
    pub node_id: &'a str,
    /// Set by SIGINT/SIGTERM (or the caller) to stop the node.
    pub stop: Arc<AtomicBool>,
}

/// One recorded input message for replay.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedInput {
    /// Input port.
    pub port: String,
    /// Producer sequence number.
    pub seq: u64,
    /// Payload (empty = end of stream).
    pub bytes: Vec<u8>,
}

/// One output message produced during replay.
#[derive(Debug, Clone, PartialEq)]
pub struct ProducedOutput {
    /// Output port.
    pub port: String,
    /// Payload.
    pub bytes: Vec<u8>,
}

/// Type-erased entry points of an operator type, stored in the operator registry.
#[derive(Clone, Copy)]
pub struct OperatorImpl {
    /// Run as a node of a live flow.
    pub run: fn(NodeSetup<'_>) -> Result<(), RuntimeError>,
    /// Run alone on recorded inputs (with the recorded run's `--max-steps`), returning its
    /// outputs.
    pub replay: ReplayFn,
}

impl OperatorImpl {
    /// The entry points of operator type `O`.
    pub fn of<O: Operator>() -> Self {
        Self {
            run: run_operator::<O>,
            replay: replay_operator::<O>,
        }
    }
}

fn outputs_of(spec: &NodeSpec) -> Vec<(String, MessageKind)> {
    spec.outputs
        .iter()
        .map(|o| (o.name.clone(), o.kind))
        .collect()
}

fn make_operator<O: Operator>(
    spec: &NodeSpec,
    outputs: &[(String, MessageKind)],
    sink: &mut dyn OutputSink,
    max_steps: Option<u64>,
) -> Result<O, RuntimeError> {
    let config: O::Config =
        config_from_value(&spec.config).map_err(|message| RuntimeError::Config {
            node: spec.id.clone(),
            message,
        })?;
    let mut ctx = Context::new(&spec.id, outputs, sink, max_steps);
    O::new(config, &mut ctx).map_err(|e| RuntimeError::Operator(format!("{}: new: {e:#}", spec.id)))
}

fn dispatch<O: Operator>(
    op: &mut O,
    spec: &NodeSpec,
    outputs: &[(String, MessageKind)],
    sink: &mut dyn OutputSink,
    max_steps: Option<u64>,
    event: Event<'_>,
    timing: &mut StageTiming,
) -> Result<Flow, RuntimeError> {
    let mut ctx = Context::new(&spec.id, outputs, sink, max_steps);
    let started = Instant::now();
    let flow = op.on_event(event, &mut ctx);
    timing.seconds += started.elapsed().as_secs_f64();
    timing.calls += 1;
    flow.map_err(|e| RuntimeError::Operator(format!("{}: {e:#}", spec.id)))
}

/// Wall time one node spent inside its operator's `on_event` and the number of calls: one row
/// of the run folder's [`TIMINGS_FILE`] (the per-stage time breakdown of the report).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageTiming {
    /// Wall seconds inside `on_event`.
    pub seconds: f64,
    /// Calls of `on_event`.
    pub calls: u64,
}

/// Per-node timings in the run folder: header `stage,seconds,calls`, one row per node process.
pub const TIMINGS_FILE: &str = "timings.csv";

/// Appends `node`'s row to `run_dir/timings.csv`, writing the header when the file is new. An
/// exclusive lock on the file keeps the header first and the rows of nodes that stop at the same
/// moment whole.
pub fn append_timing(run_dir: &Path, node: &str, timing: StageTiming) -> Result<(), RuntimeError> {
    use std::io::Write as _;
    let path = run_dir.join(TIMINGS_FILE);
    let io = |e| RuntimeError::io(&path, e);
    let mut file = std::fs::File::options()
        .create(true)
        .append(true)
        .open(&path)
        .map_err(io)?;
    file.lock().map_err(io)?;
    let mut text = String::new();
    if file.metadata().map_err(io)?.len() == 0 {
        text.push_str("stage,seconds,calls\n");
    }
    text.push_str(&format!("{node},{:.6},{}\n", timing.seconds, timing.calls));
    let written = file.write_all(text.as_bytes()).map_err(io);
    let _ = file.unlock();
    written
}

/// Hands each output to a callback (replay), so a replay holds no outputs itself.
struct CallbackSink<'a, 'f> {
    outputs: &'a [(String, MessageKind)],
    emit: &'f mut OutputCallback<'f>,
}

impl OutputSink for CallbackSink<'_, '_> {
    fn send(&mut self, port: usize, bytes: &[u8]) -> Result<(), OperatorError> {
        (self.emit)(&self.outputs[port].0, bytes).map_err(OperatorError::sink)
    }

    fn loan(
        &mut self,
        port: usize,
        len: usize,
        fill: &mut dyn FnMut(&mut [u8]) -> anyhow::Result<()>,
    ) -> Result<(), OperatorError> {
        crate::loan_on_heap(len, fill, |buf| self.send(port, buf))
    }
}

/// Where a replay reads its recorded inputs from, in recorded order: an iterator, so a recording
/// can be streamed input by input ([`crate::record::replay_recording`]) instead of loaded whole.
pub type InputSource<'a> = dyn Iterator<Item = Result<RecordedInput, RuntimeError>> + 'a;

/// Where a replay sends each output it produces: `(output port, payload)`.
pub type OutputCallback<'a> = dyn FnMut(&str, &[u8]) -> Result<(), RuntimeError> + 'a;

/// The replay entry point of an operator: its node spec, the recorded inputs in order, a callback
/// that receives every output as it is produced, and the recorded run's `--max-steps`.
pub type ReplayFn = fn(
    &NodeSpec,
    &mut InputSource<'_>,
    &mut OutputCallback<'_>,
    Option<u64>,
) -> Result<(), RuntimeError>;

/// Run operator `O` alone on recorded inputs (in order, pulled from `inputs` one at a time, after
/// one firing of each declared timer) and hand each output to `emit` as it is sent; `max_steps`
/// is the recorded run's `--max-steps`, which the operator sees as it did then. An error from `inputs` or `emit` ends the replay with
/// that error.
pub fn replay_operator<O: Operator>(
    spec: &NodeSpec,
    inputs: &mut InputSource<'_>,
    emit: &mut OutputCallback<'_>,
    max_steps: Option<u64>,
) -> Result<(), RuntimeError> {
    let outputs = outputs_of(spec);
    let mut sink = CallbackSink {
        outputs: &outputs,
        emit,
    };
    let mut op: O = make_operator(spec, &outputs, &mut sink, max_steps)?;
    let mut timing = StageTiming::default();
    // Timer events are not recorded. Each declared timer fires once before the first input:
    // that is what starts a lockstep source (the simulator renders its first frame on its
    // start timer, then one per action), and a node whose timers only flush early changes
    // nothing by it. A node driven by periodic timers does not replay faithfully.
    for timer in &spec.timers {
        let event = Event::Timer { name: &timer.name };
        if dispatch(&mut op, spec, &outputs, &mut sink, None, event, &mut timing)? == Flow::Stop {
            return Ok(());
        }
    }
    for input in inputs {
        let input = input?;
        let Some(in_spec) = spec.inputs.iter().find(|i| i.name == input.port) else {
            return Err(RuntimeError::Other(format!(
                "recorded input `{}` is not an input of node `{}`",
                input.port, spec.id
            )));
        };
        let event = if input.bytes.is_empty() {
            Event::InputClosed { port: &input.port }
        } else {
            Event::Input(Input {
                port: &input.port,
                kind: in_spec.kind,
                seq: input.seq,
                bytes: &input.bytes,
            })
        };
        if dispatch(&mut op, spec, &outputs, &mut sink, None, event, &mut timing)? == Flow::Stop {
            return Ok(());
        }
    }
    dispatch(
        &mut op,
        spec,
        &outputs,
        &mut sink,
        None,
        Event::Stop,
        &mut timing,
    )?;
    Ok(())
}

/// Run `replay` on inputs held in memory and collect every output it produces (tests and small
/// recordings; [`crate::record::replay_recording`] streams instead).
pub fn replay_to_vec(
    replay: ReplayFn,
    spec: &NodeSpec,
    inputs: &[RecordedInput],
    max_steps: Option<u64>,
) -> Result<Vec<ProducedOutput>, RuntimeError> {
    let mut produced = Vec::new();
    let mut source = inputs.iter().cloned().map(Ok);
    replay(
        spec,
        &mut source,
        &mut |port: &str, bytes: &[u8]| {
            produced.push(ProducedOutput {
                port: port.to_string(),
                bytes: bytes.to_vec(),
            });
            Ok(())
        },
        max_steps,
    )?;
    Ok(produced)
}

/// A live output port: shared memory and/or Zenoh.
struct LivePort {
    shm: Option<ShmPublisher>,
    zenoh: Option<ZenohPublisher>,
    seq: u64,
}

struct LiveSink {
    ports: Vec<LivePort>,
}

impl OutputSink for LiveSink {
    fn send(&mut self, port: usize, bytes: &[u8]) -> Result<(), OperatorError> {
        self.send_live(port, bytes).map_err(OperatorError::sink)
    }

    fn loan(
        &mut self,
        port: usize,
        len: usize,
        fill: &mut dyn FnMut(&mut [u8]) -> anyhow::Result<()>,
    ) -> Result<(), OperatorError> {
        self.loan_live(port, len, fill).map_err(|e| match e {
            // The operator's own failure keeps its message as the operator wrote it.
            RuntimeError::Operator(message) => OperatorError::Fill(message),
            RuntimeError::Port(e) => e,
            e => OperatorError::sink(e),
        })
    }
}

impl LiveSink {
    fn send_live(&mut self, port: usize, bytes: &[u8]) -> Result<(), RuntimeError> {
        let p = &mut self.ports[port];
        p.seq += 1;
        if let Some(shm) = &p.shm {
            shm.send_copy(p.seq, bytes)?;
        }
        if let Some(z) = &p.zenoh {
            z.send(p.seq, bytes.to_vec())?;
        }
        Ok(())
    }

    fn loan_live(
        &mut self,
        port: usize,
        len: usize,
        fill: &mut dyn FnMut(&mut [u8]) -> anyhow::Result<()>,
    ) -> Result<(), RuntimeError> {
        let p = &mut self.ports[port];
        p.seq += 1;
        match (&p.shm, &p.zenoh) {
            (Some(shm), None) => shm.loan_and_send(p.seq, len, fill),
            (Some(shm), Some(z)) => {
                // Bridged: fill in place, and forward the same bytes to remote consumers.
                let mut copy = Vec::new();
                shm.loan_and_send(p.seq, len, &mut |buf| {
                    fill(buf)?;
                    copy = buf.to_vec();
                    Ok(())
                })?;
                z.send(p.seq, copy)
            }
            (None, Some(z)) => crate::loan_on_heap(len, fill, |buf| z.send(p.seq, buf.to_vec())),
            (None, None) => Ok(()),
        }
    }
}

impl LiveSink {
    fn end_of_stream(&mut self) {
        for p in &mut self.ports {
            p.seq += 1;
            if let Some(shm) = &p.shm {
                let _ = shm.send_copy(p.seq, &[]);
            }
            if let Some(z) = &p.zenoh {
                let _ = z.send(p.seq, Vec::new());
            }
        }
    }
}

enum LiveInput {
    Shm(ShmSubscriber),
    Zenoh(ZenohSubscriber),
}

/// Limits of the shared-memory service of `node/output`, the same for every participant.
pub fn shm_limits(dataflow: &Dataflow, node: &str, output: &str) -> ShmLimits {
    let queues: Vec<_> = dataflow
        .consumers(node, output)
        .map(|(_, i)| (i.queue_size, i.drop))
        .collect();
    ShmLimits::for_consumers(&queues)
}

/// True when node `id` is an external executable (`path:`). External nodes speak Zenoh only: they
/// cannot join iceoryx2 shared memory, so every topic they produce or consume travels over Zenoh.
pub fn is_external(dataflow: &Dataflow, id: &str) -> bool {
    dataflow
        .node(id)
        .is_some_and(|n| matches!(n.implementation, NodeImpl::Path { .. }))
}

/// True when the shared-memory-class output `node/output` must also be published on Zenoh: a
/// consumer runs on another machine or is an external node.
pub fn output_needs_zenoh(dataflow: &Dataflow, node: &str, output: &str) -> bool {
    let machine = dataflow.node(node).map(|n| n.machine.as_str());
    dataflow
        .consumers(node, output)
        .any(|(n, _)| Some(n.machine.as_str()) != machine || is_external(dataflow, &n.id))
}

/// True when a process on `machine` can read the shared-memory-class output `node/output` from
/// iceoryx2: the producer is a built-in operator on the same machine. Otherwise (another machine,
/// or an external producer that publishes on Zenoh only) it subscribes over Zenoh.
pub fn readable_from_shm(dataflow: &Dataflow, node: &str, machine: &str) -> bool {
    dataflow
        .node(node)
        .is_some_and(|n| n.machine == machine && !is_external(dataflow, node))
}

/// Install SIGINT/SIGTERM handlers that set `stop`.
pub fn install_stop_signals(stop: &Arc<AtomicBool>) -> Result<(), RuntimeError> {
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, stop.clone())
            .map_err(|e| RuntimeError::Other(format!("cannot install signal handler: {e}")))?;
    }
    Ok(())
}

/// Run operator `O` as node `setup.node_id`: connect ports, announce readiness, wait for the
/// launcher's start, then deliver events until the operator stops, all inputs close, or a stop is
/// requested. Sends end-of-stream on every output before returning.
pub fn run_operator<O: Operator>(setup: NodeSetup<'_>) -> Result<(), RuntimeError> {
    let dataflow = setup.dataflow;
    let run = setup.run;
    let spec = dataflow
        .node(setup.node_id)
        .ok_or_else(|| RuntimeError::UnknownNode(setup.node_id.to_string()))?;
    let session = open_zenoh(&run.client_settings(&spec.machine))?;
    let needs_shm = spec
        .outputs
        .iter()
        .any(|o| o.kind.transport_class() == TransportClass::SharedMemory)
        || spec
            .inputs
            .iter()
            .any(|i| i.kind.transport_class() == TransportClass::SharedMemory);
    let iox = if needs_shm {
        Some(iox_node(&format!("activemap-{}-{}", run.run_id, spec.id))?)
    } else {
        None
    };

    let mut ports = Vec::new();
    for out in &spec.outputs {
        let key = topic_key(&run.run_id, &spec.id, &out.name);
        let remote = output_needs_zenoh(dataflow, &spec.id, &out.name);
        let port = match (out.kind.transport_class(), &iox) {
            (TransportClass::SharedMemory, Some(iox)) => LivePort {
                shm: Some(ShmPublisher::create(
                    iox,
                    &key,
                    shm_limits(dataflow, &spec.id, &out.name),
                )?),
                zenoh: if remote {
                    Some(ZenohPublisher::create(&session, &key)?)
                } else {
                    None
                },
                seq: 0,
            },
            _ => LivePort {
                shm: None,
                zenoh: Some(ZenohPublisher::create(&session, &key)?),
                seq: 0,
            },
        };
        ports.push(port);
    }
    let mut inputs = Vec::new();
    for input in &spec.inputs {
        let key = topic_key(&run.run_id, &input.source_node, &input.source_output);
        let live = match (&iox, input.kind.transport_class()) {
            (Some(iox), TransportClass::SharedMemory)
                if readable_from_shm(dataflow, &input.source_node, &spec.machine) =>
            {
                LiveInput::Shm(ShmSubscriber::create(
                    iox,
                    &key,
                    shm_limits(dataflow, &input.source_node, &input.source_output),
                    input.queue_size,
                )?)
            }
            _ => LiveInput::Zenoh(ZenohSubscriber::create(
                &session,
                &key,
                input.queue_size,
                input.drop,
            )?),
        };
        inputs.push(live);
    }

    // Barrier: subscribe to start, announce ready, wait.
    let start = ZenohSubscriber::create(
        &session,
        &control_key(&run.run_id, "start"),
        1,
        DropPolicy::DropOldest,
    )?;
    let stop_sub = ZenohSubscriber::create(
        &session,
        &control_key(&run.run_id, "stop"),
        1,
        DropPolicy::DropOldest,
    )?;
    let ready = ZenohPublisher::create(
        &session,
        &control_key(&run.run_id, &format!("ready/{}", spec.id)),
    )?;
    let mut last_announce = Instant::now() - Duration::from_secs(1);
    loop {
        if setup.stop.load(Ordering::Relaxed) {
            return Ok(());
        }
        if last_announce.elapsed() >= Duration::from_millis(200) {
            ready.send(0, spec.id.as_bytes().to_vec())?;
            last_announce = Instant::now();
        }
        if start.recv(Some(Duration::from_millis(20)))?.is_some() {
            break;
        }
    }

    let mut sink = LiveSink { ports };
    let mut timing = StageTiming::default();
    let result = event_loop::<O>(
        spec,
        &mut timing,
        &mut sink,
        &inputs,
        &stop_sub,
        &setup.stop,
        run.max_steps,
    );
    sink.end_of_stream();
    // Launched nodes know their run folder from the launcher's environment.
    if let Some(run_dir) = std::env::var_os("ACTIVEMAP_RUN_DIR")
        && let Err(e) = append_timing(Path::new(&run_dir), &spec.id, timing)
    {
        eprintln!("{}: cannot record timings: {e}", spec.id);
    }
    // Let Zenoh flush the last messages before the session closes.
    std::thread::sleep(Duration::from_millis(50));
    drop(sink);
    let _ = zenoh::Wait::wait(session.close());
    result
}

fn event_loop<O: Operator>(
    spec: &NodeSpec,
    timing: &mut StageTiming,
    sink: &mut LiveSink,
    inputs: &[LiveInput],
    stop_sub: &ZenohSubscriber,
    stop: &AtomicBool,
    max_steps: Option<u64>,
) -> Result<(), RuntimeError> {
    let outputs = &outputs_of(spec);
    let mut op: O = make_operator(spec, outputs, sink, max_steps)?;
    let started = Instant::now();
    let mut timers: Vec<(String, Duration, Instant)> = spec
        .timers
        .iter()
        .map(|t| (t.name.clone(), t.period, started + t.period))
        .collect();
    let mut closed = vec![false; inputs.len()];
    // The producer's sequence number last seen per input: a gap on a `drop: block` input is a
    // message lost in transit (nothing may drop it), and is said on stderr, naming the input.
    let mut last_seq = vec![0u64; inputs.len()];
    let mut idle = IDLE_SLEEP_MIN;
    loop {
        if stop.load(Ordering::Relaxed) || stop_sub.recv(None)?.is_some() {
            dispatch(&mut op, spec, outputs, sink, max_steps, Event::Stop, timing)?;
            return Ok(());
        }
        let mut busy = false;
        for (i, live) in inputs.iter().enumerate() {
            if closed[i] {
                continue;
            }
            let port = &spec.inputs[i].name;
            let kind = spec.inputs[i].kind;
            let mut flow = Ok(Flow::Continue);
            let mut got_eos = false;
            let last = &mut last_seq[i];
            let input = &spec.inputs[i];
            let mut handle = |seq: u64, bytes: &[u8]| {
                if let Some(lost) = lost_in_transit(*last, seq, input.drop) {
                    eprintln!(
                        "activemap: node `{}` input `{port}` (from {}): {lost} message(s) lost in transit before sequence number {seq}",
                        spec.id,
                        input.source_topic()
                    );
                }
                *last = seq;
                let event = if bytes.is_empty() {
                    got_eos = true;
                    Event::InputClosed { port }
                } else {
                    Event::Input(Input {
                        port,
                        kind,
                        seq,
                        bytes,
                    })
                };
                flow = dispatch(&mut op, spec, outputs, sink, max_steps, event, timing);
            };
            let received = match live {
                LiveInput::Shm(s) => s.try_recv(&mut handle)?,
                LiveInput::Zenoh(z) => z.try_recv(&mut handle)?,
            };
            busy |= received;
            if got_eos {
                closed[i] = true;
            }
            if flow? == Flow::Stop {
                dispatch(&mut op, spec, outputs, sink, max_steps, Event::Stop, timing)?;
                return Ok(());
            }
        }
        if !inputs.is_empty() && closed.iter().all(|c| *c) {
            dispatch(&mut op, spec, outputs, sink, max_steps, Event::Stop, timing)?;
            return Ok(());
        }
        let now = Instant::now();
        for (name, period, due) in &mut timers {
            if now >= *due {
                // Skip missed ticks rather than bursting.
                while *due <= now {
                    *due += *period;
                }
                busy = true;
                if dispatch(
                    &mut op,
                    spec,
                    outputs,
                    sink,
                    max_steps,
                    Event::Timer {
                        name: name.as_str(),
                    },
                    timing,
                )? == Flow::Stop
                {
                    dispatch(&mut op, spec, outputs, sink, max_steps, Event::Stop, timing)?;
                    return Ok(());
                }
            }
        }
        if busy {
            idle = IDLE_SLEEP_MIN;
        } else {
            let next_timer = timers.iter().map(|t| t.2).min();
            let mut sleep = idle;
            if let Some(t) = next_timer {
                sleep = sleep.min(t.saturating_duration_since(Instant::now()));
            }
            std::thread::sleep(sleep);
            idle = (idle * 2).min(IDLE_SLEEP_MAX);
        }
    }
}

/// Run folder layout helpers.
pub fn logs_dir(run_dir: &Path) -> PathBuf {
    run_dir.join("logs")
}

/// How many messages a `drop: block` input lost between sequence numbers `last` and `seq` (the
/// producer numbers its messages 1, 2, …). `None` when nothing was lost, before the first
/// message (`last` 0: a restarted consumer starts mid-stream), on a drop-oldest input
/// (dropping is its policy), or when the producer restarted (`seq` at or below `last`).
fn lost_in_transit(last: u64, seq: u64, drop: DropPolicy) -> Option<u64> {
    (drop == DropPolicy::Block && last > 0 && seq > last + 1).then(|| seq - last - 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_gap_in_a_blocking_inputs_sequence_numbers_counts_the_lost_messages() {
        assert_eq!(lost_in_transit(3, 4, DropPolicy::Block), None);
        assert_eq!(lost_in_transit(3, 5, DropPolicy::Block), Some(1));
        assert_eq!(lost_in_transit(3, 9, DropPolicy::Block), Some(5));
        // Dropping is a ring's policy; a first message mid-stream or a restarted producer is
        // no loss.
        assert_eq!(lost_in_transit(3, 9, DropPolicy::DropOldest), None);
        assert_eq!(lost_in_transit(0, 7, DropPolicy::Block), None);
        assert_eq!(lost_in_transit(7, 1, DropPolicy::Block), None);
    }
    use crate::{OperatorDescriptor, PortSpec, check_config_as};
    use activemap_schemas::{Counter, Payload};

    /// Running sum: deterministic, so replay must reproduce it exactly.
    struct Summer {
        total: i64,
        scale: i64,
    }

    #[derive(serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct SummerConfig {
        scale: i64,
    }

    impl Operator for Summer {
        type Config = SummerConfig;
        fn new(config: SummerConfig, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
            Ok(Self {
                total: 0,
                scale: config.scale,
            })
        }
        fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
            match event {
                Event::Input(i) => {
                    let c: Counter = i.decode()?;
                    self.total += c.value * self.scale;
                    ctx.send(
                        "sum",
                        &Counter {
                            seq: c.seq,
                            value: self.total,
                        },
                    )?;
                    // Sending the wrong type on a port is an error, not a silent mis-encode.
                    assert!(
                        ctx.send(
                            "sum",
                            &activemap_schemas::Action {
                                step: 0,
                                action: activemap_schemas::ActionKind::Stop
                            }
                        )
                        .is_err()
                    );
                    Ok(Flow::Continue)
                }
                Event::Stop => {
                    ctx.send("sum", &Counter { seq: 0, value: -1 })?;
                    Ok(Flow::Stop)
                }
                _ => Ok(Flow::Continue),
            }
        }
    }

    #[test]
    fn timings_of_concurrent_nodes_form_one_csv_with_one_header() {
        let dir = tempfile::tempdir().unwrap();
        let threads: Vec<_> = (0..6)
            .map(|t| {
                let d = dir.path().to_path_buf();
                std::thread::spawn(move || {
                    for k in 0..25u64 {
                        let timing = StageTiming {
                            seconds: t as f64 + k as f64 * 1e-3,
                            calls: k,
                        };
                        append_timing(&d, &format!("node{t}"), timing).unwrap();
                    }
                })
            })
            .collect();
        threads.into_iter().for_each(|t| t.join().unwrap());
        let text = std::fs::read_to_string(dir.path().join(TIMINGS_FILE)).unwrap();
        let mut lines = text.lines();
        assert_eq!(lines.next(), Some("stage,seconds,calls"));
        let mut rows = 0;
        for line in lines {
            let f: Vec<&str> = line.split(',').collect();
            let t: u64 = f[0].strip_prefix("node").unwrap().parse().unwrap();
            let (secs, calls): (f64, u64) = (f[1].parse().unwrap(), f[2].parse().unwrap());
            assert_eq!(f.len(), 3, "{line}");
            assert!(
                (secs - (t as f64 + calls as f64 * 1e-3)).abs() < 1e-6,
                "{line}"
            );
            rows += 1;
        }
        assert_eq!(rows, 150);
        let missing = dir.path().join("absent");
        let e = append_timing(&missing, "x", StageTiming::default()).unwrap_err();
        assert!(e.to_string().contains("absent"), "{e}");
    }

    /// The catalog of the test operator `summer` (Counter `in` → Counter `sum`).
    fn summer_catalog() -> [OperatorDescriptor; 1] {
        [OperatorDescriptor {
            name: "summer",
            summary: "test",
            inputs: &[PortSpec {
                name: "in",
                kind: MessageKind::Counter,
            }],
            outputs: &[PortSpec {
                name: "sum",
                kind: MessageKind::Counter,
            }],
            evaluation: false,
            check_config: check_config_as::<SummerConfig>,
        }]
    }

    #[test]
    fn replay_feeds_inputs_in_order_and_delivers_stop_last() {
        let catalog = summer_catalog();
        let src = "nodes:\n  - id: s\n    operator: summer\n    config: { scale: 10 }\n    inputs:\n      in: s/sum\n";
        let flow = Dataflow::parse("t.yaml", src, PathBuf::new(), &catalog).unwrap();
        let spec = flow.node("s").unwrap();
        let inputs: Vec<_> = (1..=3)
            .map(|v| RecordedInput {
                port: "in".into(),
                seq: v as u64,
                bytes: Counter {
                    seq: v as u64,
                    value: v,
                }
                .to_bytes()
                .unwrap(),
            })
            .collect();
        let out = replay_to_vec(replay_operator::<Summer>, spec, &inputs, None).unwrap();
        let values: Vec<i64> = out
            .iter()
            .map(|o| Counter::from_bytes(&o.bytes).unwrap().value)
            .collect();
        assert_eq!(values, vec![10, 30, 60, -1]);
        // A garbled input is an error naming the port.
        let bad = [RecordedInput {
            port: "in".into(),
            seq: 1,
            bytes: vec![1, 0, 0xff],
        }];
        let err = replay_to_vec(replay_operator::<Summer>, spec, &bad, None)
            .unwrap_err()
            .to_string();
        assert!(err.contains("input `in`"), "{err}");
    }

    #[test]
    fn replay_streams_a_recording_and_matches_outputs_by_hash() {
        let catalog = summer_catalog();
        let src = "nodes:\n  - id: src\n    operator: summer\n    config: { scale: 1 }\n    inputs:\n      in: s/sum\n  - id: s\n    operator: summer\n    config: { scale: 10 }\n    inputs:\n      in: src/sum\n";
        let flow = Dataflow::parse("t.yaml", src, PathBuf::new(), &catalog).unwrap();
        let spec = flow.node("s").unwrap();
        let counter = |seq: u64, value: i64| Counter { seq, value }.to_bytes().unwrap();
        let dir = tempfile::tempdir().unwrap();
        let run = |sums: [i64; 4]| {
            // Each output is recorded after the next input: the comparison must wait for it.
            let mut msgs = vec![("src/sum", false, 1, counter(1, 1))];
            for v in 2..=3 {
                msgs.push(("src/sum", false, v, counter(v, v as i64)));
                msgs.push(("s/sum", false, v - 1, counter(v - 1, sums[v as usize - 2])));
            }
            msgs.push(("src/sum", false, 4, Vec::new()));
            msgs.push(("s/sum", false, 3, counter(3, sums[2])));
            msgs.push(("s/sum", false, 4, counter(0, sums[3])));
            let path = dir.path().join("rec.mcap");
            crate::record::write_test_recording(&path, src, None, &msgs, &[]);
            let reader = crate::record::RecordingReader::open(&path).unwrap();
            crate::record::replay_recording(
                reader,
                spec,
                replay_operator::<Summer>,
                &Default::default(),
            )
            .unwrap()
        };
        let good = run([10, 30, 60, -1]);
        assert_eq!(good.inputs, 4);
        assert!(!good.truncated);
        assert_eq!(good.report.per_port["sum"], (4, 4, 4));
        assert!(good.report.all_match());
        let bad = run([10, 31, 60, -1]);
        assert_eq!(bad.report.per_port["sum"], (3, 4, 4));
        assert!(!bad.report.all_match());
    }

    /// A chain x → a → b → c of running sums (scales 1, 1, 2, 10), where a's and b's outputs are
    /// recorded as digests only: replaying c must remake b/sum by replaying b, whose inputs are
    /// remade by replaying a on x's recorded outputs, and check each against its digest.
    #[test]
    fn replay_regenerates_inputs_recorded_as_digests() {
        use crate::record::{self, Producer, Producers, RecordingReader};
        let catalog = summer_catalog();
        let src = "nodes:\n\
          - { id: x, operator: summer, config: { scale: 1 }, inputs: { in: c/sum } }\n\
          - { id: a, operator: summer, config: { scale: 1 }, inputs: { in: x/sum } }\n\
          - { id: b, operator: summer, config: { scale: 2 }, inputs: { in: a/sum } }\n\
          - { id: c, operator: summer, config: { scale: 10 }, inputs: { in: b/sum } }\n";
        let flow = Dataflow::parse("t.yaml", src, PathBuf::new(), &catalog).unwrap();
        let counter = |seq: u64, value: i64| Counter { seq, value }.to_bytes().unwrap();
        // Worked by hand: a sums x's 1, 2, 3 and sends -1 (seq 0) at its stop; b doubles and
        // sums a's, c multiplies b's by ten and sums.
        let a_out = [(1, 1), (2, 3), (3, 6), (0, -1)];
        let b_out = [(1, 2), (2, 8), (3, 20), (0, 18), (0, -1)];
        let c_out = [(1, 20), (2, 100), (3, 300), (0, 480), (0, 470), (0, -1)];
        let dir = tempfile::tempdir().unwrap();
        let write = |name: &str, b_values: &[(u64, i64)], digests: &[&str]| {
            let mut msgs = Vec::new();
            let mut stream = |topic: &'static str, values: &[(u64, i64)]| {
                for (n, &(seq, v)) in values.iter().enumerate() {
                    msgs.push((topic, false, n as u64 + 1, counter(seq, v)));
                }
                msgs.push((topic, false, values.len() as u64 + 1, Vec::new()));
            };
            stream("x/sum", &[(1, 1), (2, 2), (3, 3)]);
            stream("a/sum", &a_out);
            stream("b/sum", b_values);
            stream("c/sum", &c_out);
            let path = dir.path().join(name);
            record::write_test_recording(&path, src, None, &msgs, digests);
            path
        };
        let producers: Producers = ["x", "a", "b", "c"]
            .iter()
            .map(|id| {
                let spec = flow.node(id).unwrap().clone();
                let producer = Producer {
                    spec,
                    port: "sum".into(),
                    replay: replay_operator::<Summer>,
                };
                (format!("{id}/sum"), producer)
            })
            .collect();
        let replay = |path: &std::path::Path, node: &str, producers: &Producers| {
            let reader = RecordingReader::open(path).unwrap();
            let spec = flow.node(node).unwrap();
            record::replay_recording(reader, spec, replay_operator::<Summer>, producers)
        };

        // Two levels of regeneration, every output of c matched.
        let good = write("good.mcap", &b_out, &["a/sum", "b/sum"]);
        let r = replay(&good, "c", &producers).unwrap();
        assert_eq!(r.report.per_port["sum"], (6, 6, 6));
        assert_eq!(r.inputs, 6);
        // The producer itself is compared with the digests of its outputs.
        let r = replay(&good, "b", &producers).unwrap();
        assert_eq!(r.report.per_port["sum"], (5, 5, 5));
        // Read without producers, a digest channel yields its 24-byte digests.
        let rec = record::read_recording(&good).unwrap();
        let b: Vec<_> = rec.messages.iter().filter(|m| m.topic == "b/sum").collect();
        assert_eq!(b.len(), 6);
        for (m, &(seq, v)) in b.iter().zip(&b_out) {
            assert!(m.digest_only);
            assert_eq!(
                record::parse_digest(&m.bytes),
                Some(record::digest(&counter(seq, v)))
            );
        }
        assert!(b[5].bytes.is_empty() && !b[5].digest_only);
        assert!(
            rec.messages
                .iter()
                .filter(|m| m.topic == "x/sum")
                .all(|m| !m.digest_only)
        );
        // Without a producer, c cannot be fed: a clear error naming the channel.
        let e = replay(&good, "c", &Producers::new())
            .unwrap_err()
            .to_string();
        assert!(e.contains("`b/sum` was recorded as digests"), "{e}");

        // A recorded digest the producer does not reproduce: named, message and channel.
        let wrong = [(1, 2), (2, 9), (3, 20), (0, 18), (0, -1)];
        let bad = write("bad.mcap", &wrong, &["a/sum", "b/sum"]);
        let e = replay(&bad, "c", &producers).unwrap_err().to_string();
        assert!(
            e.contains("message 2 of `b/sum`") && e.contains("differs from the recorded digest"),
            "{e}"
        );
        let r = replay(&bad, "b", &producers).unwrap();
        assert_eq!(r.report.per_port["sum"], (4, 5, 5));

        // Every channel a digest: remaking b/sum needs a/sum, x/sum, c/sum, then b/sum again.
        let cyclic = write("cyclic.mcap", &b_out, &["x/sum", "a/sum", "b/sum", "c/sum"]);
        let e = replay(&cyclic, "c", &producers).unwrap_err().to_string();
        assert!(e.contains("depends on itself"), "{e}");
    }
}
