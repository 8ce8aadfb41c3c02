//! The machine daemon (`activemap up --machine M`): a long-lived process per machine that accepts
//! dataflows submitted by `activemap start`, runs the share of each flow deployed on its machine
//! (through [`run_local`] with that machine), and answers `list`, `logs` and `down` requests.
//!
//! Daemons talk over Zenoh queries on their own control endpoints (never multicast):
//! `activemap/daemon/<machine>/<verb>`, verbs `start`, `runs`, `logs` and `down`. A daemon
//! started with `--connect` to another daemon's endpoint joins its network, so a client that
//! connects to any one daemon reaches them all. The data plane of a run is separate: it uses the
//! endpoints that the flow's `machines:` section gives.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use zenoh::Wait;
use zenoh::query::{ConsolidationMode, QueryTarget};

use crate::OperatorDescriptor;
use crate::RuntimeError;
use crate::dataflow::Dataflow;
use crate::launch::{LaunchOptions, NodeExit, broadcast_stop, new_run_id, run_local, tail};
use crate::node::logs_dir;
use crate::tls::TlsFiles;
use crate::transport::{ZenohSettings, open_zenoh};

/// Zenoh key of a daemon request: `activemap/daemon/<machine>/<verb>` (`*` for every machine).
pub fn daemon_key(machine: &str, verb: &str) -> String {
    format!("activemap/daemon/{machine}/{verb}")
}

/// A service a daemon offers besides running flows, registered by whoever starts the daemon
/// (the CLI: benchmark episodes for remote clients, `activemap_bench::episodes`): it answers the
/// queries of its own verbs and is polled between queries.
pub trait DaemonService {
    /// Answers a query; `None` when `verb` is not one of its verbs. `catalog` validates flows.
    fn answer(
        &mut self,
        verb: &str,
        payload: &[u8],
        catalog: &[OperatorDescriptor],
    ) -> Option<Result<Vec<u8>, String>>;
    /// Called between queries (about every 200 ms): reap finished work.
    fn poll(&mut self) {}
    /// The daemon is stopping: stop what it runs.
    fn shutdown(&mut self) {}
}

/// How a daemon is started.
#[derive(Debug, Clone)]
pub struct DaemonOptions {
    /// This machine's id, as named in the flows' `machines:` sections.
    pub machine: String,
    /// Control endpoints to listen on, e.g. `tcp/127.0.0.2:7400`.
    pub listen: Vec<String>,
    /// Control endpoints of other daemons to join.
    pub connect: Vec<String>,
    /// Folder of run folders (`<runs_dir>/<run_id>`).
    pub runs_dir: PathBuf,
    /// The `activemap` executable that runs built-in operators.
    pub exe: PathBuf,
    /// `path:` executables of submitted flows are relative to this folder.
    pub base_dir: PathBuf,
    /// Folders whose executables a submitted flow's `path:` nodes may run (`--allow-exec`);
    /// empty: no `path:` node is run at all, only built-in operators.
    pub allow_exec: Vec<PathBuf>,
    /// Accept listening on a non-loopback address without TLS (`--insecure`), with a warning
    /// at start and at every submitted flow.
    pub insecure: bool,
    /// Mutual TLS (`--tls-ca/--tls-cert/--tls-key`): required of every client and daemon on
    /// the `quic/` and `tls/` control endpoints, and the default for those of the runs it
    /// starts (a flow's own `machines[].tls` wins).
    pub tls: Option<TlsFiles>,
    /// Makes the derived channels (the view) of the recordings of the runs it starts.
    pub derived: Option<Arc<dyn crate::derived::DerivedFactory>>,
    /// Message kinds the recordings of its runs store as digests
    /// ([`LaunchOptions::record_digests`]).
    pub record_digests: Vec<activemap_schemas::MessageKind>,
}

