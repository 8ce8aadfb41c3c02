//! `mapper`: Gaussian-splatting mapping on keyframes (SPEC §4). A thin shell around
//! [`activemap_slam::BackgroundMapper`], which holds the whole mapping session (pairing frames
//! with the tracker's estimates, the keyframe rule, the background worker and the fixed map
//! lag; see its module doc); the in-process driver of `activemap bench slam` holds the same
//! session. One map snapshot per frame goes out tagged with the last frame it includes and
//! the newest keyframe it includes (`keyframe_id`: snapshots with the same one hold the same
//! map), with the stable id of every Gaussian, in shared memory. The node's `map_lag` must equal the consumers' (tracker, occupancy); a
//! `timers:` entry (any name) additionally publishes finished snapshots as soon as they exist.

use activemap_runtime::dataflow::Dataflow;
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, check_config_as,
};
use activemap_schemas::{MessageKind as K, PoseEstimate, RgbdFrameView, TrackingStatus};
use activemap_slam::{
    BackgroundMapper, GraphLink, MappingConfig, PoseQuality, SlamConfig, Snapshot,
};

use crate::Registered;
use crate::convert::{corrections_from_wire, map_header, pose_from_wire, slam_frame, write_map};

pub use activemap_slam::required_snapshot;

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
    /// Keyframes are stored and optimised at `1/downscale` resolution (library default, full
    /// resolution, when absent).
    #[serde(default)]
    pub downscale: Option<usize>,
    /// The depth term of the mapping loss: `rendered` (SPEC §4, `|D̂ − D|`),
    /// `opacity_weighted` (`|D̂ − o·D|`) or `normalised` (`|D̂/o − D|` where `o > 0.5`);
    /// library default when absent.
    #[serde(default)]
    pub depth_loss: Option<activemap_slam::loss::MappingDepth>,
    /// Mapping-loss tuning (issue 33); library defaults where absent.
    #[serde(default)]
    pub tuning: MapperTuning,
}

/// Optional overrides of the mapping loss, regularisers, pruning and insertion
/// (`--set mapper.tuning.alpha=0.5`); each absent one keeps the library default
/// ([`activemap_slam::MapperConfig`], [`activemap_slam::insert::InsertConfig`]).
#[derive(Debug, Clone, Default, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MapperTuning {
    /// Weight α of the colour term of the mapping loss.
    #[serde(default)]
    pub alpha: Option<f32>,
    /// Weight of the isotropic scale regulariser.
    #[serde(default)]
    pub isotropic_weight: Option<f32>,
    /// Weight of the flat scale regulariser (mean of the smallest scale).
    #[serde(default)]
    pub flat_weight: Option<f32>,
    /// Opacity below which an old-enough Gaussian in the window is pruned.
    #[serde(default)]
    pub prune_opacity_window: Option<f64>,
    /// Initial opacity of Gaussians inserted where the map is unobserved.
    #[serde(default)]
    pub insert_opacity: Option<f64>,
    /// Fraction of the already explained depth pixels re-inserted at every keyframe.
    #[serde(default)]
    pub refresh_fraction: Option<f64>,
    /// Initial opacity of the re-inserted Gaussians.
    #[serde(default)]
    pub refresh_opacity: Option<f64>,
    /// Whether readings behind the map's surface are a source of new Gaussians.
    #[serde(default)]
    pub insert_behind_map: Option<bool>,
    /// Initial scale of an inserted Gaussian as a multiple of the sample spacing.
    #[serde(default)]
    pub scale_factor: Option<f64>,
    /// Thickness of an inserted Gaussian along the surface normal, a share of its scale
    /// (0 = isotropic insertion).
    #[serde(default)]
    pub normal_thickness: Option<f64>,
    /// Largest stretch of an oriented Gaussian along the viewing direction (1 = round discs).
    #[serde(default)]
    pub max_grazing_stretch: Option<f64>,
    /// How far (in stretched scales) a disc's stretched axis must find its plane in the depth
    /// image before it is stretched (0 = off).
    #[serde(default)]
    pub stretch_support_sigmas: Option<f64>,
    /// Largest ratio of a Gaussian's largest scale to its middle one during optimisation
    /// (0 = no limit).
    #[serde(default)]
    pub max_in_plane_ratio: Option<f64>,
    /// Band behind the newest keyframe's readings whose centres are moved onto them, metres.
    #[serde(default)]
    pub snap_behind_m: Option<f64>,
    /// Also move the centres in front of the readings, within the band.
    #[serde(default)]
    pub snap_in_front: Option<bool>,
    /// Free-space carving margin, metres (0 = off).
    #[serde(default)]
    pub carve_margin_m: Option<f64>,
    /// The relative part of the carving margin, a share of the reading.
    #[serde(default)]
    pub carve_margin_fraction: Option<f64>,
    /// Densification threshold on the mean NDC-space gradient of the projected mean.
    #[serde(default)]
    pub densify_grad: Option<f64>,
    /// The per-pixel depth of a Gaussian in the mapping renders (`centre` or `plane`,
    /// `activemap_splat::DepthModel`); the tracker's `depth_model` must match.
    #[serde(default)]
    pub depth_model: Option<activemap_splat::DepthModel>,
}

