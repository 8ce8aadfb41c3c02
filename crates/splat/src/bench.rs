//! Benchmark of the renderer (`activemap bench splat`): forward, forward+backward and the
//! Fisher pass at 200×200 and 800×800 with 10k and 100k Gaussians plus the SLAM-tracking sizes
//! 100×100/10k and 200×200/40k, (pixel, Gaussian) pairs per second, the share of a rough 2-core compute roofline the forward pass reaches, and the
//! ratio to a CPU reference rasteriser written in JAX (`tools/splat_reference/`), run on the
//! same scene (exported as PLY) with the same thread count in the same run.

use crate::backward::{PixelGrads, backward};
use crate::camera::Camera;
use crate::fisher::{FisherMode, fisher};
use crate::gaussians::Gaussians;
use crate::rasterize::{RenderOptions, render};
use activemap_geometry::Intrinsics;
use nalgebra::Isometry3;
use rand::{Rng, SeedableRng};
use std::path::PathBuf;
use std::time::Instant;

/// What to run.
#[derive(Debug, Clone)]
pub struct BenchConfig {
    /// Image sizes (square), pixels.
    pub sizes: Vec<u32>,
    /// Gaussian counts.
    pub counts: Vec<usize>,
    /// Further `(size, count)` cases run after the `sizes × counts` grid: the small images SLAM
    /// tracking renders up to 100 times per frame (SPEC §4).
    pub extra_cases: Vec<(u32, usize)>,
    /// Timed repetitions per case (the median is reported).
    pub repeats: usize,
    /// The reference script (`tools/splat_reference/reference.py`); `None` skips the comparison.
    pub reference_script: Option<PathBuf>,
    /// Peak single-precision FLOP/s of the machine for the roofline share (default: 2 cores ×
    /// 2 GHz × 2 AVX-512 FMA units × 16 lanes × 2 flops = 256 GFLOP/s).
    pub peak_flops: f64,
}

impl Default for BenchConfig {
    fn default() -> Self {
        Self {
            sizes: vec![200, 800],
            counts: vec![10_000, 100_000],
            extra_cases: vec![(100, 10_000), (200, 40_000)],
            repeats: 5,
            reference_script: None,
            peak_flops: 2.0 * 2.0e9 * 2.0 * 16.0 * 2.0,
        }
    }
}

impl BenchConfig {
    /// The default cases with the JAX reference script of this repository
    /// (`tools/splat_reference/reference.py`, located at compile time) when it exists.
    pub fn with_reference() -> Self {
        let script = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../../tools/splat_reference/reference.py");
        Self {
            reference_script: script.exists().then_some(script),
            ..Self::default()
        }
    }
}

/// One benchmark result.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// Case name, e.g. `800x800_100k_forward`.
    pub case: String,
    /// Median wall time, milliseconds.
    pub median_ms: f64,
    /// Reference time / our time (how many times faster), when the reference ran.
    pub ratio_vs_ref: Option<f64>,
    /// (pixel, Gaussian) pairs evaluated per second (pixels inside each visible Gaussian's box).
    pub pairs_per_second: f64,
    /// Share of the compute roofline (forward rows only).
    pub roofline_share: Option<f64>,
}

impl std::fmt::Display for Row {
    /// `splat <case> median_ms <x> ratio_vs_ref <r> pairs_per_s <p> [roofline <s>]`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let ratio = self
            .ratio_vs_ref
            .map_or("nan".to_string(), |r| format!("{r:.2}"));
        write!(
            f,
            "splat {} median_ms {:.3} ratio_vs_ref {} pairs_per_s {:.3e}",
            self.case, self.median_ms, ratio, self.pairs_per_second
        )?;
        if let Some(s) = self.roofline_share {
            write!(f, " roofline {:.4}", s)?;
        }
        Ok(())
    }
}

/// Rough FLOPs per (pixel, Gaussian) evaluation of the forward pass: offset 2, quadratic form
/// 7, exp ≈ 15, alpha/threshold 3, compositing 10.
pub const FORWARD_FLOPS_PER_PAIR: f64 = 37.0;

