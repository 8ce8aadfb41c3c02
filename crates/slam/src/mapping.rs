//! The mapping session (SPEC §4): the keyframe rule and the Gaussian mapper, run frame by
//! frame in a background worker with a fixed map lag. The `mapper` operator holds a
//! [`BackgroundMapper`] and only wires messages; the in-process driver
//! [`crate::lockstep::LockstepSlam`] holds the very same type.
//!
//! Each frame is paired with the tracker's estimate of the same frame and goes, in order, to a
//! worker thread that decides keyframes ([`KeyframeMapper`]) and optimises the map while the
//! loop goes on. After each frame j the worker hands back the snapshot "every frame ≤ j
//! mapped" ([`Snapshot`]). The consumers (tracker, occupancy) use, for frame k, exactly the
//! snapshot of frame [`required_snapshot`]`(k, L)` = k − 1 − L, so a run stays deterministic
//! (the snapshot's content depends only on frames ≤ k − 1 − L, never on timing) while mapping
//! overlaps the next L + 1 steps. When frame k has arrived, [`BackgroundMapper::process_ready`]
//! waits until snapshot k − 1 − L is out, which is what the loop waits for anyway.
//!
//! Lost frames are not mapped (a frame the map cannot explain must not corrupt it), except
//! that after `remap_after_lost` consecutive lost frames the frame is mapped at the tracker's
//! pose, so the system cannot stay lost forever where the map has a hole; never a frame the
//! map contradicts at that pose ([`PoseQuality::Contradicted`]: a covered lens, a spin the
//! tracker was not told of).
//!
//! With the tracker's pose graph, each frame's estimate names the graph keyframe it hangs on
//! and may bring corrections ([`GraphLink`]); the worker applies them before mapping that
//! frame: each mapper keyframe moves with the graph keyframe its frame hung on
//! ([`keyframe_moves`]), and its Gaussians with it ([`Mapper::move_keyframes`]). Being part of
//! the frame's job, the corrections keep the snapshots deterministic.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, Sender, TryRecvError, channel};
use std::thread::JoinHandle;
use std::time::Instant;

use activemap_geometry::Isometry3;
use activemap_splat::{Camera, FLAG_UNKNOWN_SPACE, Gaussians, RenderOptions, render};

use crate::error::SlamError;
use crate::frame::Frame;
use crate::keyframe::{KeyframeConfig, decide};
use crate::keyframe_graph::KeyframeCorrection;
use crate::mapper::{Mapper, MapperConfig, MappingReport};
use crate::session::required_snapshot;
use crate::tracker::LostReason;
use crate::tracker::{TrackerConfig, TrackingStatus};

/// Settings of the mapping session.
#[derive(Debug, Clone, PartialEq)]
pub struct MappingConfig {
    /// The window optimisation, insertion, pruning and densification.
    pub mapper: MapperConfig,
    /// The keyframe rule.
    pub keyframe: KeyframeConfig,
    /// Keyframes are stored and optimised at `1/downscale` resolution (1 = full).
    pub downscale: usize,
    /// The co-visibility of the keyframe rule is rendered at `1/visibility_downscale`.
    pub visibility_downscale: usize,
    /// After this many consecutive `Lost` frames the current one is mapped anyway at the
    /// tracker's pose; 0 = never.
    pub remap_after_lost: usize,
    /// Map lag L in frames (see the module doc); must equal the tracker's and the occupancy's.
    pub map_lag: u64,
}

impl Default for MappingConfig {
    fn default() -> Self {
        Self {
            mapper: MapperConfig::default(),
            keyframe: KeyframeConfig::default(),
            downscale: 1,
            visibility_downscale: TrackerConfig::default().downscale,
            remap_after_lost: 5,
            map_lag: 0,
        }
    }
}

