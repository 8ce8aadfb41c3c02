//! Frontier-based exploration (Yamauchi 1997; SPEC §6 baseline): which frontier region to visit
//! next, and which goals to stop trying. [`FbePlanner`] (the decision per replan request, over
//! the one decision state [`FbeState`]) is what both the in-process
//! `activemap_policy::explorer::Explorer` and the `planner` operator call:
//!
//! - ranking ([`FbePolicy`]): the nearest region by path length, the largest, or (default) the
//!   best utility = size / (path cost + turn cost + offset), which prefers large frontiers
//!   (doorways) over small pockets along the walls;
//! - strikes: a goal whose region is still there after a visit gets one strike, two when the
//!   region did not shrink at all (it cannot be observed from its approach cell), two when the
//!   goal failed (no path, stuck). A region whose approach cell has
//!   [`FbeConfig::strikes_to_ban`] strikes nearby is skipped;
//! - amnesty: when every reachable region is banned while the map still grows, the strikes are
//!   forgiven (estimated poses shift the map, so a goal that failed may work now).
//!
//! No reachable, unbanned region and nothing to forgive ends an FBE episode.

use activemap_geometry::PlanarPose;
use nalgebra::Point2;
use serde::{Deserialize, Serialize};

use crate::dynamics::{RobotModel, wrap_angle};
use crate::error::{PlanningError, require};
use crate::frontier::FrontierRegion;
use crate::grid::{Cell, CellState, GridGeometry, OccupancyGrid};
use crate::replan::ReplanReason;

/// How FBE ranks reachable frontier regions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FbePolicy {
    /// Smallest path distance to the approach cell (ties: larger region).
    Nearest,
    /// Most cells (ties: nearer).
    Largest,
    /// Highest size / (path distance + turn cost + [`FbeConfig::cost_offset_m`]): large
    /// frontiers win over small pockets unless these are much nearer (ties: nearer).
    Utility,
}

/// Settings of the FBE decision state.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FbeConfig {
    /// The ranking.
    pub policy: FbePolicy,
    /// A strike bans approach cells within this many cells of the struck goal.
    pub exclusion_radius_cells: f64,
    /// Strikes near an approach cell that ban its region (≥ 1).
    pub strikes_to_ban: usize,
    /// Metres of driving one radian of turning on the spot costs: the forward step over the
    /// turn step (0.05 m / 5° ≈ 0.573 m/rad, so a 180° turn = 36 steps = 1.8 m).
    pub turn_cost_m_per_rad: f64,
    /// Added to every region's cost in the utility ranking, metres: keeps a tiny pocket right
    /// next to the robot from beating a doorway a few metres away (3 m: with 1 m, the real loop
    /// on house 1 kept choosing 100-cell pockets 3 m away over a 338-cell corridor 12 m away,
    /// 103/4.2 against 338/13.7, and never explored the corridor in 2000 steps; in-process
    /// episodes on houses 1–3 reach 85 % as fast or faster with 3 m).
    pub cost_offset_m: f64,
    /// Whether a reached goal whose region did not shrink is banned at once
    /// ([`FbeConfig::strikes_to_ban`] strikes) instead of struck once per visit.
    pub ban_unshrunk_at_once: bool,
    /// A reached goal whose region (the one whose approach cell is still within the exclusion
    /// radius) kept at least this fraction of its cells did not shrink.
    pub no_shrink_fraction: f64,
}

impl Default for FbeConfig {
    fn default() -> Self {
        let m = RobotModel::default();
        Self {
            policy: FbePolicy::Utility,
            exclusion_radius_cells: 3.0,
            strikes_to_ban: 2,
            turn_cost_m_per_rad: m.forward_step_m / m.turn_angle_rad,
            cost_offset_m: 3.0,
            ban_unshrunk_at_once: true,
            no_shrink_fraction: 0.9,
        }
    }
}

