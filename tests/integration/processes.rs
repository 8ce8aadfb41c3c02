//! Flows of real processes: shared-memory frames, record → replay, kill -9 recovery (the killed
//! node holds iceoryx2 resources, which the next run must clean up), a signal during the
//! end-of-run evaluation.

use std::path::PathBuf;
use std::time::Duration;

use activemap_runtime::record::{RecordedMessage, Recording, read_recording};
use activemap_schemas::{Counter, SmallMessage};

use super::harness::{follow, kill9, pids_with, root, run, spawn, wait};

/// Runs the dataflow file `flow` (relative to the repository root) into a fresh run folder and
/// reads its recording back; returns the tempdir (keeps the folder alive), the recording's
/// path and the recording.
fn run_recorded(flow: &str) -> (tempfile::TempDir, PathBuf, Recording) {
    let tmp = tempfile::tempdir().unwrap();
    let out_dir = tmp.path().join("run");
    let out = run(
        &["run", flow, "--out", out_dir.to_str().unwrap()],
        &root(),
        Duration::from_secs(120),
    );
    assert!(out.status.success(), "run failed:\n{}", out.stderr);
    let path = out_dir.join("recording.mcap");
    let rec = read_recording(&path).unwrap();
    (tmp, path, rec)
}

/// The non-empty payloads recorded on `topic`.
fn payloads<'a>(rec: &'a Recording, topic: &str) -> Vec<&'a RecordedMessage> {
    rec.messages
        .iter()
        .filter(|m| m.topic == topic && !m.bytes.is_empty())
        .collect()
}

fn counters(rec: &Recording, topic: &str) -> Vec<Counter> {
    payloads(rec, topic)
        .iter()
        .map(|m| Counter::decode(&m.bytes).expect("counter"))
        .collect()
}

#[test]
fn rgbd_800x800_crosses_processes_bit_exact_through_shared_memory() {
    let (_tmp, _, rec) = run_recorded("tests/data/dataflows/good/frames.yaml");
    assert!(!rec.truncated);
    // The checker process recomputed every pixel independently and compared bit for bit.
    let reports = counters(&rec, "checker/report");
    assert_eq!(reports.len(), 5, "{reports:?}");
    for (i, r) in reports.iter().enumerate() {
        assert_eq!(r.seq, i as u64 + 1);
        assert_eq!(r.value, 1, "frame {} differed; see checker log", r.seq);
    }
    // The recorder read the same shared-memory frames.
    let frames = payloads(&rec, "camera/frame");
    assert_eq!(frames.len(), 5);
    assert_eq!(frames[0].bytes.len(), 64 + 800 * 800 * 3 + 800 * 800 * 4);
}

/// The recorder stores a large payload that repeats the previous one of its topic but for its
/// header as a delta, and the recording still gives every frame back bit for bit (independent
/// truth: the pattern functions the source wrote with).
#[test]
fn repeated_frames_are_recorded_as_deltas_and_read_back_bit_exact() {
    use activemap_operators::testing::frame_source::{
        pattern_depth, pattern_header, pattern_of, pattern_rgb,
    };
    use activemap_schemas::RgbdFrameView;
    let (_tmp, path, rec) = run_recorded("tests/data/dataflows/good/frames_repeated.yaml");
    assert!(!rec.truncated);
    let frames = payloads(&rec, "camera/frame");
    assert_eq!(frames.len(), 6);
    for (k, m) in frames.iter().enumerate() {
        let id = k as u64 + 1;
        let view = RgbdFrameView::parse(&m.bytes).unwrap();
        assert_eq!(view.header, pattern_header(id, 800));
        let p = pattern_of(id, 3);
        assert!(
            view.rgb
                .iter()
                .enumerate()
                .all(|(i, v)| *v == pattern_rgb(p, i))
        );
        assert!(
            view.depth()
                .iter()
                .enumerate()
                .all(|(i, d)| d.to_bits() == pattern_depth(p, i).to_bits())
        );
    }
    // Two patterns in full (4.48 MB each), four repeats as small deltas, all in zstd chunks:
    // less than the two full frames, and far less than the six.
    let payload = 6 * frames[0].bytes.len() as u64;
    let size = std::fs::metadata(&path).unwrap().len();
    assert!(
        size < 2 * frames[0].bytes.len() as u64 && size < payload / 4,
        "recording of {size} bytes for {payload} bytes of frames"
    );
}

