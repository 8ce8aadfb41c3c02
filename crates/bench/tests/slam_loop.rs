//! Scripted-loop evaluation in the simulator (issue 5): ground truth only for the metrics.

mod common;

use activemap_bench::slam_loop::{LoopConfig, env_or, run_loop};

#[test]
#[ignore = "development driver; run with --ignored --nocapture"]
fn scripted_loop_driver() {
    let mut c = LoopConfig::new(
        env_or("RES", 160),
        env_or("FRAMES", 100),
        common::flow_slam_config(),
    );
    let mapper = &mut c.slam.mapping.mapper;
    mapper.insert.sample_fraction = env_or("FRAC", mapper.insert.sample_fraction);
    mapper.insert.scale_factor = env_or("SCALE", mapper.insert.scale_factor);
    mapper.iterations = env_or("MITS", mapper.iterations);
    let tracker = &mut c.slam.tracking.tracker;
    tracker.downscale = env_or("TDOWN", tracker.downscale);
    tracker.gauss_newton.prior_translation_sigma =
        env_or("PRIOR_T", tracker.gauss_newton.prior_translation_sigma);
    tracker.gauss_newton.prior_rotation_sigma =
        env_or("PRIOR_R", tracker.gauss_newton.prior_rotation_sigma);
    if env_or("SINGLE_LEVEL", 0) == 1 {
        tracker.gauss_newton.pyramid = vec![1];
    }
    c.trace = env_or("TRACE", 0) == 1;
    let dense = &mut c.slam.tracking.tracker.dense;
    dense.depth_sigma = env_or("DSIG", dense.depth_sigma);
    dense.colour_sigma = env_or("CSIG", dense.colour_sigma);
    dense.prior_translation_sigma = env_or("DPT", dense.prior_translation_sigma);
    if env_or("GROUND", 1) == 0 {
        dense.prior_axis_sigmas = [0.0; 6];
    }
    dense.prior_axis_sigmas[0] = env_or("LAT", dense.prior_axis_sigmas[0]);
    if env_or("COARSE", 1) == 0 {
        dense.pyramid = vec![2, 1];
    }
    let references = &mut c.slam.tracking.references;
    references.extra = env_or("REF_EXTRA", references.extra);
    references.min_age = env_or("REF_MIN_AGE", references.min_age);
    let r = run_loop(&c).unwrap();
    eprintln!("{r:?}");
}

/// Issue 5: a 300-frame scripted loop through procedural house 3 at 160×160, tracked with no
/// ground truth (the truth goes to the ATE only), ends with ATE RMSE ≤ 2 cm (the bound)
/// and no lost frame. SLAM runs as the pipeline runs it: the tracking and mapping sessions with
/// the `tracker` and `mapper` node configs of `dataflow.yaml` (map lag 10, keyframes at least 5
/// frames apart). The run is deterministic and gives ATE 0.273 cm, 51 439 Gaussians and 60
/// keyframes (the former facade, which mapped without lag every second frame and re-referenced
/// at every keyframe, gave 0.0511 cm). The assertion keeps the 0.5 cm bound, well inside the
/// issue's, so a real regression fails long before the bound does.
#[test]
fn a_300_frame_loop_at_160px_tracks_within_half_a_centimetre() {
    let c = LoopConfig::new(160, 300, common::flow_slam_config());
    let r = run_loop(&c).unwrap();
    eprintln!("{r:?}");
    assert!(r.ate_cm <= 0.5, "{r:?}");
    assert_eq!(r.lost, 0, "{r:?}");
}
