//! Finite-difference checks (f64) of the backward pass, for every parameter group, the pose τ
//! and the exposure, and brute-force checks of the Fisher pass.

#![allow(clippy::needless_range_loop)]

mod common;

use activemap_geometry::se3;
use activemap_splat::*;
use common::*;
use nalgebra::{Matrix6, Vector6};

const H: f64 = 1e-6;

fn options() -> RenderOptions {
    RenderOptions {
        exposure: [0.15, 0.03],
        exclude_flags: 0,
        depth: DepthModel::Centre,
    }
}

/// [`options`] with the plane depth model.
fn plane_options() -> RenderOptions {
    RenderOptions {
        depth: DepthModel::Plane,
        ..options()
    }
}

/// Relative error, with a floor that keeps FD noise on near-zero gradients out.
fn rel_err(analytic: f64, numeric: f64, floor: f64) -> f64 {
    (analytic - numeric).abs() / analytic.abs().max(numeric.abs()).max(floor)
}

#[test]
fn parameter_gradients_match_finite_differences() {
    parameter_gradients_check(options());
}

#[test]
fn plane_depth_parameter_gradients_match_finite_differences() {
    parameter_gradients_check(plane_options());
}

fn parameter_gradients_check(options: RenderOptions) {
    let options = || options;
    let cam = camera(40, 36, 60.0, [0.0; 3], [0.0; 3]);
    for seed in 0..3u64 {
        let g: Gaussians<f64> = random_scene(seed, 12, (0.1, 0.85));
        if options().depth == DepthModel::Plane {
            // The scene must exercise the slope: its depth differs from the centre model's.
            let plane = render(&g, &cam, &options()).unwrap().depth;
            let centre = render(&g, &cam, &crate::options()).unwrap().depth;
            let most = plane
                .iter()
                .zip(&centre)
                .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
            assert!(
                most > 0.01,
                "plane and centre depths differ by {most} m at most"
            );
        }
        let w = random_pixel_grads::<f64>(100 + seed, 40 * 36);
        let out = render(&g, &cam, &options()).unwrap();
        let grads = backward(&g, &out, &w).unwrap();
        let gmax = (0..g.len())
            .flat_map(|i| grads.params(i))
            .fold(0.0f64, |m, v| m.max(v.abs()));
        let mut worst = [0.0f64; 5];
        for i in 0..g.len() {
            let analytic = grads.params(i);
            for k in 0..14 {
                let mut plus = g.clone();
                *plus.param_mut(i, k) += H;
                let mut minus = g.clone();
                *minus.param_mut(i, k) -= H;
                let lp = linear_loss(&render(&plus, &cam, &options()).unwrap(), &w);
                let lm = linear_loss(&render(&minus, &cam, &options()).unwrap(), &w);
                let numeric = (lp - lm) / (2.0 * H);
                let e = rel_err(analytic[k], numeric, 1e-4 * gmax);
                let group = match k {
                    0..=2 => 0,
                    3..=5 => 1,
                    6..=9 => 2,
                    10 => 3,
                    _ => 4,
                };
                worst[group] = worst[group].max(e);
                assert!(
                    e < 1e-3,
                    "seed {seed} gaussian {i} param {k}: analytic {} numeric {numeric}",
                    analytic[k]
                );
            }
        }
        eprintln!(
            "seed {seed}: worst relative error per group (mean, colour, rotation, opacity, scale) {worst:?}"
        );
    }
}

#[test]
fn pose_and_exposure_gradients_match_finite_differences() {
    pose_and_exposure_check(options());
}

#[test]
fn plane_depth_pose_and_exposure_gradients_match_finite_differences() {
    pose_and_exposure_check(plane_options());
}

