//! Run-folder readers: every file is parsed and checked by `activemap_eval::run_folder` (the same
//! code `activemap eval` and `activemap report` use); this module only moves the typed rows into
//! numpy arrays (one per column) or, for the nested JSON documents, serialises them back to JSON
//! text for `json.loads`.

use crate::RunFolderError;
use activemap_eval::run_folder::{RunError, RunFolder};
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray2};
use pyo3::exceptions::{PyFileNotFoundError, PyOSError, PyRuntimeError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;

/// Registers the readers in the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(read_summary, m)?)?;
    m.add_function(wrap_pyfunction!(read_metrics, m)?)?;
    m.add_function(wrap_pyfunction!(read_trajectory, m)?)?;
    m.add_function(wrap_pyfunction!(read_map, m)?)?;
    m.add_function(wrap_pyfunction!(read_coverage, m)?)?;
    m.add_function(wrap_pyfunction!(read_fisher, m)?)?;
    m.add_function(wrap_pyfunction!(read_timings, m)?)?;
    m.add_function(wrap_pyfunction!(read_views, m)?)?;
    m.add_function(wrap_pyfunction!(read_test_poses, m)?)?;
    m.add_function(wrap_pyfunction!(read_llm, m)?)?;
    m.add_function(wrap_pyfunction!(checkpoints, m)?)?;
    Ok(())
}

/// A run-folder error as the Python exception that says what went wrong: a missing file as
/// `FileNotFoundError`, a malformed one as `RunFolderError` (a `ValueError`), an OS error as
/// `OSError`; the message always names the file.
pub fn to_py(e: RunError) -> PyErr {
    let message = e.to_string();
    match e {
        RunError::Missing { .. } => PyFileNotFoundError::new_err(message),
        RunError::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound => {
            PyFileNotFoundError::new_err(message)
        }
        RunError::Io { .. } => PyOSError::new_err(message),
        RunError::Malformed { .. } | RunError::MalformedRow { .. } => {
            RunFolderError::new_err(message)
        }
        _ => PyRuntimeError::new_err(message),
    }
}

/// The run folder at `dir`; a folder that does not exist is `FileNotFoundError`.
fn folder(dir: PathBuf) -> PyResult<RunFolder> {
    if !dir.is_dir() {
        return Err(PyFileNotFoundError::new_err(format!(
            "{}: not a run folder (no such directory)",
            dir.display()
        )));
    }
    Ok(RunFolder::new(dir))
}

/// JSON text of a serialisable value (the readers' structs always serialise).
fn json<T: serde::Serialize>(value: &T) -> PyResult<String> {
    serde_json::to_string(value).map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

/// `summary.json` as JSON text, with `"valid"` (no warnings) added as the file has it.
#[pyfunction]
fn read_summary(py: Python<'_>, dir: PathBuf) -> PyResult<String> {
    let run = folder(dir)?;
    let summary = py.detach(|| run.read_summary()).map_err(to_py)?;
    let mut value =
        serde_json::to_value(&summary).map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    if let Some(object) = value.as_object_mut() {
        object.insert("valid".into(), summary.is_valid().into());
    }
    json(&value)
}

/// `metrics.json` as JSON text (as `activemap eval` writes it), `None` before `activemap eval`.
#[pyfunction]
fn read_metrics(py: Python<'_>, dir: PathBuf) -> PyResult<Option<String>> {
    let run = folder(dir)?;
    let report = py.detach(|| run.read_metrics()).map_err(to_py)?;
    Ok(report.map(|r| r.to_json()))
}

/// The TUM trajectory `name` as an `(N, 8)` float64 array `t tx ty tz qx qy qz qw`
/// (`T_world_camera`, the file's column order).
#[pyfunction]
fn read_trajectory<'py>(
    py: Python<'py>,
    dir: PathBuf,
    name: &str,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let run = folder(dir)?;
    let rows = py
        .detach(|| {
            let trajectory = run.read_trajectory(name)?;
            let mut rows = Vec::with_capacity(trajectory.len() * 8);
            for (t, pose) in trajectory.stamps.iter().zip(&trajectory.poses) {
                let p = pose.translation.vector;
                let q = pose.rotation.coords; // x, y, z, w
                rows.extend_from_slice(&[*t, p.x, p.y, p.z, q.x, q.y, q.z, q.w]);
            }
            Ok::<_, RunError>(rows)
        })
        .map_err(to_py)?;
    let n = rows.len() / 8;
    let array = Array2::from_shape_vec((n, 8), rows).expect("8 columns per pose");
    Ok(array.into_pyarray(py))
}