impl MappingConfig {
    /// Checks ranges; names the offending field.
    pub fn validate(&self) -> Result<(), SlamError> {
        self.mapper.validate()?;
        let k = &self.keyframe;
        if !(1..=k.max_interval).contains(&k.min_interval) {
            return Err(SlamError::Config {
                field: "keyframe.min_interval",
                value: k.min_interval.to_string(),
                reason: "must be in 1..=keyframe.max_interval",
            });
        }
        for (field, v) in [
            ("downscale", self.downscale),
            ("visibility_downscale", self.visibility_downscale),
        ] {
            if v == 0 {
                return Err(SlamError::Config {
                    field,
                    value: "0".into(),
                    reason: "must be ≥ 1",
                });
            }
        }
        Ok(())
    }
}

/// How the tracker judged the pose a frame is mapped at (all the mapper needs of its status).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PoseQuality {
    /// Tracked: the map explains the frame.
    Ok,
    /// Lost where the map may simply not reach: too little overlap, a solution the motion
    /// check rejected, a non-finite one. Mapped after `remap_after_lost` in a row.
    Lost,
    /// Lost because the map or the references contradict the frame at the estimate (its depth
    /// or colour residual): the estimate is a guess the map disagrees with (a spin the tracker
    /// was not told of, a covered lens), so the frame is never mapped.
    Contradicted,
    /// Skipped: the frame was unusable (black, saturated, no depth, NaN colour).
    Skipped,
}

impl From<TrackingStatus> for PoseQuality {
    fn from(s: TrackingStatus) -> Self {
        match s {
            TrackingStatus::Ok => Self::Ok,
            TrackingStatus::Lost(reason) => Self::of_lost(&reason),
            TrackingStatus::Skipped(_) => Self::Skipped,
        }
    }
}

impl PoseQuality {
    /// The quality of a frame lost for `reason`: [`PoseQuality::Contradicted`] for a depth or
    /// colour residual, [`PoseQuality::Lost`] otherwise.
    pub fn of_lost(reason: &LostReason) -> Self {
        match reason {
            LostReason::DepthResidual { .. } | LostReason::ColourResidual { .. } => {
                Self::Contradicted
            }
            LostReason::LowOverlap { .. }
            | LostReason::MotionMismatch { .. }
            | LostReason::NonFinite => Self::Lost,
        }
    }
}

/// What the keyframe rule needs to remember of the last keyframe.
#[derive(Debug, Clone)]
struct LastKeyframe {
    pose: Isometry3<f64>,
    median_depth: f64,
    visible: Vec<u64>,
}

/// The keyframe rule and the Gaussian mapper, frame by frame (what the worker thread runs).
#[derive(Debug)]
pub struct KeyframeMapper {
    config: MappingConfig,
    mapper: Mapper,
    last: Option<LastKeyframe>,
    frames_since: usize,
    consecutive_lost: usize,
    /// Per mapper keyframe: the graph keyframe its frame hung on ([`GraphLink::anchor`]).
    keyframe_anchors: Vec<Option<u64>>,
    keyframes: usize,
}

impl KeyframeMapper {
    /// An empty map.
    pub fn new(config: MappingConfig) -> Result<Self, SlamError> {
        config.validate()?;
        Ok(Self {
            mapper: Mapper::new(config.mapper.clone())?,
            config,
            last: None,
            frames_since: 0,
            consecutive_lost: 0,
            keyframe_anchors: Vec::new(),
            keyframes: 0,
        })
    }

    /// Applies the tracker's pose-graph corrections (see the module doc): every keyframe, the
    /// keyframe rule's last pose and the anchored Gaussians move. Returns the number of
    /// Gaussians moved; fails, changing nothing, on corrections out of frame order or not
    /// finite.
    pub fn apply_corrections(
        &mut self,
        corrections: &[KeyframeCorrection],
    ) -> Result<usize, SlamError> {
        if corrections.is_empty() {
            return Ok(0);
        }
        let moves = keyframe_moves(&self.keyframe_anchors, corrections)?;
        let moved = self.mapper.move_keyframes(&moves)?;
        if let (Some(last), Some(m)) = (&mut self.last, moves.last()) {
            last.pose = activemap_geometry::se3::normalized(&(m * last.pose));
        }
        Ok(moved)
    }

