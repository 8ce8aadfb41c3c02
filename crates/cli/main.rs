//! `activemap`: the command-line entry point (see `activemap --help`).
//!
//! One binary: built-in operators run as `activemap node` subprocesses of `activemap run`.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use activemap_runtime::bench;
use activemap_runtime::dataflow::{Dataflow, NodeImpl, Override};
use activemap_runtime::graph::{GraphFormat, render};
use activemap_runtime::launch::{LaunchOptions, NodeExit, run_local};
use activemap_runtime::node::{NodeSetup, RunInfo, install_stop_signals};
use activemap_schemas::MessageKind;
use anyhow::{Context as _, bail};
use clap::{Parser, Subcommand, ValueEnum};

mod bench_explore;
mod bench_fisher;
mod bench_remote;
mod bench_results;
mod benches;
mod daemons;
mod evaluate;
mod replay;
mod scene_inspect;
mod view;

#[derive(Parser)]
#[command(
    name = "activemap",
    version,
    about = "Autonomous active mapping: 3DGS SLAM, Fisher-information paths and an LLM planner, as a dataflow of operators"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Check a dataflow file; errors are printed as file:line:column.
    Validate {
        /// Dataflow file.
        file: PathBuf,
        #[command(flatten)]
        set: Overrides,
    },
    /// Print the dataflow as a graph.
    Graph {
        /// Dataflow file.
        file: PathBuf,
        /// Output format.
        #[arg(long, value_enum, default_value_t = Format::Mermaid)]
        format: Format,
        #[command(flatten)]
        set: Overrides,
    },
    /// Run every node of a dataflow on this machine (Ctrl-C stops everything cleanly).
    Run {
        /// Dataflow file.
        file: PathBuf,
        /// Run folder (logs, recording); default runs/<run time>.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Step budget passed to the operators.
        #[arg(long)]
        max_steps: Option<u64>,
        /// Do not write recording.mcap.
        #[arg(long)]
        no_record: bool,
        /// How recording.mcap stores the Gaussian maps: `regenerated` (their digests only;
        /// `activemap replay` remakes them by replaying the mapper, with this build) or `full`
        /// (every map, delta-encoded; a larger file).
        #[arg(long, value_name = "MODE", default_value = "regenerated")]
        record_maps: MapRecording,
        /// Serve the run live to Foxglove over its WebSocket protocol, on HOST:PORT (default
        /// 127.0.0.1:8765, loopback; another host only when named here).
        #[arg(long, value_name = "HOST:PORT", num_args = 0..=1,
              default_missing_value = activemap_view::live::DEFAULT_LIVE_ADDRESS)]
        view: Option<String>,
        /// Do not evaluate the run (metrics.json) when it ends; report.html is still written.
        #[arg(long)]
        no_eval: bool,
        /// Test views of the end-of-run evaluation (SPEC §8: 2000).
        #[arg(long, default_value_t = 2000)]
        eval_views: usize,
        #[command(flatten)]
        set: Overrides,
    },
    /// Evaluate a finished run (SPEC §8): renders the map at seeded test views against the
    /// simulator's ground truth; writes metrics.json, metrics.md and report.html.
    Eval {
        /// Run folder.
        run_dir: PathBuf,
        #[command(flatten)]
        args: evaluate::EvalArgs,
    },
    /// Write a run folder's self-contained report.html.
    Report {
        /// Run folder.
        run_dir: PathBuf,
    },
    /// Distributed runs. With `--listen`: start this machine's long-lived daemon, which runs the
    /// share of every flow submitted with `activemap start` (the nodes whose `deploy.machine` is
    /// MACHINE), until Ctrl-C or `activemap down`. With a FILE: run this machine's share of that
    /// one flow in the foreground (every machine is given the same FILE and --run-id).
    Up {
        /// One-shot mode: the dataflow file (the same on every machine).
        file: Option<PathBuf>,
        /// This machine's id in the flows' `machines:` sections.
        #[arg(long)]
        machine: String,
        /// Daemon mode: control endpoints to listen on, e.g. tcp/127.0.0.1:7400.
        #[arg(long, conflicts_with = "file")]
        listen: Vec<String>,
        /// Daemon mode: control endpoints of other daemons to join.
        #[arg(long, requires = "listen")]
        connect: Vec<String>,
        /// Daemon mode: folder of the run folders.
        #[arg(long, default_value = "runs", requires = "listen")]
        runs: PathBuf,
        /// Daemon mode: a folder whose executables submitted flows' `path:` nodes may run
        /// (repeatable); without it only built-in operators run.
        #[arg(long = "allow-exec", value_name = "DIR", requires = "listen")]
        allow_exec: Vec<PathBuf>,
        /// Daemon mode: accept listening on a non-loopback address without TLS (warned at
        /// start and at every submitted flow).
        #[arg(long, requires = "listen")]
        insecure: bool,
        /// Daemon mode: exploration episodes it runs at once for `bench results --connect`
        /// (an episode keeps about two cores busy).
        #[arg(long, default_value_t = 1, requires = "listen", value_parser = clap::value_parser!(u64).range(1..=256))]
        slots: u64,
        /// Daemon mode: mutual TLS on `quic/` and `tls/` endpoints (clients and other daemons
        /// must show a certificate of the same CA), also used by the runs it starts.
        #[command(flatten)]
        tls: daemons::Tls,
        /// One-shot mode: run id shared by all machines of the run.
        #[arg(long, requires = "file")]
        run_id: Option<String>,
        /// One-shot mode: run folder (logs, recording of this machine's topics).
        #[arg(long, requires = "file")]
        out: Option<PathBuf>,
        /// One-shot mode: step budget passed to the operators.
        #[arg(long, requires = "file")]
        max_steps: Option<u64>,
        /// One-shot mode: do not write recording.mcap.
        #[arg(long, requires = "file")]
        no_record: bool,
    },
    /// Submit a dataflow to the machine daemons (`activemap up --listen`): each runs the nodes
    /// deployed on its machine.
    Start {
        /// Dataflow file.
        file: PathBuf,
        #[command(flatten)]
        daemons: daemons::Connect,
        /// Run id (default: a fresh one).
        #[arg(long)]
        run_id: Option<String>,
        /// Step budget passed to the operators.
        #[arg(long)]
        max_steps: Option<u64>,
        /// Do not write recording.mcap.
        #[arg(long)]
        no_record: bool,
        /// Wait for the run to end; exit non-zero when a machine reports a failure.
        #[arg(long)]
        wait: bool,
        #[command(flatten)]
        set: Overrides,
    },
    /// Stop a run on every machine.
    Stop {
        /// Run id.
        #[arg(long)]
        run_id: String,
        #[command(flatten)]
        daemons: daemons::Connect,
    },
    /// Shut the machine daemons down (their runs are stopped first).
    Down {
        #[command(flatten)]
        daemons: daemons::Connect,
    },
    /// List run folders; with --connect, the runs the machine daemons know and their state.
    List {
        /// Folder holding run folders.
        #[arg(long, default_value = "runs")]
        dir: PathBuf,
        /// Control endpoint of any daemon.
        #[arg(long)]
        connect: Vec<String>,
        #[command(flatten)]
        tls: daemons::Tls,
    },
    /// Print the last lines of a run's node logs: a local run folder, or a distributed run's
    /// logs from every machine (--run-id with --connect).
    Logs {
        /// Run folder.
        #[arg(required_unless_present = "run_id")]
        run_dir: Option<PathBuf>,
        /// Only this node.
        #[arg(long)]
        node: Option<String>,
        /// Lines per log.
        #[arg(long, default_value_t = 40)]
        lines: usize,
        /// A distributed run's id (with --connect).
        #[arg(long, requires = "connect")]
        run_id: Option<String>,
        /// Control endpoint of any daemon.
        #[arg(long)]
        connect: Vec<String>,
        #[command(flatten)]
        tls: daemons::Tls,
    },
    /// Run one operator alone on its recorded inputs and compare its outputs with the recording;
    /// with `--set`, under another configuration, and with `--out`, keep its map as a run folder.
    Replay {
        /// Recording (recording.mcap of a run folder).
        recording: PathBuf,
        /// Node to replay.
        #[arg(long)]
        node: String,
        #[command(flatten)]
        args: replay::ReplayArgs,
    },
    /// List the operators of this build.
    Operators,
    /// Scene files: how one is placed, without running an episode.
    Scene {
        #[command(subcommand)]
        which: SceneCommand,
    },
    /// Benchmarks.
    Bench {
        #[command(subcommand)]
        which: BenchCommand,
    },
    /// Run one node of a launched flow (used by `run`).
    #[command(hide = true)]
    Node {
        /// Run folder written by the launcher.
        #[arg(long)]
        run_dir: PathBuf,
        /// Node id.
        #[arg(long)]
        node: String,
    },
}

