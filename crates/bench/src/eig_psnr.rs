//! `activemap bench eig-psnr` (issue 14, the paper's Figure 2): in a partly mapped house, the
//! view EIG the scorer ranks candidates by ([`FisherScorer::pose_eigs`], against the model
//! Fisher `I(w)` of the map, unknown-space Gaussians included as in a replan) and the PSNR of
//! the map's render against the simulator's truth at the same poses, for poses drawn uniformly
//! in the estimated free space (the grid's clear cells, robot-radius eroded) with a uniform yaw
//! ([`sample_free_space_poses`], the draw of the model Fisher's Monte-Carlo poses).
//!
//! The map render is the evaluator's (SPEC §8): the frame camera, unknown-space Gaussians
//! excluded, colour clamped to [0, 1]; the truth is the simulator's renderer at that pose. The
//! paper expects a negative rank correlation (EIG is high where the map renders poorly):
//! Spearman ρ ≤ −0.3.

use std::fmt::Write as _;

use activemap_active::candidates::sample_free_space_poses;
use activemap_active::{FisherConfig, FisherScorer, GoalRequest};
use activemap_eval::ImageView;
use activemap_geometry::{Isometry3, PlanarPose};
use activemap_planning::clearance::{ClearanceConfig, ClearanceMap};
use activemap_sim::Renderer;
use activemap_splat::{Camera, FLAG_UNKNOWN_SPACE, RenderOptions, render};
use anyhow::Context as _;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::house_map::HouseMap;
use crate::scatter::{self, Scatter};
use crate::stats::{quantile, quantile_table, quartiles_by, spearman};

/// One sampled pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// The planar pose (on the floor under the last camera).
    pub pose: PlanarPose,
    /// Its view EIG.
    pub eig: f64,
    /// PSNR of the map's render against the truth, dB.
    pub psnr: f64,
}

/// What the benchmark measured.
#[derive(Debug, Clone, PartialEq)]
pub struct EigPsnr {
    /// Every sampled pose.
    pub samples: Vec<Sample>,
    /// Spearman ρ of (EIG, PSNR); `None` when undefined (a constant side, a non-finite value).
    pub spearman: Option<f64>,
    /// Gaussians of the map.
    pub gaussians: usize,
    /// Scoring image size, pixels.
    pub scoring_size: (u32, u32),
    /// Render (and truth) image size, pixels.
    pub render_size: (u32, u32),
}

/// Samples `poses` poses (seed `seed`) in `house`'s free space and measures each one's EIG and
/// PSNR.
pub fn run(
    house: &HouseMap,
    fisher: &FisherConfig,
    poses: usize,
    seed: u64,
) -> anyhow::Result<EigPsnr> {
    anyhow::ensure!(poses >= 2, "bench eig-psnr: --poses must be at least 2");
    let robot = house.sim.config().robot;
    let camera = house.sim.config().intrinsics;
    let grid = &house.grid;
    let clear = ClearanceMap::new(
        grid,
        &ClearanceConfig::for_disc(robot.radius_m, grid.geometry.resolution)?,
    )?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let planar = sample_free_space_poses(&clear, poses, &mut rng);
    anyhow::ensure!(
        !planar.is_empty(),
        "bench eig-psnr: the house grid has no clear free cell to sample poses in"
    );
    let map = house.scoring_map();
    let input = house.replan_input(&map, GoalRequest::Refine);
    let mut scorer = FisherScorer::new(fisher.clone(), robot, camera).context("bench eig-psnr")?;
    let eigs = scorer
        .pose_eigs(&input, &planar)
        .context("bench eig-psnr: pose EIGs")?;
    let scoring = scorer.view_settings().intrinsics;
    // The pose_eigs views sit on the floor under the estimated camera; so do the renders.
    let floor_z = house.pose.translation.z - robot.camera_height_m;
    let cameras: Vec<Isometry3<f64>> = planar
        .iter()
        .map(|p| robot.camera_pose(p, floor_z))
        .collect();
    let scene = house.sim.scene();
    let range = house.sim.config().depth_range;
    let options = RenderOptions {
        exclude_flags: FLAG_UNKNOWN_SPACE,
        ..RenderOptions::default()
    };
    let psnrs: Vec<f64> = cameras
        .par_iter()
        .map_init(Renderer::new, |renderer, pose| {
            let truth = renderer.render(scene, &camera, pose, range);
            let truth: Vec<f32> = truth.rgb.iter().map(|&v| v as f32 / 255.0).collect();
            let out = render(
                &house.gaussians,
                &Camera::from_world_pose(camera, pose),
                &options,
            )?;
            let rendered: Vec<f32> = out
                .colour
                .iter()
                .flat_map(|c| c.map(|v| v.clamp(0.0, 1.0)))
                .collect();
            let (w, h) = (camera.width as usize, camera.height as usize);
            Ok(activemap_eval::psnr(
                ImageView::rgb(&rendered, w, h)?,
                ImageView::rgb(&truth, w, h)?,
                1.0,
            )?)
        })
        .collect::<anyhow::Result<_>>()?;
    let samples: Vec<Sample> = planar
        .iter()
        .zip(&eigs)
        .zip(&psnrs)
        .map(|((pose, eig), psnr)| Sample {
            pose: *pose,
            eig: *eig,
            psnr: *psnr,
        })
        .collect();
    Ok(EigPsnr {
        spearman: spearman(&eigs, &psnrs),
        samples,
        gaussians: house.gaussians.len(),
        scoring_size: (scoring.width, scoring.height),
        render_size: (camera.width, camera.height),
    })
}

