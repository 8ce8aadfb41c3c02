//! Differentiable 3D Gaussian splatting on the CPU (SPEC §3, §5): RGB-D rendering, analytic
//! gradients for the map, the camera pose and the exposure, and Fisher information.
//!
//! # API
//! ```no_run
//! use activemap_splat::*;
//! # fn demo(k: activemap_geometry::Intrinsics, pose: activemap_geometry::Isometry3<f64>) -> Result<(), SplatError> {
//! let mut map = Gaussians::<f32>::new();
//! map.push([0.0, 0.0, 2.0], [0.8, 0.2, 0.1], [1.0, 0.0, 0.0, 0.0], 0.7, [0.05; 3]);
//! let camera = Camera::from_world_pose(k, &pose);           // T_world_camera in, T_cw stored
//! let out = render(&map, &camera, &RenderOptions::default())?; // colour, depth, opacity
//! let mut dl = PixelGrads::zeros(out.width * out.height);     // ∂L/∂images from your loss
//! dl.depth.iter_mut().for_each(|g| *g = 1.0);
//! let grads = backward(&map, &out, &dl)?;                    // 14 params, pose τ, exposure
//! let info = fisher(&map, &out, FisherMode::PerChannel)?;     // diag per Gaussian, 6×6 pose
//! let mut adam = GaussianAdam::new(AdamConfig::default());
//! adam.step(&mut map, &grads)?;
//! ply::write_ply("map.ply".as_ref(), &map)?;
//! # Ok(()) }
//! ```
//!
//! Modules, one stage each (gsplat style): [`gaussians`] (the 14-parameter store and its
//! conventions), [`camera`], [`project`] (EWA projection), [`tiles`] (16×16 binning and depth
//! sort), [`rasterize`] (forward), [`backward`], [`fisher`], [`adam`], [`ply`], [`bench`],
//! [`ortho`] (the orthographic top-down render of the floor plan for the LLM planner), and
//! the private `walk` (the vectorised per-pixel loops and the one back-to-front traversal that
//! the backward and Fisher passes share).
//! Everything is generic over [`Real`] (`f32` in production, `f64` for gradient checks), except
//! the display-only [`ortho`] render (`f32`).
//! Results do not depend on the rayon thread count.
//!
//! # Conventions and choices
//! - Parameters (SPEC §3) are stored raw: mean, `sh_dc` (3DGS `f_dc`, colour `0.5 + C0·f_dc`,
//!   unclamped), quaternion `[w, x, y, z]` unnormalised, opacity logit, log-scale. Gradients and
//!   Fisher diagonals are w.r.t. these raw values, in the [`layout`] order.
//! - Pixel centres at integer coordinates (`activemap_geometry::Intrinsics`).
//! - Each Gaussian touches only the pixels of its 3σ bounding box, shrunk to where `α ≥ 1/255`
//!   is possible ([`project`]); images do not depend on the tile size.
//! - Where `α` hits the 0.99 clamp its gradient w.r.t. opacity and geometry is zero (exact;
//!   3DGS ignores the clamp in backward).
//! - Pose gradients/information are for the left update `T_cw ← Exp(τ)·T_cw`, τ = [ρ, θ]
//!   (`activemap_geometry::se3`).
//! - Exposure: output colour `e^a·C + b` with scalar `a`, `b` for all channels (MonoGS).
//! - Depth ([`DepthModel`]): by default a Gaussian contributes the depth of its densest point
//!   along each pixel's ray (a plane over the splat, [`DepthModel::Plane`]), which the maps are
//!   fitted under; SPEC §3's centre depth ([`DepthModel::Centre`]) is an option, and the one
//!   the Fisher pass differentiates (it refuses a plane render).
//! - Fisher ([`fisher`]): diagonals per Gaussian for colour and depth separately,
//!   [`FisherMode::PerChannel`] (default) or [`FisherMode::ChannelSum`] (FisherRF) for the colour
//!   square; the 6×6 pose information is always summed per channel, colour and depth separate.
//! - Flags: [`RenderOptions::exclude_flags`] leaves flagged Gaussians (e.g.
//!   [`FLAG_UNKNOWN_SPACE`]) out of a render and thus out of its gradients and Fisher.

// Numeric kernels index several fixed-size arrays with the same counter; iterator chains
// would hide the formulas.
#![allow(clippy::needless_range_loop)]

pub mod adam;
pub mod backward;
pub mod bench;
pub mod camera;
pub mod fisher;
#[doc(hidden)]
pub mod fuzzing;
pub mod gaussians;
pub mod ortho;
pub mod ply;
pub mod project;
pub mod rasterize;
pub mod real;
pub mod tiles;
mod walk;

pub use adam::{AdamConfig, AdamState, GaussianAdam};
pub use backward::{Gradients, PixelGrads, backward};
pub use camera::{Camera, DEFAULT_NEAR};
pub use fisher::{FisherMode, FisherOutput, SparseFisher, fisher, fisher_sparse};
pub use gaussians::{FLAG_UNKNOWN_SPACE, Gaussians, SH_C0, layout};
pub use rasterize::{
    DepthModel, ForwardContext, MEDIAN_TRANSMITTANCE, Render, RenderOptions, median_depth, render,
};
pub use real::Real;

/// Errors of the renderer and its file formats.
#[derive(Debug, thiserror::Error)]
pub enum SplatError {
    /// Two arrays that must match in length do not.
    #[error("length mismatch: {what} has {got} entries, expected {expected}")]
    Length {
        /// Which array.
        what: &'static str,
        /// Expected length.
        expected: usize,
        /// Actual length.
        got: usize,
    },
    /// The camera is unusable.
    #[error("invalid camera: {0}")]
    Camera(String),
    /// An orthographic render's window or options are unusable ([`ortho`]).
    #[error("invalid orthographic render: {0}")]
    Ortho(String),
    /// A PLY file could not be read or written.
    #[error("PLY {path}: {message}")]
    Ply {
        /// The file.
        path: String,
        /// What is wrong, and where.
        message: String,
    },
    /// A pass was asked for something it does not compute.
    #[error("unsupported: {0}")]
    Unsupported(&'static str),
    /// An I/O error on a file.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The error.
        source: std::io::Error,
    },
}