/// True when a Zenoh endpoint (`tcp/HOST:PORT`, `udp/…`, `tls/…`, optionally with a
/// `#…`/`?…` suffix) names a loopback host: `localhost`, 127.0.0.0/8 or ::1.
pub fn endpoint_is_loopback(endpoint: &str) -> bool {
    let rest = endpoint.split_once('/').map_or(endpoint, |(_, r)| r);
    let rest = rest.split(['#', '?']).next().unwrap_or(rest);
    let host = match rest.strip_prefix('[') {
        Some(v6) => v6.split(']').next().unwrap_or(""),
        None => rest.rsplit_once(':').map_or(rest, |(h, _)| h),
    };
    host.eq_ignore_ascii_case("localhost")
        || host
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback())
}

/// True when `endpoint` is a `tls/` or `quic/` endpoint: both take the mutual-TLS settings
/// (QUIC runs TLS 1.3 itself).
fn is_tls_endpoint(endpoint: &str) -> bool {
    endpoint.starts_with("tls/") || endpoint.starts_with("quic/")
}

/// The endpoints of `listen` that anyone on the network can reach unauthenticated: not
/// loopback, and not `tls/` or `quic/` with mutual TLS on.
fn exposed_endpoints(listen: &[String], tls: bool) -> Vec<String> {
    listen
        .iter()
        .filter(|e| !(endpoint_is_loopback(e) || (tls && is_tls_endpoint(e))))
        .cloned()
        .collect()
}

/// Refuses a daemon that would listen on a non-loopback address without mutual TLS, unless
/// `insecure`; returns the exposed endpoints (to warn about) when it is allowed. With `tls`,
/// `quic/` and `tls/` endpoints are protected; such an endpoint without TLS files is refused.
pub fn check_listen(
    listen: &[String],
    insecure: bool,
    tls: bool,
) -> Result<Vec<String>, RuntimeError> {
    if !tls && let Some(e) = listen.iter().find(|e| is_tls_endpoint(e)) {
        return Err(RuntimeError::Other(format!(
            "`{e}` is a TLS endpoint: give the daemon its --tls-ca, --tls-cert and --tls-key"
        )));
    }
    let exposed = exposed_endpoints(listen, tls);
    if !exposed.is_empty() && !insecure {
        return Err(RuntimeError::Other(format!(
            "refusing to listen on {} without TLS: anyone who can reach it could submit flows \
             to this machine; listen on a loopback address, use `quic/` or `tls/` endpoints with \
             --tls-ca/--tls-cert/--tls-key (mutual TLS), or pass --insecure to accept the risk",
            exposed.join(", ")
        )));
    }
    Ok(exposed)
}

/// Refuses a flow whose `path:` nodes deployed on `machine` run an executable outside the
/// `allowed` folders, naming each such node; a path is resolved against the flow's folder
/// and compared after resolving symbolic links and `..`.
pub fn check_exec_allowed(
    flow: &Dataflow,
    machine: &str,
    allowed: &[PathBuf],
) -> Result<(), String> {
    let allowed: Vec<PathBuf> = allowed
        .iter()
        .filter_map(|d| std::fs::canonicalize(d).ok())
        .collect();
    let mut refused = Vec::new();
    for node in flow.nodes.iter().filter(|n| n.machine == machine) {
        let crate::dataflow::NodeImpl::Path { path, .. } = &node.implementation else {
            continue;
        };
        let p = Path::new(path);
        let exe = if p.is_absolute() {
            p.to_path_buf()
        } else {
            flow.base_dir.join(p)
        };
        let inside = std::fs::canonicalize(&exe)
            .is_ok_and(|exe| allowed.iter().any(|dir| exe.starts_with(dir)));
        if !inside {
            refused.push(format!(
                "node `{}`: executable `{path}` is outside the daemon's --allow-exec folders ({})",
                node.id,
                if allowed.is_empty() {
                    "none given".to_string()
                } else {
                    allowed
                        .iter()
                        .map(|d| d.display().to_string())
                        .collect::<Vec<_>>()
                        .join(", ")
                }
            ));
        }
    }
    if refused.is_empty() {
        Ok(())
    } else {
        Err(format!("{}: refused: {}", flow.file, refused.join("; ")))
    }
}

