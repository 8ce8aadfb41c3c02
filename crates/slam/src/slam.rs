//! The SLAM facade: one call per frame, shared by the tracker/mapper operators and the
//! benchmark. `process(frame, motion)` predicts the pose (previous pose, constant velocity,
//! or the commanded relative motion: never ground truth), tracks the frame against the map,
//! decides whether it is a keyframe and, if so, maps it.
//!
//! The first usable frame anchors the world at `SlamConfig::initial_pose` and becomes the
//! first keyframe. `Lost` frames keep the tracker's best pose and are not mapped (a frame the
//! map cannot explain must not corrupt it), except that after `remap_after_lost` consecutive
//! lost frames the frame is mapped at the tracker's pose so the system cannot stay lost
//! forever; `Skipped` frames take the prediction.

use crate::dense::DenseReference;
use crate::error::SlamError;
use crate::frame::Frame;
use crate::keyframe::{KeyframeConfig, KeyframeDecision, decide};
use crate::loss::Residuals;
use crate::mapper::{Mapper, MapperConfig, MappingReport};
use crate::references::{ReferenceConfig, References};
use crate::tracker::{TrackerConfig, TrackingStatus, track};
use crate::unknown::FrontierCell;
use activemap_geometry::Isometry3;
use activemap_splat::{Camera, FLAG_UNKNOWN_SPACE, Gaussians, RenderOptions, render};
use std::time::Instant;

/// All SLAM settings.
#[derive(Debug, Clone, PartialEq)]
pub struct SlamConfig {
    /// Tracking.
    pub tracker: TrackerConfig,
    /// Keyframe rule.
    pub keyframe: KeyframeConfig,
    /// Which keyframes the dense tracker aligns to (every keyframe becomes a reference).
    pub references: ReferenceConfig,
    /// Mapping.
    pub mapper: MapperConfig,
    /// Keyframes are stored and optimised at `1/mapping_downscale` resolution.
    pub mapping_downscale: usize,
    /// `T_world_camera` given to the first frame (the world is anchored there).
    pub initial_pose: Isometry3<f64>,
    /// After this many consecutive `Lost` frames the current frame is mapped anyway at the
    /// tracker's pose (the map is extended rather than staying lost forever); 0 = never.
    pub remap_after_lost: usize,
}

impl Default for SlamConfig {
    fn default() -> Self {
        Self {
            tracker: TrackerConfig::default(),
            keyframe: KeyframeConfig::default(),
            references: ReferenceConfig::default(),
            mapper: MapperConfig::default(),
            mapping_downscale: 1,
            initial_pose: Isometry3::identity(),
            remap_after_lost: 5,
        }
    }
}

/// The motion prediction that seeds tracking.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MotionPrior {
    /// Start from the previous pose.
    None,
    /// Repeat the last frame-to-frame motion.
    ConstantVelocity,
    /// The commanded motion of the camera since the previous frame, `T_prev_current` (camera
    /// frame), e.g. from the action sent to the robot. Not ground truth: collisions make it wrong.
    Relative(Isometry3<f64>),
}

/// What `process` returns for one frame.
#[derive(Debug, Clone)]
pub struct SlamOutput {
    /// Estimated `T_world_camera`.
    pub pose: Isometry3<f64>,
    /// Tracking status.
    pub status: TrackingStatus,
    /// Residuals behind the status.
    pub residuals: Residuals,
    /// Tracking iterations.
    pub iterations: usize,
    /// The keyframe decision (`None` for the first frame and for lost/skipped frames).
    pub keyframe: Option<KeyframeDecision>,
    /// Whether the frame became a keyframe and the map changed.
    pub map_updated: bool,
    /// Mapping summary when the map changed.
    pub mapping: Option<MappingReport>,
    /// Wall time of tracking, seconds.
    pub track_seconds: f64,
    /// Wall time of mapping, seconds (0 without a keyframe).
    pub map_seconds: f64,
}

/// State kept about the last keyframe for the keyframe rule.
#[derive(Debug, Clone)]
struct LastKeyframe {
    pose: Isometry3<f64>,
    median_depth: f64,
    visible_ids: Vec<u64>,
}

/// The SLAM system: tracker, keyframe rule and mapper behind one call.
#[derive(Debug, Clone)]
pub struct Slam {
    config: SlamConfig,
    mapper: Mapper,
    pose: Option<Isometry3<f64>>,
    velocity: Isometry3<f64>,
    exposure: [f64; 2],
    last_keyframe: Option<LastKeyframe>,
    /// The keyframes prepared as the dense tracker's references.
    references: References,
    frames_since_keyframe: usize,
    consecutive_lost: usize,
}

