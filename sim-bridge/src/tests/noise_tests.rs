//! Sensor and actuation noise against the configured model: sample statistics on synthetic
//! frames and on many actions, determinism, stream independence, and the configuration syntax.

use super::fixtures::box_room;
use crate::noise::{
    ActuationNoise, ColourNoise, DepthNoise, NoiseConfig, NoisePreset, SensorNoiseSampler,
};
use crate::simulator::{Action, SimConfig, Simulator};
use activemap_geometry::PlanarPose;
use serde_json::json;

/// Mean, standard deviation (n − 1) and count of `xs`.
fn stats(xs: &[f64]) -> (f64, f64, usize) {
    let n = xs.len();
    let mean = xs.iter().sum::<f64>() / n as f64;
    let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    (mean, var.sqrt(), n)
}

/// Asserts `mean` within 3 standard errors of `expected` and `std` within 3 % of `sigma`.
fn assert_gaussian(what: &str, (mean, std, n): (f64, f64, usize), expected: f64, sigma: f64) {
    let se = sigma / (n as f64).sqrt();
    assert!(
        (mean - expected).abs() < 3.0 * se,
        "{what}: mean {mean} vs {expected} (3 SE = {})",
        3.0 * se
    );
    assert!(
        (std / sigma - 1.0).abs() < 0.03,
        "{what}: std {std} vs {sigma}"
    );
}

/// Asserts a fraction `k / n` within 4 standard errors of `p`.
fn assert_rate(what: &str, k: usize, n: usize, p: f64) {
    let rate = k as f64 / n as f64;
    let se = (p * (1.0 - p) / n as f64).sqrt();
    assert!(
        (rate - p).abs() <= 4.0 * se,
        "{what}: rate {rate} vs {p} (4 SE = {})",
        4.0 * se
    );
}

fn depth_only(depth: DepthNoise) -> NoiseConfig {
    NoiseConfig {
        depth,
        ..NoiseConfig::none()
    }
}

/// Applies the sensor noise of `config` (seed `seed`) to a depth image `width` wide.
fn noisy_depth(config: &NoiseConfig, seed: u64, depth: &[f32], width: usize) -> Vec<f32> {
    let mut out = depth.to_vec();
    SensorNoiseSampler::new(config, seed).apply_to(&mut [], &mut out, width);
    out
}

#[test]
fn depth_noise_has_the_mean_and_sigma_of_the_model_at_several_depths() {
    // The realistic preset (σ = 1 mm + 0.0036·z², 1 % dropout) and a constant-σ model.
    let constant = DepthNoise {
        sigma_0: 0.004,
        ..DepthNoise::default()
    };
    for (name, depth) in [("realistic", DepthNoise::REALISTIC), ("constant", constant)] {
        let config = depth_only(depth);
        for (k, z) in [0.5f32, 1.0, 2.0, 4.0].into_iter().enumerate() {
            let (w, h) = (256, 256);
            let clean = vec![z; w * h];
            let noisy = noisy_depth(&config, 10 + k as u64, &clean, w);
            let errors: Vec<f64> = noisy
                .iter()
                .filter(|d| **d > 0.0)
                .map(|d| *d as f64 - z as f64)
                .collect();
            let s = stats(&errors);
            eprintln!(
                "{name} z = {z} m: σ model {:.5} m, measured mean {:+.6} m, std {:.5} m, \
                 dropout {:.4}",
                depth.sigma_at(z as f64),
                s.0,
                s.1,
                1.0 - s.2 as f64 / (w * h) as f64
            );
            assert_gaussian(&format!("{name} z = {z}"), s, 0.0, depth.sigma_at(z as f64));
            // A flat image has no edges: only the random dropout removes pixels.
            assert_rate(
                &format!("{name} dropout at z = {z}"),
                w * h - s.2,
                w * h,
                depth.dropout,
            );
        }
    }
}

