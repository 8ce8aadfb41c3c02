//! `activemap bench <area>` for the library crates: each area's figures come from that crate's
//! `bench::run`, so the CLI only parses options and prints rows.

use anyhow::Context as _;

/// Options of `activemap bench splat` (issue 3).
#[derive(clap::Args)]
pub struct SplatArgs {
    /// Square image sizes, pixels.
    #[arg(long, value_delimiter = ',', default_values_t = [200u32, 800])]
    sizes: Vec<u32>,
    /// Gaussian counts.
    #[arg(long, value_delimiter = ',', default_values_t = [10_000usize, 100_000])]
    counts: Vec<usize>,
    /// Timed repetitions per case (the median is reported).
    #[arg(long, default_value_t = 5)]
    repeats: usize,
    /// Also time the JAX reference rasteriser (tools/splat_reference; installs jax with pip on
    /// first use) and report the ratio.
    #[arg(long)]
    reference: bool,
}

/// Runs the splat benchmark.
pub fn splat(args: &SplatArgs) -> anyhow::Result<()> {
    let base = if args.reference {
        activemap_splat::bench::BenchConfig::with_reference()
    } else {
        activemap_splat::bench::BenchConfig::default()
    };
    let cfg = activemap_splat::bench::BenchConfig {
        sizes: args.sizes.clone(),
        counts: args.counts.clone(),
        repeats: args.repeats,
        ..base
    };
    for row in activemap_splat::bench::run(&cfg) {
        println!("{row}");
    }
    Ok(())
}

/// Options of `activemap bench sim` (issue 4).
#[derive(clap::Args)]
pub struct SimArgs {
    /// Frames rendered per case.
    #[arg(long, default_value_t = 50)]
    frames: usize,
}

/// Runs the simulator benchmark.
pub fn sim(args: &SimArgs) -> anyhow::Result<()> {
    for row in activemap_sim::bench::run(args.frames).context("simulator benchmark")? {
        println!("{row}");
    }
    Ok(())
}

/// Options of `activemap bench slam` (issue 5).
#[derive(clap::Args)]
pub struct SlamArgs {
    /// Cases as RESOLUTIONxFRAMES, e.g. 200x500,400x500.
    #[arg(long, value_delimiter = ',', default_values_t = ["200x500".to_string(), "400x500".to_string()])]
    cases: Vec<String>,
    /// The dataflow whose `tracker` and `mapper` node configs the loop runs (map lag, keyframe
    /// interval, …); where they leave `downscale` unset, tracking runs at half resolution above
    /// 160 px and mapping above 200 px.
    #[arg(long, default_value = "dataflow.yaml")]
    flow: std::path::PathBuf,
    /// Simulator noise: `none` or a preset name (`realistic`: RealSense D435 depth noise and
    /// LoCoBot-derived actuation noise, see `activemap_sim::noise`), set as the flow's
    /// `sim.noise` before `--set`. As in `activemap run`, the tracker then weighs depth by the
    /// sensor's σ(z) unless the flow's tracker sets `dense.depth_sigma_z2` itself.
    #[arg(long, default_value = "none")]
    noise: String,
    /// Overrides of the flow's node configs, e.g. `--set tracker.pose_graph=true`.
    #[command(flatten)]
    set: crate::Overrides,
}

