//! `activemap bench results` (issue 7): methods × scenes × seeds of exploration episodes, each
//! run as `activemap run` does (the launcher, the step budget, then `eval`), summarised as
//! `results.md` and `results.csv` in the layout of the paper's Table 1 (`activemap_bench::results`).
//!
//! Each cell gets its own dataflow, derived from the method's file: the `sim` node gets the
//! house, resolution and step budget, the `evaluator` node the same house, a `fisher` scorer the
//! same camera size, and every node whose config declares `seed` gets the cell's seed. Cells run
//! as child processes, `--jobs` at a time; a cell whose folder already holds a complete
//! `metrics.json` is not re-run, a half-finished one is cleared and re-run. Ctrl-C (or SIGTERM)
//! stops the running episodes cleanly and writes the table of what is complete.
//!
//! `--suite FILE` takes the grid from a suite file (`activemap_bench::results::suite`) instead
//! of the options; its camera height, field of view, planner setting (`when_no_frontier`, so
//! that every method runs the whole budget) and scene placement reach the derived dataflows
//! too: the height in the `robot` of every node that takes one, the field of view on the `sim`
//! node and a Fisher scorer's camera, the placement on `sim` and `evaluator`.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitCode, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use activemap_bench::results::{self, Cell, CellOutcome, GridSettings, Method, Suite};
use activemap_operators::checks::ROBOT_OPERATORS;
use activemap_runtime::dataflow::Override;
use activemap_runtime::yaml::{self, Loc, Node as YamlNode};
use anyhow::{Context as _, bail};
use serde_json::Value;

/// Options of `activemap bench results`.
#[derive(clap::Args)]
pub struct ResultsArgs {
    /// A suite file (`benchmarks/*.yaml`): methods, scenes with their placement, seeds, steps,
    /// camera, noise and test views in one place (`activemap_bench::results::suite`); replaces
    /// the grid options below (`--out`, `--jobs` and `--record` still apply).
    #[arg(
        long,
        conflicts_with_all = [
            "methods", "houses", "scenes", "noise", "seeds", "steps", "resolution",
            "max_rooms", "max_area", "eval_views",
        ]
    )]
    suite: Option<PathBuf>,
    /// Methods, the table's rows: a known name (`fbe` = dataflow.yaml, `fisher_eig_only` and
    /// `fisher` = flows/<name>.yaml, relative to the working directory) or NAME=DATAFLOW;
    /// repeatable and comma-separated (`--methods fbe,fisher_eig_only,fisher`).
    #[arg(
        long = "method",
        visible_alias = "methods",
        value_delimiter = ',',
        default_values_t = ["fbe".to_string()]
    )]
    methods: Vec<String>,
    /// Procedural houses (the seeds of `house:<n>` scenes); default 1,2,3 unless `--scenes`
    /// is given.
    #[arg(long, value_delimiter = ',')]
    houses: Vec<u64>,
    /// Scene files (or procedural `home:<n>`, `office:<n>`) run after the houses, e.g. `../shared/data/scenes/aws_small_house.glb` (the
    /// furnished house); made absolute, since every cell runs in its own folder.
    #[arg(long, value_delimiter = ',')]
    scenes: Vec<String>,
    /// Simulator noise of every cell: `none` or `realistic` (the `sim` node's `noise` key).
    #[arg(long)]
    noise: Option<String>,
    /// Seeds per method and house, set on every node whose config declares `seed` (the `sim`
    /// node of dataflow.yaml: a seeded start pose, so each seed is a different episode).
    #[arg(long, value_delimiter = ',', default_values_t = [1u64, 2, 3])]
    seeds: Vec<u64>,
    /// Step budget of each episode.
    #[arg(long, default_value_t = 2000)]
    steps: u64,
    /// Camera width and height, pixels.
    #[arg(long, default_value_t = 160)]
    resolution: u32,
    /// Largest number of rooms of the houses (default: the generator's).
    #[arg(long)]
    max_rooms: Option<u32>,
    /// Largest floor area of the houses, m² (default: the generator's).
    #[arg(long)]
    max_area: Option<f64>,
    /// Test views of each evaluation (SPEC §8: 2000).
    #[arg(long, default_value_t = 2000)]
    eval_views: usize,
    /// Output folder: one run folder per cell, results.md, results.csv and paired.csv
    /// (default `runs/results`, with `--suite FILE` `runs/<FILE's stem>`).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Episodes run at once (default: one per two cores).
    #[arg(long, conflicts_with = "connect")]
    jobs: Option<usize>,
    /// Keep each episode's recording.mcap (with --connect: brought back too).
    #[arg(long)]
    record: bool,
    /// Run the cells on machine daemons (`activemap up --listen … --slots N`) reached through
    /// this control endpoint (repeatable): each cell whole on one daemon with a free slot, its
    /// run folder brought back here (`bench_remote`).
    #[arg(long)]
    connect: Vec<String>,
    /// With --connect: how long to wait for a daemon's answer, in seconds.
    #[arg(long, default_value_t = 5.0, requires = "connect")]
    timeout: f64,
    /// With --connect: mutual TLS towards the daemons.
    #[command(flatten)]
    tls: crate::daemons::Tls,
}

/// What to run: the cells and the description of the grid for `results.md`.
struct Plan {
    /// Every cell.
    cells: Vec<Cell>,
    /// Lines under the title of `results.md`.
    heading: String,
    /// Output folder.
    out: PathBuf,
}

