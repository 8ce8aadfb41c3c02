//! The launcher: run every node of a dataflow as a subprocess, with per-node logs, a start barrier,
//! crash reporting with the tail of stderr, restart policies, clean stop on Ctrl-C, and recording.

use std::collections::{BTreeMap, BTreeSet};
use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use crate::RuntimeError;
use crate::dataflow::{Dataflow, NodeImpl, RestartPolicy};
use crate::finish_barrier::FinishBarrier;
use crate::node::{RunInfo, control_key, logs_dir};
use crate::progress::Progress;
use crate::record::{Recorder, RecorderOutputs, RecorderStats};
use crate::transport::{ZenohPublisher, ZenohSettings, ZenohSubscriber, open_zenoh, topic_key};
use activemap_schemas::MessageKind;

/// Options of [`run_local`].
#[derive(Debug, Clone)]
pub struct LaunchOptions {
    /// Run folder (created): logs, `run.json`, the dataflow copy, the recording.
    pub run_dir: PathBuf,
    /// The `activemap` executable that runs built-in operators (`activemap node ...`).
    pub exe: PathBuf,
    /// Step budget passed to the nodes.
    pub max_steps: Option<u64>,
    /// Write `recording.mcap`.
    pub record: bool,
    /// Message kinds the recording stores as digests when a built-in operator produces them
    /// (readers regenerate them by replay); the CLI names Gaussian maps unless `--record-maps
    /// full`. Empty: every payload is stored whole.
    pub record_digests: Vec<MessageKind>,
    /// Serve the view channels live on this `HOST:PORT` (`--view`); needs `derived`.
    pub view: Option<String>,
    /// Makes the derived channels of the recording (the view of the run), registered by the CLI;
    /// without it the recording holds the exact channels only.
    pub derived: Option<std::sync::Arc<dyn crate::derived::DerivedFactory>>,
    /// Show the run's progress on stderr, read from these messages (registered by the CLI).
    pub progress: Option<crate::progress::ProgressSource>,
    /// Give up when the nodes are not all ready after this long.
    pub startup_timeout: Duration,
    /// Grace period between SIGTERM and SIGKILL when stopping.
    pub stop_grace: Duration,
    /// Distributed mode (`activemap up`): launch only the nodes deployed on this machine, with a
    /// router on the machine's own endpoints connected to the other machines'.
    pub machine: Option<String>,
    /// Run id shared by every machine of a distributed run (default: a fresh one).
    pub run_id: Option<String>,
    /// Distributed mode: Zenoh `transport/link/tls` settings for the machines whose flow entry
    /// gives none (a daemon's mutual-TLS identity).
    pub tls: Option<serde_json::Value>,
}

impl LaunchOptions {
    /// Defaults for a run folder and executable.
    pub fn new(run_dir: PathBuf, exe: PathBuf) -> Self {
        Self {
            run_dir,
            exe,
            max_steps: None,
            record: true,
            record_digests: Vec::new(),
            view: None,
            derived: None,
            progress: None,
            startup_timeout: Duration::from_secs(60),
            stop_grace: Duration::from_secs(5),
            machine: None,
            run_id: None,
            tls: None,
        }
    }
}

/// How one node ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum NodeExit {
    /// Exited with status 0.
    Finished,
    /// Exited with a non-zero status or a signal.
    Crashed(String),
    /// Stopped by the launcher.
    Stopped,
}

/// Result of a run.
#[derive(Debug, Clone)]
pub struct RunReport {
    /// The run folder.
    pub run_dir: PathBuf,
    /// The run id.
    pub run_id: String,
    /// Per node: how it ended and how often it was restarted.
    pub nodes: BTreeMap<String, (NodeExit, u32)>,
    /// Why the flow stopped early (a crash report), if it did.
    pub failure: Option<String>,
    /// True when stopped by Ctrl-C / SIGTERM.
    pub interrupted: bool,
    /// Recorder statistics, when recording.
    pub recording: Option<RecorderStats>,
}

/// A fresh run id: unique per process and time.
pub fn new_run_id() -> String {
    let nanos = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    format!("r{:x}{:x}", std::process::id(), nanos & 0xffff_ffff_ffff)
}