    /// The settings.
    pub fn config(&self) -> &MappingConfig {
        &self.config
    }

    /// The current map.
    pub fn map(&self) -> &Gaussians<f32> {
        self.mapper.map()
    }

    /// The underlying mapper (keyframes, ids).
    pub fn mapper(&self) -> &Mapper {
        &self.mapper
    }

    /// Keyframes mapped so far.
    pub fn keyframes(&self) -> usize {
        self.keyframes
    }

    /// Ids of the map Gaussians visible from `pose` (unknown-space ones excluded), sorted.
    fn visible_ids(&self, frame: &Frame, pose: &Isometry3<f64>) -> Result<Vec<u64>, SlamError> {
        let small = frame.downscale(self.config.visibility_downscale);
        let camera = Camera::from_world_pose(small.intrinsics, pose);
        let options = RenderOptions {
            exposure: [0.0, 0.0],
            exclude_flags: FLAG_UNKNOWN_SPACE,
            ..Default::default()
        };
        let rendered = render(self.mapper.map(), &camera, &options)?;
        let mut ids: Vec<u64> = self
            .mapper
            .ids()
            .iter()
            .zip(&rendered.context.visible)
            .filter(|(_, v)| **v)
            .map(|(id, _)| *id)
            .collect();
        ids.sort_unstable();
        Ok(ids)
    }

    /// Maps one frame at its estimate when it is a keyframe (see the module doc); returns what
    /// the mapping did, `None` when the map is unchanged. `graph_anchor`: the graph keyframe
    /// the frame's estimate hangs on ([`GraphLink::anchor`]; `None` without a pose graph).
    pub fn process(
        &mut self,
        graph_anchor: Option<u64>,
        frame: Frame,
        pose: &Isometry3<f64>,
        quality: PoseQuality,
    ) -> Result<Option<MappingReport>, SlamError> {
        self.frames_since += 1;
        let is_keyframe = match quality {
            PoseQuality::Skipped => false,
            PoseQuality::Contradicted => {
                self.consecutive_lost += 1;
                false
            }
            PoseQuality::Lost => {
                self.consecutive_lost += 1;
                let remap = self.config.remap_after_lost;
                remap > 0 && self.consecutive_lost >= remap && frame.usability().is_ok()
            }
            PoseQuality::Ok => {
                self.consecutive_lost = 0;
                match &self.last {
                    None => frame.usability().is_ok(),
                    Some(last) => {
                        let visible = self.visible_ids(&frame, pose)?;
                        decide(
                            &self.config.keyframe,
                            pose,
                            &last.pose,
                            last.median_depth,
                            &visible,
                            &last.visible,
                            self.frames_since,
                        )
                        .is_keyframe
                    }
                }
            }
        };
        if !is_keyframe {
            return Ok(None);
        }
        self.consecutive_lost = 0;
        let median_depth = frame.median_depth().unwrap_or(1.0);
        let map_frame = frame.downscale(self.config.downscale);
        let report = self.mapper.add_keyframe(map_frame, *pose, [0.0, 0.0])?;
        let visible = self.visible_ids(&frame, pose)?;
        self.last = Some(LastKeyframe {
            pose: *pose,
            median_depth,
            visible,
        });
        self.frames_since = 0;
        self.keyframes += 1;
        self.keyframe_anchors.push(graph_anchor);
        Ok(Some(report))
    }
}

/// What the tracker's pose graph tells the mapper with a frame's estimate.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GraphLink {
    /// The graph keyframe (by frame) the estimate hangs on: the newest one when the frame was
    /// tracked ([`crate::TrackedFrame::graph_anchor`]). `None` without a pose graph.
    pub anchor: Option<u64>,
    /// The graph keyframes moved since the mapper last heard of them, in frame order
    /// ([`crate::LoopClosure::corrections`]); applied before the frame is mapped.
    pub corrections: Vec<KeyframeCorrection>,
}

