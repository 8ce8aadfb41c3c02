//! Errors of the planning library: every bad input is named with what was wrong and where.

use thiserror::Error;

/// Everything that can go wrong when a caller hands the planning library bad input.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum PlanningError {
    /// A grid's shape or placement is unusable (zero size, non-positive resolution, ...).
    #[error("invalid grid: {0}")]
    InvalidGrid(String),
    /// A configuration field holds a value outside its valid range.
    #[error("invalid configuration `{field}`: {reason}")]
    InvalidConfig {
        /// The offending field, e.g. `OccupancyConfig::resolution`.
        field: &'static str,
        /// Why the value is refused.
        reason: String,
    },
    /// A world point that must lie on the grid (start, goal, robot) lies outside it.
    #[error("{what} at ({x:.3}, {y:.3}) m lies outside the grid")]
    OutsideGrid {
        /// Which point, e.g. "A* start".
        what: &'static str,
        /// World x, metres.
        x: f64,
        /// World y, metres.
        y: f64,
    },
    /// A number that must be finite is NaN or infinite.
    #[error("{what} is not finite")]
    NonFinite {
        /// Which value, e.g. "camera pose".
        what: &'static str,
    },
    /// Two inputs that must have matching sizes do not.
    #[error("size mismatch in {what}: expected {expected}, got {got}")]
    SizeMismatch {
        /// Which input, e.g. "depth image".
        what: &'static str,
        /// The required length.
        expected: usize,
        /// The length given.
        got: usize,
    },
}

/// Returns an [`PlanningError::InvalidConfig`] unless `ok`.
pub(crate) fn require(ok: bool, field: &'static str, reason: &str) -> Result<(), PlanningError> {
    if ok {
        Ok(())
    } else {
        Err(PlanningError::InvalidConfig {
            field,
            reason: reason.to_string(),
        })
    }
}