/// A free TCP port on `ip` (bound then released).
pub fn free_port(ip: &str) -> Result<u16, RuntimeError> {
    let l = std::net::TcpListener::bind((ip, 0))
        .map_err(|e| RuntimeError::Other(format!("no free port on {ip}: {e}")))?;
    l.local_addr()
        .map(|a| a.port())
        .map_err(|e| RuntimeError::Other(e.to_string()))
}

/// Last `lines` lines of a file.
pub fn tail(path: &Path, lines: usize) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let all: Vec<&str> = text.lines().collect();
    all[all.len().saturating_sub(lines)..].join("\n")
}

fn describe_status(status: std::process::ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (status.code(), status.signal()) {
        (Some(c), _) => format!("exit status {c}"),
        (None, Some(s)) => format!(
            "killed by signal {s}{}",
            if s == 9 { " (SIGKILL)" } else { "" }
        ),
        _ => "unknown exit".into(),
    }
}

fn send_sigterm(child: &Child) {
    // SAFETY: kill(2) on the pid of a child we own and have not reaped yet.
    unsafe {
        libc::kill(child.id() as libc::pid_t, libc::SIGTERM);
    }
}

struct Running {
    child: Option<Child>,
    restarts: u32,
    exit: Option<NodeExit>,
}

/// Environment of an external (`path:`) node: everything it needs to join the run over Zenoh
/// without parsing the dataflow (see `sim-bridge/BRIDGE.md`). Values are plain strings or JSON.
///
/// - `ACTIVEMAP_RUN_DIR`, `ACTIVEMAP_NODE_ID`: the run folder and this node's id (every node);
/// - `ACTIVEMAP_RUN_ID`: the run id, which prefixes every key;
/// - `ACTIVEMAP_ZENOH_CONNECT`: JSON list of the Zenoh router endpoints to connect to (client mode);
/// - `ACTIVEMAP_INPUTS` / `ACTIVEMAP_OUTPUTS`: JSON objects, port name → Zenoh key;
/// - `ACTIVEMAP_CONTROL`: key prefix of the control topics (`<prefix>/ready/<id>`,
///   `<prefix>/start`, `<prefix>/stop`);
/// - `ACTIVEMAP_CONFIG`: the node's `config:` as JSON (`null` when absent);
/// - `ACTIVEMAP_MAX_STEPS`: the `--max-steps` budget, when given.
pub fn external_node_env(
    dataflow: &Dataflow,
    run: &RunInfo,
    id: &str,
) -> Result<Vec<(String, String)>, RuntimeError> {
    let spec = dataflow
        .node(id)
        .ok_or_else(|| RuntimeError::UnknownNode(id.into()))?;
    let inputs: serde_json::Map<String, serde_json::Value> = spec
        .inputs
        .iter()
        .map(|i| {
            (
                i.name.clone(),
                topic_key(&run.run_id, &i.source_node, &i.source_output).into(),
            )
        })
        .collect();
    let outputs: serde_json::Map<String, serde_json::Value> = spec
        .outputs
        .iter()
        .map(|o| (o.name.clone(), topic_key(&run.run_id, id, &o.name).into()))
        .collect();
    let connect = run.client_settings(&spec.machine).connect;
    let json = |v: &serde_json::Value| serde_json::to_string(v).expect("JSON values serialise");
    let mut env = vec![
        ("ACTIVEMAP_RUN_ID".to_string(), run.run_id.clone()),
        (
            "ACTIVEMAP_ZENOH_CONNECT".to_string(),
            json(&serde_json::json!(connect)),
        ),
        (
            "ACTIVEMAP_INPUTS".to_string(),
            json(&serde_json::Value::Object(inputs)),
        ),
        (
            "ACTIVEMAP_OUTPUTS".to_string(),
            json(&serde_json::Value::Object(outputs)),
        ),
        (
            "ACTIVEMAP_CONTROL".to_string(),
            control_key(&run.run_id, "")
                .trim_end_matches('/')
                .to_string(),
        ),
        ("ACTIVEMAP_CONFIG".to_string(), json(&spec.config)),
    ];
    if let Some(n) = run.max_steps {
        env.push(("ACTIVEMAP_MAX_STEPS".to_string(), n.to_string()));
    }
    Ok(env)
}

