//! `activemap bench explore` (issue 6): the whole exploration loop (`dataflow.yaml`: sim →
//! tracker → mapper → occupancy → frontier → FBE planner → scorer → follower, estimated poses)
//! on several procedural houses, each as a real launched run with its step budget and no
//! end-of-run rendering evaluation. Per house it prints
//! `explore fbe <house> coverage <x> ate_cm <y> steps_per_s <z>`, then the path length and the
//! share of each node's busy time (the run folder's `timings.csv`, written by every node host).
//!
//! Steps per second are the steps taken over the wall time of the launched run (process start
//! and shutdown included), on this machine as loaded at the time: quote them with the load.
//!
//! A house whose run is invalid (warnings in its `summary.json`: a start that sees nothing, a
//! robot that cannot move, an empty map…) prints `explore fbe <house> INVALID <code>: <message>`
//! per reason and is left out of the medians, which count the houses left out.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use activemap_eval::run_folder::{RunError, RunFolder};
use activemap_runtime::launch::{LaunchOptions, run_local};
use activemap_runtime::node::install_stop_signals;
use anyhow::{Context as _, bail};

/// Options of `activemap bench explore`.
#[derive(clap::Args)]
pub struct ExploreArgs {
    /// The exploration dataflow (its `sim` and `evaluator` nodes get each house).
    #[arg(long, default_value = "dataflow.yaml")]
    flow: PathBuf,
    /// Procedural houses (the seeds of `house:<n>` scenes); default 1,2,3 unless `--scenes`
    /// is given.
    #[arg(long, value_delimiter = ',')]
    houses: Vec<u64>,
    /// Scene files explored after the houses, e.g.
    /// `../shared/data/scenes/aws_small_house.glb` (the furnished house).
    #[arg(long, value_delimiter = ',')]
    scenes: Vec<String>,
    /// Simulator noise on every episode: `none` or `realistic` (the `sim` node's `noise` key).
    #[arg(long)]
    noise: Option<String>,
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
    /// Folder of the run folders (one per house).
    #[arg(long, default_value = "runs/bench-explore")]
    out: PathBuf,
}

/// One node's busy time in a run (a row of the run folder's `timings.csv`).
pub use activemap_eval::run_folder::StageTime;

/// Reads the run folder `dir`'s `timings.csv` through the run-folder contract; rows of the same
/// stage (a restarted node) are summed. Sorted by busy time, largest first. A malformed row is
/// an error naming the file and line (`timings.csv:LINE`).
pub fn read_timings(dir: &Path) -> anyhow::Result<Vec<StageTime>> {
    let run = RunFolder::new(dir);
    let rows = match run.read_timings() {
        Ok(Some(rows)) => rows,
        Ok(None) => bail!("{}: missing", run.path(RunFolder::TIMINGS).display()),
        Err(RunError::MalformedRow { path, line, detail }) => {
            bail!("{}:{line}: {detail}", path.display())
        }
        Err(e) => return Err(e.into()),
    };
    let mut out = StageTime::summed(&rows);
    out.sort_by(|a, b| b.seconds.total_cmp(&a.seconds));
    Ok(out)
}

/// `stage share%` pairs: each stage's part of the summed busy time of all stages.
pub fn shares(stages: &[StageTime]) -> Vec<(String, f64)> {
    let total: f64 = stages.iter().map(|s| s.seconds).sum();
    stages
        .iter()
        .map(|s| {
            let share = if total > 0.0 {
                100.0 * s.seconds / total
            } else {
                0.0
            };
            (s.stage.clone(), share)
        })
        .collect()
}

/// What one house's episode measured.
#[derive(Debug, Clone, PartialEq)]
pub struct HouseResult {
    /// `house:<n>`.
    pub scene: String,
    /// Final 2D coverage, percent.
    pub coverage_pct: f64,
    /// ATE RMSE, centimetres (None when too few poses).
    pub ate_cm: Option<f64>,
    /// Steps taken.
    pub steps: u64,
    /// Steps over the run's wall time.
    pub steps_per_s: f64,
    /// True path length, metres.
    pub path_length_m: f64,
    /// Forward actions, and how many of them were blocked (the evaluator's counts).
    pub forwards: (u64, u64),
    /// Busy time per node.
    pub stages: Vec<StageTime>,
    /// Why the run is invalid (the summary's warnings); empty = valid.
    pub warnings: Vec<activemap_eval::RunWarning>,
}

