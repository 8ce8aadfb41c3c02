//! `activemap bench scorer` (issue 14): the Fisher scorer's replan (unknown space, model Fisher
//! `I(w)`, candidates and their EIG, A* to the top 20 and their rollouts, path EIG and C_local)
//! on a large partly explored house map ([`crate::house_map`]), timed stage by stage through
//! [`FisherScorer::replan`], the very call the `scorer` operator makes.
//!
//! The goal is the largest reachable frontier region (the `frontier` operator's
//! [`reachable_regions`], largest first), its centroid the candidates' focus; with no frontier
//! left the replan refines. Three cases, each `repeats` times, medians reported:
//!
//! - `cold`: a fresh scorer per replan, the model Fisher built from scratch (`mc_poses` views);
//! - `incremental`: one scorer, the map snapshot's frame id bumped before each replan (what a
//!   keyframe does in the loop), so the model draws `mc_refresh` fresh poses and drops the
//!   oldest (the replan frame id is bumped too: new candidate draws);
//! - `reused`: the map unchanged since the last replan, the model Fisher reused as it is (only
//!   the replan frame id changes).
//!
//! The summary line reports the `incremental` median: what a replan costs in an episode, where
//! the map changes at every keyframe.

use std::fmt::Write as _;

use activemap_active::scorer::{ScoringMap, StageTimings};
use activemap_active::{FisherScorer, GoalRequest, ReplanInput, ReplanOutcome};
use activemap_geometry::{PlanarPose, RobotModel, planar_from_camera_pose};
use activemap_planning::clearance::ClearanceConfig;
use activemap_planning::frontier::{FrontierConfig, reachable_regions};
use anyhow::Context as _;
use nalgebra::Point2;

use crate::house_map::HouseMap;
use crate::stats::{kendall_tau, median};

/// The scorer's settings (re-exported for the CLI, which reads them from a flow's `scorer`
/// node).
pub use activemap_active::FisherConfig;

/// One timed case: its replans' timings and what each replan produced.
#[derive(Debug, Clone, PartialEq)]
pub struct Case {
    /// `cold`, `incremental` or `reused`.
    pub name: &'static str,
    /// What the case does to the model Fisher.
    pub model: String,
    /// Timings of each replan.
    pub timings: Vec<StageTimings>,
    /// Candidates that survived the free-space test, per replan.
    pub candidates: Vec<usize>,
    /// Paths scored, per replan.
    pub paths: Vec<usize>,
    /// Whether each replan reused the model unchanged.
    pub model_reused: Vec<bool>,
    /// Whether each replan chose a path.
    pub chosen: Vec<bool>,
    /// Scored poses along all paths, per replan (the path-score stage's views).
    pub path_views: Vec<usize>,
    /// Distinct poses among them (each rendered once), per replan.
    pub distinct_views: Vec<usize>,
    /// Median rollout length of the paths (actions), per replan.
    pub path_actions: Vec<f64>,
    /// Per replan with at least two paths of finite objective: whether the two best tie
    /// ([`best_two_tie`]).
    pub ties: Vec<bool>,
    /// Per replan: each path's goal and objective (for the rank agreement of two settings).
    pub objectives: Vec<Vec<(PlanarPose, f64)>>,
    /// Per replan: the chosen path's goal.
    pub chosen_goals: Vec<Option<PlanarPose>>,
    /// Per replan: every candidate that survived the free-space test with its EIG, best
    /// first (for the rank agreement of two settings' candidate EIGs).
    pub candidate_eigs: Vec<Vec<(PlanarPose, f64)>>,
}

/// Relative gap under which the two best paths' objectives count as tied: 1 % of the best's
/// magnitude (issue 34: a choice the objective cannot make).
pub const TIE_RELATIVE: f64 = 0.01;

