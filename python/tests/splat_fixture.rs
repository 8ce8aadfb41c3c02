//! The Rust side of the Python bindings' value checks: a small scene rendered, its Fisher
//! information, the scorer's view information, EIG and localisation cost computed by the Rust
//! crates directly, compared with `tests/data/splat_fixture.json`. pytest
//! (`tests/test_splat.py`) feeds the same inputs through the Python package and compares with the
//! same file, so the two agree value for value. `ACTIVEMAP_BLESS=1 cargo test -p
//! activemap-python` rewrites the file after an intended change of the renderer.

use activemap_active::FisherConfig;
use activemap_active::information::{
    self, ScoringScene, ViewInformation, ViewParts, ViewSettings, localisation_cost,
};
use activemap_geometry::{Intrinsics, Isometry3, UnitQuaternion, Vector3};
use activemap_splat::{
    Camera, DepthModel, FisherMode, Gaussians, Real, RenderOptions, fisher, render,
};
use serde_json::{Value, json};
use std::path::PathBuf;

/// The fixture file.
fn path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/splat_fixture.json")
}

/// One Gaussian in natural units: mean, RGB, quaternion `[w, x, y, z]`, opacity, scales.
type Natural = ([f64; 3], [f64; 3], [f64; 4], f64, [f64; 3]);

/// Six Gaussians in front of a camera at the origin looking along +z, overlapping so that
/// occlusion and several contributors per pixel matter; values exact in float32.
fn scene<T: Real>() -> Gaussians<T> {
    let mut g = Gaussians::<T>::new();
    let items: [Natural; 6] = [
        (
            [0.0, 0.0, 2.0],
            [0.8, 0.2, 0.1],
            [1.0, 0.0, 0.0, 0.0],
            0.75,
            [0.25, 0.125, 0.0625],
        ),
        (
            [0.25, -0.125, 2.5],
            [0.1, 0.7, 0.3],
            [0.875, 0.25, -0.125, 0.375],
            0.5,
            [0.3, 0.2, 0.1],
        ),
        (
            [-0.375, 0.25, 3.0],
            [0.2, 0.3, 0.9],
            [0.5, 0.5, 0.5, -0.5],
            0.875,
            [0.4, 0.35, 0.05],
        ),
        (
            [0.5, 0.375, 1.5],
            [0.9, 0.9, 0.2],
            [0.75, -0.5, 0.25, 0.125],
            0.625,
            [0.1, 0.15, 0.2],
        ),
        (
            [-0.125, -0.5, 2.25],
            [0.5, 0.1, 0.6],
            [1.0, 0.125, 0.25, 0.0],
            0.375,
            [0.2, 0.05, 0.3],
        ),
        (
            [0.0, 0.0, 4.0],
            [0.6, 0.6, 0.6],
            [1.0, 0.0, 0.0, 0.0],
            0.9375,
            [1.0, 1.0, 0.05],
        ),
    ];
    for (mean, rgb, rotation, opacity, scale) in items {
        g.push(mean, rgb, rotation, opacity, scale);
    }
    // The fixture stores float32-exact parameters, so both precisions render the same scene.
    let round = |v: T| T::of(v.to_f64() as f32 as f64);
    for m in &mut g.means {
        *m = m.map(round);
    }
    for s in &mut g.sh_dc {
        *s = s.map(round);
    }
    for r in &mut g.rotations {
        *r = r.map(round);
    }
    for o in &mut g.opacity_logits {
        *o = round(*o);
    }
    for s in &mut g.log_scales {
        *s = s.map(round);
    }
    g
}

/// `T_world_camera`: slightly turned and moved so no axis is special.
fn pose() -> Isometry3<f64> {
    Isometry3::from_parts(
        Vector3::new(0.05, -0.03, 0.1).into(),
        UnitQuaternion::from_euler_angles(0.04, -0.06, 0.02),
    )
}

/// A 32×24 pinhole.
fn intrinsics() -> Intrinsics {
    Intrinsics {
        width: 32,
        height: 24,
        fx: 28.0,
        fy: 28.0,
        cx: 15.5,
        cy: 11.5,
    }
}

/// Flattens rows of values into one list of f64.
fn flat<T: Real, const K: usize>(rows: &[[T; K]]) -> Vec<f64> {
    rows.iter().flatten().map(|v| v.to_f64()).collect()
}

