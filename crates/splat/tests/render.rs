//! Forward-pass behaviour: closed form of one Gaussian, culling, flags, thread-count
//! independence, and scene recovery by optimisation.

#![allow(clippy::needless_range_loop)]

mod common;

use activemap_splat::*;
use common::*;
use rand::Rng;
use rand_distr::{Distribution, Normal};

/// A flat Gaussian lying on a floor seen at a grazing angle: under the plane model every pixel
/// it covers renders (normalised by its opacity) the depth where that pixel's ray meets the
/// floor, to within the linearisation at the centre; the centre model renders the centre's
/// depth over the whole footprint, short of the floor above the centre and long below it.
#[test]
fn a_flat_gaussian_on_a_floor_renders_the_floor_depth_under_the_plane_model() {
    let (w, h) = (128u32, 128u32);
    let cam = camera(w, h, 90.0, [0.0; 3], [0.0; 3]);
    let k = cam.intrinsics;
    // Camera frame (x right, y down, z forward): the floor is the plane y = 1.
    let (floor, z0) = (1.0, 2.0);
    let mut g = Gaussians::<f64>::new();
    g.push(
        [0.0, floor, z0],
        [0.5; 3],
        [1.0, 0.0, 0.0, 0.0],
        0.9,
        [0.2, 1e-4, 0.2],
    );
    let floor_depth = |v: f64| floor * k.fy / (v - k.cy);
    let errors = |model: DepthModel| {
        let out = render(
            &g,
            &cam,
            &RenderOptions {
                depth: model,
                ..Default::default()
            },
        )
        .unwrap();
        let mut worst = 0.0f64;
        let mut count = 0;
        for v in 0..h as usize {
            for u in 0..w as usize {
                let p = v * w as usize + u;
                // Within about 1.2σ of the centre, where the linearisation holds.
                if out.opacity[p] < 0.4 || (v as f64) <= k.cy {
                    continue;
                }
                let truth = floor_depth(v as f64);
                worst = worst.max((out.depth[p] / out.opacity[p] - truth).abs() / truth);
                count += 1;
            }
        }
        (worst, count)
    };
    let (plane, n) = errors(DepthModel::Plane);
    let (centre, m) = errors(DepthModel::Centre);
    eprintln!("worst relative depth error over {n} pixels: plane {plane:.4}, centre {centre:.4}");
    assert_eq!(n, m);
    assert!(n > 20, "too few covered pixels: {n}");
    assert!(plane < 0.02, "plane model {plane}");
    assert!(centre > 0.08, "centre model {centre}");
}

/// Render options with the centre depth model, which the Fisher pass needs.
fn centre_depth() -> RenderOptions {
    RenderOptions {
        depth: DepthModel::Centre,
        ..Default::default()
    }
}

#[test]
fn one_gaussian_renders_to_its_closed_form() {
    // Isotropic Gaussian on the optical axis: Σ' = ((f·s/z)² + 0.3)·I exactly, so every pixel
    // is α = o·exp(−r²/(2σ'²)), colour c·α, depth z·α, opacity α.
    let (w, h) = (41u32, 33u32);
    let cam = camera(w, h, 60.0, [0.0; 3], [0.0; 3]);
    let (z, s, o, rgb) = (2.0, 0.15, 0.6, [0.9, 0.4, 0.1]);
    let mut g = Gaussians::<f64>::new();
    g.push([0.0, 0.0, z], rgb, [0.3, -0.2, 0.5, 0.1], o, [s; 3]);
    let out = render(&g, &cam, &RenderOptions::default()).unwrap();
    let k = cam.intrinsics;
    let var = (k.fx * s / z).powi(2) + 0.3;
    let half = var.sqrt() * 3.0f64.min((2.0 * (255.0 * o).ln()).sqrt());
    let mut lit = 0;
    for v in 0..h as usize {
        for u in 0..w as usize {
            let (dx, dy) = (u as f64 - k.cx, v as f64 - k.cy);
            let mut alpha = o * (-(dx * dx + dy * dy) / (2.0 * var)).exp();
            if alpha < 1.0 / 255.0 || dx.abs() > half || dy.abs() > half {
                alpha = 0.0;
            }
            let p = v * w as usize + u;
            for ch in 0..3 {
                let c = 0.5 + SH_C0 * ((rgb[ch] - 0.5) / SH_C0);
                assert!(
                    (out.colour[p][ch] - c * alpha).abs() < 1e-12,
                    "pixel ({u},{v}) ch {ch}"
                );
            }
            assert!((out.depth[p] - z * alpha).abs() < 1e-12);
            assert!((out.opacity[p] - alpha).abs() < 1e-12);
            lit += (alpha > 0.0) as usize;
        }
    }
    assert!(lit > 50, "only {lit} pixels lit");
}

