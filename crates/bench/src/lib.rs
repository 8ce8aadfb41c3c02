//! Benchmarks and scripted experiments: what only `activemap bench …` and the development
//! drivers need, kept out of the libraries so that `activemap-slam`, `activemap-planning` and
//! `activemap-splat` depend on neither the simulator nor the evaluation. Everything here drives
//! the libraries' own session types, the very code the operators hold.
//!
//! - [`slam_loop`]: the scripted SLAM loop in a procedural house (ground truth only for the
//!   metrics), through [`activemap_slam::LockstepSlam`];
//! - [`slam_bench`]: `activemap bench slam`, the scripted loop per case.

pub mod slam_bench;
pub mod slam_loop;
