//! Timings of the pieces the exploration loop runs (the loop's budget is ≥ 3 steps/s end to
//! end, SPEC §1 / issue 6): A* on a 400×400 grid, an occupancy update from a 160×160 depth
//! frame, frontier extraction on a 400×400 grid, and an FBE episode with true poses on each of
//! the simulator's `house:<seed>` scenes ([`crate::house_episode`]).
//! `activemap bench planning` prints the rows; [`run`] is driven by an ignored test here.

use std::time::{Duration, Instant};

use activemap_geometry::{Intrinsics, camera_pose_from_planar};
use nalgebra::Point2;
use serde::{Deserialize, Serialize};

use crate::house_episode::{self, HouseEpisodeConfig};
use activemap_planning::astar::{AstarConfig, plan};
use activemap_planning::clearance::{ClearanceConfig, ClearanceMap};
use activemap_planning::frontier::{FrontierConfig, extract_frontiers};
use activemap_planning::grid::{CellState, Grid, OccupancyGrid};
use activemap_planning::occupancy::{OccupancyConfig, OccupancyMapper};
use activemap_planning::synthetic::SyntheticWorld;

/// What to measure.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BenchConfig {
    /// Repetitions of each micro-benchmark (the median is reported).
    pub repetitions: usize,
    /// `house:<seed>` seeds for the FBE episodes (empty: no episodes).
    pub explore_seeds: Vec<u64>,
    /// Further procedural scenes for FBE episodes, after the houses (`home:<seed>`,
    /// `office:<seed>`, `house:<seed>`).
    pub explore_scenes: Vec<String>,
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
            explore_scenes: Vec::new(),
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
pub fn run(config: &BenchConfig) -> anyhow::Result<Vec<BenchRow>> {
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
        rows.extend(explore_episode(&format!("house:{seed}"), config)?);
    }
    for scene in &config.explore_scenes {
        rows.extend(explore_episode(scene, config)?);
    }
    Ok(rows)
}

/// One FBE episode on a procedural `scene` (`house:<seed>` as in `activemap bench explore`,
/// default size, or a home or office) with true poses ([`crate::house_episode`]); rows: coverage, steps, steps to
/// 85 %, path length, collisions, planning-loop steps per second (without rendering), the
/// event counters and the time shares.
pub fn explore_episode(scene: &str, config: &BenchConfig) -> anyhow::Result<Vec<BenchRow>> {
    let mut episode = HouseEpisodeConfig::benchmark(scene)?;
    episode.steps = config.explore_steps;
    episode.image_size = config.depth_size;
    episode.coverage_every = 10;
    let e = house_episode::run(&episode)?;
    // `house:1` → `explore_fbe_house1_…`, `office:3` → `explore_fbe_office3_…`.
    let tag = scene.replace(':', "");
    let name = |what: &str| format!("explore_fbe_{tag}_{what}");
    let total = e.loop_time.as_secs_f64().max(1e-12);
    let share = |d: Duration| 100.0 * d.as_secs_f64() / total;
    let c = &e.counters;
    Ok(vec![
        row(name("coverage"), 100.0 * e.coverage, "%"),
        row(name("steps"), e.steps as f64, "steps"),
        row(
            name("steps_to_85"),
            e.steps_to(0.85).map_or(f64::NAN, |s| s as f64),
            "steps",
        ),
        row(name("path_length"), e.path_length_m, "m"),
        row(name("turn_steps"), e.turn_steps as f64, "steps"),
        row(name("collisions"), e.collisions as f64, "steps"),
        row(name("loop_steps_per_s"), e.steps as f64 / total, "steps/s"),
        row(
            name("render_ms_per_step"),
            1e3 * e.render_time.as_secs_f64() / e.steps.max(1) as f64,
            "ms",
        ),
        row(name("plans"), c.plans as f64, "plans"),
        row(name("replans"), c.replans as f64, "requests"),
        row(
            name("replans_obstacle"),
            c.executor.obstacle_replans as f64,
            "replans",
        ),
        row(
            name("replans_blocked"),
            c.executor.blocked_replans as f64,
            "replans",
        ),
        row(name("bumps"), c.executor.bumps as f64, "moves"),
        row(name("stuck"), c.executor.stuck as f64, "times"),
        row(name("amnesties"), c.amnesties as f64, "times"),
        row(
            name("unreachable_goals"),
            c.unreachable_goals as f64,
            "goals",
        ),
        row(
            name("looks_skipped"),
            c.executor.looks_skipped as f64,
            "goals",
        ),
        row(
            name("unobservable_goals"),
            c.unobservable_goals as f64,
            "goals",
        ),
        row(name("share_occupancy"), share(e.times.occupancy), "%"),
        row(name("share_triggers"), share(e.times.triggers), "%"),
        row(name("share_frontiers"), share(e.times.frontiers), "%"),
        row(name("share_planning"), share(e.times.planning), "%"),
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
            depth_size: env("DEPTH", 160) as u32,
            explore_steps: env("STEPS", 2000),
            ..Default::default()
        };
        let scene = std::env::var("SCENE").unwrap_or_else(|_| format!("house:{seed}"));
        for r in explore_episode(&scene, &cfg).unwrap() {
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
