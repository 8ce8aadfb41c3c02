//! Benchmarks and scripted experiments: what only `activemap bench …` and the development
//! drivers need, kept out of the libraries so that `activemap-slam`, `activemap-planning` and
//! `activemap-splat` depend on neither the simulator nor the evaluation. Everything here drives
//! the libraries' own session types, the very code the operators hold.
//!
//! - [`slam_loop`]: the scripted SLAM loop in a procedural house (ground truth only for the
//!   metrics), through [`activemap_slam::LockstepSlam`];
//! - [`slam_bench`]: `activemap bench slam`, the scripted loop per case;
//! - [`house_episode`]: FBE episodes on the simulator's `house:<seed>` scenes with true poses,
//!   through the in-process explorer (the operators' pieces);
//! - [`planning_bench`]: `activemap bench planning`, timings of the pieces the exploration loop
//!   runs every step;
//! - [`results`]: `activemap bench results` (methods × scenes × seeds, the paper's Table 1
//!   layout and the ablation), resumable;
//! - [`house_map`]: a partly explored house map (FBE trajectory, the mapper's own insertion,
//!   the occupancy grid) for the Fisher benchmarks;
//! - [`scorer_bench`]: `activemap bench scorer`, one Fisher replan stage by stage on it;
//! - [`eig_psnr`]: `activemap bench eig-psnr`, the paper's Figure 2 (EIG against the map's
//!   PSNR at poses in the free space);
//! - [`stats`], [`scatter`]: medians, quantiles and Spearman ρ; the PNG scatter plot.

pub mod clocal_error;
pub mod eig_psnr;
pub mod episodes;
pub mod house_episode;
pub mod house_map;
pub mod planner_bench;
pub mod planning_bench;
pub mod results;
pub mod scatter;
pub mod scorer_bench;
pub mod slam_bench;
pub mod slam_loop;
pub mod stats;
