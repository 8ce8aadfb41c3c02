//! Where the agent may stand: the floor height, the obstacles in the agent's height band, the
//! navigable top-down grid and the Habitat-style motion model.
//!
//! The agent is an upright cylinder (radius `r`, height `h`) standing on the floor plane
//! `z = floor_z`. Every triangle part in the band `floor_z + max_climb ≤ z ≤ floor_z + h` is an
//! obstacle; its projection onto the floor is a 2D triangle. A position is *navigable* when a
//! horizontal floor surface lies under it and the disc of radius `r` around it touches no
//! obstacle. The navigable map samples that predicate at the centres of a grid of cells
//! (5 cm by default), so the map and the motion agree.

use crate::error::{Result, SimError};
use crate::scene::Scene;
use activemap_geometry::PlanarPose;
use std::collections::VecDeque;

/// Free space a derived start pose keeps around the robot where the floor allows, metres
/// (from the robot's centre to the nearest cell it may not stand on, so about this much plus
/// the robot's radius to the nearest obstacle).
pub const START_CLEARANCE_M: f64 = 0.5;

/// The agent's collision cylinder.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AgentShape {
    /// Cylinder radius, metres (Habitat default 0.1).
    pub radius: f64,
    /// Cylinder height, metres (Habitat default 1.5).
    pub height: f64,
    /// Geometry lower than this above the floor is stepped over, metres.
    pub max_climb: f64,
}

impl Default for AgentShape {
    /// Radius 0.1 m, height 1.5 m, climb 0.15 m.
    fn default() -> Self {
        Self {
            radius: activemap_geometry::RobotModel::default().radius_m,
            height: 1.5,
            max_climb: 0.15,
        }
    }
}

/// The floor height of a mesh: among near-horizontal triangles in the lower half of the scene,
/// the area-weighted 2 cm height bin with the most area (the highest of bins within half of the
/// maximum, so a floor slab's top face wins over its bottom face).
pub fn estimate_floor_z(scene: &Scene) -> Option<f64> {
    let bounds = scene.bounds()?;
    let mid = 0.5 * (bounds.min.z + bounds.max.z);
    let bin = 0.02;
    let mut bins: std::collections::BTreeMap<i64, f64> = Default::default();
    for t in &scene.triangles {
        let n = scene.scaled_normal(t);
        let len = n.norm();
        if len == 0.0 || n.z.abs() < 0.95 * len {
            continue;
        }
        let [a, b, c] = scene.corners(t);
        let z = (a.z + b.z + c.z) / 3.0;
        if z > mid && bounds.max.z - bounds.min.z > 0.5 {
            continue;
        }
        *bins.entry((z / bin).round() as i64).or_default() += 0.5 * len;
    }
    let max = bins.values().cloned().fold(0.0, f64::max);
    if max <= 0.0 {
        return None;
    }
    let (key, _) = bins.iter().rev().find(|(_, a)| **a >= 0.5 * max)?;
    // Refine: area-weighted mean height of the triangles in that bin.
    let (mut sum, mut area) = (0.0, 0.0);
    for t in &scene.triangles {
        let n = scene.scaled_normal(t);
        let len = n.norm();
        if len == 0.0 || n.z.abs() < 0.95 * len {
            continue;
        }
        let [a, b, c] = scene.corners(t);
        let z = (a.z + b.z + c.z) / 3.0;
        if (z / bin).round() as i64 == *key {
            sum += z * len;
            area += len;
        }
    }
    Some(sum / area)
}

type Tri2 = [[f64; 2]; 3];