#[test]
fn random_dropout_hits_the_configured_fraction_and_leaves_the_rest_exact() {
    let config = depth_only(DepthNoise {
        dropout: 0.2,
        ..DepthNoise::default()
    });
    let (w, h) = (200, 200);
    let clean: Vec<f32> = (0..w * h).map(|i| 1.0 + (i % 7) as f32 * 0.001).collect();
    let noisy = noisy_depth(&config, 3, &clean, w);
    let dropped = noisy.iter().filter(|d| **d == 0.0).count();
    eprintln!("dropout 0.2: measured {}", dropped as f64 / (w * h) as f64);
    assert_rate("dropout", dropped, w * h, 0.2);
    assert!(noisy.iter().zip(&clean).all(|(n, c)| *n == 0.0 || n == c));
}

#[test]
fn readings_outside_the_range_are_zero_and_invalid_pixels_stay_zero() {
    let config = depth_only(DepthNoise {
        sigma_0: 0.001,
        sigma_z2: 0.01,
        min_range: 0.3,
        max_range: 5.0,
        ..DepthNoise::default()
    });
    let columns = [0.0f32, 0.1, 0.29, 0.31, 1.0, 4.9, 5.01, 8.0, 50.0];
    let w = columns.len();
    let clean: Vec<f32> = (0..w * 100).map(|i| columns[i % w]).collect();
    let noisy = noisy_depth(&config, 1, &clean, w);
    for (c, n) in clean.iter().zip(&noisy) {
        if *c < 0.3 || *c > 5.0 {
            assert_eq!(*n, 0.0, "clean {c} must read 0");
        } else {
            assert!(
                *n > 0.0 && *n != *c,
                "clean {c} must read a noisy value, got {n}"
            );
        }
    }
}

#[test]
fn depth_edges_are_dropped_with_the_configured_probability_and_flat_interiors_are_not() {
    // Left half 1.0 m, right half 1.5 m (a 50 % step), plus a slanted plane below whose
    // neighbours differ by ≤ 1 % (under the 5 % threshold), and a single hole.
    let (w, h) = (64, 1200);
    let mut clean = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            clean[y * w + x] = if y < 1000 {
                if x < 32 { 1.0 } else { 1.5 }
            } else {
                2.0 + 0.01 * x as f32 + 0.005 * (y - 1000) as f32
            };
        }
    }
    let hole = 1100 * w + 10;
    clean[hole] = 0.0;
    let neighbours_of_hole = [hole - 1, hole + 1, hole - w, hole + w];
    // The step's edge pixels: columns 31 and 32 of the upper part; row 999 is also next to the
    // slanted part (≥ 33 % away), row 1000 likewise.
    let is_edge = |i: usize| {
        let (x, y) = (i % w, i / w);
        (y < 1000 && (x == 31 || x == 32))
            || y == 999
            || y == 1000
            || neighbours_of_hole.contains(&i)
    };
    let base = DepthNoise {
        edge_threshold: 0.05,
        ..DepthNoise::default()
    };
    // Probability 1: exactly the edge set reads 0, though dropping a pixel leaves a 0 next to
    // its neighbours (decisions read the clean depth).
    let all = depth_only(DepthNoise {
        edge_dropout: 1.0,
        ..base
    });
    let noisy = noisy_depth(&all, 4, &clean, w);
    for (i, d) in noisy.iter().enumerate().filter(|(i, _)| *i != hole) {
        assert_eq!(*d == 0.0, is_edge(i), "pixel ({}, {})", i % w, i / w);
    }
    // Probability 0.3: the edge set loses 30 %, the interiors nothing.
    let p = 0.3;
    let some = depth_only(DepthNoise {
        edge_dropout: p,
        ..base
    });
    let noisy = noisy_depth(&some, 5, &clean, w);
    let edge: Vec<usize> = (0..w * h).filter(|&i| i != hole && is_edge(i)).collect();
    let dropped = edge.iter().filter(|&&i| noisy[i] == 0.0).count();
    eprintln!(
        "edge dropout {p}: measured {} over {} edge pixels",
        dropped as f64 / edge.len() as f64,
        edge.len()
    );
    assert_rate("edge dropout", dropped, edge.len(), p);
    assert!(
        (0..w * h)
            .filter(|&i| i != hole && !is_edge(i))
            .all(|i| noisy[i] == clean[i]),
        "a flat interior pixel was dropped or changed"
    );
}

