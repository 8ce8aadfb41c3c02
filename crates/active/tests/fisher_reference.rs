//! The scorer's Fisher terms against brute force (f64): the view EIG from finite-difference
//! Jacobians of every rendered pixel w.r.t. every parameter, and C_local from the
//! finite-difference pose Jacobian, on a tiny map.

use activemap_active::information::{
    Diagonal, PARAMS, ScoringScene, ViewParts, ViewSettings, eig, localisation_cost,
    view_information,
};
use activemap_geometry::{Intrinsics, Isometry3, Vector6, se3};
use activemap_splat::{Camera, DepthModel, Gaussians, RenderOptions, render};
use nalgebra::{DMatrix, Translation3, UnitQuaternion, Vector3};

/// Large, overlapping Gaussians: every pixel lies well inside every footprint (no 1/255 cut
/// and no 0.99 clamp nearby), so the render is smooth in every parameter.
fn tiny_map() -> Gaussians<f64> {
    let mut map = Gaussians::<f64>::new();
    map.push(
        [0.2, -0.1, 3.0],
        [0.7, 0.2, 0.3],
        [1.0, 0.1, -0.05, 0.02],
        0.45,
        [1.2, 0.9, 1.0],
    );
    map.push(
        [-0.3, 0.2, 3.6],
        [0.1, 0.6, 0.4],
        [0.9, 0.0, 0.2, 0.1],
        0.55,
        [1.0, 1.4, 0.8],
    );
    map.push(
        [0.1, 0.3, 4.2],
        [0.3, 0.3, 0.8],
        [1.0, -0.2, 0.1, 0.3],
        0.6,
        [1.5, 1.1, 1.3],
    );
    map
}

fn intrinsics() -> Intrinsics {
    Intrinsics::from_hfov(10, 8, 50f64.to_radians())
}

fn camera_pose() -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(0.05, -0.02, 0.1),
        UnitQuaternion::from_euler_angles(0.03, -0.04, 0.02),
    )
}

/// Render options with the centre depth model, which the Fisher pass differentiates.
fn centre_depth() -> RenderOptions {
    RenderOptions {
        depth: DepthModel::Centre,
        ..RenderOptions::default()
    }
}

/// Per pixel: R, G, B, D of a render of `map` from `camera`.
fn outputs(map: &Gaussians<f64>, camera: &Camera) -> Vec<[f64; 4]> {
    let r = render(map, camera, &centre_depth()).unwrap();
    (0..r.width * r.height)
        .map(|p| [r.colour[p][0], r.colour[p][1], r.colour[p][2], r.depth[p]])
        .collect()
}

const DEPTH_WEIGHT: f64 = 0.7;

/// `(1/P)·Σ_px [Σ_ch g_ch² + w·g_D²]` from central differences, per Gaussian and parameter.
fn brute_force_diagonal(map: &Gaussians<f64>, camera: &Camera) -> Vec<Diagonal> {
    let h = 1e-6;
    let p = camera.intrinsics.pixel_count() as f64;
    (0..map.len())
        .map(|i| {
            let mut d = [0.0; PARAMS];
            for (k, dk) in d.iter_mut().enumerate() {
                let mut plus = map.clone();
                *plus.param_mut(i, k) += h;
                let mut minus = map.clone();
                *minus.param_mut(i, k) -= h;
                let (a, b) = (outputs(&plus, camera), outputs(&minus, camera));
                *dk = a
                    .iter()
                    .zip(&b)
                    .map(|(a, b)| {
                        let g: Vec<f64> = (0..4).map(|c| (a[c] - b[c]) / (2.0 * h)).collect();
                        g[0] * g[0] + g[1] * g[1] + g[2] * g[2] + DEPTH_WEIGHT * g[3] * g[3]
                    })
                    .sum::<f64>()
                    / p;
            }
            d
        })
        .collect()
}

