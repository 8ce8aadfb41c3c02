//! Pipeline messages to view messages.
//!
//! Time: every view message carries the wall-clock time (ns since the Unix epoch) at which the
//! recorder received the RGB-D frame it belongs to (matched by frame id), so an image, its
//! pose and its transform share one timestamp and Foxglove's 3D panel finds the transform of
//! each image exactly. A message whose frame was not seen (or was forgotten) takes the time it
//! arrived. The MCAP log time of a view message is its arrival time, as for the replay channels.

use std::collections::BTreeMap;
use std::fmt::Display;

use activemap_schemas::{
    CellState, EpisodeState, EpisodeStatus, FisherReport, Frontiers, GaussianMapView, Goal,
    LlmExchange, MessageKind, OccupancyGridView, Path, PoseEstimate, ReplanRequest, RgbdFrameView,
    SchemaError, SmallMessage, TrackingStatus, TruePose,
};
use foxglove::Encode;
use foxglove::bytes::Bytes;
use foxglove::messages::{
    ArrowPrimitive, CameraCalibration, Color, CompressedImage, FrameTransform, FrameTransforms,
    Grid, LinePrimitive, Log, PackedElementField, Point3, PointCloud, Pose, PoseInFrame,
    Quaternion, SceneEntity, SceneUpdate, SpherePrimitive, TextPrimitive, Timestamp, Vector2,
    Vector3, line_primitive, log, packed_element_field::NumericType,
};
use thiserror::Error;

use crate::images;
use crate::topics::ViewTopic;

/// The world frame of every map-level view message (SPEC §2).
pub const WORLD_FRAME: &str = "world";
/// The estimated camera frame (child of [`WORLD_FRAME`] through the tracker's pose).
pub const CAMERA_FRAME: &str = "camera";
/// The true camera frame (evaluation only).
pub const TRUE_CAMERA_FRAME: &str = "camera_true";

/// How much of the run the view shows. The defaults keep the view channels of the README's main
/// episode to a few MB per 100 steps (measured in the closing note of issue 17).
#[derive(Debug, Clone, PartialEq)]
pub struct ViewSettings {
    /// JPEG quality of the colour images (1–100).
    pub jpeg_quality: u8,
    /// Depth at the bright end of the depth colour map, metres.
    pub max_depth_m: f32,
    /// Show every n-th RGB-D frame (1: every frame).
    pub image_every_frames: u64,
    /// Show the occupancy grid at most once per this many frames.
    pub grid_every_frames: u64,
    /// Show the Gaussian map at most once per this many frames, and only when a keyframe changed
    /// it.
    pub map_every_frames: u64,
    /// Most Gaussian centres in one map cloud (an even stride over the map thins it).
    pub max_map_points: usize,
}

impl Default for ViewSettings {
    fn default() -> Self {
        Self {
            jpeg_quality: 85,
            max_depth_m: 8.0,
            image_every_frames: 1,
            grid_every_frames: 5,
            map_every_frames: 25,
            max_map_points: 50_000,
        }
    }
}

/// One message for a view channel: its topic, its time and its protobuf bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewMessage {
    /// The channel.
    pub topic: ViewTopic,
    /// Log time, ns since the Unix epoch.
    pub log_time_ns: u64,
    /// The encoded Foxglove message.
    pub data: Vec<u8>,
}

