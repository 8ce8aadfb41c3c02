//! `occupancy`: the 2D grid on the motion plane (SPEC §6) from the Gaussian map and the depth
//! rays of each frame at its ESTIMATED pose, wrapping `activemap_planning::occupancy`. The
//! robot's own footprint is marked free. One grid per frame, once the frame, its pose estimate
//! and the map snapshot of that frame have all arrived (lockstep order).

use std::collections::BTreeMap;

use activemap_geometry::frames::planar_from_camera_pose;
use activemap_geometry::{Intrinsics, Isometry3};
use activemap_planning::occupancy::{OccupancyConfig, OccupancyMapper};
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, PortSpec, check_config_as,
};
use activemap_schemas::{MessageKind as K, PoseEstimate, RgbdFrameView};
use activemap_splat::gaussians::sigmoid;
use nalgebra::Point2;

use crate::Registered;
use crate::convert::{frame_intrinsics, grid_to_wire, pose_from_wire, read_map};

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

struct Pending {
    depth: Vec<f32>,
    intrinsics: Intrinsics,
    stamp: f64,
}

/// The operator's state.
pub struct Occupancy {
    mapper: OccupancyMapper,
    footprint: f64,
    frames: BTreeMap<u64, Pending>,
    poses: BTreeMap<u64, Isometry3<f64>>,
    maps: BTreeMap<u64, (Vec<[f32; 3]>, Vec<f32>)>,
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
            frames: BTreeMap::new(),
            poses: BTreeMap::new(),
            maps: BTreeMap::new(),
        })
    }

    /// Integrates every frame whose depth, pose and map have arrived; returns the grids.
    pub fn process_ready(&mut self) -> anyhow::Result<Vec<activemap_schemas::OccupancyGrid>> {
        let mut out = Vec::new();
        while let Some((&k, _)) = self.frames.first_key_value() {
            if !self.poses.contains_key(&k) || !self.maps.contains_key(&k) {
                break;
            }
            let frame = self.frames.remove(&k).expect("present");
            let pose = self.poses.remove(&k).expect("present");
            let (means, opacities) = self.maps.remove(&k).expect("present");
            self.mapper.set_map_points(&means, &opacities)?;
            self.mapper
                .integrate_depth(&frame.depth, &frame.intrinsics, &pose)?;
            let planar = planar_from_camera_pose(&pose);
            self.mapper
                .mark_free_disc(Point2::new(planar.x, planar.y), self.footprint)?;
            out.push(grid_to_wire(&self.mapper.grid(), k, frame.stamp));
        }
        Ok(out)
    }
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
                    let pending = Pending {
                        depth: view.depth().into_owned(),
                        intrinsics: frame_intrinsics(&view),
                        stamp: view.header.stamp,
                    };
                    self.frames.insert(view.header.frame_id, pending);
                }
                "pose" => {
                    let e: PoseEstimate = input.decode()?;
                    self.poses
                        .insert(e.frame_id, pose_from_wire(&e.t_world_camera)?);
                }
                "map" => {
                    let (header, g) = read_map(input.bytes)?;
                    let opacities = g.opacity_logits.iter().map(|l| sigmoid(*l)).collect();
                    self.maps.insert(header.frame_id, (g.means, opacities));
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
