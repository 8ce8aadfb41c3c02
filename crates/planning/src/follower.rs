//! The greedy path follower (SPEC §6, release): if the heading error to the next waypoint
//! exceeds 5°, turn toward it; otherwise move forward. A waypoint counts as reached within a
//! distance tolerance, then the next one becomes the target.

use activemap_geometry::PlanarPose;
use nalgebra::Point2;
use serde::{Deserialize, Serialize};

use crate::dynamics::{Action, wrap_angle};
use crate::error::{PlanningError, require};

/// Settings of the greedy follower.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FollowerConfig {
    /// Turn when the absolute heading error exceeds this, radians (SPEC: 5°).
    pub turn_threshold_rad: f64,
    /// A waypoint is reached within this distance, metres. Keep it above half the forward
    /// step (and above `forward · sin(threshold)` lateral drift) or the robot may circle.
    pub waypoint_tolerance_m: f64,
}

impl Default for FollowerConfig {
    fn default() -> Self {
        Self {
            turn_threshold_rad: 5f64.to_radians(),
            waypoint_tolerance_m: 0.1,
        }
    }
}

impl FollowerConfig {
    /// Checks the ranges of every field.
    pub fn validate(&self) -> Result<(), PlanningError> {
        require(
            self.turn_threshold_rad.is_finite() && self.turn_threshold_rad >= 0.0,
            "FollowerConfig::turn_threshold_rad",
            "must be finite and non-negative",
        )?;
        require(
            self.waypoint_tolerance_m.is_finite() && self.waypoint_tolerance_m > 0.0,
            "FollowerConfig::waypoint_tolerance_m",
            "must be finite and positive",
        )
    }
}

/// Heading error (radians, in (−π, π]) from `pose` toward `target`; positive = target to the left.
pub fn heading_error(pose: &PlanarPose, target: &Point2<f64>) -> f64 {
    let bearing = (target.y - pose.y).atan2(target.x - pose.x);
    wrap_angle(bearing - pose.yaw)
}

/// The greedy action toward `target`: turn toward it when the heading error exceeds
/// `threshold`, else forward.
pub fn greedy_action(pose: &PlanarPose, target: &Point2<f64>, threshold: f64) -> Action {
    let e = heading_error(pose, target);
    if e > threshold {
        Action::TurnLeft
    } else if e < -threshold {
        Action::TurnRight
    } else {
        Action::Forward
    }
}

/// Whether the robot at heading `yaw` must turn on the spot to face `look_yaw` (the bearing of
/// the frontier it came to look at): false when the bearing is within `skip_half_angle` of the
/// heading, i.e. the frontier is already in the camera's view (its half hfov is 45°), so the
/// turn would show nothing new. Angles in radians.
pub fn look_turn_needed(yaw: f64, look_yaw: f64, skip_half_angle: f64) -> bool {
    wrap_angle(look_yaw - yaw).abs() > skip_half_angle
}

/// Follows a list of world waypoints with the greedy rule.
#[derive(Debug, Clone, PartialEq)]
pub struct GreedyFollower {
    config: FollowerConfig,
    waypoints: Vec<Point2<f64>>,
    next: usize,
}

impl GreedyFollower {
    /// A follower for `waypoints` (world points; the first is usually the robot's start cell).
    pub fn new(config: FollowerConfig, waypoints: Vec<Point2<f64>>) -> Result<Self, PlanningError> {
        config.validate()?;
        if waypoints
            .iter()
            .any(|p| !(p.x.is_finite() && p.y.is_finite()))
        {
            return Err(PlanningError::NonFinite {
                what: "follower waypoint",
            });
        }
        Ok(Self {
            config,
            waypoints,
            next: 0,
        })
    }

    /// The settings.
    pub fn config(&self) -> &FollowerConfig {
        &self.config
    }

    /// The waypoints not reached yet.
    pub fn remaining(&self) -> &[Point2<f64>] {
        &self.waypoints[self.next..]
    }

    /// The waypoint currently aimed at.
    pub fn target(&self) -> Option<Point2<f64>> {
        self.waypoints.get(self.next).copied()
    }

    /// Whether every waypoint has been reached.
    pub fn is_done(&self) -> bool {
        self.next >= self.waypoints.len()
    }

    /// Advances past reached waypoints, then returns the action toward the current one, or
    /// `None` when the path is done.
    pub fn next_action(&mut self, pose: &PlanarPose) -> Option<Action> {
        self.next_action_checked(pose, |_, _| true)
    }