/// The grid the command-line options describe.
fn plan_from_args(args: &ResultsArgs) -> anyhow::Result<Plan> {
    anyhow::ensure!(
        !args.seeds.is_empty() && !args.methods.is_empty(),
        "bench results: --method and --seeds must each name at least one"
    );
    anyhow::ensure!(args.steps > 0, "bench results: --steps must be > 0");
    anyhow::ensure!(
        (16..=4096).contains(&args.resolution),
        "bench results: --resolution must be in 16..=4096"
    );
    anyhow::ensure!(
        args.eval_views > 0,
        "bench results: --eval-views must be > 0"
    );
    let methods = args
        .methods
        .iter()
        .map(|m| {
            let mut m = Method::parse(m)?;
            m.dataflow = std::path::absolute(&m.dataflow)
                .with_context(|| format!("method `{}`: {}", m.name, m.dataflow.display()))?;
            Ok(m)
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let mut scenes = crate::bench_explore::house_scenes(&args.houses, &args.scenes);
    for file in &args.scenes {
        // A procedural home or office (`home:3`, `office:2`) is a scene without a file.
        if activemap_sim::SceneSpec::new(file.clone()).is_procedural() {
            scenes.push(file.clone());
            continue;
        }
        let path = std::path::absolute(file).with_context(|| format!("--scenes {file}"))?;
        anyhow::ensure!(path.is_file(), "--scenes {file}: no such file");
        scenes.push(path.display().to_string());
    }
    let settings = GridSettings {
        steps: args.steps,
        resolution: args.resolution,
        max_rooms: args.max_rooms,
        max_area: args.max_area,
        eval_views: args.eval_views,
        noise: args.noise.clone(),
        hfov_deg: None,
        camera_height_m: None,
        when_no_frontier: None,
        checkpoints: Vec::new(),
        llm: None,
    };
    let list = |v: &[u64]| v.iter().map(u64::to_string).collect::<Vec<_>>().join(", ");
    let heading = format!(
        "Command: `activemap {}`\n\n\
         Houses {} (max_rooms {}, max_area {}), seeds {}; {} steps per episode, {res}×{res} px \
         camera; {} test views per evaluation (SPEC §8). Methods: {}.",
        std::env::args().skip(1).collect::<Vec<_>>().join(" "),
        scenes.join(", "),
        args.max_rooms.map_or("default".into(), |v| v.to_string()),
        args.max_area
            .map_or("default".into(), |v| format!("{v} m²")),
        list(&args.seeds),
        args.steps,
        args.eval_views,
        methods
            .iter()
            .map(|m| format!("{} = `{}`", m.name, m.dataflow.display()))
            .collect::<Vec<_>>()
            .join(", "),
        res = args.resolution,
    );
    Ok(Plan {
        cells: results::cells(&methods, &scenes, &args.seeds, &settings),
        heading,
        out: args
            .out
            .clone()
            .unwrap_or_else(|| PathBuf::from("runs/results")),
    })
}

/// The grid a suite file describes (known method names resolve against the working
/// directory).
fn plan_from_suite(file: &Path, out: Option<&Path>) -> anyhow::Result<Plan> {
    let cwd = std::env::current_dir().context("reading the working directory")?;
    let suite = Suite::load(file, &cwd).map_err(|d| anyhow::anyhow!("{d}"))?;
    let s = &suite.settings;
    let or_method = |v: Option<String>| v.unwrap_or_else(|| "the method's".into());
    let scenes: Vec<String> = suite
        .scenes
        .iter()
        .map(|sc| {
            let placement = serde_json::to_string(&sc.placement).unwrap_or_default();
            if placement == "{}" {
                sc.scene.clone()
            } else {
                format!("{} {placement}", sc.scene)
            }
        })
        .collect();
    let heading = format!(
        "Command: `activemap {}`\n\n{}Suite `{}`: methods {}; scenes {}; houses max_rooms {}, \
         max_area {}; seeds {}; {} steps per episode (when no frontier is left: {}); camera \
         {res}×{res} px, field of view {}, height {}; noise {}; {} test views per evaluation \
         (SPEC §8).",
        std::env::args().skip(1).collect::<Vec<_>>().join(" "),
        suite
            .description
            .as_ref()
            .map_or(String::new(), |d| format!("{d}\n\n")),
        file.display(),
        suite
            .methods
            .iter()
            .map(|m| format!("{} = `{}`", m.name, m.dataflow.display()))
            .collect::<Vec<_>>()
            .join(", "),
        scenes.join(", "),
        s.max_rooms.map_or("default".into(), |v| v.to_string()),
        s.max_area.map_or("default".into(), |v| format!("{v} m²")),
        suite
            .seeds
            .iter()
            .map(u64::to_string)
            .collect::<Vec<_>>()
            .join(", "),
        s.steps,
        or_method(s.when_no_frontier.clone()),
        or_method(s.hfov_deg.map(|v| format!("{v}°"))),
        or_method(s.camera_height_m.map(|v| format!("{v} m"))),
        or_method(s.noise.clone()),
        s.eval_views,
        res = s.resolution,
    );
    let out = out.map(Path::to_path_buf).unwrap_or_else(|| {
        let stem = file
            .file_stem()
            .map_or("suite".into(), |f| f.to_string_lossy().into_owned());
        PathBuf::from("runs").join(stem)
    });
    // A method that would only ask the offline fallback is not run under the `llm` name.
    let mut silent = Vec::new();
    for method in &suite.methods {
        if asks_no_model(method, s.llm.as_ref())
            .with_context(|| format!("method `{}`", method.name))?
        {
            eprintln!(
                "bench results: method `{}` skipped: its planner has policy `llm` but asks no model \
                 ({} names no `llm.provider`, nor does the suite's `llm:`); offline it would be \
                 the largest-frontier fallback under another name. Name one in the suite, e.g. \
                 `llm: {{ provider: {{ kind: ollama, base_url: \"http://127.0.0.1:11434\", model: \
                 qwen2.5:1.5b }} }}`",
                method.name,
                method.dataflow.display()
            );
            silent.push(method.name.clone());
        }
    }
    let cells: Vec<Cell> = suite
        .cells()
        .into_iter()
        .filter(|c| !silent.contains(&c.method.name))
        .collect();
    if cells.is_empty() {
        bail!(
            "{}: every method was skipped: nothing to run",
            file.display()
        );
    }
    let heading = if silent.is_empty() {
        heading
    } else {
        format!(
            "{heading} Skipped (policy `llm` without a provider): {}.",
            silent.join(", ")
        )
    };
    Ok(Plan {
        cells,
        heading,
        out,
    })
}

/// True when the flow `file` has a `planner` of policy `llm` that asks no model: no
/// `llm.provider` in its config, and none in the suite's `llm:` keys.
fn asks_no_model(method: &Method, suite_llm: Option<&Value>) -> anyhow::Result<bool> {
    if suite_llm.is_some_and(|l| l.get("provider").is_some_and(|p| !p.is_null())) {
        return Ok(false);
    }
    let tree = method_flow(method)?;
    let Some(YamlNode::Seq { items: nodes, .. }) = tree.get("nodes") else {
        return Ok(false);
    };
    Ok(nodes.iter().any(|node| {
        let config = node.get("config");
        node.get("operator").and_then(YamlNode::as_str) == Some("planner")
            && config
                .and_then(|c| c.get("policy"))
                .and_then(YamlNode::as_str)
                == Some("llm")
            && config
                .and_then(|c| c.get("llm"))
                .and_then(|l| l.get("provider"))
                .is_none_or(|p| p.to_json().is_null())
    }))
}

/// Runs the grid, writes the tables and prints the Markdown.
pub fn run(args: &ResultsArgs) -> anyhow::Result<ExitCode> {
    let plan = match &args.suite {
        Some(file) => plan_from_suite(file, args.out.as_deref())?,
        None => plan_from_args(args)?,
    };
    let cells = &plan.cells;
    // Every cell's dataflow is checked before the first episode starts.
    for cell in cells {
        cell_flow(cell)?;
    }
    let exe = std::env::current_exe().context("locating the activemap executable")?;
    let remote = if args.connect.is_empty() {
        None
    } else {
        let client = crate::daemons::Connect {
            connect: args.connect.clone(),
            timeout: args.timeout,
            tls: args.tls.clone(),
        }
        .client()?;
        Some(crate::bench_remote::Remote::new(client, args.record)?)
    };
    let stop = Arc::new(AtomicBool::new(false));
    activemap_runtime::node::install_stop_signals(&stop)?;
    let jobs = match &remote {
        Some(r) => r.slots(),
        None => args.jobs.unwrap_or_else(results::default_jobs).max(1),
    };
    let count = |key: fn(&Cell) -> String| {
        cells
            .iter()
            .map(key)
            .collect::<std::collections::BTreeSet<_>>()
            .len()
    };
    eprintln!(
        "bench results: {} cells ({} methods × {} scenes × {} seeds), {jobs} at a time{}, in {}",
        cells.len(),
        count(|c| c.method.name.clone()),
        count(|c| c.scene.clone()),
        count(|c| c.seed.to_string()),
        remote
            .as_ref()
            .map_or(String::new(), |r| format!(" on {}", r.describe())),
        plan.out.display()
    );
    let suite = crate::bench_remote::SuiteProgress::new(cells.len(), jobs);
    let run = |cell: &Cell, dir: &Path| match &remote {
        Some(remote) => remote.run_cell(cell, dir, &stop, &suite),
        None => {
            suite.started(&cell.label(), "local");
            run_cell(&exe, cell, dir, args.record, &stop)
        }
    };
    let progress = |r: &results::CellResult| {
        let what = match &r.outcome {
            CellOutcome::Reused(_) => "complete from an earlier run, kept".to_string(),
            CellOutcome::Ran(m) if !m.is_valid() => {
                let codes: Vec<&str> = m.warnings.iter().map(|w| w.code.as_str()).collect();
                format!(
                    "done, INVALID ({}): left out of the means",
                    codes.join(", ")
                )
            }
            CellOutcome::Ran(_) => "done".to_string(),
            CellOutcome::Failed(why) => format!("FAILED: {why}"),
            CellOutcome::Interrupted => "stopped".to_string(),
        };
        let ran = !matches!(r.outcome, CellOutcome::Reused(_) | CellOutcome::Interrupted);
        suite.ended(&r.cell.label(), &what, ran);
    };
    let outcome = results::run_cells(cells, &plan.out, jobs, &stop, run, progress)?;
    let (md, csv) = results::write_tables(&plan.out, &plan.heading, &outcome)?;
    for path in results::write_checkpoint_tables(&plan.out, &plan.heading, &outcome)? {
        print!("{}", std::fs::read_to_string(&path).unwrap_or_default());
        eprintln!("bench results: wrote {}", path.display());
    }
    print!("{}", std::fs::read_to_string(&md).unwrap_or_default());
    if let Some((median, max)) = remote
        .as_ref()
        .and_then(|r| crate::bench_remote::median_and_max(&r.overheads()))
    {
        eprintln!(
            "bench results: dispatch overhead per cell (submit, start, results back): median {median:.2} s, max {max:.2} s over {} cells",
            remote.as_ref().map_or(0, |r| r.overheads().len())
        );
    }
    eprintln!(
        "bench results: wrote {}, {} and {}",
        md.display(),
        csv.display(),
        plan.out.join(results::files::PAIRED).display()
    );
    if outcome
        .iter()
        .any(|r| r.outcome == CellOutcome::Interrupted)
    {
        eprintln!("bench results: stopped; run the same command again to resume");
        return Ok(ExitCode::from(130));
    }
    if outcome
        .iter()
        .any(|r| matches!(r.outcome, CellOutcome::Failed(_)))
    {
        eprintln!("bench results: some cells failed (see their bench.log)");
        return Ok(ExitCode::FAILURE);
    }
    Ok(ExitCode::SUCCESS)
}

/// The cell's dataflow derived from its method's file (same nodes in the same order, written in
/// YAML flow style), validated against the operator catalog.
pub(crate) fn cell_flow(cell: &Cell) -> anyhow::Result<String> {
    let file = &cell.method.dataflow;
    let mut tree = method_flow(&cell.method)?;
    let base = file.parent().unwrap_or(Path::new("."));
    let Some(YamlNode::Seq { items: nodes, .. }) = entry(&mut tree, "nodes") else {
        bail!("{}: no `nodes` list", file.display());
    };
    let (mut sims, mut evaluators) = (0, 0);
    let s = &cell.settings;
    let placement = serde_json::to_value(cell.placement).unwrap_or(Value::Null);
    for node in nodes.iter_mut() {
        // External executables keep working from the cell's folder.
        if let Some(YamlNode::Scalar { value, .. }) = entry(node, "path")
            && Path::new(value.as_str()).is_relative()
        {
            *value = base.join(value.as_str()).display().to_string();
        }
        let operator = node
            .get("operator")
            .and_then(YamlNode::as_str)
            .unwrap_or_default()
            .to_string();
        if !matches!(node, YamlNode::Map { .. }) {
            continue;
        }
        let takes_robot = ROBOT_OPERATORS.contains(&operator.as_str());
        let needs_config = operator == "sim"
            || operator == "evaluator"
            || (takes_robot && s.camera_height_m.is_some())
            || (operator == "planner" && s.when_no_frontier.is_some());
        if needs_config {
            child_map(node, "config");
        }
        let Some(config) = entry(node, "config") else {
            continue;
        };
        if config.get("seed").is_some() {
            set(config, "seed", Some(scalar(cell.seed)));
        }
        if let (true, Some(height)) = (takes_robot, s.camera_height_m) {
            set(
                child_map(config, "robot"),
                "camera_height_m",
                Some(scalar(height)),
            );
        }
        let set_scene = |config: &mut YamlNode| {
            set(config, "scene", Some(quoted(&cell.scene)));
            set(config, "max_rooms", s.max_rooms.map(scalar));
            set(config, "max_area", s.max_area.map(scalar));
            for key in PLACEMENT_KEYS {
                set(config, key, placement.get(key).map(from_json));
            }
        };
        match operator.as_str() {
            "sim" => {
                sims += 1;
                set_scene(&mut *config);
                set(config, "width", Some(scalar(s.resolution)));
                set(config, "height", Some(scalar(s.resolution)));
                set(config, "max_steps", Some(scalar(s.steps)));
                if let Some(noise) = &s.noise {
                    set(config, "noise", Some(scalar(noise)));
                }
                if let Some(fov) = s.hfov_deg {
                    set(config, "hfov_deg", Some(scalar(fov)));
                }
            }
            "evaluator" => {
                evaluators += 1;
                set_scene(&mut *config);
                if !s.checkpoints.is_empty() {
                    set(
                        config,
                        "checkpoints",
                        Some(from_json(&serde_json::json!(s.checkpoints))),
                    );
                }
            }
            // A Fisher scorer renders at the simulator's camera (checked across nodes).
            "scorer" if config.get("mode").and_then(YamlNode::as_str) == Some("fisher") => {
                let camera = child_map(config, "camera");
                set(camera, "width", Some(scalar(s.resolution)));
                set(camera, "height", Some(scalar(s.resolution)));
                if let Some(fov) = s.hfov_deg {
                    set(camera, "hfov_deg", Some(scalar(fov)));
                }
            }
            "planner" => {
                if let Some(when) = &s.when_no_frontier {
                    set(config, "when_no_frontier", Some(scalar(when)));
                }
                let llm_policy = config.get("policy").and_then(YamlNode::as_str) == Some("llm");
                if let (true, Some(Value::Object(keys))) = (llm_policy, &s.llm) {
                    let block = child_map(config, "llm");
                    for (key, value) in keys {
                        set(block, key, Some(from_json(value)));
                    }
                }
            }
            _ => {}
        }
    }
    if sims != 1 || evaluators != 1 {
        bail!(
            "method `{}`: {} must hold exactly one `sim` and one `evaluator` node (found {sims} and {evaluators}); the bench sets the scene on them",
            cell.method.name,
            file.display()
        );
    }
    let mut text = format!(
        "# Generated by `activemap bench results` from {} for {}.\n",
        file.display(),
        cell.label()
    );
    emit(&tree, 0, &mut text);
    text.push('\n');
    activemap_operators::checks::parse(
        &format!("{} ({})", file.display(), cell.label()),
        &text,
        base,
    )
    .map_err(|d| anyhow::anyhow!("{d}"))?;
    Ok(text)
}

/// The parsed dataflow of `method`: its file with its `set` overrides applied in order (as
/// `activemap run --set` applies them).
fn method_flow(method: &Method) -> anyhow::Result<YamlNode> {
    let file = &method.dataflow;
    let text = std::fs::read_to_string(file)
        .with_context(|| format!("method `{}`: reading {}", method.name, file.display()))?;
    let mut tree = yaml::parse(&text)
        .map_err(|e| anyhow::anyhow!("{}:{}: {}", file.display(), e.loc, e.message))?;
    for (index, text) in method.set.iter().enumerate() {
        Override::parse(text)
            .and_then(|o| o.apply(&mut tree, index))
            .map_err(|e| anyhow::anyhow!("method `{}`: {e} in {}", method.name, file.display()))?;
    }
    Ok(tree)
}

/// The keys that place a scene file, on the `sim` and `evaluator` nodes.
const PLACEMENT_KEYS: [&str; 3] = ["up_axis", "transform", "floor"];

/// The mapping under `key` of mapping `node`, created (or replacing a value that is not a
/// mapping) when absent; `node` itself when it is not a mapping.
fn child_map<'a>(node: &'a mut YamlNode, key: &str) -> &'a mut YamlNode {
    let empty = || YamlNode::Map {
        entries: Vec::new(),
        loc: Loc::default(),
    };
    match node {
        YamlNode::Map { entries, .. } => {
            let i = match entries.iter().position(|e| e.0 == key) {
                Some(i) => i,
                None => {
                    entries.push((key.to_string(), Loc::default(), empty()));
                    entries.len() - 1
                }
            };
            let value = &mut entries[i].2;
            if !matches!(value, YamlNode::Map { .. }) {
                *value = empty();
            }
            value
        }
        other => other,
    }
}

