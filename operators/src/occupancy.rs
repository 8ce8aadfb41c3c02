//! `occupancy`: the 2D grid on the motion plane (SPEC §6) from the Gaussian map and the depth
//! rays of each frame at its ESTIMATED pose, wrapping `activemap_planning::occupancy`. The
//! robot's own footprint is marked free. One grid per frame, once the frame, its pose estimate
//! and the map snapshot of frame k − 1 − L (L = `map_lag`,
//! [`crate::mapper::required_snapshot`]) have all arrived (lockstep order, [`FrameJoin`]): the
//! map part lags, the depth rays of the current frame keep the grid current. Frames the
//! tracker reports lost cast no depth rays.

use activemap_geometry::frames::planar_from_camera_pose;
use activemap_geometry::snapshots::LaggedSnapshots;
use activemap_geometry::{Intrinsics, Isometry3, RobotModel};
use activemap_planning::occupancy::{OccupancyConfig, OccupancyMapper};
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, check_config_as,
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
    /// Radius around the robot always free (its own footprint), metres; default the robot's
    /// radius.
    #[serde(default)]
    pub footprint_radius: Option<f64>,
    /// The robot (its radius is the default footprint; any field left out keeps its default).
    #[serde(default)]
    pub robot: RobotModel,
    /// Use every n-th depth pixel per row and column.
    #[serde(default = "default_stride")]
    pub pixel_stride: usize,
    /// Map lag L in frames: frame k uses the map snapshot of frame k − 1 − L. Must equal the
    /// mapper's `map_lag`.
    #[serde(default)]
    pub map_lag: u64,
}

fn default_cell() -> f64 {
    0.05
}
fn default_threshold() -> u32 {
    25
}
fn default_stride() -> usize {
    1
}

/// The inputs of one frame.
#[derive(Default)]
struct Slot {
    depth: Option<(Vec<f32>, Intrinsics, f64)>,
    pose: Option<(Isometry3<f64>, TrackingStatus)>,
}

impl Slot {
    fn complete(&self) -> bool {
        self.depth.is_some() && self.pose.is_some()
    }
}

/// Map points of one snapshot (means, opacities after the sigmoid).
type MapPoints = (Vec<[f32; 3]>, Vec<f32>);