/// What `activemap scene` does.
#[derive(Subcommand)]
enum SceneCommand {
    /// Print the placement a scene file gets (up axis, transform, floor: with `up_axis=auto`
    /// what was found and the runner-up), its navigable floor area and rooms, and write a
    /// top-down PNG of the placed scene, without running an episode.
    Inspect(scene_inspect::InspectArgs),
}

/// One subcommand per benchmark area: adding one is one variant here and one arm in `bench`.
#[derive(Subcommand)]
enum BenchCommand {
    /// Latency of an 800×800 RGB-D frame between two processes: iceoryx2, iceoryx2 in place, Zenoh, memcpy.
    Transport(TransportArgs),
    /// Splat renderer: forward, forward+backward and Fisher pass, optionally against the JAX reference.
    Splat(benches::SplatArgs),
    /// Simulator: RGB-D frames per second.
    Sim(benches::SimArgs),
    /// SLAM on scripted loops: ATE, PSNR, tracking fps, mapping time.
    Slam(benches::SlamArgs),
    /// Planning library: A*, occupancy, frontiers, library-only FBE episodes.
    Planning(benches::PlanningArgs),
    /// Evaluation metrics: time per metric.
    Metrics(benches::MetricsArgs),
    /// Methods × houses × seeds of exploration episodes, evaluated: results.md/.csv in the
    /// layout of the paper's Table 1 (resumes after an interruption).
    Results(bench_results::ResultsArgs),
    /// The whole exploration loop on procedural houses: coverage, ATE, steps/s, time per node.
    Explore(bench_explore::ExploreArgs),
    /// The Fisher scorer: one replan (unknown space, I(w), candidates, 20 paths) on a large
    /// house map, median ms per stage (cold, map changed, reused).
    Scorer(bench_fisher::ScorerArgs),
    /// The LLM planner's own time per query (BEV, annotation, PNG, request, parsing) without
    /// the model, on a large house map; prints `planner overhead_median_ms <x>`.
    Planner(bench_fisher::PlannerArgs),
    /// The paper's Figure 2: view EIG against the map's PSNR at poses in the free space of a
    /// partly mapped house (Spearman ρ, scatter PNG).
    EigPsnr(bench_fisher::EigPsnrArgs),
    /// Issue 34: the localisation cost C_local against the tracking error of the tracking
    /// session moved along paths of a partly mapped house (Spearman ρ, scatter PNG).
    ClocalError(bench_fisher::ClocalErrorArgs),
}