impl HouseResult {
    /// The benchmark's lines for this house.
    pub fn lines(&self) -> Vec<String> {
        let ate = self
            .ate_cm
            .map_or_else(|| "nan".to_string(), |a| format!("{a:.1}"));
        let mut out = vec![
            format!(
                "explore fbe {} coverage {:.1} ate_cm {ate} steps_per_s {:.2}",
                self.scene, self.coverage_pct, self.steps_per_s
            ),
            format!(
                "explore fbe {} steps {} path_m {:.2} forwards {} blocked {}",
                self.scene, self.steps, self.path_length_m, self.forwards.0, self.forwards.1
            ),
        ];
        let per_step = |s: f64| 1000.0 * s / self.steps.max(1) as f64;
        for ((stage, share), t) in shares(&self.stages).iter().zip(&self.stages) {
            out.push(format!(
                "explore fbe {} stage {stage} share_pct {share:.1} busy_ms_per_step {:.1}",
                self.scene,
                per_step(t.seconds)
            ));
        }
        for w in &self.warnings {
            out.push(format!(
                "explore fbe {} INVALID {}: {}",
                self.scene, w.code, w.message
            ));
        }
        out
    }
}

/// Replaces the value of `key` in a YAML flow-map line (`key: value` up to the next `,` or
/// `}`), or adds the pair before the closing `}` when absent.
fn set_flow_key(line: &str, key: &str, value: &str) -> String {
    let pattern = format!("{key}:");
    let at = line.match_indices(&pattern).map(|(i, _)| i).find(|&i| {
        i == 0 || !line.as_bytes()[i - 1].is_ascii_alphanumeric() && line.as_bytes()[i - 1] != b'_'
    });
    match at {
        Some(i) => {
            let start = i + pattern.len();
            let end = line[start..]
                .find([',', '}'])
                .map_or(line.len(), |e| start + e);
            format!("{}{key}: {value}{}", &line[..i], &line[end..])
        }
        None => match line.rfind('}') {
            Some(close) => format!(
                "{}, {key}: {value} {}",
                line[..close].trim_end(),
                &line[close..]
            ),
            None => line.to_string(),
        },
    }
}

/// The benchmark's dataflow for one house: every flow-map line holding `scene:` (the `sim` and
/// `evaluator` nodes) gets the house (and the size limits when given); the simulator's line also
/// gets the resolution. Checked by parsing the result and reading the `sim` node's config back.
pub fn house_flow(
    text: &str,
    scene: &str,
    resolution: u32,
    max_rooms: Option<u32>,
    max_area: Option<f64>,
    noise: Option<&str>,
) -> anyhow::Result<String> {
    // The size limits shape procedural houses only; a scene file refuses them.
    let is_house = activemap_sim::SceneSpec::new(scene).is_procedural();
    let (max_rooms, max_area) = if is_house {
        (max_rooms, max_area)
    } else {
        (None, None)
    };
    let mut out = String::new();
    for line in text.lines() {
        let mut line = line.to_string();
        if line.contains("scene:") && line.contains('{') {
            line = set_flow_key(&line, "scene", &format!("\"{scene}\""));
            if let Some(r) = max_rooms {
                line = set_flow_key(&line, "max_rooms", &r.to_string());
            }
            if let Some(a) = max_area {
                line = set_flow_key(&line, "max_area", &a.to_string());
            }
            if line.contains("width:") {
                line = set_flow_key(&line, "width", &resolution.to_string());
                line = set_flow_key(&line, "height", &resolution.to_string());
                if let Some(n) = noise {
                    line = set_flow_key(&line, "noise", n);
                }
            }
        }
        out.push_str(&line);
        out.push('\n');
    }
    let flow = activemap_operators::checks::parse("bench explore flow", &out, Path::new(""))
        .map_err(|d| anyhow::anyhow!("{d}"))?;
    let sim = flow
        .nodes
        .iter()
        .find(|n| matches!(&n.implementation, activemap_runtime::dataflow::NodeImpl::Operator(op) if op == "sim"))
        .context("the flow has no `sim` node")?;
    let c = &sim.config;
    anyhow::ensure!(
        c["scene"] == scene
            && c["width"].as_u64() == Some(resolution.into())
            && c["height"].as_u64() == Some(resolution.into()),
        "the `sim` node's config line must be a one-line flow map with scene, width and height; got {c}"
    );
    Ok(out)
}

