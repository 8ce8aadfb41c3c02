//! Scripted-loop evaluation in the simulator (issue 5): ground truth only for the metrics.

use activemap_slam::scripted::{LoopConfig, run_loop};

fn env<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

#[test]
#[ignore = "development driver; run with --ignored --nocapture"]
fn scripted_loop_driver() {
    let mut c = LoopConfig::new(env("RES", 160), env("FRAMES", 100));
    c.slam.mapper.insert.sample_fraction = env("FRAC", c.slam.mapper.insert.sample_fraction);
    c.slam.mapper.insert.scale_factor = env("SCALE", c.slam.mapper.insert.scale_factor);
    c.slam.mapper.iterations = env("MITS", c.slam.mapper.iterations);
    c.slam.tracker.downscale = env("TDOWN", c.slam.tracker.downscale);
    c.slam.tracker.gauss_newton.prior_translation_sigma = env(
        "PRIOR_T",
        c.slam.tracker.gauss_newton.prior_translation_sigma,
    );
    c.slam.tracker.gauss_newton.prior_rotation_sigma =
        env("PRIOR_R", c.slam.tracker.gauss_newton.prior_rotation_sigma);
    if env("SINGLE_LEVEL", 0) == 1 {
        c.slam.tracker.gauss_newton.pyramid = vec![1];
    }
    let r = run_loop(&c).unwrap();
    eprintln!("{r:?}");
}