/// A JSON value as a YAML node: strings quoted, numbers, booleans and null plain.
fn from_json(value: &Value) -> YamlNode {
    let loc = Loc::default();
    match value {
        Value::String(text) => quoted(text),
        Value::Array(items) => YamlNode::Seq {
            items: items.iter().map(from_json).collect(),
            loc,
        },
        Value::Object(map) => YamlNode::Map {
            entries: map
                .iter()
                .map(|(k, v)| (k.clone(), loc, from_json(v)))
                .collect(),
            loc,
        },
        other => scalar(other),
    }
}

/// The value of `key` in a mapping, mutable.
fn entry<'a>(node: &'a mut YamlNode, key: &str) -> Option<&'a mut YamlNode> {
    match node {
        YamlNode::Map { entries, .. } => entries.iter_mut().find(|e| e.0 == key).map(|e| &mut e.2),
        _ => None,
    }
}

/// Sets (or with `None` removes) `key` in a mapping, keeping the entry's place.
fn set(node: &mut YamlNode, key: &str, value: Option<YamlNode>) {
    let YamlNode::Map { entries, .. } = node else {
        return;
    };
    let at = entries.iter().position(|e| e.0 == key);
    match (at, value) {
        (Some(i), Some(v)) => entries[i].2 = v,
        (Some(i), None) => {
            entries.remove(i);
        }
        (None, Some(v)) => entries.push((key.to_string(), Loc::default(), v)),
        (None, None) => {}
    }
}

