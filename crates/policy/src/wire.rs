//! Conversions between the planning library's types and the messages the policies take and
//! give. The operators send these messages; the explorer converts its own regions, reasons and
//! paths the same way, so that both feed the policies the same values.

use activemap_planning::OccupancyGrid;
use activemap_planning::frontier::{Approach, FrontierRegion as PlanRegion};
use activemap_planning::grid::Cell;
use activemap_planning::path::PlannedPath;
use activemap_planning::replan::ReplanReason as PlanReason;
use activemap_schemas::{FrontierRegion, Frontiers, Path, PlanarPose2, ReplanReason};
use nalgebra::Point2;

/// The wire regions of the library's reachable `regions` of `grid` (largest first, as the
/// library orders them), with ids 0..N−1 in that order; a region without an approach cell is
/// left out.
pub fn regions_to_wire(grid: &OccupancyGrid, regions: &[PlanRegion]) -> Vec<FrontierRegion> {
    let mut wire: Vec<FrontierRegion> = regions
        .iter()
        .filter_map(|r| {
            let a = r.approach?;
            Some(FrontierRegion {
                id: 0,
                size_cells: r.size() as u32,
                centroid: [r.centroid.x, r.centroid.y],
                closest_reachable_cell: [a.cell.x, a.cell.y],
                path_distance_m: a.path_distance_m,
                anchor: {
                    let c = grid.geometry.center(r.anchor);
                    [c.x, c.y]
                },
            })
        })
        .collect();
    for (i, r) in wire.iter_mut().enumerate() {
        r.id = i as u32;
    }
    wire
}

/// Library regions from the wire summaries (the FBE decision reads the size, the centroid and
/// the approach cell with its path distance).
pub fn regions_from_wire(frontiers: &Frontiers) -> Vec<PlanRegion> {
    frontiers
        .regions
        .iter()
        .map(|r| {
            let cell = Cell::new(r.closest_reachable_cell[0], r.closest_reachable_cell[1]);
            PlanRegion {
                cells: vec![cell; r.size_cells as usize],
                centroid: Point2::new(r.centroid[0], r.centroid[1]),
                anchor: cell,
                approach: r.path_distance_m.is_finite().then_some(Approach {
                    cell,
                    path_distance_m: r.path_distance_m,
                }),
            }
        })
        .collect()
}

/// The executor's replan reason on the wire: the three map triggers (goal occupied, path
/// blocked, obstacle ahead) are all `ObstacleAhead` there.
pub fn reason_to_wire(reason: PlanReason) -> ReplanReason {
    match reason {
        PlanReason::Startup => ReplanReason::Startup,
        PlanReason::PathDone => ReplanReason::PathDone,
        PlanReason::GoalOccupied | PlanReason::PathBlocked { .. } | PlanReason::ObstacleAhead => {
            ReplanReason::ObstacleAhead
        }
        PlanReason::NoPath => ReplanReason::NoPath,
        PlanReason::Stuck => ReplanReason::Stuck,
        PlanReason::TrackingLost => ReplanReason::TrackingLost,
        PlanReason::Blocked => ReplanReason::Blocked,
    }
}

/// The library's replan reason of a wire one (the map triggers come back as `ObstacleAhead`,
/// which the goal choice judges like the others: the goal was abandoned).
pub fn reason_from_wire(reason: ReplanReason) -> PlanReason {
    match reason {
        ReplanReason::Startup => PlanReason::Startup,
        ReplanReason::PathDone => PlanReason::PathDone,
        ReplanReason::ObstacleAhead => PlanReason::ObstacleAhead,
        ReplanReason::NoPath => PlanReason::NoPath,
        ReplanReason::Stuck => PlanReason::Stuck,
        ReplanReason::TrackingLost => PlanReason::TrackingLost,
        ReplanReason::Blocked => PlanReason::Blocked,
    }
}

/// A planned path as the wire path of frame `frame_id`.
pub fn path_to_wire(frame_id: u64, path: &PlannedPath) -> Path {
    Path {
        frame_id,
        waypoints: path
            .waypoints
            .iter()
            .map(|w| PlanarPose2 {
                x: w.x,
                y: w.y,
                yaw: w.yaw,
            })
            .collect(),
        objective: path.cost,
    }
}