impl GraphLink {
    /// The link of a tracked frame.
    pub fn of(tracked: &crate::TrackedFrame) -> Self {
        Self {
            anchor: tracked.graph_anchor,
            corrections: tracked
                .loop_closure
                .as_ref()
                .map(|c| c.corrections.clone())
                .unwrap_or_default(),
        }
    }
}

/// The world-frame move of each mapper keyframe under the pose-graph `corrections`
/// (increasing frame ids): the correction of the graph keyframe its frame hung on
/// (`keyframe_anchors`, in keyframe order), the identity when that one did not move or there
/// is none. Fails on corrections out of order or not finite, naming the frame.
pub fn keyframe_moves(
    keyframe_anchors: &[Option<u64>],
    corrections: &[KeyframeCorrection],
) -> Result<Vec<Isometry3<f64>>, SlamError> {
    for (k, c) in corrections.iter().enumerate() {
        if k > 0 && c.frame_id <= corrections[k - 1].frame_id {
            return Err(SlamError::Input {
                what: "keyframe corrections",
                reason: format!(
                    "frame {} follows frame {}: not in increasing frame order",
                    c.frame_id,
                    corrections[k - 1].frame_id
                ),
            });
        }
        if !crate::session::finite_pose(&c.correction) {
            return Err(SlamError::Input {
                what: "keyframe corrections",
                reason: format!("the correction of frame {} is not finite", c.frame_id),
            });
        }
    }
    Ok(keyframe_anchors
        .iter()
        .map(|anchor| {
            anchor
                .and_then(|a| corrections.binary_search_by_key(&a, |c| c.frame_id).ok())
                .map_or(Isometry3::identity(), |i| corrections[i].correction)
        })
        .collect())
}

/// What mapping one frame did, when it was a keyframe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyframeEvent {
    /// The keyframe's number (1 = the first).
    pub keyframe: usize,
    /// The mapper's summary.
    pub report: MappingReport,
    /// Wall time of mapping it, seconds (reporting only).
    pub seconds: f64,
}

/// The map after every frame ≤ `frame_id` was mapped.
#[derive(Debug, Clone)]
pub struct Snapshot {
    /// The last frame the snapshot includes.
    pub frame_id: u64,
    /// That frame's timestamp.
    pub stamp: f64,
    /// The map (shared between snapshots while no keyframe changes it).
    pub map: Arc<Gaussians<f32>>,
    /// The stable id of each Gaussian of `map` (parallel to it; [`Mapper::ids`]: increasing
    /// as Gaussians are added, surviving pruning), shared like `map`.
    pub ids: Arc<Vec<u64>>,
    /// Set when frame `frame_id` became a keyframe.
    pub keyframe: Option<KeyframeEvent>,
    /// Gaussians moved by the pose-graph corrections that came with frame `frame_id` (0: the
    /// corrections, if any, moved nothing). Like a keyframe, a non-zero count means the map
    /// changed at this snapshot.
    pub corrected: usize,
}

struct Job {
    frame_id: u64,
    link: GraphLink,
    stamp: f64,
    frame: Frame,
    pose: Isometry3<f64>,
    quality: PoseQuality,
}

/// The background mapping thread: frames in, snapshots out, both in frame order.
struct Worker {
    jobs: Option<Sender<Job>>,
    snapshots: Receiver<Result<Snapshot, SlamError>>,
    handle: Option<JoinHandle<KeyframeMapper>>,
}

