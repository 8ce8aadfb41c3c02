//! Errors of the SLAM library: bad input names what is wrong and where.

use activemap_splat::SplatError;

/// Why a SLAM call failed (bad input or a renderer error). Frames that are merely unusable
/// (black, saturated, no depth, NaN colour) are not errors: they give a `Skipped` status.
#[derive(Debug, thiserror::Error)]
pub enum SlamError {
    /// An image buffer does not match the intrinsics' size.
    #[error("frame {what}: {got} entries, expected {expected} ({width}×{height})")]
    FrameSize {
        /// Which buffer (rgb or depth).
        what: &'static str,
        /// Entries found.
        got: usize,
        /// Entries expected.
        expected: usize,
        /// Image width from the intrinsics.
        width: u32,
        /// Image height from the intrinsics.
        height: u32,
    },
    /// The intrinsics are unusable (zero size, zero or non-finite focal length).
    #[error("invalid intrinsics: {0}")]
    Intrinsics(String),
    /// A configuration value is out of range.
    #[error("invalid configuration {field} = {value}: {reason}")]
    Config {
        /// The field.
        field: &'static str,
        /// Its value.
        value: String,
        /// What range it must be in.
        reason: &'static str,
    },
    /// An input value (pose, cell, motion) is not finite or out of range.
    #[error("invalid input {what}: {reason}")]
    Input {
        /// Which input.
        what: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The renderer refused a call.
    #[error("renderer: {0}")]
    Splat(#[from] SplatError),
}

impl SlamError {
    /// The first `(field, value)` that is not finite and > 0, as a [`SlamError::Config`] naming it.
    pub(crate) fn require_positive(fields: &[(&'static str, f64)]) -> Result<(), SlamError> {
        match fields.iter().find(|(_, v)| !(v.is_finite() && *v > 0.0)) {
            Some(&(field, v)) => Err(SlamError::Config {
                field,
                value: v.to_string(),
                reason: "must be finite and > 0",
            }),
            None => Ok(()),
        }
    }

    /// The first `(field, value)` that is not finite and ≥ 0, as a [`SlamError::Config`]
    /// naming it.
    pub(crate) fn require_non_negative(fields: &[(&'static str, f64)]) -> Result<(), SlamError> {
        match fields.iter().find(|(_, v)| !(v.is_finite() && *v >= 0.0)) {
            Some(&(field, v)) => Err(SlamError::Config {
                field,
                value: v.to_string(),
                reason: "must be finite and ≥ 0",
            }),
            None => Ok(()),
        }
    }
}
