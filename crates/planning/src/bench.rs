//! Timings of the pieces the exploration loop runs (the loop's budget is ≥ 3 steps/s end to
//! end, SPEC §1 / issue 6): A* on a 400×400 grid, an occupancy update from a 160×160 depth
//! frame, frontier extraction on a 400×400 grid, and a synthetic FBE episode per house.
//! `activemap bench planning` prints the rows; [`run`] is driven by an ignored test here.

use std::time::{Duration, Instant};

use activemap_geometry::{Intrinsics, camera_pose_from_planar};
use nalgebra::Point2;
use serde::{Deserialize, Serialize};

use crate::astar::{AstarConfig, plan};
use crate::clearance::{ClearanceConfig, ClearanceMap};
use crate::dynamics::{Action, ActionModel};
use crate::error::PlanningError;
use crate::explorer::{Decision, Explorer, ExplorerConfig};
use crate::frontier::{FrontierConfig, extract_frontiers};
use crate::grid::{CellState, Grid, OccupancyGrid};
use crate::occupancy::{OccupancyConfig, OccupancyMapper};
use crate::synthetic::SyntheticWorld;

/// What to measure.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BenchConfig {
    /// Repetitions of each micro-benchmark (the median is reported).
    pub repetitions: usize,
    /// House seeds for the FBE episodes (empty: no episodes).
    pub explore_seeds: Vec<u64>,
    /// Step budget of each episode.
    pub explore_steps: usize,
    /// Depth resolution (square) of the episodes and of the occupancy benchmark.
    pub depth_size: u32,
}

impl Default for BenchConfig {
    fn default() -> Self {
        Self {
            repetitions: 5,
            explore_seeds: vec![1, 2, 3],
            explore_steps: 2000,
            depth_size: 160,
        }
    }
}

/// One measured figure.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BenchRow {
    /// What was measured, e.g. `astar_400x400`.
    pub name: String,
    /// The value.
    pub value: f64,
    /// Its unit, e.g. `ms`.
    pub unit: String,
}

fn row(name: impl Into<String>, value: f64, unit: &str) -> BenchRow {
    BenchRow {
        name: name.into(),
        value,
        unit: unit.into(),
    }
}

fn median_ms(mut samples: Vec<Duration>) -> f64 {
    samples.sort();
    samples
        .get(samples.len() / 2)
        .map_or(f64::NAN, |d| d.as_secs_f64() * 1e3)
}

/// The true occupancy of a synthetic world (obstacles above 5 cm occupied, the rest free).
fn truth_grid(world: &SyntheticWorld) -> OccupancyGrid {
    let data = world
        .heights
        .data
        .iter()
        .map(|h| {
            if *h > 0.05 {
                CellState::Occupied
            } else {
                CellState::Free
            }
        })
        .collect();
    Grid {
        geometry: world.heights.geometry,
        data,
    }
}

/// Runs every benchmark and returns its rows.
pub fn run(config: &BenchConfig) -> Result<Vec<BenchRow>, PlanningError> {
    let reps = config.repetitions.max(1);
    let mut rows = Vec::new();
    // A 6×6-room house of 3.3 m rooms: 398×398 cells at 5 cm.
    let world = SyntheticWorld::procedural_house(11, 6, 6, 3.3)?;
    let truth = truth_grid(&world);
    let g = truth.geometry;
    rows.push(row("grid_cells", g.len() as f64, "cells"));

    // Clearance map (EDT) and A* across the house.
    let start = g.cell_of(Point2::new(world.start.x, world.start.y));
    let goal_p = Point2::new(
        g.width as f64 * g.resolution - 1.6,
        g.height as f64 * g.resolution - 1.6,
    );
    let mut goal = g.cell_of(goal_p);
    let mut times_edt = Vec::new();
    let mut times_astar = Vec::new();
    let mut length = f64::NAN;
    for _ in 0..reps {
        let t = Instant::now();
        let map = ClearanceMap::new(&truth, &ClearanceConfig::default())?;
        times_edt.push(t.elapsed());
        if !map.is_clear(goal) {
            // Move the goal to the nearest clear cell.
            goal = (0..g.len())
                .map(|i| g.cell_at(i))
                .filter(|c| map.is_clear(*c))
                .min_by(|a, b| a.distance(&goal).total_cmp(&b.distance(&goal)))
                .unwrap_or(goal);
        }
        let t = Instant::now();
        let path = plan(&map, start, goal, &AstarConfig::default())?;
        times_astar.push(t.elapsed());
        length = path.map_or(f64::NAN, |p| p.length_m(&g));
    }
    rows.push(row("clearance_edt_400x400", median_ms(times_edt), "ms"));
    rows.push(row("astar_400x400", median_ms(times_astar), "ms"));
    rows.push(row("astar_400x400_path_length", length, "m"));

    // Occupancy from one depth frame.
    let k = Intrinsics::from_hfov(
        config.depth_size,
        config.depth_size,
        std::f64::consts::FRAC_PI_2,
    );
    let cam = camera_pose_from_planar(&world.start, 0.0, 0.88);
    let depth = world.render_depth(&k, &cam);
    let mut times_occ = Vec::new();
    let mut times_grid = Vec::new();
    for _ in 0..reps {
        let mut mapper = OccupancyMapper::new(
            OccupancyConfig::default(),
            Point2::new(0.0, 0.0),
            Point2::new(
                g.width as f64 * g.resolution,
                g.height as f64 * g.resolution,
            ),
        )?;
        let t = Instant::now();
        mapper.integrate_depth(&depth, &k, &cam)?;
        times_occ.push(t.elapsed());
        let t = Instant::now();
        let _ = mapper.grid();
        times_grid.push(t.elapsed());
    }
    let n = config.depth_size;
    rows.push(row(
        format!("occupancy_depth_{n}x{n}"),
        median_ms(times_occ),
        "ms",
    ));
    rows.push(row("occupancy_grid_400x400", median_ms(times_grid), "ms"));

    // Frontiers on a half-explored 400×400 grid: unknown beyond 6 m from the start.
    let mut partial = truth.clone();
    let s = Point2::new(world.start.x, world.start.y);
    for i in 0..g.len() {
        if (g.center(g.cell_at(i)) - s).norm() > 6.0 {
            partial.data[i] = CellState::Unknown;
        }
    }
    let mut times_frontier = Vec::new();
    let mut regions = 0;
    for _ in 0..reps {
        let t = Instant::now();
        let map = ClearanceMap::new(&partial, &ClearanceConfig::default())?;
        let f = extract_frontiers(&partial, &map, s, &FrontierConfig::default())?;
        times_frontier.push(t.elapsed());
        regions = f.regions.len();
    }
    rows.push(row("frontiers_400x400", median_ms(times_frontier), "ms"));
    rows.push(row("frontiers_400x400_regions", regions as f64, "regions"));

    for seed in &config.explore_seeds {
        rows.extend(explore_episode(*seed, config)?);
    }
    Ok(rows)
}