impl FbeConfig {
    /// Checks the ranges of every field.
    pub fn validate(&self) -> Result<(), PlanningError> {
        require(
            self.exclusion_radius_cells.is_finite() && self.exclusion_radius_cells >= 0.0,
            "FbeConfig::exclusion_radius_cells",
            "must be finite and non-negative",
        )?;
        require(
            self.strikes_to_ban >= 1,
            "FbeConfig::strikes_to_ban",
            "must be at least 1",
        )?;
        require(
            self.turn_cost_m_per_rad.is_finite() && self.turn_cost_m_per_rad >= 0.0,
            "FbeConfig::turn_cost_m_per_rad",
            "must be finite and non-negative",
        )?;
        require(
            self.cost_offset_m.is_finite() && self.cost_offset_m > 0.0,
            "FbeConfig::cost_offset_m",
            "must be finite and positive",
        )?;
        require(
            self.no_shrink_fraction.is_finite()
                && self.no_shrink_fraction > 0.0
                && self.no_shrink_fraction <= 1.0,
            "FbeConfig::no_shrink_fraction",
            "must be in (0, 1]",
        )
    }
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

/// How the last goal ended, as the follower saw it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum GoalOutcome {
    /// The robot got there (and looked at the frontier).
    Reached,
    /// No path, or the robot got stuck on the way: two strikes.
    Failed,
    /// Given up for a reason that says nothing about the goal (an obstacle appeared on the
    /// path, tracking was lost): no strike.
    Abandoned,
}

/// The goal being pursued, remembered to judge its outcome.
#[derive(Debug, Clone, Copy, PartialEq)]
struct PendingGoal {
    /// World centre of the approach cell.
    approach: Point2<f64>,
    /// Region size when chosen, cells.
    size: usize,
}

/// The FBE decision state (strikes, amnesty, ranking), shared by the explorer and the
/// `planner` operator. Strikes are kept as world points, so they survive grid growth.
#[derive(Debug, Clone, PartialEq)]
pub struct FbeState {
    config: FbeConfig,
    strikes: Vec<Point2<f64>>,
    pending: Option<PendingGoal>,
    free_at_last_amnesty: usize,
    /// Times the strikes were forgiven.
    pub amnesties: usize,
    /// Reached goals whose region did not shrink (struck twice at once).
    pub unobservable_goals: usize,
}

impl FbeState {
    /// A state with no strikes.
    pub fn new(config: FbeConfig) -> Result<Self, PlanningError> {
        config.validate()?;
        Ok(Self {
            config,
            strikes: Vec::new(),
            pending: None,
            free_at_last_amnesty: 0,
            amnesties: 0,
            unobservable_goals: 0,
        })
    }

    /// The settings.
    pub fn config(&self) -> &FbeConfig {
        &self.config
    }

    /// Struck goals (world points), one entry per strike.
    pub fn strikes(&self) -> &[Point2<f64>] {
        &self.strikes
    }

    /// Records how the last chosen goal ended, judged against the current `regions` (on a grid
    /// with `geometry`); returns the strikes added. Without a pending goal it does nothing.
    pub fn record(
        &mut self,
        outcome: GoalOutcome,
        regions: &[FrontierRegion],
        geometry: &GridGeometry,
    ) -> usize {
        let Some(goal) = self.pending.take() else {
            return 0;
        };
        let strikes = match outcome {
            GoalOutcome::Abandoned => 0,
            GoalOutcome::Failed => self.config.strikes_to_ban,
            GoalOutcome::Reached if !self.config.ban_unshrunk_at_once => 1,
            GoalOutcome::Reached => {
                let radius = self.config.exclusion_radius_cells * geometry.resolution;
                let remaining = regions
                    .iter()
                    .filter(|r| {
                        r.approach.is_some_and(|a| {
                            (geometry.center(a.cell) - goal.approach).norm() <= radius
                        })
                    })
                    .map(FrontierRegion::size)
                    .max()
                    .unwrap_or(0);
                if remaining as f64 >= self.config.no_shrink_fraction * goal.size as f64 {
                    self.unobservable_goals += 1;
                    self.config.strikes_to_ban
                } else {
                    1
                }
            }
        };
        self.strikes
            .extend(std::iter::repeat_n(goal.approach, strikes));
        strikes
    }

    /// Chooses among `regions` (on a grid with `geometry`, the robot at `robot`) by the policy,
    /// skipping banned ones, and remembers the choice as the pending goal. `None`: no reachable
    /// region is left unbanned (see [`FbeState::forgive`]).
    pub fn choose(
        &mut self,
        regions: &[FrontierRegion],
        geometry: &GridGeometry,
        robot: &PlanarPose,
    ) -> Option<FbeGoal> {
        let excluded: Vec<Cell> = self.strikes.iter().map(|p| geometry.cell_of(*p)).collect();
        let turn_cost = |cell: Cell, region: &FrontierRegion| {
            let here = Point2::new(robot.x, robot.y);
            let mut target = geometry.center(cell);
            if (target - here).norm() < geometry.resolution {
                target = region.centroid;
            }
            let bearing = (target.y - here.y).atan2(target.x - here.x);
            self.config.turn_cost_m_per_rad * wrap_angle(bearing - robot.yaw).abs()
        };
        let goal = choose_frontier(
            regions,
            self.config.policy,
            &excluded,
            self.config.exclusion_radius_cells,
            self.config.strikes_to_ban,
            self.config.cost_offset_m,
            turn_cost,
        )?;
        self.pending = Some(PendingGoal {
            approach: geometry.center(goal.cell),
            size: regions[goal.region].size(),
        });
        Some(goal)
    }