/// A flow submitted to the daemons (`activemap start`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StartRequest {
    /// Run id shared by every machine of the run.
    pub run_id: String,
    /// Name of the submitted file (for messages).
    pub file: String,
    /// The dataflow text.
    pub source: String,
    /// Step budget passed to the nodes.
    pub max_steps: Option<u64>,
    /// Write a recording of this machine's topics.
    pub record: bool,
}

/// State of a run on one machine.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum RunState {
    /// Nodes are running.
    Running,
    /// Every node finished (or was stopped on request).
    Finished,
    /// A node crashed or the launch failed; the reason.
    Failed(String),
}

/// One run as a daemon reports it (`activemap list`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RunEntry {
    /// Machine that reports it.
    pub machine: String,
    /// Run id.
    pub run_id: String,
    /// Run folder on that machine.
    pub run_dir: PathBuf,
    /// State.
    pub state: RunState,
}

/// A request for the tail of a run's logs (`activemap logs --run-id`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LogsRequest {
    /// Run id.
    pub run_id: String,
    /// Only this node's logs.
    pub node: Option<String>,
    /// Lines per log file.
    pub lines: usize,
}

/// One log file's tail, as a daemon returns it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LogTail {
    /// Machine it comes from.
    pub machine: String,
    /// File name, e.g. `tracker.stderr.log`.
    pub file: String,
    /// The last lines.
    pub text: String,
}

