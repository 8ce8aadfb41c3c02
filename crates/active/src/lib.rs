//! The paper's active-mapping core (SPEC §5–§6), transport-free: the `scorer` operator in
//! `fisher` mode and the benchmarks call it; it knows nothing of processes or messages.
//!
//! Stages, each with its own module and tests:
//! - [`information`]: the Fisher information of one view at a scoring resolution: the
//!   per-Gaussian diagonal `H(x)` and the 6×6 pose information, normalised per pixel; the view
//!   EIG `Σ_k H_k(x)/I_k` and the localisation cost `C_local = −log det(J_τᵀJ_τ)`.
//! - [`model`]: the model Fisher `I(w)` per Gaussian id, from Monte-Carlo poses in the free
//!   space (the paper) or from the keyframes (the release), updated incrementally.
//! - [`unknown`]: the unknown-space Gaussians above frontier cells (Fisher only).
//! - [`candidates`]: candidate poses around a goal point, and uniform free-space poses.
//! - [`refine`]: the refine target when no frontier is left (DBSCAN of the least-known
//!   Gaussians).
//! - [`paths`]: A* paths to the best candidates, their future poses, path EIG and the
//!   objective.
//! - [`scorer`]: one replan end to end ([`scorer::FisherScorer`]).
//! - [`report`]: its wire report (`FisherReport` from a [`ReplanOutcome`]).

pub mod candidates;
pub mod config;
pub mod information;
pub mod model;
pub mod paths;
pub mod refine;
pub mod report;
pub mod scorer;
pub mod unknown;

pub use config::{
    FisherConfig, LocalisationInformation, ModelFisherSource, PathObjective, RefineCluster,
};
pub use scorer::{FisherScorer, GoalRequest, PoseLocalisation, ReplanInput, ReplanOutcome};

/// Errors of the Fisher scorer: bad input named by what and where.
#[derive(Debug, thiserror::Error)]
pub enum ActiveError {
    /// A setting is out of range.
    #[error("fisher config: {0}")]
    Config(String),
    /// An input (map, pose, grid) is unusable.
    #[error("{what}: {reason}")]
    Input {
        /// Which input.
        what: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The renderer refused a scoring view.
    #[error("scoring render: {0}")]
    Splat(#[from] activemap_splat::SplatError),
    /// The planning library refused a grid or a path query.
    #[error("planning: {0}")]
    Planning(#[from] activemap_planning::PlanningError),
}