/// A plain (number) scalar.
fn scalar(v: impl ToString) -> YamlNode {
    YamlNode::Scalar {
        value: v.to_string(),
        quoted: false,
        loc: Loc::default(),
    }
}

/// A quoted (string) scalar.
fn quoted(v: &str) -> YamlNode {
    YamlNode::Scalar {
        value: v.to_string(),
        quoted: true,
        loc: Loc::default(),
    }
}

/// Writes `node` in YAML flow style (JSON-like, order kept): plain scalars that resolve to
/// numbers, booleans or null stay plain, every other scalar is written as a quoted string.
fn emit(node: &YamlNode, indent: usize, out: &mut String) {
    let pad = |n: usize| "  ".repeat(n);
    match node {
        YamlNode::Scalar { value, quoted, .. } => {
            let plain = !quoted && !node.to_json().is_string();
            if plain {
                out.push_str(value);
            } else {
                out.push_str(&Value::String(value.clone()).to_string());
            }
        }
        YamlNode::Seq { items, .. } => {
            out.push_str("[\n");
            for (i, item) in items.iter().enumerate() {
                out.push_str(&pad(indent + 1));
                emit(item, indent + 1, out);
                out.push_str(if i + 1 < items.len() { ",\n" } else { "\n" });
            }
            out.push_str(&pad(indent));
            out.push(']');
        }
        YamlNode::Map { entries, .. } => {
            out.push_str("{\n");
            for (i, (key, _, value)) in entries.iter().enumerate() {
                out.push_str(&pad(indent + 1));
                out.push_str(&Value::String(key.clone()).to_string());
                out.push_str(": ");
                emit(value, indent + 1, out);
                out.push_str(if i + 1 < entries.len() { ",\n" } else { "\n" });
            }
            out.push_str(&pad(indent));
            out.push('}');
        }
    }
}