struct Run {
    dir: PathBuf,
    state: Arc<Mutex<RunState>>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

/// Run the daemon until `stop` is set (Ctrl-C) or a `down` request arrives. Running flows are
/// stopped cleanly before it returns.
pub fn serve(
    opts: &DaemonOptions,
    catalog: &[OperatorDescriptor],
    services: &mut [Box<dyn DaemonService>],
    stop: Arc<AtomicBool>,
) -> Result<(), RuntimeError> {
    if opts.listen.is_empty() {
        return Err(RuntimeError::Other(
            "a daemon needs at least one explicit --listen endpoint (e.g. tcp/127.0.0.1:7400)"
                .into(),
        ));
    }
    let exposed = check_listen(&opts.listen, opts.insecure, opts.tls.is_some())?;
    if !exposed.is_empty() {
        eprintln!("{}", insecure_warning(&exposed));
    }
    std::fs::create_dir_all(&opts.runs_dir).map_err(|e| RuntimeError::io(&opts.runs_dir, e))?;
    let session = open_zenoh(&ZenohSettings {
        mode: "router".into(),
        listen: opts.listen.clone(),
        connect: opts.connect.clone(),
        tls: opts.tls.as_ref().map(TlsFiles::zenoh_config),
    })?;
    let queryable = session
        .declare_queryable(daemon_key(&opts.machine, "*"))
        .wait()
        .map_err(|e| RuntimeError::Other(format!("daemon queryable: {e}")))?;
    eprintln!(
        "activemap daemon `{}` listening on {} (runs in {})",
        opts.machine,
        opts.listen.join(", "),
        opts.runs_dir.display()
    );
    let mut runs: BTreeMap<String, Run> = BTreeMap::new();
    while !stop.load(Ordering::SeqCst) {
        for service in services.iter_mut() {
            service.poll();
        }
        // Join the supervisors of finished runs: a joinable thread keeps its stack until then
        // (a long-lived daemon would grow by one per run).
        for run in runs.values_mut() {
            if run.thread.as_ref().is_some_and(|t| t.is_finished())
                && let Some(t) = run.thread.take()
                && t.join().is_err()
            {
                eprintln!("activemap daemon: a run supervisor panicked");
            }
        }
        let query = match queryable.recv_timeout(Duration::from_millis(200)) {
            Ok(Some(q)) => q,
            Ok(None) => continue,
            Err(e) => return Err(RuntimeError::Other(format!("daemon queryable: {e}"))),
        };
        let verb = query
            .key_expr()
            .as_str()
            .rsplit('/')
            .next()
            .unwrap_or_default()
            .to_string();
        let payload = query.payload().map(|p| p.to_bytes().to_vec());
        let answer: Result<Vec<u8>, String> = match verb.as_str() {
            "start" => start_run(opts, catalog, payload.as_deref(), &mut runs),
            "runs" => Ok(serde_json::to_vec(&entries(&opts.machine, &runs)).expect("serialisable")),
            "logs" => logs(&opts.machine, payload.as_deref(), &runs),
            "down" => {
                stop.store(true, Ordering::SeqCst);
                Ok(b"down".to_vec())
            }
            other => services
                .iter_mut()
                .find_map(|s| s.answer(other, payload.as_deref().unwrap_or_default(), catalog))
                .unwrap_or_else(|| Err(format!("unknown daemon request `{other}`"))),
        };
        let key = daemon_key(&opts.machine, &verb);
        let sent = match answer {
            Ok(bytes) => query.reply(key, bytes).wait(),
            Err(why) => query.reply_err(why.into_bytes()).wait(),
        };
        if let Err(e) = sent {
            eprintln!("activemap daemon: cannot answer a `{verb}` request: {e}");
        }
    }
    for service in services.iter_mut() {
        service.shutdown();
    }
    for (id, run) in &mut runs {
        run.stop.store(true, Ordering::SeqCst);
        if let Some(t) = run.thread.take()
            && t.join().is_err()
        {
            eprintln!("activemap daemon: the supervisor of run {id} panicked");
        }
    }
    drop(queryable);
    // Linger: this daemon may be the router through which other daemons' answers to the same
    // `down` request travel back to the client.
    std::thread::sleep(Duration::from_secs(1));
    let _ = session.close().wait();
    Ok(())
}

fn insecure_warning(exposed: &[String]) -> String {
    format!(
        "activemap daemon: WARNING: listening on {} without TLS (--insecure): anyone who can \
         reach it can submit flows (built-in operators, and `path:` executables inside \
         --allow-exec) and read their logs",
        exposed.join(", ")
    )
}

fn entries(machine: &str, runs: &BTreeMap<String, Run>) -> Vec<RunEntry> {
    runs.iter()
        .map(|(id, r)| RunEntry {
            machine: machine.to_string(),
            run_id: id.clone(),
            run_dir: r.dir.clone(),
            state: r.state.lock().expect("state lock").clone(),
        })
        .collect()
}

fn start_run(
    opts: &DaemonOptions,
    catalog: &[OperatorDescriptor],
    payload: Option<&[u8]>,
    runs: &mut BTreeMap<String, Run>,
) -> Result<Vec<u8>, String> {
    let request: StartRequest = serde_json::from_slice(payload.unwrap_or_default())
        .map_err(|e| format!("malformed start request: {e}"))?;
    if request.run_id.is_empty()
        || !request
            .run_id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
    {
        return Err(format!(
            "run id `{}` must be non-empty ASCII letters, digits, `-` or `_`",
            request.run_id
        ));
    }
    if runs.contains_key(&request.run_id) {
        return Err(format!(
            "run `{}` already exists on machine `{}`",
            request.run_id, opts.machine
        ));
    }
    let flow = Dataflow::parse(
        &request.file,
        &request.source,
        opts.base_dir.clone(),
        catalog,
    )
    .map_err(|d| d.to_string())?;
    if flow.machine(&opts.machine).is_none() {
        return Err(format!(
            "{}: machine `{}` is not in the flow's `machines:`",
            request.file, opts.machine
        ));
    }
    check_exec_allowed(&flow, &opts.machine, &opts.allow_exec)?;
    let exposed = exposed_endpoints(&opts.listen, opts.tls.is_some());
    if !exposed.is_empty() {
        eprintln!("{}", insecure_warning(&exposed));
    }
    let run_dir = opts.runs_dir.join(&request.run_id);
    let mut launch = LaunchOptions::new(run_dir.clone(), opts.exe.clone());
    launch.max_steps = request.max_steps;
    launch.record = request.record;
    launch.machine = Some(opts.machine.clone());
    launch.run_id = Some(request.run_id.clone());
    launch.tls = opts.tls.as_ref().map(TlsFiles::zenoh_config);
    launch.derived = opts.derived.clone();
    launch.record_digests = opts.record_digests.clone();
    let state = Arc::new(Mutex::new(RunState::Running));
    let stop = Arc::new(AtomicBool::new(false));
    let thread = {
        let (state, stop, run_id) = (state.clone(), stop.clone(), request.run_id.clone());
        std::thread::spawn(move || {
            let outcome = match run_local(&flow, &launch, stop) {
                Ok(report) => state_of(&report.nodes, report.failure.as_deref()),
                Err(e) => RunState::Failed(e.to_string()),
            };
            eprintln!("activemap daemon: run {run_id}: {outcome:?}");
            *state.lock().expect("state lock") = outcome;
        })
    };
    eprintln!(
        "activemap daemon: run {} started from {} in {}",
        request.run_id,
        request.file,
        run_dir.display()
    );
    runs.insert(
        request.run_id.clone(),
        Run {
            dir: run_dir.clone(),
            state,
            stop,
            thread: Some(thread),
        },
    );
    Ok(serde_json::to_vec(&RunEntry {
        machine: opts.machine.clone(),
        run_id: request.run_id,
        run_dir,
        state: RunState::Running,
    })
    .expect("serialisable"))
}

fn logs(
    machine: &str,
    payload: Option<&[u8]>,
    runs: &BTreeMap<String, Run>,
) -> Result<Vec<u8>, String> {
    let request: LogsRequest = serde_json::from_slice(payload.unwrap_or_default())
        .map_err(|e| format!("malformed logs request: {e}"))?;
    let Some(run) = runs.get(&request.run_id) else {
        // Not this machine's run: an empty answer, so the client can tell machines apart.
        return Ok(b"[]".to_vec());
    };
    let tails = log_tails(machine, &run.dir, request.node.as_deref(), request.lines)
        .map_err(|e| e.to_string())?;
    Ok(serde_json::to_vec(&tails).expect("serialisable"))
}

/// The last `lines` lines of each log file of a run folder (only `node`'s, when given), sorted by
/// file name.
pub fn log_tails(
    machine: &str,
    run_dir: &Path,
    node: Option<&str>,
    lines: usize,
) -> Result<Vec<LogTail>, RuntimeError> {
    let dir = logs_dir(run_dir);
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .map_err(|e| RuntimeError::io(&dir, e))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            let name = p
                .file_name()
                .map(|f| f.to_string_lossy().into_owned())
                .unwrap_or_default();
            node.is_none_or(|n| name.starts_with(&format!("{n}.")))
        })
        .collect();
    files.sort();
    Ok(files
        .iter()
        .map(|p| LogTail {
            machine: machine.to_string(),
            file: p
                .file_name()
                .map(|f| f.to_string_lossy().into_owned())
                .unwrap_or_default(),
            text: tail(p, lines),
        })
        .collect())
}