/// `(N, k)` array of `rows` (k = the arrays' length), moved into numpy without a copy.
fn columns<'py, T: numpy::Element, const K: usize>(
    py: Python<'py>,
    rows: Vec<[T; K]>,
) -> Bound<'py, PyArray2<T>> {
    let n = rows.len();
    Array2::from_shape_vec((n, K), rows.into_flattened())
        .expect("K columns per row")
        .into_pyarray(py)
}

/// `map.ply` as a dict of arrays: `means` (N, 3), `sh_dc` (N, 3), `rotations` (N, 4) `[w, x, y,
/// z]`, `opacity_logits` (N,), `log_scales` (N, 3), all float32 as stored, and `flags` (N,) uint8.
#[pyfunction]
fn read_map<'py>(py: Python<'py>, dir: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    let run = folder(dir)?;
    let map = py.detach(|| run.read_map()).map_err(to_py)?;
    let out = PyDict::new(py);
    out.set_item("means", columns(py, map.means))?;
    out.set_item("sh_dc", columns(py, map.sh_dc))?;
    out.set_item("rotations", columns(py, map.rotations))?;
    out.set_item("opacity_logits", map.opacity_logits.into_pyarray(py))?;
    out.set_item("log_scales", columns(py, map.log_scales))?;
    out.set_item("flags", map.flags.into_pyarray(py))?;
    Ok(out)
}

/// Column of an optional value as float64, NaN where absent.
fn optional(values: impl Iterator<Item = Option<f64>>) -> Vec<f64> {
    values.map(|v| v.unwrap_or(f64::NAN)).collect()
}

/// `coverage.csv` as `{"step": uint64, "coverage": float64}`, `None` when absent.
#[pyfunction]
fn read_coverage<'py>(py: Python<'py>, dir: PathBuf) -> PyResult<Option<Bound<'py, PyDict>>> {
    let run = folder(dir)?;
    let Some(rows) = py.detach(|| run.read_coverage()).map_err(to_py)? else {
        return Ok(None);
    };
    let out = PyDict::new(py);
    let step: Vec<u64> = rows.iter().map(|r| r.step).collect();
    let coverage: Vec<f64> = rows.iter().map(|r| r.coverage).collect();
    out.set_item("step", step.into_pyarray(py))?;
    out.set_item("coverage", coverage.into_pyarray(py))?;
    Ok(Some(out))
}

/// `fisher.csv` as one array per column (the file's header order), `None` when the run made no
/// Fisher replan. Optional reals are float64 with NaN where empty, `actions` too.
#[pyfunction]
fn read_fisher<'py>(py: Python<'py>, dir: PathBuf) -> PyResult<Option<Bound<'py, PyDict>>> {
    let run = folder(dir)?;
    let Some(rows) = py.detach(|| run.read_fisher()).map_err(to_py)? else {
        return Ok(None);
    };
    let out = PyDict::new(py);
    let r = &rows;
    out.set_item(
        "step",
        r.iter()
            .map(|r| r.step)
            .collect::<Vec<_>>()
            .into_pyarray(py),
    )?;
    out.set_item(
        "refine",
        r.iter()
            .map(|r| r.refine)
            .collect::<Vec<_>>()
            .into_pyarray(py),
    )?;
    out.set_item(
        "candidates",
        r.iter()
            .map(|r| r.candidates)
            .collect::<Vec<_>>()
            .into_pyarray(py),
    )?;
    out.set_item(
        "paths",
        r.iter()
            .map(|r| r.paths)
            .collect::<Vec<_>>()
            .into_pyarray(py),
    )?;
    out.set_item(
        "chosen",
        r.iter()
            .map(|r| r.chosen)
            .collect::<Vec<_>>()
            .into_pyarray(py),
    )?;
    out.set_item(
        "objective",
        optional(r.iter().map(|r| r.objective)).into_pyarray(py),
    )?;
    out.set_item(
        "eig_sum",
        optional(r.iter().map(|r| r.eig_sum)).into_pyarray(py),
    )?;
    out.set_item(
        "eig_first",
        optional(r.iter().map(|r| r.eig_first)).into_pyarray(py),
    )?;
    out.set_item(
        "c_local_sum",
        optional(r.iter().map(|r| r.c_local_sum)).into_pyarray(py),
    )?;
    out.set_item(
        "actions",
        optional(r.iter().map(|r| r.actions.map(f64::from))).into_pyarray(py),
    )?;
    out.set_item(
        "total_ms",
        r.iter()
            .map(|r| r.total_ms)
            .collect::<Vec<_>>()
            .into_pyarray(py),
    )?;
    out.set_item(
        "model_reused",
        r.iter()
            .map(|r| r.model_reused)
            .collect::<Vec<_>>()
            .into_pyarray(py),
    )?;
    out.set_item(
        "fallback",
        r.iter()
            .map(|r| r.fallback)
            .collect::<Vec<_>>()
            .into_pyarray(py),
    )?;
    Ok(Some(out))
}

