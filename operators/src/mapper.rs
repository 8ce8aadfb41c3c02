//! `mapper`: Gaussian-splatting mapping on keyframes (SPEC §4), wrapping
//! `activemap_slam::Mapper` and the keyframe rule. Each frame is paired with the tracker's
//! estimate of the same frame; lost frames are never mapped.
//!
//! Background mapping with a fixed map lag: the frames go, in order, to a worker thread that
//! decides keyframes and optimises the map while the loop goes on. After each frame j the worker
//! hands back the map snapshot "every frame ≤ j mapped", which goes out tagged with frame id j
//! (shared memory). The consumers (tracker, occupancy) use, for frame k, exactly the snapshot of
//! frame [`required_snapshot`]`(k, L)` = k − 1 − L, so a run stays deterministic (the snapshot's
//! content depends only on frames ≤ k − 1 − L, never on timing) while mapping overlaps the next
//! L + 1 steps. The mapper's own `map_lag` must equal the consumers': when frame k arrives it
//! waits (blocks) until snapshot k − 1 − L is out, which is what the loop waits for anyway; a
//! `timers:` entry (any name) additionally publishes finished snapshots as soon as they exist.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, Sender, TryRecvError, channel};
use std::thread::JoinHandle;

use activemap_geometry::Isometry3;
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, PortSpec, check_config_as,
};
use activemap_schemas::{MessageKind as K, PoseEstimate, RgbdFrameView, TrackingStatus};
use activemap_slam::{
    Frame, KeyframeConfig, Mapper as SlamMapper, MapperConfig, MappingReport, TrackerConfig,
    keyframe::decide,
};
use activemap_splat::{Camera, FLAG_UNKNOWN_SPACE, Gaussians, RenderOptions, render};

use crate::Registered;
use crate::convert::{map_header, pose_from_wire, slam_frame, write_map};

/// Config.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// Optimisation iterations per keyframe (library default when absent).
    #[serde(default)]
    pub iterations: Option<usize>,
    /// Keyframes in the optimisation window (library default when absent).
    #[serde(default)]
    pub window: Option<usize>,
    /// Map lag L in frames: the consumers use the snapshot of frame k − 1 − L for frame k, so
    /// mapping may run up to L + 1 frames behind the loop. Must equal the tracker's and the
    /// occupancy's `map_lag`.
    #[serde(default)]
    pub map_lag: u64,
    /// Fewest frames between keyframes (library default when absent). Fewer keyframes cut
    /// the mapping work per step; the occupancy grid stays current through each frame's depth.
    #[serde(default)]
    pub keyframe_min_interval: Option<usize>,
}

/// The map snapshot frame `k` is tracked and gridded against under map lag `lag`:
/// k − 1 − L, clamped at frame 0 (the first frames all use the first snapshot).
pub fn required_snapshot(k: u64, lag: u64) -> u64 {
    k.saturating_sub(1 + lag)
}

struct LastKeyframe {
    pose: Isometry3<f64>,
    median_depth: f64,
    visible: Vec<u64>,
}

/// The keyframe rule and the Gaussian mapper: what the worker thread runs, frame by frame.
pub struct MapperCore {
    mapper: SlamMapper,
    keyframe: KeyframeConfig,
    visibility_downscale: usize,
    last: Option<LastKeyframe>,
    frames_since: usize,
    /// Keyframes mapped so far.
    pub keyframes: usize,
    /// What the last keyframe's mapping did.
    pub last_report: Option<MappingReport>,
}

impl MapperCore {
    /// An empty map.
    pub fn from_config(config: &Config) -> anyhow::Result<Self> {
        let mut mc = MapperConfig::default();
        if let Some(n) = config.iterations {
            mc.iterations = n;
        }
        if let Some(w) = config.window {
            mc.window = w;
        }
        mc.validate()?;
        let mut keyframe = KeyframeConfig::default();
        if let Some(n) = config.keyframe_min_interval {
            anyhow::ensure!(
                (1..=keyframe.max_interval).contains(&n),
                "mapper: keyframe_min_interval must be in 1..={}, got {n}",
                keyframe.max_interval
            );
            keyframe.min_interval = n;
        }
        Ok(Self {
            mapper: SlamMapper::new(mc)?,
            keyframe,
            visibility_downscale: TrackerConfig::default().downscale,
            last: None,
            frames_since: 0,
            keyframes: 0,
            last_report: None,
        })
    }

