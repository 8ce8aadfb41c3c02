//! The CPU renderer and the Fisher information on numpy arrays.
//!
//! Each entry point exists for float32 (`*_f32`, the production precision, what `map.ply`
//! holds) and float64 (`*_f64`, for gradient and finite-difference checks); the Python wrapper
//! picks one from the dtype of `means`. Inputs are the 14 raw parameters of
//! `activemap_splat::gaussians` as C-contiguous arrays; outputs are the Rust vectors moved into
//! numpy.

use activemap_active::FisherConfig;
use activemap_active::information::{
    self, Diagonal, ScoringScene, ViewInformation, ViewParts, ViewSettings,
};
use activemap_geometry::{Intrinsics, Isometry3, Matrix3, UnitQuaternion};
use activemap_splat::{Camera, FisherMode, Gaussians, Real, RenderOptions, SplatError};
use nalgebra::{Matrix6, Rotation3, Translation3};
use numpy::ndarray::{Array2, Array3};
use numpy::{
    Element, IntoPyArray, PyArray2, PyArray3, PyReadonlyArray1, PyReadonlyArray2,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Registers the functions in the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(render_f32, m)?)?;
    m.add_function(wrap_pyfunction!(render_f64, m)?)?;
    m.add_function(wrap_pyfunction!(fisher_f32, m)?)?;
    m.add_function(wrap_pyfunction!(fisher_f64, m)?)?;
    m.add_function(wrap_pyfunction!(view_information_f32, m)?)?;
    m.add_function(wrap_pyfunction!(view_information_f64, m)?)?;
    m.add_function(wrap_pyfunction!(eig, m)?)?;
    m.add_function(wrap_pyfunction!(localisation_cost, m)?)?;
    m.add_function(wrap_pyfunction!(bench_scene, m)?)?;
    m.add_function(wrap_pyfunction!(rust_render_seconds, m)?)?;
    Ok(())
}

/// The six intrinsics `(width, height, fx, fy, cx, cy)` as the Python side passes them.
type IntrinsicsTuple = (u32, u32, f64, f64, f64, f64);

/// A renderer error as `ValueError` (bad lengths, camera) or `RuntimeError`.
fn splat_err(e: SplatError) -> PyErr {
    match e {
        SplatError::Length { .. } | SplatError::Camera(_) => PyValueError::new_err(e.to_string()),
        _ => PyRuntimeError::new_err(e.to_string()),
    }
}

/// The rows of `array`, which must be C-contiguous of shape (N, `K`), read in place; `what`
/// names it in errors.
fn rows<'a, T: Element, const K: usize>(
    array: &'a PyReadonlyArray2<'_, T>,
    what: &str,
) -> PyResult<&'a [[T; K]]> {
    let shape = array.shape();
    if shape[1] != K {
        return Err(PyValueError::new_err(format!(
            "{what} must have shape (N, {K}), got {shape:?}"
        )));
    }
    let flat = array
        .as_slice()
        .map_err(|_| PyValueError::new_err(format!("{what} must be a C-contiguous array")))?;
    let (chunks, rest) = flat.as_chunks::<K>();
    debug_assert!(rest.is_empty());
    Ok(chunks)
}

/// The Gaussians of the raw parameter arrays, checked for shapes and equal lengths.
fn gaussians<T: Element + Real>(
    means: &PyReadonlyArray2<'_, T>,
    sh_dc: &PyReadonlyArray2<'_, T>,
    rotations: &PyReadonlyArray2<'_, T>,
    opacity_logits: &PyReadonlyArray1<'_, T>,
    log_scales: &PyReadonlyArray2<'_, T>,
    flags: Option<&PyReadonlyArray1<'_, u8>>,
) -> PyResult<Gaussians<T>> {
    let means = rows::<T, 3>(means, "means")?;
    let n = means.len();
    let opacity = opacity_logits
        .as_slice()
        .map_err(|_| PyValueError::new_err("opacity_logits must be a C-contiguous 1-D array"))?;
    let flags = match flags {
        Some(f) => f
            .as_slice()
            .map_err(|_| PyValueError::new_err("flags must be a C-contiguous 1-D array"))?
            .to_vec(),
        None => vec![0; n],
    };
    let map = Gaussians {
        means: means.to_vec(),
        sh_dc: rows::<T, 3>(sh_dc, "sh_dc")?.to_vec(),
        rotations: rows::<T, 4>(rotations, "rotations")?.to_vec(),
        opacity_logits: opacity.to_vec(),
        log_scales: rows::<T, 3>(log_scales, "log_scales")?.to_vec(),
        flags,
    };
    map.validate().map_err(splat_err)?;
    Ok(map)
}

