//! `occupancy`: the 2D grid on the motion plane (SPEC §6) from the Gaussian map and the depth
//! rays of each frame at its ESTIMATED pose, wrapping `activemap_planning::occupancy`. The
//! robot's own footprint is marked free. One grid per frame, once the frame, its pose estimate
//! and the map snapshot of that frame have all arrived (lockstep order, [`FrameJoin`]). Frames
//! the tracker reports lost cast no depth rays.

use activemap_geometry::frames::planar_from_camera_pose;
use activemap_geometry::{Intrinsics, Isometry3};
use activemap_planning::occupancy::{OccupancyConfig, OccupancyMapper};
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, PortSpec, check_config_as,
};
use activemap_schemas::{
    GaussianMapView, MessageKind as K, PoseEstimate, RgbdFrameView, TrackingStatus,
};
use activemap_splat::gaussians::sigmoid;
use nalgebra::Point2;

use crate::Registered;
use crate::convert::{frame_intrinsics, grid_to_wire, pose_from_wire};
use crate::join::FrameJoin;

/// Config.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// Cell size, metres (SPEC §6: 0.05).
    #[serde(default = "default_cell")]
    pub cell_size: f64,
    /// Map Gaussians per cell (in the height band) for "occupied" (release: ~25).
    #[serde(default = "default_threshold")]
    pub point_threshold: u32,
    /// Radius around the robot always free (its own footprint), metres.
    #[serde(default = "default_footprint")]
    pub footprint_radius: f64,
    /// Use every n-th depth pixel per row and column.
    #[serde(default = "default_stride")]
    pub pixel_stride: usize,
}

fn default_cell() -> f64 {
    0.05
}
fn default_threshold() -> u32 {
    25
}
fn default_footprint() -> f64 {
    0.15
}
fn default_stride() -> usize {
    1
}

/// The inputs of one frame.
#[derive(Default)]
struct Slot {
    depth: Option<(Vec<f32>, Intrinsics, f64)>,
    pose: Option<(Isometry3<f64>, TrackingStatus)>,
    /// Map points in the height band (means, opacities after the sigmoid).
    map: Option<(Vec<[f32; 3]>, Vec<f32>)>,
}

impl Slot {
    fn complete(&self) -> bool {
        self.depth.is_some() && self.pose.is_some() && self.map.is_some()
    }
}

/// The operator's state.
pub struct Occupancy {
    mapper: OccupancyMapper,
    footprint: f64,
    join: FrameJoin<Slot>,
    /// Frames whose depth was not integrated because tracking was lost.
    pub skipped_lost: usize,
}

impl Occupancy {
    /// An all-unknown grid around the start.
    pub fn from_config(config: Config) -> anyhow::Result<Self> {
        let occ = OccupancyConfig {
            resolution: config.cell_size,
            point_threshold: config.point_threshold,
            pixel_stride: config.pixel_stride,
            ..OccupancyConfig::default()
        };
        occ.validate()?;
        anyhow::ensure!(
            config.footprint_radius.is_finite() && config.footprint_radius >= 0.0,
            "occupancy: footprint_radius must be ≥ 0"
        );
        Ok(Self {
            mapper: OccupancyMapper::new(occ, Point2::new(-2.0, -2.0), Point2::new(2.0, 2.0))?,
            footprint: config.footprint_radius,
            join: FrameJoin::new(),
            skipped_lost: 0,
        })
    }

    /// Stores the depth image of frame `k`.
    pub fn add_depth(&mut self, k: u64, depth: Vec<f32>, intrinsics: Intrinsics, stamp: f64) {
        self.join.slot(k).depth = Some((depth, intrinsics, stamp));
    }

    /// Stores the pose estimate of frame `k` and the tracker's status for it.
    pub fn add_pose(&mut self, k: u64, pose: Isometry3<f64>, status: TrackingStatus) {
        self.join.slot(k).pose = Some((pose, status));
    }

