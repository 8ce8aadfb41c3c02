//! `activemap bench results --connect ENDPOINT…`: the cells of a suite run on machine daemons
//! (`activemap up --listen … --slots N`) instead of this machine, each whole on one daemon, with
//! its run folder's files brought back over the daemons' Zenoh session
//! (`activemap_runtime::daemon::episodes`); and the suite's progress lines, shared with local
//! runs.
//!
//! A cell goes to a daemon with a free slot; a daemon that stops answering is dropped for the
//! rest of the suite and its cells go to the others (the reason is printed); a cell that fails
//! on its own (its `activemap run` failed, or the daemon refused its flow) is reported once, as
//! a local failure is.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Condvar, Mutex};
use std::time::{Duration, Instant};

use activemap_bench::episodes::{
    EpisodeClient as _, EpisodeError, EpisodeRequest, EpisodeState, SceneRef,
};
use activemap_bench::results::{Cell, grid::CELL_FILE};
use activemap_runtime::daemon::DaemonClient;

/// How often a running remote cell's state is asked for.
const POLL: Duration = Duration::from_millis(200);
/// Unanswered polls in a row after which a daemon counts as lost.
const LOST_AFTER: u32 = 3;

/// Progress of a whole suite: cells done, running (where) and queued, with an estimate of the
/// time left from the cell times measured so far; one plain line per event, for a pipe.
pub struct SuiteProgress {
    started: Instant,
    total: usize,
    state: Mutex<ProgressState>,
}

#[derive(Default)]
struct ProgressState {
    queued: usize,
    done: usize,
    slots: usize,
    /// Running cells: label → (machine, start).
    running: BTreeMap<String, (String, Instant)>,
    /// Seconds of the cells run in this invocation.
    times: Vec<f64>,
}

