//! `activemap bench scorer` and `activemap bench eig-psnr` (issue 14): the Fisher scorer on a
//! partly explored house (`activemap_bench::house_map`), timed (`scorer_bench`) and checked
//! against the map's rendering quality (`eig_psnr`, the paper's Figure 2).
//!
//! Both take the flow's settings: the `mapper` node's mapping session for the house map and
//! the `scorer` node's `fisher:` block for the scorer (the library defaults, the paper's, when
//! the flow has none); the CLI only parses options and prints.

use std::path::{Path, PathBuf};

use activemap_bench::house_map::{self, HouseMapConfig};
use activemap_bench::scorer_bench::FisherConfig;
use activemap_runtime::dataflow::{Dataflow, NodeImpl};
use anyhow::Context as _;

/// Options shared by both benchmarks: the flow and the house.
#[derive(clap::Args)]
pub struct HouseArgs {
    /// The dataflow whose `mapper` node builds the map and whose `scorer` node's `fisher:`
    /// block configures the scorer (defaults, the paper's, when it has none).
    #[arg(long, default_value = "flows/fisher.yaml")]
    flow: PathBuf,
    /// The procedural house (`house:<n>`).
    #[arg(long, default_value_t = 1)]
    house: u64,
    /// Square camera image side, pixels (the frames, the map's renders; the scorer renders at
    /// its own `scoring_width`).
    #[arg(long, default_value_t = 160)]
    resolution: u32,
    /// Overrides a field of the scorer's `fisher:` settings, KEY=VALUE with a JSON or plain
    /// value (repeatable), e.g. `--fisher max_actions=30 --fisher scoring_width=32`.
    #[arg(long = "fisher", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
}

/// The large map both timing benchmarks build: how many Gaussians, in how many steps.
#[derive(clap::Args)]
pub struct MapSizeArgs {
    /// Map size to reach: the exploration stops once the map holds this many Gaussians.
    #[arg(long, default_value_t = 150_000)]
    gaussians: usize,
    /// Most exploration steps to reach the map size.
    #[arg(long, default_value_t = 2000)]
    max_steps: usize,
    /// Insertion sampling fraction of the unobserved depth pixels (the mapper's default is
    /// about 0.19 at 160²; denser reaches the map size in fewer frames). `0` keeps the mapper's.
    #[arg(long, default_value_t = 1.0)]
    insert_fraction: f64,
}

/// Options of `activemap bench scorer`.
#[derive(clap::Args)]
pub struct ScorerArgs {
    #[command(flatten)]
    house: HouseArgs,
    #[command(flatten)]
    size: MapSizeArgs,
    /// Replans timed per case (medians reported).
    #[arg(long, default_value_t = 5)]
    repeats: usize,
    /// Also runs one `cold` replan and the `incremental` case on the same house with these
    /// further `fisher` overrides (space-separated KEY=VALUE, on top of the `--fisher` ones;
    /// repeatable; the model Fisher's τ too when a key starts with `model` or `mc_`), and prints
    /// `scorer compare "<overrides>" median_ms <x> ratio <x / base> tie_fraction <f>
    /// tau_vs_base <τ> candidate_tau_vs_base <τ> top_overlap <f> same_choice <k>/<n>`: the
    /// timing ratio in the same conditions, the rank agreement with the base settings of the
    /// path objectives and of the candidate EIGs (medians over the replans), and the share of
    /// the base's top candidates the other keeps among its top.
    #[arg(long, value_name = "OVERRIDES")]
    compare: Vec<String>,
}

/// Options of `activemap bench planner`.
#[derive(clap::Args)]
pub struct PlannerArgs {
    #[command(flatten)]
    house: HouseArgs,
    #[command(flatten)]
    size: MapSizeArgs,
    /// BEV long side, pixels (the paper's 800).
    #[arg(long = "bev-size", default_value_t = 800)]
    bev_size: u32,
    /// Queries timed (medians reported).
    #[arg(long, default_value_t = 15)]
    repeats: usize,
    /// Also write the last query's BEV (the PNG the model was sent) here.
    #[arg(long)]
    png: Option<PathBuf>,
}