#[test]
fn colour_noise_has_the_configured_sigma() {
    let config = NoiseConfig {
        rgb: ColourNoise { sigma: 3.0 },
        ..NoiseConfig::none()
    };
    let mut rgb = vec![128u8; 3 * 200 * 200];
    SensorNoiseSampler::new(&config, 8).apply_to(&mut rgb, &mut [], 200);
    let values: Vec<f64> = rgb.iter().map(|c| *c as f64 - 128.0).collect();
    let s = stats(&values);
    // Rounding to integer levels adds the variance of a unit uniform, 1/12.
    let expected = (9.0f64 + 1.0 / 12.0).sqrt();
    eprintln!("colour σ 3: measured mean {:+.4}, std {:.4}", s.0, s.1);
    assert_gaussian("colour", s, 0.0, expected);
}

#[test]
fn sensor_noise_is_deterministic_per_seed() {
    let config = NoiseConfig::realistic();
    let (w, h) = (120, 90);
    let clean: Vec<f32> = (0..w * h)
        .map(|i| {
            if i % w < 60 {
                1.2
            } else {
                3.0 + (i / w) as f32 * 0.01
            }
        })
        .collect();
    let run = |seed| {
        let mut rgb: Vec<u8> = (0..3 * w * h).map(|i| (i % 251) as u8).collect();
        let mut depth = clean.clone();
        SensorNoiseSampler::new(&config, seed).apply_to(&mut rgb, &mut depth, w);
        (rgb, depth)
    };
    assert_eq!(run(1), run(1));
    let (a, b) = (run(1), run(2));
    assert_ne!(a.0, b.0);
    assert_ne!(a.1, b.1);
}

#[test]
fn realistic_noise_on_an_800_px_frame_changes_it_and_is_timed() {
    // A frame like the simulator's: a floor-like gradient and a wall with an edge.
    let (w, h) = (800, 800);
    let depth: Vec<f32> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            if x > 500 {
                2.0
            } else {
                1.0 + 8.0 * (1.0 - y as f32 / h as f32)
            }
        })
        .collect();
    let rgb: Vec<u8> = (0..3 * w * h).map(|i| (i % 256) as u8).collect();
    let realistic = NoiseConfig::realistic();
    let parts = [
        ("depth and colour", realistic),
        (
            "depth",
            NoiseConfig {
                rgb: ColourNoise::default(),
                ..realistic
            },
        ),
        (
            "colour",
            NoiseConfig {
                depth: DepthNoise::default(),
                ..realistic
            },
        ),
    ];
    for (name, config) in parts {
        let mut sampler = SensorNoiseSampler::new(&config, 1);
        let (mut r, mut d) = (rgb.clone(), depth.clone());
        sampler.apply_to(&mut r, &mut d, w);
        assert_eq!(d != depth, config.depth.is_active(), "{name}");
        assert_eq!(r != rgb, config.rgb.is_active(), "{name}");
        let runs = 5;
        let mut total = std::time::Duration::ZERO;
        for _ in 0..runs {
            let (mut r, mut d) = (rgb.clone(), depth.clone());
            let start = std::time::Instant::now();
            sampler.apply_to(&mut r, &mut d, w);
            total += start.elapsed();
            std::hint::black_box((&r, &d));
        }
        eprintln!(
            "realistic sensor noise at 800×800, {name}: {:.1} ms per frame",
            total.as_secs_f64() * 1e3 / runs as f64
        );
    }
}

/// A 10 m × 10 m empty room, the agent in the middle.
fn open_sim(noise: NoiseConfig, seed: u64) -> Simulator {
    let config = SimConfig {
        noise,
        seed,
        start: Some(PlanarPose::new(5.0, 5.0, 0.3)),
        ..SimConfig::with_resolution(16, 16)
    };
    Simulator::new(box_room([0.0, 0.0, 0.0], [10.0, 10.0, 2.5]), config).unwrap()
}