/// Distance from `p` to the filled 2D triangle `t` (0 inside).
fn distance_to_triangle(p: [f64; 2], t: &Tri2) -> f64 {
    let cross = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| {
        (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    };
    let area = cross(t[0], t[1], t[2]);
    if area.abs() > 1e-12 {
        let s = area.signum();
        if (0..3).all(|k| s * cross(t[k], t[(k + 1) % 3], p) >= 0.0) {
            return 0.0;
        }
    }
    (0..3)
        .map(|k| closest_on_segment(p, t[k], t[(k + 1) % 3]))
        .map(|q| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt())
        .fold(f64::INFINITY, f64::min)
}

fn closest_on_segment(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    let d = [b[0] - a[0], b[1] - a[1]];
    let len2 = d[0] * d[0] + d[1] * d[1];
    let t = if len2 > 0.0 {
        (((p[0] - a[0]) * d[0] + (p[1] - a[1]) * d[1]) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    [a[0] + t * d[0], a[1] + t * d[1]]
}

/// Nearest point of the filled triangle `t` to `p` (p itself when inside).
fn closest_on_triangle(p: [f64; 2], t: &Tri2) -> [f64; 2] {
    if distance_to_triangle(p, t) == 0.0 {
        return p;
    }
    (0..3)
        .map(|k| closest_on_segment(p, t[k], t[(k + 1) % 3]))
        .min_by(|a, b| {
            let da = (p[0] - a[0]).powi(2) + (p[1] - a[1]).powi(2);
            let db = (p[0] - b[0]).powi(2) + (p[1] - b[1]).powi(2);
            da.total_cmp(&db)
        })
        .unwrap_or(p)
}

/// Clips the polygon `poly` (3D) to `z ≥ lo` (`keep_above`) or `z ≤ hi`.
fn clip_z(poly: &[[f64; 3]], bound: f64, keep_above: bool) -> Vec<[f64; 3]> {
    let inside = |p: &[f64; 3]| {
        if keep_above {
            p[2] >= bound
        } else {
            p[2] <= bound
        }
    };
    let mut out = Vec::with_capacity(poly.len() + 2);
    for i in 0..poly.len() {
        let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
        if inside(&a) {
            out.push(a);
        }
        if inside(&a) != inside(&b) {
            let t = (bound - a[2]) / (b[2] - a[2]);
            out.push(std::array::from_fn(|k| a[k] + t * (b[k] - a[k])));
        }
    }
    out
}

/// A uniform 2D grid over the scene's footprint: cell `(i, j)` covers
/// `x ∈ [origin_x + i·s, origin_x + (i+1)·s)`, `y ∈ [origin_y + j·s, …)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridFrame {
    /// World x of the grid's lower-left corner.
    pub origin_x: f64,
    /// World y of the grid's lower-left corner.
    pub origin_y: f64,
    /// Cell side, metres.
    pub cell_size: f64,
    /// Cells along x.
    pub width: usize,
    /// Cells along y.
    pub height: usize,
}

impl GridFrame {
    /// The cell holding world point (x, y), if inside the grid.
    pub fn cell_of(&self, x: f64, y: f64) -> Option<(usize, usize)> {
        let i = ((x - self.origin_x) / self.cell_size).floor();
        let j = ((y - self.origin_y) / self.cell_size).floor();
        (i >= 0.0 && j >= 0.0 && (i as usize) < self.width && (j as usize) < self.height)
            .then_some((i as usize, j as usize))
    }
    /// World (x, y) of the centre of cell (i, j).
    pub fn centre(&self, i: usize, j: usize) -> (f64, f64) {
        (
            self.origin_x + (i as f64 + 0.5) * self.cell_size,
            self.origin_y + (j as f64 + 0.5) * self.cell_size,
        )
    }
}

/// One room of [`NavigableMap::rooms`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Room {
    /// Navigable area, m².
    pub area: f64,
    /// World (x, y) of the mean of its cells' centres.
    pub centre: (f64, f64),
}

/// The rooms of a navigable map ([`NavigableMap::rooms`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Rooms {
    /// Per cell (as [`NavigableMap::cells`]): the index of its room in `rooms`, `u32::MAX`
    /// for cells in none.
    pub label: Vec<u32>,
    /// The rooms, largest first.
    pub rooms: Vec<Room>,
}

/// The navigable top-down map: one flag per cell, row-major with `j` (world y) as the row.
#[derive(Debug, Clone, PartialEq)]
pub struct NavigableMap {
    /// Grid geometry.
    pub frame: GridFrame,
    /// `cells[j * width + i]`: the agent may stand at the cell centre.
    pub cells: Vec<bool>,
}