    /// [`GreedyFollower::next_action`] that keeps clear of obstacles when cutting toward the
    /// next waypoint: a waypoint reached within the tolerance is only left behind when
    /// `line_is_clear(here, following waypoint)` holds, or once the robot is within half the
    /// tolerance of it. The planned move between two waypoints is clear, but the line from
    /// where the robot actually is may graze a door jamb; closing in first shrinks the offset.
    /// Half the tolerance (0.05 m by default) is still above half a forward step, so the robot
    /// does not circle.
    pub fn next_action_checked(
        &mut self,
        pose: &PlanarPose,
        line_is_clear: impl Fn(Point2<f64>, Point2<f64>) -> bool,
    ) -> Option<Action> {
        let here = Point2::new(pose.x, pose.y);
        while let Some(t) = self.waypoints.get(self.next) {
            let d = (t - here).norm();
            if d > self.config.waypoint_tolerance_m {
                break;
            }
            let close = d <= 0.5 * self.config.waypoint_tolerance_m;
            match self.waypoints.get(self.next + 1) {
                Some(u) if !close && !line_is_clear(here, *u) => break,
                _ => self.next += 1,
            }
        }
        let t = self.waypoints.get(self.next)?;
        Some(greedy_action(pose, t, self.config.turn_threshold_rad))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dynamics::{RobotModel, rollout};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn a_waypoint_is_left_early_only_when_the_line_to_the_next_is_clear() {
        // Waypoints (0.5, 0) then (0.5, 1); the robot comes in along y = 0.075, reaching the
        // tolerance (0.1 m) of the first one at x ≈ 0.435, 7.5 cm off its line.
        let waypoints = vec![Point2::new(0.5, 0.0), Point2::new(0.5, 1.0)];
        let drive = |line_is_clear: &dyn Fn(Point2<f64>, Point2<f64>) -> bool| {
            let mut f = GreedyFollower::new(FollowerConfig::default(), waypoints.clone()).unwrap();
            let model = RobotModel::default();
            let mut pose = PlanarPose::new(0.0, 0.075, 0.0);
            for _ in 0..200 {
                if f.remaining().len() == 1 {
                    return Point2::new(pose.x, pose.y);
                }
                let a = f.next_action_checked(&pose, line_is_clear).unwrap();
                pose = model.apply(&pose, a);
            }
            panic!("never passed the first waypoint");
        };
        let first = waypoints[0];
        // A clear line: the waypoint is left as soon as it is within 0.1 m.
        let loose = drive(&|_, _| true);
        assert!((loose - first).norm() <= 0.1 && (loose - first).norm() > 0.05);
        // A line that grazes something unless it starts within 3 cm of x = 0.5: the robot
        // closes in to within 0.05 m first.
        let tight = drive(&|a: Point2<f64>, _| (a.x - 0.5).abs() < 0.03);
        assert!((tight - first).norm() <= 0.05, "{tight:?}");
    }

    #[test]
    fn turns_toward_the_side_of_the_target_and_goes_forward_when_aligned() {
        let p = PlanarPose::new(0.0, 0.0, 0.0);
        let th = 5f64.to_radians();
        assert_eq!(
            greedy_action(&p, &Point2::new(1.0, 0.5), th),
            Action::TurnLeft
        );
        assert_eq!(
            greedy_action(&p, &Point2::new(1.0, -0.5), th),
            Action::TurnRight
        );
        // 4° off: forward; 6° off: turn.
        let a4 = 4f64.to_radians();
        let a6 = 6f64.to_radians();
        assert_eq!(
            greedy_action(&p, &Point2::new(a4.cos(), a4.sin()), th),
            Action::Forward
        );
        assert_eq!(
            greedy_action(&p, &Point2::new(a6.cos(), -a6.sin()), th),
            Action::TurnRight
        );
        // Behind across the ±π seam.
        let q = PlanarPose::new(0.0, 0.0, 3.1);
        assert_eq!(
            greedy_action(&q, &Point2::new(-1.0, -0.1), th),
            Action::TurnLeft
        );
    }

    #[test]
    fn follower_and_dynamics_reach_random_goals_in_free_space() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let cfg = FollowerConfig::default();
        let model = RobotModel::default();
        for _ in 0..200 {
            let start = PlanarPose::new(
                rng.random_range(-2.0..2.0),
                rng.random_range(-2.0..2.0),
                rng.random_range(-std::f64::consts::PI..std::f64::consts::PI),
            );
            let n = rng.random_range(1..5);
            let wps: Vec<Point2<f64>> = (0..n)
                .map(|_| Point2::new(rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0)))
                .collect();
            let r = rollout(&start, &wps, &cfg, &model, 5000).unwrap();
            assert!(r.reached, "did not reach {wps:?} from {start:?}");
            let last = r.poses.last().copied().unwrap_or(start);
            let goal = wps[n - 1];
            assert!(((last.x - goal.x).powi(2) + (last.y - goal.y).powi(2)).sqrt() <= 0.1 + 1e-9);
            // Efficiency: the travelled distance is at most the polyline length plus slack for
            // the 5° wiggle and the tolerance cut-offs.
            let mut poly = 0.0;
            let mut prev = Point2::new(start.x, start.y);
            for w in &wps {
                poly += (w - prev).norm();
                prev = *w;
            }
            let forward = r.actions.iter().filter(|a| **a == Action::Forward).count();
            assert!((forward as f64) * 0.05 <= poly * 1.01 + 0.05 * n as f64 + 0.1);
        }
    }

    #[test]
    fn look_turn_is_skipped_only_when_the_frontier_is_in_view() {
        let half = 40f64.to_radians();
        assert!(!look_turn_needed(0.0, 39f64.to_radians(), half));
        assert!(!look_turn_needed(0.0, -39f64.to_radians(), half));
        assert!(look_turn_needed(0.0, 41f64.to_radians(), half));
        assert!(look_turn_needed(0.0, std::f64::consts::PI, half));
        // Across the ±π seam: 170° and −170° are 20° apart.
        assert!(!look_turn_needed(
            170f64.to_radians(),
            -170f64.to_radians(),
            half
        ));
        // 0 never skips a real turn.
        assert!(look_turn_needed(0.0, 1f64.to_radians(), 0.0));
    }

    #[test]
    fn done_follower_returns_none_and_bad_waypoints_are_refused() {
        let mut f =
            GreedyFollower::new(FollowerConfig::default(), vec![Point2::new(0.05, 0.0)]).unwrap();
        assert_eq!(f.next_action(&PlanarPose::new(0.0, 0.0, 0.0)), None);
        assert!(f.is_done());
        assert!(
            GreedyFollower::new(FollowerConfig::default(), vec![Point2::new(f64::NAN, 0.0)])
                .is_err()
        );
    }
}
