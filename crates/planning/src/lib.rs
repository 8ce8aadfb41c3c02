//! Occupancy grid, frontiers, A*, path shortcutting, the greedy follower and forward dynamics
//! (SPEC §6): the planning library shared by the occupancy, frontier, planner and follower
//! operators and by the Fisher scorer. No transport here.
//!
//! - [`grid`]: the 2D grid on the motion plane and world ↔ cell conversion;
//! - [`occupancy`]: the grid from map points and depth rays, with the 3×3 opening;
//! - [`distance`]: the exact Euclidean distance transform;
//! - [`clearance`]: the robot-width collision check built on it;
//! - [`segment`]: cells touched by segments (supercover for checks, DDA for rays);
//! - [`frontier`]: frontier cells and regions with their closest reachable cell;
//! - [`astar`] and [`shortcut`]: paths;
//! - [`path`]: the path to a goal as the scorer makes it (A*, shortcut, headings);
//! - [`follower`], [`dynamics`], [`stuck`], [`replan`]: the pieces of path execution;
//! - [`executor`]: the one path executor (the `follower` operator and the explorer run it);
//! - [`fbe`]: the frontier-based-exploration goal choice (the `planner` operator's decision);
//! - [`synthetic`]: a 2.5D test world with an exact depth renderer and procedural houses;

#![warn(missing_docs)]

pub mod astar;
pub mod clearance;
pub mod distance;
pub mod dynamics;
pub mod error;
pub mod executor;
pub mod fbe;
pub mod follower;
pub mod frontier;
pub mod grid;
pub mod morphology;
pub mod occupancy;
pub mod path;
pub mod replan;
pub mod segment;
pub mod shortcut;
pub mod stuck;
pub mod synthetic;

pub use error::PlanningError;
pub use grid::{Cell, CellState, Grid, GridGeometry, OccupancyGrid};