/// Runs the SLAM benchmark on scripted loops.
pub fn slam(args: &SlamArgs) -> anyhow::Result<()> {
    let cases = args
        .cases
        .iter()
        .map(|c| {
            let (res, frames) = c
                .split_once('x')
                .with_context(|| format!("case `{c}`: expected RESOLUTIONxFRAMES"))?;
            Ok((
                res.parse()
                    .with_context(|| format!("case `{c}`: resolution"))?,
                frames
                    .parse()
                    .with_context(|| format!("case `{c}`: frames"))?,
            ))
        })
        .collect::<anyhow::Result<Vec<(u32, usize)>>>()?;
    activemap_sim::NoisePreset::from_name(&args.noise)
        .with_context(|| format!("--noise {}: expected `none` or `realistic`", args.noise))?;
    // The noise is the flow's `sim` node's, so the flow's checks configure the tracker for it
    // (`activemap_operators::checks::implied_overrides`) as they do in `activemap run`.
    let noise_override =
        activemap_runtime::dataflow::Override::parse(&format!("sim.noise={}", args.noise))
            .map_err(|e| anyhow::anyhow!("--noise: {e}"))?;
    let overrides = [vec![noise_override], args.set.set.clone()].concat();
    let flow = crate::load(&args.flow, &overrides)?;
    let (tracker, mapper) = activemap_operators::mapper::slam_nodes(&flow)
        .with_context(|| format!("{}", args.flow.display()))?;
    let noise =
        activemap_operators::single_node_config::<activemap_operators::sim::Config>(&flow, "sim")
            .with_context(|| format!("{}", args.flow.display()))?
            .noise;
    let slam_for = |resolution: u32| {
        let (track, map) = activemap_bench::slam_loop::resolution_profile(
            resolution,
            tracker.downscale,
            mapper.downscale,
        );
        let (mut t, mut m) = (tracker.clone(), mapper.clone());
        (t.downscale, m.downscale) = (Some(track), Some(map));
        activemap_operators::mapper::slam_config(&t, &m)
    };
    let noise_name = noise.is_active().then_some(args.noise.as_str());
    println!(
        "# SLAM of {}: tracker {:?}, mapper {:?}, noise {}",
        args.flow.display(),
        tracker,
        mapper,
        args.noise
    );
    for row in activemap_bench::slam_bench::run(&cases, &noise, noise_name, slam_for)
        .context("SLAM benchmark")?
    {
        println!("{row}");
    }
    Ok(())
}

/// Options of `activemap bench planning` (issue 6, the planning library alone).
#[derive(clap::Args)]
pub struct PlanningArgs {
    /// Repetitions of each micro-benchmark.
    #[arg(long, default_value_t = 5)]
    repetitions: usize,
    /// Seeds of the library-only FBE episodes (true poses, synthetic 2.5D houses); empty skips them.
    #[arg(long, value_delimiter = ',', default_values_t = [1u64, 2, 3])]
    seeds: Vec<u64>,
    /// Further procedural scenes for the same episodes, after the houses: `home:<seed>`,
    /// `office:<seed>` (the large scenes of issue 36) or `house:<seed>`.
    #[arg(long, value_delimiter = ',')]
    scenes: Vec<String>,
    /// Step budget of each episode.
    #[arg(long, default_value_t = 2000)]
    steps: usize,
}

/// Runs the planning micro-benchmarks.
pub fn planning(args: &PlanningArgs) -> anyhow::Result<()> {
    let cfg = activemap_bench::planning_bench::BenchConfig {
        repetitions: args.repetitions,
        explore_seeds: args.seeds.clone(),
        explore_scenes: args.scenes.clone(),
        explore_steps: args.steps,
        ..Default::default()
    };
    for row in activemap_bench::planning_bench::run(&cfg).context("planning benchmark")? {
        println!("planning {} {:.3} {}", row.name, row.value, row.unit);
    }
    Ok(())
}

/// Options of `activemap bench metrics` (issue 7).
#[derive(clap::Args)]
pub struct MetricsArgs {
    /// Image width.
    #[arg(long, default_value_t = 640)]
    width: usize,
    /// Image height.
    #[arg(long, default_value_t = 480)]
    height: usize,
    /// Repetitions per metric.
    #[arg(long, default_value_t = 3)]
    repetitions: usize,
}

/// Times every evaluation metric.
pub fn metrics(args: &MetricsArgs) -> anyhow::Result<()> {
    let rows = activemap_eval::bench::run(args.width, args.height, args.repetitions)
        .context("metrics benchmark")?;
    for row in rows {
        match row.mean_ms {
            Some(ms) => println!("metrics {} {} mean_ms {ms:.3}", row.name, row.input),
            None => println!("metrics {} {} missing ({})", row.name, row.input, row.note),
        }
    }
    Ok(())
}
