//! The discrete actions of the robot (SPEC §1: forward 5 cm, turn 5°) and their forward model,
//! which turns an action sequence, or a path followed by the greedy follower, into the future
//! planar poses that the Fisher scorer evaluates (SPEC §6).

use activemap_geometry::PlanarPose;
use nalgebra::Point2;
use serde::{Deserialize, Serialize};

use crate::error::{PlanningError, require};
use crate::follower::{FollowerConfig, GreedyFollower};

/// One discrete robot action.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Action {
    /// Move forward along the heading by [`ActionModel::forward_m`].
    Forward,
    /// Turn counter-clockwise (toward +yaw) by [`ActionModel::turn_rad`].
    TurnLeft,
    /// Turn clockwise by [`ActionModel::turn_rad`].
    TurnRight,
}

/// Sizes of the discrete actions.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ActionModel {
    /// Forward step, metres (SPEC: 0.05).
    pub forward_m: f64,
    /// Turn step, radians (SPEC: 5°).
    pub turn_rad: f64,
}

impl Default for ActionModel {
    fn default() -> Self {
        Self {
            forward_m: 0.05,
            turn_rad: 5f64.to_radians(),
        }
    }
}

/// Whether a forward move of `forward_m` metres was blocked: the robot went from `from` to
/// `to` (planar positions, metres) less than half a step. The follower judges its tracked
/// poses with it (a bumper), the evaluator the true ones (the blocked-move count).
pub fn forward_was_blocked(from: Point2<f64>, to: Point2<f64>, forward_m: f64) -> bool {
    (to - from).norm() < 0.5 * forward_m
}

/// Wraps an angle to (−π, π].
pub fn wrap_angle(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    let w = a - t * (a / t).round();
    if w <= -std::f64::consts::PI { w + t } else { w }
}

impl ActionModel {
    /// Checks the ranges of every field.
    pub fn validate(&self) -> Result<(), PlanningError> {
        require(
            self.forward_m.is_finite() && self.forward_m > 0.0,
            "ActionModel::forward_m",
            "must be finite and positive",
        )?;
        require(
            self.turn_rad.is_finite()
                && self.turn_rad > 0.0
                && self.turn_rad < std::f64::consts::PI,
            "ActionModel::turn_rad",
            "must be in (0, π)",
        )
    }

    /// The pose after applying `action` at `pose` in free space (no collisions or slides).
    pub fn apply(&self, pose: &PlanarPose, action: Action) -> PlanarPose {
        match action {
            Action::Forward => PlanarPose::new(
                pose.x + self.forward_m * pose.yaw.cos(),
                pose.y + self.forward_m * pose.yaw.sin(),
                pose.yaw,
            ),
            Action::TurnLeft => {
                PlanarPose::new(pose.x, pose.y, wrap_angle(pose.yaw + self.turn_rad))
            }
            Action::TurnRight => {
                PlanarPose::new(pose.x, pose.y, wrap_angle(pose.yaw - self.turn_rad))
            }
        }
    }

    /// The poses after each action of `actions`, starting from `start` (start not included).
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
}

/// The result of simulating the follower along a path.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Rollout {
    /// The actions the follower chose, in order.
    pub actions: Vec<Action>,
    /// The pose after each action (the start not included).
    pub poses: Vec<PlanarPose>,
    /// Whether the last waypoint was reached within `max_steps`.
    pub reached: bool,
}

/// Simulates the greedy follower on `waypoints` from `start` with the forward model, for at
/// most `max_steps` actions: the poses the robot would visit following the path.
pub fn rollout(
    start: &PlanarPose,
    waypoints: &[Point2<f64>],
    follower: &FollowerConfig,
    model: &ActionModel,
    max_steps: usize,
) -> Result<Rollout, PlanningError> {
    model.validate()?;
    let mut f = GreedyFollower::new(*follower, waypoints.to_vec())?;
    let mut pose = *start;
    let mut out = Rollout {
        actions: Vec::new(),
        poses: Vec::new(),
        reached: false,
    };
    for _ in 0..max_steps {
        match f.next_action(&pose) {
            None => break,
            Some(a) => {
                pose = model.apply(&pose, a);
                out.actions.push(a);
                out.poses.push(pose);
            }
        }
    }
    out.reached = f.is_done() || f.next_action(&pose).is_none();
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn actions_move_and_turn_by_the_configured_amounts() {
        let m = ActionModel::default();
        let p = PlanarPose::new(1.0, 2.0, std::f64::consts::FRAC_PI_2);
        let f = m.apply(&p, Action::Forward);
        assert!((f.x - 1.0).abs() < 1e-12 && (f.y - 2.05).abs() < 1e-12);
        let l = m.apply(&p, Action::TurnLeft);
        assert!((l.yaw - 95f64.to_radians()).abs() < 1e-12 && l.x == p.x);
        let r = m.apply(&p, Action::TurnRight);
        assert!((r.yaw - 85f64.to_radians()).abs() < 1e-12);
        // 72 left turns of 5° are a full circle.
        let spun = m.rollout_actions(&p, &[Action::TurnLeft; 72]);
        assert!(wrap_angle(spun[71].yaw - p.yaw).abs() < 1e-9);
        assert_eq!(spun.len(), 72);
    }

    #[test]
    fn wrap_angle_stays_in_range() {
        for k in -20..20 {
            let a = k as f64 * 0.7;
            let w = wrap_angle(a);
            assert!(w > -std::f64::consts::PI - 1e-12 && w <= std::f64::consts::PI + 1e-12);
            assert!(
                ((a - w) / std::f64::consts::TAU).fract().abs() < 1e-9
                    || ((a - w) / std::f64::consts::TAU).fract().abs() > 1.0 - 1e-9
            );
        }
    }
}