/// The benchmark scene: `n` Gaussians spread in the 90° frustum of a camera at the origin
/// looking along +z, depth 1–5 m, scales 1–5 cm, opacity 0.3–0.9 (seed 7).
pub fn scene(n: usize) -> Gaussians<f32> {
    let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let mut g = Gaussians::new();
    for _ in 0..n {
        let z: f64 = r.random_range(1.0..5.0);
        let mean = [
            r.random_range(-0.95..0.95) * z,
            r.random_range(-0.95..0.95) * z,
            z,
        ];
        let rgb = [0; 3].map(|_| r.random_range(0.0..1.0));
        let q = [0; 4].map(|_| r.random_range(-1.0..1.0));
        let scale = [0; 3].map(|_| r.random_range(0.01..0.05));
        g.push(mean, rgb, q, r.random_range(0.3..0.9), scale);
    }
    g
}

/// The benchmark camera: 90° field of view, identity pose.
pub fn camera(size: u32) -> Camera {
    Camera::new(
        Intrinsics::from_hfov(size, size, std::f64::consts::FRAC_PI_2),
        Isometry3::identity(),
    )
}

fn median_ms(repeats: usize, mut f: impl FnMut()) -> f64 {
    f(); // warm-up
    let mut times: Vec<f64> = (0..repeats.max(1))
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    times.sort_by(|a, b| a.total_cmp(b));
    times[times.len() / 2]
}