/// Options of `activemap bench eig-psnr`.
#[derive(clap::Args)]
pub struct EigPsnrArgs {
    #[command(flatten)]
    house: HouseArgs,
    /// Exploration steps before the measurement (a partly mapped house).
    #[arg(long, default_value_t = 300)]
    steps: usize,
    /// Poses sampled in the estimated free space.
    #[arg(long, default_value_t = 300)]
    poses: usize,
    /// Seed of the pose draw.
    #[arg(long, default_value_t = 2025)]
    seed: u64,
    /// Insertion sampling fraction (`0`: the mapper's default, as in an episode).
    #[arg(long, default_value_t = 0.0)]
    insert_fraction: f64,
    /// The scatter plot (x = log10 EIG, y = PSNR), PNG.
    #[arg(long, default_value = "runs/eig_psnr.png")]
    out: PathBuf,
}

/// Options of `activemap bench clocal-error`.
#[derive(clap::Args)]
pub struct ClocalErrorArgs {
    #[command(flatten)]
    house: HouseArgs,
    /// Exploration steps before the measurement (a partly mapped house).
    #[arg(long, default_value_t = 300)]
    steps: usize,
    /// Goal poses drawn in the estimated free space, one driven path each.
    #[arg(long, default_value_t = 40)]
    paths: usize,
    /// Frames per error window, and the spacing of the sampled poses along a path.
    #[arg(long, default_value_t = 5)]
    window: usize,
    /// Most steps driven along one path.
    #[arg(long, default_value_t = 150)]
    max_steps_per_path: usize,
    /// Seed of the goal draw and of the simulator's noise streams.
    #[arg(long, default_value_t = 2025)]
    seed: u64,
    /// The simulator's noise: `none`, `realistic`, or a JSON map as the `sim` node's `noise`
    /// takes (`{"preset": "realistic", "actuation": "none"}`).
    #[arg(long, default_value = "none")]
    noise: String,
    /// The scatter plot (x = C_local, y = the window's translation error in cm), PNG.
    #[arg(long, default_value = "runs/clocal_error.png")]
    out: PathBuf,
}

/// Runs `activemap bench clocal-error`: the tracking session of the flow's `tracker` node moved
/// along paths of a partly mapped house, its error against `C_local` and other candidates.
pub fn clocal_error(args: &ClocalErrorArgs) -> anyhow::Result<()> {
    let (mapping, fisher, source) = flow_settings(&args.house.flow, &args.house.overrides)?;
    let loaded = Dataflow::load(&args.house.flow, &activemap_operators::catalog())
        .map_err(|d| anyhow::anyhow!("{d}"))?;
    let (tracker, _) = activemap_operators::mapper::slam_nodes(&loaded)
        .with_context(|| format!("{}", args.house.flow.display()))?;
    let tracking = tracker
        .tracking_config()
        .with_context(|| format!("{}: tracker node", args.house.flow.display()))?;
    let value = if args.noise.trim_start().starts_with('{') {
        serde_json::from_str(&args.noise)
            .with_context(|| format!("bench clocal-error: --noise {}: not JSON", args.noise))?
    } else {
        serde_json::Value::String(args.noise.clone())
    };
    let noise: activemap_sim::NoiseConfig = serde_json::from_value(value)
        .with_context(|| format!("bench clocal-error: --noise {}", args.noise))?;
    let config = HouseMapConfig {
        progress_every: 100,
        noise,
        seed: args.seed,
        tracking: Some(tracking),
        ..HouseMapConfig::new(args.house.house, args.house.resolution, args.steps, mapping)
    };
    let house = house_map::build(&config).context("bench clocal-error: building the house map")?;
    println!("# bench clocal-error: {}", house.describe(&config));
    println!(
        "# tracking: the `tracker` node of {} beside the build and along each path; noise {}",
        args.house.flow.display(),
        args.noise
    );
    println!("# fisher settings: {source}");
    let result = activemap_bench::clocal_error::run(
        &house,
        &fisher,
        &activemap_bench::clocal_error::ClocalConfig {
            paths: args.paths,
            seed: args.seed,
            window: args.window,
            max_steps_per_path: args.max_steps_per_path,
        },
    )?;
    print!("{}", result.table());
    result.write_plot(&args.out)?;
    println!("# scatter plot: {}", args.out.display());
    println!("{}", result.summary());
    Ok(())
}