impl SuiteProgress {
    /// A suite of `total` cells run `slots` at a time.
    pub fn new(total: usize, slots: usize) -> Self {
        Self {
            started: Instant::now(),
            total,
            state: Mutex::new(ProgressState {
                queued: total,
                slots,
                ..ProgressState::default()
            }),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, ProgressState> {
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Cells can now run `slots` at a time (a daemon was lost).
    pub fn set_slots(&self, slots: usize) {
        self.lock().slots = slots;
    }

    /// `label` started on `machine`.
    pub fn started(&self, label: &str, machine: &str) {
        let mut s = self.lock();
        s.queued = s.queued.saturating_sub(1);
        s.running
            .insert(label.to_string(), (machine.to_string(), Instant::now()));
        self.print(&s, &format!("{label}: started on {machine}"));
    }

    /// `label` goes back to the queue: `why`.
    pub fn requeued(&self, label: &str, why: &str) {
        let mut s = self.lock();
        s.running.remove(label);
        s.queued += 1;
        self.print(&s, &format!("{label}: re-queued ({why})"));
    }

    /// `label` ended (`what`: done, failed, kept from an earlier run…); `ran` when it ran in
    /// this invocation (its time joins the estimate).
    pub fn ended(&self, label: &str, what: &str, ran: bool) {
        let mut s = self.lock();
        if let Some((_, since)) = s.running.remove(label) {
            if ran {
                s.times.push(since.elapsed().as_secs_f64());
            }
        } else {
            s.queued = s.queued.saturating_sub(1);
        }
        s.done += 1;
        self.print(&s, &format!("{label}: {what}"));
    }

    /// Prints the event and the suite's state.
    fn print(&self, s: &ProgressState, event: &str) {
        let mut by_machine: BTreeMap<&str, usize> = BTreeMap::new();
        for (machine, _) in s.running.values() {
            *by_machine.entry(machine).or_default() += 1;
        }
        let machines = by_machine
            .iter()
            .map(|(m, n)| format!("{m} {n}"))
            .collect::<Vec<_>>()
            .join(", ");
        let eta = match estimate_left(s) {
            Some(left) => format!("; about {} left", human(left)),
            None => String::new(),
        };
        eprintln!(
            "bench results: [{:>6.0} s] {event} | done {}/{}, running {}{}, queued {}{eta}",
            self.started.elapsed().as_secs_f64(),
            s.done,
            self.total,
            s.running.len(),
            if machines.is_empty() {
                String::new()
            } else {
                format!(" ({machines})")
            },
            s.queued,
        );
    }
}

/// Seconds left: the mean cell time for each queued cell and the rest of it for each running
/// one, spread over the slots; none before a cell has ended.
fn estimate_left(s: &ProgressState) -> Option<f64> {
    if s.times.is_empty() {
        return None;
    }
    let mean = s.times.iter().sum::<f64>() / s.times.len() as f64;
    let running: f64 = s
        .running
        .values()
        .map(|(_, since)| (mean - since.elapsed().as_secs_f64()).max(0.0))
        .sum();
    Some((running + mean * s.queued as f64) / s.slots.max(1) as f64)
}

/// Seconds as `42 s`, `7 min` or `2.5 h`.
fn human(seconds: f64) -> String {
    if seconds < 120.0 {
        format!("{seconds:.0} s")
    } else if seconds < 7200.0 {
        format!("{:.0} min", seconds / 60.0)
    } else {
        format!("{:.1} h", seconds / 3600.0)
    }
}

/// The daemons' slots as the client sees them.
struct Pool {
    machines: Mutex<Vec<Machine>>,
    freed: Condvar,
}

struct Machine {
    name: String,
    slots: usize,
    busy: usize,
    lost: Option<String>,
}

impl Pool {
    /// Slots of the machines not lost.
    fn live_slots(machines: &[Machine]) -> usize {
        machines
            .iter()
            .filter(|m| m.lost.is_none())
            .map(|m| m.slots)
            .sum()
    }

    /// Takes a slot on the live machine with the most free ones (waiting for one); `Err` with
    /// the reason when every machine is lost or a stop was requested.
    fn acquire(&self, stop: &AtomicBool) -> Result<String, String> {
        let mut machines = self.machines.lock().unwrap_or_else(|p| p.into_inner());
        loop {
            if stop.load(Ordering::SeqCst) {
                return Err("stopped before the episode started".into());
            }
            if machines.iter().all(|m| m.lost.is_some()) {
                let lost = machines
                    .iter()
                    .map(|m| format!("{}: {}", m.name, m.lost.as_deref().unwrap_or("")))
                    .collect::<Vec<_>>()
                    .join("; ");
                return Err(format!("no daemon left to run it (lost: {lost})"));
            }
            if let Some(m) = machines
                .iter_mut()
                .filter(|m| m.lost.is_none() && m.busy < m.slots)
                .max_by_key(|m| (m.slots - m.busy, std::cmp::Reverse(m.name.clone())))
            {
                m.busy += 1;
                return Ok(m.name.clone());
            }
            machines = self
                .freed
                .wait_timeout(machines, Duration::from_millis(200))
                .unwrap_or_else(|p| p.into_inner())
                .0;
        }
    }

    /// Gives a slot back; with `lost`, the machine takes no further cell.
    fn release(&self, name: &str, lost: Option<String>) -> Option<usize> {
        let mut machines = self.machines.lock().unwrap_or_else(|p| p.into_inner());
        let mut live = None;
        if let Some(m) = machines.iter_mut().find(|m| m.name == name) {
            m.busy = m.busy.saturating_sub(1);
            if lost.is_some() && m.lost.is_none() {
                m.lost = lost;
                live = Some(Self::live_slots(&machines));
            }
        }
        self.freed.notify_all();
        live
    }
}

/// Runs a suite's cells on the daemons a client reaches.
pub struct Remote {
    client: DaemonClient,
    pool: Pool,
    record: bool,
    /// Scene files already hashed: path → content address.
    scenes: Mutex<HashMap<PathBuf, SceneRef>>,
    /// Per cell: wall time from submission to its files back, minus the episode's own time.
    overheads: Mutex<Vec<f64>>,
    attempts: AtomicU64,
}

impl Remote {
    /// Asks every daemon `client` reaches for its slots; an error when none answers.
    pub fn new(client: DaemonClient, record: bool) -> anyhow::Result<Self> {
        let boards = client.episode_boards()?;
        anyhow::ensure!(
            !boards.is_empty(),
            "bench results --connect: no daemon answered (is `activemap up --listen …` running there?)"
        );
        let machines = boards
            .iter()
            .map(|b| Machine {
                name: b.machine.clone(),
                slots: b.slots,
                busy: 0,
                lost: None,
            })
            .collect();
        Ok(Self {
            client,
            pool: Pool {
                machines: Mutex::new(machines),
                freed: Condvar::new(),
            },
            record,
            scenes: Mutex::new(HashMap::new()),
            overheads: Mutex::new(Vec::new()),
            attempts: AtomicU64::new(0),
        })
    }

    /// The machines and their slots, e.g. `a (1 slot), b (2 slots)`.
    pub fn describe(&self) -> String {
        let machines = self.pool.machines.lock().unwrap_or_else(|p| p.into_inner());
        machines
            .iter()
            .map(|m| {
                format!(
                    "{} ({} slot{})",
                    m.name,
                    m.slots,
                    if m.slots == 1 { "" } else { "s" }
                )
            })
            .collect::<Vec<_>>()
            .join(", ")
    }

    /// Cells that can run at once: every daemon's slots.
    pub fn slots(&self) -> usize {
        Pool::live_slots(&self.pool.machines.lock().unwrap_or_else(|p| p.into_inner()))
    }

    /// The dispatch overheads measured so far (seconds per cell).
    pub fn overheads(&self) -> Vec<f64> {
        self.overheads
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// Runs `cell` on some daemon with its files brought back into `dir` (which holds only
    /// `cell.json`), moving to another daemon when one is lost.
    pub fn run_cell(
        &self,
        cell: &Cell,
        dir: &Path,
        stop: &AtomicBool,
        progress: &SuiteProgress,
    ) -> Result<(), String> {
        let label = cell.label();
        loop {
            let machine = self.pool.acquire(stop)?;
            progress.started(&label, &machine);
            let outcome = self.run_on(&machine, cell, dir, stop);
            match outcome {
                Ok(overhead) => {
                    self.pool.release(&machine, None);
                    self.overheads
                        .lock()
                        .unwrap_or_else(|p| p.into_inner())
                        .push(overhead);
                    return Ok(());
                }
                Err(EpisodeError::Unreachable(why)) if !stop.load(Ordering::SeqCst) => {
                    if let Some(live) = self.pool.release(&machine, Some(why.clone())) {
                        progress.set_slots(live);
                        eprintln!(
                            "bench results: machine `{machine}` lost ({why}): it gets no further cell"
                        );
                    }
                    clear_but_cell_file(dir)?;
                    progress.requeued(&label, &format!("machine `{machine}` lost"));
                }
                Err(EpisodeError::Refused(why)) if why.contains("busy:") => {
                    // Another client took the slot: try again shortly.
                    self.pool.release(&machine, None);
                    progress.requeued(&label, &why);
                    std::thread::sleep(Duration::from_secs(1));
                }
                Err(e) => {
                    self.pool.release(&machine, None);
                    return Err(e.to_string());
                }
            }
        }
    }

    /// One attempt on `machine`: its scene there, the cell's flow, the episode to its end and
    /// its files back; the dispatch overhead in seconds.
    fn run_on(
        &self,
        machine: &str,
        cell: &Cell,
        dir: &Path,
        stop: &AtomicBool,
    ) -> Result<f64, EpisodeError> {
        let submitted = Instant::now();
        let mut remote_cell = cell.clone();
        let scene_file = Path::new(&cell.scene);
        if scene_file.is_file() {
            let scene = self.scene_ref(scene_file)?;
            let there = self.client.ensure_scene(machine, scene_file, &scene)?;
            remote_cell.scene = there.display().to_string();
        }
        let flow = crate::bench_results::cell_flow(&remote_cell)
            .map_err(|e| EpisodeError::Refused(format!("{e:#}")))?;
        let attempt = self.attempts.fetch_add(1, Ordering::SeqCst);
        let job_id = format!(
            "{}-{attempt}-{}",
            activemap_runtime::launch::new_run_id(),
            cell.label()
                .chars()
                .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
                .collect::<String>()
        );
        let request = EpisodeRequest {
            job_id: job_id.chars().take(128).collect(),
            label: cell.label(),
            flow,
            max_steps: cell.settings.steps,
            eval_views: cell.settings.eval_views,
            record: self.record,
        };
        self.client.start_episode(machine, &request)?;
        let mut misses = 0;
        let mut cancelled = false;
        let ended = loop {
            std::thread::sleep(POLL);
            if stop.load(Ordering::SeqCst) && !cancelled {
                cancelled = true;
                let _ = self.client.cancel_episode(machine, &request.job_id);
            }
            match self.client.episode_board(machine) {
                Ok(board) => {
                    misses = 0;
                    match board.get(&request.job_id) {
                        None => {
                            return Err(EpisodeError::Unreachable(format!(
                                "machine `{machine}` no longer knows episode {} (its daemon \
                                 restarted)",
                                request.job_id
                            )));
                        }
                        Some(e) if e.state == EpisodeState::Running => {}
                        Some(e) => break e.clone(),
                    }
                }
                Err(EpisodeError::Unreachable(why)) => {
                    misses += 1;
                    if misses >= LOST_AFTER {
                        return Err(EpisodeError::Unreachable(format!(
                            "{why}; {misses} polls in a row unanswered"
                        )));
                    }
                }
                Err(e) => return Err(e),
            }
        };
        self.client
            .fetch_episode(machine, &request.job_id, self.record, dir)?;
        let overhead = (submitted.elapsed().as_secs_f64() - ended.seconds).max(0.0);
        match ended.state {
            EpisodeState::Failed(why) => Err(EpisodeError::Refused(format!(
                "on machine `{machine}`: {why}"
            ))),
            _ => Ok(overhead),
        }
    }

    /// The content address of a scene file, hashed once per suite.
    fn scene_ref(&self, file: &Path) -> Result<SceneRef, EpisodeError> {
        let mut scenes = self.scenes.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(s) = scenes.get(file) {
            return Ok(s.clone());
        }
        let s = SceneRef::of_file(file).map_err(EpisodeError::Refused)?;
        scenes.insert(file.to_path_buf(), s.clone());
        Ok(s)
    }
}

/// Empties a cell's folder but for its `cell.json` (before it runs again elsewhere).
fn clear_but_cell_file(dir: &Path) -> Result<(), String> {
    let entries = std::fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    for entry in entries.flatten() {
        let path = entry.path();
        if entry.file_name() == CELL_FILE {
            continue;
        }
        let removed = if path.is_dir() {
            std::fs::remove_dir_all(&path)
        } else {
            std::fs::remove_file(&path)
        };
        removed.map_err(|e| format!("{}: {e}", path.display()))?;
    }
    Ok(())
}

/// Median and largest of `values` (none when empty).
pub fn median_and_max(values: &[f64]) -> Option<(f64, f64)> {
    if values.is_empty() {
        return None;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    let median = if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    };
    Some((median, v[n - 1]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_estimate_spreads_the_mean_cell_time_over_the_slots() {
        let mut s = ProgressState {
            queued: 3,
            slots: 2,
            ..ProgressState::default()
        };
        assert_eq!(estimate_left(&s), None);
        s.times = vec![10.0, 30.0];
        // Three queued cells of 20 s on two slots, nothing running.
        assert_eq!(estimate_left(&s), Some(30.0));
        assert_eq!(human(30.0), "30 s");
        assert_eq!(human(600.0), "10 min");
        assert_eq!(human(9000.0), "2.5 h");
        assert_eq!(median_and_max(&[3.0, 1.0, 2.0, 10.0]), Some((2.5, 10.0)));
    }

    #[test]
    fn slots_go_to_the_freest_live_machine_and_lost_machines_take_none() {
        let machine = |name: &str, slots| Machine {
            name: name.into(),
            slots,
            busy: 0,
            lost: None,
        };
        let pool = Pool {
            machines: Mutex::new(vec![machine("a", 1), machine("b", 2)]),
            freed: Condvar::new(),
        };
        let stop = AtomicBool::new(false);
        assert_eq!(pool.acquire(&stop).unwrap(), "b");
        assert_eq!(pool.acquire(&stop).unwrap(), "a", "a tie goes by name");
        assert_eq!(pool.acquire(&stop).unwrap(), "b");
        assert_eq!(pool.release("b", Some("gone".into())), Some(1));
        assert_eq!(pool.release("b", None), None);
        assert_eq!(pool.release("a", Some("gone too".into())), Some(0));
        let e = pool.acquire(&stop).unwrap_err();
        assert!(e.contains("a: gone too") && e.contains("b: gone"), "{e}");
    }
}