/// One FBE episode on a 3×2-room house (seeded) with true poses; rows: coverage, steps,
/// path length, planning-loop steps per second (without rendering) and the time shares.
pub fn explore_episode(seed: u64, config: &BenchConfig) -> Result<Vec<BenchRow>, PlanningError> {
    let world = SyntheticWorld::procedural_house(seed, 3, 2, 3.0)?;
    let k = Intrinsics::from_hfov(
        config.depth_size,
        config.depth_size,
        std::f64::consts::FRAC_PI_2,
    );
    let model = ActionModel::default();
    let mut ex = Explorer::new(
        ExplorerConfig::default(),
        Point2::new(world.start.x - 1.0, world.start.y - 1.0),
        Point2::new(world.start.x + 1.0, world.start.y + 1.0),
    )?;
    let mut pose = world.start;
    let (mut steps, mut path, mut bumps) = (0usize, 0.0, 0usize);
    let (mut render, mut loop_time) = (Duration::ZERO, Duration::ZERO);
    for _ in 0..config.explore_steps {
        let cam = camera_pose_from_planar(&pose, 0.0, 0.88);
        let t = Instant::now();
        let depth = world.render_depth(&k, &cam);
        render += t.elapsed();
        let t = Instant::now();
        let decision = ex.step(&pose, &depth, &k, &cam)?;
        loop_time += t.elapsed();
        steps += 1;
        match decision {
            Decision::Finished => break,
            Decision::Act(a) => {
                let next = world.step(&pose, a, &model, 0.05);
                if a == Action::Forward {
                    if next == pose {
                        bumps += 1;
                    }
                    path += ((next.x - pose.x).powi(2) + (next.y - pose.y).powi(2)).sqrt();
                }
                pose = next;
            }
        }
    }
    let coverage = ex.grid().map_or(0.0, |g| world.coverage(g));
    let name = |what: &str| format!("explore_fbe_house{seed}_{what}");
    let total = loop_time.as_secs_f64().max(1e-12);
    let share = |d: Duration| 100.0 * d.as_secs_f64() / total;
    Ok(vec![
        row(name("coverage"), 100.0 * coverage, "%"),
        row(name("steps"), steps as f64, "steps"),
        row(name("path_length"), path, "m"),
        row(name("bumps"), bumps as f64, "steps"),
        row(name("loop_steps_per_s"), steps as f64 / total, "steps/s"),
        row(
            name("render_ms_per_step"),
            1e3 * render.as_secs_f64() / steps.max(1) as f64,
            "ms",
        ),
        row(name("plans"), ex.counters.plans as f64, "plans"),
        row(
            name("replans_path_blocked"),
            ex.counters.path_blocked as f64,
            "replans",
        ),
        row(
            name("replans_obstacle_ahead"),
            ex.counters.obstacle_ahead as f64,
            "replans",
        ),
        row(
            name("replans_goal_occupied"),
            ex.counters.goal_occupied as f64,
            "replans",
        ),
        row(name("stuck"), ex.counters.stuck as f64, "times"),
        row(
            name("recovery_spins"),
            ex.counters.recovery_spins as f64,
            "spins",
        ),
        row(
            name("unreachable_goals"),
            ex.counters.unreachable_goals as f64,
            "goals",
        ),
        row(name("share_occupancy"), share(ex.times.occupancy), "%"),
        row(name("share_triggers"), share(ex.times.triggers), "%"),
        row(name("share_frontiers"), share(ex.times.frontiers), "%"),
        row(name("share_planning"), share(ex.times.planning), "%"),
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Development driver: `cargo test -p activemap-planning --release bench -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn print_episode() {
        let seed: u64 = std::env::var("SEED")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(2);
        let env = |k: &str, d: usize| {
            std::env::var(k)
                .ok()
                .and_then(|s| s.parse().ok())
                .unwrap_or(d)
        };
        let cfg = BenchConfig {
            depth_size: env("DEPTH", 64) as u32,
            explore_steps: env("STEPS", 2000),
            ..Default::default()
        };
        for r in explore_episode(seed, &cfg).unwrap() {
            println!("{:<40} {:>12.3} {}", r.name, r.value, r.unit);
        }
    }

    #[test]
    #[ignore]
    fn print_benchmark() {
        for r in run(&BenchConfig::default()).unwrap() {
            println!("{:<40} {:>12.3} {}", r.name, r.value, r.unit);
        }
    }
}