/// The flow's mapping session settings and the scorer's Fisher settings (with where they came
/// from).
fn flow_settings(
    flow: &Path,
    overrides: &[String],
) -> anyhow::Result<(activemap_slam::MappingConfig, FisherConfig, String)> {
    let loaded = Dataflow::load(flow, &activemap_operators::catalog()).map_err(|d| {
        anyhow::anyhow!(
            "{d}\n(the Fisher benchmarks read the `mapper` and `scorer` nodes of --flow {})",
            flow.display()
        )
    })?;
    let (_, mapper) = activemap_operators::mapper::slam_nodes(&loaded)
        .with_context(|| format!("{}", flow.display()))?;
    let mapping = mapper
        .mapping_config()
        .with_context(|| format!("{}: mapper node", flow.display()))?;
    let scorer = loaded
        .nodes
        .iter()
        .find(|n| matches!(&n.implementation, NodeImpl::Operator(o) if o == "scorer"));
    let (mut block, mut source) = match scorer.and_then(|n| n.config.get("fisher").map(|v| (n, v)))
    {
        Some((node, block)) => (
            block.clone(),
            format!("the `{}` node of {}", node.id, flow.display()),
        ),
        None => (
            serde_json::json!({}),
            format!(
                "the library defaults ({} has no scorer `fisher:` block)",
                flow.display()
            ),
        ),
    };
    let serde_json::Value::Object(fields) = &mut block else {
        anyhow::bail!(
            "{}: the scorer's `fisher:` must be a mapping",
            flow.display()
        );
    };
    for o in overrides {
        let (key, value) = o
            .split_once('=')
            .with_context(|| format!("--fisher `{o}`: expected KEY=VALUE"))?;
        let value = serde_json::from_str(value.trim())
            .unwrap_or_else(|_| serde_json::Value::String(value.trim().to_string()));
        fields.insert(key.trim().to_string(), value);
    }
    if !overrides.is_empty() {
        source += &format!(", overridden by --fisher {}", overrides.join(" --fisher "));
    }
    let fisher: FisherConfig =
        serde_json::from_value(block).with_context(|| format!("fisher settings from {source}"))?;
    fisher
        .validate()
        .map_err(|e| anyhow::anyhow!("fisher settings from {source}: {e}"))?;
    Ok((mapping, fisher, source))
}

fn fraction(f: f64) -> Option<f64> {
    (f != 0.0).then_some(f)
}

/// The house map of `house` grown to `size` with the flow's `mapping`; `what` names the
/// benchmark in errors and progress.
fn large_house(
    house: &HouseArgs,
    size: &MapSizeArgs,
    mapping: activemap_slam::MappingConfig,
    what: &str,
) -> anyhow::Result<house_map::HouseMap> {
    anyhow::ensure!(
        size.gaussians >= 1,
        "bench {what}: --gaussians must be at least 1"
    );
    let config = HouseMapConfig {
        target_gaussians: Some(size.gaussians),
        insert_fraction: fraction(size.insert_fraction),
        progress_every: 100,
        ..HouseMapConfig::new(house.house, house.resolution, size.max_steps, mapping)
    };
    let map = house_map::build(&config)
        .with_context(|| format!("bench {what}: building the house map"))?;
    anyhow::ensure!(
        map.gaussians.len() >= size.gaussians,
        "bench {what}: the map holds only {} Gaussians after {} frames (target {}); raise \
         --max-steps or --insert-fraction, or lower --gaussians",
        map.gaussians.len(),
        map.frames,
        size.gaussians
    );
    println!("# bench {what}: {}", map.describe(&config));
    Ok(map)
}

