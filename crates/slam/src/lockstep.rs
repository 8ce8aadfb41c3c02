//! The in-process SLAM driver: a [`TrackingSession`] and a [`BackgroundMapper`] fed frame by
//! frame exactly as the `tracker` and `mapper` operators feed them in a lockstep run (same
//! types, same order of operations, same map lag), without any transport. The scripted loop and
//! `activemap bench slam` run SLAM through it, so their figures describe the pipeline's SLAM.
//!
//! Per frame k: the frame goes to both sessions; the mapper hands out the snapshots it has
//! finished (waiting for snapshot k − 1 − L, as the operator does once frame k has arrived);
//! the tracker tracks frame k against exactly that snapshot; its estimate goes back to the
//! mapper, whose worker maps it in the background while the next frames are tracked.
//!
//! ```no_run
//! use activemap_slam::{Frame, LockstepSlam, MotionPrior, SlamConfig};
//! # fn demo(frames: Vec<Frame>) -> Result<(), activemap_slam::SlamError> {
//! let mut slam = LockstepSlam::new(SlamConfig::default())?;
//! for frame in frames {
//!     let estimate = slam.process(frame, MotionPrior::ConstantVelocity)?;
//!     println!("{:?} {:?}", estimate.pose, estimate.status);
//! }
//! let (mapping, _events) = slam.finish()?;
//! println!("{} Gaussians, {} keyframes", mapping.map().len(), mapping.keyframes());
//! # Ok(()) }
//! ```

use std::sync::Arc;

use activemap_splat::Gaussians;

use crate::error::SlamError;
use crate::frame::Frame;
use crate::mapping::GraphLink;
use crate::mapping::{BackgroundMapper, KeyframeEvent, KeyframeMapper, MappingConfig};
use crate::session::{MotionPrior, TrackedFrame, TrackingConfig, TrackingSession};

/// Both sessions' settings; `map_lag` must be the same in both (as across the operators).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SlamConfig {
    /// The tracking session.
    pub tracking: TrackingConfig,
    /// The mapping session.
    pub mapping: MappingConfig,
}

impl SlamConfig {
    /// Sets the map lag of both sessions.
    pub fn with_map_lag(mut self, lag: u64) -> Self {
        self.tracking.map_lag = lag;
        self.mapping.map_lag = lag;
        self
    }
}

/// The in-process lockstep driver (see the module doc).
pub struct LockstepSlam {
    tracking: TrackingSession,
    mapping: BackgroundMapper,
    next: u64,
    newest_map: Arc<Gaussians<f32>>,
    keyframes: Vec<(u64, KeyframeEvent)>,
}

impl LockstepSlam {
    /// Both sessions with an empty map; the mapping worker starts.
    pub fn new(config: SlamConfig) -> Result<Self, SlamError> {
        if config.tracking.map_lag != config.mapping.map_lag {
            return Err(SlamError::Config {
                field: "map_lag",
                value: format!(
                    "tracking {} vs mapping {}",
                    config.tracking.map_lag, config.mapping.map_lag
                ),
                reason: "the tracker and the mapper must use the same map lag",
            });
        }
        Ok(Self {
            tracking: TrackingSession::new(config.tracking)?,
            mapping: BackgroundMapper::new(config.mapping)?,
            next: 0,
            newest_map: Arc::new(Gaussians::new()),
            keyframes: Vec::new(),
        })
    }

    /// The tracking session.
    pub fn tracking(&self) -> &TrackingSession {
        &self.tracking
    }

    /// The newest map snapshot handed out so far (it lags the frames by up to L + 1).
    pub fn newest_map(&self) -> &Arc<Gaussians<f32>> {
        &self.newest_map
    }

    /// The keyframes mapped so far, with the frame each came from.
    pub fn keyframe_events(&self) -> &[(u64, KeyframeEvent)] {
        &self.keyframes
    }

    /// Tracks the next frame, taken after `motion` from the previous one (ignored for the
    /// first), and hands it to the mapper; returns its estimate.
    pub fn process(
        &mut self,
        frame: Frame,
        motion: MotionPrior,
    ) -> Result<TrackedFrame, SlamError> {
        let k = self.next;
        if k > 0 {
            self.tracking.add_motion(k - 1, motion);
        }
        self.tracking.add_frame(k, frame.clone());
        self.mapping.add_frame(k, frame);
        loop {
            for s in self.mapping.process_ready(false)? {
                if let Some(event) = s.keyframe {
                    self.keyframes.push((s.frame_id, event));
                }
                self.newest_map = s.map.clone();
                self.tracking.add_map(s.frame_id, s.map);
            }
            if let Some(estimate) = self.tracking.process_ready()?.pop() {
                self.mapping.add_pose(
                    estimate.frame_id,
                    estimate.stamp,
                    estimate.pose,
                    estimate.status.into(),
                    GraphLink::of(&estimate),
                );
                self.next += 1;
                return Ok(estimate);
            }
        }
    }