impl Worker {
    fn spawn(mut core: KeyframeMapper) -> Result<Self, SlamError> {
        let (job_tx, job_rx) = channel::<Job>();
        let (snap_tx, snap_rx) = channel();
        let handle = std::thread::Builder::new()
            .name("mapper-worker".into())
            .spawn(move || {
                let mut current = Arc::new(core.map().clone());
                let mut current_ids = Arc::new(core.mapper().ids().to_vec());
                while let Ok(job) = job_rx.recv() {
                    let started = Instant::now();
                    let mut corrected = 0;
                    let result = core
                        .apply_corrections(&job.link.corrections)
                        .and_then(|moved| {
                            corrected = moved;
                            core.process(job.link.anchor, job.frame, &job.pose, job.quality)
                        })
                        .map(|report| {
                            // One copy of the map per change, made by the corrections, the
                            // keyframe or both.
                            if corrected > 0 || report.is_some() {
                                current = Arc::new(core.map().clone());
                            }
                            let keyframe = report.map(|report| {
                                current_ids = Arc::new(core.mapper().ids().to_vec());
                                KeyframeEvent {
                                    keyframe: core.keyframes(),
                                    report,
                                    seconds: started.elapsed().as_secs_f64(),
                                }
                            });
                            Snapshot {
                                frame_id: job.frame_id,
                                stamp: job.stamp,
                                map: current.clone(),
                                ids: current_ids.clone(),
                                keyframe,
                                corrected,
                            }
                        });
                    let failed = result.is_err();
                    if snap_tx.send(result).is_err() || failed {
                        break;
                    }
                }
                core
            })
            .map_err(|e| SlamError::Input {
                what: "mapping worker",
                reason: format!("cannot start the thread: {e}"),
            })?;
        Ok(Self {
            jobs: Some(job_tx),
            snapshots: snap_rx,
            handle: Some(handle),
        })
    }

    fn stopped() -> SlamError {
        SlamError::Input {
            what: "mapping worker",
            reason: "the worker thread stopped unexpectedly".into(),
        }
    }

    fn submit(&self, job: Job) -> Result<(), SlamError> {
        self.jobs
            .as_ref()
            .and_then(|tx| tx.send(job).ok())
            .ok_or_else(Self::stopped)
    }

    /// The next finished snapshot; waits for it when `block`.
    fn next(&self, block: bool) -> Result<Option<Snapshot>, SlamError> {
        let got = if block {
            self.snapshots
                .recv()
                .map_err(|_| TryRecvError::Disconnected)
        } else {
            self.snapshots.try_recv()
        };
        match got {
            Ok(result) => result.map(Some),
            Err(TryRecvError::Empty) => Ok(None),
            Err(TryRecvError::Disconnected) => Err(Self::stopped()),
        }
    }

    /// Stops the thread after the submitted jobs and returns its mapper.
    fn finish(mut self) -> Result<KeyframeMapper, SlamError> {
        self.jobs = None;
        let handle = self.handle.take().expect("joined once");
        handle.join().map_err(|_| SlamError::Input {
            what: "mapping worker",
            reason: "the worker thread panicked".into(),
        })
    }
}

