//! Issue 4: the Python bridge client (`sim-bridge/python/activemap_sim_client.py`) takes the `sim`
//! node's place as an external `path:` node and drives the exploration loop in lockstep over
//! Zenoh: python sim → tracker → mapper → occupancy → frontier → planner → scorer → follower →
//! python sim. The test installs the pinned `eclipse-zenoh` into a venv under the target dir.

use std::path::{Path, PathBuf};
use std::time::Duration;

use super::harness;
use activemap_eval::RunFolder;

/// The Python package, pinned to the version of the Rust `zenoh` crate in Cargo.lock (1.10.2).
const ZENOH_PACKAGE: &str = "eclipse-zenoh==1.10.2";
/// Lockstep steps of the episode.
const STEPS: u64 = 20;

/// A venv with the pinned Zenoh package (see [`harness::python_venv`]).
fn python_with_zenoh() -> Option<PathBuf> {
    harness::python_venv(
        "python-bridge-venv",
        "import importlib.metadata as m, sys; sys.exit(m.version('eclipse-zenoh') != '1.10.2')",
        &[ZENOH_PACKAGE],
    )
}

/// The reference loop with the Python client as `sim` (no evaluator: the box room has no
/// ground-truth scene for it), with the `realistic` sensor and actuation noise (seeded).
fn bridge_flow(python: &Path, log: &Path) -> String {
    let client = harness::root().join("sim-bridge/python/activemap_sim_client.py");
    let reference =
        std::fs::read_to_string(harness::root().join("dataflow.yaml")).expect("read dataflow.yaml");
    // Keep the built-in stages between `tracker` and the evaluation node.
    let start = reference.find("  - id: tracker").expect("tracker node");
    let end = reference
        .find("  # Evaluation only")
        .expect("evaluator node");
    format!(
        "nodes:
  - id: sim
    path: \"{}\"
    args: [\"{}\"]
    config: {{ scene: box, width: 64, height: 64, hfov_deg: 90, max_steps: {STEPS}, seed: 3, noise: realistic, log: \"{}\" }}
    outputs:
      - {{ id: rgbd, type: RgbdFrame }}
      - {{ id: true_pose, type: TruePose }}
      - {{ id: episode, type: EpisodeStatus }}
    inputs:
      action: {{ source: follower/action, drop: block }}

{}",
        python.display(),
        client.display(),
        log.display(),
        &reference[start..end]
    )
}

#[test]
fn python_client_drives_the_loop_in_lockstep() {
    let Some(python) = python_with_zenoh() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let log = tmp.path().join("client.jsonl");
    let flow = tmp.path().join("bridge.yaml");
    std::fs::write(&flow, bridge_flow(&python, &log)).unwrap();
    let out = tmp.path().join("run");
    let done = harness::run(
        &[
            "run",
            flow.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--no-record",
        ],
        tmp.path(),
        Duration::from_secs(300),
    );
    let client_err = std::fs::read_to_string(out.join("logs/sim.stderr.log")).unwrap_or_default();
    assert!(
        done.status.success(),
        "run failed:\n{}\n--- python client stderr ---\n{client_err}",
        done.stderr
    );
    // Every node, the Python one included, ended by itself.
    for node in [
        "sim",
        "tracker",
        "mapper",
        "occupancy",
        "frontier",
        "planner",
        "scorer",
        "follower",
    ] {
        let line = done
            .stderr
            .lines()
            .find(|l| l.trim_start().starts_with(&format!("{node} ")))
            .unwrap_or_else(|| panic!("no exit line for `{node}`:\n{}", done.stderr));
        assert!(line.contains("finished"), "{line}\n{}", done.stderr);
    }
    assert!(
        client_err.contains("episode over: max_steps reached"),
        "{client_err}"
    );

    // The client's log: frame k, then the action answering frame k, then frame k + 1, ...
    let records: Vec<serde_json::Value> = std::fs::read_to_string(&log)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let frames: Vec<u64> = records
        .iter()
        .filter(|r| r["event"] == "frame")
        .map(|r| r["id"].as_u64().unwrap())
        .collect();
    let actions: Vec<u64> = records
        .iter()
        .filter(|r| r["event"] == "action")
        .map(|r| r["step"].as_u64().unwrap())
        .collect();
    assert_eq!(frames, (0..=STEPS).collect::<Vec<_>>(), "{records:?}");
    assert_eq!(actions, (0..STEPS).collect::<Vec<_>>(), "{records:?}");
    for (i, r) in records.iter().enumerate() {
        let expected = if i % 2 == 0 { "frame" } else { "action" };
        assert_eq!(
            r["event"], expected,
            "record {i} out of lockstep: {records:?}"
        );
    }
    assert_eq!(records.last().unwrap()["state"], "finished");
    // The tracker consumed every frame over Zenoh (its operator ran once per input at least).
    let timings = RunFolder::new(&out)
        .read_timings()
        .unwrap()
        .unwrap_or_default();
    let tracker_calls: u64 = timings
        .iter()
        .find(|t| t.stage == "tracker")
        .map(|t| t.calls)
        .unwrap_or_else(|| panic!("no tracker row in timings.csv: {timings:?}"));
    assert!(
        tracker_calls > STEPS,
        "tracker ran {tracker_calls} times for {} frames",
        STEPS + 1
    );
}
