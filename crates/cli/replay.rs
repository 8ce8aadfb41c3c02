//! `activemap replay`: one operator alone on its recorded inputs.
//!
//! Without options the replay checks the recording: every output the operator produces is
//! compared with the recorded one (length and 128-bit hash). With `--set` the operator runs
//! under another configuration on the very same inputs, so its outputs are expected to differ;
//! with `--out` the last map it produced becomes the `map.ply` of a new run folder that holds
//! the recorded run's trajectories and summary, and `activemap eval` measures it. That is a
//! paired experiment on a fixed trajectory: a mapper setting judged on the frames and poses of a
//! real episode (Fisher revisits included), without the policy taking another path because the
//! map changed.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use activemap_eval::run_folder::RunFolder;
use activemap_eval::step_metrics::{FrameReport, ate_rmse, observed_only, tracking_summary};
use activemap_geometry::tum::Trajectory;
use activemap_operators::convert::pose_from_wire;
use activemap_operators::evaluator::frame_report;
use activemap_runtime::dataflow::{Dataflow, NodeImpl, NodeSpec, Override};
use activemap_runtime::record;
use activemap_schemas::{MessageKind, PoseEstimate, SmallMessage};
use anyhow::{Context as _, bail};

use crate::evaluate::EvalArgs;

/// Options of `activemap replay` beyond the recording and the node.
#[derive(clap::Args)]
pub(crate) struct ReplayArgs {
    /// Set a key of a node's `config:` in the recorded dataflow before replaying
    /// (repeatable, as `activemap run --set`): the node then runs under another configuration on
    /// the same inputs, and its outputs are reported, not required to match.
    #[arg(long = "set", value_name = "NODE.KEY=VALUE", value_parser = Override::parse)]
    pub(crate) set: Vec<Override>,
    /// Write a run folder of the replay: the recorded run's trajectories, coverage, summary and
    /// bird's-eye view (copied from the recording's folder), the effective dataflow.yaml, and the
    /// replayed node's last map as `map.ply`; then evaluate it as `activemap run` does. Only
    /// for a node with a map output (the mapper). The folder must not exist yet.
    #[arg(long, value_name = "DIR")]
    pub(crate) out: Option<PathBuf>,
    /// With `--out`: write the folder but do not evaluate it (`activemap eval DIR` later).
    #[arg(long, requires = "out")]
    pub(crate) no_eval: bool,
    /// With `--out`: test views of the evaluation, rendered at the run's own camera as
    /// `activemap run` does (SPEC §8: 2000).
    #[arg(long, default_value_t = 2000, requires = "out")]
    pub(crate) eval_views: usize,
}

/// The files of the recorded run folder a replay folder takes over unchanged (what the
/// replayed mapper does not make); the optional ones are copied when present.
const COPIED: [(&str, bool); 6] = [
    (RunFolder::TRAJECTORY_EST, true),
    (RunFolder::TRAJECTORY_TRUE, true),
    (RunFolder::SUMMARY, true),
    (RunFolder::TRAJECTORY_FINAL, false),
    (RunFolder::COVERAGE, false),
    (RunFolder::BEV, false),
];