/// Start the node `id`'s process with logs under the run folder.
fn spawn_node(
    dataflow: &Dataflow,
    run: &RunInfo,
    id: &str,
    opts: &LaunchOptions,
) -> Result<Child, RuntimeError> {
    let spec = dataflow
        .node(id)
        .ok_or_else(|| RuntimeError::UnknownNode(id.into()))?;
    let logs = logs_dir(&opts.run_dir);
    let out_path = logs.join(format!("{id}.stdout.log"));
    let err_path = logs.join(format!("{id}.stderr.log"));
    let open = |p: &Path| {
        File::options()
            .create(true)
            .append(true)
            .open(p)
            .map_err(|e| RuntimeError::io(p, e))
    };
    let mut cmd = match &spec.implementation {
        NodeImpl::Operator(_) => {
            let mut c = Command::new(&opts.exe);
            c.arg("node")
                .arg("--run-dir")
                .arg(&opts.run_dir)
                .arg("--node")
                .arg(id);
            c
        }
        NodeImpl::Path { path, args } => {
            let p = Path::new(path);
            let exe = if p.is_absolute() {
                p.to_path_buf()
            } else {
                dataflow.base_dir.join(p)
            };
            let mut c = Command::new(exe);
            c.args(args).envs(external_node_env(dataflow, run, id)?);
            c
        }
    };
    cmd.env("ACTIVEMAP_RUN_DIR", &opts.run_dir)
        .env("ACTIVEMAP_NODE_ID", id)
        .stdin(Stdio::null())
        .stdout(open(&out_path)?)
        .stderr(open(&err_path)?);
    cmd.spawn()
        .map_err(|e| RuntimeError::Other(format!("cannot start node `{id}`: {e}")))
}

