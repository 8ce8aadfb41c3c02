//! Episodes run for a remote client (`activemap bench results --connect`): a daemon with free
//! slots (`activemap up --slots N`) takes a whole exploration episode, runs it as
//! `activemap run FLOW --out DIR` on its own machine, and serves the episode folder's files back,
//! all over the daemon network's Zenoh session (no shared file system).
//!
//! Verbs (under `activemap/daemon/<machine>/`):
//! - `episodes`: the board (slots and every episode with its state), JSON [`EpisodeBoard`];
//! - `episode`: start one ([`EpisodeRequest`]); refused when every slot is busy;
//! - `episode_cancel`: stop one (SIGTERM to its launcher, which stops its nodes cleanly);
//! - `episode_files` / `episode_read`: list an ended episode's files, read one in chunks;
//! - `scene_have` / `scene_put`: the content-addressed scene store (SHA-256 of the file), so that
//!   a scene file named by a suite travels to the daemon once and is checked by its hash.
//!
//! The episode runs in a child process started with `PR_SET_PDEATHSIG`: a daemon that dies takes
//! its episodes down with it rather than leaving them running unsupervised.

use std::collections::BTreeMap;
use std::io::{Read as _, Seek as _, SeekFrom, Write as _};
use std::path::{Component, Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};
use sha2::{Digest as _, Sha256};

use activemap_runtime::OperatorDescriptor;
use activemap_runtime::RuntimeError;
use activemap_runtime::daemon::{DaemonClient, DaemonOptions, DaemonService, no_answer};
use activemap_runtime::dataflow::Dataflow;

/// Largest chunk of a file read or uploaded in one request (bytes).
pub const CHUNK_BYTES: u64 = 4 << 20;
/// The episode's dataflow, as written in its folder.
pub const EPISODE_FLOW: &str = "cell_dataflow.yaml";
/// The output of the episode's `activemap run`, in its folder.
pub const EPISODE_LOG: &str = "bench.log";
/// The recording of an episode, sent back only when asked.
const RECORDING: &str = "recording.mcap";

/// An episode for a daemon to run.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EpisodeRequest {
    /// Client-chosen id, unique on the daemon: ASCII letters, digits, `-`, `_`.
    pub job_id: String,
    /// What the episode is, for the daemon's log (e.g. `fbe/house:1/seed 1`).
    pub label: String,
    /// The dataflow text (every file it names must exist on the daemon's machine).
    pub flow: String,
    /// Step budget (`--max-steps`).
    pub max_steps: u64,
    /// Test views of the evaluation (`--eval-views`).
    pub eval_views: usize,
    /// Keep the recording (`recording.mcap`).
    pub record: bool,
}

/// Where an episode is.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum EpisodeState {
    /// Its `activemap run` is running.
    Running,
    /// Its `activemap run` exited with success.
    Succeeded,
    /// It could not start or its `activemap run` failed: why.
    Failed(String),
}

/// One episode on a daemon's board.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EpisodeEntry {
    /// The client's id.
    pub job_id: String,
    /// The client's label.
    pub label: String,
    /// Its state.
    pub state: EpisodeState,
    /// Seconds since it started (running) or that its `activemap run` took (ended).
    pub seconds: f64,
}

/// A daemon's episodes and how many it runs at once.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EpisodeBoard {
    /// The daemon's machine.
    pub machine: String,
    /// Episodes it runs at once (`--slots`).
    pub slots: usize,
    /// Every episode it was given, by job id.
    pub episodes: Vec<EpisodeEntry>,
}

impl EpisodeBoard {
    /// Slots not taken by a running episode.
    pub fn free_slots(&self) -> usize {
        let running = self
            .episodes
            .iter()
            .filter(|e| e.state == EpisodeState::Running)
            .count();
        self.slots.saturating_sub(running)
    }

    /// The entry of `job_id`.
    pub fn get(&self, job_id: &str) -> Option<&EpisodeEntry> {
        self.episodes.iter().find(|e| e.job_id == job_id)
    }
}

/// A file of an ended episode's folder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeFile {
    /// Path relative to the episode folder, `/`-separated.
    pub path: String,
    /// Size in bytes.
    pub size: u64,
}

/// Which files of an episode to list.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FilesRequest {
    /// The episode.
    pub job_id: String,
    /// Include the recording.
    pub record: bool,
}

