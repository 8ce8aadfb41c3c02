//! Mapping quality, independent of tracking (issue 5, mapper half).
//!
//! The procedural house (seed 3) and the rectangle loop of `activemap_bench::slam_loop` are
//! rendered by the simulator; the mapping session's [`KeyframeMapper`] (the keyframe rule and
//! the mapper the `mapper` operator runs) receives every frame at its TRUE pose (like the ICL
//! test that maps frames with their given poses). The tracker is never run: this measures the
//! mapper alone. Metrics: held-out PSNR at poses never mapped (every 10th loop pose shifted
//! 2.5 cm forward and turned 2.5°, as in `slam_loop.rs`), training PSNR at the keyframes, the
//! median depth residual `|D̂/o − D|` over covered keyframe pixels, the Gaussian count and the
//! mapping wall time per keyframe.

use activemap_bench::slam_loop::{env_or, held_out_pose, rectangle_loop};
use activemap_geometry::Isometry3;
use activemap_sim::house::{HouseConfig, generate};
use activemap_sim::{SimConfig, Simulator};
use activemap_slam::{
    Frame, KeyframeConfig, KeyframeMapper, MapperConfig, MappingConfig, PoseQuality,
};
use activemap_splat::{Camera, FLAG_UNKNOWN_SPACE, Gaussians, Render, RenderOptions, render};
use std::time::Instant;

/// One mapping-quality run.
struct QualityConfig {
    resolution: u32,
    frames: usize,
    /// Stop after this many keyframes.
    max_keyframes: usize,
    keyframe: KeyframeConfig,
    mapper: MapperConfig,
}

/// What one run measured.
#[derive(Debug)]
#[allow(dead_code)] // Fields are read through Debug in the drivers.
struct QualityResult {
    frames: usize,
    keyframes: usize,
    psnr_train: f64,
    psnr_test: f64,
    held_out_views: usize,
    depth_median_residual_m: f64,
    gaussians: usize,
    seconds_per_keyframe: f64,
    /// Process CPU seconds (all threads) per keyframe: with the machine shared, CPU/2 is
    /// closer to the wall time on a quiet 2-core machine than the loaded wall time.
    cpu_seconds_per_keyframe: f64,
    inserted: usize,
    pruned: usize,
    densified: usize,
}

fn render_clean(map: &Gaussians<f32>, frame: &Frame, pose: &Isometry3<f64>) -> Render<f32> {
    let camera = Camera::from_world_pose(frame.intrinsics, pose);
    render(
        map,
        &camera,
        &RenderOptions {
            exposure: [0.0, 0.0],
            exclude_flags: FLAG_UNKNOWN_SPACE,
            ..Default::default()
        },
    )
    .expect("render")
}

/// PSNR (peak 1) of the rendered colour, clamped to [0, 1], against the frame.
fn psnr(rendered: &Render<f32>, frame: &Frame) -> f64 {
    let mut se = 0.0f64;
    for (r, t) in rendered.colour.iter().zip(&frame.rgb) {
        for c in 0..3 {
            let d = (r[c].clamp(0.0, 1.0) - t[c]) as f64;
            se += d * d;
        }
    }
    let mse = se / (3 * frame.rgb.len()) as f64;
    -10.0 * mse.log10()
}

fn frame_of(sim: &mut Simulator, pose: Option<&Isometry3<f64>>) -> Frame {
    let rgbd = match pose {
        Some(p) => sim.render_at(p),
        None => sim.render(),
    };
    Frame::from_rgb8(rgbd.intrinsics, &rgbd.rgb, rgbd.depth, 0.0).expect("frame")
}

fn run(config: &QualityConfig) -> QualityResult {
    let house = generate(3, &HouseConfig::default()).expect("house");
    let room = *house.start_room().expect("the house has rooms");
    let (start, actions) = rectangle_loop(room.min, room.max, 0.7, config.frames);
    let sim_config = SimConfig {
        start: Some(start),
        ..SimConfig::with_resolution(config.resolution, config.resolution)
    };
    let mut sim = Simulator::new(house.scene, sim_config).expect("simulator");
    let mut mapper = KeyframeMapper::new(MappingConfig {
        mapper: config.mapper.clone(),
        keyframe: config.keyframe.clone(),
        ..MappingConfig::default()
    })
    .expect("mapper");
    let mut map_seconds = 0.0;
    let mut cpu_seconds = 0.0;
    let mut held_out = Vec::new();
    let mut frames = 0;
    let mut totals = [0usize; 3];
    for i in 0..config.frames {
        if i > 0 {
            sim.step(actions[(i - 1).min(actions.len() - 1)]);
        }
        frames += 1;
        let frame = frame_of(&mut sim, None);
        let pose = sim.true_pose();
        if i % 10 == 5 {
            held_out.push(held_out_pose(&sim));
        }
        let t = Instant::now();
        let cpu_start = process_cpu_seconds();
        let Some(report) = mapper
            .process(None, frame, &pose, PoseQuality::Ok)
            .expect("mapping")
        else {
            continue;
        };
        totals[0] += report.inserted;
        totals[1] += report.pruned;
        totals[2] += report.densified;
        map_seconds += t.elapsed().as_secs_f64();
        cpu_seconds += process_cpu_seconds() - cpu_start;
        if mapper.keyframes() >= config.max_keyframes {
            break;
        }
    }
    let mapper = mapper.mapper();
    let map = mapper.map();
    let mut train = Vec::new();
    let mut residuals = Vec::new();
    for kf in mapper.keyframes() {
        let r = render_clean(map, &kf.frame, &kf.pose);
        train.push(psnr(&r, &kf.frame));
        for p in 0..kf.frame.depth.len() {
            let (d, o) = (kf.frame.depth[p], r.opacity[p]);
            if d > 0.01 && o > 0.5 {
                residuals.push((r.depth[p] / o - d).abs());
            }
        }
    }
    let mut test = Vec::new();
    for pose in &held_out {
        let frame = frame_of(&mut sim, Some(pose));
        test.push(psnr(&render_clean(map, &frame, pose), &frame));
    }
    residuals.sort_by(f32::total_cmp);
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    QualityResult {
        frames,
        keyframes: mapper.keyframes().len(),
        psnr_train: mean(&train),
        psnr_test: mean(&test),
        held_out_views: test.len(),
        depth_median_residual_m: residuals
            .get(residuals.len() / 2)
            .map_or(f64::NAN, |&r| r as f64),
        gaussians: map.len(),
        seconds_per_keyframe: map_seconds / mapper.keyframes().len().max(1) as f64,
        cpu_seconds_per_keyframe: cpu_seconds / mapper.keyframes().len().max(1) as f64,
        inserted: totals[0],
        pruned: totals[1],
        densified: totals[2],
    }
}