fn wrap(a: f64) -> f64 {
    activemap_geometry::robot::wrap_angle(a)
}

#[test]
fn forward_and_turn_noise_have_the_configured_mean_and_sigma() {
    let custom = ActuationNoise {
        forward_sigma_frac: 0.1,
        forward_sigma_m: 0.002,
        heading_sigma_deg: 0.5,
        turn_sigma_deg: 1.0,
    };
    for (name, actuation) in [("custom", custom), ("realistic", ActuationNoise::REALISTIC)] {
        let noise = NoiseConfig {
            actuation,
            ..NoiseConfig::none()
        };
        let mut sim = open_sim(noise, 21);
        let start = sim.true_planar_pose();
        let step = sim.config().robot.forward_step_m;
        let turn = sim.config().robot.turn_angle_rad;
        let n = 20_000;
        let (mut dist, mut heading) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for _ in 0..n {
            sim.set_planar_pose(start).unwrap();
            assert!(!sim.step(Action::Forward).collided);
            let p = sim.true_planar_pose();
            let (dx, dy) = (p.x - start.x, p.y - start.y);
            let dyaw = wrap(p.yaw - start.yaw);
            // Travel along the old heading plus half the change.
            let direction = wrap(dy.atan2(dx) - start.yaw);
            assert!((direction - 0.5 * dyaw).abs() < 1e-9, "{direction} {dyaw}");
            dist.push(dx.hypot(dy));
            heading.push(dyaw.to_degrees());
        }
        let (sd, sh) = (stats(&dist), stats(&heading));
        eprintln!(
            "{name}: forward mean {:.5} m std {:.5} m (σ {:.5}); heading mean {:+.4}° std \
             {:.4}° (σ {})",
            sd.0,
            sd.1,
            actuation.forward_sigma(step),
            sh.0,
            sh.1,
            actuation.heading_sigma_deg
        );
        assert_gaussian(
            &format!("{name} distance"),
            sd,
            step,
            actuation.forward_sigma(step),
        );
        assert_gaussian(
            &format!("{name} heading"),
            sh,
            0.0,
            actuation.heading_sigma_deg,
        );
        for (action, sign) in [(Action::TurnLeft, 1.0), (Action::TurnRight, -1.0)] {
            let mut angles = Vec::with_capacity(n);
            for _ in 0..n {
                sim.set_planar_pose(start).unwrap();
                sim.step(action);
                let p = sim.true_planar_pose();
                assert_eq!((p.x, p.y), (start.x, start.y));
                angles.push(wrap(p.yaw - start.yaw).to_degrees());
            }
            let s = stats(&angles);
            eprintln!(
                "{name} {action:?}: mean {:+.4}° std {:.4}° (σ {})",
                s.0, s.1, actuation.turn_sigma_deg
            );
            assert_gaussian(
                &format!("{name} {action:?}"),
                s,
                sign * turn.to_degrees(),
                actuation.turn_sigma_deg,
            );
        }
    }
}

#[test]
fn noisy_motion_still_stops_and_slides_at_walls() {
    let noise = NoiseConfig {
        actuation: ActuationNoise {
            forward_sigma_frac: 0.2,
            heading_sigma_deg: 0.5,
            ..ActuationNoise::default()
        },
        ..NoiseConfig::none()
    };
    let room = |start, sliding| {
        let config = SimConfig {
            noise,
            seed: 3,
            start: Some(start),
            allow_sliding: sliding,
            ..SimConfig::with_resolution(16, 16)
        };
        Simulator::new(box_room([0.0, 0.0, 0.0], [4.0, 3.0, 2.5]), config).unwrap()
    };
    // Head-on: never inside the wall's clearance, obstructed once there.
    let mut sim = room(PlanarPose::new(2.0, 1.5, 0.0), true);
    let mut collided = 0;
    for _ in 0..100 {
        collided += sim.step(Action::Forward).collided as usize;
        let p = sim.true_planar_pose();
        assert!(
            p.x <= 3.9 + 1e-9 && sim.navigation().is_navigable(p.x, p.y),
            "{p:?}"
        );
    }
    assert!(collided > 40, "only {collided} obstructed steps");
    // 60° towards the +x wall with sliding: hugs the wall and keeps moving along it.
    let mut sim = room(PlanarPose::new(3.7, 0.5, 60f64.to_radians()), true);
    for _ in 0..30 {
        sim.step(Action::Forward);
    }
    let p = sim.true_planar_pose();
    assert!((p.x - 3.9).abs() < 1e-3 && p.y > 1.4, "should slide: {p:?}");
    // Without sliding an obstructed step does not move the agent (its heading may change).
    let mut stuck = room(PlanarPose::new(3.7, 0.5, 60f64.to_radians()), false);
    let mut last = stuck.true_planar_pose();
    for _ in 0..30 {
        let r = stuck.step(Action::Forward);
        let p = stuck.true_planar_pose();
        if r.collided {
            assert_eq!((p.x, p.y), (last.x, last.y));
        }
        last = p;
    }
    assert!(last.x <= 3.9 + 1e-9 && last.y < 1.0, "{last:?}");
}