/// One daemon's answer to a request: its machine and the reply bytes or the error text.
pub type Answer = (String, Result<Vec<u8>, String>);

/// A client of the daemon network, connected to one daemon's control endpoint.
pub struct DaemonClient {
    session: zenoh::Session,
    timeout: Duration,
}

impl DaemonClient {
    /// Connect to the daemon network through `connect` (any daemon's `--listen` endpoint),
    /// presenting `tls` on `quic/` and `tls/` endpoints.
    pub fn connect(
        connect: &[String],
        timeout: Duration,
        tls: Option<&TlsFiles>,
    ) -> Result<Self, RuntimeError> {
        if connect.is_empty() {
            return Err(RuntimeError::Other(
                "give a daemon endpoint with --connect (e.g. tcp/127.0.0.1:7400)".into(),
            ));
        }
        let session = open_zenoh(&ZenohSettings {
            mode: "client".into(),
            listen: vec![],
            connect: connect.to_vec(),
            tls: tls.map(TlsFiles::zenoh_config),
        })
        .map_err(|e| {
            RuntimeError::Other(format!(
                "no daemon reachable at {} (is `activemap up --listen ...` running there?): {e}",
                connect.join(", ")
            ))
        })?;
        Ok(Self { session, timeout })
    }

    /// How long a query waits for answers.
    pub fn timeout(&self) -> Duration {
        self.timeout
    }