/// Whether the two lowest finite values of a replan's path `objectives` lie within
/// [`TIE_RELATIVE`] of the best's magnitude; `None` with fewer than two finite values.
pub fn best_two_tie(objectives: &[f64]) -> Option<bool> {
    let mut values: Vec<f64> = objectives
        .iter()
        .copied()
        .filter(|o| o.is_finite())
        .collect();
    if values.len() < 2 {
        return None;
    }
    values.sort_by(f64::total_cmp);
    Some(values[1] - values[0] <= TIE_RELATIVE * values[0].abs())
}

impl Case {
    fn new(name: &'static str, model: String) -> Self {
        Self {
            name,
            model,
            timings: Vec::new(),
            candidates: Vec::new(),
            paths: Vec::new(),
            model_reused: Vec::new(),
            chosen: Vec::new(),
            path_views: Vec::new(),
            distinct_views: Vec::new(),
            path_actions: Vec::new(),
            ties: Vec::new(),
            objectives: Vec::new(),
            chosen_goals: Vec::new(),
            candidate_eigs: Vec::new(),
        }
    }

    fn push(&mut self, outcome: &ReplanOutcome) {
        self.timings.push(outcome.timings);
        self.candidates.push(outcome.candidates.len());
        self.paths.push(outcome.paths.len());
        self.model_reused.push(outcome.model_reused);
        self.chosen.push(outcome.chosen.is_some());
        self.distinct_views.push(outcome.distinct_path_views);
        self.path_views
            .push(outcome.paths.iter().map(|p| p.scored_steps.len()).sum());
        let actions: Vec<f64> = outcome.paths.iter().map(|p| p.actions as f64).collect();
        self.path_actions.push(median(&actions).unwrap_or(f64::NAN));
        let objectives: Vec<f64> = outcome.paths.iter().map(|p| p.objective).collect();
        self.ties.extend(best_two_tie(&objectives));
        self.objectives.push(
            outcome
                .paths
                .iter()
                .map(|p| (p.goal, p.objective))
                .collect(),
        );
        self.chosen_goals
            .push(outcome.chosen.map(|i| outcome.paths[i].goal));
        self.candidate_eigs
            .push(outcome.candidates.iter().map(|c| (c.pose, c.eig)).collect());
    }

    /// The median of one stage over the replans (ms).
    pub fn median_of(&self, stage: fn(&StageTimings) -> f64) -> f64 {
        median(&self.timings.iter().map(stage).collect::<Vec<_>>()).unwrap_or(f64::NAN)
    }

    /// The median total (ms).
    pub fn median_total_ms(&self) -> f64 {
        self.median_of(|t| t.total_ms)
    }
}

/// What the benchmark measured.
#[derive(Debug, Clone, PartialEq)]
pub struct ScorerBench {
    /// Gaussians of the map.
    pub gaussians: usize,
    /// Unknown-space Gaussians the replans added.
    pub unknown_gaussians: usize,
    /// The goal: the largest frontier's size (cells) and centroid, or `None` (refine).
    pub frontier: Option<(usize, [f64; 2])>,
    /// Reachable frontier regions of the grid.
    pub regions: usize,
    /// `cold`, `incremental`, `reused`.
    pub cases: Vec<Case>,
    /// The scorer settings.
    pub fisher: FisherConfig,
    /// Scoring image size, pixels.
    pub scoring_size: (u32, u32),
    /// Threads of the global pool (the machine's cores unless `RAYON_NUM_THREADS` says).
    pub threads: usize,
    /// The last replan's note (why it fell back), if any.
    pub note: Option<String>,
    /// Kendall τ of the top candidates' EIG between independent model Fisher draws, one per
    /// pair of draws ([`model_tau`]).
    pub model_tau: Vec<f64>,
}

/// Pairs of independent model Fisher draws [`run`] compares (`scorer model_tau`).
pub const MODEL_TAU_PAIRS: usize = 3;