/// A chunk of an episode's file to read.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ReadRequest {
    /// The episode.
    pub job_id: String,
    /// The file, as listed.
    pub path: String,
    /// First byte.
    pub offset: u64,
    /// Bytes to read (at most [`CHUNK_BYTES`]).
    pub len: u64,
}

/// A scene file by content: its SHA-256 (64 lowercase hex digits) and extension.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct SceneRef {
    /// SHA-256 of the file's bytes, lowercase hex.
    pub sha256: String,
    /// Extension without the dot (`glb`, `obj`, …): loaders tell formats by it.
    pub ext: String,
}

impl SceneRef {
    /// The reference of a file on this machine (reads it whole to hash it).
    pub fn of_file(path: &Path) -> Result<Self, String> {
        let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        let r = Self {
            sha256: sha256_hex(&bytes),
            ext,
        };
        r.check()?;
        Ok(r)
    }

    /// Refuses a hash that is not 64 lowercase hex digits or an extension that is not 1–8 ASCII
    /// letters or digits: both become a file name on the daemon.
    fn check(&self) -> Result<(), String> {
        let hex = self.sha256.len() == 64
            && self
                .sha256
                .bytes()
                .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b));
        let ext = (1..=8).contains(&self.ext.len())
            && self.ext.bytes().all(|b| b.is_ascii_alphanumeric());
        if hex && ext {
            Ok(())
        } else {
            Err(format!(
                "scene reference `{}.{}`: needs a SHA-256 of 64 lowercase hex digits and an \
                 extension of 1-8 letters or digits",
                self.sha256, self.ext
            ))
        }
    }

    /// The file name in a scene store.
    fn file_name(&self) -> String {
        format!("{}.{}", self.sha256, self.ext)
    }
}

/// A chunk of a scene file uploaded to a daemon (postcard-encoded: it carries raw bytes).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ScenePut {
    /// The scene.
    pub scene: SceneRef,
    /// Size of the whole file.
    pub total: u64,
    /// Where this chunk starts; chunks come in order, from 0.
    pub offset: u64,
    /// The chunk.
    pub data: Vec<u8>,
}

/// SHA-256 of `bytes` as lowercase hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// True for a job id that can name a folder: 1–128 ASCII letters, digits, `-` or `_`.
fn valid_job_id(id: &str) -> bool {
    (1..=128).contains(&id.len())
        && id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
}

/// One episode the daemon runs or ran.
struct Episode {
    label: String,
    dir: PathBuf,
    state: Arc<Mutex<(EpisodeState, f64)>>,
    started: Instant,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

/// The daemon's side: its episodes, its slots and its scene store.
pub struct EpisodeHost {
    machine: String,
    slots: usize,
    /// Episode folders: `<runs>/episodes/<job id>`.
    root: PathBuf,
    /// Content-addressed scenes: `<runs>/scenes/<sha256>.<ext>`.
    scenes: PathBuf,
    exe: PathBuf,
    base_dir: PathBuf,
    allow_exec: Vec<PathBuf>,
    episodes: BTreeMap<String, Episode>,
}

impl EpisodeHost {
    /// A host with `slots` slots for the daemon started with `opts`, keeping its folders under
    /// its runs folder.
    pub fn new(opts: &DaemonOptions, slots: usize) -> Result<Self, RuntimeError> {
        let root = opts.runs_dir.join("episodes");
        let scenes = opts.runs_dir.join("scenes");
        for dir in [&root, &scenes] {
            std::fs::create_dir_all(dir).map_err(|e| RuntimeError::io(dir, e))?;
        }
        Ok(Self {
            machine: opts.machine.clone(),
            slots,
            root,
            scenes,
            exe: opts.exe.clone(),
            base_dir: opts.base_dir.clone(),
            allow_exec: opts.allow_exec.clone(),
            episodes: BTreeMap::new(),
        })
    }

