//! Runs the cells of a grid on `jobs` worker threads, resuming: complete cells are read, not
//! re-run; half-finished folders are cleared and run again; a stop request (Ctrl-C) lets the
//! running cells end as their runner decides and starts no new one.
//!
//! How one cell runs (the exploration episode and its evaluation) is the caller's closure: the
//! library holds no process or transport code.

use super::grid::{Cell, CellState, cell_state};
use activemap_eval::MetricsReport;
use activemap_eval::run_folder::RunError;
use std::path::Path;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// How one cell ended in this invocation.
#[derive(Debug, Clone, PartialEq)]
pub enum CellOutcome {
    /// Already complete from an earlier invocation: not re-run.
    Reused(Box<MetricsReport>),
    /// Run now and complete.
    Ran(Box<MetricsReport>),
    /// Run now but it left no usable `metrics.json`: why.
    Failed(String),
    /// Not run, or cut short, because a stop was requested.
    Interrupted,
}

impl CellOutcome {
    /// The metrics, when the cell is complete.
    pub fn metrics(&self) -> Option<&MetricsReport> {
        match self {
            CellOutcome::Reused(m) | CellOutcome::Ran(m) => Some(m),
            _ => None,
        }
    }
}

/// A cell and how it ended.
#[derive(Debug, Clone, PartialEq)]
pub struct CellResult {
    /// The cell.
    pub cell: Cell,
    /// How it ended.
    pub outcome: CellOutcome,
}

/// Runs every cell of `cells` whose folder under `out` is not complete, `jobs` at a time (at
/// least 1), calling `run_cell(cell, folder)` with the folder freshly created and holding only
/// `cell.json`. `progress` sees each result as it is known. Returns the results in `cells`
/// order. Errors only for folders that cannot be read or prepared, before any cell runs when
/// the folder holds other settings.
pub fn run_cells<R, P>(
    cells: &[Cell],
    out: &Path,
    jobs: usize,
    stop: &AtomicBool,
    run_cell: R,
    progress: P,
) -> Result<Vec<CellResult>, RunError>
where
    R: Fn(&Cell, &Path) -> Result<(), String> + Sync,
    P: Fn(&CellResult) + Sync,
{
    // Read every state first, so a settings clash stops the grid before anything runs.
    let mut results: Vec<Option<CellResult>> = Vec::with_capacity(cells.len());
    let mut pending = Vec::new();
    for (i, cell) in cells.iter().enumerate() {
        match cell_state(cell, out)? {
            CellState::Complete(m) => {
                let r = CellResult {
                    cell: cell.clone(),
                    outcome: CellOutcome::Reused(m),
                };
                progress(&r);
                results.push(Some(r));
            }
            CellState::Absent | CellState::HalfFinished => {
                results.push(None);
                pending.push(i);
            }
        }
    }
    let results = Mutex::new(results);
    let next = AtomicUsize::new(0);
    let first_error: Mutex<Option<RunError>> = Mutex::new(None);
    let worker = || {
        loop {
            let k = next.fetch_add(1, Ordering::SeqCst);
            let Some(&i) = pending.get(k) else { return };
            let cell = &cells[i];
            let outcome = if stop.load(Ordering::SeqCst) {
                CellOutcome::Interrupted
            } else {
                match run_one(cell, out, stop, &run_cell) {
                    Ok(o) => o,
                    Err(e) => {
                        let message = e.to_string();
                        first_error
                            .lock()
                            .unwrap_or_else(|p| p.into_inner())
                            .get_or_insert(e);
                        CellOutcome::Failed(message)
                    }
                }
            };
            let r = CellResult {
                cell: cell.clone(),
                outcome,
            };
            progress(&r);
            results.lock().unwrap_or_else(|p| p.into_inner())[i] = Some(r);
        }
    };
    std::thread::scope(|s| {
        for _ in 0..jobs.max(1).min(pending.len().max(1)) {
            s.spawn(worker);
        }
    });
    if let Some(e) = first_error.into_inner().unwrap_or_else(|p| p.into_inner()) {
        return Err(e);
    }
    Ok(results
        .into_inner()
        .unwrap_or_else(|p| p.into_inner())
        .into_iter()
        .zip(cells)
        .map(|(r, cell)| {
            r.unwrap_or_else(|| CellResult {
                cell: cell.clone(),
                outcome: CellOutcome::Interrupted,
            })
        })
        .collect())
}

/// Clears and prepares the cell's folder, runs it and reads what it left.
fn run_one<R>(
    cell: &Cell,
    out: &Path,
    stop: &AtomicBool,
    run_cell: &R,
) -> Result<CellOutcome, RunError>
where
    R: Fn(&Cell, &Path) -> Result<(), String>,
{
    let dir = cell.dir(out);
    if dir.exists() {
        std::fs::remove_dir_all(&dir).map_err(|source| RunError::Io {
            path: dir.clone(),
            source,
        })?;
    }
    cell.save(&dir)?;
    let ran = run_cell(cell, &dir);
    Ok(match cell_state(cell, out)? {
        CellState::Complete(m) => CellOutcome::Ran(m),
        _ if stop.load(Ordering::SeqCst) => CellOutcome::Interrupted,
        _ => CellOutcome::Failed(match ran {
            Err(why) => why,
            Ok(()) => format!(
                "the run ended without a usable {}",
                dir.join(activemap_eval::run_folder::RunFolder::METRICS_JSON)
                    .display()
            ),
        }),
    })
}