#[test]
fn record_then_replay_reproduces_every_output() {
    let (_tmp, rec_path, rec) = run_recorded("tests/data/dataflows/good/counter.yaml");
    // Independent truth: the source sends 1..=20, the doubler (factor 3) answers 3·v, nothing lost.
    let sent: Vec<i64> = counters(&rec, "source/count")
        .iter()
        .map(|c| c.value)
        .collect();
    assert_eq!(sent, (1..=20).collect::<Vec<_>>());
    let doubled: Vec<i64> = counters(&rec, "double/doubled")
        .iter()
        .map(|c| c.value)
        .collect();
    assert_eq!(doubled, (1..=20).map(|v| 3 * v).collect::<Vec<_>>());
    let out = run(
        &["replay", rec_path.to_str().unwrap(), "--node", "double"],
        &root(),
        Duration::from_secs(60),
    );
    assert!(
        out.status.success(),
        "replay failed:\n{}\n{}",
        out.stdout,
        out.stderr
    );
    assert!(
        out.stdout
            .contains("replay double: 21 inputs, 20/20 outputs matched"),
        "{}",
        out.stdout
    );
}

#[test]
fn kill_9_of_an_operator_is_reported_and_the_next_run_starts_clean() {
    let tmp = tempfile::tempdir().unwrap();
    let flow = tmp.path().join("long.yaml");
    std::fs::write(
        &flow,
        "nodes:\n  - id: camera\n    operator: frame_source\n    config: { count: 100000, size: 64 }\n    timers: { tick: 5ms }\n  - id: victim\n    operator: frame_checker\n    inputs:\n      frame: camera/frame\n",
    )
    .unwrap();
    let out_dir = tmp.path().join("run1");
    let child = spawn(
        &[
            "run",
            flow.to_str().unwrap(),
            "--out",
            out_dir.to_str().unwrap(),
        ],
        &root(),
    );
    // Wait until the victim is running and messages flow, then kill -9 it.
    let needle_dir = out_dir.to_string_lossy().to_string();
    let mut victim = None;
    for _ in 0..600 {
        let pids = pids_with(&["node", "--node victim", &needle_dir]);
        let log = std::fs::read(out_dir.join("recording.mcap"))
            .map(|b| b.len())
            .unwrap_or(0);
        if let Some(pid) = pids.first()
            && log > 4096
        {
            victim = Some(*pid);
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let victim = victim.expect("victim node never started");
    kill9(victim);
    let out = wait(child, Duration::from_secs(60), "run with a killed node");
    assert!(!out.status.success());
    assert!(
        out.stderr
            .contains("node `victim` crashed: killed by signal 9 (SIGKILL)"),
        "stderr:\n{}",
        out.stderr
    );
    // The recording written so far reads back.
    let rec = read_recording(&out_dir.join("recording.mcap")).unwrap();
    assert!(!counters(&rec, "victim/report").is_empty());
    assert!(rec.messages.iter().any(|m| m.topic == "camera/frame"));
    // No process of the run is left, and a second run starts and finishes cleanly.
    assert!(
        pids_with(&["node", &needle_dir]).is_empty(),
        "leftover node processes"
    );
    let out2 = tmp.path().join("run2");
    let out = run(
        &[
            "run",
            "tests/data/dataflows/good/frames.yaml",
            "--out",
            out2.to_str().unwrap(),
        ],
        &root(),
        Duration::from_secs(120),
    );
    assert!(out.status.success(), "second run failed:\n{}", out.stderr);
}

/// A SIGTERM during the end-of-run evaluation ends `activemap run` at once (exit 130) with
/// the run folder complete and unevaluated (no `metrics.json`), instead of being held until
/// the evaluation ends (an hour at the paper's profile).
#[test]
fn a_signal_during_the_evaluation_ends_the_run_with_its_folder_intact() {
    let tmp = tempfile::tempdir().unwrap();
    let flow = tmp.path().join("small.yaml");
    std::fs::write(
        &flow,
        super::harness::small_house_flow("dataflow.yaml", 10, &[]),
    )
    .unwrap();
    let out_dir = tmp.path().join("run");
    let child = spawn(
        &[
            "run",
            flow.to_str().unwrap(),
            "--out",
            out_dir.to_str().unwrap(),
            "--no-record",
            // Long enough that the signal lands inside it.
            "--eval-views",
            "200000",
        ],
        &root(),
    );
    let (child, evaluating) = follow(child, Some("evaluating the run"));
    evaluating
        .recv_timeout(Duration::from_secs(120))
        .expect("the run never reached its evaluation");
    std::thread::sleep(Duration::from_millis(500));
    // SAFETY: kill(2) on our own child.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGTERM) }, 0);
    // Killed and failed if it goes on (it would hold a core for an hour).
    let out = child.finish(Duration::from_secs(30), "the evaluation after SIGTERM");
    let stderr = out.stderr;
    assert_eq!(out.status.code(), Some(130), "stderr:\n{stderr}");
    assert!(
        stderr.contains("evaluation stopped by signal") && stderr.contains("activemap eval"),
        "stderr:\n{stderr}"
    );
    let folder = activemap_eval::RunFolder::new(&out_dir);
    assert!(folder.has_summary(), "the run's own files are kept");
    assert!(
        !out_dir
            .join(activemap_eval::RunFolder::METRICS_JSON)
            .exists()
    );
}