    /// Answers one of this module's verbs; `None` when `verb` is not one of them.
    fn answer_verb(
        &mut self,
        verb: &str,
        payload: &[u8],
        catalog: &[OperatorDescriptor],
    ) -> Option<Result<Vec<u8>, String>> {
        Some(match verb {
            "episodes" => Ok(json(&self.board())),
            "episode" => parse(payload, "episode")
                .and_then(|r| self.start(r, catalog))
                .map(|e| json(&e)),
            "episode_cancel" => parse::<String>(payload, "episode_cancel").and_then(|id| {
                let e = self.episode(&id)?;
                e.stop.store(true, Ordering::SeqCst);
                Ok(b"cancelled".to_vec())
            }),
            "episode_files" => parse::<FilesRequest>(payload, "episode_files")
                .and_then(|r| self.files(&r))
                .map(|f| json(&f)),
            "episode_read" => {
                parse::<ReadRequest>(payload, "episode_read").and_then(|r| self.read(&r))
            }
            "scene_have" => parse::<SceneRef>(payload, "scene_have")
                .and_then(|s| self.scene_path(&s))
                .map(|p| json(&p)),
            "scene_put" => postcard::from_bytes::<ScenePut>(payload)
                .map_err(|e| format!("malformed scene_put request: {e}"))
                .and_then(|p| self.scene_put(p))
                .map(|p| json(&p)),
            _ => return None,
        })
    }

    /// The board.
    fn board(&self) -> EpisodeBoard {
        EpisodeBoard {
            machine: self.machine.clone(),
            slots: self.slots,
            episodes: self
                .episodes
                .iter()
                .map(|(id, e)| {
                    let (state, seconds) = e.state.lock().expect("episode state").clone();
                    let seconds = if state == EpisodeState::Running {
                        e.started.elapsed().as_secs_f64()
                    } else {
                        seconds
                    };
                    EpisodeEntry {
                        job_id: id.clone(),
                        label: e.label.clone(),
                        state,
                        seconds,
                    }
                })
                .collect(),
        }
    }

    fn episode(&self, job_id: &str) -> Result<&Episode, String> {
        self.episodes.get(job_id).ok_or_else(|| {
            format!(
                "machine `{}` has no episode `{job_id}` (was the daemon restarted?)",
                self.machine
            )
        })
    }

    /// Starts an episode in a free slot.
    fn start(
        &mut self,
        request: EpisodeRequest,
        catalog: &[OperatorDescriptor],
    ) -> Result<EpisodeEntry, String> {
        if !valid_job_id(&request.job_id) {
            return Err(format!(
                "episode id `{}` must be 1-128 ASCII letters, digits, `-` or `_`",
                request.job_id
            ));
        }
        if self.episodes.contains_key(&request.job_id) {
            return Err(format!(
                "episode `{}` already exists on machine `{}`",
                request.job_id, self.machine
            ));
        }
        if self.board().free_slots() == 0 {
            return Err(format!(
                "busy: machine `{}` runs {} episode(s) at once and all its slots are taken",
                self.machine, self.slots
            ));
        }
        let flow = Dataflow::parse(
            &request.label,
            &request.flow,
            self.base_dir.clone(),
            catalog,
        )
        .map_err(|d| d.to_string())?;
        // The episode runs every node here, whatever machine the flow names.
        let mut machines: Vec<&str> = flow.nodes.iter().map(|n| n.machine.as_str()).collect();
        machines.dedup();
        for m in machines {
            activemap_runtime::daemon::check_exec_allowed(&flow, m, &self.allow_exec)?;
        }
        let dir = self.root.join(&request.job_id);
        if dir.exists() {
            std::fs::remove_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        }
        std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        let flow_path = dir.join(EPISODE_FLOW);
        std::fs::write(&flow_path, &request.flow)
            .map_err(|e| format!("{}: {e}", flow_path.display()))?;
        let log_path = dir.join(EPISODE_LOG);
        let log =
            std::fs::File::create(&log_path).map_err(|e| format!("{}: {e}", log_path.display()))?;
        let log2 = log
            .try_clone()
            .map_err(|e| format!("{}: {e}", log_path.display()))?;
        let mut cmd = Command::new(&self.exe);
        cmd.arg("run")
            .arg(&flow_path)
            .arg("--out")
            .arg(&dir)
            .arg("--max-steps")
            .arg(request.max_steps.to_string())
            .arg("--eval-views")
            .arg(request.eval_views.to_string());
        if !request.record {
            cmd.arg("--no-record");
        }
        cmd.current_dir(&self.base_dir)
            .stdin(Stdio::null())
            .stdout(log)
            .stderr(log2);
        die_with_parent(&mut cmd);
        let state = Arc::new(Mutex::new((EpisodeState::Running, 0.0)));
        let stop = Arc::new(AtomicBool::new(false));
        let started = Instant::now();
        let thread = {
            let (state, stop) = (state.clone(), stop.clone());
            let (id, label) = (request.job_id.clone(), request.label.clone());
            let machine = self.machine.clone();
            std::thread::spawn(move || {
                let outcome = supervise(cmd, &stop, &log_path);
                let seconds = started.elapsed().as_secs_f64();
                eprintln!(
                    "activemap daemon `{machine}`: episode {id} ({label}): {outcome:?} after {seconds:.1} s"
                );
                *state.lock().expect("episode state") = (outcome, seconds);
            })
        };
        eprintln!(
            "activemap daemon `{}`: episode {} ({}) started in {}",
            self.machine,
            request.job_id,
            request.label,
            dir.display()
        );
        self.episodes.insert(
            request.job_id.clone(),
            Episode {
                label: request.label.clone(),
                dir,
                state,
                started,
                stop,
                thread: Some(thread),
            },
        );
        Ok(EpisodeEntry {
            job_id: request.job_id,
            label: request.label,
            state: EpisodeState::Running,
            seconds: 0.0,
        })
    }