#[test]
fn sensor_and_actuation_streams_are_independent() {
    let realistic = NoiseConfig::realistic();
    let sensor_only = NoiseConfig {
        actuation: ActuationNoise::default(),
        ..realistic
    };
    // Actions drawn from the actuation stream leave the sensor stream where it was.
    let mut a = open_sim(realistic, 7);
    let mut b = open_sim(sensor_only, 7);
    let start = a.true_planar_pose();
    for k in 0..20 {
        a.step(if k % 3 == 0 {
            Action::TurnLeft
        } else {
            Action::Forward
        });
    }
    assert_ne!(a.true_planar_pose(), start);
    a.set_planar_pose(start).unwrap();
    assert_eq!(a.render(), b.render());
    // Frames drawn from the sensor stream leave the trajectory as it was.
    let (mut c, mut d) = (open_sim(realistic, 7), open_sim(realistic, 7));
    for k in 0..20 {
        let action = if k % 4 == 1 {
            Action::TurnRight
        } else {
            Action::Forward
        };
        c.step(action);
        d.step(action);
        let _ = c.render();
    }
    assert_eq!(c.true_planar_pose(), d.true_planar_pose());
    // Another seed is another trajectory.
    let mut e = open_sim(realistic, 8);
    for _ in 0..20 {
        e.step(Action::Forward);
    }
    let mut f = open_sim(realistic, 7);
    for _ in 0..20 {
        f.step(Action::Forward);
    }
    assert_ne!(e.true_planar_pose(), f.true_planar_pose());
}

#[test]
fn evaluation_renders_stay_noise_free() {
    let mut noisy = open_sim(NoiseConfig::realistic(), 5);
    let mut clean = open_sim(NoiseConfig::none(), 5);
    let pose = noisy.true_pose();
    assert_eq!(noisy.render_at(&pose), clean.render_at(&pose));
    assert_ne!(noisy.render(), clean.render());
    // A noise-free simulator renders the same through every path.
    assert_eq!(clean.render(), clean.render_at(&pose));
}

#[test]
fn the_realistic_preset_parses_and_has_the_documented_numbers() {
    let r = NoiseConfig::from_value(&json!("realistic")).unwrap();
    assert_eq!(r, NoiseConfig::realistic());
    assert_eq!(
        r.depth,
        DepthNoise {
            sigma_0: 0.001,
            sigma_z2: 0.0036,
            min_range: 0.28,
            max_range: 10.0,
            edge_threshold: 0.05,
            edge_dropout: 0.5,
            dropout: 0.01,
        }
    );
    assert_eq!(r.rgb, ColourNoise { sigma: 2.0 });
    assert_eq!(
        r.actuation,
        ActuationNoise {
            forward_sigma_frac: 0.056,
            forward_sigma_m: 0.0,
            heading_sigma_deg: 0.09,
            turn_sigma_deg: 0.66,
        }
    );
    // The D435 derivation: c2 = subpixel / (f · baseline), f = 424 / tan(43.5°).
    let f = 424.0 / 43.5f64.to_radians().tan();
    assert!((0.08 / (f * 0.050) - r.depth.sigma_z2).abs() < 5e-5);
    assert_eq!(
        NoisePreset::from_name("none").unwrap().config(),
        NoiseConfig::default()
    );
    assert_eq!(
        NoiseConfig::from_value(&json!("none")).unwrap(),
        NoiseConfig::none()
    );
    assert_eq!(
        NoiseConfig::from_value(&json!(null)).unwrap(),
        NoiseConfig::none()
    );
    assert!(!NoiseConfig::none().is_active());
}