/// Render and Fisher of the scene at precision `T`.
fn splat_values<T: Real>() -> Value {
    let map = scene::<T>();
    let camera = Camera::from_world_pose(intrinsics(), &pose());
    let image = render(&map, &camera, &RenderOptions::default()).unwrap();
    let centre = RenderOptions {
        depth: DepthModel::Centre,
        ..RenderOptions::default()
    };
    let info = fisher(
        &map,
        &render(&map, &camera, &centre).unwrap(),
        FisherMode::PerChannel,
    )
    .unwrap();
    json!({
        "colour": flat(&image.colour),
        "depth": image.depth.iter().map(|v| v.to_f64()).collect::<Vec<_>>(),
        "opacity": image.opacity.iter().map(|v| v.to_f64()).collect::<Vec<_>>(),
        "fisher_colour": flat(&info.colour),
        "fisher_depth": flat(&info.depth),
        "pose_colour": info.pose_colour.transpose().as_slice().to_vec(),
        "pose_depth": info.pose_depth.transpose().as_slice().to_vec(),
    })
}

/// Everything the fixture holds.
fn fixture() -> Value {
    let map = scene::<f32>();
    let defaults = FisherConfig::default();
    let settings = ViewSettings {
        intrinsics: intrinsics(),
        far_m: defaults.far_m,
        depth_weight: defaults.depth_weight,
        localisation: defaults.localisation,
    };
    let view: ViewInformation = information::view_information(
        &ScoringScene::new(map.clone()),
        &pose(),
        &settings,
        ViewParts::DiagonalAndPose,
    )
    .unwrap();
    let mut diagonal = vec![[0.0f64; 14]; map.len()];
    for (i, d) in &view.diagonal {
        diagonal[*i as usize] = *d;
    }
    // A prior I + λ that differs per Gaussian and parameter.
    let prior: Vec<[f64; 14]> = (0..map.len())
        .map(|i| std::array::from_fn(|k| 0.5 + 0.25 * i as f64 + 0.125 * k as f64))
        .collect();
    let pose_info = view.pose.unwrap();
    let m = pose();
    let matrix = m.to_homogeneous();
    json!({
        "gaussians": {
            "means": flat(&map.means),
            "sh_dc": flat(&map.sh_dc),
            "rotations": flat(&map.rotations),
            "opacity_logits": map.opacity_logits.iter().map(|v| *v as f64).collect::<Vec<_>>(),
            "log_scales": flat(&map.log_scales),
        },
        "pose": matrix.transpose().as_slice().to_vec(),
        "intrinsics": [intrinsics().width, intrinsics().height, intrinsics().fx, intrinsics().fy,
            intrinsics().cx, intrinsics().cy],
        "f32": splat_values::<f32>(),
        "f64": splat_values::<f64>(),
        "view_information": {
            "depth_weight": settings.depth_weight,
            "far": settings.far_m,
            "diagonal": flat(&diagonal),
            "pose": pose_info.transpose().as_slice().to_vec(),
            "low_opacity_pixels": view.low_opacity_pixels,
        },
        "prior": flat(&prior),
        "eig": information::eig(&view, prior.as_slice()),
        "localisation_cost": localisation_cost(&pose_info, defaults.degenerate_ratio),
    })
}

#[test]
fn the_fixture_holds_what_the_rust_crates_compute() {
    let now = fixture();
    if std::env::var_os("ACTIVEMAP_BLESS").is_some() {
        std::fs::create_dir_all(path().parent().unwrap()).unwrap();
        std::fs::write(path(), serde_json::to_string_pretty(&now).unwrap() + "\n").unwrap();
        return;
    }
    let text = std::fs::read_to_string(path()).unwrap_or_else(|e| {
        panic!(
            "{}: {e}; write it with ACTIVEMAP_BLESS=1 cargo test -p activemap-python",
            path().display()
        )
    });
    let stored: Value = serde_json::from_str(&text).unwrap();
    assert_eq!(
        stored, now,
        "the renderer, Fisher pass or scorer changed what they compute for the fixture scene; \
         if intended, rewrite it with ACTIVEMAP_BLESS=1 cargo test -p activemap-python"
    );
}
