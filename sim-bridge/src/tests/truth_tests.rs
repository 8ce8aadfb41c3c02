use super::fixtures::*;
use crate::ground_truth::{oriented_surface_samples, surface_area, surface_samples, test_poses};
use crate::navigation::{AgentShape, Navigation};
use crate::noise::{DepthNoise, NoiseConfig};
use crate::simulator::{SimConfig, Simulator};
use activemap_geometry::PlanarPose;

#[test]
fn surface_samples_are_on_the_surface_and_area_weighted() {
    // Box 4 × 2 × 1: faces ±x 2 m², ±y 4 m², ±z 8 m² (total 28 m²).
    let scene = box_room([0.0, 0.0, 0.0], [4.0, 2.0, 1.0]);
    assert!((surface_area(&scene) - 28.0).abs() < 1e-9);
    let n = 28_000;
    let pts = surface_samples(&scene, n, 11);
    assert_eq!(pts.len(), n);
    assert_eq!(pts, surface_samples(&scene, n, 11));
    let mut counts = [0usize; 3];
    for p in &pts {
        let d = [p.x.min(4.0 - p.x), p.y.min(2.0 - p.y), p.z.min(1.0 - p.z)];
        let axis = (0..3).min_by(|&a, &b| d[a].total_cmp(&d[b])).unwrap();
        assert!(d[axis] < 1e-6, "sample off the surface: {p:?}");
        counts[axis] += 1;
    }
    // Expected fractions 4/28, 8/28, 16/28; binomial σ ≤ 0.003, allow 5σ.
    for (c, e) in counts.iter().zip([4.0 / 28.0, 8.0 / 28.0, 16.0 / 28.0]) {
        assert!((*c as f64 / n as f64 - e).abs() < 0.015, "{counts:?}");
    }
    // With normals: the same points, each normal the unit axis of the face it lies on.
    let oriented = oriented_surface_samples(&scene, n, 11);
    assert_eq!(oriented.iter().map(|s| s.point).collect::<Vec<_>>(), pts);
    for s in &oriented {
        let p = s.point;
        let d = [p.x.min(4.0 - p.x), p.y.min(2.0 - p.y), p.z.min(1.0 - p.z)];
        let axis = (0..3).min_by(|&a, &b| d[a].total_cmp(&d[b])).unwrap();
        assert!((s.normal[axis].abs() - 1.0).abs() < 1e-12, "{s:?}");
    }
}

#[test]
fn test_poses_are_navigable_seeded_and_spread() {
    let scene = box_room([0.0, 0.0, 0.0], [4.0, 3.0, 2.5]);
    let nav = Navigation::build(&scene, 0.0, AgentShape::default(), 0.05).unwrap();
    let poses = test_poses(&nav, 2000, 3);
    assert_eq!(poses.len(), 2000);
    assert_eq!(poses, test_poses(&nav, 2000, 3));
    assert_ne!(poses, test_poses(&nav, 2000, 4));
    assert!(poses.iter().all(|p| nav.is_navigable(p.x, p.y)));
    assert!(
        poses
            .iter()
            .all(|p| (-std::f64::consts::PI..std::f64::consts::PI).contains(&p.yaw))
    );
    // Uniform over the navigable rectangle (0.1, 3.9) × (0.1, 2.9): mean ≈ centre.
    let mx = poses.iter().map(|p| p.x).sum::<f64>() / 2000.0;
    let my = poses.iter().map(|p| p.y).sum::<f64>() / 2000.0;
    assert!(
        (mx - 2.0).abs() < 0.1 && (my - 1.5).abs() < 0.1,
        "{mx} {my}"
    );
}

#[test]
fn sensor_noise_is_seeded_and_has_the_configured_spread() {
    let scene = box_room([-1.0, -5.0, 0.0], [2.0, 5.0, 2.5]);
    let noise = NoiseConfig {
        depth: DepthNoise {
            sigma_0: 0.002,
            sigma_z2: 0.004,
            ..DepthNoise::default()
        },
        rgb: crate::noise::ColourNoise { sigma: 3.0 },
        ..NoiseConfig::none()
    };
    let make = |seed| {
        let config = SimConfig {
            noise,
            seed,
            start: Some(PlanarPose::new(0.0, 0.0, 0.0)),
            ..SimConfig::with_resolution(64, 64)
        };
        Simulator::new(scene.clone(), config).unwrap()
    };
    let (mut a, mut b, mut c) = (make(1), make(1), make(2));
    let (fa, fb, fc) = (a.render(), b.render(), c.render());
    assert_eq!(fa, fb);
    assert_ne!(fa.depth, fc.depth);
    let clean = a.render_at(&a.true_pose());
    // The depth error divided by σ(z) = σ0 + c2·z² of the clean depth has unit std.
    let rel: Vec<f64> = fa
        .depth
        .iter()
        .zip(&clean.depth)
        .map(|(n, c)| (*n as f64 - *c as f64) / noise.depth.sigma_at(*c as f64))
        .collect();
    let std = (rel.iter().map(|r| r * r).sum::<f64>() / rel.len() as f64).sqrt();
    assert!((std - 1.0).abs() < 0.05, "normalised depth std {std}");
}