    /// The files of an ended episode, sorted, without the recording unless asked.
    fn files(&self, request: &FilesRequest) -> Result<Vec<EpisodeFile>, String> {
        let e = self.episode(&request.job_id)?;
        if e.state.lock().expect("episode state").0 == EpisodeState::Running {
            return Err(format!("episode `{}` is still running", request.job_id));
        }
        let mut out = Vec::new();
        list_files(&e.dir, &e.dir, &mut out)?;
        out.retain(|f| request.record || f.path != RECORDING);
        out.sort_by(|a, b| a.path.cmp(&b.path));
        Ok(out)
    }

    /// A chunk of one of an episode's files.
    fn read(&self, request: &ReadRequest) -> Result<Vec<u8>, String> {
        let e = self.episode(&request.job_id)?;
        let rel = Path::new(&request.path);
        if !rel.components().all(|c| matches!(c, Component::Normal(_))) {
            return Err(format!(
                "`{}` is not a path inside the episode",
                request.path
            ));
        }
        let path = e.dir.join(rel);
        let mut file =
            std::fs::File::open(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        file.seek(SeekFrom::Start(request.offset))
            .map_err(|e| format!("{}: {e}", path.display()))?;
        let mut data = Vec::new();
        file.take(request.len.min(CHUNK_BYTES))
            .read_to_end(&mut data)
            .map_err(|e| format!("{}: {e}", path.display()))?;
        Ok(data)
    }

    /// The store's path of a scene when it holds it.
    fn scene_path(&self, scene: &SceneRef) -> Result<Option<PathBuf>, String> {
        scene.check()?;
        let path = self.scenes.join(scene.file_name());
        Ok(path.is_file().then_some(path))
    }

    /// Appends an uploaded chunk; the last one is checked against the hash and the file
    /// published under its name (its path returned), a mismatch deleted and refused.
    fn scene_put(&self, put: ScenePut) -> Result<Option<PathBuf>, String> {
        put.scene.check()?;
        let part = self.scenes.join(format!("{}.part", put.scene.file_name()));
        let mut file = std::fs::OpenOptions::new()
            .create(true)
            .write(true)
            .truncate(put.offset == 0)
            .open(&part)
            .map_err(|e| format!("{}: {e}", part.display()))?;
        let len = file.metadata().map_err(|e| e.to_string())?.len();
        if len != put.offset {
            return Err(format!(
                "scene {}: chunk at byte {} but {} bytes arrived so far",
                put.scene.file_name(),
                put.offset,
                len
            ));
        }
        file.seek(SeekFrom::End(0))
            .and_then(|_| file.write_all(&put.data))
            .map_err(|e| format!("{}: {e}", part.display()))?;
        drop(file);
        let end = put.offset + put.data.len() as u64;
        if end < put.total {
            return Ok(None);
        }
        let bytes = std::fs::read(&part).map_err(|e| format!("{}: {e}", part.display()))?;
        let got = sha256_hex(&bytes);
        if got != put.scene.sha256 || end != put.total {
            let _ = std::fs::remove_file(&part);
            return Err(format!(
                "scene {}: the upload's SHA-256 is {got} ({end} of {} bytes): refused",
                put.scene.file_name(),
                put.total
            ));
        }
        let path = self.scenes.join(put.scene.file_name());
        std::fs::rename(&part, &path).map_err(|e| format!("{}: {e}", path.display()))?;
        Ok(Some(path))
    }

    /// Stops every running episode and waits for them (the daemon is going down).
    fn stop_all(&mut self) {
        for e in self.episodes.values() {
            e.stop.store(true, Ordering::SeqCst);
        }
        self.reap(true);
    }

    /// Joins the supervisors of ended episodes (all of them when `all`).
    fn reap(&mut self, all: bool) {
        for (id, e) in &mut self.episodes {
            if (all || e.thread.as_ref().is_some_and(|t| t.is_finished()))
                && let Some(t) = e.thread.take()
                && t.join().is_err()
            {
                eprintln!("activemap daemon: the supervisor of episode {id} panicked");
            }
        }
    }
}

impl DaemonService for EpisodeHost {
    fn answer(
        &mut self,
        verb: &str,
        payload: &[u8],
        catalog: &[OperatorDescriptor],
    ) -> Option<Result<Vec<u8>, String>> {
        self.answer_verb(verb, payload, catalog)
    }