/// Runs the reference script on a PLY scene; returns its `case → median_ms` lines.
fn run_reference(
    script: &PathBuf,
    ply: &std::path::Path,
    size: u32,
    repeats: usize,
) -> Result<Vec<(String, f64)>, String> {
    let threads = rayon::current_num_threads();
    let out = std::process::Command::new("python3")
        .arg(script)
        .args([
            "--ply",
            &ply.display().to_string(),
            "--size",
            &size.to_string(),
            "--repeats",
            &repeats.to_string(),
        ])
        .args(["--threads", &threads.to_string()])
        .output()
        .map_err(|e| format!("cannot start python3 {}: {e}", script.display()))?;
    if !out.status.success() {
        return Err(format!(
            "reference failed: {}",
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    Ok(String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| {
            let w: Vec<&str> = l.split_whitespace().collect();
            match w.as_slice() {
                ["ref", case, "median_ms", ms, ..] => {
                    ms.parse().ok().map(|m| (case.to_string(), m))
                }
                ["ref", "image_sum", sum, ..] => {
                    sum.parse().ok().map(|m| ("image_sum".to_string(), m))
                }
                _ => None,
            }
        })
        .collect())
}

/// Runs every case; errors of the reference run are reported on stderr and leave
/// `ratio_vs_ref` empty.
pub fn run(cfg: &BenchConfig) -> Vec<Row> {
    let mut rows = Vec::new();
    let dir = std::env::temp_dir().join(format!("activemap-splat-bench-{}", std::process::id()));
    let mut cases: Vec<(usize, Vec<u32>)> =
        cfg.counts.iter().map(|&n| (n, cfg.sizes.clone())).collect();
    for &(size, n) in &cfg.extra_cases {
        match cases.iter_mut().find(|(count, _)| *count == n) {
            Some((_, sizes)) if !sizes.contains(&size) => sizes.push(size),
            Some(_) => {}
            None => cases.push((n, vec![size])),
        }
    }
    for (n, sizes) in cases {
        let g = scene(n);
        let ply = dir.join(format!("scene_{n}.ply"));
        let ply_ok =
            std::fs::create_dir_all(&dir).is_ok() && crate::ply::write_ply(&ply, &g).is_ok();
        for size in sizes {
            let cam = camera(size);
            let opts = RenderOptions::default();
            let Ok(out) = render(&g, &cam, &opts) else {
                continue;
            };
            // The Fisher pass takes a centre-depth render.
            let centre = RenderOptions {
                depth: crate::DepthModel::Centre,
                ..opts
            };
            let Ok(fisher_out) = render(&g, &cam, &centre) else {
                continue;
            };
            let pairs: f64 = (0..g.len())
                .filter(|&i| out.context.visible[i])
                .map(|i| {
                    let b = out.context.splats[i].bbox;
                    ((b[1] - b[0] + 1) as f64) * ((b[3] - b[2] + 1) as f64)
                })
                .sum();
            let mut dl = PixelGrads::zeros(out.colour.len());
            for (i, c) in dl.colour.iter_mut().enumerate() {
                *c = [((i % 7) as f32 - 3.0) * 0.01; 3];
            }
            let forward = median_ms(cfg.repeats, || {
                let _ = render(&g, &cam, &opts);
            });
            let both = median_ms(cfg.repeats, || {
                if let Ok(o) = render(&g, &cam, &opts) {
                    let _ = backward(&g, &o, &dl);
                }
            });
            // Backward and Fisher alternate, so that load changes hit both alike.
            let (mut back_times, mut fisher_times) = (Vec::new(), Vec::new());
            for r in 0..=cfg.repeats.max(1) {
                let t = Instant::now();
                let _ = backward(&g, &out, &dl);
                let tb = t.elapsed().as_secs_f64() * 1e3;
                let t = Instant::now();
                let _ = fisher(&g, &fisher_out, FisherMode::PerChannel);
                let tf = t.elapsed().as_secs_f64() * 1e3;
                if r > 0 {
                    back_times.push(tb);
                    fisher_times.push(tf);
                }
            }
            let median = |mut v: Vec<f64>| {
                v.sort_by(|a, b| a.total_cmp(b));
                v[v.len() / 2]
            };
            let back_only = median(back_times);
            let fisher_ms = median(fisher_times);
            let reference = match (&cfg.reference_script, ply_ok) {
                (Some(script), true) => run_reference(script, &ply, size, cfg.repeats.min(2))
                    .unwrap_or_else(|e| {
                        eprintln!("splat bench: {e}");
                        Vec::new()
                    }),
                _ => Vec::new(),
            };
            if let Some((_, sum)) = reference.iter().find(|(c, _)| c == "image_sum") {
                let ours: f64 = out
                    .colour
                    .iter()
                    .flat_map(|c| c.iter())
                    .map(|v| *v as f64)
                    .sum();
                eprintln!(
                    "splat {size}x{size} n={n}: colour sum ours {ours:.3}, reference {sum:.3}"
                );
            }
            let ratio = |name: &str, ms: f64| {
                reference
                    .iter()
                    .find(|(c, _)| c == name)
                    .map(|(_, r)| r / ms)
            };
            let label = format!("{size}x{size}_{}k", n / 1000);
            let pps = |ms: f64| pairs / (ms * 1e-3);
            rows.push(Row {
                case: format!("{label}_forward"),
                median_ms: forward,
                ratio_vs_ref: ratio("forward", forward),
                pairs_per_second: pps(forward),
                roofline_share: Some(pps(forward) * FORWARD_FLOPS_PER_PAIR / cfg.peak_flops),
            });
            rows.push(Row {
                case: format!("{label}_forward_backward"),
                median_ms: both,
                ratio_vs_ref: ratio("forward_backward", both),
                pairs_per_second: pps(both),
                roofline_share: None,
            });
            rows.push(Row {
                case: format!("{label}_backward"),
                median_ms: back_only,
                ratio_vs_ref: None,
                pairs_per_second: pps(back_only),
                roofline_share: None,
            });
            rows.push(Row {
                case: format!("{label}_fisher"),
                median_ms: fisher_ms,
                ratio_vs_ref: None,
                pairs_per_second: pps(fisher_ms),
                roofline_share: None,
            });
        }
        let _ = std::fs::remove_file(&ply);
    }
    let _ = std::fs::remove_dir(&dir);
    rows
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Development driver: `cargo test -p activemap-splat --release bench -- --ignored --nocapture`.
    fn list<V: std::str::FromStr>(name: &str) -> Option<Vec<V>> {
        std::env::var(name)
            .ok()
            .map(|v| v.split(',').filter_map(|x| x.parse().ok()).collect())
    }

    /// CPU time of the whole process (all threads), nanoseconds, from /proc (Linux).
    fn process_cpu_ns() -> u64 {
        let mut total = 0;
        if let Ok(dir) = std::fs::read_dir("/proc/self/task") {
            for task in dir.flatten() {
                if let Ok(s) = std::fs::read_to_string(task.path().join("schedstat")) {
                    total += s
                        .split_whitespace()
                        .next()
                        .and_then(|v| v.parse::<u64>().ok())
                        .unwrap_or(0);
                }
            }
        }
        total
    }

    /// Development driver for the Fisher/backward cost ratio in CPU time (less sensitive to
    /// other processes than wall time); forward, backward and Fisher alternate, medians:
    /// `SPLAT_PROFILE_CASES=800x100000,200x10000 RAYON_NUM_THREADS=1 cargo test -p
    /// activemap-splat --release --lib profile_fisher_ratio -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn profile_fisher_ratio() {
        let cases = std::env::var("SPLAT_PROFILE_CASES").unwrap_or("200x10000".into());
        let repeats: usize = std::env::var("SPLAT_BENCH_REPEATS")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(5);
        let cpu_ms = |f: &mut dyn FnMut()| {
            let t = process_cpu_ns();
            f();
            (process_cpu_ns() - t) as f64 * 1e-6
        };
        let median = |mut v: Vec<f64>| {
            v.sort_by(|a, b| a.total_cmp(b));
            v[v.len() / 2]
        };
        for case in cases.split(',') {
            let (size, n) = case.split_once('x').expect("SIZExCOUNT");
            let (size, n): (u32, usize) = (size.parse().unwrap(), n.parse().unwrap());
            let g = scene(n);
            let cam = camera(size);
            let opts = RenderOptions::default();
            let out = render(&g, &cam, &opts).unwrap();
            let fisher_out = render(
                &g,
                &cam,
                &RenderOptions {
                    depth: crate::DepthModel::Centre,
                    ..opts
                },
            )
            .unwrap();
            let mut dl = PixelGrads::zeros(out.colour.len());
            for (i, c) in dl.colour.iter_mut().enumerate() {
                *c = [((i % 7) as f32 - 3.0) * 0.01; 3];
            }
            let (mut fwd, mut back, mut fish) = (Vec::new(), Vec::new(), Vec::new());
            for r in 0..=repeats {
                let tr = cpu_ms(&mut || {
                    let _ = render(&g, &cam, &opts);
                });
                let tb = cpu_ms(&mut || {
                    let _ = backward(&g, &out, &dl);
                });
                let tf = cpu_ms(&mut || {
                    let _ = fisher(&g, &fisher_out, FisherMode::PerChannel);
                });
                if r > 0 {
                    fwd.push(tr);
                    back.push(tb);
                    fish.push(tf);
                }
            }
            let (r, b, f) = (median(fwd), median(back), median(fish));
            println!(
                "profile {case}: forward cpu_ms {r:.2} backward cpu_ms {b:.2} fisher cpu_ms {f:.2} fisher/backward {:.3}",
                f / b
            );
        }
    }

    #[test]
    #[ignore]
    fn run_benchmark() {
        let script = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../../tools/splat_reference/reference.py");
        let cfg = BenchConfig {
            reference_script: std::env::var("SPLAT_BENCH_REF").is_ok().then_some(script),
            repeats: std::env::var("SPLAT_BENCH_REPEATS")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(3),
            sizes: list("SPLAT_BENCH_SIZES").unwrap_or(vec![200, 800]),
            counts: list("SPLAT_BENCH_COUNTS").unwrap_or(vec![10_000, 100_000]),
            extra_cases: if std::env::var("SPLAT_BENCH_NO_EXTRA").is_ok() {
                Vec::new()
            } else {
                BenchConfig::default().extra_cases
            },
            ..Default::default()
        };
        // SPLAT_BENCH_CASES=800x100000,200x10000 runs only those (size, count) cases.
        let cfg = match std::env::var("SPLAT_BENCH_CASES") {
            Ok(v) => {
                let cases: Vec<(u32, usize)> = v
                    .split(',')
                    .filter_map(|c| {
                        let (s, n) = c.split_once('x')?;
                        Some((s.parse().ok()?, n.parse().ok()?))
                    })
                    .collect();
                BenchConfig {
                    sizes: Vec::new(),
                    counts: Vec::new(),
                    extra_cases: cases,
                    ..cfg
                }
            }
            Err(_) => cfg,
        };
        for row in run(&cfg) {
            println!("{row}");
        }
    }
}