/// A fresh scorer with `fisher` for `house`, told every keyframe of the build (the
/// `keyframes` model Fisher renders them on its first replan).
fn fresh_scorer(house: &HouseMap, fisher: &FisherConfig) -> anyhow::Result<FisherScorer> {
    let sim = house.sim.config();
    let mut scorer =
        FisherScorer::new(fisher.clone(), sim.robot, sim.intrinsics).context("bench scorer")?;
    for (frame, pose) in &house.keyframe_poses {
        scorer.add_keyframe(*frame, *pose);
    }
    Ok(scorer)
}

/// The stability of the model Fisher (issue 34 item 2): for each of `pairs` pairs of fresh
/// scorers whose Monte-Carlo draws are independent (`model_seed` 2p+1 and 2p+2; the same
/// candidates and unknown space), Kendall τ between the view EIGs each gives the candidate
/// poses `top` (the top candidates of a replan) on the house's last frame. A keyframe model
/// Fisher draws nothing, so its τ is 1 by construction.
pub fn model_tau(
    house: &HouseMap,
    fisher: &FisherConfig,
    goal: GoalRequest,
    top: &[PlanarPose],
    pairs: usize,
) -> anyhow::Result<Vec<f64>> {
    let map = house.scoring_map();
    let input = house.replan_input(&map, goal);
    let mut taus = Vec::with_capacity(pairs);
    for p in 0..pairs as u64 {
        let eigs = |model_seed: u64| -> anyhow::Result<Vec<f64>> {
            let config = FisherConfig {
                model_seed,
                ..fisher.clone()
            };
            Ok(fresh_scorer(house, &config)?.pose_eigs(&input, top)?)
        };
        let (a, b) = (eigs(2 * p + 1)?, eigs(2 * p + 2)?);
        taus.push(kendall_tau(&a, &b).unwrap_or(f64::NAN));
    }
    Ok(taus)
}

/// How two settings' replans on the same house agree (the same frames, so the same
/// candidate draws): per replan, Kendall τ of the objectives of the paths both scored (matched
/// by goal), Kendall τ of the EIGs of the candidates both kept, how many of the base's top
/// candidates the other keeps among its own top, and whether both chose the same goal.
#[derive(Debug, Clone, PartialEq)]
pub struct Agreement {
    /// τ per replan with at least two common paths of finite objective in both.
    pub taus: Vec<f64>,
    /// τ of the candidate EIGs per replan with at least two common candidates of finite EIG.
    pub candidate_taus: Vec<f64>,
    /// Per replan: the share of the base's top `top_candidates` (by EIG) that are also among
    /// the other's top `top_candidates`, i.e. the share of the same paths planned.
    pub top_overlap: Vec<f64>,
    /// Replans whose chosen goals are the same.
    pub same_choice: usize,
    /// Replans compared.
    pub replans: usize,
}

/// A pose's exact bits: two settings' replans on the same frames draw the very same poses.
fn key(p: &PlanarPose) -> [u64; 3] {
    [p.x.to_bits(), p.y.to_bits(), p.yaw.to_bits()]
}

/// Kendall τ of the values `a` and `b` give the poses both hold (matched by [`key`], finite
/// in both); `None` with fewer than two such poses.
fn matched_tau(a: &[(PlanarPose, f64)], b: &[(PlanarPose, f64)]) -> Option<f64> {
    let (mut x, mut y) = (Vec::new(), Vec::new());
    for (pose, u) in a {
        if let Some((_, v)) = b.iter().find(|(q, _)| key(q) == key(pose))
            && u.is_finite()
            && v.is_finite()
        {
            x.push(*u);
            y.push(*v);
        }
    }
    kendall_tau(&x, &y)
}