impl NavigableMap {
    /// Whether cell (i, j) is navigable.
    pub fn is_navigable(&self, i: usize, j: usize) -> bool {
        self.cells[j * self.frame.width + i]
    }
    /// Number of navigable cells.
    pub fn count(&self) -> usize {
        self.cells.iter().filter(|&&c| c).count()
    }
    /// Navigable area, m².
    pub fn area(&self) -> f64 {
        self.count() as f64 * self.frame.cell_size * self.frame.cell_size
    }
    /// Connected-component label per cell (4-connectivity), `u32::MAX` for blocked cells, and
    /// the size of each component.
    pub fn components(&self) -> (Vec<u32>, Vec<usize>) {
        let (w, h) = (self.frame.width, self.frame.height);
        let mut label = vec![u32::MAX; w * h];
        let mut sizes = Vec::new();
        let mut queue = VecDeque::new();
        for start in 0..w * h {
            if !self.cells[start] || label[start] != u32::MAX {
                continue;
            }
            let id = sizes.len() as u32;
            let mut size = 0;
            label[start] = id;
            queue.push_back(start);
            while let Some(c) = queue.pop_front() {
                size += 1;
                let (i, j) = (c % w, c / w);
                let mut visit = |n: usize| {
                    if self.cells[n] && label[n] == u32::MAX {
                        label[n] = id;
                        queue.push_back(n);
                    }
                };
                if i > 0 {
                    visit(c - 1);
                }
                if i + 1 < w {
                    visit(c + 1);
                }
                if j > 0 {
                    visit(c - w);
                }
                if j + 1 < h {
                    visit(c + w);
                }
            }
            sizes.push(size);
        }
        (label, sizes)
    }
    /// Free space around each cell: the distance in metres from its centre to the centre of
    /// the nearest non-navigable cell (the grid's border counts as non-navigable), 0 for
    /// non-navigable cells. A two-pass chamfer distance transform with steps 1 and √2 (within
    /// about 8 % of the Euclidean distance), so the start can be chosen away from furniture.
    pub fn clearance(&self) -> Vec<f64> {
        let (w, h) = (self.frame.width, self.frame.height);
        let mut d: Vec<f64> = (0..w * h)
            .map(|c| {
                let (i, j) = (c % w, c / w);
                let border = i == 0 || j == 0 || i + 1 == w || j + 1 == h;
                if self.cells[c] && !border {
                    f64::INFINITY
                } else {
                    0.0
                }
            })
            .collect();
        let diagonal = std::f64::consts::SQRT_2;
        for j in 1..h.saturating_sub(1) {
            for i in 1..w - 1 {
                let c = j * w + i;
                let best = d[c]
                    .min(d[c - 1] + 1.0)
                    .min(d[c - w] + 1.0)
                    .min(d[c - w - 1] + diagonal)
                    .min(d[c - w + 1] + diagonal);
                d[c] = best;
            }
        }
        for j in (1..h.saturating_sub(1)).rev() {
            for i in (1..w - 1).rev() {
                let c = j * w + i;
                let best = d[c]
                    .min(d[c + 1] + 1.0)
                    .min(d[c + w] + 1.0)
                    .min(d[c + w + 1] + diagonal)
                    .min(d[c + w - 1] + diagonal);
                d[c] = best;
            }
        }
        d.iter().map(|v| v * self.frame.cell_size).collect()
    }
    /// A simple room segmentation, a marker watershed on the free space
    /// ([`NavigableMap::clearance`]): a doorway or an opening between rooms is narrower than
    /// the rooms, so the free space has a neck there.
    ///
    /// Markers are the connected parts (4-connectivity) of the cells with at least
    /// `room_clearance` metres of free space, and then those of the cells with at least
    /// `door_clearance` metres that hold no marker yet (a small room behind a door); parts under
    /// `min_area` m² are dropped. The markers then flood the other navigable cells in order of
    /// decreasing free space (ties by cell index: deterministic), so two rooms meet at the
    /// neck between them. Navigable cells no marker reaches are left out. Rooms are numbered by
    /// decreasing area.
    pub fn rooms(&self, door_clearance: f64, room_clearance: f64, min_area: f64) -> Rooms {
        use std::cmp::Reverse;
        let (w, h) = (self.frame.width, self.frame.height);
        let cell_area = self.frame.cell_size * self.frame.cell_size;
        let clearance = self.clearance();
        let mut label = vec![u32::MAX; w * h];
        let mut next = 0u32;
        for level in [room_clearance, door_clearance] {
            let part_map = NavigableMap {
                frame: self.frame,
                cells: clearance
                    .iter()
                    .zip(&self.cells)
                    .map(|(c, &n)| n && *c >= level)
                    .collect(),
            };
            let (part, sizes) = part_map.components();
            // A part becomes a marker when it is large and holds none yet.
            let mut taken = vec![false; sizes.len()];
            for (c, p) in part.iter().enumerate() {
                if *p != u32::MAX && label[c] != u32::MAX {
                    taken[*p as usize] = true;
                }
            }
            let mut marker = vec![u32::MAX; sizes.len()];
            for (k, size) in sizes.iter().enumerate() {
                if !taken[k] && *size as f64 * cell_area >= min_area {
                    marker[k] = next;
                    next += 1;
                }
            }
            for (c, p) in part.iter().enumerate() {
                if *p != u32::MAX && marker[*p as usize] != u32::MAX {
                    label[c] = marker[*p as usize];
                }
            }
        }
        // Flooding: the free space as an integer key (micrometres), larger first.
        let key = |c: usize| (clearance[c] * 1e6).round() as i64;
        let mut heap = std::collections::BinaryHeap::new();
        let neighbours = |c: usize| {
            let (i, j) = (c % w, c / w);
            [
                (i > 0).then(|| c - 1),
                (i + 1 < w).then(|| c + 1),
                (j > 0).then(|| c - w),
                (j + 1 < h).then(|| c + w),
            ]
        };
        for c in (0..w * h).filter(|&c| label[c] != u32::MAX) {
            for n in neighbours(c).into_iter().flatten() {
                if self.cells[n] && label[n] == u32::MAX {
                    heap.push((key(n), Reverse(n), Reverse(label[c])));
                }
            }
        }
        while let Some((_, Reverse(c), Reverse(l))) = heap.pop() {
            if label[c] != u32::MAX {
                continue;
            }
            label[c] = l;
            for n in neighbours(c).into_iter().flatten() {
                if self.cells[n] && label[n] == u32::MAX {
                    heap.push((key(n), Reverse(n), Reverse(l)));
                }
            }
        }
        let mut sums = vec![(0usize, 0.0, 0.0); next as usize];
        for (c, l) in label.iter().enumerate() {
            if *l != u32::MAX {
                let (x, y) = self.frame.centre(c % w, c / w);
                let s = &mut sums[*l as usize];
                *s = (s.0 + 1, s.1 + x, s.2 + y);
            }
        }
        // Largest first (ties by first cell), and the labels renumbered to match.
        let mut order: Vec<usize> = (0..sums.len()).collect();
        order.sort_by(|a, b| sums[*b].0.cmp(&sums[*a].0).then(a.cmp(b)));
        let mut rank = vec![0u32; sums.len()];
        for (r, k) in order.iter().enumerate() {
            rank[*k] = r as u32;
        }
        for l in label.iter_mut().filter(|l| **l != u32::MAX) {
            *l = rank[*l as usize];
        }
        let rooms = order
            .iter()
            .map(|&k| {
                let (n, x, y) = sums[k];
                Room {
                    area: n as f64 * cell_area,
                    centre: (x / n as f64, y / n as f64),
                }
            })
            .collect();
        Rooms { label, rooms }
    }
    /// Cells reachable from world point (x, y) through navigable cells (4-connectivity).
    pub fn reachable_from(&self, x: f64, y: f64) -> Vec<bool> {
        let (label, _) = self.components();
        match self
            .frame
            .cell_of(x, y)
            .map(|(i, j)| label[j * self.frame.width + i])
        {
            Some(l) if l != u32::MAX => label.iter().map(|&k| k == l).collect(),
            _ => vec![false; self.cells.len()],
        }
    }
}

