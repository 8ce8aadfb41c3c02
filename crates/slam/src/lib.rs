//! RGB-D Gaussian-splatting SLAM (SPEC §4): tracking and mapping without ground-truth poses,
//! MonoGS-style, on the CPU renderer of `activemap-splat`. No transport: the tracker and mapper
//! operators wrap this library.
//!
//! - [`frame`]: the RGB-D [`Frame`] (RGB f32 in [0, 1], depth metres, 0 = none) and its
//!   usability check (black / no depth / NaN frames are skipped, never a NaN pose);
//! - [`loss`]: tracking and mapping losses of SPEC §4 and the residuals behind "lost";
//! - [`tracker`]: Adam on the pose τ = [ρ, θ] and the exposure;
//! - [`keyframe`]: co-visibility / translation keyframe rule;
//! - [`insert`], [`unknown`], [`mapper`]: insertion in unobserved areas, unknown-space
//!   Gaussians (SPEC §5), window optimisation, pruning and densification;
//! - [`dense`], [`references`]: dense RGB-D alignment to keyframes, and which keyframes a
//!   frame is aligned to (the newest, plus older ones of the same place);
//! - [`slam`]: the [`Slam`] facade, `process(frame, motion) → pose, status, keyframe, map`;
//! - [`scripted`], [`bench`]: the scripted-loop evaluation in the simulator (ground truth only
//!   for the metrics) and `activemap bench slam`.
//!
//! ```no_run
//! use activemap_slam::{Frame, MotionPrior, Slam, SlamConfig};
//! # fn demo(frames: Vec<Frame>) -> Result<(), activemap_slam::SlamError> {
//! let mut slam = Slam::new(SlamConfig::default())?;
//! for frame in &frames {
//!     let out = slam.process(frame, MotionPrior::ConstantVelocity)?;
//!     println!("{:?} {:?} keyframe {}", out.pose, out.status, out.map_updated);
//! }
//! # Ok(()) }
//! ```

// Index loops over the parallel arrays of the structure-of-arrays map read better than zips.
#![allow(clippy::needless_range_loop)]

pub mod bench;
pub mod dense;
pub mod error;
pub mod frame;
pub mod gauss_newton;
pub mod insert;
pub mod keyframe;
pub mod loss;
pub mod mapper;
pub mod references;
pub mod scripted;
pub mod slam;
pub mod tracker;
pub mod unknown;

pub use error::SlamError;
pub use frame::{Frame, SkipReason};
pub use keyframe::{KeyframeConfig, KeyframeDecision};
pub use mapper::{Mapper, MapperConfig, MappingReport};
pub use references::{ReferenceConfig, References};
pub use slam::{MotionPrior, Slam, SlamConfig, SlamOutput};
pub use tracker::{TrackOutput, TrackerConfig, TrackerMethod, TrackingStatus, track};
pub use unknown::{FrontierCell, UnknownSpaceConfig};
