//! Process helpers with timeouts.

use std::io::{BufRead as _, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};

/// The `activemap` binary under test.
pub fn exe() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_activemap"))
}

/// The repository root.
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The repository's dataflow `file` made small for a test: the sim and evaluator on a small
/// procedural house (`house:3`, 2 rooms, 30 m²), a 64×64 camera and `max_steps`; each line
/// that contains a needle of `more` is replaced by its line. Fails when a rewrite found no line.
pub fn small_house_flow(file: &str, max_steps: u64, more: &[(&str, &str)]) -> String {
    let text =
        std::fs::read_to_string(root().join(file)).unwrap_or_else(|e| panic!("read {file}: {e}"));
    let scene = r#"scene: "house:3", max_rooms: 2, max_area: 30"#;
    let sim = format!(
        r#"    config: {{ {scene}, width: 64, height: 64, hfov_deg: 90, lockstep: true, max_steps: {max_steps} }}"#
    );
    let out: Vec<String> = text
        .lines()
        .map(|l| {
            if l.contains("config: { scene: \"house:7\", width") {
                sim.clone()
            } else if l.contains("config: { scene: \"house:7\" }") {
                format!("    config: {{ {scene} }}")
            } else if let Some((_, line)) = more.iter().find(|(needle, _)| l.contains(needle)) {
                line.to_string()
            } else {
                l.to_string()
            }
        })
        .collect();
    let joined = out.join("\n");
    assert_eq!(
        joined.matches("house:3").count(),
        2,
        "the test must rewrite both scene lines of {file}"
    );
    for (needle, line) in more {
        assert!(joined.contains(line), "no line of {file} holds `{needle}`");
    }
    joined
}

/// Output of a finished process.
pub struct Finished {
    pub status: ExitStatus,
    pub stdout: String,
    pub stderr: String,
}

/// Start `activemap args...` with piped output.
pub fn spawn(args: &[&str], cwd: &Path) -> Child {
    spawn_env(args, cwd, &[])
}

/// Start `activemap args...` with piped output and the variables `env` set for it (and its
/// node processes) only. The process gets SIGTERM when the test's thread ends, so a test that
/// panics leaves no daemon behind (an `activemap up` that outlived its test held `.ci/run`'s
/// build lock through an inherited descriptor).
pub fn spawn_env(args: &[&str], cwd: &Path, env: &[(&str, &str)]) -> Child {
    let mut command = Command::new(exe());
    die_with_test_thread(&mut command);
    command
        .args(args)
        // No LPIPS download from the tests: absent weights stay "missing" (a test may override).
        .env("ACTIVEMAP_LPIPS_FETCH", "0")
        .envs(env.iter().copied())
        .current_dir(cwd)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start activemap")
}