impl MapperTuning {
    /// Writes the overrides that are set into `mapper`.
    pub fn apply(&self, mapper: &mut activemap_slam::MapperConfig) {
        fn set<T: Copy>(value: Option<T>, field: &mut T) {
            if let Some(v) = value {
                *field = v;
            }
        }
        set(self.alpha, &mut mapper.alpha);
        set(self.isotropic_weight, &mut mapper.isotropic_weight);
        set(self.flat_weight, &mut mapper.flat_weight);
        set(self.prune_opacity_window, &mut mapper.prune_opacity_window);
        set(self.insert_opacity, &mut mapper.insert.opacity);
        set(self.refresh_fraction, &mut mapper.insert.refresh_fraction);
        set(self.refresh_opacity, &mut mapper.insert.refresh_opacity);
        set(self.insert_behind_map, &mut mapper.insert.insert_behind_map);
        set(self.scale_factor, &mut mapper.insert.scale_factor);
        set(self.normal_thickness, &mut mapper.insert.normal_thickness);
        set(
            self.max_grazing_stretch,
            &mut mapper.insert.max_grazing_stretch,
        );
        set(
            self.stretch_support_sigmas,
            &mut mapper.insert.stretch_support_sigmas,
        );
        set(self.max_in_plane_ratio, &mut mapper.max_in_plane_ratio);
        set(self.snap_behind_m, &mut mapper.snap_behind_m);
        set(self.snap_in_front, &mut mapper.snap_in_front);
        set(self.carve_margin_m, &mut mapper.carve_margin_m);
        set(
            self.carve_margin_fraction,
            &mut mapper.carve_margin_fraction,
        );
        set(self.densify_grad, &mut mapper.densify_grad);
        set(self.depth_model, &mut mapper.depth_model);
    }
}

impl Config {
    /// The mapping session's settings for this node (library defaults where unset).
    pub fn mapping_config(&self) -> anyhow::Result<MappingConfig> {
        let mut config = MappingConfig {
            map_lag: self.map_lag,
            ..MappingConfig::default()
        };
        if let Some(n) = self.iterations {
            config.mapper.iterations = n;
        }
        if let Some(w) = self.window {
            config.mapper.window = w;
        }
        if let Some(n) = self.keyframe_min_interval {
            config.keyframe.min_interval = n;
        }
        if let Some(d) = self.downscale {
            config.downscale = d;
        }
        if let Some(d) = self.depth_loss {
            config.mapper.depth_loss = d;
        }
        self.tuning.apply(&mut config.mapper);
        config
            .validate()
            .map_err(|e| anyhow::anyhow!("mapper: {e}"))?;
        Ok(config)
    }
}

/// The configs of a dataflow's (single) `tracker` and `mapper` nodes: what `activemap bench
/// slam` runs, so that the benchmark measures the flow's SLAM ([`slam_config`]).
pub fn slam_nodes(flow: &Dataflow) -> anyhow::Result<(crate::tracker::Config, Config)> {
    Ok((
        crate::single_node_config(flow, "tracker")?,
        crate::single_node_config(flow, "mapper")?,
    ))
}

