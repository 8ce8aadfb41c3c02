//! `activemap bench results` as a library: methods × scenes × seeds of exploration episodes,
//! each evaluated (SPEC §8), summarised in the layout of the paper's Table 1.
//!
//! - [`grid`]: the cells, their run folders and whether each is complete;
//! - [`runner`]: runs the unfinished cells on worker threads, resuming after an interruption;
//! - [`table`]: `results.md` (Table 1 layout, the ablation, per scene) and `results.csv`
//!   (mean ± spread over seeds).
//!
//! A method is a dataflow file, named on the command line as NAME=DATAFLOW or by a bare known
//! name ([`KNOWN_METHODS`]: `fbe` = `dataflow.yaml`, `fisher_eig_only` and `fisher` in
//! `flows/`); the LLM planner joins as a further dataflow file. How a cell's episode runs is
//! the caller's closure (the CLI launches `activemap run`), so this crate stays free of process
//! and transport code.

pub mod grid;
pub mod runner;
pub mod table;

pub use grid::{
    Cell, CellState, GridSettings, KNOWN_METHODS, KnownMethod, Method, cell_state, cells,
    known_method,
};
pub use runner::{CellOutcome, CellResult, run_cells};

use activemap_eval::run_folder::{RunError, write_file};
use std::path::{Path, PathBuf};

/// File names the benchmark writes in its output folder.
pub mod files {
    /// The Markdown tables.
    pub const MARKDOWN: &str = "results.md";
    /// The CSV table.
    pub const CSV: &str = "results.csv";
}

/// Episodes to run at once by default: one per two cores (an episode keeps about two cores busy:
/// tracker and mapper), at least one.
pub fn default_jobs() -> usize {
    std::thread::available_parallelism().map_or(1, |n| (n.get() / 2).max(1))
}

/// Writes `results.md` (with `heading` under the title) and `results.csv` into `out`; returns
/// their paths.
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
    Ok((md, csv))
}