/// Two isotropic Gaussians on the optical axis, a faint one 2 m ahead in front of a dense one
/// 4 m ahead: at each pixel the alphas have the closed form of the test above, so the pixel's
/// median depth is 4 m where the near alpha leaves the transmittance above one half and 2 m where
/// it does not, NaN where even both leave it above one half; the composited depth blends the two.
#[test]
fn the_median_depth_is_the_depth_where_the_transmittance_halves() {
    let (w, h) = (41u32, 33u32);
    let cam = camera(w, h, 60.0, [0.0; 3], [0.0; 3]);
    let k = cam.intrinsics;
    let mut g = Gaussians::<f64>::new();
    // Near: opacity 0.7, narrow; far: opacity 0.9, wide.
    let near = (2.0, 0.2, 0.7);
    let far = (4.0, 1.5, 0.9);
    for (z, s, o) in [near, far] {
        g.push([0.0, 0.0, z], [0.5; 3], [1.0, 0.0, 0.0, 0.0], o, [s; 3]);
    }
    let out = render(&g, &cam, &centre_depth()).unwrap();
    let median = median_depth(&out);
    let alpha = |(z, s, o): (f64, f64, f64), r2: f64| {
        let var = (k.fx * s / z).powi(2) + 0.3;
        let a = o * (-r2 / (2.0 * var)).exp();
        if a < 1.0 / 255.0 { 0.0 } else { a }
    };
    let (mut at_near, mut at_far, mut none) = (0, 0, 0);
    for v in 0..h as usize {
        for u in 0..w as usize {
            let (dx, dy) = (u as f64 - k.cx, v as f64 - k.cy);
            let r2 = dx * dx + dy * dy;
            let (a_near, a_far) = (alpha(near, r2), alpha(far, r2));
            let p = v * w as usize + u;
            let got = median[p];
            // Stay clear of pixels whose transmittance is within rounding of one half.
            let after_near = 1.0 - a_near;
            let after_both = after_near * (1.0 - a_far);
            if (after_near - 0.5).abs() < 1e-3 || (after_both - 0.5).abs() < 1e-3 {
                continue;
            }
            if after_near <= 0.5 {
                assert_eq!(got, 2.0, "pixel ({u},{v})");
                at_near += 1;
            } else if after_both <= 0.5 {
                assert_eq!(got, 4.0, "pixel ({u},{v})");
                at_far += 1;
                // The composited depth, normalised, lies between the two surfaces.
                let mean = out.depth[p] / out.opacity[p];
                if a_near > 0.05 {
                    assert!(mean > 2.05 && mean < 3.95, "pixel ({u},{v}): {mean}");
                }
            } else {
                assert!(got.is_nan(), "pixel ({u},{v}): {got}");
                none += 1;
            }
        }
    }
    assert!(
        at_near > 5 && at_far > 50 && none > 50,
        "{at_near} {at_far} {none}"
    );
}

