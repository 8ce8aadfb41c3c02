//! RGB-D Gaussian-splatting SLAM (SPEC §4): tracking and mapping without ground-truth poses,
//! MonoGS-style, on the CPU renderer of `activemap-splat`. No transport: the tracker and mapper
//! operators wrap this library.
//!
//! - [`frame`]: the RGB-D [`Frame`] (RGB f32 in [0, 1], depth metres, 0 = none) and its
//!   usability check (black / saturated / no depth / NaN frames are skipped, never a NaN
//!   pose);
//! - [`loss`]: tracking and mapping losses of SPEC §4 and the residuals behind "lost";
//! - [`tracker`]: Adam on the pose τ = [ρ, θ] and the exposure;
//! - [`keyframe`]: co-visibility / translation keyframe rule;
//! - [`insert`], [`mapper`]: insertion in unobserved areas, window optimisation, pruning and
//!   densification (the map holds observed Gaussians only: the unknown-space Gaussians of
//!   SPEC §5 belong to the Fisher scorer, `activemap_active::unknown`);
//! - [`dense`], [`references`]: dense RGB-D alignment to keyframes, and which keyframes a
//!   frame is aligned to (the newest, plus older ones of the same place);
//! - [`pose_graph`]: a keyframe pose graph (relative-pose edges, Levenberg–Marquardt with
//!   faer's sparse Cholesky);
//! - [`keyframe_graph`]: that graph over the tracking session's reference keyframes, kept when
//!   configured ([`KeyframeGraph`]: odometry and loop edges, optimisation, corrections for the
//!   mapper);
//! - [`session`]: the tracking session (prediction, lagged map snapshots, reference
//!   keyframes, lost/skipped frames), as the `tracker` operator holds it;
//! - [`mapping`]: the mapping session (keyframe rule, insertion, window optimisation in a
//!   background worker, the fixed map lag), as the `mapper` operator holds it;
//! - [`lockstep`]: [`LockstepSlam`], both sessions fed in-process frame by frame exactly as
//!   the operators feed them (the scripted loop and `activemap bench slam` run it).
//!
//! ```no_run
//! use activemap_slam::{Frame, LockstepSlam, MotionPrior, SlamConfig};
//! # fn demo(frames: Vec<Frame>) -> Result<(), activemap_slam::SlamError> {
//! let mut slam = LockstepSlam::new(SlamConfig::default().with_map_lag(10))?;
//! for frame in frames {
//!     let out = slam.process(frame, MotionPrior::ConstantVelocity)?;
//!     println!("{:?} {:?}", out.pose, out.status);
//! }
//! # Ok(()) }
//! ```

// Index loops over the parallel arrays of the structure-of-arrays map read better than zips.
#![allow(clippy::needless_range_loop)]

pub mod dense;
pub mod error;
pub mod frame;
pub mod gauss_newton;
pub mod insert;
pub mod keyframe;
pub mod keyframe_graph;
pub mod lockstep;
pub mod loss;
pub mod mapper;
pub mod mapping;
pub mod pose_graph;
pub mod references;
pub mod session;
pub mod tracker;

pub use error::SlamError;
pub use frame::{Frame, SkipReason};
pub use keyframe::{KeyframeConfig, KeyframeDecision};
pub use keyframe_graph::{
    GraphStats, KeyframeCorrection, KeyframeGraph, KeyframeGraphConfig, LoopClosure,
};
pub use lockstep::{LockstepSlam, SlamConfig};
pub use mapper::{Mapper, MapperConfig, MappingReport};
pub use mapping::{
    BackgroundMapper, GraphLink, KeyframeEvent, KeyframeMapper, MappingConfig, PoseQuality,
    Snapshot, keyframe_moves,
};
pub use pose_graph::{Edge, PoseGraph, PoseGraphConfig};
pub use references::{ReferenceConfig, References};
pub use session::{
    MotionCheck, MotionGate, MotionPrior, MotionVerdict, ReferenceOverlap, Relocalisation,
    TrackedFrame, TrackingConfig, TrackingSession, YawSearch, required_snapshot,
};
pub use tracker::{LostReason, TrackOutput, TrackerConfig, TrackerMethod, TrackingStatus, track};
