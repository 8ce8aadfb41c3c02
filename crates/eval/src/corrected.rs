//! The estimated trajectory as the tracker's keyframe pose graph finally places it. The
//! tracker publishes each frame's estimate once, when it is made (the online trajectory,
//! `trajectory_est.tum`, what the robot knew at each step). With the pose graph, each estimate
//! also names the graph keyframe it hangs on, and a loop closure later moves graph keyframes
//! by world-frame corrections `T_after · T_before⁻¹`: every frame hung on a moved keyframe moves
//! with it. Applying them all gives the trajectory the graph ends with
//! (`trajectory_final.tum`), the one SLAM systems with loop closure report their ATE on.

use std::collections::BTreeMap;

use activemap_geometry::Isometry3;
use activemap_geometry::tum::Trajectory;

/// The online estimates, moved by every later correction of the graph keyframe each hangs on.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CorrectedTrajectory {
    trajectory: Trajectory,
    /// Per graph keyframe (by frame id): the indices of the estimates hung on it.
    hung_on: BTreeMap<u64, Vec<usize>>,
}

impl CorrectedTrajectory {
    /// Applies `corrections` (graph keyframe frame id, `T_after · T_before⁻¹`) to the estimates
    /// so far, then appends the estimate `pose` at `stamp`, hung on the graph keyframe
    /// `anchor` (`None`: no pose graph; the estimate never moves). A correction of a keyframe
    /// nothing hangs on changes nothing.
    pub fn push(
        &mut self,
        stamp: f64,
        pose: Isometry3<f64>,
        anchor: Option<u64>,
        corrections: &[(u64, Isometry3<f64>)],
    ) {
        for (keyframe, correction) in corrections {
            for &i in self.hung_on.get(keyframe).into_iter().flatten() {
                let moved = correction * self.trajectory.poses[i];
                self.trajectory.poses[i] = activemap_geometry::se3::normalized(&moved);
            }
        }
        if let Some(a) = anchor {
            self.hung_on
                .entry(a)
                .or_default()
                .push(self.trajectory.len());
        }
        self.trajectory.push(stamp, pose);
    }

    /// The corrected trajectory, when some estimate hung on a graph keyframe (the pose graph
    /// was on); `None` otherwise (it would equal the online one).
    pub fn trajectory(&self) -> Option<&Trajectory> {
        (!self.hung_on.is_empty()).then_some(&self.trajectory)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_geometry::se3::pose_error;
    use nalgebra::{Translation3, UnitQuaternion};

    /// Each estimate takes exactly the corrections of its own graph keyframe that come after
    /// it, composed in order; estimates of other keyframes, and later ones, do not move.
    #[test]
    fn estimates_move_with_the_later_corrections_of_their_keyframe() {
        let a = Isometry3::from_parts(
            Translation3::new(0.1, 0.0, -0.02),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.05),
        );
        let b = Isometry3::translation(0.0, 0.03, 0.0);
        let pose = |x: f64| Isometry3::translation(x, 1.0, 0.0);
        let mut t = CorrectedTrajectory::default();
        t.push(0.0, pose(0.0), Some(0), &[]);
        t.push(1.0, pose(1.0), Some(0), &[]);
        t.push(2.0, pose(2.0), Some(2), &[]);
        // Frame 3 closes a loop: keyframe 0 moves by a; keyframe 2 does not.
        t.push(3.0, pose(3.0), Some(2), &[(0, a)]);
        // Frame 4: keyframe 0 moves again by b, keyframe 2 by a, and an unknown one (7).
        t.push(4.0, pose(4.0), Some(4), &[(0, b), (2, a), (7, b)]);
        let got = &t.trajectory().unwrap().poses;
        let want = [
            b * a * pose(0.0),
            b * a * pose(1.0),
            a * pose(2.0),
            a * pose(3.0),
            pose(4.0),
        ];
        for (k, (g, w)) in got.iter().zip(&want).enumerate() {
            let (dt, da) = pose_error(g, w);
            assert!(dt < 1e-12 && da < 1e-12, "frame {k}: {dt} m, {da} rad");
        }
        // Without a graph there is no corrected trajectory.
        let mut plain = CorrectedTrajectory::default();
        plain.push(0.0, pose(0.0), None, &[]);
        assert!(plain.trajectory().is_none());
    }
}