/// The operator's state.
pub struct Occupancy {
    mapper: OccupancyMapper,
    footprint: f64,
    join: FrameJoin<Slot>,
    /// Map snapshots by the frame they include, from the one the next frame needs on.
    maps: LaggedSnapshots<MapPoints>,
    /// The snapshot last loaded into the occupancy mapper (an unchanged map is not reloaded).
    loaded: Option<(usize, u64)>,
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
        config
            .robot
            .validate()
            .map_err(|e| anyhow::anyhow!("occupancy: {e}"))?;
        let footprint = config.footprint_radius.unwrap_or(config.robot.radius_m);
        anyhow::ensure!(
            footprint.is_finite() && footprint >= 0.0,
            "occupancy: footprint_radius must be ≥ 0"
        );
        Ok(Self {
            mapper: OccupancyMapper::new(occ, Point2::new(-2.0, -2.0), Point2::new(2.0, 2.0))?,
            footprint,
            join: FrameJoin::new(),
            maps: LaggedSnapshots::new(config.map_lag),
            loaded: None,
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
        self.maps.insert(k, (means, opacities));
    }

    /// Integrates every frame whose depth, pose and map have arrived, in frame order; returns
    /// the grids. A frame whose tracking was lost keeps the map points but casts no depth rays
    /// (its pose is only a prediction, and rays from a wrong pose would free walls).
    pub fn process_ready(&mut self) -> anyhow::Result<Vec<activemap_schemas::OccupancyGrid>> {
        let mut out = Vec::new();
        loop {
            let maps = &self.maps;
            let Some((k, slot)) = self
                .join
                .pop_ready_by(|k, s| s.complete() && maps.for_frame(k).is_some())
            else {
                break;
            };
            let (depth, intrinsics, stamp) = slot.depth.expect("complete");
            let (pose, status) = slot.pose.expect("complete");
            let needed = self.maps.needed(k);
            self.maps.retain_needed_from(k);
            let (means, opacities) = self.maps.for_frame(k).expect("ready");
            let fingerprint = (means.len(), points_fingerprint(means, opacities));
            if self.loaded != Some(fingerprint) {
                let ignored = self.mapper.set_map_points(means, opacities)?;
                if ignored > 0 {
                    eprintln!(
                        "occupancy: ignored {ignored} map points with a non-finite mean or \
                         opacity in the map of frame {needed}"
                    );
                }
                self.loaded = Some(fingerprint);
            }
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

/// A cheap content hash of map points (FNV-1a over their bits), so an unchanged snapshot (no
/// keyframe since the last one) is not binned again.
fn points_fingerprint(means: &[[f32; 3]], opacities: &[f32]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for v in means.iter().flatten().chain(opacities) {
        h ^= u64::from(v.to_bits());
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
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
                inputs::RGBD => {
                    let view = RgbdFrameView::parse(input.bytes)?;
                    self.add_depth(
                        view.header.frame_id,
                        view.depth().into_owned(),
                        frame_intrinsics(&view),
                        view.header.stamp,
                    );
                }
                inputs::POSE => {
                    let e: PoseEstimate = input.decode()?;
                    self.add_pose(e.frame_id, pose_from_wire(&e.t_world_camera)?, e.status);
                }
                inputs::MAP => {
                    let (k, means, opacities) = map_points(input.bytes)?;
                    self.add_map(k, means, opacities);
                }
                other => anyhow::bail!("occupancy: unexpected input `{other}`"),
            },
            Event::InputClosed { port: inputs::POSE } => return Ok(Flow::Stop),
            _ => return Ok(Flow::Continue),
        }
        for grid in self.process_ready()? {
            ctx.send(outputs::GRID, &grid)?;
        }
        Ok(Flow::Continue)
    }
}

/// The operator's input ports, named once for registration and dispatch.
pub mod inputs {
    activemap_runtime::ports! {
        RGBD = "rgbd": super::K::RgbdFrame,
        POSE = "pose": super::K::PoseEstimate,
        MAP = "map": super::K::GaussianMap
    }
}

/// The operator's output ports, named once for registration and dispatch.
pub mod outputs {
    activemap_runtime::ports! {
        GRID = "grid": super::K::OccupancyGrid
    }
}

/// Registry entry.
pub fn registered() -> Registered {
    Registered {
        descriptor: OperatorDescriptor {
            name: "occupancy",
            summary: "2D occupancy grid from the map and depth rays at the estimated pose (SPEC §6)",
            inputs: inputs::ALL,
            outputs: outputs::ALL,
            evaluation: false,
            check_config: check_config_as::<Config>,
        },
        implementation: Some(OperatorImpl::of::<Occupancy>()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::convert::start_anchor;

    /// The state of the wire cell holding world point (x, y).
    fn state_at(grid: &activemap_schemas::OccupancyGrid, x: f64, y: f64) -> u8 {
        let ix = ((x - grid.origin[0]) / grid.resolution).round() as u32;
        let iy = ((y - grid.origin[1]) / grid.resolution).round() as u32;
        grid.cells[(iy * grid.width + ix) as usize]
    }

    /// With map lag L = 1, frame k is gridded against the snapshot of frame k − 2 exactly:
    /// a wall cluster that first appears in snapshot 1 is absent from the grids of frames 0–2
    /// (snapshot 0) and present from frame 3 on; frame 3 waits until snapshot 1 arrives, and a
    /// newer snapshot that is already there does not leak into an older frame's grid.
    #[test]
    fn frames_use_exactly_the_lagged_snapshot() {
        let mut occ = Occupancy::from_config(Config {
            cell_size: 0.05,
            point_threshold: 25,
            footprint_radius: Some(0.15),
            robot: RobotModel::default(),
            pixel_stride: 1,
            map_lag: 1,
        })
        .unwrap();
        let intrinsics = Intrinsics::from_hfov(8, 8, std::f64::consts::FRAC_PI_2);
        let pose = start_anchor(&RobotModel::default());
        // 30 points in each cell of a 3×3 block (the opening of SPEC §6 removes lone cells).
        let wall: Vec<[f32; 3]> = (0..9 * 30)
            .map(|i| {
                let (cell, j) = (i / 30, i % 30);
                let x = 1.01 + 0.05 * (cell % 3) as f32 + 0.001 * j as f32;
                let y = 1.01 + 0.05 * (cell / 3) as f32;
                [x, y, 0.5]
            })
            .collect();
        // Snapshots 0 (empty) and 1 (the wall) both arrive before any frame.
        occ.add_map(0, vec![], vec![]);
        occ.add_map(1, wall.clone(), vec![0.9; wall.len()]);
        let mut grids = Vec::new();
        for k in 0..5u64 {
            occ.add_depth(k, vec![0.0; 64], intrinsics, k as f64);
            occ.add_pose(k, pose, TrackingStatus::Ok);
            grids.extend(occ.process_ready().unwrap());
        }
        // Frame 4 needs snapshot 2, which has not arrived.
        assert_eq!(grids.len(), 4);
        let occupied = activemap_schemas::CellState::Occupied as u8;
        for g in &grids {
            let has_wall = state_at(g, 1.075, 1.075) == occupied;
            assert_eq!(has_wall, g.frame_id >= 3, "frame {}", g.frame_id);
        }
        occ.add_map(2, vec![], vec![]);
        let last = occ.process_ready().unwrap();
        assert_eq!(last.len(), 1);
        assert_eq!(last[0].frame_id, 4);
        assert_ne!(
            state_at(&last[0], 1.075, 1.075),
            occupied,
            "snapshot 2 has no wall"
        );
    }
}
