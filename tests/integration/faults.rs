//! Issue 18, faults: `kill -9` of each operator of the exploration loop in turn, at a seeded
//! step, on the small house: the run ends (no hang) with an error naming the node and how it
//! died, leaves no process behind, its recording reads back up to the crash, and the next run
//! starts clean. The `restart: { on-failure: N }` policy of a stateless node: a killed node
//! comes back while restarts remain, and the run fails once they are used up. And a full disk
//! while recording: the run stops with an error naming the file, which reads back.

use std::io::{BufRead, BufReader, Read};
use std::path::Path;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use activemap_runtime::record::read_recording;

use super::harness::{self, kill9, pids_with, root, run, spawn};

/// Every node of `dataflow.yaml`.
const LOOP_NODES: [&str; 9] = [
    "sim",
    "tracker",
    "mapper",
    "occupancy",
    "frontier",
    "planner",
    "scorer",
    "follower",
    "evaluator",
];

/// The step of each kill: a seeded draw in {10, 15, 20, 25} (the pipe progress lines come
/// every 5 % of a 100-step budget).
fn kill_steps(seed: u64) -> Vec<u64> {
    let mut state = seed;
    LOOP_NODES
        .iter()
        .map(|_| {
            // SplitMix64.
            state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            10 + 5 * ((z ^ (z >> 31)) % 4)
        })
        .collect()
}

/// Follows a child's stderr on a thread: every line goes to the channel and into the returned
/// text.
fn follow_stderr(
    child: &mut std::process::Child,
) -> (mpsc::Receiver<String>, std::thread::JoinHandle<String>) {
    let stderr = child.stderr.take().expect("piped");
    let (tx, rx) = mpsc::channel();
    let all = std::thread::spawn(move || {
        let mut all = String::new();
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = tx.send(line.clone());
            all.push_str(&line);
            all.push('\n');
        }
        all
    });
    let mut stdout = child.stdout.take().expect("piped");
    std::thread::spawn(move || {
        let mut s = String::new();
        let _ = stdout.read_to_string(&mut s);
    });
    (rx, all)
}

/// The step of a progress line (`activemap: step 15/100 (15%) ...`).
fn progress_step(line: &str) -> Option<u64> {
    let rest = line.split("step ").nth(1)?;
    rest.split('/').next()?.trim().parse().ok()
}