#[test]
fn gaussians_behind_or_outside_the_camera_contribute_nothing() {
    let cam = camera(48, 40, 60.0, [0.0; 3], [0.0; 3]);
    let base: Gaussians<f64> = random_scene(3, 10, (0.2, 0.9));
    let mut with = base.clone();
    with.push(
        [0.0, 0.0, -2.0],
        [1.0; 3],
        [1.0, 0.0, 0.0, 0.0],
        0.9,
        [0.3; 3],
    ); // behind
    with.push(
        [0.0, 0.0, 0.005],
        [1.0; 3],
        [1.0, 0.0, 0.0, 0.0],
        0.9,
        [0.3; 3],
    ); // before near plane
    with.push(
        [30.0, 0.0, 2.0],
        [1.0; 3],
        [1.0, 0.0, 0.0, 0.0],
        0.9,
        [0.1; 3],
    ); // far right of the image
    with.push(
        [0.0, -9.0, 2.0],
        [1.0; 3],
        [1.0, 0.0, 0.0, 0.0],
        0.9,
        [0.1; 3],
    ); // far above
    let a = render(&base, &cam, &centre_depth()).unwrap();
    let b = render(&with, &cam, &centre_depth()).unwrap();
    assert_eq!(a.colour, b.colour);
    assert_eq!(a.depth, b.depth);
    assert_eq!(a.opacity, b.opacity);
    let w = random_pixel_grads::<f64>(5, 48 * 40);
    let ga = backward(&base, &a, &w).unwrap();
    let gb = backward(&with, &b, &w).unwrap();
    for i in base.len()..with.len() {
        assert!(
            gb.params(i).iter().all(|v| *v == 0.0),
            "culled gaussian {i} has a gradient"
        );
        assert!(!b.context.visible[i]);
    }
    assert_eq!(ga.pose, gb.pose);
    let f = fisher(&with, &b, FisherMode::PerChannel).unwrap();
    for i in base.len()..with.len() {
        assert!(f.colour[i].iter().chain(&f.depth[i]).all(|v| *v == 0.0));
    }
}

#[test]
fn excluded_flags_render_like_a_map_without_them() {
    let cam = camera(48, 40, 60.0, [0.0; 3], [0.0; 3]);
    let mut g: Gaussians<f32> = random_scene(4, 20, (0.2, 0.9));
    let mut keep = vec![true; g.len()];
    for i in (0..g.len()).step_by(3) {
        g.flags[i] = FLAG_UNKNOWN_SPACE;
        keep[i] = false;
    }
    let mut pruned = g.clone();
    pruned.retain(&keep).unwrap();
    let opts = RenderOptions {
        exclude_flags: FLAG_UNKNOWN_SPACE,
        ..Default::default()
    };
    let a = render(&g, &cam, &opts).unwrap();
    let b = render(&pruned, &cam, &RenderOptions::default()).unwrap();
    assert_eq!(a.colour, b.colour);
    assert_eq!(a.depth, b.depth);
    let full = render(&g, &cam, &RenderOptions::default()).unwrap();
    assert_ne!(
        full.colour, a.colour,
        "the flagged Gaussians must matter when included"
    );
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let cam = camera(120, 90, 70.0, [0.0; 3], [0.0; 3]);
    let g: Gaussians<f32> = random_scene(9, 400, (0.1, 0.95));
    let w = random_pixel_grads::<f32>(9, 120 * 90);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let out = render(
                &g,
                &cam,
                &RenderOptions {
                    exposure: [0.1, 0.0],
                    exclude_flags: 0,
                    depth: DepthModel::Centre,
                },
            )
            .unwrap();
            let grads = backward(&g, &out, &w).unwrap();
            let f = fisher(&g, &out, FisherMode::PerChannel).unwrap();
            (out.colour, out.depth, grads, f)
        })
    };
    let one = run(1);
    let two = run(2);
    assert_eq!(one.0, two.0);
    assert_eq!(one.1, two.1);
    assert_eq!(one.2, two.2);
    assert_eq!(one.3, two.3);
    assert!(one.2.pose.norm() > 0.0 && one.3.pose_colour.trace() > 0.0);
}