/// The SLAM settings the `tracker` and `mapper` operators build from their node configs.
pub fn slam_config(
    tracker: &crate::tracker::Config,
    mapper: &Config,
) -> anyhow::Result<SlamConfig> {
    anyhow::ensure!(
        tracker.map_lag == mapper.map_lag,
        "tracker map_lag {} differs from mapper map_lag {}",
        tracker.map_lag,
        mapper.map_lag
    );
    Ok(SlamConfig {
        tracking: tracker.tracking_config()?,
        mapping: mapper.mapping_config()?,
    })
}

/// The operator's state: the mapping session.
pub struct Mapper {
    session: BackgroundMapper,
    /// The newest keyframe handed out so far (what the snapshots' `keyframe_id` says).
    last_keyframe: Option<u64>,
}

impl Mapper {
    /// An empty map and a running worker.
    pub fn from_config(config: Config) -> anyhow::Result<Self> {
        Ok(Self {
            session: BackgroundMapper::new(config.mapping_config()?)?,
            last_keyframe: None,
        })
    }

    /// Stores an RGB-D frame.
    pub fn add_frame(&mut self, frame_id: u64, frame: activemap_slam::Frame) {
        self.session.add_frame(frame_id, frame);
    }

    /// Stores the tracker's estimate of a frame, with the pose-graph corrections it brought.
    pub fn add_pose(&mut self, estimate: PoseEstimate) -> anyhow::Result<()> {
        let pose = pose_from_wire(&estimate.t_world_camera)?;
        let quality = match estimate.status {
            TrackingStatus::Ok => PoseQuality::Ok,
            TrackingStatus::Lost => estimate
                .lost_reason
                .as_ref()
                .map_or(PoseQuality::Lost, PoseQuality::of_lost),
            TrackingStatus::Skipped => PoseQuality::Skipped,
        };
        let link = GraphLink {
            anchor: estimate.graph_anchor,
            corrections: corrections_from_wire(&estimate)?,
        };
        self.session
            .add_pose(estimate.frame_id, estimate.stamp, pose, quality, link);
        Ok(())
    }

    /// The snapshots finished so far (see [`BackgroundMapper::process_ready`]); logs each
    /// keyframe, the Gaussians it dropped for non-finite parameters, and the Gaussians the
    /// pose graph's corrections moved.
    pub fn process_ready(&mut self, drain: bool) -> anyhow::Result<Vec<Snapshot>> {
        let snapshots = self.session.process_ready(drain)?;
        for s in &snapshots {
            if s.corrected > 0 {
                eprintln!(
                    "mapper: frame {}: pose-graph corrections moved {} Gaussians with their keyframes",
                    s.frame_id, s.corrected
                );
            }
            if let Some(k) = &s.keyframe {
                let r = k.report;
                eprintln!(
                    "mapper: keyframe {} at frame {}: {:.0} ms, {} Gaussians \
                     (+{} inserted from {} transparent / {} nearer / {} farther px, \
                     +{} densified, -{} pruned, -{} carved)",
                    k.keyframe,
                    s.frame_id,
                    1e3 * k.seconds,
                    s.map.len(),
                    r.inserted,
                    r.unobserved.transparent,
                    r.unobserved.nearer,
                    r.unobserved.farther,
                    r.densified,
                    r.pruned,
                    r.carved
                );
                if r.dropped_non_finite > 0 {
                    eprintln!(
                        "mapper: dropped {} Gaussians with non-finite parameters at frame {}",
                        r.dropped_non_finite, s.frame_id
                    );
                }
            }
        }
        Ok(snapshots)
    }