/// Runs one house's episode into `dir` and reads its results.
fn run_house(
    exe: &Path,
    args: &ExploreArgs,
    scene: &str,
    dir: &Path,
) -> anyhow::Result<HouseResult> {
    let source = std::fs::read_to_string(&args.flow)
        .with_context(|| format!("reading {}", args.flow.display()))?;
    let text = house_flow(
        &source,
        scene,
        args.resolution,
        args.max_rooms,
        args.max_area,
        args.noise.as_deref(),
    )?;
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let flow_path = dir.join("explore_dataflow.yaml");
    std::fs::write(&flow_path, &text)
        .with_context(|| format!("writing {}", flow_path.display()))?;
    let flow = activemap_operators::checks::load(&flow_path).map_err(|d| anyhow::anyhow!("{d}"))?;
    let run_dir = dir.join("run");
    if run_dir.exists() {
        std::fs::remove_dir_all(&run_dir)
            .with_context(|| format!("clearing {}", run_dir.display()))?;
    }
    let mut opts = LaunchOptions::new(run_dir.clone(), exe.to_path_buf());
    opts.max_steps = Some(args.steps);
    opts.record = false;
    opts.record_digests = crate::MapRecording::default().digests();
    let stop = Arc::new(AtomicBool::new(false));
    install_stop_signals(&stop)?;
    let started = Instant::now();
    let report = run_local(&flow, &opts, stop)?;
    let wall = started.elapsed().as_secs_f64();
    if let Some(failure) = report.failure {
        bail!("{scene}: the flow stopped: {failure}");
    }
    if report.interrupted {
        bail!("{scene}: interrupted");
    }
    let run = RunFolder::new(&run_dir);
    let summary = run.read_summary()?;
    let coverage = summary
        .coverage
        .with_context(|| format!("{}: no `coverage`", run.path(RunFolder::SUMMARY).display()))?;
    Ok(HouseResult {
        scene: scene.to_string(),
        coverage_pct: 100.0 * coverage,
        ate_cm: summary.ate_m.map(|a| 100.0 * a),
        steps: summary.steps,
        steps_per_s: summary.steps as f64 / wall.max(1e-9),
        path_length_m: summary.path_length_m,
        forwards: (summary.forward_actions, summary.blocked_forwards),
        stages: read_timings(&run_dir)?,
        warnings: summary.warnings,
    })
}

/// The houses run when neither `--houses` nor `--scenes` is given.
const DEFAULT_HOUSES: [u64; 3] = [1, 2, 3];

/// The `house:<n>` scenes of `--houses`, or of [`DEFAULT_HOUSES`] when neither `--houses` nor
/// `--scenes` names a scene (`bench explore` and `bench results` alike).
pub fn house_scenes(houses: &[u64], files: &[String]) -> Vec<String> {
    let houses = if houses.is_empty() && files.is_empty() {
        &DEFAULT_HOUSES[..]
    } else {
        houses
    };
    houses.iter().map(|h| format!("house:{h}")).collect()
}

/// Runs the benchmark and prints its lines.
pub fn run(args: &ExploreArgs) -> anyhow::Result<()> {
    let exe = std::env::current_exe().context("locating the activemap executable")?;
    let mut scenes = house_scenes(&args.houses, &args.scenes);
    scenes.extend(args.scenes.iter().cloned());
    let mut results = Vec::new();
    for scene in &scenes {
        let dir = args
            .out
            .join(activemap_bench::results::grid::scene_folder(scene));
        let result = run_house(&exe, args, scene, &dir)?;
        for line in result.lines() {
            println!("{line}");
        }
        results.push(result);
    }
    println!("{}", median_line(&results));
    Ok(())
}