impl Drop for Worker {
    fn drop(&mut self) {
        self.jobs = None;
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// A frame's estimate as the mapping session stores it until the frame is submitted.
struct PoseEntry {
    stamp: f64,
    pose: Isometry3<f64>,
    quality: PoseQuality,
    link: GraphLink,
}

/// The mapping session (see the module doc): pairs frames with their estimates, feeds the
/// worker in frame order and hands out the snapshots it finishes.
pub struct BackgroundMapper {
    lag: u64,
    worker: Worker,
    frames: BTreeMap<u64, Frame>,
    poses: BTreeMap<u64, PoseEntry>,
    next_submit: u64,
    /// Newest frame id seen.
    newest_frame: Option<u64>,
    /// Frames handed out as snapshots so far (the next snapshot is of frame `published`).
    published: u64,
}

impl BackgroundMapper {
    /// An empty map and a running worker.
    pub fn new(config: MappingConfig) -> Result<Self, SlamError> {
        let lag = config.map_lag;
        Ok(Self {
            lag,
            worker: Worker::spawn(KeyframeMapper::new(config)?)?,
            frames: BTreeMap::new(),
            poses: BTreeMap::new(),
            next_submit: 0,
            newest_frame: None,
            published: 0,
        })
    }

    /// Stores an RGB-D frame.
    pub fn add_frame(&mut self, frame_id: u64, frame: Frame) {
        self.newest_frame = Some(self.newest_frame.map_or(frame_id, |n| n.max(frame_id)));
        self.frames.insert(frame_id, frame);
    }

    /// Stores the tracker's estimate of frame `frame_id` (taken at `stamp`) with what its pose
    /// graph said ([`GraphLink`]; the default without a graph).
    pub fn add_pose(
        &mut self,
        frame_id: u64,
        stamp: f64,
        pose: Isometry3<f64>,
        quality: PoseQuality,
        link: GraphLink,
    ) {
        self.poses.insert(
            frame_id,
            PoseEntry {
                stamp,
                pose,
                quality,
                link,
            },
        );
    }

    /// Hands every frame whose estimate has arrived to the worker (in order), then returns the
    /// snapshots finished so far. It waits for the worker only as far as the loop needs: the
    /// snapshot of frame k − 1 − L once frame k arrived (or every submitted frame when `drain`).
    pub fn process_ready(&mut self, drain: bool) -> Result<Vec<Snapshot>, SlamError> {
        while self.frames.contains_key(&self.next_submit)
            && self.poses.contains_key(&self.next_submit)
        {
            let k = self.next_submit;
            let frame = self.frames.remove(&k).expect("present");
            let entry = self.poses.remove(&k).expect("present");
            self.worker.submit(Job {
                frame_id: k,
                link: entry.link,
                stamp: entry.stamp,
                frame,
                pose: entry.pose,
                quality: entry.quality,
            })?;
            self.next_submit += 1;
        }
        let needed = self
            .newest_frame
            .map(|k| required_snapshot(k, self.lag) + 1)
            .unwrap_or(0);
        let wait_until = if drain {
            self.next_submit
        } else {
            needed.min(self.next_submit)
        };
        let mut out = Vec::new();
        loop {
            let block = self.published < wait_until;
            match self.worker.next(block)? {
                Some(s) => {
                    self.published = s.frame_id + 1;
                    out.push(s);
                }
                None => break,
            }
        }
        Ok(out)
    }

    /// Maps what was submitted, stops the worker and returns the keyframe mapper (the final
    /// map and keyframes, for evaluation). Snapshots not yet collected are dropped.
    pub fn finish(self) -> Result<KeyframeMapper, SlamError> {
        self.worker.finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Translation3;

    fn correction(frame_id: u64, x: f64) -> KeyframeCorrection {
        KeyframeCorrection {
            frame_id,
            correction: Isometry3::from_parts(Translation3::new(x, 0.0, 0.0), Default::default()),
        }
    }

    /// Each mapper keyframe takes the correction of the graph keyframe its frame hung on; one
    /// whose graph keyframe did not move, or without a graph, stays. Corrections out of frame
    /// order, or not finite, are refused.
    #[test]
    fn each_keyframe_follows_the_graph_keyframe_it_hung_on() {
        let corrections = [correction(2, 0.1), correction(7, 0.2), correction(9, 0.3)];
        let anchors = [None, Some(0), Some(2), Some(2), Some(5), Some(7), Some(9)];
        let moves = keyframe_moves(&anchors, &corrections).unwrap();
        let x: Vec<f64> = moves.iter().map(|m| m.translation.x).collect();
        assert_eq!(x, [0.0, 0.0, 0.1, 0.1, 0.0, 0.2, 0.3]);
        assert!(keyframe_moves(&[], &corrections).unwrap().is_empty());
        let swapped = [correction(7, 0.2), correction(2, 0.1)];
        let e = keyframe_moves(&[Some(2)], &swapped)
            .unwrap_err()
            .to_string();
        assert!(e.contains("frame 2 follows frame 7"), "{e}");
        let nan = [correction(2, f64::NAN)];
        let e = keyframe_moves(&[Some(2)], &nan).unwrap_err().to_string();
        assert!(e.contains("frame 2"), "{e}");
    }
}