/// The [`Agreement`] of `other`'s replans with `base`'s, case by case (by name), replan by
/// replan (as many as both ran).
pub fn agreement(base: &ScorerBench, other: &ScorerBench) -> Agreement {
    let top = base.fisher.top_candidates;
    let mut out = Agreement {
        taus: Vec::new(),
        candidate_taus: Vec::new(),
        top_overlap: Vec::new(),
        same_choice: 0,
        replans: 0,
    };
    for a in &base.cases {
        let Some(b) = other.cases.iter().find(|b| b.name == a.name) else {
            continue;
        };
        for r in 0..a.objectives.len().min(b.objectives.len()) {
            out.replans += 1;
            let chosen = (
                a.chosen_goals[r].as_ref().map(key),
                b.chosen_goals[r].as_ref().map(key),
            );
            out.same_choice += usize::from(chosen.0 == chosen.1);
            out.taus
                .extend(matched_tau(&a.objectives[r], &b.objectives[r]));
        }
        for r in 0..a.candidate_eigs.len().min(b.candidate_eigs.len()) {
            let (ca, cb) = (&a.candidate_eigs[r], &b.candidate_eigs[r]);
            out.candidate_taus.extend(matched_tau(ca, cb));
            let top = top.min(ca.len());
            if top > 0 {
                let shared = ca[..top]
                    .iter()
                    .filter(|(p, _)| cb.iter().take(top).any(|(q, _)| key(q) == key(p)))
                    .count();
                out.top_overlap.push(shared as f64 / top as f64);
            }
        }
    }
    out
}

/// Runs the three cases, `repeats` replans each, on `house`, and [`MODEL_TAU_PAIRS`] pairs
/// of model Fisher draws.
pub fn run(house: &HouseMap, fisher: &FisherConfig, repeats: usize) -> anyhow::Result<ScorerBench> {
    run_with(house, fisher, repeats, true, MODEL_TAU_PAIRS)
}

/// [`run`] with a choice: `all_cases` false runs one `cold` replan (it builds the model) and
/// the `incremental` case only (what a comparison of settings needs); `tau_pairs` pairs of
/// model Fisher draws (0: none).
pub fn run_with(
    house: &HouseMap,
    fisher: &FisherConfig,
    repeats: usize,
    all_cases: bool,
    tau_pairs: usize,
) -> anyhow::Result<ScorerBench> {
    anyhow::ensure!(repeats >= 1, "bench scorer: --repeats must be at least 1");
    let robot: RobotModel = house.sim.config().robot;
    let grid = &house.grid;
    let planar = planar_from_camera_pose(&house.pose);
    let clearance = ClearanceConfig::for_disc(robot.radius_m, grid.geometry.resolution)?;
    let regions = reachable_regions(
        grid,
        Point2::new(planar.x, planar.y),
        &clearance,
        &FrontierConfig::default(),
    )
    .context("bench scorer: frontier regions of the house grid")?;
    let (goal, frontier) = match regions.first() {
        Some(r) => (
            GoalRequest::Frontier { focus: r.centroid },
            Some((r.size(), [r.centroid.x, r.centroid.y])),
        ),
        None => (GoalRequest::Refine, None),
    };
    let base = house.frame_id;
    let map_at = |frame_id: u64| ScoringMap {
        gaussians: house.gaussians.clone(),
        ids: house.ids.clone(),
        frame_id,
    };
    let fresh = || fresh_scorer(house, fisher);
    let replan = |scorer: &mut FisherScorer, frame_id: u64, map: &ScoringMap| {
        let input = ReplanInput {
            frame_id,
            grid,
            pose: house.pose,
            map,
            goal,
        };
        scorer
            .replan(&input)
            .with_context(|| format!("bench scorer: replan at frame {frame_id}"))
    };

    // Cold: a fresh scorer each time, same frame (same draws).
    use activemap_active::ModelFisherSource as Source;
    let keyframes = house.keyframe_poses.len();
    let (built, changed) = match fisher.model_fisher {
        Source::McFreeSpace => (
            format!("built: {} MC poses", fisher.mc_poses),
            format!("map changed: {} fresh MC poses", fisher.mc_refresh),
        ),
        Source::Keyframes => (
            format!("built: {keyframes} keyframes"),
            "map changed: no new keyframe".to_string(),
        ),
        Source::Both => (
            format!(
                "built: {keyframes} keyframes + {} MC poses",
                fisher.mc_poses
            ),
            format!("map changed: {} fresh MC poses", fisher.mc_refresh),
        ),
    };
    let mut cold = Case::new("cold", built);
    let map0 = map_at(base);
    let mut scorer = fresh()?;
    let mut last = None;
    for r in 0..if all_cases { repeats } else { 1 } {
        if r > 0 {
            scorer = fresh()?;
        }
        let out = replan(&mut scorer, base, &map0)?;
        cold.push(&out);
        last = Some(out);
    }
    let scoring_size = {
        let k = scorer.view_settings().intrinsics;
        (k.width, k.height)
    };
    // Incremental: the last cold scorer goes on, the map snapshot changing before each replan.
    let mut incremental = Case::new("incremental", changed);
    let mut frame = base;
    for _ in 0..repeats {
        frame += 1;
        let out = replan(&mut scorer, frame, &map_at(frame))?;
        incremental.push(&out);
        last = Some(out);
    }
    // Reused: the map of the last incremental replan, unchanged.
    let mut reused = Case::new("reused", "map unchanged: reused".into());
    let unchanged = map_at(frame);
    for r in 0..if all_cases { repeats } else { 0 } {
        let out = replan(&mut scorer, frame + 1 + r as u64, &unchanged)?;
        reused.push(&out);
        last = Some(out);
    }
    let last = last.expect("repeats >= 1");
    let top: Vec<PlanarPose> = last
        .candidates
        .iter()
        .take(fisher.top_candidates)
        .map(|c| c.pose)
        .collect();
    let model_tau = if top.len() >= 2 && tau_pairs > 0 {
        model_tau(house, fisher, goal, &top, tau_pairs)?
    } else {
        Vec::new()
    };
    Ok(ScorerBench {
        gaussians: house.gaussians.len(),
        unknown_gaussians: last.unknown_gaussians,
        frontier,
        regions: regions.len(),
        cases: if all_cases {
            vec![cold, incremental, reused]
        } else {
            vec![cold, incremental]
        },
        fisher: fisher.clone(),
        scoring_size,
        threads: rayon::current_num_threads(),
        note: last.note,
        model_tau,
    })
}