/// Cameras on a ring around the scene centre (0, 0, 2.2), looking at it.
fn ring_camera(angle: f64, height: f64) -> Camera {
    use nalgebra::{Isometry3, Point3, Vector3};
    let centre = Point3::new(0.0, 0.0, 2.2);
    let eye = Point3::new(1.6 * angle.sin(), height, 2.2 - 1.6 * angle.cos());
    // OpenCV optical frame: z forward, y down (world −y is up here).
    let world_from_camera = Isometry3::face_towards(&eye, &centre, &Vector3::new(0.0, -1.0, 0.0));
    let k = activemap_geometry::Intrinsics::from_hfov(48, 48, 60f64.to_radians());
    Camera::from_world_pose(k, &world_from_camera)
}

#[test]
fn optimisation_recovers_a_known_scene() {
    let mut r = rng(11);
    let truth: Gaussians<f32> = {
        let mut g = Gaussians::new();
        for _ in 0..10 {
            let mean = [
                r.random_range(-0.3..0.3),
                r.random_range(-0.3..0.3),
                2.2 + r.random_range(-0.3..0.3),
            ];
            let rgb = [0; 3].map(|_| r.random_range(0.1..0.9));
            let q = [0; 4].map(|_| r.random_range(-1.0..1.0));
            let scale = [0; 3].map(|_| r.random_range(0.06..0.14));
            g.push(mean, rgb, q, r.random_range(0.6..0.9), scale);
        }
        g
    };
    let train: Vec<Camera> = (0..8)
        .map(|k| ring_camera(k as f64 * 0.35 - 1.2, if k % 2 == 0 { -0.2 } else { 0.2 }))
        .collect();
    let held_out = [ring_camera(-0.5, 0.05), ring_camera(0.7, -0.1)];
    let opts = RenderOptions::default();
    let targets: Vec<Render<f32>> = train
        .iter()
        .map(|c| render(&truth, c, &opts).unwrap())
        .collect();
    let mut g = truth.clone();
    let noise = Normal::new(0.0, 1.0).unwrap();
    for i in 0..g.len() {
        for k in 0..3 {
            g.means[i][k] += 0.06 * noise.sample(&mut r) as f32;
            g.sh_dc[i][k] += 0.8 * noise.sample(&mut r) as f32;
            g.log_scales[i][k] += 0.3 * noise.sample(&mut r) as f32;
        }
        g.opacity_logits[i] += 0.5 * noise.sample(&mut r) as f32;
    }
    let psnr_held_out = |g: &Gaussians<f32>| {
        held_out
            .iter()
            .map(|c| {
                psnr(
                    &render(g, c, &opts).unwrap().colour,
                    &render(&truth, c, &opts).unwrap().colour,
                )
            })
            .fold(f64::INFINITY, f64::min)
    };
    let before = psnr_held_out(&g);
    assert!(
        before < 25.0,
        "the perturbed start must be far from the truth ({before:.2} dB)"
    );
    let mut adam = GaussianAdam::new(AdamConfig {
        lr_mean: 2e-3,
        lr_colour: 1e-2,
        lr_rotation: 5e-3,
        lr_opacity: 2e-2,
        lr_scale: 5e-3,
        ..Default::default()
    });
    for it in 0..600 {
        let v = it % train.len();
        let out = render(&g, &train[v], &opts).unwrap();
        let t = &targets[v];
        let mut dl = PixelGrads::zeros(out.colour.len());
        for p in 0..out.colour.len() {
            for ch in 0..3 {
                dl.colour[p][ch] = 2.0 * (out.colour[p][ch] - t.colour[p][ch]);
            }
            dl.depth[p] = 2.0 * (out.depth[p] - t.depth[p]);
        }
        let grads = backward(&g, &out, &dl).unwrap();
        adam.step(&mut g, &grads).unwrap();
    }
    let after = psnr_held_out(&g);
    eprintln!("held-out PSNR: {before:.2} dB before, {after:.2} dB after");
    assert!(
        after >= 30.0,
        "held-out PSNR {after:.2} dB (started at {before:.2})"
    );
}