    /// The wire header of snapshot `s`, the snapshots being handed to it in order: its
    /// `keyframe_id` is the newest snapshot among them so far at which the map changed (a
    /// keyframe, or the pose graph's corrections).
    pub fn wire_header(&mut self, s: &Snapshot) -> activemap_schemas::GaussianMapHeader {
        if s.keyframe.is_some() || s.corrected > 0 {
            self.last_keyframe = Some(s.frame_id);
        }
        map_header(&s.map, s.frame_id, s.stamp, self.last_keyframe)
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
            Event::Input(input) if input.port == inputs::RGBD => {
                let view = RgbdFrameView::parse(input.bytes)?;
                self.add_frame(view.header.frame_id, slam_frame(&view)?);
            }
            Event::Input(input) if input.port == inputs::POSE => {
                self.add_pose(input.decode()?)?;
            }
            Event::Timer { .. } => {}
            Event::InputClosed { port: inputs::POSE } => stop = true,
            _ => return Ok(Flow::Continue),
        }
        for s in self.process_ready(stop)? {
            let header = self.wire_header(&s);
            ctx.loan(outputs::MAP, header.payload_len()?, |buf| {
                write_map(buf, header, &s.map, &s.ids)
            })?;
        }
        Ok(if stop { Flow::Stop } else { Flow::Continue })
    }
}

/// The operator's input ports, named once for registration and dispatch.
pub mod inputs {
    activemap_runtime::ports! {
        RGBD = "rgbd": super::K::RgbdFrame,
        POSE = "pose": super::K::PoseEstimate
    }
}

/// The operator's output ports, named once for registration and dispatch.
pub mod outputs {
    activemap_runtime::ports! {
        MAP = "map": super::K::GaussianMap
    }
}