    /// Send `verb` with `payload` to `machine` (`*` for all); every answer, as (machine, bytes)
    /// or (machine, error text).
    pub fn ask(
        &self,
        machine: &str,
        verb: &str,
        payload: Vec<u8>,
    ) -> Result<Vec<Answer>, RuntimeError> {
        let replies = self
            .session
            .get(daemon_key(machine, verb))
            .payload(payload)
            .target(QueryTarget::All)
            .consolidation(ConsolidationMode::None)
            .timeout(self.timeout)
            .wait()
            .map_err(|e| RuntimeError::Other(format!("daemon query {verb}: {e}")))?;
        let mut out = Vec::new();
        while let Ok(reply) = replies.recv() {
            match reply.into_result() {
                Ok(sample) => {
                    let key = sample.key_expr().as_str().to_string();
                    let m = key.split('/').nth(2).unwrap_or_default().to_string();
                    out.push((m, Ok(sample.payload().to_bytes().to_vec())));
                }
                Err(err) => out.push((
                    machine.to_string(),
                    Err(String::from_utf8_lossy(&err.payload().to_bytes()).into_owned()),
                )),
            }
        }
        Ok(out)
    }

    /// Submit `flow` to the daemons of every machine that has nodes in it. Fails, and stops what
    /// did start, when a machine's daemon does not answer or refuses the flow.
    pub fn start(
        &self,
        flow: &Dataflow,
        run_id: Option<String>,
        max_steps: Option<u64>,
        record: bool,
    ) -> Result<Vec<RunEntry>, RuntimeError> {
        let run_id = run_id.unwrap_or_else(new_run_id);
        let request = StartRequest {
            run_id: run_id.clone(),
            file: flow.file.clone(),
            source: flow.source.clone(),
            max_steps,
            record,
        };
        let payload = serde_json::to_vec(&request).expect("serialisable");
        let mut machines: Vec<&str> = flow.nodes.iter().map(|n| n.machine.as_str()).collect();
        machines.sort_unstable();
        machines.dedup();
        // Every machine's daemon must answer before any of them starts: a flow is never left
        // half-started because one daemon is still coming up.
        let mut problems = Vec::new();
        for m in &machines {
            if self.ask(m, "runs", Vec::new())?.is_empty() {
                problems.push(no_answer(m, self.timeout));
            }
        }
        if !problems.is_empty() {
            return Err(RuntimeError::Other(format!(
                "run {run_id} not started:\n  {}",
                problems.join("\n  ")
            )));
        }
        let mut started = Vec::new();
        for m in machines {
            let answers = self.ask(m, "start", payload.clone())?;
            match answers.into_iter().next() {
                None => problems.push(no_answer(m, self.timeout)),
                Some((_, Err(why))) => problems.push(format!("machine `{m}`: {why}")),
                Some((_, Ok(bytes))) => match serde_json::from_slice::<RunEntry>(&bytes) {
                    Ok(entry) => started.push(entry),
                    Err(e) => problems.push(format!("machine `{m}`: bad answer: {e}")),
                },
            }
        }
        if !problems.is_empty() {
            if !started.is_empty() {
                self.stop(&run_id)?;
            }
            return Err(RuntimeError::Other(format!(
                "run {run_id} not started:\n  {}",
                problems.join("\n  ")
            )));
        }
        Ok(started)
    }

    /// Every run every reachable daemon knows, sorted by run id then machine.
    pub fn runs(&self) -> Result<Vec<RunEntry>, RuntimeError> {
        Ok(self.runs_and_machines()?.1)
    }