/// A pipeline message that cannot be shown.
#[derive(Debug, Error)]
pub enum ViewError {
    /// The payload does not decode as its kind.
    #[error("{topic}: {kind} payload does not decode: {source}")]
    Decode {
        /// Where it came from (`node/output`).
        topic: String,
        /// Its kind.
        kind: &'static str,
        /// Why.
        source: SchemaError,
    },
    /// An image could not be encoded.
    #[error("{topic}: cannot encode the view image: {source}")]
    Image {
        /// Where it came from.
        topic: String,
        /// Why.
        source: image::ImageError,
    },
    /// A Foxglove message could not be encoded.
    #[error("cannot encode a {0} view message: {1}")]
    Encode(&'static str, String),
}

/// Frames whose arrival times are kept for matching later messages to them.
const FRAME_TIMES_KEPT: usize = 4096;

/// Turns pipeline messages into view messages; holds the little state decimation and time
/// matching need.
#[derive(Debug, Clone)]
pub struct ViewConverter {
    settings: ViewSettings,
    frame_times: BTreeMap<u64, u64>,
    last_grid_frame: Option<u64>,
    last_map: Option<(u64, u64)>,
    grid_resolution: f64,
    last_tracking: Option<TrackingStatus>,
    last_episode_state: Option<EpisodeState>,
}

impl ViewConverter {
    /// A converter with the given settings.
    pub fn new(settings: ViewSettings) -> Self {
        Self {
            settings,
            frame_times: BTreeMap::new(),
            last_grid_frame: None,
            last_map: None,
            grid_resolution: 0.05,
            last_tracking: None,
            last_episode_state: None,
        }
    }