    /// Stores the map snapshot of frame `k` as Gaussian means and opacities (post-sigmoid).
    pub fn add_map(&mut self, k: u64, means: Vec<[f32; 3]>, opacities: Vec<f32>) {
        self.join.slot(k).map = Some((means, opacities));
    }

    /// Integrates every frame whose depth, pose and map have arrived, in frame order; returns
    /// the grids. A frame whose tracking was lost keeps the map points but casts no depth rays
    /// (its pose is only a prediction, and rays from a wrong pose would free walls).
    pub fn process_ready(&mut self) -> anyhow::Result<Vec<activemap_schemas::OccupancyGrid>> {
        let mut out = Vec::new();
        while let Some((k, slot)) = self.join.pop_ready(Slot::complete) {
            let (depth, intrinsics, stamp) = slot.depth.expect("complete");
            let (pose, status) = slot.pose.expect("complete");
            let (means, opacities) = slot.map.expect("complete");
            self.mapper.set_map_points(&means, &opacities)?;
            if status == TrackingStatus::Lost {
                self.skipped_lost += 1;
            } else {
                self.mapper.integrate_depth(&depth, &intrinsics, &pose)?;
            }
            let planar = planar_from_camera_pose(&pose);
            self.mapper
                .mark_free_disc(Point2::new(planar.x, planar.y), self.footprint)?;
            out.push(grid_to_wire(&self.mapper.grid(), k, stamp));
        }
        Ok(out)
    }
}

/// The means and opacities (after the sigmoid) of a wire map, the only fields the occupancy
/// grid uses (SPEC §6), without converting the rest of the map.
pub fn map_points(bytes: &[u8]) -> anyhow::Result<(u64, Vec<[f32; 3]>, Vec<f32>)> {
    let view = GaussianMapView::parse(bytes)?;
    let means: Vec<[f32; 3]> = view
        .means()
        .chunks_exact(3)
        .map(|m| [m[0], m[1], m[2]])
        .collect();
    let opacities: Vec<f32> = view.opacities().iter().map(|l| sigmoid(*l)).collect();
    anyhow::ensure!(
        means.len() == opacities.len(),
        "map of frame {}: {} means but {} opacities",
        view.header.frame_id,
        means.len(),
        opacities.len()
    );
    Ok((view.header.frame_id, means, opacities))
}

impl Operator for Occupancy {
    type Config = Config;

    fn new(config: Config, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        Self::from_config(config)
    }

    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        match event {
            Event::Input(input) => match input.port {
                "rgbd" => {
                    let view = RgbdFrameView::parse(input.bytes)?;
                    self.add_depth(
                        view.header.frame_id,
                        view.depth().into_owned(),
                        frame_intrinsics(&view),
                        view.header.stamp,
                    );
                }
                "pose" => {
                    let e: PoseEstimate = input.decode()?;
                    self.add_pose(e.frame_id, pose_from_wire(&e.t_world_camera)?, e.status);
                }
                "map" => {
                    let (k, means, opacities) = map_points(input.bytes)?;
                    self.add_map(k, means, opacities);
                }
                other => anyhow::bail!("occupancy: unexpected input `{other}`"),
            },
            Event::InputClosed { port: "pose" } => return Ok(Flow::Stop),
            _ => return Ok(Flow::Continue),
        }
        for grid in self.process_ready()? {
            ctx.send("grid", &grid)?;
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
        PortSpec {
            name: "map",
            kind: K::GaussianMap,
        },
    ];
    const OUTPUTS: &[PortSpec] = &[PortSpec {
        name: "grid",
        kind: K::OccupancyGrid,
    }];
    Registered {
        descriptor: OperatorDescriptor {
            name: "occupancy",
            summary: "2D occupancy grid from the map and depth rays at the estimated pose (SPEC §6)",
            inputs: INPUTS,
            outputs: OUTPUTS,
            evaluation: false,
            check_config: check_config_as::<Config>,
        },
        implementation: Some(OperatorImpl::of::<Occupancy>()),
    }
}
