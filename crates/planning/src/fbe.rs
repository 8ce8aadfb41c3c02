//! Frontier-based exploration (Yamauchi 1997; SPEC §6 baseline): choose the frontier region
//! to visit — the nearest by path length, or the largest — among the regions the robot can
//! reach. `None` means no reachable frontier is left, which ends an FBE episode.

use serde::{Deserialize, Serialize};

use crate::frontier::FrontierRegion;
use crate::grid::Cell;

/// How FBE ranks reachable frontier regions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum FbePolicy {
    /// Smallest path distance to the approach cell (ties: larger region).
    Nearest,
    /// Most cells (ties: nearer).
    Largest,
}

/// The chosen region and where to drive.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FbeGoal {
    /// Index into the regions slice.
    pub region: usize,
    /// The approach cell of that region (the A* goal).
    pub cell: Cell,
    /// Path distance to it, metres.
    pub path_distance_m: f64,
}

/// Picks a region by `policy`, skipping regions without an approach cell and regions whose
/// approach cell has at least `strikes` cells of `excluded` (goals already visited or failed,
/// a cell listed once per strike) within `exclusion_radius_cells`. Ties fall back to the lower
/// index, so the choice is deterministic.
pub fn choose_frontier(
    regions: &[FrontierRegion],
    policy: FbePolicy,
    excluded: &[Cell],
    exclusion_radius_cells: f64,
    strikes: usize,
) -> Option<FbeGoal> {
    let candidates = regions.iter().enumerate().filter_map(|(i, r)| {
        let a = r.approach?;
        let hits = excluded
            .iter()
            .filter(|e| e.distance(&a.cell) <= exclusion_radius_cells)
            .count();
        let banned = strikes > 0 && hits >= strikes;
        (!banned).then_some((i, r.size(), a))
    });
    let best = match policy {
        FbePolicy::Nearest => candidates.min_by(|x, y| {
            x.2.path_distance_m
                .total_cmp(&y.2.path_distance_m)
                .then(y.1.cmp(&x.1))
                .then(x.0.cmp(&y.0))
        }),
        FbePolicy::Largest => candidates.min_by(|x, y| {
            y.1.cmp(&x.1)
                .then(x.2.path_distance_m.total_cmp(&y.2.path_distance_m))
                .then(x.0.cmp(&y.0))
        }),
    }?;
    Some(FbeGoal {
        region: best.0,
        cell: best.2.cell,
        path_distance_m: best.2.path_distance_m,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frontier::Approach;
    use nalgebra::Point2;

    fn region(size: usize, approach: Option<(i32, f64)>) -> FrontierRegion {
        FrontierRegion {
            cells: (0..size as i32).map(|x| Cell::new(x, 0)).collect(),
            centroid: Point2::origin(),
            anchor: Cell::new(0, 0),
            approach: approach.map(|(x, d)| Approach {
                cell: Cell::new(x, 5),
                path_distance_m: d,
            }),
        }
    }

    #[test]
    fn nearest_and_largest_policies_pick_the_right_region() {
        let regions = vec![
            region(10, Some((0, 2.0))),
            region(30, Some((10, 5.0))),
            region(50, None),
            region(8, Some((20, 1.0))),
        ];
        let n = choose_frontier(&regions, FbePolicy::Nearest, &[], 0.0, 1).unwrap();
        assert_eq!(
            (n.region, n.cell, n.path_distance_m),
            (3, Cell::new(20, 5), 1.0)
        );
        let l = choose_frontier(&regions, FbePolicy::Largest, &[], 0.0, 1).unwrap();
        assert_eq!(
            l.region, 1,
            "the largest reachable one, not the unreachable 50"
        );
        let one = [Cell::new(21, 5)];
        let skip = choose_frontier(&regions, FbePolicy::Nearest, &one, 2.0, 1);
        assert_eq!(skip.unwrap().region, 0);
        // One strike of two needed: not yet banned; a strike farther than the radius never counts.
        let keep = choose_frontier(&regions, FbePolicy::Nearest, &one, 2.0, 2);
        assert_eq!(keep.unwrap().region, 3);
        let two = [Cell::new(21, 5), Cell::new(20, 6)];
        assert_eq!(
            choose_frontier(&regions, FbePolicy::Nearest, &two, 2.0, 2)
                .unwrap()
                .region,
            0
        );
        let far = [Cell::new(24, 5), Cell::new(24, 5)];
        assert_eq!(
            choose_frontier(&regions, FbePolicy::Nearest, &far, 2.0, 2)
                .unwrap()
                .region,
            3
        );
        assert!(choose_frontier(&regions[2..3], FbePolicy::Nearest, &[], 0.0, 1).is_none());
        assert!(choose_frontier(&[], FbePolicy::Largest, &[], 0.0, 1).is_none());
    }
}
