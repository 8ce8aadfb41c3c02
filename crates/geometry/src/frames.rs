//! Robot and camera frames (SPEC §2). The world is z-up; the robot moves in the plane z = floor.
//! Its base frame follows REP 103 (x forward, y left, z up); the camera sits `height` metres
//! above the base looking forward, in the OpenCV optical frame (x right, y down, z forward).

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// A pose on the motion plane: position (metres) and heading `yaw` (radians, about +z, 0 = +x).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct PlanarPose {
    /// World x, metres.
    pub x: f64,
    /// World y, metres.
    pub y: f64,
    /// Heading about world +z, radians.
    pub yaw: f64,
}

impl PlanarPose {
    /// Creates a planar pose.
    pub fn new(x: f64, y: f64, yaw: f64) -> Self {
        Self { x, y, yaw }
    }

    /// The base frame `T_world_base` with the floor at height `floor_z`.
    pub fn to_isometry(&self, floor_z: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(self.x, self.y, floor_z),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), self.yaw),
        )
    }

    /// Projects a base or camera pose back onto the plane: position and heading of its
    /// forward axis (`forward` given in that frame: +x for a base, +z for an optical frame).
    pub fn from_isometry(pose: &Isometry3<f64>, forward: &Vector3<f64>) -> Self {
        let f = pose.rotation * forward;
        Self {
            x: pose.translation.x,
            y: pose.translation.y,
            yaw: f.y.atan2(f.x),
        }
    }
}

/// The rotation `R_base_optical`: columns are the optical axes (right, down, forward) expressed
/// in the base frame (forward, left, up).
pub fn base_from_optical() -> UnitQuaternion<f64> {
    let m = Matrix3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0);
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m))
}

/// `T_world_camera` for a robot at `pose` whose camera is `camera_height` metres above a floor
/// at `floor_z`, looking horizontally forward.
pub fn camera_pose_from_planar(
    pose: &PlanarPose,
    floor_z: f64,
    camera_height: f64,
) -> Isometry3<f64> {
    let base = pose.to_isometry(floor_z);
    let mount = Isometry3::from_parts(
        Translation3::new(0.0, 0.0, camera_height),
        base_from_optical(),
    );
    base * mount
}

/// The planar pose of the robot that carries a camera at `T_world_camera` (inverse of
/// [`camera_pose_from_planar`] for a level camera).
pub fn planar_from_camera_pose(t_world_camera: &Isometry3<f64>) -> PlanarPose {
    PlanarPose::from_isometry(t_world_camera, &Vector3::z())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn optical_axes_point_the_right_way() {
        let t = camera_pose_from_planar(&PlanarPose::new(1.0, 2.0, 0.0), 0.0, 0.88);
        let fwd = t.rotation * Vector3::z();
        let right = t.rotation * Vector3::x();
        let down = t.rotation * Vector3::y();
        assert!((fwd - Vector3::x()).norm() < 1e-12);
        assert!((right + Vector3::y()).norm() < 1e-12);
        assert!((down + Vector3::z()).norm() < 1e-12);
        assert!((t.translation.vector - Vector3::new(1.0, 2.0, 0.88)).norm() < 1e-12);
    }

    #[test]
    fn planar_round_trip() {
        let p = PlanarPose::new(-0.3, 4.0, 2.5);
        let back = planar_from_camera_pose(&camera_pose_from_planar(&p, 0.1, 0.88));
        assert!((back.x - p.x).abs() < 1e-12 && (back.y - p.y).abs() < 1e-12);
        assert!((back.yaw - p.yaw).abs() < 1e-12);
    }
}