    /// Indices of the `regions` (on a grid with `geometry`) a goal may go to now: those with
    /// an approach cell that the strikes do not ban (the rule [`FbeState::choose`] applies), in
    /// their order. For a choice made elsewhere (the LLM's, SPEC §7).
    pub fn eligible(&self, regions: &[FrontierRegion], geometry: &GridGeometry) -> Vec<usize> {
        let excluded: Vec<Cell> = self.strikes.iter().map(|p| geometry.cell_of(*p)).collect();
        regions
            .iter()
            .enumerate()
            .filter(|(_, r)| {
                r.approach.is_some_and(|a| {
                    !is_banned(
                        a.cell,
                        &excluded,
                        self.config.exclusion_radius_cells,
                        self.config.strikes_to_ban,
                    )
                })
            })
            .map(|(i, _)| i)
            .collect()
    }

    /// Remembers `regions[index]` (which must have an approach cell) as the pending goal, so
    /// that its outcome is judged at the next replan as if [`FbeState::choose`] had chosen it.
    pub fn commit(&mut self, regions: &[FrontierRegion], index: usize, geometry: &GridGeometry) {
        self.pending = regions[index].approach.map(|a| PendingGoal {
            approach: geometry.center(a.cell),
            size: regions[index].size(),
        });
    }

    /// Forgets the pending goal (a refine goal was sent instead: nothing to judge).
    pub fn clear_pending(&mut self) {
        self.pending = None;
    }

    /// When nothing is left to choose: forgives every strike if there are any and the map grew
    /// (`free_cells` free cells now) since the last amnesty. True when it forgave (choose again).
    pub fn forgive(&mut self, free_cells: usize) -> bool {
        if self.strikes.is_empty() || free_cells <= self.free_at_last_amnesty {
            return false;
        }
        self.free_at_last_amnesty = free_cells;
        self.strikes.clear();
        self.pending = None;
        self.amnesties += 1;
        true
    }
}

/// How the executor's replan `reason` judges the last goal: reached when the path is done,
/// failed when no path was found or the robot got stuck, abandoned (no strike) otherwise.
pub fn outcome(reason: ReplanReason) -> GoalOutcome {
    match reason {
        ReplanReason::PathDone => GoalOutcome::Reached,
        ReplanReason::NoPath | ReplanReason::Stuck => GoalOutcome::Failed,
        ReplanReason::Startup
        | ReplanReason::GoalOccupied
        | ReplanReason::PathBlocked { .. }
        | ReplanReason::ObstacleAhead
        | ReplanReason::TrackingLost
        | ReplanReason::Blocked => GoalOutcome::Abandoned,
    }
}

/// The goal FBE chose at a replan request.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FbeChoice {
    /// Index into the regions slice.
    pub region: usize,
    /// The region's approach cell: where the path goes.
    pub cell: Cell,
    /// The region's centroid: what the robot faces at the end of the path.
    pub focus: Point2<f64>,
}

/// The FBE decision made at each replan request, shared by the `planner` operator and the
/// in-process explorer so that both choose the same goals.
#[derive(Debug, Clone, PartialEq)]
pub struct FbePlanner {
    state: FbeState,
}

impl FbePlanner {
    /// A planner with no strikes.
    pub fn new(config: FbeConfig) -> Result<Self, PlanningError> {
        Ok(Self {
            state: FbeState::new(config)?,
        })
    }

    /// The decision state (strikes, amnesties).
    pub fn state(&self) -> &FbeState {
        &self.state
    }

