//! The dense tracker's keyframe references: the newest one, which every frame is aligned to,
//! and older ones of the same place, aligned to jointly ([`crate::dense::align_many`]).
//!
//! Aligning each frame to the newest reference only is visual odometry: every new reference
//! inherits the error of the one before, and the error grows with the length of the chain
//! (measured on the 500-frame scripted loop at 200²: 6.8 cm ATE). When the camera comes back
//! to a place it has seen, an older reference of that place carries the smaller error of
//! its time; aligning to it as well pulls the estimate back (a loop closure without a pose
//! graph: the older references' poses stay fixed).
//!
//! Which older references: those whose estimated pose is near the predicted one (camera
//! centres within `max_distance`, optical axes within `max_angle`), at least `min_age`
//! references older than the newest (its immediate predecessors carry the same drift), the
//! `extra` closest by `distance + metres_per_radian · angle`. Memory stays bounded: past
//! `capacity` references, the younger of the two most similar ones is dropped (the older one
//! of a place is the one worth keeping), never one of the `min_age` newest.

use crate::dense::DenseReference;
use crate::error::SlamError;
use activemap_geometry::Isometry3;
use nalgebra::Vector3;

/// Settings of the reference set.
#[derive(Debug, Clone, PartialEq)]
pub struct ReferenceConfig {
    /// Older references aligned to besides the newest (0 = the newest only: odometry).
    pub extra: usize,
    /// Older references must be at least this many references older than the newest.
    pub min_age: usize,
    /// Farthest camera centre of a usable older reference from the predicted one, metres.
    pub max_distance: f64,
    /// Largest angle between the optical axes of a usable older reference and the
    /// prediction, radians.
    pub max_angle: f64,
    /// Metres charged per radian of optical-axis difference when ranking older references.
    pub metres_per_radian: f64,
    /// Most references kept.
    pub capacity: usize,
}

impl Default for ReferenceConfig {
    fn default() -> Self {
        Self {
            extra: 2,
            min_age: 3,
            max_distance: 0.75,
            max_angle: 30f64.to_radians(),
            metres_per_radian: 1.0,
            capacity: 96,
        }
    }
}

impl ReferenceConfig {
    /// Checks ranges; names the offending field.
    pub fn validate(&self) -> Result<(), SlamError> {
        SlamError::require_positive(&[
            ("references.max_distance", self.max_distance),
            ("references.max_angle", self.max_angle),
        ])?;
        if !(self.metres_per_radian.is_finite() && self.metres_per_radian >= 0.0) {
            return Err(SlamError::Config {
                field: "references.metres_per_radian",
                value: self.metres_per_radian.to_string(),
                reason: "must be finite and ≥ 0",
            });
        }
        if self.capacity < self.min_age + 1 {
            return Err(SlamError::Config {
                field: "references.capacity",
                value: self.capacity.to_string(),
                reason: "must exceed references.min_age",
            });
        }
        Ok(())
    }
}

/// One stored reference with the order it arrived in.
#[derive(Debug, Clone)]
struct Entry {
    serial: u64,
    reference: DenseReference,
}

/// The references kept for tracking (see the module doc).
#[derive(Debug, Clone)]
pub struct References {
    config: ReferenceConfig,
    entries: Vec<Entry>,
    next_serial: u64,
}

/// Camera centre and optical axis (camera +z) of a `T_world_camera`.
fn centre_and_axis(pose: &Isometry3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    (pose.translation.vector, pose.rotation * Vector3::z())
}

impl References {
    /// An empty set.
    pub fn new(config: ReferenceConfig) -> Result<Self, SlamError> {
        config.validate()?;
        Ok(Self {
            config,
            entries: Vec::new(),
            next_serial: 0,
        })
    }

    /// The settings.
    pub fn config(&self) -> &ReferenceConfig {
        &self.config
    }

    /// Number of references kept.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether no reference exists yet.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The newest reference.
    pub fn newest(&self) -> Option<&DenseReference> {
        self.entries.last().map(|e| &e.reference)
    }

    /// Poses of the kept references, oldest first.
    pub fn poses(&self) -> Vec<Isometry3<f64>> {
        self.entries.iter().map(|e| e.reference.pose).collect()
    }