/// Registry entry.
pub fn registered() -> Registered {
    Registered {
        descriptor: OperatorDescriptor {
            name: "mapper",
            summary: "3DGS mapping on keyframes in a background worker; one map snapshot per frame, \
                      tagged with the last frame and the newest keyframe it includes, with stable \
                      Gaussian ids, in shared memory (SPEC §4)",
            inputs: inputs::ALL,
            outputs: outputs::ALL,
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
    pub(crate) fn sequence(n: usize) -> Vec<(activemap_slam::Frame, PoseEstimate)> {
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
                let frame =
                    activemap_slam::Frame::from_rgb8(r.intrinsics, &r.rgb, r.depth, k as f64)
                        .unwrap();
                let estimate = PoseEstimate {
                    frame_id: k as u64,
                    stamp: k as f64,
                    t_world_camera: pose_to_wire(&sim.true_pose()),
                    status: TrackingStatus::Ok,
                    residual_rgb: 0.0,
                    residual_depth: 0.0,
                    iterations: 0,
                    graph_anchor: None,
                    keyframe_corrections: Vec::new(),
                    lost_reason: None,
                    relocalised: None,
                };
                (frame, estimate)
            })
            .collect()
    }

    /// The disc-insertion keys of `tuning` reach the mapping session, and out-of-range values
    /// are refused with the field's name.
    #[test]
    fn disc_insertion_keys_reach_the_mapper_and_bad_values_are_refused() {
        let parse = |json: serde_json::Value| -> Config { serde_json::from_value(json).unwrap() };
        let config = parse(serde_json::json!({
            "tuning": {
                "normal_thickness": 0.2,
                "max_grazing_stretch": 2.0,
                "max_in_plane_ratio": 1.5,
                "stretch_support_sigmas": 2.5
            }
        }));
        let mapping = config.mapping_config().unwrap();
        assert_eq!(mapping.mapper.insert.normal_thickness, 0.2);
        assert_eq!(mapping.mapper.insert.max_grazing_stretch, 2.0);
        assert_eq!(mapping.mapper.max_in_plane_ratio, 1.5);
        assert_eq!(mapping.mapper.insert.stretch_support_sigmas, 2.5);
        for (key, value, field) in [
            ("normal_thickness", 1.5, "insert.normal_thickness"),
            ("normal_thickness", -0.1, "insert.normal_thickness"),
            ("max_grazing_stretch", 0.5, "insert.max_grazing_stretch"),
            ("max_in_plane_ratio", 0.5, "max_in_plane_ratio"),
            (
                "stretch_support_sigmas",
                -1.0,
                "insert.stretch_support_sigmas",
            ),
        ] {
            let config = parse(serde_json::json!({ "tuning": { key: value } }));
            let error = config.mapping_config().unwrap_err().to_string();
            assert!(error.contains(field), "{key}={value}: {error}");
        }
    }

    /// The background worker hands out one snapshot per frame, in frame order; once frame k has
    /// arrived the snapshot of frame k − 1 − L is out (what the consumers wait for), and every
    /// snapshot equals the map a synchronous mapper has after the same frames (the lag changes
    /// when a map is used, never what it holds), with the same stable ids (increasing, parallel
    /// to the map). On the wire each snapshot names the newest keyframe it includes: the frames
    /// the synchronous mapper made keyframes. Pose-graph corrections that come with frame 4's
    /// estimate (moving the graph keyframe of frame 0, so every mapper keyframe) are applied
    /// before frame 4 is mapped, exactly as the synchronous mapper applies them, and snapshot 4
    /// says the map changed.
    #[test]
    fn background_snapshots_are_in_order_on_time_and_equal_the_synchronous_map() {
        let mut frames = sequence(6);
        let correction = activemap_geometry::Isometry3::from_parts(
            nalgebra::Translation3::new(0.02, 0.0, -0.01),
            nalgebra::UnitQuaternion::from_euler_angles(0.0, 1f64.to_radians(), 0.0),
        );
        // Every frame hangs on the graph keyframe of frame 0.
        for (_, e) in &mut frames {
            e.graph_anchor = Some(0);
        }
        frames[4].1.keyframe_corrections = vec![activemap_schemas::KeyframeCorrection {
            frame_id: 0,
            correction: pose_to_wire(&correction),
        }];
        let config = Config {
            iterations: Some(5),
            window: None,
            map_lag: 2,
            keyframe_min_interval: None,
            depth_loss: None,
            downscale: None,
            tuning: MapperTuning::default(),
        };
        // Reference: the same core run synchronously.
        let mut core =
            activemap_slam::KeyframeMapper::new(config.mapping_config().unwrap()).unwrap();
        let mut expected = Vec::new();
        let mut expected_ids = Vec::new();
        let mut expected_keyframe = Vec::new();
        let mut newest = None;
        for (k, (f, e)) in frames.iter().enumerate() {
            let pose = pose_from_wire(&e.t_world_camera).unwrap();
            if !e.keyframe_corrections.is_empty() {
                let corrections = [activemap_slam::KeyframeCorrection {
                    frame_id: 0,
                    correction,
                }];
                assert!(core.apply_corrections(&corrections).unwrap() > 0);
                newest = Some(k as u64);
            }
            if core
                .process(Some(0), f.clone(), &pose, PoseQuality::Ok)
                .unwrap()
                .is_some()
            {
                newest = Some(k as u64);
            }
            expected.push(core.map().clone());
            expected_ids.push(core.mapper().ids().to_vec());
            expected_keyframe.push(newest);
        }
        assert!(core.keyframes() >= 2, "the turn must make keyframes");

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
            mapper.add_pose(e.clone()).unwrap();
            got.extend(mapper.process_ready(false).unwrap());
        }
        got.extend(mapper.process_ready(true).unwrap());
        let frame_ids: Vec<u64> = got.iter().map(|s| s.frame_id).collect();
        assert_eq!(frame_ids, (0..6).collect::<Vec<u64>>());
        for (k, (s, want)) in got.iter().zip(&expected).enumerate() {
            assert_eq!(s.map.len(), want.len(), "snapshot {}", s.frame_id);
            assert_eq!(
                s.corrected > 0,
                k == 4,
                "snapshot {k}: {} moved",
                s.corrected
            );
            assert_eq!(*s.ids, expected_ids[k], "ids of snapshot {k}");
            assert!(s.ids.windows(2).all(|w| w[0] < w[1]), "ids increase");
            let header = mapper.wire_header(s);
            assert_eq!(header.keyframe(), expected_keyframe[k], "snapshot {k}");
            assert_eq!(header.count as usize, s.ids.len());
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