/// Run every node of `dataflow` on this machine until they all finish, one crashes (per its restart
/// policy), or `stop` is set (Ctrl-C). Nodes are started behind a barrier: no node sends before
/// every node has subscribed.
pub fn run_local(
    dataflow: &Dataflow,
    opts: &LaunchOptions,
    stop: Arc<AtomicBool>,
) -> Result<RunReport, RuntimeError> {
    std::fs::create_dir_all(logs_dir(&opts.run_dir))
        .map_err(|e| RuntimeError::io(&opts.run_dir, e))?;
    let yaml_copy = opts.run_dir.join(RunInfo::DATAFLOW);
    std::fs::write(&yaml_copy, &dataflow.source).map_err(|e| RuntimeError::io(&yaml_copy, e))?;
    let run_id = opts.run_id.clone().unwrap_or_else(new_run_id);
    let (run, router) = match &opts.machine {
        None => {
            let port = free_port("127.0.0.1")?;
            let endpoint = format!("tcp/127.0.0.1:{port}");
            // One local router serves every machine of the file: `run` launches all nodes here.
            let run = RunInfo {
                run_id: run_id.clone(),
                routers: dataflow
                    .machines
                    .iter()
                    .map(|m| (m.id.clone(), vec![endpoint.clone()]))
                    .collect(),
                tls: BTreeMap::new(),
                max_steps: opts.max_steps,
            };
            let router = ZenohSettings {
                mode: "router".into(),
                listen: vec![endpoint],
                connect: vec![],
                tls: None,
            };
            (run, router)
        }
        Some(machine) => {
            let spec = dataflow.machine(machine).ok_or_else(|| {
                RuntimeError::Other(format!("machine `{machine}` is not in the dataflow"))
            })?;
            if spec.listen.iter().any(|e| e.ends_with(":0")) {
                return Err(RuntimeError::Other(format!(
                    "machine `{machine}` needs explicit `listen` endpoints (with a port) for a distributed run"
                )));
            }
            let run = RunInfo {
                run_id: run_id.clone(),
                routers: dataflow
                    .machines
                    .iter()
                    .map(|m| (m.id.clone(), m.listen.clone()))
                    .collect(),
                tls: dataflow
                    .machines
                    .iter()
                    .filter_map(|m| {
                        m.tls
                            .clone()
                            .or_else(|| opts.tls.clone())
                            .map(|t| (m.id.clone(), t))
                    })
                    .collect(),
                max_steps: opts.max_steps,
            };
            let router = ZenohSettings {
                mode: "router".into(),
                listen: spec.listen.clone(),
                connect: spec.connect.clone(),
                tls: spec.tls.clone().or_else(|| opts.tls.clone()),
            };
            (run, router)
        }
    };
    run.save(&opts.run_dir)?;
    let session = open_zenoh(&router)?;
    // A distributed run's machines keep their routers up until all of them are done.
    let finish_barrier = match &opts.machine {
        Some(machine) => FinishBarrier::declare(
            &session,
            &run.run_id,
            machine,
            dataflow.machines.iter().map(|m| m.id.clone()),
        )?,
        None => None,
    };
    let derived = match (&opts.derived, &opts.view) {
        (Some(factory), live) if opts.record || live.is_some() => {
            Some(factory.start(live.as_deref())?)
        }
        (None, Some(address)) => {
            return Err(RuntimeError::Other(format!(
                "--view {address}: this build registered no view to serve"
            )));
        }
        _ => None,
    };
    let recorder = if opts.record || opts.view.is_some() {
        Some(Recorder::start(
            RecorderOutputs {
                file: opts.record.then(|| opts.run_dir.join("recording.mcap")),
                derived,
                digests: opts.record_digests.clone(),
            },
            dataflow,
            &run,
            session.clone(),
            opts.machine.as_deref(),
        )?)
    } else {
        None
    };
    let result = supervise(dataflow, opts, &run, &session, &stop, recorder.as_ref());
    if let (Some(barrier), Ok((_, None, false))) = (&finish_barrier, &result) {
        let gone = barrier.wait_for_others(&stop, |m| eprintln!("{m}"))?;
        if !gone.is_empty() {
            eprintln!(
                "activemap: machine(s) {} ended without saying their nodes were done",
                gone.join(", ")
            );
        }
    }
    let finished = recorder.map(Recorder::finish).transpose();
    let _ = zenoh::Wait::wait(session.close());
    // Statistics only when a file was written (the live view alone records nothing).
    let recording = finished
        .map_err(|e| RuntimeError::Other(format!("{e}; the run was stopped")))?
        .and_then(|stats| stats.into_recorded(opts.record));
    let (nodes, failure, interrupted) = result?;
    Ok(RunReport {
        run_dir: opts.run_dir.clone(),
        run_id,
        nodes,
        failure,
        interrupted,
        recording,
    })
}

type Supervised = (BTreeMap<String, (NodeExit, u32)>, Option<String>, bool);