    /// The machines whose daemons answered (sorted) and every run they know, sorted by run id
    /// then machine: an empty machine list means no daemon answered, which an empty run list
    /// alone cannot tell from daemons with no runs.
    pub fn runs_and_machines(&self) -> Result<(Vec<String>, Vec<RunEntry>), RuntimeError> {
        let mut all = Vec::new();
        let mut machines = Vec::new();
        for (m, answer) in self.ask("*", "runs", Vec::new())? {
            let bytes =
                answer.map_err(|why| RuntimeError::Other(format!("machine `{m}`: {why}")))?;
            let entries: Vec<RunEntry> = serde_json::from_slice(&bytes)
                .map_err(|e| RuntimeError::Other(format!("machine `{m}`: bad answer: {e}")))?;
            all.extend(entries);
            machines.push(m);
        }
        all.sort_by(|a, b| (&a.run_id, &a.machine).cmp(&(&b.run_id, &b.machine)));
        machines.sort();
        Ok((machines, all))
    }

    /// Log tails of run `run_id` from every machine.
    pub fn logs(
        &self,
        run_id: &str,
        node: Option<String>,
        lines: usize,
    ) -> Result<Vec<LogTail>, RuntimeError> {
        let request = LogsRequest {
            run_id: run_id.to_string(),
            node,
            lines,
        };
        let mut all = Vec::new();
        for (m, answer) in self.ask("*", "logs", serde_json::to_vec(&request).expect("json"))? {
            let bytes =
                answer.map_err(|why| RuntimeError::Other(format!("machine `{m}`: {why}")))?;
            let tails: Vec<LogTail> = serde_json::from_slice(&bytes)
                .map_err(|e| RuntimeError::Other(format!("machine `{m}`: bad answer: {e}")))?;
            all.extend(tails);
        }
        all.sort_by(|a, b| (&a.machine, &a.file).cmp(&(&b.machine, &b.file)));
        Ok(all)
    }

    /// Stop run `run_id` on every machine (a broadcast on the run's control key).
    pub fn stop(&self, run_id: &str) -> Result<(), RuntimeError> {
        broadcast_stop(&self.session, run_id)
    }

    /// Shut every reachable daemon down (their running flows are stopped first); the machines
    /// that acknowledged.
    pub fn down(&self) -> Result<Vec<String>, RuntimeError> {
        let mut machines: Vec<String> = self
            .ask("*", "down", Vec::new())?
            .into_iter()
            .filter(|(_, a)| a.is_ok())
            .map(|(m, _)| m)
            .collect();
        machines.sort();
        Ok(machines)
    }

    /// Wait until run `run_id` is no longer running on any machine; its final entries.
    pub fn wait(&self, run_id: &str, poll: Duration) -> Result<Vec<RunEntry>, RuntimeError> {
        loop {
            let entries: Vec<RunEntry> = self
                .runs()?
                .into_iter()
                .filter(|e| e.run_id == run_id)
                .collect();
            if entries.is_empty() {
                return Err(RuntimeError::Other(format!("no daemon knows run {run_id}")));
            }
            if entries.iter().all(|e| e.state != RunState::Running) {
                return Ok(entries);
            }
            std::thread::sleep(poll);
        }
    }
}

/// The error text for a machine whose daemon did not answer a request.
pub fn no_answer(machine: &str, timeout: Duration) -> String {
    format!(
        "machine `{machine}`: no daemon answered within {timeout:?} (is `activemap up --machine {machine}` running and connected?)"
    )
}

impl Drop for DaemonClient {
    fn drop(&mut self) {
        let _ = self.session.close().wait();
    }
}

