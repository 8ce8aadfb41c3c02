//! Shared geometry for every crate of the project, fixed by SPEC §2:
//!
//! - [`se3`]: exponential and logarithm maps of SE(3) with the tangent order τ = [ρ, θ]
//!   (translation first) and the left update `T ← Exp(τ)·T`;
//! - [`camera`]: pinhole intrinsics in the OpenCV optical frame (x right, y down, z forward);
//! - [`frames`]: the robot's planar pose and the fixed rotation from the robot base frame
//!   (REP 103: x forward, y left, z up) to the camera optical frame;
//! - [`robot`]: the robot model (camera height, radius, step and turn sizes) and its one
//!   discrete [`Action`] type;
//! - [`tum`]: trajectories in the TUM text format (`t tx ty tz qx qy qz qw`);
//! - [`snapshots`]: map snapshots kept for a consumer running L frames behind the mapper (the map
//!   lag every map consumer shares).
//!
//! Poses are `nalgebra::Isometry3<f64>` everywhere; `T_a_b` maps points of frame `b` into `a`.

pub mod camera;
pub mod frames;
pub mod robot;
pub mod se3;
pub mod snapshots;
pub mod tum;

pub use camera::Intrinsics;
pub use frames::{PlanarPose, camera_pose_from_planar, planar_from_camera_pose};
pub use nalgebra::{Isometry3, Matrix3, Matrix6, Point3, UnitQuaternion, Vector3, Vector6};
pub use robot::{Action, RobotModel};