#[cfg(test)]
mod tests {
    use super::super::grid::{GridSettings, Method, cells};
    use super::*;
    use activemap_eval::run_folder::RunFolder;
    use std::sync::atomic::AtomicU64;

    fn grid() -> Vec<Cell> {
        let settings = GridSettings {
            steps: 10,
            resolution: 32,
            max_rooms: None,
            max_area: None,
            eval_views: 4,
            noise: None,
            ..GridSettings::default()
        };
        cells(
            &[Method::parse("fbe=x.yaml").unwrap()],
            &["house:1".into(), "house:2".into(), "house:3".into()],
            &[1, 2],
            &settings,
        )
    }

    /// A stand-in run: its PSNR encodes the house and seed, so results can be traced back.
    fn fake_run(cell: &Cell, dir: &Path) -> Result<(), String> {
        assert!(dir.join(super::super::grid::CELL_FILE).exists());
        assert_eq!(std::fs::read_dir(dir).unwrap().count(), 1, "a fresh folder");
        let house: f64 = cell.scene[6..].parse().unwrap();
        let report = MetricsReport {
            psnr_db: Some(10.0 * house + cell.seed as f64),
            ..Default::default()
        };
        std::fs::write(dir.join(RunFolder::METRICS_JSON), report.to_json())
            .map_err(|e| e.to_string())
    }

    #[test]
    fn every_cell_runs_once_then_resume_reruns_only_the_unfinished() {
        let out = tempfile::tempdir().unwrap();
        let cells = grid();
        let calls = AtomicU64::new(0);
        let stop = AtomicBool::new(false);
        let run = |c: &Cell, d: &Path| {
            calls.fetch_add(1, Ordering::SeqCst);
            fake_run(c, d)
        };
        let first = run_cells(&cells, out.path(), 3, &stop, run, |_| {}).unwrap();
        assert_eq!(calls.load(Ordering::SeqCst), 6);
        for r in &first {
            let house: f64 = r.cell.scene[6..].parse().unwrap();
            assert_eq!(
                r.outcome,
                CellOutcome::Ran(Box::new(MetricsReport {
                    psnr_db: Some(10.0 * house + r.cell.seed as f64),
                    ..Default::default()
                }))
            );
        }
        // Half-finish two cells: one lost its metrics, one holds a truncated file and a
        // stale log that the re-run must not see.
        std::fs::remove_file(cells[1].dir(out.path()).join(RunFolder::METRICS_JSON)).unwrap();
        let d4 = cells[4].dir(out.path());
        std::fs::write(d4.join(RunFolder::METRICS_JSON), "{").unwrap();
        std::fs::write(d4.join("stale.log"), "x").unwrap();
        let seen = Mutex::new(Vec::new());
        let second = run_cells(&cells, out.path(), 2, &stop, run, |r| {
            seen.lock().unwrap().push(r.cell.label())
        })
        .unwrap();
        assert_eq!(
            calls.load(Ordering::SeqCst),
            8,
            "only the two unfinished cells re-ran"
        );
        assert_eq!(seen.lock().unwrap().len(), 6);
        for (i, r) in second.iter().enumerate() {
            let reran = i == 1 || i == 4;
            assert_eq!(matches!(r.outcome, CellOutcome::Ran(_)), reran, "cell {i}");
            assert_eq!(r.outcome.metrics(), first[i].outcome.metrics(), "cell {i}");
        }
        assert!(!d4.join("stale.log").exists());
    }

    #[test]
    fn a_stop_leaves_the_rest_unrun_and_failures_are_reported() {
        let out = tempfile::tempdir().unwrap();
        let cells = grid();
        let stop = AtomicBool::new(false);
        // The third cell's run is interrupted midway (it sets the stop flag and leaves no
        // metrics); cells after it must not start.
        let run = |c: &Cell, d: &Path| {
            if c == &cells[2] {
                stop.store(true, Ordering::SeqCst);
                return Err("killed".into());
            }
            fake_run(c, d)
        };
        let results = run_cells(&cells, out.path(), 1, &stop, run, |_| {}).unwrap();
        let kinds: Vec<&str> = results
            .iter()
            .map(|r| match r.outcome {
                CellOutcome::Ran(_) => "ran",
                CellOutcome::Interrupted => "stop",
                _ => "other",
            })
            .collect();
        assert_eq!(kinds, ["ran", "ran", "stop", "stop", "stop", "stop"]);
        assert!(cells[2].dir(out.path()).exists() && !cells[3].dir(out.path()).exists());
        // Resume without a stop: the interrupted cell and the unstarted ones run.
        stop.store(false, Ordering::SeqCst);
        let failing = |c: &Cell, d: &Path| {
            if c == &cells[5] {
                return Err("tracker crashed".into());
            }
            fake_run(c, d)
        };
        let results = run_cells(&cells, out.path(), 2, &stop, failing, |_| {}).unwrap();
        assert!(matches!(results[0].outcome, CellOutcome::Reused(_)));
        assert!(matches!(results[2].outcome, CellOutcome::Ran(_)));
        assert_eq!(
            results[5].outcome,
            CellOutcome::Failed("tracker crashed".into())
        );
        let silent = |_: &Cell, _: &Path| Ok(());
        let results = run_cells(&cells, out.path(), 1, &stop, silent, |_| {}).unwrap();
        match &results[5].outcome {
            CellOutcome::Failed(why) => assert!(why.contains("metrics.json"), "{why}"),
            other => panic!("{other:?}"),
        }
    }
}
