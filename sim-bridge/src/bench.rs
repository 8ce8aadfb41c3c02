//! The `sim` benchmark: RGB-D frames per second of the renderer for a procedural house and a
//! tessellated (~100k-triangle) version of it, at 200×200 and 800×800, as the agent walks.

use crate::house::{self, HouseConfig};
use crate::simulator::{Action, SimConfig, Simulator};
use std::time::Instant;

/// One benchmark result line.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchRow {
    /// Case name, e.g. `house_800x800`.
    pub case: String,
    /// Rendered RGB-D frames per second (wall clock, one action per frame).
    pub fps: f64,
    /// Process CPU time per frame, milliseconds (all threads; `None` where /proc is absent).
    /// On a shared machine wall-clock fps understates the renderer; this does not.
    pub cpu_ms_per_frame: Option<f64>,
    /// Triangles in the scene.
    pub triangles: usize,
}

impl std::fmt::Display for BenchRow {
    /// `sim <case> fps <x>`, plus the CPU time per frame when known.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "sim {} fps {:.1}", self.case, self.fps)?;
        if let Some(ms) = self.cpu_ms_per_frame {
            write!(f, " cpu_ms_per_frame {ms:.1}")?;
        }
        Ok(())
    }
}

/// CPU time (user + system, all threads) of this process in seconds, from `/proc/self/stat`
/// (clock ticks of 10 ms).
fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which is in parentheses and may hold spaces).
    let rest = &stat[stat.rfind(')')? + 2..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let utime: f64 = fields.get(11)?.parse().ok()?;
    let stime: f64 = fields.get(12)?.parse().ok()?;
    Some((utime + stime) / 100.0)
}

/// Runs the benchmark: `frames` frames per case (a turn or step between frames), seed 1.
pub fn run(frames: usize) -> crate::Result<Vec<BenchRow>> {
    let house = house::generate(1, &HouseConfig::default())?;
    let base = house.scene;
    // Subdivide until about 100k triangles.
    let mut levels = 0;
    while base.triangles.len() * 4usize.pow(levels) < 80_000 {
        levels += 1;
    }
    let dense = base.subdivided(levels);
    let mut rows = Vec::new();
    let dense_label = format!("dense_{}k_tris", dense.triangles.len() / 1000);
    for (label, scene) in [("house", &base), (dense_label.as_str(), &dense)] {
        for size in [200u32, 800] {
            let mut sim = Simulator::new(scene.clone(), SimConfig::with_resolution(size, size))?;
            sim.render(); // warm-up
            let cpu_start = process_cpu_seconds();
            let start = Instant::now();
            for i in 0..frames.max(1) {
                let action = if i % 3 == 2 {
                    Action::Forward
                } else {
                    Action::TurnLeft
                };
                sim.step(action);
                std::hint::black_box(sim.render());
            }
            let secs = start.elapsed().as_secs_f64();
            let cpu = cpu_start
                .zip(process_cpu_seconds())
                .map(|(a, b)| 1000.0 * (b - a) / frames.max(1) as f64);
            rows.push(BenchRow {
                case: format!("{label}_{size}x{size}"),
                fps: frames.max(1) as f64 / secs,
                cpu_ms_per_frame: cpu,
                triangles: scene.triangles.len(),
            });
        }
    }
    Ok(rows)
}
