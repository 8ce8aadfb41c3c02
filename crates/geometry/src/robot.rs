//! The robot (SPEC §1): a wheeled base with an RGB-D camera at a fixed height, moving by
//! discrete actions (forward 5 cm, turn 5° left or right). One [`RobotModel`] and one
//! [`Action`] for the whole project: the simulator executes them, the tracker predicts with
//! them, the planner and the follower roll them out, and the evaluator reads the same values
//! back from the run folder. The sim node's config may override the defaults; the run folder
//! records what was used. In a dataflow every node that needs it takes an optional `robot:`
//! config (any field left out keeps its default) and `activemap validate` checks that they agree.

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use crate::frames::{PlanarPose, camera_pose_from_planar};

/// One discrete action of the robot (Habitat's action space, SPEC §1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Action {
    /// Move forward along the heading by [`RobotModel::forward_step_m`].
    Forward,
    /// Turn counter-clockwise seen from above (toward +yaw) by [`RobotModel::turn_angle_rad`].
    TurnLeft,
    /// Turn clockwise by [`RobotModel::turn_angle_rad`].
    TurnRight,
}

impl Action {
    /// All actions, in a fixed order.
    pub const ALL: [Action; 3] = [Action::Forward, Action::TurnLeft, Action::TurnRight];

    /// Parses Habitat's action names (`move_forward`, `turn_left`, `turn_right`; `forward` too).
    pub fn from_name(name: &str) -> Option<Action> {
        match name {
            "move_forward" | "forward" => Some(Action::Forward),
            "turn_left" => Some(Action::TurnLeft),
            "turn_right" => Some(Action::TurnRight),
            _ => None,
        }
    }

    /// Habitat's name of the action.
    pub fn name(self) -> &'static str {
        match self {
            Action::Forward => "move_forward",
            Action::TurnLeft => "turn_left",
            Action::TurnRight => "turn_right",
        }
    }
}

/// The robot's physical facts (SPEC §1 defaults): every place that needs one reads it here.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RobotModel {
    /// Height of the camera's optical centre above the floor, metres (0.88).
    pub camera_height_m: f64,
    /// Radius of the robot's cylindrical body, metres (0.1): planning keeps this disc off every
    /// blocked cell and the occupancy grid marks it free around the robot.
    pub radius_m: f64,
    /// Length of a forward step, metres (0.05).
    pub forward_step_m: f64,
    /// Angle of a turn, radians (5°).
    pub turn_angle_rad: f64,
}

impl Default for RobotModel {
    fn default() -> Self {
        Self {
            camera_height_m: 0.88,
            radius_m: 0.1,
            forward_step_m: 0.05,
            turn_angle_rad: 5f64.to_radians(),
        }
    }
}

/// Wraps an angle to (−π, π].
pub fn wrap_angle(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    let w = a - t * (a / t).round();
    if w <= -std::f64::consts::PI { w + t } else { w }
}

impl RobotModel {
    /// Checks the ranges of every field; the message names the field.
    pub fn validate(&self) -> Result<(), String> {
        let check = |ok: bool, field: &str, value: f64, reason: &str| {
            if ok {
                Ok(())
            } else {
                Err(format!("robot model: {field} = {value} {reason}"))
            }
        };
        check(
            self.camera_height_m.is_finite() && self.camera_height_m > 0.0,
            "camera_height_m",
            self.camera_height_m,
            "must be finite and > 0",
        )?;
        check(
            self.radius_m.is_finite() && self.radius_m > 0.0,
            "radius_m",
            self.radius_m,
            "must be finite and > 0",
        )?;
        check(
            self.forward_step_m.is_finite() && self.forward_step_m > 0.0,
            "forward_step_m",
            self.forward_step_m,
            "must be finite and > 0",
        )?;
        check(
            self.turn_angle_rad.is_finite()
                && self.turn_angle_rad > 0.0
                && self.turn_angle_rad < std::f64::consts::PI,
            "turn_angle_rad",
            self.turn_angle_rad,
            "must be in (0, π)",
        )
    }