/// `T_world_camera` from a 4×4 homogeneous float64 matrix: the bottom row must be `0 0 0 1` and
/// the rotation block orthonormal with determinant +1 (to 1e-6).
fn pose(matrix: &PyReadonlyArray2<'_, f64>) -> PyResult<Isometry3<f64>> {
    let m = matrix.as_array();
    if m.shape() != [4, 4] {
        return Err(PyValueError::new_err(format!(
            "pose must be a 4x4 matrix (T_world_camera), got shape {:?}",
            m.shape()
        )));
    }
    let bottom = [m[[3, 0]], m[[3, 1]], m[[3, 2]], m[[3, 3]]];
    if bottom != [0.0, 0.0, 0.0, 1.0] {
        return Err(PyValueError::new_err(format!(
            "pose: the bottom row of a rigid transform is [0, 0, 0, 1], got {bottom:?}"
        )));
    }
    let r = Matrix3::from_fn(|i, j| m[[i, j]]);
    let off = (r.transpose() * r - Matrix3::identity()).abs().max();
    if !(off < 1e-6 && (r.determinant() - 1.0).abs() < 1e-6) {
        return Err(PyValueError::new_err(format!(
            "pose: the 3x3 rotation block is not a rotation (RᵀR − I up to {off:.2e}, det {:.6})",
            r.determinant()
        )));
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    Ok(Isometry3::from_parts(
        Translation3::new(m[[0, 3]], m[[1, 3]], m[[2, 3]]),
        rotation,
    ))
}

/// The intrinsics of the tuple.
fn intrinsics(k: IntrinsicsTuple) -> Intrinsics {
    let (width, height, fx, fy, cx, cy) = k;
    Intrinsics {
        width,
        height,
        fx,
        fy,
        cx,
        cy,
    }
}

/// The camera at `T_world_camera` with its near and far planes.
fn camera(k: IntrinsicsTuple, world_from_camera: &Isometry3<f64>, near: f64, far: f64) -> Camera {
    let mut camera = Camera::from_world_pose(intrinsics(k), world_from_camera).with_far(far);
    camera.near = near;
    camera
}

/// The options of a render.
fn options(exposure: (f64, f64), exclude_flags: u8) -> RenderOptions {
    RenderOptions {
        exposure: [exposure.0, exposure.1],
        exclude_flags,
        ..Default::default()
    }
}

/// `(H, W, 3)` colour, `(H, W)` depth and `(H, W)` opacity of a render, moved into numpy.
type Images<'py, T> = (
    Bound<'py, PyArray3<T>>,
    Bound<'py, PyArray2<T>>,
    Bound<'py, PyArray2<T>>,
);

/// Renders and hands the three images to numpy.
#[allow(clippy::too_many_arguments)]
fn render_impl<'py, T: Element + Real>(
    py: Python<'py>,
    map: Gaussians<T>,
    world_from_camera: PyReadonlyArray2<'py, f64>,
    k: IntrinsicsTuple,
    exposure: (f64, f64),
    near: f64,
    far: f64,
    exclude_flags: u8,
    depth_model: &str,
) -> PyResult<Images<'py, T>> {
    let camera = camera(k, &pose(&world_from_camera)?, near, far);
    let depth = match depth_model {
        "plane" => activemap_splat::DepthModel::Plane,
        "centre" => activemap_splat::DepthModel::Centre,
        other => {
            return Err(PyValueError::new_err(format!(
                "depth_model must be 'plane' or 'centre', got {other:?}"
            )));
        }
    };
    let options = RenderOptions {
        depth,
        ..options(exposure, exclude_flags)
    };
    let out = py
        .detach(|| activemap_splat::render(&map, &camera, &options))
        .map_err(splat_err)?;
    let (h, w) = (out.height, out.width);
    let colour = Array3::from_shape_vec((h, w, 3), out.colour.into_flattened())
        .expect("H·W pixels")
        .into_pyarray(py);
    let depth = Array2::from_shape_vec((h, w), out.depth)
        .expect("H·W pixels")
        .into_pyarray(py);
    let opacity = Array2::from_shape_vec((h, w), out.opacity)
        .expect("H·W pixels")
        .into_pyarray(py);
    Ok((colour, depth, opacity))
}

