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

use activemap_eval::run_folder::{RunError, write_file};
use std::path::{Path, PathBuf};

/// File names the benchmark writes in its output folder.
pub mod files {
    /// The Markdown tables.
    pub const MARKDOWN: &str = "results.md";
    /// The CSV table.
    pub const CSV: &str = "results.csv";
    /// The paired comparison against the baseline (`table::paired_csv`).
    pub const PAIRED: &str = "paired.csv";
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