    /// Maps every frame processed so far, stops the worker and returns the mapping session's
    /// final state (map and keyframes) with every keyframe event of the run.
    #[allow(clippy::type_complexity)]
    pub fn finish(mut self) -> Result<(KeyframeMapper, Vec<(u64, KeyframeEvent)>), SlamError> {
        for s in self.mapping.process_ready(true)? {
            if let Some(event) = s.keyframe {
                self.keyframes.push((s.frame_id, event));
            }
        }
        Ok((self.mapping.finish()?, self.keyframes))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::SkipReason;
    use crate::tracker::TrackingStatus;
    use activemap_geometry::{Intrinsics, Isometry3};

    fn frame(rgb: [f32; 3], depth: f32) -> Frame {
        let k = Intrinsics::from_hfov(24, 24, std::f64::consts::FRAC_PI_2);
        let rgb: Vec<[f32; 3]> = (0..576)
            .map(|i| {
                if (i / 3 + i / 72) % 2 == 0 {
                    rgb
                } else {
                    rgb.map(|c| c * 0.5)
                }
            })
            .collect();
        Frame::new(k, rgb, vec![depth; 576], 0.0).unwrap()
    }

    #[test]
    fn bad_frames_are_skipped_or_lost_never_nan() {
        let mut slam = LockstepSlam::new(SlamConfig::default()).unwrap();
        // Before any map: a bad first frame is skipped and does not anchor anything.
        let out = slam
            .process(frame([0.5; 3], 0.0), MotionPrior::None)
            .unwrap();
        assert_eq!(out.status, TrackingStatus::Skipped(SkipReason::NoDepth));
        let out = slam
            .process(frame([0.6, 0.4, 0.2], 2.0), MotionPrior::None)
            .unwrap();
        assert_eq!(out.status, TrackingStatus::Ok);
        let bad = [
            (frame([0.5; 3], 0.0), SkipReason::NoDepth),
            (frame([0.0; 3], 2.0), SkipReason::Black),
            (frame([f32::NAN; 3], f32::NAN), SkipReason::NonFinite),
        ];
        for (f, reason) in bad {
            let out = slam.process(f, MotionPrior::ConstantVelocity).unwrap();
            assert_eq!(out.status, TrackingStatus::Skipped(reason));
            assert!(out.pose.translation.vector.iter().all(|v| v.is_finite()));
        }
        assert!(!slam.newest_map().is_empty(), "the good frame was mapped");
        assert_eq!(slam.keyframe_events().len(), 1);
        // A frame the map cannot explain (the wall jumped from 2 m to 0.5 m, colours changed):
        // lost, finite pose.
        let out = slam
            .process(frame([0.1, 0.9, 0.9], 0.5), MotionPrior::None)
            .unwrap();
        assert!(out.status.is_lost(), "{:?} {:?}", out.status, out.residuals);
        assert!(out.pose.translation.vector.iter().all(|v| v.is_finite()));
        // A non-finite motion prior is an input error, not a NaN pose.
        let nan = Isometry3::translation(f64::NAN, 0.0, 0.0);
        assert!(
            slam.process(frame([0.6, 0.4, 0.2], 2.0), MotionPrior::Relative(nan))
                .is_err()
        );
    }

    /// Lost frames are not mapped, but `remap_after_lost` lost frames in a row map the last
    /// one, so SLAM cannot stay lost forever where the map has a hole; a frame the map
    /// contradicts at the estimate (a wall 0.5 m away where the map has one at 2 m: a covered
    /// lens, a spin the tracker was not told of) is never mapped, however long the run.
    #[test]
    fn lost_frames_are_mapped_after_remap_after_lost_unless_the_map_contradicts_them() {
        let mut config = SlamConfig::default();
        config.mapping.remap_after_lost = 3;
        // The map's hole: the camera turned 180° (commanded), facing what neither the map nor
        // the reference keyframe shows.
        let half_turn = Isometry3::rotation(nalgebra::Vector3::y() * std::f64::consts::PI);
        let cases = [
            ("contradicted", MotionPrior::None, "depth_residual", 1),
            ("hole", MotionPrior::Relative(half_turn), "low_overlap", 2),
        ];
        for (case, first_prior, reason, keyframes) in cases {
            let mut slam = LockstepSlam::new(config.clone()).unwrap();
            slam.process(frame([0.6, 0.4, 0.2], 2.0), MotionPrior::None)
                .unwrap();
            for i in 0..3 {
                let prior = if i == 0 {
                    first_prior
                } else {
                    MotionPrior::None
                };
                let out = slam.process(frame([0.1, 0.9, 0.9], 0.5), prior).unwrap();
                let TrackingStatus::Lost(r) = out.status else {
                    panic!("{case}: frame {i} tracked: {out:?}");
                };
                assert_eq!(r.key(), reason, "{case}: frame {i}");
            }
            let (mapping, _) = slam.finish().unwrap();
            assert_eq!(mapping.keyframes(), keyframes, "{case}");
        }
    }

    #[test]
    fn mismatched_map_lags_are_a_config_error() {
        let mut config = SlamConfig::default();
        config.tracking.map_lag = 2;
        let err = LockstepSlam::new(config).err().expect("refused");
        assert!(err.to_string().contains("map_lag"), "{err}");
    }
}