    /// For a choice made elsewhere (the LLM's): judges the last goal by `reason` as
    /// [`FbePlanner::choose`] does, then returns the indices of the regions eligible now
    /// ([`FbeState::eligible`]), forgiving the strikes (once per growth of the map) when none
    /// is. Empty: nothing is left to explore. Tell the choice with [`FbePlanner::commit`].
    pub fn eligible(
        &mut self,
        reason: ReplanReason,
        grid: &OccupancyGrid,
        regions: &[FrontierRegion],
    ) -> Vec<usize> {
        self.state.record(outcome(reason), regions, &grid.geometry);
        let mut eligible = self.state.eligible(regions, &grid.geometry);
        if eligible.is_empty() && self.state.forgive(grid.count(CellState::Free)) {
            eligible = self.state.eligible(regions, &grid.geometry);
        }
        eligible
    }

    /// Remembers the region chosen among [`FbePlanner::eligible`] as the pending goal, or
    /// none (`None`: a refine goal) so that no strike follows.
    pub fn commit(
        &mut self,
        regions: &[FrontierRegion],
        chosen: Option<usize>,
        grid: &OccupancyGrid,
    ) {
        match chosen {
            Some(i) => self.state.commit(regions, i, &grid.geometry),
            None => self.state.clear_pending(),
        }
    }

    /// Judges the last goal by the executor's `reason` against the current `regions` (the
    /// reachable ones, [`crate::frontier::reachable_regions`]) of `grid`, then chooses among
    /// them for the robot at `robot`. When every region is banned the strikes are forgiven,
    /// once per growth of the map's free cells, and it chooses again. `None`: nothing is left
    /// to explore (the episode is over).
    pub fn choose(
        &mut self,
        reason: ReplanReason,
        grid: &OccupancyGrid,
        regions: &[FrontierRegion],
        robot: &PlanarPose,
    ) -> Option<FbeChoice> {
        self.state.record(outcome(reason), regions, &grid.geometry);
        let mut goal = self.state.choose(regions, &grid.geometry, robot);
        if goal.is_none() && self.state.forgive(grid.count(CellState::Free)) {
            goal = self.state.choose(regions, &grid.geometry, robot);
        }
        let goal = goal?;
        Some(FbeChoice {
            region: goal.region,
            cell: goal.cell,
            focus: regions[goal.region].centroid,
        })
    }
}

/// True when at least `strikes` (> 0) cells of `excluded` lie within `exclusion_radius_cells`
/// of `cell`: a goal there is banned.
fn is_banned(cell: Cell, excluded: &[Cell], exclusion_radius_cells: f64, strikes: usize) -> bool {
    let hits = excluded
        .iter()
        .filter(|e| e.distance(&cell) <= exclusion_radius_cells)
        .count();
    strikes > 0 && hits >= strikes
}

