//! `activemap up` / `start` / `list` / `logs` / `stop` / `down`: the machine daemons of distributed
//! runs, and the client commands that talk to them (crates/runtime/src/daemon.rs).

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use activemap_runtime::daemon::{DaemonClient, DaemonOptions, RunEntry, RunState, serve};
use activemap_runtime::node::install_stop_signals;
use activemap_runtime::tls::{TlsFiles, tls_from_args};
use anyhow::Context as _;

/// Mutual TLS: this party's identity (PEM files), on daemons and their clients alike.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct Tls {
    /// The CA certificate that signed every daemon's and client's certificate (PEM).
    #[arg(long, value_name = "FILE")]
    pub tls_ca: Option<PathBuf>,
    /// This party's certificate (PEM), signed by --tls-ca.
    #[arg(long, value_name = "FILE")]
    pub tls_cert: Option<PathBuf>,
    /// This party's private key (PEM).
    #[arg(long, value_name = "FILE")]
    pub tls_key: Option<PathBuf>,
}

impl Tls {
    /// The checked files, or `None` when no TLS option was given.
    pub fn files(&self) -> anyhow::Result<Option<TlsFiles>> {
        Ok(tls_from_args(
            self.tls_ca.clone(),
            self.tls_cert.clone(),
            self.tls_key.clone(),
        )?)
    }
}

/// Options shared by the client commands: where to reach the daemon network.
#[derive(clap::Args, Debug)]
pub struct Connect {
    /// Control endpoint of any daemon (its `up --listen`), e.g. tcp/127.0.0.1:7400 or, with
    /// mutual TLS, quic/10.0.0.1:7400 (or tls/10.0.0.1:7400).
    #[arg(long, required = true)]
    pub connect: Vec<String>,
    /// How long to wait for the daemons' answers, in seconds.
    #[arg(long, default_value_t = 5.0)]
    pub timeout: f64,
    #[command(flatten)]
    pub tls: Tls,
}

impl Connect {
    /// A client of the daemon network these options name.
    pub fn client(&self) -> anyhow::Result<DaemonClient> {
        let tls = self.tls.files()?;
        Ok(DaemonClient::connect(
            &self.connect,
            Duration::from_secs_f64(self.timeout.max(0.1)),
            tls.as_ref(),
        )?)
    }
}

/// What `activemap up --listen` was asked for (daemon mode).
pub struct Daemon {
    /// This machine's id.
    pub machine: String,
    /// Control endpoints to listen on.
    pub listen: Vec<String>,
    /// Other daemons' control endpoints to join.
    pub connect: Vec<String>,
    /// Folder of the run folders.
    pub runs: PathBuf,
    /// Folders whose executables `path:` nodes may run.
    pub allow_exec: Vec<PathBuf>,
    /// Accept non-loopback listening without TLS.
    pub insecure: bool,
    /// Episodes run at once for `bench results --connect`.
    pub slots: usize,
}

/// Run this machine's daemon until Ctrl-C or `activemap down`.
pub fn up(daemon: Daemon, tls: &Tls) -> anyhow::Result<()> {
    let opts = DaemonOptions {
        machine: daemon.machine,
        listen: daemon.listen,
        connect: daemon.connect,
        runs_dir: daemon.runs,
        exe: std::env::current_exe().context("locating the activemap executable")?,
        base_dir: std::env::current_dir().context("reading the working directory")?,
        allow_exec: daemon.allow_exec,
        insecure: daemon.insecure,
        tls: tls.files()?,
        derived: Some(Arc::new(crate::view::FoxgloveView)),
        record_digests: crate::MapRecording::default().digests(),
    };
    let episodes = activemap_bench::episodes::EpisodeHost::new(&opts, daemon.slots)?;
    let stop = Arc::new(AtomicBool::new(false));
    install_stop_signals(&stop)?;
    let mut services: Vec<Box<dyn activemap_runtime::daemon::DaemonService>> =
        vec![Box::new(episodes)];
    serve(&opts, &activemap_operators::catalog(), &mut services, stop)?;
    eprintln!("activemap daemon `{}` stopped", opts.machine);
    Ok(())
}

/// Submit a flow to the daemons; with `wait`, follow it to the end. False when the run failed.
pub fn start(
    flow: &activemap_runtime::Dataflow,
    connect: &Connect,
    run_id: Option<String>,
    max_steps: Option<u64>,
    record: bool,
    wait: bool,
) -> anyhow::Result<bool> {
    let client = connect.client()?;
    let started = client.start(flow, run_id, max_steps, record)?;
    let run_id = started
        .first()
        .map(|e| e.run_id.clone())
        .context("the flow has no nodes")?;
    println!("run {run_id} started");
    print_entries(&started);
    if !wait {
        return Ok(true);
    }
    let done = client.wait(&run_id, Duration::from_millis(250))?;
    print_entries(&done);
    // A failed run also says so on stderr, machine by machine, with the launcher's reason (a
    // node not ready in time, a crash and its log tail): the exit status alone names nothing.
    for e in &done {
        if let RunState::Failed(why) = &e.state {
            eprintln!(
                "error: run {run_id} failed on machine `{}`: {why} (its logs: {})",
                e.machine,
                activemap_runtime::node::logs_dir(&e.run_dir).display()
            );
        }
    }
    Ok(done.iter().all(|e| e.state == RunState::Finished))
}

/// Print the runs the daemons know (stdout) and which daemons answered (stderr); an error when
/// none did, so an empty list always means daemons without runs.
pub fn list(connect: &Connect) -> anyhow::Result<()> {
    let (machines, runs) = connect.client()?.runs_and_machines()?;
    if machines.is_empty() {
        anyhow::bail!("no daemon answered at {}", connect.connect.join(", "));
    }
    eprintln!("daemons answering: {}", machines.join(", "));
    print_entries(&runs);
    Ok(())
}

/// Print a run's log tails from every machine.
pub fn logs(
    connect: &Connect,
    run_id: &str,
    node: Option<String>,
    lines: usize,
) -> anyhow::Result<()> {
    let tails = connect.client()?.logs(run_id, node, lines)?;
    if tails.is_empty() {
        anyhow::bail!("no daemon has logs of run {run_id}");
    }
    for t in tails {
        println!("==> {}: {} <==\n{}", t.machine, t.file, t.text);
    }
    Ok(())
}

/// Stop one run everywhere.
pub fn stop(connect: &Connect, run_id: &str) -> anyhow::Result<()> {
    connect.client()?.stop(run_id)?;
    println!("stop sent to run {run_id}");
    Ok(())
}

/// Shut the daemons down.
pub fn down(connect: &Connect) -> anyhow::Result<()> {
    let machines = connect.client()?.down()?;
    if machines.is_empty() {
        anyhow::bail!("no daemon answered at {}", connect.connect.join(", "));
    }
    println!("daemons going down: {}", machines.join(", "));
    Ok(())
}

fn print_entries(entries: &[RunEntry]) {
    for e in entries {
        let state = match &e.state {
            RunState::Running => "running".to_string(),
            RunState::Finished => "finished".to_string(),
            RunState::Failed(why) => format!("failed: {why}"),
        };
        println!(
            "{:<24} {:<12} {:<40} {state}",
            e.run_id,
            e.machine,
            e.run_dir.display()
        );
    }
}
