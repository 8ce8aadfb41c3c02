use super::fixtures::*;
use crate::render::{DepthRange, Renderer};
use crate::scene::Material;
use activemap_geometry::{Intrinsics, Isometry3, PlanarPose, Vector3, camera_pose_from_planar};
use nalgebra::{Translation3, UnitQuaternion};

/// z-depth of the ray through pixel (u, v) to the inside of the box [lo, hi] (analytic).
fn box_depth(
    k: &Intrinsics,
    pose: &Isometry3<f64>,
    u: f64,
    v: f64,
    lo: [f64; 3],
    hi: [f64; 3],
) -> f64 {
    let d_cam = Vector3::new((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0);
    let d = pose.rotation * d_cam;
    let o = pose.translation.vector;
    let mut t_min = f64::INFINITY;
    for a in 0..3 {
        if d[a].abs() < 1e-15 {
            continue;
        }
        let bound = if d[a] > 0.0 { hi[a] } else { lo[a] };
        t_min = t_min.min((bound - o[a]) / d[a]);
    }
    t_min // the camera-frame ray has unit z, so t is the z-depth
}

#[test]
fn box_room_depth_matches_analytic_distances() {
    let (lo, hi) = ([-2.0f32, -1.5, 0.0], [3.0f32, 2.5, 2.5]);
    let scene = box_room(lo, hi);
    let k = Intrinsics::from_hfov(64, 48, std::f64::consts::FRAC_PI_2);
    let mut r = Renderer::new();
    let poses = [
        camera_pose_from_planar(&PlanarPose::new(0.0, 0.0, 0.0), 0.0, 0.88),
        camera_pose_from_planar(&PlanarPose::new(1.2, -0.4, 2.3), 0.0, 0.88),
        // An arbitrary tilted camera (not reachable by the agent, but render_at allows it).
        Isometry3::from_parts(
            Translation3::new(0.5, 0.7, 1.6),
            UnitQuaternion::from_euler_angles(0.4, -0.9, 1.1),
        ),
    ];
    let lo64 = lo.map(|c| c as f64);
    let hi64 = hi.map(|c| c as f64);
    for pose in &poses {
        let f = r.render(
            &scene,
            &k,
            pose,
            DepthRange {
                near: 0.01,
                max_depth: 100.0,
            },
        );
        for v in 0..k.height {
            for u in 0..k.width {
                let expected = box_depth(&k, pose, u as f64, v as f64, lo64, hi64);
                let got = f.depth_at(u, v) as f64;
                assert!(
                    (got - expected).abs() < 1e-5 * expected.max(1.0),
                    "pixel ({u},{v}): depth {got} vs analytic {expected}"
                );
            }
        }
    }
}

#[test]
fn depth_beyond_max_range_reads_zero_but_colour_is_kept() {
    let scene = box_room([-20.0, -1.0, 0.0], [20.0, 1.0, 2.0]);
    let k = Intrinsics::from_hfov(32, 32, std::f64::consts::FRAC_PI_2);
    let pose = camera_pose_from_planar(&PlanarPose::new(0.0, 0.0, 0.0), 0.0, 1.0);
    let f = Renderer::new().render(
        &scene,
        &k,
        &pose,
        DepthRange {
            near: 0.01,
            max_depth: 10.0,
        },
    );
    // The centre pixel looks down the 20 m corridor at the +x wall (green).
    assert_eq!(f.depth_at(16, 16), 0.0);
    assert_eq!(f.rgb_at(16, 16), [0, 255, 0]);
}

#[test]
fn textured_quad_shows_texture_where_it_should() {
    let mut scene = box_room([-10.0, -10.0, -10.0], [10.0, 10.0, 10.0]);
    scene.textures.push(gradient_texture());
    scene.materials.push(Material {
        name: "tex".into(),
        base_color: [1.0; 3],
        texture: Some(0),
    });
    let m = (scene.materials.len() - 1) as u32;
    // An oblique quad (so affine interpolation would be visibly wrong): corners in world,
    // uv (0,0) at the top-left seen from the camera (+y is the camera's left).
    let p = [
        [2.0f32, 1.0, 2.0],
        [3.0, -1.0, 2.0],
        [3.0, -1.0, 0.0],
        [2.0, 1.0, 0.0],
    ];
    push_quad(
        &mut scene,
        p,
        [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
        m,
    );
    let k = Intrinsics::from_hfov(80, 80, std::f64::consts::FRAC_PI_2);
    let pose = camera_pose_from_planar(&PlanarPose::new(0.0, 0.0, 0.0), 0.0, 1.0);
    let f = Renderer::new().render(&scene, &k, &pose, DepthRange::default());
    let tex = gradient_texture();
    let o = pose.translation.vector;
    let (a, b, d) = (
        Vector3::new(2.0, 1.0, 2.0),
        Vector3::new(3.0, -1.0, 2.0),
        Vector3::new(2.0, 1.0, 0.0),
    );
    let (eu, ev) = (b - a, d - a);
    let n = eu.cross(&ev);
    let mut checked = 0;
    for v in 0..k.height {
        for u in 0..k.width {
            let dir = pose.rotation
                * Vector3::new((u as f64 - k.cx) / k.fx, (v as f64 - k.cy) / k.fy, 1.0);
            let t = (a - o).dot(&n) / dir.dot(&n);
            let hit = o + dir * t;
            let rel = hit - a;
            let (s, w) = (
                rel.dot(&eu) / eu.norm_squared(),
                rel.dot(&ev) / ev.norm_squared(),
            );
            // Skip pixels near the quad border (partial coverage is not defined analytically).
            if !(0.02..0.98).contains(&s) || !(0.02..0.98).contains(&w) {
                continue;
            }
            let expected = tex.sample_bilinear(s as f32, w as f32);
            let got = f.rgb_at(u, v);
            for c in 0..3 {
                assert!(
                    (got[c] as f32 - expected[c]).abs() <= 1.5,
                    "pixel ({u},{v}) uv ({s:.3},{w:.3}): {got:?} vs {expected:?}"
                );
            }
            assert!((f.depth_at(u, v) as f64 - t).abs() < 1e-5);
            checked += 1;
        }
    }
    assert!(checked > 300, "quad covers too few pixels: {checked}");
    // Orientation: the top-left of the quad (uv near 0) is the dark-red-ish texel (20, 20, 200)
    // and it lies to the image's left of the bright texel (140, 140, 200).
    let (dark, bright) = find_colour(&f, [20, 20, 200])
        .zip(find_colour(&f, [140, 140, 200]))
        .expect("corners visible");
    assert!(
        dark.0 < bright.0 && dark.1 < bright.1,
        "dark {dark:?} bright {bright:?}"
    );
}

fn find_colour(f: &crate::RgbdFrame, c: [u8; 3]) -> Option<(u32, u32)> {
    (0..f.height())
        .flat_map(|v| (0..f.width()).map(move |u| (u, v)))
        .find(|&(u, v)| f.rgb_at(u, v) == c)
}

#[test]
fn rendering_is_deterministic_and_thread_count_independent() {
    let house = crate::house::generate(
        3,
        &crate::house::HouseConfig {
            texture_size: 64,
            ..Default::default()
        },
    )
    .unwrap();
    let k = Intrinsics::from_hfov(96, 96, std::f64::consts::FRAC_PI_2);
    let pose = camera_pose_from_planar(&house.start, 0.0, 0.88);
    let a = Renderer::new().render(&house.scene, &k, &pose, DepthRange::default());
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let b = pool.install(|| Renderer::new().render(&house.scene, &k, &pose, DepthRange::default()));
    assert_eq!(a, b);
    assert!(
        a.depth.iter().all(|d| *d > 0.0),
        "a closed house has a surface behind every pixel"
    );
}

/// `render_into` writes every pixel of caller buffers holding stale data (as a reused
/// shared-memory sample does), with the same bits as `render`, and a reused renderer gives the
/// same frame as a fresh one. Wrong buffer sizes are errors naming the buffer.
#[test]
fn render_into_overwrites_stale_buffers_and_checks_their_size() {
    // One textured house frame, and a lone quad that leaves most pixels empty.
    let house = crate::house::generate(
        3,
        &crate::house::HouseConfig {
            texture_size: 64,
            ..Default::default()
        },
    )
    .unwrap();
    let mut quad = crate::Scene::default();
    let m = flat(&mut quad, [0.2, 0.4, 0.6]);
    push_quad(
        &mut quad,
        [
            [2.0, -0.3, 0.5],
            [2.0, 0.3, 0.5],
            [2.0, 0.3, 1.2],
            [2.0, -0.3, 1.2],
        ],
        [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
        m,
    );
    let k = Intrinsics::from_hfov(40, 30, std::f64::consts::FRAC_PI_2);
    let mut reused = Renderer::new();
    for (scene, planar) in [
        (&house.scene, house.start),
        (&quad, PlanarPose::new(0.0, 0.0, 0.0)),
        (&house.scene, house.start),
    ] {
        let pose = camera_pose_from_planar(&planar, 0.0, 0.88);
        let fresh = Renderer::new().render(scene, &k, &pose, DepthRange::default());
        let mut rgb = vec![0xAB; 3 * 40 * 30];
        let mut depth = vec![f32::NAN; 40 * 30];
        reused
            .render_into(
                scene,
                &k,
                &pose,
                DepthRange::default(),
                &mut rgb,
                &mut depth,
            )
            .unwrap();
        assert_eq!(rgb, fresh.rgb);
        assert_eq!(
            depth.iter().map(|d| d.to_bits()).collect::<Vec<_>>(),
            fresh.depth.iter().map(|d| d.to_bits()).collect::<Vec<_>>()
        );
    }
    // The quad frame really had empty pixels (black, depth 0) next to covered ones.
    let pose = camera_pose_from_planar(&PlanarPose::new(0.0, 0.0, 0.0), 0.0, 0.88);
    let f = Renderer::new().render(&quad, &k, &pose, DepthRange::default());
    assert!(f.depth.contains(&0.0) && f.depth.iter().any(|d| *d > 0.0));
    let (mut rgb, mut depth) = (vec![0u8; 3 * 40 * 30], vec![0f32; 40 * 30 - 1]);
    let err = reused
        .render_into(
            &quad,
            &k,
            &pose,
            DepthRange::default(),
            &mut rgb,
            &mut depth,
        )
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("depth") && err.contains("1199") && err.contains("1200"),
        "{err}"
    );
    let mut rgb = vec![0u8; 5];
    let mut depth = vec![0f32; 40 * 30];
    let err = reused
        .render_into(
            &quad,
            &k,
            &pose,
            DepthRange::default(),
            &mut rgb,
            &mut depth,
        )
        .unwrap_err()
        .to_string();
    assert!(err.contains("rgb") && err.contains("3600"), "{err}");
}
