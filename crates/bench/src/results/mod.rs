//! `activemap bench results` as a library: methods × scenes × seeds of exploration episodes,
//! each evaluated (SPEC §8), summarised in the layout of the paper's Table 1.
//!
//! - [`grid`]: the cells, their run folders and whether each is complete;
//! - [`runner`]: runs the unfinished cells on worker threads, resuming after an interruption;
//! - [`table`]: `results.md` (Table 1 layout, the ablation, the paired comparison against
//!   FBE, per scene), `results.csv` (mean ± spread over seeds) and `paired.csv`;
//! - [`suite`]: a benchmark suite file (methods, scenes with their placement, seeds, steps,
//!   camera, noise, test views) read into the grid's cells.
//!
//! A method is a dataflow file, named on the command line as NAME=DATAFLOW or by a bare known
//! name ([`KNOWN_METHODS`]: `fbe` = `dataflow.yaml`, `fisher_eig_only` and `fisher` in
//! `flows/`); the LLM planner joins as a further dataflow file. How a cell's episode runs is
//! the caller's closure (the CLI launches `activemap run`), so this crate stays free of process
//! and transport code.

pub mod grid;
pub mod runner;
pub mod suite;
pub mod table;

pub use grid::{
    Cell, CellState, GridSettings, KNOWN_METHODS, KnownMethod, Method, cell_state, cells,
    known_method,
};
pub use runner::{CellOutcome, CellResult, run_cells};
pub use suite::{Suite, SuiteScene};

use activemap_eval::run_folder::{RunError, RunFolder, write_file};
use std::path::{Path, PathBuf};

/// File names the benchmark writes in its output folder.
pub mod files {
    /// The Markdown tables.
    pub const MARKDOWN: &str = "results.md";
    /// The CSV table.
    pub const CSV: &str = "results.csv";
    /// The paired comparison against the baseline (`table::paired_csv`).
    pub const PAIRED: &str = "paired.csv";

    /// The Markdown tables read at checkpoint `step` (`results_step_N.md`).
    pub fn markdown_at(step: u64) -> String {
        format!("results_step_{step}.md")
    }

    /// The CSV table at checkpoint `step` (`results_step_N.csv`).
    pub fn csv_at(step: u64) -> String {
        format!("results_step_{step}.csv")
    }
}

/// Episodes to run at once by default: one per two cores (an episode keeps about two cores busy:
/// tracker and mapper), at least one.
pub fn default_jobs() -> usize {
    std::thread::available_parallelism().map_or(1, |n| (n.get() / 2).max(1))
}

/// Writes `results.md` (with `heading` under the title), `results.csv` and `paired.csv` into
/// `out`; returns the paths of the first two.
pub fn write_tables(
    out: &Path,
    heading: &str,
    results: &[CellResult],
) -> Result<(PathBuf, PathBuf), RunError> {
    std::fs::create_dir_all(out).map_err(|source| RunError::Io {
        path: out.to_path_buf(),
        source,
    })?;
    let md = out.join(files::MARKDOWN);
    let csv = out.join(files::CSV);
    write_file(&md, table::markdown(heading, results))?;
    write_file(&csv, table::csv(results))?;
    write_file(&out.join(files::PAIRED), table::paired_csv(results))?;
    Ok((md, csv))
}

/// The results read at checkpoint `step` of the same episodes: each complete cell's metrics
/// from its `checkpoints/step_N/metrics.json`; a cell without that checkpoint (an episode that
/// ended earlier, or one run before checkpoints were asked for) is failed with the reason, so
/// the tables list it as unfinished rather than mixing budgets.
pub fn at_checkpoint(out: &Path, results: &[CellResult], step: u64) -> Vec<CellResult> {
    results
        .iter()
        .map(|r| {
            let outcome = match r.outcome.metrics() {
                None => r.outcome.clone(),
                Some(_) => {
                    let checkpoint = RunFolder::new(r.cell.dir(out)).checkpoint(step);
                    match checkpoint.read_metrics() {
                        Ok(Some(m)) => CellOutcome::Reused(Box::new(m)),
                        Ok(None) => CellOutcome::Failed(format!(
                            "{}: missing (no checkpoint evaluated at step {step})",
                            checkpoint.path(RunFolder::METRICS_JSON).display()
                        )),
                        Err(e) => CellOutcome::Failed(e.to_string()),
                    }
                }
            };
            CellResult {
                cell: r.cell.clone(),
                outcome,
            }
        })
        .collect()
}

/// Writes the tables at every checkpoint of the cells' settings (`results_step_N.md` and
/// `.csv`, [`files::markdown_at`]), each read from the same episodes ([`at_checkpoint`]);
/// returns the Markdown paths, by step.
pub fn write_checkpoint_tables(
    out: &Path,
    heading: &str,
    results: &[CellResult],
) -> Result<Vec<PathBuf>, RunError> {
    let mut steps: Vec<u64> = results
        .iter()
        .flat_map(|r| r.cell.settings.checkpoints.iter().copied())
        .collect();
    steps.sort_unstable();
    steps.dedup();
    let mut written = Vec::new();
    for step in steps {
        let at = at_checkpoint(out, results, step);
        let md = out.join(files::markdown_at(step));
        let heading = format!(
            "**At step {step}**: the checkpoints of the same episodes (the last-step tables are \
             in `{}`).\n\n{heading}",
            files::MARKDOWN
        );
        write_file(&md, table::markdown(&heading, &at))?;
        write_file(&out.join(files::csv_at(step)), table::csv(&at))?;
        written.push(md);
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_eval::MetricsReport;

    #[test]
    fn checkpoint_tables_read_each_cells_checkpoint_and_list_the_missing() {
        let out = tempfile::tempdir().unwrap();
        let settings = GridSettings {
            steps: 40,
            eval_views: 4,
            checkpoints: vec![10],
            ..GridSettings::default()
        };
        let method = Method::parse("fbe=dataflow.yaml").unwrap();
        let cells = cells(
            &[method],
            &["house:1".into(), "house:2".into()],
            &[1],
            &settings,
        );
        let report = |completeness: f64| MetricsReport {
            completeness: Some(completeness),
            ..MetricsReport::default()
        };
        // The first cell was checkpointed at step 10 (completeness 0.3); the second was not.
        let checkpoint = RunFolder::new(cells[0].dir(out.path())).checkpoint(10);
        checkpoint.create().unwrap();
        checkpoint.write_metrics(&report(0.3), "").unwrap();
        let results: Vec<CellResult> = cells
            .iter()
            .map(|cell| CellResult {
                cell: cell.clone(),
                outcome: CellOutcome::Ran(Box::new(report(0.9))),
            })
            .collect();
        let at = at_checkpoint(out.path(), &results, 10);
        assert_eq!(at[0].outcome.metrics().unwrap().completeness, Some(0.3));
        match &at[1].outcome {
            CellOutcome::Failed(why) => assert!(why.contains("step 10"), "{why}"),
            other => panic!("{other:?}"),
        }
        let written = write_checkpoint_tables(out.path(), "smoke", &results).unwrap();
        assert_eq!(written, [out.path().join("results_step_10.md")]);
        let md = std::fs::read_to_string(&written[0]).unwrap();
        assert!(
            md.contains("**At step 10**") && md.contains("smoke"),
            "{md}"
        );
        assert!(md.contains("30.0"), "the checkpoint's completeness: {md}");
        assert!(out.path().join("results_step_10.csv").is_file());
    }
}