#[test]
fn presets_take_overrides_and_sections_take_preset_names() {
    let v = NoiseConfig::from_value(&json!({
        "preset": "realistic",
        "depth": { "sigma_z2": 0.003 },
    }))
    .unwrap();
    let mut expected = NoiseConfig::realistic();
    expected.depth.sigma_z2 = 0.003;
    assert_eq!(v, expected);
    // Without a preset the base is noise-free; integers are numbers too.
    let v = NoiseConfig::from_value(&json!({
        "rgb": { "sigma": 3 },
        "actuation": { "turn_sigma_deg": 1.5 },
    }))
    .unwrap();
    assert_eq!(v.rgb.sigma, 3.0);
    assert_eq!(v.actuation.turn_sigma_deg, 1.5);
    assert_eq!(v.depth, DepthNoise::default());
    // A section may name a preset.
    let v =
        NoiseConfig::from_value(&json!({ "preset": "realistic", "actuation": "none" })).unwrap();
    assert_eq!(v.actuation, ActuationNoise::default());
    assert_eq!(v.depth, DepthNoise::REALISTIC);
    // The explicit form round-trips.
    let explicit = serde_json::to_value(NoiseConfig::realistic()).unwrap();
    assert!(explicit.get("preset").is_none());
    assert_eq!(
        serde_json::from_value::<NoiseConfig>(explicit).unwrap(),
        NoiseConfig::realistic()
    );
}

#[test]
fn bad_noise_values_are_refused_naming_the_field() {
    let err = |v: serde_json::Value| NoiseConfig::from_value(&v).unwrap_err();
    for (value, names) in [
        (
            json!({ "depth": { "sigma_z2": -0.1 } }),
            "noise.depth.sigma_z2",
        ),
        (
            json!({ "depth": { "dropout": 1.5 } }),
            "noise.depth.dropout",
        ),
        (
            json!({ "depth": { "min_range": 2.0, "max_range": 1.0 } }),
            "noise.depth.max_range",
        ),
        (
            json!({ "depth": { "edge_dropout": 0.5 } }),
            "noise.depth.edge_threshold",
        ),
        (json!({ "rgb": { "sigma": "loud" } }), "noise.rgb.sigma"),
        (
            json!({ "preset": "realistic", "actuation": { "turn_sigma_deg": -1 } }),
            "noise.actuation.turn_sigma_deg",
        ),
        (json!({ "depth": { "sigma_z3": 0.1 } }), "sigma_z3"),
        (json!({ "colour": {} }), "colour"),
        (json!("noisy"), "noisy"),
        (json!({ "preset": "loud" }), "noise.preset"),
        (json!({ "rgb": 2 }), "noise.rgb"),
    ] {
        let e = err(value.clone());
        assert!(e.contains(names), "{value}: {e}");
    }
    let e = err(json!({ "depth": { "sigma_z3": 0.1 } }));
    assert!(e.contains("noise.depth") && e.contains("sigma_z2"), "{e}");
    // The simulator refuses a bad configuration given directly, naming the field too.
    let mut noise = NoiseConfig::realistic();
    noise.rgb.sigma = f64::NAN;
    let config = SimConfig {
        noise,
        ..SimConfig::with_resolution(8, 8)
    };
    let e = Simulator::new(box_room([0.0, 0.0, 0.0], [4.0, 3.0, 2.5]), config)
        .unwrap_err()
        .to_string();
    assert!(e.contains("noise.rgb.sigma"), "{e}");
}