fn supervise(
    dataflow: &Dataflow,
    opts: &LaunchOptions,
    run: &RunInfo,
    session: &zenoh::Session,
    stop: &AtomicBool,
    recorder: Option<&Recorder>,
) -> Result<Supervised, RuntimeError> {
    let ready_sub = ZenohSubscriber::create(
        session,
        &control_key(&run.run_id, "ready/*"),
        1024,
        crate::dataflow::DropPolicy::DropOldest,
    )?;
    let start_pub = ZenohPublisher::create(session, &control_key(&run.run_id, "start"))?;
    let stop_pub = ZenohPublisher::create(session, &control_key(&run.run_id, "stop"))?;
    // A stop broadcast by another machine or by `activemap stop`.
    let stop_sub = ZenohSubscriber::create(
        session,
        &control_key(&run.run_id, "stop"),
        1,
        crate::dataflow::DropPolicy::DropOldest,
    )?;
    let mut nodes: BTreeMap<String, Running> = BTreeMap::new();
    let everyone: Vec<&str> = dataflow.nodes.iter().map(|n| n.id.as_str()).collect();
    for n in dataflow
        .nodes
        .iter()
        .filter(|n| opts.machine.as_ref().is_none_or(|m| *m == n.machine))
    {
        let child = spawn_node(dataflow, run, &n.id, opts);
        let child = match child {
            Ok(c) => c,
            Err(e) => {
                for r in nodes.values_mut() {
                    if let Some(c) = &mut r.child {
                        let _ = c.kill();
                        let _ = c.wait();
                    }
                }
                return Err(e);
            }
        };
        nodes.insert(
            n.id.clone(),
            Running {
                child: Some(child),
                restarts: 0,
                exit: None,
            },
        );
    }
    let mut progress = opts
        .progress
        .map(|source| Progress::new(source.noun, opts.max_steps));
    // The run's progress: every output of the progress source's kind.
    let progress_subs = progress_subscribers(dataflow, run, session, opts.progress)?;
    let say = |progress: &Option<Progress>, message: String| match progress {
        Some(p) => p.println(&message),
        None => eprintln!("{message}"),
    };
    let started_at = Instant::now();
    let mut ready: BTreeSet<String> = BTreeSet::new();
    let mut barrier_open = false;
    let mut failure: Option<String> = None;
    let mut interrupted = false;
    loop {
        while let Some(sample) = ready_sub.recv(None)? {
            let id = String::from_utf8_lossy(&sample.payload().to_bytes()).to_string();
            let fresh = ready.insert(id);
            if barrier_open && fresh {
                start_pub.send(0, Vec::new())?;
            }
        }
        // The barrier spans every machine: remote nodes announce through the connected routers.
        if !barrier_open && everyone.iter().all(|id| ready.contains(*id)) {
            barrier_open = true;
        }
        if barrier_open && started_at.elapsed() < Duration::from_secs(600) {
            // Repeat `start` while nodes may still be waiting (restarts, late subscribers).
            start_pub.send(0, Vec::new())?;
        }
        if !barrier_open && started_at.elapsed() > opts.startup_timeout {
            let missing: Vec<_> = everyone.iter().filter(|id| !ready.contains(**id)).collect();
            failure = Some(format!(
                "nodes not ready after {:?}: {}",
                opts.startup_timeout,
                missing
                    .iter()
                    .map(|s| s.to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
            break;
        }
        if stop.load(Ordering::Relaxed) || stop_sub.recv(None)?.is_some() {
            interrupted = true;
            break;
        }
        if let Some(p) = &mut progress {
            drain_statuses(&progress_subs, p, None)?;
        }
        let mut crashed = None;
        for (id, r) in nodes.iter_mut() {
            let Some(child) = &mut r.child else { continue };
            let Ok(Some(status)) = child.try_wait() else {
                continue;
            };
            r.child = None;
            if status.success() {
                r.exit = Some(NodeExit::Finished);
                say(&progress, format!("activemap: node `{id}` finished"));
                continue;
            }
            let what = describe_status(status);
            let stderr_tail = tail(
                &logs_dir(&opts.run_dir).join(format!("{id}.stderr.log")),
                20,
            );
            let spec = dataflow.node(id).expect("launched from the dataflow");
            let report = format!(
                "node `{id}` crashed: {what}\n--- last lines of {} ---\n{stderr_tail}",
                logs_dir(&opts.run_dir)
                    .join(format!("{id}.stderr.log"))
                    .display()
            );
            say(&progress, format!("activemap: {report}"));
            match spec.restart {
                RestartPolicy::OnFailure(max) if r.restarts < max => {
                    r.restarts += 1;
                    ready.remove(id);
                    say(
                        &progress,
                        format!("activemap: restarting `{id}` ({}/{max})", r.restarts),
                    );
                    r.child = Some(spawn_node(dataflow, run, id, opts)?);
                }
                _ => {
                    r.exit = Some(NodeExit::Crashed(what));
                    crashed = Some(report);
                }
            }
        }
        if let Some(report) = crashed {
            failure = Some(report);
            break;
        }
        // A recorder that failed (e.g. a full disk) stops the run: nothing goes unrecorded.
        if recorder.is_some_and(Recorder::failed) {
            failure = Some("the recorder failed; stopping the run".into());
            break;
        }
        if nodes.values().all(|r| r.child.is_none()) {
            break;
        }
        if let Some(p) = &mut progress {
            let running: Vec<_> = nodes
                .iter()
                .filter(|(_, r)| r.child.is_some())
                .map(|(id, _)| id.as_str())
                .collect();
            p.waiting(&format!(
                "{}/{} nodes running: {}",
                running.len(),
                nodes.len(),
                running.join(" ")
            ));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    // Stop whatever still runs: broadcast stop, SIGTERM, then SIGKILL after the grace period.
    // Other machines stop too when this one failed or was stopped (not when it simply finished).
    if failure.is_some() || interrupted {
        let _ = stop_pub.send(0, Vec::new());
    }
    for r in nodes.values() {
        if let Some(c) = &r.child {
            send_sigterm(c);
        }
    }
    let deadline = Instant::now() + opts.stop_grace;
    for (id, r) in nodes.iter_mut() {
        let Some(child) = &mut r.child else { continue };
        loop {
            match child.try_wait() {
                Ok(Some(_)) => {
                    r.exit.get_or_insert(NodeExit::Stopped);
                    break;
                }
                Ok(None) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(20))
                }
                _ => {
                    say(
                        &progress,
                        format!("activemap: node `{id}` ignored SIGTERM; killing it"),
                    );
                    let _ = child.kill();
                    let _ = child.wait();
                    r.exit.get_or_insert(NodeExit::Stopped);
                    break;
                }
            }
        }
        r.child = None;
    }
    if let Some(mut p) = progress {
        // The simulator's last status may arrive after its process ended.
        if !p.ended() {
            drain_statuses(&progress_subs, &mut p, Some(Duration::from_millis(300)))?;
        }
        p.finish();
    }
    let summary = nodes
        .into_iter()
        .map(|(id, r)| (id, (r.exit.unwrap_or(NodeExit::Stopped), r.restarts)))
        .collect();
    Ok((summary, failure, interrupted))
}

/// Hands every waiting progress message to `progress`, read by `subs`' source; with `wait`,
/// waits that long for one more on each subscriber until the run's end is seen.
fn drain_statuses(
    subs: &ProgressSubscribers,
    progress: &mut Progress,
    wait: Option<Duration>,
) -> Result<(), RuntimeError> {
    for sub in &subs.subscribers {
        while let Some(sample) = sub.recv(wait.filter(|_| !progress.ended()))? {
            if let Some(status) = (subs.read)(&sample.payload().to_bytes()) {
                progress.status(&status);
            }
        }
    }
    Ok(())
}

/// Subscribers to every progress output of a flow, and how to read them.
struct ProgressSubscribers {
    subscribers: Vec<ZenohSubscriber>,
    read: fn(&[u8]) -> Option<crate::progress::StepStatus>,
}

/// Subscribers to every output of `source`'s kind in the dataflow (small messages travel on
/// Zenoh); none without a source.
fn progress_subscribers(
    dataflow: &Dataflow,
    run: &RunInfo,
    session: &zenoh::Session,
    source: Option<crate::progress::ProgressSource>,
) -> Result<ProgressSubscribers, RuntimeError> {
    let mut subscribers = Vec::new();
    if let Some(source) = source {
        for n in &dataflow.nodes {
            for o in n.outputs.iter().filter(|o| o.kind == source.kind) {
                subscribers.push(ZenohSubscriber::create(
                    session,
                    &topic_key(&run.run_id, &n.id, &o.name),
                    256,
                    crate::dataflow::DropPolicy::DropOldest,
                )?);
            }
        }
    }
    Ok(ProgressSubscribers {
        subscribers,
        read: source.map_or(|_| None, |s| s.read),
    })
}

/// Broadcast a stop to every node and daemon of run `run_id` through the router at `connect`.
pub fn stop_run(run_id: &str, connect: &[String]) -> Result<(), RuntimeError> {
    let session = open_zenoh(&ZenohSettings {
        mode: "client".into(),
        listen: vec![],
        connect: connect.to_vec(),
        tls: None,
    })?;
    let sent = broadcast_stop(&session, run_id);
    let _ = zenoh::Wait::wait(session.close());
    sent
}

/// Publish run `run_id`'s stop on an open session: every node, launcher and daemon of the run
/// hears it.
pub fn broadcast_stop(session: &zenoh::Session, run_id: &str) -> Result<(), RuntimeError> {
    let publisher = ZenohPublisher::create(session, &control_key(run_id, "stop"))?;
    // Give the declaration time to reach the router, then repeat to be safe.
    for _ in 0..5 {
        std::thread::sleep(Duration::from_millis(100));
        publisher.send(0, Vec::new())?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::node::{output_needs_zenoh, readable_from_shm};
    use crate::{OperatorDescriptor, PortSpec};
    use activemap_schemas::MessageKind;

    fn accept_any(_: &serde_json::Value) -> Result<(), String> {
        Ok(())
    }

    /// A built-in camera and viewer around an external simulator (`path:`).
    fn flow() -> Dataflow {
        let catalog = [
            OperatorDescriptor {
                name: "viewer",
                summary: "test",
                inputs: &[PortSpec {
                    name: "frame",
                    kind: MessageKind::RgbdFrame,
                }],
                outputs: &[PortSpec {
                    name: "action",
                    kind: MessageKind::Action,
                }],
                evaluation: false,
                check_config: accept_any,
            },
            OperatorDescriptor {
                name: "camera",
                summary: "test",
                inputs: &[],
                outputs: &[PortSpec {
                    name: "frame",
                    kind: MessageKind::RgbdFrame,
                }],
                evaluation: false,
                check_config: accept_any,
            },
        ];
        let src = "nodes:
  - id: ext
    path: ./sim.py
    args: [--fast]
    config: { scene: box }
    outputs: [{ id: rgbd, type: RgbdFrame }]
    inputs:
      action: view/action
      frame: cam/frame
  - id: view
    operator: viewer
    inputs:
      frame: ext/rgbd
  - id: cam
    operator: camera
  - id: view2
    operator: viewer
    inputs:
      frame: cam/frame
";
        Dataflow::parse("t.yaml", src, PathBuf::new(), &catalog).unwrap()
    }

    #[test]
    fn external_nodes_exchange_large_topics_over_zenoh() {
        let flow = flow();
        // An external producer publishes on Zenoh only: its consumers may not read iceoryx2.
        assert!(!readable_from_shm(
            &flow,
            "ext",
            crate::dataflow::DEFAULT_MACHINE
        ));
        // A built-in producer on the same machine is read from shared memory ...
        assert!(readable_from_shm(
            &flow,
            "cam",
            crate::dataflow::DEFAULT_MACHINE
        ));
        // ... and also bridged to Zenoh because an external node consumes it.
        assert!(output_needs_zenoh(&flow, "cam", "frame"));
        // Small messages to an external consumer are on Zenoh anyway; an output nobody
        // external or remote reads gets no Zenoh copy.
        assert!(output_needs_zenoh(&flow, "view", "action"));
        assert!(!output_needs_zenoh(&flow, "view2", "action"));
    }

    #[test]
    fn external_node_environment_names_every_key() {
        let flow = flow();
        let run = RunInfo {
            run_id: "r1".into(),
            routers: [(
                crate::dataflow::DEFAULT_MACHINE.to_string(),
                vec!["tcp/127.0.0.1:7447".to_string()],
            )]
            .into(),
            tls: BTreeMap::new(),
            max_steps: Some(20),
        };
        let env: BTreeMap<String, String> = external_node_env(&flow, &run, "ext")
            .unwrap()
            .into_iter()
            .collect();
        let json = |k: &str| serde_json::from_str::<serde_json::Value>(&env[k]).unwrap();
        assert_eq!(env["ACTIVEMAP_RUN_ID"], "r1");
        assert_eq!(
            json("ACTIVEMAP_ZENOH_CONNECT"),
            serde_json::json!(["tcp/127.0.0.1:7447"])
        );
        assert_eq!(
            json("ACTIVEMAP_INPUTS"),
            serde_json::json!({"action": "activemap/r1/view/action", "frame": "activemap/r1/cam/frame"})
        );
        assert_eq!(
            json("ACTIVEMAP_OUTPUTS"),
            serde_json::json!({"rgbd": "activemap/r1/ext/rgbd"})
        );
        assert_eq!(env["ACTIVEMAP_CONTROL"], "activemap/r1/_ctl");
        assert_eq!(
            json("ACTIVEMAP_CONFIG"),
            serde_json::json!({"scene": "box"})
        );
        assert_eq!(env["ACTIVEMAP_MAX_STEPS"], "20");
        assert!(external_node_env(&flow, &run, "nobody").is_err());
    }
}