/// Obstacles and floor of a scene for one agent shape: answers "may the agent stand here?".
#[derive(Debug, Clone)]
pub struct Navigation {
    floor_z: f64,
    shape: AgentShape,
    /// Obstacle footprints (2D triangles).
    obstacles: Vec<Tri2>,
    /// Spatial hash of obstacles: bucket → obstacle indices.
    buckets: Vec<Vec<u32>>,
    bucket_frame: GridFrame,
    /// Floor presence per navigable-map cell.
    floor: Vec<bool>,
    map: NavigableMap,
}

const BUCKET_SIZE: f64 = 0.25;
/// Largest navigable grid (cells) before [`Navigation::build`] refuses (about 1 GB of flags and
/// labels); a 400 m × 400 m footprint at 5 cm.
const MAX_GRID_CELLS: usize = 64 << 20;

impl Navigation {
    /// Builds obstacles, floor coverage and the navigable map (cells of `cell_size` metres).
    pub fn build(scene: &Scene, floor_z: f64, shape: AgentShape, cell_size: f64) -> Result<Self> {
        if !(shape.radius > 0.0 && shape.height > shape.max_climb && shape.max_climb >= 0.0) {
            return Err(SimError::InvalidConfig {
                field: "agent",
                value: format!("{shape:?}"),
                reason: "need radius > 0 and height > max_climb >= 0",
            });
        }
        if !cell_size.is_finite() || cell_size <= 0.0 {
            return Err(SimError::InvalidConfig {
                field: "nav_cell_size",
                value: cell_size.to_string(),
                reason: "must be > 0",
            });
        }
        let bounds = scene
            .bounds()
            .ok_or_else(|| SimError::EmptyScene(scene.name.clone()))?;
        let (lo, hi) = (floor_z + shape.max_climb, floor_z + shape.height);
        let mut obstacles = Vec::new();
        let mut floor_tris = Vec::new();
        for t in &scene.triangles {
            let c = scene.corners(t).map(|p| [p.x, p.y, p.z]);
            let n = scene.scaled_normal(t);
            let len = n.norm();
            if len == 0.0 {
                continue;
            }
            let zmin = c.iter().map(|p| p[2]).fold(f64::INFINITY, f64::min);
            let zmax = c.iter().map(|p| p[2]).fold(f64::NEG_INFINITY, f64::max);
            if n.z.abs() >= 0.9 * len && zmin >= floor_z - 0.1 && zmax <= lo {
                floor_tris.push(c.map(|p| [p[0], p[1]]));
            }
            if zmax < lo || zmin > hi {
                continue;
            }
            let poly = clip_z(&clip_z(&c, lo, true), hi, false);
            for k in 1..poly.len().saturating_sub(1) {
                obstacles.push([poly[0], poly[k], poly[k + 1]].map(|p| [p[0], p[1]]));
            }
        }
        let margin = 2.0 * cell_size;
        let grid = |s: f64| {
            let ox = ((bounds.min.x - margin) / s).floor() * s;
            let oy = ((bounds.min.y - margin) / s).floor() * s;
            GridFrame {
                origin_x: ox,
                origin_y: oy,
                cell_size: s,
                width: ((bounds.max.x + margin - ox) / s).ceil() as usize,
                height: ((bounds.max.y + margin - oy) / s).ceil() as usize,
            }
        };
        let frame = grid(cell_size);
        if frame.width.saturating_mul(frame.height) > MAX_GRID_CELLS {
            return Err(SimError::InvalidConfig {
                field: "nav_cell_size",
                value: cell_size.to_string(),
                reason: "the scene footprint needs more than 64M navigation cells; use larger cells",
            });
        }
        let bucket_frame = grid(BUCKET_SIZE.max(cell_size));
        let mut buckets = vec![Vec::new(); bucket_frame.width * bucket_frame.height];
        for (oi, o) in obstacles.iter().enumerate() {
            let (i0, j0, i1, j1) = cell_range(&bucket_frame, o, 0.0);
            for j in j0..=j1 {
                for i in i0..=i1 {
                    buckets[j * bucket_frame.width + i].push(oi as u32);
                }
            }
        }
        let mut floor = vec![false; frame.width * frame.height];
        for t in &floor_tris {
            let (i0, j0, i1, j1) = cell_range(&frame, t, 0.0);
            for j in j0..=j1 {
                for i in i0..=i1 {
                    let (x, y) = frame.centre(i, j);
                    if distance_to_triangle([x, y], t) <= 1e-9 {
                        floor[j * frame.width + i] = true;
                    }
                }
            }
        }
        let mut nav = Navigation {
            floor_z,
            shape,
            obstacles,
            buckets,
            bucket_frame,
            floor,
            map: NavigableMap {
                frame,
                cells: Vec::new(),
            },
        };
        let cells: Vec<bool> = (0..frame.width * frame.height)
            .map(|c| {
                let (x, y) = frame.centre(c % frame.width, c / frame.width);
                nav.floor[c] && !nav.collides(x, y)
            })
            .collect();
        nav.map.cells = cells;
        Ok(nav)
    }