/// `timings.csv` as `{"stage": list[str], "seconds": float64, "calls": uint64}` (one row per
/// node process, as written), `None` when the run recorded none.
#[pyfunction]
fn read_timings<'py>(py: Python<'py>, dir: PathBuf) -> PyResult<Option<Bound<'py, PyDict>>> {
    let run = folder(dir)?;
    let Some(rows) = py.detach(|| run.read_timings()).map_err(to_py)? else {
        return Ok(None);
    };
    let out = PyDict::new(py);
    out.set_item(
        "stage",
        rows.iter().map(|r| r.stage.clone()).collect::<Vec<_>>(),
    )?;
    out.set_item(
        "seconds",
        rows.iter()
            .map(|r| r.seconds)
            .collect::<Vec<_>>()
            .into_pyarray(py),
    )?;
    out.set_item(
        "calls",
        rows.iter()
            .map(|r| r.calls)
            .collect::<Vec<_>>()
            .into_pyarray(py),
    )?;
    Ok(Some(out))
}

/// `eval/test_poses.csv` (per test view: `view`, `x_m`, `y_m`, `yaw_deg`: where it was taken, in
/// the world frame), `None` before `activemap eval` or for runs evaluated before the file existed.
#[pyfunction]
fn read_test_poses<'py>(py: Python<'py>, dir: PathBuf) -> PyResult<Option<Bound<'py, PyDict>>> {
    let run = folder(dir)?;
    let Some(rows) = py.detach(|| run.read_test_poses()).map_err(to_py)? else {
        return Ok(None);
    };
    let out = PyDict::new(py);
    let view: Vec<u64> = rows.iter().map(|r| r.view as u64).collect();
    out.set_item("view", view.into_pyarray(py))?;
    for (name, value) in [
        ("x_m", rows.iter().map(|r| r.x_m).collect::<Vec<_>>()),
        ("y_m", rows.iter().map(|r| r.y_m).collect()),
        ("yaw_deg", rows.iter().map(|r| r.yaw_deg).collect()),
    ] {
        out.set_item(name, value.into_pyarray(py))?;
    }
    Ok(Some(out))
}

/// `eval/views.csv` (per test view: `view`, `psnr_db`, `ssim`, `lpips`, `depth_mae_m`; NaN where
/// not computed), `None` before `activemap eval`.
#[pyfunction]
fn read_views<'py>(py: Python<'py>, dir: PathBuf) -> PyResult<Option<Bound<'py, PyDict>>> {
    let run = folder(dir)?;
    let Some(rows) = py.detach(|| run.read_views()).map_err(to_py)? else {
        return Ok(None);
    };
    let out = PyDict::new(py);
    let view: Vec<u64> = rows.iter().map(|r| r.view as u64).collect();
    out.set_item("view", view.into_pyarray(py))?;
    out.set_item(
        "psnr_db",
        rows.iter()
            .map(|r| r.psnr_db)
            .collect::<Vec<_>>()
            .into_pyarray(py),
    )?;
    out.set_item(
        "ssim",
        rows.iter()
            .map(|r| r.ssim)
            .collect::<Vec<_>>()
            .into_pyarray(py),
    )?;
    out.set_item(
        "lpips",
        optional(rows.iter().map(|r| r.lpips)).into_pyarray(py),
    )?;
    out.set_item(
        "depth_mae_m",
        optional(rows.iter().map(|r| r.depth_mae_m)).into_pyarray(py),
    )?;
    Ok(Some(out))
}

/// `llm.jsonl` as JSON text of a list of exchanges, `None` when the run made none.
#[pyfunction]
fn read_llm(py: Python<'_>, dir: PathBuf) -> PyResult<Option<String>> {
    let run = folder(dir)?;
    let records = py.detach(|| run.read_llm()).map_err(to_py)?;
    records.map(|r| json(&r)).transpose()
}

/// The run's checkpoints as `(step, folder)` pairs, ascending.
#[pyfunction]
fn checkpoints(dir: PathBuf) -> PyResult<Vec<(u64, PathBuf)>> {
    let run = folder(dir)?;
    let list = run.checkpoints().map_err(to_py)?;
    Ok(list
        .into_iter()
        .map(|(step, f)| (step, f.dir().to_path_buf()))
        .collect())
}