fn finite_pose(p: &Isometry3<f64>) -> bool {
    p.translation
        .vector
        .iter()
        .chain(p.rotation.coords.iter())
        .all(|v| v.is_finite())
}

impl Slam {
    /// A SLAM system with an empty map.
    pub fn new(config: SlamConfig) -> Result<Self, SlamError> {
        config.tracker.validate()?;
        if config.mapping_downscale == 0 {
            return Err(SlamError::Config {
                field: "mapping_downscale",
                value: "0".into(),
                reason: "must be ≥ 1",
            });
        }
        if !finite_pose(&config.initial_pose) {
            return Err(SlamError::Input {
                what: "initial_pose",
                reason: "not finite".into(),
            });
        }
        let mapper = Mapper::new(config.mapper.clone())?;
        let references = References::new(config.references.clone())?;
        Ok(Self {
            references,
            config,
            mapper,
            pose: None,
            velocity: Isometry3::identity(),
            exposure: [0.0, 0.0],
            last_keyframe: None,
            frames_since_keyframe: 0,
            consecutive_lost: 0,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &SlamConfig {
        &self.config
    }

    /// The map (unknown-space Gaussians included, flagged).
    pub fn map(&self) -> &Gaussians<f32> {
        self.mapper.map()
    }

    /// The mapper (keyframes, ids).
    pub fn mapper(&self) -> &Mapper {
        &self.mapper
    }

    /// The latest pose estimate, once a frame has been processed.
    pub fn pose(&self) -> Option<Isometry3<f64>> {
        self.pose
    }

    /// Adds unknown-space Gaussians above frontier cells (SPEC §5), for the planner side.
    pub fn seed_unknown_space(
        &mut self,
        cells: &[FrontierCell],
        seed: u64,
    ) -> Result<usize, SlamError> {
        self.mapper.seed_unknown_space(cells, seed)
    }

    fn predict(&self, motion: &MotionPrior) -> Result<Isometry3<f64>, SlamError> {
        let previous = self.pose.unwrap_or(self.config.initial_pose);
        let predicted = match motion {
            MotionPrior::None => previous,
            MotionPrior::ConstantVelocity => previous * self.velocity,
            MotionPrior::Relative(delta) => {
                if !finite_pose(delta) {
                    return Err(SlamError::Input {
                        what: "relative motion prior",
                        reason: "not finite".into(),
                    });
                }
                previous * delta
            }
        };
        Ok(predicted)
    }

    /// Processes one frame (see the module doc).
    pub fn process(&mut self, frame: &Frame, motion: MotionPrior) -> Result<SlamOutput, SlamError> {
        let predicted = self.predict(&motion)?;
        let track_frame = frame.downscale(self.config.tracker.downscale);
        if self.last_keyframe.is_none() {
            return self.bootstrap(frame, &track_frame, predicted);
        }
        let start = Instant::now();
        let references = self.references.select(&predicted);
        let tracked = track(
            &self.config.tracker,
            self.mapper.map(),
            &track_frame,
            &predicted,
            self.exposure,
            &references,
        )?;
        let track_seconds = start.elapsed().as_secs_f64();
        let mut output = SlamOutput {
            pose: tracked.pose,
            status: tracked.status,
            residuals: tracked.residuals,
            iterations: tracked.iterations,
            keyframe: None,
            map_updated: false,
            mapping: None,
            track_seconds,
            map_seconds: 0.0,
        };
        let previous = self.pose.unwrap_or(self.config.initial_pose);
        self.pose = Some(tracked.pose);
        self.frames_since_keyframe += 1;
        if tracked.status == TrackingStatus::Lost {
            self.consecutive_lost += 1;
            let remap = self.config.remap_after_lost;
            if remap > 0 && self.consecutive_lost >= remap {
                self.consecutive_lost = 0;
                let start = Instant::now();
                output.mapping = Some(self.make_keyframe(frame, &track_frame, tracked.pose)?);
                output.map_seconds = start.elapsed().as_secs_f64();
                output.map_updated = true;
            }
            return Ok(output);
        }
        if tracked.status != TrackingStatus::Ok {
            return Ok(output);
        }
        self.consecutive_lost = 0;
        self.velocity = previous.inverse() * tracked.pose;
        self.exposure = tracked.exposure;
        let last = self.last_keyframe.as_ref().expect("bootstrapped");
        let mut visible: Vec<u64> = self
            .mapper
            .ids()
            .iter()
            .zip(&tracked.visible)
            .filter(|(_, v)| **v)
            .map(|(id, _)| *id)
            .collect();
        visible.sort_unstable();
        let decision = decide(
            &self.config.keyframe,
            &tracked.pose,
            &last.pose,
            last.median_depth,
            &visible,
            &last.visible_ids,
            self.frames_since_keyframe,
        );
        output.keyframe = Some(decision);
        if decision.is_keyframe {
            let start = Instant::now();
            output.mapping = Some(self.make_keyframe(frame, &track_frame, tracked.pose)?);
            output.map_seconds = start.elapsed().as_secs_f64();
            output.map_updated = true;
        }
        Ok(output)
    }

    /// First usable frame: anchor the world and map it.
    fn bootstrap(
        &mut self,
        frame: &Frame,
        track_frame: &Frame,
        pose: Isometry3<f64>,
    ) -> Result<SlamOutput, SlamError> {
        let mut output = SlamOutput {
            pose,
            status: TrackingStatus::Ok,
            residuals: Residuals::default(),
            iterations: 0,
            keyframe: None,
            map_updated: false,
            mapping: None,
            track_seconds: 0.0,
            map_seconds: 0.0,
        };
        if let Err(reason) = frame.usability() {
            output.status = TrackingStatus::Skipped(reason);
            return Ok(output);
        }
        self.pose = Some(pose);
        let start = Instant::now();
        output.mapping = Some(self.make_keyframe(frame, track_frame, pose)?);
        output.map_seconds = start.elapsed().as_secs_f64();
        output.map_updated = true;
        Ok(output)
    }

    /// Maps a keyframe and records what the keyframe rule needs about it.
    fn make_keyframe(
        &mut self,
        frame: &Frame,
        track_frame: &Frame,
        pose: Isometry3<f64>,
    ) -> Result<MappingReport, SlamError> {
        let map_frame = frame.downscale(self.config.mapping_downscale);
        let median_depth = frame.median_depth().unwrap_or(1.0);
        let report = self.mapper.add_keyframe(map_frame, pose, self.exposure)?;
        let camera = Camera::from_world_pose(track_frame.intrinsics, &pose);
        let rendered = render(
            self.mapper.map(),
            &camera,
            &RenderOptions {
                exposure: self.exposure,
                exclude_flags: FLAG_UNKNOWN_SPACE,
            },
        )?;
        let mut visible_ids: Vec<u64> = self
            .mapper
            .ids()
            .iter()
            .zip(&rendered.context.visible)
            .filter(|(_, v)| **v)
            .map(|(id, _)| *id)
            .collect();
        visible_ids.sort_unstable();
        self.references.push(DenseReference::new(
            track_frame,
            pose,
            &self.config.tracker.dense,
        ));
        self.last_keyframe = Some(LastKeyframe {
            pose,
            median_depth,
            visible_ids,
        });
        self.frames_since_keyframe = 0;
        Ok(report)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::SkipReason;
    use activemap_geometry::Intrinsics;

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
        let mut slam = Slam::new(SlamConfig::default()).unwrap();
        // Before any map: a bad first frame is skipped and does not anchor anything.
        let out = slam
            .process(&frame([0.5; 3], 0.0), MotionPrior::None)
            .unwrap();
        assert_eq!(out.status, TrackingStatus::Skipped(SkipReason::NoDepth));
        assert!(slam.map().is_empty());
        let out = slam
            .process(&frame([0.6, 0.4, 0.2], 2.0), MotionPrior::None)
            .unwrap();
        assert!(out.map_updated && !slam.map().is_empty());
        let bad = [
            (frame([0.5; 3], 0.0), SkipReason::NoDepth),
            (frame([0.0; 3], 2.0), SkipReason::Black),
            (frame([f32::NAN; 3], f32::NAN), SkipReason::NonFinite),
        ];
        for (f, reason) in bad {
            let out = slam.process(&f, MotionPrior::ConstantVelocity).unwrap();
            assert_eq!(out.status, TrackingStatus::Skipped(reason));
            assert!(out.pose.translation.vector.iter().all(|v| v.is_finite()) && !out.map_updated);
        }
        // A frame the map cannot explain (the wall jumped from 2 m to 0.5 m, colours changed):
        // lost, finite pose, no mapping.
        let out = slam
            .process(&frame([0.1, 0.9, 0.9], 0.5), MotionPrior::None)
            .unwrap();
        assert_eq!(out.status, TrackingStatus::Lost, "{:?}", out.residuals);
        assert!(out.pose.translation.vector.iter().all(|v| v.is_finite()) && !out.map_updated);
        // A non-finite motion prior is an input error, not a NaN pose.
        let nan = Isometry3::translation(f64::NAN, 0.0, 0.0);
        assert!(
            slam.process(&frame([0.6, 0.4, 0.2], 2.0), MotionPrior::Relative(nan))
                .is_err()
        );
    }
}