impl ScorerBench {
    /// The `incremental` case (the summary's).
    pub fn incremental(&self) -> &Case {
        self.cases
            .iter()
            .find(|c| c.name == "incremental")
            .expect("the benchmark always runs the incremental case")
    }

    /// The summary lines `scorer replan_median_ms <x> gaussians <n>` (x: the `incremental`
    /// median total; n: the map's Gaussians) and `scorer tie_fraction <f> replans <m>` (the
    /// share of all the cases' replans whose two best paths tie within 1 %) and `scorer
    /// model_tau <τ> pairs <p>` (the mean Kendall τ of the top candidates' EIG between
    /// independent model Fisher draws, [`model_tau`]).
    pub fn summary(&self) -> String {
        let ties: Vec<bool> = self
            .cases
            .iter()
            .flat_map(|c| c.ties.iter().copied())
            .collect();
        let fraction = if ties.is_empty() {
            f64::NAN
        } else {
            ties.iter().filter(|&&t| t).count() as f64 / ties.len() as f64
        };
        let tau = if self.model_tau.is_empty() {
            f64::NAN
        } else {
            self.model_tau.iter().sum::<f64>() / self.model_tau.len() as f64
        };
        format!(
            "scorer replan_median_ms {:.1} gaussians {}\nscorer tie_fraction {fraction:.2} replans {}\n\
             scorer model_tau {tau:.3} pairs {}",
            self.incremental().median_total_ms(),
            self.gaussians,
            ties.len(),
            self.model_tau.len()
        )
    }

