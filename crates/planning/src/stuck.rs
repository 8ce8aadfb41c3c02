//! Stuck detection: the robot makes no progress toward its goal over N steps (a collision, a
//! slide, or a follower that circles). Progress is a new best distance to the goal, better by
//! at least `min_improvement_m`; turning on the spot is not progress, so N should exceed the
//! number of turns of a half circle (36 at 5°).

use serde::{Deserialize, Serialize};

use crate::error::{PlanningError, require};

/// Watches the distance to the current goal and reports when it stopped shrinking.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProgressMonitor {
    window: usize,
    min_improvement_m: f64,
    best: f64,
    steps_since_progress: usize,
}

impl ProgressMonitor {
    /// A monitor that declares the robot stuck after `window` steps without a new best
    /// distance improved by `min_improvement_m` metres.
    pub fn new(window: usize, min_improvement_m: f64) -> Result<Self, PlanningError> {
        require(window >= 1, "ProgressMonitor::window", "must be at least 1")?;
        require(
            min_improvement_m.is_finite() && min_improvement_m >= 0.0,
            "ProgressMonitor::min_improvement_m",
            "must be finite and non-negative",
        )?;
        Ok(Self {
            window,
            min_improvement_m,
            best: f64::INFINITY,
            steps_since_progress: 0,
        })
    }

    /// Forgets the history (call on a new goal or path).
    pub fn reset(&mut self) {
        self.best = f64::INFINITY;
        self.steps_since_progress = 0;
    }

    /// Records the distance to the goal after one step; returns true when stuck.
    pub fn observe(&mut self, distance_to_goal_m: f64) -> bool {
        if distance_to_goal_m.is_finite() && distance_to_goal_m < self.best - self.min_improvement_m
        {
            self.best = distance_to_goal_m;
            self.steps_since_progress = 0;
        } else {
            self.steps_since_progress += 1;
        }
        self.steps_since_progress >= self.window
    }

    /// Steps since the last progress.
    pub fn steps_since_progress(&self) -> usize {
        self.steps_since_progress
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamics::{Action, RobotModel};
    use activemap_geometry::PlanarPose;

    #[test]
    fn a_blocked_robot_is_stuck_and_a_turning_then_driving_robot_is_not() {
        let model = RobotModel::default();
        let goal = (2.0, 0.0);
        let dist = |p: &PlanarPose| ((p.x - goal.0).powi(2) + (p.y - goal.1).powi(2)).sqrt();
        // Turn 180° (36 turns), then drive: never stuck with a 40-step window.
        let mut m = ProgressMonitor::new(40, 0.01).unwrap();
        let mut p = PlanarPose::new(0.0, 0.0, std::f64::consts::PI);
        let mut actions = vec![Action::TurnLeft; 36];
        actions.extend([Action::Forward; 30]);
        for a in actions {
            p = model.apply(&p, a);
            assert!(!m.observe(dist(&p)));
        }
        // Pressing against a wall: forward commands that do not move the robot.
        let mut stuck_at = None;
        for k in 0..100 {
            if m.observe(dist(&p)) {
                stuck_at = Some(k);
                break;
            }
        }
        assert_eq!(stuck_at, Some(39));
        m.reset();
        assert!(!m.observe(dist(&p)));
        assert!(ProgressMonitor::new(0, 0.0).is_err());
    }
}
