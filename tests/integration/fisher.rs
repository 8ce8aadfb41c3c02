//! Issue 14 end to end: the `fisher` policy (`flows/fisher.yaml`: largest frontier, Fisher
//! paths, refine when no frontier is left) as real processes on a small procedural house at
//! 64×64, a short step budget. The episode runs to its budget (the planner never ends it),
//! every replan leaves a `FisherReport` in the recording, and two runs of the same seeded flow
//! take exactly the same actions (Monte-Carlo sampling is seeded; the loop stays in lockstep,
//! the scorer waiting for the same lagged map snapshot every time). To keep the test profile's
//! cost down the scorer samples 64 candidates and plans 5 paths per replan (the flow: 256 and
//! 20); everything else is the flow's.

use std::path::Path;
use std::time::Duration;

use super::harness;
use activemap_eval::RunFolder;
use activemap_runtime::record::read_recording;
use activemap_schemas::{Action, ActionKind, FisherReport, Payload};

/// The step budget: the 72-turn start-up look-around, then replans and paths.
const STEPS: u64 = 130;

/// `flows/fisher.yaml` with a small house, a 64×64 camera (the scorer's too), fewer
/// candidates and paths per replan, and the budget.
fn small_fisher_flow() -> String {
    harness::small_house_flow(
        "flows/fisher.yaml",
        STEPS,
        &[
            (
                "camera: { width: 160, height: 160, hfov_deg: 90 }",
                "      camera: { width: 64, height: 64, hfov_deg: 90 }",
            ),
            (
                "fisher: { objective: paper }",
                "      fisher: { objective: paper, candidates: 64, top_candidates: 5 }",
            ),
        ],
    )
}

/// What one run leaves: the actions the simulator executed (steps 0..STEPS; the follower's
/// answer to the last frame may or may not be recorded before the run shuts down) and the
/// scorer's reports, in order.
struct Episode {
    actions: Vec<(u64, ActionKind)>,
    reports: Vec<FisherReport>,
    steps: u64,
    episode: String,
}

/// Runs the small `fisher` episode in `dir` and reads its recording back.
fn run_episode(dir: &Path) -> Episode {
    let flow = dir.join("fisher.yaml");
    std::fs::write(&flow, small_fisher_flow()).unwrap();
    let out = dir.join("run");
    let done = harness::run(
        &[
            "run",
            flow.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--no-eval",
        ],
        dir,
        Duration::from_secs(900),
    );
    assert!(done.status.success(), "run failed:\n{}", done.stderr);
    let run = RunFolder::new(&out);
    let summary = run.read_summary().unwrap();
    let recording = read_recording(&out.join(RunFolder::RECORDING)).unwrap();
    assert!(!recording.truncated, "the recording was cut short");
    let mut actions = Vec::new();
    let mut reports = Vec::new();
    for m in &recording.messages {
        if m.bytes.is_empty() {
            continue;
        }
        match m.topic.as_str() {
            "follower/action" => {
                let a = <Action as Payload>::from_bytes(&m.bytes).unwrap();
                if a.step < STEPS {
                    actions.push((a.step, a.action));
                }
            }
            "scorer/report" => {
                reports.push(<FisherReport as Payload>::from_bytes(&m.bytes).unwrap())
            }
            _ => {}
        }
    }
    eprintln!(
        "fisher episode: {} steps ({}), {} actions, {} reports; {}",
        summary.steps,
        summary.episode,
        actions.len(),
        reports.len(),
        reports
            .iter()
            .map(|r| format!(
                "frame {}{}: {} candidates, {} paths, chosen {}, {:.0} ms (unknown {:.0}, model {:.0}, candidates {:.0}, paths {:.0}, path scores {:.0}){}",
                r.frame_id,
                if r.refine { " (refine)" } else { "" },
                r.candidates.len(),
                r.paths.len(),
                r.chosen,
                r.timings.total_ms,
                r.timings.unknown_ms,
                r.timings.model_ms,
                r.timings.candidates_ms,
                r.timings.paths_ms,
                r.timings.path_scores_ms,
                r.fallback
                    .as_ref()
                    .map_or(String::new(), |f| format!(", fallback: {f}"))
            ))
            .collect::<Vec<_>>()
            .join("; ")
    );
    Episode {
        actions,
        reports,
        steps: summary.steps,
        episode: summary.episode,
    }
}

/// A short seeded `fisher` episode runs end to end through the real processes to its step
/// budget, scoring each replan with Fisher information (at least one chosen Fisher path), and a
/// second run of the same flow takes the same actions and makes the same decisions.
#[test]
fn fisher_episode_runs_to_its_budget_and_repeats_exactly() {
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let first = run_episode(a.path());
    assert!(
        first.episode.contains("max_steps"),
        "the episode must run to its budget: {} after {} steps",
        first.episode,
        first.steps
    );
    let steps: Vec<u64> = first.actions.iter().map(|(k, _)| *k).collect();
    assert_eq!(steps, (0..STEPS).collect::<Vec<_>>(), "one action per step");
    assert!(
        first.actions.iter().all(|(_, a)| *a != ActionKind::Stop),
        "the planner never ends a fisher episode"
    );
    assert!(!first.reports.is_empty(), "no replan was reported");
    assert!(
        first
            .reports
            .iter()
            .any(|r| r.chosen >= 0 && r.fallback.is_none() && !r.candidates.is_empty()),
        "no replan chose a Fisher path"
    );
    for r in &first.reports {
        if r.chosen >= 0 {
            let p = &r.paths[r.chosen as usize];
            assert!(
                p.objective.is_finite(),
                "frame {}: chosen {p:?}",
                r.frame_id
            );
            assert_eq!(p.eig.len(), p.scored_steps.len());
            assert_eq!(p.c_local.len(), p.scored_steps.len());
        }
    }

    let second = run_episode(b.path());
    assert_eq!(
        first.actions, second.actions,
        "two runs of the same seeded flow took different actions"
    );
    let decisions = |e: &Episode| -> Vec<(u64, bool, i32, usize, Option<String>)> {
        e.reports
            .iter()
            .map(|r| {
                (
                    r.frame_id,
                    r.refine,
                    r.chosen,
                    r.candidates.len(),
                    r.fallback.clone(),
                )
            })
            .collect()
    };
    assert_eq!(decisions(&first), decisions(&second));
}