/// The closing line: median coverage and steps per second over the valid houses, naming the
/// invalid ones left out.
pub fn median_line(results: &[HouseResult]) -> String {
    let (valid, invalid): (Vec<&HouseResult>, Vec<&HouseResult>) =
        results.iter().partition(|r| r.warnings.is_empty());
    let names = |v: &[&HouseResult]| {
        v.iter()
            .map(|r| r.scene.as_str())
            .collect::<Vec<_>>()
            .join(",")
    };
    let left_out = if invalid.is_empty() {
        String::new()
    } else {
        format!("{} invalid left out: {}", invalid.len(), names(&invalid))
    };
    if valid.is_empty() {
        return format!("explore fbe median: no valid house ({left_out})");
    }
    let median = |pick: fn(&HouseResult) -> f64| {
        let mut v: Vec<f64> = valid.iter().map(|r| pick(r)).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    format!(
        "explore fbe median coverage {:.1} steps_per_s {:.2} (houses {}{})",
        median(|r| r.coverage_pct),
        median(|r| r.steps_per_s),
        names(&valid),
        if left_out.is_empty() {
            String::new()
        } else {
            format!("; {left_out}")
        }
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_runtime::dataflow::Dataflow;

    /// A restarted node's two rows are summed; shares are of the summed busy time and add up
    /// to 100 %; a malformed row is an error naming the file and line.
    #[test]
    fn timings_are_summed_per_stage_and_shared() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("timings.csv");
        std::fs::write(
            &path,
            "stage,seconds,calls\ntracker,3.0,10\nsim,1.0,10\ntracker,1.0,5\n",
        )
        .unwrap();
        let t = read_timings(dir.path()).unwrap();
        assert_eq!(
            t,
            vec![
                StageTime {
                    stage: "tracker".into(),
                    seconds: 4.0,
                    calls: 15
                },
                StageTime {
                    stage: "sim".into(),
                    seconds: 1.0,
                    calls: 10
                }
            ]
        );
        let s = shares(&t);
        assert_eq!(s[0], ("tracker".to_string(), 80.0));
        assert_eq!(s[1], ("sim".to_string(), 20.0));
        std::fs::write(&path, "stage,seconds,calls\ntracker,x,1\n").unwrap();
        let e = format!("{:#}", read_timings(dir.path()).unwrap_err());
        assert!(e.contains("timings.csv:2"), "{e}");
    }

    /// The reference dataflow rewritten for a house keeps validating and its `sim` and
    /// `evaluator` nodes get the house; the sim gets the resolution.
    #[test]
    fn house_flow_sets_the_scene_and_resolution() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let text = std::fs::read_to_string(root.join("dataflow.yaml")).unwrap();
        let out = house_flow(&text, "house:2", 96, Some(2), Some(30.0), None).unwrap();
        let flow =
            Dataflow::parse("t", &out, PathBuf::new(), &activemap_operators::catalog()).unwrap();
        let config = |id: &str| {
            flow.nodes
                .iter()
                .find(|n| n.id == id)
                .unwrap()
                .config
                .clone()
        };
        let (sim, ev) = (config("sim"), config("evaluator"));
        assert_eq!(sim["scene"], "house:2");
        assert_eq!(sim["width"], 96);
        assert_eq!(sim["height"], 96);
        assert_eq!(sim["max_rooms"], 2);
        assert_eq!(ev["scene"], "house:2");
        assert_eq!(ev["max_area"], 30.0);
        assert_eq!(
            set_flow_key("config: { a: 1, ab: 2 }", "b", "3"),
            "config: { a: 1, ab: 2, b: 3 }"
        );
    }

    /// The per-house line has the issue's exact shape.
    #[test]
    fn the_house_line_has_the_issue_format() {
        let r = HouseResult {
            scene: "house:2".into(),
            coverage_pct: 87.26,
            ate_cm: Some(3.04),
            steps: 2000,
            steps_per_s: 3.456,
            path_length_m: 41.5,
            forwards: (800, 3),
            stages: vec![StageTime {
                stage: "tracker".into(),
                seconds: 100.0,
                calls: 4000,
            }],
            warnings: Vec::new(),
        };
        let lines = r.lines();
        assert_eq!(
            lines[0],
            "explore fbe house:2 coverage 87.3 ate_cm 3.0 steps_per_s 3.46"
        );
        assert_eq!(
            lines[1],
            "explore fbe house:2 steps 2000 path_m 41.50 forwards 800 blocked 3"
        );
        assert_eq!(
            lines[2],
            "explore fbe house:2 stage tracker share_pct 100.0 busy_ms_per_step 50.0"
        );
    }

    /// An invalid house prints its reasons and is left out of the medians, which name it.
    #[test]
    fn invalid_houses_are_marked_and_left_out_of_the_medians() {
        let house =
            |n: u64, coverage_pct: f64, warnings: Vec<activemap_eval::RunWarning>| HouseResult {
                scene: format!("house:{n}"),
                coverage_pct,
                ate_cm: None,
                steps: 206,
                steps_per_s: 2.0,
                path_length_m: 0.0,
                forwards: (206, 206),
                stages: Vec::new(),
                warnings,
            };
        let stuck = vec![activemap_eval::RunWarning::new(
            "robot_cannot_move",
            "206 of 206 forward moves blocked",
        )];
        let results = [
            house(1, 80.0, Vec::new()),
            house(2, 100.0, stuck.clone()),
            house(3, 90.0, Vec::new()),
        ];
        assert_eq!(
            results[1].lines().last().unwrap(),
            "explore fbe house:2 INVALID robot_cannot_move: 206 of 206 forward moves blocked"
        );
        assert!(!results[0].lines().iter().any(|l| l.contains("INVALID")));
        assert_eq!(
            median_line(&results),
            "explore fbe median coverage 90.0 steps_per_s 2.00 (houses house:1,house:3; 1 invalid left out: house:2)"
        );
        assert_eq!(
            median_line(&[house(2, 100.0, stuck)]),
            "explore fbe median: no valid house (1 invalid left out: house:2)"
        );
    }
}