/// User + system CPU time of this process so far, seconds (Linux `/proc/self/stat`, clock
/// ticks of 1/100 s); NaN elsewhere.
fn process_cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return f64::NAN;
    };
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let after = stat.rsplit(')').next().unwrap_or("");
    let fields: Vec<&str> = after.split_whitespace().collect();
    let ticks = |k: usize| fields.get(k).and_then(|v| v.parse::<f64>().ok());
    match (ticks(11), ticks(12)) {
        (Some(u), Some(s)) => (u + s) / 100.0,
        _ => f64::NAN,
    }
}

/// Development driver: `RES=160 FRAMES=120 cargo test -p activemap-bench --test
/// mapping_quality -- --ignored --nocapture`.
#[test]
#[ignore = "development driver; run with --ignored --nocapture"]
fn mapping_quality_driver() {
    let mut mapper = MapperConfig::default();
    mapper.iterations = env_or("MITS", mapper.iterations);
    mapper.insert.sample_fraction = env_or("FRAC", mapper.insert.sample_fraction);
    mapper.prune_opacity_window = env_or("PRUNE", mapper.prune_opacity_window);
    mapper.window = env_or("WINDOW", mapper.window);
    mapper.prune_min_age = env_or("MIN_AGE", mapper.prune_min_age);
    mapper.views_per_iteration = env_or("VIEWS", mapper.views_per_iteration);
    mapper.insert.target_samples = env_or("TARGET", mapper.insert.target_samples);
    mapper.densify_grad = env_or("DENSIFY", mapper.densify_grad);
    mapper.coarse_iterations = env_or("COARSE", mapper.coarse_iterations);
    mapper.insert.scale_factor = env_or("SCALE", mapper.insert.scale_factor);
    mapper.insert.opacity = env_or("OPACITY", mapper.insert.opacity);
    let mut keyframe = KeyframeConfig::default();
    keyframe.min_covisibility = env_or("COVIS", keyframe.min_covisibility);
    keyframe.translation_fraction = env_or("KF_T", keyframe.translation_fraction);
    let config = QualityConfig {
        resolution: env_or("RES", 160),
        frames: env_or("FRAMES", 120),
        max_keyframes: env_or("MAX_KF", usize::MAX),
        keyframe,
        mapper,
    };
    let r = run(&config);
    eprintln!("res {} {r:?}", config.resolution);
}

/// Quality floor on a short sequence at 80×80 with the default mapper (10 keyframes, 44
/// frames). Measured (this seed, deterministic): held-out PSNR 27.0 dB and depth median
/// residual 2.5 cm with the session-3 defaults. The session-2 mapper defaults (opacity 0.5,
/// scale 1× the 1/64 spacing, window prune at 0.7, every window view per iteration, densify at
/// 2e-4) gave 25.0 dB and 17.6 cm on the same frames, and the 0.7 window prune applied to
/// young Gaussians (age 10) emptied the map (4.4 dB). The floors below (25.8 dB, 6 cm) fail
/// on those maps and leave 1.2 dB of margin to the current one.
#[test]
fn short_sequence_meets_a_quality_floor() {
    let config = QualityConfig {
        resolution: 80,
        frames: 60,
        max_keyframes: 10,
        keyframe: KeyframeConfig::default(),
        mapper: MapperConfig::default(),
    };
    let r = run(&config);
    eprintln!("{r:?}");
    assert!(r.keyframes >= 5, "{r:?}");
    assert!(r.held_out_views >= 2, "{r:?}");
    assert!(r.psnr_test >= 25.8, "held-out PSNR below the floor: {r:?}");
    assert!(
        r.depth_median_residual_m <= 0.06,
        "depth residual above the ceiling: {r:?}"
    );
}
