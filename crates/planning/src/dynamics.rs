//! The discrete actions of the robot (SPEC §1: forward 5 cm, turn 5°) and their forward model,
//! which turns an action sequence, or a path followed by the greedy follower, into the future
//! planar poses that the Fisher scorer evaluates (SPEC §6).

use activemap_geometry::PlanarPose;
use nalgebra::Point2;
use serde::{Deserialize, Serialize};

use crate::error::PlanningError;
use crate::follower::{FollowerConfig, GreedyFollower};

/// The robot's one action type and its model (step and turn sizes, camera height, radius):
/// `activemap_geometry::robot`, re-exported for the planners.
pub use activemap_geometry::robot::{Action, RobotModel, wrap_angle};

/// Whether a forward move of `forward_m` metres was blocked: the robot went from `from` to
/// `to` (planar positions, metres) less than half a step. The follower judges its tracked
/// poses with it (a bumper), the evaluator the true ones (the blocked-move count).
pub fn forward_was_blocked(from: Point2<f64>, to: Point2<f64>, forward_m: f64) -> bool {
    (to - from).norm() < 0.5 * forward_m
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
    model: &RobotModel,
    max_steps: usize,
) -> Result<Rollout, PlanningError> {
    model
        .validate()
        .map_err(|reason| PlanningError::InvalidConfig {
            field: "RobotModel",
            reason,
        })?;
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
        let m = RobotModel::default();
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