    /// The view messages of one pipeline message, received at `now_ns` on channel `topic`
    /// (`node/output`). An empty payload (end of stream) and kinds without a picture give none.
    pub fn convert(
        &mut self,
        topic: &str,
        kind: MessageKind,
        bytes: &[u8],
        now_ns: u64,
    ) -> Result<Vec<ViewMessage>, ViewError> {
        if bytes.is_empty() {
            return Ok(Vec::new());
        }
        let decode_err = |source| ViewError::Decode {
            topic: topic.to_string(),
            kind: kind.name(),
            source,
        };
        let node = topic.split('/').next().unwrap_or(topic);
        let mut out = Vec::new();
        match kind {
            MessageKind::RgbdFrame => {
                let frame = RgbdFrameView::parse(bytes).map_err(decode_err)?;
                self.rgbd(topic, &frame, now_ns, &mut out)?;
            }
            MessageKind::PoseEstimate => {
                let pose = PoseEstimate::decode(bytes).map_err(decode_err)?;
                let t = self.time_of(pose.frame_id, now_ns);
                let fox = fox_pose(&pose.t_world_camera);
                out.push(pose_message(ViewTopic::EstimatedPose, &fox, t, now_ns)?);
                out.push(transform_message(CAMERA_FRAME, &fox, t, now_ns)?);
                if self.last_tracking != Some(pose.status) {
                    if pose.status != TrackingStatus::Ok || self.last_tracking.is_some() {
                        let level = match pose.status {
                            TrackingStatus::Lost => log::Level::Warning,
                            _ => log::Level::Info,
                        };
                        let text = match &pose.lost_reason {
                            Some(reason) => {
                                format!("frame {}: tracking Lost: {reason}", pose.frame_id)
                            }
                            None => format!("frame {}: tracking {:?}", pose.frame_id, pose.status),
                        };
                        out.push(log_message(node, level, text, t, now_ns)?);
                    }
                    self.last_tracking = Some(pose.status);
                }
                if let Some(r) = &pose.relocalised {
                    let text = format!("frame {}: relocalised: {r}", pose.frame_id);
                    out.push(log_message(node, log::Level::Warning, text, t, now_ns)?);
                }
            }
            MessageKind::TruePose => {
                let pose = TruePose::decode(bytes).map_err(decode_err)?;
                let t = self.time_of(pose.frame_id, now_ns);
                let fox = fox_pose(&pose.t_world_camera);
                out.push(pose_message(ViewTopic::TruePose, &fox, t, now_ns)?);
                out.push(transform_message(TRUE_CAMERA_FRAME, &fox, t, now_ns)?);
            }
            MessageKind::OccupancyGrid => {
                let grid = OccupancyGridView::parse(bytes).map_err(decode_err)?;
                self.grid_resolution = grid.header.resolution;
                let frame = grid.header.frame_id;
                let due = self.last_grid_frame.is_none_or(|last| {
                    frame < last || frame - last >= self.settings.grid_every_frames.max(1)
                });
                if due {
                    self.last_grid_frame = Some(frame);
                    let t = self.time_of(frame, now_ns);
                    out.push(grid_message(&grid, t, now_ns)?);
                }
            }
            MessageKind::GaussianMap => {
                let map = GaussianMapView::parse(bytes).map_err(decode_err)?;
                let (frame, keyframe) = (map.header.frame_id, map.header.keyframe_id);
                let due = match self.last_map {
                    None => map.header.count > 0,
                    Some((last_frame, last_keyframe)) => {
                        keyframe != last_keyframe
                            && (frame < last_frame
                                || frame - last_frame >= self.settings.map_every_frames.max(1))
                    }
                };
                if due {
                    self.last_map = Some((frame, keyframe));
                    let t = self.time_of(frame, now_ns);
                    out.push(self.map_message(&map, t, now_ns)?);
                }
            }
            MessageKind::Frontiers => {
                let f = Frontiers::decode(bytes).map_err(decode_err)?;
                let t = self.time_of(f.frame_id, now_ns);
                out.push(self.frontier_message(&f, t, now_ns)?);
            }
            MessageKind::Goal => {
                let g = Goal::decode(bytes).map_err(decode_err)?;
                let t = self.time_of(g.frame_id, now_ns);
                let text = if g.target < 0 {
                    format!(
                        "frame {}: goal: refine the map around ({:.2}, {:.2})",
                        g.frame_id, g.focus[0], g.focus[1]
                    )
                } else {
                    format!(
                        "frame {}: goal: frontier {} at ({:.2}, {:.2})",
                        g.frame_id, g.target, g.focus[0], g.focus[1]
                    )
                };
                out.push(log_message(node, log::Level::Info, text, t, now_ns)?);
                let entity = SceneEntity {
                    timestamp: Some(timestamp(t)),
                    frame_id: WORLD_FRAME.into(),
                    id: "goal".into(),
                    spheres: vec![SpherePrimitive {
                        pose: Some(planar_pose(g.focus[0], g.focus[1], 0.1, 0.0)),
                        size: Some(Vector3 {
                            x: 0.25,
                            y: 0.25,
                            z: 0.25,
                        }),
                        color: Some(rgba(1.0, 0.55, 0.0, 0.9)),
                    }],
                    ..Default::default()
                };
                out.push(scene_message(ViewTopic::Path, vec![entity], now_ns)?);
            }
            MessageKind::Path => {
                let p = Path::decode(bytes).map_err(decode_err)?;
                let t = self.time_of(p.frame_id, now_ns);
                out.push(path_message(&p, t, now_ns)?);
                if p.waypoints.is_empty() {
                    let text = format!("frame {}: no path (objective {})", p.frame_id, p.objective);
                    out.push(log_message(node, log::Level::Warning, text, t, now_ns)?);
                }
            }
            MessageKind::ReplanRequest => {
                let r = ReplanRequest::decode(bytes).map_err(decode_err)?;
                let t = self.time_of(r.frame_id, now_ns);
                let text = format!("frame {}: replan ({:?})", r.frame_id, r.reason);
                out.push(log_message(node, log::Level::Info, text, t, now_ns)?);
            }
            MessageKind::FisherReport => {
                let r = FisherReport::decode(bytes).map_err(decode_err)?;
                let t = self.time_of(r.frame_id, now_ns);
                out.push(candidates_message(&r, t, now_ns)?);
                let (level, text) = fisher_summary(&r);
                out.push(log_message(node, level, text, t, now_ns)?);
            }
            MessageKind::LlmExchange => {
                let x = LlmExchange::decode(bytes).map_err(decode_err)?;
                let t = self.time_of(x.frame_id, now_ns);
                let (level, text) = llm_summary(&x);
                out.push(log_message(node, level, text, t, now_ns)?);
            }
            MessageKind::EpisodeStatus => {
                let s = EpisodeStatus::decode(bytes).map_err(decode_err)?;
                if self.last_episode_state != Some(s.state) {
                    self.last_episode_state = Some(s.state);
                    if s.state != EpisodeState::Running {
                        let level = match s.state {
                            EpisodeState::Failed => log::Level::Error,
                            _ => log::Level::Info,
                        };
                        let text = format!(
                            "episode {:?} at step {} of {}{}",
                            s.state,
                            s.step,
                            s.max_steps,
                            if s.message.is_empty() {
                                String::new()
                            } else {
                                format!(": {}", s.message)
                            }
                        );
                        out.push(log_message(node, level, text, now_ns, now_ns)?);
                    }
                }
            }
            MessageKind::Action | MessageKind::Counter => {}
        }
        Ok(out)
    }

