//! Evaluation metrics of SPEC §8, each checked against an independent reference in its tests:
//!
//! - [`psnr`](mod@psnr): PSNR (+∞ for identical images);
//! - [`ssim`](mod@ssim): SSIM as Wang et al. 2004 / scikit-image (Gaussian window 11, σ 1.5);
//! - [`lpips`]: LPIPS with AlexNet (weights fetched by `tools/lpips/fetch_weights.py`);
//! - [`depth`]: depth mean absolute error over valid ground-truth pixels;
//! - [`ate`](mod@ate): ATE RMSE after Umeyama SE(3) alignment, associated as `evo` does;
//! - [`completeness`](mod@completeness): fraction of ground-truth mesh samples with an observed point within 5 cm;
//! - [`surface`]: surface completeness, accuracy and completion error of the map's
//!   reconstructed surface (rendered depth fused in a TSDF);
//! - [`offset`]: signed distance of the Gaussian centres to the ground-truth surface;
//! - [`observable`]: which ground-truth samples a camera pose of the robot can see;
//! - [`coverage`]: seen / navigable floor area;
//! - [`step_metrics`]: what the `evaluator` node measures as a run goes (coverage against the
//!   reachable floor, blocked forward moves, path length, ATE, the observed map, the BEV of the
//!   last grid, the run's validity warnings);
//! - [`fog`]: the release's fog-of-war 2D coverage along the true trajectory;
//! - [`test_poses`]: the seeded test poses on the navigable plane;
//! - [`views`]: all image metrics of one test view and their means over the views;
//! - [`report`]: [`MetricsReport`], all of them with missing values explicit;
//! - [`bench`](mod@bench): timings of every metric (`bench::run`);
//! - [`run_folder`]: the run folder as one typed contract ([`RunFolder`]: every file's name
//!   and format, [`Summary`], the CSV rows);
//! - [`bev`](mod@bev): the bird's-eye view of a run and its drawing ([`bev::Bev`]);
//! - [`run_eval`]: `activemap eval RUN_DIR` ([`run_eval::evaluate_run`]) over a run folder;
//! - [`html`]: the self-contained `report.html` of a run ([`html::write_report`]);
//! - [`validity`]: the checks that mark a run invalid ([`RunWarning`]: a start that sees nothing,
//!   a robot that cannot move, an empty map, metrics on empty views).
//!
//! Images are [`ImageView`]s: borrowed row-major `f32` buffers, RGB in [0, 1], depth in metres.
//! No transport. I/O only in `lpips` (weights), `run_folder`, `run_eval` and `html`.

pub mod ate;
pub mod bench;
pub mod bev;
pub mod completeness;
pub mod corrected;
pub mod coverage;
pub mod depth;
pub mod depth_breakdown;
pub mod error;
pub mod fog;
pub mod html;
pub mod image;
pub mod lpips;
pub mod observable;
pub mod offset;
pub mod psnr;
pub mod report;
pub mod run_eval;
pub mod run_folder;
pub mod ssim;
pub mod step_metrics;
pub mod surface;
pub mod test_poses;
pub mod validity;
pub mod views;

#[cfg(test)]
pub(crate) mod testing;

pub use ate::{AteOptions, AteResult, associate, ate, umeyama_se3};
pub use completeness::{
    COMPLETENESS_THRESHOLD_M, PointGrid, SurfaceClass, SurfaceCompleteness, complete_fraction,
    complete_samples, completeness, completeness_by_surface, sample_mesh_surface,
};
pub use corrected::CorrectedTrajectory;
pub use coverage::coverage_2d;
pub use depth::depth_mae;
pub use depth_breakdown::{DepthErrorClass, DepthErrorShare, DepthErrorTally};
pub use error::EvalError;
pub use image::ImageView;
pub use lpips::LpipsAlex;
pub use offset::{OffsetStats, SurfaceOffsets, orient_towards, surface_offsets};
pub use psnr::{mean_squared_error, psnr};
pub use report::MetricsReport;
pub use run_folder::{RunError, RunFolder, Summary, TrackingSummary};
pub use ssim::ssim;
pub use test_poses::{NavigableGrid, TEST_VIEW_COUNT, sample_test_poses};
pub use validity::RunWarning;
pub use views::{ViewMeans, ViewMetrics, evaluate_view};