    /// Ranking score of `pose` against `other`: `None` when beyond the distance or angle
    /// limits, else `distance + metres_per_radian · angle`.
    fn score(&self, pose: &Isometry3<f64>, other: &Isometry3<f64>) -> Option<f64> {
        let (c0, a0) = centre_and_axis(pose);
        let (c1, a1) = centre_and_axis(other);
        let distance = (c0 - c1).norm();
        let angle = a0.dot(&a1).clamp(-1.0, 1.0).acos();
        (distance <= self.config.max_distance && angle <= self.config.max_angle)
            .then_some(distance + self.config.metres_per_radian * angle)
    }

    /// Adds `reference` as the newest; drops one if over capacity (see the module doc).
    pub fn push(&mut self, reference: DenseReference) {
        self.entries.push(Entry {
            serial: self.next_serial,
            reference,
        });
        self.next_serial += 1;
        if self.entries.len() > self.config.capacity {
            let protected = self.entries.len() - self.config.min_age.max(1);
            // The closest pair (i < j, j not protected): drop j, the younger.
            let mut best: Option<(f64, usize)> = None;
            for j in 1..protected {
                for i in 0..j {
                    let s = self
                        .score(
                            &self.entries[i].reference.pose,
                            &self.entries[j].reference.pose,
                        )
                        .unwrap_or(f64::INFINITY);
                    if best.is_none_or(|(b, _)| s < b) {
                        best = Some((s, j));
                    }
                }
            }
            // With no similar pair at all, the oldest unprotected one after the first goes.
            let drop = match best {
                Some((s, j)) if s.is_finite() => j,
                _ => 1.min(protected.saturating_sub(1)),
            };
            self.entries.remove(drop);
        }
    }

    /// The references to align a frame predicted at `predicted` to: the newest first, then up
    /// to `extra` older ones near the prediction, closest first. Empty before any `push`.
    pub fn select(&self, predicted: &Isometry3<f64>) -> Vec<&DenseReference> {
        self.select_with_serials(predicted)
            .into_iter()
            .map(|(_, r)| r)
            .collect()
    }

    /// [`References::select`] with each reference's serial (the order it was pushed in,
    /// from 0: the tracker's pose-graph node).
    pub fn select_with_serials(&self, predicted: &Isometry3<f64>) -> Vec<(u64, &DenseReference)> {
        let Some(newest) = self.entries.last() else {
            return Vec::new();
        };
        let mut older: Vec<(f64, u64, &DenseReference)> = self
            .entries
            .iter()
            .filter(|e| e.serial + self.config.min_age as u64 <= newest.serial)
            .filter_map(|e| {
                self.score(predicted, &e.reference.pose)
                    .map(|s| (s, e.serial, &e.reference))
            })
            .collect();
        older.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        std::iter::once((newest.serial, &newest.reference))
            .chain(
                older
                    .into_iter()
                    .take(self.config.extra)
                    .map(|(_, serial, r)| (serial, r)),
            )
            .collect()
    }