/// SIGTERM to the child when the thread that started it ends (`PR_SET_PDEATHSIG` follows the
/// spawning thread: each test runs on its own).
fn die_with_test_thread(command: &mut Command) {
    use std::os::unix::process::CommandExt as _;
    // SAFETY: prctl is async-signal-safe and touches no memory of the parent.
    unsafe {
        command.pre_exec(|| {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
}

/// A child whose output is drained on threads (a chatty child never blocks on a full pipe),
/// its stderr read line by line as it comes ([`follow`]).
pub struct Followed {
    child: Child,
    stdout: std::thread::JoinHandle<String>,
    stderr: std::thread::JoinHandle<String>,
}

/// Follows `child`'s output: every stderr line that contains `needle` is sent, as it is read,
/// on the returned receiver (nothing is sent for `None`).
pub fn follow(mut child: Child, needle: Option<&str>) -> (Followed, Receiver<String>) {
    let mut out = child.stdout.take().expect("piped");
    let err = child.stderr.take().expect("piped");
    let needle = needle.map(str::to_string);
    let (tx, rx) = std::sync::mpsc::channel();
    let stdout = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = out.read_to_string(&mut s);
        s
    });
    let stderr = std::thread::spawn(move || {
        let mut all = String::new();
        for line in BufReader::new(err).lines().map_while(Result::ok) {
            if needle.as_deref().is_some_and(|n| line.contains(n)) {
                let _ = tx.send(line.clone());
            }
            all.push_str(&line);
            all.push('\n');
        }
        all
    });
    (
        Followed {
            child,
            stdout,
            stderr,
        },
        rx,
    )
}

impl Followed {
    /// The child's process id.
    pub fn id(&self) -> u32 {
        self.child.id()
    }

    /// Waits for the child at most `timeout`; kills it and panics on timeout.
    pub fn finish(mut self, timeout: Duration, what: &str) -> Finished {
        let deadline = Instant::now() + timeout;
        let status = loop {
            if let Some(status) = self.child.try_wait().expect("try_wait") {
                break status;
            }
            if Instant::now() > deadline {
                let _ = self.child.kill();
                let _ = self.child.wait();
                let stderr = self.stderr.join().unwrap_or_default();
                panic!("{what}: timed out after {timeout:?}; stderr:\n{stderr}");
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        Finished {
            status,
            stdout: self.stdout.join().unwrap_or_default(),
            stderr: self.stderr.join().unwrap_or_default(),
        }
    }
}

/// Wait for `child` at most `timeout`; kill it and panic on timeout.
pub fn wait(child: Child, timeout: Duration, what: &str) -> Finished {
    follow(child, None).0.finish(timeout, what)
}

/// Run `activemap args...` to completion under a timeout.
pub fn run(args: &[&str], cwd: &Path, timeout: Duration) -> Finished {
    run_env(args, cwd, &[], timeout)
}

/// [`run`] with the variables `env` set for the process.
pub fn run_env(args: &[&str], cwd: &Path, env: &[(&str, &str)], timeout: Duration) -> Finished {
    let what = format!("activemap {}", args.join(" "));
    wait(spawn_env(args, cwd, env), timeout, &what)
}

/// Pids of processes whose command line contains every one of `needles`.
pub fn pids_with(needles: &[&str]) -> Vec<u32> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir("/proc").into_iter().flatten().flatten() {
        let Ok(pid) = entry.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let Ok(cmd) = std::fs::read(entry.path().join("cmdline")) else {
            continue;
        };
        let cmd = String::from_utf8_lossy(&cmd).replace('\0', " ");
        if needles.iter().all(|n| cmd.contains(n)) {
            out.push(pid);
        }
    }
    out
}

/// A venv named `name` next to the test binary with `packages` installed (pip), created or
/// reused; `installed` is a Python snippet that exits 0 when the pinned versions are already
/// there. `None` when there is no `python3`; a failing `venv` or `pip` fails the test with its
/// output.
pub fn python_venv(name: &str, installed: &str, packages: &[&str]) -> Option<PathBuf> {
    if !Command::new("python3")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success())
    {
        eprintln!("skipping {name}: python3 is not available");
        return None;
    }
    let target = exe()
        .parent()
        .and_then(Path::parent)
        .expect("the binary lives in <target>/<profile>/")
        .to_path_buf();
    let venv = target.join(name);
    let python = venv.join("bin").join("python");
    let run = |cmd: &mut Command, what: &str| {
        let out = cmd.output().unwrap_or_else(|e| panic!("{what}: {e}"));
        assert!(
            out.status.success(),
            "{what} failed:\n{}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    };
    if !python.exists() {
        run(
            Command::new("python3").args(["-m", "venv"]).arg(&venv),
            "python3 -m venv",
        );
    }
    let pinned = Command::new(&python)
        .args(["-c", installed])
        .output()
        .is_ok_and(|o| o.status.success());
    if !pinned {
        run(
            Command::new(&python)
                .args(["-m", "pip", "install", "--disable-pip-version-check"])
                .args(packages),
            &format!("pip install {}", packages.join(" ")),
        );
    }
    Some(python)
}

/// Send SIGKILL to `pid` (a process found with [`pids_with`]).
pub fn kill9(pid: u32) {
    // SAFETY: kill(2) on a pid found in /proc.
    assert_eq!(
        unsafe { libc::kill(pid as i32, libc::SIGKILL) },
        0,
        "kill {pid}"
    );
}
