//! `activemap bench planner` (issue 15): the LLM planner's own time per query — BEV render,
//! annotation, PNG encoding, request building and reply parsing — without the model's
//! latency, on a partly explored house map ([`crate::house_map`]).
//!
//! The whole decision is the product's: [`LlmPlanner::decide`] with the `openai` provider,
//! talking to a loopback server in this process that answers at once with a fixed Chat
//! Completions reply; the planner's overhead is its wall time minus the provider's measured
//! latency (the loopback round trip). The stage rows time the BEV's stages
//! ([`bev_window`] → [`render_map`] → [`annotate`] → [`Bev::png`]) alone, for the breakdown.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpListener;
use std::time::Instant;

use activemap_geometry::frames::planar_from_camera_pose;
use activemap_llm::bev::{Annotations, Bev, BevConfig, annotate, bev_window, render_map};
use activemap_llm::config::{HttpProviderConfig, LlmConfig, PromptStyle, ProviderConfig};
use activemap_llm::{Candidate, LlmPlanner, Query};
use activemap_planning::clearance::ClearanceConfig;
use activemap_planning::frontier::{FrontierConfig, reachable_regions};
use nalgebra::Point2;

use crate::house_map::HouseMap;
use crate::stats::median;

/// Medians of one benchmark run, milliseconds.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannerBench {
    /// Gaussians in the map.
    pub gaussians: usize,
    /// Candidates offered.
    pub candidates: usize,
    /// BEV long side, pixels.
    pub long_side_px: u32,
    /// PNG size, bytes.
    pub png_bytes: usize,
    /// Queries timed.
    pub repeats: usize,
    /// Stage medians: window, render, annotate, PNG.
    pub stages_ms: [f64; 4],
    /// The decision's own time (all stages, prompt, request, parsing), median.
    pub overhead_ms: f64,
    /// The loopback provider's latency, median.
    pub latency_ms: f64,
    /// The last query's BEV, PNG bytes (what the model was sent).
    pub png: Vec<u8>,
}

/// A loopback HTTP server that answers every request at once with `body` (a Chat
/// Completions JSON); returns its base URL. It serves until the process ends.
fn instant_server(body: String) -> anyhow::Result<String> {
    let listener = TcpListener::bind("127.0.0.1:0")?;
    let url = format!("http://{}", listener.local_addr()?);
    std::thread::spawn(move || {
        for stream in listener.incoming().flatten() {
            let mut reader = BufReader::new(stream);
            let mut length = 0usize;
            let mut line = String::new();
            loop {
                line.clear();
                if reader.read_line(&mut line).unwrap_or(0) == 0 {
                    break;
                }
                if line == "\r\n" {
                    break;
                }
                if let Some(v) = line.to_ascii_lowercase().strip_prefix("content-length:") {
                    length = v.trim().parse().unwrap_or(0);
                }
            }
            let mut request = vec![0u8; length];
            let _ = reader.read_exact(&mut request);
            let mut stream = reader.into_inner();
            let _ = write!(
                stream,
                "HTTP/1.1 200 OK\r\ncontent-type: application/json\r\ncontent-length: {}\r\nconnection: close\r\n\r\n{body}",
                body.len()
            );
        }
    });
    Ok(url)
}

/// The candidates of the house map's grid, as the planner offers them (the frontier
/// operator's regions: reachable, largest first).
pub fn candidates(house: &HouseMap) -> anyhow::Result<Vec<Candidate>> {
    let robot = planar_from_camera_pose(&house.pose);
    let geometry = house.grid.geometry;
    let mut regions = reachable_regions(
        &house.grid,
        Point2::new(robot.x, robot.y),
        &ClearanceConfig::default(),
        &FrontierConfig::default(),
    )?;
    regions.retain(|r| r.approach.is_some());
    regions.sort_by_key(|r| std::cmp::Reverse(r.size()));
    let cell = geometry.resolution;
    Ok(regions
        .iter()
        .map(|r| {
            let anchor = geometry.center(r.anchor);
            Candidate {
                centroid: [r.centroid.x, r.centroid.y],
                label_at: [anchor.x, anchor.y],
                size_cells: r.size() as u32,
                area_m2: r.size() as f64 * cell * cell,
                path_distance_m: r.approach.map_or(f64::INFINITY, |a| a.path_distance_m),
            }
        })
        .collect())
}