impl EigPsnr {
    /// The summary line `eig_psnr spearman <ρ> poses <n>` (ρ `nan` when undefined).
    pub fn summary(&self) -> String {
        format!(
            "eig_psnr spearman {} poses {}",
            self.spearman
                .map_or("nan".to_string(), |r| format!("{r:.3}")),
            self.samples.len()
        )
    }

    /// The table: quantiles of EIG and PSNR, and the PSNR by EIG quartile.
    pub fn table(&self) -> String {
        let eig: Vec<f64> = self.samples.iter().map(|s| s.eig).collect();
        let psnr: Vec<f64> = self.samples.iter().map(|s| s.psnr).collect();
        let mut s = String::new();
        let _ = writeln!(
            s,
            "# {} poses uniform in the estimated free space, random yaw; EIG at {}×{} px (the \
             scorer's), PSNR of the map ({} Gaussians, unknown space excluded) at {}×{} px",
            self.samples.len(),
            self.scoring_size.0,
            self.scoring_size.1,
            self.gaussians,
            self.render_size.0,
            self.render_size.1
        );
        s.push_str(&quantile_table(&[("eig", &eig), ("psnr_db", &psnr)], 10, 4));
        // PSNR per EIG quartile (by rank, so each holds a quarter of the poses).
        let _ = writeln!(
            s,
            "{:<18} {:>5} {:>12} {:>12} {:>12}",
            "eig_quartile", "poses", "eig_median", "psnr_median", "psnr_mean"
        );
        for (k, part) in quartiles_by(&eig).iter().enumerate() {
            let e: Vec<f64> = part.iter().map(|&i| eig[i]).collect();
            let p: Vec<f64> = part.iter().map(|&i| psnr[i]).collect();
            let mean = if p.is_empty() {
                f64::NAN
            } else {
                p.iter().sum::<f64>() / p.len() as f64
            };
            let _ = writeln!(
                s,
                "{:<18} {:>5} {:>12.4} {:>12.2} {:>12.2}",
                format!("Q{} (low→high)", k + 1),
                part.len(),
                quantile(&e, 0.5).unwrap_or(f64::NAN),
                quantile(&p, 0.5).unwrap_or(f64::NAN),
                mean
            );
        }
        s
    }

    /// Writes the scatter plot (x = log10 EIG, y = PSNR) to `path`; poses with EIG 0 (nothing
    /// seen) have no logarithm and are left out of the plot (not of ρ).
    pub fn write_plot(&self, path: &std::path::Path) -> anyhow::Result<()> {
        let points: Vec<(f64, f64)> = self
            .samples
            .iter()
            .filter(|s| s.eig > 0.0)
            .map(|s| (s.eig.log10(), s.psnr))
            .collect();
        let title = format!(
            "EIG VS PSNR   {} POSES   SPEARMAN {}",
            self.samples.len(),
            self.spearman
                .map_or("NAN".to_string(), |r| format!("{r:.3}"))
        );
        scatter::write_png(
            &Scatter {
                title: &title,
                x_label: "LOG10 EIG",
                y_label: "PSNR (DB)",
                points: &points,
            },
            path,
        )
    }
}