    /// The floor height this navigation was built for.
    pub fn floor_z(&self) -> f64 {
        self.floor_z
    }

    /// The agent shape this navigation was built for.
    pub fn shape(&self) -> AgentShape {
        self.shape
    }

    /// The navigable top-down map.
    pub fn map(&self) -> &NavigableMap {
        &self.map
    }

    /// Whether the agent's disc at (x, y) touches an obstacle.
    pub fn collides(&self, x: f64, y: f64) -> bool {
        self.nearest_obstacle(x, y, self.shape.radius)
            .is_some_and(|(_, d)| d < self.shape.radius)
    }

    /// Whether floor lies under (x, y).
    pub fn has_floor(&self, x: f64, y: f64) -> bool {
        self.map
            .frame
            .cell_of(x, y)
            .is_some_and(|(i, j)| self.floor[j * self.map.frame.width + i])
    }

    /// Whether the agent may stand at (x, y).
    pub fn is_navigable(&self, x: f64, y: f64) -> bool {
        self.has_floor(x, y) && !self.collides(x, y)
    }

    /// The nearest obstacle point within `search` metres of (x, y), and its distance.
    fn nearest_obstacle(&self, x: f64, y: f64, search: f64) -> Option<([f64; 2], f64)> {
        let f = &self.bucket_frame;
        let probe = [[x, y]; 3];
        let (i0, j0, i1, j1) = cell_range(f, &probe, search);
        let mut best: Option<([f64; 2], f64)> = None;
        for j in j0..=j1 {
            for i in i0..=i1 {
                for &oi in &self.buckets[j * f.width + i] {
                    let q = closest_on_triangle([x, y], &self.obstacles[oi as usize]);
                    let d = ((x - q[0]).powi(2) + (y - q[1]).powi(2)).sqrt();
                    if d <= search && best.is_none_or(|(_, bd)| d < bd) {
                        best = Some((q, d));
                    }
                }
            }
        }
        best
    }