    /// The wall time of frame `frame_id`, or `now_ns` when it is unknown.
    fn time_of(&self, frame_id: u64, now_ns: u64) -> u64 {
        self.frame_times.get(&frame_id).copied().unwrap_or(now_ns)
    }

    fn rgbd(
        &mut self,
        topic: &str,
        frame: &RgbdFrameView<'_>,
        now_ns: u64,
        out: &mut Vec<ViewMessage>,
    ) -> Result<(), ViewError> {
        let h = frame.header;
        self.frame_times.insert(h.frame_id, now_ns);
        while self.frame_times.len() > FRAME_TIMES_KEPT {
            self.frame_times.pop_first();
        }
        if !h
            .frame_id
            .is_multiple_of(self.settings.image_every_frames.max(1))
        {
            return Ok(());
        }
        let image_err = |source| ViewError::Image {
            topic: topic.to_string(),
            source,
        };
        let stamp = Some(timestamp(now_ns));
        let color = images::rgb_to_jpeg(frame.rgb, h.width, h.height, self.settings.jpeg_quality)
            .map_err(image_err)?;
        out.push(encode_message(
            ViewTopic::Color,
            now_ns,
            &CompressedImage {
                timestamp: stamp,
                frame_id: CAMERA_FRAME.into(),
                data: Bytes::from(color),
                format: "jpeg".into(),
            },
        )?);
        let depth =
            images::depth_to_png(&frame.depth(), h.width, h.height, self.settings.max_depth_m)
                .map_err(image_err)?;
        out.push(encode_message(
            ViewTopic::Depth,
            now_ns,
            &CompressedImage {
                timestamp: stamp,
                frame_id: CAMERA_FRAME.into(),
                data: Bytes::from(depth),
                format: "png".into(),
            },
        )?);
        let (fx, fy, cx, cy) = (h.fx, h.fy, h.cx, h.cy);
        out.push(encode_message(
            ViewTopic::Calibration,
            now_ns,
            &CameraCalibration {
                timestamp: stamp,
                frame_id: CAMERA_FRAME.into(),
                width: h.width,
                height: h.height,
                distortion_model: "plumb_bob".into(),
                d: vec![0.0; 5],
                k: vec![fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
                r: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                p: vec![fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
            },
        )?);
        Ok(())
    }

    fn map_message(
        &self,
        map: &GaussianMapView<'_>,
        t: u64,
        now_ns: u64,
    ) -> Result<ViewMessage, ViewError> {
        let n = map.header.count as usize;
        let stride = n.div_ceil(self.settings.max_map_points.max(1)).max(1);
        let (means, colors, opacities) = (map.means(), map.colors(), map.opacities());
        let mut data = Vec::with_capacity(n / stride * 16 + 16);
        for i in (0..n).step_by(stride) {
            for c in 0..3 {
                data.extend_from_slice(&means[3 * i + c].to_le_bytes());
            }
            for c in 0..3 {
                data.push(unit_to_byte(colors[3 * i + c]));
            }
            data.push(unit_to_byte(opacities[i]));
        }
        let field = |name: &str, offset: u32, ty: NumericType| PackedElementField {
            name: name.into(),
            offset,
            r#type: ty as i32,
        };
        encode_message(
            ViewTopic::Map,
            now_ns,
            &PointCloud {
                timestamp: Some(timestamp(t)),
                frame_id: WORLD_FRAME.into(),
                pose: Some(identity_pose()),
                point_stride: 16,
                fields: vec![
                    field("x", 0, NumericType::Float32),
                    field("y", 4, NumericType::Float32),
                    field("z", 8, NumericType::Float32),
                    field("red", 12, NumericType::Uint8),
                    field("green", 13, NumericType::Uint8),
                    field("blue", 14, NumericType::Uint8),
                    field("alpha", 15, NumericType::Uint8),
                ],
                data: Bytes::from(data),
            },
        )
    }

    fn frontier_message(
        &self,
        f: &Frontiers,
        t: u64,
        now_ns: u64,
    ) -> Result<ViewMessage, ViewError> {
        let res = self.grid_resolution;
        let mut spheres = Vec::with_capacity(f.regions.len());
        let mut texts = Vec::with_capacity(f.regions.len());
        for r in &f.regions {
            // The diameter of a disc with the region's area, kept visible and within reason.
            let d =
                (2.0 * (r.size_cells as f64 / std::f64::consts::PI).sqrt() * res).clamp(0.15, 1.5);
            spheres.push(SpherePrimitive {
                pose: Some(planar_pose(r.centroid[0], r.centroid[1], 0.05, 0.0)),
                size: Some(Vector3 {
                    x: d,
                    y: d,
                    z: 0.05,
                }),
                color: Some(rgba(0.9, 0.1, 0.1, 0.6)),
            });
            texts.push(TextPrimitive {
                pose: Some(planar_pose(r.anchor[0], r.anchor[1], 0.3, 0.0)),
                billboard: true,
                font_size: 14.0,
                scale_invariant: true,
                color: Some(rgba(1.0, 1.0, 1.0, 1.0)),
                text: r.id.to_string(),
            });
        }
        let entity = SceneEntity {
            timestamp: Some(timestamp(t)),
            frame_id: WORLD_FRAME.into(),
            id: "frontiers".into(),
            spheres,
            texts,
            ..Default::default()
        };
        scene_message(ViewTopic::Frontiers, vec![entity], now_ns)
    }
}

fn encode_message<T: Encode>(
    topic: ViewTopic,
    log_time_ns: u64,
    msg: &T,
) -> Result<ViewMessage, ViewError>
where
    T::Error: Display,
{
    let mut data = Vec::with_capacity(msg.encoded_len().unwrap_or(256));
    msg.encode(&mut data)
        .map_err(|e| ViewError::Encode(topic.topic(), e.to_string()))?;
    Ok(ViewMessage {
        topic,
        log_time_ns,
        data,
    })
}

/// A Foxglove timestamp from ns since the Unix epoch (saturating at 2106).
fn timestamp(ns: u64) -> Timestamp {
    let sec = (ns / 1_000_000_000).min(u32::MAX as u64) as u32;
    Timestamp::new(sec, (ns % 1_000_000_000) as u32)
}

fn unit_to_byte(v: f32) -> u8 {
    if v.is_finite() {
        (v.clamp(0.0, 1.0) * 255.0).round() as u8
    } else {
        0
    }
}

fn rgba(r: f64, g: f64, b: f64, a: f64) -> Color {
    Color { r, g, b, a }
}

fn identity_pose() -> Pose {
    Pose {
        position: Some(Vector3 {
            x: 0.0,
            y: 0.0,
            z: 0.0,
        }),
        orientation: Some(Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }),
    }
}

/// A pose at (x, y, z) with heading `yaw` about world z.
fn planar_pose(x: f64, y: f64, z: f64, yaw: f64) -> Pose {
    Pose {
        position: Some(Vector3 { x, y, z }),
        orientation: Some(Quaternion {
            x: 0.0,
            y: 0.0,
            z: (yaw / 2.0).sin(),
            w: (yaw / 2.0).cos(),
        }),
    }
}

fn fox_pose(p: &activemap_schemas::Pose) -> Pose {
    let [x, y, z] = p.translation;
    let [qx, qy, qz, qw] = p.rotation_xyzw;
    Pose {
        position: Some(Vector3 { x, y, z }),
        orientation: Some(Quaternion {
            x: qx,
            y: qy,
            z: qz,
            w: qw,
        }),
    }
}

fn pose_message(
    topic: ViewTopic,
    pose: &Pose,
    t: u64,
    now_ns: u64,
) -> Result<ViewMessage, ViewError> {
    encode_message(
        topic,
        now_ns,
        &PoseInFrame {
            timestamp: Some(timestamp(t)),
            frame_id: WORLD_FRAME.into(),
            pose: Some(*pose),
        },
    )
}

fn transform_message(
    child: &str,
    pose: &Pose,
    t: u64,
    now_ns: u64,
) -> Result<ViewMessage, ViewError> {
    encode_message(
        ViewTopic::Transforms,
        now_ns,
        &FrameTransforms {
            transforms: vec![FrameTransform {
                timestamp: Some(timestamp(t)),
                parent_frame_id: WORLD_FRAME.into(),
                child_frame_id: child.into(),
                translation: pose.position,
                rotation: pose.orientation,
            }],
        },
    )
}

fn log_message(
    name: &str,
    level: log::Level,
    message: String,
    t: u64,
    now_ns: u64,
) -> Result<ViewMessage, ViewError> {
    encode_message(
        ViewTopic::Log,
        now_ns,
        &Log {
            timestamp: Some(timestamp(t)),
            level: level as i32,
            message,
            name: name.into(),
            file: String::new(),
            line: 0,
        },
    )
}

fn scene_message(
    topic: ViewTopic,
    entities: Vec<SceneEntity>,
    now_ns: u64,
) -> Result<ViewMessage, ViewError> {
    encode_message(
        topic,
        now_ns,
        &SceneUpdate {
            deletions: Vec::new(),
            entities,
        },
    )
}

fn grid_message(
    grid: &OccupancyGridView<'_>,
    t: u64,
    now_ns: u64,
) -> Result<ViewMessage, ViewError> {
    let h = grid.header;
    // ROS-like occupancy values: free 0, unknown 50, occupied 100.
    let data: Vec<u8> = grid
        .cells
        .iter()
        .map(|&c| match CellState::from_byte(c) {
            Some(CellState::Free) => 0,
            Some(CellState::Occupied) => 100,
            _ => 50,
        })
        .collect();
    encode_message(
        ViewTopic::Occupancy,
        now_ns,
        &Grid {
            timestamp: Some(timestamp(t)),
            frame_id: WORLD_FRAME.into(),
            pose: Some(planar_pose(h.origin_x, h.origin_y, 0.0, 0.0)),
            column_count: h.width,
            cell_size: Some(Vector2 {
                x: h.resolution,
                y: h.resolution,
            }),
            row_stride: h.width,
            cell_stride: 1,
            fields: vec![PackedElementField {
                name: "occupancy".into(),
                offset: 0,
                r#type: NumericType::Uint8 as i32,
            }],
            data: Bytes::from(data),
        },
    )
}

fn path_message(p: &Path, t: u64, now_ns: u64) -> Result<ViewMessage, ViewError> {
    let points: Vec<Point3> = p
        .waypoints
        .iter()
        .map(|w| Point3 {
            x: w.x,
            y: w.y,
            z: 0.03,
        })
        .collect();
    let arrows = p
        .waypoints
        .last()
        .map(|w| ArrowPrimitive {
            pose: Some(planar_pose(w.x, w.y, 0.03, w.yaw)),
            shaft_length: 0.25,
            shaft_diameter: 0.04,
            head_length: 0.1,
            head_diameter: 0.1,
            color: Some(rgba(0.1, 0.8, 0.2, 1.0)),
        })
        .into_iter()
        .collect();
    let entity = SceneEntity {
        timestamp: Some(timestamp(t)),
        frame_id: WORLD_FRAME.into(),
        id: "path".into(),
        lines: vec![LinePrimitive {
            r#type: line_primitive::Type::LineStrip as i32,
            pose: Some(identity_pose()),
            thickness: 3.0,
            scale_invariant: true,
            points,
            color: Some(rgba(0.1, 0.8, 0.2, 1.0)),
            ..Default::default()
        }],
        arrows,
        ..Default::default()
    };
    scene_message(ViewTopic::Path, vec![entity], now_ns)
}

fn candidates_message(r: &FisherReport, t: u64, now_ns: u64) -> Result<ViewMessage, ViewError> {
    let n = r.candidates.len().max(1) as f64;
    // Candidates come best EIG first: brightest first.
    let mut arrows: Vec<ArrowPrimitive> = r
        .candidates
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let v = 1.0 - 0.8 * i as f64 / n;
            ArrowPrimitive {
                pose: Some(planar_pose(c.x, c.y, 0.05, c.yaw)),
                shaft_length: 0.15,
                shaft_diameter: 0.02,
                head_length: 0.06,
                head_diameter: 0.05,
                color: Some(rgba(0.2 * v, 0.5 * v, v, 0.8)),
            }
        })
        .collect();
    for (i, p) in r.paths.iter().enumerate() {
        let chosen = i as i32 == r.chosen;
        arrows.push(ArrowPrimitive {
            pose: Some(planar_pose(p.goal.x, p.goal.y, 0.1, p.goal.yaw)),
            shaft_length: if chosen { 0.35 } else { 0.2 },
            shaft_diameter: if chosen { 0.05 } else { 0.03 },
            head_length: 0.1,
            head_diameter: if chosen { 0.12 } else { 0.07 },
            color: Some(if chosen {
                rgba(1.0, 0.2, 0.8, 1.0)
            } else {
                rgba(0.9, 0.9, 0.2, 0.8)
            }),
        });
    }
    let entity = SceneEntity {
        timestamp: Some(timestamp(t)),
        frame_id: WORLD_FRAME.into(),
        id: "candidates".into(),
        arrows,
        ..Default::default()
    };
    scene_message(ViewTopic::Candidates, vec![entity], now_ns)
}

