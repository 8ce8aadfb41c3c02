//! A small 2.5D world for tests and benchmarks of the planning loop without the simulator:
//! a grid of obstacle heights (walls, furniture) over a flat floor under a flat ceiling, an
//! exact depth renderer for it, procedural houses, and the true collision check of a disc robot.

use activemap_geometry::{Intrinsics, Isometry3, PlanarPose};
use nalgebra::{Point2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::dynamics::{Action, RobotModel};
use crate::error::PlanningError;
use crate::grid::{Cell, CellState, Grid, GridGeometry, OccupancyGrid};

/// A 2.5D world: each cell holds the height of its obstacle (0 = floor).
#[derive(Debug, Clone, PartialEq)]
pub struct SyntheticWorld {
    /// Obstacle height per cell, metres above the floor at z = 0.
    pub heights: Grid<f32>,
    /// Ceiling height, metres.
    pub ceiling: f64,
    /// A collision-free start pose.
    pub start: PlanarPose,
}

impl SyntheticWorld {
    /// Cells the robot can stand on: floor cells (height below `min_obstacle`) in the same
    /// 4-connected component as the start.
    pub fn navigable(&self, min_obstacle: f32) -> Grid<bool> {
        let g = self.heights.geometry;
        let mut out = Grid::filled(g, false);
        let s = g.cell_of(Point2::new(self.start.x, self.start.y));
        let mut stack = vec![s];
        while let Some(c) = stack.pop() {
            let Some(i) = g.index(c) else { continue };
            if out.data[i] || self.heights.data[i] >= min_obstacle {
                continue;
            }
            out.data[i] = true;
            stack.extend([
                c.offset(1, 0),
                c.offset(-1, 0),
                c.offset(0, 1),
                c.offset(0, -1),
            ]);
        }
        out
    }

    /// Fraction of navigable cells that `grid` marks free (the release's 2D coverage).
    pub fn coverage(&self, grid: &OccupancyGrid) -> f64 {
        let nav = self.navigable(0.05);
        let g = self.heights.geometry;
        let (mut seen, mut total) = (0usize, 0usize);
        for i in 0..g.len() {
            if nav.data[i] {
                total += 1;
                let p = g.center(g.cell_at(i));
                if grid.get(grid.geometry.cell_of(p)) == Some(&CellState::Free) {
                    seen += 1;
                }
            }
        }
        seen as f64 / total.max(1) as f64
    }

    /// Whether a disc robot of `radius` metres at `p` overlaps an obstacle cell (or leaves the
    /// world).
    pub fn collides(&self, p: Point2<f64>, radius: f64) -> bool {
        let g = self.heights.geometry;
        let (a, b) = (
            g.cell_of(p - nalgebra::Vector2::new(radius, radius)),
            g.cell_of(p + nalgebra::Vector2::new(radius, radius)),
        );
        for y in a.y..=b.y {
            for x in a.x..=b.x {
                let c = Cell::new(x, y);
                let h = self.heights.get(c).copied().unwrap_or(f32::INFINITY);
                if h > 0.05 {
                    // Closest point of the cell square to p.
                    let lo = g.center(c) - nalgebra::Vector2::new(0.5, 0.5) * g.resolution;
                    let q = Point2::new(
                        p.x.clamp(lo.x, lo.x + g.resolution),
                        p.y.clamp(lo.y, lo.y + g.resolution),
                    );
                    if (q - p).norm() < radius {
                        return true;
                    }
                }
            }
        }
        false
    }

    /// Applies `action` with collisions: a forward move into an obstacle does not happen.
    pub fn step(
        &self,
        pose: &PlanarPose,
        action: Action,
        model: &RobotModel,
        radius: f64,
    ) -> PlanarPose {
        let next = model.apply(pose, action);
        if action == Action::Forward && self.collides(Point2::new(next.x, next.y), radius) {
            *pose
        } else {
            next
        }
    }

    /// Renders the z-depth image of the world seen by a camera at `t_world_camera`
    /// (floor, ceiling and obstacle sides and tops are exact; 0 beyond 50 m).
    pub fn render_depth(&self, k: &Intrinsics, t_world_camera: &Isometry3<f64>) -> Vec<f32> {
        let mut out = vec![0f32; k.pixel_count()];
        let o = t_world_camera.translation.vector;
        for v in 0..k.height as usize {
            for u in 0..k.width as usize {
                let rc = k.unproject(u as f64, v as f64, 1.0);
                let d: Vector3<f64> = t_world_camera.rotation * rc.coords;
                out[v * k.width as usize + u] = self.cast(&o, &d) as f32;
            }
        }
        out
    }

    /// Ray parameter `s` (point = o + s·d) of the first surface hit along `d`.
    fn cast(&self, o: &Vector3<f64>, d: &Vector3<f64>) -> f64 {
        let mut s_max = 50.0f64;
        if d.z < -1e-12 {
            s_max = s_max.min(-o.z / d.z);
        } else if d.z > 1e-12 {
            s_max = s_max.min((self.ceiling - o.z) / d.z);
        }
        let g = self.heights.geometry;
        let r = g.resolution;
        let (ux, uy) = ((o.x - g.origin_x) / r, (o.y - g.origin_y) / r);
        let (dx, dy) = (d.x / r, d.y / r);
        let mut cell = Cell::new(ux.floor() as i32, uy.floor() as i32);
        let step_x = if dx > 0.0 { 1 } else { -1 };
        let step_y = if dy > 0.0 { 1 } else { -1 };
        let border = |u: f64, c: i32, st: i32| {
            if st > 0 {
                c as f64 + 1.0 - u
            } else {
                u - c as f64
            }
        };
        let mut t_x = if dx != 0.0 {
            border(ux, cell.x, step_x) / dx.abs()
        } else {
            f64::INFINITY
        };
        let mut t_y = if dy != 0.0 {
            border(uy, cell.y, step_y) / dy.abs()
        } else {
            f64::INFINITY
        };
        let (dt_x, dt_y) = (1.0 / dx.abs(), 1.0 / dy.abs());
        let mut t_in = 0.0f64;
        while t_in < s_max {
            let t_out = t_x.min(t_y).min(s_max);
            let h = match self.heights.get(cell) {
                Some(h) => *h as f64,
                None => return if t_in > 0.0 { t_in } else { 0.0 },
            };
            if h > 0.0 {
                let z_in = o.z + t_in * d.z;
                if z_in <= h {
                    return t_in;
                }
                let z_out = o.z + t_out * d.z;
                if z_out <= h {
                    return (h - o.z) / d.z; // the top face
                }
            }
            t_in = t_out;
            if t_x <= t_y {
                cell.x += step_x;
                t_x += dt_x;
            } else {
                cell.y += step_y;
                t_y += dt_y;
            }
        }
        if s_max < 50.0 { s_max } else { 0.0 }
    }

    /// A procedural house of `rooms_x × rooms_y` rooms of `room_m` metres, with walls (2.5 m
    /// high, 10 cm thick), an 0.8 m door in every interior wall of a spanning tree plus some
    /// extra doors, and a few furniture boxes (0.4–0.8 m high); 5 cm cells. Same seed, same house.
    pub fn procedural_house(
        seed: u64,
        rooms_x: usize,
        rooms_y: usize,
        room_m: f64,
    ) -> Result<Self, PlanningError> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let res = 0.05;
        let room = (room_m / res).round() as i32;
        let (w, h) = (rooms_x as i32 * room + 2, rooms_y as i32 * room + 2);
        let g = GridGeometry::new(0.0, 0.0, res, w as usize, h as usize)?;
        let mut heights = Grid::filled(g, 0f32);
        let wall = 2.5f32;
        let fill = |x0: i32, y0: i32, x1: i32, y1: i32, hgt: f32, grid: &mut Grid<f32>| {
            for y in y0..=y1 {
                for x in x0..=x1 {
                    grid.set(Cell::new(x, y), hgt);
                }
            }
        };
        // Outer walls and interior walls on room borders (2 cells thick).
        for i in 0..=rooms_x as i32 {
            let x = (i * room).min(w - 2);
            fill(x, 0, x + 1, h - 1, wall, &mut heights);
        }
        for j in 0..=rooms_y as i32 {
            let y = (j * room).min(h - 2);
            fill(0, y, w - 1, y + 1, wall, &mut heights);
        }
        // Doors: a random spanning tree over rooms (so every room is reachable) plus extras.
        let door = (0.8 / res) as i32;
        let n = rooms_x * rooms_y;
        let mut connected = vec![false; n];
        connected[0] = true;
        let mut doors: Vec<(usize, usize)> = Vec::new();
        while connected.iter().any(|c| !c) {
            let a = rng.random_range(0..n);
            let (ax, ay) = (a % rooms_x, a / rooms_x);
            let nbrs: Vec<usize> = [(1i32, 0i32), (-1, 0), (0, 1), (0, -1)]
                .iter()
                .filter_map(|(dx, dy)| {
                    let (bx, by) = (ax as i32 + dx, ay as i32 + dy);
                    (bx >= 0 && by >= 0 && bx < rooms_x as i32 && by < rooms_y as i32)
                        .then(|| by as usize * rooms_x + bx as usize)
                })
                .collect();
            let b = nbrs[rng.random_range(0..nbrs.len())];
            let extra = connected[a] && connected[b] && a != b && rng.random_bool(0.05);
            if connected[a] != connected[b] || extra {
                connected[a] = true;
                connected[b] = true;
                doors.push((a.min(b), a.max(b)));
            }
        }
        for (a, b) in doors {
            let (ax, ay) = ((a % rooms_x) as i32, (a / rooms_x) as i32);
            let (bx, by) = ((b % rooms_x) as i32, (b / rooms_x) as i32);
            let offset = rng.random_range(4..(room - door - 4).max(5));
            if ay == by {
                let x = ax.max(bx) * room;
                let y0 = ay * room + offset;
                fill(x, y0, x + 1, y0 + door - 1, 0.0, &mut heights);
            } else {
                let y = ay.max(by) * room;
                let x0 = ax * room + offset;
                fill(x0, y, x0 + door - 1, y + 1, 0.0, &mut heights);
            }
        }
        // Furniture: one or two boxes per room, away from the walls' door zones' centres.
        for j in 0..rooms_y as i32 {
            for i in 0..rooms_x as i32 {
                for _ in 0..rng.random_range(1..3) {
                    let (bw, bh) = (rng.random_range(6..14), rng.random_range(6..14));
                    let x0 = i * room + rng.random_range(8..(room - bw - 8).max(9));
                    let y0 = j * room + rng.random_range(8..(room - bh - 8).max(9));
                    let hgt = rng.random_range(0.4..0.8);
                    fill(x0, y0, x0 + bw - 1, y0 + bh - 1, hgt, &mut heights);
                }
            }
        }
        // Start: the free cell nearest the centre of room 0 with 0.3 m clearance.
        let world = Self {
            heights,
            ceiling: 2.5,
            start: PlanarPose::default(),
        };
        let c = Point2::new(0.5 * room_m, 0.5 * room_m);
        let mut best: Option<(f64, Point2<f64>)> = None;
        for i in 0..g.len() {
            let p = g.center(g.cell_at(i));
            if (p.x < room_m && p.y < room_m) && !world.collides(p, 0.3) {
                let d = (p - c).norm();
                if best.is_none_or(|b| d < b.0) {
                    best = Some((d, p));
                }
            }
        }
        let (_, p) = best.ok_or_else(|| PlanningError::InvalidGrid("no free start cell".into()))?;
        Ok(Self {
            start: PlanarPose::new(p.x, p.y, rng.random_range(-3.0..3.0)),
            ..world
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use activemap_geometry::camera_pose_from_planar;

    #[test]
    fn depth_of_a_wall_matches_the_closed_form() {
        // One wall column at x ∈ [2.0, 2.05), high; camera at 0.88 m facing +x.
        let g = GridGeometry::new(-1.0, -5.0, 0.05, 80, 200).unwrap();
        let mut heights = Grid::filled(g, 0f32);
        for y in 0..200 {
            heights.set(Cell::new(60, y), 2.5);
        }
        let world = SyntheticWorld {
            heights,
            ceiling: 2.5,
            start: PlanarPose::default(),
        };
        let k = Intrinsics::from_hfov(40, 40, std::f64::consts::FRAC_PI_2);
        let cam = camera_pose_from_planar(&PlanarPose::new(0.0, 0.0, 0.0), 0.0, 0.88);
        let depth = world.render_depth(&k, &cam);
        for v in 0..40 {
            for u in 0..40 {
                let rc = k.unproject(u as f64, v as f64, 1.0);
                let d = cam.rotation * rc.coords;
                // Closed form: the first of wall (x = 2.0), floor (z = 0), ceiling (z = 2.5).
                let mut s = 2.0 / d.x;
                if d.z < 0.0 {
                    s = s.min(-0.88 / d.z);
                } else if d.z > 0.0 {
                    s = s.min((2.5 - 0.88) / d.z);
                }
                let got = depth[v * 40 + u] as f64;
                assert!((got - s).abs() < 1e-4, "pixel ({u},{v}): {got} vs {s}");
            }
        }
    }

    #[test]
    fn houses_are_deterministic_connected_and_the_start_is_free() {
        let a = SyntheticWorld::procedural_house(4, 3, 2, 3.0).unwrap();
        let b = SyntheticWorld::procedural_house(4, 3, 2, 3.0).unwrap();
        assert_eq!(a, b);
        assert!(!a.collides(Point2::new(a.start.x, a.start.y), 0.3));
        // Every room centre region is reachable: each room holds navigable cells.
        let nav = a.navigable(0.05);
        let g = a.heights.geometry;
        for j in 0..2 {
            for i in 0..3 {
                let any = (0..g.len()).any(|k| {
                    let p = g.center(g.cell_at(k));
                    nav.data[k]
                        && p.x > i as f64 * 3.0 + 0.2
                        && p.x < (i + 1) as f64 * 3.0 - 0.2
                        && p.y > j as f64 * 3.0 + 0.2
                        && p.y < (j + 1) as f64 * 3.0 - 0.2
                });
                assert!(any, "room ({i},{j}) unreachable");
            }
        }
        // Walking into a wall does not move the robot.
        let model = RobotModel::default();
        let p = PlanarPose::new(0.2, 1.5, std::f64::consts::PI);
        assert_eq!(a.step(&p, Action::Forward, &model, 0.1), p);
    }
}