    /// Habitat-style forward motion by `distance` along `pose.yaw`. Returns the new pose and
    /// whether the motion was obstructed. With `allow_sliding`, an obstructed step moves to
    /// the nearest free point of the target (pushing the disc out of the walls it touches, so
    /// the agent slides along them), accepted only if it is navigable and no longer than
    /// the commanded step; otherwise the agent stays. The result is always navigable when the
    /// start was.
    pub fn try_forward(
        &self,
        pose: &PlanarPose,
        distance: f64,
        allow_sliding: bool,
    ) -> (PlanarPose, bool) {
        let (s, c) = pose.yaw.sin_cos();
        let target = [pose.x + distance * c, pose.y + distance * s];
        if self.is_navigable(target[0], target[1]) {
            return (PlanarPose::new(target[0], target[1], pose.yaw), false);
        }
        if !allow_sliding {
            return (*pose, true);
        }
        let r = self.shape.radius;
        let mut p = target;
        for _ in 0..8 {
            match self.nearest_obstacle(p[0], p[1], r) {
                Some((q, d)) if d < r => {
                    if d < 1e-9 {
                        return (*pose, true);
                    }
                    let push = (r + 1e-6) / d;
                    p = [q[0] + (p[0] - q[0]) * push, q[1] + (p[1] - q[1]) * push];
                }
                _ => break,
            }
        }
        let moved = ((p[0] - pose.x).powi(2) + (p[1] - pose.y).powi(2)).sqrt();
        if self.is_navigable(p[0], p[1]) && moved <= distance.abs() + 1e-9 {
            (PlanarPose::new(p[0], p[1], pose.yaw), true)
        } else {
            (*pose, true)
        }
    }

