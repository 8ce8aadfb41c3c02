//! The one error type of the metrics library: every variant names the metric and what is wrong.

use std::path::PathBuf;

/// Why a metric could not be computed.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// Two inputs that must have the same shape do not.
    #[error("{metric}: size mismatch: {detail}")]
    SizeMismatch {
        /// The metric that was asked for.
        metric: &'static str,
        /// Which sizes differ.
        detail: String,
    },
    /// An input holds NaN or ±∞ where a finite number is required.
    #[error("{metric}: non-finite value in {input} at {location}")]
    NonFinite {
        /// The metric that was asked for.
        metric: &'static str,
        /// Which input (e.g. `rendered`, `truth`).
        input: &'static str,
        /// Where, e.g. `pixel (x 3, y 7) channel 1` or `pose 12`.
        location: String,
    },
    /// An input holds nothing the metric can use.
    #[error("{metric}: empty input: {detail}")]
    Empty {
        /// The metric that was asked for.
        metric: &'static str,
        /// What is empty.
        detail: String,
    },
    /// A parameter is out of its valid range.
    #[error("{metric}: invalid parameter: {detail}")]
    InvalidParameter {
        /// The metric that was asked for.
        metric: &'static str,
        /// Which parameter and why.
        detail: String,
    },
    /// No pose of the estimate has a reference pose close enough in time.
    #[error(
        "ATE: no common timestamps: none of the {estimate_len} estimated poses is within {max_time_diff} s of one of the {reference_len} reference poses"
    )]
    NoCommonTimestamps {
        /// Poses in the reference trajectory.
        reference_len: usize,
        /// Poses in the estimated trajectory.
        estimate_len: usize,
        /// The association tolerance, seconds.
        max_time_diff: f64,
    },
    /// The alignment could not be computed (the SVD of the position covariance failed).
    #[error("ATE: degenerate alignment: {detail}")]
    DegenerateAlignment {
        /// Why.
        detail: String,
    },
    /// The LPIPS weight file is absent.
    #[error("LPIPS: weights not found at {}; fetch them with `{fetch_command}`", path.display())]
    LpipsWeightsMissing {
        /// Where they were looked for.
        path: PathBuf,
        /// The command that fetches and converts them.
        fetch_command: &'static str,
    },
    /// The LPIPS weight file is absent and fetching it automatically failed.
    #[error(
        "LPIPS: weights not found at {} and the automatic fetch failed ({reason}); fetch them with `{fetch_command}`",
        path.display()
    )]
    LpipsFetchFailed {
        /// Where they were looked for.
        path: PathBuf,
        /// Why the fetch failed.
        reason: String,
        /// The command that fetches and converts them by hand.
        fetch_command: &'static str,
    },
    /// The LPIPS weight file exists but cannot be used.
    #[error("LPIPS: bad weight file {}: {detail}", path.display())]
    LpipsWeightsInvalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        detail: String,
    },
}