/// A launcher outcome as a run state: failed when the flow stopped on a failure or a node crashed.
fn state_of(nodes: &BTreeMap<String, (NodeExit, u32)>, failure: Option<&str>) -> RunState {
    match failure {
        Some(why) => RunState::Failed(why.to_string()),
        None if nodes
            .values()
            .any(|(e, _)| matches!(e, NodeExit::Crashed(_))) =>
        {
            RunState::Failed("a node crashed".into())
        }
        None => RunState::Finished,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loopback_endpoints_are_told_from_exposed_ones() {
        for e in [
            "tcp/127.0.0.1:7400",
            "tcp/127.0.0.3:7400",
            "tcp/localhost:7400",
            "tcp/[::1]:7400",
            "udp/127.0.0.2:9#iface=lo",
        ] {
            assert!(endpoint_is_loopback(e), "{e}");
        }
        for e in [
            "tcp/10.0.0.1:7400",
            "tcp/0.0.0.0:7400",
            "tcp/[::]:7400",
            "tcp/robot.lan:7400",
        ] {
            assert!(!endpoint_is_loopback(e), "{e}");
        }
        assert!(
            check_listen(&["tcp/127.0.0.2:1".into()], false, false)
                .unwrap()
                .is_empty()
        );
        let e = check_listen(&["tcp/10.0.0.1:7400".into()], false, false)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("tcp/10.0.0.1:7400") && e.contains("--insecure"),
            "{e}"
        );
        assert_eq!(
            check_listen(&["tcp/10.0.0.1:7400".into()], true, false).unwrap(),
            ["tcp/10.0.0.1:7400"]
        );
        // Mutual TLS protects `tls/` endpoints, not plain TCP ones beside them.
        assert!(
            check_listen(&["tls/10.0.0.1:7400".into()], false, true)
                .unwrap()
                .is_empty()
        );
        let e = check_listen(
            &["tls/10.0.0.1:7400".into(), "tcp/10.0.0.1:7401".into()],
            false,
            true,
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("tcp/10.0.0.1:7401") && !e.contains("7400"),
            "{e}"
        );
        // A `tls/` or `quic/` endpoint without the files: refused, saying what is missing.
        for endpoint in ["tls/127.0.0.1:7400", "quic/127.0.0.1:7400"] {
            let e = check_listen(&[endpoint.into()], false, false)
                .unwrap_err()
                .to_string();
            assert!(e.contains("--tls-cert") && e.contains(endpoint), "{e}");
        }
        // Mutual TLS protects `quic/` endpoints as it does `tls/` ones.
        assert!(
            check_listen(&["quic/10.0.0.1:7400".into()], false, true)
                .unwrap()
                .is_empty()
        );
    }

    /// A `path:` node runs only from an `--allow-exec` folder (after resolving `..` and
    /// links); the refusal names the node; nodes of other machines are not this daemon's.
    #[test]
    fn path_nodes_run_only_from_allowed_folders() {
        let dir = tempfile::tempdir().unwrap();
        let tools = dir.path().join("tools");
        let other = dir.path().join("other");
        std::fs::create_dir_all(&tools).unwrap();
        std::fs::create_dir_all(&other).unwrap();
        std::fs::write(tools.join("ok.sh"), "#!/bin/sh\n").unwrap();
        std::fs::write(other.join("evil.sh"), "#!/bin/sh\n").unwrap();
        let flow = |exe: &str| {
            let src = format!(
                "nodes:\n  - id: tool\n    path: {exe}\n    outputs: [{{ id: out, type: Counter }}]\n"
            );
            Dataflow::parse("f.yaml", &src, dir.path().to_path_buf(), &[]).unwrap()
        };
        let allowed = [tools.clone()];
        let machine = flow("./tools/ok.sh").nodes[0].machine.clone();
        assert!(check_exec_allowed(&flow("./tools/ok.sh"), &machine, &allowed).is_ok());
        for exe in [
            "./other/evil.sh",
            "./tools/../other/evil.sh",
            "./tools/missing.sh",
        ] {
            let e = check_exec_allowed(&flow(exe), &machine, &allowed).unwrap_err();
            assert!(
                e.contains("node `tool`") && e.contains(exe) && e.contains("--allow-exec"),
                "{e}"
            );
        }
        let e = check_exec_allowed(&flow("./tools/ok.sh"), &machine, &[]).unwrap_err();
        assert!(e.contains("none given"), "{e}");
        assert!(check_exec_allowed(&flow("./other/evil.sh"), "elsewhere", &[]).is_ok());
    }
}