/// File in a cell's folder holding its derived dataflow.
const CELL_FLOW: &str = "cell_dataflow.yaml";
/// File in a cell's folder holding the output of its `activemap run`.
const CELL_LOG: &str = "bench.log";

/// Runs one cell: `activemap run` on the cell's dataflow into `dir`, with the step budget and
/// the evaluation; on a stop request the episode gets SIGTERM and stops cleanly.
fn run_cell(
    exe: &Path,
    cell: &Cell,
    dir: &Path,
    record: bool,
    stop: &AtomicBool,
) -> Result<(), String> {
    let flow = cell_flow(cell).map_err(|e| format!("{e:#}"))?;
    let flow_path = dir.join(CELL_FLOW);
    std::fs::write(&flow_path, flow).map_err(|e| format!("{}: {e}", flow_path.display()))?;
    if stop.load(Ordering::SeqCst) {
        return Err("stopped before the episode started".into());
    }
    let log_path = dir.join(CELL_LOG);
    let log =
        std::fs::File::create(&log_path).map_err(|e| format!("{}: {e}", log_path.display()))?;
    let log2 = log
        .try_clone()
        .map_err(|e| format!("{}: {e}", log_path.display()))?;
    let mut cmd = Command::new(exe);
    cmd.arg("run")
        .arg(&flow_path)
        .arg("--out")
        .arg(dir)
        .arg("--max-steps")
        .arg(cell.settings.steps.to_string())
        .arg("--eval-views")
        .arg(cell.settings.eval_views.to_string());
    if !record {
        cmd.arg("--no-record");
    }
    let child = cmd
        .stdin(Stdio::null())
        .stdout(log)
        .stderr(log2)
        .spawn()
        .map_err(|e| format!("starting {}: {e}", exe.display()))?;
    let status = wait_or_stop(child, stop)?;
    if status.success() {
        Ok(())
    } else {
        Err(format!(
            "activemap run: {status}; last lines of {}:\n{}",
            log_path.display(),
            activemap_runtime::launch::tail(&log_path, 8)
        ))
    }
}