/// Times `repeats` decisions of the LLM planner on `house` at `long_side_px`.
pub fn run(house: &HouseMap, long_side_px: u32, repeats: usize) -> anyhow::Result<PlannerBench> {
    anyhow::ensure!(repeats >= 1, "bench planner: repeats must be at least 1");
    let mut offered = candidates(house)?;
    if offered.is_empty() {
        // A fully explored map still gets a BEV; offer the robot's own cell.
        let robot = planar_from_camera_pose(&house.pose);
        offered.push(Candidate {
            centroid: [robot.x, robot.y],
            label_at: [robot.x, robot.y],
            size_cells: 1,
            area_m2: 0.0025,
            path_distance_m: 0.0,
        });
    }
    let reply = serde_json::json!({
        "id": "bench", "object": "chat.completion", "model": "bench",
        "choices": [{"index": 0, "message": {"role": "assistant",
            "content": "Plan: explore the largest opening.\n{\"target\": 0, \"reason\": \"largest\"}"},
            "finish_reason": "stop"}],
        "usage": {"prompt_tokens": 1000, "completion_tokens": 20}
    })
    .to_string();
    let url = instant_server(reply)?;
    let bev = BevConfig {
        long_side_px,
        ..BevConfig::default()
    };
    let config = LlmConfig {
        prompt: PromptStyle::Image,
        provider: Some(ProviderConfig::Openai(HttpProviderConfig::new(
            &format!("{url}/v1"),
            "bench",
        ))),
        bev: bev.clone(),
        ..LlmConfig::default()
    };
    let provider =
        activemap_llm::provider::from_config(config.provider.as_ref().unwrap(), None, 0)?;
    let mut planner = LlmPlanner::new(config, Some(provider))?;
    let robot = planar_from_camera_pose(&house.pose);
    let camera_z = house.pose.translation.z;
    let path: Vec<[f64; 2]> = vec![[robot.x, robot.y]];
    let annotations = Annotations {
        robot: [robot.x, robot.y, robot.yaw],
        path: path.clone(),
        last_frontier: None,
        candidates: offered.iter().map(|c| c.label_at).collect(),
    };
    let mut stages: [Vec<f64>; 4] = Default::default();
    let mut overhead = Vec::new();
    let mut latency = Vec::new();
    let mut png = Vec::new();
    for i in 0..repeats {
        let t = Instant::now();
        let window = bev_window(&house.gaussians, camera_z, &annotations, &bev)?;
        stages[0].push(ms(t));
        let t = Instant::now();
        let map = render_map(&house.gaussians, camera_z, &window, &bev)?;
        stages[1].push(ms(t));
        let t = Instant::now();
        let image: Bev = annotate(map, &annotations, &bev)?;
        stages[2].push(ms(t));
        let t = Instant::now();
        let _ = image.png();
        stages[3].push(ms(t));
        // The product's decision; a new map version each time so that it asks.
        let decision = planner.decide(&Query {
            step: i as u64,
            total_steps: 2000,
            map: &house.gaussians,
            map_version: i as u64,
            camera_height_m: camera_z,
            robot: [robot.x, robot.y, robot.yaw],
            path: &path,
            candidates: &offered,
        })?;
        let exchange = decision
            .exchange
            .ok_or_else(|| anyhow::anyhow!("bench planner: decision {i} made no query"))?;
        anyhow::ensure!(
            exchange.fallback.is_none(),
            "bench planner: decision {i} fell back: {:?}",
            exchange.fallback
        );
        overhead.push(exchange.overhead_ms);
        png = exchange.bev_png;
        latency.push(exchange.completion.latency_ms);
    }
    Ok(PlannerBench {
        gaussians: house.gaussians.len(),
        candidates: offered.len(),
        long_side_px,
        png_bytes: png.len(),
        repeats,
        stages_ms: stages.map(|s| median(&s).unwrap_or(f64::NAN)),
        overhead_ms: median(&overhead).unwrap_or(f64::NAN),
        latency_ms: median(&latency).unwrap_or(f64::NAN),
        png,
    })
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

impl PlannerBench {
    /// The table: stage medians and the decision's overhead.
    pub fn table(&self) -> String {
        let mut s = format!(
            "# {} Gaussians, {} candidates, BEV {} px long side, PNG {} kB, {} queries (medians)\n",
            self.gaussians,
            self.candidates,
            self.long_side_px,
            self.png_bytes / 1000,
            self.repeats
        );
        s += "| stage | median ms |\n|---|---:|\n";
        for (name, v) in [
            "window (crop)",
            "render (orthographic splat)",
            "annotate (marks, numbers)",
            "PNG encode",
        ]
        .iter()
        .zip(self.stages_ms)
        {
            s += &format!("| {name} | {v:.1} |\n");
        }
        s += &format!(
            "| whole decision without the model (BEV, PNG, prompt, request, parse) | {:.1} |\n",
            self.overhead_ms
        );
        s += &format!(
            "| loopback provider latency (excluded) | {:.1} |\n",
            self.latency_ms
        );
        s
    }

    /// The one-line summary the issue names.
    pub fn summary(&self) -> String {
        format!("planner overhead_median_ms {:.1}", self.overhead_ms)
    }
}