/// The Fisher information of a view as a dict of numpy arrays.
#[allow(clippy::too_many_arguments)]
fn fisher_impl<'py, T: Element + Real>(
    py: Python<'py>,
    map: Gaussians<T>,
    world_from_camera: PyReadonlyArray2<'py, f64>,
    k: IntrinsicsTuple,
    mode: &str,
    exposure: (f64, f64),
    near: f64,
    far: f64,
    exclude_flags: u8,
) -> PyResult<Bound<'py, PyDict>> {
    let mode = match mode {
        "per_channel" => FisherMode::PerChannel,
        "channel_sum" => FisherMode::ChannelSum,
        other => {
            return Err(PyValueError::new_err(format!(
                "mode must be 'per_channel' or 'channel_sum', got {other:?}"
            )));
        }
    };
    let camera = camera(k, &pose(&world_from_camera)?, near, far);
    // The Fisher pass differentiates the centre depth model.
    let options = RenderOptions {
        depth: activemap_splat::DepthModel::Centre,
        ..options(exposure, exclude_flags)
    };
    let info = py
        .detach(|| {
            let image = activemap_splat::render(&map, &camera, &options)?;
            activemap_splat::fisher(&map, &image, mode)
        })
        .map_err(splat_err)?;
    let n = info.colour.len();
    let out = PyDict::new(py);
    let diag = |v: Vec<[T; 14]>| {
        Array2::from_shape_vec((n, 14), v.into_flattened())
            .expect("14 parameters per Gaussian")
            .into_pyarray(py)
    };
    out.set_item("colour", diag(info.colour))?;
    out.set_item("depth", diag(info.depth))?;
    out.set_item("pose_colour", matrix6(py, &info.pose_colour))?;
    out.set_item("pose_depth", matrix6(py, &info.pose_depth))?;
    Ok(out)
}

/// A 6×6 matrix as a row-major numpy array.
fn matrix6<'py>(py: Python<'py>, m: &Matrix6<f64>) -> Bound<'py, PyArray2<f64>> {
    Array2::from_shape_fn((6, 6), |(i, j)| m[(i, j)]).into_pyarray(py)
}

/// The scorer's normalised view information as a dict: `diagonal` (N, 14) float64, zero for
/// Gaussians the view does not inform, `pose` (6, 6), `low_opacity_pixels`.
fn view_information_impl<'py, T: Element + Real>(
    py: Python<'py>,
    map: Gaussians<T>,
    world_from_camera: PyReadonlyArray2<'py, f64>,
    k: IntrinsicsTuple,
    depth_weight: f64,
    far: f64,
) -> PyResult<Bound<'py, PyDict>> {
    if !(depth_weight.is_finite() && depth_weight >= 0.0) {
        return Err(PyValueError::new_err(format!(
            "depth_weight must be finite and non-negative, got {depth_weight}"
        )));
    }
    if far.is_nan() || far <= 0.0 {
        return Err(PyValueError::new_err(format!(
            "far must be positive, got {far}"
        )));
    }
    let world_from_camera = pose(&world_from_camera)?;
    let settings = ViewSettings {
        intrinsics: intrinsics(k),
        far_m: far,
        depth_weight,
        localisation: Default::default(),
    };
    let n = map.len();
    let view = py
        .detach(|| {
            let scene = ScoringScene::new(map);
            information::view_information(
                &scene,
                &world_from_camera,
                &settings,
                ViewParts::DiagonalAndPose,
            )
        })
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    let mut dense = vec![[0.0f64; 14]; n];
    for (i, d) in &view.diagonal {
        dense[*i as usize] = *d;
    }
    let out = PyDict::new(py);
    out.set_item(
        "diagonal",
        Array2::from_shape_vec((n, 14), dense.into_flattened())
            .expect("14 parameters per Gaussian")
            .into_pyarray(py),
    )?;
    out.set_item(
        "pose",
        matrix6(py, &view.pose.unwrap_or_else(Matrix6::zeros)),
    )?;
    out.set_item("low_opacity_pixels", view.low_opacity_pixels)?;
    Ok(out)
}