/// Waits for `child`; when `stop` is set, sends it SIGTERM (the launcher then stops its nodes
/// cleanly) and waits for it to end.
fn wait_or_stop(mut child: Child, stop: &AtomicBool) -> Result<std::process::ExitStatus, String> {
    let mut signalled = false;
    loop {
        if let Some(status) = child.try_wait().map_err(|e| e.to_string())? {
            return Ok(status);
        }
        if stop.load(Ordering::SeqCst) && !signalled {
            signalled = true;
            // std can only SIGKILL a child, which would orphan the episode's nodes.
            let _ = Command::new("kill")
                .arg("-TERM")
                .arg(child.id().to_string())
                .status();
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[cfg(test)]
mod tests {
    //! End to end through the real binary: a tiny grid (1 method × 2 houses × 1 seed, few
    //! steps, 64×64), interrupted by SIGINT while the second cell runs, then resumed.

    use super::*;
    use activemap_eval::MetricsReport;
    use activemap_runtime::dataflow::Dataflow;

    fn root() -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR"))
    }

    /// The `activemap` binary next to this test executable (cargo builds it for the package's
    /// integration tests in the same `cargo test -p activemap`).
    fn binary() -> PathBuf {
        let exe = std::env::current_exe().unwrap();
        let bin = exe
            .parent()
            .and_then(Path::parent)
            .unwrap()
            .join("activemap");
        assert!(
            bin.exists(),
            "{} not built: run `cargo test -p activemap` (it builds the binary) or `cargo build`",
            bin.display()
        );
        bin
    }

    fn cell(settings: GridSettings) -> Cell {
        let mut m = Method::parse("fbe=dataflow.yaml").unwrap();
        m.dataflow = root().join("dataflow.yaml");
        results::cells(&[m], &["house:3".into()], &[5], &settings).remove(0)
    }

    /// A suite's `llm:` keys reach the `llm` planner's `llm:` block (the flow's own keys kept,
    /// the provider added) and make the flow ask a model; without them `flows/llm.yaml` asks
    /// none (skipped by a suite), and a flow without an `llm` planner is never skipped.
    #[test]
    fn a_suites_llm_keys_reach_the_llm_planner_and_an_llm_method_without_provider_is_skipped() {
        let llm_flow = root().join("flows/llm.yaml");
        let provider = serde_json::json!({ "provider": {
            "kind": "ollama", "base_url": "http://127.0.0.1:11434", "model": "qwen2.5:1.5b" } });
        let method = |file: &str| Method {
            name: "m".into(),
            dataflow: root().join(file),
            set: Vec::new(),
        };
        assert!(asks_no_model(&method("flows/llm.yaml"), None).unwrap());
        assert!(!asks_no_model(&method("flows/llm.yaml"), Some(&provider)).unwrap());
        assert!(!asks_no_model(&method("flows/fisher.yaml"), None).unwrap());
        // A method's own override naming a provider asks a model too.
        let with_provider = Method {
            set: vec![
                "planner.llm.provider={ kind: ollama, base_url: \"http://127.0.0.1:11434\", model: m }"
                    .into(),
            ],
            ..method("flows/llm.yaml")
        };
        assert!(!asks_no_model(&with_provider, None).unwrap());
        let mut m = Method::parse("llm").unwrap();
        m.dataflow = llm_flow;
        let settings = GridSettings {
            llm: Some(provider),
            ..small()
        };
        let cell = results::cells(&[m], &["house:3".into()], &[5], &settings).remove(0);
        let text = cell_flow(&cell).unwrap();
        let flow = Dataflow::parse("cell", &text, root(), &activemap_operators::catalog()).unwrap();
        let planner = &flow.node("planner").unwrap().config;
        assert_eq!(planner["policy"], "llm");
        assert_eq!(planner["llm"]["provider"]["model"], "qwen2.5:1.5b");
        assert_eq!(planner["llm"]["provider"]["kind"], "ollama");
    }

    /// A method's `set` overrides reach its cells' dataflows, in order, before the cell's own
    /// settings (which still win on the keys they set); an override naming no node fails with
    /// the method's name.
    #[test]
    fn a_methods_overrides_reach_its_cell_flow() {
        let m = Method {
            name: "fisher_utility".into(),
            dataflow: root().join("flows/fisher.yaml"),
            set: vec![
                "planner.frontier=utility".into(),
                "scorer.fisher.max_actions=null".into(),
                "sim.width=999".into(),
            ],
        };
        let cell = results::cells(
            std::slice::from_ref(&m),
            &["house:3".into()],
            &[5],
            &small(),
        )
        .remove(0);
        let text = cell_flow(&cell).unwrap();
        let flow = Dataflow::parse("cell", &text, root(), &activemap_operators::catalog()).unwrap();
        assert_eq!(flow.node("planner").unwrap().config["frontier"], "utility");
        assert_eq!(flow.node("planner").unwrap().config["policy"], "fbe");
        let fisher = &flow.node("scorer").unwrap().config["fisher"];
        assert!(fisher["max_actions"].is_null(), "{fisher}");
        assert_eq!(fisher["objective"], "paper");
        // The cell's resolution is set after the overrides.
        assert_eq!(flow.node("sim").unwrap().config["width"], 64);
        let bad = Method {
            set: vec!["nosuchnode.key=1".into()],
            ..m
        };
        let cell = results::cells(&[bad], &["house:3".into()], &[5], &small()).remove(0);
        let e = format!("{:#}", cell_flow(&cell).unwrap_err());
        assert!(
            e.contains("method `fisher_utility`") && e.contains("no node `nosuchnode`"),
            "{e}"
        );
    }

    fn small() -> GridSettings {
        GridSettings {
            steps: 25,
            resolution: 64,
            max_rooms: Some(2),
            max_area: Some(30.0),
            eval_views: 8,
            noise: None,
            ..GridSettings::default()
        }
    }

    #[test]
    fn cell_flow_sets_the_scene_size_and_budget_and_stays_valid() {
        let text = cell_flow(&cell(small())).unwrap();
        let flow = Dataflow::parse("cell", &text, root(), &activemap_operators::catalog()).unwrap();
        let sim = &flow.node("sim").unwrap().config;
        assert_eq!(sim["scene"], "house:3");
        assert_eq!(
            (sim["width"].as_u64(), sim["height"].as_u64()),
            (Some(64), Some(64))
        );
        assert_eq!(sim["max_steps"].as_u64(), Some(25));
        assert_eq!(sim["max_rooms"].as_u64(), Some(2));
        // Everything else is the method's flow, in its order.
        let original = Dataflow::load(
            &root().join("dataflow.yaml"),
            &activemap_operators::catalog(),
        )
        .unwrap();
        let shape = |f: &Dataflow| -> Vec<String> {
            f.nodes
                .iter()
                .map(|n| {
                    let inputs: Vec<String> = n
                        .inputs
                        .iter()
                        .map(|i| {
                            format!(
                                "{}<-{}/{}:{}",
                                i.name, i.source_node, i.source_output, i.queue_size
                            )
                        })
                        .collect();
                    format!("{} {:?} {:?}", n.id, inputs, n.timers)
                })
                .collect()
        };
        assert_eq!(shape(&flow), shape(&original));
        for n in &original.nodes {
            if n.id != "sim" && n.id != "evaluator" {
                assert_eq!(flow.node(&n.id).unwrap().config, n.config, "{}", n.id);
            }
        }
        assert_eq!(
            sim["lockstep"],
            original.node("sim").unwrap().config["lockstep"]
        );
        let ev = &flow.node("evaluator").unwrap().config;
        assert_eq!(ev["scene"], "house:3");
        assert_eq!(ev["max_area"].as_f64(), Some(30.0));
        // Generator defaults: the keys go away rather than keeping the file's values.
        let text = cell_flow(&cell(GridSettings {
            max_rooms: None,
            max_area: None,
            ..small()
        }))
        .unwrap();
        assert!(!text.contains("max_rooms") && !text.contains("max_area"));
        // A flow without an evaluator cannot be scored.
        let dir = tempfile::tempdir().unwrap();
        let no_eval = dir.path().join("x.yaml");
        let base = std::fs::read_to_string(root().join("dataflow.yaml")).unwrap();
        let cut = base.find("  - id: evaluator").unwrap();
        std::fs::write(&no_eval, &base[..cut]).unwrap();
        let mut c = cell(small());
        c.method.dataflow = no_eval;
        let e = cell_flow(&c).unwrap_err().to_string();
        assert!(e.contains("exactly one `sim` and one `evaluator`"), "{e}");
    }

    /// A Fisher method's scorer gets the cell's camera size with the simulator (the flow
    /// would not validate otherwise), keeping its field of view and its Fisher settings.
    #[test]
    fn cell_flow_gives_the_fisher_scorer_the_simulator_camera() {
        let mut c = cell(small());
        c.method.dataflow = root().join("flows/fisher_eig_only.yaml");
        let text = cell_flow(&c).unwrap();
        let flow = Dataflow::parse("cell", &text, root(), &activemap_operators::catalog()).unwrap();
        let scorer = &flow.node("scorer").unwrap().config;
        assert_eq!(scorer["camera"]["width"].as_u64(), Some(64));
        assert_eq!(scorer["camera"]["height"].as_u64(), Some(64));
        assert_eq!(scorer["camera"]["hfov_deg"].as_f64(), Some(90.0));
        assert_eq!(scorer["fisher"]["objective"], "eig_only");
    }

    /// A suite's camera, robot, planner and placement settings reach every node that needs
    /// them, and the derived flow of each known method still passes the cross-node checks
    /// (one robot, the scorer's camera equal to the simulator's).
    #[test]
    fn cell_flow_applies_a_suites_camera_robot_planner_and_placement() {
        let settings = GridSettings {
            hfov_deg: Some(79.0),
            camera_height_m: Some(1.25),
            when_no_frontier: Some("refine".into()),
            noise: Some("realistic".into()),
            ..small()
        };
        let placement: activemap_sim::Placement = serde_json::from_value(serde_json::json!({
            "up_axis": "y",
            "floor": "auto",
            "transform": { "scale": 0.5, "translate": [1.0, 2.0, 0.0] }
        }))
        .unwrap();
        for known in results::KNOWN_METHODS {
            let mut c = cell(settings.clone());
            c.method.dataflow = root().join(known.dataflow);
            c.scene = "/nowhere/room.glb".into();
            c.placement = placement;
            let text = cell_flow(&c).unwrap_or_else(|e| panic!("{}: {e:#}", known.name));
            // Loaded as `activemap run` loads it: the tracker's depth noise is implied by the
            // simulator's (`activemap_operators::checks::implied_overrides`).
            let flow = activemap_operators::checks::parse("cell", &text, &root()).unwrap();
            let mut robots = 0;
            for node in &flow.nodes {
                let op = match &node.implementation {
                    activemap_runtime::dataflow::NodeImpl::Operator(op) => op.as_str(),
                    _ => "",
                };
                if ROBOT_OPERATORS.contains(&op) {
                    robots += 1;
                    assert_eq!(
                        node.config["robot"]["camera_height_m"].as_f64(),
                        Some(1.25),
                        "{}: {}",
                        known.name,
                        node.id
                    );
                }
                if op == "planner" {
                    assert_eq!(node.config["when_no_frontier"], "refine", "{}", known.name);
                }
                if op == "scorer" && node.config["mode"] == "fisher" {
                    assert_eq!(node.config["camera"]["hfov_deg"].as_f64(), Some(79.0));
                    assert_eq!(node.config["camera"]["width"].as_u64(), Some(64));
                }
                if op == "sim" || op == "evaluator" {
                    assert_eq!(node.config["scene"], "/nowhere/room.glb");
                    assert_eq!(node.config["up_axis"], "y");
                    assert_eq!(node.config["floor"], "auto");
                    assert_eq!(node.config["transform"]["scale"].as_f64(), Some(0.5));
                    assert_eq!(node.config["transform"]["translate"][1].as_f64(), Some(2.0));
                }
                if op == "sim" {
                    assert_eq!(node.config["hfov_deg"].as_f64(), Some(79.0));
                    assert_eq!(node.config["noise"], "realistic");
                }
                if op == "tracker" {
                    assert_eq!(
                        node.config["dense"]["depth_sigma_z2"].as_f64(),
                        Some(
                            activemap_sim::NoisePreset::Realistic
                                .config()
                                .depth
                                .sigma_z2
                        )
                    );
                }
            }
            assert!(robots >= 5, "{}: {robots} robot nodes", known.name);
            // The cross-node checks (robot, camera) pass on the derived flow.
            activemap_operators::checks::check_flow(&flow)
                .unwrap_or_else(|e| panic!("{}: {e}", known.name));
        }
        // Without suite settings the method's own values stay.
        let text = cell_flow(&cell(small())).unwrap();
        assert!(
            !text.contains("camera_height_m") && !text.contains("when_no_frontier"),
            "{text}"
        );
    }

    /// `--suite` runs through the same grid runner: both methods run the suite's whole budget
    /// with the suite's settings, and the tables carry the paired comparison. In this
    /// one-room house FBE alone ends its episode when no frontier is left (at step 222 with
    /// seed 0 at 64×64, `when_no_frontier: end`); under the suite it refines instead and runs
    /// all 240 steps. Grid options beside `--suite` are refused.
    #[test]
    fn a_suite_runs_every_method_for_the_whole_budget() {
        let tmp = tempfile::tempdir().unwrap();
        let suite = tmp.path().join("tiny.yaml");
        std::fs::write(
            &suite,
            "methods: [fbe, fisher]\nscenes: [house:3]\nhouses: { max_rooms: 1, max_area: 12 }\n\
             seeds: [0]\nsteps: 240\ncamera: { resolution: 64 }\neval_views: 4\n",
        )
        .unwrap();
        let out = tmp.path().join("out");
        let done = Command::new(binary())
            .current_dir(root())
            .args(["bench", "results", "--jobs", "1", "--suite"])
            .arg(&suite)
            .arg("--out")
            .arg(&out)
            .stdin(Stdio::null())
            .output()
            .unwrap();
        let log = String::from_utf8_lossy(&done.stderr);
        assert!(done.status.success(), "{log}");
        assert!(
            log.contains("2 cells (2 methods × 1 scenes × 1 seeds)"),
            "{log}"
        );
        for method in ["fbe", "fisher"] {
            let dir = out.join(method).join("house-3/seed0");
            let summary: Value =
                serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json")).unwrap())
                    .unwrap();
            assert_eq!(
                summary["episode"], "Finished at step 240: max_steps reached",
                "{method}: {summary}"
            );
            let flow = std::fs::read_to_string(dir.join(CELL_FLOW)).unwrap();
            assert!(
                flow.contains("\"when_no_frontier\": \"refine\""),
                "{method}: {flow}"
            );
        }
        // FBE did run out of frontiers, and went on refining to the budget.
        let planner =
            std::fs::read_to_string(out.join("fbe/house-3/seed0/logs/planner.stderr.log")).unwrap();
        assert!(
            planner.contains("no reachable frontier left") && planner.contains("refine goal"),
            "{planner}"
        );
        let md = std::fs::read_to_string(out.join("results.md")).unwrap();
        assert!(
            md.contains("Suite `") && md.contains("## Paired against `fbe`"),
            "{md}"
        );
        let paired = std::fs::read_to_string(out.join("paired.csv")).unwrap();
        assert!(
            paired.contains("\nfisher,fbe,psnr_db,higher,1,"),
            "{paired}"
        );
        let clash = Command::new(binary())
            .current_dir(root())
            .args(["bench", "results", "--steps", "5", "--suite"])
            .arg(&suite)
            .output()
            .unwrap();
        let log = String::from_utf8_lossy(&clash.stderr);
        assert!(
            !clash.status.success() && log.contains("cannot be used with"),
            "{log}"
        );
    }

    fn bench(out: &Path, steps: u64) -> Command {
        let mut cmd = Command::new(binary());
        cmd.current_dir(root()).args([
            "bench",
            "results",
            "--method",
            "fbe=dataflow.yaml",
            "--houses",
            "3,4",
            "--seeds",
            "1",
            "--steps",
            steps.to_string().as_str(),
            "--resolution",
            "64",
            "--max-rooms",
            "2",
            "--max-area",
            "30",
            "--eval-views",
            "8",
            "--jobs",
            "1",
            "--out",
        ]);
        cmd.arg(out).stdin(Stdio::null());
        cmd
    }

    fn wait_until(what: &str, timeout: Duration, mut done: impl FnMut() -> bool) {
        let t0 = std::time::Instant::now();
        while !done() {
            assert!(t0.elapsed() < timeout, "timed out waiting for {what}");
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    #[test]
    fn tiny_grid_table_matches_its_runs_and_resumes_after_an_interrupt() {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("out");
        let first = out.join("fbe/house-3/seed1");
        let second = out.join("fbe/house-4/seed1");
        let metrics = |d: &Path| d.join("metrics.json");

        // 1. Interrupt while the second cell's episode runs.
        let mut child = bench(&out, 25)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        wait_until("the first cell", Duration::from_secs(300), || {
            metrics(&first).exists() && second.join(CELL_FLOW).exists()
        });
        Command::new("kill")
            .args(["-INT", &child.id().to_string()])
            .status()
            .unwrap();
        let mut log = String::new();
        std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut log).unwrap();
        let status = child.wait().unwrap();
        assert_eq!(status.code(), Some(130), "{log}");
        assert!(
            !metrics(&second).exists(),
            "the interrupted cell finished: {log}"
        );
        let md = std::fs::read_to_string(out.join("results.md")).unwrap();
        assert!(md.contains("fbe house:4 seed 1: not run (stopped)"), "{md}");
        assert!(md.contains("| 1/2 |"), "{md}");
        std::fs::write(first.join("marker"), "kept").unwrap();

        // 2. Resume: the complete cell is kept, the interrupted one re-runs.
        let done = bench(&out, 25).output().unwrap();
        let log = String::from_utf8_lossy(&done.stderr);
        assert!(done.status.success(), "{log}");
        assert!(first.join("marker").exists(), "complete cell re-run: {log}");
        assert!(
            log.contains("fbe house:3 seed 1: complete from an earlier run, kept"),
            "{log}"
        );
        assert!(log.contains("fbe house:4 seed 1: done"), "{log}");

        // 3. The table holds the runs' own numbers.
        let report = |d: &Path| {
            MetricsReport::from_json(&std::fs::read_to_string(metrics(d)).unwrap()).unwrap()
        };
        let (a, b) = (report(&first), report(&second));
        let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
        let rows: Vec<Vec<&str>> = csv.lines().map(|l| l.split(',').collect()).collect();
        let col = |name: &str| rows[0].iter().position(|c| *c == name).unwrap();
        let value = |row: &[&str], name: &str| -> Option<f64> {
            let v = row[col(name)];
            (!v.is_empty()).then(|| v.parse().unwrap())
        };
        assert_eq!(rows.len(), 4, "{csv}");
        let (all, h3, h4) = (&rows[1], &rows[2], &rows[3]);
        assert_eq!((all[1], h3[1], h4[1]), ("all", "house:3", "house:4"));
        for (name, get, scale) in [
            ("psnr_db", a.psnr_db.zip(b.psnr_db), 1.0),
            ("ssim", a.ssim.zip(b.ssim), 1.0),
            ("depth_mae_m", a.depth_mae_m.zip(b.depth_mae_m), 1.0),
            ("ate_rmse_m", a.ate_rmse_m.zip(b.ate_rmse_m), 1.0),
            (
                "completeness_pct",
                a.completeness.zip(b.completeness),
                100.0,
            ),
            ("coverage_2d_pct", a.coverage_2d.zip(b.coverage_2d), 100.0),
        ] {
            let (x, y) = get.unwrap_or_else(|| panic!("{name} missing in a run"));
            assert_eq!(value(h3, name), Some(x * scale), "{name}");
            assert_eq!(value(h4, name), Some(y * scale), "{name}");
            let mean = value(all, name).unwrap();
            assert!(
                (mean - (x + y) / 2.0 * scale).abs() <= 1e-9 * mean.abs().max(1.0),
                "{name}"
            );
        }
        assert_eq!(value(all, "ssim_n"), Some(1.0));
        let md = std::fs::read_to_string(out.join("results.md")).unwrap();
        assert!(
            md.contains(&format!(
                "| fbe | {:.2} |",
                (a.psnr_db.unwrap() + b.psnr_db.unwrap()) / 2.0
            )),
            "{md}"
        );
        // Every run folder has the per-stage timings.
        let timings =
            std::fs::read_to_string(second.join(activemap_eval::RunFolder::TIMINGS)).unwrap();
        assert!(timings.starts_with("stage,seconds,calls\n"), "{timings}");
        for node in ["sim", "tracker", "mapper", "evaluator"] {
            assert!(timings.contains(&format!("\n{node},")), "{node}: {timings}");
        }

        // 4. Other settings into the same folder are refused, naming the difference.
        let clash = bench(&out, 26).output().unwrap();
        let log = String::from_utf8_lossy(&clash.stderr);
        assert!(
            !clash.status.success() && log.contains("steps 25 there, 26 now"),
            "{log}"
        );
    }
}