    /// A start pose derived from the map: among the navigable cells of the largest connected
    /// region with at least [`START_CLEARANCE_M`] of free space around them (or, where no
    /// cell has that much, the most), the one closest to the region's centroid, facing +x. The
    /// clearance keeps a scene file's start off the furniture: the centroid of a furnished
    /// room's floor often lies millimetres from a sofa the robot cannot see behind itself.
    pub fn derived_start(&self, scene_name: &str) -> Result<PlanarPose> {
        let (label, sizes) = self.map.components();
        let (best, _) = sizes
            .iter()
            .enumerate()
            .max_by_key(|(i, s)| (**s, std::cmp::Reverse(*i)))
            .ok_or_else(|| SimError::NoNavigableArea(scene_name.to_string()))?;
        let f = &self.map.frame;
        let members: Vec<usize> = (0..label.len())
            .filter(|&c| label[c] == best as u32)
            .collect();
        let (mut sx, mut sy) = (0.0, 0.0);
        for &c in &members {
            let (x, y) = f.centre(c % f.width, c / f.width);
            sx += x;
            sy += y;
        }
        let (cx, cy) = (sx / members.len() as f64, sy / members.len() as f64);
        let clearance = self.map.clearance();
        let most = members.iter().map(|&c| clearance[c]).fold(0.0, f64::max);
        let wanted = START_CLEARANCE_M.min(most);
        let c = members
            .iter()
            .filter(|&&c| clearance[c] >= wanted)
            .min_by(|&&a, &&b| {
                let d = |c: usize| {
                    let (x, y) = f.centre(c % f.width, c / f.width);
                    (x - cx).powi(2) + (y - cy).powi(2)
                };
                d(a).total_cmp(&d(b))
            })
            .copied()
            .ok_or_else(|| SimError::NoNavigableArea(scene_name.to_string()))?;
        let (x, y) = f.centre(c % f.width, c / f.width);
        Ok(PlanarPose::new(x, y, 0.0))
    }

    /// A seeded episode start: the centre of a navigable cell drawn uniformly among those
    /// reachable from `anchor` (so the episode explores the same connected floor), with a yaw
    /// uniform in [−π, π). Different seeds give different episodes of one scene; `None` when
    /// `anchor` is not on the navigable map.
    pub fn random_start(&self, anchor: &PlanarPose, seed: u64) -> Option<PlanarPose> {
        use rand::{Rng, SeedableRng};
        let reachable = self.map.reachable_from(anchor.x, anchor.y);
        let cells: Vec<usize> = (0..reachable.len()).filter(|&c| reachable[c]).collect();
        if cells.is_empty() {
            return None;
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let c = cells[rng.random_range(0..cells.len())];
        let f = &self.map.frame;
        let (x, y) = f.centre(c % f.width, c / f.width);
        let yaw = (rng.random::<f64>() * 2.0 - 1.0) * std::f64::consts::PI;
        Some(PlanarPose::new(x, y, yaw))
    }
}

/// Inclusive cell index range of the bounding box of `t` grown by `grow`, clamped to the grid.
fn cell_range(f: &GridFrame, t: &Tri2, grow: f64) -> (usize, usize, usize, usize) {
    let minx = t.iter().map(|p| p[0]).fold(f64::INFINITY, f64::min) - grow;
    let maxx = t.iter().map(|p| p[0]).fold(f64::NEG_INFINITY, f64::max) + grow;
    let miny = t.iter().map(|p| p[1]).fold(f64::INFINITY, f64::min) - grow;
    let maxy = t.iter().map(|p| p[1]).fold(f64::NEG_INFINITY, f64::max) + grow;
    let idx =
        |v: f64, o: f64, n: usize| (((v - o) / f.cell_size).floor().max(0.0) as usize).min(n - 1);
    (
        idx(minx, f.origin_x, f.width),
        idx(miny, f.origin_y, f.height),
        idx(maxx, f.origin_x, f.width),
        idx(maxy, f.origin_y, f.height),
    )
}
