//! `mapper`: Gaussian-splatting mapping on keyframes (SPEC §4), wrapping
//! `activemap_slam::Mapper` and the keyframe rule. Each frame is paired with the tracker's
//! estimate of the same frame; lost frames are never mapped. A map snapshot (shared memory)
//! goes out after every frame, in lockstep order, which is what the tracker waits for.

use std::collections::BTreeMap;

use activemap_geometry::Isometry3;
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, PortSpec, check_config_as,
};
use activemap_schemas::{MessageKind as K, PoseEstimate, RgbdFrameView, TrackingStatus};
use activemap_slam::{
    Frame, KeyframeConfig, Mapper as SlamMapper, MapperConfig, TrackerConfig, keyframe::decide,
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
}

struct LastKeyframe {
    pose: Isometry3<f64>,
    median_depth: f64,
    visible: Vec<u64>,
}

/// The operator's state.
pub struct Mapper {
    mapper: SlamMapper,
    keyframe: KeyframeConfig,
    visibility_downscale: usize,
    frames: BTreeMap<u64, Frame>,
    poses: BTreeMap<u64, PoseEstimate>,
    last: Option<LastKeyframe>,
    frames_since: usize,
    /// Keyframes mapped so far.
    pub keyframes: usize,
}

impl Mapper {
    /// An empty map.
    pub fn from_config(config: Config) -> anyhow::Result<Self> {
        let mut mc = MapperConfig::default();
        if let Some(n) = config.iterations {
            mc.iterations = n;
        }
        if let Some(w) = config.window {
            mc.window = w;
        }
        mc.validate()?;
        Ok(Self {
            mapper: SlamMapper::new(mc)?,
            keyframe: KeyframeConfig::default(),
            visibility_downscale: TrackerConfig::default().downscale,
            frames: BTreeMap::new(),
            poses: BTreeMap::new(),
            last: None,
            frames_since: 0,
            keyframes: 0,
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

    /// Maps every frame whose pose has arrived, in order; returns the processed frame ids.
    pub fn process_ready(&mut self) -> anyhow::Result<Vec<(u64, f64)>> {
        let mut done = Vec::new();
        while let Some((&k, _)) = self.frames.first_key_value() {
            let Some(estimate) = self.poses.remove(&k) else {
                break;
            };
            let frame = self.frames.remove(&k).expect("present");
            let pose = pose_from_wire(&estimate.t_world_camera)?;
            self.frames_since += 1;
            if estimate.status == TrackingStatus::Ok {
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
                if is_keyframe {
                    let median_depth = frame.median_depth().unwrap_or(1.0);
                    let visible_frame = frame.clone();
                    self.mapper.add_keyframe(visible_frame, pose, [0.0, 0.0])?;
                    let visible = self.visible_ids(&frame, &pose)?;
                    self.last = Some(LastKeyframe {
                        pose,
                        median_depth,
                        visible,
                    });
                    self.frames_since = 0;
                    self.keyframes += 1;
                }
            }
            done.push((k, frame.stamp));
        }
        Ok(done)
    }
}

impl Operator for Mapper {
    type Config = Config;

    fn new(config: Config, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        Self::from_config(config)
    }

    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        match event {
            Event::Input(input) if input.port == "rgbd" => {
                let view = RgbdFrameView::parse(input.bytes)?;
                self.frames.insert(view.header.frame_id, slam_frame(&view)?);
            }
            Event::Input(input) if input.port == "pose" => {
                let e: PoseEstimate = input.decode()?;
                self.poses.insert(e.frame_id, e);
            }
            Event::InputClosed { port: "pose" } => return Ok(Flow::Stop),
            _ => return Ok(Flow::Continue),
        }
        for (k, stamp) in self.process_ready()? {
            let header = map_header(self.mapper.map(), k, stamp);
            let map = self.mapper.map();
            ctx.loan("map", header.payload_len()?, |buf| {
                write_map(buf, header, map)
            })?;
        }
        Ok(Flow::Continue)
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
            summary: "3DGS mapping on keyframes; one map snapshot per frame in shared memory (SPEC §4)",
            inputs: INPUTS,
            outputs: OUTPUTS,
            evaluation: false,
            check_config: check_config_as::<Config>,
        },
        implementation: Some(OperatorImpl::of::<Mapper>()),
    }
}
