//! Scripted-loop evaluation in the simulator (issue 5): ground truth only for the metrics.

use activemap_slam::scripted::{LoopConfig, env_or, run_loop};

#[test]
#[ignore = "development driver; run with --ignored --nocapture"]
fn scripted_loop_driver() {
    let mut c = LoopConfig::new(env_or("RES", 160), env_or("FRAMES", 100));
    c.slam.mapper.insert.sample_fraction = env_or("FRAC", c.slam.mapper.insert.sample_fraction);
    c.slam.mapper.insert.scale_factor = env_or("SCALE", c.slam.mapper.insert.scale_factor);
    c.slam.mapper.iterations = env_or("MITS", c.slam.mapper.iterations);
    c.slam.tracker.downscale = env_or("TDOWN", c.slam.tracker.downscale);
    c.slam.tracker.gauss_newton.prior_translation_sigma = env_or(
        "PRIOR_T",
        c.slam.tracker.gauss_newton.prior_translation_sigma,
    );
    c.slam.tracker.gauss_newton.prior_rotation_sigma =
        env_or("PRIOR_R", c.slam.tracker.gauss_newton.prior_rotation_sigma);
    if env_or("SINGLE_LEVEL", 0) == 1 {
        c.slam.tracker.gauss_newton.pyramid = vec![1];
    }
    c.trace = env_or("TRACE", 0) == 1;
    let dense = &mut c.slam.tracker.dense;
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
    let references = &mut c.slam.references;
    references.extra = env_or("REF_EXTRA", references.extra);
    references.min_age = env_or("REF_MIN_AGE", references.min_age);
    let r = run_loop(&c).unwrap();
    eprintln!("{r:?}");
}

/// Issue 5: a 300-frame scripted loop through procedural house 3 at 160×160, tracked with no
/// ground truth (the truth goes to the ATE only), ends with ATE RMSE ≤ 2 cm (the bound)
/// and no lost frame. The run is deterministic; with the ground-robot motion prior and the
/// alignment to older keyframes it gives ATE 0.0511 cm, 60 893 Gaussians and 75 keyframes
/// (single-keyframe odometry gave 1.85 cm). The assertion keeps a 10× margin over that, 0.5 cm,
/// so a real regression fails long before the bound does.
#[test]
fn a_300_frame_loop_at_160px_tracks_within_half_a_centimetre() {
    let c = LoopConfig::new(160, 300);
    let r = run_loop(&c).unwrap();
    eprintln!("{r:?}");
    assert!(r.ate_cm <= 0.5, "{r:?}");
    assert_eq!(r.lost, 0, "{r:?}");
}