/// Picks a region by `policy`, skipping regions without an approach cell and regions whose
/// approach cell has at least `strikes` cells of `excluded` (goals struck, a cell listed once
/// per strike) within `exclusion_radius_cells`. The utility policy adds `turn_cost(approach,
/// region)` metres and `cost_offset_m` to the path distance. Ties fall back to the lower index,
/// so the choice is deterministic.
pub fn choose_frontier(
    regions: &[FrontierRegion],
    policy: FbePolicy,
    excluded: &[Cell],
    exclusion_radius_cells: f64,
    strikes: usize,
    cost_offset_m: f64,
    turn_cost: impl Fn(Cell, &FrontierRegion) -> f64,
) -> Option<FbeGoal> {
    let candidates = regions.iter().enumerate().filter_map(|(i, r)| {
        let a = r.approach?;
        let banned = is_banned(a.cell, excluded, exclusion_radius_cells, strikes);
        (!banned).then_some((i, r.size(), a, r))
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
        FbePolicy::Utility => candidates
            .map(|c| {
                let cost = c.2.path_distance_m + turn_cost(c.2.cell, c.3) + cost_offset_m;
                (c, c.1 as f64 / cost)
            })
            .min_by(|(x, ux), (y, uy)| {
                uy.total_cmp(ux)
                    .then(x.2.path_distance_m.total_cmp(&y.2.path_distance_m))
                    .then(x.0.cmp(&y.0))
            })
            .map(|(c, _)| c),
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

    fn no_turn(_: Cell, _: &FrontierRegion) -> f64 {
        0.0
    }

    fn geometry() -> GridGeometry {
        GridGeometry {
            origin_x: 0.0,
            origin_y: 0.0,
            resolution: 0.05,
            width: 100,
            height: 100,
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
        let choose = |policy, excluded: &[Cell], radius, strikes| {
            choose_frontier(&regions, policy, excluded, radius, strikes, 1.0, no_turn)
        };
        let n = choose(FbePolicy::Nearest, &[], 0.0, 1).unwrap();
        assert_eq!(
            (n.region, n.cell, n.path_distance_m),
            (3, Cell::new(20, 5), 1.0)
        );
        let l = choose(FbePolicy::Largest, &[], 0.0, 1).unwrap();
        assert_eq!(
            l.region, 1,
            "the largest reachable one, not the unreachable 50"
        );
        let one = [Cell::new(21, 5)];
        assert_eq!(choose(FbePolicy::Nearest, &one, 2.0, 1).unwrap().region, 0);
        // One strike of two needed: not yet banned; a strike farther than the radius never counts.
        assert_eq!(choose(FbePolicy::Nearest, &one, 2.0, 2).unwrap().region, 3);
        let two = [Cell::new(21, 5), Cell::new(20, 6)];
        assert_eq!(choose(FbePolicy::Nearest, &two, 2.0, 2).unwrap().region, 0);
        let far = [Cell::new(24, 5), Cell::new(24, 5)];
        assert_eq!(choose(FbePolicy::Nearest, &far, 2.0, 2).unwrap().region, 3);
        assert!(
            choose_frontier(
                &regions[2..3],
                FbePolicy::Nearest,
                &[],
                0.0,
                1,
                1.0,
                no_turn
            )
            .is_none()
        );
        assert!(choose_frontier(&[], FbePolicy::Largest, &[], 0.0, 1, 1.0, no_turn).is_none());
    }

    /// Utility = size / (path + turn + offset), worked by hand: a 6-cell pocket 0.2 m away
    /// (6 / 1.2 = 5.0) loses to a 40-cell doorway 3 m away (40 / 4 = 10), which the nearest
    /// policy would not pick; a 180° turn (π × 0.573 m/rad = 1.8 m) in front of the doorway
    /// (40 / 5.8 = 6.9) still beats the pocket, but an 11-cell pocket (11 / 1.2 = 9.2) wins
    /// over the turned-away doorway, and loses to it without the turn (9.2 vs 10).
    #[test]
    fn utility_prefers_large_frontiers_and_counts_the_turn() {
        let regions = vec![region(6, Some((0, 0.2))), region(40, Some((30, 3.0)))];
        let pick = |regions: &[FrontierRegion], turn: &dyn Fn(Cell, &FrontierRegion) -> f64| {
            choose_frontier(regions, FbePolicy::Utility, &[], 0.0, 2, 1.0, turn)
                .unwrap()
                .region
        };
        assert_eq!(pick(&regions, &no_turn), 1);
        let nearest = choose_frontier(&regions, FbePolicy::Nearest, &[], 0.0, 2, 1.0, no_turn);
        assert_eq!(nearest.unwrap().region, 0);
        let per_rad = FbeConfig::default().turn_cost_m_per_rad;
        assert!((per_rad * std::f64::consts::PI - 1.8).abs() < 1e-12);
        let behind_doorway = |c: Cell, _: &FrontierRegion| {
            if c.x == 30 {
                per_rad * std::f64::consts::PI
            } else {
                0.0
            }
        };
        assert_eq!(pick(&regions, &behind_doorway), 1);
        let bigger_pocket = vec![region(11, Some((0, 0.2))), region(40, Some((30, 3.0)))];
        assert_eq!(pick(&bigger_pocket, &behind_doorway), 0);
        assert_eq!(pick(&bigger_pocket, &no_turn), 1);
    }

    /// The state computes the turn from the robot's heading: with the robot facing away from a
    /// doorway and toward an equal-sized region at the same distance, it picks the one ahead.
    #[test]
    fn state_ranks_by_the_heading_change_at_the_start() {
        let g = geometry();
        let mut ahead = region(20, Some((0, 1.0)));
        let mut behind = region(20, Some((0, 1.0)));
        // Robot at (2.5, 2.5) facing +x; approach cells 1 m ahead and 1 m behind.
        ahead.approach.as_mut().unwrap().cell = g.cell_of(Point2::new(3.5, 2.5));
        behind.approach.as_mut().unwrap().cell = g.cell_of(Point2::new(1.5, 2.5));
        let robot = PlanarPose::new(2.5, 2.5, 0.0);
        let mut s = FbeState::new(FbeConfig::default()).unwrap();
        assert_eq!(
            s.choose(&[behind.clone(), ahead.clone()], &g, &robot)
                .unwrap()
                .region,
            1
        );
        let facing_back = PlanarPose::new(2.5, 2.5, std::f64::consts::PI);
        assert_eq!(
            s.choose(&[behind, ahead], &g, &facing_back).unwrap().region,
            0
        );
    }

    /// A reached goal whose region is still there at full size is banned at once (two strikes);
    /// one whose region shrank gets one strike and stays eligible; a failure counts two; an
    /// abandoned goal none.
    #[test]
    fn reached_goal_whose_region_did_not_shrink_is_banned_at_once() {
        let g = geometry();
        let robot = PlanarPose::new(0.0, 0.0, 0.0);
        let pocket = region(20, Some((10, 1.0)));
        let doorway = region(10, Some((60, 2.0)));
        let regions = vec![pocket.clone(), doorway.clone()];
        let config = FbeConfig {
            policy: FbePolicy::Nearest,
            ..FbeConfig::default()
        };
        let mut s = FbeState::new(config).unwrap();
        assert_eq!(s.choose(&regions, &g, &robot).unwrap().region, 0);
        // Back at the pocket after the visit: unchanged.
        assert_eq!(s.record(GoalOutcome::Reached, &regions, &g), 2);
        assert_eq!(s.unobservable_goals, 1);
        assert_eq!(
            s.choose(&regions, &g, &robot).unwrap().region,
            1,
            "the unobservable pocket must be banned after one visit"
        );
        // The doorway's region shrank to 5 cells: one strike, still the nearest eligible.
        let shrunk = vec![pocket.clone(), region(5, Some((60, 2.0)))];
        assert_eq!(s.record(GoalOutcome::Reached, &shrunk, &g), 1);
        assert_eq!(s.choose(&shrunk, &g, &robot).unwrap().region, 1);
        assert_eq!(s.record(GoalOutcome::Abandoned, &shrunk, &g), 0);
        assert_eq!(s.choose(&shrunk, &g, &robot).unwrap().region, 1);
        assert_eq!(s.record(GoalOutcome::Failed, &shrunk, &g), 2);
        assert!(s.choose(&shrunk, &g, &robot).is_none());
        // Nothing pending any more: recording again changes nothing.
        assert_eq!(s.record(GoalOutcome::Failed, &shrunk, &g), 0);
        // Amnesty only when the map grew.
        assert!(s.forgive(100));
        assert!(s.strikes().is_empty());
        assert!(s.choose(&shrunk, &g, &robot).is_some());
        assert_eq!(s.record(GoalOutcome::Failed, &shrunk, &g), 2);
        assert!(!s.forgive(100), "the map did not grow");
        assert!(s.forgive(101));
        assert_eq!(s.amnesties, 2);
    }

    /// A choice made elsewhere (the LLM's) follows the same rules: eligible are the regions
    /// with an approach that no strikes ban; a committed goal that failed is struck and drops
    /// out; a refine goal (nothing committed) strikes nothing.
    #[test]
    fn eligible_regions_and_committed_goals_follow_the_strike_rules() {
        let g = geometry();
        let regions = vec![
            region(20, Some((10, 1.0))),
            region(30, None),
            region(10, Some((60, 2.0))),
        ];
        let mut s = FbeState::new(FbeConfig::default()).unwrap();
        assert_eq!(
            s.eligible(&regions, &g),
            vec![0, 2],
            "no approach, not eligible"
        );
        s.commit(&regions, 2, &g);
        assert_eq!(s.record(GoalOutcome::Failed, &regions, &g), 2);
        assert_eq!(s.eligible(&regions, &g), vec![0]);
        s.commit(&regions, 0, &g);
        s.clear_pending();
        assert_eq!(
            s.record(GoalOutcome::Failed, &regions, &g),
            0,
            "nothing pending"
        );
        assert_eq!(s.eligible(&regions, &g), vec![0]);
    }

    #[test]
    fn bad_config_is_refused_with_its_field() {
        let bad = FbeConfig {
            strikes_to_ban: 0,
            ..FbeConfig::default()
        };
        let e = FbeState::new(bad).unwrap_err().to_string();
        assert!(e.contains("strikes_to_ban"), "{e}");
        let bad = FbeConfig {
            no_shrink_fraction: 1.5,
            ..FbeConfig::default()
        };
        let e = FbeState::new(bad).unwrap_err().to_string();
        assert!(e.contains("no_shrink_fraction"), "{e}");
    }
}