macro_rules! splat_functions {
    ($t:ty, $render:ident, $fisher:ident, $info:ident) => {
        /// Renders colour (H, W, 3), depth (H, W) and opacity (H, W) (`activemap_splat::render`;
        /// `depth_model` `plane`, the maps' default, or `centre`).
        #[pyfunction]
        #[pyo3(signature = (means, sh_dc, rotations, opacity_logits, log_scales, flags,
            world_from_camera, intrinsics, exposure=(0.0, 0.0), near=0.01, far=f64::INFINITY,
            exclude_flags=0, depth_model="plane"))]
        #[allow(clippy::too_many_arguments)]
        fn $render<'py>(
            py: Python<'py>,
            means: PyReadonlyArray2<'py, $t>,
            sh_dc: PyReadonlyArray2<'py, $t>,
            rotations: PyReadonlyArray2<'py, $t>,
            opacity_logits: PyReadonlyArray1<'py, $t>,
            log_scales: PyReadonlyArray2<'py, $t>,
            flags: Option<PyReadonlyArray1<'py, u8>>,
            world_from_camera: PyReadonlyArray2<'py, f64>,
            intrinsics: IntrinsicsTuple,
            exposure: (f64, f64),
            near: f64,
            far: f64,
            exclude_flags: u8,
            depth_model: &str,
        ) -> PyResult<Images<'py, $t>> {
            let map = gaussians(
                &means,
                &sh_dc,
                &rotations,
                &opacity_logits,
                &log_scales,
                flags.as_ref(),
            )?;
            render_impl(
                py,
                map,
                world_from_camera,
                intrinsics,
                exposure,
                near,
                far,
                exclude_flags,
                depth_model,
            )
        }

        /// The Fisher information of the rendered view (`activemap_splat::fisher`, of a render
        /// with the centre depth model): per-Gaussian colour and depth diagonals (N, 14) and the
        /// 6×6 pose information of each.
        #[pyfunction]
        #[pyo3(signature = (means, sh_dc, rotations, opacity_logits, log_scales, flags,
            world_from_camera, intrinsics, mode="per_channel", exposure=(0.0, 0.0), near=0.01,
            far=f64::INFINITY, exclude_flags=0))]
        #[allow(clippy::too_many_arguments)]
        fn $fisher<'py>(
            py: Python<'py>,
            means: PyReadonlyArray2<'py, $t>,
            sh_dc: PyReadonlyArray2<'py, $t>,
            rotations: PyReadonlyArray2<'py, $t>,
            opacity_logits: PyReadonlyArray1<'py, $t>,
            log_scales: PyReadonlyArray2<'py, $t>,
            flags: Option<PyReadonlyArray1<'py, u8>>,
            world_from_camera: PyReadonlyArray2<'py, f64>,
            intrinsics: IntrinsicsTuple,
            mode: &str,
            exposure: (f64, f64),
            near: f64,
            far: f64,
            exclude_flags: u8,
        ) -> PyResult<Bound<'py, PyDict>> {
            let map = gaussians(
                &means,
                &sh_dc,
                &rotations,
                &opacity_logits,
                &log_scales,
                flags.as_ref(),
            )?;
            fisher_impl(
                py,
                map,
                world_from_camera,
                intrinsics,
                mode,
                exposure,
                near,
                far,
                exclude_flags,
            )
        }

        /// The scorer's information of one view (`activemap_active::information`).
        #[pyfunction]
        #[pyo3(signature = (means, sh_dc, rotations, opacity_logits, log_scales, flags,
            world_from_camera, intrinsics, depth_weight=None, far=None))]
        #[allow(clippy::too_many_arguments)]
        fn $info<'py>(
            py: Python<'py>,
            means: PyReadonlyArray2<'py, $t>,
            sh_dc: PyReadonlyArray2<'py, $t>,
            rotations: PyReadonlyArray2<'py, $t>,
            opacity_logits: PyReadonlyArray1<'py, $t>,
            log_scales: PyReadonlyArray2<'py, $t>,
            flags: Option<PyReadonlyArray1<'py, u8>>,
            world_from_camera: PyReadonlyArray2<'py, f64>,
            intrinsics: IntrinsicsTuple,
            depth_weight: Option<f64>,
            far: Option<f64>,
        ) -> PyResult<Bound<'py, PyDict>> {
            // The scorer's defaults (`FisherConfig`): what a `fisher` run uses.
            let defaults = FisherConfig::default();
            let depth_weight = depth_weight.unwrap_or(defaults.depth_weight);
            let far = far.unwrap_or(defaults.far_m);
            let map = gaussians(
                &means,
                &sh_dc,
                &rotations,
                &opacity_logits,
                &log_scales,
                flags.as_ref(),
            )?;
            view_information_impl(py, map, world_from_camera, intrinsics, depth_weight, far)
        }
    };
}

splat_functions!(f32, render_f32, fisher_f32, view_information_f32);
splat_functions!(f64, render_f64, fisher_f64, view_information_f64);