#[derive(clap::Args)]
struct TransportArgs {
    /// Frames measured per path.
    #[arg(long, default_value_t = 200)]
    frames: usize,
    /// Frame side, pixels.
    #[arg(long, default_value_t = 800)]
    size: u32,
    /// Gap between frames, µs.
    #[arg(long, default_value_t = 5000)]
    period_us: u64,
    /// Internal: act as the publisher of this path.
    #[arg(long, hide = true)]
    peer: Option<String>,
    /// Internal: service key for the peer.
    #[arg(long, hide = true, default_value = "")]
    key: String,
    /// Internal: Zenoh endpoint for the peer.
    #[arg(long, hide = true, default_value = "")]
    endpoint: String,
}

/// `--set` overrides of node configs, shared by the subcommands that read a dataflow file.
#[derive(clap::Args)]
pub(crate) struct Overrides {
    /// Set a key of a node's `config:` (repeatable): NODE.KEY[.SUBKEY...]=VALUE, VALUE read as
    /// YAML (`--set sim.noise=realistic --set sim.width=320`); missing keys are created. Only
    /// `config:` can be set, not inputs or other node keys. Checked like the file; the run
    /// folder's dataflow.yaml holds the effective values.
    #[arg(long = "set", value_name = "NODE.KEY=VALUE", value_parser = Override::parse)]
    pub(crate) set: Vec<Override>,
}

#[derive(Clone, Copy, ValueEnum)]
enum Format {
    Mermaid,
    Dot,
}

/// Reads a dataflow file with `--set` overrides applied, validated against the operator catalog
/// and across nodes (`activemap_operators::checks`).
pub(crate) fn load(file: &Path, overrides: &[Override]) -> anyhow::Result<Dataflow> {
    activemap_operators::checks::load_with(file, overrides).map_err(|d| anyhow::anyhow!("{d}"))
}

