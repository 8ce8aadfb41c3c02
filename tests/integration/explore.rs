//! Issue 6 end to end: the reference exploration loop (`dataflow.yaml`: sim → tracker → mapper →
//! occupancy → frontier → planner (FBE) → scorer → follower → sim) on a small procedural house at
//! low resolution, as real processes with ESTIMATED poses. Checks that the episode ends by itself
//! (no reachable frontier left, or the step budget), that the run folder holds every result file,
//! and the coverage and tracking accuracy the evaluator measured.

use std::time::Duration;

use super::harness;
use activemap_eval::{RunFolder, Summary};

/// The reference dataflow with a smaller house, a 64×64 camera and a step budget.
fn small_flow(max_steps: u64) -> String {
    harness::small_house_flow("dataflow.yaml", max_steps, &[])
}

/// Runs the small episode and returns the run folder (kept alive by the returned tempdir).
fn run_episode(max_steps: u64) -> (tempfile::TempDir, std::path::PathBuf, Summary) {
    let tmp = tempfile::tempdir().unwrap();
    let flow = tmp.path().join("explore.yaml");
    std::fs::write(&flow, small_flow(max_steps)).unwrap();
    let out = tmp.path().join("run");
    let done = harness::run(
        &[
            "run",
            flow.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--eval-views",
            "20",
        ],
        tmp.path(),
        Duration::from_secs(600),
    );
    assert!(done.status.success(), "run failed:\n{}", done.stderr);
    for file in [
        RunFolder::TRAJECTORY_EST,
        RunFolder::TRAJECTORY_TRUE,
        RunFolder::MAP,
        RunFolder::BEV,
        RunFolder::COVERAGE,
        RunFolder::SUMMARY,
        RunFolder::RECORDING,
        RunFolder::METRICS_JSON,
        RunFolder::REPORT,
    ] {
        assert!(
            out.join(file).exists(),
            "{file} missing; stderr:\n{}",
            done.stderr
        );
    }
    let summary = RunFolder::new(&out).read_summary().unwrap();
    eprintln!("explore summary: {summary:?}");
    (tmp, out, summary)
}

/// The whole loop runs as processes with estimated poses, ends by itself, and leaves every
/// result file, the metrics and the report.
#[test]
fn fbe_episode_runs_end_to_end_and_leaves_a_report() {
    let (_tmp, out, summary) = run_episode(120);
    let steps = summary.steps;
    assert!(steps > 50, "the loop stopped early: {summary:?}");
    assert_eq!(summary.scene.as_deref(), Some("house:3"));
    let metrics = RunFolder::new(&out).read_metrics().unwrap().unwrap();
    assert!(metrics.test_views == 20, "metrics.json: {metrics:?}");
    // A healthy episode raises no validity warning (issue 16): the start sees the house, the
    // robot moves, the map is not empty, no test view is empty.
    assert!(
        summary.is_valid(),
        "summary warnings: {:?}",
        summary.warnings
    );
    assert!(
        metrics.is_valid(),
        "metrics warnings: {:?}",
        metrics.warnings
    );
}

/// Issue 6's target: a short episode on a small house at 64×64 reaches 80 % coverage and ends
/// by itself (no reachable frontier left) well within the step budget, so the robot did not
/// spend it in a collision-stuck loop; it travels, tracking stays accurate, and few forward
/// moves are blocked. Measured 2026-12-01: 100 % coverage, ended at step 336 of 400, 7.2 m
/// travelled, ATE 0.95 cm, 2 of 147 forward moves blocked, about 40–80 s in the test profile.
#[test]
fn fbe_episode_reaches_80_percent_coverage() {
    let (_tmp, _out, summary) = run_episode(400);
    let coverage = summary.coverage.unwrap();
    assert!(
        coverage >= 0.8,
        "coverage {coverage} below the issue's 80 %: {summary:?}"
    );
    let episode = summary.episode.as_str();
    assert!(
        episode.contains("no reachable frontier left"),
        "the episode did not end by itself: {summary:?}"
    );
    assert!(summary.steps < 400, "the step budget ran out: {summary:?}");
    assert!(
        summary.path_length_m > 3.0,
        "the robot hardly moved: {summary:?}"
    );
    let ate_m = summary.ate_m.unwrap();
    assert!(ate_m < 0.05, "ATE {ate_m} m: {summary:?}");
    // The evaluator counts forward moves that did not move the robot (it drove into
    // something): a few may happen where the map lags, a loop of them may not.
    let forwards = summary.forward_actions;
    let blocked = summary.blocked_forwards;
    assert!(forwards > 50, "too few forward moves: {summary:?}");
    assert!(
        blocked * 20 <= forwards,
        "{blocked} of {forwards} forward moves blocked: {summary:?}"
    );
}