    /// The table: one row per case, median ms per stage, and the counts.
    pub fn table(&self) -> String {
        let mut s = String::new();
        let f = &self.fisher;
        let _ = writeln!(
            s,
            "# scorer settings: scoring {}×{} px, K = {} candidates, top {}, stride {}, max_actions {:?}, \
             model {:?} (N = {}, refresh {}), objective {:?}; {} threads",
            self.scoring_size.0,
            self.scoring_size.1,
            f.candidates,
            f.top_candidates,
            f.stride,
            f.max_actions,
            f.model_fisher,
            f.mc_poses,
            f.mc_refresh,
            f.objective,
            self.threads
        );
        let _ = writeln!(
            s,
            "# map {} Gaussians + {} unknown-space = {} scored; goal: {}",
            self.gaussians,
            self.unknown_gaussians,
            self.gaussians + self.unknown_gaussians,
            match self.frontier {
                Some((cells, [x, y])) => format!(
                    "largest of {} frontier regions ({cells} cells, centroid ({x:.2}, {y:.2}))",
                    self.regions
                ),
                None => "refine (no reachable frontier)".into(),
            }
        );
        let _ = writeln!(
            s,
            "{:<12} {:>4} {:>10} {:>11} {:>10} {:>10} {:>14} {:>10}  {:>5} {:>5} {:>7} {:>6} {:>8} {:>6}  model",
            "case",
            "runs",
            "unknown_ms",
            "model_ms",
            "cands_ms",
            "paths_ms",
            "path_scores_ms",
            "total_ms",
            "cands",
            "paths",
            "actions",
            "views",
            "distinct",
            "chosen"
        );
        for c in &self.cases {
            let med = |v: &[usize]| {
                median(&v.iter().map(|&x| x as f64).collect::<Vec<_>>()).unwrap_or(f64::NAN)
            };
            let reused = c.model_reused.iter().filter(|r| **r).count();
            let _ = writeln!(
                s,
                "{:<12} {:>4} {:>10.1} {:>11.1} {:>10.1} {:>10.1} {:>14.1} {:>10.1}  {:>5.0} {:>5.0} {:>7.0} {:>6.0} {:>8.0} {:>3}/{:<2}  {}{}",
                c.name,
                c.timings.len(),
                c.median_of(|t| t.unknown_ms),
                c.median_of(|t| t.model_ms),
                c.median_of(|t| t.candidates_ms),
                c.median_of(|t| t.paths_ms),
                c.median_of(|t| t.path_scores_ms),
                c.median_total_ms(),
                med(&c.candidates),
                med(&c.paths),
                median(&c.path_actions).unwrap_or(f64::NAN),
                med(&c.path_views),
                med(&c.distinct_views),
                c.chosen.iter().filter(|x| **x).count(),
                c.chosen.len(),
                c.model,
                if reused > 0 {
                    format!(" ({reused} reused)")
                } else {
                    String::new()
                },
            );
        }
        let _ = writeln!(
            s,
            "# medians over the runs; cands = candidates in free space (each one view), actions = \
             median rollout length of the paths, views = poses scored along all paths, distinct = \
             those rendered (paths share their first moves); the \
             summary line reports `incremental` (the map changed since the last replan, as \
             after every keyframe in an episode)"
        );
        if let Some(note) = &self.note {
            let _ = writeln!(s, "# last replan's note: {note}");
        }
        s
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_two_best_paths_tie_within_one_percent_of_the_best() {
        use super::best_two_tie;
        assert_eq!(best_two_tie(&[-10.0, f64::INFINITY]), None);
        assert_eq!(best_two_tie(&[]), None);
        assert_eq!(best_two_tie(&[5.0, -10.0, -9.95]), Some(true));
        assert_eq!(best_two_tie(&[-9.8, -10.0, 3.0]), Some(false));
        assert_eq!(
            best_two_tie(&[2.0, 2.0]),
            Some(true),
            "equal objectives tie"
        );
        assert_eq!(best_two_tie(&[100.0, 100.5, f64::INFINITY]), Some(true));
    }

    use super::*;
    use crate::house_map::{HouseMapConfig, build};

    /// Smoke run of both Fisher benchmarks on a tiny house map (32² frames, a few steps, a
    /// small scorer): the cases, the table and the exact summary lines.
    #[test]
    fn both_fisher_benchmarks_run_on_a_tiny_house() {
        let mut mapping = activemap_slam::MappingConfig::default();
        mapping.mapper.iterations = 2;
        mapping.mapper.coarse_iterations = 1;
        let config = HouseMapConfig {
            insert_fraction: Some(0.5),
            ..HouseMapConfig::new(1, 32, 6, mapping)
        };
        let house = build(&config).unwrap();
        assert_eq!(house.frames, 6);
        assert!(house.keyframes >= 1 && !house.gaussians.is_empty());
        assert_eq!(house.ids.len(), house.gaussians.len());
        assert!(house.describe(&config).contains("TRUE poses"));
        let fisher = FisherConfig {
            mc_poses: 2,
            mc_refresh: 1,
            candidates: 6,
            top_candidates: 2,
            scoring_width: 8,
            max_actions: Some(10),
            ..FisherConfig::default()
        };
        let bench = run(&house, &fisher, 2).unwrap();
        let names: Vec<&str> = bench.cases.iter().map(|c| c.name).collect();
        assert_eq!(names, ["cold", "incremental", "reused"]);
        assert!(bench.cases.iter().all(|c| c.timings.len() == 2));
        assert!(bench.cases[0].model_reused.iter().all(|r| !r));
        assert!(bench.cases[1].model_reused.iter().all(|r| !r));
        assert!(bench.cases[2].model_reused.iter().all(|r| *r));
        let summary = bench.summary();
        let lines: Vec<&str> = summary.lines().collect();
        let (timing, ties) = (lines[0], lines[1]);
        let tau: Vec<&str> = lines[2].split(' ').collect();
        assert_eq!((tau[0], tau[1], tau[3]), ("scorer", "model_tau", "pairs"));
        assert_eq!(bench.model_tau.len(), MODEL_TAU_PAIRS);
        let same = agreement(&bench, &bench);
        assert_eq!(same.same_choice, same.replans);
        assert!(same.taus.iter().all(|t| *t == 1.0));
        assert!(!same.candidate_taus.is_empty());
        assert!(same.candidate_taus.iter().all(|t| *t == 1.0));
        assert!(same.top_overlap.iter().all(|t| *t == 1.0));
        let tie_fields: Vec<&str> = ties.split(' ').collect();
        assert_eq!(
            (
                tie_fields[0],
                tie_fields[1],
                tie_fields[3],
                tie_fields.len()
            ),
            ("scorer", "tie_fraction", "replans", 5),
            "{ties}"
        );
        let counted: usize = bench.cases.iter().map(|c| c.ties.len()).sum();
        assert_eq!(tie_fields[4], counted.to_string());
        let fields: Vec<&str> = timing.split(' ').collect();
        assert_eq!(fields.len(), 5, "{summary}");
        assert_eq!(
            (fields[0], fields[1], fields[3]),
            ("scorer", "replan_median_ms", "gaussians")
        );
        assert!(fields[2].parse::<f64>().unwrap() > 0.0);
        assert_eq!(fields[4], house.gaussians.len().to_string());
        let table = bench.table();
        assert!(
            table.contains("incremental") && table.contains("path_scores_ms"),
            "{table}"
        );
        assert!(run(&house, &fisher, 0).is_err());

        let eig = crate::eig_psnr::run(&house, &fisher, 12, 3).unwrap();
        assert_eq!(eig.samples.len(), 12);
        assert!(
            eig.samples
                .iter()
                .all(|s| s.eig >= 0.0 && s.psnr.is_finite())
        );
        let line = eig.summary();
        assert!(
            line.starts_with("eig_psnr spearman ") && line.ends_with(" poses 12"),
            "{line}"
        );
        assert!(eig.table().contains("psnr_db"));
        let dir = tempfile::tempdir().unwrap();
        let png = dir.path().join("plot/eig_psnr.png");
        eig.write_plot(&png).unwrap();
        assert!(image::open(&png).is_ok());
    }
}