fn fisher_summary(r: &FisherReport) -> (log::Level, String) {
    let mut text = format!(
        "frame {}: fisher {}: {} candidates, {} paths",
        r.frame_id,
        if r.refine { "refine" } else { "replan" },
        r.candidates.len(),
        r.paths.len()
    );
    let mut level = log::Level::Info;
    match r
        .paths
        .get(r.chosen.max(0) as usize)
        .filter(|_| r.chosen >= 0)
    {
        Some(p) => {
            let eig: f64 = p.eig.iter().sum();
            let c_local: f64 = p.c_local.iter().sum();
            text.push_str(&format!(
                ", chose path {} to ({:.2}, {:.2}): objective {:.3} (Σ EIG {:.3e}, Σ C_local {:.3})",
                r.chosen, p.goal.x, p.goal.y, p.objective, eig, c_local
            ));
        }
        None => {
            level = log::Level::Warning;
            text.push_str(", none chosen");
        }
    }
    text.push_str(&format!(" in {:.0} ms", r.timings.total_ms));
    if let Some(note) = &r.note {
        text.push_str(&format!("; {note}"));
    }
    if let Some(fallback) = &r.fallback {
        level = log::Level::Warning;
        text.push_str(&format!("; fallback: {fallback}"));
    }
    (level, text)
}

fn llm_summary(x: &LlmExchange) -> (log::Level, String) {
    let mut text = format!(
        "frame {}: LLM {}/{} decided {} in {:.0} ms ({} attempts)",
        x.frame_id, x.provider, x.model, x.decision, x.latency_ms, x.attempts
    );
    if let Some(reason) = &x.reason {
        text.push_str(&format!(": {reason}"));
    }
    if let Some(f) = &x.follow_up {
        text.push_str(&format!("; follow-up turn after {}", f.cause));
    }
    match &x.failure {
        Some(failure) => {
            text.push_str(&format!("; fallback after {failure}"));
            (log::Level::Warning, text)
        }
        None => (log::Level::Info, text),
    }
}

#[cfg(test)]
mod tests;