/// EIG of a pose equals the brute-force sum Σ_ik H_ik / prior_ik to 1e-6 relative.
#[test]
fn view_eig_matches_finite_differences() {
    let map = tiny_map();
    let k = intrinsics();
    let pose = camera_pose();
    let settings = ViewSettings {
        intrinsics: k,
        far_m: 50.0,
        depth_weight: DEPTH_WEIGHT,
        localisation: Default::default(),
    };
    let view = view_information(
        &ScoringScene::new(map.clone()),
        &pose,
        &settings,
        ViewParts::DiagonalAndPose,
    )
    .unwrap();
    assert_eq!(view.diagonal.len(), map.len());
    // A prior with a different value per entry, so a swapped index would show.
    let prior: Vec<Diagonal> = (0..map.len())
        .map(|i| std::array::from_fn(|k| 1e-3 * (1.0 + i as f64 + 0.37 * k as f64)))
        .collect();
    let brute = brute_force_diagonal(&map, &Camera::from_world_pose(k, &pose).with_far(50.0));
    let expected: f64 = brute
        .iter()
        .zip(&prior)
        .map(|(h, p)| h.iter().zip(p).map(|(h, p)| h / p).sum::<f64>())
        .sum();
    let got = eig(&view, prior.as_slice());
    assert!(expected > 0.0);
    assert!(
        ((got - expected) / expected).abs() < 1e-6,
        "EIG {got} vs brute force {expected}"
    );
}

/// The finite-difference pose Jacobian (left update τ = [ρ, θ] of T_camera_world), rows =
/// per-pixel outputs (R, G, B, √w·D), normalised by √P.
fn pose_jacobian(map: &Gaussians<f64>, k: Intrinsics, pose: &Isometry3<f64>) -> DMatrix<f64> {
    let h = 1e-6;
    let camera_from_world = pose.inverse();
    let p = k.pixel_count();
    let mut j = DMatrix::zeros(4 * p, 6);
    for c in 0..6 {
        let mut tau = Vector6::zeros();
        tau[c] = h;
        let at = |t: &Vector6<f64>| outputs(map, &Camera::new(k, se3::exp(t) * camera_from_world));
        let (a, b) = (at(&tau), at(&-tau));
        for px in 0..p {
            for o in 0..4 {
                let w = if o == 3 { DEPTH_WEIGHT.sqrt() } else { 1.0 };
                j[(4 * px + o, c)] = w * (a[px][o] - b[px][o]) / (2.0 * h) / (p as f64).sqrt();
            }
        }
    }
    j
}

/// C_local equals −log det of the finite-difference JᵀJ.
#[test]
fn localisation_cost_matches_finite_differences() {
    let map = tiny_map();
    let k = intrinsics();
    let pose = camera_pose();
    let settings = ViewSettings {
        intrinsics: k,
        far_m: 50.0,
        depth_weight: DEPTH_WEIGHT,
        localisation: Default::default(),
    };
    let view = view_information(
        &ScoringScene::new(map.clone()),
        &pose,
        &settings,
        ViewParts::DiagonalAndPose,
    )
    .unwrap();
    let j = pose_jacobian(&map, k, &pose);
    let jtj = j.transpose() * &j;
    let expected = -jtj.determinant().ln();
    let got = localisation_cost(&view.pose.unwrap(), 1e-12);
    assert!(expected.is_finite(), "{jtj}");
    assert!(
        (got - expected).abs() < 1e-5 * expected.abs().max(1.0),
        "C_local {got} vs finite differences {expected}"
    );
}

/// +∞, not NaN: a view that sees no Gaussian, and a degenerate one: a single isotropic
/// Gaussian straight ahead looks the same after any roll about the optical axis, so that
/// direction is unconstrained.
#[test]
fn localisation_cost_is_infinite_for_empty_and_degenerate_views() {
    let k = intrinsics();
    let settings = ViewSettings {
        intrinsics: k,
        far_m: 50.0,
        depth_weight: DEPTH_WEIGHT,
        localisation: Default::default(),
    };
    let mut map = Gaussians::<f64>::new();
    map.push(
        [0.0, 0.0, 3.0],
        [0.6, 0.4, 0.2],
        [1.0, 0.0, 0.0, 0.0],
        0.5,
        [0.5; 3],
    );
    let behind = Isometry3::from_parts(
        Translation3::identity(),
        UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f64::consts::PI),
    );
    let empty = view_information(
        &ScoringScene::new(map.clone()),
        &behind,
        &settings,
        ViewParts::DiagonalAndPose,
    )
    .unwrap();
    assert!(empty.is_empty());
    assert_eq!(localisation_cost(&empty.pose.unwrap(), 1e-9), f64::INFINITY);
    let blob = view_information(
        &ScoringScene::new(map.clone()),
        &Isometry3::identity(),
        &settings,
        ViewParts::DiagonalAndPose,
    )
    .unwrap();
    assert!(!blob.is_empty());
    let cost = localisation_cost(&blob.pose.unwrap(), 1e-9);
    assert_eq!(
        cost,
        f64::INFINITY,
        "roll about the optical axis is unconstrained"
    );
}