/// Runs `activemap bench scorer`.
pub fn scorer(args: &ScorerArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.repeats >= 1,
        "bench scorer: --repeats must be at least 1"
    );
    let (mapping, fisher, source) = flow_settings(&args.house.flow, &args.house.overrides)?;
    let house = large_house(&args.house, &args.size, mapping, "scorer")?;
    println!("# fisher settings: {source}");
    let bench = activemap_bench::scorer_bench::run(&house, &fisher, args.repeats)?;
    print!("{}", bench.table());
    let mut compared = Vec::new();
    for c in &args.compare {
        let mut overrides = args.house.overrides.clone();
        overrides.extend(c.split_whitespace().map(str::to_string));
        let (_, other, source) = flow_settings(&args.house.flow, &overrides)?;
        println!("# compare: fisher settings from {source}");
        // Only the incremental case; the model Fisher's τ when the overrides touch it.
        let touches_model = c
            .split_whitespace()
            .any(|kv| kv.starts_with("model") || kv.starts_with("mc_"));
        let run = activemap_bench::scorer_bench::run_with(
            &house,
            &other,
            args.repeats,
            false,
            if touches_model {
                activemap_bench::scorer_bench::MODEL_TAU_PAIRS
            } else {
                0
            },
        )?;
        print!("{}", run.table());
        println!("{}", run.summary().replace("scorer ", "# compared: "));
        let agree = activemap_bench::scorer_bench::agreement(&bench, &run);
        let base_ms = bench.incremental().median_total_ms();
        let ms = run.incremental().median_total_ms();
        let tau = activemap_bench::stats::median(&agree.taus).unwrap_or(f64::NAN);
        let candidate_tau =
            activemap_bench::stats::median(&agree.candidate_taus).unwrap_or(f64::NAN);
        let overlap = activemap_bench::stats::median(&agree.top_overlap).unwrap_or(f64::NAN);
        let ties = run.summary();
        let tie = ties
            .lines()
            .nth(1)
            .and_then(|l| l.split(' ').nth(2))
            .unwrap_or("nan")
            .to_string();
        compared.push(format!(
            "scorer compare \"{c}\" median_ms {ms:.1} ratio {:.3} tie_fraction {tie} tau_vs_base {tau:.3} candidate_tau_vs_base {candidate_tau:.3} top_overlap {overlap:.2} same_choice {}/{}",
            ms / base_ms,
            agree.same_choice,
            agree.replans
        ));
    }
    println!("{}", bench.summary());
    for line in compared {
        println!("{line}");
    }
    Ok(())
}

/// Runs `activemap bench planner`: the LLM planner's own time per query on the house map.
pub fn planner(args: &PlannerArgs) -> anyhow::Result<()> {
    let (mapping, _, _) = flow_settings(&args.house.flow, &args.house.overrides)?;
    let house = large_house(&args.house, &args.size, mapping, "planner")?;
    let bench = activemap_bench::planner_bench::run(&house, args.bev_size, args.repeats)?;
    if let Some(path) = &args.png {
        std::fs::write(path, &bench.png).with_context(|| format!("{}", path.display()))?;
        println!("# BEV written to {}", path.display());
    }
    print!("{}", bench.table());
    println!("{}", bench.summary());
    Ok(())
}

/// Runs `activemap bench eig-psnr`.
pub fn eig_psnr(args: &EigPsnrArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.poses >= 2,
        "bench eig-psnr: --poses must be at least 2"
    );
    let (mapping, fisher, source) = flow_settings(&args.house.flow, &args.house.overrides)?;
    let config = HouseMapConfig {
        insert_fraction: fraction(args.insert_fraction),
        progress_every: 100,
        ..HouseMapConfig::new(args.house.house, args.house.resolution, args.steps, mapping)
    };
    let house = house_map::build(&config).context("bench eig-psnr: building the house map")?;
    println!("# bench eig-psnr: {}", house.describe(&config));
    println!("# fisher settings: {source}");
    let result = activemap_bench::eig_psnr::run(&house, &fisher, args.poses, args.seed)?;
    print!("{}", result.table());
    result.write_plot(&args.out)?;
    println!("# scatter plot: {}", args.out.display());
    println!("{}", result.summary());
    Ok(())
}