fn main() -> ExitCode {
    keep_freed_memory();
    log_library_errors();
    match real_main() {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Tunes glibc's allocator for this program's pattern: per-frame buffers of a few MB (renders,
/// Fisher passes, maps) allocated and freed over and over. By default glibc serves them with
/// fresh mmaps or trims the freed heap, so each is faulted in and zeroed by the kernel again:
/// 13 % of the Fisher scorer's samples in `perf` were the kernel clearing pages. Blocks below
/// 32 MiB now come from the heap, and up to 1 GiB of freed heap is kept for reuse. Measured:
/// the main loop 15 % faster (`run dataflow.yaml --no-record --max-steps 400`, median of 3
/// alternated runs, 27.1 s against 31.9 s). Peak memory is unchanged (a freed block is reused,
/// not added to); memory freed after a peak is kept.
///
/// The trim threshold does not cover the heaps of the worker threads' arenas (at most 64 MiB
/// each): glibc unmaps such a heap whole as soon as it is free, unless the top pad exceeds it.
/// The Fisher scorer's candidate views (one per rayon worker, ~50 MB of buffers each) emptied
/// and re-created a heap per view, and the kernel's page clearing was again 15 % of its
/// samples; a 128 MiB top pad keeps those heaps. Measured: `bench scorer` replan 2.85/3.02 s
/// → 2.31/2.38 s (two alternated pairs, `incremental`; the pad set by `GLIBC_TUNABLES`).
fn keep_freed_memory() {
    #[cfg(target_env = "gnu")]
    // SAFETY: mallopt only sets allocator parameters; it is called before any thread starts.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
        libc::mallopt(libc::M_TOP_PAD, 128 << 20);
    }
}

/// Sends the libraries' `tracing` events to stderr (a node's goes to its log file): errors only
/// by default, so a transport fault inside Zenoh (a link it closes, a handshake it refuses) is
/// on record where it happened; `RUST_LOG` (e.g. `RUST_LOG=zenoh=debug`) selects more. Never
/// stdout, which carries command output.
fn log_library_errors() {
    use tracing_subscriber::EnvFilter;
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("error"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(false)
        .try_init();
}

fn real_main() -> anyhow::Result<ExitCode> {
    // Every subcommand that records or reads a recording stores Gaussian maps column-wise.
    activemap_operators::register_recording_codecs();
    let cli = Cli::parse();
    match cli.command {
        Command::Validate { file, set } => {
            let flow = load(&file, &set.set)?;
            let shown: Vec<String> = set.set.iter().map(Override::label).collect();
            println!(
                "{}: ok ({} nodes, {} machines)",
                std::iter::once(file.display().to_string())
                    .chain(shown)
                    .collect::<Vec<_>>()
                    .join(" "),
                flow.nodes.len(),
                flow.machines.len()
            );
        }
        Command::Graph { file, format, set } => {
            let flow = load(&file, &set.set)?;
            let format = match format {
                Format::Mermaid => GraphFormat::Mermaid,
                Format::Dot => GraphFormat::Dot,
            };
            print!("{}", render(&flow, format));
        }
        Command::Operators => {
            for r in activemap_operators::registry() {
                let d = r.descriptor;
                let state = if r.implementation.is_some() {
                    "built"
                } else {
                    "planned"
                };
                println!("{:<16} {:<8} {}", d.name, state, d.summary);
            }
        }
        Command::Run {
            file,
            out,
            max_steps,
            no_record,
            record_maps,
            view,
            no_eval,
            eval_views,
            set,
        } => {
            let eval = (!no_eval).then(|| evaluate::EvalArgs {
                views: eval_views,
                ..Default::default()
            });
            let outputs = Outputs {
                record: !no_record,
                record_maps,
                view,
            };
            return run(&file, &set.set, out, max_steps, outputs, None, eval);
        }
        Command::Eval { run_dir, args } => evaluate::eval(&run_dir, &args)?,
        Command::Report { run_dir } => evaluate::report(&run_dir)?,
        Command::Up {
            file,
            machine,
            listen,
            connect,
            runs,
            allow_exec,
            insecure,
            slots,
            tls,
            run_id,
            out,
            max_steps,
            no_record,
        } => match file {
            Some(file) => {
                let run_id = run_id.context("one-shot `up FILE` needs --run-id")?;
                return run(
                    &file,
                    &[],
                    out,
                    max_steps,
                    Outputs {
                        record: !no_record,
                        record_maps: MapRecording::default(),
                        view: None,
                    },
                    Some((machine, run_id)),
                    None,
                );
            }
            None if listen.is_empty() => {
                bail!("`up` needs --listen ENDPOINT (daemon mode) or a dataflow FILE (one-shot)")
            }
            None => daemons::up(
                daemons::Daemon {
                    machine,
                    listen,
                    connect,
                    runs,
                    allow_exec,
                    insecure,
                    slots: slots as usize,
                },
                &tls,
            )?,
        },
        Command::Start {
            file,
            daemons: connect,
            run_id,
            max_steps,
            no_record,
            wait,
            set,
        } => {
            let flow = load(&file, &set.set)?;
            if !daemons::start(&flow, &connect, run_id, max_steps, !no_record, wait)? {
                return Ok(ExitCode::FAILURE);
            }
        }
        Command::Stop {
            run_id,
            daemons: connect,
        } => daemons::stop(&connect, &run_id)?,
        Command::Down { daemons: connect } => daemons::down(&connect)?,
        Command::List { connect, tls, .. } if !connect.is_empty() => {
            daemons::list(&daemons::Connect {
                connect,
                timeout: 5.0,
                tls,
            })?;
        }
        Command::List { dir, .. } => {
            let mut runs: Vec<_> = std::fs::read_dir(&dir)
                .with_context(|| format!("reading {}", dir.display()))?
                .flatten()
                .filter(|e| e.path().join(RunInfo::FILE).exists())
                .collect();
            runs.sort_by_key(|e| e.file_name());
            for e in runs {
                let info = RunInfo::load(&e.path())?;
                let nodes = std::fs::read_dir(e.path().join("logs"))
                    .map(|d| d.count() / 2)
                    .unwrap_or(0);
                println!(
                    "{:<30} run {}  {nodes} nodes",
                    e.path().display(),
                    info.run_id
                );
            }
        }
        Command::Logs {
            run_dir,
            node,
            lines,
            run_id,
            connect,
            tls,
        } => match (run_id, run_dir) {
            (Some(run_id), _) => daemons::logs(
                &daemons::Connect {
                    connect,
                    timeout: 5.0,
                    tls,
                },
                &run_id,
                node,
                lines,
            )?,
            (None, Some(run_dir)) => {
                let tails = activemap_runtime::daemon::log_tails(
                    "local",
                    &run_dir,
                    node.as_deref(),
                    lines,
                )?;
                for t in tails {
                    println!(
                        "==> {} <==\n{}",
                        run_dir.join("logs").join(&t.file).display(),
                        t.text
                    );
                }
            }
            (None, None) => bail!("give a run folder, or --run-id with --connect"),
        },
        Command::Node { run_dir, node } => run_node(&run_dir, &node)?,
        Command::Replay {
            recording,
            node,
            args,
        } => return replay::replay(&recording, &node, &args),
        Command::Scene { which } => match which {
            SceneCommand::Inspect(args) => scene_inspect::run(&args)?,
        },
        Command::Bench { which } => match which {
            BenchCommand::Transport(args) => bench_transport(&args)?,
            BenchCommand::Splat(args) => benches::splat(&args)?,
            BenchCommand::Sim(args) => benches::sim(&args)?,
            BenchCommand::Slam(args) => benches::slam(&args)?,
            BenchCommand::Planning(args) => benches::planning(&args)?,
            BenchCommand::Metrics(args) => benches::metrics(&args)?,
            BenchCommand::Results(args) => return bench_results::run(&args),
            BenchCommand::Explore(args) => bench_explore::run(&args)?,
            BenchCommand::Scorer(args) => bench_fisher::scorer(&args)?,
            BenchCommand::Planner(args) => bench_fisher::planner(&args)?,
            BenchCommand::EigPsnr(args) => bench_fisher::eig_psnr(&args)?,
            BenchCommand::ClocalError(args) => bench_fisher::clocal_error(&args)?,
        },
    }
    Ok(ExitCode::SUCCESS)
}

/// What a local run writes and serves besides its run folder.
/// How the recorder stores the Gaussian maps of built-in operators (`--record-maps`).
///
/// Maps are most of a recording's bytes (the README's main episode: 312 of 375 MB stored in
/// full), and they are a deterministic function of the mapper's recorded inputs, so by default
/// only their digests are written and readers remake them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) enum MapRecording {
    /// Each map's length and 128-bit hash only (`record::DIGEST_ENCODING`); `activemap replay`
    /// regenerates the maps by replaying the mapper on its recorded inputs and checks every one
    /// against its digest. Replay then costs the mapper's time, and needs the same build (a
    /// build whose mapper computes differently is told so at the first map).
    #[default]
    Regenerated,
    /// Every map, delta-encoded against the previous one (`record::DELTA_ENCODING`): larger
    /// files whose maps read back without rerunning anything (e.g. to replay with another build).
    Full,
}

impl MapRecording {
    /// The kinds the recorder stores as digests ([`LaunchOptions::record_digests`]).
    pub(crate) fn digests(self) -> Vec<MessageKind> {
        match self {
            Self::Regenerated => vec![MessageKind::GaussianMap],
            Self::Full => Vec::new(),
        }
    }
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

struct Outputs {
    /// Write recording.mcap.
    record: bool,
    /// How it stores the Gaussian maps.
    record_maps: MapRecording,
    /// Serve the live view on this address.
    view: Option<String>,
}

fn run(
    file: &Path,
    overrides: &[Override],
    out: Option<PathBuf>,
    max_steps: Option<u64>,
    outputs: Outputs,
    distributed: Option<(String, String)>,
    eval: Option<evaluate::EvalArgs>,
) -> anyhow::Result<ExitCode> {
    let flow = load(file, overrides)?;
    let local = |machine: &str| distributed.as_ref().is_none_or(|(m, _)| m == machine);
    for n in flow.nodes.iter().filter(|n| local(&n.machine)) {
        if let NodeImpl::Operator(op) = &n.implementation {
            let entry = activemap_operators::find(op).context("validated operator missing")?;
            if entry.implementation.is_none() {
                bail!(
                    "{}:{}: node `{}` uses operator `{op}`, which is declared but not built yet in this version",
                    flow.file,
                    n.loc,
                    n.id
                );
            }
        }
    }
    let run_dir = out.unwrap_or_else(|| {
        let secs = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0);
        PathBuf::from("runs").join(format!("run-{secs}"))
    });
    let mut opts = LaunchOptions::new(
        run_dir,
        std::env::current_exe().context("locating the activemap executable")?,
    );
    opts.max_steps = max_steps;
    opts.record = outputs.record;
    opts.record_digests = outputs.record_maps.digests();
    opts.view = outputs.view;
    opts.derived = Some(Arc::new(view::FoxgloveView));
    opts.progress = Some(activemap_operators::sim::EPISODE_PROGRESS);
    if let Some((machine, run_id)) = distributed {
        opts.machine = Some(machine);
        opts.run_id = Some(run_id);
    }
    let stop = Arc::new(AtomicBool::new(false));
    install_stop_signals(&stop)?;
    let report = run_local(&flow, &opts, stop.clone())?;
    eprintln!(
        "activemap: run {} in {}",
        report.run_id,
        report.run_dir.display()
    );
    for (id, (exit, restarts)) in &report.nodes {
        let exit = match exit {
            NodeExit::Finished => "finished".to_string(),
            NodeExit::Stopped => "stopped".to_string(),
            NodeExit::Crashed(why) => format!("crashed ({why})"),
        };
        eprintln!(
            "  {id:<20} {exit}{}",
            if *restarts > 0 {
                format!(", {restarts} restarts")
            } else {
                String::new()
            }
        );
    }
    if let Some(stats) = &report.recording {
        eprintln!(
            "activemap: recorded {} messages ({:.1} MB of payload, {:.1} MB written) to {}",
            stats.messages,
            stats.bytes as f64 / 1e6,
            stats.written_bytes as f64 / 1e6,
            report
                .run_dir
                .join(activemap_eval::RunFolder::RECORDING)
                .display()
        );
        for (topic, n) in &stats.dropped {
            eprintln!("activemap: warning: the recorder lost {n} messages on {topic}");
        }
    }
    if let Some(failure) = report.failure {
        eprintln!("error: the flow stopped: {failure}");
        return Ok(ExitCode::FAILURE);
    }
    if report.interrupted {
        eprintln!("activemap: stopped by signal");
        return Ok(ExitCode::from(130));
    }
    exit_on_stop_during_evaluation(stop, &report.run_dir);
    finish_run(&report.run_dir, eval)?;
    Ok(ExitCode::SUCCESS)
}

/// Once the flow has finished, the run folder is complete and the evaluation (about an hour at
/// 800×800 and 2000 test views) is work that `activemap eval` can redo: a SIGINT or SIGTERM
/// then ends the process at once instead of being held until the evaluation ends. The
/// evaluation writes `metrics.json` last, so an interrupted one leaves the folder unevaluated.
fn exit_on_stop_during_evaluation(stop: Arc<AtomicBool>, run_dir: &Path) {
    let run_dir = run_dir.display().to_string();
    std::thread::spawn(move || {
        while !stop.load(Ordering::SeqCst) {
            std::thread::sleep(std::time::Duration::from_millis(100));
        }
        eprintln!(
            "activemap: evaluation stopped by signal; the run folder is complete, evaluate it with `activemap eval {run_dir}`"
        );
        std::process::exit(130);
    });
}

/// After a successful run whose flow wrote an evaluation summary (an `evaluator` node): the
/// metrics of SPEC §8 (unless disabled) and report.html, so one command leaves a report.
pub(crate) fn finish_run(run_dir: &Path, eval: Option<evaluate::EvalArgs>) -> anyhow::Result<()> {
    if !activemap_eval::RunFolder::new(run_dir).has_summary() {
        return Ok(());
    }
    match eval {
        Some(mut args) => {
            // The automatic evaluation renders at the run's own camera (800×800 for the paper's
            // profile), not at `activemap eval`'s 160×160 default.
            if let Some((width, height, hfov_deg)) = sim_camera(run_dir) {
                (args.width, args.height, args.hfov_deg) = (width, height, hfov_deg);
            }
            eprintln!(
                "activemap: evaluating the run at {} test views of {}×{} (skip with --no-eval)",
                args.views, args.width, args.height
            );
            evaluate::eval(run_dir, &args)
        }
        None => evaluate::report(run_dir),
    }
}

/// The `sim` node's camera in a run folder's `dataflow.yaml`: width, height and horizontal FOV
/// (degrees, 90 when unset); `None` without a readable flow or a `sim` node with a width.
fn sim_camera(run_dir: &Path) -> Option<(u32, u32, f64)> {
    let flow = load(&run_dir.join(RunInfo::DATAFLOW), &[]).ok()?;
    let sim = flow
        .nodes
        .iter()
        .find(|n| matches!(&n.implementation, NodeImpl::Operator(op) if op == "sim"))?;
    let c = &sim.config;
    let width = u32::try_from(c.get("width")?.as_u64()?).ok()?;
    let height = u32::try_from(c.get("height")?.as_u64()?).ok()?;
    let hfov = c.get("hfov_deg").and_then(|v| v.as_f64()).unwrap_or(90.0);
    Some((width, height, hfov))
}

fn run_node(run_dir: &Path, node: &str) -> anyhow::Result<()> {
    let run = RunInfo::load(run_dir)?;
    let flow = load(&run_dir.join(RunInfo::DATAFLOW), &[])?;
    let spec = flow
        .node(node)
        .with_context(|| format!("node `{node}` is not in the dataflow"))?;
    let NodeImpl::Operator(op) = &spec.implementation else {
        bail!("node `{node}` is an external executable, not a built-in operator");
    };
    let implementation = activemap_operators::find(op)
        .and_then(|r| r.implementation)
        .with_context(|| format!("operator `{op}` is not built in this version"))?;
    let stop = Arc::new(AtomicBool::new(false));
    install_stop_signals(&stop)?;
    (implementation.run)(NodeSetup {
        dataflow: &flow,
        run: &run,
        node_id: node,
        stop,
    })?;
    Ok(())
}

fn bench_transport(args: &TransportArgs) -> anyhow::Result<()> {
    let period = Duration::from_micros(args.period_us);
    if let Some(path) = &args.peer {
        bench::transport_peer(
            path,
            &args.key,
            args.frames,
            args.size,
            period,
            &args.endpoint,
        )?;
        return Ok(());
    }
    let opts = bench::TransportBenchOptions {
        frames: args.frames,
        size: args.size,
        period,
    };
    let rows = bench::run_transport(&std::env::current_exe()?, &opts)?;
    print!("{}", bench::format_rows(&rows));
    Ok(())
}
