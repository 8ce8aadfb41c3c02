//! `frontier`: frontier regions of each occupancy grid (SPEC §6), wrapping
//! `activemap_planning::frontier::reachable_regions` (the in-process explorer's too): (3×3 dilation of the connected free space
//! − free space) ∩ unknown, connected regions above the minimum size, each with its size,
//! centroid and the closest cell the robot can reach. Only reachable regions are published,
//! largest first, with ids 0..N−1. One message per grid.

use activemap_geometry::RobotModel;
use activemap_geometry::frames::planar_from_camera_pose;
use activemap_planning::OccupancyGrid as PlanGrid;
use activemap_planning::clearance::ClearanceConfig;
use activemap_planning::frontier::{FrontierConfig, reachable_regions};
use activemap_runtime::{
    Context, Event, Flow, Operator, OperatorDescriptor, OperatorImpl, check_config_as,
};
use activemap_schemas::{FrontierRegion, Frontiers, MessageKind as K, PoseEstimate};
use nalgebra::Point2;

use crate::Registered;
use crate::convert::{pose_from_wire, read_grid};
use crate::join::FrameJoin;

/// Config.
#[derive(Debug, Clone, Copy, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// Regions need more than this many cells (SPEC §6: 5).
    #[serde(default = "default_min")]
    pub min_region_cells: usize,
    /// Robot width in cells for reachability; default: the width that keeps the robot's disc
    /// off blocked cells ([`crate::convert::robot_clearance`], the one A* and the follower use).
    #[serde(default)]
    pub robot_width_cells: Option<f64>,
    /// The robot (its radius gives the default width; any field left out keeps its default).
    #[serde(default)]
    pub robot: RobotModel,
}

fn default_min() -> usize {
    5
}

/// The reachable frontier regions of `grid` seen from `robot`, largest first (ties: the
/// library's order), as wire regions with ids 0..N−1 in that order.
pub fn frontier_regions(
    grid: &PlanGrid,
    robot: Point2<f64>,
    config: &Config,
) -> anyhow::Result<Vec<FrontierRegion>> {
    let shared = crate::convert::robot_clearance(&config.robot, grid.geometry.resolution)?;
    let clearance = ClearanceConfig {
        robot_width_cells: config.robot_width_cells.unwrap_or(shared.robot_width_cells),
        ..shared
    };
    let fc = FrontierConfig {
        min_region_cells: config.min_region_cells,
        ..FrontierConfig::default()
    };
    let regions = reachable_regions(grid, robot, &clearance, &fc)?;
    Ok(activemap_policy::wire::regions_to_wire(grid, &regions))
}

/// The inputs of one frame.
#[derive(Default)]
struct Slot {
    grid: Option<(f64, PlanGrid)>,
    robot: Option<Point2<f64>>,
}

/// The operator's state.
pub struct Frontier {
    config: Config,
    join: FrameJoin<Slot>,
}

impl Operator for Frontier {
    type Config = Config;

    fn new(config: Config, _ctx: &mut Context<'_>) -> anyhow::Result<Self> {
        Ok(Self {
            config,
            join: FrameJoin::new(),
        })
    }

    fn on_event(&mut self, event: Event<'_>, ctx: &mut Context<'_>) -> anyhow::Result<Flow> {
        match event {
            Event::Input(input) if input.port == inputs::GRID => {
                let stamp = activemap_schemas::OccupancyGridView::parse(input.bytes)?
                    .header
                    .stamp;
                let (k, grid) = read_grid(input.bytes)?;
                self.join.slot(k).grid = Some((stamp, grid));
            }
            Event::Input(input) if input.port == inputs::POSE => {
                let e: PoseEstimate = input.decode()?;
                let p = planar_from_camera_pose(&pose_from_wire(&e.t_world_camera)?);
                self.join.slot(e.frame_id).robot = Some(Point2::new(p.x, p.y));
            }
            Event::InputClosed { port: inputs::POSE } => return Ok(Flow::Stop),
            _ => return Ok(Flow::Continue),
        }
        while let Some((k, slot)) = self
            .join
            .pop_ready(|s| s.grid.is_some() && s.robot.is_some())
        {
            let ((stamp, grid), robot) = (slot.grid.expect("ready"), slot.robot.expect("ready"));
            let regions = frontier_regions(&grid, robot, &self.config)?;
            ctx.send(
                "regions",
                &Frontiers {
                    frame_id: k,
                    stamp,
                    regions,
                },
            )?;
        }
        Ok(Flow::Continue)
    }
}

/// The operator's input ports, named once for registration and dispatch.
pub mod inputs {
    activemap_runtime::ports! {
        GRID = "grid": super::K::OccupancyGrid,
        POSE = "pose": super::K::PoseEstimate
    }
}

/// The operator's output ports, named once for registration and dispatch.
pub mod outputs {
    activemap_runtime::ports! {
        REGIONS = "regions": super::K::Frontiers
    }
}

/// Registry entry.
pub fn registered() -> Registered {
    Registered {
        descriptor: OperatorDescriptor {
            name: "frontier",
            summary: "Reachable frontier regions of the grid: size, centroid, closest reachable cell (SPEC §6)",
            inputs: inputs::ALL,
            outputs: outputs::ALL,
            evaluation: false,
            check_config: check_config_as::<Config>,
        },
        implementation: Some(OperatorImpl::of::<Frontier>()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A hand-made room: free left part, unknown right part behind an open doorway. The only
    /// frontier is the free/unknown boundary column, 5+ cells tall, reachable from the robot.
    #[test]
    fn one_region_on_a_hand_made_grid() {
        let rows = [
            "############",
            "#.......????",
            "#.......????",
            "#.......????",
            "#.......????",
            "#.......????",
            "#.......????",
            "#.......????",
            "############",
        ];
        let grid = PlanGrid::from_ascii(&rows, 0.05).unwrap();
        let robot = grid.geometry.center(activemap_planning::Cell::new(3, 4));
        let config = Config {
            min_region_cells: 5,
            robot_width_cells: Some(3.0),
            robot: RobotModel::default(),
        };
        let regions = frontier_regions(&grid, robot, &config).unwrap();
        assert_eq!(regions.len(), 1, "{regions:?}");
        let r = regions[0];
        // The frontier is the unknown column x = 8 next to the free cells (rows 1..=7).
        assert_eq!(r.size_cells, 7);
        let c = grid.geometry.center(activemap_planning::Cell::new(8, 4));
        assert!(
            (r.centroid[0] - c.x).abs() < 1e-9 && (r.centroid[1] - c.y).abs() < 1e-9,
            "{r:?}"
        );
        // The approach cell is within the approach radius of the frontier, and its path
        // distance is at least the straight line from the robot (and, in this open room, at
        // most the 8-connected path length bound √2 × straight line).
        let a = grid.geometry.center(activemap_planning::Cell::new(
            r.closest_reachable_cell[0],
            r.closest_reachable_cell[1],
        ));
        let straight = (a - robot).norm();
        assert!(
            r.path_distance_m >= straight - 1e-9
                && r.path_distance_m <= std::f64::consts::SQRT_2 * straight + 1e-9,
            "{r:?} straight {straight}"
        );
        // Closing the doorway with a wall leaves nothing to explore.
        let closed: Vec<String> = rows
            .iter()
            .map(|r| r.replacen("#.......?", "#.......#", 1))
            .collect();
        let closed: Vec<&str> = closed.iter().map(|s| s.as_str()).collect();
        let grid = PlanGrid::from_ascii(&closed, 0.05).unwrap();
        assert!(frontier_regions(&grid, robot, &config).unwrap().is_empty());
    }
}