    /// The references of the place `pose` looks at, whatever their age: up to `1 + extra`
    /// within `max_distance` and `max_angle` of it, closest first (the first is the primary
    /// one of [`crate::dense::align_many`]). The relocaliser's choice ([`crate::YawSearch`]):
    /// after a spin, the newest reference looks elsewhere. Empty when none is near.
    pub fn select_near(&self, pose: &Isometry3<f64>) -> Vec<(u64, &DenseReference)> {
        let mut near: Vec<(f64, u64, &DenseReference)> = self
            .entries
            .iter()
            .filter_map(|e| {
                self.score(pose, &e.reference.pose)
                    .map(|s| (s, e.serial, &e.reference))
            })
            .collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0).then(b.1.cmp(&a.1)));
        near.into_iter()
            .take(1 + self.config.extra)
            .map(|(_, serial, r)| (serial, r))
            .collect()
    }

    /// The serial the next [`References::push`] gives.
    pub fn next_serial(&self) -> u64 {
        self.next_serial
    }

    /// Replaces the pose of every kept reference for which `pose_of(serial)` gives one (the
    /// pose graph's corrected estimates).
    pub fn update_poses(&mut self, pose_of: impl Fn(u64) -> Option<Isometry3<f64>>) {
        for e in &mut self.entries {
            if let Some(p) = pose_of(e.serial) {
                e.reference.pose = p;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dense::DenseConfig;
    use crate::frame::Frame;
    use activemap_geometry::{Intrinsics, PlanarPose, camera_pose_from_planar};

    fn reference_at(x: f64, y: f64, yaw: f64) -> DenseReference {
        let k = Intrinsics::from_hfov(8, 8, std::f64::consts::FRAC_PI_2);
        let frame = Frame::new(k, vec![[0.5; 3]; 64], vec![2.0; 64], 0.0).unwrap();
        let pose = camera_pose_from_planar(&PlanarPose::new(x, y, yaw), 0.0, 1.0);
        DenseReference::new(&frame, pose, &DenseConfig::default())
    }

    fn pose(x: f64, y: f64, yaw: f64) -> Isometry3<f64> {
        camera_pose_from_planar(&PlanarPose::new(x, y, yaw), 0.0, 1.0)
    }

    #[test]
    fn selects_the_newest_then_old_references_of_the_same_place() {
        let mut set = References::new(ReferenceConfig::default()).unwrap();
        assert!(set.select(&pose(0.0, 0.0, 0.0)).is_empty());
        // A lap: out along x, back along x facing the other way, then the start again.
        let path = [
            (0.0, 0.0, 0.0),
            (0.3, 0.0, 0.0),
            (0.6, 0.0, 0.0),
            (0.9, 0.0, 0.0),
            (0.9, 0.0, 3.1),
            (0.5, 0.0, 3.1),
            (0.05, 0.0, 0.1),
        ];
        for (x, y, yaw) in path {
            set.push(reference_at(x, y, yaw));
        }
        let chosen = set.select(&pose(0.05, 0.0, 0.05));
        let xs: Vec<f64> = chosen.iter().map(|r| r.pose.translation.x).collect();
        // Newest (0.05), then the two closest old ones facing the same way: 0.0 and 0.3. The
        // ones facing back (yaw 3.1) are beyond the angle limit; 0.9 is beyond 0.75 m.
        assert_eq!(xs, vec![0.05, 0.0, 0.3]);
        // The references less than `min_age` older than the newest are never chosen.
        let chosen = set.select(&pose(0.9, 0.0, 3.1));
        let xs: Vec<f64> = chosen.iter().map(|r| r.pose.translation.x).collect();
        assert_eq!(xs, vec![0.05], "the yaw-3.1 references are too recent");
        // No extras asked: odometry.
        let odometry = References {
            config: ReferenceConfig {
                extra: 0,
                ..ReferenceConfig::default()
            },
            ..set.clone()
        };
        assert_eq!(odometry.select(&pose(0.05, 0.0, 0.05)).len(), 1);
    }

    #[test]
    fn over_capacity_the_younger_of_the_most_similar_pair_goes() {
        let config = ReferenceConfig {
            capacity: 5,
            min_age: 2,
            ..ReferenceConfig::default()
        };
        let mut set = References::new(config).unwrap();
        for (x, yaw) in [(0.0, 0.0), (1.0, 0.0), (0.02, 0.0), (2.0, 0.0), (3.0, 0.0)] {
            set.push(reference_at(x, 0.0, yaw));
        }
        assert_eq!(set.len(), 5);
        set.push(reference_at(4.0, 0.0, 0.0));
        let xs: Vec<f64> = set.poses().iter().map(|p| p.translation.x).collect();
        // 0.0 and 0.02 are the most similar pair: the younger (0.02) is dropped.
        assert_eq!(xs, vec![0.0, 1.0, 2.0, 3.0, 4.0]);
        // Nothing similar left (all 1 m apart, beyond 0.75 m): the oldest after the first goes,
        // never the two newest.
        set.push(reference_at(5.0, 0.0, 0.0));
        let xs: Vec<f64> = set.poses().iter().map(|p| p.translation.x).collect();
        assert_eq!(xs, vec![0.0, 2.0, 3.0, 4.0, 5.0]);
    }

    #[test]
    fn bad_settings_are_named() {
        let bad = ReferenceConfig {
            capacity: 2,
            min_age: 3,
            ..ReferenceConfig::default()
        };
        let err = References::new(bad).unwrap_err().to_string();
        assert!(err.contains("references.capacity"), "{err}");
        let bad = ReferenceConfig {
            max_distance: 0.0,
            ..ReferenceConfig::default()
        };
        let err = References::new(bad).unwrap_err().to_string();
        assert!(err.contains("references.max_distance"), "{err}");
    }
}