/// The view EIG `Σ_i Σ_k H_ik / I_ik` (`activemap_active::information::eig`) of a view's
/// diagonal `H` (N, 14) against the prior `I + λ` (N, 14, positive where `H` is non-zero).
#[pyfunction]
fn eig(
    py: Python<'_>,
    diagonal: PyReadonlyArray2<'_, f64>,
    prior: PyReadonlyArray2<'_, f64>,
) -> PyResult<f64> {
    let h = rows::<f64, 14>(&diagonal, "diagonal")?;
    let p = rows::<f64, 14>(&prior, "prior")?;
    if h.len() != p.len() {
        return Err(PyValueError::new_err(format!(
            "diagonal has {} rows but prior has {}: one row per Gaussian in both",
            h.len(),
            p.len()
        )));
    }
    let view = ViewInformation {
        diagonal: h
            .iter()
            .enumerate()
            .filter(|(_, d)| d.iter().any(|v| *v != 0.0))
            .map(|(i, d)| (i as u32, *d))
            .collect(),
        pose: None,
        low_opacity_pixels: 0,
    };
    for (i, _) in &view.diagonal {
        let row = &p[*i as usize];
        if let Some(v) = row.iter().find(|v| !(v.is_finite() && **v > 0.0)) {
            return Err(PyValueError::new_err(format!(
                "prior row {i} holds {v}: the prior I + λ must be positive and finite where the \
                 diagonal is non-zero"
            )));
        }
    }
    let prior: &[Diagonal] = p;
    Ok(py.detach(|| information::eig(&view, prior)))
}

/// The localisation cost `−log det` of a 6×6 pose information
/// (`activemap_active::information::localisation_cost`), +∞ when degenerate.
#[pyfunction]
#[pyo3(signature = (pose_information, degenerate_ratio=None))]
fn localisation_cost(
    pose_information: PyReadonlyArray2<'_, f64>,
    degenerate_ratio: Option<f64>,
) -> PyResult<f64> {
    let degenerate_ratio = degenerate_ratio.unwrap_or(FisherConfig::default().degenerate_ratio);
    let m = pose_information.as_array();
    if m.shape() != [6, 6] {
        return Err(PyValueError::new_err(format!(
            "pose_information must be 6x6, got shape {:?}",
            m.shape()
        )));
    }
    let matrix = Matrix6::from_fn(|i, j| m[[i, j]]);
    Ok(information::localisation_cost(&matrix, degenerate_ratio))
}

/// The renderer benchmark's scene (`activemap_splat::bench::scene`: `n` Gaussians in the 90°
/// frustum of a camera at the origin looking along +z, seed 7) as a dict of float32 arrays.
#[pyfunction]
fn bench_scene(py: Python<'_>, n: usize) -> PyResult<Bound<'_, PyDict>> {
    let map = py.detach(|| activemap_splat::bench::scene(n));
    let out = PyDict::new(py);
    let cols = |rows: Vec<[f32; 3]>| {
        let n = rows.len();
        Array2::from_shape_vec((n, 3), rows.into_flattened())
            .expect("3 columns")
            .into_pyarray(py)
    };
    out.set_item("means", cols(map.means))?;
    out.set_item("sh_dc", cols(map.sh_dc))?;
    let n = map.rotations.len();
    out.set_item(
        "rotations",
        Array2::from_shape_vec((n, 4), map.rotations.into_flattened())
            .expect("4 columns")
            .into_pyarray(py),
    )?;
    out.set_item("opacity_logits", map.opacity_logits.into_pyarray(py))?;
    out.set_item("log_scales", cols(map.log_scales))?;
    Ok(out)
}

/// Seconds of each of `repeats` calls of the Rust `activemap_splat::render` alone on the
/// float32 Gaussians of the arrays (gathered once, outside the timing), default options: the
/// baseline of `python/benchmarks/render_ratio.py`.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn rust_render_seconds<'py>(
    py: Python<'py>,
    means: PyReadonlyArray2<'py, f32>,
    sh_dc: PyReadonlyArray2<'py, f32>,
    rotations: PyReadonlyArray2<'py, f32>,
    opacity_logits: PyReadonlyArray1<'py, f32>,
    log_scales: PyReadonlyArray2<'py, f32>,
    world_from_camera: PyReadonlyArray2<'py, f64>,
    intrinsics: IntrinsicsTuple,
    repeats: usize,
) -> PyResult<Vec<f64>> {
    let map = gaussians(
        &means,
        &sh_dc,
        &rotations,
        &opacity_logits,
        &log_scales,
        None,
    )?;
    let camera = camera(intrinsics, &pose(&world_from_camera)?, 0.01, f64::INFINITY);
    py.detach(|| {
        (0..repeats)
            .map(|_| {
                let t = std::time::Instant::now();
                let out = activemap_splat::render(&map, &camera, &RenderOptions::default())?;
                let seconds = t.elapsed().as_secs_f64();
                drop(out);
                Ok(seconds)
            })
            .collect::<Result<Vec<f64>, SplatError>>()
    })
    .map_err(splat_err)
}