    /// The current map.
    pub fn map(&self) -> &Gaussians<f32> {
        self.mapper.map()
    }

    fn visible_ids(&self, frame: &Frame, pose: &Isometry3<f64>) -> anyhow::Result<Vec<u64>> {
        let small = frame.downscale(self.visibility_downscale);
        let camera = Camera::from_world_pose(small.intrinsics, pose);
        let options = RenderOptions {
            exposure: [0.0, 0.0],
            exclude_flags: FLAG_UNKNOWN_SPACE,
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

    /// Maps one frame at its estimate (a keyframe when the rule says so; lost frames never);
    /// returns whether the map changed.
    pub fn process(&mut self, frame: Frame, estimate: &PoseEstimate) -> anyhow::Result<bool> {
        let pose = pose_from_wire(&estimate.t_world_camera)?;
        self.frames_since += 1;
        if estimate.status != TrackingStatus::Ok {
            return Ok(false);
        }
        let is_keyframe = match &self.last {
            None => frame.usability().is_ok(),
            Some(last) => {
                let visible = self.visible_ids(&frame, &pose)?;
                decide(
                    &self.keyframe,
                    &pose,
                    &last.pose,
                    last.median_depth,
                    &visible,
                    &last.visible,
                    self.frames_since,
                )
                .is_keyframe
            }
        };
        if !is_keyframe {
            return Ok(false);
        }
        let median_depth = frame.median_depth().unwrap_or(1.0);
        let visible_frame = frame.clone();
        self.last_report = Some(self.mapper.add_keyframe(visible_frame, pose, [0.0, 0.0])?);
        let visible = self.visible_ids(&frame, &pose)?;
        self.last = Some(LastKeyframe {
            pose,
            median_depth,
            visible,
        });
        self.frames_since = 0;
        self.keyframes += 1;
        Ok(true)
    }
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
}

struct Job {
    frame: Frame,
    estimate: PoseEstimate,
}

/// The background mapping thread: frames in, snapshots out, both in frame order.
struct Worker {
    jobs: Option<Sender<Job>>,
    snapshots: Receiver<anyhow::Result<Snapshot>>,
    handle: Option<JoinHandle<()>>,
}

impl Worker {
    fn spawn(mut core: MapperCore) -> anyhow::Result<Self> {
        let (job_tx, job_rx) = channel::<Job>();
        let (snap_tx, snap_rx) = channel();
        let handle = std::thread::Builder::new()
            .name("mapper-worker".into())
            .spawn(move || {
                let mut current = Arc::new(core.map().clone());
                while let Ok(job) = job_rx.recv() {
                    let frame_id = job.estimate.frame_id;
                    let stamp = job.estimate.stamp;
                    let started = std::time::Instant::now();
                    let result = core.process(job.frame, &job.estimate).map(|changed| {
                        if changed {
                            current = Arc::new(core.map().clone());
                            let r = core.last_report.unwrap_or_default();
                            eprintln!(
                                "mapper: keyframe {} at frame {frame_id}: {:.0} ms, {} Gaussians \
                                 (+{} inserted, +{} densified, -{} pruned)",
                                core.keyframes,
                                1e3 * started.elapsed().as_secs_f64(),
                                core.map().len(),
                                r.inserted,
                                r.densified,
                                r.pruned
                            );
                        }
                        Snapshot {
                            frame_id,
                            stamp,
                            map: current.clone(),
                        }
                    });
                    let failed = result.is_err();
                    if snap_tx.send(result).is_err() || failed {
                        break;
                    }
                }
            })?;
        Ok(Self {
            jobs: Some(job_tx),
            snapshots: snap_rx,
            handle: Some(handle),
        })
    }

    fn submit(&self, job: Job) -> anyhow::Result<()> {
        self.jobs
            .as_ref()
            .and_then(|tx| tx.send(job).ok())
            .ok_or_else(|| anyhow::anyhow!("mapper: the mapping worker has stopped"))
    }

    /// The next finished snapshot; waits for it when `block`.
    fn next(&self, block: bool) -> anyhow::Result<Option<Snapshot>> {
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
            Err(TryRecvError::Disconnected) => {
                anyhow::bail!("mapper: the mapping worker stopped unexpectedly")
            }
        }
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

/// The operator's state: pairs frames with their estimates, feeds the worker in frame order and
/// hands out the snapshots it finishes.
pub struct Mapper {
    lag: u64,
    worker: Worker,
    frames: BTreeMap<u64, Frame>,
    poses: BTreeMap<u64, PoseEstimate>,
    next_submit: u64,
    /// Newest frame id seen on `rgbd`.
    newest_frame: Option<u64>,
    /// Frames handed out as snapshots so far (the next snapshot is of frame `published`).
    published: u64,
}

impl Mapper {
    /// An empty map and a running worker.
    pub fn from_config(config: Config) -> anyhow::Result<Self> {
        let core = MapperCore::from_config(&config)?;
        Ok(Self {
            lag: config.map_lag,
            worker: Worker::spawn(core)?,
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

    /// Stores the tracker's estimate of a frame.
    pub fn add_pose(&mut self, estimate: PoseEstimate) {
        self.poses.insert(estimate.frame_id, estimate);
    }

    /// Hands every frame whose estimate has arrived to the worker (in order), then returns the
    /// snapshots finished so far. It waits for the worker only as far as the loop needs: the
    /// snapshot of frame k − 1 − L once frame k arrived (or every submitted frame when `drain`).
    pub fn process_ready(&mut self, drain: bool) -> anyhow::Result<Vec<Snapshot>> {
        while self.frames.contains_key(&self.next_submit)
            && self.poses.contains_key(&self.next_submit)
        {
            let k = self.next_submit;
            let frame = self.frames.remove(&k).expect("present");
            let estimate = self.poses.remove(&k).expect("present");
            self.worker.submit(Job { frame, estimate })?;
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
}

impl Operator for Mapper {
    type Config = Config;

    fn new(config: Config, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        Self::from_config(config)
    }

    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        let mut stop = false;
        match event {
            Event::Input(input) if input.port == "rgbd" => {
                let view = RgbdFrameView::parse(input.bytes)?;
                self.add_frame(view.header.frame_id, slam_frame(&view)?);
            }
            Event::Input(input) if input.port == "pose" => {
                self.add_pose(input.decode()?);
            }
            Event::Timer { .. } => {}
            Event::InputClosed { port: "pose" } => stop = true,
            _ => return Ok(Flow::Continue),
        }
        for s in self.process_ready(stop)? {
            let header = map_header(&s.map, s.frame_id, s.stamp);
            ctx.loan("map", header.payload_len()?, |buf| {
                write_map(buf, header, &s.map)
            })?;
        }
        Ok(if stop { Flow::Stop } else { Flow::Continue })
    }
}

/// Registry entry.
pub fn registered() -> Registered {
    const INPUTS: &[PortSpec] = &[
        PortSpec {
            name: "rgbd",
            kind: K::RgbdFrame,
        },
        PortSpec {
            name: "pose",
            kind: K::PoseEstimate,
        },
    ];
    const OUTPUTS: &[PortSpec] = &[PortSpec {
        name: "map",
        kind: K::GaussianMap,
    }];
    Registered {
        descriptor: OperatorDescriptor {
            name: "mapper",
            summary: "3DGS mapping on keyframes in a background worker; one map snapshot per frame, \
                      tagged with the last frame it includes, in shared memory (SPEC §4)",
            inputs: INPUTS,
            outputs: OUTPUTS,
            evaluation: false,
            check_config: check_config_as::<Config>,
        },
        implementation: Some(OperatorImpl::of::<Mapper>()),
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::convert::pose_to_wire;
    use activemap_sim::{Action as SimAction, SimConfig, Simulator};

    /// A short true-pose sequence in a small procedural house: (frame, estimate) per step, the
    /// robot turning left (new view every frame, so keyframes happen).
    pub(crate) fn sequence(n: usize) -> Vec<(Frame, PoseEstimate)> {
        let mut hc = activemap_sim::house::HouseConfig::default();
        hc.max_rooms = 2;
        hc.min_rooms = hc.min_rooms.min(2);
        hc.max_area = 30.0;
        hc.min_area = hc.min_area.min(30.0);
        let scene = activemap_sim::house::generate(3, &hc).unwrap().scene;
        let mut sim = Simulator::new(scene, SimConfig::with_resolution(32, 32)).unwrap();
        (0..n)
            .map(|k| {
                if k > 0 {
                    for _ in 0..3 {
                        sim.step(SimAction::TurnLeft);
                    }
                }
                let r = sim.render();
                let frame = Frame::from_rgb8(r.intrinsics, &r.rgb, r.depth, k as f64).unwrap();
                let estimate = PoseEstimate {
                    frame_id: k as u64,
                    stamp: k as f64,
                    t_world_camera: pose_to_wire(&sim.true_pose()),
                    status: TrackingStatus::Ok,
                    residual_rgb: 0.0,
                    residual_depth: 0.0,
                    iterations: 0,
                };
                (frame, estimate)
            })
            .collect()
    }

    #[test]
    fn required_snapshot_is_k_minus_one_minus_lag_clamped_at_zero() {
        assert_eq!(required_snapshot(0, 0), 0);
        assert_eq!(required_snapshot(1, 0), 0);
        assert_eq!(required_snapshot(5, 0), 4);
        assert_eq!(required_snapshot(5, 3), 1);
        assert_eq!(required_snapshot(4, 3), 0);
        assert_eq!(required_snapshot(2, 10), 0);
    }

    /// The background worker hands out one snapshot per frame, in frame order; once frame k has
    /// arrived the snapshot of frame k − 1 − L is out (what the consumers wait for), and every
    /// snapshot equals the map a synchronous mapper has after the same frames (the lag changes
    /// when a map is used, never what it holds).
    #[test]
    fn background_snapshots_are_in_order_on_time_and_equal_the_synchronous_map() {
        let frames = sequence(6);
        let config = Config {
            iterations: Some(5),
            window: None,
            map_lag: 2,
            keyframe_min_interval: None,
        };
        // Reference: the same core run synchronously.
        let mut core = MapperCore::from_config(&config).unwrap();
        let mut expected = Vec::new();
        for (f, e) in &frames {
            core.process(f.clone(), e).unwrap();
            expected.push(core.map().clone());
        }
        assert!(core.keyframes >= 2, "the turn must make keyframes");

        let mut mapper = Mapper::from_config(config).unwrap();
        let mut got: Vec<Snapshot> = Vec::new();
        for (k, (f, e)) in frames.iter().enumerate() {
            mapper.add_frame(k as u64, f.clone());
            got.extend(mapper.process_ready(false).unwrap());
            if k >= 1 {
                // Frame k's own pose is not there yet, but the loop needs snapshot k − 1 − L.
                let need = required_snapshot(k as u64, 2);
                assert!(
                    got.last().is_some_and(|s| s.frame_id >= need),
                    "frame {k}: snapshot {need} not out yet"
                );
            }
            mapper.add_pose(*e);
            got.extend(mapper.process_ready(false).unwrap());
        }
        got.extend(mapper.process_ready(true).unwrap());
        let ids: Vec<u64> = got.iter().map(|s| s.frame_id).collect();
        assert_eq!(ids, (0..6).collect::<Vec<u64>>());
        for (s, want) in got.iter().zip(&expected) {
            assert_eq!(s.map.len(), want.len(), "snapshot {}", s.frame_id);
            // Same map up to float summation order (the optimiser's parallel reductions).
            let worst = s
                .map
                .means
                .iter()
                .zip(&want.means)
                .flat_map(|(a, b)| (0..3).map(move |i| (a[i] - b[i]).abs()))
                .fold(0.0f32, f32::max);
            assert!(
                worst < 1e-3,
                "snapshot {}: means differ by {worst}",
                s.frame_id
            );
        }
    }
}