    /// The planar pose after `action` at `pose` in free space (no collisions or slides).
    pub fn apply(&self, pose: &PlanarPose, action: Action) -> PlanarPose {
        match action {
            Action::Forward => PlanarPose::new(
                pose.x + self.forward_step_m * pose.yaw.cos(),
                pose.y + self.forward_step_m * pose.yaw.sin(),
                pose.yaw,
            ),
            Action::TurnLeft => {
                PlanarPose::new(pose.x, pose.y, wrap_angle(pose.yaw + self.turn_angle_rad))
            }
            Action::TurnRight => {
                PlanarPose::new(pose.x, pose.y, wrap_angle(pose.yaw - self.turn_angle_rad))
            }
        }
    }

    /// The poses after each of `actions` from `start` in free space (start not included).
    pub fn rollout_actions(&self, start: &PlanarPose, actions: &[Action]) -> Vec<PlanarPose> {
        let mut pose = *start;
        actions
            .iter()
            .map(|a| {
                pose = self.apply(&pose, *a);
                pose
            })
            .collect()
    }

    /// The commanded motion of the camera for `action`, `T_prev_current` in the optical frame
    /// (forward = +z by one step; a left turn swings the optical axis toward camera −x): the
    /// tracker's motion prior. Not ground truth: collisions make it wrong.
    pub fn camera_motion(&self, action: Action) -> Isometry3<f64> {
        let origin = PlanarPose::new(0.0, 0.0, 0.0);
        let before = camera_pose_from_planar(&origin, 0.0, self.camera_height_m);
        let after =
            camera_pose_from_planar(&self.apply(&origin, action), 0.0, self.camera_height_m);
        before.inverse() * after
    }

    /// The camera pose `T_world_camera` of the robot at planar `pose` on a floor at `floor_z`.
    pub fn camera_pose(&self, pose: &PlanarPose, floor_z: f64) -> Isometry3<f64> {
        camera_pose_from_planar(pose, floor_z, self.camera_height_m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    /// The commanded motion is the camera-frame motion of the robot: forward = +z (optical
    /// axis) by 5 cm; a left turn rotates the optical axis toward camera −x (left) by 5°; a
    /// right turn undoes it.
    #[test]
    fn camera_motion_matches_the_camera_frame() {
        let robot = RobotModel::default();
        let f = robot.camera_motion(Action::Forward);
        assert!((f.translation.vector - Vector3::new(0.0, 0.0, 0.05)).norm() < 1e-12);
        assert!(f.rotation.angle() < 1e-12);
        let l = robot.camera_motion(Action::TurnLeft);
        assert!(l.translation.vector.norm() < 1e-12);
        assert!((l.rotation.angle() - 5f64.to_radians()).abs() < 1e-12);
        let fwd = l.rotation * Vector3::z();
        assert!(
            fwd.x < -0.08,
            "left turn must swing the optical axis to camera −x: {fwd:?}"
        );
        let r = robot.camera_motion(Action::TurnRight);
        assert!((r * l).rotation.angle() < 1e-12);
    }

    #[test]
    fn actions_round_trip_through_their_names_and_bad_models_are_refused() {
        for a in Action::ALL {
            assert_eq!(Action::from_name(a.name()), Some(a));
        }
        assert_eq!(Action::from_name("fly"), None);
        assert!(RobotModel::default().validate().is_ok());
        let bad = RobotModel {
            radius_m: f64::NAN,
            ..RobotModel::default()
        };
        assert!(bad.validate().unwrap_err().contains("radius_m"));
    }

    #[test]
    fn turning_wraps_the_heading() {
        let robot = RobotModel::default();
        let mut p = PlanarPose::new(0.0, 0.0, 0.0);
        for _ in 0..72 {
            p = robot.apply(&p, Action::TurnLeft);
        }
        assert!(p.yaw.abs() < 1e-9, "{p:?}");
        assert!((wrap_angle(3.0 * std::f64::consts::PI) - std::f64::consts::PI).abs() < 1e-12);
    }
}