fn pose_and_exposure_check(options: RenderOptions) {
    let options = || options;
    for seed in 0..3u64 {
        let cam = camera(48, 40, 70.0, [0.05, -0.02, 0.1], [0.02, -0.03, 0.01]);
        let g: Gaussians<f64> = random_scene(10 + seed, 15, (0.1, 0.85));
        let w = random_pixel_grads::<f64>(200 + seed, 48 * 40);
        let out = render(&g, &cam, &options()).unwrap();
        let grads = backward(&g, &out, &w).unwrap();
        let loss_at = |tau: &Vector6<f64>| {
            let mut c = cam;
            c.camera_from_world = se3::exp(tau) * cam.camera_from_world;
            linear_loss(&render(&g, &c, &options()).unwrap(), &w)
        };
        let scale = grads.pose.amax();
        for k in 0..6 {
            let mut tau = Vector6::zeros();
            tau[k] = H;
            let numeric = (loss_at(&tau) - loss_at(&-tau)) / (2.0 * H);
            let e = rel_err(grads.pose[k], numeric, 1e-4 * scale);
            assert!(
                e < 1e-3,
                "seed {seed} tau[{k}]: analytic {} numeric {numeric}",
                grads.pose[k]
            );
        }
        for k in 0..2 {
            let mut op = options();
            op.exposure[k] += H;
            let lp = linear_loss(&render(&g, &cam, &op).unwrap(), &w);
            op.exposure[k] -= 2.0 * H;
            let lm = linear_loss(&render(&g, &cam, &op).unwrap(), &w);
            let numeric = (lp - lm) / (2.0 * H);
            assert!(
                rel_err(grads.exposure[k], numeric, 1e-9) < 1e-6,
                "exposure {k}: {} vs {numeric}",
                grads.exposure[k]
            );
        }
    }
}

/// Per-pixel Jacobian rows from one-hot backward calls: for pixel p and output `which`
/// (0..3 colour channel, 3 = all colour channels at once, 4 = depth).
fn one_hot_grads(g: &Gaussians<f64>, out: &Render<f64>, p: usize, which: usize) -> Gradients<f64> {
    let mut w = PixelGrads::zeros(out.width * out.height);
    match which {
        0..=2 => w.colour[p][which] = 1.0,
        3 => w.colour[p] = [1.0; 3],
        _ => w.depth[p] = 1.0,
    }
    backward(g, out, &w).unwrap()
}

#[test]
fn fisher_equals_brute_force_sums_of_per_pixel_jacobians() {
    let cam = camera(20, 18, 60.0, [0.0; 3], [0.0; 3]);
    let mut g: Gaussians<f64> = random_scene(7, 6, (0.2, 0.9));
    // One nearly opaque Gaussian: its alpha hits the 0.99 clamp near the centre.
    g.push(
        [0.05, 0.02, 1.8],
        [0.3, 0.6, 0.9],
        [1.0, 0.2, 0.0, 0.1],
        0.997,
        [0.12, 0.08, 0.1],
    );
    let out = render(&g, &cam, &options()).unwrap();
    let per_channel = fisher(&g, &out, FisherMode::PerChannel).unwrap();
    let summed = fisher(&g, &out, FisherMode::ChannelSum).unwrap();
    let n = g.len();
    let mut diag_pc = vec![[0.0; 14]; n];
    let mut diag_sum = vec![[0.0; 14]; n];
    let mut diag_depth = vec![[0.0; 14]; n];
    let mut pose_col = Matrix6::zeros();
    let mut pose_dep = Matrix6::zeros();
    for p in 0..out.width * out.height {
        for which in 0..5 {
            let gr = one_hot_grads(&g, &out, p, which);
            for i in 0..n {
                let row = gr.params(i);
                let target = match which {
                    0..=2 => &mut diag_pc[i],
                    3 => &mut diag_sum[i],
                    _ => &mut diag_depth[i],
                };
                for k in 0..14 {
                    target[k] += row[k] * row[k];
                }
            }
            match which {
                0..=2 => pose_col += gr.pose * gr.pose.transpose(),
                4 => pose_dep += gr.pose * gr.pose.transpose(),
                _ => {}
            }
        }
    }
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(b.abs()) + 1e-14;
    for i in 0..n {
        for k in 0..14 {
            assert!(
                close(per_channel.colour[i][k], diag_pc[i][k]),
                "colour diag g{i} k{k}: {} vs {}",
                per_channel.colour[i][k],
                diag_pc[i][k]
            );
            assert!(
                close(summed.colour[i][k], diag_sum[i][k]),
                "summed diag g{i} k{k}: {} vs {}",
                summed.colour[i][k],
                diag_sum[i][k]
            );
            assert!(
                close(per_channel.depth[i][k], diag_depth[i][k]),
                "depth diag g{i} k{k}: {} vs {}",
                per_channel.depth[i][k],
                diag_depth[i][k]
            );
        }
    }
    for a in 0..6 {
        for b in 0..6 {
            assert!(
                close(per_channel.pose_colour[(a, b)], pose_col[(a, b)]),
                "pose colour ({a},{b})"
            );
            assert!(
                close(per_channel.pose_depth[(a, b)], pose_dep[(a, b)]),
                "pose depth ({a},{b})"
            );
        }
    }
    // The information is not trivially zero.
    assert!(pose_col.trace() > 0.0 && pose_dep.trace() > 0.0);
    assert!(diag_pc.iter().all(|d| d[0] > 0.0));
}
