//! `activemap._native`: the Rust half of the `activemap` Python package (issue 38).
//!
//! Thin bindings over the crates that already do the work, so every format and formula has one
//! copy:
//! - [`run`]: a run folder read through `activemap_eval::run_folder::RunFolder` (summary,
//!   metrics, trajectories, map, coverage, Fisher replans, timings, per-view metrics, LLM
//!   exchanges) into numpy arrays, column dictionaries and JSON text;
//! - [`splat`]: the CPU renderer (`activemap_splat::render`), the Fisher information of a view
//!   (`activemap_splat::fisher`) and the scorer's normalised view information, EIG and
//!   localisation cost (`activemap_active::information`) on numpy arrays.
//!
//! Arrays cross the boundary without copies where numpy allows: outputs are the Rust vectors
//! themselves handed to numpy; inputs are read in place (C-contiguous arrays of the expected
//! dtype; the Python wrapper converts anything else once) and gathered into the renderer's
//! structure of arrays with one `memcpy` per parameter group. Every call into Rust that does
//! real work releases the GIL (`Python::detach`).

use pyo3::prelude::*;

pub mod run;
pub mod splat;

pyo3::create_exception!(
    activemap,
    RunFolderError,
    pyo3::exceptions::PyValueError,
    "A run folder's file is there but malformed (the message names the file and, for a CSV or \
     JSON-lines row, its line)."
);

/// The extension module `activemap._native`.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("RunFolderError", m.py().get_type::<RunFolderError>())?;
    run::register(m)?;
    splat::register(m)?;
    Ok(())
}