fn wait_exit(child: &mut std::process::Child, timeout: Duration) -> std::process::ExitStatus {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(s) = child.try_wait().unwrap() {
            return s;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("the run did not end within {timeout:?} after the kill (a hang)");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Starts `activemap run FLOW --out OUT_DIR --no-eval` and returns once its progress reports
/// step `at`: the child, its whole stderr (when it ends), and the 180 s deadline the wait ran
/// under. `what` names the case in the failure message.
fn run_until_step(
    flow: &Path,
    out_dir: &Path,
    at: u64,
    what: &str,
) -> (
    std::process::Child,
    std::thread::JoinHandle<String>,
    Instant,
) {
    let mut child = spawn(
        &[
            "run",
            flow.to_str().unwrap(),
            "--out",
            out_dir.to_str().unwrap(),
            "--no-eval",
        ],
        &root(),
    );
    let (lines, all) = follow_stderr(&mut child);
    let deadline = Instant::now() + Duration::from_secs(180);
    loop {
        let line = lines
            .recv_timeout(deadline.saturating_duration_since(Instant::now()))
            .unwrap_or_else(|_| panic!("{what}: the run never reached step {at}"));
        if progress_step(&line).is_some_and(|s| s >= at) {
            return (child, all, deadline);
        }
    }
}

/// Runs the small loop, kills `node` with SIGKILL once the run reports step `at`, and checks
/// the aftermath.
fn kill_one(tmp: &Path, flow: &Path, node: &str, at: u64) {
    let out_dir = tmp.join(format!("run-{node}"));
    let (mut child, all, _) = run_until_step(flow, &out_dir, at, node);
    let dir = out_dir.to_string_lossy().to_string();
    let pids = pids_with(&["node", &format!("--node {node} "), &dir]);
    let pids = if pids.is_empty() {
        pids_with(&["node", &format!("--node {node}"), &dir])
    } else {
        pids
    };
    assert_eq!(pids.len(), 1, "{node}: processes {pids:?}");
    kill9(pids[0]);
    let status = wait_exit(&mut child, Duration::from_secs(60));
    let stderr = all.join().unwrap();
    assert!(!status.success(), "{node}: the run succeeded after a kill");
    assert!(
        stderr.contains(&format!(
            "node `{node}` crashed: killed by signal 9 (SIGKILL)"
        )),
        "{node}: stderr:\n{stderr}"
    );
    assert!(
        pids_with(&["node", &dir]).is_empty(),
        "{node}: processes of the run were left behind"
    );
    // The recording reads back up to the crash: frames, and poses of at least `at` steps.
    let rec = read_recording(&out_dir.join("recording.mcap"))
        .unwrap_or_else(|e| panic!("{node}: recording unreadable: {e}"));
    let frames = rec
        .messages
        .iter()
        .filter(|m| m.topic == "sim/rgbd")
        .count() as u64;
    assert!(
        frames >= at,
        "{node}: {frames} frames recorded, killed at step {at}"
    );
}

/// Each operator of the loop killed in turn at a seeded step.
#[test]
fn kill_9_of_each_loop_operator_is_reported_and_the_next_run_starts_clean() {
    let tmp = tempfile::tempdir().unwrap();
    let flow = tmp.path().join("loop.yaml");
    std::fs::write(&flow, harness::small_house_flow("dataflow.yaml", 100, &[])).unwrap();
    let steps = kill_steps(18);
    for (node, at) in LOOP_NODES.iter().zip(steps) {
        eprintln!("killing `{node}` at step {at}");
        kill_one(tmp.path(), &flow, node, at);
    }
    // A run after all that starts and finishes.
    let out = tmp.path().join("after");
    let done = run(
        &[
            "run",
            flow.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--max-steps",
            "15",
            "--no-eval",
        ],
        &root(),
        Duration::from_secs(180),
    );
    assert!(
        done.status.success(),
        "the run after the kills failed:\n{}",
        done.stderr
    );
}

/// `restart: { on-failure: 1 }` on a stateless node: killed once, it is restarted and the run
/// goes on to its end; killed again, the run fails naming it.
#[test]
fn a_stateless_node_restarts_on_failure_until_its_limit() {
    let tmp = tempfile::tempdir().unwrap();
    let flow = tmp.path().join("restart.yaml");
    std::fs::write(
        &flow,
        "nodes:\n  - id: source\n    operator: counter_source\n    config: { count: 400 }\n    timers: { tick: 20ms }\n  - id: double\n    operator: doubler\n    restart: { on-failure: 1 }\n    inputs:\n      value: { source: source/count, queue_size: 64, drop: block }\n",
    )
    .unwrap();
    let attempt = |name: &str, kills: usize| -> (bool, String) {
        let out_dir = tmp.path().join(name);
        let mut child = spawn(
            &[
                "run",
                flow.to_str().unwrap(),
                "--out",
                out_dir.to_str().unwrap(),
            ],
            &root(),
        );
        let (_lines, all) = follow_stderr(&mut child);
        let dir = out_dir.to_string_lossy().to_string();
        let mut killed: Vec<u32> = Vec::new();
        let deadline = Instant::now() + Duration::from_secs(60);
        while killed.len() < kills {
            assert!(
                Instant::now() < deadline,
                "{name}: no new `double` process to kill"
            );
            // A fresh process (not one already killed) that has been up a moment.
            if let Some(pid) = pids_with(&["node", "--node double", &dir])
                .into_iter()
                .find(|p| !killed.contains(p))
            {
                std::thread::sleep(Duration::from_millis(500));
                kill9(pid);
                killed.push(pid);
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let status = wait_exit(&mut child, Duration::from_secs(60));
        let stderr = all.join().unwrap();
        assert!(pids_with(&["node", &dir]).is_empty(), "{name}: leftovers");
        (status.success(), stderr)
    };
    let (ok, stderr) = attempt("once", 1);
    assert!(ok, "killed once, the run failed:\n{stderr}");
    assert!(stderr.contains("restarting `double` (1/1)"), "{stderr}");
    assert!(stderr.contains("1 restarts"), "{stderr}");
    let (ok, stderr) = attempt("twice", 2);
    assert!(
        !ok,
        "killed twice with one restart allowed, the run succeeded"
    );
    assert!(
        stderr.contains("node `double` crashed: killed by signal 9 (SIGKILL)"),
        "{stderr}"
    );
}

/// Caps the size of any file process `pid` writes at `bytes` (prlimit(2) RLIMIT_FSIZE, soft
/// limit only): what a full disk does to the next write, for that process alone.
fn limit_file_size(pid: u32, bytes: u64) {
    let mut old = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: prlimit(2) reads and writes the two rlimit structs given.
    unsafe {
        assert_eq!(
            libc::prlimit(pid as i32, libc::RLIMIT_FSIZE, std::ptr::null(), &mut old),
            0
        );
        let new = libc::rlimit {
            rlim_cur: bytes,
            rlim_max: old.rlim_max,
        };
        assert_eq!(
            libc::prlimit(pid as i32, libc::RLIMIT_FSIZE, &new, std::ptr::null_mut()),
            0,
            "prlimit {pid}"
        );
    }
}

/// A full disk while recording: once the episode runs, the launcher (which writes the
/// recording; its nodes keep their own limits) may write no file beyond 256 KiB more than the
/// recording holds. The run stops within a bounded time with an error naming the file and the
/// cause, leaves no process behind, and the recording reads back up to the cut.
#[test]
fn a_full_disk_while_recording_stops_the_run_with_a_clear_error_and_a_readable_file() {
    let tmp = tempfile::tempdir().unwrap();
    let flow = tmp.path().join("full.yaml");
    std::fs::write(&flow, harness::small_house_flow("dataflow.yaml", 200, &[])).unwrap();
    let out_dir = tmp.path().join("run");
    let (mut child, all, deadline) = run_until_step(&flow, &out_dir, 10, "full disk");
    let path = out_dir.join("recording.mcap");
    let frames_of = |rec: &activemap_runtime::record::Recording| {
        rec.messages
            .iter()
            .filter(|m| m.topic == "sim/rgbd")
            .count()
    };
    // What the file holds once it has frames (the recorder flushes every second) must survive
    // the cut.
    let (size, before) = loop {
        let size = std::fs::metadata(&path).unwrap().len();
        let frames = frames_of(&read_recording(&path).unwrap());
        if frames > 0 {
            break (size, frames);
        }
        assert!(Instant::now() < deadline, "no frame reached the file");
        std::thread::sleep(Duration::from_millis(200));
    };
    let limit = size + 256 * 1024;
    limit_file_size(child.id(), limit);
    let status = wait_exit(&mut child, Duration::from_secs(120));
    let stderr = all.join().unwrap();
    assert!(!status.success(), "the run succeeded on a full disk");
    assert!(
        stderr.contains(&format!("recording {}", path.display()))
            && stderr.contains("the disk is full or a file-size limit was reached")
            && stderr.contains("the run was stopped"),
        "stderr:\n{stderr}"
    );
    let dir = out_dir.to_string_lossy().to_string();
    assert!(
        pids_with(&["node", &dir]).is_empty(),
        "processes of the run were left behind"
    );
    assert!(std::fs::metadata(&path).unwrap().len() <= limit);
    let rec = read_recording(&path).expect("the recording reads back");
    assert!(rec.truncated, "a cut recording must say so");
    let after = frames_of(&rec);
    assert!(
        after >= before,
        "{after} frames read back, {before} were on disk before the disk filled"
    );
}