/// Runs `activemap replay` (see the module doc); exit status failure when a plain replay's
/// outputs differ from the recording.
pub(crate) fn replay(
    recording_path: &Path,
    node: &str,
    args: &ReplayArgs,
) -> anyhow::Result<ExitCode> {
    let source_dir = recording_path
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_default();
    if let Some(out) = &args.out {
        check_out_folder(out, &source_dir)?;
    }
    // Streamed: the recording is read input by input, never held whole.
    let reader = record::RecordingReader::open(recording_path)?;
    if reader.dataflow_yaml().is_empty() {
        bail!(
            "{}: no embedded dataflow (not an activemap recording?)",
            recording_path.display()
        );
    }
    let name = format!("{} (embedded dataflow)", recording_path.display());
    // The recording's own flow, as recorded, makes the producers that regenerate its
    // digest-only inputs (they must compute what was recorded); the replayed node runs under
    // the overrides (an unknown key is refused when the node reads its config).
    let catalog = activemap_operators::catalog();
    let parse = |overrides: &[Override]| {
        Dataflow::parse_with(
            &name,
            reader.dataflow_yaml(),
            PathBuf::new(),
            &catalog,
            overrides,
        )
        .map_err(|d| anyhow::anyhow!("{d}"))
    };
    let recorded = parse(&[])?;
    let changed = if args.set.is_empty() {
        None
    } else {
        Some(parse(&args.set)?)
    };
    let flow = changed.as_ref().unwrap_or(&recorded);
    let spec = flow
        .node(node)
        .with_context(|| format!("node `{node}` is not in the recorded dataflow"))?;
    let NodeImpl::Operator(op) = &spec.implementation else {
        bail!("node `{node}` is an external executable; replay runs built-in operators");
    };
    let implementation = activemap_operators::find(op)
        .and_then(|r| r.implementation)
        .with_context(|| format!("operator `{op}` is not built in this version"))?;
    let map_ports: Vec<String> = spec
        .outputs
        .iter()
        .filter(|o| o.kind == MessageKind::GaussianMap)
        .map(|o| o.name.clone())
        .collect();
    if args.out.is_some() && map_ports.len() != 1 {
        bail!(
            "--out keeps the replayed node's map, and node `{node}` (operator `{op}`) has {} map \
             outputs; replay the mapper",
            map_ports.len()
        );
    }
    let spec = replay_spec(spec, op, recording_path);
    let producers = replay_producers(&recorded, recording_path);
    // One buffer, overwritten by each map: only the last one is kept.
    let mut last_map: Vec<u8> = Vec::new();
    // A tracker's estimates, measured against the recorded run's true poses at the end.
    let mut estimates = (op == "tracker").then(TrackerEstimates::default);
    let mut observe = |port: &str, bytes: &[u8]| {
        if args.out.is_some() && map_ports.iter().any(|p| p == port) && !bytes.is_empty() {
            last_map.clear();
            last_map.extend_from_slice(bytes);
        }
        if let Some(estimates) = &mut estimates
            && port == "pose"
        {
            estimates.push(bytes);
        }
    };
    let started = std::time::Instant::now();
    let record::StreamedReplay {
        report,
        inputs,
        truncated,
    } = record::replay_recording_observed(
        reader,
        &spec,
        implementation.replay,
        &producers,
        &mut observe,
    )?;
    if truncated {
        eprintln!(
            "warning: the recording ends early (its writer was killed); replaying what it holds"
        );
    }
    for (port, (matched, recorded, made)) in &report.per_port {
        println!("  {node}/{port}: {matched} matched, {recorded} recorded, {made} produced");
    }
    println!(
        "replay {node}: {} inputs, {}/{} outputs matched{} in {:.1} s",
        inputs,
        report.matched(),
        report.recorded(),
        if args.set.is_empty() {
            ""
        } else {
            " (under --set: differences are expected)"
        },
        started.elapsed().as_secs_f64()
    );
    if let Some(estimates) = &estimates {
        for line in estimates.report(&source_dir)? {
            println!("{line}");
        }
    }
    if let Some(out) = &args.out {
        if last_map.is_empty() {
            bail!("node `{node}` produced no map in the replay: nothing to write to --out");
        }
        write_folder(out, &source_dir, flow, &last_map)?;
        println!("replay {node}: run folder {}", out.display());
        let eval = (!args.no_eval).then(|| EvalArgs {
            views: args.eval_views,
            ..EvalArgs::default()
        });
        crate::finish_run(out, eval)?;
    }
    Ok(if report.all_match() || !args.set.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

/// The pose estimates a replayed tracker produced, for the tracking figures of the replay
/// against the recorded run's (its folder's true and estimated trajectories): an open-loop
/// comparison of tracker settings on the frames, actions and maps of one real episode.
#[derive(Default)]
struct TrackerEstimates {
    estimated: Trajectory,
    reports: Vec<FrameReport>,
    /// The first estimate that did not decode (it and every later one are left out).
    error: Option<String>,
}

impl TrackerEstimates {
    /// Reads one `pose` output.
    fn push(&mut self, bytes: &[u8]) {
        if self.error.is_some() {
            return;
        }
        let decoded = PoseEstimate::decode(bytes)
            .map_err(anyhow::Error::from)
            .and_then(|e| Ok((pose_from_wire(&e.t_world_camera)?, e)));
        match decoded {
            Ok((pose, e)) => {
                self.estimated.push(e.stamp, pose);
                self.reports.push(frame_report(&e));
            }
            Err(e) => {
                self.error = Some(format!(
                    "estimate {} does not decode: {e:#}",
                    self.reports.len()
                ))
            }
        }
    }

    /// The replay's ATE and tracking summary beside the recorded run's, as lines; a note
    /// instead when the recording's folder has no true trajectory.
    fn report(&self, source_dir: &Path) -> anyhow::Result<Vec<String>> {
        if let Some(e) = &self.error {
            bail!("replay tracker: {e}");
        }
        let folder = RunFolder::new(source_dir);
        if !folder.path(RunFolder::TRAJECTORY_TRUE).is_file() {
            return Ok(vec![format!(
                "replay tracker: no {} beside the recording: no ATE",
                RunFolder::TRAJECTORY_TRUE
            )]);
        }
        let truth = folder.read_trajectory(RunFolder::TRAJECTORY_TRUE)?;
        let ate = |t: &Trajectory| -> anyhow::Result<String> {
            Ok(ate_rmse(&truth, t)?.map_or("n/a".into(), |m| format!("{:.2}", 100.0 * m)))
        };
        let replayed = ate(&self.estimated)?;
        let recorded = if folder.path(RunFolder::TRAJECTORY_EST).is_file() {
            ate(&folder.read_trajectory(RunFolder::TRAJECTORY_EST)?)?
        } else {
            "n/a".into()
        };
        let summary = tracking_summary(&truth, &self.estimated, &self.reports);
        let mut lines = vec![format!("replay tracking: {}", summary.line())];
        if let Some(recorded) = folder
            .has_summary()
            .then(|| folder.read_summary())
            .transpose()?
            .and_then(|s| s.tracking)
        {
            lines.push(format!("recorded tracking: {}", recorded.line()));
        }
        lines.push(format!(
            "replay tracker ate_cm {replayed} recorded_ate_cm {recorded} frames {}",
            self.estimated.len()
        ));
        Ok(lines)
    }
}

/// Refuses an `--out` that exists already, or a recording outside a run folder (whose
/// trajectories and summary the replay folder needs), before the replay spends its time.
fn check_out_folder(out: &Path, source_dir: &Path) -> anyhow::Result<()> {
    if out.exists() {
        bail!(
            "{}: already exists; --out writes a new run folder",
            out.display()
        );
    }
    for (file, required) in COPIED {
        let path = source_dir.join(file);
        if required && !path.is_file() {
            bail!(
                "{}: missing; --out needs the recording inside its run folder (with the \
                 recorded run's {file})",
                path.display()
            );
        }
    }
    Ok(())
}

/// Writes the replay's run folder (see [`ReplayArgs::out`]): copies of the recorded run's
/// files, the effective dataflow, the map, and the summary with the new map's size.
fn write_folder(
    out: &Path,
    source_dir: &Path,
    flow: &Dataflow,
    map_bytes: &[u8],
) -> anyhow::Result<()> {
    let folder = RunFolder::new(out);
    folder.create()?;
    for (file, required) in COPIED {
        let from = source_dir.join(file);
        if !required && !from.is_file() {
            continue;
        }
        std::fs::copy(&from, out.join(file))
            .with_context(|| format!("copying {} to {}", from.display(), out.display()))?;
    }
    std::fs::write(out.join(RunFolder::DATAFLOW), &flow.source)
        .with_context(|| format!("writing {}", out.join(RunFolder::DATAFLOW).display()))?;
    let (_, map) = activemap_operators::convert::read_map(map_bytes)
        .context("decoding the replayed node's last map")?;
    let map = observed_only(&map)?;
    folder.write_map(&map)?;
    let mut summary = folder.read_summary()?;
    summary.map_gaussians = map.len();
    if let Ok(evaluator) = activemap_operators::single_node_config::<
        activemap_operators::evaluator::Config,
    >(flow, "evaluator")
    {
        summary.map_depth_model = Some(evaluator.depth_model.unwrap_or_default());
    }
    folder.write_summary(&summary)?;
    Ok(())
}

/// Node `node` (operator `op`) as replay runs it: a node that talks to the outside world (the
/// LLM planner) is served the recorded answers.
fn replay_spec(node: &NodeSpec, op: &str, recording_path: &Path) -> NodeSpec {
    let mut spec = node.clone();
    spec.config = activemap_operators::replay_config(op, &node.config, recording_path, &node.id);
    spec
}

/// Every built-in operator output of `flow`, as a producer that can remake the payloads the
/// recording holds as digests (the maps of `--record-maps regenerated`).
fn replay_producers(flow: &Dataflow, recording_path: &Path) -> record::Producers {
    let mut producers = record::Producers::new();
    for node in &flow.nodes {
        let NodeImpl::Operator(op) = &node.implementation else {
            continue;
        };
        let Some(replay) = activemap_operators::find(op)
            .and_then(|r| r.implementation)
            .map(|i| i.replay)
        else {
            continue;
        };
        let spec = replay_spec(node, op, recording_path);
        for output in &node.outputs {
            producers.insert(
                format!("{}/{}", node.id, output.name),
                record::Producer {
                    spec: spec.clone(),
                    port: output.name.clone(),
                    replay,
                },
            );
        }
    }
    producers
}
