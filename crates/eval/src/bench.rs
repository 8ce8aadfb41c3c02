//! Timing of every metric on synthetic inputs of the paper's sizes (800×800 renders would be
//! larger; 640×480 matches the test data). `activemap bench eval` prints these rows.

use crate::ate::{AteOptions, ate};
use crate::completeness::{COMPLETENESS_THRESHOLD_M, completeness};
use crate::error::EvalError;
use crate::image::ImageView;
use crate::lpips::LpipsAlex;
use crate::{depth_mae, psnr, ssim};
use activemap_geometry::tum::Trajectory;
use nalgebra::{Isometry3, Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::time::Instant;

/// One benchmark result.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchRow {
    /// What was timed.
    pub name: String,
    /// Input size, human-readable.
    pub input: String,
    /// Timed repetitions.
    pub repetitions: usize,
    /// Mean wall time per call, milliseconds (`None` when the metric could not run).
    pub mean_ms: Option<f64>,
    /// The metric's value on the input (a sanity check), or why it could not run.
    pub note: String,
}

/// Mean wall time of `repetitions` calls of `f`, ms, and the last value.
fn time<T>(repetitions: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let start = Instant::now();
    let mut last = f();
    for _ in 1..repetitions {
        last = f();
    }
    (
        start.elapsed().as_secs_f64() * 1e3 / repetitions as f64,
        last,
    )
}

/// A smooth seeded RGB test pattern plus noise, `width × height`, values in [0, 1].
fn pattern(width: usize, height: usize, seed: u64, noise: f32) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::with_capacity(width * height * 3);
    for y in 0..height {
        for x in 0..width {
            for c in 0..3 {
                let v = 0.5 + 0.4 * ((x as f32 * 0.05 + c as f32).sin() * (y as f32 * 0.03).cos());
                out.push((v + noise * rng.random_range(-1.0f32..1.0)).clamp(0.0, 1.0));
            }
        }
    }
    out
}

/// Times PSNR, SSIM, LPIPS (when its weights are present), depth MAE on `width × height`
/// images, ATE on a 2000-pose trajectory and completeness on 200k mesh samples vs 200k points.
/// `repetitions` ≥ 1 per metric.
pub fn run(width: usize, height: usize, repetitions: usize) -> Result<Vec<BenchRow>, EvalError> {
    let repetitions = repetitions.max(1);
    let size = format!("{width}×{height}");
    let a = pattern(width, height, 1, 0.02);
    let b = pattern(width, height, 2, 0.08);
    let ia = ImageView::rgb(&a, width, height)?;
    let ib = ImageView::rgb(&b, width, height)?;
    let mut rows = Vec::new();
    let mut row = |name: &str, input: &str, ms: Option<f64>, note: String| {
        rows.push(BenchRow {
            name: name.into(),
            input: input.into(),
            repetitions,
            mean_ms: ms,
            note,
        });
    };

    let (ms, v) = time(repetitions, || psnr(ia, ib, 1.0));
    row("psnr", &size, Some(ms), format!("{:.4} dB", v?));
    let (ms, v) = time(repetitions, || ssim(ia, ib, 1.0));
    row("ssim", &size, Some(ms), format!("{:.6}", v?));
    match LpipsAlex::load_default() {
        Ok(net) => {
            let (ms, v) = time(repetitions, || net.distance(ia, ib));
            row("lpips_alex", &size, Some(ms), format!("{:.6}", v?));
        }
        Err(e) => row("lpips_alex", &size, None, e.to_string()),
    }
    let depth_a: Vec<f32> = a.iter().step_by(3).map(|v| 0.5 + 4.0 * v).collect();
    let depth_b: Vec<f32> = b.iter().step_by(3).map(|v| 0.5 + 4.0 * v).collect();
    let (ms, v) = time(repetitions, || {
        depth_mae(
            ImageView::depth(&depth_a, width, height)?,
            ImageView::depth(&depth_b, width, height)?,
        )
    });
    row("depth_mae", &size, Some(ms), format!("{:.5} m", v?));

    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let (mut reference, mut estimate) = (Trajectory::default(), Trajectory::default());
    for i in 0..2000 {
        let t = f64::from(i) * 0.1;
        let p = Vector3::new(t.cos() * 3.0, (0.7 * t).sin() * 2.0, 0.01 * t);
        reference.push(t, Isometry3::translation(p.x, p.y, p.z));
        let n = Vector3::new(rng.random(), rng.random(), rng.random()) * 0.02;
        estimate.push(
            t + 0.001,
            Isometry3::translation(p.x + n.x + 1.0, p.y + n.y, p.z + n.z),
        );
    }
    let (ms, v) = time(repetitions, || {
        ate(&reference, &estimate, AteOptions::default())
    });
    row(
        "ate_aligned",
        "2000 poses",
        Some(ms),
        format!("{:.5} m", v?.rmse),
    );

    let box_point = |rng: &mut ChaCha8Rng| {
        Point3::new(
            rng.random_range(0.0..8.0),
            rng.random_range(0.0..8.0),
            rng.random_range(0.0..2.5),
        )
    };
    let truth: Vec<Point3<f64>> = (0..200_000).map(|_| box_point(&mut rng)).collect();
    let observed: Vec<Point3<f64>> = (0..200_000).map(|_| box_point(&mut rng)).collect();
    let (ms, v) = time(repetitions, || {
        completeness(&truth, &observed, COMPLETENESS_THRESHOLD_M)
    });
    row(
        "completeness_5cm",
        "200k vs 200k points",
        Some(ms),
        format!("{:.4}", v?),
    );
    Ok(rows)
}

#[cfg(test)]
mod tests {
    #[test]
    #[ignore = "benchmark: run with --ignored --nocapture"]
    fn print_bench_rows() {
        for r in super::run(640, 480, 3).unwrap() {
            println!("{r:?}");
        }
    }
}