    fn poll(&mut self) {
        self.reap(false);
    }

    fn shutdown(&mut self) {
        self.stop_all();
    }
}

/// An answer as JSON.
fn json<T: Serialize>(value: &T) -> Vec<u8> {
    serde_json::to_vec(value).expect("serialisable")
}

/// A JSON request of `verb`, or an error naming it.
fn parse<T: serde::de::DeserializeOwned>(payload: &[u8], verb: &str) -> Result<T, String> {
    serde_json::from_slice(payload).map_err(|e| format!("malformed {verb} request: {e}"))
}

/// Every regular file under `dir`, relative to `root`.
fn list_files(root: &Path, dir: &Path, out: &mut Vec<EpisodeFile>) -> Result<(), String> {
    let entries = std::fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    for entry in entries.flatten() {
        let path = entry.path();
        let kind = entry
            .file_type()
            .map_err(|e| format!("{}: {e}", path.display()))?;
        if kind.is_dir() {
            list_files(root, &path, out)?;
        } else if kind.is_file() {
            let rel = path.strip_prefix(root).unwrap_or(&path);
            out.push(EpisodeFile {
                path: rel
                    .components()
                    .map(|c| c.as_os_str().to_string_lossy().into_owned())
                    .collect::<Vec<_>>()
                    .join("/"),
                size: entry.metadata().map_err(|e| e.to_string())?.len(),
            });
        }
    }
    Ok(())
}

/// The child gets SIGTERM when the thread that started it (the episode's supervisor, which
/// lives as long as the child) ends, in particular when the daemon dies.
fn die_with_parent(cmd: &mut Command) {
    use std::os::unix::process::CommandExt as _;
    // SAFETY: prctl is async-signal-safe and touches no memory of the parent.
    unsafe {
        cmd.pre_exec(|| {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
}

/// Runs the episode's `activemap run` to its end; SIGTERM on a stop request.
fn supervise(mut cmd: Command, stop: &AtomicBool, log: &Path) -> EpisodeState {
    let mut child = match cmd.spawn() {
        Ok(c) => c,
        Err(e) => return EpisodeState::Failed(format!("starting activemap run: {e}")),
    };
    let mut signalled = false;
    loop {
        match child.try_wait() {
            Ok(Some(status)) if status.success() => return EpisodeState::Succeeded,
            Ok(Some(status)) => {
                return EpisodeState::Failed(format!(
                    "activemap run: {status}{}; last lines of {EPISODE_LOG}:\n{}",
                    if signalled {
                        " (stopped on request)"
                    } else {
                        ""
                    },
                    activemap_runtime::launch::tail(log, 8)
                ));
            }
            Ok(None) => {}
            Err(e) => return EpisodeState::Failed(format!("waiting for activemap run: {e}")),
        }
        if stop.load(Ordering::SeqCst) && !signalled {
            signalled = true;
            // SAFETY: kill(2) on our own child's pid.
            unsafe {
                libc::kill(child.id() as libc::pid_t, libc::SIGTERM);
            }
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Why a request about an episode did not succeed: the daemon could not be reached (its
/// episodes should go elsewhere) or it answered with a refusal (the request's own fault, or
/// `busy`).
#[derive(Debug, Clone, PartialEq)]
pub enum EpisodeError {
    /// No answer, or the session failed: the machine is lost to the client.
    Unreachable(String),
    /// The daemon answered with this error.
    Refused(String),
}

impl std::fmt::Display for EpisodeError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            EpisodeError::Unreachable(why) | EpisodeError::Refused(why) => f.write_str(why),
        }
    }
}

/// The client side of the episode verbs, on a [`DaemonClient`] (`activemap bench results
/// --connect`).
pub trait EpisodeClient {
    /// Every reachable daemon's episode board, sorted by machine.
    fn episode_boards(&self) -> Result<Vec<EpisodeBoard>, RuntimeError>;

    /// One machine's episode board.
    fn episode_board(&self, machine: &str) -> Result<EpisodeBoard, EpisodeError>;

    /// Starts an episode on `machine`.
    fn start_episode(
        &self,
        machine: &str,
        request: &EpisodeRequest,
    ) -> Result<EpisodeEntry, EpisodeError>;

    /// Asks `machine` to stop an episode (its files stay readable once it has ended).
    fn cancel_episode(&self, machine: &str, job_id: &str) -> Result<(), EpisodeError>;

    /// Copies an ended episode's files (the recording only with `record`) from `machine` into
    /// `dest`, chunk by chunk; the bytes copied.
    fn fetch_episode(
        &self,
        machine: &str,
        job_id: &str,
        record: bool,
        dest: &Path,
    ) -> Result<u64, EpisodeError>;

    /// The path on `machine` of the scene file `file` (of this machine), uploading it first
    /// when the daemon's store does not hold its content yet.
    fn ensure_scene(
        &self,
        machine: &str,
        file: &Path,
        scene: &SceneRef,
    ) -> Result<PathBuf, EpisodeError>;
}

impl EpisodeClient for DaemonClient {
    /// Every reachable daemon's episode board, sorted by machine.
    fn episode_boards(&self) -> Result<Vec<EpisodeBoard>, RuntimeError> {
        let mut boards = Vec::new();
        for (m, answer) in self.ask("*", "episodes", Vec::new())? {
            let bytes =
                answer.map_err(|why| RuntimeError::Other(format!("machine `{m}`: {why}")))?;
            boards.push(serde_json::from_slice::<EpisodeBoard>(&bytes).map_err(|e| {
                RuntimeError::Other(format!("machine `{m}`: bad episodes answer: {e}"))
            })?);
        }
        boards.sort_by(|a, b| a.machine.cmp(&b.machine));
        Ok(boards)
    }

    /// One machine's episode board.
    fn episode_board(&self, machine: &str) -> Result<EpisodeBoard, EpisodeError> {
        ask_json(self, machine, "episodes", Vec::new())
    }

    /// Starts an episode on `machine`.
    fn start_episode(
        &self,
        machine: &str,
        request: &EpisodeRequest,
    ) -> Result<EpisodeEntry, EpisodeError> {
        ask_json(self, machine, "episode", json(request))
    }

    /// Asks `machine` to stop an episode (its files stay readable once it has ended).
    fn cancel_episode(&self, machine: &str, job_id: &str) -> Result<(), EpisodeError> {
        ask_one(self, machine, "episode_cancel", json(&job_id)).map(|_| ())
    }

    /// Copies an ended episode's files (the recording only with `record`) from `machine` into
    /// `dest`, chunk by chunk; the bytes copied.
    fn fetch_episode(
        &self,
        machine: &str,
        job_id: &str,
        record: bool,
        dest: &Path,
    ) -> Result<u64, EpisodeError> {
        let request = FilesRequest {
            job_id: job_id.to_string(),
            record,
        };
        let files: Vec<EpisodeFile> = ask_json(self, machine, "episode_files", json(&request))?;
        let local = |why: String| EpisodeError::Refused(format!("{}: {why}", dest.display()));
        let mut total = 0;
        for f in files {
            let rel = Path::new(&f.path);
            if !rel.components().all(|c| matches!(c, Component::Normal(_))) {
                return Err(EpisodeError::Refused(format!(
                    "machine `{machine}` listed `{}`, not a path inside the episode",
                    f.path
                )));
            }
            let path = dest.join(rel);
            if let Some(parent) = path.parent() {
                std::fs::create_dir_all(parent).map_err(|e| local(e.to_string()))?;
            }
            let mut out = std::fs::File::create(&path).map_err(|e| local(e.to_string()))?;
            let mut offset = 0;
            while offset < f.size {
                let read = ReadRequest {
                    job_id: job_id.to_string(),
                    path: f.path.clone(),
                    offset,
                    len: CHUNK_BYTES.min(f.size - offset),
                };
                let chunk = ask_one(self, machine, "episode_read", json(&read))?;
                if chunk.is_empty() {
                    return Err(EpisodeError::Refused(format!(
                        "machine `{machine}`: {} ended at byte {offset} of {}",
                        f.path, f.size
                    )));
                }
                out.write_all(&chunk).map_err(|e| local(e.to_string()))?;
                offset += chunk.len() as u64;
            }
            total += f.size;
        }
        Ok(total)
    }

    /// The path on `machine` of the scene file `file` (of this machine), uploading it first
    /// when the daemon's store does not hold its content yet.
    fn ensure_scene(
        &self,
        machine: &str,
        file: &Path,
        scene: &SceneRef,
    ) -> Result<PathBuf, EpisodeError> {
        if let Some(path) = ask_json::<Option<PathBuf>>(self, machine, "scene_have", json(scene))? {
            return Ok(path);
        }
        let bytes = std::fs::read(file)
            .map_err(|e| EpisodeError::Refused(format!("{}: {e}", file.display())))?;
        let mut offset = 0;
        loop {
            let end = (offset + CHUNK_BYTES as usize).min(bytes.len());
            let put = ScenePut {
                scene: scene.clone(),
                total: bytes.len() as u64,
                offset: offset as u64,
                data: bytes[offset..end].to_vec(),
            };
            let payload = postcard::to_allocvec(&put).expect("serialisable");
            let answer: Option<PathBuf> = ask_json(self, machine, "scene_put", payload)?;
            if let Some(path) = answer {
                return Ok(path);
            }
            if end == bytes.len() {
                return Err(EpisodeError::Refused(format!(
                    "machine `{machine}`: the upload of {} ended without the scene being stored",
                    file.display()
                )));
            }
            offset = end;
        }
    }
}

/// Asks one machine; its one answer's bytes.
fn ask_one(
    client: &DaemonClient,
    machine: &str,
    verb: &str,
    payload: Vec<u8>,
) -> Result<Vec<u8>, EpisodeError> {
    let answers = client
        .ask(machine, verb, payload)
        .map_err(|e| EpisodeError::Unreachable(format!("machine `{machine}`: {e}")))?;
    match answers.into_iter().next() {
        None => Err(EpisodeError::Unreachable(no_answer(
            machine,
            client.timeout(),
        ))),
        Some((_, Ok(bytes))) => Ok(bytes),
        // Zenoh answers a query whose queryable vanished (a dead daemon, before its link's
        // lease expires) with an error reply reading `Timeout`; a daemon never does.
        Some((_, Err(why))) if why == "Timeout" => Err(EpisodeError::Unreachable(no_answer(
            machine,
            client.timeout(),
        ))),
        Some((_, Err(why))) => Err(EpisodeError::Refused(format!("machine `{machine}`: {why}"))),
    }
}

/// Asks one machine and reads its JSON answer.
fn ask_json<T: serde::de::DeserializeOwned>(
    client: &DaemonClient,
    machine: &str,
    verb: &str,
    payload: Vec<u8>,
) -> Result<T, EpisodeError> {
    let bytes = ask_one(client, machine, verb, payload)?;
    serde_json::from_slice(&bytes)
        .map_err(|e| EpisodeError::Refused(format!("machine `{machine}`: bad {verb} answer: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scene_references_are_checked_before_they_name_a_file() {
        let ok = SceneRef {
            sha256: sha256_hex(b"abc"),
            ext: "glb".into(),
        };
        assert_eq!(
            ok.sha256, "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad",
            "the FIPS 180-2 test vector"
        );
        assert!(ok.check().is_ok());
        for (sha, ext) in [
            ("../../etc/passwd", "glb"),
            (&ok.sha256[..63], "glb"),
            (&ok.sha256.to_uppercase(), "glb"),
            (&ok.sha256, "g/b"),
            (&ok.sha256, ""),
        ] {
            let r = SceneRef {
                sha256: sha.to_string(),
                ext: ext.to_string(),
            };
            assert!(r.check().is_err(), "{sha}.{ext}");
        }
        assert!(valid_job_id("c3_fbe-1") && !valid_job_id("../x") && !valid_job_id(""));
    }

    fn host(dir: &Path) -> EpisodeHost {
        let opts = DaemonOptions {
            machine: "m".into(),
            listen: vec![],
            connect: vec![],
            runs_dir: dir.to_path_buf(),
            exe: PathBuf::from("/bin/false"),
            base_dir: dir.to_path_buf(),
            allow_exec: vec![],
            insecure: false,
            tls: None,
            record_digests: vec![],
            derived: None,
        };
        EpisodeHost::new(&opts, 1).unwrap()
    }

    /// A scene uploaded in chunks is published under its hash; a corrupted upload is refused
    /// and leaves nothing behind; chunks out of order are refused.
    #[test]
    fn scenes_upload_in_chunks_and_are_checked_by_hash() {
        let dir = tempfile::tempdir().unwrap();
        let h = host(dir.path());
        let bytes: Vec<u8> = (0..10_000u32).map(|i| (i * 7 % 251) as u8).collect();
        let scene = SceneRef {
            sha256: sha256_hex(&bytes),
            ext: "obj".into(),
        };
        assert_eq!(h.scene_path(&scene).unwrap(), None);
        let put = |offset: usize, end: usize, data: &[u8]| ScenePut {
            scene: scene.clone(),
            total: data.len() as u64,
            offset: offset as u64,
            data: data[offset..end].to_vec(),
        };
        assert_eq!(h.scene_put(put(0, 4000, &bytes)).unwrap(), None);
        assert!(h.scene_put(put(5000, 6000, &bytes)).is_err(), "a gap");
        assert_eq!(h.scene_put(put(4000, 8000, &bytes)).unwrap(), None);
        let path = h.scene_put(put(8000, 10_000, &bytes)).unwrap().unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), bytes);
        assert_eq!(h.scene_path(&scene).unwrap(), Some(path));
        // Same hash, other bytes: refused, and no partial file is left.
        let mut bad = bytes.clone();
        bad[17] ^= 1;
        let other = SceneRef {
            ext: "ply".into(),
            ..scene.clone()
        };
        let e = h
            .scene_put(ScenePut {
                scene: other.clone(),
                total: bad.len() as u64,
                offset: 0,
                data: bad,
            })
            .unwrap_err();
        assert!(e.contains("refused"), "{e}");
        assert_eq!(h.scene_path(&other).unwrap(), None);
        assert_eq!(
            std::fs::read_dir(dir.path().join("scenes"))
                .unwrap()
                .count(),
            1
        );
    }

    /// Reads stay inside the episode folder.
    #[test]
    fn reads_refuse_paths_that_leave_the_episode() {
        let dir = tempfile::tempdir().unwrap();
        let mut h = host(dir.path());
        let edir = dir.path().join("episodes/e1");
        std::fs::create_dir_all(edir.join("logs")).unwrap();
        std::fs::write(edir.join("metrics.json"), b"{}").unwrap();
        std::fs::write(edir.join("logs/sim.stderr.log"), b"hello").unwrap();
        std::fs::write(edir.join(RECORDING), b"mcap").unwrap();
        h.episodes.insert(
            "e1".into(),
            Episode {
                label: "l".into(),
                dir: edir,
                state: Arc::new(Mutex::new((EpisodeState::Succeeded, 1.0))),
                started: Instant::now(),
                stop: Arc::new(AtomicBool::new(false)),
                thread: None,
            },
        );
        let files = h
            .files(&FilesRequest {
                job_id: "e1".into(),
                record: false,
            })
            .unwrap();
        let names: Vec<&str> = files.iter().map(|f| f.path.as_str()).collect();
        assert_eq!(names, ["logs/sim.stderr.log", "metrics.json"]);
        let read = |path: &str, offset: u64| {
            h.read(&ReadRequest {
                job_id: "e1".into(),
                path: path.into(),
                offset,
                len: 3,
            })
        };
        assert_eq!(read("logs/sim.stderr.log", 1).unwrap(), b"ell");
        for bad in ["../e1/metrics.json", "/etc/passwd", "logs/../../x"] {
            assert!(read(bad, 0).is_err(), "{bad}");
        }
        assert!(h.episode("nope").is_err_and(|e| e.contains("no episode")));
    }
}
